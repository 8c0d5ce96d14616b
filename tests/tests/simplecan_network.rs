//! SimpleCAN networks on the simulated bus (500 kbit/s, bit time with stuff bits): devices
//! with the SRDO table and SimpleCAN in their slot, configured by SDO as a tool does
//! (`system_tests::simplecan_net`), each test named after the SC_REQ it verifies.
//!
//! The cycle: N = 10 slots of 1 ms, a sync every 10 cycles (100 ms). SC-ID 30h (node 1, slot
//! 0) is the emergency stop; 38h (node 2, slot 3) a second producer; both nodes are potential
//! masters. Node 3 consumes 30h with a safety timeout of 50 ms and 38h with 1000 ms; node 4
//! consumes 38h with 1000 ms.

use shared::canopen::nmt::NmtCommand;
use shared::node::Event;
use shared::safety::cause::Cause;
use shared::simplecan::ScId;
use shared::simplecan::frame::SYNC_IDENTIFIER;
use shared::{Duration, Instant};
use system_tests::simplecan_net::{
    INPUT, OUTPUT_1, OUTPUT_2, ROLE_CONSUME, ROLE_MASTER, ROLE_PRODUCE, ScConfig, ScEntry,
    ScNetwork,
};

const ESTOP: u8 = 0x30;
const SECOND: u8 = 0x38;
const TIMEOUT_MS: u16 = 50;
/// The longest 8-byte frame at 500 kbit/s: 135 bits, 270 µs. Each SCL states it as its
/// maximum buffering time (SC_REQ_33): a sync is handed in at the end of its frame.
const FRAME_US: u16 = 270;

fn produce(sc_id: u8, slot: u16) -> ScEntry {
    ScEntry {
        sc_id,
        role: ROLE_PRODUCE,
        slot,
        timeout_ms: 0,
        mapped: INPUT,
    }
}

fn consume(sc_id: u8, slot: u16, timeout_ms: u16, mapped: u32) -> ScEntry {
    ScEntry {
        sc_id,
        role: ROLE_CONSUME,
        slot,
        timeout_ms,
        mapped,
    }
}

fn master(sc_id: u8) -> ScEntry {
    ScEntry {
        sc_id,
        role: ROLE_MASTER,
        slot: 0,
        timeout_ms: 0,
        mapped: 0,
    }
}

fn config(potential_master: bool, entries: Vec<ScEntry>) -> ScConfig {
    ScConfig {
        slots: 10,
        sync_every: 10,
        buffering_us: FRAME_US,
        potential_master,
        entries,
    }
}

/// Node 1 (30h, master), node 2 (38h, master, knows 30h), node 3 (consumes 30h with 50 ms,
/// 38h with 1000 ms), node 4 (consumes 38h, 1000 ms): configured, the emergency stop released (input 1), not
/// started.
fn network() -> ScNetwork {
    let mut net = ScNetwork::new(500_000, &[1, 2, 3, 4]);
    net.run_for(Duration::from_millis(10));
    let configs = [
        (1, config(true, vec![produce(ESTOP, 0), master(SECOND)])),
        (2, config(true, vec![produce(SECOND, 3), master(ESTOP)])),
        (
            3,
            config(
                false,
                vec![
                    consume(ESTOP, 0, TIMEOUT_MS, OUTPUT_1),
                    consume(SECOND, 3, 1000, OUTPUT_2),
                ],
            ),
        ),
        (
            4,
            config(
                false,
                vec![consume(SECOND, 3, 1000, OUTPUT_1), master(ESTOP)],
            ),
        ),
    ];
    for (id, config) in &configs {
        net.configure(*id, config).unwrap();
    }
    net.set_input(1, 1);
    net.set_input(2, 1);
    net
}

fn sc(raw: u8) -> ScId {
    ScId::new(raw).unwrap()
}

/// The master SC-ID of each sync on the bus since `since`.
fn syncs_since(net: &ScNetwork, since: Instant) -> Vec<(Instant, u8)> {
    net.sent(SYNC_IDENTIFIER.raw())
        .into_iter()
        .filter(|(start, _, _)| *start >= since)
        .map(|(start, _, frame)| (start, frame.data()[0]))
        .collect()
}

