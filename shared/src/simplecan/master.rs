//! Master election, sync transmission and the several-masters check, `docs/simplecan.md`
//! section 7 (SC_REQ_22, SC_REQ_23, SC_REQ_25, SC_REQ_26, SC_REQ_27, SC_REQ_28).
//!
//! [`Master`] is the role of one potential master: it listens first, for one maximum sync
//! interval (a late joiner must find the network's master and synchronise to it, SC_REQ_25)
//! and then `t_wait` (SC_REQ_27); hearing a lower SC-ID it follows, hearing a higher one it
//! synchronises and takes over; active, it sends a sync in the last slot every k cycles
//! (SC_REQ_22), each confirmed by the controller within 2 ms or aborted (SC_REQ_23), and after
//! an abort or a transmit error it backs off `t_wait` (SC_REQ_28); 2000 ms without the sync
//! of the master it follows (SC_REQ_32) and it listens `t_wait` and starts on its own. Its
//! synchronisation to another master is [`super::sync::SyncTracker`]'s; the SCL hands the
//! tracker's change to synced in ([`Master::on_synced`]).
//!
//! [`MasterMonitor`] is every SCL's check of SC_REQ_26.

use super::frame::SyncPacket;
use super::schedule::{Cycle, Schedule};
use super::{MAX_SYNC_INTERVAL, SYNC_CONFIRMATION_TIMEOUT, SYNC_LOSS_TIMEOUT, ScId};
use crate::time::{Duration, Instant, expired};

/// How far back [`Master::align`] moves a time base at one sync: the most two clocks within
/// 50 ppm of the true time (SC_REQ_31) part over the longest sync interval (2 × 50 ppm ×
/// 500 ms = 50 µs). Ahead it follows the other channel's time in full (the caller checked
/// it); back only this far, because a sync that waited for the bus behind other frames says
/// a time older than the true one by the wait, which a single reading cannot tell apart.
pub const ALIGN_BACK_LIMIT: Duration = Duration::from_micros(50);

/// What the master asks of the controller.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[must_use = "the sync must be sent, or the pending transmission aborted"]
pub enum Action {
    /// Send this sync now (encode it with the node hash of the master's SC-ID), and report
    /// [`Master::on_transmitted`] or [`Master::on_transmit_error`].
    Send(SyncPacket),
    /// Abort the pending sync and clear the transmit buffer (SC_REQ_23, SC_REQ_28).
    Abort,
}

/// The master's own time base while it has one: global time `global` at local `local`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
struct Anchor {
    local: Instant,
    global: u64,
}

impl Anchor {
    #[cfg_attr(target_os = "none", inline(never))]
    fn global_at(&self, now: Instant) -> u64 {
        self.global
            .saturating_add(now.saturating_since(self.local).as_micros())
    }

    /// The local instant of a global time at or after the anchor's.
    fn local_at(&self, global: u64) -> Instant {
        self.local
            .saturating_add(Duration::from_micros(global.saturating_sub(self.global)))
    }
}

/// The role's state; the time base lives in the states that have one, so an active master
/// without one cannot be written down.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum State {
    /// Listening until `until`; then active, on `anchor` after a back-off, else on a new time.
    Listening {
        until: Instant,
        anchor: Option<Anchor>,
    },
    /// A master with a lower SC-ID is active; its last sync was heard at `heard`.
    Following { master: ScId, heard: Instant },
    /// A master with a higher SC-ID is active (last heard at `heard`): synchronise to it,
    /// then take over.
    TakingOver { heard: Instant },
    /// Active: the next sync is due at `next_sync`.
    Active { anchor: Anchor, next_sync: Instant },
    /// A sync of cycle `cycle` was handed out; its confirmation is due by `deadline`.
    Confirming {
        anchor: Anchor,
        deadline: Instant,
        cycle: u64,
    },
}

