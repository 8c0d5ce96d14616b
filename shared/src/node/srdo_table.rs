//! The CANopen Safety SRDO table (EN 50325-5 7.1, CiA 304 9.5): the safety protocol in the
//! node's slot ([`SafetyProtocol`]). It owns the SRDO records (0x1301..0x1340,
//! 0x1381..0x13C0, 0x13FE, 0x13FF) and the double-reception counters
//! ([`DOUBLE_RECEPTION_INDEX`]), runs the producers and consumers in Operational, checks its
//! own derived tables against its records ([`integrity`]), and persists its records.

mod integrity;

use heapless::Vec;

use super::dictionary::put;
use super::persist::{self, Reader};
use super::slot::{Refused, RowImage, SafetyProtocol, Slot};
use super::{ApiError, Event, NodeConfig, PersistError, SafeStateCause, Sink};
use crate::canopen::od::{AbortCode, Address};
use crate::frame::CanFrame;
use crate::process_image::ProcessImage;
use crate::safety::MAX_SRDOS;
use crate::safety::config::{
    CONFIGURATION_VALID, MAX_MAPPING_ENTRIES, ResolvedMapping, SafetyConfig, SrdoRecord,
};
use crate::safety::srdo::{
    self, Consumer, Discarded, InvertedOutcome, PlainOutcome, Producer, SrdoFault, SrdoFaultCause,
};
use crate::safety::types::{Direction, SrdoNumber};
use crate::time::Instant;

pub use integrity::{IDLE_PERIOD as INTEGRITY_IDLE_PERIOD, IntegrityFault};

/// Run-time state of one SRDO in Operational.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Role {
    /// Not running.
    Idle,
    /// Producing.
    Producer(Producer),
    /// Consuming.
    Consumer(Consumer),
}

/// One SRDO slot at run time: its resolved mapping, its state machine and a pair counter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct SrdoRuntime {
    pub(super) mapping: ResolvedMapping,
    pub(super) role: Role,
    pub(super) pairs: u32,
}

impl SrdoRuntime {
    pub(super) const IDLE: SrdoRuntime = SrdoRuntime {
        mapping: ResolvedMapping::EMPTY,
        role: Role::Idle,
        pairs: 0,
    };
}

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

/// RAM per SRDO, in bytes: its run-time state with the resolved mapping (`SrdoRuntime`) and
/// its configuration record. The identifier table (128 bytes) and the rest of the node are per
/// node, not per SRDO. `cargo xtask bench` reports the figure measured in the thumbv7em image.
pub const RAM_PER_SRDO: usize =
    core::mem::size_of::<SrdoRuntime>() + core::mem::size_of::<SrdoRecord>();

// The target per SRDO, against the reference C stack's figure on Cortex-M4: both in
// docs/performance.md. Checked at compile time on every target, so the cross build proves it
// for thumbv7em.
const _: () = assert!(RAM_PER_SRDO <= 160, "more than 160 bytes of RAM per SRDO");

/// Entry of the identifier table: the slot in the low 7 bits plus one (0: not ours; slots
/// `0..64` give `1..=64`), bit 7 set for the inverted frame. Whether the SRDO transmits is its
/// run-time role's to say (a frame on a producer's own identifier reaches no consumer).
pub(super) const LOOKUP_INVERTED: u8 = 0x80;
const LOOKUP_SLOT: u8 = 0x7F;
/// First identifier of the SRDO range ([`SRDO_IDENTIFIERS`](crate::safety::types::SRDO_IDENTIFIERS)).
pub(super) const SRDO_ID_BASE: u16 = *crate::safety::types::SRDO_IDENTIFIERS.start();
/// Identifiers in the SRDO range (128).
pub(super) const SRDO_IDS: usize =
    (*crate::safety::types::SRDO_IDENTIFIERS.end() - SRDO_ID_BASE + 1) as usize;

/// Bytes of one stored SRDO record without its mapping entries.
const RECORD_FIXED: usize = 1 + 2 + 1 + 4 + 4 + 1 + 2;

