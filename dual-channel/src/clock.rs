//! The check of the other channel's time base against this channel's own (CiA 304 9.5: each
//! channel's timing is its own, so one channel's clock running too fast or too slow must not
//! stay latent).
//!
//! **How.** The other channel sends a link heartbeat every link period *by its clock*; after
//! a heartbeat the next one is scheduled one period on from when it was sent, so consecutive
//! heartbeats are never closer than a period of the sender's time (a late wake-up only
//! widens them), except the one sent at once on an NMT state change. So [`SPAN`] consecutive
//! heartbeat intervals must take at least `SPAN` periods of this channel's time, less
//! [`TOLERANCE_PERCENT`]. Shorter means the other channel's clock runs fast against ours, or
//! ours slow against the other's: the check runs in both channels, and whichever clock
//! drifts, one of the two sees the other as fast. (A peer's clock so slow that a heartbeat
//! is two periods late is the link time-out's: `link::Receiver`.) A heartbeat whose NMT state
//! or epoch differs from the previous one (the one sent at once on a change) starts the
//! measurement again.
//!
//! **Tolerance.** 10 % over 32 periods: crystals differ by well under 0.1 %; the margin
//! covers the link's latency jitter (a heartbeat behind other messages, under 0.5 ms at
//! 1 Mbit/s) and a receiving loop that handles a heartbeat late (the time stamp is when it
//! is handled) for up to 3.2 periods. A clock off by more than that (a wrong PLL
//! multiplier, a failed crystal with the fallback oscillator at another frequency) is
//! found within 32 periods of it starting to drift (320 ms at a 10 ms link period), while
//! the other channel's own timers keep the node safe meanwhile (outputs in series).

use shared::{Duration, Instant};

/// Heartbeat intervals measured at once.
pub const SPAN: usize = 32;

/// How much shorter than `SPAN` periods the span may be, in percent.
pub const TOLERANCE_PERCENT: u64 = 10;

/// The other channel's heartbeats came faster than its period allows: its clock runs fast
/// against this channel's, or this channel's slow against the other's.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ClockDrift {
    /// The measured span of [`SPAN`] intervals, in µs of this channel's time.
    pub span_us: u64,
}

/// The measurement of the other channel's heartbeat rate.
#[derive(Clone, Copy, Debug)]
pub struct PeerClock {
    period: Duration,
    /// When the last `SPAN` heartbeats were handled, oldest first from `next` on (a ring):
    /// the low 32 bits of the microseconds, which is half the RAM of full [`Instant`]s (the
    /// images' RAM budget is tight). Only differences are taken, with wrapping arithmetic, and
    /// they are exact while a span is shorter than 2^32 µs (71 minutes); 32 heartbeats that
    /// far apart cannot arrive, the link time-out (a few link periods) ends the link first.
    times: [u32; SPAN],
    /// Heartbeats recorded since the measurement (re)started, at most `SPAN`.
    recorded: usize,
    next: usize,
    /// The NMT state and epoch of the previous heartbeat.
    previous: Option<(u8, u8)>,
}

impl PeerClock {
    /// The check of heartbeats the other channel sends every `period`.
    pub const fn new(period: Duration) -> Self {
        PeerClock {
            period,
            times: [0; SPAN],
            recorded: 0,
            next: 0,
            previous: None,
        }
    }

    /// The shortest span of [`SPAN`] intervals allowed, in µs.
    pub const fn shortest_span(&self) -> u64 {
        self.period.as_micros() * SPAN as u64 * (100 - TOLERANCE_PERCENT) / 100
    }

    /// Starts the measurement again (the link was restarted).
    pub fn restart(&mut self) {
        self.recorded = 0;
        self.next = 0;
        self.previous = None;
    }

