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
//!
//! SimpleCAN's measuring run ([`simplecan`]): the SimpleCAN images configured from a
//! SimpleCAN network file (node 1 the master and producer of an SC-ID, node 33 its consumer)
//! and started; once both report Operational and node 33's outputs are on, one second is
//! profiled on every MCU with node 1's contacts opened and closed once in it.

use safety_config::client::Client;
use safety_config::network_file::Network as NetworkFile;
use safety_config::procedure::{self, NodeResult, Operator};
use shared::CanFrame;
use shared::canopen::nmt::{NmtCommand, NmtState};

use shared::canopen::storage::{self, Slot, StorageError};

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
    /// What each MCU executed (names in the network's order).
    pub costs: Vec<Cost>,
    /// The bus-load part, when asked for.
    pub load: Option<LoadReport>,
    /// Each MCU's profile of the pre-operational window (names in the network's order).
    pub pre_operational: Vec<Window>,
    /// Each MCU's profile of the Operational window.
    pub operational: Vec<Window>,
    /// Each MCU's deepest stack over the whole case, in bytes below its initial stack
    /// pointer ([`crate::cpu::Machine::deepest_stack`]).
    pub deepest_stack: Vec<u32>,
}

impl Nominal {
    /// Its profiles, for [`crate::figures`].
    pub fn profiled(&self) -> crate::figures::Profiled<'_> {
        crate::figures::Profiled {
            protocol: crate::profile::Protocol::CanopenSafety,
            pre_operational: &self.pre_operational,
            operational: &self.operational,
            deepest_stack: &self.deepest_stack,
        }
    }
}

/// One MCU's profile over one measuring window ([`crate::profile`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Window {
    /// The activations (wake-up to wake-up), oldest first.
    pub activations: Vec<crate::profile::Activation>,
    /// Instructions per function, most first.
    pub functions: Vec<(String, u64)>,
    /// The protocol's deliveries on the bus in the window: SRDO 1's pairs (CANopen Safety),
    /// the data packets of node 1's SC-ID (SimpleCAN).
    pub pairs: u64,
    /// Frames on the bus in the window, by identifier (every sender's), in order of identifier.
    pub frames: Vec<(u16, u64)>,
    /// Instructions per block start address, most first ([`crate::profile::Profile::blocks`]).
    pub blocks: Vec<(u32, u64)>,
    /// An idle loop iteration, function by function
    /// ([`crate::profile::Profile::timer_iteration`]).
    pub idle_iteration: Vec<(String, u64)>,
    /// The activations with the protocol's work ([`crate::profile::Protocol::is_work`]),
    /// instructions per function summed over all of them, most first
    /// ([`crate::profile::Profile::functions_of`]).
    pub work_functions: Vec<(String, u64)>,
    /// The same activations' instructions per block start address, most first
    /// ([`crate::profile::Profile::blocks_of`]).
    pub work_blocks: Vec<(u32, u64)>,
}

/// Starts a new profiling window on every MCU.
fn start_windows(network: &mut Network) {
    for mcu in 0..network.names().count() {
        network.machine_mut(mcu).start_profile();
    }
}

/// Ends the profiling window on every MCU: the deepest stack is still followed.
fn pause_windows(network: &mut Network) {
    for mcu in 0..network.names().count() {
        network.machine_mut(mcu).pause_profile();
    }
}

/// Every MCU's profile of the window since [`start_windows`].
fn windows(
    network: &Network,
    protocol: crate::profile::Protocol,
    pairs: u64,
    frames: &[(u16, u64)],
) -> Vec<Window> {
    (0..network.names().count())
        .map(|mcu| {
            let machine = network.machine(mcu);
            let (activations, functions, blocks, idle_iteration, work_functions, work_blocks) =
                machine.profile().map_or_else(Default::default, |p| {
                    let work = |marks| protocol.is_work_marks(marks);
                    (
                        p.activations().to_vec(),
                        p.functions(machine.symbols()),
                        p.blocks(),
                        p.timer_iteration(machine.symbols()),
                        p.functions_of(machine.symbols(), work),
                        p.blocks_of(work),
                    )
                });
            Window {
                idle_iteration,
                work_functions,
                work_blocks,
                activations,
                functions,
                blocks,
                pairs,
                frames: frames.to_vec(),
            }
        })
        .collect()
}

