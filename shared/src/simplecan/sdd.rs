//! The safety data dictionary: what an SCL sends and receives (SC_REQ_12, SC_REQ_16).
//!
//! One entry per SC-ID (`docs/simplecan.md` section 1), at most 80 (SC_REQ_12): the SC-ID,
//! its node hash (SC_REQ_15), and either the slot it is produced in or the safety timeout it
//! is consumed with. Built by [`Sdd::new`], which refuses a dictionary that breaks a rule, so
//! a value of it is always consistent; the device checks it before normal operation and
//! stays in the safe state when it is refused (SC_REQ_16).
//!
//! A dictionary holds as many entries as the device it is built for (`E`, 1..=80), not
//! always 80: the SimpleCAN layer of a device with two entries keeps a dictionary of two, so
//! neither its state nor the frames that build it carry 78 unused entries.

use super::{HashLookup, NodeHash, ScId};
use crate::time::Duration;
use heapless::Vec;

/// The most entries a safety data dictionary holds (SC_REQ_12): one per SC-ID.
pub const MAX_ENTRIES: usize = ScId::COUNT;

/// The longest safety timeout a consumer may be given: 60 s. (A timeout exists to bound the
/// reaction time, SC_REQ_45; one of a minute is already a configuration mistake to ask about.)
pub const MAX_TIMEOUT: Duration = Duration::from_millis(60_000);

/// How an SCL uses one SC-ID.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Role {
    /// It sends the SC-ID's value in slot `slot` of every cycle.
    Produce {
        /// The slot.
        slot: u16,
    },
    /// It receives it, and sets it to 0 when its age reaches `timeout` (SC_REQ_20).
    Consume {
        /// The safety timeout.
        timeout: Duration,
    },
    /// It only checks this SC-ID's syncs: the SC-ID of a potential master.
    Master,
}

/// One entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Entry {
    /// The SC-ID.
    pub sc_id: ScId,
    /// Its node hash.
    pub hash: NodeHash,
    /// What this SCL does with it.
    pub role: Role,
}

/// Why a safety data dictionary is refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SddError {
    /// More than 80 entries (SC_REQ_12).
    TooManyEntries {
        /// How many were given.
        count: usize,
    },
    /// More entries than the device holds (its SDD capacity, at most 80, SC_REQ_12).
    OverCapacity {
        /// How many were given.
        count: usize,
        /// How many the device holds.
        capacity: usize,
    },
    /// One SC-ID in two entries.
    DuplicateScId {
        /// The SC-ID.
        sc_id: ScId,
    },
    /// A consumed SC-ID with a timeout of 0 or above 60 s.
    Timeout {
        /// The SC-ID.
        sc_id: ScId,
    },
}

/// A checked safety data dictionary of at most `E` entries (1..=80, SC_REQ_12).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Sdd<const E: usize> {
    entries: Vec<Entry, E>,
}

impl<const E: usize> Sdd<E> {
    /// The dictionary of `entries`, refused with the first rule it breaks: more than 80
    /// entries ([`SddError::TooManyEntries`]), more than `E` ([`SddError::OverCapacity`]),
    /// an SC-ID twice, a consumed SC-ID's timeout of 0 or above [`MAX_TIMEOUT`].
    pub fn new(entries: &[Entry]) -> Result<Self, SddError> {
        const {
            assert!(E >= 1 && E <= MAX_ENTRIES, "1..=80 SDD entries (SC_REQ_12)");
        }
        let over_capacity = SddError::OverCapacity {
            count: entries.len(),
            capacity: E,
        };
        if entries.len() > MAX_ENTRIES {
            return Err(SddError::TooManyEntries {
                count: entries.len(),
            });
        }
        if entries.len() > E {
            return Err(over_capacity);
        }
        let mut checked: Vec<Entry, E> = Vec::new();
        for entry in entries {
            if checked.iter().any(|held| held.sc_id == entry.sc_id) {
                return Err(SddError::DuplicateScId { sc_id: entry.sc_id });
            }
            if let Role::Consume { timeout } = entry.role
                && (timeout == Duration::ZERO || timeout > MAX_TIMEOUT)
            {
                return Err(SddError::Timeout { sc_id: entry.sc_id });
            }
            // At most E entries were given, so there is room.
            checked.push(*entry).map_err(|_| over_capacity)?;
        }
        Ok(Sdd { entries: checked })
    }

