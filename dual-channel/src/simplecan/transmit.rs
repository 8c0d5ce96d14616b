//! Model A for SimpleCAN transmission (SC_REQ_10): channel A puts the node's packets on the
//! bus; channel B computes each of them itself, with its own core, and checks the one on the
//! bus against its own.
//!
//! Why channel A transmits: it is the channel that speaks for the node on the bus (its
//! boot-up, SDO answers, EMCY, the plain SRDO frames), and channel B's controller receives
//! what A's sends (one transceiver, Model III), so B can see every packet of the node and A
//! cannot see its own. B's core runs the same SimpleCAN layer on the same configuration and
//! the same received frames, on its own samples and its own clock, so it hands out the same
//! packets at the same slots (within the sample window and the sync tolerance below); the
//! runtime keeps them here instead of sending them.
//!
//! - A data packet must come back from the bus **bit for bit** as B computed it (value,
//!   cycle stamp, CRC), within its slot (1 ms, docs/simplecan.md section 5): otherwise
//!   [`TransmitFault::Mismatch`] or, at the end of the slot, [`TransmitFault::Missing`].
//! - **Syncs, each channel on its own clock.** B's master decides on B's own clock when its
//!   syncs are due (listening, `t_wait`, the cycle: `shared::simplecan::master`), and A's sync
//!   on the bus is checked against B's own: the same master and cycle, a CRC B's own decoder
//!   accepts, within 2 ms of B's (SC_REQ_23), and **not ahead of B's own time** by more than
//!   [`SYNC_OFFSET_TOLERANCE`]: the global time A's sync gives (its cycle and offset, plus the
//!   buffering time the node states, 5E00h:03, as every receiver takes it, SC_REQ_33) against
//!   B's global time when it hears it. A sync that agrees is confirmed to B's core with A's
//!   frame, and B's master takes its time from it (`Device::on_partner_transmitted`), the
//!   buffering time included: B's time is then A's plus the stated buffering beyond the real
//!   delay, which is why later syncs are judged with it. **The first sync** after entering
//!   Operational is judged without it: both masters started on their own clocks at NMT start,
//!   B's time is A's (within the loops' handling of that frame), and A's time plus a stated
//!   buffering that exceeds the sync's real delay by more than the tolerance (a node may state
//!   any buffering time up to its guarantee, SC_REQ_33; the emulated network's file states
//!   more than its sync's frame time) would be ahead of B's own although A's clock is not: a mismatch on the
//!   node's first sync. Without it the first sync's check is lenient by the real delay (at
//!   least the sync's frame time), once. Taking A's time at every sync, two clocks within
//!   50 ppm of each other (SC_REQ_31) part by at most a sync interval's drift
//!   (50 µs at 500 ms), while a clock of A's running ahead of B's by more than the tolerance
//!   over one sync interval (2000 ppm at 100 ms, 400 ppm at 500 ms) is a mismatch. Behind,
//!   A's sync cannot be told from one that waited for the bus; 2 ms is the bound there.
//! - **Heard before B computed its own.** The channels' clocks are two (SC_REQ_31): A's time
//!   may run ahead of B's by up to [`SYNC_OFFSET_TOLERANCE`] (the sync check above holds it
//!   there), so A's slot starts first and its packet can come off the bus before B's timer
//!   reaches the same slot, once A's lead exceeds the frame time (an 8-byte frame at
//!   1 Mbit/s takes about 130 µs). Such a packet waits, at most `heard_ahead`
//!   ([`Bounds::heard_ahead`], the same 200 µs on a board), for B to compute its own, and is
//!   then judged exactly as one heard after it.
//! - A packet of the node (an SC-ID it produces, a sync naming its master SC-ID) that B did
//!   not compute within that time, or a second one before B computed any, is a mismatch:
//!   A's core is not doing what B's does.
//! - **The sample window.** Each channel's core reads the produced value from its own sample
//!   (its own contact of an emergency stop) at the start of the slot, and two contacts never
//!   move at exactly the same moment: across a slot start A's packet may carry the value
//!   before the change and B's the one after, or the other way round. A data packet that
//!   differs from B's only in its value, with a CRC B's own decoder accepts and B's cycle
//!   stamp, stands for B's when its value is one of B's samples within the window (as for
//!   an SRDO frame, `channel_b::role`): B's previous sample, replaced less than the window
//!   before the packet was heard; B's current sample when the packet is heard (B's sample
//!   changed after B's core read it for its own packet, between B's slot start and A's
//!   packet on the bus); or B's next sample, taken within the window after it (the packet
//!   waits for it, [`TransmitCheck::sampled`]). Otherwise, and at once for any other
//!   difference, it is a mismatch. A SimpleCAN packet cannot wait for the channels' samples
//!   to agree as a changed SRDO frame does: it must go in its slot (section 5).
//!
//! Sans-I/O: fed frames and `now`, it returns faults and its next deadline.

use super::{Decoded, RawFrame};
use shared::time::expired;
use shared::{Duration, Instant};

/// How many produced values channel B keeps a sample history of, and how many of A's
/// packets may wait for B's next sample: one per SDD entry.
const PRODUCED: usize = super::ENTRIES;

