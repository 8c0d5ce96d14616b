//! The QEMU board layer: the same channel runtime on QEMU's `netduinoplus2` (STM32F405 model).
//!
//! QEMU models the Cortex-M4 core with SysTick, USART2/USART3 and semihosting, but not the
//! clock tree's ready flags, bxCAN, GPIO or timer compare interrupts, so `embassy_stm32::init`
//! cannot run here. This layer therefore brings its own:
//!
//! - an embassy-time driver whose clock is the host's (semihosting `SYS_ELAPSED`, to the
//!   microsecond) and whose alarms are checked on every SysTick interrupt (1 kHz), so a
//!   wake-up is at most 1 ms late, which is the emulator's timing resolution, not the core's:
//!   the core judges every timer against `now`. The host clock, not a count of ticks, because
//!   an emulated MCU that the host does not schedule for a while loses ticks; with the host
//!   clock every instance and the hub share one time base, and such a stall is seen for what
//!   it is (a late message), measured ([`Status::longest_stall_ms`](emulation_wire::Status::longest_stall_ms)) and reported;
//! - interrupt-driven, register-level USART2 (CAN frames over serial to the host-side bus hub,
//!   [`emulation_wire`], which also carries the input pin's value from the hub and
//!   the channel's [`Status`] to it) and USART3 (the link to the other channel);
//! - semihosting for the run's arguments (`selftest` to stop after the start-up self-tests) and
//!   the exit code; a panic or HardFault exits QEMU with failure, never hangs;
//! - parameters in RAM ([`RamFlash`]).
//!
//! QEMU models no GPIO: the input pin's value comes from the hub ([`Wire::Input`]; released,
//! 1, until the hub says otherwise) and the output pin's value goes to it in the status.

use crate::diagnostics::{Diagnostics, Observed};
use core::cell::{Cell, RefCell};
use core::sync::atomic::{AtomicU32, Ordering};
use core::task::Waker;
use cortex_m::peripheral::NVIC;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::exception;
use critical_section::Mutex;
use dual_channel::runtime::{ChannelEvent, Io, Role, Runtime};
use embassy_executor::Spawner;
use embassy_futures::select::{Either3, select3};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::pipe::Pipe;
use embassy_time::Timer;
use embassy_time_queue_utils::Queue;
use emulation_wire::{self as can_serial, Wire};
use shared::canopen::storage::{Flash as _, RamFlash, Slot};
use shared::safety::types::SrdoNumber;
use shared::{CanFrame, Duration, Instant};
use static_cell::ConstStaticCell;
use stm32_metapac::{Interrupt, RCC, USART2, USART3, interrupt};

use crate::Device;

/// The core clock QEMU's netduinoplus2 runs SysTick from.
const CPU_HZ: u32 = 168_000_000;
/// SysTick interrupts per second.
const TICK_HZ: u32 = 1_000;
/// SysTick reload value for one tick.
const RELOAD: u32 = CPU_HZ / TICK_HZ - 1;
/// Link heartbeat period under emulation: 100 ms (a time-out after 200 ms). With 50 ms, link
/// time-outs (a gap over 100 ms) were seen during configuration in some runs of `cargo xtask
/// e2e`, although no emulated MCU stalled or stayed busy that long (measured: stalls up to
/// 30 ms, loop wake-ups up to 18 ms): the delay lies outside the channel's loop, presumably
/// on the emulated serial path, and is not yet understood. 100 ms still gives five heartbeats per SCT of the
/// emulated network's consumer (500 ms); the hardware layer uses 10 ms.
const LINK_PERIOD: Duration = Duration::from_millis(100);

/// Bytes received on USART2 (CAN bridge) and USART3 (link), filled by their interrupts.
static CAN_RX: Pipe<CriticalSectionRawMutex, 4096> = Pipe::new();
static LINK_RX: Pipe<CriticalSectionRawMutex, 256> = Pipe::new();
/// Set when the CAN receive pipe overflowed (reported by the main loop).
static CAN_RX_LOST: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);

/// The longest gap between two SysTick interrupts beyond one tick, in real milliseconds.
static LONGEST_STALL_MS: AtomicU32 = AtomicU32::new(0);

