//! What both channels of one safety node share (EN 50325-5 Annex A.4, Model III; CiA 304 9.5):
//!
//! - [`link`]: the inter-MCU link, its message set, framing and checks;
//! - [`clock`]: the check of the other channel's time base against this channel's own;
//! - [`crosscheck`]: the comparison of the two channels' verdicts on received SRDOs;
//! - [`can_loopback`]: the start-up test of the CAN controller's message buffers and filters;
//! - [`can_serial`], [`diagnostics`]: the emulated board's CAN-over-serial line and the
//!   status a channel reports on it;
//! - [`runtime`]: one channel around its copy of the protocol core: bus, link, cross-checks
//!   and output, with the channel-specific parts ([`runtime::Role`]) supplied by channel A and
//!   channel B.
//!
//! Everything here is sans-I/O and runs in host tests exactly as on the MCU.

#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]

pub mod can_loopback;
pub mod can_serial;
pub mod clock;
pub mod cobs_frames;
pub mod crosscheck;
pub mod device;
pub mod diagnostics;
pub mod link;
pub mod runtime;
pub mod selftest;
