//! SimpleCAN on the two channels (SC_REQ_10, SC_REQ_24): the checks each channel runs beside
//! its core, which the runtime drives (`runtime::simplecan`, feature `simplecan`).
//!
//! - [`ForwardCheck`]: channel B pairs each SimpleCAN frame it hears with channel A's copy;
//! - [`VerdictCheck`] keyed by [`ConsumedEntry`]: both channels' verdicts on each consumed
//!   data packet, compared as for SRDOs;
//! - [`transmit::TransmitCheck`]: Model A for transmission, channel B's check of the packets
//!   channel A puts on the bus against the ones B computed;
//! - [`Checks`]: the three together with the consumed values' outputs, one per channel.
//!
//! The rest of this page is about forwarding.
//!
//! Model III: both controllers hang on one transceiver, so channel B hears every SimpleCAN
//! frame on the bus itself, and channel A forwards the same frame over the link as it
//! received it (`Message::SimpleCanPacket`). B pairs the two copies in bus order, which both
//! controllers see alike: each frame B heard must come from A, equal byte for byte, within
//! `bound`, and each forwarded copy must be one B heard. A copy that differs, one that does
//! not come, or one B never heard is a fault of the pair of channels (the link, A's
//! controller or B's): B goes to the safe state with its own cause, rather than decoding
//! either copy.
//!
//! Sans-I/O: fed frames and `now`, it returns faults and the next deadline.

use crate::crosscheck::{CrossFault, Stream, Verdict, VerdictCheck};
use crate::link::Message;
use crate::runtime::{ChannelEvent, ChannelProtocol, Io};
use shared::CanFrame;
use shared::node::SrdoAndSimpleCan;
use shared::node::simplecan::{EntryObjects, ROLE_CONSUME, ROLE_PRODUCE};
use shared::safety::cause::Cause;
use shared::{Duration, Instant};

pub mod transmit;

pub use transmit::{Bounds, OnBus, SYNC_OFFSET_TOLERANCE, TransmitCheck};

/// How many frames may wait for their other copy; more is a fault (`Overrun`). A SimpleCAN
/// frame takes at least 111 bit times on the bus (8 bytes, base identifier, no stuff bits,
/// interframe space), so 8 waiting frames span at least 888 µs at 1 Mbit/s: a bound up to
/// that never overruns, even on a bus full of SimpleCAN frames.
pub const DEPTH: usize = 8;

/// One SimpleCAN frame as a controller received it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RawFrame {
    /// CAN identifier.
    pub id: u16,
    /// Data length code.
    pub len: u8,
    /// Payload, bytes beyond `len` 0.
    pub data: [u8; 8],
}

impl RawFrame {
    /// `frame` as a SimpleCAN frame: `None` unless it is a data frame on 02Fh..07Fh. A
    /// remote frame there is no packet (docs/simplecan.md section 10: rejected before the
    /// CRC is looked at): each channel's core rejects its own reception, and there is nothing
    /// to forward, pair or judge.
    pub fn of(frame: &CanFrame) -> Option<RawFrame> {
        let id = frame.id();
        if frame.is_remote() || !shared::simplecan::frame::is_simplecan(id) {
            return None;
        }
        Some(RawFrame {
            id: id.raw(),
            len: frame.dlc(),
            data: *frame.raw_data(),
        })
    }

    /// The link message channel A sends for this frame: the frame, not unpacked.
    pub const fn forward(self) -> Message {
        Message::SimpleCanPacket {
            id: self.id,
            len: self.len,
            data: self.data,
        }
    }
}

/// Why the two copies of a SimpleCAN frame do not agree.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ForwardFault {
    /// The forwarded copy differs from the frame B heard.
    Differs {
        /// The identifier B heard.
        heard: u16,
        /// The identifier of A's copy.
        forwarded: u16,
    },
    /// B heard this frame, and A's copy did not come within the bound.
    Lost {
        /// The identifier.
        id: u16,
    },
    /// A forwarded this frame, and B did not hear it within the bound.
    Unheard {
        /// The identifier.
        id: u16,
    },
    /// More than [`DEPTH`] frames wait for their other copy.
    Overrun,
}

type Waiting = heapless::Deque<(RawFrame, Instant), DEPTH>;

