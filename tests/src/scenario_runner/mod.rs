//! The scenario runner: a scenario file ([`file`](mod@file)) names a network (a network file of the
//! configuration tool), a timeline of stimuli and faults and the outcomes expected, with
//! bounds; [`run`] plays it on the dual-channel host simulation ([`crate::dual`]: both
//! channel runtimes of every node, their link, the simulated bus) and checks each expected
//! outcome, printing the value measured beside its bound. Besides the outcomes the file
//! names, the campaigns' independent oracle ([`crate::campaign::oracle`]) judges every
//! receive SRDO whose producer is in the network: no output may carry data that was not a
//! valid pair from its producer within SCT and SRVT.
//!
//! Time 0 of the timeline is the start: 1 ms after the tool's NMT start of all nodes, which
//! follows the tool's whole configuration procedure (EN 50325-5 8.3.1). The simulation is
//! deterministic: the same file gives the same measurements.

pub mod emulated;
pub mod file;

use crate::bus::{Fault, Match};
use crate::campaign::oracle::{self, MonitoredSrdo};
use crate::dual::{DualNetwork, Side};
use dual_channel::runtime::ChannelEvent;
use file::{Channel, Expectation, FaultSpec, Scenario, Stimulus};
use shared::canopen::nmt;
use shared::node::{Event, SafeStateCause};
use shared::safety::cause::Cause;
use shared::{CanFrame, CanId, Duration, Instant};
use std::collections::{BTreeMap, HashSet};
use std::fmt::Write as _;

/// How much of the timeline before a failed expectation's reference is printed.
const BEFORE: Duration = Duration::from_millis(30);
/// How much after its bound.
const AFTER: Duration = Duration::from_millis(10);
/// How much of the emulated network's timeline before a failed expectation's reference is
/// printed, in seconds: more than on the host, as the channels report their status every
/// 250 ms when nothing changes.
const BEFORE_EMULATED: f64 = 0.300;

/// Where a scenario was played.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Played {
    /// On the dual-channel host simulation ([`run`]).
    Host,
    /// On the emulated network: the shipped images on the emulated STM32F405s ([`emulated`]).
    Emulated,
}

/// One checked outcome.
#[derive(Clone, Debug)]
pub struct Check {
    /// The scenario file's line of the expectation (0 for the oracle's checks).
    pub line: usize,
    /// What was expected, with its bound.
    pub expected: String,
    /// What was measured.
    pub measured: String,
    /// Whether it held.
    pub passed: bool,
    /// The span of the timeline that shows it (of the emulated network: on the hub's clock).
    pub window: (Instant, Instant),
}

/// What a run found.
#[derive(Clone, Debug)]
pub struct Report {
    /// Every check, in file order, then the oracle's.
    pub checks: Vec<Check>,
    /// The timeline around the first failed check.
    pub timeline: Option<String>,
    /// Where it was played.
    pub played: Played,
}

impl Report {
    /// `true` when every check held.
    pub fn passed(&self) -> bool {
        self.checks.iter().all(|check| check.passed)
    }

    /// The report as printed: one line per check, then the timeline of a failure.
    pub fn text(&self, scenario: &Scenario) -> String {
        let mut text = format!(
            "scenario {} — {} ({}; {} kbit/s; {})\n",
            scenario.path.display(),
            scenario.name,
            scenario.covers,
            scenario.bit_rate / 1000,
            match (self.played, scenario.hub_only()) {
                (Played::Emulated, _) => "on the emulated network",
                (Played::Host, true) => "faults the hub can inject too",
                (Played::Host, false) => "host-only faults",
            }
        );
        for check in &self.checks {
            let place = if check.line == 0 {
                "oracle ".to_string()
            } else {
                format!("line {:<3}", check.line)
            };
            let _ = writeln!(
                text,
                "  {} {place} {}: {}",
                if check.passed { "PASS" } else { "FAIL" },
                check.expected,
                check.measured
            );
        }
        if let Some(timeline) = &self.timeline {
            let _ = writeln!(text, "  timeline around the first failure:");
            for line in timeline.lines() {
                let _ = writeln!(text, "    {line}");
            }
        }
        text
    }
}

