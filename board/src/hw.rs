//! The hardware board layer: embassy-stm32 on the STM32F405RG.
//!
//! Reference wiring (both MCUs alike): CAN1 RX PB8 / TX PB9 to the shared transceiver, the
//! link on USART3 TX PB10 / RX PB11 (crossed to the other MCU), the channel's safety input on
//! PC0 (its own contact, closed = 1), its safety output on PC1 (its own relay, 1 = enabled),
//! the node-ID switches on PC2 (bit 0) to PC8 (bit 6), closed = 1, read at start-up,
//! 8 MHz HSE crystal.
//!
//! [`run`] runs the channel loop ([`dual_channel::channel_loop`]) over [`HwDriver`] and sleeps
//! (`wfi`) until whatever comes first: a CAN frame, link bytes, or the instant the loop asked
//! for (the runtime's next deadline, the 1 ms input sample), on the board's own time base
//! ([`clock`], TIM2). There is no async executor: one loop, interrupts that only move link
//! bytes or wake it, and a sleep that cannot miss a wake-up ([`sleep_until_woken`]). The loop reads the bxCAN's receive FIFOs
//! itself, behind the acceptance filters it derives from the configuration (SRDO identifiers
//! into FIFO 0, NMT, GFC and SDO into FIFO 1), and a FIFO overrun or a bus-off is the safe
//! state, each with its own cause ([`dual_channel::runtime::ChannelFault::ReceiveOverrun`],
//! [`dual_channel::runtime::ChannelFault::BusOff`]). The link USART has a driver of its own
//! ([`link_usart`]): link messages go whole into its transmit queue, which its interrupt
//! empties, and the loop is woken when a whole message has arrived. The independent watchdog
//! is fed by the channel loop only.
//!
//! The bxCAN's driver is the board's own, on the registers (`can1`, RM0090 32; why not
//! embassy-stm32's or the `bxcan` crate's: `docs/can-driver.md`). The loop fills the
//! transmit mailboxes from its queue through [`dual_channel::transmit_queue::Transmitter`],
//! which also tells which frames went out and takes back the frames of an identifier not yet
//! sent (SimpleCAN: SC_REQ_18, SC_REQ_23).

use core::cell::UnsafeCell;
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, Ordering};
use dual_channel::channel_loop::{self, ChannelLoop, Driver, QueueFull};
use dual_channel::filters::{self, AcceptanceList};
use dual_channel::runtime::{ChannelEvent, Role, Runtime};
use embassy_stm32::gpio::{Input, Level, Output, Pull, Speed};
use embassy_stm32::time::Hertz;
use embassy_stm32::{Config, bind_interrupts};
use safety_device::parameter_flash::{STM32F405_SLOTS, SectorSlots, Sectors};
use shared::canopen::storage::{self, StorageError};
use shared::node::Event;
use shared::node::NodeError;
use shared::{CanFrame, Duration, Instant};

use crate::Device;
use crate::can_registers::ErrorState;

mod can1;
use can1::CanPort;
mod can_wakeup;
mod clock;
mod flash;
mod link_usart;
mod watchdog;
use watchdog::Watchdog;

bind_interrupts!(struct Irqs {
    USART3 => link_usart::LinkInterrupt;
    TIM2 => clock::Alarm;
});

/// CAN bit rate (CiA 301 Table 1): the device description's.
pub const BIT_RATE: u32 = safety_device::BIT_RATE;

