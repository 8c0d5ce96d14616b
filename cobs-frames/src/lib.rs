//! COBS-encoded, zero-delimited frames: encoding one, and reassembling them from a byte
//! stream. What the inter-channel link (`dual-channel`) and the emulation's CAN-over-serial
//! line (`emulation-wire`) share, in a crate of its own so that neither depends on the other.

#![no_std]
#![forbid(unsafe_code)]

#[cfg(test)]
extern crate std;

/// A frame in the making: bytes up to the next 0x00 delimiter.
///
/// The bytes are kept in an array and a count rather than a `heapless::Vec`, whose
/// `extend_from_slice` moves one element at a time: a run is appended with one copy.
#[derive(Clone, Debug)]
pub struct Reassembler<const N: usize> {
    buffer: [u8; N],
    /// Bytes of `buffer` in use.
    len: usize,
    overflowed: bool,
}

impl<const N: usize> Default for Reassembler<N> {
    fn default() -> Self {
        Self::new()
    }
}

/// What one byte completed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Completed {
    /// A frame of this many decoded bytes.
    Frame(usize),
    /// A frame that does not decode, or was longer than the buffer.
    Broken,
}

impl<const N: usize> Reassembler<N> {
    /// An empty reassembler.
    pub const fn new() -> Self {
        Reassembler {
            buffer: [0; N],
            len: 0,
            overflowed: false,
        }
    }

    /// Feeds one byte. At a delimiter, decodes the frame into `out` and says how long it is;
    /// an empty frame (two delimiters in a row: idle line or resynchronisation) is nothing.
    pub fn push(&mut self, byte: u8, out: &mut [u8; N]) -> Option<Completed> {
        if self.keep(byte) {
            return None;
        }
        let overflowed = core::mem::replace(&mut self.overflowed, false);
        if self.len == 0 && !overflowed {
            return None;
        }
        let frame = self.buffer.get(..self.len).unwrap_or_default();
        let decoded = (!overflowed).then(|| decode(frame, out)).flatten();
        self.len = 0;
        Some(decoded.map_or(Completed::Broken, Completed::Frame))
    }

    /// Keeps `byte` when it is not the delimiter (`true`: what [`Reassembler::push`] does
    /// with it, and nothing completes); a delimiter is left for `push` (`false`). A receiver
    /// fed a byte at a time calls this first and makes the buffer a frame is decoded into
    /// only at a delimiter, not for every byte (zeroing it for every byte was the largest
    /// part of the QEMU board layer's serial line, until that layer retired on 2026-12-07).
    pub fn keep(&mut self, byte: u8) -> bool {
        if byte == 0 {
            return false;
        }
        match self.buffer.get_mut(self.len) {
            Some(slot) => {
                *slot = byte;
                self.len += 1;
            }
            None => self.overflowed = true,
        }
        true
    }

    /// Feeds `bytes` up to the first delimiter that completes a frame (an empty frame is
    /// nothing, as for [`Reassembler::push`]); returns how many of them it took and what the
    /// last one completed. The same as pushing those bytes one at a time, without a call per
    /// byte: the bytes between delimiters are copied as one run.
    pub fn push_slice(&mut self, bytes: &[u8], out: &mut [u8; N]) -> (usize, Option<Completed>) {
        let mut taken = 0;
        while let Some(rest) = bytes.get(taken..) {
            let Some(delimiter) = rest.iter().position(|&byte| byte == 0) else {
                self.collect(rest);
                return (bytes.len(), None);
            };
            self.collect(rest.get(..delimiter).unwrap_or_default());
            taken += delimiter + 1;
            if let Some(completed) = self.push(0, out) {
                return (taken, Some(completed));
            }
        }
        (taken, None)
    }

    /// Appends non-delimiter bytes; what does not fit marks the frame as overflowed, as a
    /// byte [`Reassembler::push`] cannot keep does. Kept out of line: the emulator's profile
    /// tells a loop iteration that received a link message by its entry
    /// (`emulator::profile::MARKERS`).
    #[inline(never)]
    fn collect(&mut self, bytes: &[u8]) {
        let room = N - self.len;
        let (kept, dropped) = bytes.split_at(bytes.len().min(room));
        // `kept` fits the room left by construction.
        if let Some(slots) = self.buffer.get_mut(self.len..self.len + kept.len()) {
            slots.copy_from_slice(kept);
            self.len += kept.len();
        }
        if !dropped.is_empty() {
            self.overflowed = true;
        }
    }
}

