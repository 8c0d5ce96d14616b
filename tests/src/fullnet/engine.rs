//! An event-driven simulation of dual-channel nodes on the simulated bus, fast enough for a
//! network of 127 nodes over an hour of bus time, that makes the same calls on the channel
//! runtimes as [`DualNetwork`](crate::dual::DualNetwork) at the same instants (a test runs
//! both on one scenario and compares the bus trace frame for frame).
//!
//! What makes it fast, without touching the protocol core or the channel code:
//!
//! - **Steps to the next deadline.** Channel deadlines, link frame ends and background senders
//!   are kept in binary heaps; a step handles only what is due, not every node.
//! - **Acceptance filtering.** A channel in Operational gets only the frames its core and role
//!   look at: NMT (000h), GFC (001h), its SDO request identifier (600h + node-ID) and the two
//!   identifiers of each SRDO it has configured, transmit or receive. Every other frame is
//!   ignored by the core (`Node::handle_frame` dispatches on exactly these) and by both roles
//!   (they look only at the node's transmit identifiers), which a bxCAN's identifier filters
//!   would do in hardware. The safety configuration cannot change in Operational (the objects
//!   are read-only there), and a channel outside Operational gets every frame. A channel not
//!   addressed by a frame but with a deadline due is polled as `DualNetwork` would poll it on
//!   that delivery.
//! - **Link bytes in one go.** The link decoder only collects bytes until the frame delimiter
//!   (00h); the bytes before it are handed over, each with its own arrival time, when the
//!   delimiter arrives, so a link message costs one step instead of one per byte.
//! - **No allocation per frame.** Scratch buffers are reused; nothing is logged unless asked.

use super::handoff::Handoff;
use crate::bus::{Bus, Delivery, ORDERED_BY_IDENTIFIER};
use crate::dual::{B_INPUTS, ChannelARuntime, ChannelBRuntime, LINK_BYTE_TIME, Side};
use crate::network::device_config;
use channel_a::role::ChannelA;
use channel_b::role::ChannelB;
use dual_channel::runtime::{ChannelEvent, Io, Role, Runtime};
use safety_config::transport::{Transport, TransportError};
use shared::canopen::nmt::{self, NmtCommand, NmtState};
use shared::canopen::od::Address;
use shared::canopen::storage::RamFlash;
use shared::safety::types::SrdoNumber;
use shared::{CanFrame, Duration, Instant};
use std::cmp::Reverse;
use std::collections::{BinaryHeap, VecDeque};

/// The number of CAN identifiers (11 bits).
const IDENTIFIERS: usize = 2048;

/// Bits of an [`EventHeap`] key below the instant: the number's.
const NUMBER_BITS: u32 = 16;

/// Events (an instant and a number: a channel or a sender), earliest first and, at one
/// instant, the lowest number first: the order of the tuple `(instant, number)`. Each entry
/// is one `u64`, the instant's microseconds above the number's 16 bits, so that the heap
/// compares one integer, not a tuple (with tuples, the full network ran 3.7 % more
/// instructions: callgrind, `fullnet network --minutes 0.05`). Numbers are below 2¹⁶ (channels 0..254, senders 0..16); instants below
/// 2⁴⁸ µs (8.9 years of simulated time), and a later one is kept as that last instant.
#[derive(Debug, Default)]
struct EventHeap(BinaryHeap<Reverse<u64>>);

impl EventHeap {
    /// The key of `number` at `at`: ordered as `(at, number)` is (see [`EventHeap`]).
    fn key(at: Instant, number: u32) -> u64 {
        debug_assert!(number < 1 << NUMBER_BITS, "a channel or sender number");
        let micros = at.as_micros().min((1 << (64 - NUMBER_BITS)) - 1);
        micros << NUMBER_BITS | u64::from(number & ((1 << NUMBER_BITS) - 1))
    }

    /// The instant and the number of `key`.
    fn unpack(key: u64) -> (Instant, u32) {
        // The low 16 bits: the number, which fits a `u32`.
        let number = (key & ((1 << NUMBER_BITS) - 1)) as u32;
        (Instant::from_micros(key >> NUMBER_BITS), number)
    }

    fn push(&mut self, at: Instant, number: u32) {
        self.0.push(Reverse(Self::key(at, number)));
    }

    /// The earliest entry.
    fn peek(&self) -> Option<(Instant, u32)> {
        self.0.peek().map(|&Reverse(key)| Self::unpack(key))
    }

    fn pop(&mut self) {
        self.0.pop();
    }
}

