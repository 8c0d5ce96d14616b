//! Atomic parameter storage on two flash slots (CiA 301 7.5.2.13 / 7.5.2.14, 0x1010 / 0x1011).
//!
//! Two promises, whatever moment the power fails at and whatever single bit of a stored record
//! flips afterwards:
//!
//! 1. A store leaves the old or the new record, whole, never a mix: a device that restored half
//!    of a new configuration and half of an old one could run with a signature matching neither.
//! 2. Once a new record is committed, no older record ever loads again: when the newest record
//!    is damaged, [`load`] reports [`StorageError::Corrupt`]. An older configuration is
//!    internally consistent (its signatures match, 0x13FE says A5h), so a node that fell back
//!    to it would validate it and run a configuration the user has replaced (EN 50325-5 8.3.1).
//!
//! # Slot layout (layout version 2)
//!
//! All integers little-endian; every field starts on a 32-bit word, and no word is programmed
//! twice between two erases (so word-programmed flash needs no re-programming of a programmed
//! word).
//!
//! | offset | bytes | field |
//! |-------:|------:|-------|
//! | 0 | 4 | commit word: erased (FFFF FFFFh) until the record below was written and verified, then programmed to 0 |
//! | 4 | 4 | retired word: erased while the record is in force; programmed to 0 once a newer record is committed in the other slot, and before the slot is erased |
//! | 8 | 16 | header: magic "CSP2", layout (2), kind, reserved (0, 0), sequence number, payload length |
//! | 24 | `len` | payload |
//! | 24 + `len` | 0..=3 | padding to a word, erased (FFh) |
//! | 24 + ⌈`len`⌉₄ | 4 | CRC-32 over header, payload and padding |
//!
//! # Storing: erase ahead, program only
//!
//! Erasing a slot on the STM32F405 (a 128 KiB sector) takes seconds, and the processor runs
//! from the same flash, so neither an instruction nor an interrupt runs meanwhile: a channel
//! stalled that long loses its link to the other channel. So a store only programs words,
//! and the slot it needs is erased ahead, at start-up ([`erase_ahead`]):
//!
//! 1. The target is the slot that holds neither the newest record nor a damaged one. Every
//!    word the new record will occupy must read erased. When one does not, a medium whose
//!    erase stalls the processor ([`Flash::erase_stalls`]) refuses the store with
//!    [`StorageError::NotErased`], nothing written; any other medium (RAM, in host
//!    simulations) *retires* the target (retired word programmed) and erases it.
//! 2. Header, payload and CRC are written and read back; only a record that verifies is
//!    committed, by programming the commit word.
//! 3. The other slot, when it holds a committed record, is retired (one word programmed).
//!    It is not erased: a retired slot is ignored by [`load`], whatever it still holds.
//!
//! [`erase_ahead`], at start-up, erases the target of the next store when it is not blank:
//! it retires it first, then erases it. Its target holds neither the newest record nor a
//! damaged one, so the erase never touches the record in force. After a store the next
//! start-up erases the superseded slot, and the next store finds its target blank; a second
//! store without a start-up in between finds the target still holding the superseded record
//! and is refused on the hardware.
//!
//! The new record's sequence number is one more than the newest one found (serial-number
//! arithmetic, RFC 1982, so the counter may wrap).
//!
//! # Loading: what each slot says
//!
//! A slot is judged first by its two words, which sit at fixed offsets and so do not depend
//! on the header being intact:
//!
//! | commit word | retired word | record | the slot is |
//! |---|---|---|---|
//! | erased | any | any | *uncommitted*: erased, a store torn before its commit, or what a torn erase of a retired slot left; ignored |
//! | not erased | 0 | any | *retired*: superseded or about to be erased; ignored |
//! | not erased | erased | verifies | *live* |
//! | not erased | erased | does not verify | *damaged*: it was complete and verified when committed, so it is damage, whichever byte (header included) changed |
//! | not erased | partly programmed | verifies | *retiring*: its retirement was torn by a power cut (then a newer live record is in the other slot), or its retired word is damaged |
//! | not erased | partly programmed | does not verify | a torn erase of a retired slot; ignored |
//!
//! Then: any damaged slot makes the load [`StorageError::Corrupt`]. Otherwise the newest of the
//! live and retiring records (by sequence number, which is CRC-protected in both) decides: a
//! live one loads, a retiring one is damage (a record is retired only after a newer one was
//! committed, so a retiring record can never legitimately be the newest). No live or retiring
//! record: nothing is stored.
//!
//! # Why this is right
//!
//! - *Old or new after a power cut.* Until the commit word is programmed, the target is
//!   uncommitted and ignored, and the old record is untouched and live. A commit word torn by
//!   the power cut is not erased, and the record behind it had already verified, so the new
//!   record is live. Between the commit and the old slot's retirement both slots are live and
//!   the sequence number (intact in both: both verify) picks the new one. A torn retirement
//!   makes the old slot retiring, older than the live new one. A torn erase hits only retired
//!   (or uncommitted) slots: both the erase of a store on RAM and the erase ahead retire the
//!   slot first, and neither erases the record in force.
//! - *An un-erased retired slot.* After a store the superseded record stays, intact, in its
//!   retired slot until the next start-up. It is ignored by its retired word alone (a word at
//!   a fixed offset, programmed to 0), so it cannot load whatever happens to the new record:
//!   a flip of the new record makes it damaged or retiring, which is
//!   [`StorageError::Corrupt`]; a flip in the retired word of the old slot (0 to a partly
//!   programmed word) makes it retiring and older than the new record, which loads.
//! - *Never older after damage.* In every state in which the new record is committed, a flip in
//!   its header, payload, padding or CRC makes it damaged, and a flip in its retired word (from
//!   erased to one bit programmed) makes it retiring and newest; both are
//!   [`StorageError::Corrupt`], whether or not the old record is still in the other slot. A
//!   flip in the damaged slot's header cannot hide it, because the commit and retired words,
//!   not the header, say whether a slot holds a committed record.
//! - *The one exception, by necessity:* the commit word's last programming step. A commit word
//!   torn by a power cut and a programmed commit word with a bit flipped are the same bits on
//!   the medium; the first must load the new record (the store had verified it), so the second
//!   does too. Either way what loads is the newest record and it verifies by its CRC: the flip
//!   cannot bring back an older record, nor let a damaged one through.
//! - *Limits.* Two intact records with one sequence number are reported as damage, but no
//!   store writes them (a new record is newer than every intact one), and a store over them
//!   can leave one of them in force if it is torn. Two independent faults (a flip in the new record's retired word *and* in its
//!   record) are outside this argument: the slot then looks like a torn erase and an older live
//!   record could load. A torn erase that erased a retired slot's retired word completely while
//!   leaving its commit word programmed makes that slot damaged: the load fails safe
//!   ([`StorageError::Corrupt`]) though an intact record is in the other slot.
//!
//! [`RamFlash`] models NOR flash on the host (erased = 0xFF, a write can only clear bits);
//! [`PowerCutFlash`] wraps a medium and loses power after a given number of bytes, tearing the
//! write or erase in progress. The tests cut the power at every byte of a store and of an
//! erase ahead, and damage every bit of the new record in every state a cut can leave.
//!
//! The hardware image implements [`Flash`] on two flash sectors; nothing here knows about
//! sectors, alignment or timing beyond what the trait says ([`Flash::erase_stalls`]).

