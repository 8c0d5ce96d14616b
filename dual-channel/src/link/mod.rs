//! The inter-MCU link between channel A and channel B (EN 50325-5 Annex A.4, Model III): the
//! message set, its framing on the USART, and the receiver's checks.
//!
//! Sans-I/O like the protocol core: the sender turns a [`Message`] into bytes for the UART,
//! the receiver is fed bytes and `now`, and reports messages, faults and its deadline.
//!
//! # Framing
//!
//! ```text
//! COBS( sequence: u16 LE | message (tag, fields) | CRC-32 LE over the preceding bytes ) 0x00
//! ```
//!
//! COBS (`cobs_frames`, the encoding of the `cobs` crate) makes 0x00 a reliable frame
//! delimiter, so a receiver that starts mid-stream or loses bytes resynchronises at the next
//! delimiter. The message has a fixed layout per variant ([`layout`]: a tag, then its fields
//! at full width); the CRC-32 (ISO-HDLC, the `crc` crate) detects corruption; the sequence
//! number detects lost, repeated and reordered messages.
//!
//! # Faults
//!
//! A corrupt, malformed, missing (sequence gap), repeated or late message is a [`LinkFault`];
//! the channel treats every one as a reason for the safe state (Model III: the link is part of
//! the safety function). The receiver resynchronises afterwards so that the channels can agree
//! again after an NMT reset.
//!
//! # Latency
//!
//! The time-out only finds a link that falls silent; a link that keeps delivering, but late,
//! goes unnoticed by it. The round trip ([`RoundTrip`]) measures it: a channel sends a
//! [`Message::Probe`] with a stamp of its clock, the other sends the stamp back at once in a
//! [`Message::Echo`], and a round trip at or over the bound, or a probe not answered within
//! it, is [`LinkFault::Latency`]. The bound follows from what the link must carry in time
//! ([`round_trip_bound`]).

use cobs_frames::{Completed, Reassembler};
use crc::{CRC_32_ISO_HDLC, Crc};
use shared::{Duration, Instant};

pub mod layout;
mod round_trip;

pub use round_trip::{RoundTrip, round_trip_bound, stamp};

/// CRC-32 of every link frame.
const CRC: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);

/// Largest unencoded frame: sequence (2) + the largest message ([`layout::MAX_BODY`]) + CRC (4).
const MAX_RAW: usize = 2 + layout::MAX_BODY + 4;
/// Largest frame on the wire: COBS adds at most one byte per 254, plus the delimiter.
pub const MAX_WIRE: usize = cobs::max_encoding_length(MAX_RAW) + 1;

// The device's timing (the tool's response-time calculation) counts frames of the length the
// device description states; a longer message must raise it there.
const _: () = assert!(
    MAX_WIRE == safety_device::timing::LINK_LONGEST_FRAME,
    "the longest link frame is not the device description's LINK_LONGEST_FRAME"
);

/// One byte on the link at the boards' rate: the device's link baud rate, ten bits a byte.
pub use safety_device::timing::LINK_BYTE_TIME as BYTE_TIME;

/// The byte that ends every message on the wire: COBS leaves it out of the frame, so a
/// board can tell a message's end from its bytes without decoding them.
pub const DELIMITER: u8 = 0x00;

/// Link messages that may be ahead of one message in a channel's link transmit queue, and
/// the message itself: the device's count (a heartbeat and the probe sent with it, the echo
/// of the other channel's probe, an input digest sent at an input change, a verdict on a
/// received pair).
pub use safety_device::timing::LINK_MESSAGES_AHEAD as MESSAGES_AHEAD;

/// The longest one message takes through its sender's queue and onto the line:
/// [`MESSAGES_AHEAD`] frames of [`MAX_WIRE`] bytes at [`BYTE_TIME`].
pub const QUEUE_TIME: Duration =
    Duration::from_micros(MESSAGES_AHEAD * MAX_WIRE as u64 * BYTE_TIME.as_micros());

