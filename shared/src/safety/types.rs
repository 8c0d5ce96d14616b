//! Checked types for the numbers of the CANopen Safety protocol.
//!
//! Each type is built by a `new`-style constructor that returns a [`ConfigError`] naming the
//! rule that was broken, so an SDO write and the configuration check before Operational reject
//! the same values for the same reason.

use super::MAX_SRDOS;
use super::config::ConfigError;

/// An SRDO number, `1..=64` (EN 50325-5 6.2.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SrdoNumber(u8);

impl SrdoNumber {
    /// SRDO 1.
    pub const FIRST: SrdoNumber = SrdoNumber(1);

    /// SRDO `number`, if it is in `1..=64`.
    pub const fn new(number: u8) -> Option<Self> {
        if number >= 1 && number as usize <= MAX_SRDOS {
            Some(SrdoNumber(number))
        } else {
            None
        }
    }

    /// The SRDO whose zero-based slot is `index` (`0..64`).
    pub(crate) const fn from_index(index: usize) -> Self {
        // Callers iterate over at most MAX_SRDOS slots, so `index + 1 <= 64` fits in a u8.
        SrdoNumber((index as u8).wrapping_add(1))
    }

    /// The SRDO whose zero-based slot is `index`, if it is in `0..64`.
    pub const fn of_slot(index: usize) -> Option<Self> {
        if index < MAX_SRDOS {
            // `index + 1 <= 64` fits in a u8.
            Some(SrdoNumber(index as u8 + 1))
        } else {
            None
        }
    }

    /// The number, `1..=64`.
    pub const fn get(self) -> u8 {
        self.0
    }

    /// The zero-based slot, `0..64`.
    pub const fn index(self) -> usize {
        self.0 as usize - 1
    }

    /// Index of the communication parameter object, `0x1301..=0x1340`.
    pub const fn communication_index(self) -> u16 {
        0x1300 + self.0 as u16
    }

    /// Index of the mapping parameter object, `0x1381..=0x13C0`.
    pub const fn mapping_index(self) -> u16 {
        0x1380 + self.0 as u16
    }
}

/// Information direction, sub-index 01h of the communication parameter (EN 50325-5 Table 5).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Direction {
    /// 00h: the SRDO does not exist / is not valid.
    Deleted = 0,
    /// 01h: the SRDO exists and this device produces it.
    Transmit = 1,
    /// 02h: the SRDO exists and this device consumes it.
    Receive = 2,
}

impl Direction {
    /// Parses sub-index 01h; 03h..FFh are reserved (EN 50325-5 Table 5).
    pub const fn new(raw: u8) -> Result<Self, ConfigError> {
        match raw {
            0 => Ok(Direction::Deleted),
            1 => Ok(Direction::Transmit),
            2 => Ok(Direction::Receive),
            _ => Err(ConfigError::DirectionReserved),
        }
    }
}

/// The SRDO identifiers: 101h..=180h, COB-ID 1 odd, COB-ID 2 even (EN 50325-5 Table 5;
/// CiA 304 8.4.2.2, sub-indices 5h and 6h). The one statement of the range: the node's
/// identifier table, the channels' SRDO frame filters and their counters all use it.
pub const SRDO_IDENTIFIERS: core::ops::RangeInclusive<u16> = 0x101..=0x180;
/// Lowest COB-ID 1 of the SRDO range (EN 50325-5 Table 5: 257).
pub const FIRST_COB_ID_MIN: u32 = *SRDO_IDENTIFIERS.start() as u32;
/// Highest COB-ID 1 of the SRDO range (EN 50325-5 Table 5: 383): the last odd identifier.
pub const FIRST_COB_ID_MAX: u32 = *SRDO_IDENTIFIERS.end() as u32 - 1;

/// The two identifiers of one SRDO: COB-ID 1 (plain data) is odd in `0x101..=0x17F`, COB-ID 2
/// (inverted data) is the even identifier right after it (EN 50325-5 6.4.1.3, 7.1.1).
///
/// Two consecutive identifiers `2k+1` and `2k+2` always differ in at least two bit positions
/// (bit 0 and at least bit 1), as 7.1.1 requires.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CobIdPair {
    first: u16,
}

impl CobIdPair {
    /// Checks COB-ID 1 on its own (sub-index 05h).
    pub const fn check_first(raw: u32) -> Result<(), ConfigError> {
        if raw < FIRST_COB_ID_MIN {
            Err(ConfigError::CobIdTooLow)
        } else if raw > FIRST_COB_ID_MAX {
            Err(ConfigError::CobIdTooHigh)
        } else if raw % 2 == 0 {
            Err(ConfigError::CobIdParity)
        } else {
            Ok(())
        }
    }

    /// Checks COB-ID 2 on its own (sub-index 06h): even in `0x102..=0x180`.
    pub const fn check_second(raw: u32) -> Result<(), ConfigError> {
        if raw < FIRST_COB_ID_MIN + 1 {
            Err(ConfigError::CobIdTooLow)
        } else if raw > FIRST_COB_ID_MAX + 1 {
            Err(ConfigError::CobIdTooHigh)
        } else if raw % 2 == 1 {
            Err(ConfigError::CobIdParity)
        } else {
            Ok(())
        }
    }

    /// The pair, if both identifiers are valid and the second follows the first.
    pub const fn new(first: u32, second: u32) -> Result<Self, ConfigError> {
        if let Err(error) = Self::check_first(first) {
            return Err(error);
        }
        if let Err(error) = Self::check_second(second) {
            return Err(error);
        }
        if second != first + 1 {
            return Err(ConfigError::CobIdsNotConsecutive);
        }
        // `first <= 0x17F` was checked, so it fits in u16.
        Ok(CobIdPair {
            first: first as u16,
        })
    }