/// Channel B's pairing of the frames it hears with those A forwards.
#[derive(Clone, Debug)]
pub struct ForwardCheck {
    bound: Duration,
    heard: Waiting,
    forwarded: Waiting,
}

impl ForwardCheck {
    /// A check that waits at most `bound` for the second copy of a frame.
    pub fn new(bound: Duration) -> Self {
        ForwardCheck {
            bound,
            heard: Waiting::new(),
            forwarded: Waiting::new(),
        }
    }

    /// B's controller received `frame` at `now`. `Ok(Some(frame))`: both copies agree and
    /// the frame is B's to decode.
    pub fn heard(
        &mut self,
        now: Instant,
        frame: RawFrame,
    ) -> Result<Option<RawFrame>, ForwardFault> {
        Self::pair(now, self.bound, frame, &mut self.forwarded, &mut self.heard)
            .map_err(|fault| fault.map_or(ForwardFault::Overrun, |a| Self::differs(frame, a)))
    }

    /// A's copy of a frame came over the link at `now`.
    pub fn forwarded(
        &mut self,
        now: Instant,
        frame: RawFrame,
    ) -> Result<Option<RawFrame>, ForwardFault> {
        Self::pair(now, self.bound, frame, &mut self.heard, &mut self.forwarded)
            .map_err(|fault| fault.map_or(ForwardFault::Overrun, |b| Self::differs(b, frame)))
    }

    fn differs(heard: RawFrame, forwarded: RawFrame) -> ForwardFault {
        ForwardFault::Differs {
            heard: heard.id,
            forwarded: forwarded.id,
        }
    }

    /// Pairs `frame` with the oldest waiting copy of the other side, or queues it.
    /// `Err(Some(other))`: the copies differ; `Err(None)`: the queue is full.
    // Out of line in the images: a marker of the emulator's profile
    // (`emulator::profile::MARKERS`), found in every activation that runs it.
    #[cfg_attr(target_os = "none", inline(never))]
    fn pair(
        now: Instant,
        bound: Duration,
        frame: RawFrame,
        others: &mut Waiting,
        mine: &mut Waiting,
    ) -> Result<Option<RawFrame>, Option<RawFrame>> {
        match others.pop_front() {
            Some((other, _)) if other == frame => Ok(Some(frame)),
            Some((other, _)) => Err(Some(other)),
            None => mine
                .push_back((frame, now + bound))
                .map(|()| None)
                .map_err(|_| None),
        }
    }

    /// The fault of a copy whose other one is overdue at `now`, if any.
    pub fn poll(&self, now: Instant) -> Result<(), ForwardFault> {
        if let Some((frame, deadline)) = self.heard.front() {
            if now >= *deadline {
                return Err(ForwardFault::Lost { id: frame.id });
            }
        }
        if let Some((frame, deadline)) = self.forwarded.front() {
            if now >= *deadline {
                return Err(ForwardFault::Unheard { id: frame.id });
            }
        }
        Ok(())
    }

    /// `true` when no copy waits for its other one: [`poll`](Self::poll) finds no fault and
    /// [`deadline`](Self::deadline) is `None`.
    pub fn is_idle(&self) -> bool {
        self.heard.is_empty() && self.forwarded.is_empty()
    }

    /// When [`poll`](Self::poll) must run next, if a copy waits.
    pub fn deadline(&self) -> Option<Instant> {
        let heard = self.heard.front().map(|(_, at)| *at);
        let forwarded = self.forwarded.front().map(|(_, at)| *at);
        match (heard, forwarded) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }
}

/// How many SDD entries a channel cross-checks verdicts for: the host simulations' devices'
/// four (`SimpleCanNode<_, 4, 4>`). A layer with more entries does not build
/// ([`ChannelProtocol::simplecan`] asserts it when compiled).
#[cfg(not(target_os = "none"))]
pub const ENTRIES: usize = 4;
/// How many SDD entries a channel cross-checks verdicts for: the firmware images' two
/// (`board::SIMPLECAN_ENTRIES`); the checks' RAM grows with it (docs/footprint.md). A layer
/// with more entries does not build ([`ChannelProtocol::simplecan`] asserts it when
/// compiled).
#[cfg(target_os = "none")]
pub const ENTRIES: usize = 2;