/// Counts `event`'s frame by identifier into `frames`.
fn count_frame(frames: &mut Vec<(u16, u64)>, event: &Event) {
    if let Event::Frame { frame, .. } = event {
        let id = frame.id().raw();
        match frames.binary_search_by_key(&id, |(known, _)| *known) {
            Ok(index) => frames[index].1 += 1,
            Err(index) => frames.insert(index, (id, 1)),
        }
    }
}

/// The bus-load part of the nominal case: frames on a free identifier of higher priority
/// than every SRDO (a babbling node) and SDO upload requests to node 33, generated in the
/// virtual time with the hub's generator (`can_hub::load`) so that the traffic other than
/// SRDOs fills `percent` of the bus, for `seconds`, beside SRDO 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoadSpec {
    /// Share of the bus, in percent.
    pub percent: u32,
    /// How long, in virtual time.
    pub duration: Nanos,
}

/// What the bus-load part measured.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadReport {
    /// The share of the bus's bit time the frames other than SRDOs took.
    pub share: f64,
    /// SDO requests sent and answered.
    pub sdo_requests: u64,
    /// Answers to them.
    pub sdo_answers: u64,
    /// Plain-to-inverted gaps of SRDO 1's pairs, sorted.
    pub gaps: Vec<Nanos>,
}

/// How far the share of the bus the load took may be from the share asked for, in percentage
/// points: the generator fills its share frame by frame, so the last frame's bits are the
/// only difference it leaves.
pub const LOAD_SHARE_TOLERANCE: f64 = 0.5;

impl LoadReport {
    /// What the bus-load part must have shown beside its SRDOs, with `percent` asked for: no
    /// SDO request lost (node 33 answers each; the last may still be on its way when the part
    /// ends), the load's share within [`LOAD_SHARE_TOLERANCE`] of `percent`, and SRDO pairs
    /// completed throughout. `Err` names what was not.
    pub fn judge(&self, percent: u32) -> Result<(), String> {
        if self.sdo_answers + 1 < self.sdo_requests || self.sdo_answers > self.sdo_requests {
            return Err(format!(
                "node 33 answered {} of {} SDO requests under bus load",
                self.sdo_answers, self.sdo_requests
            ));
        }
        let share = self.share * 100.0;
        if (share - f64::from(percent)).abs() > LOAD_SHARE_TOLERANCE {
            return Err(format!(
                "the load took {share:.2} % of the bus, not {percent} % (± {LOAD_SHARE_TOLERANCE})"
            ));
        }
        if self.gaps.is_empty() {
            return Err("no SRDO pair was completed while the bus was loaded".to_string());
        }
        Ok(())
    }
}

/// The babbling identifier of the bus-load part: free in the pre-defined connection set
/// (CiA 301 7.3.5: NMT 000h, EMCY from 081h) and above every SRDO's priority (CiA 304: 101h
/// and up).
const BABBLE_ID: u16 = 0x050;

/// What one MCU executed in two windows of equal length, counted by the emulator
/// (instructions, not cycles): pre-operational before the configuration (heartbeats, the
/// link) and Operational with SRDO 1 running.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Cost {
    /// The MCU.
    pub name: String,
    /// Instructions in the pre-operational window.
    pub idle_instructions: u64,
    /// Wake-ups from WFI in it: loop iterations.
    pub idle_wake_ups: u64,
    /// Instructions in the Operational window.
    pub operational_instructions: u64,
    /// Wake-ups in it.
    pub operational_wake_ups: u64,
    /// SRDO 1 pairs on the bus in the Operational window.
    pub pairs: u64,
}

impl Cost {
    /// Instructions per loop iteration, pre-operational.
    pub fn per_idle_iteration(&self) -> f64 {
        self.idle_instructions as f64 / self.idle_wake_ups.max(1) as f64
    }

    /// Instructions per SRDO pair above the pre-operational baseline: all layers (CAN and
    /// link interrupts, the loop, the core).
    pub fn per_pair(&self) -> f64 {
        self.operational_instructions
            .saturating_sub(self.idle_instructions) as f64
            / self.pairs.max(1) as f64
    }
}

