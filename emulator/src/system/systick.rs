//! The SysTick timer (ARMv7-M ARM B3.3), counted in core cycles.
//!
//! The counter is evaluated lazily: it keeps the value it had at the last tick boundary it
//! was brought to and works out the ticks since from the cycle count, so an idle timer costs
//! nothing and a deadline is exact to the cycle.

/// CSR.ENABLE.
const ENABLE: u32 = 1 << 0;
/// CSR.TICKINT.
const TICKINT: u32 = 1 << 1;
/// CSR.CLKSOURCE: 1 = the processor clock, 0 = the external reference clock.
const CLKSOURCE: u32 = 1 << 2;
/// CSR.COUNTFLAG.
const COUNTFLAG: u32 = 1 << 16;
/// The counter's width (B3.3, SYST_RVR and SYST_CVR): 24 bits.
const MASK_24: u32 = 0x00FF_FFFF;
/// The external reference clock of the STM32F4: HCLK divided by 8 (RM0090 6.2: "The RCC feeds
/// the external clock of the Cortex System Timer (SysTick) with the AHB clock (HCLK) divided
/// by 8"). The core runs at HCLK, so one reference tick is 8 core cycles.
const EXTERNAL_DIVIDER: u64 = 8;
/// SYST_CALIB (B3.3): NOREF 0 (the reference clock exists), SKEW 1 and TENMS the 1 ms
/// count of HCLK/8 at the F405's 168 MHz maximum, 21,000 (PM0214 4.5, STK_CALIB: "the calibration
/// value ... when HCLK is programmed at the maximum frequency, the SysTick period is 1 ms").
pub const CALIB: u32 = (1 << 30) | 21_000;

/// The SysTick timer.
#[derive(Clone, Debug)]
pub struct SysTick {
    csr: u32,
    reload: u32,
    /// The counter's value at `base`.
    current: u32,
    /// The cycle count of the last tick boundary the counter was brought to.
    base: u64,
}

impl Default for SysTick {
    fn default() -> Self {
        SysTick::new()
    }
}

impl SysTick {
    /// The reset state (B3.3, SYST_CSR: 0, with CLKSOURCE's reset value implementation defined;
    /// the STM32F4 resets it to 0, PM0214 4.5). RVR and CVR are UNKNOWN at reset: 0 here.
    pub fn new() -> SysTick {
        SysTick {
            csr: 0,
            reload: 0,
            current: 0,
            base: 0,
        }
    }

    fn divider(&self) -> u64 {
        if self.csr & CLKSOURCE != 0 {
            1
        } else {
            EXTERNAL_DIVIDER
        }
    }

    fn enabled(&self) -> bool {
        self.csr & ENABLE != 0
    }

    /// Brings the counter to cycle `now`. Returns `true` when it reached 0 on the way
    /// (COUNTFLAG is then set; the caller pends SysTick when [`SysTick::interrupts`]).
    pub fn catch_up(&mut self, now: u64) -> bool {
        if !self.enabled() || now <= self.base {
            return false;
        }
        let divider = self.divider();
        let ticks = (now - self.base) / divider;
        self.base += ticks * divider;
        let (current, wrapped) = count_down(self.current, self.reload, ticks);
        self.current = current;
        if wrapped {
            self.csr |= COUNTFLAG;
        }
        wrapped
    }

    /// Whether reaching 0 pends the SysTick exception (CSR.TICKINT).
    pub fn interrupts(&self) -> bool {
        self.csr & TICKINT != 0
    }

    /// The cycle count at which the counter next reaches 0 with TICKINT set (`None`: never
    /// without a register write).
    pub fn next_event(&self) -> Option<u64> {
        if !self.enabled() || !self.interrupts() {
            return None;
        }
        let ticks = if self.current > 0 {
            u64::from(self.current)
        } else if self.reload == 0 {
            return None;
        } else {
            1 + u64::from(self.reload)
        };
        Some(self.base + ticks * self.divider())
    }

    /// Reads the register at `offset` from 0xE000E010 at cycle `now` (reading CSR clears
    /// COUNTFLAG, B3.3). `None`: no register there.
    pub fn read(&mut self, offset: u32, now: u64) -> Option<(u32, bool)> {
        let wrapped = self.catch_up(now);
        let value = match offset {
            0x0 => {
                let value = self.csr;
                self.csr &= !COUNTFLAG;
                value
            }
            0x4 => self.reload,
            0x8 => self.current,
            0xC => CALIB,
            _ => return None,
        };
        Some((value, wrapped))
    }

