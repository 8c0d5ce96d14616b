//! The bxCAN identifier filter banks (RM0090 32.7.4, registers 32.9.4): 28 banks shared by
//! CAN1 and CAN2 (CAN1 owns the banks below CAN2SB), each one 32-bit filter or two 16-bit
//! filters, in identifier mask or identifier list mode, assigned to FIFO 0 or FIFO 1, with
//! the filter match index numbered per FIFO as the manual's "Example of filter numbering"
//! figure shows (deactivated banks keep their numbers).

use super::frame::Frame;

/// Number of filter banks of the STM32F405 (shared by CAN1 and CAN2).
pub const BANKS: usize = 28;

/// CAN_FMR reserved bits as they read after reset (RM0090 32.9.4, reset value 0x2A1C 0E01).
const FMR_RESERVED: u32 = 0x2A1C_0000;

/// Where a received frame goes: the FIFO of the filter that matched and its filter number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FilterMatch {
    /// Receive FIFO 0 or 1 (the bank's FFAx bit).
    pub fifo: usize,
    /// The filter match index stored in CAN_RDTxR.FMI.
    pub index: u8,
}

/// One filter inside a bank: its rank under the manual's priority rules and where it sits.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    /// 0 for a 32-bit filter, 1 for a 16-bit one ("a 32-bit filter takes priority").
    scale_rank: u8,
    /// 0 for list mode, 1 for mask mode ("priority is given to the identifier list mode").
    mode_rank: u8,
    /// Bank number then position in the bank: the filter number's order within a FIFO.
    bank: usize,
    position: usize,
    fifo: usize,
    index: u8,
}

/// The filter registers: CAN_FMR, CAN_FM1R, CAN_FS1R, CAN_FFA1R, CAN_FA1R and CAN_FiRx.
#[derive(Clone, Debug)]
pub struct FilterBanks {
    /// FINIT: filter initialization mode (set after reset).
    init: bool,
    /// CAN2SB: the first bank that belongs to CAN2.
    can2_start: u32,
    /// FBMx: 1 = identifier list mode.
    mode: u32,
    /// FSCx: 1 = single 32-bit scale.
    scale: u32,
    /// FFAx: 1 = FIFO 1.
    fifo: u32,
    /// FACTx: 1 = bank active.
    active: u32,
    /// CAN_FiR1 and CAN_FiR2 of each bank.
    registers: [[u32; 2]; BANKS],
}

impl Default for FilterBanks {
    fn default() -> Self {
        Self::new()
    }
}

/// The mask of bits FM1R, FS1R, FFA1R and FA1R implement (one per bank).
const BANK_BITS: u32 = (1 << BANKS) - 1;

impl FilterBanks {
    /// The filter registers after reset: FINIT = 1, CAN2SB = 14, all banks inactive, 16-bit,
    /// mask mode, FIFO 0. CAN_FiRx are undefined after reset (RM0090 32.9.4); the model holds
    /// 0 in them.
    pub fn new() -> FilterBanks {
        FilterBanks {
            init: true,
            can2_start: 14,
            mode: 0,
            scale: 0,
            fifo: 0,
            active: 0,
            registers: [[0; 2]; BANKS],
        }
    }

    /// Whether the filters are in initialization mode (FINIT = 1): no filter accepts frames.
    pub fn in_initialization(&self) -> bool {
        self.init
    }

    /// Reads a filter register at `offset` in the CAN block (0x200..0x320), `None` when the
    /// offset holds no filter register.
    pub fn read(&self, offset: u32) -> Option<u32> {
        match offset {
            0x200 => Some(FMR_RESERVED | (self.can2_start << 8) | u32::from(self.init)),
            0x204 => Some(self.mode),
            0x20C => Some(self.scale),
            0x214 => Some(self.fifo),
            0x21C => Some(self.active),
            0x240..0x320 => {
                let (bank, register) = Self::bank_register(offset);
                Some(self.registers[bank][register])
            }
            _ => None,
        }
    }

    /// Writes a filter register; `false` when the offset holds no filter register. Writes
    /// the manual forbids in the present state have no effect: FM1R, FS1R and FFA1R only
    /// with FINIT = 1, a bank's FiRx only while FINIT = 1 or the bank is inactive.
    pub fn write(&mut self, offset: u32, value: u32) -> bool {
        match offset {
            0x200 => {
                self.init = value & 1 != 0;
                self.can2_start = (value >> 8) & 0x3F;
            }
            0x204 if self.init => self.mode = value & BANK_BITS,
            0x20C if self.init => self.scale = value & BANK_BITS,
            0x214 if self.init => self.fifo = value & BANK_BITS,
            0x204 | 0x20C | 0x214 => {}
            0x21C => self.active = value & BANK_BITS,
            0x240..0x320 => {
                let (bank, register) = Self::bank_register(offset);
                if self.init || self.active & (1 << bank) == 0 {
                    self.registers[bank][register] = value;
                }
            }
            _ => return false,
        }
        true
    }

