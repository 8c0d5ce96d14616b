//! Reassembling COBS-encoded, zero-delimited frames from a byte stream: what the inter-channel
//! link (`dual-channel`) and the emulation's CAN-over-serial line (`emulation-wire`) share, in a
//! crate of its own so that neither depends on the other.

#![no_std]
#![forbid(unsafe_code)]

#[cfg(test)]
extern crate std;

/// A frame in the making: bytes up to the next 0x00 delimiter.
#[derive(Clone, Debug, Default)]
pub struct Reassembler<const N: usize> {
    buffer: heapless::Vec<u8, N>,
    overflowed: bool,
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
            buffer: heapless::Vec::new(),
            overflowed: false,
        }
    }

    /// Feeds one byte. At a delimiter, decodes the frame into `out` and says how long it is;
    /// an empty frame (two delimiters in a row: idle line or resynchronisation) is nothing.
    pub fn push(&mut self, byte: u8, out: &mut [u8; N]) -> Option<Completed> {
        if byte != 0 {
            if self.buffer.push(byte).is_err() {
                self.overflowed = true;
            }
            return None;
        }
        let overflowed = core::mem::replace(&mut self.overflowed, false);
        if self.buffer.is_empty() && !overflowed {
            return None;
        }
        let decoded = (!overflowed).then(|| decode(&self.buffer, out)).flatten();
        self.buffer.clear();
        Some(decoded.map_or(Completed::Broken, Completed::Frame))
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
    /// byte [`Reassembler::push`] cannot keep does.
    fn collect(&mut self, bytes: &[u8]) {
        let room = N - self.buffer.len();
        let (kept, dropped) = bytes.split_at(bytes.len().min(room));
        // `kept` fits the room left by construction.
        let _ = self.buffer.extend_from_slice(kept);
        if !dropped.is_empty() {
            self.overflowed = true;
        }
    }
}

/// Decodes one COBS frame without its delimiter (`source` holds no 00h: the reassembler
/// keeps none) into `out`; its length, or `None` when it does not decode. Each code byte `c`
/// is followed by `c − 1` data bytes, and stands for a 00h after them unless it is FFh or the
/// frame ends there; a block running past the end of the frame is a broken frame. What
/// `cobs::decode` of the `cobs` crate accepts, with the same result (a test compares them on
/// any input), a block at a time instead of a state machine per byte.
fn decode(source: &[u8], out: &mut [u8]) -> Option<usize> {
    let mut read = 0;
    let mut written = 0;
    let mut zero_before = false;
    while let Some(&code) = source.get(read) {
        if zero_before {
            *out.get_mut(written)? = 0;
            written += 1;
        }
        let data = usize::from(code).checked_sub(1)?;
        let block = source.get(read + 1..read + 1 + data)?;
        out.get_mut(written..written + data)?.copy_from_slice(block);
        written += data;
        read += 1 + data;
        zero_before = code != 0xFF;
    }
    (read > 0).then_some(written)
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
