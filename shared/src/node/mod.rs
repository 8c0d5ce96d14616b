//! One CANopen Safety device: NMT slave, SDO server, heartbeat, EMCY, GFC and up to `N` SRDOs
//! around a process image, fed frames and time, answering with frames, events and deadlines.
//!
//! The device is a shell ([`Device`]) with a safety protocol in its slot ([`SafetyProtocol`],
//! where the division of work is written down): [`Node`] is the shell with the CANopen Safety
//! SRDO table ([`SrdoTable`]); a second safety protocol implements the same trait beside it.
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
//! [`Device::poll`] returns the instant at which it wants to be polled again. It is never later
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
//!
//! # Node-ID and bit rate by LSS (CiA 305)
//! With the crate's `lss` feature (off by default), a board that lets LSS set the node-ID
//! calls `Device::enable_lss` with its switches before the first poll; the device then
//! answers on 7E5h ([`crate::canopen::lss`], where the safety rules are written down): the
//! switches win where set; otherwise the LSS node-ID stored with the parameters, or none,
//! and an unconfigured device boots no further than NMT Initialising, silent but for LSS. A
//! configured node-ID takes effect at NMT reset communication; the stored safety
//! configuration stays valid only on the node-ID it was validated for. Store configuration
//! writes the LSS settings into the same stored record as the parameters, atomically,
//! leaving the parameters as they were. Without the feature the device has no LSS slave,
//! keeps no LSS state and stores no LSS settings (its stored image is byte for byte the one
//! of a device that never had LSS, and one holding LSS settings is rejected as malformed).
//! The firmware images carry it: both channels enable it (`dual_channel::lss`).

pub mod access;
mod both;
mod dictionary;
mod persist;
pub mod simplecan;
mod slot;
mod srdo_table;

use crate::canopen::emcy::{self, Emergency};
use crate::canopen::heartbeat::{self, Heartbeat};
#[cfg(feature = "lss")]
use crate::canopen::lss::{self, BitRates, Lss, LssEvent, LssSettings, StoreFailure};
use crate::canopen::nmt::{self, NmtCommand, NmtError, NmtState};
use crate::canopen::node_id::NodeId;
use crate::canopen::od::{AbortCode, Address};
use crate::canopen::sdo::SdoServer;
use crate::canopen::storage::{Flash, StorageError};
use crate::frame::{CanFrame, CanId};
use crate::process_image::{AppObject, ProcessImage, TableError};
use crate::safety::config::{ConfigFault, SafetyConfig};
use crate::safety::gfc;
use crate::safety::srdo::{Discarded, SrdoFault};
use crate::safety::types::SrdoNumber;
use crate::time::{Duration, Instant};
#[cfg(feature = "lss")]
use core::ops::ControlFlow;

pub use both::{BothSignatures, SrdoAndSimpleCan, WithSrdoTable};
pub use persist::PersistError;
pub use simplecan::SimpleCan;
pub use slot::{Refused, SafetyProtocol, Slot};
pub use srdo_table::{
    DOUBLE_RECEPTION_INDEX, DoubleReception, INTEGRITY_IDLE_PERIOD, IntegrityFault, RAM_PER_SRDO,
    SrdoTable,
};

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
    /// Withdraws every frame on `id` handed over and not yet on the bus (aborts the transmit
    /// mailbox, clears the queue entry). A protocol that bounds when its frames may be on the
    /// bus asks for it: SimpleCAN at the end of a producer's slot and for a sync not confirmed
    /// within 2 ms (`docs/simplecan.md` section 5; SC_REQ_18, SC_REQ_23). A sink that carries
    /// SimpleCAN must implement it; the default does nothing, which is right only for a sink
    /// whose protocols never withdraw a frame (CANopen Safety: the SRDO table never does).
    fn abort(&mut self, id: CanId) {
        let _ = id;
    }
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
    /// A fault the safety protocol in the slot found that the causes above do not name,
    /// reported in the EMCY it gives: error code `code` with `named` in byte 0 and `cause` in
    /// byte 1 of the manufacturer-specific field, as an SRDO's EMCY names the SRDO and its
    /// cause. Small on purpose: the cause travels by value through every event and latch.
    Protocol {
        /// The EMCY error code (CiA 301 Table 21, or the protocol's profile).
        code: u16,
        /// The protocol's cause code (EMCY manufacturer-specific byte 1).
        cause: u8,
        /// What the fault concerns, in the protocol's numbering (EMCY manufacturer-specific
        /// byte 0; SimpleCAN: the CAN identifier of the packet, its SC-ID or 2Fh for a sync);
        /// 0: nothing in particular.
        named: u8,
    },
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
    /// A safety protocol other than the SRDO table refused its configuration at the
    /// Operational entry (SimpleCAN: SC_REQ_16, SC_REQ_34); the device stays in its NMT state
    /// and in the safe state. `cause` is a code of the cause table
    /// ([`crate::safety::cause::Cause`]), `detail` what it names (a SimpleCAN SDD entry, 1-based,
    /// or 0).
    ProtocolConfigurationRefused {
        /// The cause code.
        cause: u8,
        /// The entry it names, or 0.
        detail: u8,
    },
    /// A consumer discarded a frame as a CAN double reception (or an inverted frame seen
    /// first after monitoring started), or, before its first pair since entering Operational,
    /// a half of a pair a producer's NMT reset cut; nothing was delivered and nothing failed.
    /// Double receptions are counted in [`SrdoTable::double_reception`].
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
    /// Something LSS did or refused (CiA 305; [`Device::enable_lss`]).
    #[cfg(feature = "lss")]
    Lss(LssEvent),
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