/// The time driver: the host's clock, alarms checked on SysTick.
struct HostClockDriver {
    /// The last time handed out (the clock never goes backwards) and the host clock at the
    /// last SysTick interrupt.
    last: Mutex<Cell<u64>>,
    last_tick: Mutex<Cell<u64>>,
    queue: Mutex<RefCell<Queue>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: HostClockDriver = HostClockDriver {
    last: Mutex::new(Cell::new(0)),
    last_tick: Mutex::new(Cell::new(0)),
    queue: Mutex::new(RefCell::new(Queue::new())),
});

/// The semihosting block `SYS_ELAPSED` fills: the 64-bit tick count, low word first.
#[repr(C)]
struct Elapsed {
    low: u32,
    high: u32,
}

/// Host ticks per second (`SYS_TICKFREQ`); QEMU counts nanoseconds.
static HOST_TICK_HZ: AtomicU32 = AtomicU32::new(0);

/// Host ticks since QEMU started (`SYS_ELAPSED`), or `None` where semihosting has no clock.
fn host_ticks() -> Option<u64> {
    let mut block = Elapsed { low: 0, high: 0 };
    // SAFETY: SYS_ELAPSED (30h) writes two words into the block, which lives on this stack
    // frame for the call.
    let result =
        unsafe { cortex_m_semihosting::syscall1(0x30, &mut block as *mut Elapsed as usize) };
    (result == 0).then_some(u64::from(block.high) << 32 | u64::from(block.low))
}

impl HostClockDriver {
    /// Microseconds since start, never less than the last value handed out.
    fn micros(&self, cs: critical_section::CriticalSection<'_>) -> u64 {
        let hz = u64::from(HOST_TICK_HZ.load(Ordering::Relaxed)).max(1);
        let host = host_ticks().map_or(0, |ticks| {
            (u128::from(ticks) * 1_000_000 / u128::from(hz)) as u64
        });
        let last = self.last.borrow(cs);
        let now = host.max(last.get());
        last.set(now);
        now
    }
}

impl embassy_time_driver::Driver for HostClockDriver {
    fn now(&self) -> u64 {
        critical_section::with(|cs| self.micros(cs))
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        critical_section::with(|cs| {
            let now = self.micros(cs);
            let mut queue = self.queue.borrow(cs).borrow_mut();
            queue.schedule_wake(at, waker);
            // Wakes what is due already; the rest waits for the next tick.
            queue.next_expiration(now);
        });
    }
}

#[exception]
fn SysTick() {
    critical_section::with(|cs| {
        let now = DRIVER.micros(cs);
        let last_tick = DRIVER.last_tick.borrow(cs);
        let gap_ms = now.saturating_sub(last_tick.get()) / 1000;
        if last_tick.get() != 0 && gap_ms > 1 {
            let stall = u32::try_from(gap_ms - 1).unwrap_or(u32::MAX);
            LONGEST_STALL_MS.fetch_max(stall, Ordering::Relaxed);
        }
        last_tick.set(now);
        DRIVER.queue.borrow(cs).borrow_mut().next_expiration(now);
    });
}

/// A fault the core cannot recover from ends the emulated run with failure.
#[exception]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::bkpt();
    }
}

#[interrupt]
fn USART2() {
    while USART2.sr().read().rxne() {
        let byte = USART2.dr().read().dr() as u8;
        // A full pipe loses the byte: the frame fails its CRC and the core's timers act.
        if CAN_RX.try_write(&[byte]).is_err() {
            CAN_RX_LOST.store(true, core::sync::atomic::Ordering::Relaxed);
        }
    }
}

#[interrupt]
fn USART3() {
    while USART3.sr().read().rxne() {
        let byte = USART3.dr().read().dr() as u8;
        // A lost byte is a link fault at the other end of the framing: safe state.
        let _ = LINK_RX.try_write(&[byte]);
    }
}

/// Enables a USART on APB1 with its receive interrupt (QEMU ignores the baud rate).
fn usart_init(usart: stm32_metapac::usart::Usart, irq: Interrupt) {
    usart.brr().write(|w| w.set_brr(0x16D));
    usart.cr1().write(|w| {
        w.set_ue(true);
        w.set_te(true);
        w.set_re(true);
        w.set_rxneie(true);
    });
    // SAFETY: the handlers for these interrupts are defined above and only touch their own
    // USART and a critical-section-protected pipe; enabling them cannot break a critical
    // section (none is active here, during start-up).
    unsafe { NVIC::unmask(irq) };
}

