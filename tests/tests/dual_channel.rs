//! Two dual-channel nodes on one simulated bus: node 1 (emergency stop, SRDO producer) and
//! node 33 (safe output, SRDO consumer), each channel A and channel B with their link. The
//! scenarios of the firmware and the emulated network, on the host, with the same channel
//! code as the firmware (EN 50325-5 Annex A.4, Model III; CiA 304 9.5).

use dual_channel::crosscheck::CrossFault;
use dual_channel::link::LinkFault;
use dual_channel::runtime::{ChannelEvent, ChannelFault};
use shared::canopen::nmt::{NmtCommand, NmtState};
use shared::node::Event;
use shared::safety::srdo::SrdoFaultCause;
use shared::safety::types::SrdoNumber;
use shared::{Duration, Instant};
use system_tests::bus::{Fault, Injection, Match};
use system_tests::dual::{DualNetwork, Side};

fn running() -> DualNetwork {
    let mut net = DualNetwork::new(500_000, &[1, 33]);
    net.configure_and_start().expect("configuration accepted");
    net.run_for(Duration::from_millis(200));
    net
}

fn fault_of(net: &DualNetwork, since: usize, id: u8) -> Option<(Instant, Side, ChannelFault)> {
    net.first_event(since, id, |_, e| matches!(e, ChannelEvent::Fault(_)))
        .and_then(|(at, side, event)| match event {
            ChannelEvent::Fault(fault) => Some((at, side, fault)),
            _ => None,
        })
}

/// Nominal: every channel Operational and working, node 33's output (both channels in series)
/// follows node 1's input, confirmed by both channels.
#[test]
fn cia304_9_5_nominal_two_dual_channel_nodes_exchange_confirmed_srdos() {
    let net = running();
    for id in [1u8, 33] {
        let node = net.node(id);
        assert_eq!(
            node.a.node().nmt_state(),
            NmtState::Operational,
            "node {id} A"
        );
        assert_eq!(
            node.b.node().nmt_state(),
            NmtState::Operational,
            "node {id} B"
        );
        assert!(
            node.a.is_working() && node.b.is_working(),
            "node {id}: {:?}",
            net.log
        );
    }
    assert_eq!(net.output(33), 1);
    let confirmed = net
        .log
        .iter()
        .filter(|(_, id, _, e)| *id == 33 && matches!(e, ChannelEvent::Confirmed { .. }))
        .count();
    assert!(
        confirmed >= 2 * 6,
        "both channels confirmed every pair: {confirmed}"
    );
    // Channel A sent the plain frames, channel B the inverted ones (participants 1 and 2).
    let senders = |id: u16| {
        net.trace
            .iter()
            .filter(|(_, frame, _)| frame.id().raw() == id)
            .map(|(_, _, from)| *from)
            .collect::<std::collections::BTreeSet<_>>()
    };
    assert_eq!(senders(0x101), [1].into());
    assert_eq!(senders(0x102), [2].into());
}

/// The emergency stop pressed (both contacts open): node 33's output goes to 0 at once, in
/// each channel, without waiting for the cross-check (safe direction first).
#[test]
fn sc_req_05_emergency_stop_reaches_both_output_channels() {
    let mut net = running();
    let pressed = net.now;
    net.set_inputs(1, 0, 0);
    net.run_for(Duration::from_millis(50));
    assert_eq!(net.output(33), 0);
    assert!(net.node(33).a.is_working(), "data, not a fault");
    let off = net
        .log
        .iter()
        .find(|(at, id, _, e)| {
            *at >= pressed
                && *id == 33
                && matches!(e, ChannelEvent::Node(Event::SrdoReceived { data: 0, .. }))
        })
        .map(|(at, ..)| at.saturating_since(pressed))
        .unwrap();
    assert!(off <= Duration::from_millis(1), "{off:?}");
    let since = net.log.len();
    net.set_inputs(1, 1, 1);
    net.run_for(Duration::from_millis(50));
    assert_eq!(net.output(33), 1, "{:?}", &net.log[since..]);
}