/// EMCY 6300h detail byte 1 when the stored parameters were unusable at boot (byte 0 is 0:
/// no particular SRDO). Distinct from every [`ConfigError`](crate::safety::config::ConfigError)
/// cause code.
pub const STORED_PARAMETERS_REJECTED: u8 = 0xF0;

/// EMCY 6300h detail byte 1 when the restored configuration was validated on another node-ID
/// (byte 2 is that node-ID). Distinct from every
/// [`ConfigError`](crate::safety::config::ConfigError) cause code.
pub const VALIDATED_FOR_ANOTHER_NODE_ID: u8 = 0xF1;

/// A CANopen Safety device with `N` SRDOs (`1..=64`), storing its parameters in `F`: the
/// device shell with the SRDO table in its protocol slot.
pub type Node<F, const N: usize> = Device<F, SrdoTable<N>>;

/// A device with `N` SRDOs (`2..=32`) and SimpleCAN with `E` SDD entries beside them, storing
/// its parameters in `F`: CANopen Safety as [`Node`], and SimpleCAN once configured
/// (5E00h:04 = 1; `docs/simplecan.md` section 11).
pub type SimpleCanNode<F, const N: usize, const E: usize> = Device<F, SrdoAndSimpleCan<N, E>>;

impl<F: Flash, const N: usize, const E: usize> SimpleCanNode<F, N, E> {
    /// A device with `N` SRDOs and SimpleCAN (disabled until configured) in NMT Initialising
    /// with its parameters restored from `flash` (or the defaults).
    pub fn new(config: NodeConfig, flash: F) -> Result<Self, NodeError> {
        let both = SrdoAndSimpleCan::new(&config).ok_or(NodeError::SrdoCount)?;
        Device::with_protocol(config, flash, both)
    }
}

/// One device: the shell (NMT, SDO server, heartbeat, EMCY, GFC, storage, safe-state latch)
/// around a process image, with the safety protocol `P` in its slot ([`SafetyProtocol`]),
/// storing its parameters in `F`.
#[derive(Clone)]
pub struct Device<F: Flash, P: SafetyProtocol> {
    sdo: SdoServer,
    core: Core<F, P>,
}

/// Everything but the SDO server, so that the server can borrow the rest as its object
/// dictionary.
#[derive(Clone)]
struct Core<F: Flash, P: SafetyProtocol> {
    shell: Shell,
    protocol: P,
    image: ProcessImage,
    heartbeat: Heartbeat,
    gfc_parameter: u8,
    deferred_event: Option<Event>,
    access: access::AccessControl<P::Signatures>,
    /// The time of the SDO request being served (the object dictionary has no `now`).
    now: Instant,
    flash: F,
    /// The LSS slave, when the board enabled it ([`Device::enable_lss`]).
    #[cfg(feature = "lss")]
    lss: Option<Lss>,
    /// The LSS settings in the stored image (kept by 0x1010 and 0x1011).
    #[cfg(feature = "lss")]
    stored_lss: Option<LssSettings>,
    /// What LSS has to say at the next poll (the node-ID's source and an unsupported stored
    /// bit rate, at start and reset).
    #[cfg(feature = "lss")]
    lss_events: [Option<LssEvent>; 2],
}

/// The part of the shell a protocol reaches through its [`Slot`]: NMT state, the latch and
/// what it sends, the next deadline.
#[derive(Clone)]
struct Shell {
    config: NodeConfig,
    state: NmtState,
    next_deadline: Instant,
    fault: Option<SafeStateCause>,
    gfc_requested: bool,
    error_register: u8,
    /// Bytes 2..=4 of the EMCY's manufacturer-specific field for the next application cause
    /// ([`Device::enter_safe_state_with`]).
    application_data: [u8; 3],
}

impl<F: Flash, const N: usize> Node<F, N> {
    /// A device with `N` SRDOs in NMT Initialising with its parameters restored from `flash`
    /// (or the defaults). The first [`Device::poll`] sends the boot-up message and enters
    /// Pre-operational.
    pub fn new(config: NodeConfig, flash: F) -> Result<Self, NodeError> {
        let table = SrdoTable::new(&config).ok_or(NodeError::SrdoCount)?;
        Device::with_protocol(config, flash, table)
    }
}

