//! The full network run: 64 producers and 64 consumers ([`super::plan`]) at 1 Mbit/s
//! with heartbeats and PDO-like background load, every producer's input changing at seeded
//! random moments; what the bus and the outputs show, measured by a monitor that sees only
//! the frames on the bus and the nodes' outputs.

use super::configure::{node_spec, receive, stored_image, transmit};
use super::engine::{Engine, Observer, Periodic};
use super::plan::{self, BIT_RATE, PRODUCERS, Role, Timing};
use crate::dual::Side;
use dual_channel::runtime::ChannelEvent;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use shared::canopen::nmt::NmtCommand;
use shared::node::Event;
use shared::safety::types::SrdoNumber;
use shared::{CanFrame, Duration, Instant};
use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// What the monitor measured for one SRDO, from the frames on the bus.
#[derive(Clone, Debug, Default)]
pub struct SrdoStats {
    /// The CiA 304 pair (and the producer's node-ID).
    pub pair: u8,
    /// The consumer's node-ID.
    pub consumer: u8,
    /// Valid-looking pairs (a plain frame, then an inverted one).
    pub pairs: u64,
    /// The longest plain-to-inverted gap (µs), against the SRVT.
    pub max_gap_us: u64,
    /// The longest interval between two pairs' inverted frames after the first (µs),
    /// against the SCT.
    pub max_interval_us: u64,
    /// From the NMT start to the first pair's inverted frame (µs), against the SCT.
    pub first_us: u64,
    last_plain: Option<Instant>,
    last_pair: Option<Instant>,
}

/// Min, mean and max of a set of durations (µs).
#[derive(Clone, Copy, Debug, Default)]
pub struct Summary {
    /// How many.
    pub count: u64,
    /// Smallest.
    pub min_us: u64,
    /// Largest.
    pub max_us: u64,
    sum_us: u64,
}

impl Summary {
    /// Adds one.
    pub fn add(&mut self, micros: u64) {
        if self.count == 0 || micros < self.min_us {
            self.min_us = micros;
        }
        self.max_us = self.max_us.max(micros);
        self.sum_us += micros;
        self.count += 1;
    }

    /// The mean (µs), 0 when empty.
    pub fn mean_us(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            self.sum_us as f64 / self.count as f64
        }
    }
}

/// Which kind of traffic a frame is, for the load shares.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Traffic {
    /// SRDO frames (0x101..=0x180).
    Srdo,
    /// Heartbeats and boot-up (0x701..=0x77F).
    Heartbeat,
    /// The PDO-like background.
    Pdo,
    /// Everything else (NMT, SDO, EMCY, GFC).
    Other,
}

impl Traffic {
    /// The kind of `id`.
    pub fn of(id: u16) -> Self {
        match id {
            0x101..=0x180 => Traffic::Srdo,
            0x701..=0x77F => Traffic::Heartbeat,
            id if (plan::PDO_FIRST_ID..plan::PDO_FIRST_ID + plan::PDO_STREAMS).contains(&id) => {
                Traffic::Pdo
            }
            _ => Traffic::Other,
        }
    }
}

/// The monitor: the frames on the bus and the nodes' outputs, nothing else.
pub struct Monitor {
    /// Per SRDO pair 1..=64 (index pair − 1).
    pub srdos: Vec<SrdoStats>,
    /// When the NMT start reached the nodes.
    pub started: Option<Instant>,
    /// Frames and bits delivered since the NMT start, per [`Traffic`] kind.
    pub frames: [u64; 4],
    /// Bits, as [`Monitor::frames`].
    pub bits: [u64; 4],
    /// Bits of every frame delivered since power-on.
    pub bits_total: u64,
    /// Input changes waiting for their consumer's output: per node index, (when, value).
    pending: Vec<Option<(Instant, u64)>>,
    /// Reaction times to the safe value (input 1 → 0) and back (0 → 1).
    pub to_safe: Summary,
    /// See [`Monitor::to_safe`].
    pub to_run: Summary,
    /// Faults and safe states the channels reported (must stay 0 without injected faults).
    pub faults: u64,
    /// The first few of them, described.
    pub fault_lines: Vec<String>,
}

impl Monitor {
    /// A monitor for `roles` (node index = position).
    pub fn new(roles: &[Role]) -> Self {
        let mut srdos: Vec<SrdoStats> = (1..=PRODUCERS)
            .map(|pair| SrdoStats {
                pair,
                ..SrdoStats::default()
            })
            .collect();
        for role in roles {
            if let Some((pair, _)) = role.consumes {
                srdos[usize::from(pair) - 1].consumer = role.id;
            }
        }
        Monitor {
            srdos,
            started: None,
            frames: [0; 4],
            bits: [0; 4],
            bits_total: 0,
            pending: vec![None; roles.len()],
            to_safe: Summary::default(),
            to_run: Summary::default(),
            faults: 0,
            fault_lines: Vec::new(),
        }
    }

    /// The input behind node `consumer`'s output changed to `value` at `at`.
    pub fn input_changed(&mut self, consumer: usize, at: Instant, value: u64) {
        self.pending[consumer] = Some((at, value));
    }

