//! One CANopen Safety device: NMT slave, SDO server, heartbeat, EMCY, GFC and up to `N` SRDOs
//! around a process image, fed frames and time, answering with frames, events and deadlines.
//!
//! # Driving a node
//! ```text
//! let mut node = Node::<_, 4>::new(config, flash)?;   // Initialising
//! loop {
//!     let deadline = node.poll(now, &mut sink);        // boot-up, timers, cyclic SRDOs
//!     // sleep until `deadline` or until a frame arrives, then:
//!     node.handle_frame(now, &frame, &mut sink);
//! }
//! ```
//! [`Node::poll`] returns the instant at which it wants to be polled again. It is never later
//! than the earliest real deadline; it may be earlier (after a frame pushed a timer back), in
//! which case that poll finds nothing to do and answers the next one. Polling when nothing is
//! due costs one comparison.
//!
//! # Safe state (EN 50325-5 8.2.2)
//! The device is in its *working state* only in Operational, with a configuration that passed
//! the Operational-entry check, and with no latched fault. In every other case each received
//! SRDO value (every object mapped by a receive SRDO) is 0 (SC_REQ_05). A fault of a received
//! SRDO or a GFC latches the safe state until NMT resets the node or its communication; the
//! cause is reported as an [`Event`] and as an EMCY. The producers keep sending the device's
//! own inputs through a communication fault (they are another device's safety function),
//! but stop for good when their own two halves disagree.

pub mod access;
mod dictionary;
mod integrity;
mod persist;

use heapless::Vec;

use crate::canopen::emcy::{self, Emergency};
use crate::canopen::heartbeat::{self, Heartbeat};
use crate::canopen::nmt::{self, NmtCommand, NmtError, NmtState};
use crate::canopen::node_id::NodeId;
use crate::canopen::od::{AbortCode, Address};
use crate::canopen::sdo::SdoServer;
use crate::canopen::storage::{Flash, StorageError};
use crate::frame::{CanFrame, CanId};
use crate::process_image::{AppObject, ProcessImage, TableError};
use crate::safety::config::{ConfigFault, ResolvedMapping, SafetyConfig};
use crate::safety::srdo::{
    self, Consumer, Discarded, InvertedOutcome, PlainOutcome, Producer, SrdoFault, SrdoFaultCause,
};
use crate::safety::types::{Direction, SrdoNumber};
use crate::safety::{MAX_SRDOS, gfc};
use crate::time::{Duration, Instant};

pub use integrity::{IDLE_PERIOD as INTEGRITY_IDLE_PERIOD, IntegrityFault};
pub use persist::PersistError;

/// What a device is: its identity, its application objects, and the defaults of its
/// communication parameters.
#[derive(Clone, Copy, Debug)]
pub struct NodeConfig {
    /// Node-ID, `1..=127`.
    pub node_id: NodeId,
    /// Object 0x1000, device type.
    pub device_type: u32,
    /// Object 0x1008, manufacturer device name.
    pub device_name: &'static str,
    /// Object 0x1018, identity: vendor-ID, product code, revision number, serial number.
    pub identity: [u32; 4],
    /// The application objects SRDO mappings can point at.
    pub app_objects: &'static [AppObject],
    /// Default mapping of SRDO 1 when the pre-defined connection set makes it a producer.
    pub default_transmit_mapping: &'static [u32],
    /// Default mapping of SRDO 1 when the pre-defined connection set makes it a consumer.
    pub default_receive_mapping: &'static [u32],
    /// Default of object 0x1017, producer heartbeat time in ms (0: off).
    pub heartbeat_ms: u16,
    /// How long a segmented SDO transfer may wait for its next request.
    pub sdo_timeout: Duration,
    /// Transmit an SRDO as soon as its mapped data changes, besides cyclically
    /// (EN 50325-5 6.2.1).
    pub event_driven: bool,
    /// Send a GFC when this device detects a fault (EN 50325-5 6.3.1 example).
    pub gfc_on_fault: bool,
}

/// Where the frames and events of a node go. Implemented by the caller: a test recorder, a
/// simulated bus, or the firmware's transmit queue.
///
/// A firmware adapter that cannot queue a frame must itself drive its outputs to the safe
/// state: the core cannot know that a frame it handed over was lost.
pub trait Sink {
    /// Sends `frame` on the bus, in the order handed over.
    fn transmit(&mut self, frame: CanFrame);
    /// Reports `event` to the application.
    fn event(&mut self, event: Event);
}

/// Why the device is in its latched safe state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SafeStateCause {
    /// An SRDO failed (EN 50325-5 7.1.2, 7.1.3; CiA 304 9.5).
    Srdo(SrdoFault),
    /// A global fail-safe command was received (EN 50325-5 7.2.1).
    Gfc,
    /// The application found a fault the protocol core cannot see (in a dual-channel device:
    /// the channels disagree, or their link failed). `detail` is the application's cause
    /// code, reported in EMCY FF02h. Producers stop too: the data behind them is in doubt.
    Application {
        /// The application's cause code (EMCY detail byte 1).
        detail: u8,
    },
    /// The periodic check in Operational found the configuration in use damaged (EMCY 6300h;
    /// detail byte 1 F2h..F5h names what differed). Producers stop too.
    Integrity(IntegrityFault),
}

