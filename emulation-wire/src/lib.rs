//! CAN frames over a serial line, for the emulated network (the emulation's own wire format: the
//! safety runtime does not depend on it, and the hub depends on nothing else of the node).
//! Written for the QEMU board layer (`board::qemu`, retired with the QEMU images on
//! 2026-12-07): QEMU models no CAN controller, so that layer sent and received CAN frames on
//! USART2, and the bus hub (`can-hub --socket`) put them on the simulated bus. No image speaks
//! the line since; the hub's serial side and its tests still do, and the hub's and the
//! emulator's control ports report every channel's [`Status`].
//!
//! QEMU models no GPIO either, so the same line carried the board's pins: the hub sets the
//! channel's safety input ([`Wire::Input`]) and the channel reports its state and output
//! ([`Wire::Status`]). These never reach the bus.
//!
//! The line also carries the channel's link to the other channel ([`Wire::Link`]) and the
//! shared virtual time ([`Wire::Time`]): one ordered stream per channel, so that a channel
//! handles every frame, link byte and input change the hub sent it before its clock passes
//! the time the hub granted after them (`docs/emulation.md`).
//!
//! ```text
//! COBS( word: u16 LE | body | CRC-16/XMODEM LE ) 0x00
//!   word bits 14..11 = 0: a CAN frame, bits 10..0 = identifier, bit 15 = RTR;
//!                         body = dlc: u8 | data[dlc] (none for RTR)
//!   word = 0x4001:        Input, body = value: u8
//!   word = 0x4002:        Status, body = Status::LEN bytes (see Status::to_bytes)
//!   word = 0x4003:        Time, body = microseconds: u64 LE without its high zero bytes,
//!                         1 to 8 bytes (hub to channel: a grant; channel to hub: the
//!                         grant it has handled)
//!   word = 0x4004:        Link, body = 1..=LINK_CHUNK link bytes
//!   word = 0x4005:        Accept (channel to hub), body = flags: u8 (bit 0: the list's
//!                         first chunk, bit 1: its last) | 0..=ACCEPT_CHUNK identifiers:
//!                         u16 LE
//! ```
//!
//! A channel tells the hub which identifiers its CAN controller accepts ([`Wire::Accept`],
//! the list `dual_channel::filters` derives from its configuration, which the hardware layer
//! writes into bxCAN's filter banks), and from then on the hub sends it only the frames on
//! those identifiers, as the controller would let through; before the first list, every
//! frame. On a loaded host each byte on the line cost a hand-over between QEMU's
//! threads (`docs/emulation.md`), so frames the controller would reject anyway made every
//! channel's line, and with it the shared virtual time, slower.

#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]

use cobs_frames::{Completed, Reassembler};
use crc::{CRC_16_XMODEM, Crc};
use shared::{CanFrame, CanId};

const CRC: Crc<u16> = Crc::<u16>::new(&CRC_16_XMODEM);
/// The lookahead of the emulated network's shared virtual time: a paced channel's clock runs
/// at most this far past the last [`Wire::Time`] grant it handled, and the hub's clock at most
/// this far past the oldest grant a channel acknowledged (`can_hub::pace`,
/// `docs/emulation.md`). It bounds, whatever the host load, how much later than the hub sent
/// it a channel handles a frame, and how far apart the two channels of a node handle one. The
/// emulator's socketcand port paces its whole network with it (`emulator::socketcand`).
pub const LOOKAHEAD: shared::Duration = shared::Duration::from_millis(20);

/// How often (virtual time) the hub grants time to each paced channel; well below
/// [`LOOKAHEAD`], so that a channel that keeps up is never held.
pub const GRANT_PERIOD: shared::Duration = shared::Duration::from_millis(5);

/// The lookahead of the SimpleCAN run on the QEMU images (until 2026-12-07): the QEMU
/// images built with `board`'s feature `simplecan` paced their clocks with it, and xtask gave
/// it to the hub (`--lookahead`). SimpleCAN's millisecond grid (a packet within its 1 ms slot,
/// a receiver's ±2 ms, SC_REQ_30) needed the channels' clocks far closer to the hub's than
/// [`LOOKAHEAD`] (`docs/emulation.md`, section "SimpleCAN on the emulated network"). Nothing
/// uses it since.
pub const SIMPLECAN_LOOKAHEAD: shared::Duration = shared::Duration::from_micros(500);

