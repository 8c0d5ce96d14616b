//! SimpleCAN's system-level requirements on the host network of two dual-channel nodes
//! (`system_tests::simplecan_dual`) at 500 kbit/s, configured by the configuration tool's own
//! procedure from the safety manual's example network file
//! (`manual/src/examples/simplecan-network.toml`): node 1 is the master and produces the
//! emergency stop (SC-ID 30h, slot 0, its input 6000h:01); node 33 consumes it with a safety
//! timeout of 60 ms into its output 6200h:01. N = 10 slots of 1 ms, a sync every 10 cycles.
//!
//! - SC_REQ_45: the calculator's worst-case reaction for that file bounds the reaction
//!   measured on the network, and the configured safety timeout covers the whole chain.
//! - SC_REQ_08: non-safety traffic beside SimpleCAN moves no packet beyond its slot and
//!   changes no verdict.
//! - SC_REQ_09: a producer with no consumer keeps producing, on time.

use dual_channel::runtime::ChannelEvent;
use safety_config::calc::sfrt::DeviceTiming;
use safety_config::calc::simplecan::{self as calc, ScReaction};
use safety_config::network_file::{self, Network};
use shared::canopen::nmt::NmtState;
use shared::{CanFrame, CanId, Duration, Instant};
use system_tests::bus::frame_time;
use system_tests::dual::Side;
use system_tests::simplecan_dual::{
    ScDualNetwork, calculator_timing, emergency_stop_reactions, reaction_with_every_packet_lost,
    running_from_file,
};

/// The safety manual's worked example, the file `cargo xtask manual` computes its figures from.
const FILE: &str = include_str!("../../manual/src/examples/simplecan-network.toml");
const BIT_RATE: u32 = 500_000;
const ESTOP: u8 = 0x30;
/// SimpleCAN's identifiers: the sync (02Fh) and the SC-IDs 30h..7Fh (`docs/simplecan.md`
/// section 1).
const SIMPLECAN_IDS: std::ops::RangeInclusive<u16> = 0x02F..=0x07F;
/// One cycle: N = 10 slots of 1 ms.
const CYCLE_US: u64 = 10_000;
/// One slot (SC_REQ_18).
const SLOT_US: u64 = 1_000;

fn file() -> Network {
    network_file::parse(FILE, "simplecan-network.toml").expect("the manual's example parses")
}

/// The one consumed SC-ID's bound for the example file on `timing`.
fn bound(timing: &DeviceTiming) -> ScReaction {
    let network = file();
    let simplecan = network.simplecan.as_ref().expect("a [simplecan] section");
    let mut reactions = calc::reactions(simplecan, BIT_RATE, timing).expect("a bound");
    assert_eq!(reactions.len(), 1, "{reactions:?}");
    reactions.remove(0)
}

/// The network of `file`, configured by the tool, started, its consumer's output on.
fn running(file: &Network) -> ScDualNetwork {
    running_from_file(file, BIT_RATE).expect("the tool configures and starts every node")
}

/// The SimpleCAN frames on the bus from `from` on: (end of the frame, frame).
fn simplecan_frames(net: &ScDualNetwork, from: Instant) -> Vec<(Instant, CanFrame)> {
    net.trace
        .iter()
        .filter(|(at, frame, _)| *at >= from && SIMPLECAN_IDS.contains(&frame.id().raw()))
        .map(|&(at, frame, _)| (at, frame))
        .collect()
}

/// Every verdict node 33's channels reported from `from` on, in order, without its instant:
/// (channel, event).
fn verdicts(net: &ScDualNetwork, from: Instant) -> Vec<(Side, ChannelEvent)> {
    net.log
        .iter()
        .filter(|(at, id, ..)| *at >= from && *id == 33)
        .map(|(_, _, side, event)| (*side, *event))
        .collect()
}