/// Something the application should know.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Event {
    /// The NMT state changed to this one.
    NmtState(NmtState),
    /// A valid SRDO pair was received and its data delivered (EN 50325-5 6.2.2).
    SrdoReceived {
        /// The SRDO.
        srdo: SrdoNumber,
        /// Its plain data, little-endian, in the mapped bytes (the rest 0).
        data: u64,
    },
    /// An SRDO failed; the device is in the safe state.
    SrdoFault(SrdoFault),
    /// The device entered its latched safe state for this cause.
    SafeState(SafeStateCause),
    /// A GFC was received.
    GfcReceived,
    /// This device sent a GFC.
    GfcSent,
    /// The configuration did not pass the Operational-entry check; the device stays in its
    /// NMT state and in the safe state (EN 50325-5 8.3.1).
    ConfigurationRefused(ConfigFault),
    /// A consumer discarded a frame as a CAN double reception (or an inverted frame seen
    /// first after monitoring started); nothing was delivered and nothing failed. Counted in
    /// [`Node::double_reception`].
    FrameDiscarded {
        /// The SRDO.
        srdo: SrdoNumber,
        /// Which frame, and why.
        discarded: Discarded,
    },
    /// A remote frame (RTR) on an SRDO identifier was ignored (EN 50325-5 6.2.1).
    RemoteFrameIgnored(SrdoNumber),
    /// An NMT frame was not obeyed.
    NmtRefused(NmtError),
    /// Parameters were restored from storage at power-on or reset.
    ParametersRestored,
    /// Stored parameters could not be used; the defaults are in force.
    StoredParametersRejected(PersistError),
    /// Storing or reading parameters failed in the medium.
    StorageFailed(StorageError),
    /// The restored configuration was validated on another node-ID: it is kept for a tool to
    /// see and change, but it is not valid here (0x13FE reads 0) until it is validated again
    /// for this node-ID (IEC 61784-3 addressing: its identifiers may belong to another node).
    ValidatedForAnotherNodeId {
        /// The node-ID the stored configuration was validated for.
        validated_for: NodeId,
    },
}

/// Why an application call was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ApiError {
    /// This device has no such SRDO, or it is not a transmit SRDO with a valid mapping.
    NotATransmitSrdo,
    /// The data is not as long as the SRDO's mapping.
    WrongLength,
    /// The object access was refused.
    Object(AbortCode),
    /// Only in NMT Operational (a GFC, EN 50325-5 8.2.2; CiA 301 Table 2).
    NotOperational,
}

/// Why a node could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NodeError {
    /// `N` is 0 or more than 64.
    SrdoCount,
    /// The application object table is not valid.
    Table(TableError),
    /// An application object uses an index the node answers itself.
    ReservedIndex(u16),
}

/// Run-time state of one SRDO in Operational.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Role {
    /// Not running.
    Idle,
    /// Producing.
    Producer(Producer),
    /// Consuming.
    Consumer(Consumer),
}

/// One SRDO slot at run time: its resolved mapping, its state machine and a pair counter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct SrdoRuntime {
    mapping: ResolvedMapping,
    role: Role,
    pairs: u32,
}

impl SrdoRuntime {
    const IDLE: SrdoRuntime = SrdoRuntime {
        mapping: ResolvedMapping::EMPTY,
        role: Role::Idle,
        pairs: 0,
    };
}

/// EMCY 6300h detail byte 1 when the stored parameters were unusable at boot (byte 0 is 0:
/// no particular SRDO). Distinct from every [`ConfigError`](crate::safety::config::ConfigError)
/// cause code.
pub const STORED_PARAMETERS_REJECTED: u8 = 0xF0;

/// EMCY 6300h detail byte 1 when the restored configuration was validated on another node-ID
/// (byte 2 is that node-ID). Distinct from every
/// [`ConfigError`](crate::safety::config::ConfigError) cause code.
pub const VALIDATED_FOR_ANOTHER_NODE_ID: u8 = 0xF1;

/// How often a consumer discarded a frame that CAN double reception (ISO 11898-1: a receiver
/// may accept a frame that its transmitter repeats after an error in the last bit of the
/// end-of-frame field) or a start of monitoring between a plain and its inverted frame
/// produces. Counted since power-on or the last NMT reset, over all SRDOs; readable in
/// object [`DOUBLE_RECEPTION_INDEX`]. The counters saturate.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DoubleReception {
    /// Exact repeats of the pending plain frame (same identifier, length and data),
    /// discarded (sub-index 1).
    pub plain_repeated: u32,
    /// Inverted frames with no plain frame pending, discarded (sub-index 2).
    pub inverted_without_plain: u32,
}

/// The manufacturer-specific object (EN 50325-5 leaves 2000h..5FFFh to the manufacturer)
/// that holds [`DoubleReception`]: sub-index 0 = 2, sub-index 1 = repeated plain frames
/// discarded, sub-index 2 = inverted frames without plain frame discarded, each UNSIGNED32,
/// read-only. No application object may use this index.
pub const DOUBLE_RECEPTION_INDEX: u16 = 0x5C00;

/// RAM per SRDO, in bytes: its run-time state with the resolved mapping ([`SrdoRuntime`]) and
/// its configuration record. The identifier table (128 bytes) and the rest of the node are per
/// node, not per SRDO. `cargo xtask bench` reports the figure measured in the thumbv7em image.
pub const RAM_PER_SRDO: usize =
    core::mem::size_of::<SrdoRuntime>() + core::mem::size_of::<crate::safety::config::SrdoRecord>();

// Target: at most 160 bytes per SRDO (the reference C stack needs 676 on Cortex-M4). Checked
// at compile time on every target, so the cross build proves it for thumbv7em.
const _: () = assert!(RAM_PER_SRDO <= 160, "more than 160 bytes of RAM per SRDO");