/// The CANopen Safety SRDO table of a device with `N` SRDOs (`1..=64`): its configuration
/// (the SRDO records, 0x13FE) and, in Operational, one producer or consumer per existing SRDO.
///
/// Stored section (after the shell's header in the stored parameter image), integers
/// little-endian:
///
/// | bytes | field |
/// |-------|-------|
/// | 1 | 0x13FE configuration valid |
/// | 1 | number of SRDO records `N` |
/// | per SRDO | direction (1), refresh time / SCT (2), SRVT (1), COB-ID 1 (4), COB-ID 2 (4), mapping count (1), that many entries (4 each), signature (2) |
#[derive(Clone, Debug)]
pub struct SrdoTable<const N: usize> {
    pub(super) safety: SafetyConfig<N>,
    pub(super) runtime: [SrdoRuntime; N],
    pub(super) active: Vec<u8, N>,
    pub(super) lookup: [u8; SRDO_IDS],
    pub(super) integrity: integrity::Integrity,
    /// In Operational with a configuration that passed the Operational-entry check: SRDOs
    /// are disabled otherwise (EN 50325-5 8.2.2).
    running: bool,
    /// The producers stopped for good until NMT reset (their own halves disagreed, or the
    /// data behind them is in doubt).
    producers_halted: bool,
    /// Transmit an SRDO as soon as its mapped data changes (EN 50325-5 6.2.1).
    event_driven: bool,
    remote_frames_ignored: u32,
    double_reception: DoubleReception,
    /// The earliest timer of the running SRDOs as the last poll left them: what
    /// [`SafetyProtocol::deadline`] answers without a second pass over the SRDOs, when
    /// [`SrdoTable::next_timer_judged`] holds.
    next_timer: Instant,
    /// For which device state the last poll judged [`SrdoTable::next_timer`]; stale when
    /// anything since may have moved a timer (a frame, a changed object, the safe state, a
    /// start or stop), and then the deadline is computed.
    next_timer_judged: Judged,
}

/// For which device state [`SrdoTable::next_timer`] was judged: one byte the deadline compares
/// with the state it is asked for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
enum Judged {
    /// Judged with the device out of its latched safe state.
    Unlatched,
    /// Judged with the device in its latched safe state.
    Latched,
    /// Something may have moved a timer since.
    Stale,
}

impl Judged {
    /// Judged with the device latched (`true`) or not.
    #[inline]
    fn when(latched: bool) -> Self {
        if latched {
            Judged::Latched
        } else {
            Judged::Unlatched
        }
    }
}

impl<const N: usize> SrdoTable<N> {
    /// The table of the device `config` describes, stopped, with the pre-defined connection
    /// set. `None` when `N` is 0 (a CANopen Safety device without an SRDO) or more than
    /// [`MAX_SRDOS`].
    pub fn new(config: &NodeConfig) -> Option<Self> {
        if N == 0 {
            return None;
        }
        Self::beside(config)
    }

    /// The table beside another safety protocol, as [`SrdoTable::new`] builds it, except that
    /// it may hold no SRDO (`N` = 0): it then serves 13FEh and 13FFh:00 = 0, validates and
    /// starts like any other, and sends and accepts no SRDO. That is the table of a device
    /// that speaks SimpleCAN instead of SRDOs ([`SrdoAndSimpleCan`](super::SrdoAndSimpleCan)).
    /// `None` when `N` is more than [`MAX_SRDOS`].
    pub fn beside(config: &NodeConfig) -> Option<Self> {
        if N > MAX_SRDOS {
            return None;
        }
        Some(SrdoTable {
            safety: Self::defaults(config),
            runtime: [SrdoRuntime::IDLE; N],
            active: Vec::new(),
            lookup: [0; SRDO_IDS],
            integrity: integrity::Integrity::IDLE,
            running: false,
            producers_halted: false,
            event_driven: config.event_driven,
            remote_frames_ignored: 0,
            double_reception: DoubleReception::default(),
            next_timer: Instant::NEVER,
            next_timer_judged: Judged::Stale,
        })
    }

    /// The pre-defined connection set for this device.
    fn defaults(config: &NodeConfig) -> SafetyConfig<N> {
        SafetyConfig::predefined(
            config.node_id.raw(),
            config.default_transmit_mapping,
            config.default_receive_mapping,
        )
    }

    /// The safety configuration (objects 0x1301..0x13FF).
    pub fn config(&self) -> &SafetyConfig<N> {
        &self.safety
    }