/// The SRDO-specific part of every device whose slot holds an SRDO table ([`Node`],
/// [`SimpleCanNode`]).
impl<F: Flash, P, const N: usize> Device<F, P>
where
    P: SafetyProtocol + WithSrdoTable<Table = SrdoTable<N>>,
{
    /// Valid pairs received (consumer) or sent (producer) by `srdo` since entering Operational.
    pub fn srdo_pairs(&self, srdo: SrdoNumber) -> u32 {
        self.core.protocol.srdo_table().pairs(srdo)
    }

    /// Remote frames ignored on SRDO identifiers since power-on or reset.
    pub fn remote_frames_ignored(&self) -> u32 {
        self.core.protocol.srdo_table().remote_frames_ignored()
    }

    /// The safety configuration (objects 0x1301..0x13FF).
    pub fn safety_config(&self) -> &SafetyConfig<N> {
        self.core.protocol.srdo_table().config()
    }

    /// Frames the consumers discarded as double receptions, since power-on or reset.
    pub fn double_reception(&self) -> DoubleReception {
        self.core.protocol.srdo_table().double_reception()
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
    /// must be handed before the next [`Device::poll`].
    pub fn set_transmit_half(
        &mut self,
        srdo: SrdoNumber,
        data: &[u8],
        inverted: bool,
    ) -> Result<(), ApiError> {
        let mapping = self
            .core
            .protocol
            .srdo_table()
            .transmit_mapping(srdo, &self.core.image)?;
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
                self.core.changed(span.offset);
            }
            at = end;
        }
        Ok(())
    }

    /// Fault injection for system tests (feature `fault-injection`, which no firmware image
    /// enables): flips bit `bit` (0..=7) of byte `byte` of the identifier table the receive
    /// path looks frames up in, as a memory fault would. Out-of-range positions flip nothing.
    #[cfg(feature = "fault-injection")]
    pub fn inject_identifier_table_flip(&mut self, byte: usize, bit: u8) {
        if let Some(entry) = self.core.protocol.srdo_table_mut().lookup.get_mut(byte) {
            *entry ^= 1 << (bit % 8);
        }
    }

    /// Fault injection for system tests (feature `fault-injection`): flips bit `bit` (0..=15)
    /// of the refresh time / SCT field of the record of SRDO `index` (0-based) the node runs,
    /// as a memory fault in the configuration would. Out-of-range positions flip nothing.
    #[cfg(feature = "fault-injection")]
    pub fn inject_record_flip(&mut self, index: usize, bit: u8) {
        if let Some(record) = self
            .core
            .protocol
            .srdo_table_mut()
            .safety
            .srdos
            .get_mut(index)
        {
            record.cycle_time ^= 1 << (bit % 16);
        }
    }
}

impl<F: Flash, P: SafetyProtocol> Device<F, P> {
    /// A device running `protocol` in NMT Initialising with its parameters restored from
    /// `flash` (or the defaults). The first [`Device::poll`] sends the boot-up message and
    /// enters Pre-operational.
    pub fn with_protocol(config: NodeConfig, flash: F, protocol: P) -> Result<Self, NodeError> {
        let mut device = Self::prepare(config, flash, protocol)?;
        device.restore_parameters();
        Ok(device)
    }

    /// The first step of [`Device::with_protocol`]: the device checked and built, in NMT
    /// Initialising, with the protocol's defaults in force and nothing read from `flash`
    /// yet; [`Device::restore_parameters`] is the second step.
    ///
    /// Two steps so that a caller that keeps a large device where it is built (a firmware
    /// image's task state) restores it there through `&mut`, instead of taking it out of a
    /// function that did both: every such move is a copy of the device on the stack
    /// (`docs/footprint.md`). A device polled without the second step boots with the
    /// defaults, which are not validated, so it stays out of Operational (EN 50325-5 8.3.1).
    pub fn prepare(config: NodeConfig, flash: F, protocol: P) -> Result<Self, NodeError> {
        let image = ProcessImage::new(config.app_objects).map_err(NodeError::Table)?;
        if let Some(index) = config
            .app_objects
            .iter()
            .map(|object| object.address.index)
            .find(|&index| protocol.owns(index) || access::INDICES.contains(&index))
        {
            return Err(NodeError::ReservedIndex(index));
        }
        Ok(Device {
            sdo: SdoServer::new(config.sdo_timeout),
            core: Core {
                shell: Shell {
                    config,
                    state: NmtState::Initialising,
                    next_deadline: Instant::ZERO,
                    fault: None,
                    gfc_requested: false,
                    error_register: 0,
                    application_data: [0; 3],
                },
                protocol,
                image,
                heartbeat: Heartbeat::new(0, Instant::ZERO),
                gfc_parameter: gfc::GFC_NOT_VALID,
                deferred_event: None,
                access: access::AccessControl::new(P::NO_SIGNATURES),
                now: Instant::ZERO,
                flash,
                #[cfg(feature = "lss")]
                lss: None,
                #[cfg(feature = "lss")]
                stored_lss: None,
                #[cfg(feature = "lss")]
                lss_events: [None, None],
            },
        })
    }

