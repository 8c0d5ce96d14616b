//! The leaky counter of packets with a bad CRC (SC_REQ_42).
//!
//! SC_REQ_42 asks for the safe state when the CRC is invalid for 1000 packets in one hour,
//! and its note suggests the algorithm implemented here, as written: every bad packet adds 1;
//! every 3.6 s (3600 s / 1000) the counter, if not 0, loses 1; at 1000 the SCL signals the
//! safe state. The leak ticks on a fixed grid from the counter's creation, whether or not the
//! counter is 0, so its phase never depends on when bad packets arrive.
//!
//! What the algorithm detects is a *rate*: bad packets arriving faster than one per 3.6 s on
//! average, until 1000 more have arrived than have leaked away. 1000 bad packets within a
//! few seconds trip it; 1000 spread evenly over an hour (one per 3.6 s) leak away as fast as
//! they come and do not. That is the note's algorithm, and the tests pin both cases.
//!
//! The arithmetic: the counter is a `u16` held in `0..=1000` (it stops at 1000, latched);
//! the leaks owed since the last update are computed by dividing the time since (by 1000
//! and then by 3600, `crate::time::div_rem_u16`), so a poll after any gap, however long,
//! costs the same and cannot overflow.

use crate::time::{Duration, Instant, div_rem_u16, expired};
use core::num::NonZeroU16;

/// How many bad packets trip the counter (SC_REQ_42).
pub const THRESHOLD: u16 = 1000;

/// How often the counter leaks by one: 3600 s / 1000 (SC_REQ_42's note).
pub const LEAK_PERIOD: Duration = Duration::from_millis(3600);

/// [`LEAK_PERIOD`] in milliseconds, and a millisecond in microseconds, as divisors
/// ([`div_rem_u16`]).
const LEAK_PERIOD_MS: NonZeroU16 = match NonZeroU16::new(3600) {
    Some(ms) => ms,
    None => panic!("the leak period is 3600 ms"),
};
const MICROS_PER_MILLI: NonZeroU16 = match NonZeroU16::new(1000) {
    Some(micros) => micros,
    None => panic!("a millisecond is 1000 µs"),
};
const _: () =
    assert!(LEAK_PERIOD.as_micros() == LEAK_PERIOD_MS.get() as u64 * MICROS_PER_MILLI.get() as u64);

/// The leaky counter of bad-CRC packets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BadCrcCounter {
    count: u16,
    /// The next leak tick; ticks lie on `created + n × LEAK_PERIOD`.
    next_leak: Instant,
}

/// What a bad packet did to the counter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[must_use = "a tripped counter means the safe state (SC_REQ_42)"]
pub enum Verdict {
    /// Still below 1000.
    Counting,
    /// The counter reached 1000: signal the safe state. Latched until the SCL is reset.
    Tripped,
}

impl BadCrcCounter {
    /// A counter at 0 whose first leak is due `LEAK_PERIOD` after `now`.
    pub const fn new(now: Instant) -> Self {
        BadCrcCounter {
            count: 0,
            next_leak: now.saturating_add(LEAK_PERIOD),
        }
    }

    /// The count now (after the leaks due by the last call).
    pub const fn count(&self) -> u16 {
        self.count
    }

    /// `true` once the counter has reached 1000.
    pub const fn tripped(&self) -> bool {
        self.count >= THRESHOLD
    }

    /// Applies the leaks due at `now`: one per tick at or before `now`, none once tripped
    /// (the safe state is latched; SC_REQ_41 allows leaving it only by a reset).
    pub fn poll(&mut self, now: Instant) {
        if !expired(self.next_leak, now) {
            return;
        }
        // Ticks due: the one at `next_leak` and one per whole period after it, the elapsed
        // microseconds divided by 1000 and then by 3600 (LEAK_PERIOD_MS), which is dividing
        // by 3 600 000 without a 64-bit division on the MCU. At most u64::MAX / 3 600 000 + 1.
        let elapsed = now.saturating_since(self.next_leak).as_micros();
        let (elapsed_ms, _) = div_rem_u16(elapsed, MICROS_PER_MILLI);
        let ticks = 1 + div_rem_u16(elapsed_ms, LEAK_PERIOD_MS).0;
        self.next_leak = self.next_leak.saturating_add(Duration::from_micros(
            ticks.saturating_mul(LEAK_PERIOD.as_micros()),
        ));
        if !self.tripped() {
            // `ticks` may exceed u16: the counter cannot go below 0 anyway.
            self.count = self
                .count
                .saturating_sub(u16::try_from(ticks).unwrap_or(u16::MAX));
        }
    }

    /// A packet with a bad CRC arrived at `now`: the leaks due first, then 1 more.
    pub fn bad_packet(&mut self, now: Instant) -> Verdict {
        self.poll(now);
        if !self.tripped() {
            self.count += 1;
        }
        if self.tripped() {
            Verdict::Tripped
        } else {
            Verdict::Counting
        }
    }

