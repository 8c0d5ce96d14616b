//! The SimpleCAN data and time sync packets, `docs/simplecan.md` sections 1–4 and 10.
//!
//! A packet is one classic CAN data frame of 8 bytes on identifier `SC-ID` (data) or 02Fh
//! (sync). Bytes 5..7 hold a CRC-24 (polynomial 0x7B01BD, Hamming distance 8 over our
//! 56-bit data word) over the node hash of the SC-ID, which is never sent, then the identifier
//! and length, then bytes 0..4.
//!
//! # What cannot panic
//! [`decode`] takes any [`CanFrame`] and returns a [`Packet`] or a [`DecodeError`]; every
//! index it uses is into the frame's fixed 8-byte buffer.

use super::{HashLookup, NodeHash, ScId};
use crate::frame::{CanFrame, CanId};

/// The CAN identifier of every master's time sync packet (section 1).
pub const SYNC_IDENTIFIER: CanId = CanId::from_masked(0x02F);

/// Every SimpleCAN packet has 8 data bytes.
pub const PACKET_LENGTH: u8 = 8;

/// The CRC-24 of section 4: Koopman's 0xbd80de (explicit 0x17b01bd), initial value FFFFFFh,
/// MSB first, no final XOR. HD = 8 up to 59 data bits (Koopman's HD=6 table), and our data
/// word is 56 bits; `tests::sc_req_15_crc_detects_every_error_of_up_to_seven_bits`
/// recomputes that.
pub const CRC_ALGORITHM: crc::Algorithm<u32> = crc::Algorithm {
    width: 24,
    poly: 0x7B_01BD,
    init: 0xFF_FFFF,
    refin: false,
    refout: false,
    xorout: 0,
    check: 0x74_A079,
    residue: 0,
};

/// Bit by bit, without the crate's lookup table: a packet feeds 11 octets, and the table cost
/// more flash than the protocol's whole frame code (docs/footprint.md).
const CRC: crc::Crc<u32, crc::NoTable> = crc::Crc::<u32, crc::NoTable>::new(&CRC_ALGORITHM);

/// The largest sync offset: the last slot lasts 1 ms (section 3).
pub const MAX_OFFSET_MICROS: u16 = 999;

/// A data packet: one SDD entry's value, stamped with the cycle it was sent in (section 2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DataPacket {
    /// Whose value it is; also the CAN identifier.
    pub sc_id: ScId,
    /// The value (its safe state is 0, SC_REQ_05).
    pub value: u32,
    /// The low 8 bits of the number of the cycle the producer sent it in.
    pub cycle_stamp: u8,
}

/// A time sync packet (section 3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SyncPacket {
    master: ScId,
    cycle: u16,
    offset_micros: u16,
}

/// A decoded SimpleCAN packet whose CRC checked.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Packet {
    /// Safety data of one SC-ID.
    Data(DataPacket),
    /// A master's time.
    Sync(SyncPacket),
}

/// Why a frame is not a valid SimpleCAN packet (section 10, in the order checked).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecodeError {
    /// The identifier is neither 02Fh nor an SC-ID: not a SimpleCAN frame at all.
    NotSimpleCan,
    /// A remote frame on a SimpleCAN identifier.
    RemoteFrame,
    /// A data length code other than 8 on a SimpleCAN identifier.
    WrongLength {
        /// The length received.
        dlc: u8,
    },
    /// A sync whose byte 0 is not an SC-ID (030h..07Fh).
    InvalidMasterScId {
        /// The byte received.
        raw: u8,
    },
    /// A packet of an SC-ID whose node hash this SCL does not know, so its CRC cannot be
    /// checked.
    UnknownScId {
        /// The SC-ID: the identifier of a data packet, byte 0 of a sync.
        sc_id: ScId,
    },
    /// The CRC does not match (counted by the leaky counter, SC_REQ_42).
    BadCrc {
        /// The SC-ID whose node hash the CRC was checked with.
        sc_id: ScId,
    },
    /// A sync whose offset into the last slot is 1000 µs or more.
    OffsetOutOfRange {
        /// The offset received, in microseconds.
        offset_micros: u16,
    },
}

