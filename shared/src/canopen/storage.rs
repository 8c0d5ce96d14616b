//! Atomic parameter storage on two flash slots (CiA 301 7.5.2.13 / 7.5.2.14, 0x1010 / 0x1011).
//!
//! A store must never leave a mix of the old and the new parameters, whatever moment the
//! power fails at: a device that restores half of a new configuration and half of an old one
//! could run with a signature that matches neither. The scheme is the classic A/B one:
//!
//! - The medium offers two equal slots ([`Flash`]). Every record goes into the slot that does
//!   *not* hold the newest valid record, so the newest valid record is never erased or written
//!   while a store is in progress.
//! - A record is a header (magic, layout version, kind, sequence number, payload length), the
//!   payload, and a CRC-32 over header and payload. The CRC is written last and is the commit:
//!   until it is complete and matches, the record does not exist.
//! - [`load`] takes the valid record with the newest sequence number (serial-number arithmetic,
//!   so the counter may wrap). A *defaults marker* record ([`restore_defaults`]) says "use the
//!   defaults at the next reset" and is committed the same way.
//!
//! [`RamFlash`] models NOR flash on the host (erased = 0xFF, a write can only clear bits);
//! [`PowerCutFlash`] wraps a medium and loses power after a given number of bytes, tearing the
//! write or erase in progress. The tests cut the power at every byte of a store.
//!
//! The hardware image implements [`Flash`] on two flash sectors; nothing here knows about
//! sectors, alignment or timing beyond what the trait says.

use crc::{CRC_32_ISO_HDLC, Crc, Digest};

/// CRC-32 (ISO-HDLC, as Ethernet and zip use it) that commits a record.
const CRC: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);
/// "CSP1": marks the start of a record.
const MAGIC: u32 = u32::from_le_bytes(*b"CSP1");
/// Record layout version.
const LAYOUT: u8 = 1;
/// Header: magic (4), layout (1), kind (1), reserved (2), sequence (4), payload length (4).
const HEADER_LEN: usize = 16;
/// The CRC that follows the payload.
const CRC_LEN: usize = 4;
/// Record kind: the payload is the stored parameters.
const KIND_PAYLOAD: u8 = 1;
/// Record kind: use the defaults (no payload).
const KIND_DEFAULTS: u8 = 2;

/// One of the two storage slots.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Slot {
    /// The first slot.
    A,
    /// The second slot.
    B,
}

impl Slot {
    /// The other slot.
    pub const fn other(self) -> Slot {
        match self {
            Slot::A => Slot::B,
            Slot::B => Slot::A,
        }
    }
}

/// Why a store or load did not complete.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StorageError {
    /// The payload does not fit in a slot (or in the caller's buffer on load).
    TooLarge,
    /// An access outside a slot was attempted (a bug in the caller or the medium's size).
    OutOfBounds,
    /// The medium reported a failure.
    Medium,
    /// What was written does not read back (worn or failing flash).
    VerifyFailed,
    /// No committed record is left, but a damaged one is: the stored parameters are lost.
    Corrupt,
    /// The power failed during the operation (reported by [`PowerCutFlash`]).
    PowerLost,
}

/// A medium with two equal, independently erasable slots.
pub trait Flash {
    /// Bytes per slot.
    fn slot_len(&self) -> usize;
    /// Reads `buf.len()` bytes of `slot` from `offset`.
    fn read(&mut self, slot: Slot, offset: usize, buf: &mut [u8]) -> Result<(), StorageError>;
    /// Erases `slot` (every byte reads 0xFF afterwards).
    fn erase(&mut self, slot: Slot) -> Result<(), StorageError>;
    /// Writes `data` to `slot` at `offset`; the bytes were erased before.
    fn write(&mut self, slot: Slot, offset: usize, data: &[u8]) -> Result<(), StorageError>;
}

/// A record header as stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Header {
    kind: u8,
    sequence: u32,
    len: u32,
}

impl Header {
    fn encode(self) -> [u8; HEADER_LEN] {
        let mut bytes = [0u8; HEADER_LEN];
        bytes[0..4].copy_from_slice(&MAGIC.to_le_bytes());
        bytes[4] = LAYOUT;
        bytes[5] = self.kind;
        bytes[8..12].copy_from_slice(&self.sequence.to_le_bytes());
        bytes[12..16].copy_from_slice(&self.len.to_le_bytes());
        bytes
    }

