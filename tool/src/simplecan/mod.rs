//! SimpleCAN (FSD350) on the tool's side: what the network file's `[simplecan]` section
//! becomes on each node.
//!
//! - [`hash`]: the node hash of each SC-ID (SC_REQ_15), derived from the network's name and
//!   the producer's identity.
//! - [`signature`]: the configuration signature, CRC-32/MPEG-2 by the tool's own bit-by-bit
//!   code (`docs/simplecan.md` section 11, SC_REQ_17).
//! - [`plan`]: the SDO operations that configure and verify a node's SimpleCAN objects
//!   (SC_REQ_35, SC_REQ_36), as a pure function, and their execution.
//!
//! [`NodeConfig`] is one node's configuration objects (5E00h..5EFFh, section 11) as values:
//! [`node_config`] derives it from the file, [`plan::read_back`] from what a node holds, and
//! the two are compared field by field.

pub mod hash;
pub mod plan;
pub mod signature;

use shared::canopen::od::Address;
use std::collections::BTreeMap;

/// 5E00h: the network's cycle and this node's part in it (section 11).
pub const SETTINGS: u16 = 0x5E00;
/// 5E01h:00: SDD entries in use.
pub const ENTRIES_IN_USE: Address = Address::new(0x5E01, 0);
/// 5E10h: the record of SDD entry 1; entry n is 5E10h + n − 1.
pub const FIRST_ENTRY: u16 = 0x5E10;
/// 5EFEh:00: the configuration valid flag (A5h valid).
pub const CONFIGURATION_VALID: Address = Address::new(0x5EFE, 0);
/// 5EFFh:00: the configuration signature.
pub const SIGNATURE: Address = Address::new(0x5EFF, 0);
/// The value of 5EFEh that declares the configuration valid.
pub const VALID: u8 = 0xA5;
/// The most SDD entries a node holds (SC_REQ_12): one per SC-ID.
pub const MAX_ENTRIES: usize = shared::simplecan::sdd::MAX_ENTRIES;

/// The SC-IDs, 30h..7Fh (`docs/simplecan.md` section 1).
pub const SC_IDS: std::ops::RangeInclusive<u8> =
    shared::simplecan::ScId::LOWEST.raw()..=shared::simplecan::ScId::HIGHEST.raw();

/// The worst-case age, in µs, of a consumed value just before its next packet is accepted,
/// on a fault-free network: the age counts from the start of the producer's slot
/// (`docs/simplecan.md` section 5), the next packet starts one cycle later, may go out as late
/// as the end of its 1 ms slot and may wait the buffering time in the receiver.
pub fn worst_case_age_us(slots_per_cycle: u16, buffering_us: u16) -> u64 {
    u64::from(slots_per_cycle) * shared::simplecan::SLOT.as_micros()
        + shared::simplecan::SLOT.as_micros()
        + u64::from(buffering_us)
}

/// The network-wide part of the `[simplecan]` section.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct SimpleCanNetwork {
    /// The network's name: part of every node hash, so packets of another network fail
    /// their CRC (SC_REQ_15).
    pub network_name: String,
    /// N, slots of 1 ms per cycle (SC_REQ_18).
    pub slots_per_cycle: u16,
    /// k, cycles between two syncs of the active master (SC_REQ_22).
    pub cycles_between_syncs: u16,
    /// The guaranteed maximum buffering time, µs (SC_REQ_33).
    pub buffering_us: u16,
    /// Each node's part, by node-ID; a node of the file without one has SimpleCAN off.
    pub nodes: BTreeMap<u8, NodeSimpleCan>,
    /// The node hash of every produced SC-ID, by SC-ID (distinct, never 0).
    pub hashes: BTreeMap<u8, u32>,
}

/// One node's `[node.simplecan]` table.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct NodeSimpleCan {
    /// Whether it may become the master (sends syncs as its lowest produced SC-ID).
    pub potential_master: bool,
    /// The SC-IDs it sends.
    pub produced: Vec<Produced>,
    /// The SC-IDs it receives.
    pub consumed: Vec<Consumed>,
}

impl NodeSimpleCan {
    /// Its lowest produced SC-ID: the ID its syncs carry when it is a potential master.
    pub fn lowest_produced(&self) -> Option<u8> {
        self.produced.iter().map(|produced| produced.sc_id).min()
    }
}

/// A produced SC-ID.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Produced {
    /// The SC-ID.
    pub sc_id: u8,
    /// Its slot, 0..=N − 3.
    pub slot: u16,
    /// The object its value is read from, as a mapping entry (index << 16 | sub << 8 | bits).
    pub object: u32,
}

