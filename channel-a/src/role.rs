//! Channel A's part in the pair (CiA 304 9.5, EN 50325-5 Annex A.4): it speaks for the node on
//! the bus (SDO answers, NMT boot-up and heartbeat, EMCY, GFC) and sends the plain frame of
//! every transmit SRDO, built by the protocol core. The inverted frame is channel B's; channel
//! A checks that it is the exact inverse of its own plain frame.
//!
//! # Frames on the node's identifiers
//!
//! A CAN controller does not receive the frames it sends itself (one transceiver, Model III),
//! so every frame channel A receives on a plain identifier of its transmit SRDOs was sent by
//! another device, and every frame on an inverted identifier must be channel B's answer to the
//! plain frame A is waiting on. Anything else is a [`ChannelFault::ForeignFrame`]. The one
//! exception is CAN's double reception (ISO 11898-1: a frame whose last end-of-frame bit was
//! disturbed is sent again and received twice): an exact copy of the inverted frame just
//! accepted, within [`SAMPLE_WINDOW`], is ignored; it carries the newest data, not older.
//!
//! # A pair cut by NMT reset
//!
//! NMT reset can fall between a plain frame and its inverted frame: channel B may have
//! co-signed the plain frame before its own reset, and its inverted frame reach channel A's
//! loop only after A's reset and start (each channel runs its own loop; on the emulated network
//! the hub may deliver it after both NMT frames). The pairs awaited at the reset are kept as
//! *cut* for their refresh time: the exact inverse of a cut pair's plain frame, once, ends it
//! quietly. Every other frame on the node's identifiers is foreign as before, so masquerade
//! detection is armed right after the start; the inverse of a plain frame channel A itself sent
//! is what channel B's inverted frame would be anyway, and is accepted once, as it would have
//! been without the reset.
//!
//! A pair awaited after the start comes before a cut one: its first plain frame usually
//! carries the cut pair's data (the input did not change), and a plain frame still in the
//! transmit queue at the reset reaches the bus after the NMT frame, so channel B, reset by
//! then, never co-signs it. The inverted frame of the new pair is then the inverse of both;
//! taken as the cut pair's end, it would leave the new pair without one, and a refresh time
//! later a transmit mismatch (30h) with nothing wrong.

use dual_channel::runtime::{ChannelFault, FrameSlots, Role, SAMPLE_WINDOW, fold_signatures};
use shared::canopen::od::Address;
use shared::safety::config::SafetyConfig;
use shared::safety::signature;
use shared::safety::types::{Direction, SrdoNumber};
use shared::{CanFrame, Duration, Instant};

/// A plain frame sent, waiting for channel B's inverted frame on the bus.
#[derive(Clone, Copy, Debug)]
struct Awaited {
    /// The plain frame sent.
    frame: CanFrame,
    plain: u16,
    srdo: SrdoNumber,
    /// The SRDO's refresh time: the next pair is due then, so this one must be complete.
    limit: Duration,
    /// When the wait was first seen by [`Role::poll`] (`outgoing` has no clock).
    since: Option<Instant>,
}

/// Channel A's role: which plain frames wait for channel B's inverted frame.
///
/// Channel A sees every inverted frame of its node's pairs on the bus. One that does not
/// follow its plain frame within the SRDO's refresh time means that channel B withheld it
/// (its own check failed and it says so over the link), or that it was lost on the way: the
/// node's pair is broken either way, and A reports it (CiA 304 9.5; the in-operation check of
/// the CAN message path). Without it A would wait for ever and the node would fall silent
/// without saying why.
///
/// Both lists are fixed slots, never shifted (shifting pulls compiler-builtins' `memmove` into
/// the image; see [`FrameSlots`]).
#[derive(Clone, Debug, Default)]
pub struct ChannelA {
    /// Plain frames whose inverted frame has not been seen on the bus yet.
    awaiting: [Option<Awaited>; 8],
    /// The newest plain frame per SRDO produced meanwhile, sent once the pair before it is
    /// complete (a pair's frames are never interleaved with the next pair's).
    deferred: FrameSlots<8>,
    /// The last inverted frame accepted, and when: its copy within the window is a double
    /// reception.
    last_inverted: Option<(CanFrame, Instant)>,
    /// The pairs awaited when NMT reset came: the inverse of one, once and within the SRDO's
    /// refresh time, ends it (see the module documentation).
    cut: [Option<Awaited>; 8],
}

