//! The stored parameter image: what 0x1010 saves and a reset restores.
//!
//! The image is serialised here into a small, versioned byte layout and handed to
//! [`crate::canopen::storage`], which makes storing it atomic. It is the shell's header, the
//! LSS settings when LSS stored some (with the crate's `lss` feature, [`crate::canopen::lss`]:
//! the node-ID and bit rate, in the same record as the parameters, so one atomic store covers
//! both), the access control's stored part ([`super::access`]: the salted hash of the device
//! secret and the audit record), then the section of the safety protocol in the node's slot
//! ([`SafetyProtocol::persist`]; the SRDO table's layout is on [`super::SrdoTable`]). Parsing
//! is strict: a wrong version, unknown flags, a length that does not add up, an out-of-range
//! node-ID, another number of signatures than the protocol's (or whatever the protocol refuses
//! in its section: a wrong SRDO count, an out-of-range count) is refused as a whole, and the
//! node then runs on its defaults (which are not validated, so it stays in the safe state
//! until a tool configures it).
//!
//! 0x1011 (restore defaults) keeps the access part and the LSS settings: it stores an image
//! without parameters instead of erasing, unless there is nothing to keep, so no SDO write
//! removes the secret or the audit record (SC_REQ_43), nor the node's LSS address. 0x1010
//! keeps the LSS settings stored; LSS store configuration ([`store_lss`]) rewrites only them,
//! leaving the stored parameters byte for byte as they were. Without the `lss` feature no
//! image has LSS settings: bit 2 of the flags is unknown there, so an image with them is
//! refused as malformed, and every image is the layout's without them, byte for byte.
//!
//! The image carries the node-ID of the device that stored it. 0x13FE can only hold A5h on a
//! device whose configuration was validated there (by the tool, or restored from an image
//! stored under the same node-ID), so that node-ID is the one the configuration was validated
//! for; the node withdraws the validity when it starts under another node-ID (IEC 61784-3
//! addressing: the stored COB-IDs are absolute and may belong to another node there).
//!
//! Layout (version 3), all integers little-endian:
//!
//! | bytes | field |
//! |-------|-------|
//! | 1 | format version (3) |
//! | 1 | node-ID of the device that stored the image, `1..=127` |
//! | 1 | flags: bit 0 the parameters follow, bit 1 a secret follows, bit 2 LSS settings follow (`lss` feature); other bits 0 |
//! | 1 | number of the protocol's signatures `M` (the SRDO table: one per SRDO) |
//! | 2 | if bit 2: the LSS node-ID (FFh: unconfigured) and bit-timing index (FFh: none) |
//! | 16 + 32 | if bit 1: the secret's salt, `SHA-256(salt ‖ secret)` |
//! | 4 | audit: validated changes |
//! | 2 M + 2 M | audit: the signatures before, then after, the last validated change |
//! | 2 | if bit 0: 0x1017 producer heartbeat time |
//! | the rest | if bit 0: the protocol's section |
//!
//! Images of versions 1 (no node-ID) and 2 (no access control) are refused
//! ([`PersistError::PreviousFormat`]): no hardware ever ran a firmware that wrote them, and a
//! second parser for them would be flash spent on nothing.

use super::SrdoTable;
use super::access::{AccessControl, Audit, Persisted, SALT_LEN, Secret};
use super::slot::SafetyProtocol;
#[cfg(feature = "lss")]
use crate::canopen::lss::LssSettings;
use crate::canopen::node_id::NodeId;
use crate::canopen::storage::{self, Flash, StorageError};
use crate::safety::MAX_SRDOS;