/// CiA 304 9.5: channel B of node 1 reads a different input than channel A: B sends no
/// inverted frame, both channels of node 1 report the discrepancy, node 33 goes safe (SRVT).
#[test]
fn cia304_9_5_channel_b_disagreeing_with_channel_a_sends_nothing() {
    let mut net = running();
    let since = net.log.len();
    let from = net.now;
    net.set_inputs(1, 1, 0);
    net.run_for(Duration::from_millis(100));
    let (_, _, fault) = fault_of(&net, since, 1).expect("node 1 reports");
    assert_eq!(
        fault,
        ChannelFault::TransmitMismatch {
            srdo: SrdoNumber::FIRST
        }
    );
    for side in [Side::A, Side::B] {
        assert!(
            net.first_event(since, 1, |s, e| s == side
                && matches!(e, ChannelEvent::Fault(_)))
                .is_some(),
            "channel {side:?} of node 1 reports"
        );
    }
    let inverted_after = net
        .trace
        .iter()
        .filter(|(at, frame, _)| *at > from && frame.id().raw() == 0x102)
        .count();
    assert_eq!(inverted_after, 0, "no inverted frame after the mismatch");
    let consumer = net.first_event(since, 33, |_, e| {
        matches!(e, ChannelEvent::Node(Event::SrdoFault(f)) if f.cause == SrdoFaultCause::SrvtElapsed)
    });
    assert!(
        consumer.is_some(),
        "node 33 detects the missing inverted frame"
    );
    assert_eq!(net.output(33), 0);
    // The node reports it on the bus: EMCY FF02h from node 1 (channel A speaks).
    assert!(net.trace.iter().any(|(at, frame, _)| *at > from
        && frame.id().raw() == 0x081
        && frame.data()[..2] == [0x02, 0xFF]));
}

/// The link between node 33's channels is cut: both channels time out within two link
/// periods and go to the safe state.
#[test]
fn link_cut_puts_both_channels_in_the_safe_state() {
    let mut net = running();
    let since = net.log.len();
    let cut = net.now;
    net.node_mut(33).link_faults.cut = true;
    net.run_for(Duration::from_millis(50));
    for side in [Side::A, Side::B] {
        let (at, _, fault) = net
            .first_event(since, 33, |s, e| {
                s == side && matches!(e, ChannelEvent::Fault(_))
            })
            .and_then(|(at, s, e)| match e {
                ChannelEvent::Fault(f) => Some((at, s, f)),
                _ => None,
            })
            .expect("each channel latches");
        assert_eq!(fault, ChannelFault::Link(LinkFault::Timeout), "{side:?}");
        // Two link periods after the last message received; one already on the wire at the
        // cut still arrives.
        let in_flight =
            dual_channel::link::MAX_WIRE as u64 * system_tests::dual::LINK_BYTE_TIME.as_micros();
        assert!(
            at.saturating_since(cut) <= Duration::from_micros(20_000 + in_flight),
            "{side:?}"
        );
    }
    assert_eq!(net.output(33), 0);
    // And it stays safe while SRDOs keep arriving.
    net.run_for(Duration::from_millis(100));
    assert_eq!(net.output(33), 0);
}

/// CiA 304 9.5: a link that was cut and is mended again, then NMT reset and start, brings node
/// 33 back to work: the reset gives the link a whole time-out from the reset (as at power-on),
/// instead of judging the silence from before it. (The shipped images on the emulated
/// STM32F405 latched a link time-out within a millisecond of the reset.) A link still cut
/// after the reset times out again, and the output stays off.
#[test]
fn cia304_9_5_a_mended_link_works_again_after_nmt_reset() {
    let mut net = running();
    net.node_mut(33).link_faults.cut = true;
    net.run_for(Duration::from_millis(50));
    assert_eq!(net.output(33), 0, "the cut link latched the safe state");

    // Mended at once before the reset: the channels have heard nothing for the whole cut.
    net.node_mut(33).link_faults.cut = false;
    let since = net.log.len();
    net.nmt(NmtCommand::ResetNode, 0);
    net.run_for(Duration::from_millis(100));
    net.nmt(NmtCommand::Start, 0);
    net.run_for(Duration::from_millis(300));
    assert_eq!(
        fault_of(&net, since, 33),
        None,
        "no fault after the reset with the link mended"
    );
    assert_eq!(net.output(33), 1);

    // Cut again and reset: the time-out counts from the reset, and still latches.
    net.node_mut(33).link_faults.cut = true;
    net.run_for(Duration::from_millis(50));
    let since = net.log.len();
    let reset = net.now;
    net.nmt(NmtCommand::ResetNode, 0);
    net.run_for(Duration::from_millis(100));
    let (at, _, fault) = fault_of(&net, since, 33).expect("the cut link times out again");
    assert_eq!(fault, ChannelFault::Link(LinkFault::Timeout));
    assert!(at > reset, "after the reset");
    net.nmt(NmtCommand::Start, 0);
    net.run_for(Duration::from_millis(300));
    assert_eq!(net.output(33), 0);
}

