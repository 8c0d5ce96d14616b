//! The view as a person reads it: drawn on ratatui's `TestBackend` at 120 × 40, the text of
//! the rendered buffer.

use super::*;
use crate::monitor::model::SrdoWatch;
use ratatui::Terminal;
use ratatui::backend::TestBackend;
use shared::{CanFrame, CanId};

const MS: Duration = Duration::from_millis(1);

fn frame(id: u16, data: &[u8]) -> CanFrame {
    CanFrame::new(CanId::new(id).unwrap(), data).unwrap()
}

/// The screen's text, one string a row, trailing blanks removed.
fn rendered(monitor: &Monitor, screen: &Screen) -> Vec<String> {
    let mut terminal = Terminal::new(TestBackend::new(120, 40)).unwrap();
    terminal.draw(|f| draw(f, monitor, screen)).unwrap();
    let buffer = terminal.backend().buffer();
    (0..buffer.area.height)
        .map(|y| {
            let row: String = (0..buffer.area.width)
                .map(|x| buffer[(x, y)].symbol())
                .collect();
            row.trim_end().to_owned()
        })
        .collect()
}

fn row<'a>(screen: &'a [String], starting: &str) -> &'a str {
    screen
        .iter()
        .find(|line| line.trim_start().starts_with(starting))
        .unwrap_or_else(|| panic!("no row starting {starting:?} in\n{}", screen.join("\n")))
}

/// The emulated network's bus: node 1 producing 101h/102h every 100 ms, node 33
/// consuming it (SCT 500 ms, SRVT 100 ms), both Operational; then one pair not inverted,
/// node 33's EMCY for it, an SDO abort and a GFC.
fn bus() -> Monitor {
    let mut monitor = Monitor::new(vec![SrdoWatch {
        producer: Some((1, 1)),
        consumers: vec![(33, 1)],
        refresh: Some(100 * MS),
        sct: Some(500 * MS),
        srvt: Some(100 * MS),
        ..SrdoWatch::learned(0x101)
    }]);
    monitor.nodes.entry(1).or_default().name = Some("emergency stop".into());
    for n in 0..10u32 {
        let at = n * 100 * MS;
        monitor.feed(at, &frame(0x701, &[0x05]));
        monitor.feed(at + MS, &frame(0x721, &[0x05]));
        monitor.feed(at + 2 * MS, &frame(0x101, &[0x01, 0x00]));
        monitor.feed(at + 3 * MS, &frame(0x102, &[0xFE, 0xFF]));
    }
    monitor.feed(1002 * MS, &frame(0x101, &[0x01, 0x00]));
    monitor.feed(1003 * MS, &frame(0x102, &[0xFE, 0xFE]));
    monitor.feed(
        1004 * MS,
        &frame(0x0A1, &[0x00, 0x82, 0x11, 1, 0x05, 0, 0, 0]),
    );
    monitor.feed(1010 * MS, &frame(0x621, &[0x2F, 0x01, 0x13, 3, 0, 0, 0, 0]));
    monitor.feed(
        1011 * MS,
        &frame(0x5A1, &[0x80, 0x01, 0x13, 3, 0x22, 0, 0, 0x08]),
    );
    monitor.feed(1020 * MS, &frame(0x001, &[]));
    monitor.poll(1050 * MS);
    monitor
}