/// What one channel tells the other. Small, fixed-size values only.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Message {
    /// Sent at least every heartbeat period (four times per smallest SCT or more): the
    /// sender's NMT state (heartbeat code), whether it is in its working state, its
    /// configuration digest and its input digest, so that one message a period carries
    /// everything the periodic cross-checks compare.
    Heartbeat {
        /// NMT state, as in the heartbeat message (CiA 301 7.2.8.3.2).
        nmt: u8,
        /// `true` in the working state, `false` in the safe state.
        working: bool,
        /// How many NMT resets (node or communication) the sender has been through since
        /// power-on, modulo 256. Both channels see the same NMT commands on the bus, so their
        /// counts agree; a message sent before a reset that arrives after it is recognised by
        /// the count in the heartbeat that preceded it, and ignored.
        epoch: u8,
        /// 0x13FE as the sender holds it.
        valid: u8,
        /// CRC-32 over all SRDO signatures (0x13FF sub 1..N, little-endian), computed by the
        /// sender's own implementation. Compared in Operational, where the configuration
        /// cannot change (`nmt` says whether the sender is there).
        signatures: u32,
        /// The sender's input digest, as [`Message::Inputs`] carries it.
        inputs: u32,
        /// The sender's node-ID in force, FFh when unconfigured (CiA 305; compared in the
        /// same epoch, [`crate::lss::Settings`]).
        node: u8,
        /// The sender's LSS bit rate, the CiA 305 table index, FFh for the board's own
        /// (compared in Operational, [`crate::lss::Settings`]).
        bit_rate: u8,
    },
    /// The sender's own sample of its safety inputs, for the input cross-check: sent when
    /// they change (and with every heartbeat, in [`Message::Heartbeat`]).
    Inputs {
        /// Input bits, channel-specific layout agreed by both.
        sample: u32,
    },
    /// The sender's verdict on one received SRDO pair.
    Verdict {
        /// SRDO number (1..=64).
        srdo: u8,
        /// Count of valid pairs of this SRDO so far (identifies the pair).
        pair: u32,
        /// Plain data of the pair (little-endian, mapping length), 0 when not valid.
        data: u64,
        /// `true` when the pair passed every check.
        valid: bool,
    },
    /// Channel B's plain half of a transmit SRDO differed from channel A's frame on the bus:
    /// B did not send the inverted frame (CiA 304 9.5).
    TransmitMismatch {
        /// SRDO number.
        srdo: u8,
    },
    /// The sender went to the safe state; the receiver follows (each channel can force it).
    SafeState {
        /// Cause code (the EMCY detail byte 1 the sender reported).
        cause: u8,
    },
    /// Channel A puts this plain frame of a transmit SRDO on the bus (sent before the frame
    /// itself): channel B co-signs only a plain frame on the bus that equals it (CiA 304 9.5).
    PlainFrame {
        /// CAN identifier (the SRDO's COB-ID 1).
        id: u16,
        /// Data length in bytes (0..=8).
        len: u8,
        /// The data, little-endian, bytes beyond `len` 0.
        data: u64,
    },
    /// The sender saw a frame on one of the node's transmit SRDO identifiers that the node
    /// did not send: the receiver goes to the safe state for it and sends a GFC.
    ForeignFrame {
        /// The identifier.
        id: u16,
    },
    /// The sender measures the link's round trip: the receiver answers at once with
    /// [`Message::Echo`] carrying the same stamp ([`RoundTrip`]).
    Probe {
        /// The low 32 bits of the sender's clock, in µs, when it sent the probe ([`stamp`]).
        stamp: u32,
    },
    /// The answer to a [`Message::Probe`], sent as soon as the probe arrived.
    Echo {
        /// The probe's stamp, unchanged.
        stamp: u32,
    },
    /// Channel A puts this LSS answer on the bus (7E4h, sent before the frame itself):
    /// channel B pairs it with its own slave's answer ([`crate::lss::AnswerPairing`]).
    LssAnswer {
        /// The answer's 8 data bytes (every LSS frame is 8 bytes, CiA 305).
        data: [u8; 8],
    },
    /// Channel A received this SimpleCAN frame (data or sync) and forwards it to channel B
    /// as it came off the bus, not unpacked (SC_REQ_24): B decodes and checks it with its
    /// own code. Behind the `simplecan` feature, which no shipped image enables; its tag
    /// ([`layout`]) is its own, so the other variants' encodings do not depend on the feature.
    #[cfg(feature = "simplecan")]
    SimpleCanPacket {
        /// CAN identifier (02Fh or an SC-ID).
        id: u16,
        /// Data length code as received (0..=8; anything but 8 is B's to reject).
        len: u8,
        /// The payload bytes as received, bytes beyond `len` 0.
        data: [u8; 8],
    },
    /// The sender's verdict on one received SimpleCAN data packet of an SDD entry it
    /// consumes (SC_REQ_10: both channels validate, the verdicts are cross-checked as SRDO
    /// verdicts are). After [`Message::SimpleCanPacket`], behind the same feature.
    #[cfg(feature = "simplecan")]
    SimpleCanVerdict {
        /// The SDD entry, 1-based (5E10h + entry − 1).
        entry: u8,
        /// The packet's SC-ID (its identifier).
        sc_id: u8,
        /// The packet's cycle stamp (byte 4).
        cycle_stamp: u8,
        /// The packet's value (bytes 0..4, little-endian).
        value: u32,
        /// `true` when the sender's channel accepted it (CRC, slot, cycle: delivered).
        valid: bool,
    },
    /// Channel B found a SimpleCAN fault of the pair of channels (sent before its
    /// [`Message::SafeState`]): channel A, which speaks for the node, latches the same fault,
    /// so that its EMCY FF02h carries the cause and names the identifier, as for
    /// [`Message::TransmitMismatch`]. Behind the same feature.
    #[cfg(feature = "simplecan")]
    SimpleCanFault {
        /// The cause code, 70h..79h (`crate::simplecan::SimpleCanFault::cause`).
        cause: u8,
        /// The identifier concerned (a consumed entry's fault: the entry number, 1-based).
        id: u16,
        /// A copy that differs: the identifier of channel A's copy; otherwise 0.
        other: u16,
    },
}