impl ChannelA {
    /// `frame`, the plain frame of `srdo`, goes on the bus: its inverted frame is awaited.
    /// A full list means more transmit SRDOs in flight than this role tracks: the frame goes
    /// without tracking rather than never (B's check still guards it; its inverted frame is
    /// then reported as foreign, the safe side).
    fn await_inverted(&mut self, frame: CanFrame, srdo: Transmit) {
        if let Some(slot) = self.awaiting.iter_mut().find(|slot| slot.is_none()) {
            *slot = Some(Awaited {
                frame,
                plain: srdo.plain,
                srdo: srdo.srdo,
                limit: srdo.refresh,
                since: None,
            });
        }
    }
}

/// `true` when `inverted` is the exact inverse of `plain`: same length, every bit flipped.
fn is_inverse(plain: &CanFrame, inverted: &CanFrame) -> bool {
    plain.data().len() == inverted.data().len()
        && plain
            .data()
            .iter()
            .zip(inverted.data())
            .all(|(plain, inverted)| *plain == !*inverted)
}

/// A transmit SRDO of the configuration.
#[derive(Clone, Copy)]
struct Transmit {
    srdo: SrdoNumber,
    plain: u16,
    inverted: u16,
    refresh: Duration,
}

/// The transmit SRDOs of `config`.
fn transmit_srdos<const N: usize>(config: &SafetyConfig<N>) -> impl Iterator<Item = Transmit> + '_ {
    config
        .srdos
        .iter()
        .enumerate()
        .filter(|(_, record)| record.parsed_direction() == Ok(Direction::Transmit))
        // A configuration holds at most 64 SRDOs, so every one has a number.
        .filter_map(|(index, record)| {
            Some(Transmit {
                srdo: SrdoNumber::of_slot(index)?,
                plain: (record.cob_id_1 & 0x7FF) as u16,
                inverted: (record.cob_id_2 & 0x7FF) as u16,
                refresh: Duration::from_millis(u64::from(record.cycle_time)),
            })
        })
}

impl<const N: usize> Role<N> for ChannelA {
    fn outgoing(&mut self, frame: CanFrame, config: &SafetyConfig<N>) -> Option<CanFrame> {
        let id = frame.id().raw();
        let Some(srdo) = transmit_srdos(config).find(|t| t.plain == id || t.inverted == id) else {
            return Some(frame);
        };
        let plain = srdo.plain;
        if plain != id {
            return None; // The inverted frame is channel B's.
        }
        if self
            .awaiting
            .iter()
            .flatten()
            .any(|awaited| awaited.plain == plain)
        {
            // The previous pair is not complete: keep only the newest data for later.
            // Capacity is the number of transmit SRDOs awaited, at most 8 here; a frame that
            // does not fit is dropped and the next cycle carries the data.
            let _ = self.deferred.keep(frame);
            return None;
        }
        self.await_inverted(frame, srdo);
        Some(frame)
    }

