//! The reaction-time calculator against the simulation: for the network the reaction-time
//! measurement runs (`system_tests::fullnet::reaction`: node 1 → node 33, refresh 25 ms,
//! SCT 50 ms, SRVT 20 ms), the calculated bound of `safety-config sfrt` must cover every
//! simulated reaction at every bit rate, with and without higher-priority traffic, and stay
//! within a stated factor of the worst one seen (EN 50325-5 9.3.1).

use safety_config::calc::bus::{Stream, frame_micros};
use safety_config::calc::sfrt::{self, DeviceTiming, example_network};
use safety_config::network_file::parse;
use system_tests::bus::BIT_RATES;
use system_tests::dual::LINK_BYTE_TIME;
use system_tests::fullnet::reaction::{
    self, HIGHER_PRIORITY_ID, HIGHER_PRIORITY_SHARE, Path, REFRESH_MS, SCT_MS, SRVT_MS,
};

/// Repetitions per case: enough phases against the refresh cycle to meet the link's
/// heartbeat and the higher-priority frames, few enough for a test (the report runs 200).
const REPETITIONS: u32 = 40;

/// How the simulation runs the channels: sampling, processing and output take no time, both
/// contacts of the input move together, the link as the simulation models it.
fn simulated() -> DeviceTiming {
    DeviceTiming {
        input_sample_us: 0,
        contact_skew_us: 0,
        link_byte_us: LINK_BYTE_TIME.as_micros(),
        processing_us: 0,
        output_us: 0,
    }
}

/// The higher-priority traffic of the measurement, as a stream (`reaction::start`).
fn higher_priority(bit_rate: u32) -> Stream {
    let frame = frame_micros(8, bit_rate);
    Stream {
        id: HIGHER_PRIORITY_ID,
        len: 8,
        period_us: (frame as f64 / HIGHER_PRIORITY_SHARE).ceil() as u64,
    }
}

/// Bound ≥ every simulated value, and bound ≤ factor × the worst simulated value, for each
/// path, bit rate and load. The factors state how far above the worst case seen the
/// calculation may lie (measured with 40 repetitions: event-driven 3.6 to 7.3, GFC 1.1 to
/// 3.8, SCT expiry 1.00 to 1.021). The event-driven bound charges each of the two link
/// crossings with five maximal link messages ahead (1.38 ms at 1 Mbit/s on the link, two of
/// them the latency supervision's probe and echo), which the random phases rarely meet, and
/// every frame with an 8-byte frame of blocking, which an idle bus never has (the GFC's 50 µs
/// at 1 Mbit/s against 190 µs). The SCT path, the one that sets the safety function's worst case, is
/// within 3 % (2.03 % at 1 Mbit/s with higher-priority traffic: channel B co-signs each plain
/// frame against its own announcement, which can come up to five link messages after the
/// frame, and the mute of some phases falls between the plain and the inverted frame, so the
/// pair before counts; the worst of 40 phases is then 49,067 µs against the bound's 50,065).
#[test]
fn en50325_5_9_3_1_the_calculated_bound_covers_every_simulated_reaction() {
    let network = parse(&example_network(REFRESH_MS, SCT_MS, SRVT_MS), "reaction").unwrap();
    let mut report = String::new();
    for bit_rate in BIT_RATES {
        for loaded in [false, true] {
            let extra: Vec<Stream> = if loaded {
                vec![higher_priority(bit_rate)]
            } else {
                vec![]
            };
            let streams = sfrt::planned_streams(&network, None, &extra);
            let bound = &sfrt::reactions(&network, &streams, bit_rate, &simulated()).unwrap()[0];
            for path in Path::ALL {
                let case = reaction::measure(path, bit_rate, loaded, REPETITIONS, 1).unwrap();
                let (calculated, factor) = match path {
                    Path::EventDriven => (bound.fault_free_us, 8.0),
                    Path::Gfc => (bound.gfc_us, 4.0),
                    Path::SctExpiry => (bound.one_fault_us, 1.03),
                };
                let worst = case.times.max_us;
                report.push_str(&format!(
                    "{:<28} {:>4} kbit/s loaded={loaded:<5} simulated max {worst:>6} µs, bound {calculated:>6} µs, {:.2}x\n",
                    path.name(),
                    bit_rate / 1000,
                    calculated as f64 / worst as f64
                ));
                assert!(
                    calculated >= worst,
                    "{} at {bit_rate} bit/s (loaded {loaded}): bound {calculated} µs below the simulated {worst} µs\n{report}",
                    path.name()
                );
                assert!(
                    calculated as f64 <= factor * worst as f64,
                    "{} at {bit_rate} bit/s (loaded {loaded}): bound {calculated} µs more than {factor} × the simulated {worst} µs\n{report}",
                    path.name()
                );
            }
        }
    }
    println!("{report}");
}

/// The calculator's link is the simulation's: one byte at 1 Mbit/s, 10 bits. (The frame
/// times are one function, `safety_config::calc::bus::frame_micros`, which the full
/// network's plan calls and `worst_case_frame_bits_bound_every_frame` checks against the bus
/// model's real stuff bits.)
#[test]
fn the_calculator_models_the_link_as_the_simulation_does() {
    assert_eq!(
        DeviceTiming::HARDWARE.link_byte_us,
        LINK_BYTE_TIME.as_micros()
    );
}
