//! Seeded fault campaigns on the host simulation (EN 50325-5 5.3 Table 1, IEC 61784-3; CiA
//! 304 9.5): node 1 (SRDO producer) and node 33 (SRDO consumer), each channel A and channel B
//! with their link ([`crate::dual`]), on the simulated bus at a bit rate the campaign is given
//! ([`BIT_RATES`]; 500 kbit/s, [`BIT_RATE`], for the deterministic tests).
//!
//! A scenario starts the network, lets node 1 send a random non-zero input value until node
//! 33's output carries it, injects one fault whose parameters and timing come from the seed,
//! runs on, and hands the bus frames and node 33's outputs to the [`oracle`], which does not
//! reuse the implementation. Outcome: *detected* (node 33's output reached the safe state,
//! with the latency from the moment the fault took effect), *harmless* (nothing required
//! the safe state and the output kept following the producer, e.g. a CAN double reception
//! discarded, or a lost frame SCT absorbs), *unsafe* (the oracle found an output that was not
//! justified; must never happen), *late* (safe state beyond the class's bound; must never
//! happen either). The same seed gives the same scenario: the simulation is deterministic.
//!
//! The faults are wrappers around the bus ([`crate::dual::DualNetwork::tap`] and the bus's
//! own [`Fault`] vocabulary shared with the hub), the link ([`crate::dual::LinkFaults`]),
//! one channel's controller (muted or babbling: [`Fault::Mute`], frames sent; bus-off:
//! [`DualNetwork::bus_off`], the path the channel loop takes, and the cause it latches),
//! one channel's input, and one channel's core (bit flips through the `fault-injection`
//! hooks).

pub mod oracle;
pub mod recorded;
pub mod report;
pub mod simplecan;
pub mod simplecan_dual;
pub mod simplecan_oracle;

use crate::bus::{Delivery, Fault, Match, frame_bits, frame_time};
use crate::dual::{DualNetwork, Side};
use dual_channel::runtime::{ChannelEvent, ChannelFault, SAMPLE_WINDOW};
use oracle::{MonitoredSrdo, REACTION};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use shared::canopen::nmt::NmtCommand;
use shared::node::Event;
use shared::{CanFrame, CanId, Duration, Instant};
use std::cell::{Cell, RefCell};
use std::fmt::Write as _;
use std::rc::Rc;

/// The producer's node-ID (pre-defined connection set: transmit SRDO 1 on 101h/102h).
pub const PRODUCER: u8 = 1;
/// The consumer's node-ID (configured to receive node 1's SRDO 1).
pub const CONSUMER: u8 = 33;
/// The bus's bit rate in the deterministic tests and the default campaign.
pub const BIT_RATE: u32 = 500_000;
/// The bit rates a campaign can run at: those of CiA 301 Table 2 the reaction-time
/// measurement covers too (EN 50325-5 Table 1 is independent of the rate, the frame times
/// are not).
pub const BIT_RATES: [u32; 4] = [125_000, 250_000, 500_000, 1_000_000];
/// The producer's refresh time: EN 50325-5 Table 5's pre-defined 25 ms for node-IDs 1..=32.
pub const REFRESH: Duration = Duration::from_millis(25);
/// The consumer's SCT: the pre-defined 50 ms for node-IDs 33..=64, not rewritten by the tool.
pub const SCT: Duration = Duration::from_millis(50);
/// The consumer's SRVT: the pre-defined 20 ms, not rewritten by the tool.
pub const SRVT: Duration = Duration::from_millis(20);
/// The link's supervision time-out: two heartbeat periods ([`crate::dual::LINK_PERIOD`]).
pub const LINK_TIMEOUT: Duration = Duration::from_millis(20);
/// Bus participants of node 1's channels (participant 0 is the tool, also the injector).
pub const PRODUCER_PARTICIPANTS: [usize; 2] = [1, 2];
/// The participant foreign frames come from (inserted, replayed, masquerading).
pub const INJECTOR: usize = 0;

/// Node 33's receive SRDO 1 as the oracle watches it: the configuration
/// [`DualNetwork::configure_and_start`] writes (COB-IDs 101h and 102h) and the pre-defined
/// values it leaves (SCT 50 ms, SRVT 20 ms, one mapped byte each way).
pub const MONITORED: MonitoredSrdo = MonitoredSrdo {
    consumer: CONSUMER,
    plain_id: 0x101,
    inverted_id: 0x102,
    len: 1,
    sct: SCT,
    srvt: SRVT,
    producer: PRODUCER_PARTICIPANTS,
};

/// A fault class: the eight communication error classes of IEC 61784-3 (EN 50325-5 Table 1)
/// and the single-channel faults of a Model III node.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Class {
    /// Corruption the CAN CRC misses: a data bit, the identifier, the length.
    Corruption,
    /// Unintended repetition, CAN double reception included.
    Repetition,
    /// Incorrect sequence: inverted before plain, an old pair replayed, pairs interleaved.
    Sequence,
    /// Loss: plain, inverted, both, bursts.
    Loss,
    /// Unacceptable delay: just inside and just beyond SRVT and SCT.
    Delay,
    /// Insertion: a foreign frame on an SRDO identifier.
    Insertion,
    /// Masquerade: a well-formed pair from another sender, or a non-safety frame.
    Masquerade,
    /// Addressing: wrong identifier pairs.
    Addressing,
    /// Addressing: the producer switched off and on again with another node-ID (its SDO
    /// server, heartbeat and EMCY move with it, and so would its pre-defined COB-IDs), with
    /// its stored configuration or with the defaults.
    NodeId,
    /// One channel's safety input stuck while the emergency stop is pressed.
    StuckInput,
    /// A bit flip in one channel's configuration or identifier table in Operational.
    BitFlip,
    /// The link between the channels cut, corrupted or slow.
    Link,
    /// One channel's CAN controller silent.
    ControllerSilent,
    /// One channel's CAN controller babbling a high-priority identifier.
    Babbling,
    /// One channel's CAN controller bus-off (neither sends nor receives).
    BusOff,
    /// Channel B of the producer never sends its inverted frame.
    NoInverted,
    /// One channel's clock too fast or too slow.
    ClockDrift,
}

impl Class {
    /// Every class, in report order.
    pub const ALL: [Class; 17] = [
        Class::Corruption,
        Class::Repetition,
        Class::Sequence,
        Class::Loss,
        Class::Delay,
        Class::Insertion,
        Class::Masquerade,
        Class::Addressing,
        Class::NodeId,
        Class::StuckInput,
        Class::BitFlip,
        Class::Link,
        Class::ControllerSilent,
        Class::Babbling,
        Class::BusOff,
        Class::NoInverted,
        Class::ClockDrift,
    ];

