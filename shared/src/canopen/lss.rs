//! LSS slave (CiA 305 Layer Setting Services): node-ID and bit rate set over the bus, by the
//! identity of object 1018h.
//!
//! The wire format follows CANopenNode (`305/CO_LSSslave.c`) and python-canopen
//! (`canopen/lss.py`) exactly; lely-core (`src/co/lss.c`) names the figures of CiA 305
//! version 3.0.0 each protocol is drawn in, cited below as "Fig. N". Every frame is 8 bytes,
//! master to slave on [`MASTER_TO_SLAVE`] (7E5h), slave to master on [`SLAVE_TO_MASTER`]
//! (7E4h); byte 0 is the command specifier, the rest little-endian, unused bytes 0.
//!
//! | specifier | service | LSS state | answer |
//! |---|---|---|---|
//! | 04h | switch state global (Fig. 31): byte 1 = 0 waiting, 1 configuration | both | none |
//! | 40h..43h | switch state selective (Fig. 32): vendor, product, revision, serial, in this order | waiting | 44h after a whole match |
//! | 11h | configure node-ID (Fig. 33) | configuration | 11h, error code |
//! | 13h | configure bit timing (Fig. 34): selector, index | configuration | 13h, error code |
//! | 15h | activate bit timing (Fig. 35): switch delay in ms | configuration | none |
//! | 17h | store configuration (Fig. 36) | configuration | 17h, error code |
//! | 5Ah..5Dh | inquire vendor, product, revision, serial (Fig. 37 to 40) | configuration | the same, the value |
//! | 5Eh | inquire node-ID (Fig. 41) | configuration | 5Eh, the active node-ID |
//! | 46h..4Bh | identify remote slave (Fig. 42): vendor, product, revision low, high, serial low, high | both | 4Fh after a whole match (Fig. 43) |
//! | 4Ch | identify non-configured remote slave (Fig. 44) | both | 50h when unconfigured (Fig. 45) |
//! | 51h | fastscan (Fig. 46): ID number, bit check, LSS sub, LSS next | waiting | 4Fh on a match |
//!
//! A frame that is not 8 bytes long, a remote frame, or an unknown specifier gets no answer
//! and changes nothing, as CiA 305 has every LSS message 8 bytes long; so does a service in
//! the LSS state that does not offer it. A request that is refused changes nothing: the
//! pending values are replaced whole or not at all.
//!
//! The device's use of this slave (`Device::enable_lss` in [`crate::node`], the LSS settings
//! in the stored image) is behind the crate's `lss` feature, off by default and on in the
//! firmware images, whose two channels both run the slave (`dual_channel::lss`). This module
//! itself is always built (the tool's LSS master frames its requests with it).
//!
//! # Safety rules
//!
//! These are the node's own, on top of CiA 305; each has tests named after the figure they
//! touch and the rule (`cia305_fig33_rule_2_...`).
//!
//! 1. *No configuration in Operational* (`cia305_..._rule_1_...`). The LSS configuration state is
//!    entered only outside NMT Operational: in Operational a switch to the configuration
//!    state (global, selective or by fastscan) is not obeyed and not answered, and
//!    [`LssEvent::RefusedInOperational`] names the specifier for the node's log. A node that
//!    enters Operational leaves the configuration state ([`Lss::leave_configuration`]), so no
//!    configuring service ever reaches a node in Operational.
//! 2. *Pending until reset* (`cia305_..._rule_2_...`). A configured node-ID is *pending*: the node
//!    keeps its *active* node-ID until NMT reset communication (or reset node), as CiA 305
//!    asks, so nothing runs on a half-changed address. Inquire node-ID answers the active
//!    one. The one exception is CiA 305's own: an unconfigured node that was given a
//!    node-ID takes it when the master switches it back to the waiting state, by an NMT
//!    reset communication of its own ([`LssOutcome::reset_communication`]). A node that
//!    restarts on another node-ID than the one its stored safety configuration was
//!    validated for withdraws that validation (the node's rule, EN 50325-5 6.4.1.6): an
//!    address changed by LSS never runs a configuration checked for another address.
//! 3. *Switches win* (`cia305_..._rule_3_...`). Where the board's node-ID switches are set, their
//!    node-ID is the node's, whatever LSS stored; configure node-ID is then refused with the
//!    manufacturer-specific error FFh, [`SWITCHES_SET`]. All switches open means "use LSS":
//!    the LSS node-ID stored with the parameters, or none; a node without a node-ID is
//!    *unconfigured* (node-ID FFh): it sends no boot-up message and nothing else but LSS
//!    answers, obeys no NMT command, and answers fastscan and identify non-configured
//!    remote slave.
//! 4. *Silent switch* (`cia305_..._rule_4_...`). Activate bit timing makes the node send nothing for
//!    the switch delay, then reports the new bit rate ([`LssEvent::SwitchBitRate`]) for the
//!    board to apply, then sends nothing for the switch delay again (CiA 305 Fig. 35).
//!
//! What cannot panic: every field is read from a checked 8-byte array; nothing indexes by a
//! received value without a bound check.

