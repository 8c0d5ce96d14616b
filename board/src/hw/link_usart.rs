//! The link's USART3, interrupt-driven by our own handler (RM0090 30.6), and why it is not
//! embassy-stm32's buffered USART.
//!
//! embassy-stm32's `BufferedUart` (0.6) clears the IDLE and overrun flags of the F4's USART
//! by the sequence RM0090 30.6.1 prescribes, a read of SR followed by a read of DR, and it
//! does so in every interrupt in which SR shows IDLE, also when RXNE is clear. A byte that
//! completes between those two reads is taken out of DR by the second one and never pushed
//! into the receive ring: it is lost without a flag. Its authors name the race
//! (embassy-rs/embassy pull request 1561: "a character could arrive after checking SR, but
//! before reading DR"). On the link it costs a COBS code byte now and then, the other channel
//! latches "link message malformed" (11h), and a node in fault-free operation goes to its
//! safe state: the shipped images showed it on the emulated STM32F405, in the
//! emergency-stop scenario, when the IDLE interrupt of one message ran after the first byte
//! of the next one had begun.
//!
//! This handler reads DR only when SR shows RXNE (RM0090 30.6.1: RXNE "cleared by a read to
//! the USART_DR register"; an overrun, noise, framing or parity flag is cleared by the same
//! SR-then-DR sequence and always comes with RXNE set, the byte in DR being the one before
//! the overrun). IDLE detection is not enabled (IDLEIE stays 0): the loop is woken instead
//! when a frame delimiter arrives ([`DELIMITER`]) or the receive queue is half full, so the
//! IDLE flag is never cleared and never needs to be. Transmission: TXE with TXEIE (RM0090
//! 30.6.4), one byte from the transmit queue per interrupt, TXEIE cleared when it is empty.
//!
//! The set-up is ours too ([`set_up`]: clock, pins, BRR, TE and RE, RM0090 30.6), no longer
//! embassy-stm32's `Uart::new_blocking`, whose general configuration (every parity, stop bit,
//! oversampling and driver-enable choice of every STM32 family) the link does not use. The
//! emulator's USART model (written from RM0090, `emulator/src/peripherals/usart.rs`) runs this
//! driver in the shipped images.

use core::cell::RefCell;
use core::sync::atomic::{AtomicBool, Ordering};
use dual_channel::byte_ring::ByteRing;
use embassy_stm32::Peri;
use embassy_stm32::gpio::{AfType, Flex, OutputType, Pull, Speed};
use embassy_stm32::interrupt::typelevel::{self, Handler, Interrupt};
use embassy_stm32::pac;
use embassy_stm32::peripherals::{PB10, PB11, USART3};
use embassy_stm32::usart::{RxPin, TxPin};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;

use dual_channel::link::DELIMITER;
/// Receive queue, bytes: what arrives while the loop is busy.
const RX_BYTES: usize = 256;
/// Transmit queue, bytes (the link's transmit queue: `super::LINK_TX_BYTES`).
const TX_BYTES: usize = super::LINK_TX_BYTES;

type Shared<T> = Mutex<CriticalSectionRawMutex, RefCell<T>>;

/// Bytes received, oldest first, and how many frame delimiters are among them.
struct Received {
    bytes: ByteRing<RX_BYTES>,
    delimiters: usize,
}

impl Received {
    /// Whether the loop has something worth an iteration: a whole frame, or a queue half full.
    fn worth_reading(&self) -> bool {
        self.delimiters > 0 || self.bytes.len() >= RX_BYTES / 2
    }
}

/// Bytes received.
static RX: Shared<Received> = Mutex::new(RefCell::new(Received {
    bytes: ByteRing::new(),
    delimiters: 0,
}));
/// Bytes to send, oldest first.
static TX: Shared<ByteRing<TX_BYTES>> = Mutex::new(RefCell::new(ByteRing::new()));
/// A byte was lost since the last [`take_lost`]: the receive queue was full, or the USART
/// overran (its one-byte DR was not read in time).
static LOST: AtomicBool = AtomicBool::new(false);
/// The receive queue is worth a loop iteration ([`Received::worth_reading`]) or a byte was
/// lost: set by the handler, recomputed by [`read`] under the queue's lock, read by the
/// loop's sleep without taking the lock ([`readable`]), which it checks at every wake-up, a
/// byte's interrupt included.
static READABLE: AtomicBool = AtomicBool::new(false);

/// The USART3 interrupt: receive what RXNE says is there, send what TXE asks for.
pub struct LinkInterrupt;

impl Handler<typelevel::USART3> for LinkInterrupt {
    unsafe fn on_interrupt() {
        let usart = pac::USART3;
        let status = usart.sr().read();
        if status.rxne() {
            // RM0090 30.6.1: this read after the SR read clears RXNE and, with them, ORE,
            // NF, FE and PE; DR holds the byte received (the one before an overrun).
            let byte = usart.dr().read().dr() as u8;
            RX.lock(|rx| {
                let mut rx = rx.borrow_mut();
                let kept = rx.bytes.push(byte);
                if kept && byte == DELIMITER {
                    rx.delimiters += 1;
                }
                if !kept || status.ore() {
                    LOST.store(true, Ordering::Relaxed);
                }
                // The loop, woken by this interrupt, looks at the flag ([`readable`]).
                if !kept || status.ore() || rx.worth_reading() {
                    READABLE.store(true, Ordering::Relaxed);
                }
            });
        }
        if status.txe() && usart.cr1().read().txeie() {
            TX.lock(|tx| match tx.borrow_mut().pop() {
                // RM0090 30.6.1: a write to DR clears TXE.
                Some(byte) => usart.dr().write(|w| w.set_dr(u16::from(byte))),
                None => usart.cr1().modify(|w| w.set_txeie(false)),
            });
        }
    }
}