    /// The entries, in the order given.
    pub fn entries(&self) -> &[Entry] {
        &self.entries
    }

    /// The entry of `sc_id`.
    pub fn entry(&self, sc_id: ScId) -> Option<&Entry> {
        self.entries.iter().find(|entry| entry.sc_id == sc_id)
    }

    /// The lowest SC-ID this SCL produces: the ID of SC_REQ_25/27 when it is a potential
    /// master.
    pub fn lowest_produced(&self) -> Option<ScId> {
        self.entries
            .iter()
            .filter(|entry| matches!(entry.role, Role::Produce { .. }))
            .map(|entry| entry.sc_id)
            .min()
    }
}

impl<const E: usize> HashLookup for Sdd<E> {
    fn node_hash(&self, sc_id: ScId) -> Option<NodeHash> {
        self.entry(sc_id).map(|entry| entry.hash)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(raw: u8, role: Role) -> Entry {
        Entry {
            sc_id: ScId::new(raw).unwrap(),
            hash: NodeHash(u32::from(raw) * 0x0101_0101),
            role,
        }
    }

    fn consume(raw: u8) -> Entry {
        entry(
            raw,
            Role::Consume {
                timeout: Duration::from_millis(100),
            },
        )
    }

    #[test]
    fn sc_req_12_the_sdd_holds_80_entries_and_refuses_an_81st() {
        let all: std::vec::Vec<Entry> = (0x30..=0x7F).map(consume).collect();
        let sdd = Sdd::<80>::new(&all).unwrap();
        assert_eq!(sdd.entries().len(), 80);
        let mut more = all;
        more.push(consume(0x30));
        assert_eq!(
            Sdd::<80>::new(&more),
            Err(SddError::TooManyEntries { count: 81 })
        );
        // 80 entries with one SC-ID twice: the duplicate is named.
        let mut twice: std::vec::Vec<Entry> = (0x30..0x7F).map(consume).collect();
        twice.push(consume(0x31));
        assert_eq!(
            Sdd::<80>::new(&twice),
            Err(SddError::DuplicateScId {
                sc_id: ScId::new(0x31).unwrap()
            })
        );
    }

    #[test]
    fn sc_req_16_a_timeout_of_0_or_over_a_minute_is_refused() {
        for bad in [0, 60_001] {
            let sdd = Sdd::<1>::new(&[entry(
                0x40,
                Role::Consume {
                    timeout: Duration::from_millis(bad),
                },
            )]);
            assert_eq!(
                sdd,
                Err(SddError::Timeout {
                    sc_id: ScId::new(0x40).unwrap()
                })
            );
        }
    }

    #[test]
    fn sc_req_15_the_sdd_gives_the_node_hash_of_each_sc_id() {
        let sdd = Sdd::<4>::new(&[
            entry(0x41, Role::Produce { slot: 2 }),
            entry(0x35, Role::Produce { slot: 0 }),
            entry(0x30, Role::Master),
            consume(0x50),
        ])
        .unwrap();
        assert_eq!(
            sdd.node_hash(ScId::new(0x50).unwrap()),
            Some(NodeHash(0x5050_5050))
        );
        assert_eq!(sdd.node_hash(ScId::new(0x51).unwrap()), None);
        assert_eq!(sdd.lowest_produced(), ScId::new(0x35));
    }

    /// A dictionary holds no more than the device's capacity: a third entry for a device of
    /// two is refused with both figures, two are accepted.
    #[test]
    fn sc_req_12_the_sdd_refuses_more_entries_than_the_device_holds() {
        let three = [consume(0x30), consume(0x31), consume(0x32)];
        assert_eq!(
            Sdd::<2>::new(&three),
            Err(SddError::OverCapacity {
                count: 3,
                capacity: 2
            })
        );
        assert_eq!(
            Sdd::<2>::new(&three[..2]).map(|sdd| sdd.entries().len()),
            Ok(2)
        );
        // Over 80 is SC_REQ_12's own limit, whatever the capacity.
        let all: std::vec::Vec<Entry> = (0x30..=0x7F).map(consume).chain([consume(0x30)]).collect();
        assert_eq!(
            Sdd::<2>::new(&all),
            Err(SddError::TooManyEntries { count: 81 })
        );
    }
}
