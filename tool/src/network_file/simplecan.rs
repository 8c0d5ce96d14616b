//! The network file's SimpleCAN part: the `[simplecan]` section and each node's
//! `[node.simplecan]` table, checked rule by rule with line, column and a sentence.
//!
//! ```toml
//! [simplecan]
//! network_name = "press line 3"   # part of every node hash (SC_REQ_15)
//! slots_per_cycle = 10            # N, slots of 1 ms (SC_REQ_18), 3..1000
//! cycles_between_syncs = 10       # k: N × k ms within 100..500 (SC_REQ_22)
//! buffering_us = 500              # guaranteed maximum buffering time (SC_REQ_33)
//!
//! [[node]]
//! id = 1
//! identity = { vendor = 0xABC, product = 0x304, serial = 1 }
//! [node.simplecan]
//! potential_master = true         # optional, default false (SC_REQ_25..28)
//! produce = [ { sc_id = 0x30, slot = 0, object = "input" } ]
//! consume = [ { sc_id = 0x41, timeout_ms = 50, object = "output" } ]
//! ```
//!
//! The rules, each refused with its own sentence: SC-IDs 30h..7Fh, each produced by exactly
//! one node and listed at most once per node (SC_REQ_12, SC_REQ_15); at most 80 SDD entries
//! per node, counting the syncs of other potential masters it must check (SC_REQ_12); slots
//! 0..N−3, one producer per slot (SC_REQ_18, SC_REQ_21); N × k within 100..500 ms
//! (SC_REQ_22); safety timeouts 1..60000 ms (SC_REQ_20) and longer than the worst-case age of
//! a value a fault-free network delivers; the mapped object exists and is mappable in that
//! direction; a consumed SC-ID is produced by a node of the file; a potential master produces
//! an SC-ID, and some node is one; the network's packet rate within SC_REQ_04's bound
//! (`shared::simplecan::schedule::Schedule::new`, the device's own check); distinct node
//! hashes.

