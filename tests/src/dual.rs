//! Dual-channel nodes on the simulated bus (EN 50325-5 Annex A.4, Model III): each node is
//! channel A and channel B, each a [`Runtime`] around its own protocol core with its own CAN
//! controller on the bus and a serial link between them. Faults can be injected on the bus, on
//! the link, and into one channel's view of the bus.
//!
//! This is the host twin of the emulated network: the same channel code as the firmware, under
//! simulated time, deterministic.

use crate::bus::{Bus, Delivery, Fault, Injection, Match, ORDERED_BY_IDENTIFIER};
use crate::network::device_config;
use crate::tool_bus::{client, sdo_error};
use channel_a::role::ChannelA;
use channel_b::role::ChannelB;
use dual_channel::runtime::{ChannelEvent, Io, Runtime};
use safety_config::ToolError;
use safety_config::network_file;
use safety_config::procedure::{self, Quiet};
use shared::canopen::nmt::{self, NmtCommand};
use shared::canopen::od::Address;
use shared::canopen::sdo_client::ClientError;
use shared::canopen::storage::RamFlash;
use shared::safety::types::SrdoNumber;
use shared::{CanFrame, Duration, Instant};
use std::collections::VecDeque;

/// A link heartbeat every 10 ms: five per SCT of 50 ms (the link supervision asks for at least four).
pub const LINK_PERIOD: Duration = Duration::from_millis(10);
/// Time per byte on the link USART (1 Mbit/s, 10 bits per byte).
pub const LINK_BYTE_TIME: Duration = Duration::from_micros(10);

/// Channel A of a simulated node.
pub type ChannelARuntime = Runtime<RamFlash<8192>, ChannelA, 4>;
/// Channel B of a simulated node.
pub type ChannelBRuntime = Runtime<RamFlash<8192>, ChannelB, 4>;

/// What one channel handed out during one call.
#[derive(Default)]
struct Out {
    frames: Vec<CanFrame>,
    link: Vec<u8>,
    events: Vec<ChannelEvent>,
    outputs: Vec<(u8, u64)>,
}

impl Io for Out {
    fn transmit(&mut self, frame: CanFrame) {
        self.frames.push(frame);
    }
    fn link(&mut self, bytes: &[u8]) {
        self.link.extend_from_slice(bytes);
    }
    fn output(&mut self, srdo: SrdoNumber, data: u64) {
        self.outputs.push((srdo.get(), data));
    }
    fn event(&mut self, event: ChannelEvent) {
        self.events.push(event);
    }
}

/// One direction of a link: bytes in flight with their arrival times.
#[derive(Default)]
struct Wire {
    bytes: VecDeque<(Instant, u8)>,
    busy_until: Instant,
}

/// Faults on one node's link.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkFaults {
    /// Nothing gets through, either way.
    pub cut: bool,
    /// The next byte from A to B gets this bit mask XOR-ed into it.
    pub corrupt_next_a_to_b: Option<u8>,
    /// Extra latency of every byte, both ways (a slow link, as under emulation).
    pub latency: Duration,
}

/// One channel's time base against simulated time: from the anchor on it runs `ppm` parts
/// per million fast (negative: slow). The default is simulated time itself.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ChannelClock {
    anchor_global: u64,
    anchor_local: u64,
    ppm: i64,
}

impl ChannelClock {
    /// The channel's time at simulated time `global`.
    pub fn local(&self, global: Instant) -> Instant {
        if global == Instant::NEVER {
            return global;
        }
        let elapsed = i128::from(global.as_micros().saturating_sub(self.anchor_global));
        let scaled = elapsed * (1_000_000 + i128::from(self.ppm)) / 1_000_000;
        Instant::from_micros(self.anchor_local + scaled.max(0) as u64)
    }

    /// The first simulated time at which the channel's time has reached `local` (rounded
    /// up, so a deadline is never polled before it is due in the channel's time).
    pub fn global(&self, local: Instant) -> Instant {
        if local == Instant::NEVER || self.ppm == 0 && self.anchor_global == self.anchor_local {
            return local;
        }
        let ahead = i128::from(local.as_micros().saturating_sub(self.anchor_local));
        let rate = 1_000_000 + i128::from(self.ppm);
        let elapsed = (ahead * 1_000_000 + rate - 1) / rate;
        Instant::from_micros(self.anchor_global + elapsed as u64)
    }