/// What the simulation tells whoever watches it. Every method has a default that does
/// nothing, so an observer implements only what it measures.
pub trait Observer {
    /// A frame reached the receivers at `at` (sent by participant `from`) after occupying the
    /// bus for `bits` bits.
    fn delivered(&mut self, _at: Instant, _frame: &CanFrame, _from: usize, _bits: u32) {}
    /// The effective output of node `node` (index), both channels' outputs in series (AND),
    /// for its watched receive SRDO, changed to `value` at `at`.
    fn output(&mut self, _at: Instant, _node: usize, _value: u64) {}
    /// A channel of node `node` (index) reported `event` at `at`.
    fn event(&mut self, _at: Instant, _node: usize, _side: Side, _event: &ChannelEvent) {}
}

/// An observer that watches nothing.
pub struct Unobserved;

impl Observer for Unobserved {}

/// What one channel handed out during one call; reused from call to call.
#[derive(Default)]
struct Scratch {
    frames: Vec<CanFrame>,
    link: Vec<u8>,
    events: Vec<ChannelEvent>,
    outputs: usize,
    /// The channel (engine numbering) the call was on.
    channel: u32,
    /// Whether the call ran (a deadline call is skipped when the deadline moved).
    ran: bool,
    /// Its new deadline, when it changed and is not [`Instant::NEVER`]: a timer entry.
    timer: Option<Instant>,
    /// Arrivals of the frame delimiters it put on the wire to the other channel.
    link_ends: Vec<Instant>,
    /// This channel's output of the node's watched receive SRDO after the call.
    own_output: u64,
}

impl Scratch {
    fn clear(&mut self) {
        self.frames.clear();
        self.link.clear();
        self.events.clear();
        self.outputs = 0;
        self.ran = false;
        self.timer = None;
        self.link_ends.clear();
    }
}

impl Io for Scratch {
    fn transmit(&mut self, frame: CanFrame) {
        self.frames.push(frame);
    }
    fn link(&mut self, bytes: &[u8]) {
        self.link.extend_from_slice(bytes);
    }
    fn output(&mut self, _srdo: SrdoNumber, _data: u64) {
        self.outputs += 1;
    }
    fn event(&mut self, event: ChannelEvent) {
        self.events.push(event);
    }
}

/// One direction of a link: bytes in flight, and when they arrive. Bytes sent back to back
/// arrive [`LINK_BYTE_TIME`] apart, so a run of them is its first byte's arrival and its
/// length, not an entry per byte.
#[derive(Default)]
struct Wire {
    /// Bytes in flight from `head` on, oldest first.
    bytes: Vec<u8>,
    head: usize,
    /// Runs of bytes sent back to back: (the first byte's arrival, how many), oldest first.
    runs: VecDeque<(Instant, usize)>,
    busy_until: Instant,
}

impl Wire {
    /// Queues `bytes`, written at `now`, behind what is in flight; calls `delimiter` with the
    /// arrival of every frame delimiter (00h).
    fn send(&mut self, now: Instant, bytes: &[u8], mut delimiter: impl FnMut(Instant)) {
        let start = self.busy_until.max(now);
        let first = start + LINK_BYTE_TIME;
        match self.runs.back_mut() {
            // Right behind the last run (it ends at `busy_until`): the same run goes on.
            Some((_, len)) if start == self.busy_until => *len += bytes.len(),
            _ => self.runs.push_back((first, bytes.len())),
        }
        if self.head == self.bytes.len() {
            self.bytes.clear();
            self.head = 0;
        } else if self.head > 4096 {
            // A wire that never runs empty still does not grow without bound.
            self.bytes.drain(..self.head);
            self.head = 0;
        }
        self.bytes.extend_from_slice(bytes);
        let mut at = start;
        for &byte in bytes {
            at = at + LINK_BYTE_TIME;
            if byte == 0 {
                delimiter(at);
            }
        }
        self.busy_until = at;
    }

    /// Hands every byte that arrived by `until` to `receive`, in order, as slices: each
    /// slice ends at a frame delimiter (00h) or at the last byte arrived, and comes with the
    /// arrival of its last byte. A link receiver does nothing with a byte before the
    /// delimiter, so this is what handing over byte by byte with each byte's arrival does,
    /// without a call per byte.
    fn receive(&mut self, until: Instant, mut receive: impl FnMut(Instant, &[u8])) {
        let step = LINK_BYTE_TIME.as_micros();
        while let Some((first, len)) = self.runs.front_mut() {
            if *first > until {
                return;
            }
            let arrived = until.saturating_since(*first).as_micros() / step + 1;
            let count = (*len).min(usize::try_from(arrived).unwrap_or(usize::MAX));
            let bytes = &self.bytes[self.head..self.head + count];
            let mut start = 0;
            while start < count {
                let end = bytes[start..]
                    .iter()
                    .position(|&byte| byte == 0)
                    .map_or(count, |at| start + at + 1);
                let last = *first + Duration::from_micros((end - 1) as u64 * step);
                receive(last, &bytes[start..end]);
                start = end;
            }
            self.head += count;
            if count == *len {
                self.runs.pop_front();
            } else {
                *first = *first + Duration::from_micros(count as u64 * step);
                *len -= count;
                return;
            }
        }
    }
}

