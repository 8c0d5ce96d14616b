//! The channel's time base and its wake-up alarm on TIM2 (RM0090 18, general-purpose timers
//! TIM2 to TIM5), the board's own: a free-running 32-bit counter at 1 MHz, extended to the
//! protocol core's 64-bit microseconds in software, and output-compare channel 1 as the
//! alarm that wakes the loop at the instant it asked for.
//!
//! Why not embassy-time's TIM2 driver: the images have no async executor (the loop waits with
//! `wfi`, [`super::run`]), and that driver's alarms exist to serve an executor's timer queue;
//! what the loop needs is one clock reading and one alarm.
//!
//! - Time base (RM0090 18.3.1, 18.3.2): CK_CNT = the APB1 timer clock / (PSC + 1), PSC
//!   taken at the update event the start forces (EGR.UG); ARR = 2^32 - 1, so the counter runs
//!   0 to 2^32 - 1 and wraps every 71.6 minutes.
//! - [`now`] extends the counter ([`crate::counter::Extended`], host-tested): a reading below
//!   the last one means the counter wrapped once since. The loop reads the clock at every wake-up and wakes at least every input sample
//!   period (`dual_channel::channel_loop::SAMPLE_PERIOD`); the longest it does not is a store's
//!   flash erase at start-up, seconds, never a wrap's 71 minutes.
//! - The alarm (18.3.8): CC1IF is set when the counter reaches CCR1, and with CC1IE the
//!   timer's interrupt (IRQ 28) is raised; its handler only clears CC1IE, so that the core
//!   wakes (`wfi`) and the line does not stay pending.

use core::sync::atomic::{AtomicU32, Ordering};

use crate::counter::Extended;
use embassy_stm32::interrupt::typelevel::{self, Handler, Interrupt as _};
use embassy_stm32::pac;
use shared::{Duration, Instant};

/// The counter's frequency: one tick per microsecond, the protocol core's unit.
const TICK_HZ: u32 = 1_000_000;
/// The longest an alarm is set ahead: a loop never asks for more than an input sample period
/// ahead; this bounds a wrong deadline to one wake-up per second, far inside the counter's
/// 71-minute range, so that the 32-bit compare never matches a later round of the counter.
const LONGEST_ALARM: Duration = Duration::from_millis(1000);

/// The counter's last reading and its wraps ([`now`], [`Extended::parts`]): written by the
/// thread only, so two atomics without a lock do.
static LAST: AtomicU32 = AtomicU32::new(0);
/// See [`LAST`].
static WRAPS: AtomicU32 = AtomicU32::new(0);

/// Starts TIM2 as the time base at 1 MHz from `timer_clock` (the APB1 timer clock, Hz);
/// `false` when that clock does not divide into whole microseconds within PSC's 16 bits.
pub fn start(timer_clock: u32) -> bool {
    let divider = timer_clock / TICK_HZ;
    if divider == 0 || timer_clock % TICK_HZ != 0 || divider > 1 << 16 {
        return false;
    }
    embassy_stm32::rcc::enable_and_reset::<embassy_stm32::peripherals::TIM2>();
    let tim = pac::TIM2;
    tim.cr1().modify(|w| w.set_cen(false));
    tim.psc().write_value((divider - 1) as u16);
    tim.arr().write_value(u32::MAX);
    // The update event loads PSC (18.3.1) and clears the counter; its flag is not wanted.
    tim.egr().write(|w| w.set_ug(true));
    tim.sr().write_value(pac::timer::regs::SrGp16(0));
    tim.dier().write_value(pac::timer::regs::DierGp16(0));
    tim.cr1().modify(|w| w.set_cen(true));
    LAST.store(0, Ordering::Relaxed);
    WRAPS.store(0, Ordering::Relaxed);
    typelevel::TIM2::unpend();
    // SAFETY: the handler touches only TIM2's DIER, which the thread reads and writes only
    // with the line's interrupt unable to preempt in between (`arm` writes CCR1 and SR
    // before it sets CC1IE in one write).
    unsafe { typelevel::TIM2::enable() };
    true
}

/// The time since [`start`], in microseconds. Called by the thread only (the channel loop and
/// the start-up), at least once per wrap of the counter (see the module's documentation).
#[inline(never)]
pub fn now() -> Instant {
    let mut counter =
        Extended::from_parts(LAST.load(Ordering::Relaxed), WRAPS.load(Ordering::Relaxed));
    let micros = counter.read(pac::TIM2.cnt().read());
    let (last, wraps) = counter.parts();
    LAST.store(last, Ordering::Relaxed);
    WRAPS.store(wraps, Ordering::Relaxed);
    Instant::from_micros(micros)
}

/// Sets the alarm to `at`, or to [`LONGEST_ALARM`] after `now` when `at` is later: the
/// timer's interrupt is raised when the counter reaches it. The instant it was set to, which
/// the caller waits for ([`due`]); `None` when that is not after `now` (or has passed since):
/// the caller does not wait.
pub fn arm(at: Instant, now: Instant) -> Option<Instant> {
    if at <= now {
        return None;
    }
    let at = at.min(now + LONGEST_ALARM);
    let tim = pac::TIM2;
    tim.dier().write(|w| w.set_ccie(0, false));
    tim.ccr(0).write_value(at.as_micros() as u32);
    // Only CC1IF cleared: writing 1 to a flag leaves it as it is (18.4.5).
    let mut clear = pac::timer::regs::SrGp16(u32::MAX);
    clear.set_ccif(0, false);
    tim.sr().write_value(clear);
    tim.dier().write(|w| w.set_ccie(0, true));
    // The counter may have passed CCR1 between the caller's reading and the write (the
    // compare is an equality, 18.3.8): then the flag is never set, and the caller must not
    // wait for it.
    (self::now() < at).then_some(at)
}

/// Whether the instant the alarm was set to has come.
pub fn due(at: Instant) -> bool {
    shared::time::expired(at, now())
}

/// TIM2's interrupt (RM0090 Table 61, IRQ 28): the alarm. It masks itself (CC1IE cleared)
/// and leaves the rest to the loop, which the interrupt woke.
pub struct Alarm;

impl Handler<typelevel::TIM2> for Alarm {
    unsafe fn on_interrupt() {
        pac::TIM2.dier().write(|w| w.set_ccie(0, false));
    }
}

/// Spins until `duration` has passed on the time base.
pub fn delay(duration: Duration) {
    let until = now() + duration;
    while !due(until) {}
}
