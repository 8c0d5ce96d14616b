//! The exception model of the Cortex-M4 (ARMv7-M ARM B1.5): which exceptions are enabled,
//! pending and active, their priorities and grouping (AIRCR.PRIGROUP), the execution priority
//! with PRIMASK, FAULTMASK and BASEPRI, and the choice of the exception to take next.
//!
//! Pure state: the NVIC (B3.4) and the SCB (B3.2) registers are views of it, and the CPU side
//! stacks and unstacks the frames (B1.5.6, B1.5.8).

/// Interrupt lines of the STM32F405 (RM0090 Table 61: positions 0 to 81).
pub const IRQ_LINES: usize = 82;
/// Exception numbers 0 to 15 are the system's, 16 onwards the interrupt lines (B1.5.2).
pub const FIRST_IRQ: u32 = 16;
/// All exception numbers.
pub const EXCEPTIONS: usize = FIRST_IRQ as usize + IRQ_LINES;
/// Bits of priority the STM32F4 implements (PM0214 4.3.7: the upper four of each byte).
pub const PRIORITY_BITS: u32 = 4;

/// Exception numbers of the system exceptions (B1.5.2).
pub mod number {
    /// Reset.
    pub const RESET: u32 = 1;
    /// Non-maskable interrupt.
    pub const NMI: u32 = 2;
    /// HardFault.
    pub const HARD_FAULT: u32 = 3;
    /// MemManage fault.
    pub const MEM_MANAGE: u32 = 4;
    /// BusFault.
    pub const BUS_FAULT: u32 = 5;
    /// UsageFault.
    pub const USAGE_FAULT: u32 = 6;
    /// Supervisor call.
    pub const SVCALL: u32 = 11;
    /// Debug monitor.
    pub const DEBUG_MONITOR: u32 = 12;
    /// PendSV.
    pub const PENDSV: u32 = 14;
    /// SysTick.
    pub const SYSTICK: u32 = 15;
}

/// The special-purpose mask registers (B1.4.3) as the CPU holds them now.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Masks {
    /// PRIMASK.PM: raises the execution priority to 0.
    pub primask: bool,
    /// FAULTMASK.FM: raises the execution priority to -1.
    pub faultmask: bool,
    /// BASEPRI: when non-zero, raises the execution priority to its group priority.
    pub basepri: u8,
}

/// The exceptions' state.
#[derive(Clone, Debug)]
pub struct Exceptions {
    pending: [bool; EXCEPTIONS],
    active: [bool; EXCEPTIONS],
    /// NVIC_ISER for the interrupt lines; SHCSR's MEMFAULTENA, BUSFAULTENA, USGFAULTENA for
    /// exceptions 4 to 6; the others are always enabled.
    enabled: [bool; EXCEPTIONS],
    /// Priority bytes (B3.4 NVIC_IPR, B3.2 SHPR1-3), the unimplemented low bits zero.
    priority: [u8; EXCEPTIONS],
    /// AIRCR.PRIGROUP (B1.5.4).
    prigroup: u8,
}

impl Default for Exceptions {
    fn default() -> Self {
        Exceptions::new()
    }
}

impl Exceptions {
    /// The reset state: nothing pending or active, the interrupt lines and the configurable
    /// faults disabled, every priority 0, PRIGROUP 0 (B1.5.5 reset behaviour, B3.2 SHCSR).
    pub fn new() -> Exceptions {
        let mut enabled = [false; EXCEPTIONS];
        for n in [
            number::RESET,
            number::NMI,
            number::HARD_FAULT,
            number::SVCALL,
            number::DEBUG_MONITOR,
            number::PENDSV,
            number::SYSTICK,
        ] {
            enabled[n as usize] = true;
        }
        Exceptions {
            pending: [false; EXCEPTIONS],
            active: [false; EXCEPTIONS],
            enabled,
            priority: [0; EXCEPTIONS],
            prigroup: 0,
        }
    }

    fn valid(n: u32) -> bool {
        (n as usize) < EXCEPTIONS
    }

    /// Whether exception `n` is pending.
    pub fn is_pending(&self, n: u32) -> bool {
        Self::valid(n) && self.pending[n as usize]
    }

    /// Whether exception `n` is active.
    pub fn is_active(&self, n: u32) -> bool {
        Self::valid(n) && self.active[n as usize]
    }

    /// Whether exception `n` is enabled.
    pub fn is_enabled(&self, n: u32) -> bool {
        Self::valid(n) && self.enabled[n as usize]
    }

