//! The hardware board layer: embassy-stm32 on the STM32F405RG.
//!
//! Reference wiring (both MCUs alike): CAN1 RX PB8 / TX PB9 to the shared transceiver, the
//! link on USART3 TX PB10 / RX PB11 (crossed to the other MCU), the channel's safety input on
//! PC0 (its own contact, closed = 1), its safety output on PC1 (its own relay, 1 = enabled),
//! the node-ID switches on PC2 (bit 0) to PC8 (bit 6), closed = 1, read at start-up,
//! 8 MHz HSE crystal.
//!
//! One task owns the channel runtime and wakes for whatever comes first: a CAN frame, link
//! bytes, the runtime's next deadline or the 1 ms input sample. Two small tasks move frames
//! between the bxCAN and static channels, and drain the link transmit pipe into the USART. The
//! independent watchdog is fed by the runtime loop only.

use dual_channel::can_loopback::{LoopbackController, LoopbackFault, Received};
use dual_channel::runtime::{ChannelEvent, Io, Role, Runtime};
use embassy_executor::Spawner;
use embassy_futures::select::{Either4, select4};
use embassy_stm32::can::filter::{ListEntry32, Mask32};
use embassy_stm32::can::{
    Can, Fifo, Frame, Rx0InterruptHandler, Rx1InterruptHandler, SceInterruptHandler, StandardId,
    TxInterruptHandler,
};
use embassy_stm32::gpio::{Input, Level, Output, Pull, Speed};
use embassy_stm32::peripherals::{CAN1, IWDG, USART3};
use embassy_stm32::time::Hertz;
use embassy_stm32::usart::{self, BufferedUart, BufferedUartRx, BufferedUartTx};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{Config, bind_interrupts};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_sync::pipe::Pipe;
use embassy_sync::priority_channel::{Min, PriorityChannel};
use embassy_time::Timer;
use embedded_io_async::{Read, Write};
use shared::canopen::storage::StorageError;
use shared::safety::types::SrdoNumber;
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
/// Inputs are sampled this often.
pub const SAMPLE_PERIOD: Duration = Duration::from_millis(1);
/// The watchdog bites when the runtime loop has not run for this long.
pub const WATCHDOG_TIMEOUT_US: u32 = 20_000;

/// Frames received, for the runtime task.
static CAN_RX: Channel<CriticalSectionRawMutex, CanFrame, 32> = Channel::new();
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

/// What the runtime hands out, applied to the hardware.
struct BoardIo<'a, 'd> {
    output: &'a mut Output<'d>,
    /// Numbers the frames handed to [`CAN_TX`], for their order within one identifier.
    sequencer: Sequencer,
}

impl Io for BoardIo<'_, '_> {
    fn transmit(&mut self, frame: CanFrame) {
        if CAN_TX.try_send(self.sequencer.queue(frame)).is_err() {
            // A full transmit queue loses the frame: the consumers' timers catch it.
            defmt::warn!(
                "CAN transmit queue full, frame {=u16:X} dropped",
                frame.id().raw()
            );
        }
    }

    fn link(&mut self, bytes: &[u8]) {
        if LINK_TX
            .try_write(bytes)
            .map_or(true, |written| written < bytes.len())
        {
            // The other channel sees a sequence gap or a corrupt frame: a fault, safe state.
            defmt::warn!("link transmit pipe full");
        }
    }

    fn output(&mut self, _srdo: SrdoNumber, data: u64) {
        // One relay per channel: energised only for a non-zero confirmed value.
        self.output
            .set_level(if data != 0 { Level::High } else { Level::Low });
    }

    fn event(&mut self, event: ChannelEvent) {
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

#[embassy_executor::task]
async fn can_task(mut can: Can<'static>) {
    can.modify_filters()
        .clear()
        .enable_bank(0, Fifo::Fifo0, Mask32::accept_all());
    can.enable().await;
    let (mut tx, mut rx) = can.split();
    loop {
        match embassy_futures::select::select(rx.read(), CAN_TX.receive()).await {
            embassy_futures::select::Either::First(Ok(envelope)) => {
                if let Some(frame) = from_bxcan(&envelope.frame) {
                    if CAN_RX.try_send(frame).is_err() {
                        defmt::warn!("CAN receive queue full");
                    }
                }
            }
            embassy_futures::select::Either::First(Err(error)) => {
                defmt::warn!("CAN bus error {}", error);
            }
            embassy_futures::select::Either::Second(queued) => {
                if let Some(frame) = to_bxcan(&queued.frame) {
                    tx.write(&frame).await;
                }
            }
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
    let input_objects = device.inputs;
    let p = embassy_stm32::init(clocks());
    let mut watchdog = IndependentWatchdog::new(p.IWDG, WATCHDOG_TIMEOUT_US);
    watchdog.unleash();

    let mut output = Output::new(p.PC1, Level::Low, Speed::Low);
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
    let link = match BufferedUart::new(
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
    let (link_tx, mut link_rx): (BufferedUartTx<'static>, BufferedUartRx<'static>) = link.split();
    spawner.spawn(can_task(can).unwrap_or_else(|_| halt_safe("CAN task")));
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
    let mut runtime = match Runtime::new(config, parameters, role, now(), LINK_PERIOD) {
        Ok(runtime) => runtime,
        Err(_) => halt_safe("device description refused"),
    };
    let mut io = BoardIo {
        output: &mut output,
        sequencer: Sequencer::new(),
    };
    let mut sampled: Option<bool> = None;
    let mut next_sample = now();
    let mut link_buf = [0u8; 64];
    let mut stack_reported = 0;
    loop {
        let deadline = runtime.poll(now(), &mut io);
        watchdog.pet();
        let stack = crate::stack::used();
        if stack > stack_reported {
            stack_reported = stack;
            defmt::info!("stack high-water mark: {=usize} bytes", stack);
        }
        let wake = deadline.min(next_sample);
        match select4(
            CAN_RX.receive(),
            link_rx.read(&mut link_buf),
            Timer::at(embassy_instant(wake)),
            core::future::pending::<()>(),
        )
        .await
        {
            Either4::First(frame) => runtime.on_frame(now(), &frame, &mut io),
            Either4::Second(Ok(n)) => {
                let at = now();
                for &byte in &link_buf[..n] {
                    runtime.on_link_byte(at, byte, &mut io);
                }
            }
            Either4::Second(Err(_)) => defmt::warn!("link read error"),
            Either4::Third(()) | Either4::Fourth(()) => {}
        }
        let at = now();
        if at >= next_sample {
            next_sample = at + SAMPLE_PERIOD;
            let level = input.is_high();
            if sampled != Some(level) {
                sampled = Some(level);
                let value = [u8::from(level)];
                if runtime
                    .set_input(
                        at,
                        input_objects.plain,
                        input_objects.inverted,
                        &value,
                        &mut io,
                    )
                    .is_err()
                {
                    defmt::error!("input object refused");
                }
            }
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