/// The grant period of the SimpleCAN run on the QEMU images, about half
/// [`SIMPLECAN_LOOKAHEAD`] (xtask gave it to the hub, `--grant-period`). Nothing uses it
/// since.
pub const SIMPLECAN_GRANT_PERIOD: shared::Duration = shared::Duration::from_micros(250);

/// Most link bytes one [`Wire::Link`] message carries.
pub const LINK_CHUNK: usize = 32;
/// Most identifiers one [`Wire::Accept`] message carries.
pub const ACCEPT_CHUNK: usize = 16;
/// Largest unencoded message: word, the longest body (an acceptance chunk), CRC.
const MAX_RAW: usize = 2 + const_max(const_max(Status::LEN, LINK_CHUNK), 1 + 2 * ACCEPT_CHUNK) + 2;
const INPUT: u16 = 0x4001;
const STATUS: u16 = 0x4002;
const TIME: u16 = 0x4003;
const LINK: u16 = 0x4004;
const ACCEPT: u16 = 0x4005;
/// [`AcceptChunk`] flag bits.
const FIRST: u8 = 0b01;
const LAST: u8 = 0b10;

const fn const_max(a: usize, b: usize) -> usize {
    if a > b { a } else { b }
}
/// Largest encoded frame, delimiter included.
pub const MAX_WIRE: usize = cobs::max_encoding_length(MAX_RAW) + 1;

/// Why received bytes were not a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SerialError {
    /// Bad COBS, bad length, bad CRC, or an identifier or DLC out of range.
    Malformed,
}

/// The variant's doc comment.
impl core::fmt::Display for SerialError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            SerialError::Malformed => {
                f.write_str("bad COBS, bad length, bad CRC, or an identifier or DLC out of range")
            }
        }
    }
}

/// One channel's state as the control ports report it: what a QEMU image told the hub about
/// itself over its line (until 2026-12-07), or what the emulator observes of a shipped image
/// from outside (`emulator::control`). Counters wrap.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Status {
    /// The channel's NMT state as its heartbeat code (0: Initialising, 4: Stopped,
    /// 5: Operational, 127: Pre-operational).
    pub nmt: u8,
    /// Neither the channel nor its core is in the safe state.
    pub working: bool,
    /// The other channel has been heard on the link.
    pub link_up: bool,
    /// The value on the channel's output pin (lowest byte of receive SRDO 1's output).
    pub output: u8,
    /// The channel's safety input as it last sampled it.
    pub input: u8,
    /// The cause code of the last safe state latched (0: none since power-on or reset; every
    /// code and its name are in `shared::safety::cause::Cause`, see [`Status::latched_cause`]).
    pub cause: u8,
    /// SRDO frames this channel sent.
    pub sent: u16,
    /// Valid SRDO pairs this channel's core received.
    pub validated: u16,
    /// The longest time, in real milliseconds, the emulated MCU did not run (its tick
    /// interrupt came late): the emulator's scheduling jitter, for the report.
    pub longest_stall_ms: u16,
    /// The longest time, in milliseconds, between two receptions from the link (the other
    /// channel's heartbeat period plus the link's jitter), for the report.
    pub longest_link_gap_ms: u16,
    /// The longest time, in milliseconds, the channel's loop spent on one wake-up (handling
    /// frames, link bytes and timers before waiting again), for the report.
    pub longest_busy_ms: u16,
    /// The stack's high-water mark in bytes (saturating), for the report.
    pub stack_used: u16,
    /// SRDO frames the core discarded as CAN double reception (exact repeats of a pending
    /// plain frame, inverted frames with no plain frame pending; ISO 11898-1), since power-on
    /// or NMT reset, saturating: object 5C00h sub-indices 1 and 2 added up.
    pub discarded: u16,
}

impl Status {
    /// The NMT state [`Status::nmt`] names, `None` for a byte that is no heartbeat state code.
    pub const fn nmt_state(&self) -> Option<shared::canopen::nmt::NmtState> {
        shared::canopen::nmt::NmtState::from_heartbeat_code(self.nmt)
    }

    /// The cause [`Status::cause`] names, `None` for a byte that is no cause code (an
    /// application's own detail byte).
    pub fn latched_cause(&self) -> Option<shared::safety::cause::Cause> {
        shared::safety::cause::Cause::from_code(self.cause)
    }

    /// Bytes of an encoded status.
    pub const LEN: usize = 20;