/// How far channel A's sync may be ahead of channel B's own time: the global time A's sync
/// gives when B hears it (with the stated buffering time) against B's. Two clocks within
/// 50 ppm (SC_REQ_31) part by 50 µs over the longest sync interval (500 ms), the channels'
/// loops handle NMT start (which starts both masters) within the link latency of each other
/// (about 0.2 ms at most, once, before the first sync aligns them, whose check leaves the
/// stated buffering time out), and from then on B's time carries the stated buffering as A's
/// syncs do: far less than the 2 ms a receiver tolerates (SC_REQ_30).
pub const SYNC_OFFSET_TOLERANCE: Duration = Duration::from_micros(200);

/// How long a data packet of the node may take to appear on the bus: its slot.
pub const DATA_WITHIN: Duration = Duration::from_millis(1);

/// How long a sync of the node may take to appear on the bus (SC_REQ_23).
pub const SYNC_WITHIN: Duration = Duration::from_millis(2);

/// Model A's time bounds in channel B: how long A's packet may take to appear after B computed
/// its own, and how far A's sync may be ahead of B's time. [`Bounds::STANDARD`] is the
/// hardware's and the host's (the slot, SC_REQ_23's 2 ms, [`SYNC_OFFSET_TOLERANCE`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Bounds {
    /// A data packet of the node: [`DATA_WITHIN`].
    pub data_within: Duration,
    /// A sync of the node: [`SYNC_WITHIN`].
    pub sync_within: Duration,
    /// A's sync ahead of B's own time: [`SYNC_OFFSET_TOLERANCE`].
    pub sync_ahead: Duration,
    /// A packet of the node (data or sync) heard before B computed its own: how long it may
    /// wait for B's. On a board [`SYNC_OFFSET_TOLERANCE`]: A's time leads B's by at most
    /// that, and A's frame comes off the bus a frame time after A's slot starts.
    pub heard_ahead: Duration,
}

impl Bounds {
    /// The standard's bounds, as on a board.
    pub const STANDARD: Bounds = Bounds {
        data_within: DATA_WITHIN,
        sync_within: SYNC_WITHIN,
        sync_ahead: SYNC_OFFSET_TOLERANCE,
        heard_ahead: SYNC_OFFSET_TOLERANCE,
    };
}

impl Default for Bounds {
    fn default() -> Self {
        Bounds::STANDARD
    }
}

/// How many of the node's packets may wait for channel A's: a data packet per produced
/// SC-ID and a sync (each waits at most 2 ms, and no two data packets share a slot).
const WAITING: usize = super::ENTRIES + 1;

/// Why the node's packet on the bus is not the one channel B computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TransmitFault {
    /// The packet on the bus differs from B's, or B computed none.
    Mismatch {
        /// The identifier.
        id: u16,
    },
    /// B computed a packet that did not appear on the bus in time.
    Missing {
        /// The identifier.
        id: u16,
    },
}

/// Channel B's samples of a produced value since its latest change: the value before it
/// (`value`), when it changed (`replaced`) and the value since (`current`).
#[derive(Clone, Copy, Debug)]
struct Previous {
    id: u16,
    value: u32,
    replaced: Instant,
    current: u32,
}

/// Channel A's packet on the bus standing for one of channel B's: the `frame` to confirm to
/// B's core as sent (B's own for a data packet, A's for a sync, whose time B's master takes),
/// and when A's came off the bus (`heard`: before B computed its own when heard ahead).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OnBus {
    /// The frame to confirm.
    pub frame: RawFrame,
    /// When channel A's packet was heard on the bus.
    pub heard: Instant,
}

/// Channel A's data packet on the bus, heard at `heard`, whose value is not B's, waiting
/// until `until` for B's next sample to take that value.
#[derive(Clone, Copy, Debug)]
struct Disputed {
    own: RawFrame,
    value: u32,
    heard: Instant,
    until: Instant,
}

/// Channel A's packet heard at `at`, before channel B computed its own, waiting until
/// `until` for B's; `buffering` is the node's stated buffering time when it was heard.
#[derive(Clone, Copy, Debug)]
struct Early {
    heard: RawFrame,
    decoded: Decoded,
    at: Instant,
    until: Instant,
    buffering: Duration,
}

/// Channel B's packets of the node that wait for channel A's on the bus, and A's that wait
/// for B's.
#[derive(Clone, Debug)]
pub struct TransmitCheck {
    window: Duration,
    bounds: Bounds,
    waiting: heapless::Vec<(RawFrame, Instant), WAITING>,
    early: heapless::Vec<Early, WAITING>,
    previous: heapless::Vec<Previous, PRODUCED>,
    disputed: heapless::Vec<Disputed, PRODUCED>,
    /// Whether one of A's syncs agreed since the last reset: B's master took its time from
    /// it, stated buffering included, and later syncs are judged with the buffering.
    aligned: bool,
}

impl TransmitCheck {
    /// Nothing waiting; A's value is accepted when it is one of B's samples within `window`
    /// (the channels' sample window); the standard's time bounds.
    pub fn new(window: Duration) -> Self {
        TransmitCheck {
            window,
            bounds: Bounds::STANDARD,
            waiting: heapless::Vec::new(),
            early: heapless::Vec::new(),
            previous: heapless::Vec::new(),
            disputed: heapless::Vec::new(),
            aligned: false,
        }
    }

    /// [`TransmitCheck::new`] with the time bounds `bounds` instead of the standard's (an
    /// image whose frames take longer to reach B; every image now keeps the standard's),
    /// built where it is kept rather than built and then changed.
    pub fn with_bounds(window: Duration, bounds: Bounds) -> Self {
        TransmitCheck {
            bounds,
            ..Self::new(window)
        }
    }

    /// The time bounds the check applies from now on.
    pub fn set_bounds(&mut self, bounds: Bounds) {
        self.bounds = bounds;
    }

