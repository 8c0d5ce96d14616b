//! Seeded fault campaigns over SimpleCAN (IEC 61784-3's communication errors, as SimpleCAN
//! answers them: `docs/simplecan.md` sections 2..7), on the host network of
//! [`crate::simplecan_net`], judged by the independent [`super::simplecan_oracle`].
//!
//! The network: node 1 produces the emergency stop, SC-ID 30h in slot 0, and is a potential
//! master; node 2 produces 38h in slot 3 and is a potential master; node 3 consumes 30h with a
//! 50 ms safety timeout into its output 6200h:01. N = 10 slots of 1 ms, a sync every 10 cycles,
//! 500 kbit/s. A scenario starts the network (released: value 1), lets it synchronise, and
//! injects its class's fault at a seeded instant:
//!
//! - *the producer leaves* (bad CRC, replay, masquerade, delay, lost, master gone): node 1 is
//!   switched off, and (except for lost and master gone) 1..6 frames of 30h with value 1 go
//!   from the tool's port (participant 0) into the producer's slot of the following cycles,
//!   so that only the check the class is about stands between them and the output: a
//!   corrupted, a replayed, a masqueraded packet, or the packet node 1 would have sent,
//!   delayed. Node 1 is the active master, so master gone also watches node 2 take over;
//! - *the producer stays* (babbling, sync loss, two masters, leaky counter): a higher-priority
//!   identifier hogs the bus, every sync is lost on the bus for a while, a second master's
//!   syncs appear, or packets with a bad CRC arrive at a rate around the leaky counter's limit.
//!
//! The oracle then looks at every frame on the bus and node 3's output.
//!
//! Outcome: *detected* (the consumer's output went to 0 where the class's rule requires it,
//! with the latency from the class's reference instant), *harmless* (the output never had to
//! change, and did not), *spurious* (the output went to 0 while the oracle required nothing:
//! must not happen in the classes whose rule the oracle predicts exactly), *unsafe* (the oracle
//! found an output not backed by a valid packet within its safety timeout, or not 0 where a
//! rule requires the safe state: must never happen); a detection beyond the class's bound is
//! *late* (must never happen).

use super::simplecan_oracle::{self as oracle, MonitoredEntry};
use crate::bus::frame_time;
use crate::simplecan_net::{
    INPUT, OUTPUT_1, ROLE_CONSUME, ROLE_MASTER, ROLE_PRODUCE, ReceiveLoss, ScConfig, ScEntry,
    ScNetwork, node_hash,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use shared::canopen::nmt::NmtCommand;
use shared::frame::CanId;
use shared::{CanFrame, Duration, Instant};

/// The emergency stop's SC-ID.
pub const ESTOP: u8 = 0x30;
/// The second producer's (and master's) SC-ID.
pub const SECOND: u8 = 0x38;
/// The consumer's safety timeout for 30h.
pub const TIMEOUT_MS: u16 = 50;
/// The bit rate.
pub const BIT_RATE: u32 = 500_000;
/// The longest 8-byte frame at 500 kbit/s, the stated buffering time (SC_REQ_33).
const FRAME_US: u16 = 270;
/// Slots per cycle.
const SLOTS: u16 = 10;
/// The cycle: N slots of 1 ms.
const CYCLE_US: u64 = SLOTS as u64 * 1_000;

/// A SimpleCAN fault class.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScClass {
    /// A packet of 30h with the value changed and the CRC left as it was (corruption).
    BadCrc,
    /// An old packet of 30h (value 1, an old cycle stamp) sent again (repetition, delay).
    Replay,
    /// A packet of 30h with value 1 and the current stamp, signed with 38h's node hash
    /// (masquerade: another SC-ID's, or another network's, sender).
    Masquerade,
    /// The producer switched off (loss): the value must be 0 at the timeout.
    Lost,
    /// The packet the producer would have sent next (value 1, its cycle's stamp, its own
    /// hash) on the bus late: within its slot and the 2 ms tolerance, past them, or past the
    /// safety timeout (delay, SC_REQ_20, SC_REQ_18).
    Delay,
    /// A higher-priority identifier (002h..02Eh, ahead of every SimpleCAN frame) sent back
    /// to back for 1 to 120 ms beside the SimpleCAN traffic: a bus hog (SC_REQ_20).
    Babbling,
    /// Every sync lost by every receiver for 1000 to 3000 ms while the producer goes on
    /// (SC_REQ_32).
    SyncLoss,
    /// 1 to 3 checked syncs of a second master, 38h, while 30h is active (SC_REQ_26).
    TwoMasters,
    /// The active master (node 1, 30h) switched off: node 2 (38h) must take over after
    /// 2000 ms and its t_wait, not before (SC_REQ_25, SC_REQ_27, SC_REQ_32).
    MasterGone,
    /// Packets of 30h with a bad CRC, evenly spaced 2 to 40 ms apart, 3 fewer to 3 more
    /// than the leaky counter needs to reach 1000 (SC_REQ_42).
    LeakyCounter,
    /// Dual-channel nodes: the producer's two contacts move less than the sample window
    /// apart across a slot start (SC_REQ_10; [`super::simplecan_dual`]): no safe state.
    DualSkew,
    /// The contacts further apart than the window and a cycle: the producer's safe state.
    DualSkewBeyond,
    /// One of the producer's channel clocks off within the envelope the Model A sync check
    /// keeps (SC_REQ_31): no safe state.
    DualClock,
    /// One of the producer's channel clocks 2,500 to 5,000 ppm off: the producer's safe
    /// state.
    DualClockBeyond,
}

