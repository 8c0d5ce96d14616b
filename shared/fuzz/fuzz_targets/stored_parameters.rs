//! Any bytes in the parameter storage at power-on: no panic, and a node that starts from
//! them is in Pre-operational and in the safe state.
#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;
use shared::canopen::nmt::NmtState;
use shared::canopen::storage::{Flash, RamFlash, Slot};
use shared::node::Node;
use shared::Instant;

fuzz_target!(|data: &[u8]| {
    let mut flash = RamFlash::<8192>::new();
    let (a, b) = data.split_at(data.len() / 2);
    let _ = flash.erase(Slot::A);
    let _ = flash.erase(Slot::B);
    let _ = flash.write(Slot::A, 0, &a[..a.len().min(8192)]);
    let _ = flash.write(Slot::B, 0, &b[..b.len().min(8192)]);
    let Ok(mut node) = Node::<_, 2>::new(common::config(33, false), flash) else {
        return;
    };
    let mut sink = common::Checker::default();
    node.poll(Instant::ZERO, &mut sink);
    assert_eq!(node.nmt_state(), NmtState::PreOperational);
    assert!(!node.is_working());
});
