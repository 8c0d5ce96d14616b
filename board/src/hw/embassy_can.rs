//! CAN1 through embassy-stm32's own bxCAN driver: the shipped default (`docs/can-driver.md`).
//!
//! The channel loop reads the receive FIFOs itself ([`CanPort::receive`]); a FIFO overrun is
//! read from CAN_RFxR.FOVR, which the driver does not report. The loop also fills the transmit
//! mailboxes from its queue, as the `bxcan` adapter does: both go through
//! [`crate::transmit_queue::Transmitter`], which also tells which frames went out (SimpleCAN:
//! SC_REQ_18, SC_REQ_23). Until the SimpleCAN images needed to know what went out, a task of
//! its own moved frames from an embassy-sync priority channel into the mailboxes; the loop
//! could not see the mailboxes' records there, nor take a frame back out of that channel.

use core::future::{Future, poll_fn};
use core::pin::pin;
use core::task::Poll;
use dual_channel::can_loopback::{LoopbackController, LoopbackFault, Received};
use dual_channel::channel_loop::{self, QueueFull};
use dual_channel::filters::{self, Bank, BankLayout};
use embassy_futures::select::{Either, select};
use embassy_stm32::Peri;
use embassy_stm32::bind_interrupts;
use embassy_stm32::can::enums::{BusError, TryReadError};
use embassy_stm32::can::filter::{ListEntry16, ListEntry32, Mask16};
use embassy_stm32::can::{
    Can, CanRx, CanTx, Fifo, Frame, Mailbox as EmbassyMailbox, Rx0InterruptHandler,
    Rx1InterruptHandler, SceInterruptHandler, StandardId, TxInterruptHandler,
};
use embassy_stm32::peripherals::{CAN1, PB8, PB9};
use shared::{CanFrame, Instant};

use super::{embassy_instant, halt_safe, now};
use crate::transmit_queue::{Controller, Mailbox, Placement, Refusal, Transmitter};

bind_interrupts!(struct Irqs {
    CAN1_RX0 => Rx0InterruptHandler<CAN1>;
    CAN1_RX1 => Rx1InterruptHandler<CAN1>;
    CAN1_SCE => SceInterruptHandler<CAN1>;
    CAN1_TX => TxInterruptHandler<CAN1>;
});

/// Frames waiting for a transmit mailbox: by identifier, not first in first out
/// ([`crate::transmit_queue`]), so the node's own heartbeat or EMCY never holds back its SRDO
/// or GFC.
const TRANSMIT_QUEUE: usize = 16;

/// CAN1 as the channel loop uses it: the receive FIFOs and filters, the transmit path.
pub struct CanPort {
    /// Kept: its drop would reset the controller under the halves. Used again only to
    /// switch the bit rate.
    controller: Can<'static>,
    rx: CanRx<'static>,
    tx: CanTx<'static>,
    transmitter: Transmitter<TRANSMIT_QUEUE>,
    /// A frame the wait took from a FIFO, for the next [`CanPort::receive`].
    frame: Option<CanFrame>,
}

/// embassy-stm32's mailboxes for the transmit path ([`crate::transmit_queue`]).
impl Controller for CanTx<'_> {
    /// embassy-stm32 0.6 refuses a frame while a pending one has the same identifier (FIFO
    /// scheduling stays off outside the loop-back test), so up to three frames of different
    /// identifiers are pending at once; when all three are pending with lower priority it
    /// takes the lowest back out.
    fn place(&mut self, frame: &CanFrame) -> Result<Placement, Refusal> {
        let Some(frame) = to_bxcan(frame) else {
            // Not a frame the driver can carry (a `CanFrame` never is one): dropped, logged.
            defmt::warn!("CAN frame not sendable, dropped");
            return Err(Refusal::Unsendable);
        };
        let status = self.try_write(&frame).map_err(|_| Refusal::Busy)?;
        Ok(Placement {
            mailbox: mailbox_of(status.mailbox()),
            displaced: status.dequeued_frame().is_some(),
        })
    }

    fn abort(&mut self, mailbox: Mailbox) -> bool {
        CanTx::abort(self, embassy_mailbox(mailbox))
    }

    fn empty(&self) -> [bool; 3] {
        super::empty_mailboxes()
    }
}

