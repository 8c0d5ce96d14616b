//! The SRDO configuration (objects 0x1301..0x1340, 0x1381..0x13C0, 0x13FE, 0x13FF) and the one
//! validation that judges it.
//!
//! # One validation, used everywhere
//! Existing stacks check a single SDO write with a few local rules and the whole configuration
//! with other, stricter rules when the device starts, so a tool can download a configuration
//! that every write accepted and that the device then refuses (or worse, the other way round).
//! Here one set of functions decides:
//!
//! - [`check_srdo`] judges one SRDO that exists (direction 1 or 2): every field, the COB-ID
//!   pair, SRVT below SCT, identifiers not used by another SRDO, and the mapping resolved
//!   against the application objects in the right direction.
//! - [`check_mapping`] judges a mapping on its own (used when sub-index 0 is written, before
//!   the SRDO exists and so before its direction is known).
//! - [`SafetyConfig::write`] applies one SDO write to a *copy* of the affected record and runs
//!   the same checks on the result, so an accepted write always leaves every existing SRDO
//!   valid; a refused write changes nothing.
//! - [`SafetyConfig::check_for_operational`] runs [`check_srdo`] over every existing SRDO and
//!   compares signatures (EN 50325-5 8.3.1, CiA 304 9.5) before the node may enter
//!   Operational.
//!
//! The invariant "every existing SRDO passes [`check_srdo`]" therefore holds after any
//! sequence of accepted writes; a configuration restored from storage or damaged in RAM is
//! caught by the Operational-entry check, which is the same function.

use super::signature;
use super::types::{CobIdPair, Direction, MappingEntry, SrdoNumber};
use crate::canopen::od::{AbortCode, Address};
use crate::process_image::{Mappable, ProcessImage, Span};
use crate::time::Duration;

/// Most mapping entries an SRDO can have: 8 data bytes of at least one byte each, plain and
/// inverted (EN 50325-5 6.2: an SR application object is at most 8 octets per frame).
pub const MAX_MAPPING_ENTRIES: usize = 16;
/// Largest SRDO payload (one classic CAN frame).
pub const MAX_SRDO_DATA: usize = 8;
/// The only transmission type an SRDO has (EN 50325-5 Table 5, sub-index 04h).
pub const TRANSMISSION_TYPE: u8 = 254;
/// The value of 0x13FE that declares the configuration valid (EN 50325-5 6.4.1.6).
pub const CONFIGURATION_VALID: u8 = 0xA5;

/// One SRDO's configuration as the object dictionary holds it: raw values as written, so
/// read-back returns exactly what the tool downloaded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SrdoRecord {
    /// 0x1301+n sub-index 01h, information direction (raw).
    pub direction: u8,
    /// 0x1301+n sub-index 02h, refresh time (transmit) or SCT (receive), in ms.
    pub cycle_time: u16,
    /// 0x1301+n sub-index 03h, SRVT in ms (receive; reserved for transmit).
    pub srvt: u8,
    /// 0x1301+n sub-index 05h, COB-ID 1 (plain data).
    pub cob_id_1: u32,
    /// 0x1301+n sub-index 06h, COB-ID 2 (inverted data).
    pub cob_id_2: u32,
    /// 0x1381+n sub-index 00h, number of mapping entries.
    pub mapping_count: u8,
    /// 0x1381+n sub-indices 01h..10h; odd sub-indices map plain data, even ones inverted data.
    pub mapping: [u32; MAX_MAPPING_ENTRIES],
    /// 0x13FF sub-index n, the safety configuration signature written by the tool.
    pub signature: u16,
}

impl SrdoRecord {
    /// An SRDO that does not exist, with the defaults of EN 50325-5 Table 5 for its times and
    /// no identifiers (they are manufacturer-specific; ours must be configured).
    pub const DELETED: SrdoRecord = SrdoRecord {
        direction: 0,
        cycle_time: 25,
        srvt: 20,
        cob_id_1: 0,
        cob_id_2: 0,
        mapping_count: 0,
        mapping: [0; MAX_MAPPING_ENTRIES],
        signature: 0,
    };

