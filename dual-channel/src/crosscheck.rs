//! The cross-check of receive SRDO verdicts between the two channels (EN 50325-5 Annex A.4,
//! Model III; CiA 304 9.5).
//!
//! Each channel validates every received SRDO pair with its own copy of the protocol core and
//! sends its verdict ([`crate::link::Message::Verdict`]) to the other. A pair is *confirmed* when both
//! channels' verdicts for it agree in validity and data. A disagreement, or a verdict the other
//! channel does not confirm within the timeout, is a [`CrossFault`]: both outputs go to the safe
//! state.
//!
//! Pairs can follow each other faster than a verdict crosses the link (an SRDO is sent at once
//! on every change of its data, so a bouncing contact sends pairs a few frame times apart):
//! up to [`DEPTH`] verdicts per SRDO and channel wait for their match, in order. One more is a
//! fault, as is any that waits longer than the timeout.
//!
//! The policy for outputs that goes with it (in the channel logic): an output moves towards
//! the safe state (0) as soon as the channel's own core says so, and away from it only with a
//! confirmed pair that is the newest pair each channel accepted. A confirmation can come
//! after a newer pair (its verdict was on the link while the newer one arrived on the bus);
//! the confirmed [`Verdict`] therefore names its pair, so that the channel can discard it.
//!
//! The check is written once for every safety protocol of the node: it keeps verdicts apart
//! by a [`Stream`] (an SRDO by default; with the feature `simplecan`, a consumed SimpleCAN
//! SDD entry, `crate::simplecan::ConsumedEntry`).

use shared::safety::types::SrdoNumber;
use shared::{Duration, Instant};

/// What verdicts are kept apart by: one stream of safety data of the protocol (an SRDO, a
/// SimpleCAN SDD entry), numbered from 1 as the protocol numbers it.
pub trait Stream: Copy + PartialEq + core::fmt::Debug {
    /// The stream numbered `number`, `None` when the protocol has no such number.
    fn from_number(number: u8) -> Option<Self>;
    /// Its place among the check's slots, 0-based.
    fn index(self) -> usize;
}

impl Stream for SrdoNumber {
    fn from_number(number: u8) -> Option<Self> {
        SrdoNumber::new(number)
    }
    fn index(self) -> usize {
        SrdoNumber::index(self)
    }
}

/// One channel's verdict on one pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Verdict {
    /// Count of valid pairs of the SRDO so far, identifying the pair.
    pub pair: u32,
    /// Whether the pair passed every check.
    pub valid: bool,
    /// Its plain data (0 when not valid).
    pub data: u64,
}

/// Why the channels do not agree, on stream `S` (an SRDO unless said otherwise; the variants
/// name the SRDO case, a SimpleCAN channel translates them into its own faults at once).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CrossFault<S = SrdoNumber> {
    /// The two verdicts on the same SRDO differ (pair, validity or data).
    Disagreement {
        /// SRDO number.
        srdo: S,
    },
    /// A verdict was not matched by the other channel in time.
    Unconfirmed {
        /// SRDO number.
        srdo: S,
    },
    /// A verdict named an SRDO this node does not have.
    UnknownSrdo {
        /// The SRDO number received.
        srdo: u8,
    },
    /// More verdicts on one SRDO waited for the other channel's than it can be behind by
    /// ([`DEPTH`]): it lost some, or is not validating at all.
    QueueFull {
        /// SRDO number.
        srdo: S,
    },
}

/// How many verdicts per SRDO and channel may wait for the other channel's.
pub const DEPTH: usize = 4;

/// Verdicts of one channel waiting for a match, oldest first.
type Pending = heapless::Deque<(Verdict, Instant), DEPTH>;

#[derive(Clone, Debug, Default)]
struct Slot {
    local: Pending,
    remote: Pending,
}

impl Slot {
    /// When the oldest verdict still waiting in this slot arrived. Each queue is in order of
    /// arrival (verdicts are appended with the `now` of their arrival, and the runtime's
    /// clock never goes backwards), so its front is its oldest: the timeout is checked on
    /// the two fronts, not on every waiting verdict.
    fn oldest(&self) -> Option<Instant> {
        let local = self.local.front().map(|(_, since)| *since);
        let remote = self.remote.front().map(|(_, since)| *since);
        match (local, remote) {
            (Some(local), Some(remote)) => Some(local.min(remote)),
            (since, None) | (None, since) => since,
        }
    }
}

/// Whose verdict arrived.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Side {
    Local,
    Remote,
}

