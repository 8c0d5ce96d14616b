//! The three hot paths of the protocol core as a plain program, for instruction counting:
//! `cargo xtask bench` runs it under callgrind, counting only inside the three measured
//! functions (`--toggle-collect`), and divides by the iterations.
//!
//! ```text
//! hot_paths <validated-pair|produced-pair|idle-poll|integrity-check> <iterations>
//! hot_paths <validated-pair-at|produced-pair-at> <srdos> <iterations>
//! ```
//!
//! - `validated-pair`: an 8-byte SRDO pair received by an Operational consumer (node 33):
//!   both frames in, identifier lookup, order, SRVT and SCT checks, bit-by-bit inversion,
//!   data delivered to the object dictionary.
//! - `produced-pair`: a cyclic transmission of an 8-byte SRDO by a producer (node 1): the
//!   poll that finds it due gathers the mapped data, checks the halves and hands both frames
//!   to the sink.
//! - `idle-poll`: a poll with nothing due.
//! - `integrity-check`: the poll at which the periodic integrity check in Operational is due
//!   (node 1, one producer: the Operational-entry check again, the tables derived again and
//!   compared). It runs once per refresh time, in a poll of its own; `produced-pair` counts
//!   only the polls that transmit.
//! - `validated-pair-at` and `produced-pair-at`: the same two paths on a node with `srdos`
//!   (1, 4, 16 or 64) SRDOs configured and running, all receive SRDOs (node 33) or all
//!   transmit SRDOs (node 1) with the same mapping and timing, on consecutive identifiers
//!   from 101h. The consumer is fed the pairs of its SRDOs in turn, every 500 µs (so each
//!   SRDO's SCT is honoured at 64); the producer's SRDOs share a refresh time, so each
//!   transmitting poll sends one pair per SRDO. Divided by the pairs, not the iterations.

use shared::canopen::od::Address;
use shared::canopen::sdo_client;
use shared::canopen::storage::RamFlash;
use shared::canopen::{NodeId, nmt};
use shared::node::{Event, Node, NodeConfig, Sink};
use shared::process_image::{Access, AppObject, Mappable};
use shared::{CanFrame, CanId, Duration, Instant};
use std::hint::black_box;

const fn object(index: u16, mappable: Mappable) -> AppObject {
    AppObject {
        address: Address::new(index, 1),
        len: 4,
        access: Access::ReadOnly,
        mappable,
    }
}

/// Two 32-bit inputs and two 32-bit outputs, each with its inverted copy: 8 bytes per frame.
static OBJECTS: [AppObject; 8] = [
    object(0x6000, Mappable::Transmit),
    object(0x6001, Mappable::Transmit),
    object(0x6002, Mappable::Transmit),
    object(0x6003, Mappable::Transmit),
    object(0x6200, Mappable::Receive),
    object(0x6201, Mappable::Receive),
    object(0x6202, Mappable::Receive),
    object(0x6203, Mappable::Receive),
];

fn config(node_id: u8) -> NodeConfig {
    NodeConfig {
        node_id: NodeId::new(node_id).expect("valid node-ID"),
        device_type: 0x0001_0191,
        device_name: "bench",
        identity: [0; 4],
        app_objects: &OBJECTS,
        default_transmit_mapping: &[0x6000_0120, 0x6001_0120, 0x6002_0120, 0x6003_0120],
        default_receive_mapping: &[0x6200_0120, 0x6201_0120, 0x6202_0120, 0x6203_0120],
        heartbeat_ms: 0,
        sdo_timeout: Duration::from_millis(500),
        event_driven: false,
        gfc_on_fault: false,
    }
}

/// Keeps what it is handed observable, so nothing is optimised away.
#[derive(Default)]
pub struct Counter {
    frames: u32,
    events: u32,
    last: Option<CanFrame>,
}

impl Sink for Counter {
    fn transmit(&mut self, frame: CanFrame) {
        self.frames += 1;
        self.last = Some(black_box(frame));
    }
    fn event(&mut self, event: Event) {
        self.events += 1;
        black_box(event);
    }
}

/// The node type measured: one SRDO.
pub type BenchNode = Node<RamFlash<4096>, 1>;