    /// The fixed little-endian layout: nmt, flags (bit 0 working, bit 1 link up), output,
    /// input, cause, pad, sent, validated, longest stall, longest link gap, longest busy, stack used, discarded.
    pub fn to_bytes(&self) -> [u8; Self::LEN] {
        let mut out = [0u8; Self::LEN];
        out[0] = self.nmt;
        out[1] = u8::from(self.working) | u8::from(self.link_up) << 1;
        out[2] = self.output;
        out[3] = self.input;
        out[4] = self.cause;
        out[6..8].copy_from_slice(&self.sent.to_le_bytes());
        out[8..10].copy_from_slice(&self.validated.to_le_bytes());
        out[10..12].copy_from_slice(&self.longest_stall_ms.to_le_bytes());
        out[12..14].copy_from_slice(&self.longest_link_gap_ms.to_le_bytes());
        out[14..16].copy_from_slice(&self.longest_busy_ms.to_le_bytes());
        out[16..18].copy_from_slice(&self.stack_used.to_le_bytes());
        out[18..20].copy_from_slice(&self.discarded.to_le_bytes());
        out
    }

    fn from_bytes(body: &[u8]) -> Result<Self, SerialError> {
        let body: &[u8; Self::LEN] = body.try_into().map_err(|_| SerialError::Malformed)?;
        if body[1] & !0b11 != 0 || body[5] != 0 {
            return Err(SerialError::Malformed);
        }
        Ok(Status {
            nmt: body[0],
            working: body[1] & 1 != 0,
            link_up: body[1] & 2 != 0,
            output: body[2],
            input: body[3],
            cause: body[4],
            sent: u16::from_le_bytes([body[6], body[7]]),
            validated: u16::from_le_bytes([body[8], body[9]]),
            longest_stall_ms: u16::from_le_bytes([body[10], body[11]]),
            longest_link_gap_ms: u16::from_le_bytes([body[12], body[13]]),
            longest_busy_ms: u16::from_le_bytes([body[14], body[15]]),
            stack_used: u16::from_le_bytes([body[16], body[17]]),
            discarded: u16::from_le_bytes([body[18], body[19]]),
        })
    }
}

/// One message on the serial line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Wire {
    /// A CAN frame, either way.
    Can(CanFrame),
    /// Hub to channel: the channel's safety input pin reads this.
    Input(u8),
    /// Channel to hub: the channel's state.
    Status(Status),
    /// Hub to channel: the shared virtual time, in microseconds, up to which the hub has sent
    /// the channel everything (a grant); channel to hub: the grant the channel has handled,
    /// with everything before it (an acknowledgement).
    Time(u64),
    /// Bytes of the link between the two channels of a node, relayed by the hub.
    Link(LinkBytes),
    /// Channel to hub: part of the list of identifiers the channel's controller accepts
    /// (the whole list replaces the previous one once its last chunk has come).
    Accept(AcceptChunk),
}

/// Up to [`ACCEPT_CHUNK`] identifiers of an acceptance list, and where in the list they are.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AcceptChunk {
    flags: u8,
    len: u8,
    /// The identifiers, zero past `len` (so that equality compares the identifiers carried).
    ids: [u16; ACCEPT_CHUNK],
}

impl AcceptChunk {
    /// The chunks that carry `ids` (11-bit identifiers) in order: one with no identifier
    /// for an empty list.
    pub fn split(ids: &[u16]) -> impl Iterator<Item = AcceptChunk> + '_ {
        let count = ids.len().div_ceil(ACCEPT_CHUNK).max(1);
        (0..count).map(move |n| {
            let part = ids
                .get(n * ACCEPT_CHUNK..ids.len().min((n + 1) * ACCEPT_CHUNK))
                .unwrap_or_default();
            let mut chunk = AcceptChunk {
                flags: if n == 0 { FIRST } else { 0 } | if n + 1 == count { LAST } else { 0 },
                // `part` holds at most ACCEPT_CHUNK = 16 identifiers.
                len: part.len() as u8,
                ids: [0; ACCEPT_CHUNK],
            };
            chunk.ids[..part.len()].copy_from_slice(part);
            chunk
        })
    }

    /// The identifiers carried.
    pub fn ids(&self) -> &[u16] {
        self.ids.get(..usize::from(self.len)).unwrap_or_default()
    }

    /// `true` for the first chunk of a list: the identifiers before it belong to the list it
    /// replaces.
    pub fn is_first(&self) -> bool {
        self.flags & FIRST != 0
    }

    /// `true` for the last chunk of a list: the list is complete.
    pub fn is_last(&self) -> bool {
        self.flags & LAST != 0
    }
}

