//! Channel B's part in the pair (CiA 304 9.5, EN 50325-5 Annex A.4): silent on the bus except
//! for the inverted frame of each transmit SRDO, which it builds by its own path
//! ([`crate::diverse`]) and sends only for a plain frame on the bus that channel A announced
//! over the link and that matched B's own result bit by bit. It follows SDO requests into its
//! own copy of the object dictionary (the core does that), and signs the configuration with
//! its own CRC ([`crate::signature`]).
//!
//! # Only what channel A sent
//!
//! Channel A announces each plain frame over the link before it puts it on the bus. Channel B
//! co-signs a plain frame only when it equals that announcement; whichever of the two arrives
//! first waits for the other for up to the window. A plain frame that differs from the
//! announcement, or is never announced, was not sent by channel A (inserted, replayed,
//! corrupted on the bus in a way the CAN CRC missed): a [`ChannelFault::ForeignFrame`], and
//! nothing is co-signed. A CAN controller does not receive its own frames, so any frame on an
//! inverted identifier is foreign to channel B. An exact copy of the plain frame just seen,
//! within the window, is CAN's double reception (ISO 11898-1), not a foreign frame.
//!
//! # Discrepancy window
//!
//! The two channels sample their inputs independently, so around an input change channel A's
//! frame may carry a sample channel B has just replaced, or one B has not taken yet. Channel
//! B therefore accepts A's plain frame when it matches B's current inputs, or B's previous
//! inputs if they were read less than [`ChannelB::window`] ago; otherwise it holds the frame
//! for up to the window, waiting for its own next sample. Only a frame that matches none of
//! these is a discrepancy. (Channel A, for its part, holds a frame with changed data until B's
//! sample agrees, for up to the same window: `dual_channel::runtime`; so the window applies
//! alike whichever contact moved first.) The window must stay well below the smallest SRVT of
//! the consumers (the inverted frame may leave up to one window late) and above the link
//! latency; the default is [`SAMPLE_WINDOW`].
//!
//! # The window bounds the age of what B co-signs
//!
//! The window is counted from B's own reading of its inputs, and holds at the instant the
//! inverted frame is handed to the controller (CiA 304 9.5; the sample-window part of the
//! SFRT):
//!
//! - B co-signs only a value its inputs read less than the window before: its current sample
//!   counts from the last time the inputs were read ([`Role::sampled`] for a sample with no
//!   change, [`Role::input`] for a change), its previous sample from the last reading before
//!   the change, not from the reading that found the change (up to a sample period later);
//! - a plain frame waits for B's sample, or for its announcement, at most the window counted
//!   from its arrival on the bus, so the inverted frame follows the plain frame within the
//!   window (the consumers' SRVT must allow it);
//! - what falls due at an instant is settled before anything else that arrives at that instant
//!   is handled: a sample or an announcement that comes just as a frame's wait ends does not
//!   get the frame co-signed after its time.

use crate::diverse::{DiverseError, InputTable, compare_and_invert};
use crate::signature::{Parameters, signature};
use dual_channel::runtime::{ChannelFault, FrameSlots, Role, SAMPLE_WINDOW, fold_signatures};
use shared::canopen::od::Address;
use shared::safety::config::{SafetyConfig, SrdoRecord};
use shared::safety::types::SrdoNumber;
use shared::{CanFrame, CanId, Duration, Instant};

/// The default discrepancy window.
pub const DEFAULT_WINDOW: Duration = SAMPLE_WINDOW;

/// A plain frame channel B could not confirm yet.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Held {
    frame: CanFrame,
    srdo: SrdoNumber,
    since: Instant,
    /// An exact copy of the plain frame seen before it, within the window: if no
    /// announcement comes for it, it was that frame received twice.
    copy: bool,
}

/// Channel B's role: its own inputs, in its own layout, and the discrepancy window.
#[derive(Clone, Debug)]
pub struct ChannelB {
    inputs: InputTable,
    /// When [`ChannelB::inputs`] were last read (`None`: never).
    read_at: Option<Instant>,
    /// When the inputs last changed: further changes at that instant belong to the same
    /// sample.
    changed_at: Option<Instant>,
    /// The inputs before the latest change, and when they were last read.
    previous: Option<(InputTable, Instant)>,
    /// A plain frame announced by channel A, confirmed by B's sample, waiting for B's next
    /// sample.
    held: Option<Held>,
    /// A plain frame on the bus not announced by channel A yet.
    unannounced: Option<Held>,
    /// Channel A's announced plain frame per SRDO not seen on the bus yet.
    announced: FrameSlots<4>,
    /// Channel A's announcements of its ended epoch (made before its NMT reset) whose plain
    /// frame this channel has not seen yet: the frame was still in A's transmit queue at the
    /// reset, and reaches the bus after the NMT frame ([`Role::peer_reset`]).
    ended: FrameSlots<4>,
    /// Until when [`ChannelB::ended`] is kept: the window from A's heartbeat of the new epoch.
    ended_until: Instant,
    /// A plain frame this channel saw before its own NMT reset, not announced yet: its
    /// announcement, still on the link, is of the ended epoch ([`Role::reset`]). Or one seen
    /// after that reset, before channel A's heartbeat of the new epoch, and followed by a
    /// plain frame with other data before its announcement ([`ChannelB::ahead_of_peer`]).
    ended_unannounced: Option<Held>,
    /// NMT resets of this channel not yet matched by channel A's heartbeat of a new epoch
    /// (positive: this channel reset first, and an announcement A made before its own reset
    /// may still be on the link), or the other way round (negative). Both channels handle
    /// every NMT reset, each in its own loop, so it returns to 0.
    epoch_lead: i8,
    /// The last plain frame seen on the bus, and when (its copy within the window is a double
    /// reception).
    last_plain: Option<(CanFrame, Instant)>,
    window: Duration,
}

