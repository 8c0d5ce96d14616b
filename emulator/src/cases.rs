//! End-to-end cases on the shipped images, in one process and in virtual time: the
//! configuration tool's library configures both nodes over the emulated bus
//! ([`crate::tool_port`]), starts them, and the case reads every verdict from what a test
//! rig around real boards would see: the frames on the bus and the output pins.
//!
//! The nominal case ([`nominal`]): both nodes boot, are configured from a network file
//! (node 1 producing its contacts on SRDO 1, node 33 consuming them on its outputs),
//! validated, stored in flash and started; both then report Operational in their heartbeats
//! and node 33's two outputs come on. Then node 1's contacts open (the emergency stop): both
//! of node 33's outputs must go off within the producer's refresh time (EN 50325-5 7.1.2: the
//! SRDO goes out at once on the change, and the consumer acts on the validated pair; the
//! emulation adds no host jitter, so the bound is the standard's, with no margin).

use safety_config::client::Client;
use safety_config::network_file::Network as NetworkFile;
use safety_config::procedure::{self, NodeResult, Operator};
use shared::canopen::nmt::{NmtCommand, NmtState};

use crate::network::{Event, Network};
use crate::time::Nanos;
use crate::tool_port::ToolPort;

/// Prints the tool's progress.
struct Narrator;

impl Operator for Narrator {
    fn note(&mut self, line: &str) {
        println!("tool: {line}");
    }
    fn confirm_identity(
        &mut self,
        _node: &safety_config::network_file::NodeSpec,
        _differences: &str,
    ) -> bool {
        false
    }
}

/// What the nominal case measured.
#[derive(Clone, Debug, PartialEq)]
pub struct Nominal {
    /// Virtual time the configuration took (both nodes: read, write, validate, store).
    pub configured_in: Nanos,
    /// SDO requests the tool sent.
    pub sdo_requests: u64,
    /// From the contacts opening to the last of node 33's outputs going off.
    pub reaction: Nanos,
    /// The bound: the producer's refresh time.
    pub bound: Nanos,
}

const MS: Nanos = 1_000_000;

/// The node-ID of the MCU at `index` in a network built as `emulate-network` builds it (two
/// channels a node, in the order of the node-IDs).
fn mcu_indices(network: &Network, node: u8) -> Vec<usize> {
    network
        .names()
        .enumerate()
        .filter(|(_, name)| {
            name.strip_prefix("node")
                .and_then(|rest| rest.strip_suffix(['a', 'b']))
                .is_some_and(|id| id == node.to_string())
        })
        .map(|(index, _)| index)
        .collect()
}

/// Runs `network` until `until` holds for an event or `patience` of virtual time has passed;
/// every event seen is handed to `seen` (the caller's trace). Returns when it held.
fn run_until_event(
    network: &mut Network,
    patience: Nanos,
    seen: &mut dyn FnMut(&Event),
    mut until: impl FnMut(&Network, &Event) -> bool,
) -> Option<Nanos> {
    let end = network.now() + patience;
    while network.now() < end {
        let step = (network.now() + MS).min(end);
        network.run_until(step);
        for event in network.take_events() {
            seen(&event);
            if until(network, &event) {
                return Some(event_time(&event));
            }
        }
    }
    None
}

fn event_time(event: &Event) -> Nanos {
    match event {
        Event::Frame { at, .. } | Event::Output { at, .. } | Event::Refused { at, .. } => *at,
        Event::Stopped { at, .. } | Event::Reset { at, .. } => *at,
    }
}

