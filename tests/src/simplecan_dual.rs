//! A SimpleCAN network of dual-channel nodes under simulated time (SC_REQ_10, SC_REQ_24):
//! each node is channel A and channel B, each a [`Runtime`] around its own core with the SRDO
//! table and SimpleCAN in its slot ([`SrdoAndSimpleCan`]), its own CAN controller on the bus
//! and a serial link between them, configured by SDO over the same bus by the tool library's
//! client (participant 0, [`crate::simplecan_net::configure`]).
//!
//! The controllers: each channel's frames go out by identifier (as `board::hw` queues them);
//! a frame is confirmed to its sender when it has been on the bus
//! ([`Runtime::on_transmitted`]), and delivered to every other controller, the sender's own
//! never (one transceiver, Model III). Faults can be injected into one channel's view of the
//! bus ([`Fault::Drop`], [`Fault::Corrupt`], [`Fault::Delay`]), as in [`crate::dual`].

use crate::bus::{Bus, Delivery, Fault, Injection, Match, ORDERED_BY_IDENTIFIER};
use crate::dual::{ChannelClock, LINK_BYTE_TIME, LINK_PERIOD, Side, through_receive_faults};
use crate::simplecan_net::{ESTOP, ScConfig, ScEntry, configure, device_config};
use crate::tool_bus::Simulation;
use channel_a::role::ChannelA;
use channel_b::role::ChannelB;
use dual_channel::runtime::{ChannelEvent, Io, Runtime};
use shared::canopen::nmt::{self, NmtCommand};
use shared::canopen::od::Address;
use shared::canopen::storage::RamFlash;
use shared::node::SrdoAndSimpleCan;
use shared::safety::types::SrdoNumber;
use shared::{CanFrame, Duration, Instant};
use std::collections::VecDeque;

/// The core's protocol: 4 SRDOs and 4 SDD entries, as the single-channel network's devices.
pub type Protocol = SrdoAndSimpleCan<4, 4>;
/// Channel A of a node.
pub type ScChannelA = Runtime<RamFlash<8192>, ChannelA, 4, Protocol>;
/// Channel B of a node.
pub type ScChannelB = Runtime<RamFlash<8192>, ChannelB, 4, Protocol>;

/// Channel B samples the same input object as channel A (its own contact).
const B_INPUTS: [(u16, u8, u8); 1] = [(0x6000, 1, 1)];

/// What one channel handed out during one call.
#[derive(Default)]
struct Out {
    frames: Vec<CanFrame>,
    link: Vec<u8>,
    events: Vec<ChannelEvent>,
    outputs: Vec<(u8, u32)>,
    aborts: Vec<u16>,
}

impl Io for Out {
    fn transmit(&mut self, frame: CanFrame) {
        self.frames.push(frame);
    }
    fn link(&mut self, bytes: &[u8]) {
        self.link.extend_from_slice(bytes);
    }
    fn output(&mut self, _: SrdoNumber, _: u64) {}
    fn event(&mut self, event: ChannelEvent) {
        self.events.push(event);
    }
    fn simplecan_output(&mut self, sc_id: u8, value: u32) {
        self.outputs.push((sc_id, value));
    }
    fn abort(&mut self, id: shared::CanId) {
        self.aborts.push(id.raw());
    }
}

/// One direction of a link: bytes in flight with their arrival times.
#[derive(Default)]
struct Wire {
    bytes: VecDeque<(Instant, u8)>,
    busy_until: Instant,
}

/// One dual-channel SimpleCAN node.
pub struct ScDualNode {
    /// Node-ID.
    pub id: u8,
    /// Channel A.
    pub a: ScChannelA,
    /// Channel B.
    pub b: ScChannelB,
    a_to_b: Wire,
    b_to_a: Wire,
    deadlines: [Instant; 2],
    /// Faults in one channel's receive path (that channel's controller alone).
    pub receive_faults: Vec<(Side, Injection)>,
    held_back: Vec<(Instant, Side, CanFrame)>,
    /// How fast each channel's clock runs against the network's time (channel A, channel B;
    /// exact unless [`ScDualNetwork::set_clock`] says otherwise). Each channel is handed its
    /// own time, `ChannelClock::local`.
    clocks: [ChannelClock; 2],
}