/// A corrupt link message is a fault at once.
#[test]
fn a_corrupt_link_byte_is_a_fault() {
    let mut net = running();
    let since = net.log.len();
    net.node_mut(33).link_faults.corrupt_next_a_to_b = Some(0x04);
    net.run_for(Duration::from_millis(30));
    let (_, side, fault) = fault_of(&net, since, 33).expect("a fault");
    assert_eq!(side, Side::B);
    assert!(
        matches!(
            fault,
            ChannelFault::Link(LinkFault::Corrupt | LinkFault::Malformed)
        ),
        "{fault:?}"
    );
    assert_eq!(net.output(33), 0);
}

/// One channel's CAN controller receives a valid-looking pair with other data (both frames
/// altered alike in its receive path): the verdicts disagree and both channels go safe.
#[test]
fn differing_verdicts_put_both_channels_in_the_safe_state() {
    let mut net = running();
    let since = net.log.len();
    let now = net.now;
    let node = net.node_mut(33);
    for id in [0x101u16, 0x102] {
        node.receive_faults.push((
            Side::A,
            Injection::new(
                Match::next_with_id(id, now),
                Fault::Corrupt {
                    byte: 0,
                    mask: 0x02,
                },
            ),
        ));
    }
    net.run_for(Duration::from_millis(60));
    let (_, _, fault) = fault_of(&net, since, 33).expect("a fault");
    assert!(
        matches!(
            fault,
            ChannelFault::Cross(CrossFault::Disagreement {
                srdo: SrdoNumber::FIRST
            })
        ),
        "{fault:?}"
    );
    assert!(!net.node(33).a.is_working() && !net.node(33).b.is_working());
    assert_eq!(net.output(33), 0);
}

/// NMT reset communication clears the latch in both channels; the node works again.
#[test]
fn nmt_reset_clears_both_channels_together() {
    let mut net = running();
    net.node_mut(33).link_faults.corrupt_next_a_to_b = Some(0x01);
    net.run_for(Duration::from_millis(30));
    assert_eq!(net.output(33), 0);
    net.nmt(NmtCommand::ResetCommunication, 33);
    net.run_for(Duration::from_millis(5));
    net.nmt(NmtCommand::Start, 33);
    net.run_for(Duration::from_millis(100));
    let node = net.node(33);
    assert!(
        node.a.is_working() && node.b.is_working(),
        "{:?} {:?} {:?} {:?}",
        node.a.fault(),
        node.b.fault(),
        node.a.node().fault(),
        node.a.node().nmt_state()
    );
    assert_eq!(net.output(33), 1);
}

/// NMT reset node restores the application objects to their defaults (CiA 301 7.3.2.2.3),
/// the safety inputs among them; each channel writes its current input sample back, so the
/// producer sends the input as it is, not a default, and never a pair whose halves differ.
#[test]
fn nmt_reset_node_keeps_the_producer_sending_the_sampled_input() {
    let mut net = running();
    // A lost inverted frame leaves channel A waiting for it: the reset must end the wait
    // (found on the emulated network: node 1 stayed silent after the reset).
    net.inject(Match::next_with_id(0x102, Instant::ZERO), Fault::Drop);
    net.run_for(Duration::from_millis(150));
    assert_eq!(net.output(33), 0, "SRVT");
    net.nmt(NmtCommand::ResetNode, 0);
    net.run_for(Duration::from_millis(50));
    net.nmt(NmtCommand::Start, 0);
    net.run_for(Duration::from_millis(200));
    for id in [1u8, 33] {
        let node = net.node(id);
        assert!(
            node.a.is_working() && node.b.is_working(),
            "node {id}: {:?} {:?}",
            node.a.fault(),
            node.a.node().fault()
        );
    }
    assert_eq!(net.output(33), 1, "node 1's input is still released");
    net.set_inputs(1, 0, 0);
    net.run_for(Duration::from_millis(20));
    assert_eq!(net.output(33), 0);
}

