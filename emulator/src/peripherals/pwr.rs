//! The power controller of the STM32F405 (RM0090 5): PWR_CR with the regulator's voltage
//! scale (VOS) and the backup domain's write protection (DBP), PWR_CSR with the flags.
//!
//! The regulator is ideal: the scale selected is the scale in force (VOSRDY reads 1), and the
//! backup regulator is ready as soon as it is enabled. Low-power modes (LPDS, PDDS) and the
//! voltage detector (PVDE) are stored but not acted on: the images use neither.

use super::{AccessError, Context, Peripheral};

/// The block's base address (RM0090 2.3, Table 1).
pub const BASE: u32 = 0x4000_7000;
/// The block's size.
pub const SIZE: u32 = 0x400;
const NAME: &str = "PWR (RM0090 5)";

/// PWR_CR.DBP: disable backup domain write protection (RM0090 5.4.1).
const DBP: u32 = 1 << 8;
/// PWR_CR.VOS: scale 1 (the F405's one VOS bit; bit 15 is reserved on this part).
const VOS: u32 = 1 << 14;
/// PWR_CR bits that hold a value: LPDS, PDDS, PVDE, PLS, DBP, FPDS, VOS.
const CR_WRITABLE: u32 = 0b11 | (1 << 4) | (0b111 << 5) | DBP | (1 << 9) | VOS;
/// PWR_CR.CWUF and CSBF: write one to clear CSR.WUF and CSR.SBF; they read as zero.
const CWUF: u32 = 1 << 2;
const CSBF: u32 = 1 << 3;
/// PWR_CSR bits (RM0090 5.4.2).
const WUF: u32 = 1 << 0;
const SBF: u32 = 1 << 1;
const BRR: u32 = 1 << 3;
const EWUP: u32 = 1 << 8;
const BRE: u32 = 1 << 9;
const VOSRDY: u32 = 1 << 14;

/// The PWR model.
#[derive(Clone, Debug)]
pub struct Pwr {
    cr: u32,
    csr: u32,
}

impl Default for Pwr {
    fn default() -> Self {
        Pwr::new()
    }
}

impl Pwr {
    /// The reset state (RM0090 5.4.1: PWR_CR 0x0000 4000, scale 1; 5.4.2: PWR_CSR 0).
    pub fn new() -> Pwr {
        Pwr { cr: VOS, csr: 0 }
    }

    /// PWR_CR.DBP: whether RCC_BDCR and the backup domain may be written (RM0090 5.1.2).
    pub fn backup_writable(&self) -> bool {
        self.cr & DBP != 0
    }

    /// Whether the regulator is at scale 1 (the scale for HCLK above 144 MHz, RM0090 5.1.3).
    pub fn scale1(&self) -> bool {
        self.cr & VOS != 0
    }
}

impl Peripheral for Pwr {
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
            0x0 => Ok(self.cr),
            0x4 => {
                let brr = if self.csr & BRE != 0 { BRR } else { 0 };
                Ok(self.csr | brr | VOSRDY)
            }
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
            0x0 => {
                self.cr = value & CR_WRITABLE;
                if value & CWUF != 0 {
                    self.csr &= !WUF;
                }
                if value & CSBF != 0 {
                    self.csr &= !SBF;
                }
                Ok(())
            }
            // EWUP and BRE are writable; BRE only with the backup domain unprotected.
            0x4 => {
                let mut writable = EWUP;
                if self.backup_writable() {
                    writable |= BRE;
                }
                self.csr = (self.csr & !writable) | (value & writable);
                Ok(())
            }
            _ => Err(AccessError::Unmodelled {
                block: NAME,
                offset,
            }),
        }
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
    fn rm0090_5_4_1_cr_resets_to_scale_1_and_keeps_vos_and_dbp() {
        let mut pwr = Pwr::new();
        assert_eq!(pwr.read(&CTX, 0, 4).unwrap(), 0x4000);
        // embassy-stm32 writes both VOS bits of the F42x layout; the F405 keeps bit 14.
        pwr.write(&CTX, 0, 4, 0xC000 | DBP).unwrap();
        assert_eq!(pwr.read(&CTX, 0, 4).unwrap(), 0x4000 | DBP);
        assert!(pwr.backup_writable());
        assert!(pwr.scale1());
    }

    #[test]
    fn rm0090_5_4_2_vosrdy_reads_ready_and_bre_needs_dbp() {
        let mut pwr = Pwr::new();
        assert_ne!(pwr.read(&CTX, 4, 4).unwrap() & VOSRDY, 0);
        pwr.write(&CTX, 4, 4, BRE).unwrap();
        assert_eq!(pwr.read(&CTX, 4, 4).unwrap() & (BRE | BRR), 0);
        pwr.write(&CTX, 0, 4, DBP).unwrap();
        pwr.write(&CTX, 4, 4, BRE).unwrap();
        assert_eq!(pwr.read(&CTX, 4, 4).unwrap() & (BRE | BRR), BRE | BRR);
    }

    #[test]
    fn rm0090_5_4_unmodelled_offsets_and_widths_are_refused() {
        let mut pwr = Pwr::new();
        assert!(pwr.read(&CTX, 8, 4).is_err());
        assert!(pwr.write(&CTX, 0, 2, 0).is_err());
    }
}