    /// The header in `bytes`, when it is one this code wrote.
    fn decode(bytes: &[u8; HEADER_LEN]) -> Option<Header> {
        let word = |at: usize| {
            u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]])
        };
        let kind = bytes[5];
        let known_kind = kind == KIND_PAYLOAD || kind == KIND_DEFAULTS;
        (word(0) == MAGIC && bytes[4] == LAYOUT && known_kind && bytes[6..8] == [0, 0]).then(|| {
            Header {
                kind,
                sequence: word(8),
                len: word(12),
            }
        })
    }

    /// `true` when `self` was written after `other` (RFC 1982 serial-number comparison).
    fn is_newer_than(self, other: Header) -> bool {
        // Reinterpreting the wrapped difference as signed is the point of the comparison.
        #[allow(clippy::cast_possible_wrap)]
        let ahead = self.sequence.wrapping_sub(other.sequence) as i32;
        ahead > 0
    }
}

/// What a slot holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Content {
    /// No record header (erased, or a store torn before its header was complete).
    Empty,
    /// A complete header whose CRC does not match: a torn store, or a damaged record.
    Damaged,
    /// A committed record.
    Committed(Header),
}

/// Reads the header of `slot` and checks the record's CRC, streaming the payload through a
/// small scratch buffer so no buffer of the payload's size is needed.
fn content<F: Flash>(flash: &mut F, slot: Slot) -> Result<Content, StorageError> {
    let mut raw = [0u8; HEADER_LEN];
    flash.read(slot, 0, &mut raw)?;
    let Some(header) = Header::decode(&raw) else {
        return Ok(Content::Empty);
    };
    let len = header.len as usize;
    let fits = len
        .checked_add(HEADER_LEN + CRC_LEN)
        .is_some_and(|total| total <= flash.slot_len());
    if !fits || (header.kind == KIND_DEFAULTS && len != 0) {
        return Ok(Content::Damaged);
    }
    let mut digest = CRC.digest();
    digest.update(&raw);
    let mut scratch = [0u8; 64];
    let mut at = 0;
    while at < len {
        let chunk = (len - at).min(scratch.len());
        flash.read(slot, HEADER_LEN + at, &mut scratch[..chunk])?;
        digest.update(&scratch[..chunk]);
        at += chunk;
    }
    let mut stored = [0u8; CRC_LEN];
    flash.read(slot, HEADER_LEN + len, &mut stored)?;
    Ok(if digest.finalize() == u32::from_le_bytes(stored) {
        Content::Committed(header)
    } else {
        Content::Damaged
    })
}

/// Both slots: the newest committed record, if any, and whether a slot holds a damaged one.
fn scan<F: Flash>(flash: &mut F) -> Result<(Option<(Slot, Header)>, bool), StorageError> {
    let a = content(flash, Slot::A)?;
    let b = content(flash, Slot::B)?;
    let damaged = a == Content::Damaged || b == Content::Damaged;
    let newest = match (a, b) {
        (Content::Committed(a), Content::Committed(b)) if b.is_newer_than(a) => Some((Slot::B, b)),
        (Content::Committed(a), _) => Some((Slot::A, a)),
        (_, Content::Committed(b)) => Some((Slot::B, b)),
        _ => None,
    };
    Ok((newest, damaged))
}

