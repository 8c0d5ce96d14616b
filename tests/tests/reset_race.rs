//! NMT reset node and start of both nodes at every phase of node 1's SRDO cycle, on the
//! dual-channel host network (both channel runtimes, their link, the simulated bus): each
//! channel handles the NMT frames in its own loop, and a plain frame may be in channel A's
//! transmit queue when the reset comes, so that it reaches the bus after the NMT frame. None of
//! that may leave a node in its safe state (CiA 304 9.5, CiA 301 7.2.8.3.1), and a pair left
//! without its inverted frame after the start must still be a transmit mismatch (30h).

use dual_channel::runtime::{ChannelEvent, ChannelFault};
use shared::canopen::nmt::{self, NmtCommand};
use shared::safety::types::SrdoNumber;
use shared::{CanFrame, CanId, Duration, Instant};
use system_tests::bus::{Fault, Injection, Match, frame_time};
use system_tests::dual::{DualNetwork, Side};

/// Node 1's refresh time in [`system_tests::dual::NETWORK_FILE`]: the cycle the sweep covers.
const REFRESH: Duration = Duration::from_millis(25);

/// The sweep's step through the cycle.
const STEP: Duration = Duration::from_micros(100);

/// Node 1's plain and inverted identifiers (SRDO 1, EN 50325-5 Table 5).
const PLAIN: u16 = 0x101;
const INVERTED: u16 = 0x102;

/// Both nodes configured and started, every link byte `link_latency` late (as under the
/// QEMU images' emulation until 2026-12-07, where each channel's loop ran in its own QEMU).
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

/// Node 1's channel A on the bus (node 1 is the network's first node: participant 1).
const NODE_1_A: usize = 1;

/// The bus's bit rate in [`running`].
const BIT_RATE: u32 = 500_000;

/// A frame no node follows (an SDO request to node 127, which is not on the bus), with eight
/// data bytes: it keeps the bus busy.
fn filler() -> CanFrame {
    CanFrame::new(CanId::new(0x67F).expect("identifier"), &[0x55; 8]).expect("frame")
}

/// [`filler`] on an identifier below node 1's plain frame's (an emergency message of node 127,
/// which is not on the bus): it goes on the bus before that frame.
fn high_priority_filler() -> CanFrame {
    CanFrame::new(CanId::new(0x0FF).expect("identifier"), &[0x55; 8]).expect("frame")
}

/// Where the log stood before an NMT command, and when node 1's plain frame of the ended epoch
/// reached the bus.
struct Overtaken {
    log: usize,
    plain_at: Instant,
}

/// Node 1's channel A hands its next plain frame to its controller (announcing it to channel
/// B over the link) while the tool's frames keep the bus busy, and the tool queues NMT reset
/// communication to all nodes right after, with `hold` frames of its own behind it on an
/// identifier below the plain frame's: the NMT frame wins arbitration, and the plain frame,
/// announced before the reset, reaches the bus after it and after the `hold` frames. Asserts
/// that order on the bus.
fn reset_overtaking_a_queued_plain_frame(net: &mut DualNetwork, hold: usize) -> Overtaken {
    until_on_bus(net, PLAIN);
    let (at, frame, _) = *net.trace.last().expect("the plain frame");
    // A hands out its plain frames every refresh time; the bus was idle for the last one.
    let handed = Instant::from_micros(at.as_micros() - frame_time(&frame, BIT_RATE).as_micros());
    let next = handed + REFRESH;
    net.run_until(Instant::from_micros(next.as_micros() - 300));
    net.send_foreign(filler());
    net.send_foreign(filler());
    net.run_until(next);
    assert!(
        net.bus.queued(NODE_1_A) > 0 && net.on_the_bus().any(|(_, f, _)| f == filler()),
        "node 1's plain frame waits in channel A's queue behind the tool's frames"
    );
    let since = (net.log.len(), net.trace.len());
    net.send_foreign(nmt::command_frame(NmtCommand::ResetCommunication, 0));
    for _ in 0..hold {
        net.send_foreign(high_priority_filler());
    }
    until_on_bus(net, PLAIN);
    let frames = &net.trace[since.1..];
    let reset = frames
        .iter()
        .position(|(_, f, _)| f.id().raw() == 0)
        .expect("the NMT command on the bus");
    let plain = frames
        .iter()
        .position(|(_, f, _)| f.id().raw() == PLAIN)
        .expect("the plain frame on the bus");
    assert!(
        reset < plain,
        "the NMT command overtakes the plain frame: {frames:?}"
    );
    let held = frames[reset..plain]
        .iter()
        .filter(|(_, f, _)| *f == high_priority_filler())
        .count();
    assert_eq!(held, hold, "the tool's frames between: {frames:?}");
    Overtaken {
        log: since.0,
        plain_at: frames[plain].0,
    }
}