use crc::{CRC_32_ISO_HDLC, Crc, Digest};

/// CRC-32 (ISO-HDLC, as Ethernet and zip use it) that seals a record.
const CRC: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);
/// "CSP2": marks the start of a record header.
const MAGIC: u32 = u32::from_le_bytes(*b"CSP2");
/// Slot layout version (the module documentation's table).
const LAYOUT: u8 = 2;
/// Offset of the commit word.
const COMMIT_AT: usize = 0;
/// Offset of the retired word.
const RETIRED_AT: usize = 4;
/// Offset of the header.
const HEADER_AT: usize = 8;
/// Header: magic (4), layout (1), kind (1), reserved (2), sequence (4), payload length (4).
const HEADER_LEN: usize = 16;
/// Offset of the payload.
const PAYLOAD_AT: usize = HEADER_AT + HEADER_LEN;
/// The CRC that follows the padded payload.
const CRC_LEN: usize = 4;
/// A word of flash: the unit every field is aligned to.
const WORD: usize = 4;
/// An erased word.
const ERASED: [u8; WORD] = [0xFF; WORD];
/// What the commit and retired words are programmed to.
const PROGRAMMED: [u8; WORD] = [0; WORD];
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
    /// A committed record is damaged (any byte of it, header included): the stored parameters
    /// are lost, and no older record is used instead.
    Corrupt,
    /// The power failed during the operation (reported by [`PowerCutFlash`]).
    PowerLost,
    /// Refused, nothing written: the free slot still holds a superseded record, and erasing
    /// it would hold the processor (seconds on the STM32F405). Reset the node before storing
    /// again: the free parameter slot is erased at start-up ([`erase_ahead`]).
    NotErased,
}

/// A medium with two equal, independently erasable slots.
pub trait Flash {
    /// Bytes per slot.
    fn slot_len(&self) -> usize;
    /// `true` when an erase holds the processor (flash the processor executes from: no
    /// instruction and no interrupt runs until the erase ends); a store then never erases,
    /// and the free slot is erased ahead ([`erase_ahead`]). `false` for RAM.
    fn erase_stalls(&self) -> bool;
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
        #[expect(
            clippy::cast_possible_wrap,
            reason = "serial-number arithmetic reads the wrapped difference as signed"
        )]
        let ahead = self.sequence.wrapping_sub(other.sequence) as i32;
        ahead > 0
    }
}

/// The padded payload length and the offset of the CRC for a payload of `len` bytes, when the
/// whole record fits in a slot of `slot_len` bytes.
fn layout(len: usize, slot_len: usize) -> Option<(usize, usize)> {
    let padded = len.checked_next_multiple_of(WORD)?;
    let crc_at = PAYLOAD_AT.checked_add(padded)?;
    (crc_at.checked_add(CRC_LEN)? <= slot_len).then_some((padded, crc_at))
}

/// What a slot holds (the module documentation's table).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Content {
    /// Commit word erased, or retired (fully, or a torn erase of a retired slot): ignored.
    Ignored,
    /// Committed, not retired, intact.
    Live(Header),
    /// Committed, not retired, and the record does not verify.
    Damaged,
    /// Committed, retired word partly programmed, intact.
    Retiring(Header),
}

