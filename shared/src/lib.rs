//! Sans-I/O protocol core of a dual-channel CANopen Safety node (EN 50325-5, CiA 304).
//!
//! The crate never reads a clock and never touches hardware. A [`Node`] is fed received
//! frames together with the time they arrived, and is polled with the current time; it hands
//! every frame it wants to send and every event (state changes, SRDOs received, safety faults
//! with their cause) to a [`Sink`] the caller provides, and it reports the next instant at
//! which it needs to be polled. The same code runs on the host (tests, simulation) and on the
//! microcontrollers.
//!
//! Layout:
//! - [`canopen`]: the CANopen services a safety device needs around the safety layer
//!   (NMT slave, SDO server, EMCY, heartbeat, object addressing, persistence). Nothing in it
//!   knows about SRDOs, so a second safety protocol can reuse it.
//! - [`safety`]: the CANopen Safety layer proper: checked protocol numbers, SRDO configuration
//!   and its one validation, the configuration signature, SRDO producer and consumer, GFC.
//! - [`node`]: one device, wiring both together with an application process image.
//!
//! # What cannot panic
//! No public function of this crate panics on any input: frames, SDO requests, stored images
//! and times are all parsed into checked types first, and every failure is a value. Arithmetic
//! on time saturates (see [`time`]).
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]

pub mod canopen;
pub mod frame;
pub mod node;
pub mod process_image;
pub mod safety;
pub mod simplecan;
pub mod time;

pub use frame::{CanFrame, CanId};
pub use node::{Event, Node, NodeConfig, Sink};
pub use time::{Duration, Instant};
