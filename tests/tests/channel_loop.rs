//! The boards' channel loop (`dual_channel::channel_loop`) on simulated bxCAN controllers:
//! the network the other system tests run, but every channel behind its acceptance filters
//! and two receive FIFOs of three frames, its pins driven by the loop.

use dual_channel::runtime::ChannelProtocol;
use dual_channel::runtime::{ChannelEvent, ChannelFault};
use shared::canopen::nmt::{NmtCommand, NmtState};
use shared::{CanFrame, CanId, Duration};
use system_tests::loop_net::{Filtering, LoopNetwork, SimpleCanLoopNetwork};
use system_tests::simplecan_net::{ESTOP, ScConfig, ScEntry};

fn started(filtering: Filtering) -> LoopNetwork {
    let mut net = LoopNetwork::new(500_000, &[1, 33], filtering);
    net.configure_and_start().expect("configured");
    net.run_for(Duration::from_millis(200));
    for node in &net.nodes {
        assert_eq!(node.a.node().nmt_state(), NmtState::Operational);
        assert!(node.a.is_working() && node.b.is_working());
    }
    net
}

fn faults<P: ChannelProtocol<4>>(net: &LoopNetwork<P>) -> Vec<(u8, ChannelFault)> {
    net.nodes
        .iter()
        .flat_map(|node| {
            node.drivers.iter().flat_map(move |driver| {
                driver
                    .events
                    .iter()
                    .filter_map(move |(_, event)| match event {
                        ChannelEvent::Fault(fault) => Some((node.id, *fault)),
                        _ => None,
                    })
            })
        })
        .collect()
}

/// SC_REQ_05, EN 50325-5 7.1: configured by the tool and started, node 33's output pins
/// follow node 1's input pins through the loop (low before the first pair, high while the
/// contacts are closed, low when they open), in both channels.
#[test]
fn sc_req_05_the_output_pins_follow_the_producers_input_pins_through_the_loop() {
    let mut net = started(Filtering::Banks);
    let consumer = net.node(33);
    for driver in &consumer.drivers {
        assert!(driver.output, "energised while the contacts are closed");
        assert_eq!(driver.output_changes.first().map(|c| c.1), Some(false));
    }
    net.press(1, false);
    net.run_for(Duration::from_millis(100));
    for driver in &net.node(33).drivers {
        assert!(!driver.output, "low once the contacts opened");
    }
    net.press(1, true);
    net.run_for(Duration::from_millis(100));
    assert!(net.node(33).drivers.iter().all(|driver| driver.output));
    assert_eq!(faults(&net), []);
}

/// EN 50325-5 7.1.1: with the filters the loop programs, a channel's controller takes only
/// its node's identifiers (and LSS requests, CiA 305): node 33's heartbeats, node 1's SDO
/// answers and every other frame not for it never reach its FIFOs.
#[test]
fn en50325_5_7_1_1_the_controller_rejects_every_frame_the_node_does_not_follow() {
    let net = started(Filtering::Banks);
    for node in &net.nodes {
        let list = node.loops[0].filters().expect("filters applied");
        let ids: Vec<u16> = list.ids().iter().map(|id| id.raw()).collect();
        assert_eq!(
            ids,
            [
                0x000,
                0x001,
                0x101,
                0x102,
                0x600 + u16::from(node.id),
                0x7E5
            ],
            "node {}",
            node.id
        );
        for driver in &node.drivers {
            assert!(driver.rejected > 0, "heartbeats of the others are rejected");
            assert_eq!(driver.lost, 0);
        }
    }
}

