//! The board layer of the firmware images: everything that touches hardware, and nothing else.
//!
//! `hw` (feature `hw`): the STM32F405RG: the board's own register-level drivers for the
//! bxCAN, the link USART, the parameter flash and the independent watchdog (RM0090), and
//! embassy-stm32 for the clock tree, the pins, the time driver and the interrupt vectors. It
//! is an adapter of the one channel loop
//! ([`ChannelLoop`](dual_channel::channel_loop::ChannelLoop)) around a channel
//! [`Runtime`](dual_channel::runtime::Runtime): it implements the loop's
//! [`Driver`](dual_channel::channel_loop::Driver) and waits on the hardware; the loop and the
//! logic it drives are host-tested in `dual-channel`, `channel-a`, `channel-b` and `tests`,
//! and the images themselves run on the emulated STM32F405 (`emulator`).
//!
//! Beside `hw`, the crate holds what reads the hardware's own layout, host-tested:
//!
//! - [`can_registers`]: the bxCAN's register fields (CAN_BTR's bit timing, the error state in
//!   CAN_ESR, RM0090 32.9).
//! - [`stack`]'s search for the stack's high-water mark is adapter logic because it encodes
//!   how the MCU's stack lies in RAM: a full-descending stack of 32-bit words between the
//!   linker's `_stack_end` and the initial stack pointer, painted word by word by cortex-m-rt's
//!   reset handler, so that the lowest word no longer painted is the deepest ever used.
//! - [`frame_trail`]'s walk is adapter logic because it encodes the frame records the
//!   target's code generation leaves on that stack (`thumbv7em-none-eabihf`: r7 points at a
//!   two-word record, the caller's r7 and then the return address with the Thumb bit set, and
//!   each caller's record lies above its callee's).
//!
//! What the values the layer reads and writes mean lives with its concept: the node-ID
//! switches, the reset flags and the parameter slots in flash (their sectors, their
//! programming in whole words) in `safety_device` (`switches`, `reset_cause`,
//! `parameter_flash`); the order of the transmit queue and the record of the bxCAN's transmit
//! mailboxes in `dual_channel::transmit_queue`, the link USART's byte queue in
//! `dual_channel::byte_ring`.
#![no_std]

use dual_channel::channel_loop::Pins;
use shared::canopen::NodeId;
use shared::node::NodeConfig;

pub mod can_registers;
pub mod counter;
pub mod frame_trail;
#[cfg(all(target_os = "none", feature = "hw"))]
pub mod hw;
#[cfg(target_os = "none")]
mod panic;
#[cfg(target_os = "none")]
pub mod ram;
pub mod stack;

/// SDD entries of the SimpleCAN layer in an image with the feature `simplecan`
/// ([`Protocol`]): the demo network's nodes use one each (node 1 produces 30h, node 33
/// consumes it); the channels cross-check at most [`dual_channel::simplecan::ENTRIES`].
#[cfg(feature = "simplecan")]
pub const SIMPLECAN_ENTRIES: usize = 2;

/// The SRDOs of the image's SRDO table: the device's
/// ([`SRDO_COUNT`](safety_device::SRDO_COUNT)).
#[cfg(not(feature = "simplecan"))]
pub const SRDOS: usize = safety_device::SRDO_COUNT;
/// The SRDOs of the image's SRDO table: none. An image with SimpleCAN speaks it instead of
/// SRDOs: with the SRDO table's code beside SimpleCAN's, the images exceeded their flash
/// budget (measured on the images of 2026-12-05: docs/footprint.md, History, "Before:
/// SimpleCAN beside the SRDO table"). The host simulations run both at once
/// (`shared::node::SimpleCanNode`).
#[cfg(feature = "simplecan")]
pub const SRDOS: usize = 0;

/// The safety protocol in the image's channel core: the SRDO table of [`SRDOS`] SRDOs.
#[cfg(not(feature = "simplecan"))]
pub type Protocol<const N: usize> = shared::node::SrdoTable<N>;
/// The safety protocol in the image's channel core (feature `simplecan`): SimpleCAN with
/// [`SIMPLECAN_ENTRIES`] SDD entries, beside an SRDO table of [`SRDOS`] = 0 SRDOs (13FEh,
/// 13FFh:00 = 0), whose stored image and signatures take one row (`R` = 1).
#[cfg(feature = "simplecan")]
pub type Protocol<const N: usize> = shared::node::SrdoAndSimpleCan<N, SIMPLECAN_ENTRIES, 1>;

/// What a board layer needs to know about the device it runs.
#[derive(Clone, Copy)]
pub struct Device {
    /// The device description for a node-ID.
    pub describe: fn(NodeId) -> NodeConfig,
    /// The node-ID the description stands in with while the switches give none and LSS has
    /// not set one (`SAFETY_NODE_ID` at build time, default 1); the hardware layer reads its
    /// switches ([`node_id_from_switches`](safety_device::switches::node_id_from_switches)).
    pub default_id: NodeId,
    /// The channel's pins and the objects they are sampled into or driven by (the device
    /// description's [`INPUT_PINS`](safety_device::INPUT_PINS) and
    /// [`OUTPUT_PINS`](safety_device::OUTPUT_PINS)).
    pub pins: Pins,
}