/// One dual-channel node of the simulation.
pub struct SimNode {
    /// Node-ID.
    pub id: u8,
    /// Channel A.
    pub a: ChannelARuntime,
    /// Channel B.
    pub b: ChannelBRuntime,
    /// Towards channel A (from B) and towards channel B (from A).
    wires: [Wire; 2],
    deadlines: [Instant; 2],
    /// Whether each channel was Operational after its last call (filtered delivery).
    operational: [bool; 2],
    /// The receive SRDO whose effective output is reported to the observer.
    watched: Option<SrdoNumber>,
    /// Each channel's output of it as last applied, and their AND as last reported.
    outputs: [u64; 2],
    output: u64,
}

impl SimNode {
    /// The effective output of receive SRDO `srdo`: both channels' outputs in series (AND).
    pub fn output(&self, srdo: SrdoNumber) -> u64 {
        self.a.output(srdo) & self.b.output(srdo)
    }
}

/// What a call on a channel does before it polls.
#[derive(Clone, Copy)]
enum Action {
    Poll,
    Frame(CanFrame),
    /// Every link byte that arrived up to then.
    Link(Instant),
    Input(u8),
}

/// A background sender: one identifier, a fixed length, a fixed period, data that changes
/// with every frame (a counter), so that the stuff bits vary as they do on a real bus.
#[derive(Clone, Copy, Debug)]
pub struct Periodic {
    /// Identifier.
    pub id: u16,
    /// Data length.
    pub len: u8,
    /// Period.
    pub period: Duration,
    /// First transmission.
    pub first: Instant,
}

struct Sender {
    periodic: Periodic,
    participant: usize,
    next: Instant,
    count: u64,
}

/// The network: participant 0 is the tool; node `i`'s channel A is participant `2i + 1`,
/// channel B `2i + 2` (as in `DualNetwork`); background senders follow the nodes.
pub struct Engine<O: Observer> {
    /// Simulated time.
    pub now: Instant,
    /// The bus.
    pub bus: Bus,
    /// The nodes, each boxed so that a batch can move half of them to the second thread
    /// and back as pointers (a node is about 23 KiB).
    pub nodes: Vec<Box<SimNode>>,
    /// Who watches.
    pub observer: O,
    /// Deliver every frame to every channel (as `DualNetwork` does) instead of filtering:
    /// for the test that shows filtering changes nothing.
    pub unfiltered: bool,
    /// Every frame as delivered, when `Some` (tests only: an hour would not fit).
    pub trace: Option<Vec<(Instant, CanFrame, usize)>>,
    in_flight: Vec<Delivery>,
    /// Channel deadlines as (instant, channel); an entry that no longer equals the channel's
    /// deadline is stale and skipped.
    timers: EventHeap,
    /// Link frame delimiters arriving: (instant, receiving channel).
    link_ends: EventHeap,
    senders: Vec<Sender>,
    sender_due: EventHeap,
    /// Operational channels per identifier, in channel order.
    subscribers: Vec<Vec<u32>>,
    /// Channels not in Operational (they get every frame), in channel order.
    open: Vec<u32>,
    /// Boxed, so that taking it out for a call moves a pointer, not the whole value (that
    /// move, twice per call, was 2.5 % of the simulation's instructions in `memcpy`).
    scratch: Option<Box<Scratch>>,
    recipients: Vec<u32>,
    due: Vec<u32>,
    arrivals: Vec<Delivery>,
    tool_inbox: VecDeque<CanFrame>,
    link_period: Duration,
    /// Threads for large batches of calls at one instant (1: none but the caller's).
    pub threads: usize,
    /// How many calls at one instant make a batch worth two threads.
    pub batch_threshold: usize,
    batch_scratch: Vec<Scratch>,
    /// The second thread, started by the first batch that uses it.
    second: Option<Handoff<Half>>,
    /// The last half handed to it, kept for its allocations.
    spare: Option<Half>,
}

/// The upper half of a batch, for the second thread: its nodes (moved out of the engine and
/// back), its calls and what each handed out.
struct Half {
    nodes: Vec<Box<SimNode>>,
    /// Index of the first node in `nodes`.
    offset: usize,
    calls: Vec<u32>,
    outs: Vec<Scratch>,
    now: Instant,
    action: Action,
    deadline_only: bool,
}

impl Half {
    fn run(mut self) -> Self {
        let count = self.calls.len();
        run_calls(
            &mut self.nodes,
            self.offset,
            &self.calls,
            &mut self.outs[..count],
            self.now,
            self.action,
            self.deadline_only,
        );
        self
    }
}

