//! SimpleCAN (FSD350) as a safety protocol in the node's slot ([`SafetyProtocol`]): its
//! configuration objects 5E00h..5EFFh (`docs/simplecan.md` section 11), their storage, the
//! check at the Operational entry, and the building blocks of [`crate::simplecan`] driven on
//! the bus.
//!
//! # What it does, requirement by requirement
//! - **Configuration** (SC_REQ_16, SC_REQ_17, SC_REQ_34, SC_REQ_39, SC_REQ_43): the objects of
//!   section 11, written only in Pre-operational (0800 0022h otherwise) and only while the
//!   device is unlocked (the shell's access control, [`SafetyProtocol::needs_unlock`]). At the
//!   Operational entry with SimpleCAN enabled (5E00h:04 = 1) it requires 5EFEh = A5h,
//!   recomputes the CRC-32 signature ([`SimpleCanObjects::signature`]) against 5EFFh and
//!   builds the safety data dictionary ([`Sdd`]) and the cycle ([`Schedule`]); any refusal
//!   keeps the device out of Operational with EMCY 6300h naming the cause and the entry.
//! - **Start unsynced** (SC_REQ_29): with no global time (neither synced nor the active
//!   master) producers send nothing and consumers discard every data packet.
//! - **Time** (SC_REQ_30..33): every checked sync goes to the [`SyncTracker`].
//! - **Master** (SC_REQ_22..28): with 5E00h:05 = 1 the node is a potential master as its
//!   lowest produced SC-ID ([`Master`]); its syncs are confirmed by
//!   [`SafetyProtocol::on_transmitted`] or aborted ([`Sink::abort`]).
//! - **Producers** (SC_REQ_18, section 5): at the start of its slot each produced SC-ID sends
//!   the value of its mapped object with the cycle stamp; a packet not confirmed by the end of
//!   its slot is aborted.
//! - **Consumers** (SC_REQ_20, SC_REQ_05): a timely packet's value goes to the mapped object;
//!   its age counts from the start of the producer's slot; at the safety timeout the value is
//!   0 and the device latches its safe state.
//! - **Faults** (SC_REQ_26, SC_REQ_42): several masters, or 1000 on the bad-CRC leaky counter,
//!   latch the safe state ([`SafeStateCause::Protocol`], the cause table's codes).
//! - **Safe state** (SC_REQ_40, SC_REQ_41): latched, it sends nothing (what is still queued is
//!   withdrawn) and delivers nothing; only NMT reset clears the shell's latch.

use heapless::Vec;

use super::dictionary::{exact, length, put};
use super::persist::{self, Reader};
use super::slot::{Refused, RowImage, SafetyProtocol, Slot};
use super::{Event, NodeConfig, PersistError, SafeStateCause, Sink};
use crate::canopen::emcy::code;
use crate::canopen::od::{AbortCode, Address};
use crate::frame::CanFrame;
use crate::process_image::{Mappable, ProcessImage, Span};
use crate::safety::cause::Cause;
use crate::safety::config::CONFIGURATION_VALID;
use crate::simplecan::consumer::{Age, ConsumedValue};
use crate::simplecan::crc_monitor::{BadCrcCounter, Verdict};
use crate::simplecan::frame::{
    DataPacket, Packet, SYNC_IDENTIFIER, SyncPacket, data_identifier, decode, is_simplecan,
};
use crate::simplecan::master::{Action, Master, MasterMonitor};
use crate::simplecan::schedule::{MAX_SLOTS, MIN_SLOTS, Schedule};
use crate::simplecan::sdd::{self, Entry, Role, Sdd};
use crate::simplecan::sync::{Change, SyncTracker};
use crate::simplecan::{MAX_SYNC_INTERVAL, MIN_SYNC_INTERVAL, NodeHash, SLOT, ScId};
use crate::time::{Duration, Instant, expired};

/// 5E00h: the cycle and the SCL's own settings (section 11).
pub const CYCLE_INDEX: u16 = 0x5E00;
/// 5E01h: how many SDD entries are in use.
pub const COUNT_INDEX: u16 = 0x5E01;
/// 5E10h: SDD entry 1; entry n is 5E10h + n − 1, up to 5E5Fh for entry 80.
pub const FIRST_ENTRY_INDEX: u16 = 0x5E10;
/// The last index of the configuration proper: any accepted write up to here sets 5EFEh to 0.
const LAST_CONFIGURATION_INDEX: u16 = FIRST_ENTRY_INDEX + sdd::MAX_ENTRIES as u16 - 1;
/// 5EFEh: A5h when the configuration is declared valid.
pub const VALID_INDEX: u16 = 0x5EFE;
/// 5EFFh: the configuration signature, CRC-32 (SC_REQ_17).
pub const SIGNATURE_INDEX: u16 = 0x5EFF;

/// 5E10h + n − 1 sub-index 02h: the entry's SC-ID is produced.
pub const ROLE_PRODUCE: u8 = 1;
/// ... consumed.
pub const ROLE_CONSUME: u8 = 2;
/// ... only a potential master's syncs are checked with its node hash.
pub const ROLE_MASTER: u8 = 3;

/// The configuration signature's CRC (section 11): CRC-32/MPEG-2, polynomial 04C11DB7h as
/// SC_REQ_17 names it. The tool computes it with its own code; this is the device's. Bit by
/// bit, without the crate's lookup table (its flash: docs/footprint.md): it runs when the configuration is checked, not per
/// packet.
const SIGNATURE_CRC: crc::Crc<u32, crc::NoTable> =
    crc::Crc::<u32, crc::NoTable>::new(&crc::CRC_32_MPEG_2);