use super::{FileError, NodeSpec, Parser, RawNode, mapping_entry};
use crate::simplecan::{
    Consumed, MAX_ENTRIES, NodeSimpleCan, Produced, SC_IDS, SimpleCanNetwork, hash,
    worst_case_age_us,
};
use serde::Deserialize;
use shared::process_image::Mappable;
use shared::simplecan::schedule::{MAX_SLOTS, MIN_SLOTS, Schedule, ScheduleError};
use shared::simplecan::sdd::MAX_TIMEOUT;
use shared::simplecan::{MAX_SYNC_INTERVAL, MIN_SYNC_INTERVAL, ScId};
use std::collections::BTreeMap;
use toml::Spanned;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawSimpleCan {
    network_name: Spanned<String>,
    slots_per_cycle: Spanned<i64>,
    cycles_between_syncs: Spanned<i64>,
    buffering_us: Spanned<i64>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawNodeSimpleCan {
    #[serde(default)]
    potential_master: Option<Spanned<bool>>,
    #[serde(default)]
    produce: Vec<Spanned<RawProduce>>,
    #[serde(default)]
    consume: Vec<Spanned<RawConsume>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawProduce {
    sc_id: Spanned<i64>,
    slot: Spanned<i64>,
    object: Spanned<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConsume {
    sc_id: Spanned<i64>,
    timeout_ms: Spanned<i64>,
    object: Spanned<String>,
}

fn millis(micros: u64) -> String {
    if micros % 1000 == 0 {
        format!("{} ms", micros / 1000)
    } else {
        format!("{} ms", micros as f64 / 1000.0)
    }
}

/// Parses and checks the SimpleCAN part of a network file whose nodes are `nodes` (already
/// checked), `raw_nodes` their raw tables in the same order.
pub(super) fn parse(
    parser: &Parser<'_>,
    section: Option<&Spanned<RawSimpleCan>>,
    raw_nodes: &[Spanned<RawNode>],
    nodes: &[NodeSpec],
) -> Result<Option<SimpleCanNetwork>, FileError> {
    let Some(section) = section else {
        if let Some(table) = raw_nodes
            .iter()
            .find_map(|node| node.get_ref().simplecan.as_ref())
        {
            return Err(parser.error(
                table.span(),
                "this node has a [node.simplecan] table, but the file has no [simplecan] section (network name, slots per cycle, cycles between syncs, buffering time)",
            ));
        }
        return Ok(None);
    };
    let raw = section.get_ref();
    let network_name = raw.network_name.get_ref().trim().to_owned();
    if network_name.is_empty() {
        return Err(parser.error(
            raw.network_name.span(),
            "the network name is empty: it goes into every node hash (SC_REQ_15), so packets of another network fail the CRC; give the network a name of its own",
        ));
    }
    let slots_per_cycle: u16 = parser.number(
        &raw.slots_per_cycle,
        i64::from(MIN_SLOTS)..=i64::from(MAX_SLOTS),
        "the number of slots per cycle (SC_REQ_18, SC_REQ_21: at least one producer slot and the two empty ones)",
    )?;
    let cycles_between_syncs: u16 = parser.number(
        &raw.cycles_between_syncs,
        1..=65535,
        "the number of cycles between syncs",
    )?;
    let interval_ms = u64::from(slots_per_cycle) * u64::from(cycles_between_syncs);
    let (shortest, longest) = (
        MIN_SYNC_INTERVAL.as_micros() / 1000,
        MAX_SYNC_INTERVAL.as_micros() / 1000,
    );
    if !(shortest..=longest).contains(&interval_ms) {
        return Err(parser.error(
            raw.cycles_between_syncs.span(),
            format!(
                "the sync interval is {slots_per_cycle} slots × {cycles_between_syncs} cycles = {interval_ms} ms, but must be {shortest} to {longest} ms (SC_REQ_22)"
            ),
        ));
    }
    let buffering_us: u16 = parser.number(
        &raw.buffering_us,
        0..=65535,
        "the maximum buffering time (µs, SC_REQ_33)",
    )?;
    let last_slot = slots_per_cycle - 3;

    let mut by_node: BTreeMap<u8, NodeSimpleCan> = BTreeMap::new();
    // SC-ID → (producer, the span of its sc_id) and slot → (SC-ID, producer).
    let mut producers: BTreeMap<u8, (u8, std::ops::Range<usize>)> = BTreeMap::new();
    let mut slots: BTreeMap<u16, (u8, u8)> = BTreeMap::new();
    let mut consumers: Vec<(u8, u8, std::ops::Range<usize>)> = Vec::new();
    for (spec, node) in nodes.iter().zip(raw_nodes) {
        let Some(table) = &node.get_ref().simplecan else {
            continue;
        };
        let id = spec.id;
        let table_raw = table.get_ref();
        let mut own = NodeSimpleCan {
            potential_master: table_raw
                .potential_master
                .as_ref()
                .is_some_and(|value| *value.get_ref()),
            ..NodeSimpleCan::default()
        };
        let mut listed: Vec<u8> = Vec::new();
        let mut sc_id_of = |value: &Spanned<i64>| -> Result<u8, FileError> {
            let raw = *value.get_ref();
            let shown = if (0..=0xFF).contains(&raw) {
                format!("{raw:02X}h")
            } else {
                raw.to_string()
            };
            let sc_id = u8::try_from(raw)
                .ok()
                .filter(|sc_id| SC_IDS.contains(sc_id))
                .ok_or_else(|| {
                    parser.error(
                        value.span(),
                        format!(
                            "node {id}: the SC-ID is {shown}, but must be 30h to 7Fh, one of the 80 entries a safety data dictionary has (SC_REQ_12, docs/simplecan.md section 1)"
                        ),
                    )
                })?;
            if listed.contains(&sc_id) {
                return Err(parser.error(
                    value.span(),
                    format!(
                        "node {id}: SC-ID {sc_id:02X}h is listed twice: each SC-ID is one entry of the node's safety data dictionary, produced or consumed (SC_REQ_12)"
                    ),
                ));
            }
            listed.push(sc_id);
            Ok(sc_id)
        };
        for produce in &table_raw.produce {
            let produce = produce.get_ref();
            let sc_id = sc_id_of(&produce.sc_id)?;
            let label = format!("node {id}: SC-ID {sc_id:02X}h");
            let raw_slot = *produce.slot.get_ref();
            let slot = u16::try_from(raw_slot)
                .ok()
                .filter(|slot| *slot <= last_slot)
                .ok_or_else(|| {
                    parser.error(
                        produce.slot.span(),
                        format!(
                            "{label}: slot {raw_slot} is not a producer's slot: a cycle of {slots_per_cycle} slots gives producers 0 to {last_slot}, the last two stay empty and the sync goes in the last (SC_REQ_18, SC_REQ_21)"
                        ),
                    )
                })?;
            if let Some((producer, _)) = producers.get(&sc_id) {
                return Err(parser.error(
                    produce.sc_id.span(),
                    format!(
                        "SC-ID {sc_id:02X}h is produced by node {producer} and by node {id}: each SC-ID has exactly one producer, whose identity its node hash carries (SC_REQ_15)"
                    ),
                ));
            }
            if let Some((other, producer)) = slots.get(&slot) {
                return Err(parser.error(
                    produce.slot.span(),
                    format!(
                        "{label}: slot {slot} is already SC-ID {other:02X}h's (node {producer}): one producer per slot, so no packet waits for another's arbitration (SC_REQ_18, SC_REQ_21)"
                    ),
                ));
            }
            let object = mapping_entry(parser, &label, &produce.object, Mappable::Transmit)?;
            producers.insert(sc_id, (id, produce.sc_id.span()));
            slots.insert(slot, (sc_id, id));
            own.produced.push(Produced {
                sc_id,
                slot,
                object,
            });
        }
        let worst_age = worst_case_age_us(slots_per_cycle, buffering_us);
        for consume in &table_raw.consume {
            let consume = consume.get_ref();
            let sc_id = sc_id_of(&consume.sc_id)?;
            let label = format!("node {id}: SC-ID {sc_id:02X}h");
            let longest = MAX_TIMEOUT.as_micros() / 1000;
            let timeout_ms: u16 = parser.number(
                &consume.timeout_ms,
                1..=longest as i64,
                &format!("{label}: the safety timeout (ms, SC_REQ_20)"),
            )?;
            if u64::from(timeout_ms) * 1000 <= worst_age {
                return Err(parser.error(
                    consume.timeout_ms.span(),
                    format!(
                        "{label}: a safety timeout of {timeout_ms} ms is not met by a fault-free network: the value is refreshed once a cycle ({slots_per_cycle} ms), its packet may go out at the end of its 1 ms slot and wait {} in the buffers (SC_REQ_33), so its age reaches {} before the next one counts (SC_REQ_20; at the timeout itself the value is 0); give more than {}",
                        millis(u64::from(buffering_us)),
                        millis(worst_age),
                        millis(worst_age),
                    ),
                ));
            }
            let object = mapping_entry(parser, &label, &consume.object, Mappable::Receive)?;
            consumers.push((id, sc_id, consume.sc_id.span()));
            own.consumed.push(Consumed {
                sc_id,
                timeout_ms,
                object,
            });
        }
        if own.potential_master && own.produced.is_empty() {
            let span = table_raw
                .potential_master
                .as_ref()
                .map_or(table.span(), Spanned::span);
            return Err(parser.error(
                span,
                format!(
                    "node {id} is a potential master but produces no SC-ID: a master's syncs carry its lowest produced SC-ID (SC_REQ_25, docs/simplecan.md section 3)"
                ),
            ));
        }
        by_node.insert(id, own);
    }
    for (id, sc_id, span) in &consumers {
        if !producers.contains_key(sc_id) {
            return Err(parser.error(
                span.clone(),
                format!(
                    "node {id} consumes SC-ID {sc_id:02X}h, but no node of the file produces it: its value would stay 0 (SC_REQ_05) and its node hash cannot be generated"
                ),
            ));
        }
    }
    if !by_node.is_empty() && !by_node.values().any(|node| node.potential_master) {
        return Err(parser.error(
            raw.network_name.span(),
            "no node of the network is a potential master: nobody sends syncs, so every SimpleCAN layer stays unsynced and sends nothing (SC_REQ_25, SC_REQ_29); give one producer potential_master = true",
        ));
    }
    // The device's own check of the cycle (section 5) and of the packet rate (section 8).
    let schedule: Vec<(ScId, u16)> = by_node
        .values()
        .flat_map(|node| &node.produced)
        .filter_map(|produced| ScId::new(produced.sc_id).map(|sc_id| (sc_id, produced.slot)))
        .collect();
    if let Err(error) = <Schedule>::new(slots_per_cycle, cycles_between_syncs, &schedule) {
        return Err(parser.error(raw.slots_per_cycle.span(), schedule_sentence(error)));
    }

    let mut network = SimpleCanNetwork {
        network_name,
        slots_per_cycle,
        cycles_between_syncs,
        buffering_us,
        nodes: by_node,
        hashes: BTreeMap::new(),
    };
    for (&sc_id, (producer, span)) in &producers {
        let Some(spec) = nodes.iter().find(|node| node.id == *producer) else {
            continue;
        };
        let value = hash::node_hash(&network.network_name, sc_id, *producer, &spec.identity)
            .ok_or_else(|| {
                parser.error(
                    span.clone(),
                    format!("SC-ID {sc_id:02X}h: every word of its hash digest is 0; change the network name"),
                )
            })?;
        network.hashes.insert(sc_id, value);
    }
    if let Some((first, second, value)) = hash::first_collision(&network.hashes) {
        return Err(parser.error(
            raw.network_name.span(),
            format!(
                "SC-IDs {first:02X}h and {second:02X}h get the same node hash {value:08X}h from this network name: a packet of one would pass the other's CRC check (SC_REQ_15); change the network name"
            ),
        ));
    }
    for (id, node) in &network.nodes {
        let entries = crate::simplecan::node_config(&network, *id).entries.len();
        if entries > MAX_ENTRIES {
            return Err(parser.error(
                raw.network_name.span(),
                format!(
                    "node {id} would hold {entries} SDD entries ({} produced, {} consumed, the rest other potential masters' syncs), but a safety data dictionary holds at most {MAX_ENTRIES} (SC_REQ_12)",
                    node.produced.len(),
                    node.consumed.len()
                ),
            ));
        }
    }
    Ok(Some(network))
}

/// A sentence for what `Schedule::new` refused.
fn schedule_sentence(error: ScheduleError) -> String {
    match error {
        ScheduleError::ResidualErrorRate { packets_per_second } => format!(
            "the network sends {packets_per_second} SimpleCAN packets per second (data and syncs), above the {} that keep SimpleCAN's residual error rate within 1 % of SIL 3's (SC_REQ_04, docs/simplecan.md section 8): fewer producers or a longer cycle",
            shared::simplecan::residual::MAX_PACKETS_PER_SECOND
        ),
        ScheduleError::SlotCount { slots } => {
            format!("a cycle of {slots} slots is refused: 3 to 1000 (SC_REQ_18, SC_REQ_21)")
        }
        ScheduleError::SlotNotForProducers { sc_id, slot } => format!(
            "SC-ID {:02X}h in slot {slot}: the last two slots stay empty (SC_REQ_21)",
            sc_id.raw()
        ),
        ScheduleError::SlotTaken {
            slot,
            first,
            second,
        } => format!(
            "slot {slot} is SC-ID {:02X}h's and SC-ID {:02X}h's: one producer per slot (SC_REQ_18)",
            first.raw(),
            second.raw()
        ),
        ScheduleError::ScIdTwice { sc_id } => format!(
            "SC-ID {:02X}h has two slots: each SC-ID has one producer (SC_REQ_15)",
            sc_id.raw()
        ),
        ScheduleError::SyncInterval { interval_ms } => {
            format!("the sync interval of {interval_ms} ms is outside 100 to 500 ms (SC_REQ_22)")
        }
        ScheduleError::TooManyProducers { sc_id, capacity } => format!(
            "SC-ID {:02X}h is one producer more than the {capacity} a schedule holds (SC_REQ_12)",
            sc_id.raw()
        ),
    }
}
