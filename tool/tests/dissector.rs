//! The Wireshark dissector of `safety-config dissector`, run by tshark on a trace the monitor
//! recorded as pcap: SRDO pairs judged as the monitor judges them (EN 50325-5 7.1), the GFC,
//! and SimpleCAN packets whose CRC the Lua code computes as the device's Rust code does
//! (`shared::simplecan::frame`, SC_REQ_15). tshark is Debian's package, which `cargo xtask
//! setup` installs.

use safety_config::monitor::candump;
use safety_config::monitor::model::{Monitor, PairVerdict};
use shared::simplecan::frame::{DataPacket, DecodeError, SyncPacket, decode};
use shared::simplecan::{NodeHash, ScId};
use shared::{CanFrame, CanId};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

const MS: Duration = Duration::from_millis(1);

/// One SRDO (101h/102h, SRVT 20 ms, SCT 250 ms) and SC-ID 30h from node 1 to node 33.
const NETWORK: &str = r#"
[simplecan]
network_name = "dissector test network"
slots_per_cycle = 10
cycles_between_syncs = 10
buffering_us = 500

[[node]]
id = 1
name = "emergency stop"
identity = { vendor = 0xABC, product = 0x304, revision = 1, serial = 1 }
[[node.srdo]]
number = 1
direction = "transmit"
refresh_time_ms = 100
srvt_ms = 20
cob_ids = [0x101, 0x102]
mapping = ["input", "input_inverted"]
[node.simplecan]
potential_master = true
produce = [{ sc_id = 0x30, slot = 0, object = "input" }]

[[node]]
id = 33
name = "safe output"
identity = { vendor = 0xABC, product = 0x304, revision = 1, serial = 33 }
[[node.srdo]]
number = 1
direction = "receive"
sct_ms = 250
srvt_ms = 20
cob_ids = [0x101, 0x102]
mapping = ["output", "output_inverted"]
[node.simplecan]
consume = [{ sc_id = 0x30, timeout_ms = 50, object = "output" }]
"#;

fn frame(id: u16, data: &[u8]) -> CanFrame {
    CanFrame::new(CanId::new(id).unwrap(), data).unwrap()
}