fn side(channel: Channel) -> Side {
    match channel {
        Channel::A => Side::A,
        Channel::B => Side::B,
    }
}

fn ms(duration: Duration) -> String {
    format!("{:.3} ms", duration.as_micros() as f64 / 1000.0)
}

fn at(start: Instant, us: u64) -> Instant {
    start + Duration::from_micros(us)
}

/// The bus participant of node `id`'s channel `side` (see [`DualNetwork`]); the file was
/// checked to name only nodes of its network.
fn participant(net: &DualNetwork, id: u8, side: Side) -> usize {
    let index = net
        .nodes
        .iter()
        .position(|node| node.id == id)
        .unwrap_or_default();
    1 + 2 * index + side as usize
}

/// The cause of a safe state a channel event reports, if it reports one.
pub fn cause_of(event: &ChannelEvent) -> Option<Cause> {
    match event {
        ChannelEvent::Fault(fault) => Some(fault.cause()),
        ChannelEvent::Node(Event::SrdoFault(fault)) => Some(fault.cause.cause()),
        ChannelEvent::Node(Event::SafeState(cause)) => match cause {
            SafeStateCause::Srdo(fault) => Some(fault.cause.cause()),
            SafeStateCause::Gfc => Some(Cause::Gfc),
            SafeStateCause::Application { detail } => Cause::from_code(*detail),
            SafeStateCause::Integrity(fault) => Cause::from_code(fault.emergency_detail()[1]),
            SafeStateCause::Protocol { cause, .. } => Cause::from_code(*cause),
        },
        ChannelEvent::Node(Event::GfcReceived) => Some(Cause::Gfc),
        _ => None,
    }
}

/// A frame from a description the file was checked for.
fn frame(id: u16, data: &[u8]) -> Result<CanFrame, String> {
    let id = CanId::new(id).map_err(|_| format!("identifier {id:#x} is not an 11-bit one"))?;
    CanFrame::new(id, data).map_err(|_| format!("{} data bytes do not fit a frame", data.len()))
}

