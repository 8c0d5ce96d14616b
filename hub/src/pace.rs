//! Shared virtual time held to the host clock: a clock that follows the host's but never runs
//! more than a lookahead past what the participants it paces have acknowledged, so that a
//! participant the host does not run makes the virtual time stand still instead of running
//! away from it.
//!
//! Each paced participant is granted the virtual time now and then ([`Pacer::grants_due`]),
//! runs up to it, and acknowledges it ([`Pacer::acknowledged`]); the virtual time follows the
//! host clock, but never more than [`Pacer::lookahead`] past the oldest acknowledgement. The
//! emulated network's socketcand port runs the network so (`emulator::socketcand`, the
//! network its one paced participant): third-party tools time out on the wall clock, so the
//! network never runs ahead of it, and when the host cannot keep up the virtual time falls
//! behind instead of racing to catch up; the report ([`PaceReport`], the control port's
//! `pace` line) says by how much.
//!
//! Sans-I/O: the program hands in the host clock, grants sent and acknowledgements received,
//! and asks for the virtual time and when the next grant is due.

use shared::{Duration, Instant};
use std::collections::{BTreeMap, VecDeque};

pub use emulation_wire::{GRANT_PERIOD, LOOKAHEAD};

/// A grant not acknowledged for this long (host time) is sent again (a participant may miss
/// one it was not ready for).
pub const RESEND: Duration = Duration::from_millis(100);

/// One paced participant: what it acknowledged, the grants not yet acknowledged with the
/// host time each was sent, and the last time granted.
#[derive(Clone, Debug)]
struct Paced {
    acknowledged: Instant,
    pending: VecDeque<(Instant, Instant)>,
    granted: Option<Instant>,
}

/// What the pacing did, for the report (host durations).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PaceReport {
    /// The virtual time now.
    pub virtual_time: Instant,
    /// How far the virtual time is behind the host clock (since the first [`Pacer::advance`]).
    pub behind: Duration,
    /// The longest stretch of host time during which the virtual time stood still because a
    /// participant had not acknowledged.
    pub longest_hold: Duration,
    /// Round trips of grants (sent to acknowledged, host time): how many, median, 99th
    /// percentile and longest.
    pub round_trips: usize,
    /// Median round trip.
    pub round_trip_median: Duration,
    /// 99th percentile round trip.
    pub round_trip_p99: Duration,
    /// Longest round trip.
    pub round_trip_max: Duration,
}

/// The virtual clock.
#[derive(Clone, Debug)]
pub struct Pacer {
    lookahead: Duration,
    grant_period: Duration,
    now: Instant,
    /// The host time of the last [`Pacer::advance`], and of the first.
    host_last: Option<Instant>,
    host_first: Option<Instant>,
    paced: BTreeMap<usize, Paced>,
    /// Since when (host time) the virtual time is held by an acknowledgement.
    held_since: Option<Instant>,
    longest_hold: Duration,
    /// Grant round trips in microseconds (host time).
    round_trips: Vec<u64>,
}

impl Pacer {
    /// A clock at virtual time zero with `lookahead` and a grant every `grant_period`.
    pub fn new(lookahead: Duration, grant_period: Duration) -> Self {
        Pacer {
            lookahead,
            grant_period,
            now: Instant::ZERO,
            host_last: None,
            host_first: None,
            paced: BTreeMap::new(),
            held_since: None,
            longest_hold: Duration::ZERO,
            round_trips: Vec::new(),
        }
    }

    /// The lookahead.
    pub fn lookahead(&self) -> Duration {
        self.lookahead
    }

    /// The virtual time as of the last [`Pacer::advance`].
    pub fn now(&self) -> Instant {
        self.now
    }

    /// Participant `id` is paced: from now on the virtual time waits for it. It starts as
    /// having acknowledged the present virtual time.
    pub fn join(&mut self, id: usize) {
        self.paced.insert(
            id,
            Paced {
                acknowledged: self.now,
                pending: VecDeque::new(),
                granted: None,
            },
        );
    }

    /// Participant `id` left: the virtual time no longer waits for it.
    pub fn leave(&mut self, id: usize) {
        self.paced.remove(&id);
    }

    /// `true` when `id` is paced.
    pub fn is_paced(&self, id: usize) -> bool {
        self.paced.contains_key(&id)
    }