/// One SDD entry's objects (5E10h + n − 1, sub-indices 01h..06h), as written.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EntryObjects {
    /// :01 SC-ID, 30h..7Fh.
    pub sc_id: u8,
    /// :02 role: [`ROLE_PRODUCE`], [`ROLE_CONSUME`] or [`ROLE_MASTER`].
    pub role: u8,
    /// :03 the producer's slot (produced and consumed entries), 0..N − 3.
    pub slot: u16,
    /// :04 safety timeout in ms (consumed entries), 1..60000.
    pub timeout_ms: u16,
    /// :05 node hash (SC_REQ_15).
    pub hash: u32,
    /// :06 mapped object, `index << 16 | sub << 8 | bits`.
    pub mapped: u32,
}

/// Bytes one entry takes in the stored section.
const ENTRY_STORED: usize = 14;
/// Bytes of the stored section besides the entries: 5EFEh, 5EFFh, 5E00h:01..05, 5E01h and
/// the entry capacity.
const FIXED_STORED: usize = 1 + 4 + 8 + 1 + 1;

/// The SimpleCAN configuration objects of a device holding up to `E` SDD entries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SimpleCanObjects<const E: usize> {
    /// 5E00h:01 slots per cycle N.
    pub slots: u16,
    /// 5E00h:02 cycles between syncs k.
    pub sync_every: u16,
    /// 5E00h:03 guaranteed maximum buffering time in µs (SC_REQ_33).
    pub buffering_us: u16,
    /// 5E00h:04 SimpleCAN enabled (1) or not (0).
    pub enabled: u8,
    /// 5E00h:05 potential master (1) or not (0).
    pub potential_master: u8,
    /// 5E01h entries in use.
    pub count: u8,
    /// 5E10h..: the entries.
    pub entries: [EntryObjects; E],
    /// 5EFEh.
    pub valid: u8,
    /// 5EFFh.
    pub signature: u32,
}

impl<const E: usize> SimpleCanObjects<E> {
    /// The defaults: disabled, N = 10, a sync every 10 cycles (100 ms), no entries, not
    /// valid.
    pub const DEFAULT: Self = SimpleCanObjects {
        slots: 10,
        sync_every: 10,
        buffering_us: 0,
        enabled: 0,
        potential_master: 0,
        count: 0,
        entries: [EntryObjects {
            sc_id: 0,
            role: 0,
            slot: 0,
            timeout_ms: 0,
            hash: 0,
            mapped: 0,
        }; E],
        valid: 0,
        signature: 0,
    };

    /// The configuration signature of section 11 for the node `node_id`: CRC-32/MPEG-2 over
    /// the node-ID, 5E00h:01..05, 5E01h and each entry in use, sub-indices 01..06, each value
    /// at its type's size, least significant octet first.
    pub fn signature(&self, node_id: u8) -> u32 {
        let mut digest = SIGNATURE_CRC.digest();
        digest.update(&[node_id]);
        digest.update(&self.slots.to_le_bytes());
        digest.update(&self.sync_every.to_le_bytes());
        digest.update(&self.buffering_us.to_le_bytes());
        digest.update(&[self.enabled, self.potential_master, self.count]);
        for entry in self.entries.iter().take(usize::from(self.count)) {
            digest.update(&[entry.sc_id, entry.role]);
            digest.update(&entry.slot.to_le_bytes());
            digest.update(&entry.timeout_ms.to_le_bytes());
            digest.update(&entry.hash.to_le_bytes());
            digest.update(&entry.mapped.to_le_bytes());
        }
        digest.finalize()
    }

    /// The objects of a section [`SafetyProtocol::persist`] wrote, exactly `bytes` long.
    pub(super) fn from_stored(bytes: &[u8]) -> Result<Self, PersistError> {
        let mut reader = Reader::new(bytes);
        let mut objects = Self::DEFAULT;
        objects.valid = reader.u8()?;
        objects.signature = reader.u32()?;
        objects.slots = reader.u16()?;
        objects.sync_every = reader.u16()?;
        objects.buffering_us = reader.u16()?;
        objects.enabled = reader.u8()?;
        objects.potential_master = reader.u8()?;
        objects.count = reader.u8()?;
        if usize::from(reader.u8()?) != E {
            return Err(PersistError::SrdoCountMismatch);
        }
        if usize::from(objects.count) > E {
            return Err(PersistError::Malformed);
        }
        for entry in objects.entries.iter_mut() {
            entry.sc_id = reader.u8()?;
            entry.role = reader.u8()?;
            entry.slot = reader.u16()?;
            entry.timeout_ms = reader.u16()?;
            entry.hash = reader.u32()?;
            entry.mapped = reader.u32()?;
        }
        if !reader.is_empty() {
            return Err(PersistError::Malformed);
        }
        Ok(objects)
    }
}

/// Why a SimpleCAN configuration is refused, with the entry (1-based) it names, if any.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Refusal {
    /// The cause, one of the cause table's SimpleCAN configuration codes.
    pub cause: Cause,
    /// The SDD entry, 1..=80, or 0 when the cause names none.
    pub entry: u8,
    /// The SDO abort code a write of 5E01h that this refusal stops is answered with.
    pub abort: AbortCode,
}

impl Refusal {
    const fn inconsistent(entry: u8, abort: AbortCode) -> Self {
        Refusal {
            cause: Cause::SimpleCanConfiguration,
            entry,
            abort,
        }
    }
}

/// The configuration checked and turned into the blocks' values.
struct Built<const E: usize> {
    sdd: Sdd<E>,
    schedule: Schedule<E>,
    streams: Vec<Stream, E>,
    /// The potential master's SC-ID (its lowest produced) and node hash.
    master: Option<(ScId, NodeHash)>,
}

/// One SC-ID this SCL produces or consumes, at run time.
#[derive(Clone, Copy, Debug)]
enum Stream {
    Produce {
        sc_id: ScId,
        hash: NodeHash,
        slot: u16,
        span: Span,
        /// The cycle it last sent in.
        sent: Option<u64>,
        /// Sent and not yet confirmed: aborted at this instant, the end of its slot.
        pending_until: Option<Instant>,
    },
    Consume {
        sc_id: ScId,
        span: Span,
        value: ConsumedValue,
    },
}

