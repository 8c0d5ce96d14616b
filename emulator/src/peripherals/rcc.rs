//! Reset and clock control of the STM32F405 (RM0090 7, "Reset and clock control for
//! STM32F405xx/07xx and STM32F415xx/17xx"; chapter 6 is the F42x/F43x's): the oscillators
//! with their start-up times, the main PLL, the system clock switch and the bus prescalers
//! (which give [`Clocks`]), the peripheral enable and reset registers, the backup domain
//! control register and the reset flags.
//!
//! The HSE can be made to fail to start ([`Hse::FailsToStart`]): HSERDY then never sets, as
//! with a broken crystal, and whatever waits for it waits until its watchdog or run budget.

use super::{AccessError, Context, Peripheral};
use crate::time::{Clocks, Nanos};

/// The block's base address (RM0090 2.3, Table 1).
pub const BASE: u32 = 0x4002_3800;
/// The block's size.
pub const SIZE: u32 = 0x400;
const NAME: &str = "RCC (RM0090 7)";

/// HSI frequency (RM0090 7.2.2).
pub const HSI_HZ: u32 = 16_000_000;
/// The HSE start-up time the model takes: tSU(HSE), typical, of the F405 datasheet (DS8626,
/// "HSE 4-26 MHz oscillator characteristics").
pub const HSE_STARTUP: Nanos = 2_000_000;
/// The main PLL's lock time the model takes: tLOCK of DS8626 ("Main PLL characteristics"),
/// typical.
pub const PLL_LOCK: Nanos = 100_000;
/// The LSI start-up time the model takes: tSU(LSI) of DS8626, typical.
pub const LSI_STARTUP: Nanos = 15_000;
/// The HSI's start-up time (tSU(HSI) of DS8626, typical).
pub const HSI_STARTUP: Nanos = 2_200;
/// HSICAL as this emulated part reads it (a factory trim value; any is as good).
const HSICAL: u32 = 0x7A;

/// The external oscillator on the board.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Hse {
    /// A crystal of this frequency (Hz) that starts as the datasheet says.
    Crystal(u32),
    /// A crystal that never starts: HSERDY stays 0 (RM0090 7.2.1).
    FailsToStart,
}

/// The board of this project: an 8 MHz crystal (`board::hw`).
pub const BOARD_HSE: Hse = Hse::Crystal(8_000_000);

/// Why the last reset happened, as RCC_CSR records it (RM0090 7.3.21).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResetCause {
    /// Power on: PORRSTF, PINRSTF, BORRSTF.
    PowerOn,
    /// AIRCR.SYSRESETREQ: SFTRSTF.
    Software,
    /// The independent watchdog: IWDGRSTF.
    IndependentWatchdog,
}

/// The offset of the F42x/F43x's RCC_DCKCFGR (RM0090 6.3.27), reserved on the F405 (RM0090
/// 7.3.24, register map). embassy-stm32 reads it and writes it with zeros (its F4 register
/// description is the F42x's): the part reads a reserved word as 0 and ignores writes, so the
/// model does the same for this word, and refuses a non-zero write, which would expect a
/// clock selection the F405 does not have.
const DCKCFGR_F42X: u32 = 0x8C;
// RCC_CR bits (RM0090 7.3.1).
const HSION: u32 = 1 << 0;
const HSIRDY: u32 = 1 << 1;
const HSEON: u32 = 1 << 16;
const HSERDY: u32 = 1 << 17;
const HSEBYP: u32 = 1 << 18;
const CSSON: u32 = 1 << 19;
const PLLON: u32 = 1 << 24;
const PLLRDY: u32 = 1 << 25;
const PLLI2SON: u32 = 1 << 26;
// RCC_CSR bits (RM0090 7.3.21).
const LSION: u32 = 1 << 0;
const LSIRDY: u32 = 1 << 1;
const RMVF: u32 = 1 << 24;
const BORRSTF: u32 = 1 << 25;
const PINRSTF: u32 = 1 << 26;
const PORRSTF: u32 = 1 << 27;
const SFTRSTF: u32 = 1 << 28;
const IWDGRSTF: u32 = 1 << 29;
const RESET_FLAGS: u32 = 0xFE00_0000;

/// The clock sources of CFGR.SW / SWS (RM0090 7.3.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Source {
    Hsi,
    Hse,
    Pll,
}

