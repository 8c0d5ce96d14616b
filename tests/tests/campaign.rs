//! The fault campaigns' deterministic tests (one or more per class, each asserting the safe
//! state within the bound the configuration implies, judged by the independent oracle), a
//! seeded campaign per class, and the oracle's own tests: it must flag what is unsafe, or
//! its silence proves nothing.

use dual_channel::runtime::ChannelEvent;
use shared::canopen::nmt::NmtCommand;
use shared::canopen::od::Address;
use shared::node::Event;
use shared::{CanFrame, CanId, Duration, Instant};
use system_tests::bus::{Delivery, Fault, Match};
use system_tests::campaign::oracle::{self, MonitoredSrdo, REACTION};
use system_tests::campaign::{
    self, CONSUMER, Class, INJECTOR, MONITORED, PRODUCER, REFRESH, SCT, SRVT, steady, tap_srdo,
    verdict,
};
use system_tests::dual::{DualNetwork, Side};

const INPUT: u8 = 0x5A;

fn frame(id: u16, data: &[u8]) -> CanFrame {
    CanFrame::new(CanId::new(id).unwrap(), data).unwrap()
}

fn ms(value: u64) -> Duration {
    Duration::from_millis(value)
}

fn plus(a: Duration, b: Duration) -> Duration {
    Duration::from_micros(a.as_micros() + b.as_micros())
}

/// Runs on for `run`, then asserts that the oracle found nothing and node 33 reached its
/// safe state no later than `bound` after `effect`; returns the latency.
fn safe_within(net: &mut DualNetwork, effect: Instant, bound: Duration, run: Duration) -> Duration {
    let from = net.now;
    net.run_for(run);
    let verdict = verdict(net, from.min(effect));
    assert!(
        verdict.judgement.violations.is_empty(),
        "{:?}\n{}",
        verdict.judgement.violations,
        campaign::timeline(net, from, net.now, "oracle")
    );
    let safe = verdict
        .safe_at
        .unwrap_or_else(|| panic!("{}", campaign::timeline(net, from, net.now, "never safe")));
    let latency = safe.saturating_since(effect);
    assert!(latency <= bound, "latency {latency:?} over {bound:?}");
    assert_eq!(net.output(CONSUMER), 0);
    latency
}

/// Runs on for `run`, then asserts that the oracle found nothing, node 33 never left its
/// working state and still carries the producer's data.
fn harmless(net: &mut DualNetwork, run: Duration, expected: u8) {
    let from = net.now;
    net.run_for(run);
    let verdict = verdict(net, from);
    assert!(
        verdict.judgement.violations.is_empty(),
        "{:?}",
        verdict.judgement.violations
    );
    assert_eq!(
        verdict.safe_at,
        None,
        "{}",
        campaign::timeline(net, from, net.now, "safe")
    );
    assert_eq!(net.output(CONSUMER), u64::from(expected));
    let node = net.node(CONSUMER);
    assert!(node.a.is_working() && node.b.is_working());
}

/// When the tap first acted.
fn effect_of(effect: &std::rc::Rc<std::cell::Cell<Option<Instant>>>) -> Instant {
    effect.get().expect("the fault took effect")
}

// --- The oracle's own tests -------------------------------------------------------------

const WATCHED: MonitoredSrdo = MonitoredSrdo {
    consumer: 33,
    plain_id: 0x101,
    inverted_id: 0x102,
    len: 1,
    sct: Duration::from_millis(50),
    srvt: Duration::from_millis(20),
    producer: [1, 2],
};

fn at(ms: u64) -> Instant {
    Instant::from_micros(ms * 1000)
}

fn start_and_pair(data: u8, pair_at: u64) -> Vec<(Instant, CanFrame, usize)> {
    vec![
        (at(0), frame(0x000, &[0x01, 0]), 0),
        (at(pair_at), frame(0x101, &[data]), 1),
        (at(pair_at), frame(0x102, &[!data]), 2),
    ]
}

