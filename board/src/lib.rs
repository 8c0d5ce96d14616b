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
