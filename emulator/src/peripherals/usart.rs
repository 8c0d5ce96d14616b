//! USART3 (RM0090 30) in asynchronous mode: transmit data register and shift register timed
//! by the baud rate, receive data register with overrun and idle-line detection, the status
//! flags and their clearing sequences, and interrupt 39. Two models are wired together by
//! handing the words one offers ([`Usart::take_transmitted`]) to the other's
//! [`Usart::receive`] at their end times.
//!
//! Modelled (RM0090 30.3, 30.6):
//! - Baud rate (30.3.4): a bit lasts USARTDIV × 16 PCLK1 cycles (OVER8 = 0, BRR read as
//!   mantissa × 16 + fraction) or USARTDIV × 8 (OVER8 = 1, fraction bit 3 ignored); a frame
//!   is a start bit, 8 or 9 data bits (M) and 0.5, 1, 1.5 or 2 stop bits (CR2.STOP): 8N1 is
//!   10 bit times.
//! - Transmitter (30.3.2): setting TE (with UE) sends an idle frame first; a word written to
//!   DR waits in TDR (TXE = 0) until the shift register is free, then TXE = 1 and the word
//!   leaves; TC is set when a frame ends with TDR empty, cleared by reading SR then writing
//!   DR, or by writing 0 to it.
//! - Receiver (30.3.3): a word received with UE and RE sets RXNE; a word arriving while RXNE
//!   is set sets ORE and is lost (RDR keeps the previous word); IDLE is set when the line
//!   stays idle for one frame after a reception, and not again before the next one; ORE and
//!   IDLE are cleared by reading SR then DR; reading DR clears RXNE, as does writing 0.
//! - Interrupt (30.4): TXE·TXEIE, TC·TCIE, (RXNE or ORE)·RXNEIE, IDLE·IDLEIE on IRQ 39
//!   (RM0090 Table 61).
//!
//! Not modelled, and refused when software enables them (the access error ends the run):
//! parity (PCE), send break (SBK), mute mode (RWU), synchronous mode (CLKEN), LIN (LINEN,
//! LBDIE), IrDA, smartcard, half-duplex, DMA and hardware flow control (CR3 bits 1 to 10).
//! Noise, framing and parity errors never occur (NF, FE, PE read 0). A BRR below the
//! manual's minimum is not checked. Registers take half-word and word accesses (30.6).

use std::collections::VecDeque;

use super::{AccessError, Context, Peripheral};
use crate::time::{Clocks, Nanos};

/// The USART3 block's base address.
pub const BASE: u32 = 0x4000_4800;
/// The USART3 block's size.
pub const SIZE: u32 = 0x400;
/// USART3 global interrupt (RM0090 Table 61).
pub const IRQ: u32 = 39;

const NAME: &str = "USART3 (RM0090 30)";
const LINES: [u32; 1] = [IRQ];

/// USART_SR bits (RM0090 30.6.1).
mod sr {
    pub const ORE: u32 = 1 << 3;
    pub const IDLE: u32 = 1 << 4;
    pub const RXNE: u32 = 1 << 5;
    pub const TC: u32 = 1 << 6;
    pub const TXE: u32 = 1 << 7;
}

/// USART_CR1 bits (RM0090 30.6.4).
mod cr1 {
    pub const SBK: u32 = 1 << 0;
    pub const RWU: u32 = 1 << 1;
    pub const RE: u32 = 1 << 2;
    pub const TE: u32 = 1 << 3;
    pub const IDLEIE: u32 = 1 << 4;
    pub const RXNEIE: u32 = 1 << 5;
    pub const TCIE: u32 = 1 << 6;
    pub const TXEIE: u32 = 1 << 7;
    pub const PCE: u32 = 1 << 10;
    pub const M: u32 = 1 << 12;
    pub const UE: u32 = 1 << 13;
    pub const OVER8: u32 = 1 << 15;
    /// The bits the register implements (bit 14 is reserved).
    pub const ALL: u32 = 0xBFFF;
    /// The bits whose function the model does not implement.
    pub const REFUSED: u32 = SBK | RWU | PCE;
}

/// USART_CR2 bits (RM0090 30.6.5).
mod cr2 {
    pub const LBDIE: u32 = 1 << 6;
    pub const CLKEN: u32 = 1 << 11;
    pub const LINEN: u32 = 1 << 14;
    pub const ALL: u32 = 0x7F6F;
    pub const REFUSED: u32 = LBDIE | CLKEN | LINEN;
}

