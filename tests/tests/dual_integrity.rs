//! Integrity of the dual-channel layer, judged from outside (EN 50325-5 Annex A.4, Model III;
//! CiA 304 9.5): node 1 (emergency stop, SRDO producer) and node 33 (safe output, consumer) on
//! the simulated bus, each channel A and channel B with their link. The oracles read only what
//! an observer outside the nodes sees: the inputs the test sets, the frames on the bus and the
//! channels' outputs; none of them reuses the code under test.
//!
//! - a confirmation of an older pair never switches an output back on;
//! - channel B co-signs only the plain frame channel A announced and sent, and channel A checks
//!   that the inverted frame on the bus is the exact inverse of its own;
//! - a frame on a producer's identifiers that the producer did not send (inserted, replayed, a
//!   second sender) puts the producer in the safe state and its consumers too, within about a
//!   frame time (a GFC);
//! - the channels treat a short input difference alike whichever contact moved, and one
//!   channel's SRDO fault reaches the other at once.

use dual_channel::runtime::ChannelEvent;
use shared::canopen::nmt::{NmtCommand, NmtState};
use shared::node::Event;
use shared::{CanFrame, CanId, Duration, Instant};
use system_tests::bus::{Fault, Injection, Match};
use system_tests::dual::{DualNetwork, Side};

/// The producer's plain and inverted identifiers (node 1's predefined pair).
const PLAIN: u16 = 0x101;
const INVERTED: u16 = 0x102;
/// The consumers' SRVT in these networks (EN 50325-5 Table 5 default).
const SRVT: Duration = Duration::from_millis(20);
/// The largest one-way link latency the link supervision accepts: a verdict not matched
/// within two link periods (20 ms) is a fault; its message takes about 0.2 ms on the wire.
const LARGEST_LATENCY: Duration = Duration::from_micros(19_500);

fn running() -> DualNetwork {
    let mut net = DualNetwork::new(500_000, &[1, 33]);
    net.configure_and_start().expect("configuration accepted");
    net.run_for(Duration::from_millis(200));
    net
}

fn frame(id: u16, data: &[u8]) -> CanFrame {
    CanFrame::new(CanId::new(id).expect("identifier"), data).expect("data")
}

fn us(micros: u64) -> Duration {
    Duration::from_micros(micros)
}

/// The complete pairs of node 1 on the bus, as an observer sees them: a plain frame followed
/// by the next frame on the inverted identifier carrying its exact inverse. (time the pair
/// completed, plain data, time the plain frame ended).
fn pairs_on_bus(net: &DualNetwork) -> Vec<(Instant, u64, Instant)> {
    let mut pairs = Vec::new();
    let mut plain: Option<(Instant, CanFrame)> = None;
    for (at, frame, _) in &net.trace {
        match frame.id().raw() {
            PLAIN => plain = Some((*at, *frame)),
            INVERTED => {
                if let Some((plain_at, first)) = plain.take() {
                    let inverse = first.data().len() == frame.data().len()
                        && first
                            .data()
                            .iter()
                            .zip(frame.data())
                            .all(|(p, i)| *p == !*i);
                    if inverse {
                        let mut bytes = [0u8; 8];
                        bytes[..first.data().len()].copy_from_slice(first.data());
                        pairs.push((*at, u64::from_le_bytes(bytes), plain_at));
                    }
                }
            }
            _ => {}
        }
    }
    pairs
}

/// The value channel `side` of node `id` drove on its output at `at` (after everything that
/// happened at `at`).
fn output_at(net: &DualNetwork, id: u8, side: Side, at: Instant) -> u64 {
    net.outputs
        .iter()
        .rev()
        .find(|(t, node, s, srdo, _)| *node == id && *s == side && *srdo == 1 && *t <= at)
        .map_or(0, |(.., value)| *value)
}