/// Why the link is not trustworthy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LinkFault {
    /// A frame failed its CRC.
    Corrupt,
    /// A frame could not be decoded (bad COBS, unknown message, too long, too short).
    Malformed,
    /// Messages were lost: this sequence number was expected, a later one came.
    Missing {
        /// The expected sequence number.
        expected: u16,
        /// The one received.
        received: u16,
    },
    /// A message came again, or out of order (an earlier sequence number).
    Repeated {
        /// The expected sequence number.
        expected: u16,
        /// The one received.
        received: u16,
    },
    /// No valid message within the link timeout.
    Timeout,
    /// The link is too slow for what it carries: a probe's echo came back at or over the
    /// round-trip bound, or had not come back when the bound ran out (a slow link, or a
    /// silent one), or answered no probe this channel was waiting on ([`RoundTrip`]).
    Latency,
}

/// Why a message could not be encoded (a bug: every message fits).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EncodeError;

/// The sending side: numbers and frames messages.
#[derive(Clone, Debug, Default)]
pub struct Sender {
    sequence: u16,
}

impl Sender {
    /// A sender starting at sequence number 0.
    pub const fn new() -> Self {
        Sender { sequence: 0 }
    }

    /// The bytes to write to the UART for `message`, delimiter included.
    pub fn encode(
        &mut self,
        message: &Message,
    ) -> Result<heapless::Vec<u8, MAX_WIRE>, EncodeError> {
        let mut out = heapless::Vec::new();
        self.encode_into(message, &mut out)?;
        Ok(out)
    }

