//! What the fuzz targets share: a device description and a sink that checks invariants.

use shared::canopen::od::Address;
use shared::node::{Event, NodeConfig, Sink};
use shared::process_image::{Access, AppObject, Mappable};
use shared::{CanFrame, Duration};

const fn object(index: u16, sub: u8, len: u8, mappable: Mappable) -> AppObject {
    AppObject {
        address: Address::new(index, sub),
        len,
        access: Access::ReadOnly,
        mappable,
    }
}

/// Inputs and outputs with inverted copies, plus a writable parameter.
pub static OBJECTS: [AppObject; 7] = [
    object(0x6000, 1, 1, Mappable::Transmit),
    object(0x6001, 1, 1, Mappable::Transmit),
    object(0x6200, 1, 1, Mappable::Receive),
    object(0x6201, 1, 1, Mappable::Receive),
    object(0x6100, 1, 4, Mappable::Transmit),
    object(0x6101, 1, 4, Mappable::Transmit),
    AppObject {
        address: Address::new(0x2000, 1),
        len: 2,
        access: Access::ReadWrite,
        mappable: Mappable::No,
    },
];

/// A device with node-ID `node_id`.
pub fn config(node_id: u8, event_driven: bool) -> NodeConfig {
    NodeConfig {
        node_id: shared::canopen::NodeId::new(node_id.clamp(1, 127))
            .unwrap_or_else(|_| unreachable!()),
        device_type: 0x0001_0191,
        device_name: "fuzzed safety node with a name longer than four bytes",
        identity: [1, 2, 3, 4],
        app_objects: &OBJECTS,
        default_transmit_mapping: &[0x6000_0108, 0x6001_0108],
        default_receive_mapping: &[0x6200_0108, 0x6201_0108],
        heartbeat_ms: 10,
        sdo_timeout: Duration::from_millis(100),
        event_driven,
        gfc_on_fault: event_driven,
    }
}

/// Counts what a node hands over and checks every frame is well-formed.
#[derive(Default)]
pub struct Checker {
    pub frames: usize,
    pub events: usize,
}

impl Sink for Checker {
    fn transmit(&mut self, frame: CanFrame) {
        assert!(frame.dlc() <= 8 && frame.id().raw() <= 0x7FF);
        self.frames += 1;
    }
    fn event(&mut self, _event: Event) {
        self.events += 1;
    }
}