    /// From simulated time `now` on, the channel's clock runs `ppm` parts per million fast.
    pub fn set_rate(&mut self, now: Instant, ppm: i64) {
        self.anchor_local = self.local(now).as_micros();
        self.anchor_global = now.as_micros();
        self.ppm = ppm.max(-999_999);
    }
}

/// `frame` as channel `side`'s controller receives it at `now`, after the receive faults
/// injected into that channel's path (`faults`, each counted as it applies): `None` when a
/// fault takes it away, a delayed frame put into `held_back` for later. One place for every
/// dual-channel network of this crate (SRDOs here, SimpleCAN in `crate::simplecan_dual`).
pub(crate) fn through_receive_faults(
    faults: &mut [(Side, Injection)],
    held_back: &mut Vec<(Instant, Side, CanFrame)>,
    side: Side,
    frame: CanFrame,
    now: Instant,
) -> Option<CanFrame> {
    let mut frame = frame;
    for (fault_side, injection) in faults.iter_mut() {
        let matches = *fault_side == side
            && now >= injection.when.after
            && injection.when.id.is_none_or(|id| id == frame.id().raw())
            && injection
                .when
                .count
                .is_none_or(|count| injection.applied < count);
        if !matches {
            continue;
        }
        injection.applied += 1;
        match injection.fault {
            Fault::Drop | Fault::Mute => return None,
            Fault::Corrupt { byte, mask } => {
                let mut data = *frame.raw_data();
                if let Some(target) = data.get_mut(byte) {
                    *target ^= mask;
                }
                frame = CanFrame::from_parts(frame.id(), frame.dlc(), data).ok()?;
            }
            Fault::Delay(delay) => {
                held_back.push((now + delay, side, frame));
                return None;
            }
            Fault::Repeat | Fault::Reorder => {}
        }
    }
    Some(frame)
}

/// Which channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// Channel A.
    A,
    /// Channel B.
    B,
}

/// One simulated dual-channel node.
pub struct DualNode {
    /// Node-ID.
    pub id: u8,
    /// Channel A.
    pub a: ChannelARuntime,
    /// Channel B.
    pub b: ChannelBRuntime,
    a_to_b: Wire,
    b_to_a: Wire,
    deadlines: [Instant; 2],
    /// Faults on this node's link.
    pub link_faults: LinkFaults,
    /// Frames this channel's CAN controller receives are altered by these faults (a fault in
    /// one channel's receive path only). [`Fault::Delay`] here holds a frame back from that
    /// channel alone: its loop handles the frame later than the other channel's does.
    pub receive_faults: Vec<(Side, Injection)>,
    /// Frames held back by a receive delay: (when the channel handles it, which channel, frame).
    held_back: Vec<(Instant, Side, CanFrame)>,
    /// Each channel's time base (channel A, channel B): a clock too fast or too slow.
    pub clocks: [ChannelClock; 2],
}

impl DualNode {
    /// Both channels of node `id` powered on at `now` with these storage media (channel A's,
    /// channel B's).
    fn powered_on(id: u8, [flash_a, flash_b]: [RamFlash<8192>; 2], now: Instant) -> Self {
        DualNode {
            id,
            a: Runtime::new(
                device_config(id, "dual node, channel A"),
                flash_a,
                ChannelA::default(),
                now,
                LINK_PERIOD,
            )
            .expect("valid device"),
            b: Runtime::new(
                device_config(id, "dual node, channel B"),
                flash_b,
                ChannelB::new(&B_INPUTS).expect("valid inputs"),
                now,
                LINK_PERIOD,
            )
            .expect("valid device"),
            a_to_b: Wire::default(),
            b_to_a: Wire::default(),
            deadlines: [now; 2],
            link_faults: LinkFaults::default(),
            receive_faults: Vec::new(),
            held_back: Vec::new(),
            clocks: [ChannelClock::default(); 2],
        }
    }
}

/// The network: participant 0 is the tool; node `i`'s channel A is participant `2i + 1`,
/// channel B `2i + 2`.
pub struct DualNetwork {
    /// Simulated time.
    pub now: Instant,
    /// The bus.
    pub bus: Bus,
    /// The nodes.
    pub nodes: Vec<DualNode>,
    in_flight: Vec<Delivery>,
    /// Everything the channels reported: (time, node-ID, channel, event).
    pub log: Vec<(Instant, u8, Side, ChannelEvent)>,
    /// Every frame on the bus, as delivered.
    pub trace: Vec<(Instant, CanFrame, usize)>,
    /// Every change of a channel's output: (time, node-ID, channel, receive SRDO, value).
    pub outputs: Vec<(Instant, u8, Side, u8, u64)>,
    /// A wrapper around the bus (the campaigns' seeded faults, `crate::campaign`): every
    /// delivery the bus makes goes through it, and what it returns is delivered instead
    /// (altered, dropped, delayed, repeated, or with frames of its own added).
    pub tap: Option<Box<dyn FnMut(Delivery) -> Vec<Delivery>>>,
}