    /// The direction, if the raw value is one of the defined ones.
    pub fn parsed_direction(&self) -> Result<Direction, ConfigError> {
        Direction::new(self.direction)
    }

    /// `true` when the SRDO exists (direction is not 0). A reserved direction value counts as
    /// existing, so it is judged (and refused) rather than ignored.
    pub fn exists(&self) -> bool {
        self.direction != 0
    }

    /// The mapping entries in use, sub-index 1 first.
    pub fn entries(&self) -> &[u32] {
        let count = usize::from(self.mapping_count).min(MAX_MAPPING_ENTRIES);
        &self.mapping[..count]
    }
}

/// Why a configuration (or one write to it) was refused.
///
/// The doc comment of each variant is its message; [`ConfigError::abort_code`] is the SDO abort
/// code it is answered with, and [`ConfigError::cause_code`] the byte that names it in EMCY.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ConfigError {
    /// The information direction is a reserved value (03h..FFh).
    DirectionReserved,
    /// The refresh time or SCT is 0 ms; it shall be n > 0 (EN 50325-5 6.2.1).
    CycleTimeZero,
    /// The SRVT is 0 ms; it shall be n > 0 (EN 50325-5 6.2.1).
    SrvtZero,
    /// The SRVT is not shorter than the SCT, so a late second frame could never be told from a
    /// missing cycle.
    SrvtNotBelowSct,
    /// The COB-ID is below the SRDO range (COB-ID 1 from 0x101, COB-ID 2 from 0x102).
    CobIdTooLow,
    /// The COB-ID is above the SRDO range (COB-ID 1 up to 0x17F, COB-ID 2 up to 0x180).
    CobIdTooHigh,
    /// COB-ID 1 must be odd and COB-ID 2 even (EN 50325-5 6.4.1.3).
    CobIdParity,
    /// COB-ID 2 is not COB-ID 1 + 1 (EN 50325-5 6.4.1.3).
    CobIdsNotConsecutive,
    /// The COB-IDs are already used by another SRDO of this device.
    CobIdInUse,
    /// A COB-ID cannot be changed while the SRDO exists (CiA 304 8.4.2.2).
    CobIdChangedWhileExists,
    /// The mapping cannot be changed while the SRDO exists; delete it first
    /// (EN 50325-5 6.4.1.4).
    MappingWhileExists,
    /// A mapping entry cannot be changed while sub-index 00h is not 0 (EN 50325-5 Table 8).
    MappingNotDisabled,
    /// The number of mapping entries must be even: plain and inverted entries come in pairs
    /// (EN 50325-5 Table 6).
    MappingCountOdd,
    /// The mapped data would not fit in one CAN frame of 8 bytes.
    MappingTooLong,
    /// An existing SRDO has no mapping.
    MappingEmpty,
    /// A mapping entry names an object that does not exist.
    MappedObjectMissing,
    /// A mapping entry names a sub-index that does not exist.
    MappedSubIndexMissing,
    /// A mapping entry names an object that cannot be mapped into an SRDO of this direction.
    NotMappable,
    /// A mapping entry's length is not the whole length of its object in bytes.
    MappedLengthMismatch,
    /// A plain entry and its inverted entry have different lengths.
    PairLengthMismatch,
    /// A plain entry and its inverted entry map the same object, so the inverted frame could
    /// never carry the inverted data.
    PairSameObject,
    /// Object 0x13FE does not hold A5h: the configuration was not declared valid
    /// (EN 50325-5 6.4.1.6).
    NotDeclaredValid,
    /// The signature in 0x13FF does not match the configuration (EN 50325-5 8.3.1).
    SignatureMismatch,
}