impl DecodeError {
    /// `true` for the packets SC_REQ_42's leaky counter counts: those whose CRC was checked
    /// and did not match.
    pub const fn is_bad_crc(self) -> bool {
        matches!(self, DecodeError::BadCrc { .. })
    }
}

impl SyncPacket {
    /// A sync from `master` for `cycle` (modulo 65536), taken `offset_micros` into the
    /// cycle's last slot; `None` when the offset is not below 1000 µs.
    pub const fn new(master: ScId, cycle: u16, offset_micros: u16) -> Option<Self> {
        if offset_micros <= MAX_OFFSET_MICROS {
            Some(SyncPacket {
                master,
                cycle,
                offset_micros,
            })
        } else {
            None
        }
    }

    /// The lowest SC-ID the master transmits.
    pub const fn master(&self) -> ScId {
        self.master
    }

    /// The cycle whose last slot carries this sync, modulo 65536.
    pub const fn cycle(&self) -> u16 {
        self.cycle
    }

    /// Microseconds into the last slot at which the master took its time, `0..=999`.
    pub const fn offset_micros(&self) -> u16 {
        self.offset_micros
    }

    /// The frame, signed with the node hash of the master's SC-ID.
    pub fn encode(&self, hash: NodeHash) -> CanFrame {
        let cycle = self.cycle.to_be_bytes();
        let offset = self.offset_micros.to_be_bytes();
        seal(
            SYNC_IDENTIFIER,
            hash,
            [self.master.raw(), cycle[0], cycle[1], offset[0], offset[1]],
        )
    }
}

impl DataPacket {
    /// The frame, signed with the node hash of its SC-ID.
    pub fn encode(&self, hash: NodeHash) -> CanFrame {
        let value = self.value.to_le_bytes();
        seal(
            data_identifier(self.sc_id),
            hash,
            [value[0], value[1], value[2], value[3], self.cycle_stamp],
        )
    }
}

/// The CAN identifier of `sc_id`'s data packets: the SC-ID itself.
pub const fn data_identifier(sc_id: ScId) -> CanId {
    CanId::from_masked(sc_id.raw() as u16)
}

/// `true` when `id` is one SimpleCAN uses (02Fh or an SC-ID): the frames to hand to
/// [`decode`], and the acceptance filter a driver applies.
pub const fn is_simplecan(id: CanId) -> bool {
    let raw = id.raw();
    raw == SYNC_IDENTIFIER.raw()
        || (raw >= ScId::LOWEST.raw() as u16 && raw <= ScId::HIGHEST.raw() as u16)
}

/// The CRC of section 4 over the node hash, `(identifier << 4) | DLC` and `content`.
// Out of line in the images: a marker of the emulator's profile
// (`emulator::profile::MARKERS`), found in every activation that runs it.
#[cfg_attr(target_os = "none", inline(never))]
fn crc(hash: NodeHash, id: CanId, content: &[u8; 5]) -> u32 {
    let mut digest = CRC.digest();
    digest.update(&hash.0.to_be_bytes());
    // An 11-bit identifier shifted by 4 and a 4-bit length fill 15 bits of the u16.
    digest.update(&((id.raw() << 4) | u16::from(PACKET_LENGTH)).to_be_bytes());
    digest.update(content);
    digest.finalize()
}

/// The 8-byte frame: `content`, then the CRC, most significant byte first.
// Out of line in the images: a marker of the emulator's profile
// (`emulator::profile::MARKERS`), found in every activation that runs it.
#[cfg_attr(target_os = "none", inline(never))]
fn seal(id: CanId, hash: NodeHash, content: [u8; 5]) -> CanFrame {
    let [_, high, middle, low] = crc(hash, id, &content).to_be_bytes();
    let [a, b, c, d, e] = content;
    CanFrame::with_len(id, [a, b, c, d, e, high, middle, low], PACKET_LENGTH)
}