    /// Valid pairs received (consumer) or sent (producer) by `srdo` since entering Operational.
    pub fn pairs(&self, srdo: SrdoNumber) -> u32 {
        self.runtime
            .get(srdo.index())
            .map_or(0, |runtime| runtime.pairs)
    }

    /// Remote frames ignored on SRDO identifiers since power-on or reset.
    pub fn remote_frames_ignored(&self) -> u32 {
        self.remote_frames_ignored
    }

    /// Frames the consumers discarded as double receptions, since power-on or reset.
    pub fn double_reception(&self) -> DoubleReception {
        self.double_reception
    }

    /// The resolved mapping of transmit SRDO `srdo`: the running one in Operational, otherwise
    /// resolved from its (valid) configuration.
    pub(super) fn transmit_mapping(
        &self,
        srdo: SrdoNumber,
        image: &ProcessImage,
    ) -> Result<ResolvedMapping, ApiError> {
        let index = srdo.index();
        if let Some(SrdoRuntime {
            mapping,
            role: Role::Producer(_),
            ..
        }) = self.runtime.get(index)
        {
            return Ok(*mapping);
        }
        let record = self
            .safety
            .srdos
            .get(index)
            .ok_or(ApiError::NotATransmitSrdo)?;
        let others = self
            .safety
            .srdos
            .iter()
            .enumerate()
            .filter(|(i, _)| *i != index)
            .map(|(_, r)| r);
        match crate::safety::config::check_srdo(record, image, others) {
            Ok(valid) if valid.direction == Direction::Transmit => Ok(valid.mapping),
            _ => Err(ApiError::NotATransmitSrdo),
        }
    }

    /// Puts every received value in the safe state (0, SC_REQ_05). One copy for the safe
    /// state and for stopping.
    #[inline(never)]
    fn clear_received(&self, image: &mut ProcessImage) {
        for runtime in &self.runtime {
            if matches!(runtime.role, Role::Consumer(_)) {
                srdo::clear(image, &runtime.mapping);
            }
        }
    }

    /// A frame on an SRDO identifier at `offset` from [`SRDO_ID_BASE`], in Operational (the hot
    /// path of a consumer). Inlined into the device's frame handler on the host, where the
    /// caller's loop then saves and restores its registers once rather than per frame; out of
    /// line in the firmware images, which keep one copy.
    #[cfg_attr(not(target_os = "none"), inline(always))]
    #[cfg_attr(target_os = "none", inline)]
    fn on_srdo_frame<S: Sink>(
        &mut self,
        now: Instant,
        offset: usize,
        frame: &CanFrame,
        slot: &mut Slot<'_, S>,
    ) {
        let tag = self.lookup.get(offset).copied().unwrap_or(0);
        let position = usize::from(tag & LOOKUP_SLOT);
        if position == 0 {
            return; // Not an identifier this device uses.
        }
        let number = SrdoNumber::from_index(position - 1);
        if frame.is_remote() {
            // EN 50325-5 6.2.1: an SRDO is never requested by RTR; counted and ignored.
            self.remote_frames_ignored = self.remote_frames_ignored.saturating_add(1);
            slot.event(Event::RemoteFrameIgnored(number));
            return;
        }
        if slot.latched() {
            return; // Latched: nothing is delivered any more.
        }
        // The consumer holds its SCT and SRVT from the record (taken at the Operational entry
        // and compared with the record by the integrity check), so the record is not read here.
        let Some(runtime) = self.runtime.get_mut(position - 1) else {
            return;
        };
        let Role::Consumer(consumer) = &mut runtime.role else {
            return; // Our own identifiers (a producer's).
        };
        self.next_timer_judged = Judged::Stale;
        let len = runtime.mapping.len;
        let result = if tag & LOOKUP_INVERTED == 0 {
            consumer
                .on_plain(now, frame.raw_data(), frame.dlc(), len)
                .map(|outcome| match outcome {
                    PlainOutcome::Pending => {
                        slot.wake_at(consumer.deadline());
                        None
                    }
                    PlainOutcome::Discarded(discarded) => Some(discarded),
                })
        } else {
            // A `match`, not `Result::map` with a closure: the closure was compiled out of
            // line, and its call (registers saved, captures spilled) cost the validated pair
            // instructions (`cargo xtask bench`) and channel B's image flash.
            match consumer.on_inverted(now, frame.raw_data(), frame.dlc(), len) {
                Ok(InvertedOutcome::Pair { plain, inverted }) => {
                    srdo::deliver(slot.image_mut(), &runtime.mapping, plain, inverted);
                    runtime.pairs = runtime.pairs.wrapping_add(1);
                    slot.event(Event::SrdoReceived {
                        srdo: number,
                        data: plain & srdo::payload_mask(len),
                    });
                    Ok(None)
                }
                Ok(InvertedOutcome::Discarded(discarded)) => Ok(Some(discarded)),
                Err(cause) => Err(cause),
            }
        };
        match result {
            Ok(None) => {}
            Ok(Some(discarded)) => self.discarded(number, discarded, slot.reborrow()),
            Err(cause) => self.latch(
                SafeStateCause::Srdo(SrdoFault {
                    srdo: number,
                    cause,
                }),
                slot.reborrow(),
            ),
        }
    }

