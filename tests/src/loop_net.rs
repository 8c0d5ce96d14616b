//! Dual-channel nodes whose channels run the boards' own loop
//! ([`dual_channel::channel_loop::ChannelLoop`]) over a simulated driver: the receive FIFOs
//! and acceptance filters of a bxCAN (two FIFOs of three frames, the bank layout the
//! hardware adapter programs), the link, the pins, the clock. Under simulated time,
//! deterministic, on the same bus model as the other simulations.
//!
//! [`DualNetwork`](crate::dual::DualNetwork) drives the channel runtimes directly and stays
//! the network of the campaigns and the system tests; this one checks what only the loop
//! does: filters, receive queues, input sampling, output pins. Its channels' protocol is the
//! SRDO table unless said otherwise ([`LoopNetwork<P>`], P a [`ChannelProtocol`]): with
//! [`SimpleCanLoopNetwork`] the cores run SimpleCAN beside the SRDOs, and each controller
//! confirms its frames to its loop when they have been on the bus ([`Driver::transmitted`]).

use crate::bus::{Bus, Delivery, ORDERED_BY_IDENTIFIER};
use crate::dual::{B_INPUTS, LINK_PERIOD, NETWORK_FILE};
use crate::network::device_config;
use crate::tool_bus::{Simulation, client};
use channel_a::role::ChannelA;
use channel_b::role::ChannelB;
use dual_channel::channel_loop::{ChannelLoop, Driver, Pins, QueueFull, Received};
use dual_channel::filters::{AcceptanceList, BankLayout, CAN1_BANKS, Fifo, bank_layout};
use dual_channel::runtime::{ChannelEvent, ChannelProtocol, Runtime};
use safety_config::ToolError;
use safety_config::network_file;
use safety_config::procedure::{self, Quiet};
use shared::canopen::lss::BitRate;
use shared::canopen::nmt::{self, NmtCommand, NmtState};
use shared::canopen::storage::RamFlash;
use shared::node::{SrdoAndSimpleCan, SrdoTable};
use shared::{CanFrame, Duration, Instant};
use std::collections::VecDeque;

/// Frames one bxCAN receive FIFO holds (RM0090 32.7.5).
pub const FIFO_DEPTH: usize = 3;

/// The device's pins, as the firmware images have them.
pub const PINS: Pins = Pins {
    inputs: &safety_device::INPUT_PINS,
    outputs: &safety_device::OUTPUT_PINS,
};

/// What the simulated controller's filters do.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Filtering {
    /// The banks the loop asks for, as the hardware adapter programs them.
    Banks,
    /// Every frame into FIFO 0 (the board layer before it had filters).
    AcceptAll,
}

/// A channel's board under simulation.
#[derive(Clone)]
pub struct SimDriver {
    now: Instant,
    filtering: Filtering,
    banks: Option<BankLayout>,
    fifos: [VecDeque<CanFrame>; 2],
    overrun: bool,
    /// The controller went bus-off (and recovered): the next receive reports it.
    pub bus_off: bool,
    sent: Vec<CanFrame>,
    /// Frames of this controller that have been on the bus, not yet reported to the loop.
    confirmed: VecDeque<CanFrame>,
    /// The controller reports its frames on the bus ([`Driver::transmitted`]); `false`: a
    /// controller that never does (the frames still go out).
    pub confirms: bool,
    /// Every withdrawal the loop asked of the controller: (time, identifier). The bus model
    /// cannot take back a queued frame; the log is what a test checks.
    pub aborts: Vec<(Instant, u16)>,
    link_out: Vec<u8>,
    link_in: VecDeque<u8>,
    /// The processor was held (a flash program, as a store's): the next
    /// [`Driver::link_deaf`] reports it, once.
    pub deaf: bool,
    /// What the loop answered to each [`Driver::link_deaf`]: whether the runtime restarted
    /// its link receiver.
    pub restarts: Vec<bool>,
    /// The input pin's level.
    pub input: bool,
    /// The output pin's level.
    pub output: bool,
    /// Every event the channel reported.
    pub events: Vec<(Instant, ChannelEvent)>,
    /// Frames the controller's filters rejected.
    pub rejected: u64,
    /// Frames lost because their FIFO was full.
    pub lost: u64,
    /// Each output pin change: (time, level).
    pub output_changes: Vec<(Instant, bool)>,
    /// The input pin as the loop read it: each run of equal readings as (first reading,
    /// last reading, level).
    pub readings: Vec<(Instant, Instant, bool)>,
    /// Every frame the loop handed to the controller, and when.
    pub handed: Vec<(Instant, CanFrame)>,
    /// Every bit-rate switch the loop asked of the controller ([`Driver::switch_bit_rate`]),
    /// and when. The bus model runs at one rate: the log is what a test checks.
    pub switched: Vec<(Instant, BitRate)>,
}