/// What the SCL counts while it runs (since the Operational entry), for tests, tools and
/// the figures of the documentation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SimpleCanCounters {
    /// Data packets confirmed on the bus.
    pub sent: u32,
    /// Data packets aborted at the end of their slot (SC_REQ_18).
    pub aborted: u32,
    /// Syncs sent and confirmed.
    pub syncs_sent: u32,
    /// Syncs aborted, not confirmed within 2 ms (SC_REQ_23).
    pub syncs_aborted: u32,
    /// Data packets accepted and delivered.
    pub accepted: u32,
    /// Data packets discarded while unsynced (SC_REQ_29).
    pub discarded_unsynced: u32,
    /// Data packets discarded outside their slot (section 5).
    pub untimely: u32,
    /// Frames on SimpleCAN identifiers rejected by the decoder (section 10), bad CRCs
    /// included.
    pub rejected: u32,
}

/// The blocks in Operational.
struct Running<const E: usize> {
    sdd: Sdd<E>,
    schedule: Schedule<E>,
    tracker: SyncTracker,
    master: Option<(Master, NodeHash)>,
    monitor: MasterMonitor,
    bad_crc: BadCrcCounter,
    streams: Vec<Stream, E>,
    /// A sync handed to the controller and not confirmed or aborted yet.
    sync_pending: bool,
}

/// The SimpleCAN layer of a device holding up to `E` (1..=80) SDD entries.
pub struct SimpleCan<const E: usize> {
    objects: SimpleCanObjects<E>,
    running: Option<Running<E>>,
    counters: SimpleCanCounters,
}

impl<const E: usize> Default for SimpleCan<E> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const E: usize> SimpleCan<E> {
    /// A layer with the default objects (disabled), stopped.
    pub const fn new() -> Self {
        const {
            assert!(
                E >= 1 && E <= sdd::MAX_ENTRIES,
                "1..=80 SDD entries (SC_REQ_12)"
            );
        }
        SimpleCan {
            objects: SimpleCanObjects::DEFAULT,
            running: None,
            counters: SimpleCanCounters {
                sent: 0,
                aborted: 0,
                syncs_sent: 0,
                syncs_aborted: 0,
                accepted: 0,
                discarded_unsynced: 0,
                untimely: 0,
                rejected: 0,
            },
        }
    }

    /// The configuration objects.
    pub fn objects(&self) -> &SimpleCanObjects<E> {
        &self.objects
    }

    /// Puts restored objects in force (the SRDO table beside it restored them first).
    pub(super) fn set_objects(&mut self, objects: SimpleCanObjects<E>) {
        self.objects = objects;
    }

    /// What it counted since the Operational entry.
    pub fn counters(&self) -> SimpleCanCounters {
        self.counters
    }

    /// `true` while it runs (Operational with SimpleCAN enabled and its configuration
    /// accepted).
    pub fn is_running(&self) -> bool {
        self.running.is_some()
    }

    /// `true` when it has a global time: synced to a master, or the active master itself.
    pub fn has_global_time(&self, now: Instant) -> bool {
        self.running
            .as_ref()
            .is_some_and(|running| running.global_time(now).is_some())
    }

    /// `true` while this SCL is the active master.
    pub fn is_active_master(&self) -> bool {
        self.running
            .as_ref()
            .and_then(|running| running.master.as_ref())
            .is_some_and(|(master, _)| master.is_active())
    }

    /// The master the SCL is synced to, if any (not itself).
    pub fn synced_to(&self) -> Option<ScId> {
        self.running.as_ref().and_then(|r| r.tracker.master())
    }

    /// The global time at `now`, if it has one.
    pub fn global_time(&self, now: Instant) -> Option<u64> {
        self.running.as_ref().and_then(|r| r.global_time(now))
    }

    /// The age at `now` of the value consumed on `sc_id`, while it is valid.
    pub fn age(&self, sc_id: ScId, now: Instant) -> Option<Duration> {
        self.running
            .as_ref()?
            .streams
            .iter()
            .find_map(|stream| match stream {
                Stream::Consume {
                    sc_id: id, value, ..
                } if *id == sc_id => value.age(now),
                _ => None,
            })
    }