/// A babbling higher-priority identifier (080h, the bus 100 % loaded with it) beside node
/// 1's SRDO for 5 s, with loops that get to their FIFOs only every 2 ms: the filters reject
/// it before the FIFOs, so no SRDO frame is lost and nothing goes to the safe state. The
/// same babbler without filters fills the FIFOs, and the loss is the safe state with its
/// own cause (never a silent drop).
#[test]
fn iec61784_3_loss_a_babbling_identifier_cannot_push_an_srdo_out_of_the_receive_queue() {
    let babble = CanFrame::new(CanId::new(0x080).unwrap(), &[]).unwrap();
    let mut net = started(Filtering::Banks);
    net.babbler = Some(babble);
    net.service_interval = Duration::from_millis(2);
    let since = net.trace.len();
    net.run_for(Duration::from_millis(5_000));
    let babbled = net.trace[since..]
        .iter()
        .filter(|(_, frame, _)| frame.id().raw() == 0x080)
        .count();
    let pairs = net.trace[since..]
        .iter()
        .filter(|(_, frame, _)| frame.id().raw() == 0x102)
        .count();
    // A frame without data is 47 bits and stuffing, about 100 us at 500 kbit/s: the bus
    // carried close to 10,000 a second, and node 1's pairs every 25 ms beside them.
    assert!(babbled > 40_000, "{babbled} babbled frames");
    assert!(pairs >= 190, "{pairs} pairs");
    for node in &net.nodes {
        for driver in &node.drivers {
            assert_eq!(driver.lost, 0, "node {}", node.id);
        }
    }
    assert_eq!(faults(&net), []);
    assert!(net.node(33).drivers.iter().all(|driver| driver.output));

    let mut open = started(Filtering::AcceptAll);
    open.babbler = Some(babble);
    open.service_interval = Duration::from_millis(2);
    open.run_for(Duration::from_millis(100));
    let lost: u64 = open.node(33).drivers.iter().map(|driver| driver.lost).sum();
    assert!(lost > 0);
    assert!(
        faults(&open).contains(&(33, ChannelFault::ReceiveOverrun)),
        "{:?}",
        faults(&open)
    );
    assert_eq!(ChannelFault::ReceiveOverrun.cause_code(), 0x3A);
    assert!(open.node(33).drivers.iter().all(|driver| !driver.output));
}

/// EN 50325-5 7.1.2: channel A's controller of node 33 goes bus-off (it neither sent nor
/// received for a while, so safety frames may have gone unseen): the channel goes to the
/// safe state with bus-off's own cause 3Bh, not a receive overrun's, both channels' outputs
/// go low, and the node names the cause in EMCY FF02h (byte 4).
#[test]
fn en50325_5_7_1_2_a_bus_off_controller_is_the_safe_state_with_its_own_cause() {
    let mut net = started(Filtering::Banks);
    let since = net.trace.len();
    net.node_mut(33).drivers[0].bus_off = true;
    net.run_for(Duration::from_millis(50));
    assert_eq!(faults(&net).first(), Some(&(33, ChannelFault::BusOff)));
    assert!(!faults(&net).contains(&(33, ChannelFault::ReceiveOverrun)));
    assert_eq!(ChannelFault::BusOff.cause_code(), 0x3B);
    assert!(net.node(33).drivers.iter().all(|driver| !driver.output));
    assert!(
        net.trace[since..]
            .iter()
            .any(|(_, frame, _)| frame.id().raw() == 0x0A1
                && frame.data()[..2] == [0x02, 0xFF]
                && frame.data()[4] == 0x3B),
        "EMCY FF02h with cause 3Bh from node 33"
    );
}

/// Node 1 the master and producer of 30h in slot 0 (its input 6000h:01), node 33 consuming
/// it with a 50 ms timeout into its output 6200:01; N = 10 slots of 1 ms, a sync every 100 ms,
/// each SCL stating 270 µs of buffering (the longest 8-byte frame at 500 kbit/s); configured
/// by SDO through the loop, started, and run until node 33's output pins are on.
fn simplecan_started() -> SimpleCanLoopNetwork {
    let config = |potential_master, entry| ScConfig {
        slots: 10,
        sync_every: 10,
        buffering_us: 270,
        potential_master,
        entries: vec![entry],
    };
    let producer = ScEntry::ESTOP_PRODUCER;
    let consumer = ScEntry::ESTOP_CONSUMER;
    let mut net = SimpleCanLoopNetwork::new(500_000, &[1, 33], Filtering::Banks);
    net.configure_simplecan_and_start(&[
        (1, config(true, producer)),
        (33, config(false, consumer)),
    ])
    .expect("configured");
    for _ in 0..1500 {
        if net.node(33).drivers.iter().all(|driver| driver.output) {
            break;
        }
        net.run_for(Duration::from_millis(1));
    }
    assert!(
        net.node(33).drivers.iter().all(|driver| driver.output),
        "node 33's output pins on: {:?}",
        faults(&net)
    );
    net
}