impl SimDriver {
    fn new(filtering: Filtering) -> Self {
        SimDriver {
            now: Instant::ZERO,
            filtering,
            banks: None,
            fifos: [VecDeque::new(), VecDeque::new()],
            overrun: false,
            bus_off: false,
            sent: Vec::new(),
            confirmed: VecDeque::new(),
            confirms: true,
            aborts: Vec::new(),
            link_out: Vec::new(),
            link_in: VecDeque::new(),
            deaf: false,
            restarts: Vec::new(),
            input: false,
            output: false,
            events: Vec::new(),
            rejected: 0,
            lost: 0,
            output_changes: Vec::new(),
            readings: Vec::new(),
            handed: Vec::new(),
            switched: Vec::new(),
        }
    }

    /// The controller receives `frame` from the bus: filtered, then into its FIFO, or lost
    /// with the overrun flag set when the FIFO is full.
    fn deliver(&mut self, frame: CanFrame) {
        let fifo = match self.filtering {
            Filtering::AcceptAll => Some(Fifo::Srdo),
            // Before the loop programmed them the banks accept nothing.
            Filtering::Banks => self
                .banks
                .as_ref()
                .and_then(|banks| banks.fifo(frame.id().raw(), frame.is_remote())),
        };
        let Some(fifo) = fifo else {
            self.rejected += 1;
            return;
        };
        let queue = &mut self.fifos[fifo as usize];
        if queue.len() < FIFO_DEPTH {
            queue.push_back(frame);
        } else {
            self.overrun = true;
            self.lost += 1;
        }
    }

    fn waiting(&self) -> bool {
        self.fifos.iter().any(|fifo| !fifo.is_empty())
            || self.overrun
            || self.bus_off
            || !self.link_in.is_empty()
            || !self.confirmed.is_empty()
    }
}

impl SimDriver {
    /// `bytes` arrive on this channel's link before the next service, as if the other
    /// channel had sent them (a frame damaged on the way, for tests).
    pub fn link_arrives(&mut self, bytes: &[u8]) {
        self.link_in.extend(bytes);
    }
}

impl Driver for SimDriver {
    fn now(&mut self) -> Instant {
        self.now
    }
    fn transmit(&mut self, frame: &CanFrame) -> Result<(), QueueFull> {
        self.sent.push(*frame);
        self.handed.push((self.now, *frame));
        Ok(())
    }
    fn receive(&mut self) -> Option<Received> {
        if std::mem::take(&mut self.bus_off) {
            return Some(Received::BusOff);
        }
        if std::mem::take(&mut self.overrun) {
            return Some(Received::Overrun);
        }
        // FIFO 0 first, as the hardware adapter reads them.
        self.fifos
            .iter_mut()
            .find_map(VecDeque::pop_front)
            .map(Received::Frame)
    }
    fn apply_filters(&mut self, list: &AcceptanceList) {
        self.banks = Some(bank_layout(list, CAN1_BANKS).expect("the banks hold any list"));
    }
    fn link_write(&mut self, bytes: &[u8]) -> Result<(), QueueFull> {
        self.link_out.extend_from_slice(bytes);
        Ok(())
    }
    fn link_deaf(&mut self) -> bool {
        core::mem::take(&mut self.deaf)
    }
    fn link_restarted(&mut self, restarted: bool) {
        self.restarts.push(restarted);
    }
    fn link_read(&mut self, buf: &mut [u8]) -> usize {
        let count = buf.len().min(self.link_in.len());
        for (slot, byte) in buf.iter_mut().zip(self.link_in.drain(..count)) {
            *slot = byte;
        }
        count
    }
    fn input(&mut self, _pin: usize) -> bool {
        match self.readings.last_mut() {
            Some((_, last, level)) if *level == self.input => *last = self.now,
            _ => self.readings.push((self.now, self.now, self.input)),
        }
        self.input
    }
    fn set_output(&mut self, _pin: usize, level: bool) {
        if level != self.output || self.output_changes.is_empty() {
            self.output_changes.push((self.now, level));
        }
        self.output = level;
    }
    fn event(&mut self, event: &ChannelEvent) {
        self.events.push((self.now, *event));
    }
    fn switch_bit_rate(&mut self, rate: BitRate) {
        self.switched.push((self.now, rate));
    }
    fn transmitted(&mut self) -> Option<CanFrame> {
        self.confirmed.pop_front()
    }
    fn abort(&mut self, id: shared::CanId) {
        self.aborts.push((self.now, id.raw()));
    }
}

/// Channel A's runtime, with the protocol `P`.
pub type RuntimeA<P = SrdoTable<4>> = Runtime<RamFlash<8192>, ChannelA, 4, P>;
/// Channel B's runtime, with the protocol `P`.
pub type RuntimeB<P = SrdoTable<4>> = Runtime<RamFlash<8192>, ChannelB, 4, P>;

