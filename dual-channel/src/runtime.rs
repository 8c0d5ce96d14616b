//! One channel of the safety node around its own copy of the protocol core (EN 50325-5
//! Annex A.4, Model III; CiA 304 9.5).
//!
//! The runtime is what runs on each MCU between the board layer and the protocol core. It is
//! sans-I/O like the core: the board layer feeds it CAN frames, link bytes and `now`, and it
//! answers through [`Io`]: frames for the bus, bytes for the link, output values, events.
//!
//! What it adds to the core:
//!
//! - **Roles.** Channel A answers SDO and sends the plain frame of each transmit SRDO; channel
//!   B is silent on the bus except for the inverted frame, which it builds by its own path and
//!   sends only after comparing channel A's plain frame with its own result ([`Role`]).
//! - **Receive cross-check.** Each valid pair the core delivers becomes a verdict sent over the
//!   link and compared with the other channel's ([`VerdictCheck`]). An output moves towards the
//!   safe state at once (bitwise AND with the new data) and away from it only with data both
//!   channels confirmed, and only when the confirmed pair is the newest this channel accepted
//!   and the newest the other channel reported: a confirmation that arrives after a newer pair
//!   (its verdict was on the link meanwhile) may lower an output, never raise it (SC_REQ_05).
//! - **Co-signing only what channel A sent.** Channel A announces every plain frame over the
//!   link ([`Message::PlainFrame`]) before it puts the frame on the bus; channel B sends the
//!   inverted frame only for a plain frame on the bus that equals the announcement and agrees
//!   with B's own sample; channel A checks that the inverted frame on the bus is the exact
//!   inverse of its plain frame ([`ChannelFault::InvertedMismatch`]).
//! - **Frames on our identifiers that we did not send.** A CAN controller does not receive its
//!   own frames (one transceiver, Model III): channel A sees channel B's inverted frames and
//!   channel B sees channel A's plain frames, and nothing else should appear on the node's
//!   transmit identifiers. Anything else (inserted, replayed, a second sender) is a
//!   [`ChannelFault::ForeignFrame`]: the node's safe state, EMCY FF02h naming the identifier,
//!   and a GFC (EN 50325-5 7.2.1), so that every consumer is in its safe state within about a
//!   frame time. Watched in Operational, also once latched (every further foreign frame sends
//!   another GFC); an exact copy of the frame just received, within [`SAMPLE_WINDOW`], is CAN's
//!   double reception, not foreign. Why a GFC and not a pair carrying the safe value: consumers cannot tell our
//!   pair from the foreign sender's, so a safe-value pair would be followed by the foreign
//!   sender's next one and the output would come back on; the GFC latches every consumer until
//!   NMT reset. It stops every safety node on the bus, not only this SRDO's consumers: a
//!   device sending on another's identifiers is a fault of the network, not of one SRDO.
//! - **Link supervision.** A heartbeat every `link_period` (at least four per smallest SCT);
//!   a missing, late, repeated or corrupt message is a fault ([`Receiver`]).
//! - **Link latency supervision.** Where the node produces SRDOs, channel B's co-signing
//!   needs channel A's announcement within B's window: each channel probes the link's round
//!   trip every `link_period`, and channel B also when a plain frame of its node arrives; the
//!   other channel echoes at once, and a round trip at or over [`round_trip_bound`] of the
//!   window ([`Role::announcement_window`]) is [`LinkFault::Latency`] ([`RoundTrip`], where
//!   the bound is argued). Its deadline is settled before anything else a call brings, so
//!   that a link too slow latches as such before channel B's wait for an announcement ends;
//!   and a channel whose link is at fault sends no [`Message::ForeignFrame`] over it: the
//!   link may not carry it, and channel B's verdict on a plain frame rests on the link's
//!   announcements (channel A, which receives every plain frame but its own, finds a foreign
//!   one without the link).
//! - **Configuration and NMT cross-check.** Every heartbeat carries the sender's NMT state and
//!   a digest of the signatures it computes by its own implementation; in Operational the
//!   digests must match (an output leaves the safe state only after they have, once per
//!   Operational period), and the NMT states may differ for at most two link periods. A
//!   heartbeat goes out at once on every NMT state change, and carries the count of NMT
//!   resets (the epoch): a message sent before a reset that arrives after it is ignored.
//! - **Time base cross-check.** Each channel checks that the other's heartbeats do not come
//!   faster than the link period allows (32 intervals shorter than 90 % of 32 periods)
//!   ([`crate::clock`]); whichever clock drifts, one channel sees the other as fast.
//! - **Input cross-check.** Each channel sends a digest of its input samples on every change
//!   and with every heartbeat; samples that differ for longer than [`INPUT_DISCREPANCY`] are a
//!   fault (a stuck or broken contact), even when no SRDO carries them.
//! - **Symmetric sample window.** The two contacts of one input never move at exactly the same
//!   moment. A transmit SRDO frame carrying changed data waits while the channels' samples
//!   differ, for at most [`SAMPLE_WINDOW`]; it goes as soon as the other channel's sample
//!   agrees (its input digest arrives). Channel B accepts channel A's frame against its
//!   current sample or, within the same window, its previous one (`channel_b::role`). So a
//!   difference shorter than the window is tolerated whichever contact moved first or alone,
//!   and a longer one is a transmit mismatch whichever it was. (Before, channel A sent a
//!   changed sample at once: a short blip on A's contact alone went on the bus, B never
//!   agreed, and the node tripped, while the same blip on B's contact was tolerated.)
//! - **Start-up together.** A core boots only once the other channel has been heard on the
//!   link, and the channel that speaks for the node (A) only once the other's core has booted
//!   (its heartbeat says so): the node's boot-up message means both channels follow the bus. A
//!   channel whose partner never speaks stays silent and reports the link time-out.
//! - **Latched safe state.** Any fault: outputs 0, the core's own safe state (EMCY FF02h, its
//!   producers stop), the other channel told at once, also when the fault is one the core
//!   found itself (an SRDO fault in this channel's receive path the other cannot see).
//!   Cleared only by NMT reset node or communication, which both channels see on the bus.

use crate::clock::PeerClock;
use crate::crosscheck::{CrossFault, Verdict, VerdictCheck};
use crate::link::{LinkFault, Message, Receiver, RoundTrip, Sender, round_trip_bound};
use crate::lss::{AnswerPairing, LssMismatch, Settings};
use crate::supervision::{ConfigurationCheck, InputCheck, NmtCheck};
use shared::canopen::NodeId;
use shared::canopen::lss::BitRates;
use shared::canopen::nmt::NmtState;
use shared::canopen::od::{AbortCode, Address};
use shared::canopen::storage::Flash;
use shared::node::{
    Device, Event, NodeConfig, NodeError, SafeStateCause, SafetyProtocol, Sink, SrdoTable,
    WithSrdoTable,
};
use shared::safety::cause::Cause;
use shared::safety::config::SafetyConfig;
use shared::safety::types::{Direction, SRDO_IDENTIFIERS, SrdoNumber};
use shared::{CanFrame, Duration, Instant};

/// How long after power-on the other channel's first link message may take (its self-tests
/// run first). Until then the channel is in its safe state anyway: it has not confirmed
/// anything.
pub const STARTUP: Duration = Duration::from_millis(1000);

/// How long the two channels' input samples may differ: the two contacts of one emergency
/// stop never open at exactly the same moment. Longer is a fault (a contact stuck or broken).
pub const INPUT_DISCREPANCY: Duration = Duration::from_millis(200);

/// How long a transmit SRDO frame with changed data waits for the other channel's sample to
/// agree, and how long channel B accepts its previous sample or waits for its next one and
/// for channel A's announcement of a plain frame: the device's sample window.
pub use safety_device::timing::SAMPLE_WINDOW;

/// How many safety inputs (plain objects) a channel samples and cross-checks; one more is
/// [`ChannelFault::InputTableFull`].
pub const MAX_INPUTS: usize = 8;

/// The cause code of a GFC received (EN 50325-5 7.2.1) in the link's safe-state message and
/// the status report; every code and its name are in [`Cause`].
pub const GFC_CAUSE: u8 = Cause::Gfc.code();

/// The cause code of a safe state the core reported (the EMCY detail byte 1 it sent).
pub fn safe_state_code(cause: &SafeStateCause) -> u8 {
    match cause {
        SafeStateCause::Srdo(fault) => fault.cause.cause_code(),
        SafeStateCause::Gfc => GFC_CAUSE,
        SafeStateCause::Application { detail } => *detail,
        // F2h..F5h, as in EMCY 6300h byte 1.
        SafeStateCause::Integrity(fault) => fault.emergency_detail()[1],
        // The protocol's cause code, as in its EMCY byte 1.
        SafeStateCause::Protocol { cause, .. } => *cause,
    }
}

/// The safety protocol in a channel's core: the SRDO table (`shared::node::Node`, the
/// CANopen Safety images), or with the feature `simplecan` SimpleCAN beside an SRDO table
/// (`shared::node::SrdoAndSimpleCan`, `crate::simplecan`): of none in the SimpleCAN images
/// (`board::Protocol`), of four in the host simulations.
pub trait ChannelProtocol<const N: usize>:
    SafetyProtocol + WithSrdoTable<Table = SrdoTable<N>> + Sized
{
    /// The protocol of the device `config` describes (`None`: it cannot hold `N` SRDOs).
    fn build(config: &NodeConfig) -> Option<Self>;

    /// The SimpleCAN layer beside the SRDOs, as the channel's cross-checks read it (`None`:
    /// the protocol has none, or it is disabled).
    #[cfg(feature = "simplecan")]
    fn simplecan(&self) -> Option<crate::simplecan::Layer> {
        None
    }
}

impl<const N: usize> ChannelProtocol<N> for SrdoTable<N> {
    fn build(config: &NodeConfig) -> Option<Self> {
        SrdoTable::new(config)
    }
}

/// What differs between channel A and channel B.
pub trait Role<const N: usize> {
    /// A frame this channel's core wants to send; what goes on the bus (`None`: nothing).
    fn outgoing(&mut self, frame: CanFrame, config: &SafetyConfig<N>) -> Option<CanFrame>;

