//! bxCAN1 of the STM32F405 (RM0090 32): operating modes, three transmit mailboxes, two
//! receive FIFOs of three, 28 filter banks, test modes, error confinement, bus-off recovery
//! and the four interrupt lines, talking to a bus model through [`Can::offer`] and friends.
//!
//! What is modelled, with the RM0090 clause each part follows:
//! - 32.4: sleep after reset, initialization on INRQ (INAK), sleep on SLEEP (SLAK, SLAKI),
//!   leaving either only after 11 recessive bits (synchronisation; the model assumes an idle
//!   bus), wake-up on bus activity (WKUI, with AWUM clearing SLEEP by itself); a mode request
//!   made during a transmission waits for its end.
//! - 32.5: silent mode (receives, never starts a transmission), loop-back mode (own frames
//!   are received through the filters, CAN_RX is ignored) and both combined. In loop-back
//!   the model times its own frames from BTR and does not put them on the bus model (the
//!   frames a plain loop-back drives on CAN_TX are not modelled).
//! - 32.7.1: mailboxes pending by TXRQ, served by identifier (lowest first, then lowest
//!   mailbox) or by request order with TXFP; abort by ABRQ (at once when pending, at the end
//!   of the transmission otherwise); automatic retransmission unless NART; RQCP/TXOK/ALST/
//!   TERR, TME, CODE and LOW.
//! - 32.7.3: FIFOs of three messages, FMP, FULL, FOVR, release by RFOM, overrun overwriting
//!   the last message (RFLM = 0) or dropping the new one (RFLM = 1).
//! - 32.7.4: filters in `filters` (all four scale/mode combinations, FIFO assignment, FMI).
//! - 32.7.6: TEC and REC by the ISO 11898-1 rules the bus reports (transmit error +8, success
//!   -1, receive error +1, success -1 or back to 119 from above 127; no TEC change for an ACK
//!   error while error passive), EWGF (96), EPVF (above 127), bus-off above 255, recovery
//!   after 128 occurrences of 11 recessive bits (idle bus assumed), automatically with ABOM,
//!   else after software set and cleared INRQ.
//! - 32.7.7: the bit time from BTR (BRP, TS1, TS2) and PCLK1.
//! - 32.8: the TX (19), RX0 (20), RX1 (21) and SCE (22) lines of RM0090 Table 61, ERRI set
//!   when an error sets an enabled CAN_ESR condition.
//!
//! Not modelled: time-triggered communication (TTCM is stored, TIME fields read 0, TGT is
//! not sent), the sample point and resynchronisation (SJW is stored), CAN2, RXM (a
//! reception is instantaneous) and the actual bus level (MSR.SAMP and MSR.RX read as an
//! idle, recessive bus), debug freeze (DBF is stored). Registers are word-accessed only
//! (RM0090 32.9: "accessed by words"); other widths are refused.
//!
//! The bus side: a bus model asks [`Can::offer`] which frame the controller would send,
//! starts it with [`Can::start_transmission`], and reports the outcome with
//! [`Can::transmitted`], [`Can::lost_arbitration`] or [`Can::error`]; it hands every frame
//! it carries to the other controllers with [`Can::deliver`] and receive-side errors with
//! [`Can::receive_error`], timing frames with [`Can::frame_duration`].

mod filters;
mod frame;
#[cfg(test)]
mod tests;

pub use filters::{BANKS, FilterBanks, FilterMatch, image_16, image_32};
pub use frame::{Frame, INTERMISSION_BITS, Identifier, crc15};

use super::{AccessError, Context, Peripheral};
use crate::time::{Clocks, Nanos};

/// The CAN1 block's base address (RM0090 2.3, memory map).
pub const BASE: u32 = 0x4000_6400;
/// The CAN1 block's size.
pub const SIZE: u32 = 0x400;
/// CAN1 TX interrupt (RM0090 Table 61).
pub const IRQ_TX: u32 = 19;
/// CAN1 RX0 interrupt (RM0090 Table 61).
pub const IRQ_RX0: u32 = 20;
/// CAN1 RX1 interrupt (RM0090 Table 61).
pub const IRQ_RX1: u32 = 21;
/// CAN1 SCE (status change and error) interrupt (RM0090 Table 61).
pub const IRQ_SCE: u32 = 22;

const NAME: &str = "CAN1 (RM0090 32)";
const LINES: [u32; 4] = [IRQ_TX, IRQ_RX0, IRQ_RX1, IRQ_SCE];

