//! TIM2 (RM0090 18, general-purpose timers TIM2 to TIM5): the 32-bit counter clocked by
//! the APB1 timer clock through the preloaded prescaler, up or down counting to the
//! auto-reload value, update events, the four output-compare channels' flags and the
//! interrupt they raise on line 28 (RM0090 Table 61).
//!
//! Modelled (RM0090 18.3, 18.4):
//! - Time base (18.3.1, 18.3.2): CK_CNT = timer clock / (PSC + 1), the clock being
//!   [`Clocks::apb1_timers`]; PSC is preloaded and taken at the next update event (UEV);
//!   ARR is preloaded when ARPE = 1, else written through; the counter is blocked while
//!   ARR is 0.
//! - Upcounting (DIR = 0): 0 to ARR, then overflow, UEV and 0 again; a counter above ARR
//!   runs to the top of 32 bits first. Downcounting (DIR = 1): ARR down to 0, then
//!   underflow, UEV and ARR again.
//! - UEV: shadow registers loaded (PSC, ARR with ARPE, CCRx with OCxPE) and UIF set, unless
//!   UDIS = 1 (the counter still restarts); one-pulse mode (OPM) clears CEN at the UEV.
//! - EGR.UG: counter (0, or ARR when downcounting) and prescaler counter reinitialised, UEV
//!   (UIF only with URS = 0); CCxG sets CCxIF; TG sets TIF.
//! - Output compare (18.3.8): CCxIF set when the counter reaches CCRx (the flag is set
//!   whether or not the output is enabled); SR flags cleared by writing 0, writing 1 has no
//!   effect (18.4.5).
//! - Interrupt: UIF·UIE, CCxIF·CCxIE, TIF·TIE on IRQ 28.
//!
//! Not modelled, refused when software enables them: center-aligned modes (CMS), slave
//! mode and external clock (SMCR.SMS, ECE), input capture (CCxS not 00), DMA requests
//! (DIER bits 8 to 14), the DMA burst registers (DCR, DMAR) and the option register (OR).
//! Output pins (OCxREF, CCER polarity) and the clock division CKD (input filters only) are
//! stored and do nothing. CR2 (master mode, TRGO) is stored. The overcapture flags never
//! set (no capture). Registers take half-word and word accesses (18.4); bytes are refused.

use super::{AccessError, Context, Peripheral};
use crate::time::{Clocks, Nanos};

/// The TIM2 block's base address.
pub const BASE: u32 = 0x4000_0000;
/// The TIM2 block's size.
pub const SIZE: u32 = 0x400;
/// TIM2 global interrupt (RM0090 Table 61).
pub const IRQ: u32 = 28;

const NAME: &str = "TIM2 (RM0090 18)";
const LINES: [u32; 1] = [IRQ];

/// TIMx_CR1 bits (RM0090 18.4.1).
mod cr1 {
    pub const CEN: u32 = 1 << 0;
    pub const UDIS: u32 = 1 << 1;
    pub const URS: u32 = 1 << 2;
    pub const OPM: u32 = 1 << 3;
    pub const DIR: u32 = 1 << 4;
    pub const CMS: u32 = 0b11 << 5;
    pub const ARPE: u32 = 1 << 7;
    pub const ALL: u32 = 0x3FF;
}

/// TIMx_SR bits (RM0090 18.4.5).
mod sr {
    pub const UIF: u32 = 1 << 0;
    pub const TIF: u32 = 1 << 6;
    /// UIF, CC1IF..CC4IF, TIF, CC1OF..CC4OF.
    pub const ALL: u32 = 0x1E5F;
}

/// TIMx_DIER bits (RM0090 18.4.4): UIE, CC1IE..CC4IE, TIE accepted; DMA requests refused.
mod dier {
    pub const ACCEPTED: u32 = 0x5F;
    pub const REFUSED: u32 = 0x5F00;
}