    /// A frame seen on the bus at `now` in Operational, before the core handles it: a frame
    /// to send in reply (channel B's inverted frame, channel A's next plain frame), or the
    /// fault it shows (a pair that cannot be confirmed, a frame on a transmit identifier the
    /// node did not send).
    fn observe(
        &mut self,
        now: Instant,
        frame: &CanFrame,
        config: &SafetyConfig<N>,
    ) -> Result<Option<CanFrame>, ChannelFault>;

    /// [`Role::observe`] for a frame that arrived on the bus at `seen`, before `now` (one kept
    /// while this channel was not Operational yet): a role that bounds a frame's wait counts
    /// it from `seen` (`channel_b::role`).
    fn observe_seen(
        &mut self,
        now: Instant,
        seen: Instant,
        frame: &CanFrame,
        config: &SafetyConfig<N>,
    ) -> Result<Option<CanFrame>, ChannelFault> {
        let _ = seen;
        self.observe(now, frame, config)
    }

    /// The other channel announced over the link at `now` that it puts `frame` (a plain
    /// frame) on the bus ([`Message::PlainFrame`]): channel B's inverted frame if the plain
    /// frame is already there and agrees.
    fn announced(
        &mut self,
        _now: Instant,
        _frame: &CanFrame,
        _config: &SafetyConfig<N>,
    ) -> Result<Option<CanFrame>, ChannelFault> {
        Ok(None)
    }

    /// This channel's safety input `address` was sampled as `value` at `now` (channel B keeps
    /// its own copy, in its own layout). May release a frame that was waiting for it.
    fn input(
        &mut self,
        now: Instant,
        address: Address,
        value: &[u8],
        config: &SafetyConfig<N>,
    ) -> Result<Option<CanFrame>, ChannelFault>;

    /// This channel read all its safety inputs at `now` and none changed since the last
    /// [`Role::input`]: a sample's age counts from its last reading (channel B co-signs only
    /// what its inputs read within the window). May release a frame that was waiting.
    fn sampled(
        &mut self,
        now: Instant,
        config: &SafetyConfig<N>,
    ) -> Result<Option<CanFrame>, ChannelFault> {
        let _ = (now, config);
        Ok(None)
    }

    /// Time-outs of the role's own (channel B: a plain frame it could not confirm in time, or
    /// one never announced).
    fn poll(&mut self, now: Instant) -> Result<(), ChannelFault>;

    /// When [`Role::poll`] next has something to do.
    fn deadline(&self) -> Instant;

    /// The signature of every SRDO of `config` as this channel computes it (by its own
    /// implementation), folded into one CRC-32 for the link.
    fn signature_digest(&self, config: &SafetyConfig<N>) -> u32;

    /// NMT reset node or communication: forget every pair in progress (the core forgot its
    /// own; a pair begun before the reset is never completed after it). The other half of
    /// such a pair may still reach this channel after the reset, from the other channel's
    /// loop: a role that watches for it says how it tells it from a foreign frame
    /// (`channel_a::role`).
    fn reset(&mut self) {}

    /// The other channel went through an NMT reset (its heartbeat, which names a new epoch,
    /// arrived at `now`; the link keeps the order, so every message before it was sent before
    /// that reset). A role that keeps what the other channel announced sets it apart here
    /// (`channel_b::role`).
    fn peer_reset(&mut self, now: Instant) {
        let _ = now;
    }

    /// A frame seen at `now` while this channel is not Operational, or kept since
    /// ([`Runtime::on_frame`] keeps SRDO frames for the entry into Operational): `true` when
    /// the role accounts for it already, so that it is not kept (channel B: channel A's plain
    /// frame of its ended epoch, which nobody co-signs, `channel_b::role`).
    fn ended_frame(&mut self, now: Instant, frame: &CanFrame) -> bool {
        let _ = (now, frame);
        false
    }

    /// `true` for the channel whose frames other than SRDOs go on the bus (channel A): its
    /// core boots only after the other channel's has.
    fn speaks_for_the_node(&self) -> bool {
        false
    }

    /// How long a frame of the other channel's half may wait for this channel (its sample,
    /// an announcement, its own entry into Operational).
    fn window(&self) -> Duration {
        SAMPLE_WINDOW
    }

    /// How long channel B waits for channel A's announcement of a plain frame (B's window):
    /// the link's round-trip bound follows from it on both channels ([`round_trip_bound`]).
    /// Channel B's is its [`Role::window`]; channel A's is the same, the device's
    /// [`SAMPLE_WINDOW`].
    fn announcement_window(&self) -> Duration {
        self.window()
    }

    /// This channel's own decoding of a SimpleCAN frame with the node hashes `hash_of`
    /// (SC_REQ_10: each channel validates every packet). The default is the frame's fields
    /// as they stand, unchecked: a channel without a decoder of its own (channel A) has its
    /// core's, which checked the frame already. Channel B answers with its diverse decoder
    /// (`channel_b::simplecan`).
    #[cfg(feature = "simplecan")]
    fn simplecan_decode(
        &self,
        frame: &crate::simplecan::RawFrame,
        hash_of: impl Fn(u8) -> Option<u32>,
    ) -> crate::simplecan::Decoded {
        let _ = hash_of;
        crate::simplecan::Decoded::fields(frame)
    }
}

/// Why a channel went to the safe state on its own account (faults of the SRDOs themselves
/// are the core's, reported as [`Event`]s).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ChannelFault {
    /// The link failed.
    Link(LinkFault),
    /// The channels' verdicts on a received SRDO disagree or were not confirmed.
    Cross(CrossFault),
    /// A transmit SRDO's plain half differs between the channels (CiA 304 9.5): found by
    /// channel B, or reported to channel A by channel B; or channel A's pair was left
    /// incomplete for a refresh time.
    TransmitMismatch {
        /// SRDO number.
        srdo: SrdoNumber,
    },
    /// The inverted frame on the bus is not the exact inverse of channel A's plain frame
    /// (CiA 304 9.5, EN 50325-5 7.1.1): found by channel A. Also sends a GFC: it may be a
    /// foreign sender's that completed the pair at the consumers (EN 50325-5 7.2.1).
    InvertedMismatch {
        /// SRDO number.
        srdo: SrdoNumber,
    },
    /// A frame on one of the node's transmit SRDO identifiers that the node did not send
    /// (inserted, replayed, a second sender, or a plain frame that differs from what channel
    /// A announced). Also sends a GFC (EN 50325-5 7.2.1).
    ForeignFrame {
        /// The identifier (named in EMCY FF02h, bytes 5..=6).
        id: u16,
    },
    /// In Operational the channels hold different configurations (0x13FE or signatures).
    ConfigurationMismatch,
    /// The channels' NMT states differed for longer than two link periods.
    NmtMismatch,
    /// The two channels' input samples differed for longer than [`INPUT_DISCREPANCY`] (a
    /// stuck or broken contact on one channel).
    InputDiscrepancy,
    /// The core handed the channel more frames or events in one call than the channel holds:
    /// it cannot have seen (or sent) everything, a design limit exceeded, not data.
    CoreOutputFull,
    /// More safety inputs were sampled than the channel's input table holds: a design limit
    /// exceeded (the device description declares more inputs than the channel tracks).
    InputTableFull,
    /// After NMT reset node an input sample written before could not be written back into
    /// the core's objects: the core is not what it was.
    InputRestoreFailed,
    /// The other channel's heartbeats came faster than its period allows: one of the two
    /// clocks runs too fast or too slow ([`crate::clock`]).
    ClockDrift,
    /// A frame the channel follows (its acceptance filters passed it) found the receive queue
    /// full, so the channel cannot know that it saw every safety frame
    /// ([`crate::channel_loop::Received::Overrun`]).
    ReceiveOverrun,
    /// The channel's CAN controller went bus-off, so frames the channel follows may have gone
    /// unseen ([`crate::channel_loop::Received::BusOff`]).
    BusOff,
    /// The channels' LSS differ (CiA 305 on both channels, [`crate::lss`]): an answer, the
    /// node-ID in force or the bit rate.
    Lss(LssMismatch),
    /// The other channel went to its safe state.
    PeerSafeState {
        /// The other channel's cause code.
        cause: u8,
    },
    /// The channels' SimpleCAN checks found a fault (forwarding, verdicts, Model A
    /// transmission: `crate::simplecan`).
    #[cfg(feature = "simplecan")]
    SimpleCan(crate::simplecan::SimpleCanFault),
}

impl ChannelFault {
    /// This fault's cause code and name ([`Cause`]).
    pub const fn cause(self) -> Cause {
        match self {
            ChannelFault::Link(LinkFault::Corrupt) => Cause::LinkCorrupt,
            ChannelFault::Link(LinkFault::Malformed) => Cause::LinkMalformed,
            ChannelFault::Link(LinkFault::Missing { .. }) => Cause::LinkMissing,
            ChannelFault::Link(LinkFault::Repeated { .. }) => Cause::LinkRepeated,
            ChannelFault::Link(LinkFault::Timeout) => Cause::LinkTimeout,
            ChannelFault::Link(LinkFault::Latency) => Cause::LinkLatency,
            ChannelFault::Cross(CrossFault::Disagreement { .. }) => Cause::VerdictsDisagree,
            ChannelFault::Cross(CrossFault::Unconfirmed { .. }) => Cause::VerdictUnconfirmed,
            ChannelFault::Cross(CrossFault::UnknownSrdo { .. }) => Cause::VerdictForUnknownSrdo,
            ChannelFault::Cross(CrossFault::QueueFull { .. }) => Cause::VerdictQueueFull,
            ChannelFault::TransmitMismatch { .. } => Cause::TransmitMismatch,
            ChannelFault::ConfigurationMismatch => Cause::ConfigurationMismatch,
            ChannelFault::NmtMismatch => Cause::NmtMismatch,
            ChannelFault::InputDiscrepancy => Cause::InputDiscrepancy,
            ChannelFault::ForeignFrame { .. } => Cause::ForeignFrame,
            ChannelFault::InvertedMismatch { .. } => Cause::InvertedMismatch,
            ChannelFault::CoreOutputFull => Cause::CoreOutputFull,
            ChannelFault::InputTableFull => Cause::InputTableFull,
            ChannelFault::InputRestoreFailed => Cause::InputRestoreFailed,
            ChannelFault::ClockDrift => Cause::ClockDrift,
            ChannelFault::ReceiveOverrun => Cause::ReceiveOverrun,
            ChannelFault::BusOff => Cause::BusOff,
            ChannelFault::Lss(mismatch) => mismatch.cause(),
            ChannelFault::PeerSafeState { .. } => Cause::PeerSafeState,
            #[cfg(feature = "simplecan")]
            ChannelFault::SimpleCan(fault) => fault.cause(),
        }
    }

