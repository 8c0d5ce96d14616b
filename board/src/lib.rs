//! Board layers of the firmware images: everything that touches hardware, and nothing else.
//!
//! - [`hw`] (feature `hw`): embassy-stm32 on the STM32F405RG: bxCAN, the link USART, the
//!   safety input and output pins and the independent watchdog.
//! - [`qemu`] (feature `qemu`): QEMU's `netduinoplus2`: a SysTick time driver, register-level
//!   USARTs (CAN frames over serial, and the link), semihosting.
//!
//! Both run a channel [`Runtime`](dual_channel::runtime::Runtime); the logic it drives is
//! host-tested in `dual-channel`, `channel-a` and `channel-b`. On the host this crate holds
//! only the types both layers share.
#![no_std]

use shared::canopen::od::Address;

#[cfg(all(target_os = "none", feature = "hw"))]
pub mod hw;
#[cfg(all(target_os = "none", feature = "qemu"))]
pub mod qemu;

/// The channel's safety input and its inverted copy in the object dictionary.
#[derive(Clone, Copy, Debug)]
pub struct InputObjects {
    /// The plain object (e.g. 0x6000:1).
    pub plain: Address,
    /// Its inverted copy (e.g. 0x6001:1).
    pub inverted: Address,
}

/// The start-up self-tests both layers run before the channel starts: RAM (a dedicated 1 KiB
/// area, March C-) and the link CRC's known answer. `false` when one fails; the caller stays
/// in the safe state.
#[cfg(target_os = "none")]
pub fn self_tests() -> bool {
    use dual_channel::selftest;
    static mut AREA: [u32; 256] = [0; 256];
    // SAFETY: this is the only access to `AREA`, made once at start-up before any task runs;
    // `self_tests` is called once per boot by the board layer.
    let area = unsafe { &mut *core::ptr::addr_of_mut!(AREA) };
    match selftest::march(area.as_mut_slice()) {
        Ok(()) => defmt::info!("self-test: RAM (1 KiB, March C-) passed"),
        Err(fault) => {
            defmt::error!("self-test: RAM failed {}", fault);
            return false;
        }
    }
    if !selftest::crc_known_answer() {
        defmt::error!("self-test: CRC known answer failed");
        return false;
    }
    defmt::info!("self-test: CRC known answer passed");
    true
}
