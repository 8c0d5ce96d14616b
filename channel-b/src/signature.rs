//! Channel B's own computation of the SRDO configuration signatures (EN 50325-5 6.4.1.5,
//! Table 9), deliberately different from channel A's (CiA 304 9.5: diversity).
//!
//! Channel A uses the byte-table CRC-16/XMODEM of the `crc` crate over the record's fields.
//! Channel B feeds the raw values of its own object dictionary copy, least significant octet
//! of each field first as Table 9's formula (2) orders them, eight bits at a time through a
//! table-free step of its own (`shift_byte`: shifts and additions derived from the
//! polynomial, tested against the bit-by-bit definition of the CRC for every
//! register value and octet): another algorithm and another code path than A's, and no table
//! at all. The two are cross-checked over the link
//! (in [`dual_channel::link::Message::Heartbeat`]) before Operational and with every link
//! heartbeat after.
//!
//! Both channels recompute every signature for each heartbeat (and compare the other's
//! digest with the one of their own last heartbeat), so that a bit flipped in one channel's
//! copy of the configuration shows as differing digests within a link period; the
//! byte step makes that recomputation cheaper than shifting bit by bit (and took fewer
//! instructions than the 16-entry nibble table it replaced in the full-network profile:
//! docs/network-performance.md has the figures); each heartbeat reads the object dictionary
//! copy again.

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

/// Eight bits (`octet`, most significant first) through the register (generator polynomial
/// of Table 9, x^16 + x^12 + x^5 + 1): the same as eight steps of the bit-by-bit definition (a
/// test compares them for every register value and octet). Why: the eight steps shift the register left by eight and add `t`·x^16 reduced by the polynomial,
/// where `t` is the top octet of the register plus `octet`. With x^16 = x^12 + x^5 + 1, the
/// part of `t` that crosses x^16 again once reduced is its top four bits, so with
/// `u = t + (t >> 4)` the added remainder is `u`·(x^12 + x^5 + 1): `u << 12`, `u << 5` and
/// `u`, truncated to the register's 16 bits.
fn shift_byte(crc: u16, octet: u8) -> u16 {
    let top = (crc >> 8) as u8 ^ octet;
    let u = u16::from(top ^ (top >> 4));
    (crc << 8) ^ (u << 12) ^ (u << 5) ^ u
}

/// Shifts the low `octets` octets of `value`, least significant first, through the CRC
/// register, each octet most significant bit first.
fn feed(mut crc: u16, value: u32, octets: usize) -> u16 {
    for &octet in value.to_le_bytes().iter().take(octets) {
        crc = shift_byte(crc, octet);
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

    /// The generator polynomial of Table 9 (x^16 + x^12 + x^5 + 1), most significant bit first.
    const POLYNOMIAL: u16 = 0x1021;

    /// One bit through the CRC register, the definition the byte step is tested against: the register
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

    /// The byte step is the bit-by-bit definition, for every register value and octet.
    #[test]
    fn an_octet_through_the_step_is_eight_bits_through_the_register() {
        for crc in 0..=u16::MAX {
            for octet in 0..=u8::MAX {
                let mut bitwise = crc;
                for bit in (0..8).rev() {
                    bitwise = shift_bit(bitwise, u16::from(octet >> bit));
                }
                assert_eq!(shift_byte(crc, octet), bitwise, "{crc:04X} {octet:02X}");
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
