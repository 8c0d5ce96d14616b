//! The stored parameter image: what 0x1010 saves and a reset restores.
//!
//! The image is serialised here into a small, versioned byte layout and handed to
//! [`crate::canopen::storage`], which makes storing it atomic. Parsing is strict: a wrong
//! version, a wrong SRDO count, a length that does not add up, an out-of-range count or
//! node-ID is refused as a whole, and the node then runs on its defaults (which are not
//! validated, so it stays in the safe state until a tool configures it).
//!
//! The image carries the node-ID of the device that stored it. 0x13FE can only hold A5h on a
//! device whose configuration was validated there (by the tool, or restored from an image
//! stored under the same node-ID), so that node-ID is the one the configuration was validated
//! for; the node withdraws the validity when it starts under another node-ID (IEC 61784-3
//! addressing: the stored COB-IDs are absolute and may belong to another node there).
//! Version 1 images, which do not carry it, are refused ([`PersistError::PreviousFormat`]).
//!
//! Layout, all integers little-endian:
//!
//! | bytes | field |
//! |-------|-------|
//! | 1 | format version (2) |
//! | 1 | node-ID of the device that stored the image, `1..=127` |
//! | 2 | 0x1017 producer heartbeat time |
//! | 1 | 0x13FE configuration valid |
//! | 1 | number of SRDO records `N` |
//! | per SRDO | direction (1), refresh time / SCT (2), SRVT (1), COB-ID 1 (4), COB-ID 2 (4), mapping count (1), that many entries (4 each), signature (2) |

use crate::canopen::node_id::NodeId;
use crate::canopen::storage::{self, Flash, StorageError};
use crate::safety::MAX_SRDOS;
use crate::safety::config::{MAX_MAPPING_ENTRIES, SafetyConfig, SrdoRecord};

/// Format version of the layout above.
const VERSION: u8 = 2;
/// Bytes of the header.
const HEADER: usize = 6;
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
    /// The stored image was written by an earlier firmware in a format that does not say
    /// which node-ID its configuration was validated for, so it is not used (configure and
    /// store again).
    PreviousFormat(u8),
    /// The stored node-ID is not in `1..=127`.
    BadNodeId(u8),
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

/// Serialises `safety`, the heartbeat time and the storing device's node-ID into `out`;
/// returns the length used.
fn encode<const N: usize>(
    safety: &SafetyConfig<N>,
    heartbeat_ms: u16,
    node_id: NodeId,
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
    push(&[node_id.raw()]);
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

/// What a stored image holds.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Image<const N: usize> {
    safety: SafetyConfig<N>,
    heartbeat_ms: u16,
    /// The node-ID of the device that stored it.
    node_id: NodeId,
}

/// Parses a stored image; all or nothing.
fn decode<const N: usize>(bytes: &[u8]) -> Result<Image<N>, PersistError> {
    let mut reader = Reader { bytes };
    let version = reader.u8()?;
    match version {
        VERSION => {}
        1 => return Err(PersistError::PreviousFormat(version)),
        _ => return Err(PersistError::UnknownVersion(version)),
    }
    let raw_node_id = reader.u8()?;
    let node_id = NodeId::new(raw_node_id).map_err(|_| PersistError::BadNodeId(raw_node_id))?;
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
    Ok(Image {
        safety: SafetyConfig {
            srdos,
            configuration_valid,
        },
        heartbeat_ms,
        node_id,
    })
}

/// Stores the parameters (0x1010) of the device with `node_id`.
pub(super) fn store<F: Flash, const N: usize>(
    flash: &mut F,
    safety: &SafetyConfig<N>,
    heartbeat_ms: u16,
    node_id: NodeId,
) -> Result<(), StorageError> {
    let mut image = [0u8; MAX_IMAGE];
    let len = encode(safety, heartbeat_ms, node_id, &mut image);
    storage::store(flash, &image[..len])
}

/// Loads stored parameters into `safety` and `heartbeat_ms`: `Ok(Some(node-ID))` when they
/// were restored, with the node-ID of the device that stored them; `Ok(None)` when nothing is
/// stored (defaults stay); `Err` when the stored image is unusable (the caller keeps the
/// defaults).
pub(super) fn load<F: Flash, const N: usize>(
    flash: &mut F,
    safety: &mut SafetyConfig<N>,
    heartbeat_ms: &mut u16,
) -> Result<Option<NodeId>, PersistError> {
    let mut image = [0u8; MAX_IMAGE];
    let Some(len) = storage::load(flash, &mut image).map_err(PersistError::Storage)? else {
        return Ok(None);
    };
    let restored = decode::<N>(image.get(..len).ok_or(PersistError::Malformed)?)?;
    *safety = restored.safety;
    *heartbeat_ms = restored.heartbeat_ms;
    Ok(Some(restored.node_id))
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

    fn node(id: u8) -> NodeId {
        NodeId::new(id).unwrap()
    }

    fn encoded() -> ([u8; MAX_IMAGE], usize) {
        let mut out = [0u8; MAX_IMAGE];
        let len = encode(&sample(), 250, node(7), &mut out);
        (out, len)
    }

    #[test]
    fn image_round_trips_with_the_node_id() {
        let (out, len) = encoded();
        assert_eq!(
            decode::<2>(&out[..len]),
            Ok(Image {
                safety: sample(),
                heartbeat_ms: 250,
                node_id: node(7),
            })
        );
    }

    #[test]
    fn every_truncation_and_extension_is_refused() {
        let (out, len) = encoded();
        for cut in 0..len {
            assert!(decode::<2>(&out[..cut]).is_err(), "cut at {cut}");
        }
        assert_eq!(decode::<2>(&out[..len + 1]), Err(PersistError::Malformed));
    }

    #[test]
    fn foreign_images_are_refused() {
        let (mut out, len) = encoded();
        assert_eq!(
            decode::<3>(&out[..len]),
            Err(PersistError::SrdoCountMismatch)
        );
        for raw in [0, 128, 255] {
            let mut copy = out;
            copy[1] = raw;
            assert_eq!(decode::<2>(&copy[..len]), Err(PersistError::BadNodeId(raw)));
        }
        out[0] = 9;
        assert_eq!(
            decode::<2>(&out[..len]),
            Err(PersistError::UnknownVersion(9))
        );
    }

    /// A version 1 image (no node-ID) is never misread as version 2, whatever it holds.
    #[test]
    fn a_version_1_image_is_refused_as_the_previous_format() {
        let (mut out, len) = encoded();
        out[0] = 1;
        assert_eq!(
            decode::<2>(&out[..len]),
            Err(PersistError::PreviousFormat(1))
        );
    }

    #[test]
    fn an_out_of_range_mapping_count_is_refused_not_panicking() {
        let (mut out, len) = encoded();
        // First record's mapping count sits after the header and 12 bytes of the record.
        out[HEADER + 12] = 200;
        assert_eq!(decode::<2>(&out[..len]), Err(PersistError::Malformed));
    }
}