    /// Bits delivered since the NMT start.
    pub fn bits_since_start(&self) -> u64 {
        self.bits.iter().sum()
    }
}

impl Observer for Monitor {
    fn delivered(&mut self, at: Instant, frame: &CanFrame, _from: usize, bits: u32) {
        let bits = u64::from(bits);
        self.bits_total += bits;
        let id = frame.id().raw();
        if id == 0 && frame.data().first() == Some(&0x01) && self.started.is_none() {
            self.started = Some(at);
            for srdo in &mut self.srdos {
                srdo.last_pair = Some(at);
            }
        }
        if self.started.is_none() {
            return;
        }
        let kind = Traffic::of(id);
        self.frames[kind as usize] += 1;
        self.bits[kind as usize] += bits;
        if kind != Traffic::Srdo || frame.is_remote() {
            return;
        }
        // Pair n: plain 0xFF + 2n (odd), inverted 0x100 + 2n (even).
        let pair = usize::from((id - 0xFF) / 2);
        let Some(srdo) = self.srdos.get_mut(pair - 1) else {
            return;
        };
        if id % 2 == 1 {
            srdo.last_plain = Some(at);
        } else if let Some(plain) = srdo.last_plain.take() {
            srdo.max_gap_us = srdo.max_gap_us.max(at.saturating_since(plain).as_micros());
            if let Some(last) = srdo.last_pair {
                let interval = at.saturating_since(last).as_micros();
                if srdo.pairs == 0 {
                    srdo.first_us = interval;
                } else {
                    srdo.max_interval_us = srdo.max_interval_us.max(interval);
                }
            }
            srdo.last_pair = Some(at);
            srdo.pairs += 1;
        }
    }

    fn output(&mut self, at: Instant, node: usize, value: u64) {
        if let Some((since, wanted)) = self.pending[node] {
            if value == wanted {
                let micros = at.saturating_since(since).as_micros();
                if wanted == 0 {
                    self.to_safe.add(micros);
                } else {
                    self.to_run.add(micros);
                }
                self.pending[node] = None;
            }
        }
    }

    fn event(&mut self, at: Instant, node: usize, side: Side, event: &ChannelEvent) {
        let fault = matches!(
            event,
            ChannelEvent::Fault(_)
                | ChannelEvent::Node(Event::SrdoFault(_))
                | ChannelEvent::Node(Event::SafeState(_))
        );
        if fault {
            self.faults += 1;
            if self.fault_lines.len() < 10 {
                self.fault_lines.push(format!(
                    "{:.6} s node index {node} channel {side:?}: {event:?}",
                    at.as_micros() as f64 / 1e6
                ));
            }
        }
    }
}

/// What a full network run measured.
pub struct Report {
    /// The timing the network ran with.
    pub timing: Timing,
    /// Bus time simulated after the NMT start.
    pub bus_time: Duration,
    /// Simulated time in all (boot included).
    pub simulated: Duration,
    /// Wall time of configuring every node (the tool's procedure against each core alone).
    pub configuration_wall: std::time::Duration,
    /// SDO requests the configuration took.
    pub sdo_requests: u64,
    /// Wall time of the simulation (boot and the run).
    pub simulation_wall: std::time::Duration,
    /// CPU time the process got meanwhile, all its threads, where the system says
    /// ([`process_cpu_time`]): on a shared machine the wall time includes waiting for a core.
    pub simulation_cpu: Option<std::time::Duration>,
    /// Threads the network ran on.
    pub threads: usize,
    /// The monitor.
    pub monitor: Monitor,
    /// Bits the bus model counted since power-on, and bits of frames not yet delivered at
    /// the end (arbitrated, still on the bus).
    pub bus_bits: u64,
    /// The bus's frame count.
    pub bus_frames: u64,
    /// The bit rate.
    pub bit_rate: u32,
    /// Every frame delivered, when asked for (tests).
    pub trace: Option<Vec<(Instant, CanFrame, usize)>>,
}

impl Report {
    /// Bus load since the NMT start: bits delivered over bit times elapsed.
    pub fn load(&self) -> f64 {
        self.monitor.bits_since_start() as f64
            / (self.bit_rate as f64 * self.bus_time.as_micros() as f64 / 1e6)
    }

    /// The share of one kind of traffic.
    pub fn share(&self, kind: Traffic) -> f64 {
        self.monitor.bits[kind as usize] as f64
            / (self.bit_rate as f64 * self.bus_time.as_micros() as f64 / 1e6)
    }
}

/// The node specifications (for the tool) of `roles` with `timing`.
pub fn specs(roles: &[Role], timing: &Timing) -> Vec<safety_config::network_file::NodeSpec> {
    roles
        .iter()
        .map(|role| {
            let mut srdos = Vec::new();
            if let Some(pair) = role.produces {
                srdos.push(transmit(1, pair, timing.refresh_ms, timing.srvt_ms));
            }
            if let Some((pair, number)) = role.consumes {
                srdos.push(receive(number, pair, timing.sct_ms, timing.srvt_ms));
            }
            node_spec(role.id, srdos)
        })
        .collect()
}