    /// Channel B's own sample of the value it produces on identifier `id` changed at `now`
    /// from `before` to `after`. A packet of A's waiting for that value stands for B's now:
    /// B's own packet, to confirm to B's core as sent.
    pub fn sampled(&mut self, now: Instant, id: u16, before: u32, after: u32) -> Option<OnBus> {
        if before != after {
            let previous = Previous {
                id,
                value: before,
                replaced: now,
                current: after,
            };
            match self.previous.iter_mut().find(|kept| kept.id == id) {
                Some(kept) => *kept = previous,
                // One per produced SC-ID, at most ENTRIES: a value beyond is not kept, and
                // A's packet then has to equal B's own.
                None => {
                    let _ = self.previous.push(previous);
                }
            }
        }
        let disputed = take_first(&mut self.disputed, |disputed| {
            disputed.own.id == id && disputed.value == after
        })?;
        Some(OnBus {
            frame: disputed.own,
            heard: disputed.heard,
        })
    }

    /// B's core handed out `own` at `now`: channel A's must appear by its deadline.
    ///
    /// `Ok(Some(on_bus))` when A's packet was heard already (within [`Bounds::heard_ahead`]) and
    /// stands for `own`, to confirm to B's core as sent; `Ok(None)` when it waits for A's, or
    /// A's early one waits for B's next sample (the window). A packet still waiting on the
    /// same identifier is missing: A's did not come before B computed the next one (with the
    /// standard's bounds its deadline, the slot, has passed by then and the poll reports it
    /// first; a bound as long as the cycle would otherwise let the newer packet hide it).
    pub fn computed(
        &mut self,
        now: Instant,
        own: RawFrame,
    ) -> Result<Option<OnBus>, TransmitFault> {
        if self.waiting.iter().any(|(kept, _)| kept.id == own.id) {
            return Err(TransmitFault::Missing { id: own.id });
        }
        if let Some(early) = take_first(&mut self.early, |early| early.heard.id == own.id) {
            let since = micros_from(now, early.at);
            return self.judge(
                own,
                early.heard,
                early.decoded,
                early.at,
                since,
                early.buffering,
            );
        }
        let deadline = now + self.within(own.id);
        self.waiting
            .push((own, deadline))
            .map(|()| None)
            .map_err(|_| TransmitFault::Mismatch { id: own.id })
    }

    /// A packet of the node was heard on the bus at `now` (`decoded` by B's own decoder):
    /// `Ok(Some(on_bus))`, the packet to confirm to B's core as sent;
    /// `Ok(None)`, a packet that waits: for B to compute its own (heard ahead of it, at most
    /// [`Bounds::heard_ahead`]), or a data packet whose value waits for B's next sample (the
    /// window).
    ///
    /// A sync that agrees is answered with `heard`, A's own: B's core takes its time from it.
    /// `buffering` is the node's stated buffering time (5E00h:03, SC_REQ_33), added to A's
    /// sync's time from the second sync on (the first: the module's documentation).
    pub fn heard(
        &mut self,
        now: Instant,
        heard: RawFrame,
        decoded: Decoded,
        buffering: Duration,
    ) -> Result<Option<OnBus>, TransmitFault> {
        let mismatch = TransmitFault::Mismatch { id: heard.id };
        let Some((own, deadline)) = take_first(&mut self.waiting, |(own, _)| own.id == heard.id)
        else {
            // Ahead of B's own: it waits for it, one per identifier (a second is not a
            // packet B can still compute: A's core is ahead by a whole cycle).
            if self.early.iter().any(|early| early.heard.id == heard.id) {
                return Err(mismatch);
            }
            let early = Early {
                heard,
                decoded,
                at: now,
                until: now + self.bounds.heard_ahead,
                buffering,
            };
            return self.early.push(early).map(|()| None).map_err(|_| mismatch);
        };
        // B computed its own `within` before the deadline.
        let within = self.within(heard.id);
        let computed =
            Instant::from_micros(deadline.as_micros().saturating_sub(within.as_micros()));
        let since = micros_from(computed, now);
        self.judge(own, heard, decoded, now, since, buffering)
    }

    /// How long after B computed its packet on `id` A's may appear: a sync's bound or a data
    /// packet's.
    fn within(&self, id: u16) -> Duration {
        if id == shared::simplecan::frame::SYNC_IDENTIFIER.raw() {
            self.bounds.sync_within
        } else {
            self.bounds.data_within
        }
    }