/// USART_CR3 bits (RM0090 30.6.6): EIE and ONEBIT are accepted, the rest refused.
mod cr3 {
    pub const ALL: u32 = 0x0FFF;
    pub const REFUSED: u32 = 0x07FE;
}

/// A word on its way out: what the wire carries from `start` to `end`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Transmitted {
    /// The data bits (8, or 9 with M = 1).
    pub word: u16,
    /// The start bit's beginning.
    pub start: Nanos,
    /// The end of the last stop bit: when a receiver has the word.
    pub end: Nanos,
}

/// The USART3 model.
#[derive(Clone, Debug)]
pub struct Usart {
    control1: u32,
    control2: u32,
    control3: u32,
    baud_rate: u32,
    guard_time: u32,
    /// The transmit data register (TXE = 0 while it holds a word).
    transmit_data: Option<u16>,
    /// The end of the data frame in the shift register.
    shifting_until: Option<Nanos>,
    /// The end of the idle frame sent after TE was set.
    idle_frame_until: Option<Nanos>,
    transmission_complete: bool,
    receive_data: u16,
    receive_not_empty: bool,
    overrun: bool,
    idle: bool,
    /// When IDLE is due if nothing else arrives.
    idle_at: Option<Nanos>,
    incoming: VecDeque<(u16, Nanos)>,
    outgoing: VecDeque<Transmitted>,
    /// SR as last read: the first half of the clearing sequences.
    status_seen: u32,
    clocks: Clocks,
    now: Nanos,
}

impl Default for Usart {
    fn default() -> Self {
        Self::new()
    }
}

impl Usart {
    /// The USART after reset: disabled, TXE and TC set (RM0090 30.6.1, SR reset 0x00C0).
    pub fn new() -> Usart {
        Usart {
            control1: 0,
            control2: 0,
            control3: 0,
            baud_rate: 0,
            guard_time: 0,
            transmit_data: None,
            shifting_until: None,
            idle_frame_until: None,
            transmission_complete: true,
            receive_data: 0,
            receive_not_empty: false,
            overrun: false,
            idle: false,
            idle_at: None,
            incoming: VecDeque::new(),
            outgoing: VecDeque::new(),
            status_seen: 0,
            clocks: Clocks::RESET,
            now: 0,
        }
    }

    /// PCLK1 cycles of one bit (RM0090 30.3.4, "Fractional baud rate generation").
    pub fn bit_cycles(&self) -> u64 {
        let mantissa = u64::from(self.baud_rate >> 4);
        let fraction = u64::from(self.baud_rate & 0xF);
        if self.control1 & cr1::OVER8 != 0 {
            mantissa * 8 + (fraction & 0x7)
        } else {
            mantissa * 16 + fraction
        }
        .max(1)
    }

    /// A frame's length in half bits: start bit, 8 or 9 data bits, the stop bits.
    fn frame_half_bits(&self) -> u64 {
        let data = if self.control1 & cr1::M != 0 { 9 } else { 8 };
        let stop = match (self.control2 >> 12) & 0x3 {
            0b00 => 2,
            0b01 => 1,
            0b10 => 4,
            _ => 3,
        };
        2 + 2 * data + stop
    }

    /// The duration of one frame (a word, or an idle frame) at the present settings.
    pub fn frame_time(&self) -> Nanos {
        let half_cycles = u128::from(self.frame_half_bits() * self.bit_cycles());
        let hz = u128::from(self.clocks.pclk1.max(1));
        (half_cycles * 1_000_000_000).div_ceil(2 * hz) as Nanos
    }

    /// Takes the next word the transmitter has started, with its start and end times.
    pub fn take_transmitted(&mut self) -> Option<Transmitted> {
        self.outgoing.pop_front()
    }

    /// A word whose last stop bit arrives at `at` on the RX line (taken when the model's
    /// time reaches `at`).
    pub fn receive(&mut self, word: u16, at: Nanos) {
        let position = self
            .incoming
            .iter()
            .position(|&(_, time)| time > at)
            .unwrap_or(self.incoming.len());
        self.incoming.insert(position, (word, at));
    }