    /// Checks the objects against the process image and builds the blocks' values: the SDD,
    /// the cycle with every producer's slot (produced and consumed SC-IDs), the mapped
    /// objects. `count` entries are taken (a write of 5E01h checks the count it would set).
    fn build(&self, count: u8, image: &ProcessImage) -> Result<Built<E>, Refusal> {
        let objects = &self.objects;
        let mut entries: Vec<Entry, E> = Vec::new();
        let mut slots: Vec<(ScId, u16), E> = Vec::new();
        let mut streams: Vec<Stream, E> = Vec::new();
        for (index, raw) in objects.entries.iter().take(usize::from(count)).enumerate() {
            // At most E ≤ 80 entries: `n` fits a byte.
            let n = index as u8 + 1;
            let sc_id =
                ScId::new(raw.sc_id).ok_or(Refusal::inconsistent(n, AbortCode::InvalidValue))?;
            let hash = NodeHash(raw.hash);
            let role = match raw.role {
                ROLE_PRODUCE => Role::Produce { slot: raw.slot },
                ROLE_CONSUME => Role::Consume {
                    timeout: Duration::from_millis(u64::from(raw.timeout_ms)),
                },
                ROLE_MASTER => Role::Master,
                _ => return Err(Refusal::inconsistent(n, AbortCode::InvalidValue)),
            };
            let stream = match role {
                Role::Produce { slot } => Some(Stream::Produce {
                    sc_id,
                    hash,
                    slot,
                    span: mapped_span(raw.mapped, Mappable::Transmit, image, n)?,
                    sent: None,
                    pending_until: None,
                }),
                Role::Consume { timeout } => Some(Stream::Consume {
                    sc_id,
                    span: mapped_span(raw.mapped, Mappable::Receive, image, n)?,
                    value: ConsumedValue::new(timeout),
                }),
                Role::Master => None,
            };
            let overflow = Refusal::inconsistent(n, AbortCode::ValueTooHigh);
            if let Some(stream) = stream {
                // The consumer needs the producer's slot to judge timeliness (section 5).
                slots.push((sc_id, raw.slot)).map_err(|_| overflow)?;
                streams.push(stream).map_err(|_| overflow)?;
            }
            entries
                .push(Entry { sc_id, hash, role })
                .map_err(|_| overflow)?;
        }
        let sdd = Sdd::new(&entries).map_err(|error| {
            let sc_id = match error {
                sdd::SddError::DuplicateScId { sc_id } | sdd::SddError::Timeout { sc_id } => {
                    Some(sc_id)
                }
                sdd::SddError::TooManyEntries { .. } | sdd::SddError::OverCapacity { .. } => None,
            };
            Refusal::inconsistent(entry_of(&entries, sc_id), AbortCode::ParameterIncompatible)
        })?;
        let schedule =
            Schedule::new(objects.slots, objects.sync_every, &slots).map_err(|error| {
                use crate::simplecan::schedule::ScheduleError::*;
                let sc_id = match error {
                    SlotNotForProducers { sc_id, .. }
                    | ScIdTwice { sc_id }
                    | TooManyProducers { sc_id, .. } => Some(sc_id),
                    SlotTaken { second, .. } => Some(second),
                    SlotCount { .. } | SyncInterval { .. } | ResidualErrorRate { .. } => None,
                };
                Refusal::inconsistent(entry_of(&entries, sc_id), AbortCode::ParameterIncompatible)
            })?;
        let master = if objects.potential_master == 1 {
            let id = sdd
                .lowest_produced()
                .ok_or(Refusal::inconsistent(0, AbortCode::ParameterIncompatible))?;
            // The lowest produced SC-ID is in the SDD, so its hash is known.
            let hash = sdd
                .entry(id)
                .map(|entry| entry.hash)
                .ok_or(Refusal::inconsistent(0, AbortCode::ParameterIncompatible))?;
            Some((id, hash))
        } else {
            None
        };
        Ok(Built {
            sdd,
            schedule,
            streams,
            master,
        })
    }

    /// Puts every consumed value in `image` to 0 (SC_REQ_05).
    fn clear_consumed(&self, image: &mut ProcessImage) {
        if let Some(running) = &self.running {
            for stream in &running.streams {
                if let Stream::Consume { span, .. } = stream {
                    image.clear(*span);
                }
            }
        }
    }

    /// A fault of its own concerning the packets on identifier `named` (an SC-ID, or 2Fh for
    /// syncs; EMCY byte 0, as an SRDO's EMCY names the SRDO): its values to the safe state,
    /// then the shell's latch.
    fn fault<S: Sink>(&mut self, cause: Cause, emergency: u16, named: u8, slot: &mut Slot<'_, S>) {
        let cause = SafeStateCause::Protocol {
            code: emergency,
            cause: cause.code(),
            named,
        };
        let latched = slot.latched();
        self.enter_safe_state(slot.image_mut(), cause, latched);
        self.withdraw_pending(slot);
        slot.latch(cause);
    }

    /// Withdraws everything handed to the controller and not yet confirmed (SC_REQ_40: no
    /// safety communication in the safe state).
    fn withdraw_pending<S: Sink>(&mut self, slot: &mut Slot<'_, S>) {
        let Some(running) = &mut self.running else {
            return;
        };
        if running.sync_pending {
            running.sync_pending = false;
            slot.abort(SYNC_IDENTIFIER);
        }
        for stream in running.streams.iter_mut() {
            if let Stream::Produce {
                sc_id,
                pending_until,
                ..
            } = stream
                && pending_until.take().is_some()
            {
                slot.abort(data_identifier(*sc_id));
            }
        }
    }

    fn on_sync<S: Sink>(&mut self, now: Instant, sync: SyncPacket, slot: &mut Slot<'_, S>) {
        let Some(running) = &mut self.running else {
            return;
        };
        if let Err(several) = running.monitor.on_sync(now, sync.master()) {
            // Named: the master that kept sending.
            let named = several.higher.raw();
            self.fault(
                Cause::SimpleCanSeveralMasters,
                code::PROTOCOL_ERROR,
                named,
                slot,
            );
            return;
        }
        let change = running.tracker.on_sync(now, &sync);
        if let Some((master, _)) = &mut running.master {
            if let Some(Action::Abort) = master.on_sync(now, sync.master()) {
                running.sync_pending = false;
                self.counters.syncs_aborted += 1;
                slot.abort(SYNC_IDENTIFIER);
            }
            if let (Some(Change::Synced { .. }), Some(global)) =
                (change, running.tracker.global_time(now))
            {
                master.on_synced(now, global);
            }
        }
    }

    fn on_data<S: Sink>(&mut self, now: Instant, packet: DataPacket, slot: &mut Slot<'_, S>) {
        let Some(running) = &mut self.running else {
            return;
        };
        let global = running.global_time(now);
        let Some(Stream::Consume { span, value, .. }) = running.streams.iter_mut().find(
            |stream| matches!(stream, Stream::Consume { sc_id, .. } if *sc_id == packet.sc_id),
        ) else {
            // An SC-ID it produces or only checks syncs of: nothing to deliver.
            return;
        };
        let Some(global) = global else {
            self.counters.discarded_unsynced += 1;
            return;
        };
        match running
            .schedule
            .timely(packet.sc_id, packet.cycle_stamp, global)
        {
            Ok(start) => {
                value.accept(packet.value, local_of(now, global, start));
                slot.image_mut().put_le(*span, u64::from(value.value(now)));
                self.counters.accepted += 1;
            }
            Err(_) => self.counters.untimely += 1,
        }
    }
}