    /// The cause code sent to the other channel and in EMCY FF02h (byte 1): the code of
    /// [`ChannelFault::cause`].
    pub const fn cause_code(self) -> u8 {
        self.cause().code()
    }
}

/// What a channel reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ChannelEvent {
    /// The core reported this.
    Node(Event),
    /// The channel latched its safe state for this fault.
    Fault(ChannelFault),
    /// Both channels confirmed this data for a receive SRDO.
    Confirmed {
        /// SRDO number.
        srdo: SrdoNumber,
        /// The data.
        data: u64,
    },
    /// Both channels confirmed this value of a consumed SimpleCAN SC-ID (SC_REQ_10).
    #[cfg(feature = "simplecan")]
    SimpleCanConfirmed {
        /// The SC-ID.
        sc_id: u8,
        /// The value.
        value: u32,
    },
}

impl ChannelEvent {
    /// `true` for the events every pair brings (a pair received, data both channels
    /// confirmed): a board counts them rather than logging each one (the runtime counts the
    /// pairs per SRDO); transitions and faults are logged.
    pub fn is_per_pair(&self) -> bool {
        match self {
            ChannelEvent::Node(Event::SrdoReceived { .. }) | ChannelEvent::Confirmed { .. } => true,
            #[cfg(feature = "simplecan")]
            ChannelEvent::SimpleCanConfirmed { .. } => true,
            _ => false,
        }
    }
}

/// The board layer, as the runtime sees it.
pub trait Io {
    /// Puts `frame` on the CAN bus.
    fn transmit(&mut self, frame: CanFrame);
    /// Writes `bytes` to the link.
    fn link(&mut self, bytes: &[u8]);
    /// Drives the physical output(s) behind receive SRDO `srdo` to `data` (0: safe state).
    fn output(&mut self, srdo: SrdoNumber, data: u64);
    /// Reports an event (log, diagnostics).
    fn event(&mut self, event: ChannelEvent);
    /// Drives the physical output(s) behind the consumed SimpleCAN SC-ID `sc_id` to `value`
    /// (0: safe state). The default drives nothing: a board without SimpleCAN outputs.
    #[cfg(feature = "simplecan")]
    fn simplecan_output(&mut self, sc_id: u8, value: u32) {
        let _ = (sc_id, value);
    }
    /// Withdraws the frames on `id` handed to [`Io::transmit`] and not yet on the bus (the
    /// core's [`Sink::abort`]: a SimpleCAN packet at the end of its slot, a sync not
    /// confirmed within 2 ms; SC_REQ_18, SC_REQ_23). The default withdraws nothing: a board
    /// without SimpleCAN.
    #[cfg(feature = "simplecan")]
    fn abort(&mut self, id: shared::CanId) {
        let _ = id;
    }
}

/// Collects what the core hands out during one call, into lists on the caller's stack
/// (declared by `collect!`). The lists are separate locals, not fields of one value built
/// at once: built as one value, the empty lists were zeroed whole (a `memset`) at every core
/// call (its share of the full-network simulation's instructions: docs/network-performance.md).
struct Collect<'a> {
    frames: &'a mut heapless::Vec<CanFrame, 16>,
    events: &'a mut heapless::Vec<Event, 16>,
    /// More than fit: treated as a fault of the channel (it cannot have seen everything).
    overflow: bool,
    /// Identifiers whose frames the core withdrew ([`Sink::abort`]: SimpleCAN).
    #[cfg(feature = "simplecan")]
    aborts: &'a mut heapless::Vec<shared::CanId, 8>,
}

/// `collect!(name)` declares the empty lists of a [`Collect`] on the stack and `name`, a
/// [`Collect`] over them, for one call of the core.
macro_rules! collect {
    ($name:ident) => {
        let mut frames = heapless::Vec::new();
        let mut events = heapless::Vec::new();
        #[cfg(feature = "simplecan")]
        let mut aborts = heapless::Vec::new();
        let mut $name = Collect {
            frames: &mut frames,
            events: &mut events,
            overflow: false,
            #[cfg(feature = "simplecan")]
            aborts: &mut aborts,
        };
    };
}

impl Sink for Collect<'_> {
    #[cfg_attr(target_os = "none", inline(never))]
    fn transmit(&mut self, frame: CanFrame) {
        if self.frames.push(frame).is_err() {
            self.overflow = true;
        }
    }
    #[cfg_attr(target_os = "none", inline(never))]
    fn event(&mut self, event: Event) {
        if self.events.push(event).is_err() {
            self.overflow = true;
        }
    }
    #[cfg(feature = "simplecan")]
    fn abort(&mut self, id: shared::CanId) {
        if self.aborts.push(id).is_err() {
            self.overflow = true;
        }
    }
}

/// A safety input as the channel last sampled it.
#[derive(Clone, Copy, Debug)]
struct InputSample {
    plain: Address,
    inverted: Address,
    bytes: [u8; 8],
    len: usize,
}

impl InputSample {
    fn value(&self) -> u64 {
        u64::from_le_bytes(self.bytes)
    }
}

/// One channel: its core (with the safety protocol `P`, the SRDO table unless said
/// otherwise), its role, the link and the cross-checks.
#[derive(Clone)]
pub struct Runtime<F: Flash, R: Role<N>, const N: usize, P: ChannelProtocol<N> = SrdoTable<N>> {
    node: Device<F, P>,
    role: R,
    sender: Sender,
    receiver: Receiver,
    /// The link's latency supervision: this channel's probes and the bound they are held to.
    round_trip: RoundTrip,
    verdicts: VerdictCheck<N>,
    link_period: Duration,
    next_heartbeat: Instant,
    /// The configuration digest this channel sent in its last heartbeat, which the other
    /// channel's digest is compared with: each channel computes its own once per link period
    /// (and on every NMT state change, when it sends a heartbeat at once), not again for each
    /// digest it receives. In Operational, where the digests are compared, the configuration
    /// cannot change, and every entry to it sends a heartbeat; a bit flipped in this
    /// channel's copy changes the digest of its next heartbeat, which the other channel
    /// compares within the period. `None` before the first heartbeat.
    own_digest: Option<u32>,
    /// The NMT cross-check, with this channel's epoch (NMT resets since power-on) and the
    /// other's: messages sent in another epoch than ours are ignored.
    nmt: NmtCheck,
    fault: Option<ChannelFault>,
    /// The other channel has been heard: the core may boot.
    link_up: bool,
    /// This channel's inputs as last sampled, folded into [`Message::Inputs`] and written
    /// back to the core after an NMT reset.
    inputs: heapless::Vec<InputSample, MAX_INPUTS>,
    /// The input cross-check against the other channel's digest.
    input_check: InputCheck,
    /// The configuration cross-check: only once the other channel's configuration digest
    /// matched ours in this Operational period may an output leave the safe state.
    configuration: ConfigurationCheck,
    /// The other channel's heartbeat rate against this channel's clock.
    peer_clock: PeerClock,
    outputs: [u64; N],
    /// Valid pairs per receive SRDO this channel's core accepted in this Operational period.
    pairs: [u32; N],
    /// The newest pair per receive SRDO the other channel reported a verdict on.
    peer_pairs: [u32; N],
    /// Transmit SRDO frames with changed data that wait for the channels' samples to agree
    /// (at most [`SAMPLE_WINDOW`]); the newest per identifier.
    waiting: FrameSlots<N>,
    /// SRDO frames seen while this channel's core was not yet Operational, with when: the
    /// other channel may have handled NMT start first and sent its half already. Handed to
    /// the role on entering Operational if still within its window.
    early: heapless::Vec<(Instant, CanFrame), 4>,
    /// The last transmit SRDO frame per identifier this channel's core handed on.
    handed_on: FrameSlots<N>,
    /// Channel B's pairing of its LSS answers with channel A's announcements.
    lss: AnswerPairing,
    /// The channels' SimpleCAN checks (forwarding, verdicts, Model A transmission).
    #[cfg(feature = "simplecan")]
    simplecan: crate::simplecan::Checks,
}

/// SimpleCAN on the two channels: the runtime's part (`crate::simplecan` holds the checks).
#[cfg(feature = "simplecan")]
#[path = "simplecan/runtime.rs"]
mod simplecan;

impl<F: Flash, R: Role<N>, const N: usize, P: ChannelProtocol<N>> Runtime<F, R, N, P> {
    /// A channel powered on at `now`, sending a link heartbeat every `link_period` and
    /// expecting one from the other channel within twice that, its core's parameters
    /// restored from `flash` ([`Runtime::around`], then [`Runtime::restore_parameters`]).
    pub fn new(
        config: NodeConfig,
        flash: F,
        role: R,
        now: Instant,
        link_period: Duration,
    ) -> Result<Self, NodeError> {
        let mut runtime = Self::around(config, flash, role, now, link_period)?;
        runtime.restore_parameters();
        Ok(runtime)
    }

