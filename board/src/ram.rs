//! The RAM test: March C- ([`dual_channel::selftest::march`]) over all of RAM, run right
//! after reset, before the start-up code initialises `.data` and `.bss` (cortex-m-rt's
//! `pre_init`), so that it covers the memory every channel datum will live in (the
//! runtime, the protocol core, the process image, the stacks), not a sample of it. Only the
//! top [`MARGIN`] bytes (the test's own stack frame) and the word holding the verdict are left
//! out; the verdict word gets a pattern test of its own.
//!
//! The verdict waits in `.uninit` (which the start-up code does not touch) until
//! [`crate::self_test`] reads it: the channel starts only on a pass.

use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use dual_channel::selftest::{Words, march};

/// Bytes below the top of RAM left for the test's own stack frame.
const MARGIN: usize = 512;
/// Where RAM begins (`memory.x`: RAM ORIGIN).
const RAM_ORIGIN: usize = 0x2000_0000;
/// The verdict of a passed test; anything else is a failure.
const PASSED: u32 = 0x600D_2A11;
/// The verdict when the verdict word itself failed its pattern test.
const WORD_FAILED: u32 = 0xBAD0_0001;
/// The verdict when the March test failed (where is not kept: the start-up code overwrites
/// RAM right after, and a failed channel stays in its safe state either way).
const MARCH_FAILED: u32 = 0xBAD0_0002;

/// The verdict, and the bytes tested, kept across the start-up code.
#[unsafe(link_section = ".uninit.RAM_TEST")]
static mut VERDICT: MaybeUninit<[u32; 2]> = MaybeUninit::uninit();

/// Word-addressed raw RAM from `start`, `len` words.
struct Raw {
    start: *mut u32,
    len: usize,
}

impl Words for Raw {
    fn len(&self) -> usize {
        self.len
    }
    fn read(&mut self, index: usize) -> u32 {
        // SAFETY: `index < len`, checked by `march`'s loops; the range is RAM nothing else
        // uses before the start-up code runs (see `ram_test`).
        unsafe { self.start.add(index).read_volatile() }
    }
    fn write(&mut self, index: usize, value: u32) {
        // SAFETY: as for `read`.
        unsafe { self.start.add(index).write_volatile(value) }
    }
}

// cortex-m-rt's reset handler calls `__pre_init` before it initialises RAM (its link.x
// provides an empty default); this one jumps to the test, which returns to the handler.
core::arch::global_asm!(
    ".section .text.__pre_init,\"ax\"",
    ".global __pre_init",
    ".type __pre_init,%function",
    ".thumb_func",
    "__pre_init:",
    "b {test}",
    test = sym ram_test,
);

/// Runs before RAM is initialised. Touches no static but through raw pointers, uses only its
/// own frame at the top of the stack, and leaves the verdict in `VERDICT`.
///
/// # Safety
///
/// Called once by cortex-m-rt's reset handler (through `__pre_init`), before `.data` and
/// `.bss` are initialised; nothing else runs. The ranges tested are RAM below the current
/// stack frame.
unsafe extern "C" fn ram_test() {
    let verdict = addr_of_mut!(VERDICT) as *mut u32;
    let sp = cortex_m::register::msp::read() as usize;
    let top = (sp - MARGIN) & !3;
    // The verdict words first: the patterns must read back.
    for pattern in [0u32, 0xFFFF_FFFF, 0x5555_5555, 0xAAAA_AAAA] {
        for word in 0..2 {
            // SAFETY: the two words of `VERDICT`, in RAM, unused by anyone yet.
            let read = unsafe {
                verdict.add(word).write_volatile(pattern);
                verdict.add(word).read_volatile()
            };
            if read != pattern {
                // SAFETY: as above; the best place there is for this verdict.
                unsafe { verdict.write_volatile(WORD_FAILED) };
                return;
            }
        }
    }
    let below = Raw {
        start: RAM_ORIGIN as *mut u32,
        len: (verdict as usize - RAM_ORIGIN) / 4,
    };
    let above_start = verdict as usize + 8;
    let above = Raw {
        start: above_start as *mut u32,
        len: top.saturating_sub(above_start) / 4,
    };
    let bytes = (below.len + above.len) * 4;
    for mut part in [below, above] {
        if march(&mut part).is_err() {
            // SAFETY: the verdict word, tested above.
            unsafe { verdict.write_volatile(MARCH_FAILED) };
            return;
        }
    }
    // SAFETY: the verdict words, tested above.
    unsafe {
        verdict.write_volatile(PASSED);
        verdict.add(1).write_volatile(bytes as u32);
    }
}

/// Why the RAM test did not pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub enum RamVerdict {
    /// The March C- test found a fault.
    March,
    /// The word holding the verdict failed its pattern test.
    VerdictWord,
    /// No verdict: the test did not run or its result was lost.
    Missing,
}

/// The RAM test's verdict: the bytes tested, or why it failed. Read once; the word is then
/// cleared so that a verdict is never read twice.
pub fn verdict() -> Result<usize, RamVerdict> {
    let verdict = addr_of_mut!(VERDICT) as *mut u32;
    // SAFETY: the verdict words were written by `ram_test` (or hold whatever RAM held, which
    // is then not `PASSED` but for a 1 in 2^32 chance); aligned, in RAM, read here once by
    // the one thread of the start-up.
    let (word, bytes) = unsafe { (verdict.read_volatile(), verdict.add(1).read_volatile()) };
    // SAFETY: as above.
    unsafe { verdict.write_volatile(0) };
    match word {
        PASSED => Ok(bytes as usize),
        MARCH_FAILED => Err(RamVerdict::March),
        WORD_FAILED => Err(RamVerdict::VerdictWord),
        _ => Err(RamVerdict::Missing),
    }
}
