//! The device this node is: its application objects and its description for the protocol
//! core. Both channels, the firmware images and the host simulations use this one table.

use shared::Duration;
use shared::canopen::NodeId;
use shared::canopen::od::Address;
use shared::node::NodeConfig;
use shared::process_image::{Access, AppObject, Mappable};

const fn object(index: u16, mappable: Mappable) -> AppObject {
    AppObject {
        address: Address::new(index, 1),
        len: 1,
        access: Access::ReadOnly,
        mappable,
    }
}

/// A safety input with its inverted copy (e.g. one contact of an emergency stop, 1 = closed,
/// released) and a safety output with its inverted copy (1 = the machine may run). 0 is the
/// safe state of both (SC_REQ_05).
pub static OBJECTS: [AppObject; 4] = [
    object(0x6000, Mappable::Transmit),
    object(0x6001, Mappable::Transmit),
    object(0x6200, Mappable::Receive),
    object(0x6201, Mappable::Receive),
];

/// Safety input (plain).
pub const INPUT: Address = Address::new(0x6000, 1);
/// Safety input (inverted copy).
pub const INPUT_INVERTED: Address = Address::new(0x6001, 1);
/// Safety output (plain).
pub const OUTPUT: Address = Address::new(0x6200, 1);
/// Safety output (inverted copy).
pub const OUTPUT_INVERTED: Address = Address::new(0x6201, 1);

/// The names a person uses for the application objects (in a network file, in a tool's
/// output), one per entry of [`OBJECTS`].
pub static OBJECT_NAMES: [(&str, Address); 4] = [
    ("input", INPUT),
    ("input_inverted", INPUT_INVERTED),
    ("output", OUTPUT),
    ("output_inverted", OUTPUT_INVERTED),
];

/// The device description for node-ID `id` (1..=127).
pub fn config(id: NodeId, name: &'static str) -> NodeConfig {
    NodeConfig {
        node_id: id,
        device_type: 0x0001_0191,
        device_name: name,
        identity: [0x0000_0ABC, 0x0000_0304, 1, u32::from(id.raw())],
        app_objects: &OBJECTS,
        default_transmit_mapping: &[0x6000_0108, 0x6001_0108],
        default_receive_mapping: &[0x6200_0108, 0x6201_0108],
        heartbeat_ms: 100,
        sdo_timeout: Duration::from_millis(500),
        event_driven: true,
        gfc_on_fault: false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every application object has exactly one name, and every name an object.
    #[test]
    fn every_object_has_one_name() {
        for object in &OBJECTS {
            let named = OBJECT_NAMES
                .iter()
                .filter(|(_, address)| *address == object.address)
                .count();
            assert_eq!(named, 1, "{:?}", object.address);
        }
        assert_eq!(OBJECT_NAMES.len(), OBJECTS.len());
    }
}