    /// Whether A's packet `heard` (`decoded` by B's decoder, heard at `at`, `since` µs after
    /// B computed `own`: negative when heard ahead) stands for B's `own`: `Ok(Some(_))` it
    /// does, `Ok(None)` its value waits for B's next sample, `Err(_)` it does not.
    // Out of line in the images: a marker of the emulator's profile
    // (`emulator::profile::MARKERS`), found in every activation that runs it.
    #[cfg_attr(target_os = "none", inline(never))]
    fn judge(
        &mut self,
        own: RawFrame,
        heard: RawFrame,
        decoded: Decoded,
        at: Instant,
        since: i64,
        buffering: Duration,
    ) -> Result<Option<OnBus>, TransmitFault> {
        let mismatch = TransmitFault::Mismatch { id: heard.id };
        if let Decoded::Sync { .. } = Decoded::fields(&own) {
            let on_bus = OnBus {
                frame: heard,
                heard: at,
            };
            // Until B's time is taken from one of A's syncs it is B's own master's, started
            // with A's at NMT start: A's sync gives its time without the buffering then.
            let buffering = if self.aligned {
                buffering
            } else {
                Duration::ZERO
            };
            if !sync_agrees(&own, decoded, since, buffering, self.bounds.sync_ahead) {
                return Err(mismatch);
            }
            self.aligned = true;
            return Ok(Some(on_bus));
        }
        let on_bus = OnBus {
            frame: own,
            heard: at,
        };
        if own == heard {
            return Ok(Some(on_bus));
        }
        let Some(value) = other_value(&own, &heard, decoded) else {
            return Err(mismatch);
        };
        // B's previous sample within the window, or B's current one: B's sample changed
        // after B's core read it for `own` (between B's slot start and A's packet).
        let recent = self.previous.iter().any(|previous| {
            previous.id == own.id
                && (previous.current == value
                    || (previous.value == value && !expired(previous.replaced + self.window, at)))
        });
        if recent {
            return Ok(Some(on_bus));
        }
        let disputed = Disputed {
            own,
            value,
            heard: at,
            until: at + self.window,
        };
        // At most one of B's packets per produced SC-ID waits, so at most one dispute.
        self.disputed
            .push(disputed)
            .map(|()| None)
            .map_err(|_| mismatch)
    }

    /// `true` when no packet waits (B's for A's, A's heard early, a dispute):
    /// [`poll`](Self::poll) finds no fault and [`deadline`](Self::deadline) is
    /// [`Instant::NEVER`].
    pub fn is_idle(&self) -> bool {
        self.waiting.is_empty() && self.early.is_empty() && self.disputed.is_empty()
    }

    /// The fault of a packet whose deadline has passed at `now`, if any: B's not on the bus
    /// in time, A's heard ahead of a packet B did not compute in time, or A's with a value
    /// B's next sample did not take in time.
    pub fn poll(&self, now: Instant) -> Result<(), TransmitFault> {
        if let Some((own, _)) = self.waiting.iter().find(|(_, at)| expired(*at, now)) {
            return Err(TransmitFault::Missing { id: own.id });
        }
        if let Some(early) = self.early.iter().find(|early| expired(early.until, now)) {
            return Err(TransmitFault::Mismatch { id: early.heard.id });
        }
        match self
            .disputed
            .iter()
            .find(|disputed| expired(disputed.until, now))
        {
            Some(disputed) => Err(TransmitFault::Mismatch {
                id: disputed.own.id,
            }),
            None => Ok(()),
        }
    }

    /// When [`poll`](Self::poll) must run next ([`Instant::NEVER`]: nothing waits).
    pub fn deadline(&self) -> Instant {
        let waiting = self.waiting.iter().map(|(_, at)| *at);
        let early = self.early.iter().map(|early| early.until);
        let disputed = self.disputed.iter().map(|disputed| disputed.until);
        waiting
            .chain(early)
            .chain(disputed)
            .min()
            .unwrap_or(Instant::NEVER)
    }

    /// Forgets every waiting packet (leaving Operational, NMT reset), and that B's time was
    /// taken from A's (both masters start again on their own clocks); B's sample history
    /// stays, it is the inputs', not the layer's.
    pub fn reset(&mut self) {
        self.waiting.clear();
        self.early.clear();
        self.disputed.clear();
        self.aligned = false;
    }
}

/// The value of `heard`, a data packet that differs from B's `own` in its value alone: the
/// same identifier, length and cycle stamp, and a CRC B's decoder accepted (`decoded`).
/// `None` for any other difference.
fn other_value(own: &RawFrame, heard: &RawFrame, decoded: Decoded) -> Option<u32> {
    match (Decoded::fields(own), decoded) {
        (
            Decoded::Data {
                sc_id, cycle_stamp, ..
            },
            Decoded::Data {
                sc_id: heard_id,
                value,
                cycle_stamp: heard_stamp,
            },
        ) if heard.id == own.id
            && heard.len == own.len
            && u16::from(heard_id) == own.id
            && sc_id == heard_id
            && heard_stamp == cycle_stamp =>
        {
            Some(value)
        }
        _ => None,
    }
}

/// Microseconds from `from` to `to`, negative when `to` is earlier (saturating).
fn micros_from(from: Instant, to: Instant) -> i64 {
    let magnitude = |duration: Duration| i64::try_from(duration.as_micros()).unwrap_or(i64::MAX);
    if to >= from {
        magnitude(to.saturating_since(from))
    } else {
        -magnitude(from.saturating_since(to))
    }
}

/// A's sync (`decoded` by B's own decoder, heard `since` µs after B computed `own`, negative
/// when heard ahead of it) stands for B's `own`: the same master and cycle, and the global
/// time it gives with `buffering` not ahead of B's own global time by more than `ahead`
/// ([`SYNC_OFFSET_TOLERANCE`] on a board). B's global time at the hearing is its own sync's
/// plus `since`; both syncs' cycles are the same, so the offsets say it.
fn sync_agrees(
    own: &RawFrame,
    decoded: Decoded,
    since: i64,
    buffering: Duration,
    ahead: Duration,
) -> bool {
    let (
        Decoded::Sync {
            master,
            cycle,
            offset_micros,
        },
        Decoded::Sync {
            master: heard_master,
            cycle: heard_cycle,
            offset_micros: heard_offset,
        },
    ) = (Decoded::fields(own), decoded)
    else {
        return false;
    };
    // Signed: B's time at the hearing is before its own sync's when A's was heard ahead.
    let micros = |duration: Duration| i64::try_from(duration.as_micros()).unwrap_or(i64::MAX);
    let own_time = i64::from(offset_micros).saturating_add(since);
    let given = i64::from(heard_offset).saturating_add(micros(buffering));
    master == heard_master
        && cycle == heard_cycle
        && given <= own_time.saturating_add(micros(ahead))
}

