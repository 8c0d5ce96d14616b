//! CAN1 driven on its registers by the board's own code (RM0090 32), and why it is neither
//! embassy-stm32's bxCAN driver nor the `bxcan` crate's: the shipped default
//! (`docs/can-driver.md`).
//!
//! The board needs little of the controller: one bit timing, silent loop-back for the CiA 304
//! 9.5 start-up test with transmit FIFO priority (TXFP) and two 32-bit list banks, then the
//! node's filter banks (16-bit list and mask, from [`dual_channel::filters`]), the three
//! transmit mailboxes behind [`dual_channel::transmit_queue::Transmitter`], both receive FIFOs
//! and their overrun flags, and a wake-up on a received frame or a completed mailbox.
//! embassy-stm32 0.6's driver carries much more (a buffered mode, CAN2, per-mailbox wakers, the
//! error interrupt, a filter API for every mode), and its `transmit`, with all three mailboxes
//! pending, takes the lowest-priority frame back out without comparing it with the new one,
//! so the transmit queue, filling lowest identifier first, could swap two frames in and out
//! for as long as the bus stays busy. The `bxcan` crate has no TXFP and refuses the loop-back
//! plan (`docs/can-driver.md`). What is left is written here from RM0090 32.4 (operating
//! modes), 32.7 (functional description) and 32.9 (registers), and runs on the emulator's
//! model of the controller (`emulator/src/peripherals/bxcan`, written from RM0090).
//!
//! The loop does everything; the interrupts only wake it ([`super::can_wakeup`]).
//! embassy-stm32 still gives the clock, the pins and the interrupt vectors.

use dual_channel::can_loopback::{LoopbackController, LoopbackFault, Received};
use dual_channel::channel_loop::{self, QueueFull};
use dual_channel::filters::{self, Bank, BankLayout};
use dual_channel::transmit_queue::{Controller, Mailbox, Placement, Refusal, Transmitter};
use embassy_stm32::Peri;
use embassy_stm32::can::{RxPin, TxPin};
use embassy_stm32::gpio::{AfType, Flex, OutputType, Pull, Speed};
use embassy_stm32::pac;
use embassy_stm32::peripherals::{CAN1, PB8, PB9};
use shared::{CanFrame, Instant};

use super::can_wakeup::{self, Irqs, MAILBOX_FREE, RECEIVED, unmask_receive, unmask_transmit};
use super::{bit_timing_register, clock, halt_safe, now};

/// Frames waiting for a transmit mailbox, as [`dual_channel::transmit_queue`] orders them.
const TRANSMIT_QUEUE: usize = 16;

/// CAN_TIxR and CAN_RIxR: the standard identifier's place (STID, bits 31:21, RM0090 32.9.3).
const STID_SHIFT: u32 = 21;
/// CAN_TIxR and CAN_RIxR: the extended identifier bit (IDE, bit 2).
const IDE: u32 = 1 << 2;
/// CAN_TIxR and CAN_RIxR: the remote frame bit (RTR, bit 1).
const RTR: u32 = 1 << 1;
/// CAN_TIxR: the transmit request (TXRQ, bit 0).
const TXRQ: u32 = 1;
/// A 16-bit filter entry: STID in bits 15:5, RTR bit 4, IDE bit 3 (RM0090 32.7.4, Figure 342).
const ENTRY16_STID_SHIFT: u32 = 5;
/// A 16-bit filter entry's RTR bit.
const ENTRY16_RTR: u32 = 1 << 4;
/// A 16-bit filter entry's IDE bit.
const ENTRY16_IDE: u32 = 1 << 3;
/// CAN_BTR: loop-back mode (LBKM, bit 30, RM0090 32.9.2).
const BTR_LBKM: u32 = 1 << 30;
/// CAN_BTR: silent mode (SILM, bit 31).
const BTR_SILM: u32 = 1 << 31;
/// The largest standard identifier.
const STID_MAX: u16 = 0x7FF;