/// The oracle of the stale-confirmation defect: at no instant does a channel of node 33 drive
/// a bit its newest complete pair on the bus does not carry (in particular, nothing once the
/// emergency-stop pair is on the bus). Returns how often an output left 0 (so a test can
/// show that the outputs did follow the releases).
fn assert_never_driven_on_stale_data(net: &DualNetwork, context: &str) -> usize {
    let pairs = pairs_on_bus(net);
    let newest = |at: Instant| {
        pairs
            .iter()
            .rev()
            .find(|(t, ..)| *t <= at)
            .map_or(0, |(_, data, _)| *data)
    };
    let mut raised = 0;
    for side in [Side::A, Side::B] {
        let changes = net
            .outputs
            .iter()
            .filter(|(_, node, s, srdo, _)| *node == 33 && *s == side && *srdo == 1)
            .map(|(t, ..)| *t);
        let instants: Vec<Instant> = changes.chain(pairs.iter().map(|(t, ..)| *t)).collect();
        for at in instants {
            let driven = output_at(net, 33, side, at);
            assert_eq!(
                driven & !newest(at),
                0,
                "{context}: channel {side:?} of node 33 drives {driven:#x} at {at:?}, \
                 the newest pair on the bus carries {:#x}",
                newest(at)
            );
        }
        raised += net
            .outputs
            .iter()
            .filter(|(_, node, s, srdo, value)| {
                *node == 33 && *s == side && *srdo == 1 && *value != 0
            })
            .count();
    }
    raised
}

fn faulted(net: &DualNetwork, id: u8, since: usize) -> Vec<(Instant, Side, ChannelEvent)> {
    net.log[since..]
        .iter()
        .filter(|(_, node, _, e)| *node == id && matches!(e, ChannelEvent::Fault(_)))
        .map(|(at, _, side, e)| (*at, *side, *e))
        .collect()
}

/// EN 50325-5 7.1.2, SC_REQ_05: an output leaves 0 only on a confirmation of the newest pair
/// each channel accepted. Releases followed by an emergency stop at every spacing from 50 µs
/// to 25 ms, with node 33's link latency swept across everything the link supervision
/// accepts (0 to 19.5 ms): no channel ever drives its output on data older than the newest
/// pair on the bus, i.e. never re-energises it after the emergency-stop pair turned it off.
#[test]
fn en50325_5_7_1_2_a_stale_confirmation_never_re_energises_an_output() {
    let spacings_us = [
        50u64, 100, 150, 200, 300, 400, 500, 800, 1_000, 1_500, 2_000, 3_000, 5_000, 8_000, 12_000,
        16_000, 20_000, 25_000,
    ];
    let mut latencies: Vec<u64> = (0..=19).map(|ms| ms * 1_000).collect();
    latencies.extend([250, 500, 750, LARGEST_LATENCY.as_micros()]);
    for latency in latencies {
        let mut net = running();
        net.node_mut(33).link_faults.latency = us(latency);
        net.set_inputs(1, 0, 0);
        net.run_for(Duration::from_millis(100));
        let since = net.log.len();
        for spacing in spacings_us {
            net.set_inputs(1, 1, 1);
            net.run_for(us(spacing));
            net.set_inputs(1, 0, 0);
            net.run_for(Duration::from_millis(80));
            assert_eq!(net.output(33), 0, "pressed, latency {latency} µs");
        }
        let context = format!("link latency {latency} µs");
        let raised = assert_never_driven_on_stale_data(&net, &context);
        assert_eq!(
            faulted(&net, 33, since),
            vec![],
            "{context}: within what the link supervision accepts"
        );
        assert!(raised > 0, "{context}: the outputs followed the releases");
    }
}