/// Recessive bits the controller needs to see to synchronise on the bus (RM0090 32.4.1).
const SYNCHRONISATION_BITS: u64 = 11;
/// Occurrences of 11 recessive bits that end bus-off (RM0090 32.7.6).
const RECOVERY_OCCURRENCES: u64 = 128;

/// CAN_MCR bits (RM0090 32.9.2).
mod mcr {
    pub const INRQ: u32 = 1 << 0;
    pub const SLEEP: u32 = 1 << 1;
    pub const TXFP: u32 = 1 << 2;
    pub const RFLM: u32 = 1 << 3;
    pub const NART: u32 = 1 << 4;
    pub const AWUM: u32 = 1 << 5;
    pub const ABOM: u32 = 1 << 6;
    pub const TTCM: u32 = 1 << 7;
    pub const RESET: u32 = 1 << 15;
    pub const DBF: u32 = 1 << 16;
    /// The configuration bits stored as written.
    pub const CONFIGURATION: u32 = TXFP | RFLM | NART | AWUM | ABOM | TTCM | DBF;
}

/// CAN_IER bits (RM0090 32.9.2).
mod ier {
    pub const TMEIE: u32 = 1 << 0;
    pub const FMPIE0: u32 = 1 << 1;
    pub const FFIE0: u32 = 1 << 2;
    pub const FOVIE0: u32 = 1 << 3;
    pub const EWGIE: u32 = 1 << 8;
    pub const EPVIE: u32 = 1 << 9;
    pub const BOFIE: u32 = 1 << 10;
    pub const LECIE: u32 = 1 << 11;
    pub const ERRIE: u32 = 1 << 15;
    pub const WKUIE: u32 = 1 << 16;
    pub const SLKIE: u32 = 1 << 17;
    /// Every bit the register implements.
    pub const ALL: u32 = 0x7F | 0xF00 | ERRIE | WKUIE | SLKIE;
}

/// CAN_BTR bits (RM0090 32.9.2).
mod btr {
    pub const LBKM: u32 = 1 << 30;
    pub const SILM: u32 = 1 << 31;
    /// BRP, TS1, TS2, SJW, LBKM, SILM.
    pub const ALL: u32 = 0x3FF | (0xF << 16) | (0x7 << 20) | (0x3 << 24) | LBKM | SILM;
    /// The value after reset.
    pub const RESET: u32 = 0x0123_0000;
}

/// A bus error as CAN_ESR.LEC codes it (RM0090 32.9.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BusError {
    /// Stuff error (LEC 001).
    Stuff = 1,
    /// Form error (LEC 010).
    Form = 2,
    /// Acknowledgment error: no dominant bit in the ACK slot (LEC 011).
    Acknowledgment = 3,
    /// Bit recessive error: sent recessive, read dominant (LEC 100).
    BitRecessive = 4,
    /// Bit dominant error: sent dominant, read recessive (LEC 101).
    BitDominant = 5,
    /// CRC error (LEC 110).
    Crc = 6,
}

/// The controller's operating mode (RM0090 32.4, "bxCAN operating modes" figure).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Sleep mode (SLAK = 1): after reset, or on SLEEP.
    Sleep,
    /// Initialization mode (INAK = 1): on INRQ; BTR is writable.
    Initialization,
    /// Normal mode: synchronised on the bus, transmitting and receiving.
    Normal,
}

/// Where a transmit mailbox stands (RM0090 32.7.1, "Transmit mailbox states" figure).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum MailboxState {
    /// TME = 1: free for software.
    Empty,
    /// Requested (pending or scheduled): waiting for the bus.
    Pending,
    /// On the bus now.
    Transmitting,
}

/// The result of one transmission attempt.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Outcome {
    Success,
    ArbitrationLost,
    Error(BusError),
}

#[derive(Clone, Copy, Debug)]
struct Mailbox {
    /// CAN_TIxR without TXRQ: STID, EXID, IDE, RTR.
    identifier: u32,
    /// CAN_TDTxR: DLC and TGT (TIME is not modelled).
    timing: u32,
    /// CAN_TDLxR.
    low: u32,
    /// CAN_TDHxR.
    high: u32,
    state: MailboxState,
    /// ABRQ set while the mailbox was on the bus: empty it at the end of the attempt.
    abort: bool,
    /// Request sequence number (TXFP order).
    order: u64,
    request_completed: bool,
    transmit_ok: bool,
    arbitration_lost: bool,
    transmit_error: bool,
}

impl Mailbox {
    const EMPTY: Mailbox = Mailbox {
        identifier: 0,
        timing: 0,
        low: 0,
        high: 0,
        state: MailboxState::Empty,
        abort: false,
        order: 0,
        request_completed: false,
        transmit_ok: false,
        arbitration_lost: false,
        transmit_error: false,
    };