    /// A heartbeat with NMT state `nmt` and epoch `epoch` handled at `now`.
    pub fn heartbeat(&mut self, now: Instant, nmt: u8, epoch: u8) -> Result<(), ClockDrift> {
        if self
            .previous
            .is_some_and(|previous| previous != (nmt, epoch))
        {
            // Sent at once on an NMT change: closer than a period to the one before.
            self.restart();
        }
        self.previous = Some((nmt, epoch));
        // The entry this heartbeat overwrites is the one `SPAN` heartbeats back.
        let full = self.recorded >= SPAN;
        // Truncation is intended: see `times`.
        #[allow(clippy::cast_possible_truncation)]
        let stamp = now.as_micros() as u32;
        let oldest = self.times[self.next];
        self.times[self.next] = stamp;
        self.next = (self.next + 1) % SPAN;
        if !full {
            self.recorded += 1;
            return Ok(());
        }
        let span_us = u64::from(stamp.wrapping_sub(oldest));
        // `span < SPAN · period · (100 − tolerance) / 100`, multiplied out: no 64-bit
        // division in the firmware.
        let allowed = self
            .period
            .as_micros()
            .saturating_mul(SPAN as u64 * (100 - TOLERANCE_PERCENT));
        if span_us.saturating_mul(100) < allowed {
            return Err(ClockDrift { span_us });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn feed(
        clock: &mut PeerClock,
        interval_us: u64,
        count: usize,
        from: u64,
    ) -> Result<u64, ClockDrift> {
        let mut t = from;
        for _ in 0..count {
            clock.heartbeat(Instant::from_micros(t), 5, 0)?;
            t += interval_us;
        }
        Ok(t)
    }

    /// Heartbeats at the period, or later (late wake-ups), never trip the check; 11 % too
    /// fast trips it after `SPAN` intervals, 9 % does not.
    #[test]
    fn cia304_9_5_a_peer_clock_more_than_10_percent_fast_is_found() {
        let mut clock = PeerClock::new(Duration::from_millis(10));
        assert!(feed(&mut clock, 10_000, 200, 0).is_ok());
        assert!(feed(&mut clock, 13_000, 200, 3_000_000).is_ok());
        let mut fast = PeerClock::new(Duration::from_millis(10));
        let error = feed(&mut fast, 8_900, 200, 0).unwrap_err();
        assert!(error.span_us < fast.shortest_span());
        let mut within = PeerClock::new(Duration::from_millis(10));
        assert!(feed(&mut within, 9_100, 200, 0).is_ok());
        // Found exactly at the heartbeat that completes `SPAN` intervals: 11.2 % fast.
        let mut counted = PeerClock::new(Duration::from_millis(10));
        assert!(feed(&mut counted, 8_990, SPAN, 1_000_000).is_ok());
        let last = 1_000_000 + 8_990 * SPAN as u64;
        assert!(counted.heartbeat(Instant::from_micros(last), 5, 0).is_err());
        // 11.0 % fast stays within (32 intervals of 9.01 ms > 288 ms).
        let mut edge = PeerClock::new(Duration::from_millis(10));
        assert!(feed(&mut edge, 9_010, 200, 1_000_000).is_ok());
    }

    /// The heartbeat sent at once on an NMT change (closer than a period) restarts the
    /// measurement instead of tripping it; so does a new epoch.
    #[test]
    fn cia304_9_5_an_nmt_change_heartbeat_does_not_look_like_a_fast_clock() {
        let mut clock = PeerClock::new(Duration::from_millis(10));
        let mut t = 0;
        for round in 0..100u64 {
            for _ in 0..3 {
                clock
                    .heartbeat(Instant::from_micros(t), 5, round as u8)
                    .unwrap();
                t += 10_000;
            }
            // An NMT change 1 ms after a periodic heartbeat, then periodic again from it.
            t = t - 10_000 + 1_000;
            clock
                .heartbeat(Instant::from_micros(t), 0x7F, round as u8)
                .unwrap();
            t += 10_000;
        }
        // A receiving loop that stalls three periods and then handles the heartbeats sent
        // meanwhile in a burst is within the tolerance.
        let mut stalled = PeerClock::new(Duration::from_millis(10));
        let t = feed(&mut stalled, 10_000, 40, 0).unwrap();
        for _ in 0..3 {
            stalled
                .heartbeat(Instant::from_micros(t + 30_000), 5, 0)
                .unwrap();
        }
        assert!(feed(&mut stalled, 10_000, 100, t + 30_000).is_ok());
    }

    #[test]
    fn cia304_9_5_the_check_holds_across_the_wrap_of_its_32_bit_stamps() {
        let from = (1u64 << 32) - 100_000;
        let mut steady = PeerClock::new(Duration::from_millis(10));
        assert!(feed(&mut steady, 10_000, 200, from).is_ok());
        let mut fast = PeerClock::new(Duration::from_millis(10));
        assert!(feed(&mut fast, 8_900, 200, from).is_err());
    }
}