    fn bank_register(offset: u32) -> (usize, usize) {
        let index = ((offset - 0x240) / 4) as usize;
        (index / 2, index % 2)
    }

    /// The number of filters a bank holds: 32-bit mask 1, 32-bit list 2, 16-bit mask 2,
    /// 16-bit list 4 (RM0090 32.7.4, "Filter bank scale configuration").
    fn filters_in(&self, bank: usize) -> usize {
        match (self.scale & (1 << bank) != 0, self.mode & (1 << bank) != 0) {
            (true, false) => 1,
            (true, true) | (false, false) => 2,
            (false, true) => 4,
        }
    }

    /// The banks that belong to CAN1: below CAN2SB (all 28 when CAN2SB is 28 or more).
    fn can1_banks(&self) -> usize {
        (self.can2_start as usize).min(BANKS)
    }

    /// The first filter number of each CAN1 bank within its FIFO's numbering: numbers run
    /// over the banks assigned to the same FIFO, active or not.
    pub fn first_numbers(&self) -> Vec<u8> {
        let mut next = [0u32; 2];
        (0..self.can1_banks())
            .map(|bank| {
                let fifo = usize::from(self.fifo & (1 << bank) != 0);
                let first = next[fifo];
                next[fifo] += self.filters_in(bank) as u32;
                first as u8
            })
            .collect()
    }

    /// The filter a frame received by CAN1 passes, chosen by the manual's priority rules
    /// when several match: 32-bit before 16-bit, list before mask, then the lower filter
    /// number (between the two FIFOs, the lower bank). `None`: the frame is discarded.
    pub fn accept(&self, frame: &Frame) -> Option<FilterMatch> {
        if self.init {
            return None;
        }
        let image32 = image_32(frame);
        let image16 = image_16(frame);
        let firsts = self.first_numbers();
        let mut best: Option<Candidate> = None;
        for (bank, first) in firsts.iter().copied().enumerate() {
            if self.active & (1 << bank) == 0 {
                continue;
            }
            let [r1, r2] = self.registers[bank];
            let list = self.mode & (1 << bank) != 0;
            let wide = self.scale & (1 << bank) != 0;
            let fifo = usize::from(self.fifo & (1 << bank) != 0);
            // Each filter of the bank: (position, matched?).
            let matches: Vec<(usize, bool)> = match (wide, list) {
                // One 32-bit filter: identifier FR1, mask FR2 (bit 0 is reserved).
                (true, false) => vec![(0, (image32 ^ r1) & r2 & !1 == 0)],
                // Two 32-bit identifiers: FR1 is filter n, FR2 is n + 1.
                (true, true) => vec![(0, (image32 ^ r1) & !1 == 0), (1, (image32 ^ r2) & !1 == 0)],
                // Two 16-bit filters: identifier in the low half, mask in the high half.
                (false, false) => vec![
                    (0, (image16 ^ r1) & (r1 >> 16) & 0xFFFF == 0),
                    (1, (image16 ^ r2) & (r2 >> 16) & 0xFFFF == 0),
                ],
                // Four 16-bit identifiers: FR1 low, FR1 high, FR2 low, FR2 high.
                (false, true) => vec![
                    (0, image16 == r1 & 0xFFFF),
                    (1, image16 == r1 >> 16),
                    (2, image16 == r2 & 0xFFFF),
                    (3, image16 == r2 >> 16),
                ],
            };
            for (position, matched) in matches {
                if !matched {
                    continue;
                }
                let candidate = Candidate {
                    scale_rank: u8::from(!wide),
                    mode_rank: u8::from(!list),
                    bank,
                    position,
                    fifo,
                    index: first + position as u8,
                };
                let better = match best {
                    None => true,
                    Some(current) => {
                        (
                            candidate.scale_rank,
                            candidate.mode_rank,
                            candidate.bank,
                            candidate.position,
                        ) < (
                            current.scale_rank,
                            current.mode_rank,
                            current.bank,
                            current.position,
                        )
                    }
                };
                if better {
                    best = Some(candidate);
                }
            }
        }
        best.map(|candidate| FilterMatch {
            fifo: candidate.fifo,
            index: candidate.index,
        })
    }
}

/// A frame's identifier as a 32-bit filter sees it (RM0090 32.7.4 figure "Filter bank
/// scale configuration"): STID\[10:0\] in bits 31:21, EXID\[17:0\] in 20:3, IDE bit 2, RTR bit 1.
pub fn image_32(frame: &Frame) -> u32 {
    (frame.id.standard_part() << 21)
        | (frame.id.extension_part() << 3)
        | (u32::from(frame.id.is_extended()) << 2)
        | (u32::from(frame.remote) << 1)
}

/// A frame's identifier as a 16-bit filter sees it: STID\[10:0\] in bits 15:5, RTR bit 4, IDE
/// bit 3, EXID\[17:15\] in 2:0.
pub fn image_16(frame: &Frame) -> u32 {
    (frame.id.standard_part() << 5)
        | (u32::from(frame.remote) << 4)
        | (u32::from(frame.id.is_extended()) << 3)
        | (frame.id.extension_part() >> 15)
}
