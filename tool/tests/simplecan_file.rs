//! The network file's SimpleCAN part: every rule refused with its line, column and a
//! sentence, and what a good file gives.

use safety_config::network_file::{FileError, parse};
use safety_config::simplecan::{self, hash, role};

/// Node 1 produces 30h (slot 0) and is a potential master; node 2 produces 41h (slot 3) and
/// consumes 30h; node 33 consumes both.
const GOOD: &str = r#"[simplecan]
network_name = "press line 3"
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
id = 2
identity = { vendor = 0xABC, product = 0x304, serial = 2 }
[node.simplecan]
produce = [{ sc_id = 0x41, slot = 3, object = "input_inverted" }]
consume = [{ sc_id = 0x30, timeout_ms = 50, object = "output" }]

[[node]]
id = 33
identity = { vendor = 0xABC, product = 0x304, serial = 33 }
[node.simplecan]
consume = [
  { sc_id = 0x30, timeout_ms = 50, object = "output" },
  { sc_id = 0x41, timeout_ms = 12, object = "output_inverted" },
]
"#;

/// `GOOD` with `from` replaced by `to` (exactly once), parsed; the error it must give.
fn error(from: &str, to: &str) -> FileError {
    assert_eq!(GOOD.matches(from).count(), 1, "{from}");
    parse(&GOOD.replace(from, to), "net.toml").expect_err(to)
}

fn assert_at(error: &FileError, line: usize, column: usize, words: &str) {
    assert_eq!((error.line, error.column), (line, column), "{error}");
    assert!(error.message.contains(words), "{error}");
    assert!(
        error
            .to_string()
            .starts_with(&format!("net.toml:{line}:{column}: ")),
        "{error}"
    );
}

#[test]
fn sc_req_16_a_good_file_gives_each_node_its_configuration() {
    let network = parse(GOOD, "net.toml").unwrap();
    let simplecan = network.simplecan.as_ref().unwrap();
    assert_eq!(
        (
            simplecan.slots_per_cycle,
            simplecan.cycles_between_syncs,
            simplecan.buffering_us
        ),
        (10, 10, 500)
    );
    let node_1 = &network.nodes[0];
    assert_eq!(
        simplecan.hashes[&0x30],
        hash::node_hash("press line 3", 0x30, 1, &node_1.identity).unwrap()
    );
    let consumer = simplecan::node_config(simplecan, 33);
    assert_eq!(consumer.enabled, 1);
    assert_eq!(consumer.potential_master, 0);
    let entries: Vec<_> = consumer
        .entries
        .iter()
        .map(|e| (e.sc_id, e.role, e.slot, e.timeout_ms, e.hash, e.mapped))
        .collect();
    assert_eq!(
        entries,
        vec![
            (
                0x30,
                role::CONSUME,
                0,
                50,
                simplecan.hashes[&0x30],
                0x6200_0108
            ),
            (
                0x41,
                role::CONSUME,
                3,
                12,
                simplecan.hashes[&0x41],
                0x6201_0108
            ),
        ]
    );
    let master = simplecan::node_config(simplecan, 1);
    assert_eq!(master.potential_master, 1);
    assert_eq!(
        master.entries[0].mapped, 0x6000_0108,
        "input, 8 bits, as a mapping entry"
    );
}

#[test]
fn a_file_without_simplecan_has_none() {
    let network = parse(
        "[[node]]\nid = 1\nidentity = { vendor = 1, product = 2, serial = 3 }\n",
        "net.toml",
    )
    .unwrap();
    assert_eq!(network.simplecan, None);
}

#[test]
fn sc_req_16_a_node_table_needs_the_network_section() {
    let text = GOOD.replace(
        "[simplecan]\nnetwork_name = \"press line 3\"\nslots_per_cycle = 10\ncycles_between_syncs = 10\nbuffering_us = 500\n",
        "",
    );
    let error = parse(&text, "net.toml").unwrap_err();
    assert!(error.message.contains("no [simplecan] section"), "{error}");
    assert_eq!((error.line, error.column), (5, 1), "{error}");
}

#[test]
fn sc_req_15_the_network_name_must_not_be_empty() {
    assert_at(
        &error("\"press line 3\"", "\"  \""),
        2,
        16,
        "network name is empty",
    );
}

#[test]
fn sc_req_18_slots_per_cycle_3_to_1000() {
    assert_at(
        &error("slots_per_cycle = 10", "slots_per_cycle = 2"),
        3,
        19,
        "slots per cycle",
    );
    assert_at(
        &error("slots_per_cycle = 10", "slots_per_cycle = 1001"),
        3,
        19,
        "must be 3 to 1000",
    );
}