/// A consumed SDD entry, by its number (1-based: 5E10h + entry − 1), as the verdict
/// cross-check keeps verdicts apart.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ConsumedEntry(u8);

impl ConsumedEntry {
    /// The entry number, `1..=ENTRIES`.
    pub const fn get(self) -> u8 {
        self.0
    }
}

impl Stream for ConsumedEntry {
    fn from_number(number: u8) -> Option<Self> {
        (1..=ENTRIES)
            .contains(&usize::from(number))
            .then_some(ConsumedEntry(number))
    }
    fn index(self) -> usize {
        usize::from(self.0) - 1
    }
}

/// The SimpleCAN layer of a channel's core as the checks read it: its entries in use (at
/// most [`ENTRIES`]), whether it is the node's potential master, whether it runs, and how
/// many data packets it accepted. A copy, so that a check can hold it while the core runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layer {
    /// The entries in use, the first `count` of them.
    pub entries: [EntryObjects; ENTRIES],
    /// How many are in use.
    pub count: usize,
    /// 5E00h:05: this node sends syncs as its lowest produced SC-ID.
    pub potential_master: bool,
    /// Operational, configuration accepted: the layer sends and receives.
    pub running: bool,
    /// Data packets it accepted and delivered since the Operational entry.
    pub accepted: u32,
    /// 5E00h:03, the stated maximum buffering time of a received packet (SC_REQ_33).
    pub buffering: Duration,
}

impl Layer {
    fn in_use(&self) -> &[EntryObjects] {
        self.entries.get(..self.count).unwrap_or(&self.entries)
    }

    /// The node hash of `sc_id`, if an entry in use has it (SC_REQ_15).
    pub fn hash_of(&self, sc_id: u8) -> Option<u32> {
        self.in_use()
            .iter()
            .find(|entry| entry.sc_id == sc_id)
            .map(|entry| entry.hash)
    }

    /// The consumed entry of `sc_id` and the entry's number, if the node consumes it.
    pub fn consumed(&self, sc_id: u8) -> Option<ConsumedEntry> {
        let index = self
            .in_use()
            .iter()
            .position(|entry| entry.sc_id == sc_id && entry.role == ROLE_CONSUME)?;
        // At most ENTRIES entries (4 on the host, 2 in the images): fits a u8.
        ConsumedEntry::from_number(index as u8 + 1)
    }

    /// The SC-ID this node's syncs carry: its lowest produced one, when it is a potential
    /// master (docs/simplecan.md section 3).
    pub fn master_sc_id(&self) -> Option<u8> {
        if !self.potential_master {
            return None;
        }
        self.in_use()
            .iter()
            .filter(|entry| entry.role == ROLE_PRODUCE)
            .map(|entry| entry.sc_id)
            .min()
    }

    /// The entries that produce their value from the object at `address`.
    pub fn produced_from(
        &self,
        address: shared::canopen::od::Address,
    ) -> impl Iterator<Item = &EntryObjects> {
        self.in_use().iter().filter(move |entry| {
            let [_, sub, low, high] = entry.mapped.to_le_bytes();
            entry.role == ROLE_PRODUCE
                && address.index == u16::from_le_bytes([low, high])
                && address.sub == sub
        })
    }

    /// `true` for a frame only this node sends: a data packet of an SC-ID it produces, or
    /// a sync naming its own master SC-ID.
    pub fn is_own(&self, frame: &RawFrame) -> bool {
        if frame.id == shared::simplecan::frame::SYNC_IDENTIFIER.raw() {
            return self.master_sc_id().is_some_and(|own| frame.data[0] == own);
        }
        self.in_use()
            .iter()
            .any(|entry| entry.role == ROLE_PRODUCE && u16::from(entry.sc_id) == frame.id)
    }
}

impl<const N: usize, const E: usize, const R: usize> ChannelProtocol<N>
    for SrdoAndSimpleCan<N, E, R>
{
    fn build(config: &shared::node::NodeConfig) -> Option<Self> {
        SrdoAndSimpleCan::new(config)
    }

    fn simplecan(&self) -> Option<Layer> {
        const {
            assert!(
                E <= ENTRIES,
                "the channels cross-check at most ENTRIES entries"
            )
        };
        let layer = &self.simplecan;
        let objects = layer.objects();
        if objects.enabled == 0 {
            return None;
        }
        let mut entries = [EntryObjects::default(); ENTRIES];
        for (slot, entry) in entries.iter_mut().zip(&objects.entries) {
            *slot = *entry;
        }
        Some(Layer {
            entries,
            count: usize::from(objects.count).min(E),
            potential_master: objects.potential_master == 1,
            running: layer.is_running(),
            accepted: layer.counters().accepted,
            buffering: Duration::from_micros(u64::from(objects.buffering_us)),
        })
    }
}