impl ScDualNode {
    fn clock(&self, side: Side) -> ChannelClock {
        self.clocks[side as usize]
    }
}

/// The network: participant 0 is the tool; node `i`'s channel A is participant `2i + 1`,
/// channel B `2i + 2`.
pub struct ScDualNetwork {
    /// Simulated time.
    pub now: Instant,
    /// The bus.
    pub bus: Bus,
    /// The nodes.
    pub nodes: Vec<ScDualNode>,
    in_flight: Vec<Delivery>,
    /// Everything the channels reported: (time, node-ID, channel, event).
    pub log: Vec<(Instant, u8, Side, ChannelEvent)>,
    /// Every frame on the bus, as delivered, with its sender.
    pub trace: Vec<(Instant, CanFrame, usize)>,
    /// Every change of a channel's SimpleCAN output: (time, node-ID, channel, SC-ID, value).
    pub outputs: Vec<(Instant, u8, Side, u8, u32)>,
    /// Every withdrawal a channel asked of its controller: (time, node-ID, channel,
    /// identifier). The bus model cannot take back a queued frame; the log is what a test
    /// checks.
    pub aborts: Vec<(Instant, u8, Side, u16)>,
}

fn participant(index: usize, side: Side) -> usize {
    1 + 2 * index + side as usize
}

impl ScDualNetwork {
    /// Dual-channel nodes with node-IDs `ids` on a bus at `bit_rate`, powered on at t = 0.
    pub fn new(bit_rate: u32, ids: &[u8]) -> Self {
        let nodes: Vec<ScDualNode> = ids
            .iter()
            .map(|&id| ScDualNode {
                id,
                a: Runtime::new(
                    device_config(id),
                    RamFlash::new(),
                    ChannelA::default(),
                    Instant::ZERO,
                    LINK_PERIOD,
                )
                .expect("valid device"),
                b: Runtime::new(
                    device_config(id),
                    RamFlash::new(),
                    ChannelB::new(&B_INPUTS).expect("valid inputs"),
                    Instant::ZERO,
                    LINK_PERIOD,
                )
                .expect("valid device"),
                a_to_b: Wire::default(),
                b_to_a: Wire::default(),
                deadlines: [Instant::ZERO; 2],
                receive_faults: Vec::new(),
                held_back: Vec::new(),
                clocks: [ChannelClock::default(); 2],
            })
            .collect();
        let mut bus = Bus::new(bit_rate, 1 + 2 * nodes.len());
        bus.set_transmit_mailboxes(ORDERED_BY_IDENTIFIER);
        ScDualNetwork {
            now: Instant::ZERO,
            bus,
            nodes,
            in_flight: Vec::new(),
            log: Vec::new(),
            trace: Vec::new(),
            outputs: Vec::new(),
            aborts: Vec::new(),
        }
    }

    fn index(&self, id: u8) -> usize {
        self.nodes
            .iter()
            .position(|node| node.id == id)
            .expect("a node with this ID")
    }

    /// The node with node-ID `id`.
    pub fn node(&self, id: u8) -> &ScDualNode {
        &self.nodes[self.index(id)]
    }

    /// Channel `side` of node `id` receives what `when` matches altered by `fault`.
    pub fn inject_receive(&mut self, id: u8, side: Side, when: Match, fault: Fault) {
        let index = self.index(id);
        self.nodes[index]
            .receive_faults
            .push((side, Injection::new(when, fault)));
    }

    /// Adds a fault on the bus (every receiver sees it; [`Fault::Mute`] silences a sender).
    pub fn inject(&mut self, when: Match, fault: Fault) {
        self.bus.inject(Injection::new(when, fault));
    }

