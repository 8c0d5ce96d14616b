//! The scenario runner's half for the emulated network (`cargo xtask scenario --emulated`,
//! and every `cargo xtask test`): the expectations judged from what the emulated network
//! observed ([`judge`]): each channel's status and the bus frames, on the network's virtual
//! time. The shipped images play the files on the emulated STM32F405s
//! (`emulator::scenario`, which applies each step at its instant and reads a channel's status
//! from its output pin and its node's EMCY frames, as a rig around real boards would); until
//! 2026-12-07 xtask played them on the QEMU images under the hub. Each step is written as
//! the hub's control commands ([`commands`], `hub/src/control.rs`), which say whether the
//! emulated network can play it and how the run prints it. Beside the file's bounds, the
//! campaigns' oracle ([`crate::campaign::oracle`], which does not reuse the implementation)
//! judges every run from each frame with its sender and each output change (in the hub's
//! event vocabulary, `can_hub::events`; [`crate::campaign::recorded`] turns them into the
//! oracle's input): an output not justified by a valid pair from node 1 within SCT and SRVT
//! fails the run, with the instant and why. Everything here is sans-I/O, so it is tested on
//! recorded observations.
//!
//! **What the QEMU images' reports could show.** A channel reported its status at once when
//! its NMT state, working state, link, input, output or cause changed, and periodically
//! otherwise; the hub stamped each report with its time of arrival. So a measured latency
//! included the report's way over the emulated serial line (the e2e tests' `MARGIN_MS`
//! covered that), and an output was "safe" from the report that said so. A step was applied
//! once the player saw the hub's clock at or past its time (from the frames on the bus, a few
//! tens of milliseconds apart, and the reports), so a little late; every time the file gives
//! after a step is measured from when the step was applied ([`Observed::time_of`]), so a late
//! step moves its expectations with it, and the run prints when each step was applied. A
//! scenario for the emulated network names the network `cargo xtask run` configures
//! (`scenarios/networks/emulated.toml`, checked against xtask's own), at its bit rate, and
//! only faults of the hub's vocabulary; anything else is refused before the network is
//! touched.

use super::{BEFORE_EMULATED, Check, Played, Report, ms};
use crate::campaign::oracle::Judgement;
use crate::campaign::recorded::{EMULATED_ALLOWANCE, Recorded};
use crate::dual::Side;
use crate::scenario_runner::file::{Channel, Expectation, FaultSpec, Scenario, Step, Stimulus};
use can_hub::control::Command;
use can_hub::events::Event;
use emulation_wire::Status;
use shared::canopen::nmt;
use shared::safety::cause::Cause;
use shared::{CanFrame, Duration};
use std::fmt::Write as _;

/// How much of the timeline after a failed expectation's bound is printed.
const AFTER: f64 = 0.100;

/// The participant name of node `node`'s channel (`node1a`, `node33b`: the names the
/// emulated network gives its MCUs, `xtask/src/network.rs`).
pub fn participant(node: u8, channel: Channel) -> String {
    match channel {
        Channel::A => format!("node{node}a"),
        Channel::B => format!("node{node}b"),
    }
}

/// The hub's control commands that apply `stimulus`, in order; an error is a sentence for
/// a stimulus the hub cannot apply. An NMT command or a GFC is a frame the hub puts on the
/// bus itself (`insert`), as the tool would send it: the hub's answer then gives the time
/// the frame was queued, on the hub's clock.
pub fn commands(stimulus: &Stimulus) -> Result<Vec<Command>, String> {
    let frame = |frame: CanFrame| Command::Insert {
        id: frame.id().raw(),
        data: frame.data().to_vec(),
    };
    Ok(match stimulus {
        Stimulus::Input {
            node,
            channel,
            value,
        } => {
            let channels = match channel {
                Some(channel) => vec![*channel],
                None => vec![Channel::A, Channel::B],
            };
            channels
                .into_iter()
                .map(|channel| Command::Input {
                    name: participant(*node, channel),
                    value: *value,
                })
                .collect()
        }
        Stimulus::Nmt { command, node } => vec![frame(nmt::command_frame(*command, *node))],
        Stimulus::Gfc => vec![Command::Insert {
            id: 0x001,
            data: Vec::new(),
        }],
        Stimulus::Fault(fault) => {
            if !fault.hub_can() {
                return Err(format!(
                    "the fault `{}` as written here is one the hub cannot inject (its control \
                     port drops one frame at a time, delays by whole milliseconds, and has \
                     none of the host-only faults)",
                    fault.kind()
                ));
            }
            vec![match fault {
                FaultSpec::Drop { id, .. } => Command::Drop(*id),
                FaultSpec::Corrupt { id, byte, mask } => Command::Corrupt {
                    id: *id,
                    byte: *byte,
                    mask: *mask,
                },
                FaultSpec::Delay { id, by_us } => Command::Delay {
                    id: *id,
                    ms: by_us / 1000,
                },
                FaultSpec::Repeat { id } => Command::Repeat(*id),
                FaultSpec::Reorder { id } => Command::Reorder(*id),
                FaultSpec::Insert { id, data } => Command::Insert {
                    id: *id,
                    data: data.clone(),
                },
                FaultSpec::Mute { node, channel } => {
                    Command::Mute(participant(*node, *channel), true)
                }
                FaultSpec::Cut { node } => Command::Cut(format!("node{node}-link")),
                FaultSpec::Clear => Command::Clear,
                other => return Err(format!("the fault `{}` is not the hub's", other.kind())),
            }]
        }
    })
}

