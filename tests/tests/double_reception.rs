//! CAN double reception on the simulated bus (ISO 11898-1: a receiver may accept a frame that
//! its transmitter repeats after an error in the last bit of the end-of-frame field) and a
//! consumer that starts monitoring at any instant of a running producer (EN 50325-5 7.1.2;
//! CiA 304 9.5). Node 1 produces SRDO 1 on 0x101/0x102, node 33 consumes it; single-channel
//! devices first, then the dual-channel nodes, whose two channels must still agree.
//!
//! The safety rule stays: nothing that is not a valid, timely pair is ever delivered, and
//! nothing is delivered twice.

use dual_channel::runtime::ChannelEvent;
use shared::canopen::nmt::{self, NmtCommand, NmtState};
use shared::canopen::od::Address;
use shared::node::Event;
use shared::{Duration, Instant};
use system_tests::bus::{Fault, Match, frame_time};
use system_tests::dual::{DualNetwork, Side};
use system_tests::network::{Happening, Network};

const BIT_RATE: u32 = 500_000;
/// Node 1's refresh time (the pre-defined connection set, EN 50325-5 Table 5).
const PERIOD: u64 = 25_000;
const PRODUCER: usize = 0;
const CONSUMER: usize = 1;

/// Node 1 configured, validated and Operational; node 33 configured and validated for 0x101/
/// 0x102 but left in Pre-operational.
fn producer_running() -> Network {
    let mut net = Network::new(BIT_RATE, &[(1, "producer 1"), (33, "consumer 33")]);
    net.run_for(Duration::from_millis(10));
    let write = |net: &mut Network, sub, data: &[u8]| {
        net.write(33, Address::new(0x1301, sub), data)
            .expect("configuration accepted");
    };
    write(&mut net, 1, &[0]);
    write(&mut net, 5, &0x101u32.to_le_bytes());
    write(&mut net, 6, &0x102u32.to_le_bytes());
    write(&mut net, 1, &[2]);
    for id in [1, 33] {
        net.sign_and_validate(id, &[1]).expect("validated");
    }
    net.set_input(PRODUCER, 1);
    net.nmt(NmtCommand::Start, 1);
    net.run_for(Duration::from_millis(100));
    net
}

/// The instant `micros` µs after power-on.
const fn us(micros: u64) -> Instant {
    Instant::from_micros(micros)
}

/// How long `frame` is on the bus, in µs.
fn bus_time(frame: &shared::CanFrame) -> u64 {
    frame_time(frame, BIT_RATE).as_micros()
}

fn faults_of(net: &Network, device: usize, since: usize) -> Vec<String> {
    net.log[since..]
        .iter()
        .filter(|(_, d, h)| {
            *d == Some(device)
                && matches!(
                    h,
                    Happening::Event(Event::SrdoFault(_) | Event::SafeState(_))
                )
        })
        .map(|(at, _, h)| format!("{at:?} {h:?}"))
        .collect()
}