/// The bit rates LSS may configure on this image (CiA 305).
#[cfg(not(feature = "simplecan"))]
const LSS_BIT_RATES: shared::canopen::lss::BitRates = safety_device::LSS_BIT_RATES;
/// The bit rates LSS may configure on this image (CiA 305): SimpleCAN's slots need 500 kbit/s
/// or more.
#[cfg(feature = "simplecan")]
const LSS_BIT_RATES: shared::canopen::lss::BitRates = safety_device::SIMPLECAN_LSS_BIT_RATES;
/// Link heartbeat period: five per SCT of 50 ms.
pub const LINK_PERIOD: Duration = Duration::from_millis(10);
/// Link USART baud rate: the device description's.
pub const LINK_BAUD: u32 = safety_device::timing::LINK_BAUD;
/// The link's transmit queue, bytes, which the USART's interrupt empties ([`link_usart`]):
/// 5.1 ms of the line at [`LINK_BAUD`].
const LINK_TX_BYTES: usize = 512;
/// The longest the erase ahead at start-up may take ([`erase_ahead`]): one 128 KiB sector at
/// the reset value of the programming parallelism (x8, which [`flash`]'s erase keeps),
/// the STM32F405 datasheet's maximum (DS8626, t_ERASE128KB). The other channel waits this
/// much longer for this one's first link message ([`Runtime::allow_longer_start_up`]).
const ERASE_AHEAD_LONGEST: Duration = Duration::from_millis(4000);
/// The watchdog bites when the runtime loop has not run for this long.
pub const WATCHDOG_TIMEOUT_US: u32 = 20_000;

/// The time base of the protocol core: [`clock`]'s microseconds.
fn now() -> Instant {
    clock::now()
}

/// The 168 MHz clock tree from the 8 MHz crystal (APB1 42 MHz for bxCAN and USART3).
fn clocks() -> Config {
    use embassy_stm32::rcc::{
        AHBPrescaler, APBPrescaler, Hse, HseMode, Pll, PllMul, PllPDiv, PllPreDiv, PllQDiv,
        PllSource, Sysclk,
    };
    let mut config = Config::default();
    config.rcc.hse = Some(Hse {
        freq: Hertz(8_000_000),
        mode: HseMode::Oscillator,
    });
    config.rcc.pll_src = PllSource::HSE;
    config.rcc.pll = Some(Pll {
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL168,
        divp: Some(PllPDiv::DIV2),
        divq: Some(PllQDiv::DIV7),
        divr: None,
    });
    config.rcc.ahb_pre = AHBPrescaler::DIV1;
    config.rcc.apb1_pre = APBPrescaler::DIV4;
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config.rcc.sys = Sysclk::PLL1_P;
    config
}

/// The flash accelerator on (RM0090 3.5.2, FLASH_ACR, 3.9.1): prefetch, instruction cache
/// and data cache. embassy-stm32 sets only the wait states, so without this every fetch at
/// 168 MHz waits for the flash. Each cache is reset while it is off (ICRST and DCRST are
/// written only with the cache disabled), then enabled.
fn accelerator_on() {
    let acr = embassy_stm32::pac::FLASH.acr();
    acr.modify(|w| {
        w.set_icen(false);
        w.set_dcen(false);
    });
    acr.modify(|w| {
        w.set_icrst(true);
        w.set_dcrst(true);
    });
    acr.modify(|w| {
        w.set_icrst(false);
        w.set_dcrst(false);
    });
    acr.modify(|w| {
        w.set_prften(true);
        w.set_icen(true);
        w.set_dcen(true);
    });
}

/// How long the crystal may take to start before the channel halts: ST's HSE_STARTUP_TIMEOUT
/// (the crystal's own start-up is a few milliseconds, DS8626 t_SU(HSE)).
const CRYSTAL_START_MS: u32 = 100;

/// Starts the crystal oscillator (RM0090 6.2.1: HSEON, then HSERDY) and waits for it at most
/// [`CRYSTAL_START_MS`] on the 16 MHz HSI the MCU starts on. embassy-stm32's clock set-up waits
/// for HSERDY without a bound, so a dead crystal would hang the channel silently before the
/// watchdog is armed; this halts it in the safe state with the reason instead.
fn crystal_starts() -> bool {
    let rcc = embassy_stm32::pac::RCC;
    rcc.cr().modify(|w| w.set_hseon(true));
    for _ in 0..CRYSTAL_START_MS {
        if rcc.cr().read().hserdy() {
            return true;
        }
        // A millisecond at the HSI's 16 MHz.
        cortex_m::asm::delay(16_000);
    }
    rcc.cr().read().hserdy()
}

