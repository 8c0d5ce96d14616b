//! SimpleCAN fault campaigns at test size (`system_tests::campaign::simplecan`), each class
//! judged by the independent oracle (`system_tests::campaign::simplecan_oracle`, which does
//! not call `shared::simplecan`): no scenario unsafe, and each class's fault met as the
//! requirement says.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use shared::frame::CanId;
use shared::safety::cause::Cause;
use shared::{CanFrame, Duration, Instant};
use system_tests::campaign::simplecan::{
    self, ESTOP, SECOND, ScClass, ScOutcome, ScSummary, TIMEOUT_MS,
};
use system_tests::campaign::simplecan_oracle::{self as oracle, ValidPacket};
use system_tests::simplecan_net::{ScNetwork, node_hash};

const SCENARIOS: u64 = 4;

/// `scenarios` seeds of `class`: none unsafe, spurious or late.
fn passes(class: ScClass, scenarios: u64) -> ScSummary {
    let summary = simplecan::campaign(class, 0, scenarios);
    assert!(summary.passed(), "{}: {summary:?}", class.name());
    println!("{}", simplecan::line(class, &summary));
    summary
}

/// Node 3's output, its SimpleCAN cause if latched, and the oracle's verdict for `class`.
fn verdict(net: &ScNetwork, class: ScClass) -> (u8, Option<u8>, ScOutcome) {
    let output = net.devices[net.index_of(3)]
        .outputs
        .last()
        .expect("an output")
        .1;
    (output, net.protocol_cause(3), simplecan::judge(class, net))
}

fn ms(millis: u64) -> Duration {
    Duration::from_millis(millis)
}

/// The start of the last packet of 30h on the bus.
fn last_packet(net: &ScNetwork) -> Instant {
    net.sent(u16::from(ESTOP))
        .last()
        .expect("a packet of 30h")
        .0
}

/// Every scenario of `class` safe, and every one ending with the output at 0 within the
/// safety timeout of the last valid packet (the producer has left; nothing injected may
/// keep the value alive).
fn safe_and_timed_out(class: ScClass) {
    let summary = passes(class, SCENARIOS);
    assert_eq!(summary.detected, SCENARIOS, "{}: {summary:?}", class.name());
    let worst = summary.max_latency.expect("detections");
    assert!(
        worst <= Duration::from_millis(u64::from(TIMEOUT_MS)),
        "{worst:?}"
    );
    println!(
        "{}: {} injected, worst latency {} µs of {TIMEOUT_MS} ms",
        class.name(),
        summary.injected,
        worst.as_micros()
    );
}

/// The producer gone, the packet it would have sent (value 1, the right stamp, in its slot)
/// with one seeded bit flipped: the CRC-24 refuses it (SC_REQ_42's bad-CRC check), the value
/// is 0 at the timeout.
#[test]
fn sc_req_42_corrupted_packets_never_keep_the_value_past_its_timeout() {
    safe_and_timed_out(ScClass::BadCrc);
}

/// The producer gone, an old packet of 30h (value 1, an earlier cycle's stamp) sent again
/// in the producer's slot is refused: its stamp is not the one of the slot's cycle (SC_REQ_18,
/// `docs/simplecan.md` section 2's cycle stamp).
#[test]
fn sc_req_18_replayed_packets_never_keep_the_value_past_its_timeout() {
    safe_and_timed_out(ScClass::Replay);
}

/// The producer gone, a packet of 30h with the right stamp in the right slot but signed with
/// another SC-ID's node hash is refused (SC_REQ_15).
#[test]
fn sc_req_15_masqueraded_packets_never_keep_the_value_past_its_timeout() {
    safe_and_timed_out(ScClass::Masquerade);
}

/// The producer switched off: the consumer's output is 0 no later than the safety timeout
/// after the last valid packet started (SC_REQ_20).
#[test]
fn sc_req_20_a_lost_producer_gives_0_within_the_safety_timeout() {
    safe_and_timed_out(ScClass::Lost);
}

/// The oracle itself: an output of 1 that outlives the last valid packet of 1 by more than
/// the safety timeout is unsafe at the first instant not backed, and a backed one is not.
#[test]
fn sc_req_20_the_oracle_finds_a_value_held_beyond_its_timeout() {
    let entry = simplecan::monitored();
    let at = |ms: u64| shared::Instant::from_micros(ms * 1_000);
    let valid = [ValidPacket {
        start: at(100),
        end: at(100) + Duration::from_micros(270),
        produced: at(100),
        value: 1,
    }];
    let backed = [(at(100) + Duration::from_micros(300), 1), (at(140), 0)];
    assert_eq!(
        oracle::first_unbacked(&entry, &valid, &backed, at(200)),
        None
    );
    let held = [(at(100) + Duration::from_micros(300), 1)];
    assert_eq!(
        oracle::first_unbacked(&entry, &valid, &held, at(200)),
        Some(at(150) + Duration::from_micros(1))
    );
    let early = [(at(100), 1)];
    assert_eq!(
        oracle::first_unbacked(&entry, &valid, &early, at(120)),
        Some(at(100)),
        "a value before its packet ended"
    );
}