    /// The name on the command line and in file names.
    pub fn name(self) -> &'static str {
        match self {
            Class::Corruption => "corruption",
            Class::Repetition => "repetition",
            Class::Sequence => "sequence",
            Class::Loss => "loss",
            Class::Delay => "delay",
            Class::Insertion => "insertion",
            Class::Masquerade => "masquerade",
            Class::Addressing => "addressing",
            Class::NodeId => "node-id",
            Class::StuckInput => "stuck-input",
            Class::BitFlip => "bit-flip",
            Class::Link => "link",
            Class::ControllerSilent => "controller-silent",
            Class::Babbling => "babbling",
            Class::BusOff => "bus-off",
            Class::NoInverted => "no-inverted",
            Class::ClockDrift => "clock-drift",
        }
    }

    /// The class named `name`.
    pub fn from_name(name: &str) -> Option<Class> {
        Class::ALL.into_iter().find(|class| class.name() == name)
    }

    /// The requirement it verifies (requirements/*.toml).
    pub fn requirement(self) -> &'static str {
        match self {
            Class::Corruption => "IEC 61784-3 corruption",
            Class::Repetition => "IEC 61784-3 repetition",
            Class::Sequence => "IEC 61784-3 sequence",
            Class::Loss => "IEC 61784-3 loss",
            Class::Delay => "IEC 61784-3 delay",
            Class::Insertion => "IEC 61784-3 insertion",
            Class::Masquerade => "IEC 61784-3 masquerade",
            Class::Addressing | Class::NodeId => "IEC 61784-3 addressing",
            Class::StuckInput
            | Class::BitFlip
            | Class::Link
            | Class::NoInverted
            | Class::ClockDrift => "CiA 304 9.5",
            Class::ControllerSilent | Class::Babbling | Class::BusOff => "EN 50325-5 7.1.2",
        }
    }

    /// The bound on the latency from the fault taking effect to node 33's safe state that
    /// the configuration implies on a bus at `bit_rate`, and how it follows. The timing
    /// parameters are the same at every rate; what the rate adds is the time a frame the
    /// detection waits for spends getting onto the bus ([`frame_allowance`]).
    pub fn bound(self, bit_rate: u32) -> (Duration, &'static str) {
        let sum = |parts: &[Duration]| {
            Duration::from_micros(parts.iter().map(|part| part.as_micros()).sum())
        };
        let frame = frame_allowance(bit_rate);
        match self {
            Class::Corruption
            | Class::Repetition
            | Class::Sequence
            | Class::Loss
            | Class::Delay
            | Class::Insertion
            | Class::Masquerade
            | Class::Addressing
            | Class::NodeId
            | Class::ControllerSilent
            | Class::Babbling
            | Class::BusOff => (
                sum(&[SCT, REACTION]),
                "SCT + reaction: the consumer's SCT runs from the last valid pair before the fault, so any fault that stops valid pairs is caught by SCT at the latest; earlier mechanisms (inversion, sequence, SRVT, the producer's foreign-frame GFC) only shorten it",
            ),
            Class::NoInverted => (
                sum(&[REFRESH, frame, SRVT, REACTION]),
                "refresh time + frame allowance + SRVT + reaction: the next plain frame is queued within one refresh time, is on the bus a frame allowance later, and its inverted frame is missing after SRVT",
            ),
            Class::StuckInput => (
                sum(&[REFRESH, SAMPLE_WINDOW, frame, SRVT, REACTION]),
                "from pressing the emergency stop: refresh time (the stuck channel's next cyclic frame) + sample window (the other channel's previous sample is accepted that long) + frame allowance (that plain frame onto the bus) + SRVT (the missing inverted frame) + reaction",
            ),
            Class::BitFlip => (
                sum(&[REFRESH, SCT, REACTION]),
                "refresh time + SCT + reaction: the integrity check runs every shortest refresh time or SCT of the running SRDOs (in node 1: 25 ms, then node 33's SCT as node 1 stops sending; in node 33: within its SCT)",
            ),
            Class::ClockDrift => (
                sum(&[
                    Duration::from_micros(
                        crate::dual::LINK_PERIOD.as_micros()
                            * (dual_channel::clock::SPAN as u64 + 2),
                    ),
                    SCT,
                    REACTION,
                ]),
                "(32 + 2) link periods + SCT + reaction: a clock off by 12 % or more makes 32 of the other channel's heartbeat intervals shorter than 90 % of 32 periods within 34 periods (dual_channel::clock); in node 1 the producer then stops and node 33's SCT runs out",
            ),
            Class::Link => (
                sum(&[LINK_TIMEOUT, SCT, REACTION]),
                "link time-out (2 heartbeat periods) + SCT + reaction: a link fault latches both channels of that node; in node 1 the producer stops and node 33's SCT runs out",
            ),
        }
    }
}

/// Bits of the longest standard frame (8 data bytes) with the most stuff bits, intermission
/// included: 44 + 64 + 24 stuff bits + 3 (ISO 11898-1 10.4, 10.5).
pub const LONGEST_FRAME_BITS: u64 = 135;

/// How long a frame queued now may take to be complete on a bus at `bit_rate`: the frame
/// in progress ends, then its own transmission; each at most [`LONGEST_FRAME_BITS`] (the
/// producer's SRDO identifiers win arbitration against everything but NMT, GFC and the
/// babbling controller's, whose class does not wait for a frame).
pub fn frame_allowance(bit_rate: u32) -> Duration {
    Duration::from_micros((2 * LONGEST_FRAME_BITS * 1_000_000).div_ceil(u64::from(bit_rate)))
}

/// How one scenario ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// Node 33's output reached the safe state within the bound.
    Detected,
    /// Nothing required the safe state, and the output kept following the producer.
    Harmless,
    /// The oracle found an output not justified by a valid pair within SCT and SRVT.
    Unsafe,
    /// The safe state came later than the class's bound, or never for a fault that must be
    /// detected (a clock beyond its tolerance; a bus-off the faulted channel did not latch
    /// under its own cause).
    Late,
    /// The network did not reach its steady state before the fault (a harness failure).
    SetupFailed,
    /// The fault never took effect (a harness failure).
    NotApplied,
}

