//! NMT reset node and start of both nodes at every phase of node 1's SRDO cycle, on the
//! dual-channel host network (both channel runtimes, their link, the simulated bus): each
//! channel handles the NMT frames in its own loop, and a plain frame may be in channel A's
//! transmit queue when the reset comes, so that it reaches the bus after the NMT frame. None of
//! that may leave a node in its safe state (CiA 304 9.5, CiA 301 7.2.8.3.1), and a pair left
//! without its inverted frame after the start must still be a transmit mismatch (30h).

use dual_channel::runtime::{ChannelEvent, ChannelFault};
use shared::canopen::nmt::{self, NmtCommand};
use shared::safety::types::SrdoNumber;
use shared::{Duration, Instant};
use system_tests::bus::{Fault, Match};
use system_tests::dual::{DualNetwork, Side};

/// Node 1's refresh time in [`system_tests::dual::NETWORK_FILE`]: the cycle the sweep covers.
const REFRESH: Duration = Duration::from_millis(25);

/// The sweep's step through the cycle.
const STEP: Duration = Duration::from_micros(100);

/// Node 1's plain and inverted identifiers (SRDO 1, EN 50325-5 Table 5).
const PLAIN: u16 = 0x101;
const INVERTED: u16 = 0x102;

/// Both nodes configured and started, every link byte `link_latency` late (as under
/// emulation, where each channel's loop runs in its own QEMU).
fn running(link_latency: Duration) -> DualNetwork {
    let mut net = DualNetwork::new(500_000, &[1, 33]);
    for id in [1, 33] {
        net.node_mut(id).link_faults.latency = link_latency;
    }
    net.configure_and_start().expect("configuration accepted");
    net.run_for(Duration::from_millis(200));
    net
}

/// Runs `net` until the next frame on `id` is on the bus.
fn until_on_bus(net: &mut DualNetwork, id: u16) {
    let seen = net.trace.len();
    let give_up = net.now + Duration::from_millis(200);
    while !net.trace[seen..].iter().any(|(_, f, _)| f.id().raw() == id) {
        assert!(net.now < give_up, "no frame on {id:03X}h");
        net.run_for(Duration::from_micros(50));
    }
}

/// NMT reset node for all nodes, then `gap` of time, as the scenario player and `cargo xtask
/// e2e` send it (the player waits for both boot-up messages before the start). Returns where
/// the log and the bus trace stood before the reset.
fn reset(net: &mut DualNetwork, gap: Duration) -> (usize, usize) {
    let since = (net.log.len(), net.trace.len());
    net.nmt(NmtCommand::ResetNode, 0);
    net.run_for(gap);
    since
}

/// NMT start for all nodes, put on the bus now (the network does not run).
fn start(net: &mut DualNetwork) {
    net.send_foreign(nmt::command_frame(NmtCommand::Start, 0));
}

/// The faults any channel reported since log position `since`.
fn faults(net: &DualNetwork, since: usize) -> Vec<(Instant, u8, Side, ChannelFault)> {
    net.log[since..]
        .iter()
        .filter_map(|(at, id, side, event)| match event {
            ChannelEvent::Fault(fault) => Some((*at, *id, *side, *fault)),
            _ => None,
        })
        .collect()
}

/// `true` when node 1's channel A put a plain frame on the bus after the NMT reset and before
/// the start (trace from position `since`): it was in A's transmit queue when the reset came.
fn plain_frame_after_the_reset(net: &DualNetwork, since: usize) -> bool {
    let frames = &net.trace[since..];
    let Some(reset) = frames.iter().position(|(_, f, _)| f.id().raw() == 0) else {
        return false;
    };
    frames[reset + 1..]
        .iter()
        .take_while(|(_, f, _)| f.id().raw() != 0)
        .any(|(_, f, _)| f.id().raw() == PLAIN)
}

