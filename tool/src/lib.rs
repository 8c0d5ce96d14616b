//! A configuration tool for CANopen Safety nodes (EN 50325-5): configure and verify a network
//! of nodes from one file, over any CAN interface.
//!
//! - [`transport`]: the one CAN transport trait (send; receive with a deadline) and the
//!   adapters: [`socketcand`] (TCP), [`slcan`] (serial adapters), `socketcan` (Linux, behind
//!   the `socketcan` feature). The host simulation's adapter lives in the `system-tests`
//!   crate, which depends on this one.
//! - [`calc`]: the calculators: reaction times (EN 50325-5 9.3), bus load and residual error
//!   rate (9.4).
//! - [`access`]: the node's protection against unauthorised configuration (SC_REQ_43):
//!   the secret (never on the command line), unlock, set-secret, the audit record.
//! - [`client`]: SDO and NMT over a transport, with errors that name the node and the object.
//! - [`network_file`]: the network file (TOML) and its errors with line and column.
//! - [`signature`]: the tool's own Table 9 signature (CRC-16/XMODEM), independent of the node's.
//! - [`simplecan`]: SimpleCAN nodes: node hashes, the configuration objects and their CRC-32
//!   signature (the tool's own), the configure/verify plan.
//! - [`procedure`]: `configure` and `verify` (EN 50325-5 8.3.1), `scan`.
//! - [`eds`]: the node's EDS and DCFs (CiA 306), from the device description.
//! - [`dissector`]: a Wireshark Lua dissector of a network file's safety frames (SRDO pairs,
//!   GFC, SimpleCAN packets with their CRC).
//! - [`lss`]: the LSS master (CiA 305): fastscan of unconfigured nodes and their node-IDs from
//!   the network file, node-ID and bit rate of one node, store, inquire.
//! - [`monitor`]: the live bus monitor: SRDO pairs and their verdicts, NMT, EMCY, SDO; candump
//!   logs recorded and replayed.
//! - [`error`]: every error as a sentence.

pub mod access;
pub mod calc;
pub mod client;
pub mod dissector;
pub mod eds;
pub mod error;
pub mod lss;
pub mod monitor;
pub mod network_file;
pub mod procedure;
pub mod signature;
pub mod simplecan;
pub mod slcan;
#[cfg(feature = "socketcan")]
pub mod socketcan;
pub mod socketcand;
pub mod transport;

pub use error::ToolError;
pub use transport::Transport;
