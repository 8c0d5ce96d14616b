//! The embedded flash memory interface (RM0090 3, registers at 0x4002_3C00) and the 1 MiB
//! flash array of the STM32F405 it programs and erases, with a power cut that can be
//! injected during any program or erase operation.
//!
//! Section numbers follow RM0090's later revisions (3.5 read interface, 3.6 erase and
//! program operations, 3.7 option bytes, 3.9 registers); older revisions number the erase
//! and program section 3.5.
//!
//! Modelled:
//! - ACR (3.5, 3.9.1): LATENCY, PRFTEN, ICEN, DCEN stored and readable, ICRST and DCRST
//!   writable only while their cache is disabled; [`Flash::accelerator`] for the CPU side.
//! - KEYR (3.6.1): 0x45670123 then 0xCDEF89AB clears CR.LOCK; any wrong sequence is a bus
//!   error ([`Flash::take_bus_error`]) and locks CR until reset. Setting LOCK locks again.
//!   A KEYR write while CR is unlocked is ignored (the manual does not say).
//! - OPTKEYR (3.7.2): 0x08192A3B then 0x4C5D6E7F clears OPTCR.OPTLOCK, a wrong sequence is
//!   a bus error and locks OPTCR until reset; OPTCR is stored, but starting an option byte
//!   program (OPTSTRT) is refused.
//! - CR and SR (3.6, 3.9.4, 3.9.5): sector erase (SER, SNB, STRT) and mass erase (MER,
//!   STRT), not both at once (neither happens); programming (PG) by a write to the array
//!   through [`Flash::program`]: the access must match PSIZE (else PGPERR), stay in one
//!   128-bit row (else PGAERR), have PG set (else PGSERR) and not target a write-protected
//!   sector (else WRPERR); any of these leaves the array untouched and sets OPERR too when
//!   ERRIE = 1. BSY during an operation, EOP at its end when EOPIE = 1. Programming can
//!   only clear bits (3.6.4: "writing '1' requires a flash memory erase operation"): the
//!   array holds the AND of the old and the written value.
//! - The sector map of RM0090 Table 5 (1 MiB: four 16 KiB, one 64 KiB, seven 128 KiB).
//! - Durations: the STM32F405xx/07xx datasheet (DS8626, "Flash memory programming" table),
//!   typical column, per parallelism: [`WORD_PROGRAM_TIME`], [`SECTOR_ERASE_16K`],
//!   [`SECTOR_ERASE_64K`], [`SECTOR_ERASE_128K`], [`MASS_ERASE`]. The x64 parallelism needs
//!   an external VPP the model does not have; it takes the x32 figures.
//! - Stall (3.6, note on BSY): an access to CR or to the array while BSY stalls the bus
//!   until the operation ends. The CPU side waits until [`Flash::busy_until`]; if it calls
//!   anyway, the model finishes the operation first, as if the stall happened.
//! - Interrupt (3.6.5): EOP·EOPIE or OPERR·ERRIE on IRQ 4 (RM0090 Table 61).
//! - Power cut ([`Flash::cut_power_at`]): the chosen operation stops half done, as a real
//!   cut may leave it (the datasheet promises nothing about the order bits change in): a
//!   program with a seeded subset of its bits cleared, an erase with each 128-bit row
//!   seeded to erased, untouched or with a subset of its bits set. The array keeps that
//!   content; [`Flash::with_memory`] powers a new flash interface on it.
//!
//! Not modelled: read protection levels, the OTP area and the option bytes' effect (the
//! write-protected sectors are given with [`Flash::set_write_protected`]), flash wait
//! states' effect on timing (the CPU side reads [`Flash::accelerator`]), the caches'
//! contents, erase suspend by reads (reads stall). Registers take word accesses only
//! (3.9: "accessed by words"); bytes and half-words are refused.

use super::{AccessError, Context, Peripheral};
use crate::time::Nanos;

/// The flash interface registers' base address.
pub const BASE: u32 = 0x4002_3C00;
/// The register block's size.
pub const SIZE: u32 = 0x400;
/// The flash array's address in the memory map.
pub const MEMORY_BASE: u32 = 0x0800_0000;
/// The F405's flash array size: 1 MiB.
pub const MEMORY_SIZE: usize = 1 << 20;
/// FLASH global interrupt (RM0090 Table 61).
pub const IRQ: u32 = 4;

/// The sectors of RM0090 Table 5: offset from [`MEMORY_BASE`] and size.
pub const SECTORS: [(u32, u32); 12] = [
    (0x0_0000, 16 << 10),
    (0x0_4000, 16 << 10),
    (0x0_8000, 16 << 10),
    (0x0_C000, 16 << 10),
    (0x1_0000, 64 << 10),
    (0x2_0000, 128 << 10),
    (0x4_0000, 128 << 10),
    (0x6_0000, 128 << 10),
    (0x8_0000, 128 << 10),
    (0xA_0000, 128 << 10),
    (0xC_0000, 128 << 10),
    (0xE_0000, 128 << 10),
];

const MILLISECOND: Nanos = 1_000_000;

