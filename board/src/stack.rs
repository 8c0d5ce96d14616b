//! The stack's high-water mark, measured: cortex-m-rt's reset handler paints the whole stack
//! with `STACK_PAINT_VALUE` before `main` (feature `paint-stack`), and the deepest word no
//! longer holding it shows how much stack was ever used. The images' RAM budget reserves
//! `STACK_RESERVE` for the stack (`cargo xtask build`); the board layer logs the measured
//! figure, and `cargo xtask e2e` fails when an emulated channel used more than the reserve.
//!
//! The search for that word is spread over the loop's iterations ([`Sweep`], host-tested
//! here; `Sampled` on the target reads the stack with it), a bounded number of words per
//! iteration, so that no iteration pays for the whole stack: the loop's longest iteration is
//! the processing step the safety manual's response time is built on.

/// Words of the stack one loop iteration reads at most. Few: the loop runs at every wake-up
/// (every link message, every frame, the input sample every millisecond), and the search
/// is paid at each of them, in the idle iteration too, where it was the largest single part
/// (`docs/emulated-figures.md` has what an iteration costs with it); enough that a pass over
/// the region (all the RAM above the statics, not only the stack's reserve) takes a few
/// seconds of the loop's iterations, so that a new mark comes that much later, never lost.
pub const WORDS_PER_STEP: usize = 8;

/// The search for the deepest word no longer painted, a few words per call.
///
/// The stack grows down, from the top of its region towards its lowest address; a word
/// written stays written (nothing paints it again), so the deepest one written is the lowest
/// word of the region that is not painted. The sweep reads the region from its lowest word
/// up, [`WORDS_PER_STEP`] words per call, up to the deepest word found so far; a word found
/// not painted is the new deepest (every word below it was read painted on this pass), and
/// the next pass starts again at the lowest word. A word written below the deepest after
/// the pass went by it is found on the next pass: the mark comes late by at most two passes
/// (a pass over `n` painted words takes `n / WORDS_PER_STEP` calls), it is never lost, and it
/// is never deeper than what was used. (A scan of the whole region at once, every 64th
/// iteration as the layers did before, made that iteration many times longer than the
/// others; `docs/emulated-figures.md` has what an iteration costs now.)
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sweep {
    /// Words in the region.
    words: usize,
    /// The next word to read (0 is the lowest).
    cursor: usize,
    /// The lowest word found not painted; `words` while none is.
    deepest: usize,
}

impl Sweep {
    /// A sweep over a region of `words` words, nothing found yet.
    pub const fn new(words: usize) -> Self {
        Sweep {
            words,
            cursor: 0,
            deepest: words,
        }
    }

    /// Reads at most [`WORDS_PER_STEP`] words through `painted` (word index, 0 the lowest:
    /// whether the word still holds the paint); the bytes of stack used, from the top of the
    /// region down to the deepest word written, when this call found a deeper one.
    pub fn step(&mut self, mut painted: impl FnMut(usize) -> bool) -> Option<usize> {
        let end = self.deepest.min(self.cursor.saturating_add(WORDS_PER_STEP));
        for word in self.cursor..end {
            if !painted(word) {
                self.deepest = word;
                self.cursor = 0;
                return Some((self.words - word) * 4);
            }
        }
        self.cursor = if end >= self.deepest { 0 } else { end };
        None
    }
}

#[cfg(target_os = "none")]
pub use target::{Sampled, region};

#[cfg(target_os = "none")]
mod target {
    use super::Sweep;
    use core::ptr::addr_of;
    use cortex_m_rt::STACK_PAINT_VALUE;

    unsafe extern "C" {
        /// The lowest address of the stack (cortex-m-rt's link.x: the end of `.uninit`).
        static _stack_end: u32;
        /// The initial stack pointer, the top of the stack.
        static _stack_start: u32;
    }

    /// The high-water mark of this image's stack, searched a few words per loop iteration
    /// ([`Sweep`]).
    pub struct Sampled {
        bottom: usize,
        sweep: Sweep,
    }

    impl Default for Sampled {
        fn default() -> Self {
            Self::new()
        }
    }

    /// The stack's region, from its lowest address to its top (the initial stack pointer):
    /// mapped RAM, word-aligned at both ends.
    pub fn region() -> core::ops::Range<usize> {
        // Only the addresses of the linker's symbols are taken, never their contents.
        addr_of!(_stack_end) as usize..addr_of!(_stack_start) as usize
    }

    impl Sampled {
        /// A search over the whole stack region, nothing found yet.
        pub fn new() -> Self {
            let core::ops::Range {
                start: bottom,
                end: top,
            } = region();
            Sampled {
                bottom,
                sweep: Sweep::new(top.saturating_sub(bottom) / 4),
            }
        }