/// The entry number (1-based) of `sc_id` among `entries`, or 0.
fn entry_of(entries: &[Entry], sc_id: Option<ScId>) -> u8 {
    sc_id
        .and_then(|id| entries.iter().position(|entry| entry.sc_id == id))
        // At most 80 entries.
        .map_or(0, |index| index as u8 + 1)
}

/// The process image span of mapped object `mapped` (`index << 16 | sub << 8 | bits`):
/// an application object of exactly that many bits, at most 32 (a SimpleCAN value,
/// section 2), mappable in `direction`.
fn mapped_span(
    mapped: u32,
    direction: Mappable,
    image: &ProcessImage,
    entry: u8,
) -> Result<Span, Refusal> {
    let [bits, sub, index_low, index_high] = mapped.to_le_bytes();
    let address = Address::new(u16::from_le_bytes([index_low, index_high]), sub);
    let (object, span) = image
        .find(address)
        .ok_or(Refusal::inconsistent(entry, AbortCode::NoObject))?;
    if object.mappable != direction || u32::from(object.len) * 8 != u32::from(bits) || bits > 32 {
        return Err(Refusal::inconsistent(entry, AbortCode::NotMappable));
    }
    Ok(span)
}

/// The local instant at which the global time is `global`, when it is `global_now` at `now`.
fn local_of(now: Instant, global_now: u64, global: u64) -> Instant {
    if global >= global_now {
        now.saturating_add(Duration::from_micros(global - global_now))
    } else {
        Instant::from_micros(now.as_micros().saturating_sub(global_now - global))
    }
}

impl<const E: usize> Running<E> {
    /// The global time: the active master's own, else the tracker's while synced.
    fn global_time(&self, now: Instant) -> Option<u64> {
        self.master
            .as_ref()
            .and_then(|(master, _)| master.global_time(now))
            .or_else(|| self.tracker.global_time(now))
    }
}

/// The stored image of a SimpleCAN layer of `E` entries: `E` times the bytes one entry needs
/// (the entry and, counted once per entry, the shell's fixed part with this section's own).
pub type SimpleCanImage<const E: usize> = RowImage<IMAGE_PER_ENTRY, E>;

/// Bytes of the stored image per entry: the entry itself and the shell's fixed part with
/// this section's own (the shell's header, salt, hash, change counter, the two audit
/// signatures of 4 bytes, the heartbeat time: 66 bytes, and the LSS settings with the `lss`
/// feature; 15 of its own) counted once per entry, which covers it for any layer of at
/// least one entry.
const IMAGE_PER_ENTRY: usize = ENTRY_STORED + 66 + persist::LSS_LEN + FIXED_STORED;

impl<const E: usize> SafetyProtocol for SimpleCan<E> {
    const MAX_PERSISTED: usize = FIXED_STORED + E * ENTRY_STORED;

    type Image = SimpleCanImage<E>;

    fn image() -> SimpleCanImage<E> {
        RowImage::zeroed()
    }

    fn load_defaults(&mut self, _config: &NodeConfig) {
        self.objects = SimpleCanObjects::DEFAULT;
    }

    fn persist(&self, out: &mut [u8]) -> usize {
        let objects = &self.objects;
        let mut at = 0usize;
        let mut push = |bytes: &[u8]| {
            if let Some(target) = out.get_mut(at..at + bytes.len()) {
                target.copy_from_slice(bytes);
            }
            at += bytes.len();
        };
        push(&[objects.valid]);
        push(&objects.signature.to_le_bytes());
        push(&objects.slots.to_le_bytes());
        push(&objects.sync_every.to_le_bytes());
        push(&objects.buffering_us.to_le_bytes());
        // E ≤ 80 is checked when the layer is built.
        push(&[
            objects.enabled,
            objects.potential_master,
            objects.count,
            E as u8,
        ]);
        for entry in &objects.entries {
            push(&[entry.sc_id, entry.role]);
            push(&entry.slot.to_le_bytes());
            push(&entry.timeout_ms.to_le_bytes());
            push(&entry.hash.to_le_bytes());
            push(&entry.mapped.to_le_bytes());
        }
        at.min(out.len())
    }

    fn restore(&mut self, bytes: &[u8]) -> Result<(), PersistError> {
        self.objects = SimpleCanObjects::from_stored(bytes)?;
        Ok(())
    }

    fn withdraw_validation(&mut self) {
        self.objects.valid = 0;
    }

    fn owns(&self, index: u16) -> bool {
        Self::needs_unlock(index)
    }

    /// Every one of its objects is safety configuration (section 11).
    fn needs_unlock(index: u16) -> bool {
        (CYCLE_INDEX..=SIGNATURE_INDEX).contains(&index)
    }

    /// 5EFFh as two halves, least significant first.
    type Signatures = [u16; 2];

    const NO_SIGNATURES: [u16; 2] = [0; 2];

    fn validated_signatures(&self) -> Option<[u16; 2]> {
        let [a, b, c, d] = self.objects.signature.to_le_bytes();
        (self.objects.valid == CONFIGURATION_VALID)
            .then_some([u16::from_le_bytes([a, b]), u16::from_le_bytes([c, d])])
    }

