//! B's decoder against docs/simplecan.md section 9 and against the shared decoder.

use super::*;
use proptest::prelude::*;
use shared::frame::{CanFrame, CanId};
use shared::simplecan::frame::{DecodeError, Packet, decode};
use shared::simplecan::{NodeHash, ScId};

/// The shared decoder's result, in B's terms, so the two can be compared.
fn shared_verdict(id: u16, remote: bool, len: u8, data: [u8; 8], hash: Option<u32>) -> Verdict {
    let can_id = CanId::new(id).unwrap();
    let frame = if remote {
        CanFrame::remote(can_id, len).unwrap()
    } else {
        CanFrame::from_parts(can_id, len, data).unwrap()
    };
    let hashes = |_: ScId| hash.map(NodeHash);
    match decode(&frame, &hashes) {
        Ok(Packet::Data(packet)) => Verdict::Data {
            sc_id: packet.sc_id.raw(),
            value: packet.value,
            cycle_stamp: packet.cycle_stamp,
        },
        Ok(Packet::Sync(sync)) => Verdict::Sync {
            master: sync.master().raw(),
            cycle: sync.cycle(),
            offset_micros: sync.offset_micros(),
        },
        Err(DecodeError::NotSimpleCan) => Verdict::NotSimpleCan,
        Err(error) => Verdict::Invalid(match error {
            DecodeError::RemoteFrame => Rejection::Remote,
            DecodeError::WrongLength { .. } => Rejection::Length,
            DecodeError::InvalidMasterScId { .. } => Rejection::Master,
            DecodeError::UnknownScId { .. } => Rejection::UnknownScId,
            DecodeError::BadCrc { .. } => Rejection::Crc,
            DecodeError::OffsetOutOfRange { .. } => Rejection::Offset,
            DecodeError::NotSimpleCan => unreachable!("matched above"),
        }),
    }
}

/// The worked vectors of docs/simplecan.md section 9: hash, identifier, CAN payload.
const VECTORS: [(u32, u16, [u8; 8]); 3] = [
    (
        0x1234_5678,
        0x030,
        [0x01, 0x00, 0x00, 0x00, 0x05, 0xA4, 0x18, 0x27],
    ),
    (
        0xA5C3_0F96,
        0x07F,
        [0xEF, 0xBE, 0xAD, 0xDE, 0xFF, 0x8B, 0x1C, 0x68],
    ),
    (
        0x1234_5678,
        0x02F,
        [0x30, 0x01, 0x02, 0x00, 0xFA, 0xFD, 0x34, 0x07],
    ),
];

#[test]
fn sc_req_10_channel_b_decodes_the_worked_vectors_of_section_9() {
    let verdicts: Vec<Verdict> = VECTORS
        .iter()
        .map(|&(hash, id, data)| check(id, false, 8, data, |_| Some(hash)))
        .collect();
    assert_eq!(
        verdicts,
        [
            Verdict::Data {
                sc_id: 0x30,
                value: 1,
                cycle_stamp: 5
            },
            Verdict::Data {
                sc_id: 0x7F,
                value: 0xDEAD_BEEF,
                cycle_stamp: 0xFF
            },
            Verdict::Sync {
                master: 0x30,
                cycle: 0x0102,
                offset_micros: 250
            },
        ]
    );
}

#[test]
fn sc_req_10_channel_b_rejects_every_single_bit_flip_of_the_worked_vectors() {
    for (hash, id, data) in VECTORS {
        for bit in 0..64 {
            let mut flipped = data;
            flipped[bit / 8] ^= 1 << (bit % 8);
            let verdict = check(id, false, 8, flipped, |_| Some(hash));
            assert!(
                matches!(verdict, Verdict::Invalid(_)),
                "identifier {id:03X}h, bit {bit}: {verdict:?}"
            );
            assert_eq!(verdict, shared_verdict(id, false, 8, flipped, Some(hash)));
        }
    }
}

#[test]
fn sc_req_10_channel_b_agrees_with_the_shared_decoder_on_the_worked_vectors() {
    for (hash, id, data) in VECTORS {
        assert_eq!(
            check(id, false, 8, data, |_| Some(hash)),
            shared_verdict(id, false, 8, data, Some(hash))
        );
    }
}

proptest! {
    /// Random frames on and around the SimpleCAN identifiers, half of them sealed with the
    /// right CRC by the shared encoder's rule, so that both valid and invalid verdicts are
    /// compared.
    #[test]
    fn sc_req_10_channel_b_agrees_with_the_shared_decoder_on_random_frames(
        id in 0x020u16..0x090,
        remote in proptest::bool::weighted(0.05),
        len in prop_oneof![9 => Just(8u8), 1 => 0u8..=8],
        mut data in any::<[u8; 8]>(),
        hash in proptest::option::weighted(0.95, any::<u32>()),
        seal in any::<bool>(),
        sync_master in 0x30u8..=0x7F,
    ) {
        if id == 0x02F && seal {
            data[0] = sync_master;
            data[3] &= 0x03;
        }
        if let (true, Some(hash)) = (seal, hash) {
            let [_, a, b, c] =
                crc24(hash, id, 8, [data[0], data[1], data[2], data[3], data[4]]).to_be_bytes();
            data[5..8].copy_from_slice(&[a, b, c]);
        }
        let data = if remote { [0; 8] } else {
            let mut d = [0u8; 8];
            d[..usize::from(len)].copy_from_slice(&data[..usize::from(len)]);
            d
        };
        prop_assert_eq!(
            check(id, remote, len, data, |_| hash),
            shared_verdict(id, remote, len, data, hash)
        );
    }
}