impl ScClass {
    /// The classes whose name starts with `prefix` (`simplecan` names them all).
    pub fn matching(prefix: &str) -> Vec<ScClass> {
        ScClass::ALL
            .into_iter()
            .filter(|class| class.name().starts_with(prefix))
            .collect()
    }

    /// Every class.
    pub const ALL: [ScClass; 14] = [
        ScClass::BadCrc,
        ScClass::Replay,
        ScClass::Masquerade,
        ScClass::Lost,
        ScClass::Delay,
        ScClass::Babbling,
        ScClass::SyncLoss,
        ScClass::TwoMasters,
        ScClass::MasterGone,
        ScClass::LeakyCounter,
        ScClass::DualSkew,
        ScClass::DualSkewBeyond,
        ScClass::DualClock,
        ScClass::DualClockBeyond,
    ];

    /// The name on the command line and in the report.
    pub fn name(self) -> &'static str {
        match self {
            ScClass::BadCrc => "simplecan-bad-crc",
            ScClass::Replay => "simplecan-replay",
            ScClass::Masquerade => "simplecan-masquerade",
            ScClass::Lost => "simplecan-lost",
            ScClass::Delay => "simplecan-delay",
            ScClass::Babbling => "simplecan-babbling",
            ScClass::SyncLoss => "simplecan-sync-loss",
            ScClass::TwoMasters => "simplecan-two-masters",
            ScClass::MasterGone => "simplecan-master-gone",
            ScClass::LeakyCounter => "simplecan-leaky-counter",
            ScClass::DualSkew => "simplecan-dual-skew",
            ScClass::DualSkewBeyond => "simplecan-dual-skew-beyond",
            ScClass::DualClock => "simplecan-dual-clock",
            ScClass::DualClockBeyond => "simplecan-dual-clock-beyond",
        }
    }

    /// The requirement whose rule the class's detection follows.
    pub fn requirement(self) -> &'static str {
        match self {
            ScClass::BadCrc | ScClass::LeakyCounter => "SC_REQ_42",
            ScClass::Replay => "SC_REQ_18",
            ScClass::Masquerade => "SC_REQ_15",
            ScClass::Lost | ScClass::Delay | ScClass::Babbling => "SC_REQ_20",
            ScClass::SyncLoss => "SC_REQ_32",
            ScClass::TwoMasters => "SC_REQ_26",
            ScClass::MasterGone => "SC_REQ_25, SC_REQ_27",
            ScClass::DualSkew | ScClass::DualSkewBeyond | ScClass::DualClockBeyond => "SC_REQ_10",
            ScClass::DualClock => "SC_REQ_31, SC_REQ_10",
        }
    }

    /// What the latency runs from, for the report.
    pub fn latency_from(self) -> &'static str {
        match self {
            ScClass::SyncLoss => "the end of the last sync the consumer heard",
            ScClass::TwoMasters => "the end of the sync that showed two masters",
            ScClass::LeakyCounter => "the end of the packet that took the counter to 1000",
            ScClass::MasterGone => "the old master's last sync (to the new master's first)",
            ScClass::DualSkew => "the first contact's press (to node 33's output at 0)",
            ScClass::DualSkewBeyond => "the first contact's change (to node 1's safe state)",
            ScClass::DualClock => "– (no safe state may follow)",
            ScClass::DualClockBeyond => "the clock's change (to node 1's safe state)",
            _ => "the slot of the last valid packet of 1",
        }
    }

    /// The bound of the class's latency, from the configuration: the safety timeout
    /// (SC_REQ_20); for sync loss 2000 ms more (SC_REQ_32); for two masters and the leaky
    /// counter the reaction allowance (the safe state at the frame that shows the fault); for
    /// master gone 2000 ms, 38h's t_wait (40 ms, SC_REQ_27), then at most one cycle to the
    /// last slot and that slot itself.
    pub fn bound(self) -> Duration {
        let timeout = Duration::from_millis(u64::from(TIMEOUT_MS));
        match self {
            ScClass::SyncLoss => plus(oracle::SYNC_LOSS, timeout),
            ScClass::TwoMasters | ScClass::LeakyCounter => REACTION,
            ScClass::DualSkew => super::simplecan_dual::PRESS_BOUND,
            ScClass::DualSkewBeyond => super::simplecan_dual::APART_BOUND,
            ScClass::DualClock | ScClass::DualClockBeyond => super::simplecan_dual::CLOCK_BOUND,
            ScClass::MasterGone => {
                let slots = Duration::from_millis(u64::from(SLOTS) + 1);
                plus(plus(oracle::SYNC_LOSS, t_wait(SECOND)), slots)
            }
            _ => timeout,
        }
    }

    /// Whether the class runs on dual-channel nodes ([`super::simplecan_dual`]).
    pub fn dual_channel(self) -> bool {
        matches!(
            self,
            ScClass::DualSkew
                | ScClass::DualSkewBeyond
                | ScClass::DualClock
                | ScClass::DualClockBeyond
        )
    }

    /// Whether the oracle predicts this class's outcome exactly, so that a safe state it did
    /// not require is a failure (spurious) rather than a harmless early reaction.
    fn exact(self) -> bool {
        matches!(
            self,
            ScClass::Babbling | ScClass::SyncLoss | ScClass::TwoMasters | ScClass::LeakyCounter
        )
    }
}

