//! The return addresses of the calls that led to a point, read from the frame records on the
//! stack: what the panic handler logs instead of the panic's location (`board::panic`).
//!
//! `thumbv7em-none-eabihf` keeps a frame pointer in every function: the prologue pushes r7 and
//! lr and points r7 at the saved r7, so each frame holds a record of two words, the caller's
//! frame pointer and then the return address into the caller, and the records form a chain up
//! the stack. The walk trusts nothing it reads: it reads only word-aligned records inside the
//! stack region, follows a link only upwards (a caller's frame lies above its callee's: the
//! stack grows down), and stops after [`TRAIL_DEPTH`] records, so a corrupted stack ends it
//! early instead of leading it astray or round in a loop.

use core::ops::Range;

/// Return addresses the panic handler logs: enough to pass the handler, `core`'s `panic_fmt`,
/// the panic function that called it (`panic_bounds_check`, `unwrap_failed`, …) and reach the
/// code that panicked, with room for the function around it.
pub const TRAIL_DEPTH: usize = 6;

/// Up to `N` return addresses, the innermost call first.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameTrail<const N: usize> {
    addresses: [u32; N],
    len: usize,
}

impl<const N: usize> FrameTrail<N> {
    /// Walks the records from the one `frame` (a frame pointer's value) points at, reading
    /// words with `read`, which is called only for word-aligned addresses inside `stack`.
    pub fn walk(frame: usize, stack: Range<usize>, read: impl Fn(usize) -> u32) -> Self {
        let mut trail = FrameTrail {
            addresses: [0; N],
            len: 0,
        };
        let mut frame = frame;
        while let Some(slot) = trail.addresses.get_mut(trail.len) {
            let inside = frame % 4 == 0
                && frame >= stack.start
                && frame.checked_add(8).is_some_and(|end| end <= stack.end);
            if !inside {
                break;
            }
            let caller = read(frame) as usize;
            // The return address with the Thumb state bit cleared: the address of the
            // instruction after the call.
            *slot = read(frame + 4) & !1;
            trail.len += 1;
            if caller <= frame {
                break;
            }
            frame = caller;
        }
        trail
    }

    /// The addresses found, the innermost call first.
    pub fn addresses(&self) -> &[u32] {
        self.addresses.get(..self.len).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    extern crate std;

    use super::*;
    use std::cell::RefCell;
    use std::vec::Vec;

    const BASE: usize = 0x2000_0000;

    /// A stack of `words` at [`BASE`], and a reader that records every address it is asked
    /// for and fails the test on one outside the stack or not word-aligned.
    struct Stack {
        words: Vec<u32>,
        read: RefCell<Vec<usize>>,
    }

    impl Stack {
        fn new(words: usize) -> Self {
            Stack {
                words: std::vec![0; words],
                read: RefCell::new(Vec::new()),
            }
        }

        fn range(&self) -> Range<usize> {
            BASE..BASE + 4 * self.words.len()
        }

        /// Writes a frame record at word `at`: the caller's frame pointer, the return address.
        fn record(&mut self, at: usize, caller: usize, returns_to: u32) {
            self.words[at] = caller as u32;
            self.words[at + 1] = returns_to;
        }

        fn walk<const N: usize>(&self, frame: usize) -> FrameTrail<N> {
            FrameTrail::walk(frame, self.range(), |address| {
                assert_eq!(address % 4, 0, "unaligned read at {address:#x}");
                assert!(
                    self.range().contains(&address),
                    "read outside at {address:#x}"
                );
                self.read.borrow_mut().push(address);
                self.words[(address - BASE) / 4]
            })
        }
    }

    fn at(word: usize) -> usize {
        BASE + 4 * word
    }

    #[test]
    fn the_trail_follows_the_records_up_the_stack_innermost_call_first() {
        let mut stack = Stack::new(64);
        // Handler at word 4, called from panic_fmt's frame at 10, from the panicking
        // function's frame at 20, from the loop's at 40, whose caller's frame pointer is 0.
        stack.record(4, at(10), 0x0800_1235);
        stack.record(10, at(20), 0x0800_2001);
        stack.record(20, at(40), 0x0800_3457);
        stack.record(40, 0, 0x0800_4001);
        let trail = stack.walk::<6>(at(4));
        assert_eq!(
            trail.addresses(),
            [0x0800_1234, 0x0800_2000, 0x0800_3456, 0x0800_4000]
        );
    }

    #[test]
    fn the_trail_stops_after_its_depth() {
        let mut stack = Stack::new(64);
        for record in 0..10 {
            stack.record(
                4 * record,
                at(4 * record + 4),
                0x0800_0001 + 0x100 * record as u32,
            );
        }
        let trail = stack.walk::<3>(at(0));
        assert_eq!(trail.addresses(), [0x0800_0000, 0x0800_0100, 0x0800_0200]);
        // Three records of two words, nothing more read.
        assert_eq!(stack.read.borrow().len(), 6);
    }

    #[test]
    fn a_link_that_does_not_go_up_the_stack_ends_the_trail() {
        let mut stack = Stack::new(64);
        // A loop (20 -> 10 -> 20) and a link to itself: each ends after the record it is in.
        stack.record(10, at(20), 0x0800_1001);
        stack.record(20, at(10), 0x0800_2001);
        assert_eq!(
            stack.walk::<6>(at(10)).addresses(),
            [0x0800_1000, 0x0800_2000]
        );
        stack.record(30, at(30), 0x0800_3001);
        assert_eq!(stack.walk::<6>(at(30)).addresses(), [0x0800_3000]);
    }

    #[test]
    fn a_frame_pointer_outside_the_stack_or_unaligned_is_not_read() {
        let mut stack = Stack::new(16);
        // Below the stack, above it, a record that would end past its top, unaligned.
        for frame in [BASE - 8, BASE + 64, BASE + 60, BASE + 6] {
            assert_eq!(stack.walk::<6>(frame).addresses(), [] as [u32; 0]);
        }
        assert!(stack.read.borrow().is_empty());
        // A chain that leads out of the stack ends at the last record inside.
        stack.record(2, at(100), 0x0800_1001);
        stack.record(6, at(9) + 2, 0x0800_2001);
        assert_eq!(stack.walk::<6>(at(2)).addresses(), [0x0800_1000]);
        assert_eq!(stack.walk::<6>(at(6)).addresses(), [0x0800_2000]);
        // The last two words of the stack still hold a record.
        stack.record(14, 0, 0x0800_3001);
        assert_eq!(stack.walk::<6>(at(14)).addresses(), [0x0800_3000]);
    }

    #[test]
    fn a_frame_pointer_near_the_end_of_the_address_space_is_not_read() {
        let trail =
            FrameTrail::<6>::walk(usize::MAX - 3, 0..usize::MAX, |_| panic!("no record there"));
        assert_eq!(trail.addresses(), [] as [u32; 0]);
    }
}