    /// The bus participant of channel `side` of node `id`.
    pub fn participant(&self, id: u8, side: Side) -> usize {
        participant(self.index(id), side)
    }

    /// Runs until `end`.
    pub fn run_until(&mut self, end: Instant) {
        loop {
            let next = self.next_activity();
            if next > end {
                self.now = self.now.max(end);
                return;
            }
            self.now = self.now.max(next);
            self.step();
        }
    }

    /// Runs for `duration`.
    pub fn run_for(&mut self, duration: Duration) {
        self.run_until(self.now + duration);
    }

    fn next_activity(&self) -> Instant {
        let deliveries = self.in_flight.iter().map(|d| d.at);
        let channels = self.nodes.iter().flat_map(|node| node.deadlines);
        let held_back = self
            .nodes
            .iter()
            .flat_map(|node| node.held_back.iter().map(|(at, ..)| *at));
        let links = self.nodes.iter().flat_map(|node| {
            node.a_to_b
                .bytes
                .front()
                .into_iter()
                .chain(node.b_to_a.bytes.front())
                .map(|(at, _)| *at)
        });
        deliveries
            .chain(channels)
            .chain(held_back)
            .chain(links)
            .chain(self.bus.next_start(self.now))
            .min()
            .unwrap_or(Instant::NEVER)
    }

    fn step(&mut self) {
        let now = self.now;
        let (due, later): (Vec<_>, Vec<_>) = self.in_flight.drain(..).partition(|d| d.at <= now);
        self.in_flight = later;
        for delivery in due {
            self.trace
                .push((delivery.at, delivery.frame, delivery.from));
            for index in 0..self.nodes.len() {
                for side in [Side::A, Side::B] {
                    if participant(index, side) == delivery.from {
                        // The sender's controller confirms; it does not receive its own.
                        self.with_channel(index, side, |now, a, b, out| match (a, b) {
                            (Some(a), _) => a.on_transmitted(now, &delivery.frame, out),
                            (_, Some(b)) => b.on_transmitted(now, &delivery.frame, out),
                            _ => {}
                        });
                        continue;
                    }
                    if let Some(frame) = self.received_by(index, side, delivery.frame, now) {
                        self.receive(index, side, frame);
                    }
                }
            }
        }
        for index in 0..self.nodes.len() {
            let (due, later): (Vec<_>, Vec<_>) = self.nodes[index]
                .held_back
                .drain(..)
                .partition(|(at, ..)| *at <= now);
            self.nodes[index].held_back = later;
            for (_, side, frame) in due {
                self.receive(index, side, frame);
            }
        }
        for index in 0..self.nodes.len() {
            for side in [Side::A, Side::B] {
                self.deliver_link(index, side, now);
            }
        }
        for index in 0..self.nodes.len() {
            for side in [Side::A, Side::B] {
                if self.nodes[index].deadlines[side as usize] <= now {
                    self.with_channel(index, side, |_, _, _, _| {});
                }
            }
        }
        if self.bus.next_start(now) == Some(now) {
            let deliveries = self.bus.arbitrate(now);
            self.in_flight.extend(deliveries);
        }
    }

    fn receive(&mut self, index: usize, side: Side, frame: CanFrame) {
        self.with_channel(index, side, |now, a, b, out| match (a, b) {
            (Some(a), _) => a.on_frame(now, &frame, out),
            (_, Some(b)) => b.on_frame(now, &frame, out),
            _ => {}
        });
    }

    /// The frame as channel `side` of node `index` receives it, after its receive faults.
    fn received_by(
        &mut self,
        index: usize,
        side: Side,
        frame: CanFrame,
        now: Instant,
    ) -> Option<CanFrame> {
        let node = &mut self.nodes[index];
        through_receive_faults(
            &mut node.receive_faults,
            &mut node.held_back,
            side,
            frame,
            now,
        )
    }

