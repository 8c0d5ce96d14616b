//! The hardware board layer: embassy-stm32 on the STM32F405RG.
//!
//! Reference wiring (both MCUs alike): CAN1 RX PB8 / TX PB9 to the shared transceiver, the
//! link on USART3 TX PB10 / RX PB11 (crossed to the other MCU), the channel's safety input on
//! PC0 (its own contact, closed = 1), its safety output on PC1 (its own relay, 1 = enabled),
//! the node-ID switches on PC2 (bit 0) to PC8 (bit 6), closed = 1, read at start-up,
//! 8 MHz HSE crystal.
//!
//! One task runs the channel loop ([`dual_channel::channel_loop`]) over [`HwDriver`] and wakes
//! for whatever comes first: a CAN frame, link bytes, or the instant the loop asked for (the
//! runtime's next deadline, the 1 ms input sample). The loop reads the bxCAN's receive FIFOs
//! itself, behind the acceptance filters it derives from the configuration (SRDO identifiers
//! into FIFO 0, NMT, GFC and SDO into FIFO 1), and a FIFO overrun is the safe state
//! ([`dual_channel::runtime::ChannelFault::ReceiveOverrun`]). Two small tasks move frames from
//! a priority queue into the transmit mailboxes and drain the link transmit pipe into the
//! USART. The independent watchdog is fed by the channel loop only.

use dual_channel::can_loopback::{LoopbackController, LoopbackFault, Received};
use dual_channel::channel_loop::{self, ChannelLoop, Driver, QueueFull};
use dual_channel::filters::{self, AcceptanceList, Bank};
use dual_channel::runtime::{ChannelEvent, Role, Runtime};
use embassy_executor::Spawner;
use embassy_futures::select::{Either3, select3};
use embassy_stm32::can::enums::TryReadError;
use embassy_stm32::can::filter::{ListEntry16, ListEntry32, Mask16};
use embassy_stm32::can::{
    Can, CanRx, CanTx, Fifo, Frame, Rx0InterruptHandler, Rx1InterruptHandler, SceInterruptHandler,
    StandardId, TxInterruptHandler,
};
use embassy_stm32::gpio::{Input, Level, Output, Pull, Speed};
use embassy_stm32::peripherals::{CAN1, IWDG, USART3};
use embassy_stm32::time::Hertz;
use embassy_stm32::usart::{self, BufferedUart, BufferedUartRx, BufferedUartTx};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{Config, bind_interrupts};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::pipe::Pipe;
use embassy_sync::priority_channel::{Min, PriorityChannel};
use embassy_time::Timer;
use embedded_io_async::{Read, Write};
use shared::canopen::storage::StorageError;
use shared::{CanFrame, Duration, Instant};
use static_cell::StaticCell;

use crate::Device;
use crate::parameter_flash::{STM32F405_SLOTS, SectorSlots, Sectors};
use crate::transmit_queue::{Queued, Sequencer};

bind_interrupts!(struct Irqs {
    CAN1_RX0 => Rx0InterruptHandler<CAN1>;
    CAN1_RX1 => Rx1InterruptHandler<CAN1>;
    CAN1_SCE => SceInterruptHandler<CAN1>;
    CAN1_TX => TxInterruptHandler<CAN1>;
    USART3 => usart::BufferedInterruptHandler<USART3>;
});

/// CAN bit rate (CiA 301 Table 1): the device description's.
pub const BIT_RATE: u32 = dual_channel::device::BIT_RATE;
/// Link heartbeat period: five per SCT of 50 ms.
pub const LINK_PERIOD: Duration = Duration::from_millis(10);
/// Link USART baud rate.
pub const LINK_BAUD: u32 = 1_000_000;
/// The watchdog bites when the runtime loop has not run for this long.
pub const WATCHDOG_TIMEOUT_US: u32 = 20_000;

/// Frames to send, from the runtime task: by identifier, not first in first out
/// ([`crate::transmit_queue`]), so the node's own heartbeat or EMCY never holds back its SRDO
/// or GFC.
static CAN_TX: PriorityChannel<CriticalSectionRawMutex, Queued, Min, 16> = PriorityChannel::new();
/// Link bytes to send.
static LINK_TX: Pipe<CriticalSectionRawMutex, 256> = Pipe::new();

fn now() -> Instant {
    Instant::from_micros(embassy_time::Instant::now().as_micros())
}

