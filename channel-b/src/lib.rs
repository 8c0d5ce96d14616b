//! Channel B of the dual-channel CANopen Safety node: the logic that is not hardware glue.
//!
//! The channel runs the protocol core inside [`dual_channel::runtime::Runtime`] with its own
//! [`role`]. Everything here is tested on the host; the firmware image (`main.rs`) only wires a
//! board layer to it.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]

/// Which MCU of the pair this image runs on.
pub const CHANNEL: char = 'B';

pub mod diverse;
pub mod role;
pub mod signature;
pub mod simplecan;