    /// As [`Sender::encode`], into the caller's empty `out`: the bytes are written where the
    /// caller keeps them, not returned by value and copied out of the result (a copy call for
    /// every message sent, on the images). On an error `out` holds no message.
    pub fn encode_into(
        &mut self,
        message: &Message,
        out: &mut heapless::Vec<u8, MAX_WIRE>,
    ) -> Result<(), EncodeError> {
        out.clear();
        let mut raw = [0u8; MAX_RAW];
        let (sequence, rest) = raw.split_first_chunk_mut::<2>().ok_or(EncodeError)?;
        *sequence = self.sequence.to_le_bytes();
        let (body, _) = rest
            .split_first_chunk_mut::<{ layout::MAX_BODY }>()
            .ok_or(EncodeError)?;
        let end = 2 + message.write(body).ok_or(EncodeError)?;
        let crc = CRC.checksum(raw.get(..end).ok_or(EncodeError)?);
        raw.get_mut(end..end + 4)
            .ok_or(EncodeError)?
            .copy_from_slice(&crc.to_le_bytes());
        // `MAX_WIRE` holds the longest encoding of `MAX_RAW` bytes and the delimiter, so
        // this cannot fail.
        if cobs_frames::encode_into(raw.get(..end + 4).ok_or(EncodeError)?, out).is_err() {
            out.clear();
            return Err(EncodeError);
        }
        self.sequence = self.sequence.wrapping_add(1);
        Ok(())
    }
}

/// The receiving side: reassembles frames, checks CRC and sequence, watches the timeout.
#[derive(Clone, Debug)]
pub struct Receiver {
    frames: Reassembler<MAX_WIRE>,
    /// The next sequence number; `None` until the first valid message, whose number starts
    /// the count (the other channel may have started first).
    expected: Option<u16>,
    timeout: Duration,
    deadline: Instant,
}

impl Receiver {
    /// A receiver expecting a message every `timeout` at most, and the first one within
    /// `startup` of `now` (the other channel may take longer to come up). The first valid
    /// message's sequence number starts the count.
    pub fn new(now: Instant, timeout: Duration, startup: Duration) -> Self {
        Receiver {
            frames: Reassembler::new(),
            expected: None,
            timeout,
            deadline: now + startup,
        }
    }

    /// Starts over as at start-up, at `now`: the frame in progress is dropped, and the next
    /// valid message starts the count (what comes before it is not a fault); it must come
    /// within the timeout, or the start-up wait if that ends later. For a channel that knows
    /// it could not receive for a while (its processor held by a flash program), so that the
    /// bytes it lost meanwhile are not taken for a fault of the link.
    pub fn restart(&mut self, now: Instant) {
        self.frames = Reassembler::new();
        self.expected = None;
        self.deadline = self.deadline.max(now + self.timeout);
    }

    /// An NMT reset at `now`: a link that had timed out (a wire cut, and perhaps mended since)
    /// starts over as at start-up ([`Receiver::restart`]: its silence before the reset is not
    /// judged after it, and the next valid message starts the count), so the other channel's
    /// next message must come within a whole timeout from the reset. A link that had not
    /// timed out is left as it is: the message on the wire across the reset completes and
    /// the count goes on. Returns whether it started over.
    pub fn reset_if_timed_out(&mut self, now: Instant) -> bool {
        let timed_out = self.poll(now).is_err();
        if timed_out {
            self.restart(now);
        }
        timed_out
    }

    /// Allows the first message `longer` more (the other channel's start-up may take that
    /// much longer on this board); no effect once a valid message came, after which only the
    /// timeout counts.
    pub fn extend_startup(&mut self, longer: Duration) {
        if self.expected.is_none() {
            self.deadline = self.deadline + longer;
        }
    }

    /// When [`Receiver::poll`] reports a timeout unless a valid message comes first.
    pub fn deadline(&self) -> Instant {
        self.deadline
    }

    /// [`LinkFault::Timeout`] once no valid message came within the timeout. Fires at the
    /// deadline itself.
    pub fn poll(&self, now: Instant) -> Result<(), LinkFault> {
        if shared::time::expired(self.deadline, now) {
            Err(LinkFault::Timeout)
        } else {
            Ok(())
        }
    }

    /// Feeds one received byte; returns a message or a fault when it completes a frame.
    pub fn receive(&mut self, now: Instant, byte: u8) -> Option<Result<Message, LinkFault>> {
        // Only a delimiter completes a frame: the buffer it decodes into is made only then.
        if self.frames.keep(byte) {
            return None;
        }
        let mut raw = [0u8; MAX_WIRE];
        let completed = self.frames.push(byte, &mut raw)?;
        self.completed(now, completed, &raw)
    }