/// The nominal case on a network of nodes 1 (producer) and 33 (consumer) built with every
/// contact closed, configured from `file`. `seen` receives every event (for the caller's log
/// and trace). Fails with a sentence naming the step.
pub fn nominal(
    network: &mut Network,
    file: &NetworkFile,
    seen: &mut dyn FnMut(&Event),
) -> Result<Nominal, String> {
    let producer = mcu_indices(network, 1);
    let consumer = mcu_indices(network, 33);
    if producer.len() != 2 || consumer.len() != 2 {
        return Err("the nominal case needs nodes 1 and 33, two channels each".into());
    }
    let refresh = file
        .nodes
        .iter()
        .find(|node| node.id == 1)
        .and_then(|node| node.srdos.first())
        .map(|srdo| Nanos::from(srdo.settings.cycle_time) * MS)
        .ok_or("the network file gives node 1 no SRDO")?;
    let mut booted = [false; 2];
    let stopped = |event: &Event| matches!(event, Event::Stopped { .. });
    run_until_event(network, 5_000 * MS, seen, |_, event| {
        if let Event::Frame { frame, .. } = event {
            match (frame.id().raw(), frame.data()) {
                (0x701, [0]) => booted[0] = true,
                (0x721, [0]) => booted[1] = true,
                _ => {}
            }
        }
        stopped(event) || booted == [true, true]
    });
    if booted != [true, true] {
        return Err(format!(
            "no boot-up message from both nodes within 5 s (node 1: {}, node 33: {})",
            booted[0], booted[1]
        ));
    }
    let started = network.now();
    let (requests, configured_in) = {
        let mut client = Client::new(ToolPort::join(network, "tool"), file.sdo_timeout);
        let report = procedure::configure(&mut client, file, false, &mut Narrator)
            .map_err(|error| format!("configuration: {error}"))?;
        for result in &report.nodes {
            if let NodeResult::Failed { error, .. } = result {
                return Err(format!("configuration: {error}"));
            }
        }
        client
            .nmt(NmtCommand::Start, 0)
            .map_err(|error| format!("NMT start: {error}"))?;
        let requests = client.requests;
        let network = client.transport.network();
        (requests, network.now() - started)
    };
    let mut operational = [false; 2];
    run_until_event(network, 2_000 * MS, seen, |network, event| {
        if let Event::Frame { frame, .. } = event {
            let state = frame
                .data()
                .first()
                .and_then(|&code| NmtState::from_heartbeat_code(code));
            match (frame.id().raw(), state) {
                (0x701, Some(NmtState::Operational)) => operational[0] = true,
                (0x721, Some(NmtState::Operational)) => operational[1] = true,
                _ => {}
            }
        }
        stopped(event)
            || (operational == [true, true] && consumer.iter().all(|&mcu| network.output(mcu)))
    });
    if operational != [true, true] {
        return Err(format!(
            "after configuration and NMT start, not both nodes report Operational in their \
             heartbeats within 2 s (node 1: {}, node 33: {})",
            operational[0], operational[1]
        ));
    }
    if !consumer.iter().all(|&mcu| network.output(mcu)) {
        return Err(
            "both nodes Operational, but node 33's outputs did not come on with node \
                    1's contacts closed"
                .into(),
        );
    }
    // Steady state for a while: every pair validated, nothing drops out.
    let steady = run_until_event(network, 1_000 * MS, seen, |network, event| {
        stopped(event) || !consumer.iter().all(|&mcu| network.output(mcu))
    });
    if let Some(at) = steady {
        return Err(format!(
            "node 33's outputs went off at {:.3} ms with node 1's contacts closed",
            at as f64 / 1e6
        ));
    }
    // The emergency stop: both of node 1's contacts open at once.
    let pressed = network.now();
    for &mcu in &producer {
        network.set_input(mcu, false);
    }
    let off = run_until_event(network, refresh + 1_000 * MS, seen, |network, event| {
        stopped(event) || consumer.iter().all(|&mcu| !network.output(mcu))
    })
    .filter(|_| consumer.iter().all(|&mcu| !network.output(mcu)))
    .ok_or("node 33's outputs did not go off within a second after node 1's contacts opened")?;
    Ok(Nominal {
        configured_in,
        sdo_requests: requests,
        reaction: off - pressed,
        bound: refresh,
    })
}