    /// The first step of [`Runtime::new`]: the channel around its core as
    /// [`Device::prepare`] builds it, the core's parameters not read from `flash` yet.
    ///
    /// The firmware images keep the runtime in the `Result` this returns, in their task's
    /// state, and restore the parameters there ([`Runtime::restore_parameters`]): built and
    /// restored in one function, the runtime was copied through that function's stack frame
    /// on its way out, with the restore's frame under it (the frames measured in
    /// `docs/footprint.md`). Out of line,
    /// so that the construction's temporaries are in this frame only, never under the
    /// channel loop.
    #[inline(never)]
    pub fn around(
        config: NodeConfig,
        flash: F,
        role: R,
        now: Instant,
        link_period: Duration,
    ) -> Result<Self, NodeError> {
        let timeout = Duration::from_micros(2 * link_period.as_micros());
        let protocol = P::build(&config).ok_or(NodeError::SrdoCount)?;
        #[cfg(feature = "simplecan")]
        let (window, bounds) = (role.window(), crate::simplecan::Bounds::STANDARD);
        Ok(Runtime {
            node: Device::prepare(config, flash, protocol)?,
            role,
            sender: Sender::new(),
            receiver: Receiver::new(now, timeout, STARTUP),
            round_trip: RoundTrip::new(),
            verdicts: VerdictCheck::new(timeout),
            link_period,
            next_heartbeat: now,
            own_digest: None,
            nmt: NmtCheck::new(timeout),
            fault: None,
            link_up: false,
            inputs: heapless::Vec::new(),
            input_check: InputCheck::new(),
            configuration: ConfigurationCheck::new(),
            peer_clock: PeerClock::new(link_period),
            outputs: [0; N],
            pairs: [0; N],
            peer_pairs: [0; N],
            waiting: FrameSlots::default(),
            early: heapless::Vec::new(),
            handed_on: FrameSlots::default(),
            lss: AnswerPairing::default(),
            #[cfg(feature = "simplecan")]
            simplecan: crate::simplecan::Checks::new(window, timeout, bounds),
        })
    }

    /// This channel could not receive link bytes for a while up to `now`: its processor was
    /// held by flash programs (a store of the parameters, which the node refuses in
    /// Operational). Outside Operational the link receiver starts over as at start-up and
    /// the probes outstanding are forgotten ([`Receiver::restart`], [`RoundTrip::forget`]),
    /// so the bytes lost meanwhile and the round trips the stall stretched are not taken for
    /// faults of the link; `true` then. In Operational it changes nothing (`false`): nothing
    /// programs the flash there, and the supervision judges whatever it finds. Nothing that
    /// the link carries outside Operational drives an output: no pair is co-signed and no
    /// output leaves its safe state before both channels have compared their configurations
    /// in Operational.
    pub fn link_was_deaf(&mut self, now: Instant) -> bool {
        if self.node.nmt_state() == NmtState::Operational {
            return false;
        }
        self.receiver.restart(now);
        self.round_trip.forget();
        self.lss.link_was_deaf();
        true
    }

    /// Allows the other channel's first link message `longer` more than [`STARTUP`], for a
    /// board whose start-up may take that much longer on one channel than on the other (the
    /// hardware's erase ahead of a parameter slot, `board::hw`); before the first message
    /// only (see [`Receiver::extend_startup`]).
    pub fn allow_longer_start_up(&mut self, longer: Duration) {
        self.receiver.extend_startup(longer);
    }

    /// Enables the core's LSS slave (CiA 305, `Device::enable_lss`) after
    /// [`Runtime::restore_parameters`], before the first poll: `switches` is the node-ID the
    /// board's switches set (`None`: all open, "use LSS"), `supported` the bit rates the board
    /// can switch to. Both channels enable it alike; channel A answers for the node and
    /// channel B checks its answers ([`crate::lss`]). `false` when the core refused (polled
    /// already, or enabled before).
    #[must_use = "`false` means LSS was not enabled"]
    pub fn enable_lss(&mut self, switches: Option<NodeId>, supported: BitRates) -> bool {
        self.node.enable_lss(switches, supported)
    }

    /// This channel's node-ID in force and LSS bit rate, as its heartbeat carries them.
    pub fn lss_settings(&self) -> Settings {
        Settings {
            node_id: self.node.configured_node_id(),
            bit_rate: self.node.lss().and_then(|lss| lss.bit_rate()),
        }
    }

    /// The second step of [`Runtime::new`]: the core's stored parameters loaded in place
    /// ([`Device::restore_parameters`]). Out of line: the stored image it reads into is in
    /// its own frame.
    #[inline(never)]
    pub fn restore_parameters(&mut self) {
        self.node.restore_parameters();
        // The configuration changed under any digest computed before.
        self.own_digest = None;
    }

    /// The channel's core.
    pub fn node(&self) -> &Device<F, P> {
        &self.node
    }

    /// The channel's core, for fault injection in system tests (feature `fault-injection`,
    /// which no firmware image enables).
    #[cfg(feature = "fault-injection")]
    pub fn node_mut(&mut self) -> &mut Device<F, P> {
        &mut self.node
    }

    /// The channel's role.
    pub fn role(&self) -> &R {
        &self.role
    }

    /// The fault the channel latched, if any.
    pub fn fault(&self) -> Option<ChannelFault> {
        self.fault
    }

    /// The value the channel drives on the output(s) of receive SRDO `srdo`.
    pub fn output(&self, srdo: SrdoNumber) -> u64 {
        self.outputs.get(srdo.index()).copied().unwrap_or(0)
    }

    /// `true` while neither the core nor the channel is in its safe state.
    pub fn is_working(&self) -> bool {
        self.fault.is_none() && self.node.is_working()
    }

    /// `true` once the other channel has been heard on the link: until then the core does
    /// not boot, so the node announces itself (boot-up) only when both channels are up.
    pub fn link_up(&self) -> bool {
        self.link_up
    }

    /// A frame from the bus.
    pub fn on_frame(&mut self, now: Instant, frame: &CanFrame, io: &mut impl Io) {
        if !self.link_up {
            return; // The core has not booted: the node is not on the bus yet.
        }
        self.settle_round_trip(now, io);
        #[cfg(feature = "simplecan")]
        if self.simplecan_frame(now, frame, io) {
            return;
        }
        if self.node.nmt_state() == NmtState::Operational {
            // Also in the safe state: a foreign sender on our identifiers is reported (and a
            // GFC sent) whenever it sends, not only the first time.
            let reply = self.role.observe(now, frame, self.node.safety_config());
            self.role_reply(now, reply, io);
            if !self.role.speaks_for_the_node() && self.is_own_plain_frame(frame) {
                // Channel B's wait for the announcement of this frame starts now: a probe
                // sent now comes back after every announcement channel A made before the
                // frame reached the bus, or is late before the wait ends ([`RoundTrip`]).
                self.probe(now, io);
            }
        } else if is_srdo(frame) && !frame.is_remote() {
            // Not Operational yet, but perhaps about to be: each channel handles NMT start in
            // its own loop, and the other's half of a pair may come first. Kept for the window.
            let window = self.role.window();
            self.early
                .retain(|(at, _)| !shared::time::expired(*at + window, now));
            if !self.role.ended_frame(now, frame) {
                let _ = self.early.push((now, *frame)); // Full: the oldest ones are kept.
            }
        }
        collect!(collect);
        self.node.handle_frame(now, frame, &mut collect);
        self.after_core(now, &collect, io);
    }

    /// The board's receive queue overflowed with frames the channel follows: the safe state
    /// ([`ChannelFault::ReceiveOverrun`]), never a silent loss.
    pub fn on_receive_overrun(&mut self, io: &mut impl Io) {
        self.latch(ChannelFault::ReceiveOverrun, io);
    }

    /// The channel's CAN controller went bus-off: the safe state ([`ChannelFault::BusOff`]),
    /// as for an overrun, under its own cause.
    pub fn on_bus_off(&mut self, io: &mut impl Io) {
        self.latch(ChannelFault::BusOff, io);
    }

    /// A byte from the link.
    pub fn on_link_byte(&mut self, now: Instant, byte: u8, io: &mut impl Io) {
        self.settle_round_trip(now, io);
        if let Some(completed) = self.receiver.receive(now, byte) {
            self.on_link_completed(now, completed, io);
        }
    }

    /// Bytes from the link, all received by `now` (what the UART buffered since the last
    /// call): each message or fault they complete is handled at `now`, in order, as
    /// [`Runtime::on_link_byte`] handles it for one byte at a time.
    pub fn on_link_bytes(&mut self, now: Instant, bytes: &[u8], io: &mut impl Io) {
        self.settle_round_trip(now, io);
        let mut rest = bytes;
        while !rest.is_empty() {
            let (taken, completed) = self.receiver.receive_bytes(now, rest);
            rest = rest.get(taken..).unwrap_or_default();
            if let Some(completed) = completed {
                self.on_link_completed(now, completed, io);
            }
        }
    }

    /// A message or a fault from the link.
    fn on_link_completed(
        &mut self,
        now: Instant,
        completed: Result<Message, LinkFault>,
        io: &mut impl Io,
    ) {
        match completed {
            Err(fault) => self.latch(ChannelFault::Link(fault), io),
            Ok(message) => {
                if !self.link_up {
                    // The silent channel's core boots as soon as it hears the other; the
                    // channel that speaks for the node waits until the other's core has
                    // booted, so that its boot-up message means both channels follow the bus.
                    // An unconfigured node (node-ID FFh, CiA 305) stays in Initialising,
                    // serving LSS: the other's core runs when its heartbeat says so.
                    let peer_booted = matches!(message, Message::Heartbeat { nmt, node, .. }
                        if nmt != NmtState::Initialising.heartbeat_code()
                            || node == shared::canopen::lss::UNCONFIGURED);
                    self.link_up = !self.role.speaks_for_the_node() || peer_booted;
                }
                self.on_message(now, message, io);
            }
        }
    }