/// Writes a record of `kind` into the slot that does not hold the newest one, then erases
/// the superseded record, so that a later corruption of the new record cannot make an older
/// configuration come back: with no committed record left, [`load`] reports
/// [`StorageError::Corrupt`] instead.
fn commit<F: Flash>(flash: &mut F, kind: u8, payload: &[u8]) -> Result<(), StorageError> {
    let len = u32::try_from(payload.len()).map_err(|_| StorageError::TooLarge)?;
    if HEADER_LEN + payload.len() + CRC_LEN > flash.slot_len() {
        return Err(StorageError::TooLarge);
    }
    let (target, sequence) = match scan(flash)?.0 {
        Some((slot, header)) => (slot.other(), header.sequence.wrapping_add(1)),
        None => (Slot::A, 0),
    };
    let header = Header {
        kind,
        sequence,
        len,
    };
    let encoded = header.encode();
    let mut digest: Digest<'_, u32> = CRC.digest();
    digest.update(&encoded);
    digest.update(payload);
    let crc = digest.finalize().to_le_bytes();

    flash.erase(target)?;
    flash.write(target, 0, &encoded)?;
    flash.write(target, HEADER_LEN, payload)?;
    // The commit: only a complete, matching CRC makes the record exist.
    flash.write(target, HEADER_LEN + payload.len(), &crc)?;
    if content(flash, target)? != Content::Committed(header) {
        return Err(StorageError::VerifyFailed);
    }
    // The new record is committed; the old one goes. A power cut before this erase leaves
    // two committed records and the newer one wins.
    flash.erase(target.other())
}

/// Stores `payload` atomically: after a power failure at any point, [`load`] returns either
/// the previous record or `payload`, never a mix.
pub fn store<F: Flash>(flash: &mut F, payload: &[u8]) -> Result<(), StorageError> {
    commit(flash, KIND_PAYLOAD, payload)
}

/// Records, atomically, that the next [`load`] shall report "nothing stored" so the device
/// starts on its defaults (0x1011, restore default parameters).
pub fn restore_defaults<F: Flash>(flash: &mut F) -> Result<(), StorageError> {
    commit(flash, KIND_DEFAULTS, &[])
}

/// Copies the newest stored payload into `buf` and returns its length; `None` when nothing is
/// stored or the newest record asks for the defaults.
pub fn load<F: Flash>(flash: &mut F, buf: &mut [u8]) -> Result<Option<usize>, StorageError> {
    let (newest, damaged) = scan(flash)?;
    let Some((slot, header)) = newest else {
        return if damaged {
            Err(StorageError::Corrupt)
        } else {
            Ok(None)
        };
    };
    if header.kind == KIND_DEFAULTS {
        return Ok(None);
    }
    let len = header.len as usize;
    let target = buf.get_mut(..len).ok_or(StorageError::TooLarge)?;
    flash.read(slot, HEADER_LEN, target)?;
    // Read again and compare with the CRC checked in `newest`: the bytes handed out are the
    // bytes that were verified, even if the medium changed in between.
    let mut digest = CRC.digest();
    digest.update(&header.encode());
    digest.update(target);
    let mut stored = [0u8; CRC_LEN];
    flash.read(slot, HEADER_LEN + len, &mut stored)?;
    if digest.finalize() != u32::from_le_bytes(stored) {
        return Err(StorageError::VerifyFailed);
    }
    Ok(Some(len))
}

/// Two slots of `N` bytes in RAM that behave like NOR flash: erased bytes read 0xFF and a
/// write can only clear bits. For host tests, the emulator build and the simulator.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RamFlash<const N: usize> {
    slots: [[u8; N]; 2],
}

impl<const N: usize> Default for RamFlash<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> RamFlash<N> {
    /// Two erased slots.
    pub const fn new() -> Self {
        RamFlash {
            slots: [[0xFF; N]; 2],
        }
    }

    /// Two slots of zeros, as a medium in no known state; erase both before use. For a
    /// `static` in zero-initialised RAM (no initial image in flash, no copy on the stack).
    pub const fn zeroed() -> Self {
        RamFlash { slots: [[0; N]; 2] }
    }

    /// The raw bytes of `slot`, for tests that corrupt or inspect the medium.
    pub fn slot_mut(&mut self, slot: Slot) -> &mut [u8; N] {
        &mut self.slots[slot as usize]
    }

    fn range(offset: usize, len: usize) -> Result<core::ops::Range<usize>, StorageError> {
        let end = offset.checked_add(len).ok_or(StorageError::OutOfBounds)?;
        if end > N {
            return Err(StorageError::OutOfBounds);
        }
        Ok(offset..end)
    }
}

