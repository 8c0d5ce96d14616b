//! The Cortex-M4 system part Unicorn lacks, modelled from the ARMv7-M Architecture Reference
//! Manual: the System Control Space (B3.2 SCB, B3.3 SysTick, B3.4 NVIC, B3.2 CPACR, the
//! FP extension's FPCCR), the DWT's cycle counter (C1.8) and DEMCR (C1.6, DEMCR).
//!
//! Pure register logic over [`exceptions::Exceptions`]: the CPU side (`crate::cpu`) routes the
//! private peripheral bus here, reads the special registers it needs from Unicorn, and does
//! exception entry and return.

pub mod exceptions;
pub mod systick;

use crate::peripherals::AccessError;
use exceptions::{Exceptions, FIRST_IRQ, IRQ_LINES, number};
use systick::SysTick;

/// Base of the System Control Space (B3.2).
pub const SCS_BASE: u32 = 0xE000_E000;
/// Base of the Data Watchpoint and Trace unit (C1.8.1).
pub const DWT_BASE: u32 = 0xE000_1000;

/// The block names of messages.
const SCS: &str = "System Control Space (ARMv7-M B3.2)";
const DWT: &str = "DWT (ARMv7-M C1.8)";

/// CPUID of the STM32F405's core: Cortex-M4 r0p1 (PM0214 4.4, CPUID: 0x410FC241).
pub const CPUID: u32 = 0x410F_C241;
/// AIRCR.VECTKEY: writes without it are ignored (B3.2, AIRCR).
const VECTKEY: u32 = 0x05FA;
/// CCR reset value (B3.2, CCR): STKALIGN set (PM0214 4.4, CCR: the Cortex-M4 resets it to 1).
const CCR_RESET: u32 = 1 << 9;
/// CCR bits software may write: NONBASETHRDENA, USERSETMPEND, UNALIGN_TRP, DIV_0_TRP,
/// BFHFNMIGN, STKALIGN.
const CCR_WRITABLE: u32 = (1 << 0) | (1 << 1) | (1 << 3) | (1 << 4) | (1 << 8) | (1 << 9);
/// CCR.STKALIGN.
pub const CCR_STKALIGN: u32 = 1 << 9;
/// CCR.NONBASETHRDENA.
pub const CCR_NONBASETHRDENA: u32 = 1 << 0;
/// SCR bits (B3.2, SCR): SLEEPONEXIT, SLEEPDEEP, SEVONPEND.
const SCR_WRITABLE: u32 = (1 << 1) | (1 << 2) | (1 << 4);
/// SCR.SLEEPONEXIT.
pub const SCR_SLEEPONEXIT: u32 = 1 << 1;
/// SCR.SEVONPEND.
pub const SCR_SEVONPEND: u32 = 1 << 4;
/// FPCCR reset value (B3.2, FPCCR; lazy FP state preservation): ASPEN and LSPEN set.
const FPCCR_RESET: u32 = 0xC000_0000;
/// MVFR0 and MVFR1 of the Cortex-M4 with FPU (Cortex-M4 TRM 7.2: single precision).
const MVFR0: u32 = 0x1011_0021;
const MVFR1: u32 = 0x1100_0011;
/// DEMCR.TRCENA: enables the DWT and ITM (C1.6, DEMCR).
const DEMCR_TRCENA: u32 = 1 << 24;
/// DWT_CTRL.NUMCOMP: four comparators on the Cortex-M4 (read-only field).
const DWT_NUMCOMP: u32 = 4 << 28;
/// DWT_CTRL.CYCCNTENA.
const DWT_CYCCNTENA: u32 = 1;

