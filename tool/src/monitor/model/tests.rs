//! The monitor's model on frames with known timing: every verdict at and just inside its
//! limit, the discards of CAN double reception, learning, heartbeat, EMCY and SDO decoding.

use super::*;
use shared::CanId;

const MS: Duration = Duration::from_millis(1);

fn frame(id: u16, data: &[u8]) -> CanFrame {
    CanFrame::new(CanId::new(id).unwrap(), data).unwrap()
}

fn inverse(data: &[u8]) -> Vec<u8> {
    data.iter().map(|byte| !byte).collect()
}

/// The SRDO of `cargo xtask run`'s network: 101h/102h, SCT 500 ms, SRVT 100 ms.
fn watched() -> Monitor {
    Monitor::new(vec![SrdoWatch {
        producer: Some((1, 1)),
        consumers: vec![(33, 1)],
        refresh: Some(100 * MS),
        sct: Some(500 * MS),
        srvt: Some(100 * MS),
        ..SrdoWatch::learned(0x101)
    }])
}

/// A pair of `data` at `at`, the inverted frame `gap` later.
fn pair(monitor: &mut Monitor, at: Duration, gap: Duration, data: &[u8]) {
    monitor.feed(at, &frame(0x101, data));
    monitor.feed(at + gap, &frame(0x102, &inverse(data)));
}

fn srdo(monitor: &Monitor) -> &SrdoView {
    &monitor.srdos[&0x101]
}

/// EN 50325-5 7.1.1 and 7.1.2: pairs that are inverse, within SRVT and SCT are valid, with
/// their gaps and periods measured as the frames' time differences.
#[test]
fn monitor_matches_pairs_and_measures_gap_and_period() {
    let mut monitor = watched();
    pair(&mut monitor, 10 * MS, 2 * MS, &[0x01, 0x00]);
    pair(&mut monitor, 110 * MS, 3 * MS, &[0x01, 0x00]);
    pair(&mut monitor, 215 * MS, 99 * MS, &[0x00, 0x00]);
    let view = srdo(&monitor);
    assert_eq!(view.count(PairVerdict::Valid), 3);
    assert_eq!(view.faults(), 0);
    assert_eq!(Vec::from(view.gaps.clone()), [2 * MS, 3 * MS, 99 * MS]);
    assert_eq!(Vec::from(view.periods.clone()), [100 * MS, 105 * MS]);
    assert_eq!(view.last_data, Some(frame(0x101, &[0x00, 0x00])));
    assert_eq!(view.silent_for(400 * MS), Some(185 * MS));
}

/// EN 50325-5 7.1.1: one bit not inverted, or another length, is a fault of that pair.
#[test]
fn monitor_finds_a_pair_that_is_not_inverted_to_the_bit() {
    let mut monitor = watched();
    for bit in 0..16 {
        let at = Duration::from_millis(100 * bit);
        monitor.feed(at, &frame(0x101, &[0x01, 0x00]));
        let mut inverted = inverse(&[0x01, 0x00]);
        inverted[(bit / 8) as usize] ^= 1 << (bit % 8);
        monitor.feed(at + MS, &frame(0x102, &inverted));
    }
    assert_eq!(srdo(&monitor).count(PairVerdict::NotInverted), 16);
    monitor.feed(2000 * MS, &frame(0x101, &[0x01, 0x00]));
    monitor.feed(2001 * MS, &frame(0x102, &[0xFE]));
    assert_eq!(srdo(&monitor).count(PairVerdict::LengthsDiffer), 1);
    assert_eq!(srdo(&monitor).count(PairVerdict::Valid), 0);
}

/// EN 50325-5 7.1.2: an inverted frame at SRVT exactly is late (a deadline counts as
/// expired at the instant itself); one microsecond earlier it is in time.
#[test]
fn monitor_judges_the_srvt_at_the_limit_itself() {
    let mut monitor = watched();
    pair(
        &mut monitor,
        Duration::ZERO,
        100 * MS - Duration::from_micros(1),
        &[1, 0],
    );
    assert_eq!(srdo(&monitor).last_verdict.unwrap().1, PairVerdict::Valid);
    monitor.feed(300 * MS, &frame(0x101, &[1, 0]));
    assert_eq!(monitor.deadline(), Some(400 * MS));
    monitor.feed(400 * MS, &frame(0x102, &inverse(&[1, 0])));
    assert_eq!(srdo(&monitor).count(PairVerdict::SrvtExceeded), 1);
    assert_eq!(srdo(&monitor).gaps.back(), Some(&(100 * MS)));
}

