//! The link latency supervision agrees with channel B's co-signing (CiA 304 9.5, EN 50325-5
//! Annex A.4): node 1 (emergency stop, producer) and node 33 (safe output, consumer) on the
//! simulated bus, node 1's link between its channels slowed by a constant latency both ways
//! (`system_tests::dual::LinkFaults::latency`).
//!
//! - over the whole range of latencies the supervision accepts, channel B sees every
//!   announcement in time: no foreign frame, no safe state, the pairs flow;
//! - beyond it, the node goes to the safe state for the link's latency (cause 15h), never for a
//!   foreign frame, and no GFC goes on the bus: whether the link was slow from power-on or
//!   turned slow at any instant of the refresh cycle (as the seeded campaigns inject it).

use dual_channel::link::{BYTE_TIME, LinkFault, MAX_WIRE, round_trip_bound, stamp};
use dual_channel::runtime::{ChannelEvent, ChannelFault, SAMPLE_WINDOW};
use shared::safety::cause::Cause;
use shared::safety::gfc::GFC_ID;
use shared::{Duration, Instant};
use system_tests::dual::{DualNetwork, Side};

/// The producer's plain and inverted identifiers (node 1's predefined pair).
const PLAIN: u16 = 0x101;
const INVERTED: u16 = 0x102;
/// Node 1's refresh time in [`system_tests::dual::NETWORK_FILE`].
const REFRESH: Duration = Duration::from_millis(25);
/// The sweep's step.
const STEP: Duration = Duration::from_micros(250);

/// The round-trip bound of node 1's channels: channel B's window less the link queue time.
fn bound() -> Duration {
    round_trip_bound(SAMPLE_WINDOW)
}

/// The largest constant latency (both ways) the supervision accepts whatever the link
/// carries: a round trip is twice the latency and the bytes of the probe and its echo, each
/// behind at most one heartbeat and one probe of its sender's (the simulation's link sends
/// the messages of one call back to back, the latency counted once for them:
/// `system_tests::dual`), so the round trip stays under the bound up to here.
fn surely_accepted() -> Duration {
    let queued = 4 * MAX_WIRE as u64 * BYTE_TIME.as_micros();
    Duration::from_micros((bound().as_micros() - queued) / 2)
}

/// The smallest constant latency the supervision refuses whatever the link carries: the
/// round trip is at least twice the latency.
fn surely_refused() -> Duration {
    Duration::from_micros(bound().as_micros().div_ceil(2))
}

fn us(micros: u64) -> Duration {
    Duration::from_micros(micros)
}

/// Node 1's link `latency` slow from power-on, both nodes configured and started.
fn started_with(latency: Duration) -> DualNetwork {
    let mut net = DualNetwork::new(500_000, &[1, 33]);
    net.node_mut(1).link_faults.latency = latency;
    net.configure_and_start().expect("configuration accepted");
    net.run_for(Duration::from_millis(200));
    net
}

/// Node 1's emergency stop pressed and released `rounds` times, at spacings that move the
/// changes across the refresh cycle, then 100 ms of quiet.
fn press_and_release(net: &mut DualNetwork, rounds: u64) {
    for round in 0..rounds {
        let value = (round % 2) as u8;
        net.set_inputs(1, value, value);
        net.run_for(us(7_300 + 500 * round));
    }
    net.set_inputs(1, 1, 1);
    net.run_for(Duration::from_millis(100));
}

/// Every fault node `id`'s channels latched since log position `since`.
fn faults(net: &DualNetwork, since: usize, id: u8) -> Vec<(Instant, Side, ChannelFault)> {
    net.log[since..]
        .iter()
        .filter(|(_, node, ..)| *node == id)
        .filter_map(|(at, _, side, event)| match event {
            ChannelEvent::Fault(fault) => Some((*at, *side, *fault)),
            _ => None,
        })
        .collect()
}