/// A SimpleCAN frame as a channel's own decoder reads it ([`crate::runtime::Role`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Decoded {
    /// A data packet: SC-ID, value (bytes 0..4, little-endian), cycle stamp (byte 4).
    Data {
        /// The SC-ID.
        sc_id: u8,
        /// The value.
        value: u32,
        /// The cycle stamp.
        cycle_stamp: u8,
    },
    /// A sync: the master's SC-ID, the cycle number, the offset into the last slot in µs.
    Sync {
        /// The master's SC-ID (byte 0).
        master: u8,
        /// The cycle number (bytes 1..3, big-endian).
        cycle: u16,
        /// The offset (bytes 3..5, big-endian).
        offset_micros: u16,
    },
    /// Not a valid packet.
    Invalid,
}

impl Decoded {
    /// The fields of `frame` as they stand, nothing checked (docs/simplecan.md sections 2
    /// and 3); a frame of another length than 8 is [`Decoded::Invalid`].
    pub fn fields(frame: &RawFrame) -> Decoded {
        let d = frame.data;
        if frame.len != 8 {
            return Decoded::Invalid;
        }
        if frame.id == shared::simplecan::frame::SYNC_IDENTIFIER.raw() {
            return Decoded::Sync {
                master: d[0],
                cycle: u16::from_be_bytes([d[1], d[2]]),
                offset_micros: u16::from_be_bytes([d[3], d[4]]),
            };
        }
        match u8::try_from(frame.id) {
            Ok(sc_id) => Decoded::Data {
                sc_id,
                value: u32::from_le_bytes([d[0], d[1], d[2], d[3]]),
                cycle_stamp: d[4],
            },
            Err(_) => Decoded::Invalid,
        }
    }
}

/// What the channels' SimpleCAN checks found: each a fault of the pair of channels, the
/// node's safe state with its own cause.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SimpleCanFault {
    /// Channel A's copy and channel B's reception of a frame do not agree (SC_REQ_24).
    Forward(ForwardFault),
    /// The channels' verdicts on a consumed packet differ or were not matched in time
    /// (SC_REQ_10).
    Verdict(CrossFault<ConsumedEntry>),
    /// The packet channel A put on the bus is not the one channel B computed (SC_REQ_10,
    /// Model A), or it is a packet of the node B did not compute.
    TransmitMismatch {
        /// The identifier.
        id: u16,
    },
    /// Channel B computed a packet of the node that channel A did not put on the bus in
    /// time (SC_REQ_10, Model A).
    TransmitMissing {
        /// The identifier.
        id: u16,
    },
}

impl SimpleCanFault {
    /// The link message by which channel B hands this fault to channel A
    /// ([`Message::SimpleCanFault`]).
    pub fn message(self) -> Message {
        let (id, other) = match self {
            SimpleCanFault::Forward(ForwardFault::Differs { heard, forwarded }) => {
                (heard, forwarded)
            }
            SimpleCanFault::Forward(ForwardFault::Lost { id } | ForwardFault::Unheard { id })
            | SimpleCanFault::TransmitMismatch { id }
            | SimpleCanFault::TransmitMissing { id } => (id, 0),
            SimpleCanFault::Forward(ForwardFault::Overrun) => (0, 0),
            SimpleCanFault::Verdict(
                CrossFault::Disagreement { srdo: entry }
                | CrossFault::Unconfirmed { srdo: entry }
                | CrossFault::QueueFull { srdo: entry },
            ) => (u16::from(entry.get()), 0),
            SimpleCanFault::Verdict(CrossFault::UnknownSrdo { srdo }) => (u16::from(srdo), 0),
        };
        Message::SimpleCanFault {
            cause: self.cause().code(),
            id,
            other,
        }
    }