/// CiA 304 9.5, CiA 301 7.2.8.3.1: NMT reset node and start at every phase of node 1's SRDO
/// cycle (0 to the refresh time in 100 us steps, from the plain frame on the bus), with the
/// start 1 ms and 20 ms after the reset (within the refresh time: a pair the reset cut may
/// still end) and the link as fast as the USART or 1 ms late: both nodes work again after every
/// one, and node 33's output follows node 1. Before channel A let its pair awaited after the
/// start take the inverted frame first, the phases where node 1's plain frame was in A's
/// transmit queue at the reset left node 1 in the safe state with cause 30h one refresh time
/// after the start: the new pair's inverted frame, the inverse of the cut one too, was taken as
/// the cut pair's end.
#[test]
fn cia304_9_5_nmt_reset_and_start_at_every_phase_of_the_srdo_cycle_leave_both_nodes_working() {
    let mut failed = Vec::new();
    let mut queued_at_reset = 0;
    for latency in [Duration::ZERO, Duration::from_millis(1)] {
        for gap in [Duration::from_millis(1), Duration::from_millis(20)] {
            let mut net = running(latency);
            for step in 0..REFRESH.as_micros() / STEP.as_micros() {
                until_on_bus(&mut net, PLAIN);
                net.run_for(Duration::from_micros(step * STEP.as_micros()));
                let (log, trace) = reset(&mut net, gap);
                start(&mut net);
                net.run_for(Duration::from_millis(100));
                queued_at_reset += usize::from(plain_frame_after_the_reset(&net, trace));
                let faults = faults(&net, log);
                if !faults.is_empty() || net.output(33) != 1 {
                    failed.push((latency, gap, step, faults, net.output(33)));
                    // A node in its safe state sends no pairs to take the phase from.
                    net = running(latency);
                }
            }
        }
    }
    assert!(
        queued_at_reset > 0,
        "the sweep reaches the phase where the plain frame waits in A's queue at the reset"
    );
    assert!(
        failed.is_empty(),
        "{} resets failed: {failed:?}",
        failed.len()
    );
}

/// The network reset (the start not sent yet, 20 ms after the reset) at the first phase of the
/// cycle, in [`STEP`]s from node 1's plain frame on the bus, at which the reset finds node 1's
/// plain frame in channel A's transmit queue; with where the log stood before that reset.
fn reset_with_a_plain_frame_queued() -> (DualNetwork, usize) {
    let mut net = running(Duration::ZERO);
    for step in 0..REFRESH.as_micros() / STEP.as_micros() {
        until_on_bus(&mut net, PLAIN);
        net.run_for(Duration::from_micros(step * STEP.as_micros()));
        let (log, trace) = reset(&mut net, Duration::from_millis(20));
        if plain_frame_after_the_reset(&net, trace) {
            return (net, log);
        }
        start(&mut net);
        net.run_for(Duration::from_millis(100));
    }
    panic!("no phase of the cycle finds the plain frame queued at the reset");
}

/// CiA 304 9.5 (rule 4: each channel's frames come back through the other's controller):
/// detection is not weakened by the pair the reset cut. At the phase where the reset finds a
/// plain frame in channel A's queue, channel B's inverted frame of node 1's first pair after
/// the start is lost: channel A still reports the transmit mismatch (30h) one refresh time
/// after that plain frame, channel B follows, and node 33 goes to its safe state.
#[test]
fn cia304_9_5_a_first_pair_after_reset_and_start_without_its_inverted_frame_is_a_transmit_mismatch()
{
    let (mut net, since) = reset_with_a_plain_frame_queued();
    let started = net.now;
    net.inject(Match::next_with_id(INVERTED, started), Fault::Drop);
    start(&mut net);
    net.run_for(Duration::from_millis(300));
    let mismatch = ChannelFault::TransmitMismatch {
        srdo: SrdoNumber::FIRST,
    };
    let node_1: Vec<_> = faults(&net, since)
        .into_iter()
        .filter(|(_, id, ..)| *id == 1)
        .collect();
    let (at, _, side, fault) = *node_1.first().expect("node 1 reports the lost frame");
    assert_eq!((side, fault), (Side::A, mismatch), "{node_1:?}");
    let first_plain = net
        .trace
        .iter()
        .find(|(at, f, _)| *at >= started && f.id().raw() == PLAIN)
        .map(|(at, ..)| *at)
        .expect("node 1's first plain frame after the start");
    assert!(
        at.saturating_since(first_plain) <= Duration::from_micros(REFRESH.as_micros() + 1_000),
        "reported {:?} after the plain frame",
        at.saturating_since(first_plain)
    );
    assert!(
        node_1.iter().any(|(_, _, side, _)| *side == Side::B),
        "channel B follows: {node_1:?}"
    );
    assert_eq!(net.output(33), 0, "node 33 is in its safe state");
}