fn embassy_instant(at: Instant) -> embassy_time::Instant {
    embassy_time::Instant::from_micros(at.as_micros())
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

/// embassy-stm32's blocking flash driver as the word-programmed medium of the parameter
/// slots ([`crate::parameter_flash`]); every erase runs in an [`EraseWindow`].
pub struct Stm32Sectors<'d> {
    flash: embassy_stm32::flash::Flash<'d, embassy_stm32::flash::Blocking>,
}

impl Sectors for Stm32Sectors<'_> {
    fn read(&mut self, at: u32, buf: &mut [u8]) -> Result<(), StorageError> {
        self.flash
            .blocking_read(at, buf)
            .map_err(|_| StorageError::Medium)
    }

    fn erase(&mut self, from: u32, to: u32) -> Result<(), StorageError> {
        let window = EraseWindow::open().ok_or(StorageError::Medium)?;
        let erased = self.flash.blocking_erase(from, to);
        if window.close().is_none() {
            // The loop's watchdog is not back: stop feeding it, so the MCU resets (at most
            // the wide window later) and starts again with it configured.
            halt_safe("watchdog window not restored after a flash erase");
        }
        erased.map_err(|_| StorageError::Medium)
    }

    fn program(&mut self, at: u32, word: [u8; 4]) -> Result<(), StorageError> {
        self.flash
            .blocking_write(at, &word)
            .map_err(|_| StorageError::Medium)
    }
}

/// The independent watchdog widened for one sector erase.
///
/// Erasing a 128 KiB sector holds the CPU for up to 2 s (STM32F405 datasheet, t_ERASE128KB at
/// x32 parallelism), a hundred times the loop's watchdog time, so an erase would reset the MCU
/// in the middle of every store. Stores happen only outside Operational (0x1010 and 0x1011
/// are refused there), with the output low; for the erase alone the watchdog is set to
/// /64 and 4095 counts: 8.2 s at the LSI's nominal 32 kHz and still 5.6 s at its fastest
/// (47 kHz), then put back to the loop's window exactly as it was.
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

/// The board as the channel loop sees it: the bxCAN's receive FIFOs and filters, the transmit
/// queue, the link USART, the input and output pins, embassy's clock.
struct HwDriver<'d> {
    can: CanRx<'static>,
    link: BufferedUartRx<'static>,
    input: Input<'d>,
    output: Output<'d>,
    /// Numbers the frames handed to [`CAN_TX`], for their order within one identifier.
    sequencer: Sequencer,
    /// A frame the wait took from a FIFO, for the loop's next [`Driver::receive`].
    frame: Option<CanFrame>,
    /// Link bytes the wait read, for the loop's next [`Driver::link_read`] (which takes them
    /// whole: its buffer is as long).
    link_bytes: [u8; 64],
    link_count: usize,
}

impl HwDriver<'_> {
    /// `true` (and the flags cleared) when a receive FIFO overflowed since the last call:
    /// bxCAN keeps three frames per FIFO and, with RFLM = 0 (the reset value, kept), the
    /// newest overwrites the third, so a frame the filters passed was lost (RM0090 32.7.5).
    fn overrun() -> bool {
        let can = embassy_stm32::pac::CAN1;
        let mut lost = false;
        for fifo in 0..2 {
            if can.rfr(fifo).read().fovr() {
                // FOVR is cleared by writing 1; FULL likewise, RFOM = 0 releases nothing.
                can.rfr(fifo).write(|w| w.set_fovr(true));
                lost = true;
            }
        }
        lost
    }
}