/// Refuses, in a sentence, a scenario the emulated network cannot play: another network
/// than `emulated` (the one xtask configures), another bit rate than `bit_rate`, or a
/// fault the hub cannot inject (named with its line).
pub fn check_playable(
    scenario: &Scenario,
    emulated: &safety_config::network_file::Network,
    bit_rate: u32,
) -> Result<(), String> {
    let path = scenario.path.display();
    if &scenario.network != emulated {
        return Err(format!(
            "{path}: its network {} is not the emulated network's (the network file xtask \
             configures: scenarios/networks/emulated.toml)",
            scenario.network_path.display()
        ));
    }
    if scenario.bit_rate != bit_rate {
        return Err(format!(
            "{path}: it runs at {} kbit/s, the emulated bus at {} kbit/s",
            scenario.bit_rate / 1000,
            bit_rate / 1000
        ));
    }
    for step in &scenario.steps {
        commands(&step.stimulus).map_err(|why| format!("{path}:{}: {why}", step.line))?;
    }
    Ok(())
}

/// What the emulated network observed while a scenario played, every time in seconds on its
/// virtual clock (the hub's, on the QEMU images).
#[derive(Clone, Debug, Default)]
pub struct Observed {
    /// Time 0 of the timeline.
    pub start: f64,
    /// When each step took effect (when the emulator applied it; on the QEMU images the hub's
    /// answer to its last command), in step order.
    pub applied: Vec<f64>,
    /// Every status report: (participant, time, status).
    pub statuses: Vec<(String, f64, Status)>,
    /// Every frame on the bus with the time it completed.
    pub frames: Vec<(f64, CanFrame)>,
    /// The end of the run.
    pub end: f64,
    /// The events of the network the scenario played on, in the hub's vocabulary
    /// (`can_hub::events`), from the network's start to [`Observed::end`]: the oracle's input.
    pub events: Vec<Event>,
    /// From when the oracle's findings count, on the network's clock: the end of the scenario
    /// played before on the same network (so the reset between them is judged with this
    /// one), 0 for the first.
    pub judged_from: f64,
}

impl Observed {
    /// The hub time of timeline time `us`: from the latest step at or before it, when that
    /// step was applied (a little after its time; every time after it moves with it), else
    /// from the start.
    pub fn time_of(&self, scenario: &Scenario, us: u64) -> f64 {
        scenario
            .steps
            .iter()
            .zip(&self.applied)
            .rev()
            .find(|(step, _)| step.at_us <= us)
            .map_or(self.start + us as f64 / 1e6, |(step, applied)| {
                applied + (us - step.at_us) as f64 / 1e6
            })
    }

    /// Node `node`'s two channels' latest statuses at `t` (`None` for one not heard yet).
    fn at(&self, node: u8, t: f64) -> [Option<&Status>; 2] {
        [Channel::A, Channel::B].map(|channel| {
            let name = participant(node, channel);
            self.statuses
                .iter()
                .filter(|(who, when, _)| *who == name && *when <= t)
                .map(|(_, _, status)| status)
                .next_back()
        })
    }

    /// The times of node `node`'s reports from `from` on.
    fn reports(&self, node: u8, from: f64) -> impl Iterator<Item = (f64, Channel, &Status)> {
        let names = [Channel::A, Channel::B].map(|channel| (participant(node, channel), channel));
        self.statuses.iter().filter_map(move |(who, when, status)| {
            let (_, channel) = names.iter().find(|(name, _)| name == who)?;
            (*when >= from).then_some((*when, *channel, status))
        })
    }
}

