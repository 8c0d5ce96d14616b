//! What the hardware layer's `bxcan` 0.8 adapter decides without the hardware, host-tested:
//! the acceptance filter banks from [`dual_channel::filters::bank_layout`] put into bxcan's
//! filter API, the bit timing register and the controller's error state read from CAN_ESR
//! (the transmit path both drivers share is [`crate::transmit_queue`]). The adapter itself (`board::hw`, feature
//! `can-bxcan`) only moves these between the registers and the channel loop
//! (`docs/can-driver.md`).
//!
//! The error state is bxCAN hardware, not a driver's: the embassy-stm32 driver reads it
//! through this module too.

use bxcan::filter::{BankConfig, ListEntry16, Mask16, MasterFilters};
use bxcan::{FilterOwner, StandardId};
use dual_channel::filters::{self, Bank, BankLayout};

/// Why the filter banks were not programmed. Either leaves the banks as they were.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum FilterFault {
    /// The layout needs more filter banks than the controller owns.
    TooFewBanks {
        /// Banks the layout needs.
        needed: u8,
        /// Banks the controller owns (CAN_FMR.CAN2SB on a master instance).
        owned: u8,
    },
    /// A bank names an identifier or a mask over 11 bits (not a standard identifier).
    IdentifierOutOfRange {
        /// The bank, from 0.
        bank: u8,
        /// The value.
        value: u16,
    },
}

/// The receive FIFO of a bank, as bxcan names it (RM0090 32.7.4, CAN_FFA1R).
pub fn fifo(fifo: filters::Fifo) -> bxcan::Fifo {
    match fifo {
        filters::Fifo::Srdo => bxcan::Fifo::Fifo0,
        filters::Fifo::Services => bxcan::Fifo::Fifo1,
    }
}

/// One bank of the layout as bxcan's configuration: data frames only (RTR = 0), standard
/// identifiers only (IDE = 0), as [`Bank`] has it.
pub fn bank_config(bank: &Bank, index: u8) -> Result<BankConfig, FilterFault> {
    let id = |value: u16| {
        StandardId::new(value).ok_or(FilterFault::IdentifierOutOfRange { bank: index, value })
    };
    Ok(match *bank {
        Bank::List16([a, b, c, d]) => BankConfig::List16([
            ListEntry16::data_frames_with_id(id(a)?),
            ListEntry16::data_frames_with_id(id(b)?),
            ListEntry16::data_frames_with_id(id(c)?),
            ListEntry16::data_frames_with_id(id(d)?),
        ]),
        Bank::Mask16([(first, first_mask), (second, second_mask)]) => BankConfig::Mask16([
            *Mask16::frames_with_std_id(id(first)?, id(first_mask)?).data_frames_only(),
            *Mask16::frames_with_std_id(id(second)?, id(second_mask)?).data_frames_only(),
        ]),
    })
}