/// A medium borrowed for as long as the user lives: a parameter store kept in a `static`
/// (so that the large buffer is never moved through the stack) serves through a reference.
impl<F: Flash + ?Sized> Flash for &mut F {
    fn slot_len(&self) -> usize {
        (**self).slot_len()
    }
    fn read(&mut self, slot: Slot, offset: usize, buf: &mut [u8]) -> Result<(), StorageError> {
        (**self).read(slot, offset, buf)
    }
    fn erase(&mut self, slot: Slot) -> Result<(), StorageError> {
        (**self).erase(slot)
    }
    fn write(&mut self, slot: Slot, offset: usize, data: &[u8]) -> Result<(), StorageError> {
        (**self).write(slot, offset, data)
    }
}

impl<const N: usize> Flash for RamFlash<N> {
    fn slot_len(&self) -> usize {
        N
    }

    fn read(&mut self, slot: Slot, offset: usize, buf: &mut [u8]) -> Result<(), StorageError> {
        let range = Self::range(offset, buf.len())?;
        buf.copy_from_slice(&self.slots[slot as usize][range]);
        Ok(())
    }

    fn erase(&mut self, slot: Slot) -> Result<(), StorageError> {
        self.slots[slot as usize].fill(0xFF);
        Ok(())
    }

    fn write(&mut self, slot: Slot, offset: usize, data: &[u8]) -> Result<(), StorageError> {
        let range = Self::range(offset, data.len())?;
        for (cell, byte) in self.slots[slot as usize][range].iter_mut().zip(data) {
            *cell &= byte;
        }
        Ok(())
    }
}

/// What a torn erase leaves behind in the part it did not reach.
const INDETERMINATE: [u8; 16] = [0xA5; 16];

/// A medium that loses power after `budget` more bytes have been written (an erase counts as
/// one unit). The write in progress is torn: its first bytes land, the rest do not; an erase in
/// progress leaves the first half of the slot erased and the rest indeterminate. Every access
/// after the cut fails with [`StorageError::PowerLost`] until [`PowerCutFlash::power_on`].
#[derive(Clone, Debug)]
pub struct PowerCutFlash<F> {
    inner: F,
    budget: Option<usize>,
    powered: bool,
}

impl<F: Flash> PowerCutFlash<F> {
    /// `inner`, losing power after `budget` bytes (`None`: never).
    pub fn new(inner: F, budget: Option<usize>) -> Self {
        PowerCutFlash {
            inner,
            budget,
            powered: true,
        }
    }

    /// Plans a power cut after `budget` more bytes.
    pub fn cut_after(&mut self, budget: usize) {
        self.budget = Some(budget);
    }

    /// Power comes back, with no further cut planned.
    pub fn power_on(&mut self) {
        self.powered = true;
        self.budget = None;
    }

    /// `true` until the power was cut.
    pub fn powered(&self) -> bool {
        self.powered
    }

    /// The medium underneath.
    pub fn into_inner(self) -> F {
        self.inner
    }

    /// Takes up to `wanted` units from the budget; returns how many may proceed.
    fn spend(&mut self, wanted: usize) -> Result<usize, StorageError> {
        if !self.powered {
            return Err(StorageError::PowerLost);
        }
        match self.budget {
            None => Ok(wanted),
            Some(left) => {
                let granted = left.min(wanted);
                self.budget = Some(left - granted);
                if granted < wanted {
                    self.powered = false;
                }
                Ok(granted)
            }
        }
    }
}

impl<F: Flash> Flash for PowerCutFlash<F> {
    fn slot_len(&self) -> usize {
        self.inner.slot_len()
    }

    fn read(&mut self, slot: Slot, offset: usize, buf: &mut [u8]) -> Result<(), StorageError> {
        if !self.powered {
            return Err(StorageError::PowerLost);
        }
        self.inner.read(slot, offset, buf)
    }

    fn erase(&mut self, slot: Slot) -> Result<(), StorageError> {
        if self.spend(1)? == 1 {
            return self.inner.erase(slot);
        }
        // Torn erase: the first half of the slot ends up erased, the second half in an
        // indeterminate state (modelled as a fixed bit pattern).
        self.inner.erase(slot)?;
        let len = self.inner.slot_len();
        let mut at = len / 2;
        while at < len {
            let chunk = (len - at).min(INDETERMINATE.len());
            self.inner.write(slot, at, &INDETERMINATE[..chunk])?;
            at += chunk;
        }
        Err(StorageError::PowerLost)
    }

