//! Cycles of 1 ms slots and who sends in which, `docs/simplecan.md` section 5 (SC_REQ_18,
//! SC_REQ_21), with the packet-rate bound of section 8 (SC_REQ_04).
//!
//! Global time here is microseconds since the start of the active master's cycle 0, as a
//! `u64` ([`super::sync`] unwraps the 16-bit cycle number of the syncs into it); slot `s` of
//! cycle `c` starts at `(c × N + s) × 1000` µs.

use super::residual::MAX_PACKETS_PER_SECOND;
use super::{MAX_SYNC_INTERVAL, MIN_SYNC_INTERVAL, SLOT, SYNC_TOLERANCE, ScId};
use crate::time::div_rem_u16;
use core::num::NonZeroU16;
use heapless::Vec;

/// A slot in microseconds, as a divisor ([`div_rem_u16`]).
const SLOT_MICROS: NonZeroU16 = match NonZeroU16::new(SLOT.as_micros() as u16) {
    Some(micros) => micros,
    None => panic!("a slot lasts 1 ms"),
};
const _: () = assert!(SLOT.as_micros() == SLOT_MICROS.get() as u64);

/// The fewest slots in a cycle: one producer slot and the two empty ones (SC_REQ_21).
pub const MIN_SLOTS: u16 = 3;

/// The most slots in a cycle (1 s).
pub const MAX_SLOTS: u16 = 1000;

/// Why a cycle and its producers' slots are refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ScheduleError {
    /// A cycle of fewer than 3 or more than 1000 slots.
    SlotCount {
        /// The number of slots asked for.
        slots: u16,
    },
    /// A producer in one of the last two slots, which stay empty (SC_REQ_21).
    SlotNotForProducers {
        /// The producer.
        sc_id: ScId,
        /// Its slot.
        slot: u16,
    },
    /// Two SC-IDs in one slot.
    SlotTaken {
        /// The slot.
        slot: u16,
        /// The SC-ID that has it.
        first: ScId,
        /// The SC-ID that asked for it too.
        second: ScId,
    },
    /// One SC-ID given two slots.
    ScIdTwice {
        /// The SC-ID.
        sc_id: ScId,
    },
    /// More producers than the schedule holds (a device's holds its own SDD's entries, a
    /// network's every SC-ID).
    TooManyProducers {
        /// The producer that did not fit.
        sc_id: ScId,
        /// How many the schedule holds.
        capacity: u8,
    },
    /// A sync interval (every k cycles) outside 100..=500 ms (SC_REQ_22).
    SyncInterval {
        /// k × N, in milliseconds.
        interval_ms: u32,
    },
    /// More packets per second than SC_REQ_04's bound of 665 allows (section 8).
    ResidualErrorRate {
        /// The network's packets per second, data and syncs, rounded up.
        packets_per_second: u32,
    },
}

/// The length of a cycle, and the arithmetic of slots and global time on it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Cycle {
    slots: NonZeroU16,
}

impl Cycle {
    /// N, the slots per cycle.
    pub const fn slots(&self) -> u16 {
        self.slots.get()
    }

    /// The length of a cycle in microseconds.
    pub const fn micros(&self) -> u64 {
        self.slots.get() as u64 * SLOT.as_micros()
    }

    /// The slot a sync goes in: the last (SC_REQ_21).
    pub const fn sync_slot(&self) -> u16 {
        self.slots.get() - 1
    }

    /// The global time at which slot `slot` of cycle `cycle` starts (saturating).
    #[cfg_attr(target_os = "none", inline(never))]
    pub const fn slot_start(&self, cycle: u64, slot: u16) -> u64 {
        cycle
            .saturating_mul(self.slots.get() as u64)
            .saturating_add(slot as u64)
            .saturating_mul(SLOT.as_micros())
    }

    /// The cycle and slot that global time `global` falls in: the slot number since global
    /// time 0, divided by N (without a 64-bit division, [`div_rem_u16`]).
    pub const fn position(&self, global: u64) -> (u64, u16) {
        let (slot_number, _) = div_rem_u16(global, SLOT_MICROS);
        div_rem_u16(slot_number, self.slots)
    }