/// The producer gone, the packets it would have sent next put on the bus late (within its
/// slot and the tolerance, past them, or past the safety timeout): none keeps the value
/// beyond the safety timeout of its slot (SC_REQ_20).
#[test]
fn sc_req_20_delayed_packets_never_keep_the_value_past_its_timeout() {
    safe_and_timed_out(ScClass::Delay);
}

/// A packet 1 ms late is still within its slot and the 2 ms tolerance: taken, its value's
/// age counted from its slot, so the output's 0 comes one cycle later than without it. One
/// 4 ms late is refused: the output is 0 at the timeout of the last packet node 1 sent
/// (SC_REQ_20, SC_REQ_18, `docs/simplecan.md` section 5).
#[test]
fn sc_req_20_a_packet_late_within_the_slot_tolerance_is_taken_and_one_later_is_not() {
    for (late, taken) in [(ms(1), true), (ms(4), false)] {
        let mut net = simplecan::started();
        let last = last_packet(&net);
        assert_eq!(simplecan::delayed(&mut net, &[late]), 1);
        let (output, cause, outcome) = verdict(&net, ScClass::Delay);
        assert_eq!((output, cause), (0, Some(Cause::SimpleCanTimeout.code())));
        let zero = net.devices[net.index_of(3)].outputs.last().unwrap().0;
        let after = zero.saturating_since(last);
        // The consumer's clock leads the bus by its buffering time beyond the sync frame's.
        let timeout = ms(u64::from(TIMEOUT_MS));
        let expected = if taken {
            ms(u64::from(TIMEOUT_MS) + 10)
        } else {
            timeout
        };
        assert!(
            after <= expected && after.as_micros() + 100 >= expected.as_micros(),
            "{late:?} late: 0 after {after:?}"
        );
        assert!(
            matches!(outcome, ScOutcome::Detected(latency) if latency <= timeout),
            "{outcome:?}"
        );
    }
}

/// A higher-priority identifier hogging the bus: every seeded scenario safe, no safe state
/// while the value was still young (SC_REQ_20).
#[test]
fn sc_req_20_a_babbling_higher_priority_identifier_never_keeps_a_stale_value() {
    passes(ScClass::Babbling, SCENARIOS);
}

/// 10 ms of babbling on 010h delay a packet or withdraw one (SC_REQ_18): the consumer rides
/// through. 100 ms starve it: 0 at the safety timeout of the last packet that got through
/// (SC_REQ_20), and latched.
#[test]
fn sc_req_20_ten_ms_of_babbling_change_nothing_and_a_hundred_ms_give_0_at_the_timeout() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut net = simplecan::started();
    simplecan::babble(&mut net, 0x010, ms(10), &mut rng);
    assert_eq!(
        verdict(&net, ScClass::Babbling),
        (1, None, ScOutcome::Harmless)
    );
    let mut net = simplecan::started();
    simplecan::babble(&mut net, 0x010, ms(100), &mut rng);
    let (output, cause, outcome) = verdict(&net, ScClass::Babbling);
    assert_eq!((output, cause), (0, Some(Cause::SimpleCanTimeout.code())));
    assert!(
        matches!(outcome, ScOutcome::Detected(latency) if latency <= ms(50)),
        "{outcome:?}"
    );
}

/// Every sync lost for a while: every seeded scenario safe, none unsynced early (SC_REQ_32).
#[test]
fn sc_req_32_lost_syncs_never_leave_a_consumer_synced_beyond_2000_ms() {
    passes(ScClass::SyncLoss, SCENARIOS);
}