    /// Delivers the link bytes due at `now` to channel `side` of node `index`.
    fn deliver_link(&mut self, index: usize, side: Side, now: Instant) {
        loop {
            let node = &mut self.nodes[index];
            let wire = match side {
                Side::A => &mut node.b_to_a,
                Side::B => &mut node.a_to_b,
            };
            let Some(&(at, byte)) = wire.bytes.front() else {
                return;
            };
            if at > now {
                return;
            }
            wire.bytes.pop_front();
            let at = node.clock(side).local(at);
            self.with_channel(index, side, |_, a, b, out| match (a, b) {
                (Some(a), _) => a.on_link_byte(at, byte, out),
                (_, Some(b)) => b.on_link_byte(at, byte, out),
                _ => {}
            });
        }
    }

    /// Runs `action` on one channel, polls it, and applies what it handed out.
    fn with_channel(
        &mut self,
        index: usize,
        side: Side,
        action: impl FnOnce(Instant, Option<&mut ScChannelA>, Option<&mut ScChannelB>, &mut Out),
    ) {
        let mut out = Out::default();
        let now = self.now;
        let node = &mut self.nodes[index];
        let clock = node.clock(side);
        let local = clock.local(now);
        let deadline = match side {
            Side::A => {
                action(local, Some(&mut node.a), None, &mut out);
                node.a.poll(local, &mut out)
            }
            Side::B => {
                // The simulated contacts are read continuously (`crate::dual`).
                node.b.inputs_sampled(local, &mut out);
                action(local, None, Some(&mut node.b), &mut out);
                node.b.poll(local, &mut out)
            }
        };
        node.deadlines[side as usize] = clock.global(deadline);
        let id = node.id;
        if !out.link.is_empty() {
            let wire = match side {
                Side::A => &mut node.a_to_b,
                Side::B => &mut node.b_to_a,
            };
            let mut at = wire.busy_until.max(now);
            for &byte in &out.link {
                at = at + LINK_BYTE_TIME;
                wire.bytes.push_back((at, byte));
            }
            wire.busy_until = at;
        }
        for frame in out.frames {
            self.bus.send(participant(index, side), frame);
        }
        for event in out.events {
            self.log.push((now, id, side, event));
        }
        for (sc_id, value) in out.outputs {
            self.outputs.push((now, id, side, sc_id, value));
        }
        for abort in out.aborts {
            self.aborts.push((now, id, side, abort));
        }
    }

    /// Both channels of node `id` sample their safety input 6000h:01 as `value` (the two
    /// contacts of an emergency stop; 1 closed, released).
    pub fn set_inputs(&mut self, id: u8, value: u8) {
        let index = self.index(id);
        let plain = Address::new(0x6000, 1);
        let inverted = Address::new(0x6001, 1);
        for side in [Side::A, Side::B] {
            self.with_channel(index, side, |now, a, b, out| {
                let result = match (a, b) {
                    (Some(a), _) => a.set_input(now, plain, inverted, &[value], out),
                    (_, Some(b)) => b.set_input(now, plain, inverted, &[value], out),
                    _ => Ok(()),
                };
                result.expect("input object");
            });
        }
    }

    /// From now on, channel `side` of node `id`'s clock runs `ppm` parts per million fast
    /// (negative: slow) against the network's time, from an exact one.
    pub fn set_clock(&mut self, id: u8, side: Side, ppm: i64) {
        let index = self.index(id);
        let mut clock = ChannelClock::default();
        clock.set_rate(self.now, ppm);
        self.nodes[index].clocks[side as usize] = clock;
    }

    /// Channel `side` of node `id` alone samples its contact of 6000h:01 as `value` (the
    /// two contacts of one emergency stop never move at exactly the same moment).
    pub fn set_input_of(&mut self, id: u8, side: Side, value: u8) {
        let index = self.index(id);
        let plain = Address::new(0x6000, 1);
        let inverted = Address::new(0x6001, 1);
        self.with_channel(index, side, |now, a, b, out| {
            let result = match (a, b) {
                (Some(a), _) => a.set_input(now, plain, inverted, &[value], out),
                (_, Some(b)) => b.set_input(now, plain, inverted, &[value], out),
                _ => Ok(()),
            };
            result.expect("input object");
        });
    }