/// How often a mode change is polled for ([`mode_reached`]), and how many times: 10 ms in
/// all, longer than any frame the controller may have to finish first (RM0090 32.4.1) and
/// than the 11 recessive bits it needs to join the bus, at any bit rate of CiA 301 down to
/// 10 kbit/s; half the watchdog's time.
const MODE_POLL_US: u64 = 20;
/// See [`MODE_POLL_US`].
const MODE_POLLS: u32 = 500;
/// How many times an abort request is read back before it is given up: it completes at once
/// for a pending frame and at the end of the transmission for one going out (RM0090 32.7.1),
/// a frame's time; these reads take milliseconds at 168 MHz.
const ABORT_POLLS: u32 = 200_000;

/// CAN1 and its two pins, owned for as long as the loop drives them.
pub struct CanPort {
    _peripheral: Peri<'static, CAN1>,
    _rx: Flex<'static>,
    _tx: Flex<'static>,
    mailboxes: Mailboxes,
    transmitter: Transmitter<TRANSMIT_QUEUE>,
    /// [`CanPort::prepare_wait`] armed the wake-up of a completed mailbox.
    completion_awaited: bool,
}

/// CAN1's three transmit mailboxes (RM0090 32.7.1), for the transmit path and the loop-back
/// test.
struct Mailboxes;

impl Controller for Mailboxes {
    /// Takes a frame into an empty mailbox (CAN_TSR.CODE names it) unless a pending one has
    /// the same identifier: the controller serves pending mailboxes by identifier and then by
    /// mailbox number, not in request order (RM0090 32.7.1), so frames of one identifier
    /// must go one at a time to leave in queue order. With all three pending it takes back
    /// the lowest-priority frame (CODE names that one then) when the new frame has a higher
    /// priority, and refuses otherwise; in FIFO order (TXFP, the loop-back test) it refuses.
    fn place(&mut self, frame: &CanFrame) -> Result<Placement, Refusal> {
        let can = pac::CAN1;
        let word = identifier_word(frame);
        let tsr = can.tsr().read();
        for index in 0..3 {
            if !tsr.tme(index) && can.tx(index).tir().read().0 & !TXRQ == word {
                return Err(Refusal::Busy);
            }
        }
        let Some(chosen) = Mailbox::new(tsr.code()) else {
            return Err(Refusal::Busy);
        };
        let index = chosen.index();
        let mut displaced = false;
        if !tsr.tme(index) {
            // All three pending: CODE is the lowest-priority one (RM0090 32.9.3).
            let lowest = can.tx(index).tir().read().0 & !TXRQ;
            if can.mcr().read().txfp() || word >= lowest {
                return Err(Refusal::Busy);
            }
            // Went out meanwhile (`false`): the mailbox is empty and its frame was sent.
            displaced = abort(index);
            if !can.tsr().read().tme(index) {
                return Err(Refusal::Busy);
            }
        }
        let mailbox = can.tx(index);
        let data = frame.raw_data();
        mailbox.tdtr().write(|w| w.set_dlc(frame.dlc()));
        mailbox
            .tdlr()
            .write_value(pac::can::regs::Tdlr(u32::from_le_bytes([
                data[0], data[1], data[2], data[3],
            ])));
        mailbox
            .tdhr()
            .write_value(pac::can::regs::Tdhr(u32::from_le_bytes([
                data[4], data[5], data[6], data[7],
            ])));
        // The identifier last, with TXRQ: the mailbox is pending and write-protected from
        // this write on (RM0090 32.7.1).
        mailbox.tir().write_value(pac::can::regs::Tir(word | TXRQ));
        Ok(Placement {
            mailbox: chosen,
            displaced,
        })
    }

    fn abort(&mut self, mailbox: Mailbox) -> bool {
        // An empty mailbox's TXOK tells of its last frame, not of an abort.
        if pac::CAN1.tsr().read().tme(mailbox.index()) {
            return false;
        }
        abort(mailbox.index())
    }

    fn empty(&self) -> [bool; 3] {
        super::empty_mailboxes()
    }
}

