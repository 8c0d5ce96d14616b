//! The SocketCAN adapter at run time (feature `socketcan`): needs a CAN interface named by
//! `SAFETY_CONFIG_VCAN` (e.g. `vcan0`, see `tool/src/socketcan.rs`); without it the test
//! says so and passes, because this kernel has no vcan.
#![cfg(feature = "socketcan")]

use safety_config::Transport;
use safety_config::socketcan::SocketCan;
use shared::{CanFrame, CanId};
use std::time::Duration;

#[test]
fn socketcan_frames_cross_between_two_sockets() {
    let Ok(interface) = std::env::var("SAFETY_CONFIG_VCAN") else {
        eprintln!("SAFETY_CONFIG_VCAN is not set: SocketCAN not exercised");
        return;
    };
    let mut a = SocketCan::open(&interface).unwrap();
    let mut b = SocketCan::open(&interface).unwrap();
    let frame = CanFrame::new(CanId::new(0x5A1).unwrap(), &[0x60, 0x01, 0x13, 0x01]).unwrap();
    a.send(&frame).unwrap();
    let deadline = b.now() + Duration::from_secs(2);
    assert_eq!(b.receive(deadline).unwrap(), Some(frame));
}
