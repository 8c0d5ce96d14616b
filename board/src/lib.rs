//! Board layers of the firmware images: everything that touches hardware, and nothing else.
//!
//! [`hw`] runs a channel [`Runtime`](dual_channel::runtime::Runtime) on the STM32F405RG with
//! embassy-stm32: bxCAN, the link USART, the safety input and output pins and the independent
//! watchdog. The logic it drives is host-tested in `dual-channel`, `channel-a` and `channel-b`.
//! On the host this crate is empty.
#![no_std]

#[cfg(target_os = "none")]
pub mod hw;
