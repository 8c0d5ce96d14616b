//! What the hardware layer's time base (`board::hw`'s `clock`, TIM2 at 1 MHz, RM0090 18)
//! reads that is not hardware, host-tested: the free-running 32-bit counter extended to the
//! protocol core's 64-bit microseconds.

/// A 32-bit up-counter that wraps from `u32::MAX` to 0, extended to 64 bits by counting its
/// wraps. Correct as long as it is read at least once per wrap (a reading below the one
/// before means exactly one wrap since).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Extended {
    last: u32,
    wraps: u32,
}

impl Extended {
    /// A counter read as 0, not wrapped yet.
    pub const fn new() -> Self {
        Extended { last: 0, wraps: 0 }
    }

    /// The counter whose last reading was `last`, after `wraps` wraps ([`Extended::parts`]).
    pub const fn from_parts(last: u32, wraps: u32) -> Self {
        Extended { last, wraps }
    }

    /// The last reading and the wraps, for a caller that keeps them in two atomics.
    pub const fn parts(self) -> (u32, u32) {
        (self.last, self.wraps)
    }

    /// The 64-bit value of the reading `count`, remembered as the last one.
    pub fn read(&mut self, count: u32) -> u64 {
        if count < self.last {
            self.wraps = self.wraps.wrapping_add(1);
        }
        self.last = count;
        (u64::from(self.wraps) << 32) | u64::from(count)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// RM0090 18.3.2: the upcounter counts to ARR (here `u32::MAX`), then restarts from 0; the
    /// extension carries on across the restart, and readings within one round stay as read.
    #[test]
    fn the_extended_counter_carries_on_across_the_wrap() {
        let mut counter = Extended::new();
        assert_eq!(counter.read(0), 0);
        assert_eq!(counter.read(1_000), 1_000);
        assert_eq!(counter.read(u32::MAX), u64::from(u32::MAX));
        assert_eq!(counter.read(5), (1 << 32) + 5);
        assert_eq!(counter.read(5), (1 << 32) + 5);
        assert_eq!(
            counter.read(u32::MAX - 1),
            (1 << 32) + u64::from(u32::MAX - 1)
        );
        assert_eq!(counter.read(0), 2 << 32);
        let (last, wraps) = counter.parts();
        assert_eq!(Extended::from_parts(last, wraps), counter);
    }

    /// Read at least once per wrap, the extended value never goes backwards and grows by
    /// exactly what the counter advanced.
    #[test]
    fn read_once_per_wrap_the_extended_counter_is_monotonic_and_exact() {
        let mut counter = Extended::new();
        let mut total: u64 = 0;
        let mut raw: u32 = 0;
        // Steps up to just under a whole wrap, as a loop that reads the clock at every wake-up.
        for step in [
            1u32,
            999,
            u32::MAX,
            12_345_678,
            3_000_000_000,
            7,
            u32::MAX - 1,
            2,
        ] {
            raw = raw.wrapping_add(step);
            total += u64::from(step);
            assert_eq!(counter.read(raw), total, "after a step of {step}");
        }
    }
}