/// Both channels of a node report the safe state: not working, outputs at 0.
fn safe(statuses: [Option<&Status>; 2]) -> bool {
    statuses
        .iter()
        .all(|status| status.is_some_and(|status| !status.working && status.output == 0))
}

/// The cause of node `node`'s first safe state from `from`: the first report of a channel
/// leaving the working state that names its own finding, not "other channel safe" (40h),
/// which only says the other channel was first; 40h when neither names another.
fn first_cause(observed: &Observed, node: u8, from: f64) -> Option<u8> {
    let mut told = None;
    for (_, _, status) in observed.reports(node, from) {
        if status.working {
            continue;
        }
        if status.cause != Cause::PeerSafeState.code() {
            return Some(status.cause);
        }
        told = Some(status.cause);
    }
    told
}

fn cause_name(code: u8) -> String {
    Cause::from_code(code).map_or(format!("{code:02X}h"), |cause| cause.to_string())
}

/// Judges `scenario`'s expectations from what the network observed, in the host runs' words
/// (PASS or FAIL, what was expected with its bound, the value measured), with the timeline
/// of reports and frames around the first failure.
pub fn judge(scenario: &Scenario, observed: &Observed) -> Report {
    let t = |us: u64| format!("t = {}", ms(Duration::from_micros(us)));
    let latency = |seconds: f64| ms(Duration::from_micros((seconds * 1e6).round() as u64));
    let window = |from: f64, bound_s: f64| (from - BEFORE_EMULATED, from + bound_s + AFTER);
    let mut checks = Vec::new();
    let mut windows = Vec::new();
    for expect in &scenario.expects {
        let (expected, measured, passed, span) = match &expect.expectation {
            Expectation::Safe {
                node,
                after_us,
                within_us,
                cause,
            } => {
                let reference = observed.time_of(scenario, *after_us);
                let already = safe(observed.at(*node, reference));
                let reached = observed
                    .reports(*node, reference)
                    .map(|(when, ..)| when)
                    .find(|when| safe(observed.at(*node, *when)));
                let found = first_cause(observed, *node, reference);
                let in_time =
                    reached.is_some_and(|when| (when - reference) * 1e6 <= *within_us as f64);
                let right_cause =
                    cause.is_none_or(|cause| found.is_some_and(|code| code == cause.code()));
                let expected = format!(
                    "node {node} safe within {} of {}{}",
                    ms(Duration::from_micros(*within_us)),
                    t(*after_us),
                    cause.map_or(String::new(), |cause| format!(", cause {cause}"))
                );
                let measured = match (already, reached) {
                    (true, _) => "safe already before".to_string(),
                    (false, None) => "never safe".to_string(),
                    (false, Some(when)) => format!(
                        "safe after {}, cause {}",
                        latency(when - reference),
                        found.map_or("not named".to_string(), cause_name)
                    ),
                };
                let (from, to) = window(reference, *within_us as f64 / 1e6);
                let to = reached.map_or(to, |when| to.max(when + AFTER));
                (
                    expected,
                    measured,
                    !already && in_time && right_cause,
                    (from, to),
                )
            }
            Expectation::Output { node, at_us, value } => {
                let when = observed.time_of(scenario, *at_us);
                let [a, b] = observed.at(*node, when);
                let measured = a.zip(b).map(|(a, b)| a.output & b.output);
                (
                    format!("node {node}'s output {value:#04x} at {}", t(*at_us)),
                    measured.map_or("no report from both channels".to_string(), |output| {
                        format!("{output:#04x}")
                    }),
                    measured.is_some_and(|output| u64::from(output) == *value),
                    window(when, 0.0),
                )
            }
            Expectation::Working { node, until_us } => {
                let until = observed.time_of(scenario, *until_us);
                let left = observed
                    .reports(*node, observed.start)
                    .find(|(when, _, status)| *when <= until && !status.working);
                (
                    format!("node {node} working from the start to {}", t(*until_us)),
                    match left {
                        None => "no safety event".to_string(),
                        Some((when, channel, status)) => format!(
                            "channel {channel:?} left the working state at {} ({})",
                            latency(when - observed.start),
                            cause_name(status.cause)
                        ),
                    },
                    left.is_none(),
                    left.map_or((observed.start, until.min(observed.end)), |(when, ..)| {
                        window(when, 0.0)
                    }),
                )
            }
            Expectation::NoEmcy {
                node,
                from_us,
                until_us,
            } => {
                let (from, until) = (
                    observed.time_of(scenario, *from_us),
                    observed.time_of(scenario, *until_us),
                );
                let emcy: Vec<&(f64, CanFrame)> = observed
                    .frames
                    .iter()
                    .filter(|(when, frame)| {
                        *when >= from
                            && *when <= until
                            && frame.id().raw() == 0x080 + u16::from(*node)
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
                        Some((when, frame)) => format!(
                            "{} EMCY, the first at {}: {:02X?}",
                            emcy.len(),
                            latency(when - observed.start),
                            frame.data()
                        ),
                    },
                    emcy.is_empty(),
                    emcy.first()
                        .map_or((from, until.min(observed.end)), |(when, _)| {
                            window(*when, 0.0)
                        }),
                )
            }
            Expectation::Emcy {
                node,
                code,
                after_us,
                within_us,
            } => {
                let reference = observed.time_of(scenario, *after_us);
                let seen = observed.frames.iter().find(|(when, frame)| {
                    *when >= reference
                        && frame.id().raw() == 0x080 + u16::from(*node)
                        && frame.data().get(..2) == Some(&code.to_le_bytes()[..])
                });
                let after = seen.map(|(when, _)| when - reference);
                (
                    format!(
                        "EMCY {code:04X}h from node {node} within {} of {}",
                        ms(Duration::from_micros(*within_us)),
                        t(*after_us)
                    ),
                    after.map_or("none".to_string(), |after| {
                        format!("after {}", latency(after))
                    }),
                    after.is_some_and(|after| after * 1e6 <= *within_us as f64),
                    window(reference, *within_us as f64 / 1e6),
                )
            }
        };
        checks.push(Check {
            line: expect.line,
            expected,
            measured,
            passed,
            window: (
                shared::Instant::from_micros(0),
                shared::Instant::from_micros(0),
            ),
        });
        windows.push(span);
    }
    for (check, window) in oracle_checks(scenario, observed) {
        checks.push(check);
        windows.push(window);
    }
    let timeline = checks
        .iter()
        .zip(&windows)
        .find(|(check, _)| !check.passed)
        .map(|(check, (from, to))| {
            timeline(
                scenario,
                observed,
                *from,
                to.min(observed.end),
                &check.expected,
            )
        });
    Report {
        checks,
        timeline,
        played: Played::Emulated,
    }
}