/// EN 50325-5 7.1.2, CiA 304 9.5: node 33 starts monitoring (NMT start queued) at a grid of
/// instants across one period of node 1's SRDO, and at every microsecond from before the
/// plain frame to after its inverted frame: it always reaches its working state and
/// delivers, and never faults.
#[test]
fn en50325_5_7_1_2_a_consumer_started_at_any_instant_of_a_running_producer_works() {
    let reference = producer_running();
    // The start of node 1's last plain frame (delivery end minus its time on the bus).
    let (plain_end, plain_start) = reference
        .trace
        .iter()
        .rev()
        .find(|(_, frame)| frame.id().raw() == 0x101)
        .map(|(end, frame)| (end.as_micros(), end.as_micros() - bus_time(frame)))
        .expect("node 1 produces");
    let inverted_end = reference
        .trace
        .iter()
        .find(|(end, frame)| frame.id().raw() == 0x102 && end.as_micros() > plain_end)
        .map(|(end, _)| end.as_micros())
        .expect("its inverted frame");
    let nmt_time = bus_time(&nmt::command_frame(NmtCommand::Start, 33));
    // Two cycles later the plain frame starts two periods later (cyclic, phase kept).
    let first = plain_start + 2 * PERIOD;
    let window = (first - nmt_time - 2)..=(first + (inverted_end - plain_start) + 2);
    let instants: Vec<Instant> = (0..PERIOD)
        .step_by(500)
        .map(|offset| first - PERIOD / 2 + offset)
        .chain(window)
        .map(us)
        .collect();

    let mut lone_inverted_seen = 0;
    for queued_at in instants {
        let mut net = producer_running();
        net.run_until(queued_at);
        let since = net.log.len();
        net.bus.send(0, nmt::command_frame(NmtCommand::Start, 33));
        net.run_for(Duration::from_millis(300));
        let consumer = &net.devices[CONSUMER];
        assert_eq!(net.state(CONSUMER), NmtState::Operational, "{queued_at:?}");
        assert!(
            consumer.node.is_working(),
            "NMT start queued at {queued_at:?}: {:?}",
            faults_of(&net, CONSUMER, since)
        );
        assert!(consumer.pairs_received >= 10, "{queued_at:?}");
        assert_eq!(net.output(CONSUMER), 1, "{queued_at:?}");
        let discarded = consumer.node.double_reception();
        assert_eq!(discarded.plain_repeated, 0, "{queued_at:?}");
        lone_inverted_seen += discarded.inverted_without_plain;
    }
    assert!(
        lone_inverted_seen > 0,
        "the grid reached the instants between a plain and its inverted frame"
    );
}

/// A running pair: node 1 producing, node 33 Operational and working.
fn both_running() -> Network {
    let mut net = producer_running();
    net.nmt(NmtCommand::Start, 33);
    net.run_for(Duration::from_millis(100));
    assert!(net.devices[CONSUMER].node.is_working());
    net
}

/// ISO 11898-1 double reception on the bus: every plain frame, every inverted frame, or
/// every SRDO frame delivered twice. Node 33 never faults, delivers every pair exactly once,
/// and counts each copy it discarded.
#[test]
fn iso11898_1_duplicated_frames_on_the_bus_never_fault_and_never_deliver_twice() {
    for repeated in [&[0x101u16][..], &[0x102], &[0x101, 0x102]] {
        let mut net = both_running();
        let since = net.log.len();
        let pairs_before = net.devices[CONSUMER].pairs_received;
        let trace_before = net.trace.len();
        let after = net.now;
        for &id in repeated {
            net.inject(
                Match {
                    id: Some(id),
                    from: None,
                    after,
                    count: None,
                },
                Fault::Repeat,
            );
        }
        net.run_for(Duration::from_millis(500));
        assert!(
            faults_of(&net, CONSUMER, since).is_empty(),
            "{repeated:x?}: {:?}",
            faults_of(&net, CONSUMER, since)
        );
        assert!(net.devices[CONSUMER].node.is_working(), "{repeated:x?}");
        let count = |id: u16| {
            net.trace[trace_before..]
                .iter()
                .filter(|(_, frame)| frame.id().raw() == id)
                .count() as u64
        };
        let copies = |id: u16| if repeated.contains(&id) { 2 } else { 1 };
        let pairs_on_bus = count(0x102) / copies(0x102);
        assert_eq!(count(0x101) / copies(0x101), pairs_on_bus);
        assert!(pairs_on_bus >= 19, "{repeated:x?}: {pairs_on_bus}");
        let delivered = net.devices[CONSUMER].pairs_received - pairs_before;
        // A pair whose frames straddle the end of the run may still be on its way.
        assert!(
            delivered == pairs_on_bus || delivered + 1 == pairs_on_bus,
            "{repeated:x?}: each pair once: {delivered} of {pairs_on_bus}"
        );
        let discarded = net.devices[CONSUMER].node.double_reception();
        let expected = |id: u16| {
            if repeated.contains(&id) {
                u32::try_from(count(id) / 2).unwrap()
            } else {
                0
            }
        };
        assert_eq!(
            (discarded.plain_repeated, discarded.inverted_without_plain),
            (expected(0x101), expected(0x102)),
            "{repeated:x?}: every copy counted"
        );
        assert_eq!(net.output(CONSUMER), 1);
    }
}