/// Start-up: channel A's core (the one that speaks for the node) boots only after channel
/// B's has, so the node's boot-up message means both channels follow the bus; a channel
/// whose partner never speaks stays silent and reports the link time-out.
#[test]
fn a_node_announces_itself_only_when_both_channels_are_up() {
    let mut net = DualNetwork::new(500_000, &[1]);
    net.node_mut(1).link_faults.cut = true;
    net.run_for(Duration::from_millis(1500));
    assert!(
        net.trace
            .iter()
            .all(|(_, frame, _)| frame.id().raw() != 0x701),
        "no boot-up while the channels cannot hear each other"
    );
    assert_eq!(
        net.node(1).a.fault(),
        Some(ChannelFault::Link(LinkFault::Timeout))
    );

    let mut net = DualNetwork::new(500_000, &[1]);
    net.run_for(Duration::from_millis(50));
    let boot_up = net
        .trace
        .iter()
        .find(|(_, frame, _)| frame.id().raw() == 0x701 && frame.data() == [0x00])
        .map(|(at, ..)| *at)
        .expect("boot-up once both are up");
    assert_eq!(net.node(1).b.node().nmt_state(), NmtState::PreOperational);
    assert!(boot_up <= Instant::from_millis(30), "{boot_up:?}");
}

/// An output leaves the safe state only after both channels compared their configuration
/// digests in Operational. Each channel sends its digest at once when its NMT state changes,
/// so the comparison is done at Operational entry, before the first pair: that pair already
/// drives the output. (Until 2026-11-30 the digests waited for the next periodic heartbeat
/// and the first pair was withheld; the emulated network showed that the start-up handshake
/// then outlasted the NMT grace.)
#[test]
fn outputs_follow_the_first_pair_once_the_configurations_were_compared_at_operational_entry() {
    let mut net = DualNetwork::new(500_000, &[1, 33]);
    net.configure_and_start().expect("configuration accepted");
    let confirmed = |net: &DualNetwork| {
        net.log.iter().any(|(_, id, side, e)| {
            *id == 33 && *side == Side::A && matches!(e, ChannelEvent::Confirmed { .. })
        })
    };
    let give_up = net.now + Duration::from_millis(100);
    while !confirmed(&net) && net.now < give_up {
        net.run_for(Duration::from_micros(50));
    }
    assert!(confirmed(&net), "a pair was confirmed");
    assert_eq!(
        net.node(33).a.output(SrdoNumber::FIRST),
        1,
        "the first confirmed pair drives the output"
    );
}

/// The two contacts of one emergency stop never open at exactly the same moment: a difference
/// shorter than the discrepancy time is tolerated, a longer one (a stuck or broken contact) is
/// a fault in both channels, even before any SRDO runs.
#[test]
fn input_discrepancy_is_tolerated_briefly_and_latched_when_it_lasts() {
    use dual_channel::runtime::INPUT_DISCREPANCY;
    let mut net = DualNetwork::new(500_000, &[1]);
    net.run_for(Duration::from_millis(50));
    net.set_inputs(1, 1, 1);
    net.run_for(Duration::from_millis(50));
    // Channel A's contact opens first, channel B's 150 ms later: tolerated.
    net.set_inputs(1, 0, 1);
    net.run_for(Duration::from_millis(150));
    net.set_inputs(1, 0, 0);
    net.run_for(Duration::from_millis(300));
    assert_eq!(net.node(1).a.fault(), None);
    assert_eq!(net.node(1).b.fault(), None);
    // Channel B's contact stays closed while A's is open: a fault after the discrepancy time.
    let since = net.now;
    net.set_inputs(1, 1, 0);
    net.run_for(Duration::from_micros(
        INPUT_DISCREPANCY.as_micros() + 50_000,
    ));
    for side in [Side::A, Side::B] {
        let (at, _, event) = net
            .first_event(0, 1, |s, e| {
                s == side && matches!(e, ChannelEvent::Fault(_))
            })
            .expect("each channel latches");
        let ChannelEvent::Fault(fault) = event else {
            unreachable!()
        };
        // The first to see it latches `InputDiscrepancy`; the other may learn it over the link.
        let code = ChannelFault::InputDiscrepancy.cause_code();
        assert!(
            fault == ChannelFault::InputDiscrepancy
                || fault == ChannelFault::PeerSafeState { cause: code },
            "{side:?}: {fault:?}"
        );
        let after = at.saturating_since(since);
        assert!(after >= INPUT_DISCREPANCY, "{side:?} after {after:?}");
        assert!(
            after <= Duration::from_micros(INPUT_DISCREPANCY.as_micros() + 20_000),
            "{side:?} after {after:?}"
        );
    }
}

