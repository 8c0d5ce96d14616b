//! Configured nodes without a bus: the configuration tool's own procedure
//! (`safety_config::procedure::configure_node`, EN 50325-5 8.3.1: write, read back, sign with
//! the tool's CRC, validate, store) run against one protocol core alone, in-process, so that
//! the storage image a configured node holds costs microseconds instead of a few hundred SDO
//! exchanges of bus time. The simulation starts both channels of the node on that image.
//!
//! The same procedure over the simulated bus, against both channels of a dual-channel node,
//! gives byte for byte the same image (test `stored_image_equals_the_one_configured_over_the_bus`).

use crate::network::{DeviceNode, device_config};
use safety_config::client::Client;
use safety_config::error::ToolError;
use safety_config::network_file::{Identity, NodeSpec, SrdoSpec};
use safety_config::procedure::{Quiet, configure_node};
use safety_config::signature::SrdoSettings;
use safety_config::transport::{Transport, TransportError};
use shared::canopen::storage::RamFlash;
use shared::node::{Event, Sink};
use shared::{CanFrame, Instant};
use std::collections::VecDeque;
use std::time::Duration;

/// The SDO timeout the tool uses (the device's own is 500 ms).
pub const SDO_TIMEOUT: Duration = Duration::from_millis(500);

/// How long one exchange with the core alone takes on the transport's clock (a figure for
/// the clock only: nothing waits).
const EXCHANGE: Duration = Duration::from_micros(100);

/// Frames the core hands out, for the tool to receive.
struct Inbox<'a>(&'a mut VecDeque<CanFrame>);

impl Sink for Inbox<'_> {
    fn transmit(&mut self, frame: CanFrame) {
        self.0.push_back(frame);
    }
    fn event(&mut self, _event: Event) {}
}

/// One protocol core as the tool's only partner: every frame the tool sends reaches it at
/// once, and what it answers is received.
pub struct Alone {
    /// The core.
    pub node: DeviceNode,
    now: Duration,
    inbox: VecDeque<CanFrame>,
}

impl Alone {
    /// The core of node `id` on its defaults, booted (Pre-operational).
    pub fn new(id: u8) -> Self {
        let mut node = DeviceNode::new(device_config(id, "configured alone"), RamFlash::new())
            .expect("valid device description");
        let mut inbox = VecDeque::new();
        let _ = node.poll(Instant::ZERO, &mut Inbox(&mut inbox));
        Alone {
            node,
            now: Duration::ZERO,
            inbox,
        }
    }

    fn instant(&self) -> Instant {
        Instant::from_micros(u64::try_from(self.now.as_micros()).unwrap_or(u64::MAX))
    }
}

impl Transport for Alone {
    fn now(&mut self) -> Duration {
        self.now
    }

    fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        self.now += EXCHANGE;
        let now = self.instant();
        let mut inbox = Inbox(&mut self.inbox);
        self.node.handle_frame(now, frame, &mut inbox);
        let _ = self.node.poll(now, &mut inbox);
        Ok(())
    }

    fn receive(&mut self, deadline: Duration) -> Result<Option<CanFrame>, TransportError> {
        if let Some(frame) = self.inbox.pop_front() {
            return Ok(Some(frame));
        }
        self.now = self.now.max(deadline);
        Ok(None)
    }
}

/// The identity the device reports for node `id` (0x1018, as `safety_device::config`
/// sets it).
pub fn identity(id: u8) -> Identity {
    let config = device_config(id, "");
    Identity {
        vendor: config.identity[0],
        product: config.identity[1],
        revision: Some(config.identity[2]),
        serial: config.identity[3],
    }
}

/// A node for the network file: node `id` with these SRDOs.
pub fn node_spec(id: u8, srdos: Vec<SrdoSpec>) -> NodeSpec {
    NodeSpec {
        id,
        name: None,
        identity: identity(id),
        srdos,
        clear_gfc_indication: false,
    }
}

/// SRDO `number` transmitting the device's input (0x6000, inverted copy 0x6001) on the
/// CiA 304 pair of `pair` (0xFF + 2·pair, 0x100 + 2·pair) every `refresh_ms`.
pub fn transmit(number: u8, pair: u8, refresh_ms: u16, srvt_ms: u8) -> SrdoSpec {
    SrdoSpec {
        number,
        settings: SrdoSettings {
            direction: 1,
            cycle_time: refresh_ms,
            srvt: srvt_ms,
            cob_id_1: 0xFF + 2 * u32::from(pair),
            cob_id_2: 0x100 + 2 * u32::from(pair),
            mapping: safety_device::config(
                shared::canopen::NodeId::new(1).expect("1 is a node-ID"),
                "",
            )
            .default_transmit_mapping
            .to_vec(),
        },
    }
}

/// SRDO `number` receiving the pair of `pair` into the device's output (0x6200, inverted
/// copy 0x6201) with SCT `sct_ms` and SRVT `srvt_ms`.
pub fn receive(number: u8, pair: u8, sct_ms: u16, srvt_ms: u8) -> SrdoSpec {
    SrdoSpec {
        number,
        settings: SrdoSettings {
            direction: 2,
            cycle_time: sct_ms,
            srvt: srvt_ms,
            cob_id_1: 0xFF + 2 * u32::from(pair),
            cob_id_2: 0x100 + 2 * u32::from(pair),
            mapping: safety_device::config(
                shared::canopen::NodeId::new(1).expect("1 is a node-ID"),
                "",
            )
            .default_receive_mapping
            .to_vec(),
        },
    }
}

/// The storage image node `spec.id` holds after the tool configured it as `spec` says and
/// stored it (0x1010), by the tool's procedure against the core alone; and the SDO requests
/// that took.
pub fn stored_image(spec: &NodeSpec) -> Result<(RamFlash<8192>, u64), ToolError> {
    let mut client = Client::new(Alone::new(spec.id), SDO_TIMEOUT);
    let configured = configure_node(
        &mut client,
        spec,
        &mut Quiet {
            accept_identity: false,
        },
    )?;
    Ok((
        client.transport.node.flash().clone(),
        configured.sdo_requests,
    ))
}