/// The calls `calls` (channels, in order) on `nodes` (node `offset` first), each with
/// `action` at `now` (a deadline call only if the channel's deadline is still due), what
/// each handed out into `outs`.
fn run_calls(
    nodes: &mut [Box<SimNode>],
    offset: usize,
    calls: &[u32],
    outs: &mut [Scratch],
    now: Instant,
    action: Action,
    deadline_only: bool,
) {
    for (&c, out) in calls.iter().zip(outs.iter_mut()) {
        let (index, side) = split(c);
        let node = &mut nodes[index - offset];
        if deadline_only && node.deadlines[side as usize] > now {
            out.clear();
            continue;
        }
        run_call(node, index, side, now, action, out);
    }
}

/// Channel number `c`: node `c / 2`, side A for even, B for odd; participant `c + 1`.
fn channel(node: usize, side: Side) -> u32 {
    (2 * node + side as usize) as u32
}

fn split(channel: u32) -> (usize, Side) {
    let channel = channel as usize;
    let side = if channel % 2 == 0 { Side::A } else { Side::B };
    (channel / 2, side)
}

/// The identifiers a channel in Operational handles (see the module documentation).
fn accepted(node_id: u8, config: &shared::safety::config::SafetyConfig<4>) -> Vec<u16> {
    let mut ids = vec![nmt::NMT_ID.raw(), shared::safety::gfc::GFC_ID.raw()];
    ids.push(0x600 + u16::from(node_id));
    for record in &config.srdos {
        if record.direction != 0 {
            for cob_id in [record.cob_id_1, record.cob_id_2] {
                ids.push((cob_id & 0x7FF) as u16);
            }
        }
    }
    ids.sort_unstable();
    ids.dedup();
    ids
}

impl<O: Observer> Engine<O> {
    /// Dual-channel nodes `(node-ID, stored parameters)` on a bus at `bit_rate`, powered on
    /// at t = 0, with a link heartbeat every `link_period`. A node with `None` starts on its
    /// defaults.
    pub fn new(
        bit_rate: u32,
        nodes: Vec<(u8, Option<RamFlash<8192>>)>,
        link_period: Duration,
        observer: O,
    ) -> Self {
        let nodes: Vec<Box<SimNode>> = nodes
            .into_iter()
            .map(|(id, image)| {
                let image = image.unwrap_or_default();
                Box::new(SimNode {
                    id,
                    a: Runtime::new(
                        device_config(id, "dual node, channel A"),
                        image.clone(),
                        ChannelA::default(),
                        Instant::ZERO,
                        link_period,
                    )
                    .expect("valid device"),
                    b: Runtime::new(
                        device_config(id, "dual node, channel B"),
                        image,
                        ChannelB::new(&B_INPUTS).expect("valid inputs"),
                        Instant::ZERO,
                        link_period,
                    )
                    .expect("valid device"),
                    wires: Default::default(),
                    deadlines: [Instant::ZERO; 2],
                    operational: [false; 2],
                    watched: None,
                    outputs: [0; 2],
                    output: 0,
                })
            })
            .collect();
        let channels = 2 * nodes.len() as u32;
        let mut timers = EventHeap::default();
        for c in 0..channels {
            timers.push(Instant::ZERO, c);
        }
        Engine {
            now: Instant::ZERO,
            bus: {
                let mut bus = Bus::new(bit_rate, 1 + channels as usize);
                // Each channel's whole transmit queue by identifier, as the board layer keeps
                // it (`board::transmit_queue`) and `DualNetwork` and the hub model it: a
                // node's own heartbeat or EMCY never holds back its SRDO or its GFC.
                bus.set_transmit_mailboxes(ORDERED_BY_IDENTIFIER);
                bus
            },
            nodes,
            observer,
            unfiltered: false,
            trace: None,
            in_flight: Vec::new(),
            timers,
            link_ends: EventHeap::default(),
            senders: Vec::new(),
            sender_due: EventHeap::default(),
            subscribers: vec![Vec::new(); IDENTIFIERS],
            open: (0..channels).collect(),
            scratch: Some(Box::default()),
            recipients: Vec::new(),
            due: Vec::new(),
            arrivals: Vec::new(),
            tool_inbox: VecDeque::new(),
            link_period,
            threads: 1,
            batch_threshold: 16,
            batch_scratch: Vec::new(),
            second: None,
            spare: None,
        }
    }

    /// The link heartbeat period.
    pub fn link_period(&self) -> Duration {
        self.link_period
    }

    /// The index of the node with node-ID `id`.
    pub fn index(&self, id: u8) -> usize {
        self.nodes
            .iter()
            .position(|node| node.id == id)
            .expect("a node with this node-ID")
    }

    /// Reports the effective output of receive SRDO `srdo` of node `index` to the observer.
    pub fn watch(&mut self, index: usize, srdo: SrdoNumber) {
        let node = &mut self.nodes[index];
        node.watched = Some(srdo);
        node.outputs = [node.a.output(srdo), node.b.output(srdo)];
        node.output = node.output(srdo);
    }