/// Takes the first element of `list` that `matches` out of it, the last element taking its
/// place: what `list.iter().position(..)` and `heapless::Vec::swap_remove` do together, but
/// through a swap of two elements that are disjoint by construction (`split_at_mut`) and a
/// `pop`. `swap_remove`'s `core::ptr::copy`, and the same move through `core::mem::replace`,
/// compile to a call of compiler-builtins' `memmove` (what it costs the images:
/// docs/footprint.md).
fn take_first<T, const N: usize>(
    list: &mut heapless::Vec<T, N>,
    matches: impl Fn(&T) -> bool,
) -> Option<T> {
    let index = list.iter().position(matches)?;
    let last_index = list.len().checked_sub(1)?;
    let (head, tail) = list.split_at_mut(last_index);
    if let (Some(found), Some(last)) = (head.get_mut(index), tail.first_mut()) {
        core::mem::swap(found, last);
    }
    list.pop()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Worked vector 1 of docs/simplecan.md section 9 (SC-ID 30h, value 1, stamp 5).
    const DATA: RawFrame = RawFrame {
        id: 0x030,
        len: 8,
        data: [0x01, 0x00, 0x00, 0x00, 0x05, 0xA4, 0x18, 0x27],
    };

    /// Worked vector 3 (master 30h, cycle 0102h, offset 250 µs).
    const SYNC: RawFrame = RawFrame {
        id: 0x02F,
        len: 8,
        data: [0x30, 0x01, 0x02, 0x00, 0xFA, 0xFD, 0x34, 0x07],
    };

    const WINDOW: Duration = Duration::from_millis(5);

    /// `take_first` leaves a list as `position` and heapless' own `swap_remove` leave it, for
    /// every length up to the capacity, every key searched for (keys repeat, so the first of
    /// them is taken; each element also carries its place, so every move shows) and one that
    /// is not there.
    #[test]
    fn take_first_is_position_and_swap_remove() {
        for len in 0..=4u8 {
            let list: heapless::Vec<(u8, u8), 4> = (0..len).map(|k| (k % 3, k)).collect();
            for wanted in 0..4u8 {
                let mut ours = list.clone();
                let mut theirs = list.clone();
                let expected = theirs
                    .iter()
                    .position(|&(key, _)| key == wanted)
                    .map(|index| theirs.swap_remove(index));
                assert_eq!(
                    take_first(&mut ours, |&(key, _)| key == wanted),
                    expected,
                    "{list:?}, {wanted}"
                );
                assert_eq!(ours, theirs, "{list:?}, {wanted}");
            }
        }
    }

    fn at(micros: u64) -> Instant {
        Instant::from_micros(micros)
    }

    /// `frame` to confirm, A's heard at `micros`.
    fn on_bus(frame: RawFrame, micros: u64) -> OnBus {
        OnBus {
            frame,
            heard: at(micros),
        }
    }

    #[test]
    fn sc_req_10_a_data_packet_equal_to_channel_b_s_within_its_slot_is_confirmed() {
        let mut check = TransmitCheck::new(WINDOW);
        assert!(check.is_idle());
        check.computed(at(1_000), DATA).unwrap();
        assert_eq!(check.deadline(), at(2_000));
        assert!(!check.is_idle(), "B's packet waits");
        assert_eq!(
            check.heard(at(1_500), DATA, Decoded::fields(&DATA), Duration::ZERO),
            Ok(Some(on_bus(DATA, 1_500)))
        );
        assert_eq!(check.deadline(), Instant::NEVER);
        assert!(check.is_idle());
        assert_eq!(check.poll(at(10_000)), Ok(()));
    }

    /// Every single-bit flip fails the CRC (section 4), so B's decoder rejects it: a
    /// mismatch at once, whatever B's samples were.
    #[test]
    fn sc_req_10_a_data_packet_that_differs_in_any_bit_is_a_mismatch() {
        for bit in 0..64 {
            let mut heard = DATA;
            heard.data[bit / 8] ^= 1 << (bit % 8);
            let mut check = TransmitCheck::new(WINDOW);
            let _ = check.sampled(at(0), 0x030, 0, 1);
            check.computed(at(0), DATA).unwrap();
            assert_eq!(
                check.heard(at(100), heard, Decoded::Invalid, Duration::ZERO),
                Err(TransmitFault::Mismatch { id: 0x030 }),
                "bit {bit}"
            );
        }
    }

    /// DATA as channel A would send it with value 0 (a valid packet; B's decoder's verdict).
    fn with_value_0() -> (RawFrame, Decoded) {
        let mut heard = DATA;
        heard.data[0] = 0;
        let decoded = Decoded::Data {
            sc_id: 0x30,
            value: 0,
            cycle_stamp: 5,
        };
        (heard, decoded)
    }

    /// B's contact moved first (0 to 1, 3 ms before the slot): A's packet with B's previous
    /// value stands for B's; 5 ms after B's change it no longer does.
    #[test]
    fn sc_req_10_a_value_that_was_channel_b_s_within_the_window_is_accepted() {
        let (heard, decoded) = with_value_0();
        for (heard_at, accepted) in [(3_270, true), (4_999, true), (5_000, false)] {
            let mut check = TransmitCheck::new(WINDOW);
            assert_eq!(check.sampled(at(0), 0x030, 0, 1), None);
            check.computed(at(3_000), DATA).unwrap();
            let result = check.heard(at(heard_at), heard, decoded, Duration::ZERO);
            assert_eq!(
                result == Ok(Some(on_bus(DATA, heard_at))),
                accepted,
                "heard at {heard_at}: {result:?}"
            );
        }
    }

    /// A's contact moved first: A's packet waits for B's next sample, at most the window; B
    /// taking A's value confirms B's own packet; B not taking it is a mismatch at the end.
    #[test]
    fn sc_req_10_a_value_channel_b_samples_within_the_window_is_accepted() {
        let (heard, decoded) = with_value_0();
        let mut check = TransmitCheck::new(WINDOW);
        check.computed(at(10_000), DATA).unwrap();
        assert_eq!(
            check.heard(at(10_270), heard, decoded, Duration::ZERO),
            Ok(None)
        );
        assert_eq!(check.deadline(), at(15_270));
        assert_eq!(
            check.sampled(at(15_000), 0x031, 1, 0),
            None,
            "another value"
        );
        assert_eq!(
            check.sampled(at(15_100), 0x030, 1, 0),
            Some(on_bus(DATA, 10_270))
        );
        assert_eq!(check.deadline(), Instant::NEVER);
        assert_eq!(check.poll(at(20_000)), Ok(()));

        let mut check = TransmitCheck::new(WINDOW);
        check.computed(at(10_000), DATA).unwrap();
        assert_eq!(
            check.heard(at(10_270), heard, decoded, Duration::ZERO),
            Ok(None)
        );
        assert_eq!(check.poll(at(15_269)), Ok(()));
        assert_eq!(
            check.poll(at(15_270)),
            Err(TransmitFault::Mismatch { id: 0x030 })
        );
    }

    /// B's contact moved (1 to 0) after B's core read it for its packet and before A's
    /// packet came off the bus: A's value 0 is B's current sample, it stands for B's at once
    /// (before, it waited for a next sample of 0 that never came: 78h after the window).
    #[test]
    fn sc_req_10_a_value_channel_b_sampled_after_computing_its_own_is_accepted() {
        let (heard, decoded) = with_value_0();
        let mut check = TransmitCheck::new(WINDOW);
        assert_eq!(check.computed(at(10_000), DATA), Ok(None));
        assert_eq!(check.sampled(at(10_100), 0x030, 1, 0), None);
        assert_eq!(
            check.heard(at(10_270), heard, decoded, Duration::ZERO),
            Ok(Some(on_bus(DATA, 10_270)))
        );
        assert_eq!(check.deadline(), Instant::NEVER);
        // A value B's sample took and left again more than the window ago is not accepted.
        let mut check = TransmitCheck::new(WINDOW);
        let _ = check.sampled(at(0), 0x030, 1, 0);
        let _ = check.sampled(at(1_000), 0x030, 0, 1);
        check.computed(at(10_000), DATA).unwrap();
        assert_eq!(
            check.heard(at(10_270), heard, decoded, Duration::ZERO),
            Ok(None)
        );
        assert_eq!(
            check.poll(at(15_270)),
            Err(TransmitFault::Mismatch { id: 0x030 })
        );
    }

    /// Only the value may differ: another cycle stamp, or a value B's decoder did not read
    /// from a packet of this SC-ID, is a mismatch at once.
    #[test]
    fn sc_req_10_a_packet_differing_in_more_than_its_value_is_a_mismatch_at_once() {
        let (heard, _) = with_value_0();
        for decoded in [
            Decoded::Data {
                sc_id: 0x30,
                value: 0,
                cycle_stamp: 6,
            },
            Decoded::Data {
                sc_id: 0x31,
                value: 0,
                cycle_stamp: 5,
            },
            Decoded::Invalid,
        ] {
            let mut check = TransmitCheck::new(WINDOW);
            let _ = check.sampled(at(0), 0x030, 0, 1);
            check.computed(at(1_000), DATA).unwrap();
            assert_eq!(
                check.heard(at(1_270), heard, decoded, Duration::ZERO),
                Err(TransmitFault::Mismatch { id: 0x030 }),
                "{decoded:?}"
            );
        }
    }

    /// A's packet heard with none of B's waiting waits `heard_ahead` (200 µs on a board) for
    /// B to compute it; B computing none by then is a mismatch, at that moment.
    #[test]
    fn sc_req_10_a_packet_of_the_node_channel_b_did_not_compute_is_a_mismatch() {
        let mut check = TransmitCheck::new(WINDOW);
        assert_eq!(
            check.heard(at(1_000), DATA, Decoded::fields(&DATA), Duration::ZERO),
            Ok(None)
        );
        assert_eq!(check.deadline(), at(1_200));
        assert_eq!(check.poll(at(1_199)), Ok(()));
        assert_eq!(
            check.poll(at(1_200)),
            Err(TransmitFault::Mismatch { id: 0x030 })
        );
    }

    /// SC_REQ_31: A's time may lead B's by up to the sync tolerance, so A's packet can come
    /// off the bus before B's timer reaches the slot (at 1 Mbit/s once the lead exceeds
    /// about 130 µs). Heard 199 µs ahead, it stands for B's packet when B computes it: the
    /// same bit for bit, or only B's previous sample's value within the window; anything
    /// else is a mismatch at once, as when heard after B's.
    #[test]
    fn sc_req_31_a_packet_heard_ahead_of_channel_b_s_own_within_the_tolerance_is_judged_as_one_after()
     {
        let mut check = TransmitCheck::new(WINDOW);
        assert_eq!(
            check.heard(at(10_000), DATA, Decoded::fields(&DATA), Duration::ZERO),
            Ok(None)
        );
        assert_eq!(
            check.computed(at(10_199), DATA),
            Ok(Some(on_bus(DATA, 10_000)))
        );
        assert_eq!(check.deadline(), Instant::NEVER);
        assert_eq!(check.poll(at(20_000)), Ok(()));

        // B's contact moved 0 to 1 at 8 ms; A's packet still carries 0.
        let (old_value, decoded) = with_value_0();
        let mut check = TransmitCheck::new(WINDOW);
        assert_eq!(check.sampled(at(8_000), 0x030, 0, 1), None);
        assert_eq!(
            check.heard(at(10_000), old_value, decoded, Duration::ZERO),
            Ok(None)
        );
        assert_eq!(
            check.computed(at(10_150), DATA),
            Ok(Some(on_bus(DATA, 10_000)))
        );

        // Another cycle stamp: A's core is a cycle off B's.
        let mut other_stamp = DATA;
        other_stamp.data[4] = 6;
        let mut check = TransmitCheck::new(WINDOW);
        let _ = check.heard(at(10_000), other_stamp, Decoded::Invalid, Duration::ZERO);
        assert_eq!(
            check.computed(at(10_100), DATA),
            Err(TransmitFault::Mismatch { id: 0x030 })
        );
    }

    /// Two of A's packets on one identifier before B computed either: A's core is a packet
    /// ahead of B's, a mismatch at the second.
    #[test]
    fn sc_req_10_a_second_packet_heard_ahead_of_channel_b_s_is_a_mismatch() {
        let mut check = TransmitCheck::new(WINDOW);
        let _ = check.heard(at(0), DATA, Decoded::fields(&DATA), Duration::ZERO);
        assert_eq!(
            check.heard(at(100), DATA, Decoded::fields(&DATA), Duration::ZERO),
            Err(TransmitFault::Mismatch { id: 0x030 })
        );
    }

    /// A check whose B has taken its time from one of A's syncs already: the state from the
    /// node's second sync on, where A's syncs are judged with the stated buffering.
    fn aligned_check() -> TransmitCheck {
        let mut check = TransmitCheck::new(WINDOW);
        check.computed(at(0), SYNC).unwrap();
        assert_eq!(
            check.heard(at(300), SYNC, Decoded::fields(&SYNC), Duration::ZERO),
            Ok(Some(on_bus(SYNC, 300)))
        );
        check
    }

    /// SC_REQ_33 and SC_REQ_31: both masters start on their own clocks at NMT start, so B's
    /// time before the first sync is its own, not A's plus the stated buffering. A's first
    /// sync, sent at B's own time (offset 250 µs both) and heard 290 µs later (an 8-byte
    /// frame at 500 kbit/s and the loop), agrees with 500 µs of stated buffering (the
    /// emulated network's, beyond the frame time by more than the tolerance); judged with the
    /// buffering it was a mismatch on 02Fh. From the second sync on B's time carries the
    /// buffering, and the same figures are A's sync 10 µs too far ahead; after leaving
    /// Operational the next sync is a first one again.
    #[test]
    fn sc_req_33_the_first_sync_is_judged_without_the_stated_buffering_later_ones_with_it() {
        let buffering = Duration::from_micros(500);
        let mut check = TransmitCheck::new(WINDOW);
        check.computed(at(1_000_000), SYNC).unwrap();
        assert_eq!(
            check.heard(at(1_000_290), SYNC, Decoded::fields(&SYNC), buffering),
            Ok(Some(on_bus(SYNC, 1_000_290))),
            "the first sync"
        );
        check.computed(at(1_100_000), SYNC).unwrap();
        assert_eq!(
            check.heard(at(1_100_290), SYNC, Decoded::fields(&SYNC), buffering),
            Err(TransmitFault::Mismatch { id: 0x02F }),
            "the second sync"
        );
        let mut check = TransmitCheck::new(WINDOW);
        check.computed(at(1_000_000), SYNC).unwrap();
        let _ = check.heard(at(1_000_290), SYNC, Decoded::fields(&SYNC), buffering);
        check.reset();
        check.computed(at(2_000_000), SYNC).unwrap();
        assert_eq!(
            check.heard(at(2_000_290), SYNC, Decoded::fields(&SYNC), buffering),
            Ok(Some(on_bus(SYNC, 2_000_290))),
            "the first sync after a reset"
        );
    }

    /// A sync heard 100 µs before B computed its own (offset 250 µs, 270 µs of stated
    /// buffering, B's time taken from A's before): B's time at the hearing was 150 µs into
    /// the slot, so A's may give at most 350 µs (offset 80).
    #[test]
    fn sc_req_10_a_sync_heard_ahead_agrees_only_within_the_offset_tolerance() {
        let buffering = Duration::from_micros(270);
        for (offset, agrees) in [(0u16, true), (80, true), (81, false)] {
            let mut heard = SYNC;
            heard.data[3..5].copy_from_slice(&offset.to_be_bytes());
            let mut check = aligned_check();
            assert_eq!(
                check.heard(at(5_000), heard, Decoded::fields(&heard), buffering),
                Ok(None)
            );
            let expected = if agrees {
                Ok(Some(on_bus(heard, 5_000)))
            } else {
                Err(TransmitFault::Mismatch { id: 0x02F })
            };
            assert_eq!(check.computed(at(5_100), SYNC), expected, "offset {offset}");
        }
    }

    /// Leaving Operational forgets A's packets heard ahead as well as B's.
    #[test]
    fn sc_req_10_reset_forgets_packets_heard_ahead() {
        let mut check = TransmitCheck::new(WINDOW);
        let _ = check.heard(at(0), DATA, Decoded::fields(&DATA), Duration::ZERO);
        check.reset();
        assert_eq!(check.deadline(), Instant::NEVER);
        assert_eq!(check.poll(at(1_000)), Ok(()));
    }

    /// At the end of the slot itself, as every deadline of the node.
    #[test]
    fn sc_req_10_a_data_packet_not_on_the_bus_by_the_end_of_its_slot_is_missing() {
        let mut check = TransmitCheck::new(WINDOW);
        check.computed(at(5_000), DATA).unwrap();
        assert_eq!(check.poll(at(5_999)), Ok(()));
        assert_eq!(
            check.poll(at(6_000)),
            Err(TransmitFault::Missing { id: 0x030 })
        );
    }

    /// Wider bounds (an image whose frames take longer to reach B, `with_bounds`): a data
    /// packet heard 30 ms after B computed it is missing with the standard's slot, confirmed
    /// with 60 ms; a sync heard 30 ms late likewise against SC_REQ_23's 2 ms.
    #[test]
    fn sc_req_10_the_bounds_set_replace_the_standard_s() {
        let wide = Bounds {
            data_within: Duration::from_millis(60),
            sync_within: Duration::from_millis(60),
            sync_ahead: Duration::from_millis(60),
            heard_ahead: Duration::from_millis(60),
        };
        for (frame, slot) in [(DATA, 1_000), (SYNC, 2_000)] {
            let mut check = TransmitCheck::new(WINDOW);
            check.computed(at(0), frame).unwrap();
            assert_eq!(check.deadline(), at(slot), "the standard's");
            assert_eq!(
                check.poll(at(30_000)),
                Err(TransmitFault::Missing { id: frame.id })
            );
            let mut check = TransmitCheck::with_bounds(WINDOW, wide);
            check.computed(at(0), frame).unwrap();
            assert_eq!(check.deadline(), at(60_000));
            assert_eq!(check.poll(at(30_000)), Ok(()));
            assert_eq!(
                check.heard(at(30_000), frame, Decoded::fields(&frame), Duration::ZERO),
                Ok(Some(on_bus(frame, 30_000)))
            );
        }
        assert_eq!(Bounds::default(), Bounds::STANDARD);
    }

    /// B computing the node's next packet while the previous one on the same identifier
    /// still waits for A's: the previous one is missing, even within a bound as long as the
    /// cycle (10 ms here, a 60 ms bound), instead of being replaced by the newer one.
    #[test]
    fn sc_req_10_a_packet_still_waiting_when_channel_b_computes_the_next_is_missing() {
        let mut check = TransmitCheck::new(WINDOW);
        check.set_bounds(Bounds {
            data_within: Duration::from_millis(60),
            ..Bounds::STANDARD
        });
        check.computed(at(0), DATA).unwrap();
        let mut next = DATA;
        next.data[4] = 6;
        assert_eq!(
            check.computed(at(10_000), next),
            Err(TransmitFault::Missing { id: 0x030 })
        );
    }

    #[test]
    /// B computed its sync 250 µs into the last slot and hears A's 300 µs later, with 270 µs
    /// of stated buffering (B's time taken from A's before): B's time is then 550 µs into the
    /// slot, and A's sync may give at most 200 µs more (offset 480); behind (an earlier
    /// offset) it agrees, and B's core is confirmed with A's frame, whose time it takes.
    fn sc_req_10_a_sync_agrees_by_master_cycle_and_not_ahead_of_channel_b_s_time() {
        let with_offset = |offset: u16| {
            let mut sync = SYNC;
            sync.data[3..5].copy_from_slice(&offset.to_be_bytes());
            sync
        };
        let decoded = |frame: &RawFrame| Decoded::fields(frame);
        let buffering = Duration::from_micros(270);
        for (offset, agrees) in [(250, true), (480, true), (481, false), (0, true)] {
            let heard = with_offset(offset);
            let mut check = aligned_check();
            check.computed(at(0), SYNC).unwrap();
            assert_eq!(check.deadline(), at(2_000), "SC_REQ_23: 2 ms");
            let result = check.heard(at(300), heard, decoded(&heard), buffering);
            let expected = if agrees {
                Ok(Some(on_bus(heard, 300)))
            } else {
                Err(TransmitFault::Mismatch { id: 0x02F })
            };
            assert_eq!(result, expected, "offset {offset}");
        }
        // Another cycle, or a sync B's decoder rejected, is a mismatch.
        let mut other_cycle = SYNC;
        other_cycle.data[2] = 0x03;
        let mut check = TransmitCheck::new(WINDOW);
        check.computed(at(0), SYNC).unwrap();
        assert!(
            check
                .heard(at(300), other_cycle, decoded(&other_cycle), Duration::ZERO)
                .is_err()
        );
        let mut check = TransmitCheck::new(WINDOW);
        check.computed(at(0), SYNC).unwrap();
        assert!(
            check
                .heard(at(300), SYNC, Decoded::Invalid, Duration::ZERO)
                .is_err()
        );
    }
}