/// Format version of the layout above.
const VERSION: u8 = 3;
/// Flag: the parameters follow.
const HAS_PARAMETERS: u8 = 0x01;
/// Flag: a secret follows.
const HAS_SECRET: u8 = 0x02;
/// Flag: LSS settings follow the header (the `lss` feature's).
#[cfg(feature = "lss")]
const HAS_LSS: u8 = 0x04;
/// Every flag this firmware knows.
#[cfg(feature = "lss")]
const FLAGS: u8 = HAS_PARAMETERS | HAS_SECRET | HAS_LSS;
/// Every flag this firmware knows: without the `lss` feature, not the LSS settings'.
#[cfg(not(feature = "lss"))]
const FLAGS: u8 = HAS_PARAMETERS | HAS_SECRET;
/// Bytes of the shell's header: version, node-ID, flags, `M`.
const HEADER: usize = 4;
/// Bytes of the LSS settings in an image: with the `lss` feature, the node-ID and the
/// bit-timing index.
#[cfg(feature = "lss")]
pub(super) const LSS_LEN: usize = 2;
/// Bytes of the LSS settings in an image: none without the `lss` feature.
#[cfg(not(feature = "lss"))]
pub(super) const LSS_LEN: usize = 0;
/// The most signatures a protocol has: one per SRDO of the largest SRDO table.
const MAX_SIGNATURES: usize = MAX_SRDOS;
/// Bytes of the access part at most: salt, hash, change counter, two signatures each.
#[cfg(test)]
const ACCESS_MAX: usize = SALT_LEN + 32 + 4 + 4 * MAX_SIGNATURES;
/// Bytes of the parameters' own header: the heartbeat time.
const PARAMETERS_HEADER: usize = 2;
/// The largest protocol section an image holds: the SRDO table's of the largest device (64
/// SRDOs with 16 mapping entries each). A protocol whose
/// [`MAX_PERSISTED`](SafetyProtocol::MAX_PERSISTED) is larger does not build.
pub const MAX_SECTION: usize = SrdoTable::<MAX_SRDOS>::MAX_PERSISTED;
/// The largest image of any device (each device's own is its protocol's
/// [`Image`](SafetyProtocol::Image), sized for it).
#[cfg(test)]
pub const MAX_IMAGE: usize = HEADER + LSS_LEN + ACCESS_MAX + PARAMETERS_HEADER + MAX_SECTION;

/// Why stored parameters were not used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PersistError {
    /// The medium failed.
    Storage(StorageError),
    /// The stored image has a format version this firmware does not know.
    UnknownVersion(u8),
    /// The stored image is for a device with another number of SRDOs (or of signatures in
    /// its audit record).
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

/// Serialises the LSS settings when given (`lss` feature), the access part, and the
/// parameters when given (`protocol`'s section and the heartbeat time), of the device with
/// `node_id` into `out`; returns the length used.
fn encode<P: SafetyProtocol>(
    parameters: Option<(&P, u16)>,
    access: &Persisted<P::Signatures>,
    node_id: NodeId,
    #[cfg(feature = "lss")] lss: Option<LssSettings>,
    out: &mut [u8],
) -> usize {
    const {
        assert!(
            P::MAX_PERSISTED <= MAX_SECTION,
            "the protocol's section does not fit"
        );
        assert!(
            core::mem::size_of::<P::Image>()
                >= HEADER
                    + LSS_LEN
                    + SALT_LEN
                    + 32
                    + 4
                    + 2 * core::mem::size_of::<P::Signatures>()
                    + PARAMETERS_HEADER
                    + P::MAX_PERSISTED,
            "the protocol's image buffer does not hold its largest image"
        );
        assert!(
            core::mem::size_of::<P::Signatures>() <= 2 * MAX_SIGNATURES,
            "the protocol's signatures do not fit"
        );
    };
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
    #[cfg(feature = "lss")]
    if lss.is_some() {
        flags |= HAS_LSS;
    }
    let audit = &access.audit;
    // At most MAX_SIGNATURES (checked above), so the count fits its byte.
    let count = audit.after.as_ref().len() as u8;
    push(&[VERSION, node_id.raw(), flags, count]);
    #[cfg(feature = "lss")]
    if let Some(lss) = lss {
        push(&lss.encode());
    }
    if let Some(secret) = &access.secret {
        push(&secret.salt);
        push(&secret.hash);
    }
    push(&audit.changes.to_le_bytes());
    for signature in audit.before.as_ref().iter().chain(audit.after.as_ref()) {
        push(&signature.to_le_bytes());
    }
    let Some((protocol, heartbeat_ms)) = parameters else {
        return at.min(out.len());
    };
    push(&heartbeat_ms.to_le_bytes());
    let len = out.len();
    let Some(section) = out.get_mut(at..) else {
        return len; // The buffer holds the access part (checked above): not reached.
    };
    (at + protocol.persist(section).min(P::MAX_PERSISTED)).min(len)
}

