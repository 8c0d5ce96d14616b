//! The SimpleCAN configuration signature (`docs/simplecan.md` section 11; SC_REQ_17,
//! SC_REQ_34..36), by the tool's own code.
//!
//! CRC-32 with SC_REQ_17's polynomial 04C11DB7h, initial value FFFFFFFFh, not reflected, no
//! final XOR (the CRC-32/MPEG-2 parameter set; check("123456789") = 0376E6E7h), over the
//! node-ID, 5E00h:01..05, 5E01h and each entry's sub-indices 01..06, every value at its
//! type's size, least significant octet first.
//!
//! Why it is independent of the device's: the node computes the signature with the `crc`
//! crate's table-driven code over the values its own object dictionary holds. This module
//! shares neither code nor types with it: it serialises the tool's [`NodeConfig`] (built from
//! the network file, or decoded from what a node answered) with its own code, and shifts the
//! CRC register one bit at a time. A defect in one of the two cannot sign a wrong
//! configuration without the other disagreeing; the tests check this code against vectors a
//! separate script computed from the section's text, and against the `crc` crate on random
//! octets.

use super::NodeConfig;

/// SC_REQ_17's polynomial.
pub const POLYNOMIAL: u32 = 0x04C1_1DB7;

/// The octets the signature covers, in section 11's order.
pub fn octets(config: &NodeConfig) -> Vec<u8> {
    let mut octets = Vec::with_capacity(10 + 14 * config.entries.len());
    octets.push(config.node_id);
    octets.extend(config.slots_per_cycle.to_le_bytes());
    octets.extend(config.cycles_between_syncs.to_le_bytes());
    octets.extend(config.buffering_us.to_le_bytes());
    octets.push(config.enabled);
    octets.push(config.potential_master);
    // At most 80 entries (the file parser refuses more), so the count fits 5E01h's octet.
    octets.push(config.entries.len() as u8);
    for entry in &config.entries {
        octets.push(entry.sc_id);
        octets.push(entry.role);
        octets.extend(entry.slot.to_le_bytes());
        octets.extend(entry.timeout_ms.to_le_bytes());
        octets.extend(entry.hash.to_le_bytes());
        octets.extend(entry.mapped.to_le_bytes());
    }
    octets
}

/// CRC-32/MPEG-2 of `octets`, one bit at a time, each octet most significant bit first.
pub fn crc32_mpeg2(octets: &[u8]) -> u32 {
    let mut register: u32 = 0xFFFF_FFFF;
    for &octet in octets {
        for bit in (0..8).rev() {
            let incoming = u32::from(octet >> bit) & 1;
            let top = register >> 31;
            register <<= 1;
            if top ^ incoming == 1 {
                register ^= POLYNOMIAL;
            }
        }
    }
    register
}

/// The signature of `config` (the value for 5EFFh).
pub fn signature(config: &NodeConfig) -> u32 {
    crc32_mpeg2(&octets(config))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sc_req_17_crc_32_mpeg_2_check_value() {
        assert_eq!(crc32_mpeg2(b"123456789"), 0x0376_E6E7);
        assert_eq!(crc32_mpeg2(&[]), 0xFFFF_FFFF);
    }
}