/// Entry of the identifier table: the slot in the low 7 bits plus one (0: not ours), bit 7 set
/// for the inverted frame, bit 6 set for a transmit SRDO.
const LOOKUP_INVERTED: u8 = 0x80;
const LOOKUP_TRANSMIT: u8 = 0x40;
const LOOKUP_SLOT: u8 = 0x3F;
/// First identifier of the SRDO range ([`SRDO_IDENTIFIERS`](crate::safety::types::SRDO_IDENTIFIERS)).
const SRDO_ID_BASE: u16 = *crate::safety::types::SRDO_IDENTIFIERS.start();
/// Identifiers in the SRDO range (128).
const SRDO_IDS: usize = (*crate::safety::types::SRDO_IDENTIFIERS.end() - SRDO_ID_BASE + 1) as usize;

/// A CANopen Safety device with `N` SRDOs (`1..=64`), storing its parameters in `F`.
pub struct Node<F: Flash, const N: usize> {
    sdo: SdoServer,
    core: Core<F, N>,
}

/// Everything but the SDO server, so that the server can borrow the rest as its object
/// dictionary.
struct Core<F: Flash, const N: usize> {
    config: NodeConfig,
    state: NmtState,
    safety: SafetyConfig<N>,
    image: ProcessImage,
    runtime: [SrdoRuntime; N],
    active: Vec<u8, N>,
    lookup: [u8; SRDO_IDS],
    heartbeat: Heartbeat,
    next_deadline: Instant,
    fault: Option<SafeStateCause>,
    producers_halted: bool,
    gfc_parameter: u8,
    gfc_requested: bool,
    error_register: u8,
    remote_frames_ignored: u32,
    double_reception: DoubleReception,
    deferred_event: Option<Event>,
    integrity: integrity::Integrity,
    access: access::AccessControl<N>,
    /// Bytes 2..=4 of the EMCY's manufacturer-specific field for the next application cause
    /// ([`Node::enter_safe_state_with`]).
    application_data: [u8; 3],
    /// The time of the SDO request being served (the object dictionary has no `now`).
    now: Instant,
    flash: F,
}

impl<F: Flash, const N: usize> Node<F, N> {
    /// A device in NMT Initialising with its parameters restored from `flash` (or the
    /// defaults). The first [`Node::poll`] sends the boot-up message and enters
    /// Pre-operational.
    pub fn new(config: NodeConfig, flash: F) -> Result<Self, NodeError> {
        if N == 0 || N > MAX_SRDOS {
            return Err(NodeError::SrdoCount);
        }
        let image = ProcessImage::new(config.app_objects).map_err(NodeError::Table)?;
        let mut reserved = [DOUBLE_RECEPTION_INDEX].into_iter().chain(access::INDICES);
        if let Some(index) = reserved.find(|&index| image.has_index(index)) {
            return Err(NodeError::ReservedIndex(index));
        }
        let mut core = Core {
            config,
            state: NmtState::Initialising,
            safety: Core::<F, N>::defaults(&config),
            image,
            runtime: [SrdoRuntime::IDLE; N],
            active: Vec::new(),
            lookup: [0; SRDO_IDS],
            heartbeat: Heartbeat::new(0, Instant::ZERO),
            next_deadline: Instant::ZERO,
            fault: None,
            producers_halted: false,
            gfc_parameter: gfc::GFC_NOT_VALID,
            gfc_requested: false,
            error_register: 0,
            remote_frames_ignored: 0,
            double_reception: DoubleReception::default(),
            deferred_event: None,
            integrity: integrity::Integrity::IDLE,
            access: access::AccessControl::new(),
            application_data: [0; 3],
            now: Instant::ZERO,
            flash,
        };
        core.restore_parameters(Instant::ZERO);
        Ok(Node {
            sdo: SdoServer::new(config.sdo_timeout),
            core,
        })
    }

    /// Handles one frame received at `now`.
    #[inline]
    pub fn handle_frame(&mut self, now: Instant, frame: &CanFrame, sink: &mut impl Sink) {
        let id = frame.id().raw();
        if id.wrapping_sub(SRDO_ID_BASE) < SRDO_IDS as u16 {
            self.core.on_srdo_frame(now, frame, sink);
        } else if id == nmt::NMT_ID.raw() {
            match nmt::parse(frame, self.core.config.node_id) {
                Ok(Some(command)) => self.on_nmt(now, command, sink),
                Ok(None) => {}
                Err(error) => sink.event(Event::NmtRefused(error)),
            }
        } else if id == gfc::GFC_ID.raw() {
            self.core.on_gfc(sink);
        } else if id == 0x600 + u16::from(self.core.config.node_id.raw()) {
            self.on_sdo_request(now, frame, sink);
        }
    }

    /// Runs every timer due at `now` and returns the instant of the next poll.
    #[inline]
    pub fn poll(&mut self, now: Instant, sink: &mut impl Sink) -> Instant {
        if now < self.core.next_deadline {
            return self.core.next_deadline;
        }
        self.poll_due(now, sink)
    }

    /// The slow path of [`Node::poll`]: something is (or may be) due.
    #[inline(never)]
    fn poll_due(&mut self, now: Instant, sink: &mut impl Sink) -> Instant {
        if self.core.state == NmtState::Initialising {
            self.core.boot(now, sink);
        }
        if let Some(response) = self.sdo.poll(now) {
            sink.transmit(self.core.sdo_response(response));
        }
        self.core.run_timers(now, sink);
        let mut next = self.core.srdo_deadline(now);
        next = next.min(self.core.heartbeat.deadline());
        if let Some(sdo) = self.sdo.deadline() {
            next = next.min(sdo);
        }
        self.core.next_deadline = next;
        next
    }

