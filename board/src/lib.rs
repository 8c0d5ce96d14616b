//! Board layers of the firmware images: everything that touches hardware, and nothing else.
//!
//! - `hw` (feature `hw`): embassy-stm32 on the STM32F405RG: bxCAN, the link USART, the
//!   safety input and output pins and the independent watchdog.
//! - `qemu` (feature `qemu`): QEMU's `netduinoplus2`: a SysTick time driver, register-level
//!   USARTs (CAN frames over serial, and the link), semihosting.
//!
//! Both are adapters of the one channel loop
//! ([`ChannelLoop`](dual_channel::channel_loop::ChannelLoop)) around a channel
//! [`Runtime`](dual_channel::runtime::Runtime): each implements its
//! [`Driver`](dual_channel::channel_loop::Driver) and waits in its own way; the loop and the
//! logic it drives are host-tested in `dual-channel`, `channel-a`, `channel-b` and `tests`. On the host this crate holds
//! the types both layers share and what the hardware layer needs that is not hardware:
//! [`parameter_flash`] (the parameter slots on word-programmed flash), [`diagnostics`] (the
//! status a channel reports on the emulated board's line), [`stack`]'s search for the stack's
//! high-water mark, [`frame_trail`]'s walk of the frame records a panic is logged by, the
//! node-ID switches' decoding and
//! the emulated run's arguments, all host-tested.
#![no_std]

use dual_channel::channel_loop::Pins;
use shared::canopen::NodeId;
use shared::node::NodeConfig;
use shared::{CanFrame, CanId};

pub mod bxcan_adapter;
pub mod diagnostics;
pub mod frame_trail;
#[cfg(all(target_os = "none", feature = "hw"))]
pub mod hw;
#[cfg(target_os = "none")]
mod panic;
pub mod parameter_flash;
#[cfg(all(target_os = "none", feature = "qemu"))]
pub mod qemu;
#[cfg(target_os = "none")]
pub mod ram;
pub mod reset_cause;
pub mod stack;
pub mod transmit_queue;

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
/// SRDOs: with the SRDO table's code beside SimpleCAN's, the images are 11 to 15 KiB over
/// their flash budget (docs/footprint.md). The host simulations run both at once
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
    /// The node-ID when the emulated run is given none (`SAFETY_NODE_ID` at build time, default
    /// 1); the hardware layer reads its switches instead ([`node_id_from_switches`]).
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
    /// image was built for (`SAFETY_NODE_ID`, default 1) for an emulated run without one.
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

/// A received standard frame as the CAN controller reports it (identifier, remote flag,
/// length code, the eight data registers), or `None` when it is not CANopen's: a length code
/// over 8 (ISO 11898-1 allows 9 to 15 for 8 bytes; CANopen frames never carry them) is
/// dropped like an extended frame, and the consumers' timers catch a frame lost so.
pub fn received_frame(id: u16, remote: bool, dlc: u8, data: &[u8; 8]) -> Option<CanFrame> {
    let id = CanId::new(id).ok()?;
    if remote {
        CanFrame::remote(id, dlc).ok()
    } else {
        CanFrame::new(id, data.get(..usize::from(dlc))?).ok()
    }
}

/// The virtual time (microseconds) a paced emulated channel's clock shows at host time
/// `host`: the last grant `granted`, handled at host time `host_at_grant`, plus the host time
/// since, but at most `lookahead` past the grant, and never less than `last`, the time
/// handed out before (the clock never goes backwards; the hub's grants only grow, and one
/// older than `last` holds the clock there). So the clock is never more than `lookahead`
/// past the newest grant handled, or past what it showed already: the bound the argument in
/// `docs/emulation.md` rests on. Saturating, it cannot overflow.
pub fn paced_clock(last: u64, granted: u64, host_at_grant: u64, host: u64, lookahead: u64) -> u64 {
    let since = host.saturating_sub(host_at_grant).min(lookahead);
    last.max(granted.saturating_add(since))
}

/// Host ticks (semihosting `SYS_ELAPSED`, `hz` of them a second: `SYS_TICKFREQ`) as whole
/// microseconds, rounded down, saturating. The QEMU layer's clock reads it on every call of
/// `now()`, many times a loop round: at a whole number of ticks per microsecond (QEMU counts
/// nanoseconds) one 64-bit division; otherwise the exact 128-bit product and quotient, whose
/// software division cost the emulated core most of the longest loop round traced (41,082
/// of 73,580 instructions, `cargo xtask bench --target-cost`, 2026-12-03).
pub fn micros_from_host_ticks(ticks: u64, hz: u32) -> u64 {
    let hz = hz.max(1);
    if hz % 1_000_000 == 0 {
        ticks / u64::from(hz / 1_000_000)
    } else {
        u64::try_from(u128::from(ticks) * 1_000_000 / u128::from(hz)).unwrap_or(u64::MAX)
    }
}