/// The reaction allowance of a safe state the oracle requires at a frame: the consumer
/// latches it when it handles that frame.
pub const REACTION: Duration = Duration::from_millis(1);

/// `a + b` (`shared::Duration` has no addition of its own).
fn plus(a: Duration, b: Duration) -> Duration {
    Duration::from_micros(a.as_micros() + b.as_micros())
}

/// SC_REQ_27's `t_wait = (ID − 30h) × 5 ms`, from the requirement's formula.
fn t_wait(sc_id: u8) -> Duration {
    Duration::from_millis(u64::from(sc_id - 0x30) * 5)
}

/// What one scenario came to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScOutcome {
    /// The output went to 0 where the class's rule requires it, with the latency from the
    /// class's reference instant ([`ScClass::latency_from`]).
    Detected(Duration),
    /// Nothing the consumer took changed.
    Harmless,
    /// The output went to 0 at this instant while a valid packet still backed it and no rule
    /// required the safe state.
    Spurious(Instant),
    /// The oracle found a value not backed by a valid packet, or not 0 where a rule requires
    /// the safe state, at this instant.
    Unsafe(Instant),
}

/// One scenario's result.
#[derive(Clone, Debug)]
pub struct ScResult {
    /// The class.
    pub class: ScClass,
    /// The seed.
    pub seed: u64,
    /// The frames injected (for sync loss: the syncs lost).
    pub injected: usize,
    /// The outcome.
    pub outcome: ScOutcome,
}

fn entry(sc_id: u8, role: u8, slot: u16, timeout_ms: u16, mapped: u32) -> ScEntry {
    ScEntry {
        sc_id,
        role,
        slot,
        timeout_ms,
        mapped,
    }
}

fn config(potential_master: bool, entries: Vec<ScEntry>) -> ScConfig {
    ScConfig {
        slots: SLOTS,
        sync_every: 10,
        buffering_us: FRAME_US,
        potential_master,
        entries,
    }
}

/// What the oracle is told: the SDD entry 30h as node 3 has it, the cycle, the masters.
pub fn monitored() -> MonitoredEntry {
    MonitoredEntry {
        sc_id: ESTOP,
        hash: node_hash(ESTOP),
        slot: 0,
        slots: SLOTS,
        timeout: Duration::from_millis(u64::from(TIMEOUT_MS)),
        masters: [(ESTOP, node_hash(ESTOP)), (SECOND, node_hash(SECOND))],
        buffering: Duration::from_micros(u64::from(FRAME_US)),
    }
}

/// The configured network, started and synchronised, the emergency stop released (1).
pub fn started() -> ScNetwork {
    let mut net = ScNetwork::new(BIT_RATE, &[1, 2, 3]);
    net.run_for(Duration::from_millis(10));
    let configs = [
        (
            1,
            config(
                true,
                vec![
                    entry(ESTOP, ROLE_PRODUCE, 0, 0, INPUT),
                    entry(SECOND, ROLE_MASTER, 0, 0, 0),
                ],
            ),
        ),
        (
            2,
            config(
                true,
                vec![
                    entry(SECOND, ROLE_PRODUCE, 3, 0, INPUT),
                    entry(ESTOP, ROLE_MASTER, 0, 0, 0),
                ],
            ),
        ),
        (
            3,
            config(
                false,
                vec![
                    entry(ESTOP, ROLE_CONSUME, 0, TIMEOUT_MS, OUTPUT_1),
                    entry(SECOND, ROLE_MASTER, 0, 0, 0),
                ],
            ),
        ),
    ];
    for (id, config) in &configs {
        net.configure(*id, config)
            .unwrap_or_else(|error| panic!("the campaign network's configuration: {error}"));
    }
    net.set_input(1, 1);
    net.set_input(2, 1);
    net.nmt(NmtCommand::Start, 0);
    net.run_for(Duration::from_millis(1_000));
    net
}

/// The packets of 30h node 1 sent, from the trace.
fn produced(net: &ScNetwork) -> Vec<CanFrame> {
    net.trace
        .iter()
        .filter(|(_, _, frame, from)| *from == 1 && frame.id().raw() == u16::from(ESTOP))
        .map(|&(_, _, frame, _)| frame)
        .collect()
}