    /// The paced participants.
    pub fn participants(&self) -> impl Iterator<Item = usize> + '_ {
        self.paced.keys().copied()
    }

    /// The latest the virtual time may be: the lookahead past the oldest acknowledgement
    /// (never, without paced participants).
    pub fn limit(&self) -> Instant {
        self.paced
            .values()
            .map(|paced| paced.acknowledged + self.lookahead)
            .min()
            .unwrap_or(Instant::NEVER)
    }

    /// Moves the virtual time on with the host clock `host`, as far as the acknowledgements
    /// allow; returns it. Never goes backwards.
    pub fn advance(&mut self, host: Instant) -> Instant {
        let first = *self.host_first.get_or_insert(host);
        let elapsed = self
            .host_last
            .map_or(Duration::ZERO, |last| host.saturating_since(last));
        self.host_last = Some(host.max(first));
        let wanted = self.now + elapsed;
        let limit = self.limit();
        if wanted > limit {
            let since = *self.held_since.get_or_insert(host);
            self.longest_hold = self.longest_hold.max(host.saturating_since(since));
        } else {
            self.held_since = None;
        }
        self.now = self.now.max(wanted.min(limit));
        self.now
    }

    /// The participants to send a grant of the virtual time now to, at host time `host`
    /// (recorded as sent): those with no grant outstanding whose last is a grant period old,
    /// and those whose outstanding grant is [`RESEND`] old. One grant at a time: a
    /// participant that has not handled the last one would only be handed more to work
    /// through behind it.
    pub fn grants_due(&mut self, host: Instant) -> Vec<usize> {
        let (now, period) = (self.now, self.grant_period);
        let mut due = Vec::new();
        for (&id, paced) in &mut self.paced {
            let fresh =
                paced.pending.is_empty() && paced.granted.is_none_or(|last| now >= last + period);
            let stale = paced
                .pending
                .back()
                .is_some_and(|(_, sent)| host.saturating_since(*sent) >= RESEND);
            if fresh || stale {
                // A participant that never answers must not make the pacer hold more and more.
                if paced.pending.len() >= 64 {
                    paced.pending.pop_front();
                }
                paced.pending.push_back((now, host));
                paced.granted = Some(now);
                due.push(id);
            }
        }
        due
    }

    /// The virtual time at which the next grant falls due (`None`: only when an
    /// acknowledgement comes, or a resend).
    pub fn next_grant(&self) -> Option<Instant> {
        self.paced
            .values()
            .filter(|paced| paced.pending.is_empty())
            .map(|paced| {
                paced
                    .granted
                    .map_or(self.now, |last| last + self.grant_period)
            })
            .min()
    }

    /// `id` acknowledged the grant of virtual time `time` at host time `host`. An
    /// acknowledgement of a time never granted, or older than one already acknowledged,
    /// changes nothing.
    pub fn acknowledged(&mut self, id: usize, time: Instant, host: Instant) {
        let Some(paced) = self.paced.get_mut(&id) else {
            return;
        };
        let Some(position) = paced.pending.iter().position(|(t, _)| *t == time) else {
            return;
        };
        let (_, sent) = paced.pending[position];
        paced.pending.drain(..=position);
        paced.acknowledged = paced.acknowledged.max(time);
        self.round_trips
            .push(host.saturating_since(sent).as_micros());
    }

    /// What the pacing did until host time `host`.
    pub fn report(&self, host: Instant) -> PaceReport {
        let mut sorted = self.round_trips.clone();
        sorted.sort_unstable();
        let at = |fraction: f64| {
            let index = ((sorted.len() as f64 - 1.0) * fraction).round() as usize;
            Duration::from_micros(sorted.get(index).copied().unwrap_or(0))
        };
        let host_elapsed = self
            .host_first
            .map_or(Duration::ZERO, |first| host.saturating_since(first));
        PaceReport {
            virtual_time: self.now,
            behind: Duration::from_micros(
                host_elapsed
                    .as_micros()
                    .saturating_sub(self.now.as_micros()),
            ),
            longest_hold: self.longest_hold,
            round_trips: sorted.len(),
            round_trip_median: at(0.5),
            round_trip_p99: at(0.99),
            round_trip_max: at(1.0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The tests' own lookahead and grant period (the figures below follow from them).
    const LOOK: Duration = Duration::from_millis(10);
    const PERIOD: Duration = Duration::from_millis(2);

    fn ms(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    /// Without paced participants, or with all of them keeping up, the virtual time is the
    /// host's.
    #[test]
    fn virtual_time_follows_the_host_while_everyone_keeps_up() {
        let mut pacer = Pacer::new(LOOK, PERIOD);
        assert_eq!(pacer.advance(ms(1_000)), ms(0), "starts at zero");
        assert_eq!(pacer.advance(ms(1_500)), ms(500));
        pacer.join(0);
        assert_eq!(pacer.grants_due(ms(1_500)), [0]);
        pacer.acknowledged(0, ms(500), ms(1_500));
        for step in 1..=100 {
            let host = ms(1_500 + 2 * step);
            let now = pacer.advance(host);
            assert_eq!(now, ms(500 + 2 * step));
            assert_eq!(pacer.next_grant(), Some(now));
            assert_eq!(pacer.grants_due(host), [0]);
            assert_eq!(pacer.next_grant(), None, "one grant outstanding at a time");
            assert!(pacer.grants_due(host).is_empty());
            pacer.acknowledged(0, now, host + Duration::from_micros(300));
        }
        let report = pacer.report(ms(1_700));
        assert_eq!(report.behind, Duration::ZERO);
        assert_eq!(report.longest_hold, Duration::ZERO);
        assert_eq!(report.round_trips, 101);
        assert_eq!(report.round_trip_max, Duration::from_micros(300));
    }

    /// A participant that stops acknowledging (the host does not run it) holds the virtual
    /// time at its last acknowledgement plus the lookahead, however long it stays away; once
    /// it catches up, the time moves on from there, not with a jump to the host clock.
    #[test]
    fn a_participant_that_falls_behind_holds_the_time_of_the_whole_network() {
        let mut pacer = Pacer::new(LOOK, PERIOD);
        pacer.advance(ms(0));
        pacer.join(0);
        pacer.join(1);
        assert_eq!(pacer.grants_due(ms(0)), [0, 1]);
        pacer.acknowledged(0, ms(0), ms(0));
        pacer.acknowledged(1, ms(0), ms(0));
        // Participant 1 keeps up, participant 0 does not run for 500 ms of host time.
        let mut resent = 0;
        for host in (2..=500).step_by(2) {
            let now = pacer.advance(ms(host));
            assert!(now <= ms(0) + LOOK, "{now:?} at host {host} ms");
            for id in pacer.grants_due(ms(host)) {
                if id == 1 {
                    pacer.acknowledged(1, now, ms(host));
                } else {
                    resent += 1;
                }
            }
        }
        assert_eq!(resent, 5, "the unanswered grant goes again every 100 ms");
        assert_eq!(pacer.now(), ms(10));
        let report = pacer.report(ms(500));
        assert_eq!(report.behind, Duration::from_millis(490));
        assert!(report.longest_hold >= Duration::from_millis(480));
        // Participant 0 handles the grant of 10 ms: the time moves on by host time, from 10.
        pacer.acknowledged(0, ms(10), ms(501));
        assert_eq!(pacer.advance(ms(504)), ms(14));
        assert_eq!(
            pacer.advance(ms(520)),
            ms(20),
            "held again at 10 + lookahead"
        );
    }

    /// Leaving releases the hold; acknowledgements of times never granted, or out of order,
    /// change nothing; the clock never goes backwards.
    #[test]
    fn stray_acknowledgements_and_leaving() {
        let mut pacer = Pacer::new(LOOK, PERIOD);
        pacer.advance(ms(0));
        pacer.join(3);
        assert_eq!(pacer.advance(ms(100)), ms(10));
        pacer.acknowledged(3, ms(50), ms(100));
        assert_eq!(pacer.advance(ms(101)), ms(10), "50 ms was never granted");
        assert_eq!(pacer.grants_due(ms(101)), [3]);
        pacer.acknowledged(3, ms(10), ms(102));
        assert_eq!(pacer.advance(ms(200)), ms(20));
        pacer.acknowledged(3, ms(10), ms(201));
        assert_eq!(pacer.advance(ms(202)), ms(20));
        pacer.leave(3);
        assert!(!pacer.is_paced(3));
        assert_eq!(pacer.advance(ms(300)), ms(118));
        assert_eq!(
            pacer.advance(ms(250)),
            ms(118),
            "host clock went back: time holds"
        );
    }
}
