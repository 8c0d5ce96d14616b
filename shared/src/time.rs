//! Time as the protocol core sees it: microseconds handed in by the caller.
//!
//! The core never reads a clock. The caller passes `now` with every call, and the core answers
//! with the [`Instant`] of its next deadline. A 64-bit microsecond count does not wrap in the
//! life of a machine (about 584 000 years), so deadlines are absolute instants and comparing
//! them needs no wrap-around arithmetic; adding a duration saturates instead of overflowing.

/// A point in time, in microseconds since an epoch chosen by the caller (typically power-on).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Instant(u64);

/// A span of time, in microseconds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Duration(u64);

impl Instant {
    /// The epoch itself.
    pub const ZERO: Instant = Instant(0);
    /// An instant later than any the caller will ever pass; used as "no deadline".
    pub const NEVER: Instant = Instant(u64::MAX);

    /// The instant `micros` microseconds after the epoch.
    pub const fn from_micros(micros: u64) -> Self {
        Instant(micros)
    }

    /// The instant `millis` milliseconds after the epoch (saturating).
    pub const fn from_millis(millis: u64) -> Self {
        Instant(millis.saturating_mul(1000))
    }

    /// Microseconds since the epoch.
    pub const fn as_micros(self) -> u64 {
        self.0
    }

    /// `self + duration`, saturating at [`Instant::NEVER`].
    #[inline]
    pub const fn saturating_add(self, duration: Duration) -> Instant {
        Instant(self.0.saturating_add(duration.0))
    }

    /// The time from `earlier` to `self`, or zero if `earlier` is later than `self`.
    #[inline]
    pub const fn saturating_since(self, earlier: Instant) -> Duration {
        Duration(self.0.saturating_sub(earlier.0))
    }
}

impl Duration {
    /// No time at all.
    pub const ZERO: Duration = Duration(0);

    /// A duration of `micros` microseconds.
    pub const fn from_micros(micros: u64) -> Self {
        Duration(micros)
    }

    /// A duration of `millis` milliseconds (saturating).
    pub const fn from_millis(millis: u64) -> Self {
        Duration(millis.saturating_mul(1000))
    }

    /// The duration in microseconds.
    pub const fn as_micros(self) -> u64 {
        self.0
    }
}

impl core::ops::Add<Duration> for Instant {
    type Output = Instant;
    /// Saturating: see [`Instant::saturating_add`].
    ///
    /// Out of line in the firmware images: the 64-bit saturating addition inlined at each of
    /// its 39 call sites cost more flash than the calls (`docs/footprint.md`). The host builds
    /// (tests, benchmarks) inline it as before.
    #[cfg_attr(target_os = "none", inline(never))]
    #[cfg_attr(not(target_os = "none"), inline)]
    fn add(self, rhs: Duration) -> Instant {
        self.saturating_add(rhs)
    }
}

/// `true` when a timer armed to expire at `deadline` has expired at `now`.
///
/// A timer expires *at* its deadline, not after it: a pair of SRDO frames that completes exactly
/// SCT after the previous one is already late (EN 50325-5 7.1.2 asks for reception *before* the
/// time has elapsed). Keeping this in one function means every timer in the crate agrees.
#[inline]
pub const fn expired(deadline: Instant, now: Instant) -> bool {
    now.0 >= deadline.0
}

