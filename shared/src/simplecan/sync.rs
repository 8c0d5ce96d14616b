//! Unsynced and synced: the SCL's view of the global time, `docs/simplecan.md` section 6
//! (SC_REQ_29, SC_REQ_30, SC_REQ_32, SC_REQ_33; SC_REQ_31's budget in the tests).
//!
//! The tracker starts unsynced and has no global time, so a producer has no slot to send in
//! and a consumer cannot judge any packet's timeliness: both do nothing (SC_REQ_29). Two syncs
//! from one master whose global times advance by what the local clock measured, within
//! ±2 ms, make it synced (SC_REQ_30); every sync's global time is taken as
//! `sync time + maximum buffering time` at the instant it is handed in (SC_REQ_33). 2000 ms
//! without a sync from its master make it unsynced again (SC_REQ_32), and so does a sync from
//! its master that disagrees by more than 2 ms. A lower SC-ID's sync that agrees with the
//! time it holds moves it to that master (a takeover, section 7); one that disagrees makes it
//! unsynced.

use super::frame::SyncPacket;
use super::schedule::Cycle;
use super::{SYNC_LOSS_TIMEOUT, SYNC_TOLERANCE, ScId};
use crate::time::{Duration, Instant, expired};

/// A global time and the local instant it belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct Sample {
    master: ScId,
    local: Instant,
    global: u64,
}

impl Sample {
    /// The global time at local instant `now` by this sample's anchor.
    #[cfg_attr(target_os = "none", inline(never))]
    fn global_at(&self, now: Instant) -> u64 {
        self.global
            .saturating_add(now.saturating_since(self.local).as_micros())
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum State {
    Unsynced { candidate: Option<Sample> },
    Synced { anchor: Sample },
}

/// Why the tracker went unsynced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Unsynced {
    /// No sync from the master for 2000 ms (SC_REQ_32).
    Timeout,
    /// A sync from the master, or one taking over from it, disagreed by more than 2 ms.
    Disagreed {
        /// How far, in microseconds.
        by_micros: u64,
    },
}

/// A change of the tracker's state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[must_use = "unsynced means: send nothing and discard what arrives (SC_REQ_29)"]
pub enum Change {
    /// Synced to `master` (SC_REQ_30), or moved to it on a takeover.
    Synced {
        /// The master.
        master: ScId,
    },
    /// Unsynced again.
    Unsynced(Unsynced),
}

/// The SCL's synchronisation state and global time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SyncTracker {
    cycle: Cycle,
    max_buffering: Duration,
    state: State,
}

impl SyncTracker {
    /// An unsynced tracker for the network's `cycle`, on a receiver that states it buffers a
    /// packet for at most `max_buffering` (SC_REQ_33).
    pub const fn new(cycle: Cycle, max_buffering: Duration) -> Self {
        SyncTracker {
            cycle,
            max_buffering,
            state: State::Unsynced { candidate: None },
        }
    }

    /// `true` when synced: producers may send and consumers may accept (SC_REQ_29).
    pub const fn is_synced(&self) -> bool {
        matches!(self.state, State::Synced { .. })
    }

    /// The master synced to.
    pub const fn master(&self) -> Option<ScId> {
        match self.state {
            State::Synced { anchor } => Some(anchor.master),
            State::Unsynced { .. } => None,
        }
    }

    /// The global time at local instant `now`, when synced.
    pub fn global_time(&self, now: Instant) -> Option<u64> {
        match self.state {
            State::Synced { anchor } => Some(anchor.global_at(now)),
            State::Unsynced { .. } => None,
        }
    }

    /// The local instant at which the global time is (or was) `global`, when synced: how a
    /// consumer turns a slot start into the instant a value's age counts from.
    pub fn local_instant(&self, global: u64) -> Option<Instant> {
        match self.state {
            State::Synced { anchor } => {
                let local = anchor.local.as_micros();
                Some(Instant::from_micros(if global >= anchor.global {
                    local.saturating_add(global - anchor.global)
                } else {
                    local.saturating_sub(anchor.global - global)
                }))
            }
            State::Unsynced { .. } => None,
        }
    }