impl Source {
    fn from_bits(bits: u32) -> Option<Source> {
        match bits & 3 {
            0 => Some(Source::Hsi),
            1 => Some(Source::Hse),
            2 => Some(Source::Pll),
            _ => None,
        }
    }

    fn bits(self) -> u32 {
        match self {
            Source::Hsi => 0,
            Source::Hse => 1,
            Source::Pll => 2,
        }
    }
}

/// The RCC model.
#[derive(Clone, Debug)]
pub struct Rcc {
    hse: Hse,
    /// CR's control bits (the ready bits are computed).
    cr: u32,
    hsitrim: u32,
    pllcfgr: u32,
    /// CFGR without SWS.
    cfgr: u32,
    /// The source the system clock runs from (CFGR.SWS).
    sws: Source,
    cir: u32,
    /// AHB1, AHB2, AHB3, APB1, APB2 reset registers.
    rstr: [u32; 5],
    /// AHB1, AHB2, AHB3, APB1, APB2 enable registers.
    enr: [u32; 5],
    /// AHB1, AHB2, AHB3, APB1, APB2 low-power enable registers.
    lpenr: [u32; 5],
    bdcr: u32,
    csr: u32,
    sscgr: u32,
    plli2scfgr: u32,
    /// When each oscillator, once on, is ready (`None`: off, or never).
    hsi_ready_at: Option<Nanos>,
    hse_ready_at: Option<Nanos>,
    pll_ready_at: Option<Nanos>,
    lsi_ready_at: Option<Nanos>,
    /// PWR_CR.DBP: whether the backup domain (BDCR) may be written (RM0090 5.1.2).
    backup_writable: bool,
    now: Nanos,
}

impl Rcc {
    /// The RCC after power-on with `hse` on the board (RM0090 7.3: each register's reset
    /// value).
    pub fn new(hse: Hse) -> Rcc {
        Rcc {
            hse,
            cr: HSION,
            hsitrim: 0x10,
            pllcfgr: 0x2400_3010,
            cfgr: 0,
            sws: Source::Hsi,
            cir: 0,
            rstr: [0; 5],
            // CCMDATARAMEN is set at reset (RM0090 7.3.10).
            enr: [0x0010_0000, 0, 0, 0, 0],
            lpenr: [
                0x7E67_91FF,
                0x0000_00F1,
                0x0000_0001,
                0x36FE_C9FF,
                0x0007_5F33,
            ],
            bdcr: 0,
            csr: PORRSTF | PINRSTF | BORRSTF,
            sscgr: 0,
            plli2scfgr: 0x2000_3000,
            hsi_ready_at: Some(0),
            hse_ready_at: None,
            pll_ready_at: None,
            lsi_ready_at: None,
            backup_writable: false,
            now: 0,
        }
    }

    /// The RCC after a system reset at `now` (RM0090 7.1.1): every register back to its
    /// reset value except the reset flags, which gain the cause's (and PINRSTF: the internal
    /// reset drives the NRST pin), and the backup domain's BDCR, which a system reset does not
    /// touch (RM0090 7.1.3).
    pub fn after_reset(&self, cause: ResetCause, now: Nanos) -> Rcc {
        let mut rcc = Rcc::new(self.hse);
        rcc.now = now;
        rcc.hsi_ready_at = Some(now + HSI_STARTUP);
        rcc.bdcr = self.bdcr;
        rcc.csr = (self.csr & RESET_FLAGS)
            | match cause {
                ResetCause::PowerOn => PORRSTF | PINRSTF | BORRSTF,
                ResetCause::Software => SFTRSTF | PINRSTF,
                ResetCause::IndependentWatchdog => IWDGRSTF | PINRSTF,
            };
        rcc
    }

    /// Tells the model whether PWR_CR.DBP allows writes to the backup domain.
    pub fn set_backup_writable(&mut self, writable: bool) {
        self.backup_writable = writable;
    }

    fn ready(at: Option<Nanos>, now: Nanos) -> bool {
        at.is_some_and(|at| now >= at)
    }

    fn source_ready(&self, source: Source, now: Nanos) -> bool {
        match source {
            Source::Hsi => Self::ready(self.hsi_ready_at, now),
            Source::Hse => Self::ready(self.hse_ready_at, now),
            Source::Pll => Self::ready(self.pll_ready_at, now),
        }
    }