    fn transmitter_enabled(&self) -> bool {
        self.control1 & (cr1::UE | cr1::TE) == (cr1::UE | cr1::TE)
    }

    fn receiver_enabled(&self) -> bool {
        self.control1 & (cr1::UE | cr1::RE) == (cr1::UE | cr1::RE)
    }

    fn word_mask(&self) -> u16 {
        if self.control1 & cr1::M != 0 {
            0x1FF
        } else {
            0xFF
        }
    }

    /// Moves TDR into the free shift register at `at`.
    fn start_next(&mut self, at: Nanos) {
        if !self.transmitter_enabled()
            || self.shifting_until.is_some()
            || self.idle_frame_until.is_some()
        {
            return;
        }
        let Some(word) = self.transmit_data.take() else {
            return;
        };
        let end = at + self.frame_time();
        self.shifting_until = Some(end);
        self.outgoing.push_back(Transmitted {
            word: word & self.word_mask(),
            start: at,
            end,
        });
    }

    fn next_due(&self) -> Option<Nanos> {
        [
            self.shifting_until,
            self.idle_frame_until,
            self.idle_at,
            self.incoming.front().map(|&(_, at)| at),
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
            if self.shifting_until == Some(due) {
                self.shifting_until = None;
                self.start_next(due);
                if self.shifting_until.is_none() {
                    self.transmission_complete = true;
                }
            } else if self.idle_frame_until == Some(due) {
                self.idle_frame_until = None;
                self.start_next(due);
            } else if let Some(&(word, at)) = self.incoming.front().filter(|&&(_, at)| at == due) {
                self.incoming.pop_front();
                if self.receiver_enabled() {
                    if self.receive_not_empty {
                        self.overrun = true;
                    } else {
                        self.receive_data = word & self.word_mask();
                        self.receive_not_empty = true;
                    }
                    self.idle_at = Some(at + self.frame_time());
                }
            } else if self.idle_at == Some(due) {
                self.idle_at = None;
                self.idle = true;
            }
        }
        self.now = self.now.max(now);
    }

    fn sync(&mut self, ctx: &Context) {
        self.clocks = ctx.clocks;
        self.run_until(ctx.now);
    }

    fn status(&self) -> u32 {
        (u32::from(self.overrun) * sr::ORE)
            | (u32::from(self.idle) * sr::IDLE)
            | (u32::from(self.receive_not_empty) * sr::RXNE)
            | (u32::from(self.transmission_complete) * sr::TC)
            | (u32::from(self.transmit_data.is_none()) * sr::TXE)
    }

    fn refuse(offset: u32) -> AccessError {
        AccessError::Unmodelled {
            block: NAME,
            offset,
        }
    }
}

