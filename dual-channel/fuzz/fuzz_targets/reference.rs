//! Reference encoders for the link and the CAN-over-serial line, written from the framing the
//! modules document, not from their code: bitwise CRCs, a plain COBS encoder. The targets build
//! frames with these (at any sequence number, with any body) and check the product's encoders
//! against them.

/// CRC-32/ISO-HDLC, bit by bit (reflected polynomial 0xEDB88320, initial value and final XOR
/// 0xFFFFFFFF).
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &byte in bytes {
        crc ^= u32::from(byte);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// CRC-16/XMODEM, bit by bit (polynomial 0x1021, initial value 0, no reflection, no final XOR).
pub fn crc16(bytes: &[u8]) -> u16 {
    let mut crc = 0u16;
    for &byte in bytes {
        crc ^= u16::from(byte) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// Checks both CRCs against their catalogue check values ("123456789").
pub fn check_crcs() {
    assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    assert_eq!(crc16(b"123456789"), 0x31C3);
}

/// COBS (Cheshire and Baker) with the 0x00 delimiter appended. Frames here are far shorter
/// than one 254-byte block, so the block-boundary conventions of encoders never differ.
pub fn cobs(raw: &[u8]) -> Vec<u8> {
    let mut out = vec![0u8];
    let mut code_at = 0;
    let mut code = 1u8;
    for &byte in raw {
        if byte == 0 {
            out[code_at] = code;
            code_at = out.len();
            out.push(0);
            code = 1;
        } else {
            out.push(byte);
            code += 1;
            if code == 0xFF {
                out[code_at] = code;
                code_at = out.len();
                out.push(0);
                code = 1;
            }
        }
    }
    out[code_at] = code;
    out.push(0);
    out
}

/// The raw (unencoded) link frame: sequence LE, body, CRC-32 LE over both.
pub fn link_raw(sequence: u16, body: &[u8]) -> Vec<u8> {
    let mut raw = sequence.to_le_bytes().to_vec();
    raw.extend_from_slice(body);
    let crc = crc32(&raw);
    raw.extend_from_slice(&crc.to_le_bytes());
    raw
}

/// The raw CAN-over-serial frame: word and body as given, CRC-16 LE over them.
pub fn serial_raw(word_and_body: &[u8]) -> Vec<u8> {
    let mut raw = word_and_body.to_vec();
    let crc = crc16(&raw);
    raw.extend_from_slice(&crc.to_le_bytes());
    raw
}