    fn write(&mut self, slot: Slot, offset: usize, data: &[u8]) -> Result<(), StorageError> {
        let granted = self.spend(data.len())?;
        self.inner.write(slot, offset, &data[..granted])?;
        if granted < data.len() {
            // The byte being written when the power failed holds a random mix of bits.
            if let Some(&byte) = data.get(granted) {
                self.inner.write(slot, offset + granted, &[byte | 0x5A])?;
            }
            return Err(StorageError::PowerLost);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    type Medium = RamFlash<256>;

    fn loaded<F: Flash>(flash: &mut F) -> Result<Option<std::vec::Vec<u8>>, StorageError> {
        let mut buf = [0u8; 256];
        Ok(load(flash, &mut buf)?.map(|len| buf[..len].to_vec()))
    }

    #[test]
    fn nothing_stored_loads_nothing() {
        assert_eq!(loaded(&mut Medium::new()), Ok(None));
    }

    #[test]
    fn stores_load_back_newest_first_and_alternate_slots() {
        let mut flash = Medium::new();
        store(&mut flash, b"first").unwrap();
        assert_eq!(loaded(&mut flash), Ok(Some(b"first".to_vec())));
        store(&mut flash, b"second, longer").unwrap();
        assert_eq!(loaded(&mut flash), Ok(Some(b"second, longer".to_vec())));
        // The second record went to slot B and the first was erased after the commit.
        assert!(flash.slot_mut(Slot::A).iter().all(|&b| b == 0xFF));
        store(&mut flash, b"").unwrap();
        assert_eq!(loaded(&mut flash), Ok(Some(std::vec::Vec::new())));
        assert!(flash.slot_mut(Slot::B).iter().all(|&b| b == 0xFF));
    }

    /// CiA 301 7.5.2.14: after "restore defaults" the device starts on its defaults; a later
    /// store is used again.
    #[test]
    fn cia301_7_5_2_14_restore_defaults_hides_the_stored_record_until_the_next_store() {
        let mut flash = Medium::new();
        store(&mut flash, b"configured").unwrap();
        restore_defaults(&mut flash).unwrap();
        assert_eq!(loaded(&mut flash), Ok(None));
        store(&mut flash, b"again").unwrap();
        assert_eq!(loaded(&mut flash), Ok(Some(b"again".to_vec())));
    }

    #[test]
    fn a_payload_too_large_for_a_slot_is_refused_and_changes_nothing() {
        let mut flash = Medium::new();
        store(&mut flash, b"kept").unwrap();
        let big = [7u8; 256 - HEADER_LEN - CRC_LEN + 1];
        assert_eq!(store(&mut flash, &big), Err(StorageError::TooLarge));
        assert_eq!(loaded(&mut flash), Ok(Some(b"kept".to_vec())));
        let exact = [7u8; 256 - HEADER_LEN - CRC_LEN];
        store(&mut flash, &exact).unwrap();
        let mut small = [0u8; 8];
        assert_eq!(load(&mut flash, &mut small), Err(StorageError::TooLarge));
    }

    #[test]
    fn a_damaged_record_is_reported_not_replaced_by_an_older_one() {
        let mut flash = Medium::new();
        store(&mut flash, b"old").unwrap();
        store(&mut flash, b"new").unwrap();
        // One bit of the committed payload flips in slot B.
        flash.slot_mut(Slot::B)[HEADER_LEN] ^= 0x01;
        assert_eq!(loaded(&mut flash), Err(StorageError::Corrupt));
        // A new store still works, and is then what loads.
        store(&mut flash, b"fresh").unwrap();
        assert_eq!(loaded(&mut flash), Ok(Some(b"fresh".to_vec())));
    }

    #[test]
    fn sequence_numbers_compare_across_wrap_around() {
        let at = |sequence| Header {
            kind: KIND_PAYLOAD,
            sequence,
            len: 0,
        };
        assert!(at(1).is_newer_than(at(0)));
        assert!(!at(0).is_newer_than(at(1)));
        assert!(at(0).is_newer_than(at(u32::MAX)));
        assert!(!at(5).is_newer_than(at(5)));
    }

    #[test]
    fn both_slots_committed_means_the_newer_wins_whichever_slot_it_is_in() {
        // A power cut between the commit and the erase of the old record leaves both.
        for (first, second) in [(Slot::A, Slot::B), (Slot::B, Slot::A)] {
            let mut flash = Medium::new();
            let mut write = |slot: Slot, sequence: u32, payload: &[u8]| {
                let header = Header {
                    kind: KIND_PAYLOAD,
                    sequence,
                    len: payload.len() as u32,
                }
                .encode();
                let mut digest = CRC.digest();
                digest.update(&header);
                digest.update(payload);
                flash.write(slot, 0, &header).unwrap();
                flash.write(slot, HEADER_LEN, payload).unwrap();
                flash
                    .write(
                        slot,
                        HEADER_LEN + payload.len(),
                        &digest.finalize().to_le_bytes(),
                    )
                    .unwrap();
            };
            write(first, u32::MAX, b"older");
            write(second, 0, b"newer");
            assert_eq!(loaded(&mut flash), Ok(Some(b"newer".to_vec())));
        }
    }

    /// Power fails after every possible number of bytes during a store (and during the
    /// erase of the superseded record): afterwards the old or the new payload loads, never a
    /// mix and never nothing; once the store has answered Ok, only the new one.
    #[test]
    fn cia301_7_5_2_13_a_power_cut_at_any_byte_leaves_the_old_or_the_new_record() {
        let old = b"old configuration, 0x13FE = A5, signatures of the old mapping";
        let new = b"NEW configuration, different length";
        let mut base = Medium::new();
        store(&mut base, b"oldest").unwrap();
        store(&mut base, old).unwrap();
        let total = HEADER_LEN + new.len() + CRC_LEN + 2;
        let mut outcomes = [0usize; 2];
        for budget in 0..=total + 1 {
            let mut flash = PowerCutFlash::new(base.clone(), Some(budget));
            let result = store(&mut flash, new);
            flash.power_on();
            let after = loaded(&mut flash).unwrap().unwrap();
            if result.is_ok() {
                assert_eq!(after, new.to_vec(), "budget {budget}");
            } else {
                assert_eq!(result, Err(StorageError::PowerLost));
                assert!(
                    after == old.to_vec() || after == new.to_vec(),
                    "budget {budget}: {after:?}"
                );
            }
            outcomes[usize::from(after == new.to_vec())] += 1;
            // And the medium stays usable: the next store completes and is what loads.
            store(&mut flash, b"next").unwrap();
            assert_eq!(loaded(&mut flash), Ok(Some(b"next".to_vec())));
        }
        // Both outcomes really occurred: the sweep covered the commit point.
        assert!(outcomes[0] > 0 && outcomes[1] > 0, "{outcomes:?}");
    }

    /// Two torn stores in a row on a medium that only ever held the first record.
    #[test]
    fn repeated_power_cuts_never_lose_the_committed_record() {
        let mut base = Medium::new();
        store(&mut base, b"committed").unwrap();
        for first in 0..30 {
            for second in [0, 1, 5, 17, 20, 40] {
                let mut flash = PowerCutFlash::new(base.clone(), Some(first));
                let _ = store(&mut flash, b"torn one");
                let mut flash = PowerCutFlash::new(flash.into_inner(), Some(second));
                let _ = restore_defaults(&mut flash);
                flash.power_on();
                let after = loaded(&mut flash);
                assert!(
                    matches!(&after, Ok(Some(p)) if p == b"committed" || p == b"torn one")
                        || after == Ok(None),
                    "cuts at {first}/{second}: {after:?}"
                );
            }
        }
    }

    #[test]
    fn accesses_outside_a_slot_are_refused() {
        let mut flash = RamFlash::<8>::new();
        let mut buf = [0u8; 4];
        assert_eq!(
            flash.read(Slot::A, 6, &mut buf),
            Err(StorageError::OutOfBounds)
        );
        assert_eq!(
            flash.write(Slot::B, usize::MAX, &buf),
            Err(StorageError::OutOfBounds)
        );
        assert_eq!(store(&mut flash, b""), Err(StorageError::TooLarge));
    }
}