/// Reads one word of `slot`.
fn word<F: Flash>(flash: &mut F, slot: Slot, at: usize) -> Result<[u8; WORD], StorageError> {
    let mut bytes = [0u8; WORD];
    flash.read(slot, at, &mut bytes)?;
    Ok(bytes)
}

/// The header of the record in `slot`, when header, payload, padding and CRC verify. Streams
/// the payload through a small scratch buffer so no buffer of the payload's size is needed.
fn verified<F: Flash>(flash: &mut F, slot: Slot) -> Result<Option<Header>, StorageError> {
    let mut raw = [0u8; HEADER_LEN];
    flash.read(slot, HEADER_AT, &mut raw)?;
    let Some(header) = Header::decode(&raw) else {
        return Ok(None);
    };
    let Some((padded, crc_at)) = layout(header.len as usize, flash.slot_len()) else {
        return Ok(None);
    };
    if header.kind == KIND_DEFAULTS && header.len != 0 {
        return Ok(None);
    }
    let mut digest = CRC.digest();
    digest.update(&raw);
    let mut scratch = [0u8; 64];
    let mut at = 0;
    while at < padded {
        let chunk = (padded - at).min(scratch.len());
        flash.read(slot, PAYLOAD_AT + at, &mut scratch[..chunk])?;
        digest.update(&scratch[..chunk]);
        at += chunk;
    }
    let stored = word(flash, slot, crc_at)?;
    Ok((digest.finalize() == u32::from_le_bytes(stored)).then_some(header))
}

/// Judges `slot` by its commit and retired words, then its record.
fn content<F: Flash>(flash: &mut F, slot: Slot) -> Result<Content, StorageError> {
    let commit = word(flash, slot, COMMIT_AT)?;
    let retired = word(flash, slot, RETIRED_AT)?;
    if commit == ERASED || retired == PROGRAMMED {
        return Ok(Content::Ignored);
    }
    Ok(match (retired == ERASED, verified(flash, slot)?) {
        (true, Some(header)) => Content::Live(header),
        (true, None) => Content::Damaged,
        (false, Some(header)) => Content::Retiring(header),
        (false, None) => Content::Ignored,
    })
}

/// Both slots, judged.
fn contents<F: Flash>(flash: &mut F) -> Result<[Content; 2], StorageError> {
    Ok([content(flash, Slot::A)?, content(flash, Slot::B)?])
}

/// The newest of the live and retiring records, with `true` when it is live.
fn newest(contents: [Content; 2]) -> Result<Option<(Slot, Header, bool)>, StorageError> {
    let candidate = |slot: Slot| match contents[slot as usize] {
        Content::Live(header) => Some((slot, header, true)),
        Content::Retiring(header) => Some((slot, header, false)),
        Content::Ignored | Content::Damaged => None,
    };
    Ok(match (candidate(Slot::A), candidate(Slot::B)) {
        (Some(a), Some(b)) if b.1.is_newer_than(a.1) => Some(b),
        (Some(a), Some(b)) if a.1.is_newer_than(b.1) => Some(a),
        // Two records with one sequence number: no store writes that.
        (Some(_), Some(_)) => return Err(StorageError::Corrupt),
        (Some(one), None) | (None, Some(one)) => Some(one),
        (None, None) => None,
    })
}

/// The record in force: `None` when nothing is stored; [`StorageError::Corrupt`] when a
/// committed record is damaged or the newest one is retiring.
fn in_force(contents: [Content; 2]) -> Result<Option<(Slot, Header)>, StorageError> {
    if contents.contains(&Content::Damaged) {
        return Err(StorageError::Corrupt);
    }
    match newest(contents)? {
        Some((slot, header, true)) => Ok(Some((slot, header))),
        Some((_, _, false)) => Err(StorageError::Corrupt),
        None => Ok(None),
    }
}

/// Programs the retired word of `slot`, unless it is programmed already (no word is
/// programmed twice between erases).
fn retire<F: Flash>(flash: &mut F, slot: Slot) -> Result<(), StorageError> {
    if word(flash, slot, RETIRED_AT)? == ERASED {
        flash.write(slot, RETIRED_AT, &PROGRAMMED)?;
    }
    Ok(())
}

/// Retires `slot`, then erases it: a torn erase then hits a retired slot (the module
/// documentation's table).
fn retire_and_erase<F: Flash>(flash: &mut F, slot: Slot) -> Result<(), StorageError> {
    retire(flash, slot)?;
    flash.erase(slot)
}

/// `true` when the `len` bytes of `slot` from its start all read erased. Compares whole
/// words where it can: at start-up this reads a whole slot, while the watchdog runs.
fn erased<F: Flash>(flash: &mut F, slot: Slot, len: usize) -> Result<bool, StorageError> {
    let mut scratch = [0u8; 256];
    let mut at = 0;
    while at < len {
        let chunk = (len - at).min(scratch.len());
        let bytes = &mut scratch[..chunk];
        flash.read(slot, at, bytes)?;
        let words = bytes.chunks_exact(WORD);
        let rest = words.remainder();
        let all_erased = rest.iter().all(|&byte| byte == 0xFF)
            && words
                .map(|word| u32::from_ne_bytes([word[0], word[1], word[2], word[3]]))
                .all(|word| word == u32::MAX);
        if !all_erased {
            return Ok(false);
        }
        at += chunk;
    }
    Ok(true)
}

