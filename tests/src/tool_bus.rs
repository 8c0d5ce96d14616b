//! The configuration tool's transport on a simulated network: participant 0 of the bus of a
//! [`Network`] or a [`DualNetwork`], where receiving advances simulated time (in steps of
//! 100 µs, shorter than any frame) until a frame arrives or the deadline passes.
//! Deterministic, like the rest of the simulation.
//!
//! The networks' own SDO, signing and configuration methods ([`Network::write`],
//! [`DualNetwork::configure_and_start`], ...) are thin wrappers that run the tool library
//! (`safety_config`) over this transport: the procedure exists once, in the tool.

use crate::dual::DualNetwork;
use crate::network::Network;
use safety_config::ToolError;
use safety_config::client::Client;
use safety_config::transport::{Transport, TransportError};
use shared::canopen::sdo_client::ClientError;
use shared::{CanFrame, Instant};
use std::time::Duration;

/// How far simulated time moves while the tool waits, at most, before it looks again.
const STEP: Duration = Duration::from_micros(100);

/// How long the networks' wrappers wait for an SDO answer.
pub const SDO_TIMEOUT: Duration = Duration::from_millis(1000);

/// A simulated network seen from its tool participant (participant 0).
pub trait Simulation {
    /// Simulated time.
    fn now(&self) -> Instant;
    /// Queues `frame` on the bus from the tool.
    fn tool_send(&mut self, frame: CanFrame);
    /// The frame at position `index` of the bus trace (every frame on the bus, in order,
    /// the tool's own included), if it has been delivered.
    fn traced(&self, index: usize) -> Option<CanFrame>;
    /// How many frames the trace holds.
    fn traced_count(&self) -> usize;
    /// Runs the network until `end`.
    fn run_until(&mut self, end: Instant);
}

impl Simulation for Network {
    fn now(&self) -> Instant {
        self.now
    }
    fn tool_send(&mut self, frame: CanFrame) {
        self.bus.send(0, frame);
    }
    fn traced(&self, index: usize) -> Option<CanFrame> {
        self.trace.get(index).map(|(_, frame)| *frame)
    }
    fn traced_count(&self) -> usize {
        self.trace.len()
    }
    fn run_until(&mut self, end: Instant) {
        Network::run_until(self, end);
    }
}

impl Simulation for DualNetwork {
    fn now(&self) -> Instant {
        self.now
    }
    fn tool_send(&mut self, frame: CanFrame) {
        self.bus.send(0, frame);
    }
    fn traced(&self, index: usize) -> Option<CanFrame> {
        self.trace.get(index).map(|(_, frame, _)| *frame)
    }
    fn traced_count(&self) -> usize {
        self.trace.len()
    }
    fn run_until(&mut self, end: Instant) {
        DualNetwork::run_until(self, end);
    }
}

impl<S: Simulation + ?Sized> Simulation for &mut S {
    fn now(&self) -> Instant {
        (**self).now()
    }
    fn tool_send(&mut self, frame: CanFrame) {
        (**self).tool_send(frame);
    }
    fn traced(&self, index: usize) -> Option<CanFrame> {
        (**self).traced(index)
    }
    fn traced_count(&self) -> usize {
        (**self).traced_count()
    }
    fn run_until(&mut self, end: Instant) {
        (**self).run_until(end);
    }
}

/// The tool's side of a simulated network (owned, or borrowed as `&mut`).
pub struct SimulatedBus<S: Simulation = Network> {
    /// The network (devices, bus, trace).
    pub net: S,
    /// The next entry of the trace the tool has not seen.
    cursor: usize,
    /// Frames the tool sent that have not yet come by in the trace (the trace holds every
    /// frame on the bus, the tool's own too; a real interface does not receive its own).
    echoes: Vec<CanFrame>,
}

impl<S: Simulation> SimulatedBus<S> {
    /// The tool on `net`, seeing frames from now on.
    pub fn new(net: S) -> Self {
        let cursor = net.traced_count();
        SimulatedBus {
            net,
            cursor,
            echoes: Vec::new(),
        }
    }

    fn to_instant(time: Duration) -> Instant {
        Instant::from_micros(u64::try_from(time.as_micros()).unwrap_or(u64::MAX))
    }
}

impl<S: Simulation> Transport for SimulatedBus<S> {
    fn now(&mut self) -> Duration {
        Duration::from_micros(self.net.now().as_micros())
    }

    fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        self.net.tool_send(*frame);
        self.echoes.push(*frame);
        Ok(())
    }

    fn receive(&mut self, deadline: Duration) -> Result<Option<CanFrame>, TransportError> {
        loop {
            while let Some(frame) = self.net.traced(self.cursor) {
                self.cursor += 1;
                if let Some(position) = self.echoes.iter().position(|echo| *echo == frame) {
                    self.echoes.remove(position);
                    continue;
                }
                return Ok(Some(frame));
            }
            let now = self.now();
            if now >= deadline {
                return Ok(None);
            }
            self.net
                .run_until(Self::to_instant((now + STEP).min(deadline)));
        }
    }
}

/// The tool library's client on `net` (borrowed), with [`SDO_TIMEOUT`].
pub fn client<S: Simulation + ?Sized>(net: &mut S) -> Client<SimulatedBus<&mut S>> {
    Client::new(SimulatedBus::new(net), SDO_TIMEOUT)
}

/// The SDO client error a tool error of one SDO transfer stands for (the networks' `read`
/// and `write` keep reporting shared's [`ClientError`], which their callers match on).
///
/// The simulated transport never fails and one transfer fails only with an SDO error, so
/// every error reaching here has its [`ClientError`]; any other would be a fault of the tool
/// library, reported as a protocol error rather than hidden.
pub fn sdo_error(error: ToolError) -> ClientError {
    error.sdo_client_error().unwrap_or(ClientError::Protocol)
}