/// Flushes the data cache after the flash array changed (an erase or a program), so that no
/// read of the parameter slots returns a word cached from before (RM0090 3.5.2: the data
/// cache holds words read through the D-bus; reset only while disabled, 3.9.1).
fn flush_data_cache() {
    let acr = embassy_stm32::pac::FLASH.acr();
    acr.modify(|w| w.set_dcen(false));
    acr.modify(|w| w.set_dcrst(true));
    acr.modify(|w| w.set_dcrst(false));
    acr.modify(|w| w.set_dcen(true));
}

/// Set by every flash program and erase: the processor waited for the flash, and the link
/// USART's interrupt with it, so link bytes may have been lost (its one-byte receive
/// register overran). Taken by [`HwDriver`]'s `link_deaf`, which tells the runtime.
static LINK_DEAF: AtomicBool = AtomicBool::new(false);

/// The flash interface ([`flash`], the board's own driver) as the word-programmed medium of
/// the parameter slots ([`safety_device::parameter_flash`]); every erase runs in an
/// [`EraseWindow`]. The processor executes from this flash, so an erase stalls it: a store
/// only programs words, and the free slot is erased ahead at start-up ([`erase_ahead`]).
pub struct Stm32Sectors {
    flash: flash::ParameterFlash,
}

impl Sectors for Stm32Sectors {
    fn erase_stalls(&self) -> bool {
        true
    }

    fn read(&mut self, at: u32, buf: &mut [u8]) -> Result<(), StorageError> {
        self.flash.read(at, buf).map_err(|_| StorageError::Medium)
    }

    fn erase(&mut self, from: u32, to: u32) -> Result<(), StorageError> {
        let window = EraseWindow::open().ok_or(StorageError::Medium)?;
        LINK_DEAF.store(true, Ordering::Relaxed);
        let erased = self.flash.erase(from, to);
        flush_data_cache();
        if window.close().is_none() {
            // The loop's watchdog is not back: stop feeding it, so the MCU resets (at most
            // the wide window later) and starts again with it configured.
            halt_safe("watchdog window not restored after a flash erase");
        }
        erased.map_err(|_| StorageError::Medium)
    }

    fn program(&mut self, at: u32, word: [u8; 4]) -> Result<(), StorageError> {
        LINK_DEAF.store(true, Ordering::Relaxed);
        let written = self.flash.program(at, word);
        flush_data_cache();
        written.map_err(|_| StorageError::Medium)
    }
}

/// The independent watchdog widened for one sector erase.
///
/// Erasing a 128 KiB sector holds the CPU for seconds (STM32F405 datasheet, t_ERASE128KB),
/// a hundred times the loop's watchdog time or more, so an erase would reset the MCU. The
/// only erase is the erase ahead at start-up ([`erase_ahead`]), before the channel loop
/// runs, with the output low; for the erase alone the watchdog is set to /64 and 4095
/// counts: 8.2 s at the LSI's nominal 32 kHz and still 5.6 s at its fastest (47 kHz), then
/// put back to the loop's window exactly as it was.
#[must_use = "the watchdog stays wide until the window is closed"]
struct EraseWindow {
    prescaler: embassy_stm32::pac::iwdg::vals::Pr,
    reload: u16,
}

impl EraseWindow {
    /// Spins for the watchdog's register update; `None` when it never completes (the LSI
    /// has stopped).
    fn updated() -> Option<()> {
        let iwdg = embassy_stm32::pac::IWDG;
        // An update takes at most 5 LSI periods (RM0090 21.3.6), microseconds at 168 MHz:
        // far fewer than these iterations.
        for _ in 0..100_000 {
            let status = iwdg.sr().read();
            if !status.pvu() && !status.rvu() {
                return Some(());
            }
        }
        None
    }

    fn set(prescaler: embassy_stm32::pac::iwdg::vals::Pr, reload: u16) -> Option<()> {
        use embassy_stm32::pac::iwdg::vals::Key;
        let iwdg = embassy_stm32::pac::IWDG;
        Self::updated()?;
        iwdg.kr().write(|w| w.set_key(Key::ENABLE));
        iwdg.pr().write(|w| w.set_pr(prescaler));
        iwdg.rlr().write(|w| w.set_rl(reload));
        // The counter takes the new reload value only once the update is through.
        Self::updated()?;
        iwdg.kr().write(|w| w.set_key(Key::RESET));
        Some(())
    }

