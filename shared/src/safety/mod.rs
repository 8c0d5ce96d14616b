//! The CANopen Safety layer (EN 50325-5, CiA 304): SRDO, GFC and the safety objects.
//!
//! - [`types`]: a checked type for every protocol number (SRDO number, direction, COB-ID pair,
//!   refresh time / SCT, SRVT, mapping entry).
//! - [`config`]: the SRDO configuration as stored in 0x1301..0x1340 and 0x1381..0x13C0, and the
//!   one validation that judges a single SDO write and the whole configuration on the way into
//!   Operational alike.
//! - [`signature`]: the safety configuration signature of 0x13FF (EN 50325-5 6.4.1.5).
//! - [`srdo`]: the SRDO producer and consumer state machines (EN 50325-5 7.1).
//! - [`gfc`]: the global fail-safe command (EN 50325-5 7.2).

pub mod cause;
pub mod config;
pub mod gfc;
pub mod signature;
pub mod srdo;
pub mod types;

pub use config::{ConfigError, SafetyConfig, SrdoRecord};
pub use types::{CobIdPair, Direction, SrdoNumber};

/// The largest number of SRDOs a device can have (EN 50325-5 6.2.1, 9.4.1).
pub const MAX_SRDOS: usize = 64;