/// A frame of `identifier` with `data`.
fn frame_of(identifier: u16, data: [u8; 8]) -> CanFrame {
    CanFrame::new(CanId::new(identifier).expect("an 11-bit identifier"), &data).expect("8 bytes")
}

/// A frame of 30h with `data`.
fn packet(data: [u8; 8]) -> CanFrame {
    frame_of(u16::from(ESTOP), data)
}

/// A packet of 30h with `value` and `stamp`, its CRC computed by the oracle's own CRC-24
/// over `hash` (`docs/simplecan.md` sections 2 and 4).
fn signed(hash: u32, value: u8, stamp: u8) -> [u8; 8] {
    let payload = [value, 0, 0, 0, stamp];
    let [_, c2, c1, c0] = oracle::packet_crc(hash, u16::from(ESTOP), &payload).to_be_bytes();
    [value, 0, 0, 0, stamp, c2, c1, c0]
}

/// How late the delayed packet of a cycle goes on the bus after its slot's start: a third
/// within the slot and the tolerance beyond it (accepted up to about 2.7 ms: received
/// within 3 ms of the slot's start, `docs/simplecan.md` section 5), a third past them but
/// within the cycle, a third past the safety timeout (its stamp then names a cycle 5 to 15
/// back; never 256 cycles, which a continuous physical layer does not store, SC_REQ_44).
fn delay(rng: &mut ChaCha8Rng) -> Duration {
    Duration::from_micros(match rng.random_range(0..3) {
        0 => rng.random_range(0..3_000),
        1 => rng.random_range(3_000..10_000),
        _ => rng.random_range(50_000..=150_000),
    })
}

/// Runs the scenario `seed` of `class`.
pub fn run(class: ScClass, seed: u64) -> ScResult {
    if class.dual_channel() {
        return super::simplecan_dual::run(class, seed);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ ((class as u64) << 56));
    let mut net = started();
    let released = produced(&net);
    net.run_for(Duration::from_micros(rng.random_range(0..20_000)));
    let injected = match class {
        ScClass::BadCrc
        | ScClass::Replay
        | ScClass::Masquerade
        | ScClass::Lost
        | ScClass::MasterGone => producer_leaves(class, &mut net, &mut rng, &released),
        ScClass::Delay => {
            let packets = rng.random_range(1..=6);
            let delays: Vec<_> = (0..packets).map(|_| delay(&mut rng)).collect();
            delayed(&mut net, &delays)
        }
        ScClass::Babbling => {
            let identifier = rng.random_range(0x002..=0x02E);
            let span = Duration::from_micros(rng.random_range(1_000..=120_000));
            babble(&mut net, identifier, span, &mut rng)
        }
        ScClass::SyncLoss => lose_syncs(
            &mut net,
            Duration::from_millis(rng.random_range(1_000..=3_000)),
        ),
        ScClass::TwoMasters => {
            let syncs = rng.random_range(1..=3);
            for _ in 0..syncs {
                // The network's cycle (from the last sync on the bus) or a random one.
                let cycle = rng.random_bool(0.5).then(|| rng.random());
                second_master(&mut net, cycle, rng.random_range(0..1_000));
                net.run_for(Duration::from_micros(rng.random_range(1_000..=200_000)));
            }
            net.run_for(Duration::from_millis(100));
            syncs
        }
        ScClass::LeakyCounter => {
            let spacing = Duration::from_micros(rng.random_range(2_000..=40_000));
            let count = leaky_count(spacing, rng.random_range(-3..=3));
            bad_crcs(&mut net, count, spacing, &mut rng)
        }
        ScClass::DualSkew
        | ScClass::DualSkewBeyond
        | ScClass::DualClock
        | ScClass::DualClockBeyond => unreachable!("run on dual-channel nodes, above"),
    };
    ScResult {
        class,
        seed,
        injected,
        outcome: judge(class, &net),
    }
}

/// Node 1 leaves the bus (it was producing 30h and was the active master): the last packet
/// of 30h it sent, and when that started (its slot's start: node 1 is the master, so its
/// slots start by its own clock).
fn switch_off_producer(net: &mut ScNetwork) -> (CanFrame, Instant) {
    net.switch_off(1);
    let (start, _, frame) = *net.sent(u16::from(ESTOP)).last().expect("a packet of 30h");
    (frame, start)
}

/// Sends each of `frames` (instant, frame) from the tool's port at its instant, in order of
/// the instants, then runs on for `after`. Returns how many were sent.
fn inject(net: &mut ScNetwork, mut frames: Vec<(Instant, CanFrame)>, after: Duration) -> usize {
    frames.sort_by_key(|&(at, _)| at);
    let injected = frames.len();
    for (at, frame) in frames {
        net.run_until(at);
        net.bus.send(0, frame);
    }
    net.run_for(after);
    injected
}