/// The length of each measuring window.
const WINDOW: Nanos = 1_000 * MS;

/// Each MCU's (instructions, wake-ups) now.
fn counters(network: &Network) -> Vec<(u64, u64)> {
    (0..network.names().count())
        .map(|mcu| {
            let machine = network.machine(mcu);
            (machine.instructions(), machine.wake_ups())
        })
        .collect()
}

pub(crate) const MS: Nanos = 1_000_000;

/// The node-ID of the MCU at `index` in a network built as `emulate-network` builds it (two
/// channels a node, in the order of the node-IDs).
pub(crate) fn mcu_indices(network: &Network, node: u8) -> Vec<usize> {
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

pub(crate) fn event_time(event: &Event) -> Nanos {
    match event {
        Event::Frame { at, .. } | Event::Output { at, .. } | Event::Refused { at, .. } => *at,
        Event::Stopped { at, .. } | Event::Reset { at, .. } | Event::BitRate { at, .. } => *at,
    }
}

/// The nominal case on a network of nodes 1 (producer) and 33 (consumer) built with every
/// contact closed, configured from `file`. `seen` receives every event (for the caller's log
/// and trace). Fails with a sentence naming the step.
pub fn nominal(
    network: &mut Network,
    file: &NetworkFile,
    load: Option<LoadSpec>,
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
    let stopped = |event: &Event| matches!(event, Event::Stopped { .. });
    let (pre_operational, idle) = pre_operational_window(network, seen)?;
    let (configured_in, requests) = configure_and_start(network, file, &consumer, seen)?;
    // Steady state for a while: every pair validated, nothing drops out.
    let operational_from = counters(network);
    let plain = file
        .nodes
        .iter()
        .find(|node| node.id == 1)
        .and_then(|node| node.srdos.first())
        .map(|srdo| srdo.settings.cob_id_1 & 0x7FF)
        .unwrap_or_default();
    let mut pairs = 0;
    start_windows(network);
    let mut operational_frames = Vec::new();
    let steady = run_until_event(network, WINDOW, seen, |network, event| {
        count_frame(&mut operational_frames, event);
        if let Event::Frame { frame, .. } = event
            && u32::from(frame.id().raw()) == plain
        {
            pairs += 1;
        }
        stopped(event) || !consumer.iter().all(|&mcu| network.output(mcu))
    });
    let costs = counters(network)
        .iter()
        .zip(&operational_from)
        .zip(&idle)
        .zip(network.names())
        .map(|(((now, from), idle), name)| Cost {
            name: name.to_owned(),
            idle_instructions: idle.0,
            idle_wake_ups: idle.1,
            operational_instructions: now.0 - from.0,
            operational_wake_ups: now.1 - from.1,
            pairs,
        })
        .collect();
    let operational = windows(
        network,
        crate::profile::Protocol::CanopenSafety,
        pairs,
        &operational_frames,
    );
    pause_windows(network);
    if let Some(at) = steady {
        return Err(format!(
            "node 33's outputs went off at {:.3} ms with node 1's contacts closed",
            at as f64 / 1e6
        ));
    }
    let load = match load {
        Some(spec) => Some(under_load(network, spec, plain, &consumer, seen)?),
        None => None,
    };
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
    let deepest_stack = (0..network.names().count())
        .map(|mcu| network.machine(mcu).deepest_stack().unwrap_or(0))
        .collect();
    Ok(Nominal {
        configured_in,
        sdo_requests: requests,
        reaction: off - pressed,
        bound: refresh,
        costs,
        load,
        pre_operational,
        operational,
        deepest_stack,
    })
}

/// Each MCU's (instructions, wake-ups) over a window, in the network's order.
type Counts = Vec<(u64, u64)>;

/// From power-on (the deepest stack counts every step of a case): the boot-up messages of
/// nodes 1 and 33, then one profiled window before the configuration; every MCU's profile of
/// it and its (instructions, wake-ups) in it.
fn pre_operational_window(
    network: &mut Network,
    seen: &mut dyn FnMut(&Event),
) -> Result<(Vec<Window>, Counts), String> {
    start_windows(network);
    pause_windows(network);
    wait_for_boot_ups(network, &[1, 33], seen)?;
    let idle_from = counters(network);
    start_windows(network);
    let mut idle_frames = Vec::new();
    if let Some(at) = run_until_event(network, WINDOW, seen, |_, event| {
        count_frame(&mut idle_frames, event);
        matches!(event, Event::Stopped { .. })
    }) {
        return Err(format!("an MCU stopped at {:.3} ms", at as f64 / 1e6));
    }
    let pre_operational = windows(
        network,
        crate::profile::Protocol::CanopenSafety,
        0,
        &idle_frames,
    );
    pause_windows(network);
    let idle = counters(network)
        .iter()
        .zip(&idle_from)
        .map(|(now, from)| (now.0 - from.0, now.1 - from.1))
        .collect();
    Ok((pre_operational, idle))
}

/// Configures both nodes from `file` with the tool's library and starts them (NMT start to
/// all), then runs until both report Operational in their heartbeats and the `consumer`'s
/// outputs (node 33's MCUs) are on, at most 2 s: the virtual time the configuration took
/// and the SDO requests it sent, or which of these did not happen.
fn configure_and_start(
    network: &mut Network,
    file: &NetworkFile,
    consumer: &[usize],
    seen: &mut dyn FnMut(&Event),
) -> Result<(Nanos, u64), String> {
    let started = network.now();
    let requests = configure_then(network, file, |client| {
        client
            .nmt(NmtCommand::Start, 0)
            .map_err(|error| format!("NMT start: {error}"))
    })?;
    let configured_in = network.now() - started;
    let mut operational = [false; 2];
    run_until_event(network, 2_000 * MS, seen, |network, event| {
        if let Event::Frame { frame, .. } = event {
            note_operational(&mut operational, frame);
        }
        matches!(event, Event::Stopped { .. })
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
    Ok((configured_in, requests))
}

/// What SimpleCAN's measuring run measured ([`simplecan`]).
#[derive(Clone, Debug, PartialEq)]
pub struct SimpleCanRun {
    /// Virtual time the configuration took (both nodes: read, write, validate, store).
    pub configured_in: Nanos,
    /// SDO requests the tool sent.
    pub sdo_requests: u64,
    /// The SC-ID node 1 produces and node 33 consumes.
    pub sc_id: u8,
    /// From the contacts opening to the last of node 33's outputs going off.
    pub reaction: Nanos,
    /// From the contacts closing to the last of node 33's outputs coming on again.
    pub restored: Nanos,
    /// Each MCU's profile of the pre-operational window (names in the network's order).
    pub pre_operational: Vec<Window>,
    /// Each MCU's profile of the Operational window, the emergency stop in it.
    pub operational: Vec<Window>,
    /// Each MCU's deepest stack over the whole run, in bytes below its initial stack pointer.
    pub deepest_stack: Vec<u32>,
}

impl SimpleCanRun {
    /// Its profiles, for [`crate::figures`].
    pub fn profiled(&self) -> crate::figures::Profiled<'_> {
        crate::figures::Profiled {
            protocol: crate::profile::Protocol::Simplecan,
            pre_operational: &self.pre_operational,
            operational: &self.operational,
            deepest_stack: &self.deepest_stack,
        }
    }
}

/// SimpleCAN's measuring run on a network of nodes 1 and 33 (the SimpleCAN images) built
/// with every contact closed, configured from `file` (its SimpleCAN part: node 1 produces one
/// SC-ID, node 33 consumes it): a pre-operational window, the configuration and NMT start,
/// then one profiled window of Operational in which node 1's contacts open at a third (node
/// 33's outputs must go off) and close at two thirds (they must come on again). `seen`
/// receives every event. Fails with a sentence naming the step.
pub fn simplecan(
    network: &mut Network,
    file: &NetworkFile,
    seen: &mut dyn FnMut(&Event),
) -> Result<SimpleCanRun, String> {
    let producer = mcu_indices(network, 1);
    let consumer = mcu_indices(network, 33);
    if producer.len() != 2 || consumer.len() != 2 {
        return Err("SimpleCAN's measuring run needs nodes 1 and 33, two channels each".into());
    }
    let part = file
        .simplecan
        .as_ref()
        .ok_or("the network file has no SimpleCAN part")?;
    let sc_id = part
        .nodes
        .get(&1)
        .and_then(|node| node.produced.first())
        .map(|produced| produced.sc_id)
        .ok_or("the network file gives node 1 no SC-ID to produce")?;
    if !part
        .nodes
        .get(&33)
        .is_some_and(|node| node.consumed.iter().any(|c| c.sc_id == sc_id))
    {
        return Err(format!(
            "the network file does not have node 33 consume node 1's SC-ID {sc_id:02X}h"
        ));
    }
    let (pre_operational, _) = pre_operational_window(network, seen)?;
    let (configured_in, sdo_requests) = configure_and_start(network, file, &consumer, seen)?;
    let outputs =
        |network: &Network, on: bool| consumer.iter().all(|&mcu| network.output(mcu) == on);
    let third = WINDOW / 3;
    let mut packets = 0;
    let mut frames = Vec::new();
    let mut count = |event: &Event| {
        count_frame(&mut frames, event);
        if let Event::Frame { frame, .. } = event
            && frame.id().raw() == u16::from(sc_id)
        {
            packets += 1;
        }
        seen(event);
    };
    let stopped = |at: Nanos| format!("an MCU stopped at {:.3} ms", at as f64 / 1e6);
    start_windows(network);
    let end = network.now() + WINDOW;
    // Steady: SC-ID's packets flowing, node 33's outputs on.
    if let Some(at) = run_until_event(network, third, &mut count, |network, event| {
        matches!(event, Event::Stopped { .. }) || !outputs(network, true)
    }) {
        return Err(match outputs(network, true) {
            true => stopped(at),
            false => format!(
                "node 33's outputs went off at {:.3} ms with node 1's contacts closed",
                at as f64 / 1e6
            ),
        });
    }
    // The emergency stop: both of node 1's contacts open at once.
    let pressed = network.now();
    for &mcu in &producer {
        network.set_input(mcu, false);
    }
    let off = run_until_event(network, third, &mut count, |network, event| {
        matches!(event, Event::Stopped { .. }) || outputs(network, false)
    })
    .filter(|_| outputs(network, false))
    .ok_or("node 33's outputs did not go off within a third of the window after node 1's contacts opened")?;
    network.run_until(pressed + third);
    for event in network.take_events() {
        if let Event::Stopped { at, .. } = event {
            return Err(stopped(at));
        }
        count(&event);
    }
    let released = network.now();
    for &mcu in &producer {
        network.set_input(mcu, true);
    }
    let on = run_until_event(network, end - released, &mut count, |network, event| {
        matches!(event, Event::Stopped { .. }) || outputs(network, true)
    })
    .filter(|_| outputs(network, true))
    .ok_or("node 33's outputs did not come on again before the end of the window after node 1's contacts closed")?;
    network.run_until(end);
    for event in network.take_events() {
        if let Event::Stopped { at, .. } = event {
            return Err(stopped(at));
        }
        count(&event);
    }
    let operational = windows(
        network,
        crate::profile::Protocol::Simplecan,
        packets,
        &frames,
    );
    pause_windows(network);
    let deepest_stack = (0..network.names().count())
        .map(|mcu| network.machine(mcu).deepest_stack().unwrap_or(0))
        .collect();
    Ok(SimpleCanRun {
        configured_in,
        sdo_requests,
        sc_id,
        reaction: off - pressed,
        restored: on - released,
        pre_operational,
        operational,
        deepest_stack,
    })
}

/// Notes in `operational` (nodes 1 and 33) a heartbeat that says Operational (CiA 301
/// 7.2.8.3.2.2: 700h + node-ID, the state 05h).
pub(crate) fn note_operational(operational: &mut [bool; 2], frame: &CanFrame) {
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

/// Runs until every node of `nodes` has sent its boot-up message (CiA 301 7.2.8.3.2.2:
/// 700h + node-ID, data 00h), at most 5 s of virtual time.
pub(crate) fn wait_for_boot_ups(
    network: &mut Network,
    nodes: &[u8],
    seen: &mut dyn FnMut(&Event),
) -> Result<(), String> {
    let mut booted = vec![false; nodes.len()];
    run_until_event(network, 5_000 * MS, seen, |_, event| {
        if let Event::Frame { frame, .. } = event
            && frame.data() == [0]
            && let Some(index) = nodes
                .iter()
                .position(|&node| frame.id().raw() == 0x700 + u16::from(node))
        {
            booted[index] = true;
        }
        matches!(event, Event::Stopped { .. }) || booted.iter().all(|&b| b)
    });
    let silent: Vec<u8> = nodes
        .iter()
        .zip(&booted)
        .filter(|(_, booted)| !**booted)
        .map(|(node, _)| *node)
        .collect();
    if silent.is_empty() {
        Ok(())
    } else {
        Err(format!(
            "no boot-up message within 5 s from node(s) {silent:?}"
        ))
    }
}

/// The parameter slots of `safety_device::parameter_flash::STM32F405_SLOTS` (flash sectors 10
/// and 11) in an emulated MCU's flash array, read with the storage layer the images use.
struct Slots<'a>(&'a [u8]);

/// Where the two slots begin in the flash array, and their length
/// (`safety_device::parameter_flash`).
const SLOTS: ([usize; 2], usize) = ([0x000C_0000, 0x000E_0000], 0x0002_0000);

impl storage::Flash for Slots<'_> {
    fn slot_len(&self) -> usize {
        SLOTS.1
    }
    fn read(&mut self, slot: Slot, offset: usize, buf: &mut [u8]) -> Result<(), StorageError> {
        let index = match slot {
            Slot::A => 0,
            Slot::B => 1,
        };
        let start = SLOTS.0[index] + offset;
        let bytes = self
            .0
            .get(start..start + buf.len())
            .ok_or(StorageError::Medium)?;
        buf.copy_from_slice(bytes);
        Ok(())
    }
    fn erase(&mut self, _slot: Slot) -> Result<(), StorageError> {
        Err(StorageError::Medium)
    }
    fn erase_stalls(&self) -> bool {
        // The F405's flash: an erase holds the processor (only loads run on this view).
        true
    }
    fn write(&mut self, _slot: Slot, _offset: usize, _data: &[u8]) -> Result<(), StorageError> {
        Err(StorageError::Medium)
    }
}

/// What MCU `mcu`'s flash holds as its stored parameters: the payload the storage layer
/// loads (`None`: nothing stored, the defaults), or why it loads nothing.
pub fn stored(network: &Network, mcu: usize) -> Result<Option<Vec<u8>>, StorageError> {
    let array = network.machine(mcu).flash_array();
    let mut buf = vec![0; SLOTS.1];
    let len = storage::load(&mut Slots(&array), &mut buf)?;
    Ok(len.map(|len| buf[..len].to_vec()))
}

/// Node 1's configuration alone, from `file`.
fn node_1_only(file: &NetworkFile) -> Result<NetworkFile, String> {
    let mut only = file.clone();
    only.nodes.retain(|node| node.id == 1);
    if only.nodes.is_empty() {
        return Err("the network file has no node 1".into());
    }
    Ok(only)
}

/// Node 1's stores without a power cut: what each channel held before and after, and how
/// many flash operations each channel's store took.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Reference {
    /// Per channel (A, B): the payload loaded before the store.
    pub old: [Option<Vec<u8>>; 2],
    /// Per channel: the payload loaded after it.
    pub new: [Option<Vec<u8>>; 2],
    /// Per channel: the flash operations (programs and erases) from boot-up to the end of
    /// the configuration.
    pub operations: [u64; 2],
}