/// The faults node 1 reported since log position `since`.
fn node_1_faults(net: &DualNetwork, since: usize) -> Vec<(Instant, u8, Side, ChannelFault)> {
    faults(net, since)
        .into_iter()
        .filter(|(_, id, ..)| *id == 1)
        .collect()
}

/// CiA 304 9.5, CiA 301 7.2.8.3.1 (the model's first finding, `docs/model-checking.md`): the
/// NMT reset communication overtakes node 1's plain frame in channel A's transmit queue (A
/// announced it before the reset), right behind the plain frame or held off the bus by two of
/// the tool's frames (so that channel A's heartbeat of the new epoch reaches channel B first),
/// and the master's start follows anywhere from at once to past channel B's window after the
/// plain frame (0 to 6 ms in 100 us steps). The plain frame of the ended epoch is channel A's
/// own, of a pair A cut: channel B neither co-signs it nor reports it as foreign, and both
/// nodes work after the start. Before channel B kept the announcements of A's ended epoch for
/// the frames still to come, the frame found no announcement: foreign (34h) at the end of B's
/// window when A's first plain frame of the new epoch came later (a start from 4.2 ms after
/// the plain frame on), and taken for a copy of that frame otherwise (B then co-signed the
/// new frame against the old one's arrival). Kept only until the entry into Operational, with
/// a start past the window the announcement let A's first frame of the new epoch go by
/// unsigned: a transmit mismatch (30h).
#[test]
fn cia304_9_5_a_plain_frame_overtaken_by_nmt_reset_is_neither_co_signed_nor_foreign() {
    let mut failed = Vec::new();
    for hold in [0, 2] {
        for step in 0..=60 {
            let mut net = running(Duration::ZERO);
            let reset = reset_overtaking_a_queued_plain_frame(&mut net, hold);
            net.run_until(reset.plain_at + Duration::from_micros(step * STEP.as_micros()));
            start(&mut net);
            net.run_for(Duration::from_millis(100));
            let faults = node_1_faults(&net, reset.log);
            if !faults.is_empty() || net.output(33) != 1 {
                failed.push((hold, step, faults, net.output(33)));
            }
        }
    }
    assert!(
        failed.is_empty(),
        "{} starts failed: {failed:?}",
        failed.len()
    );
}

/// While node 1's plain frame is on the bus, the tool queues NMT reset communication and start
/// to all nodes, back to back: they follow the plain frame at once. Returns where the log stood
/// before, and when the reset reached the bus.
fn reset_and_start_behind_a_plain_frame(net: &mut DualNetwork) -> (usize, Instant) {
    let give_up = net.now + Duration::from_millis(200);
    while !net.on_the_bus().any(|(_, f, _)| f.id().raw() == PLAIN) {
        assert!(net.now < give_up, "no plain frame on the bus");
        net.run_for(Duration::from_micros(10));
    }
    let since = net.log.len();
    net.send_foreign(nmt::command_frame(NmtCommand::ResetCommunication, 0));
    start(net);
    until_on_bus(net, 0);
    let reset_at = net.trace.last().expect("the reset").0;
    (since, reset_at)
}

