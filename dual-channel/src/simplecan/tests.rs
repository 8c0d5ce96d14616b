//! The pairing of heard and forwarded SimpleCAN frames: agreement, corruption, loss.

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
    assert_eq!(check.heard(at(0), VECTOR), Ok(None));
    assert_eq!(check.deadline(), Some(at(2_000)));
    assert_eq!(check.forwarded(at(300), VECTOR), Ok(Some(VECTOR)));
    assert_eq!(check.forwarded(at(400), VECTOR), Ok(None));
    assert_eq!(check.heard(at(500), VECTOR), Ok(Some(VECTOR)));
    assert_eq!(check.deadline(), None);
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