/// The oracle accepts an output that follows a valid pair from the producer, and flags an
/// output raised before its pair, kept beyond SCT, kept after an inverted frame that is not
/// the inverse, or raised by a well-formed pair from another sender.
#[test]
fn campaign_oracle_flags_unjustified_outputs() {
    let follows = [(at(10), 0usize, 0x5Au64), (at(10), 1, 0x5A), (at(55), 0, 0)];
    let frames = start_and_pair(0x5A, 10);
    let clean = oracle::judge(WATCHED, &frames, &follows, at(55));
    assert!(clean.violations.is_empty(), "{clean:?}");
    assert_eq!(clean.first_error.map(|(at, _)| at), None);
    // Past the SCT of the pair at 10 ms (due by 60 ms): the output must be 0 by 61 ms.
    let kept = oracle::judge(WATCHED, &frames, &follows[..2], at(70));
    assert_eq!(kept.first_error.map(|(t, _)| t), Some(at(60)));
    assert!(!kept.violations.is_empty(), "kept beyond SCT");
    // Raised before the pair.
    let early = [(at(9), 0usize, 0x5Au64), (at(9), 1, 0x5A)];
    assert!(
        !oracle::judge(WATCHED, &frames, &early, at(20))
            .violations
            .is_empty()
    );
    // More bits than the pair carries.
    let more = [(at(10), 0usize, 0xFFu64), (at(10), 1, 0xFF)];
    assert!(
        !oracle::judge(WATCHED, &frames, &more, at(20))
            .violations
            .is_empty()
    );
    // An inverted frame that is not the inverse at 35 ms: 0 within the reaction allowance.
    let mut corrupted = frames.clone();
    corrupted.push((at(35), frame(0x101, &[0x5A]), 1));
    corrupted.push((at(35), frame(0x102, &[0x00]), 2));
    let judged = oracle::judge(WATCHED, &corrupted, &follows[..2], at(40));
    assert_eq!(judged.first_error.map(|(t, _)| t), Some(at(35)));
    assert!(!judged.violations.is_empty());
    let in_time = [follows[0], follows[1], (at(35) + REACTION, 1, 0)];
    assert!(
        oracle::judge(WATCHED, &corrupted, &in_time, at(40))
            .violations
            .is_empty()
    );
    // A well-formed pair from another sender justifies nothing.
    let mut foreign = frames.clone();
    foreign.push((at(20), frame(0x101, &[0xFF]), 0));
    foreign.push((at(20), frame(0x102, &[0x00]), 0));
    let raised = [follows[0], follows[1], (at(21), 0, 0xFF), (at(21), 1, 0xFF)];
    assert!(
        !oracle::judge(WATCHED, &foreign, &raised, at(30))
            .violations
            .is_empty()
    );
    // A lone plain frame: SRVT after it the safe state is required.
    let mut lone = frames.clone();
    lone.push((at(30), frame(0x101, &[0x5A]), 1));
    let judged = oracle::judge(WATCHED, &lone, &follows[..2], at(60));
    assert_eq!(judged.first_error.map(|(t, _)| t), Some(at(50)));
    // A second plain frame with other data: a sequence error; an exact copy is not.
    let mut copy = frames.clone();
    copy.insert(2, (at(10), frame(0x101, &[0x5A]), 1));
    assert!(
        oracle::judge(WATCHED, &copy, &follows, at(55))
            .violations
            .is_empty()
    );
    let mut other = frames.clone();
    other.insert(2, (at(10), frame(0x101, &[0x5B]), 1));
    assert_eq!(
        oracle::judge(WATCHED, &other, &[], at(20))
            .first_error
            .map(|(t, _)| t),
        Some(at(10))
    );
    // After an NMT reset node the latch is cleared, but nothing is justified until a pair
    // follows a new start.
    let mut reset = corrupted.clone();
    reset.push((at(38), frame(0x000, &[0x81, 33]), 0));
    reset.extend(
        start_and_pair(0x11, 45)
            .into_iter()
            .map(|(t, f, p)| (t + ms(40), f, p)),
    );
    let again = [
        follows[0],
        follows[1],
        (at(35), 1, 0),
        (at(85), 0, 0x11),
        (at(85), 1, 0x11),
    ];
    assert!(
        oracle::judge(WATCHED, &reset, &again, at(90))
            .violations
            .is_empty()
    );
}