use super::NodeId;
use crate::frame::{CanFrame, CanId};
use crate::time::{Duration, Instant};

/// The identifier of the LSS master's requests (CiA 305: 7E5h).
pub const MASTER_TO_SLAVE: CanId = CanId::from_masked(0x7E5);
/// The identifier of the LSS slaves' answers (CiA 305: 7E4h).
pub const SLAVE_TO_MASTER: CanId = CanId::from_masked(0x7E4);

/// The node-ID byte of an unconfigured node (CiA 305: FFh).
pub const UNCONFIGURED: u8 = 0xFF;

/// The command specifiers (CiA 305 v3.0.0; CANopenNode `305/CO_LSS.h`, python-canopen
/// `canopen/lss.py`).
pub mod specifier {
    /// Switch state global (Fig. 31).
    pub const SWITCH_GLOBAL: u8 = 0x04;
    /// Configure node-ID (Fig. 33).
    pub const CONFIGURE_NODE_ID: u8 = 0x11;
    /// Configure bit timing parameters (Fig. 34).
    pub const CONFIGURE_BIT_TIMING: u8 = 0x13;
    /// Activate bit timing parameters (Fig. 35).
    pub const ACTIVATE_BIT_TIMING: u8 = 0x15;
    /// Store configuration (Fig. 36).
    pub const STORE_CONFIGURATION: u8 = 0x17;
    /// Switch state selective: vendor-ID (Fig. 32).
    pub const SWITCH_SELECTIVE_VENDOR: u8 = 0x40;
    /// Switch state selective: product code.
    pub const SWITCH_SELECTIVE_PRODUCT: u8 = 0x41;
    /// Switch state selective: revision number.
    pub const SWITCH_SELECTIVE_REVISION: u8 = 0x42;
    /// Switch state selective: serial number.
    pub const SWITCH_SELECTIVE_SERIAL: u8 = 0x43;
    /// Switch state selective: the slave's answer.
    pub const SWITCH_SELECTIVE_ANSWER: u8 = 0x44;
    /// Identify remote slave: vendor-ID (Fig. 42).
    pub const IDENTIFY_VENDOR: u8 = 0x46;
    /// Identify remote slave: product code.
    pub const IDENTIFY_PRODUCT: u8 = 0x47;
    /// Identify remote slave: lowest revision number.
    pub const IDENTIFY_REVISION_LOW: u8 = 0x48;
    /// Identify remote slave: highest revision number.
    pub const IDENTIFY_REVISION_HIGH: u8 = 0x49;
    /// Identify remote slave: lowest serial number.
    pub const IDENTIFY_SERIAL_LOW: u8 = 0x4A;
    /// Identify remote slave: highest serial number.
    pub const IDENTIFY_SERIAL_HIGH: u8 = 0x4B;
    /// Identify non-configured remote slave (Fig. 44).
    pub const IDENTIFY_NON_CONFIGURED: u8 = 0x4C;
    /// Identify slave: the answer to identify remote slave and to fastscan (Fig. 43).
    pub const IDENTIFY_SLAVE: u8 = 0x4F;
    /// Identify non-configured slave: the answer to 4Ch (Fig. 45).
    pub const NON_CONFIGURED_SLAVE: u8 = 0x50;
    /// Fastscan (Fig. 46).
    pub const FASTSCAN: u8 = 0x51;
    /// Inquire identity vendor-ID (Fig. 37).
    pub const INQUIRE_VENDOR: u8 = 0x5A;
    /// Inquire identity product code (Fig. 38).
    pub const INQUIRE_PRODUCT: u8 = 0x5B;
    /// Inquire identity revision number (Fig. 39).
    pub const INQUIRE_REVISION: u8 = 0x5C;
    /// Inquire identity serial number (Fig. 40).
    pub const INQUIRE_SERIAL: u8 = 0x5D;
    /// Inquire node-ID (Fig. 41).
    pub const INQUIRE_NODE_ID: u8 = 0x5E;
}

/// The fastscan bit check that resets every unconfigured slave's scan and asks whether any
/// is there (CANopenNode `CO_LSS_FASTSCAN_CONFIRM`).
pub const FASTSCAN_CONFIRM: u8 = 0x80;

