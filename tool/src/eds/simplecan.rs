//! The SimpleCAN configuration objects 5E00h..5EFFh in the EDS (`docs/simplecan.md` section
//! 11), for a device that serves SimpleCAN beside its SRDOs (`shared::node::SimpleCanNode`):
//! types, access and defaults as `shared::node::simplecan` serves them. Sub-index 0 of 5E00h
//! and of each entry is read-only (0601 0002h on a write); every other entry is writable in
//! Pre-operational only.

use super::{Entry, Object, UNSIGNED8, UNSIGNED16, UNSIGNED32, compound, single};
use shared::canopen::od::Address;
use shared::node::simplecan::{
    COUNT_INDEX, CYCLE_INDEX, FIRST_ENTRY_INDEX, SIGNATURE_INDEX, SimpleCanObjects, VALID_INDEX,
};

/// The defaults (`SimpleCanObjects::DEFAULT`): one place, the device's.
const DEFAULT: SimpleCanObjects<1> = SimpleCanObjects::DEFAULT;

/// The objects 5E00h, 5E01h, 5E10h..5E10h + `entries` − 1, 5EFEh and 5EFFh of a device that
/// holds `entries` SDD entries, in index order.
pub fn objects(entries: u8) -> Vec<Object> {
    let mut objects = Vec::new();
    let mut cycle = compound(
        CYCLE_INDEX,
        "SimpleCAN cycle and SCL settings",
        0x9,
        5,
        "ro",
    );
    let at = |sub| Address::new(CYCLE_INDEX, sub);
    cycle.entries.extend([
        Entry::new(at(1), "Slots per cycle", UNSIGNED16, "rw")
            .default(DEFAULT.slots)
            .limits(3, 1000),
        Entry::new(at(2), "Cycles between syncs", UNSIGNED16, "rw").default(DEFAULT.sync_every),
        Entry::new(at(3), "Maximum buffering time (us)", UNSIGNED16, "rw")
            .default(DEFAULT.buffering_us),
        Entry::new(at(4), "SimpleCAN enabled", UNSIGNED8, "rw")
            .default(DEFAULT.enabled)
            .limits(0, 1),
        Entry::new(at(5), "Potential master", UNSIGNED8, "rw")
            .default(DEFAULT.potential_master)
            .limits(0, 1),
    ]);
    objects.push(cycle);
    let mut count = single(COUNT_INDEX, "SDD entries in use", UNSIGNED8, "rw");
    count.entries[0] = count.entries[0]
        .clone()
        .default(DEFAULT.count)
        .limits(0, u32::from(entries));
    objects.push(count);
    let empty = DEFAULT.entries[0];
    for n in 1..=entries {
        let index = FIRST_ENTRY_INDEX + u16::from(n) - 1;
        let at = |sub| Address::new(index, sub);
        let mut entry = compound(index, &format!("SDD entry {n}"), 0x9, 6, "ro");
        entry.entries.extend([
            Entry::new(at(1), "SC-ID", UNSIGNED8, "rw").default(empty.sc_id),
            Entry::new(at(2), "Role", UNSIGNED8, "rw").default(empty.role),
            Entry::new(at(3), "Slot", UNSIGNED16, "rw").default(empty.slot),
            Entry::new(at(4), "Safety timeout (ms)", UNSIGNED16, "rw").default(empty.timeout_ms),
            Entry::new(at(5), "Node hash", UNSIGNED32, "rw")
                .default(format!("0x{:08X}", empty.hash)),
            Entry::new(at(6), "Mapped object", UNSIGNED32, "rw")
                .default(format!("0x{:08X}", empty.mapped)),
        ]);
        objects.push(entry);
    }
    let mut valid = single(
        VALID_INDEX,
        "SimpleCAN configuration valid",
        UNSIGNED8,
        "rw",
    );
    valid.entries[0] = valid.entries[0].clone().default(DEFAULT.valid);
    objects.push(valid);
    let mut signature = single(
        SIGNATURE_INDEX,
        "SimpleCAN configuration signature",
        UNSIGNED32,
        "rw",
    );
    signature.entries[0] = signature.entries[0]
        .clone()
        .default(format!("0x{:08X}", DEFAULT.signature));
    objects.push(signature);
    objects
}