/// The emergency stop pressed at 20 phases of the 10 ms cycle (every 500 µs): each measured
/// reaction (input to node 33's output off) is within the calculator's fault-free bound for
/// the same file on the host's timing; with every packet after the demand lost, the output
/// goes off by the safety timeout and within the one-fault bound. On the hardware's timing
/// the fault-free chain (input sample, the producer's step, its slot wait, the packet, the
/// buffering, the consumer's step, the cross-check, the output) is shorter than the
/// configured safety timeout, so the reaction time is the timeout's path: the safety
/// timeout plus the steps around it (SC_REQ_45; its note leaves out the sensor, the
/// actuator and filtering).
#[test]
fn sc_req_45_the_computed_reaction_bounds_the_measured_one_and_the_timeout_covers_the_chain() {
    let host = bound(&calculator_timing());
    let reactions =
        emergency_stop_reactions(&file(), BIT_RATE, (1, 33, ESTOP), 20).expect("reactions");
    for (phase, &reaction) in reactions.iter().enumerate() {
        assert!(
            reaction <= host.fault_free_us,
            "phase {phase}: measured {reaction} µs, computed {} µs",
            host.fault_free_us
        );
    }
    let worst = reactions.iter().copied().max().expect("20 phases");
    // Every packet after the demand lost at node 33 (both controllers): the value ages out.
    let timed_out =
        reaction_with_every_packet_lost(&file(), BIT_RATE, (1, 33, ESTOP)).expect("a reaction");
    let timeout_us = {
        let network = file();
        let simplecan = network.simplecan.as_ref().expect("a [simplecan] section");
        let consumed = simplecan.nodes[&33]
            .consumed
            .iter()
            .find(|c| c.sc_id == 0x30)
            .expect("node 33 consumes 30h");
        u64::from(consumed.timeout_ms) * 1000
    };
    assert!(
        timed_out <= host.one_fault_us,
        "measured {timed_out} µs, computed {} µs",
        host.one_fault_us
    );
    assert!(
        timed_out + CYCLE_US >= timeout_us,
        "the output went off {timed_out} µs after the demand, before the timeout could expire"
    );

    let hardware = bound(&DeviceTiming::HARDWARE_SIMPLECAN);
    let chain: Vec<&str> = hardware.parts.iter().map(|part| part.what).collect();
    for part in [
        "input sample",
        "producer's slot wait",
        "packet on the bus",
        "receive buffering",
        "consumer's validation",
        "channels' cross-check",
        "output stage",
    ] {
        assert!(
            chain.iter().any(|what| what.starts_with(part)),
            "{part} missing from {chain:?}"
        );
    }
    assert_eq!(
        hardware.parts.iter().map(|part| part.micros).sum::<u64>(),
        hardware.fault_free_us
    );
    assert!(
        hardware.fault_free_us <= timeout_us,
        "the fault-free chain, {} µs, is longer than the {timeout_us} µs timeout",
        hardware.fault_free_us
    );
    assert_eq!(hardware.worst_us, hardware.one_fault_us);
    println!(
        "SimpleCAN emergency stop, host network: measured worst {worst} µs, computed {} µs; \
         every packet lost: measured {timed_out} µs, computed {} µs; hardware timing: \
         fault-free chain {} µs within the {timeout_us} µs timeout, worst case {} µs",
        host.fault_free_us, host.one_fault_us, hardware.fault_free_us, hardware.worst_us
    );
}

/// Non-safety traffic the tool's participant puts on the bus: (frame, period).
fn non_safety_streams() -> Vec<(CanFrame, Duration)> {
    let frame =
        |id: u16, data: &[u8]| CanFrame::new(CanId::new(id).expect("11-bit"), data).expect("frame");
    vec![
        // PDO-like process data of other devices.
        (frame(0x181, &[0x55; 8]), Duration::from_millis(1)),
        (
            frame(0x281, &[0xA5, 0x5A, 0x0F, 0xF0]),
            Duration::from_millis(2),
        ),
        // SDO: reading node 33's vendor-ID (1018h:01), which it answers on 5A1h.
        (
            frame(0x621, &[0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0]),
            Duration::from_millis(10),
        ),
    ]
}