/// The producer leaves the bus (loss); the classes of corrupted, old or masqueraded packets
/// then put 1..6 frames into the producer's slot of the following cycles, where only the
/// check the class is about can refuse them. Returns the frames injected.
fn producer_leaves(
    class: ScClass,
    net: &mut ScNetwork,
    rng: &mut ChaCha8Rng,
    released: &[CanFrame],
) -> usize {
    let (last, last_start) = switch_off_producer(net);
    let attacks = match class {
        ScClass::Lost | ScClass::MasterGone => 0,
        _ => rng.random_range(1..=6u64),
    };
    let mut frames = Vec::new();
    for k in 1..=attacks {
        let at = last_start + Duration::from_micros(CYCLE_US * k + rng.random_range(0..500));
        // The stamp of the k-th cycle after the last packet's.
        let stamp = last.raw_data()[4].wrapping_add(k as u8);
        let frame = match class {
            ScClass::BadCrc => {
                // The packet the producer would have sent, one seeded bit flipped.
                let mut data = signed(node_hash(ESTOP), 1, stamp);
                let bit = rng.random_range(0..64);
                data[bit / 8] ^= 1 << (bit % 8);
                packet(data)
            }
            // A released packet of the last second, sent again as it was.
            ScClass::Replay => {
                released[rng.random_range(released.len().saturating_sub(100)..released.len())]
            }
            // The right stamp and slot, signed with 38h's hash.
            ScClass::Masquerade => packet(signed(node_hash(SECOND), 1, stamp)),
            _ => unreachable!("no frames injected"),
        };
        frames.push((at, frame));
    }
    inject(
        net,
        frames,
        match class {
            // The takeover: 2000 ms, t_wait, a cycle, and 250 ms to see it hold.
            ScClass::MasterGone => Duration::from_millis(2_300),
            _ => Duration::from_millis(200),
        },
    )
}

/// The producer leaves the bus, and the packets it would have sent in the following cycles
/// (value 1, each cycle's stamp, its own hash) go on the bus `delays` after their slots'
/// starts (the k-th delay for the k-th cycle). Returns the packets sent.
pub fn delayed(net: &mut ScNetwork, delays: &[Duration]) -> usize {
    let (last, last_start) = switch_off_producer(net);
    let frames = (1..)
        .zip(delays)
        .map(|(k, &late)| {
            let stamp = last.raw_data()[4].wrapping_add(k as u8);
            let at = last_start + plus(Duration::from_micros(CYCLE_US * k), late);
            (at, packet(signed(node_hash(ESTOP), 1, stamp)))
        })
        .collect();
    inject(net, frames, Duration::from_millis(200))
}

/// `span` of frames of `identifier` (002h..02Eh: above every SimpleCAN frame, below NMT and
/// GFC), 8 random bytes each, queued at once so that they go back to back: every SimpleCAN
/// frame waits, a packet beyond its slot is withdrawn (SC_REQ_18), a sync beyond 2 ms
/// (SC_REQ_23). Runs on 200 ms after the span; returns the frames sent.
pub fn babble(net: &mut ScNetwork, identifier: u16, span: Duration, rng: &mut ChaCha8Rng) -> usize {
    let mut queued = Duration::ZERO;
    let mut frames = 0;
    while queued < span {
        let frame = frame_of(identifier, rng.random());
        queued = plus(queued, frame_time(&frame, BIT_RATE));
        net.bus.send(0, frame);
        frames += 1;
    }
    net.run_for(plus(span, Duration::from_millis(200)));
    frames
}

/// Every sync lost by every receiver for `span` (the master sees each go out); the data
/// packets go on. Runs on 300 ms after the span; returns the syncs lost.
pub fn lose_syncs(net: &mut ScNetwork, span: Duration) -> usize {
    let loss = ReceiveLoss {
        id: oracle::SYNC_ID,
        from: net.now,
        until: net.now + span,
    };
    net.receive_loss.push(loss);
    net.run_for(plus(span, Duration::from_millis(300)));
    net.trace
        .iter()
        .filter(|&&(_, end, frame, _)| loss.loses(&frame, end))
        .count()
}

/// A checked sync of 38h (signed with 38h's hash) from the tool's port, now: of `cycle`, or
/// of the cycle of the last sync on the bus, with `offset` µs (0..999).
pub fn second_master(net: &mut ScNetwork, cycle: Option<u16>, offset: u16) {
    let cycle = cycle.unwrap_or_else(|| {
        let (_, _, last) = *net.sent(oracle::SYNC_ID).last().expect("a sync");
        u16::from_be_bytes([last.raw_data()[1], last.raw_data()[2]])
    });
    let [c1, c0] = cycle.to_be_bytes();
    let [o1, o0] = offset.to_be_bytes();
    let payload = [SECOND, c1, c0, o1, o0];
    let [_, r2, r1, r0] =
        oracle::packet_crc(node_hash(SECOND), oracle::SYNC_ID, &payload).to_be_bytes();
    net.bus.send(
        0,
        frame_of(oracle::SYNC_ID, [SECOND, c1, c0, o1, o0, r2, r1, r0]),
    );
}