    fn frame(&self) -> Frame {
        let stid = self.identifier >> 21;
        let extended = self.identifier & (1 << 2) != 0;
        let id = if extended {
            Identifier::Extended((stid << 18) | ((self.identifier >> 3) & 0x3_FFFF))
        } else {
            Identifier::Standard(stid as u16)
        };
        let mut data = [0; 8];
        data[..4].copy_from_slice(&self.low.to_le_bytes());
        data[4..].copy_from_slice(&self.high.to_le_bytes());
        Frame {
            id,
            remote: self.identifier & (1 << 1) != 0,
            dlc: (self.timing & 0xF) as u8,
            data,
        }
    }
}

/// One receive FIFO: three mailboxes, the output one at `head`.
#[derive(Clone, Copy, Debug)]
struct ReceiveFifo {
    /// CAN_RIxR, CAN_RDTxR, CAN_RDLxR, CAN_RDHxR of each mailbox.
    slots: [[u32; 4]; 3],
    head: usize,
    count: usize,
    full: bool,
    overrun: bool,
}

impl ReceiveFifo {
    const EMPTY: ReceiveFifo = ReceiveFifo {
        slots: [[0; 4]; 3],
        head: 0,
        count: 0,
        full: false,
        overrun: false,
    };
}

/// A frame the controller sends to itself in loop-back mode.
#[derive(Clone, Copy, Debug)]
struct LoopbackTransfer {
    mailbox: usize,
    end: Nanos,
}

/// The bxCAN1 model.
#[derive(Clone, Debug)]
pub struct Can {
    init_request: bool,
    sleep_request: bool,
    /// CAN_MCR configuration bits.
    configuration: u32,
    mode: Mode,
    /// Leaving sleep or initialization: normal mode once the bus is seen idle, at this time.
    synchronised_at: Option<Nanos>,
    error_interrupt: bool,
    wakeup_interrupt: bool,
    sleep_interrupt: bool,
    mailboxes: [Mailbox; 3],
    next_order: u64,
    fifos: [ReceiveFifo; 2],
    interrupt_enable: u32,
    transmit_errors: u16,
    receive_errors: u16,
    last_error: u8,
    bus_off: bool,
    /// INRQ set (initialization entered) since bus-off: the software's recovery request.
    bus_off_initialization_cycled: bool,
    /// Since when the controller counts recessive bits towards bus-off recovery.
    recovery_from: Option<Nanos>,
    bit_timing: u32,
    filters: FilterBanks,
    clocks: Clocks,
    now: Nanos,
    loopback: Option<LoopbackTransfer>,
    loopback_free_at: Nanos,
}

impl Default for Can {
    fn default() -> Self {
        Self::new()
    }
}

impl Can {
    /// The controller after reset: sleep mode, mailboxes empty, FIFOs empty, filters in
    /// initialization mode (RM0090 32.4: "after reset the bxCAN is in sleep mode").
    pub fn new() -> Can {
        Can {
            init_request: false,
            sleep_request: true,
            configuration: mcr::DBF,
            mode: Mode::Sleep,
            synchronised_at: None,
            error_interrupt: false,
            wakeup_interrupt: false,
            sleep_interrupt: false,
            mailboxes: [Mailbox::EMPTY; 3],
            next_order: 0,
            fifos: [ReceiveFifo::EMPTY; 2],
            interrupt_enable: 0,
            transmit_errors: 0,
            receive_errors: 0,
            last_error: 0,
            bus_off: false,
            bus_off_initialization_cycled: false,
            recovery_from: None,
            bit_timing: btr::RESET,
            filters: FilterBanks::new(),
            clocks: Clocks::RESET,
            now: 0,
            loopback: None,
            loopback_free_at: 0,
        }
    }

    /// The operating mode now (INAK and SLAK as read).
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// The filter banks (read-only view for a test or a trace).
    pub fn filters(&self) -> &FilterBanks {
        &self.filters
    }

    /// The transmit error counter (ISO 11898-1 TEC; above 255 in bus-off).
    pub fn transmit_error_counter(&self) -> u16 {
        self.transmit_errors
    }

    /// The receive error counter (ISO 11898-1 REC).
    pub fn receive_error_counter(&self) -> u16 {
        self.receive_errors
    }

    /// Whether the controller is bus-off (CAN_ESR.BOFF).
    pub fn is_bus_off(&self) -> bool {
        self.bus_off
    }

