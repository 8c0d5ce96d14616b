//! CAN1 through the `bxcan` 0.8 crate (feature `can-bxcan`), in the manner of
//! `canadensis_bxcan`: the channel loop's task owns the controller and does all of it, receive
//! FIFOs, filters and transmit mailboxes; embassy-stm32 still gives the clock, the pins and
//! the interrupt vectors. Not the shipped driver (`docs/can-driver.md`: with bxcan's transmit
//! rule the CiA 304 9.5 loop-back plan cannot fill the mailboxes in its order, so this image
//! halts at its start-up self-test until the plan's bursts are reordered).
//!
//! What bxcan decides is host-tested in [`crate::bxcan_adapter`] (filter banks, bit timing,
//! mailbox records); this module moves it between the registers and the loop. Interrupts only
//! wake the loop ([`super::can_wakeup`], shared with the board's own driver).

use bxcan::filter::ListEntry32;
use bxcan::{Can, Data, Frame, Id, Interrupts, StandardId};
use dual_channel::can_loopback::{LoopbackController, LoopbackFault, Received};
use dual_channel::channel_loop::{self, QueueFull};
use dual_channel::filters::BankLayout;
use embassy_stm32::Peri;
use embassy_stm32::can::{RxPin, TxPin};
use embassy_stm32::gpio::{AfType, Flex, OutputType, Pull, Speed};
use embassy_stm32::peripherals::{CAN1, PB8, PB9};
use shared::{CanFrame, Instant};

use super::can_wakeup::{self, Irqs, MAILBOX_FREE, RECEIVED, unmask_receive, unmask_transmit};
use super::{bit_timing_register, embassy_instant, halt_safe, now};
use crate::bxcan_adapter;
use crate::transmit_queue::{Controller, Mailbox, Placement, Refusal, Transmitter};

/// CAN1 and its two pins, owned for as long as bxcan drives them.
pub struct Can1 {
    _peripheral: Peri<'static, CAN1>,
    _rx: Flex<'static>,
    _tx: Flex<'static>,
}

// SAFETY: `Can1` holds embassy-stm32's one CAN1 token, so no other driver reaches the
// controller, and `REGISTERS` is CAN1's register block (stm32-metapac's address, RM0090
// Table 1), valid for the whole run. Outside bxcan only the hardware layer's reads of CAN_ESR
// (`board::hw`) and of CAN_TSR's mailbox-empty bits ([`Controller::empty`] below), status
// registers whose reads change nothing, touch it, from the task that owns the `Can`, never
// during a bxcan call; the interrupt handlers below touch only the NVIC.
unsafe impl bxcan::Instance for Can1 {
    const REGISTERS: *mut bxcan::RegisterBlock = embassy_stm32::pac::CAN1.as_ptr().cast();
}

// SAFETY: CAN1 is the STM32F405's master bxCAN: the 28 filter banks are its registers, CAN2
// gets the banks from CAN_FMR.CAN2SB (reset value 14, kept) on, and this board does not use
// CAN2 (RM0090 32.7.4).
unsafe impl bxcan::FilterOwner for Can1 {
    const NUM_FILTER_BANKS: u8 = 28;
}

/// Frames waiting for a transmit mailbox, as [`crate::transmit_queue`] orders them.
const TRANSMIT_QUEUE: usize = 16;

/// CAN1 as the channel loop uses it, all on the loop's task.
pub struct CanPort {
    can: Can<Can1>,
    transmitter: Transmitter<TRANSMIT_QUEUE>,
}

/// bxcan's mailboxes for the transmit path ([`crate::transmit_queue`]).
impl Controller for Can<Can1> {
    /// bxcan refuses a frame when a pending one has the same or a higher priority (so
    /// frames of one identifier leave in queue order), and when all three are pending with
    /// lower priority it takes the lowest back out.
    fn place(&mut self, frame: &CanFrame) -> Result<Placement, Refusal> {
        let Some(frame) = to_bxcan(frame) else {
            // Not a frame bxcan can carry (a `CanFrame` never is one): dropped, logged.
            defmt::warn!("CAN frame not sendable, dropped");
            return Err(Refusal::Unsendable);
        };
        let status = self.transmit(&frame).map_err(|_| Refusal::Busy)?;
        Ok(Placement {
            mailbox: mailbox_of(status.mailbox()),
            displaced: status.dequeued_frame().is_some(),
        })
    }

    fn abort(&mut self, mailbox: Mailbox) -> bool {
        Can::abort(self, bxcan_mailbox(mailbox))
    }

    fn empty(&self) -> [bool; 3] {
        super::empty_mailboxes()
    }
}

fn mailbox_of(mailbox: bxcan::Mailbox) -> Mailbox {
    match mailbox {
        bxcan::Mailbox::Mailbox0 => Mailbox::ALL[0],
        bxcan::Mailbox::Mailbox1 => Mailbox::ALL[1],
        bxcan::Mailbox::Mailbox2 => Mailbox::ALL[2],
    }
}