/// A node with the pre-defined SRDO 1, validated over SDO and started at t = 0.
pub fn operational(node_id: u8) -> BenchNode {
    let mut node = BenchNode::new(config(node_id), RamFlash::new()).expect("valid node");
    let mut sink = Counter::default();
    node.poll(Instant::ZERO, &mut sink);
    if node_id <= 32 {
        // Inputs that are exact inverses of each other.
        node.write_object(Address::new(0x6001, 1), &[0xFF; 4])
            .expect("input");
        node.write_object(Address::new(0x6003, 1), &[0xFF; 4])
            .expect("input");
    }
    let signature = shared::safety::signature::compute(&node.safety_config().srdos[0]);
    let sdo = CanId::new(0x600 + u16::from(node_id)).expect("valid id");
    let mut exchange = |request: [u8; 8]| {
        let mut sink = Counter::default();
        let frame = CanFrame::new(sdo, &request).expect("8 bytes");
        node.handle_frame(Instant::ZERO, &frame, &mut sink);
        sink.last.and_then(|f| f.data().try_into().ok())
    };
    sdo_client::download(
        &mut exchange,
        Address::new(0x13FF, 1),
        &signature.to_le_bytes(),
    )
    .expect("signature accepted");
    sdo_client::download(&mut exchange, Address::new(0x13FE, 0), &[0xA5]).expect("valid");
    node.handle_frame(
        Instant::ZERO,
        &nmt::command_frame(nmt::NmtCommand::Start, 0),
        &mut sink,
    );
    assert!(
        node.is_working(),
        "node {node_id} is Operational and working"
    );
    node
}

/// The `i`-th valid pair for node 33's SRDO 1: varying data and its exact inverse.
pub fn pair_frames(i: u64) -> (CanFrame, CanFrame) {
    let value = i.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    let plain = CanFrame::new(CanId::new(0x141).expect("id"), &value.to_le_bytes());
    let inverted = CanFrame::new(CanId::new(0x142).expect("id"), &(!value).to_le_bytes());
    (plain.expect("frame"), inverted.expect("frame"))
}

// The measured functions: callgrind counts only inside them (`--toggle-collect`), so building
// the frames and the loop around them are not counted.

/// Measured: both frames of a valid pair into the consumer.
#[inline(never)]
pub fn receive_pair(
    node: &mut BenchNode,
    at: Instant,
    plain: &CanFrame,
    inverted: &CanFrame,
    sink: &mut Counter,
) {
    node.handle_frame(at, plain, sink);
    node.handle_frame(at + Duration::from_micros(300), inverted, sink);
}

/// Measured: the poll at which a cyclic transmission is due.
#[inline(never)]
pub fn produce(node: &mut BenchNode, due: Instant, sink: &mut Counter) -> Instant {
    node.poll(due, sink)
}

/// Measured: the poll at which the integrity check is due.
#[inline(never)]
pub fn check(node: &mut BenchNode, due: Instant, sink: &mut Counter) -> Instant {
    // Not the same body as `produce`, so the two are never folded into one function.
    black_box(node.poll(due, sink))
}

/// Measured: a poll with nothing due.
#[inline(never)]
pub fn idle(node: &mut BenchNode, now: Instant, sink: &mut Counter) -> Instant {
    node.poll(now, sink)
}

fn validated_pair(iterations: u64) -> Counter {
    let mut node = operational(33);
    let mut sink = Counter::default();
    for i in 0..iterations {
        let (plain, inverted) = pair_frames(i);
        let at = Instant::from_millis(10 * (i + 1));
        receive_pair(&mut node, at, &plain, &inverted, &mut sink);
    }
    assert!(node.is_working(), "every pair was valid");
    assert_eq!(sink.events as u64, iterations, "every pair was delivered");
    sink
}

/// The producer's refresh time (the pre-defined 25 ms), and so the integrity check's period.
const REFRESH_US: u64 = 25_000;

/// `iterations` transmissions of node 1's SRDO 1 and the integrity checks between them: the
/// transmissions are due 0.5 ms after entering Operational and every refresh time after
/// (DSP 304 9.5), the check every refresh time from the entry itself, so every poll is one
/// or the other; each goes through its own measured function.
fn producer_polls(iterations: u64) -> Counter {
    let mut node = operational(1);
    let mut sink = Counter::default();
    let mut due = node.poll(Instant::ZERO, &mut sink);
    let (mut produced, mut checked) = (0, 0);
    while produced < iterations || checked < iterations {
        let before = sink.frames;
        if due.as_micros() % REFRESH_US == 0 {
            due = check(&mut node, due, &mut sink);
            assert_eq!(sink.frames, before, "the check sends nothing");
            checked += 1;
        } else {
            due = produce(&mut node, due, &mut sink);
            assert_eq!(sink.frames, before + 2, "a pair per transmitting poll");
            produced += 1;
        }
    }
    assert!(node.is_working(), "the check found nothing");
    sink
}