/// Why the node-ID switches were not accepted: the node stays in the safe state, silent on
/// the bus, and says why in its log.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum SwitchFault {
    /// Two readings 1 ms apart differ (a switch between positions, or a broken contact).
    Unsettled {
        /// The first reading.
        first: u8,
        /// The second reading.
        second: u8,
    },
    /// The reading is not a node-ID (CiA 301 7.5.2: 1 to 127): all switches open.
    Invalid(u8),
}

/// The node-ID on the board's seven switches (bit 0 first, closed = 1), from two readings
/// taken 1 ms apart at start-up; a change later takes effect at the next reset, as CiA 301
/// has it for node-IDs. Readings that differ, or 0, are refused. Both channels read the
/// switches; when they read different IDs, channel B does not follow the tool's requests for
/// channel A's node, keeps its unvalidated defaults and stays out of Operational, and the
/// link's NMT cross-check puts both channels in the safe state (host test
/// `channels_with_different_node_ids_never_leave_the_safe_state`).
pub fn node_id_from_switches(first: u8, second: u8) -> Result<NodeId, SwitchFault> {
    if first != second {
        return Err(SwitchFault::Unsettled { first, second });
    }
    NodeId::new(first).map_err(|_| SwitchFault::Invalid(first))
}

/// The arguments of an emulated run (QEMU semihosting command line, words separated by
/// spaces): `selftest` stops after the start-up self-tests; `node=N` sets the node-ID;
/// `paced` puts the clock on the hub's virtual time.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Arguments {
    /// Stop after the self-tests.
    pub selftest: bool,
    /// The node-ID, when given (1..=127).
    pub node: Option<NodeId>,
    /// Panic right after the self-tests (`crash`), to check that a panic ends the emulated
    /// run with failure instead of hanging.
    pub crash: bool,
    /// The clock follows the emulated network's virtual time, granted by the hub (`paced`,
    /// given by `cargo xtask run` and `e2e`); otherwise it is the host's.
    pub paced: bool,
    /// A word that was not understood (the run refuses to start).
    pub unknown: bool,
}