    /// Reports a frame a consumer discarded, and counts it when it is a double reception.
    /// Cold: kept out of the receive hot path.
    #[cold]
    #[inline(never)]
    fn discarded<S: Sink>(
        &mut self,
        srdo: SrdoNumber,
        discarded: Discarded,
        mut slot: Slot<'_, S>,
    ) {
        let counter = match discarded {
            Discarded::PlainRepeated => Some(&mut self.double_reception.plain_repeated),
            Discarded::InvertedWithoutPlain => {
                Some(&mut self.double_reception.inverted_without_plain)
            }
            // Not a double reception: reported by its event, not counted in 5C00h.
            Discarded::PlainReplacedBeforeFirstPair
            | Discarded::InvertedNotPairedBeforeFirstPair => None,
        };
        if let Some(counter) = counter {
            *counter = counter.saturating_add(1);
        }
        slot.event(Event::FrameDiscarded { srdo, discarded });
    }

    /// An SRDO failed (reported as [`Event::SrdoFault`]) or the integrity check found damage:
    /// this table in the safe state for `cause`, then the device's latched. Cold: kept out
    /// of the receive hot path.
    #[cold]
    #[inline(never)]
    fn latch<S: Sink>(&mut self, cause: SafeStateCause, mut slot: Slot<'_, S>) {
        if let SafeStateCause::Srdo(fault) = cause {
            slot.event(Event::SrdoFault(fault));
        }
        let already_latched = slot.latched();
        self.enter_safe_state(slot.image_mut(), cause, already_latched);
        slot.latch(cause);
    }

    /// Every running SRDO's timers (Operational only); returns the earliest timer of the
    /// running SRDOs after them, each judged as [`SafetyProtocol::deadline`] judges it with the
    /// device's state at that SRDO's turn (which a fault on the way makes moot).
    fn run_srdos<S: Sink>(&mut self, now: Instant, slot: &mut Slot<'_, S>) -> Instant {
        let mut next = Instant::NEVER;
        let mut position = 0;
        while let Some(&index) = self.active.get(position) {
            position += 1;
            let index = usize::from(index);
            // Producers and consumers hold what they need of their records (taken at the
            // Operational entry and compared with the records by the integrity check), so the
            // records are not read here.
            let Some(runtime) = self.runtime.get_mut(index) else {
                continue;
            };
            // Each arm gives the SRDO's next timer as `deadline` judges it; a fault makes it
            // moot (the pass's answer is then dropped, see `poll`).
            let (result, timer) = match &mut runtime.role {
                Role::Producer(producer) => {
                    if self.producers_halted {
                        (Ok(()), Instant::NEVER)
                    } else if !producer.due(now) {
                        (Ok(()), producer.deadline(now))
                    } else {
                        match srdo::gather(slot.image(), &runtime.mapping) {
                            Ok((plain, inverted)) => {
                                let [first, second] =
                                    producer.frames(plain, inverted, runtime.mapping.len);
                                slot.transmit(first);
                                slot.transmit(second);
                                producer.sent(now);
                                runtime.pairs = runtime.pairs.wrapping_add(1);
                                (Ok(()), producer.deadline(now))
                            }
                            Err(cause) => (Err(cause), Instant::NEVER),
                        }
                    }
                }
                Role::Consumer(consumer) if !slot.latched() => {
                    (consumer.check_timers(now), consumer.deadline())
                }
                Role::Consumer(_) | Role::Idle => (Ok(()), Instant::NEVER),
            };
            next = next.min(timer);
            if let Err(cause) = result {
                self.latch(
                    SafeStateCause::Srdo(SrdoFault {
                        srdo: SrdoNumber::from_index(index),
                        cause,
                    }),
                    slot.reborrow(),
                );
            }
        }
        next
    }