    /// Feeds received bytes up to the first one that completes a message or a fault; returns
    /// how many it took and what they completed (`None` when it took them all and nothing
    /// was complete). The same as feeding those bytes one at a time to
    /// [`Receiver::receive`], without a call per byte: a board hands over what its UART
    /// buffered, and calls again with the rest.
    pub fn receive_bytes(
        &mut self,
        now: Instant,
        bytes: &[u8],
    ) -> (usize, Option<Result<Message, LinkFault>>) {
        let mut taken = 0;
        // One buffer for every frame these bytes complete: each is decoded over the last
        // one's bytes, and only the bytes it decoded are read.
        let mut raw = [0u8; MAX_WIRE];
        while taken < bytes.len() {
            let (count, completed) = self
                .frames
                .push_slice(bytes.get(taken..).unwrap_or_default(), &mut raw);
            taken += count;
            let Some(completed) = completed else {
                break;
            };
            if let Some(result) = self.completed(now, completed, &raw) {
                return (taken, Some(result));
            }
        }
        (taken, None)
    }

    /// What a completed frame (decoded into `raw`) is: a message, a fault, or nothing.
    fn completed(
        &mut self,
        now: Instant,
        completed: Completed,
        raw: &[u8; MAX_WIRE],
    ) -> Option<Result<Message, LinkFault>> {
        let result = match completed {
            Completed::Broken => Err(LinkFault::Malformed),
            Completed::Frame(len) => self.check(now, raw.get(..len).unwrap_or_default()),
        };
        if self.expected.is_none() && result.is_err() {
            // Before the first valid message the line may carry the tail of a frame the other
            // channel sent before this one listened: not a fault, the start-up deadline
            // still applies.
            return None;
        }
        Some(result)
    }

    /// Checks a decoded frame: length, CRC, message (in its one encoding), sequence.
    fn check(&mut self, now: Instant, raw: &[u8]) -> Result<Message, LinkFault> {
        if raw.len() < 2 + 1 + 4 {
            return Err(LinkFault::Malformed);
        }
        let (payload, crc) = raw.split_at(raw.len() - 4);
        let stored = u32::from_le_bytes([crc[0], crc[1], crc[2], crc[3]]);
        if CRC.checksum(payload) != stored {
            return Err(LinkFault::Corrupt);
        }
        let sequence = u16::from_le_bytes([payload[0], payload[1]]);
        // One message, one encoding: the layout reads a body of exactly its tag's length,
        // with every field in range, so what the CRC protects is what an encoder wrote.
        let message = Message::read(&payload[2..]).ok_or(LinkFault::Malformed)?;
        let expected = self.expected.unwrap_or(sequence);
        // Resynchronise on the sequence received, whatever the verdict, so that one lost
        // message is one fault, not a fault for every message after it.
        self.expected = Some(sequence.wrapping_add(1));
        match sequence_order(sequence, expected) {
            Order::Expected => {
                self.deadline = now + self.timeout;
                Ok(message)
            }
            Order::Ahead => Err(LinkFault::Missing {
                expected,
                received: sequence,
            }),
            Order::Behind => Err(LinkFault::Repeated {
                expected,
                received: sequence,
            }),
        }
    }
}

/// Where a received sequence number stands relative to the expected one.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Order {
    Expected,
    Ahead,
    Behind,
}

/// Serial-number comparison (RFC 1982) on 16 bits: the difference, read as signed, says
/// whether `received` is ahead of or behind `expected`, across the wrap from 0xFFFF to 0.
fn sequence_order(received: u16, expected: u16) -> Order {
    // Reinterpreting the wrapped difference as signed is the point of the comparison.
    #[allow(clippy::cast_possible_wrap)]
    let difference = received.wrapping_sub(expected) as i16;
    match difference {
        0 => Order::Expected,
        d if d > 0 => Order::Ahead,
        _ => Order::Behind,
    }
}

#[cfg(test)]
mod tests;
