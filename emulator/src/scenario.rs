//! The scenario files written for the emulated network (`scenarios/emulated/*.toml`) played
//! on the shipped images: each step applied at its instant of virtual time on the emulated
//! network (a contact, an NMT command or GFC from a tool on the bus, the hub's fault
//! vocabulary on the bus model, a cut link wire), and every expectation judged by the judge
//! the QEMU network had until 2026-12-07 (`system_tests::scenario_runner::emulated::judge`,
//! with the campaigns' oracle on the frames and output pins).
//!
//! **What a node's status is here.** The QEMU images reported each channel's status over their
//! serial line; the shipped images send no such report. A rig around real boards sees each
//! channel's output pin and the node's EMCY frames, and so does this player: a channel's
//! status is its output pin, and the node's last EMCY names why it left the working state
//! (channel A speaks for the node on the bus: its EMCY carries its own finding, or "the other
//! channel was first", 40h). So "node 33 safe with cause X" holds when both output pins are
//! off and an EMCY of node 33 names X.

use can_hub::bus::{Fault, Injection, Match};
use can_hub::events::Event as HubEvent;
use emulation_wire::Status;
use shared::canopen::nmt;
use shared::{CanFrame, CanId, Duration, Instant};
use system_tests::scenario_runner::Report;
use system_tests::scenario_runner::emulated::{self as player, Observed};
use system_tests::scenario_runner::file::{Channel, FaultSpec, Scenario, Stimulus};

use crate::cases::{MS, mcu_indices};
use crate::e2e::{Rig, emcy_cause};
use crate::network::{Event, Network};
use crate::time::Nanos;

/// How far back from a scenario's start its frames and statuses are kept for the judge.
const KEPT_BEFORE: Nanos = 1_000 * MS;

/// The MCU of node `node`'s channel `channel`.
fn mcu(network: &Network, node: u8, channel: Channel) -> Result<usize, String> {
    let channels = mcu_indices(network, node);
    let index = match channel {
        Channel::A => 0,
        Channel::B => 1,
    };
    channels
        .get(index)
        .copied()
        .ok_or_else(|| format!("node {node} is not on the emulated network"))
}

fn frame(id: u16, data: &[u8]) -> Result<CanFrame, String> {
    CanId::new(id)
        .ok()
        .and_then(|id| CanFrame::new(id, data).ok())
        .ok_or_else(|| format!("no CAN frame {id:03X}h with {} data bytes", data.len()))
}

/// Refuses, in a sentence naming the line, a step the shipped images' network cannot play:
/// an input value other than 0 or 1 (one contact per channel), and the faults that are not
/// on the bus, a contact or the link wire.
pub fn check_playable(scenario: &Scenario) -> Result<(), String> {
    for step in &scenario.steps {
        let refuse = |why: String| format!("{}:{}: {why}", scenario.path.display(), step.line);
        match &step.stimulus {
            Stimulus::Input { value, .. } if *value > 1 => {
                return Err(refuse(format!(
                    "input value {value:#04x}: the shipped images read one contact per \
                     channel, 0 or 1"
                )));
            }
            Stimulus::Fault(
                fault @ (FaultSpec::LinkCorrupt { .. }
                | FaultSpec::LinkLatency { .. }
                | FaultSpec::Clock { .. }),
            ) => {
                return Err(refuse(format!(
                    "the fault `{}` is not one the emulated network injects (the bus, a \
                     contact, the link wire)",
                    fault.kind()
                )));
            }
            Stimulus::Fault(fault) if !fault.hub_can() => {
                return Err(refuse(format!(
                    "the fault `{}` as written here is a host simulation's only",
                    fault.kind()
                )));
            }
            _ => {}
        }
    }
    Ok(())
}

