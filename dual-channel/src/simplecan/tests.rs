//! The SimpleCAN checks of the two channels: pairing of heard and forwarded frames, the
//! verdicts on consumed entries, the outputs they drive, the node's own packets.

use super::*;

const BOUND: Duration = Duration::from_millis(2);

/// Worked vector 1 of docs/simplecan.md section 9.
const VECTOR: RawFrame = RawFrame {
    id: 0x030,
    len: 8,
    data: [0x01, 0x00, 0x00, 0x00, 0x05, 0xA4, 0x18, 0x27],
};

fn at(micros: u64) -> Instant {
    Instant::ZERO + Duration::from_micros(micros)
}

#[test]
fn sc_req_24_a_frame_heard_and_forwarded_alike_is_handed_on_in_either_order() {
    let mut check = ForwardCheck::new(BOUND);
    assert!(check.is_idle());
    assert_eq!(check.heard(at(0), VECTOR), Ok(None));
    assert_eq!(check.deadline(), Some(at(2_000)));
    assert!(!check.is_idle(), "a copy waits");
    assert_eq!(check.forwarded(at(300), VECTOR), Ok(Some(VECTOR)));
    assert!(check.is_idle());
    assert_eq!(check.forwarded(at(400), VECTOR), Ok(None));
    assert!(!check.is_idle(), "a copy waits");
    assert_eq!(check.heard(at(500), VECTOR), Ok(Some(VECTOR)));
    assert_eq!(check.deadline(), None);
    assert!(check.is_idle());
    assert_eq!(check.poll(at(10_000)), Ok(()));
}

#[test]
fn sc_req_24_a_corrupted_forwarded_copy_is_a_fault() {
    for bit in 0..64 {
        let mut corrupted = VECTOR;
        corrupted.data[bit / 8] ^= 1 << (bit % 8);
        let mut check = ForwardCheck::new(BOUND);
        check.heard(at(0), VECTOR).unwrap();
        assert_eq!(
            check.forwarded(at(100), corrupted),
            Err(ForwardFault::Differs {
                heard: 0x030,
                forwarded: 0x030
            }),
            "bit {bit}"
        );
    }
    let mut check = ForwardCheck::new(BOUND);
    check
        .forwarded(
            at(0),
            RawFrame {
                id: 0x031,
                ..VECTOR
            },
        )
        .unwrap();
    assert_eq!(
        check.heard(at(100), VECTOR),
        Err(ForwardFault::Differs {
            heard: 0x030,
            forwarded: 0x031
        })
    );
}

#[test]
fn sc_req_24_a_lost_forwarded_copy_is_a_fault_at_the_bound_itself() {
    let mut check = ForwardCheck::new(BOUND);
    check.heard(at(0), VECTOR).unwrap();
    assert_eq!(check.poll(at(1_999)), Ok(()));
    assert_eq!(check.poll(at(2_000)), Err(ForwardFault::Lost { id: 0x030 }));
}

#[test]
fn sc_req_24_a_forwarded_copy_b_never_heard_is_a_fault_at_the_bound_itself() {
    let mut check = ForwardCheck::new(BOUND);
    check.forwarded(at(0), VECTOR).unwrap();
    assert_eq!(check.poll(at(1_999)), Ok(()));
    assert_eq!(
        check.poll(at(2_000)),
        Err(ForwardFault::Unheard { id: 0x030 })
    );
}

#[test]
fn sc_req_24_more_waiting_frames_than_the_depth_is_a_fault() {
    let mut check = ForwardCheck::new(BOUND);
    for n in 0..DEPTH as u64 {
        assert_eq!(check.heard(at(n), VECTOR), Ok(None));
    }
    assert_eq!(check.heard(at(9), VECTOR), Err(ForwardFault::Overrun));
}

#[test]
fn sc_req_24_the_forwarded_message_carries_the_frame_unpacked() {
    assert_eq!(
        VECTOR.forward(),
        Message::SimpleCanPacket {
            id: 0x030,
            len: 8,
            data: [0x01, 0x00, 0x00, 0x00, 0x05, 0xA4, 0x18, 0x27],
        }
    );
}

/// SC_REQ_10: both channels' verdicts on a consumed packet are compared by the SRDOs' own
/// check, kept apart by SDD entry: agreement confirms the value, a differing value, SC-ID,
/// stamp or validity is a disagreement, an entry beyond the channel's is refused.
#[test]
fn sc_req_10_verdicts_on_consumed_entries_are_compared_as_for_srdos() {
    let entry = |n| ConsumedEntry::from_number(n).unwrap();
    let mut check = VerdictCheck::<ENTRIES, ConsumedEntry>::new(BOUND);
    let ours = verdict(0x30, 5, 1, true);
    assert_eq!(check.local(at(0), entry(1), ours), Ok(None));
    assert_eq!(check.remote(at(100), 1, ours), Ok(Some(ours)));
    for theirs in [
        verdict(0x30, 5, 0, true),
        verdict(0x31, 5, 1, true),
        verdict(0x30, 6, 1, true),
        verdict(0x30, 5, 1, false),
    ] {
        let mut check = VerdictCheck::<ENTRIES, ConsumedEntry>::new(BOUND);
        check.local(at(0), entry(2), ours).unwrap();
        assert_eq!(
            check.remote(at(100), 2, theirs),
            Err(CrossFault::Disagreement { srdo: entry(2) }),
            "{theirs:?}"
        );
    }
    assert_eq!(
        check.remote(at(0), ENTRIES as u8 + 1, ours),
        Err(CrossFault::UnknownSrdo {
            srdo: ENTRIES as u8 + 1
        })
    );
    // Two channels that both rejected a packet agree, and confirm nothing.
    let rejected = verdict(0x30, 7, 0, false);
    check.local(at(0), entry(1), rejected).unwrap();
    assert_eq!(check.remote(at(0), 1, rejected), Ok(None));
    let fault = SimpleCanFault::Verdict(CrossFault::Disagreement { srdo: entry(1) });
    assert_eq!(fault.cause(), Cause::SimpleCanVerdictsDisagree);
}