    fn open() -> Option<EraseWindow> {
        let iwdg = embassy_stm32::pac::IWDG;
        Self::updated()?;
        let window = EraseWindow {
            prescaler: iwdg.pr().read().pr(),
            reload: iwdg.rlr().read().rl(),
        };
        Self::set(embassy_stm32::pac::iwdg::vals::Pr::DIVIDE_BY64, 0x0FFF)?;
        Some(window)
    }

    fn close(self) -> Option<()> {
        Self::set(self.prescaler, self.reload)
    }
}

/// The board as the channel loop sees it: the bxCAN ([`CanPort`]), the link USART, the input
/// and output pins, embassy's clock.
struct HwDriver<'d> {
    can: CanPort,
    /// The controller's error state when last read, for reporting changes once.
    error_state: ErrorState,
    input: Input<'d>,
    output: Output<'d>,
}

impl HwDriver<'_> {
    /// `true` when the controller has gone bus-off since the last call ([`ErrorState`]);
    /// every change of its error state is logged. The loop calls [`Driver::receive`] at every
    /// wake-up and at least every 1 ms, and a bus-off lasts at least 128 times 11 recessive
    /// bits (2.8 ms at 500 kbit/s, 1.4 ms at 1 Mbit/s) before the automatic recovery, so none
    /// passes unseen; the loop does not run during a flash erase, which only happens at
    /// start-up, before the loop ([`erase_ahead`]).
    fn went_bus_off(&mut self) -> bool {
        let esr = embassy_stm32::pac::CAN1.esr().read().0;
        let state = ErrorState::from_esr(esr);
        if state == self.error_state {
            return false;
        }
        let entered = state.loses_frames() && !self.error_state.loses_frames();
        defmt::warn!(
            "CAN error state {} (transmit errors {=u8}, receive errors {=u8})",
            state,
            crate::can_registers::transmit_errors(esr),
            crate::can_registers::receive_errors(esr)
        );
        self.error_state = state;
        if entered {
            defmt::error!("CAN bus-off: frames may have gone unseen");
        }
        entered
    }
}

impl Driver for HwDriver<'_> {
    fn now(&mut self) -> Instant {
        now()
    }

    fn transmit(&mut self, frame: &CanFrame) -> Result<(), QueueFull> {
        self.can.transmit(frame)
    }

    fn receive(&mut self) -> Option<channel_loop::Received> {
        if self.went_bus_off() {
            return Some(channel_loop::Received::BusOff);
        }
        self.can.receive()
    }

    fn apply_filters(&mut self, list: &AcceptanceList) {
        let Ok(layout) = filters::bank_layout(list, filters::CAN1_BANKS) else {
            // Any list fits CAN1's 14 banks (the fallback takes two; host-tested).
            halt_safe("no acceptance filter layout");
        };
        if !layout.exact {
            defmt::warn!("CAN filters: SRDO range masked, the loop filters the rest");
        }
        self.can.apply_filters(&layout);
        defmt::info!("CAN filters: {=usize} identifiers", list.ids().len());
    }

    fn link_write(&mut self, bytes: &[u8]) -> Result<(), QueueFull> {
        // All or nothing: a message cut short would reach the other channel corrupt; the
        // loop never waits for room.
        if link_usart::write(bytes) {
            Ok(())
        } else {
            defmt::warn!("link transmit queue full");
            Err(QueueFull)
        }
    }

    fn link_read(&mut self, buf: &mut [u8]) -> usize {
        if link_usart::take_lost() {
            // The link's frame check finds the gap; said once here, where it happened.
            defmt::warn!("link bytes lost: receive queue full or USART overrun");
        }
        link_usart::read(buf)
    }

    fn input(&mut self, _pin: usize) -> bool {
        self.input.is_high()
    }

    fn set_output(&mut self, _pin: usize, level: bool) {
        // One relay per channel (the device description's one output pin).
        self.output
            .set_level(if level { Level::High } else { Level::Low });
    }

    fn event(&mut self, event: &ChannelEvent) {
        // Transitions and faults are logged; the pairs are counted by the runtime.
        if !event.is_per_pair() {
            defmt::info!("{}", event);
        }
        if let ChannelEvent::Node(Event::StorageFailed(StorageError::NotErased)) = event {
            defmt::warn!(
                "parameter store refused (device state): the free parameter slot still holds \
                 the record the last store superseded, and erasing it now would stall this \
                 channel for seconds; switch the node off and on before storing again: the \
                 free parameter slot is erased at start-up"
            );
        }
    }

    fn switch_bit_rate(&mut self, rate: shared::canopen::lss::BitRate) {
        // Every rate LSS may make pending was checked at start-up to have a timing.
        let Some(timing) = can_timing(rate) else {
            halt_safe("no CAN bit timing for the bit rate LSS activated");
        };
        self.can.switch_bit_rate(timing);
        defmt::info!(
            "CAN switched to {=u32} bit/s (LSS activate bit timing)",
            rate.bits_per_second().unwrap_or(0)
        );
    }

    fn link_deaf(&mut self) -> bool {
        LINK_DEAF.swap(false, Ordering::Relaxed)
    }

    fn link_restarted(&mut self, restarted: bool) {
        if restarted {
            defmt::info!(
                "link receiver restarted: this channel programmed its parameter flash and \
                 could not receive meanwhile; bytes it lost are not taken for a link fault"
            );
        } else {
            defmt::warn!("parameter flash programmed in Operational: the link judges as usual");
        }
    }

    #[cfg(feature = "simplecan")]
    fn transmitted(&mut self) -> Option<CanFrame> {
        self.can.transmitted()
    }

    #[cfg(feature = "simplecan")]
    fn abort(&mut self, id: shared::CanId) {
        self.can.abort(id);
    }
}