/// Error code 0 of configure node-ID, configure bit timing and store: done.
pub const OK: u8 = 0;
/// Configure node-ID: the node-ID is out of range; configure bit timing: the bit rate is not
/// supported; store: storing is not supported (error code 1).
pub const REFUSED: u8 = 1;
/// Store configuration: the storage medium failed (error code 2).
pub const STORE_FAILED: u8 = 2;
/// Error code FFh: manufacturer-specific, byte 2 says which.
pub const MANUFACTURER_SPECIFIC: u8 = 0xFF;
/// The manufacturer-specific error (byte 2 after FFh) of configure node-ID on a node whose
/// node-ID switches are set: the switches win (safety rule 3), nothing changed.
pub const SWITCHES_SET: u8 = 0x01;

/// A bit rate of the CiA 301 bit-timing table (table selector 0), by its table index.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BitRate {
    /// Index 0: 1 Mbit/s.
    Kbit1000,
    /// Index 1: 800 kbit/s.
    Kbit800,
    /// Index 2: 500 kbit/s.
    Kbit500,
    /// Index 3: 250 kbit/s.
    Kbit250,
    /// Index 4: 125 kbit/s.
    Kbit125,
    /// Index 6: 50 kbit/s (index 5 is reserved).
    Kbit50,
    /// Index 7: 20 kbit/s.
    Kbit20,
    /// Index 8: 10 kbit/s.
    Kbit10,
    /// Index 9: automatic bit rate detection.
    Automatic,
}

impl BitRate {
    /// Every entry of the table, in index order.
    pub const ALL: [BitRate; 9] = [
        BitRate::Kbit1000,
        BitRate::Kbit800,
        BitRate::Kbit500,
        BitRate::Kbit250,
        BitRate::Kbit125,
        BitRate::Kbit50,
        BitRate::Kbit20,
        BitRate::Kbit10,
        BitRate::Automatic,
    ];

    /// The entry at `index`; `None` outside the table and for the reserved index 5.
    pub const fn from_index(index: u8) -> Option<BitRate> {
        Some(match index {
            0 => BitRate::Kbit1000,
            1 => BitRate::Kbit800,
            2 => BitRate::Kbit500,
            3 => BitRate::Kbit250,
            4 => BitRate::Kbit125,
            6 => BitRate::Kbit50,
            7 => BitRate::Kbit20,
            8 => BitRate::Kbit10,
            9 => BitRate::Automatic,
            _ => return None,
        })
    }

    /// Its table index.
    pub const fn index(self) -> u8 {
        match self {
            BitRate::Kbit1000 => 0,
            BitRate::Kbit800 => 1,
            BitRate::Kbit500 => 2,
            BitRate::Kbit250 => 3,
            BitRate::Kbit125 => 4,
            BitRate::Kbit50 => 6,
            BitRate::Kbit20 => 7,
            BitRate::Kbit10 => 8,
            BitRate::Automatic => 9,
        }
    }

    /// The bit rate in bit/s; `None` for automatic detection.
    pub const fn bits_per_second(self) -> Option<u32> {
        Some(match self {
            BitRate::Kbit1000 => 1_000_000,
            BitRate::Kbit800 => 800_000,
            BitRate::Kbit500 => 500_000,
            BitRate::Kbit250 => 250_000,
            BitRate::Kbit125 => 125_000,
            BitRate::Kbit50 => 50_000,
            BitRate::Kbit20 => 20_000,
            BitRate::Kbit10 => 10_000,
            BitRate::Automatic => return None,
        })
    }

    /// The entry for `bits_per_second`, if the table has it.
    pub fn from_bits_per_second(bits_per_second: u32) -> Option<BitRate> {
        BitRate::ALL
            .into_iter()
            .find(|rate| rate.bits_per_second() == Some(bits_per_second))
    }
}

/// The bit rates a board supports: a set of [`BitRate`]s.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BitRates(u16);

impl BitRates {
    /// No bit rate can be configured: configure bit timing is always refused.
    pub const NONE: BitRates = BitRates(0);

    /// The set of `rates`.
    pub const fn of(rates: &[BitRate]) -> BitRates {
        let mut bits = 0u16;
        let mut at = 0;
        while at < rates.len() {
            bits |= 1 << rates[at].index();
            at += 1;
        }
        BitRates(bits)
    }

    /// `true` when `rate` is in the set.
    pub const fn contains(self, rate: BitRate) -> bool {
        self.0 & (1 << rate.index()) != 0
    }
}