/// The model's second finding (`docs/model-checking.md`, with an input change), CiA 304 9.5:
/// the master resets and starts the network right behind node 1's plain frame, with the link
/// between the channels up to 1 ms late (as under emulation), and both contacts open anywhere
/// from the reset to 1 ms after it: channel B may take the plain frame of the ended epoch
/// before its announcement and reset before the announcement comes, and A's first plain frame
/// of the new epoch, carrying the new sample, may reach B before that announcement or before
/// A's heartbeat of the new epoch. Node 1 reports no fault, and node 33's output follows the
/// press and the release. Before channel B kept the frame it saw before its own reset for the
/// announcement still on the link, that announcement was compared with A's first plain frame
/// of the new epoch, and found it foreign (34h), with the link 0.75 ms late or more and the
/// contacts opened 0.7 ms after the reset or later.
#[test]
fn cia304_9_5_an_input_change_right_after_reset_and_start_behind_a_plain_frame_is_not_foreign() {
    let mut failed = Vec::new();
    for latency in (0..=4).map(|quarter| Duration::from_micros(quarter * 250)) {
        for step in 0..=10 {
            let mut net = running(latency);
            let (log, reset_at) = reset_and_start_behind_a_plain_frame(&mut net);
            net.run_until(reset_at + Duration::from_micros(step * STEP.as_micros()));
            net.set_inputs(1, 0, 0);
            net.run_for(Duration::from_millis(100));
            let pressed = net.output(33);
            net.set_inputs(1, 1, 1);
            net.run_for(Duration::from_millis(100));
            let faults = node_1_faults(&net, log);
            if !faults.is_empty() || pressed != 0 || net.output(33) != 1 {
                failed.push((latency, step, faults, pressed, net.output(33)));
            }
        }
    }
    assert!(
        failed.is_empty(),
        "{} resets failed: {failed:?}",
        failed.len()
    );
}

/// The model's third finding (`docs/model-checking.md`, channel B's loop late), CiA 304 9.5:
/// the master resets and starts the network right behind node 1's plain frame while channel
/// B's loop handles its bus frames late (0.25 to 3 ms), so that it takes A's heartbeat of the
/// new epoch and A's first announcement of the new epoch before the plain frame of the ended
/// epoch. B must not co-sign the old frame against the new announcement, nor find the new
/// frame unannounced: node 1 reports no fault, and node 33's output follows node 1. Before
/// channel B kept the announcements of A's ended epoch for the frames still to come, B did
/// both from a delay of 1 ms on, and reported A's first plain frame of the new epoch as
/// foreign (34h) at the end of its window.
#[test]
fn cia304_9_5_a_late_channel_b_does_not_co_sign_the_ended_epochs_plain_frame() {
    let mut failed = Vec::new();
    for quarter in 1..=12 {
        let delay = Duration::from_micros(quarter * 250);
        let mut net = running(Duration::ZERO);
        let now = net.now;
        net.node_mut(1).receive_faults.push((
            Side::B,
            Injection::new(
                Match {
                    id: None,
                    from: None,
                    after: now,
                    count: None,
                },
                Fault::Delay(delay),
            ),
        ));
        let (log, _) = reset_and_start_behind_a_plain_frame(&mut net);
        net.run_for(Duration::from_millis(100));
        let faults = node_1_faults(&net, log);
        if !faults.is_empty() || net.output(33) != 1 {
            failed.push((delay, faults, net.output(33)));
        }
    }
    assert!(
        failed.is_empty(),
        "{} delays failed: {failed:?}",
        failed.len()
    );
}

/// EN 50325-5 7.2.1, CiA 304 9.5: setting the ended epoch's frame apart lets only that frame go
/// by. In the order of the model's first finding (the reset overtaking node 1's queued plain
/// frame), a foreign device sends on node 1's plain identifier right after that frame, before
/// the start 1 ms later: its copy of the frame, or other data. Node 1 reports the foreign
/// frame (34h) on its plain identifier, and node 33 is in its safe state.
#[test]
fn en50325_5_7_2_1_a_foreign_frame_behind_the_ended_epochs_plain_frame_is_detected() {
    for data in [0x01u8, 0x00] {
        let mut net = running(Duration::ZERO);
        let reset = reset_overtaking_a_queued_plain_frame(&mut net, 0);
        net.send_foreign(
            CanFrame::new(CanId::new(PLAIN).expect("identifier"), &[data]).expect("frame"),
        );
        net.run_until(reset.plain_at + Duration::from_millis(1));
        start(&mut net);
        net.run_for(Duration::from_millis(100));
        let faults = node_1_faults(&net, reset.log);
        assert!(
            faults
                .iter()
                .any(|(.., fault)| *fault == ChannelFault::ForeignFrame { id: PLAIN }),
            "data {data:02X}h: {faults:?}"
        );
        assert_eq!(net.output(33), 0, "node 33 is in its safe state");
    }
}