    /// This channel's sample of safety input `plain` (and its inverted copy `inverted`, which
    /// the core's transmit check needs).
    pub fn set_input(
        &mut self,
        now: Instant,
        plain: Address,
        inverted: Address,
        value: &[u8],
        io: &mut impl Io,
    ) -> Result<(), AbortCode> {
        self.settle_round_trip(now, io);
        let len = value.len();
        let mut bytes = [0u8; 8];
        bytes
            .get_mut(..len)
            .ok_or(AbortCode::LengthTooHigh)?
            .copy_from_slice(value);
        let sample = InputSample {
            plain,
            inverted,
            bytes,
            len,
        };
        Self::write_input(&mut self.node, &sample)?;
        let before = self
            .inputs
            .iter()
            .find(|entry| entry.plain == plain)
            .map_or(sample.value(), InputSample::value);
        match self.inputs.iter_mut().find(|entry| entry.plain == plain) {
            Some(entry) => *entry = sample,
            None => {
                if self.inputs.push(sample).is_err() {
                    // More inputs than the cross-check tracks: a design error, not data.
                    self.latch(ChannelFault::InputTableFull, io);
                }
            }
        }
        let digest = self.input_digest();
        self.send(&Message::Inputs { sample: digest }, io);
        self.compare_inputs(now);
        let reply = self
            .role
            .input(now, plain, value, self.node.safety_config());
        self.role_reply(now, reply, io);
        if self.link_up {
            collect!(collect);
            self.node.poll(now, &mut collect);
            self.after_core(now, &collect, io);
        }
        // After the core's frame for this sample: a sample back where it was supersedes the
        // frame of the short difference, which never goes on the bus.
        self.release_waiting(now, io);
        #[cfg(feature = "simplecan")]
        self.simplecan_sampled(now, plain, before, sample.value(), io);
        #[cfg(not(feature = "simplecan"))]
        let _ = before;
        Ok(())
    }

    /// This channel read every safety input at `now` and none changed since the last
    /// [`Runtime::set_input`] (which reports changes): the board calls it on every sample, so
    /// that a sample's age counts from its last reading (channel B co-signs only a value its
    /// inputs read within [`SAMPLE_WINDOW`]; a board that stops reading its pins gets nothing
    /// co-signed after the window).
    pub fn inputs_sampled(&mut self, now: Instant, io: &mut impl Io) {
        self.settle_round_trip(now, io);
        let reply = self.role.sampled(now, self.node.safety_config());
        self.role_reply(now, reply, io);
    }

    /// Runs what is due at `now`; returns when to call again.
    pub fn poll(&mut self, now: Instant, io: &mut impl Io) -> Instant {
        self.settle_round_trip(now, io);
        let node_deadline = if self.link_up {
            collect!(collect);
            let deadline = self.node.poll(now, &mut collect);
            self.after_core(now, &collect, io);
            deadline
        } else {
            Instant::NEVER
        };
        if let Err(fault) = self.role.poll(now) {
            self.role_reply(now, Err(fault), io);
        }
        self.release_waiting(now, io);
        if let Err(fault) = self.receiver.poll(now) {
            self.latch(ChannelFault::Link(fault), io);
        }
        if let Err(fault) = self.verdicts.poll(now) {
            self.latch(ChannelFault::Cross(fault), io);
        }
        if let Err(fault) = self.nmt.poll(now) {
            self.latch(fault, io);
        }
        if let Err(fault) = self.input_check.poll(now) {
            self.latch(fault, io);
        }
        if let Err(mismatch) = self.lss.poll(now) {
            self.latch(ChannelFault::Lss(mismatch), io);
        }
        if shared::time::expired(self.next_heartbeat, now) {
            self.heartbeat(io);
            if self.link_up {
                self.arm_round_trip();
                self.probe(now, io);
            }
            self.next_heartbeat = now + self.link_period;
        }
        // Supervision deadlines already passed have done their work (the fault is latched);
        // only those still ahead count, so the caller never gets a deadline at or before now.
        let supervision = [
            self.role.deadline(),
            self.receiver.deadline(),
            self.round_trip.deadline(),
            self.verdicts.deadline(),
            self.nmt.deadline(),
            self.input_check.deadline(),
            self.waiting_deadline(),
            self.lss.deadline(),
        ];
        #[cfg(feature = "simplecan")]
        let node_deadline = node_deadline.min(self.simplecan_poll(now, io));
        earliest_ahead(node_deadline.min(self.next_heartbeat), &supervision, now)
    }

    /// What the role answered: a frame to send (not in the safe state), or a fault.
    fn role_reply(
        &mut self,
        now: Instant,
        reply: Result<Option<CanFrame>, ChannelFault>,
        io: &mut impl Io,
    ) {
        match reply {
            Ok(Some(frame)) => {
                if self.fault.is_none() {
                    self.put_on_bus(frame, io);
                }
            }
            Ok(None) => {}
            Err(ChannelFault::ForeignFrame { id }) => {
                // Over a link at fault the report may not arrive, and channel B's verdict on a
                // plain frame rests on the link's announcements: one that is late looks like
                // none. Channel A finds a foreign frame without the link (it receives every
                // plain frame but its own), and its GFC goes as before.
                if !matches!(self.fault, Some(ChannelFault::Link(_))) {
                    self.send(&Message::ForeignFrame { id }, io);
                }
                self.foreign_frame(now, id, io);
            }
            Err(fault @ ChannelFault::InvertedMismatch { .. }) => {
                // Channel A cannot tell channel B's faulty inverted frame from a foreign
                // sender's, longer than the plain frame and carrying its inverse in its first
                // bytes, which completes the pair at the consumers (CiA 304 compares the first
                // n bytes): the GFC goes at once, as for any foreign frame (EN 50325-5 7.2.1).
                if self.fault.is_none() {
                    self.gfc_and_latch(now, fault, io);
                }
            }
            Err(fault) => {
                if self.fault.is_none() {
                    if let ChannelFault::TransmitMismatch { srdo } = fault {
                        let srdo = srdo.get();
                        self.send(&Message::TransmitMismatch { srdo }, io);
                    }
                    self.latch(fault, io);
                }
            }
        }
    }

    /// A frame on the node's transmit identifier `id` that the node did not send, found by
    /// this channel or the other: the safe state (EMCY naming `id`) and a GFC at once, each
    /// time one is seen (EN 50325-5 7.2.1). Only channel A's GFC reaches the bus; channel B's
    /// core records it (0x1300) like channel A's.
    ///
    /// The GFC is handed out before the latch's EMCY: the consumers must stop on it before
    /// the intruder's next frame, and a frame handed out first starts first when the bus is
    /// idle (the transmit queue orders by identifier, but cannot pull back a frame already
    /// on the bus).
    fn foreign_frame(&mut self, now: Instant, id: u16, io: &mut impl Io) {
        self.gfc_and_latch(now, ChannelFault::ForeignFrame { id }, io);
    }

    /// The safe state for `fault` and a GFC, the GFC handed out first
    /// ([`Runtime::foreign_frame`]).
    fn gfc_and_latch(&mut self, now: Instant, fault: ChannelFault, io: &mut impl Io) {
        let held = self.latch_holding(fault, io);
        // Foreign frames are watched in Operational only, where the core accepts the request;
        // outside Operational no GFC may go out (CiA 301 Table 2) and the latch is the reaction.
        let _ = self.node.request_gfc();
        collect!(collect);
        self.node.poll(now, &mut collect);
        self.after_core(now, &collect, io);
        for frame in held {
            io.transmit(frame);
        }
    }

    /// Puts `frame` on the bus; a plain SRDO frame of channel A is first announced to channel
    /// B over the link, so that B co-signs only what A sent.
    fn put_on_bus(&mut self, frame: CanFrame, io: &mut impl Io) {
        if self.role.speaks_for_the_node() && is_srdo(&frame) {
            let mut data = [0u8; 8];
            let len = frame.data().len();
            if let Some(bytes) = data.get_mut(..len) {
                bytes.copy_from_slice(frame.data());
            }
            self.send(
                &Message::PlainFrame {
                    id: frame.id().raw(),
                    // `len` <= 8.
                    len: len as u8,
                    data: u64::from_le_bytes(data),
                },
                io,
            );
        }
        io.transmit(frame);
    }

    /// A transmit SRDO frame of this channel's core: on towards the bus, unless it carries
    /// changed data while the channels' samples differ (for less than [`SAMPLE_WINDOW`]).
    // Out of line in the images: a marker of the emulator's profile
    // (`emulator::profile::MARKERS`), found in every activation that runs it.
    #[cfg_attr(target_os = "none", inline(never))]
    fn core_frame(&mut self, now: Instant, frame: CanFrame, io: &mut impl Io) {
        let id = frame.id();
        let changed = self.handed_on.get(id).is_none_or(|last| *last != frame);
        let samples_differ = self
            .input_check
            .differ_since()
            .is_some_and(|since| !shared::time::expired(since + SAMPLE_WINDOW, now));
        if changed && samples_differ {
            // One entry per transmit SRDO, and `N` is the SRDO count: it fits.
            let _ = self.waiting.keep(frame);
            return;
        }
        // A frame handed on supersedes one still waiting for the same SRDO.
        let _ = self.waiting.take(id);
        let _ = self.handed_on.keep(frame);
        if let Some(frame) = self.role.outgoing(frame, self.node.safety_config()) {
            self.put_on_bus(frame, io);
        }
    }

    /// Hands on the waiting frames once the samples agree or the window has passed.
    fn release_waiting(&mut self, now: Instant, io: &mut impl Io) {
        if self.waiting.is_empty() || self.waiting_deadline() > now {
            return;
        }
        // Handed on now (the samples agree, or the window has passed), none waits again.
        while let Some(frame) = self.waiting.take_any() {
            if self.fault.is_none() {
                self.core_frame(now, frame, io);
            }
        }
    }

    /// Until when the waiting frames wait ([`Instant::ZERO`]: not at all any more).
    fn waiting_deadline(&self) -> Instant {
        match (self.waiting.is_empty(), self.input_check.differ_since()) {
            (true, _) => Instant::NEVER,
            (false, Some(since)) => since + SAMPLE_WINDOW,
            (false, None) => Instant::ZERO,
        }
    }

    /// The SRDO frames seen just before this channel entered Operational, still within the
    /// role's window, observed now as if they had come after (see [`Runtime::on_frame`]).
    fn observe_early(&mut self, now: Instant, io: &mut impl Io) {
        let window = self.role.window();
        let early = core::mem::take(&mut self.early);
        for (at, frame) in early {
            if self.fault.is_none() && !shared::time::expired(at + window, now) {
                let reply = self
                    .role
                    .observe_seen(now, at, &frame, self.node.safety_config());
                self.role_reply(now, reply, io);
            }
        }
    }

    /// Latches [`LinkFault::Latency`] once a probe has not been answered within the bound:
    /// first thing in every call, so that what else the call brings (channel B's end of a wait
    /// for an announcement) comes after it.
    fn settle_round_trip(&mut self, now: Instant, io: &mut impl Io) {
        if let Err(fault) = self.round_trip.poll(now) {
            self.latch(ChannelFault::Link(fault), io);
        }
    }

