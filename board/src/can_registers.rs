//! What the hardware layer's bxCAN driver (`board::hw`'s `can1`, RM0090 32) reads and writes
//! that is not hardware, host-tested: the bit timing register (CAN_BTR) and the controller's
//! error state read from CAN_ESR. The transmit path is [`dual_channel::transmit_queue`]; the
//! filter banks come from `dual_channel::filters::bank_layout` (`docs/can-driver.md`).

/// The bxCAN bit timing, in time quanta: as embassy-stm32's `calc_can_timings` gives it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BitTiming {
    /// The clock divider for one time quantum (1..=1024).
    pub prescaler: u16,
    /// Time segment 1, propagation and phase segment 1 (1..=16).
    pub seg1: u8,
    /// Time segment 2, phase segment 2 (1..=8).
    pub seg2: u8,
    /// Resynchronisation jump width (1..=4).
    pub sync_jump_width: u8,
}

/// A bit timing the bxCAN cannot be set to: a field outside its range (RM0090 32.9.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct BitTimingOutOfRange;

impl BitTiming {
    /// The CAN_BTR value (RM0090 32.9.2: BRP in bits 9:0, TS1 in 19:16, TS2 in 22:20, SJW in
    /// 25:24, each one less than the value it stands for; the mode bits LBKM and SILM 0).
    pub fn register(self) -> Result<u32, BitTimingOutOfRange> {
        let field = |value: u32, max: u32, shift: u32| {
            if (1..=max).contains(&value) {
                Ok((value - 1) << shift)
            } else {
                Err(BitTimingOutOfRange)
            }
        };
        Ok(field(u32::from(self.prescaler), 1024, 0)?
            | field(u32::from(self.seg1), 16, 16)?
            | field(u32::from(self.seg2), 8, 20)?
            | field(u32::from(self.sync_jump_width), 4, 24)?)
    }

    /// The bit rate this timing gives from `clock` Hz: one bit is the sync quantum, TS1 and
    /// TS2 (RM0090 32.7.7).
    pub fn bit_rate(self, clock: u32) -> u32 {
        let quanta = 1 + u32::from(self.seg1) + u32::from(self.seg2);
        clock / (u32::from(self.prescaler.max(1)) * quanta)
    }
}

/// The controller's error state (ISO 11898-1 fault confinement), from CAN_ESR.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum ErrorState {
    /// Both error counters below 96.
    Active,
    /// An error counter at 96 or more (the warning limit, EWGF).
    Warning,
    /// An error counter over 127 (EPVF): the controller still receives and acknowledges
    /// every frame; its own frames wait the suspend-transmission time after each.
    Passive,
    /// The transmit error counter over 255 (BOFF): the controller neither sends nor
    /// receives until it has seen 128 times 11 recessive bits (automatic recovery, ABOM,
    /// which the driver sets).
    BusOff,
}

impl ErrorState {
    /// The state CAN_ESR `esr` shows (RM0090 32.9.2: EWGF bit 0, EPVF bit 1, BOFF bit 2),
    /// the gravest flag set.
    pub fn from_esr(esr: u32) -> ErrorState {
        if esr & (1 << 2) != 0 {
            ErrorState::BusOff
        } else if esr & (1 << 1) != 0 {
            ErrorState::Passive
        } else if esr & 1 != 0 {
            ErrorState::Warning
        } else {
            ErrorState::Active
        }
    }

    /// `true` when frames the filters would have passed may have gone unseen: bus-off. The
    /// channel then cannot know that it saw every safety frame, as after a FIFO overrun, and
    /// the hardware layer reports it to the loop (`Received::BusOff`: the safe state, with
    /// its own cause 3Bh). Warning and error passive lose no frame: SRVT and SCT bound what
    /// they delay.
    pub fn loses_frames(self) -> bool {
        self == ErrorState::BusOff
    }
}

/// The transmit error counter in CAN_ESR `esr` (TEC, bits 23:16).
pub fn transmit_errors(esr: u32) -> u8 {
    (esr >> 16) as u8
}

/// The receive error counter in CAN_ESR `esr` (REC, bits 31:24).
pub fn receive_errors(esr: u32) -> u8 {
    (esr >> 24) as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    /// RM0090 32.9.2: the bit timing register of 500 kbit/s from the 42 MHz APB1 clock
    /// (prescaler 6, 1 + 11 + 2 quanta, sample point at 85.7 %), and values outside the
    /// register's fields refused rather than cut.
    #[test]
    fn bit_timing_register_fields_and_ranges() {
        let timing = BitTiming {
            prescaler: 6,
            seg1: 11,
            seg2: 2,
            sync_jump_width: 1,
        };
        assert_eq!(timing.register(), Ok(0x001A_0005));
        assert_eq!(timing.bit_rate(42_000_000), 500_000);
        let widest = BitTiming {
            prescaler: 1024,
            seg1: 16,
            seg2: 8,
            sync_jump_width: 4,
        };
        assert_eq!(
            widest.register(),
            Ok(0x037F_03FF),
            "every field at its maximum"
        );
        for wrong in [
            BitTiming {
                prescaler: 0,
                ..timing
            },
            BitTiming {
                prescaler: 1025,
                ..timing
            },
            BitTiming { seg1: 0, ..timing },
            BitTiming { seg1: 17, ..timing },
            BitTiming { seg2: 9, ..timing },
            BitTiming {
                sync_jump_width: 5,
                ..timing
            },
        ] {
            assert_eq!(wrong.register(), Err(BitTimingOutOfRange), "{wrong:?}");
        }
    }

    /// ISO 11898-1 fault confinement as CAN_ESR shows it: the gravest flag decides, only
    /// bus-off loses frames, and the counters are read from their fields.
    #[test]
    fn error_state_from_the_status_register() {
        assert_eq!(ErrorState::from_esr(0), ErrorState::Active);
        assert_eq!(ErrorState::from_esr(0b001), ErrorState::Warning);
        assert_eq!(ErrorState::from_esr(0b011), ErrorState::Passive);
        assert_eq!(ErrorState::from_esr(0b111), ErrorState::BusOff);
        assert_eq!(ErrorState::from_esr(0b100), ErrorState::BusOff);
        // The last error code (bits 6:4) and the counters are not a state.
        assert_eq!(ErrorState::from_esr(0xFF7F_0070), ErrorState::Active);
        let esr = 0x8AF8_0003;
        assert_eq!(ErrorState::from_esr(esr), ErrorState::Passive);
        assert_eq!(transmit_errors(esr), 0xF8);
        assert_eq!(receive_errors(esr), 0x8A);
        for state in [ErrorState::Active, ErrorState::Warning, ErrorState::Passive] {
            assert!(!state.loses_frames(), "{state:?}");
        }
        assert!(ErrorState::BusOff.loses_frames());
    }
}
