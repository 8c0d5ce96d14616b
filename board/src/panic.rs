//! The panic handler of both images: logs the panic with defmt, without `core::fmt`, and ends
//! in a HardFault.
//!
//! A panic in the firmware is a defect, never a path of the protocol (bad input gets an error
//! value). What the handler does is what `panic-probe` did before it, minus the formatting:
//! interrupts off, one log line, then `udf` with UsageFault disabled, so the fault escalates to
//! HardFault. Under QEMU the HardFault handler ends the run with failure (`board::qemu`); on the
//! hardware the default HardFault handler spins without feeding the independent watchdog, so
//! the MCU resets and starts again in the safe state.
//!
//! A static message (`panic!("literal")`, `expect("literal")`, `unwrap` on `None`) is logged as
//! it is, with the file and line. A formatted message is not rendered: rendering it is what
//! links `core::fmt::write` and the formatting below it into the image (`docs/footprint.md`);
//! the location names the `panic!` that raised it.

use core::panic::PanicInfo;
use core::sync::atomic::{AtomicBool, Ordering};

#[panic_handler]
fn panic(info: &PanicInfo) -> ! {
    static PANICKED: AtomicBool = AtomicBool::new(false);
    cortex_m::interrupt::disable();
    // A panic while logging the first one logs nothing more.
    if !PANICKED.swap(true, Ordering::Relaxed) {
        let (file, line) = info.location().map_or(("<unknown>", 0), |location| {
            (location.file(), location.line())
        });
        match info.message().as_str() {
            Some(message) => {
                defmt::error!("panicked at {=str}:{=u32}: {=str}", file, line, message);
            }
            None => defmt::error!(
                "panicked at {=str}:{=u32} (formatted message, not rendered)",
                file,
                line
            ),
        }
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