/// 1 to [`LINK_CHUNK`] bytes of the link between two channels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkBytes {
    len: u8,
    /// The bytes, zero past `len` (so that equality compares the bytes carried).
    bytes: [u8; LINK_CHUNK],
}

impl LinkBytes {
    /// `bytes` as one message, or `None` when empty or longer than [`LINK_CHUNK`].
    pub fn new(bytes: &[u8]) -> Option<LinkBytes> {
        if bytes.is_empty() || bytes.len() > LINK_CHUNK {
            return None;
        }
        let mut out = [0u8; LINK_CHUNK];
        out[..bytes.len()].copy_from_slice(bytes);
        Some(LinkBytes {
            // `bytes.len()` <= LINK_CHUNK = 32.
            len: bytes.len() as u8,
            bytes: out,
        })
    }

    /// The bytes carried.
    pub fn as_slice(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or_default()
    }
}

/// The bytes for `frame`, delimiter included.
pub fn encode(frame: &CanFrame) -> heapless::Vec<u8, MAX_WIRE> {
    encode_wire(&Wire::Can(*frame))
}

/// The bytes for `message`, delimiter included.
pub fn encode_wire(message: &Wire) -> heapless::Vec<u8, MAX_WIRE> {
    let mut raw = [0u8; MAX_RAW];
    let end = match message {
        Wire::Can(frame) => {
            let id = frame.id().raw() | if frame.is_remote() { 0x8000 } else { 0 };
            raw[..2].copy_from_slice(&id.to_le_bytes());
            raw[2] = frame.dlc();
            let data = if frame.is_remote() {
                &[][..]
            } else {
                frame.data()
            };
            raw[3..3 + data.len()].copy_from_slice(data);
            3 + data.len()
        }
        Wire::Input(value) => {
            raw[..2].copy_from_slice(&INPUT.to_le_bytes());
            raw[2] = *value;
            3
        }
        Wire::Status(status) => {
            raw[..2].copy_from_slice(&STATUS.to_le_bytes());
            raw[2..2 + Status::LEN].copy_from_slice(&status.to_bytes());
            2 + Status::LEN
        }
        Wire::Time(micros) => {
            // The shortest form (a grant goes every few milliseconds, and each byte on the
            // line costs the emulator a hand-over): 4 bytes up to 71 minutes.
            let bytes = micros.to_le_bytes();
            let len = time_len(*micros);
            raw[..2].copy_from_slice(&TIME.to_le_bytes());
            raw[2..2 + len].copy_from_slice(&bytes[..len]);
            2 + len
        }
        Wire::Link(bytes) => {
            let bytes = bytes.as_slice();
            raw[..2].copy_from_slice(&LINK.to_le_bytes());
            raw[2..2 + bytes.len()].copy_from_slice(bytes);
            2 + bytes.len()
        }
        Wire::Accept(chunk) => {
            raw[..2].copy_from_slice(&ACCEPT.to_le_bytes());
            raw[2] = chunk.flags;
            for (at, id) in chunk.ids().iter().enumerate() {
                raw[3 + 2 * at..5 + 2 * at].copy_from_slice(&id.to_le_bytes());
            }
            3 + 2 * chunk.ids().len()
        }
    };
    let crc = CRC.checksum(&raw[..end]);
    raw[end..end + 2].copy_from_slice(&crc.to_le_bytes());
    let mut out = heapless::Vec::new();
    // `MAX_WIRE` holds the longest encoding of `MAX_RAW` bytes and the delimiter, so this
    // cannot fail (were it to, nothing would be sent, and the receivers' timers would act).
    if cobs_frames::encode_into(&raw[..end + 2], &mut out).is_err() {
        out.clear();
    }
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

    /// Feeds one byte; returns a message (or why not) when the byte ends one.
    pub fn push(&mut self, byte: u8) -> Option<Result<Wire, SerialError>> {
        // Only a delimiter completes a frame: the buffer it decodes into is made only then.
        if self.frames.keep(byte) {
            return None;
        }
        let mut raw = [0u8; MAX_WIRE];
        Some(match self.frames.push(byte, &mut raw)? {
            Completed::Broken => Err(SerialError::Malformed),
            Completed::Frame(len) => parse(raw.get(..len).unwrap_or_default()),
        })
    }
}

