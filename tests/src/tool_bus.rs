//! The configuration tool's transport on the simulated network: participant 0 of
//! [`Network`]'s bus, where receiving advances simulated time (in steps of 100 µs, shorter
//! than any frame) until a frame arrives or the deadline passes. Deterministic, like the rest
//! of the simulation.

use crate::network::Network;
use safety_config::transport::{Transport, TransportError};
use shared::{CanFrame, Instant};
use std::time::Duration;

/// How far simulated time moves while the tool waits, at most, before it looks again.
const STEP: Duration = Duration::from_micros(100);

/// The tool's side of a simulated network.
pub struct SimulatedBus {
    /// The network (devices, bus, trace).
    pub net: Network,
    /// The next entry of `net.trace` the tool has not seen.
    cursor: usize,
    /// Frames the tool sent that have not yet come by in the trace (the trace holds every
    /// frame on the bus, the tool's own too; a real interface does not receive its own).
    echoes: Vec<CanFrame>,
}

impl SimulatedBus {
    /// The tool on `net`, seeing frames from now on.
    pub fn new(net: Network) -> Self {
        let cursor = net.trace.len();
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

impl Transport for SimulatedBus {
    fn now(&mut self) -> Duration {
        Duration::from_micros(self.net.now.as_micros())
    }

    fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        self.net.bus.send(0, *frame);
        self.echoes.push(*frame);
        Ok(())
    }

    fn receive(&mut self, deadline: Duration) -> Result<Option<CanFrame>, TransportError> {
        loop {
            while let Some((_, frame)) = self.net.trace.get(self.cursor).copied() {
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