/// Runs `net` for `duration`, putting `streams` on the bus from the tool's participant
/// when `loaded`.
fn run(
    net: &mut ScDualNetwork,
    duration: Duration,
    streams: &[(CanFrame, Duration)],
    loaded: bool,
) {
    let end = net.now + duration;
    let mut next: Vec<Instant> = streams.iter().map(|_| net.now).collect();
    loop {
        let due = next.iter().copied().min().filter(|_| loaded).unwrap_or(end);
        if due >= end {
            net.run_until(end);
            return;
        }
        net.run_until(due);
        for (at, (frame, period)) in next.iter_mut().zip(streams) {
            if *at <= due {
                net.bus.send(0, *frame);
                *at = *at + *period;
            }
        }
    }
}

/// The same network run twice from the same state, for 1 s with the emergency stop pressed
/// in the middle: once alone, once beside PDO-like frames and SDO transfers (node 33
/// answering) on identifiers outside SimpleCAN's, at least 30 % of the bus. Every
/// SimpleCAN packet and sync is on the bus in both runs, in the same order with the same
/// content, at most one non-safety frame's worst-case time later (CAN does not pre-empt a
/// frame on the bus; SimpleCAN's identifiers win every arbitration against them), and
/// still within its 1 ms slot; node 33's channels give the same verdicts in the same order,
/// and the reaction differs by at most that blocking (SC_REQ_08).
#[test]
fn sc_req_08_non_safety_traffic_beside_simplecan_changes_no_slot_and_no_verdict() {
    let streams = non_safety_streams();
    let blocking_us = streams
        .iter()
        .map(|(frame, _)| frame_time(frame, BIT_RATE).as_micros())
        .chain([frame_time(
            &CanFrame::new(CanId::new(0x5A1).expect("11-bit"), &[0; 8]).expect("frame"),
            BIT_RATE,
        )
        .as_micros()])
        .max()
        .expect("streams");
    let mut measured = Vec::new();
    for loaded in [false, true] {
        let mut net = running(&file());
        let start = net.now;
        run(&mut net, Duration::from_millis(500), &streams, loaded);
        let pressed = net.now;
        net.set_inputs(1, 0);
        run(&mut net, Duration::from_millis(500), &streams, loaded);
        let busy_us: u64 = net
            .trace
            .iter()
            .filter(|(at, frame, _)| *at >= start && !SIMPLECAN_IDS.contains(&frame.id().raw()))
            .map(|(_, frame, _)| frame_time(frame, BIT_RATE).as_micros())
            .sum();
        let load = busy_us as f64 / net.now.saturating_since(start).as_micros() as f64;
        assert_eq!(net.faults(1), [None, None], "loaded: {loaded}");
        assert_eq!(net.faults(33), [None, None], "loaded: {loaded}");
        assert_eq!(net.node(33).a.node().nmt_state(), NmtState::Operational);
        let off = net
            .output_off(33, ESTOP, pressed)
            .expect("the output goes off");
        measured.push((
            simplecan_frames(&net, start),
            verdicts(&net, start),
            off.saturating_since(pressed).as_micros(),
            load,
        ));
    }
    let (alone, alone_verdicts, alone_reaction, _) = &measured[0];
    let (beside, beside_verdicts, beside_reaction, load) = &measured[1];
    assert!(*load >= 0.30, "non-safety load {load:.3}");
    assert_eq!(alone.len(), beside.len());
    assert!(alone.len() >= 100, "{} SimpleCAN frames", alone.len());
    let mut latest = 0;
    for ((at_alone, frame_alone), (at_beside, frame_beside)) in alone.iter().zip(beside) {
        assert_eq!(frame_alone, frame_beside);
        let later = at_beside.saturating_since(*at_alone).as_micros();
        assert!(
            *at_beside >= *at_alone,
            "{frame_beside:?} earlier with load"
        );
        assert!(
            later <= blocking_us,
            "{frame_beside:?} {later} µs later, more than one frame ({blocking_us} µs)"
        );
        // Alone, a packet starts at its slot's start: with load it still ends in its slot.
        let slot_start = at_alone.as_micros() - frame_time(frame_alone, BIT_RATE).as_micros();
        assert!(
            at_beside.as_micros() <= slot_start + SLOT_US,
            "{frame_beside:?}"
        );
        latest = latest.max(later);
    }
    assert_eq!(alone_verdicts, beside_verdicts);
    assert!(beside_reaction.abs_diff(*alone_reaction) <= blocking_us);
    println!(
        "non-safety load {:.1} %: {} SimpleCAN frames, each at most {latest} µs later (bound \
         {blocking_us} µs), {} verdicts unchanged, reaction {alone_reaction} µs alone, \
         {beside_reaction} µs with load",
        load * 100.0,
        beside.len(),
        beside_verdicts.len()
    );
}