/// Word (access) programming time, any parallelism (DS8626, t_prog typical).
pub const WORD_PROGRAM_TIME: Nanos = 16_000;
/// 16 KiB sector erase time at x8, x16, x32 (DS8626, t_ERASE16KB typical).
pub const SECTOR_ERASE_16K: [Nanos; 3] = [400 * MILLISECOND, 300 * MILLISECOND, 250 * MILLISECOND];
/// 64 KiB sector erase time at x8, x16, x32 (DS8626, t_ERASE64KB typical).
pub const SECTOR_ERASE_64K: [Nanos; 3] =
    [1_200 * MILLISECOND, 700 * MILLISECOND, 550 * MILLISECOND];
/// 128 KiB sector erase time at x8, x16, x32 (DS8626, t_ERASE128KB typical).
pub const SECTOR_ERASE_128K: [Nanos; 3] = [
    2_000 * MILLISECOND,
    1_300 * MILLISECOND,
    1_000 * MILLISECOND,
];
/// Mass erase time at x8, x16, x32 (DS8626, t_ME typical).
pub const MASS_ERASE: [Nanos; 3] = [
    16_000 * MILLISECOND,
    11_000 * MILLISECOND,
    8_000 * MILLISECOND,
];

const NAME: &str = "FLASH interface (RM0090 3)";
const LINES: [u32; 1] = [IRQ];

/// The control register's unlock keys (RM0090 3.6.1).
const KEYS: [u32; 2] = [0x4567_0123, 0xCDEF_89AB];
/// The option control register's unlock keys (RM0090 3.7.2).
const OPTION_KEYS: [u32; 2] = [0x0819_2A3B, 0x4C5D_6E7F];
/// FLASH_OPTCR after reset on a device with default option bytes (RM0090 3.9.6).
const OPTCR_RESET: u32 = 0x0FFF_AAED;

/// FLASH_SR bits (RM0090 3.9.4).
mod sr {
    pub const EOP: u32 = 1 << 0;
    pub const OPERR: u32 = 1 << 1;
    pub const WRPERR: u32 = 1 << 4;
    pub const PGAERR: u32 = 1 << 5;
    pub const PGPERR: u32 = 1 << 6;
    pub const PGSERR: u32 = 1 << 7;
    pub const BSY: u32 = 1 << 16;
    /// The flags cleared by writing 1.
    pub const CLEARABLE: u32 = EOP | OPERR | WRPERR | PGAERR | PGPERR | PGSERR;
}

/// FLASH_CR bits (RM0090 3.9.5).
mod cr {
    pub const PG: u32 = 1 << 0;
    pub const SER: u32 = 1 << 1;
    pub const MER: u32 = 1 << 2;
    pub const STRT: u32 = 1 << 16;
    pub const EOPIE: u32 = 1 << 24;
    pub const ERRIE: u32 = 1 << 25;
    pub const LOCK: u32 = 1 << 31;
    /// PG, SER, MER, SNB, PSIZE, EOPIE, ERRIE: stored as written.
    pub const STORED: u32 = PG | SER | MER | (0xF << 3) | (0x3 << 8) | EOPIE | ERRIE;
}

/// FLASH_ACR bits (RM0090 3.9.1).
mod acr {
    pub const ICEN: u32 = 1 << 9;
    pub const DCEN: u32 = 1 << 10;
    pub const ICRST: u32 = 1 << 11;
    pub const DCRST: u32 = 1 << 12;
    pub const ALL: u32 = 0x7 | (0x3F << 8);
}

/// What an operation does to the array when it ends.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Work {
    /// Program `size` bytes of `value` (little-endian) at array offset `offset`.
    Program {
        offset: usize,
        size: usize,
        value: u64,
    },
    /// Erase sector `sector`.
    SectorErase { sector: usize },
    /// Erase every sector.
    MassErase,
}

#[derive(Clone, Copy, Debug)]
struct Operation {
    work: Work,
    start: Nanos,
    end: Nanos,
    /// Its number since power-on (the step a power cut names).
    step: u64,
}

/// An armed power cut: during operation `step`, from `seed`.
#[derive(Clone, Copy, Debug)]
struct PowerCut {
    step: u64,
    seed: u64,
}

/// The flash interface and its array.
#[derive(Clone, Debug)]
pub struct Flash {
    memory: Vec<u8>,
    access_control: u32,
    control: u32,
    locked: bool,
    key_stage: usize,
    option_locked: bool,
    option_key_stage: usize,
    option_control: u32,
    /// A wrong key sequence locked the control registers until reset.
    locked_until_reset: bool,
    option_locked_until_reset: bool,
    bus_error: bool,
    status: u32,
    operation: Option<Operation>,
    operations_started: u64,
    write_protected: u16,
    power_cut: Option<PowerCut>,
    powered_off: bool,
    now: Nanos,
}

impl Default for Flash {
    fn default() -> Self {
        Self::new()
    }
}