fn working(net: &ScNetwork, ids: &[u8]) {
    for &id in ids {
        assert!(
            net.node(id).is_working(),
            "node {id}: {:?}",
            net.node(id).fault()
        );
    }
}

/// Started together, the lowest SC-ID is the master (SC_REQ_25): 30h sends every sync, 38h
/// heard it before its own t_wait ended and follows. Every SCL is synced to 30h within two
/// sync intervals of the first sync (SC_REQ_30), and the emergency stop's value reaches the
/// consumer.
#[test]
fn sc_req_25_started_together_the_lowest_sc_id_is_the_master() {
    let mut net = network();
    let start = net.now;
    net.nmt(NmtCommand::Start, 0);
    // Time to synchronise: the first instant node 3 has a global time.
    let mut synced_at = None;
    while net.now < start + Duration::from_millis(2_000) {
        net.run_for(Duration::from_micros(100));
        let simplecan = &net.node(3).protocol().simplecan;
        if synced_at.is_none() && simplecan.has_global_time(net.now) {
            synced_at = Some(net.now);
        }
    }
    let syncs = syncs_since(&net, start);
    assert!(syncs.len() >= 14, "{syncs:?}");
    assert!(syncs.iter().all(|&(_, id)| id == ESTOP), "{syncs:?}");
    let first = syncs[0].0;
    // 500 ms of listening and t_wait = 0 for 30h (SC_REQ_25, SC_REQ_27).
    assert!(first >= start + Duration::from_millis(500));
    assert!(first < start + Duration::from_millis(502));
    let synced_at = synced_at.expect("node 3 synchronised");
    let to_sync = synced_at.saturating_since(first);
    assert!(to_sync <= Duration::from_millis(101), "{to_sync:?}");
    println!(
        "time to synchronise: node 3 synced {} µs after the first sync ({} µs after its start)",
        to_sync.as_micros(),
        synced_at.saturating_since(start).as_micros()
    );
    assert!(net.node(1).protocol().simplecan.is_active_master());
    assert!(!net.node(2).protocol().simplecan.is_active_master());
    for id in [2, 3, 4] {
        assert_eq!(
            net.node(id).protocol().simplecan.synced_to(),
            Some(sc(ESTOP))
        );
    }
    working(&net, &[1, 2, 3, 4]);
    assert_eq!(net.devices[net.index_of(3)].outputs.last().unwrap().1, 1);
}

/// A potential master that joins late synchronises to the network's master first and only
/// then takes over, continuing its time (SC_REQ_25): the consumers stay synced throughout,
/// the higher master stops at the lower's first sync, and nobody sees two masters (SC_REQ_26).
#[test]
fn sc_req_25_a_late_joiner_synchronises_first_then_takes_over() {
    let mut net = network();
    net.switch_off(1);
    net.nmt(NmtCommand::Start, 0);
    net.run_for(Duration::from_millis(1_500));
    assert!(
        net.node(2).protocol().simplecan.is_active_master(),
        "{:?} {:?} {:?}",
        net.state(2),
        net.node(2).fault(),
        net.node(2).protocol().simplecan.counters()
    );
    let joined = net.now;
    net.switch_on(1);
    net.run_for(Duration::from_millis(5));
    net.set_input(1, 1);
    net.nmt(NmtCommand::Start, 1);
    net.run_for(Duration::from_millis(1_500));
    let syncs = syncs_since(&net, joined);
    let takeover = syncs
        .iter()
        .position(|&(_, id)| id == ESTOP)
        .expect("30h took over");
    // At least two syncs of 38h heard before its own first (SC_REQ_25, SC_REQ_30).
    assert!(takeover >= 2, "{syncs:?}");
    assert!(
        syncs[takeover..].iter().all(|&(_, id)| id == ESTOP),
        "38h stopped at 30h's first sync: {syncs:?}"
    );
    // The cycle continues: 30h's first sync is a whole number of cycles after 38h's last,
    // within what 30h's time may differ from 38h's: the frame time its buffering time
    // overstates (SC_REQ_33).
    let gap = syncs[takeover].0.saturating_since(syncs[takeover - 1].0);
    let off = gap.as_micros() % 10_000;
    assert!(off.min(10_000 - off) <= u64::from(FRAME_US), "{gap:?}");
    assert!(net.node(1).protocol().simplecan.is_active_master());
    // The master that stepped down produces again once synced to 30h by two syncs
    // (SC_REQ_29, SC_REQ_30): its packets pause for at most one sync interval and a cycle.
    let second: Vec<Instant> = net
        .sent(u16::from(SECOND))
        .into_iter()
        .map(|(start, _, _)| start)
        .filter(|start| *start >= joined)
        .collect();
    let pause = second
        .windows(2)
        .map(|pair| pair[1].saturating_since(pair[0]))
        .max()
        .unwrap();
    assert!(pause <= Duration::from_millis(111), "{pause:?}");
    println!("takeover: 38h paused {} µs", pause.as_micros());
    working(&net, &[1, 2, 3, 4]);
    for id in [3, 4] {
        let lost = net.devices[net.index_of(id)]
            .events
            .iter()
            .any(|(_, event)| matches!(event, Event::SafeState(_)));
        assert!(!lost, "node {id}");
    }
    assert_eq!(net.devices[net.index_of(3)].outputs.last().unwrap().1, 1);
}

