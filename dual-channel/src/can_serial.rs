//! CAN frames over a serial line, for the emulated network: QEMU models no CAN controller, so
//! the QEMU board layer sends and receives CAN frames on USART2, and a host-side bus hub puts
//! them on the simulated bus.
//!
//! ```text
//! COBS( id: u16 LE, bit 15 = RTR | dlc: u8 | data[dlc] | CRC-16/XMODEM LE ) 0x00
//! ```

use crate::cobs_frames::{Completed, Reassembler};
use crc::{CRC_16_XMODEM, Crc};
use shared::{CanFrame, CanId};

const CRC: Crc<u16> = Crc::<u16>::new(&CRC_16_XMODEM);
/// Largest unencoded frame: identifier, DLC, 8 data bytes, CRC.
const MAX_RAW: usize = 2 + 1 + 8 + 2;
/// Largest encoded frame, delimiter included.
pub const MAX_WIRE: usize = cobs::max_encoding_length(MAX_RAW) + 1;

/// Why received bytes were not a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SerialError {
    /// Bad COBS, bad length, bad CRC, or an identifier or DLC out of range.
    Malformed,
}

/// The bytes for `frame`, delimiter included.
pub fn encode(frame: &CanFrame) -> heapless::Vec<u8, MAX_WIRE> {
    let mut raw = [0u8; MAX_RAW];
    let id = frame.id().raw() | if frame.is_remote() { 0x8000 } else { 0 };
    raw[..2].copy_from_slice(&id.to_le_bytes());
    raw[2] = frame.dlc();
    let data = if frame.is_remote() {
        &[][..]
    } else {
        frame.data()
    };
    raw[3..3 + data.len()].copy_from_slice(data);
    let end = 3 + data.len();
    let crc = CRC.checksum(&raw[..end]);
    raw[end..end + 2].copy_from_slice(&crc.to_le_bytes());
    let mut wire = [0u8; MAX_WIRE];
    // `wire` holds the longest encoding of `MAX_RAW` bytes.
    let len = cobs::encode(&raw[..end + 2], &mut wire);
    let mut out = heapless::Vec::new();
    // Cannot fail: `len` + 1 <= MAX_WIRE.
    let _ = out.extend_from_slice(&wire[..len]);
    let _ = out.push(0);
    out
}

/// Reassembles frames from a byte stream.
#[derive(Clone, Debug, Default)]
pub struct Decoder {
    frames: Reassembler<MAX_WIRE>,
}

impl Decoder {
    /// An empty decoder.
    pub const fn new() -> Self {
        Decoder {
            frames: Reassembler::new(),
        }
    }

    /// Feeds one byte; returns a frame (or why not) when the byte ends one.
    pub fn push(&mut self, byte: u8) -> Option<Result<CanFrame, SerialError>> {
        let mut raw = [0u8; MAX_WIRE];
        Some(match self.frames.push(byte, &mut raw)? {
            Completed::Broken => Err(SerialError::Malformed),
            Completed::Frame(len) => parse(raw.get(..len).unwrap_or_default()),
        })
    }
}

fn parse(raw: &[u8]) -> Result<CanFrame, SerialError> {
    if raw.len() < 5 {
        return Err(SerialError::Malformed);
    }
    let (body, crc) = raw.split_at(raw.len() - 2);
    if CRC.checksum(body) != u16::from_le_bytes([crc[0], crc[1]]) {
        return Err(SerialError::Malformed);
    }
    let word = u16::from_le_bytes([body[0], body[1]]);
    let id = CanId::new(word & 0x7FFF).map_err(|_| SerialError::Malformed)?;
    let dlc = body[2];
    let data = &body[3..];
    if word & 0x8000 != 0 {
        if !data.is_empty() {
            return Err(SerialError::Malformed);
        }
        return CanFrame::remote(id, dlc).map_err(|_| SerialError::Malformed);
    }
    if usize::from(dlc) != data.len() {
        return Err(SerialError::Malformed);
    }
    CanFrame::new(id, data).map_err(|_| SerialError::Malformed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn frames_round_trip(id in 0u16..=0x7FF, data in proptest::collection::vec(any::<u8>(), 0..=8), remote: bool) {
            let id = CanId::new(id).unwrap();
            let frame = if remote {
                CanFrame::remote(id, data.len() as u8).unwrap()
            } else {
                CanFrame::new(id, &data).unwrap()
            };
            let mut decoder = Decoder::new();
            let results: Vec<_> = encode(&frame).iter().filter_map(|&b| decoder.push(b)).collect();
            prop_assert_eq!(results, vec![Ok(frame)]);
        }

        #[test]
        fn noise_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
            let mut decoder = Decoder::new();
            for byte in bytes {
                let _ = decoder.push(byte);
            }
        }
    }
}