    /// PCLK1 cycles of one bit: tq = (BRP + 1) PCLK1 cycles, a bit is 1 + (TS1 + 1) +
    /// (TS2 + 1) tq (RM0090 32.7.7, "Bit timing").
    pub fn bit_time_cycles(&self) -> u64 {
        let prescaler = u64::from(self.bit_timing & 0x3FF) + 1;
        let segment1 = u64::from((self.bit_timing >> 16) & 0xF) + 1;
        let segment2 = u64::from((self.bit_timing >> 20) & 0x7) + 1;
        prescaler * (1 + segment1 + segment2)
    }

    /// The duration of `bits` bits at this controller's bit rate and PCLK1.
    pub fn bits_duration(&self, bits: u64) -> Nanos {
        Clocks::nanos(bits * self.bit_time_cycles(), self.clocks.pclk1)
    }

    /// The duration of a frame on the bus at this controller's bit rate, SOF to EOF.
    pub fn frame_duration(&self, frame: &Frame) -> Nanos {
        self.bits_duration(u64::from(frame.bit_length()))
    }

    fn loop_back(&self) -> bool {
        self.bit_timing & btr::LBKM != 0
    }

    fn silent(&self) -> bool {
        self.bit_timing & btr::SILM != 0
    }

    fn error_warning(&self) -> bool {
        self.transmit_errors >= 96 || self.receive_errors >= 96
    }

    fn error_passive(&self) -> bool {
        self.transmit_errors > 127 || self.receive_errors > 127
    }

    /// The non-empty mailboxes, the next one to send first: by identifier (arbitration
    /// order, then the lower mailbox number) or, with TXFP, by request order.
    fn priority_order(&self) -> Vec<usize> {
        let mut order: Vec<usize> = (0..3)
            .filter(|&index| self.mailboxes[index].state != MailboxState::Empty)
            .collect();
        if self.configuration & mcr::TXFP != 0 {
            order.sort_by_key(|&index| self.mailboxes[index].order);
        } else {
            order.sort_by_key(|&index| (self.mailboxes[index].frame().arbitration_key(), index));
        }
        order
    }

    fn transmitting(&self) -> Option<usize> {
        (0..3).find(|&index| self.mailboxes[index].state == MailboxState::Transmitting)
    }

    /// How many transmit requests the mailboxes have taken since reset (TXRQ set in an
    /// empty mailbox, RM0090 32.7.1): a bus model compares it around an access to see a
    /// request at the instant it is made.
    pub fn transmit_requests(&self) -> u64 {
        self.next_order
    }

    /// The frame the controller would start on the bus now: its highest-priority pending
    /// mailbox, in normal mode, not bus-off, not silent, not in loop-back, and not already
    /// transmitting.
    pub fn offer(&self) -> Option<Frame> {
        self.next_for_bus()
            .map(|index| self.mailboxes[index].frame())
    }

    fn next_for_bus(&self) -> Option<usize> {
        if self.mode != Mode::Normal
            || self.bus_off
            || self.silent()
            || self.loop_back()
            || self.transmitting().is_some()
        {
            return None;
        }
        self.next_pending()
    }

    fn next_pending(&self) -> Option<usize> {
        self.priority_order()
            .into_iter()
            .find(|&index| self.mailboxes[index].state == MailboxState::Pending)
    }

    /// The bus starts the offered frame at `at` (its SOF): the mailbox is in transmission
    /// until the bus reports the outcome. Returns the frame, `None` when nothing is offered.
    pub fn start_transmission(&mut self, at: Nanos) -> Option<Frame> {
        self.now = self.now.max(at);
        let index = self.next_for_bus()?;
        self.mailboxes[index].state = MailboxState::Transmitting;
        Some(self.mailboxes[index].frame())
    }

    /// The frame in transmission was sent and acknowledged, ending at `at`.
    pub fn transmitted(&mut self, at: Nanos) {
        self.now = self.now.max(at);
        if let Some(index) = self.transmitting() {
            self.conclude(index, Outcome::Success, at);
        }
    }

    /// The frame in transmission lost arbitration at `at`.
    pub fn lost_arbitration(&mut self, at: Nanos) {
        self.now = self.now.max(at);
        if let Some(index) = self.transmitting() {
            self.conclude(index, Outcome::ArbitrationLost, at);
        }
    }

    /// The frame in transmission ended with a bus error at `at`.
    pub fn error(&mut self, kind: BusError, at: Nanos) {
        self.now = self.now.max(at);
        if let Some(index) = self.transmitting() {
            self.conclude(index, Outcome::Error(kind), at);
        }
    }