    /// The earliest timer of the running SRDOs, each judged by [`SrdoTable::timer`]: a pass
    /// over them, for a deadline asked for when the last poll's answer no longer holds.
    fn timers(&self, now: Instant, latched: bool) -> Instant {
        self.active
            .iter()
            .filter_map(|&index| self.runtime.get(usize::from(index)))
            .map(|runtime| self.timer(runtime, now, latched))
            .min()
            .unwrap_or(Instant::NEVER)
    }

    /// [`SafetyProtocol::deadline`] from a fresh pass over the SRDOs, whatever the last poll
    /// left: what the answer from the poll's own pass must equal.
    #[cfg(test)]
    pub(super) fn fresh_deadline(&self, now: Instant, latched: bool) -> Instant {
        self.integrity.deadline().min(self.timers(now, latched))
    }

    /// The earliest instant at which `runtime` has something to do.
    #[inline]
    fn timer(&self, runtime: &SrdoRuntime, now: Instant, latched: bool) -> Instant {
        match &runtime.role {
            Role::Consumer(consumer) if !latched => consumer.deadline(),
            Role::Producer(producer) if !self.producers_halted => producer.deadline(now),
            _ => Instant::NEVER,
        }
    }
}

/// Bytes of a stored image per SRDO of the table, the shell's part included: a record with 16
/// mapping entries (79 bytes) and its two audit signatures (4), and the shell's fixed part
/// (60 bytes: header, salt, hash, change counter, heartbeat time, and this table's own two
/// bytes; and the LSS settings with the `lss` feature) counted once per SRDO, which covers
/// it for any table of at least one SRDO.
pub(super) const IMAGE_PER_SRDO: usize =
    RECORD_FIXED + 4 * MAX_MAPPING_ENTRIES + 4 + 60 + persist::LSS_LEN;

/// The stored image of a table of `N` SRDOs: `N` times [`IMAGE_PER_SRDO`] bytes, so that a
/// device of 4 SRDOs restores its parameters through 572 bytes of stack (580 with the `lss`
/// feature), not the 5 KiB of the largest table.
pub type SrdoImage<const N: usize> = RowImage<IMAGE_PER_SRDO, N>;

impl<const N: usize> SafetyProtocol for SrdoTable<N> {
    /// 0x13FE, `N`, and `N` records with 16 mapping entries each at most.
    const MAX_PERSISTED: usize = 2 + N * (RECORD_FIXED + 4 * MAX_MAPPING_ENTRIES);

    type Image = SrdoImage<N>;

    fn image() -> SrdoImage<N> {
        RowImage::zeroed()
    }

    fn load_defaults(&mut self, config: &NodeConfig) {
        self.safety = Self::defaults(config);
    }

    fn persist(&self, out: &mut [u8]) -> usize {
        let mut at = 0usize;
        let mut push = |bytes: &[u8]| {
            if let Some(target) = out.get_mut(at..at + bytes.len()) {
                target.copy_from_slice(bytes);
            }
            at += bytes.len();
        };
        push(&[self.safety.configuration_valid]);
        // N <= 64 is checked when the table is built.
        push(&[N as u8]);
        for record in &self.safety.srdos {
            push(&[record.direction]);
            push(&record.cycle_time.to_le_bytes());
            push(&[record.srvt]);
            push(&record.cob_id_1.to_le_bytes());
            push(&record.cob_id_2.to_le_bytes());
            push(&[record.mapping_count]);
            for entry in record.entries() {
                push(&entry.to_le_bytes());
            }
            push(&record.signature.to_le_bytes());
        }
        at.min(out.len())
    }