impl Peripheral for Usart {
    fn name(&self) -> &'static str {
        NAME
    }

    fn read(&mut self, ctx: &Context, offset: u32, size: u32) -> Result<u32, AccessError> {
        self.sync(ctx);
        if size == 1 {
            return Err(AccessError::Width {
                block: NAME,
                offset,
                size,
            });
        }
        Ok(match offset {
            0x00 => {
                let status = self.status();
                self.status_seen = status;
                status
            }
            0x04 => {
                let word = self.receive_data & self.word_mask();
                self.receive_not_empty = false;
                if self.status_seen & sr::ORE != 0 {
                    self.overrun = false;
                }
                if self.status_seen & sr::IDLE != 0 {
                    self.idle = false;
                }
                self.status_seen &= !(sr::ORE | sr::IDLE);
                u32::from(word)
            }
            0x08 => self.baud_rate,
            0x0C => self.control1,
            0x10 => self.control2,
            0x14 => self.control3,
            0x18 => self.guard_time,
            _ => return Err(Self::refuse(offset)),
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
        if size == 1 {
            return Err(AccessError::Width {
                block: NAME,
                offset,
                size,
            });
        }
        match offset {
            0x00 => {
                // RXNE and TC are cleared by writing 0; the other flags are read-only.
                if value & sr::RXNE == 0 {
                    self.receive_not_empty = false;
                }
                if value & sr::TC == 0 {
                    self.transmission_complete = false;
                }
            }
            0x04 => {
                self.transmit_data = Some((value & 0x1FF) as u16);
                if self.status_seen & sr::TC != 0 {
                    self.transmission_complete = false;
                }
                self.status_seen &= !sr::TC;
                self.start_next(self.now);
            }
            0x08 => self.baud_rate = value & 0xFFFF,
            0x0C => {
                if value & cr1::REFUSED != 0 {
                    return Err(Self::refuse(offset));
                }
                let was_enabled = self.transmitter_enabled();
                self.control1 = value & cr1::ALL;
                if !was_enabled && self.transmitter_enabled() {
                    self.idle_frame_until = Some(self.now + self.frame_time());
                } else if !self.transmitter_enabled() {
                    self.idle_frame_until = None;
                }
            }
            0x10 => {
                if value & cr2::REFUSED != 0 {
                    return Err(Self::refuse(offset));
                }
                self.control2 = value & cr2::ALL;
            }
            0x14 => {
                if value & cr3::REFUSED != 0 {
                    return Err(Self::refuse(offset));
                }
                self.control3 = value & cr3::ALL;
            }
            0x18 => self.guard_time = value & 0xFFFF,
            _ => return Err(Self::refuse(offset)),
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
        let enabled = |bit: u32| self.control1 & bit != 0;
        irq == IRQ
            && ((enabled(cr1::TXEIE) && self.transmit_data.is_none())
                || (enabled(cr1::TCIE) && self.transmission_complete)
                || (enabled(cr1::RXNEIE) && (self.receive_not_empty || self.overrun))
                || (enabled(cr1::IDLEIE) && self.idle))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SR: u32 = 0x00;
    const DR: u32 = 0x04;
    const BRR: u32 = 0x08;
    const CR1: u32 = 0x0C;
    const CR2: u32 = 0x10;

    /// 16 MHz PCLK1 and BRR 0x8B: 139 cycles a bit, 10 bits a frame, 86 875 ns.
    const FRAME: Nanos = 86_875;
    const BRR_115200: u32 = 0x8B;

    type Bench = crate::peripherals::bench::Bench<Usart>;

    impl Bench {
        fn new() -> Bench {
            Bench::on(Usart::new(), Clocks::RESET)
        }

        /// UE, TE, RE at 115 200 baud, then past the idle frame.
        fn enabled() -> Bench {
            let mut bench = Bench::new();
            bench.write(BRR, BRR_115200);
            bench.write(CR1, cr1::UE | cr1::TE | cr1::RE);
            bench.wait(FRAME);
            bench
        }
    }

    #[test]
    fn rm0090_30_6_registers_after_reset() {
        let mut bench = Bench::new();
        assert_eq!(bench.read(SR), sr::TXE | sr::TC);
        for offset in [BRR, CR1, CR2, 0x14, 0x18] {
            assert_eq!(bench.read(offset), 0);
        }
    }

    #[test]
    fn rm0090_30_3_4_oversampling_by_16_bit_time_is_brr_cycles() {
        let mut bench = Bench::new();
        bench.write(BRR, BRR_115200);
        assert_eq!(bench.model.bit_cycles(), 139);
        assert_eq!(bench.model.frame_time(), FRAME);
    }

    #[test]
    fn rm0090_30_3_4_oversampling_by_8_uses_three_fraction_bits() {
        let mut bench = Bench::new();
        // USARTDIV 17.375: mantissa 17, fraction 3 (bit 3 of the fraction is ignored).
        bench.write(CR1, cr1::OVER8);
        bench.write(BRR, (17 << 4) | 0xB);
        assert_eq!(bench.model.bit_cycles(), 17 * 8 + 3);
        assert_eq!(bench.model.frame_time(), FRAME);
    }

    #[test]
    fn rm0090_30_3_1_word_length_and_stop_bits_set_the_frame_length() {
        let mut bench = Bench::new();
        bench.write(BRR, 0x100);
        let bit = Clocks::nanos(0x100, Clocks::RESET.pclk1);
        assert_eq!(bench.model.frame_time(), 10 * bit);
        bench.write(CR2, 0b10 << 12);
        assert_eq!(bench.model.frame_time(), 11 * bit, "2 stop bits");
        bench.write(CR1, cr1::M);
        assert_eq!(
            bench.model.frame_time(),
            12 * bit,
            "9 data bits, 2 stop bits"
        );
        bench.write(CR1, 0);
        bench.write(CR2, 0b01 << 12);
        assert_eq!(bench.model.frame_time(), 19 * bit / 2, "half a stop bit");
        bench.write(CR2, 0b11 << 12);
        assert_eq!(bench.model.frame_time(), 21 * bit / 2, "1.5 stop bits");
    }

    #[test]
    fn rm0090_30_3_2_setting_te_sends_an_idle_frame_first() {
        let mut bench = Bench::new();
        bench.write(BRR, BRR_115200);
        bench.write(CR1, cr1::UE | cr1::TE);
        bench.write(DR, 0x41);
        let sent = bench.model.take_transmitted();
        assert_eq!(sent, None, "the idle frame is on the line");
        bench.wait(FRAME);
        let sent = bench
            .model
            .take_transmitted()
            .expect("started after the idle frame");
        assert_eq!(
            sent,
            Transmitted {
                word: 0x41,
                start: FRAME,
                end: 2 * FRAME
            }
        );
    }

    #[test]
    fn rm0090_30_3_2_txe_is_set_when_tdr_moves_to_the_shift_register() {
        let mut bench = Bench::enabled();
        bench.write(DR, 1);
        assert_ne!(bench.read(SR) & sr::TXE, 0, "shift register was free");
        bench.write(DR, 2);
        assert_eq!(bench.read(SR) & sr::TXE, 0, "waits in TDR");
        bench.wait(FRAME);
        assert_ne!(bench.read(SR) & sr::TXE, 0);
        let first = bench.model.take_transmitted().expect("first");
        let second = bench.model.take_transmitted().expect("second");
        assert_eq!(first.end, second.start, "back to back");
        assert_eq!(second.word, 2);
    }

    #[test]
    fn rm0090_30_3_2_tc_is_set_when_the_last_frame_ends() {
        let mut bench = Bench::enabled();
        bench.read(SR);
        bench.write(DR, 1);
        assert_eq!(
            bench.read(SR) & sr::TC,
            0,
            "cleared by the SR-then-DR sequence"
        );
        bench.write(DR, 2);
        bench.wait(FRAME);
        assert_eq!(bench.read(SR) & sr::TC, 0, "second frame still going");
        bench.wait(FRAME - 1);
        assert_eq!(bench.read(SR) & sr::TC, 0);
        bench.wait(1);
        assert_ne!(bench.read(SR) & sr::TC, 0);
    }

    #[test]
    fn rm0090_30_6_1_tc_is_cleared_by_writing_0_and_only_then_without_the_sequence() {
        let mut bench = Bench::enabled();
        bench.write(DR, 1);
        assert_ne!(
            bench.model.status() & sr::TC,
            0,
            "a DR write without an SR read first leaves TC"
        );
        bench.write(SR, !sr::TC);
        assert_eq!(bench.model.status() & sr::TC, 0);
    }

    #[test]
    fn rm0090_30_3_3_a_received_word_sets_rxne_and_reading_dr_clears_it() {
        let mut bench = Bench::enabled();
        bench.model.receive(0x5A, bench.now + 10);
        assert_eq!(bench.read(SR) & sr::RXNE, 0, "not yet arrived");
        bench.wait(10);
        assert_ne!(bench.read(SR) & sr::RXNE, 0);
        assert_eq!(bench.read(DR), 0x5A);
        assert_eq!(bench.read(SR) & sr::RXNE, 0);
    }

    #[test]
    fn rm0090_30_6_1_rxne_is_cleared_by_writing_0() {
        let mut bench = Bench::enabled();
        bench.model.receive(1, bench.now);
        bench.wait(0);
        bench.write(SR, !sr::RXNE);
        assert_eq!(bench.read(SR) & sr::RXNE, 0);
    }

    #[test]
    fn rm0090_30_3_3_overrun_keeps_rdr_and_is_cleared_by_reading_sr_then_dr() {
        let mut bench = Bench::enabled();
        bench.model.receive(1, bench.now);
        bench.model.receive(2, bench.now + FRAME);
        bench.wait(FRAME);
        let status = bench.read(SR);
        assert_ne!(status & sr::ORE, 0);
        assert_eq!(bench.read(DR), 1, "the earlier word is kept");
        assert_eq!(bench.read(SR) & (sr::ORE | sr::RXNE), 0);
    }

    #[test]
    fn rm0090_30_6_1_ore_stays_without_the_sr_read_first() {
        let mut bench = Bench::enabled();
        bench.model.receive(1, bench.now);
        bench.model.receive(2, bench.now);
        bench.wait(0);
        bench.read(DR);
        assert_ne!(bench.model.status() & sr::ORE, 0);
    }

    #[test]
    fn rm0090_30_3_3_idle_is_set_one_idle_frame_after_a_reception_and_once() {
        let mut bench = Bench::enabled();
        bench.model.receive(1, bench.now);
        bench.model.receive(2, bench.now + FRAME);
        bench.wait(FRAME);
        bench.read(SR);
        bench.read(DR);
        bench.wait(FRAME - 1);
        assert_eq!(bench.read(SR) & sr::IDLE, 0);
        bench.wait(1);
        assert_ne!(bench.read(SR) & sr::IDLE, 0);
        bench.read(DR);
        assert_eq!(
            bench.read(SR) & sr::IDLE,
            0,
            "cleared by reading SR then DR"
        );
        bench.wait(10 * FRAME);
        assert_eq!(
            bench.read(SR) & sr::IDLE,
            0,
            "not again before the next reception"
        );
    }

    #[test]
    fn rm0090_30_3_3_nothing_is_received_without_re() {
        let mut bench = Bench::new();
        bench.write(BRR, BRR_115200);
        bench.write(CR1, cr1::UE | cr1::TE);
        bench.model.receive(1, bench.now);
        bench.wait(10 * FRAME);
        assert_eq!(bench.read(SR) & (sr::RXNE | sr::IDLE), 0);
    }

    #[test]
    fn rm0090_30_4_interrupt_sources_and_their_enables() {
        let mut bench = Bench::enabled();
        assert!(!bench.model.interrupt(IRQ));
        bench.write(CR1, cr1::UE | cr1::TE | cr1::RE | cr1::TXEIE);
        assert!(bench.model.interrupt(IRQ), "TXE");
        bench.write(CR1, cr1::UE | cr1::TE | cr1::RE | cr1::TCIE);
        assert!(bench.model.interrupt(IRQ), "TC");
        bench.write(SR, !sr::TC);
        assert!(!bench.model.interrupt(IRQ));
        bench.write(CR1, cr1::UE | cr1::TE | cr1::RE | cr1::RXNEIE);
        bench.model.receive(1, bench.now);
        bench.model.receive(2, bench.now);
        bench.wait(0);
        assert!(bench.model.interrupt(IRQ), "RXNE");
        bench.write(SR, !sr::RXNE);
        assert!(bench.model.interrupt(IRQ), "ORE with RXNEIE");
        bench.read(SR);
        bench.read(DR);
        assert!(!bench.model.interrupt(IRQ));
        bench.write(CR1, cr1::UE | cr1::TE | cr1::RE | cr1::IDLEIE);
        bench.wait(FRAME);
        assert!(bench.model.interrupt(IRQ), "IDLE");
        assert_eq!(Usart::new().interrupt_lines(), &[39]);
    }

    #[test]
    fn rm0090_30_3_two_usarts_wired_together_carry_words_at_the_byte_time() {
        let mut a = Bench::enabled();
        let mut b = Bench::enabled();
        a.write(DR, 0x31);
        a.write(DR, 0x32);
        a.wait(2 * FRAME);
        while let Some(sent) = a.model.take_transmitted() {
            b.model.receive(sent.word, sent.end);
        }
        b.wait(FRAME - 1);
        assert_eq!(b.read(SR) & sr::RXNE, 0);
        b.wait(1);
        assert_eq!(b.read(DR), 0x31);
        b.wait(FRAME);
        assert_eq!(b.read(DR), 0x32);
    }

    #[test]
    fn rm0090_30_6_byte_accesses_and_unmodelled_features_are_refused() {
        let mut bench = Bench::new();
        let ctx = bench.ctx();
        assert!(matches!(
            bench.model.read(&ctx, SR, 1),
            Err(AccessError::Width { .. })
        ));
        assert!(bench.model.write(&ctx, CR1, 4, cr1::PCE).is_err(), "parity");
        assert!(bench.model.write(&ctx, 0x14, 4, 1 << 7).is_err(), "DMA");
        assert!(bench.model.write(&ctx, 0x14, 4, 1 << 11).is_ok(), "ONEBIT");
        assert!(bench.model.read(&ctx, 0x1C, 4).is_err());
    }
}
