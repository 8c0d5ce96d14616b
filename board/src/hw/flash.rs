//! The flash interface for the parameter slots, by the board's own code on its registers
//! (RM0090 3.6), and why it is not embassy-stm32's flash driver.
//!
//! The parameter store needs three operations of the STM32F405's flash: read bytes, erase a
//! 128 KiB sector, program one 32-bit word ([`safety_device::parameter_flash::Sectors`]).
//! embassy-stm32 0.6's blocking driver does these through a general layer (a region table for
//! every STM32 family, sectors found by search, an asynchronous variant with its interrupt,
//! the data cache saved and restored for the dual-bank parts' erratum, which the single-bank
//! F405 does not have), none of which the store uses. What is left is written here from
//! RM0090 3.6 (erase and program operations) and 3.9 (registers), and runs on the emulator's
//! model of the flash interface (`emulator/src/peripherals/flash.rs`, written from RM0090),
//! whose power cuts the power-cut sweep injects into every step of a store.
//!
//! The data cache is flushed by the caller after every erase and program (`super::Stm32Sectors`).

use embassy_stm32::Peri;
use embassy_stm32::pac;
use embassy_stm32::peripherals::FLASH;

/// Where the flash array is mapped (RM0090 2.3, Table 5).
const ARRAY: u32 = 0x0800_0000;
/// The STM32F405RG's flash array: 1 MiB.
const ARRAY_SIZE: u32 = 0x0010_0000;
/// Sectors 5 to 11 are 128 KiB each and start at this offset (RM0090 Table 5; sectors 0 to 3
/// are 16 KiB, sector 4 is 64 KiB, and the parameter slots use none of them).
const FIRST_LARGE_SECTOR: u32 = 0x0002_0000;
/// A large sector's size.
const LARGE_SECTOR: u32 = 0x0002_0000;
/// The number of the first large sector.
const FIRST_LARGE_SECTOR_NUMBER: u8 = 5;
/// The key sequence that unlocks FLASH_CR (RM0090 3.6.1).
const KEYS: [u32; 2] = [0x4567_0123, 0xCDEF_89AB];

/// The flash array as the parameter store writes it.
pub struct ParameterFlash {
    _flash: Peri<'static, FLASH>,
}

/// The flash interface refused an operation, or it is not one this driver does (an address
/// outside the array, a range that is not whole large sectors, an unaligned word).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Refused;

impl ParameterFlash {
    /// The driver, owning embassy-stm32's token for the flash interface.
    pub fn new(flash: Peri<'static, FLASH>) -> ParameterFlash {
        ParameterFlash { _flash: flash }
    }

    /// Copies the array's bytes from offset `at` into `buf`.
    pub fn read(&mut self, at: u32, buf: &mut [u8]) -> Result<(), Refused> {
        let len = u32::try_from(buf.len()).map_err(|_| Refused)?;
        let end = at.checked_add(len).ok_or(Refused)?;
        if end > ARRAY_SIZE {
            return Err(Refused);
        }
        // SAFETY: `at..end` lies inside the flash array, which is mapped and readable for the
        // whole run (RM0090 2.3); nothing in this program holds a mutable reference to it, and
        // it changes only through this driver, which `&mut self` keeps from running meanwhile.
        let array = unsafe { core::slice::from_raw_parts((ARRAY + at) as *const u8, buf.len()) };
        buf.copy_from_slice(array);
        Ok(())
    }

    /// Erases the large sectors that make up offsets `from..to` (RM0090 3.6.3: SER, SNB,
    /// STRT, then BSY awaited), at the reset value of the parallelism (x8). The processor
    /// stalls while it runs.
    pub fn erase(&mut self, from: u32, to: u32) -> Result<(), Refused> {
        if from < FIRST_LARGE_SECTOR
            || to > ARRAY_SIZE
            || from >= to
            || (from - FIRST_LARGE_SECTOR) % LARGE_SECTOR != 0
            || (to - FIRST_LARGE_SECTOR) % LARGE_SECTOR != 0
        {
            return Err(Refused);
        }
        let first = (from - FIRST_LARGE_SECTOR) / LARGE_SECTOR;
        let last = (to - FIRST_LARGE_SECTOR) / LARGE_SECTOR;
        let mut result = Ok(());
        unlock();
        for index in first..last {
            // At most 7 large sectors: the number fits.
            let sector = FIRST_LARGE_SECTOR_NUMBER + index as u8;
            pac::FLASH.cr().write(|w| {
                w.set_ser(true);
                w.set_snb(sector);
            });
            pac::FLASH.cr().modify(|w| w.set_strt(true));
            result = finished();
            if result.is_err() {
                break;
            }
        }
        lock();
        result
    }

    /// Programs `word` at offset `at` (RM0090 3.6.4: PG with the x32 parallelism, the word
    /// written to the array, BSY awaited), which must be word-aligned.
    pub fn program(&mut self, at: u32, word: [u8; 4]) -> Result<(), Refused> {
        if at % 4 != 0 || at >= ARRAY_SIZE {
            return Err(Refused);
        }
        unlock();
        pac::FLASH.cr().write(|w| {
            w.set_pg(true);
            w.set_psize(pac::flash::vals::Psize::PSIZE32);
        });
        // SAFETY: a word-aligned address inside the flash array (checked above), written
        // with PG set, as RM0090 3.6.4 prescribes for programming; the array is not a Rust
        // object, so no reference is invalidated.
        unsafe { core::ptr::write_volatile((ARRAY + at) as *mut u32, u32::from_le_bytes(word)) };
        cortex_m::asm::dsb();
        let result = finished();
        lock();
        result
    }
}

/// Unlocks FLASH_CR with the key sequence when it is locked (RM0090 3.6.1; a key written
/// while it is unlocked would be a wrong sequence).
fn unlock() {
    if pac::FLASH.cr().read().lock() {
        for key in KEYS {
            pac::FLASH.keyr().write_value(key);
        }
    }
}

/// Clears the operation bits and locks FLASH_CR again (RM0090 3.9.5: LOCK is set by software
/// and cleared only by the key sequence).
fn lock() {
    pac::FLASH.cr().write(|w| w.set_lock(true));
}

/// Waits while the flash is busy (BSY, RM0090 3.9.4), then reports the operation's error
/// flags (programming sequence, parallelism, alignment, write protection) and clears them
/// (they are cleared by writing 1).
fn finished() -> Result<(), Refused> {
    let status = loop {
        let status = pac::FLASH.sr().read();
        if !status.bsy() {
            break status;
        }
    };
    let failed = status.pgserr() || status.pgperr() || status.pgaerr() || status.wrperr();
    pac::FLASH.sr().write(|w| {
        w.set_pgserr(true);
        w.set_pgperr(true);
        w.set_pgaerr(true);
        w.set_wrperr(true);
        w.set_operr(true);
        w.set_eop(true);
    });
    if failed { Err(Refused) } else { Ok(()) }
}
