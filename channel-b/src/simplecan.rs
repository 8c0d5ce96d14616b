//! Channel B's own SimpleCAN decoder (SC_REQ_10, SC_REQ_24).
//!
//! Channel A forwards each SimpleCAN frame it receives to B as it came off the bus
//! (`Message::SimpleCanPacket`: identifier, length, raw bytes), and both validate it. This
//! decoder is deliberately separate from `shared::simplecan::frame`, so that a fault in one
//! (a wrong table, a wrong byte order, a wrong check order) is not shared by both channels
//! (IEC 61784-3 Model C: two independent checks of one packet):
//!
//! - the CRC is computed bit by bit from the polynomial of docs/simplecan.md section 4,
//!   over one 88-bit word assembled in a `u128`, not by the `crc` crate's table;
//! - it works on the raw identifier, length and bytes, not on `CanFrame`, `ScId` or
//!   `NodeHash`, and returns its verdict as plain numbers, which the cross-check compares
//!   with channel A's.
//!
//! The tests compare it with the shared decoder on the worked vectors of section 9 and on
//! random frames.

/// CRC-24 polynomial 0x7B01BD without its x^24 term (docs/simplecan.md section 4).
const POLYNOMIAL: u32 = 0x7B_01BD;
/// The identifier of a time sync packet.
const SYNC_ID: u16 = 0x02F;
/// The lowest and highest SC-ID.
const SC_IDS: core::ops::RangeInclusive<u16> = 0x030..=0x07F;

/// What channel B concluded about one SimpleCAN frame: the fields it cross-checks with A.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// A data packet whose CRC checked: SC-ID, value, cycle stamp.
    Data {
        /// SC-ID (the identifier).
        sc_id: u8,
        /// The value, little-endian in bytes 0..4.
        value: u32,
        /// Byte 4.
        cycle_stamp: u8,
    },
    /// A sync whose CRC and offset checked.
    Sync {
        /// The master's SC-ID (byte 0).
        master: u8,
        /// The cycle number, bytes 1..3 big-endian.
        cycle: u16,
        /// Offset into the last slot in µs, bytes 3..5 big-endian (below 1000).
        offset_micros: u16,
    },
    /// A SimpleCAN identifier whose frame is not a valid packet: B's reason, in the order of
    /// docs/simplecan.md section 10.
    Invalid(Rejection),
    /// Not a SimpleCAN identifier.
    NotSimpleCan,
}

/// Why channel B rejected a frame on a SimpleCAN identifier.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rejection {
    /// A remote frame.
    Remote,
    /// A length other than 8.
    Length,
    /// A sync whose byte 0 is not an SC-ID.
    Master,
    /// An SC-ID whose node hash B does not know.
    UnknownScId,
    /// The CRC does not match.
    Crc,
    /// A sync offset of 1000 µs or more.
    Offset,
}

/// The CRC of section 4, bit by bit: node hash (32 bits), a 0 bit, identifier (11), DLC (4),
/// five content bytes (40), MSB first; initial value FFFFFFh, no reflection, no final XOR.
pub fn crc24(hash: u32, id: u16, dlc: u8, content: [u8; 5]) -> u32 {
    let mut word = u128::from(hash);
    word = (word << 16) | u128::from(((id & 0x7FF) << 4) | u16::from(dlc & 0x0F));
    for byte in content {
        word = (word << 8) | u128::from(byte);
    }
    let mut register: u32 = 0xFF_FFFF;
    for bit in (0..88).rev() {
        let incoming = ((word >> bit) & 1) as u32;
        let top = (register >> 23) & 1;
        register = (register << 1) & 0xFF_FFFF;
        if top ^ incoming == 1 {
            register ^= POLYNOMIAL;
        }
    }
    register
}

/// Channel B's verdict on the frame `id`, `len`, `data` (as forwarded or as heard), with the
/// node hash `hash_of(sc_id)` (`None`: unknown SC-ID).
pub fn check(
    id: u16,
    remote: bool,
    len: u8,
    data: [u8; 8],
    hash_of: impl Fn(u8) -> Option<u32>,
) -> Verdict {
    let sync = id == SYNC_ID;
    if !sync && !SC_IDS.contains(&id) {
        return Verdict::NotSimpleCan;
    }
    let reject = Verdict::Invalid;
    if remote {
        return reject(Rejection::Remote);
    }
    if len != 8 {
        return reject(Rejection::Length);
    }
    let sc_id = if sync { data[0] } else { id as u8 };
    if !SC_IDS.contains(&u16::from(sc_id)) {
        return reject(Rejection::Master);
    }
    let Some(hash) = hash_of(sc_id) else {
        return reject(Rejection::UnknownScId);
    };
    let content = [data[0], data[1], data[2], data[3], data[4]];
    let sent = (u32::from(data[5]) << 16) | (u32::from(data[6]) << 8) | u32::from(data[7]);
    if crc24(hash, id, len, content) != sent {
        return reject(Rejection::Crc);
    }
    if sync {
        let offset_micros = (u16::from(data[3]) << 8) | u16::from(data[4]);
        if offset_micros >= 1000 {
            return reject(Rejection::Offset);
        }
        Verdict::Sync {
            master: sc_id,
            cycle: (u16::from(data[1]) << 8) | u16::from(data[2]),
            offset_micros,
        }
    } else {
        Verdict::Data {
            sc_id,
            value: u32::from(data[0])
                | (u32::from(data[1]) << 8)
                | (u32::from(data[2]) << 16)
                | (u32::from(data[3]) << 24),
            cycle_stamp: data[4],
        }
    }
}

#[cfg(test)]
mod tests;