/// A consumed SC-ID.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Consumed {
    /// The SC-ID.
    pub sc_id: u8,
    /// Its safety timeout in ms (SC_REQ_20).
    pub timeout_ms: u16,
    /// The object its value is written to, as a mapping entry.
    pub object: u32,
}

/// The role of an SDD entry (5E10h + n − 1, sub-index 02h).
pub mod role {
    /// The node sends this SC-ID.
    pub const PRODUCE: u8 = 1;
    /// The node receives this SC-ID.
    pub const CONSUME: u8 = 2;
    /// The node only checks this potential master's syncs.
    pub const MASTER_SYNCS: u8 = 3;
}

/// The role of an SDD entry in words.
pub fn role_name(value: u8) -> &'static str {
    match value {
        role::PRODUCE => "produced",
        role::CONSUME => "consumed",
        role::MASTER_SYNCS => "a potential master's syncs",
        _ => "of an unknown role",
    }
}

/// One SDD entry as the node holds it (5E10h + n − 1, sub-indices 01h..06h).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct SddEntry {
    /// :01 the SC-ID.
    pub sc_id: u8,
    /// :02 the role ([`role`]).
    pub role: u8,
    /// :03 the producer's slot (produce and consume), else 0.
    pub slot: u16,
    /// :04 the safety timeout in ms (consume), else 0.
    pub timeout_ms: u16,
    /// :05 the node hash.
    pub hash: u32,
    /// :06 the mapped object (index << 16 | sub << 8 | bits), 0 for a master's syncs.
    pub mapped: u32,
}

/// A node's SimpleCAN configuration objects as values (section 11), in the order the
/// signature covers them.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct NodeConfig {
    /// The node-ID (the first octet of the signature).
    pub node_id: u8,
    /// 5E00h:01 N.
    pub slots_per_cycle: u16,
    /// 5E00h:02 k.
    pub cycles_between_syncs: u16,
    /// 5E00h:03 the maximum buffering time, µs.
    pub buffering_us: u16,
    /// 5E00h:04 SimpleCAN enabled (0 or 1).
    pub enabled: u8,
    /// 5E00h:05 potential master (0 or 1).
    pub potential_master: u8,
    /// 5E10h.. the entries; their count is 5E01h.
    pub entries: Vec<SddEntry>,
}

/// The configuration objects of node `node_id` that `network` asks for: its produced and
/// consumed SC-IDs, and an entry (role 3) for the syncs of every other potential master whose
/// SC-ID it does not already hold (a sync is checked with its master's hash, section 3);
/// ordered by SC-ID. A node without a `[node.simplecan]` table gets SimpleCAN off and no
/// entries, so no stale configuration stays enabled on it.
pub fn node_config(network: &SimpleCanNetwork, node_id: u8) -> NodeConfig {
    let mut config = NodeConfig {
        node_id,
        slots_per_cycle: network.slots_per_cycle,
        cycles_between_syncs: network.cycles_between_syncs,
        buffering_us: network.buffering_us,
        enabled: 0,
        potential_master: 0,
        entries: Vec::new(),
    };
    let Some(node) = network.nodes.get(&node_id) else {
        return config;
    };
    config.enabled = 1;
    config.potential_master = u8::from(node.potential_master);
    let hash = |sc_id: u8| network.hashes.get(&sc_id).copied().unwrap_or(0);
    for produced in &node.produced {
        config.entries.push(SddEntry {
            sc_id: produced.sc_id,
            role: role::PRODUCE,
            slot: produced.slot,
            timeout_ms: 0,
            hash: hash(produced.sc_id),
            mapped: produced.object,
        });
    }
    // A consumer judges each packet's timeliness by its producer's slot (section 5), so a
    // consumed entry carries it; the file's check guarantees the SC-ID has a producer.
    let producer_slot = |sc_id: u8| {
        network
            .nodes
            .values()
            .flat_map(|other| &other.produced)
            .find(|produced| produced.sc_id == sc_id)
            .map_or(0, |produced| produced.slot)
    };
    for consumed in &node.consumed {
        config.entries.push(SddEntry {
            sc_id: consumed.sc_id,
            role: role::CONSUME,
            slot: producer_slot(consumed.sc_id),
            timeout_ms: consumed.timeout_ms,
            hash: hash(consumed.sc_id),
            mapped: consumed.object,
        });
    }
    for master in network
        .nodes
        .iter()
        .filter(|(id, other)| **id != node_id && other.potential_master)
        .filter_map(|(_, other)| other.lowest_produced())
    {
        if !config.entries.iter().any(|entry| entry.sc_id == master) {
            config.entries.push(SddEntry {
                sc_id: master,
                role: role::MASTER_SYNCS,
                slot: 0,
                timeout_ms: 0,
                hash: hash(master),
                mapped: 0,
            });
        }
    }
    config.entries.sort_by_key(|entry| entry.sc_id);
    config
}