    /// When [`poll`](Self::poll) has something to do: the next leak while the counter is
    /// above 0 and not tripped; otherwise never (a leak of 0 changes nothing, and the grid is
    /// recomputed from `next_leak` whenever the counter is touched again).
    #[must_use]
    pub const fn deadline(&self) -> Instant {
        if self.count == 0 || self.tripped() {
            Instant::NEVER
        } else {
            self.next_leak
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    /// `n` bad packets at `now`.
    fn burst(counter: &mut BadCrcCounter, now: Instant, n: u16) -> Verdict {
        let mut verdict = Verdict::Counting;
        for _ in 0..n {
            verdict = counter.bad_packet(now);
        }
        verdict
    }

    #[test]
    fn sc_req_42_999_bad_packets_do_not_trip_1000_do() {
        let mut counter = BadCrcCounter::new(at(0));
        assert_eq!(burst(&mut counter, at(1000), 999), Verdict::Counting);
        assert_eq!(counter.count(), 999);
        assert!(!counter.tripped());
        assert_eq!(counter.bad_packet(at(1000)), Verdict::Tripped);
        assert!(counter.tripped());
    }

    #[test]
    fn sc_req_42_the_counter_leaks_one_every_3_6_s_at_the_tick_itself() {
        let mut counter = BadCrcCounter::new(at(0));
        let _ = burst(&mut counter, at(0), 10);
        assert_eq!(counter.deadline(), at(3600));
        counter.poll(at(3599));
        assert_eq!(counter.count(), 10);
        counter.poll(at(3600));
        assert_eq!(counter.count(), 9);
        assert_eq!(counter.deadline(), at(7200));
        // Three more ticks in one late poll: 7.2 s, 10.8 s, 14.4 s.
        counter.poll(at(14_400));
        assert_eq!(counter.count(), 6);
        assert_eq!(counter.deadline(), at(18_000));
    }

    /// A bad packet at the very tick: the leak is applied first.
    #[test]
    fn sc_req_42_a_bad_packet_at_a_tick_counts_after_the_leak() {
        let mut counter = BadCrcCounter::new(at(0));
        let _ = burst(&mut counter, at(0), 999);
        // At 3.6 s: 999 − 1 + 1 = 999, not 1000.
        assert_eq!(counter.bad_packet(at(3600)), Verdict::Counting);
        assert_eq!(counter.count(), 999);
        assert_eq!(counter.bad_packet(at(3600)), Verdict::Tripped);
    }

    #[test]
    fn sc_req_42_the_counter_never_goes_below_zero() {
        let mut counter = BadCrcCounter::new(at(0));
        let _ = counter.bad_packet(at(0));
        counter.poll(at(36_000));
        assert_eq!(counter.count(), 0);
        assert_eq!(counter.deadline(), Instant::NEVER);
        // The grid kept its phase: the next leak after a new bad packet is at 39.6 s.
        let _ = counter.bad_packet(at(37_000));
        assert_eq!(counter.deadline(), at(39_600));
    }

    /// One bad packet every 3.6 s, just after each tick, for an hour and more: 1000 bad
    /// packets within an hour, and the counter never exceeds 1 (the note's algorithm measures
    /// a rate above one per 3.6 s; see the module documentation).
    #[test]
    fn sc_req_42_bad_packets_at_the_leak_rate_do_not_accumulate() {
        let mut counter = BadCrcCounter::new(at(0));
        for n in 0..2000u64 {
            assert_eq!(counter.bad_packet(at(n * 3600 + 1)), Verdict::Counting);
            assert!(counter.count() <= 1);
        }
        // Slightly faster than the leak (one every 3.5 s): it trips, after about 35 hours.
        let mut counter = BadCrcCounter::new(at(0));
        let mut n = 0u64;
        while counter.bad_packet(at(n * 3500)) == Verdict::Counting {
            n += 1;
        }
        assert!((35_000..37_000).contains(&n), "tripped after {n} packets");
    }

    #[test]
    fn sc_req_42_tripped_is_latched_and_saturates() {
        let mut counter = BadCrcCounter::new(at(0));
        let _ = burst(&mut counter, at(0), 1000);
        assert_eq!(counter.bad_packet(at(1)), Verdict::Tripped);
        assert_eq!(counter.count(), THRESHOLD);
        assert_eq!(counter.deadline(), Instant::NEVER);
        counter.poll(at(10_000_000));
        assert!(counter.tripped());
        assert_eq!(
            burst(&mut counter, at(10_000_001), 60_000),
            Verdict::Tripped
        );
        assert_eq!(counter.count(), THRESHOLD);
    }

    proptest::proptest! {
        /// Against the note read literally, one leak tick at a time: after any sequence of
        /// gaps and bursts the counts agree, and the deadline is the next tick that matters.
        #[test]
        fn sc_req_42_the_counter_matches_the_note_tick_by_tick(
            steps in proptest::collection::vec((0u64..20_000, 0u16..400), 1..60)
        ) {
            let mut counter = BadCrcCounter::new(at(0));
            let (mut model, mut next_tick, mut now) = (0u16, 3600u64, 0u64);
            for (gap_ms, bad) in steps {
                now += gap_ms;
                while next_tick <= now {
                    if model != 0 && model < THRESHOLD {
                        model -= 1;
                    }
                    next_tick += 3600;
                }
                for _ in 0..bad {
                    if model < THRESHOLD {
                        model += 1;
                    }
                    let verdict = counter.bad_packet(at(now));
                    proptest::prop_assert_eq!(verdict == Verdict::Tripped, model >= THRESHOLD);
                }
                counter.poll(at(now));
                proptest::prop_assert_eq!(counter.count(), model);
                let expected = if model == 0 || model >= THRESHOLD { Instant::NEVER } else { at(next_tick) };
                proptest::prop_assert_eq!(counter.deadline(), expected);
            }
        }
    }

    /// The longest gaps there are: no overflow, no panic, the counter simply empties.
    #[test]
    fn sc_req_42_no_overflow_at_the_end_of_time() {
        let mut counter = BadCrcCounter::new(at(0));
        let _ = burst(&mut counter, at(0), 500);
        counter.poll(Instant::from_micros(u64::MAX - 1));
        assert_eq!(counter.count(), 0);
        let _ = counter.bad_packet(Instant::NEVER);
        assert_eq!(counter.count(), 1);
        let mut late = BadCrcCounter::new(Instant::NEVER);
        assert_eq!(late.bad_packet(Instant::NEVER), Verdict::Counting);
    }
}