/// What store configuration keeps: the pending node-ID and bit rate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LssSettings {
    /// The node-ID; `None`: unconfigured (FFh).
    pub node_id: Option<NodeId>,
    /// The bit rate; `None`: never configured by LSS (the board's own).
    pub bit_rate: Option<BitRate>,
}

impl LssSettings {
    /// Nothing configured: no node-ID, the board's bit rate.
    pub const UNCONFIGURED: LssSettings = LssSettings {
        node_id: None,
        bit_rate: None,
    };

    /// The two stored bytes: the node-ID (FFh: none) and the bit-timing index (FFh: none).
    pub const fn encode(self) -> [u8; 2] {
        [
            match self.node_id {
                Some(id) => id.raw(),
                None => UNCONFIGURED,
            },
            match self.bit_rate {
                Some(rate) => rate.index(),
                None => 0xFF,
            },
        ]
    }

    /// The settings [`LssSettings::encode`] wrote; `None` for any other bytes.
    pub const fn decode(bytes: [u8; 2]) -> Option<LssSettings> {
        let node_id = match bytes[0] {
            UNCONFIGURED => None,
            raw => match NodeId::new(raw) {
                Ok(id) => Some(id),
                Err(_) => return None,
            },
        };
        let bit_rate = match bytes[1] {
            0xFF => None,
            index => match BitRate::from_index(index) {
                Some(rate) => Some(rate),
                None => return None,
            },
        };
        Some(LssSettings { node_id, bit_rate })
    }
}

/// The LSS state of the slave (CiA 305: LSS waiting, LSS configuration).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LssState {
    /// LSS waiting: only switching, identification and fastscan are answered.
    Waiting,
    /// LSS configuration: node-ID, bit timing, store and inquiries are served.
    Configuration,
}

/// Where the node's node-ID comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NodeIdSource {
    /// The board's node-ID switches (they win over LSS: safety rule 3).
    Switches,
    /// The node-ID LSS configured (and stored, or pending until the last reset).
    Lss,
    /// None: the node is unconfigured (node-ID FFh).
    Unconfigured,
}

/// Why store configuration did not store.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreFailure {
    /// The node cannot store its LSS settings (error code 1).
    NotSupported,
    /// The medium failed (error code 2); nothing stored changed.
    Failed(crate::canopen::storage::StorageError),
}

/// Something the node's log should show about LSS.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LssEvent {
    /// The LSS configuration state was entered (switch global, selective or fastscan).
    ConfigurationEntered,
    /// The LSS waiting state was entered from the configuration state.
    WaitingEntered,
    /// A switch to the configuration state arrived in NMT Operational and was not obeyed
    /// (safety rule 1); `specifier` is the request's command specifier.
    RefusedInOperational {
        /// 04h (global), 43h (selective) or 51h (fastscan).
        specifier: u8,
    },
    /// The node left the LSS configuration state because it entered NMT Operational
    /// (safety rule 1).
    ConfigurationLeftForOperational,
    /// A node-ID is pending (`None`: unconfigured), in force at the next reset
    /// communication (safety rule 2).
    NodeIdPending(Option<NodeId>),
    /// Configure node-ID was refused; nothing changed. `requested` is the byte received.
    NodeIdRefused {
        /// The node-ID byte of the request.
        requested: u8,
        /// `true`: the switches are set (safety rule 3); `false`: not a node-ID (0, 80h..FEh).
        switches: bool,
    },
    /// A bit rate is pending, activated by activate bit timing.
    BitRatePending(BitRate),
    /// Configure bit timing was refused (another table, an index outside it, or a bit rate
    /// the board does not support); nothing changed.
    BitRateRefused {
        /// The table selector received.
        selector: u8,
        /// The table index received.
        index: u8,
    },
    /// The switch delay of activate bit timing has passed: the board switches the CAN
    /// controller to this bit rate now; the node stays silent for the delay again (safety
    /// rule 4).
    SwitchBitRate(BitRate),
    /// Store configuration stored these settings.
    Stored(LssSettings),
    /// Store configuration failed; what was stored before is still in force.
    StoreFailed(StoreFailure),
    /// The node has no node-ID (FFh): it sends nothing but LSS answers until a master gives
    /// it one (safety rule 3).
    Unconfigured,
    /// The bit rate stored by LSS is not one this board can switch to (its image supports
    /// other rates than the one that stored it): the board starts at its own rate, and the
    /// stored one stays unused until the next store configuration replaces it (CiA 305 only
    /// ever makes a supported rate pending).
    StoredBitRateUnsupported(BitRate),
    /// The node-ID switches are set and win over the LSS node-ID stored (safety rule 3).
    SwitchesWin {
        /// The switches' node-ID.
        switches: NodeId,
        /// The stored LSS node-ID they override (`None`: unconfigured).
        stored: Option<NodeId>,
    },
}