impl ChannelB {
    /// Channel B with the inputs it samples (index, sub-index, length in bytes).
    pub fn new(inputs: &[(u16, u8, u8)]) -> Result<Self, DiverseError> {
        let mut table = InputTable::new();
        for &(index, sub, len) in inputs {
            table.declare(index, sub, len)?;
        }
        Ok(ChannelB {
            inputs: table,
            read_at: None,
            changed_at: None,
            previous: None,
            held: None,
            unannounced: None,
            announced: FrameSlots::default(),
            ended: FrameSlots::default(),
            ended_until: Instant::NEVER,
            ended_unannounced: None,
            epoch_lead: 0,
            last_plain: None,
            window: DEFAULT_WINDOW,
        })
    }

    /// The discrepancy window.
    pub fn window(&self) -> Duration {
        self.window
    }

    /// `true` between this channel's NMT reset and channel A's heartbeat of the new epoch
    /// (the link keeps its order: A's announcements of before its reset come before that
    /// heartbeat).
    fn ahead_of_peer(&self) -> bool {
        self.epoch_lead > 0
    }

    /// The inverted frame for `frame` if it matches `inputs`.
    fn confirm(frame: &CanFrame, record: &SrdoRecord, inputs: &InputTable) -> Option<CanFrame> {
        let mapping = &record.mapping[..usize::from(record.mapping_count).min(16)];
        let inverted = compare_and_invert(frame.data(), mapping, inputs).ok()?;
        let id = CanId::new((record.cob_id_2 & 0x7FF) as u16).ok()?;
        CanFrame::new(id, &inverted[..frame.data().len()]).ok()
    }

    /// `true` when a sample last read at `read` is younger than the window at `now`.
    fn fresh(&self, read: Instant, now: Instant) -> bool {
        !shared::time::expired(read + self.window, now)
    }

    /// The inverted frame for `frame` from B's current sample, or its previous one, whichever
    /// agrees and was read within the window at `now`.
    fn confirm_fresh(
        &self,
        now: Instant,
        frame: &CanFrame,
        record: &SrdoRecord,
    ) -> Option<CanFrame> {
        let current = self
            .read_at
            .filter(|read| self.fresh(*read, now))
            .and_then(|_| Self::confirm(frame, record, &self.inputs));
        current.or_else(|| {
            let (previous, read) = self.previous.as_ref()?;
            if self.fresh(*read, now) {
                Self::confirm(frame, record, previous)
            } else {
                None
            }
        })
    }

    /// A plain frame both on the bus (since `seen`) and announced by channel A: the inverted
    /// frame if B's current sample, or its previous one, read within the window agrees;
    /// otherwise it waits for B's next sample, until the window counted from `seen` ends.
    fn co_sign(
        &mut self,
        now: Instant,
        seen: Instant,
        frame: &CanFrame,
        srdo: SrdoNumber,
        record: &SrdoRecord,
    ) -> Result<Option<CanFrame>, ChannelFault> {
        if let Some(held) = self.held.take() {
            // A new plain frame while the last one is unconfirmed: the last one stays
            // unconfirmed for good.
            return Err(ChannelFault::TransmitMismatch { srdo: held.srdo });
        }
        if let Some(inverted) = self.confirm_fresh(now, frame, record) {
            return Ok(Some(inverted));
        }
        self.held = Some(Held {
            frame: *frame,
            srdo,
            since: seen,
            copy: false,
        });
        Ok(None)
    }

    /// Settles what is due at `now`: a plain frame never announced within the window is
    /// foreign (its copy is dropped), one held past the window is a discrepancy. Every entry
    /// point runs this first, so nothing that arrives at or after a wait's end acts on it.
    fn expire(&mut self, now: Instant) -> Result<(), ChannelFault> {
        self.expire_ended(now);
        if self
            .ended_unannounced
            .is_some_and(|seen| shared::time::expired(seen.since + self.window, now))
        {
            // Of this channel's ended epoch, never co-signed: a foreign frame then is channel
            // A's to find (it receives every plain frame but its own), a copy is a double
            // reception.
            self.ended_unannounced = None;
        }
        if let Some(seen) = self
            .unannounced
            .filter(|seen| shared::time::expired(seen.since + self.window, now))
        {
            self.unannounced = None;
            if !seen.copy {
                return Err(ChannelFault::ForeignFrame {
                    id: seen.frame.id().raw(),
                });
            }
        }
        match self.held {
            Some(held) if shared::time::expired(held.since + self.window, now) => {
                self.held = None;
                Err(ChannelFault::TransmitMismatch { srdo: held.srdo })
            }
            _ => Ok(()),
        }
    }

    /// Forgets the announcements of A's ended epoch at the end of their window
    /// ([`ChannelB::ended_until`]): a frame of that epoch not on the bus a window after A's
    /// heartbeat of the new epoch was lost on the way (or its controller gave it up), and its
    /// announcement must not let a later frame with the same data go by unsigned.
    fn expire_ended(&mut self, now: Instant) {
        if shared::time::expired(self.ended_until, now) {
            self.ended.clear();
            self.ended_until = Instant::NEVER;
        }
    }

    /// The held frame's inverted frame if B's current sample, read at `now`, agrees.
    fn release_held<const N: usize>(
        &mut self,
        now: Instant,
        config: &SafetyConfig<N>,
    ) -> Result<Option<CanFrame>, ChannelFault> {
        let Some(held) = self.held else {
            return Ok(None);
        };
        let Some((_, record)) = transmit_srdo(config, held.frame.id().raw()) else {
            self.held = None;
            return Err(ChannelFault::TransmitMismatch { srdo: held.srdo });
        };
        match self.confirm_fresh(now, &held.frame, record) {
            Some(inverted) => {
                self.held = None;
                Ok(Some(inverted))
            }
            None => Ok(None),
        }
    }
}

/// `true` when `id` is the inverted identifier (COB-ID 2) of a transmit SRDO of `config`.
fn is_inverted_id<const N: usize>(config: &SafetyConfig<N>, id: u16) -> bool {
    config
        .srdos
        .iter()
        .any(|record| record.direction == 1 && record.cob_id_2 & 0x7FF == u32::from(id))
}