fn directory() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("safety-config-dissector-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A small xorshift generator: the same frames on every run.
struct Random(u64);

impl Random {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
}

/// The SRDO frames, each case of EN 50325-5 7.1 once, and the verdict the dissector gives
/// on the frame that completes (or breaks) a pair.
fn srdo_frames() -> Vec<(Duration, CanFrame, Option<&'static str>)> {
    let plain = frame(0x101, &[0x01, 0x00]);
    let inverted = frame(0x102, &[0xFE, 0xFF]);
    vec![
        (Duration::ZERO, plain, None),
        (2 * MS, inverted, Some("valid")),
        // EN 50325-5 7.1.1: bit 7 of byte 1 is not inverted.
        (100 * MS, plain, None),
        (102 * MS, frame(0x102, &[0xFE, 0x7F]), Some("not inverted")),
        // 7.1.2: the inverted frame 30 ms after the plain one, SRVT 20 ms.
        (200 * MS, plain, None),
        (230 * MS, inverted, Some("SRVT exceeded")),
        // At the limit counts as exceeded, as the node's timer does.
        (300 * MS, plain, None),
        (320 * MS, inverted, Some("SRVT exceeded")),
        // A repeated plain frame (CAN double reception) is discarded: SRVT runs from the first.
        (400 * MS, plain, None),
        (401 * MS, plain, None),
        (403 * MS, inverted, Some("valid")),
        // No inverted frame: the next plain frame, after SRVT, says so.
        (500 * MS, plain, None),
        (600 * MS, plain, Some("inverted frame missing")),
        (602 * MS, inverted, Some("valid")),
        // 7.1.2: 300 ms since the previous pair, SCT 250 ms.
        (900 * MS, plain, None),
        (902 * MS, inverted, Some("SCT exceeded")),
        // 7.1.3: different lengths.
        (1000 * MS, frame(0x101, &[0x01]), None),
        (1002 * MS, inverted, Some("lengths differ")),
        // Time passed beyond SRVT with another frame before the inverted one came: missing,
        // as the monitor judges it, said on the late inverted frame.
        (1040 * MS, plain, None),
        (1070 * MS, frame(0x701, &[0x05]), None),
        (1075 * MS, inverted, Some("inverted frame missing")),
    ]
}

/// What tshark decoded of one frame: field name → value.
type Decoded = BTreeMap<&'static str, String>;

const FIELDS: [&str; 16] = [
    "frame.number",
    "cansafety.frame",
    "cansafety.srdo.verdict",
    "cansafety.srdo.valid",
    "cansafety.srdo.inverted_ok",
    "cansafety.srdo.mismatch",
    "cansafety.srdo.gap_ms",
    "cansafety.srdo.srvt_exceeded",
    "cansafety.srdo.period_ms",
    "cansafety.srdo.sct_exceeded",
    "cansafety.srdo.plain_frame",
    "cansafety.gfc",
    "cansafety.simplecan.sc_id",
    "cansafety.simplecan.crc_ok",
    "cansafety.simplecan.crc_computed",
    "cansafety.simplecan.problem",
];

/// Runs `program` with `arguments`, failing the test with its output when it fails.
fn run(program: &str, arguments: &[&Path]) -> Vec<u8> {
    let output = Command::new(program)
        .args(arguments)
        .output()
        .unwrap_or_else(|error| {
            panic!("{program} did not start ({error}); tshark: run `cargo xtask setup`")
        });
    assert!(
        output.status.success(),
        "{program} {arguments:?}: {}\n{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    output.stdout
}

/// The trace `frames` as the monitor records it (`--record trace.pcap` of a replayed
/// candump log), decoded by tshark with the dissector of [`NETWORK`].
fn decode_with_tshark(frames: &[(Duration, CanFrame)]) -> Vec<Decoded> {
    let dir = directory();
    let network = dir.join("network.toml");
    std::fs::write(&network, NETWORK).unwrap();
    let start = Duration::from_secs(1_700_000_000);
    let lines: Vec<String> = frames
        .iter()
        .map(|(at, frame)| candump::line(start + *at, "can0", frame))
        .collect();
    let log = dir.join("trace.log");
    std::fs::write(&log, lines.join("\n")).unwrap();
    let pcap = dir.join("trace.pcap");
    let tool = env!("CARGO_BIN_EXE_safety-config");
    let mut record = Command::new(tool);
    record
        .args(["monitor", "--plain", "--fast", "--replay"])
        .arg(&log)
        .arg("--record")
        .arg(&pcap);
    let recorded = record.output().unwrap();
    assert!(recorded.status.success(), "{recorded:?}");
    let lua = dir.join("safety.lua");
    std::fs::write(&lua, run(tool, &[Path::new("dissector"), &network])).unwrap();

    let mut arguments: Vec<String> = vec![
        "-X".into(),
        format!("lua_script:{}", lua.display()),
        "-r".into(),
        pcap.display().to_string(),
        // CANopen as well, as a user opens the trace: the dissector decodes beside it.
        "-d".into(),
        "can.subdissector,canopen".into(),
        "-T".into(),
        "fields".into(),
        "-E".into(),
        "separator=|".into(),
    ];
    for field in FIELDS {
        arguments.push("-e".into());
        arguments.push(field.into());
    }
    let output = Command::new("tshark")
        .args(&arguments)
        .output()
        .unwrap_or_else(|error| panic!("tshark is missing ({error}): run `cargo xtask setup`"));
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{stdout}\n{stderr}");
    assert!(
        !stderr.contains("Lua") && !stderr.contains("error"),
        "the dissector failed to load or run: {stderr}"
    );
    let decoded: Vec<Decoded> = stdout
        .lines()
        .map(|line| {
            FIELDS
                .into_iter()
                .zip(line.split('|').map(str::to_owned))
                .filter(|(_, value)| !value.is_empty())
                .collect()
        })
        .collect();
    assert_eq!(decoded.len(), frames.len(), "{stdout}");
    decoded
}

/// tshark prints a boolean field as 1/0 (Wireshark 4.0) or True/False (later versions).
fn flag(decoded: &Decoded, field: &str) -> Option<bool> {
    decoded.get(field).map(|value| match value.as_str() {
        "1" | "True" => true,
        "0" | "False" => false,
        other => panic!("{field} = {other:?} is not a boolean"),
    })
}

fn number(decoded: &Decoded, field: &str) -> f64 {
    decoded[field]
        .parse()
        .unwrap_or_else(|_| panic!("{field} = {:?}", decoded[field]))
}

/// The whole trace: SRDO pairs, a GFC, SimpleCAN packets good and corrupted.
#[test]
fn en50325_5_7_1_1_and_sc_req_15_tshark_decodes_a_recorded_trace_with_the_dissector() {
    let network = safety_config::network_file::parse(NETWORK, "network.toml").unwrap();
    let hash = network.simplecan.as_ref().unwrap().hashes[&0x30];
    let sc_30 = ScId::new(0x30).unwrap();
    let hashes = |sc_id: ScId| (sc_id == sc_30).then_some(NodeHash(hash));

    let srdo = srdo_frames();
    let mut frames: Vec<(Duration, CanFrame)> = srdo.iter().map(|(at, f, _)| (*at, *f)).collect();
    let gfc_at = frames.len();
    frames.push((1100 * MS, shared::safety::gfc::frame()));
    // SimpleCAN: packets of 30h encoded by the device's code, each also with one bit of its
    // data or CRC flipped; a sync of master 30h; a packet of 31h, whose hash the file lacks.
    let simplecan_at = frames.len();
    let mut random = Random(0x5EED_CAFE_F00D_0001);
    let mut at = 1200 * MS;
    let mut packets = vec![
        DataPacket {
            sc_id: sc_30,
            value: 1,
            cycle_stamp: 5,
        }
        .encode(NodeHash(hash)),
        SyncPacket::new(sc_30, 0x0102, 250)
            .unwrap()
            .encode(NodeHash(hash)),
    ];
    for _ in 0..48 {
        let word = random.next();
        let good = DataPacket {
            sc_id: sc_30,
            value: word as u32,
            cycle_stamp: (word >> 32) as u8,
        }
        .encode(NodeHash(hash));
        let mut bytes = [0u8; 8];
        bytes.copy_from_slice(good.data());
        let bit = (word >> 40) as usize % 64;
        bytes[bit / 8] ^= 1 << (bit % 8);
        packets.push(good);
        packets.push(frame(0x030, &bytes));
    }
    packets.push(frame(0x031, &[1, 2, 3, 4, 5, 6, 7, 8]));
    for packet in &packets {
        frames.push((at, *packet));
        at += MS;
    }

    let decoded = decode_with_tshark(&frames);

    // SRDOs: every verdict as expected, and the checks behind it.
    for (n, (_, frame, verdict)) in srdo.iter().enumerate() {
        let row = &decoded[n];
        let kind = match frame.id().raw() {
            0x101 => Some("SRDO plain"),
            0x102 => Some("SRDO inverted"),
            _ => None,
        };
        assert_eq!(
            row.get("cansafety.frame").map(String::as_str),
            kind,
            "frame {}: {row:?}",
            n + 1
        );
        assert_eq!(
            row.get("cansafety.srdo.verdict").map(String::as_str),
            *verdict,
            "frame {}: {row:?}",
            n + 1
        );
    }
    let valid = &decoded[1];
    assert_eq!(flag(valid, "cansafety.srdo.valid"), Some(true));
    assert_eq!(flag(valid, "cansafety.srdo.inverted_ok"), Some(true));
    assert_eq!(valid["cansafety.srdo.mismatch"], "0000");
    assert_eq!(number(valid, "cansafety.srdo.gap_ms"), 2.0);
    assert_eq!(flag(valid, "cansafety.srdo.srvt_exceeded"), Some(false));
    assert_eq!(valid["cansafety.srdo.plain_frame"], "1");
    let not_inverted = &decoded[3];
    assert_eq!(flag(not_inverted, "cansafety.srdo.valid"), Some(false));
    assert_eq!(
        flag(not_inverted, "cansafety.srdo.inverted_ok"),
        Some(false)
    );
    assert_eq!(not_inverted["cansafety.srdo.mismatch"], "0080");
    assert_eq!(number(not_inverted, "cansafety.srdo.period_ms"), 100.0);
    let late = &decoded[5];
    assert_eq!(flag(late, "cansafety.srdo.inverted_ok"), Some(true));
    assert_eq!(number(late, "cansafety.srdo.gap_ms"), 30.0);
    assert_eq!(flag(late, "cansafety.srdo.srvt_exceeded"), Some(true));
    assert_eq!(number(&decoded[7], "cansafety.srdo.gap_ms"), 20.0);
    assert_eq!(
        flag(&decoded[7], "cansafety.srdo.srvt_exceeded"),
        Some(true)
    );
    assert_eq!(
        number(&decoded[10], "cansafety.srdo.gap_ms"),
        3.0,
        "from the first copy"
    );
    assert_eq!(decoded[12]["cansafety.srdo.plain_frame"], "12");
    let slow = &decoded[15];
    assert_eq!(number(slow, "cansafety.srdo.period_ms"), 300.0);
    assert_eq!(flag(slow, "cansafety.srdo.sct_exceeded"), Some(true));
    assert_eq!(flag(slow, "cansafety.srdo.srvt_exceeded"), Some(false));
    assert_eq!(flag(&decoded[17], "cansafety.srdo.inverted_ok"), None);
    assert_eq!(decoded[20]["cansafety.srdo.plain_frame"], "19");

    // The monitor's model reaches the same verdicts on the same frames.
    let mut monitor = Monitor::for_network(&network);
    for (at, frame) in &frames {
        monitor.feed(*at, frame);
    }
    let mut lua_counts: BTreeMap<String, u64> = BTreeMap::new();
    for row in &decoded[..srdo.len()] {
        if let Some(verdict) = row.get("cansafety.srdo.verdict") {
            *lua_counts.entry(verdict.clone()).or_default() += 1;
        }
    }
    let model_counts: BTreeMap<String, u64> = monitor.srdos[&0x101]
        .verdicts
        .iter()
        .map(|(verdict, count)| (PairVerdict::describe(*verdict).to_owned(), *count))
        .collect();
    assert_eq!(lua_counts, model_counts);

    // The GFC.
    assert_eq!(decoded[gfc_at]["cansafety.frame"], "GFC");
    assert_eq!(flag(&decoded[gfc_at], "cansafety.gfc"), Some(true));

    // SimpleCAN: the Lua CRC is the Rust one on every packet, and its verdict the decoder's.
    for (n, packet) in packets.iter().enumerate() {
        let row = &decoded[simplecan_at + n];
        let expected = decode(packet, &hashes);
        match expected {
            Ok(_) => {
                assert_eq!(
                    flag(row, "cansafety.simplecan.crc_ok"),
                    Some(true),
                    "{row:?}"
                );
                assert_eq!(row.get("cansafety.simplecan.problem"), None, "{row:?}");
                let crc =
                    u32::from_be_bytes([0, packet.data()[5], packet.data()[6], packet.data()[7]]);
                assert_eq!(
                    row["cansafety.simplecan.crc_computed"],
                    format!("0x{crc:06x}"),
                    "{row:?}"
                );
            }
            Err(DecodeError::BadCrc { .. }) => {
                assert_eq!(
                    flag(row, "cansafety.simplecan.crc_ok"),
                    Some(false),
                    "{row:?}"
                );
                assert_eq!(row["cansafety.simplecan.problem"], "bad CRC");
                // The CRC the Lua code computed over the received content is the Rust
                // encoder's over the same content.
                let data = packet.data();
                let recomputed = DataPacket {
                    sc_id: sc_30,
                    value: u32::from_le_bytes([data[0], data[1], data[2], data[3]]),
                    cycle_stamp: data[4],
                }
                .encode(NodeHash(hash));
                let crc = recomputed.data();
                assert_eq!(
                    row["cansafety.simplecan.crc_computed"],
                    format!("0x{:02x}{:02x}{:02x}", crc[5], crc[6], crc[7]),
                    "{row:?}"
                );
            }
            Err(DecodeError::UnknownScId { .. }) => {
                assert_eq!(row["cansafety.simplecan.sc_id"], "0x31");
                assert_eq!(flag(row, "cansafety.simplecan.crc_ok"), None);
                assert!(
                    row["cansafety.simplecan.problem"].starts_with("no node hash for SC-ID 31h"),
                    "{row:?}"
                );
            }
            Err(other) => panic!("packet {n}: {other:?} is not a case of this test"),
        }
    }
    assert_eq!(decoded[simplecan_at]["cansafety.frame"], "SimpleCAN data");
    assert_eq!(
        decoded[simplecan_at + 1]["cansafety.frame"],
        "SimpleCAN sync"
    );
    let bad = decoded[simplecan_at..]
        .iter()
        .filter(|row| flag(row, "cansafety.simplecan.crc_ok") == Some(false))
        .count();
    assert_eq!(bad, 48, "every corrupted packet, and only those");
}