/// What one request led to: at most one answer, at most one event.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct LssOutcome {
    /// The answer to send on [`SLAVE_TO_MASTER`].
    pub response: Option<CanFrame>,
    /// What to log.
    pub event: Option<LssEvent>,
    /// The node must perform an NMT reset communication now: an unconfigured node was given a
    /// node-ID and switched back to the waiting state (CiA 305; CANopenNode
    /// `CO_LSSslave_process`).
    pub reset_communication: bool,
}

impl LssOutcome {
    fn answer(data: [u8; 8]) -> Self {
        LssOutcome {
            response: Some(CanFrame::with_len(SLAVE_TO_MASTER, data, 8)),
            ..Self::default()
        }
    }

    fn event(event: LssEvent) -> Self {
        LssOutcome {
            event: Some(event),
            ..Self::default()
        }
    }

    fn with(mut self, event: LssEvent) -> Self {
        self.event = Some(event);
        self
    }
}

/// An activate bit timing in progress (safety rule 4).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Switch {
    /// When the request arrived: the node is silent from here.
    start: Instant,
    /// The switch delay.
    delay: Duration,
    /// The bit rate to switch to.
    rate: BitRate,
    /// `true` once [`LssEvent::SwitchBitRate`] was reported.
    switched: bool,
}

/// The LSS slave of one node (sans-I/O: fed frames and `now`, answers with frames and events).
/// Comparable whole, so a test can show that a refused request changed nothing.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Lss {
    identity: [u32; 4],
    switches: Option<NodeId>,
    supported: BitRates,
    state: LssState,
    active: Option<NodeId>,
    pending: Option<NodeId>,
    pending_rate: Option<BitRate>,
    stored: Option<NodeId>,
    /// A stored bit rate outside `supported`, not taken (reported at start and reset).
    unsupported_rate: Option<BitRate>,
    /// The next switch state selective specifier expected (40h: none started).
    selective: u8,
    /// The next identify remote slave specifier expected (46h: none started).
    identify: u8,
    /// The fastscan LSSPos: the part of the identity the next fastscan request checks.
    fastscan_position: u8,
    switch: Option<Switch>,
}

impl Lss {
    /// The LSS slave of a node with `identity` (object 1018h sub-indices 1 to 4), its node-ID
    /// switches (`None`: all open, "use LSS"), the LSS settings stored with its parameters
    /// (`None`: none stored) and the bit rates its board can switch to. The active node-ID is
    /// the switches', else the stored one, else none (unconfigured). A stored bit rate the
    /// board does not support is not taken: the board starts at its own
    /// ([`LssEvent::StoredBitRateUnsupported`]).
    pub fn new(
        identity: [u32; 4],
        switches: Option<NodeId>,
        stored: Option<LssSettings>,
        supported: BitRates,
    ) -> Lss {
        let stored = stored.unwrap_or(LssSettings::UNCONFIGURED);
        let (pending_rate, unsupported_rate) = match stored.bit_rate {
            Some(rate) if !supported.contains(rate) => (None, Some(rate)),
            rate => (rate, None),
        };
        Lss {
            identity,
            switches,
            supported,
            state: LssState::Waiting,
            active: switches.or(stored.node_id),
            pending: stored.node_id,
            pending_rate,
            stored: stored.node_id,
            unsupported_rate,
            selective: specifier::SWITCH_SELECTIVE_VENDOR,
            identify: specifier::IDENTIFY_VENDOR,
            fastscan_position: 0,
            switch: None,
        }
    }

    /// The node-ID in force (`None`: unconfigured, FFh).
    pub fn active(&self) -> Option<NodeId> {
        self.active
    }

    /// The node-ID configured by LSS, in force at the next reset communication (`None`:
    /// unconfigured).
    pub fn pending(&self) -> Option<NodeId> {
        self.pending
    }

    /// The bit rate stored or configured by LSS (`None`: the board's own). The board starts
    /// its CAN controller on the stored one.
    pub fn bit_rate(&self) -> Option<BitRate> {
        self.pending_rate
    }

    /// The LSS state.
    pub fn state(&self) -> LssState {
        self.state
    }

    /// Where the active node-ID comes from.
    pub fn source(&self) -> NodeIdSource {
        match (self.switches, self.active) {
            (Some(_), _) => NodeIdSource::Switches,
            (None, Some(_)) => NodeIdSource::Lss,
            (None, None) => NodeIdSource::Unconfigured,
        }
    }

