//! SimpleCAN's system-level requirements on the host network of two dual-channel nodes
//! (`system_tests::simplecan_dual`) at 500 kbit/s, configured by the configuration tool's own
//! procedure from the safety manual's example network file
//! (`manual/src/examples/simplecan-network.toml`): node 1 is the master and produces the
//! emergency stop (SC-ID 30h, slot 0, its input 6000h:01); node 33 consumes it with a safety
//! timeout of 50 ms into its output 6200h:01. N = 10 slots of 1 ms, a sync every 10 cycles.
//!
//! - SC_REQ_45: the calculator's worst-case reaction for that file bounds the reaction
//!   measured on the network, and the configured safety timeout covers the whole chain.

use safety_config::calc::sfrt::DeviceTiming;
use safety_config::calc::simplecan::{self as calc, ScReaction};
use safety_config::network_file::{self, Network};
use shared::{Duration, Instant};
use system_tests::bus::{Fault, Match};
use system_tests::dual::{LINK_BYTE_TIME, Side};
use system_tests::simplecan_dual::ScDualNetwork;

/// The safety manual's worked example, the file `cargo xtask manual` computes its figures from.
const FILE: &str = include_str!("../../manual/src/examples/simplecan-network.toml");
const BIT_RATE: u32 = 500_000;
const ESTOP: u8 = 0x30;
/// One cycle: N = 10 slots of 1 ms.
const CYCLE_US: u64 = 10_000;

fn file() -> Network {
    network_file::parse(FILE, "simplecan-network.toml").expect("the manual's example parses")
}

/// The host network's devices as the calculator describes a device: the input is the
/// object itself (no sampling, no contact skew), every step takes no time, no output stage;
/// the link between the channels is the simulation's, [`LINK_BYTE_TIME`] a byte.
fn host_timing() -> DeviceTiming {
    DeviceTiming {
        input_sample_us: 0,
        contact_skew_us: 0,
        link_byte_us: LINK_BYTE_TIME.as_micros(),
        processing_us: 0,
        output_us: 0,
    }
}

/// The one consumed SC-ID's bound for the example file on `timing`.
fn bound(timing: &DeviceTiming) -> ScReaction {
    let network = file();
    let simplecan = network.simplecan.as_ref().expect("a [simplecan] section");
    let mut reactions = calc::reactions(simplecan, BIT_RATE, timing).expect("a bound");
    assert_eq!(reactions.len(), 1, "{reactions:?}");
    reactions.remove(0)
}

/// Nodes `ids` configured by the tool from `file`, started, and run until every consumer's
/// output is on (both channels confirmed a value of 1) or, without a consumer, for 1.5 s.
fn running(file: &Network, ids: &[u8]) -> ScDualNetwork {
    let mut net = ScDualNetwork::new(BIT_RATE, ids);
    net.configure_from_file_and_start(file)
        .expect("the tool configures every node");
    let until = net.now + Duration::from_millis(1500);
    let consumer = ids.contains(&33);
    while net.now < until && !(consumer && net.output(33, ESTOP) == 1) {
        net.run_for(Duration::from_millis(1));
    }
    if consumer {
        assert_eq!(
            net.output(33, ESTOP),
            1,
            "faults: {:?} {:?}",
            net.faults(1),
            net.faults(33)
        );
    }
    net
}

/// When node 33's effective output (both channels' outputs in series) went to 0 at or after
/// `from`: the first channel that switched its output off.
fn output_off(net: &ScDualNetwork, from: Instant) -> Option<Instant> {
    net.outputs
        .iter()
        .find(|&&(at, id, _, sc_id, value)| at >= from && id == 33 && sc_id == ESTOP && value == 0)
        .map(|&(at, ..)| at)
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
    let host = bound(&host_timing());
    let mut worst = 0;
    for phase in 0..20u64 {
        let mut net = running(&file(), &[1, 33]);
        net.run_for(Duration::from_micros(phase * 500));
        let pressed = net.now;
        net.set_inputs(1, 0);
        net.run_for(Duration::from_millis(100));
        let off = output_off(&net, pressed).expect("the output goes off");
        let reaction = off.saturating_since(pressed).as_micros();
        assert!(
            reaction <= host.fault_free_us,
            "phase {phase}: measured {reaction} µs, computed {} µs",
            host.fault_free_us
        );
        assert_eq!(net.faults(33), [None, None], "a value of 0 is no fault");
        worst = worst.max(reaction);
    }
    // Every packet after the demand lost at node 33 (both controllers): the value ages out.
    let mut net = running(&file(), &[1, 33]);
    net.run_for(Duration::from_micros(2_500));
    let pressed = net.now;
    let every_packet = Match {
        id: Some(u16::from(ESTOP)),
        from: None,
        after: pressed,
        count: None,
    };
    for side in [Side::A, Side::B] {
        net.inject_receive(33, side, every_packet, Fault::Drop);
    }
    net.set_inputs(1, 0);
    net.run_for(Duration::from_millis(200));
    let off = output_off(&net, pressed).expect("the value ages out");
    let timed_out = off.saturating_since(pressed).as_micros();
    let timeout_us = 50_000;
    assert!(
        timed_out <= host.one_fault_us,
        "measured {timed_out} µs, computed {} µs",
        host.one_fault_us
    );
    assert!(
        timed_out + CYCLE_US >= timeout_us,
        "the output went off {timed_out} µs after the demand, before the timeout could expire"
    );

    let hardware = bound(&DeviceTiming::HARDWARE);
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
        "the fault-free chain, {} µs, is longer than the 50 ms timeout",
        hardware.fault_free_us
    );
    assert_eq!(hardware.worst_us, hardware.one_fault_us);
    println!(
        "SimpleCAN emergency stop, host network: measured worst {worst} µs, computed {} µs; \
         every packet lost: measured {timed_out} µs, computed {} µs; hardware timing: \
         fault-free chain {} µs within the 50 ms timeout, worst case {} µs",
        host.fault_free_us, host.one_fault_us, hardware.fault_free_us, hardware.worst_us
    );
}