/// CiA 304 9.5: channel B co-signs only a plain frame channel A announced. Around a release
/// whose channel B contact closed first, a device inserts the plain frame of "released"
/// (equal to B's sample, not A's): no valid pair with that data may reach node 33 while A's
/// contact is open, and node 1 takes the network safe.
#[test]
fn cia304_9_5_an_inserted_plain_frame_is_never_co_signed() {
    let mut net = running();
    net.set_inputs(1, 0, 0);
    net.run_for(Duration::from_millis(100));
    assert_eq!(net.output(33), 0);
    let since = net.log.len();
    net.set_input(1, Side::B, 1);
    net.run_for(Duration::from_millis(1));
    let inserted = net.now;
    net.send_foreign(frame(PLAIN, &[0x01]));
    net.run_for(Duration::from_millis(100));
    // Channel A's contact never closed: nothing may drive node 33's output.
    assert!(
        net.outputs
            .iter()
            .all(|(t, node, _, _, value)| *t < inserted || *node != 33 || *value == 0),
        "node 33's output came on while node 1's channel A contact was open"
    );
    assert!(!faulted(&net, 1, since).is_empty(), "node 1 reports it");
    assert_consumer_safe_within(&net, 33, inserted, Duration::from_millis(1));
}

/// CiA 304 9.5: channel A's plain frame corrupted on the bus in a way the CAN CRC misses, into
/// what channel B's sample reads (B's contact closed first on a release): B does not co-sign
/// what A did not send, so node 33's output stays off until A's contact closes.
#[test]
fn cia304_9_5_a_corrupted_plain_frame_is_never_co_signed() {
    let mut net = running();
    net.set_inputs(1, 0, 0);
    net.run_for(Duration::from_millis(100));
    net.set_input(1, Side::B, 1);
    let changed = net.now;
    net.inject(
        Match::next_with_id(PLAIN, changed),
        Fault::Corrupt {
            byte: 0,
            mask: 0x01,
        },
    );
    net.run_for(Duration::from_millis(100));
    assert!(
        net.outputs
            .iter()
            .all(|(t, node, _, _, value)| *t < changed || *node != 33 || *value == 0),
        "node 33's output came on while node 1's channel A contact was open"
    );
    assert_eq!(net.output(33), 0);
}

/// CiA 304 9.5, EN 50325-5 7.1.1: channel A checks that the inverted frame on the bus is the
/// exact inverse of its own plain frame: a corrupted inverted frame is reported by node 1
/// at once, not left to the consumers.
#[test]
fn cia304_9_5_a_checks_the_inverted_frame_is_the_inverse_of_its_plain_frame() {
    let mut net = running();
    let since = net.log.len();
    let from = net.now;
    net.inject(
        Match::next_with_id(INVERTED, from),
        Fault::Corrupt {
            byte: 0,
            mask: 0x10,
        },
    );
    net.run_for(Duration::from_millis(60));
    let corrupted_at = net
        .trace
        .iter()
        .find(|(at, frame, _)| *at >= from && frame.id().raw() == INVERTED)
        .map(|(at, ..)| *at)
        .expect("an inverted frame");
    let faults = faulted(&net, 1, since);
    let first_a = faults.iter().find(|(_, side, _)| *side == Side::A);
    let (at, ..) = first_a.expect("channel A of node 1 reports the wrong inverted frame");
    assert_eq!(*at, corrupted_at, "at once: {faults:?}");
    assert_eq!(net.output(33), 0);
}

/// CiA 304 9.5: what channel B's co-signing costs. The plain-to-inverted gap (end of the
/// plain frame to end of the inverted frame on the bus) with channel A announcing each plain
/// frame over the link, nominal and up to the link latency the producer's link latency
/// supervision accepts (a round trip under `dual_channel::link::round_trip_bound` of the
/// window: 1.25 ms each way; `tests/tests/link_latency.rs` sweeps the range): well under the
/// SRVT.
#[test]
fn cia304_9_5_the_plain_to_inverted_gap_stays_well_under_the_srvt() {
    for latency in [0u64, 1_000, 1_250] {
        let mut net = running();
        net.node_mut(1).link_faults.latency = us(latency);
        let from = net.now;
        for round in 0..20u64 {
            net.set_inputs(1, (round % 2) as u8, (round % 2) as u8);
            net.run_for(Duration::from_micros(7_300 + 500 * round));
        }
        net.run_for(Duration::from_millis(100));
        let gaps: Vec<u64> = pairs_on_bus(&net)
            .iter()
            .filter(|(at, ..)| *at > from)
            .map(|(at, _, plain_at)| at.saturating_since(*plain_at).as_micros())
            .collect();
        assert!(gaps.len() > 20, "pairs: {}", gaps.len());
        let longest = *gaps.iter().max().expect("gaps");
        let mean = gaps.iter().sum::<u64>() / gaps.len() as u64;
        eprintln!(
            "link latency {latency} µs: plain-to-inverted gap mean {mean} µs, longest {longest} µs over {} pairs",
            gaps.len()
        );
        assert!(
            faulted(&net, 1, 0).is_empty() && faulted(&net, 33, 0).is_empty(),
            "latency {latency} µs"
        );
        assert!(
            longest * 4 <= SRVT.as_micros(),
            "gap {longest} µs at latency {latency} µs"
        );
    }
}