        /// Called once per loop iteration: the mark, when this call found it deeper than the
        /// last one it returned.
        pub fn poll(&mut self) -> Option<usize> {
            let bottom = self.bottom;
            self.sweep.step(|word| {
                // SAFETY: `Sweep` asks for words below the region's word count only, so the
                // address lies in [_stack_end, _stack_start), the stack: mapped RAM, word-
                // aligned (both symbols are). Reading a word of it races with nothing that
                // matters (a word being written is in use either way).
                unsafe { ((bottom + 4 * word) as *const u32).read_volatile() == STACK_PAINT_VALUE }
            })
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;

    use super::*;
    use std::vec;

    /// Calls `step` on `stack` (true: painted) until it reports or `calls` run out; the report
    /// and the calls it took.
    fn sweep_until_found(
        sweep: &mut Sweep,
        stack: &[bool],
        calls: usize,
    ) -> (Option<usize>, usize) {
        for call in 1..=calls {
            if let Some(used) = sweep.step(|word| stack[word]) {
                return (Some(used), call);
            }
        }
        (None, calls)
    }

    /// The first mark is the deepest word written, found within one pass over the painted
    /// words (and not before the pass reaches it), in bytes from the top; nothing when the
    /// stack is as painted.
    #[test]
    fn the_first_mark_is_the_deepest_word_written_within_one_pass() {
        let words = 3000;
        let mut stack = vec![true; words];
        let mut sweep = Sweep::new(words);
        let pass = words / WORDS_PER_STEP + 1;
        assert_eq!(sweep_until_found(&mut sweep, &stack, 2 * pass).0, None);
        // Used from the top down to word 2000, with a gap of untouched words in a frame.
        for (word, painted) in stack.iter_mut().enumerate().skip(2000) {
            *painted = word % 7 == 0 || word > 2100;
        }
        stack[2000] = false;
        let mut sweep = Sweep::new(words);
        let (found, calls) = sweep_until_found(&mut sweep, &stack, 2 * pass);
        assert_eq!(found, Some((words - 2000) * 4));
        assert_eq!(calls, 2000 / WORDS_PER_STEP + 1);
    }

    /// No call reads more than `WORDS_PER_STEP` words, none reads outside the region, and
    /// after a mark a pass reads only the words below it.
    #[test]
    fn a_call_reads_a_bounded_number_of_words_inside_the_region() {
        let words = 1000;
        let mut stack = vec![true; words];
        stack[900] = false;
        let mut sweep = Sweep::new(words);
        let mut highest = 0;
        for _ in 0..3 * words / WORDS_PER_STEP {
            let mut read = 0;
            sweep.step(|word| {
                assert!(word < words);
                highest = highest.max(word);
                read += 1;
                stack[word]
            });
            assert!(read <= WORDS_PER_STEP);
        }
        assert_eq!(
            highest, 900,
            "after the mark, only the words below it are read"
        );
    }

    /// A deeper use after the first mark is found on a later pass, also when the pass had
    /// already gone past the word when it was written; the mark never goes back up, and a
    /// shallower use changes nothing.
    #[test]
    fn a_deeper_use_is_found_later_and_the_mark_only_deepens() {
        let words = 2048;
        let mut stack = vec![true; words];
        stack[1500] = false;
        let mut sweep = Sweep::new(words);
        let passes = words / WORDS_PER_STEP + 1;
        assert_eq!(
            sweep_until_found(&mut sweep, &stack, passes).0,
            Some((words - 1500) * 4)
        );
        // The pass goes by word 300, then word 300 is written.
        for _ in 0..2 {
            assert_eq!(sweep.step(|word| stack[word]), None);
        }
        stack[300] = false;
        stack[1800] = false; // shallower than the mark: not a new mark
        let (found, calls) = sweep_until_found(&mut sweep, &stack, 2 * passes);
        assert_eq!(found, Some((words - 300) * 4));
        assert!(calls <= 2 * (1500 / WORDS_PER_STEP + 1));
        // Nothing deeper: no more reports, whatever else is written above the mark.
        stack[1000] = false;
        assert_eq!(sweep_until_found(&mut sweep, &stack, 3 * passes).0, None);
    }

    /// An empty region (no stack between the symbols) reads nothing and reports nothing.
    #[test]
    fn an_empty_region_reads_nothing() {
        let mut sweep = Sweep::new(0);
        for _ in 0..3 {
            assert_eq!(sweep.step(|_| panic!("no word to read")), None);
        }
    }
}