/// CiA 304 9.5: what channel B's keeping of the ended epoch's announcements costs. Node 1's
/// plain frame is lost on the bus (all receivers miss it: a fault), and the master resets the
/// network 0.5 ms later and starts it after `gap`. The announcement of the lost frame is set
/// apart for a window from A's heartbeat of the new epoch: A's first plain frame after a start
/// within that window carries the same data and goes by unsigned, a transmit mismatch (30h,
/// the safe side: without the reset the lost frame is one too); after a start past it both
/// nodes work. Never a foreign frame.
#[test]
fn cia304_9_5_a_plain_frame_lost_just_before_reset_and_start_is_never_a_foreign_frame() {
    for (gap, works) in [
        (1_000, false),
        (3_000, false),
        (6_000, true),
        (20_000, true),
    ] {
        let mut net = running(Duration::ZERO);
        until_on_bus(&mut net, PLAIN);
        let (at, frame, _) = *net.trace.last().expect("the plain frame");
        let handed =
            Instant::from_micros(at.as_micros() - frame_time(&frame, BIT_RATE).as_micros());
        let now = net.now;
        net.inject(Match::next_with_id(PLAIN, now), Fault::Drop);
        net.run_until(handed + REFRESH + Duration::from_micros(500));
        let since = net.log.len();
        net.send_foreign(nmt::command_frame(NmtCommand::ResetCommunication, 0));
        net.run_for(Duration::from_micros(gap));
        start(&mut net);
        net.run_for(Duration::from_millis(100));
        let faults = node_1_faults(&net, since);
        let mismatch = ChannelFault::TransmitMismatch {
            srdo: SrdoNumber::FIRST,
        };
        if works {
            assert!(faults.is_empty(), "start {gap} us after: {faults:?}");
            assert_eq!(net.output(33), 1, "start {gap} us after");
        } else {
            assert!(
                !faults.is_empty() && faults.iter().all(|(.., fault)| *fault == mismatch),
                "start {gap} us after: {faults:?}"
            );
        }
    }
}

/// Everything node `id` reported that takes it to its safe state since log position `since`:
/// a channel's fault, or its core's SRDO fault (the consumer's pairing, EN 50325-5 7.1).
fn safe_states(net: &DualNetwork, since: usize, id: u8) -> Vec<(Instant, Side, ChannelEvent)> {
    net.log[since..]
        .iter()
        .filter(|(_, node, _, event)| {
            *node == id
                && matches!(
                    event,
                    ChannelEvent::Fault(_)
                        | ChannelEvent::Node(shared::node::Event::SrdoFault(_))
                        | ChannelEvent::Node(shared::node::Event::SafeState(_))
                )
        })
        .map(|(at, _, side, event)| (*at, *side, *event))
        .collect()
}

/// Node 1's channel A hands its next plain frame to its controller while the tool's frames
/// keep the bus busy, and the tool queues NMT reset communication and start to all nodes
/// right after, with `hold` frames of its own behind them on an identifier below the plain
/// frame's: the NMT frames win arbitration over the plain frame, which reaches the bus after
/// the start and the `hold` frames (the model's finding on the consumer's first pair, first
/// variant). Both contacts of node 1 open between the reset and the start. Returns where the
/// log stood before, with the bus trace from the reset to the plain frame.
fn reset_and_start_overtaking_a_queued_plain_frame(
    net: &mut DualNetwork,
    hold: usize,
) -> (usize, Vec<(Instant, CanFrame, usize)>) {
    until_on_bus(net, PLAIN);
    let (at, frame, _) = *net.trace.last().expect("the plain frame");
    let handed = Instant::from_micros(at.as_micros() - frame_time(&frame, BIT_RATE).as_micros());
    let next = handed + REFRESH;
    net.run_until(Instant::from_micros(next.as_micros() - 300));
    net.send_foreign(filler());
    net.send_foreign(filler());
    net.run_until(next);
    assert!(
        net.bus.queued(NODE_1_A) > 0 && net.on_the_bus().any(|(_, f, _)| f == filler()),
        "node 1's plain frame waits in channel A's queue behind the tool's frames"
    );
    let since = (net.log.len(), net.trace.len());
    net.send_foreign(nmt::command_frame(NmtCommand::ResetCommunication, 0));
    net.send_foreign(nmt::command_frame(NmtCommand::Start, 0));
    for _ in 0..hold {
        net.send_foreign(high_priority_filler());
    }
    net.set_inputs(1, 0, 0);
    until_on_bus(net, PLAIN);
    (since.0, net.trace[since.1..].to_vec())
}