    /// Arms the latency supervision where the node produces SRDOs, which channel B co-signs
    /// on channel A's announcements, with the bound of the announcement window; disarms it
    /// otherwise (the verdicts and NMT states the link carries then have the time-out's
    /// tolerance). Called every link period: a changed configuration counts from the next.
    fn arm_round_trip(&mut self) {
        let produces = self
            .node
            .safety_config()
            .srdos
            .iter()
            .any(|record| record.parsed_direction() == Ok(Direction::Transmit));
        let bound = produces.then(|| round_trip_bound(self.role.announcement_window()));
        self.round_trip.set_bound(bound);
    }

    /// Sends a probe of the link's round trip, if the supervision is armed.
    fn probe(&mut self, now: Instant, io: &mut impl Io) {
        if let Some(probe) = self.round_trip.probe(now) {
            self.send(&probe, io);
        }
    }

    /// `true` for a data frame on the plain identifier (COB-ID 1) of one of the node's
    /// transmit SRDOs.
    fn is_own_plain_frame(&self, frame: &CanFrame) -> bool {
        let id = u32::from(frame.id().raw());
        !frame.is_remote()
            && self.node.safety_config().srdos.iter().any(|record| {
                record.parsed_direction() == Ok(Direction::Transmit)
                    && record.cob_id_1 & 0x7FF == id
            })
    }

    /// An LSS answer of this channel's core (CiA 305): channel A announces it to channel B
    /// and puts it on the bus; channel B pairs it with A's announcement ([`crate::lss`]).
    fn lss_answer(&mut self, now: Instant, answer: &CanFrame, io: &mut impl Io) {
        if self.role.speaks_for_the_node() {
            self.send(
                &Message::LssAnswer {
                    data: crate::lss::answer_bytes(answer),
                },
                io,
            );
            io.transmit(*answer);
        } else if let Err(mismatch) = self.lss.own(now, answer) {
            self.latch(ChannelFault::Lss(mismatch), io);
        }
    }

    // Out of line in the images: a marker of the emulator's profile
    // (`emulator::profile::MARKERS`), found in every activation that runs it.
    #[cfg_attr(target_os = "none", inline(never))]
    fn heartbeat(&mut self, io: &mut impl Io) {
        let config = self.node.safety_config();
        let signatures = self.role.signature_digest(config);
        self.own_digest = Some(signatures);
        let settings = self.lss_settings();
        let heartbeat = Message::Heartbeat {
            nmt: self.node.nmt_state().heartbeat_code(),
            working: self.is_working(),
            epoch: self.nmt.epoch(),
            valid: config.configuration_valid,
            signatures,
            inputs: self.input_digest(),
            node: settings.node_byte(),
            bit_rate: settings.bit_rate_byte(),
        };
        self.send(&heartbeat, io);
    }

    // Out of line in the images: a marker of the emulator's profile
    // (`emulator::profile::MARKERS`), found in every activation that runs it.
    #[cfg_attr(target_os = "none", inline(never))]
    fn send(&mut self, message: &Message, io: &mut impl Io) {
        // Every message fits a frame; an encoding failure would be a bug, and the other
        // channel then sees a sequence gap and goes to the safe state.
        let mut bytes = heapless::Vec::new();
        if self.sender.encode_into(message, &mut bytes).is_ok() {
            io.link(&bytes);
        }
    }

    /// What the core handed out: frames through the role, events through the cross-checks.
    /// The lists are borrowed, not moved: they hold 16 frames and 16 events, and moving them
    /// (into the call and into each loop) showed in the full-network simulation's profile as
    /// instructions in `memcpy`.
    fn after_core(&mut self, now: Instant, collect: &Collect<'_>, io: &mut impl Io) {
        for &frame in collect.frames.iter() {
            if is_srdo(&frame) {
                if self.fault.is_none() {
                    self.core_frame(now, frame, io);
                }
            } else {
                #[cfg(feature = "simplecan")]
                self.simplecan_own(now, &frame, io);
                if crate::lss::is_answer(&frame) {
                    self.lss_answer(now, &frame, io);
                } else if let Some(frame) = self.role.outgoing(frame, self.node.safety_config()) {
                    io.transmit(frame);
                }
            }
        }
        let mut nmt_changed = false;
        for &event in collect.events.iter() {
            io.event(ChannelEvent::Node(event));
            nmt_changed |= matches!(event, Event::NmtState(_));
            match event {
                Event::SrdoReceived { srdo, data } => self.local_pair(now, srdo, data, io),
                Event::NmtState(NmtState::Initialising) => {
                    self.nmt.reset();
                    self.role.reset();
                    self.waiting.clear();
                    self.handed_on.clear();
                    // A difference seen before the reset must last its full time after it to
                    // count again: the reset clears the latch, and the other channel's news
                    // (its new input digest, say) may be on the link behind the reset.
                    self.input_check.restart(now);
                    // Likewise a link that had timed out (a wire cut and mended): its
                    // silence before the reset is not judged after it; the other channel's
                    // next message must come within a whole time-out from the reset, as at
                    // power-on, and a link still dead times out again then (CiA 304 9.5).
                    if self.receiver.reset_if_timed_out(now) {
                        self.round_trip.forget();
                    }
                    self.follow_core(io);
                }
                Event::NmtState(NmtState::PreOperational) => {
                    self.restore_inputs(io);
                    self.follow_core(io);
                }
                Event::SafeState(cause) => {
                    if !matches!(cause, SafeStateCause::Application { .. }) {
                        // A fault the core found (an SRDO fault, a GFC): the other channel,
                        // whose receive path may not show it, is told at once rather than
                        // through the verdict time-out. Application causes are this
                        // channel's own latch, which tells it already.
                        self.send(
                            &Message::SafeState {
                                cause: safe_state_code(&cause),
                            },
                            io,
                        );
                    }
                    self.follow_core(io);
                }
                Event::NmtState(NmtState::Operational) => {
                    self.follow_core(io);
                    self.observe_early(now, io);
                }
                Event::NmtState(_) => self.follow_core(io),
                _ => {}
            }
        }
        #[cfg(feature = "simplecan")]
        self.simplecan_aborts(collect.aborts, io);
        if collect.overflow {
            self.latch(ChannelFault::CoreOutputFull, io);
        }
        if nmt_changed {
            // The other channel learns a new NMT state at once, not at the next heartbeat:
            // otherwise the start-up handshake (each channel boots on hearing the other) and
            // the link's latency could take longer than the NMT grace of two link periods.
            self.heartbeat(io);
            self.next_heartbeat = now + self.link_period;
        }
        let own = self.node.nmt_state();
        self.nmt.compare(now, own);
    }

    /// The core left the working state (a fault of its own, or NMT): outputs 0.
    fn follow_core(&mut self, io: &mut impl Io) {
        if !self.node.is_working() {
            self.clear_outputs(io);
        }
        if self.node.nmt_state() != NmtState::Operational {
            #[cfg(feature = "simplecan")]
            self.simplecan.reset();
            self.verdicts.reset();
            self.pairs = [0; N];
            self.peer_pairs = [0; N];
            self.configuration.reset();
        }
        if matches!(
            self.node.nmt_state(),
            NmtState::Initialising | NmtState::PreOperational
        ) && self.node.fault().is_none()
        {
            // NMT reset: the channel's own latch clears with the core's.
            self.fault = None;
        }
    }

    fn local_pair(&mut self, now: Instant, srdo: SrdoNumber, data: u64, io: &mut impl Io) {
        let index = srdo.index();
        if index >= N {
            return;
        }
        self.pairs[index] = self.pairs[index].wrapping_add(1);
        let verdict = Verdict {
            pair: self.pairs[index],
            valid: true,
            data,
        };
        self.send(
            &Message::Verdict {
                srdo: srdo.get(),
                pair: verdict.pair,
                data,
                valid: true,
            },
            io,
        );
        // Towards the safe state at once: any bit this pair clears is cleared now.
        let safer = self.outputs[index] & data;
        self.drive(srdo, safer, io);
        match self.verdicts.local(now, srdo, verdict) {
            Ok(Some(confirmed)) => self.confirmed(srdo, confirmed, io),
            Ok(None) => {}
            Err(fault) => self.latch(ChannelFault::Cross(fault), io),
        }
    }