#[test]
fn sc_req_22_the_sync_interval_is_100_to_500_ms() {
    assert_at(
        &error("cycles_between_syncs = 10", "cycles_between_syncs = 9"),
        4,
        24,
        "10 slots × 9 cycles = 90 ms, but must be 100 to 500 ms (SC_REQ_22)",
    );
    assert_at(
        &error("cycles_between_syncs = 10", "cycles_between_syncs = 51"),
        4,
        24,
        "= 510 ms",
    );
    for good in ["cycles_between_syncs = 50", "cycles_between_syncs = 10"] {
        let text = GOOD.replace("cycles_between_syncs = 10", good);
        parse(&text, "net.toml").unwrap_or_else(|e| panic!("{good}: {e}"));
    }
}

#[test]
fn sc_req_33_the_buffering_time_is_a_u16_of_microseconds() {
    assert_at(
        &error("buffering_us = 500", "buffering_us = 70000"),
        5,
        16,
        "maximum buffering time",
    );
}

#[test]
fn sc_req_12_sc_ids_are_30h_to_7fh() {
    assert_at(
        &error("sc_id = 0x30, slot = 0", "sc_id = 0x2F, slot = 0"),
        12,
        22,
        "node 1: the SC-ID is 2Fh, but must be 30h to 7Fh",
    );
    assert_at(
        &error("sc_id = 0x41, slot = 3", "sc_id = 0x80, slot = 3"),
        18,
        22,
        "SC-ID is 80h",
    );
}

#[test]
fn sc_req_15_each_sc_id_has_exactly_one_producer() {
    assert_at(
        &error(
            "sc_id = 0x41, slot = 3, object = \"input_inverted\"",
            "sc_id = 0x30, slot = 3, object = \"input_inverted\"",
        ),
        18,
        22,
        "SC-ID 30h is produced by node 1 and by node 2",
    );
}

#[test]
fn sc_req_12_an_sc_id_is_listed_once_per_node() {
    assert_at(
        &error(
            "{ sc_id = 0x41, timeout_ms = 12,",
            "{ sc_id = 0x30, timeout_ms = 12,",
        ),
        27,
        13,
        "node 33: SC-ID 30h is listed twice",
    );
    // Produced and consumed by the same node is the same SDD entry twice.
    assert_at(
        &error(
            "consume = [{ sc_id = 0x30, timeout_ms = 50, object = \"output\" }]",
            "consume = [{ sc_id = 0x41, timeout_ms = 50, object = \"output\" }]",
        ),
        19,
        22,
        "node 2: SC-ID 41h is listed twice",
    );
}

#[test]
fn sc_req_21_producers_keep_out_of_the_last_two_slots() {
    assert_at(
        &error("slot = 3", "slot = 8"),
        18,
        35,
        "slot 8 is not a producer's slot: a cycle of 10 slots gives producers 0 to 7",
    );
    let text = GOOD.replace("slot = 3", "slot = 7");
    parse(&text, "net.toml").unwrap();
}

#[test]
fn sc_req_18_one_producer_per_slot() {
    assert_at(
        &error("slot = 3", "slot = 0"),
        18,
        35,
        "node 2: SC-ID 41h: slot 0 is already SC-ID 30h's (node 1)",
    );
}

#[test]
fn sc_req_20_timeouts_are_1_to_60000_ms() {
    assert_at(
        &error("timeout_ms = 12", "timeout_ms = 0"),
        27,
        32,
        "the safety timeout (ms, SC_REQ_20) is 0, but must be 1 to 60000",
    );
    assert_at(
        &error("timeout_ms = 12", "timeout_ms = 60001"),
        27,
        32,
        "must be 1 to 60000",
    );
}

/// N = 10 ms and 500 µs of buffering: the age reaches 10 + 1 + 0.5 = 11.5 ms before the next
/// packet counts; 11 ms is refused with those numbers, 12 ms accepted (GOOD has it).
#[test]
fn sc_req_20_a_timeout_the_cycle_cannot_meet_is_refused_with_the_numbers() {
    assert_at(
        &error("timeout_ms = 12", "timeout_ms = 11"),
        27,
        32,
        "node 33: SC-ID 41h: a safety timeout of 11 ms is not met by a fault-free network: the value is refreshed once a cycle (10 ms), its packet may go out at the end of its 1 ms slot and wait 0.5 ms in the buffers (SC_REQ_33), so its age reaches 11.5 ms",
    );
    assert_eq!(simplecan::worst_case_age_us(10, 500), 11_500);
}