/// The object of SDD entry `n` (1..=80).
pub fn entry_index(n: usize) -> u16 {
    // n ≤ 80, so the sum stays below 5E60h.
    FIRST_ENTRY + (n as u16).saturating_sub(1)
}

/// The name of a SimpleCAN configuration object, for messages.
pub fn object_name(address: Address) -> Option<String> {
    let Address { index, sub } = address;
    match index {
        SETTINGS => Some(
            match sub {
                0 => "SimpleCAN settings: highest sub-index",
                1 => "SimpleCAN slots per cycle",
                2 => "SimpleCAN cycles between syncs",
                3 => "SimpleCAN maximum buffering time",
                4 => "SimpleCAN enabled",
                5 => "SimpleCAN potential master",
                _ => return None,
            }
            .into(),
        ),
        0x5E01 => Some("SimpleCAN SDD entries in use".into()),
        0x5E10..=0x5E5F => {
            let n = index - FIRST_ENTRY + 1;
            let field = match sub {
                1 => "SC-ID",
                2 => "role",
                3 => "slot",
                4 => "safety timeout",
                5 => "node hash",
                6 => "mapped object",
                _ => return None,
            };
            Some(format!("SimpleCAN SDD entry {n} {field}"))
        }
        0x5EFE => Some("SimpleCAN configuration valid".into()),
        0x5EFF => Some("SimpleCAN configuration signature".into()),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn network() -> SimpleCanNetwork {
        let mut nodes = BTreeMap::new();
        nodes.insert(
            1,
            NodeSimpleCan {
                potential_master: true,
                produced: vec![Produced {
                    sc_id: 0x31,
                    slot: 0,
                    object: 0x6000_0108,
                }],
                consumed: vec![],
            },
        );
        nodes.insert(
            2,
            NodeSimpleCan {
                potential_master: true,
                produced: vec![Produced {
                    sc_id: 0x40,
                    slot: 1,
                    object: 0x6000_0108,
                }],
                consumed: vec![],
            },
        );
        nodes.insert(
            33,
            NodeSimpleCan {
                potential_master: false,
                produced: vec![],
                consumed: vec![Consumed {
                    sc_id: 0x31,
                    timeout_ms: 50,
                    object: 0x6200_0108,
                }],
            },
        );
        SimpleCanNetwork {
            network_name: "line".into(),
            slots_per_cycle: 10,
            cycles_between_syncs: 10,
            buffering_us: 500,
            nodes,
            hashes: [(0x31, 0x1111_1111), (0x40, 0x4040_4040)].into(),
        }
    }

    /// Section 3: every SCL checks every potential master's syncs with that master's hash; a
    /// consumer of the master's SC-ID already holds it, the others get a role-3 entry.
    #[test]
    fn sc_req_16_every_node_holds_the_hash_of_every_potential_master() {
        let network = network();
        let consumer = node_config(&network, 33);
        assert_eq!(consumer.enabled, 1);
        assert_eq!(
            consumer.entries,
            vec![
                SddEntry {
                    sc_id: 0x31,
                    role: role::CONSUME,
                    slot: 0,
                    timeout_ms: 50,
                    hash: 0x1111_1111,
                    mapped: 0x6200_0108,
                },
                SddEntry {
                    sc_id: 0x40,
                    role: role::MASTER_SYNCS,
                    slot: 0,
                    timeout_ms: 0,
                    hash: 0x4040_4040,
                    mapped: 0,
                },
            ]
        );
        let master = node_config(&network, 1);
        assert_eq!(master.potential_master, 1);
        assert_eq!(
            master
                .entries
                .iter()
                .map(|e| (e.sc_id, e.role))
                .collect::<Vec<_>>(),
            vec![(0x31, role::PRODUCE), (0x40, role::MASTER_SYNCS)]
        );
    }

    #[test]
    fn sc_req_16_a_node_outside_the_section_gets_simplecan_off() {
        let config = node_config(&network(), 7);
        assert_eq!((config.enabled, config.potential_master), (0, 0));
        assert!(config.entries.is_empty());
        assert_eq!(config.slots_per_cycle, 10);
    }
}