/// The network [`DualNetwork::configure_and_start`] configures: node 1's pre-defined SRDO 1
/// (EN 50325-5 Table 5: transmit on 101h/102h, refresh time 25 ms) and node 33 consuming it
/// (SCT 50 ms, its pre-defined value; SRVT 20 ms).
pub const NETWORK_FILE: &str = r#"
[bus]
sdo_timeout_ms = 1000

[[node]]
id = 1
name = "emergency stop"
identity = { vendor = 0xABC, product = 0x304, revision = 1, serial = 1 }

[[node.srdo]]
number = 1
direction = "transmit"
refresh_time_ms = 25
srvt_ms = 20
cob_ids = [0x101, 0x102]
mapping = ["input", "input_inverted"]

[[node]]
id = 33
name = "safe output"
identity = { vendor = 0xABC, product = 0x304, revision = 1, serial = 33 }

[[node.srdo]]
number = 1
direction = "receive"
sct_ms = 50
srvt_ms = 20
cob_ids = [0x101, 0x102]
mapping = ["output", "output_inverted"]
"#;

/// Channel B of the demo device samples the same input object as channel A (its own contact).
pub const B_INPUTS: [(u16, u8, u8); 1] = [(0x6000, 1, 1)];

impl DualNetwork {
    /// Dual-channel nodes with these node-IDs on a bus at `bit_rate`, powered on at t = 0.
    pub fn new(bit_rate: u32, ids: &[u8]) -> Self {
        let nodes: Vec<DualNode> = ids
            .iter()
            .map(|&id| DualNode::powered_on(id, [RamFlash::new(), RamFlash::new()], Instant::ZERO))
            .collect();
        // Each channel's controller sends by identifier, as `board::hw` queues its frames
        // (`dual_channel::transmit_queue`); each sends one half of an SRDO, so a pair keeps
        // its order.
        let mut bus = Bus::new(bit_rate, 1 + 2 * nodes.len());
        bus.set_transmit_mailboxes(ORDERED_BY_IDENTIFIER);
        DualNetwork {
            now: Instant::ZERO,
            bus,
            nodes,
            in_flight: Vec::new(),
            log: Vec::new(),
            trace: Vec::new(),
            outputs: Vec::new(),
            tap: None,
        }
    }

    /// The node with node-ID `id`.
    pub fn node(&self, id: u8) -> &DualNode {
        self.nodes
            .iter()
            .find(|node| node.id == id)
            .expect("a node with this ID")
    }

    /// The node with node-ID `id`, mutably.
    pub fn node_mut(&mut self, id: u8) -> &mut DualNode {
        self.nodes
            .iter_mut()
            .find(|node| node.id == id)
            .expect("a node with this ID")
    }

    fn index(&self, id: u8) -> usize {
        self.nodes
            .iter()
            .position(|node| node.id == id)
            .expect("a node with this ID")
    }