/// Checks that both channels of consumer `id` are in the safe state (core latched, outputs 0)
/// at most `bound` after `from`.
fn assert_consumer_safe_within(net: &DualNetwork, id: u8, from: Instant, bound: Duration) {
    for side in [Side::A, Side::B] {
        let safe = net
            .first_event(0, id, |s, e| {
                s == side && matches!(e, ChannelEvent::Node(Event::SafeState(_)))
            })
            .filter(|(at, ..)| *at >= from);
        let (at, ..) = safe.unwrap_or_else(|| {
            panic!(
                "channel {side:?} of node {id} never went safe: {:?}",
                net.log
            )
        });
        let after = at.saturating_since(from);
        eprintln!(
            "channel {side:?} of node {id} safe {} µs after the foreign frame",
            after.as_micros()
        );
        assert!(
            after <= bound,
            "channel {side:?} of node {id} safe {after:?} after the foreign frame"
        );
        assert_eq!(output_at(net, id, side, at), 0);
    }
    let node = net.node(id);
    assert!(!node.a.is_working() && !node.b.is_working());
}

/// The EMCY of node 1 naming identifier `id` (FF02h, cause 34h: a frame on the node's own
/// transmit identifier that it did not send; bytes 5..=6 the identifier).
fn emcy_names(net: &DualNetwork, id: u16) -> bool {
    net.trace.iter().any(|(_, frame, _)| {
        let data = frame.data();
        frame.id().raw() == 0x081
            && data.len() == 8
            && data[..2] == [0x02, 0xFF]
            && data[4] == 0x34
            && data[5..7] == id.to_le_bytes()
    })
}

/// Runs a foreign-frame scenario after the emergency stop was pressed; `foreign` sends the
/// foreign frames. Returns the network and when the first foreign frame ended on the bus.
fn after_a_press_with(foreign: impl FnOnce(&mut DualNetwork)) -> (DualNetwork, Instant) {
    let mut net = running();
    net.set_inputs(1, 0, 0);
    net.run_for(Duration::from_millis(60));
    assert_eq!(net.output(33), 0);
    let from = net.now;
    foreign(&mut net);
    net.run_for(Duration::from_millis(100));
    let first = net
        .trace
        .iter()
        .find(|(at, _, sender)| *at >= from && *sender == 0)
        .map(|(at, ..)| *at)
        .expect("the foreign frame went on the bus");
    (net, first)
}

/// EN 50325-5 7.2.1 (GFC), SC_REQ_05: a device replays an earlier valid pair of node 1
/// ("released") after the emergency stop was pressed. Node 1's channels see a frame on its
/// identifiers it did not send: node 1 goes to the safe state with an EMCY naming the
/// identifier, and node 33 is safe within about a frame time (1 ms at 500 kbit/s) instead of
/// running on the replayed data until SCT.
#[test]
fn en50325_5_7_2_1_a_replayed_pair_takes_the_consumers_safe_within_a_frame_time() {
    let (net, first) = after_a_press_with(|net| {
        net.send_foreign(frame(PLAIN, &[0x01]));
        net.send_foreign(frame(INVERTED, &[0xFE]));
    });
    assert_consumer_safe_within(&net, 33, first, Duration::from_millis(1));
    assert!(
        net.outputs
            .iter()
            .all(|(t, node, _, _, value)| *t < first || *node != 33 || *value == 0),
        "the replayed pair drove node 33's output"
    );
    assert!(emcy_names(&net, PLAIN), "EMCY naming 101h");
    assert!(!net.node(1).a.is_working() && !net.node(1).b.is_working());
}