/// Writes bytes, waiting for the transmit register (instant under QEMU).
fn usart_write(usart: stm32_metapac::usart::Usart, bytes: &[u8]) {
    for &byte in bytes {
        while !usart.sr().read().txe() {}
        usart.dr().write(|w| w.set_dr(u16::from(byte)));
    }
}

fn send(message: &Wire) {
    usart_write(USART2, &can_serial::encode_wire(message));
}

struct QemuIo;

impl Io for QemuIo {
    fn transmit(&mut self, frame: CanFrame) {
        usart_write(USART2, &can_serial::encode(&frame));
    }
    fn link(&mut self, bytes: &[u8]) {
        usart_write(USART3, bytes);
    }
    fn output(&mut self, srdo: SrdoNumber, data: u64) {
        defmt::info!("output of SRDO {=u8} = {=u64}", srdo.get(), data);
    }
    fn event(&mut self, event: ChannelEvent) {
        defmt::info!("{}", event);
    }
}

fn now() -> Instant {
    Instant::from_micros(embassy_time::Instant::now().as_micros())
}

/// The semihosting command line (QEMU's `-semihosting-config arg=...`).
fn arguments() -> crate::Arguments {
    let mut buf = [0u8; 96];
    #[repr(C)]
    struct Block {
        buf: *mut u8,
        len: usize,
    }
    let mut block = Block {
        buf: buf.as_mut_ptr(),
        len: buf.len(),
    };
    // SAFETY: SYS_GET_CMDLINE (0x15) writes at most `len` bytes into `buf` and the length
    // back into the block, both of which live on this stack frame for the call.
    let result = unsafe {
        cortex_m_semihosting::syscall1(
            cortex_m_semihosting::nr::GET_CMDLINE,
            &mut block as *mut Block as usize,
        )
    };
    if result != 0 {
        return crate::Arguments::default();
    }
    crate::parse_arguments(&buf[..block.len.min(buf.len())])
}

