//! The periodic check in Operational that the tables the SRDO paths run on are still the ones
//! the validated records give (EN 50325-5 8.3.1 keeps a node out of Operational with a
//! configuration that does not pass its check; this keeps it out of the working state when the
//! configuration in RAM stops passing, or the tables derived from it stop matching it).
//!
//! # What is checked
//!
//! On the way into Operational the node validates the records (0x1301.., 0x1381.., 0x13FE,
//! 0x13FF) once and derives from them what the receive and transmit paths actually use: the
//! identifier table (CAN identifier → SRDO slot, plain or inverted), each running SRDO's
//! resolved mapping and role (transmit or receive) with the record's values its producer or
//! consumer runs with (refresh time and identifiers, or SCT and SRVT), and the list of running
//! SRDOs. The configuration digest the two channels of a dual-channel device compare covers the
//! records only. Here, every period (see below), the same Operational-entry check runs again on
//! the records (each signature, 0x13FE) and the tables are derived again into fresh ones and
//! compared with the ones in use entry by entry. The derivation goes through the same validation
//! functions as at Operational entry: this finds damage in memory, not a fault in that code
//! (which the configuration tests cover). Any difference latches the safe state
//! ([`crate::node::SafeStateCause::Integrity`]) with EMCY 6300h (data set) and an event naming
//! what differed. Not covered: the SRDO state machines' own timers and counters (they are
//! state, not configuration; a damaged timer shows as an SCT or SRVT fault), and mapping
//! entries beyond a record's count (nothing reads or stores them).
//!
//! # How often, and why that is enough
//!
//! The period is the shortest refresh time or SCT of the running SRDOs ([`period`]), checked
//! at the deadline itself like every other timer. A consumer's SCT is the time within which the
//! device must notice that valid data stopped arriving, and the system designer budgets it
//! into the process safety time of every safety function the SRDO carries. A table damaged at
//! any moment is therefore found, and the safe state entered, within one SCT (at most one
//! period after the damage, in the poll at that deadline): no later than the device would
//! react to the loss of the SRDO itself, so the damage adds no reaction time the process
//! safety time does not already contain. A producer's refresh time bounds the same way how
//! long it can send with a damaged mapping. With no SRDO running, nothing is derived and the
//! check runs every [`IDLE_PERIOD`].
//!
//! Cost: one check runs the Operational-entry check (one CRC-16 signature and one mapping
//! resolution per existing SRDO, and the COB-ID comparison with every other record) and
//! compares the identifier table, the active list and every slot's mapping. `cargo xtask
//! bench` counts the poll that runs it with callgrind (`shared/examples/hot_paths.rs`, mode
//! `integrity-check`, one 8-byte producer with a 25 ms refresh time; the figure is in
//! `docs/performance.md`): at that period a small fraction of a 168 MHz Cortex-M4 even at two
//! cycles an instruction. It grows about linearly with the SRDOs (quadratically only in the
//! COB-ID comparison, 64 × 63 for the largest device). The check runs in a poll of its own,
//! so the receive path does not pay for it; the transmit poll pays for one more deadline.

use heapless::Vec;

use super::{
    LOOKUP_INVERTED, Role, SRDO_ID_BASE, SRDO_IDS, SafeStateCause, Sink, SrdoRuntime, SrdoTable,
};
use crate::node::slot::Slot;
use crate::process_image::ProcessImage;
use crate::safety::config::ConfigFault;
use crate::safety::types::{Direction, SrdoNumber};
use crate::time::{Duration, Instant};

/// How often the check runs in Operational when no SRDO runs.
pub const IDLE_PERIOD: Duration = Duration::from_millis(100);

/// EMCY 6300h detail byte 1 for each [`IntegrityFault`] (byte 0 names the SRDO, or 0).
/// Distinct from every [`ConfigError`](crate::safety::config::ConfigError) cause code and
/// from [`crate::node::STORED_PARAMETERS_REJECTED`] and
/// [`crate::node::VALIDATED_FOR_ANOTHER_NODE_ID`].
pub mod cause {
    use crate::safety::cause::Cause;
    /// The records no longer pass the Operational-entry check (byte 2: the check's cause code).
    pub const RECORDS: u8 = Cause::IntegrityRecords.code();
    /// The identifier table differs from the records.
    pub const IDENTIFIER_TABLE: u8 = Cause::IntegrityIdentifierTable.code();
    /// An SRDO's resolved mapping or role, or the times or identifiers it runs with, differ
    /// from its record.
    pub const RUNTIME: u8 = Cause::IntegrityRuntime.code();
    /// The list of running SRDOs differs from the records.
    pub const ACTIVE_LIST: u8 = Cause::IntegrityActiveList.code();
}

/// What the integrity check found in Operational.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum IntegrityFault {
    /// The records (or 0x13FE) changed in Operational and no longer pass the Operational-entry
    /// check.
    Records(ConfigFault),
    /// The identifier table the receive path looks frames up in differs from the records.
    IdentifierTable,
    /// This SRDO's resolved mapping or role (producer, consumer, idle), or the times (refresh
    /// time, or SCT and SRVT) or identifiers its producer or consumer runs with, differ from
    /// its record.
    Runtime(SrdoNumber),
    /// The list of running SRDOs differs from the records.
    ActiveList,
}