    /// The sync's global time at `now`, the instant it is handed in: the cycle number unwrapped
    /// to the cycle nearest `reference`'s estimate, plus the maximum buffering time.
    fn sample(&self, now: Instant, sync: &SyncPacket, reference: Option<&Sample>) -> Sample {
        let cycle = match reference {
            // Serial-number arithmetic: the wire's 16 bits name the cycle within ±32768 of the
            // one expected.
            Some(reference) => {
                let (expected, _) = self.cycle.position(reference.global_at(now));
                let distance = i64::from(sync.cycle().wrapping_sub(expected as u16) as i16);
                expected.saturating_add_signed(distance)
            }
            None => u64::from(sync.cycle()),
        };
        let last_slot = self.cycle.slot_start(cycle, self.cycle.sync_slot());
        Sample {
            master: sync.master(),
            local: now,
            global: last_slot
                .saturating_add(u64::from(sync.offset_micros()))
                .saturating_add(self.max_buffering.as_micros()),
        }
    }

    /// A sync (already decoded and checked) handed in at `now`.
    pub fn on_sync(&mut self, now: Instant, sync: &SyncPacket) -> Option<Change> {
        match self.state {
            State::Unsynced { candidate } => {
                let reference = candidate.filter(|c| c.master == sync.master());
                let sample = self.sample(now, sync, reference.as_ref());
                match reference {
                    Some(first) if disagreement(&first, &sample) <= SYNC_TOLERANCE.as_micros() => {
                        self.state = State::Synced { anchor: sample };
                        Some(Change::Synced {
                            master: sample.master,
                        })
                    }
                    _ => {
                        // The first sync, one from another master, or one that disagreed:
                        // it is the candidate now.
                        self.state = State::Unsynced {
                            candidate: Some(sample),
                        };
                        None
                    }
                }
            }
            State::Synced { anchor } => {
                if sync.master() > anchor.master {
                    // A higher master's time is not ours; whether it should be sending at all
                    // is the several-masters check's question (SC_REQ_26).
                    return None;
                }
                let sample = self.sample(now, sync, Some(&anchor));
                let by_micros = disagreement(&anchor, &sample);
                if by_micros <= SYNC_TOLERANCE.as_micros() {
                    self.state = State::Synced { anchor: sample };
                    (sync.master() != anchor.master).then_some(Change::Synced {
                        master: sample.master,
                    })
                } else {
                    self.state = State::Unsynced {
                        candidate: Some(sample),
                    };
                    Some(Change::Unsynced(Unsynced::Disagreed { by_micros }))
                }
            }
        }
    }

    /// Checks the sync timeout at `now` (SC_REQ_32: unsynced at 2000 ms without a sync).
    pub fn poll(&mut self, now: Instant) -> Option<Change> {
        if expired(self.deadline(), now) {
            self.state = State::Unsynced { candidate: None };
            Some(Change::Unsynced(Unsynced::Timeout))
        } else {
            None
        }
    }

    /// When synced, the instant the sync timeout expires; otherwise never.
    #[must_use]
    pub fn deadline(&self) -> Instant {
        match self.state {
            State::Synced { anchor } => anchor.local + SYNC_LOSS_TIMEOUT,
            State::Unsynced { .. } => Instant::NEVER,
        }
    }
}

/// How far `later`'s global time is from what `earlier` predicts for the same instant.
fn disagreement(earlier: &Sample, later: &Sample) -> u64 {
    earlier.global_at(later.local).abs_diff(later.global)
}

#[cfg(test)]
mod tests {
    use super::*;

    const N: u16 = 10;

    /// The cycle of `slots` slots, as a schedule with a sync every 500 ms builds it.
    fn cycle(slots: u16) -> Cycle {
        <crate::simplecan::schedule::Schedule>::new(slots, 500 / slots, &[])
            .unwrap()
            .cycle()
    }

    fn master(raw: u8) -> ScId {
        ScId::new(raw).unwrap()
    }

