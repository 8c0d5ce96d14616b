//! Channel B of the dual-channel CANopen Safety node: the logic that is not hardware glue.
//!
//! Skeleton: the diverse SRDO building, the inter-MCU link and the cross-checks arrive with
//! the firmware issue (see README). Everything that lands here is tested on the host.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]

/// Which MCU of the pair this image runs on.
pub const CHANNEL: char = 'B';

pub mod diverse;
pub mod signature;