    /// The second step of [`Device::with_protocol`]: the stored parameters loaded into a
    /// prepared device, in place (or the defaults when none are stored or they are
    /// unusable); the same path as an NMT reset's. Only before the first [`Device::poll`]
    /// (in NMT Initialising): later it does nothing, as the device's parameters change only
    /// by SDO and NMT reset.
    pub fn restore_parameters(&mut self) {
        if self.core.shell.state == NmtState::Initialising {
            self.core.restore_parameters(Instant::ZERO);
        }
    }

    /// Enables the LSS slave (CiA 305, [`crate::canopen::lss`]) after
    /// [`Device::restore_parameters`] and before the first [`Device::poll`]: `switches` is
    /// the node-ID the board's switches set (`None`: all open, "use LSS"), `supported` the bit
    /// rates the board can switch to. The node-ID in force becomes the switches', else the
    /// LSS node-ID stored with the parameters (which are restored again for it), else none:
    /// the device is unconfigured and stays in NMT Initialising, silent but for LSS, until a
    /// master gives it a node-ID. `false` (and nothing changes) after the first poll or when
    /// LSS is enabled already.
    #[cfg(feature = "lss")]
    #[must_use = "`false` means LSS was not enabled"]
    pub fn enable_lss(&mut self, switches: Option<NodeId>, supported: BitRates) -> bool {
        let core = &mut self.core;
        // A device without LSS leaves Initialising at its first poll.
        if core.shell.state != NmtState::Initialising || core.lss.is_some() {
            return false;
        }
        let lss = Lss::new(
            core.shell.config.identity,
            switches,
            core.stored_lss,
            supported,
        );
        core.lss_events = lss.start_events();
        if let Some(id) = lss.active() {
            if id != core.shell.config.node_id {
                core.shell.config.node_id = id;
                core.restore_parameters(Instant::ZERO);
            }
        }
        core.lss = Some(lss);
        true
    }

    /// The LSS slave, when enabled ([`Device::enable_lss`]): the bit rate LSS stored for the
    /// board to start its CAN controller on, where the node-ID comes from.
    #[cfg(feature = "lss")]
    pub fn lss(&self) -> Option<&Lss> {
        self.core.lss.as_ref()
    }

    /// The node-ID in force; `None` when LSS is enabled and the device has none
    /// (unconfigured, node-ID FFh).
    #[cfg(feature = "lss")]
    pub fn configured_node_id(&self) -> Option<NodeId> {
        match &self.core.lss {
            Some(lss) => lss.active(),
            None => Some(self.core.shell.config.node_id),
        }
    }

    /// Handles one frame received at `now`: the protocol's own, or NMT, GFC or SDO.
    #[inline]
    pub fn handle_frame(&mut self, now: Instant, frame: &CanFrame, sink: &mut impl Sink) {
        let Core {
            shell,
            protocol,
            image,
            ..
        } = &mut self.core;
        if protocol.on_frame(now, frame, &mut Slot { shell, image, sink }) {
            return;
        }
        self.on_service_frame(now, frame, sink);
    }

    /// A frame the protocol did not take: NMT, GFC, SDO or LSS. Out of line, so that the
    /// protocol's receive path does not pay for the registers these services use.
    #[inline(never)]
    fn on_service_frame(&mut self, now: Instant, frame: &CanFrame, sink: &mut impl Sink) {
        let id = frame.id().raw();
        #[cfg(feature = "lss")]
        if self.core.lss_holds_back(now) && id != lss::MASTER_TO_SLAVE.raw() {
            // Unconfigured, or silent for a bit-rate switch: only LSS is served.
            return;
        }
        if id == nmt::NMT_ID.raw() {
            match nmt::parse(frame, self.core.shell.config.node_id) {
                Ok(Some(command)) => self.on_nmt(now, command, sink),
                Ok(None) => {}
                Err(error) => sink.event(Event::NmtRefused(error)),
            }
        } else if id == gfc::GFC_ID.raw() {
            self.core.on_gfc(sink);
        } else if id == 0x600 + u16::from(self.core.shell.config.node_id.raw()) {
            self.on_sdo_request(now, frame, sink);
        }
        #[cfg(feature = "lss")]
        if id == lss::MASTER_TO_SLAVE.raw() {
            self.on_lss(now, frame, sink);
        }
    }