fn idle_poll(iterations: u64) -> Counter {
    let mut node = operational(33);
    let mut sink = Counter::default();
    let now = Instant::from_millis(1);
    let mut deadline = node.poll(now, &mut sink);
    for _ in 0..iterations {
        deadline = idle(&mut node, now, &mut sink);
    }
    black_box(deadline);
    assert_eq!(sink.frames, 0, "nothing was due");
    sink
}

/// Writes the records of `N` SRDOs over SDO (all `direction`, on identifiers 101h + 2k and
/// 102h + 2k, the device's default mapping for that direction, refresh time or SCT 25 ms or
/// 50 ms, SRVT 20 ms), signs and validates them, and starts the node at t = 0.
fn configured<const N: usize>(node_id: u8) -> Node<RamFlash<4096>, N> {
    let mut node =
        Node::<RamFlash<4096>, N>::new(config(node_id), RamFlash::new()).expect("valid node");
    let mut sink = Counter::default();
    node.poll(Instant::ZERO, &mut sink);
    if node_id <= 32 {
        node.write_object(Address::new(0x6001, 1), &[0xFF; 4])
            .expect("input");
        node.write_object(Address::new(0x6003, 1), &[0xFF; 4])
            .expect("input");
    }
    let transmit = node_id <= 32;
    let mapping = if transmit {
        config(node_id).default_transmit_mapping
    } else {
        config(node_id).default_receive_mapping
    };
    for k in 0..N as u16 {
        // Deleted first, so that the identifiers and the mapping may change.
        write(&mut node, 0x1301 + k, 1, &[0]);
        write(&mut node, 0x1381 + k, 0, &[0]);
        for (sub, entry) in (1..).zip(mapping) {
            write(&mut node, 0x1381 + k, sub, &entry.to_le_bytes());
        }
        write(&mut node, 0x1381 + k, 0, &[mapping.len() as u8]);
        let cycle_time: u16 = if transmit { 25 } else { 50 };
        write(&mut node, 0x1301 + k, 2, &cycle_time.to_le_bytes());
        write(&mut node, 0x1301 + k, 3, &[20]);
        write(
            &mut node,
            0x1301 + k,
            5,
            &u32::from(0x101 + 2 * k).to_le_bytes(),
        );
        write(
            &mut node,
            0x1301 + k,
            6,
            &u32::from(0x102 + 2 * k).to_le_bytes(),
        );
        write(&mut node, 0x1301 + k, 1, &[if transmit { 1 } else { 2 }]);
    }
    for k in 0..N {
        let signature = shared::safety::signature::compute(&node.safety_config().srdos[k]);
        write(&mut node, 0x13FF, k as u8 + 1, &signature.to_le_bytes());
    }
    write(&mut node, 0x13FE, 0, &[0xA5]);
    node.handle_frame(
        Instant::ZERO,
        &nmt::command_frame(nmt::NmtCommand::Start, 0),
        &mut sink,
    );
    assert!(
        node.is_working(),
        "node {node_id} is Operational and working"
    );
    node
}

/// One SDO download to `node` at t = 0, which must be accepted.
fn write<const N: usize>(node: &mut Node<RamFlash<4096>, N>, index: u16, sub: u8, data: &[u8]) {
    let sdo = CanId::new(0x600 + u16::from(node.node_id().raw())).expect("valid id");
    let exchange = |request: [u8; 8]| {
        let mut sink = Counter::default();
        let frame = CanFrame::new(sdo, &request).expect("8 bytes");
        node.handle_frame(Instant::ZERO, &frame, &mut sink);
        sink.last.and_then(|f| f.data().try_into().ok())
    };
    sdo_client::download(exchange, Address::new(index, sub), data)
        .unwrap_or_else(|error| panic!("{index:04X}:{sub:02X} refused: {error:?}"));
}

/// Measured: both frames of a valid pair into a consumer with `N` SRDOs.
#[inline(never)]
pub fn receive_pair_at<const N: usize>(
    node: &mut Node<RamFlash<4096>, N>,
    at: Instant,
    plain: &CanFrame,
    inverted: &CanFrame,
    sink: &mut Counter,
) {
    node.handle_frame(at, plain, sink);
    node.handle_frame(at + Duration::from_micros(300), inverted, sink);
}

