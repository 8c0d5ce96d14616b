//! SimpleCAN fault campaigns at test size (`system_tests::campaign::simplecan`), each class
//! judged by the independent oracle (`system_tests::campaign::simplecan_oracle`, which does
//! not call `shared::simplecan`): no scenario unsafe, and each class's fault met as the
//! requirement says.

use shared::Duration;
use system_tests::campaign::simplecan::{self, ScClass, TIMEOUT_MS};
use system_tests::campaign::simplecan_oracle::{self as oracle, ValidPacket};

const SCENARIOS: u64 = 4;

/// Every scenario of `class` safe, and every one ending with the output at 0 within the
/// safety timeout of the last valid packet (the producer has left; nothing injected may
/// keep the value alive).
fn safe_and_timed_out(class: ScClass) {
    let summary = simplecan::campaign(class, 0, SCENARIOS);
    assert_eq!(summary.unsafe_, 0, "{}: {summary:?}", class.name());
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
