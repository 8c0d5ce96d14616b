//! The stored parameter image: what 0x1010 saves and a reset restores.
//!
//! The image is serialised here into a small, versioned byte layout and handed to
//! [`crate::canopen::storage`], which makes storing it atomic. Parsing is strict: a wrong
//! version, a wrong SRDO count, a length that does not add up or an out-of-range count is
//! refused as a whole, and the node then runs on its defaults (which are not validated, so it
//! stays in the safe state until a tool configures it).
//!
//! Layout, all integers little-endian:
//!
//! | bytes | field |
//! |-------|-------|
//! | 1 | format version (1) |
//! | 2 | 0x1017 producer heartbeat time |
//! | 1 | 0x13FE configuration valid |
//! | 1 | number of SRDO records `N` |
//! | per SRDO | direction (1), refresh time / SCT (2), SRVT (1), COB-ID 1 (4), COB-ID 2 (4), mapping count (1), that many entries (4 each), signature (2) |

use crate::canopen::storage::{self, Flash, StorageError};
use crate::safety::MAX_SRDOS;
use crate::safety::config::{MAX_MAPPING_ENTRIES, SafetyConfig, SrdoRecord};

/// Format version of the layout above.
const VERSION: u8 = 1;
/// Bytes of the header.
const HEADER: usize = 5;
/// Bytes of one SRDO record without its mapping entries.
const RECORD_FIXED: usize = 1 + 2 + 1 + 4 + 4 + 1 + 2;
/// The largest image: 64 SRDOs with 16 mapping entries each.
pub const MAX_IMAGE: usize = HEADER + MAX_SRDOS * (RECORD_FIXED + 4 * MAX_MAPPING_ENTRIES);

/// Why stored parameters were not used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PersistError {
    /// The medium failed.
    Storage(StorageError),
    /// The stored image has a format version this firmware does not know.
    UnknownVersion(u8),
    /// The stored image is for a device with another number of SRDOs.
    SrdoCountMismatch,
    /// The stored image is truncated or has bytes left over.
    Malformed,
}

/// A cursor over the stored bytes that never reads past the end.
struct Reader<'a> {
    bytes: &'a [u8],
}

impl Reader<'_> {
    fn take<const L: usize>(&mut self) -> Result<[u8; L], PersistError> {
        let (head, rest) = self
            .bytes
            .split_at_checked(L)
            .ok_or(PersistError::Malformed)?;
        self.bytes = rest;
        <[u8; L]>::try_from(head).map_err(|_| PersistError::Malformed)
    }
    fn u8(&mut self) -> Result<u8, PersistError> {
        Ok(self.take::<1>()?[0])
    }
    fn u16(&mut self) -> Result<u16, PersistError> {
        Ok(u16::from_le_bytes(self.take()?))
    }
    fn u32(&mut self) -> Result<u32, PersistError> {
        Ok(u32::from_le_bytes(self.take()?))
    }
}

/// Serialises `safety` and the heartbeat time into `out`; returns the length used.
fn encode<const N: usize>(
    safety: &SafetyConfig<N>,
    heartbeat_ms: u16,
    out: &mut [u8; MAX_IMAGE],
) -> usize {
    let mut at = 0usize;
    let mut push = |bytes: &[u8]| {
        if let Some(target) = out.get_mut(at..at + bytes.len()) {
            target.copy_from_slice(bytes);
        }
        at += bytes.len();
    };
    push(&[VERSION]);
    push(&heartbeat_ms.to_le_bytes());
    push(&[safety.configuration_valid]);
    // N <= 64 is checked when the node is built.
    push(&[N as u8]);
    for record in &safety.srdos {
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
    at.min(MAX_IMAGE)
}

/// Parses a stored image; all or nothing.
fn decode<const N: usize>(bytes: &[u8]) -> Result<(SafetyConfig<N>, u16), PersistError> {
    let mut reader = Reader { bytes };
    let version = reader.u8()?;
    if version != VERSION {
        return Err(PersistError::UnknownVersion(version));
    }
    let heartbeat_ms = reader.u16()?;
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
    if !reader.bytes.is_empty() {
        return Err(PersistError::Malformed);
    }
    Ok((
        SafetyConfig {
            srdos,
            configuration_valid,
        },
        heartbeat_ms,
    ))
}

/// Stores the parameters (0x1010).
pub(super) fn store<F: Flash, const N: usize>(
    flash: &mut F,
    safety: &SafetyConfig<N>,
    heartbeat_ms: u16,
) -> Result<(), StorageError> {
    let mut image = [0u8; MAX_IMAGE];
    let len = encode(safety, heartbeat_ms, &mut image);
    storage::store(flash, &image[..len])
}

/// Loads stored parameters into `safety` and `heartbeat_ms`: `Ok(true)` when they were
/// restored, `Ok(false)` when nothing is stored (defaults stay), `Err` when the stored image
/// is unusable (the caller keeps the defaults).
pub(super) fn load<F: Flash, const N: usize>(
    flash: &mut F,
    safety: &mut SafetyConfig<N>,
    heartbeat_ms: &mut u16,
) -> Result<bool, PersistError> {
    let mut image = [0u8; MAX_IMAGE];
    let Some(len) = storage::load(flash, &mut image).map_err(PersistError::Storage)? else {
        return Ok(false);
    };
    let (restored, heartbeat) = decode::<N>(image.get(..len).ok_or(PersistError::Malformed)?)?;
    *safety = restored;
    *heartbeat_ms = heartbeat;
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> SafetyConfig<2> {
        let mut config = SafetyConfig::<2>::predefined(1, &[0x6000_0108, 0x6001_0108], &[]);
        config.srdos[1].direction = 2;
        config.srdos[1].signature = 0xBEEF;
        config.configuration_valid = 0xA5;
        config
    }

    #[test]
    fn image_round_trips() {
        let mut out = [0u8; MAX_IMAGE];
        let len = encode(&sample(), 250, &mut out);
        assert_eq!(decode::<2>(&out[..len]), Ok((sample(), 250)));
    }

    #[test]
    fn every_truncation_and_extension_is_refused() {
        let mut out = [0u8; MAX_IMAGE];
        let len = encode(&sample(), 250, &mut out);
        for cut in 0..len {
            assert!(decode::<2>(&out[..cut]).is_err(), "cut at {cut}");
        }
        assert_eq!(decode::<2>(&out[..len + 1]), Err(PersistError::Malformed));
    }

    #[test]
    fn foreign_images_are_refused() {
        let mut out = [0u8; MAX_IMAGE];
        let len = encode(&sample(), 250, &mut out);
        assert_eq!(
            decode::<3>(&out[..len]),
            Err(PersistError::SrdoCountMismatch)
        );
        out[0] = 9;
        assert_eq!(
            decode::<2>(&out[..len]),
            Err(PersistError::UnknownVersion(9))
        );
    }

    #[test]
    fn an_out_of_range_mapping_count_is_refused_not_panicking() {
        let mut out = [0u8; MAX_IMAGE];
        let len = encode(&sample(), 250, &mut out);
        // First record's mapping count sits after header (5) + 13 bytes.
        out[HEADER + 12] = 200;
        assert_eq!(decode::<2>(&out[..len]), Err(PersistError::Malformed));
    }
}