/// Configures node 1 alone on a network from `build` (nodes 1 and 33, contacts closed) and
/// records [`Reference`].
pub fn reference(
    build: &dyn Fn() -> Result<Network, String>,
    file: &NetworkFile,
) -> Result<Reference, String> {
    let file = node_1_only(file)?;
    let mut network = build()?;
    wait_for_boot_ups(&mut network, &[1], &mut |_| {})?;
    let channels = mcu_indices(&network, 1);
    let load = |network: &Network, mcu: usize| {
        stored(network, mcu)
            .map_err(|error| format!("{}: {error:?}", network.participant_name(mcu)))
    };
    let old = [load(&network, channels[0])?, load(&network, channels[1])?];
    let before = channels
        .iter()
        .map(|&mcu| network.machine(mcu).flash_operations())
        .collect::<Vec<_>>();
    configure_then(&mut network, &file, |_| Ok(()))?;
    let new = [load(&network, channels[0])?, load(&network, channels[1])?];
    if new[0].is_none() || new == old {
        return Err("configuring node 1 stored nothing new in its channels' flash".into());
    }
    let operations = [0, 1].map(|c| network.machine(channels[c]).flash_operations() - before[c]);
    Ok(Reference {
        old,
        new,
        operations,
    })
}

/// Configures from `file` with the tool's library, then `then` with the same client; the
/// SDO requests sent, or the tool's error as a sentence.
fn configure_then(
    network: &mut Network,
    file: &NetworkFile,
    then: impl FnOnce(&mut Client<ToolPort<'_>>) -> Result<(), String>,
) -> Result<u64, String> {
    let mut client = Client::new(ToolPort::join(network, "tool"), file.sdo_timeout);
    let report = procedure::configure(&mut client, file, false, &mut Narrator)
        .map_err(|error| format!("configuration: {error}"))?;
    for result in &report.nodes {
        if let NodeResult::Failed { error, .. } = result {
            return Err(format!("configuration: {error}"));
        }
    }
    then(&mut client)?;
    Ok(client.requests)
}

/// What a power cut during node 1's store left.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Cut {
    /// Per channel (A, B): whether its flash holds the new record (else the old one).
    pub new: [bool; 2],
}