/// The copy of a plain frame discarded, the inverted frame lost: SRVT still fires (EN 50325-5
/// 7.1.2), from the first copy.
#[test]
fn en50325_5_7_1_2_a_repeated_plain_frame_without_its_inverted_frame_still_trips_srvt() {
    let mut net = both_running();
    let since = net.log.len();
    let after = net.now;
    net.inject(Match::next_with_id(0x101, after), Fault::Repeat);
    net.inject(Match::next_with_id(0x102, after), Fault::Drop);
    net.run_for(Duration::from_millis(100));
    let faults = faults_of(&net, CONSUMER, since);
    assert!(
        faults.first().is_some_and(|f| f.contains("SrvtElapsed")),
        "{faults:?}"
    );
    assert_eq!(net.output(CONSUMER), 0);
}

// ---- Dual-channel nodes -------------------------------------------------------------------

fn dual_running() -> DualNetwork {
    let mut net = DualNetwork::new(BIT_RATE, &[1, 33]);
    net.configure_and_start().expect("configuration accepted");
    net.run_for(Duration::from_millis(200));
    net
}

/// The last frame on `id` in the dual network's bus trace: when it started and ended (µs).
fn last_on_bus(net: &DualNetwork, id: u16) -> (u64, u64) {
    net.trace
        .iter()
        .rev()
        .find(|(_, frame, _)| frame.id().raw() == id)
        .map(|(end, frame, _)| (end.as_micros() - bus_time(frame), end.as_micros()))
        .unwrap_or_else(|| panic!("no frame on {id:03X}h in the dual network's trace"))
}

fn channel_faults(net: &DualNetwork, since: usize) -> Vec<String> {
    net.log[since..]
        .iter()
        .filter(|(_, _, _, e)| {
            matches!(
                e,
                ChannelEvent::Fault(_) | ChannelEvent::Node(Event::SrdoFault(_))
            )
        })
        .map(|(at, id, side, e)| format!("{at:?} node {id} {side:?} {e:?}"))
        .collect()
}

fn assert_all_working(net: &DualNetwork, what: &str) {
    for id in [1u8, 33] {
        let node = net.node(id);
        assert!(
            node.a.is_working() && node.b.is_working(),
            "{what}: node {id}: {:?}",
            channel_faults(net, 0)
        );
    }
}

/// ISO 11898-1 double reception with dual-channel nodes (EN 50325-5 Annex A.4, Model III):
/// SRDO frames delivered twice on the bus trip neither channel of either node; both channels
/// of node 33 confirm the same pairs (their verdicts agree), count the same discards, and
/// the output stays 1.
#[test]
fn iso11898_1_dual_channel_nodes_agree_on_duplicated_frames() {
    for repeated in [&[0x101u16][..], &[0x102], &[0x101, 0x102]] {
        let mut net = dual_running();
        assert_all_working(&net, "before");
        let since = net.log.len();
        let after = net.now;
        for &id in repeated {
            net.inject(
                Match {
                    id: Some(id),
                    from: None,
                    after,
                    count: None,
                },
                Fault::Repeat,
            );
        }
        net.run_for(Duration::from_millis(500));
        assert!(
            channel_faults(&net, since).is_empty(),
            "{repeated:x?}: {:?}",
            channel_faults(&net, since)
        );
        assert_all_working(&net, &format!("{repeated:x?}"));
        assert_eq!(net.output(33), 1, "{repeated:x?}");
        let confirmed = |side: Side| {
            net.log[since..]
                .iter()
                .filter(|(_, id, s, e)| {
                    *id == 33 && *s == side && matches!(e, ChannelEvent::Confirmed { .. })
                })
                .count()
        };
        let (a, b) = (confirmed(Side::A), confirmed(Side::B));
        assert!(a >= 15, "{repeated:x?}: {a} pairs confirmed");
        assert!(a.abs_diff(b) <= 1, "{repeated:x?}: A {a}, B {b}");
        let node = net.node(33);
        let (a, b) = (
            node.a.node().double_reception(),
            node.b.node().double_reception(),
        );
        assert_eq!(a, b, "{repeated:x?}: both channels saw the same copies");
        assert!(
            a.plain_repeated + a.inverted_without_plain > 0,
            "{repeated:x?}"
        );
    }
}