    fn on_message(&mut self, now: Instant, message: Message, io: &mut impl Io) {
        match message {
            // Answered at once, whatever the state or epoch: the other channel's round trip
            // is measured on it.
            Message::Probe { stamp } => return self.send(&Message::Echo { stamp }, io),
            Message::Echo { stamp } => {
                if let Err(fault) = self.round_trip.echo(now, stamp) {
                    self.latch(ChannelFault::Link(fault), io);
                }
                return;
            }
            _ => {}
        }
        #[cfg(feature = "defmt")]
        if !matches!(message, Message::Heartbeat { .. }) {
            defmt::debug!("link: {}", message);
        }
        if let Message::Heartbeat {
            nmt,
            epoch,
            valid,
            signatures,
            inputs,
            node,
            bit_rate,
            ..
        } = message
        {
            if self.peer_clock.heartbeat(now, nmt, epoch).is_err() {
                self.latch(ChannelFault::ClockDrift, io);
            }
            let before = self.nmt.peer_epoch();
            self.nmt.peer(now, nmt, epoch, self.node.nmt_state());
            if before.is_some_and(|before| before != epoch) {
                self.role.peer_reset(now);
                // A frame of the other channel's ended epoch kept before this heartbeat came.
                let role = &mut self.role;
                self.early
                    .retain(|(_, frame)| !role.ended_frame(now, frame));
            }
            if self.nmt.same_epoch() {
                // The node-ID in force changes only at an NMT reset, a new epoch on both
                // channels; the bit rate not in Operational ([`crate::lss`]).
                let operational = nmt == NmtState::Operational.heartbeat_code()
                    && self.node.nmt_state() == NmtState::Operational;
                let peer = Settings::from_bytes(node, bit_rate);
                if let Err(mismatch) = peer.compare(&self.lss_settings(), operational) {
                    self.latch(ChannelFault::Lss(mismatch), io);
                }
                // The digests as of the sender's heartbeat, in the order the checks took them
                // when they came as messages of their own: configuration, then inputs.
                self.peer_configuration(nmt, valid, signatures, io);
                self.peer_inputs(now, inputs, io);
            }
            return;
        }
        // An announcement of a plain frame counts whatever the epochs: it says what channel A
        // puts on the bus now, and channel B uses it only for a bus frame equal to it. After an
        // NMT reset and start, A's first announcement can overtake B's own handling of those
        // NMT frames (each channel runs its own loop); dropping it would make A's first plain
        // frame look foreign to B. A replay of an announced frame by another device is still
        // caught by A, which never receives its own frames.
        // So does an LSS answer: LSS lives across NMT resets, and answers pair in order.
        let announcement = matches!(
            message,
            Message::PlainFrame { .. } | Message::LssAnswer { .. }
        );
        if !announcement && !self.nmt.same_epoch() {
            // Sent before a reset that one of us has been through and the other not yet (the
            // link may lag the bus): not about the present. Epochs that stay apart are an NMT
            // mismatch ([`NmtCheck`]).
            return;
        }
        match message {
            Message::Heartbeat { .. } | Message::Probe { .. } | Message::Echo { .. } => {}
            Message::Inputs { sample } => self.peer_inputs(now, sample, io),
            Message::Verdict {
                srdo,
                pair,
                data,
                valid,
            } => {
                if self.node.nmt_state() != NmtState::Operational {
                    // Sent before the other channel left Operational too, and still on the
                    // link when this one left and cleared its verdicts: about a pair that
                    // neither channel acts on any more (outputs are 0 outside Operational), so
                    // it waits for no local verdict (CiA 304 9.5).
                    return;
                }
                if let Some(newest) = usize::from(srdo)
                    .checked_sub(1)
                    .and_then(|index| self.peer_pairs.get_mut(index))
                {
                    *newest = pair;
                }
                let verdict = Verdict { pair, valid, data };
                match self.verdicts.remote(now, srdo, verdict) {
                    // A confirmed verdict names one of the check's SRDOs, so it has a number.
                    Ok(Some(confirmed)) => match SrdoNumber::new(srdo) {
                        Some(srdo) => self.confirmed(srdo, confirmed, io),
                        None => {
                            self.latch(ChannelFault::Cross(CrossFault::UnknownSrdo { srdo }), io)
                        }
                    },
                    Ok(None) => {}
                    Err(fault) => self.latch(ChannelFault::Cross(fault), io),
                }
            }
            Message::TransmitMismatch { srdo } => {
                // The other channel reports a mismatch either way: the safe state. A number
                // that is no SRDO makes the message no message of the set.
                let fault = SrdoNumber::new(srdo)
                    .map_or(ChannelFault::Link(LinkFault::Malformed), |srdo| {
                        ChannelFault::TransmitMismatch { srdo }
                    });
                self.latch(fault, io);
            }
            Message::PlainFrame { id, len, data } => {
                let bytes = data.to_le_bytes();
                let frame = shared::CanId::new(id)
                    .ok()
                    .zip(bytes.get(..usize::from(len)))
                    .and_then(|(id, data)| CanFrame::new(id, data).ok());
                match frame {
                    Some(frame) => {
                        let reply = self.role.announced(now, &frame, self.node.safety_config());
                        self.role_reply(now, reply, io);
                    }
                    None => self.latch(ChannelFault::Link(LinkFault::Malformed), io),
                }
            }
            Message::ForeignFrame { id } => self.foreign_frame(now, id, io),
            Message::LssAnswer { data } => {
                // Only channel A announces; the one that speaks for the node never gets one.
                let paired = if self.role.speaks_for_the_node() {
                    Err(ChannelFault::Link(LinkFault::Malformed))
                } else {
                    self.lss.announced(now, data).map_err(ChannelFault::Lss)
                };
                if let Err(fault) = paired {
                    self.latch(fault, io);
                }
            }
            #[cfg(feature = "simplecan")]
            message @ (Message::SimpleCanPacket { .. }
            | Message::SimpleCanVerdict { .. }
            | Message::SimpleCanFault { .. }) => {
                self.simplecan_message(now, message, io);
            }
            Message::SafeState { cause } => {
                // A channel already in its safe state (its own core found the fault too, say:
                // both see the same bus) keeps its own cause, which is what it reports.
                if self.fault.is_none() && self.node.fault().is_none() {
                    self.latch(ChannelFault::PeerSafeState { cause }, io);
                }
            }
        }
    }

    /// The other channel's configuration digest (CiA 304 9.5: both channels hold the same
    /// configuration), compared where neither can change it: in Operational.
    fn peer_configuration(&mut self, nmt: u8, valid: u8, signatures: u32, io: &mut impl Io) {
        let own = self.node.safety_config();
        let own_digest = match self.own_digest {
            Some(digest) => digest,
            None => self.role.signature_digest(own),
        };
        let differs = valid != own.configuration_valid || signatures != own_digest;
        let checked = self.configuration.peer(
            nmt == NmtState::Operational.heartbeat_code(),
            self.node.nmt_state() == NmtState::Operational,
            differs,
        );
        if let Err(fault) = checked {
            self.latch(fault, io);
        }
    }

    /// The other channel's input digest, for the input cross-check.
    fn peer_inputs(&mut self, now: Instant, sample: u32, io: &mut impl Io) {
        let own = self.input_digest();
        self.input_check.peer(now, sample, own);
        self.release_waiting(now, io);
    }

    /// Writes a sample and its inverted copy to the core's objects.
    fn write_input(node: &mut Device<F, P>, sample: &InputSample) -> Result<(), AbortCode> {
        let value = sample.bytes.get(..sample.len).unwrap_or_default();
        let mut flipped = [0u8; 8];
        for (out, byte) in flipped.iter_mut().zip(value) {
            *out = !byte;
        }
        node.write_object(sample.plain, value)?;
        node.write_object(
            sample.inverted,
            flipped.get(..sample.len).unwrap_or_default(),
        )
    }

    /// NMT reset node brought the application objects back to their defaults (CiA 301
    /// 7.3.2.2.3): the inputs are what the channel sampled, not defaults, so they are written
    /// again. A write that fails now succeeded before: the core is not what it was, a fault.
    fn restore_inputs(&mut self, io: &mut impl Io) {
        let failed = self
            .inputs
            .iter()
            .any(|sample| Self::write_input(&mut self.node, sample).is_err());
        if failed {
            self.latch(ChannelFault::InputRestoreFailed, io);
        }
    }

    /// CRC-32 over this channel's input samples, in the order they were first sampled.
    fn input_digest(&self) -> u32 {
        const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
        let mut digest = CRC.digest();
        for sample in &self.inputs {
            digest.update(&sample.plain.index.to_le_bytes());
            digest.update(&[sample.plain.sub]);
            digest.update(&sample.value().to_le_bytes());
        }
        digest.finalize()
    }

    /// Starts or stops the input discrepancy timer against this channel's digest now.
    fn compare_inputs(&mut self, now: Instant) {
        let own = self.input_digest();
        self.input_check.compare(now, own);
    }

    /// Both channels confirmed `verdict` on receive SRDO `srdo`. It drives the output only if
    /// it is the newest pair this channel accepted and the newest the other channel reported;
    /// an older one (its verdict crossed the link while a newer pair arrived) may only lower
    /// the output (SC_REQ_05: a stale confirmation never switches an output back on).
    fn confirmed(&mut self, srdo: SrdoNumber, verdict: Verdict, io: &mut impl Io) {
        let data = verdict.data;
        io.event(ChannelEvent::Confirmed { srdo, data });
        if !self.configuration.confirmed() {
            // Both channels agree on the data, but not yet (in Operational) on the
            // configuration that produced it: the output stays where it is.
            return;
        }
        let index = srdo.index();
        if index >= N {
            return;
        }
        let newest = self.pairs.get(index) == Some(&verdict.pair)
            && self.peer_pairs.get(index) == Some(&verdict.pair);
        let value = if newest {
            data
        } else {
            self.outputs[index] & data
        };
        self.drive(srdo, value, io);
    }

    /// Drives receive SRDO `srdo`'s output(s) to `data` (0 outside the working state). The
    /// callers checked that `srdo` is one of the node's (`srdo.index() < N`).
    fn drive(&mut self, srdo: SrdoNumber, data: u64, io: &mut impl Io) {
        let value = if self.is_working() { data } else { 0 };
        let Some(output) = self.outputs.get_mut(srdo.index()) else {
            return;
        };
        if *output != value {
            *output = value;
            io.output(srdo, value);
        }
    }

    fn clear_outputs(&mut self, io: &mut impl Io) {
        #[cfg(feature = "simplecan")]
        self.simplecan.clear_outputs(io);
        // N <= 64 (the core refuses more), so every slot has a number.
        for (index, output) in self.outputs.iter_mut().enumerate() {
            if *output != 0 {
                *output = 0;
                if let Some(srdo) = SrdoNumber::of_slot(index) {
                    io.output(srdo, 0);
                }
            }
        }
    }

    /// Latches the channel's safe state for `fault` (once).
    fn latch(&mut self, fault: ChannelFault, io: &mut impl Io) {
        for frame in self.latch_holding(fault, io) {
            io.transmit(frame);
        }
    }

