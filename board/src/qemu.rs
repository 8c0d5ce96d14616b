//! The QEMU board layer: the same channel runtime on QEMU's `netduinoplus2` (STM32F405 model).
//!
//! QEMU models the Cortex-M4 core with SysTick, USART2/USART3 and semihosting, but not the
//! clock tree's ready flags, bxCAN, GPIO or timer compare interrupts, so `embassy_stm32::init`
//! cannot run here. This layer therefore brings its own:
//!
//! - an embassy-time driver on SysTick (1 kHz interrupt; `now` to the microsecond from the
//!   counter; alarms are checked every tick, so a wake-up is at most 1 ms late, which is the
//!   emulator's timing resolution, not the core's: the core judges every timer against `now`);
//! - interrupt-driven, register-level USART2 (CAN frames over serial to the host-side bus hub,
//!   [`dual_channel::can_serial`]) and USART3 (the link to the other channel);
//! - semihosting for the run's arguments (`selftest` to stop after the start-up self-tests) and
//!   the exit code; a panic or HardFault exits QEMU with failure, never hangs;
//! - parameters in RAM ([`RamFlash`]).
//!
//! The inputs and outputs are not modelled by QEMU; the input reads as released (1) and the
//! output value is logged.

use core::cell::{Cell, RefCell};
use core::task::Waker;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{NVIC, SCB, SYST};
use cortex_m_rt::exception;
use critical_section::Mutex;
use dual_channel::can_serial;
use dual_channel::runtime::{ChannelEvent, Io, Role, Runtime};
use embassy_executor::Spawner;
use embassy_futures::select::{Either3, select3};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::pipe::Pipe;
use embassy_time::Timer;
use embassy_time_queue_utils::Queue;
use shared::canopen::storage::RamFlash;
use shared::{CanFrame, Duration, Instant};
use stm32_metapac::{Interrupt, RCC, USART2, USART3, interrupt};

use crate::Device;

/// The core clock QEMU's netduinoplus2 runs SysTick from.
const CPU_HZ: u32 = 168_000_000;
/// SysTick interrupts per second.
const TICK_HZ: u32 = 1_000;
/// SysTick reload value for one tick.
const RELOAD: u32 = CPU_HZ / TICK_HZ - 1;
/// Link heartbeat period under emulation: 50 ms, because four QEMU instances sharing a small
/// host see scheduling gaps of tens of milliseconds. It still gives at least four heartbeats
/// per SCT when the emulated network's consumers use an SCT of 200 ms or more (`cargo xtask
/// emulate` configures 500 ms); the hardware layer uses 10 ms.
const LINK_PERIOD: Duration = Duration::from_millis(50);

/// Bytes received on USART2 (CAN bridge) and USART3 (link), filled by their interrupts.
static CAN_RX: Pipe<CriticalSectionRawMutex, 4096> = Pipe::new();
static LINK_RX: Pipe<CriticalSectionRawMutex, 256> = Pipe::new();
/// Set when the CAN receive pipe overflowed (reported by the main loop).
static CAN_RX_LOST: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);

/// The SysTick time driver.
struct SysTickDriver {
    /// Whole ticks since start.
    ticks: Mutex<Cell<u64>>,
    queue: Mutex<RefCell<Queue>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: SysTickDriver = SysTickDriver {
    ticks: Mutex::new(Cell::new(0)),
    queue: Mutex::new(RefCell::new(Queue::new())),
});

impl SysTickDriver {
    /// Microseconds since start. Inside a critical section the SysTick interrupt cannot run,
    /// so a counter that wrapped since the last tick shows as a pending SysTick: counted here
    /// so that time never goes backwards.
    fn micros(&self, cs: critical_section::CriticalSection<'_>) -> u64 {
        let mut ticks = self.ticks.borrow(cs).get();
        let mut current = SYST::get_current();
        if SCB::is_pendst_pending() {
            ticks += 1;
            current = SYST::get_current();
        }
        let elapsed_cycles = u64::from(RELOAD - current.min(RELOAD));
        ticks * u64::from(1_000_000 / TICK_HZ) + elapsed_cycles * 1_000_000 / u64::from(CPU_HZ)
    }
}

impl embassy_time_driver::Driver for SysTickDriver {
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
        let ticks = DRIVER.ticks.borrow(cs);
        ticks.set(ticks.get() + 1);
        let now = DRIVER.micros(cs);
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

struct QemuIo;

impl Io for QemuIo {
    fn transmit(&mut self, frame: CanFrame) {
        usart_write(USART2, &can_serial::encode(&frame));
    }
    fn link(&mut self, bytes: &[u8]) {
        usart_write(USART3, bytes);
    }
    fn output(&mut self, srdo: u8, data: u64) {
        defmt::info!("output of SRDO {=u8} = {=u64}", srdo, data);
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

    let Ok(mut runtime) = Runtime::new(
        (device.describe)(id),
        RamFlash::<4096>::new(),
        role,
        now(),
        LINK_PERIOD,
    ) else {
        defmt::error!("device description refused");
        exit(false);
    };
    let mut io = QemuIo;
    // QEMU models no GPIO: the input reads as released.
    if runtime
        .set_input(
            now(),
            input_objects.plain,
            input_objects.inverted,
            &[1],
            &mut io,
        )
        .is_err()
    {
        exit(false);
    }
    let mut can = can_serial::Decoder::new();
    let mut can_buf = [0u8; 64];
    let mut link_buf = [0u8; 64];
    loop {
        let deadline = runtime.poll(now(), &mut io);
        let wake = embassy_time::Instant::from_micros(deadline.as_micros());
        match select3(
            CAN_RX.read(&mut can_buf),
            LINK_RX.read(&mut link_buf),
            Timer::at(wake),
        )
        .await
        {
            Either3::First(n) => {
                if CAN_RX_LOST.swap(false, core::sync::atomic::Ordering::Relaxed) {
                    defmt::warn!("CAN receive pipe overflowed: bytes lost");
                }
                for &byte in &can_buf[..n] {
                    match can.push(byte) {
                        Some(Ok(frame)) => {
                            defmt::debug!(
                                "CAN rx {=u16:X} {=[u8]:X}",
                                frame.id().raw(),
                                frame.data()
                            );
                            runtime.on_frame(now(), &frame, &mut io);
                        }
                        Some(Err(error)) => defmt::warn!("CAN bridge: {}", error),
                        None => {}
                    }
                }
            }
            Either3::Second(n) => {
                let at = now();
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