/// EN 50325-5 7.1.2, CiA 304 9.5 with dual-channel nodes: node 33 (both channels) leaves and
/// re-enters Operational at a grid of instants across one period of node 1's SRDO, every
/// 10 µs around its plain and inverted frames included; both channels reach their working
/// state, confirm pairs and agree.
#[test]
fn en50325_5_7_1_2_dual_channel_consumer_started_at_any_instant_works() {
    let (plain_start, _) = last_on_bus(&dual_running(), 0x101);
    let first = plain_start + 2 * PERIOD;
    let instants: Vec<Instant> = (0..PERIOD)
        .step_by(2_500)
        .map(|offset| first - PERIOD / 2 + offset)
        .chain((0..60).map(|step| first - 100 + 10 * step))
        .map(us)
        .collect();

    let mut lone_inverted_seen = 0;
    for queued_at in instants {
        let mut net = dual_running();
        net.bus
            .send(0, nmt::command_frame(NmtCommand::EnterPreOperational, 33));
        net.run_until(queued_at);
        let since = net.log.len();
        net.bus.send(0, nmt::command_frame(NmtCommand::Start, 33));
        net.run_for(Duration::from_millis(300));
        assert!(
            channel_faults(&net, since).is_empty(),
            "{queued_at:?}: {:?}",
            channel_faults(&net, since)
        );
        assert_all_working(&net, &format!("{queued_at:?}"));
        assert_eq!(net.output(33), 1, "{queued_at:?}");
        let node = net.node(33);
        let (a, b) = (
            node.a.node().double_reception(),
            node.b.node().double_reception(),
        );
        lone_inverted_seen += a.inverted_without_plain + b.inverted_without_plain;
    }
    assert!(
        lone_inverted_seen > 0,
        "the grid reached the instants between a plain and its inverted frame"
    );
}

/// CiA 304 9.5 with dual-channel nodes: node 33 leaves Operational (NMT Enter
/// Pre-operational) at a grid of instants every 20 µs around the end of node 1's inverted
/// frame, so that the other channel's verdict on that pair is still on the link when a channel
/// has left Operational and cleared its verdicts. The late verdict is about a pair neither
/// channel acts on any more: no fault, both channels stay out of the safe state, and node 33
/// works again after NMT Start.
#[test]
fn cia304_9_5_a_verdict_still_on_the_link_when_the_consumer_leaves_operational_is_no_fault() {
    let (_, inverted_end) = last_on_bus(&dual_running(), 0x102);
    let around = inverted_end + 2 * PERIOD;
    for queued_at in (around - 400..around + 800).step_by(20).map(us) {
        let mut net = dual_running();
        net.run_until(queued_at);
        let since = net.log.len();
        net.bus
            .send(0, nmt::command_frame(NmtCommand::EnterPreOperational, 33));
        net.run_for(Duration::from_millis(100));
        assert!(
            channel_faults(&net, since).is_empty(),
            "{queued_at:?}: {:?}",
            channel_faults(&net, since)
        );
        net.bus.send(0, nmt::command_frame(NmtCommand::Start, 33));
        net.run_for(Duration::from_millis(300));
        assert!(channel_faults(&net, since).is_empty(), "{queued_at:?}");
        assert_all_working(&net, &format!("{queued_at:?}"));
        assert_eq!(net.output(33), 1, "{queued_at:?}");
    }
}