    /// [`Runtime::latch`], but the frames the core sends on entering the safe state (its
    /// EMCY) are returned for the caller to hand out, after a frame that must go first.
    /// Nothing when the channel was latched already.
    fn latch_holding(&mut self, fault: ChannelFault, io: &mut impl Io) -> HeldFrames {
        let mut held = HeldFrames::new();
        if self.fault.is_some() {
            return held;
        }
        self.fault = Some(fault);
        self.waiting.clear();
        self.clear_outputs(io);
        io.event(ChannelEvent::Fault(fault));
        if !matches!(fault, ChannelFault::PeerSafeState { .. }) {
            self.send(
                &Message::SafeState {
                    cause: fault.cause_code(),
                },
                io,
            );
        }
        collect!(collect);
        let named = match fault {
            ChannelFault::ForeignFrame { id } => {
                let [low, high] = id.to_le_bytes();
                [low, high, 0]
            }
            // The other channel's own cause, which it cannot send on the bus itself.
            ChannelFault::PeerSafeState { cause } => [cause, 0, 0],
            #[cfg(feature = "simplecan")]
            ChannelFault::SimpleCan(fault) => self.simplecan_named(fault),
            _ => [0; 3],
        };
        self.node
            .enter_safe_state_with(fault.cause_code(), named, &mut collect);
        // An unconfigured node (no node-ID, CiA 305) sends nothing but LSS answers: its
        // cause is in the event and on the link, not in an EMCY.
        let configured = self.node.configured_node_id().is_some();
        for &frame in collect.frames.iter() {
            if configured && !is_srdo(&frame) {
                if let Some(frame) = self.role.outgoing(frame, self.node.safety_config()) {
                    if let Err(frame) = held.push(frame) {
                        // More than the core sends on entering the safe state (one EMCY):
                        // out at once rather than lost, only its place in the order goes.
                        io.transmit(frame);
                    }
                }
            }
        }
        for &event in collect.events.iter() {
            io.event(ChannelEvent::Node(event));
        }
        held
    }
}

/// The frames [`Runtime::latch_holding`] hands back: the core's EMCY on entering the safe
/// state (one frame; room for a few).
type HeldFrames = heapless::Vec<CanFrame, 4>;

/// At most one frame per identifier, in `C` fixed slots. Entries are never shifted: shifting
/// (`retain`, `swap_remove`) compiles to a `memmove` call here, which pulls compiler-builtins'
/// `memmove` into the channel images (its size: docs/footprint.md).
#[derive(Clone, Copy, Debug)]
pub struct FrameSlots<const C: usize> {
    slots: [Option<CanFrame>; C],
}

impl<const C: usize> Default for FrameSlots<C> {
    fn default() -> Self {
        FrameSlots { slots: [None; C] }
    }
}

impl<const C: usize> FrameSlots<C> {
    /// The frame kept for identifier `id`, if any.
    pub fn get(&self, id: shared::CanId) -> Option<&CanFrame> {
        self.slots.iter().flatten().find(|kept| kept.id() == id)
    }

    /// Keeps `frame` as the one for its identifier, replacing an older one; `false` when
    /// every slot holds another identifier.
    pub fn keep(&mut self, frame: CanFrame) -> bool {
        let same = self
            .slots
            .iter()
            .position(|slot| slot.is_some_and(|kept| kept.id() == frame.id()));
        let free = || self.slots.iter().position(Option::is_none);
        match same
            .or_else(free)
            .and_then(|index| self.slots.get_mut(index))
        {
            Some(slot) => {
                *slot = Some(frame);
                true
            }
            None => false,
        }
    }

    /// Removes and returns the frame kept for identifier `id`.
    pub fn take(&mut self, id: shared::CanId) -> Option<CanFrame> {
        self.slots
            .iter_mut()
            .find(|slot| slot.is_some_and(|kept| kept.id() == id))
            .and_then(Option::take)
    }

    /// Removes and returns any one frame.
    pub fn take_any(&mut self) -> Option<CanFrame> {
        self.slots.iter_mut().find_map(Option::take)
    }

    /// `true` when no frame is kept.
    pub fn is_empty(&self) -> bool {
        self.slots.iter().all(Option::is_none)
    }

    /// Forgets every frame.
    pub fn clear(&mut self) {
        self.slots = [None; C];
    }
}

/// `true` for identifiers in the SRDO range ([`SRDO_IDENTIFIERS`]).
pub fn is_srdo(frame: &CanFrame) -> bool {
    SRDO_IDENTIFIERS.contains(&frame.id().raw())
}

/// The earliest of `first` and those of `deadlines` after `now` (a deadline at or before
/// `now` has done its work). A plain loop over the slice: the iterator chain it replaces
/// (`into_iter`, `filter`, `fold` on the array) was compiled into a copy of the array and a
/// call per element at every poll (`docs/emulated-figures.md`).
fn earliest_ahead(first: Instant, deadlines: &[Instant], now: Instant) -> Instant {
    let mut earliest = first;
    for &deadline in deadlines {
        if deadline > now && deadline < earliest {
            earliest = deadline;
        }
    }
    earliest
}

/// CRC-32 over signatures, as [`Role::signature_digest`] folds them for the link: each
/// signature little-endian, in SRDO order. The fold is shared; the signatures are not.
pub fn fold_signatures(signatures: impl Iterator<Item = u16>) -> u32 {
    const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
    let mut digest = CRC.digest();
    for signature in signatures {
        digest.update(&signature.to_le_bytes());
    }
    digest.finalize()
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::CanId;

    fn frame(id: u16, value: u8) -> CanFrame {
        CanFrame::new(CanId::new(id).unwrap(), &[value]).unwrap()
    }

    /// Eighteen input objects, nine plain and nine inverted, one byte each.
    static MANY_INPUTS: [shared::process_image::AppObject; 18] = {
        use shared::process_image::{Access, AppObject, Mappable};
        let mut objects = [AppObject {
            address: Address::new(0x6000, 1),
            len: 1,
            access: Access::ReadOnly,
            mappable: Mappable::Transmit,
        }; 18];
        let mut index = 0;
        while index < 18 {
            objects[index].address = Address::new(0x6000 + index as u16, 1);
            index += 1;
        }
        objects
    };

    /// A role that does nothing: the input table is the runtime's own.
    struct Quiet;

    impl Role<1> for Quiet {
        fn outgoing(&mut self, frame: CanFrame, _: &SafetyConfig<1>) -> Option<CanFrame> {
            Some(frame)
        }
        fn observe(
            &mut self,
            _: Instant,
            _: &CanFrame,
            _: &SafetyConfig<1>,
        ) -> Result<Option<CanFrame>, ChannelFault> {
            Ok(None)
        }
        fn input(
            &mut self,
            _: Instant,
            _: Address,
            _: &[u8],
            _: &SafetyConfig<1>,
        ) -> Result<Option<CanFrame>, ChannelFault> {
            Ok(None)
        }
        fn poll(&mut self, _: Instant) -> Result<(), ChannelFault> {
            Ok(())
        }
        fn deadline(&self) -> Instant {
            Instant::NEVER
        }
        fn signature_digest(&self, _: &SafetyConfig<1>) -> u32 {
            0
        }
    }

    /// What the runtime did, as far as the test looks.
    #[derive(Default)]
    struct Seen {
        faults: std::vec::Vec<ChannelFault>,
    }

    impl Io for Seen {
        fn transmit(&mut self, _: CanFrame) {}
        fn link(&mut self, _: &[u8]) {}
        fn output(&mut self, _: SrdoNumber, _: u64) {}
        fn event(&mut self, event: ChannelEvent) {
            if let ChannelEvent::Fault(fault) = event {
                self.faults.push(fault);
            }
        }
    }

    /// More safety inputs than the channel's input table holds is a limit of the channel's
    /// design, and the fault says so: not an input discrepancy, which is the other channel's
    /// sample differing from this one's.
    #[test]
    fn more_inputs_than_the_input_table_holds_is_a_full_table_not_a_discrepancy() {
        let mut config =
            safety_device::config(shared::canopen::NodeId::new(1).unwrap(), "input table test");
        config.app_objects = &MANY_INPUTS;
        let mut runtime = Runtime::<_, _, 1>::new(
            config,
            shared::canopen::storage::RamFlash::<4096>::new(),
            Quiet,
            Instant::ZERO,
            Duration::from_millis(10),
        )
        .unwrap();
        let mut seen = Seen::default();
        let now = Instant::from_millis(1);
        for input in 0..MAX_INPUTS as u16 {
            let plain = Address::new(0x6000 + 2 * input, 1);
            let inverted = Address::new(0x6001 + 2 * input, 1);
            runtime
                .set_input(now, plain, inverted, &[1], &mut seen)
                .unwrap();
        }
        assert_eq!(runtime.fault(), None, "{:?}", seen.faults);
        let (plain, inverted) = (Address::new(0x6010, 1), Address::new(0x6011, 1));
        runtime
            .set_input(now, plain, inverted, &[1], &mut seen)
            .unwrap();
        assert_eq!(runtime.fault(), Some(ChannelFault::InputTableFull));
        assert_eq!(seen.faults, [ChannelFault::InputTableFull]);
        assert_eq!(ChannelFault::InputTableFull.cause_code(), 0x37);
    }

    /// One frame per identifier: the newest replaces the older, a full set refuses another
    /// identifier, and what is taken is gone.
    /// Pairs are counted, not logged one by one; transitions and faults are logged.
    #[test]
    fn only_the_events_of_every_pair_are_per_pair() {
        let srdo = SrdoNumber::FIRST;
        assert!(ChannelEvent::Node(Event::SrdoReceived { srdo, data: 1 }).is_per_pair());
        assert!(ChannelEvent::Confirmed { srdo, data: 1 }.is_per_pair());
        assert!(!ChannelEvent::Node(Event::GfcReceived).is_per_pair());
        assert!(!ChannelEvent::Node(Event::NmtState(NmtState::Operational)).is_per_pair());
        assert!(!ChannelEvent::Fault(ChannelFault::BusOff).is_per_pair());
    }

    #[test]
    fn frame_slots_keep_the_newest_frame_per_identifier() {
        let mut slots = FrameSlots::<2>::default();
        assert!(slots.is_empty());
        assert!(slots.keep(frame(0x101, 1)));
        assert!(slots.keep(frame(0x101, 2)));
        assert_eq!(slots.get(frame(0x101, 0).id()), Some(&frame(0x101, 2)));
        assert!(slots.keep(frame(0x103, 3)));
        assert!(!slots.keep(frame(0x105, 4)), "full");
        assert_eq!(slots.take(frame(0x101, 0).id()), Some(frame(0x101, 2)));
        assert_eq!(slots.take(frame(0x101, 0).id()), None);
        assert_eq!(slots.take_any(), Some(frame(0x103, 3)));
        assert!(slots.is_empty());
        assert!(slots.keep(frame(0x105, 4)));
        slots.clear();
        assert_eq!(slots.take_any(), None);
    }
}