/// The SimpleCAN channels' protocol: 4 SRDOs and 4 SDD entries beside them, as
/// [`crate::simplecan_dual`]'s nodes.
pub type SimpleCanProtocol = SrdoAndSimpleCan<4, 4>;

/// A loop network whose cores run SimpleCAN beside the SRDOs.
pub type SimpleCanLoopNetwork = LoopNetwork<SimpleCanProtocol>;

/// One node: both channels' runtimes, their loops and their boards.
#[derive(Clone)]
pub struct LoopNode<P: ChannelProtocol<4> = SrdoTable<4>> {
    /// Node-ID.
    pub id: u8,
    /// Channel A.
    pub a: RuntimeA<P>,
    /// Channel B.
    pub b: RuntimeB<P>,
    /// Channel A's loop, channel B's loop.
    pub loops: [ChannelLoop; 2],
    /// Channel A's board, channel B's board.
    pub drivers: [SimDriver; 2],
    deadlines: [Instant; 2],
    last_service: [Instant; 2],
}

/// The network: participant 0 is the tool, node `i`'s channels are `2i + 1` and `2i + 2`,
/// the babbler (if any) comes last.
#[derive(Clone)]
pub struct LoopNetwork<P: ChannelProtocol<4> = SrdoTable<4>> {
    /// Simulated time.
    pub now: Instant,
    /// The bus.
    pub bus: Bus,
    /// The nodes.
    pub nodes: Vec<LoopNode<P>>,
    in_flight: Vec<Delivery>,
    /// Every frame on the bus, as delivered: (time, frame, sender).
    pub trace: Vec<(Instant, CanFrame, usize)>,
    /// A participant that puts this frame on the bus whenever nobody else has one waiting,
    /// so the bus is never idle (100 % load), yet every other frame gets on it.
    pub babbler: Option<CanFrame>,
    /// A channel's loop gets to its queues at most this often (the time one wake-up of a
    /// busy loop takes); zero: at once.
    pub service_interval: Duration,
}

impl<P: ChannelProtocol<4>> LoopNetwork<P> {
    /// Nodes with these node-IDs, powered on at t = 0, their controllers filtering so.
    pub fn new(bit_rate: u32, ids: &[u8], filtering: Filtering) -> Self {
        let nodes = ids
            .iter()
            .map(|&id| LoopNode {
                id,
                a: Runtime::new(
                    device_config(id, "loop node, channel A"),
                    RamFlash::new(),
                    ChannelA::default(),
                    Instant::ZERO,
                    LINK_PERIOD,
                )
                .expect("valid device"),
                b: Runtime::new(
                    device_config(id, "loop node, channel B"),
                    RamFlash::new(),
                    ChannelB::new(&B_INPUTS).expect("valid inputs"),
                    Instant::ZERO,
                    LINK_PERIOD,
                )
                .expect("valid device"),
                loops: [ChannelLoop::new(PINS), ChannelLoop::new(PINS)],
                drivers: [SimDriver::new(filtering), SimDriver::new(filtering)],
                deadlines: [Instant::ZERO; 2],
                last_service: [Instant::ZERO; 2],
            })
            .collect::<Vec<_>>();
        let mut bus = Bus::new(bit_rate, 2 + 2 * nodes.len());
        bus.set_transmit_mailboxes(ORDERED_BY_IDENTIFIER);
        LoopNetwork {
            now: Instant::ZERO,
            bus,
            nodes,
            in_flight: Vec::new(),
            trace: Vec::new(),
            babbler: None,
            service_interval: Duration::ZERO,
        }
    }

    fn babbler_participant(&self) -> usize {
        1 + 2 * self.nodes.len()
    }

    /// The node with node-ID `id`.
    pub fn node(&self, id: u8) -> &LoopNode<P> {
        self.nodes.iter().find(|node| node.id == id).expect("node")
    }

    /// The node with node-ID `id`, mutably.
    pub fn node_mut(&mut self, id: u8) -> &mut LoopNode<P> {
        self.nodes
            .iter_mut()
            .find(|node| node.id == id)
            .expect("node")
    }

