//! The CANopen services (EN 50325-4 / CiA 301) a safety device needs around its safety layer.
//!
//! Nothing in this module knows about SRDOs or GFC: it addresses objects, answers SDO
//! requests, follows NMT commands, produces heartbeat and EMCY frames, persists parameters,
//! and sets its node-ID and bit rate by LSS (CiA 305).
//! That keeps it usable by a second safety protocol on the same node.

pub mod emcy;
pub mod heartbeat;
pub mod lss;
pub mod nmt;
pub mod node_id;
pub mod od;
pub mod sdo;
pub mod sdo_client;
pub mod storage;

pub use node_id::NodeId;
pub use od::{AbortCode, Address, ObjectDictionary};