/// The master role of one SCL.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Master {
    id: ScId,
    cycle: Cycle,
    sync_every_cycles: u16,
    state: State,
}

impl Master {
    /// A potential master whose lowest transmitted SC-ID is `id`, on `schedule`'s network,
    /// starting at `now`: it listens for 500 ms and then `t_wait` before its first sync.
    pub fn new<const P: usize>(id: ScId, schedule: &Schedule<P>, now: Instant) -> Self {
        Master {
            id,
            cycle: schedule.cycle(),
            sync_every_cycles: schedule.sync_every_cycles(),
            state: State::Listening {
                until: now + MAX_SYNC_INTERVAL + id.t_wait(),
                anchor: None,
            },
        }
    }

    /// `true` while this SCL is the active master (sending, or waiting for a confirmation).
    pub const fn is_active(&self) -> bool {
        matches!(self.state, State::Active { .. } | State::Confirming { .. })
    }

    /// The global time at `now` while active: the time this master gives the network.
    pub fn global_time(&self, now: Instant) -> Option<u64> {
        match self.state {
            State::Active { anchor, .. } | State::Confirming { anchor, .. } => {
                Some(anchor.global_at(now))
            }
            _ => None,
        }
    }

    /// A checked sync from `from` arrived at `now`.
    pub fn on_sync(&mut self, now: Instant, from: ScId) -> Option<Action> {
        if from < self.id {
            let pending = matches!(self.state, State::Confirming { .. });
            let master = match self.state {
                State::Following { master, .. } => master.min(from),
                _ => from,
            };
            // A lower SC-ID wins (SC_REQ_25): follow it, and withdraw a sync not yet out.
            self.state = State::Following { master, heard: now };
            return pending.then_some(Action::Abort);
        }
        if from > self.id
            && matches!(
                self.state,
                State::Listening { .. } | State::TakingOver { .. }
            )
        {
            // A late joiner synchronises to the network's master first (SC_REQ_25).
            self.state = State::TakingOver { heard: now };
        }
        None
    }

    /// The SCL's tracker became synced, with global time `global` at `now`: a master waiting
    /// to take over does so, continuing the network's time and cycle numbers, with its first
    /// sync in the last slot of the next cycle (the master it replaces sends at most every
    /// 100 ms, so not then).
    pub fn on_synced(&mut self, now: Instant, global: u64) {
        if let State::TakingOver { .. } = self.state {
            let anchor = Anchor { local: now, global };
            let (cycle, _) = self.cycle.position(global);
            let first = self.cycle.slot_start(cycle + 1, self.cycle.sync_slot());
            self.state = State::Active {
                anchor,
                next_sync: anchor.local_at(first),
            };
        }
    }

    /// The controller confirmed the sync on the bus (SC_REQ_23). The next one is due k
    /// cycles after this one's slot, whenever the confirmation came.
    pub fn on_transmitted(&mut self) {
        if let State::Confirming { anchor, cycle, .. } = self.state {
            let next = cycle + u64::from(self.sync_every_cycles);
            let global = self.cycle.slot_start(next, self.cycle.sync_slot());
            self.state = State::Active {
                anchor,
                next_sync: anchor.local_at(global),
            };
        }
    }

    /// The cycle of the sync handed out and not confirmed yet, if one is.
    pub const fn confirming_cycle(&self) -> Option<u64> {
        match self.state {
            State::Confirming { cycle, .. } => Some(cycle),
            _ => None,
        }
    }