    /// The controller detected an error while receiving a frame at `at` (REC + 1, LEC).
    pub fn receive_error(&mut self, kind: BusError, at: Nanos) {
        self.now = self.now.max(at);
        if self.mode != Mode::Normal || self.bus_off || self.loop_back() {
            return;
        }
        self.receive_errors = (self.receive_errors + 1).min(255);
        self.last_error = kind as u8;
        self.error_event();
    }

    /// A frame on the bus, ending at `at`, that this controller did not send. In sleep mode
    /// it is bus activity (WKUI, and wake-up with AWUM) and is not received; in normal mode
    /// (not loop-back, not bus-off) it goes through the filters into a FIFO.
    pub fn deliver(&mut self, frame: &Frame, at: Nanos) {
        self.now = self.now.max(at);
        match self.mode {
            Mode::Sleep => {
                self.wakeup_interrupt = true;
                if self.configuration & mcr::AWUM != 0 {
                    self.sleep_request = false;
                    self.settle();
                }
                return;
            }
            Mode::Initialization => return,
            Mode::Normal => {}
        }
        if self.loop_back() || self.bus_off {
            return;
        }
        self.receive(frame);
    }

    /// A frame received without error: REC, LEC, filters and FIFO.
    fn receive(&mut self, frame: &Frame) {
        if self.receive_errors > 127 {
            self.receive_errors = 119;
        } else if self.receive_errors > 0 {
            self.receive_errors -= 1;
        }
        self.last_error = 0;
        let Some(accepted) = self.filters.accept(frame) else {
            return;
        };
        let identifier = image_32(frame);
        let timing = u32::from(frame.dlc & 0xF) | (u32::from(accepted.index) << 8);
        let mut bytes = [0u8; 8];
        bytes[..frame.data_len()].copy_from_slice(&frame.data[..frame.data_len()]);
        let low = u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
        let high = u32::from_le_bytes([bytes[4], bytes[5], bytes[6], bytes[7]]);
        let slot = [identifier, timing, low, high];
        let locked = self.configuration & mcr::RFLM != 0;
        let fifo = &mut self.fifos[accepted.fifo];
        if fifo.count < 3 {
            fifo.slots[(fifo.head + fifo.count) % 3] = slot;
            fifo.count += 1;
            if fifo.count == 3 {
                fifo.full = true;
            }
        } else {
            fifo.overrun = true;
            if !locked {
                fifo.slots[(fifo.head + 2) % 3] = slot;
            }
        }
    }

    fn conclude(&mut self, index: usize, outcome: Outcome, at: Nanos) {
        let one_shot = self.configuration & mcr::NART != 0;
        let passive = self.error_passive();
        let mailbox = &mut self.mailboxes[index];
        let done = match outcome {
            Outcome::Success => {
                mailbox.transmit_ok = true;
                true
            }
            Outcome::ArbitrationLost => {
                mailbox.transmit_ok = false;
                mailbox.arbitration_lost = true;
                one_shot || mailbox.abort
            }
            Outcome::Error(_) => {
                mailbox.transmit_ok = false;
                mailbox.transmit_error = true;
                one_shot || mailbox.abort
            }
        };
        if done {
            mailbox.state = MailboxState::Empty;
            mailbox.request_completed = true;
            mailbox.abort = false;
        } else {
            mailbox.state = MailboxState::Pending;
        }
        match outcome {
            Outcome::Success => {
                self.transmit_errors = self.transmit_errors.saturating_sub(1);
                self.last_error = 0;
            }
            Outcome::ArbitrationLost => {}
            Outcome::Error(kind) => {
                // ISO 11898-1 fault confinement: +8 for a transmitter, except an ACK error
                // of an error-passive transmitter.
                if !(kind == BusError::Acknowledgment && passive) {
                    self.transmit_errors += 8;
                }
                self.last_error = kind as u8;
                if self.transmit_errors > 255 && !self.bus_off {
                    self.bus_off = true;
                    self.bus_off_initialization_cycled = false;
                    self.recovery_from = (self.configuration & mcr::ABOM != 0).then_some(at);
                }
                self.error_event();
            }
        }
        self.settle();
    }

    /// ERRI: set when an error set a CAN_ESR condition whose interrupt is enabled.
    fn error_event(&mut self) {
        let enabled = self.interrupt_enable;
        if (self.error_warning() && enabled & ier::EWGIE != 0)
            || (self.error_passive() && enabled & ier::EPVIE != 0)
            || (self.bus_off && enabled & ier::BOFIE != 0)
            || (self.last_error != 0 && enabled & ier::LECIE != 0)
        {
            self.error_interrupt = true;
        }
    }