    fn read(&mut self, address: Address, buf: &mut [u8]) -> Result<usize, AbortCode> {
        let objects = &self.objects;
        let Address { index, sub } = address;
        match index {
            CYCLE_INDEX => match sub {
                0 => put(buf, &[5]),
                1 => put(buf, &objects.slots.to_le_bytes()),
                2 => put(buf, &objects.sync_every.to_le_bytes()),
                3 => put(buf, &objects.buffering_us.to_le_bytes()),
                4 => put(buf, &[objects.enabled]),
                5 => put(buf, &[objects.potential_master]),
                _ => Err(AbortCode::NoSubIndex),
            },
            COUNT_INDEX if sub == 0 => put(buf, &[objects.count]),
            VALID_INDEX if sub == 0 => put(buf, &[objects.valid]),
            SIGNATURE_INDEX if sub == 0 => put(buf, &objects.signature.to_le_bytes()),
            COUNT_INDEX | VALID_INDEX | SIGNATURE_INDEX => Err(AbortCode::NoSubIndex),
            _ => {
                let entry = entry_objects(&objects.entries, index).ok_or(AbortCode::NoObject)?;
                match sub {
                    0 => put(buf, &[6]),
                    1 => put(buf, &[entry.sc_id]),
                    2 => put(buf, &[entry.role]),
                    3 => put(buf, &entry.slot.to_le_bytes()),
                    4 => put(buf, &entry.timeout_ms.to_le_bytes()),
                    5 => put(buf, &entry.hash.to_le_bytes()),
                    6 => put(buf, &entry.mapped.to_le_bytes()),
                    _ => Err(AbortCode::NoSubIndex),
                }
            }
        }
    }

    /// Only in Pre-operational (SC_REQ_39: the device is then in its safe state; in Stopped
    /// the shell serves no SDO). The value is checked before anything changes; an accepted
    /// write to 5E00h..5E5Fh withdraws the validation (5EFEh = 0).
    fn write(
        &mut self,
        address: Address,
        data: &[u8],
        image: &ProcessImage,
        operational: bool,
    ) -> Result<(), AbortCode> {
        let Address { index, sub } = address;
        // The object and sub-index exist (and sub-index 0 of a record is read-only) before
        // the state is looked at, as for every other object.
        let mut scratch = [0u8; 4];
        let held = self.read(address, &mut scratch)?;
        if sub == 0 && (index == CYCLE_INDEX || index >= FIRST_ENTRY_INDEX) && index < VALID_INDEX {
            return Err(AbortCode::ReadOnly);
        }
        if operational {
            return Err(AbortCode::DeviceState);
        }
        // The object's length (as it reads) before its value, or whether it may change now:
        // a value of the wrong length is the request's fault (CiA 301 7.2.4.3.17).
        length(data, held)?;
        let objects = &mut self.objects;
        match (index, sub) {
            (CYCLE_INDEX, 1) => {
                let slots = u16::from_le_bytes(exact(data)?);
                objects.slots = within(slots, MIN_SLOTS, MAX_SLOTS)?;
            }
            (CYCLE_INDEX, 2) => {
                let k = u16::from_le_bytes(exact(data)?);
                let interval = u64::from(k) * u64::from(objects.slots) * SLOT.as_micros();
                within(
                    interval,
                    MIN_SYNC_INTERVAL.as_micros(),
                    MAX_SYNC_INTERVAL.as_micros(),
                )?;
                objects.sync_every = k;
            }
            (CYCLE_INDEX, 3) => objects.buffering_us = u16::from_le_bytes(exact(data)?),
            (CYCLE_INDEX, 4) => objects.enabled = within(exact::<1>(data)?[0], 0, 1)?,
            (CYCLE_INDEX, 5) => objects.potential_master = within(exact::<1>(data)?[0], 0, 1)?,
            (COUNT_INDEX, _) => {
                let [count] = exact(data)?;
                if usize::from(count) > E {
                    return Err(AbortCode::ValueTooHigh);
                }
                // The count last: every entry it takes in is checked (section 11). 0 is
                // always accepted: it is how the entries are opened for a change.
                if count != 0 {
                    self.build(count, image).map_err(|refusal| refusal.abort)?;
                }
                self.objects.count = count;
            }
            (VALID_INDEX, _) => {
                objects.valid = exact::<1>(data)?[0];
                return Ok(());
            }
            (SIGNATURE_INDEX, _) => {
                objects.signature = u32::from_le_bytes(exact(data)?);
                return Ok(());
            }
            _ => {
                if objects.count != 0 {
                    // As a PDO mapping: the entries change only while none is in use.
                    return Err(AbortCode::UnsupportedAccess);
                }
                let entry =
                    entry_objects_mut(&mut objects.entries, index).ok_or(AbortCode::NoObject)?;
                match sub {
                    1 => {
                        let [raw] = exact(data)?;
                        entry.sc_id = within(raw, ScId::LOWEST.raw(), ScId::HIGHEST.raw())?;
                    }
                    2 => entry.role = within(exact::<1>(data)?[0], ROLE_PRODUCE, ROLE_MASTER)?,
                    3 => {
                        let slot = u16::from_le_bytes(exact(data)?);
                        entry.slot = within(slot, 0, MAX_SLOTS - 3)?;
                    }
                    4 => {
                        let timeout = u16::from_le_bytes(exact(data)?);
                        let most = sdd::MAX_TIMEOUT.as_micros() / 1000;
                        entry.timeout_ms = within(u64::from(timeout), 0, most)? as u16;
                    }
                    5 => entry.hash = u32::from_le_bytes(exact(data)?),
                    _ => entry.mapped = u32::from_le_bytes(exact(data)?),
                }
            }
        }
        if index <= LAST_CONFIGURATION_INDEX {
            self.objects.valid = 0;
        }
        Ok(())
    }