/// How many bad packets `spacing` apart take SC_REQ_42's leaky counter to 1000, plus
/// `margin`: 1000, plus the leaks (one per 3.6 s) over the span they take, plus `margin`.
/// Whether they reach 1000 depends on where the leak ticks fall; the oracle counts that.
pub fn leaky_count(spacing: Duration, margin: i64) -> u64 {
    let limit = i64::from(oracle::BAD_CRC_LIMIT);
    let mut count = limit;
    // The span grows with the count; four rounds settle it within the spacings used here.
    for _ in 0..4 {
        let leaks = (count as u64 - 1) * spacing.as_micros() / oracle::LEAK_PERIOD.as_micros();
        count = limit + leaks as i64 + margin;
    }
    count.max(0) as u64
}

/// `count` packets of 30h with one bit flipped (a bad CRC; value 1, a random stamp), evenly
/// `spacing` apart from now. Runs on 200 ms after the last; returns the packets sent.
pub fn bad_crcs(net: &mut ScNetwork, count: u64, spacing: Duration, rng: &mut ChaCha8Rng) -> usize {
    let first = net.now;
    let frames = (0..count)
        .map(|n| {
            let mut data = signed(node_hash(ESTOP), 1, rng.random());
            let bit = rng.random_range(0..64);
            data[bit / 8] ^= 1 << (bit % 8);
            (
                first + Duration::from_micros(n * spacing.as_micros()),
                packet(data),
            )
        })
        .collect();
    inject(net, frames, Duration::from_millis(200))
}

/// The oracle's verdict on node 3's output over the whole run of a scenario of `class`.
pub fn judge(class: ScClass, net: &ScNetwork) -> ScOutcome {
    let until = net.now;
    let entry = monitored();
    // The bus as the consumer heard it.
    let bus: Vec<_> = net
        .trace
        .iter()
        .filter(|&&(_, end, frame, _)| !net.receive_loss.iter().any(|loss| loss.loses(&frame, end)))
        .map(|&(start, end, frame, _)| (start, end, frame))
        .collect();
    let valid = oracle::valid_packets(&entry, &bus);
    let outputs = &net.devices[net.index_of(3)].outputs;
    if let Some(at) = oracle::first_unbacked(&entry, &valid, outputs, until) {
        return ScOutcome::Unsafe(at);
    }
    // The rules that require the safe state at a frame: several masters (SC_REQ_26), the
    // bad-CRC counter at 1000 (SC_REQ_42).
    let started = oracle::started_at(&bus).expect("the NMT start on the bus");
    let required = [
        oracle::several_masters(&entry, &bus),
        oracle::bad_crc_trip(&entry, &bus, started),
    ]
    .into_iter()
    .flatten()
    .min();
    if let Some(from) = required
        && let Some(at) = oracle::first_not_safe(outputs, from + REACTION)
    {
        return ScOutcome::Unsafe(at);
    }
    // When the output went to 0 for good (after it had carried the released value).
    let zero = match outputs.last() {
        Some(&(at, 0)) if outputs.len() > 1 => Some(at),
        _ => None,
    };
    let Some(zero) = zero else {
        return ScOutcome::Harmless;
    };
    // Backed by a valid packet beyond the consumer's own slot-start estimate (which leads
    // the bus by up to its buffering time) and no rule required it: spurious.
    let backed = valid.iter().any(|packet| {
        packet.value != 0
            && packet.end <= zero
            && packet.produced + entry.timeout > zero + entry.buffering
    });
    if class.exact() && backed && required.is_none_or(|from| zero < from) {
        return ScOutcome::Spurious(zero);
    }
    let latency = match class {
        ScClass::TwoMasters | ScClass::LeakyCounter => match required {
            Some(from) => zero.saturating_since(from),
            None => return ScOutcome::Spurious(zero),
        },
        ScClass::SyncLoss => {
            let heard = oracle::last_sync_before(&entry, &bus, zero).expect("a sync");
            zero.saturating_since(heard)
        }
        ScClass::MasterGone => takeover(&bus, until),
        _ => {
            let Some(from) = valid
                .iter()
                .filter(|packet| packet.value != 0 && packet.end <= zero)
                .map(|packet| packet.produced)
                .max()
            else {
                return ScOutcome::Harmless;
            };
            zero.saturating_since(from)
        }
    };
    if class == ScClass::MasterGone && latency < plus(oracle::SYNC_LOSS, t_wait(SECOND)) {
        // 38h took over while 30h still counted as active (SC_REQ_27).
        return ScOutcome::Spurious(zero);
    }
    ScOutcome::Detected(latency)
}

/// From the start of 30h's last sync to the start of 38h's first after it; to the end of the
/// run when 38h never took over (beyond any bound).
fn takeover(bus: &[(Instant, Instant, CanFrame)], until: Instant) -> Duration {
    let syncs = || {
        bus.iter()
            .filter(|(_, _, frame)| frame.id().raw() == oracle::SYNC_ID)
            .map(|&(start, _, frame)| (start, frame.raw_data()[0]))
    };
    let last = syncs()
        .filter(|&(_, master)| master == ESTOP)
        .map(|(start, _)| start)
        .next_back()
        .expect("a sync of 30h");
    let first = syncs()
        .find(|&(start, master)| master == SECOND && start > last)
        .map_or(until, |(start, _)| start);
    first.saturating_since(last)
}