/// The oracle's configuration is the one node 33 runs (read back over SDO, not taken from
/// the implementation): COB-IDs, SCT, SRVT and one mapped byte each way.
#[test]
fn campaign_oracle_configuration_matches_the_node() {
    let mut net = steady(INPUT);
    let read = |net: &mut DualNetwork, index, sub| {
        let bytes = net.read(CONSUMER, Address::new(index, sub)).unwrap();
        let mut raw = [0u8; 4];
        raw[..bytes.len()].copy_from_slice(&bytes);
        u32::from_le_bytes(raw)
    };
    assert_eq!(read(&mut net, 0x1301, 5), u32::from(MONITORED.plain_id));
    assert_eq!(read(&mut net, 0x1301, 6), u32::from(MONITORED.inverted_id));
    assert_eq!(
        u64::from(read(&mut net, 0x1301, 2)) * 1000,
        MONITORED.sct.as_micros()
    );
    assert_eq!(
        u64::from(read(&mut net, 0x1301, 3)) * 1000,
        MONITORED.srvt.as_micros()
    );
    assert_eq!(read(&mut net, 0x1381, 0), 2);
    // Each mapping entry is 8 bits (length in the low byte).
    assert_eq!(read(&mut net, 0x1381, 1) & 0xFF, 8 * MONITORED.len as u32);
}

// --- The communication error classes, deterministic -------------------------------------

/// A data bit flipped in the inverted frame (missed by the CAN CRC): node 33 is safe on that
/// frame (EN 50325-5 7.1.1).
#[test]
fn iec61784_3_corruption_a_data_bit_of_the_inverted_frame_is_safe_on_arrival() {
    let mut net = steady(INPUT);
    let effect = tap_srdo(&mut net, |_, d| {
        (d.frame.id().raw() == 0x102).then(|| {
            let mut data = *d.frame.raw_data();
            data[0] ^= 0x10;
            vec![Delivery {
                frame: CanFrame::from_parts(d.frame.id(), d.frame.dlc(), data).unwrap(),
                ..d
            }]
        })
    });
    net.run_for(ms(30));
    let latency = safe_within(&mut net, effect_of(&effect), REACTION, ms(50));
    assert_eq!(latency, Duration::ZERO);
}

/// The inverted frame's identifier corrupted into the plain frame's (a second plain frame
/// with other data): a sequence error on arrival.
#[test]
fn iec61784_3_corruption_an_identifier_changed_into_the_plain_one_is_safe_on_arrival() {
    let mut net = steady(INPUT);
    let effect = tap_srdo(&mut net, |_, d| {
        (d.frame.id().raw() == 0x102).then(|| {
            vec![Delivery {
                frame: CanFrame::from_parts(CanId::new(0x101).unwrap(), 1, *d.frame.raw_data())
                    .unwrap(),
                ..d
            }]
        })
    });
    net.run_for(ms(30));
    safe_within(&mut net, effect_of(&effect), REACTION, ms(50));
}

/// A plain frame shortened to 0 bytes: shorter than its mapping, refused on arrival.
#[test]
fn iec61784_3_corruption_a_shortened_frame_is_safe_on_arrival() {
    let mut net = steady(INPUT);
    let effect = tap_srdo(&mut net, |_, d| {
        (d.frame.id().raw() == 0x101).then(|| {
            vec![Delivery {
                frame: CanFrame::from_parts(d.frame.id(), 0, [0; 8]).unwrap(),
                ..d
            }]
        })
    });
    net.run_for(ms(30));
    safe_within(&mut net, effect_of(&effect), REACTION, ms(50));
}

/// CAN double reception of the plain frame (the bus repeats it right after the first
/// copy): discarded, nothing changes (ISO 11898-1).
#[test]
fn iec61784_3_repetition_can_double_reception_changes_nothing() {
    let mut net = steady(INPUT);
    let now = net.now;
    net.inject(Match::next_with_id(0x101, now), Fault::Repeat);
    harmless(&mut net, ms(150), INPUT);
    assert!(
        net.node(CONSUMER)
            .a
            .node()
            .double_reception()
            .plain_repeated
            >= 1
    );
}

/// A copy of the plain frame delivered 10 ms after its pair (a gateway repeating): a lone
/// plain frame, safe SRVT after it.
#[test]
fn iec61784_3_repetition_a_late_copy_of_the_plain_frame_is_safe_by_srvt() {
    let mut net = steady(INPUT);
    let effect = tap_srdo(&mut net, |_, d| {
        (d.frame.id().raw() == 0x101).then(|| {
            vec![
                d,
                Delivery {
                    at: d.at + ms(10),
                    ..d
                },
            ]
        })
    });
    net.run_for(ms(30));
    safe_within(&mut net, effect_of(&effect), plus(SRVT, REACTION), ms(80));
}