/// The transmit SRDO whose plain COB-ID is `id`, read by channel B itself from the raw
/// records (direction 1).
fn transmit_srdo<const N: usize>(
    config: &SafetyConfig<N>,
    id: u16,
) -> Option<(SrdoNumber, &SrdoRecord)> {
    config
        .srdos
        .iter()
        .enumerate()
        .find(|(_, record)| record.direction == 1 && record.cob_id_1 & 0x7FF == u32::from(id))
        // A configuration holds at most 64 SRDOs, so every one has a number.
        .and_then(|(position, record)| Some((SrdoNumber::of_slot(position)?, record)))
}

impl<const N: usize> Role<N> for ChannelB {
    fn outgoing(&mut self, _frame: CanFrame, _config: &SafetyConfig<N>) -> Option<CanFrame> {
        None
    }

    fn observe(
        &mut self,
        now: Instant,
        frame: &CanFrame,
        config: &SafetyConfig<N>,
    ) -> Result<Option<CanFrame>, ChannelFault> {
        self.observe_seen(now, now, frame, config)
    }

    fn observe_seen(
        &mut self,
        now: Instant,
        seen: Instant,
        frame: &CanFrame,
        config: &SafetyConfig<N>,
    ) -> Result<Option<CanFrame>, ChannelFault> {
        self.expire(now)?;
        if frame.is_remote() {
            return Ok(None); // Remote frames on SRDO identifiers are ignored (EN 50325-5 6.2.1).
        }
        let id = frame.id().raw();
        if is_inverted_id(config, id) {
            return Err(ChannelFault::ForeignFrame { id }); // Never our own: we do not receive it.
        }
        let Some((srdo, record)) = transmit_srdo(config, id) else {
            return Ok(None);
        };
        let copy = self
            .last_plain
            .is_some_and(|(last, at)| last == *frame && now.saturating_since(at) < self.window);
        self.last_plain = Some((*frame, seen));
        if let Some(ended) = self.ended.take(frame.id()) {
            if ended == *frame {
                // Channel A's frame of its ended epoch: A cut that pair at its reset, and no
                // announcement of the new epoch is for it (A's frames of one identifier reach
                // the bus in the order A handed them out, so it comes before any of them).
                return Ok(None);
            }
            // Not that frame, so that frame was lost on the way: the announcement goes, and
            // this frame is judged like any other.
        }
        match (self.announced.take(frame.id()), self.unannounced) {
            (Some(announced), _) if announced == *frame => {
                self.co_sign(now, seen, frame, srdo, record)
            }
            (Some(_), _) => Err(ChannelFault::ForeignFrame { id }),
            // The same frame twice before its announcement: received twice.
            (None, Some(seen)) if seen.frame == *frame => Ok(None),
            (None, Some(before))
                if before.frame.id() == frame.id()
                    && self.ahead_of_peer()
                    && self.ended_unannounced.is_none() =>
            {
                // After this channel's reset and before A's heartbeat of the new epoch, the
                // frame before may be A's of the ended epoch (queued at A's reset, overtaken
                // by the reset and the start), its announcement still on the link ahead of
                // that heartbeat, and this one A's first of the new epoch, its announcement
                // behind. The one before takes its announcement away when it comes, as a
                // frame seen before this channel's reset does (`announced`); a different
                // announcement finds it foreign, and so does channel A, which receives every
                // plain frame but its own.
                self.ended_unannounced = Some(before);
                self.unannounced = Some(Held {
                    frame: *frame,
                    srdo,
                    since: seen,
                    copy,
                });
                Ok(None)
            }
            (None, Some(_)) => Err(ChannelFault::ForeignFrame { id }),
            (None, None) => {
                // Channel A may send the same data twice in a row, and the announcement may
                // come after the frame: a copy waits for its announcement like any frame, and
                // only one never announced is a double reception (dropped) rather than foreign.
                self.unannounced = Some(Held {
                    frame: *frame,
                    srdo,
                    since: seen,
                    copy,
                });
                Ok(None)
            }
        }
    }

    fn announced(
        &mut self,
        now: Instant,
        frame: &CanFrame,
        config: &SafetyConfig<N>,
    ) -> Result<Option<CanFrame>, ChannelFault> {
        self.expire(now)?;
        let id = frame.id().raw();
        let Some((srdo, record)) = transmit_srdo(config, id) else {
            // Channel A announces only plain frames of transmit SRDOs: its configuration is
            // not ours (the configuration cross-check reports that too).
            return Err(ChannelFault::ConfigurationMismatch);
        };
        if let Some(seen) = self
            .ended_unannounced
            .take_if(|seen| seen.frame.id() == frame.id())
        {
            // The announcement of the frame this channel saw before its own reset comes first
            // (the link keeps the order): the pair was cut by that reset, nothing is
            // co-signed. Announced otherwise than it came on the bus, the frame was foreign; a
            // copy of the frame before it (a double reception) has no announcement of its own,
            // and this one is for the next frame.
            if seen.frame == *frame {
                return Ok(None);
            }
            if !seen.copy {
                return Err(ChannelFault::ForeignFrame { id });
            }
        }
        match self.unannounced.take() {
            Some(seen) if seen.frame.id() == frame.id() => {
                if seen.frame == *frame {
                    self.co_sign(now, seen.since, frame, srdo, record)
                } else {
                    Err(ChannelFault::ForeignFrame { id })
                }
            }
            other => {
                self.unannounced = other;
                // One announcement per transmit SRDO in flight; with more than four in flight
                // at once the newest is not kept, and its frame is reported as foreign (the
                // safe side).
                let _ = self.announced.keep(*frame);
                Ok(None)
            }
        }
    }

