//! The demo scenario as a system test: two nodes on a simulated bus, configured over SDO,
//! an emergency stop and three injected faults (EN 50325-5 7.1.2, 7.1.3; CiA 304 9.5).

use shared::Duration;
use system_tests::bus::BIT_RATES;
use system_tests::network::Happening;
use system_tests::scenario::{self, OUTPUT_NODE, Silent};

#[test]
fn every_expectation_of_the_demo_holds_at_every_bit_rate() {
    for bit_rate in BIT_RATES {
        let run = scenario::run(bit_rate, &mut Silent);
        for outcome in &run.outcomes {
            assert!(
                outcome.passed,
                "{bit_rate} bit/s: {} ({})",
                outcome.what, outcome.measured
            );
        }
        assert!(run.outcomes.len() >= 19, "the scenario checks what it says");
    }
}

/// The simulation is deterministic: the same scenario gives the same bus trace.
#[test]
fn the_simulation_repeats_exactly() {
    let first = scenario::run(500_000, &mut Silent).network.candump();
    let second = scenario::run(500_000, &mut Silent).network.candump();
    assert_eq!(first, second);
    assert!(first.lines().count() > 100);
}

/// Emergency stop to output 0 takes two SRDO frames on the bus (event-driven SRDO): slower
/// at a lower bit rate, never faster than the frames themselves.
#[test]
fn estop_latency_scales_with_the_frame_time() {
    let slow = scenario::run(125_000, &mut Silent).estop_latency.unwrap();
    let fast = scenario::run(1_000_000, &mut Silent).estop_latency.unwrap();
    assert!(slow > fast, "{slow:?} vs {fast:?}");
    // Two 1-byte frames at 1 Mbit/s: at least 2 × 55 bits.
    assert!(fast >= Duration::from_micros(110), "{fast:?}");
    assert!(slow <= Duration::from_millis(26), "{slow:?}");
}

/// SC_REQ_05: whenever node 33 reports an SRDO fault, its output is 0 at that instant.
#[test]
fn sc_req_05_the_output_is_zero_from_the_moment_of_every_fault() {
    let run = scenario::run(500_000, &mut Silent);
    let log = &run.network.log;
    for (position, (at, device, happening)) in log.iter().enumerate() {
        if *device == Some(OUTPUT_NODE)
            && matches!(
                happening,
                Happening::Event(shared::node::Event::SrdoFault(_))
            )
        {
            let output_zero = log[position..]
                .iter()
                .take_while(|(later, _, _)| later == at)
                .any(|(_, d, h)| *d == Some(OUTPUT_NODE) && *h == Happening::Output(0));
            assert!(
                output_zero,
                "fault at {at:?} without output 0 at the same instant"
            );
        }
    }
}