/// Whether any channel reported a foreign frame (its own or the other's), or a GFC went on
/// the bus, since the given positions.
fn foreign_or_gfc(net: &DualNetwork, since: usize, trace_since: usize) -> Option<String> {
    let foreign = net.log[since..].iter().find(|(.., event)| match event {
        ChannelEvent::Fault(ChannelFault::ForeignFrame { .. }) => true,
        ChannelEvent::Fault(ChannelFault::PeerSafeState { cause }) => {
            *cause == Cause::ForeignFrame.code()
        }
        _ => false,
    });
    if let Some(found) = foreign {
        return Some(format!("foreign frame reported: {found:?}"));
    }
    net.trace[trace_since..]
        .iter()
        .find(|(_, frame, _)| frame.id() == GFC_ID)
        .map(|found| format!("GFC on the bus: {found:?}"))
}

/// `true` for the link's latency fault, found by the channel itself or by the other one.
fn is_latency(fault: &ChannelFault) -> bool {
    matches!(fault, ChannelFault::Link(LinkFault::Latency))
        || *fault
            == ChannelFault::PeerSafeState {
                cause: Cause::LinkLatency.code(),
            }
}

/// The complete pairs of node 1 on the bus since trace position `since`: a plain frame
/// followed by the next inverted frame carrying its exact inverse.
fn pairs(net: &DualNetwork, since: usize) -> usize {
    let mut count = 0;
    let mut plain = None;
    for (_, frame, _) in &net.trace[since..] {
        match frame.id().raw() {
            PLAIN => plain = Some(*frame),
            INVERTED => {
                if let Some(first) = plain.take() {
                    let inverse = first.data().len() == frame.data().len()
                        && first
                            .data()
                            .iter()
                            .zip(frame.data())
                            .all(|(a, b)| *a == !*b);
                    count += usize::from(inverse);
                }
            }
            _ => {}
        }
    }
    count
}

/// The bounds the sweep relies on are what the supervision's arithmetic gives: the surely
/// accepted latency below the surely refused one, both above zero, and the stamp of a probe
/// the low bits of the clock.
#[test]
fn cia304_9_5_the_latencies_the_sweep_relies_on_are_consistent() {
    assert!(surely_accepted() > Duration::ZERO);
    assert!(surely_accepted() < surely_refused());
    assert!(surely_refused() < SAMPLE_WINDOW);
    assert_eq!(stamp(Instant::from_micros((1 << 32) + 5)), 5);
}

/// CiA 304 9.5, EN 50325-5 Annex A.4: the link latency swept in steps of 250 µs from none to
/// twice the window, node 1's emergency stop pressed and released across the refresh cycle
/// at each. Up to the latency the supervision surely accepts: no fault at all, and the pairs
/// reach node 33 (channel B saw every announcement in time). From the latency it surely
/// refuses: the safe state, for the link's latency. Between the two, either; and at no
/// latency a foreign frame, a GFC, or a safe state for another cause.
#[test]
fn cia304_9_5_a_link_latency_sweep_finds_no_foreign_frame_and_accepts_what_co_signing_bears() {
    let mut accepted = Vec::new();
    let mut refused = Vec::new();
    let mut latency = Duration::ZERO;
    while latency <= Duration::from_micros(2 * SAMPLE_WINDOW.as_micros()) {
        let context = format!("link latency {} µs", latency.as_micros());
        let mut net = started_with(latency);
        let (since, trace_since) = (net.log.len(), net.trace.len());
        press_and_release(&mut net, 12);
        if let Some(found) = foreign_or_gfc(&net, 0, 0) {
            panic!("{context}: {found}");
        }
        let node_1 = faults(&net, 0, 1);
        if node_1.is_empty() {
            assert!(
                latency < surely_refused(),
                "{context}: accepted, the round trip is at least the bound"
            );
            assert!(
                pairs(&net, trace_since) >= 12,
                "{context}: the pairs flow ({})",
                pairs(&net, trace_since)
            );
            accepted.push(latency.as_micros());
        } else {
            assert!(
                latency > surely_accepted(),
                "{context}: refused within what the supervision accepts: {node_1:?}"
            );
            for side in [Side::A, Side::B] {
                let first = node_1.iter().find(|(_, s, _)| *s == side);
                let (_, _, fault) = first.unwrap_or_else(|| panic!("{context}: {side:?} latched"));
                assert!(is_latency(fault), "{context}: {side:?} latched {fault:?}");
            }
            refused.push(latency.as_micros());
        }
        assert_eq!(faults(&net, since, 33), vec![], "{context}: node 33");
        latency = us(latency.as_micros() + STEP.as_micros());
    }
    eprintln!(
        "bound {} µs; accepted up to {:?} µs, refused from {:?} µs",
        bound().as_micros(),
        accepted.last(),
        refused.first()
    );
    assert!(
        accepted.iter().all(|a| refused.iter().all(|r| a < r)),
        "one threshold: accepted {accepted:?}, refused {refused:?}"
    );
}