/// The encoded frame would not fit the caller's buffer (a buffer of
/// `cobs::max_encoding_length(source.len()) + 1` bytes always holds it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BufferFull;

/// Appends the COBS encoding of `source` and its 00h delimiter to `out`, a block at a time
/// (a code byte, then a copy of the data bytes it covers), straight into the caller's buffer:
/// no intermediate buffer to zero and copy. The bytes are those of `cobs::try_encode` of the
/// `cobs` crate followed by the delimiter (a test compares them on any input): each block is
/// a code byte `c` and the `c − 1` bytes before the next 00h of `source`, at most 254 of them
/// (`c` = FFh: a full block, no 00h after it); a full block that ends `source` has no empty
/// block after it. On [`BufferFull`], `out` holds what fitted, no frame: the caller drops it.
pub fn encode_into<const N: usize>(
    source: &[u8],
    out: &mut heapless::Vec<u8, N>,
) -> Result<(), BufferFull> {
    /// The most data bytes one code byte covers.
    const FULL: usize = 254;
    let mut rest = source;
    loop {
        let window = rest.get(..FULL).unwrap_or(rest);
        let zero = window.iter().position(|&byte| byte == 0);
        let data = zero.unwrap_or(window.len());
        // `data` <= 254, so the code byte `data + 1` fits an octet.
        out.push(data as u8 + 1).map_err(|_| BufferFull)?;
        out.extend_from_slice(rest.get(..data).unwrap_or_default())
            .map_err(|_| BufferFull)?;
        match zero {
            // The 00h is the code byte's own: the next block starts after it (an empty
            // block when `source` ends with 00h).
            Some(at) => rest = rest.get(at + 1..).unwrap_or_default(),
            None if data == FULL && rest.len() > FULL => {
                rest = rest.get(FULL..).unwrap_or_default()
            }
            None => break,
        }
    }
    out.push(0).map_err(|_| BufferFull)
}