/// A lasting input difference latched the safe state; the contacts agree again only just
/// after the NMT reset (the other channel's news is on the link behind the reset): the
/// difference from before the reset does not count against the channels after it (found on
/// the emulated network).
#[test]
fn an_input_difference_from_before_a_reset_does_not_latch_after_it() {
    use dual_channel::runtime::INPUT_DISCREPANCY;
    let mut net = running();
    net.set_inputs(1, 1, 0);
    net.run_for(Duration::from_micros(
        INPUT_DISCREPANCY.as_micros() + 100_000,
    ));
    assert!(net.node(1).a.fault().is_some(), "latched");
    let since = net.log.len();
    net.nmt(NmtCommand::ResetNode, 1);
    net.run_for(Duration::from_millis(1));
    net.set_inputs(1, 1, 1);
    net.run_for(Duration::from_millis(50));
    net.nmt(NmtCommand::Start, 1);
    net.run_for(Duration::from_millis(300));
    assert_eq!(fault_of(&net, since, 1), None);
    assert!(net.node(1).a.is_working() && net.node(1).b.is_working());
}

/// CiA 304 9.5: channel A of the producer sees every inverted frame of its node on the bus;
/// one that never comes (lost, or withheld by channel B) breaks the node's pair, and A says
/// so within the refresh time instead of falling silent.
#[test]
fn cia304_9_5_a_lost_inverted_frame_is_reported_by_the_producer() {
    let mut net = running();
    let since = net.log.len();
    net.inject(Match::next_with_id(0x102, net.now), Fault::Drop);
    net.run_for(Duration::from_millis(300));
    let (_, side, fault) = fault_of(&net, since, 1).expect("node 1 reports it");
    assert_eq!(
        (side, fault),
        (
            Side::A,
            ChannelFault::TransmitMismatch {
                srdo: SrdoNumber::FIRST
            }
        )
    );
    assert_eq!(net.output(33), 0);
}

/// The link lags the bus: a channel's safe-state message sent before an NMT reset can arrive
/// after the other channel's reset. It belongs to the epoch before the reset and is ignored;
/// the channels come back together (found on the emulated network, where a stale message
/// latched the safe state again right after the reset).
#[test]
fn a_link_message_from_before_an_nmt_reset_is_ignored_after_it() {
    let mut net = running();
    // Slow, as a producer's link may be: its round trip must stay under the announcement
    // window less the link queue time (`dual_channel::link::round_trip_bound`), which a
    // latency of 1.25 ms each way keeps to (until 2026-12-01 this test ran at 8 ms, before B
    // co-signed only announced frames; then at 4 ms, before the link latency supervision).
    net.node_mut(1).link_faults.latency = Duration::from_micros(1_250);
    net.run_for(Duration::from_millis(50));
    // Channel B of node 1 reads otherwise; the moment one channel latches, the contacts
    // agree again and the reset comes, while its safe-state message is still on the link.
    net.set_inputs(1, 1, 0);
    let give_up = net.now + Duration::from_millis(200);
    while net.node(1).a.fault().is_none() && net.node(1).b.fault().is_none() && net.now < give_up {
        net.run_for(Duration::from_micros(50));
    }
    assert!(
        net.node(1).a.fault().is_some() != net.node(1).b.fault().is_some(),
        "one channel latched, the other has not heard yet"
    );
    net.set_inputs(1, 1, 1);
    let since = net.log.len();
    net.nmt(NmtCommand::ResetNode, 1);
    net.run_for(Duration::from_millis(100));
    net.nmt(NmtCommand::Start, 1);
    net.run_for(Duration::from_millis(200));
    assert_eq!(fault_of(&net, since, 1), None, "{:?}", &net.log[since..]);
    assert!(net.node(1).a.is_working() && net.node(1).b.is_working());
}