/// 1500 ms without a sync: the consumer stays synced and its value flows. 2500 ms: it is
/// unsynced 2000 ms after the last sync it heard, discards the producer's packets from then
/// on (SC_REQ_29), and its value is 0 within the safety timeout after that (SC_REQ_32).
#[test]
fn sc_req_32_a_consumer_is_unsynced_2000_ms_after_its_last_sync_and_not_before() {
    let mut net = simplecan::started();
    simplecan::lose_syncs(&mut net, ms(1_500));
    assert_eq!(
        verdict(&net, ScClass::SyncLoss),
        (1, None, ScOutcome::Harmless)
    );
    let mut net = simplecan::started();
    simplecan::lose_syncs(&mut net, ms(2_500));
    let (output, cause, outcome) = verdict(&net, ScClass::SyncLoss);
    assert_eq!((output, cause), (0, Some(Cause::SimpleCanTimeout.code())));
    let ScOutcome::Detected(latency) = outcome else {
        panic!("{outcome:?}");
    };
    assert!(latency >= ms(2_000) && latency <= ms(2_050), "{latency:?}");
}

/// A second master's checked syncs: every seeded scenario puts the consumer in the safe
/// state at the first one (SC_REQ_26).
#[test]
fn sc_req_26_a_second_masters_sync_puts_the_consumer_in_the_safe_state_at_once() {
    let summary = passes(ScClass::TwoMasters, SCENARIOS);
    assert_eq!(summary.detected, SCENARIOS);
    let mut net = simplecan::started();
    simplecan::second_master(&mut net, None, 0);
    net.run_for(ms(100));
    let (output, cause, outcome) = verdict(&net, ScClass::TwoMasters);
    assert_eq!(
        (output, cause),
        (0, Some(Cause::SimpleCanSeveralMasters.code()))
    );
    assert!(
        matches!(outcome, ScOutcome::Detected(latency) if latency <= simplecan::REACTION),
        "{outcome:?}"
    );
}

/// The active master switched off: node 2 (38h) sends the next sync no earlier than 2000 ms
/// plus its t_wait of 40 ms after 30h's last, and within one cycle and a slot after that
/// (SC_REQ_25, SC_REQ_27, SC_REQ_32); the consumer of 30h is 0 within its timeout.
#[test]
fn sc_req_25_a_master_that_disappears_is_replaced_after_2000_ms_and_its_t_wait() {
    let summary = passes(ScClass::MasterGone, 2);
    assert_eq!(summary.detected, 2);
    let worst = summary.max_latency.expect("takeovers");
    assert!(
        worst >= ms(2_040) && worst <= ScClass::MasterGone.bound(),
        "{worst:?}"
    );
}

/// Bad CRCs around the leaky counter's limit: every seeded scenario in the safe state at
/// exactly the packet that takes the oracle's own counter to 1000, or running on when it
/// never gets there (SC_REQ_42).
#[test]
fn sc_req_42_bad_crcs_around_the_limit_trip_the_counter_exactly_at_1000() {
    passes(ScClass::LeakyCounter, SCENARIOS);
}

/// 999 bad packets 2 ms apart (2 s, no leak yet): running, the value flowing. 1000: the safe
/// state at the 1000th (SC_REQ_42). 40 ms apart the boundary moves by the leaks over the
/// span: just below it the node runs on, just above it trips.
#[test]
fn sc_req_42_999_bad_crcs_keep_running_and_the_1000th_is_the_safe_state() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let mut net = simplecan::started();
    simplecan::bad_crcs(&mut net, 999, ms(2), &mut rng);
    assert_eq!(
        verdict(&net, ScClass::LeakyCounter),
        (1, None, ScOutcome::Harmless)
    );
    let mut net = simplecan::started();
    simplecan::bad_crcs(&mut net, 1_000, ms(2), &mut rng);
    let (output, cause, outcome) = verdict(&net, ScClass::LeakyCounter);
    assert_eq!((output, cause), (0, Some(Cause::SimpleCanBadCrc.code())));
    assert_eq!(outcome, ScOutcome::Detected(Duration::ZERO));
    // 40 ms apart the packets span about 40 s, so 11 leaks: 3 fewer than 1000 plus them
    // never reach 1000 (the tick before the first packet may leak nothing, so the peak is
    // 997 or 996), 3 more always do.
    for (margin, trips) in [(-3, false), (3, true)] {
        let count = simplecan::leaky_count(ms(40), margin);
        assert_eq!(count as i64, 1_011 + margin);
        let mut net = simplecan::started();
        simplecan::bad_crcs(&mut net, count, ms(40), &mut rng);
        let (output, cause, outcome) = verdict(&net, ScClass::LeakyCounter);
        if trips {
            assert_eq!((output, cause), (0, Some(Cause::SimpleCanBadCrc.code())));
            assert_eq!(outcome, ScOutcome::Detected(Duration::ZERO));
        } else {
            assert_eq!((output, cause, outcome), (1, None, ScOutcome::Harmless));
        }
    }
}

