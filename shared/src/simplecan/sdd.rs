//! The safety data dictionary: what an SCL sends and receives (SC_REQ_12, SC_REQ_16).
//!
//! One entry per SC-ID (`docs/simplecan.md` section 1), at most 80 (SC_REQ_12): the SC-ID,
//! its node hash (SC_REQ_15), and either the slot it is produced in or the safety timeout it
//! is consumed with. Built by [`Sdd::new`], which refuses a dictionary that breaks a rule, so
//! a value of it is always consistent; the device checks it before normal operation and
//! stays in the safe state when it is refused (SC_REQ_16).

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

/// A checked safety data dictionary.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Sdd {
    entries: Vec<Entry, MAX_ENTRIES>,
}

impl Sdd {
    /// The dictionary of `entries`, refused with the first rule it breaks.
    pub fn new(entries: &[Entry]) -> Result<Self, SddError> {
        if entries.len() > MAX_ENTRIES {
            return Err(SddError::TooManyEntries {
                count: entries.len(),
            });
        }
        let mut checked: Vec<Entry, MAX_ENTRIES> = Vec::new();
        for entry in entries {
            if checked.iter().any(|held| held.sc_id == entry.sc_id) {
                return Err(SddError::DuplicateScId { sc_id: entry.sc_id });
            }
            if let Role::Consume { timeout } = entry.role
                && (timeout == Duration::ZERO || timeout > MAX_TIMEOUT)
            {
                return Err(SddError::Timeout { sc_id: entry.sc_id });
            }
            // At most MAX_ENTRIES entries were given, so there is room.
            checked.push(*entry).map_err(|_| SddError::TooManyEntries {
                count: entries.len(),
            })?;
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

impl HashLookup for Sdd {
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
        let sdd = Sdd::new(&all).unwrap();
        assert_eq!(sdd.entries().len(), 80);
        let mut more = all;
        more.push(consume(0x30));
        assert_eq!(Sdd::new(&more), Err(SddError::TooManyEntries { count: 81 }));
        // 80 entries with one SC-ID twice: the duplicate is named.
        let mut twice: std::vec::Vec<Entry> = (0x30..0x7F).map(consume).collect();
        twice.push(consume(0x31));
        assert_eq!(
            Sdd::new(&twice),
            Err(SddError::DuplicateScId {
                sc_id: ScId::new(0x31).unwrap()
            })
        );
    }

    #[test]
    fn sc_req_16_a_timeout_of_0_or_over_a_minute_is_refused() {
        for bad in [0, 60_001] {
            let sdd = Sdd::new(&[entry(
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
        let sdd = Sdd::new(&[
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
}