/// The master disappears: node 3's value of 30h is 0 within its 50 ms timeout (SC_REQ_20,
/// SC_REQ_05) and it is in the safe state; 2000 ms after the last sync the others are
/// unsynced (SC_REQ_32) and 38h, after its t_wait, is the master (SC_REQ_27); node 4, whose
/// timeout of 38h (1000 ms) outlasts the resynchronisation, keeps its value.
#[test]
fn sc_req_32_a_master_that_disappears_is_replaced_and_its_consumers_time_out() {
    let mut net = network();
    net.nmt(NmtCommand::Start, 0);
    net.run_for(Duration::from_millis(1_500));
    working(&net, &[1, 2, 3, 4]);
    let last_packet = net.sent(u16::from(ESTOP)).last().unwrap().0;
    let last_sync = syncs_since(&net, Instant::ZERO).last().unwrap().0;
    net.switch_off(1);
    net.run_for(Duration::from_millis(3_000));
    let node3 = &net.devices[net.index_of(3)];
    let (zero_at, value) = *node3.outputs.last().unwrap();
    assert_eq!(value, 0);
    // Produced at the start of slot 0, at most the frame's time before it was on the bus.
    let age = zero_at.saturating_since(last_packet);
    assert!(
        age <= Duration::from_millis(u64::from(TIMEOUT_MS)),
        "{age:?}"
    );
    assert_eq!(net.protocol_cause(3), Some(Cause::SimpleCanTimeout.code()));
    let replaced = syncs_since(&net, last_sync + Duration::from_micros(1));
    let (first, id) = replaced[0];
    assert_eq!(id, SECOND);
    let silence = first.saturating_since(last_sync);
    // 2000 ms without a sync, t_wait = (38h − 30h) × 5 ms = 40 ms, then the last slot.
    assert!(silence >= Duration::from_millis(2_040), "{silence:?}");
    assert!(silence <= Duration::from_millis(2_051), "{silence:?}");
    assert!(net.node(2).protocol().simplecan.is_active_master());
    assert!(net.node(4).is_working());
    assert_eq!(
        net.node(4).protocol().simplecan.synced_to(),
        Some(sc(SECOND))
    );
    assert_eq!(net.devices[net.index_of(4)].outputs.last().unwrap().1, 1);
}

/// Node 2 configured without 30h's hash cannot check 30h's syncs, so it never follows and
/// becomes a second active master: everyone who hears both goes to the safe state
/// (SC_REQ_26), and sends nothing from then on (SC_REQ_40).
#[test]
fn sc_req_26_two_active_masters_put_the_network_in_the_safe_state() {
    let mut net = network();
    net.configure(2, &config(true, vec![produce(SECOND, 3)]))
        .unwrap();
    net.nmt(NmtCommand::Start, 0);
    net.run_for(Duration::from_millis(1_000));
    for id in [1, 3, 4] {
        assert_eq!(
            net.protocol_cause(id),
            Some(Cause::SimpleCanSeveralMasters.code()),
            "node {id}"
        );
    }
    let latched = net.devices[net.index_of(1)]
        .events
        .iter()
        .find(|(_, event)| matches!(event, Event::SafeState(_)))
        .unwrap()
        .0;
    let after = net.trace.iter().filter(|(start, _, frame, from)| {
        *from == 1 && *start > latched && (0x02F..=0x07F).contains(&frame.id().raw())
    });
    assert_eq!(after.count(), 0, "node 1 sent after its safe state");
    assert_eq!(net.devices[net.index_of(3)].outputs.last().unwrap().1, 0);
}