    /// A frame on 7E5h: the LSS slave's, when enabled (CiA 305).
    #[cfg(feature = "lss")]
    fn on_lss(&mut self, now: Instant, frame: &CanFrame, sink: &mut impl Sink) {
        let Core {
            shell,
            access,
            flash,
            lss,
            stored_lss,
            ..
        } = &mut self.core;
        let Some(lss) = lss.as_mut() else {
            return;
        };
        let operational = shell.state == NmtState::Operational;
        let node_id = shell.config.node_id;
        let outcome = lss.on_frame(now, frame, operational, |settings| {
            persist::store_lss::<F, P>(flash, node_id, access.persisted(), settings)
                .map_err(StoreFailure::Failed)
        });
        if let Some(LssEvent::Stored(settings)) = outcome.event {
            *stored_lss = Some(settings);
        }
        if let Some(response) = outcome.response {
            sink.transmit(response);
        }
        if let Some(event) = outcome.event {
            sink.event(Event::Lss(event));
        }
        if outcome.reset_communication {
            // As an NMT reset communication would (SC_REQ_43: an unlock ends at a reset).
            self.core.access.lock();
            self.sdo.reset();
            self.core.reset(now, false, sink);
        }
        self.core.shell.next_deadline = Instant::ZERO;
    }

    /// The controller reports that `frame`, handed to the sink before, went out on the bus
    /// at `now` (a transmit mailbox completed): the protocol's confirmation (SimpleCAN: a
    /// sync confirmed, SC_REQ_23; a data packet sent within its slot, SC_REQ_18).
    pub fn on_transmitted(&mut self, now: Instant, frame: &CanFrame, sink: &mut impl Sink) {
        let Core {
            shell,
            protocol,
            image,
            ..
        } = &mut self.core;
        protocol.on_transmitted(now, frame, &mut Slot { shell, image, sink });
    }

    /// The other channel of a dual-channel device put `frame` on the bus, heard at `heard` (at
    /// or before `now`: the other channel's frame can come off the bus before this channel
    /// computed its own), standing for a frame this device handed to the sink (Model A,
    /// SC_REQ_10: this channel computes the node's packets, the other transmits them): a
    /// confirmation as [`Device::on_transmitted`]'s at `now`, and SimpleCAN's master takes
    /// the time of a sync from it.
    pub fn on_partner_transmitted(
        &mut self,
        now: Instant,
        heard: Instant,
        frame: &CanFrame,
        sink: &mut impl Sink,
    ) {
        let Core {
            shell,
            protocol,
            image,
            ..
        } = &mut self.core;
        protocol.on_partner_transmitted(now, heard, frame, &mut Slot { shell, image, sink });
    }

    /// Runs every timer due at `now` and returns the instant of the next poll.
    ///
    /// Out of line in the firmware images: `cargo xtask bench --target-cost` counts the
    /// core's poll by this function's entry and exit on the real image
    /// (docs/performance.md), which LLVM's inlining threshold of 45 would otherwise fold into
    /// the channel loop.
    #[cfg_attr(not(target_os = "none"), inline)]
    #[cfg_attr(target_os = "none", inline(never))]
    pub fn poll(&mut self, now: Instant, sink: &mut impl Sink) -> Instant {
        if now < self.core.shell.next_deadline {
            return self.core.shell.next_deadline;
        }
        self.poll_due(now, sink)
    }

    /// The slow path of [`Device::poll`]: something is (or may be) due.
    #[inline(never)]
    fn poll_due(&mut self, now: Instant, sink: &mut impl Sink) -> Instant {
        #[cfg(feature = "lss")]
        let lss_deadline = match self.core.poll_lss(now, sink) {
            ControlFlow::Continue(deadline) => deadline,
            ControlFlow::Break(deadline) => return deadline,
        };
        if self.core.shell.state == NmtState::Initialising {
            self.core.boot(now, sink);
        }
        if let Some(response) = self.sdo.poll(now) {
            sink.transmit(self.core.sdo_response(response));
        }
        self.core.run_timers(now, sink);
        let mut next = self.core.protocol_deadline(now);
        #[cfg(feature = "lss")]
        {
            next = next.min(lss_deadline);
        }
        next = next.min(self.core.heartbeat.deadline());
        if let Some(sdo) = self.sdo.deadline() {
            next = next.min(sdo);
        }
        self.core.shell.next_deadline = next;
        next
    }