/// The totals of a class: injected, detected, harmless, spurious, unsafe, late, the worst
/// latency.
#[derive(Clone, Debug, Default)]
pub struct ScSummary {
    /// Scenarios run.
    pub scenarios: u64,
    /// Frames injected (loss and master gone: one fault per scenario).
    pub injected: u64,
    /// Scenarios whose output went to 0 where a rule requires it.
    pub detected: u64,
    /// Scenarios in which nothing the consumer took changed.
    pub harmless: u64,
    /// Scenarios with a safe state that no rule required (must be 0).
    pub spurious: u64,
    /// Scenarios the oracle judged unsafe (must be 0).
    pub unsafe_: u64,
    /// Detections beyond the class's bound (must be 0).
    pub late: u64,
    /// The worst latency of a detection.
    pub max_latency: Option<Duration>,
    /// Every detection latency, in µs (the plot's data).
    pub latencies: Vec<u64>,
    /// The seeds of the unsafe, spurious and late scenarios, to replay them.
    pub failed_seeds: Vec<u64>,
}

impl ScSummary {
    /// Adds one result.
    pub fn add(&mut self, result: &ScResult) {
        self.scenarios += 1;
        self.injected += result.injected.max(1) as u64;
        match result.outcome {
            ScOutcome::Detected(latency) => {
                self.detected += 1;
                if latency > result.class.bound() {
                    self.late += 1;
                    self.failed_seeds.push(result.seed);
                }
                self.max_latency = Some(self.max_latency.map_or(latency, |m| m.max(latency)));
                self.latencies.push(latency.as_micros());
            }
            ScOutcome::Harmless => self.harmless += 1,
            ScOutcome::Spurious(_) => {
                self.spurious += 1;
                self.failed_seeds.push(result.seed);
            }
            ScOutcome::Unsafe(_) => {
                self.unsafe_ += 1;
                self.failed_seeds.push(result.seed);
            }
        }
    }

    /// No scenario unsafe, spurious or late.
    pub fn passed(&self) -> bool {
        self.unsafe_ == 0 && self.spurious == 0 && self.late == 0
    }
}

/// `scenarios` seeds of `class` from `first_seed`.
pub fn campaign(class: ScClass, first_seed: u64, scenarios: u64) -> ScSummary {
    let mut summary = ScSummary::default();
    for seed in first_seed..first_seed + scenarios {
        summary.add(&run(class, seed));
    }
    summary
}

/// The marker lines around the SimpleCAN section of `docs/campaigns.md`: the CANopen Safety
/// report keeps what lies between them, the SimpleCAN run replaces it.
pub const SECTION_BEGIN: &str = "<!-- simplecan-campaign:begin -->";
/// The end marker.
pub const SECTION_END: &str = "<!-- simplecan-campaign:end -->";

/// The longest latency of `summary` in µs, "–" when nothing was detected.
fn max_latency(summary: &ScSummary) -> String {
    summary
        .max_latency
        .map_or("–".to_string(), |latency| latency.as_micros().to_string())
}

/// The plot's file name for `class` (`<class>.svg` in the run's plots directory).
pub fn plot_name(class: ScClass) -> String {
    format!("{}.svg", class.name())
}

/// Writes `dir/<class>.svg`: the latency histogram of `summary` with the class's bound.
pub fn plot(dir: &std::path::Path, class: ScClass, summary: &ScSummary) -> Result<(), String> {
    super::report::histogram(
        &dir.join(plot_name(class)),
        class.name(),
        class.bound().as_micros(),
        &summary.latencies,
        (summary.detected, summary.injected),
    )
}

/// One line of the console output for `summary` of `class`.
pub fn line(class: ScClass, summary: &ScSummary) -> String {
    let mut text = format!(
        "campaign {:<24} injected {:>7}  detected {:>6}  harmless {:>6}  spurious {}  unsafe {}  late {}  max latency {:>8} µs (bound {} µs)",
        class.name(),
        summary.injected,
        summary.detected,
        summary.harmless,
        summary.spurious,
        summary.unsafe_,
        summary.late,
        max_latency(summary),
        class.bound().as_micros()
    );
    if let Some(seed) = summary.failed_seeds.first() {
        text.push_str(&format!(
            "\n  first failing seed {seed}: cargo xtask campaign --class {} --replay {seed}",
            class.name()
        ));
    }
    text
}