    /// The events the node logs when it starts or resets: it is unconfigured, or its switches
    /// win over a stored LSS node-ID that differs from theirs (safety rule 3); and the stored
    /// bit rate is one the board does not support.
    pub fn start_events(&self) -> [Option<LssEvent>; 2] {
        let node_id = match (self.switches, self.active) {
            (Some(switches), _) if self.stored.is_some_and(|stored| stored != switches) => {
                Some(LssEvent::SwitchesWin {
                    switches,
                    stored: self.stored,
                })
            }
            (_, None) => Some(LssEvent::Unconfigured),
            _ => None,
        };
        [
            node_id,
            self.unsupported_rate
                .map(LssEvent::StoredBitRateUnsupported),
        ]
    }

    /// `true` while activate bit timing keeps the node silent (safety rule 4).
    pub fn muted(&self, now: Instant) -> bool {
        self.switch.is_some_and(|switch| {
            now >= switch.start && now < switch.start + switch.delay + switch.delay
        })
    }

    /// The next instant [`Lss::poll`] has something to do ([`Instant::NEVER`]: none).
    #[must_use]
    pub fn deadline(&self) -> Instant {
        match self.switch {
            Some(switch) if !switch.switched => switch.start + switch.delay,
            Some(switch) => switch.start + switch.delay + switch.delay,
            None => Instant::NEVER,
        }
    }

    /// Runs the bit-rate switch: [`LssEvent::SwitchBitRate`] once the first switch delay has
    /// passed; the second delay ends the silence.
    pub fn poll(&mut self, now: Instant) -> Option<LssEvent> {
        let switch = self.switch.as_mut()?;
        if !switch.switched {
            if !crate::time::expired(switch.start + switch.delay, now) {
                return None;
            }
            switch.switched = true;
            return Some(LssEvent::SwitchBitRate(switch.rate));
        }
        if crate::time::expired(switch.start + switch.delay + switch.delay, now) {
            self.switch = None;
        }
        None
    }

    /// NMT reset communication or reset node: the pending node-ID comes into force (the
    /// switches' where they are set), the LSS state goes back to waiting. Returns the node-ID
    /// in force (`None`: unconfigured).
    pub fn reset_communication(&mut self) -> Option<NodeId> {
        self.active = self.switches.or(self.pending);
        self.enter_waiting();
        self.active
    }

    /// The node enters NMT Operational: the configuration state is left (safety rule 1).
    pub fn leave_configuration(&mut self) -> Option<LssEvent> {
        if self.state != LssState::Configuration {
            return None;
        }
        self.enter_waiting();
        Some(LssEvent::ConfigurationLeftForOperational)
    }

    /// Store configuration succeeded elsewhere with `settings` in force: kept as the stored
    /// node-ID (for [`LssEvent::SwitchesWin`]).
    fn stored_as(&mut self, settings: LssSettings) {
        self.stored = settings.node_id;
        self.unsupported_rate = None;
    }

    fn enter_waiting(&mut self) {
        self.state = LssState::Waiting;
        self.selective = specifier::SWITCH_SELECTIVE_VENDOR;
        self.identify = specifier::IDENTIFY_VENDOR;
    }

    fn unconfigured(&self) -> bool {
        self.active.is_none() && self.pending.is_none()
    }

    /// Handles a frame on [`MASTER_TO_SLAVE`] received at `now`; `operational`: the node is
    /// in NMT Operational. `store` stores the given settings beside the parameters (called
    /// only by store configuration).
    pub fn on_frame(
        &mut self,
        now: Instant,
        frame: &CanFrame,
        operational: bool,
        store: impl FnOnce(LssSettings) -> Result<(), StoreFailure>,
    ) -> LssOutcome {
        if frame.id() != MASTER_TO_SLAVE || frame.is_remote() || self.muted(now) {
            return LssOutcome::default();
        }
        let Ok(data) = <[u8; 8]>::try_from(frame.data()) else {
            return LssOutcome::default();
        };
        let [command, b1, b2, b3, b4, b5, b6, b7] = data;
        let value = u32::from_le_bytes([b1, b2, b3, b4]);
        match command {
            specifier::SWITCH_GLOBAL => self.switch_global(b1, operational),
            specifier::IDENTIFY_VENDOR..=specifier::IDENTIFY_SERIAL_HIGH => {
                self.identify_remote(command, value)
            }
            specifier::IDENTIFY_NON_CONFIGURED => {
                if self.unconfigured() {
                    LssOutcome::answer([specifier::NON_CONFIGURED_SLAVE, 0, 0, 0, 0, 0, 0, 0])
                } else {
                    LssOutcome::default()
                }
            }
            _ => match self.state {
                LssState::Waiting => match command {
                    specifier::SWITCH_SELECTIVE_VENDOR..=specifier::SWITCH_SELECTIVE_SERIAL => {
                        self.switch_selective(command, value, operational)
                    }
                    specifier::FASTSCAN => self.fastscan(value, b5, b6, b7, operational),
                    _ => LssOutcome::default(),
                },
                LssState::Configuration => self.configure(now, command, b1, b2, store),
            },
        }
    }

