//! The QEMU board layer: the same channel runtime on QEMU's `netduinoplus2` (STM32F405 model).
//!
//! QEMU models the Cortex-M4 core with SysTick, USART2/USART3 and semihosting, but not the
//! clock tree's ready flags, bxCAN, GPIO or timer compare interrupts, so `embassy_stm32::init`
//! cannot run here. This layer therefore brings its own:
//!
//! - an embassy-time driver on the emulated network's shared virtual time (argument `paced`,
//!   which `cargo xtask run` and `e2e` give): the clock is the last time the hub granted
//!   ([`Wire::Time`]) plus the host time since, but never more than
//!   [`LOOKAHEAD`] past that grant (the SimpleCAN images' is
//!   [`can_serial::SIMPLECAN_LOOKAHEAD`]); each grant is acknowledged once everything the
//!   hub sent before it has been handed to the runtime. So a channel whose serial line lags
//!   or that the host does not schedule sees its time stand still instead of frames arriving
//!   late, and the hub holds the time of the whole network for it (`can_hub::pace`,
//!   `docs/emulation.md`). Unpaced (an image run alone) the clock is the host's (semihosting
//!   `SYS_ELAPSED`). The channel loop waits with WFI (`wait`) and checks its deadline on
//!   every interrupt (SysTick at 1 kHz, USART2), so a wake-up is at most 1 ms late, the
//!   emulator's timing resolution, not the core's: the core judges every timer against
//!   `now`. (embassy-time alarms, which nothing in this layer uses any more, are still
//!   served, on SysTick and on every grant.) How long the host did not run the
//!   MCU (its tick came late, host time) is measured
//!   ([`Status::longest_stall_ms`](emulation_wire::Status::longest_stall_ms)) and
//!   reported;
//! - interrupt-driven, register-level USART2: CAN frames over serial to the host-side bus hub
//!   ([`emulation_wire`]), which also carries the input pin's value from the hub,
//!   the channel's [`Status`] to it, the time grants and the link to the other channel
//!   ([`Wire::Link`], relayed by the hub): one ordered line, so that a frame and a link
//!   message the hub sent in one order arrive in that order (on hardware the link is USART3,
//!   a line of its own with a latency of about 0.2 ms);
//! - semihosting for the run's arguments (`selftest` to stop after the start-up self-tests) and
//!   the exit code; a panic or HardFault exits QEMU with failure, never hangs;
//! - parameters in RAM ([`RamFlash`]).
//!
//! QEMU models no GPIO: the input pin's value comes from the hub ([`Wire::Input`]; released,
//! 1, until the hub says otherwise) and the output pin's value goes to it in the status.

use crate::diagnostics::Diagnostics;
use core::cell::{Cell, RefCell};
use core::sync::atomic::{AtomicU32, Ordering};
use core::task::Waker;
use cortex_m::peripheral::NVIC;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::exception;
use critical_section::Mutex;
use dual_channel::channel_loop::{ChannelLoop, Driver, QueueFull, Received};
use dual_channel::filters::AcceptanceList;
use dual_channel::runtime::{ChannelEvent, Role, Runtime};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::pipe::Pipe;
use embassy_time_queue_utils::Queue;
use emulation_wire::arguments::{Arguments, parse_arguments};
use emulation_wire::clock::{micros_from_host_ticks, paced_clock};
use emulation_wire::{self as can_serial, LinkBytes, Wire};
use shared::canopen::storage::{Flash as _, RamFlash, Slot};
use shared::{CanFrame, Duration, Instant};
use static_cell::ConstStaticCell;
use stm32_metapac::{Interrupt, RCC, USART2, interrupt};

use crate::Device;

/// The lookahead this image's clock runs with past the hub's last grant: the CANopen Safety
/// run's [`can_serial::LOOKAHEAD`], or with the feature `simplecan` the SimpleCAN run's
/// [`can_serial::SIMPLECAN_LOOKAHEAD`] (the hub is given the same by xtask).
pub const LOOKAHEAD: Duration = if cfg!(feature = "simplecan") {
    can_serial::SIMPLECAN_LOOKAHEAD
} else {
    can_serial::LOOKAHEAD
};