/// An inverted frame inserted before its plain frame (CiA 304 9.5, chronological order): the
/// consumer discards it; the producer, which did not send it, sends a GFC.
#[test]
fn iec61784_3_sequence_an_inverted_frame_before_its_plain_frame_is_safe() {
    let mut net = steady(INPUT);
    let effect = tap_srdo(&mut net, |_, d| {
        (d.frame.id().raw() == 0x101).then(|| {
            let early = Delivery {
                frame: frame(0x102, &[!INPUT]),
                from: INJECTOR,
                ..d
            };
            vec![early, d]
        })
    });
    net.run_for(ms(30));
    safe_within(&mut net, effect_of(&effect), plus(SRVT, REACTION), ms(80));
}

/// An old pair (other data) replayed after the emergency stop was pressed: the output never
/// comes back on, and the node is safe within a few frame times (the producer's GFC).
#[test]
fn iec61784_3_sequence_an_old_pair_replayed_never_raises_the_output() {
    let mut net = steady(INPUT);
    net.set_inputs(PRODUCER, 0, 0);
    net.run_for(ms(30));
    assert_eq!(net.output(CONSUMER), 0);
    let since = net.trace.len();
    net.send_foreign(frame(0x101, &[INPUT]));
    net.send_foreign(frame(0x102, &[!INPUT]));
    net.run_for(ms(1));
    let effect = net.trace[since..]
        .iter()
        .find(|(_, _, from)| *from == INJECTOR)
        .map(|(at, ..)| *at)
        .unwrap();
    safe_within(&mut net, effect, ms(1), ms(80));
}

/// A lost inverted frame: safe at SRVT after the plain frame (EN 50325-5 7.1.2).
#[test]
fn iec61784_3_loss_a_lost_inverted_frame_is_safe_at_srvt() {
    let mut net = steady(INPUT);
    let plain = std::rc::Rc::new(std::cell::Cell::new(None));
    let seen = plain.clone();
    let effect = tap_srdo(&mut net, move |_, d| {
        if d.frame.id().raw() == 0x101 && seen.get().is_none() {
            seen.set(Some(d.at));
        }
        (d.frame.id().raw() == 0x102 && seen.get().is_some()).then(Vec::new)
    });
    net.run_for(ms(30));
    safe_within(&mut net, effect_of(&effect), plus(SRVT, REACTION), ms(80));
    let verdict = verdict(&net, plain.get().unwrap());
    assert_eq!(
        verdict.safe_at,
        Some(plain.get().unwrap() + SRVT),
        "at SRVT itself"
    );
}

/// Every SRDO frame lost from now on: safe at SCT after the last pair.
#[test]
fn iec61784_3_loss_all_frames_lost_is_safe_at_sct() {
    let mut net = steady(INPUT);
    let effect = tap_srdo(&mut net, |_, _| Some(Vec::new()));
    let now = net.now;
    safe_within(&mut net, now, plus(SCT, REACTION), ms(120));
    assert!(effect.get().is_some());
}

/// The inverted frame 1 ms beyond SRVT after its plain frame: safe at SRVT; 1 ms inside:
/// accepted (EN 50325-5 7.1.2).
#[test]
fn iec61784_3_delay_an_inverted_frame_just_beyond_srvt_is_safe_and_just_inside_is_accepted() {
    for (beyond, extra) in [(true, 1_000u64), (false, 0)] {
        let mut net = steady(INPUT);
        let plain = std::rc::Rc::new(std::cell::Cell::new(Instant::ZERO));
        let seen = plain.clone();
        let mut done = false;
        let effect = tap_srdo(&mut net, move |_, d| {
            if d.frame.id().raw() == 0x101 {
                seen.set(d.at);
                return None;
            }
            if done || seen.get() == Instant::ZERO {
                return None;
            }
            done = true;
            let target = if beyond {
                seen.get() + SRVT + Duration::from_micros(extra)
            } else {
                seen.get() + ms(19)
            };
            Some(vec![Delivery { at: target, ..d }])
        });
        net.run_for(ms(30));
        if beyond {
            safe_within(&mut net, effect_of(&effect), plus(SRVT, REACTION), ms(80));
        } else {
            harmless(&mut net, ms(100), INPUT);
        }
    }
}