    fn input(
        &mut self,
        now: Instant,
        address: Address,
        value: &[u8],
        config: &SafetyConfig<N>,
    ) -> Result<Option<CanFrame>, ChannelFault> {
        // The sample is taken whatever fell due: the inputs are the pins.
        let expired = self.expire(now);
        let mut bytes = [0u8; 8];
        let len = value.len().min(8);
        bytes[..len].copy_from_slice(&value[..len]);
        let before = self.inputs.clone();
        // An input B does not sample is not B's: its transmit check then fails, as it must.
        let _ = self
            .inputs
            .set(address.index, address.sub, u64::from_le_bytes(bytes));
        if self.inputs != before && self.changed_at != Some(now) {
            // The first change of this sample: the inputs before it were last read at the
            // previous reading (a second input changing in the same sample keeps that).
            self.previous = self.read_at.map(|read| (before, read));
            self.changed_at = Some(now);
        }
        self.read_at = Some(now);
        expired?;
        self.release_held(now, config)
    }

    fn sampled(
        &mut self,
        now: Instant,
        config: &SafetyConfig<N>,
    ) -> Result<Option<CanFrame>, ChannelFault> {
        let expired = self.expire(now);
        self.read_at = Some(now);
        expired?;
        self.release_held(now, config)
    }

    fn window(&self) -> Duration {
        self.window
    }

    /// Channel B's verdict on a SimpleCAN frame is its own decoder's
    /// ([`crate::simplecan::check`]), written apart from the shared one (SC_REQ_10, Model C).
    #[cfg(feature = "simplecan")]
    fn simplecan_decode(
        &self,
        frame: &dual_channel::simplecan::RawFrame,
        hash_of: impl Fn(u8) -> Option<u32>,
    ) -> dual_channel::simplecan::Decoded {
        use crate::simplecan::Verdict;
        use dual_channel::simplecan::Decoded;
        // The runtime hands over data frames only (`RawFrame::of`).
        match crate::simplecan::check(frame.id, false, frame.len, frame.data, hash_of) {
            Verdict::Data {
                sc_id,
                value,
                cycle_stamp,
            } => Decoded::Data {
                sc_id,
                value,
                cycle_stamp,
            },
            Verdict::Sync {
                master,
                cycle,
                offset_micros,
            } => Decoded::Sync {
                master,
                cycle,
                offset_micros,
            },
            Verdict::Invalid(_) | Verdict::NotSimpleCan => Decoded::Invalid,
        }
    }

    fn reset(&mut self) {
        // The pair in progress is forgotten; the input samples are not (they are the pins),
        // and neither are channel A's announcements: one may have arrived just before this
        // channel's own reset, for A's first plain frame after it (A handled the NMT frames
        // first). An announcement only ever lets through a bus frame equal to it, and a newer
        // one for the same SRDO replaces it; those A made before its own reset are set apart
        // when its heartbeat names the new epoch (`peer_reset`).
        //
        // A plain frame seen before this reset and not announced yet is never co-signed, but
        // its announcement is still on the link, and comes before any later one: kept, it
        // takes that announcement away with it (for the window of its arrival). Forgotten, the
        // announcement would wait in its slot for the next plain frame, A's first of the new
        // epoch, and find it foreign when it carries another sample.
        self.held = None;
        self.ended_unannounced = self.unannounced.take();
        self.last_plain = None;
        self.epoch_lead = self.epoch_lead.saturating_add(1).min(1);
    }

    fn peer_reset(&mut self, now: Instant) {
        // What channel A announced before its reset and this channel has not seen on the bus
        // is a plain frame still in A's transmit queue at the reset: it reaches the bus after
        // the NMT frame, before any frame A sends in its new epoch on that identifier, and is
        // co-signed by nobody (A cut that pair). Set apart, its announcement lets that frame
        // go by, neither co-signed nor foreign (`observe_seen`). Left in its slot, it would
        // be taken for the next plain frame on the bus that comes before its own announcement
        // (a slow link): from then on each frame is compared with the announcement before its
        // own, and the first changed data is a foreign frame (34h). Forgotten, the frame of
        // the ended epoch would be unannounced: foreign at the end of the window, or, with
        // A's first frame of the new epoch on the bus before that, co-signed against the new
        // announcement. Announcements made after A's reset come after this heartbeat.
        //
        // Kept for the window from now: the frame was queued before A's reset, so before
        // this heartbeat left A, and only the NMT frames and frames of higher priority go
        // before it. Kept longer, an announcement whose frame was lost (a controller cut off
        // the bus, then the master's reset and start) would let A's first frame of the new
        // epoch go by unsigned when it carries the same data.
        self.ended_until = now + self.window;
        self.epoch_lead = self.epoch_lead.saturating_sub(1).max(-1);
        while let Some(frame) = self.announced.take_any() {
            // As many slots as `announced`: it fits unless frames of four other identifiers
            // are still set apart from an earlier reset, and then the oldest are kept (this
            // frame is then reported as foreign: the safe side).
            let _ = self.ended.keep(frame);
        }
    }

    fn ended_frame(&mut self, now: Instant, frame: &CanFrame) -> bool {
        // Seen before this channel's entry into Operational (or kept since): channel A's
        // frame of its ended epoch goes with its announcement, as in `observe_seen`, however
        // late the master's start comes (the frame is not kept past the window).
        self.expire_ended(now);
        if self.ended.get(frame.id()) == Some(frame) {
            let _ = self.ended.take(frame.id());
            return true;
        }
        false
    }

    fn poll(&mut self, now: Instant) -> Result<(), ChannelFault> {
        self.expire(now)
    }

    fn deadline(&self) -> Instant {
        let held = self
            .held
            .map_or(Instant::NEVER, |held| held.since + self.window);
        let unannounced = self
            .unannounced
            .map_or(Instant::NEVER, |seen| seen.since + self.window);
        held.min(unannounced)
    }