    /// Sets or clears the pending state of `n` (numbers outside the device are ignored).
    pub fn set_pending(&mut self, n: u32, pending: bool) {
        if Self::valid(n) {
            self.pending[n as usize] = pending;
        }
    }

    /// Sets or clears the active state of `n` (for AIRCR.VECTCLRACTIVE and tests).
    pub fn set_active(&mut self, n: u32, active: bool) {
        if Self::valid(n) {
            self.active[n as usize] = active;
        }
    }

    /// Enables or disables `n` (interrupt lines and the three configurable faults; the
    /// others stay enabled).
    pub fn set_enabled(&mut self, n: u32, enabled: bool) {
        let configurable = (number::MEM_MANAGE..=number::USAGE_FAULT).contains(&n) || n >= 16;
        if Self::valid(n) && configurable {
            self.enabled[n as usize] = enabled;
        }
    }

    /// The priority byte of `n` as software reads it (0 for the fixed-priority exceptions).
    pub fn priority_byte(&self, n: u32) -> u8 {
        if Self::valid(n) {
            self.priority[n as usize]
        } else {
            0
        }
    }

    /// Sets the priority byte of a configurable exception (4 and up); the bits the device
    /// does not implement read as zero (B1.5.4).
    pub fn set_priority_byte(&mut self, n: u32, value: u8) {
        if Self::valid(n) && n >= number::MEM_MANAGE {
            let implemented = !(0xFFu8 >> PRIORITY_BITS);
            self.priority[n as usize] = value & implemented;
        }
    }

    /// AIRCR.PRIGROUP.
    pub fn prigroup(&self) -> u8 {
        self.prigroup
    }

    /// Sets AIRCR.PRIGROUP (3 bits).
    pub fn set_prigroup(&mut self, prigroup: u8) {
        self.prigroup = prigroup & 7;
    }

    /// The priority of `n`: -3, -2, -1 for Reset, NMI and HardFault, the priority byte for
    /// the others (B1.5.4).
    pub fn priority(&self, n: u32) -> i16 {
        match n {
            number::RESET => -3,
            number::NMI => -2,
            number::HARD_FAULT => -1,
            _ => i16::from(self.priority_byte(n)),
        }
    }

    /// The group priority of a priority value: the bits above the subpriority field, whose
    /// width is PRIGROUP + 1 (B1.5.4). Negative priorities are their own group.
    pub fn group_of(&self, priority: i16) -> i16 {
        if priority < 0 {
            return priority;
        }
        let subpriority_bits = u32::from(self.prigroup) + 1;
        (priority >> subpriority_bits) << subpriority_bits
    }

    /// The execution priority (B1.5.4, pseudocode ExecutionPriority()): the highest group
    /// priority among the active exceptions, boosted by BASEPRI, PRIMASK and FAULTMASK; 256
    /// in Thread mode with nothing active or masked.
    pub fn execution_priority(&self, masks: Masks) -> i16 {
        let mut highest: i16 = 256;
        for n in 1..EXCEPTIONS as u32 {
            if self.active[n as usize] {
                highest = highest.min(self.group_of(self.priority(n)));
            }
        }
        let mut boosted: i16 = 256;
        if masks.basepri != 0 {
            boosted = self.group_of(i16::from(masks.basepri));
        }
        if masks.primask {
            boosted = 0;
        }
        if masks.faultmask {
            boosted = -1;
        }
        highest.min(boosted)
    }

    /// The pending and enabled exception of highest priority: lowest priority value, then
    /// lowest exception number (B1.5.4). Whether it may preempt is [`Exceptions::to_take`]'s.
    pub fn highest_pending(&self) -> Option<u32> {
        let mut best: Option<(i16, u32)> = None;
        for n in 1..EXCEPTIONS as u32 {
            if self.pending[n as usize] && self.enabled[n as usize] {
                let priority = self.priority(n);
                if best.is_none_or(|(p, _)| priority < p) {
                    best = Some((priority, n));
                }
            }
        }
        best.map(|(_, n)| n)
    }

    /// The exception to take now, if the highest pending one's group priority is higher
    /// (lower in value) than the execution priority (B1.5.4: preemption needs a strictly
    /// higher group priority).
    pub fn to_take(&self, masks: Masks) -> Option<u32> {
        let n = self.highest_pending()?;
        (self.group_of(self.priority(n)) < self.execution_priority(masks)).then_some(n)
    }

