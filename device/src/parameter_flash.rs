//! The two parameter slots of `shared::canopen::storage` on flash that is programmed in whole
//! 32-bit words, as the STM32F4's is at x32 parallelism, and where this device keeps them
//! ([`STM32F405_SLOTS`]). Hardware-free, so it is tested on the host; the hardware layer's
//! [`Sectors`] is the board's own register-level flash driver (`board::hw::flash`, RM0090
//! 3.6). It is the device's, not the board layer's: which sectors hold the parameters and
//! that they are written in whole words are facts of this device's flash (the STM32F405RG's
//! sector map, `memory.x` region PARAMETERS), as its pins are, while only the registers that
//! erase and program them are the adapter's.
//!
//! The [`Flash`] trait allows writes at any byte offset; the flash takes aligned words. A write
//! therefore reads each word it touches, clears the new bytes' zero bits into it and programs
//! the word. The storage layer (slot layout version 2) writes only whole fields that start on
//! a word, each once between erases, so every word is programmed exactly once after its
//! erase and nothing relies on programming further zero bits into a programmed word (which the
//! STM32F4 is documented to accept, ST AN3969, but which has not been verified on our
//! hardware); a host test programs the storage layer's stores on flash that refuses a second
//! programming. A word the hardware refused shows as a record that does not verify: before
//! its commit, the store fails and the old record stays in force.

use shared::canopen::storage::{Flash, Slot, StorageError};

/// Flash programmed in aligned 32-bit words. Addresses are offsets from the flash origin.
pub trait Sectors {
    /// `true` when an erase holds the processor (it runs from this flash):
    /// [`Flash::erase_stalls`].
    fn erase_stalls(&self) -> bool;
    /// Reads `buf.len()` bytes from `at`.
    fn read(&mut self, at: u32, buf: &mut [u8]) -> Result<(), StorageError>;
    /// Erases the sectors from `from` to `to` (exclusive).
    fn erase(&mut self, from: u32, to: u32) -> Result<(), StorageError>;
    /// Programs the aligned word at `at` (bits go from 1 to 0 only).
    fn program(&mut self, at: u32, word: [u8; 4]) -> Result<(), StorageError>;
}

/// Two equal slots, each a range of whole sectors.
#[derive(Debug)]
pub struct SectorSlots<S> {
    sectors: S,
    starts: [u32; 2],
    len: u32,
}

/// The STM32F405's slots: sectors 10 and 11, 128 KiB each (RM0090 Table 5; `memory.x`
/// region PARAMETERS).
pub const STM32F405_SLOTS: ([u32; 2], u32) = ([0x000C_0000, 0x000E_0000], 0x0002_0000);

impl<S: Sectors> SectorSlots<S> {
    /// Slots of `len` bytes starting at `starts` (A, B).
    pub const fn new(sectors: S, (starts, len): ([u32; 2], u32)) -> Self {
        SectorSlots {
            sectors,
            starts,
            len,
        }
    }

    /// The medium underneath.
    pub fn sectors(&self) -> &S {
        &self.sectors
    }

    /// The flash address of `offset` in `slot`, when `len` bytes from there stay in the slot.
    fn address(&self, slot: Slot, offset: usize, len: usize) -> Result<u32, StorageError> {
        let end = offset.checked_add(len).ok_or(StorageError::OutOfBounds)?;
        if end > self.len as usize {
            return Err(StorageError::OutOfBounds);
        }
        // `offset` <= `end` <= `self.len`, a u32.
        Ok(self.starts[slot as usize] + offset as u32)
    }
}

impl<S: Sectors> Flash for SectorSlots<S> {
    fn slot_len(&self) -> usize {
        self.len as usize
    }

    fn erase_stalls(&self) -> bool {
        self.sectors.erase_stalls()
    }

    fn read(&mut self, slot: Slot, offset: usize, buf: &mut [u8]) -> Result<(), StorageError> {
        let at = self.address(slot, offset, buf.len())?;
        self.sectors.read(at, buf)
    }

    fn erase(&mut self, slot: Slot) -> Result<(), StorageError> {
        let from = self.starts[slot as usize];
        self.sectors.erase(from, from + self.len)
    }