/// Applies one stimulus now.
fn apply(
    net: &mut DualNetwork,
    scenario: &Scenario,
    stimulus: &Stimulus,
    stuck: &mut HashSet<(u8, usize)>,
) -> Result<(), String> {
    let now = net.now;
    let every = |id: Option<u16>, from: Option<usize>| Match {
        id,
        from,
        after: now,
        count: None,
    };
    match stimulus {
        Stimulus::Input {
            node,
            channel,
            value,
        } => {
            let sides = match channel {
                Some(channel) => vec![side(*channel)],
                None => vec![Side::A, Side::B],
            };
            for side in sides {
                if !stuck.contains(&(*node, side as usize)) {
                    net.set_input(*node, side, *value);
                }
            }
        }
        Stimulus::Nmt { command, node } => net.send_foreign(nmt::command_frame(*command, *node)),
        Stimulus::Gfc => net.send_foreign(frame(0x001, &[])?),
        Stimulus::Fault(fault) => match fault {
            FaultSpec::Drop { id, count, all } => {
                let count = if *all { None } else { Some(count.unwrap_or(1)) };
                net.inject(
                    Match {
                        count,
                        ..every(Some(*id), None)
                    },
                    Fault::Drop,
                );
            }
            FaultSpec::Corrupt { id, byte, mask } => net.inject(
                Match::next_with_id(*id, now),
                Fault::Corrupt {
                    byte: *byte,
                    mask: *mask,
                },
            ),
            FaultSpec::Delay { id, by_us } => net.inject(
                Match::next_with_id(*id, now),
                Fault::Delay(Duration::from_micros(*by_us)),
            ),
            FaultSpec::Repeat { id } => net.inject(Match::next_with_id(*id, now), Fault::Repeat),
            FaultSpec::Reorder { id } => net.inject(Match::next_with_id(*id, now), Fault::Reorder),
            FaultSpec::Insert { id, data } => net.send_foreign(frame(*id, data)?),
            FaultSpec::Mute { node, channel } => {
                let from = participant(net, *node, side(*channel));
                net.inject(Match::all_from(from, now), Fault::Mute);
            }
            FaultSpec::Cut { node } => net.node_mut(*node).link_faults.cut = true,
            FaultSpec::Clear => net.bus.clear_faults(),
            FaultSpec::LinkCorrupt { node, mask } => {
                net.node_mut(*node).link_faults.corrupt_next_a_to_b = Some(*mask);
            }
            FaultSpec::LinkLatency { node, us } => {
                net.node_mut(*node).link_faults.latency = Duration::from_micros(*us);
            }
            FaultSpec::Clock {
                node,
                channel,
                percent,
            } => {
                net.node_mut(*node).clocks[side(*channel) as usize].set_rate(now, percent * 10_000)
            }
            FaultSpec::RecordFlip {
                node,
                channel,
                srdo,
                bit,
            } => {
                let index = usize::from(srdo.saturating_sub(1));
                let dual = net.node_mut(*node);
                match side(*channel) {
                    Side::A => dual.a.node_mut().inject_record_flip(index, *bit),
                    Side::B => dual.b.node_mut().inject_record_flip(index, *bit),
                }
            }
            FaultSpec::IdentifierTableFlip {
                node,
                channel,
                byte,
                bit,
            } => {
                let dual = net.node_mut(*node);
                match side(*channel) {
                    Side::A => dual.a.node_mut().inject_identifier_table_flip(*byte, *bit),
                    Side::B => dual.b.node_mut().inject_identifier_table_flip(*byte, *bit),
                }
            }
            FaultSpec::StuckInput { node, channel } => {
                stuck.insert((*node, side(*channel) as usize));
            }
            FaultSpec::Babbling {
                node,
                channel,
                id,
                frames,
            } => {
                let from = participant(net, *node, side(*channel));
                let babble = frame(*id, &[0xFF; 8])?;
                for _ in 0..*frames {
                    net.bus.send(from, babble);
                }
            }
            FaultSpec::BusOff { node, channel } => net.bus_off(*node, side(*channel)),
            FaultSpec::NoInverted { node } => {
                let from = participant(net, *node, Side::B);
                let spec = scenario.network.nodes.iter().find(|spec| spec.id == *node);
                for srdo in spec.iter().flat_map(|spec| &spec.srdos) {
                    if srdo.settings.direction == 1 {
                        let inverted = (srdo.settings.cob_id_2 & 0x7FF) as u16;
                        net.inject(every(Some(inverted), Some(from)), Fault::Drop);
                    }
                }
            }
        },
    }
    Ok(())
}

/// The first safety event of node `id` at or after `from`: (when, its cause if it names one).
fn first_safety_event(
    net: &DualNetwork,
    id: u8,
    from: Instant,
) -> Option<(Instant, Option<Cause>)> {
    net.log
        .iter()
        .filter(|(when, node, ..)| *when >= from && *node == id)
        .find_map(|(when, _, _, event)| {
            let safety = matches!(
                event,
                ChannelEvent::Fault(_)
                    | ChannelEvent::Node(
                        Event::SrdoFault(_) | Event::SafeState(_) | Event::GfcReceived
                    )
            );
            safety.then(|| (*when, cause_of(event)))
        })
}