    fn on_nmt(&mut self, now: Instant, command: NmtCommand, sink: &mut impl Sink) {
        let core = &mut self.core;
        if command != NmtCommand::EnterPreOperational {
            core.access.lock(); // SC_REQ_43: the unlock ends here.
        }
        match command {
            NmtCommand::Start => {
                if core.shell.state != NmtState::Operational {
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
        core.shell.next_deadline = Instant::ZERO;
    }

    fn on_sdo_request(&mut self, now: Instant, frame: &CanFrame, sink: &mut impl Sink) {
        // CiA 301 Table 2 / CiA 304 Table 2: SDO only in Pre-operational and Operational.
        if !matches!(
            self.core.shell.state,
            NmtState::PreOperational | NmtState::Operational
        ) {
            return;
        }
        self.core.now = now;
        if let Some(response) = self.sdo.handle(now, frame.data(), &mut self.core) {
            sink.transmit(self.core.sdo_response(response));
        }
        self.core.flush_pending(sink);
        self.core.shell.next_deadline = Instant::ZERO;
    }

    /// The node-ID. With LSS enabled and no node-ID, the one the device was built with, which
    /// it does not use: `Device::configured_node_id` (with the `lss` feature) says `None` then.
    pub fn node_id(&self) -> NodeId {
        self.core.shell.config.node_id
    }

    /// The NMT state.
    pub fn nmt_state(&self) -> NmtState {
        self.core.shell.state
    }

    /// `true` in the working state: Operational, configuration validated, no latched fault.
    pub fn is_working(&self) -> bool {
        self.core.shell.state == NmtState::Operational && self.core.shell.fault.is_none()
    }

    /// The cause of the latched safe state, if any.
    pub fn fault(&self) -> Option<SafeStateCause> {
        self.core.shell.fault
    }

    /// The error register, object 0x1001.
    pub fn error_register(&self) -> u8 {
        self.core.shell.error_register
    }

    /// The safety protocol in the slot.
    pub fn protocol(&self) -> &P {
        &self.core.protocol
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
    /// object of the table, read-only ones included, with exactly its length. Tells the
    /// protocol (a transmit SRDO that maps it is due at once when event-driven).
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
            self.core.changed(span.offset);
        }
        Ok(())
    }

    /// Puts the device in its latched safe state for a fault the application found (EMCY
    /// FF02h with `detail`); producers stop. Cleared only by NMT reset, like every other cause.
    pub fn enter_safe_state(&mut self, detail: u8, sink: &mut impl Sink) {
        self.enter_safe_state_with(detail, [0; 3], sink);
    }

    /// Like [`Device::enter_safe_state`], with what the application names with its cause in
    /// bytes 2..=4 of the EMCY's manufacturer-specific field, after `detail` (a dual-channel
    /// device names the identifier of a frame it did not send, for example).
    pub fn enter_safe_state_with(&mut self, detail: u8, data: [u8; 3], sink: &mut impl Sink) {
        self.core.shell.application_data = data;
        self.core
            .latch(SafeStateCause::Application { detail }, sink);
        self.core.shell.next_deadline = Instant::ZERO;
    }

    /// Requests a GFC (EN 50325-5 6.3), sent at the next poll, which sets 0x1300 to 1.
    /// Refused outside Operational: SRDO and GFC communication is enabled in Operational only
    /// (EN 50325-5 8.2.2), and in Stopped a device sends only NMT error control (CiA 301
    /// Table 2).
    #[must_use = "a refused request sends no GFC"]
    pub fn request_gfc(&mut self) -> Result<(), ApiError> {
        if self.core.shell.state != NmtState::Operational {
            return Err(ApiError::NotOperational);
        }
        self.core.shell.gfc_requested = true;
        self.core.shell.next_deadline = Instant::ZERO;
        Ok(())
    }

    /// The protection of the safety configuration (SC_REQ_43).
    pub fn access(&self) -> &access::AccessControl<P::Signatures> {
        &self.core.access
    }
}

impl<F: Flash, P: SafetyProtocol> Core<F, P> {
    /// Power-on or reset: boot-up message, then Pre-operational (CiA 301 7.3.2.2.1). Cold:
    /// kept out of the poll's hot path.
    #[cold]
    #[inline(never)]
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
            self.shell.config.node_id,
            NmtState::Initialising,
        ));
        self.heartbeat.set_period(self.heartbeat.period_ms(), now);
        self.change_state(NmtState::PreOperational, sink);
        if let Some([srdo, cause, node_id]) = refused {
            // The stored configuration is unusable (the defaults, not validated, are in
            // force) or not valid for this node-ID: say so on the bus, after the boot-up
            // message (CiA 301 7.2.7).
            self.shell.error_register |= emcy::register::GENERIC | emcy::register::PROFILE;
            self.shell
                .send_emergency(emcy::code::DATA_SET, [srdo, cause, node_id, 0, 0], sink);
        }
    }

    /// NMT reset node or reset communication: parameters back to their stored (or default)
    /// values, the latched safe state and the error register cleared, then boot again.
    fn reset(&mut self, now: Instant, application_too: bool, sink: &mut impl Sink) {
        self.protocol.stop(&mut self.image);
        if application_too {
            self.image.clear_all();
        }
        self.shell.fault = None;
        self.protocol.reset();
        self.gfc_parameter = gfc::GFC_NOT_VALID;
        self.shell.gfc_requested = false;
        self.shell.error_register = 0;
        #[cfg(feature = "lss")]
        if let Some(lss) = self.lss.as_mut() {
            // CiA 305: the pending node-ID comes into force (the switches' where set).
            if let Some(id) = lss.reset_communication() {
                self.shell.config.node_id = id;
            }
            self.lss_events = lss.start_events();
        }
        self.restore_parameters(now);
        self.shell.state = NmtState::Initialising;
        sink.event(Event::NmtState(NmtState::Initialising));
        #[cfg(feature = "lss")]
        if self.unconfigured() {
            // No node-ID: no boot-up message; LSS waits for a master (CiA 305).
            self.shell.next_deadline = Instant::ZERO;
            return;
        }
        self.boot(now, sink);
    }

    /// The LSS part of [`Device::poll`], before anything else of it: the LSS slave's events
    /// and deadline; `Break` with the deadline when nothing else is due (the device is
    /// unconfigured, or silent for a bit-rate switch), `Continue` with it otherwise.
    #[cfg(feature = "lss")]
    fn poll_lss(&mut self, now: Instant, sink: &mut impl Sink) -> ControlFlow<Instant, Instant> {
        let Some(lss) = self.lss.as_mut() else {
            return ControlFlow::Continue(Instant::NEVER);
        };
        if let Some(event) = lss.poll(now) {
            sink.event(Event::Lss(event));
        }
        let deadline = lss.deadline();
        for event in self.lss_events.iter_mut().filter_map(Option::take) {
            sink.event(Event::Lss(event));
        }
        if !self.lss_holds_back(now) {
            return ControlFlow::Continue(deadline);
        }
        // Unconfigured (it says why it cannot start: stored parameters rejected, say) or
        // silent for a bit-rate switch: no boot-up, no timer, nothing sent.
        if self.unconfigured() {
            self.flush_pending(sink);
        }
        self.shell.next_deadline = deadline;
        ControlFlow::Break(deadline)
    }

    /// `true` when LSS is enabled and the device has no node-ID (FFh).
    #[cfg(feature = "lss")]
    fn unconfigured(&self) -> bool {
        self.lss.as_ref().is_some_and(|lss| lss.active().is_none())
    }

    /// `true` when only LSS is served: the device is unconfigured, or silent for a bit-rate
    /// switch (CiA 305 Fig. 35).
    #[cfg(feature = "lss")]
    fn lss_holds_back(&self, now: Instant) -> bool {
        self.lss
            .as_ref()
            .is_some_and(|lss| lss.active().is_none() || lss.muted(now))
    }

    /// Loads the stored parameters, or the defaults when none are stored or they are unusable.
    fn restore_parameters(&mut self, now: Instant) {
        let mut heartbeat_ms = self.shell.config.heartbeat_ms;
        self.protocol.load_defaults(&self.shell.config);
        // With the access control's stored part (SC_REQ_43: the secret, the audit record).
        self.deferred_event = match persist::load(
            &mut self.flash,
            &mut self.protocol,
            &mut heartbeat_ms,
            &mut self.access,
            #[cfg(feature = "lss")]
            &mut self.stored_lss,
        ) {
            Ok(Some(stored_by)) if stored_by == self.shell.config.node_id => {
                Some(Event::ParametersRestored)
            }
            Ok(Some(validated_for)) => {
                // Validated (if at all) on another node-ID: its identifiers may belong
                // to another node here (IEC 61784-3 addressing). Kept for the tool, not
                // valid until validated again for this node-ID (EN 50325-5 6.4.1.6).
                self.protocol.withdraw_validation();
                Some(Event::ValidatedForAnotherNodeId { validated_for })
            }
            Ok(None) => None,
            Err(error) => {
                self.protocol.load_defaults(&self.shell.config);
                heartbeat_ms = self.shell.config.heartbeat_ms;
                Some(Event::StoredParametersRejected(error))
            }
        };
        self.heartbeat = Heartbeat::new(heartbeat_ms, now);
    }

    fn change_state(&mut self, state: NmtState, sink: &mut impl Sink) {
        if self.shell.state == NmtState::Operational && state != NmtState::Operational {
            self.protocol.stop(&mut self.image);
        }
        if self.shell.state != state {
            self.shell.state = state;
            sink.event(Event::NmtState(state));
        }
        #[cfg(feature = "lss")]
        if state == NmtState::Operational {
            // LSS safety rule 1: no configuration state in Operational.
            if let Some(event) = self.lss.as_mut().and_then(Lss::leave_configuration) {
                sink.event(Event::Lss(event));
            }
        }
    }

    /// Pre-operational (or Stopped) to Operational: only with a configuration the protocol
    /// accepts (EN 50325-5 8.3.1, CiA 304 9.5); otherwise the device stays where it is, in the
    /// safe state, and the protocol has said why.
    fn enter_operational(&mut self, now: Instant, sink: &mut impl Sink) {
        self.protocol.stop(&mut self.image);
        let Core {
            shell,
            protocol,
            image,
            ..
        } = self;
        if protocol
            .start(now, &mut Slot { shell, image, sink })
            .is_ok()
        {
            self.change_state(NmtState::Operational, sink);
        }
    }

    /// A frame on CAN-ID 001h. Any frame on the GFC identifier in Operational is obeyed,
    /// whatever its length: in doubt, the safe state (EN 50325-5 7.2.1 specifies no data).
    fn on_gfc(&mut self, sink: &mut impl Sink) {
        if self.shell.state != NmtState::Operational {
            return;
        }
        self.gfc_parameter = gfc::GFC_VALID;
        sink.event(Event::GfcReceived);
        self.latch(SafeStateCause::Gfc, sink);
    }

    /// Enters the latched safe state for a cause the shell found: the protocol puts what it
    /// received in the safe state first, then the shell latches.
    fn latch(&mut self, cause: SafeStateCause, sink: &mut impl Sink) {
        let already_latched = self.shell.fault.is_some();
        self.protocol
            .enter_safe_state(&mut self.image, cause, already_latched);
        self.shell.latch(cause, sink);
        // Polled at once: a protocol withdraws there what it had queued (SimpleCAN,
        // SC_REQ_40), which `enter_safe_state` has no sink for.
        self.shell.next_deadline = Instant::ZERO;
    }

    /// Heartbeat, GFC requests, and the protocol's timers.
    fn run_timers(&mut self, now: Instant, sink: &mut impl Sink) {
        if self.heartbeat.poll(now) {
            sink.transmit(heartbeat::frame(
                self.shell.config.node_id,
                self.shell.state,
            ));
        }
        if self.shell.state == NmtState::Operational {
            let Core {
                shell,
                protocol,
                image,
                ..
            } = self;
            protocol.poll(now, &mut Slot { shell, image, sink });
        }
        // Last, so that a fault found by the protocol's timers above sends its GFC in this
        // same poll (EN 50325-5 6.3) rather than at the next one. A request left over from
        // Operational when the node has left it since is dropped: no GFC outside
        // Operational (EN 50325-5 8.2.2; CiA 301 Table 2).
        if self.shell.gfc_requested {
            self.send_requested_gfc(sink);
        }
    }

    /// The GFC requested since the last poll, in Operational only. Cold: kept out of the
    /// poll's hot path.
    #[cold]
    #[inline(never)]
    fn send_requested_gfc(&mut self, sink: &mut impl Sink) {
        self.shell.gfc_requested = false;
        if self.shell.state == NmtState::Operational {
            self.gfc_parameter = gfc::GFC_VALID;
            sink.transmit(gfc::frame());
            sink.event(Event::GfcSent);
        }
    }

    /// The earliest deadline of a GFC request and, in Operational, of the protocol.
    fn protocol_deadline(&self, now: Instant) -> Instant {
        let next = if self.shell.gfc_requested {
            now
        } else {
            Instant::NEVER
        };
        if self.shell.state != NmtState::Operational {
            return next;
        }
        next.min(self.protocol.deadline(now, self.shell.fault.is_some()))
    }

    /// The application changed the process image byte at `offset`.
    fn changed(&mut self, offset: u8) {
        if self.protocol.object_changed(offset) {
            self.shell.next_deadline = Instant::ZERO;
        }
    }

    /// An SDO response frame on 580h + node-ID.
    fn sdo_response(&self, data: [u8; 8]) -> CanFrame {
        CanFrame::with_len(
            CanId::from_masked(0x580 + u16::from(self.shell.config.node_id.raw())),
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

impl Shell {
    /// Latches the safe state for `cause` (once) and says why: an event and an EMCY; a GFC
    /// too when configured. The protocol has put its received values in the safe state.
    /// Cold: kept out of the receive hot path.
    #[cold]
    #[inline(never)]
    fn latch(&mut self, cause: SafeStateCause, sink: &mut impl Sink) {
        if self.fault.is_some() {
            return;
        }
        self.fault = Some(cause);
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
            SafeStateCause::Protocol { code, cause, named } => (code, [named, cause, 0, 0, 0]),
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

    /// A configuration refused at Operational entry: the error register and EMCY 6300h
    /// (data set) with `detail`.
    fn refuse_configuration(&mut self, detail: [u8; 5], sink: &mut impl Sink) {
        self.error_register |= emcy::register::GENERIC | emcy::register::PROFILE;
        self.send_emergency(emcy::code::DATA_SET, detail, sink);
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
}

#[cfg(test)]
mod access_tests;
#[cfg(all(test, feature = "lss"))]
mod lss_tests;
#[cfg(test)]
mod sdo_tests;
#[cfg(test)]
mod simplecan_tests;
#[cfg(test)]
mod slot_tests;
#[cfg(test)]
mod tests;