/// The instant of the last packet of 30h on the bus (the end of its frame).
fn last_packet(net: &SimpleCanLoopNetwork) -> shared::Instant {
    net.trace
        .iter()
        .rev()
        .find(|(_, frame, _)| frame.id().raw() == u16::from(ESTOP))
        .map(|(at, _, _)| *at)
        .expect("a packet of 30h")
}

/// When node 33's output (its two channels' pins in series) was last switched off.
fn output_off_since(net: &SimpleCanLoopNetwork, since: shared::Instant) -> Option<shared::Instant> {
    net.node(33)
        .drivers
        .iter()
        .filter_map(|driver| {
            driver
                .output_changes
                .iter()
                .find(|(at, level)| *at >= since && !level)
                .map(|(at, _)| *at)
        })
        .min()
}

/// SC_REQ_05, SC_REQ_18, SC_REQ_24: two dual-channel SimpleCAN nodes whose channels run the
/// boards' loop: the loop adds the sync and the node's SC-IDs to the controller's filters,
/// hands the controller's confirmations to the runtime (no packet of 30h withdrawn over 2 s,
/// 200 of them on the bus), and drives node 33's output pins from the consumed value through
/// the device description's pin table (6200h:01, mapped by the SDD entry), in both channels,
/// without a fault.
#[test]
fn sc_req_24_the_loop_drives_a_simplecan_output_pin_from_the_consumed_value() {
    let mut net = simplecan_started();
    for node in &net.nodes {
        let list = node.loops[0].filters().expect("filters applied");
        let ids: Vec<u16> = list.ids().iter().map(|id| id.raw()).collect();
        assert!(ids.contains(&0x02F) && ids.contains(&0x030), "{ids:?}");
    }
    let since = net.trace.len();
    let start = net.now;
    net.run_for(Duration::from_millis(2000));
    let packets = net.trace[since..]
        .iter()
        .filter(|(_, frame, _)| frame.id().raw() == 0x030)
        .count();
    assert_eq!(packets, 200, "one per 10 ms cycle");
    for node in &net.nodes {
        for driver in &node.drivers {
            assert_eq!(driver.aborts, [], "node {}: nothing withdrawn", node.id);
        }
    }
    assert_eq!(output_off_since(&net, start), None);
    assert_eq!(faults(&net), []);
}

/// SC_REQ_05, SC_REQ_20: node 1's emergency stop pressed (both contacts, 5 ms after a packet
/// of 30h, so that both channels sample it before the next slot): node 33's output pins are
/// low within one cycle and one slot (11 ms: the next packet, its frame and the loop's
/// wake-up); released, they are on again within two cycles; no fault on either node.
#[test]
fn sc_req_05_a_simplecan_emergency_stop_switches_the_output_pins_off_and_on_through_the_loop() {
    let mut net = simplecan_started();
    net.run_for(Duration::from_millis(200));
    let pressed = last_packet(&net) + Duration::from_millis(5);
    net.run_until(pressed);
    net.press(1, false);
    net.run_for(Duration::from_millis(30));
    let off = output_off_since(&net, pressed).expect("output off");
    let reaction = off.as_micros() - pressed.as_micros();
    assert!(reaction <= 11_000, "{reaction} µs");
    assert!(net.node(33).drivers.iter().all(|driver| !driver.output));
    net.run_for(Duration::from_millis(100));
    let released = last_packet(&net) + Duration::from_millis(5);
    net.run_until(released);
    net.press(1, true);
    net.run_for(Duration::from_millis(30));
    assert!(net.node(33).drivers.iter().all(|driver| driver.output));
    assert_eq!(faults(&net), []);
}