    /// The time base moves so that the global time is `global` at `now`; the next sync stays
    /// due at the same global time, now by the new time base. For the channel of a
    /// dual-channel device that does not transmit (Model A, SC_REQ_10): it computes its own
    /// syncs on its own clock, checks the other channel's on the bus against them and takes
    /// the other channel's time from each (`dual_channel::simplecan`), so that two crystals
    /// within 50 ppm (SC_REQ_31) part by at most a sync interval's drift. Nothing while not
    /// active.
    ///
    /// A `global` behind its own time at `now` moves it back by [`ALIGN_BACK_LIMIT`] at most.
    pub fn align(&mut self, now: Instant, global: u64) {
        let Some(own) = self.global_time(now) else {
            return;
        };
        let global = global.max(own.saturating_sub(ALIGN_BACK_LIMIT.as_micros()));
        let aligned = Anchor { local: now, global };
        match &mut self.state {
            State::Active { anchor, next_sync } => {
                let due = anchor.global_at(*next_sync);
                *anchor = aligned;
                *next_sync = aligned.local_at(due);
            }
            State::Confirming { anchor, .. } => *anchor = aligned,
            _ => {}
        }
    }

    /// The controller reported an error while sending the sync (a collision, say) at `now`:
    /// abort it and back off `t_wait` (SC_REQ_28).
    pub fn on_transmit_error(&mut self, now: Instant) -> Option<Action> {
        if let State::Confirming { anchor, .. } = self.state {
            self.back_off(now, anchor);
            Some(Action::Abort)
        } else {
            None
        }
    }

    /// Listen `t_wait` (SC_REQ_28), keeping the time base for the retry.
    fn back_off(&mut self, now: Instant, anchor: Anchor) {
        self.state = State::Listening {
            until: now + self.id.t_wait(),
            anchor: Some(anchor),
        };
    }

    /// What is due at `now`.
    pub fn poll(&mut self, now: Instant) -> Option<Action> {
        match self.state {
            State::Following { heard, .. } | State::TakingOver { heard }
                if expired(heard + SYNC_LOSS_TIMEOUT, now) =>
            {
                // 2000 ms without the master's sync (SC_REQ_32): no master is active. Those
                // 2000 ms were the listening a late joiner does; `t_wait` more orders the
                // potential masters (SC_REQ_27), then this one starts on a time of its own.
                self.state = State::Listening {
                    until: now + self.id.t_wait(),
                    anchor: None,
                };
                self.poll(now)
            }
            State::Listening { until, anchor } if expired(until, now) => {
                // Alone (first start, or after losing the network): now is the start of the
                // last slot of cycle 0. After a back-off: the time base it had.
                let anchor = anchor.unwrap_or(Anchor {
                    local: now,
                    global: self.cycle.slot_start(0, self.cycle.sync_slot()),
                });
                let (_, global) = self
                    .cycle
                    .next_slot(anchor.global_at(now), self.cycle.sync_slot());
                self.state = State::Active {
                    anchor,
                    next_sync: anchor.local_at(global),
                };
                // Once more: the sync is due now or later, and is sent or scheduled.
                self.poll(now)
            }
            State::Active { anchor, next_sync } if expired(next_sync, now) => {
                let global = anchor.global_at(now);
                let (cycle, slot) = self.cycle.position(global);
                let slot_start = self.cycle.slot_start(cycle, slot);
                // Within the 1 ms slot the offset is below 1000; the cycle number is sent
                // modulo 65536.
                let offset = u16::try_from(global - slot_start).unwrap_or(u16::MAX);
                let sync = SyncPacket::new(self.id, cycle as u16, offset)
                    .filter(|_| slot == self.cycle.sync_slot());
                let Some(sync) = sync else {
                    // Polled after the last slot ended: the next cycle's last slot.
                    let (_, next) = self.cycle.next_slot(global, self.cycle.sync_slot());
                    self.state = State::Active {
                        anchor,
                        next_sync: anchor.local_at(next),
                    };
                    return None;
                };
                self.state = State::Confirming {
                    anchor,
                    deadline: now + SYNC_CONFIRMATION_TIMEOUT,
                    cycle,
                };
                Some(Action::Send(sync))
            }
            State::Confirming {
                anchor, deadline, ..
            } if expired(deadline, now) => {
                // Not confirmed within 2 ms (SC_REQ_23): abort, then back off (SC_REQ_28).
                self.back_off(now, anchor);
                Some(Action::Abort)
            }
            _ => None,
        }
    }