/// CFSR bits (B3.2, CFSR) the CPU side records when it stops on a fault.
pub mod cfsr {
    /// UFSR.UNDEFINSTR: an undefined instruction.
    pub const UNDEFINSTR: u32 = 1 << 16;
    /// UFSR.INVSTATE: an instruction executed with EPSR.T or IT state invalid.
    pub const INVSTATE: u32 = 1 << 17;
    /// UFSR.INVPC: an invalid EXC_RETURN or integrity check failure on return.
    pub const INVPC: u32 = 1 << 18;
    /// UFSR.NOCP: a coprocessor access with the coprocessor disabled or absent.
    pub const NOCP: u32 = 1 << 19;
    /// UFSR.UNALIGNED.
    pub const UNALIGNED: u32 = 1 << 24;
    /// UFSR.DIVBYZERO.
    pub const DIVBYZERO: u32 = 1 << 25;
}

/// HFSR bits (B3.2, HFSR).
pub mod hfsr {
    /// VECTTBL: a bus fault on a vector table read.
    pub const VECTTBL: u32 = 1 << 1;
    /// FORCED: a configurable fault escalated to HardFault.
    pub const FORCED: u32 = 1 << 30;
    /// DEBUGEVT: a debug event (a breakpoint with halting debug off).
    pub const DEBUGEVT: u32 = 1 << 31;
}

/// What a write to the system part asks of the CPU side.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Effects {
    /// AIRCR.SYSRESETREQ with the right key: a system reset (B3.2, AIRCR).
    pub system_reset: bool,
}

/// The Cortex-M4 system part's state.
#[derive(Clone, Debug)]
pub struct SystemControl {
    /// Exceptions: enabled, pending, active, priorities.
    pub exceptions: Exceptions,
    /// The SysTick timer.
    pub systick: SysTick,
    actlr: u32,
    vtor: u32,
    scr: u32,
    ccr: u32,
    /// CFSR (B3.2, CFSR), set by the CPU side on a fault.
    pub cfsr: u32,
    /// HFSR (B3.2, HFSR), set by the CPU side on a fault.
    pub hfsr: u32,
    dfsr: u32,
    mmfar: u32,
    bfar: u32,
    afsr: u32,
    cpacr: u32,
    fpccr: u32,
    fpcar: u32,
    fpdscr: u32,
    demcr: u32,
    dwt_ctrl: u32,
    /// CYCCNT's value at `cyccnt_base` cycles.
    cyccnt: u32,
    cyccnt_base: u64,
}

impl Default for SystemControl {
    fn default() -> Self {
        SystemControl::new()
    }
}

/// What the CPU side tells a register access.
#[derive(Clone, Copy, Debug)]
pub struct CoreState {
    /// Core clock cycles since power-on, asleep or not (SysTick counts these).
    pub cycles: u64,
    /// Instructions executed since power-on (the DWT's CYCCNT counts these: the core's
    /// cycles while it runs, at one instruction per cycle, see `crate::cpu`).
    pub instructions: u64,
    /// IPSR: the exception number being handled, 0 in Thread mode.
    pub ipsr: u32,
}

impl SystemControl {
    /// The reset state.
    pub fn new() -> SystemControl {
        SystemControl {
            exceptions: Exceptions::new(),
            systick: SysTick::new(),
            actlr: 0,
            vtor: 0,
            scr: 0,
            ccr: CCR_RESET,
            cfsr: 0,
            hfsr: 0,
            dfsr: 0,
            mmfar: 0,
            bfar: 0,
            afsr: 0,
            cpacr: 0,
            fpccr: FPCCR_RESET,
            fpcar: 0,
            fpdscr: 0,
            demcr: 0,
            dwt_ctrl: 0,
            cyccnt: 0,
            cyccnt_base: 0,
        }
    }

    /// VTOR (B3.2, VTOR).
    pub fn vtor(&self) -> u32 {
        self.vtor
    }

    /// CCR (B3.2, CCR).
    pub fn ccr(&self) -> u32 {
        self.ccr
    }

    /// SCR (B3.2, SCR).
    pub fn scr(&self) -> u32 {
        self.scr
    }

    /// CPACR (B3.2, CPACR).
    pub fn cpacr(&self) -> u32 {
        self.cpacr
    }