    /// Switch state global (Fig. 31).
    fn switch_global(&mut self, mode: u8, operational: bool) -> LssOutcome {
        match (mode, self.state) {
            (0, LssState::Configuration) => {
                // CiA 305 (CANopenNode `CO_LSSslave_receive`): an unconfigured node that was
                // given a node-ID takes it now, by a reset communication of its own.
                let reset = self.active.is_none() && self.pending.is_some();
                self.enter_waiting();
                LssOutcome {
                    reset_communication: reset,
                    ..LssOutcome::event(LssEvent::WaitingEntered)
                }
            }
            (0, LssState::Waiting) => {
                self.enter_waiting();
                LssOutcome::default()
            }
            (1, _) if operational => LssOutcome::event(LssEvent::RefusedInOperational {
                specifier: specifier::SWITCH_GLOBAL,
            }),
            (1, LssState::Waiting) => {
                self.state = LssState::Configuration;
                LssOutcome::event(LssEvent::ConfigurationEntered)
            }
            _ => LssOutcome::default(),
        }
    }

    /// Switch state selective (Fig. 32): the four parts in order, each matching; a part out of
    /// order or not matching starts the sequence over (lely-core `co_lss_switch_sel`).
    fn switch_selective(&mut self, command: u8, value: u32, operational: bool) -> LssOutcome {
        let part = usize::from(command - specifier::SWITCH_SELECTIVE_VENDOR);
        let in_order = command == specifier::SWITCH_SELECTIVE_VENDOR || command == self.selective;
        if !in_order || self.identity.get(part) != Some(&value) {
            self.selective = specifier::SWITCH_SELECTIVE_VENDOR;
            return LssOutcome::default();
        }
        if command != specifier::SWITCH_SELECTIVE_SERIAL {
            self.selective = command + 1;
            return LssOutcome::default();
        }
        self.selective = specifier::SWITCH_SELECTIVE_VENDOR;
        if operational {
            return LssOutcome::event(LssEvent::RefusedInOperational { specifier: command });
        }
        self.state = LssState::Configuration;
        LssOutcome::answer([specifier::SWITCH_SELECTIVE_ANSWER, 0, 0, 0, 0, 0, 0, 0])
            .with(LssEvent::ConfigurationEntered)
    }

    /// Identify remote slave (Fig. 42): vendor and product equal, revision and serial number
    /// in their ranges (bounds included), the six parts in order (lely-core `co_lss_id_slave`).
    fn identify_remote(&mut self, command: u8, value: u32) -> LssOutcome {
        let [vendor, product, revision, serial] = self.identity;
        let matches = match command {
            specifier::IDENTIFY_VENDOR => value == vendor,
            specifier::IDENTIFY_PRODUCT => value == product,
            specifier::IDENTIFY_REVISION_LOW => value <= revision,
            specifier::IDENTIFY_REVISION_HIGH => value >= revision,
            specifier::IDENTIFY_SERIAL_LOW => value <= serial,
            _ => value >= serial,
        };
        let in_order = command == specifier::IDENTIFY_VENDOR || command == self.identify;
        if !in_order || !matches {
            self.identify = specifier::IDENTIFY_VENDOR;
            return LssOutcome::default();
        }
        if command != specifier::IDENTIFY_SERIAL_HIGH {
            self.identify = command + 1;
            return LssOutcome::default();
        }
        self.identify = specifier::IDENTIFY_VENDOR;
        LssOutcome::answer([specifier::IDENTIFY_SLAVE, 0, 0, 0, 0, 0, 0, 0])
    }