    /// When [`poll`](Self::poll) has something to do.
    #[must_use]
    pub const fn deadline(&self) -> Instant {
        match self.state {
            State::Listening { until, .. } => until,
            State::Active { next_sync, .. } => next_sync,
            State::Confirming { deadline, .. } => deadline,
            State::Following { heard, .. } | State::TakingOver { heard } => {
                heard.saturating_add(SYNC_LOSS_TIMEOUT)
            }
        }
    }
}

/// Every SCL's check for several active masters (SC_REQ_26).
///
/// Only the lowest SC-ID may be active (SC_REQ_25), and a master that hears a lower one stops
/// at once; so a sync from a master with a higher SC-ID than one whose sync was seen within
/// the last 2000 ms (the time after which that one counts as gone, SC_REQ_32) means two
/// masters are active. A lower SC-ID after a higher one is a takeover, not a fault. Latched:
/// the safe state lasts until the SCL is reset (SC_REQ_41).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MasterMonitor {
    /// The lowest master heard within the window, and when it was last heard.
    lowest: Option<(ScId, Instant)>,
    several: Option<(ScId, ScId)>,
}

/// Two masters found active at once.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SeveralMasters {
    /// The master that should be the only one.
    pub lower: ScId,
    /// The master that kept sending.
    pub higher: ScId,
}

impl MasterMonitor {
    /// A monitor that has heard no master yet.
    pub const fn new() -> Self {
        MasterMonitor {
            lowest: None,
            several: None,
        }
    }

