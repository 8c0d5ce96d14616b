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
//!
//! The image also carries the access control's stored part ([`super::access`]): the salted
//! hash of the device secret and the audit record. 0x1011 (restore defaults) keeps them: it
//! stores an image without parameters instead of erasing, unless there is nothing to keep, so
//! no SDO write removes the secret or the audit record (SC_REQ_43).
//!
//! Layout (version 3), all integers little-endian:
//!
//! | bytes | field |
//! |-------|-------|
//! | 1 | format version (3) |
//! | 1 | node-ID of the device that stored the image, `1..=127` |
//! | 1 | flags: bit 0 the parameters follow, bit 1 a secret follows; other bits 0 |
//! | 1 | number of SRDOs `N` |
//! | 16 + 32 | if bit 1: the secret's salt, `SHA-256(salt ‖ secret)` |
//! | 4 | audit: validated changes |
//! | 2 N + 2 N | audit: the signatures before, then after, the last validated change |
//! | 2 | if bit 0: 0x1017 producer heartbeat time |
//! | 1 | if bit 0: 0x13FE configuration valid |
//! | per SRDO | if bit 0: direction (1), refresh time / SCT (2), SRVT (1), COB-ID 1 (4), COB-ID 2 (4), mapping count (1), that many entries (4 each), signature (2) |
//!
//! Images of versions 1 (no node-ID) and 2 (no access control) are refused
//! ([`PersistError::PreviousFormat`]): no hardware ever ran a firmware that wrote them, and a
//! second parser for them would be flash spent on nothing.

use super::access::{AccessControl, Audit, Persisted, SALT_LEN, Secret};
use crate::canopen::node_id::NodeId;
use crate::canopen::storage::{self, Flash, StorageError};
use crate::safety::MAX_SRDOS;
use crate::safety::config::{MAX_MAPPING_ENTRIES, SafetyConfig, SrdoRecord};

/// Format version of the layout above.
const VERSION: u8 = 3;
/// Flag: the parameters follow.
const HAS_PARAMETERS: u8 = 0x01;
/// Flag: a secret follows.
const HAS_SECRET: u8 = 0x02;
/// Bytes of the header: version, node-ID, flags, `N`.
const HEADER: usize = 4;
/// Bytes of the access part at most: salt, hash, change counter, two signatures per SRDO.
const ACCESS_MAX: usize = SALT_LEN + 32 + 4 + 4 * MAX_SRDOS;
/// Bytes of the parameters' own header: heartbeat time, 0x13FE.
const PARAMETERS_HEADER: usize = 3;
/// Bytes of one SRDO record without its mapping entries.
const RECORD_FIXED: usize = 1 + 2 + 1 + 4 + 4 + 1 + 2;
/// The largest image: the access part and 64 SRDOs with 16 mapping entries each.
pub const MAX_IMAGE: usize =
    HEADER + ACCESS_MAX + PARAMETERS_HEADER + MAX_SRDOS * (RECORD_FIXED + 4 * MAX_MAPPING_ENTRIES);

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
    /// The stored image is truncated, has bytes left over, or flags this firmware does not
    /// know.
    Malformed,
    /// The stored image was written by an earlier firmware in a format this one does not
    /// read (version 1 does not say which node-ID its configuration was validated for,
    /// version 2 has no access control), so it is not used (configure and store again).
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

/// The stored parameters proper.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Parameters<const N: usize> {
    safety: SafetyConfig<N>,
    heartbeat_ms: u16,
}

/// Serialises the access part, and the parameters when given, of the device with `node_id`
/// into `out`; returns the length used.
fn encode<const N: usize>(
    parameters: Option<(&SafetyConfig<N>, u16)>,
    access: &Persisted<N>,
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
    let mut flags = 0;
    if parameters.is_some() {
        flags |= HAS_PARAMETERS;
    }
    if access.secret.is_some() {
        flags |= HAS_SECRET;
    }
    push(&[VERSION]);
    push(&[node_id.raw()]);
    push(&[flags]);
    // N <= 64 is checked when the node is built.
    push(&[N as u8]);
    if let Some(secret) = &access.secret {
        push(&secret.salt);
        push(&secret.hash);
    }
    push(&access.audit.changes.to_le_bytes());
    for signature in access.audit.before.iter().chain(&access.audit.after) {
        push(&signature.to_le_bytes());
    }
    if let Some((safety, heartbeat_ms)) = parameters {
        push(&heartbeat_ms.to_le_bytes());
        push(&[safety.configuration_valid]);
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
    }
    at.min(MAX_IMAGE)
}