    /// The start of the first slot `slot` at or after global time `global`, and its cycle:
    /// when a producer owning `slot` sends next (SC_REQ_18).
    pub const fn next_slot(&self, global: u64, slot: u16) -> (u64, u64) {
        let (cycle, _) = self.position(global);
        let this_cycle = self.slot_start(cycle, slot);
        if this_cycle >= global {
            (cycle, this_cycle)
        } else {
            (cycle + 1, self.slot_start(cycle + 1, slot))
        }
    }
}

/// A network's cycle: its length, how often the master sends a sync, and the slots of up to
/// `P` producers (a device's schedule holds the SC-IDs of its own SDD, the configuration
/// tool's every SC-ID of the network). Built only by [`Schedule::new`], so every value of it
/// meets section 5 and SC_REQ_04.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Schedule<const P: usize = { ScId::COUNT }> {
    slots: NonZeroU16,
    sync_every_cycles: u16,
    producers: Vec<(ScId, u16), P>,
}

/// Why a data packet is not timely (section 5).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Untimely {
    /// The SC-ID has no slot in the schedule.
    NoSlot,
    /// It arrived outside its slot of the cycle it is stamped with, widened by 2 ms either
    /// way (repeated, delayed, resequenced or sent out of turn).
    OutsideItsSlot {
        /// How far from the window it arrived, in microseconds.
        by_micros: u64,
    },
}

impl<const P: usize> Schedule<P> {
    /// A cycle of `slots` slots, a sync every `sync_every_cycles` cycles, and the producers'
    /// slots; refused with the first rule it breaks.
    pub fn new(
        slots: u16,
        sync_every_cycles: u16,
        producers: &[(ScId, u16)],
    ) -> Result<Self, ScheduleError> {
        let nonzero = match NonZeroU16::new(slots) {
            Some(nonzero) if (MIN_SLOTS..=MAX_SLOTS).contains(&slots) => nonzero,
            _ => return Err(ScheduleError::SlotCount { slots }),
        };
        let interval_ms = u32::from(sync_every_cycles) * u32::from(slots);
        let interval_us = u64::from(interval_ms) * 1000;
        if interval_us < MIN_SYNC_INTERVAL.as_micros()
            || interval_us > MAX_SYNC_INTERVAL.as_micros()
        {
            return Err(ScheduleError::SyncInterval { interval_ms });
        }
        let mut checked: Vec<(ScId, u16), P> = Vec::new();
        for &(sc_id, slot) in producers {
            if slot >= slots - 2 {
                return Err(ScheduleError::SlotNotForProducers { sc_id, slot });
            }
            if let Some(&(first, _)) = checked.iter().find(|(_, taken)| *taken == slot) {
                return Err(ScheduleError::SlotTaken {
                    slot,
                    first,
                    second: sc_id,
                });
            }
            if checked.iter().any(|(other, _)| *other == sc_id) {
                return Err(ScheduleError::ScIdTwice { sc_id });
            }
            checked
                .push((sc_id, slot))
                .map_err(|_| ScheduleError::TooManyProducers {
                    sc_id,
                    // A capacity is at most ScId::COUNT (80) where one is reached.
                    capacity: u8::try_from(P).unwrap_or(u8::MAX),
                })?;
        }
        // ν = 1000 × P / N + 1000 / (k × N) packets per second ≤ 665, in whole numbers:
        // 1000 × (P × k + 1) ≤ 665 × k × N. The sync interval k × N is 100..=500 ms (checked
        // above) and P at most 80, so the terms are at most 1000 × (80 × 500 + 1) and
        // 665 × 500: 32-bit arithmetic (no 64-bit division on the MCU).
        let producers_per_cycle = checked.len() as u32;
        let k = u32::from(sync_every_cycles);
        let packets_per_k_cycles = 1000 * (producers_per_cycle * k + 1);
        if packets_per_k_cycles > MAX_PACKETS_PER_SECOND * interval_ms {
            // Rounded up: the bound was exceeded, the figure says by how much.
            return Err(ScheduleError::ResidualErrorRate {
                packets_per_second: packets_per_k_cycles.div_ceil(interval_ms),
            });
        }
        Ok(Schedule {
            slots: nonzero,
            sync_every_cycles,
            producers: checked,
        })
    }

    /// The cycle: N slots of 1 ms.
    pub const fn cycle(&self) -> Cycle {
        Cycle { slots: self.slots }
    }