/// Starts the board (SysTick, USARTs), runs the self-tests and then the channel.
pub async fn run<R: Role<N>, const N: usize>(_spawner: Spawner, device: Device, role: R) -> ! {
    let Some(mut core) = cortex_m::Peripherals::take() else {
        exit(false);
    };
    // SAFETY: SYS_TICKFREQ (31h) takes no argument block.
    let hz = unsafe { cortex_m_semihosting::syscall1(0x31, 0) };
    match u32::try_from(hz) {
        Ok(hz) if hz > 0 && hz != u32::MAX && host_ticks().is_some() => {
            HOST_TICK_HZ.store(hz, Ordering::Relaxed);
        }
        _ => {
            defmt::error!("semihosting gives no host clock (SYS_ELAPSED, SYS_TICKFREQ)");
            exit(false);
        }
    }
    core.SYST.set_clock_source(SystClkSource::Core);
    core.SYST.set_reload(RELOAD);
    core.SYST.clear_current();
    core.SYST.enable_interrupt();
    core.SYST.enable_counter();
    RCC.apb1enr().modify(|w| {
        w.set_usart2en(true);
        w.set_usart3en(true);
    });
    usart_init(USART2, Interrupt::USART2);
    usart_init(USART3, Interrupt::USART3);

    let arguments = arguments();
    if arguments.unknown {
        defmt::error!("semihosting arguments not understood (use `selftest`, `node=N`)");
        exit(false);
    }
    let passed = crate::self_tests();
    // QEMU has no bxCAN: the controller's loop-back test (`dual_channel::can_loopback`) runs
    // in the hardware layer only; its plan and verdict are host-tested.
    defmt::info!("self-test: CAN loop-back not run (QEMU models no bxCAN)");
    defmt::info!("self-test verdict: {=bool}", passed);
    if !passed || arguments.selftest {
        exit(passed);
    }
    if arguments.crash {
        panic!("deliberate crash (argument `crash`)");
    }
    let id = arguments.node.unwrap_or(device.default_id);
    defmt::info!("node-ID {=u8}", id.raw());
    let input_objects = device.inputs;

    // The parameter store lives in a zero-initialised static, erased here: 8 KiB that the
    // runtime's construction would otherwise move through the stack (measured: the main
    // task's frame held several copies).
    static PARAMETERS: ConstStaticCell<RamFlash<4096>> = ConstStaticCell::new(RamFlash::zeroed());
    let Some(parameters) = PARAMETERS.try_take() else {
        defmt::error!("the parameter store is taken already");
        exit(false);
    };
    for slot in [Slot::A, Slot::B] {
        if parameters.erase(slot).is_err() {
            defmt::error!("the parameter store cannot be erased");
            exit(false);
        }
    }
    let Ok(mut runtime) = Runtime::new((device.describe)(id), parameters, role, now(), LINK_PERIOD)
    else {
        defmt::error!("device description refused");
        exit(false);
    };
    let mut board = QemuIo;
    let mut diagnostics = Diagnostics::new();
    // QEMU models no GPIO: the input reads as released until the hub sets it.
    let mut input = 1u8;
    let mut io = Observed {
        io: &mut board,
        diagnostics: &mut diagnostics,
    };
    if runtime
        .set_input(
            now(),
            input_objects.plain,
            input_objects.inverted,
            &[input],
            &mut io,
        )
        .is_err()
    {
        exit(false);
    }
    io.diagnostics.input(input);
    let mut can = can_serial::Decoder::new();
    let mut can_buf = [0u8; 64];
    let mut link_buf = [0u8; 64];
    let mut woke = now();
    loop {
        let at = now();
        let deadline = runtime.poll(at, &mut io);
        let stall = LONGEST_STALL_MS.load(Ordering::Relaxed);
        io.diagnostics
            .stalled(u16::try_from(stall).unwrap_or(u16::MAX));
        io.diagnostics.stack(crate::stack::used());
        if let Some(status) = io.diagnostics.report(at, &runtime) {
            send(&Wire::Status(status));
        }
        let deadline = deadline.min(io.diagnostics.deadline());
        let wake = embassy_time::Instant::from_micros(deadline.as_micros());
        io.diagnostics.busy(woke, now());
        let event = select3(
            CAN_RX.read(&mut can_buf),
            LINK_RX.read(&mut link_buf),
            Timer::at(wake),
        )
        .await;
        woke = now();
        match event {
            Either3::First(n) => {
                if CAN_RX_LOST.swap(false, core::sync::atomic::Ordering::Relaxed) {
                    defmt::warn!("CAN receive pipe overflowed: bytes lost");
                }
                for &byte in &can_buf[..n] {
                    match can.push(byte) {
                        Some(Ok(Wire::Can(frame))) => {
                            defmt::debug!(
                                "CAN rx {=u16:X} {=[u8]:X}",
                                frame.id().raw(),
                                frame.data()
                            );
                            runtime.on_frame(now(), &frame, &mut io);
                        }
                        Some(Ok(Wire::Input(value))) => {
                            if value != input {
                                defmt::info!("input pin {=u8}", value);
                                input = value;
                            }
                            io.diagnostics.input(value);
                            if runtime
                                .set_input(
                                    now(),
                                    input_objects.plain,
                                    input_objects.inverted,
                                    &[value],
                                    &mut io,
                                )
                                .is_err()
                            {
                                // The device description has no such input object: a build
                                // error, not a run-time condition.
                                exit(false);
                            }
                        }
                        Some(Ok(Wire::Status(_))) => {
                            defmt::warn!("CAN bridge: status from the hub")
                        }
                        Some(Err(error)) => defmt::warn!("CAN bridge: {}", error),
                        None => {}
                    }
                }
            }
            Either3::Second(n) => {
                let at = now();
                io.diagnostics.link_received(at);
                for &byte in &link_buf[..n] {
                    runtime.on_link_byte(at, byte, &mut io);
                }
            }
            Either3::Third(()) => {}
        }
    }
}

/// Ends the emulated run with success or failure.
pub fn exit(success: bool) -> ! {
    use cortex_m_semihosting::debug;
    debug::exit(if success {
        debug::EXIT_SUCCESS
    } else {
        debug::EXIT_FAILURE
    });
    loop {
        cortex_m::asm::wfi();
    }
}