    fn on_nmt(&mut self, now: Instant, command: NmtCommand, sink: &mut impl Sink) {
        let core = &mut self.core;
        if command != NmtCommand::EnterPreOperational {
            core.access.lock(); // SC_REQ_43: the unlock ends here.
        }
        match command {
            NmtCommand::Start => {
                if core.state != NmtState::Operational {
                    core.enter_operational(now, sink);
                }
            }
            NmtCommand::Stop => {
                self.sdo.reset();
                core.change_state(NmtState::Stopped, sink);
            }
            NmtCommand::EnterPreOperational => core.change_state(NmtState::PreOperational, sink),
            NmtCommand::ResetNode | NmtCommand::ResetCommunication => {
                self.sdo.reset();
                core.reset(now, command == NmtCommand::ResetNode, sink);
            }
        }
        core.next_deadline = Instant::ZERO;
    }

    fn on_sdo_request(&mut self, now: Instant, frame: &CanFrame, sink: &mut impl Sink) {
        // CiA 301 Table 2 / CiA 304 Table 2: SDO only in Pre-operational and Operational.
        if !matches!(
            self.core.state,
            NmtState::PreOperational | NmtState::Operational
        ) {
            return;
        }
        self.core.now = now;
        if let Some(response) = self.sdo.handle(now, frame.data(), &mut self.core) {
            sink.transmit(self.core.sdo_response(response));
        }
        self.core.flush_pending(sink);
        self.core.next_deadline = Instant::ZERO;
    }

    /// The node-ID.
    pub fn node_id(&self) -> NodeId {
        self.core.config.node_id
    }

    /// The NMT state.
    pub fn nmt_state(&self) -> NmtState {
        self.core.state
    }

    /// `true` in the working state: Operational, configuration validated, no latched fault.
    pub fn is_working(&self) -> bool {
        self.core.state == NmtState::Operational && self.core.fault.is_none()
    }

    /// The cause of the latched safe state, if any.
    pub fn fault(&self) -> Option<SafeStateCause> {
        self.core.fault
    }

    /// Valid pairs received (consumer) or sent (producer) by `srdo` since entering Operational.
    pub fn srdo_pairs(&self, srdo: SrdoNumber) -> u32 {
        self.core
            .runtime
            .get(srdo.index())
            .map_or(0, |runtime| runtime.pairs)
    }

    /// Remote frames ignored on SRDO identifiers since power-on or reset.
    pub fn remote_frames_ignored(&self) -> u32 {
        self.core.remote_frames_ignored
    }

    /// The error register, object 0x1001.
    pub fn error_register(&self) -> u8 {
        self.core.error_register
    }

    /// The safety configuration (objects 0x1301..0x13FF).
    pub fn safety_config(&self) -> &SafetyConfig<N> {
        &self.core.safety
    }

    /// The application objects' values.
    pub fn process_image(&self) -> &ProcessImage {
        &self.core.image
    }

    /// The storage medium (for tests and tools that inspect it).
    pub fn flash(&self) -> &F {
        &self.core.flash
    }

    /// The storage medium, mutably (for tests that inject medium faults).
    pub fn flash_mut(&mut self) -> &mut F {
        &mut self.core.flash
    }

    /// Reads an application object.
    pub fn read_object(&self, address: Address, buf: &mut [u8]) -> Result<usize, AbortCode> {
        self.core.image.read(address, buf)
    }

    /// Writes an application object from the application side (inputs, for example): any
    /// object of the table, read-only ones included, with exactly its length. Marks the
    /// transmit SRDOs that map it as changed.
    pub fn write_object(&mut self, address: Address, data: &[u8]) -> Result<(), AbortCode> {
        let (object, span) = self.core.image.find(address).ok_or(AbortCode::NoObject)?;
        if data.len() != usize::from(object.len) {
            return Err(if data.len() > usize::from(object.len) {
                AbortCode::LengthTooHigh
            } else {
                AbortCode::LengthTooLow
            });
        }
        if self.core.image.get(span) != data {
            self.core.image.set(span, data);
            self.core.mark_changed(span.offset);
        }
        Ok(())
    }

    /// Hands both payloads of transmit SRDO `srdo` at once: `plain` goes to the objects of the
    /// plain entries, `inverted` to those of the inverted entries. Nothing is checked here:
    /// the producer checks that they are exact inverses before every transmission, and sends
    /// nothing (latching the safe state) when they are not.
    pub fn set_transmit_payloads(
        &mut self,
        srdo: SrdoNumber,
        plain: &[u8],
        inverted: &[u8],
    ) -> Result<(), ApiError> {
        self.set_transmit_half(srdo, plain, false)?;
        self.set_transmit_half(srdo, inverted, true)
    }

    /// Hands one half of transmit SRDO `srdo`: the plain payload (`inverted == false`) or the
    /// inverted one. Two channels can each build their half by their own path; both halves
    /// must be handed before the next [`Node::poll`].
    pub fn set_transmit_half(
        &mut self,
        srdo: SrdoNumber,
        data: &[u8],
        inverted: bool,
    ) -> Result<(), ApiError> {
        let mapping = self.core.transmit_mapping(srdo)?;
        if data.len() != usize::from(mapping.len) {
            return Err(ApiError::WrongLength);
        }
        let spans = if inverted {
            &mapping.inverted
        } else {
            &mapping.plain
        };
        let mut at = 0usize;
        for span in spans.iter().take(usize::from(mapping.pairs)) {
            let end = at + usize::from(span.len);
            let part = data.get(at..end).ok_or(ApiError::WrongLength)?;
            if self.core.image.get(*span) != part {
                self.core.image.set(*span, part);
                self.core.mark_changed(span.offset);
            }
            at = end;
        }
        Ok(())
    }