/// When every output of node `id` (each receive SRDO, both channels) is 0 at or after
/// `from`.
fn outputs_zero_since(net: &DualNetwork, id: u8, from: Instant) -> Option<Instant> {
    let mut values: BTreeMap<(usize, u8), u64> = BTreeMap::new();
    let zero = |values: &BTreeMap<(usize, u8), u64>| values.values().all(|value| *value == 0);
    for (when, node, side, srdo, value) in &net.outputs {
        if *node != id {
            continue;
        }
        if *when > from && zero(&values) {
            return Some(from);
        }
        values.insert((*side as usize, *srdo), *value);
        if *when >= from && zero(&values) {
            return Some(*when);
        }
    }
    zero(&values).then_some(from)
}

/// The effective output of node `id`'s lowest receive SRDO at `when` (channels in series).
fn output_at(net: &DualNetwork, id: u8, when: Instant) -> u64 {
    let lowest = net
        .outputs
        .iter()
        .filter(|(_, node, ..)| *node == id)
        .map(|(_, _, _, srdo, _)| *srdo)
        .min();
    let mut values = [0u64; 2];
    for (changed, node, side, srdo, value) in &net.outputs {
        if *changed <= when && *node == id && Some(*srdo) == lowest {
            values[*side as usize] = *value;
        }
    }
    values[0] & values[1]
}

/// The receive SRDOs whose producer is in the network, as the oracle watches them:
/// (consumer, SRDO number, what to watch); `participant` gives the bus participant of a
/// node's channel (the host simulation's numbers, or the emulated network's names as the
/// recorded log numbers them).
fn monitored(
    scenario: &Scenario,
    mut participant: impl FnMut(u8, Side) -> usize,
) -> Vec<(u8, u8, MonitoredSrdo)> {
    let mut watched = Vec::new();
    for consumer in &scenario.network.nodes {
        for srdo in consumer.srdos.iter().filter(|s| s.settings.direction == 2) {
            let ids = (srdo.settings.cob_id_1, srdo.settings.cob_id_2);
            let producer = scenario.network.nodes.iter().find(|node| {
                node.srdos.iter().any(|s| {
                    s.settings.direction == 1 && (s.settings.cob_id_1, s.settings.cob_id_2) == ids
                })
            });
            let Some(producer) = producer else { continue };
            // Plain and inverted entries alternate; the plain ones give the mapped length.
            let bits: u32 = srdo
                .settings
                .mapping
                .iter()
                .step_by(2)
                .map(|entry| entry & 0xFF)
                .sum();
            watched.push((
                consumer.id,
                srdo.number,
                MonitoredSrdo {
                    consumer: consumer.id,
                    plain_id: (ids.0 & 0x7FF) as u16,
                    inverted_id: (ids.1 & 0x7FF) as u16,
                    len: bits.div_ceil(8) as usize,
                    sct: Duration::from_millis(u64::from(srdo.settings.cycle_time)),
                    srvt: Duration::from_millis(u64::from(srdo.settings.srvt)),
                    producer: [
                        participant(producer.id, Side::A),
                        participant(producer.id, Side::B),
                    ],
                },
            ));
        }
    }
    watched
}

/// Every `*.toml` file directly in `dir`, sorted by name (the networks they use live in a
/// subdirectory).
pub fn files_in(dir: &std::path::Path) -> Result<Vec<std::path::PathBuf>, String> {
    let entries = std::fs::read_dir(dir).map_err(|error| {
        format!(
            "the scenarios in {} cannot be listed: {error}",
            dir.display()
        )
    })?;
    let mut files: Vec<std::path::PathBuf> = entries
        .filter_map(|entry| entry.ok().map(|entry| entry.path()))
        .filter(|path| path.is_file() && path.extension().is_some_and(|ext| ext == "toml"))
        .collect();
    files.sort();
    Ok(files)
}