fn parse(raw: &[u8]) -> Result<Wire, SerialError> {
    if raw.len() < 5 {
        return Err(SerialError::Malformed);
    }
    let (body, crc) = raw.split_at(raw.len() - 2);
    if CRC.checksum(body) != u16::from_le_bytes([crc[0], crc[1]]) {
        return Err(SerialError::Malformed);
    }
    let word = u16::from_le_bytes([body[0], body[1]]);
    match word {
        INPUT => match body[2..] {
            [value] => Ok(Wire::Input(value)),
            _ => Err(SerialError::Malformed),
        },
        STATUS => Status::from_bytes(&body[2..]).map(Wire::Status),
        TIME => parse_time(&body[2..]).map(Wire::Time),
        LINK => LinkBytes::new(&body[2..])
            .map(Wire::Link)
            .ok_or(SerialError::Malformed),
        ACCEPT => parse_accept(&body[2..]).map(Wire::Accept),
        _ if word & 0x7800 != 0 => Err(SerialError::Malformed),
        _ => parse_frame(word, body).map(Wire::Can),
    }
}

/// Bytes of the shortest little-endian form of `micros`: at least one.
fn time_len(micros: u64) -> usize {
    (8 - micros.leading_zeros() as usize / 8).max(1)
}

/// A time in its shortest form only (so that no time has two encodings).
fn parse_time(body: &[u8]) -> Result<u64, SerialError> {
    if body.is_empty() || body.len() > 8 {
        return Err(SerialError::Malformed);
    }
    let mut bytes = [0u8; 8];
    bytes[..body.len()].copy_from_slice(body);
    let micros = u64::from_le_bytes(bytes);
    if time_len(micros) != body.len() {
        return Err(SerialError::Malformed);
    }
    Ok(micros)
}

/// Flags, then whole 11-bit identifiers, at most [`ACCEPT_CHUNK`] of them.
fn parse_accept(body: &[u8]) -> Result<AcceptChunk, SerialError> {
    let (&flags, ids) = body.split_first().ok_or(SerialError::Malformed)?;
    if flags & !(FIRST | LAST) != 0 || ids.len() % 2 != 0 || ids.len() > 2 * ACCEPT_CHUNK {
        return Err(SerialError::Malformed);
    }
    let mut chunk = AcceptChunk {
        flags,
        // At most ACCEPT_CHUNK = 16 identifiers, checked above.
        len: (ids.len() / 2) as u8,
        ids: [0; ACCEPT_CHUNK],
    };
    for (slot, id) in chunk.ids.iter_mut().zip(ids.chunks_exact(2)) {
        *slot = u16::from_le_bytes([id[0], id[1]]);
        if *slot > 0x7FF {
            return Err(SerialError::Malformed);
        }
    }
    Ok(chunk)
}