/// EN 50325-5 7.2.1: a single frame inserted on node 1's inverted identifier (channel B's,
/// seen by channel B only as foreign): node 1 and node 33 safe within about a frame time.
#[test]
fn en50325_5_7_2_1_an_inserted_inverted_frame_takes_the_consumers_safe() {
    let (net, first) = after_a_press_with(|net| net.send_foreign(frame(INVERTED, &[0xFE])));
    assert_consumer_safe_within(&net, 33, first, Duration::from_millis(1));
    assert!(emcy_names(&net, INVERTED), "EMCY naming 102h");
}

/// EN 50325-5 7.2.1: a second sender on node 1's identifiers (a misconfigured device sending
/// its own pairs every 10 ms): caught at its first frame.
#[test]
fn en50325_5_7_2_1_a_second_sender_takes_the_consumers_safe() {
    let (net, first) = after_a_press_with(|net| {
        for _ in 0..5 {
            net.send_foreign(frame(PLAIN, &[0x01]));
            net.send_foreign(frame(INVERTED, &[0xFE]));
            net.run_for(Duration::from_millis(10));
        }
    });
    assert_consumer_safe_within(&net, 33, first, Duration::from_millis(1));
    assert!(emcy_names(&net, PLAIN));
    assert_eq!(net.node(33).a.node().nmt_state(), NmtState::Operational);
}

/// ISO 11898-1 double reception (a frame whose last EOF bit was disturbed is sent again and
/// received twice): a copy of the node's own frame is not a foreign frame.
#[test]
fn cia304_9_5_a_frame_received_twice_is_not_a_foreign_frame() {
    let mut net = running();
    let since = net.log.len();
    for id in [PLAIN, INVERTED] {
        net.inject(Match::next_with_id(id, net.now), Fault::Repeat);
        net.run_for(Duration::from_millis(60));
    }
    assert_eq!(faulted(&net, 1, since), vec![]);
    let node = net.node(1);
    assert!(node.a.is_working() && node.b.is_working());
}

/// CiA 304 9.5: a short input difference (under the 5 ms window) is tolerated alike whichever
/// channel's contact moved alone; a lasting one trips the node alike.
#[test]
fn cia304_9_5_a_short_input_difference_is_treated_alike_on_either_channel() {
    for side in [Side::A, Side::B] {
        for blip_us in [300u64, 1_000, 2_000, 4_000] {
            for offset_us in [0u64, 3_000, 11_000, 24_000] {
                let mut net = running();
                net.run_for(us(offset_us));
                let since = net.log.len();
                net.set_input(1, side, 0);
                net.run_for(us(blip_us));
                net.set_input(1, side, 1);
                net.run_for(Duration::from_millis(100));
                let context = format!("{side:?} alone for {blip_us} µs at +{offset_us} µs");
                assert_eq!(faulted(&net, 1, since), vec![], "{context}");
                assert_eq!(faulted(&net, 33, since), vec![], "{context}");
                assert_eq!(net.output(33), 1, "{context}");
            }
        }
        // A lasting difference on the same contact trips the node.
        let mut net = running();
        let since = net.log.len();
        net.set_input(1, side, 0);
        net.run_for(Duration::from_millis(60));
        assert!(!faulted(&net, 1, since).is_empty(), "{side:?} lasting");
        assert_eq!(net.output(33), 0, "{side:?} lasting");
    }
}