impl Outcome {
    /// `true` for the outcomes a campaign must never have.
    pub fn is_failure(self) -> bool {
        !matches!(self, Outcome::Detected | Outcome::Harmless)
    }
}

/// The result of one scenario.
#[derive(Clone, Debug)]
pub struct ScenarioResult {
    /// The class.
    pub class: Class,
    /// The seed.
    pub seed: u64,
    /// The bus's bit rate.
    pub bit_rate: u32,
    /// The randomised fault, in words.
    pub fault: String,
    /// How it ended.
    pub outcome: Outcome,
    /// From the fault taking effect to node 33's safe state.
    pub latency: Option<Duration>,
    /// From the moment the oracle's rules required the safe state to node 33's safe state.
    pub reaction: Option<Duration>,
    /// What was wrong, with the timeline around it (failures only).
    pub report: Option<String>,
}

/// A fault injected into the running network.
struct Injected {
    /// What, in words; `{}` is replaced by what a tap wrote when it acted.
    fault: String,
    /// What the tap wrote.
    detail: Option<Rc<RefCell<String>>>,
    /// When it took effect (set by a tap when it first alters a frame).
    effect: Rc<Cell<Option<Instant>>>,
    /// How long to run after the injection.
    horizon: Duration,
    /// The fault must end in the safe state (a harmless end is a failure).
    must_detect: bool,
    /// The channel the fault hits and the fault it must latch first, under its own cause
    /// (a bus-off: [`ChannelFault::BusOff`], 3Bh). Read from the channels' logs, apart from
    /// the oracle, which sees only the bus and node 33's outputs.
    own_fault: Option<(u8, Side, ChannelFault)>,
}

impl Injected {
    fn at(fault: String, at: Instant) -> Self {
        Injected {
            fault,
            detail: None,
            effect: Rc::new(Cell::new(Some(at))),
            horizon: Duration::ZERO,
            must_detect: false,
            own_fault: None,
        }
    }
    fn tapped(fault: String, effect: Rc<Cell<Option<Instant>>>) -> Self {
        Injected {
            fault,
            detail: None,
            effect,
            horizon: Duration::ZERO,
            must_detect: false,
            own_fault: None,
        }
    }
    fn described_by(mut self, detail: Rc<RefCell<String>>) -> Self {
        self.detail = Some(detail);
        self
    }
}

fn frame(id: u16, dlc: u8, data: [u8; 8]) -> CanFrame {
    CanFrame::from_parts(CanId::new(id).expect("11-bit identifier"), dlc, data)
        .expect("length up to 8")
}

fn is_genuine_srdo(delivery: &Delivery) -> bool {
    PRODUCER_PARTICIPANTS.contains(&delivery.from)
        && matches!(delivery.frame.id().raw(), 0x101 | 0x102)
}

fn add(a: Duration, b: Duration) -> Duration {
    Duration::from_micros(a.as_micros() + b.as_micros())
}

fn micros(range: std::ops::Range<u64>, rng: &mut ChaCha8Rng) -> Duration {
    Duration::from_micros(rng.random_range(range))
}

/// The participant of node `id`'s channel `side` (see [`DualNetwork`]).
fn participant(id: u8, side: Side) -> usize {
    let index = if id == PRODUCER { 0 } else { 1 };
    1 + 2 * index + side as usize
}

fn random_side(rng: &mut ChaCha8Rng) -> Side {
    if rng.random_bool(0.5) {
        Side::A
    } else {
        Side::B
    }
}

fn random_node(rng: &mut ChaCha8Rng) -> u8 {
    if rng.random_bool(0.5) {
        PRODUCER
    } else {
        CONSUMER
    }
}

/// Installs a tap that applies `alter` to the genuine SRDO frames from the producer, counting
/// them from 0 at the first plain frame (even: plain, odd: inverted); `alter` returns the deliveries to make instead and whether it altered
/// anything (the first alteration is the moment the fault took effect).
pub fn tap_srdo(
    net: &mut DualNetwork,
    mut alter: impl FnMut(usize, Delivery) -> Option<Vec<Delivery>> + 'static,
) -> Rc<Cell<Option<Instant>>> {
    let effect = Rc::new(Cell::new(None));
    let first = effect.clone();
    let mut count = 0usize;
    net.tap = Some(Box::new(move |delivery: Delivery| {
        if !is_genuine_srdo(&delivery) {
            return vec![delivery];
        }
        if count == 0 && delivery.frame.id().raw() == 0x102 {
            // The inverted half of a pair whose plain frame was on its way when the tap was
            // installed: counting starts at a plain frame, so even numbers are plain frames.
            return vec![delivery];
        }
        let index = count;
        count += 1;
        match alter(index, delivery) {
            Some(mut instead) => {
                // Nothing reaches a receiver before it was on the bus.
                for d in &mut instead {
                    d.at = d.at.max(delivery.at);
                }
                if first.get().is_none() {
                    // The first added or altered delivery; the original's time when it was
                    // lost, altered or held back (it should have arrived then).
                    let kept = instead.contains(&delivery);
                    let added = instead
                        .iter()
                        .filter(|d| **d != delivery)
                        .map(|d| d.at)
                        .min();
                    let at = match (kept, added) {
                        (true, Some(at)) => at,
                        (false, Some(at)) => at.min(delivery.at),
                        (_, None) => delivery.at,
                    };
                    first.set(Some(at));
                }
                instead
            }
            None => vec![delivery],
        }
    }));
    effect
}

