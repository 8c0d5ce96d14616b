//! The SimpleCAN configuration signature (docs/simplecan.md section 11): the tool's own
//! CRC-32/MPEG-2 against vectors that `tests/vectors/simplecan_signature.py` computed from the
//! section's text (by polynomial long division, not by this code), and against the `crc`
//! crate the device uses, on random octets.

use proptest::prelude::*;
use safety_config::simplecan::signature::{crc32_mpeg2, octets, signature};
use safety_config::simplecan::{NodeConfig, SddEntry, role};

fn config(
    node_id: u8,
    enabled: u8,
    potential_master: u8,
    entries: &[(u8, u8, u16, u16, u32, u32)],
) -> NodeConfig {
    NodeConfig {
        node_id,
        slots_per_cycle: 10,
        cycles_between_syncs: 10,
        buffering_us: 500,
        enabled,
        potential_master,
        entries: entries
            .iter()
            .map(|&(sc_id, role, slot, timeout_ms, hash, mapped)| SddEntry {
                sc_id,
                role,
                slot,
                timeout_ms,
                hash,
                mapped,
            })
            .collect(),
    }
}

/// Hexadecimal octets as the script prints them.
fn hex(text: &str) -> Vec<u8> {
    text.split_whitespace()
        .map(|octet| u8::from_str_radix(octet, 16).unwrap())
        .collect()
}

#[test]
fn sc_req_17_the_check_value_of_crc_32_mpeg_2() {
    assert_eq!(crc32_mpeg2(b"123456789"), 0x0376_E6E7);
}

#[test]
fn sc_req_17_vector_producer() {
    let config = config(
        1,
        1,
        1,
        &[(0x30, role::PRODUCE, 0, 0, 0x1234_5678, 0x6000_0108)],
    );
    assert_eq!(
        octets(&config),
        hex("01 0A 00 0A 00 F4 01 01 01 01 30 01 00 00 00 00 78 56 34 12 08 01 00 60")
    );
    assert_eq!(signature(&config), 0xF2D6_6EA2);
}

#[test]
fn sc_req_17_vector_consumer() {
    let config = config(
        33,
        1,
        0,
        &[
            (0x30, role::CONSUME, 0, 50, 0x1234_5678, 0x6200_0108),
            (0x41, role::CONSUME, 0, 12, 0xA5C3_0F96, 0x6201_0108),
        ],
    );
    assert_eq!(
        octets(&config),
        hex(
            "21 0A 00 0A 00 F4 01 01 00 02 30 02 00 00 32 00 78 56 34 12 08 01 00 62 41 02 00 00 0C 00 96 0F C3 A5 08 01 01 62"
        )
    );
    assert_eq!(signature(&config), 0x3413_2C74);
}

#[test]
fn sc_req_17_vector_disabled() {
    let config = config(7, 0, 0, &[]);
    assert_eq!(octets(&config), hex("07 0A 00 0A 00 F4 01 00 00 00"));
    assert_eq!(signature(&config), 0xEB3C_1B2B);
}

#[test]
fn sc_req_17_vector_master_syncs() {
    let config = config(
        2,
        1,
        0,
        &[
            (0x30, role::MASTER_SYNCS, 0, 0, 0x1234_5678, 0),
            (0x41, role::PRODUCE, 3, 0, 0xA5C3_0F96, 0x6001_0108),
        ],
    );
    assert_eq!(signature(&config), 0xDFA7_FDF2);
}

/// The node-ID is signed: the same configuration for another node has another signature
/// (a configuration copied to a renumbered node is refused, section 11).
#[test]
fn sc_req_17_the_node_id_is_signed() {
    let one = config(1, 1, 1, &[(0x30, role::PRODUCE, 0, 0, 1, 0x6000_0108)]);
    let mut other = one.clone();
    other.node_id = 2;
    assert_ne!(signature(&one), signature(&other));
}

proptest! {
    /// The tool's bit-by-bit code and the device's crate (`crc::CRC_32_MPEG_2`, table-driven)
    /// agree on any octets.
    #[test]
    fn sc_req_17_the_tools_crc_agrees_with_the_devices_crate(data in proptest::collection::vec(any::<u8>(), 0..1200)) {
        let device = crc::Crc::<u32>::new(&crc::CRC_32_MPEG_2);
        prop_assert_eq!(crc32_mpeg2(&data), device.checksum(&data));
    }
}

/// `safety-config sign --json FILE` prints each node's SimpleCAN signature beside the SRDOs'
/// (the value the library computes for the file), and the text form names 0x5EFF.
#[test]
fn sc_req_17_the_sign_command_prints_each_nodes_simplecan_signature() {
    let text = r#"[simplecan]
network_name = "bench"
slots_per_cycle = 10
cycles_between_syncs = 10
buffering_us = 500

[[node]]
id = 1
identity = { vendor = 0xABC, product = 0x304, serial = 1 }
[node.simplecan]
potential_master = true
produce = [{ sc_id = 0x30, slot = 0, object = "input" }]

[[node]]
id = 33
identity = { vendor = 0xABC, product = 0x304, serial = 33 }
[node.simplecan]
consume = [{ sc_id = 0x30, timeout_ms = 50, object = "output" }]
"#;
    let dir = std::env::temp_dir().join(format!("sctool-sign-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("net.toml");
    std::fs::write(&path, text).unwrap();
    let network = safety_config::network_file::parse(text, "net.toml").unwrap();
    let expected = safety_config::procedure::offline_simplecan(&network);
    let run = |json: bool| {
        let mut command = std::process::Command::new(env!("CARGO_BIN_EXE_safety-config"));
        if json {
            command.arg("--json");
        }
        let output = command.arg("sign").arg(&path).output().unwrap();
        assert!(output.status.success(), "{output:?}");
        String::from_utf8(output.stdout).unwrap()
    };
    let printed: serde_json::Value = serde_json::from_str(&run(true)).unwrap();
    let rows = printed["simplecan"].as_array().unwrap();
    assert_eq!(rows.len(), 2);
    for ((config, value), row) in expected.iter().zip(rows) {
        assert_eq!(row["node"], u64::from(config.node_id));
        assert_eq!(row["signature"], u64::from(*value));
        assert_eq!(
            row["configuration"]["entries"][0]["hash"],
            u64::from(network.simplecan.as_ref().unwrap().hashes[&0x30])
        );
    }
    let words = run(false);
    assert!(
        words.contains(&format!(
            "node 33 SimpleCAN (on, 1 SDD entries): signature {:08X}h (0x5EFF:00)",
            expected[1].1
        )),
        "{words}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