/// Which transmit mailboxes are empty (CAN_TSR.TME0..2, RM0090 32.9.3): read, never written,
/// so that neither driver's own use of the register is disturbed.
fn empty_mailboxes() -> [bool; 3] {
    let tsr = embassy_stm32::pac::CAN1.tsr().read();
    [tsr.tme(0), tsr.tme(1), tsr.tme(2)]
}

/// The hardware's start-up: the board's self-tests, then the independent watchdog of
/// [`WATCHDOG_TIMEOUT_US`], which only [`dual_channel::selftest::start_up`] arms.
struct HwStartUp {
    iwdg: embassy_stm32::Peri<'static, embassy_stm32::peripherals::IWDG>,
}

impl dual_channel::selftest::StartUp for HwStartUp {
    type Watchdog = Watchdog;

    fn self_test(&mut self, test: dual_channel::selftest::SelfTest) -> bool {
        crate::self_test(test)
    }

    fn arm_watchdog(self) -> Self::Watchdog {
        Watchdog::arm(self.iwdg)
    }
}

/// The channel's runtime on this board: parameters on the STM32F405's flash sectors, the
/// image's protocol ([`crate::Protocol`]).
pub type ChannelRuntime<R, const N: usize> =
    Runtime<SectorSlots<Stm32Sectors>, R, N, crate::Protocol<N>>;

/// Where [`run`] builds the channel's runtime: a static of the channel's image, so that the
/// runtime, the largest object of the image, is counted in RAM when the image is linked
/// (`cargo xtask build` holds it to the RAM budget) and not on the stack, where only the
/// measured high-water mark would show it.
pub struct RuntimeSlot<R: Role<N>, const N: usize> {
    built: UnsafeCell<MaybeUninit<Result<ChannelRuntime<R, N>, NodeError>>>,
    taken: AtomicBool,
}

// SAFETY: the slot's contents are reached only through `take`, which hands out its one
// mutable reference once (the `taken` flag, swapped atomically); the image has one thread,
// and no interrupt handler reaches the slot.
unsafe impl<R: Role<N>, const N: usize> Sync for RuntimeSlot<R, N> {}