    fn observe(
        &mut self,
        now: Instant,
        frame: &CanFrame,
        config: &SafetyConfig<N>,
    ) -> Result<Option<CanFrame>, ChannelFault> {
        let id = frame.id().raw();
        if frame.is_remote() {
            return Ok(None); // Remote frames on SRDO identifiers are ignored (EN 50325-5 6.2.1).
        }
        let Some(srdo) = transmit_srdos(config).find(|t| t.inverted == id || t.plain == id) else {
            return Ok(None);
        };
        if srdo.plain == id {
            return Err(ChannelFault::ForeignFrame { id }); // Never our own: we do not receive it.
        }
        // The pair awaited now comes before a cut one (see the module documentation).
        let awaited_slot = self
            .awaiting
            .iter_mut()
            .find(|slot| slot.is_some_and(|awaited| awaited.plain == srdo.plain));
        let ends_awaited = awaited_slot
            .as_ref()
            .is_some_and(|slot| slot.is_some_and(|awaited| is_inverse(&awaited.frame, frame)));
        if !ends_awaited {
            if let Some(cut) = self.cut.iter_mut().find(|slot| {
                slot.is_some_and(|cut| {
                    cut.plain == srdo.plain
                        && is_inverse(&cut.frame, frame)
                        && cut
                            .since
                            .is_none_or(|since| !shared::time::expired(since + cut.limit, now))
                })
            }) {
                *cut = None;
                // Its copy within the window is a double reception, as for any inverted frame.
                self.last_inverted = Some((*frame, now));
                return Ok(None);
            }
        }
        let Some(awaited) = awaited_slot.and_then(Option::take) else {
            let copy = self.last_inverted.is_some_and(|(last, at)| {
                last == *frame && !shared::time::expired(at + SAMPLE_WINDOW, now)
            });
            return if copy {
                Ok(None)
            } else {
                Err(ChannelFault::ForeignFrame { id })
            };
        };
        if !is_inverse(&awaited.frame, frame) {
            self.deferred.clear();
            return Err(ChannelFault::InvertedMismatch { srdo: srdo.srdo });
        }
        self.last_inverted = Some((*frame, now));
        let Some(next) = self.deferred.take(awaited.frame.id()) else {
            return Ok(None);
        };
        self.await_inverted(next, srdo);
        Ok(Some(next))
    }

    fn input(
        &mut self,
        _now: Instant,
        _address: Address,
        _value: &[u8],
        _config: &SafetyConfig<N>,
    ) -> Result<Option<CanFrame>, ChannelFault> {
        // Channel A's inputs live in its core's process image, written by the runtime.
        Ok(None)
    }

    fn poll(&mut self, now: Instant) -> Result<(), ChannelFault> {
        // A cut pair's end not seen within its refresh time will not come: forgotten, not a
        // fault (the reset abandoned the pair on both channels).
        for slot in &mut self.cut {
            if let Some(cut) = slot {
                let since = *cut.since.get_or_insert(now);
                if shared::time::expired(since + cut.limit, now) {
                    *slot = None;
                }
            }
        }
        // Loops over the slots, not `flatten()`: the adapter was not inlined at the images'
        // optimisation level, and this runs at every poll.
        for slot in &mut self.awaiting {
            let Some(awaited) = slot else {
                continue;
            };
            let since = *awaited.since.get_or_insert(now);
            if shared::time::expired(since + awaited.limit, now) {
                let srdo = awaited.srdo;
                self.awaiting = [None; 8];
                self.deferred.clear();
                return Err(ChannelFault::TransmitMismatch { srdo });
            }
        }
        Ok(())
    }

    fn reset(&mut self) {
        // Every pair awaited is cut; one cut before and still not ended is forgotten (at
        // most one pair per SRDO is awaited, so the slots suffice).
        self.cut = core::mem::take(&mut self.awaiting);
        self.deferred.clear();
        self.last_inverted = None;
    }

    fn deadline(&self) -> Instant {
        let mut earliest = Instant::NEVER;
        for awaited in self.awaiting.iter().filter_map(Option::as_ref) {
            let deadline = match awaited.since {
                Some(since) => since + awaited.limit,
                // Not stamped yet: the next poll does it.
                None => Instant::ZERO,
            };
            earliest = earliest.min(deadline);
        }
        earliest
    }

    fn signature_digest(&self, config: &SafetyConfig<N>) -> u32 {
        // Table-driven CRC-16 of the `crc` crate, through the protocol core.
        fold_signatures(config.srdos.iter().map(signature::compute))
    }