/// Decodes one COBS frame without its delimiter (`source` holds no 00h: the reassembler
/// keeps none) into `out`; its length, or `None` when it does not decode. Each code byte `c`
/// is followed by `c − 1` data bytes, and stands for a 00h after them unless it is FFh or the
/// frame ends there; a block running past the end of the frame is a broken frame. What
/// `cobs::decode` of the `cobs` crate accepts, with the same result (a test compares them on
/// any input), in one pass over the bytes: a link message's blocks are short (every 00h of
/// the message ends one), and a copy call per block cost more than the bytes it copied.
fn decode(source: &[u8], out: &mut [u8]) -> Option<usize> {
    let mut written = 0;
    // Data bytes still to come in the current block; 0: the next byte is a code byte.
    let mut remaining = 0u8;
    let mut zero_before = false;
    for &byte in source {
        if remaining > 0 {
            *out.get_mut(written)? = byte;
            written += 1;
            remaining -= 1;
            continue;
        }
        if zero_before {
            *out.get_mut(written)? = 0;
            written += 1;
        }
        remaining = byte.checked_sub(1)?;
        zero_before = byte != 0xFF;
    }
    (remaining == 0 && !source.is_empty()).then_some(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    proptest::proptest! {
        /// The block decoder accepts what the `cobs` crate's decoder accepts, with the same
        /// bytes: on any frame without 00h (what the reassembler hands it), valid or not, and
        /// on the encoding of any payload.
        #[test]
        fn the_block_decoder_decodes_as_the_cobs_crate_does(
            raw in proptest::collection::vec(1u8..=255, 0..600),
            payload in proptest::collection::vec(proptest::num::u8::ANY, 0..600),
        ) {
            let mut encoded = [0u8; 700];
            let len = cobs::try_encode(&payload, &mut encoded).unwrap();
            for source in [&raw[..], &encoded[..len]] {
                let mut ours = [0u8; 700];
                let mut theirs = [0u8; 700];
                let expected = cobs::decode(source, &mut theirs).ok().map(|r| r.frame_size());
                let got = decode(source, &mut ours);
                proptest::prop_assert_eq!(got, expected);
                if let Some(len) = got {
                    proptest::prop_assert_eq!(&ours[..len], &theirs[..len]);
                }
            }
            let mut small = [0u8; 8];
            let expected = cobs::decode(&encoded[..len], &mut small).ok().map(|r| r.frame_size());
            proptest::prop_assert_eq!(decode(&encoded[..len], &mut small), expected);
        }
    }

    proptest::proptest! {
        /// `encode_into` gives the bytes of the `cobs` crate's encoder and the delimiter, on
        /// any payload (00h runs and blocks of 254 and more non-zero bytes included), and
        /// reports a buffer too small for them.
        #[test]
        fn encode_into_gives_the_cobs_crate_encoding_and_the_delimiter(
            payload in proptest::collection::vec(
                proptest::prop_oneof![proptest::num::u8::ANY, 1u8..=255, 1u8..=255, 1u8..=255],
                0..800,
            ),
        ) {
            let mut expected = [0u8; 820];
            let len = cobs::try_encode(&payload, &mut expected).unwrap();
            let mut out = heapless::Vec::<u8, 820>::new();
            proptest::prop_assert_eq!(encode_into(&payload, &mut out), Ok(()));
            proptest::prop_assert_eq!(&out[..len], &expected[..len]);
            proptest::prop_assert_eq!(out.len(), len + 1);
            proptest::prop_assert_eq!(out[len], 0);
            let mut short = heapless::Vec::<u8, 820>::new();
            let _ = short.extend_from_slice(&[0; 820][..820 - len]);
            proptest::prop_assert_eq!(encode_into(&payload, &mut short), Err(BufferFull));
        }
    }

    /// The edges of the block rule, spelled out: empty, 00h alone, a full block ending the
    /// payload (no empty block after it) and one followed by more bytes.
    #[test]
    fn encode_into_handles_empty_and_full_blocks() {
        let encoded = |payload: &[u8]| {
            let mut out = heapless::Vec::<u8, 600>::new();
            encode_into(payload, &mut out).unwrap();
            out.to_vec()
        };
        assert_eq!(encoded(&[]), [1, 0]);
        assert_eq!(encoded(&[0]), [1, 1, 0]);
        assert_eq!(encoded(&[5, 0, 6]), [2, 5, 2, 6, 0]);
        let full = [7u8; 254];
        let mut expected = std::vec![0xFF];
        expected.extend_from_slice(&full);
        expected.push(0);
        assert_eq!(encoded(&full), expected);
        let mut longer = full.to_vec();
        longer.push(8);
        expected.pop();
        expected.extend_from_slice(&[2, 8, 0]);
        assert_eq!(encoded(&longer), expected);
    }

    /// Every way of cutting a stream into slices gives what pushing it byte by byte gives:
    /// frames, broken frames (bad COBS, overflow) and skipped empty frames alike.
    #[test]
    fn a_slice_completes_what_its_bytes_complete_one_at_a_time() {
        let mut stream = std::vec::Vec::new();
        let mut frame = [0u8; 16];
        for payload in [&[1u8, 0, 2][..], &[], &[0, 0, 0], &[5; 9]] {
            let len = cobs::try_encode(payload, &mut frame).unwrap();
            stream.extend_from_slice(&frame[..len]);
            stream.push(0);
        }
        stream.extend_from_slice(&[0, 3, 0, 0, 9, 9, 9, 9, 9, 9, 9, 9, 9, 9, 9, 9, 9, 0, 7]);
        let mut expected = std::vec::Vec::new();
        let mut one = Reassembler::<12>::new();
        let mut out = [0u8; 12];
        for (at, &byte) in stream.iter().enumerate() {
            if let Some(completed) = one.push(byte, &mut out) {
                let frame = match completed {
                    Completed::Frame(len) => Some(out[..len].to_vec()),
                    Completed::Broken => None,
                };
                expected.push((at + 1, frame));
            }
        }
        assert!(
            expected.len() >= 6,
            "the stream exercises frames and faults"
        );
        for cut in 1..=stream.len() {
            let mut sliced = Reassembler::<12>::new();
            let mut got = std::vec::Vec::new();
            let mut offset = 0;
            for chunk in stream.chunks(cut) {
                let mut rest = chunk;
                while !rest.is_empty() {
                    let (taken, completed) = sliced.push_slice(rest, &mut out);
                    assert!(taken > 0 && taken <= rest.len());
                    offset += taken;
                    rest = &rest[taken..];
                    if let Some(completed) = completed {
                        let frame = match completed {
                            Completed::Frame(len) => Some(out[..len].to_vec()),
                            Completed::Broken => None,
                        };
                        got.push((offset, frame));
                    }
                }
            }
            assert_eq!(got, expected, "slices of {cut}");
        }
    }
}