/// CiA 304 9.5: one channel's core finds an SRDO fault the other cannot see (a corrupted
/// inverted frame in channel A's receive path only): the other channel is told over the link
/// and latches at once, not through the 20 ms verdict time-out.
#[test]
fn cia304_9_5_one_channels_srdo_fault_reaches_the_other_at_once() {
    for faulty in [Side::A, Side::B] {
        let mut net = running();
        let since = net.log.len();
        let now = net.now;
        net.node_mut(33).receive_faults.push((
            faulty,
            Injection::new(
                Match::next_with_id(INVERTED, now),
                Fault::Corrupt {
                    byte: 0,
                    mask: 0x04,
                },
            ),
        ));
        net.run_for(Duration::from_millis(60));
        let (found, ..) = net
            .first_event(since, 33, |s, e| {
                s == faulty && matches!(e, ChannelEvent::Node(Event::SafeState(_)))
            })
            .expect("the faulty channel's core goes safe");
        let other = if faulty == Side::A { Side::B } else { Side::A };
        let (told, ..) = net
            .first_event(since, 33, |s, e| {
                s == other && matches!(e, ChannelEvent::Fault(_))
            })
            .expect("the other channel latches");
        let after = told.saturating_since(found);
        assert!(
            after <= Duration::from_millis(1),
            "{faulty:?} faulty: the other channel latched {after:?} later"
        );
        assert_eq!(net.output(33), 0);
    }
}

/// CiA 304 9.5: an SRDO fault both channels' cores find (both see the same bus) is reported by
/// each as its own cause; the other channel's safe-state message adds nothing (the status
/// report and the emulated network's checks read the cause).
#[test]
fn cia304_9_5_a_fault_both_channels_found_keeps_each_channels_own_cause() {
    let mut net = running();
    let since = net.log.len();
    net.inject(
        Match::next_with_id(INVERTED, net.now),
        Fault::Corrupt {
            byte: 0,
            mask: 0x04,
        },
    );
    net.run_for(Duration::from_millis(60));
    for side in [Side::A, Side::B] {
        assert!(
            net.first_event(since, 33, |s, e| {
                s == side && matches!(e, ChannelEvent::Node(Event::SafeState(_)))
            })
            .is_some(),
            "channel {side:?} of node 33 found the fault"
        );
    }
    assert_eq!(
        faulted(&net, 33, since),
        vec![],
        "no cause but each core's own"
    );
    assert_eq!(net.output(33), 0);
}

/// CiA 304 9.5 with NMT reset (CiA 301 7.3.2): channel B may take longer than channel A to
/// handle an NMT frame both received at the same instant (each runs its own loop), so channel
/// A's announcement of its first plain frame after a reset and start can reach B before B has
/// itself been reset. B keeps that announcement (it states what A sends, whatever A's reset
/// count) and co-signs the frame: no foreign frame, no fault, the node works. Checked with B's
/// NMT frames held back by 1 to 8 ms, inside the two link periods the NMT cross-check allows.
#[test]
fn cia304_9_5_an_announcement_that_overtakes_channel_bs_nmt_reset_is_kept() {
    for lag_ms in [1u64, 2, 4, 8] {
        let mut net = running();
        let since = net.log.len();
        let now = net.now;
        net.node_mut(1).receive_faults.push((
            Side::B,
            Injection::new(
                Match {
                    id: Some(0x000),
                    from: None,
                    after: now,
                    count: None,
                },
                Fault::Delay(Duration::from_millis(lag_ms)),
            ),
        ));
        net.nmt(NmtCommand::ResetNode, 0);
        // The tool starts the nodes as soon as node 1 (channel A) has announced itself.
        let boot_up = loop {
            if let Some((at, ..)) = net.first_event(since, 1, |side, event| {
                side == Side::A
                    && matches!(
                        event,
                        ChannelEvent::Node(Event::NmtState(NmtState::PreOperational))
                    )
            }) {
                break at;
            }
            assert!(
                net.now < now + Duration::from_millis(500),
                "node 1 never booted"
            );
            net.run_for(us(100));
        };
        assert!(
            boot_up < now + Duration::from_millis(lag_ms),
            "A booted before B reset"
        );
        net.nmt(NmtCommand::Start, 0);
        net.run_for(Duration::from_millis(300));
        let faults = faulted(&net, 1, since);
        assert!(
            faults.is_empty(),
            "lag {lag_ms} ms: node 1 faulted: {faults:?}"
        );
        let node = net.node(1);
        assert!(
            node.a.is_working() && node.b.is_working(),
            "lag {lag_ms} ms: node 1 not working"
        );
        assert!(
            net.node(33).a.is_working(),
            "lag {lag_ms} ms: node 33 not working"
        );
    }
}