    fn speaks_for_the_node(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::CanId;

    fn frame(id: u16) -> CanFrame {
        CanFrame::new(CanId::new(id).unwrap(), &[1]).unwrap()
    }

    /// Channel B's inverted frame for plain data `value`.
    fn inverted(value: u8) -> CanFrame {
        CanFrame::new(CanId::new(0x102).unwrap(), &[!value]).unwrap()
    }

    /// Channel A sends the plain frame and everything else, never the inverted frame of a
    /// transmit SRDO.
    #[test]
    fn cia304_9_5_a_sends_the_plain_frame_only() {
        let config = SafetyConfig::<2>::predefined(1, &[0x6000_0108, 0x6001_0108], &[]);
        let mut a = ChannelA::default();
        assert!(a.outgoing(frame(0x101), &config).is_some());
        assert!(a.outgoing(frame(0x102), &config).is_none());
        // B's inverted frame completes the pair.
        assert_eq!(a.observe(Instant::ZERO, &inverted(1), &config), Ok(None));
        assert!(a.outgoing(frame(0x701), &config).is_some());
        assert!(a.outgoing(frame(0x581), &config).is_some());
        // A receive SRDO's identifiers are not A's to filter (it never sends them anyway).
        let consumer = SafetyConfig::<2>::predefined(33, &[], &[0x6200_0108, 0x6201_0108]);
        assert!(a.outgoing(frame(0x142), &consumer).is_some());
    }

    /// EN 50325-5 7.1.1: the next plain frame waits until channel B's inverted frame of the
    /// previous pair is on the bus, so pairs never interleave; only the newest data waits.
    #[test]
    fn en50325_5_7_1_1_a_new_plain_frame_waits_for_the_previous_pair() {
        let config = SafetyConfig::<2>::predefined(1, &[0x6000_0108, 0x6001_0108], &[]);
        let mut a = ChannelA::default();
        let data = |value: u8| CanFrame::new(CanId::new(0x101).unwrap(), &[value]).unwrap();
        assert_eq!(a.outgoing(data(1), &config), Some(data(1)));
        assert_eq!(a.outgoing(data(2), &config), None);
        assert_eq!(a.outgoing(data(3), &config), None);
        assert_eq!(
            a.observe(Instant::ZERO, &inverted(1), &config),
            Ok(Some(data(3)))
        );
        assert_eq!(a.outgoing(data(4), &config), None);
        assert_eq!(
            a.observe(Instant::ZERO, &inverted(3), &config),
            Ok(Some(data(4)))
        );
        assert_eq!(a.observe(Instant::ZERO, &inverted(4), &config), Ok(None));
        assert_eq!(a.outgoing(data(5), &config), Some(data(5)));
    }

    /// CiA 304 9.5: an inverted frame that does not follow within the refresh time (channel
    /// B withheld it, or it was lost) is reported, at the deadline itself, not waited for.
    #[test]
    fn cia304_9_5_a_pair_left_incomplete_is_reported_after_the_refresh_time() {
        let mut config = SafetyConfig::<2>::predefined(1, &[0x6000_0108, 0x6001_0108], &[]);
        config.srdos[0].cycle_time = 20;
        let mut a = ChannelA::default();
        assert_eq!(Role::<2>::deadline(&a), Instant::NEVER);
        assert!(a.outgoing(frame(0x101), &config).is_some());
        let sent = Instant::from_millis(100);
        assert_eq!(Role::<2>::poll(&mut a, sent), Ok(()));
        assert_eq!(Role::<2>::deadline(&a), Instant::from_millis(120));
        assert_eq!(
            Role::<2>::poll(&mut a, Instant::from_micros(119_999)),
            Ok(())
        );
        assert_eq!(
            Role::<2>::poll(&mut a, Instant::from_millis(120)),
            Err(ChannelFault::TransmitMismatch {
                srdo: SrdoNumber::FIRST
            })
        );
        assert_eq!(Role::<2>::deadline(&a), Instant::NEVER, "reported once");
        // A completed pair is not reported.
        assert!(a.outgoing(frame(0x101), &config).is_some());
        assert_eq!(Role::<2>::poll(&mut a, sent), Ok(()));
        assert_eq!(a.observe(sent, &inverted(1), &config), Ok(None));
        assert_eq!(Role::<2>::poll(&mut a, Instant::from_millis(500)), Ok(()));
    }

    /// CiA 304 9.5, EN 50325-5 7.2.1: NMT reset between the plain and the inverted frame.
    /// The inverse of the plain frame sent before the reset ends the cut pair once (and its
    /// copy is a double reception); other data, a third one, or one after the refresh time
    /// is foreign.
    #[test]
    fn cia304_9_5_a_pair_cut_by_nmt_reset_ends_only_with_its_inverse_once() {
        let mut config = SafetyConfig::<2>::predefined(1, &[0x6000_0108, 0x6001_0108], &[]);
        config.srdos[0].cycle_time = 20;
        let foreign = Err(ChannelFault::ForeignFrame { id: 0x102 });
        let plain = CanFrame::new(CanId::new(0x101).unwrap(), &[1]).unwrap();
        let sent = Instant::from_millis(100);
        let cut = |a: &mut ChannelA| {
            assert!(a.outgoing(plain, &config).is_some());
            assert_eq!(Role::<2>::poll(a, sent), Ok(()));
            Role::<2>::reset(a);
        };
        let mut a = ChannelA::default();
        cut(&mut a);
        assert_eq!(a.observe(sent, &inverted(2), &config), foreign);
        let mut a = ChannelA::default();
        cut(&mut a);
        let soon = Instant::from_millis(103);
        assert_eq!(a.observe(soon, &inverted(1), &config), Ok(None));
        assert_eq!(a.observe(soon, &inverted(1), &config), Ok(None), "a copy");
        let later = soon + SAMPLE_WINDOW;
        assert_eq!(a.observe(later, &inverted(1), &config), foreign);
        let mut a = ChannelA::default();
        cut(&mut a);
        assert_eq!(Role::<2>::poll(&mut a, Instant::from_millis(120)), Ok(()));
        assert_eq!(
            a.observe(Instant::from_millis(120), &inverted(1), &config),
            foreign,
            "after the refresh time"
        );
    }

    /// CiA 304 9.5: after NMT reset and start, channel A's first plain frame usually carries
    /// the data of the pair the reset cut, so one inverted frame is the inverse of both. It
    /// ends the pair awaited now, not the cut one: no transmit mismatch a refresh time later.
    /// The cut pair's own inverted frame, if it still comes, is then that frame again, and
    /// ends the cut pair quietly.
    #[test]
    fn cia304_9_5_the_first_pair_after_reset_and_start_ends_with_its_own_inverted_frame() {
        let mut config = SafetyConfig::<2>::predefined(1, &[0x6000_0108, 0x6001_0108], &[]);
        config.srdos[0].cycle_time = 20;
        let mut a = ChannelA::default();
        assert!(a.outgoing(frame(0x101), &config).is_some());
        Role::<2>::reset(&mut a);
        let started = Instant::from_millis(105);
        assert!(a.outgoing(frame(0x101), &config).is_some());
        assert_eq!(Role::<2>::poll(&mut a, started), Ok(()));
        let answered = Instant::from_micros(105_120);
        assert_eq!(a.observe(answered, &inverted(1), &config), Ok(None));
        assert_eq!(Role::<2>::deadline(&a), Instant::NEVER, "nothing awaited");
        let late = answered + SAMPLE_WINDOW;
        assert_eq!(
            a.observe(late, &inverted(1), &config),
            Ok(None),
            "the cut end"
        );
        assert_eq!(Role::<2>::poll(&mut a, Instant::from_millis(200)), Ok(()));
    }

    /// CiA 304 9.5: the pair cut by NMT reset does not hide a new pair left without its
    /// inverted frame: the inverse of the cut pair's plain frame ends the cut pair only, and
    /// the new pair, with other data, is still a transmit mismatch at its refresh time.
    #[test]
    fn cia304_9_5_a_cut_pair_does_not_hide_a_new_pair_left_without_its_inverted_frame() {
        let mut config = SafetyConfig::<2>::predefined(1, &[0x6000_0108, 0x6001_0108], &[]);
        config.srdos[0].cycle_time = 20;
        let mut a = ChannelA::default();
        assert!(a.outgoing(frame(0x101), &config).is_some());
        Role::<2>::reset(&mut a);
        let started = Instant::from_millis(105);
        let other = CanFrame::new(CanId::new(0x101).unwrap(), &[0]).unwrap();
        assert!(a.outgoing(other, &config).is_some());
        assert_eq!(Role::<2>::poll(&mut a, started), Ok(()));
        assert_eq!(a.observe(started, &inverted(1), &config), Ok(None));
        assert_eq!(
            Role::<2>::poll(&mut a, Instant::from_millis(125)),
            Err(ChannelFault::TransmitMismatch {
                srdo: SrdoNumber::FIRST
            })
        );
    }

    /// CiA 304 9.5, EN 50325-5 7.1.1: the inverted frame on the bus must be the exact inverse
    /// of channel A's plain frame; another one is reported, not taken as the pair's end.
    #[test]
    fn cia304_9_5_a_wrong_inverted_frame_is_reported() {
        let config = SafetyConfig::<2>::predefined(1, &[0x6000_0108, 0x6001_0108], &[]);
        let mut a = ChannelA::default();
        assert!(a.outgoing(frame(0x101), &config).is_some());
        assert_eq!(
            a.observe(Instant::ZERO, &inverted(3), &config),
            Err(ChannelFault::InvertedMismatch {
                srdo: SrdoNumber::FIRST
            })
        );
        // A longer frame with the right first byte is not the inverse either.
        assert!(a.outgoing(frame(0x101), &config).is_some());
        let longer = CanFrame::new(CanId::new(0x102).unwrap(), &[0xFE, 0x00]).unwrap();
        assert_eq!(
            a.observe(Instant::ZERO, &longer, &config),
            Err(ChannelFault::InvertedMismatch {
                srdo: SrdoNumber::FIRST
            })
        );
    }

    /// EN 50325-5 7.2.1: channel A never receives its own plain frame, so any frame on the
    /// plain identifier is foreign, and an inverted frame nobody waits for is too; a copy of
    /// the inverted frame just accepted (CAN double reception) within the window is not.
    #[test]
    fn en50325_5_7_2_1_frames_a_did_not_send_or_await_are_foreign() {
        let config = SafetyConfig::<2>::predefined(1, &[0x6000_0108, 0x6001_0108], &[]);
        let mut a = ChannelA::default();
        let foreign = |id| Err(ChannelFault::ForeignFrame { id });
        assert_eq!(
            a.observe(Instant::ZERO, &frame(0x101), &config),
            foreign(0x101)
        );
        assert_eq!(
            a.observe(Instant::ZERO, &inverted(1), &config),
            foreign(0x102)
        );
        assert!(a.outgoing(frame(0x101), &config).is_some());
        let t = Instant::from_millis(10);
        assert_eq!(a.observe(t, &inverted(1), &config), Ok(None));
        assert_eq!(
            a.observe(t + Duration::from_micros(300), &inverted(1), &config),
            Ok(None)
        );
        assert_eq!(a.observe(t, &inverted(0), &config), foreign(0x102));
        assert_eq!(
            a.observe(t + SAMPLE_WINDOW, &inverted(1), &config),
            foreign(0x102)
        );
        // Remote frames are the core's to ignore.
        let remote = CanFrame::remote(CanId::new(0x101).unwrap(), 1).unwrap();
        assert_eq!(a.observe(t, &remote, &config), Ok(None));
    }
}
