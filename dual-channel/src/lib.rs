//! What both channels of one safety node share (EN 50325-5 Annex A.4, Model III; CiA 304 9.5):
//!
//! - [`link`]: the inter-MCU link, its message set, framing and checks;
//! - [`clock`]: the check of the other channel's time base against this channel's own;
//! - [`crosscheck`]: the comparison of the two channels' verdicts on received SRDOs (and,
//!   generically, on any protocol's streams);
//! - [`can_loopback`]: the start-up test of the CAN controller's message buffers and filters;
//! - [`supervision`]: the runtime's checks of the other channel (inputs, NMT state and epoch,
//!   configuration), each a small value with `poll` and `deadline`;
//! - [`filters`]: the CAN acceptance filters a channel needs, from its configuration, and
//!   their bxCAN bank layout;
//! - [`channel_loop`]: the loop every board runs around the runtime, over a small driver
//!   interface (CAN, link, pins, time);
//! - [`transmit_queue`]: the order in which a channel's frames go to the CAN controller's
//!   transmit mailboxes (by identifier, as arbitration), and which of them went out;
//! - [`runtime`]: one channel around its copy of the protocol core: bus, link, cross-checks
//!   and output, with the channel-specific parts ([`runtime::Role`]) supplied by channel A and
//!   channel B;
//! - `simplecan` (feature `simplecan`, host-side): SimpleCAN on the two channels, forwarding,
//!   the verdict cross-check and Model A transmission (SC_REQ_10, SC_REQ_24).
//!
//! Everything here is sans-I/O and runs in host tests exactly as on the MCU.

#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]

pub mod byte_ring;
pub mod can_loopback;
pub mod channel_loop;
pub mod clock;
pub mod crosscheck;
pub mod filters;
pub mod link;
pub mod lss;
pub mod runtime;
pub mod selftest;
#[cfg(feature = "simplecan")]
pub mod simplecan;
pub mod supervision;
pub mod transmit_queue;