fn mailbox_of(mailbox: EmbassyMailbox) -> Mailbox {
    match mailbox {
        EmbassyMailbox::Mailbox0 => Mailbox::ALL[0],
        EmbassyMailbox::Mailbox1 => Mailbox::ALL[1],
        EmbassyMailbox::Mailbox2 => Mailbox::ALL[2],
    }
}

fn embassy_mailbox(mailbox: Mailbox) -> EmbassyMailbox {
    match mailbox.index() {
        0 => EmbassyMailbox::Mailbox0,
        1 => EmbassyMailbox::Mailbox1,
        _ => EmbassyMailbox::Mailbox2,
    }
}

impl CanPort {
    /// Brings CAN1 up at `timing`: the CiA 304 9.5 loop-back test, then on the bus with no
    /// filter bank enabled (the channel loop programs the node's before the core boots).
    pub async fn start(
        can: Peri<'static, CAN1>,
        rx: Peri<'static, PB8>,
        tx: Peri<'static, PB9>,
        timing: embassy_stm32::can::util::NominalBitTiming,
        watchdog: &mut super::Watchdog,
    ) -> CanPort {
        let mut can = Can::new(can, rx, tx, Irqs);
        // `Can::set_bitrate` unwraps the timing calculation, which links the `Debug`
        // formatting of its error into the image (`docs/footprint.md`); the board calculates
        // it and hands the result in. The configuration leaves initialisation mode when it
        // is dropped, as in `set_bitrate`.
        drop(can.modify_config().set_bit_timing(timing));
        match loopback_test(&mut can, watchdog).await {
            Ok(()) => {
                defmt::info!("self-test: CAN loop-back (3 mailboxes, 2 FIFOs, filters) passed")
            }
            Err(fault) => {
                defmt::error!("self-test: CAN loop-back failed {}", fault);
                halt_safe("CAN controller self-test failed");
            }
        }
        // No filter bank enabled: the controller takes no frame until the channel loop has
        // programmed the node's filters (its first service, before the core boots).
        can.modify_filters().clear();
        can.enable().await;
        let (can_tx, can_rx) = can.split();
        CanPort {
            controller: can,
            rx: can_rx,
            tx: can_tx,
            transmitter: Transmitter::new(),
            frame: None,
        }
    }

    /// Switches the controller to `timing` (CiA 305 activate bit timing, in the node's
    /// silence after the first switch delay): the configuration enters initialisation mode,
    /// writes BTR (RM0090 32.9.2) and leaves it when dropped, as in `start`.
    pub fn switch_bit_rate(&mut self, timing: embassy_stm32::can::util::NominalBitTiming) {
        drop(self.controller.modify_config().set_bit_timing(timing));
    }

    /// Queues `frame` and fills the mailboxes from the queue.
    pub fn transmit(&mut self, frame: &CanFrame) -> Result<(), QueueFull> {
        self.transmitter.transmit(frame, &mut self.tx)
    }

    /// The oldest frame confirmed as sent since the last call (SC_REQ_18, SC_REQ_23).
    #[cfg(feature = "simplecan")]
    pub fn transmitted(&mut self) -> Option<CanFrame> {
        self.transmitter.transmitted(&self.tx)
    }

    /// Withdraws the frames on `id` not yet sent (SC_REQ_18, SC_REQ_23).
    #[cfg(feature = "simplecan")]
    pub fn abort(&mut self, id: shared::CanId) {
        self.transmitter.withdraw(id, &mut self.tx);
    }

    /// The next frame of the FIFOs, or their overrun (CAN_RFxR.FOVR: bxCAN keeps three
    /// frames per FIFO and, with RFLM = 0, the reset value kept, the newest overwrites the
    /// third, so a frame the filters passed was lost, RM0090 32.7.5).
    pub fn receive(&mut self) -> Option<channel_loop::Received> {
        let can = embassy_stm32::pac::CAN1;
        let mut lost = false;
        for fifo in 0..2 {
            if can.rfr(fifo).read().fovr() {
                // FOVR is cleared by writing 1; FULL likewise, RFOM = 0 releases nothing.
                can.rfr(fifo).write(|w| w.set_fovr(true));
                lost = true;
            }
        }
        if lost {
            return Some(channel_loop::Received::Overrun);
        }
        if let Some(frame) = self.frame.take() {
            return Some(channel_loop::Received::Frame(frame));
        }
        loop {
            match self.rx.try_read() {
                Ok(envelope) => {
                    // Not CANopen's (extended, length over 8): as if filtered out.
                    if let Some(frame) = from_bxcan(&envelope.frame) {
                        return Some(channel_loop::Received::Frame(frame));
                    }
                }
                Err(TryReadError::Empty) => return None,
                Err(TryReadError::BusError(error)) => {
                    defmt::warn!("CAN bus error {}", LastError::from(&error));
                    return None;
                }
            }
        }
    }