    fn restore(&mut self, bytes: &[u8]) -> Result<(), PersistError> {
        let mut reader = Reader::new(bytes);
        let configuration_valid = reader.u8()?;
        if usize::from(reader.u8()?) != N {
            return Err(PersistError::SrdoCountMismatch);
        }
        let mut srdos = [SrdoRecord::DELETED; N];
        for record in srdos.iter_mut() {
            record.direction = reader.u8()?;
            record.cycle_time = reader.u16()?;
            record.srvt = reader.u8()?;
            record.cob_id_1 = reader.u32()?;
            record.cob_id_2 = reader.u32()?;
            record.mapping_count = reader.u8()?;
            let count = usize::from(record.mapping_count);
            if count > MAX_MAPPING_ENTRIES {
                return Err(PersistError::Malformed);
            }
            for entry in record.mapping.iter_mut().take(count) {
                *entry = reader.u32()?;
            }
            record.signature = reader.u16()?;
        }
        if !reader.is_empty() {
            return Err(PersistError::Malformed);
        }
        self.safety = SafetyConfig {
            srdos,
            configuration_valid,
        };
        Ok(())
    }

    fn withdraw_validation(&mut self) {
        self.safety.configuration_valid = 0;
    }

    fn owns(&self, index: u16) -> bool {
        SafetyConfig::<N>::owns(index) || index == DOUBLE_RECEPTION_INDEX
    }

    /// The SRDO records, 0x13FE and 0x13FF; not the double-reception counters (read-only).
    fn needs_unlock(index: u16) -> bool {
        SafetyConfig::<N>::owns(index)
    }

    type Signatures = [u16; N];

    const NO_SIGNATURES: [u16; N] = [0; N];

    /// 0x13FF's, while 0x13FE reads A5h (every other accepted write sets it to 0).
    fn validated_signatures(&self) -> Option<[u16; N]> {
        (self.safety.configuration_valid == CONFIGURATION_VALID)
            .then(|| self.safety.srdos.map(|record| record.signature))
    }

    fn read(&mut self, address: Address, buf: &mut [u8]) -> Result<usize, AbortCode> {
        if address.index != DOUBLE_RECEPTION_INDEX {
            return self.safety.read(address, buf);
        }
        let count = match address.sub {
            0 => return put(buf, &[2]),
            1 => self.double_reception.plain_repeated,
            2 => self.double_reception.inverted_without_plain,
            _ => return Err(AbortCode::NoSubIndex),
        };
        put(buf, &count.to_le_bytes())
    }

    fn write(
        &mut self,
        address: Address,
        data: &[u8],
        image: &ProcessImage,
        operational: bool,
    ) -> Result<(), AbortCode> {
        if address.index != DOUBLE_RECEPTION_INDEX {
            return self.safety.write(address, data, image, operational);
        }
        let mut scratch = [0u8; 4];
        self.read(address, &mut scratch)?;
        Err(AbortCode::ReadOnly)
    }

    /// Only with a configuration that passes the check (EN 50325-5 8.3.1, CiA 304 9.5);
    /// otherwise 0x13FE reads 0 from then on, and the EMCY 6300h says which SRDO failed and
    /// why.
    fn start<S: Sink>(&mut self, now: Instant, slot: &mut Slot<'_, S>) -> Result<(), Refused> {
        let node_id = slot.node_id().raw();
        let SrdoTable {
            safety,
            runtime,
            active,
            lookup,
            ..
        } = self;
        let records = &safety.srdos;
        let result = safety.check_for_operational(slot.image(), |number, valid| {
            let index = number.index();
            let Some(record) = records.get(index) else {
                return;
            };
            // Each takes the times (and a producer its identifiers) it runs with from the
            // record it was just validated from; the integrity check compares them again.
            let role = match valid.direction {
                Direction::Transmit => Role::Producer(Producer::start(
                    now,
                    node_id,
                    record.cycle_time,
                    valid.cob_ids,
                )),
                _ => Role::Consumer(Consumer::start(now, record.cycle_time, record.srvt)),
            };
            if let Some(entry) = runtime.get_mut(index) {
                *entry = SrdoRuntime {
                    mapping: valid.mapping,
                    role,
                    pairs: 0,
                };
            }
            // `index < N <= 64`, so it fits the table's seven bits with the +1.
            let tag = index as u8 + 1;
            let first = usize::from(valid.cob_ids.first() - SRDO_ID_BASE);
            if let Some(plain) = lookup.get_mut(first) {
                *plain = tag;
            }
            if let Some(inverted) = lookup.get_mut(first + 1) {
                *inverted = tag | LOOKUP_INVERTED;
            }
            let _ = active.push(index as u8);
        });
        match result {
            Ok(()) => {
                self.start_integrity(now);
                self.running = true;
                Ok(())
            }
            Err(fault) => {
                self.stop(slot.image_mut());
                // The node has just refused this configuration, so 0x13FE must not go on
                // reading A5h (EN 50325-5 6.4.1.6). In the object dictionary only: the stored
                // record stays as written.
                self.withdraw_validation();
                let srdo = fault.srdo.map_or(0, SrdoNumber::get);
                Err(slot.refuse_configuration(
                    [srdo, fault.error.cause_code(), 0, 0, 0],
                    Event::ConfigurationRefused(fault),
                ))
            }
        }
    }