    /// Whether CPACR grants access to CP10 and CP11, the FP extension (B3.2, CPACR).
    pub fn fpu_enabled(&self) -> bool {
        let cp10 = (self.cpacr >> 20) & 3;
        let cp11 = (self.cpacr >> 22) & 3;
        cp10 != 0 && cp10 != 2 && cp10 == cp11
    }

    /// Brings SysTick to `cycles` and pends its exception when it reached 0 with TICKINT.
    pub fn catch_up(&mut self, cycles: u64) {
        if self.systick.catch_up(cycles) && self.systick.interrupts() {
            self.exceptions.set_pending(number::SYSTICK, true);
        }
    }

    /// The cycle count of the system part's next event (SysTick reaching 0).
    pub fn next_event(&self) -> Option<u64> {
        self.systick.next_event()
    }

    fn cyccnt_now(&self, instructions: u64) -> u32 {
        if self.cyccnt_counting() {
            self.cyccnt
                .wrapping_add(instructions.wrapping_sub(self.cyccnt_base) as u32)
        } else {
            self.cyccnt
        }
    }

    fn cyccnt_counting(&self) -> bool {
        self.demcr & DEMCR_TRCENA != 0 && self.dwt_ctrl & DWT_CYCCNTENA != 0
    }

    /// Re-bases CYCCNT at `instructions` around a change of its enables.
    fn cyccnt_change(&mut self, instructions: u64, change: impl FnOnce(&mut SystemControl)) {
        self.cyccnt = self.cyccnt_now(instructions);
        self.cyccnt_base = instructions;
        change(self);
    }

    /// Reads `size` bytes at `address` (in the SCS or the DWT).
    pub fn read(&mut self, address: u32, size: u32, core: CoreState) -> Result<u32, AccessError> {
        if (DWT_BASE..DWT_BASE + 0x1000).contains(&address) {
            return self.read_dwt(address - DWT_BASE, size, core);
        }
        let offset = address.wrapping_sub(SCS_BASE);
        let unmodelled = AccessError::Unmodelled { block: SCS, offset };
        let width = AccessError::Width {
            block: SCS,
            offset,
            size,
        };
        // Byte-addressable registers: NVIC_IPR (B3.4), SHPR1-3 , CFSR (B3.2).
        if let Some(value) = self.read_bytes(offset, size) {
            return Ok(value);
        }
        if size != 4 || offset % 4 != 0 {
            return Err(if self.is_word_register(offset) {
                width
            } else {
                unmodelled
            });
        }
        let e = &self.exceptions;
        Ok(match offset {
            // ICTR (B3.4, ICTR): INTLINESNUM = lines / 32 rounded up, minus 1.
            0x004 => (IRQ_LINES as u32).div_ceil(32) - 1,
            0x008 => self.actlr,
            0x010..=0x01C => {
                let (value, wrapped) = self
                    .systick
                    .read(offset - 0x010, core.cycles)
                    .ok_or(unmodelled)?;
                if wrapped && self.systick.interrupts() {
                    self.exceptions.set_pending(number::SYSTICK, true);
                }
                value
            }
            0x100..=0x10B | 0x180..=0x18B => self.irq_bits(offset & 0xF, |n| e.is_enabled(n)),
            0x200..=0x20B | 0x280..=0x28B => self.irq_bits(offset & 0xF, |n| e.is_pending(n)),
            0x300..=0x30B => self.irq_bits(offset & 0xF, |n| e.is_active(n)),
            0xD00 => CPUID,
            0xD04 => self.icsr(core.ipsr),
            0xD08 => self.vtor,
            0xD0C => (0xFA05 << 16) | (u32::from(e.prigroup()) << 8),
            0xD10 => self.scr,
            0xD14 => self.ccr,
            0xD24 => self.shcsr(),
            0xD2C => self.hfsr,
            0xD30 => self.dfsr,
            0xD34 => self.mmfar,
            0xD38 => self.bfar,
            0xD3C => self.afsr,
            0xD88 => self.cpacr,
            0xDFC => self.demcr,
            0xF34 => self.fpccr,
            0xF38 => self.fpcar,
            0xF3C => self.fpdscr,
            0xF40 => MVFR0,
            0xF44 => MVFR1,
            _ => return Err(unmodelled),
        })
    }

