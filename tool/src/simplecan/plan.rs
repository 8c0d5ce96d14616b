//! Configuring and verifying a node's SimpleCAN objects (`docs/simplecan.md` section 11;
//! SC_REQ_35, SC_REQ_36), as a plan of SDO operations and its execution.
//!
//! [`configure_plan`] is a pure function of the node's [`NodeConfig`]: the exact sequence
//!
//! 1. 5E01h = 0 (no entry in use while they change);
//! 2. 5E00h sub-indices 01..05;
//! 3. each entry n = 1..count, sub-indices 01..06;
//! 4. 5E01h = count (the node checks every entry when it takes the count);
//! 5. read back, in the reverse order (last entry first, each from sub-index 06h down, then
//!    5E01h, then 5E00h from 05h down), every value decoded by [`decode`] into a
//!    [`NodeConfig`] of its own and compared field by field with the file's (SC_REQ_36);
//! 6. the signature (the tool's own CRC-32, [`super::signature`]) to 5EFFh, read back;
//! 7. 5EFEh = A5h, read back; store (1010h:01 = "save"), 5EFEh read again.
//!
//! [`execute`] runs it: any refusal, silence or difference stops the node there, 5EFEh is set
//! to 0 (best effort: every accepted write to 5E00h..5E5Fh has already set it to 0), and the
//! error says what differed. The read-back path shares nothing with the write path but the
//! addresses: the writes serialise the file's values ([`writes`]); the reads are SDO uploads
//! whose answers [`decode`] turns back into values with its own table of types, and the
//! comparison is of values, not of the octets sent.

use super::signature::signature;
use super::{
    CONFIGURATION_VALID, ENTRIES_IN_USE, MAX_ENTRIES, NodeConfig, SETTINGS, SIGNATURE, SddEntry,
    VALID, entry_index, object_name,
};
use crate::client::Client;
use crate::error::ToolError;
use crate::procedure::{STORE_PARAMETERS as STORE, explain_store_refusal};
use crate::transport::Transport;
use shared::canopen::od::Address;
use std::collections::BTreeMap;

/// One SDO operation of a plan.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Operation {
    /// SDO download of `data` to `address`.
    Write {
        /// The object.
        address: Address,
        /// The value, as SDO carries it (least significant octet first).
        data: Vec<u8>,
    },
    /// SDO upload of `address`, `len` octets, into the read-back record.
    ReadBack {
        /// The object.
        address: Address,
        /// Its type's size.
        len: usize,
    },
    /// Decode the read-back record ([`decode`]) and compare it with the file's configuration;
    /// stop on any difference.
    Compare,
    /// SDO upload of `address`; the node must hold `value` (`len` octets).
    Expect {
        /// The object.
        address: Address,
        /// Its type's size.
        len: usize,
        /// The value it must hold.
        value: u32,
    },
}

/// The settings' sub-indices 01..05 and their sizes.
const SETTINGS_SIZES: [(u8, usize); 5] = [(1, 2), (2, 2), (3, 2), (4, 1), (5, 1)];
/// An entry's sub-indices 01..06 and their sizes.
const ENTRY_SIZES: [(u8, usize); 6] = [(1, 1), (2, 1), (3, 2), (4, 2), (5, 4), (6, 4)];

/// Every value of `config` but the entry count, with its object and its type's size, in
/// object order: the settings 01..05, then each entry's 01..06. The one list of which field
/// goes where, for the writes and the comparison.
fn values(config: &NodeConfig) -> Vec<(Address, usize, u32)> {
    let settings = [
        u32::from(config.slots_per_cycle),
        u32::from(config.cycles_between_syncs),
        u32::from(config.buffering_us),
        u32::from(config.enabled),
        u32::from(config.potential_master),
    ];
    let mut values: Vec<_> = SETTINGS_SIZES
        .iter()
        .zip(settings)
        .map(|(&(sub, len), value)| (Address::new(SETTINGS, sub), len, value))
        .collect();
    for (n, entry) in (1..).zip(&config.entries) {
        let fields = [
            u32::from(entry.sc_id),
            u32::from(entry.role),
            u32::from(entry.slot),
            u32::from(entry.timeout_ms),
            entry.hash,
            entry.mapped,
        ];
        values.extend(
            ENTRY_SIZES
                .iter()
                .zip(fields)
                .map(|(&(sub, len), value)| (Address::new(entry_index(n), sub), len, value)),
        );
    }
    values
}

/// The writes of steps 1..4, in order.
pub fn writes(config: &NodeConfig) -> Vec<Operation> {
    let write = |address: Address, data: Vec<u8>| Operation::Write { address, data };
    let mut plan = vec![write(ENTRIES_IN_USE, vec![0])];
    plan.extend(
        values(config)
            .into_iter()
            .map(|(address, len, value)| write(address, value.to_le_bytes()[..len].to_vec())),
    );
    // At most 80 entries (the file parser refuses more).
    plan.push(write(ENTRIES_IN_USE, vec![config.entries.len() as u8]));
    plan
}

