//! The fixed layout of a link message: a tag octet, then the variant's fields in their
//! declared order, each at its full width, little-endian. No varints, no optional parts: a
//! message has one length, fixed by its tag, and one encoding, so the receiver checks a body
//! by its length and its fields' ranges alone (a `bool` is 00h or 01h), and the link's
//! timing has no data-dependent worst case (every message of a variant takes the same bytes).
//!
//! ```text
//! tag  variant            fields (octets)                                       body
//! 01h  Heartbeat          nmt 1 | working 1 | epoch 1 | valid 1 |                 15
//!                         signatures 4 | inputs 4 | node 1 | bit_rate 1
//! 02h  Inputs             sample 4                                                 5
//! 03h  Verdict            srdo 1 | pair 4 | data 8 | valid 1                      15
//! 04h  TransmitMismatch   srdo 1                                                   2
//! 05h  SafeState          cause 1                                                  2
//! 06h  PlainFrame         id 2 | len 1 | data 8                                   12
//! 07h  ForeignFrame       id 2                                                     3
//! 08h  SimpleCanPacket    id 2 | len 1 | data[0..8] 8                             12
//! 09h  SimpleCanVerdict   entry 1 | sc_id 1 | cycle_stamp 1 | value 4 | valid 1     9
//! 0Ah  SimpleCanFault     cause 1 | id 2 | other 2                                 6
//! 0Bh  Probe              stamp 4                                                  5
//! 0Ch  Echo               stamp 4                                                  5
//! 0Dh  LssAnswer          data 8                                                   9
//! ```
//!
//! The tags are constants, not the variants' order: a variant behind a feature (the
//! SimpleCAN ones) changes no other variant's encoding, and a receiver built without it
//! refuses its tag as it refuses any unknown one.
//!
//! Hand-written rather than a serialisation crate (postcard until 2026-12): the layout is
//! part of the link's safety argument (one encoding per message, a fixed worst-case length
//! for the SRVT bound) and is shorter to state and check here than a general format's rules;
//! `docs/link-layout.md` gives the measured comparison.

use super::Message;

/// The longest body: [`Message::Verdict`] and [`Message::Heartbeat`].
pub const MAX_BODY: usize = 15;

const HEARTBEAT: u8 = 0x01;
const INPUTS: u8 = 0x02;
const VERDICT: u8 = 0x03;
const TRANSMIT_MISMATCH: u8 = 0x04;
const SAFE_STATE: u8 = 0x05;
const PLAIN_FRAME: u8 = 0x06;
const FOREIGN_FRAME: u8 = 0x07;
#[cfg(feature = "simplecan")]
const SIMPLECAN_PACKET: u8 = 0x08;
#[cfg(feature = "simplecan")]
const SIMPLECAN_VERDICT: u8 = 0x09;
#[cfg(feature = "simplecan")]
const SIMPLECAN_FAULT: u8 = 0x0A;
const PROBE: u8 = 0x0B;
const ECHO: u8 = 0x0C;
const LSS_ANSWER: u8 = 0x0D;

/// Writes fields one after the other into a body.
struct Put<'a> {
    out: &'a mut [u8; MAX_BODY],
    /// How many octets are written; `None` once a field did not fit (which the table rules
    /// out, and a test writes every variant to check).
    at: Option<usize>,
}

impl Put<'_> {
    fn bytes(&mut self, bytes: &[u8]) -> &mut Self {
        self.at = self.at.and_then(|at| {
            let end = at + bytes.len();
            self.out.get_mut(at..end)?.copy_from_slice(bytes);
            Some(end)
        });
        self
    }

    fn u8(&mut self, value: u8) -> &mut Self {
        self.bytes(&[value])
    }

    fn bool(&mut self, value: bool) -> &mut Self {
        self.u8(u8::from(value))
    }

    fn u16(&mut self, value: u16) -> &mut Self {
        self.bytes(&value.to_le_bytes())
    }

    fn u32(&mut self, value: u32) -> &mut Self {
        self.bytes(&value.to_le_bytes())
    }

    fn u64(&mut self, value: u64) -> &mut Self {
        self.bytes(&value.to_le_bytes())
    }
}

/// Reads fields one after the other from a body; `None` once one is missing or out of range.
struct Take<'a> {
    rest: &'a [u8],
}

impl Take<'_> {
    fn array<const N: usize>(&mut self) -> Option<[u8; N]> {
        let (head, rest) = self.rest.split_first_chunk::<N>()?;
        self.rest = rest;
        Some(*head)
    }

    fn u8(&mut self) -> Option<u8> {
        self.array::<1>().map(|[byte]| byte)
    }

    fn bool(&mut self) -> Option<bool> {
        match self.u8()? {
            0 => Some(false),
            1 => Some(true),
            _ => None,
        }
    }

    fn u16(&mut self) -> Option<u16> {
        self.array().map(u16::from_le_bytes)
    }

    fn u32(&mut self) -> Option<u32> {
        self.array().map(u32::from_le_bytes)
    }

    fn u64(&mut self) -> Option<u64> {
        self.array().map(u64::from_le_bytes)
    }

    /// `message` when every octet of the body was read.
    fn end(&self, message: Message) -> Option<Message> {
        self.rest.is_empty().then_some(message)
    }
}