/// The two channels of node 33 read different node-IDs from their switches (33 and 34): the
/// node never drives its outputs. Each channel's link heartbeat names its node-ID in force,
/// so the first heartbeats already put both channels in the safe state with the cause in
/// words (`dual_channel::lss::Settings`); channel B, which does not follow the tool's
/// requests for node 33, also keeps unvalidated defaults and refuses Operational.
#[test]
fn channels_with_different_node_ids_never_leave_the_safe_state() {
    use channel_b::role::ChannelB;
    use dual_channel::runtime::Runtime;
    use shared::canopen::storage::RamFlash;
    let mut net = DualNetwork::new(500_000, &[1, 33]);
    net.node_mut(33).b = Runtime::new(
        system_tests::network::device_config(34, "dual node, channel B"),
        RamFlash::new(),
        ChannelB::new(&[(0x6000, 1, 1)]).expect("valid inputs"),
        Instant::ZERO,
        system_tests::dual::LINK_PERIOD,
    )
    .expect("valid device");
    // The tool configures node 33 as usual; only channel A answers it.
    net.configure_and_start()
        .expect("channel A answers the tool");
    for _ in 0..2_000 {
        net.run_for(Duration::from_millis(1));
        let node = net.node(33);
        assert_eq!(
            (
                node.a.output(SrdoNumber::FIRST),
                node.b.output(SrdoNumber::FIRST)
            ),
            (0, 0),
            "at {:?}",
            net.now
        );
    }
    let node = net.node(33);
    assert!(!node.a.is_working() && !node.b.is_working());
    // Each channel says why: B holds unvalidated defaults, A sees the NMT states differ.
    let said = |side: Side, what: &dyn Fn(&ChannelEvent) -> bool| {
        net.log
            .iter()
            .any(|(_, id, s, event)| *id == 33 && *s == side && what(event))
    };
    assert!(said(Side::B, &|e| matches!(
        e,
        ChannelEvent::Node(Event::ConfigurationRefused(fault))
            if fault.error == shared::safety::config::ConfigError::NotDeclaredValid
    )));
    assert!(said(Side::A, &|e| matches!(
        e,
        ChannelEvent::Fault(ChannelFault::Lss(
            dual_channel::lss::LssMismatch::NodeIdDiffers { other, own }
        )) if other.map(|id| id.raw()) == Some(34) && own.map(|id| id.raw()) == Some(33)
    )));
    // Node 1 runs normally: the fault is node 33's alone.
    assert!(net.node(1).a.is_working() && net.node(1).b.is_working());
}

/// How long channel A's loop holds back channel B's inverted frame in the tests of a pair cut
/// by an NMT reset: the reset goes out at most 50 us after the frame, the start 1 ms after
/// the reset, and node 1's first plain frame after the start 0.6 ms later (the bus at
/// 500 kbit/s): A handles the stale frame once Operational, before its new pair.
const STALE: Duration = Duration::from_micros(1_300);

/// Runs `net` until the next frame on `id` is on the bus.
fn until_on_bus(net: &mut DualNetwork, id: u16) {
    let seen = net.trace.len();
    let give_up = net.now + Duration::from_millis(200);
    while !net.trace[seen..].iter().any(|(_, f, _)| f.id().raw() == id) {
        assert!(net.now < give_up, "no frame on {id:03X}h");
        net.run_for(Duration::from_micros(50));
    }
}

/// NMT reset node, then start, as the scenario runner and `cargo xtask e2e` send them.
fn reset_and_start(net: &mut DualNetwork, id: u8) {
    net.nmt(NmtCommand::ResetNode, id);
    net.nmt(NmtCommand::Start, id);
}