    /// The sync of `from` for `cycle`, `offset` µs into its last slot.
    fn sync(from: u8, cycle: u16, offset: u16) -> SyncPacket {
        SyncPacket::new(master(from), cycle, offset).unwrap()
    }

    fn at_us(micros: u64) -> Instant {
        Instant::from_micros(micros)
    }

    /// A tracker that received cycle 0's and cycle 10's syncs of master 30h 100 ms apart.
    fn synced(max_buffering: Duration) -> SyncTracker {
        let mut tracker = SyncTracker::new(cycle(N), max_buffering);
        let _ = tracker.on_sync(at_us(1_000_000), &sync(0x30, 0, 0));
        let change = tracker.on_sync(at_us(1_100_000), &sync(0x30, 10, 0));
        assert_eq!(
            change,
            Some(Change::Synced {
                master: master(0x30)
            })
        );
        tracker
    }

    #[test]
    fn sc_req_29_an_scl_starts_unsynced_without_a_global_time() {
        let mut tracker = SyncTracker::new(cycle(N), Duration::ZERO);
        assert!(!tracker.is_synced());
        assert_eq!(tracker.global_time(at_us(0)), None);
        assert_eq!(tracker.local_instant(0), None);
        // One sync is not enough.
        assert_eq!(tracker.on_sync(at_us(5_000), &sync(0x30, 0, 0)), None);
        assert!(!tracker.is_synced());
        assert_eq!(tracker.global_time(at_us(5_000)), None);
        assert_eq!(tracker.deadline(), Instant::NEVER);
    }

    /// Two syncs 100 ms apart by the master's time: synced when the receiver measured
    /// between 98 and 102 ms, not at 97.999 or 102.001.
    #[test]
    fn sc_req_30_synced_after_two_syncs_within_2_ms() {
        for (gap, synced) in [
            (97_999, false),
            (98_000, true),
            (100_000, true),
            (102_000, true),
            (102_001, false),
        ] {
            let mut tracker = SyncTracker::new(cycle(N), Duration::ZERO);
            let _ = tracker.on_sync(at_us(1_000_000), &sync(0x30, 0, 0));
            let _ = tracker.on_sync(at_us(1_000_000 + gap), &sync(0x30, 10, 0));
            assert_eq!(tracker.is_synced(), synced, "gap {gap} µs");
        }
    }

    #[test]
    fn sc_req_30_two_syncs_from_different_masters_do_not_sync() {
        let mut tracker = SyncTracker::new(cycle(N), Duration::ZERO);
        let _ = tracker.on_sync(at_us(0), &sync(0x30, 0, 0));
        let _ = tracker.on_sync(at_us(100_000), &sync(0x31, 10, 0));
        assert!(!tracker.is_synced());
        // The second master's next sync completes its pair.
        let _ = tracker.on_sync(at_us(200_000), &sync(0x31, 20, 0));
        assert_eq!(tracker.master(), Some(master(0x31)));
    }

    /// The global time once synced: the second sync's, advancing with the local clock.
    #[test]
    fn sc_req_30_the_global_time_follows_the_second_sync() {
        let tracker = synced(Duration::ZERO);
        // Cycle 10's last slot starts at (10 × 10 + 9) ms.
        assert_eq!(tracker.global_time(at_us(1_100_000)), Some(109_000));
        assert_eq!(tracker.global_time(at_us(1_100_500)), Some(109_500));
        assert_eq!(tracker.local_instant(109_000), Some(at_us(1_100_000)));
        assert_eq!(tracker.local_instant(100_000), Some(at_us(1_091_000)));
    }

    /// SC_REQ_33: the stated maximum buffering time is added to every sync's age.
    #[test]
    fn sc_req_33_the_buffering_time_is_added_to_every_sync() {
        let tracker = synced(Duration::from_micros(300));
        assert_eq!(tracker.global_time(at_us(1_100_000)), Some(109_300));
    }