fn inject(class: Class, rng: &mut ChaCha8Rng, net: &mut DualNetwork, input: u8) -> Injected {
    let now = net.now;
    match class {
        Class::Corruption => {
            let target = rng.random_range(0..4usize);
            let kind = rng.random_range(0..3u8);
            let data_mask = rng.random_range(1..=255u8);
            let mut id_mask = rng.random_range(1..=0x7FFu16);
            let new_dlc = rng.random_range(0..=7u8);
            let fill: [u8; 8] = rng.random();
            let description = Rc::new(RefCell::new(String::new()));
            let text = description.clone();
            let effect = tap_srdo(net, move |index, delivery| {
                if index != target {
                    return None;
                }
                let f = delivery.frame;
                let id = f.id().raw();
                let altered = match kind {
                    0 => {
                        let mut data = *f.raw_data();
                        data[0] ^= data_mask;
                        *text.borrow_mut() =
                            format!("data of frame {id:03X}h XOR {data_mask:02X}h");
                        frame(id, f.dlc(), data)
                    }
                    1 => {
                        while id ^ id_mask == 0 {
                            id_mask >>= 1;
                        }
                        *text.borrow_mut() =
                            format!("identifier {id:03X}h became {:03X}h", id ^ id_mask);
                        frame(id ^ id_mask, f.dlc(), *f.raw_data())
                    }
                    _ => {
                        // Another length: 0..=8 without the frame's own.
                        let dlc = if new_dlc >= f.dlc() {
                            new_dlc + 1
                        } else {
                            new_dlc
                        };
                        let mut data = *f.raw_data();
                        data[usize::from(f.dlc())..].copy_from_slice(&fill[usize::from(f.dlc())..]);
                        *text.borrow_mut() =
                            format!("length of frame {id:03X}h {} became {dlc}", f.dlc());
                        frame(id, dlc, data)
                    }
                };
                Some(vec![Delivery {
                    frame: altered,
                    ..delivery
                }])
            });
            Injected::tapped(
                format!("SRDO frame #{target} after the start: {{}}"),
                effect,
            )
            .described_by(description)
        }
        Class::Repetition => repetition(rng, net),
        Class::Sequence => sequence(rng, net, input),
        Class::Loss => {
            let start = rng.random_range(0..4usize);
            let (what, count) = match rng.random_range(0..4u8) {
                0 => ("the plain frame", 1),
                1 => ("the inverted frame", 1),
                2 => ("a whole pair", 2),
                _ => ("a burst of SRDO frames", rng.random_range(3..=12usize)),
            };
            // A pair starts on a plain frame (even index), single frames on their own kind.
            let first = match what {
                "the plain frame" | "a whole pair" => start & !1,
                "the inverted frame" => start | 1,
                _ => start,
            };
            let effect = tap_srdo(net, move |index, _| {
                (index >= first && index < first + count).then(Vec::new)
            });
            Injected::tapped(
                format!("{what} lost ({count} frame(s) from SRDO frame #{first})"),
                effect,
            )
        }
        Class::Delay => delay(rng, net),
        Class::Insertion => {
            let wait = micros(0..30_000, rng);
            net.run_for(wait);
            let id = if rng.random_bool(0.5) { 0x101 } else { 0x102 };
            let dlc = rng.random_range(0..=8u8);
            let data: [u8; 8] = rng.random();
            let inserted = frame(id, dlc, data);
            net.send_foreign(inserted);
            foreign_effect(
                net,
                format!("inserted {id:03X}h [{dlc}] {:02X?}", inserted.data()),
            )
        }
        Class::Masquerade => {
            // The producer's data first changes (0, the emergency stop, in a third of the
            // scenarios), so a masquerading pair has something to contradict.
            let genuine = if rng.random_bool(1.0 / 3.0) {
                0
            } else {
                rng.random_range(0..=255u8)
            };
            net.set_inputs(PRODUCER, genuine, genuine);
            net.run_for(add(Duration::from_millis(30), micros(0..25_000, rng)));
            let posing = rng.random_range(0..=255u8);
            if rng.random_bool(0.2) {
                // A non-safety frame (PDO, SDO, heartbeat range) with the same data.
                let id = rng.random_range(0x181..=0x7FFu16);
                net.send_foreign(frame(id, 1, [posing, 0, 0, 0, 0, 0, 0, 0]));
                let at = net.now;
                return Injected::at(
                    format!(
                        "producer sends {genuine:#04x}; non-safety frame {id:03X}h carries {posing:#04x}"
                    ),
                    at,
                );
            }
            net.send_foreign(frame(0x101, 1, [posing, 0, 0, 0, 0, 0, 0, 0]));
            net.send_foreign(frame(0x102, 1, [!posing, 0, 0, 0, 0, 0, 0, 0]));
            foreign_effect(
                net,
                format!(
                    "producer sends {genuine:#04x}; a well-formed pair from another sender carries {posing:#04x}"
                ),
            )
        }
        Class::Addressing => {
            let start = rng.random_range(0..2usize) * 2;
            let pairs = rng.random_range(1..=4usize);
            let other = 0x101 + 2 * rng.random_range(1..=63u16);
            let which = rng.random_range(0..4u8);
            let what = match which {
                0 => format!(
                    "both frames of {pairs} pair(s) on the pair {other:03X}h/{:03X}h",
                    other + 1
                ),
                1 => format!("the plain frame of {pairs} pair(s) on {other:03X}h"),
                2 => format!(
                    "the inverted frame of {pairs} pair(s) on {:03X}h",
                    other + 1
                ),
                _ => format!("{pairs} pair(s) with their identifiers swapped"),
            };
            let effect = tap_srdo(net, move |index, delivery| {
                if index < start || index >= start + 2 * pairs {
                    return None;
                }
                let f = delivery.frame;
                let plain = f.id().raw() == 0x101;
                let id = match (which, plain) {
                    (0 | 1, true) => other,
                    (0 | 2, false) => other + 1,
                    (3, true) => 0x102,
                    (3, false) => 0x101,
                    _ => return None,
                };
                Some(vec![Delivery {
                    frame: frame(id, f.dlc(), *f.raw_data()),
                    ..delivery
                }])
            });
            Injected::tapped(what, effect)
        }
        Class::NodeId => node_id(rng, net),
        Class::StuckInput => {
            let stuck = random_side(rng);
            let moving = if stuck == Side::A { Side::B } else { Side::A };
            net.run_for(micros(0..50_000, rng));
            net.set_input(PRODUCER, moving, 0);
            let at = net.now;
            Injected::at(
                format!(
                    "channel {stuck:?}'s input stuck at {input:#04x}; emergency stop pressed (channel {moving:?} reads 0)"
                ),
                at,
            )
        }
        Class::BitFlip => {
            let id = random_node(rng);
            let side = random_side(rng);
            let record = rng.random_bool(0.5);
            let bit = rng.random_range(0..16u8);
            let byte = rng.random_range(0..128usize);
            let node = net.node_mut(id);
            let what = if record {
                let core = match side {
                    Side::A => node.a.node_mut(),
                    Side::B => node.b.node_mut(),
                };
                core.inject_record_flip(0, bit);
                format!("node {id} channel {side:?}: bit {bit} of SRDO 1's refresh time / SCT")
            } else {
                let bit = bit % 8;
                let core = match side {
                    Side::A => node.a.node_mut(),
                    Side::B => node.b.node_mut(),
                };
                core.inject_identifier_table_flip(byte, bit);
                format!("node {id} channel {side:?}: bit {bit} of identifier table byte {byte}")
            };
            Injected::at(what, now)
        }
        Class::Link => {
            let id = random_node(rng);
            let node = net.node_mut(id);
            let what = match rng.random_range(0..3u8) {
                0 => {
                    node.link_faults.cut = true;
                    format!("node {id}: link cut")
                }
                1 => {
                    let mask = rng.random_range(1..=255u8);
                    node.link_faults.corrupt_next_a_to_b = Some(mask);
                    format!("node {id}: next link byte A to B XOR {mask:02X}h")
                }
                _ => {
                    let latency = micros(500..40_000, rng);
                    node.link_faults.latency = latency;
                    format!("node {id}: link latency {} µs", latency.as_micros())
                }
            };
            Injected::at(what, now)
        }
        Class::ControllerSilent => {
            let id = random_node(rng);
            let side = random_side(rng);
            net.inject(Match::all_from(participant(id, side), now), Fault::Mute);
            Injected::at(
                format!("node {id} channel {side:?}: CAN controller silent"),
                now,
            )
        }
        Class::Babbling => {
            let id = random_node(rng);
            let side = random_side(rng);
            let babble = rng.random_range(0x001..=0x100u16);
            let dlc = rng.random_range(0..=8u8);
            let data: [u8; 8] = rng.random();
            let from = participant(id, side);
            for _ in 0..2500 {
                net.bus.send(from, frame(babble, dlc, data));
            }
            Injected::at(
                format!(
                    "node {id} channel {side:?}: CAN controller babbling {babble:03X}h [{dlc}]"
                ),
                now,
            )
        }
        Class::BusOff => {
            let id = random_node(rng);
            let side = random_side(rng);
            // The product's path: the controller silent and deaf, and the channel told by
            // its driver (`DualNetwork::bus_off`); not a muted controller that only SCT finds.
            net.bus_off(id, side);
            let mut injected = Injected::at(
                format!("node {id} channel {side:?}: CAN controller bus-off"),
                now,
            );
            injected.must_detect = true;
            injected.own_fault = Some((id, side, ChannelFault::BusOff));
            injected
        }
        Class::ClockDrift => {
            let id = random_node(rng);
            let side = random_side(rng);
            // Beyond the tolerance (12 % to 40 %, fast or slow: `dual_channel::clock` finds
            // more than 11.1 % fast or 10 % slow) in three scenarios of four, within it (up
            // to 5 %) in the fourth.
            let magnitude = if rng.random_bool(0.75) {
                rng.random_range(120_000..=400_000i64)
            } else {
                rng.random_range(0..=50_000i64)
            };
            let ppm = if rng.random_bool(0.5) {
                magnitude
            } else {
                -magnitude
            };
            net.node_mut(id).clocks[side as usize].set_rate(now, ppm);
            let mut injected = Injected::at(
                format!(
                    "node {id} channel {side:?}: clock {:+.1} %",
                    ppm as f64 / 10_000.0
                ),
                now,
            );
            injected.must_detect = magnitude >= 120_000;
            injected
        }
        Class::NoInverted => {
            let wait = micros(0..25_000, rng);
            let when = Match {
                id: Some(0x102),
                from: Some(participant(PRODUCER, Side::B)),
                after: now + wait,
                count: None,
            };
            net.inject(when, Fault::Drop);
            Injected::at(
                format!(
                    "node 1 channel B sends no inverted frame from +{} µs",
                    wait.as_micros()
                ),
                now + wait,
            )
        }
    }
}

