//! Reassembling COBS-encoded, zero-delimited frames from a byte stream: what the inter-channel
//! link (`dual-channel`) and the emulation's CAN-over-serial line (`emulation-wire`) share, in a
//! crate of its own so that neither depends on the other.

#![no_std]
#![forbid(unsafe_code)]

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
        let decoded = (!overflowed)
            .then(|| cobs::decode(&self.buffer, out).ok())
            .flatten();
        self.buffer.clear();
        Some(decoded.map_or(Completed::Broken, |report| {
            Completed::Frame(report.frame_size())
        }))
    }
}
