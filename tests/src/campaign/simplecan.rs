//! Seeded fault campaigns over SimpleCAN (IEC 61784-3's communication errors, as SimpleCAN
//! answers them: `docs/simplecan.md` sections 2..7), on the host network of
//! [`crate::simplecan_net`], judged by the independent [`super::simplecan_oracle`].
//!
//! The network: node 1 produces the emergency stop, SC-ID 30h in slot 0, and is a potential
//! master; node 2 produces 38h in slot 3 and is a potential master; node 3 consumes 30h with a
//! 50 ms safety timeout into its output 6200h:01. N = 10 slots of 1 ms, a sync every 10 cycles,
//! 500 kbit/s. A scenario starts the network (released: value 1), lets it synchronise, switches
//! the producer off at a seeded instant, and (except for loss) injects 1..6 frames of 30h
//! from the tool's port (participant 0) into the producer's slot of the following cycles, at
//! a seeded offset into the slot: a corrupted, a replayed or a masqueraded packet of value 1,
//! so that only the check the class is about stands between it and the output. The oracle
//! then looks at every frame on the bus and node 3's output.
//!
//! Outcome: *detected* (the consumer's output went to 0 after the last valid packet of 1,
//! with the latency from that packet's start), *harmless* (the output never had to change),
//! *unsafe* (the oracle found an output not backed by a valid packet within its safety
//! timeout: must never happen). Classes not yet here: delay beyond the slot, sync loss, two
//! masters, a babbling higher-priority identifier, the 1000-per-hour leaky counter.

use super::simplecan_oracle::{self as oracle, MonitoredEntry};
use crate::simplecan_net::{
    INPUT, OUTPUT_1, ROLE_CONSUME, ROLE_MASTER, ROLE_PRODUCE, ScConfig, ScEntry, ScNetwork,
    node_hash,
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
    pub const ALL: [ScClass; 4] = [
        ScClass::BadCrc,
        ScClass::Replay,
        ScClass::Masquerade,
        ScClass::Lost,
    ];

    /// The name on the command line and in the report.
    pub fn name(self) -> &'static str {
        match self {
            ScClass::BadCrc => "simplecan-bad-crc",
            ScClass::Replay => "simplecan-replay",
            ScClass::Masquerade => "simplecan-masquerade",
            ScClass::Lost => "simplecan-lost",
        }
    }
}

/// What one scenario came to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScOutcome {
    /// The output went to 0 within the bound, with the latency from the last valid packet's
    /// start to the output's 0.
    Detected(Duration),
    /// Nothing the consumer took changed.
    Harmless,
    /// The oracle found a value not backed by a valid packet, at this instant.
    Unsafe(Instant),
}

/// One scenario's result.
#[derive(Clone, Debug)]
pub struct ScResult {
    /// The class.
    pub class: ScClass,
    /// The seed.
    pub seed: u64,
    /// The frames injected.
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

/// A frame of 30h with `data`.
fn packet(data: [u8; 8]) -> CanFrame {
    CanFrame::new(CanId::new(u16::from(ESTOP)).expect("30h"), &data).expect("8 bytes")
}

/// Runs the scenario `seed` of `class`.
pub fn run(class: ScClass, seed: u64) -> ScResult {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ ((class as u64) << 56));
    let mut net = started();
    let released = produced(&net);
    net.run_for(Duration::from_micros(rng.random_range(0..20_000)));
    // The producer leaves the bus (loss); every other class then puts its frames into the
    // producer's slot of the following cycles, where only the check the class is about can
    // refuse them.
    net.switch_off(1);
    let last = *produced(&net).last().expect("a packet of 30h");
    let last_start = net
        .sent(u16::from(ESTOP))
        .last()
        .map(|&(start, _, _)| start)
        .expect("a packet of 30h");
    let cycle = Duration::from_millis(u64::from(SLOTS));
    let attacks = if class == ScClass::Lost {
        0
    } else {
        rng.random_range(1..=6u64)
    };
    let mut injected = 0;
    for k in 1..=attacks {
        let at =
            last_start + Duration::from_micros(cycle.as_micros() * k + rng.random_range(0..500));
        net.run_until(at);
        let stamp = last.raw_data()[4].wrapping_add(k as u8);
        let signed = |hash: u32| {
            let payload = [1, 0, 0, 0, stamp];
            let [_, c2, c1, c0] =
                oracle::packet_crc(hash, u16::from(ESTOP), &payload).to_be_bytes();
            [1, 0, 0, 0, stamp, c2, c1, c0]
        };
        let frame = match class {
            ScClass::BadCrc => {
                // The packet the producer would have sent, one seeded bit flipped.
                let mut data = signed(node_hash(ESTOP));
                let bit = rng.random_range(0..64);
                data[bit / 8] ^= 1 << (bit % 8);
                packet(data)
            }
            // A released packet of the last second, sent again as it was.
            ScClass::Replay => {
                released[rng.random_range(released.len().saturating_sub(100)..released.len())]
            }
            // The right stamp and slot, signed with 38h's hash.
            ScClass::Masquerade => packet(signed(node_hash(SECOND))),
            ScClass::Lost => unreachable!("no frames injected"),
        };
        net.bus.send(0, frame);
        injected += 1;
    }
    net.run_for(Duration::from_millis(200));
    let until = net.now;
    let entry = monitored();
    let bus: Vec<_> = net
        .trace
        .iter()
        .map(|&(start, end, frame, _)| (start, end, frame))
        .collect();
    let valid = oracle::valid_packets(&entry, &bus);
    let outputs = &net.devices[net.index_of(3)].outputs;
    let outcome = if let Some(at) = oracle::first_unbacked(&entry, &valid, outputs, until) {
        ScOutcome::Unsafe(at)
    } else {
        let last_released = valid
            .iter()
            .filter(|packet| packet.value != 0)
            .map(|packet| packet.start)
            .max();
        let zero = outputs
            .iter()
            .rev()
            .find(|&&(at, value)| value == 0 && Some(at) > last_released)
            .map(|&(at, _)| at);
        match (last_released, zero) {
            (Some(from), Some(at)) => ScOutcome::Detected(at.saturating_since(from)),
            _ => ScOutcome::Harmless,
        }
    };
    ScResult {
        class,
        seed,
        injected,
        outcome,
    }
}