/// What a stored image holds.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Image<const N: usize> {
    /// The parameters, unless the image was stored by 0x1011 (restore defaults).
    parameters: Option<Parameters<N>>,
    /// The access control's stored part.
    access: Persisted<N>,
    /// The node-ID of the device that stored it.
    node_id: NodeId,
}

/// Reads the SRDO records after the parameters' header.
fn decode_records<const N: usize>(
    reader: &mut Reader<'_>,
    heartbeat_ms: u16,
    configuration_valid: u8,
) -> Result<Parameters<N>, PersistError> {
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
    Ok(Parameters {
        safety: SafetyConfig {
            srdos,
            configuration_valid,
        },
        heartbeat_ms,
    })
}

/// Reads the node-ID byte.
fn decode_node_id(reader: &mut Reader<'_>) -> Result<NodeId, PersistError> {
    let raw = reader.u8()?;
    NodeId::new(raw).map_err(|_| PersistError::BadNodeId(raw))
}

/// Reads the SRDO count byte, which must be `N`.
fn check_count<const N: usize>(reader: &mut Reader<'_>) -> Result<(), PersistError> {
    if usize::from(reader.u8()?) == N {
        Ok(())
    } else {
        Err(PersistError::SrdoCountMismatch)
    }
}

/// Parses a stored image; all or nothing.
fn decode<const N: usize>(bytes: &[u8]) -> Result<Image<N>, PersistError> {
    let mut reader = Reader { bytes };
    let image = match reader.u8()? {
        VERSION => {
            let node_id = decode_node_id(&mut reader)?;
            let flags = reader.u8()?;
            if flags & !(HAS_PARAMETERS | HAS_SECRET) != 0 {
                return Err(PersistError::Malformed);
            }
            check_count::<N>(&mut reader)?;
            let secret = if flags & HAS_SECRET != 0 {
                Some(Secret {
                    salt: reader.take()?,
                    hash: reader.take()?,
                })
            } else {
                None
            };
            let mut audit = Audit::NONE;
            audit.changes = reader.u32()?;
            for signature in audit.before.iter_mut().chain(audit.after.iter_mut()) {
                *signature = reader.u16()?;
            }
            let parameters = if flags & HAS_PARAMETERS != 0 {
                let heartbeat_ms = reader.u16()?;
                let configuration_valid = reader.u8()?;
                Some(decode_records(
                    &mut reader,
                    heartbeat_ms,
                    configuration_valid,
                )?)
            } else {
                None
            };
            Image {
                parameters,
                access: Persisted { secret, audit },
                node_id,
            }
        }
        version @ (1 | 2) => return Err(PersistError::PreviousFormat(version)),
        version => return Err(PersistError::UnknownVersion(version)),
    };
    if !reader.bytes.is_empty() {
        return Err(PersistError::Malformed);
    }
    Ok(image)
}

/// Stores the parameters (0x1010) of the device with `node_id`, with the access control's
/// stored part.
pub(super) fn store<F: Flash, const N: usize>(
    flash: &mut F,
    safety: &SafetyConfig<N>,
    heartbeat_ms: u16,
    node_id: NodeId,
    access: &Persisted<N>,
) -> Result<(), StorageError> {
    let mut image = [0u8; MAX_IMAGE];
    let len = encode(Some((safety, heartbeat_ms)), access, node_id, &mut image);
    storage::store(flash, &image[..len])
}

/// 0x1011: the defaults at the next reset. Erases the stored parameters when there is
/// nothing of the access control to keep; otherwise stores an image with the access part
/// alone, so the secret and the audit record stay.
pub(super) fn restore_defaults<F: Flash, const N: usize>(
    flash: &mut F,
    node_id: NodeId,
    access: &Persisted<N>,
) -> Result<(), StorageError> {
    if *access == Persisted::NEW {
        return storage::restore_defaults(flash);
    }
    let mut image = [0u8; MAX_IMAGE];
    let len = encode(None, access, node_id, &mut image);
    storage::store(flash, &image[..len])
}

