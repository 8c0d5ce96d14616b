//! Calculators for planning a network of these nodes, sans-I/O: the worst-case reaction time
//! of each safety function ([`sfrt`], EN 50325-5 9.3), the bus load and the residual error
//! rate per SIL ([`budget`], [`residual`], EN 50325-5 9.4), on frame times and arbitration
//! ([`bus`]), with the processing step measured on the target ([`target`]). `safety-config sfrt` and `safety-config budget` print them; the safety manual's
//! tables are made by the same functions.

pub mod budget;
pub mod bus;
pub mod report;
pub mod residual;
pub mod sfrt;
pub mod simplecan;
pub mod target;
mod target_measured;
mod target_measured_simplecan;