/// The TIM2 model.
#[derive(Clone, Debug)]
pub struct Tim2 {
    control1: u32,
    control2: u32,
    slave_mode: u32,
    interrupt_enable: u32,
    status: u32,
    capture_compare_mode: [u32; 2],
    capture_compare_enable: u32,
    counter: u32,
    /// PSC as written (preload) and as used (shadow).
    prescaler: u32,
    prescaler_active: u32,
    /// The prescaler's own counter: timer clock cycles since the last counter tick.
    prescaler_count: u64,
    /// ARR as written (preload) and as used (shadow).
    reload: u32,
    reload_active: u32,
    /// CCRx as written (preload) and as compared (shadow).
    compare: [u32; 4],
    compare_active: [u32; 4],
    /// The timer clock and the instant its cycles are counted from.
    clock_hz: u32,
    anchor: Nanos,
    /// Timer clock cycles since `anchor` the model has counted.
    cycles_done: u64,
}

impl Default for Tim2 {
    fn default() -> Self {
        Self::new()
    }
}

impl Tim2 {
    /// The timer after reset: stopped, every register 0 (RM0090 18.4).
    pub fn new() -> Tim2 {
        Tim2 {
            control1: 0,
            control2: 0,
            slave_mode: 0,
            interrupt_enable: 0,
            status: 0,
            capture_compare_mode: [0; 2],
            capture_compare_enable: 0,
            counter: 0,
            prescaler: 0,
            prescaler_active: 0,
            prescaler_count: 0,
            reload: 0,
            reload_active: 0,
            compare: [0; 4],
            compare_active: [0; 4],
            clock_hz: Clocks::RESET.apb1_timers(),
            anchor: 0,
            cycles_done: 0,
        }
    }

    /// The counter now (TIMx_CNT as the last access or advance left it).
    pub fn counter(&self) -> u32 {
        self.counter
    }

    fn running(&self) -> bool {
        self.control1 & cr1::CEN != 0 && self.reload_active != 0
    }

    fn downcounting(&self) -> bool {
        self.control1 & cr1::DIR != 0
    }

    /// Whether channel `channel`'s CCR is preloaded (OCxPE in CCMR1/CCMR2).
    fn compare_preloaded(&self, channel: usize) -> bool {
        let mode = self.capture_compare_mode[channel / 2];
        mode & (1 << (3 + 8 * (channel % 2))) != 0
    }

    /// Counter ticks until the next overflow or underflow (the UEV tick).
    fn ticks_to_update(&self) -> u64 {
        let counter = u64::from(self.counter);
        let reload = u64::from(self.reload_active);
        if self.downcounting() {
            counter + 1
        } else if counter <= reload {
            reload - counter + 1
        } else {
            u64::from(u32::MAX) - counter + 1
        }
    }

    /// Counter ticks until the counter next equals `compare` (`None`: never before the UEV
    /// changes the picture).
    fn ticks_to_compare(&self, compare: u32) -> Option<u64> {
        let counter = u64::from(self.counter);
        let reload = u64::from(self.reload_active);
        let compare = u64::from(compare);
        if self.downcounting() {
            if compare < counter {
                Some(counter - compare)
            } else if compare <= reload {
                Some(counter + 1 + reload - compare)
            } else {
                None
            }
        } else {
            let top = if counter <= reload {
                reload
            } else {
                u64::from(u32::MAX)
            };
            if compare > counter && compare <= top {
                Some(compare - counter)
            } else if compare <= reload {
                Some(top - counter + 1 + compare)
            } else {
                None
            }
        }
    }

    /// Counter ticks until the next event (a UEV or a compare match).
    fn ticks_to_event(&self) -> u64 {
        self.compare_active
            .iter()
            .filter_map(|&compare| self.ticks_to_compare(compare))
            .fold(self.ticks_to_update(), u64::min)
    }

    /// Timer clock cycles until the counter has ticked `ticks` times: the prescaler counter
    /// first runs up to PSC, then each tick takes PSC + 1 cycles.
    fn cycles_for_ticks(&self, ticks: u64) -> u64 {
        let period = u64::from(self.prescaler_active) + 1;
        let first = period - self.prescaler_count;
        first + (ticks - 1) * period
    }