impl ConfigError {
    /// The SDO abort code that answers a write refused for this reason.
    pub const fn abort_code(self) -> AbortCode {
        use ConfigError::*;
        match self {
            DirectionReserved => AbortCode::ValueTooHigh,
            CycleTimeZero | SrvtZero => AbortCode::ValueTooLow,
            CobIdTooLow => AbortCode::ValueTooLow,
            CobIdTooHigh => AbortCode::ValueTooHigh,
            CobIdParity | CobIdChangedWhileExists | MappingCountOdd => AbortCode::InvalidValue,
            SrvtNotBelowSct | CobIdsNotConsecutive | CobIdInUse | MappingEmpty
            | PairLengthMismatch | PairSameObject | SignatureMismatch | NotDeclaredValid => {
                AbortCode::ParameterIncompatible
            }
            MappingWhileExists => AbortCode::DeviceState,
            MappingNotDisabled => AbortCode::UnsupportedAccess,
            MappingTooLong => AbortCode::MappingTooLong,
            MappedObjectMissing => AbortCode::NoObject,
            MappedSubIndexMissing => AbortCode::NoSubIndex,
            NotMappable | MappedLengthMismatch => AbortCode::NotMappable,
        }
    }

    /// A stable number for this reason, sent in the manufacturer-specific bytes of EMCY. (11
    /// was "transmission type fixed", now answered as a read-only entry; it is not reused.)
    ///
    /// Out of line: inlined, its table was in the firmware images twice (`docs/footprint.md`).
    #[inline(never)]
    pub const fn cause_code(self) -> u8 {
        use ConfigError::*;
        match self {
            DirectionReserved => 1,
            CycleTimeZero => 2,
            SrvtZero => 3,
            SrvtNotBelowSct => 4,
            CobIdTooLow => 5,
            CobIdTooHigh => 6,
            CobIdParity => 7,
            CobIdsNotConsecutive => 8,
            CobIdInUse => 9,
            CobIdChangedWhileExists => 10,
            MappingWhileExists => 12,
            MappingNotDisabled => 13,
            MappingCountOdd => 14,
            MappingTooLong => 15,
            MappingEmpty => 16,
            MappedObjectMissing => 17,
            MappedSubIndexMissing => 18,
            NotMappable => 19,
            MappedLengthMismatch => 20,
            PairLengthMismatch => 21,
            PairSameObject => 22,
            NotDeclaredValid => 23,
            SignatureMismatch => 24,
        }
    }

    /// Every reason, in the order of their cause codes.
    pub const ALL: [ConfigError; 23] = {
        use ConfigError::*;
        [
            DirectionReserved,
            CycleTimeZero,
            SrvtZero,
            SrvtNotBelowSct,
            CobIdTooLow,
            CobIdTooHigh,
            CobIdParity,
            CobIdsNotConsecutive,
            CobIdInUse,
            CobIdChangedWhileExists,
            MappingWhileExists,
            MappingNotDisabled,
            MappingCountOdd,
            MappingTooLong,
            MappingEmpty,
            MappedObjectMissing,
            MappedSubIndexMissing,
            NotMappable,
            MappedLengthMismatch,
            PairLengthMismatch,
            PairSameObject,
            NotDeclaredValid,
            SignatureMismatch,
        ]
    };

    /// The reason an EMCY names by [`ConfigError::cause_code`], if it names one.
    pub fn from_cause_code(code: u8) -> Option<ConfigError> {
        Self::ALL
            .into_iter()
            .find(|error| error.cause_code() == code)
    }

    /// The reason in words, for a person reading a tool's output (the variant's doc comment).
    pub const fn describe(self) -> &'static str {
        use ConfigError::*;
        match self {
            DirectionReserved => "the information direction is a reserved value (03h..FFh)",
            CycleTimeZero => "the refresh time or SCT is 0 ms; it shall be more than 0",
            SrvtZero => "the SRVT is 0 ms; it shall be more than 0",
            SrvtNotBelowSct => "the SRVT is not shorter than the SCT",
            CobIdTooLow => "a COB-ID is below the SRDO range (0x101/0x102)",
            CobIdTooHigh => "a COB-ID is above the SRDO range (0x17F/0x180)",
            CobIdParity => "COB-ID 1 must be odd and COB-ID 2 even",
            CobIdsNotConsecutive => "COB-ID 2 is not COB-ID 1 + 1",
            CobIdInUse => "the COB-IDs are already used by another SRDO of this device",
            CobIdChangedWhileExists => "a COB-ID cannot be changed while the SRDO exists",
            MappingWhileExists => "the mapping cannot be changed while the SRDO exists",
            MappingNotDisabled => "a mapping entry cannot be changed while sub-index 00h is not 0",
            MappingCountOdd => {
                "the number of mapping entries is odd (plain and inverted come in pairs)"
            }
            MappingTooLong => "the mapped data would not fit in one CAN frame of 8 bytes",
            MappingEmpty => "an existing SRDO has no mapping",
            MappedObjectMissing => "a mapping entry names an object that does not exist",
            MappedSubIndexMissing => "a mapping entry names a sub-index that does not exist",
            NotMappable => {
                "a mapping entry names an object that cannot be mapped in this direction"
            }
            MappedLengthMismatch => "a mapping entry's length is not its object's length",
            PairLengthMismatch => "a plain entry and its inverted entry have different lengths",
            PairSameObject => "a plain entry and its inverted entry map the same object",
            NotDeclaredValid => {
                "0x13FE does not hold A5h: the configuration was not declared valid"
            }
            SignatureMismatch => "the signature in 0x13FF does not match the configuration",
        }
    }
}