/// Programs `layout` into the controller's banks: bank `k` of the layout into filter bank
/// `k`, every other bank disabled. Every bank is converted before the first register is
/// written, so a refused layout leaves the banks as they were (never half of a new list).
/// bxcan holds the filters in initialisation mode (CAN_FMR.FINIT) until `banks` is dropped;
/// meanwhile the controller accepts nothing, which costs at most frames of a configuration
/// being changed outside Operational.
pub fn program<I: FilterOwner>(
    banks: &mut MasterFilters<'_, I>,
    layout: &BankLayout,
) -> Result<(), FilterFault> {
    let owned = banks.num_banks();
    let needed = u8::try_from(layout.banks.len()).unwrap_or(u8::MAX);
    if needed > owned {
        return Err(FilterFault::TooFewBanks { needed, owned });
    }
    let mut configs: [Option<(bxcan::Fifo, BankConfig)>; filters::CAN1_BANKS] =
        [None; filters::CAN1_BANKS];
    for ((index, (bank, feeds)), config) in (0u8..).zip(layout.banks.iter()).zip(&mut configs) {
        *config = Some((fifo(*feeds), bank_config(bank, index)?));
    }
    banks.clear();
    for (index, config) in (0u8..).zip(configs) {
        if let Some((feeds, config)) = config {
            banks.enable_bank(index, feeds, config);
        }
    }
    Ok(())
}

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
    /// 25:24, each one less than the value it stands for; the mode bits LBKM and SILM 0),
    /// which is what bxcan's `set_bit_timing` takes.
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
    /// which both drivers set).
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
    extern crate std;

    use super::*;
    use core::cell::UnsafeCell;
    use dual_channel::filters::{AcceptanceList, CAN1_BANKS, bank_layout};
    use shared::canopen::NodeId;
    use shared::safety::config::{SafetyConfig, SrdoRecord};
    use shared::{CanFrame, CanId};
    use std::sync::Mutex;

    /// RAM laid out as a bxCAN register block, for bxcan to write its filter registers
    /// into; the test reads them back and decodes them by RM0090, not by bxcan.
    #[repr(C, align(4))]
    struct FakeRegisters(UnsafeCell<[u32; WORDS]>);
    const WORDS: usize = core::mem::size_of::<bxcan::RegisterBlock>() / 4;
    // SAFETY: only the tests below touch it, one at a time (`FAKE_LOCK`).
    unsafe impl Sync for FakeRegisters {}
    static FAKE: FakeRegisters = FakeRegisters(UnsafeCell::new([0; WORDS]));
    static FAKE_LOCK: Mutex<()> = Mutex::new(());

    struct FakeCan;
    // SAFETY: `FAKE` is as large as bxcan's register block and word-aligned; only `FakeCan`
    // (one at a time, under `FAKE_LOCK`) and the test's reads after bxcan returned use it.
    unsafe impl bxcan::Instance for FakeCan {
        const REGISTERS: *mut bxcan::RegisterBlock = FAKE.0.get().cast();
    }
    // SAFETY: the fake owns all 28 banks of a master bxCAN, as CAN1 of the STM32F405 does.
    unsafe impl FilterOwner for FakeCan {
        const NUM_FILTER_BANKS: u8 = 28;
    }

    // Word offsets of the registers (RM0090 32.9.5: byte offset / 4).
    const MSR: usize = 1;
    const TSR: usize = 2;
    /// CAN_TSR.TME0..TME2 (bits 26..=28): the transmit mailboxes empty.
    const TME_ALL: u32 = 0b111 << 26;
    const FMR: usize = 0x200 / 4;
    const FM1R: usize = 0x204 / 4;
    const FS1R: usize = 0x20C / 4;
    const FFA1R: usize = 0x214 / 4;
    const FA1R: usize = 0x21C / 4;
    const BANK0: usize = 0x240 / 4;
    /// The banks CAN2 owns with CAN2SB = 14, 14 to 27, in CAN_FA1R.
    const CAN2_BANKS: u32 = 0x0FFF_C000;

    fn read(word: usize) -> u32 {
        // SAFETY: in bounds of `FAKE`, under `FAKE_LOCK`, no bxcan call running.
        unsafe { (*FAKE.0.get())[word] }
    }

    fn write(word: usize, value: u32) {
        // SAFETY: in bounds of `FAKE`, under `FAKE_LOCK`, no bxcan call running.
        unsafe { (*FAKE.0.get())[word] = value }
    }

    /// `program` with `layout` on a controller owning `owned` banks (CAN_FMR.CAN2SB) whose
    /// banks were all enabled for accept-everything before (so that a bank the layout does
    /// not use must be seen off): its result and the registers after it.
    fn programmed(layout: &BankLayout, owned: u8) -> (Result<(), FilterFault>, [u32; WORDS]) {
        let _guard = FAKE_LOCK.lock().unwrap();
        let mut can = fake_can(owned);
        let result = program(&mut can.modify_filters(), layout);
        // SAFETY: as `write`; bxcan is done with the registers.
        (result, unsafe { *FAKE.0.get() })
    }

    /// A `Can` on the zeroed fake, CAN_FMR as at reset but for CAN2SB = `owned`, all filter
    /// banks active in 32-bit mask mode with filter and mask 0 (everything passes), every
    /// transmit mailbox empty. Under `FAKE_LOCK`.
    fn fake_can(owned: u8) -> bxcan::Can<FakeCan> {
        for word in 0..WORDS {
            write(word, 0);
        }
        write(FMR, 0x2A1C_0001 | u32::from(owned) << 8);
        write(FA1R, 0x0FFF_FFFF);
        write(FS1R, 0x0FFF_FFFF);
        write(TSR, TME_ALL);
        // `Can::builder` waits for INAK = 1, SLAK = 0; `leave_disabled` for the reverse.
        write(MSR, 0b01);
        let builder = bxcan::Can::builder(FakeCan);
        write(MSR, 0b10);
        builder.leave_disabled()
    }

    /// The FIFO the programmed registers send a standard frame with `id` and `remote` to, by
    /// RM0090 32.7.4: the lowest-numbered active bank of CAN1's (below CAN2SB) that matches; 16-bit scale, an entry
    /// is STID in bits 15:5, RTR in bit 4, IDE in bit 3 (the frame's IDE and EXID are 0).
    fn register_fifo(registers: &[u32; WORDS], id: u16, remote: bool) -> Option<u8> {
        let frame = u32::from(id) << 5 | u32::from(remote) << 4;
        (0..CAN1_BANKS).find_map(|bank| {
            if registers[FA1R] & (1 << bank) == 0 {
                return None;
            }
            assert_eq!(
                registers[FS1R] & (1 << bank),
                0,
                "bank {bank}: 16-bit scale"
            );
            let [r1, r2] = [registers[BANK0 + 2 * bank], registers[BANK0 + 2 * bank + 1]];
            let halves = |r: u32| [r & 0xFFFF, r >> 16];
            let matched = if registers[FM1R] & (1 << bank) != 0 {
                halves(r1)
                    .into_iter()
                    .chain(halves(r2))
                    .any(|entry| entry == frame)
            } else {
                [halves(r1), halves(r2)]
                    .into_iter()
                    .any(|[filter, mask]| (frame ^ filter) & mask == 0)
            };
            matched.then(|| u8::from(registers[FFA1R] & (1 << bank) != 0))
        })
    }

    fn expected_fifo(layout: &BankLayout, id: u16, remote: bool) -> Option<u8> {
        layout.fifo(id, remote).map(|fifo| match fifo {
            filters::Fifo::Srdo => 0,
            filters::Fifo::Services => 1,
        })
    }

    /// A configuration of node 33 with `count` SRDOs on 101h/102h, 103h/104h, ...
    fn list(count: usize) -> AcceptanceList {
        let mut config = SafetyConfig::<64>::predefined(1, &[], &[]);
        for (index, record) in config.srdos.iter_mut().enumerate() {
            *record = SrdoRecord::DELETED;
            if index < count {
                record.direction = 2;
                record.cob_id_1 = 0x101 + 2 * index as u32;
                record.cob_id_2 = 0x102 + 2 * index as u32;
            }
        }
        AcceptanceList::of(NodeId::new(33).unwrap(), &config)
    }

    fn data(id: u16) -> CanFrame {
        CanFrame::new(CanId::new(id).unwrap(), &[0]).unwrap()
    }

    /// EN 50325-5 7.1.1, 7.2.1, CiA 301 7.3.5: the banks bxcan writes for the node's list
    /// (4 SRDOs: 3 banks; 26: 14, the most that is exact) pass every listed identifier as a
    /// data frame and nothing else, SRDOs to FIFO 0, NMT, GFC and SDO to FIFO 1, and every
    /// bank from before is disabled; decoded from the registers by the reference manual,
    /// for all 2048 identifiers, data and remote. CAN2's banks (14 to 27) are left alone.
    #[test]
    fn en50325_5_7_1_1_bxcan_filter_registers_pass_exactly_the_acceptance_list() {
        for count in [0, 1, 4, 26] {
            let list = list(count);
            let layout = bank_layout(&list, CAN1_BANKS).unwrap();
            assert!(layout.exact);
            let (result, registers) = programmed(&layout, 14);
            assert_eq!(result, Ok(()));
            assert_eq!(
                registers[FA1R],
                CAN2_BANKS | ((1 << layout.banks.len()) - 1),
                "{count} SRDOs: CAN1's banks 0..{} active, no other; CAN2's 14..=27 untouched",
                layout.banks.len()
            );
            assert_eq!(registers[FMR] & 1, 0, "filters out of initialisation mode");
            for id in 0..=0x7FF_u16 {
                let fifo = register_fifo(&registers, id, false);
                assert_eq!(fifo, expected_fifo(&layout, id, false), "{count}: {id:#x}");
                assert_eq!(fifo.is_some(), list.accepts(&data(id)), "{count}: {id:#x}");
                assert_eq!(register_fifo(&registers, id, true), None, "remote {id:#x}");
            }
            for srdo in 0..count as u16 {
                assert_eq!(register_fifo(&registers, 0x101 + 2 * srdo, false), Some(0));
            }
            for service in [0x000, 0x001, 0x621, 0x7E5] {
                assert_eq!(register_fifo(&registers, service, false), Some(1));
            }
        }
    }

    /// EN 50325-5 7.1.1: beyond 26 SRDOs the fallback's mask bank, as bxcan writes it, passes
    /// the SRDO range 100h..=180h to FIFO 0 and rejects everything else that is not NMT, GFC
    /// or SDO; the software filter narrows the range.
    #[test]
    fn en50325_5_7_1_1_bxcan_fallback_mask_bank_passes_the_srdo_range_only() {
        let list = list(40);
        let layout = bank_layout(&list, CAN1_BANKS).unwrap();
        assert!(!layout.exact);
        let (result, registers) = programmed(&layout, 14);
        assert_eq!(result, Ok(()));
        assert_eq!(registers[FM1R] & 1, 0, "bank 0 in mask mode");
        for id in 0..=0x7FF_u16 {
            let fifo = register_fifo(&registers, id, false);
            assert_eq!(fifo, expected_fifo(&layout, id, false), "{id:#x}");
            let srdo_range = (0x100..=0x180).contains(&id);
            let service = [0x000, 0x001, 0x621, 0x7E5].contains(&id);
            assert_eq!(fifo.is_some(), srdo_range || service, "{id:#x}");
        }
    }

    /// A layout that does not fit the banks the controller owns, or names a value over 11
    /// bits, is refused before any register is written: the banks keep what they had.
    #[test]
    fn a_refused_filter_layout_leaves_the_banks_as_they_were() {
        let layout = bank_layout(&list(4), CAN1_BANKS).unwrap();
        let mut wide = layout.clone();
        wide.banks[2] = (
            Bank::List16([0x001, 0x800, 0x001, 0x001]),
            filters::Fifo::Services,
        );
        let small = (layout, 2);
        for ((layout, owned), fault) in [
            (
                (wide, 14),
                FilterFault::IdentifierOutOfRange {
                    bank: 2,
                    value: 0x800,
                },
            ),
            (
                small,
                FilterFault::TooFewBanks {
                    needed: 3,
                    owned: 2,
                },
            ),
        ] {
            let (result, registers) = programmed(&layout, owned);
            assert_eq!(result, Err(fault));
            assert_eq!(registers[FA1R], 0x0FFF_FFFF, "{fault:?}: no bank disabled");
            assert_eq!(registers[FS1R], 0x0FFF_FFFF, "{fault:?}: no bank rescaled");
            assert!(
                registers[BANK0..].iter().all(|&word| word == 0),
                "{fault:?}"
            );
        }
    }

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

    /// What decides `docs/can-driver.md`: bxcan 0.8 puts a frame into a second or third
    /// mailbox only when it has a higher priority than every pending one (its rule for
    /// keeping frames of one identifier in order; it has no setter for CAN_MCR.TXFP), so
    /// the CiA 304 9.5 loop-back plan, whose bursts must take mailboxes 0, 1 and 2 in their
    /// own order, is refused at its third frame (`LoopbackFault::Refused(2)`), five frames in
    /// all; the same bursts in falling identifier order fill the mailboxes. The hardware is
    /// played by the test: after each frame bxcan accepts, its mailbox is marked pending
    /// (TMEx = 0) and CODE names the lowest empty one; after each burst all are empty.
    #[test]
    fn bxcan_0_8_refuses_the_loopback_plan_in_its_mailbox_order() {
        use dual_channel::can_loopback::PLAN;
        let _guard = FAKE_LOCK.lock().unwrap();
        let mut can = fake_can(14);
        let mut burst_results = |bursts: &[std::vec::Vec<(u16, u8, u8)>]| {
            let mut refused = std::vec::Vec::new();
            for (index, burst) in bursts.iter().enumerate() {
                let mut empty = [true; 3];
                for (place, &(id, dlc, fill)) in burst.iter().enumerate() {
                    let code = empty.iter().position(|&free| free).unwrap_or(0) as u32;
                    let tme = (0..3)
                        .filter(|&m| empty[m])
                        .map(|m| 1 << (26 + m))
                        .sum::<u32>();
                    write(TSR, tme | code << 24);
                    let data = bxcan::Data::new(&[fill; 8][..usize::from(dlc)]).unwrap();
                    let frame = bxcan::Frame::new_data(StandardId::new(id).unwrap(), data);
                    match can.transmit(&frame) {
                        Ok(status) => {
                            assert!(status.dequeued_frame().is_none());
                            empty[status.mailbox() as usize] = false;
                        }
                        Err(_) => refused.push((index, place)),
                    }
                }
                // The burst has left: mailboxes empty, their requests done (TXRQ = 0).
                for mailbox in 0..3 {
                    let tir = 0x180 / 4 + 4 * mailbox;
                    let word = read(tir);
                    write(tir, word & !1);
                }
            }
            refused
        };
        let plan: std::vec::Vec<std::vec::Vec<(u16, u8, u8)>> = PLAN
            .iter()
            .map(|burst| burst.iter().map(|f| (f.id, f.dlc, f.fill)).collect())
            .collect();
        assert_eq!(
            burst_results(&plan),
            [(0, 2), (1, 1), (2, 2), (3, 1), (3, 2)],
            "(burst, place) of each frame bxcan refuses"
        );
        let falling: std::vec::Vec<_> = plan
            .iter()
            .map(|burst| {
                let mut burst = burst.clone();
                burst.sort_by_key(|frame| core::cmp::Reverse(frame.0));
                burst
            })
            .collect();
        assert_eq!(
            burst_results(&falling),
            [],
            "falling identifiers: all taken"
        );
    }
}