/// CiA 304 9.5, EN 50325-5 7.2.1: the NMT reset falls between node 1's plain and inverted
/// frames, and channel A's loop handles channel B's inverted frame of that pair only after
/// the reset and the start (on the emulated network the hub delivers it after both). It is
/// the inverse of the plain frame A sent before the reset: the end of an abandoned pair, not
/// a foreign frame, and the node keeps working.
#[test]
fn cia304_9_5_the_inverted_frame_of_a_pair_cut_by_an_nmt_reset_is_not_foreign() {
    let mut net = running();
    let now = net.now;
    net.node_mut(1).receive_faults.push((
        Side::A,
        Injection::new(Match::next_with_id(0x102, now), Fault::Delay(STALE)),
    ));
    until_on_bus(&mut net, 0x102);
    let since = net.log.len();
    reset_and_start(&mut net, 1);
    net.run_for(Duration::from_millis(300));
    assert_eq!(fault_of(&net, since, 1), None, "{:?}", &net.log[since..]);
    assert!(net.node(1).a.is_working() && net.node(1).b.is_working());
    assert_eq!(net.output(33), 1, "the consumer follows node 1 again");
}

/// EN 50325-5 7.2.1, CiA 304 9.5: masquerade detection is armed right after NMT reset and
/// start, also while a pair cut by the reset may still end: a frame on node 1's inverted
/// identifier that is not the inverse of the pre-reset plain frame, and one on its plain
/// identifier, are foreign.
#[test]
fn en50325_5_7_2_1_a_foreign_frame_right_after_reset_and_start_is_detected() {
    use shared::{CanFrame, CanId};
    for (id, data) in [(0x102u16, 0x5Au8), (0x101, 0x01)] {
        let mut net = running();
        let now = net.now;
        net.node_mut(1).receive_faults.push((
            Side::A,
            Injection::new(Match::next_with_id(0x102, now), Fault::Delay(STALE)),
        ));
        until_on_bus(&mut net, 0x102);
        let since = net.log.len();
        reset_and_start(&mut net, 1);
        net.send_foreign(CanFrame::new(CanId::new(id).unwrap(), &[data]).unwrap());
        net.run_for(Duration::from_millis(300));
        let (_, _, fault) = fault_of(&net, since, 1).expect("node 1 detects it");
        assert_eq!(fault, ChannelFault::ForeignFrame { id }, "on {id:03X}h");
        assert_eq!(net.output(33), 0, "the consumer is in its safe state");
    }
}

/// EN 50325-5 Annex A.4: a channel held by its own flash programs (a store) restarts its
/// link receiver only outside Operational, where nothing the link carries drives an output:
/// in Operational the same report changes nothing. Restarted, the link keeps working: the
/// next messages are counted again and no fault comes of it.
#[test]
fn cia304_9_5_a_channel_deaf_while_storing_restarts_its_link_only_outside_operational() {
    let mut net = DualNetwork::new(500_000, &[1, 33]);
    net.configure_and_start().expect("configuration accepted");
    net.run_for(Duration::from_millis(200));
    assert_eq!(net.node(33).a.node().nmt_state(), NmtState::Operational);
    let late = Instant::from_millis(60_000);
    assert!(!net.node_mut(33).a.link_was_deaf(late));
    assert!(!net.node_mut(33).b.link_was_deaf(late));

    net.nmt(NmtCommand::EnterPreOperational, 0);
    net.run_for(Duration::from_millis(50));
    // The channels' clocks run at the simulation's rate in this network.
    let now = net.now;
    let node = net.node_mut(33);
    assert_eq!(node.a.node().nmt_state(), NmtState::PreOperational);
    assert!(node.a.link_was_deaf(now));
    assert!(node.b.link_was_deaf(now));
    net.run_for(Duration::from_millis(200));
    assert_eq!(net.node(33).a.fault(), None);
    assert_eq!(net.node(33).b.fault(), None);
    net.nmt(NmtCommand::Start, 0);
    net.run_for(Duration::from_millis(200));
    assert_eq!(net.node(33).a.fault(), None);
    assert!(net.node(33).a.node().is_working());
}