impl<R: Role<N>, const N: usize> RuntimeSlot<R, N> {
    /// An empty slot.
    #[allow(clippy::new_without_default)] // reason: built in a `static`, where only a `const fn` will do
    pub const fn new() -> Self {
        RuntimeSlot {
            built: UnsafeCell::new(MaybeUninit::uninit()),
            taken: AtomicBool::new(false),
        }
    }

    /// The slot's place, the first time; `None` after.
    #[allow(clippy::mut_from_ref)] // reason: handed out once, guarded by `taken` (see `Sync`)
    fn take(
        &'static self,
    ) -> Option<&'static mut MaybeUninit<Result<ChannelRuntime<R, N>, NodeError>>> {
        if self.taken.swap(true, Ordering::AcqRel) {
            return None;
        }
        // SAFETY: `taken` was clear, so no reference to the contents exists, and none will
        // be made again (see the `Sync` implementation).
        Some(unsafe { &mut *self.built.get() })
    }
}

/// Sleeps (`wfi`) until a wake-up the loop armed has come: `woken` says whether one has. The
/// check and the sleep run with interrupts masked (PRIMASK), so an interrupt between them is
/// not lost: it stays pending, and a pending interrupt ends `wfi` even while masked
/// (ARMv7-M B1.5.19); its handler runs when the mask is lifted, and the check is made again.
fn sleep_until_woken(mut woken: impl FnMut() -> bool) {
    loop {
        cortex_m::interrupt::disable();
        let ready = woken();
        if !ready {
            cortex_m::asm::wfi();
        }
        // SAFETY: the mask was set just above and nothing of this program relies on it
        // beyond this point (the handlers share only atomics and `Mutex`-guarded queues).
        unsafe { cortex_m::interrupt::enable() };
        if ready {
            return;
        }
    }
}

/// Initialises the board, runs the start-up self-tests, arms the watchdog and runs the
/// channel until reset, with its runtime, of the role `role` makes, built in `slot`.
pub fn run<R: Role<N>, const N: usize>(
    device: Device,
    role: impl FnOnce() -> R,
    slot: &'static RuntimeSlot<R, N>,
) -> ! {
    let (runtime, mut driver, mut watchdog) = start(device, role, slot);
    let mut channel = ChannelLoop::new(device.pins);
    let mut stack_mark = crate::stack::Sampled::new();
    loop {
        let wake = channel.service(runtime, &mut driver);
        watchdog.pet();
        if let Some(stack) = stack_mark.poll() {
            defmt::info!("stack high-water mark: {=usize} bytes", stack);
        }
        // The next service takes what woke it (a frame, link bytes, the instant).
        if !driver.can.prepare_wait() {
            continue;
        }
        // Woken at the instant the alarm was set to: the loop's, or sooner when that was
        // further ahead than the alarm reaches.
        let Some(alarm) = clock::arm(wake, now()) else {
            continue;
        };
        sleep_until_woken(|| driver.can.woken() || link_usart::readable() || clock::due(alarm));
    }
}