/// The SimpleCAN section of the report, markers included; `seconds` the run's wall time on
/// `threads` threads.
pub fn section(
    command: &str,
    first_seed: u64,
    scenarios: u64,
    rows: &[(ScClass, ScSummary)],
    seconds: f64,
    threads: usize,
) -> String {
    let total: u64 = rows.iter().map(|(_, summary)| summary.scenarios).sum();
    let mut text = format!(
        "{SECTION_BEGIN}\n## SimpleCAN\n\n`{command}` ({scenarios} scenarios per class, seeds \
         {first_seed}..{}): {total} scenarios in {seconds:.1} s on {threads} thread(s) of \
         the shared 2-core development machine. On the host SimpleCAN network \
         (`tests/src/campaign/simplecan.rs`): node 1 produces the emergency stop 30h in slot 0 \
         and is the active master, node 2 produces 38h in slot 3 and is the other potential \
         master, node 3 consumes 30h with a 50 ms safety timeout; N = 10 slots of 1 ms, a sync \
         every 10 cycles, 500 kbit/s. Judged by `tests/src/campaign/simplecan_oracle.rs`, which \
         decodes the frames, computes the CRC-24, follows the syncs, counts the bad CRCs and \
         looks for several masters itself (it does not call `shared::simplecan`): an output of \
         1 must be backed by a valid packet (signed, stamped, in its slot within 2 ms, the \
         consumer synced) whose slot started at most the safety timeout before (SC_REQ_20); \
         the output must be 0 from a sync showing two masters (SC_REQ_26) and from the packet \
         that takes the leaky bad-CRC counter to 1000 (SC_REQ_42).\n\n\
         | class | requirement | scenarios | injected | detected | harmless | spurious | unsafe | late | max latency µs | bound µs | latency from |\n\
         |---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|\n",
        first_seed + scenarios
    );
    for (class, summary) in rows {
        text.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
            class.name(),
            class.requirement(),
            summary.scenarios,
            summary.injected,
            summary.detected,
            summary.harmless,
            summary.spurious,
            summary.unsafe_,
            summary.late,
            max_latency(summary),
            class.bound().as_micros(),
            class.latency_from()
        ));
    }
    text.push_str(
        "\nThe faults: bad CRC, replay, masquerade and delay switch the producer off at a \
         seeded instant and put 1..6 frames of value 1 into its slot of the following cycles \
         (one bit flipped; a packet of the last second again; the right stamp signed with \
         38h's hash; the packet node 1 would have sent, 0..3 ms, 3..10 ms or 50..150 ms after \
         its slot's start). Lost switches the producer off; master gone too, and waits for \
         node 2 to take over. Babbling queues frames of one identifier 002h..02Eh back to \
         back for 1..120 ms. Sync loss makes every receiver lose every sync for 1000..3000 ms (the master sees each go out). Two \
         masters sends 1..3 checked syncs of 38h (the network's time or a random one). The \
         leaky counter sends packets of 30h with one bit flipped, 2..40 ms apart, 1000 plus \
         the leaks over their span, give or take 3: the oracle's own counter says whether \
         they reach 1000. *Injected* counts frames (sync loss: syncs lost; lost and master \
         gone: 1). *Spurious*: a safe state while a valid packet still backed the value and \
         no rule required it, counted only for babbling, sync loss, two masters and the leaky \
         counter, whose outcome the oracle predicts exactly (must be 0). *Late*: a detection \
         beyond the bound (must be 0).\n\n\
         Each class's latencies against its bound: `<class>.svg` in the run's plots directory \
         (`target/campaign/plots/`, generated). \
         The `simplecan-dual-…` classes run on dual-channel nodes (both channel runtimes, \
         their link, Model A; `tests/src/campaign/simplecan_dual.rs`): node 1 produces 30h \
         and is the master, node 33 consumes it (50 ms), at 500 or 1000 kbit/s (seeded). \
         *Skew*: node 1's two contacts move on a press or a release 0..4.6 ms apart (the \
         5 ms sample window less a frame time), the first within 3 ms of a slot-0 start; no \
         safe state may follow, and a press must reach node 33's output (detected) within \
         the window, a cycle and a slot. *Skew beyond*: 17..150 ms apart; node 1 must be \
         safe within two windows, a cycle and a slot. *Clock*: from Operational on, channel \
         A's clock 400 ppm slow to 1,600 ppm fast relative to B's (either channel's clock \
         changed), 1 s, no safe state. *Clock beyond*: 2,500..5,000 ppm either way; node 1 \
         must be safe within 600 ms (the oracle allows node 33's timeout the master clock's \
         rate times a sync interval and a timeout more, 750 µs at 5,000 ppm). Run on the code \
         before two Model A fixes, 2,000 per class: 21 spurious in skew (a value that was \
         channel B's current sample but not its previous or next one) and 122 in clock (a \
         packet of A's heard before B computed its own); none after.\n",
    );
    text.push_str(SECTION_END);
    text.push('\n');
    text
}

/// `report` with its SimpleCAN section replaced by `section` (appended when it has none).
pub fn with_section(report: &str, section: &str) -> String {
    match (report.find(SECTION_BEGIN), report.find(SECTION_END)) {
        (Some(begin), Some(end)) if begin < end => {
            let after = &report[end + SECTION_END.len()..];
            format!(
                "{}{section}{}",
                &report[..begin],
                after.strip_prefix('\n').unwrap_or(after)
            )
        }
        _ if report.trim().is_empty() => section.to_string(),
        _ => format!("{}\n\n{section}", report.trim_end_matches('\n')),
    }
}

/// The SimpleCAN section of `report`, if it has one.
pub fn section_of(report: &str) -> Option<&str> {
    let begin = report.find(SECTION_BEGIN)?;
    let end = report.find(SECTION_END)?;
    (begin < end).then(|| &report[begin..end + SECTION_END.len()])
}
