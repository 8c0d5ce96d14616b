//! The bxCAN's interrupts as wake-ups of the channel loop, for the driver that leaves the
//! controller to the loop ([`super::can1`]).
//!
//! Each handler masks its own line in the NVIC and sets its flag; the loop clears the flag and
//! unmasks the lines again before it checks whether to sleep, so no handler touches the
//! controller and a condition already pending wakes it at once (the lines are
//! level-triggered, RM0090 32.8: FIFO not empty with FMPIEx, a mailbox's request completed
//! with TMEIE).

use core::sync::atomic::{AtomicBool, Ordering};

use embassy_stm32::interrupt::typelevel::{self, Binding, Handler, Interrupt as _};

embassy_stm32::bind_interrupts!(
    /// The bxCAN's receive and transmit lines, bound to this module's handlers.
    pub struct Irqs {
    CAN1_RX0 => WakeOnReceive;
    CAN1_RX1 => WakeOnReceive;
    CAN1_TX => WakeOnTransmit;
});

/// An interrupt line's wake-up of the loop: a flag its handler sets.
pub struct Wakeup {
    fired: AtomicBool,
}

impl Wakeup {
    const fn new() -> Self {
        Wakeup {
            fired: AtomicBool::new(false),
        }
    }

    fn fire(&self) {
        self.fired.store(true, Ordering::Release);
    }

    /// Forgets an earlier firing and puts the lines back into the NVIC with `unmask`: a
    /// condition already pending fires again at once, none is missed.
    pub fn arm(&self, unmask: impl Fn()) {
        self.fired.store(false, Ordering::Relaxed);
        unmask();
    }

    /// Whether a handler fired since [`Wakeup::arm`].
    pub fn fired(&self) -> bool {
        self.fired.load(Ordering::Acquire)
    }
}

/// A frame is waiting in a receive FIFO.
pub static RECEIVED: Wakeup = Wakeup::new();
/// A transmit mailbox completed its request.
pub static MAILBOX_FREE: Wakeup = Wakeup::new();

/// The receive FIFOs' handler (FMPIE0, FMPIE1): masks its line, wakes the loop.
pub struct WakeOnReceive;

impl Handler<typelevel::CAN1_RX0> for WakeOnReceive {
    unsafe fn on_interrupt() {
        typelevel::CAN1_RX0::disable();
        RECEIVED.fire();
    }
}

impl Handler<typelevel::CAN1_RX1> for WakeOnReceive {
    unsafe fn on_interrupt() {
        typelevel::CAN1_RX1::disable();
        RECEIVED.fire();
    }
}

/// The transmit mailboxes' handler (TMEIE): masks its line, wakes the loop.
pub struct WakeOnTransmit;

impl Handler<typelevel::CAN1_TX> for WakeOnTransmit {
    unsafe fn on_interrupt() {
        typelevel::CAN1_TX::disable();
        MAILBOX_FREE.fire();
    }
}

/// Puts the receive lines back into the NVIC. A line whose FIFO is empty now first loses the
/// pending state it took while masked: the FIFO that raised it was still full when the
/// handler returned (the line is level-triggered, ARMv7-M B3.4.1, so it pended again behind
/// the mask), and the loop has read the FIFO since; left pending, it would wake the loop at
/// once for nothing, an iteration per frame received. A FIFO that holds a frame keeps its
/// line pending, and wakes the loop at once, as before.
pub fn unmask_receive() {
    let can = embassy_stm32::pac::CAN1;
    if can.rfr(0).read().fmp() == 0 {
        typelevel::CAN1_RX0::unpend();
    }
    if can.rfr(1).read().fmp() == 0 {
        typelevel::CAN1_RX1::unpend();
    }
    // SAFETY: the handlers share nothing with the task but the `Wakeup` atomics, and no
    // critical section of this program relies on these lines being masked.
    unsafe {
        typelevel::CAN1_RX0::enable();
        typelevel::CAN1_RX1::enable();
    }
}

/// Puts the transmit line back into the NVIC; as [`unmask_receive`], a line pending from a
/// completion the driver has acknowledged since (no RQCP set) loses its pending state first.
pub fn unmask_transmit() {
    let status = embassy_stm32::pac::CAN1.tsr().read();
    if !(0..3).any(|mailbox| status.rqcp(mailbox)) {
        typelevel::CAN1_TX::unpend();
    }
    // SAFETY: as `unmask_receive`.
    unsafe { typelevel::CAN1_TX::enable() }
}

/// The interrupts are bound to this module's handlers.
pub fn bound(
    _: impl Binding<typelevel::CAN1_RX0, WakeOnReceive>
    + Binding<typelevel::CAN1_RX1, WakeOnReceive>
    + Binding<typelevel::CAN1_TX, WakeOnTransmit>,
) {
}