/// Everything before the loop: the clocks, the self-tests, the watchdog, the erase ahead, the
/// node-ID, the runtime built in `slot`, the CAN controller and the link. Out of line, so that
/// its stack frame is given back before the loop runs: the runtime is returned by value into
/// it before it is moved into `slot` (the compiler does not build it in the static's place,
/// which any function could read), a start-up peak of the stack that the loop does not keep.
#[inline(never)]
#[allow(clippy::mut_from_ref)] // reason: the runtime is `slot`'s, taken once (`RuntimeSlot::take`)
fn start<R: Role<N>, const N: usize>(
    device: Device,
    role: impl FnOnce() -> R,
    slot: &'static RuntimeSlot<R, N>,
) -> (
    &'static mut ChannelRuntime<R, N>,
    HwDriver<'static>,
    Watchdog,
) {
    if !crystal_starts() {
        halt_safe("the crystal (HSE) did not start");
    }
    let p = embassy_stm32::init(clocks());
    accelerator_on();
    let _ = Irqs;
    let timer_clock = embassy_stm32::rcc::frequency::<embassy_stm32::peripherals::TIM2>();
    if !clock::start(timer_clock.0) {
        halt_safe("the timer clock does not divide into microseconds");
    }
    // Why the MCU started, then the flags cleared (RMVF) so that the next start says its own.
    let csr = embassy_stm32::pac::RCC.csr().read().0;
    embassy_stm32::pac::RCC.csr().modify(|w| w.set_rmvf(true));
    if safety_device::reset_cause::after_watchdog(csr) {
        defmt::warn!("reset by {=str}", safety_device::reset_cause::describe(csr));
    } else {
        defmt::info!("reset by {=str}", safety_device::reset_cause::describe(csr));
    }
    // The self-tests first, then the watchdog (`dual_channel::selftest::start_up` says why).
    let mut watchdog = match dual_channel::selftest::start_up(HwStartUp { iwdg: p.IWDG }) {
        Ok(watchdog) => watchdog,
        Err(test) => {
            defmt::error!(
                "start-up self-test {} failed; the watchdog stays unarmed",
                test
            );
            halt_safe("start-up self-test failed");
        }
    };

    let output = Output::new(p.PC1, Level::Low, Speed::Low);
    let input = Input::new(p.PC0, Pull::Down);

    // The erase ahead first, with the output low: before the CAN controller and the link
    // USART receive anything (their interrupts would not run during the erase, and a full
    // receive FIFO is a fault) and before the runtime and its link supervision exist.
    let mut parameters = SectorSlots::new(
        Stm32Sectors {
            flash: flash::ParameterFlash::new(p.FLASH),
        },
        STM32F405_SLOTS,
    );
    erase_ahead(&mut parameters);
    // Before the link: nothing was lost on it.
    LINK_DEAF.store(false, Ordering::Relaxed);

    let switch_pins = [
        Input::new(p.PC2, Pull::Down),
        Input::new(p.PC3, Pull::Down),
        Input::new(p.PC4, Pull::Down),
        Input::new(p.PC5, Pull::Down),
        Input::new(p.PC6, Pull::Down),
        Input::new(p.PC7, Pull::Down),
        Input::new(p.PC8, Pull::Down),
    ];
    let read_switches = || {
        switch_pins
            .iter()
            .enumerate()
            .fold(0u8, |id, (bit, pin)| id | (u8::from(pin.is_high()) << bit))
    };
    let first = read_switches();
    clock::delay(Duration::from_millis(1));
    // All switches open: the node-ID is LSS's (CiA 305), set when LSS is enabled below.
    let switches = match safety_device::switches::node_id_or_lss(first, read_switches()) {
        Ok(Some(id)) => {
            defmt::info!("node-ID {=u8} from the switches", id.raw());
            Some(id)
        }
        Ok(None) => {
            defmt::info!("node-ID switches all open: the node-ID is set by LSS (CiA 305)");
            None
        }
        Err(fault) => {
            defmt::error!("node-ID switches refused: {}", fault);
            halt_safe("no valid node-ID");
        }
    };
    drop(switch_pins);

    // Without switches the description's default stands in until LSS sets the node-ID in
    // force (`Runtime::enable_lss`): the node sends nothing but LSS answers until it has one.
    let config = (device.describe)(switches.unwrap_or(device.default_id));
    // Kept as built and borrowed, not moved out of its `Ok`: the move took the whole runtime
    // through this task's stack frame; the parameters restored where it is kept, for the
    // same reason (`docs/footprint.md`).
    let Some(place) = slot.take() else {
        halt_safe("the channel's runtime slot was taken twice");
    };
    let runtime = match place.write(ChannelRuntime::<R, N>::around(
        config,
        parameters,
        role(),
        now(),
        LINK_PERIOD,
    )) {
        Ok(runtime) => runtime,
        Err(_) => halt_safe("device description refused"),
    };
    // The other channel may be erasing ahead while this one was not, or for longer.
    runtime.allow_longer_start_up(ERASE_AHEAD_LONGEST);
    runtime.restore_parameters();
    if !runtime.enable_lss(switches, LSS_BIT_RATES) {
        halt_safe("LSS not enabled before the first poll");
    }
    // Every rate LSS may configure has a timing from this clock, or the node does not start:
    // a switch to a rate without one would leave it on no rate at all.
    let untimed = shared::canopen::lss::BitRate::ALL
        .into_iter()
        .filter(|&rate| LSS_BIT_RATES.contains(rate))
        .any(|rate| can_timing(rate).is_none());
    if untimed {
        halt_safe("an LSS bit rate has no CAN bit timing from the APB1 clock");
    }
    // The CAN controller starts at the bit rate LSS stored (CiA 305 store configuration),
    // else at the hardware's.
    let start_rate = runtime
        .lss_settings()
        .bit_rate
        .unwrap_or(safety_device::BIT_RATE_ENTRY);
    let Some(timing) = can_timing(start_rate) else {
        halt_safe("no CAN bit timing for the start-up bit rate from the APB1 clock");
    };
    if start_rate != safety_device::BIT_RATE_ENTRY {
        defmt::info!(
            "CAN at {=u32} bit/s, the bit rate LSS stored",
            start_rate.bits_per_second().unwrap_or(0)
        );
    }
    let can = CanPort::start(p.CAN1, p.PB8, p.PB9, timing, &mut watchdog);
    // Kept for as long as the loop runs: the link's pins stay set up while it lives.
    let Some(_link) = link_usart::set_up(p.USART3, p.PB11, p.PB10, LINK_BAUD) else {
        halt_safe("link USART configuration refused");
    };
    link_usart::start();
    let driver = HwDriver {
        can,
        error_state: ErrorState::Active,
        input,
        output,
    };
    (runtime, driver, watchdog)
}

