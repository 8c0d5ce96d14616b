//! A classic CAN frame as the bxCAN model and a bus model exchange it: identifier, remote
//! flag, DLC and data, with the arbitration order and the bit length (stuff bits included)
//! that ISO 11898-1 gives it.

/// A CAN identifier: 11-bit standard or 29-bit extended (RM0090 32.7.3, the IDE bit).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Identifier {
    /// An 11-bit standard identifier (STID).
    Standard(u16),
    /// A 29-bit extended identifier (STID in the top 11 bits, EXID in the low 18).
    Extended(u32),
}

impl Identifier {
    /// The 11 bits sent first on the bus (STID for both formats).
    pub fn standard_part(self) -> u32 {
        match self {
            Identifier::Standard(id) => u32::from(id) & 0x7FF,
            Identifier::Extended(id) => (id >> 18) & 0x7FF,
        }
    }

    /// The 18 extension bits (EXID); 0 for a standard identifier.
    pub fn extension_part(self) -> u32 {
        match self {
            Identifier::Standard(_) => 0,
            Identifier::Extended(id) => id & 0x3_FFFF,
        }
    }

    /// Whether the identifier is extended (IDE = 1).
    pub fn is_extended(self) -> bool {
        matches!(self, Identifier::Extended(_))
    }
}

/// One data or remote frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Frame {
    /// The identifier.
    pub id: Identifier,
    /// A remote frame (RTR = 1): no data field.
    pub remote: bool,
    /// The data length code as sent (0 to 15; values above 8 carry 8 bytes).
    pub dlc: u8,
    /// The data bytes; only the first [`Frame::data_len`] are sent.
    pub data: [u8; 8],
}

/// The bits after the stuffed part of a frame: CRC delimiter, ACK slot and delimiter, EOF.
const UNSTUFFED_TAIL_BITS: u32 = 1 + 2 + 7;

/// The intermission between two frames (ISO 11898-1 interframe space), in bits.
pub const INTERMISSION_BITS: u32 = 3;

impl Frame {
    /// A data frame (DLC = the length of `data`, at most 8 bytes are kept).
    pub fn data(id: Identifier, data: &[u8]) -> Frame {
        let len = data.len().min(8);
        let mut bytes = [0; 8];
        bytes[..len].copy_from_slice(&data[..len]);
        Frame {
            id,
            remote: false,
            dlc: len as u8,
            data: bytes,
        }
    }

    /// A remote frame asking for `dlc` bytes.
    pub fn remote(id: Identifier, dlc: u8) -> Frame {
        Frame {
            id,
            remote: true,
            dlc: dlc & 0xF,
            data: [0; 8],
        }
    }

    /// The number of data bytes on the bus: none for a remote frame, else DLC capped at 8.
    pub fn data_len(&self) -> usize {
        if self.remote {
            0
        } else {
            usize::from(self.dlc.min(8))
        }
    }

    /// The frame's arbitration order: the bits of the arbitration field as sent, so that
    /// the lower key wins arbitration on the bus (dominant 0 beats recessive 1). Standard:
    /// STID, RTR, IDE = 0. Extended: STID, SRR = 1, IDE = 1, EXID, RTR. A standard frame
    /// beats an extended one with the same STID at the SRR/RTR or IDE bit.
    pub fn arbitration_key(&self) -> u64 {
        let stid = u64::from(self.id.standard_part());
        let rtr = u64::from(self.remote);
        match self.id {
            Identifier::Standard(_) => (stid << 21) | (rtr << 20),
            Identifier::Extended(_) => {
                let exid = u64::from(self.id.extension_part());
                (stid << 21) | (1 << 20) | (1 << 19) | (exid << 1) | rtr
            }
        }
    }

    /// The frame's bits from SOF to the end of the data field, before stuffing.
    fn unstuffed_head(&self) -> Vec<bool> {
        let mut bits = Vec::with_capacity(64 + 64);
        let push = |value: u32, width: u32, bits: &mut Vec<bool>| {
            for shift in (0..width).rev() {
                bits.push((value >> shift) & 1 == 1);
            }
        };
        push(0, 1, &mut bits); // SOF
        push(self.id.standard_part(), 11, &mut bits);
        match self.id {
            Identifier::Standard(_) => {
                push(u32::from(self.remote), 1, &mut bits); // RTR
                push(0, 1, &mut bits); // IDE
                push(0, 1, &mut bits); // r0
            }
            Identifier::Extended(_) => {
                push(1, 1, &mut bits); // SRR
                push(1, 1, &mut bits); // IDE
                push(self.id.extension_part(), 18, &mut bits);
                push(u32::from(self.remote), 1, &mut bits); // RTR
                push(0, 2, &mut bits); // r1, r0
            }
        }
        push(u32::from(self.dlc & 0xF), 4, &mut bits);
        for byte in &self.data[..self.data_len()] {
            push(u32::from(*byte), 8, &mut bits);
        }
        bits
    }