    /// A checked sync from `from` at `now`; `Err` once several masters were seen (latched).
    #[must_use = "several masters means the safe state (SC_REQ_26)"]
    pub fn on_sync(&mut self, now: Instant, from: ScId) -> Result<(), SeveralMasters> {
        if self.several.is_none() {
            match self.lowest {
                Some((lower, heard))
                    if lower < from && !expired(heard + SYNC_LOSS_TIMEOUT, now) =>
                {
                    self.several = Some((lower, from));
                }
                _ => self.lowest = Some((from, now)),
            }
        }
        match self.several {
            Some((lower, higher)) => Err(SeveralMasters { lower, higher }),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const N: u16 = 10;
    const K: u16 = 10;

    fn sc(raw: u8) -> ScId {
        ScId::new(raw).unwrap()
    }

    fn schedule() -> Schedule {
        <Schedule>::new(N, K, &[]).unwrap()
    }

    fn at_us(micros: u64) -> Instant {
        Instant::from_micros(micros)
    }

    fn at(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    /// Polls `master` at its deadline (no later than `until`), confirming every sync at once;
    /// the instants it sent at.
    fn run(master: &mut Master, until: Instant) -> std::vec::Vec<(Instant, SyncPacket)> {
        let mut sent = std::vec::Vec::new();
        loop {
            let now = master.deadline();
            if now > until {
                return sent;
            }
            match master.poll(now) {
                Some(Action::Send(sync)) => {
                    sent.push((now, sync));
                    master.on_transmitted();
                }
                Some(Action::Abort) => panic!("unexpected abort at {now:?}"),
                None => {}
            }
        }
    }

    #[test]
    fn sc_req_27_a_lone_master_waits_500_ms_and_t_wait_before_its_first_sync() {
        for (raw, first) in [(0x30, 500), (0x33, 515), (0x7F, 895)] {
            let mut master = Master::new(sc(raw), &schedule(), at(0));
            assert_eq!(master.deadline(), at(first));
            assert_eq!(master.poll(at_us(first * 1000 - 1)), None);
            assert!(!master.is_active());
            let Some(Action::Send(sync)) = master.poll(at(first)) else {
                panic!("no sync from {raw:X}h at {first} ms");
            };
            assert_eq!(
                (sync.master(), sync.cycle(), sync.offset_micros()),
                (sc(raw), 0, 0)
            );
        }
    }

    /// SC_REQ_31 with two channels: aligned to the other channel's time (100 µs ahead of its
    /// own), the master keeps its next sync due at the same global time, now 100 µs earlier
    /// on its own clock; a master that is not active has no time to move.
    #[test]
    fn sc_req_31_an_aligned_master_keeps_its_next_sync_at_the_same_global_time() {
        let mut master = Master::new(sc(0x30), &schedule(), at(0));
        master.align(at(1), 5_000);
        assert_eq!(master.global_time(at(1)), None, "listening: nothing moves");
        let Some(Action::Send(_)) = master.poll(at(500)) else {
            panic!("no sync at 500 ms");
        };
        assert_eq!(master.confirming_cycle(), Some(0));
        master.on_transmitted();
        assert_eq!(master.confirming_cycle(), None);
        assert_eq!(master.deadline(), at(600));
        // Its own time at 500.3 ms is 9,300 µs (the sync slot of cycle 0 began at 500 ms).
        master.align(at_us(500_300), 9_400);
        assert_eq!(master.global_time(at_us(500_300)), Some(9_400));
        assert_eq!(master.deadline(), at_us(599_900));
        let Some(Action::Send(sync)) = master.poll(at_us(599_900)) else {
            panic!("no sync at 599.9 ms");
        };
        assert_eq!((sync.cycle(), sync.offset_micros()), (10, 0));
        master.on_transmitted();
        // Behind its own time by 1 ms (a sync that waited for the bus, say): back 50 µs only.
        let own = master.global_time(at(600)).unwrap();
        master.align(at(600), own - 1_000);
        assert_eq!(
            master.global_time(at(600)),
            Some(own - ALIGN_BACK_LIMIT.as_micros())
        );
    }

    /// Masters powered up together: the lowest SC-ID sends first, the next hears it within
    /// its 5 ms and follows; only one is ever active.
    #[test]
    fn sc_req_27_masters_started_together_do_not_collide() {
        let mut low = Master::new(sc(0x30), &schedule(), at(0));
        let mut high = Master::new(sc(0x31), &schedule(), at(0));
        assert!(matches!(low.poll(at(500)), Some(Action::Send(_))));
        low.on_transmitted();
        assert_eq!(high.on_sync(at_us(500_300), sc(0x30)), None);
        assert_eq!(high.deadline(), at_us(2_500_300));
        assert_eq!(high.poll(at(505)), None);
        assert!(low.is_active() && !high.is_active());
    }

    /// SC_REQ_22: one sync every k × N = 100 ms, in the last slot, for a minute.
    #[test]
    fn sc_req_22_the_active_master_sends_every_100_to_500_ms() {
        let mut master = Master::new(sc(0x30), &schedule(), at(0));
        let sent = run(&mut master, at(60_500));
        assert_eq!(sent.len(), 601);
        for pair in sent.windows(2) {
            let gap = pair[1].0.saturating_since(pair[0].0);
            assert_eq!(gap, Duration::from_millis(100));
            assert_eq!(pair[1].1.cycle(), pair[0].1.cycle().wrapping_add(K));
        }
        for (_, sync) in &sent {
            assert_eq!(sync.offset_micros(), 0);
        }
        // The slowest schedule allowed: every 50 cycles of 10 ms.
        let slow = <Schedule>::new(N, 50, &[]).unwrap();
        let mut master = Master::new(sc(0x30), &slow, at(0));
        let sent = run(&mut master, at(10_500));
        for pair in sent.windows(2) {
            assert_eq!(
                pair[1].0.saturating_since(pair[0].0),
                Duration::from_millis(500)
            );
        }
    }

    /// Polled after the last slot ended (a late executor): no sync outside the last slot
    /// (SC_REQ_21); the next cycle's last slot instead.
    #[test]
    fn sc_req_21_a_late_poll_sends_in_the_next_last_slot_not_outside_it() {
        let mut master = Master::new(sc(0x30), &schedule(), at(0));
        assert!(matches!(master.poll(at(500)), Some(Action::Send(_))));
        master.on_transmitted();
        assert_eq!(master.deadline(), at(600));
        assert_eq!(master.poll(at(601)), None);
        assert_eq!(master.deadline(), at(610));
        let Some(Action::Send(sync)) = master.poll(at_us(610_400)) else {
            panic!("no sync in the next last slot");
        };
        assert_eq!((sync.cycle(), sync.offset_micros()), (11, 400));
    }

    /// SC_REQ_23: not confirmed within 2 ms, the sync is aborted at exactly 2 ms; the master
    /// then backs off t_wait (SC_REQ_28) and sends in the next last slot after it.
    #[test]
    fn sc_req_23_an_unconfirmed_sync_is_aborted_after_2_ms() {
        let mut master = Master::new(sc(0x32), &schedule(), at(0));
        assert!(matches!(master.poll(at(510)), Some(Action::Send(_))));
        assert_eq!(master.deadline(), at(512));
        assert_eq!(master.poll(at_us(511_999)), None);
        assert_eq!(master.poll(at(512)), Some(Action::Abort));
        assert!(!master.is_active());
        // t_wait of 32h is 10 ms: listening until 522 ms, then the next last slot (529 ms
        // on this master's time, whose cycle 0 last slot was at 510 ms).
        assert_eq!(master.deadline(), at(522));
        assert_eq!(master.poll(at(522)), None);
        assert_eq!(master.deadline(), at(530));
        let Some(Action::Send(sync)) = master.poll(at(530)) else {
            panic!("no retry");
        };
        assert_eq!(sync.cycle(), 2);
    }

    /// SC_REQ_28: a transmit error aborts the sync and backs off t_wait.
    #[test]
    fn sc_req_28_after_a_transmit_error_the_master_backs_off_t_wait() {
        let mut master = Master::new(sc(0x34), &schedule(), at(0));
        assert!(matches!(master.poll(at(520)), Some(Action::Send(_))));
        assert_eq!(
            master.on_transmit_error(at_us(520_100)),
            Some(Action::Abort)
        );
        assert_eq!(master.deadline(), at_us(540_100));
        assert_eq!(master.poll(at_us(540_099)), None);
        // A lower master heard during the back-off wins.
        assert_eq!(master.on_sync(at(530), sc(0x30)), None);
        assert_eq!(master.poll(at(600)), None);
        assert!(!master.is_active());
    }

    /// SC_REQ_25: an active master hearing a lower SC-ID stops at once, even with a sync
    /// waiting for its confirmation.
    #[test]
    fn sc_req_25_the_lowest_sc_id_wins() {
        let mut master = Master::new(sc(0x40), &schedule(), at(0));
        assert!(matches!(master.poll(at(580)), Some(Action::Send(_))));
        assert_eq!(
            master.on_sync(at_us(580_100), sc(0x35)),
            Some(Action::Abort)
        );
        assert!(!master.is_active());
        assert_eq!(master.deadline(), at_us(2_580_100));
        // A higher master's sync does not make an active master yield.
        let mut master = Master::new(sc(0x30), &schedule(), at(0));
        let _ = run(&mut master, at(600));
        assert_eq!(master.on_sync(at(650), sc(0x31)), None);
        assert!(master.is_active());
    }

    /// SC_REQ_25: a late joiner with a lower SC-ID first synchronises to the active master,
    /// then takes over with the network's cycle numbers, in the next cycle's last slot.
    #[test]
    fn sc_req_25_a_late_joiner_synchronises_before_it_takes_over() {
        let mut joiner = Master::new(sc(0x30), &schedule(), at(10_000));
        assert_eq!(joiner.on_sync(at(10_040), sc(0x45)), None);
        assert_eq!(joiner.deadline(), at(12_040));
        assert_eq!(joiner.poll(at(10_600)), None, "no sync before synchronised");
        // The tracker synced on the second sync: global time 5_009_000 µs (cycle 500's last
        // slot) at 10_140 ms.
        joiner.on_synced(at(10_140), 5_009_000);
        assert!(joiner.is_active());
        assert_eq!(joiner.deadline(), at(10_150));
        let Some(Action::Send(sync)) = joiner.poll(at(10_150)) else {
            panic!("no takeover");
        };
        assert_eq!((sync.master(), sync.cycle()), (sc(0x30), 501));
    }

    /// The lost master: 2000 ms after its last sync (SC_REQ_32) a follower listens t_wait
    /// and starts on its own time, the lowest remaining SC-ID first.
    #[test]
    fn sc_req_25_a_lost_master_is_replaced_after_the_sync_loss_timeout() {
        let mut follower = Master::new(sc(0x31), &schedule(), at(0));
        let _ = follower.on_sync(at(100), sc(0x30));
        assert_eq!(follower.deadline(), at(2_100));
        assert_eq!(follower.poll(at_us(2_099_999)), None);
        assert_eq!(follower.poll(at(2_100)), None);
        assert_eq!(follower.deadline(), at(2_105));
        let Some(Action::Send(sync)) = follower.poll(at(2_105)) else {
            panic!("no sync from the follower");
        };
        assert_eq!((sync.master(), sync.cycle()), (sc(0x31), 0));
    }

    /// A higher master that vanishes before this one synchronised to it: 2000 ms after its
    /// last sync this one starts on its own (t_wait of 30h is 0, so at once).
    #[test]
    fn sc_req_25_a_master_waiting_to_take_over_does_not_wait_for_ever() {
        let mut joiner = Master::new(sc(0x30), &schedule(), at(0));
        let _ = joiner.on_sync(at(40), sc(0x45));
        assert_eq!(joiner.deadline(), at(2_040));
        assert!(matches!(joiner.poll(at(2_040)), Some(Action::Send(_))));
    }

    #[test]
    fn sc_req_26_one_master_and_a_takeover_are_not_several() {
        let mut monitor = MasterMonitor::new();
        for n in 0..30 {
            assert_eq!(monitor.on_sync(at(n * 100), sc(0x40)), Ok(()));
        }
        // A lower SC-ID takes over.
        assert_eq!(monitor.on_sync(at(3_050), sc(0x30)), Ok(()));
        assert_eq!(monitor.on_sync(at(3_150), sc(0x30)), Ok(()));
    }

    #[test]
    fn sc_req_26_a_higher_master_still_sending_means_the_safe_state() {
        let mut monitor = MasterMonitor::new();
        assert_eq!(monitor.on_sync(at(0), sc(0x40)), Ok(()));
        assert_eq!(monitor.on_sync(at(50), sc(0x30)), Ok(()));
        let several = SeveralMasters {
            lower: sc(0x30),
            higher: sc(0x40),
        };
        assert_eq!(monitor.on_sync(at(100), sc(0x40)), Err(several));
        // Latched: the lower master's next sync does not clear it.
        assert_eq!(monitor.on_sync(at(150), sc(0x30)), Err(several));
    }

    /// The window is the sync loss timeout: a higher master 1999.999 ms after the lower one's
    /// last sync is a second master; at 2000 ms the lower one is gone.
    #[test]
    fn sc_req_26_a_master_silent_for_2000_ms_is_gone() {
        let mut monitor = MasterMonitor::new();
        let _ = monitor.on_sync(at(0), sc(0x30));
        let mut probe = monitor;
        assert!(probe.on_sync(at_us(1_999_999), sc(0x31)).is_err());
        assert_eq!(monitor.on_sync(at(2_000), sc(0x31)), Ok(()));
    }
}