/// EN 50325-5 7.1.2: a plain frame with no inverted frame is judged missing when SRVT has
/// passed, by a poll alone (no further frame needed), and the monitor says when that is.
#[test]
fn monitor_judges_a_missing_inverted_frame_at_the_srvt_deadline() {
    let mut monitor = watched();
    monitor.feed(50 * MS, &frame(0x101, &[1, 0]));
    assert_eq!(monitor.deadline(), Some(150 * MS));
    monitor.poll(150 * MS - Duration::from_micros(1));
    assert_eq!(srdo(&monitor).last_verdict, None);
    monitor.poll(150 * MS);
    assert_eq!(
        srdo(&monitor).last_verdict,
        Some((150 * MS, PairVerdict::InvertedMissing))
    );
    assert_eq!(monitor.deadline(), None);
    // The late inverted frame that follows has no plain frame left: discarded.
    monitor.feed(160 * MS, &frame(0x102, &inverse(&[1, 0])));
    assert_eq!(srdo(&monitor).orphan_inverted, 1);
    assert!(
        monitor
            .happenings
            .iter()
            .any(|(at, line)| *at == 150 * MS && line == "SRDO 101h/102h: inverted frame missing")
    );
}

/// EN 50325-5 7.1.2: a pair whose plain frame comes SCT or more after the previous pair's
/// is a fault; just inside SCT it is valid.
#[test]
fn monitor_judges_the_period_against_the_sct() {
    let mut monitor = watched();
    pair(&mut monitor, Duration::ZERO, MS, &[1, 0]);
    pair(
        &mut monitor,
        500 * MS - Duration::from_micros(1),
        MS,
        &[1, 0],
    );
    assert_eq!(srdo(&monitor).count(PairVerdict::Valid), 2);
    pair(
        &mut monitor,
        1000 * MS - Duration::from_micros(1),
        MS,
        &[1, 0],
    );
    assert_eq!(srdo(&monitor).count(PairVerdict::SctExceeded), 1);
}

/// CiA 304 9.5 and ISO 11898-1 double reception, as the node judges them: an exact repeat
/// of the pending plain frame is discarded (the gap runs from the first copy), a plain frame
/// with other data before the inverted one is a fault, an inverted frame without a plain
/// frame is discarded.
#[test]
fn monitor_discards_double_reception_and_finds_a_plain_frame_repeated_with_other_data() {
    let mut monitor = watched();
    monitor.feed(Duration::ZERO, &frame(0x101, &[1, 0]));
    monitor.feed(MS, &frame(0x101, &[1, 0]));
    monitor.feed(5 * MS, &frame(0x102, &inverse(&[1, 0])));
    assert_eq!(srdo(&monitor).repeated_plain, 1);
    assert_eq!(srdo(&monitor).gaps.back(), Some(&(5 * MS)));
    assert_eq!(srdo(&monitor).count(PairVerdict::Valid), 1);
    monitor.feed(6 * MS, &frame(0x102, &inverse(&[1, 0])));
    assert_eq!(srdo(&monitor).orphan_inverted, 1);
    monitor.feed(100 * MS, &frame(0x101, &[1, 0]));
    monitor.feed(101 * MS, &frame(0x101, &[0, 0]));
    assert_eq!(srdo(&monitor).count(PairVerdict::PlainRepeated), 1);
    monitor.feed(102 * MS, &frame(0x102, &inverse(&[0, 0])));
    assert_eq!(srdo(&monitor).count(PairVerdict::Valid), 2);
}

/// An SRDO in no network file is learned from its first frame (EN 50325-5 7.2.1: plain on
/// the odd COB-ID, inverted on the next); without limits it is judged on inversion alone.
#[test]
fn monitor_learns_an_srdo_from_the_bus_and_judges_it_without_limits() {
    let mut monitor = Monitor::default();
    monitor.feed(Duration::ZERO, &frame(0x111, &[0xAA]));
    monitor.feed(900 * MS, &frame(0x112, &[0x55]));
    monitor.feed(5000 * MS, &frame(0x111, &[0xAA]));
    monitor.feed(5001 * MS, &frame(0x112, &[0x54]));
    let view = &monitor.srdos[&0x111];
    assert_eq!(view.watch, SrdoWatch::learned(0x111));
    assert_eq!(view.count(PairVerdict::Valid), 1);
    assert_eq!(view.count(PairVerdict::NotInverted), 1);
    // An inverted frame first is learned as its SRDO too, and discarded.
    monitor.feed(6000 * MS, &frame(0x120, &[0]));
    assert_eq!(monitor.srdos[&0x11F].orphan_inverted, 1);
    assert_eq!(monitor.deadline(), None);
}