    /// The next start of slot `slot` at least `ahead` from now, by the global time channel
    /// A of node `id` has (its own as the master, or the one it is synced to).
    pub fn next_slot_start(&self, id: u8, slot: u16, ahead: Duration) -> Instant {
        let layer = &self.node(id).a.node().protocol().simplecan;
        let cycle = u64::from(layer.objects().slots) * 1000;
        let from = self.now + ahead;
        let local = self.node(id).clock(Side::A).local(from);
        let global = layer.global_time(local).expect("a global time");
        let offset = u64::from(slot) * 1000;
        let start = (global.saturating_sub(offset)).div_ceil(cycle) * cycle + offset;
        from + Duration::from_micros(start - global)
    }

    /// The global time channel A of node `id` has at the network's time `at`, if any.
    pub fn global_time(&self, id: u8, at: Instant) -> Option<u64> {
        let node = self.node(id);
        let layer = &node.a.node().protocol().simplecan;
        layer.global_time(node.clock(Side::A).local(at))
    }

    /// The effective output of node `id` for consumed SC-ID `sc_id`: both channels'
    /// outputs in series (AND).
    pub fn output(&self, id: u8, sc_id: u8) -> u32 {
        let node = self.node(id);
        node.a.simplecan_output(sc_id) & node.b.simplecan_output(sc_id)
    }

    /// The tool sends an NMT command to `target` (0: all).
    pub fn nmt(&mut self, command: NmtCommand, target: u8) {
        self.bus.send(0, nmt::command_frame(command, target));
        self.run_for(Duration::from_millis(1));
    }

    /// Waits for every node's boot-up (both channels up, the link first), configures each
    /// node with its SimpleCAN configuration by the tool's procedure
    /// ([`crate::simplecan_net::configure`]: both channels take in the same SDO writes, A
    /// answers), closes every input and starts the network.
    pub fn configure_and_start(&mut self, configs: &[(u8, ScConfig)]) -> Result<(), String> {
        self.wait_for_boot_up();
        for (id, config) in configs {
            configure(self, *id, config)?;
        }
        let ids: Vec<u8> = self.nodes.iter().map(|node| node.id).collect();
        for id in ids {
            self.set_inputs(id, 1);
        }
        self.nmt(NmtCommand::Start, 0);
        Ok(())
    }

    /// As [`Self::configure_and_start`], but configured by the configuration tool's own
    /// procedure from a network file (`safety_config::procedure::configure`: identity check,
    /// writes, read-back, the tool's CRC-32 signature, 5EFEh, store; the node hashes the
    /// tool derives from the file, SC_REQ_15), so that a test runs exactly the configuration
    /// the tool's calculators are given.
    pub fn configure_from_file_and_start(
        &mut self,
        file: &safety_config::network_file::Network,
    ) -> Result<(), String> {
        self.wait_for_boot_up();
        let mut quiet = safety_config::procedure::Quiet {
            accept_identity: false,
        };
        let report = safety_config::procedure::configure(
            &mut crate::tool_bus::client(self),
            file,
            false,
            &mut quiet,
        )
        .map_err(|error| error.to_string())?;
        if !report.success() {
            return Err(format!("the tool did not configure every node: {report:?}"));
        }
        let ids: Vec<u8> = self.nodes.iter().map(|node| node.id).collect();
        for id in ids {
            self.set_inputs(id, 1);
        }
        self.nmt(NmtCommand::Start, 0);
        Ok(())
    }

    /// Runs until channel A of every node is Pre-operational (both channels booted, the
    /// link first), at most 100 ms.
    fn wait_for_boot_up(&mut self) {
        for _ in 0..100 {
            if self.nodes.iter().all(|node| {
                node.a.node().nmt_state() == shared::canopen::nmt::NmtState::PreOperational
            }) {
                break;
            }
            self.run_for(Duration::from_millis(1));
        }
    }