    /// Node `id` is switched off and on again now with node-ID `new_id` (its node-ID
    /// switches were changed): both channels restart on the same bus participants, with the
    /// parameters each had stored (`keep_storage`) or with erased storage (the defaults).
    /// What its controllers still had queued and its link carried is lost; its receive
    /// faults and clocks start afresh.
    pub fn repower(&mut self, id: u8, new_id: u8, keep_storage: bool) {
        let index = self.index(id);
        let old = &self.nodes[index];
        let flash = if keep_storage {
            [old.a.node().flash().clone(), old.b.node().flash().clone()]
        } else {
            [RamFlash::new(), RamFlash::new()]
        };
        for side in [Side::A, Side::B] {
            self.bus.leave(participant(index, side));
        }
        self.nodes[index] = DualNode::powered_on(new_id, flash, self.now);
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
                        continue;
                    }
                    let Some(frame) = self.received_by(index, side, delivery.frame, now) else {
                        continue;
                    };
                    self.with_channel(index, side, |now, a, b, out| match (a, b) {
                        (Some(a), _) => a.on_frame(now, &frame, out),
                        (_, Some(b)) => b.on_frame(now, &frame, out),
                        _ => {}
                    });
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
                self.with_channel(index, side, |now, a, b, out| match (a, b) {
                    (Some(a), _) => a.on_frame(now, &frame, out),
                    (_, Some(b)) => b.on_frame(now, &frame, out),
                    _ => {}
                });
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
            match self.tap.as_mut() {
                Some(tap) => self.in_flight.extend(deliveries.into_iter().flat_map(tap)),
                None => self.in_flight.extend(deliveries),
            }
        }
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
            let at = self.nodes[index].clocks[side as usize].local(at);
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
        action: impl FnOnce(
            Instant,
            Option<&mut ChannelARuntime>,
            Option<&mut ChannelBRuntime>,
            &mut Out,
        ),
    ) {
        let mut out = Out::default();
        let node = &mut self.nodes[index];
        let clock = node.clocks[side as usize];
        // The channel runs on its own time base.
        let now = clock.local(self.now);
        let deadline = match side {
            Side::A => {
                action(now, Some(&mut node.a), None, &mut out);
                node.a.poll(now, &mut out)
            }
            Side::B => {
                // The simulated contacts are read continuously: channel B's sample is as old
                // as the last change, never older than now.
                node.b.inputs_sampled(now, &mut out);
                action(now, None, Some(&mut node.b), &mut out);
                node.b.poll(now, &mut out)
            }
        };
        node.deadlines[side as usize] = clock.global(deadline);
        let now = self.now;
        let id = node.id;
        if !out.link.is_empty() && !node.link_faults.cut {
            let corrupt = match side {
                Side::A => node.link_faults.corrupt_next_a_to_b.take(),
                Side::B => None,
            };
            let wire = match side {
                Side::A => &mut node.a_to_b,
                Side::B => &mut node.b_to_a,
            };
            let mut at = wire.busy_until.max(now + node.link_faults.latency);
            for (position, &byte) in out.link.iter().enumerate() {
                at = at + LINK_BYTE_TIME;
                let byte = match corrupt {
                    Some(mask) if position == 0 => byte ^ mask,
                    _ => byte,
                };
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
        for (srdo, value) in out.outputs {
            self.outputs.push((now, id, side, srdo, value));
        }
    }

    /// Both channels of node `id` sample their safety input: A reads `a`, B reads `b`.
    pub fn set_inputs(&mut self, id: u8, a: u8, b: u8) {
        let index = self.index(id);
        let plain = Address::new(0x6000, 1);
        let inverted = Address::new(0x6001, 1);
        self.with_channel(index, Side::A, |now, channel, _, out| {
            if let Some(channel) = channel {
                channel
                    .set_input(now, plain, inverted, &[a], out)
                    .expect("input object");
            }
        });
        self.with_channel(index, Side::B, |now, _, channel, out| {
            if let Some(channel) = channel {
                channel
                    .set_input(now, plain, inverted, &[b], out)
                    .expect("input object");
            }
        });
    }

    /// The frames on the bus now (arbitrated, not yet delivered): (end, frame, sender).
    pub fn on_the_bus(&self) -> impl Iterator<Item = (Instant, CanFrame, usize)> + '_ {
        self.in_flight
            .iter()
            .map(|delivery| (delivery.at, delivery.frame, delivery.from))
    }

    /// One channel of node `id` samples its safety input as `value` (the other keeps its
    /// sample): one contact changing alone.
    pub fn set_input(&mut self, id: u8, side: Side, value: u8) {
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

    /// The effective output of node `id`: both channels' outputs in series (AND).
    pub fn output(&self, id: u8) -> u64 {
        let node = self.node(id);
        node.a.output(SrdoNumber::FIRST) & node.b.output(SrdoNumber::FIRST)
    }

    /// The tool sends an NMT command to `target` (0: all).
    pub fn nmt(&mut self, command: NmtCommand, target: u8) {
        self.bus.send(0, nmt::command_frame(command, target));
        self.run_for(Duration::from_millis(1));
    }

    /// A frame from a foreign device (the tool's participant): inserted, replayed, a second
    /// sender on a node's identifiers.
    pub fn send_foreign(&mut self, frame: CanFrame) {
        self.bus.send(0, frame);
    }

    /// Channel `side` of node `id`: its CAN controller goes bus-off now (ISO 11898-1 12.1.4.2:
    /// a transmit error counter above 255). It sends nothing more and receives nothing, and
    /// its runtime gets at once what the channel loop hands it when the board's driver
    /// reports the bus-off state (`dual_channel::channel_loop::Received::BusOff`, bxCAN's
    /// BOFF in CAN_ESR): [`Runtime::on_bus_off`]. The loop's own part (the driver's report
    /// turned into that call) is [`crate::loop_net`]'s to test.
    pub fn bus_off(&mut self, id: u8, side: Side) {
        let now = self.now;
        let index = self.index(id);
        self.inject(Match::all_from(participant(index, side), now), Fault::Mute);
        let everything = Match {
            id: None,
            from: None,
            after: now,
            count: None,
        };
        self.nodes[index]
            .receive_faults
            .push((side, Injection::new(everything, Fault::Drop)));
        self.with_channel(index, side, |_, a, b, out| match (a, b) {
            (Some(a), _) => a.on_bus_off(out),
            (_, Some(b)) => b.on_bus_off(out),
            _ => {}
        });
    }

    /// Adds a fault on the bus (every receiver sees it).
    pub fn inject(&mut self, when: Match, fault: Fault) {
        self.bus.inject(Injection::new(when, fault));
    }

    /// SDO download from the tool (the tool library's client, `safety_config::client`).
    pub fn write(&mut self, id: u8, address: Address, data: &[u8]) -> Result<(), ClientError> {
        client(self).write(id, address, data).map_err(sdo_error)
    }

    /// SDO upload from the tool (the tool library's client).
    pub fn read(&mut self, id: u8, address: Address) -> Result<Vec<u8>, ClientError> {
        client(self).read(id, address).map_err(sdo_error)
    }

    /// The tool reads SRDO 1 back, signs it with its own CRC, writes and reads back 0x13FF,
    /// and declares the configuration valid: `safety_config::procedure::sign_and_validate`.
    pub fn sign_and_validate(&mut self, id: u8) -> Result<(), ToolError> {
        procedure::sign_and_validate(&mut client(self), id, &[1]).map(|_| ())
    }

    /// Configures node 1 to produce and node 33 to consume SRDO 1 on 101h/102h
    /// ([`NETWORK_FILE`]) by the tool's whole procedure (EN 50325-5 8.3.1: identity, writes,
    /// read-back against the file, signatures, 0x13FE, store; `safety_config::procedure::
    /// configure_node`), and starts the network with both channels of node 1 reading input 1.
    pub fn configure_and_start(&mut self) -> Result<(), ToolError> {
        let file = network_file::parse(NETWORK_FILE, "dual::NETWORK_FILE")?;
        self.configure_and_start_with(&file)
    }

    /// Configures every node of this network that `file` lists by the tool's whole procedure
    /// (as [`DualNetwork::configure_and_start`] does with [`NETWORK_FILE`]), lets both
    /// channels of every node with a transmit SRDO read input 1, and starts the network.
    pub fn configure_and_start_with(
        &mut self,
        file: &network_file::Network,
    ) -> Result<(), ToolError> {
        // Both channels of every node come up together (the link first): wait for boot-up.
        for _ in 0..100 {
            if self.nodes.iter().all(|node| {
                node.a.node().nmt_state() == shared::canopen::nmt::NmtState::PreOperational
            }) {
                break;
            }
            self.run_for(Duration::from_millis(1));
        }
        let mut quiet = Quiet {
            accept_identity: false,
        };
        let ids: Vec<u8> = self.nodes.iter().map(|node| node.id).collect();
        for spec in file.nodes.iter().filter(|spec| ids.contains(&spec.id)) {
            procedure::configure_node(&mut client(self), spec, &mut quiet)?;
        }
        for spec in file.nodes.iter().filter(|spec| ids.contains(&spec.id)) {
            if spec.srdos.iter().any(|srdo| srdo.settings.direction == 1) {
                self.set_inputs(spec.id, 1, 1);
            }
        }
        self.nmt(NmtCommand::Start, 0);
        Ok(())
    }

    /// The first event at or after log position `since` from node `id` that `matches`.
    pub fn first_event(
        &self,
        since: usize,
        id: u8,
        matches: impl Fn(Side, &ChannelEvent) -> bool,
    ) -> Option<(Instant, Side, ChannelEvent)> {
        self.log[since..]
            .iter()
            .find(|(_, node, side, event)| *node == id && matches(*side, event))
            .map(|(at, _, side, event)| (*at, *side, *event))
    }
}

fn participant(index: usize, side: Side) -> usize {
    1 + 2 * index + side as usize
}