/// The totals of a class: injected, detected, harmless, unsafe, the worst latency.
#[derive(Clone, Debug, Default)]
pub struct ScSummary {
    /// Scenarios run.
    pub scenarios: u64,
    /// Frames injected (loss: one fault per scenario).
    pub injected: u64,
    /// Scenarios whose output went to 0 at a timeout.
    pub detected: u64,
    /// Scenarios in which nothing the consumer took changed.
    pub harmless: u64,
    /// Scenarios the oracle judged unsafe (must be 0).
    pub unsafe_: u64,
    /// The worst latency of a detection.
    pub max_latency: Option<Duration>,
}

impl ScSummary {
    /// Adds one result.
    pub fn add(&mut self, result: &ScResult) {
        self.scenarios += 1;
        self.injected += result.injected.max(1) as u64;
        match result.outcome {
            ScOutcome::Detected(latency) => {
                self.detected += 1;
                self.max_latency = Some(self.max_latency.map_or(latency, |m| m.max(latency)));
            }
            ScOutcome::Harmless => self.harmless += 1,
            ScOutcome::Unsafe(_) => self.unsafe_ += 1,
        }
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

/// One line of the console output for `summary` of `class`.
pub fn line(class: ScClass, summary: &ScSummary) -> String {
    format!(
        "campaign {:<22} injected {:>6}  detected {:>6}  harmless {:>6}  unsafe {}  max latency {:>8} µs (bound {} µs)",
        class.name(),
        summary.injected,
        summary.detected,
        summary.harmless,
        summary.unsafe_,
        max_latency(summary),
        u64::from(TIMEOUT_MS) * 1_000
    )
}

/// The SimpleCAN section of the report, markers included.
pub fn section(
    command: &str,
    first_seed: u64,
    scenarios: u64,
    rows: &[(ScClass, ScSummary)],
) -> String {
    let mut text = format!(
        "{SECTION_BEGIN}\n## SimpleCAN\n\n`{command}` ({scenarios} scenarios per class, seeds \
         {first_seed}..{}), on the host SimpleCAN network (`tests/src/campaign/simplecan.rs`): \
         node 1 produces the emergency stop 30h in slot 0, node 3 consumes it with a 50 ms \
         safety timeout; N = 10 slots of 1 ms, 500 kbit/s. In every scenario the producer \
         leaves the bus at a seeded instant; the classes then put 1..6 frames of value 1 into \
         its slot of the following cycles (a corrupted, an old or a masqueraded packet). Judged \
         by `tests/src/campaign/simplecan_oracle.rs`, which decodes the frames and computes \
         the CRC-24 itself (it does not call `shared::simplecan`). Latency: from the start of \
         the last valid packet of 1 to the output's 0; bound: the safety timeout (SC_REQ_20).\n\n\
         | class | scenarios | injected | detected | harmless | unsafe | max latency µs | bound µs |\n\
         |---|---:|---:|---:|---:|---:|---:|---:|\n",
        first_seed + scenarios
    );
    for (class, summary) in rows {
        text.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} |\n",
            class.name(),
            summary.scenarios,
            summary.injected,
            summary.detected,
            summary.harmless,
            summary.unsafe_,
            max_latency(summary),
            u64::from(TIMEOUT_MS) * 1_000
        ));
    }
    text.push_str(
        "\nNot yet campaigned over SimpleCAN: a packet delayed beyond its slot, sync loss, two \
         masters, a master that disappears, a babbling higher-priority identifier, the \
         1000-per-hour leaky counter. Sync loss, two masters, a disappearing master and the \
         leaky counter have their tests (`sc_req_32_…`, `sc_req_26_…`, `sc_req_42_…` in \
         `shared` and `tests/tests/simplecan_network.rs`); a delayed packet and a babbling \
         identifier have none over SimpleCAN yet.\n",
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
