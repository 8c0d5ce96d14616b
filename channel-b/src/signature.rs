//! Channel B's own computation of the SRDO configuration signatures (EN 50325-5 6.4.1.5,
//! Table 9), deliberately different from channel A's (CiA 304 9.5: diversity).
//!
//! Channel A uses the table-driven CRC-16/XMODEM of the `crc` crate over the record's fields.
//! Channel B shifts bit by bit, least significant octet of each field first as Table 9's
//! formula (2) orders them, straight from the raw values of its own object dictionary copy. The
//! two are cross-checked over the link ([`dual_channel::link::Message::Configuration`]) before
//! Operational and periodically after.

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

/// Shifts the low `octets` octets of `value`, least significant first, through the CRC
/// register, each octet most significant bit first.
fn feed(mut crc: u16, value: u32, octets: u32) -> u16 {
    for octet in 0..octets {
        let byte = (value >> (8 * octet)) & 0xFF;
        for bit in (0..8).rev() {
            let incoming = (byte >> bit) & 1;
            let feedback = u32::from(crc >> 15) ^ incoming;
            crc <<= 1;
            if feedback == 1 {
                crc ^= 0x1021;
            }
        }
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