/// A pair held back until 1 ms beyond SCT after the previous pair: safe at SCT.
#[test]
fn iec61784_3_delay_a_pair_beyond_sct_is_safe_at_sct() {
    let mut net = steady(INPUT);
    let last = std::rc::Rc::new(std::cell::Cell::new(Instant::ZERO));
    let seen = last.clone();
    let mut done = false;
    let effect = tap_srdo(&mut net, move |_, d| {
        if d.frame.id().raw() == 0x102 {
            seen.set(d.at);
            return None;
        }
        if done || seen.get() == Instant::ZERO {
            return None;
        }
        done = true;
        Some(vec![Delivery {
            at: seen.get() + SCT + ms(1),
            ..d
        }])
    });
    net.run_for(plus(REFRESH, REFRESH));
    safe_within(&mut net, effect_of(&effect), plus(SCT, REACTION), ms(80));
}

/// A foreign plain frame on node 1's identifier: node 1 sends a GFC, node 33 is safe within
/// about a frame time (EN 50325-5 7.2.1).
#[test]
fn iec61784_3_insertion_a_foreign_plain_frame_is_safe_within_a_millisecond() {
    let mut net = steady(INPUT);
    net.run_for(ms(3));
    let since = net.trace.len();
    net.send_foreign(frame(0x101, &[0xFF]));
    net.run_for(ms(1));
    let effect = net.trace[since..]
        .iter()
        .find(|(_, _, from)| *from == INJECTOR)
        .map(|(at, ..)| *at)
        .unwrap();
    safe_within(&mut net, effect, ms(1), ms(80));
    assert!(
        net.trace
            .iter()
            .any(|(at, f, _)| *at >= effect && f.id().raw() == 0x001),
        "GFC"
    );
}

/// A well-formed pair with other data from another sender after the emergency stop: the
/// output never follows it, and node 33 is safe within a millisecond.
#[test]
fn iec61784_3_masquerade_a_well_formed_foreign_pair_never_raises_the_output() {
    let mut net = steady(INPUT);
    net.set_inputs(PRODUCER, 0, 0);
    net.run_for(ms(40));
    let since = net.trace.len();
    net.send_foreign(frame(0x101, &[0xFF]));
    net.send_foreign(frame(0x102, &[0x00]));
    net.run_for(ms(1));
    let effect = net.trace[since..]
        .iter()
        .find(|(_, _, from)| *from == INJECTOR)
        .map(|(at, ..)| *at)
        .unwrap();
    safe_within(&mut net, effect, ms(1), ms(80));
}

/// A non-safety frame with the same data on another identifier changes nothing.
#[test]
fn iec61784_3_masquerade_a_non_safety_frame_changes_nothing() {
    let mut net = steady(INPUT);
    net.send_foreign(frame(0x201, &[INPUT]));
    net.send_foreign(frame(0x181, &[!INPUT]));
    harmless(&mut net, ms(100), INPUT);
}

/// Node 1's pairs on another SRDO's identifiers (103h/104h): node 33 gets no pair, safe by
/// SCT.
#[test]
fn iec61784_3_addressing_pairs_on_another_identifier_pair_are_safe_by_sct() {
    let mut net = steady(INPUT);
    let effect = tap_srdo(&mut net, |_, d| {
        let id = d.frame.id().raw() + 2;
        Some(vec![Delivery {
            frame: CanFrame::from_parts(
                CanId::new(id).unwrap(),
                d.frame.dlc(),
                *d.frame.raw_data(),
            )
            .unwrap(),
            ..d
        }])
    });
    let now = net.now;
    safe_within(&mut net, now, plus(SCT, REACTION), ms(120));
    assert!(effect.get().is_some());
}