/// The reads of step 5 for `count` entries: the reverse of the write order.
pub fn read_back(count: usize) -> Vec<Operation> {
    let mut plan = Vec::new();
    for n in (1..=count.min(MAX_ENTRIES)).rev() {
        for &(sub, len) in ENTRY_SIZES.iter().rev() {
            plan.push(Operation::ReadBack {
                address: Address::new(entry_index(n), sub),
                len,
            });
        }
    }
    plan.push(Operation::ReadBack {
        address: ENTRIES_IN_USE,
        len: 1,
    });
    for &(sub, len) in SETTINGS_SIZES.iter().rev() {
        plan.push(Operation::ReadBack {
            address: Address::new(SETTINGS, sub),
            len,
        });
    }
    plan
}

/// The whole sequence that configures a node with `config` (the module's steps 1..7).
pub fn configure_plan(config: &NodeConfig) -> Vec<Operation> {
    let value = signature(config);
    let mut plan = writes(config);
    plan.extend(read_back(config.entries.len()));
    plan.push(Operation::Compare);
    plan.push(Operation::Write {
        address: SIGNATURE,
        data: value.to_le_bytes().to_vec(),
    });
    plan.push(Operation::Expect {
        address: SIGNATURE,
        len: 4,
        value,
    });
    plan.push(Operation::Write {
        address: CONFIGURATION_VALID,
        data: vec![VALID],
    });
    let valid = Operation::Expect {
        address: CONFIGURATION_VALID,
        len: 1,
        value: u32::from(VALID),
    };
    plan.push(valid.clone());
    plan.push(Operation::Write {
        address: STORE,
        data: b"save".to_vec(),
    });
    plan.push(valid);
    plan
}

/// The configuration of node `node_id` that the values read back describe, `count` entries
/// of them: every field from its own address (missing values are 0 and differ).
pub fn decode(node_id: u8, count: usize, values: &BTreeMap<Address, u32>) -> NodeConfig {
    let get = |index: u16, sub: u8| values.get(&Address::new(index, sub)).copied().unwrap_or(0);
    let narrow16 = |value: u32| u16::try_from(value).unwrap_or(u16::MAX);
    let narrow8 = |value: u32| u8::try_from(value).unwrap_or(u8::MAX);
    NodeConfig {
        node_id,
        slots_per_cycle: narrow16(get(SETTINGS, 1)),
        cycles_between_syncs: narrow16(get(SETTINGS, 2)),
        buffering_us: narrow16(get(SETTINGS, 3)),
        enabled: narrow8(get(SETTINGS, 4)),
        potential_master: narrow8(get(SETTINGS, 5)),
        entries: (1..=count.min(MAX_ENTRIES))
            .map(|n| {
                let index = entry_index(n);
                SddEntry {
                    sc_id: narrow8(get(index, 1)),
                    role: narrow8(get(index, 2)),
                    slot: narrow16(get(index, 3)),
                    timeout_ms: narrow16(get(index, 4)),
                    hash: get(index, 5),
                    mapped: get(index, 6),
                }
            })
            .collect(),
    }
}

/// The differences between the file's configuration and the node's, one line each:
/// `SimpleCAN SDD entry 1 safety timeout (5E10h:04h): file 32h, node 28h`.
pub fn config_diff(file: &NodeConfig, node: &NodeConfig) -> Vec<String> {
    let mut lines = Vec::new();
    let mut compare = |address: Address, file: u32, held: u32| {
        if file != held {
            lines.push(format!(
                "{} ({:04X}h:{:02X}h): file {file:X}h, node {held:X}h",
                object_name(address).unwrap_or_default(),
                address.index,
                address.sub
            ));
        }
    };
    compare(
        ENTRIES_IN_USE,
        file.entries.len() as u32,
        node.entries.len() as u32,
    );
    // Settings first, then the entries both hold, in the same positions of both lists.
    for ((address, _, want), (_, _, held)) in values(file).into_iter().zip(values(node)) {
        compare(address, want, held);
    }
    lines
}

/// Runs `plan` (from [`configure_plan`] for `config`) on node `config.node_id`; returns the
/// signature written. On any error 5EFEh is set to 0 (best effort) and the error returned.
pub fn execute<T: Transport>(
    client: &mut Client<T>,
    config: &NodeConfig,
    plan: &[Operation],
) -> Result<u32, ToolError> {
    let node = config.node_id;
    let result = run(client, config, plan);
    if result.is_err() {
        // Best effort: a node that stopped answering cannot be told, and every write it
        // accepted has already set 5EFEh to 0.
        let _ = client.write(node, CONFIGURATION_VALID, &[0]);
    }
    result
}

