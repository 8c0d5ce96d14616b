//! The clock of an emulated channel: host time from QEMU's semihosting ticks, and the clock
//! paced by the hub's grants ([`crate::Wire::Time`]), which never runs more than the
//! lookahead past the newest grant (`docs/emulation.md`). The QEMU board layer reads the
//! ticks and keeps the grants; the arithmetic is here, host-tested.

/// The virtual time (microseconds) a paced emulated channel's clock shows at host time
/// `host`: the last grant `granted`, handled at host time `host_at_grant`, plus the host time
/// since, but at most `lookahead` past the grant, and never less than `last`, the time
/// handed out before (the clock never goes backwards; the hub's grants only grow, and one
/// older than `last` holds the clock there). So the clock is never more than `lookahead`
/// past the newest grant handled, or past what it showed already: the bound the argument in
/// `docs/emulation.md` rests on. Saturating, it cannot overflow.
pub fn paced_clock(last: u64, granted: u64, host_at_grant: u64, host: u64, lookahead: u64) -> u64 {
    let since = host.saturating_sub(host_at_grant).min(lookahead);
    last.max(granted.saturating_add(since))
}

/// Host ticks (semihosting `SYS_ELAPSED`, `hz` of them a second: `SYS_TICKFREQ`) as whole
/// microseconds, rounded down, saturating. The QEMU layer's clock reads it on every call of
/// `now()`, many times a loop round: at a whole number of ticks per microsecond (QEMU counts
/// nanoseconds) one 64-bit division; otherwise the exact 128-bit product and quotient, whose
/// software division cost the emulated core most of the longest loop round traced (`cargo
/// xtask bench --target-cost`, 2026-12-03).
pub fn micros_from_host_ticks(ticks: u64, hz: u32) -> u64 {
    let hz = hz.max(1);
    if hz % 1_000_000 == 0 {
        ticks / u64::from(hz / 1_000_000)
    } else {
        u64::try_from(u128::from(ticks) * 1_000_000 / u128::from(hz)).unwrap_or(u64::MAX)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The exact quotient floor(ticks × 10⁶ / hz), computed without overflow.
    fn exact(ticks: u64, hz: u32) -> u64 {
        u64::try_from(u128::from(ticks) * 1_000_000 / u128::from(hz.max(1))).unwrap_or(u64::MAX)
    }

    /// Host ticks become the exact microseconds, rounded down, by either path: whole ticks per
    /// microsecond (QEMU's nanoseconds, 1 MHz, 24 MHz) and the rest (32,768 Hz, 1 Hz, a tick
    /// frequency of 0 taken as 1), at the edges (0, one below a whole microsecond, u64::MAX)
    /// and at values spread over the range.
    #[test]
    fn host_ticks_become_exact_microseconds_rounded_down() {
        let frequencies = [1_000_000_000, 1_000_000, 24_000_000, 32_768, 1, 0, u32::MAX];
        let edges = [0, 1, 999, 1_000, 1_001, 999_999, u64::MAX, u64::MAX - 1];
        // A multiplicative walk over the range (no generator needed).
        let walk = (0..500u64).scan(1u64, |value, _| {
            *value = value
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            Some([*value, *value >> 20])
        });
        let ticks: heapless::Vec<u64, 1100> = edges.into_iter().chain(walk.flatten()).collect();
        for hz in frequencies {
            for &t in &ticks {
                assert_eq!(
                    micros_from_host_ticks(t, hz),
                    exact(t, hz),
                    "{t} ticks at {hz} Hz"
                );
            }
        }
        assert_eq!(micros_from_host_ticks(1_999, 1_000_000_000), 1);
        assert_eq!(micros_from_host_ticks(2_000, 1_000_000_000), 2);
    }

    /// The paced clock runs with the host from a grant, stands still at the lookahead past it
    /// until the next grant, never goes backwards, and does not overflow.
    #[test]
    fn a_paced_clock_never_runs_more_than_the_lookahead_past_its_grant() {
        let lookahead = 10_000;
        // Granted 1 s at host 5 s: host time runs on up to the lookahead, then stops.
        assert_eq!(
            paced_clock(0, 1_000_000, 5_000_000, 5_000_000, lookahead),
            1_000_000
        );
        assert_eq!(
            paced_clock(0, 1_000_000, 5_000_000, 5_004_000, lookahead),
            1_004_000
        );
        assert_eq!(
            paced_clock(0, 1_000_000, 5_000_000, 5_900_000, lookahead),
            1_010_000
        );
        // A grant older than what was handed out holds the clock: never backwards.
        assert_eq!(
            paced_clock(1_010_000, 1_002_000, 6_000_000, 6_001_000, lookahead),
            1_010_000
        );
        assert_eq!(
            paced_clock(1_010_000, 1_002_000, 6_000_000, 6_009_000, lookahead),
            1_011_000
        );
        // A host clock read before the grant was handled adds nothing.
        assert_eq!(paced_clock(0, 7, 100, 50, lookahead), 7);
        assert_eq!(paced_clock(0, u64::MAX, 0, u64::MAX, lookahead), u64::MAX);
        for host in (0..100_000_000).step_by(777_777) {
            let shown = paced_clock(0, 42, 0, host, lookahead);
            assert!(shown <= 42 + lookahead, "{shown} at host {host}");
        }
    }
}