/// Node 1 switched off and on again as node `new_id`, started by NMT; then node 33's
/// communication reset and node 33 started again. Returns when node 1 went off.
fn renumber_producer(net: &mut DualNetwork, new_id: u8, keep_storage: bool) -> Instant {
    let off = net.now;
    net.repower(PRODUCER, new_id, keep_storage);
    net.run_for(ms(100));
    net.nmt(NmtCommand::Start, 0);
    net.run_for(ms(60));
    net.nmt(NmtCommand::ResetCommunication, CONSUMER);
    net.run_for(ms(20));
    net.nmt(NmtCommand::Start, CONSUMER);
    off
}

/// After node 1 came back as node 9: the oracle finds nothing, node 33 was safe within SCT
/// of node 1 going off, node 9 put no SRDO frame on 101h/102h after its boot-up, and node
/// 33's output never rose again after its own restart. Returns when node 9 booted.
fn never_accepted(net: &mut DualNetwork, off: Instant, restarted: Instant) -> Instant {
    net.run_for(ms(200));
    let verdict = verdict(net, off);
    assert!(
        verdict.judgement.violations.is_empty(),
        "{:?}",
        verdict.judgement.violations
    );
    let safe = verdict.safe_at.expect("safe while node 1 was away");
    assert!(safe.saturating_since(off) <= plus(SCT, REACTION));
    let booted = net
        .trace
        .iter()
        .find(|(at, frame, _)| *at >= off && frame.id().raw() == 0x709 && frame.data() == [0])
        .map(|(at, ..)| *at)
        .expect("node 9's boot-up");
    assert!(
        !net.trace
            .iter()
            .any(|(at, frame, _)| *at >= booted && matches!(frame.id().raw(), 0x101 | 0x102)),
        "an SRDO frame on 101h/102h from the renumbered node"
    );
    assert!(
        !net.outputs
            .iter()
            .any(|(at, id, _, _, value)| *at >= restarted && *id == CONSUMER && *value != 0),
        "node 33's output rose after its restart"
    );
    assert_eq!(net.output(CONSUMER), 0);
    booted
}

/// A producer whose node-ID changed keeps its stored configuration, but that was validated
/// for node-ID 1: NMT start refuses it (0x13FE reads 0) with EMCY 6300h from its new
/// node-ID, so node 33 never accepts its data as node 1's, and its SDO server moved (node 1
/// no longer answers, node 9 does).
#[test]
fn iec61784_3_addressing_a_renumbered_producer_refuses_the_configuration_of_its_old_node_id() {
    let mut net = steady(INPUT);
    let off = renumber_producer(&mut net, 9, true);
    let restarted = net.now;
    never_accepted(&mut net, off, restarted);
    let refused = net.first_event(0, 9, |_, event| {
        matches!(
            event,
            ChannelEvent::Node(Event::ValidatedForAnotherNodeId { .. })
        )
    });
    assert!(refused.is_some(), "the stored configuration names node 1");
    assert!(
        net.trace.iter().any(|(at, frame, _)| *at >= off
            && frame.id().raw() == 0x089
            && frame.data()[..3] == [0x00, 0x63, 0x21]),
        "EMCY 6300h from node 9"
    );
    let identity = Address::new(0x1018, 1);
    assert!(
        net.read(PRODUCER, identity).is_err(),
        "node 1's SDO server moved"
    );
    assert!(net.read(9, identity).is_ok(), "node 9 answers");
    assert_eq!(
        net.read(9, Address::new(0x13FE, 0)).expect("0x13FE"),
        [0],
        "0x13FE reads 0 after the refusal"
    );
}

/// A producer whose node-ID changed with its storage erased has no valid configuration
/// (and its pre-defined SRDO would be on other identifiers): node 33 accepts nothing from
/// it, and after its own restart is safe again by SCT.
#[test]
fn iec61784_3_addressing_a_renumbered_producer_with_defaults_is_never_accepted() {
    let mut net = steady(INPUT);
    let off = renumber_producer(&mut net, 9, false);
    let restarted = net.now;
    never_accepted(&mut net, off, restarted);
}

// --- Single-channel faults, deterministic -------------------------------------------------

/// Channel B's input stuck closed while channel A reads the emergency stop pressed: no
/// inverted frame, node 33 safe by SRVT (CiA 304 9.5, each half built its own way).
#[test]
fn cia304_9_5_a_stuck_input_on_one_channel_still_stops_the_output() {
    let mut net = steady(INPUT);
    net.set_input(PRODUCER, Side::A, 0);
    let pressed = net.now;
    let bound = plus(
        plus(REFRESH, dual_channel::runtime::SAMPLE_WINDOW),
        plus(SRVT, REACTION),
    );
    safe_within(&mut net, pressed, bound, ms(100));
}