    /// k: the active master sends a sync every k cycles.
    pub const fn sync_every_cycles(&self) -> u16 {
        self.sync_every_cycles
    }

    /// The slot of `sc_id`, if it has one.
    pub fn slot_of(&self, sc_id: ScId) -> Option<u16> {
        self.producers
            .iter()
            .find(|(id, _)| *id == sc_id)
            .map(|&(_, slot)| slot)
    }

    /// Whether a data packet of `sc_id` stamped `stamp`, received at global time `global`,
    /// is timely (section 5): the stamp names the cycle nearest `global`'s whose low 8 bits
    /// it is, and `global` must lie in `sc_id`'s slot of that cycle, widened by
    /// [`SYNC_TOLERANCE`] either way. Timely, it returns the global time the slot started,
    /// from which the value's age counts (SC_REQ_20).
    pub fn timely(&self, sc_id: ScId, stamp: u8, global: u64) -> Result<u64, Untimely> {
        let slot = self.slot_of(sc_id).ok_or(Untimely::NoSlot)?;
        let cycle_of = self.cycle();
        let (cycle, _) = cycle_of.position(global);
        // Serial-number arithmetic (RFC 1982 style): the stamp is at most 128 cycles away.
        let distance = i64::from(stamp.wrapping_sub(cycle as u8) as i8);
        let stamped = cycle.saturating_add_signed(distance);
        let start = cycle_of.slot_start(stamped, slot);
        let earliest = start.saturating_sub(SYNC_TOLERANCE.as_micros());
        let latest = start
            .saturating_add(SLOT.as_micros())
            .saturating_add(SYNC_TOLERANCE.as_micros());
        if global < earliest {
            Err(Untimely::OutsideItsSlot {
                by_micros: earliest - global,
            })
        } else if global > latest {
            Err(Untimely::OutsideItsSlot {
                by_micros: global - latest,
            })
        } else {
            Ok(start)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sc(raw: u8) -> ScId {
        ScId::new(raw).unwrap()
    }

    /// N = 10, a sync every 10 cycles (100 ms), producers 30h in slot 0 and 41h in slot 7.
    fn schedule() -> Schedule {
        <Schedule>::new(10, 10, &[(sc(0x30), 0), (sc(0x41), 7)]).unwrap()
    }

    #[test]
    fn sc_req_18_a_producer_sends_at_the_start_of_its_slot_every_cycle() {
        let schedule = schedule();
        assert_eq!(schedule.cycle().next_slot(0, 7), (0, 7_000));
        assert_eq!(schedule.cycle().next_slot(7_000, 7), (0, 7_000));
        assert_eq!(schedule.cycle().next_slot(7_001, 7), (1, 17_000));
        assert_eq!(schedule.cycle().position(17_999), (1, 7));
        assert_eq!(schedule.cycle().position(18_000), (1, 8));
    }

    #[test]
    fn sc_req_18_a_schedule_refuses_more_producers_than_it_holds() {
        let producers = [(sc(0x30), 0), (sc(0x31), 1), (sc(0x32), 2)];
        assert!(Schedule::<3>::new(10, 10, &producers).is_ok());
        assert_eq!(
            Schedule::<2>::new(10, 10, &producers),
            Err(ScheduleError::TooManyProducers {
                sc_id: sc(0x32),
                capacity: 2
            })
        );
    }

    #[test]
    fn sc_req_21_the_last_two_slots_are_not_for_producers() {
        assert_eq!(
            <Schedule>::new(10, 10, &[(sc(0x30), 8)]),
            Err(ScheduleError::SlotNotForProducers {
                sc_id: sc(0x30),
                slot: 8
            })
        );
        assert!(<Schedule>::new(10, 10, &[(sc(0x30), 9)]).is_err());
        assert!(<Schedule>::new(10, 10, &[(sc(0x30), 7)]).is_ok());
        assert_eq!(
            <Schedule>::new(2, 50, &[]),
            Err(ScheduleError::SlotCount { slots: 2 })
        );
    }

    #[test]
    fn sc_req_21_a_sync_goes_in_the_last_slot() {
        let schedule = schedule();
        assert_eq!(schedule.cycle().sync_slot(), 9);
        assert_eq!(
            schedule.cycle().next_slot(0, schedule.cycle().sync_slot()),
            (0, 9_000)
        );
    }

    #[test]
    fn sc_req_18_two_producers_never_share_a_slot() {
        assert_eq!(
            <Schedule>::new(10, 10, &[(sc(0x30), 3), (sc(0x31), 3)]),
            Err(ScheduleError::SlotTaken {
                slot: 3,
                first: sc(0x30),
                second: sc(0x31)
            })
        );
        assert_eq!(
            <Schedule>::new(10, 10, &[(sc(0x30), 3), (sc(0x30), 4)]),
            Err(ScheduleError::ScIdTwice { sc_id: sc(0x30) })
        );
    }

    #[test]
    fn sc_req_22_the_sync_interval_is_between_100_and_500_ms() {
        assert!(<Schedule>::new(10, 10, &[]).is_ok());
        assert!(<Schedule>::new(10, 50, &[]).is_ok());
        assert_eq!(
            <Schedule>::new(10, 9, &[]),
            Err(ScheduleError::SyncInterval { interval_ms: 90 })
        );
        assert_eq!(
            <Schedule>::new(10, 51, &[]),
            Err(ScheduleError::SyncInterval { interval_ms: 510 })
        );
    }

    /// Section 8 step 5: six producers in ten slots are within SC_REQ_04, seven are not.
    #[test]
    fn sc_req_04_the_schedule_refuses_more_than_665_packets_per_second() {
        let six: std::vec::Vec<(ScId, u16)> = (0..6).map(|s| (sc(0x30 + s as u8), s)).collect();
        assert!(<Schedule>::new(10, 10, &six).is_ok());
        let seven: std::vec::Vec<(ScId, u16)> = (0..7).map(|s| (sc(0x30 + s as u8), s)).collect();
        assert_eq!(
            <Schedule>::new(10, 10, &seven),
            Err(ScheduleError::ResidualErrorRate {
                packets_per_second: 710
            })
        );
        // The shortest cycle with its one producer slot: 343 packets per second.
        assert!(<Schedule>::new(3, 34, &[(sc(0x30), 0)]).is_ok());
    }

    #[test]
    fn sc_req_18_a_packet_outside_its_slot_is_not_timely() {
        let schedule = schedule();
        let slot_7_of_cycle_3 = schedule.cycle().slot_start(3, 7);
        let stamp = 3;
        // In the slot, and up to 2 ms either side of it.
        for global in [
            slot_7_of_cycle_3 - 2_000,
            slot_7_of_cycle_3,
            slot_7_of_cycle_3 + 3_000,
        ] {
            assert_eq!(
                schedule.timely(sc(0x41), stamp, global),
                Ok(slot_7_of_cycle_3)
            );
        }
        assert_eq!(
            schedule.timely(sc(0x41), stamp, slot_7_of_cycle_3 + 3_001),
            Err(Untimely::OutsideItsSlot { by_micros: 1 })
        );
        assert_eq!(
            schedule.timely(sc(0x41), stamp, slot_7_of_cycle_3 - 2_001),
            Err(Untimely::OutsideItsSlot { by_micros: 1 })
        );
        assert_eq!(schedule.timely(sc(0x35), stamp, 0), Err(Untimely::NoSlot));
    }

    /// A packet repeated one cycle later carries last cycle's stamp, and one repeated 256
    /// cycles later would need a bus that stores frames for 2.56 s (section 2).
    #[test]
    fn sc_req_18_a_packet_repeated_a_cycle_later_is_not_timely() {
        let schedule = schedule();
        let sent = schedule.cycle().slot_start(300, 0);
        assert_eq!(schedule.timely(sc(0x30), 300u64 as u8, sent), Ok(sent));
        let next_cycle = schedule.cycle().slot_start(301, 0);
        assert!(schedule.timely(sc(0x30), 300u64 as u8, next_cycle).is_err());
        // The stamp's wrap: cycle 255 stamped 255, received early in cycle 256's time.
        let wrap = schedule.cycle().slot_start(255, 0);
        assert_eq!(schedule.timely(sc(0x30), 255, wrap), Ok(wrap));
        assert_eq!(
            schedule.timely(sc(0x30), 0, schedule.cycle().slot_start(256, 0)),
            Ok(schedule.cycle().slot_start(256, 0))
        );
    }
}