/// The emergency stop: pressed (input 0) on node 1, node 3's output follows within one cycle
/// and a frame; the worst age of the value at node 3, sampled every 100 µs over 2 s, against
/// its 50 ms timeout (SC_REQ_20, SC_REQ_45).
#[test]
fn sc_req_20_the_emergency_stop_reaches_the_consumer_with_its_age_within_the_timeout() {
    let mut net = network();
    net.nmt(NmtCommand::Start, 0);
    net.run_for(Duration::from_millis(1_000));
    let mut worst = Duration::ZERO;
    let until = net.now + Duration::from_millis(2_000);
    while net.now < until {
        net.run_for(Duration::from_micros(100));
        let age = net
            .node(3)
            .protocol()
            .simplecan
            .age(sc(ESTOP), net.now)
            .expect("a valid value");
        worst = worst.max(age);
    }
    // One cycle (10 ms) between packets, the age counted from the slot's start.
    assert!(worst < Duration::from_millis(11), "{worst:?}");
    assert!(worst < Duration::from_millis(u64::from(TIMEOUT_MS)));
    let pressed = net.now;
    net.set_input(1, 0);
    net.run_for(Duration::from_millis(20));
    let (at, value) = *net.devices[net.index_of(3)].outputs.last().unwrap();
    assert_eq!(value, 0);
    let latency = at.saturating_since(pressed);
    assert!(latency <= Duration::from_millis(11), "{latency:?}");
    working(&net, &[1, 2, 3, 4]);
    println!(
        "worst age of 30h at node 3: {} µs of a {TIMEOUT_MS} ms timeout; emergency stop: \
         input to output {} µs",
        worst.as_micros(),
        latency.as_micros()
    );
}

/// Every data packet goes on the bus in its own slot of the master's cycle, and is over
/// before the slot ends (SC_REQ_18, section 5): the delay from the slot's start to the
/// frame's start, over 3 s of traffic, is the slot timing jitter.
#[test]
fn sc_req_18_every_packet_is_on_the_bus_within_its_slot() {
    let mut net = network();
    net.nmt(NmtCommand::Start, 0);
    net.run_for(Duration::from_millis(1_000));
    // The master's global time is its local time plus a constant (one clock here).
    let master = &net.node(1).protocol().simplecan;
    let offset = master.global_time(net.now).unwrap() as i64 - net.now.as_micros() as i64;
    let from = net.now;
    net.run_for(Duration::from_millis(3_000));
    for (sc_id, slot) in [(ESTOP, 0u64), (SECOND, 3)] {
        let packets: Vec<_> = net
            .sent(u16::from(sc_id))
            .into_iter()
            .filter(|(start, _, _)| *start >= from)
            .collect();
        assert!(packets.len() >= 299, "{sc_id:02X}h: {}", packets.len());
        let (mut earliest, mut latest) = (i64::MAX, i64::MIN);
        for (start, end, _) in &packets {
            let global = start.as_micros() as i64 + offset;
            // The start of the producer's slot nearest the frame's start.
            let own = slot as i64 * 1_000;
            let slot_start = ((global - own + 5_000).div_euclid(10_000)) * 10_000 + own;
            let into = global - slot_start;
            let end = end.as_micros() as i64 + offset - slot_start;
            // A producer's slot is by its own time, which a receiver of the syncs holds
            // within the frame time its buffering time overstates (SC_REQ_33).
            assert!(
                into >= -i64::from(FRAME_US),
                "{sc_id:02X}h early: {into} µs"
            );
            assert!(end <= 1_000, "{sc_id:02X}h past its slot: {end} µs");
            earliest = earliest.min(into);
            latest = latest.max(into);
        }
        println!(
            "{sc_id:02X}h: {} packets, each on the bus {earliest}..={latest} µs from its slot's \
             start by the master's time",
            packets.len()
        );
    }
    working(&net, &[1, 2, 3, 4]);
    let aborted: u32 = [1, 2]
        .iter()
        .map(|&id| net.node(id).protocol().simplecan.counters().aborted)
        .sum();
    assert_eq!(aborted, 0);
}