/// CiA 304 9.5: a latency just past the bound, from power-on: the node goes to the safe state
/// for the link's latency before it ever starts co-signing, node 1's channel A says so on the
/// bus (EMCY FF02h, cause 15h), node 33's output never comes on, and no foreign frame is
/// reported.
#[test]
fn cia304_9_5_a_latency_just_past_the_bound_trips_the_latency_cause_not_a_foreign_frame() {
    let latency = surely_refused();
    let mut net = started_with(latency);
    press_and_release(&mut net, 4);
    assert_eq!(foreign_or_gfc(&net, 0, 0), None);
    let node_1 = faults(&net, 0, 1);
    let first_a = node_1.iter().find(|(_, side, _)| *side == Side::A);
    let (_, _, fault) = first_a.expect("channel A of node 1 latched");
    assert!(is_latency(fault), "{node_1:?}");
    assert!(
        node_1
            .iter()
            .any(|(.., fault)| *fault == ChannelFault::Link(LinkFault::Latency)),
        "a channel found it itself: {node_1:?}"
    );
    assert!(
        net.trace
            .iter()
            .any(|(_, frame, _)| frame.id().raw() == 0x081
                && frame.data()[..2] == [0x02, 0xFF]
                && frame.data()[4] == Cause::LinkLatency.code()),
        "EMCY FF02h with cause 15h (manufacturer-specific byte 1) from node 1"
    );
    assert!(
        net.outputs
            .iter()
            .all(|(.., node, _, _, value)| *node != 33 || *value == 0)
    );
}

/// CiA 304 9.5: the link turns slow while the pairs flow, at every phase of node 1's refresh
/// cycle (in steps of 1 ms) and at latencies from just past the bound to three times the
/// window (those the campaign found channel B reporting channel A's own frame as foreign at,
/// among them): the first fault on each of node 1's channels is the link's latency, no
/// foreign frame is reported and no GFC goes on the bus. Channel B's probe at a plain frame's
/// arrival falls due before its wait for the announcement ends, and the fault is settled
/// first.
#[test]
fn cia304_9_5_a_link_turning_slow_at_any_phase_trips_the_latency_cause_never_a_foreign_frame() {
    let latencies = [
        surely_refused().as_micros(),
        SAMPLE_WINDOW.as_micros() + 250,
        8_820,
        3 * SAMPLE_WINDOW.as_micros(),
    ];
    let base = started_with(Duration::ZERO);
    for latency in latencies {
        for phase_ms in 0..REFRESH.as_micros() / 1_000 {
            let context = format!("latency {latency} µs from phase {phase_ms} ms");
            let mut net = started_with(Duration::ZERO);
            assert_eq!(net.now, base.now, "the same start each time");
            net.run_for(Duration::from_millis(phase_ms));
            let (since, trace_since) = (net.log.len(), net.trace.len());
            net.node_mut(1).link_faults.latency = us(latency);
            net.run_for(Duration::from_millis(100));
            if let Some(found) = foreign_or_gfc(&net, since, trace_since) {
                panic!("{context}: {found}");
            }
            let node_1 = faults(&net, since, 1);
            for side in [Side::A, Side::B] {
                let first = node_1.iter().find(|(_, s, _)| *s == side);
                let (_, _, fault) = first.unwrap_or_else(|| panic!("{context}: {side:?} latched"));
                assert!(is_latency(fault), "{context}: {side:?} latched {fault:?}");
            }
        }
    }
}