/// The slot the next store writes to: the one that holds neither the newest record nor a
/// damaged one. A damaged slot is kept until a new record is committed (it keeps the medium
/// reporting damage if that store is torn); otherwise the newest record is kept.
fn target(found: [Content; 2]) -> Slot {
    match found {
        [Content::Damaged, _] => Slot::B,
        [_, Content::Damaged] => Slot::A,
        _ => newest(found)
            .ok()
            .flatten()
            .map_or(Slot::A, |(slot, _, _)| slot.other()),
    }
}

/// Writes a record of `kind` into the target slot ([`target`]), commits it once it verifies,
/// then retires the other slot (the module documentation's "Storing").
fn commit<F: Flash>(flash: &mut F, kind: u8, payload: &[u8]) -> Result<(), StorageError> {
    let len = u32::try_from(payload.len()).map_err(|_| StorageError::TooLarge)?;
    let (padded, crc_at) = layout(payload.len(), flash.slot_len()).ok_or(StorageError::TooLarge)?;
    let found = contents(flash)?;
    let target = target(found);
    // Newer than every intact record on the medium, whichever is in force.
    let sequence = found
        .iter()
        .filter_map(|content| match content {
            Content::Live(header) | Content::Retiring(header) => Some(*header),
            Content::Ignored | Content::Damaged => None,
        })
        .reduce(|a, b| if b.is_newer_than(a) { b } else { a })
        .map_or(0, |header| header.sequence.wrapping_add(1));
    let header = Header {
        kind,
        sequence,
        len,
    };
    let encoded = header.encode();
    let padding = &ERASED[..padded - payload.len()];
    let mut digest: Digest<'_, u32> = CRC.digest();
    digest.update(&encoded);
    digest.update(payload);
    digest.update(padding);
    let crc = digest.finalize().to_le_bytes();

    // Every word the record occupies must be erased. The words beyond it are neither
    // programmed by this store nor read by a load (the CRC ends the record).
    if !erased(flash, target, crc_at + CRC_LEN)? {
        if flash.erase_stalls() {
            // Nothing written: the record in force stays as it is.
            return Err(StorageError::NotErased);
        }
        retire_and_erase(flash, target)?;
    }
    flash.write(target, HEADER_AT, &encoded)?;
    flash.write(target, PAYLOAD_AT, payload)?;
    flash.write(target, crc_at, &crc)?;
    // Only a record that reads back whole is committed.
    let words_erased =
        word(flash, target, COMMIT_AT)? == ERASED && word(flash, target, RETIRED_AT)? == ERASED;
    if !words_erased || verified(flash, target)? != Some(header) {
        return Err(StorageError::VerifyFailed);
    }
    // The commit.
    flash.write(target, COMMIT_AT, &PROGRAMMED)?;
    if content(flash, target)? != Content::Live(header) {
        return Err(StorageError::VerifyFailed);
    }
    // The new record is in force. The other slot is retired when it holds a committed record
    // (an uncommitted one is ignored as it is); it is erased later, by [`erase_ahead`] or by
    // the next store on a medium whose erase does not stall.
    if word(flash, target.other(), COMMIT_AT)? != ERASED {
        retire(flash, target.other())?;
    }
    Ok(())
}

/// Erases the slot the next store will write to, when it is not blank, so that the store
/// only programs words: the erase ahead, for start-up, before anything depends on the
/// processor's timing. Returns the slot it erased, `None` when the target was blank already.
///
/// Never erases the record in force (the target holds neither the newest record nor a
/// damaged one), and retires the target before the erase, so a power cut during it leaves a
/// slot that loads as ignored (the module documentation's table). When a slot is damaged
/// the load fails ([`StorageError::Corrupt`]) and the target is the other slot: its record
/// cannot load while the damage stays, and the next store would write over it anyway.
pub fn erase_ahead<F: Flash>(flash: &mut F) -> Result<Option<Slot>, StorageError> {
    let target = target(contents(flash)?);
    if erased(flash, target, flash.slot_len())? {
        return Ok(None);
    }
    retire_and_erase(flash, target)?;
    Ok(Some(target))
}

/// Stores `payload` atomically: after a power failure at any point, [`load`] returns either
/// the previous record or `payload`, never a mix; once this returns `Ok`, never the previous.
pub fn store<F: Flash>(flash: &mut F, payload: &[u8]) -> Result<(), StorageError> {
    commit(flash, KIND_PAYLOAD, payload)
}

/// Records, atomically, that the next [`load`] shall report "nothing stored" so the device
/// starts on its defaults (0x1011, restore default parameters).
pub fn restore_defaults<F: Flash>(flash: &mut F) -> Result<(), StorageError> {
    commit(flash, KIND_DEFAULTS, &[])
}