    fn is_word_register(&self, offset: u32) -> bool {
        matches!(offset & !3,
            0x004 | 0x008 | 0x010..=0x01C | 0x100..=0x10B | 0x180..=0x18B | 0x200..=0x20B
            | 0x280..=0x28B | 0x300..=0x30B | 0xD00..=0xD14 | 0xD24 | 0xD2C..=0xD3C | 0xD88
            | 0xDFC | 0xF00 | 0xF34..=0xF44)
    }

    /// The byte-addressable registers, read with any width (`None`: not one of them).
    fn read_bytes(&self, offset: u32, size: u32) -> Option<u32> {
        if !matches!(size, 1 | 2 | 4) || offset % size != 0 {
            return None;
        }
        let byte = |at: u32| -> Option<u8> {
            match at {
                0x400..=0x4EF => Some(self.exceptions.priority_byte(FIRST_IRQ + (at - 0x400))),
                0xD18..=0xD23 => Some(self.exceptions.priority_byte(4 + (at - 0xD18))),
                0xD28..=0xD2B => Some((self.cfsr >> (8 * (at - 0xD28))) as u8),
                _ => None,
            }
        };
        let mut value = 0u32;
        for i in 0..size {
            value |= u32::from(byte(offset + i)?) << (8 * i);
        }
        Some(value)
    }

    fn irq_bits(&self, word_offset: u32, bit: impl Fn(u32) -> bool) -> u32 {
        let first = word_offset / 4 * 32;
        (0..32)
            .filter(|i| first + i < IRQ_LINES as u32 && bit(FIRST_IRQ + first + i))
            .fold(0, |value, i| value | (1 << i))
    }

    fn each_irq_bit(word_offset: u32, value: u32, mut apply: impl FnMut(u32)) {
        let first = word_offset / 4 * 32;
        for i in 0..32 {
            if value & (1 << i) != 0 && first + i < IRQ_LINES as u32 {
                apply(FIRST_IRQ + first + i);
            }
        }
    }

    /// ICSR (B3.2, ICSR).
    fn icsr(&self, ipsr: u32) -> u32 {
        let e = &self.exceptions;
        let mut value = ipsr & 0x1FF;
        if ipsr != 0 && e.active_count() <= 1 {
            value |= 1 << 11; // RETTOBASE
        }
        if let Some(n) = e.highest_pending() {
            value |= (n & 0x1FF) << 12; // VECTPENDING
        }
        if e.irq_pending() {
            value |= 1 << 22; // ISRPENDING
        }
        if e.is_pending(number::SYSTICK) {
            value |= 1 << 26; // PENDSTSET
        }
        if e.is_pending(number::PENDSV) {
            value |= 1 << 28; // PENDSVSET
        }
        if e.is_pending(number::NMI) {
            value |= 1 << 31; // NMIPENDSET
        }
        value
    }

    /// SHCSR (B3.2, SHCSR).
    fn shcsr(&self) -> u32 {
        let e = &self.exceptions;
        let bits = [
            (0, e.is_active(number::MEM_MANAGE)),
            (1, e.is_active(number::BUS_FAULT)),
            (3, e.is_active(number::USAGE_FAULT)),
            (7, e.is_active(number::SVCALL)),
            (8, e.is_active(number::DEBUG_MONITOR)),
            (10, e.is_active(number::PENDSV)),
            (11, e.is_active(number::SYSTICK)),
            (12, e.is_pending(number::USAGE_FAULT)),
            (13, e.is_pending(number::MEM_MANAGE)),
            (14, e.is_pending(number::BUS_FAULT)),
            (15, e.is_pending(number::SVCALL)),
            (16, e.is_enabled(number::MEM_MANAGE)),
            (17, e.is_enabled(number::BUS_FAULT)),
            (18, e.is_enabled(number::USAGE_FAULT)),
        ];
        bits.iter()
            .filter(|(_, set)| *set)
            .fold(0, |value, (bit, _)| value | (1 << bit))
    }