/// Requests the abort of mailbox `index` (CAN_TSR.ABRQx) and waits until the controller
/// clears the request with the mailbox empty: `true` when the frame was taken back (TXOKx
/// clear), `false` when it went out first, or the request did not complete in
/// [`ABORT_POLLS`] reads (the mailbox is then still pending, which the caller reads).
fn abort(index: usize) -> bool {
    let can = pac::CAN1;
    // The request completion bits are written 0: writing 0 leaves them as they are.
    can.tsr().write(|w| w.set_abrq(index, true));
    for _ in 0..ABORT_POLLS {
        let tsr = can.tsr().read();
        if !tsr.abrq(index) {
            return tsr.tme(index) && !tsr.txok(index);
        }
    }
    false
}

/// A standard data or remote frame's CAN_TIxR value without TXRQ: STID, IDE 0, RTR. For
/// standard frames it orders as CAN arbitration does (a lower value wins; a data frame before
/// a remote frame of the same identifier).
fn identifier_word(frame: &CanFrame) -> u32 {
    let remote = if frame.is_remote() { RTR } else { 0 };
    (u32::from(frame.id().raw()) << STID_SHIFT) | remote
}

/// The oldest frame of FIFO 0 (the SRDOs), else of FIFO 1, released from its FIFO (RM0090
/// 32.7.5: read the output mailbox, then RFOM). `Err` with the identifier (an extended one cut
/// to 16 bits) and length code of a frame that is not CANopen's (extended, length over 8);
/// `None` when both FIFOs are empty.
fn take() -> Option<Result<CanFrame, (u16, u8)>> {
    let can = pac::CAN1;
    let fifo = (0..2).find(|&fifo| can.rfr(fifo).read().fmp() != 0)?;
    let mailbox = can.rx(fifo);
    let identifier = mailbox.rir().read().0;
    let dlc = mailbox.rdtr().read().dlc();
    let [d0, d1, d2, d3] = mailbox.rdlr().read().0.to_le_bytes();
    let [d4, d5, d6, d7] = mailbox.rdhr().read().0.to_le_bytes();
    // FULL and FOVR are cleared by writing 1: written 0 here, they stay.
    can.rfr(fifo).write(|w| w.set_rfom(true));
    if identifier & IDE != 0 {
        return Some(Err(((identifier >> 3) as u16, dlc)));
    }
    let id = (identifier >> STID_SHIFT) as u16;
    let data = [d0, d1, d2, d3, d4, d5, d6, d7];
    Some(CanFrame::received(id, identifier & RTR != 0, dlc, &data).ok_or((id, dlc)))
}

/// Whether a receive FIFO overran since the last call (CAN_RFxR.FOVR, cleared here): bxCAN
/// keeps three frames per FIFO and, with RFLM = 0, the newest overwrites the third, so a
/// frame the filters passed was lost (RM0090 32.7.5).
fn overran() -> bool {
    let can = pac::CAN1;
    let mut lost = false;
    for fifo in 0..2 {
        if can.rfr(fifo).read().fovr() {
            can.rfr(fifo).write(|w| w.set_fovr(true));
            lost = true;
        }
    }
    lost
}

/// One filter bank's registers (RM0090 32.7.4, 32.9.4).
struct FilterBank {
    /// Identifier list mode (CAN_FM1R.FBMx = 1), else mask mode.
    list: bool,
    /// 32-bit scale (CAN_FS1R.FSCx = 1), else two 16-bit filters per register.
    wide: bool,
    /// Assigned to FIFO 1 (CAN_FFA1R.FFAx = 1), else FIFO 0.
    fifo1: bool,
    /// CAN_FiR1 and CAN_FiR2.
    words: [u32; 2],
}

/// A 16-bit filter entry for data frames with standard identifier `id`; an identifier over
/// 11 bits (which an acceptance list cannot hold) halts in the safe state.
fn entry16(id: u16) -> u32 {
    if id > STID_MAX {
        halt_safe("CAN filter identifier over 11 bits");
    }
    u32::from(id) << ENTRY16_STID_SHIFT
}