    /// Adds a background sender; returns its participant number.
    pub fn add_sender(&mut self, periodic: Periodic) -> usize {
        let participant = 1 + 2 * self.nodes.len() + self.senders.len();
        let index = self.senders.len() as u32;
        self.senders.push(Sender {
            periodic,
            participant,
            next: periodic.first,
            count: 0,
        });
        self.sender_due.push(periodic.first, index);
        participant
    }

    /// The bus participant of channel `side` of node `index`.
    pub fn participant(index: usize, side: Side) -> usize {
        channel(index, side) as usize + 1
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

    fn prune_timers(&mut self) {
        while let Some((at, c)) = self.timers.peek() {
            let (node, side) = split(c);
            if self.nodes[node].deadlines[side as usize] == at {
                return;
            }
            self.timers.pop();
        }
    }

    fn next_activity(&mut self) -> Instant {
        self.prune_timers();
        let mut next = Instant::NEVER;
        for delivery in &self.in_flight {
            next = next.min(delivery.at);
        }
        for heap in [&self.timers, &self.link_ends, &self.sender_due] {
            if let Some((at, _)) = heap.peek() {
                next = next.min(at);
            }
        }
        if let Some(start) = self.bus.next_start(self.now) {
            next = next.min(start);
        }
        next
    }

    /// Takes every channel whose deadline is due at `now` off the timer heap into `due`.
    fn take_due_timers(&mut self, now: Instant) {
        while let Some((at, c)) = self.timers.peek() {
            if at > now {
                break;
            }
            self.timers.pop();
            let (node, side) = split(c);
            if self.nodes[node].deadlines[side as usize] == at {
                self.due.push(c);
            }
        }
    }

    /// Everything due at `self.now`, in `DualNetwork`'s order: deliveries, link bytes,
    /// deadlines, then background senders and the next arbitration.
    fn step(&mut self) {
        let now = self.now;
        // Deliveries, in the order the bus produced them.
        let mut arrivals = std::mem::take(&mut self.arrivals);
        arrivals.clear();
        let mut index = 0;
        while index < self.in_flight.len() {
            if self.in_flight[index].at <= now {
                arrivals.push(self.in_flight.remove(index));
            } else {
                index += 1;
            }
        }
        for delivery in &arrivals {
            self.deliver(delivery);
        }
        self.arrivals = arrivals;
        // Link messages ending now.
        let mut due = std::mem::take(&mut self.due);
        due.clear();
        while let Some((at, c)) = self.link_ends.peek() {
            if at > now {
                break;
            }
            self.link_ends.pop();
            due.push(c);
        }
        due.sort_unstable();
        due.dedup();
        self.call_batch(&due, Action::Link(now), false);
        // Deadlines.
        due.clear();
        self.due = due;
        self.take_due_timers(now);
        let mut due = std::mem::take(&mut self.due);
        due.sort_unstable();
        due.dedup();
        self.call_batch(&due, Action::Poll, true);
        due.clear();
        self.due = due;
        // Background senders.
        while let Some((at, index)) = self.sender_due.peek() {
            if at > now {
                break;
            }
            self.sender_due.pop();
            let sender = &mut self.senders[index as usize];
            let mut data = [0u8; 8];
            data.copy_from_slice(&sender.count.to_le_bytes());
            let id = shared::CanId::new(sender.periodic.id).expect("an 11-bit identifier");
            let frame = CanFrame::new(id, &data[..usize::from(sender.periodic.len)])
                .expect("at most 8 bytes");
            sender.count += 1;
            sender.next = sender.next + sender.periodic.period;
            let (participant, next) = (sender.participant, sender.next);
            self.sender_due.push(next, index);
            self.bus.send(participant, frame);
        }
        if self.bus.next_start(now) == Some(now) {
            self.bus.arbitrate_into(now, &mut self.in_flight);
        }
    }

    /// One frame reaches every channel that handles it (and the tool).
    fn deliver(&mut self, delivery: &Delivery) {
        let now = self.now;
        self.observer
            .delivered(delivery.at, &delivery.frame, delivery.from, delivery.bits);
        if let Some(trace) = &mut self.trace {
            trace.push((delivery.at, delivery.frame, delivery.from));
        }
        if delivery.from != 0 {
            self.tool_inbox.push_back(delivery.frame);
            if self.tool_inbox.len() > 64 {
                self.tool_inbox.pop_front();
            }
        }
        let mut recipients = std::mem::take(&mut self.recipients);
        recipients.clear();
        let sender = delivery.from.wrapping_sub(1) as u32;
        if self.unfiltered {
            recipients.extend(0..2 * self.nodes.len() as u32);
        } else {
            let id = usize::from(delivery.frame.id().raw());
            recipients.extend_from_slice(&self.subscribers[id]);
            recipients.extend_from_slice(&self.open);
            // Those not addressed but due are polled, as every delivery polls every channel
            // in `DualNetwork`.
            let mut due = std::mem::take(&mut self.due);
            due.clear();
            self.due = due;
            self.take_due_timers(now);
            recipients.extend_from_slice(&self.due);
            recipients.sort_unstable();
            recipients.dedup();
        }
        let id = delivery.frame.id().raw();
        for &c in &recipients {
            if c == sender {
                // Not delivered back to its sender; if it was due, the deadline phase polls it.
                let (node, side) = split(c);
                let deadline = self.nodes[node].deadlines[side as usize];
                if deadline <= now {
                    self.timers.push(deadline, c);
                }
                continue;
            }
            let (node, side) = split(c);
            let handles = self.unfiltered
                || !self.nodes[node].operational[side as usize]
                || self.subscribers[usize::from(id)].binary_search(&c).is_ok();
            if handles {
                self.call(node, side, Action::Frame(delivery.frame));
            } else if self.nodes[node].deadlines[side as usize] <= now {
                self.call(node, side, Action::Poll);
            }
        }
        self.due.clear();
        self.recipients = recipients;
    }

    /// Runs `action` on one channel, polls it, and applies what it handed out.
    fn call(&mut self, index: usize, side: Side, action: Action) {
        let mut out = self.scratch.take().unwrap_or_default();
        run_call(
            &mut self.nodes[index],
            index,
            side,
            self.now,
            action,
            &mut out,
        );
        self.apply(&out);
        self.scratch = Some(out);
    }

    /// Applies what one channel's call handed out to everything outside its node: timer and
    /// link heaps, the bus, the observer, the acceptance filters.
    fn apply(&mut self, out: &Scratch) {
        if !out.ran {
            return;
        }
        let now = self.now;
        let c = out.channel;
        let (index, side) = split(c);
        if let Some(deadline) = out.timer {
            self.timers.push(deadline, c);
        }
        let other = channel(index, side) ^ 1;
        for &at in &out.link_ends {
            self.link_ends.push(at, other);
        }
        let participant = c as usize + 1;
        for &frame in &out.frames {
            self.bus.send(participant, frame);
        }
        for event in &out.events {
            self.observer.event(now, index, side, event);
        }
        let node = &mut self.nodes[index];
        node.outputs[side as usize] = out.own_output;
        if out.outputs > 0 && node.watched.is_some() {
            let value = node.outputs[0] & node.outputs[1];
            if value != node.output {
                node.output = value;
                self.observer.output(now, index, value);
            }
        }
        self.update_filter(index, side);
    }

    /// The calls `due` (channels, in order) all make at `self.now`, each with `action` (a
    /// deadline call only if the channel's deadline is still due). Large batches run on two
    /// threads when [`Engine::threads`] says so: the nodes are independent within one
    /// instant (a call changes its own node only; bytes it puts on the link arrive later),
    /// and what each call handed out is applied afterwards in channel order, as one call
    /// after the other would have applied it, so the result is the same.
    fn call_batch(&mut self, due: &[u32], action: Action, deadline_only: bool) {
        let now = self.now;
        if self.threads < 2 || due.len() < self.batch_threshold {
            for &c in due {
                let (node, side) = split(c);
                if !deadline_only || self.nodes[node].deadlines[side as usize] <= now {
                    self.call(node, side, action);
                }
            }
            return;
        }
        // Split at a node boundary: both channels of a node on one thread, in order. The
        // upper half's nodes move to the second thread (as pointers) and come back.
        let middle = split(due[due.len() / 2]).0;
        let cut = due.partition_point(|&c| split(c).0 < middle);
        let (first, second) = due.split_at(cut);
        let mut half = self.spare.take().unwrap_or_else(|| Half {
            nodes: Vec::new(),
            offset: 0,
            calls: Vec::new(),
            outs: Vec::new(),
            now,
            action,
            deadline_only,
        });
        half.nodes.extend(self.nodes.drain(middle..));
        half.offset = middle;
        half.calls.clear();
        half.calls.extend_from_slice(second);
        if half.outs.len() < second.len() {
            half.outs.resize_with(second.len(), Scratch::default);
        }
        (half.now, half.action, half.deadline_only) = (now, action, deadline_only);
        let worker = self.second.get_or_insert_with(|| Handoff::new(Half::run));
        worker.submit(half);
        let mut pool = std::mem::take(&mut self.batch_scratch);
        if pool.len() < first.len() {
            pool.resize_with(first.len(), Scratch::default);
        }
        run_calls(
            &mut self.nodes,
            0,
            first,
            &mut pool[..first.len()],
            now,
            action,
            deadline_only,
        );
        let mut half = worker.wait();
        self.nodes.append(&mut half.nodes);
        for out in pool[..first.len()].iter().chain(&half.outs[..second.len()]) {
            self.apply(out);
        }
        self.batch_scratch = pool;
        self.spare = Some(half);
    }

    /// Moves a channel between "every frame" and its identifiers when it entered or left
    /// Operational.
    fn update_filter(&mut self, index: usize, side: Side) {
        let node = &self.nodes[index];
        let (state, config) = match side {
            Side::A => (node.a.node().nmt_state(), node.a.node().safety_config()),
            Side::B => (node.b.node().nmt_state(), node.b.node().safety_config()),
        };
        let operational = state == NmtState::Operational;
        if operational == node.operational[side as usize] {
            return;
        }
        let c = channel(index, side);
        let ids = accepted(node.id, config);
        self.nodes[index].operational[side as usize] = operational;
        if operational {
            for id in ids {
                let list = &mut self.subscribers[usize::from(id)];
                if let Err(at) = list.binary_search(&c) {
                    list.insert(at, c);
                }
            }
            if let Ok(at) = self.open.binary_search(&c) {
                self.open.remove(at);
            }
        } else {
            for list in &mut self.subscribers {
                if let Ok(at) = list.binary_search(&c) {
                    list.remove(at);
                }
            }
            if let Err(at) = self.open.binary_search(&c) {
                self.open.insert(at, c);
            }
        }
    }

    /// Both channels of node `index` sample their safety input: A reads `a`, B reads `b`.
    pub fn set_inputs(&mut self, index: usize, a: u8, b: u8) {
        self.call(index, Side::A, Action::Input(a));
        self.call(index, Side::B, Action::Input(b));
    }

    /// The tool (participant 0) sends an NMT command to `target` (0: all).
    pub fn nmt(&mut self, command: NmtCommand, target: u8) {
        self.bus.send(0, nmt::command_frame(command, target));
    }

    /// Participant 0 (the tool, or a foreign device) queues `frame` now.
    pub fn send_from_tool(&mut self, frame: CanFrame) {
        self.bus.send(0, frame);
    }

    /// Runs in steps of 1 ms until every node's channel A is Pre-operational, at most
    /// `limit`; `false` if some never got there.
    pub fn wait_for_boot(&mut self, limit: Duration) -> bool {
        let give_up = self.now + limit;
        while self.now < give_up {
            if self
                .nodes
                .iter()
                .all(|node| node.a.node().nmt_state() == NmtState::PreOperational)
            {
                return true;
            }
            self.run_for(Duration::from_millis(1));
        }
        false
    }
}

/// The configuration tool on the engine's bus (participant 0): receiving advances simulated
/// time in steps of 100 µs until a frame arrives or the deadline passes.
impl<O: Observer> Transport for Engine<O> {
    fn now(&mut self) -> std::time::Duration {
        std::time::Duration::from_micros(self.now.as_micros())
    }

    fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        self.bus.send(0, *frame);
        Ok(())
    }

    fn receive(
        &mut self,
        deadline: std::time::Duration,
    ) -> Result<Option<CanFrame>, TransportError> {
        let deadline =
            Instant::from_micros(u64::try_from(deadline.as_micros()).unwrap_or(u64::MAX));
        loop {
            if let Some(frame) = self.tool_inbox.pop_front() {
                return Ok(Some(frame));
            }
            if self.now >= deadline {
                return Ok(None);
            }
            let step = (self.now + Duration::from_micros(100)).min(deadline);
            self.run_until(step);
        }
    }
}

/// One call on channel `side` of `node` (index `index`) at `now`: the action, the poll, the
/// new deadline and the bytes for the other channel's wire; everything outside the node goes
/// into `out`, for [`Engine::apply`].
fn run_call(
    node: &mut SimNode,
    index: usize,
    side: Side,
    now: Instant,
    action: Action,
    out: &mut Scratch,
) {
    out.clear();
    out.ran = true;
    out.channel = channel(index, side);
    let incoming = &mut node.wires[side as usize];
    let deadline = match side {
        Side::A => act(&mut node.a, incoming, now, action, out),
        Side::B => act(&mut node.b, incoming, now, action, out),
    };
    if node.deadlines[side as usize] != deadline {
        node.deadlines[side as usize] = deadline;
        if deadline != Instant::NEVER {
            out.timer = Some(deadline);
        }
    }
    if !out.link.is_empty() {
        // The other channel receives: the wire towards it.
        let other = match side {
            Side::A => Side::B,
            Side::B => Side::A,
        };
        let link_ends = &mut out.link_ends;
        node.wires[other as usize].send(now, &out.link, |at| link_ends.push(at));
    }
    out.own_output = node.watched.map_or(0, |srdo| match side {
        Side::A => node.a.output(srdo),
        Side::B => node.b.output(srdo),
    });
}