    /// Whether a pending exception is held back only by PRIMASK, FAULTMASK or BASEPRI (so
    /// that clearing them must be watched for).
    pub fn held_by_masks(&self, masks: Masks) -> bool {
        self.to_take(masks).is_none() && self.to_take(Masks::default()).is_some()
    }

    /// Exception entry's bookkeeping (B1.5.6 ExceptionTaken): `n` becomes active and stops
    /// being pending.
    pub fn activate(&mut self, n: u32) {
        if Self::valid(n) {
            self.pending[n as usize] = false;
            self.active[n as usize] = true;
        }
    }

    /// Exception return's bookkeeping (B1.5.8 DeActivate): `n` is no longer active.
    pub fn deactivate(&mut self, n: u32) {
        if Self::valid(n) {
            self.active[n as usize] = false;
        }
    }

    /// How many exceptions are active.
    pub fn active_count(&self) -> usize {
        self.active.iter().filter(|&&a| a).count()
    }

    /// Whether any interrupt line (not a system exception) is pending (ICSR.ISRPENDING).
    pub fn irq_pending(&self) -> bool {
        self.pending[FIRST_IRQ as usize..].iter().any(|&p| p)
    }

    /// Clears every active state (AIRCR.VECTCLRACTIVE, B3.2).
    pub fn clear_active(&mut self) {
        self.active = [false; EXCEPTIONS];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TIM2: u32 = FIRST_IRQ + 28;
    const USART3: u32 = FIRST_IRQ + 39;

    #[test]
    fn armv7m_b1_5_4_lowest_priority_value_then_lowest_number_is_taken_first() {
        let mut e = Exceptions::new();
        for n in [TIM2, USART3] {
            e.set_enabled(n, true);
            e.set_pending(n, true);
        }
        assert_eq!(e.highest_pending(), Some(TIM2));
        e.set_priority_byte(TIM2, 0x20);
        e.set_priority_byte(USART3, 0x10);
        assert_eq!(e.highest_pending(), Some(USART3));
    }

    #[test]
    fn armv7m_b1_5_4_unimplemented_priority_bits_read_as_zero() {
        let mut e = Exceptions::new();
        e.set_priority_byte(TIM2, 0xFF);
        assert_eq!(e.priority_byte(TIM2), 0xF0);
    }

    #[test]
    fn armv7m_b1_5_4_preemption_needs_a_higher_group_priority() {
        let mut e = Exceptions::new();
        e.set_enabled(TIM2, true);
        e.set_enabled(USART3, true);
        e.set_priority_byte(TIM2, 0x40);
        e.set_priority_byte(USART3, 0x50);
        e.activate(USART3);
        e.set_pending(TIM2, true);
        assert_eq!(e.to_take(Masks::default()), Some(TIM2));
        // PRIGROUP 5: bits [7:6] are the group, so 0x40 and 0x50 share group 0x40.
        e.set_prigroup(5);
        assert_eq!(e.to_take(Masks::default()), None);
    }

    #[test]
    fn armv7m_b1_5_4_primask_basepri_faultmask_raise_the_execution_priority() {
        let mut e = Exceptions::new();
        e.set_enabled(TIM2, true);
        e.set_priority_byte(TIM2, 0x40);
        e.set_pending(TIM2, true);
        let primask = Masks {
            primask: true,
            ..Masks::default()
        };
        assert_eq!(e.execution_priority(primask), 0);
        assert_eq!(e.to_take(primask), None);
        assert!(e.held_by_masks(primask));
        let basepri = Masks {
            basepri: 0x40,
            ..Masks::default()
        };
        assert_eq!(e.to_take(basepri), None);
        let basepri_lower = Masks {
            basepri: 0x50,
            ..Masks::default()
        };
        assert_eq!(e.to_take(basepri_lower), Some(TIM2));
        let faultmask = Masks {
            faultmask: true,
            ..Masks::default()
        };
        assert_eq!(e.execution_priority(faultmask), -1);
        // NMI (-2) still preempts FAULTMASK.
        e.set_pending(number::NMI, true);
        assert_eq!(e.to_take(faultmask), Some(number::NMI));
    }

    #[test]
    fn armv7m_b3_4_nvic_a_disabled_interrupt_stays_pending_and_is_not_taken() {
        let mut e = Exceptions::new();
        e.set_pending(TIM2, true);
        assert_eq!(e.to_take(Masks::default()), None);
        assert!(e.is_pending(TIM2));
        assert!(e.irq_pending());
        // The fixed exceptions cannot be disabled.
        e.set_enabled(number::SYSTICK, false);
        assert!(e.is_enabled(number::SYSTICK));
    }
}