impl Driver for HwDriver<'_> {
    fn now(&mut self) -> Instant {
        now()
    }

    fn transmit(&mut self, frame: &CanFrame) -> Result<(), QueueFull> {
        CAN_TX
            .try_send(self.sequencer.queue(*frame))
            .map_err(|_| QueueFull)
    }

    fn receive(&mut self) -> Option<channel_loop::Received> {
        if Self::overrun() {
            return Some(channel_loop::Received::Overrun);
        }
        if let Some(frame) = self.frame.take() {
            return Some(channel_loop::Received::Frame(frame));
        }
        loop {
            match self.can.try_read() {
                Ok(envelope) => {
                    // Not CANopen's (extended, length over 8): as if filtered out.
                    if let Some(frame) = from_bxcan(&envelope.frame) {
                        return Some(channel_loop::Received::Frame(frame));
                    }
                }
                Err(TryReadError::Empty) => return None,
                Err(TryReadError::BusError(error)) => {
                    defmt::warn!("CAN bus error {}", error);
                    return None;
                }
            }
        }
    }

    fn apply_filters(&mut self, list: &AcceptanceList) {
        let Ok(layout) = filters::bank_layout(list, filters::CAN1_BANKS) else {
            // Any list fits CAN1's 14 banks (the fallback takes two; host-tested).
            halt_safe("no acceptance filter layout");
        };
        if !layout.exact {
            defmt::warn!("CAN filters: SRDO range masked, the loop filters the rest");
        }
        let id = |raw: u16| StandardId::new(raw).unwrap_or(StandardId::ZERO);
        let mut banks = self.can.modify_filters();
        banks.clear();
        for (index, &(bank, fifo)) in layout.banks.iter().enumerate() {
            let fifo = match fifo {
                filters::Fifo::Srdo => Fifo::Fifo0,
                filters::Fifo::Services => Fifo::Fifo1,
            };
            // At most 14 banks: the index fits.
            let index = index as u8;
            match bank {
                Bank::List16(ids) => {
                    banks.enable_bank(
                        index,
                        fifo,
                        ids.map(|raw| ListEntry16::data_frames_with_id(id(raw))),
                    );
                }
                Bank::Mask16(pairs) => {
                    banks.enable_bank(
                        index,
                        fifo,
                        pairs.map(|(raw, mask)| {
                            *Mask16::frames_with_std_id(id(raw), id(mask)).data_frames_only()
                        }),
                    );
                }
            }
        }
        // Dropping the proxy leaves filter initialisation mode.
        drop(banks);
        defmt::info!("CAN filters: {=usize} identifiers", list.ids().len());
    }

    fn link_write(&mut self, bytes: &[u8]) -> Result<(), QueueFull> {
        // All or nothing: a message cut short would reach the other channel corrupt.
        if LINK_TX.free_capacity() < bytes.len() {
            defmt::warn!("link transmit pipe full");
            return Err(QueueFull);
        }
        LINK_TX.try_write(bytes).map(|_| ()).map_err(|_| QueueFull)
    }

    fn link_read(&mut self, buf: &mut [u8]) -> usize {
        let stashed = core::mem::take(&mut self.link_count);
        if let (Some(to), Some(from)) = (buf.get_mut(..stashed), self.link_bytes.get(..stashed)) {
            if stashed > 0 {
                to.copy_from_slice(from);
                return stashed;
            }
        }
        match embassy_futures::poll_once(self.link.read(buf)) {
            core::task::Poll::Ready(Ok(count)) => count,
            core::task::Poll::Ready(Err(_)) => {
                defmt::warn!("link read error");
                0
            }
            core::task::Poll::Pending => 0,
        }
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
        defmt::info!("{}", event);
    }
}

/// The bxCAN in silent loop-back mode, for [`dual_channel::can_loopback::run`].
struct Loopback<'a, 'd> {
    can: &'a mut Can<'d>,
}

impl LoopbackController for Loopback<'_, '_> {
    fn now(&self) -> Instant {
        now()
    }

    fn queue(&mut self, frame: &CanFrame) -> Option<u8> {
        let frame = to_bxcan(frame)?;
        let status = self.can.try_write(&frame).ok()?;
        Some(status.mailbox() as u8)
    }

    async fn receive(&mut self, until: Instant) -> Received {
        match embassy_time::with_deadline(embassy_instant(until), self.can.read()).await {
            Ok(Ok(envelope)) => match from_bxcan(&envelope.frame) {
                Some(frame) => Received::Frame(frame),
                None => Received::Unreadable {
                    id: raw_id(&envelope.frame),
                    dlc: envelope.frame.header().len(),
                },
            },
            Ok(Err(_)) => Received::BusError,
            Err(_) => Received::Nothing,
        }
    }
}

/// CiA 304 9.5: the controller's message buffers and filters, tested in silent loop-back mode
/// before it joins the bus (plan, loop and verdict: [`dual_channel::can_loopback`]). Leaves
/// the controller out of loop-back, for [`can_task`] to set its filters and enable it.
async fn loopback_test(
    can: &mut Can<'_>,
    watchdog: &mut IndependentWatchdog<'_, IWDG>,
) -> Result<(), LoopbackFault> {
    use dual_channel::can_loopback::{ACCEPT_FIFO0, ACCEPT_FIFO1};
    // The plan's identifiers are 11-bit constants; an invalid one would become 0 and fail the
    // test as missing.
    let listed = |ids: [u16; 2]| {
        ids.map(|id| {
            ListEntry32::data_frames_with_id(StandardId::new(id).unwrap_or(StandardId::ZERO))
        })
    };
    can.modify_config().set_loopback(true).set_silent(true);
    can.modify_filters()
        .clear()
        .enable_bank(0, Fifo::Fifo0, listed(ACCEPT_FIFO0))
        .enable_bank(1, Fifo::Fifo1, listed(ACCEPT_FIFO1));
    // In queue order, so that a burst fills mailboxes 0, 1 and 2 one after the other.
    can.set_tx_fifo_scheduling(true);
    can.enable().await;
    // Each burst takes at most BURST_WAIT (5 ms), well inside the watchdog's time.
    let verdict =
        dual_channel::can_loopback::run(&mut Loopback { can: &mut *can }, || watchdog.pet()).await;
    can.set_tx_fifo_scheduling(false);
    // Out of loop-back; dropping the configuration proxy leaves initialisation mode.
    can.modify_config().set_loopback(false).set_silent(false);
    verdict
}