/// Applies `stimulus` now, `tool` being the external participant that sends NMT commands,
/// GFCs and inserted frames.
fn apply(network: &mut Network, tool: usize, stimulus: &Stimulus) -> Result<(), String> {
    let now = Instant::from_micros(network.now() / 1_000);
    match stimulus {
        Stimulus::Input {
            node,
            channel,
            value,
        } => {
            let channels = match channel {
                Some(channel) => vec![*channel],
                None => vec![Channel::A, Channel::B],
            };
            for channel in channels {
                let index = mcu(network, *node, channel)?;
                network.set_input(index, *value != 0);
            }
        }
        Stimulus::Nmt { command, node } => {
            network.send(tool, nmt::command_frame(*command, *node));
        }
        Stimulus::Gfc => network.send(tool, frame(0x001, &[])?),
        Stimulus::Fault(fault) => {
            let on = |id: u16, count: Option<u32>| Match {
                id: Some(id),
                from: None,
                after: now,
                count,
            };
            let injection = match fault {
                FaultSpec::Drop { id, count, all } => Some(Injection::new(
                    on(*id, if *all { None } else { count.or(Some(1)) }),
                    Fault::Drop,
                )),
                FaultSpec::Corrupt { id, byte, mask } => Some(Injection::new(
                    on(*id, Some(1)),
                    Fault::Corrupt {
                        byte: *byte,
                        mask: *mask,
                    },
                )),
                FaultSpec::Delay { id, by_us } => Some(Injection::new(
                    on(*id, Some(1)),
                    Fault::Delay(Duration::from_micros(*by_us)),
                )),
                FaultSpec::Repeat { id } => Some(Injection::new(on(*id, Some(1)), Fault::Repeat)),
                FaultSpec::Reorder { id } => Some(Injection::new(on(*id, Some(1)), Fault::Reorder)),
                FaultSpec::Mute { node, channel } => Some(Injection::new(
                    Match::all_from(mcu(network, *node, *channel)?, now),
                    Fault::Mute,
                )),
                FaultSpec::Insert { id, data } => {
                    network.send(tool, frame(*id, data)?);
                    None
                }
                FaultSpec::Cut { node } => {
                    for channel in [Channel::A, Channel::B] {
                        let index = mcu(network, *node, channel)?;
                        network.cut_link(index, true);
                    }
                    None
                }
                FaultSpec::Clear => {
                    network.bus_mut().clear_faults();
                    None
                }
                other => {
                    return Err(format!(
                        "the fault `{}` is not one the emulated network injects",
                        other.kind()
                    ));
                }
            };
            if let Some(injection) = injection {
                network.bus_mut().inject(injection);
            }
        }
    }
    Ok(())
}

/// Seconds of virtual time.
fn seconds(at: Nanos) -> f64 {
    at as f64 / 1e9
}

/// What the judge reads of each channel, built from the pins and the EMCY frames (see the
/// module documentation).
struct Statuses {
    /// Per MCU: its name, node, output pin, working, cause.
    channels: Vec<(String, u8, bool, bool, u8)>,
    kept: Vec<(String, f64, Status)>,
}

impl Statuses {
    fn new(network: &Network, nodes: &[u8], at: Nanos) -> Statuses {
        let mut statuses = Statuses {
            channels: Vec::new(),
            kept: Vec::new(),
        };
        for &node in nodes {
            for index in mcu_indices(network, node) {
                let name = network.participant_name(index);
                statuses
                    .channels
                    .push((name, node, network.output(index), true, 0));
            }
        }
        for index in 0..statuses.channels.len() {
            statuses.keep(index, at);
        }
        statuses
    }

    fn keep(&mut self, index: usize, at: Nanos) {
        let (name, _, output, working, cause) = &self.channels[index];
        self.kept.push((
            name.clone(),
            seconds(at),
            Status {
                working: *working,
                output: u8::from(*output),
                cause: *cause,
                ..Status::default()
            },
        ));
    }

    fn see(&mut self, network: &Network, event: &Event) {
        match event {
            Event::Output { at, mcu, on } => {
                let name = network.participant_name(*mcu);
                if let Some(index) = self.channels.iter().position(|c| c.0 == name) {
                    self.channels[index].2 = *on;
                    self.keep(index, *at);
                }
            }
            Event::Frame { at, frame, .. } => {
                if let Some((node, cause)) = emcy_cause(frame) {
                    for index in 0..self.channels.len() {
                        if self.channels[index].1 == node {
                            self.channels[index].3 = false;
                            self.channels[index].4 = cause.code();
                            self.keep(index, *at);
                        }
                    }
                }
            }
            _ => {}
        }
    }
}

/// What the oracle and the judge read of the whole run: every frame with its sender and
/// every output pin change in the hub's event vocabulary, and every frame with its time.
#[derive(Default)]
pub struct Kept {
    history: Vec<HubEvent>,
    frames: Vec<(f64, CanFrame)>,
}

impl Kept {
    /// Keeps `event`; `names` are the network's participants (MCUs first).
    pub fn record(&mut self, names: &[String], event: &Event) {
        let instant = |at: Nanos| Instant::from_micros(at / 1_000);
        match event {
            Event::Frame { at, from, frame } => {
                self.history.push(HubEvent::Frame {
                    at: instant(*at),
                    from: from.clone(),
                    frame: *frame,
                });
                self.frames.push((seconds(*at), *frame));
            }
            Event::Output { at, mcu, on } => self.history.push(HubEvent::Output {
                at: instant(*at),
                channel: names.get(*mcu).cloned().unwrap_or_default(),
                value: u8::from(*on),
            }),
            _ => {}
        }
    }
}