impl core::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.describe())
    }
}

/// A refused configuration: which SRDO (none for device-wide reasons) and why.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ConfigFault {
    /// The SRDO that failed, or `None` for 0x13FE.
    pub srdo: Option<SrdoNumber>,
    /// The reason.
    pub error: ConfigError,
}

/// An SRDO mapping resolved to spans of the process image: pair `k` copies `plain[k]` into (or
/// out of) the plain frame and `inverted[k]` into (or out of) the inverted frame, in order.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ResolvedMapping {
    /// Spans of the plain-data objects, in frame order.
    pub plain: [Span; MAX_MAPPING_ENTRIES / 2],
    /// Spans of the inverted-data objects, in frame order.
    pub inverted: [Span; MAX_MAPPING_ENTRIES / 2],
    /// Number of pairs in use.
    pub pairs: u8,
    /// Payload length in bytes, `1..=8` for an existing SRDO.
    pub len: u8,
}

impl ResolvedMapping {
    /// No mapping at all.
    pub const EMPTY: ResolvedMapping = ResolvedMapping {
        plain: [Span { offset: 0, len: 0 }; MAX_MAPPING_ENTRIES / 2],
        inverted: [Span { offset: 0, len: 0 }; MAX_MAPPING_ENTRIES / 2],
        pairs: 0,
        len: 0,
    };

    /// `true` when the byte at `offset` of the process image is mapped (plain or inverted).
    pub fn covers(&self, offset: u8) -> bool {
        let pairs = usize::from(self.pairs).min(self.plain.len());
        self.plain[..pairs]
            .iter()
            .chain(&self.inverted[..pairs])
            .any(|span| offset >= span.offset && offset - span.offset < span.len)
    }
}

/// A validated, existing SRDO, ready to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ValidSrdo {
    /// Producer or consumer.
    pub direction: Direction,
    /// The identifiers.
    pub cob_ids: CobIdPair,
    /// Refresh time (transmit) or SCT (receive).
    pub cycle_time: Duration,
    /// SRVT (receive).
    pub srvt: Duration,
    /// The resolved mapping.
    pub mapping: ResolvedMapping,
}

/// Judges a mapping: even number of entries, each naming an existing application object by its
/// whole length in bytes, plain and inverted entries of a pair equally long and naming
/// different objects, at most 8 bytes per frame; with `direction` given, each object must be
/// mappable in that direction.
pub fn check_mapping(
    record: &SrdoRecord,
    image: &ProcessImage,
    direction: Option<Direction>,
) -> Result<ResolvedMapping, ConfigError> {
    let count = usize::from(record.mapping_count);
    if count % 2 != 0 {
        return Err(ConfigError::MappingCountOdd);
    }
    if count > MAX_MAPPING_ENTRIES {
        return Err(ConfigError::MappingTooLong);
    }
    let mut resolved = ResolvedMapping::default();
    let mut total = 0usize;
    for (pair, entries) in record.mapping[..count].chunks_exact(2).enumerate() {
        let plain = resolve_entry(MappingEntry(entries[0]), image, direction)?;
        let inverted = resolve_entry(MappingEntry(entries[1]), image, direction)?;
        if plain.len != inverted.len {
            return Err(ConfigError::PairLengthMismatch);
        }
        if plain.offset == inverted.offset {
            return Err(ConfigError::PairSameObject);
        }
        total += usize::from(plain.len);
        if total > MAX_SRDO_DATA {
            return Err(ConfigError::MappingTooLong);
        }
        resolved.plain[pair] = plain;
        resolved.inverted[pair] = inverted;
    }
    // `count <= 16` and `total <= 8`, so both fit in a byte.
    resolved.pairs = (count / 2) as u8;
    resolved.len = total as u8;
    Ok(resolved)
}