/// Copies the newest stored payload into `buf` and returns its length; `None` when nothing is
/// stored or the newest record asks for the defaults; [`StorageError::Corrupt`] when the newest
/// record is damaged (never an older record instead).
pub fn load<F: Flash>(flash: &mut F, buf: &mut [u8]) -> Result<Option<usize>, StorageError> {
    let Some((slot, header)) = in_force(contents(flash)?)? else {
        return Ok(None);
    };
    if header.kind == KIND_DEFAULTS {
        return Ok(None);
    }
    let len = header.len as usize;
    let (padded, crc_at) = layout(len, flash.slot_len()).ok_or(StorageError::Corrupt)?;
    let target = buf.get_mut(..len).ok_or(StorageError::TooLarge)?;
    flash.read(slot, PAYLOAD_AT, target)?;
    // Read again and compare with the CRC checked in `in_force`: the bytes handed out are the
    // bytes that were verified, even if the medium changed in between.
    let mut digest = CRC.digest();
    digest.update(&header.encode());
    digest.update(target);
    let mut padding = [0u8; WORD];
    let padding = &mut padding[..padded - len];
    flash.read(slot, PAYLOAD_AT + len, padding)?;
    digest.update(padding);
    if digest.finalize() != u32::from_le_bytes(word(flash, slot, crc_at)?) {
        return Err(StorageError::VerifyFailed);
    }
    Ok(Some(len))
}