/// Cuts node 1's power during flash operation `step` of its channel `channel` (0: A, 1: B)
/// since boot-up, while the tool configures it, from `seed`; then checks what EN 50325-5
/// 5.3 and CiA 301 7.5.2 (1010h) ask of a store interrupted by a power loss: each channel's
/// flash loads the old record or the new one, never a mix, never damage and never an older
/// one; and the node starts again (its boot-up message). `None` when the store was over
/// before `step`.
pub fn power_cut(
    build: &dyn Fn() -> Result<Network, String>,
    file: &NetworkFile,
    reference: &Reference,
    channel: usize,
    step: u64,
    seed: u64,
) -> Result<Option<Cut>, String> {
    let file = node_1_only(file)?;
    let mut network = build()?;
    wait_for_boot_ups(&mut network, &[1], &mut |_| {})?;
    let channels = mcu_indices(&network, 1);
    let target = channels[channel];
    let base = network.machine(target).flash_operations();
    network.machine_mut(target).cut_power_at(base + step, seed);
    let configured = configure_then(&mut network, &file, |_| Ok(()));
    if !network.stopped(target) {
        return match configured {
            Ok(_) => Ok(None),
            Err(why) => Err(format!("without a power cut: {why}")),
        };
    }
    let mut new = [false; 2];
    for (c, &mcu) in channels.iter().enumerate() {
        let name = network.participant_name(mcu);
        let held = stored(&network, mcu).map_err(|error| {
            format!("{name}: after a power cut at step {step}, its stored parameters do not load: {error:?}")
        })?;
        new[c] = if held == reference.new[c] {
            true
        } else if held == reference.old[c] {
            false
        } else {
            return Err(format!(
                "{name}: after a power cut at step {step}, its flash holds neither the old nor \
                 the new parameters"
            ));
        };
    }
    // The stop the cut caused is reported; what follows is the new power-on.
    network.take_events();
    network.power_cycle(&channels);
    wait_for_boot_ups(&mut network, &[1], &mut |_| {})
        .map_err(|why| format!("after the power came back: {why}"))?;
    Ok(Some(Cut { new }))
}