/// Resolves one mapping entry to its span of the process image.
fn resolve_entry(
    entry: MappingEntry,
    image: &ProcessImage,
    direction: Option<Direction>,
) -> Result<Span, ConfigError> {
    let address = Address::new(entry.index(), entry.sub());
    let Some((object, span)) = image.find(address) else {
        return Err(if image.has_index(address.index) {
            ConfigError::MappedSubIndexMissing
        } else {
            ConfigError::MappedObjectMissing
        });
    };
    let wanted = match direction {
        Some(Direction::Transmit) => Some(Mappable::Transmit),
        Some(Direction::Receive) => Some(Mappable::Receive),
        Some(Direction::Deleted) | None => None,
    };
    if object.mappable == Mappable::No || wanted.is_some_and(|wanted| wanted != object.mappable) {
        return Err(ConfigError::NotMappable);
    }
    if u16::from(entry.bits()) != u16::from(object.len) * 8 {
        return Err(ConfigError::MappedLengthMismatch);
    }
    Ok(span)
}

/// Judges one existing SRDO (direction 1 or 2) completely; `others` are the device's other
/// SRDO records, whose identifiers it must not reuse.
pub fn check_srdo<'a>(
    record: &SrdoRecord,
    image: &ProcessImage,
    others: impl Iterator<Item = &'a SrdoRecord>,
) -> Result<ValidSrdo, ConfigError> {
    let direction = record.parsed_direction()?;
    if record.cycle_time == 0 {
        return Err(ConfigError::CycleTimeZero);
    }
    // CiA 304 8.4.2.2 gives sub-index 03h the range 1..=255 whatever the direction; the
    // single-write check refuses 0 too, so both judge a transmit SRDO alike.
    if record.srvt == 0 {
        return Err(ConfigError::SrvtZero);
    }
    if direction == Direction::Receive && u16::from(record.srvt) >= record.cycle_time {
        return Err(ConfigError::SrvtNotBelowSct);
    }
    let cob_ids = CobIdPair::new(record.cob_id_1, record.cob_id_2)?;
    for other in others {
        if other.exists()
            && (other.cob_id_1 == record.cob_id_1 || other.cob_id_2 == record.cob_id_2)
        {
            return Err(ConfigError::CobIdInUse);
        }
    }
    if record.mapping_count == 0 {
        return Err(ConfigError::MappingEmpty);
    }
    let mapping = check_mapping(record, image, Some(direction))?;
    Ok(ValidSrdo {
        direction,
        cob_ids,
        cycle_time: Duration::from_millis(u64::from(record.cycle_time)),
        srvt: Duration::from_millis(u64::from(record.srvt)),
        mapping,
    })
}

/// The safety configuration of a device with `N` SRDOs (`1..=64`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SafetyConfig<const N: usize> {
    /// SRDO 1..=N.
    pub srdos: [SrdoRecord; N],
    /// 0x13FE, configuration valid.
    pub configuration_valid: u8,
}

