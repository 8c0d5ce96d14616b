//! Reference encoders for the link, written from the framing its modules document, not from
//! their code: a bitwise CRC, a plain COBS encoder, the link messages' layout from its table.
//! The targets build frames with these (at any sequence number, with any body) and check the
//! product's encoders against them.

use dual_channel::link::Message;

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

/// Checks the CRC against its catalogue check value ("123456789").
pub fn check_crc() {
    assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
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

/// The field widths (octets) of each link message tag, from the table in
/// `dual_channel::link::layout`. The SimpleCAN tags (08h..0Ah) are unknown here: the fuzz
/// crate builds `dual-channel` without its feature `simplecan`, as the shipped images are.
fn widths(tag: u8) -> Option<&'static [usize]> {
    Some(match tag {
        0x01 => &[1, 1, 1, 1, 4, 4, 1, 1],
        0x02 => &[4],
        0x03 => &[1, 4, 8, 1],
        0x04 | 0x05 => &[1],
        0x06 => &[2, 1, 8],
        0x07 => &[2],
        0x0B | 0x0C => &[4],
        0x0D => &[8],
        _ => return None,
    })
}

/// The fields of `body` (tag first) as little-endian numbers, when its length is its tag's.
fn fields(body: &[u8]) -> Option<(u8, Vec<u64>)> {
    let (&tag, mut rest) = body.split_first()?;
    let widths = widths(tag)?;
    if rest.len() != widths.iter().sum::<usize>() {
        return None;
    }
    let mut values = Vec::new();
    for &width in widths {
        let (field, tail) = rest.split_at(width);
        values.push(
            field
                .iter()
                .rev()
                .fold(0u64, |value, &byte| value << 8 | u64::from(byte)),
        );
        rest = tail;
    }
    Some((tag, values))
}

/// The link message whose body is exactly `body`: `None` for an unknown tag, a wrong length,
/// or a flag other than 0 or 1.
pub fn link_message(body: &[u8]) -> Option<Message> {
    let (tag, f) = fields(body)?;
    let flag = |value: u64| match value {
        0 => Some(false),
        1 => Some(true),
        _ => None,
    };
    // Each field was read at its width, so the narrowing casts keep every bit.
    Some(match tag {
        0x01 => Message::Heartbeat {
            nmt: f[0] as u8,
            working: flag(f[1])?,
            epoch: f[2] as u8,
            valid: f[3] as u8,
            signatures: f[4] as u32,
            inputs: f[5] as u32,
            node: f[6] as u8,
            bit_rate: f[7] as u8,
        },
        0x02 => Message::Inputs { sample: f[0] as u32 },
        0x03 => Message::Verdict {
            srdo: f[0] as u8,
            pair: f[1] as u32,
            data: f[2],
            valid: flag(f[3])?,
        },
        0x04 => Message::TransmitMismatch { srdo: f[0] as u8 },
        0x05 => Message::SafeState { cause: f[0] as u8 },
        0x06 => Message::PlainFrame {
            id: f[0] as u16,
            len: f[1] as u8,
            data: f[2],
        },
        0x07 => Message::ForeignFrame { id: f[0] as u16 },
        0x0B => Message::Probe { stamp: f[0] as u32 },
        0x0C => Message::Echo { stamp: f[0] as u32 },
        0x0D => Message::LssAnswer {
            data: f[0].to_le_bytes(),
        },
        _ => return None,
    })
}

/// A body of a known tag made from any bytes: the tag from the first (01h..07h, 0Bh..0Dh),
/// the fields from the rest, cut or padded with zeros to the tag's length.
pub fn link_body_from(bytes: &[u8]) -> Vec<u8> {
    const TAGS: [u8; 10] = [0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x0B, 0x0C, 0x0D];
    let tag = TAGS[usize::from(bytes.first().copied().unwrap_or(0)) % TAGS.len()];
    let len = widths(tag).map_or(0, |widths| widths.iter().sum());
    let mut body = vec![tag];
    body.extend(bytes.iter().skip(1).copied().chain(core::iter::repeat(0)).take(len));
    body
}

/// The body of `message` by the table: its tag, then each field at its width, little-endian.
pub fn link_body(message: &Message) -> Vec<u8> {
    let (tag, values): (u8, Vec<u64>) = match *message {
        Message::Heartbeat {
            nmt,
            working,
            epoch,
            valid,
            signatures,
            inputs,
            node,
            bit_rate,
        } => (
            0x01,
            vec![
                nmt.into(),
                working.into(),
                epoch.into(),
                valid.into(),
                signatures.into(),
                inputs.into(),
                node.into(),
                bit_rate.into(),
            ],
        ),
        Message::Inputs { sample } => (0x02, vec![sample.into()]),
        Message::Verdict {
            srdo,
            pair,
            data,
            valid,
        } => (0x03, vec![srdo.into(), pair.into(), data, valid.into()]),
        Message::TransmitMismatch { srdo } => (0x04, vec![srdo.into()]),
        Message::SafeState { cause } => (0x05, vec![cause.into()]),
        Message::PlainFrame { id, len, data } => (0x06, vec![id.into(), len.into(), data]),
        Message::ForeignFrame { id } => (0x07, vec![id.into()]),
        Message::Probe { stamp } => (0x0B, vec![stamp.into()]),
        Message::Echo { stamp } => (0x0C, vec![stamp.into()]),
        Message::LssAnswer { data } => (0x0D, vec![u64::from_le_bytes(data)]),
    };
    let mut body = vec![tag];
    for (&width, value) in widths(tag).unwrap_or_default().iter().zip(values) {
        body.extend_from_slice(&value.to_le_bytes()[..width]);
    }
    body
}