    /// The emergency-stop network: nodes 1 and 33 at `bit_rate`, each SCL stating
    /// `buffering_us` (SC_REQ_33), the clocks of `clocks` (node-ID, channel, ppm) off from
    /// power-on; node 1 the potential master producing [`ScEntry::ESTOP_PRODUCER`] (30h in
    /// slot 0 from its input), node 33 consuming it ([`ScEntry::ESTOP_CONSUMER`], 50 ms);
    /// N = 10 slots of 1 ms, a sync every 10 cycles. Configured, started and run until node
    /// 33's output is on (both channels confirmed a value of 1), at most 1.5 s; `Err` says
    /// what did not happen.
    pub fn estop_running(
        bit_rate: u32,
        buffering_us: u16,
        clocks: &[(u8, Side, i64)],
    ) -> Result<ScDualNetwork, String> {
        let mut net = ScDualNetwork::new(bit_rate, &[1, 33]);
        for &(id, side, ppm) in clocks {
            net.set_clock(id, side, ppm);
        }
        let config = |potential_master, entry| ScConfig {
            slots: 10,
            sync_every: 10,
            buffering_us,
            potential_master,
            entries: vec![entry],
        };
        let producer = config(true, ScEntry::ESTOP_PRODUCER);
        let consumer = config(false, ScEntry::ESTOP_CONSUMER);
        net.configure_and_start(&[(1, producer), (33, consumer)])?;
        let until = net.now + Duration::from_millis(1500);
        while net.output(33, ESTOP) != 1 && net.now < until {
            net.run_for(Duration::from_millis(1));
        }
        if net.output(33, ESTOP) != 1 {
            return Err(format!(
                "node 33's output of 30h not on within 1.5 s; faults: node 1 {:?}, node 33 {:?}",
                net.faults(1),
                net.faults(33)
            ));
        }
        Ok(net)
    }

    /// The fault each channel of node `id` latched, if any (channel A, channel B).
    pub fn faults(&self, id: u8) -> [Option<dual_channel::runtime::ChannelFault>; 2] {
        let node = self.node(id);
        [node.a.fault(), node.b.fault()]
    }
}

impl Simulation for ScDualNetwork {
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
        ScDualNetwork::run_until(self, end);
    }
}

impl ScDualNetwork {
    /// When node `id`'s effective output for SC-ID `sc_id` (both channels' outputs in
    /// series) went to 0 at or after `from`: when the first of its channels switched off.
    pub fn output_off(&self, id: u8, sc_id: u8, from: Instant) -> Option<Instant> {
        self.outputs
            .iter()
            .find(|&&(at, node, _, sc, value)| {
                at >= from && node == id && sc == sc_id && value == 0
            })
            .map(|&(at, ..)| at)
    }
}

/// The SimpleCAN nodes of `file` (those with a `[node.simplecan]` table) on a bus at
/// `bit_rate`, configured by the tool's procedure from `file`
/// ([`ScDualNetwork::configure_from_file_and_start`]), started, and run until every
/// consumer's output is on for every SC-ID it consumes (both channels confirmed a value of
/// 1), at most 1.5 s; a network without a consumer runs the 1.5 s.
pub fn running_from_file(
    file: &safety_config::network_file::Network,
    bit_rate: u32,
) -> Result<ScDualNetwork, String> {
    let simplecan = file
        .simplecan
        .as_ref()
        .ok_or("the network file has no [simplecan] section")?;
    let ids: Vec<u8> = simplecan.nodes.keys().copied().collect();
    let consumed: Vec<(u8, u8)> = simplecan
        .nodes
        .iter()
        .flat_map(|(&id, node)| node.consumed.iter().map(move |c| (id, c.sc_id)))
        .collect();
    let mut net = ScDualNetwork::new(bit_rate, &ids);
    net.configure_from_file_and_start(file)?;
    let until = net.now + Duration::from_millis(1500);
    let all_on = |net: &ScDualNetwork| {
        !consumed.is_empty() && consumed.iter().all(|&(id, sc)| net.output(id, sc) == 1)
    };
    while net.now < until && !all_on(&net) {
        net.run_for(Duration::from_millis(1));
    }
    for &(id, sc_id) in &consumed {
        if net.output(id, sc_id) != 1 {
            return Err(format!(
                "node {id}'s output for SC-ID {sc_id:02X}h is not on 1.5 s after the start (faults {:?})",
                net.faults(id)
            ));
        }
    }
    Ok(net)
}