impl<const N: usize> SafetyConfig<N> {
    /// The pre-defined connection set for `node_id` (EN 50325-5 Table 5, CiA 304 8.3.3):
    /// SRDO 1 transmits for node-IDs 1..=32 (refresh time 25 ms) and receives for 33..=64
    /// (SCT 50 ms, SRVT 20 ms) on COB-IDs 0xFF + 2·id and 0x100 + 2·id, with the device's
    /// default mapping for that direction; node-IDs 65..=127 have no SRDO. Signatures are 0 and
    /// 0x13FE is 0: a tool must validate the configuration before the node may run.
    pub fn predefined(node_id: u8, transmit_mapping: &[u32], receive_mapping: &[u32]) -> Self {
        let mut srdos = [SrdoRecord::DELETED; N];
        if let (Some(first), Some(pair)) = (srdos.first_mut(), CobIdPair::predefined(node_id)) {
            first.cob_id_1 = u32::from(pair.first());
            first.cob_id_2 = u32::from(pair.second());
            let mapping = if node_id <= 32 {
                first.direction = Direction::Transmit as u8;
                first.cycle_time = 25;
                transmit_mapping
            } else {
                first.direction = Direction::Receive as u8;
                first.cycle_time = 50;
                receive_mapping
            };
            let count = mapping.len().min(MAX_MAPPING_ENTRIES);
            first.mapping[..count].copy_from_slice(&mapping[..count]);
            // `count <= 16`.
            first.mapping_count = count as u8;
        }
        SafetyConfig {
            srdos,
            configuration_valid: 0,
        }
    }

    /// The record of `srdo`, if this device has it.
    pub fn record(&self, srdo: SrdoNumber) -> Option<&SrdoRecord> {
        self.srdos.get(srdo.index())
    }

    /// The records other than slot `index`.
    fn others(&self, index: usize) -> impl Iterator<Item = &SrdoRecord> {
        self.srdos
            .iter()
            .enumerate()
            .filter(move |(i, _)| *i != index)
            .map(|(_, r)| r)
    }

    /// Checks every existing SRDO with [`check_srdo`] (no signature, no 0x13FE).
    pub fn check_structure(&self, image: &ProcessImage) -> Result<(), ConfigFault> {
        for (index, record) in self.srdos.iter().enumerate() {
            if record.exists() {
                check_srdo(record, image, self.others(index)).map_err(|error| ConfigFault {
                    srdo: Some(SrdoNumber::from_index(index)),
                    error,
                })?;
            }
        }
        Ok(())
    }

    /// The check on the way into Operational (EN 50325-5 8.3.1, CiA 304 9.5): 0x13FE holds A5h,
    /// every existing SRDO passes [`check_srdo`], and every signature in 0x13FF matches the one
    /// computed here. Returns each existing SRDO, validated, in slot order.
    pub fn check_for_operational(
        &self,
        image: &ProcessImage,
        mut each: impl FnMut(SrdoNumber, ValidSrdo),
    ) -> Result<(), ConfigFault> {
        if self.configuration_valid != CONFIGURATION_VALID {
            return Err(ConfigFault {
                srdo: None,
                error: ConfigError::NotDeclaredValid,
            });
        }
        for (index, record) in self.srdos.iter().enumerate() {
            if !record.exists() {
                continue;
            }
            let number = SrdoNumber::from_index(index);
            let valid =
                check_srdo(record, image, self.others(index)).map_err(|error| ConfigFault {
                    srdo: Some(number),
                    error,
                })?;
            if signature::compute(record) != record.signature {
                return Err(ConfigFault {
                    srdo: Some(number),
                    error: ConfigError::SignatureMismatch,
                });
            }
            each(number, valid);
        }
        Ok(())
    }

    /// `true` when `index` is one of the safety configuration objects this module answers:
    /// 0x1301..=0x1340, 0x1381..=0x13C0 (whether or not this device has that SRDO), 0x13FE,
    /// 0x13FF.
    pub fn owns(index: u16) -> bool {
        matches!(index, 0x1301..=0x1340 | 0x1381..=0x13C0 | 0x13FE | 0x13FF)
    }