    /// With SimpleCAN disabled, nothing to check and nothing runs. Enabled: 5EFEh = A5h, the
    /// signature, then the SDD and the cycle (SC_REQ_16, SC_REQ_34); every packet then waits
    /// for a global time (SC_REQ_29).
    fn start<S: Sink>(&mut self, now: Instant, slot: &mut Slot<'_, S>) -> Result<(), Refused> {
        self.counters = SimpleCanCounters::default();
        if self.objects.enabled == 0 {
            return Ok(());
        }
        let checked = if self.objects.valid != CONFIGURATION_VALID {
            Err(Refusal {
                cause: Cause::SimpleCanNotValidated,
                entry: 0,
                abort: AbortCode::ParameterIncompatible,
            })
        } else if self.objects.signature(slot.node_id().raw()) != self.objects.signature {
            Err(Refusal {
                cause: Cause::SimpleCanSignature,
                entry: 0,
                abort: AbortCode::ParameterIncompatible,
            })
        } else {
            self.build(self.objects.count, slot.image())
        };
        let built = match checked {
            Ok(built) => built,
            Err(refusal) => {
                // Refused here, so 5EFEh must not go on reading A5h (as 13FEh,
                // EN 50325-5 6.4.1.6); the stored value stays as written.
                self.withdraw_validation();
                let cause = refusal.cause.code();
                return Err(slot.refuse_configuration(
                    [0, cause, refusal.entry, 0, 0],
                    Event::ProtocolConfigurationRefused {
                        cause,
                        detail: refusal.entry,
                    },
                ));
            }
        };
        let Built {
            sdd,
            schedule,
            streams,
            master,
        } = built;
        let buffering = Duration::from_micros(u64::from(self.objects.buffering_us));
        let tracker = SyncTracker::new(schedule.cycle(), buffering);
        let master = master.map(|(id, hash)| (Master::new(id, &schedule, now), hash));
        self.running = Some(Running {
            sdd,
            schedule,
            tracker,
            master,
            monitor: MasterMonitor::new(),
            bad_crc: BadCrcCounter::new(now),
            streams,
            sync_pending: false,
        });
        // Every consumed value is 0 until its first timely packet (SC_REQ_05, SC_REQ_29).
        self.clear_consumed(slot.image_mut());
        slot.wake_at(now);
        Ok(())
    }

    fn stop(&mut self, image: &mut ProcessImage) {
        self.clear_consumed(image);
        self.running = None;
    }

    fn reset(&mut self) {
        self.counters = SimpleCanCounters::default();
    }

    /// Every frame on 02Fh..07Fh is its own; used only while it runs and the device is not
    /// in its safe state (SC_REQ_40).
    fn on_frame<S: Sink>(
        &mut self,
        now: Instant,
        frame: &CanFrame,
        slot: &mut Slot<'_, S>,
    ) -> bool {
        if !is_simplecan(frame.id()) {
            return false;
        }
        let Some(running) = &mut self.running else {
            return true;
        };
        if slot.latched() {
            return true;
        }
        match decode(frame, &running.sdd) {
            Ok(Packet::Sync(sync)) => self.on_sync(now, sync, slot),
            Ok(Packet::Data(packet)) => self.on_data(now, packet, slot),
            Err(error) => {
                self.counters.rejected = self.counters.rejected.saturating_add(1);
                if error.is_bad_crc() && running.bad_crc.bad_packet(now) == Verdict::Tripped {
                    // Named: the identifier of the packet that tripped it (02Fh..07Fh).
                    let named = frame.id().raw() as u8;
                    self.fault(Cause::SimpleCanBadCrc, code::PROTOCOL_ERROR, named, slot);
                }
            }
        }
        let latched = slot.latched();
        slot.wake_at(self.deadline(now, latched));
        true
    }

    fn poll<S: Sink>(&mut self, now: Instant, slot: &mut Slot<'_, S>) {
        if slot.latched() {
            // SC_REQ_40: what was still queued when the shell latched goes too.
            self.withdraw_pending(slot);
            return;
        }
        let Some(running) = &mut self.running else {
            return;
        };
        running.bad_crc.poll(now);
        // Unsynced again (SC_REQ_32) shows in the global time below.
        let _ = running.tracker.poll(now);
        if let Some((master, hash)) = &mut running.master {
            match master.poll(now) {
                Some(Action::Send(sync)) => {
                    running.sync_pending = true;
                    slot.transmit(sync.encode(*hash));
                }
                Some(Action::Abort) => {
                    running.sync_pending = false;
                    self.counters.syncs_aborted += 1;
                    slot.abort(SYNC_IDENTIFIER);
                }
                None => {}
            }
        }
        let global = running.global_time(now);
        let cycle = running.schedule.cycle();
        let mut timed_out = None;
        for stream in running.streams.iter_mut() {
            match stream {
                Stream::Produce {
                    sc_id,
                    hash,
                    slot: own,
                    span,
                    sent,
                    pending_until,
                } => {
                    if pending_until.is_some_and(|until| expired(until, now)) {
                        // Not on the bus by the end of its slot (section 5).
                        *pending_until = None;
                        self.counters.aborted += 1;
                        slot.abort(data_identifier(*sc_id));
                    }
                    let Some(global) = global else {
                        continue; // SC_REQ_29: no global time, nothing sent.
                    };
                    let (number, current) = cycle.position(global);
                    if current != *own || *sent == Some(number) {
                        continue;
                    }
                    let mut bytes = [0u8; 4];
                    let value = slot.image().get(*span);
                    bytes[..value.len().min(4)].copy_from_slice(&value[..value.len().min(4)]);
                    let packet = DataPacket {
                        sc_id: *sc_id,
                        value: u32::from_le_bytes(bytes),
                        // The stamp is the cycle number modulo 256 (section 2).
                        cycle_stamp: number as u8,
                    };
                    *sent = Some(number);
                    let end = cycle.slot_start(number, *own) + SLOT.as_micros();
                    *pending_until = Some(local_of(now, global, end));
                    slot.transmit(packet.encode(*hash));
                }
                Stream::Consume {
                    sc_id, span, value, ..
                } => {
                    if value.poll(now) == Age::TimedOut {
                        slot.image_mut().clear(*span);
                        // Named: the first SC-ID found at its timeout.
                        timed_out = timed_out.or(Some(sc_id.raw()));
                    }
                }
            }
        }
        if let Some(named) = timed_out {
            self.fault(Cause::SimpleCanTimeout, code::RPDO_TIMEOUT, named, slot);
        }
    }