/// EN 50325-5 7.2.1, CiA 304 9.5; the manual's residual risks: a foreign frame on node 1's
/// inverted identifier, queued while node 1's plain frame is on the bus and longer than it
/// with its first byte the exact inverse (CiA 304 compares the first n bytes), completes that
/// pair at the consumer before channel B's own inverted frame. The window is accepted, and
/// bounded: the value the consumer can take is node 1's own plain data (channel A's frame,
/// announced to channel B), and node 1's channel A sees at the foreign frame's end that it is
/// not the inverse of its plain frame and sends the GFC at once, which takes node 33 safe
/// within one frame of blocking and the GFC's own frame (processing takes no simulated time
/// here; the manual adds the producer's and the consumer's steps).
#[test]
fn en50325_5_7_2_1_a_foreign_inverted_frame_completing_a_plain_frame_ends_within_the_gfc_bound() {
    use safety_config::calc::bus::frame_micros;
    let mut net = running();
    net.set_inputs(1, 0, 0);
    net.run_for(Duration::from_millis(60));
    assert_eq!(net.output(33), 0);
    net.set_inputs(1, 1, 1);
    let plain = loop {
        if let Some((_, plain, _)) = net
            .on_the_bus()
            .find(|(_, frame, sender)| frame.id().raw() == PLAIN && *sender != 0)
        {
            break plain;
        }
        net.run_for(us(5));
    };
    let mut data = [0x55u8; 8];
    data[0] = !plain.data()[0];
    net.send_foreign(frame(INVERTED, &data));
    net.run_for(Duration::from_millis(20));
    let (foreign_end, ..) = *net
        .trace
        .iter()
        .find(|(_, frame, sender)| *sender == 0 && frame.id().raw() == INVERTED)
        .expect("the foreign frame went on the bus");
    // The foreign frame was the pair's second half: it followed the plain frame at once.
    let (plain_end, ..) = *net
        .trace
        .iter()
        .rev()
        .find(|(at, frame, _)| *at < foreign_end && frame.id().raw() == PLAIN)
        .expect("the plain frame before it");
    let between = net
        .trace
        .iter()
        .filter(|(at, ..)| *at > plain_end && *at < foreign_end)
        .count();
    assert_eq!(
        between, 0,
        "nothing between the plain frame and the foreign one"
    );
    // A frame that started meanwhile (CAN does not preempt), then the GFC itself.
    let bound = us(frame_micros(8, 500_000) + frame_micros(0, 500_000));
    let mut safe_at = Instant::ZERO;
    for side in [Side::A, Side::B] {
        let (at, ..) = net
            .first_event(0, 33, |s, e| {
                s == side && matches!(e, ChannelEvent::Node(Event::SafeState(_)))
            })
            .expect("node 33 went safe");
        let after = at.saturating_since(foreign_end);
        eprintln!(
            "node 33 channel {side:?} safe {} µs after the foreign frame",
            after.as_micros()
        );
        assert!(
            after <= bound,
            "channel {side:?} safe {after:?} after the foreign frame, over {bound:?}"
        );
        safe_at = safe_at.max(at);
    }
    // Until then node 33 drove nothing but 0 or node 1's own plain data.
    for (at, _, side, _, value) in net
        .outputs
        .iter()
        .filter(|(at, node, ..)| *node == 33 && *at >= foreign_end)
    {
        assert!(
            *value == 0 || *value == u64::from(plain.data()[0]),
            "channel {side:?} of node 33 drove {value:#x} at {at:?}, not node 1's data"
        );
    }
    let gfc = net
        .trace
        .iter()
        .find(|(at, frame, _)| *at >= foreign_end && frame.id().raw() == 0x001);
    assert!(
        gfc.is_some_and(|(at, ..)| *at <= safe_at),
        "the GFC took node 33 safe"
    );
}
