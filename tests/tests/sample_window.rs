//! The sample window holds at every instant of the boards' loop (CiA 304 9.5; the manual's
//! sample-window part of the SFRT): one channel's contact of the producer changes alone at
//! every microsecond across the window around a plain frame's arrival, and a loop iteration
//! beyond it, on the loop network (`system_tests::loop_net`: the boards' own loop, its pins
//! read on every wake-up and at least every millisecond). Whatever the instant, channel B
//! hands the controller an inverted frame only for a value its own pin read less than the
//! window before, and less than the window after the plain frame reached it.

use dual_channel::runtime::SAMPLE_WINDOW;
use safety_config::calc::sfrt::DeviceTiming;
use shared::{CanFrame, Duration, Instant};
use system_tests::loop_net::{Filtering, LoopNetwork};

/// The producer's plain and inverted identifiers ([`system_tests::dual::NETWORK_FILE`]).
const PLAIN: u16 = 0x101;
const INVERTED: u16 = 0x102;

/// A loop iteration beyond the window: the loop reads its pins at least this often.
const ITERATION: Duration = dual_channel::channel_loop::SAMPLE_PERIOD;

/// Node 1 producing, node 33 consuming, both Operational with the contacts closed; the logs
/// the sweep reads start empty.
fn started() -> LoopNetwork {
    let mut net = LoopNetwork::new(500_000, &[1, 33], Filtering::Banks);
    net.configure_and_start().expect("configured");
    net.run_for(Duration::from_millis(200));
    assert!(
        net.nodes
            .iter()
            .all(|node| node.a.is_working() && node.b.is_working())
    );
    net.trace.clear();
    for driver in net
        .nodes
        .iter_mut()
        .flat_map(|node| node.drivers.iter_mut())
    {
        driver.handed.clear();
        driver.readings.clear();
    }
    net
}

/// When the next plain frame of node 1 reaches the bus after `from`, in an undisturbed run.
fn next_plain(net: &LoopNetwork, from: Instant) -> Instant {
    let mut probe = net.clone();
    probe.run_for(Duration::from_millis(60));
    probe
        .trace
        .iter()
        .find(|(at, frame, _)| *at > from && frame.id().raw() == PLAIN)
        .map(|(at, ..)| *at)
        .expect("node 1 sends a plain frame every refresh time")
}

/// What one run shows of channel B's co-signing.
#[derive(Default)]
struct Worst {
    /// The oldest reading of the co-signed value, at the instant the frame was handed over
    /// (µs).
    sample_age: u64,
    /// The longest time from a plain frame's arrival to its inverted frame (µs).
    after_plain: u64,
    /// Inverted frames checked.
    co_signed: usize,
}

/// Checks every inverted frame node 1's channel B handed over in `net`, and folds the
/// worst cases into `worst`; `what` names the run in a failure.
fn check(net: &LoopNetwork, what: &str, worst: &mut Worst) {
    let window = SAMPLE_WINDOW.as_micros();
    let b = &net.node(1).drivers[1];
    for (handed, inverted) in b.handed.iter().filter(|(_, f)| f.id().raw() == INVERTED) {
        let value = !inverted.data()[0] != 0;
        // The newest reading of that value at or before the hand-over.
        let read = b
            .readings
            .iter()
            .filter(|(first, _, level)| *level == value && first <= handed)
            .map(|(_, last, _)| (*last).min(*handed))
            .max();
        let Some(read) = read else {
            panic!("{what}: B co-signed {value} at {handed:?}, a value its pin never read");
        };
        let age = handed.saturating_since(read).as_micros();
        assert!(
            age < window,
            "{what}: B co-signed {value} at {handed:?}, last read {age} µs before (window {window} µs)"
        );
        // The plain frame it answers: the newest one on the bus carrying its inverse.
        let plain: Option<&(Instant, CanFrame, usize)> =
            net.trace.iter().rev().find(|(at, frame, _)| {
                frame.id().raw() == PLAIN && at <= handed && frame.data()[0] == !inverted.data()[0]
            });
        let (arrived, ..) = plain.expect("a plain frame before its inverted frame");
        let gap = handed.saturating_since(*arrived).as_micros();
        assert!(
            gap < window,
            "{what}: B co-signed {gap} µs after the plain frame (window {window} µs)"
        );
        worst.sample_age = worst.sample_age.max(age);
        worst.after_plain = worst.after_plain.max(gap);
        worst.co_signed += 1;
    }
}

/// CiA 304 9.5: one channel's contact opens alone at every microsecond from a window and a
/// loop iteration before a plain frame's arrival to a window and a loop iteration after it,
/// on channel A's pin and on channel B's, and either stays open (stuck, or the first contact
/// of a real demand) or closes again a window later (a flipped reading). B never co-signs a
/// value its pin has not read within the window, never a window or more after the plain
/// frame, and the manual's sample-window part of the SFRT (the calculator's contact skew)
/// covers the oldest sample co-signed.
#[test]
fn cia304_9_5_b_co_signs_only_samples_read_within_the_window_at_every_instant() {
    let net = started();
    let arrival = next_plain(&net, net.now + Duration::from_millis(5));
    let span = SAMPLE_WINDOW.as_micros() + ITERATION.as_micros();
    let first = Instant::from_micros(arrival.as_micros() - span);
    assert!(
        first > net.now,
        "the sweep starts after the network settled"
    );
    let mut base = net.clone();
    base.run_until(first);
    let end = arrival + SAMPLE_WINDOW + SAMPLE_WINDOW + ITERATION + ITERATION;
    let mut worst = Worst::default();
    for side in [0, 1] {
        for lasting in [None, Some(SAMPLE_WINDOW)] {
            for step in 0..=2 * span {
                let at = first + Duration::from_micros(step);
                let mut run = base.clone();
                run.run_until(at);
                run.node_mut(1).drivers[side].input = false;
                if let Some(lasting) = lasting {
                    run.run_until(at + lasting);
                    run.node_mut(1).drivers[side].input = true;
                }
                run.run_until(end);
                let name = if side == 0 { "A" } else { "B" };
                let what = format!("channel {name}'s contact open at {at:?} for {lasting:?}");
                check(&run, &what, &mut worst);
            }
        }
    }
    assert!(worst.co_signed > 0, "the sweep saw channel B co-sign");
    assert!(
        worst.after_plain > 0,
        "the sweep saw channel B hold a plain frame"
    );
    let skew = DeviceTiming::HARDWARE.contact_skew_us;
    assert!(
        worst.sample_age < skew,
        "the oldest sample co-signed ({} µs) is beyond the manual's sample window ({skew} µs)",
        worst.sample_age
    );
    println!(
        "{} inverted frames checked; oldest sample co-signed {} µs, longest plain-to-inverted {} µs",
        worst.co_signed, worst.sample_age, worst.after_plain
    );
}
