//! The panic handler of the images: logs where the panic came from as return addresses, and
//! ends in a HardFault.
//!
//! A panic in the firmware is a defect, never a path of the protocol (bad input gets an error
//! value). What the handler does is what `panic-probe` did before it, minus the formatting:
//! interrupts off, one log line, then `udf` with UsageFault disabled, so the fault escalates to
//! HardFault. The default HardFault handler spins without feeding the independent watchdog, so
//! the MCU resets and starts again in the safe state (the emulated STM32F405 ends its run at
//! the HardFault instead, `cargo xtask emulate --panic-at`).
//!
//! The handler reads nothing of the [`PanicInfo`]: neither the message nor the location. Reading
//! either keeps every panic site's location (a 16-byte record and its file name in flash) and
//! the standard library's formatting (`core::fmt`: the bounds-check panics store
//! `<usize as Display>::fmt` in their arguments) in the image (measured in
//! `docs/footprint.md`). The log line names the panic's place by the return addresses of the
//! calls that led to the handler instead, found by the frame records the target keeps
//! (`thumbv7em-none-eabihf` forces frame pointers: every function starts with `push {…, r7,
//! lr}` and points r7 at the saved r7, the saved lr above it). `cargo xtask where a|b ADDRESS…`
//! turns them into functions, files and lines from the image's debug information; with a probe
//! attached, `probe-rs run` prints the same backtrace when the core stops on the fault.
//!
//! What that costs: where a function holds several panics, the compiler shares one call of
//! the panic among them (their arguments are dead, so the calls are alike), and its return
//! address names the function, with what was inlined at the call, but no line. The place of a
//! panic is then the function and the calls above it in the trail, not the statement.

use core::panic::PanicInfo;
use core::sync::atomic::{AtomicBool, Ordering};

use crate::frame_trail::{FrameTrail, TRAIL_DEPTH};

#[panic_handler]
fn panic(_info: &PanicInfo) -> ! {
    static PANICKED: AtomicBool = AtomicBool::new(false);
    cortex_m::interrupt::disable();
    // A panic while logging the first one logs nothing more.
    if !PANICKED.swap(true, Ordering::Relaxed) {
        let trail = trail();
        defmt::error!(
            "panicked; return addresses {=[?]:#010x} (`cargo xtask where` names them)",
            trail.addresses()
        );
    }
    // SAFETY: the System Handler Control and State Register of the Cortex-M4 (ARMv7-M ARM
    // B3.2.13) at its architected address; clearing USGFAULTENA only makes the undefined
    // instruction below escalate to HardFault. Interrupts are off, so nothing else touches
    // the register meanwhile.
    unsafe {
        const SHCSR: *mut u32 = 0xE000_ED24 as *mut u32;
        const USGFAULTENA: u32 = 1 << 18;
        core::ptr::write_volatile(SHCSR, core::ptr::read_volatile(SHCSR) & !USGFAULTENA);
    }
    cortex_m::asm::udf()
}

/// The return addresses of the frames above the handler's, read from the stack.
#[inline(always)]
fn trail() -> FrameTrail<TRAIL_DEPTH> {
    let frame: usize;
    // SAFETY: copies r7, the frame pointer, into a register; reads no memory, writes nothing.
    unsafe {
        core::arch::asm!("mov {}, r7", out(reg) frame, options(nomem, nostack, preserves_flags));
    }
    FrameTrail::walk(frame, crate::stack::region(), |address| {
        // SAFETY: `FrameTrail::walk` reads only word-aligned addresses inside the stack's
        // region, which is mapped RAM; the records it reads belong to the handler's callers,
        // suspended under it for good, and interrupts are off, so nothing writes them
        // meanwhile.
        unsafe { (address as *const u32).read_volatile() }
    })
}