fn bxcan_mailbox(mailbox: Mailbox) -> bxcan::Mailbox {
    match mailbox.index() {
        0 => bxcan::Mailbox::Mailbox0,
        1 => bxcan::Mailbox::Mailbox1,
        _ => bxcan::Mailbox::Mailbox2,
    }
}

impl CanPort {
    /// Brings CAN1 up at `timing`: pins and clock, the CiA 304 9.5 loop-back test, then on
    /// the bus with no filter bank enabled (the channel loop programs the node's before the
    /// core boots).
    pub async fn start(
        can: Peri<'static, CAN1>,
        rx: Peri<'static, PB8>,
        tx: Peri<'static, PB9>,
        timing: embassy_stm32::can::util::NominalBitTiming,
        watchdog: &mut super::Watchdog,
    ) -> CanPort {
        can_wakeup::bound(Irqs);
        let Ok(btr) = bit_timing_register(timing) else {
            halt_safe("CAN bit timing outside the bxCAN's fields");
        };
        let (rx_af, tx_af) = (RxPin::<CAN1>::af_num(&*rx), TxPin::<CAN1>::af_num(&*tx));
        let mut rx = Flex::new(rx);
        rx.set_as_af_unchecked(rx_af, AfType::input(Pull::None));
        let mut tx = Flex::new(tx);
        tx.set_as_af_unchecked(tx_af, AfType::output(OutputType::PushPull, Speed::VeryHigh));
        embassy_stm32::rcc::enable_and_reset::<CAN1>();
        let instance = Can1 {
            _peripheral: can,
            _rx: rx,
            _tx: tx,
        };
        let mut can = Can::builder(instance)
            .set_bit_timing(btr)
            .set_loopback(true)
            .set_silent(true)
            .leave_disabled();
        can.enable_interrupts(
            Interrupts::FIFO0_MESSAGE_PENDING
                | Interrupts::FIFO1_MESSAGE_PENDING
                | Interrupts::TRANSMIT_MAILBOX_EMPTY,
        );
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
        joined(&mut can).await;
        CanPort {
            can,
            transmitter: Transmitter::new(),
        }
    }

    /// Switches the controller to `timing` (CiA 305 activate bit timing, in the node's
    /// silence after the first switch delay): bxcan enters initialisation mode, writes BTR
    /// (RM0090 32.9.2) and leaves it when the configuration is dropped.
    pub fn switch_bit_rate(&mut self, timing: embassy_stm32::can::util::NominalBitTiming) {
        let Ok(btr) = bit_timing_register(timing) else {
            halt_safe("CAN bit timing outside the bxCAN's fields");
        };
        drop(self.can.modify_config().set_bit_timing(btr));
    }

    /// Queues `frame` and fills the mailboxes from the queue.
    pub fn transmit(&mut self, frame: &CanFrame) -> Result<(), QueueFull> {
        self.transmitter.transmit(frame, &mut self.can)
    }

    /// The oldest frame confirmed as sent since the last call (SC_REQ_18, SC_REQ_23).
    #[cfg(feature = "simplecan")]
    pub fn transmitted(&mut self) -> Option<CanFrame> {
        self.transmitter.transmitted(&self.can)
    }

    /// Withdraws the frames on `id` not yet sent (SC_REQ_18, SC_REQ_23).
    #[cfg(feature = "simplecan")]
    pub fn abort(&mut self, id: shared::CanId) {
        self.transmitter.withdraw(id, &mut self.can);
    }

    /// The next frame of the FIFOs (FIFO 0, the SRDOs, first), or an overrun, which bxcan
    /// reports from CAN_RFxR.FOVR before the frames still in that FIFO.
    pub fn receive(&mut self) -> Option<channel_loop::Received> {
        loop {
            match self.can.receive() {
                Ok(frame) => {
                    // Not CANopen's (extended, length over 8): as if filtered out.
                    if let Some(frame) = from_bxcan(&frame) {
                        return Some(channel_loop::Received::Frame(frame));
                    }
                }
                Err(nb::Error::Other(_)) => return Some(channel_loop::Received::Overrun),
                Err(nb::Error::WouldBlock) => return None,
            }
        }
    }

    /// Programs `layout` into CAN1's filter banks ([`bxcan_adapter::program`]).
    pub fn apply_filters(&mut self, layout: &BankLayout) {
        if let Err(fault) = bxcan_adapter::program(&mut self.can.modify_filters(), layout) {
            defmt::error!("CAN filters refused: {}", fault);
            halt_safe("acceptance filters not programmed");
        }
    }