    fn write_shcsr(&mut self, value: u32) {
        let e = &mut self.exceptions;
        let bit = |b: u32| value & (1 << b) != 0;
        e.set_active(number::MEM_MANAGE, bit(0));
        e.set_active(number::BUS_FAULT, bit(1));
        e.set_active(number::USAGE_FAULT, bit(3));
        e.set_active(number::SVCALL, bit(7));
        e.set_active(number::DEBUG_MONITOR, bit(8));
        e.set_active(number::PENDSV, bit(10));
        e.set_active(number::SYSTICK, bit(11));
        e.set_pending(number::USAGE_FAULT, bit(12));
        e.set_pending(number::MEM_MANAGE, bit(13));
        e.set_pending(number::BUS_FAULT, bit(14));
        e.set_pending(number::SVCALL, bit(15));
        e.set_enabled(number::MEM_MANAGE, bit(16));
        e.set_enabled(number::BUS_FAULT, bit(17));
        e.set_enabled(number::USAGE_FAULT, bit(18));
    }

    /// Writes the low `size` bytes of `value` at `address` (in the SCS or the DWT).
    pub fn write(
        &mut self,
        address: u32,
        size: u32,
        value: u32,
        core: CoreState,
    ) -> Result<Effects, AccessError> {
        if (DWT_BASE..DWT_BASE + 0x1000).contains(&address) {
            self.write_dwt(address - DWT_BASE, size, value, core)?;
            return Ok(Effects::default());
        }
        let offset = address.wrapping_sub(SCS_BASE);
        let unmodelled = AccessError::Unmodelled { block: SCS, offset };
        if self.write_bytes(offset, size, value) {
            return Ok(Effects::default());
        }
        if size != 4 || offset % 4 != 0 {
            return Err(if self.is_word_register(offset) {
                AccessError::Width {
                    block: SCS,
                    offset,
                    size,
                }
            } else {
                unmodelled
            });
        }
        let mut effects = Effects::default();
        match offset {
            0x008 => self.actlr = value & 0x307,
            0x010..=0x01C => {
                let wrapped = self
                    .systick
                    .write(offset - 0x010, value, core.cycles)
                    .ok_or(unmodelled)?;
                if wrapped && self.systick.interrupts() {
                    self.exceptions.set_pending(number::SYSTICK, true);
                }
            }
            0x100..=0x10B => Self::each_irq_bit(offset & 0xF, value, |n| {
                self.exceptions.set_enabled(n, true)
            }),
            0x180..=0x18B => Self::each_irq_bit(offset & 0xF, value, |n| {
                self.exceptions.set_enabled(n, false)
            }),
            0x200..=0x20B => Self::each_irq_bit(offset & 0xF, value, |n| {
                self.exceptions.set_pending(n, true)
            }),
            0x280..=0x28B => Self::each_irq_bit(offset & 0xF, value, |n| {
                self.exceptions.set_pending(n, false)
            }),
            // IABR is read-only (B3.4, NVIC_IABR); CPUID too (B3.2, CPUID).
            0x300..=0x30B | 0xD00 => {}
            0xD04 => self.write_icsr(value),
            // TBLOFF, bits [29:7] (B3.2, VTOR).
            0xD08 => self.vtor = value & 0x3FFF_FF80,
            0xD0C => {
                if value >> 16 == VECTKEY {
                    self.exceptions.set_prigroup(((value >> 8) & 7) as u8);
                    // VECTCLRACTIVE and VECTRESET are for a debugger with the core halted
                    // (B3.2, AIRCR: UNPREDICTABLE otherwise); SYSRESETREQ asks for a reset.
                    effects.system_reset = value & (1 << 2) != 0;
                }
            }
            0xD10 => self.scr = value & SCR_WRITABLE,
            0xD14 => self.ccr = value & CCR_WRITABLE,
            0xD24 => self.write_shcsr(value),
            // Write one to clear (B3.2 HFSR, C1.6 DFSR).
            0xD2C => self.hfsr &= !value,
            0xD30 => self.dfsr &= !value,
            0xD34 => self.mmfar = value,
            0xD38 => self.bfar = value,
            0xD3C => self.afsr &= !value,
            0xD88 => self.cpacr = value & 0x00F0_0000,
            0xDFC => {
                self.cyccnt_change(core.instructions, |s| s.demcr = value & 0x010F_07F1);
            }
            // STIR (B3.4, STIR): pends the interrupt line it names.
            0xF00 => {
                let line = value & 0x1FF;
                if (line as usize) < IRQ_LINES {
                    self.exceptions.set_pending(FIRST_IRQ + line, true);
                }
            }
            0xF34 => self.fpccr = (self.fpccr & !0xC000_0000) | (value & 0xC000_0000),
            0xF38 => self.fpcar = value & !7,
            0xF3C => self.fpdscr = value & 0x07C0_0000,
            0xF40 | 0xF44 => {}
            _ => return Err(unmodelled),
        }
        Ok(effects)
    }