/// Two slots of `N` bytes in RAM that behave like NOR flash: erased bytes read 0xFF and a
/// write can only clear bits. For host tests, the emulator build and the simulator.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RamFlash<const N: usize> {
    slots: [[u8; N]; 2],
    /// What [`Flash::erase_stalls`] says: `false` unless a test asks for the hardware's
    /// behaviour ([`RamFlash::with_stalling_erase`]).
    erase_stalls: bool,
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
            erase_stalls: false,
        }
    }

    /// The same medium, saying that its erase holds the processor, as the hardware's flash
    /// does: a store then refuses to erase ([`StorageError::NotErased`]). For tests of the
    /// hardware's sequence.
    pub const fn with_stalling_erase(mut self) -> Self {
        self.erase_stalls = true;
        self
    }

    /// Two slots of zeros, as a medium in no known state; erase both before use. For a
    /// `static` in zero-initialised RAM (no initial image in flash, no copy on the stack).
    pub const fn zeroed() -> Self {
        RamFlash {
            slots: [[0; N]; 2],
            erase_stalls: false,
        }
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
    fn erase_stalls(&self) -> bool {
        (**self).erase_stalls()
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

    fn erase_stalls(&self) -> bool {
        self.erase_stalls
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
/// two units). The write in progress is torn: its first bytes land, the rest do not. An erase
/// cut at its first unit leaves the slot as it was (the power failed as it began); cut at its
/// second, it leaves the first half of the slot erased and the rest indeterminate. Every access
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

    fn erase_stalls(&self) -> bool {
        self.inner.erase_stalls()
    }

    fn read(&mut self, slot: Slot, offset: usize, buf: &mut [u8]) -> Result<(), StorageError> {
        if !self.powered {
            return Err(StorageError::PowerLost);
        }
        self.inner.read(slot, offset, buf)
    }

    fn erase(&mut self, slot: Slot) -> Result<(), StorageError> {
        match self.spend(2)? {
            2 => return self.inner.erase(slot),
            // The power failed as the erase began: the slot is as it was (an erase that had
            // not yet changed a cell), which leaves both records of a store behind.
            0 => return Err(StorageError::PowerLost),
            _ => {}
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
        // The first store left slot B as it was: nothing to retire in it.
        assert!(flash.slot_mut(Slot::B).iter().all(|&b| b == 0xFF));
        store(&mut flash, b"second, longer").unwrap();
        assert_eq!(loaded(&mut flash), Ok(Some(b"second, longer".to_vec())));
        // The second record went to slot B and the first was retired after the commit, not
        // erased.
        assert_eq!(flash.slot_mut(Slot::A)[RETIRED_AT..][..WORD], PROGRAMMED);
        assert_eq!(flash.slot_mut(Slot::B)[RETIRED_AT..][..WORD], ERASED);
        // RAM does not stall: the third store erases slot A itself, then retires slot B.
        store(&mut flash, b"").unwrap();
        assert_eq!(loaded(&mut flash), Ok(Some(std::vec::Vec::new())));
        assert_eq!(flash.slot_mut(Slot::A)[RETIRED_AT..][..WORD], ERASED);
        assert_eq!(flash.slot_mut(Slot::B)[RETIRED_AT..][..WORD], PROGRAMMED);
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
        let big = [7u8; 256 - PAYLOAD_AT - CRC_LEN + 1];
        assert_eq!(store(&mut flash, &big), Err(StorageError::TooLarge));
        assert_eq!(loaded(&mut flash), Ok(Some(b"kept".to_vec())));
        let exact = [7u8; 256 - PAYLOAD_AT - CRC_LEN];
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
        flash.slot_mut(Slot::B)[PAYLOAD_AT] ^= 0x01;
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

    /// Writes a committed record of `sequence` into `slot` by hand, as a store would.
    fn committed(flash: &mut Medium, slot: Slot, sequence: u32, payload: &[u8]) {
        let header = Header {
            kind: KIND_PAYLOAD,
            sequence,
            len: payload.len() as u32,
        };
        let (padded, crc_at) = layout(payload.len(), 256).unwrap();
        let mut digest = CRC.digest();
        digest.update(&header.encode());
        digest.update(payload);
        digest.update(&ERASED[..padded - payload.len()]);
        flash.write(slot, HEADER_AT, &header.encode()).unwrap();
        flash.write(slot, PAYLOAD_AT, payload).unwrap();
        flash
            .write(slot, crc_at, &digest.finalize().to_le_bytes())
            .unwrap();
        flash.write(slot, COMMIT_AT, &PROGRAMMED).unwrap();
    }

    #[test]
    fn both_slots_committed_means_the_newer_wins_whichever_slot_it_is_in() {
        // A power cut between the commit and the retirement of the old record leaves both.
        for (first, second) in [(Slot::A, Slot::B), (Slot::B, Slot::A)] {
            let mut flash = Medium::new();
            committed(&mut flash, first, u32::MAX, b"older");
            committed(&mut flash, second, 0, b"newer");
            assert_eq!(loaded(&mut flash), Ok(Some(b"newer".to_vec())));
            // Retiring the older one changes nothing; retiring the newer one is damage (no
            // store retires the newest record).
            let mut retired = flash.clone();
            retired.write(first, RETIRED_AT, &PROGRAMMED).unwrap();
            assert_eq!(loaded(&mut retired), Ok(Some(b"newer".to_vec())));
            let mut torn = flash.clone();
            torn.write(second, RETIRED_AT, &[0xFE, 0xFF, 0xFF, 0xFF])
                .unwrap();
            assert_eq!(loaded(&mut torn), Err(StorageError::Corrupt));
            // Two records with one sequence number are damage too.
            let mut twins = Medium::new();
            committed(&mut twins, first, 7, b"one");
            committed(&mut twins, second, 7, b"two");
            assert_eq!(loaded(&mut twins), Err(StorageError::Corrupt));
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
        let mut outcomes = [0usize; 2];
        for budget in 0.. {
            let mut flash = PowerCutFlash::new(base.clone(), Some(budget));
            let result = store(&mut flash, new);
            let completed = flash.powered();
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
            if completed {
                break;
            }
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

    /// The bytes of the record `store` writes for a payload of `len` bytes.
    fn extent(len: usize) -> usize {
        layout(len, 256).unwrap().1 + CRC_LEN
    }

    /// The slot that holds the record in force: committed and not retired (the other one
    /// is erased or retired).
    fn holding(flash: &mut Medium) -> Slot {
        let live = |slot: &[u8; 256]| {
            slot[COMMIT_AT..COMMIT_AT + WORD] != ERASED
                && slot[RETIRED_AT..RETIRED_AT + WORD] == ERASED
        };
        if live(flash.slot_mut(Slot::A)) {
            Slot::A
        } else {
            Slot::B
        }
    }

    /// EN 50325-5 8.3.1: every single-bit flip anywhere in the stored record (header
    /// included) is reported as damage, never read as "nothing stored" or as an older record.
    #[test]
    fn en50325_5_8_3_1_every_single_bit_flip_of_a_record_is_reported_as_damage() {
        let new = b"NEW configuration";
        let mut base = Medium::new();
        store(&mut base, b"old configuration").unwrap();
        store(&mut base, new).unwrap();
        let slot = holding(&mut base);
        for bit in 0..extent(new.len()) * 8 {
            let mut flash = base.clone();
            flash.slot_mut(slot)[bit / 8] ^= 1 << (bit % 8);
            let after = loaded(&mut flash);
            assert!(
                after == Err(StorageError::Corrupt) || after == Ok(Some(new.to_vec())),
                "bit {bit}: {after:?}"
            );
            if !commit_word(bit) {
                assert_eq!(after, Err(StorageError::Corrupt), "bit {bit}");
            }
        }
    }

    /// `true` for a bit of the commit word (see the module documentation).
    fn commit_word(bit: usize) -> bool {
        (COMMIT_AT..COMMIT_AT + WORD).contains(&(bit / 8))
    }

    /// EN 50325-5 8.3.1: a power cut after the new record is committed but before the
    /// superseded one is erased leaves both; a damaged new record must then be reported, never
    /// replaced by the old one. Every cut of the sweep, then every bit of the new record.
    #[test]
    fn en50325_5_8_3_1_new_committed_old_not_erased_then_new_damaged_never_loads_the_old() {
        let old = b"old configuration, the one the user replaced";
        let new = b"NEW configuration";
        let mut base = Medium::new();
        store(&mut base, old).unwrap();
        let old_slot = holding(&mut base);
        let mut both = 0;
        for budget in 0.. {
            let mut flash = PowerCutFlash::new(base.clone(), Some(budget));
            let result = store(&mut flash, new);
            flash.power_on();
            let mut medium = flash.into_inner();
            if result.is_ok() {
                break;
            }
            let old_left = medium.slot_mut(old_slot).iter().any(|&b| b != 0xFF);
            if loaded(&mut medium) != Ok(Some(new.to_vec())) || !old_left {
                continue;
            }
            both += 1;
            for bit in 0..extent(new.len()) * 8 {
                let mut damaged = medium.clone();
                damaged.slot_mut(old_slot.other())[bit / 8] ^= 1 << (bit % 8);
                let after = loaded(&mut damaged);
                assert_ne!(after, Ok(Some(old.to_vec())), "budget {budget} bit {bit}");
                if commit_word(bit) {
                    assert_eq!(after, Ok(Some(new.to_vec())), "budget {budget} bit {bit}");
                } else {
                    assert_eq!(
                        after,
                        Err(StorageError::Corrupt),
                        "budget {budget} bit {bit}"
                    );
                }
            }
        }
        // The sweep reached the state it is about.
        assert!(both > 0);
    }

    /// A store onto a medium that reports damage, torn at every byte: afterwards the medium
    /// reports the damage or holds the new record; the older record behind the damaged one
    /// never loads (the damaged slot is kept until the new record is committed).
    #[test]
    fn en50325_5_8_3_1_a_torn_store_over_a_damaged_record_never_brings_back_an_older_one() {
        let old = b"old configuration";
        for damage_at in [
            COMMIT_AT + WORD,
            HEADER_AT,
            HEADER_AT + 8,
            PAYLOAD_AT,
            PAYLOAD_AT + 4,
        ] {
            // Old and new both committed (a cut before the old one was retired), then the
            // new one damaged (retired word, magic, sequence, payload, CRC).
            let mut base = Medium::new();
            committed(&mut base, Slot::A, 3, old);
            committed(&mut base, Slot::B, 4, b"new");
            base.slot_mut(Slot::B)[damage_at] ^= 0x10;
            assert_eq!(loaded(&mut base), Err(StorageError::Corrupt));
            for budget in 0.. {
                let mut flash = PowerCutFlash::new(base.clone(), Some(budget));
                let result = store(&mut flash, b"fresh");
                let completed = flash.powered();
                flash.power_on();
                let after = loaded(&mut flash);
                assert!(
                    after == Err(StorageError::Corrupt) || after == Ok(Some(b"fresh".to_vec())),
                    "damage at {damage_at}, budget {budget}: {after:?}"
                );
                if result.is_ok() {
                    assert_eq!(after, Ok(Some(b"fresh".to_vec())));
                }
                if completed {
                    break;
                }
            }
        }
    }

    /// A medium that counts its erases.
    #[derive(Clone, Debug)]
    struct Counting {
        inner: Medium,
        erases: usize,
    }

    impl Flash for Counting {
        fn slot_len(&self) -> usize {
            self.inner.slot_len()
        }
        fn erase_stalls(&self) -> bool {
            self.inner.erase_stalls()
        }
        fn read(&mut self, slot: Slot, offset: usize, buf: &mut [u8]) -> Result<(), StorageError> {
            self.inner.read(slot, offset, buf)
        }
        fn erase(&mut self, slot: Slot) -> Result<(), StorageError> {
            self.erases += 1;
            self.inner.erase(slot)
        }
        fn write(&mut self, slot: Slot, offset: usize, data: &[u8]) -> Result<(), StorageError> {
            self.inner.write(slot, offset, data)
        }
    }

    /// CiA 301 7.5.2.13 on flash whose erase stalls the processor: a store only programs
    /// words; a second store before the next erase ahead is refused and changes nothing; the
    /// erase ahead erases the superseded slot only, once.
    #[test]
    fn cia301_7_5_2_13_a_store_on_stalling_flash_never_erases_and_the_erase_ahead_frees_the_next_slot()
     {
        let mut flash = Counting {
            inner: Medium::new().with_stalling_erase(),
            erases: 0,
        };
        assert_eq!(erase_ahead(&mut flash), Ok(None), "a blank medium");
        store(&mut flash, b"first").unwrap();
        store(&mut flash, b"second").unwrap();
        assert_eq!(flash.erases, 0);
        assert_eq!(loaded(&mut flash), Ok(Some(b"second".to_vec())));

        // Slot A still holds the first record, retired: a third store would need an erase.
        let before = flash.inner.clone();
        assert_eq!(store(&mut flash, b"third"), Err(StorageError::NotErased));
        assert_eq!(restore_defaults(&mut flash), Err(StorageError::NotErased));
        assert_eq!(flash.inner, before, "a refused store writes nothing");
        assert_eq!(flash.erases, 0);
        assert_eq!(loaded(&mut flash), Ok(Some(b"second".to_vec())));

        // Start-up: the erase ahead erases slot A, not the record in force; only once.
        assert_eq!(erase_ahead(&mut flash), Ok(Some(Slot::A)));
        assert!(flash.inner.slot_mut(Slot::A).iter().all(|&b| b == 0xFF));
        assert_eq!(loaded(&mut flash), Ok(Some(b"second".to_vec())));
        assert_eq!(erase_ahead(&mut flash), Ok(None));
        assert_eq!(flash.erases, 1);
        store(&mut flash, b"third").unwrap();
        assert_eq!(flash.erases, 1);
        assert_eq!(loaded(&mut flash), Ok(Some(b"third".to_vec())));
    }

    /// The erase ahead never changes what loads: on every state the stores and the cuts of
    /// the tests leave (nothing, one record, two committed, a damaged newest record over an
    /// intact older one), the load answers the same before and after it.
    #[test]
    fn en50325_5_8_3_1_the_erase_ahead_never_changes_what_loads() {
        let mut states = std::vec::Vec::new();
        states.push(Medium::new());
        let mut one = Medium::new();
        store(&mut one, b"one").unwrap();
        states.push(one.clone());
        let mut two = one.clone();
        store(&mut two, b"two").unwrap();
        states.push(two);
        for (first, second) in [(Slot::A, Slot::B), (Slot::B, Slot::A)] {
            let mut both = Medium::new();
            committed(&mut both, first, 3, b"older");
            committed(&mut both, second, 4, b"newer");
            states.push(both.clone());
            for damage_at in [RETIRED_AT, HEADER_AT, PAYLOAD_AT] {
                let mut damaged = both.clone();
                damaged.slot_mut(second)[damage_at] ^= 0x10;
                states.push(damaged);
            }
        }
        // And every cut of a store on RAM over two records.
        let mut base = Medium::new();
        store(&mut base, b"oldest").unwrap();
        store(&mut base, b"old").unwrap();
        for budget in 0..200 {
            let mut flash = PowerCutFlash::new(base.clone(), Some(budget));
            let _ = store(&mut flash, b"new");
            states.push(flash.into_inner());
        }
        for (number, state) in states.into_iter().enumerate() {
            let mut flash = state.with_stalling_erase();
            let before = loaded(&mut flash);
            erase_ahead(&mut flash).unwrap();
            assert_eq!(loaded(&mut flash), before, "state {number}");
            // And the next store finds its target blank: it needs no erase.
            store(&mut flash, b"next").unwrap();
            assert_eq!(
                loaded(&mut flash),
                Ok(Some(b"next".to_vec())),
                "state {number}"
            );
        }
    }

    /// CiA 301 7.5.2.13 and EN 50325-5 8.3.1 on flash whose erase stalls: the power fails
    /// after every possible number of bytes of a start-up's erase ahead followed by a store.
    /// Afterwards the old or the new record loads, never the oldest (still in the retired
    /// slot until the erase ahead); once the store answered Ok, only the new one; and the
    /// next start-up's erase ahead lets the next store complete.
    #[test]
    fn cia301_7_5_2_13_a_power_cut_at_any_byte_of_the_erase_ahead_and_the_store_leaves_old_or_new()
    {
        let oldest = b"oldest configuration, superseded, retired, not erased";
        let old = b"old configuration, 0x13FE = A5";
        let new = b"NEW configuration, of another length";
        let mut base = Medium::new().with_stalling_erase();
        store(&mut base, oldest).unwrap();
        store(&mut base, old).unwrap();
        let mut outcomes = [0usize; 2];
        for budget in 0.. {
            let mut flash = PowerCutFlash::new(base.clone(), Some(budget));
            let erased = erase_ahead(&mut flash);
            let result = erased.and_then(|_| store(&mut flash, new));
            let completed = flash.powered();
            flash.power_on();
            let after = loaded(&mut flash).unwrap().unwrap();
            assert_ne!(after, oldest.to_vec(), "budget {budget}");
            if result.is_ok() {
                assert_eq!(after, new.to_vec(), "budget {budget}");
            } else {
                assert_eq!(result, Err(StorageError::PowerLost), "budget {budget}");
                assert!(
                    after == old.to_vec() || after == new.to_vec(),
                    "budget {budget}: {after:?}"
                );
            }
            outcomes[usize::from(after == new.to_vec())] += 1;
            // The next start-up and store.
            erase_ahead(&mut flash).unwrap();
            store(&mut flash, b"next").unwrap();
            assert_eq!(
                loaded(&mut flash),
                Ok(Some(b"next".to_vec())),
                "budget {budget}"
            );
            if completed {
                break;
            }
        }
        assert!(outcomes[0] > 0 && outcomes[1] > 0, "{outcomes:?}");
    }

    /// EN 50325-5 8.3.1: after a completed store the superseded record stays whole in its
    /// retired slot until the next erase ahead. Every single-bit flip of either slot, and
    /// every cut of a further store (on RAM, which erases the retired slot itself), never
    /// loads it.
    #[test]
    fn en50325_5_8_3_1_a_retired_slot_not_erased_never_loads_the_older_record() {
        let old = b"old configuration, the one the user replaced";
        let new = b"NEW configuration";
        let mut base = Medium::new();
        store(&mut base, old).unwrap();
        store(&mut base, new).unwrap();
        let live = holding(&mut base);
        // The old record is there, whole, behind its retired word.
        assert_eq!(&base.slot_mut(live.other())[PAYLOAD_AT..][..old.len()], old);
        for slot in [Slot::A, Slot::B] {
            for bit in 0..extent(old.len()) * 8 {
                let mut flash = base.clone();
                flash.slot_mut(slot)[bit / 8] ^= 1 << (bit % 8);
                let after = loaded(&mut flash);
                assert_ne!(after, Ok(Some(old.to_vec())), "{slot:?} bit {bit}");
                assert!(
                    after == Ok(Some(new.to_vec())) || after == Err(StorageError::Corrupt),
                    "{slot:?} bit {bit}: {after:?}"
                );
            }
        }
        for budget in 0.. {
            let mut flash = PowerCutFlash::new(base.clone(), Some(budget));
            let result = store(&mut flash, b"fresh");
            let completed = flash.powered();
            flash.power_on();
            let after = loaded(&mut flash);
            assert!(
                after == Ok(Some(new.to_vec())) || after == Ok(Some(b"fresh".to_vec())),
                "budget {budget}: {after:?}"
            );
            if result.is_ok() {
                assert_eq!(after, Ok(Some(b"fresh".to_vec())));
            }
            if completed {
                break;
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
