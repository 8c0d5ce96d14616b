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