/// A received frame's identifier as far as it fits (extended identifiers cut to 16 bits), for
/// the report of a frame that is not CANopen's.
fn raw_id(frame: &Frame) -> u16 {
    match frame.id() {
        embassy_stm32::can::Id::Standard(id) => id.as_raw(),
        embassy_stm32::can::Id::Extended(id) => id.as_raw() as u16,
    }
}

/// Moves frames from [`CAN_TX`], lowest identifier first, into the transmit mailboxes.
#[embassy_executor::task]
async fn can_tx_task(mut tx: CanTx<'static>) {
    loop {
        let queued = CAN_TX.receive().await;
        if let Some(frame) = to_bxcan(&queued.frame) {
            tx.write(&frame).await;
        }
    }
}

#[embassy_executor::task]
async fn link_tx_task(mut tx: BufferedUartTx<'static>) {
    let mut buf = [0u8; 64];
    loop {
        let n = LINK_TX.read(&mut buf).await;
        if tx.write_all(&buf[..n]).await.is_err() {
            defmt::warn!("link write failed");
        }
    }
}

/// A standard data or remote frame from the bxCAN ([`crate::received_frame`] has the rules).
/// The length is taken from the header and the data from the raw registers: embassy-stm32's
/// `Frame::data` would panic on a length code over 8.
fn from_bxcan(frame: &Frame) -> Option<CanFrame> {
    let embassy_stm32::can::Id::Standard(id) = frame.id() else {
        return None;
    };
    let mut data = [0u8; 8];
    data.copy_from_slice(frame.raw_data().get(..8)?);
    crate::received_frame(
        id.as_raw(),
        frame.header().rtr(),
        frame.header().len(),
        &data,
    )
}

fn to_bxcan(frame: &CanFrame) -> Option<Frame> {
    let id = StandardId::new(frame.id().raw())?;
    if frame.is_remote() {
        Frame::new_remote(id, usize::from(frame.dlc())).ok()
    } else {
        Frame::new_data(id, frame.data()).ok()
    }
}