/// splitmix64: a small, well-known generator, so a seed gives the same cut every time.
fn next_random(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Flash {
    /// A flash interface after power-on with an erased array.
    pub fn new() -> Flash {
        Flash::with_memory(vec![0xFF; MEMORY_SIZE])
    }

    /// The flash interface after a system reset (RM0090 7.1.2): the registers at their
    /// reset values, locked, the array as it stands. An operation still in progress is cut
    /// off with nothing of it applied (the model applies an operation at its end).
    pub fn after_reset(&self) -> Flash {
        Flash::with_memory(self.memory.clone())
    }

    /// A flash interface after power-on over `memory` (padded with erased bytes or cut to
    /// 1 MiB): the registers at their reset values, the array as it was left.
    pub fn with_memory(mut memory: Vec<u8>) -> Flash {
        memory.resize(MEMORY_SIZE, 0xFF);
        Flash {
            memory,
            access_control: 0,
            control: 0,
            locked: true,
            key_stage: 0,
            option_locked: true,
            option_key_stage: 0,
            option_control: OPTCR_RESET & !1,
            locked_until_reset: false,
            option_locked_until_reset: false,
            bus_error: false,
            status: 0,
            operation: None,
            operations_started: 0,
            write_protected: 0,
            power_cut: None,
            powered_off: false,
            now: 0,
        }
    }

    /// The array's bytes (offset 0 is [`MEMORY_BASE`]).
    pub fn memory(&self) -> &[u8] {
        &self.memory
    }

    /// The array's bytes, writable: for loading an image before the run.
    pub fn memory_mut(&mut self) -> &mut [u8] {
        &mut self.memory
    }

    /// The array, for powering on a new flash interface after a cut.
    pub fn into_memory(self) -> Vec<u8> {
        self.memory
    }

    /// Reads `size` bytes (1, 2 or 4, little-endian) at `address` in the array; `None`
    /// outside it. A read while BSY stalls on hardware: see [`Flash::busy_until`].
    pub fn read_memory(&self, address: u32, size: u32) -> Option<u32> {
        let offset = address.checked_sub(MEMORY_BASE)? as usize;
        let bytes = self
            .memory
            .get(offset..offset.checked_add(size as usize)?)?;
        Some(
            bytes
                .iter()
                .rev()
                .fold(0u32, |value, byte| (value << 8) | u32::from(*byte)),
        )
    }

    /// LATENCY, PRFTEN, ICEN and DCEN as the software set them (RM0090 3.5).
    pub fn accelerator(&self) -> (u32, bool, bool, bool) {
        let value = self.access_control;
        (
            value & 0x7,
            value & (1 << 8) != 0,
            value & acr::ICEN != 0,
            value & acr::DCEN != 0,
        )
    }

    /// Marks sectors as write-protected (bit n: sector n), as option bytes programmed
    /// before the run would (nWRPn = 0).
    pub fn set_write_protected(&mut self, sectors: u16) {
        self.write_protected = sectors & 0xFFF;
        self.option_control = (self.option_control & !(0xFFF << 16))
            | (u32::from(!self.write_protected & 0xFFF) << 16);
    }

    /// When the operation in progress ends (`None`: not busy): the CPU side stalls an
    /// access to CR or to the array until then.
    pub fn busy_until(&self) -> Option<Nanos> {
        self.operation.map(|operation| operation.end)
    }

    /// Whether a wrong key sequence made a bus error since the last call (the CPU side
    /// raises it as a bus fault).
    pub fn take_bus_error(&mut self) -> bool {
        core::mem::take(&mut self.bus_error)
    }

    /// Arms a power cut during the program or erase operation number `step` (counted from
    /// 0 since power-on): it stops half way, the array left as a cut may leave it, chosen
    /// from `seed`.
    pub fn cut_power_at(&mut self, step: u64, seed: u64) {
        self.power_cut = Some(PowerCut { step, seed });
    }

    /// Program and erase operations started since power-on (the steps
    /// [`Flash::cut_power_at`] counts).
    pub fn operations_started(&self) -> u64 {
        self.operations_started
    }

    /// Whether the armed power cut happened: the run must end here.
    pub fn power_lost(&self) -> bool {
        self.powered_off
    }

    /// The sector holding array offset `offset`.
    fn sector_of(offset: usize) -> usize {
        SECTORS
            .iter()
            .rposition(|&(start, _)| start as usize <= offset)
            .unwrap_or(0)
    }

    fn parallelism(&self) -> usize {
        ((self.control >> 8) & 0x3) as usize
    }

    /// The erase time of a sector at the present parallelism.
    fn erase_time(&self, sector: usize) -> Nanos {
        let column = self.parallelism().min(2);
        match SECTORS[sector].1 >> 10 {
            16 => SECTOR_ERASE_16K[column],
            64 => SECTOR_ERASE_64K[column],
            _ => SECTOR_ERASE_128K[column],
        }
    }

    fn error(&mut self, flags: u32) {
        self.status |= flags;
        if self.control & cr::ERRIE != 0 {
            self.status |= sr::OPERR;
        }
    }

    fn start(&mut self, work: Work, duration: Nanos) {
        let step = self.operations_started;
        self.operations_started += 1;
        self.operation = Some(Operation {
            work,
            start: self.now,
            end: self.now + duration,
            step,
        });
    }

    /// The array range an operation changes.
    fn range(work: Work) -> core::ops::Range<usize> {
        match work {
            Work::Program { offset, size, .. } => offset..offset + size,
            Work::SectorErase { sector } => {
                let (start, size) = SECTORS[sector];
                start as usize..(start + size) as usize
            }
            Work::MassErase => 0..MEMORY_SIZE,
        }
    }

    fn complete(&mut self, operation: Operation) {
        self.operation = None;
        let range = Self::range(operation.work);
        match operation.work {
            Work::Program { value, .. } => {
                for (index, byte) in self.memory[range].iter_mut().enumerate() {
                    *byte &= (value >> (8 * index)) as u8;
                }
            }
            Work::SectorErase { .. } | Work::MassErase => self.memory[range].fill(0xFF),
        }
        if self.control & cr::EOPIE != 0 {
            self.status |= sr::EOP;
        }
    }

    /// The armed cut happens during `operation`: leave the array half changed.
    fn cut(&mut self, operation: Operation, seed: u64) {
        self.operation = None;
        self.powered_off = true;
        let mut state = seed ^ operation.step;
        let range = Self::range(operation.work);
        match operation.work {
            Work::Program { value, .. } => {
                for (index, byte) in self.memory[range].iter_mut().enumerate() {
                    let target = *byte & (value >> (8 * index)) as u8;
                    // Of the bits going from 1 to 0, a seeded subset made it.
                    let programmed = (*byte & !target) & next_random(&mut state) as u8;
                    *byte &= !programmed;
                }
            }
            Work::SectorErase { .. } | Work::MassErase => {
                for row in self.memory[range].chunks_mut(16) {
                    match next_random(&mut state) % 3 {
                        0 => row.fill(0xFF),
                        1 => {}
                        _ => {
                            for byte in row {
                                *byte |= next_random(&mut state) as u8;
                            }
                        }
                    }
                }
            }
        }
    }

    fn run_until(&mut self, now: Nanos) {
        if let Some(operation) = self.operation {
            let cut = self
                .power_cut
                .filter(|cut| cut.step == operation.step && !self.powered_off);
            if let Some(cut) = cut {
                let middle = operation.start + (operation.end - operation.start) / 2;
                if middle <= now {
                    self.now = self.now.max(middle);
                    self.cut(operation, cut.seed);
                }
            } else if operation.end <= now {
                self.now = self.now.max(operation.end);
                self.complete(operation);
            }
        }
        self.now = self.now.max(now);
    }

    /// A stalled access: the operation in progress ends first.
    fn stall(&mut self) {
        if let Some(operation) = self.operation {
            let until = if self.power_cut.is_some_and(|cut| cut.step == operation.step) {
                operation.start + (operation.end - operation.start) / 2
            } else {
                operation.end
            };
            self.run_until(until);
        }
    }

    /// A write of `size` bytes of `value` at `address` in the array (the CPU's store):
    /// programs it if the interface is set up for it, else sets the error flag the manual
    /// names and leaves the array as it was.
    pub fn program(&mut self, address: u32, size: u32, value: u64, ctx: &Context) {
        self.run_until(ctx.now);
        if self.powered_off {
            return;
        }
        self.stall();
        let Some(offset) = address
            .checked_sub(MEMORY_BASE)
            .map(|offset| offset as usize)
            .filter(|&offset| offset < MEMORY_SIZE)
        else {
            return;
        };
        let size = size as usize;
        let mut errors = 0;
        if self.control & cr::PG == 0 {
            // Not a program sequence: the alignment and size rules do not apply.
            errors |= sr::PGSERR;
        } else {
            if offset % 16 + size > 16 || offset + size > MEMORY_SIZE {
                errors |= sr::PGAERR;
            }
            if size != 1 << self.parallelism() {
                errors |= sr::PGPERR;
            }
            if self.write_protected & (1 << Self::sector_of(offset)) != 0 {
                errors |= sr::WRPERR;
            }
        }
        if errors != 0 {
            self.error(errors);
            return;
        }
        self.start(
            Work::Program {
                offset,
                size,
                value,
            },
            WORD_PROGRAM_TIME,
        );
    }

    fn write_control(&mut self, value: u32) -> Result<(), AccessError> {
        if self.locked {
            return Ok(());
        }
        self.control = value & cr::STORED;
        if value & cr::LOCK != 0 {
            self.locked = true;
        }
        if value & cr::STRT == 0 {
            return Ok(());
        }
        match (value & cr::SER != 0, value & cr::MER != 0) {
            (true, false) => {
                let sector = ((value >> 3) & 0xF) as usize;
                if sector >= SECTORS.len() {
                    // The F405 has twelve sectors; what SNB 12 to 15 do is not modelled.
                    return Err(AccessError::Unmodelled {
                        block: NAME,
                        offset: 0x10,
                    });
                }
                if self.write_protected & (1 << sector) != 0 {
                    self.error(sr::WRPERR);
                } else {
                    let duration = self.erase_time(sector);
                    self.start(Work::SectorErase { sector }, duration);
                }
            }
            (false, true) => {
                if self.write_protected != 0 {
                    self.error(sr::WRPERR);
                } else {
                    let duration = MASS_ERASE[self.parallelism().min(2)];
                    self.start(Work::MassErase, duration);
                }
            }
            // Neither, or both: no erase (RM0090 3.6.3 note).
            _ => {}
        }
        Ok(())
    }

    /// One key of an unlock sequence; a wrong one locks until reset with a bus error.
    fn key(
        value: u32,
        keys: [u32; 2],
        stage: &mut usize,
        locked: &mut bool,
        locked_until_reset: &mut bool,
        bus_error: &mut bool,
    ) {
        if *locked_until_reset {
            *bus_error = true;
            return;
        }
        if !*locked {
            return;
        }
        if value == keys[*stage] {
            *stage += 1;
            if *stage == 2 {
                *stage = 0;
                *locked = false;
            }
        } else {
            *stage = 0;
            *locked_until_reset = true;
            *bus_error = true;
        }
    }
}

impl Peripheral for Flash {
    fn name(&self) -> &'static str {
        NAME
    }

    fn read(&mut self, ctx: &Context, offset: u32, size: u32) -> Result<u32, AccessError> {
        self.run_until(ctx.now);
        if size != 4 {
            return Err(AccessError::Width {
                block: NAME,
                offset,
                size,
            });
        }
        Ok(match offset {
            0x00 => self.access_control,
            0x04 | 0x08 => 0,
            0x0C => self.status | (u32::from(self.operation.is_some()) * sr::BSY),
            0x10 => {
                self.control
                    | (u32::from(self.operation.is_some()) * cr::STRT)
                    | (u32::from(self.locked) * cr::LOCK)
            }
            0x14 => self.option_control | u32::from(self.option_locked),
            _ => {
                return Err(AccessError::Unmodelled {
                    block: NAME,
                    offset,
                });
            }
        })
    }

    fn write(
        &mut self,
        ctx: &Context,
        offset: u32,
        size: u32,
        value: u32,
    ) -> Result<(), AccessError> {
        self.run_until(ctx.now);
        if size != 4 {
            return Err(AccessError::Width {
                block: NAME,
                offset,
                size,
            });
        }
        match offset {
            0x00 => {
                let mut value = value & acr::ALL;
                if self.access_control & acr::ICEN != 0 {
                    value = (value & !acr::ICRST) | (self.access_control & acr::ICRST);
                }
                if self.access_control & acr::DCEN != 0 {
                    value = (value & !acr::DCRST) | (self.access_control & acr::DCRST);
                }
                self.access_control = value;
            }
            0x04 => Self::key(
                value,
                KEYS,
                &mut self.key_stage,
                &mut self.locked,
                &mut self.locked_until_reset,
                &mut self.bus_error,
            ),
            0x08 => Self::key(
                value,
                OPTION_KEYS,
                &mut self.option_key_stage,
                &mut self.option_locked,
                &mut self.option_locked_until_reset,
                &mut self.bus_error,
            ),
            0x0C => self.status &= !(value & sr::CLEARABLE),
            0x10 => {
                self.stall();
                return self.write_control(value);
            }
            0x14 => {
                if !self.option_locked {
                    if value & (1 << 1) != 0 {
                        // OPTSTRT: option byte programming is not modelled.
                        return Err(AccessError::Unmodelled {
                            block: NAME,
                            offset,
                        });
                    }
                    self.option_control = value & 0x0FFF_FFEC;
                    if value & 1 != 0 {
                        self.option_locked = true;
                    }
                }
            }
            _ => {
                return Err(AccessError::Unmodelled {
                    block: NAME,
                    offset,
                });
            }
        }
        Ok(())
    }

    fn advance(&mut self, ctx: &Context) {
        self.run_until(ctx.now);
    }

    fn next_event(&self, _ctx: &Context) -> Option<Nanos> {
        let operation = self.operation?;
        if self.power_cut.is_some_and(|cut| cut.step == operation.step) {
            Some(operation.start + (operation.end - operation.start) / 2)
        } else {
            Some(operation.end)
        }
    }

    fn interrupt_lines(&self) -> &'static [u32] {
        &LINES
    }

    fn interrupt(&self, irq: u32) -> bool {
        irq == IRQ
            && ((self.control & cr::EOPIE != 0 && self.status & sr::EOP != 0)
                || (self.control & cr::ERRIE != 0 && self.status & sr::OPERR != 0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::time::Clocks;

    const ACR: u32 = 0x00;
    const KEYR: u32 = 0x04;
    const OPTKEYR: u32 = 0x08;
    const SR: u32 = 0x0C;
    const CR: u32 = 0x10;
    const OPTCR: u32 = 0x14;
    /// PSIZE x32.
    const X32: u32 = 0b10 << 8;

    type Bench = crate::peripherals::bench::Bench<Flash>;

    impl Bench {
        fn new() -> Bench {
            Bench::on(Flash::new(), Clocks::RESET)
        }

        fn unlock(&mut self) {
            self.write(KEYR, KEYS[0]);
            self.write(KEYR, KEYS[1]);
        }

        fn program(&mut self, address: u32, size: u32, value: u64) {
            let ctx = self.ctx();
            self.model.program(address, size, value, &ctx);
        }

        fn word(&self, address: u32) -> u32 {
            self.model.read_memory(address, 4).expect("in the array")
        }
    }

    #[test]
    fn rm0090_3_9_registers_after_reset() {
        let mut bench = Bench::new();
        assert_eq!(bench.read(ACR), 0);
        assert_eq!(bench.read(SR), 0);
        assert_eq!(bench.read(CR), 0x8000_0000);
        assert_eq!(bench.read(OPTCR), 0x0FFF_AAED);
        assert_eq!(bench.word(MEMORY_BASE), 0xFFFF_FFFF);
    }

    #[test]
    fn rm0090_3_5_acr_latency_and_accelerator_bits_read_back() {
        let mut bench = Bench::new();
        bench.write(ACR, 5 | (1 << 8) | acr::ICEN | acr::DCEN);
        assert_eq!(bench.read(ACR), 5 | (1 << 8) | acr::ICEN | acr::DCEN);
        assert_eq!(bench.model.accelerator(), (5, true, true, true));
    }

    #[test]
    fn rm0090_3_9_1_cache_reset_bits_are_written_only_with_the_cache_disabled() {
        let mut bench = Bench::new();
        bench.write(ACR, acr::ICEN | acr::DCEN);
        bench.write(ACR, acr::ICEN | acr::DCEN | acr::ICRST | acr::DCRST);
        assert_eq!(bench.read(ACR) & (acr::ICRST | acr::DCRST), 0);
        bench.write(ACR, 0);
        bench.write(ACR, acr::ICRST | acr::DCRST);
        assert_eq!(bench.read(ACR), acr::ICRST | acr::DCRST);
    }

    #[test]
    fn rm0090_3_6_1_the_key_sequence_unlocks_cr() {
        let mut bench = Bench::new();
        bench.write(CR, cr::PG);
        assert_eq!(bench.read(CR), cr::LOCK, "locked: the write is ignored");
        bench.unlock();
        bench.write(CR, cr::PG);
        assert_eq!(bench.read(CR), cr::PG);
        assert!(!bench.model.take_bus_error());
    }

    #[test]
    fn rm0090_3_6_1_a_wrong_key_is_a_bus_error_and_locks_until_reset() {
        let mut bench = Bench::new();
        bench.write(KEYR, KEYS[0]);
        bench.write(KEYR, 0x1234_5678);
        assert!(bench.model.take_bus_error());
        bench.unlock();
        assert!(bench.model.take_bus_error(), "still a bus error");
        bench.write(CR, cr::PG);
        assert_eq!(bench.read(CR), cr::LOCK);
        let mut fresh = Bench::on(Flash::with_memory(bench.model.into_memory()), Clocks::RESET);
        fresh.unlock();
        fresh.write(CR, cr::PG);
        assert_eq!(fresh.read(CR), cr::PG, "a reset ends the lock");
    }

    #[test]
    fn rm0090_3_9_5_setting_lock_locks_cr_again() {
        let mut bench = Bench::new();
        bench.unlock();
        bench.write(CR, cr::LOCK);
        bench.write(CR, cr::PG);
        assert_eq!(bench.read(CR), cr::LOCK);
    }

    #[test]
    fn rm0090_3_6_4_a_word_program_is_busy_for_the_datasheet_time_then_in_the_array() {
        let mut bench = Bench::new();
        bench.unlock();
        bench.write(CR, cr::PG | X32 | cr::EOPIE);
        bench.program(MEMORY_BASE + 0x100, 4, 0x1234_5678);
        assert_ne!(bench.read(SR) & sr::BSY, 0);
        assert_eq!(bench.model.busy_until(), Some(WORD_PROGRAM_TIME));
        bench.wait(WORD_PROGRAM_TIME - 1);
        assert_ne!(bench.read(SR) & sr::BSY, 0);
        bench.wait(1);
        assert_eq!(bench.read(SR), sr::EOP);
        assert_eq!(bench.word(MEMORY_BASE + 0x100), 0x1234_5678);
        assert!(bench.model.interrupt(IRQ));
        bench.write(SR, sr::EOP);
        assert!(!bench.model.interrupt(IRQ));
    }

    #[test]
    fn rm0090_3_9_4_eop_is_set_only_with_eopie() {
        let mut bench = Bench::new();
        bench.unlock();
        bench.write(CR, cr::PG | X32);
        bench.program(MEMORY_BASE, 4, 0);
        bench.wait(WORD_PROGRAM_TIME);
        assert_eq!(bench.read(SR), 0);
    }

    #[test]
    fn rm0090_3_6_4_programming_can_only_clear_bits() {
        let mut bench = Bench::new();
        bench.unlock();
        bench.write(CR, cr::PG | X32);
        bench.program(MEMORY_BASE, 4, 0xF0F0_F0F0);
        bench.wait(WORD_PROGRAM_TIME);
        bench.program(MEMORY_BASE, 4, 0xFF00_FF00);
        bench.wait(WORD_PROGRAM_TIME);
        assert_eq!(bench.word(MEMORY_BASE), 0xF000_F000);
        assert_eq!(bench.read(SR) & !sr::EOP, 0, "no error flag");
    }

    #[test]
    fn rm0090_3_9_4_a_write_without_pg_is_a_programming_sequence_error() {
        let mut bench = Bench::new();
        bench.program(MEMORY_BASE, 4, 0);
        assert_eq!(bench.read(SR), sr::PGSERR, "locked, PG clear");
        bench.unlock();
        bench.write(CR, X32 | cr::ERRIE);
        bench.program(MEMORY_BASE, 4, 0);
        assert_eq!(bench.read(SR), sr::PGSERR | sr::OPERR, "OPERR with ERRIE");
        assert!(bench.model.interrupt(IRQ));
        assert_eq!(bench.word(MEMORY_BASE), 0xFFFF_FFFF);
    }

    #[test]
    fn rm0090_3_6_4_the_access_size_must_match_psize() {
        let mut bench = Bench::new();
        bench.unlock();
        bench.write(CR, cr::PG | X32);
        bench.program(MEMORY_BASE, 2, 0);
        assert_eq!(bench.read(SR), sr::PGPERR);
        assert_eq!(bench.model.busy_until(), None);
        bench.write(SR, sr::PGPERR);
        bench.write(CR, cr::PG | (0b01 << 8));
        bench.program(MEMORY_BASE, 2, 0x1234);
        bench.wait(WORD_PROGRAM_TIME);
        assert_eq!(bench.read(SR), 0);
        assert_eq!(bench.word(MEMORY_BASE), 0xFFFF_1234);
    }

    #[test]
    fn rm0090_3_6_4_data_crossing_a_128_bit_row_is_an_alignment_error() {
        let mut bench = Bench::new();
        bench.unlock();
        bench.write(CR, cr::PG | X32);
        bench.program(MEMORY_BASE + 14, 4, 0);
        assert_eq!(bench.read(SR), sr::PGAERR);
        bench.write(SR, sr::PGAERR);
        bench.program(MEMORY_BASE + 12, 4, 0);
        bench.wait(WORD_PROGRAM_TIME);
        assert_eq!(bench.read(SR), 0);
    }

    #[test]
    fn rm0090_3_6_3_sector_erase_takes_the_datasheet_time_and_sets_the_sector_to_ff() {
        let mut bench = Bench::new();
        for byte in &mut bench.model.memory_mut()[..0x2_0000 + 16] {
            *byte = 0;
        }
        bench.unlock();
        bench.write(CR, cr::SER | (1 << 3) | X32 | cr::EOPIE);
        bench.write(CR, cr::SER | (1 << 3) | X32 | cr::EOPIE | cr::STRT);
        assert_ne!(bench.read(CR) & cr::STRT, 0, "STRT reads 1 while busy");
        assert_eq!(bench.model.busy_until(), Some(SECTOR_ERASE_16K[2]));
        bench.wait(SECTOR_ERASE_16K[2]);
        assert_eq!(bench.read(SR), sr::EOP);
        assert_eq!(bench.read(CR) & cr::STRT, 0);
        let memory = bench.model.memory();
        assert!(memory[0x4000..0x8000].iter().all(|&byte| byte == 0xFF));
        assert!(memory[..0x4000].iter().all(|&byte| byte == 0));
        assert!(memory[0x8000..0x2_0000].iter().all(|&byte| byte == 0));
        // A 128 KiB sector at x8.
        bench.write(CR, cr::SER | (5 << 3) | cr::STRT);
        assert_eq!(
            bench.model.busy_until(),
            Some(bench.now + SECTOR_ERASE_128K[0])
        );
    }

    #[test]
    fn rm0090_3_6_3_mass_erase_erases_every_sector() {
        let mut bench = Bench::new();
        bench.model.memory_mut().fill(0);
        bench.unlock();
        bench.write(CR, cr::MER | X32 | cr::STRT);
        bench.wait(MASS_ERASE[2]);
        assert!(bench.model.memory().iter().all(|&byte| byte == 0xFF));
    }

    #[test]
    fn rm0090_3_6_3_mer_and_ser_together_erase_nothing() {
        let mut bench = Bench::new();
        bench.model.memory_mut().fill(0);
        bench.unlock();
        bench.write(CR, cr::MER | cr::SER | cr::STRT);
        assert_eq!(bench.model.busy_until(), None);
        assert_eq!(bench.word(MEMORY_BASE), 0);
    }

    #[test]
    fn rm0090_table_5_sector_map_of_the_1_mib_array() {
        let sizes: Vec<u32> = SECTORS.iter().map(|&(_, size)| size >> 10).collect();
        assert_eq!(
            sizes,
            [16, 16, 16, 16, 64, 128, 128, 128, 128, 128, 128, 128]
        );
        let mut next = 0;
        for (start, size) in SECTORS {
            assert_eq!(start, next, "contiguous");
            next = start + size;
        }
        assert_eq!(next as usize, MEMORY_SIZE);
        assert_eq!(Flash::sector_of(0x1_FFFF), 4);
        assert_eq!(Flash::sector_of(0x2_0000), 5);
    }

    #[test]
    fn rm0090_3_9_4_a_write_protected_sector_gives_wrperr() {
        let mut bench = Bench::new();
        bench.model.set_write_protected(1 << 2);
        assert_eq!(bench.read(OPTCR) >> 16, 0xFFB);
        bench.unlock();
        bench.write(CR, cr::SER | (2 << 3) | X32 | cr::STRT);
        assert_eq!(bench.read(SR), sr::WRPERR);
        bench.write(CR, cr::PG | X32);
        bench.program(MEMORY_BASE + 0x8000, 4, 0);
        assert_eq!(bench.read(SR), sr::WRPERR);
        assert_eq!(bench.word(MEMORY_BASE + 0x8000), 0xFFFF_FFFF);
        bench.write(CR, cr::MER | X32 | cr::STRT);
        assert_eq!(bench.model.busy_until(), None, "mass erase refused too");
    }

    #[test]
    fn rm0090_3_6_an_access_while_busy_stalls_until_the_operation_ends() {
        let mut bench = Bench::new();
        bench.unlock();
        bench.write(CR, cr::PG | X32);
        bench.program(MEMORY_BASE, 4, 0x0000_FFFF);
        bench.program(MEMORY_BASE + 4, 4, 0xFFFF_0000);
        assert_eq!(
            bench.word(MEMORY_BASE),
            0x0000_FFFF,
            "the first ended first"
        );
        assert_eq!(bench.model.busy_until(), Some(2 * WORD_PROGRAM_TIME));
    }

    #[test]
    fn rm0090_3_7_2_option_key_sequence_unlocks_optcr_and_optstrt_is_refused() {
        let mut bench = Bench::new();
        bench.write(OPTCR, 0);
        assert_eq!(bench.read(OPTCR), 0x0FFF_AAED, "locked");
        bench.write(OPTKEYR, OPTION_KEYS[0]);
        bench.write(OPTKEYR, OPTION_KEYS[1]);
        assert_eq!(bench.read(OPTCR) & 1, 0);
        bench.write(OPTCR, 0x0FFF_AAEC & !(1 << 16));
        assert_eq!(bench.read(OPTCR), 0x0FFE_AAEC);
        let ctx = bench.ctx();
        assert!(bench.model.write(&ctx, OPTCR, 4, 0x0FFF_AAEE).is_err());
    }

    #[test]
    fn rm0090_3_9_registers_are_accessed_by_words() {
        let mut bench = Bench::new();
        let ctx = bench.ctx();
        assert!(matches!(
            bench.model.read(&ctx, SR, 2),
            Err(AccessError::Width { .. })
        ));
        assert!(bench.model.read(&ctx, 0x18, 4).is_err());
        assert_eq!(bench.model.interrupt_lines(), &[4]);
    }

    #[test]
    fn ds8626_power_cut_during_a_word_program_leaves_some_bits_programmed() {
        let run = |seed: u64| {
            let mut bench = Bench::new();
            bench.model.cut_power_at(1, seed);
            bench.unlock();
            bench.write(CR, cr::PG | X32);
            bench.program(MEMORY_BASE, 4, 0x1234_5678);
            bench.wait(WORD_PROGRAM_TIME);
            assert!(!bench.model.power_lost(), "operation 0 completes");
            bench.program(MEMORY_BASE + 4, 4, 0x0000_0000);
            assert_eq!(
                bench.model.next_event(&bench.ctx()),
                Some(bench.now + WORD_PROGRAM_TIME / 2)
            );
            bench.wait(WORD_PROGRAM_TIME);
            assert!(bench.model.power_lost());
            (bench.word(MEMORY_BASE), bench.word(MEMORY_BASE + 4))
        };
        let (first, half) = run(7);
        assert_eq!(first, 0x1234_5678);
        assert_ne!(half, 0xFFFF_FFFF, "some bits programmed");
        assert_ne!(half, 0, "not all of them");
        assert_eq!(run(7).1, half, "the same seed, the same word");
        let others: Vec<u32> = (0..8).map(|seed| run(seed).1).collect();
        assert!(others.iter().any(|&word| word != half), "seeds differ");
    }

    #[test]
    fn ds8626_power_cut_during_a_sector_erase_leaves_it_partly_erased() {
        let mut bench = Bench::new();
        bench.model.memory_mut()[..0x4000].fill(0);
        bench.model.cut_power_at(0, 42);
        bench.unlock();
        bench.write(CR, cr::SER | X32 | cr::STRT);
        bench.wait(SECTOR_ERASE_16K[2]);
        assert!(bench.model.power_lost());
        let sector = &bench.model.memory()[..0x4000];
        let erased = sector
            .chunks(16)
            .filter(|row| row.iter().all(|&b| b == 0xFF))
            .count();
        let untouched = sector
            .chunks(16)
            .filter(|row| row.iter().all(|&b| b == 0))
            .count();
        assert!(erased > 0 && untouched > 0 && erased + untouched < 0x4000 / 16);
        let memory = bench.model.into_memory();
        let after = Flash::with_memory(memory.clone());
        assert_eq!(after.memory(), &memory[..], "the array survives the cut");
    }
}
