//! The full-network simulation: the fast engine against `DualNetwork` (same trace, same
//! events), the stored configuration against one done over the bus, and properties of a
//! short full-network run (no SCT or SRVT event without faults, the bus load is the frames'
//! bit times summed).

use dual_channel::runtime::{ChannelEvent, Runtime};
use safety_config::client::Client;
use safety_config::procedure::{Quiet, configure_node};
use shared::canopen::nmt::{self, NmtCommand};
use shared::canopen::storage::RamFlash;
use shared::{CanFrame, Duration, Instant};
use system_tests::bus::{Fault, Injection, Match, frame_bits};
use system_tests::dual::{B_INPUTS, DualNetwork, LINK_PERIOD, Side};
use system_tests::fullnet::configure::{node_spec, receive, stored_image, transmit};
use system_tests::fullnet::engine::{Engine, Observer, Unobserved};
use system_tests::fullnet::{network, report};
use system_tests::network::device_config;

/// Every event per channel, in order, with its time.
#[derive(Default)]
struct Events(Vec<(Instant, usize, Side, ChannelEvent)>);

impl Observer for Events {
    fn event(&mut self, at: Instant, node: usize, side: Side, event: &ChannelEvent) {
        self.0.push((at, node, side, *event));
    }
}

/// Nodes 1 → 33 and 2 → 34, as stored images.
fn images() -> Vec<(u8, RamFlash<8192>)> {
    [
        node_spec(1, vec![transmit(1, 1, 25, 20)]),
        node_spec(2, vec![transmit(1, 2, 25, 20)]),
        node_spec(33, vec![receive(1, 1, 50, 20)]),
        node_spec(34, vec![receive(1, 2, 50, 20)]),
    ]
    .iter()
    .map(|spec| (spec.id, stored_image(spec).expect("configured").0))
    .collect()
}

/// What both simulations are asked to do: the same stimuli at the same instants.
trait Stimuli {
    fn run_until(&mut self, at: Instant);
    fn inputs(&mut self, node: usize, a: u8, b: u8);
    fn tool_sends(&mut self, frame: CanFrame);
    fn inject(&mut self, injection: Injection);
}

impl Stimuli for DualNetwork {
    fn run_until(&mut self, at: Instant) {
        DualNetwork::run_until(self, at);
    }
    fn inputs(&mut self, node: usize, a: u8, b: u8) {
        let id = self.nodes[node].id;
        self.set_inputs(id, a, b);
    }
    fn tool_sends(&mut self, frame: CanFrame) {
        self.send_foreign(frame);
    }
    fn inject(&mut self, injection: Injection) {
        self.bus.inject(injection);
    }
}

impl<O: Observer> Stimuli for Engine<O> {
    fn run_until(&mut self, at: Instant) {
        Engine::run_until(self, at);
    }
    fn inputs(&mut self, node: usize, a: u8, b: u8) {
        self.set_inputs(node, a, b);
    }
    fn tool_sends(&mut self, frame: CanFrame) {
        self.send_from_tool(frame);
    }
    fn inject(&mut self, injection: Injection) {
        self.bus.inject(injection);
    }
}

/// Start, an emergency stop and its release, one contact alone (an input discrepancy that
/// latches node 2), a GFC, NMT reset and start, node 1 muted (SCT expiry at node 33).
fn script(net: &mut impl Stimuli) {
    let ms = Instant::from_millis;
    net.run_until(ms(300));
    net.inputs(0, 1, 1);
    net.inputs(1, 1, 1);
    net.tool_sends(nmt::command_frame(NmtCommand::Start, 0));
    net.run_until(ms(1_013));
    net.inputs(0, 0, 0);
    net.run_until(ms(1_507));
    net.inputs(0, 1, 1);
    net.run_until(ms(2_001));
    net.inputs(1, 0, 1);
    net.run_until(ms(2_503));
    net.tool_sends(shared::safety::gfc::frame());
    net.run_until(ms(3_000));
    net.tool_sends(nmt::command_frame(NmtCommand::ResetCommunication, 0));
    net.run_until(ms(3_100));
    net.inputs(1, 1, 1);
    net.tool_sends(nmt::command_frame(NmtCommand::Start, 0));
    net.run_until(ms(3_617));
    for participant in [1, 2] {
        net.inject(Injection::new(
            Match::all_from(participant, ms(3_617)),
            Fault::Mute,
        ));
    }
    net.run_until(ms(4_500));
}