/// The SimpleCAN packet `frame` carries, checked in the order of section 10.
///
/// `hashes` gives the node hash of a data packet's SC-ID or of a sync's master.
pub fn decode(frame: &CanFrame, hashes: &impl HashLookup) -> Result<Packet, DecodeError> {
    let id = frame.id();
    if !is_simplecan(id) {
        return Err(DecodeError::NotSimpleCan);
    }
    if frame.is_remote() {
        return Err(DecodeError::RemoteFrame);
    }
    if frame.dlc() != PACKET_LENGTH {
        return Err(DecodeError::WrongLength { dlc: frame.dlc() });
    }
    let bytes = frame.raw_data();
    let content = [bytes[0], bytes[1], bytes[2], bytes[3], bytes[4]];
    let received_crc = u32::from_be_bytes([0, bytes[5], bytes[6], bytes[7]]);
    let sync = id == SYNC_IDENTIFIER;
    let sc_id = if sync {
        ScId::new(content[0]).ok_or(DecodeError::InvalidMasterScId { raw: content[0] })?
    } else {
        // `is_simplecan` placed a data identifier in 0x30..=0x7F, which is a u8 and an SC-ID.
        ScId::new(id.raw() as u8).ok_or(DecodeError::NotSimpleCan)?
    };
    let hash = hashes
        .node_hash(sc_id)
        .ok_or(DecodeError::UnknownScId { sc_id })?;
    if crc(hash, id, &content) != received_crc {
        return Err(DecodeError::BadCrc { sc_id });
    }
    if sync {
        let cycle = u16::from_be_bytes([content[1], content[2]]);
        let offset_micros = u16::from_be_bytes([content[3], content[4]]);
        SyncPacket::new(sc_id, cycle, offset_micros)
            .map(Packet::Sync)
            .ok_or(DecodeError::OffsetOutOfRange { offset_micros })
    } else {
        Ok(Packet::Data(DataPacket {
            sc_id,
            value: u32::from_le_bytes([content[0], content[1], content[2], content[3]]),
            cycle_stamp: content[4],
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const HASH_1: NodeHash = NodeHash(0x1234_5678);
    const HASH_2: NodeHash = NodeHash(0xA5C3_0F96);

    fn sc(raw: u8) -> ScId {
        ScId::new(raw).unwrap()
    }

    /// The configuration of the vectors: SC-ID 30h has hash 1, 7Fh hash 2, 31h another one.
    fn hashes(sc_id: ScId) -> Option<NodeHash> {
        match sc_id.raw() {
            0x30 => Some(HASH_1),
            0x31 => Some(NodeHash(0x0BAD_CAFE)),
            0x7F => Some(HASH_2),
            _ => None,
        }
    }

    fn frame(id: u16, bytes: [u8; 8]) -> CanFrame {
        CanFrame::new(CanId::new(id).unwrap(), &bytes).unwrap()
    }

    /// A second CRC-24, bit by bit from section 4's text, for the tests only.
    fn reference_crc(octets: &[u8]) -> u32 {
        let mut crc: u32 = 0xFF_FFFF;
        for octet in octets {
            for bit in (0..8).rev() {
                let input = (octet >> bit) & 1 == 1;
                let top = crc & 0x80_0000 != 0;
                crc = (crc << 1) & 0xFF_FFFF;
                if input != top {
                    crc ^= 0x7B_01BD;
                }
            }
        }
        crc
    }

    // docs/simplecan.md section 9, vector by vector.
    const VECTOR_1: [u8; 8] = [0x01, 0x00, 0x00, 0x00, 0x05, 0xA4, 0x18, 0x27];
    const VECTOR_2: [u8; 8] = [0xEF, 0xBE, 0xAD, 0xDE, 0xFF, 0x8B, 0x1C, 0x68];
    const VECTOR_3: [u8; 8] = [0x30, 0x01, 0x02, 0x00, 0xFA, 0xFD, 0x34, 0x07];

    #[test]
    fn sc_req_15_crc_check_value_and_parameters() {
        assert_eq!(CRC.checksum(b"123456789"), 0x74_A079);
        assert_eq!(reference_crc(b"123456789"), 0x74_A079);
    }

    #[test]
    fn sc_req_15_data_vectors_of_the_document() {
        let one = DataPacket {
            sc_id: sc(0x30),
            value: 1,
            cycle_stamp: 5,
        };
        assert_eq!(one.encode(HASH_1), frame(0x030, VECTOR_1));
        assert_eq!(
            decode(&frame(0x030, VECTOR_1), &hashes),
            Ok(Packet::Data(one))
        );
        let two = DataPacket {
            sc_id: sc(0x7F),
            value: 0xDEAD_BEEF,
            cycle_stamp: 0xFF,
        };
        assert_eq!(two.encode(HASH_2), frame(0x07F, VECTOR_2));
        assert_eq!(
            decode(&frame(0x07F, VECTOR_2), &hashes),
            Ok(Packet::Data(two))
        );
    }

    #[test]
    fn sc_req_15_sync_vector_of_the_document() {
        let sync = SyncPacket::new(sc(0x30), 0x0102, 250).unwrap();
        assert_eq!(sync.encode(HASH_1), frame(0x02F, VECTOR_3));
        assert_eq!(
            decode(&frame(0x02F, VECTOR_3), &hashes),
            Ok(Packet::Sync(sync))
        );
    }

    /// The hash is in the CRC and nowhere on the wire: the same packet under another hash
    /// differs only in bytes 5..7, and a consumer with the wrong hash rejects it.
    #[test]
    fn sc_req_15_the_node_hash_is_signed_in_but_never_sent() {
        let packet = DataPacket {
            sc_id: sc(0x30),
            value: 1,
            cycle_stamp: 5,
        };
        let right = packet.encode(HASH_1);
        let other = packet.encode(HASH_2);
        assert_eq!(right.data()[..5], other.data()[..5]);
        assert_ne!(right.data()[5..], other.data()[5..]);
        assert_eq!(
            decode(&other, &hashes),
            Err(DecodeError::BadCrc { sc_id: sc(0x30) })
        );
    }

    /// Corruption of the data: every single bit of bytes 0..4 and of the CRC.
    #[test]
    fn sc_req_15_every_corrupted_bit_of_the_payload_is_rejected() {
        for (id, vector) in [(0x030, VECTOR_1), (0x07F, VECTOR_2), (0x02F, VECTOR_3)] {
            for bit in 0..64 {
                let mut bytes = vector;
                bytes[bit / 8] ^= 1 << (bit % 8);
                let result = decode(&frame(id, bytes), &hashes);
                // A sync whose byte 0 left 30h..7Fh, or names a master without a known
                // hash, is rejected before its CRC is checked.
                let before_crc = matches!(
                    result,
                    Err(DecodeError::InvalidMasterScId { .. } | DecodeError::UnknownScId { .. })
                );
                assert!(
                    result.is_err_and(|e| e.is_bad_crc()) || (id == 0x02F && bit < 8 && before_crc),
                    "identifier {id:03X}h, bit {bit}: {result:?}"
                );
            }
        }
    }

    /// Corruption of the identifier: into another SC-ID with a known hash (masquerade: the
    /// other hash does not sign it), into one without (cannot be checked), into the sync
    /// identifier, and out of SimpleCAN's range.
    #[test]
    fn sc_req_15_a_corrupted_identifier_is_rejected() {
        assert_eq!(
            decode(&frame(0x031, VECTOR_1), &hashes),
            Err(DecodeError::BadCrc { sc_id: sc(0x31) })
        );
        assert_eq!(
            decode(&frame(0x032, VECTOR_1), &hashes),
            Err(DecodeError::UnknownScId { sc_id: sc(0x32) })
        );
        assert_eq!(
            decode(&frame(0x02F, VECTOR_1), &hashes),
            Err(DecodeError::InvalidMasterScId { raw: 0x01 })
        );
        // A data packet of 30h read as a sync from master 30h: the identifier is in the CRC.
        let mut bytes = VECTOR_1;
        bytes[0] = 0x30;
        let data = decode(&frame(0x030, bytes), &hashes);
        let sync = decode(&frame(0x02F, bytes), &hashes);
        assert!(data.is_err_and(|e| e.is_bad_crc()) && sync.is_err_and(|e| e.is_bad_crc()));
        for outside in [0x000, 0x001, 0x02E, 0x080, 0x101, 0x7FF] {
            assert_eq!(
                decode(&frame(outside, VECTOR_1), &hashes),
                Err(DecodeError::NotSimpleCan)
            );
        }
    }

    /// Corruption of the length, and remote frames.
    #[test]
    fn sc_req_15_a_wrong_length_or_a_remote_frame_is_rejected() {
        let id = CanId::new(0x030).unwrap();
        for dlc in 0..8 {
            let short = CanFrame::from_parts(id, dlc, VECTOR_1).unwrap();
            assert_eq!(
                decode(&short, &hashes),
                Err(DecodeError::WrongLength { dlc })
            );
        }
        assert_eq!(
            decode(&CanFrame::remote(id, 8).unwrap(), &hashes),
            Err(DecodeError::RemoteFrame)
        );
    }

    #[test]
    fn a_sync_offset_of_a_whole_slot_or_more_is_rejected() {
        assert!(SyncPacket::new(sc(0x30), 0, 999).is_some());
        assert!(SyncPacket::new(sc(0x30), 0, 1000).is_none());
        // A frame whose CRC is right but whose offset is 1000 µs, built with the reference CRC.
        let content = [0x30, 0x00, 0x00, 0x03, 0xE8];
        let mut fed = HASH_1.0.to_be_bytes().to_vec();
        fed.extend_from_slice(&[0x02, 0xF8]);
        fed.extend_from_slice(&content);
        let [_, a, b, c] = reference_crc(&fed).to_be_bytes();
        let bytes = [
            content[0], content[1], content[2], content[3], content[4], a, b, c,
        ];
        assert_eq!(
            decode(&frame(0x02F, bytes), &hashes),
            Err(DecodeError::OffsetOutOfRange {
                offset_micros: 1000
            })
        );
    }

    /// `x^k mod G`: the syndrome of an error in the codeword bit `k` places from its end.
    fn column(k: usize) -> u32 {
        let mut remainder: u32 = 1;
        for _ in 0..k {
            let top = remainder & 0x80_0000 != 0;
            remainder = (remainder << 1) & 0xFF_FFFF;
            if top {
                remainder ^= 0x7B_01BD;
            }
        }
        remainder
    }

    /// The smallest weight of an undetected error among patterns of up to 7 bits over
    /// `data_bits + 24` codeword bits, or `None` when every one is detected. Every pattern of
    /// weight at most 7 is the union of one of at most 3 bits and one of at most 4; it goes
    /// undetected exactly when their syndromes are equal (or a single part's is zero).
    fn undetected_weight_up_to_7(data_bits: usize) -> Option<usize> {
        let n = data_bits + 24;
        let columns: Vec<u32> = (0..n).map(column).collect();
        // seen[w]: a bit per 24-bit syndrome reached by some pattern of weight w.
        let mut seen = vec![vec![0u64; 1 << 18]; 5];
        let mut mark = |w: usize, syndrome: u32| -> Option<usize> {
            if syndrome == 0 {
                return Some(w);
            }
            let (word, bit) = ((syndrome >> 6) as usize, syndrome & 63);
            for (other, set) in seen.iter().enumerate().skip(1) {
                if set[word] >> bit & 1 == 1 && w + other <= 7 && other <= w {
                    return Some(w + other);
                }
            }
            seen[w][word] |= 1 << bit;
            None
        };
        for &single in &columns {
            if let Some(w) = mark(1, single) {
                return Some(w);
            }
        }
        for a in 0..n {
            for b in a + 1..n {
                if let Some(w) = mark(2, columns[a] ^ columns[b]) {
                    return Some(w);
                }
            }
        }
        for a in 0..n {
            for b in a + 1..n {
                for c in b + 1..n {
                    if let Some(w) = mark(3, columns[a] ^ columns[b] ^ columns[c]) {
                        return Some(w);
                    }
                }
            }
        }
        for a in 0..n {
            for b in a + 1..n {
                let ab = columns[a] ^ columns[b];
                for c in b + 1..n {
                    let abc = ab ^ columns[c];
                    for &fourth in &columns[c + 1..] {
                        if let Some(w) = mark(4, abc ^ fourth) {
                            return Some(w);
                        }
                    }
                }
            }
        }
        None
    }

    /// Section 4: HD = 8 over our 56-bit data word, recomputed rather than taken from
    /// Koopman's table; and at 60 bits (one past the table's 59) a pattern of at most 7 bits
    /// slips through, so the table and this search agree on the boundary.
    #[test]
    fn sc_req_15_crc_detects_every_error_of_up_to_seven_bits() {
        assert_eq!(undetected_weight_up_to_7(56), None);
        assert_eq!(undetected_weight_up_to_7(60), Some(6));
    }

    /// The columns of the search are the real packet's: flipping one transmitted bit of a
    /// data packet changes its CRC by exactly the column of that bit's place in the
    /// codeword (data word bit `i` from the end is codeword place `24 + i`).
    #[test]
    fn sc_req_15_the_search_models_the_real_packet() {
        let content = [0x01, 0x00, 0x00, 0x00, 0x05];
        let id = CanId::new(0x030).unwrap();
        let original = crc(HASH_1, id, &content);
        for bit in 0..40 {
            let mut flipped = content;
            flipped[4 - bit / 8] ^= 1 << (bit % 8);
            assert_eq!(crc(HASH_1, id, &flipped) ^ original, column(24 + bit));
        }
        for bit in 0..15 {
            // The identifier and DLC word: bits 0..3 are the DLC, 4..14 the identifier.
            let word = (id.raw() << 4) | 8;
            let mut digest = CRC.digest();
            digest.update(&HASH_1.0.to_be_bytes());
            digest.update(&(word ^ (1 << bit)).to_be_bytes());
            digest.update(&content);
            assert_eq!(digest.finalize() ^ original, column(24 + 40 + bit));
        }
    }

    proptest! {
        /// The table-driven CRC of the `crc` crate and the bitwise one agree, and so every
        /// packet encodes and decodes to itself.
        #[test]
        fn sc_req_15_crc_matches_the_reference(
            hash in any::<u32>(), raw in 0x30u8..=0x7F, value in any::<u32>(), stamp in any::<u8>()
        ) {
            let sc_id = sc(raw);
            let packet = DataPacket { sc_id, value, cycle_stamp: stamp };
            let frame = packet.encode(NodeHash(hash));
            let mut fed = hash.to_be_bytes().to_vec();
            fed.extend_from_slice(&((u16::from(raw) << 4) | 8).to_be_bytes());
            fed.extend_from_slice(&frame.data()[..5]);
            let [_, a, b, c] = reference_crc(&fed).to_be_bytes();
            prop_assert_eq!(&frame.data()[5..], &[a, b, c]);
            let lookup = |id: ScId| (id == sc_id).then_some(NodeHash(hash));
            prop_assert_eq!(decode(&frame, &lookup), Ok(Packet::Data(packet)));
        }

        /// Any frame at all decodes to a value or an error, never a panic, and a packet that
        /// decodes encodes back to the same frame.
        #[test]
        fn decoding_any_frame_is_total(id in 0u16..=0x7FF, dlc in 0u8..=8, bytes in any::<[u8; 8]>()) {
            let frame = CanFrame::from_parts(CanId::new(id).unwrap(), dlc, bytes).unwrap();
            match decode(&frame, &hashes) {
                Ok(Packet::Data(data)) => prop_assert_eq!(data.encode(hashes(data.sc_id).unwrap()), frame),
                Ok(Packet::Sync(sync)) => prop_assert_eq!(sync.encode(hashes(sync.master()).unwrap()), frame),
                Err(_) => {}
            }
        }
    }
}
