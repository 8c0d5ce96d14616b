//! The stored parameter image: what 0x1010 saves and a reset restores.
//!
//! The image is serialised here into a small, versioned byte layout and handed to
//! [`crate::canopen::storage`], which makes storing it atomic. It is the shell's header
//! followed by the section of the safety protocol in the node's slot
//! ([`SafetyProtocol::persist`]; the SRDO table's layout is on [`super::SrdoTable`]). Parsing
//! is strict: a wrong version, a length that does not add up, an out-of-range node-ID (or
//! whatever the protocol refuses in its section: a wrong SRDO count, an out-of-range count) is
//! refused as a whole, and the node then runs on its defaults (which are not validated, so it
//! stays in the safe state until a tool configures it).
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
//! | the rest | the protocol's section |

use super::SrdoTable;
use super::slot::SafetyProtocol;
use crate::canopen::node_id::NodeId;
use crate::canopen::storage::{self, Flash, StorageError};
use crate::safety::MAX_SRDOS;

/// Format version of the layout above.
const VERSION: u8 = 2;
/// Bytes of the shell's header.
const HEADER: usize = 4;
/// The largest protocol section an image holds: the SRDO table's of the largest device (64
/// SRDOs with 16 mapping entries each). A protocol whose
/// [`MAX_PERSISTED`](SafetyProtocol::MAX_PERSISTED) is larger does not build.
pub const MAX_SECTION: usize = SrdoTable::<MAX_SRDOS>::MAX_PERSISTED;
/// The largest image.
pub const MAX_IMAGE: usize = HEADER + MAX_SECTION;

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

/// A cursor over stored bytes that never reads past the end.
pub(super) struct Reader<'a> {
    bytes: &'a [u8],
}

impl<'a> Reader<'a> {
    /// A cursor at the start of `bytes`.
    pub(super) fn new(bytes: &'a [u8]) -> Self {
        Reader { bytes }
    }
    fn take<const L: usize>(&mut self) -> Result<[u8; L], PersistError> {
        let (head, rest) = self
            .bytes
            .split_at_checked(L)
            .ok_or(PersistError::Malformed)?;
        self.bytes = rest;
        <[u8; L]>::try_from(head).map_err(|_| PersistError::Malformed)
    }
    pub(super) fn u8(&mut self) -> Result<u8, PersistError> {
        Ok(self.take::<1>()?[0])
    }
    pub(super) fn u16(&mut self) -> Result<u16, PersistError> {
        Ok(u16::from_le_bytes(self.take()?))
    }
    pub(super) fn u32(&mut self) -> Result<u32, PersistError> {
        Ok(u32::from_le_bytes(self.take()?))
    }
    /// `true` when every byte was read.
    pub(super) fn is_empty(&self) -> bool {
        self.bytes.is_empty()
    }
    /// The bytes not yet read.
    fn rest(&self) -> &'a [u8] {
        self.bytes
    }
}

/// Serialises the heartbeat time, the storing device's node-ID and `protocol`'s section into
/// `out`; returns the length used.
fn encode<P: SafetyProtocol>(
    protocol: &P,
    heartbeat_ms: u16,
    node_id: NodeId,
    out: &mut [u8; MAX_IMAGE],
) -> usize {
    const {
        assert!(
            P::MAX_PERSISTED <= MAX_SECTION,
            "the protocol's section does not fit"
        )
    };
    let Some((header, section)) = out.split_first_chunk_mut::<HEADER>() else {
        return 0; // `HEADER < MAX_IMAGE`: not reached.
    };
    let [heartbeat_low, heartbeat_high] = heartbeat_ms.to_le_bytes();
    *header = [VERSION, node_id.raw(), heartbeat_low, heartbeat_high];
    HEADER + protocol.persist(section).min(MAX_SECTION)
}

/// What the shell's header holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Header {
    heartbeat_ms: u16,
    /// The node-ID of the device that stored it.
    node_id: NodeId,
}