    fn deadline(&self, now: Instant, latched: bool) -> Instant {
        let Some(running) = &self.running else {
            return Instant::NEVER;
        };
        let pending = running.sync_pending
            || running.streams.iter().any(|stream| {
                matches!(
                    stream,
                    Stream::Produce {
                        pending_until: Some(_),
                        ..
                    }
                )
            });
        if latched {
            return if pending { now } else { Instant::NEVER };
        }
        let mut next = running.bad_crc.deadline().min(running.tracker.deadline());
        if let Some((master, _)) = &running.master {
            next = next.min(master.deadline());
        }
        let global = running.global_time(now);
        let cycle = running.schedule.cycle();
        for stream in &running.streams {
            let due = match stream {
                Stream::Produce {
                    slot: own,
                    sent,
                    pending_until,
                    ..
                } => {
                    let send = global.map_or(Instant::NEVER, |global| {
                        let (number, current) = cycle.position(global);
                        let start = if current == *own && *sent != Some(number) {
                            global
                        } else {
                            cycle.next_slot(global.saturating_add(1), *own).1
                        };
                        local_of(now, global, start)
                    });
                    send.min(pending_until.unwrap_or(Instant::NEVER))
                }
                Stream::Consume { value, .. } => value.deadline(),
            };
            next = next.min(due);
        }
        next
    }

    /// Every consumed value to 0 (SC_REQ_05); sending stops while latched (SC_REQ_40), for
    /// every cause: SimpleCAN has no producer that may keep sending.
    fn enter_safe_state(
        &mut self,
        image: &mut ProcessImage,
        _cause: SafeStateCause,
        already_latched: bool,
    ) {
        if !already_latched {
            self.clear_consumed(image);
        }
    }

    fn object_changed(&mut self, _offset: u8) -> bool {
        // Produced values are sent in their slot, never on change (section 5).
        false
    }

    fn on_transmitted<S: Sink>(&mut self, now: Instant, frame: &CanFrame, slot: &mut Slot<'_, S>) {
        let Some(running) = &mut self.running else {
            return;
        };
        let id = frame.id();
        if id == SYNC_IDENTIFIER && running.sync_pending {
            running.sync_pending = false;
            self.counters.syncs_sent += 1;
            if let Some((master, _)) = &mut running.master {
                master.on_transmitted();
                // Its own sync counts for the several-masters check too (SC_REQ_26).
                if let Some(own) = running.sdd.lowest_produced()
                    && let Err(several) = running.monitor.on_sync(now, own)
                {
                    let named = several.higher.raw();
                    self.fault(
                        Cause::SimpleCanSeveralMasters,
                        code::PROTOCOL_ERROR,
                        named,
                        slot,
                    );
                }
            }
            return;
        }
        for stream in running.streams.iter_mut() {
            if let Stream::Produce {
                sc_id,
                pending_until,
                ..
            } = stream
                && data_identifier(*sc_id) == id
                && pending_until.take().is_some()
            {
                self.counters.sent += 1;
            }
        }
    }

    /// The other channel's sync (or data packet) on the bus stands for this one's (Model A):
    /// confirmed as [`SafetyProtocol::on_transmitted`] confirms, and for a sync of this master
    /// its time base moves to the other channel's: the global time at `heard` is that sync's
    /// (its cycle, the offset it carries) plus the buffering time this SCL states (5E00h:03),
    /// as a receiver takes a sync's time (SC_REQ_33), and at `now` that plus the time since.
    /// The caller has checked the sync against this channel's own
    /// (`dual_channel::simplecan::transmit`).
    fn on_partner_transmitted<S: Sink>(
        &mut self,
        now: Instant,
        heard: Instant,
        frame: &CanFrame,
        slot: &mut Slot<'_, S>,
    ) {
        let buffering = u64::from(self.objects.buffering_us);
        let aligned = self.running.as_ref().and_then(|running| {
            let (master, _) = running.master.as_ref()?;
            let cycle = master.confirming_cycle()?;
            let schedule = running.schedule.cycle();
            if frame.id() != SYNC_IDENTIFIER || !running.sync_pending {
                return None;
            }
            let data = frame.raw_data();
            let offset = u64::from(u16::from_be_bytes([data[3], data[4]]));
            let start = schedule.slot_start(cycle, schedule.sync_slot());
            let since_heard = now.saturating_since(heard).as_micros();
            Some(start + offset + buffering + since_heard)
        });
        self.on_transmitted(now, frame, slot);
        if let (Some(global), Some(running)) = (aligned, &mut self.running)
            && let Some((master, _)) = &mut running.master
        {
            master.align(now, global);
            let latched = slot.latched();
            slot.wake_at(self.deadline(now, latched));
        }
    }
}

/// `value` when it lies in `low..=high`; otherwise the abort code that says which side.
fn within<T: PartialOrd>(value: T, low: T, high: T) -> Result<T, AbortCode> {
    if value < low {
        Err(AbortCode::ValueTooLow)
    } else if value > high {
        Err(AbortCode::ValueTooHigh)
    } else {
        Ok(value)
    }
}

/// The entry at `index` (5E10h + n − 1), if this device holds entry n.
fn entry_objects(entries: &[EntryObjects], index: u16) -> Option<&EntryObjects> {
    let n = usize::from(index.checked_sub(FIRST_ENTRY_INDEX)?);
    entries.get(n).filter(|_| index <= LAST_CONFIGURATION_INDEX)
}

fn entry_objects_mut(entries: &mut [EntryObjects], index: u16) -> Option<&mut EntryObjects> {
    let n = usize::from(index.checked_sub(FIRST_ENTRY_INDEX)?);
    if index > LAST_CONFIGURATION_INDEX {
        return None;
    }
    entries.get_mut(n)
}