/// `dividend / divisor` and `dividend % divisor`, for a divisor that fits 16 bits.
///
/// The MCU divides 32 bits by 32 in hardware (UDIV) and has no 64-bit division: a `/` or `%` on
/// `u64` links compiler-builtins' general routine (`u64_div_rem` and its wrappers; what they
/// cost in flash is in docs/footprint.md). Every 64-bit division of microseconds the protocol core needs is by
/// a factor of at most 16 bits, taken one after the other (1000 µs per slot, then N slots per
/// cycle; 1000 µs per millisecond, then 3600 ms per leak of the bad-CRC counter), so it is
/// done here as schoolbook long division in base 2¹⁶: four 32-bit divisions, each of the
/// remainder so far (below the divisor, so it fits 16 bits) followed by the next 16-bit digit
/// of the dividend. `floor(floor(a / b) / c) = floor(a / (b × c))` for positive integers, so
/// the steps give what one division by the product would. Tested against the compiler's own
/// 64-bit division (`tests::div_rem_u16_is_the_64_bit_division`).
#[cfg_attr(target_os = "none", inline(never))]
pub const fn div_rem_u16(dividend: u64, divisor: core::num::NonZeroU16) -> (u64, u16) {
    let divisor = divisor.get() as u32;
    let mut quotient = 0u64;
    let mut remainder = 0u32;
    let mut shift = 64;
    while shift > 0 {
        shift -= 16;
        // remainder < divisor ≤ 0xFFFF, so this is below divisor × 2¹⁶ and fits 32 bits; its
        // quotient is one 16-bit digit.
        let part = (remainder << 16) | ((dividend >> shift) as u32 & 0xFFFF);
        quotient |= ((part / divisor) as u64) << shift;
        remainder = part % divisor;
    }
    // remainder < divisor ≤ 0xFFFF.
    (quotient, remainder as u16)
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::num::NonZeroU16;
    use proptest::prelude::*;

    #[test]
    fn div_rem_u16_is_the_64_bit_division_at_the_edges() {
        let dividends = [
            0,
            1,
            999,
            1000,
            1001,
            0xFFFF,
            0x1_0000,
            u64::from(u32::MAX),
            1 << 32,
            (1 << 48) - 1,
            1 << 48,
            u64::MAX - 1,
            u64::MAX,
        ];
        for divisor in [1, 2, 3, 999, 1000, 3600, 0x7FFF, 0x8000, 0xFFFE, 0xFFFF] {
            let d = NonZeroU16::new(divisor).unwrap();
            for dividend in dividends {
                let expected = (
                    dividend / u64::from(divisor),
                    (dividend % u64::from(divisor)) as u16,
                );
                assert_eq!(div_rem_u16(dividend, d), expected, "{dividend} / {divisor}");
            }
        }
    }

    proptest! {
        #[test]
        fn div_rem_u16_is_the_64_bit_division(dividend in any::<u64>(), divisor in 1u16..) {
            let expected = (dividend / u64::from(divisor), (dividend % u64::from(divisor)) as u16);
            prop_assert_eq!(div_rem_u16(dividend, NonZeroU16::new(divisor).unwrap()), expected);
        }

        #[test]
        fn two_divisions_are_the_division_by_the_product(
            dividend in any::<u64>(), first in 1u16.., second in 1u16..,
        ) {
            let (once, _) = div_rem_u16(dividend, NonZeroU16::new(first).unwrap());
            let (twice, _) = div_rem_u16(once, NonZeroU16::new(second).unwrap());
            prop_assert_eq!(twice, dividend / (u64::from(first) * u64::from(second)));
        }
    }

    #[test]
    fn adding_saturates_instead_of_wrapping() {
        let late = Instant::from_micros(u64::MAX - 5);
        assert_eq!(late + Duration::from_micros(10), Instant::NEVER);
        assert_eq!(Duration::from_millis(u64::MAX).as_micros(), u64::MAX);
    }

    #[test]
    fn a_timer_expires_at_its_deadline_not_after() {
        let deadline = Instant::from_millis(50);
        assert!(!expired(deadline, Instant::from_micros(49_999)));
        assert!(expired(deadline, Instant::from_micros(50_000)));
    }

    #[test]
    fn since_never_goes_negative() {
        let a = Instant::from_micros(10);
        let b = Instant::from_micros(20);
        assert_eq!(b.saturating_since(a), Duration::from_micros(10));
        assert_eq!(a.saturating_since(b), Duration::ZERO);
    }
}