/// The RAM per SRDO of the image's protocol core, kept in the image so that `cargo xtask
/// bench` reports the figure for the real target, not the host.
#[cfg(target_os = "none")]
#[used]
#[unsafe(no_mangle)]
static SHARED_RAM_PER_SRDO: u32 = shared::node::RAM_PER_SRDO as u32;

impl Device {
    /// The demo device (`safety_device`) named `describe` gives, with the node-ID the
    /// image was built for (`SAFETY_NODE_ID`, default 1) standing in while the switches give
    /// none.
    pub fn built(describe: fn(NodeId) -> NodeConfig) -> Result<Device, u8> {
        let raw = option_env!("SAFETY_NODE_ID")
            .and_then(|text| text.parse::<u8>().ok())
            .unwrap_or(1);
        Ok(Device {
            describe,
            default_id: NodeId::new(raw).map_err(|_| raw)?,
            pins: Pins {
                inputs: &safety_device::INPUT_PINS,
                outputs: &safety_device::OUTPUT_PINS,
            },
        })
    }
}

/// The image's seal: [`dual_channel::selftest::SEALED`] and the CRC-32 of the flash contents,
/// written into the linked image by `cargo xtask build` (zeros until then). Read only through
/// the image's bytes in flash ([`image`]), which the compiler cannot assume.
#[cfg(target_os = "none")]
#[used]
#[unsafe(no_mangle)]
static IMAGE_SEAL: [u32; 2] = [0, 0];

/// Where flash begins (`memory.x`: FLASH ORIGIN), the image's first byte.
#[cfg(target_os = "none")]
const FLASH_ORIGIN: usize = 0x0800_0000;

/// The image in flash: the code and read-only data (from the first byte of flash to
/// `__erodata`) and the load image of the initialised data (`__sidata`, as long as `.data`).
#[cfg(target_os = "none")]
fn image() -> (&'static [u8], &'static [u8]) {
    unsafe extern "C" {
        static __erodata: u32;
        static __sidata: u32;
        static __sdata: u32;
        static __edata: u32;
    }
    // Only the addresses of the linker's symbols are taken, never their contents.
    let erodata = core::ptr::addr_of!(__erodata) as usize;
    let sidata = core::ptr::addr_of!(__sidata) as usize;
    let data_len = core::ptr::addr_of!(__edata) as usize - core::ptr::addr_of!(__sdata) as usize;
    // SAFETY: both ranges are the image as linked (cortex-m-rt's link.x: vector table, code
    // and read-only data from the flash origin to `__erodata`; the load image of `.data` at
    // `__sidata`); flash is mapped, never written while the firmware runs, and read as bytes.
    unsafe {
        (
            core::slice::from_raw_parts(FLASH_ORIGIN as *const u8, erodata - FLASH_ORIGIN),
            core::slice::from_raw_parts(sidata as *const u8, data_len),
        )
    }
}

/// One start-up self-test, as the board layer runs them through
/// [`dual_channel::selftest::start_up`] before the channel starts (and, on the hardware,
/// before the independent watchdog is armed): the RAM test's verdict (March C- over all RAM,
/// run before RAM was initialised: [`ram`]), the image CRC against its seal and the link
/// CRC's known answer. `false` when it failed; the caller stays in the safe state.
#[cfg(target_os = "none")]
#[inline(never)]
pub fn self_test(test: dual_channel::selftest::SelfTest) -> bool {
    use dual_channel::selftest::{self, SelfTest};
    match test {
        SelfTest::Ram => match ram::verdict() {
            Ok(bytes) => {
                defmt::info!(
                    "self-test: RAM (March C-, {=usize} bytes, before start-up) passed",
                    bytes
                );
                true
            }
            Err(fault) => {
                defmt::error!("self-test: RAM failed {}", fault);
                false
            }
        },
        SelfTest::ImageCrc => {
            let seal = core::ptr::addr_of!(IMAGE_SEAL) as usize - FLASH_ORIGIN;
            let (code, data) = image();
            match selftest::check_image(code, data, seal) {
                Ok(()) => {
                    defmt::info!(
                        "self-test: image CRC passed ({=usize} bytes)",
                        code.len() + data.len()
                    );
                    true
                }
                Err(fault) => {
                    defmt::error!("self-test: image CRC failed {}", fault);
                    false
                }
            }
        }
        SelfTest::CrcKnownAnswer => {
            let passed = selftest::crc_known_answer();
            if passed {
                defmt::info!("self-test: CRC known answer passed");
            } else {
                defmt::error!("self-test: CRC known answer failed");
            }
            passed
        }
    }
}