    fn write_bytes(&mut self, offset: u32, size: u32, value: u32) -> bool {
        if !matches!(size, 1 | 2 | 4) || offset % size != 0 {
            return false;
        }
        let in_block = |at: u32| matches!(at, 0x400..=0x4EF | 0xD18..=0xD23 | 0xD28..=0xD2B);
        if !(0..size).all(|i| in_block(offset + i)) {
            return false;
        }
        for i in 0..size {
            let at = offset + i;
            let byte = (value >> (8 * i)) as u8;
            match at {
                0x400..=0x4EF => self
                    .exceptions
                    .set_priority_byte(FIRST_IRQ + (at - 0x400), byte),
                0xD18..=0xD23 => {
                    let n = 4 + (at - 0xD18);
                    // Only the configurable system exceptions have a priority field.
                    if matches!(n, 4 | 5 | 6 | 11 | 12 | 14 | 15) {
                        self.exceptions.set_priority_byte(n, byte);
                    }
                }
                // CFSR: write one to clear (B3.2, CFSR).
                _ => self.cfsr &= !(u32::from(byte) << (8 * (at - 0xD28))),
            }
        }
        true
    }

    fn write_icsr(&mut self, value: u32) {
        let e = &mut self.exceptions;
        if value & (1 << 31) != 0 {
            e.set_pending(number::NMI, true);
        }
        if value & (1 << 28) != 0 {
            e.set_pending(number::PENDSV, true);
        }
        if value & (1 << 27) != 0 {
            e.set_pending(number::PENDSV, false);
        }
        if value & (1 << 26) != 0 {
            e.set_pending(number::SYSTICK, true);
        }
        if value & (1 << 25) != 0 {
            e.set_pending(number::SYSTICK, false);
        }
    }

    fn read_dwt(&mut self, offset: u32, size: u32, core: CoreState) -> Result<u32, AccessError> {
        if size != 4 {
            return Err(AccessError::Width {
                block: DWT,
                offset,
                size,
            });
        }
        match offset {
            0x000 => Ok(DWT_NUMCOMP | self.dwt_ctrl),
            0x004 => Ok(self.cyccnt_now(core.instructions)),
            _ => Err(AccessError::Unmodelled { block: DWT, offset }),
        }
    }