    fn write(&mut self, slot: Slot, offset: usize, data: &[u8]) -> Result<(), StorageError> {
        let start = self.address(slot, offset, data.len())?;
        if data.is_empty() {
            // Nothing to program: not even the word around `start`.
            return Ok(());
        }
        let end = start + data.len() as u32;
        let mut word_at = start & !3;
        while word_at < end {
            let mut word = [0u8; 4];
            self.sectors.read(word_at, &mut word)?;
            for (i, byte) in word.iter_mut().enumerate() {
                let address = word_at + i as u32;
                if (start..end).contains(&address) {
                    *byte &= data[(address - start) as usize];
                }
            }
            self.sectors.program(word_at, word)?;
            word_at += 4;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use shared::canopen::storage;
    use std::vec::Vec;

    /// Word-programmed NOR flash: erased bytes read FFh, programming needs an aligned word
    /// and only clears bits; every programmed address is recorded.
    struct WordNor {
        bytes: Vec<u8>,
        programmed: Vec<u32>,
        /// Refuse to program a word a second time before its erase.
        once_only: bool,
        /// Words programmed since their last erase.
        since_erase: std::collections::BTreeSet<u32>,
        /// What [`Sectors::erase_stalls`] says.
        stalls: bool,
        /// Erases so far.
        erases: usize,
    }

    impl WordNor {
        fn new(len: usize) -> Self {
            WordNor {
                bytes: std::vec![0xFF; len],
                programmed: Vec::new(),
                once_only: false,
                since_erase: std::collections::BTreeSet::new(),
                stalls: false,
                erases: 0,
            }
        }
    }

    impl Sectors for WordNor {
        fn erase_stalls(&self) -> bool {
            self.stalls
        }
        fn read(&mut self, at: u32, buf: &mut [u8]) -> Result<(), StorageError> {
            let at = at as usize;
            let source = self
                .bytes
                .get(at..at + buf.len())
                .ok_or(StorageError::Medium)?;
            buf.copy_from_slice(source);
            Ok(())
        }
        fn erase(&mut self, from: u32, to: u32) -> Result<(), StorageError> {
            self.bytes
                .get_mut(from as usize..to as usize)
                .ok_or(StorageError::Medium)?
                .fill(0xFF);
            self.erases += 1;
            self.since_erase.retain(|&at| at < from || at >= to);
            Ok(())
        }
        fn program(&mut self, at: u32, word: [u8; 4]) -> Result<(), StorageError> {
            if at % 4 != 0 || (!self.since_erase.insert(at) && self.once_only) {
                return Err(StorageError::Medium);
            }
            let cells = self
                .bytes
                .get_mut(at as usize..at as usize + 4)
                .ok_or(StorageError::Medium)?;
            for (cell, byte) in cells.iter_mut().zip(word) {
                *cell &= byte;
            }
            self.programmed.push(at);
            Ok(())
        }
    }

    /// Two 64-byte slots at 0 and 64, in a 128-byte part.
    fn slots() -> SectorSlots<WordNor> {
        SectorSlots::new(WordNor::new(128), ([0, 64], 64))
    }

    #[test]
    fn unaligned_writes_land_exactly_and_program_only_the_words_they_touch() {
        for offset in 0..9 {
            for len in 0..10 {
                let mut flash = slots();
                let data: Vec<u8> = (0..len as u8).map(|i| i.wrapping_mul(37)).collect();
                flash.write(Slot::B, offset, &data).unwrap();
                let bytes = &flash.sectors().bytes;
                for (address, &byte) in bytes.iter().enumerate() {
                    let expected = address
                        .checked_sub(64 + offset)
                        .and_then(|i| data.get(i))
                        .copied()
                        .unwrap_or(0xFF);
                    assert_eq!(byte, expected, "offset {offset} len {len} at {address}");
                }
                let first = (64 + offset) as u32 & !3;
                let words = (offset + len).div_ceil(4) - offset / 4;
                let expected: Vec<u32> = if len == 0 {
                    Vec::new()
                } else {
                    (0..words as u32).map(|w| first + 4 * w).collect()
                };
                assert_eq!(
                    flash.sectors().programmed,
                    expected,
                    "offset {offset} len {len}"
                );
            }
        }
    }

    #[test]
    fn writes_next_to_written_bytes_keep_them() {
        let mut flash = slots();
        flash.write(Slot::A, 1, &[0x12, 0x34]).unwrap();
        flash.write(Slot::A, 3, &[0x56, 0x78]).unwrap();
        flash.write(Slot::A, 0, &[0x9A]).unwrap();
        assert_eq!(
            flash.sectors().bytes[..6],
            [0x9A, 0x12, 0x34, 0x56, 0x78, 0xFF]
        );
    }

    #[test]
    fn accesses_outside_a_slot_are_refused_untouched() {
        let mut flash = slots();
        assert_eq!(
            flash.write(Slot::A, 62, &[0; 3]),
            Err(StorageError::OutOfBounds)
        );
        assert_eq!(
            flash.write(Slot::A, usize::MAX, &[0]),
            Err(StorageError::OutOfBounds)
        );
        assert_eq!(
            flash.read(Slot::B, 60, &mut [0; 5]),
            Err(StorageError::OutOfBounds)
        );
        assert!(flash.sectors().programmed.is_empty());
        assert!(flash.sectors().bytes.iter().all(|&b| b == 0xFF));
    }

    /// The storage layer's records, whose CRC follows a payload of any length, round-trip on
    /// word-programmed flash; and a store leaves only the newest record.
    #[test]
    fn records_of_every_length_round_trip() {
        for len in 0..=20 {
            let mut flash = SectorSlots::new(WordNor::new(256), ([0, 128], 128));
            let old = [0xA5u8; 7];
            storage::store(&mut flash, &old).unwrap();
            let payload: Vec<u8> = (0..len as u8).map(|i| i ^ 0x3C).collect();
            storage::store(&mut flash, &payload).unwrap();
            let mut buf = [0u8; 32];
            let loaded = storage::load(&mut flash, &mut buf).unwrap();
            assert_eq!(
                loaded.map(|n| &buf[..n]),
                Some(&payload[..]),
                "length {len}"
            );
        }
    }

    /// The storage layer's stores, restores and loads work on flash that programs each word
    /// only once between erases: no write relies on re-programming a programmed word.
    #[test]
    fn stores_never_program_a_word_twice_between_erases() {
        let mut flash = SectorSlots::new(WordNor::new(256), ([0, 128], 128));
        flash.sectors.once_only = true;
        let mut buf = [0u8; 64];
        for round in 0..12u8 {
            let payload: Vec<u8> = (0..round * 3 % 17).map(|i| i ^ round).collect();
            storage::store(&mut flash, &payload).unwrap();
            let loaded = storage::load(&mut flash, &mut buf).unwrap();
            assert_eq!(
                loaded.map(|n| &buf[..n]),
                Some(&payload[..]),
                "round {round}"
            );
            if round % 5 == 4 {
                storage::restore_defaults(&mut flash).unwrap();
                assert_eq!(storage::load(&mut flash, &mut buf), Ok(None));
            }
        }
    }

    /// CiA 301 7.5.2.13 on flash whose erase holds the processor, as the STM32F405's does: a
    /// store only programs words, each once, and never erases; a second store is refused
    /// until the start-up's erase ahead, which erases one slot (the superseded one) and never
    /// programs a word twice either.
    #[test]
    fn cia301_7_5_2_13_stores_on_stalling_flash_only_program_and_the_erase_ahead_erases_once() {
        let mut flash = SectorSlots::new(WordNor::new(256), ([0, 128], 128));
        flash.sectors.once_only = true;
        flash.sectors.stalls = true;
        let mut buf = [0u8; 64];
        for start_up in 0..6u8 {
            let erased = storage::erase_ahead(&mut flash).unwrap();
            // The first start-up finds blank flash; every later one the superseded slot.
            assert_eq!(erased.is_some(), start_up > 1, "start-up {start_up}");
            let erases = flash.sectors.erases;
            let payload: Vec<u8> = (0..start_up * 5 % 19).map(|i| i ^ start_up).collect();
            storage::store(&mut flash, &payload).unwrap();
            assert_eq!(flash.sectors.erases, erases, "a store erased");
            let loaded = storage::load(&mut flash, &mut buf).unwrap();
            assert_eq!(loaded.map(|n| &buf[..n]), Some(&payload[..]));
            if start_up > 0 {
                assert_eq!(
                    storage::store(&mut flash, b"again"),
                    Err(StorageError::NotErased)
                );
                let loaded = storage::load(&mut flash, &mut buf).unwrap();
                assert_eq!(loaded.map(|n| &buf[..n]), Some(&payload[..]));
            }
        }
    }
}