    fn pll_source(&self) -> Source {
        if self.pllcfgr & (1 << 22) != 0 {
            Source::Hse
        } else {
            Source::Hsi
        }
    }

    /// When the PLL's input is ready (`None`: never).
    fn pll_input_ready_at(&self) -> Option<Nanos> {
        match self.pll_source() {
            Source::Hse => self.hse_ready_at,
            _ => self.hsi_ready_at,
        }
    }

    fn hse_hz(&self) -> u32 {
        match self.hse {
            Hse::Crystal(hz) => hz,
            Hse::FailsToStart => 0,
        }
    }

    /// The PLL's P output, Hz (RM0090 7.3.2: f(VCO) = f(input) × PLLN / PLLM, PLLCLK =
    /// f(VCO) / PLLP).
    fn pll_hz(&self) -> u32 {
        let input = match self.pll_source() {
            Source::Hse => self.hse_hz(),
            _ => HSI_HZ,
        };
        let m = self.pllcfgr & 0x3F;
        let n = (self.pllcfgr >> 6) & 0x1FF;
        let p = 2 * (((self.pllcfgr >> 16) & 3) + 1);
        if m == 0 {
            return 0;
        }
        (u64::from(input) * u64::from(n) / u64::from(m) / u64::from(p)) as u32
    }

    /// SYSCLK, HCLK, PCLK1 and PCLK2 as the switch and the prescalers set them now.
    pub fn clocks(&self) -> Clocks {
        let sysclk = match self.sws {
            Source::Hsi => HSI_HZ,
            Source::Hse => self.hse_hz(),
            Source::Pll => self.pll_hz(),
        };
        let hpre = (self.cfgr >> 4) & 0xF;
        let ahb_divider = if hpre < 8 {
            1
        } else {
            [2, 4, 8, 16, 64, 128, 256, 512][(hpre - 8) as usize]
        };
        let hclk = sysclk / ahb_divider;
        let apb = |bits: u32| if bits < 4 { 1 } else { 1 << (bits - 3) };
        Clocks {
            sysclk,
            hclk,
            pclk1: hclk / apb((self.cfgr >> 10) & 7),
            pclk2: hclk / apb((self.cfgr >> 13) & 7),
        }
    }

    /// Whether the peripheral of `bit` in the APB1 enable register (RM0090 7.3.13) is
    /// clocked.
    pub fn apb1_enabled(&self, bit: u32) -> bool {
        self.enr[3] & (1 << bit) != 0
    }

    /// RCC_CSR's reset flags.
    pub fn reset_flags(&self) -> u32 {
        self.csr & RESET_FLAGS
    }

    /// Brings the switch to `now`: a requested source that has become ready takes over.
    fn settle(&mut self, now: Nanos) {
        self.now = self.now.max(now);
        if let Some(requested) = Source::from_bits(self.cfgr) {
            if requested != self.sws && self.source_ready(requested, self.now) {
                self.sws = requested;
            }
        }
    }

    fn cr_value(&self, now: Nanos) -> u32 {
        let mut value = self.cr | (self.hsitrim << 3) | (HSICAL << 8);
        if self.cr & HSION != 0 && Self::ready(self.hsi_ready_at, now) {
            value |= HSIRDY;
        }
        if Self::ready(self.hse_ready_at, now) {
            value |= HSERDY;
        }
        if Self::ready(self.pll_ready_at, now) {
            value |= PLLRDY;
        }
        value
    }

    fn write_cr(&mut self, value: u32, now: Nanos) {
        let old = self.cr;
        // HSI stays on while it clocks the system (RM0090 7.3.1, HSION).
        let mut hsion = value & HSION;
        if self.sws == Source::Hsi || (self.cr & PLLON != 0 && self.pll_source() == Source::Hsi) {
            hsion = HSION;
        }
        // HSEBYP can only be written while the HSE is off.
        let hsebyp = if old & HSEON == 0 {
            value & HSEBYP
        } else {
            old & HSEBYP
        };
        self.cr = hsion | (value & (HSEON | CSSON | PLLON | PLLI2SON)) | hsebyp;
        self.hsitrim = (value >> 3) & 0x1F;
        if self.cr & HSION == 0 {
            self.hsi_ready_at = None;
        } else if old & HSION == 0 {
            self.hsi_ready_at = Some(now + HSI_STARTUP);
        }
        if self.cr & HSEON == 0 {
            self.hse_ready_at = None;
        } else if old & HSEON == 0 {
            self.hse_ready_at = match self.hse {
                Hse::Crystal(_) => Some(now + HSE_STARTUP),
                Hse::FailsToStart => None,
            };
        }
        if self.cr & PLLON == 0 {
            self.pll_ready_at = None;
        } else if old & PLLON == 0 {
            self.pll_ready_at = self
                .pll_input_ready_at()
                .map(|input| input.max(now) + PLL_LOCK);
        }
    }