/// The grant period the hub runs this image's network with (xtask gives it): the CANopen
/// Safety run's [`can_serial::GRANT_PERIOD`] or the SimpleCAN run's
/// [`can_serial::SIMPLECAN_GRANT_PERIOD`]. The image does not use it itself; channel B's
/// SimpleCAN bounds do (a loop wakes on every grant).
pub const GRANT_PERIOD: Duration = if cfg!(feature = "simplecan") {
    can_serial::SIMPLECAN_GRANT_PERIOD
} else {
    can_serial::GRANT_PERIOD
};

/// The core clock QEMU's netduinoplus2 runs SysTick from.
const CPU_HZ: u32 = 168_000_000;
/// SysTick interrupts per second.
const TICK_HZ: u32 = 1_000;
/// SysTick reload value for one tick.
const RELOAD: u32 = CPU_HZ / TICK_HZ - 1;
/// Link heartbeat period under emulation: 100 ms (a time-out after 200 ms), five heartbeats
/// per SCT of the emulated network's consumer (500 ms); the hardware layer uses 10 ms. (With
/// 50 ms and the host's clock, link time-outs were seen during configuration: QEMU's USART
/// takes one byte per round trip through its main loop, so the bytes queued for a channel
/// were delivered late when the host was busy, `docs/emulation.md`. On the virtual time such
/// a lag holds the clock instead.)
const LINK_PERIOD: Duration = Duration::from_millis(100);

/// Bytes received on USART2 (CAN bridge, link, time grants), filled by its interrupt.
static CAN_RX: Pipe<CriticalSectionRawMutex, 4096> = Pipe::new();
/// Set when the CAN receive pipe overflowed (reported by the main loop).
static CAN_RX_LOST: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);

/// The longest gap between two SysTick interrupts beyond one tick, in host milliseconds.
static LONGEST_STALL_MS: AtomicU32 = AtomicU32::new(0);