    /// Reads a safety configuration object by SDO rules.
    pub fn read(&self, address: Address, buf: &mut [u8]) -> Result<usize, AbortCode> {
        let mut put = |bytes: &[u8]| -> Result<usize, AbortCode> {
            let target = buf.get_mut(..bytes.len()).ok_or(AbortCode::OutOfMemory)?;
            target.copy_from_slice(bytes);
            Ok(bytes.len())
        };
        match address.index {
            0x13FE if address.sub == 0 => put(&[self.configuration_valid]),
            0x13FE => Err(AbortCode::NoSubIndex),
            0x13FF => match address.sub {
                // N <= 64 by construction of the node.
                0 => put(&[N as u8]),
                sub => {
                    let record = self
                        .srdos
                        .get(usize::from(sub) - 1)
                        .ok_or(AbortCode::NoSubIndex)?;
                    put(&record.signature.to_le_bytes())
                }
            },
            index @ 0x1301..=0x1340 => {
                let record = self
                    .srdos
                    .get(usize::from(index - 0x1301))
                    .ok_or(AbortCode::NoObject)?;
                match address.sub {
                    0 => put(&[6]),
                    1 => put(&[record.direction]),
                    2 => put(&record.cycle_time.to_le_bytes()),
                    3 => put(&[record.srvt]),
                    4 => put(&[TRANSMISSION_TYPE]),
                    5 => put(&record.cob_id_1.to_le_bytes()),
                    6 => put(&record.cob_id_2.to_le_bytes()),
                    _ => Err(AbortCode::NoSubIndex),
                }
            }
            index @ 0x1381..=0x13C0 => {
                let record = self
                    .srdos
                    .get(usize::from(index - 0x1381))
                    .ok_or(AbortCode::NoObject)?;
                match usize::from(address.sub) {
                    0 => put(&[record.mapping_count]),
                    sub @ 1..=MAX_MAPPING_ENTRIES => put(&record.mapping[sub - 1].to_le_bytes()),
                    _ => Err(AbortCode::NoSubIndex),
                }
            }
            _ => Err(AbortCode::NoObject),
        }
    }

    /// Applies one SDO write to a safety configuration object, or refuses it with the specific
    /// abort code and changes nothing.
    ///
    /// `operational` is `true` in NMT Operational, where every safety configuration object is
    /// read-only (EN 50325-5 8.2.2; CiA 304 Table 2 note 1: abort 0800 0022h). An accepted
    /// write to 0x1301..0x13C0 or 0x13FF sets 0x13FE to 0 (EN 50325-5 6.4.1.6).
    pub fn write(
        &mut self,
        address: Address,
        data: &[u8],
        image: &ProcessImage,
        operational: bool,
    ) -> Result<(), AbortCode> {
        if !Self::owns(address.index) {
            return Err(AbortCode::NoObject);
        }
        if operational {
            // Existence of the entry is still answered first, so a tool learns the real reason.
            let mut scratch = [0u8; 4];
            self.read(address, &mut scratch)?;
            return Err(AbortCode::DeviceState);
        }
        match address.index {
            0x13FE => self.write_configuration_valid(address, data, image),
            0x13FF => {
                let slot = match address.sub {
                    0 => return Err(AbortCode::ReadOnly),
                    sub => usize::from(sub) - 1,
                };
                let value = u16::from_le_bytes(exact(data)?);
                let record = self.srdos.get_mut(slot).ok_or(AbortCode::NoSubIndex)?;
                record.signature = value;
                self.configuration_valid = 0;
                Ok(())
            }
            index @ 0x1301..=0x1340 => {
                let slot = usize::from(index - 0x1301);
                let candidate = self.write_communication(slot, address.sub, data, image)?;
                self.commit(slot, candidate);
                Ok(())
            }
            index => {
                let slot = usize::from(index - 0x1381);
                let candidate = self.write_mapping(slot, address.sub, data, image)?;
                self.commit(slot, candidate);
                Ok(())
            }
        }
    }

    /// Stores an accepted candidate record and withdraws the validity declaration.
    fn commit(&mut self, slot: usize, candidate: SrdoRecord) {
        if let Some(record) = self.srdos.get_mut(slot) {
            *record = candidate;
            self.configuration_valid = 0;
        }
    }