    /// The pre-defined pair of SRDO 1 for `node_id` `1..=64`: `0xFF + 2·id` and `0x100 + 2·id`
    /// (EN 50325-5 Table 5, CiA 304 8.3.3 Table 4).
    pub const fn predefined(node_id: u8) -> Option<Self> {
        if node_id >= 1 && node_id <= 64 {
            Some(CobIdPair {
                first: 0xFF + 2 * node_id as u16,
            })
        } else {
            None
        }
    }

    /// COB-ID 1, the identifier of the plain frame.
    pub const fn first(self) -> u16 {
        self.first
    }

    /// COB-ID 2, the identifier of the inverted frame.
    pub const fn second(self) -> u16 {
        self.first + 1
    }
}

/// One entry of an SRDO mapping (EN 50325-5 6.4.1.4, by reference to the PDO mapping format of
/// EN 50325-4): object index (bits 31..16), sub-index (15..8), length in bits (7..0).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MappingEntry(pub u32);

impl MappingEntry {
    /// The entry for `index`:`sub` with `bits` bits.
    pub const fn new(index: u16, sub: u8, bits: u8) -> Self {
        MappingEntry(((index as u32) << 16) | ((sub as u32) << 8) | bits as u32)
    }

    /// The mapped object's index.
    pub const fn index(self) -> u16 {
        (self.0 >> 16) as u16
    }

    /// The mapped object's sub-index.
    pub const fn sub(self) -> u8 {
        (self.0 >> 8) as u8
    }

    /// The mapped length in bits.
    pub const fn bits(self) -> u8 {
        self.0 as u8
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// EN 50325-5 Table 5: COB-ID 1 is odd in 257..=383, COB-ID 2 even in 258..=384.
    #[test]
    fn en50325_5_table5_cob_id_ranges_and_parity() {
        assert_eq!(CobIdPair::check_first(0x100), Err(ConfigError::CobIdTooLow));
        assert_eq!(CobIdPair::check_first(0x101), Ok(()));
        assert_eq!(CobIdPair::check_first(0x17F), Ok(()));
        assert_eq!(
            CobIdPair::check_first(0x181),
            Err(ConfigError::CobIdTooHigh)
        );
        assert_eq!(CobIdPair::check_first(0x102), Err(ConfigError::CobIdParity));
        assert_eq!(
            CobIdPair::check_second(0x101),
            Err(ConfigError::CobIdTooLow)
        );
        assert_eq!(CobIdPair::check_second(0x102), Ok(()));
        assert_eq!(CobIdPair::check_second(0x180), Ok(()));
        assert_eq!(
            CobIdPair::check_second(0x182),
            Err(ConfigError::CobIdTooHigh)
        );
        assert_eq!(
            CobIdPair::check_second(0x103),
            Err(ConfigError::CobIdParity)
        );
        assert_eq!(
            CobIdPair::check_first(0x8000_0101),
            Err(ConfigError::CobIdTooHigh)
        );
    }

    /// EN 50325-5 7.1.1: COB-ID 2 is the even identifier following COB-ID 1, and the two
    /// identifiers differ in at least two bit positions.
    #[test]
    fn en50325_5_7_1_1_pair_is_consecutive_and_differs_in_two_bits() {
        assert_eq!(
            CobIdPair::new(0x101, 0x104),
            Err(ConfigError::CobIdsNotConsecutive)
        );
        for first in (0x101..=0x17F).step_by(2) {
            let pair = CobIdPair::new(first, first + 1).unwrap();
            assert!(
                (pair.first() ^ pair.second()).count_ones() >= 2,
                "{first:#x}"
            );
        }
    }

    /// CiA 304 8.3.3 Table 4: pre-defined SRDO 1 identifiers for node-IDs 1..=64 only.
    #[test]
    fn cia304_8_3_3_predefined_identifiers() {
        assert_eq!(
            CobIdPair::predefined(1).map(|p| (p.first(), p.second())),
            Some((0x101, 0x102))
        );
        assert_eq!(
            CobIdPair::predefined(33).map(|p| (p.first(), p.second())),
            Some((0x141, 0x142))
        );
        assert_eq!(
            CobIdPair::predefined(64).map(|p| (p.first(), p.second())),
            Some((0x17F, 0x180))
        );
        assert_eq!(CobIdPair::predefined(65), None);
        assert_eq!(CobIdPair::predefined(0), None);
    }

    #[test]
    fn en50325_5_table5_direction_values() {
        assert_eq!(Direction::new(0), Ok(Direction::Deleted));
        assert_eq!(Direction::new(1), Ok(Direction::Transmit));
        assert_eq!(Direction::new(2), Ok(Direction::Receive));
        assert_eq!(Direction::new(3), Err(ConfigError::DirectionReserved));
        assert_eq!(Direction::new(0xFF), Err(ConfigError::DirectionReserved));
    }

    #[test]
    fn srdo_numbers_are_one_to_sixty_four_with_their_object_indices() {
        assert_eq!(SrdoNumber::new(0), None);
        assert_eq!(SrdoNumber::new(65), None);
        let last = SrdoNumber::new(64).unwrap();
        assert_eq!(
            (last.communication_index(), last.mapping_index()),
            (0x1340, 0x13C0)
        );
        assert_eq!(SrdoNumber::from_index(0), SrdoNumber::new(1).unwrap());
    }

    #[test]
    fn mapping_entry_fields() {
        let entry = MappingEntry::new(0x6000, 0x01, 8);
        assert_eq!(entry.0, 0x6000_0108);
        assert_eq!((entry.index(), entry.sub(), entry.bits()), (0x6000, 1, 8));
    }
}
