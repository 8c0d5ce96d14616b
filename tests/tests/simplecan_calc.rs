//! The SimpleCAN calculators (`safety_config::calc::simplecan`) against the simulated
//! SimpleCAN network of the campaigns (`system_tests::campaign::simplecan`, the same
//! configuration): the measured emergency stop (input to output) within the computed
//! fault-free bound and close to it, the value at timeout within the one-fault bound, and
//! the residual error rate of `docs/simplecan.md` section 8.

use safety_config::calc::residual::Sil;
use safety_config::calc::sfrt::DeviceTiming;
use safety_config::calc::simplecan::{self as calc, ScReaction};
use safety_config::simplecan::{Consumed, NodeSimpleCan, Produced, SimpleCanNetwork};
use shared::Duration;
use std::collections::BTreeMap;
use system_tests::campaign::simplecan::{self as campaign, ESTOP, SECOND, ScClass, TIMEOUT_MS};
use system_tests::simplecan_net::{INPUT, OUTPUT_1};

/// The campaign's network as a network file's `[simplecan]` section gives it.
fn network(producers: &[(u8, u8, u16)]) -> SimpleCanNetwork {
    let mut nodes = BTreeMap::new();
    for &(node, sc_id, slot) in producers {
        nodes
            .entry(node)
            .or_insert_with(|| NodeSimpleCan {
                potential_master: true,
                ..NodeSimpleCan::default()
            })
            .produced
            .push(Produced {
                sc_id,
                slot,
                object: INPUT,
            });
    }
    nodes.insert(
        3,
        NodeSimpleCan {
            potential_master: false,
            produced: Vec::new(),
            consumed: vec![Consumed {
                sc_id: ESTOP,
                timeout_ms: TIMEOUT_MS,
                object: OUTPUT_1,
            }],
        },
    );
    SimpleCanNetwork {
        network_name: "campaign".into(),
        slots_per_cycle: 10,
        cycles_between_syncs: 10,
        buffering_us: 270,
        nodes,
        hashes: BTreeMap::new(),
    }
}

/// The host simulation's devices: the input is the object itself (no sampling), one
/// channel (no link), every step instant, no output stage.
const SIMULATED: DeviceTiming = DeviceTiming {
    input_sample_us: 0,
    contact_skew_us: 0,
    link_byte_us: 0,
    processing_us: 0,
    output_us: 0,
};

fn estop(timing: &DeviceTiming) -> ScReaction {
    let reactions = calc::reactions(&network(&[(1, ESTOP, 0), (2, SECOND, 3)]), 500_000, timing)
        .expect("a bound");
    assert_eq!(reactions.len(), 1);
    reactions.into_iter().next().expect("one")
}

/// The emergency stop pressed at 40 phases of the 10 ms cycle (every 250 µs): every measured
/// input-to-output time is within the computed fault-free bound, and the worst is within
/// one slot and the buffering of it (the bound is not loose); the lost producer's value at
/// timeout (the campaign's worst) within the one-fault bound (SC_REQ_20).
#[test]
fn sc_req_20_the_computed_reaction_bounds_the_simulated_emergency_stop() {
    let bound = estop(&SIMULATED);
    assert_eq!(bound.fault_free_us, 10_000 + 1_000 + 270);
    let mut worst = 0;
    for phase in 0..40u64 {
        let mut net = campaign::started();
        net.run_for(Duration::from_micros(phase * 250));
        let pressed = net.now;
        net.set_input(1, 0);
        net.run_for(Duration::from_millis(20));
        let (at, value) = *net.devices[net.index_of(3)]
            .outputs
            .last()
            .expect("outputs");
        assert_eq!(value, 0, "phase {phase}");
        let latency = at.saturating_since(pressed).as_micros();
        assert!(
            latency <= bound.fault_free_us,
            "phase {phase}: {latency} µs"
        );
        worst = worst.max(latency);
    }
    assert!(
        worst + 1_000 + 270 >= bound.fault_free_us,
        "worst {worst} µs"
    );
    let lost = campaign::campaign(ScClass::Lost, 0, 20);
    let timed_out = lost.max_latency.expect("detections").as_micros();
    assert!(timed_out <= bound.one_fault_us, "{timed_out} µs");
    println!(
        "emergency stop: measured worst {worst} µs, computed {} µs; value at timeout: measured {timed_out} µs, computed {} µs",
        bound.fault_free_us, bound.one_fault_us
    );
}

/// On the hardware's timing with SimpleCAN's measured step the path adds the input sample,
/// three steps and the link: the parts add up to the total, and the one-fault path is the
/// timeout's.
#[test]
fn sc_req_20_the_hardware_reaction_is_its_parts() {
    let reaction = estop(&DeviceTiming::HARDWARE_SIMPLECAN);
    let sum: u64 = reaction.parts.iter().map(|part| part.micros).sum();
    assert_eq!(sum, reaction.fault_free_us);
    assert!(reaction.one_fault_us > u64::from(TIMEOUT_MS) * 1000);
    assert_eq!(reaction.worst_us, reaction.one_fault_us);
    assert_eq!((reaction.producer, reaction.consumer), (1, 3));
}

/// `docs/simplecan.md` section 8 step 5: N = 10, a sync every 10 cycles, 6 producer slots:
/// ν = 610 /s, Λ_SL = 9.16 × 10⁻¹⁰ /h, within SIL 3's share (10⁻⁹ /h); 7 producer slots:
/// 710 /s, 1.07 × 10⁻⁹ /h, beyond it (SC_REQ_04).
#[test]
fn sc_req_04_the_residual_error_rate_of_a_network_against_sil_3() {
    let six: Vec<_> = (0..6u8).map(|n| (10 + n, 0x30 + n, u16::from(n))).collect();
    let residual = calc::residual(&network(&six), Sil::Sil3);
    assert!((residual.packets_per_second - 610.0).abs() < 1e-9);
    assert!(
        (residual.rate_per_hour - 9.16e-10).abs() < 0.01e-10,
        "{residual:?}"
    );
    assert!((residual.limit_per_hour - 1e-9).abs() < 1e-24);
    assert!(residual.within());
    let seven: Vec<_> = (0..7u8).map(|n| (10 + n, 0x30 + n, u16::from(n))).collect();
    let residual = calc::residual(&network(&seven), Sil::Sil3);
    assert!((residual.packets_per_second - 710.0).abs() < 1e-9);
    assert!(!residual.within(), "{residual:?}");
    assert!(calc::residual(&network(&seven), Sil::Sil2).within());
}

/// A consumed SC-ID nobody produces has no bound, and the error says which.
#[test]
fn sc_req_20_a_consumed_sc_id_without_producer_is_named() {
    let error = calc::reactions(&network(&[(2, SECOND, 3)]), 500_000, &SIMULATED).unwrap_err();
    assert_eq!(
        error.to_string(),
        "node 3 consumes SC-ID 30h, but no node in the file produces it"
    );
}