/// The bus-load part of [`nominal`]: node 33's outputs must stay on throughout, every SDO
/// request answered.
fn under_load(
    network: &mut Network,
    spec: LoadSpec,
    plain: u32,
    consumer: &[usize],
    seen: &mut dyn FnMut(&Event),
) -> Result<LoadReport, String> {
    use can_hub::load::Load;
    use shared::{CanId, Instant};
    let frame = |id: u16, data: &[u8]| {
        CanId::new(id)
            .ok()
            .and_then(|id| CanFrame::new(id, data).ok())
            .ok_or_else(|| format!("no frame {id:03X}h"))
    };
    // 1018h:01h, as python-canopen reads an identity (CiA 301 7.2.4.3.4: upload request).
    let request = frame(0x621, &[0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0])?;
    let babble = frame(BABBLE_ID, &[0x55; 8])?;
    let frames = vec![request, babble, babble, babble, babble];
    let start = network.now();
    let mut generator = Load::new(
        spec.percent,
        500_000,
        frames,
        Instant::from_micros(start / 1_000),
    )
    .map_err(|error| error.to_string())?;
    let sender = network.join_external("load");
    let (mut requests, mut answers) = (0u64, 0u64);
    let mut other_bits = 0u64;
    let mut plain_at: Option<Nanos> = None;
    let mut gaps = Vec::new();
    let end = start + spec.duration;
    let mut queued = false;
    while network.now() < end {
        let now = Instant::from_micros(network.now() / 1_000);
        if !queued && let Some(next) = generator.poll(now) {
            if next.id().raw() == 0x621 {
                requests += 1;
            }
            network.send(sender, next);
            queued = true;
        }
        network.run_until((network.now() + 100_000).min(end));
        for event in network.take_events() {
            seen(&event);
            match &event {
                Event::Frame { at, from, frame } => {
                    let ours = from == "load";
                    if ours {
                        queued = false;
                    }
                    generator.completed(frame, ours);
                    let id = u32::from(frame.id().raw());
                    if id == plain {
                        plain_at = Some(*at);
                    } else if id == plain + 1 {
                        if let Some(t) = plain_at.take() {
                            gaps.push(at - t);
                        }
                    } else {
                        other_bits += u64::from(can_hub::bus::frame_bits(frame));
                        if frame.id().raw() == 0x5A1 {
                            answers += 1;
                        }
                    }
                }
                Event::Stopped { at, .. } => {
                    return Err(format!(
                        "an MCU stopped under bus load at {:.3} ms",
                        *at as f64 / 1e6
                    ));
                }
                _ => {}
            }
            if !consumer.iter().all(|&mcu| network.output(mcu)) {
                return Err(format!(
                    "node 33's outputs went off under {} % bus load at {:.3} ms",
                    spec.percent,
                    network.now() as f64 / 1e6
                ));
            }
        }
    }
    // Nothing more is kept for the generator (its last frame still goes out).
    network.leave_external(sender);
    gaps.sort_unstable();
    let seconds = spec.duration as f64 / 1e9;
    let report = LoadReport {
        share: other_bits as f64 / (500_000.0 * seconds),
        sdo_requests: requests,
        sdo_answers: answers,
        gaps,
    };
    report.judge(spec.percent)?;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bus-load part's verdict beside its SRDOs: every SDO request answered but the last,
    /// which may still be on its way; the share asked for within its tolerance; pairs
    /// completed. Each departure is named.
    #[test]
    fn the_bus_load_part_fails_on_a_lost_answer_a_wrong_share_or_no_pair() {
        let good = LoadReport {
            share: 0.302,
            sdo_requests: 500,
            sdo_answers: 499,
            gaps: vec![215_000],
        };
        assert_eq!(good.judge(30), Ok(()));
        let lost = LoadReport {
            sdo_answers: 498,
            ..good.clone()
        };
        assert!(lost.judge(30).unwrap_err().contains("answered 498 of 500"));
        let extra = LoadReport {
            sdo_answers: 501,
            ..good.clone()
        };
        assert!(extra.judge(30).is_err());
        let thin = LoadReport {
            share: 0.294,
            ..good.clone()
        };
        assert!(thin.judge(30).unwrap_err().contains("29.40 %"));
        let no_pair = LoadReport {
            gaps: Vec::new(),
            ..good
        };
        assert!(no_pair.judge(30).unwrap_err().contains("no SRDO pair"));
    }
}