    /// Fastscan (Fig. 46; CANopenNode `CO_LSSslave_receive`, lely-core `co_lss_fastscan`):
    /// only an unconfigured node takes part. Bit check 80h resets the scan; otherwise the
    /// bits `bit_check..=31` of the identity part `sub` (the one the scan is at) must equal
    /// the request's, then the scan moves to part `next`; a whole part checked (bit check 0)
    /// with `next` below `sub` selects the node: it enters the configuration state.
    fn fastscan(
        &mut self,
        value: u32,
        bit_check: u8,
        sub: u8,
        next: u8,
        operational: bool,
    ) -> LssOutcome {
        if !self.unconfigured() {
            return LssOutcome::default();
        }
        if (bit_check > 31 && bit_check != FASTSCAN_CONFIRM) || sub > 3 || next > 3 {
            return LssOutcome::default();
        }
        let identified = LssOutcome::answer([specifier::IDENTIFY_SLAVE, 0, 0, 0, 0, 0, 0, 0]);
        if bit_check == FASTSCAN_CONFIRM {
            self.fastscan_position = 0;
            return identified;
        }
        if sub != self.fastscan_position {
            return LssOutcome::default();
        }
        let mask = u32::MAX << bit_check;
        let part = self.identity.get(usize::from(sub)).copied().unwrap_or(0);
        if (part ^ value) & mask != 0 {
            return LssOutcome::default();
        }
        if bit_check == 0 && next < sub {
            if operational {
                // Not reached: an unconfigured node never enters Operational.
                return LssOutcome::event(LssEvent::RefusedInOperational {
                    specifier: specifier::FASTSCAN,
                });
            }
            self.fastscan_position = 0;
            self.state = LssState::Configuration;
            return identified.with(LssEvent::ConfigurationEntered);
        }
        self.fastscan_position = next;
        identified
    }

    /// The services of the configuration state (Fig. 33 to 41).
    fn configure(
        &mut self,
        now: Instant,
        command: u8,
        b1: u8,
        b2: u8,
        store: impl FnOnce(LssSettings) -> Result<(), StoreFailure>,
    ) -> LssOutcome {
        let reply =
            |code: u8, detail: u8| LssOutcome::answer([command, code, detail, 0, 0, 0, 0, 0]);
        let inquiry = |value: u32| {
            let [v0, v1, v2, v3] = value.to_le_bytes();
            LssOutcome::answer([command, v0, v1, v2, v3, 0, 0, 0])
        };
        match command {
            specifier::CONFIGURE_NODE_ID => {
                if self.switches.is_some() {
                    return reply(MANUFACTURER_SPECIFIC, SWITCHES_SET).with(
                        LssEvent::NodeIdRefused {
                            requested: b1,
                            switches: true,
                        },
                    );
                }
                let requested = match b1 {
                    UNCONFIGURED => None,
                    raw => match NodeId::new(raw) {
                        Ok(id) => Some(id),
                        Err(_) => {
                            return reply(REFUSED, 0).with(LssEvent::NodeIdRefused {
                                requested: b1,
                                switches: false,
                            });
                        }
                    },
                };
                self.pending = requested;
                reply(OK, 0).with(LssEvent::NodeIdPending(requested))
            }
            specifier::CONFIGURE_BIT_TIMING => {
                let rate = if b1 == 0 {
                    BitRate::from_index(b2).filter(|&rate| self.supported.contains(rate))
                } else {
                    None
                };
                match rate {
                    Some(rate) => {
                        self.pending_rate = Some(rate);
                        reply(OK, 0).with(LssEvent::BitRatePending(rate))
                    }
                    None => reply(REFUSED, 0).with(LssEvent::BitRateRefused {
                        selector: b1,
                        index: b2,
                    }),
                }
            }
            specifier::ACTIVATE_BIT_TIMING => {
                // Only a bit rate the board supports was ever made pending; with none pending
                // the node switches to nothing and answers nothing (CANopenNode drops the
                // request where setting the bit timing is not supported).
                let Some(rate) = self.pending_rate else {
                    return LssOutcome::default();
                };
                self.switch = Some(Switch {
                    start: now,
                    delay: Duration::from_millis(u64::from(u16::from_le_bytes([b1, b2]))),
                    rate,
                    switched: false,
                });
                LssOutcome::default()
            }
            specifier::STORE_CONFIGURATION => {
                let settings = LssSettings {
                    node_id: self.pending,
                    bit_rate: self.pending_rate,
                };
                match store(settings) {
                    Ok(()) => {
                        self.stored_as(settings);
                        reply(OK, 0).with(LssEvent::Stored(settings))
                    }
                    Err(failure) => {
                        let code = match failure {
                            StoreFailure::NotSupported => REFUSED,
                            StoreFailure::Failed(_) => STORE_FAILED,
                        };
                        reply(code, 0).with(LssEvent::StoreFailed(failure))
                    }
                }
            }
            specifier::INQUIRE_VENDOR..=specifier::INQUIRE_SERIAL => {
                let part = usize::from(command - specifier::INQUIRE_VENDOR);
                inquiry(self.identity.get(part).copied().unwrap_or(0))
            }
            specifier::INQUIRE_NODE_ID => reply(self.active.map_or(UNCONFIGURED, NodeId::raw), 0),
            _ => LssOutcome::default(),
        }
    }
}

#[cfg(test)]
mod tests;
