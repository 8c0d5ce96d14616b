//! The MCU debug component of the STM32F405 (RM0090 38, "Debug support"): DBGMCU_IDCODE,
//! DBGMCU_CR and the freeze registers DBGMCU_APB1_FZ and DBGMCU_APB2_FZ, on the private
//! peripheral bus at 0xE004_2000.
//!
//! No debugger is attached to the emulated MCU and its core never halts, so the freeze bits
//! (which stop timers and watchdogs while the core is halted) and the low-power debug bits
//! are stored and read back but change nothing.

use super::{AccessError, Context, Peripheral};

/// The block's base address (RM0090 38, MCU device ID code).
pub const BASE: u32 = 0xE004_2000;
/// The block's size.
pub const SIZE: u32 = 0x10;
const NAME: &str = "DBGMCU (RM0090 38)";

/// DEV_ID of the STM32F405/407/415/417 (RM0090 38, DBGMCU_IDCODE).
pub const DEV_ID: u32 = 0x413;
/// REV_ID of the emulated part: revision 2 (one of the revision codes RM0090 lists; the
/// images do not depend on it).
pub const REV_ID: u32 = 0x1007;
/// DBGMCU_IDCODE.
pub const IDCODE: u32 = (REV_ID << 16) | DEV_ID;
/// DBGMCU_CR's bits: DBG_SLEEP, DBG_STOP, DBG_STANDBY, TRACE_IOEN, TRACE_MODE.
const CR_WRITABLE: u32 = 0b111 | (1 << 5) | (0b11 << 6);
/// DBGMCU_APB1_FZ's bits: the timers 2-7 and 12-14, RTC, WWDG, IWDG, I2C1-3 SMBus timeouts,
/// CAN1 and CAN2.
const APB1_FZ_WRITABLE: u32 =
    0x01FF | (1 << 10) | (1 << 11) | (1 << 12) | (0b111 << 21) | (0b11 << 25);
/// DBGMCU_APB2_FZ's bits: TIM1, TIM8, TIM9, TIM10, TIM11.
const APB2_FZ_WRITABLE: u32 = 0b11 | (0b111 << 16);

/// The DBGMCU model.
#[derive(Clone, Debug, Default)]
pub struct Dbgmcu {
    cr: u32,
    apb1_fz: u32,
    apb2_fz: u32,
}

impl Dbgmcu {
    /// The reset state: every bit 0.
    pub fn new() -> Dbgmcu {
        Dbgmcu::default()
    }

    /// DBGMCU_APB1_FZ as written (for tests of what the image asked for).
    pub fn apb1_freeze(&self) -> u32 {
        self.apb1_fz
    }
}

impl Peripheral for Dbgmcu {
    fn name(&self) -> &'static str {
        NAME
    }

    fn read(&mut self, _ctx: &Context, offset: u32, size: u32) -> Result<u32, AccessError> {
        if size != 4 {
            return Err(AccessError::Width {
                block: NAME,
                offset,
                size,
            });
        }
        match offset {
            0x0 => Ok(IDCODE),
            0x4 => Ok(self.cr),
            0x8 => Ok(self.apb1_fz),
            0xC => Ok(self.apb2_fz),
            _ => Err(AccessError::Unmodelled {
                block: NAME,
                offset,
            }),
        }
    }

    fn write(
        &mut self,
        _ctx: &Context,
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
        match offset {
            // IDCODE is read-only.
            0x0 => {}
            0x4 => self.cr = value & CR_WRITABLE,
            0x8 => self.apb1_fz = value & APB1_FZ_WRITABLE,
            0xC => self.apb2_fz = value & APB2_FZ_WRITABLE,
            _ => {
                return Err(AccessError::Unmodelled {
                    block: NAME,
                    offset,
                });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::time::Clocks;

    const CTX: Context = Context {
        now: 0,
        clocks: Clocks::RESET,
    };

    #[test]
    fn rm0090_38_idcode_names_the_f405_and_is_read_only() {
        let mut dbgmcu = Dbgmcu::new();
        assert_eq!(dbgmcu.read(&CTX, 0, 4).unwrap() & 0xFFF, 0x413);
        dbgmcu.write(&CTX, 0, 4, 0).unwrap();
        assert_eq!(dbgmcu.read(&CTX, 0, 4).unwrap(), IDCODE);
    }

    #[test]
    fn rm0090_38_cr_and_apb1_fz_keep_their_bits() {
        let mut dbgmcu = Dbgmcu::new();
        dbgmcu.write(&CTX, 4, 4, u32::MAX).unwrap();
        assert_eq!(dbgmcu.read(&CTX, 4, 4).unwrap(), CR_WRITABLE);
        // DBG_IWDG_STOP and DBG_CAN1_STOP.
        dbgmcu.write(&CTX, 8, 4, (1 << 12) | (1 << 25)).unwrap();
        assert_eq!(dbgmcu.apb1_freeze(), (1 << 12) | (1 << 25));
        assert!(dbgmcu.read(&CTX, 0x10, 4).is_err());
    }
}