/// Plays `scenario` on the rig's network (nodes 1 and 33 configured, stored and started,
/// node 1's contacts closed, node 33's outputs on) and judges it. The rig's `seen` must
/// record every event into `kept` (from the network's start: the oracle knows every pair
/// before the scenario); `judged_from`: from when the oracle's findings count (the end of
/// the scenario played before, or this one's start).
fn play(
    rig: &mut Rig<'_>,
    scenario: &Scenario,
    kept: &std::cell::RefCell<Kept>,
    judged_from: Nanos,
) -> Result<(Report, Observed), String> {
    let start = rig.network.now();
    let mut statuses = Statuses::new(rig.network, &[1, 33], start);
    let mut applied = Vec::new();
    let end = start + scenario.run_us * 1_000;
    let mut steps = scenario.steps.iter().peekable();
    while rig.network.now() < end || steps.peek().is_some() {
        while let Some(step) = steps.next_if(|step| start + step.at_us * 1_000 <= rig.network.now())
        {
            apply(rig.network, rig.tool, &step.stimulus)
                .map_err(|why| format!("{}:{}: {why}", scenario.path.display(), step.line))?;
            applied.push(seconds(rig.network.now()));
        }
        let due = steps.peek().map_or(end, |step| start + step.at_us * 1_000);
        let until = (rig.network.now() + MS).min(due.max(rig.network.now() + 1));
        rig.network.run_until(until);
        for event in rig.network.take_events() {
            (rig.seen)(&event);
            statuses.see(rig.network, &event);
        }
    }
    let from = seconds(start.saturating_sub(KEPT_BEFORE));
    let end_s = seconds(end);
    let kept = kept.borrow();
    let observed = Observed {
        start: seconds(start),
        applied,
        statuses: statuses.kept,
        frames: kept
            .frames
            .iter()
            .filter(|(t, _)| *t >= from && *t <= end_s)
            .cloned()
            .collect(),
        end: end_s,
        events: kept.history.clone(),
        judged_from: seconds(judged_from),
    };
    let report = player::judge(scenario, &observed);
    // A cut link is mended: the reset before the next scenario starts it over.
    for step in &scenario.steps {
        if let Stimulus::Fault(FaultSpec::Cut { node }) = step.stimulus {
            for channel in [Channel::A, Channel::B] {
                let index = mcu(rig.network, node, channel)?;
                rig.network.cut_link(index, false);
            }
        }
    }
    Ok((report, observed))
}

/// Plays `scenarios` one after the other on `network` after the nominal case (nodes 1 and 33
/// configured and stored), each after an NMT reset and start of both nodes (`Rig::reset`);
/// prints each report as the host runs print it. `seen` receives every event. Returns
/// whether every scenario passed, or why one could not be played.
pub fn play_all(
    network: &mut Network,
    scenarios: &[Scenario],
    seen: &mut dyn FnMut(&Event),
) -> Result<bool, String> {
    for scenario in scenarios {
        check_playable(scenario)?;
    }
    let names: Vec<String> = network.names().map(str::to_owned).collect();
    let kept = std::cell::RefCell::new(Kept::default());
    let mut observe = |event: &Event| {
        seen(event);
        kept.borrow_mut().record(&names, event);
    };
    let mut rig = Rig::new(network, &mut observe)?;
    let mut passed_count = 0;
    let mut judged_from = None;
    for scenario in scenarios {
        rig.reset(&format!("the scenario before {}", scenario.path.display()))?;
        let start = rig.network.now();
        let (report, observed) = play(&mut rig, scenario, &kept, judged_from.unwrap_or(start))?;
        judged_from = Some(rig.network.now());
        print!("{}", report.text(scenario));
        for (step, applied) in scenario.steps.iter().zip(&observed.applied) {
            println!(
                "  {}, applied at t = {:.3} ms",
                player::step_line(step),
                (applied - observed.start) * 1e3
            );
        }
        passed_count += usize::from(report.passed());
    }
    rig.network.leave_external(rig.tool);
    println!(
        "emulate-network: scenarios: {passed_count} of {} passed on the shipped images",
        scenarios.len()
    );
    Ok(passed_count == scenarios.len())
}

#[cfg(test)]
mod tests {
    use super::*;
    use system_tests::scenario_runner::file;

    fn scenario(steps: &str) -> Scenario {
        let base = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/emulated");
        let text = format!(
            "name = \"test\"\ncovers = \"test\"\nnetwork = \"../networks/emulated.toml\"\n\
             run_ms = 100\n{steps}[[expect]]\noutput = 33\nat_ms = 50\nequals = 1\n"
        );
        file::parse(&text, "test.toml", &base).expect("the test's scenario parses")
    }

    /// A step the shipped images cannot play is refused with its line, before the network is
    /// touched: an input value other than 0 or 1 (one contact per channel), a fault that is
    /// not on the bus, a contact or the link wire.
    #[test]
    fn a_step_the_shipped_images_cannot_play_is_refused_with_its_line() {
        let input = scenario("[[step]]\nat_ms = 10\ninput = { node = 1, value = 0x5A }\n");
        let why = check_playable(&input).expect_err("0x5A is no contact state");
        assert!(why.contains("test.toml:5") && why.contains("0x5a"), "{why}");

        let clock = scenario(
            "[[step]]\nat_ms = 10\nfault = { kind = \"clock\", node = 1, channel = \"A\", percent = 1 }\n",
        );
        let why = check_playable(&clock).expect_err("the clock is not the emulated network's");
        assert!(
            why.contains("test.toml:5") && why.contains("clock"),
            "{why}"
        );

        let fine = scenario("[[step]]\nat_ms = 10\ninput = { node = 1, value = 0 }\n");
        assert_eq!(check_playable(&fine), Ok(()));
    }
}