#[test]
fn the_view_shows_nodes_srdo_pairs_with_their_numbers_emcy_in_words_and_sdo_aborts() {
    let monitor = bus();
    let screen = rendered(
        &monitor,
        &Screen {
            title: "safety-config monitor: socketcand:127.0.0.1:29536/can0".into(),
            keys: "q quit".into(),
            ..Screen::default()
        },
    );
    let text = screen.join("\n");
    assert!(
        screen[0]
            .starts_with("safety-config monitor: socketcand:127.0.0.1:29536/can0   bus time 1.1 s"),
        "{text}"
    );
    let node_1 = row(&screen, "1 ");
    assert!(node_1.contains("emergency stop"), "{node_1}");
    assert!(node_1.contains("Operational"), "{node_1}");
    assert!(node_1.contains("150.0 ms"), "heartbeat age: {node_1}");
    assert!(node_1.contains("100.0 ms"), "heartbeat period: {node_1}");
    let node_33 = row(&screen, "33 ");
    assert!(
        node_33.contains("8200h SRDO 1: not inverted"),
        "EMCY in words: {node_33}"
    );
    assert!(node_33.contains("1/1"), "SDO requests/responses: {node_33}");
    let srdo = row(&screen, "101h/102h");
    // 10 valid pairs, 1 fault, last gap 1.0 ms of SRVT 100, last period 100.0 of SCT 500.
    for expected in [
        "1 → 33",
        " 10 ",
        " 1 ",
        "1.0 / 100",
        "100.0 / 500",
        "not inverted",
    ] {
        assert!(srdo.contains(expected), "{expected:?} in {srdo}");
    }
    assert!(srdo.contains("▁▁▁▁"), "timeline: {srdo}");
    assert!(
        text.contains("GFC: 1 (latest 0.0 s ago)   SDO: 1 requests, 1 responses, 1 aborts"),
        "{text}"
    );
    assert!(
        text.contains("node 33: SDO 1301h:03h aborted by the node with 08000022h:"),
        "{text}"
    );
    assert!(
        text.contains("1.004 s  node 33: EMCY 8200h: SRDO 1: not inverted"),
        "{text}"
    );
    assert!(
        text.contains("1.020 s  GFC (global fail-safe command) on the bus"),
        "{text}"
    );
    assert_eq!(screen[39], "q quit");
}

/// A consumer's SCT passed without a pair: the SRDO says so in words and seconds.
#[test]
fn the_view_says_when_an_srdo_has_been_silent_past_its_sct() {
    let mut monitor = bus();
    monitor.poll(2500 * MS);
    let screen = rendered(&monitor, &Screen::default());
    let srdo = row(&screen, "101h/102h");
    assert!(srdo.contains("silent 1.5 s (SCT 500 ms)"), "{srdo}");
}

/// Panels of the caller come first, with their title; help covers the middle while shown;
/// a paused view says so.
#[test]
fn the_view_shows_the_callers_panels_help_and_pause() {
    let screen = rendered(
        &bus(),
        &Screen {
            title: "run".into(),
            panels: vec![("Channels".into(), vec!["node1a Operational working".into()])],
            help: Some(vec!["q  quit".into()]),
            paused: true,
            ..Screen::default()
        },
    );
    let text = screen.join("\n");
    assert!(screen[0].contains("PAUSED"), "{text}");
    assert!(screen[1].contains("Channels"), "{text}");
    assert_eq!(screen[2], "node1a Operational working");
    assert!(text.contains("Help (any key closes)"), "{text}");
    assert!(text.contains("│q  quit"), "{text}");
}

#[test]
fn a_timeline_scales_to_its_limit_and_marks_a_value_at_the_limit() {
    let values = [0, 50, 99, 100, 150].map(Duration::from_millis);
    assert_eq!(timeline(values.into_iter(), 100 * MS, 12), "▁▅█!!");
    assert_eq!(timeline(values.into_iter(), 100 * MS, 2), "!!");
    assert_eq!(timeline(std::iter::empty(), 100 * MS, 12), "");
}

#[test]
fn the_summary_gives_every_node_and_srdo_with_its_largest_gap_and_period() {
    let lines = summary(&bus());
    assert!(
        lines.contains(&"SRDO 101h/102h (1 → 33): 10 valid, 1 not inverted; largest gap 1.0 ms (SRVT 100 ms), largest period 100.0 ms (SCT 500 ms); now not inverted".to_owned()),
        "{lines:#?}"
    );
    assert!(
        lines[0].starts_with("node 1 (emergency stop): Operational, heartbeat age 150.0 ms"),
        "{lines:#?}"
    );
}

