//! The stack's high-water mark, measured: the free stack is painted with a pattern at
//! start-up, and the deepest word no longer holding it shows how much stack was ever used.
//! The images' RAM budget reserves 8 KiB for the stack (`cargo xtask build`); both board
//! layers report the measured figure (the QEMU layer in its status, the hardware layer in its
//! log), so the reserve is checked against what the code does, not assumed.

use core::ptr::addr_of;

/// The pattern painted on the free stack.
const PAINT: u32 = 0x57AC_C0DE;

/// Bytes left unpainted below the caller's frame (the painting function's own frame).
const MARGIN: usize = 256;

unsafe extern "C" {
    /// The lowest address of the stack (cortex-m-rt's link.x: the end of `.uninit`).
    static _stack_end: u32;
    /// The initial stack pointer, the top of the stack.
    static _stack_start: u32;
}

fn bounds() -> (usize, usize) {
    // Only the addresses of the linker's symbols are taken, never their contents.
    (
        addr_of!(_stack_end) as usize,
        addr_of!(_stack_start) as usize,
    )
}

/// Paints the stack below the caller's frame. Call once at start-up, before anything else
/// could be using that memory.
pub fn paint() {
    cortex_m::interrupt::free(|_| {
        let (bottom, _) = bounds();
        let sp = cortex_m::register::msp::read() as usize;
        let limit = sp.saturating_sub(MARGIN) & !3;
        let mut at = bottom;
        while at < limit {
            // SAFETY: [bottom, limit) is stack below the current frame (and its margin), not
            // in use by anyone: interrupts are disabled and nothing else runs. Aligned words.
            unsafe { (at as *mut u32).write_volatile(PAINT) };
            at += 4;
        }
    });
}

/// Bytes of stack used so far: from the top to the deepest word no longer painted.
pub fn used() -> usize {
    let (bottom, top) = bounds();
    let mut at = bottom;
    // SAFETY: [bottom, top) is the stack, mapped RAM; reading a word of it races with nothing
    // that matters (a word being written is in use either way). Aligned words.
    while at < top && unsafe { (at as *const u32).read_volatile() } == PAINT {
        at += 4;
    }
    top - at
}
