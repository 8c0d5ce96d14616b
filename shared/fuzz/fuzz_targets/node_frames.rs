//! Any sequence of frames and time steps into a configured node: no panic, never a
//! deadline in the past, and outputs are 0 whenever the node is not in its working state.
#![no_main]

#[path = "common.rs"]
mod common;

use arbitrary::Arbitrary;
use libfuzzer_sys::fuzz_target;
use shared::canopen::nmt::{NmtCommand, command_frame};
use shared::canopen::od::Address;
use shared::canopen::storage::RamFlash;
use shared::node::Node;
use shared::{CanFrame, CanId, Duration, Instant};

#[derive(Arbitrary, Debug)]
struct Step {
    advance_us: u16,
    id: u16,
    remote: bool,
    dlc: u8,
    data: [u8; 8],
}

#[derive(Arbitrary, Debug)]
struct Input {
    node_id: u8,
    event_driven: bool,
    steps: Vec<Step>,
}

/// Validates the pre-defined configuration the way a tool does, over SDO.
fn validate(node: &mut Node<RamFlash<8192>, 2>, node_id: u8, sink: &mut common::Checker) {
    let record = node.safety_config().srdos[0];
    let signature = shared::safety::signature::compute(&record).to_le_bytes();
    let sdo = CanId::new(0x600 + u16::from(node_id)).unwrap_or_else(|_| unreachable!());
    let requests = [
        [0x2B, 0xFF, 0x13, 0x01, signature[0], signature[1], 0, 0],
        [0x2F, 0xFE, 0x13, 0x00, 0xA5, 0, 0, 0],
    ];
    for request in requests {
        let frame = CanFrame::new(sdo, &request).unwrap_or_else(|_| unreachable!());
        node.handle_frame(Instant::ZERO, &frame, sink);
    }
    // Inputs that are exact inverses, so a producer has valid data to send.
    let _ = node.write_object(Address::new(0x6001, 1), &[0xFF]);
    node.handle_frame(Instant::ZERO, &command_frame(NmtCommand::Start, 0), sink);
}

fuzz_target!(|input: Input| {
    let node_id = input.node_id.clamp(1, 127);
    let Ok(mut node) = Node::<RamFlash<8192>, 2>::new(
        common::config(node_id, input.event_driven),
        RamFlash::new(),
    ) else {
        return;
    };
    let mut sink = common::Checker::default();
    let mut now = Instant::ZERO;
    node.poll(now, &mut sink);
    validate(&mut node, node_id, &mut sink);
    for step in input.steps {
        now = now + Duration::from_micros(u64::from(step.advance_us));
        let Ok(id) = CanId::new(step.id & 0x7FF) else {
            continue;
        };
        let frame = if step.remote {
            CanFrame::remote(id, step.dlc % 9)
        } else {
            CanFrame::from_parts(id, step.dlc % 9, step.data)
        };
        if let Ok(frame) = frame {
            node.handle_frame(now, &frame, &mut sink);
        }
        let deadline = node.poll(now, &mut sink);
        assert!(deadline > now, "a poll must leave nothing due at `now`");
        if !node.is_working() {
            let mut buf = [0u8; 8];
            for sub in [Address::new(0x6200, 1), Address::new(0x6201, 1)] {
                let _ = node.read_object(sub, &mut buf);
                assert_eq!(
                    buf[0], 0,
                    "SC_REQ_05: outputs are 0 outside the working state"
                );
            }
        }
    }
});