    /// Puts the device in its latched safe state for a fault the application found (EMCY
    /// FF02h with `detail`); producers stop. Cleared only by NMT reset, like every other cause.
    pub fn enter_safe_state(&mut self, detail: u8, sink: &mut impl Sink) {
        self.enter_safe_state_with(detail, [0; 3], sink);
    }

    /// Like [`Node::enter_safe_state`], with what the application names with its cause in
    /// bytes 2..=4 of the EMCY's manufacturer-specific field, after `detail` (a dual-channel
    /// device names the identifier of a frame it did not send, for example).
    pub fn enter_safe_state_with(&mut self, detail: u8, data: [u8; 3], sink: &mut impl Sink) {
        self.core.application_data = data;
        self.core
            .latch(SafeStateCause::Application { detail }, sink);
        self.core.next_deadline = Instant::ZERO;
    }

    /// Requests a GFC (EN 50325-5 6.3), sent at the next poll, which sets 0x1300 to 1.
    /// Refused outside Operational: SRDO and GFC communication is enabled in Operational only
    /// (EN 50325-5 8.2.2), and in Stopped a device sends only NMT error control (CiA 301
    /// Table 2).
    #[must_use = "a refused request sends no GFC"]
    pub fn request_gfc(&mut self) -> Result<(), ApiError> {
        if self.core.state != NmtState::Operational {
            return Err(ApiError::NotOperational);
        }
        self.core.gfc_requested = true;
        self.core.next_deadline = Instant::ZERO;
        Ok(())
    }

    /// The protection of the safety configuration (SC_REQ_43).
    pub fn access(&self) -> &access::AccessControl<N> {
        &self.core.access
    }

    /// Frames the consumers discarded as double receptions, since power-on or reset.
    pub fn double_reception(&self) -> DoubleReception {
        self.core.double_reception
    }

    /// Fault injection for system tests (feature `fault-injection`, which no firmware image
    /// enables): flips bit `bit` (0..=7) of byte `byte` of the identifier table the receive
    /// path looks frames up in, as a memory fault would. Out-of-range positions flip nothing.
    #[cfg(feature = "fault-injection")]
    pub fn inject_identifier_table_flip(&mut self, byte: usize, bit: u8) {
        if let Some(entry) = self.core.lookup.get_mut(byte) {
            *entry ^= 1 << (bit % 8);
        }
    }

    /// Fault injection for system tests (feature `fault-injection`): flips bit `bit` (0..=15)
    /// of the refresh time / SCT field of the record of SRDO `index` (0-based) the node runs,
    /// as a memory fault in the configuration would. Out-of-range positions flip nothing.
    #[cfg(feature = "fault-injection")]
    pub fn inject_record_flip(&mut self, index: usize, bit: u8) {
        if let Some(record) = self.core.safety.srdos.get_mut(index) {
            record.cycle_time ^= 1 << (bit % 16);
        }
    }
}

impl<F: Flash, const N: usize> Core<F, N> {
    /// The pre-defined connection set for this device.
    fn defaults(config: &NodeConfig) -> SafetyConfig<N> {
        SafetyConfig::predefined(
            config.node_id.raw(),
            config.default_transmit_mapping,
            config.default_receive_mapping,
        )
    }

    /// Power-on or reset: boot-up message, then Pre-operational (CiA 301 7.3.2.2.1).
    fn boot(&mut self, now: Instant, sink: &mut impl Sink) {
        let refused = match self.deferred_event {
            Some(Event::StoredParametersRejected(_)) => Some([0, STORED_PARAMETERS_REJECTED, 0]),
            Some(Event::ValidatedForAnotherNodeId { validated_for }) => {
                Some([0, VALIDATED_FOR_ANOTHER_NODE_ID, validated_for.raw()])
            }
            _ => None,
        };
        if let Some(event) = self.deferred_event.take() {
            sink.event(event);
        }
        sink.transmit(heartbeat::frame(
            self.config.node_id,
            NmtState::Initialising,
        ));
        self.heartbeat.set_period(self.heartbeat.period_ms(), now);
        self.change_state(NmtState::PreOperational, sink);
        if let Some([srdo, cause, node_id]) = refused {
            // The stored configuration is unusable (the defaults, not validated, are in
            // force) or not valid for this node-ID: say so on the bus, after the boot-up
            // message (CiA 301 7.2.7).
            self.error_register |= emcy::register::GENERIC | emcy::register::PROFILE;
            self.send_emergency(emcy::code::DATA_SET, [srdo, cause, node_id, 0, 0], sink);
        }
    }

    /// NMT reset node or reset communication: parameters back to their stored (or default)
    /// values, the latched safe state and the error register cleared, then boot again.
    fn reset(&mut self, now: Instant, application_too: bool, sink: &mut impl Sink) {
        self.stop_srdos();
        if application_too {
            self.image.clear_all();
        }
        self.fault = None;
        self.producers_halted = false;
        self.gfc_parameter = gfc::GFC_NOT_VALID;
        self.gfc_requested = false;
        self.error_register = 0;
        self.remote_frames_ignored = 0;
        self.double_reception = DoubleReception::default();
        self.restore_parameters(now);
        self.state = NmtState::Initialising;
        sink.event(Event::NmtState(NmtState::Initialising));
        self.boot(now, sink);
    }