/// Parses an emulated run's command line. Without any `arg=`, QEMU's command line is the
/// image's path: a first word with a `/` in it is that, not an argument.
pub fn parse_arguments(line: &[u8]) -> Arguments {
    let mut arguments = Arguments::default();
    for (index, word) in line
        .split(|&b| b == b' ' || b == 0)
        .filter(|w| !w.is_empty())
        .enumerate()
    {
        if index == 0 && word.contains(&b'/') {
            continue;
        }
        if word == b"selftest" {
            arguments.selftest = true;
        } else if word == b"crash" {
            arguments.crash = true;
        } else if word == b"paced" {
            arguments.paced = true;
        } else if let Some(value) = word.strip_prefix(b"node=") {
            let id = core::str::from_utf8(value)
                .ok()
                .and_then(|text| text.parse::<u8>().ok())
                .and_then(|raw| NodeId::new(raw).ok());
            match id {
                Some(id) => arguments.node = Some(id),
                None => arguments.unknown = true,
            }
        } else {
            arguments.unknown = true;
        }
    }
    arguments
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The exact quotient floor(ticks × 10⁶ / hz), computed without overflow.
    fn exact(ticks: u64, hz: u32) -> u64 {
        u64::try_from(u128::from(ticks) * 1_000_000 / u128::from(hz.max(1))).unwrap_or(u64::MAX)
    }

    /// Host ticks become the exact microseconds, rounded down, by either path: whole ticks per
    /// microsecond (QEMU's nanoseconds, 1 MHz, 24 MHz) and the rest (32,768 Hz, 1 Hz, a tick
    /// frequency of 0 taken as 1), at the edges (0, one below a whole microsecond, u64::MAX)
    /// and at values spread over the range.
    #[test]
    fn host_ticks_become_exact_microseconds_rounded_down() {
        let frequencies = [1_000_000_000, 1_000_000, 24_000_000, 32_768, 1, 0, u32::MAX];
        let edges = [0, 1, 999, 1_000, 1_001, 999_999, u64::MAX, u64::MAX - 1];
        // A multiplicative walk over the range (no generator needed).
        let walk = (0..500u64).scan(1u64, |value, _| {
            *value = value
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            Some([*value, *value >> 20])
        });
        let ticks: heapless::Vec<u64, 1100> = edges.into_iter().chain(walk.flatten()).collect();
        for hz in frequencies {
            for &t in &ticks {
                assert_eq!(
                    micros_from_host_ticks(t, hz),
                    exact(t, hz),
                    "{t} ticks at {hz} Hz"
                );
            }
        }
        assert_eq!(micros_from_host_ticks(1_999, 1_000_000_000), 1);
        assert_eq!(micros_from_host_ticks(2_000, 1_000_000_000), 2);
    }

    /// CiA 301 7.2.2 / ISO 11898-1: every length code a controller can report, for data and
    /// remote frames; none panics, and only 0 to 8 make a frame.
    #[test]
    fn every_received_length_code_is_handled() {
        let data = [1, 2, 3, 4, 5, 6, 7, 8];
        for dlc in 0..=15u8 {
            let frame = received_frame(0x181, false, dlc, &data);
            let remote = received_frame(0x181, true, dlc, &data);
            if dlc <= 8 {
                assert_eq!(frame.unwrap().data(), &data[..usize::from(dlc)]);
                assert!(remote.is_some_and(|r| r.is_remote() && r.dlc() == dlc));
            } else {
                assert!(frame.is_none() && remote.is_none(), "length {dlc}");
            }
        }
        assert!(received_frame(0x800, false, 1, &data).is_none());
    }

    /// The paced clock runs with the host from a grant, stands still at the lookahead past it
    /// until the next grant, never goes backwards, and does not overflow.
    #[test]
    fn a_paced_clock_never_runs_more_than_the_lookahead_past_its_grant() {
        let lookahead = 10_000;
        // Granted 1 s at host 5 s: host time runs on up to the lookahead, then stops.
        assert_eq!(
            paced_clock(0, 1_000_000, 5_000_000, 5_000_000, lookahead),
            1_000_000
        );
        assert_eq!(
            paced_clock(0, 1_000_000, 5_000_000, 5_004_000, lookahead),
            1_004_000
        );
        assert_eq!(
            paced_clock(0, 1_000_000, 5_000_000, 5_900_000, lookahead),
            1_010_000
        );
        // A grant older than what was handed out holds the clock: never backwards.
        assert_eq!(
            paced_clock(1_010_000, 1_002_000, 6_000_000, 6_001_000, lookahead),
            1_010_000
        );
        assert_eq!(
            paced_clock(1_010_000, 1_002_000, 6_000_000, 6_009_000, lookahead),
            1_011_000
        );
        // A host clock read before the grant was handled adds nothing.
        assert_eq!(paced_clock(0, 7, 100, 50, lookahead), 7);
        assert_eq!(paced_clock(0, u64::MAX, 0, u64::MAX, lookahead), u64::MAX);
        for host in (0..100_000_000).step_by(777_777) {
            let shown = paced_clock(0, 42, 0, host, lookahead);
            assert!(shown <= 42 + lookahead, "{shown} at host {host}");
        }
    }

    #[test]
    fn cia301_7_5_2_node_id_from_switches() {
        assert_eq!(node_id_from_switches(33, 33).map(NodeId::raw), Ok(33));
        assert_eq!(node_id_from_switches(127, 127).map(NodeId::raw), Ok(127));
        assert_eq!(node_id_from_switches(1, 1).map(NodeId::raw), Ok(1));
        assert_eq!(node_id_from_switches(0, 0), Err(SwitchFault::Invalid(0)));
        assert_eq!(
            node_id_from_switches(128, 128),
            Err(SwitchFault::Invalid(128))
        );
        assert_eq!(
            node_id_from_switches(33, 32),
            Err(SwitchFault::Unsettled {
                first: 33,
                second: 32
            })
        );
    }

    #[test]
    fn emulated_run_arguments() {
        assert_eq!(parse_arguments(b""), Arguments::default());
        let both = parse_arguments(b"node=33 selftest");
        assert!(both.selftest && !both.unknown);
        assert_eq!(both.node.map(NodeId::raw), Some(33));
        assert!(parse_arguments(b"node=0").unknown);
        assert!(parse_arguments(b"node=128").unknown);
        assert!(parse_arguments(b"node=x").unknown);
        assert!(parse_arguments(b"verbose").unknown);
        assert!(parse_arguments(b"crash").crash);
        let paced = parse_arguments(b"node=33 paced");
        assert!(paced.paced && !paced.unknown);
        assert!(!parse_arguments(b"node=33").paced);
        let path = parse_arguments(b"target/qemu/channel-a node=2");
        assert_eq!((path.unknown, path.node.map(NodeId::raw)), (false, Some(2)));
        assert!(parse_arguments(b"node=2 target/qemu/channel-a").unknown);
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

/// One start-up self-test, as both layers run them through
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