/// CiA 304 9.5, EN 50325-5 7.1.2 and 8.2.2 (the model's finding on the consumer's first pair,
/// first variant, `docs/model-checking.md`): NMT reset communication and start both overtake
/// node 1's plain frame in channel A's transmit queue, the tool's frames hold that frame off
/// the bus for 0 to 3 frame times more, and both contacts of node 1 open between the reset
/// and the start. Held long enough for channel A's heartbeat of the new epoch to reach
/// channel B first, the ended epoch's plain frame goes by unsigned (B sets it apart), and
/// node 33, Operational since the start, takes it, then node 1's first plain frame of the new
/// epoch, which carries the open contacts. That pair is node 1's first after the start, and
/// node 33 takes it: no node reports a fault, and node 33's output follows the press and the
/// release. Before a consumer let a plain frame that no pair completed since its entry into
/// Operational be replaced by a later one (SRVT still counted from the first), node 33 took
/// the second plain frame for a sequence error and went to its safe state (SRDO fault 04h),
/// from one of the tool's frames on (with none, channel B co-signed the ended epoch's frame,
/// A's heartbeat not having reached it yet, and node 33 took that pair).
#[test]
fn cia304_9_5_a_plain_frame_overtaken_by_nmt_reset_and_start_does_not_stop_the_consumer() {
    let mut failed = Vec::new();
    let mut unpaired = 0;
    for hold in 0..=3 {
        let mut net = running(Duration::ZERO);
        let (since, frames) = reset_and_start_overtaking_a_queued_plain_frame(&mut net, hold);
        let ids: Vec<u16> = frames.iter().map(|(_, f, _)| f.id().raw()).collect();
        let reset = ids.iter().position(|&id| id == 0).expect("the reset");
        let plain = ids
            .iter()
            .position(|&id| id == PLAIN)
            .expect("the plain frame");
        assert!(
            ids[reset + 1..plain].contains(&0) && frames[plain].1.data() == [1],
            "the reset and the start both go before the ended epoch's plain frame: {frames:?}"
        );
        let trace = net.trace.len();
        net.run_for(Duration::from_millis(100));
        let order: Vec<(u16, Vec<u8>)> = net.trace[trace..]
            .iter()
            .filter(|(_, f, _)| [PLAIN, INVERTED].contains(&f.id().raw()))
            .map(|(_, f, _)| (f.id().raw(), f.data().to_vec()))
            .take(2)
            .collect();
        // The ended epoch's plain frame went by unsigned: the next is the new epoch's.
        unpaired += usize::from(order.first() == Some(&(PLAIN, vec![0])));
        let pressed = net.output(33);
        net.set_inputs(1, 1, 1);
        net.run_for(Duration::from_millis(100));
        let stops: Vec<_> = [1, 33]
            .into_iter()
            .flat_map(|id| safe_states(&net, since, id))
            .collect();
        if !stops.is_empty() || (pressed, net.output(33)) != (0, 1) {
            failed.push((hold, order, stops, pressed, net.output(33)));
        }
    }
    assert!(
        unpaired > 0,
        "some hold lets the ended epoch's plain frame go by unsigned"
    );
    assert!(
        failed.is_empty(),
        "{} holds failed: {failed:#?}",
        failed.len()
    );
}

/// While node 1's plain frame is on the bus, the tool queues NMT reset communication and
/// start to all nodes and, behind them, `hold` frames of its own on an identifier below both
/// of node 1's; both contacts of node 1 open. Channel B co-signs the plain frame when it
/// ends, but its inverted frame waits in B's queue behind the tool's frames, and behind
/// channel A's first plain frame of the new epoch if that comes before they end. Returns
/// where the log stood before.
fn reset_and_start_holding_the_inverted_frame(net: &mut DualNetwork, hold: usize) -> usize {
    let give_up = net.now + Duration::from_millis(200);
    while !net.on_the_bus().any(|(_, f, _)| f.id().raw() == PLAIN) {
        assert!(net.now < give_up, "no plain frame on the bus");
        net.run_for(Duration::from_micros(10));
    }
    let since = net.log.len();
    net.send_foreign(nmt::command_frame(NmtCommand::ResetCommunication, 0));
    net.send_foreign(nmt::command_frame(NmtCommand::Start, 0));
    for _ in 0..hold {
        net.send_foreign(high_priority_filler());
    }
    net.set_inputs(1, 0, 0);
    since
}