/// Parses a stored image, the protocol's section into `protocol`; all or nothing (`protocol`
/// is unchanged on an error).
fn decode<P: SafetyProtocol>(bytes: &[u8], protocol: &mut P) -> Result<Header, PersistError> {
    let mut reader = Reader::new(bytes);
    let version = reader.u8()?;
    match version {
        VERSION => {}
        1 => return Err(PersistError::PreviousFormat(version)),
        _ => return Err(PersistError::UnknownVersion(version)),
    }
    let raw_node_id = reader.u8()?;
    let node_id = NodeId::new(raw_node_id).map_err(|_| PersistError::BadNodeId(raw_node_id))?;
    let heartbeat_ms = reader.u16()?;
    protocol.restore(reader.rest())?;
    Ok(Header {
        heartbeat_ms,
        node_id,
    })
}

/// Stores the parameters (0x1010) of the device with `node_id`.
pub(super) fn store<F: Flash, P: SafetyProtocol>(
    flash: &mut F,
    protocol: &P,
    heartbeat_ms: u16,
    node_id: NodeId,
) -> Result<(), StorageError> {
    let mut image = [0u8; MAX_IMAGE];
    let len = encode(protocol, heartbeat_ms, node_id, &mut image);
    storage::store(flash, image.get(..len).unwrap_or(&image))
}

/// Loads stored parameters into `protocol` and `heartbeat_ms`: `Ok(Some(node-ID))` when they
/// were restored, with the node-ID of the device that stored them; `Ok(None)` when nothing is
/// stored (defaults stay); `Err` when the stored image is unusable (nothing changed, the
/// caller keeps the defaults).
pub(super) fn load<F: Flash, P: SafetyProtocol>(
    flash: &mut F,
    protocol: &mut P,
    heartbeat_ms: &mut u16,
) -> Result<Option<NodeId>, PersistError> {
    let mut image = [0u8; MAX_IMAGE];
    let Some(len) = storage::load(flash, &mut image).map_err(PersistError::Storage)? else {
        return Ok(None);
    };
    let header = decode(image.get(..len).ok_or(PersistError::Malformed)?, protocol)?;
    *heartbeat_ms = header.heartbeat_ms;
    Ok(Some(header.node_id))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::safety::config::SafetyConfig;

    fn sample() -> SafetyConfig<2> {
        let mut config = SafetyConfig::<2>::predefined(1, &[0x6000_0108, 0x6001_0108], &[]);
        config.srdos[1].direction = 2;
        config.srdos[1].signature = 0xBEEF;
        config.configuration_valid = 0xA5;
        config
    }

    /// A stopped SRDO table of `N` SRDOs, on the pre-defined set of node 1.
    fn table<const N: usize>() -> SrdoTable<N> {
        SrdoTable::new(&crate::node::tests::config(1)).unwrap()
    }

    /// [`decode`] into a fresh table of `N` SRDOs: the header and the table's records.
    fn decode<const N: usize>(bytes: &[u8]) -> Result<(Header, SafetyConfig<N>), PersistError> {
        let mut table = table::<N>();
        let header = super::decode(bytes, &mut table)?;
        Ok((header, table.config().clone()))
    }

    fn node(id: u8) -> NodeId {
        NodeId::new(id).unwrap()
    }

    fn encoded() -> ([u8; MAX_IMAGE], usize) {
        let mut out = [0u8; MAX_IMAGE];
        let mut table = table::<2>();
        table.safety = sample();
        let len = encode(&table, 250, node(7), &mut out);
        (out, len)
    }

    #[test]
    fn image_round_trips_with_the_node_id() {
        let (out, len) = encoded();
        assert_eq!(
            decode::<2>(&out[..len]),
            Ok((
                Header {
                    heartbeat_ms: 250,
                    node_id: node(7),
                },
                sample()
            ))
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
        // First record's mapping count sits after the header, 0x13FE, N and 12 bytes of the
        // record.
        out[HEADER + 2 + 12] = 200;
        assert_eq!(decode::<2>(&out[..len]), Err(PersistError::Malformed));
    }

    /// The figure the protocol slot's documentation gives for the largest section.
    #[test]
    fn the_largest_section_is_the_64_srdo_table_s() {
        assert_eq!(MAX_SECTION, 5_058);
        assert_eq!(MAX_IMAGE, 5_062);
    }
}