    /// The update event: shadow registers and UIF, unless UDIS; one-pulse mode stops.
    fn update_event(&mut self, set_flag: bool) {
        if self.control1 & cr1::UDIS != 0 {
            return;
        }
        self.prescaler_active = self.prescaler;
        if self.control1 & cr1::ARPE != 0 {
            self.reload_active = self.reload;
        }
        for channel in 0..4 {
            if self.compare_preloaded(channel) {
                self.compare_active[channel] = self.compare[channel];
            }
        }
        if set_flag {
            self.status |= sr::UIF;
        }
    }

    /// Counts timer clock cycles up to `target` (cycles since the anchor).
    fn count_to(&mut self, target: u64) {
        while self.cycles_done < target {
            if !self.running() {
                self.cycles_done = target;
                return;
            }
            let ticks = self.ticks_to_event();
            let needed = self.cycles_for_ticks(ticks);
            let remaining = target - self.cycles_done;
            if needed > remaining {
                let period = u64::from(self.prescaler_active) + 1;
                let first = period - self.prescaler_count;
                if remaining < first {
                    self.prescaler_count += remaining;
                } else {
                    let ticked = 1 + (remaining - first) / period;
                    self.prescaler_count = (remaining - first) % period;
                    self.step(ticked);
                }
                self.cycles_done = target;
                return;
            }
            self.cycles_done += needed;
            self.prescaler_count = 0;
            if ticks == self.ticks_to_update() {
                // Overflow or underflow: the UEV, then the counter restarts (from the new
                // ARR when downcounting).
                self.update_event(true);
                if self.control1 & cr1::OPM != 0 {
                    self.control1 &= !cr1::CEN;
                }
                self.counter = if self.downcounting() {
                    self.reload_active
                } else {
                    0
                };
            } else {
                self.step(ticks);
            }
            for channel in 0..4 {
                if self.compare_active[channel] == self.counter {
                    self.status |= 1 << (channel + 1);
                }
            }
        }
    }

    /// `ticks` counter ticks that cross no overflow.
    fn step(&mut self, ticks: u64) {
        let ticks = ticks as u32;
        self.counter = if self.downcounting() {
            self.counter.wrapping_sub(ticks)
        } else {
            self.counter.wrapping_add(ticks)
        };
    }

    /// Timer clock cycles between the anchor and `now`.
    fn cycles_at(&self, now: Nanos) -> u64 {
        let elapsed = u128::from(now.saturating_sub(self.anchor));
        (elapsed * u128::from(self.clock_hz) / 1_000_000_000) as u64
    }

    /// The instant cycle `cycles` (since the anchor) is reached.
    fn time_of(&self, cycles: u64) -> Nanos {
        self.anchor + Clocks::nanos(cycles, self.clock_hz)
    }

    fn sync(&mut self, ctx: &Context) {
        let target = self.cycles_at(ctx.now);
        self.count_to(target);
        let hz = ctx.clocks.apb1_timers();
        if hz != self.clock_hz {
            // A new timer clock: count from now on at the new frequency.
            self.clock_hz = hz;
            self.anchor = ctx.now;
            self.cycles_done = 0;
        }
    }

    fn refuse(offset: u32) -> AccessError {
        AccessError::Unmodelled {
            block: NAME,
            offset,
        }
    }

    /// UG: reinitialise counter and prescaler, then the update event.
    fn generate_update(&mut self) {
        self.prescaler_count = 0;
        let set_flag = self.control1 & cr1::URS == 0;
        self.update_event(set_flag);
        self.counter = if self.downcounting() {
            self.reload_active
        } else {
            0
        };
    }
}