/// SC_REQ_18, SC_REQ_23: a controller that confirms nothing (node 1's channel A): its core
/// withdraws each packet of 30h at the end of its slot, and the loop hands the withdrawal to
/// the controller (`Driver::abort`), 1 ms after the slot's start; the sync likewise 2 ms
/// after it was handed out.
#[test]
fn sc_req_18_the_loop_hands_the_cores_withdrawal_of_an_unconfirmed_packet_to_the_controller() {
    let mut net = simplecan_started();
    net.node_mut(1).drivers[0].confirms = false;
    let since = net.now;
    net.run_for(Duration::from_millis(250));
    let aborts: Vec<(shared::Instant, u16)> = net.node(1).drivers[0]
        .aborts
        .iter()
        .filter(|(at, _)| *at >= since)
        .copied()
        .collect();
    let packets: Vec<shared::Instant> = net
        .trace
        .iter()
        .filter(|(at, frame, _)| *at >= since && frame.id().raw() == u16::from(ESTOP))
        .map(|(at, _, _)| *at)
        .collect();
    assert!(!packets.is_empty());
    let withdrawn: Vec<&(shared::Instant, u16)> = aborts
        .iter()
        .filter(|(_, id)| *id == u16::from(ESTOP))
        .collect();
    assert!(
        withdrawn.len() + 1 >= packets.len(),
        "{} withdrawals of 30h for {} packets",
        withdrawn.len(),
        packets.len()
    );
    for (at, _) in &withdrawn {
        // The packet's frame ended (270 us or less) after its slot's start; the withdrawal
        // comes at the slot's end.
        let packet = packets
            .iter()
            .rev()
            .find(|end| *end <= at)
            .expect("a packet before");
        let after = at.as_micros() - packet.as_micros();
        assert!(
            (700..=1000).contains(&after),
            "{after} us after the packet's end"
        );
    }
    let sync_withdrawn = aborts
        .iter()
        .find(|(_, id)| *id == 0x02F)
        .map(|(at, _)| *at)
        .expect("the sync withdrawn too");
    let sync_end = net
        .trace
        .iter()
        .rev()
        .find(|(at, frame, _)| *at <= sync_withdrawn && frame.id().raw() == 0x02F)
        .map(|(at, _, _)| *at)
        .expect("the sync on the bus");
    let after = sync_withdrawn.as_micros() - sync_end.as_micros();
    assert!(
        (1700..=2000).contains(&after),
        "sync withdrawn {after} us after its end"
    );
    assert!(
        net.node(1).drivers[1].aborts.is_empty(),
        "channel B sends nothing to withdraw"
    );
}

/// EN 50325-5 Annex A.4: a channel whose processor was held by its own flash programs (a
/// store) drops what its link buffered meanwhile and restarts its receiver, outside
/// Operational only. A damaged link frame that would otherwise latch the safe state then
/// costs nothing; the same frame without that report, or in Operational, is a link fault.
#[test]
fn cia304_9_5_a_channel_deaf_while_storing_drops_what_its_link_buffered_outside_operational() {
    // A frame that decodes (COBS) but fails its CRC.
    let damaged = [0x08, 1, 2, 3, 4, 5, 6, 7, 0x00];
    let link_fault = |net: &LoopNetwork| {
        faults(net)
            .iter()
            .any(|(id, fault)| *id == 33 && matches!(fault, ChannelFault::Link(_)))
    };
    let mut net = started(Filtering::Banks);
    net.nmt(NmtCommand::EnterPreOperational, 0);
    net.run_for(Duration::from_millis(50));
    let driver = &mut net.node_mut(33).drivers[1];
    driver.deaf = true;
    driver.link_arrives(&damaged);
    net.run_for(Duration::from_millis(100));
    assert_eq!(net.node(33).drivers[1].restarts, [true]);
    assert!(!link_fault(&net), "{:?}", faults(&net));
    assert_eq!(net.node(33).b.fault(), None);

    net.node_mut(33).drivers[1].link_arrives(&damaged);
    net.run_for(Duration::from_millis(20));
    assert!(link_fault(&net), "{:?}", faults(&net));

    let mut net = started(Filtering::Banks);
    let driver = &mut net.node_mut(33).drivers[1];
    driver.deaf = true;
    driver.link_arrives(&damaged);
    net.run_for(Duration::from_millis(20));
    assert_eq!(net.node(33).drivers[1].restarts, [false]);
    assert!(link_fault(&net), "{:?}", faults(&net));
}