/// The example file without its consumer: node 1 alone produces 30h.
fn producer_only() -> Network {
    let text = FILE
        .split("[[node]]\nid = 33")
        .next()
        .expect("the producer's part");
    network_file::parse(text, "producer-only.toml").expect("a network of one producer")
}

/// Node 1, the producer and master, alone on the bus: no consumer, nothing a SimpleCAN
/// layer could acknowledge with. It keeps producing for 2 s: one packet each cycle, exactly
/// one cycle apart (nothing it sends waits for anything received), a sync every 100 ms, no
/// fault, and the packet carries the pressed emergency stop from the next cycle on. SimpleCAN
/// has no acknowledgement; the ACK bit of every CAN frame is the data-link layer's
/// (ISO 11898-1), which a receiving controller gives whatever the safety layer makes of the
/// frame, and which this bus model, like SimpleCAN, does not look at (SC_REQ_09).
#[test]
fn sc_req_09_a_producer_with_no_consumer_keeps_producing_on_time() {
    let mut net = running(&producer_only());
    let start = net.now;
    net.run_for(Duration::from_millis(1000));
    let pressed = net.now;
    net.set_inputs(1, 0);
    net.run_for(Duration::from_millis(1000));
    assert_eq!(net.faults(1), [None, None]);
    assert_eq!(net.node(1).a.node().nmt_state(), NmtState::Operational);
    let frames = simplecan_frames(&net, start);
    let packets: Vec<&(Instant, CanFrame)> = frames
        .iter()
        .filter(|(_, frame)| frame.id().raw() == u16::from(ESTOP))
        .collect();
    let syncs = frames.len() - packets.len();
    assert_eq!(packets.len(), 200, "one per 10 ms cycle");
    assert!((19..=21).contains(&syncs), "{syncs} syncs in 2 s");
    // Each packet starts at its slot's start, exactly one cycle after the one before.
    let starts: Vec<u64> = packets
        .iter()
        .map(|(end, frame)| end.as_micros() - frame_time(frame, BIT_RATE).as_micros())
        .collect();
    for pair in starts.windows(2) {
        assert_eq!(
            pair[1] - pair[0],
            CYCLE_US,
            "packets starting at {pair:?} µs"
        );
    }
    // The value (bytes 0..4, least significant first): 1 until the press, 0 from the first
    // packet built after it.
    for (at, frame) in &packets {
        assert_eq!(frame.data()[1..4], [0, 0, 0], "{at:?}");
    }
    let value = |(_, frame): &&(Instant, CanFrame)| frame.data()[0];
    let before: Vec<u8> = packets
        .iter()
        .filter(|(at, _)| *at <= pressed)
        .map(value)
        .collect();
    let after: Vec<u8> = packets
        .iter()
        .filter(|(at, _)| at.saturating_since(pressed).as_micros() > CYCLE_US + SLOT_US)
        .map(value)
        .collect();
    assert!(before.iter().all(|&v| v == 1), "{before:?}");
    assert!(
        !after.is_empty() && after.iter().all(|&v| v == 0),
        "{after:?}"
    );
    println!(
        "producer alone: {} packets and {syncs} syncs in 2 s, no fault",
        packets.len()
    );
}