/// The network file gives each SRDO its producer's refresh time and its consumers' SCT and
/// SRVT; a consumer's SRVT (not the producer's) is the one judged.
#[test]
fn monitor_takes_the_srdo_limits_from_the_network_file() {
    let text = r#"
[[node]]
id = 1
name = "emergency stop"
identity = { vendor = 0xABC, product = 0x304, serial = 1 }
[[node.srdo]]
number = 1
direction = "transmit"
refresh_time_ms = 100
srvt_ms = 20
cob_ids = [0x101, 0x102]
mapping = ["input", "input_inverted"]

[[node]]
id = 33
identity = { vendor = 0xABC, product = 0x304, serial = 33 }
[[node.srdo]]
number = 2
direction = "receive"
sct_ms = 500
srvt_ms = 100
cob_ids = [0x101, 0x102]
mapping = ["output", "output_inverted"]
"#;
    let network = crate::network_file::parse(text, "net.toml").unwrap();
    let monitor = Monitor::for_network(&network);
    assert_eq!(
        Vec::from_iter(monitor.srdos.values().map(|view| view.watch.clone())),
        [SrdoWatch {
            plain: 0x101,
            inverted: 0x102,
            producer: Some((1, 1)),
            consumers: vec![(33, 2)],
            refresh: Some(100 * MS),
            sct: Some(500 * MS),
            srvt: Some(100 * MS),
        }]
    );
    assert_eq!(monitor.nodes[&1].name.as_deref(), Some("emergency stop"));
    assert_eq!(monitor.nodes[&33].state, None);
}

/// CiA 301 7.2.8.3.2: heartbeat state (toggle bit masked), its age and period; a boot-up
/// message means Pre-operational and starts the period afresh.
#[test]
fn monitor_follows_nmt_state_and_heartbeat_age() {
    let mut monitor = Monitor::default();
    monitor.feed(Duration::ZERO, &frame(0x721, &[0x00]));
    monitor.feed(100 * MS, &frame(0x721, &[0x7F]));
    monitor.feed(200 * MS, &frame(0x721, &[0x85]));
    let node = &monitor.nodes[&33];
    assert_eq!(node.state, Some(NmtState::Operational));
    assert_eq!(node.heartbeat_period, Some(100 * MS));
    assert_eq!(node.heartbeat_age(250 * MS), Some(50 * MS));
    assert_eq!(node.heartbeats, 3);
    monitor.feed(300 * MS, &frame(0x721, &[0x00]));
    assert_eq!(monitor.nodes[&33].heartbeat_period, None);
    let lines: Vec<&str> = monitor.happenings.iter().map(|(_, l)| l.as_str()).collect();
    assert_eq!(
        lines,
        [
            "node 33: boot-up, Pre-operational",
            "node 33: Operational",
            "node 33: boot-up, Pre-operational"
        ]
    );
}