/// A bit flip in channel B's copy of node 33's SCT in Operational: the integrity check
/// latches the safe state within one SCT (CiA 304 9.5: what runs is what was validated).
#[test]
fn cia304_9_5_a_bit_flip_in_one_channels_configuration_is_safe_within_sct() {
    let mut net = steady(INPUT);
    net.node_mut(CONSUMER).b.node_mut().inject_record_flip(0, 3);
    let now = net.now;
    safe_within(&mut net, now, plus(SCT, REACTION), ms(120));
}

/// A byte corrupted on node 33's link: both channels latch at the next message.
#[test]
fn cia304_9_5_a_corrupted_link_byte_is_safe_at_once() {
    let mut net = steady(INPUT);
    net.node_mut(CONSUMER).link_faults.corrupt_next_a_to_b = Some(0x04);
    let now = net.now;
    safe_within(
        &mut net,
        now,
        plus(Duration::from_millis(10), REACTION),
        ms(60),
    );
}

/// Channel B of node 1 never sends its inverted frame: node 33 safe by SRVT after the next
/// plain frame.
#[test]
fn cia304_9_5_channel_b_never_sending_its_inverted_frame_is_safe_by_srvt() {
    let mut net = steady(INPUT);
    let now = net.now;
    let when = Match {
        id: Some(0x102),
        from: Some(2),
        after: now,
        count: None,
    };
    net.inject(when, Fault::Drop);
    safe_within(&mut net, now, plus(plus(REFRESH, SRVT), REACTION), ms(100));
}

/// Channel A of node 1 babbling identifier 010h back to back: no SRDO gets through, node 33
/// safe by SCT (EN 50325-5 7.1.2).
#[test]
fn en50325_5_7_1_2_a_babbling_controller_is_safe_by_sct() {
    let mut net = steady(INPUT);
    for _ in 0..2000 {
        net.bus.send(1, frame(0x010, &[0xAA; 8]));
    }
    let now = net.now;
    safe_within(&mut net, now, plus(SCT, REACTION), ms(120));
}

/// A channel's CAN controller bus-off, as the channel loop sees it (the driver reports it:
/// `Received::BusOff`): that channel latches the safe state at once under bus-off's own cause
/// 3Bh, not by its SCT running out, and node 33 is safe within SCT + reaction whichever
/// channel of which node it is (EN 50325-5 7.1.2).
#[test]
fn en50325_5_7_1_2_a_bus_off_controller_latches_its_own_cause_and_the_consumer_is_safe() {
    for (id, side) in [
        (CONSUMER, Side::A),
        (CONSUMER, Side::B),
        (PRODUCER, Side::A),
        (PRODUCER, Side::B),
    ] {
        let mut net = steady(INPUT);
        let now = net.now;
        net.bus_off(id, side);
        assert_eq!(
            campaign::first_fault(&net, id, side, now),
            Some(dual_channel::runtime::ChannelFault::BusOff),
            "node {id} channel {side:?}"
        );
        assert_eq!(
            dual_channel::runtime::ChannelFault::BusOff.cause_code(),
            0x3B
        );
        safe_within(&mut net, now, plus(SCT, REACTION), ms(120));
    }
}

/// Node 33's channel B clock 15 % fast (its runtime driven with scaled time): channel A
/// finds the other channel's heartbeats too frequent and both latch; 15 % slow: channel B
/// finds channel A's too frequent. Within 34 link periods either way.
#[test]
fn cia304_9_5_a_channel_clock_beyond_tolerance_is_found_fast_or_slow() {
    for ppm in [150_000i64, -150_000] {
        let mut net = steady(INPUT);
        let now = net.now;
        net.node_mut(CONSUMER).clocks[Side::B as usize].set_rate(now, ppm);
        let bound = plus(ms(340), REACTION);
        safe_within(&mut net, now, bound, ms(400));
        let faults = [net.node(CONSUMER).a.fault(), net.node(CONSUMER).b.fault()];
        assert!(
            faults.contains(&Some(dual_channel::runtime::ChannelFault::ClockDrift)),
            "{ppm}: {faults:?}"
        );
    }
}