/// The reference: `DualNetwork` with the same stored images (its transmit queues are in
/// identifier order, as the engine's are).
fn reference() -> DualNetwork {
    let images = images();
    let ids: Vec<u8> = images.iter().map(|(id, _)| *id).collect();
    let mut net = DualNetwork::new(500_000, &ids);
    for (node, (id, image)) in net.nodes.iter_mut().zip(images) {
        node.a = Runtime::new(
            device_config(id, "dual node, channel A"),
            image.clone(),
            channel_a::role::ChannelA::default(),
            Instant::ZERO,
            LINK_PERIOD,
        )
        .expect("valid device");
        node.b = Runtime::new(
            device_config(id, "dual node, channel B"),
            image,
            channel_b::role::ChannelB::new(&B_INPUTS).expect("valid inputs"),
            Instant::ZERO,
            LINK_PERIOD,
        )
        .expect("valid device");
    }
    net
}

/// The fast engine on the reference's nodes, on `threads` threads.
fn engine(unfiltered: bool, threads: usize) -> Engine<Events> {
    let nodes = images()
        .into_iter()
        .map(|(id, image)| (id, Some(image)))
        .collect();
    let mut engine = Engine::new(500_000, nodes, LINK_PERIOD, Events::default());
    engine.unfiltered = unfiltered;
    engine.set_threads(threads);
    engine.trace = Some(Vec::new());
    engine
}

/// Per channel, its events in order.
fn per_channel(
    events: &[(Instant, usize, Side, ChannelEvent)],
) -> Vec<Vec<(Instant, ChannelEvent)>> {
    let mut channels = vec![Vec::new(); 8];
    for (at, node, side, event) in events {
        channels[2 * node + *side as usize].push((*at, *event));
    }
    channels
}

/// The fast engine (acceptance filtering, link messages in one step, heaps of deadlines)
/// makes the same calls as `DualNetwork`: on a script with every path the full network uses
/// and several faults, the same frames at the same microseconds from the same senders, and
/// every channel reports the same events at the same instants. Filtering or not changes
/// nothing either, nor does running the channels on two threads.
#[test]
fn fast_engine_gives_the_dual_network_trace_frame_for_frame() {
    let mut reference = reference();
    script(&mut reference);
    let expected: Vec<(Instant, CanFrame, usize)> = reference.trace.clone();
    let expected_events: Vec<(Instant, usize, Side, ChannelEvent)> = reference
        .log
        .iter()
        .map(|(at, id, side, event)| {
            let node = reference.nodes.iter().position(|n| n.id == *id).unwrap();
            (*at, node, *side, *event)
        })
        .collect();
    // The script does what it is meant to: SRDOs, faults of several kinds, a GFC.
    assert!(
        expected
            .iter()
            .filter(|(_, f, _)| f.id().raw() == 0x101)
            .count()
            > 50
    );
    assert!(expected.iter().any(|(_, f, _)| f.id().raw() == 0x001));
    assert!(
        expected_events
            .iter()
            .filter(|(.., e)| matches!(e, ChannelEvent::Fault(_)))
            .count()
            >= 4,
        "{expected_events:?}"
    );
    // With two threads, once with every window's frames and link bytes through the
    // threads' board and once through the exchange's slots (a board of two words).
    for (unfiltered, threads, board) in
        [(false, 1, 32), (true, 1, 32), (false, 2, 32), (false, 2, 2)]
    {
        let mut fast = engine(unfiltered, threads);
        fast.limit_board(board);
        script(&mut fast);
        let trace = fast.trace.take().unwrap();
        let first_difference = expected
            .iter()
            .zip(&trace)
            .position(|(a, b)| a != b)
            .unwrap_or(expected.len().min(trace.len()));
        assert_eq!(
            (first_difference, trace.len()),
            (expected.len(), expected.len()),
            "unfiltered {unfiltered}, {threads} threads: traces differ from frame \
             {first_difference}: {:?} / {:?}",
            expected.get(first_difference),
            trace.get(first_difference)
        );
        assert_eq!(
            per_channel(&fast.observer.0),
            per_channel(&expected_events),
            "unfiltered {unfiltered}, {threads} threads"
        );
    }
}