    /// Programs `layout` into CAN1's filter banks.
    pub fn apply_filters(&mut self, layout: &BankLayout) {
        let id = |raw: u16| StandardId::new(raw).unwrap_or(StandardId::ZERO);
        let mut banks = self.rx.modify_filters();
        banks.clear();
        for (index, &(bank, fifo)) in layout.banks.iter().enumerate() {
            let fifo = match fifo {
                filters::Fifo::Srdo => Fifo::Fifo0,
                filters::Fifo::Services => Fifo::Fifo1,
            };
            // At most 14 banks: the index fits.
            let index = index as u8;
            match bank {
                Bank::List16(ids) => {
                    banks.enable_bank(
                        index,
                        fifo,
                        ids.map(|raw| ListEntry16::data_frames_with_id(id(raw))),
                    );
                }
                Bank::Mask16(pairs) => {
                    banks.enable_bank(
                        index,
                        fifo,
                        pairs.map(|(raw, mask)| {
                            *Mask16::frames_with_std_id(id(raw), id(mask)).data_frames_only()
                        }),
                    );
                }
            }
        }
        // Dropping the proxy leaves filter initialisation mode.
    }

    /// Waits for a received frame (kept for the next [`CanPort::receive`]), or for a pending
    /// mailbox to complete while frames wait for one (with SimpleCAN also while a sent frame
    /// is still to be confirmed).
    pub async fn wait(&mut self) {
        self.transmitter.fill(&mut self.tx);
        if cfg!(feature = "simplecan") && self.transmitter.has_sent(&self.tx) {
            // A frame went out since the loop last asked: its confirmation is due now.
            return;
        }
        let completion_awaited = self.transmitter.is_waiting()
            || (cfg!(feature = "simplecan") && self.transmitter.is_pending());
        let received = if completion_awaited {
            match select(self.rx.read(), completion(&self.tx)).await {
                Either::First(received) => received,
                Either::Second(()) => return,
            }
        } else {
            self.rx.read().await
        };
        match received {
            Ok(envelope) => self.frame = from_bxcan(&envelope.frame),
            Err(error) => defmt::warn!("CAN bus error {}", LastError::from(&error)),
        }
    }
}

/// Returns once a mailbox that is pending now has emptied (its frame went out, or was taken
/// back): embassy-stm32's `flush` of each, which its transmit interrupt wakes. A mailbox
/// empty at the call is left out (its flush would return at once).
async fn completion(tx: &CanTx<'_>) {
    let pending = super::empty_mailboxes().map(|empty| !empty);
    let mut first = pin!(tx.flush(EmbassyMailbox::Mailbox0));
    let mut second = pin!(tx.flush(EmbassyMailbox::Mailbox1));
    let mut third = pin!(tx.flush(EmbassyMailbox::Mailbox2));
    poll_fn(|cx| {
        let flushes = [first.as_mut(), second.as_mut(), third.as_mut()];
        for (flush, pending) in flushes.into_iter().zip(pending) {
            if pending && flush.poll(cx).is_ready() {
                return Poll::Ready(());
            }
        }
        Poll::Pending
    })
    .await;
}

/// The bxCAN in silent loop-back mode, for [`dual_channel::can_loopback::run`].
struct Loopback<'a, 'd> {
    can: &'a mut Can<'d>,
}

impl LoopbackController for Loopback<'_, '_> {
    fn now(&self) -> Instant {
        now()
    }

    fn queue(&mut self, frame: &CanFrame) -> Option<u8> {
        let frame = to_bxcan(frame)?;
        let status = self.can.try_write(&frame).ok()?;
        Some(status.mailbox() as u8)
    }