/// CiA 304 9.5, EN 50325-5 7.1.2 and 8.2.2 (the model's finding on the consumer's first pair,
/// second variant, `docs/model-checking.md`): the master resets and starts the network right
/// behind node 1's plain frame, which channel B co-signs before its reset, and frames of
/// higher priority than node 1's (a tool's, or other devices' emergency messages) keep the
/// bus busy for 0 to 2 ms after the start, so that B's inverted frame of the pair the reset
/// cut waits in B's transmit queue. Both contacts of node 1 open meanwhile. With the bus busy
/// past node 1's start delay, channel A's first plain frame of the new epoch (the open
/// contacts) goes before that inverted frame, and node 33 sees the new plain frame, then the
/// ended epoch's inverted frame, which is not its inverse, then the new inverted frame. No
/// node reports a fault, and node 33's output follows node 1. Before a consumer left such an
/// inverted frame undelivered until its first pair since entering Operational (the SRVT of
/// the pending plain frame still running), node 33 went to its safe state (SRDO fault 05h,
/// not inverted) from 3 of the tool's frames on.
#[test]
fn cia304_9_5_an_inverted_frame_held_behind_reset_start_and_the_new_plain_frame_does_not_stop_the_consumer()
 {
    let mut failed = Vec::new();
    let mut overtaken = 0;
    for hold in 0..=8 {
        let mut net = running(Duration::ZERO);
        let since = reset_and_start_holding_the_inverted_frame(&mut net, hold);
        let trace = net.trace.len();
        net.run_for(Duration::from_millis(100));
        let order: Vec<(u16, Vec<u8>)> = net.trace[trace..]
            .iter()
            .filter(|(_, f, _)| [PLAIN, INVERTED].contains(&f.id().raw()))
            .map(|(_, f, _)| (f.id().raw(), f.data().to_vec()))
            .take(3)
            .collect();
        overtaken +=
            usize::from(order == [(PLAIN, vec![1]), (PLAIN, vec![0]), (INVERTED, vec![0xFE])]);
        let pressed = net.output(33);
        net.set_inputs(1, 1, 1);
        net.run_for(Duration::from_millis(100));
        let stops: Vec<_> = [1, 33]
            .into_iter()
            .flat_map(|id| safe_states(&net, since, id))
            .collect();
        if !stops.is_empty() || (pressed, net.output(33)) != (0, 1) {
            failed.push((hold, order, stops, pressed, net.output(33)));
        }
    }
    assert!(
        overtaken > 0,
        "some hold puts node 1's new plain frame before the cut pair's inverted frame"
    );
    assert!(
        failed.is_empty(),
        "{} holds failed: {failed:#?}",
        failed.len()
    );
}

/// EN 50325-5 7.2.1, CiA 304 9.5: a consumer that discards, before its first pair, an
/// inverted frame that is not the inverse of its pending plain frame leaves no real fault
/// unseen. After NMT reset and start, a foreign device sends a frame on node 1's inverted
/// identifier with the wrong data while node 1's first plain frame of the new epoch is on the
/// bus: node 1 reports the foreign frame (34h) on that identifier, and node 33 is in its safe
/// state, whichever inverted frame it took first.
#[test]
fn en50325_5_7_2_1_a_wrong_inverted_frame_before_the_consumers_first_pair_is_still_detected() {
    let mut net = running(Duration::ZERO);
    let (since, _) = reset(&mut net, Duration::from_millis(20));
    start(&mut net);
    let give_up = net.now + Duration::from_millis(200);
    while !net.on_the_bus().any(|(_, f, _)| f.id().raw() == PLAIN) {
        assert!(net.now < give_up, "no plain frame after the start");
        net.run_for(Duration::from_micros(10));
    }
    net.send_foreign(
        CanFrame::new(CanId::new(INVERTED).expect("identifier"), &[0x00]).expect("frame"),
    );
    net.run_for(Duration::from_millis(100));
    let faults = node_1_faults(&net, since);
    assert!(
        faults
            .iter()
            .any(|(.., fault)| *fault == ChannelFault::ForeignFrame { id: INVERTED }),
        "{faults:?}"
    );
    assert!(!safe_states(&net, since, 33).is_empty(), "node 33 stops");
    assert_eq!(net.output(33), 0, "node 33 is in its safe state");
}