    /// Moves towards the mode INRQ and SLEEP ask for (RM0090 32.4 figure): entering sleep or
    /// initialization waits for the end of a transmission; leaving them waits for 11
    /// recessive bits.
    fn settle(&mut self) {
        let target = match (self.init_request, self.sleep_request) {
            (true, false) => Mode::Initialization,
            (false, true) => Mode::Sleep,
            (false, false) => Mode::Normal,
            (true, true) => {
                self.synchronised_at = None;
                return;
            }
        };
        if target == self.mode {
            self.synchronised_at = None;
            return;
        }
        match target {
            Mode::Initialization | Mode::Sleep => {
                self.synchronised_at = None;
                if self.transmitting().is_some() || self.loopback.is_some() {
                    return;
                }
                if self.mode == Mode::Sleep {
                    self.sleep_interrupt = false;
                }
                self.mode = target;
                self.recovery_from = None;
                if target == Mode::Sleep {
                    self.sleep_interrupt = true;
                }
                if target == Mode::Initialization && self.bus_off {
                    self.bus_off_initialization_cycled = true;
                }
            }
            Mode::Normal => {
                if self.synchronised_at.is_none() {
                    self.synchronised_at =
                        Some(self.now + self.bits_duration(SYNCHRONISATION_BITS));
                }
            }
        }
    }

    /// In loop-back mode, starts the next pending mailbox at `at` (or when the previous
    /// loop-back frame and its intermission are over).
    fn loopback_start(&mut self, at: Nanos) {
        if !self.loop_back()
            || self.mode != Mode::Normal
            || self.bus_off
            || self.loopback.is_some()
            || self.init_request
            || self.sleep_request
        {
            return;
        }
        let Some(index) = self.next_pending() else {
            return;
        };
        let start = at.max(self.loopback_free_at);
        let frame = self.mailboxes[index].frame();
        self.mailboxes[index].state = MailboxState::Transmitting;
        self.loopback = Some(LoopbackTransfer {
            mailbox: index,
            end: start + self.frame_duration(&frame),
        });
    }

    fn recovery_at(&self) -> Option<Nanos> {
        self.recovery_from
            .map(|from| from + self.bits_duration(RECOVERY_OCCURRENCES * SYNCHRONISATION_BITS))
    }

    /// The earliest thing the model does by itself.
    fn next_due(&self) -> Option<Nanos> {
        [
            self.synchronised_at,
            self.loopback.map(|transfer| transfer.end),
            self.recovery_at(),
        ]
        .into_iter()
        .flatten()
        .min()
    }

    fn run_until(&mut self, now: Nanos) {
        while let Some(due) = self.next_due() {
            if due > now {
                break;
            }
            self.now = self.now.max(due);
            if self.synchronised_at == Some(due) {
                self.synchronised_at = None;
                if self.mode == Mode::Sleep {
                    self.sleep_interrupt = false;
                }
                self.mode = Mode::Normal;
                if self.bus_off
                    && (self.configuration & mcr::ABOM != 0 || self.bus_off_initialization_cycled)
                {
                    self.recovery_from = Some(due);
                }
                self.loopback_start(due);
            } else if let Some(transfer) = self.loopback.filter(|transfer| transfer.end == due) {
                self.loopback = None;
                self.loopback_free_at = due + self.bits_duration(u64::from(INTERMISSION_BITS));
                let frame = self.mailboxes[transfer.mailbox].frame();
                self.conclude(transfer.mailbox, Outcome::Success, due);
                self.receive(&frame);
                self.loopback_start(due);
            } else if self.recovery_at() == Some(due) {
                self.recovery_from = None;
                self.bus_off = false;
                self.bus_off_initialization_cycled = false;
                self.transmit_errors = 0;
                self.receive_errors = 0;
                self.loopback_start(due);
            }
        }
        self.now = self.now.max(now);
    }

    fn sync(&mut self, ctx: &Context) {
        self.clocks = ctx.clocks;
        self.run_until(ctx.now);
    }

    fn read_mcr(&self) -> u32 {
        self.configuration | u32::from(self.init_request) | (u32::from(self.sleep_request) << 1)
    }

    fn read_msr(&self) -> u32 {
        u32::from(self.mode == Mode::Initialization)
            | (u32::from(self.mode == Mode::Sleep) << 1)
            | (u32::from(self.error_interrupt) << 2)
            | (u32::from(self.wakeup_interrupt) << 3)
            | (u32::from(self.sleep_interrupt) << 4)
            | (u32::from(self.transmitting().is_some() || self.loopback.is_some()) << 8)
            // SAMP and RX: an idle, recessive bus.
            | (1 << 10)
            | (1 << 11)
    }