    async fn receive(&mut self, until: Instant) -> Received {
        match embassy_time::with_deadline(embassy_instant(until), self.can.read()).await {
            Ok(Ok(envelope)) => match from_bxcan(&envelope.frame) {
                Some(frame) => Received::Frame(frame),
                None => Received::Unreadable {
                    id: raw_id(&envelope.frame),
                    dlc: envelope.frame.header().len(),
                },
            },
            Ok(Err(_)) => Received::BusError,
            Err(_) => Received::Nothing,
        }
    }
}

/// CiA 304 9.5: the controller's message buffers and filters, tested in silent loop-back mode
/// before it joins the bus (plan, loop and verdict: [`dual_channel::can_loopback`]). Leaves
/// the controller out of loop-back, for [`CanPort::start`] to clear its filters and enable it.
async fn loopback_test(
    can: &mut Can<'_>,
    watchdog: &mut super::Watchdog,
) -> Result<(), LoopbackFault> {
    use dual_channel::can_loopback::{ACCEPT_FIFO0, ACCEPT_FIFO1};
    // The plan's identifiers are 11-bit constants; an invalid one would become 0 and fail the
    // test as missing.
    let listed = |ids: [u16; 2]| {
        ids.map(|id| {
            ListEntry32::data_frames_with_id(StandardId::new(id).unwrap_or(StandardId::ZERO))
        })
    };
    can.modify_config().set_loopback(true).set_silent(true);
    can.modify_filters()
        .clear()
        .enable_bank(0, Fifo::Fifo0, listed(ACCEPT_FIFO0))
        .enable_bank(1, Fifo::Fifo1, listed(ACCEPT_FIFO1));
    // In queue order, so that a burst fills mailboxes 0, 1 and 2 one after the other.
    can.set_tx_fifo_scheduling(true);
    can.enable().await;
    // Each burst takes at most BURST_WAIT (5 ms), well inside the watchdog's time.
    let verdict =
        dual_channel::can_loopback::run(&mut Loopback { can: &mut *can }, || watchdog.pet()).await;
    can.set_tx_fifo_scheduling(false);
    // Out of loop-back; dropping the configuration proxy leaves initialisation mode.
    can.modify_config().set_loopback(false).set_silent(false);
    verdict
}

/// A received frame's identifier as far as it fits (extended identifiers cut to 16 bits), for
/// the report of a frame that is not CANopen's.
fn raw_id(frame: &Frame) -> u16 {
    match frame.id() {
        embassy_stm32::can::Id::Standard(id) => id.as_raw(),
        embassy_stm32::can::Id::Extended(id) => id.as_raw() as u16,
    }
}

/// A standard data or remote frame from the bxCAN ([`CanFrame::received`] has the rules).
/// The length is taken from the header and the data from the raw registers: embassy-stm32's
/// `Frame::data` would panic on a length code over 8.
fn from_bxcan(frame: &Frame) -> Option<CanFrame> {
    let embassy_stm32::can::Id::Standard(id) = frame.id() else {
        return None;
    };
    let mut data = [0u8; 8];
    data.copy_from_slice(frame.raw_data().get(..8)?);
    CanFrame::received(
        id.as_raw(),
        frame.header().rtr(),
        frame.header().len(),
        &data,
    )
}

fn to_bxcan(frame: &CanFrame) -> Option<Frame> {
    let id = StandardId::new(frame.id().raw())?;
    if frame.is_remote() {
        Frame::new_remote(id, usize::from(frame.dlc())).ok()
    } else {
        Frame::new_data(id, frame.data()).ok()
    }
}

/// embassy-stm32's [`BusError`] for the log, named by our own type: embassy's crates are
/// built without their `defmt` feature, whose log and panic sites took far more flash than
/// this name costs back (both measured in `docs/footprint.md`).
#[derive(defmt::Format)]
enum LastError {
    Stuff,
    Form,
    Acknowledge,
    BitRecessive,
    BitDominant,
    Crc,
    Software,
}

impl From<&BusError> for LastError {
    fn from(error: &BusError) -> Self {
        match error {
            BusError::Stuff => LastError::Stuff,
            BusError::Form => LastError::Form,
            BusError::Acknowledge => LastError::Acknowledge,
            BusError::BitRecessive => LastError::BitRecessive,
            BusError::BitDominant => LastError::BitDominant,
            BusError::Crc => LastError::Crc,
            BusError::Software => LastError::Software,
        }
    }
}