    /// Loads the stored parameters, or the defaults when none are stored or they are unusable.
    fn restore_parameters(&mut self, now: Instant) {
        let mut heartbeat_ms = self.config.heartbeat_ms;
        self.safety = Self::defaults(&self.config);
        let access = &mut self.access; // SC_REQ_43: the secret and the audit record.
        self.deferred_event =
            match persist::load(&mut self.flash, &mut self.safety, &mut heartbeat_ms, access) {
                Ok(Some(stored_by)) if stored_by == self.config.node_id => {
                    Some(Event::ParametersRestored)
                }
                Ok(Some(validated_for)) => {
                    // Validated (if at all) on another node-ID: its identifiers may belong
                    // to another node here (IEC 61784-3 addressing). Kept for the tool, not
                    // valid until validated again for this node-ID (EN 50325-5 6.4.1.6).
                    self.safety.configuration_valid = 0;
                    Some(Event::ValidatedForAnotherNodeId { validated_for })
                }
                Ok(None) => None,
                Err(error) => {
                    self.safety = Self::defaults(&self.config);
                    heartbeat_ms = self.config.heartbeat_ms;
                    Some(Event::StoredParametersRejected(error))
                }
            };
        self.heartbeat = Heartbeat::new(heartbeat_ms, now);
    }

    fn change_state(&mut self, state: NmtState, sink: &mut impl Sink) {
        if self.state == NmtState::Operational && state != NmtState::Operational {
            self.stop_srdos();
        }
        if self.state != state {
            self.state = state;
            sink.event(Event::NmtState(state));
        }
    }

    /// Pre-operational (or Stopped) to Operational: only with a configuration that passes the
    /// check (EN 50325-5 8.3.1, CiA 304 9.5); otherwise the device stays where it is, in the
    /// safe state, sets 0x13FE to 0, and says which SRDO failed and why.
    fn enter_operational(&mut self, now: Instant, sink: &mut impl Sink) {
        self.stop_srdos();
        let node_id = self.config.node_id.raw();
        let Core {
            safety,
            image,
            runtime,
            active,
            lookup,
            ..
        } = self;
        let result = safety.check_for_operational(image, |number, valid| {
            let slot = number.index();
            let (role, transmit) = match valid.direction {
                Direction::Transmit => (
                    Role::Producer(Producer::start(now, node_id)),
                    LOOKUP_TRANSMIT,
                ),
                _ => (Role::Consumer(Consumer::start(now, valid.cycle_time)), 0),
            };
            if let Some(entry) = runtime.get_mut(slot) {
                *entry = SrdoRuntime {
                    mapping: valid.mapping,
                    role,
                    pairs: 0,
                };
            }
            // `slot < N <= 64`, so it fits the table's six bits with the +1.
            let tag = (slot as u8 + 1) | transmit;
            let first = usize::from(valid.cob_ids.first() - SRDO_ID_BASE);
            if let Some(plain) = lookup.get_mut(first) {
                *plain = tag;
            }
            if let Some(inverted) = lookup.get_mut(first + 1) {
                *inverted = tag | LOOKUP_INVERTED;
            }
            let _ = active.push(slot as u8);
        });
        match result {
            Ok(()) => {
                self.start_integrity(now);
                self.change_state(NmtState::Operational, sink);
            }
            Err(fault) => {
                self.stop_srdos();
                // The node has just refused this configuration, so 0x13FE must not go on
                // reading A5h (EN 50325-5 6.4.1.6). In the object dictionary only: the stored
                // record stays as written.
                self.safety.configuration_valid = 0;
                self.error_register |= emcy::register::GENERIC | emcy::register::PROFILE;
                let srdo = fault.srdo.map_or(0, SrdoNumber::get);
                self.send_emergency(
                    emcy::code::DATA_SET,
                    [srdo, fault.error.cause_code(), 0, 0, 0],
                    sink,
                );
                sink.event(Event::ConfigurationRefused(fault));
            }
        }
    }

    /// Stops every SRDO and puts every received value in the safe state.
    fn stop_srdos(&mut self) {
        for runtime in self.runtime.iter_mut() {
            if matches!(runtime.role, Role::Consumer(_)) {
                srdo::clear(&mut self.image, &runtime.mapping);
            }
            *runtime = SrdoRuntime::IDLE;
        }
        self.active.clear();
        self.lookup = [0; SRDO_IDS];
        self.integrity = integrity::Integrity::IDLE;
    }