impl Peripheral for Tim2 {
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
            0x00 => self.control1,
            0x04 => self.control2,
            0x08 => self.slave_mode,
            0x0C => self.interrupt_enable,
            0x10 => self.status,
            0x14 => 0,
            0x18 => self.capture_compare_mode[0],
            0x1C => self.capture_compare_mode[1],
            0x20 => self.capture_compare_enable,
            0x24 => self.counter,
            0x28 => self.prescaler,
            0x2C => self.reload,
            0x34 | 0x38 | 0x3C | 0x40 => self.compare[((offset - 0x34) / 4) as usize],
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
                if value & cr1::CMS != 0 {
                    return Err(Self::refuse(offset));
                }
                self.control1 = value & cr1::ALL;
            }
            0x04 => self.control2 = value & 0xF8,
            0x08 => {
                // SMS (bits 2:0) and ECE (bit 14) would drive the counter from elsewhere.
                if value & (0x7 | (1 << 14)) != 0 {
                    return Err(Self::refuse(offset));
                }
                self.slave_mode = value & 0xFFFF;
            }
            0x0C => {
                if value & dier::REFUSED != 0 {
                    return Err(Self::refuse(offset));
                }
                self.interrupt_enable = value & dier::ACCEPTED;
            }
            0x10 => self.status &= value | !sr::ALL,
            0x14 => {
                if value & 1 != 0 {
                    self.generate_update();
                }
                self.status |= value & 0x1E;
                if value & (1 << 6) != 0 {
                    self.status |= sr::TIF;
                }
            }
            0x18 | 0x1C => {
                // CCxS (bits 1:0 and 9:8) other than output compare would be input capture.
                if value & 0x0303 != 0 {
                    return Err(Self::refuse(offset));
                }
                self.capture_compare_mode[((offset - 0x18) / 4) as usize] = value & 0xFFFF;
            }
            0x20 => self.capture_compare_enable = value & 0xBBBB,
            0x24 => self.counter = value,
            0x28 => self.prescaler = value & 0xFFFF,
            0x2C => {
                self.reload = value;
                if self.control1 & cr1::ARPE == 0 {
                    self.reload_active = value;
                }
            }
            0x34 | 0x38 | 0x3C | 0x40 => {
                let channel = ((offset - 0x34) / 4) as usize;
                self.compare[channel] = value;
                if !self.compare_preloaded(channel) {
                    self.compare_active[channel] = value;
                }
            }
            _ => return Err(Self::refuse(offset)),
        }
        Ok(())
    }

    fn advance(&mut self, ctx: &Context) {
        self.sync(ctx);
    }

    fn next_event(&self, _ctx: &Context) -> Option<Nanos> {
        if !self.running() {
            return None;
        }
        let needed = self.cycles_for_ticks(self.ticks_to_event());
        Some(self.time_of(self.cycles_done + needed))
    }

    fn interrupt_lines(&self) -> &'static [u32] {
        &LINES
    }

    fn interrupt(&self, irq: u32) -> bool {
        irq == IRQ && self.status & self.interrupt_enable & 0x5F != 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CR1: u32 = 0x00;
    const DIER: u32 = 0x0C;
    const SR: u32 = 0x10;
    const EGR: u32 = 0x14;
    const CCMR1: u32 = 0x18;
    const CNT: u32 = 0x24;
    const PSC: u32 = 0x28;
    const ARR: u32 = 0x2C;
    const CCR1: u32 = 0x34;
    const CCR2: u32 = 0x38;

    /// 168 MHz core, APB1 at 42 MHz with a prescaler of 4: the timers run at 84 MHz.
    const CLOCKS: Clocks = Clocks {
        sysclk: 168_000_000,
        hclk: 168_000_000,
        pclk1: 42_000_000,
        pclk2: 84_000_000,
    };
    const MICROSECOND: Nanos = 1_000;
    /// PSC for one tick a microsecond at 84 MHz.
    const PSC_1_MHZ: u32 = 83;

    type Bench = crate::peripherals::bench::Bench<Tim2>;

    impl Bench {
        fn new() -> Bench {
            let mut bench = Bench::on(Tim2::new(), CLOCKS);
            let ctx = bench.ctx();
            bench.model.advance(&ctx);
            bench
        }

        /// One tick a microsecond, ARR as given, update generated with URS = 1, counting.
        fn counting(reload: u32, control: u32) -> Bench {
            let mut bench = Bench::new();
            bench.write(PSC, PSC_1_MHZ);
            bench.write(ARR, reload);
            bench.write(CR1, cr1::URS);
            bench.write(EGR, 1);
            bench.write(CR1, control | cr1::CEN);
            bench
        }
    }

    #[test]
    fn rm0090_18_4_registers_after_reset() {
        let mut bench = Bench::new();
        for offset in [
            CR1, 0x04, 0x08, DIER, SR, CCMR1, 0x1C, 0x20, CNT, PSC, ARR, CCR1,
        ] {
            assert_eq!(bench.read(offset), 0, "offset {offset:#x}");
        }
        bench.write(CR1, cr1::CEN);
        bench.wait(1_000_000);
        assert_eq!(bench.read(CNT), 0, "ARR 0 blocks the counter");
    }

    #[test]
    fn rm0090_18_3_2_the_counter_ticks_at_the_apb1_timer_clock_over_psc_plus_1() {
        let mut bench = Bench::counting(0xFFFF, 0);
        bench.wait(1_000 * MICROSECOND);
        assert_eq!(bench.read(CNT), 1_000);
        bench.wait(MICROSECOND / 2);
        assert_eq!(bench.read(CNT), 1_000);
        bench.wait(MICROSECOND / 2);
        assert_eq!(bench.read(CNT), 1_001);
    }

    #[test]
    fn rm0090_18_3_2_the_timer_clock_is_pclk1_itself_with_apb1_prescaler_1() {
        let mut bench = Bench::new();
        bench.clocks = Clocks::RESET;
        bench.write(PSC, 15);
        bench.write(ARR, 0xFFFF);
        bench.write(EGR, 1);
        bench.write(CR1, cr1::CEN);
        bench.wait(100 * MICROSECOND);
        assert_eq!(bench.read(CNT), 100, "16 MHz / 16");
    }

    #[test]
    fn rm0090_18_3_1_psc_is_preloaded_and_taken_at_the_update_event() {
        let mut bench = Bench::counting(0xFFFF, 0);
        bench.write(PSC, 2 * PSC_1_MHZ + 1);
        bench.wait(100 * MICROSECOND);
        assert_eq!(bench.read(CNT), 100, "the old prescaler until the UEV");
        assert_eq!(bench.read(PSC), 2 * PSC_1_MHZ + 1);
        bench.write(EGR, 1);
        bench.wait(100 * MICROSECOND);
        assert_eq!(bench.read(CNT), 50);
    }

    #[test]
    fn rm0090_18_3_2_upcounting_overflows_after_arr_sets_uif_and_restarts_from_0() {
        let mut bench = Bench::counting(99, 0);
        bench.write(DIER, 1);
        bench.wait(99 * MICROSECOND);
        assert_eq!(bench.read(CNT), 99);
        assert_eq!(bench.read(SR) & sr::UIF, 0);
        assert!(!bench.model.interrupt(IRQ));
        bench.wait(MICROSECOND);
        assert_eq!(bench.read(CNT), 0);
        assert_ne!(bench.read(SR) & sr::UIF, 0);
        assert!(bench.model.interrupt(IRQ));
    }

    #[test]
    fn rm0090_18_3_2_downcounting_underflows_after_0_and_reloads_arr() {
        let mut bench = Bench::counting(99, cr1::DIR);
        bench.write(CNT, 10);
        bench.wait(10 * MICROSECOND);
        assert_eq!(bench.read(CNT), 0);
        assert_eq!(bench.read(SR) & sr::UIF, 0);
        bench.wait(MICROSECOND);
        assert_eq!(bench.read(CNT), 99);
        assert_ne!(bench.read(SR) & sr::UIF, 0);
    }

    #[test]
    fn rm0090_18_3_2_without_arpe_arr_is_written_through() {
        let mut bench = Bench::counting(0xFFFF, 0);
        bench.wait(10 * MICROSECOND);
        bench.write(ARR, 19);
        bench.wait(10 * MICROSECOND);
        assert_ne!(bench.read(SR) & sr::UIF, 0, "overflowed at the new ARR");
        assert_eq!(bench.read(CNT), 0);
    }

    #[test]
    fn rm0090_18_3_2_with_arpe_arr_waits_for_the_update_event() {
        let mut bench = Bench::counting(0xFFFF, cr1::ARPE);
        bench.wait(10 * MICROSECOND);
        bench.write(ARR, 19);
        bench.wait(10 * MICROSECOND);
        assert_eq!(bench.read(SR) & sr::UIF, 0);
        assert_eq!(bench.read(CNT), 20);
        bench.write(EGR, 1);
        bench.wait(20 * MICROSECOND);
        assert_ne!(bench.read(SR) & sr::UIF, 0, "the new ARR after the UEV");
    }

    #[test]
    fn rm0090_18_4_1_urs_keeps_ug_from_setting_uif() {
        let mut bench = Bench::counting(0xFFFF, cr1::URS);
        assert_eq!(bench.read(SR) & sr::UIF, 0, "UG with URS = 1");
        bench.write(CR1, cr1::CEN);
        bench.write(EGR, 1);
        assert_ne!(bench.read(SR) & sr::UIF, 0, "UG with URS = 0");
    }

    #[test]
    fn rm0090_18_4_6_ug_reinitialises_the_counter_and_the_prescaler() {
        let mut bench = Bench::counting(0xFFFF, 0);
        bench.wait(10 * MICROSECOND + MICROSECOND / 2);
        bench.write(EGR, 1);
        assert_eq!(bench.read(CNT), 0);
        bench.wait(MICROSECOND - 12);
        assert_eq!(bench.read(CNT), 0, "prescaler counter restarted");
        bench.wait(12);
        assert_eq!(bench.read(CNT), 1);
    }

    #[test]
    fn rm0090_18_4_1_udis_suppresses_the_update_event_but_not_the_restart() {
        let mut bench = Bench::counting(9, cr1::UDIS);
        bench.write(PSC, 0);
        bench.wait(10 * MICROSECOND);
        assert_eq!(bench.read(CNT), 0, "restarted");
        assert_eq!(bench.read(SR) & sr::UIF, 0, "no UEV");
        bench.wait(MICROSECOND);
        assert_eq!(bench.read(CNT), 1, "PSC not taken");
    }

    #[test]
    fn rm0090_18_4_1_one_pulse_mode_stops_at_the_update_event() {
        let mut bench = Bench::counting(9, cr1::OPM);
        bench.wait(100 * MICROSECOND);
        assert_eq!(bench.read(CR1) & cr1::CEN, 0);
        assert_eq!(bench.read(CNT), 0);
        assert_ne!(bench.read(SR) & sr::UIF, 0);
    }

    #[test]
    fn rm0090_18_3_8_compare_match_sets_ccxif_and_raises_the_interrupt() {
        let mut bench = Bench::counting(0xFFFF, 0);
        bench.write(CCR1, 0x8000);
        bench.write(CCR2, 100);
        bench.write(DIER, 0b100);
        bench.wait(99 * MICROSECOND);
        assert_eq!(bench.read(SR) & 0b110, 0);
        bench.wait(MICROSECOND);
        assert_eq!(bench.read(SR) & 0b110, 0b100, "CC2IF");
        assert!(bench.model.interrupt(IRQ));
        bench.wait(0x8000 * MICROSECOND);
        assert_eq!(bench.read(SR) & 0b110, 0b110, "CC1IF too");
    }

    #[test]
    fn rm0090_18_4_5_status_flags_are_cleared_by_writing_0_and_kept_by_writing_1() {
        let mut bench = Bench::counting(9, 0);
        bench.write(CCR1, 5);
        // CCR2..CCR4 above ARR never match (at 0 they would match at each overflow).
        for offset in [CCR2, 0x3C, 0x40] {
            bench.write(offset, 1_000);
        }
        bench.wait(10 * MICROSECOND);
        assert_eq!(bench.read(SR), sr::UIF | 0b10);
        bench.write(SR, !sr::UIF);
        assert_eq!(bench.read(SR), 0b10);
        bench.write(SR, 0xFFFF_FFFF);
        assert_eq!(bench.read(SR), 0b10);
        bench.write(SR, 0);
        assert_eq!(bench.read(SR), 0);
    }

    #[test]
    fn rm0090_18_4_7_ocxpe_preloads_ccrx_until_the_update_event() {
        let mut bench = Bench::counting(0xFFFF, 0);
        bench.write(CCMR1, 1 << 3);
        bench.write(CCR1, 50);
        bench.wait(60 * MICROSECOND);
        assert_eq!(bench.read(SR) & 0b10, 0, "CCR1 still 0 in the shadow");
        bench.write(EGR, 1);
        bench.wait(50 * MICROSECOND);
        assert_eq!(bench.read(SR) & 0b10, 0b10);
    }

    #[test]
    fn rm0090_18_4_6_ccxg_and_tg_set_their_flags() {
        let mut bench = Bench::new();
        bench.write(EGR, 0b101_0100);
        assert_eq!(bench.read(SR), sr::TIF | 0b1_0100);
    }

    #[test]
    fn rm0090_18_4_1_clearing_cen_stops_the_counter() {
        let mut bench = Bench::counting(0xFFFF, 0);
        bench.wait(10 * MICROSECOND);
        bench.write(CR1, 0);
        bench.wait(100 * MICROSECOND);
        assert_eq!(bench.read(CNT), 10);
        bench.write(CR1, cr1::CEN);
        bench.wait(5 * MICROSECOND);
        assert_eq!(bench.read(CNT), 15);
    }

    #[test]
    fn rm0090_18_4_10_cnt_is_32_bits_and_runs_above_arr_to_the_top() {
        let mut bench = Bench::counting(100, 0);
        bench.write(CNT, 0xFFFF_FFFE);
        bench.wait(MICROSECOND);
        assert_eq!(bench.read(CNT), 0xFFFF_FFFF);
        bench.wait(MICROSECOND);
        assert_eq!(bench.read(CNT), 0);
        assert_ne!(bench.read(SR) & sr::UIF, 0);
    }

    #[test]
    fn rm0090_18_3_next_event_is_the_next_flag() {
        let mut bench = Bench::counting(0xFFFF, 0);
        bench.write(CCR1, 0x8000);
        let ctx = bench.ctx();
        assert_eq!(
            bench.model.next_event(&ctx),
            Some(bench.now + 0x8000 * MICROSECOND)
        );
        bench.wait(0x8000 * MICROSECOND);
        let ctx = bench.ctx();
        assert_eq!(
            bench.model.next_event(&ctx),
            Some(bench.now + 0x8000 * MICROSECOND),
            "the overflow"
        );
    }

    #[test]
    fn rm0090_18_4_unmodelled_functions_are_refused() {
        let mut bench = Bench::new();
        let ctx = bench.ctx();
        assert!(
            bench.model.write(&ctx, CR1, 4, 1 << 5).is_err(),
            "center-aligned"
        );
        assert!(
            bench.model.write(&ctx, 0x08, 4, 0b111).is_err(),
            "slave mode"
        );
        assert!(
            bench.model.write(&ctx, DIER, 4, 1 << 8).is_err(),
            "DMA request"
        );
        assert!(
            bench.model.write(&ctx, CCMR1, 4, 0b01).is_err(),
            "input capture"
        );
        assert!(bench.model.read(&ctx, 0x48, 4).is_err(), "DCR");
        assert!(matches!(
            bench.model.read(&ctx, CNT, 1),
            Err(AccessError::Width { .. })
        ));
        assert_eq!(bench.model.interrupt_lines(), &[28]);
    }
}