/// CiA 301 7.2.8.3.2.2 (heartbeat consumer: a heartbeat not received within the consumer
/// time is a heartbeat event): a node whose heartbeat is older than its consumer time is
/// flagged lost once, at the instant the time ran out, while the bus goes on (another node's
/// frames move the model's time), and a heartbeat *at* the limit is late; its next heartbeat
/// clears it. A node without a consumer time is not judged.
#[test]
fn cia301_7_2_8_3_2_2_a_heartbeat_older_than_its_consumer_time_is_flagged_lost() {
    let mut monitor = Monitor::default();
    monitor.nodes.entry(1).or_default().consumer_time = Some(250 * MS);
    for beat in 0..3 {
        monitor.feed(beat * 100 * MS, &frame(0x701, &[0x05]));
        monitor.feed(beat * 100 * MS, &frame(0x721, &[0x05]));
    }
    assert_eq!(monitor.deadline(), Some(450 * MS), "node 1: 200 + 250 ms");
    // Node 1 falls silent; node 33 goes on.
    monitor.feed(300 * MS, &frame(0x721, &[0x05]));
    monitor.feed(400 * MS, &frame(0x721, &[0x05]));
    assert!(!monitor.nodes[&1].heartbeat_lost, "due at 450 ms");
    monitor.poll(450 * MS);
    assert!(
        monitor.nodes[&1].heartbeat_lost,
        "a heartbeat at the limit is late"
    );
    assert_eq!(monitor.deadline(), None, "flagged once");
    monitor.feed(500 * MS, &frame(0x721, &[0x05]));
    monitor.feed(600 * MS, &frame(0x701, &[0x05]));
    assert!(!monitor.nodes[&1].heartbeat_lost);
    assert_eq!(monitor.deadline(), Some(850 * MS));
    // Node 33, with no consumer time, is never judged.
    monitor.poll(5_000 * MS);
    assert!(!monitor.nodes[&33].heartbeat_lost);
    let lines: Vec<(Duration, &str)> = monitor
        .happenings
        .iter()
        .map(|(at, line)| (*at, line.as_str()))
        .collect();
    assert_eq!(
        lines,
        [
            (Duration::ZERO, "node 1: Operational"),
            (Duration::ZERO, "node 33: Operational"),
            (
                450 * MS,
                "node 1: heartbeat lost (none for its consumer time, 250 ms)"
            ),
            (600 * MS, "node 1: heartbeat back after 400.0 ms of silence"),
            (
                850 * MS,
                "node 1: heartbeat lost (none for its consumer time, 250 ms)"
            ),
        ]
    );
}

/// EMCYs in words: the SRDO and the cause from this device's manufacturer-specific bytes,
/// through `shared::safety::cause::Cause`, and the error register's bits.
#[test]
fn monitor_decodes_this_devices_emcy_into_words() {
    let cases = [
        (
            code::RPDO_TIMEOUT,
            [1, 0x01, 0, 0, 0],
            "SRDO 1: SCT elapsed",
        ),
        (
            code::PROTOCOL_ERROR,
            [2, 0x05, 0, 0, 0],
            "SRDO 2: not inverted",
        ),
        (
            code::APPLICATION_FAULT,
            [0, 0x33, 0, 0, 0],
            "channel cross-check: input discrepancy",
        ),
        (
            code::APPLICATION_FAULT,
            [0, 0x3B, 0, 0, 0],
            "channel cross-check: CAN controller bus-off",
        ),
        (
            code::APPLICATION_FAULT,
            [0, 0xE7, 0, 0, 0],
            "channel cross-check: cause E7h",
        ),
        (code::GLOBAL_FAIL_SAFE, [0; 5], "GFC received: safe state"),
        (
            code::DATA_SET,
            [0, 0xF0, 0, 0, 0],
            "stored parameters rejected: defaults in force, not validated",
        ),
        (
            code::DATA_SET,
            [0, 0xF1, 7, 0, 0],
            "configuration was validated for node-ID 7, not this one",
        ),
        (
            code::DATA_SET,
            [0, 0xF3, 0, 0, 0],
            "configuration in use damaged (identifier table)",
        ),
        (
            code::DATA_SET,
            [1, 24, 0, 0, 0],
            "SRDO 1: configuration refused at NMT start: the signature in 0x13FF does not match the configuration",
        ),
        (
            code::DATA_SET,
            [0, 23, 0, 0, 0],
            "configuration refused at NMT start: 0x13FE does not hold A5h: the configuration was not declared valid",
        ),
        (
            code::DATA_SET,
            [2, 11, 0, 0, 0],
            "SRDO 2: configuration refused at NMT start (reason 11)",
        ),
        (code::NO_ERROR, [0; 5], "error reset: no error"),
        (0x1234, [0; 5], "error code 1234h"),
    ];
    for (code, detail, words) in cases {
        let emergency = Emergency {
            code,
            register: 0x11,
            detail,
        };
        assert_eq!(describe_emergency(&emergency), words, "{code:04X}h");
    }
    assert_eq!(describe_register(0x11), "generic, communication");
    assert_eq!(describe_register(0), "no error");

    let mut monitor = Monitor::default();
    monitor.feed(MS, &frame(0x0A1, &[0x50, 0x82, 0x11, 1, 0x01, 0, 0, 0]));
    assert_eq!(
        monitor.nodes[&33].last_emergency.map(|(_, e)| e.code),
        Some(code::RPDO_TIMEOUT)
    );
    assert_eq!(
        monitor.happenings.back().unwrap().1,
        "node 33: EMCY 8250h: SRDO 1: SCT elapsed"
    );
}