/// The time driver: the virtual time the hub grants (or the host's clock, unpaced), alarms
/// checked on SysTick and on every grant.
struct VirtualClockDriver {
    /// The last time handed out (the clock never goes backwards) and the host clock at the
    /// last SysTick interrupt (host microseconds).
    last: Mutex<Cell<u64>>,
    last_tick: Mutex<Cell<u64>>,
    /// `Some((granted, host))`: paced; the last grant and the host clock when it was handled.
    grant: Mutex<Cell<Option<(u64, u64)>>>,
    queue: Mutex<RefCell<Queue>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: VirtualClockDriver = VirtualClockDriver {
    last: Mutex::new(Cell::new(0)),
    last_tick: Mutex::new(Cell::new(0)),
    grant: Mutex::new(Cell::new(None)),
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

/// Host microseconds since QEMU started.
fn host_micros() -> u64 {
    let hz = HOST_TICK_HZ.load(Ordering::Relaxed);
    host_ticks().map_or(0, |ticks| micros_from_host_ticks(ticks, hz))
}

impl VirtualClockDriver {
    /// Microseconds since start, never less than the last value handed out.
    fn micros(&self, cs: critical_section::CriticalSection<'_>) -> u64 {
        self.micros_at(cs, host_micros())
    }

    fn micros_at(&self, cs: critical_section::CriticalSection<'_>, host: u64) -> u64 {
        let last = self.last.borrow(cs);
        let now = match self.grant.borrow(cs).get() {
            Some((granted, at)) => {
                paced_clock(last.get(), granted, at, host, LOOKAHEAD.as_micros())
            }
            None => host.max(last.get()),
        };
        last.set(now);
        now
    }

    /// From now on the clock is paced by the hub's grants: until the first, it shows at
    /// most the lookahead past zero.
    fn pace(&self) {
        critical_section::with(|cs| {
            self.last.borrow(cs).set(0);
            self.grant.borrow(cs).set(Some((0, host_micros())));
        });
    }

    /// The hub granted the virtual time `granted` (microseconds); wakes what is due.
    fn granted(&self, granted: u64) {
        critical_section::with(|cs| {
            if self.grant.borrow(cs).get().is_some() {
                self.grant.borrow(cs).set(Some((granted, host_micros())));
            }
            let now = self.micros(cs);
            self.queue.borrow(cs).borrow_mut().next_expiration(now);
        });
    }
}

impl embassy_time_driver::Driver for VirtualClockDriver {
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
        let host = host_micros();
        let last_tick = DRIVER.last_tick.borrow(cs);
        let gap_ms = host.saturating_sub(last_tick.get()) / 1000;
        if last_tick.get() != 0 && gap_ms > 1 {
            let stall = u32::try_from(gap_ms - 1).unwrap_or(u32::MAX);
            LONGEST_STALL_MS.fetch_max(stall, Ordering::Relaxed);
        }
        last_tick.set(host);
        let now = DRIVER.micros_at(cs, host);
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

/// What the serial line handed over that the loop has not taken yet: the line carries frames,
/// link bytes and the input pin in one order, and the driver hands them on in that order
/// (a link message or an input change stops [`Driver::receive`] until the loop has taken
/// it).
#[derive(Clone, Copy)]
enum Pending {
    /// Link bytes, for [`Driver::link_read`].
    Link(LinkBytes),
    /// The input pin changed: for [`Driver::input`].
    Input,
}

/// The emulated board as the channel loop sees it: CAN frames, link bytes, the input pin and
/// the hub's time grants over USART2 ([`emulation_wire`]).
struct QemuDriver {
    decoder: can_serial::Decoder,
    /// Bytes read from the receive pipe, `bytes[at..len]` not decoded yet.
    bytes: [u8; 64],
    at: usize,
    len: usize,
    pending: Option<Pending>,
    /// The input pin as the hub last set it (released, 1, until it says otherwise).
    input: u8,
    diagnostics: Diagnostics,
    /// SimpleCAN frames handed to the hub, not yet confirmed to the loop. The hub puts a
    /// frame on the emulated bus as it gets it (within the lookahead, docs/emulation.md), so
    /// the board confirms it as sent at once; there is no mailbox to withdraw it from.
    #[cfg(feature = "simplecan")]
    sent: heapless::Deque<CanFrame, 8>,
}

impl QemuDriver {
    /// `true` while bytes wait in the driver or in the receive pipe.
    fn has_bytes(&self) -> bool {
        self.at < self.len || !CAN_RX.is_empty()
    }

    /// The next byte from the line, if one is there.
    fn next_byte(&mut self) -> Option<u8> {
        if self.at >= self.len {
            self.len = CAN_RX.try_read(&mut self.bytes).unwrap_or(0);
            self.at = 0;
        }
        let byte = *self.bytes[..self.len].get(self.at)?;
        self.at += 1;
        Some(byte)
    }

    /// The next message from the line, if a whole one is there.
    fn next_message(&mut self) -> Option<Wire> {
        while let Some(byte) = self.next_byte() {
            match self.decoder.push(byte) {
                Some(Ok(message)) => return Some(message),
                Some(Err(error)) => defmt::warn!("CAN bridge: {}", error),
                None => {}
            }
        }
        None
    }

    /// The hub granted the virtual time `granted`: everything it sent before has been handed
    /// to the loop (the driver hands the line on in order), so the clock may run to it (plus
    /// the lookahead) and the hub may move the network's time on.
    fn grant(granted: u64) {
        DRIVER.granted(granted);
        send(&Wire::Time(granted));
    }

    /// Waits for the hub's first grant of the virtual time and acknowledges it; keeps the
    /// last input pin value the hub set meanwhile. Frames and link bytes before it are not
    /// for this channel yet: it has not powered on (on hardware, a controller that is not
    /// on the bus yet does not receive them either).
    fn first_grant(&mut self) {
        loop {
            match self.next_message() {
                Some(Wire::Time(granted)) => return Self::grant(granted),
                Some(Wire::Input(value)) => self.input = value,
                Some(_) => {}
                None => wait(Instant::NEVER),
            }
        }
    }
}

impl Driver for QemuDriver {
    fn now(&mut self) -> Instant {
        now()
    }

    fn transmit(&mut self, frame: &CanFrame) -> Result<(), QueueFull> {
        marker::transmitted(frame);
        self.diagnostics.transmitted(frame);
        usart_write(USART2, &can_serial::encode(frame));
        #[cfg(feature = "simplecan")]
        if dual_channel::simplecan::RawFrame::of(frame).is_some()
            && self.sent.push_back(*frame).is_err()
        {
            // More than the loop confirms in one call: the oldest confirmation is lost, and
            // the core withdraws that packet (its producer sends the next in its slot).
            let _ = self.sent.pop_front();
            let _ = self.sent.push_back(*frame);
        }
        Ok(())
    }

    #[cfg(feature = "simplecan")]
    fn transmitted(&mut self) -> Option<CanFrame> {
        self.sent.pop_front()
    }

    fn receive(&mut self) -> Option<Received> {
        if CAN_RX_LOST.swap(false, Ordering::Relaxed) {
            // Bytes lost on the line may have been a frame: as a FIFO overrun on hardware.
            defmt::warn!("CAN receive pipe overflowed: bytes lost");
            return Some(Received::Overrun);
        }
        while self.pending.is_none() {
            match self.next_message()? {
                Wire::Can(frame) => {
                    marker::received(&frame);
                    defmt::debug!("CAN rx {=u16:X} {=[u8]:X}", frame.id().raw(), frame.data());
                    return Some(Received::Frame(frame));
                }
                Wire::Link(bytes) => self.pending = Some(Pending::Link(bytes)),
                Wire::Input(value) => {
                    if value != self.input {
                        defmt::info!("input pin {=u8}", value);
                    }
                    self.input = value;
                    self.diagnostics.input(value);
                    self.pending = Some(Pending::Input);
                }
                Wire::Time(granted) => Self::grant(granted),
                Wire::Status(_) | Wire::Accept(_) => {
                    defmt::warn!("CAN bridge: a channel's message from the hub")
                }
            }
        }
        None
    }

    fn apply_filters(&mut self, list: &AcceptanceList) {
        // The hub plays the controller's filter banks: it sends only frames on these
        // identifiers (`Wire::Accept`); the loop's software filter, the same list, stays.
        defmt::info!("CAN filters: {=usize} identifiers", list.ids().len());
        let mut ids = [0u16; dual_channel::filters::MAX_ACCEPTED];
        for (slot, id) in ids.iter_mut().zip(list.ids()) {
            *slot = id.raw();
        }
        let count = list.ids().len().min(ids.len());
        for chunk in can_serial::AcceptChunk::split(&ids[..count]) {
            send(&Wire::Accept(chunk));
        }
    }

    fn link_write(&mut self, bytes: &[u8]) -> Result<(), QueueFull> {
        // On the CAN bridge's line, relayed by the hub to the other channel (see the module
        // documentation); a link message is at most a few dozen bytes.
        for chunk in bytes.chunks(can_serial::LINK_CHUNK) {
            if let Some(chunk) = LinkBytes::new(chunk) {
                send(&Wire::Link(chunk));
            }
        }
        Ok(())
    }

    fn link_read(&mut self, buf: &mut [u8]) -> usize {
        let Some(Pending::Link(bytes)) = self.pending else {
            return 0;
        };
        self.pending = None;
        marker::link_received();
        let bytes = bytes.as_slice();
        let count = bytes.len().min(buf.len());
        buf[..count].copy_from_slice(&bytes[..count]);
        self.diagnostics.link_received(now());
        count
    }

    fn input(&mut self, _pin: usize) -> bool {
        if matches!(self.pending, Some(Pending::Input)) {
            self.pending = None;
        }
        self.input != 0
    }

    fn set_output(&mut self, pin: usize, level: bool) {
        defmt::info!("output pin {=usize} = {=bool}", pin, level);
    }

    fn event(&mut self, event: &ChannelEvent) {
        self.diagnostics.event(event);
        defmt::info!("{}", event);
    }
}

fn now() -> Instant {
    Instant::from_micros(embassy_time::Instant::now().as_micros())
}

/// The semihosting command line (QEMU's `-semihosting-config arg=...`).
fn arguments() -> Arguments {
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
        return Arguments::default();
    }
    parse_arguments(&buf[..block.len.min(buf.len())])
}

/// QEMU's start-up: the board's self-tests in the hardware's order; netduinoplus2 models no
/// independent watchdog, so there is none to arm.
struct QemuStartUp;

impl dual_channel::selftest::StartUp for QemuStartUp {
    type Watchdog = ();

    fn self_test(&mut self, test: dual_channel::selftest::SelfTest) -> bool {
        crate::self_test(test)
    }

    fn arm_watchdog(self) {}
}

/// The panic of the argument `crash`, in a function of its own: `cargo xtask test` checks
/// that the panic's log line leads back to this `panic!`. Kept out of line so that its call
/// of the panic is its own: where a function holds several panics, the compiler shares one
/// call among them (their arguments are dead, `board::panic`), and the return address then
/// names the function but no line.
#[inline(never)]
fn deliberate_crash() -> ! {
    panic!("deliberate crash (argument `crash`)");
}

/// Starts the board (SysTick, USARTs), runs the self-tests and then the channel.
pub async fn run<R: Role<N>, const N: usize>(device: Device, role: R) -> ! {
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
    let arguments = arguments();
    if arguments.unknown {
        defmt::error!("semihosting arguments not understood (use `selftest`, `node=N`, `paced`)");
        exit(false);
    }
    if arguments.paced {
        DRIVER.pace();
    }
    RCC.apb1enr().modify(|w| {
        w.set_usart2en(true);
    });
    usart_init(USART2, Interrupt::USART2);
    let passed = dual_channel::selftest::start_up(QemuStartUp).is_ok();
    // QEMU has no bxCAN: the controller's loop-back test (`dual_channel::can_loopback`) runs
    // in the hardware layer only; its plan and verdict are host-tested.
    defmt::info!("self-test: CAN loop-back not run (QEMU models no bxCAN)");
    defmt::info!("self-test verdict: {=bool}", passed);
    if !passed || arguments.selftest {
        exit(passed);
    }
    if arguments.crash {
        deliberate_crash();
    }
    let id = arguments.node.unwrap_or(device.default_id);
    defmt::info!("node-ID {=u8}", id.raw());

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
    let mut driver = QemuDriver {
        decoder: can_serial::Decoder::new(),
        bytes: [0; 64],
        at: 0,
        len: 0,
        pending: None,
        // QEMU models no GPIO: the input reads as released until the hub sets it.
        input: 1,
        diagnostics: Diagnostics::new(),
        #[cfg(feature = "simplecan")]
        sent: heapless::Deque::new(),
    };
    if arguments.paced {
        // The channel powers on at the network's virtual time, not at zero: the hub may have
        // run for a while before this MCU joined, and a clock that jumped from zero to the
        // first grant once the runtime ran would look like a link time-out.
        driver.first_grant();
    }
    driver.diagnostics.input(driver.input);
    // Kept as built and borrowed, not moved out of its `Ok`: the move took the runtime through
    // this task's stack frame; the parameters restored where it is kept, for the same reason
    // (`docs/footprint.md`).
    let mut built = Runtime::<_, _, N, crate::Protocol<N>>::around(
        (device.describe)(id),
        parameters,
        role,
        now(),
        LINK_PERIOD,
    );
    let Ok(runtime) = &mut built else {
        defmt::error!("device description refused");
        exit(false);
    };
    runtime.restore_parameters();
    // The node-ID in use (`node=N`, else the build's) stands for set switches, which win
    // over LSS (CiA 305): a QEMU node answers LSS but keeps its node-ID. The emulated
    // STM32F405 runs the hardware images, whose switches may be all open.
    if !runtime.enable_lss(Some(id), safety_device::LSS_OWN_BIT_RATE_ONLY) {
        defmt::error!("LSS not enabled before the first poll");
        exit(false);
    }
    let mut channel = ChannelLoop::new(device.pins);
    let mut woke = now();
    let mut stack_mark = crate::stack::Sampled::new();
    loop {
        let deadline = channel.service(runtime, &mut driver);
        let at = now();
        let stall = LONGEST_STALL_MS.load(Ordering::Relaxed);
        driver
            .diagnostics
            .stalled(u16::try_from(stall).unwrap_or(u16::MAX));
        if let Some(stack) = stack_mark.poll() {
            driver.diagnostics.stack(stack);
            // Logged as the hardware layer logs it, so an image run alone shows it too.
            defmt::info!("stack high-water mark: {=usize} bytes", stack);
        }
        if let Some(status) = driver.diagnostics.report(at, runtime) {
            send(&Wire::Status(status));
        }
        let deadline = deadline.min(driver.diagnostics.deadline());
        driver.diagnostics.busy(woke, now());
        if !driver.has_bytes() {
            wait(deadline);
        }
        // An await in the loop keeps the loop's state in the task's static storage: without
        // one, it lived on the stack, deeper than the stack reserve (`docs/footprint.md`).
        // The task is ready again at once: no idle here.
        embassy_futures::yield_now().await;
        woke = now();
    }
}

/// Waits with the core halted (WFI) until bytes arrived on USART2 or the clock reached
/// `deadline`.
///
/// Not embassy's executor idle: it waits with WFE, which QEMU 10.0 implements as a yield,
/// not a halt, so an idle emulated MCU kept a host core busy (measured: 6.4 s of CPU in 12 s
/// alone, 54 %), and four of them on two host cores starved each other and the hub
/// (`docs/emulation.md`). This layer's channel loop is the image's only task, so it may
/// block here. The check runs with interrupts masked: an interrupt that arrives after it
/// still ends the WFI (a pending interrupt wakes the core whatever PRIMASK says) and runs
/// once they are unmasked, so no wake-up is lost; SysTick (1 kHz) ends every WFI within a
/// millisecond, the layer's timing resolution.
fn wait(deadline: Instant) {
    loop {
        cortex_m::interrupt::disable();
        let due = !CAN_RX.is_empty() || now() >= deadline;
        if !due {
            cortex_m::asm::wfi();
        }
        // SAFETY: the channel loop calls this outside any critical section (interrupts were
        // enabled when it masked them above), so unmasking breaks none.
        unsafe { cortex_m::interrupt::enable() };
        if due {
            return;
        }
    }
}

/// Markers for `cargo xtask bench --target-cost` (`xtask/src/target_cost.rs`), which counts
/// the instructions of the channel loop under QEMU's instruction trace: the trace holds
/// program counters only, so what a call of [`ChannelLoop::service`] handled is told by which
/// of these it ran. Each is a function of its own (`#[inline(never)]`, bodies made distinct
/// by [`core::hint::black_box`] so that the compiler does not merge them); the measurement
/// subtracts their instructions from the calls around them (the `bl` and its argument stay,
/// two or three instructions). This layer only: the hardware image has none of them.
mod marker {
    use core::hint::black_box;
    use shared::CanFrame;
    use shared::safety::types::SRDO_IDENTIFIERS;

    /// `Some(true)` for a plain SRDO frame, `Some(false)` for an inverted one, by CiA 304's
    /// pre-defined assignment (SRDO n on 0FFh + 2n and 100h + 2n: plain on the odd
    /// identifier), which the emulated network keeps (101h/102h).
    fn srdo_half(frame: &CanFrame) -> Option<bool> {
        let id = frame.id().raw();
        SRDO_IDENTIFIERS.contains(&id).then_some(id & 1 == 1)
    }

    /// The driver hands `frame` to the loop.
    #[inline(never)]
    pub fn received(frame: &CanFrame) {
        match srdo_half(frame) {
            Some(true) => received_plain(),
            Some(false) => received_inverted(),
            None => {}
        }
        // Something after the call keeps it a `bl`: as the last thing it would be a tail
        // call (`b.w`), which the count does not see as a call.
        black_box(0u8);
    }

    /// The loop queues `frame` for the bus.
    #[inline(never)]
    pub fn transmitted(frame: &CanFrame) {
        match srdo_half(frame) {
            Some(true) => transmitted_plain(),
            Some(false) => transmitted_inverted(),
            None => {}
        }
        // Something after the call keeps it a `bl`: as the last thing it would be a tail
        // call (`b.w`), which the count does not see as a call.
        black_box(0u8);
    }

    #[inline(never)]
    fn received_plain() {
        black_box(1u8);
    }

    #[inline(never)]
    fn received_inverted() {
        black_box(2u8);
    }

    #[inline(never)]
    fn transmitted_plain() {
        black_box(3u8);
    }

    #[inline(never)]
    fn transmitted_inverted() {
        black_box(4u8);
    }

    /// The driver hands link bytes to the loop.
    #[inline(never)]
    pub fn link_received() {
        black_box(5u8);
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