/// USART3 and the link's pins, set up by [`set_up`]: kept for as long as the link runs (a
/// dropped pin returns to its reset state).
pub struct LinkUsart {
    _usart: Peri<'static, USART3>,
    _rx: Flex<'static>,
    _tx: Flex<'static>,
}

/// Sets USART3 up for the link (RM0090 30.6): its clock enabled and the block reset, PB11 as
/// RX and PB10 as TX (their alternate function), 8 data bits, no parity, one stop bit (CR1 M,
/// PCE, CR2 STOP at their reset values), oversampling by 16, `baud` from the APB1 clock
/// (30.6.3: BRR holds USARTDIV in sixteenths, the clock over the baud rate, rounded), then
/// UE, TE and RE. `None` when the baud rate is out of BRR's reach.
pub fn set_up(
    usart: Peri<'static, USART3>,
    rx: Peri<'static, PB11>,
    tx: Peri<'static, PB10>,
    baud: u32,
) -> Option<LinkUsart> {
    let clock = embassy_stm32::rcc::frequency::<USART3>().0;
    let divider = clock.checked_add(baud / 2)?.checked_div(baud)?;
    // The mantissa is at least 1 (RM0090 30.6.3) and BRR has 16 bits.
    let divider = u16::try_from(divider)
        .ok()
        .filter(|&divider| divider >= 16)?;
    let (rx_af, tx_af) = (RxPin::<USART3>::af_num(&*rx), TxPin::<USART3>::af_num(&*tx));
    let mut rx = Flex::new(rx);
    rx.set_as_af_unchecked(rx_af, AfType::input(Pull::None));
    let mut tx = Flex::new(tx);
    tx.set_as_af_unchecked(tx_af, AfType::output(OutputType::PushPull, Speed::Medium));
    embassy_stm32::rcc::enable_and_reset::<USART3>();
    let registers = pac::USART3;
    registers
        .brr()
        .write_value(pac::usart::regs::Brr(u32::from(divider)));
    registers.cr1().write(|w| {
        w.set_ue(true);
        w.set_te(true);
        w.set_re(true);
    });
    Some(LinkUsart {
        _usart: usart,
        _rx: rx,
        _tx: tx,
    })
}

/// Starts the driver on a USART3 that [`set_up`] set up (clock, pins, BRR, TE and RE):
/// empties the queues, enables RXNEIE and the interrupt in the NVIC.
pub fn start() {
    RX.lock(|rx| {
        let mut rx = rx.borrow_mut();
        rx.bytes.clear();
        rx.delimiters = 0;
    });
    TX.lock(|tx| tx.borrow_mut().clear());
    LOST.store(false, Ordering::Relaxed);
    pac::USART3.cr1().modify(|w| {
        w.set_rxneie(true);
        w.set_idleie(false);
        w.set_txeie(false);
    });
    typelevel::USART3::unpend();
    // SAFETY: the handler bound to USART3 is [`LinkInterrupt`], whose shared state is behind
    // critical sections and atomics; enabling it breaks no critical section in progress (the
    // caller is the channel's task, outside any).
    unsafe { typelevel::USART3::enable() };
}

/// Queues `bytes` whole for sending, or none of them (`false`: no room).
pub fn write(bytes: &[u8]) -> bool {
    TX.lock(|tx| {
        // The whole message in one copy, or nothing when it does not fit.
        if !tx.borrow_mut().extend(bytes) {
            return false;
        }
        // Inside the critical section: the handler clears TXEIE under the same lock.
        pac::USART3.cr1().modify(|w| w.set_txeie(true));
        true
    })
}

/// Moves the bytes received into `buf`, oldest first; how many.
pub fn read(buf: &mut [u8]) -> usize {
    RX.lock(|rx| {
        let mut rx = rx.borrow_mut();
        let count = rx.bytes.take_into(buf);
        // The delimiters taken out with them leave the count.
        let taken = buf
            .get(..count)
            .unwrap_or_default()
            .iter()
            .filter(|&&byte| byte == DELIMITER)
            .count();
        rx.delimiters = rx.delimiters.saturating_sub(taken);
        READABLE.store(
            rx.worth_reading() || LOST.load(Ordering::Relaxed),
            Ordering::Relaxed,
        );
        count
    })
}

/// Whether a byte was lost since the last call (and forgets it).
pub fn take_lost() -> bool {
    LOST.swap(false, Ordering::Relaxed)
}

/// Whether the loop has link bytes worth an iteration: a whole frame waits in the receive
/// queue (its delimiter came), the queue is half full, or a byte was lost. The bytes of a
/// frame still arriving wait for its delimiter: the loop reads them with the next wake-up,
/// and does not iterate once per byte (an iteration outlasts a byte on the line).
pub fn readable() -> bool {
    READABLE.load(Ordering::Relaxed)
}