#[test]
fn sc_req_16_the_mapped_object_exists_and_is_mappable_that_way() {
    assert_at(
        &error(
            "slot = 0, object = \"input\"",
            "slot = 0, object = \"output\"",
        ),
        12,
        47,
        "node 1: SC-ID 30h: object 6200h:01h cannot be mapped into a transmit SRDO or a produced SC-ID",
    );
    assert_at(
        &error(
            "{ sc_id = 0x30, timeout_ms = 50, object = \"output\" },",
            "{ sc_id = 0x30, timeout_ms = 50, object = \"input\" },",
        ),
        26,
        45,
        "cannot be mapped into a receive SRDO or a consumed SC-ID",
    );
    assert_at(
        &error("object = \"input_inverted\"", "object = \"0x6100:1:8\""),
        18,
        47,
        "node 2: SC-ID 41h: the device has no mappable object 6100h:01h",
    );
    assert_at(
        &error("object = \"input_inverted\"", "object = \"lamp\""),
        18,
        47,
        "is neither an object name",
    );
}

#[test]
fn sc_req_16_a_consumed_sc_id_is_produced_in_the_file() {
    assert_at(
        &error("sc_id = 0x41, timeout_ms", "sc_id = 0x42, timeout_ms"),
        27,
        13,
        "node 33 consumes SC-ID 42h, but no node of the file produces it",
    );
}

#[test]
fn sc_req_25_a_potential_master_produces_and_some_node_is_one() {
    assert_at(
        &error("potential_master = true", "potential_master = false"),
        2,
        16,
        "no node of the network is a potential master",
    );
    let text = GOOD.replace(
        "[node.simplecan]\nconsume = [\n",
        "[node.simplecan]\npotential_master = true\nconsume = [\n",
    );
    let error = parse(&text, "net.toml").unwrap_err();
    assert_eq!((error.line, error.column), (25, 20), "{error}");
    assert!(
        error
            .message
            .contains("node 33 is a potential master but produces no SC-ID"),
        "{error}"
    );
}

/// One potential master producing `count` SC-IDs in slots 0.. of a cycle of 100 slots, a
/// sync every 5 cycles (500 ms).
fn producers(count: u8) -> String {
    let mut text = String::from(
        "[simplecan]\nnetwork_name = \"n\"\nslots_per_cycle = 100\ncycles_between_syncs = 5\nbuffering_us = 0\n",
    );
    text.push_str("[[node]]\nid = 1\nidentity = { vendor = 1, product = 2, serial = 3 }\n[node.simplecan]\npotential_master = true\nproduce = [\n");
    for slot in 0..count {
        text.push_str(&format!(
            "  {{ sc_id = {}, slot = {slot}, object = \"input\" }},\n",
            0x30 + slot
        ));
    }
    text.push_str("]\n");
    text
}

/// SC_REQ_04 through the device's own schedule check (docs/simplecan.md section 8): 66
/// producers at N = 100 with a sync every 500 ms are 660 + 2 = 662 packets/s, accepted; 67
/// are 670 + 2 = 672, above 665, refused with the figure.
#[test]
fn sc_req_04_the_packet_rate_bound_is_the_devices_own_check() {
    let error = parse(&producers(67), "net.toml").unwrap_err();
    assert_eq!((error.line, error.column), (3, 19), "{error}");
    assert!(
        error
            .message
            .contains("the network sends 672 SimpleCAN packets per second"),
        "{error}"
    );
    let network = parse(&producers(66), "net.toml").unwrap();
    assert_eq!(network.simplecan.unwrap().nodes[&1].produced.len(), 66);
}

/// The 80 entries of SC_REQ_12 are the 80 SC-IDs, and an SC-ID is listed once per node, so
/// no file that passes the SC-ID rules can give a node more: a node consuming every SC-ID but
/// its own produced one holds exactly 80, and is accepted.
#[test]
fn sc_req_12_a_node_may_hold_all_eighty_entries() {
    let mut text = String::from(
        "[simplecan]\nnetwork_name = \"n\"\nslots_per_cycle = 500\ncycles_between_syncs = 1\nbuffering_us = 0\n",
    );
    text.push_str("[[node]]\nid = 1\nidentity = { vendor = 1, product = 2, serial = 1 }\n[node.simplecan]\npotential_master = true\nproduce = [\n");
    for slot in 0..79u8 {
        text.push_str(&format!(
            "  {{ sc_id = {}, slot = {slot}, object = \"input\" }},\n",
            0x31 + slot
        ));
    }
    text.push_str("]\n[[node]]\nid = 2\nidentity = { vendor = 1, product = 2, serial = 2 }\n[node.simplecan]\nproduce = [{ sc_id = 0x30, slot = 79, object = \"input\" }]\nconsume = [\n");
    for sc_id in 0x31..=0x7Fu8 {
        text.push_str(&format!(
            "  {{ sc_id = {sc_id}, timeout_ms = 1000, object = \"output\" }},\n"
        ));
    }
    text.push_str("]\n");
    let network = parse(&text, "net.toml").unwrap();
    let simplecan = network.simplecan.unwrap();
    assert_eq!(simplecan::node_config(&simplecan, 2).entries.len(), 80);
    assert_eq!(simplecan.hashes.len(), 80);
}