impl FilterBank {
    /// A bank of the node's layout ([`dual_channel::filters`]), data frames only.
    fn of(bank: &Bank, fifo: filters::Fifo) -> FilterBank {
        let pair = |low: u32, high: u32| low | (high << 16);
        let (list, words) = match *bank {
            Bank::List16([a, b, c, d]) => (
                true,
                [pair(entry16(a), entry16(b)), pair(entry16(c), entry16(d))],
            ),
            // The mask also compares RTR (data frames only) and IDE (standard only).
            Bank::Mask16([(a, mask_a), (b, mask_b)]) => (
                false,
                [
                    pair(entry16(a), entry16(mask_a) | ENTRY16_RTR | ENTRY16_IDE),
                    pair(entry16(b), entry16(mask_b) | ENTRY16_RTR | ENTRY16_IDE),
                ],
            ),
        };
        FilterBank {
            list,
            wide: false,
            fifo1: fifo == filters::Fifo::Services,
            words,
        }
    }

    /// A 32-bit list bank for data frames with the standard identifiers `ids`.
    fn listing(ids: [u16; 2], fifo1: bool) -> FilterBank {
        FilterBank {
            list: true,
            wide: true,
            fifo1,
            words: ids.map(|id| u32::from(id & STID_MAX) << STID_SHIFT),
        }
    }
}

/// Programs CAN1's filter banks: `banks` from bank 0 on, the rest of CAN1's banks off (CAN2's,
/// from CAN_FMR.CAN2SB on, reset value 14 kept, left alone). In filter initialisation mode
/// (FINIT), in which the controller receives nothing (RM0090 32.7.4).
fn set_filters(banks: impl Iterator<Item = FilterBank>) {
    let can = pac::CAN1;
    can.fmr().modify(|w| w.set_finit(true));
    can.fa1r()
        .modify(|w| w.0 &= !((1 << filters::CAN1_BANKS) - 1));
    for (index, bank) in banks.take(filters::CAN1_BANKS).enumerate() {
        can.fm1r().modify(|w| w.set_fbm(index, bank.list));
        can.fs1r().modify(|w| w.set_fsc(index, bank.wide));
        can.ffa1r().modify(|w| w.set_ffa(index, bank.fifo1));
        can.fb(index)
            .fr1()
            .write_value(pac::can::regs::Fr1(bank.words[0]));
        can.fb(index)
            .fr2()
            .write_value(pac::can::regs::Fr2(bank.words[1]));
        can.fa1r().modify(|w| w.set_fact(index, true));
    }
    can.fmr().modify(|w| w.set_finit(false));
}

/// Polls CAN_MSR until the controller is in initialisation mode (`initialising`: INAK set)
/// or has left it (INAK clear), and out of sleep (SLAK clear) either way; `false` after
/// [`MODE_POLLS`] polls.
/// How long a bit-rate switch waits for initialisation mode: longer than a frame at the
/// slowest rate LSS may configure, shorter than the watchdog's time-out
/// ([`super::WATCHDOG_TIMEOUT_US`]).
const SWITCH_PATIENCE: shared::Duration = shared::Duration::from_millis(15);

fn mode_reached(initialising: bool) -> bool {
    for _ in 0..MODE_POLLS {
        let msr = pac::CAN1.msr().read();
        if msr.inak() == initialising && !msr.slak() {
            return true;
        }
        clock::delay(shared::Duration::from_micros(MODE_POLL_US));
    }
    false
}

/// Initialisation mode (RM0090 32.4.1: INRQ set, SLEEP cleared; the controller finishes the
/// frame on the bus first): halts in the safe state when it is not reached.
fn initialise() {
    pac::CAN1.mcr().modify(|w| {
        w.set_sleep(false);
        w.set_inrq(true);
    });
    if !mode_reached(true) {
        halt_safe("CAN controller did not enter initialisation mode");
    }
}

/// Normal mode (RM0090 32.4.2: INRQ cleared; the controller joins once it has seen 11
/// recessive bits): halts in the safe state when it does not.
fn join() {
    pac::CAN1.mcr().modify(|w| w.set_inrq(false));
    if !mode_reached(false) {
        halt_safe("CAN controller did not synchronise on the bus");
    }
}