/// What the shell's part of an image holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Header<S> {
    /// 0x1017, when the image holds parameters (not when 0x1011 stored it).
    heartbeat_ms: Option<u16>,
    /// The access control's stored part.
    access: Persisted<S>,
    /// The node-ID of the device that stored it.
    node_id: NodeId,
    /// The LSS settings, when LSS stored some.
    #[cfg(feature = "lss")]
    lss: Option<LssSettings>,
}

/// Parses a stored image, the protocol's section (if any) into `protocol`; all or nothing
/// (`protocol` is unchanged on an error).
fn decode<P: SafetyProtocol>(
    bytes: &[u8],
    protocol: &mut P,
) -> Result<Header<P::Signatures>, PersistError> {
    let mut reader = Reader::new(bytes);
    match reader.u8()? {
        VERSION => {}
        version @ (1 | 2) => return Err(PersistError::PreviousFormat(version)),
        version => return Err(PersistError::UnknownVersion(version)),
    }
    let raw_node_id = reader.u8()?;
    let node_id = NodeId::new(raw_node_id).map_err(|_| PersistError::BadNodeId(raw_node_id))?;
    let flags = reader.u8()?;
    if flags & !FLAGS != 0 {
        return Err(PersistError::Malformed);
    }
    let mut access = Persisted::new(P::NO_SIGNATURES);
    if usize::from(reader.u8()?) != access.audit.after.as_ref().len() {
        return Err(PersistError::SrdoCountMismatch);
    }
    #[cfg(feature = "lss")]
    let lss = if flags & HAS_LSS != 0 {
        Some(LssSettings::decode(reader.take()?).ok_or(PersistError::Malformed)?)
    } else {
        None
    };
    if flags & HAS_SECRET != 0 {
        access.secret = Some(Secret {
            salt: reader.take()?,
            hash: reader.take()?,
        });
    }
    let Audit {
        changes,
        before,
        after,
    } = &mut access.audit;
    *changes = reader.u32()?;
    for signature in before.as_mut().iter_mut().chain(after.as_mut()) {
        *signature = reader.u16()?;
    }
    let heartbeat_ms = if flags & HAS_PARAMETERS != 0 {
        let heartbeat_ms = reader.u16()?;
        protocol.restore(reader.rest())?;
        Some(heartbeat_ms)
    } else if reader.is_empty() {
        None
    } else {
        return Err(PersistError::Malformed);
    };
    Ok(Header {
        heartbeat_ms,
        access,
        node_id,
        #[cfg(feature = "lss")]
        lss,
    })
}

/// Stores the parameters (0x1010) of the device with `node_id`, with the access control's
/// stored part and the LSS settings stored before (`lss`, with the `lss` feature).
pub(super) fn store<F: Flash, P: SafetyProtocol>(
    flash: &mut F,
    protocol: &P,
    heartbeat_ms: u16,
    node_id: NodeId,
    access: &Persisted<P::Signatures>,
    #[cfg(feature = "lss")] lss: Option<LssSettings>,
) -> Result<(), StorageError> {
    let mut image = P::image();
    let image = image.as_mut();
    let len = encode(
        Some((protocol, heartbeat_ms)),
        access,
        node_id,
        #[cfg(feature = "lss")]
        lss,
        image,
    );
    storage::store(flash, image.get(..len).unwrap_or(image))
}