/// A SimpleCAN network from a file: node 1 (master, 30h in slot 0) and node 2 (41h in slot
/// 3), node 33 consuming 41h with a timeout of 20 ms; a sync, two packets of 41h 200 and
/// 500 µs into their slots, one packet of 30h with a bad CRC.
#[test]
fn sc_req_18_the_view_shows_simplecan_values_ages_slot_offsets_jitter_and_syncs() {
    use shared::simplecan::frame::{DataPacket, SyncPacket};
    use shared::simplecan::{NodeHash, ScId};
    let file = r#"[simplecan]
network_name = "view test"
slots_per_cycle = 10
cycles_between_syncs = 10
buffering_us = 0
[[node]]
id = 1
identity = { vendor = 1, product = 2, serial = 1 }
[node.simplecan]
potential_master = true
produce = [{ sc_id = 0x30, slot = 0, object = "input" }]
[[node]]
id = 2
identity = { vendor = 1, product = 2, serial = 2 }
[node.simplecan]
produce = [{ sc_id = 0x41, slot = 3, object = "input" }]
[[node]]
id = 33
identity = { vendor = 1, product = 2, serial = 33 }
[node.simplecan]
consume = [{ sc_id = 0x41, timeout_ms = 20, object = "output" }]
"#;
    let network = crate::network_file::parse(file, "net.toml").unwrap();
    let hashes = network.simplecan.as_ref().unwrap().hashes.clone();
    let hash = |sc_id: u8| NodeHash(hashes[&sc_id]);
    let sc = |raw| ScId::new(raw).unwrap();
    let us = Duration::from_micros;
    let packet = |sc_id: u8, value, stamp| {
        DataPacket {
            sc_id: sc(sc_id),
            value,
            cycle_stamp: stamp,
        }
        .encode(hash(sc_id))
    };
    let mut monitor = Monitor::for_network(&network);
    monitor.feed(
        us(9_300),
        &SyncPacket::new(sc(0x30), 0, 300)
            .unwrap()
            .encode(hash(0x30)),
    );
    monitor.feed(us(13_200), &packet(0x41, 1, 1));
    monitor.feed(us(23_500), &packet(0x41, 0xDEAD_BEEF, 2));
    monitor.feed(
        us(30_000),
        &DataPacket {
            sc_id: sc(0x30),
            value: 1,
            cycle_stamp: 3,
        }
        .encode(NodeHash(hashes[&0x30] ^ 1)),
    );
    let screen = rendered(&monitor, &Screen::default());
    let row_41 = row(&screen, "41h");
    for words in [
        "2 → 33",
        " 3 ",
        "DEADBEEFh",
        "7.0 / 20",
        "200..500",
        "300",
        "0 / 0",
    ] {
        assert!(row_41.contains(words), "{words:?} in {row_41:?}");
    }
    assert!(row(&screen, "30h").contains("0 / 1"), "a bad CRC counted");
    row(
        &screen,
        "syncs from master SC-ID 30h: 1, latest cycle 0 (+300 µs)",
    );
    row(&screen, "SimpleCAN: 1 bad CRCs, 0 malformed");
    let summary = summary(&monitor);
    assert!(
        summary.iter().any(|line| line.starts_with(
            "SimpleCAN SC-ID 41h (2 → 33, slot 3): 2 packets, value DEADBEEFh, age/timeout 7.0 / 20 ms, slot offset 200..500 µs, jitter 300 µs"
        )),
        "{summary:#?}"
    );
}

/// Without a network file: the packets counted as undecodable without the hash, and the
/// reason said.
#[test]
fn sc_req_15_the_view_says_why_simplecan_packets_are_not_decoded_without_a_file() {
    let mut monitor = Monitor::default();
    monitor.feed(
        Duration::from_millis(1),
        &frame(0x41, &[1, 0, 0, 0, 5, 1, 2, 3]),
    );
    monitor.feed(
        Duration::from_millis(2),
        &frame(0x41, &[1, 0, 0, 0, 6, 1, 2, 3]),
    );
    let screen = rendered(&monitor, &Screen::default());
    assert!(
        row(&screen, "41h").contains("2 without hash"),
        "{screen:#?}"
    );
    row(
        &screen,
        "SimpleCAN: 0 bad CRCs, 0 malformed; no network file: no node hash is known",
    );
}