    fn read_tsr(&self) -> u32 {
        let mut value = 0;
        for (index, mailbox) in self.mailboxes.iter().enumerate() {
            let shift = 8 * index;
            value |= (u32::from(mailbox.request_completed)
                | (u32::from(mailbox.transmit_ok) << 1)
                | (u32::from(mailbox.arbitration_lost) << 2)
                | (u32::from(mailbox.transmit_error) << 3)
                | (u32::from(mailbox.abort) << 7))
                << shift;
            if mailbox.state == MailboxState::Empty {
                value |= 1 << (26 + index);
            }
        }
        let order = self.priority_order();
        let code = match (0..3).find(|&index| self.mailboxes[index].state == MailboxState::Empty) {
            Some(free) => free,
            None => order[2],
        };
        value |= (code as u32) << 24;
        if order.len() > 1 {
            value |= 1 << (29 + order[order.len() - 1]);
        }
        value
    }

    fn read_rfr(&self, fifo: usize) -> u32 {
        let fifo = &self.fifos[fifo];
        fifo.count as u32 | (u32::from(fifo.full) << 3) | (u32::from(fifo.overrun) << 4)
    }

    fn read_esr(&self) -> u32 {
        u32::from(self.error_warning())
            | (u32::from(self.error_passive()) << 1)
            | (u32::from(self.bus_off) << 2)
            | (u32::from(self.last_error) << 4)
            | (u32::from(self.transmit_errors.min(255)) << 16)
            | (u32::from(self.receive_errors.min(255)) << 24)
    }

    fn write_mcr(&mut self, value: u32) {
        if value & mcr::RESET != 0 {
            // RM0090 32.9.2: a master reset; sleep mode afterwards. The filters belong to
            // both controllers and keep their configuration.
            let filters = self.filters.clone();
            let (clocks, now) = (self.clocks, self.now);
            *self = Can::new();
            self.filters = filters;
            self.clocks = clocks;
            self.now = now;
            return;
        }
        self.configuration = value & mcr::CONFIGURATION;
        self.init_request = value & mcr::INRQ != 0;
        self.sleep_request = value & mcr::SLEEP != 0;
        self.settle();
    }

    fn write_tsr(&mut self, value: u32) {
        for index in 0..3 {
            let shift = 8 * index;
            let mailbox = &mut self.mailboxes[index];
            if value & (1 << shift) != 0 {
                mailbox.request_completed = false;
                mailbox.transmit_ok = false;
                mailbox.arbitration_lost = false;
                mailbox.transmit_error = false;
            }
            if value & (1 << (shift + 7)) != 0 {
                match mailbox.state {
                    MailboxState::Empty => {}
                    MailboxState::Pending => {
                        mailbox.state = MailboxState::Empty;
                        mailbox.request_completed = true;
                        mailbox.transmit_ok = false;
                    }
                    MailboxState::Transmitting => mailbox.abort = true,
                }
            }
        }
    }

    fn write_rfr(&mut self, fifo: usize, value: u32) {
        let fifo = &mut self.fifos[fifo];
        if value & (1 << 3) != 0 {
            fifo.full = false;
        }
        if value & (1 << 4) != 0 {
            fifo.overrun = false;
        }
        if value & (1 << 5) != 0 && fifo.count > 0 {
            fifo.head = (fifo.head + 1) % 3;
            fifo.count -= 1;
        }
    }

    fn write_mailbox(&mut self, index: usize, register: u32, value: u32) {
        let mailbox = &mut self.mailboxes[index];
        if mailbox.state != MailboxState::Empty {
            // RM0090 32.9.3: write protected while the mailbox is pending.
            return;
        }
        match register {
            0x0 => {
                mailbox.identifier = value & !1;
                if value & 1 != 0 {
                    mailbox.state = MailboxState::Pending;
                    mailbox.order = self.next_order;
                    mailbox.request_completed = false;
                    mailbox.transmit_ok = false;
                    mailbox.arbitration_lost = false;
                    mailbox.transmit_error = false;
                    self.next_order += 1;
                    self.loopback_start(self.now);
                }
            }
            0x4 => mailbox.timing = value & (0xF | (1 << 8)),
            0x8 => mailbox.low = value,
            _ => mailbox.high = value,
        }
    }

    fn unmodelled(offset: u32) -> AccessError {
        AccessError::Unmodelled {
            block: NAME,
            offset,
        }
    }
}