/// Addressing, a changed node-ID: node 1 is switched off and on again with node-ID `n`
/// (2..=127, not node 33's), keeping its stored configuration (SRDO 1 on 101h/102h, signed,
/// but validated for node-ID 1, so NMT start refuses it under node-ID `n`) or with erased
/// storage (the defaults: no valid configuration, so it cannot enter Operational, and its
/// pre-defined SRDO would be on 101h + 2(n - 1)). An NMT master starts
/// all nodes when it sees the boot-up; once node 33 is safe it resets node 33's
/// communication and starts it again, so node 33 runs a second time on whatever node `n`
/// sends. The oracle judges both runs: node 33 may carry data only from valid pairs on its
/// configured identifiers from the producing device; anything else must end in its safe
/// state within SCT.
fn node_id(rng: &mut ChaCha8Rng, net: &mut DualNetwork) -> Injected {
    let new_id = loop {
        let id = rng.random_range(2..=127u8);
        if id != CONSUMER {
            break id;
        }
    };
    let keep = rng.random_bool(0.5);
    let off = micros(0..30_000, rng);
    let at = net.now;
    // Switched off: nothing from its controllers from now on until it boots again.
    let silent = Match {
        id: None,
        from: None,
        after: at,
        count: None,
    };
    for side in [Side::A, Side::B] {
        net.inject(
            Match {
                from: Some(participant(PRODUCER, side)),
                ..silent
            },
            Fault::Mute,
        );
    }
    net.run_for(off);
    net.bus
        .retain_faults(|injection| !(injection.fault == Fault::Mute && injection.when.after == at));
    net.repower(PRODUCER, new_id, keep);
    let boot_up = 0x700 + u16::from(new_id);
    let since = net.trace.len();
    for _ in 0..500 {
        net.run_for(Duration::from_millis(1));
        if net.trace[since..]
            .iter()
            .any(|(_, frame, _)| frame.id().raw() == boot_up)
        {
            break;
        }
    }
    net.nmt(NmtCommand::Start, 0);
    net.run_for(add(SCT, Duration::from_millis(5)));
    net.nmt(NmtCommand::ResetCommunication, CONSUMER);
    net.run_for(Duration::from_millis(20));
    net.nmt(NmtCommand::Start, CONSUMER);
    let mut injected = Injected::at(
        format!(
            "node 1 off for {} µs, then on as node {new_id} {}",
            off.as_micros(),
            if keep {
                "with its stored configuration"
            } else {
                "with the defaults (storage erased)"
            }
        ),
        at,
    );
    injected.must_detect = true;
    injected
}