/// Seconds on the hub's clock as an instant.
fn instant(seconds: f64) -> shared::Instant {
    shared::Instant::from_micros((seconds.max(0.0) * 1e6).round() as u64)
}

/// The oracle's verdict on each receive SRDO 1 of the scenario's network whose producer is
/// in it (the status reports carry receive SRDO 1's output only), from the hub's event log
/// ([`Recorded`]: the same oracle as the campaigns and the host runs, with the emulation's
/// allowance), with the timeline window around its first finding. The whole log from the
/// network's start is judged, so the oracle knows every pair before the scenario; findings
/// before [`Observed::judged_from`] belong to the scenario before and are left out.
fn oracle_checks(scenario: &Scenario, observed: &Observed) -> Vec<(Check, (f64, f64))> {
    if observed.events.is_empty() {
        let check = Check {
            line: 0,
            expected: "the hub's event log, for the oracle to judge".to_string(),
            measured: "no event log: nothing was judged".to_string(),
            passed: false,
            window: (instant(observed.start), instant(observed.end)),
        };
        return vec![(check, (observed.start, observed.end))];
    }
    let mut recorded = Recorded::new(&observed.events);
    let channel = |side: Side| match side {
        Side::A => Channel::A,
        Side::B => Channel::B,
    };
    let watched = super::monitored(scenario, |node, side| {
        recorded.participant(&participant(node, channel(side)))
    });
    let (start, end) = (instant(observed.start), instant(observed.end));
    watched
        .into_iter()
        .filter(|(_, number, _)| *number == 1)
        .map(|(consumer, number, srdo)| {
            let channels = [
                participant(consumer, Channel::A),
                participant(consumer, Channel::B),
            ];
            let judged = recorded.judge(srdo, [&channels[0], &channels[1]], end);
            let from = instant(observed.judged_from);
            let judgement = Judgement {
                violations: judged
                    .violations
                    .into_iter()
                    .filter(|violation| violation.at >= from)
                    .collect(),
                first_error: judged.first_error,
            };
            let window =
                judgement
                    .violations
                    .first()
                    .map_or((observed.start, observed.end), |violation| {
                        let at = violation.at.as_micros() as f64 / 1e6;
                        (at - BEFORE_EMULATED, at + AFTER)
                    });
            let mut check = super::oracle_check(consumer, number, &judgement, start, end);
            // Beside a pass, how soon after the rules first required the safe state the
            // output was off, against the allowance.
            if let (true, Some((at, why))) =
                (check.passed, first_error(&recorded, srdo, start, end))
            {
                let off = recorded.off_from([&channels[0], &channels[1]], at);
                let _ = write!(
                    check.measured,
                    "; the safe state first required at t = {} ({why}), the output off {}",
                    super::ms_signed(at, start),
                    off.map_or("never".to_string(), |off| format!(
                        "{} later (allowed {})",
                        ms(off.saturating_since(at)),
                        ms(EMULATED_ALLOWANCE)
                    ))
                );
            }
            (check, window)
        })
        .collect()
}

