//! The independent watchdog armed and fed by the board's own code on its registers (RM0090
//! 21), and why it is not embassy-stm32's `IndependentWatchdog`.
//!
//! The board arms it once, with one time-out known at compile time, and feeds it; embassy's
//! driver finds the prescaler and reload for any time-out at run time. Here both are
//! constants ([`PRESCALER`], [`RELOAD`]), computed as embassy-stm32 0.6 computes them (the
//! smallest prescaler whose range holds the time-out, the reload rounded down, the LSI taken
//! at its nominal frequency), so the watchdog bites after the same time as before. The
//! erase window (`super::EraseWindow`) widens and restores the same registers.

use embassy_stm32::Peri;
use embassy_stm32::pac;
use embassy_stm32::pac::iwdg::vals::{Key, Pr};
use embassy_stm32::peripherals::IWDG;

/// The LSI's nominal frequency, which clocks the watchdog (RM0090 21.3.1; DS8626 f_LSI).
const LSI_HZ: u32 = 32_000;
/// The prescaler's divider: /4, the smallest (RM0090 21.4.2), whose range with the 12-bit
/// reload (512 ms at the nominal LSI) holds the time-out.
const DIVIDER: u32 = 4;
/// PR for [`DIVIDER`].
const PRESCALER: Pr = Pr::DIVIDE_BY4;
/// RLR: the counter counts down from it to 0 in LSI periods divided by [`DIVIDER`], so the
/// time-out is `RELOAD + 1` of those (RM0090 21.3.2).
const RELOAD: u16 = {
    let counts = super::WATCHDOG_TIMEOUT_US / DIVIDER * LSI_HZ / 1_000_000;
    assert!(
        counts >= 1 && counts <= 0x1000,
        "time-out outside the /4 prescaler's range"
    );
    (counts - 1) as u16
};

/// The armed independent watchdog.
pub struct Watchdog {
    _iwdg: Peri<'static, IWDG>,
}

impl Watchdog {
    /// Sets the prescaler and reload (the 5555h key opens PR and RLR) and starts the
    /// watchdog (CCCCh, RM0090 21.3.2); from then on only a reset stops it.
    pub fn arm(iwdg: Peri<'static, IWDG>) -> Watchdog {
        let registers = pac::IWDG;
        registers.kr().write(|w| w.set_key(Key::ENABLE));
        registers.pr().write(|w| w.set_pr(PRESCALER));
        registers.rlr().write(|w| w.set_rl(RELOAD));
        registers.kr().write(|w| w.set_key(Key::START));
        Watchdog { _iwdg: iwdg }
    }

    /// Reloads the counter (AAAAh, RM0090 21.3.2).
    pub fn pet(&mut self) {
        pac::IWDG.kr().write(|w| w.set_key(Key::RESET));
    }
}