    /// A frame on an SRDO identifier (the hot path of a consumer).
    #[inline]
    fn on_srdo_frame(&mut self, now: Instant, frame: &CanFrame, sink: &mut impl Sink) {
        if self.state != NmtState::Operational {
            return; // EN 50325-5 8.2.2: SRDOs are disabled outside Operational.
        }
        let offset = usize::from(frame.id().raw().wrapping_sub(SRDO_ID_BASE));
        let tag = self.lookup.get(offset).copied().unwrap_or(0);
        let slot = usize::from(tag & LOOKUP_SLOT);
        if slot == 0 {
            return; // Not an identifier this device uses.
        }
        let number = SrdoNumber::from_index(slot - 1);
        if frame.is_remote() {
            // EN 50325-5 6.2.1: an SRDO is never requested by RTR; counted and ignored.
            self.remote_frames_ignored = self.remote_frames_ignored.saturating_add(1);
            sink.event(Event::RemoteFrameIgnored(number));
            return;
        }
        if tag & LOOKUP_TRANSMIT != 0 || self.fault.is_some() {
            return; // Our own identifiers; or latched: nothing is delivered any more.
        }
        let (Some(runtime), Some(record)) = (
            self.runtime.get_mut(slot - 1),
            self.safety.srdos.get(slot - 1),
        ) else {
            return;
        };
        let Role::Consumer(consumer) = &mut runtime.role else {
            return;
        };
        let len = runtime.mapping.len;
        let result = if tag & LOOKUP_INVERTED == 0 {
            let srvt = Duration::from_millis(u64::from(record.srvt));
            consumer
                .on_plain(now, frame.raw_data(), frame.dlc(), len, srvt)
                .map(|outcome| match outcome {
                    PlainOutcome::Pending => {
                        self.next_deadline = self.next_deadline.min(consumer.deadline());
                        None
                    }
                    PlainOutcome::Discarded(discarded) => Some(discarded),
                })
        } else {
            let sct = Duration::from_millis(u64::from(record.cycle_time));
            consumer
                .on_inverted(now, frame.raw_data(), frame.dlc(), len, sct)
                .map(|outcome| match outcome {
                    InvertedOutcome::Pair { plain, inverted } => {
                        srdo::deliver(&mut self.image, &runtime.mapping, plain, inverted);
                        runtime.pairs = runtime.pairs.wrapping_add(1);
                        sink.event(Event::SrdoReceived {
                            srdo: number,
                            data: plain & srdo::payload_mask(len),
                        });
                        None
                    }
                    InvertedOutcome::Discarded(discarded) => Some(discarded),
                })
        };
        match result {
            Ok(None) => {}
            Ok(Some(discarded)) => self.discarded(number, discarded, sink),
            Err(cause) => self.latch(
                SafeStateCause::Srdo(SrdoFault {
                    srdo: number,
                    cause,
                }),
                sink,
            ),
        }
    }

    /// Counts and reports a frame a consumer discarded as a double reception. Cold: kept out
    /// of the receive hot path.
    #[cold]
    #[inline(never)]
    fn discarded(&mut self, srdo: SrdoNumber, discarded: Discarded, sink: &mut impl Sink) {
        let counter = match discarded {
            Discarded::PlainRepeated => &mut self.double_reception.plain_repeated,
            Discarded::InvertedWithoutPlain => &mut self.double_reception.inverted_without_plain,
        };
        *counter = counter.saturating_add(1);
        sink.event(Event::FrameDiscarded { srdo, discarded });
    }

    /// A frame on CAN-ID 001h. Any frame on the GFC identifier in Operational is obeyed,
    /// whatever its length: in doubt, the safe state (EN 50325-5 7.2.1 specifies no data).
    fn on_gfc(&mut self, sink: &mut impl Sink) {
        if self.state != NmtState::Operational {
            return;
        }
        self.gfc_parameter = gfc::GFC_VALID;
        sink.event(Event::GfcReceived);
        self.latch(SafeStateCause::Gfc, sink);
    }

    /// Enters the latched safe state for `cause` (once), clears every received value, and says
    /// why: an event and an EMCY; a GFC too when configured. Cold: kept out of the receive
    /// hot path.
    #[cold]
    #[inline(never)]
    fn latch(&mut self, cause: SafeStateCause, sink: &mut impl Sink) {
        match cause {
            SafeStateCause::Srdo(fault) => {
                sink.event(Event::SrdoFault(fault));
                if fault.cause == SrdoFaultCause::TransmitHalvesNotInverted {
                    self.producers_halted = true;
                }
            }
            SafeStateCause::Application { .. } | SafeStateCause::Integrity(_) => {
                self.producers_halted = true;
            }
            SafeStateCause::Gfc => {}
        }
        if self.fault.is_some() {
            return;
        }
        self.fault = Some(cause);
        for runtime in self.runtime.iter_mut() {
            if matches!(runtime.role, Role::Consumer(_)) {
                srdo::clear(&mut self.image, &runtime.mapping);
            }
        }
        let (code, detail) = match cause {
            SafeStateCause::Srdo(fault) => (
                fault.cause.emergency_code(),
                [fault.srdo.get(), fault.cause.cause_code(), 0, 0, 0],
            ),
            SafeStateCause::Gfc => (emcy::code::GLOBAL_FAIL_SAFE, [0; 5]),
            SafeStateCause::Application { detail } => {
                let [first, second, third] = self.application_data;
                (
                    emcy::code::APPLICATION_FAULT,
                    [0, detail, first, second, third],
                )
            }
            SafeStateCause::Integrity(fault) => (emcy::code::DATA_SET, fault.emergency_detail()),
        };
        self.error_register |= emcy::register::GENERIC | emcy::register::COMMUNICATION;
        self.send_emergency(code, detail, sink);
        sink.event(Event::SafeState(cause));
        // A GFC only in Operational (EN 50325-5 8.2.2; CiA 301 Table 2).
        if self.config.gfc_on_fault
            && cause != SafeStateCause::Gfc
            && self.state == NmtState::Operational
        {
            self.gfc_requested = true;
            self.next_deadline = Instant::ZERO;
        }
    }

    /// Sends an EMCY, except in Stopped where CiA 301 Table 2 allows no EMCY (the event
    /// that accompanies every EMCY still reports the cause).
    fn send_emergency(&mut self, code: u16, detail: [u8; 5], sink: &mut impl Sink) {
        if self.state == NmtState::Stopped {
            return;
        }
        let emergency = Emergency {
            code,
            register: self.error_register,
            detail,
        };
        sink.transmit(emergency.frame(self.config.node_id));
    }

