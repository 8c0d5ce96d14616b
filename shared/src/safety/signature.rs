//! The safety configuration signature of object 0x13FF (EN 50325-5 6.4.1.5, Table 9).
//!
//! CRC-16 with generator polynomial x^16 + x^12 + x^5 + 1 (0x1021) and seed 0x0000, not
//! reflected, no final XOR: the parameters known as CRC-16/XMODEM. The fields are fed in
//! Table 9's order, each field's octets least-significant first (formula (2) lists a7..0,
//! then b7..0, b15..8, ...):
//!
//! | order | field                          | octets |
//! |-------|--------------------------------|--------|
//! | 1     | information direction (01h)    | 1      |
//! | 2     | refresh time / SCT (02h)       | 2      |
//! | 3     | SRVT (03h)                     | 1      |
//! | 4     | COB-ID 1 (05h)                 | 4      |
//! | 5     | COB-ID 2 (06h)                 | 4      |
//! | 6     | mapping sub-index 00h          | 1      |
//! | 7..   | per entry: its sub-index, value | 1 + 4 |
//!
//! The transmission type (04h) is not included. This implementation uses the table-driven
//! CRC of the `crc` crate; the second channel computes the same signature with an
//! independent bitwise implementation of its own (CiA 304 9.5: diversity), and the tests here
//! check this one against a third, written inside the test.

use super::config::SrdoRecord;

/// CRC-16/XMODEM: polynomial 0x1021, seed 0, as EN 50325-5 6.4.1.5 prescribes.
const ALGORITHM: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_XMODEM);

/// The signature of one SRDO's configuration, as a configuration tool computes it.
pub fn compute(record: &SrdoRecord) -> u16 {
    let mut digest = ALGORITHM.digest();
    digest.update(&[record.direction]);
    digest.update(&record.cycle_time.to_le_bytes());
    digest.update(&[record.srvt]);
    digest.update(&record.cob_id_1.to_le_bytes());
    digest.update(&record.cob_id_2.to_le_bytes());
    digest.update(&[record.mapping_count]);
    for (position, entry) in record.entries().iter().enumerate() {
        // Sub-indices run from 1 to at most 16.
        digest.update(&[(position + 1) as u8]);
        digest.update(&entry.to_le_bytes());
    }
    digest.finalize()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::safety::config::SafetyConfig;

    /// A second, independent CRC-16 (bit by bit, MSB first, poly 0x1021, seed 0) and an
    /// independent serialisation of Table 9, written from the standard's text.
    fn reference_signature(record: &SrdoRecord) -> u16 {
        let mut octets: Vec<u8> = vec![
            record.direction,
            (record.cycle_time & 0xFF) as u8,
            (record.cycle_time >> 8) as u8,
            record.srvt,
        ];
        for value in [record.cob_id_1, record.cob_id_2] {
            for shift in [0, 8, 16, 24] {
                octets.push((value >> shift) as u8);
            }
        }
        octets.push(record.mapping_count);
        for sub in 1..=record.mapping_count {
            octets.push(sub);
            let value = record.mapping[usize::from(sub) - 1];
            for shift in [0, 8, 16, 24] {
                octets.push((value >> shift) as u8);
            }
        }
        let mut crc: u16 = 0;
        for octet in octets {
            for bit in (0..8).rev() {
                let input = (octet >> bit) & 1 == 1;
                let top = crc & 0x8000 != 0;
                crc <<= 1;
                if input != top {
                    crc ^= 0x1021;
                }
            }
        }
        crc
    }

    /// The CRC itself: the standard check value of CRC-16/XMODEM over "123456789".
    #[test]
    fn en50325_5_6_4_1_5_polynomial_and_seed() {
        assert_eq!(ALGORITHM.checksum(b"123456789"), 0x31C3);
    }

    /// EN 50325-5 6.4.1.5 Table 9: golden vectors for the pre-defined SRDO 1 of several
    /// node-IDs, against the independent reference.
    #[test]
    fn en50325_5_table9_predefined_signatures_match_reference() {
        let tx = [0x6000_0108, 0x6001_0108];
        let rx = [0x6200_0108, 0x6201_0108];
        for node_id in [1u8, 2, 5, 32, 33, 40, 64] {
            let config = SafetyConfig::<1>::predefined(node_id, &tx, &rx);
            let record = &config.srdos[0];
            assert_eq!(
                compute(record),
                reference_signature(record),
                "node-ID {node_id}"
            );
        }
    }

    /// Fixed golden values, so a change to either implementation is caught even if both
    /// changed the same way. Computed with a third implementation outside this crate (a
    /// Python script over the Table 9 byte order) when this test was written.
    #[test]
    fn en50325_5_table9_golden_values() {
        let tx = [0x6000_0108, 0x6001_0108];
        let rx = [0x6200_0108, 0x6201_0108];
        let node_1 = SafetyConfig::<1>::predefined(1, &tx, &rx).srdos[0];
        let node_33 = SafetyConfig::<1>::predefined(33, &tx, &rx).srdos[0];
        assert_eq!(compute(&node_1), GOLDEN_NODE_1);
        assert_eq!(compute(&node_33), GOLDEN_NODE_33);
    }

    const GOLDEN_NODE_1: u16 = 0x191A;
    const GOLDEN_NODE_33: u16 = 0x741E;

    /// Every field of Table 9 changes the signature; the transmission type is not part of it.
    #[test]
    fn en50325_5_table9_every_field_counts() {
        let base = SafetyConfig::<1>::predefined(1, &[0x6000_0108, 0x6001_0108], &[]).srdos[0];
        let original = compute(&base);
        let variants: [fn(&mut SrdoRecord); 7] = [
            |r| r.direction = 2,
            |r| r.cycle_time = 26,
            |r| r.srvt = 21,
            |r| r.cob_id_1 = 0x103,
            |r| r.cob_id_2 = 0x104,
            |r| r.mapping[1] = 0x6002_0108,
            |r| r.mapping_count = 0,
        ];
        for (position, change) in variants.iter().enumerate() {
            let mut record = base;
            change(&mut record);
            assert_ne!(compute(&record), original, "field {position}");
            assert_eq!(
                compute(&record),
                reference_signature(&record),
                "field {position}"
            );
        }
        // Entries beyond sub-index 0 do not count.
        let mut record = base;
        record.mapping[5] = 0xDEAD_BEEF;
        assert_eq!(compute(&record), original);
    }
}
