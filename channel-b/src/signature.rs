//! Channel B's own computation of the SRDO configuration signatures (EN 50325-5 6.4.1.5,
//! Table 9), deliberately different from channel A's (CiA 304 9.5: diversity).
//!
//! Channel A uses the byte-table CRC-16/XMODEM of the `crc` crate over the record's fields.
//! Channel B feeds the raw values of its own object dictionary copy, least significant octet
//! of each field first as Table 9's formula (2) orders them, four bits at a time through a
//! 16-entry table of its own, which the compiler derives from the bit-by-bit definition of the
//! CRC ([`shift_bit`]): another algorithm, another table and another code path than A's. The
//! two are cross-checked over the link ([`dual_channel::link::Message::Configuration`]) before
//! Operational and with every link heartbeat after.
//!
//! Both channels recompute every signature for each heartbeat, so that a bit flipped in one
//! channel's copy of the configuration shows as differing digests within a link period; the
//! table makes that recomputation about four times cheaper than shifting bit by bit did, and
//! caches nothing.

/// The Table 9 fields of one SRDO as channel B reads them from its object dictionary copy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Parameters<'a> {
    /// 0x1301+n sub 01h.
    pub direction: u8,
    /// 0x1301+n sub 02h.
    pub cycle_time: u16,
    /// 0x1301+n sub 03h.
    pub srvt: u8,
    /// 0x1301+n sub 05h.
    pub cob_id_1: u32,
    /// 0x1301+n sub 06h.
    pub cob_id_2: u32,
    /// 0x1381+n sub 01h.. (the slice's length is sub-index 00h).
    pub mapping: &'a [u32],
}

/// The generator polynomial of Table 9 (x^16 + x^12 + x^5 + 1), most significant bit first.
const POLYNOMIAL: u16 = 0x1021;

/// One bit through the CRC register, the definition the table is derived from: the register
/// shifts left, and the polynomial is added when the bit shifted out differs from `incoming`.
const fn shift_bit(crc: u16, incoming: u16) -> u16 {
    let feedback = (crc >> 15) ^ (incoming & 1);
    let shifted = crc << 1;
    if feedback == 1 {
        shifted ^ POLYNOMIAL
    } else {
        shifted
    }
}

/// `NIBBLE[i]`: what four [`shift_bit`] steps add to the register when the top four bits of
/// the register, added to the four incoming bits, are `i`. Computed at compile time.
const NIBBLE: [u16; 16] = {
    let mut table = [0u16; 16];
    let mut index = 0;
    while index < 16 {
        let mut crc = (index as u16) << 12;
        let mut step = 0;
        while step < 4 {
            crc = shift_bit(crc, 0);
            step += 1;
        }
        table[index] = crc;
        index += 1;
    }
    table
};

/// Four bits (`nibble`, most significant first) through the register: the same as four
/// [`shift_bit`] steps, because the CRC is linear (a test compares them for every register
/// and nibble).
fn shift_nibble(crc: u16, nibble: u8) -> u16 {
    let index = usize::from((crc >> 12) as u8 ^ (nibble & 0x0F));
    (crc << 4) ^ NIBBLE[index]
}

/// Shifts the low `octets` octets of `value`, least significant first, through the CRC
/// register, each octet most significant bit first.
fn feed(mut crc: u16, value: u32, octets: u32) -> u16 {
    for octet in 0..octets {
        let byte = (value >> (8 * octet)) as u8;
        crc = shift_nibble(crc, byte >> 4);
        crc = shift_nibble(crc, byte);
    }
    crc
}

/// The 0x13FF signature of one SRDO (CRC-16, polynomial 0x1021, seed 0).
pub fn signature(parameters: &Parameters<'_>) -> u16 {
    let mut crc = 0u16;
    crc = feed(crc, u32::from(parameters.direction), 1);
    crc = feed(crc, u32::from(parameters.cycle_time), 2);
    crc = feed(crc, u32::from(parameters.srvt), 1);
    crc = feed(crc, parameters.cob_id_1, 4);
    crc = feed(crc, parameters.cob_id_2, 4);
    crc = feed(crc, parameters.mapping.len() as u32, 1);
    let mut sub = 0u32;
    for &entry in parameters.mapping {
        sub += 1;
        crc = feed(crc, sub, 1);
        crc = feed(crc, entry, 4);
    }
    crc
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use shared::safety::config::{SafetyConfig, SrdoRecord};

    fn parameters(record: &SrdoRecord) -> Parameters<'_> {
        Parameters {
            direction: record.direction,
            cycle_time: record.cycle_time,
            srvt: record.srvt,
            cob_id_1: record.cob_id_1,
            cob_id_2: record.cob_id_2,
            mapping: &record.mapping[..usize::from(record.mapping_count)],
        }
    }

    /// The table step is the bit-by-bit definition, for every register value and nibble.
    #[test]
    fn a_nibble_through_the_table_is_four_bits_through_the_register() {
        for crc in 0..=u16::MAX {
            for nibble in 0..16u8 {
                let mut bitwise = crc;
                for bit in (0..4).rev() {
                    bitwise = shift_bit(bitwise, u16::from(nibble >> bit));
                }
                assert_eq!(shift_nibble(crc, nibble), bitwise, "{crc:04X} {nibble:X}");
            }
        }
    }

    /// The golden vectors of the protocol core (EN 50325-5 Table 9, pre-defined SRDO 1).
    #[test]
    fn en50325_5_table9_golden_values_by_channel_b() {
        let tx = [0x6000_0108, 0x6001_0108];
        let rx = [0x6200_0108, 0x6201_0108];
        let node_1 = SafetyConfig::<1>::predefined(1, &tx, &rx).srdos[0];
        let node_33 = SafetyConfig::<1>::predefined(33, &tx, &rx).srdos[0];
        assert_eq!(signature(&parameters(&node_1)), 0x191A);
        assert_eq!(signature(&parameters(&node_33)), 0x741E);
    }

    proptest! {
        /// CiA 304 9.5: channel B's signature equals channel A's for any record.
        #[test]
        fn cia304_9_5_b_signs_what_a_signs(
            direction in any::<u8>(),
            cycle_time in any::<u16>(),
            srvt in any::<u8>(),
            cob_id_1 in any::<u32>(),
            cob_id_2 in any::<u32>(),
            mapping in proptest::collection::vec(any::<u32>(), 0..=16),
        ) {
            let mut record = SrdoRecord::DELETED;
            record.direction = direction;
            record.cycle_time = cycle_time;
            record.srvt = srvt;
            record.cob_id_1 = cob_id_1;
            record.cob_id_2 = cob_id_2;
            record.mapping_count = mapping.len() as u8;
            record.mapping[..mapping.len()].copy_from_slice(&mapping);
            prop_assert_eq!(
                signature(&parameters(&record)),
                shared::safety::signature::compute(&record)
            );
        }
    }
}