/// The emergency stop of `file`'s network: node `producer`'s input pressed at `phases`
/// instants spread evenly over one cycle (N ms) after the start, each on a network of its
/// own ([`running_from_file`]); for each the time from the press until node `consumer`'s
/// output for `sc_id` is off (µs). A consumer that latches a fault instead of taking the
/// value 0 is an error.
pub fn emergency_stop_reactions(
    file: &safety_config::network_file::Network,
    bit_rate: u32,
    (producer, consumer, sc_id): (u8, u8, u8),
    phases: u64,
) -> Result<Vec<u64>, String> {
    let cycle_us = file
        .simplecan
        .as_ref()
        .map(|simplecan| u64::from(simplecan.slots_per_cycle) * 1000)
        .ok_or("the network file has no [simplecan] section")?;
    let mut reactions = Vec::new();
    for phase in 0..phases {
        let mut net = running_from_file(file, bit_rate)?;
        net.run_for(Duration::from_micros(phase * cycle_us / phases));
        let pressed = net.now;
        net.set_inputs(producer, 0);
        net.run_for(Duration::from_micros(10 * cycle_us));
        let off = net.output_off(consumer, sc_id, pressed).ok_or(format!(
            "node {consumer}'s output stayed on after the press"
        ))?;
        if net.faults(consumer) != [None, None] {
            return Err(format!(
                "node {consumer} latched a fault instead of taking the value 0: {:?}",
                net.faults(consumer)
            ));
        }
        reactions.push(off.saturating_since(pressed).as_micros());
    }
    Ok(reactions)
}

/// This network's devices as the calculators describe a device
/// (`safety_config::calc::sfrt::DeviceTiming`): the input is the object itself (no
/// sampling, no contact skew), every step takes no time, no output stage; the link between
/// the channels is this simulation's, [`LINK_BYTE_TIME`] a byte.
pub fn calculator_timing() -> safety_config::calc::sfrt::DeviceTiming {
    safety_config::calc::sfrt::DeviceTiming {
        input_sample_us: 0,
        contact_skew_us: 0,
        link_byte_us: LINK_BYTE_TIME.as_micros(),
        processing_us: 0,
        output_us: 0,
    }
}

/// As [`emergency_stop_reactions`] for one press, 2.5 ms after the start, with every packet
/// of `sc_id` lost by both of the consumer's controllers from the press on: the time until
/// the consumer's output is off (µs), which its safety timeout sets (SC_REQ_20).
pub fn reaction_with_every_packet_lost(
    file: &safety_config::network_file::Network,
    bit_rate: u32,
    (producer, consumer, sc_id): (u8, u8, u8),
) -> Result<u64, String> {
    let mut net = running_from_file(file, bit_rate)?;
    net.run_for(Duration::from_micros(2_500));
    let pressed = net.now;
    let every_packet = Match {
        id: Some(u16::from(sc_id)),
        from: None,
        after: pressed,
        count: None,
    };
    for side in [Side::A, Side::B] {
        net.inject_receive(consumer, side, every_packet, Fault::Drop);
    }
    net.set_inputs(producer, 0);
    net.run_for(Duration::from_millis(1000));
    let off = net.output_off(consumer, sc_id, pressed).ok_or(format!(
        "node {consumer}'s output stayed on with every packet lost"
    ))?;
    Ok(off.saturating_since(pressed).as_micros())
}