/// A signed sync of `master` for `cycle` (offset 0) ending at `end_ms`, as the oracle reads
/// it (`docs/simplecan.md` section 3).
fn sync(master: u8, cycle: u16, end_ms: u64) -> (Instant, Instant, CanFrame) {
    let [c1, c0] = cycle.to_be_bytes();
    let payload = [master, c1, c0, 0, 0];
    let [_, r2, r1, r0] =
        oracle::packet_crc(node_hash(master), oracle::SYNC_ID, &payload).to_be_bytes();
    let frame = CanFrame::new(
        CanId::new(oracle::SYNC_ID).unwrap(),
        &[master, c1, c0, 0, 0, r2, r1, r0],
    )
    .unwrap();
    let end = Instant::from_millis(end_ms);
    (end, end, frame)
}

/// A packet of 30h with value 1 and `stamp`, its CRC bad when `bad`, from `start_ms` for
/// 270 µs.
fn data(stamp: u8, start_ms: u64, bad: bool) -> (Instant, Instant, CanFrame) {
    let payload = [1, 0, 0, 0, stamp];
    let crc = oracle::packet_crc(node_hash(ESTOP), u16::from(ESTOP), &payload) ^ u32::from(bad);
    let [_, r2, r1, r0] = crc.to_be_bytes();
    let frame = CanFrame::new(
        CanId::new(u16::from(ESTOP)).unwrap(),
        &[1, 0, 0, 0, stamp, r2, r1, r0],
    )
    .unwrap();
    let start = Instant::from_millis(start_ms);
    (start, start + Duration::from_micros(270), frame)
}

/// The oracle's own synchronisation: no packet is valid before the second sync of one
/// master (SC_REQ_30), a packet in its slot with its cycle's stamp is, and none is from
/// 2000 ms after the last sync on (SC_REQ_32). Syncs of cycle c end at c × 10 + 9 ms.
#[test]
fn sc_req_32_the_oracle_takes_packets_only_between_two_syncs_and_2000_ms_after_the_last() {
    let entry = simplecan::monitored();
    let trace = [
        sync(ESTOP, 0, 9),
        data(1, 10, false),
        sync(ESTOP, 10, 109),
        data(11, 110, false),
        data(210, 2_100, false),
        data(218, 2_180, false),
    ];
    let valid = oracle::valid_packets(&entry, &trace);
    let starts: Vec<u64> = valid.iter().map(|p| p.start.as_micros() / 1_000).collect();
    assert_eq!(starts, [110, 2_100], "{valid:?}");
}

/// The oracle's several-masters rule: a higher master's sync within 2000 ms of a lower
/// one's is two masters (SC_REQ_26); after 2000 ms of silence, or a lower after a higher (a
/// takeover, SC_REQ_25), it is not.
#[test]
fn sc_req_26_the_oracle_finds_a_higher_master_within_2000_ms_of_a_lower_one() {
    let entry = simplecan::monitored();
    let two = [sync(ESTOP, 0, 9), sync(SECOND, 10, 109)];
    assert_eq!(
        oracle::several_masters(&entry, &two),
        Some(Instant::from_millis(109))
    );
    let gone = [sync(ESTOP, 0, 9), sync(SECOND, 201, 2_019)];
    assert_eq!(oracle::several_masters(&entry, &gone), None);
    let takeover = [sync(SECOND, 0, 9), sync(ESTOP, 10, 109)];
    assert_eq!(oracle::several_masters(&entry, &takeover), None);
}

/// The oracle's leaky counter, by SC_REQ_42's note: 1000 bad packets 1 ms apart reach 1000
/// at the last; 1000 packets 4 ms apart span one leak at 3.6 s and do not, 1001 do.
#[test]
fn sc_req_42_the_oracle_counts_bad_crcs_with_one_leak_every_3_6_s() {
    let entry = simplecan::monitored();
    let bad = |count: u64, spacing_ms: u64| -> Vec<_> {
        (0..count)
            .map(|n| data(n as u8, 1 + n * spacing_ms, true))
            .collect()
    };
    let started = Instant::ZERO;
    let fast = bad(1_000, 1);
    assert_eq!(
        oracle::bad_crc_trip(&entry, &fast, started),
        Some(fast[999].1)
    );
    assert_eq!(oracle::bad_crc_trip(&entry, &bad(1_000, 4), started), None);
    let one_more = bad(1_001, 4);
    assert_eq!(
        oracle::bad_crc_trip(&entry, &one_more, started),
        Some(one_more[1_000].1)
    );
    let good: Vec<_> = (0..1_000u64).map(|n| data(n as u8, 1 + n, false)).collect();
    assert_eq!(oracle::bad_crc_trip(&entry, &good, started), None);
}