impl CanPort {
    /// Brings CAN1 up at `timing`: pins and clock, the CiA 304 9.5 loop-back test, then on
    /// the bus with no filter bank enabled (the channel loop programs the node's before the
    /// core boots).
    pub fn start(
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

        let registers = pac::CAN1;
        initialise();
        // RM0090 32.9.2: automatic bus-off recovery (ABOM), automatic retransmission (NART
        // 0), a full FIFO keeps overwriting its newest frame (RFLM 0, an overrun is read from
        // FOVR), no automatic wake-up, no time-triggered mode; TXFP for the loop-back test.
        registers.mcr().modify(|w| {
            w.set_abom(true);
            w.set_nart(false);
            w.set_rflm(false);
            w.set_awum(false);
            w.set_ttcm(false);
            w.set_txfp(true);
        });
        registers
            .btr()
            .write_value(pac::can::regs::Btr(btr | BTR_LBKM | BTR_SILM));
        registers.ier().write(|w| {
            w.set_fmpie(0, true);
            w.set_fmpie(1, true);
            w.set_tmeie(true);
        });
        match loopback_test(watchdog) {
            Ok(()) => {
                defmt::info!("self-test: CAN loop-back (3 mailboxes, 2 FIFOs, filters) passed")
            }
            Err(fault) => {
                defmt::error!("self-test: CAN loop-back failed {}", fault);
                halt_safe("CAN controller self-test failed");
            }
        }
        watchdog.pet();
        initialise();
        registers.mcr().modify(|w| w.set_txfp(false));
        registers.btr().write_value(pac::can::regs::Btr(btr));
        // No filter bank enabled: the controller takes no frame until the channel loop has
        // programmed the node's filters (its first service, before the core boots).
        set_filters(core::iter::empty());
        join();
        CanPort {
            _peripheral: can,
            _rx: rx,
            _tx: tx,
            mailboxes: Mailboxes,
            transmitter: Transmitter::new(),
            completion_awaited: false,
        }
    }

    /// Switches the controller to `timing` (CiA 305 activate bit timing, in the node's
    /// silence after the first switch delay). RM0090 32.9.2: BTR is written in initialisation
    /// mode, which 32.4.1 enters once the frame on the bus has ended; 32.4.2: normal mode is
    /// taken up again after 11 recessive bits at the new rate, which the loop does not wait
    /// for (the node stays silent for the second switch delay). Frames in the mailboxes and
    /// FIFOs are kept. Halts in the safe state when the controller does not enter
    /// initialisation mode within [`SWITCH_PATIENCE`]: the node could then be on neither rate.
    pub fn switch_bit_rate(&mut self, timing: embassy_stm32::can::util::NominalBitTiming) {
        let Ok(btr) = bit_timing_register(timing) else {
            halt_safe("CAN bit timing outside the bxCAN's fields");
        };
        let registers = pac::CAN1;
        registers.mcr().modify(|w| {
            w.set_sleep(false);
            w.set_inrq(true);
        });
        let give_up = now() + SWITCH_PATIENCE;
        while !registers.msr().read().inak() {
            if now() >= give_up {
                halt_safe("CAN controller did not enter initialisation mode to switch bit rate");
            }
        }
        registers.btr().write_value(pac::can::regs::Btr(btr));
        registers.mcr().modify(|w| w.set_inrq(false));
    }

    /// Queues `frame` and fills the mailboxes from the queue.
    pub fn transmit(&mut self, frame: &CanFrame) -> Result<(), QueueFull> {
        self.transmitter.transmit(frame, &mut self.mailboxes)
    }

    /// The oldest frame confirmed as sent since the last call (SC_REQ_18, SC_REQ_23).
    #[cfg(feature = "simplecan")]
    pub fn transmitted(&mut self) -> Option<CanFrame> {
        self.transmitter.transmitted(&self.mailboxes)
    }

    /// Withdraws the frames on `id` not yet sent (SC_REQ_18, SC_REQ_23).
    #[cfg(feature = "simplecan")]
    pub fn abort(&mut self, id: shared::CanId) {
        self.transmitter.withdraw(id, &mut self.mailboxes);
    }

