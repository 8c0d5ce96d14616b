//! Virtual time of the emulated MCU and the clock frequencies the peripherals count in.

/// An instant of virtual time, in nanoseconds since power-on.
pub type Nanos = u64;

/// The clock frequencies (Hz) the RCC model reports (RM0090 6.2): what the core and each bus
/// run at now. Peripheral models derive their own timing from these (a USART's byte time
/// from its BRR and its bus clock, a timer's tick from its bus clock).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Clocks {
    /// SYSCLK: the core and SysTick (with CLKSOURCE = 1).
    pub sysclk: u32,
    /// HCLK: AHB.
    pub hclk: u32,
    /// PCLK1: APB1 (bxCAN, USART3, TIM2's bus).
    pub pclk1: u32,
    /// PCLK2: APB2.
    pub pclk2: u32,
}

impl Clocks {
    /// After reset: everything on the 16 MHz HSI (RM0090 6.2.2).
    pub const RESET: Clocks = Clocks {
        sysclk: 16_000_000,
        hclk: 16_000_000,
        pclk1: 16_000_000,
        pclk2: 16_000_000,
    };

    /// The APB1 timers' clock: PCLK1, doubled when the APB1 prescaler is not 1 (RM0090 6.2,
    /// "the timer clock frequencies are automatically set").
    pub fn apb1_timers(&self) -> u32 {
        if self.pclk1 == self.hclk {
            self.pclk1
        } else {
            self.pclk1.saturating_mul(2)
        }
    }

    /// `cycles` of a clock of `hz`, in nanoseconds (rounded up: an event is never early).
    pub fn nanos(cycles: u64, hz: u32) -> Nanos {
        let hz = u64::from(hz.max(1));
        (u128::from(cycles) * 1_000_000_000).div_ceil(u128::from(hz)) as u64
    }
}
