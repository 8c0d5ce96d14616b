//! What runs is what was validated, in both channels (EN 50325-5 8.3.1; CiA 304 9.5): a bit
//! flip in Operational in one channel's identifier table or in one of its records puts both
//! channels of that node in the safe state, outputs 0, within one integrity-check period (the
//! shortest refresh time or SCT of the node's running SRDOs) and the link message that tells
//! the other channel.
//!
//! The flips go through the core's `fault-injection` hooks, which only this test build
//! enables. The oracle reads the channels' reports and outputs, not the check's internals.

use dual_channel::runtime::ChannelEvent;
use shared::node::Event;
use shared::safety::types::SrdoNumber;
use shared::{Duration, Instant};
use system_tests::dual::{DualNetwork, Side};

/// Time for the link message that tells the other channel (about 0.2 ms on the wire), and
/// one poll step of the simulation.
const LINK_MARGIN: Duration = Duration::from_millis(2);

/// Node 1 (producer) and node 33 (consumer) configured, started and exchanging pairs.
fn running() -> DualNetwork {
    let mut net = DualNetwork::new(500_000, &[1, 33]);
    net.configure_and_start().expect("configuration accepted");
    net.run_for(Duration::from_millis(200));
    for id in [1, 33] {
        let node = net.node(id);
        assert!(
            node.a.is_working() && node.b.is_working(),
            "node {id} works before the flip"
        );
    }
    net
}

/// The integrity check's period on node `id`: its shortest refresh time or SCT among the
/// SRDOs it runs (read from the configuration, not from the check).
fn check_period(net: &DualNetwork, id: u8) -> Duration {
    let shortest = net
        .node(id)
        .a
        .node()
        .safety_config()
        .srdos
        .iter()
        .filter(|record| record.direction != 0)
        .map(|record| record.cycle_time)
        .min()
        .expect("a running SRDO");
    Duration::from_millis(u64::from(shortest))
}

/// Both channels of node `id` report a safe state at or after `from`, within `bound`, and
/// drive 0 from then on.
fn both_safe_within(net: &DualNetwork, id: u8, since: usize, from: Instant, bound: Duration) {
    for side in [Side::A, Side::B] {
        let (at, ..) = net
            .first_event(since, id, |s, e| {
                s == side
                    && matches!(
                        e,
                        ChannelEvent::Node(Event::SafeState(_)) | ChannelEvent::Fault(_)
                    )
            })
            .unwrap_or_else(|| panic!("channel {side:?} of node {id} never went safe"));
        let after = at.saturating_since(from);
        assert!(
            after <= bound,
            "channel {side:?} of node {id} safe {after:?} after the flip (bound {bound:?})"
        );
    }
    let node = net.node(id);
    assert!(!node.a.is_working() && !node.b.is_working(), "node {id}");
    assert_eq!(
        node.a.output(SrdoNumber::FIRST),
        0,
        "node {id} channel A output"
    );
    assert_eq!(
        node.b.output(SrdoNumber::FIRST),
        0,
        "node {id} channel B output"
    );
}

fn flip_then_check(id: u8, side: Side, what: &str, flip: impl FnOnce(&mut DualNetwork)) {
    let mut net = running();
    let bound = Duration::from_micros(check_period(&net, id).as_micros() + LINK_MARGIN.as_micros());
    let since = net.log.len();
    let from = net.now;
    flip(&mut net);
    net.run_for(Duration::from_micros(bound.as_micros() + 1_000));
    eprintln!("node {id} channel {side:?}, {what}: bound {bound:?}");
    both_safe_within(&net, id, since, from, bound);
}

/// Every bit of the identifier-table entries of the node's own SRDO identifiers (101h/102h,
/// bytes 0 and 1) and of an unused entry, in either channel of the producer and the consumer.
#[test]
fn en50325_5_8_3_1_an_identifier_table_flip_in_one_channel_takes_both_channels_safe() {
    for id in [1u8, 33] {
        for side in [Side::A, Side::B] {
            for byte in [0usize, 1, 40] {
                for bit in 0..8u8 {
                    let what = format!("identifier table byte {byte} bit {bit}");
                    flip_then_check(id, side, &what, |net| {
                        let node = net.node_mut(id);
                        match side {
                            Side::A => node.a.node_mut().inject_identifier_table_flip(byte, bit),
                            Side::B => node.b.node_mut().inject_identifier_table_flip(byte, bit),
                        }
                    });
                }
            }
        }
    }
}

/// Every bit of the refresh time / SCT of SRDO 1's record, in either channel of the producer
/// and the consumer.
#[test]
fn en50325_5_8_3_1_a_record_flip_in_one_channel_takes_both_channels_safe() {
    for id in [1u8, 33] {
        for side in [Side::A, Side::B] {
            for bit in 0..16u8 {
                let what = format!("SRDO 1 cycle time bit {bit}");
                flip_then_check(id, side, &what, |net| {
                    let node = net.node_mut(id);
                    match side {
                        Side::A => node.a.node_mut().inject_record_flip(0, bit),
                        Side::B => node.b.node_mut().inject_record_flip(0, bit),
                    }
                });
            }
        }
    }
}
