//! Virtual time of the emulated MCU and the clock frequencies the peripherals count in.

/// An instant of virtual time, in nanoseconds since power-on.
pub type Nanos = u64;

/// The clock frequencies (Hz) the RCC model reports (RM0090 6.2): what the core and each bus
/// run at now. Peripheral models derive their own timing from these (a USART's byte time
/// from its BRR and its bus clock, a timer's tick from its bus clock).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Clocks {
    /// SYSCLK: the core and SysTick (with CLKSOURCE = 1).
    pub sysclk: u32,
    /// HCLK: AHB.
    pub hclk: u32,
    /// PCLK1: APB1 (bxCAN, USART3, TIM2's bus).
    pub pclk1: u32,
    /// PCLK2: APB2.
    pub pclk2: u32,
}

impl Clocks {
    /// After reset: everything on the 16 MHz HSI (RM0090 6.2.2).
    pub const RESET: Clocks = Clocks {
        sysclk: 16_000_000,
        hclk: 16_000_000,
        pclk1: 16_000_000,
        pclk2: 16_000_000,
    };

    /// The APB1 timers' clock: PCLK1, doubled when the APB1 prescaler is not 1 (RM0090 6.2,
    /// "the timer clock frequencies are automatically set").
    pub fn apb1_timers(&self) -> u32 {
        if self.pclk1 == self.hclk {
            self.pclk1
        } else {
            self.pclk1.saturating_mul(2)
        }
    }

    /// `cycles` of a clock of `hz`, in nanoseconds (rounded up: an event is never early).
    pub fn nanos(cycles: u64, hz: u32) -> Nanos {
        let hz = u64::from(hz.max(1));
        (u128::from(cycles) * 1_000_000_000).div_ceil(u128::from(hz)) as u64
    }
}

/// The core's cycle count and the virtual time it stands for, at a core clock that changes
/// (16 MHz HSI after reset, the PLL's 168 MHz once the image has set the clocks up).
///
/// Time is kept as the instant of the last clock change plus the cycles counted since, so a
/// change of frequency never moves past instants and the rounding error does not accumulate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CycleClock {
    cycles: u64,
    base_cycles: u64,
    base_nanos: Nanos,
    hz: u32,
}

impl CycleClock {
    /// Cycle 0 at instant 0, counting at `hz`.
    pub fn new(hz: u32) -> CycleClock {
        CycleClock {
            cycles: 0,
            base_cycles: 0,
            base_nanos: 0,
            hz: hz.max(1),
        }
    }

    /// Core cycles since power-on.
    pub fn cycles(&self) -> u64 {
        self.cycles
    }

    /// The core clock now, Hz.
    pub fn hz(&self) -> u32 {
        self.hz
    }

    /// Virtual time now: the last change's instant plus the cycles since, rounded down.
    pub fn now(&self) -> Nanos {
        self.nanos_at(self.cycles)
    }

    /// The instant of cycle count `cycles` (not before the last clock change).
    pub fn nanos_at(&self, cycles: u64) -> Nanos {
        let since = u128::from(cycles.saturating_sub(self.base_cycles));
        self.base_nanos + (since * 1_000_000_000 / u128::from(self.hz)) as u64
    }

    /// The first cycle count whose instant is at or after `at` (the current count when `at`
    /// has passed): an event is never early.
    pub fn cycles_at(&self, at: Nanos) -> u64 {
        if at <= self.now() {
            return self.cycles;
        }
        let since = u128::from(at - self.base_nanos);
        let cycles = (since * u128::from(self.hz)).div_ceil(1_000_000_000);
        self.base_cycles
            .saturating_add(u64::try_from(cycles).unwrap_or(u64::MAX))
    }

    /// Counts `cycles` more.
    pub fn add(&mut self, cycles: u64) {
        self.cycles = self.cycles.saturating_add(cycles);
    }

    /// Moves the count forward to `cycles` (never back).
    pub fn advance_to(&mut self, cycles: u64) {
        self.cycles = self.cycles.max(cycles);
    }

    /// The core clock becomes `hz` from now on.
    pub fn set_hz(&mut self, hz: u32) {
        let hz = hz.max(1);
        if hz != self.hz {
            self.base_nanos = self.now();
            self.base_cycles = self.cycles;
            self.hz = hz;
        }
    }
}

/// `<number><unit>` with unit `s`, `ms` or `us`.
pub fn parse_duration(text: &str) -> Result<Nanos, String> {
    let (number, scale) = if let Some(number) = text.strip_suffix("ms") {
        (number, 1_000_000)
    } else if let Some(number) = text.strip_suffix("us") {
        (number, 1_000)
    } else if let Some(number) = text.strip_suffix('s') {
        (number, 1_000_000_000)
    } else {
        return Err(format!(
            "`{text}` is not a duration: give a number and a unit, e.g. 500ms, 2s, 1500us"
        ));
    };
    let value: f64 = number
        .parse()
        .map_err(|_| format!("`{number}` in `{text}` is not a number"))?;
    if !(value > 0.0 && value <= 3600.0 * 1e9 / scale as f64) {
        return Err(format!(
            "`{text}`: the duration must be positive and at most an hour"
        ));
    }
    Ok((value * scale as f64) as Nanos)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cycle_clock_counts_at_the_core_clock_and_keeps_past_instants_across_a_change() {
        let mut clock = CycleClock::new(16_000_000);
        clock.add(16_000);
        assert_eq!(clock.now(), 1_000_000);
        clock.set_hz(168_000_000);
        assert_eq!(clock.now(), 1_000_000);
        clock.add(168);
        assert_eq!(clock.now(), 1_001_000);
    }

    #[test]
    fn cycle_clock_deadline_is_never_early() {
        let mut clock = CycleClock::new(168_000_000);
        clock.add(1);
        // 1 µs is 168 cycles; 1 ns more needs one more cycle.
        assert_eq!(clock.cycles_at(1_000), 168);
        assert_eq!(clock.cycles_at(1_001), 169);
        assert!(clock.nanos_at(clock.cycles_at(1_001)) >= 1_001);
        // A past instant is now.
        assert_eq!(clock.cycles_at(0), 1);
    }

    #[test]
    fn apb1_timers_run_at_twice_pclk1_when_the_prescaler_divides() {
        let clocks = Clocks {
            sysclk: 168_000_000,
            hclk: 168_000_000,
            pclk1: 42_000_000,
            pclk2: 84_000_000,
        };
        assert_eq!(clocks.apb1_timers(), 84_000_000);
        assert_eq!(Clocks::RESET.apb1_timers(), 16_000_000);
        assert_eq!(Clocks::nanos(1, 3), 333_333_334);
    }
}
