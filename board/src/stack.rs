//! The stack's high-water mark, measured: cortex-m-rt's reset handler paints the whole stack
//! with `STACK_PAINT_VALUE` before `main` (feature `paint-stack`), and the deepest word no
//! longer holding it shows how much stack was ever used. The images' RAM budget reserves
//! `STACK_RESERVE` for the stack (`cargo xtask build`); both board layers report the measured
//! figure (the QEMU layer in its status, the hardware layer in its log), and `cargo xtask e2e`
//! fails when an emulated channel used more than the reserve.

use core::ptr::addr_of;
use cortex_m_rt::STACK_PAINT_VALUE;

unsafe extern "C" {
    /// The lowest address of the stack (cortex-m-rt's link.x: the end of `.uninit`).
    static _stack_end: u32;
    /// The initial stack pointer, the top of the stack.
    static _stack_start: u32;
}

/// Bytes of stack used so far: from the top to the deepest word no longer painted.
pub fn used() -> usize {
    // Only the addresses of the linker's symbols are taken, never their contents.
    let (bottom, top) = (
        addr_of!(_stack_end) as usize,
        addr_of!(_stack_start) as usize,
    );
    let mut at = bottom;
    // SAFETY: [bottom, top) is the stack, mapped RAM; reading a word of it races with nothing
    // that matters (a word being written is in use either way). Aligned words.
    while at < top && unsafe { (at as *const u32).read_volatile() } == STACK_PAINT_VALUE {
        at += 4;
    }
    top - at
}

/// How many loop iterations [`Sampled`] lets pass between two scans.
const SAMPLE_EVERY: u16 = 64;

/// The high-water mark, scanned every [`SAMPLE_EVERY`]th loop iteration instead of every one.
///
/// A scan reads every word still painted, from the stack's lowest address up: all the RAM
/// the statics leave free, about 30,000 instructions per scan counted under QEMU, which the
/// loop paid on every iteration while it scanned each time. A word overwritten stays
/// overwritten, so a scan that comes later finds the same mark; sampling only delays when a
/// deeper mark is seen (by at most 63 iterations), never loses it.
pub struct Sampled {
    countdown: u16,
    mark: usize,
}

impl Default for Sampled {
    fn default() -> Self {
        Self::new()
    }
}

impl Sampled {
    /// A sampler whose first call scans.
    pub const fn new() -> Self {
        Sampled {
            countdown: 0,
            mark: 0,
        }
    }

    /// Called once per loop iteration: the mark, when this call scanned and found it deeper
    /// than the last one it returned.
    pub fn poll(&mut self) -> Option<usize> {
        if self.countdown > 0 {
            self.countdown -= 1;
            return None;
        }
        self.countdown = SAMPLE_EVERY - 1;
        let used = used();
        (used > self.mark).then(|| {
            self.mark = used;
            used
        })
    }
}