    /// The next frame of the FIFOs (FIFO 0, the SRDOs, first), or their overrun, which comes
    /// before the frames still in them.
    pub fn receive(&mut self) -> Option<channel_loop::Received> {
        if overran() {
            return Some(channel_loop::Received::Overrun);
        }
        loop {
            // Not CANopen's (extended, length over 8): as if filtered out.
            if let Ok(frame) = take()? {
                return Some(channel_loop::Received::Frame(frame));
            }
        }
    }

    /// Programs `layout` into CAN1's filter banks.
    pub fn apply_filters(&mut self, layout: &BankLayout) {
        set_filters(
            layout
                .banks
                .iter()
                .map(|(bank, fifo)| FilterBank::of(bank, *fifo)),
        );
    }

    /// Prepares the loop's sleep: fills the mailboxes from the queue and arms the wake-ups of
    /// a received frame and, while frames wait for a mailbox (with SimpleCAN also while a
    /// sent frame is still to be confirmed), of a completed mailbox. `false` when the loop
    /// must not sleep at all (with SimpleCAN: a frame went out since the loop last asked, and
    /// its confirmation is due now). The sleep ends when [`CanPort::woken`].
    pub fn prepare_wait(&mut self) -> bool {
        // The request completion flags (RQCPx, which raise the transmit line with TMEIE)
        // cleared before the mailboxes are filled: a mailbox that completes after this raises
        // it again. Which frames went out is read from the mailboxes' empty bits, not from
        // these flags.
        pac::CAN1.tsr().write(|w| {
            for index in 0..3 {
                w.set_rqcp(index, true);
            }
        });
        self.transmitter.fill(&mut self.mailboxes);
        if cfg!(feature = "simplecan") && self.transmitter.has_sent(&self.mailboxes) {
            return false;
        }
        self.completion_awaited = self.transmitter.is_waiting()
            || (cfg!(feature = "simplecan") && self.transmitter.is_pending());
        RECEIVED.arm(unmask_receive);
        if self.completion_awaited {
            MAILBOX_FREE.arm(unmask_transmit);
        }
        true
    }

    /// Whether what [`CanPort::prepare_wait`] armed has fired: a frame was received, or a
    /// mailbox completed while one was awaited.
    pub fn woken(&self) -> bool {
        RECEIVED.fired() || (self.completion_awaited && MAILBOX_FREE.fired())
    }
}

/// The bxCAN in silent loop-back mode, for [`dual_channel::can_loopback::run`].
struct Loopback;

impl LoopbackController for Loopback {
    fn now(&self) -> Instant {
        now()
    }

    fn queue(&mut self, frame: &CanFrame) -> Option<u8> {
        let placement = Mailboxes.place(frame).ok()?;
        Some(placement.mailbox.index() as u8)
    }

    fn receive(&mut self, until: Instant) -> Received {
        loop {
            // A lost frame fails the test as an error of the controller.
            if overran() {
                return Received::BusError;
            }
            match take() {
                Some(Ok(frame)) => return Received::Frame(frame),
                Some(Err((id, dlc))) => return Received::Unreadable { id, dlc },
                // Polled, not slept on: the test runs before the loop, and each of its bursts
                // ends within a few milliseconds.
                None if clock::due(until) => return Received::Nothing,
                None => {}
            }
        }
    }
}

/// CiA 304 9.5: the controller's message buffers and filters, tested in silent loop-back mode
/// before it joins the bus (plan, loop and verdict: [`dual_channel::can_loopback`]), on a
/// controller in initialisation mode with loop-back, silent mode and TXFP set. Leaves it in
/// loop-back, for [`CanPort::start`] to take it out.
fn loopback_test(watchdog: &mut super::Watchdog) -> Result<(), LoopbackFault> {
    use dual_channel::can_loopback::{ACCEPT_FIFO0, ACCEPT_FIFO1};
    set_filters(
        [
            FilterBank::listing(ACCEPT_FIFO0, false),
            FilterBank::listing(ACCEPT_FIFO1, true),
        ]
        .into_iter(),
    );
    join();
    // Each burst takes at most BURST_WAIT (5 ms), well inside the watchdog's time.
    dual_channel::can_loopback::run(&mut Loopback, || watchdog.pet())
}