/// CiA 304 9.5 (rule 2: channel B sends the inverted frame only after a bit-exact match): at
/// the same phase, channel B of node 1 reads its input otherwise right after the start: the
/// first pair after the start is not co-signed, and node 1 latches the transmit mismatch (30h)
/// in both channels while the pair the reset cut is still within its refresh time.
#[test]
fn cia304_9_5_a_real_discrepancy_right_after_reset_and_start_is_a_transmit_mismatch() {
    let (mut net, since) = reset_with_a_plain_frame_queued();
    start(&mut net);
    net.run_for(Duration::from_micros(200));
    net.set_input(1, Side::B, 0);
    net.run_for(Duration::from_millis(300));
    let mismatch = ChannelFault::TransmitMismatch {
        srdo: SrdoNumber::FIRST,
    };
    let node_1: Vec<_> = faults(&net, since)
        .into_iter()
        .filter(|(_, id, ..)| *id == 1)
        .collect();
    for side in [Side::A, Side::B] {
        assert!(
            node_1
                .iter()
                .any(|(_, _, s, fault)| *s == side && *fault == mismatch),
            "channel {side:?}: {node_1:?}"
        );
    }
    assert_eq!(net.output(33), 0, "node 33 is in its safe state");
}

/// EN 50325-5 7.2.1, CiA 304 9.5 (rule 2): channel B co-signs a plain frame only against
/// channel A's announcement of it, and one announcement made before A's reset must not outlive
/// it. NMT reset and start at every phase of node 1's cycle (100 us steps, the link as fast as
/// the USART or 1 ms late), then the emergency stop pressed and released: node 1 reports no
/// fault, and node 33's output follows both changes. Before channel B forgot A's
/// announcements on A's reset, the announcement of a plain frame that B saw before its own
/// reset, or that was still in A's queue at the reset, stayed in its slot: every later frame
/// that reached B before its own announcement was compared with the one before it, and the
/// press was a foreign frame (34h) on node 1's plain identifier.
#[test]
fn en50325_5_7_2_1_an_input_change_after_reset_and_start_at_any_phase_is_not_a_foreign_frame() {
    let mut failed = Vec::new();
    for latency in [Duration::ZERO, Duration::from_millis(1)] {
        let mut net = running(latency);
        for step in 0..REFRESH.as_micros() / STEP.as_micros() {
            until_on_bus(&mut net, PLAIN);
            net.run_for(Duration::from_micros(step * STEP.as_micros()));
            let (log, _) = reset(&mut net, Duration::from_millis(20));
            start(&mut net);
            net.run_for(Duration::from_millis(100));
            net.set_inputs(1, 0, 0);
            net.run_for(Duration::from_millis(100));
            let pressed = net.output(33);
            net.set_inputs(1, 1, 1);
            net.run_for(Duration::from_millis(100));
            let faults: Vec<_> = faults(&net, log)
                .into_iter()
                .filter(|(_, id, ..)| *id == 1)
                .collect();
            if !faults.is_empty() || pressed != 0 || net.output(33) != 1 {
                failed.push((latency, step, faults, pressed, net.output(33)));
                // A node in its safe state sends no pairs to take the phase from.
                net = running(latency);
            }
        }
    }
    assert!(
        failed.is_empty(),
        "{} resets failed: {failed:?}",
        failed.len()
    );
}