/// LSS store configuration (CiA 305 Fig. 36): the LSS settings `lss` in the stored image,
/// atomically, everything else of it byte for byte as it was. With nothing stored, an image
/// without parameters (the access control's stored part `access`, of the device with
/// `node_id`, and `lss`). A stored image this firmware does not read (another format
/// version, unknown flags, truncated) is not rewritten: [`StorageError::Corrupt`], nothing
/// changes (the node reported it at start-up, and a new image would hide that).
#[cfg(feature = "lss")]
pub(super) fn store_lss<F: Flash, P: SafetyProtocol>(
    flash: &mut F,
    node_id: NodeId,
    access: &Persisted<P::Signatures>,
    lss: LssSettings,
) -> Result<(), StorageError> {
    let mut image = P::image();
    let image = image.as_mut();
    let len = match storage::load(flash, image)? {
        None => encode::<P>(None, access, node_id, Some(lss), image),
        Some(len) => with_lss(image, len, lss)?,
    };
    storage::store(flash, image.get(..len).unwrap_or(image))
}

/// Puts `lss` into the stored image of `len` bytes at the start of `image`, in place: over
/// the LSS settings it holds, or inserted after the header with the flag set. Returns the
/// new length.
#[cfg(feature = "lss")]
fn with_lss(image: &mut [u8], len: usize, lss: LssSettings) -> Result<usize, StorageError> {
    let bytes = lss.encode();
    let readable = len >= HEADER
        && image.first() == Some(&VERSION)
        && image.get(2).is_some_and(|flags| flags & !FLAGS == 0);
    if !readable {
        return Err(StorageError::Corrupt);
    }
    let has_lss = image.get(2).is_some_and(|flags| flags & HAS_LSS != 0);
    if has_lss {
        image
            .get_mut(HEADER..HEADER + LSS_LEN)
            .ok_or(StorageError::Corrupt)?
            .copy_from_slice(&bytes);
        return Ok(len);
    }
    let new_len = len + LSS_LEN;
    if new_len > image.len() {
        return Err(StorageError::TooLarge);
    }
    // Moved up a byte at a time from the end, not by `copy_within`: that links the general
    // `memmove` into the images for this one copy, made once per LSS store
    // (`docs/footprint.md`).
    for index in (HEADER..len).rev() {
        let byte = image.get(index).copied().ok_or(StorageError::Corrupt)?;
        let moved = image
            .get_mut(index + LSS_LEN)
            .ok_or(StorageError::TooLarge)?;
        *moved = byte;
    }
    image
        .get_mut(HEADER..HEADER + LSS_LEN)
        .ok_or(StorageError::TooLarge)?
        .copy_from_slice(&bytes);
    if let Some(flags) = image.get_mut(2) {
        *flags |= HAS_LSS;
    }
    Ok(new_len)
}

/// 0x1011: the defaults at the next reset. Erases the stored parameters when there is
/// nothing of the access control and no LSS settings (`lss` feature) to keep; otherwise
/// stores an image with the access part and the LSS settings alone, so the secret and the
/// audit record stay (SC_REQ_43), and the node's LSS address.
pub(super) fn restore_defaults<F: Flash, P: SafetyProtocol>(
    flash: &mut F,
    node_id: NodeId,
    access: &Persisted<P::Signatures>,
    #[cfg(feature = "lss")] lss: Option<LssSettings>,
) -> Result<(), StorageError> {
    let nothing_to_keep = *access == Persisted::new(P::NO_SIGNATURES);
    #[cfg(feature = "lss")]
    let nothing_to_keep = nothing_to_keep && lss.is_none();
    if nothing_to_keep {
        return storage::restore_defaults(flash);
    }
    let mut image = P::image();
    let image = image.as_mut();
    let len = encode::<P>(
        None,
        access,
        node_id,
        #[cfg(feature = "lss")]
        lss,
        image,
    );
    storage::store(flash, image.get(..len).unwrap_or(image))
}

