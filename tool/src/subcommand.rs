//! The program's subcommands, one function each: [`offline`] (from a network file, no bus),
//! [`node`] (one node or the bus: scan, NMT, read, write, DCF, GFC, LSS), [`configuration`]
//! (configure, verify, the secret, the audit record) and [`monitor`].
//!
//! `main` parses the command line and hands each subcommand its arguments; a function here
//! prints its result (sentences, or JSON with `--json`) and says whether the command
//! succeeded.

pub mod configuration;
pub mod monitor;
pub mod node;
pub mod offline;

/// The client every subcommand on the bus talks through: the SDO client over whichever
/// interface `--bus` named.
pub type BusClient = safety_config::client::Client<Box<dyn safety_config::Transport>>;