impl Peripheral for Can {
    fn name(&self) -> &'static str {
        NAME
    }

    fn read(&mut self, ctx: &Context, offset: u32, size: u32) -> Result<u32, AccessError> {
        self.sync(ctx);
        if size != 4 {
            return Err(AccessError::Width {
                block: NAME,
                offset,
                size,
            });
        }
        Ok(match offset {
            0x000 => self.read_mcr(),
            0x004 => self.read_msr(),
            0x008 => self.read_tsr(),
            0x00C => self.read_rfr(0),
            0x010 => self.read_rfr(1),
            0x014 => self.interrupt_enable,
            0x018 => self.read_esr(),
            0x01C => self.bit_timing,
            0x180..0x1B0 => {
                let index = ((offset - 0x180) / 0x10) as usize;
                let mailbox = &self.mailboxes[index];
                match offset & 0xF {
                    0x0 => mailbox.identifier | u32::from(mailbox.state != MailboxState::Empty),
                    0x4 => mailbox.timing,
                    0x8 => mailbox.low,
                    0xC => mailbox.high,
                    _ => return Err(Self::unmodelled(offset)),
                }
            }
            0x1B0..0x1D0 => {
                let fifo = &self.fifos[((offset - 0x1B0) / 0x10) as usize];
                match offset & 0xF {
                    register @ (0x0 | 0x4 | 0x8 | 0xC) => {
                        fifo.slots[fifo.head][(register / 4) as usize]
                    }
                    _ => return Err(Self::unmodelled(offset)),
                }
            }
            _ => self
                .filters
                .read(offset)
                .ok_or_else(|| Self::unmodelled(offset))?,
        })
    }

    fn write(
        &mut self,
        ctx: &Context,
        offset: u32,
        size: u32,
        value: u32,
    ) -> Result<(), AccessError> {
        self.sync(ctx);
        if size != 4 {
            return Err(AccessError::Width {
                block: NAME,
                offset,
                size,
            });
        }
        match offset {
            0x000 => self.write_mcr(value),
            0x004 => {
                // ERRI, WKUI and SLAKI are cleared by writing 1.
                if value & (1 << 2) != 0 {
                    self.error_interrupt = false;
                }
                if value & (1 << 3) != 0 {
                    self.wakeup_interrupt = false;
                }
                if value & (1 << 4) != 0 {
                    self.sleep_interrupt = false;
                }
            }
            0x008 => self.write_tsr(value),
            0x00C => self.write_rfr(0, value),
            0x010 => self.write_rfr(1, value),
            0x014 => self.interrupt_enable = value & ier::ALL,
            0x018 => self.last_error = ((value >> 4) & 0x7) as u8,
            0x01C => {
                // RM0090 32.9.2: BTR can be modified only in initialization mode.
                if self.mode == Mode::Initialization {
                    self.bit_timing = value & btr::ALL;
                }
            }
            0x180..0x1B0 if offset & 0x3 == 0 => {
                self.write_mailbox(((offset - 0x180) / 0x10) as usize, offset & 0xF, value);
            }
            _ => {
                if !self.filters.write(offset, value) {
                    return Err(Self::unmodelled(offset));
                }
            }
        }
        Ok(())
    }

    fn advance(&mut self, ctx: &Context) {
        self.sync(ctx);
    }

    fn next_event(&self, _ctx: &Context) -> Option<Nanos> {
        self.next_due()
    }

    fn interrupt_lines(&self) -> &'static [u32] {
        &LINES
    }

    fn interrupt(&self, irq: u32) -> bool {
        let enabled = |bit: u32| self.interrupt_enable & bit != 0;
        match irq {
            IRQ_TX => {
                enabled(ier::TMEIE)
                    && self
                        .mailboxes
                        .iter()
                        .any(|mailbox| mailbox.request_completed)
            }
            IRQ_RX0 | IRQ_RX1 => {
                let index = (irq - IRQ_RX0) as usize;
                let fifo = &self.fifos[index];
                let shift = 3 * index as u32;
                (enabled(ier::FMPIE0 << shift) && fifo.count > 0)
                    || (enabled(ier::FFIE0 << shift) && fifo.full)
                    || (enabled(ier::FOVIE0 << shift) && fifo.overrun)
            }
            IRQ_SCE => {
                (enabled(ier::ERRIE) && self.error_interrupt)
                    || (enabled(ier::WKUIE) && self.wakeup_interrupt)
                    || (enabled(ier::SLKIE) && self.sleep_interrupt)
            }
            _ => false,
        }
    }
}