/// Plays `scenario` on the host simulation and checks its expectations; an error is a
/// sentence saying why it could not be played (the network's configuration failed).
pub fn run(scenario: &Scenario) -> Result<Report, String> {
    let ids: Vec<u8> = scenario.network.nodes.iter().map(|node| node.id).collect();
    let mut net = DualNetwork::new(scenario.bit_rate, &ids);
    net.configure_and_start_with(&scenario.network)
        .map_err(|error| {
            format!(
                "{}: the tool could not configure the network of {}: {error}",
                scenario.path.display(),
                scenario.network_path.display()
            )
        })?;
    let start = net.now;
    let mut stuck = HashSet::new();
    for step in &scenario.steps {
        net.run_until(at(start, step.at_us));
        apply(&mut net, scenario, &step.stimulus, &mut stuck)
            .map_err(|why| format!("{}:{}: {why}", scenario.path.display(), step.line))?;
    }
    let end = at(start, scenario.run_us);
    net.run_until(end);
    let mut checks: Vec<Check> = scenario
        .expects
        .iter()
        .map(|expect| check(&net, start, end, expect))
        .collect();
    for (consumer, number, watched) in monitored(scenario, |id, side| participant(&net, id, side)) {
        let outputs: Vec<(Instant, usize, u64)> = net
            .outputs
            .iter()
            .filter(|(_, node, _, srdo, _)| *node == consumer && *srdo == number)
            .map(|(when, _, side, _, value)| (*when, *side as usize, *value))
            .collect();
        let judgement = oracle::judge(watched, &net.trace, &outputs, end);
        checks.push(oracle_check(consumer, number, &judgement, start, end));
    }
    let timeline = checks.iter().find(|check| !check.passed).map(|check| {
        let (from, to) = check.window;
        crate::campaign::timeline(&net, from, to.min(end), &check.expected)
    });
    Ok(Report {
        checks,
        timeline,
        played: Played::Host,
    })
}

/// The oracle's verdict on receive SRDO `number` of node `consumer` as a check: PASS when
/// no output was unjustified, else the number of unjustified outputs, the first one's time
/// from `start` and why; its window is around the first (or the whole run to `end`).
fn oracle_check(
    consumer: u8,
    number: u8,
    judgement: &oracle::Judgement,
    start: Instant,
    end: Instant,
) -> Check {
    let first = judgement.violations.first();
    Check {
        line: 0,
        expected: format!(
            "node {consumer} SRDO {number} carries only data of valid pairs from its producer within SCT and SRVT"
        ),
        measured: match first {
            None => "no output unjustified".to_string(),
            Some(violation) => format!(
                "{} unjustified output(s), the first at {}: {}",
                judgement.violations.len(),
                ms_signed(violation.at, start),
                violation.why
            ),
        },
        passed: first.is_none(),
        window: first.map_or((start, end), |violation| {
            (earlier(violation.at, BEFORE), violation.at + AFTER)
        }),
    }
}

/// `at` from `start` in milliseconds, negative before it (the emulated runs judge the reset
/// before a scenario's time 0 too).
fn ms_signed(at: Instant, start: Instant) -> String {
    if at >= start {
        ms(at.saturating_since(start))
    } else {
        format!("-{}", ms(start.saturating_since(at)))
    }
}

/// `duration` before `instant`, or time 0.
fn earlier(instant: Instant, duration: Duration) -> Instant {
    Instant::from_micros(instant.as_micros().saturating_sub(duration.as_micros()))
}