/// What the checks drove, as far as these tests look.
#[derive(Default)]
struct Driven(std::vec::Vec<(u8, u32)>);

impl Io for Driven {
    fn transmit(&mut self, _: shared::CanFrame) {}
    fn link(&mut self, _: &[u8]) {}
    fn output(&mut self, _: shared::safety::types::SrdoNumber, _: u64) {}
    fn event(&mut self, _: ChannelEvent) {}
    fn simplecan_output(&mut self, sc_id: u8, value: u32) {
        self.0.push((sc_id, value));
    }
}

/// SC_REQ_10 with SC_REQ_05: an output goes towards 0 with this channel's own acceptance,
/// away from 0 only with a value both confirmed for the newest packet each accepted; a late
/// confirmation of an older packet may lower it, never raise it.
#[test]
fn sc_req_10_a_consumed_value_leaves_the_safe_state_only_when_both_channels_confirmed_it() {
    let entry = ConsumedEntry::from_number(1).unwrap();
    let mut checks = Checks::new(BOUND, BOUND, Bounds::STANDARD);
    let mut io = Driven::default();
    checks.accepted(entry, 0x30, 1, 1, &mut io);
    assert_eq!(checks.output(0x30), 0, "not before the confirmation");
    checks.peer_reported(entry, 1);
    checks.confirmed(entry, 0x30, verdict(0x30, 1, 1, true), &mut io);
    assert_eq!(checks.output(0x30), 1);
    // Packet 2 (value 0) accepted here: the output falls at once.
    checks.accepted(entry, 0x30, 2, 0, &mut io);
    assert_eq!(checks.output(0x30), 0);
    // Packet 3 (value 1) accepted here, then packet 2's and 3's confirmations: 2's is no
    // longer the newest, and 3's raises the output only once the other channel reported 3.
    checks.accepted(entry, 0x30, 3, 1, &mut io);
    checks.peer_reported(entry, 2);
    checks.confirmed(entry, 0x30, verdict(0x30, 2, 0, true), &mut io);
    assert_eq!(checks.output(0x30), 0);
    checks.confirmed(entry, 0x30, verdict(0x30, 3, 1, true), &mut io);
    assert_eq!(checks.output(0x30), 0, "the other channel's newest is 2");
    checks.peer_reported(entry, 3);
    checks.confirmed(entry, 0x30, verdict(0x30, 3, 1, true), &mut io);
    assert_eq!(checks.output(0x30), 1);
    checks.clear_outputs(&mut io);
    assert_eq!(checks.output(0x30), 0);
    assert_eq!(io.0, [(0x30, 1), (0x30, 0), (0x30, 1), (0x30, 0)]);
}

/// The node's own packets, as channel B tells them from the others: data of an SC-ID it
/// produces, a sync naming its master SC-ID (its lowest produced, when a potential master).
#[test]
fn sc_req_10_a_layer_knows_the_node_s_own_packets_and_its_consumed_entries() {
    use shared::node::simplecan::{EntryObjects, ROLE_CONSUME, ROLE_MASTER, ROLE_PRODUCE};
    let entry = |sc_id, role| EntryObjects {
        sc_id,
        role,
        hash: 0x1000 + u32::from(sc_id),
        ..EntryObjects::default()
    };
    let mut entries = [EntryObjects::default(); ENTRIES];
    entries[..3].copy_from_slice(&[
        entry(0x35, ROLE_PRODUCE),
        entry(0x31, ROLE_PRODUCE),
        entry(0x40, ROLE_CONSUME),
    ]);
    entries[3] = entry(0x30, ROLE_MASTER);
    let layer = Layer {
        entries,
        count: 4,
        potential_master: true,
        running: true,
        accepted: 0,
        buffering: Duration::ZERO,
    };
    let frame = |id, first| RawFrame {
        id,
        len: 8,
        data: [first, 0, 0, 0, 0, 0, 0, 0],
    };
    assert_eq!(layer.master_sc_id(), Some(0x31));
    assert!(layer.is_own(&frame(0x035, 0)));
    assert!(layer.is_own(&frame(0x02F, 0x31)));
    assert!(!layer.is_own(&frame(0x02F, 0x30)), "another master's sync");
    assert!(!layer.is_own(&frame(0x040, 0)));
    assert_eq!(layer.consumed(0x40), ConsumedEntry::from_number(3));
    assert_eq!(layer.consumed(0x35), None);
    assert_eq!(layer.hash_of(0x30), Some(0x1030));
    let follower = Layer {
        potential_master: false,
        ..layer
    };
    assert_eq!(follower.master_sc_id(), None);
    assert!(!follower.is_own(&frame(0x02F, 0x31)));
}
