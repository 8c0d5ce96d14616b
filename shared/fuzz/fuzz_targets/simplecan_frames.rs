//! Any CAN frame into the SimpleCAN decoder (`docs/simplecan.md` sections 1–4, 10): no panic;
//! a frame that decodes is exactly the frame its packet encodes to; and no single bit flip of
//! a valid packet's payload or length decodes to another packet (HD 8: section 4). A flip
//! that changes the SC-ID (identifier, or a sync's byte 0) is checked against another node
//! hash, and the fuzzer chooses the hashes, so it could pick two that collide; that residual
//! is the tool's to keep out by its choice of hashes, and such flips are only decoded here.
#![no_main]

use arbitrary::Arbitrary;
use libfuzzer_sys::fuzz_target;
use shared::simplecan::frame::{DataPacket, Packet, SyncPacket, decode};
use shared::simplecan::{NodeHash, ScId};
use shared::{CanFrame, CanId};

/// Where the frame comes from: raw bytes, or a packet the encoder builds (so that the
/// corrupted-bit check runs on valid packets, not only on the few random frames whose CRC
/// happens to match).
#[derive(Arbitrary, Debug)]
enum Source {
    Raw {
        id: u16,
        remote: bool,
        dlc: u8,
        data: [u8; 8],
    },
    Data {
        sc_id: u8,
        value: u32,
        cycle_stamp: u8,
    },
    Sync {
        master: u8,
        cycle: u16,
        offset_micros: u16,
    },
}

#[derive(Arbitrary, Debug)]
struct Input {
    source: Source,
    /// Node hashes of the SC-IDs this SCL knows: SC-ID 30h + i has `hashes[i]`.
    hashes: [u32; 4],
    flip: u8,
}

fuzz_target!(|input: Input| {
    let lookup = |sc_id: ScId| {
        let index = usize::from(sc_id.raw() - ScId::LOWEST.raw());
        input.hashes.get(index).copied().map(NodeHash)
    };
    let frame = match input.source {
        Source::Raw {
            id,
            remote,
            dlc,
            data,
        } => {
            let Ok(id) = CanId::new(id & 0x7FF) else {
                return;
            };
            let frame = if remote {
                CanFrame::remote(id, dlc % 9)
            } else {
                CanFrame::from_parts(id, dlc % 9, data)
            };
            let Ok(frame) = frame else {
                return;
            };
            frame
        }
        Source::Data {
            sc_id,
            value,
            cycle_stamp,
        } => {
            let Some(sc_id) = ScId::new(sc_id) else {
                return;
            };
            let Some(hash) = lookup(sc_id) else {
                return;
            };
            DataPacket {
                sc_id,
                value,
                cycle_stamp,
            }
            .encode(hash)
        }
        Source::Sync {
            master,
            cycle,
            offset_micros,
        } => {
            let Some(master) = ScId::new(master) else {
                return;
            };
            let Some(hash) = lookup(master) else {
                return;
            };
            let Some(sync) = SyncPacket::new(master, cycle, offset_micros) else {
                return;
            };
            sync.encode(hash)
        }
    };
    let id = frame.id();
    let Ok(packet) = decode(&frame, &lookup) else {
        return;
    };
    let (sc_id, encoded) = match packet {
        Packet::Data(data) => (data.sc_id, data.encode(lookup(data.sc_id).unwrap())),
        Packet::Sync(sync) => (sync.master(), sync.encode(lookup(sync.master()).unwrap())),
    };
    assert_eq!(encoded, frame, "{sc_id:?}");
    // One flipped bit among the 64 payload bits, 11 identifier bits and 4 length bits.
    let bit = usize::from(input.flip) % 79;
    let same_sc_id = !(64..75).contains(&bit) && !(matches!(packet, Packet::Sync(_)) && bit < 8);
    let corrupted = if bit < 64 {
        let mut data = *frame.raw_data();
        data[bit / 8] ^= 1 << (bit % 8);
        CanFrame::from_parts(id, 8, data)
    } else if bit < 75 {
        let flipped = CanId::new(id.raw() ^ (1 << (bit - 64))).unwrap();
        CanFrame::from_parts(flipped, 8, *frame.raw_data())
    } else {
        CanFrame::from_parts(id, 8 ^ (1 << (bit - 75)), *frame.raw_data())
    };
    if let Ok(corrupted) = corrupted {
        let result = decode(&corrupted, &lookup);
        assert!(!same_sc_id || result.is_err(), "bit {bit} went undetected");
    }
});