/// Unintended repetition: CAN double reception (the bus's own [`Fault::Repeat`]: the
/// frame occupies the bus a second time right after the first, as a transmitter repeating
/// after an error in the last bit of end-of-frame does), or one or two copies delivered later
/// (a gateway repeating).
fn repetition(rng: &mut ChaCha8Rng, net: &mut DualNetwork) -> Injected {
    let target = rng.random_range(0..4usize);
    let later = micros(100..30_000, rng);
    let copies = rng.random_range(1..=2u64);
    if rng.random_bool(0.5) {
        let id = if target % 2 == 0 { 0x101 } else { 0x102 };
        net.inject(Match::next_with_id(id, net.now), Fault::Repeat);
        // The bus delivers the copy through the tap like any frame: the second identical
        // delivery in a row is the moment the fault took effect.
        let mut previous: Option<CanFrame> = None;
        let effect = Rc::new(Cell::new(None));
        let first = effect.clone();
        net.tap = Some(Box::new(move |delivery: Delivery| {
            if is_genuine_srdo(&delivery) {
                let repeated = previous == Some(delivery.frame) && delivery.frame.id().raw() == id;
                if repeated && first.get().is_none() {
                    first.set(Some(delivery.at));
                }
                previous = Some(delivery.frame);
            }
            vec![delivery]
        }));
        return Injected::tapped(
            format!("next frame {id:03X}h repeated back to back (CAN double reception)"),
            effect,
        );
    }
    let effect = tap_srdo(net, move |index, delivery| {
        if index != target {
            return None;
        }
        let mut out = vec![delivery];
        for copy in 1..=copies {
            out.push(Delivery {
                at: delivery.at + Duration::from_micros(later.as_micros() * copy),
                ..delivery
            });
        }
        Some(out)
    });
    Injected::tapped(
        format!(
            "SRDO frame #{target} after the start delivered {copies} more time(s), every {} µs (a gateway repeating)",
            later.as_micros()
        ),
        effect,
    )
}

/// The first frame from the injector after now: when the fault took effect.
fn foreign_effect(net: &mut DualNetwork, fault: String) -> Injected {
    let since = net.trace.len();
    let effect = Rc::new(Cell::new(None));
    for _ in 0..100 {
        net.run_for(Duration::from_micros(100));
        if let Some((at, ..)) = net.trace[since..]
            .iter()
            .find(|(_, _, from)| *from == INJECTOR)
        {
            effect.set(Some(*at));
            break;
        }
    }
    Injected::tapped(fault, effect)
}

/// Incorrect sequence: an inverted frame before its plain frame, an old pair replayed
/// between pairs, or an old pair interleaved with the current one.
fn sequence(rng: &mut ChaCha8Rng, net: &mut DualNetwork, input: u8) -> Injected {
    let variant = rng.random_range(0..3u8);
    if variant == 0 {
        let target = rng.random_range(0..2usize) * 2;
        let effect = tap_srdo(net, move |index, delivery| {
            if index != target {
                return None;
            }
            let plain = delivery.frame;
            let mut inverted = *plain.raw_data();
            for byte in inverted.iter_mut().take(usize::from(plain.dlc())) {
                *byte = !*byte;
            }
            let early = Delivery {
                frame: frame(0x102, plain.dlc(), inverted),
                from: INJECTOR,
                ..delivery
            };
            Some(vec![early, delivery])
        });
        return Injected::tapped(
            format!(
                "inverted frame of pair #{} inserted before its plain frame",
                target / 2
            ),
            effect,
        );
    }
    // Record the current pair, change the data, then replay the old pair.
    let recorded: Rc<RefCell<Vec<CanFrame>>> = Rc::new(RefCell::new(Vec::new()));
    let record = recorded.clone();
    net.tap = Some(Box::new(move |delivery: Delivery| {
        if is_genuine_srdo(&delivery) && record.borrow().len() < 2 {
            record.borrow_mut().push(delivery.frame);
        }
        vec![delivery]
    }));
    net.run_for(add(REFRESH, Duration::from_millis(1)));
    let old: Vec<CanFrame> = recorded.borrow().clone();
    let current = loop {
        let value = rng.random_range(0..=255u8);
        if value != input {
            break value;
        }
    };
    net.set_inputs(PRODUCER, current, current);
    net.run_for(add(Duration::from_millis(30), micros(0..20_000, rng)));
    let effect = Rc::new(Cell::new(None));
    let first = effect.clone();
    if variant == 1 {
        let at_once = old.clone();
        net.tap = None;
        for frame in at_once {
            net.send_foreign(frame);
        }
        let replay = foreign_effect(net, String::new());
        return Injected::tapped(
            format!(
                "producer now sends {current:#04x}; the old pair ({input:#04x}) replayed between pairs"
            ),
            replay.effect,
        );
    }
    // Interleaved: old plain right after the current plain, old inverted right after the
    // current inverted.
    let mut done = 0usize;
    net.tap = Some(Box::new(move |delivery: Delivery| {
        if !is_genuine_srdo(&delivery) || done >= 2 {
            return vec![delivery];
        }
        let plain = delivery.frame.id().raw() == 0x101;
        if (done == 0) != plain {
            return vec![delivery];
        }
        let old = old[done];
        done += 1;
        let interleaved = Delivery {
            at: delivery.at + Duration::from_micros(30),
            frame: old,
            from: INJECTOR,
            bits: frame_bits(&old),
        };
        if first.get().is_none() {
            first.set(Some(interleaved.at));
        }
        vec![delivery, interleaved]
    }));
    Injected::tapped(
        format!(
            "producer now sends {current:#04x}; the old pair ({input:#04x}) interleaved with the current one"
        ),
        effect,
    )
}

/// Unacceptable delay: an inverted frame just inside or just beyond SRVT after its plain
/// frame, or a pair just inside or just beyond SCT after the previous one.
fn delay(rng: &mut ChaCha8Rng, net: &mut DualNetwork) -> Injected {
    let bit_rate = net.bus.bit_rate();
    let beyond = rng.random_bool(0.5);
    let margin = micros(50..2_000, rng);
    let inverted = rng.random_bool(0.5);
    let target = rng.random_range(1..3usize) * 2; // a pair with a previous pair seen
    let last_plain = Rc::new(Cell::new(Instant::ZERO));
    let last_pair = Rc::new(Cell::new(Instant::ZERO));
    let (plain_at, pair_at) = (last_plain.clone(), last_pair.clone());
    let effect = tap_srdo(net, move |index, delivery| {
        let is_plain = delivery.frame.id().raw() == 0x101;
        if index == target + usize::from(inverted) {
            // Delay so the frame arrives SRVT (inverted) or SCT (pair) ± margin after the
            // reference, the inverted frame following its plain about a frame time later.
            let (reference, limit, follow) = if inverted {
                (plain_at.get(), SRVT, Duration::ZERO)
            } else {
                let inverted_time = frame_time(&delivery.frame, bit_rate);
                (pair_at.get(), SCT, inverted_time)
            };
            let target_at = if beyond {
                reference + limit + margin
            } else {
                Instant::from_micros((reference + limit).as_micros() - margin.as_micros())
            };
            let target_at =
                Instant::from_micros(target_at.as_micros().saturating_sub(follow.as_micros()));
            if target_at > delivery.at {
                return Some(vec![Delivery {
                    at: target_at,
                    ..delivery
                }]);
            }
        }
        if is_plain {
            plain_at.set(delivery.at);
        } else {
            pair_at.set(delivery.at);
        }
        None
    });
    Injected::tapped(
        format!(
            "{} {} {} by {} µs",
            if inverted {
                "inverted frame after its plain frame"
            } else {
                "pair after the previous pair"
            },
            if beyond { "beyond" } else { "inside" },
            if inverted { "SRVT" } else { "SCT" },
            margin.as_micros()
        ),
        effect,
    )
}

