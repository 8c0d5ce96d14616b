//! The emulated CAN bus: the bus model, the `can-hub` program that joins tools on it over
//! socketcand, its control port and its traces.
//!
//! - [`bus`]: the bus model shared by the host simulation (`tests/`), the emulated network
//!   (`emulator`) and the hub: arbitration by identifier, each frame on the bus for its bit
//!   time with stuff bits, every participant but the sender receives it, and the fault
//!   vocabulary.
//! - [`trace`]: candump log and pcap (SocketCAN link type) writers.
//! - [`hub`]: socketcand clients (the tool library's server session,
//!   `safety_config::socketcand::server`) joined to one [`bus::Bus`] in real time (the
//!   `can-hub` program).
//! - [`port`]: the TCP side of a port that serves clients, bounded whatever they do: the
//!   hub's tool and control ports, and the emulated network's (`emulator`).
//! - [`pace`]: a virtual time that follows the host clock but never runs more than a
//!   lookahead past what the participants it paces have acknowledged: the emulated network's
//!   socketcand port runs the network with it (`emulator::socketcand`), never ahead of the
//!   wall clock that third-party tools time out on.
//! - [`load`]: bus load the hub generates itself, in the virtual time (the control port's
//!   `load` command).
//! - [`control`]: the control port's line protocol (faults, load; and for the emulated
//!   network, input pins, link cuts, power and status reports).
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