/// CiA 301 7.2.4.3.17: an abort is decoded to object and code, with the code's meaning from
/// the tool's one table; requests and responses are counted per node.
#[test]
fn monitor_counts_sdo_traffic_and_decodes_aborts() {
    let mut monitor = Monitor::default();
    monitor.feed(MS, &frame(0x621, &[0x40, 0x18, 0x10, 1, 0, 0, 0, 0]));
    monitor.feed(
        2 * MS,
        &frame(0x5A1, &[0x43, 0x18, 0x10, 1, 0xBC, 0x0A, 0, 0]),
    );
    monitor.feed(3 * MS, &frame(0x621, &[0x2F, 0x01, 0x13, 3, 0, 0, 0, 0]));
    monitor.feed(
        4 * MS,
        &frame(0x5A1, &[0x80, 0x01, 0x13, 3, 0x22, 0, 0, 0x08]),
    );
    assert_eq!(monitor.sdo_totals(), (2, 2));
    let abort = monitor.aborts[0];
    assert_eq!((abort.node, abort.index, abort.sub), (33, 0x1301, 3));
    assert_eq!(abort.code, 0x0800_0022);
    assert_eq!(abort.meaning(), abort_meaning(0x0800_0022));
    assert!(
        abort
            .to_string()
            .starts_with("node 33: SDO 1301h:03h aborted by the node with 08000022h: "),
        "{abort}"
    );
}

/// A GFC (CAN-ID 001h, EN 50325-5 7.2.1) is counted and noted; a printer that has seen
/// some happenings gets only the newer ones, also after old ones were dropped.
#[test]
fn monitor_notes_gfc_and_hands_a_printer_only_new_happenings() {
    let mut monitor = Monitor::default();
    monitor.feed(MS, &frame(0x001, &[]));
    assert_eq!((monitor.gfcs, monitor.last_gfc), (1, Some(MS)));
    assert_eq!(monitor.happenings_since(0).count(), 1);
    assert_eq!(monitor.happenings_since(1).count(), 0);
    for n in 0..100 {
        monitor.feed(Duration::from_millis(n + 2), &frame(0x001, &[]));
    }
    assert_eq!(monitor.happenings.len(), HAPPENINGS);
    assert_eq!(monitor.happenings_since(99).count(), 2);
    assert_eq!(monitor.happenings_since(0).count(), HAPPENINGS);
}

mod properties {
    use super::*;
    use proptest::prelude::*;

    fn any_frame() -> impl Strategy<Value = CanFrame> {
        (0u16..0x800, proptest::collection::vec(any::<u8>(), 0..=8))
            .prop_map(|(id, data)| frame(id, &data))
    }

    proptest! {
        /// Any frames at any non-decreasing times: the model never panics, every judged
        /// pair is counted once, and histories and lists stay within their bounds.
        #[test]
        fn monitor_takes_any_bus_without_panic_and_within_its_bounds(
            frames in proptest::collection::vec((0u64..200_000, any_frame()), 0..400)
        ) {
            let mut monitor = watched();
            let mut now = Duration::ZERO;
            for (step, frame) in &frames {
                now += Duration::from_micros(*step);
                monitor.feed(now, frame);
            }
            monitor.poll(now + Duration::from_secs(1));
            prop_assert_eq!(monitor.frames, frames.len() as u64);
            for view in monitor.srdos.values() {
                prop_assert!(view.gaps.len() <= HISTORY && view.periods.len() <= HISTORY);
                prop_assert!(view.periods.len() <= view.gaps.len());
                // Every pair taken in gives one gap and one verdict besides those reached
                // without a pair (a missing inverted frame, a plain frame repeated).
                let without_pair =
                    view.count(PairVerdict::InvertedMissing) + view.count(PairVerdict::PlainRepeated);
                let pairs: u64 = view.verdicts.values().sum::<u64>() - without_pair;
                prop_assert!(pairs >= view.gaps.len() as u64);
                prop_assert!(view.watch.inverted == view.watch.plain + 1);
            }
            prop_assert!(monitor.emergencies.len() <= RECENT && monitor.aborts.len() <= RECENT);
            prop_assert!(monitor.happenings.len() <= HAPPENINGS);
            prop_assert_eq!(monitor.deadline(), None);
        }
    }
}