/// Node 33's output changes as the oracle takes them: (time, channel, value).
fn consumer_outputs(net: &DualNetwork) -> Vec<(Instant, usize, u64)> {
    net.outputs
        .iter()
        .filter(|(_, id, _, srdo, _)| *id == CONSUMER && *srdo == 1)
        .map(|(at, _, side, _, value)| (*at, *side as usize, *value))
        .collect()
}

/// When node 33 reached its safe state at or after `from`: the first time at or after its
/// first safety event (a channel's latched fault, the core's SRDO fault, safe state or GFC)
/// at which its effective output (both channels in series) is 0.
fn safe_since(
    net: &DualNetwork,
    outputs: &[(Instant, usize, u64)],
    from: Instant,
) -> Option<Instant> {
    let event = net
        .log
        .iter()
        .find(|(at, id, _, event)| {
            *at >= from
                && *id == CONSUMER
                && matches!(
                    event,
                    ChannelEvent::Fault(_)
                        | ChannelEvent::Node(
                            Event::SrdoFault(_) | Event::SafeState(_) | Event::GfcReceived
                        )
                )
        })
        .map(|(at, ..)| *at)?;
    let mut values = [0u64; 2];
    for (at, channel, value) in outputs {
        if *at > event && values[0] & values[1] == 0 {
            return Some(event);
        }
        values[*channel] = *value;
        if *at >= event && values[0] & values[1] == 0 {
            return Some(*at.max(&event));
        }
    }
    (values[0] & values[1] == 0).then_some(event)
}

/// The network configured and started, with node 1 sending `input` and node 33's output
/// carrying it (after 100 ms): the starting point of the deterministic tests.
pub fn steady(input: u8) -> DualNetwork {
    let mut net = DualNetwork::new(BIT_RATE, &[PRODUCER, CONSUMER]);
    net.configure_and_start().expect("configuration accepted");
    net.set_inputs(PRODUCER, input, input);
    net.run_for(Duration::from_millis(100));
    assert_eq!(net.output(CONSUMER), u64::from(input), "steady state");
    net
}

/// What the oracle and the outputs say about a run.
#[derive(Debug)]
pub struct Verdict {
    /// The oracle's judgement of node 33's outputs up to now.
    pub judgement: oracle::Judgement,
    /// When node 33 reached its safe state at or after the `from` given.
    pub safe_at: Option<Instant>,
}

/// Judges `net` up to now, and finds node 33's safe state at or after `from`.
pub fn verdict(net: &DualNetwork, from: Instant) -> Verdict {
    let outputs = consumer_outputs(net);
    Verdict {
        judgement: oracle::judge(MONITORED, &net.trace, &outputs, net.now),
        safe_at: safe_since(net, &outputs, from),
    }
}

/// The network after start, carrying `input`, or why it did not get there.
fn started(rng: &mut ChaCha8Rng, input: u8, bit_rate: u32) -> Result<DualNetwork, String> {
    let mut net = DualNetwork::new(bit_rate, &[PRODUCER, CONSUMER]);
    net.configure_and_start()
        .map_err(|error| format!("configuration failed: {error:?}"))?;
    net.set_inputs(PRODUCER, input, input);
    net.run_for(add(Duration::from_millis(100), micros(0..25_000, rng)));
    let steady = net.output(CONSUMER) == u64::from(input)
        && net
            .nodes
            .iter()
            .all(|node| node.a.is_working() && node.b.is_working());
    if !steady {
        return Err(format!(
            "not in the steady state: output {:#x}, expected {input:#04x}",
            net.output(CONSUMER)
        ));
    }
    Ok(net)
}

/// Runs scenario `seed` of `class` on a bus at `bit_rate` (the same seed draws the same
/// fault at every rate).
pub fn run(class: Class, seed: u64, bit_rate: u32) -> ScenarioResult {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(class as u64);
    let input = rng.random_range(1..=255u8);
    let mut result = ScenarioResult {
        class,
        seed,
        bit_rate,
        fault: String::new(),
        outcome: Outcome::SetupFailed,
        latency: None,
        reaction: None,
        report: None,
    };
    let mut net = match started(&mut rng, input, bit_rate) {
        Ok(net) => net,
        Err(why) => {
            result.report = Some(why);
            return result;
        }
    };
    let start = net.now;
    let mut injected = inject(class, &mut rng, &mut net, input);
    let (bound, _) = class.bound(bit_rate);
    if injected.horizon == Duration::ZERO {
        injected.horizon = add(bound, Duration::from_millis(100));
    }
    net.run_for(injected.horizon);
    result.fault = injected.fault;
    let end = net.now;
    let outputs = consumer_outputs(&net);
    let judgement = oracle::judge(MONITORED, &net.trace, &outputs, end);
    let Some(effect) = injected.effect.get() else {
        result.outcome = Outcome::NotApplied;
        result.report = Some(timeline(&net, start, end, "the fault never took effect"));
        return result;
    };
    let safe = safe_since(&net, &outputs, effect);
    if let Some(detail) = &injected.detail {
        result.fault = result.fault.replace("{}", &detail.borrow());
    }
    result.latency = safe.map(|at| at.saturating_since(effect));
    result.reaction = match (safe, judgement.first_error) {
        (Some(safe), Some((required, _))) => Some(safe.saturating_since(required)),
        _ => None,
    };
    result.outcome = if !judgement.violations.is_empty() {
        Outcome::Unsafe
    } else if let Some(latency) = result.latency {
        if latency > bound {
            Outcome::Late
        } else {
            Outcome::Detected
        }
    } else if injected.must_detect {
        Outcome::Late // never detected, though it had to be
    } else {
        Outcome::Harmless
    };
    let own_fault = injected
        .own_fault
        .map(|(id, side, expected)| (id, side, expected, first_fault(&net, id, side, effect)));
    let wrong_cause = match own_fault {
        Some((id, side, expected, latched)) if latched != Some(expected) => {
            // The channel's own safe state for this fault never came.
            if !result.outcome.is_failure() {
                result.outcome = Outcome::Late;
            }
            Some(format!(
                "node {id} channel {side:?} latched {} first, not {} ({:02X}h)",
                latched.map_or("nothing".to_string(), |fault| format!(
                    "{} ({:02X}h)",
                    fault.cause().describe(),
                    fault.cause_code()
                )),
                expected.cause().describe(),
                expected.cause_code()
            ))
        }
        _ => None,
    };
    if result.outcome.is_failure() {
        let why = match (result.outcome, wrong_cause) {
            (_, Some(why)) => why,
            (outcome, None) => match outcome {
                Outcome::Unsafe => judgement
                    .violations
                    .iter()
                    .take(3)
                    .map(|violation| violation.why.clone())
                    .collect::<Vec<_>>()
                    .join("; "),
                _ => format!(
                    "safe state after {:?} µs, bound {} µs",
                    result.latency.map(Duration::as_micros),
                    bound.as_micros()
                ),
            },
        };
        let around = judgement
            .violations
            .first()
            .map_or(effect, |violation| violation.at);
        let from = Instant::from_micros(around.as_micros().saturating_sub(30_000)).max(start);
        result.report = Some(timeline(&net, from, end, &why));
    }
    result
}

