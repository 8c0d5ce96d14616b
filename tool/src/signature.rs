//! The tool's own safety configuration signature (EN 50325-5 6.4.1.5, Table 9).
//!
//! Why it is independent of the node's: the node (channel A) signs and checks with
//! `shared::safety::signature`, the table-driven CRC of the `crc` crate over shared's
//! `SrdoRecord`; channel B has a bitwise CRC of its own. This module shares neither code nor
//! types with them: it serialises the tool's own [`SrdoSettings`] (built from the network file
//! or from values read back over SDO) into Table 9's octet sequence with its own code, and
//! runs its own CRC-16/XMODEM (polynomial 1021h, seed 0000h, not reflected, no final XOR),
//! byte-at-a-time into the top of the register with eight shift steps. A fault in the node's
//! signature code therefore does not hide itself by appearing in the tool too; the tests
//! compare the two on random configurations and on the golden vectors of shared's tests.

/// The parameters of one SRDO that Table 9 covers, as the tool holds them.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct SrdoSettings {
    /// Information direction (0x1301+n:01h): 0 deleted, 1 transmit, 2 receive.
    pub direction: u8,
    /// Refresh time (transmit) or SCT (receive) in ms (sub-index 02h).
    pub cycle_time: u16,
    /// SRVT in ms (sub-index 03h).
    pub srvt: u8,
    /// COB-ID of the plain frame (sub-index 05h).
    pub cob_id_1: u32,
    /// COB-ID of the inverted frame (sub-index 06h).
    pub cob_id_2: u32,
    /// Mapping entries (0x1381+n sub-indices 1..), their count is sub-index 00h.
    pub mapping: Vec<u32>,
}

/// The octets Table 9 feeds to the CRC: direction (1), refresh time/SCT (2), SRVT (1),
/// COB-ID 1 (4), COB-ID 2 (4), mapping count (1), then per entry its sub-index (1) and value
/// (4); each field least-significant octet first. The transmission type is not included.
pub fn table9_octets(settings: &SrdoSettings) -> Vec<u8> {
    let mut octets = Vec::with_capacity(13 + 5 * settings.mapping.len());
    octets.push(settings.direction);
    octets.extend(settings.cycle_time.to_le_bytes());
    octets.push(settings.srvt);
    octets.extend(settings.cob_id_1.to_le_bytes());
    octets.extend(settings.cob_id_2.to_le_bytes());
    // At most 16 entries (0x1381 has sub-indices 1..=16); the file parser enforces it.
    octets.push(settings.mapping.len() as u8);
    for (sub, entry) in (1u8..).zip(&settings.mapping) {
        octets.push(sub);
        octets.extend(entry.to_le_bytes());
    }
    octets
}

/// CRC-16/XMODEM of `octets`, one bit at a time.
pub fn crc16_xmodem(octets: &[u8]) -> u16 {
    let mut register: u16 = 0x0000;
    for &octet in octets {
        register ^= u16::from(octet) << 8;
        for _ in 0..8 {
            register = if register & 0x8000 != 0 {
                (register << 1) ^ 0x1021
            } else {
                register << 1
            };
        }
    }
    register
}

/// The signature of one SRDO (the value for 0x13FF sub-index n).
pub fn signature(settings: &SrdoSettings) -> u16 {
    crc16_xmodem(&table9_octets(settings))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The standard check value of CRC-16/XMODEM.
    #[test]
    fn en50325_5_6_4_1_5_crc_check_value() {
        assert_eq!(crc16_xmodem(b"123456789"), 0x31C3);
        assert_eq!(crc16_xmodem(&[]), 0);
    }
}
