//! Why a channel's MCU (the device's STM32F405) started, from the reset flags in RCC_CSR
//! (RM0090 7.3.21), in words for the start-up log: after a watchdog reset the channel comes
//! back in its safe state (outputs low, pre-operational) and says that its loop stalled. The
//! board layer only reads the register (and clears its flags) and logs these words.

/// RCC_CSR's reset flags (RM0090 7.3.21).
pub mod flags {
    /// BORRSTF: brown-out (and power-on) reset.
    pub const BROWN_OUT: u32 = 1 << 25;
    /// PINRSTF: the NRST pin (every internal reset drives it too, RM0090 7.1.2).
    pub const PIN: u32 = 1 << 26;
    /// PORRSTF: power-on or power-down reset.
    pub const POWER_ON: u32 = 1 << 27;
    /// SFTRSTF: software reset (SYSRESETREQ).
    pub const SOFTWARE: u32 = 1 << 28;
    /// IWDGRSTF: independent watchdog.
    pub const INDEPENDENT_WATCHDOG: u32 = 1 << 29;
    /// WWDGRSTF: window watchdog.
    pub const WINDOW_WATCHDOG: u32 = 1 << 30;
    /// LPWRRSTF: low-power management.
    pub const LOW_POWER: u32 = 1 << 31;
}

/// Why the MCU started, by the flags RCC_CSR holds (all since they were last cleared with
/// RMVF): the most telling cause first, since every internal reset also sets PINRSTF and a
/// power-on sets BORRSTF as well.
pub fn describe(csr: u32) -> &'static str {
    use flags::*;
    if csr & INDEPENDENT_WATCHDOG != 0 {
        "the independent watchdog: the loop stalled"
    } else if csr & WINDOW_WATCHDOG != 0 {
        "the window watchdog"
    } else if csr & SOFTWARE != 0 {
        "software"
    } else if csr & LOW_POWER != 0 {
        "low-power management"
    } else if csr & POWER_ON != 0 {
        "power-on"
    } else if csr & BROWN_OUT != 0 {
        "brown-out"
    } else if csr & PIN != 0 {
        "the reset pin"
    } else {
        "no flag"
    }
}

/// Whether the MCU started after a watchdog reset: its loop stalled.
pub fn after_watchdog(csr: u32) -> bool {
    csr & (flags::INDEPENDENT_WATCHDOG | flags::WINDOW_WATCHDOG) != 0
}

#[cfg(test)]
mod tests {
    use super::flags::*;
    use super::*;

    #[test]
    fn rm0090_7_3_21_a_watchdog_reset_is_named_although_the_pin_flag_is_set_too() {
        // RM0090 7.1.2: an internal reset drives NRST, so PINRSTF accompanies every one.
        let csr = INDEPENDENT_WATCHDOG | PIN;
        assert!(describe(csr).contains("independent watchdog"));
        assert!(after_watchdog(csr));
        assert!(after_watchdog(WINDOW_WATCHDOG | PIN));
    }

    #[test]
    fn rm0090_7_3_21_power_on_sets_three_flags_and_reads_as_power_on() {
        let csr = POWER_ON | BROWN_OUT | PIN;
        assert_eq!(describe(csr), "power-on");
        assert!(!after_watchdog(csr));
    }

    #[test]
    fn rm0090_7_3_21_software_and_pin_resets_are_told_apart() {
        assert_eq!(describe(SOFTWARE | PIN), "software");
        assert_eq!(describe(PIN), "the reset pin");
        assert_eq!(describe(0), "no flag");
    }
}