/// Initialises the board, spawns the peripheral tasks and runs the channel until reset.
pub async fn run<R: Role<N>, const N: usize>(spawner: Spawner, device: Device, role: R) -> ! {
    let p = embassy_stm32::init(clocks());
    let mut watchdog = IndependentWatchdog::new(p.IWDG, WATCHDOG_TIMEOUT_US);
    watchdog.unleash();

    let output = Output::new(p.PC1, Level::Low, Speed::Low);
    let input = Input::new(p.PC0, Pull::Down);

    let switches = [
        Input::new(p.PC2, Pull::Down),
        Input::new(p.PC3, Pull::Down),
        Input::new(p.PC4, Pull::Down),
        Input::new(p.PC5, Pull::Down),
        Input::new(p.PC6, Pull::Down),
        Input::new(p.PC7, Pull::Down),
        Input::new(p.PC8, Pull::Down),
    ];
    let read_switches = || {
        switches
            .iter()
            .enumerate()
            .fold(0u8, |id, (bit, pin)| id | (u8::from(pin.is_high()) << bit))
    };
    let first = read_switches();
    Timer::after_millis(1).await;
    let node_id = match crate::node_id_from_switches(first, read_switches()) {
        Ok(id) => {
            defmt::info!("node-ID {=u8} from the switches", id.raw());
            id
        }
        Err(fault) => {
            defmt::error!("node-ID switches refused: {}", fault);
            halt_safe("no valid node-ID");
        }
    };
    drop(switches);

    let mut can = Can::new(p.CAN1, p.PB8, p.PB9, Irqs);
    // `Can::set_bitrate` unwraps the timing calculation, which links the `Debug` formatting of
    // its error into the image (`docs/footprint.md`); the same calculation, refused by name.
    let clock = embassy_stm32::rcc::frequency::<embassy_stm32::peripherals::CAN1>();
    match embassy_stm32::can::util::calc_can_timings(clock, BIT_RATE) {
        // The configuration leaves initialisation mode when it is dropped, as in `set_bitrate`.
        Ok(timing) => drop(can.modify_config().set_bit_timing(timing)),
        Err(_) => halt_safe("no CAN bit timing for 500 kbit/s from the APB1 clock"),
    }
    match loopback_test(&mut can, &mut watchdog).await {
        Ok(()) => defmt::info!("self-test: CAN loop-back (3 mailboxes, 2 FIFOs, filters) passed"),
        Err(fault) => {
            defmt::error!("self-test: CAN loop-back failed {}", fault);
            halt_safe("CAN controller self-test failed");
        }
    }
    static LINK_TX_BUF: StaticCell<[u8; 256]> = StaticCell::new();
    static LINK_RX_BUF: StaticCell<[u8; 256]> = StaticCell::new();
    let mut link_config = usart::Config::default();
    link_config.baudrate = LINK_BAUD;
    let uart = match BufferedUart::new(
        p.USART3,
        p.PB11,
        p.PB10,
        LINK_TX_BUF.init([0; 256]),
        LINK_RX_BUF.init([0; 256]),
        Irqs,
        link_config,
    ) {
        Ok(link) => link,
        Err(_) => halt_safe("link USART configuration refused"),
    };
    // In a static, split by reference: splitting by value moved the halves through the
    // task's state with a `memmove` (1,574 bytes of compiler-builtins, `docs/footprint.md`).
    static LINK: StaticCell<BufferedUart<'static>> = StaticCell::new();
    let (link_tx, link_rx): (BufferedUartTx<'static>, BufferedUartRx<'static>) =
        LINK.init(uart).split_ref();
    // No filter bank enabled: the controller takes no frame until the channel loop has
    // programmed the node's filters (its first service, before the core boots).
    can.modify_filters().clear();
    can.enable().await;
    // `can` stays alive (its drop would reset the controller); its halves go to the tasks.
    let (can_tx, can_rx) = can.split();
    spawner.spawn(can_tx_task(can_tx).unwrap_or_else(|_| halt_safe("CAN task")));
    spawner.spawn(link_tx_task(link_tx).unwrap_or_else(|_| halt_safe("link task")));

    if !crate::self_tests() {
        halt_safe("start-up self-test failed");
    }
    let parameters = SectorSlots::new(
        Stm32Sectors {
            flash: embassy_stm32::flash::Flash::new_blocking(p.FLASH),
        },
        STM32F405_SLOTS,
    );
    let config = (device.describe)(node_id);
    // Kept as built and borrowed, not moved out of its `Ok`: the move took the runtime
    // (3,584 bytes) through this task's stack frame (`docs/footprint.md`).
    let mut built = Runtime::new(config, parameters, role, now(), LINK_PERIOD);
    let runtime = match &mut built {
        Ok(runtime) => runtime,
        Err(_) => halt_safe("device description refused"),
    };
    let mut channel = ChannelLoop::new(device.pins);
    let mut driver = HwDriver {
        can: can_rx,
        link: link_rx,
        input,
        output,
        sequencer: Sequencer::new(),
        frame: None,
        link_bytes: [0; 64],
        link_count: 0,
    };
    let mut stack_reported = 0;
    loop {
        let wake = channel.service(runtime, &mut driver);
        watchdog.pet();
        let stack = crate::stack::used();
        if stack > stack_reported {
            stack_reported = stack;
            defmt::info!("stack high-water mark: {=usize} bytes", stack);
        }
        // What the wait takes (one frame, some link bytes) is kept for the next service.
        match select3(
            driver.can.read(),
            driver.link.read(&mut driver.link_bytes),
            Timer::at(embassy_instant(wake)),
        )
        .await
        {
            Either3::First(Ok(envelope)) => driver.frame = from_bxcan(&envelope.frame),
            Either3::First(Err(error)) => defmt::warn!("CAN bus error {}", error),
            Either3::Second(Ok(count)) => driver.link_count = count,
            Either3::Second(Err(_)) => defmt::warn!("link read error"),
            Either3::Third(()) => {}
        }
    }
}

/// A fault before the runtime runs: outputs stay low (their reset state), the watchdog is
/// not fed, and the MCU resets into the same check.
fn halt_safe(why: &str) -> ! {
    defmt::error!("halting in the safe state: {=str}", why);
    loop {
        cortex_m::asm::wfi();
    }
}