    /// The record that a write to communication parameter sub-index `sub` would produce.
    fn write_communication(
        &self,
        slot: usize,
        sub: u8,
        data: &[u8],
        image: &ProcessImage,
    ) -> Result<SrdoRecord, AbortCode> {
        let current = *self.srdos.get(slot).ok_or(AbortCode::NoObject)?;
        let mut candidate = current;
        match sub {
            0 => return Err(AbortCode::ReadOnly),
            1 => {
                let [raw] = exact(data)?;
                Direction::new(raw).map_err(ConfigError::abort_code)?;
                candidate.direction = raw;
            }
            2 => {
                candidate.cycle_time = u16::from_le_bytes(exact(data)?);
                if candidate.cycle_time == 0 {
                    return Err(ConfigError::CycleTimeZero.abort_code());
                }
            }
            3 => {
                let [raw] = exact(data)?;
                candidate.srvt = raw;
                if raw == 0 {
                    return Err(ConfigError::SrvtZero.abort_code());
                }
            }
            // Transmission type, fixed at 254: a read-only entry (EN 50325-5 Table 5).
            4 => return Err(AbortCode::ReadOnly),
            5 | 6 => {
                let raw = u32::from_le_bytes(exact(data)?);
                let stored = if sub == 5 {
                    current.cob_id_1
                } else {
                    current.cob_id_2
                };
                if current.exists() && raw != stored {
                    return Err(ConfigError::CobIdChangedWhileExists.abort_code());
                }
                let checked = if sub == 5 {
                    CobIdPair::check_first(raw)
                } else {
                    CobIdPair::check_second(raw)
                };
                checked.map_err(ConfigError::abort_code)?;
                if sub == 5 {
                    candidate.cob_id_1 = raw;
                } else {
                    candidate.cob_id_2 = raw;
                }
            }
            _ => return Err(AbortCode::NoSubIndex),
        }
        if candidate.exists() {
            check_srdo(&candidate, image, self.others(slot)).map_err(ConfigError::abort_code)?;
        }
        Ok(candidate)
    }

    /// The record that a write to mapping parameter sub-index `sub` would produce.
    fn write_mapping(
        &self,
        slot: usize,
        sub: u8,
        data: &[u8],
        image: &ProcessImage,
    ) -> Result<SrdoRecord, AbortCode> {
        let current = *self.srdos.get(slot).ok_or(AbortCode::NoObject)?;
        let mut candidate = current;
        let sub = usize::from(sub);
        if sub > MAX_MAPPING_ENTRIES {
            return Err(AbortCode::NoSubIndex);
        }
        if sub == 0 {
            let [count] = exact(data)?;
            if current.exists() {
                return Err(ConfigError::MappingWhileExists.abort_code());
            }
            candidate.mapping_count = count;
            check_mapping(&candidate, image, None).map_err(ConfigError::abort_code)?;
        } else {
            let raw = u32::from_le_bytes(exact(data)?);
            if current.exists() {
                return Err(ConfigError::MappingWhileExists.abort_code());
            }
            if current.mapping_count != 0 {
                return Err(ConfigError::MappingNotDisabled.abort_code());
            }
            candidate.mapping[sub - 1] = raw;
        }
        Ok(candidate)
    }

    /// 0x13FE: writing A5h declares the configuration valid, and is accepted only when the
    /// Operational-entry check would pass with it (so a tool learns at once, not at start).
    fn write_configuration_valid(
        &mut self,
        address: Address,
        data: &[u8],
        image: &ProcessImage,
    ) -> Result<(), AbortCode> {
        if address.sub != 0 {
            return Err(AbortCode::NoSubIndex);
        }
        let [value] = exact(data)?;
        if value == CONFIGURATION_VALID {
            let previous = self.configuration_valid;
            self.configuration_valid = value;
            if let Err(fault) = self.check_for_operational(image, |_, _| {}) {
                self.configuration_valid = previous;
                return Err(fault.error.abort_code());
            }
        }
        self.configuration_valid = value;
        Ok(())
    }
}

/// `data` as exactly `L` bytes, or the abort code for a length that does not match the
/// entry's data type (CiA 301 0607 0012h / 0607 0013h).
fn exact<const L: usize>(data: &[u8]) -> Result<[u8; L], AbortCode> {
    match data.len().cmp(&L) {
        core::cmp::Ordering::Greater => Err(AbortCode::LengthTooHigh),
        core::cmp::Ordering::Less => Err(AbortCode::LengthTooLow),
        core::cmp::Ordering::Equal => {
            let mut bytes = [0u8; L];
            bytes.copy_from_slice(data);
            Ok(bytes)
        }
    }
}

#[cfg(test)]
#[path = "config_tests.rs"]
mod tests;