/// Loads stored parameters into `protocol` and `heartbeat_ms`, the access control's stored
/// part into `access` and the LSS settings into `lss` (`lss` feature): `Ok(Some(node-ID))`
/// when parameters were restored, with the node-ID of the device that stored them;
/// `Ok(None)` when none are stored (defaults stay); `Err` when the stored image is unusable
/// (nothing else changed, the caller keeps the defaults, `access` holds no secret and no
/// audit record: a damaged image is a new device, see docs/access-protection.md; and `lss`
/// is `None`: no LSS address).
pub(super) fn load<F: Flash, P: SafetyProtocol>(
    flash: &mut F,
    protocol: &mut P,
    heartbeat_ms: &mut u16,
    access: &mut AccessControl<P::Signatures>,
    #[cfg(feature = "lss")] lss: &mut Option<LssSettings>,
) -> Result<Option<NodeId>, PersistError> {
    access.restore(Persisted::new(P::NO_SIGNATURES));
    #[cfg(feature = "lss")]
    {
        *lss = None;
    }
    let mut image = P::image();
    let image = image.as_mut();
    let Some(len) = storage::load(flash, image).map_err(PersistError::Storage)? else {
        return Ok(None);
    };
    let header = decode(image.get(..len).ok_or(PersistError::Malformed)?, protocol)?;
    access.restore(header.access);
    #[cfg(feature = "lss")]
    {
        *lss = header.lss;
    }
    let Some(stored_heartbeat_ms) = header.heartbeat_ms else {
        return Ok(None);
    };
    *heartbeat_ms = stored_heartbeat_ms;
    Ok(Some(header.node_id))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canopen::lss::LssSettings;
    #[cfg(feature = "lss")]
    use crate::canopen::storage::RamFlash;
    use crate::safety::config::SafetyConfig;

    fn sample() -> SafetyConfig<2> {
        let mut config = SafetyConfig::<2>::predefined(1, &[0x6000_0108, 0x6001_0108], &[]);
        config.srdos[1].direction = 2;
        config.srdos[1].signature = 0xBEEF;
        config.configuration_valid = 0xA5;
        config
    }

    fn access() -> Persisted<[u16; 2]> {
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

    /// A stopped SRDO table of `N` SRDOs, on the pre-defined set of node 1.
    fn table<const N: usize>() -> SrdoTable<N> {
        SrdoTable::new(&crate::node::tests::config(1)).unwrap()
    }

    /// [`decode`] into a fresh table of `N` SRDOs: the header and the table's records.
    fn decode<const N: usize>(
        bytes: &[u8],
    ) -> Result<(Header<[u16; N]>, SafetyConfig<N>), PersistError> {
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
        let len = encode(
            Some((&table, 250)),
            &access(),
            node(7),
            #[cfg(feature = "lss")]
            None,
            &mut out,
        );
        (out, len)
    }

    /// Where the parameters start in [`encoded`]: header, salt and hash, counter, signatures.
    const PARAMETERS_AT: usize = HEADER + SALT_LEN + 32 + 4 + 4 * 2;

    #[test]
    fn image_round_trips_with_the_node_id() {
        let (out, len) = encoded();
        assert_eq!(
            decode::<2>(&out[..len]),
            Ok((
                Header {
                    heartbeat_ms: Some(250),
                    access: access(),
                    node_id: node(7),
                    #[cfg(feature = "lss")]
                    lss: None,
                },
                sample()
            ))
        );
    }

    #[test]
    fn sc_req_43_an_image_without_parameters_keeps_secret_and_audit() {
        let mut out = [0u8; MAX_IMAGE];
        let len = encode::<SrdoTable<2>>(
            None,
            &access(),
            node(7),
            #[cfg(feature = "lss")]
            None,
            &mut out,
        );
        assert_eq!(len, PARAMETERS_AT);
        let untouched = table::<2>().config().clone();
        assert_eq!(
            decode::<2>(&out[..len]),
            Ok((
                Header {
                    heartbeat_ms: None,
                    access: access(),
                    node_id: node(7),
                    #[cfg(feature = "lss")]
                    lss: None,
                },
                untouched
            ))
        );
        let without_secret = Persisted {
            secret: None,
            ..access()
        };
        let len = encode::<SrdoTable<2>>(
            None,
            &without_secret,
            node(7),
            #[cfg(feature = "lss")]
            None,
            &mut out,
        );
        assert_eq!(decode::<2>(&out[..len]).unwrap().0.access, without_secret);
        assert_eq!(decode::<2>(&out[..len + 1]), Err(PersistError::Malformed));
    }

    /// An image with LSS settings is read by a device with the `lss` feature and refused as
    /// malformed by one without it (bit 2 of the flags is unknown there): never misread.
    #[test]
    fn cia305_an_image_with_lss_settings_is_read_only_with_the_lss_feature() {
        let (out, len) = encoded();
        let lss = LssSettings {
            node_id: Some(node(42)),
            bit_rate: None,
        };
        let mut image = out[..len].to_vec();
        image[2] |= 0x04;
        image.splice(HEADER..HEADER, lss.encode());
        let read = decode::<2>(&image).map(|(header, config)| (header.access, config));
        #[cfg(feature = "lss")]
        {
            assert_eq!(read, Ok((access(), sample())));
            assert_eq!(decode::<2>(&image).unwrap().0.lss, Some(lss));
        }
        #[cfg(not(feature = "lss"))]
        assert_eq!(read, Err(PersistError::Malformed));
    }

    #[cfg(feature = "lss")]
    #[test]
    fn cia305_lss_settings_round_trip_beside_the_parameters() {
        let lss = LssSettings {
            node_id: Some(node(42)),
            bit_rate: Some(crate::canopen::lss::BitRate::Kbit125),
        };
        let mut out = [0u8; MAX_IMAGE];
        let mut table = table::<2>();
        table.safety = sample();
        let len = encode(Some((&table, 250)), &access(), node(7), Some(lss), &mut out);
        let (header, config) = decode::<2>(&out[..len]).unwrap();
        assert_eq!(header.lss, Some(lss));
        assert_eq!(
            (header.access, header.node_id, config),
            (access(), node(7), sample())
        );
        // Bytes that are not LSS settings are refused as a whole.
        for bad in [[0u8, 0xFF], [0x80, 0xFF], [1, 5]] {
            let mut copy = out;
            copy[HEADER..HEADER + LSS_LEN].copy_from_slice(&bad);
            assert_eq!(decode::<2>(&copy[..len]), Err(PersistError::Malformed));
        }
    }

    /// The stored image as bytes.
    #[cfg(feature = "lss")]
    fn raw(flash: &mut RamFlash<2048>) -> std::vec::Vec<u8> {
        let mut buf = [0u8; 2048];
        let len = storage::load(flash, &mut buf).unwrap().unwrap();
        buf[..len].to_vec()
    }

    /// CiA 305 Fig. 36: store configuration changes the LSS settings of the stored image and
    /// nothing else of it, byte for byte.
    #[cfg(feature = "lss")]
    #[test]
    fn cia305_store_configuration_rewrites_only_the_lss_settings() {
        let mut flash = RamFlash::<2048>::new();
        let mut table = table::<2>();
        table.safety = sample();
        store(&mut flash, &table, 250, node(7), &access(), None).unwrap();
        let before = raw(&mut flash);
        let first = LssSettings {
            node_id: Some(node(42)),
            bit_rate: None,
        };
        store_lss::<_, SrdoTable<2>>(&mut flash, node(7), &access(), first).unwrap();
        let after = raw(&mut flash);
        let mut expected = before.clone();
        expected[2] |= HAS_LSS;
        expected.splice(HEADER..HEADER, first.encode());
        assert_eq!(after, expected);
        let second = LssSettings {
            node_id: None,
            bit_rate: Some(crate::canopen::lss::BitRate::Kbit500),
        };
        store_lss::<_, SrdoTable<2>>(&mut flash, node(7), &access(), second).unwrap();
        let mut expected = after.clone();
        expected[HEADER..HEADER + LSS_LEN].copy_from_slice(&second.encode());
        assert_eq!(raw(&mut flash), expected);
        // 0x1010 keeps them; so does 0x1011 (an image without parameters).
        store(&mut flash, &table, 100, node(7), &access(), Some(second)).unwrap();
        assert_eq!(decode::<2>(&raw(&mut flash)).unwrap().0.lss, Some(second));
        restore_defaults::<_, SrdoTable<2>>(
            &mut flash,
            node(7),
            &Persisted::new([0; 2]),
            Some(second),
        )
        .unwrap();
        let (header, _) = decode::<2>(&raw(&mut flash)).unwrap();
        assert_eq!((header.lss, header.heartbeat_ms), (Some(second), None));
        // With nothing stored, an image of the LSS settings and the access part alone.
        let mut empty = RamFlash::<2048>::new();
        store_lss::<_, SrdoTable<2>>(&mut empty, node(7), &access(), first).unwrap();
        let (header, _) = decode::<2>(&raw(&mut empty)).unwrap();
        assert_eq!(
            (header.lss, header.access, header.heartbeat_ms),
            (Some(first), access(), None)
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
        for flags in [0x08, 0x80, 0xFF] {
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
        // First record's mapping count sits after the access part, the heartbeat time, 0x13FE,
        // N and 12 bytes of the record.
        out[PARAMETERS_AT + PARAMETERS_HEADER + 2 + 12] = 200;
        assert_eq!(decode::<2>(&out[..len]), Err(PersistError::Malformed));
    }

    /// The figure the protocol slot's documentation gives for the largest section, and the
    /// largest image with the access part of 64 signatures.
    #[test]
    fn the_largest_section_is_the_64_srdo_table_s() {
        assert_eq!(MAX_SECTION, 5_058);
        assert_eq!(ACCESS_MAX, 308);
        let lss = if cfg!(feature = "lss") { 2 } else { 0 };
        assert_eq!(MAX_IMAGE, 5_372 + lss);
    }

    /// The image buffer is the device's own size: 143 bytes per SRDO, 145 with the `lss`
    /// feature (the product's 4 SRDOs: 572 or 580 bytes on the stack while parameters are
    /// stored or restored, where the largest table's would be 5,372 or 5,374), and the
    /// largest image of that device, LSS settings included with the feature, fits it (the
    /// build checks it too).
    #[test]
    fn the_image_buffer_is_sized_for_the_device_and_holds_its_largest_image() {
        assert_eq!(
            core::mem::size_of::<<SrdoTable<4> as SafetyProtocol>::Image>(),
            if cfg!(feature = "lss") { 580 } else { 572 }
        );
        let mut table = table::<4>();
        for record in &mut table.safety.srdos {
            record.mapping_count = 16;
        }
        let access = Persisted {
            secret: Some(Secret {
                salt: [0x5A; SALT_LEN],
                hash: [0xC3; 32],
            }),
            audit: Audit {
                changes: u32::MAX,
                before: [0xFFFF; 4],
                after: [0xFFFF; 4],
            },
        };
        let mut image = <SrdoTable<4> as SafetyProtocol>::image();
        let len = encode(
            Some((&table, 100)),
            &access,
            node(1),
            #[cfg(feature = "lss")]
            Some(LssSettings {
                node_id: Some(node(127)),
                bit_rate: Some(crate::canopen::lss::BitRate::Kbit500),
            }),
            image.as_mut(),
        );
        // 4 header + 2 LSS (with the feature) + 52 secret and counter + 16 signatures + 2
        // heartbeat + 2 + 4 records of 79.
        assert_eq!(len, 4 + LSS_LEN + 52 + 16 + 2 + 2 + 4 * 79);
        assert!(len <= image.as_ref().len(), "{len}");
    }
}