impl IntegrityFault {
    /// The five manufacturer-specific bytes of EMCY 6300h that name this fault.
    pub fn emergency_detail(self) -> [u8; 5] {
        match self {
            IntegrityFault::Records(fault) => [
                fault.srdo.map_or(0, SrdoNumber::get),
                cause::RECORDS,
                fault.error.cause_code(),
                0,
                0,
            ],
            IntegrityFault::IdentifierTable => [0, cause::IDENTIFIER_TABLE, 0, 0, 0],
            IntegrityFault::Runtime(srdo) => [srdo.get(), cause::RUNTIME, 0, 0, 0],
            IntegrityFault::ActiveList => [0, cause::ACTIVE_LIST, 0, 0, 0],
        }
    }
}

/// The check's schedule: when it is next due, and its period.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(in crate::node) struct Integrity {
    next: Instant,
    period: Duration,
}

impl Integrity {
    /// Not scheduled (outside Operational).
    pub(super) const IDLE: Integrity = Integrity {
        next: Instant::NEVER,
        period: IDLE_PERIOD,
    };

    /// Scheduled from `now`, every `period`.
    pub(super) fn start(now: Instant, period: Duration) -> Integrity {
        Integrity {
            next: now + period,
            period,
        }
    }

    /// When the check is next due (`Instant::NEVER` outside Operational).
    pub(super) fn deadline(&self) -> Instant {
        self.next
    }

    /// The period it runs at.
    #[cfg(test)]
    pub(super) fn period(&self) -> Duration {
        self.period
    }

    /// `true` when the check is due at `now`; schedules the next one.
    pub(super) fn due(&mut self, now: Instant) -> bool {
        if !crate::time::expired(self.next, now) {
            return false;
        }
        self.next = now + self.period;
        true
    }
}

/// The check's period for SRDOs with these refresh times and SCTs: the shortest, or
/// [`IDLE_PERIOD`] when none runs.
pub(super) fn period(cycle_times: impl Iterator<Item = Duration>) -> Duration {
    cycle_times.min().unwrap_or(IDLE_PERIOD)
}

impl<const N: usize> SrdoTable<N> {
    /// Schedules the check on entering Operational (the tables were just derived).
    pub(super) fn start_integrity(&mut self, now: Instant) {
        let cycle_times = self.active.iter().filter_map(|&slot| {
            let record = self.safety.srdos.get(usize::from(slot))?;
            Some(Duration::from_millis(u64::from(record.cycle_time)))
        });
        self.integrity = Integrity::start(now, period(cycle_times));
    }

    /// Runs the check when it is due at `now` (Operational only), and latches the safe state
    /// when it fails.
    pub(super) fn poll_integrity<S: Sink>(&mut self, now: Instant, slot: &mut Slot<'_, S>) {
        if !self.integrity.due(now) || slot.latched() {
            return;
        }
        if let Err(fault) = self.check_integrity(slot.image()) {
            self.latch(SafeStateCause::Integrity(fault), slot.reborrow());
        }
    }

    /// Runs the Operational-entry check on the records again and compares the tables derived
    /// from them with the ones in use.
    pub(super) fn check_integrity(&self, image: &ProcessImage) -> Result<(), IntegrityFault> {
        let mut lookup = [0u8; SRDO_IDS];
        let mut active: Vec<u8, N> = Vec::new();
        let mut runtime_fault = None;
        self.safety
            .check_for_operational(image, |number, valid| {
                let slot = number.index();
                let transmit = valid.direction == Direction::Transmit;
                // The role, and the times (and identifiers) it runs with, which it took from
                // the record at the Operational entry.
                let matches = self.runtime.get(slot).is_some_and(|runtime| {
                    runtime.mapping == valid.mapping
                        && match &runtime.role {
                            Role::Producer(producer) => transmit && producer.runs_with(&valid),
                            Role::Consumer(consumer) => !transmit && consumer.runs_with(&valid),
                            Role::Idle => false,
                        }
                });
                if !matches {
                    runtime_fault.get_or_insert(IntegrityFault::Runtime(number));
                }
                // `slot < N <= 64`: the tag's seven bits hold it with the +1.
                let tag = slot as u8 + 1;
                let first = usize::from(valid.cob_ids.first() - SRDO_ID_BASE);
                if let Some(entry) = lookup.get_mut(first) {
                    *entry = tag;
                }
                if let Some(entry) = lookup.get_mut(first + 1) {
                    *entry = tag | LOOKUP_INVERTED;
                }
                let _ = active.push(slot as u8);
            })
            .map_err(IntegrityFault::Records)?;
        if let Some(fault) = runtime_fault {
            return Err(fault);
        }
        if active != self.active {
            return Err(IntegrityFault::ActiveList);
        }
        // SRDOs that do not run must be idle, with nothing resolved.
        for (slot, runtime) in self.runtime.iter().enumerate() {
            if !active.contains(&(slot as u8)) && *runtime != SrdoRuntime::IDLE {
                return Err(IntegrityFault::Runtime(SrdoNumber::from_index(slot)));
            }
        }
        if lookup != self.lookup {
            return Err(IntegrityFault::IdentifierTable);
        }
        Ok(())
    }
}

#[cfg(test)]
#[path = "integrity_tests.rs"]
mod tests;