/// The first moment at or after `from` (the scenario's time 0) at which the oracle's rules
/// require the safe state for `srdo`, and why. The oracle latches its first finding until
/// an NMT reset, as the device does, so it is asked again on the frames from the last NMT
/// reset (of the consumer or of all nodes) at or before `from` on: the reset that the player
/// sends between two scenarios on one network.
fn first_error(
    recorded: &Recorded,
    srdo: crate::campaign::oracle::MonitoredSrdo,
    from: shared::Instant,
    end: shared::Instant,
) -> Option<(shared::Instant, &'static str)> {
    let reset = |frame: &CanFrame| {
        frame.id().raw() == 0x000
            && matches!(frame.data(), [0x81 | 0x82, node] if *node == 0 || *node == srdo.consumer)
    };
    let since = recorded
        .frames
        .iter()
        .rposition(|(at, frame, _)| *at <= from && reset(frame))
        .unwrap_or(0);
    crate::campaign::oracle::judge(srdo, &recorded.frames[since..], &[], end)
        .first_error
        .filter(|(at, _)| *at >= from)
}

/// The steps the hub took, the reports and the frames from `from` to `to` (hub seconds),
/// times from the scenario's start: what the hub saw around a failure.
pub fn timeline(scenario: &Scenario, observed: &Observed, from: f64, to: f64, why: &str) -> String {
    let mut lines: Vec<(f64, String)> = Vec::new();
    for (step, applied) in scenario.steps.iter().zip(&observed.applied) {
        if *applied >= from && *applied <= to {
            lines.push((*applied, step_line(step)));
        }
    }
    let bus = |frame: &CanFrame| {
        format!(
            "bus     {:03X} [{}] {:02X?}",
            frame.id().raw(),
            frame.dlc(),
            frame.data()
        )
    };
    if observed.events.is_empty() {
        for (when, frame) in &observed.frames {
            if *when >= from && *when <= to {
                lines.push((*when, bus(frame)));
            }
        }
    }
    // The event log's frames with their senders, and the output changes as reported.
    for event in &observed.events {
        let when = event.at().as_micros() as f64 / 1e6;
        if when < from || when > to {
            continue;
        }
        lines.push((
            when,
            match event {
                Event::Frame { from, frame, .. } => format!("{} from {from}", bus(frame)),
                Event::Output { channel, value, .. } => format!("output  {channel}: {value}"),
            },
        ));
    }
    for (who, when, status) in &observed.statuses {
        if *when >= from && *when <= to {
            lines.push((
                *when,
                format!(
                    "status  {who}: nmt={} {} link={} input={} output={} cause={:02X}h {}",
                    status.nmt,
                    if status.working { "working" } else { "SAFE" },
                    u8::from(status.link_up),
                    status.input,
                    status.output,
                    status.cause,
                    Cause::describe_code(status.cause)
                ),
            ));
        }
    }
    lines.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut text = format!("{why}\n");
    for (when, line) in lines.iter().take(400) {
        let _ = writeln!(text, "{:>10.3} ms  {line}", (when - observed.start) * 1e3);
    }
    if lines.len() > 400 {
        let _ = writeln!(text, "… {} more lines", lines.len() - 400);
    }
    text
}

/// A step as the timeline and the run's output show it: its line, its commands to the hub,
/// when it was due.
pub fn step_line(step: &Step) -> String {
    let commands = commands(&step.stimulus).map_or_else(
        |why| why,
        |commands| {
            commands
                .iter()
                .map(|command| format!("`{command}`"))
                .collect::<Vec<_>>()
                .join(", ")
        },
    );
    format!(
        "step    line {}: {commands} (due at t = {})",
        step.line,
        ms(Duration::from_micros(step.at_us))
    )
}