    #[test]
    fn sc_req_32_unsynced_after_2000_ms_without_a_sync() {
        let mut tracker = synced(Duration::ZERO);
        assert_eq!(tracker.deadline(), at_us(3_100_000));
        assert_eq!(tracker.poll(at_us(3_099_999)), None);
        assert_eq!(
            tracker.poll(at_us(3_100_000)),
            Some(Change::Unsynced(Unsynced::Timeout))
        );
        assert!(!tracker.is_synced());
        assert_eq!(tracker.global_time(at_us(3_100_000)), None);
        // A sync in time restarts the 2000 ms.
        let mut tracker = synced(Duration::ZERO);
        let _ = tracker.on_sync(at_us(1_600_000), &sync(0x30, 60, 0));
        assert_eq!(tracker.deadline(), at_us(3_600_000));
    }

    #[test]
    fn sc_req_30_a_sync_from_the_master_that_disagrees_unsyncs() {
        let mut tracker = synced(Duration::ZERO);
        assert_eq!(
            tracker.on_sync(at_us(1_200_000), &sync(0x30, 21, 0)),
            Some(Change::Unsynced(Unsynced::Disagreed { by_micros: 10_000 }))
        );
        assert!(!tracker.is_synced());
    }

    /// Section 7: a lower SC-ID taking over with the network's time moves the tracker to it;
    /// a higher master's sync does not touch the time.
    #[test]
    fn sc_req_25_a_takeover_by_a_lower_sc_id_keeps_the_tracker_synced() {
        let mut tracker = synced(Duration::ZERO);
        assert_eq!(tracker.on_sync(at_us(1_150_000), &sync(0x40, 15, 0)), None);
        assert_eq!(tracker.master(), Some(master(0x30)));
        let mut tracker = SyncTracker::new(cycle(N), Duration::ZERO);
        let _ = tracker.on_sync(at_us(0), &sync(0x40, 0, 0));
        let _ = tracker.on_sync(at_us(100_000), &sync(0x40, 10, 0));
        assert_eq!(
            tracker.on_sync(at_us(150_000), &sync(0x30, 15, 0)),
            Some(Change::Synced {
                master: master(0x30)
            })
        );
        assert_eq!(tracker.master(), Some(master(0x30)));
    }

    /// The 16-bit cycle number wraps; the tracker's time does not.
    #[test]
    fn the_cycle_number_is_unwrapped_across_its_wrap() {
        let mut tracker = SyncTracker::new(cycle(N), Duration::ZERO);
        let _ = tracker.on_sync(at_us(0), &sync(0x30, 65_530, 0));
        let _ = tracker.on_sync(at_us(100_000), &sync(0x30, 4, 0));
        assert!(tracker.is_synced());
        assert_eq!(
            tracker.global_time(at_us(100_000)),
            Some((65_540 * 10 + 9) * 1000)
        );
    }

    /// SC_REQ_31: a receiver clock 50 ppm fast against the master's, syncs 500 ms apart for
    /// an hour: never more than 25 µs off at a sync, far inside 2 ms. The budget itself: over
    /// the longest sync-less 2000 ms, 1000 ppm would use all 2 ms, 1001 ppm more.
    #[test]
    fn sc_req_31_a_clock_50_ppm_off_stays_synced() {
        let local = |global_us: u64| at_us(global_us + global_us / 20_000);
        let mut tracker = SyncTracker::new(cycle(N), Duration::ZERO);
        for n in 0..7200u64 {
            let cycle = n * 50;
            let global = (cycle * 10 + 9) * 1000;
            let change = tracker.on_sync(local(global), &sync(0x30, cycle as u16, 0));
            assert!(!matches!(change, Some(Change::Unsynced(_))), "sync {n}");
            if n > 0 {
                assert!(tracker.is_synced());
            }
        }
        for (ppm, synced) in [(1000, true), (1001, false)] {
            let mut tracker = SyncTracker::new(cycle(200), Duration::ZERO);
            let _ = tracker.on_sync(at_us(0), &sync(0x30, 0, 0));
            // 10 cycles of 200 ms = 2000 ms by the master, 2000 ms × (1 + ppm) locally.
            let _ = tracker.on_sync(at_us(2_000_000 + 2 * ppm), &sync(0x30, 10, 0));
            assert_eq!(tracker.is_synced(), synced, "{ppm} ppm");
        }
    }
}
