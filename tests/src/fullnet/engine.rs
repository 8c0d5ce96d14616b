//! An event-driven simulation of dual-channel nodes on the simulated bus, fast enough for a
//! network of 127 nodes over an hour of bus time, that makes the same calls on the channel
//! runtimes as [`DualNetwork`](crate::dual::DualNetwork) at the same instants (a test runs
//! both on one scenario and compares the bus trace frame for frame).
//!
//! What makes it fast, without touching the protocol core or the channel code:
//!
//! - **Steps to the next deadline.** Channel deadlines are kept in a tournament tree per
//!   group, link frame ends and background senders in binary heaps; a step handles only what
//!   is due, not every node.
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
//! - **Two threads** ([`Engine::set_threads`]): channel A of a node on one, channel B on the
//!   other, in windows of simulated time that end before anything sent in them can reach
//!   anyone ([`Engine`]); the threads meet once per window.

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
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

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
#[derive(Clone, Debug, Default)]
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
    /// Its new deadline, when it changed.
    timer: Option<Instant>,
    /// This channel's output of the node's watched receive SRDO after the call.
    own_output: u64,
}

impl Scratch {
    fn clear(&mut self) {
        self.frames.clear();
        self.link.clear();
        self.events.clear();
        self.outputs = 0;
        self.timer = None;
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

/// The writing end of one direction of a link: when the bytes it writes arrive. Bytes
/// written while earlier ones are in flight queue behind them, each [`LINK_BYTE_TIME`] after
/// the one before.
#[derive(Default)]
struct WireOut {
    busy_until: Instant,
}

impl WireOut {
    /// `bytes`, written at `now`: returns the first one's arrival, and calls `delimiter` with
    /// the arrival of every frame delimiter (00h) among them.
    fn write(&mut self, now: Instant, bytes: &[u8], mut delimiter: impl FnMut(Instant)) -> Instant {
        let start = self.busy_until.max(now);
        let mut at = start;
        for &byte in bytes {
            at = at + LINK_BYTE_TIME;
            if byte == 0 {
                delimiter(at);
            }
        }
        self.busy_until = at;
        start + LINK_BYTE_TIME
    }
}

/// The receiving end of one direction of a link: bytes in flight, and when they arrive.
/// Bytes sent back to back arrive [`LINK_BYTE_TIME`] apart, so a run of them is its first
/// byte's arrival and its length, not an entry per byte.
#[derive(Default)]
struct Wire {
    /// Bytes in flight from `head` on, oldest first.
    bytes: Vec<u8>,
    head: usize,
    /// Runs of bytes sent back to back: (the first byte's arrival, how many), oldest first.
    runs: VecDeque<(Instant, usize)>,
}

impl Wire {
    /// Bytes whose first arrives at `first` ([`WireOut::write`]), behind what is in flight.
    fn push_run(&mut self, first: Instant, bytes: &[u8]) {
        let step = LINK_BYTE_TIME.as_micros();
        match self.runs.back_mut() {
            // Right behind the last run: the same run goes on.
            Some((start, len)) if *start + Duration::from_micros(*len as u64 * step) == first => {
                *len += bytes.len();
            }
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

/// One channel of a dual-channel node: its runtime (channel A's or channel B's).
pub enum ChannelRuntime {
    /// Channel A.
    A(ChannelARuntime),
    /// Channel B.
    B(ChannelBRuntime),
}

/// One channel of a dual-channel node in the simulation, with what only it touches.
struct SimChannel {
    runtime: ChannelRuntime,
    /// The node's index and node-ID, and the channel's side.
    index: usize,
    id: u8,
    side: Side,
    /// The link bytes from the other channel, and the timing of those to it.
    incoming: Wire,
    outgoing: WireOut,
    deadline: Instant,
    /// Whether it was Operational after its last call (filtered delivery).
    operational: bool,
    /// The node's receive SRDO whose effective output is reported to the observer.
    watched: Option<SrdoNumber>,
    /// Its output of it after its last call.
    own_output: u64,
}

impl SimChannel {
    fn state(&self) -> (NmtState, &shared::safety::config::SafetyConfig<4>) {
        match &self.runtime {
            ChannelRuntime::A(runtime) => {
                (runtime.node().nmt_state(), runtime.node().safety_config())
            }
            ChannelRuntime::B(runtime) => {
                (runtime.node().nmt_state(), runtime.node().safety_config())
            }
        }
    }

    fn output(&self, srdo: SrdoNumber) -> u64 {
        match &self.runtime {
            ChannelRuntime::A(runtime) => runtime.output(srdo),
            ChannelRuntime::B(runtime) => runtime.output(srdo),
        }
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

#[derive(Clone)]
struct Sender {
    periodic: Periodic,
    participant: usize,
    next: Instant,
    count: u64,
}

/// Where a call stands in the order in which one thread stepping from instant to instant
/// makes the calls of the whole network: the instant; then the phase (the deliveries at that
/// instant in the order the bus made them, then the link messages, then the deadlines); then
/// the channel, numbered as by [`channel`] plus one (0 is the delivery itself, reported
/// before the calls it causes). What one call reports shares its key and keeps its order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
struct Order {
    at: Instant,
    phase: u32,
    channel: u32,
}

/// The phase of the link messages at an instant: after every delivery.
const LINK_PHASE: u32 = u32::MAX - 1;
/// The phase of the deadlines at an instant: last.
const DEADLINE_PHASE: u32 = u32::MAX;

/// What a group reports for the observer (and the tool), kept with its [`Order`] until the
/// window is over, then told in the one-thread order.
#[derive(Clone, Copy)]
enum Note {
    Delivered(Delivery),
    Event(usize, Side, ChannelEvent),
    /// A channel's output of its node's watched SRDO after a call (node, side, value), and
    /// whether the call set outputs (then the node's effective output is compared).
    Output(usize, Side, u64, bool),
}

/// The shortest time from a channel's writing a link message to the arrival of its frame
/// delimiter at the other channel: the shortest frame of the link (`dual_channel::link`:
/// sequence, tag and the shortest body, CRC-32, one COBS code byte, the delimiter: 10 bytes)
/// at [`LINK_BYTE_TIME`]. A window is never longer ([`Engine::run_until`]), so what one
/// channel writes in a window reaches the other after it, whichever group that one is in.
const LINK_LATENCY: Duration = Duration::from_micros(10 * LINK_BYTE_TIME.as_micros());

/// The deadlines of a group's channels (by their place in the group) as a tournament tree:
/// each inner node holds the earlier of its two children, so the earliest deadline is at the
/// root, a change costs a walk up the tree, and no entry goes stale (a heap of every deadline
/// set, with the stale ones skipped, spent about a tenth of a group's window in sifting).
#[derive(Clone, Debug)]
struct Deadlines {
    /// Leaves from `tree[leaves]` on; `tree[1]` is the root.
    leaves: usize,
    tree: Vec<Instant>,
}

impl Deadlines {
    /// `count` deadlines, none set ([`Instant::NEVER`]).
    fn new(count: usize) -> Self {
        let leaves = count.next_power_of_two().max(1);
        Deadlines {
            leaves,
            tree: vec![Instant::NEVER; 2 * leaves],
        }
    }

    fn set(&mut self, place: usize, at: Instant) {
        let mut node = self.leaves + place;
        self.tree[node] = at;
        while node > 1 {
            node /= 2;
            self.tree[node] = self.tree[2 * node].min(self.tree[2 * node + 1]);
        }
    }

    fn earliest(&self) -> Instant {
        self.tree[1]
    }

    /// Calls `due` with every place whose deadline is at or before `now`, in order.
    fn due(&self, now: Instant, mut due: impl FnMut(usize)) {
        if self.tree[1] > now {
            return;
        }
        // Depth first, the earlier place first; only into subtrees with a deadline due.
        let mut stack = [0usize; 64];
        let (mut top, mut node) = (0, 1);
        loop {
            if node >= self.leaves {
                due(node - self.leaves);
            } else {
                let (left, right) = (2 * node, 2 * node + 1);
                if self.tree[right] <= now {
                    stack[top] = right;
                    top += 1;
                }
                if self.tree[left] <= now {
                    node = left;
                    continue;
                }
            }
            if top == 0 {
                return;
            }
            top -= 1;
            node = stack[top];
        }
    }
}

/// Link bytes on their way between groups: runs of bytes (the receiving channel, the first
/// byte's arrival, the bytes in `bytes`) and the arrivals of their frame delimiters.
#[derive(Default)]
struct Links {
    runs: Vec<(u32, Instant, std::ops::Range<usize>)>,
    bytes: Vec<u8>,
    ends: Vec<(Instant, u32)>,
}

impl Links {
    fn clear(&mut self) {
        self.runs.clear();
        self.bytes.clear();
        self.ends.clear();
    }
}

/// A share of the channels, with everything that concerns them alone: their deadlines,
/// their link bytes arriving, their acceptance filters. A group runs a window of simulated
/// time on its own (on the second thread, for one of two) and hands back what it put on the
/// bus, what it wrote on the links, and what the observer is to hear.
struct Group {
    channels: Vec<SimChannel>,
    /// Its place in `channels` of each channel of the network (of its own only).
    local: Vec<usize>,
    unfiltered: bool,
    /// The instant of the calls being made.
    now: Instant,
    /// Its channels' deadlines, by their place in `channels`.
    deadlines: Deadlines,
    /// Link frame delimiters arriving: (instant, receiving channel).
    link_ends: EventHeap,
    /// Its Operational channels per identifier, in channel order.
    subscribers: Vec<Vec<u32>>,
    /// Its channels not in Operational (they get every frame), in channel order.
    open: Vec<u32>,
    scratch: Scratch,
    recipients: Vec<u32>,
    due: Vec<u32>,
    /// The window: the deliveries at instants before `until`, earliest first (at one instant
    /// in the order the bus made them).
    deliveries: Vec<Delivery>,
    until: Instant,
    /// Its next event ([`Group::next_event`]) after its last window or call, so that the
    /// engine does not reach into a group the other thread ran.
    next: Instant,
    /// What its calls put on the bus, with their instants, in the order they were made.
    sends: Vec<(Instant, usize, CanFrame)>,
    /// What its calls wrote on the links, and what the other channels wrote to its own,
    /// not yet on their wires (they are put there when it runs next).
    outbox: Links,
    inbox: Links,
    /// The first frame delimiter's arrival in `inbox`.
    inbox_first: Instant,
    notes: Vec<(Order, Note)>,
}

impl Group {
    /// The channels `channels` of a network of `count` channels, as at power-on: every
    /// channel due at once and open to every frame.
    fn new(channels: Vec<SimChannel>, count: usize) -> Self {
        let mut local = vec![usize::MAX; count];
        let mut open = Vec::new();
        for (k, sim) in channels.iter().enumerate() {
            let c = channel(sim.index, sim.side);
            local[c as usize] = k;
            open.push(c);
        }
        let mut deadlines = Deadlines::new(channels.len());
        for (k, sim) in channels.iter().enumerate() {
            deadlines.set(k, sim.deadline);
        }
        Group {
            channels,
            local,
            unfiltered: false,
            now: Instant::ZERO,
            deadlines,
            link_ends: EventHeap::default(),
            subscribers: vec![Vec::new(); IDENTIFIERS],
            open,
            scratch: Scratch::default(),
            recipients: Vec::new(),
            due: Vec::new(),
            deliveries: Vec::new(),
            until: Instant::ZERO,
            next: Instant::ZERO,
            sends: Vec::new(),
            outbox: Links::default(),
            inbox: Links::default(),
            inbox_first: Instant::NEVER,
            notes: Vec::new(),
        }
    }

    fn channel(&self, c: u32) -> &SimChannel {
        &self.channels[self.local[c as usize]]
    }

    fn channel_mut(&mut self, c: u32) -> &mut SimChannel {
        let k = self.local[c as usize];
        &mut self.channels[k]
    }

    /// The instant of its next deadline or link message.
    fn next_event(&mut self) -> Instant {
        let link = self.link_ends.peek().map_or(Instant::NEVER, |(at, _)| at);
        self.deadlines.earliest().min(link)
    }

    /// Every channel whose deadline is due at `now` into `due`, in channel order.
    fn take_due_timers(&mut self, now: Instant) {
        let (channels, due) = (&self.channels, &mut self.due);
        self.deadlines.due(now, |k| {
            due.push(channel(channels[k].index, channels[k].side));
        });
    }

    /// Puts what the other channels wrote to its own on their wires, and their frame
    /// delimiters among its events.
    fn apply_inbox(&mut self) {
        let mut inbox = std::mem::take(&mut self.inbox);
        for (c, first, range) in inbox.runs.drain(..) {
            self.channel_mut(c)
                .incoming
                .push_run(first, &inbox.bytes[range]);
        }
        for &(at, c) in &inbox.ends {
            self.link_ends.push(at, c);
        }
        inbox.clear();
        self.inbox = inbox;
        self.inbox_first = Instant::NEVER;
    }

    /// Takes what `links` holds for its own channels into its inbox (on two threads all of
    /// it: the other group's channels write only to this one's).
    fn receive_links(&mut self, links: &Links) {
        let own = |c: u32| self.local[c as usize] != usize::MAX;
        for &(c, first, ref range) in links.runs.iter().filter(|(c, ..)| own(*c)) {
            let start = self.inbox.bytes.len();
            self.inbox
                .bytes
                .extend_from_slice(&links.bytes[range.clone()]);
            let end = self.inbox.bytes.len();
            self.inbox.runs.push((c, first, start..end));
        }
        for &(at, c) in links.ends.iter().filter(|(_, c)| own(*c)) {
            self.inbox.ends.push((at, c));
            self.inbox_first = self.inbox_first.min(at);
        }
    }

    /// The instant it has something to do next, link bytes in its inbox included.
    fn pending(&self) -> Instant {
        self.next.min(self.inbox_first)
    }

    /// Whether it has anything to do before `until` with the deliveries `window`: its own
    /// events, or a delivery that one of its channels handles. (A delivery that none
    /// handles polls only channels that are due then: its own events.)
    fn has_work(&self, window: &[Delivery], until: Instant) -> bool {
        self.pending() < until
            || (!window.is_empty() && (self.unfiltered || !self.open.is_empty()))
            || window.iter().any(|delivery| {
                !self.subscribers[usize::from(delivery.frame.id().raw())].is_empty()
            })
    }

    /// Every instant before `until` at which it has something to do, as one thread does it
    /// for the whole network: at each instant the deliveries, the link messages ending, then
    /// the deadlines due. Nothing from the rest of the network reaches it before `until` but
    /// the deliveries it was given.
    fn run_window(&mut self) {
        self.apply_inbox();
        let deliveries = std::mem::take(&mut self.deliveries);
        let mut next = 0;
        loop {
            let mut at = self.next_event();
            if let Some(delivery) = deliveries.get(next) {
                at = at.min(delivery.at);
            }
            if at >= self.until {
                break;
            }
            self.now = at;
            let mut phase = 0;
            while let Some(delivery) = deliveries.get(next).filter(|d| d.at <= at) {
                self.deliver(delivery, phase);
                next += 1;
                phase += 1;
            }
            self.due.clear();
            while let Some((end, c)) = self.link_ends.peek() {
                if end > at {
                    break;
                }
                self.link_ends.pop();
                self.due.push(c);
            }
            self.call_due(Action::Link(at), LINK_PHASE, false);
            self.take_due_timers(at);
            self.call_due(Action::Poll, DEADLINE_PHASE, true);
        }
        self.deliveries = deliveries;
        self.next = self.next_event();
    }

    /// The calls on the channels in `due` (in channel order, each once), each with `action`
    /// (a deadline call only if the channel's deadline is still due).
    fn call_due(&mut self, action: Action, phase: u32, deadline_only: bool) {
        let mut due = std::mem::take(&mut self.due);
        due.sort_unstable();
        due.dedup();
        for &c in &due {
            if !deadline_only || self.channel(c).deadline <= self.now {
                self.call(c, action, phase);
            }
        }
        due.clear();
        self.due = due;
    }

    /// One frame reaches every channel of the group that handles it.
    fn deliver(&mut self, delivery: &Delivery, phase: u32) {
        let now = self.now;
        let mut recipients = std::mem::take(&mut self.recipients);
        recipients.clear();
        let sender = delivery.from.wrapping_sub(1) as u32;
        let id = usize::from(delivery.frame.id().raw());
        if self.unfiltered {
            recipients.extend(self.channels.iter().map(|sim| channel(sim.index, sim.side)));
            recipients.sort_unstable();
        } else {
            recipients.extend_from_slice(&self.subscribers[id]);
            recipients.extend_from_slice(&self.open);
            // Those not addressed but due are polled, as every delivery polls every channel
            // in `DualNetwork`.
            self.due.clear();
            self.take_due_timers(now);
            recipients.extend_from_slice(&self.due);
            recipients.sort_unstable();
            recipients.dedup();
        }
        for &c in &recipients {
            let deadline = self.channel(c).deadline;
            if c == sender {
                // Not delivered back to its sender; if it was due, the deadline phase polls it.
                continue;
            }
            let handles = self.unfiltered
                || !self.channel(c).operational
                || self.subscribers[id].binary_search(&c).is_ok();
            if handles {
                self.call(c, Action::Frame(delivery.frame), phase);
            } else if deadline <= now {
                self.call(c, Action::Poll, phase);
            }
        }
        self.due.clear();
        self.recipients = recipients;
    }

    /// Runs `action` on channel `c`, polls it, and keeps what it handed out: its timer here,
    /// its frames, link bytes and what the observer is to hear for the engine.
    fn call(&mut self, c: u32, action: Action, phase: u32) {
        let now = self.now;
        let mut out = std::mem::take(&mut self.scratch);
        let k = self.local[c as usize];
        let sim = &mut self.channels[k];
        run_call(sim, now, action, &mut out);
        let (index, side) = (sim.index, sim.side);
        let old_output = std::mem::replace(&mut sim.own_output, out.own_output);
        if !out.link.is_empty() {
            // The other channel's wire: its frame delimiters arrive after this window
            // ([`LINK_LATENCY`]), whichever group the other channel is in.
            let (to, until) = (c ^ 1, self.until);
            let ends = &mut self.outbox.ends;
            let first = sim.outgoing.write(now, &out.link, |end| {
                assert!(
                    end >= until,
                    "a link frame written at {now:?} arrives at {end:?}, inside the window \
                     that wrote it (up to {until:?}): the window is longer than the link's \
                     latency"
                );
                ends.push((end, to));
            });
            let start = self.outbox.bytes.len();
            self.outbox.bytes.extend_from_slice(&out.link);
            let end = self.outbox.bytes.len();
            self.outbox.runs.push((to, first, start..end));
        }
        if out.timer.is_some() {
            self.deadlines.set(k, self.channels[k].deadline);
        }
        let participant = c as usize + 1;
        for &frame in &out.frames {
            self.sends.push((now, participant, frame));
        }
        let order = Order {
            at: now,
            phase,
            channel: c + 1,
        };
        for event in &out.events {
            self.notes.push((order, Note::Event(index, side, *event)));
        }
        if out.own_output != old_output || out.outputs > 0 {
            let reported = out.outputs > 0;
            let note = Note::Output(index, side, out.own_output, reported);
            self.notes.push((order, note));
        }
        self.scratch = out;
        self.update_filter(c);
    }

    /// Moves a channel between "every frame" and its identifiers when it entered or left
    /// Operational.
    fn update_filter(&mut self, c: u32) {
        let sim = self.channel(c);
        let (state, config) = sim.state();
        let operational = state == NmtState::Operational;
        if operational == sim.operational {
            return;
        }
        let ids = accepted(sim.id, config);
        self.channel_mut(c).operational = operational;
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
}

/// The network: participant 0 is the tool; node `i`'s channel A is participant `2i + 1`,
/// channel B `2i + 2` (as in `DualNetwork`); background senders follow the nodes.
///
/// **Windows.** The channels are split into groups ([`Engine::set_threads`]: one, or two
/// that run on two threads; with two, each node has one channel in each, so that the work a
/// frame causes, which both channels of its receivers do alike, falls to both threads). The
/// groups touch nothing of each other's but the bus and the links. The engine advances all
/// groups through a window of simulated time at once, then puts what they sent on the bus in
/// the order of its instants, and what they wrote on the links on the wires. A window ends
/// where a frame not yet arbitrated could first reach a receiver (the end of the frame on
/// the bus, or the window's start if the bus is free, plus the shortest frame's time,
/// [`Bus::shortest_frame`]), and at the latest after the link's latency (`LINK_LATENCY`).
/// Every delivery and link message before its end is known when it starts, so within it the
/// groups are independent; the frames they send in it compete in arbitrations whose frames
/// arrive after it. The calls are the same, at the same instants, in the same order per
/// channel, as one thread stepping from instant to instant makes them, and the observer hears
/// everything in that one-thread order (`Order`), so the result does not depend on the
/// number of groups (`tests/tests/fullnet.rs` compares traces, events and reports).
///
/// **Two threads** (`Lane`): each thread runs one group and its own copy of the bus and
/// its traffic, which stay alike because both put the same frames on them in the same order;
/// the threads meet once per window to hand each other what their group sent and wrote
/// (`Exchange`). Nothing waits for a thread that runs the bus alone.
pub struct Engine<O: Observer> {
    /// Simulated time.
    pub now: Instant,
    /// The bus.
    pub bus: Bus,
    /// Who watches.
    pub observer: O,
    /// Deliver every frame to every channel (as `DualNetwork` does) instead of filtering:
    /// for the test that shows filtering changes nothing.
    pub unfiltered: bool,
    /// Every frame as delivered, when `Some` (tests only: an hour would not fit).
    pub trace: Option<Vec<(Instant, CanFrame, usize)>>,
    /// The groups.
    groups: Vec<Group>,
    /// The group of each channel.
    place: Vec<usize>,
    node_count: usize,
    /// Per node whose output is watched: the watched SRDO's output of each channel as last
    /// applied, and their AND as last reported.
    outputs: Vec<Option<([u64; 2], u64)>>,
    /// Whether any window or call has run (the groups are set before).
    started: bool,
    traffic: Traffic,
    tool_inbox: VecDeque<CanFrame>,
    link_period: Duration,
    /// The second thread and where the two meet, from the first run on two threads.
    second: Option<(Handoff<Box<WorkerRun>>, Arc<Exchange>)>,
    /// The windows run so far on two threads (both count them alike).
    epoch: u64,
    /// The words of a [`Board`] the two threads use ([`Engine::limit_board`]).
    board_limit: usize,
    /// A window's deliveries, the groups' frames and notes merged: reused.
    window: Vec<Delivery>,
    sends: Vec<(Instant, usize, CanFrame)>,
    notes: Vec<(Order, Note)>,
}

/// Channel number `c`: node `c / 2`, side A for even, B for odd; participant `c + 1`.
fn channel(node: usize, side: Side) -> u32 {
    (2 * node + side as usize) as u32
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

/// What happens on the bus besides the groups' calls: frames on their way to the receivers
/// and the background senders. On two threads each keeps a copy (with one of the bus).
#[derive(Clone, Default)]
struct Traffic {
    in_flight: Vec<Delivery>,
    senders: Vec<Sender>,
    sender_due: EventHeap,
}

impl Traffic {
    /// The next delivery, background frame or arbitration after the instant `now`.
    fn next(&self, bus: &Bus, now: Instant) -> Instant {
        let mut next = Instant::NEVER;
        for delivery in &self.in_flight {
            next = next.min(delivery.at);
        }
        if let Some((at, _)) = self.sender_due.peek() {
            next = next.min(at);
        }
        if let Some(start) = bus.next_start(now) {
            next = next.min(start);
        }
        next
    }

    /// The end (exclusive) of the window that starts at `start`, in a run up to `end`: the
    /// frame on the bus (or the first one arbitrated from `start` on) reaches the receivers
    /// at its end, the next one a shortest frame later at the earliest; a link message
    /// written from `start` on arrives a link latency later.
    fn window_end(bus: &Bus, start: Instant, end: Instant) -> Instant {
        let reach = bus.free_at().max(start) + bus.shortest_frame();
        reach
            .min(start + LINK_LATENCY)
            .min(end + Duration::from_micros(1))
    }

    /// Takes the deliveries before `until` into `window`, earliest first (at one instant in
    /// the order the bus made them).
    fn take_window(&mut self, until: Instant, window: &mut Vec<Delivery>) {
        window.clear();
        let mut index = 0;
        while index < self.in_flight.len() {
            if self.in_flight[index].at < until {
                window.push(self.in_flight.remove(index));
            } else {
                index += 1;
            }
        }
        // Stable: deliveries at one instant keep the order the bus made them in.
        window.sort_by_key(|delivery| delivery.at);
    }

    /// The instants from the one after `now` up to (not including) `until`: what the groups
    /// sent at each (`sends`, by instant), the background senders, the arbitration.
    fn replay(
        &mut self,
        bus: &mut Bus,
        sends: &[(Instant, usize, CanFrame)],
        now: Instant,
        until: Instant,
    ) {
        let mut next = 0;
        let mut now = now;
        loop {
            let mut at = sends.get(next).map_or(Instant::NEVER, |(at, ..)| *at);
            if let Some((due, _)) = self.sender_due.peek() {
                at = at.min(due);
            }
            if let Some(start) = bus.next_start(now) {
                at = at.min(start);
            }
            if at >= until {
                break;
            }
            now = at;
            while let Some(&(_, from, frame)) = sends.get(next).filter(|(sent, ..)| *sent <= at) {
                bus.send(from, frame);
                next += 1;
            }
            self.background(bus, at);
            if bus.next_start(at) == Some(at) {
                bus.arbitrate_into(at, &mut self.in_flight);
            }
        }
    }

    /// The background senders due at `now` queue their frames.
    fn background(&mut self, bus: &mut Bus, now: Instant) {
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
            bus.send(participant, frame);
        }
    }
}

/// The notes of a window's deliveries, each before the calls it causes.
fn delivery_notes(window: &[Delivery], notes: &mut Vec<(Order, Note)>) {
    let mut phase = 0;
    for (k, delivery) in window.iter().enumerate() {
        phase = match k.checked_sub(1).map(|before| window[before].at) {
            Some(at) if at == delivery.at => phase + 1,
            _ => 0,
        };
        let order = Order {
            at: delivery.at,
            phase,
            channel: 0,
        };
        notes.push((order, Note::Delivered(*delivery)));
    }
}

/// What one thread of a two-thread run published for the other after a window, when it
/// does not fit its [`Board`].
#[derive(Default)]
struct Published {
    /// Its group's frames for the bus.
    sends: Vec<(Instant, usize, CanFrame)>,
    /// What its group's channels wrote on the links (all for the other group's channels).
    links: Links,
}

/// Words of a [`Board`] after its epoch: a header, the group's next event, then the
/// window's frames (three words each) and link runs (two words and the bytes, eight a
/// word), as many as fit.
const BOARD_WORDS: usize = 32;

/// What one thread publishes after a window for the other to read: the window's number, in
/// a line of its own that the other spins on (stored last, with release ordering, so that
/// the reader that sees it sees the words), and the words, in lines the reader then fetches
/// all at once. What does not fit goes through the [`Exchange`]'s slots instead, whose
/// lock and vectors cost the reader more lines, one after the other, from the other core.
/// Measured (`fullnet network --minutes 1`, alternating, with the cores' round trip
/// measured before and after each pair): 1.40 to 1.46 s against 1.67 to 1.70 s through the
/// slots when a round trip between the cores took about 400 ns, 0.96 to 1.02 s against 0.94
/// to 0.97 s when it took about 50 ns; this machine has had both within minutes.
struct Board {
    epoch: Padded<AtomicU64>,
    words: Padded<[AtomicU64; BOARD_WORDS]>,
}

impl Default for Board {
    fn default() -> Self {
        Board {
            epoch: Padded(AtomicU64::new(0)),
            words: Padded(std::array::from_fn(|_| AtomicU64::new(0))),
        }
    }
}

/// The header word of a [`Board`]: how many frames and link runs follow, or that the
/// window's frames and runs are in the slot.
const OVERFLOW: u64 = 1 << 32;

/// The three words of a frame sent at `at` by `participant`.
fn send_words(at: Instant, participant: usize, frame: &CanFrame) -> [u64; 3] {
    [
        at.as_micros(),
        participant as u64
            | u64::from(frame.id().raw()) << 16
            | u64::from(frame.dlc()) << 32
            | u64::from(frame.is_remote()) << 40,
        u64::from_le_bytes(*frame.raw_data()),
    ]
}

/// The frame [`send_words`] wrote.
fn send_from_words(words: [u64; 3]) -> (Instant, usize, CanFrame) {
    let [at, head, data] = words;
    let id = shared::CanId::new((head >> 16 & 0x7FF) as u16).expect("an 11-bit identifier");
    let dlc = (head >> 32 & 0xF) as u8;
    let frame = if head >> 40 & 1 == 1 {
        CanFrame::remote(id, dlc)
    } else {
        CanFrame::from_parts(id, dlc, data.to_le_bytes())
    }
    .expect("a frame the other thread's channel sent");
    (Instant::from_micros(at), (head & 0xFFFF) as usize, frame)
}

/// Writes the window's `sends` and link `runs` (bytes in `bytes`) into `words` from index
/// 2 on; `false` when they take more than `limit` words (at most [`BOARD_WORDS`]) with the
/// two before them.
fn board_write(
    words: &[AtomicU64; BOARD_WORDS],
    sends: &[(Instant, usize, CanFrame)],
    links: &Links,
    limit: usize,
) -> bool {
    let needed = 2
        + 3 * sends.len()
        + links
            .runs
            .iter()
            .map(|(_, _, range)| 2 + range.len().div_ceil(8))
            .sum::<usize>();
    if needed > limit.min(BOARD_WORDS) || sends.len() > 0xFFFF || links.runs.len() > 0xFFFF {
        return false;
    }
    let mut next = 2;
    let mut put = |word: u64| {
        words[next].store(word, Ordering::Relaxed);
        next += 1;
    };
    for (at, participant, frame) in sends {
        send_words(*at, *participant, frame)
            .into_iter()
            .for_each(&mut put);
    }
    for (c, first, range) in &links.runs {
        put(first.as_micros());
        put(u64::from(*c) | (range.len() as u64) << 32);
        for chunk in links.bytes[range.clone()].chunks(8) {
            let mut word = [0u8; 8];
            word[..chunk.len()].copy_from_slice(chunk);
            put(u64::from_le_bytes(word));
        }
    }
    true
}

/// Reads what [`board_write`] wrote (`sends` frames and `runs` link runs) into `sends` and
/// `links`, with the arrival of every frame delimiter of the runs.
fn board_read(
    words: &[AtomicU64; BOARD_WORDS],
    header: u64,
    sends: &mut Vec<(Instant, usize, CanFrame)>,
    links: &mut Links,
) {
    let mut next = 2;
    let mut take = || {
        let word = words[next].load(Ordering::Relaxed);
        next += 1;
        word
    };
    for _ in 0..header & 0xFFFF {
        sends.push(send_from_words([take(), take(), take()]));
    }
    for _ in 0..header >> 16 & 0xFFFF {
        let first = Instant::from_micros(take());
        let head = take();
        let (c, len) = ((head & 0xFFFF_FFFF) as u32, (head >> 32) as usize);
        let start = links.bytes.len();
        while links.bytes.len() < start + len {
            let word = take().to_le_bytes();
            let count = (start + len - links.bytes.len()).min(8);
            links.bytes.extend_from_slice(&word[..count]);
        }
        links.runs.push((c, first, start..start + len));
        // Byte k of a run arrives k byte times after the first (`WireOut::write`).
        for (k, _) in links.bytes[start..]
            .iter()
            .enumerate()
            .filter(|(_, b)| **b == 0)
        {
            let at = first + Duration::from_micros(k as u64 * LINK_BYTE_TIME.as_micros());
            links.ends.push((at, c));
        }
    }
}

/// Where the two threads of a run meet once per window: what each published, in two boards
/// (and two overflow slots) each, by the window's parity (a thread that has gone on to the
/// next window cannot overwrite what the other has yet to read: it publishes that window in
/// the other board, and the one after only once the other has published, after reading);
/// and the second thread's notes for the observer, which the engine's thread collects now
/// and then, not every window.
#[derive(Default)]
struct Exchange {
    boards: [[Board; 2]; 2],
    slots: [[Padded<Mutex<Published>>; 2]; 2],
    notes: Padded<Mutex<Vec<(Order, Note)>>>,
    /// Set when the engine's thread stopped in the middle of a run (it panicked): the
    /// second thread stops waiting for it.
    abandoned: AtomicBool,
}

/// A value alone in its cache lines (128 bytes: two lines, as adjacent-line prefetching
/// fetches pairs), so that what one thread writes does not take from the other thread a line
/// it reads for something else.
#[derive(Default)]
#[repr(align(128))]
struct Padded<T>(T);

impl<T> std::ops::Deref for Padded<T> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.0
    }
}

/// Locks `mutex`; a panic while it was held (there is none: the locks only move vectors)
/// leaves its value as it was.
fn lock<T>(mutex: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(PoisonError::into_inner)
}

/// How many windows the engine's thread runs between two collections of the second
/// thread's notes (and at the end of every run).
const NOTES_EVERY: u64 = 256;

/// Spins after which a thread waiting for the other's window yields its core at every
/// further look: far more than a window's wait while both threads run (a few spins), so that
/// only a thread whose partner is not running (the machine busy with other work) yields.
const YIELD_AFTER: u32 = 1 << 14;

/// One thread's part of a run on two threads.
struct Lane {
    /// 0: the engine's thread (which tells the observer), 1: the second thread.
    side: usize,
    exchange: Arc<Exchange>,
    /// The windows run so far (both threads count alike).
    epoch: u64,
    /// The other group's next event.
    peer: Instant,
    window: Vec<Delivery>,
    sends: Vec<(Instant, usize, CanFrame)>,
    links: Links,
    /// The words of a board it uses ([`Engine::limit_board`]).
    limit: usize,
    /// Notes not yet told (on the engine's thread): its own group's and the deliveries'.
    notes: Vec<(Order, Note)>,
}

impl Lane {
    /// Runs `group` up to `end`, window by window in step with the other thread, with its
    /// own `bus` and `traffic` from the instant `now`; `tell` hears both groups' notes in
    /// the one-thread order (on the engine's thread, every [`NOTES_EVERY`] windows and at
    /// the end; the second thread leaves its notes in the exchange). `alive` says whether
    /// the other thread still runs.
    #[allow(clippy::too_many_arguments)]
    fn run(
        &mut self,
        group: &mut Group,
        bus: &mut Bus,
        traffic: &mut Traffic,
        now: &mut Instant,
        end: Instant,
        alive: impl Fn() -> bool,
        mut tell: impl FnMut(&mut Vec<(Order, Note)>),
    ) {
        let other = 1 - self.side;
        loop {
            let start = group.pending().min(self.peer).min(traffic.next(bus, *now));
            if start > end {
                break;
            }
            let until = Traffic::window_end(bus, start, end);
            traffic.take_window(until, &mut self.window);
            if group.has_work(&self.window, until) {
                group.until = until;
                group.deliveries.clone_from(&self.window);
                group.run_window();
            }
            self.epoch += 1;
            let parity = (self.epoch % 2) as usize;
            let outbox_first = group.outbox.ends.iter().map(|&(at, _)| at).min();
            if self.side == 1 && !group.notes.is_empty() {
                lock(&self.exchange.notes).append(&mut group.notes);
            }
            let board = &self.exchange.boards[self.side][parity];
            let header = if board_write(&board.words, &group.sends, &group.outbox, self.limit) {
                group.sends.len() as u64 | (group.outbox.runs.len() as u64) << 16
            } else {
                let mut published = lock(&self.exchange.slots[self.side][parity]);
                published.sends.clear();
                published.sends.extend_from_slice(&group.sends);
                std::mem::swap(&mut published.links, &mut group.outbox);
                OVERFLOW
            };
            board.words[0].store(header, Ordering::Relaxed);
            board.words[1].store(group.pending().as_micros(), Ordering::Relaxed);
            board.epoch.store(self.epoch, Ordering::Release);
            group.outbox.clear();
            let theirs = &self.exchange.boards[other][parity];
            let mut spins = 0u32;
            while theirs.epoch.load(Ordering::Acquire) != self.epoch {
                std::hint::spin_loop();
                spins = spins.wrapping_add(1);
                if spins % (1 << 12) == 0 {
                    assert!(
                        alive() && !self.exchange.abandoned.load(Ordering::Acquire),
                        "the full network's other thread stopped during a run (it panicked)"
                    );
                }
                if spins > YIELD_AFTER {
                    // The other thread is not running (the cores are busy with other work):
                    // let it have this core rather than spin through its time slice.
                    std::thread::yield_now();
                }
            }
            // Group 0's frames, then group 1's, on both threads: the buses stay alike.
            self.sends.clear();
            if self.side == 0 {
                self.sends.extend_from_slice(&group.sends);
            }
            let header = theirs.words[0].load(Ordering::Relaxed);
            let peer_pending = Instant::from_micros(theirs.words[1].load(Ordering::Relaxed));
            self.links.clear();
            if header == OVERFLOW {
                let published = lock(&self.exchange.slots[other][parity]);
                self.sends.extend_from_slice(&published.sends);
                group.receive_links(&published.links);
            } else {
                board_read(&theirs.words, header, &mut self.sends, &mut self.links);
                group.receive_links(&self.links);
            }
            if self.side == 1 {
                self.sends.extend_from_slice(&group.sends);
            }
            group.sends.clear();
            self.peer = outbox_first.map_or(peer_pending, |first| peer_pending.min(first));
            self.sends.sort_by_key(|(at, ..)| *at);
            traffic.replay(bus, &self.sends, *now, until);
            *now = (*now).max(Instant::from_micros(until.as_micros() - 1));
            if self.side == 0 {
                delivery_notes(&self.window, &mut self.notes);
                self.notes.append(&mut group.notes);
                if self.epoch % NOTES_EVERY == 0 {
                    self.tell_notes(&mut tell, until);
                }
            }
        }
        if self.side == 0 {
            // The second thread has published its last window, its notes before it.
            self.tell_notes(&mut tell, Instant::NEVER);
        }
    }

    /// Tells the notes of both threads collected so far from before `before`, in the
    /// one-thread order. The second thread may have run the next window already and left
    /// its notes too: they wait with this thread's of that window, which come later.
    fn tell_notes(&mut self, tell: &mut impl FnMut(&mut Vec<(Order, Note)>), before: Instant) {
        self.notes.append(&mut lock(&self.exchange.notes));
        // Stable: what one call reports keeps its order (its notes come from one group).
        self.notes.sort_by_key(|(order, _)| *order);
        let count = self.notes.partition_point(|(order, _)| order.at < before);
        let mut told: Vec<(Order, Note)> = self.notes.drain(..count).collect();
        tell(&mut told);
    }
}

/// A run of the second thread: its lane, its group, its copy of the bus and the traffic.
struct WorkerRun {
    lane: Lane,
    group: Group,
    bus: Bus,
    traffic: Traffic,
    now: Instant,
    end: Instant,
}

/// Tells the observer (and the trace, and the tool) one note; `outputs` keeps each watched
/// node's outputs (see [`Engine`]).
fn hear<O: Observer>(
    observer: &mut O,
    trace: &mut Option<Vec<(Instant, CanFrame, usize)>>,
    tool_inbox: &mut VecDeque<CanFrame>,
    outputs: &mut [Option<([u64; 2], u64)>],
    at: Instant,
    note: Note,
) {
    match note {
        Note::Delivered(delivery) => {
            observer.delivered(delivery.at, &delivery.frame, delivery.from, delivery.bits);
            if let Some(trace) = trace {
                trace.push((delivery.at, delivery.frame, delivery.from));
            }
            if delivery.from != 0 {
                tool_inbox.push_back(delivery.frame);
                if tool_inbox.len() > 64 {
                    tool_inbox.pop_front();
                }
            }
        }
        Note::Event(index, side, event) => observer.event(at, index, side, &event),
        Note::Output(index, side, own, reported) => {
            let Some((outputs, output)) = &mut outputs[index] else {
                return;
            };
            outputs[side as usize] = own;
            if reported {
                let value = outputs[0] & outputs[1];
                if value != *output {
                    *output = value;
                    observer.output(at, index, value);
                }
            }
        }
    }
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
        let node_count = nodes.len();
        let mut channels = Vec::with_capacity(2 * node_count);
        for (index, (id, image)) in nodes.into_iter().enumerate() {
            let image = image.unwrap_or_default();
            let a = Runtime::new(
                device_config(id, "dual node, channel A"),
                image.clone(),
                ChannelA::default(),
                Instant::ZERO,
                link_period,
            )
            .expect("valid device");
            let b = Runtime::new(
                device_config(id, "dual node, channel B"),
                image,
                ChannelB::new(&B_INPUTS).expect("valid inputs"),
                Instant::ZERO,
                link_period,
            )
            .expect("valid device");
            for (side, runtime) in [
                (Side::A, ChannelRuntime::A(a)),
                (Side::B, ChannelRuntime::B(b)),
            ] {
                channels.push(SimChannel {
                    runtime,
                    index,
                    id,
                    side,
                    incoming: Wire::default(),
                    outgoing: WireOut::default(),
                    deadline: Instant::ZERO,
                    operational: false,
                    watched: None,
                    own_output: 0,
                });
            }
        }
        let mut bus = Bus::new(bit_rate, 1 + 2 * node_count);
        // Each channel's whole transmit queue by identifier, as the board layer keeps it
        // (`dual_channel::transmit_queue`) and `DualNetwork` and the hub model it: a node's
        // own heartbeat or EMCY never holds back its SRDO or its GFC.
        bus.set_transmit_mailboxes(ORDERED_BY_IDENTIFIER);
        Engine {
            now: Instant::ZERO,
            bus,
            observer,
            unfiltered: false,
            trace: None,
            groups: vec![Group::new(channels, 2 * node_count)],
            place: vec![0; 2 * node_count],
            node_count,
            outputs: vec![None; node_count],
            started: false,
            traffic: Traffic::default(),
            tool_inbox: VecDeque::new(),
            link_period,
            second: None,
            epoch: 0,
            board_limit: BOARD_WORDS,
            window: Vec::new(),
            sends: Vec::new(),
            notes: Vec::new(),
        }
    }

    /// Runs the network on `threads` threads (1 or 2): its channels split into as many
    /// groups, with two each node's channel A in one and its channel B in the other (A in
    /// the first for even nodes, in the second for odd ones, as channel B's code differs).
    /// The result is the same either way. Before anything runs.
    ///
    /// # Panics
    /// When the network has run already, or `threads` is neither 1 nor 2.
    pub fn set_threads(&mut self, threads: usize) {
        assert!(!self.started, "the threads are set before the network runs");
        assert!(
            matches!(threads, 1 | 2),
            "the full network runs on one or two threads, not {threads}"
        );
        let count = 2 * self.node_count;
        let mut channels: Vec<Option<SimChannel>> = Vec::with_capacity(count);
        channels.resize_with(count, || None);
        for group in self.groups.drain(..) {
            for sim in group.channels {
                let c = channel(sim.index, sim.side) as usize;
                channels[c] = Some(sim);
            }
        }
        // Channel c is node c / 2's side c % 2: with two groups, (c + c / 2) % 2 puts A and B
        // of each node apart and alternates which one the first group takes.
        self.place = (0..count)
            .map(|c| if threads == 1 { 0 } else { (c + c / 2) % 2 })
            .collect();
        let mut shares: Vec<Vec<SimChannel>> = (0..threads).map(|_| Vec::new()).collect();
        for (c, sim) in channels.into_iter().enumerate() {
            shares[self.place[c]].push(sim.expect("every channel in one group"));
        }
        self.groups = shares
            .into_iter()
            .map(|share| Group::new(share, count))
            .collect();
    }

    /// For tests: on two threads, a window whose frames and link bytes take more than
    /// `words` words of the threads' board (two of them the header) goes through the
    /// exchange's slots instead (with 2, every window that sends or writes anything).
    pub fn limit_board(&mut self, words: usize) {
        self.board_limit = words;
    }

    /// The link heartbeat period.
    pub fn link_period(&self) -> Duration {
        self.link_period
    }

    fn sim(&self, index: usize, side: Side) -> &SimChannel {
        let c = channel(index, side);
        self.groups[self.place[c as usize]].channel(c)
    }

    /// Channel `side` of node `index`.
    pub fn runtime(&self, index: usize, side: Side) -> &ChannelRuntime {
        &self.sim(index, side).runtime
    }

    /// Channel A of node `index`.
    pub fn channel_a(&self, index: usize) -> &ChannelARuntime {
        match self.runtime(index, Side::A) {
            ChannelRuntime::A(runtime) => runtime,
            ChannelRuntime::B(_) => unreachable!("side A holds channel A"),
        }
    }

    /// Channel B of node `index`.
    pub fn channel_b(&self, index: usize) -> &ChannelBRuntime {
        match self.runtime(index, Side::B) {
            ChannelRuntime::B(runtime) => runtime,
            ChannelRuntime::A(_) => unreachable!("side B holds channel B"),
        }
    }

    /// The index of the node with node-ID `id`.
    pub fn index(&self, id: u8) -> usize {
        (0..self.node_count)
            .find(|&index| self.sim(index, Side::A).id == id)
            .expect("a node with this node-ID")
    }

    /// Reports the effective output of receive SRDO `srdo` of node `index` to the observer:
    /// both channels' outputs in series (AND).
    pub fn watch(&mut self, index: usize, srdo: SrdoNumber) {
        let mut own = [0; 2];
        for side in [Side::A, Side::B] {
            let c = channel(index, side);
            let sim = self.groups[self.place[c as usize]].channel_mut(c);
            sim.watched = Some(srdo);
            sim.own_output = sim.output(srdo);
            own[side as usize] = sim.own_output;
        }
        self.outputs[index] = Some((own, own[0] & own[1]));
    }

    /// Adds a background sender; returns its participant number.
    pub fn add_sender(&mut self, periodic: Periodic) -> usize {
        let participant = 1 + 2 * self.node_count + self.traffic.senders.len();
        let index = self.traffic.senders.len() as u32;
        self.traffic.senders.push(Sender {
            periodic,
            participant,
            next: periodic.first,
            count: 0,
        });
        self.traffic.sender_due.push(periodic.first, index);
        participant
    }

    /// The bus participant of channel `side` of node `index`.
    pub fn participant(index: usize, side: Side) -> usize {
        channel(index, side) as usize + 1
    }

    /// Runs until `end`.
    pub fn run_until(&mut self, end: Instant) {
        self.started = true;
        if self.groups.len() == 2 {
            self.run_two(end);
        } else {
            self.run_one(end);
        }
        self.now = self.now.max(end);
    }

    /// Runs for `duration`.
    pub fn run_for(&mut self, duration: Duration) {
        self.run_until(self.now + duration);
    }

    /// [`Engine::run_until`] on this thread, window by window.
    fn run_one(&mut self, end: Instant) {
        loop {
            let start = self.groups[0]
                .pending()
                .min(self.traffic.next(&self.bus, self.now));
            if start > end {
                return;
            }
            let until = Traffic::window_end(&self.bus, start, end);
            let mut window = std::mem::take(&mut self.window);
            self.traffic.take_window(until, &mut window);
            let group = &mut self.groups[0];
            group.unfiltered = self.unfiltered;
            if group.has_work(&window, until) {
                group.until = until;
                group.deliveries.clone_from(&window);
                group.run_window();
            }
            let mut notes = std::mem::take(&mut self.notes);
            delivery_notes(&window, &mut notes);
            notes.append(&mut group.notes);
            // Stable: what one call reports keeps its order.
            notes.sort_by_key(|(order, _)| *order);
            self.tell(&mut notes);
            self.notes = notes;
            self.pass_link_bytes();
            let mut sends = std::mem::take(&mut self.sends);
            sends.append(&mut self.groups[0].sends);
            sends.sort_by_key(|(at, ..)| *at);
            self.traffic.replay(&mut self.bus, &sends, self.now, until);
            sends.clear();
            self.sends = sends;
            self.window = window;
            self.now = self.now.max(Instant::from_micros(until.as_micros() - 1));
        }
    }

    /// [`Engine::run_until`] on two threads: the second takes group 1 with copies of the bus
    /// and the traffic, this one runs group 0 and tells the observer; both give the same
    /// bus, and this thread's copy stays the engine's.
    fn run_two(&mut self, end: Instant) {
        let (handoff, exchange) = self.second.get_or_insert_with(|| {
            let worker = Handoff::new(|mut run: Box<WorkerRun>| {
                let WorkerRun {
                    lane,
                    group,
                    bus,
                    traffic,
                    now,
                    end,
                } = &mut *run;
                lane.run(group, bus, traffic, now, *end, || true, |_| {});
                run
            });
            (worker, Arc::new(Exchange::default()))
        });
        let unfiltered = self.unfiltered;
        for group in &mut self.groups {
            group.unfiltered = unfiltered;
        }
        let second = self.groups.pop().expect("two groups");
        let lane = |side: usize, peer: Instant| Lane {
            side,
            exchange: Arc::clone(exchange),
            epoch: self.epoch,
            peer,
            window: Vec::new(),
            sends: Vec::new(),
            links: Links::default(),
            limit: self.board_limit,
            notes: Vec::new(),
        };
        let mut own = lane(0, second.pending());
        let run = Box::new(WorkerRun {
            lane: lane(1, self.groups[0].pending()),
            group: second,
            bus: self.bus.clone(),
            traffic: self.traffic.clone(),
            now: self.now,
            end,
        });
        handoff.submit(run);
        // Should this thread panic during the run, the second one stops waiting for it.
        struct Abandon<'a>(&'a Exchange);
        impl Drop for Abandon<'_> {
            fn drop(&mut self) {
                if std::thread::panicking() {
                    self.0.abandoned.store(true, Ordering::Release);
                }
            }
        }
        let exchange = Arc::clone(exchange);
        let _guard = Abandon(&exchange);
        let (observer, trace, tool_inbox, outputs) = (
            &mut self.observer,
            &mut self.trace,
            &mut self.tool_inbox,
            &mut self.outputs,
        );
        let (handoff, _) = self.second.as_ref().expect("started above");
        own.run(
            &mut self.groups[0],
            &mut self.bus,
            &mut self.traffic,
            &mut self.now,
            end,
            || !handoff.stopped(),
            |notes| {
                for (order, note) in notes.drain(..) {
                    hear(observer, trace, tool_inbox, outputs, order.at, note);
                }
            },
        );
        let (handoff, _) = self.second.as_mut().expect("started above");
        let run = handoff.wait();
        self.epoch = own.epoch;
        debug_assert_eq!(
            run.lane.epoch, own.epoch,
            "both threads ran the same windows"
        );
        self.groups.push(run.group);
    }

    /// What each group wrote on the links goes to the inbox of the group of the channel it
    /// is for (one group: its own).
    fn pass_link_bytes(&mut self) {
        for g in 0..self.groups.len() {
            let outbox = std::mem::take(&mut self.groups[g].outbox);
            for group in &mut self.groups {
                group.receive_links(&outbox);
            }
            let mut outbox = outbox;
            outbox.clear();
            self.groups[g].outbox = outbox;
        }
    }

    /// Tells the observer (and the trace and the tool) `notes`, in their order, and empties
    /// them.
    fn tell(&mut self, notes: &mut Vec<(Order, Note)>) {
        for (order, note) in notes.drain(..) {
            hear(
                &mut self.observer,
                &mut self.trace,
                &mut self.tool_inbox,
                &mut self.outputs,
                order.at,
                note,
            );
        }
    }

    /// Runs `action` on one channel now, polls it, and applies what it handed out at once.
    fn call(&mut self, index: usize, side: Side, action: Action) {
        self.started = true;
        let now = self.now;
        let c = channel(index, side);
        let g = self.place[c as usize];
        let group = &mut self.groups[g];
        group.apply_inbox();
        group.now = now;
        group.until = now + Duration::from_micros(1);
        group.call(c, action, DEADLINE_PHASE);
        group.next = group.next_event();
        let mut notes = std::mem::take(&mut group.notes);
        for (_, from, frame) in group.sends.drain(..) {
            self.bus.send(from, frame);
        }
        self.tell(&mut notes);
        self.groups[g].notes = notes;
        self.pass_link_bytes();
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
            if (0..self.node_count)
                .all(|index| self.sim(index, Side::A).state().0 == NmtState::PreOperational)
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

/// One call on channel `sim` at `now`: the action, the poll, the new deadline; everything
/// outside the channel goes into `out`, for [`Group::call`].
fn run_call(sim: &mut SimChannel, now: Instant, action: Action, out: &mut Scratch) {
    out.clear();
    let incoming = &mut sim.incoming;
    let deadline = match &mut sim.runtime {
        ChannelRuntime::A(runtime) => act(runtime, incoming, now, action, out),
        ChannelRuntime::B(runtime) => act(runtime, incoming, now, action, out),
    };
    if sim.deadline != deadline {
        sim.deadline = deadline;
        out.timer = Some(deadline);
    }
    out.own_output = sim.watched.map_or(0, |srdo| sim.output(srdo));
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
    // The simulated contacts are read continuously: a sample is never older than now.
    runtime.inputs_sampled(now, out);
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
            let (mut out, mut wire) = (WireOut::default(), Wire::default());
            let mut delimiters = Vec::new();
            let mut received = Vec::new();
            let mut pending = writes.iter().peekable();
            for until in reads {
                while let Some(&&(now, bytes)) = pending.peek() {
                    if now > until {
                        break;
                    }
                    let first =
                        out.write(Instant::from_micros(now), bytes, |at| delimiters.push(at));
                    wire.push_run(first, bytes);
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

    /// What a thread writes on its board after a window the other reads back as it was:
    /// data and remote frames of every length with their instants and senders, link runs of
    /// every length up to three words and more, each frame delimiter at the arrival the
    /// writing end gave it; and a window that does not fit is refused, not cut.
    #[test]
    fn a_board_gives_back_the_frames_and_link_bytes_written_on_it() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let board = Board::default();
        let mut refused = 0;
        for round in 0..2_000 {
            let mut sends = Vec::new();
            for _ in 0..rng.random_range(0..7) {
                let id = shared::CanId::new(rng.random_range(0..0x800)).unwrap();
                let len = rng.random_range(0..=8);
                let frame = if rng.random_range(0..5) == 0 {
                    CanFrame::remote(id, len).unwrap()
                } else {
                    let data: [u8; 8] = rng.random();
                    CanFrame::new(id, &data[..usize::from(len)]).unwrap()
                };
                let at = Instant::from_micros(rng.random_range(0..1 << 40));
                sends.push((at, rng.random_range(0..300), frame));
            }
            let mut links = Links::default();
            let mut out = WireOut::default();
            let now = Instant::from_micros(round * 1_000);
            for _ in 0..rng.random_range(0..4) {
                let c = rng.random_range(0..254);
                let bytes: Vec<u8> = (0..rng.random_range(1..30))
                    .map(|_| {
                        if rng.random_range(0..6) == 0 {
                            0
                        } else {
                            rng.random()
                        }
                    })
                    .collect();
                let ends = &mut links.ends;
                let first = out.write(now, &bytes, |at| ends.push((at, c)));
                let start = links.bytes.len();
                links.bytes.extend_from_slice(&bytes);
                links.runs.push((c, first, start..links.bytes.len()));
            }
            let fits = 2
                + 3 * sends.len()
                + links
                    .runs
                    .iter()
                    .map(|(_, _, range)| 2 + range.len().div_ceil(8))
                    .sum::<usize>()
                <= BOARD_WORDS;
            assert_eq!(board_write(&board.words, &sends, &links, BOARD_WORDS), fits);
            if !fits {
                refused += 1;
                continue;
            }
            let header = sends.len() as u64 | (links.runs.len() as u64) << 16;
            let (mut read_sends, mut read_links) = (Vec::new(), Links::default());
            board_read(&board.words, header, &mut read_sends, &mut read_links);
            assert_eq!(read_sends, sends);
            assert_eq!(read_links.runs, links.runs);
            assert_eq!(read_links.bytes, links.bytes);
            assert_eq!(read_links.ends, links.ends);
        }
        assert!((20..1_980).contains(&refused), "{refused} windows refused");
    }

    /// The tournament tree of deadlines gives what a look at every deadline gives: the
    /// earliest, and every place due at an instant in order, after any sequence of changes
    /// (counts that fill the tree and that leave most of its leaves unused, deadlines that
    /// tie, none set).
    #[test]
    fn the_deadline_tree_finds_what_a_look_at_every_deadline_finds() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for count in [0, 1, 2, 3, 64, 127, 128, 129] {
            let mut tree = Deadlines::new(count);
            let mut plain = vec![Instant::NEVER; count];
            for _ in 0..2_000 {
                if count > 0 {
                    let place = rng.random_range(0..count);
                    let at = match rng.random_range(0..8) {
                        0 => Instant::NEVER,
                        _ => Instant::from_micros(rng.random_range(0..50)),
                    };
                    tree.set(place, at);
                    plain[place] = at;
                }
                assert_eq!(
                    tree.earliest(),
                    plain.iter().copied().min().unwrap_or(Instant::NEVER)
                );
                let now = Instant::from_micros(rng.random_range(0..60));
                let mut due = Vec::new();
                tree.due(now, |place| due.push(place));
                let expected: Vec<usize> = (0..count).filter(|&k| plain[k] <= now).collect();
                assert_eq!(due, expected);
            }
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