/// Pending verdicts of `N` streams (SRDOs unless `S` says otherwise), compared as they pair
/// up.
#[derive(Clone, Debug)]
pub struct VerdictCheck<const N: usize, S: Stream = SrdoNumber> {
    timeout: Duration,
    slots: [Slot; N],
    /// How many verdicts wait in all slots: [`VerdictCheck::poll`] and
    /// [`VerdictCheck::deadline`] look at no slot while none does, which is most of the time
    /// (the two channels' verdicts on a pair come within a link message of each other).
    waiting: usize,
    stream: core::marker::PhantomData<S>,
}

impl<const N: usize, S: Stream> VerdictCheck<N, S> {
    /// Verdicts must be confirmed within `timeout` of arriving.
    pub fn new(timeout: Duration) -> Self {
        VerdictCheck {
            timeout,
            slots: core::array::from_fn(|_| Slot::default()),
            waiting: 0,
            stream: core::marker::PhantomData,
        }
    }

    /// This channel's verdict on stream `srdo` at `now`. Returns the confirmed verdict
    /// (valid, with its pair and data) when the other channel's verdict was already there
    /// and agrees.
    pub fn local(
        &mut self,
        now: Instant,
        srdo: S,
        verdict: Verdict,
    ) -> Result<Option<Verdict>, CrossFault<S>> {
        self.arrive(now, Ok(srdo), verdict, Side::Local)
    }

    /// The other channel's verdict on the stream it numbers `srdo`, received over the link.
    pub fn remote(
        &mut self,
        now: Instant,
        srdo: u8,
        verdict: Verdict,
    ) -> Result<Option<Verdict>, CrossFault<S>> {
        self.arrive(now, Err(srdo), verdict, Side::Remote)
    }

    /// `srdo`: this channel's stream, or the number the other channel sent.
    // Out of line in the images: a marker of the emulator's profile
    // (`emulator::profile::MARKERS`), found in every activation that runs it.
    #[cfg_attr(target_os = "none", inline(never))]
    fn arrive(
        &mut self,
        now: Instant,
        srdo: Result<S, u8>,
        verdict: Verdict,
        side: Side,
    ) -> Result<Option<Verdict>, CrossFault<S>> {
        let number = match srdo {
            Ok(stream) => stream,
            Err(raw) => S::from_number(raw).ok_or(CrossFault::UnknownSrdo { srdo: raw })?,
        };
        let Some(slot) = self.slots.get_mut(number.index()) else {
            // A stream of the protocol the check has no slot for: the number as the other
            // channel would send it (1-based, at most 255 slots are ever built).
            let srdo = u8::try_from(number.index() + 1).unwrap_or(u8::MAX);
            return Err(CrossFault::UnknownSrdo { srdo });
        };
        let srdo = number;
        let (mine, theirs) = match side {
            Side::Local => (&mut slot.local, &mut slot.remote),
            Side::Remote => (&mut slot.remote, &mut slot.local),
        };
        let Some((other, _)) = theirs.pop_front() else {
            if mine.push_back((verdict, now)).is_err() {
                // More verdicts waiting than the other channel can be behind by: it lost
                // some, or is not validating at all.
                self.waiting -= mine.len() + theirs.len();
                *slot = Slot::default();
                return Err(CrossFault::QueueFull { srdo });
            }
            self.waiting += 1;
            return Ok(None);
        };
        self.waiting -= 1;
        match other {
            // Agreement: the data when the pair was valid; nothing to drive when both found
            // the same fault (each channel is then in its safe state already).
            other if other == verdict => Ok(verdict.valid.then_some(verdict)),
            _ => Err(CrossFault::Disagreement { srdo }),
        }
    }

    /// `true` when no verdict waits for the other channel's: [`poll`](Self::poll) finds no
    /// fault and [`deadline`](Self::deadline) is [`Instant::NEVER`].
    pub fn is_idle(&self) -> bool {
        self.waiting == 0
    }

    /// [`CrossFault::Unconfirmed`] for a verdict older than the timeout (at the deadline itself).
    pub fn poll(&self, now: Instant) -> Result<(), CrossFault<S>> {
        if self.waiting == 0 {
            return Ok(());
        }
        for (index, slot) in self.slots.iter().enumerate() {
            if slot
                .oldest()
                .is_some_and(|since| shared::time::expired(since + self.timeout, now))
            {
                // Every slot is one of the protocol's streams (at most 64 SRDOs, 80 SDD
                // entries), so it has a number.
                let number = u8::try_from(index + 1).ok().and_then(S::from_number);
                if let Some(srdo) = number {
                    return Err(CrossFault::Unconfirmed { srdo });
                }
            }
        }
        Ok(())
    }