/// One call on a channel (either role: their runtimes differ in type only), then its poll;
/// returns the channel's next deadline.
fn act<R: Role<4>>(
    runtime: &mut Runtime<RamFlash<8192>, R, 4>,
    incoming: &mut Wire,
    now: Instant,
    action: Action,
    out: &mut Scratch,
) -> Instant {
    match action {
        Action::Poll => {}
        Action::Frame(frame) => runtime.on_frame(now, &frame, out),
        Action::Link(until) => {
            incoming.receive(until, |at, bytes| runtime.on_link_bytes(at, bytes, out));
        }
        Action::Input(value) => runtime
            .set_input(
                now,
                Address::new(0x6000, 1),
                Address::new(0x6001, 1),
                &[value],
                out,
            )
            .expect("input object"),
    }
    runtime.poll(now, out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every byte as the per-byte model had it: byte k of what is written at `now` arrives
    /// at max(now, the previous byte's arrival) + (k + 1) × the byte time.
    fn per_byte(writes: &[(u64, &[u8])]) -> Vec<(Instant, u8)> {
        let mut busy = Instant::ZERO;
        let mut out = Vec::new();
        for &(now, bytes) in writes {
            let mut at = busy.max(Instant::from_micros(now));
            for &byte in bytes {
                at = at + LINK_BYTE_TIME;
                out.push((at, byte));
            }
            busy = at;
        }
        out
    }

    /// Runs of bytes hand over every byte in order, in slices that end at a delimiter or at
    /// the last byte arrived, each slice at the arrival the per-byte model gives its last
    /// byte (so every delimiter at its own), whether a write lands behind bytes still in
    /// flight (one run) or on an idle wire (a new run), and whatever instants the receiver
    /// reads at (mid-run included); delimiters are announced at their arrival.
    #[test]
    fn a_wire_of_runs_delivers_every_byte_at_its_per_byte_arrival() {
        let writes: [(u64, &[u8]); 4] = [
            (100, &[1, 2, 0]),
            (105, &[3, 0]),    // behind the first: the same run
            (500, &[4, 5, 0]), // the wire idle again: a new run
            (530, &[6, 0]),    // right at the end of the previous run
        ];
        let expected = per_byte(&writes);
        for reads in [vec![10_000], vec![125, 131, 149, 530, 549, 10_000], {
            (0..700).collect::<Vec<u64>>()
        }] {
            let mut wire = Wire::default();
            let mut delimiters = Vec::new();
            let mut received = Vec::new();
            let mut pending = writes.iter().peekable();
            for until in reads {
                while let Some(&&(now, bytes)) = pending.peek() {
                    if now > until {
                        break;
                    }
                    wire.send(Instant::from_micros(now), bytes, |at| delimiters.push(at));
                    pending.next();
                }
                wire.receive(Instant::from_micros(until), |last, bytes| {
                    assert!(
                        last <= Instant::from_micros(until),
                        "a byte handed over early"
                    );
                    let (&end, before) = bytes.split_last().expect("never an empty slice");
                    assert!(!before.contains(&0), "a delimiter inside a slice");
                    received.extend(before.iter().map(|&byte| (None, byte)));
                    received.push((Some(last), end));
                });
            }
            let bytes: Vec<u8> = received.iter().map(|&(_, byte)| byte).collect();
            let sent: Vec<u8> = expected.iter().map(|&(_, byte)| byte).collect();
            assert_eq!(bytes, sent);
            for (&(stamp, byte), &(at, _)) in received.iter().zip(&expected) {
                if let Some(stamp) = stamp {
                    assert_eq!(stamp, at, "a slice stamped otherwise than its last byte");
                }
                assert!(
                    byte != 0 || stamp.is_some(),
                    "a delimiter not ending a slice"
                );
            }
            let ends: Vec<Instant> = expected
                .iter()
                .filter(|(_, byte)| *byte == 0)
                .map(|(at, _)| *at)
                .collect();
            assert_eq!(delimiters, ends);
        }
    }

    /// The heap hands out its entries in the order of the tuples `(instant, number)`, as the
    /// heap of tuples it replaces did: earliest first, the lower number first at one instant
    /// (equal instants are the common case: every channel's link heartbeat falls on one
    /// tick), each entry unpacked to what was pushed.
    #[test]
    fn the_event_heap_orders_as_the_tuples_do() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut heap = EventHeap::default();
        let mut tuples = BinaryHeap::new();
        for _ in 0..5_000 {
            // Few instants, so that many entries share one; some near the 2⁴⁸ µs limit.
            let micros = match rng.random_range(0..4) {
                0 => (1 << 48) - 1 - rng.random_range(0..3),
                _ => rng.random_range(0..200) * 10_000,
            };
            let at = Instant::from_micros(micros);
            let number = rng.random_range(0..300);
            heap.push(at, number);
            tuples.push(Reverse((at, number)));
            if rng.random_range(0..3) == 0 {
                let Reverse(expected) = tuples.pop().expect("pushed");
                assert_eq!(heap.peek(), Some(expected));
                heap.pop();
            }
        }
        while let Some(Reverse(expected)) = tuples.pop() {
            assert_eq!(heap.peek(), Some(expected));
            heap.pop();
        }
        assert_eq!(heap.peek(), None);
    }
}