/// A clock 5 % off is within the tolerance: nothing happens.
#[test]
fn cia304_9_5_a_channel_clock_within_tolerance_changes_nothing() {
    for ppm in [50_000i64, -50_000] {
        let mut net = steady(INPUT);
        let now = net.now;
        net.node_mut(CONSUMER).clocks[Side::A as usize].set_rate(now, ppm);
        harmless(&mut net, ms(1000), INPUT);
    }
}

// --- Seeded campaigns, a few scenarios per class (`cargo xtask campaign` runs 10,000) ------

fn seeded(class: Class) {
    seeded_at(class, campaign::BIT_RATE, 40);
}

fn seeded_at(class: Class, bit_rate: u32, count: u64) {
    let summary = campaign::campaign(class, 1_000, count, bit_rate, 1);
    for failure in &summary.failures {
        eprintln!(
            "{} seed {}: {:?} {}\n{}",
            class.name(),
            failure.seed,
            failure.outcome,
            failure.fault,
            failure.report.as_deref().unwrap_or("")
        );
    }
    assert!(summary.passed(), "{class:?}: {summary:?}");
    assert_eq!(summary.injected, count);
    assert!(summary.detected > 0, "{class:?}: no fault was detected");
    let (bound, _) = class.bound(bit_rate);
    assert!(summary.max_latency().unwrap() <= bound.as_micros());
}

#[test]
fn iec61784_3_corruption_seeded_campaign() {
    seeded(Class::Corruption);
}
#[test]
fn iec61784_3_repetition_seeded_campaign() {
    seeded(Class::Repetition);
}
#[test]
fn iec61784_3_sequence_seeded_campaign() {
    seeded(Class::Sequence);
}
#[test]
fn iec61784_3_loss_seeded_campaign() {
    seeded(Class::Loss);
}
#[test]
fn iec61784_3_delay_seeded_campaign() {
    seeded(Class::Delay);
}
#[test]
fn iec61784_3_insertion_seeded_campaign() {
    seeded(Class::Insertion);
}
#[test]
fn iec61784_3_masquerade_seeded_campaign() {
    seeded(Class::Masquerade);
}
#[test]
fn iec61784_3_addressing_seeded_campaign() {
    seeded(Class::Addressing);
}
#[test]
fn iec61784_3_addressing_changed_node_id_seeded_campaign() {
    seeded(Class::NodeId);
}
#[test]
fn cia304_9_5_stuck_input_seeded_campaign() {
    seeded(Class::StuckInput);
}
#[test]
fn cia304_9_5_bit_flip_seeded_campaign() {
    seeded(Class::BitFlip);
}
#[test]
fn cia304_9_5_link_seeded_campaign() {
    seeded(Class::Link);
}
#[test]
fn cia304_9_5_no_inverted_seeded_campaign() {
    seeded(Class::NoInverted);
}
#[test]
fn cia304_9_5_clock_drift_seeded_campaign() {
    seeded(Class::ClockDrift);
}
#[test]
fn en50325_5_7_1_2_controller_silent_seeded_campaign() {
    seeded(Class::ControllerSilent);
}
#[test]
fn en50325_5_7_1_2_babbling_seeded_campaign() {
    seeded(Class::Babbling);
}
#[test]
fn en50325_5_7_1_2_bus_off_seeded_campaign() {
    seeded(Class::BusOff);
}

/// The classes whose bound includes a frame's time on the bus, and the delay class (which
/// times its faults by frame time), at the slowest and the fastest rate.
#[test]
fn campaign_at_125_and_1000_kbit_s_stays_within_the_bounds_of_that_rate() {
    for bit_rate in [125_000, 1_000_000] {
        for class in [Class::Delay, Class::StuckInput, Class::NoInverted] {
            seeded_at(class, bit_rate, 12);
        }
    }
    let slow = Class::NoInverted.bound(125_000).0;
    let fast = Class::NoInverted.bound(1_000_000).0;
    assert_eq!(
        slow.as_micros() - fast.as_micros(),
        campaign::frame_allowance(125_000).as_micros()
            - campaign::frame_allowance(1_000_000).as_micros()
    );
}