    fn write_csr(&mut self, value: u32, now: Nanos) {
        if value & RMVF != 0 {
            self.csr &= !RESET_FLAGS;
        }
        let was_on = self.csr & LSION != 0;
        self.csr = (self.csr & !LSION) | (value & LSION);
        if value & LSION == 0 {
            self.lsi_ready_at = None;
        } else if !was_on {
            self.lsi_ready_at = Some(now + LSI_STARTUP);
        }
    }

    /// Whether the LSI runs now (RCC_CSR.LSIRDY). The independent watchdog also starts it
    /// by itself (RM0090 21.3.1), which its own model accounts for.
    pub fn lsi_ready(&self, now: Nanos) -> bool {
        Self::ready(self.lsi_ready_at, now)
    }

    fn index(offset: u32, base: u32) -> Option<usize> {
        // AHB1, AHB2, AHB3, (reserved), APB1, APB2.
        match offset - base {
            0x0 => Some(0),
            0x4 => Some(1),
            0x8 => Some(2),
            0x10 => Some(3),
            0x14 => Some(4),
            _ => None,
        }
    }
}

impl Peripheral for Rcc {
    fn name(&self) -> &'static str {
        NAME
    }

    fn read(&mut self, ctx: &Context, offset: u32, size: u32) -> Result<u32, AccessError> {
        if size != 4 {
            return Err(AccessError::Width {
                block: NAME,
                offset,
                size,
            });
        }
        self.settle(ctx.now);
        let now = self.now;
        let unmodelled = AccessError::Unmodelled {
            block: NAME,
            offset,
        };
        Ok(match offset {
            0x00 => self.cr_value(now),
            0x04 => self.pllcfgr,
            0x08 => self.cfgr | (self.sws.bits() << 2),
            0x0C => self.cir,
            0x10..=0x24 => self.rstr[Self::index(offset, 0x10).ok_or(unmodelled)?],
            0x30..=0x44 => self.enr[Self::index(offset, 0x30).ok_or(unmodelled)?],
            0x50..=0x64 => self.lpenr[Self::index(offset, 0x50).ok_or(unmodelled)?],
            0x70 => self.bdcr,
            0x74 => {
                let ready = if self.lsi_ready(now) { LSIRDY } else { 0 };
                self.csr | ready
            }
            0x80 => self.sscgr,
            0x84 => self.plli2scfgr,
            DCKCFGR_F42X => 0,
            _ => return Err(unmodelled),
        })
    }

    fn write(
        &mut self,
        ctx: &Context,
        offset: u32,
        size: u32,
        value: u32,
    ) -> Result<(), AccessError> {
        if size != 4 {
            return Err(AccessError::Width {
                block: NAME,
                offset,
                size,
            });
        }
        self.settle(ctx.now);
        let now = self.now;
        let unmodelled = AccessError::Unmodelled {
            block: NAME,
            offset,
        };
        match offset {
            0x00 => self.write_cr(value, now),
            // PLLM, PLLN, PLLP, PLLSRC, PLLQ (RM0090 7.3.2).
            0x04 => self.pllcfgr = (value & 0x0F43_7FFF) | (1 << 29),
            // SWS is read-only; SW = 11 is "not allowed" and leaves the clock where it is.
            0x08 => self.cfgr = value & !0xC,
            // The ready interrupt enables; the clear bits act on flags no model sets.
            0x0C => self.cir = value & 0x3F00,
            0x10..=0x24 => self.rstr[Self::index(offset, 0x10).ok_or(unmodelled)?] = value,
            0x30..=0x44 => self.enr[Self::index(offset, 0x30).ok_or(unmodelled)?] = value,
            0x50..=0x64 => self.lpenr[Self::index(offset, 0x50).ok_or(unmodelled)?] = value,
            0x70 => {
                // Write-protected until PWR_CR.DBP is set (RM0090 5.1.2); BDRST resets the
                // domain while it is set.
                if self.backup_writable {
                    self.bdcr = if value & (1 << 16) != 0 {
                        1 << 16
                    } else {
                        value & 0x0000_8307
                    };
                    // The LSE is not fitted on the board: LSERDY never sets.
                }
            }
            0x74 => self.write_csr(value, now),
            0x80 => self.sscgr = value & 0xCFFF_FFFF,
            0x84 => self.plli2scfgr = value & 0x7000_7FC0,
            DCKCFGR_F42X if value == 0 => {}
            _ => return Err(unmodelled),
        }
        self.settle(now);
        Ok(())
    }

    fn advance(&mut self, ctx: &Context) {
        self.settle(ctx.now);
    }

    fn next_event(&self, ctx: &Context) -> Option<Nanos> {
        // A requested switch waits for its source to be ready.
        let requested = Source::from_bits(self.cfgr)?;
        if requested == self.sws {
            return None;
        }
        let at = match requested {
            Source::Hsi => self.hsi_ready_at,
            Source::Hse => self.hse_ready_at,
            Source::Pll => self.pll_ready_at,
        }?;
        (at > ctx.now).then_some(at)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(now: Nanos) -> Context {
        Context {
            now,
            clocks: Clocks::RESET,
        }
    }

    /// The board's clock tree (`board::hw::clocks`): HSE 8 MHz, PLLM 4, PLLN 168, PLLP 2,
    /// PLLQ 7, AHB 1, APB1 4, APB2 2.
    fn configure_168_mhz(rcc: &mut Rcc, now: Nanos) -> Nanos {
        rcc.write(&at(now), 0x00, 4, HSION | HSEON).unwrap();
        let mut now = now;
        while rcc.read(&at(now), 0x00, 4).unwrap() & HSERDY == 0 {
            now += 10_000;
        }
        let pllcfgr = 4 | (168 << 6) | (1 << 22) | (7 << 24);
        rcc.write(&at(now), 0x04, 4, pllcfgr).unwrap();
        rcc.write(&at(now), 0x00, 4, HSION | HSEON | PLLON).unwrap();
        while rcc.read(&at(now), 0x00, 4).unwrap() & PLLRDY == 0 {
            now += 10_000;
        }
        let cfgr = 2 | (0b101 << 10) | (0b100 << 13);
        rcc.write(&at(now), 0x08, 4, cfgr).unwrap();
        now
    }

    #[test]
    fn rm0090_7_3_1_hse_ready_after_its_start_up_time_and_the_pll_after_lock() {
        let mut rcc = Rcc::new(BOARD_HSE);
        rcc.write(&at(0), 0x00, 4, HSION | HSEON).unwrap();
        assert_eq!(rcc.read(&at(HSE_STARTUP - 1), 0x00, 4).unwrap() & HSERDY, 0);
        assert_ne!(rcc.read(&at(HSE_STARTUP), 0x00, 4).unwrap() & HSERDY, 0);
        rcc.write(&at(HSE_STARTUP), 0x04, 4, 4 | (168 << 6) | (1 << 22))
            .unwrap();
        rcc.write(&at(HSE_STARTUP), 0x00, 4, HSION | HSEON | PLLON)
            .unwrap();
        let locked = HSE_STARTUP + PLL_LOCK;
        assert_eq!(rcc.read(&at(locked - 1), 0x00, 4).unwrap() & PLLRDY, 0);
        assert_ne!(rcc.read(&at(locked), 0x00, 4).unwrap() & PLLRDY, 0);
    }

    #[test]
    fn rm0090_7_3_3_sws_follows_sw_and_the_board_tree_gives_168_42_84_mhz() {
        let mut rcc = Rcc::new(BOARD_HSE);
        assert_eq!(rcc.clocks(), Clocks::RESET);
        let now = configure_168_mhz(&mut rcc, 0);
        assert_eq!((rcc.read(&at(now), 0x08, 4).unwrap() >> 2) & 3, 2);
        assert_eq!(
            rcc.clocks(),
            Clocks {
                sysclk: 168_000_000,
                hclk: 168_000_000,
                pclk1: 42_000_000,
                pclk2: 84_000_000,
            }
        );
    }

    #[test]
    fn rm0090_7_3_3_a_switch_to_a_source_not_ready_waits_for_it() {
        let mut rcc = Rcc::new(BOARD_HSE);
        rcc.write(&at(0), 0x00, 4, HSION | HSEON).unwrap();
        rcc.write(&at(0), 0x08, 4, 1).unwrap();
        assert_eq!((rcc.read(&at(0), 0x08, 4).unwrap() >> 2) & 3, 0);
        assert_eq!(rcc.next_event(&at(0)), Some(HSE_STARTUP));
        rcc.advance(&at(HSE_STARTUP));
        assert_eq!((rcc.read(&at(HSE_STARTUP), 0x08, 4).unwrap() >> 2) & 3, 1);
        assert_eq!(rcc.clocks().sysclk, 8_000_000);
    }

    #[test]
    fn rm0090_7_3_1_an_hse_that_fails_to_start_never_sets_hserdy_nor_locks_the_pll() {
        let mut rcc = Rcc::new(Hse::FailsToStart);
        rcc.write(&at(0), 0x04, 4, 4 | (168 << 6) | (1 << 22))
            .unwrap();
        rcc.write(&at(0), 0x00, 4, HSION | HSEON | PLLON).unwrap();
        let cr = rcc.read(&at(1_000_000_000), 0x00, 4).unwrap();
        assert_eq!(cr & (HSERDY | PLLRDY), 0);
        rcc.write(&at(0), 0x08, 4, 2).unwrap();
        assert_eq!(rcc.clocks(), Clocks::RESET);
    }

    #[test]
    fn rm0090_7_3_21_reset_flags_record_the_cause_and_rmvf_clears_them() {
        let rcc = Rcc::new(BOARD_HSE);
        assert_eq!(rcc.reset_flags(), PORRSTF | PINRSTF | BORRSTF);
        let mut rcc = rcc.after_reset(ResetCause::IndependentWatchdog, 5);
        assert_ne!(rcc.reset_flags() & IWDGRSTF, 0);
        rcc.write(&at(5), 0x74, 4, RMVF).unwrap();
        assert_eq!(rcc.reset_flags(), 0);
        let rcc = rcc.after_reset(ResetCause::Software, 6);
        assert_eq!(rcc.reset_flags(), SFTRSTF | PINRSTF);
    }

    #[test]
    fn rm0090_7_3_21_lsi_ready_after_its_start_up_time() {
        let mut rcc = Rcc::new(BOARD_HSE);
        rcc.write(&at(0), 0x74, 4, LSION).unwrap();
        assert_eq!(rcc.read(&at(0), 0x74, 4).unwrap() & LSIRDY, 0);
        assert_ne!(rcc.read(&at(LSI_STARTUP), 0x74, 4).unwrap() & LSIRDY, 0);
    }

    #[test]
    fn rm0090_5_1_2_bdcr_is_write_protected_until_dbp() {
        let mut rcc = Rcc::new(BOARD_HSE);
        rcc.write(&at(0), 0x70, 4, 0x8200).unwrap();
        assert_eq!(rcc.read(&at(0), 0x70, 4).unwrap(), 0);
        rcc.set_backup_writable(true);
        rcc.write(&at(0), 0x70, 4, 0x8200).unwrap();
        assert_eq!(rcc.read(&at(0), 0x70, 4).unwrap(), 0x8200);
    }

    #[test]
    fn rm0090_7_3_24_the_f42x_dckcfgr_is_reserved_here_reads_zero_and_refuses_a_selection() {
        let mut rcc = Rcc::new(BOARD_HSE);
        assert_eq!(rcc.read(&at(0), DCKCFGR_F42X, 4).unwrap(), 0);
        rcc.write(&at(0), DCKCFGR_F42X, 4, 0).unwrap();
        assert!(rcc.write(&at(0), DCKCFGR_F42X, 4, 1 << 27).is_err());
    }

    #[test]
    fn rm0090_7_3_unmodelled_offsets_and_widths_are_refused() {
        let mut rcc = Rcc::new(BOARD_HSE);
        assert!(rcc.read(&at(0), 0x88, 4).is_err());
        assert!(rcc.read(&at(0), 0x00, 2).is_err());
    }
}