/// The CAN bit timing of `rate` from CAN1's clock (APB1), `None` where there is none (a rate
/// the clock does not divide into, automatic detection). embassy's calculation, called here
/// rather than through `Can::set_bitrate`, which unwraps it and so links the `Debug`
/// formatting of its error into the image (`docs/footprint.md`).
fn can_timing(
    rate: shared::canopen::lss::BitRate,
) -> Option<embassy_stm32::can::util::NominalBitTiming> {
    let clock = embassy_stm32::rcc::frequency::<embassy_stm32::peripherals::CAN1>();
    embassy_stm32::can::util::calc_can_timings(clock, rate.bits_per_second()?).ok()
}

/// The CAN_BTR value of embassy's `timing` (RM0090 32.9.2,
/// [`crate::can_registers::BitTiming::register`]), for the board's CAN driver.
fn bit_timing_register(
    timing: embassy_stm32::can::util::NominalBitTiming,
) -> Result<u32, crate::can_registers::BitTimingOutOfRange> {
    crate::can_registers::BitTiming {
        prescaler: timing.prescaler.get(),
        seg1: timing.seg1.get(),
        seg2: timing.seg2.get(),
        sync_jump_width: timing.sync_jump_width.get(),
    }
    .register()
}

/// The start-up's housekeeping of the parameter slots ([`storage::erase_ahead`]): erases the
/// slot the next store writes to when it still holds the record the last store superseded,
/// so that the store only programs words. Runs before the channel loop and the link
/// supervision exist, with the output low and the watchdog widened ([`EraseWindow`]); the
/// other channel waits for it ([`ERASE_AHEAD_LONGEST`]). A failure only leaves the next store
/// refused ([`StorageError::NotErased`]): the record in force is never erased.
fn erase_ahead(parameters: &mut SectorSlots<Stm32Sectors>) {
    match storage::erase_ahead(parameters) {
        Ok(None) => {}
        Ok(Some(slot)) => defmt::info!(
            "parameter slot {} erased at start-up: it held the record the last store \
             superseded; start-up took one sector erase longer, so that the next store \
             programs without erasing",
            slot
        ),
        Err(error) => defmt::error!(
            "parameter slot not erased at start-up ({}): a store will be refused until a \
             start-up erases it",
            error
        ),
    }
}

/// A fault before the runtime runs: outputs stay low (their reset state) and the watchdog is
/// not fed. Once it is armed the MCU resets into the same check; a failed self-test comes
/// before it is armed, so that channel stays halted until it is powered again.
fn halt_safe(why: &str) -> ! {
    defmt::error!("halting in the safe state: {=str}", why);
    loop {
        cortex_m::asm::wfi();
    }
}