/// Runs the full network for `bus_time` after the NMT start, inputs changing at moments
/// drawn from `seed`, on `threads` threads (1 or 2; the report is the
/// same either way but for its times); keeps the trace when `keep_trace` (for tests: short
/// runs only).
pub fn run(
    bus_time: Duration,
    seed: u64,
    keep_trace: bool,
    threads: usize,
) -> Result<Report, String> {
    let roles = plan::roles();
    let timing = Timing::derive(PRODUCERS, roles.len() as u32, BIT_RATE);
    let specs = specs(&roles, &timing);
    let configuration = std::time::Instant::now();
    let mut nodes = Vec::new();
    let mut sdo_requests = 0;
    for spec in &specs {
        let (image, requests) =
            stored_image(spec).map_err(|error| format!("configuring node {}: {error}", spec.id))?;
        sdo_requests += requests;
        nodes.push((spec.id, Some(image)));
    }
    let configuration_wall = configuration.elapsed();

    let simulation = std::time::Instant::now();
    let cpu_before = process_cpu_time();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut engine = Engine::new(BIT_RATE, nodes, timing.link_period, Monitor::new(&roles));
    if keep_trace {
        engine.trace = Some(Vec::new());
    }
    engine.set_threads(threads);
    for stream in 0..plan::PDO_STREAMS {
        let first = Instant::from_micros(rng.random_range(0..plan::PDO_PERIOD.as_micros()));
        engine.add_sender(Periodic {
            id: plan::PDO_FIRST_ID + stream,
            len: 8,
            period: plan::PDO_PERIOD,
            first,
        });
    }
    if !engine.wait_for_boot(Duration::from_millis(2000)) {
        return Err("not every node reached Pre-operational within 2 s of power-on".into());
    }
    let producers: Vec<usize> = roles
        .iter()
        .enumerate()
        .filter(|(_, role)| role.produces.is_some())
        .map(|(index, _)| index)
        .collect();
    // The consumer (node index) of each pair.
    let mut consumer_of = vec![0usize; usize::from(PRODUCERS) + 1];
    for (index, role) in roles.iter().enumerate() {
        if let Some((pair, number)) = role.consumes {
            consumer_of[usize::from(pair)] = index;
            engine.watch(
                index,
                SrdoNumber::new(number).expect("the plan numbers receive SRDOs from 1"),
            );
        }
    }
    for &index in &producers {
        engine.set_inputs(index, 1, 1);
    }
    engine.nmt(NmtCommand::Start, 0);
    engine.run_for(Duration::from_millis(1));
    let Some(started) = engine.observer.started else {
        return Err("the NMT start did not reach the bus".into());
    };
    let end = started + bus_time;
    // Input changes: each producer's first one a second after the start (every output has
    // come up by then), then at uniformly drawn intervals.
    let mut changes = BinaryHeap::new();
    let draw = |rng: &mut ChaCha8Rng| {
        Duration::from_micros(
            rng.random_range(plan::INPUT_CHANGE_MS.0 * 1000..=plan::INPUT_CHANGE_MS.1 * 1000),
        )
    };
    for &index in &producers {
        let at = started + Duration::from_millis(1000) + draw(&mut rng);
        changes.push(Reverse((at, index)));
    }
    let mut inputs = vec![1u8; roles.len()];
    while let Some(Reverse((at, index))) = changes.pop() {
        if at > end {
            break;
        }
        engine.run_until(at);
        let value = 1 - inputs[index];
        inputs[index] = value;
        engine.set_inputs(index, value, value);
        let pair = roles[index].produces.expect("a producer");
        engine
            .observer
            .input_changed(consumer_of[usize::from(pair)], at, u64::from(value));
        changes.push(Reverse((at + draw(&mut rng), index)));
    }
    engine.run_until(end);
    let simulation_wall = simulation.elapsed();
    let simulation_cpu = process_cpu_time()
        .zip(cpu_before)
        .map(|(after, before)| after.saturating_sub(before));
    Ok(Report {
        timing,
        bus_time,
        simulated: Duration::from_micros(engine.now.as_micros()),
        configuration_wall,
        sdo_requests,
        simulation_wall,
        simulation_cpu,
        threads,
        bus_bits: engine.bus.bits_sent,
        bus_frames: engine.bus.frames_sent,
        bit_rate: BIT_RATE,
        trace: engine.trace.take(),
        monitor: engine.observer,
    })
}

/// The CPU time this process has run for, all threads, user and system, from Linux's
/// `/proc/self/stat` (fields 14 and 15, in clock ticks of 10 ms: Linux's `USER_HZ` is 100 on
/// every architecture it exposes to user space); `None` where there is no such file.
pub fn process_cpu_time() -> Option<std::time::Duration> {
    let text = std::fs::read_to_string("/proc/self/stat").ok()?;
    // The command name (field 2) is in parentheses and may hold spaces: count after it.
    let mut fields = text.get(text.rfind(')')? + 1..)?.split_whitespace();
    let user: u64 = fields.nth(11)?.parse().ok()?;
    let system: u64 = fields.next()?.parse().ok()?;
    Some(std::time::Duration::from_millis((user + system) * 10))
}