    /// Runs until `end`.
    pub fn run_until(&mut self, end: Instant) {
        loop {
            self.feed_babbler();
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

    fn feed_babbler(&mut self) {
        let Some(frame) = self.babbler else {
            return;
        };
        let babbler = self.babbler_participant();
        let others_waiting = (0..babbler).any(|from| self.bus.queued(from) > 0);
        if !others_waiting && self.bus.queued(babbler) == 0 {
            self.bus.send(babbler, frame);
        }
    }

    fn due(&self, index: usize, side: usize) -> Instant {
        let node = &self.nodes[index];
        let driver = &node.drivers[side];
        let waiting = if driver.waiting() {
            node.last_service[side] + self.service_interval
        } else {
            Instant::NEVER
        };
        node.deadlines[side].min(waiting)
    }

    fn next_activity(&self) -> Instant {
        let deliveries = self.in_flight.iter().map(|delivery| delivery.at);
        let channels =
            (0..self.nodes.len()).flat_map(|index| [self.due(index, 0), self.due(index, 1)]);
        deliveries
            .chain(channels)
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
            for (index, node) in self.nodes.iter_mut().enumerate() {
                for side in 0..2 {
                    if 1 + 2 * index + side != delivery.from {
                        node.drivers[side].deliver(delivery.frame);
                    } else if node.drivers[side].confirms {
                        // One transceiver: the sender never receives its own frame, its
                        // controller confirms it (a transmit mailbox completed).
                        node.drivers[side].confirmed.push_back(delivery.frame);
                    }
                }
            }
        }
        // Link bytes reach the other channel at once; a few rounds settle what they cause.
        for _ in 0..8 {
            let mut serviced = false;
            for index in 0..self.nodes.len() {
                for side in 0..2 {
                    if self.due(index, side) <= now {
                        self.service(index, side);
                        serviced = true;
                    }
                }
            }
            if !serviced {
                break;
            }
        }
        if self.bus.next_start(now) == Some(now) {
            let deliveries = self.bus.arbitrate(now);
            self.in_flight.extend(deliveries);
        }
    }

    fn service(&mut self, index: usize, side: usize) {
        let now = self.now;
        let node = &mut self.nodes[index];
        let driver = &mut node.drivers[side];
        driver.now = now;
        let deadline = match side {
            0 => node.loops[0].service(&mut node.a, driver),
            _ => node.loops[1].service(&mut node.b, driver),
        };
        // `now` itself: frames were left in the queue; the loop comes back a moment later.
        node.deadlines[side] = deadline.max(now + Duration::from_micros(1));
        node.last_service[side] = now;
        let sent = std::mem::take(&mut node.drivers[side].sent);
        let link = std::mem::take(&mut node.drivers[side].link_out);
        // The other channel takes them when its loop next gets to its queues.
        node.drivers[1 - side].link_in.extend(link);
        for frame in sent {
            self.bus.send(1 + 2 * index + side, frame);
        }
    }

    /// Sets the input pin of both channels of node `id`.
    pub fn press(&mut self, id: u8, level: bool) {
        for driver in &mut self.node_mut(id).drivers {
            driver.input = level;
        }
    }

    /// Sends an NMT command from the tool.
    pub fn nmt(&mut self, command: NmtCommand, target: u8) {
        self.bus.send(0, nmt::command_frame(command, target));
    }

    /// Runs until every node's channel A is Pre-operational (booted), at most 100 ms.
    fn wait_for_boot(&mut self) {
        for _ in 0..100 {
            if self
                .nodes
                .iter()
                .all(|node| node.a.node().nmt_state() == NmtState::PreOperational)
            {
                break;
            }
            self.run_for(Duration::from_millis(1));
        }
    }

    /// Configures node 1 to produce and node 33 to consume SRDO 1 ([`NETWORK_FILE`]) by the
    /// tool's procedure, and starts the network with node 1's contacts closed.
    pub fn configure_and_start(&mut self) -> Result<(), ToolError> {
        self.wait_for_boot();
        let file = network_file::parse(NETWORK_FILE, "dual::NETWORK_FILE")?;
        let mut quiet = Quiet {
            accept_identity: false,
        };
        let ids: Vec<u8> = self.nodes.iter().map(|node| node.id).collect();
        for spec in file.nodes.iter().filter(|spec| ids.contains(&spec.id)) {
            procedure::configure_node(&mut client(self), spec, &mut quiet)?;
        }
        self.press(1, true);
        self.nmt(NmtCommand::Start, 0);
        Ok(())
    }

    /// Configures each node with its SimpleCAN configuration by SDO as a tool does
    /// ([`crate::simplecan_net::configure`]), closes every node's contacts and starts the
    /// network.
    pub fn configure_simplecan_and_start(
        &mut self,
        configs: &[(u8, crate::simplecan_net::ScConfig)],
    ) -> Result<(), String> {
        self.wait_for_boot();
        for (id, config) in configs {
            crate::simplecan_net::configure(self, *id, config)?;
        }
        let ids: Vec<u8> = self.nodes.iter().map(|node| node.id).collect();
        for id in ids {
            self.press(id, true);
        }
        self.nmt(NmtCommand::Start, 0);
        Ok(())
    }
}

impl<P: ChannelProtocol<4>> Simulation for LoopNetwork<P> {
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
        LoopNetwork::<P>::run_until(self, end);
    }
}