    /// Heartbeat, GFC requests, and every running SRDO's timers.
    fn run_timers(&mut self, now: Instant, sink: &mut impl Sink) {
        if self.heartbeat.poll(now) {
            sink.transmit(heartbeat::frame(self.config.node_id, self.state));
        }
        if self.state == NmtState::Operational {
            self.run_srdos(now, sink);
            self.poll_integrity(now, sink);
        }
        // Last, so that a fault found by the SRDO timers above sends its GFC in this same
        // poll (EN 50325-5 6.3) rather than at the next one. A request left over from
        // Operational when the node has left it since is dropped: no GFC outside
        // Operational (EN 50325-5 8.2.2; CiA 301 Table 2).
        if self.gfc_requested {
            self.gfc_requested = false;
            if self.state == NmtState::Operational {
                self.gfc_parameter = gfc::GFC_VALID;
                sink.transmit(gfc::frame());
                sink.event(Event::GfcSent);
            }
        }
    }

    /// Every running SRDO's timers (Operational only).
    fn run_srdos(&mut self, now: Instant, sink: &mut impl Sink) {
        for position in 0..self.active.len() {
            let Some(&slot) = self.active.get(position) else {
                break;
            };
            let slot = usize::from(slot);
            let (Some(runtime), Some(record)) =
                (self.runtime.get_mut(slot), self.safety.srdos.get(slot))
            else {
                continue;
            };
            let number = SrdoNumber::from_index(slot);
            let result = match &mut runtime.role {
                Role::Consumer(consumer) if self.fault.is_none() => consumer.check_timers(now),
                Role::Producer(producer) if !self.producers_halted && producer.due(now) => {
                    match srdo::gather(&self.image, &runtime.mapping) {
                        Ok((plain, inverted)) => {
                            let cob_1 = CanId::from_masked(record.cob_id_1 as u16);
                            let cob_2 = CanId::from_masked(record.cob_id_2 as u16);
                            sink.transmit(CanFrame::with_len(
                                cob_1,
                                plain.to_le_bytes(),
                                runtime.mapping.len,
                            ));
                            sink.transmit(CanFrame::with_len(
                                cob_2,
                                inverted.to_le_bytes(),
                                runtime.mapping.len,
                            ));
                            producer.sent(now, Duration::from_millis(u64::from(record.cycle_time)));
                            runtime.pairs = runtime.pairs.wrapping_add(1);
                            Ok(())
                        }
                        Err(cause) => Err(cause),
                    }
                }
                _ => Ok(()),
            };
            if let Err(cause) = result {
                self.latch(
                    SafeStateCause::Srdo(SrdoFault {
                        srdo: number,
                        cause,
                    }),
                    sink,
                );
            }
        }
    }

    /// The earliest deadline of the running SRDOs.
    fn srdo_deadline(&self, now: Instant) -> Instant {
        let mut next = if self.gfc_requested {
            now
        } else {
            Instant::NEVER
        };
        if self.state != NmtState::Operational {
            return next;
        }
        next = next.min(self.integrity.deadline());
        for &slot in &self.active {
            let deadline = match self
                .runtime
                .get(usize::from(slot))
                .map(|runtime| &runtime.role)
            {
                Some(Role::Consumer(consumer)) if self.fault.is_none() => consumer.deadline(),
                Some(Role::Producer(producer)) if !self.producers_halted => producer.deadline(now),
                _ => Instant::NEVER,
            };
            next = next.min(deadline);
        }
        next
    }

    /// Marks every running producer whose mapping includes the byte at `offset` as changed
    /// (event-driven transmission, EN 50325-5 6.2.1).
    fn mark_changed(&mut self, offset: u8) {
        if !self.config.event_driven {
            return;
        }
        for runtime in self.runtime.iter_mut() {
            if let Role::Producer(producer) = &mut runtime.role {
                if runtime.mapping.covers(offset) {
                    producer.mark_changed();
                    self.next_deadline = Instant::ZERO;
                }
            }
        }
    }

    /// The resolved mapping of transmit SRDO `srdo`: the running one in Operational, otherwise
    /// resolved from its (valid) configuration.
    fn transmit_mapping(&self, srdo: SrdoNumber) -> Result<ResolvedMapping, ApiError> {
        let slot = srdo.index();
        if let Some(SrdoRuntime {
            mapping,
            role: Role::Producer(_),
            ..
        }) = self.runtime.get(slot)
        {
            return Ok(*mapping);
        }
        let record = self
            .safety
            .srdos
            .get(slot)
            .ok_or(ApiError::NotATransmitSrdo)?;
        let others = self
            .safety
            .srdos
            .iter()
            .enumerate()
            .filter(|(i, _)| *i != slot)
            .map(|(_, r)| r);
        match crate::safety::config::check_srdo(record, &self.image, others) {
            Ok(valid) if valid.direction == Direction::Transmit => Ok(valid.mapping),
            _ => Err(ApiError::NotATransmitSrdo),
        }
    }

    /// An SDO response frame on 580h + node-ID.
    fn sdo_response(&self, data: [u8; 8]) -> CanFrame {
        CanFrame::with_len(
            CanId::from_masked(0x580 + u16::from(self.config.node_id.raw())),
            data,
            8,
        )
    }

    /// Reports what an SDO access left to say (a storage failure during 0x1010, say).
    fn flush_pending(&mut self, sink: &mut impl Sink) {
        if let Some(event) = self.deferred_event.take() {
            sink.event(event);
        }
    }
}

#[cfg(test)]
mod access_tests;
#[cfg(test)]
mod sdo_tests;
#[cfg(test)]
mod tests;
