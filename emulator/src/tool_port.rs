//! The configuration tool's library on the emulated network, in-process: a
//! [`Transport`] whose clock is the network's virtual time, so that the tool's procedures
//! (configure, validate, store, NMT) drive the shipped images deterministically, with no
//! socket and no host clock between them.

use std::time::Duration;

use safety_config::transport::{Transport, TransportError};
use shared::CanFrame;

use crate::network::Network;
use crate::time::Nanos;

/// A participant on the emulated bus that the tool's library talks through. Waiting for a
/// frame runs the network.
pub struct ToolPort<'n> {
    network: &'n mut Network,
    participant: usize,
}

impl<'n> ToolPort<'n> {
    /// Joins `network`'s bus as an external participant named `name`.
    pub fn join(network: &'n mut Network, name: &str) -> Self {
        let participant = network.join_external(name);
        ToolPort {
            network,
            participant,
        }
    }

    /// The network, between the tool's steps (to drive inputs, read outputs, run on).
    pub fn network(&mut self) -> &mut Network {
        self.network
    }
}

impl Drop for ToolPort<'_> {
    /// The tool leaves the bus: nothing more is kept for it.
    fn drop(&mut self) {
        self.network.leave_external(self.participant);
    }
}

fn nanos(at: Duration) -> Nanos {
    u64::try_from(at.as_nanos()).unwrap_or(Nanos::MAX)
}

impl Transport for ToolPort<'_> {
    fn now(&mut self) -> Duration {
        Duration::from_nanos(self.network.now())
    }

    fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        self.network.send(self.participant, *frame);
        Ok(())
    }

    fn receive(&mut self, deadline: Duration) -> Result<Option<CanFrame>, TransportError> {
        Ok(self.receive_stamped(deadline)?.map(|(_, frame)| frame))
    }

    fn receive_stamped(
        &mut self,
        deadline: Duration,
    ) -> Result<Option<(Duration, CanFrame)>, TransportError> {
        if self.network.any_stopped() {
            // A power cut or a fault ended an MCU: the case decides what follows, the tool
            // does not wait out its time-outs for it.
            return Err(TransportError::Protocol(
                "an emulated MCU stopped (a power cut or a fault)".into(),
            ));
        }
        let end = nanos(deadline);
        if let Some(delivery) = self.network.receive(self.participant) {
            return Ok(Some((stamp(delivery.at), delivery.frame)));
        }
        if self.network.now() < end {
            self.network.run_until_frame_for(self.participant, end);
        }
        Ok(self
            .network
            .receive(self.participant)
            .map(|delivery| (stamp(delivery.at), delivery.frame)))
    }
}

fn stamp(at: shared::Instant) -> Duration {
    Duration::from_micros(at.as_micros())
}