/// The first fault channel `side` of node `id` latched at or after `from`.
pub fn first_fault(net: &DualNetwork, id: u8, side: Side, from: Instant) -> Option<ChannelFault> {
    net.log
        .iter()
        .find_map(|(at, node, channel, event)| match event {
            ChannelEvent::Fault(fault) if *at >= from && *node == id && *channel == side => {
                Some(*fault)
            }
            _ => None,
        })
}

/// The bus frames, channel events and node 33's outputs from `from` to `to`, as text.
pub fn timeline(net: &DualNetwork, from: Instant, to: Instant, why: &str) -> String {
    let mut lines: Vec<(Instant, String)> = Vec::new();
    for (at, frame, sender) in &net.trace {
        if *at >= from && *at <= to {
            lines.push((
                *at,
                format!(
                    "bus     {:03X} [{}] {:02X?} from participant {sender}",
                    frame.id().raw(),
                    frame.dlc(),
                    frame.data()
                ),
            ));
        }
    }
    for (at, id, side, event) in &net.log {
        if *at >= from && *at <= to {
            lines.push((*at, format!("event   node {id} {side:?}: {event:?}")));
        }
    }
    for (at, id, side, srdo, value) in &net.outputs {
        if *at >= from && *at <= to {
            lines.push((
                *at,
                format!("output  node {id} {side:?} SRDO {srdo} = {value:#x}"),
            ));
        }
    }
    lines.sort_by_key(|(at, _)| *at);
    let mut text = format!("{why}\n");
    for (at, line) in lines.iter().take(400) {
        let _ = writeln!(text, "{:>10} µs  {line}", at.as_micros());
    }
    if lines.len() > 400 {
        let _ = writeln!(text, "… {} more lines", lines.len() - 400);
    }
    text
}

/// What a campaign of one class found.
#[derive(Clone, Debug, Default)]
pub struct Summary {
    /// Scenarios run (each injects one fault).
    pub injected: u64,
    /// Scenarios whose fault ended in node 33's safe state within the bound.
    pub detected: u64,
    /// Scenarios whose fault required nothing and changed nothing.
    pub harmless: u64,
    /// Scenarios the oracle judged unsafe (must be 0).
    pub unsafe_: u64,
    /// Scenarios with the safe state beyond the bound (must be 0).
    pub late: u64,
    /// Harness failures (setup, fault not applied; must be 0).
    pub harness: u64,
    /// Every detection latency, in µs.
    pub latencies: Vec<u64>,
    /// The largest reaction after the oracle's deadline, in µs.
    pub max_reaction: u64,
    /// The failed scenarios (seed, fault, report).
    pub failures: Vec<ScenarioResult>,
}

impl Summary {
    /// Adds one scenario's result.
    pub fn add(&mut self, result: ScenarioResult) {
        self.injected += 1;
        match result.outcome {
            Outcome::Detected => self.detected += 1,
            Outcome::Harmless => self.harmless += 1,
            Outcome::Unsafe => self.unsafe_ += 1,
            Outcome::Late => self.late += 1,
            Outcome::SetupFailed | Outcome::NotApplied => self.harness += 1,
        }
        if let (Outcome::Detected | Outcome::Late, Some(latency)) = (result.outcome, result.latency)
        {
            self.latencies.push(latency.as_micros());
        }
        if let Some(reaction) = result.reaction {
            self.max_reaction = self.max_reaction.max(reaction.as_micros());
        }
        if result.outcome.is_failure() {
            self.failures.push(result);
        }
    }

    /// The largest detection latency, in µs.
    pub fn max_latency(&self) -> Option<u64> {
        self.latencies.iter().copied().max()
    }

    /// `true` when no scenario failed.
    pub fn passed(&self) -> bool {
        self.unsafe_ == 0 && self.late == 0 && self.harness == 0
    }
}

/// Runs `count` scenarios of `class` with seeds `first_seed..` at `bit_rate`, on `threads`
/// threads.
pub fn campaign(
    class: Class,
    first_seed: u64,
    count: u64,
    bit_rate: u32,
    threads: usize,
) -> Summary {
    let threads = threads.max(1) as u64;
    let results: Vec<ScenarioResult> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..threads)
            .map(|worker| {
                scope.spawn(move || {
                    (0..count)
                        .filter(|n| n % threads == worker)
                        .map(|n| run(class, first_seed.wrapping_add(n), bit_rate))
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        handles
            .into_iter()
            .flat_map(|handle| handle.join().expect("a scenario panicked"))
            .collect()
    });
    let mut summary = Summary::default();
    let mut results = results;
    results.sort_by_key(|result| result.seed);
    for result in results {
        summary.add(result);
    }
    summary
}