impl Message {
    /// Writes the message's body (tag and fields) into `out`; returns its length (`None`
    /// would be a variant longer than [`MAX_BODY`], which the table rules out).
    pub fn write(&self, out: &mut [u8; MAX_BODY]) -> Option<usize> {
        let mut put = Put { out, at: Some(0) };
        match *self {
            Message::Heartbeat {
                nmt,
                working,
                epoch,
                valid,
                signatures,
                inputs,
                node,
                bit_rate,
            } => put
                .u8(HEARTBEAT)
                .u8(nmt)
                .bool(working)
                .u8(epoch)
                .u8(valid)
                .u32(signatures)
                .u32(inputs)
                .u8(node)
                .u8(bit_rate),
            Message::Inputs { sample } => put.u8(INPUTS).u32(sample),
            Message::Verdict {
                srdo,
                pair,
                data,
                valid,
            } => put.u8(VERDICT).u8(srdo).u32(pair).u64(data).bool(valid),
            Message::TransmitMismatch { srdo } => put.u8(TRANSMIT_MISMATCH).u8(srdo),
            Message::SafeState { cause } => put.u8(SAFE_STATE).u8(cause),
            Message::PlainFrame { id, len, data } => put.u8(PLAIN_FRAME).u16(id).u8(len).u64(data),
            Message::ForeignFrame { id } => put.u8(FOREIGN_FRAME).u16(id),
            Message::Probe { stamp } => put.u8(PROBE).u32(stamp),
            Message::Echo { stamp } => put.u8(ECHO).u32(stamp),
            Message::LssAnswer { data } => put.u8(LSS_ANSWER).bytes(&data),
            #[cfg(feature = "simplecan")]
            Message::SimpleCanPacket { id, len, data } => {
                put.u8(SIMPLECAN_PACKET).u16(id).u8(len).bytes(&data)
            }
            #[cfg(feature = "simplecan")]
            Message::SimpleCanVerdict {
                entry,
                sc_id,
                cycle_stamp,
                value,
                valid,
            } => put
                .u8(SIMPLECAN_VERDICT)
                .u8(entry)
                .u8(sc_id)
                .u8(cycle_stamp)
                .u32(value)
                .bool(valid),
            #[cfg(feature = "simplecan")]
            Message::SimpleCanFault { cause, id, other } => {
                put.u8(SIMPLECAN_FAULT).u8(cause).u16(id).u16(other)
            }
        }
        .at
    }

    /// The message whose body is `body`, exactly: `None` for an unknown tag, a body shorter
    /// or longer than its tag's, or a `bool` other than 00h or 01h.
    pub fn read(body: &[u8]) -> Option<Message> {
        let (&tag, rest) = body.split_first()?;
        let mut take = Take { rest };
        let message = match tag {
            HEARTBEAT => Message::Heartbeat {
                nmt: take.u8()?,
                working: take.bool()?,
                epoch: take.u8()?,
                valid: take.u8()?,
                signatures: take.u32()?,
                inputs: take.u32()?,
                node: take.u8()?,
                bit_rate: take.u8()?,
            },
            INPUTS => Message::Inputs {
                sample: take.u32()?,
            },
            VERDICT => Message::Verdict {
                srdo: take.u8()?,
                pair: take.u32()?,
                data: take.u64()?,
                valid: take.bool()?,
            },
            TRANSMIT_MISMATCH => Message::TransmitMismatch { srdo: take.u8()? },
            SAFE_STATE => Message::SafeState { cause: take.u8()? },
            PLAIN_FRAME => Message::PlainFrame {
                id: take.u16()?,
                len: take.u8()?,
                data: take.u64()?,
            },
            FOREIGN_FRAME => Message::ForeignFrame { id: take.u16()? },
            PROBE => Message::Probe { stamp: take.u32()? },
            ECHO => Message::Echo { stamp: take.u32()? },
            LSS_ANSWER => Message::LssAnswer {
                data: take.array()?,
            },
            #[cfg(feature = "simplecan")]
            SIMPLECAN_PACKET => Message::SimpleCanPacket {
                id: take.u16()?,
                len: take.u8()?,
                data: take.array()?,
            },
            #[cfg(feature = "simplecan")]
            SIMPLECAN_VERDICT => Message::SimpleCanVerdict {
                entry: take.u8()?,
                sc_id: take.u8()?,
                cycle_stamp: take.u8()?,
                value: take.u32()?,
                valid: take.bool()?,
            },
            #[cfg(feature = "simplecan")]
            SIMPLECAN_FAULT => Message::SimpleCanFault {
                cause: take.u8()?,
                id: take.u16()?,
                other: take.u16()?,
            },
            _ => return None,
        };
        take.end(message)
    }
}