    /// The fault [`SimpleCanFault::message`] carried as `cause`, `id` and `other`; `None`
    /// for a cause that is no SimpleCAN fault of the pair of channels, or an entry that is
    /// none (not a message of the set).
    pub fn from_message(cause: u8, id: u16, other: u16) -> Option<Self> {
        let entry = || ConsumedEntry::from_number(u8::try_from(id).ok()?);
        let fault = match Cause::from_code(cause)? {
            Cause::SimpleCanForwardDiffers => SimpleCanFault::Forward(ForwardFault::Differs {
                heard: id,
                forwarded: other,
            }),
            Cause::SimpleCanForwardLost => SimpleCanFault::Forward(ForwardFault::Lost { id }),
            Cause::SimpleCanForwardUnheard => SimpleCanFault::Forward(ForwardFault::Unheard { id }),
            Cause::SimpleCanForwardOverrun => SimpleCanFault::Forward(ForwardFault::Overrun),
            Cause::SimpleCanVerdictsDisagree => {
                SimpleCanFault::Verdict(CrossFault::Disagreement { srdo: entry()? })
            }
            Cause::SimpleCanVerdictUnconfirmed => {
                SimpleCanFault::Verdict(CrossFault::Unconfirmed { srdo: entry()? })
            }
            Cause::SimpleCanVerdictForUnknownEntry => {
                SimpleCanFault::Verdict(CrossFault::UnknownSrdo {
                    srdo: u8::try_from(id).ok()?,
                })
            }
            Cause::SimpleCanVerdictQueueFull => {
                SimpleCanFault::Verdict(CrossFault::QueueFull { srdo: entry()? })
            }
            Cause::SimpleCanTransmitMismatch => SimpleCanFault::TransmitMismatch { id },
            Cause::SimpleCanTransmitMissing => SimpleCanFault::TransmitMissing { id },
            _ => return None,
        };
        Some(fault)
    }

    /// The fault's cause code and name ([`Cause`]).
    pub const fn cause(self) -> Cause {
        match self {
            SimpleCanFault::Forward(ForwardFault::Differs { .. }) => Cause::SimpleCanForwardDiffers,
            SimpleCanFault::Forward(ForwardFault::Lost { .. }) => Cause::SimpleCanForwardLost,
            SimpleCanFault::Forward(ForwardFault::Unheard { .. }) => Cause::SimpleCanForwardUnheard,
            SimpleCanFault::Forward(ForwardFault::Overrun) => Cause::SimpleCanForwardOverrun,
            SimpleCanFault::Verdict(CrossFault::Disagreement { .. }) => {
                Cause::SimpleCanVerdictsDisagree
            }
            SimpleCanFault::Verdict(CrossFault::Unconfirmed { .. }) => {
                Cause::SimpleCanVerdictUnconfirmed
            }
            SimpleCanFault::Verdict(CrossFault::UnknownSrdo { .. }) => {
                Cause::SimpleCanVerdictForUnknownEntry
            }
            SimpleCanFault::Verdict(CrossFault::QueueFull { .. }) => {
                Cause::SimpleCanVerdictQueueFull
            }
            SimpleCanFault::TransmitMismatch { .. } => Cause::SimpleCanTransmitMismatch,
            SimpleCanFault::TransmitMissing { .. } => Cause::SimpleCanTransmitMissing,
        }
    }
}

/// One consumed entry's output: what the channel drives, and the newest packet (cycle
/// stamp) each channel accepted.
#[derive(Clone, Copy, Debug, Default)]
struct Output {
    sc_id: u8,
    value: u32,
    newest: Option<u8>,
    peer_newest: Option<u8>,
}

/// One channel's SimpleCAN checks beside its core, and the outputs of its consumed values.
#[derive(Clone, Debug)]
pub struct Checks {
    /// Channel B: the pairing of what it hears with what A forwards.
    pub(crate) forward: ForwardCheck,
    /// Both: the cross-check of the verdicts on consumed packets.
    pub(crate) verdicts: VerdictCheck<ENTRIES, ConsumedEntry>,
    /// Channel B: Model A, the node's packets on the bus against B's own.
    pub(crate) transmit: TransmitCheck,
    outputs: [Output; ENTRIES],
}