    fn signature_digest(&self, config: &SafetyConfig<N>) -> u32 {
        fold_signatures(config.srdos.iter().map(|record| {
            signature(&Parameters {
                direction: record.direction,
                cycle_time: record.cycle_time,
                srvt: record.srvt,
                cob_id_1: record.cob_id_1,
                cob_id_2: record.cob_id_2,
                mapping: &record.mapping[..usize::from(record.mapping_count).min(16)],
            })
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> SafetyConfig<1> {
        SafetyConfig::<1>::predefined(1, &[0x6000_0108, 0x6001_0108], &[])
    }

    fn frame(id: u16, data: &[u8]) -> CanFrame {
        CanFrame::new(CanId::new(id).unwrap(), data).unwrap()
    }

    /// Channel B whose input reads `value`, last read at [`T`].
    fn b_with(value: u8) -> ChannelB {
        let mut b = ChannelB::new(&[(0x6000, 1, 1)]).unwrap();
        b.input(T, Address::new(0x6000, 1), &[value], &config())
            .unwrap();
        b
    }

    const T: Instant = Instant::from_millis(100);

    /// `microseconds` after `at`.
    fn after(at: Instant, microseconds: u64) -> Instant {
        at + Duration::from_micros(microseconds)
    }

    /// B reads its input at `now` and finds it unchanged.
    fn read(b: &mut ChannelB, now: Instant) -> Result<Option<CanFrame>, ChannelFault> {
        Role::<1>::sampled(b, now, &config())
    }

    /// B reads its input at `now` as `value`.
    fn read_as(
        b: &mut ChannelB,
        now: Instant,
        value: u8,
    ) -> Result<Option<CanFrame>, ChannelFault> {
        b.input(now, Address::new(0x6000, 1), &[value], &config())
    }

    /// B reads its input (unchanged) at `now`, then channel A announces `frame` over the
    /// link and puts it on the bus: what B answers.
    fn sent(
        b: &mut ChannelB,
        now: Instant,
        frame: &CanFrame,
    ) -> Result<Option<CanFrame>, ChannelFault> {
        assert_eq!(read(b, now), Ok(None));
        assert_eq!(b.announced(now, frame, &config()), Ok(None));
        b.observe(now, frame, &config())
    }

    const MISMATCH: Result<(), ChannelFault> = Err(ChannelFault::TransmitMismatch {
        srdo: SrdoNumber::FIRST,
    });

    /// CiA 304 9.5: B answers A's plain frame with the inverted frame when its own input
    /// agrees; B never sends what its core produces.
    #[test]
    fn cia304_9_5_b_sends_the_inverted_frame_after_a_bit_exact_match() {
        let mut b = b_with(0x01);
        assert_eq!(
            sent(&mut b, T, &frame(0x101, &[0x01])),
            Ok(Some(frame(0x102, &[0xFE])))
        );
        // Not a transmit SRDO's plain frame: nothing to do.
        assert_eq!(b.observe(T, &frame(0x701, &[0x05]), &config()), Ok(None));
        assert_eq!(b.outgoing(frame(0x581, &[0; 8]), &config()), None);
    }

    /// CiA 304 9.5: a frame that matches none of B's samples within the window is a
    /// discrepancy, reported with the SRDO number at the end of the window, and nothing is
    /// sent.
    #[test]
    fn cia304_9_5_a_lasting_difference_is_a_discrepancy() {
        let mut b = b_with(0x01);
        assert_eq!(sent(&mut b, T, &frame(0x101, &[0x00])), Ok(None));
        assert_eq!(Role::<1>::deadline(&b), T + DEFAULT_WINDOW);
        assert_eq!(
            Role::<1>::poll(&mut b, T + Duration::from_micros(4_999)),
            Ok(())
        );
        assert_eq!(Role::<1>::poll(&mut b, T + DEFAULT_WINDOW), MISMATCH);
        assert_eq!(Role::<1>::deadline(&b), Instant::NEVER);
    }

    /// A's frame sampled just before B's input changed (B's previous sample, within the
    /// window) is confirmed; after the window it is not.
    #[test]
    fn a_frame_sampled_before_bs_change_is_confirmed_within_the_window() {
        let mut b = b_with(0x01);
        read_as(&mut b, after(T, 500), 0x00).unwrap();
        let soon = T + Duration::from_millis(1);
        assert_eq!(
            sent(&mut b, soon, &frame(0x101, &[0x01])),
            Ok(Some(frame(0x102, &[0xFE])))
        );
        // The next frame, once the window has passed (a copy within it would be a double
        // reception).
        let late = soon + DEFAULT_WINDOW;
        assert_eq!(sent(&mut b, late, &frame(0x101, &[0x01])), Ok(None));
        assert_eq!(Role::<1>::poll(&mut b, late + DEFAULT_WINDOW), MISMATCH);
    }

    /// A's frame carrying a change B has not sampled yet is held, and sent as soon as B's
    /// own sample agrees.
    #[test]
    fn a_frame_ahead_of_bs_sample_is_held_until_b_agrees() {
        let mut b = b_with(0x00);
        assert_eq!(sent(&mut b, T, &frame(0x101, &[0x01])), Ok(None));
        let sampled = T + Duration::from_millis(2);
        assert_eq!(
            read_as(&mut b, sampled, 0x01),
            Ok(Some(frame(0x102, &[0xFE])))
        );
        assert_eq!(Role::<1>::poll(&mut b, T + DEFAULT_WINDOW), Ok(()));
    }

    /// A second plain frame while one is held: the held one is a discrepancy.
    #[test]
    fn a_second_plain_frame_while_one_is_held_is_a_discrepancy() {
        let mut b = b_with(0x00);
        sent(&mut b, T, &frame(0x101, &[0x01])).unwrap();
        assert_eq!(
            sent(&mut b, T, &frame(0x101, &[0x00])),
            Err(ChannelFault::TransmitMismatch {
                srdo: SrdoNumber::FIRST
            })
        );
    }

    /// CiA 304 9.5: B co-signs only the plain frame channel A announced, whichever of the two
    /// arrives first; a plain frame that differs from the announcement, or is never announced
    /// within the window, is foreign, even when it agrees with B's own sample.
    #[test]
    fn cia304_9_5_b_co_signs_only_what_a_announced() {
        let plain = frame(0x101, &[0x01]);
        let inverted = Ok(Some(frame(0x102, &[0xFE])));
        let foreign = Err(ChannelFault::ForeignFrame { id: 0x101 });
        // The bus first, then the link.
        let mut b = b_with(0x01);
        assert_eq!(b.observe(T, &plain, &config()), Ok(None));
        assert_eq!(Role::<1>::deadline(&b), T + DEFAULT_WINDOW);
        assert_eq!(b.announced(T, &plain, &config()), inverted);
        assert_eq!(Role::<1>::deadline(&b), Instant::NEVER);
        // Announced otherwise than it came on the bus (inserted, or corrupted past the CRC).
        let mut b = b_with(0x01);
        assert_eq!(b.observe(T, &plain, &config()), Ok(None));
        assert_eq!(b.announced(T, &frame(0x101, &[0x00]), &config()), foreign);
        let mut b = b_with(0x01);
        assert_eq!(b.announced(T, &frame(0x101, &[0x00]), &config()), Ok(None));
        assert_eq!(b.observe(T, &plain, &config()), foreign);
        // Never announced: foreign at the end of the window.
        let mut b = b_with(0x01);
        assert_eq!(b.observe(T, &plain, &config()), Ok(None));
        assert_eq!(
            Role::<1>::poll(&mut b, T + Duration::from_micros(4_999)),
            Ok(())
        );
        assert_eq!(
            Role::<1>::poll(&mut b, T + DEFAULT_WINDOW),
            foreign.map(|_: Option<CanFrame>| ())
        );
        // An announcement is used once: a replay of the same frame later is foreign.
        let mut b = b_with(0x01);
        assert_eq!(sent(&mut b, T, &plain), inverted);
        let later = T + DEFAULT_WINDOW;
        assert_eq!(b.observe(later, &plain, &config()), Ok(None));
        assert_eq!(
            Role::<1>::poll(&mut b, later + DEFAULT_WINDOW),
            foreign.map(|_: Option<CanFrame>| ())
        );
        // A frame on the inverted identifier is never B's own (B does not receive it).
        let mut b = b_with(0x01);
        assert_eq!(
            b.observe(T, &frame(0x102, &[0xFE]), &config()),
            Err(ChannelFault::ForeignFrame { id: 0x102 })
        );
    }

    /// ISO 11898-1 double reception: an exact copy of the plain frame just seen, within the
    /// window, is ignored; it is not a second frame to co-sign nor a foreign one.
    #[test]
    fn cia304_9_5_a_plain_frame_received_twice_is_co_signed_once() {
        let plain = frame(0x101, &[0x01]);
        let mut b = b_with(0x01);
        assert_eq!(sent(&mut b, T, &plain), Ok(Some(frame(0x102, &[0xFE]))));
        let copy = T + Duration::from_micros(250);
        assert_eq!(b.observe(copy, &plain, &config()), Ok(None));
        assert_eq!(Role::<1>::poll(&mut b, copy + DEFAULT_WINDOW), Ok(()));
        assert_eq!(Role::<1>::deadline(&b), Instant::NEVER);
        // Channel A sending the same data again at once is a new pair, not a copy: once it is
        // announced (here after the frame), it is co-signed.
        let mut b = b_with(0x01);
        assert_eq!(sent(&mut b, T, &plain), Ok(Some(frame(0x102, &[0xFE]))));
        assert_eq!(b.observe(copy, &plain, &config()), Ok(None));
        assert_eq!(
            b.announced(copy, &plain, &config()),
            Ok(Some(frame(0x102, &[0xFE])))
        );
    }

    /// CiA 304 9.5, the sample window: B co-signs only a value its input read less than the
    /// window before the inverted frame leaves. A board that stops reading its pins gets
    /// nothing co-signed once its last reading is a window old; a reading of the same value
    /// releases the frame.
    #[test]
    fn cia304_9_5_b_co_signs_only_a_sample_read_within_the_window() {
        let plain = frame(0x101, &[0x01]);
        let inverted = Ok(Some(frame(0x102, &[0xFE])));
        // Read at T, not since: still fresh a microsecond before the window ends.
        let mut b = b_with(0x01);
        let just_inside = after(T, DEFAULT_WINDOW.as_micros() - 1);
        assert_eq!(b.announced(just_inside, &plain, &config()), Ok(None));
        assert_eq!(b.observe(just_inside, &plain, &config()), inverted);
        // At the window's end the same reading is too old: the frame waits for a new one.
        let mut b = b_with(0x01);
        let at_end = T + DEFAULT_WINDOW;
        assert_eq!(b.announced(at_end, &plain, &config()), Ok(None));
        assert_eq!(b.observe(at_end, &plain, &config()), Ok(None));
        assert_eq!(read(&mut b, after(at_end, 300)), inverted);
        // Never read again: a discrepancy a window after the frame.
        let mut b = b_with(0x01);
        assert_eq!(b.announced(at_end, &plain, &config()), Ok(None));
        assert_eq!(b.observe(at_end, &plain, &config()), Ok(None));
        assert_eq!(Role::<1>::poll(&mut b, at_end + DEFAULT_WINDOW), MISMATCH);
    }

    /// CiA 304 9.5, the sample window: B's previous sample ages from the last reading that
    /// found it, not from the reading that found the change (up to a sample period later).
    #[test]
    fn cia304_9_5_the_previous_sample_ages_from_its_last_reading() {
        let plain = frame(0x101, &[0x01]);
        let window = DEFAULT_WINDOW.as_micros();
        let mut b = b_with(0x01);
        // Last read as 1 at T; the change to 0 found 900 µs later.
        read_as(&mut b, after(T, 900), 0x00).unwrap();
        // Within the window of the last reading of 1: co-signed.
        let inside = after(T, window - 1);
        assert_eq!(
            sent(&mut b, inside, &plain),
            Ok(Some(frame(0x102, &[0xFE])))
        );
        // Within the window of the change but not of the last reading of 1: held, and a
        // discrepancy at the end of the window.
        let mut b = b_with(0x01);
        read_as(&mut b, after(T, 900), 0x00).unwrap();
        let outside = after(T, window + 500);
        assert_eq!(sent(&mut b, outside, &plain), Ok(None));
        assert_eq!(Role::<1>::poll(&mut b, outside + DEFAULT_WINDOW), MISMATCH);
    }

    /// Two inputs changing in one sample: the previous sample is the one before the sample,
    /// not the half-changed table between the two changes.
    #[test]
    fn cia304_9_5_changes_found_by_one_sample_make_one_previous_sample() {
        let config = SafetyConfig::<1>::predefined(1, &[0x6000_0108, 0x6001_0108], &[]);
        let mut b = ChannelB::new(&[(0x6000, 1, 1), (0x6000, 2, 1)]).unwrap();
        let first = Address::new(0x6000, 1);
        let second = Address::new(0x6000, 2);
        b.input(T, first, &[1], &config).unwrap();
        b.input(T, second, &[1], &config).unwrap();
        let sample = after(T, 1000);
        b.input(sample, first, &[0], &config).unwrap();
        b.input(sample, second, &[0], &config).unwrap();
        let (previous, read) = b.previous.clone().expect("a previous sample");
        assert_eq!(read, T);
        let mut both_one = InputTable::new();
        both_one.declare(0x6000, 1, 1).unwrap();
        both_one.declare(0x6000, 2, 1).unwrap();
        both_one.set(0x6000, 1, 1).unwrap();
        both_one.set(0x6000, 2, 1).unwrap();
        assert_eq!(previous, both_one);
    }

    /// CiA 304 9.5, EN 50325-5 7.1.1: a plain frame's wait, for B's sample or for channel
    /// A's announcement, counts from its arrival on the bus, and ends before anything that
    /// arrives at its end is handled: the inverted frame never follows the plain frame by
    /// the window or more.
    #[test]
    fn cia304_9_5_a_frames_wait_counts_from_its_arrival_and_ends_first() {
        let plain = frame(0x101, &[0x01]);
        let foreign = Err(ChannelFault::ForeignFrame { id: 0x101 });
        // Seen at T, announced exactly a window later: foreign, not co-signed.
        let mut b = b_with(0x01);
        assert_eq!(b.observe(T, &plain, &config()), Ok(None));
        assert_eq!(b.announced(T + DEFAULT_WINDOW, &plain, &config()), foreign);
        // Seen at T, announced 2 ms later while B's sample disagrees: held from T, so a
        // sample that agrees at the window's end comes too late.
        let mut b = b_with(0x00);
        assert_eq!(b.observe(T, &plain, &config()), Ok(None));
        let announced = after(T, 2000);
        assert_eq!(read(&mut b, announced), Ok(None));
        assert_eq!(b.announced(announced, &plain, &config()), Ok(None));
        assert_eq!(Role::<1>::deadline(&b), T + DEFAULT_WINDOW);
        assert_eq!(
            read_as(&mut b, T + DEFAULT_WINDOW, 0x01),
            MISMATCH.map(|()| None)
        );
        // The sample is still taken: a frame after it is checked against the new value.
        let mut one = InputTable::new();
        one.declare(0x6000, 1, 1).unwrap();
        one.set(0x6000, 1, 1).unwrap();
        assert_eq!(b.inputs, one);
    }

    /// CiA 304 9.5: a plain frame channel A announced before its NMT reset and that reached the
    /// bus after it (it waited in A's transmit queue) is A's own, of a pair A cut: once A's
    /// heartbeat named the new epoch, B lets it go by, neither co-signed nor foreign, in
    /// Operational or before, and co-signs A's first frame of the new epoch against its own
    /// announcement, whichever of the two comes first.
    #[test]
    fn cia304_9_5_the_ended_epochs_plain_frame_is_neither_co_signed_nor_foreign() {
        let old = frame(0x101, &[0x01]);
        let new = frame(0x101, &[0x00]);
        let inverted = Ok(Some(frame(0x102, &[0xFF])));
        // In Operational, the new announcement before the old frame (B's bus frames late).
        let mut b = b_with(0x00);
        assert_eq!(b.announced(T, &old, &config()), Ok(None));
        Role::<1>::peer_reset(&mut b, T);
        let later = after(T, 1000);
        assert_eq!(b.announced(later, &new, &config()), Ok(None));
        assert_eq!(b.observe(later, &old, &config()), Ok(None));
        assert_eq!(Role::<1>::deadline(&b), Instant::NEVER, "nothing waits");
        assert_eq!(b.observe(later, &new, &config()), inverted);
        // Before Operational: the runtime does not keep it for the entry into Operational, and
        // the new frame before its announcement is co-signed when the announcement comes.
        let mut b = b_with(0x00);
        assert_eq!(b.announced(T, &old, &config()), Ok(None));
        Role::<1>::reset(&mut b);
        Role::<1>::peer_reset(&mut b, T);
        assert!(Role::<1>::ended_frame(&mut b, later, &old));
        assert!(
            !Role::<1>::ended_frame(&mut b, later, &old),
            "one frame per announcement"
        );
        assert_eq!(b.observe(later, &new, &config()), Ok(None));
        assert_eq!(b.announced(later, &new, &config()), inverted);
        // Kept for the window from A's heartbeat: after it, a frame with the same data is A's
        // first of the new epoch (the old one was lost on the way), co-signed against its own
        // announcement.
        let mut b = b_with(0x01);
        assert_eq!(b.announced(T, &old, &config()), Ok(None));
        Role::<1>::peer_reset(&mut b, T);
        let next = T + DEFAULT_WINDOW;
        assert_eq!(read(&mut b, next), Ok(None));
        assert_eq!(b.observe(next, &old, &config()), Ok(None));
        assert_eq!(
            b.announced(next, &old, &config()),
            Ok(Some(frame(0x102, &[0xFE])))
        );
        // A replay of the old frame after it (past the window: within it, an exact copy is a
        // double reception) is judged like any frame: never announced, it is foreign at the
        // end of the window.
        let mut b = b_with(0x00);
        assert_eq!(b.announced(T, &old, &config()), Ok(None));
        Role::<1>::peer_reset(&mut b, T);
        assert_eq!(b.observe(later, &old, &config()), Ok(None));
        let replay = later + DEFAULT_WINDOW;
        assert_eq!(b.observe(replay, &old, &config()), Ok(None));
        assert_eq!(
            Role::<1>::poll(&mut b, replay + DEFAULT_WINDOW),
            Err(ChannelFault::ForeignFrame { id: 0x101 })
        );
    }

    /// CiA 304 9.5: a plain frame B saw before its own NMT reset, whose announcement comes
    /// after it, goes with that announcement, co-signed by nobody; the next announcement, of A's
    /// first frame after the reset with another sample, is that frame's, not foreign. An
    /// announcement of other data is still foreign to the frame B saw, and B keeps the frame
    /// no longer than the window of its arrival.
    #[test]
    fn cia304_9_5_a_frame_seen_before_bs_reset_goes_with_its_late_announcement() {
        let old = frame(0x101, &[0x01]);
        let new = frame(0x101, &[0x00]);
        let mut b = b_with(0x00);
        assert_eq!(b.observe(T, &old, &config()), Ok(None));
        Role::<1>::reset(&mut b);
        assert_eq!(
            Role::<1>::deadline(&b),
            Instant::NEVER,
            "B's wait ends at its reset"
        );
        let later = after(T, 1000);
        assert_eq!(b.observe(later, &new, &config()), Ok(None));
        assert_eq!(b.announced(later, &old, &config()), Ok(None));
        assert_eq!(
            b.announced(later, &new, &config()),
            Ok(Some(frame(0x102, &[0xFF])))
        );
        // Announced otherwise than it came on the bus: foreign.
        let mut b = b_with(0x00);
        assert_eq!(b.observe(T, &old, &config()), Ok(None));
        Role::<1>::reset(&mut b);
        assert_eq!(
            b.announced(later, &new, &config()),
            Err(ChannelFault::ForeignFrame { id: 0x101 })
        );
        // Its announcement later than the window: the frame is gone, the announcement waits
        // for its own frame.
        let mut b = b_with(0x01);
        assert_eq!(b.observe(T, &old, &config()), Ok(None));
        Role::<1>::reset(&mut b);
        let late = T + DEFAULT_WINDOW;
        assert_eq!(read(&mut b, late), Ok(None));
        assert_eq!(b.announced(late, &old, &config()), Ok(None));
        assert_eq!(
            b.observe(late, &old, &config()),
            Ok(Some(frame(0x102, &[0xFE])))
        );
    }

    /// Both channels fold the same signatures, each computed its own way.
    #[test]
    fn the_digests_of_both_channels_agree() {
        let b = b_with(0);
        let config = config();
        assert_eq!(
            Role::<1>::signature_digest(&b, &config),
            fold_signatures(config.srdos.iter().map(shared::safety::signature::compute))
        );
    }

    /// CiA 304 9.5 (the model's trail after the consumer's first-pair fix,
    /// `docs/model-checking.md`): B's contact opens, B handles the NMT reset and start, then
    /// takes two plain frames before any announcement: A's frame of the ended epoch (queued
    /// at A's reset, overtaken by the reset and the start; its announcement still on the link,
    /// ahead of A's heartbeat of the new epoch) and A's first frame of the new epoch, with the
    /// new sample. Neither is foreign: the ended epoch's frame goes with its announcement,
    /// co-signed by nobody, and the new frame is co-signed against its own. Before B kept the
    /// first frame for its announcement while A's heartbeat of the new epoch had not come, the
    /// second frame was a foreign frame (34h) at once.
    #[test]
    fn cia304_9_5_the_ended_epochs_frame_and_as_first_new_frame_before_their_announcements() {
        let old = frame(0x101, &[0x01]);
        let new = frame(0x101, &[0x00]);
        let mut b = b_with(0x01);
        assert_eq!(read_as(&mut b, after(T, 100), 0x00), Ok(None));
        Role::<1>::reset(&mut b);
        assert_eq!(b.observe(after(T, 300), &old, &config()), Ok(None));
        assert_eq!(b.observe(after(T, 500), &new, &config()), Ok(None));
        assert_eq!(b.announced(after(T, 600), &old, &config()), Ok(None));
        Role::<1>::peer_reset(&mut b, after(T, 700));
        assert_eq!(
            b.announced(after(T, 800), &new, &config()),
            Ok(Some(frame(0x102, &[0xFF])))
        );
        assert_eq!(Role::<1>::deadline(&b), Instant::NEVER, "nothing waits");
        assert_eq!(
            Role::<1>::poll(&mut b, T + DEFAULT_WINDOW + DEFAULT_WINDOW),
            Ok(())
        );
    }

    /// EN 50325-5 7.2.1: keeping the first of two unannounced plain frames for its
    /// announcement, between B's reset and A's heartbeat of the new epoch, hides no foreign
    /// frame. A frame on A's plain identifier that A never announced, then A's first frame of
    /// the new epoch: the announcement of A's frame finds the other foreign (34h). Outside
    /// that interval (A's heartbeat of the new epoch came, or B was not reset), a second plain
    /// frame with other data before the announcement of the first is foreign at once.
    #[test]
    fn en50325_5_7_2_1_a_foreign_frame_before_as_first_frame_after_the_reset_is_detected() {
        let foreign = frame(0x101, &[0x03]);
        let new = frame(0x101, &[0x00]);
        let mut b = b_with(0x00);
        Role::<1>::reset(&mut b);
        assert_eq!(b.observe(after(T, 300), &foreign, &config()), Ok(None));
        assert_eq!(b.observe(after(T, 500), &new, &config()), Ok(None));
        Role::<1>::peer_reset(&mut b, after(T, 600));
        assert_eq!(
            b.announced(after(T, 800), &new, &config()),
            Err(ChannelFault::ForeignFrame { id: 0x101 })
        );
        for reset in [true, false] {
            let mut b = b_with(0x00);
            if reset {
                Role::<1>::reset(&mut b);
                Role::<1>::peer_reset(&mut b, T);
            }
            assert_eq!(b.observe(after(T, 300), &foreign, &config()), Ok(None));
            assert_eq!(
                b.observe(after(T, 500), &new, &config()),
                Err(ChannelFault::ForeignFrame { id: 0x101 }),
                "reset and heartbeat: {reset}"
            );
        }
    }
}
