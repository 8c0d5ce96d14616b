//! A byte queue on a fixed array that takes and hands out runs of bytes with a copy each
//! (at most two: where the run wraps), for the link USART's queues (`board::hw::link_usart`): its
//! interrupt moves one byte at a time, the loop moves whole messages, and a queue that
//! copied them a byte at a time through `push_back` and `pop_front` made the loop's link
//! reads and writes cost per byte (`docs/emulated-figures.md`).
//!
//! No operation panics: every index is checked, and a run that does not fit is refused whole.

/// Bytes, oldest first, in an array of `N`.
#[derive(Clone, Debug)]
pub struct ByteRing<const N: usize> {
    bytes: [u8; N],
    /// Where the oldest byte is (below `N`; 0 when empty).
    head: usize,
    /// How many bytes are held (at most `N`).
    len: usize,
}

impl<const N: usize> Default for ByteRing<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> ByteRing<N> {
    /// An empty queue.
    pub const fn new() -> Self {
        ByteRing {
            bytes: [0; N],
            head: 0,
            len: 0,
        }
    }

    /// How many bytes are held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// `true` when no byte is held.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// How many more bytes fit.
    pub fn room(&self) -> usize {
        N - self.len
    }

    /// Forgets every byte held.
    pub fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
    }

    /// Where the byte after the newest goes.
    fn tail(&self) -> usize {
        let tail = self.head + self.len;
        if tail >= N { tail - N } else { tail }
    }

    /// Appends `byte`; `false` (nothing kept) when the queue is full.
    pub fn push(&mut self, byte: u8) -> bool {
        if self.len >= N {
            return false;
        }
        let tail = self.tail();
        match self.bytes.get_mut(tail) {
            Some(slot) => {
                *slot = byte;
                self.len += 1;
                true
            }
            None => false,
        }
    }

    /// Takes the oldest byte.
    pub fn pop(&mut self) -> Option<u8> {
        if self.len == 0 {
            return None;
        }
        let byte = *self.bytes.get(self.head)?;
        self.head = if self.head + 1 >= N { 0 } else { self.head + 1 };
        self.len -= 1;
        Some(byte)
    }

    /// Appends all of `run`, or nothing of it when it does not fit (`false`).
    pub fn extend(&mut self, run: &[u8]) -> bool {
        if run.len() > self.room() {
            return false;
        }
        let tail = self.tail();
        // Up to the end of the array, then from its start.
        let first = run.len().min(N - tail);
        let (before_end, after_start) = run.split_at(first);
        let copied = self
            .bytes
            .get_mut(tail..tail + first)
            .map(|slots| slots.copy_from_slice(before_end))
            .and_then(|()| self.bytes.get_mut(..after_start.len()))
            .map(|slots| slots.copy_from_slice(after_start));
        if copied.is_none() {
            return false;
        }
        self.len += run.len();
        true
    }

    /// Moves the oldest bytes into `out`, as many as it holds or the queue has; how many.
    pub fn take_into(&mut self, out: &mut [u8]) -> usize {
        let count = out.len().min(self.len);
        if count == 0 {
            return 0;
        }
        // From the oldest byte up to the end of the array, then from its start.
        let first = count.min(N - self.head);
        let (before_end, after_start) = out.split_at_mut(first);
        let copied = self
            .bytes
            .get(self.head..self.head + first)
            .map(|run| before_end.copy_from_slice(run))
            .and_then(|()| after_start.get_mut(..count - first))
            .zip(self.bytes.get(..count - first))
            .map(|(slots, run)| slots.copy_from_slice(run));
        if copied.is_none() {
            return 0;
        }
        let head = self.head + count;
        self.head = if head >= N { head - N } else { head };
        self.len -= count;
        if self.len == 0 {
            self.head = 0;
        }
        count
    }
}

#[cfg(test)]
mod tests {
    extern crate std;

    use super::*;
    use std::collections::VecDeque;
    use std::vec::Vec;

    /// The queue holds what a `VecDeque` of the same capacity would: runs appended whole or
    /// refused whole, bytes and runs taken oldest first, across the array's end, over a long
    /// reproducible sequence of operations (a fixed linear congruential sequence).
    #[test]
    fn the_ring_keeps_the_bytes_a_bounded_queue_keeps() {
        let mut ring = ByteRing::<16>::new();
        let mut model: VecDeque<u8> = VecDeque::new();
        let mut seed: u32 = 0x2545_F491;
        let mut next = move |below: u32| {
            seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (seed >> 8) % below
        };
        let mut wrapped = false;
        for step in 0..20_000u32 {
            let length = next(13) as usize;
            let run: Vec<u8> = (0..length).map(|_| next(256) as u8).collect();
            match next(4) {
                0 => {
                    let fits = model.len() + run.len() <= 16;
                    assert_eq!(ring.extend(&run), fits, "step {step}");
                    if fits {
                        model.extend(run.iter().copied());
                    }
                }
                1 => {
                    let byte = run.first().copied().unwrap_or(0);
                    let fits = model.len() < 16;
                    assert_eq!(ring.push(byte), fits, "step {step}");
                    if fits {
                        model.push_back(byte);
                    }
                }
                2 => assert_eq!(ring.pop(), model.pop_front(), "step {step}"),
                _ => {
                    let mut out = [0u8; 12];
                    let count = ring.take_into(&mut out[..length]);
                    let expected: Vec<u8> = (0..length).map_while(|_| model.pop_front()).collect();
                    assert_eq!(&out[..count], &expected[..], "step {step}");
                }
            }
            wrapped |= ring.head + ring.len > 16;
            assert_eq!(ring.len(), model.len(), "step {step}");
            assert_eq!(ring.room(), 16 - model.len(), "step {step}");
            assert_eq!(ring.is_empty(), model.is_empty(), "step {step}");
        }
        assert!(
            wrapped,
            "the sequence never held bytes across the end of the array"
        );
    }
}
