//! The CAN-over-serial line (`emulation_wire`): any mix of messages the encoder
//! makes, bodies with a valid CRC, and raw bytes, into one decoder.
//!
//! Checked: no panic; `encode_wire` equals the reference encoder (the layout in the module's
//! documentation); a message encoded into a decoder that is at a frame boundary decodes to
//! exactly itself (encode then decode is the identity); and whatever decodes, from any bytes,
//! re-encodes to exactly the bytes received (decode then encode is the identity, so no message
//! has two encodings).
#![no_main]

#[path = "reference.rs"]
#[allow(
    dead_code,
    reason = "each target uses the reference encoders of its own line only"
)]
mod reference;

use arbitrary::Arbitrary;
use emulation_wire::{AcceptChunk, Decoder, LinkBytes, Status, Wire, encode, encode_wire};
use libfuzzer_sys::fuzz_target;
use shared::{CanFrame, CanId};

#[derive(Arbitrary, Debug)]
enum Message {
    Can {
        id: u16,
        remote: bool,
        dlc: u8,
        data: [u8; 8],
    },
    Input(u8),
    Status {
        bytes: [u8; 5],
        flags: (bool, bool),
        counters: [u16; 7],
    },
    Time(u64),
    Link(Vec<u8>),
    /// An acceptance list: its first chunk (identifiers masked to 11 bits).
    Accept(Vec<u16>),
}

#[derive(Arbitrary, Debug)]
enum Step {
    /// A message through the product's encoder.
    Encoded(Message),
    /// Word and body as given, with a valid CRC-16, COBS-encoded by the reference.
    Body(Vec<u8>),
    /// Bytes as they are.
    Raw(Vec<u8>),
}

fn wire(message: &Message) -> Option<Wire> {
    Some(match *message {
        Message::Can {
            id,
            remote,
            dlc,
            data,
        } => {
            let id = CanId::new(id & 0x07FF).ok()?;
            let dlc = dlc % 9;
            Wire::Can(if remote {
                CanFrame::remote(id, dlc).ok()?
            } else {
                CanFrame::new(id, &data[..usize::from(dlc)]).ok()?
            })
        }
        Message::Input(value) => Wire::Input(value),
        Message::Time(micros) => Wire::Time(micros),
        Message::Link(ref bytes) => Wire::Link(LinkBytes::new(bytes)?),
        Message::Accept(ref ids) => {
            let ids: Vec<u16> = ids.iter().map(|id| id & 0x07FF).collect();
            Wire::Accept(AcceptChunk::split(&ids).next()?)
        }
        Message::Status {
            bytes,
            flags,
            counters,
        } => Wire::Status(Status {
            nmt: bytes[0],
            working: flags.0,
            link_up: flags.1,
            output: bytes[1],
            input: bytes[2],
            cause: bytes[3],
            sent: counters[0],
            validated: counters[1],
            longest_stall_ms: counters[2],
            longest_link_gap_ms: counters[3],
            longest_busy_ms: counters[4],
            stack_used: counters[5],
            discarded: counters[6],
        }),
    })
}

/// The documented layout: word LE, body, CRC-16 LE, COBS, delimiter.
fn reference_encoding(message: &Wire) -> Vec<u8> {
    let mut raw = Vec::new();
    match message {
        Wire::Can(frame) => {
            let word = frame.id().raw() | if frame.is_remote() { 0x8000 } else { 0 };
            raw.extend_from_slice(&word.to_le_bytes());
            raw.push(frame.dlc());
            if !frame.is_remote() {
                raw.extend_from_slice(frame.data());
            }
        }
        Wire::Input(value) => raw.extend_from_slice(&[0x01, 0x40, *value]),
        Wire::Status(status) => {
            raw.extend_from_slice(&[0x02, 0x40]);
            raw.extend_from_slice(&status.to_bytes());
        }
        Wire::Time(micros) => {
            raw.extend_from_slice(&[0x03, 0x40]);
            let bytes = micros.to_le_bytes();
            let len = bytes.iter().rposition(|&b| b != 0).map_or(1, |at| at + 1);
            raw.extend_from_slice(&bytes[..len]);
        }
        Wire::Link(bytes) => {
            raw.extend_from_slice(&[0x04, 0x40]);
            raw.extend_from_slice(bytes.as_slice());
        }
        Wire::Accept(chunk) => {
            let flags = u8::from(chunk.is_first()) | u8::from(chunk.is_last()) << 1;
            raw.extend_from_slice(&[0x05, 0x40, flags]);
            for id in chunk.ids() {
                raw.extend_from_slice(&id.to_le_bytes());
            }
        }
    }
    reference::cobs(&reference::serial_raw(&raw))
}

fuzz_target!(|steps: Vec<Step>| {
    reference::check_crcs();
    let mut decoder = Decoder::new();
    // Bytes since the last delimiter, and whether the decoder is at a frame boundary.
    let mut frame: Vec<u8> = Vec::new();
    for step in steps.iter().take(256) {
        let (bytes, sent) = match step {
            Step::Encoded(message) => {
                let Some(message) = wire(message) else {
                    continue;
                };
                let bytes = encode_wire(&message).to_vec();
                assert_eq!(bytes, reference_encoding(&message), "{message:?}");
                if let Wire::Can(can) = message {
                    assert_eq!(&encode(&can)[..], &bytes[..]);
                }
                (bytes, Some(message))
            }
            Step::Body(body) => (
                reference::cobs(&reference::serial_raw(&body[..body.len().min(40)])),
                None,
            ),
            Step::Raw(bytes) => (bytes.clone(), None),
        };
        let at_boundary = frame.is_empty();
        let mut results = Vec::new();
        for &byte in &bytes {
            let result = decoder.push(byte);
            if byte != 0 {
                frame.push(byte);
                assert!(result.is_none(), "a result only at a delimiter");
                continue;
            }
            if let Some(Ok(message)) = result {
                frame.push(0);
                assert_eq!(
                    encode_wire(&message).to_vec(),
                    frame,
                    "decode then encode is the identity"
                );
            }
            results.extend(result);
            frame.clear();
        }
        if let (Some(message), true) = (sent, at_boundary) {
            assert_eq!(
                results,
                vec![Ok(message)],
                "encode then decode is the identity"
            );
        }
    }
});
