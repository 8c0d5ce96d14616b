//! The full network at scale and measured reaction times, by simulation: dual-channel nodes
//! (both channel runtimes, their link, the protocol core) on the simulated bus.
//!
//! - [`plan`]: which node produces and consumes which SRDO, the background traffic, and the
//!   timing derived from worst-case frame times.
//! - [`configure`]: storage images of configured nodes, by the configuration tool's own
//!   procedure against each core alone.
//! - [`engine`]: the event-driven simulation, checked against `DualNetwork` frame for frame.
//! - [`handoff`]: the second thread, which runs one group of channels for every run of the
//!   engine on two threads.
//! - [`network`]: the full network run and its monitor (bus load, SCT and SRVT margins,
//!   reaction times).
//! - [`reaction`]: reaction times of the demo's pair by event-driven SRDO, GFC and SCT expiry.
//! - [`report`]: the results as Markdown.

pub mod configure;
pub mod engine;
pub mod handoff;
pub mod network;
pub mod plan;
pub mod reaction;
pub mod report;
