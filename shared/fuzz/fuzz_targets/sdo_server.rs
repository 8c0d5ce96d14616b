//! Any sequence of SDO requests (any length, any content, any timing) into a node's SDO
//! server: no panic, every response is a well-formed 8-byte SDO frame.
#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;
use shared::canopen::storage::RamFlash;
use shared::node::Node;
use shared::{CanFrame, CanId, Duration, Instant};

fuzz_target!(|data: &[u8]| {
    let Ok(mut node) = Node::<RamFlash<8192>, 2>::new(common::config(5, false), RamFlash::new())
    else {
        return;
    };
    let mut sink = common::Checker::default();
    let mut now = Instant::ZERO;
    node.poll(now, &mut sink);
    let sdo = CanId::new(0x605).unwrap_or_else(|_| unreachable!());
    // Each request: one byte of time step (ms) and length, then up to 8 bytes.
    let mut rest = data;
    while let Some((&header, tail)) = rest.split_first() {
        let len = usize::from(header & 0x0F).min(8).min(tail.len());
        let (request, tail) = tail.split_at(len);
        rest = tail;
        now = now + Duration::from_millis(u64::from(header >> 4) * 10);
        if let Ok(frame) = CanFrame::new(sdo, request) {
            node.handle_frame(now, &frame, &mut sink);
        }
        node.poll(now, &mut sink);
    }
});