fn run<T: Transport>(
    client: &mut Client<T>,
    config: &NodeConfig,
    plan: &[Operation],
) -> Result<u32, ToolError> {
    let node = config.node_id;
    let mut held: BTreeMap<Address, u32> = BTreeMap::new();
    let mut last_write = None;
    for operation in plan {
        match operation {
            Operation::Write { address, data } => {
                client
                    .write(node, *address, data)
                    .map_err(explain_store_refusal)?;
                last_write = Some(*address);
            }
            Operation::ReadBack { address, len } => {
                held.insert(*address, client.read_unsigned(node, *address, *len)?);
            }
            Operation::Compare => {
                let read = decode(node, config.entries.len(), &held);
                let diff = config_diff(config, &read);
                if !diff.is_empty() {
                    return Err(ToolError::ReadBackMismatch {
                        node,
                        diff: diff.join("\n"),
                    });
                }
            }
            Operation::Expect {
                address,
                len,
                value,
            } => {
                let read = client.read_unsigned(node, *address, *len)?;
                if read != *value {
                    return Err(if *address == CONFIGURATION_VALID {
                        ToolError::SimpleCanNotValid {
                            node,
                            value: u8::try_from(read).unwrap_or(u8::MAX),
                            when: if last_write == Some(STORE) {
                                "storing (0x1010)"
                            } else {
                                "writing it"
                            },
                        }
                    } else {
                        ToolError::ReadBackMismatch {
                            node,
                            diff: format!(
                                "{} ({:04X}h:{:02X}h): tool {value:08X}h, node {read:08X}h",
                                object_name(*address).unwrap_or_default(),
                                address.index,
                                address.sub
                            ),
                        }
                    });
                }
            }
        }
    }
    Ok(signature(config))
}

/// What [`verify`] found on one node's SimpleCAN objects.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Checked {
    /// One line per difference from the file, the signature included.
    pub diff: Vec<String>,
    /// The value of 5EFEh.
    pub configuration_valid: u8,
}

/// Reads node `file.node_id`'s SimpleCAN objects (as many entries as the node says it
/// uses), compares them with `file`, recomputes the signature over what the node holds
/// (the tool's own CRC) and compares it with 5EFFh, and reads 5EFEh.
pub fn verify<T: Transport>(
    client: &mut Client<T>,
    file: &NodeConfig,
) -> Result<Checked, ToolError> {
    let node = file.node_id;
    let count = client.read_unsigned(node, ENTRIES_IN_USE, 1)? as usize;
    let mut held = BTreeMap::new();
    for operation in read_back(count) {
        if let Operation::ReadBack { address, len } = operation {
            held.insert(address, client.read_unsigned(node, address, len)?);
        }
    }
    let read = decode(node, count, &held);
    let mut diff = config_diff(file, &read);
    let computed = signature(&read);
    let stored = client.read_unsigned(node, SIGNATURE, 4)?;
    if stored != computed {
        diff.push(format!(
            "SimpleCAN configuration signature (5EFFh:00h): computed from the node's values {computed:08X}h, node holds {stored:08X}h"
        ));
    }
    let configuration_valid = client.read_unsigned(node, CONFIGURATION_VALID, 1)? as u8;
    Ok(Checked {
        diff,
        configuration_valid,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simplecan::role;

    fn config() -> NodeConfig {
        NodeConfig {
            node_id: 33,
            slots_per_cycle: 10,
            cycles_between_syncs: 10,
            buffering_us: 500,
            enabled: 1,
            potential_master: 0,
            entries: vec![
                SddEntry {
                    sc_id: 0x30,
                    role: role::CONSUME,
                    slot: 0,
                    timeout_ms: 50,
                    hash: 0x1234_5678,
                    mapped: 0x6200_0108,
                },
                SddEntry {
                    sc_id: 0x41,
                    role: role::CONSUME,
                    slot: 0,
                    timeout_ms: 12,
                    hash: 0xA5C3_0F96,
                    mapped: 0x6201_0108,
                },
            ],
        }
    }

    /// What the plan's read-back would record from a node that holds `config`.
    fn held(config: &NodeConfig) -> BTreeMap<Address, u32> {
        writes(config)
            .into_iter()
            .filter_map(|operation| match operation {
                Operation::Write { address, data } => {
                    let mut raw = [0u8; 4];
                    raw[..data.len()].copy_from_slice(&data);
                    Some((address, u32::from_le_bytes(raw)))
                }
                _ => None,
            })
            .collect()
    }

    #[test]
    fn sc_req_36_the_read_back_decodes_to_the_written_configuration() {
        let config = config();
        assert_eq!(decode(33, 2, &held(&config)), config);
        assert!(config_diff(&config, &decode(33, 2, &held(&config))).is_empty());
    }

    #[test]
    fn sc_req_36_every_difference_is_a_line_naming_the_object() {
        let config = config();
        let mut values = held(&config);
        values.insert(Address::new(0x5E11, 4), 40);
        values.insert(Address::new(SETTINGS, 3), 0);
        let diff = config_diff(&config, &decode(33, 2, &values));
        assert_eq!(
            diff,
            vec![
                "SimpleCAN maximum buffering time (5E00h:03h): file 1F4h, node 0h",
                "SimpleCAN SDD entry 2 safety timeout (5E11h:04h): file Ch, node 28h",
            ]
        );
        // A node that keeps one entry fewer differs in the count.
        let diff = config_diff(&config, &decode(33, 1, &values));
        assert!(
            diff.iter()
                .any(|line| line == "SimpleCAN SDD entries in use (5E01h:00h): file 2h, node 1h")
        );
    }
}