impl Checks {
    /// Checks that wait `window` for channel A's copy of a frame and `timeout` for the
    /// other channel's verdict, with Model A's time `bounds` ([`Bounds::STANDARD`] in every
    /// image).
    pub fn new(window: Duration, timeout: Duration, bounds: Bounds) -> Self {
        Checks {
            forward: ForwardCheck::new(window),
            verdicts: VerdictCheck::new(timeout),
            transmit: TransmitCheck::with_bounds(window, bounds),
            outputs: [Output::default(); ENTRIES],
        }
    }

    /// The value this channel drives for consumed SC-ID `sc_id` (0: safe state, or not
    /// consumed).
    pub fn output(&self, sc_id: u8) -> u32 {
        self.outputs
            .iter()
            .find(|output| output.sc_id == sc_id && output.sc_id != 0)
            .map_or(0, |output| output.value)
    }

    /// Leaving Operational (or NMT reset): nothing waits any more.
    pub fn reset(&mut self) {
        self.forward = ForwardCheck::new(self.forward.bound);
        self.verdicts.reset();
        self.transmit.reset();
        for output in &mut self.outputs {
            output.newest = None;
            output.peer_newest = None;
        }
    }

    /// Every output to 0 (the safe state, SC_REQ_05).
    pub fn clear_outputs(&mut self, io: &mut impl Io) {
        for output in &mut self.outputs {
            if output.value != 0 {
                output.value = 0;
                io.simplecan_output(output.sc_id, 0);
            }
        }
    }

    /// Drives `entry`'s output (SC-ID `sc_id`) to `value`.
    fn drive(&mut self, entry: ConsumedEntry, sc_id: u8, value: u32, io: &mut impl Io) {
        let Some(output) = self.outputs.get_mut(entry.index()) else {
            return;
        };
        output.sc_id = sc_id;
        if output.value != value {
            output.value = value;
            io.simplecan_output(sc_id, value);
        }
    }

    /// This channel accepted `value` with `stamp` on `entry`: the output moves towards the
    /// safe state at once (bitwise AND), never away from it before both channels confirm.
    pub(crate) fn accepted(
        &mut self,
        entry: ConsumedEntry,
        sc_id: u8,
        stamp: u8,
        value: u32,
        io: &mut impl Io,
    ) {
        let Some(output) = self.outputs.get_mut(entry.index()) else {
            return;
        };
        output.newest = Some(stamp);
        let safer = output.value & value;
        self.drive(entry, sc_id, safer, io);
    }

    /// The other channel reported a verdict on `entry` with `stamp`.
    pub(crate) fn peer_reported(&mut self, entry: ConsumedEntry, stamp: u8) {
        if let Some(output) = self.outputs.get_mut(entry.index()) {
            output.peer_newest = Some(stamp);
        }
    }

    /// Both channels confirmed `verdict` on `entry` (SC-ID `sc_id`): it drives the output
    /// when it is the newest packet each channel accepted; an older one (its verdict
    /// crossed the link while a newer packet arrived) may only lower it (SC_REQ_05), as
    /// for SRDOs.
    pub(crate) fn confirmed(
        &mut self,
        entry: ConsumedEntry,
        sc_id: u8,
        verdict: Verdict,
        io: &mut impl Io,
    ) {
        let Some(output) = self.outputs.get(entry.index()) else {
            return;
        };
        // The value is bits 0..32 of the verdict's data (see `verdict`).
        let value = verdict.data as u32;
        io.event(ChannelEvent::SimpleCanConfirmed { sc_id, value });
        let stamp = Some(verdict.pair as u8);
        let newest = output.newest == stamp && output.peer_newest == stamp;
        let value = if newest { value } else { output.value & value };
        self.drive(entry, sc_id, value, io);
    }
}

/// The verdict the cross-check compares for a packet with `sc_id`, `cycle_stamp` and
/// `value`: the stamp identifies the packet (as the pair count does an SRDO pair), the data
/// is the value with the SC-ID above it, so that both are compared; not valid, the data is
/// 0 (as for SRDOs: an invalid packet confirms nothing).
pub fn verdict(sc_id: u8, cycle_stamp: u8, value: u32, valid: bool) -> Verdict {
    Verdict {
        pair: u32::from(cycle_stamp),
        valid,
        data: if valid {
            (u64::from(sc_id) << 32) | u64::from(value)
        } else {
            0
        },
    }
}

#[cfg(test)]
mod tests;