    /// Writes the register at `offset` at cycle `now`. Returns whether the counter reached 0
    /// while being brought to `now`; `None`: no register there (CALIB is read-only and
    /// ignores writes).
    pub fn write(&mut self, offset: u32, value: u32, now: u64) -> Option<bool> {
        let wrapped = self.catch_up(now);
        match offset {
            0x0 => {
                let was_enabled = self.enabled();
                let clock_changed = (self.csr ^ value) & CLKSOURCE != 0;
                self.csr = (self.csr & COUNTFLAG) | (value & (ENABLE | TICKINT | CLKSOURCE));
                if (self.enabled() && !was_enabled) || clock_changed {
                    self.base = now;
                }
            }
            0x4 => self.reload = value & MASK_24,
            // B3.3, SYST_CVR: any write clears the counter to 0 and clears COUNTFLAG.
            0x8 => {
                self.current = 0;
                self.csr &= !COUNTFLAG;
            }
            0xC => {}
            _ => return None,
        }
        Some(wrapped)
    }
}

/// `ticks` clock edges of a down-counter at `current` with reload value `reload` (B3.3:
/// it counts down to 0, reloads on the next edge, and a reload value of 0 stops it there).
/// Returns the new value and whether it reached 0 by counting down on the way.
fn count_down(current: u32, reload: u32, ticks: u64) -> (u32, bool) {
    let current_ticks = u64::from(current);
    if ticks < current_ticks {
        return ((current_ticks - ticks) as u32, false);
    }
    let mut wrapped = current > 0;
    let mut remaining = ticks - current_ticks;
    if remaining == 0 {
        return (0, wrapped);
    }
    if reload == 0 {
        // Reloads 0 and stays there.
        return (0, wrapped);
    }
    // At 0: one edge reloads, `reload` edges count down to 0 again.
    let period = u64::from(reload) + 1;
    if remaining >= period {
        wrapped = true;
        remaining %= period;
    }
    if remaining == 0 {
        return (0, wrapped);
    }
    // One edge reloads, the rest count down (fewer than `reload` of them).
    (reload - (remaining - 1) as u32, wrapped)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn armv7m_b3_3_systick_period_is_reload_plus_one_ticks_and_countflag_clears_on_read() {
        let mut systick = SysTick::new();
        systick.write(0x4, 99, 0);
        systick.write(0x8, 0, 0);
        systick.write(0x0, ENABLE | TICKINT | CLKSOURCE, 0);
        // Reload on the first edge, then 99 edges down to 0.
        assert_eq!(systick.next_event(), Some(100));
        assert!(!systick.catch_up(99));
        assert!(systick.catch_up(100));
        assert_eq!(systick.next_event(), Some(200));
        let (csr, _) = systick.read(0x0, 150).unwrap();
        assert_ne!(csr & COUNTFLAG, 0);
        let (csr, _) = systick.read(0x0, 150).unwrap();
        assert_eq!(csr & COUNTFLAG, 0);
        assert_eq!(systick.read(0x8, 150).unwrap().0, 50);
    }

    #[test]
    fn armv7m_b3_3_systick_external_clock_ticks_every_eighth_core_cycle_on_the_stm32f4() {
        let mut systick = SysTick::new();
        systick.write(0x4, 9, 0);
        systick.write(0x0, ENABLE | TICKINT, 0);
        assert_eq!(systick.next_event(), Some(80));
    }

    #[test]
    fn armv7m_b3_3_systick_writing_cvr_clears_it_and_countflag() {
        let mut systick = SysTick::new();
        systick.write(0x4, 9, 0);
        systick.write(0x0, ENABLE | CLKSOURCE, 0);
        systick.catch_up(25);
        assert_eq!(systick.read(0x8, 25).unwrap().0, 5);
        systick.write(0x8, 1234, 25);
        assert_eq!(systick.read(0x8, 25).unwrap().0, 0);
        assert_eq!(systick.read(0x0, 25).unwrap().0 & COUNTFLAG, 0);
    }

    #[test]
    fn armv7m_b3_3_systick_a_reload_value_of_zero_stops_at_the_next_wrap() {
        let mut systick = SysTick::new();
        systick.write(0x4, 0, 0);
        systick.write(0x0, ENABLE | TICKINT | CLKSOURCE, 0);
        assert_eq!(systick.next_event(), None);
        assert!(!systick.catch_up(1_000));
    }

    #[test]
    fn armv7m_b3_3_systick_count_down_over_many_periods() {
        assert_eq!(count_down(5, 9, 3), (2, false));
        assert_eq!(count_down(5, 9, 5), (0, true));
        assert_eq!(count_down(5, 9, 6), (9, true));
        assert_eq!(count_down(0, 9, 1), (9, false));
        assert_eq!(count_down(0, 9, 10), (0, true));
        assert_eq!(count_down(0, 9, 10 + 10 * 7 + 3), (7, true));
    }
}
