//! System tests and the host demo: CANopen Safety nodes running the real protocol core on a
//! simulated CAN bus under simulated time.
//!
//! - [`bus`]: arbitration, bit timing with stuff bits, fault injection.
//! - [`network`]: devices, a configuration tool speaking SDO and NMT over the bus, the log and
//!   a candump trace.
//! - [`dual`]: dual-channel nodes (channel A and B runtimes, their link) on the same bus.
//! - [`loop_net`]: dual-channel nodes running the boards' channel loop over a simulated
//!   bxCAN (filters, receive FIFOs), link and pins.
//! - [`fullnet`]: the full network at scale (127 dual-channel nodes) and reaction times.
//! - [`scenario`]: the demo scenario with its checked expectations (`cargo xtask run`).
//! - [`scenario_runner`]: scenario files (`scenarios/`: a network, a timeline of stimuli and
//!   faults, expected outcomes with bounds) played on the dual-channel simulation
//!   (`cargo xtask scenario`).
//! - [`campaign`]: seeded fault campaigns judged by an oracle that does not reuse the
//!   implementation (`cargo xtask campaign`).
//! - [`simplecan_dual`]: a SimpleCAN network of dual-channel nodes (forwarding, verdict
//!   cross-check, Model A transmission).
//! - [`simplecan_net`]: a SimpleCAN network: devices with the SRDO table and SimpleCAN,
//!   configured by SDO, with transmit confirmations and aborts.
//! - [`tool_bus`]: the configuration tool's transport on the simulated bus.

pub use can_hub::bus;
pub mod campaign;
pub mod dual;
pub mod fullnet;
pub mod loop_net;
pub mod network;
pub mod scenario;
pub mod scenario_runner;
pub mod simplecan_dual;
pub mod simplecan_net;
pub mod tool_bus;