#[test]
fn sc_req_15_hashes_are_distinct_and_never_zero_in_a_network() {
    let network = parse(GOOD, "net.toml").unwrap();
    let hashes = &network.simplecan.as_ref().unwrap().hashes;
    assert_eq!(hashes.len(), 2);
    assert!(hashes.values().all(|hash| *hash != 0));
    assert_eq!(hash::first_collision(hashes), None);
    // Another network name gives other hashes for the same nodes and SC-IDs.
    let other = parse(&GOOD.replace("press line 3", "press line 4"), "net.toml").unwrap();
    let other = &other.simplecan.as_ref().unwrap().hashes;
    assert!(hashes.iter().all(|(sc_id, hash)| other[sc_id] != *hash));
}

/// `safety-config sfrt` and `budget` on a SimpleCAN network file print every consumed SC-ID's
/// reaction and SimpleCAN's residual error rate (SC_REQ_04, SC_REQ_20), as the library
/// computes them; `eds --simplecan N` lists 5E00h..5EFFh.
#[test]
fn sc_req_04_the_program_prints_simplecan_reactions_and_residual_rate() {
    use std::process::Command;
    let dir = std::env::temp_dir().join(format!("sc-calc-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("net.toml");
    std::fs::write(&file, GOOD).unwrap();
    let run = |args: &[&str]| {
        let output = Command::new(env!("CARGO_BIN_EXE_safety-config"))
            .args(args)
            .output()
            .expect("the program runs");
        (
            output.status.success(),
            String::from_utf8_lossy(&output.stdout).into_owned(),
        )
    };
    let path = file.to_str().unwrap();
    let network = parse(GOOD, "net.toml").unwrap();
    let simplecan = network.simplecan.as_ref().unwrap();
    // SimpleCAN's own measured step, not the SRDO images' (`DeviceTiming::HARDWARE`).
    let timing = safety_config::calc::sfrt::DeviceTiming::HARDWARE_SIMPLECAN;
    let reactions = safety_config::calc::simplecan::reactions(simplecan, 500_000, &timing).unwrap();
    let (ok, sfrt) = run(&["sfrt", path]);
    assert!(ok, "{sfrt}");
    // Three consumed SC-IDs: 30h at nodes 2 and 33, 41h at node 33.
    assert_eq!(sfrt.matches("SimpleCAN SC-ID").count(), 3, "{sfrt}");
    assert_eq!(reactions.len(), 3);
    for reaction in &reactions {
        let worst = safety_config::calc::report::ms(reaction.worst_us);
        assert!(sfrt.contains(&format!("**{worst}**")), "{worst} in {sfrt}");
    }
    // A step given on the command line is every safety function's, SimpleCAN's included.
    let given = safety_config::calc::sfrt::DeviceTiming {
        processing_us: 1000,
        ..timing
    };
    let (ok, sfrt) = run(&["sfrt", path, "--processing-us", "1000"]);
    assert!(ok, "{sfrt}");
    for reaction in safety_config::calc::simplecan::reactions(simplecan, 500_000, &given).unwrap() {
        let worst = safety_config::calc::report::ms(reaction.worst_us);
        assert!(sfrt.contains(&format!("**{worst}**")), "{worst} in {sfrt}");
    }
    assert!(
        sfrt.contains("SimpleCAN's channel step: 1.000 ms."),
        "{sfrt}"
    );
    let (ok, budget) = run(&["budget", path]);
    assert!(ok, "{budget}");
    assert!(budget.contains("SimpleCAN residual error rate"), "{budget}");
    assert!(!budget.contains("-0.00"), "{budget}");
    let (ok, eds) = run(&["eds", "--simplecan", "4"]);
    assert!(ok);
    for index in ["[5E00]", "[5E01]", "[5E10]", "[5E13]", "[5EFE]", "[5EFF]"] {
        assert!(eds.contains(index), "{index}");
    }
    assert!(!eds.contains("[5E14]"));
    std::fs::remove_dir_all(&dir).unwrap();
}