    fn write_dwt(
        &mut self,
        offset: u32,
        size: u32,
        value: u32,
        core: CoreState,
    ) -> Result<(), AccessError> {
        if size != 4 {
            return Err(AccessError::Width {
                block: DWT,
                offset,
                size,
            });
        }
        match offset {
            // Only CYCCNTENA is modelled; the other event counters are not.
            0x000 if value & !DWT_CYCCNTENA & 0x0FFF_FFFF == 0 => {
                self.cyccnt_change(core.instructions, |s| s.dwt_ctrl = value & DWT_CYCCNTENA);
                Ok(())
            }
            0x004 => {
                self.cyccnt = value;
                self.cyccnt_base = core.instructions;
                Ok(())
            }
            // The lock access register (the CoreSight unlock key): accepted, nothing locked.
            0xFB0 => Ok(()),
            _ => Err(AccessError::Unmodelled { block: DWT, offset }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const CORE: CoreState = CoreState {
        cycles: 0,
        instructions: 0,
        ipsr: 0,
    };
    const NVIC_ISER0: u32 = 0xE000_E100;
    const NVIC_ICER0: u32 = 0xE000_E180;
    const NVIC_ISPR0: u32 = 0xE000_E200;
    const NVIC_ICPR0: u32 = 0xE000_E280;
    const NVIC_IPR0: u32 = 0xE000_E400;
    const ICSR: u32 = 0xE000_ED04;
    const AIRCR: u32 = 0xE000_ED0C;
    const SHPR3: u32 = 0xE000_ED20;

    #[test]
    fn armv7m_b3_4_nvic_iser_icer_set_and_clear_enables_and_read_back() {
        let mut system = SystemControl::new();
        system.write(NVIC_ISER0, 4, 1 << 28, CORE).unwrap();
        assert_eq!(system.read(NVIC_ISER0, 4, CORE).unwrap(), 1 << 28);
        assert_eq!(system.read(NVIC_ICER0, 4, CORE).unwrap(), 1 << 28);
        system.write(NVIC_ICER0, 4, 1 << 28, CORE).unwrap();
        assert_eq!(system.read(NVIC_ISER0, 4, CORE).unwrap(), 0);
    }

    #[test]
    fn armv7m_b3_4_nvic_ispr_icpr_pend_and_unpend_and_lines_beyond_81_read_zero() {
        let mut system = SystemControl::new();
        system.write(NVIC_ISPR0 + 8, 4, u32::MAX, CORE).unwrap();
        // Lines 64 to 81 exist, 82 to 95 do not.
        assert_eq!(system.read(NVIC_ISPR0 + 8, 4, CORE).unwrap(), 0x3FFFF);
        system.write(NVIC_ICPR0 + 8, 4, 1, CORE).unwrap();
        assert_eq!(system.read(NVIC_ISPR0 + 8, 4, CORE).unwrap(), 0x3FFFE);
    }

    #[test]
    fn armv7m_b3_4_nvic_ipr_is_byte_accessible_with_four_implemented_bits() {
        let mut system = SystemControl::new();
        system.write(NVIC_IPR0 + 28, 1, 0xFF, CORE).unwrap();
        assert_eq!(system.read(NVIC_IPR0 + 28, 1, CORE).unwrap(), 0xF0);
        assert_eq!(system.read(NVIC_IPR0 + 28, 4, CORE).unwrap(), 0xF0);
    }

    #[test]
    fn armv7m_b3_2_icsr_pendsvset_pendstset_and_vectpending() {
        let mut system = SystemControl::new();
        system.write(ICSR, 4, (1 << 28) | (1 << 26), CORE).unwrap();
        let icsr = system.read(ICSR, 4, CORE).unwrap();
        assert_ne!(icsr & (1 << 28), 0);
        assert_ne!(icsr & (1 << 26), 0);
        // Both at priority 0: the lower number, PendSV (14), is pending first.
        assert_eq!((icsr >> 12) & 0x1FF, 14);
        system.write(ICSR, 4, (1 << 27) | (1 << 25), CORE).unwrap();
        assert_eq!(
            system.read(ICSR, 4, CORE).unwrap() & ((1 << 28) | (1 << 26)),
            0
        );
    }

    #[test]
    fn armv7m_b3_2_aircr_needs_vectkey_and_sysresetreq_asks_for_a_reset() {
        let mut system = SystemControl::new();
        let effects = system.write(AIRCR, 4, (5 << 8) | (1 << 2), CORE).unwrap();
        assert!(!effects.system_reset);
        assert_eq!(system.read(AIRCR, 4, CORE).unwrap(), 0xFA05_0000);
        let effects = system
            .write(AIRCR, 4, (VECTKEY << 16) | (5 << 8) | (1 << 2), CORE)
            .unwrap();
        assert!(effects.system_reset);
        assert_eq!(system.read(AIRCR, 4, CORE).unwrap(), 0xFA05_0500);
    }

    #[test]
    fn armv7m_b3_2_shpr3_sets_systick_and_pendsv_priorities() {
        let mut system = SystemControl::new();
        system.write(SHPR3, 4, 0xA0B0_00C0, CORE).unwrap();
        assert_eq!(system.exceptions.priority(number::SYSTICK), 0xA0);
        assert_eq!(system.exceptions.priority(number::PENDSV), 0xB0);
        // Exception 13 is reserved: its byte reads as zero.
        assert_eq!(system.read(SHPR3, 4, CORE).unwrap(), 0xA0B0_00C0);
    }

    #[test]
    fn armv7m_b3_2_cfsr_and_hfsr_are_write_one_to_clear() {
        let mut system = SystemControl::new();
        system.cfsr = cfsr::UNDEFINSTR | cfsr::INVSTATE;
        system.hfsr = hfsr::FORCED;
        system
            .write(0xE000_ED28, 4, cfsr::UNDEFINSTR, CORE)
            .unwrap();
        assert_eq!(system.read(0xE000_ED28, 4, CORE).unwrap(), cfsr::INVSTATE);
        // UFSR as a halfword.
        assert_eq!(system.read(0xE000_ED2A, 2, CORE).unwrap(), 2);
        system.write(0xE000_ED2C, 4, hfsr::FORCED, CORE).unwrap();
        assert_eq!(system.read(0xE000_ED2C, 4, CORE).unwrap(), 0);
    }

    #[test]
    fn armv7m_c1_8_dwt_cyccnt_counts_only_with_trcena_and_cyccntena() {
        let mut system = SystemControl::new();
        let at = |instructions| CoreState {
            cycles: 0,
            instructions,
            ipsr: 0,
        };
        system.write(DWT_BASE, 4, DWT_CYCCNTENA, at(0)).unwrap();
        assert_eq!(system.read(DWT_BASE + 4, 4, at(100)).unwrap(), 0);
        system.write(0xE000_EDFC, 4, DEMCR_TRCENA, at(100)).unwrap();
        assert_eq!(system.read(DWT_BASE + 4, 4, at(350)).unwrap(), 250);
        system.write(DWT_BASE, 4, 0, at(400)).unwrap();
        assert_eq!(system.read(DWT_BASE + 4, 4, at(1_000)).unwrap(), 300);
    }

    #[test]
    fn armv7m_b3_2_cpacr_full_access_to_cp10_and_cp11_enables_the_fpu() {
        let mut system = SystemControl::new();
        assert!(!system.fpu_enabled());
        system.write(0xE000_ED88, 4, 0xF << 20, CORE).unwrap();
        assert!(system.fpu_enabled());
    }

    #[test]
    fn unmodelled_registers_and_widths_are_refused_not_read_as_zero() {
        let mut system = SystemControl::new();
        assert!(matches!(
            system.read(0xE000_ED40, 4, CORE),
            Err(AccessError::Unmodelled { .. })
        ));
        assert!(matches!(
            system.read(0xE000_ED00, 1, CORE),
            Err(AccessError::Width { .. })
        ));
    }
}
