//! The emulated CAN bus.
//!
//! - [`bus`]: the bus model shared by the host simulation (`tests/`) and the hub: arbitration
//!   by identifier, each frame on the bus for its bit time with stuff bits, every participant
//!   but the sender receives it, and the fault vocabulary.
//! - [`trace`]: candump log and pcap (SocketCAN link type) writers.
//! - [`hub`]: participants joined to one [`bus::Bus`] in real time (the `can-hub` program):
//!   emulated MCUs speaking CAN-over-serial ([`emulation_wire`]) and tools speaking
//!   socketcand (the tool library's server session, `safety_config::socketcand::server`).
//! - [`pace`]: the shared virtual time of the emulated MCUs: the hub's clock waits for the
//!   slowest of them, so host load slows the network down but does not change its verdicts.
//! - [`load`]: bus load the hub generates itself, in the virtual time (the control port's
//!   `load` command).
//! - [`control`]: the hub's control port (input pins, faults, link cuts, load, status
//!   reports).
//! - [`events`]: the event log (frames with their senders, output changes, on the virtual
//!   time) that the scenario runner's oracle reads.
//! - [`tool`]: a client of the control port.

pub mod bus;
pub mod control;
pub mod events;
pub mod hub;
pub mod load;
pub mod pace;
pub mod port;
pub mod tool;
pub mod trace;