    /// When [`VerdictCheck::poll`] next has something to report ([`Instant::NEVER`]: nothing).
    pub fn deadline(&self) -> Instant {
        if self.waiting == 0 {
            return Instant::NEVER;
        }
        self.slots
            .iter()
            .filter_map(Slot::oldest)
            .map(|since| since + self.timeout)
            .min()
            .unwrap_or(Instant::NEVER)
    }

    /// Forgets every pending verdict (NMT reset).
    pub fn reset(&mut self) {
        self.slots = core::array::from_fn(|_| Slot::default());
        self.waiting = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn number(srdo: u8) -> SrdoNumber {
        SrdoNumber::new(srdo).unwrap()
    }

    const TIMEOUT: Duration = Duration::from_millis(5);

    fn valid(pair: u32, data: u64) -> Verdict {
        Verdict {
            pair,
            valid: true,
            data,
        }
    }

    #[test]
    fn agreeing_verdicts_confirm_the_data_whichever_comes_first() {
        let mut check = VerdictCheck::<2>::new(TIMEOUT);
        let t = Instant::from_millis(1);
        assert_eq!(check.local(t, number(1), valid(1, 0xAA)), Ok(None));
        assert_eq!(check.deadline(), t + TIMEOUT);
        assert_eq!(check.remote(t, 1, valid(1, 0xAA)), Ok(Some(valid(1, 0xAA))));
        assert_eq!(check.deadline(), Instant::NEVER);
        assert_eq!(check.remote(t, 2, valid(1, 0x55)), Ok(None));
        assert_eq!(
            check.local(t, number(2), valid(1, 0x55)),
            Ok(Some(valid(1, 0x55)))
        );
    }

    /// EN 50325-5 Annex A.4: a disagreement puts both outputs in the safe state.
    #[test]
    fn different_data_validity_or_pair_is_a_disagreement() {
        let t = Instant::ZERO;
        for other in [
            valid(1, 0xAB),
            valid(2, 0xAA),
            Verdict {
                pair: 1,
                valid: false,
                data: 0xAA,
            },
        ] {
            let mut check = VerdictCheck::<1>::new(TIMEOUT);
            check.local(t, number(1), valid(1, 0xAA)).unwrap();
            assert_eq!(
                check.remote(t, 1, other),
                Err(CrossFault::Disagreement { srdo: number(1) })
            );
        }
        // Two invalid verdicts agree on the fault, but confirm no data.
        let mut check = VerdictCheck::<1>::new(TIMEOUT);
        let invalid = Verdict {
            pair: 3,
            valid: false,
            data: 0,
        };
        check.local(t, number(1), invalid).unwrap();
        assert_eq!(check.remote(t, 1, invalid), Ok(None));
    }

    /// EN 50325-5 Annex A.4: a verdict not confirmed in time is a fault, at the deadline itself.
    #[test]
    fn an_unconfirmed_verdict_times_out() {
        let mut check = VerdictCheck::<1>::new(TIMEOUT);
        let t = Instant::from_millis(10);
        check.remote(t, 1, valid(7, 1)).unwrap();
        assert_eq!(check.poll(Instant::from_micros(14_999)), Ok(()));
        assert_eq!(
            check.poll(Instant::from_millis(15)),
            Err(CrossFault::Unconfirmed { srdo: number(1) })
        );
    }

    /// EN 50325-5 Annex A.4: more verdicts from one side than may wait is a fault too, and it
    /// says so: the queue is full, no verdict has timed out yet.
    #[test]
    fn more_verdicts_waiting_than_the_queue_holds_is_a_full_queue() {
        let mut check = VerdictCheck::<1>::new(TIMEOUT);
        let t = Instant::from_millis(10);
        for pair in 1..=DEPTH as u32 {
            check.local(t, number(1), valid(pair, 1)).unwrap();
        }
        assert_eq!(
            check.local(t, number(1), valid(DEPTH as u32 + 1, 1)),
            Err(CrossFault::QueueFull { srdo: number(1) })
        );
        // The slot starts over: the fault is reported once, not at every later verdict.
        assert_eq!(
            check.local(t, number(1), valid(DEPTH as u32 + 2, 1)),
            Ok(None)
        );
    }

    /// Found on the emulated network: an emergency stop pressed and released at once sends two
    /// pairs 17 ms apart, faster than a verdict crossed the emulated link. Both are matched,
    /// in order, and each confirms its own data.
    #[test]
    fn pairs_faster_than_the_link_are_matched_in_order() {
        let mut check = VerdictCheck::<1>::new(TIMEOUT);
        let t = Instant::from_millis(1);
        assert_eq!(check.local(t, number(1), valid(8, 0)), Ok(None));
        assert_eq!(check.local(t, number(1), valid(9, 1)), Ok(None));
        assert_eq!(check.remote(t, 1, valid(8, 0)), Ok(Some(valid(8, 0))));
        assert_eq!(check.deadline(), t + TIMEOUT, "pair 9 still waits");
        assert_eq!(check.remote(t, 1, valid(9, 1)), Ok(Some(valid(9, 1))));
        assert_eq!(check.deadline(), Instant::NEVER);
        // Out of order is a disagreement.
        check.local(t, number(1), valid(10, 0)).unwrap();
        check.local(t, number(1), valid(11, 1)).unwrap();
        assert_eq!(
            check.remote(t, 1, valid(11, 1)),
            Err(CrossFault::Disagreement { srdo: number(1) })
        );
    }

    /// With several verdicts waiting, the oldest sets the deadline and times out first; once
    /// it is matched, the next oldest takes over.
    #[test]
    fn the_oldest_waiting_verdict_sets_the_deadline() {
        let mut check = VerdictCheck::<2>::new(TIMEOUT);
        let ms = Instant::from_millis;
        check.local(ms(1), number(1), valid(1, 1)).unwrap();
        check.local(ms(2), number(1), valid(2, 0)).unwrap();
        check.remote(ms(3), 2, valid(1, 1)).unwrap();
        check.local(ms(4), number(1), valid(3, 1)).unwrap();
        assert_eq!(check.deadline(), ms(1) + TIMEOUT);
        assert_eq!(check.poll(Instant::from_micros(5_999)), Ok(()));
        assert_eq!(
            check.poll(ms(6)),
            Err(CrossFault::Unconfirmed { srdo: number(1) })
        );
        assert_eq!(check.remote(ms(5), 1, valid(1, 1)), Ok(Some(valid(1, 1))));
        assert_eq!(check.deadline(), ms(2) + TIMEOUT);
        assert_eq!(check.remote(ms(5), 1, valid(2, 0)), Ok(Some(valid(2, 0))));
        assert_eq!(check.deadline(), ms(3) + TIMEOUT, "SRDO 2's remote verdict");
        assert_eq!(
            check.poll(ms(8)),
            Err(CrossFault::Unconfirmed { srdo: number(2) })
        );
    }

    #[test]
    fn unknown_srdo_numbers_are_refused() {
        let mut check = VerdictCheck::<2>::new(TIMEOUT);
        for srdo in [0u8, 3, 255] {
            assert_eq!(
                check.remote(Instant::ZERO, srdo, valid(1, 1)),
                Err(CrossFault::UnknownSrdo { srdo })
            );
        }
    }

    proptest::proptest! {
        /// EN 50325-5 Annex A.4: the count of waiting verdicts that lets `poll` and
        /// `deadline` skip the slots is the number of verdicts in them, after any sequence of
        /// agreements, disagreements, full queues and resets; so the timeout is watched
        /// exactly as a look at every slot watches it.
        #[test]
        fn annex_a4_the_waiting_count_is_what_the_slots_hold(
            steps in proptest::collection::vec((0u8..4, 1u8..=2, 0u32..3), 0..60),
        ) {
            let mut check = VerdictCheck::<2>::new(TIMEOUT);
            for (at, (kind, srdo, pair)) in steps.into_iter().enumerate() {
                let now = Instant::from_millis(at as u64);
                let _ = match kind {
                    0 => check.local(now, number(srdo), valid(pair, 1)),
                    1 | 2 => check.remote(now, srdo, valid(pair, 1)),
                    _ => {
                        if pair == 0 {
                            check.reset();
                        }
                        Ok(None)
                    }
                };
                let held: usize = check
                    .slots
                    .iter()
                    .map(|slot| slot.local.len() + slot.remote.len())
                    .sum();
                proptest::prop_assert_eq!(check.waiting, held);
                proptest::prop_assert_eq!(check.is_idle(), held == 0);
                let scanned = check
                    .slots
                    .iter()
                    .filter_map(Slot::oldest)
                    .map(|since| since + TIMEOUT)
                    .min()
                    .unwrap_or(Instant::NEVER);
                proptest::prop_assert_eq!(check.deadline(), scanned);
                let later = now + TIMEOUT;
                proptest::prop_assert_eq!(check.poll(later).is_err(), scanned <= later);
            }
        }
    }
}