    /// Waits for a received frame, or for a free mailbox while frames wait for one (with
    /// SimpleCAN also while a sent frame is still to be confirmed).
    pub async fn wait(&mut self) {
        // Completion flags cleared before the mailboxes are filled: a mailbox that frees
        // after this raises the transmit line again. Which frames went out is read from the
        // mailboxes' empty bits, not from these flags.
        self.can.clear_tx_interrupt();
        self.transmitter.fill(&mut self.can);
        if cfg!(feature = "simplecan") && self.transmitter.has_sent(&self.can) {
            // A frame went out since the loop last asked: its confirmation is due now.
            return;
        }
        let completion_awaited = self.transmitter.is_waiting()
            || (cfg!(feature = "simplecan") && self.transmitter.is_pending());
        if !completion_awaited {
            RECEIVED.wait(unmask_receive).await;
        } else {
            embassy_futures::select::select(
                RECEIVED.wait(unmask_receive),
                MAILBOX_FREE.wait(unmask_transmit),
            )
            .await;
        }
    }
}

/// Leaves sleep mode onto the bus, once 11 recessive bits are seen (bxcan also sets
/// automatic bus-off recovery, ABOM).
async fn joined(can: &mut Can<Can1>) {
    while can.enable_non_blocking().is_err() {
        embassy_time::Timer::after_micros(20).await;
    }
}

/// The bxCAN in silent loop-back mode, for [`dual_channel::can_loopback::run`].
struct Loopback<'a> {
    can: &'a mut Can<Can1>,
}

impl LoopbackController for Loopback<'_> {
    fn now(&self) -> Instant {
        now()
    }

    fn queue(&mut self, frame: &CanFrame) -> Option<u8> {
        let frame = to_bxcan(frame)?;
        let status = self.can.transmit(&frame).ok()?;
        Some(status.mailbox() as u8)
    }

    async fn receive(&mut self, until: Instant) -> Received {
        loop {
            match self.can.receive() {
                Ok(frame) => {
                    return match from_bxcan(&frame) {
                        Some(frame) => Received::Frame(frame),
                        None => Received::Unreadable {
                            id: raw_id(&frame),
                            dlc: frame.dlc(),
                        },
                    };
                }
                // A lost frame fails the test as an error of the controller.
                Err(nb::Error::Other(_)) => return Received::BusError,
                Err(nb::Error::WouldBlock) => {
                    let woken = RECEIVED.wait(unmask_receive);
                    if embassy_time::with_deadline(embassy_instant(until), woken)
                        .await
                        .is_err()
                    {
                        return Received::Nothing;
                    }
                }
            }
        }
    }
}

/// CiA 304 9.5: the controller's message buffers and filters, tested in silent loop-back mode
/// before it joins the bus (plan, loop and verdict: [`dual_channel::can_loopback`]). Leaves
/// the controller out of loop-back and asleep, for [`CanPort::start`] to clear its filters
/// and enable it.
async fn loopback_test(
    can: &mut Can<Can1>,
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
    can.modify_filters()
        .clear()
        .enable_bank(0, bxcan::Fifo::Fifo0, listed(ACCEPT_FIFO0))
        .enable_bank(1, bxcan::Fifo::Fifo1, listed(ACCEPT_FIFO1));
    joined(can).await;
    // Each burst takes at most BURST_WAIT (5 ms), well inside the watchdog's time.
    let verdict =
        dual_channel::can_loopback::run(&mut Loopback { can: &mut *can }, || watchdog.pet()).await;
    // Out of loop-back; dropping the configuration proxy leaves initialisation mode.
    drop(can.modify_config().set_loopback(false).set_silent(false));
    verdict
}

/// A received frame's identifier as far as it fits (extended identifiers cut to 16 bits), for
/// the report of a frame that is not CANopen's.
fn raw_id(frame: &Frame) -> u16 {
    match frame.id() {
        Id::Standard(id) => id.as_raw(),
        Id::Extended(id) => id.as_raw() as u16,
    }
}

/// A standard data or remote frame from the bxCAN ([`CanFrame::received`] has the rules).
/// A length code over 8 is refused before the data is touched: bxcan's `Data` would panic
/// on it (its slice is as long as the length code).
fn from_bxcan(frame: &Frame) -> Option<CanFrame> {
    let Id::Standard(id) = frame.id() else {
        return None;
    };
    let dlc = frame.dlc();
    if dlc > 8 {
        return None;
    }
    let mut data = [0u8; 8];
    if let Some(received) = frame.data() {
        data.get_mut(..received.len())?.copy_from_slice(received);
    }
    CanFrame::received(id.as_raw(), frame.is_remote_frame(), dlc, &data)
}

fn to_bxcan(frame: &CanFrame) -> Option<Frame> {
    let id = StandardId::new(frame.id().raw())?;
    if frame.is_remote() {
        // `Frame::new_remote` asserts a length code of at most 8.
        (frame.dlc() <= 8).then(|| Frame::new_remote(id, frame.dlc()))
    } else {
        Some(Frame::new_data(id, Data::new(frame.data())?))
    }
}