fn parse_frame(word: u16, body: &[u8]) -> Result<CanFrame, SerialError> {
    let id = CanId::new(word & 0x07FF).map_err(|_| SerialError::Malformed)?;
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

    #[test]
    fn a_serial_error_reads_as_its_doc_comment() {
        assert_eq!(
            SerialError::Malformed.to_string(),
            "bad COBS, bad length, bad CRC, or an identifier or DLC out of range"
        );
    }

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
            prop_assert_eq!(results, vec![Ok(Wire::Can(frame))]);
        }

        #[test]
        fn board_messages_round_trip(
            input: u8, nmt: u8, working: bool, link_up: bool, output: u8, cause: u8,
            sent: u16, validated: u16, longest_stall_ms: u16, longest_link_gap_ms: u16, longest_busy_ms: u16, stack_used: u16, discarded: u16,
        ) {
            let status = Status { nmt, working, link_up, output, input, cause, sent, validated, longest_stall_ms, longest_link_gap_ms, longest_busy_ms, stack_used, discarded };
            let mut decoder = Decoder::new();
            for message in [Wire::Input(input), Wire::Status(status)] {
                let results: Vec<_> = encode_wire(&message).iter().filter_map(|&b| decoder.push(b)).collect();
                prop_assert_eq!(results, vec![Ok(message)]);
            }
        }

        #[test]
        fn time_and_link_round_trip(
            micros: u64, link in proptest::collection::vec(any::<u8>(), 1..=LINK_CHUNK),
        ) {
            let link = LinkBytes::new(&link).unwrap();
            let mut decoder = Decoder::new();
            for message in [Wire::Time(micros), Wire::Link(link)] {
                let results: Vec<_> = encode_wire(&message).iter().filter_map(|&b| decoder.push(b)).collect();
                prop_assert_eq!(results, vec![Ok(message)]);
            }
        }

        /// An acceptance list of any length goes over in chunks that carry it in order, the
        /// first and the last marked.
        #[test]
        fn acceptance_lists_round_trip_in_chunks(
            ids in proptest::collection::vec(0u16..=0x7FF, 0..=3 * ACCEPT_CHUNK),
        ) {
            let mut decoder = Decoder::new();
            let chunks: Vec<AcceptChunk> = AcceptChunk::split(&ids)
                .flat_map(|chunk| encode_wire(&Wire::Accept(chunk)))
                .filter_map(|b| decoder.push(b))
                .map(|message| match message {
                    Ok(Wire::Accept(chunk)) => chunk,
                    other => panic!("not an acceptance chunk: {other:?}"),
                })
                .collect();
            prop_assert_eq!(chunks.len(), ids.len().div_ceil(ACCEPT_CHUNK).max(1));
            prop_assert!(chunks[0].is_first() && chunks.iter().skip(1).all(|c| !c.is_first()));
            prop_assert!(chunks[chunks.len() - 1].is_last());
            prop_assert!(chunks[..chunks.len() - 1].iter().all(|c| !c.is_last()));
            let carried: Vec<u16> = chunks.iter().flat_map(|c| c.ids().to_vec()).collect();
            prop_assert_eq!(carried, ids);
        }

        #[test]
        fn noise_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
            let mut decoder = Decoder::new();
            for byte in bytes {
                let _ = decoder.push(byte);
            }
        }
    }

    /// A link message carries 1 to `LINK_CHUNK` bytes; a time 1 to 8 bytes, its shortest
    /// form only; an
    /// acceptance chunk its flags and up to `ACCEPT_CHUNK` 11-bit identifiers. Anything else
    /// with a valid CRC is refused, not truncated.
    #[test]
    fn bodies_of_the_wrong_length_or_range_are_refused() {
        assert!(LinkBytes::new(&[]).is_none());
        assert!(LinkBytes::new(&[0; LINK_CHUNK + 1]).is_none());
        assert_eq!(LinkBytes::new(&[1, 2]).unwrap().as_slice(), &[1, 2]);
        let sealed = |raw: &[u8]| {
            let mut raw = raw.to_vec();
            raw.extend_from_slice(&CRC.checksum(&raw).to_le_bytes());
            let mut wire = [0u8; 2 * MAX_WIRE];
            let len = cobs::encode(&raw, &mut wire);
            let mut decoder = Decoder::new();
            wire[..len]
                .iter()
                .chain(&[0])
                .find_map(|&b| decoder.push(b))
        };
        assert_eq!(sealed(&[0x03, 0x40]), Some(Err(SerialError::Malformed)));
        assert_eq!(
            sealed(&[0x03, 0x40, 1, 2, 3, 4, 5, 6, 7, 8, 9]),
            Some(Err(SerialError::Malformed))
        );
        assert_eq!(
            sealed(&[0x03, 0x40, 1, 0]),
            Some(Err(SerialError::Malformed)),
            "not the shortest form"
        );
        assert_eq!(sealed(&[0x04, 0x40]), Some(Err(SerialError::Malformed)));
        assert_eq!(sealed(&[0x03, 0x40, 0]), Some(Ok(Wire::Time(0))));
        assert_eq!(
            sealed(&[0x03, 0x40, 0x40, 0x42, 0x0F]),
            Some(Ok(Wire::Time(1_000_000)))
        );
        // A grant of an hour of virtual time is 10 bytes on the line, delimiter included.
        assert_eq!(encode_wire(&Wire::Time(3_600_000_000)).len(), 10);
        // Acceptance chunks: unknown flags, half an identifier, one that is not 11-bit, more
        // than ACCEPT_CHUNK of them.
        assert_eq!(
            sealed(&[0x05, 0x40, 0x04]),
            Some(Err(SerialError::Malformed))
        );
        assert_eq!(
            sealed(&[0x05, 0x40, 0x03, 0x01]),
            Some(Err(SerialError::Malformed))
        );
        assert_eq!(
            sealed(&[0x05, 0x40, 0x03, 0x00, 0x08]),
            Some(Err(SerialError::Malformed))
        );
        let mut long = vec![0x05, 0x40, 0x03];
        long.extend(std::iter::repeat_n([0x01, 0x06], ACCEPT_CHUNK + 1).flatten());
        assert_eq!(sealed(&long), Some(Err(SerialError::Malformed)));
        assert!(matches!(
            sealed(&[0x05, 0x40, 0x03, 0x01, 0x06]),
            Some(Ok(Wire::Accept(chunk))) if chunk.ids() == [0x601]
        ));
    }
}