    fn stop(&mut self, image: &mut ProcessImage) {
        self.clear_received(image);
        for runtime in self.runtime.iter_mut() {
            *runtime = SrdoRuntime::IDLE;
        }
        self.active.clear();
        self.lookup = [0; SRDO_IDS];
        self.integrity = integrity::Integrity::IDLE;
        self.running = false;
        self.next_timer_judged = Judged::Stale;
    }

    fn reset(&mut self) {
        self.producers_halted = false;
        self.remote_frames_ignored = 0;
        self.double_reception = DoubleReception::default();
    }

    /// Every frame in the SRDO identifier range is the table's; outside Operational it is
    /// ignored (EN 50325-5 8.2.2: SRDOs are disabled outside Operational).
    #[inline]
    fn on_frame<S: Sink>(
        &mut self,
        now: Instant,
        frame: &CanFrame,
        slot: &mut Slot<'_, S>,
    ) -> bool {
        let offset = usize::from(frame.id().raw().wrapping_sub(SRDO_ID_BASE));
        if offset >= SRDO_IDS {
            return false;
        }
        if self.running {
            self.on_srdo_frame(now, offset, frame, slot);
        }
        true
    }

    fn poll<S: Sink>(&mut self, now: Instant, slot: &mut Slot<'_, S>) {
        // The pass judges each SRDO with the device's state at its turn: its answer is the
        // deadline only when nothing entered the safe state on the way (which would change
        // how the earlier ones count), and entering it makes `next_timer` stale. The integrity
        // check entering it later makes it stale again; another protocol latching the device
        // leaves it judged for the state before, which `deadline` no longer takes.
        let latched = slot.latched();
        self.next_timer_judged = Judged::when(latched);
        self.next_timer = self.run_srdos(now, slot);
        self.poll_integrity(now, slot);
    }

    fn deadline(&self, now: Instant, latched: bool) -> Instant {
        let srdos = if self.next_timer_judged == Judged::when(latched) {
            self.next_timer
        } else {
            self.timers(now, latched)
        };
        self.integrity.deadline().min(srdos)
    }

    /// Consumers deliver 0 from then on. Producers keep sending through a communication
    /// fault or a GFC (they are another device's safety function), but stop for good when
    /// their own two halves disagree, or when the application or the integrity check put the
    /// data behind them in doubt.
    fn enter_safe_state(
        &mut self,
        image: &mut ProcessImage,
        cause: SafeStateCause,
        already_latched: bool,
    ) {
        match cause {
            SafeStateCause::Srdo(fault) => {
                if fault.cause == SrdoFaultCause::TransmitHalvesNotInverted {
                    self.producers_halted = true;
                }
            }
            SafeStateCause::Application { .. } | SafeStateCause::Integrity(_) => {
                self.producers_halted = true;
            }
            SafeStateCause::Gfc | SafeStateCause::Protocol { .. } => {}
        }
        if !already_latched {
            self.clear_received(image);
        }
        self.next_timer_judged = Judged::Stale;
    }

    /// Marks every running producer whose mapping includes the byte at `offset` as changed.
    fn object_changed(&mut self, offset: u8) -> bool {
        if !self.event_driven {
            return false;
        }
        let mut due = false;
        for runtime in self.runtime.iter_mut() {
            if let Role::Producer(producer) = &mut runtime.role {
                if runtime.mapping.covers(offset) {
                    producer.mark_changed();
                    due = true;
                }
            }
        }
        if due {
            self.next_timer_judged = Judged::Stale;
        }
        due
    }
}