/// Loads stored parameters into `safety` and `heartbeat_ms`, and the access control's stored
/// part into `access`: `Ok(Some(node-ID))` when parameters were restored, with the node-ID of
/// the device that stored them; `Ok(None)` when none are stored (defaults stay); `Err` when
/// the stored image is unusable (the caller keeps the defaults, and `access` holds no secret
/// and no audit record: a damaged image is a new device, see docs/access-protection.md).
pub(super) fn load<F: Flash, const N: usize>(
    flash: &mut F,
    safety: &mut SafetyConfig<N>,
    heartbeat_ms: &mut u16,
    access: &mut AccessControl<N>,
) -> Result<Option<NodeId>, PersistError> {
    access.restore(Persisted::NEW);
    let mut image = [0u8; MAX_IMAGE];
    let Some(len) = storage::load(flash, &mut image).map_err(PersistError::Storage)? else {
        return Ok(None);
    };
    let restored = decode::<N>(image.get(..len).ok_or(PersistError::Malformed)?)?;
    access.restore(restored.access);
    let Some(parameters) = restored.parameters else {
        return Ok(None);
    };
    *safety = parameters.safety;
    *heartbeat_ms = parameters.heartbeat_ms;
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

    fn access() -> Persisted<2> {
        Persisted {
            secret: Some(Secret {
                salt: [0x5A; SALT_LEN],
                hash: [0xC3; 32],
            }),
            audit: Audit {
                changes: 3,
                before: [0x1234, 0],
                after: [0x1234, 0xBEEF],
            },
        }
    }

    fn node(id: u8) -> NodeId {
        NodeId::new(id).unwrap()
    }

    fn encoded() -> ([u8; MAX_IMAGE], usize) {
        let mut out = [0u8; MAX_IMAGE];
        let len = encode(Some((&sample(), 250)), &access(), node(7), &mut out);
        (out, len)
    }

    /// Where the parameters start in [`encoded`]: header, salt and hash, counter, signatures.
    const PARAMETERS_AT: usize = HEADER + SALT_LEN + 32 + 4 + 4 * 2;

    #[test]
    fn image_round_trips_with_the_node_id() {
        let (out, len) = encoded();
        assert_eq!(
            decode::<2>(&out[..len]),
            Ok(Image {
                parameters: Some(Parameters {
                    safety: sample(),
                    heartbeat_ms: 250,
                }),
                access: access(),
                node_id: node(7),
            })
        );
    }

    #[test]
    fn sc_req_43_an_image_without_parameters_keeps_secret_and_audit() {
        let mut out = [0u8; MAX_IMAGE];
        let len = encode::<2>(None, &access(), node(7), &mut out);
        assert_eq!(len, PARAMETERS_AT);
        assert_eq!(
            decode::<2>(&out[..len]),
            Ok(Image {
                parameters: None,
                access: access(),
                node_id: node(7),
            })
        );
        let without_secret = Persisted {
            secret: None,
            ..access()
        };
        let len = encode::<2>(None, &without_secret, node(7), &mut out);
        assert_eq!(decode::<2>(&out[..len]).unwrap().access, without_secret);
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
        for flags in [0x04, 0x80, 0xFF] {
            let mut copy = out;
            copy[2] = flags;
            assert_eq!(decode::<2>(&copy[..len]), Err(PersistError::Malformed));
        }
        out[0] = 9;
        assert_eq!(
            decode::<2>(&out[..len]),
            Err(PersistError::UnknownVersion(9))
        );
    }

    /// A version 1 image (no node-ID) is never misread as version 3, whatever it holds.
    #[test]
    fn a_version_1_image_is_refused_as_the_previous_format() {
        let (mut out, len) = encoded();
        out[0] = 1;
        assert_eq!(
            decode::<2>(&out[..len]),
            Err(PersistError::PreviousFormat(1))
        );
    }

    /// A version 2 image (no access control) is not misread as version 3: refused, so the
    /// device starts on its defaults, not validated.
    #[test]
    fn a_version_2_image_is_refused_as_the_previous_format() {
        let (mut out, len) = encoded();
        out[0] = 2;
        assert_eq!(
            decode::<2>(&out[..len]),
            Err(PersistError::PreviousFormat(2))
        );
    }

    #[test]
    fn an_out_of_range_mapping_count_is_refused_not_panicking() {
        let (mut out, len) = encoded();
        // First record's mapping count sits after the parameters' header and 12 bytes of
        // the record.
        out[PARAMETERS_AT + PARAMETERS_HEADER + 12] = 200;
        assert_eq!(decode::<2>(&out[..len]), Err(PersistError::Malformed));
    }
}