/// Measured: the poll at which the cyclic transmissions of a producer with `N` SRDOs are due.
#[inline(never)]
pub fn produce_at<const N: usize>(
    node: &mut Node<RamFlash<4096>, N>,
    due: Instant,
    sink: &mut Counter,
) -> Instant {
    node.poll(due, sink)
}

/// The poll at which the integrity check is due, not measured.
#[inline(never)]
fn check_at<const N: usize>(
    node: &mut Node<RamFlash<4096>, N>,
    due: Instant,
    sink: &mut Counter,
) -> Instant {
    black_box(node.poll(due, sink))
}

/// `iterations` valid pairs into a consumer with `N` SRDOs, its SRDOs in turn.
fn validated_pairs_at<const N: usize>(iterations: u64) -> Counter {
    let mut node = configured::<N>(33);
    let mut sink = Counter::default();
    for i in 0..iterations {
        let value = i.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let first = 0x101 + 2 * (i % N as u64) as u16;
        let plain = CanFrame::new(CanId::new(first).expect("id"), &value.to_le_bytes());
        let inverted = CanFrame::new(CanId::new(first + 1).expect("id"), &(!value).to_le_bytes());
        let at = Instant::from_micros(500 * (i + 1));
        receive_pair_at(
            &mut node,
            at,
            &plain.expect("frame"),
            &inverted.expect("frame"),
            &mut sink,
        );
    }
    assert!(node.is_working(), "every pair was valid");
    assert_eq!(sink.events as u64, iterations, "every pair was delivered");
    sink
}

/// The transmitting polls of a producer with `N` SRDOs until `pairs` pairs are sent, and the
/// integrity checks between them (not measured).
fn produced_pairs_at<const N: usize>(pairs: u64) -> Counter {
    let mut node = configured::<N>(1);
    let mut sink = Counter::default();
    let mut due = node.poll(Instant::ZERO, &mut sink);
    let mut produced = 0;
    while produced < pairs {
        let before = sink.frames;
        if due.as_micros() % REFRESH_US == 0 {
            due = check_at(&mut node, due, &mut sink);
            assert_eq!(sink.frames, before, "the check sends nothing");
        } else {
            due = produce_at(&mut node, due, &mut sink);
            assert_eq!(sink.frames, before + 2 * N as u32, "a pair per SRDO");
            produced += N as u64;
        }
    }
    assert!(node.is_working(), "the check found nothing");
    sink
}

/// The scaled paths, by SRDO count.
fn at_scale(path: &str, srdos: u64, pairs: u64) -> Option<Counter> {
    let receive = path == "validated-pair-at";
    Some(match (srdos, receive) {
        (1, true) => validated_pairs_at::<1>(pairs),
        (4, true) => validated_pairs_at::<4>(pairs),
        (16, true) => validated_pairs_at::<16>(pairs),
        (64, true) => validated_pairs_at::<64>(pairs),
        (1, false) => produced_pairs_at::<1>(pairs),
        (4, false) => produced_pairs_at::<4>(pairs),
        (16, false) => produced_pairs_at::<16>(pairs),
        (64, false) => produced_pairs_at::<64>(pairs),
        _ => return None,
    })
}

fn main() {
    let mut args = std::env::args().skip(1);
    let (Some(path), Some(iterations)) = (args.next(), args.next()) else {
        eprintln!(
            "usage: hot_paths <validated-pair|produced-pair|idle-poll|integrity-check> <iterations>"
        );
        std::process::exit(2);
    };
    let Ok(iterations) = iterations.parse::<u64>() else {
        eprintln!("iterations must be a number, not {iterations:?}");
        std::process::exit(2);
    };
    if path.ends_with("-at") {
        let Some(Ok(pairs)) = args.next().map(|pairs| pairs.parse::<u64>()) else {
            eprintln!("usage: hot_paths {path} <srdos> <pairs>");
            std::process::exit(2);
        };
        // `iterations` is the SRDO count here.
        let Some(sink) = at_scale(&path, iterations, pairs) else {
            eprintln!("{path} runs at 1, 4, 16 or 64 SRDOs, not {iterations}");
            std::process::exit(2);
        };
        black_box(sink.last);
        return;
    }
    let sink = match path.as_str() {
        "validated-pair" => validated_pair(iterations),
        "produced-pair" | "integrity-check" => producer_polls(iterations),
        "idle-poll" => idle_poll(iterations),
        other => {
            eprintln!("unknown hot path {other:?}");
            std::process::exit(2);
        }
    };
    black_box(sink.last);
}