fn check(net: &DualNetwork, start: Instant, end: Instant, expect: &file::Expect) -> Check {
    let window = |from: Instant, bound: u64| (earlier(from, BEFORE), at(from, bound) + AFTER);
    let t = |us: u64| format!("t = {}", ms(Duration::from_micros(us)));
    let (expected, measured, passed, span) = match &expect.expectation {
        Expectation::Safe {
            node,
            after_us,
            within_us,
            cause,
        } => {
            let reference = at(start, *after_us);
            let event = first_safety_event(net, *node, reference);
            let safe = event.and_then(|(when, _)| outputs_zero_since(net, *node, when));
            let latency = safe.map(|safe| safe.saturating_since(reference));
            let in_time = latency.is_some_and(|latency| latency.as_micros() <= *within_us);
            let found = event.and_then(|(_, cause)| cause);
            let right_cause = cause.is_none_or(|cause| found == Some(cause));
            let expected = format!(
                "node {node} safe within {} of {}{}",
                ms(Duration::from_micros(*within_us)),
                t(*after_us),
                cause.map_or(String::new(), |cause| format!(", cause {cause}"))
            );
            let measured = match latency {
                None => "never safe".to_string(),
                Some(latency) => format!(
                    "safe after {}, cause {}",
                    ms(latency),
                    found.map_or("not named".to_string(), |cause| cause.to_string())
                ),
            };
            // From before the reference to after the bound, or to after the safe state when
            // it came later.
            let (from, bound_end) = window(reference, *within_us);
            let to = safe.map_or(bound_end, |safe| bound_end.max(safe + AFTER));
            (expected, measured, in_time && right_cause, (from, to))
        }
        Expectation::Output { node, at_us, value } => {
            let measured = output_at(net, *node, at(start, *at_us));
            (
                format!("node {node}'s output {value:#04x} at {}", t(*at_us)),
                format!("{measured:#04x}"),
                measured == *value,
                window(at(start, *at_us), 0),
            )
        }
        Expectation::Working { node, until_us } => {
            let until = at(start, *until_us);
            let event = first_safety_event(net, *node, start).filter(|(when, _)| *when <= until);
            (
                format!("node {node} working from the start to {}", t(*until_us)),
                match event {
                    None => "no safety event".to_string(),
                    Some((when, cause)) => format!(
                        "safety event at {} ({})",
                        t(when.saturating_since(start).as_micros()),
                        cause.map_or("no cause named".to_string(), |cause| cause.to_string())
                    ),
                },
                event.is_none(),
                event.map_or((start, until.min(end)), |(when, _)| window(when, 0)),
            )
        }
        Expectation::NoEmcy {
            node,
            from_us,
            until_us,
        } => {
            let (from, until) = (at(start, *from_us), at(start, *until_us));
            let emcy: Vec<&(Instant, CanFrame, usize)> = net
                .trace
                .iter()
                .filter(|(when, frame, _)| {
                    *when >= from && *when <= until && frame.id().raw() == 0x080 + u16::from(*node)
                })
                .collect();
            (
                format!(
                    "no EMCY from node {node} from {} to {}",
                    t(*from_us),
                    t(*until_us)
                ),
                match emcy.first() {
                    None => "none".to_string(),
                    Some((when, frame, _)) => format!(
                        "{} EMCY, the first at {}: {:02X?}",
                        emcy.len(),
                        t(when.saturating_since(start).as_micros()),
                        frame.data()
                    ),
                },
                emcy.is_empty(),
                emcy.first()
                    .map_or((from, until.min(end)), |(when, ..)| window(*when, 0)),
            )
        }
        Expectation::Emcy {
            node,
            code,
            after_us,
            within_us,
        } => {
            let reference = at(start, *after_us);
            let seen = net.trace.iter().find(|(when, frame, _)| {
                *when >= reference
                    && frame.id().raw() == 0x080 + u16::from(*node)
                    && frame.data().get(..2) == Some(&code.to_le_bytes()[..])
            });
            let latency = seen.map(|(when, ..)| when.saturating_since(reference));
            (
                format!(
                    "EMCY {code:04X}h from node {node} within {} of {}",
                    ms(Duration::from_micros(*within_us)),
                    t(*after_us)
                ),
                latency.map_or("none".to_string(), |latency| {
                    format!("after {}", ms(latency))
                }),
                latency.is_some_and(|latency| latency.as_micros() <= *within_us),
                window(reference, *within_us),
            )
        }
    };
    Check {
        line: expect.line,
        expected,
        measured,
        passed,
        window: span,
    }
}