    /// The frame's length on the bus in bits, from SOF to the end of EOF, with the stuff
    /// bits the transmitter inserts (ISO 11898-1: after five equal bits in SOF..CRC, one of
    /// the opposite value). The intermission that follows is [`INTERMISSION_BITS`].
    pub fn bit_length(&self) -> u32 {
        let mut bits = self.unstuffed_head();
        let crc = crc15(&bits);
        for shift in (0..15).rev() {
            bits.push((crc >> shift) & 1 == 1);
        }
        let mut stuffed = 0u32;
        let mut run_value = None;
        let mut run_length = 0u32;
        for bit in bits.iter().copied() {
            if Some(bit) == run_value {
                run_length += 1;
            } else {
                run_value = Some(bit);
                run_length = 1;
            }
            if run_length == 5 {
                // The stuff bit has the opposite value and starts the next run.
                stuffed += 1;
                run_value = Some(!bit);
                run_length = 1;
            }
        }
        bits.len() as u32 + stuffed + UNSTUFFED_TAIL_BITS
    }
}

/// The CAN CRC (ISO 11898-1 10.4.2.6: generator x^15 + x^14 + x^10 + x^8 + x^7 + x^4 + x^3 +
/// 1, register cleared before SOF) over a bit sequence, most significant first.
pub fn crc15(bits: &[bool]) -> u16 {
    let mut crc: u16 = 0;
    for bit in bits.iter().copied() {
        let next = bit ^ (crc & 0x4000 != 0);
        crc = (crc << 1) & 0x7FFF;
        if next {
            crc ^= 0x4599;
        }
    }
    crc
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bits_of(bytes: &[u8]) -> Vec<bool> {
        bytes
            .iter()
            .flat_map(|byte| (0..8).rev().map(move |shift| (byte >> shift) & 1 == 1))
            .collect()
    }

    #[test]
    fn iso11898_1_crc15_matches_the_catalogued_check_value() {
        // CRC-15/CAN's catalogued check value over the ASCII string "123456789".
        assert_eq!(crc15(&bits_of(b"123456789")), 0x059E);
    }

    #[test]
    fn iso11898_1_standard_frame_without_stuffing_is_44_bits_plus_8_per_byte_at_least() {
        // Minimum lengths without stuff bits: standard 44 + 8n, extended 64 + 8n (SOF to EOF).
        for len in 0..=8usize {
            let data = [0x55u8; 8];
            let standard = Frame::data(Identifier::Standard(0x555 & 0x7FF), &data[..len]);
            let extended = Frame::data(Identifier::Extended(0x0AAA_AAAA), &data[..len]);
            assert!(standard.bit_length() >= 44 + 8 * len as u32);
            assert!(extended.bit_length() >= 64 + 8 * len as u32);
            // Stuffing adds at most one bit per four after the first five (SOF..CRC).
            assert!(standard.bit_length() <= 44 + 8 * len as u32 + (34 + 8 * len as u32 - 1) / 4);
        }
    }

    #[test]
    fn iso11898_1_all_zero_identifier_frame_is_stuffed() {
        // SOF, 11 zero identifier bits, RTR, IDE, r0 and DLC 0: nineteen dominant bits in a
        // row need stuff bits, so the frame is longer than the unstuffed 44 bits.
        let frame = Frame::data(Identifier::Standard(0), &[]);
        assert!(frame.bit_length() > 44);
    }

    #[test]
    fn iso11898_1_lower_identifier_wins_arbitration() {
        let high = Frame::data(Identifier::Standard(0x100), &[]);
        let low = Frame::data(Identifier::Standard(0x101), &[]);
        assert!(high.arbitration_key() < low.arbitration_key());
    }

    #[test]
    fn iso11898_1_data_frame_beats_remote_frame_of_the_same_identifier() {
        let data = Frame::data(Identifier::Standard(0x100), &[]);
        let remote = Frame::remote(Identifier::Standard(0x100), 0);
        assert!(data.arbitration_key() < remote.arbitration_key());
    }

    #[test]
    fn iso11898_1_standard_frame_beats_extended_frame_with_the_same_base() {
        let standard = Frame::remote(Identifier::Standard(0x100), 0);
        let extended = Frame::data(Identifier::Extended(0x100 << 18), &[]);
        assert!(standard.arbitration_key() < extended.arbitration_key());
    }
}