/// The tool's procedure against one core alone stores the same image, byte for byte, as
/// the same procedure over the simulated bus against both channels of a dual-channel node.
#[test]
fn stored_image_equals_the_one_configured_over_the_bus() {
    for spec in [
        node_spec(65, vec![receive(1, 1, 45, 10)]),
        node_spec(1, vec![transmit(1, 1, 13, 10), receive(2, 64, 45, 10)]),
    ] {
        let (alone, _) = stored_image(&spec).expect("configured alone");
        let mut engine = Engine::new(1_000_000, vec![(spec.id, None)], LINK_PERIOD, Unobserved);
        assert!(engine.wait_for_boot(Duration::from_millis(2000)));
        let mut client = Client::new(engine, std::time::Duration::from_millis(500));
        configure_node(
            &mut client,
            &spec,
            &mut Quiet {
                accept_identity: false,
            },
        )
        .expect("configured over the bus");
        let engine = &client.transport;
        assert!(
            engine.channel_a(0).node().flash() == &alone,
            "node {} channel A",
            spec.id
        );
        assert!(
            engine.channel_b(0).node().flash() == &alone,
            "node {} channel B",
            spec.id
        );
        assert_eq!(
            engine
                .channel_a(0)
                .node()
                .safety_config()
                .configuration_valid,
            0xA5
        );
    }
}

/// A short run of the full network (127 dual-channel nodes, 64 producers, 64 consumers,
/// background load, input changes): no channel reports a fault or safe state, every SRDO's
/// pairs keep within SCT and SRVT, and every input change reaches its consumer's output.
#[test]
fn en50325_5_7_1_2_full_network_without_faults_has_no_sct_or_srvt_event() {
    let report = network::run(Duration::from_millis(3500), 7, false, 2).expect("runs");
    let monitor = &report.monitor;
    assert_eq!(monitor.faults, 0, "{:?}", monitor.fault_lines);
    let srvt = u64::from(report.timing.srvt_ms) * 1000;
    let sct = u64::from(report.timing.sct_ms) * 1000;
    for srdo in &monitor.srdos {
        // At least one pair per refresh time after the first, which comes within SCT.
        let cycles = (3500 - u64::from(report.timing.sct_ms)) / u64::from(report.timing.refresh_ms);
        assert!(srdo.pairs >= cycles, "{srdo:?}");
        assert!(srdo.max_gap_us < srvt, "{srdo:?}");
        assert!(
            srdo.max_interval_us < sct && srdo.first_us < sct,
            "{srdo:?}"
        );
    }
    // The first input changes come 2..4 s after the start: most producers have had one.
    assert!(monitor.to_safe.count >= 20, "{:?}", monitor.to_safe);
    assert!(monitor.to_safe.max_us < srvt + u64::from(report.timing.refresh_ms) * 1000);
}

/// The full network on two threads (channel A of every node on one, channel B on the other,
/// each thread with its own copy of the bus, meeting once per window of simulated time)
/// gives the report of one thread: every frame at the same microsecond from the same
/// sender, and every line of the report but the wall time.
#[test]
fn full_network_on_two_threads_gives_the_one_thread_report() {
    let runs: Vec<_> = [1, 2]
        .into_iter()
        .map(|threads| network::run(Duration::from_millis(1200), 11, true, threads).expect("runs"))
        .collect();
    let text = |run: &network::Report| -> String {
        report::full_network(run)
            .lines()
            .filter(|line| !line.starts_with("**Wall time**"))
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert!(runs[0].monitor.to_safe.count + runs[0].monitor.srdos[0].pairs > 50);
    assert_eq!(runs[0].trace, runs[1].trace);
    assert_eq!(text(&runs[0]), text(&runs[1]));
}

/// The bus load the report gives is the bits of the frames on the bus, recomputed here
/// from the frames themselves (stuff bits included), over the bit times elapsed; the bus
/// model's own count covers the same frames.
#[test]
fn full_network_bus_load_is_the_frames_bit_times_summed() {
    let report = network::run(Duration::from_millis(1000), 3, true, 1).expect("runs");
    let trace = report.trace.as_ref().expect("kept");
    let started = report.monitor.started.expect("started");
    let since_start: u64 = trace
        .iter()
        .filter(|(at, ..)| *at >= started)
        .map(|(_, frame, _)| u64::from(frame_bits(frame)))
        .sum();
    let load = since_start as f64 / (1_000_000.0 * 1.0);
    assert!(
        (report.load() - load).abs() < 1e-12,
        "{} {load}",
        report.load()
    );
    assert!(
        report.load() > 0.5 && report.load() < 1.0,
        "{}",
        report.load()
    );
    let all: u64 = trace
        .iter()
        .map(|(_, frame, _)| u64::from(frame_bits(frame)))
        .sum();
    assert_eq!(all, report.monitor.bits_total);
    // Frames arbitrated but still on the bus at the end are counted by the bus, not yet
    // delivered: at most one.
    assert!(
        report.bus_bits >= all && report.bus_bits - all <= 135,
        "{} {all}",
        report.bus_bits
    );
}
