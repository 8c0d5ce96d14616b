//! `cargo xtask run`: the main job. The emulated safety network ([`Network`]: the sealed
//! hardware images `cargo xtask build` makes, unchanged, on the emulated STM32F405s of
//! `emulate-network`) shown through the configuration tool's live monitor
//! (`safety_config::monitor`): every channel's status as the emulator sees it from outside,
//! and the bus as the monitor decodes it (NMT states, SRDO pairs with their
//! gaps and periods, EMCYs in words, SDO traffic), redrawn in place; single keys press the
//! emergency stop and inject faults; a summary says how the run ended.
//!
//! Keys (no Enter): `e` press or release the emergency stop on node 1, `d` drop node 1's
//! next inverted frame, `c` corrupt its next plain frame, `s` stop node 1 (both channels
//! muted), `b` channel B of node 1 reads the input otherwise, `l` cut the link between node
//! 33's channels or restore it, `g` send a GFC, `r` reset both nodes (NMT reset node, then
//! start), `p` pause the drawing, `?` help, `q` quit. When stdout is not a terminal (CI) the
//! run prints plain lines instead: the channel table when it changes and a line per happening
//! on the bus; on a terminal stdin without a terminal stdout, the keys are typed with Enter.
//! Unattended: `--for 30s` ends the run and `--at 5s:press` (and `release`, `drop`,
//! `corrupt`, `stop`, `b-differs`, `cut-link`, `restore-link`, `gfc`, `reset`, or any key of
//! the live view: `--at 5s:l`) schedules the same actions.
//!
//! The run survives every key: an action that does not have the effect it should (a node
//! that does not start again after `r`, say, because its link is cut) says why on the screen
//! and the run goes on; it ends only by `q`, Ctrl-C or `--for`. A reset runs beside the
//! screen ([`Restart`]): the nodes' boot-up messages are awaited, then NMT start, then every
//! channel Operational and working, each step on the network's time.
//!
//! The tool and the monitor join the emulated network's socketcand port, the run drives it
//! through its control port, which speaks the hub's protocol (`emulator::control`), and each
//! channel's status is what the emulator sees of it from outside (heartbeats, EMCYs, the
//! channel's own log, its pins). The run refuses images whose CRC the emulator reads
//! differently from what the build sealed, and prints both CRCs.
//!
//! `--protocol simplecan`: the same network on the SimpleCAN images, configured from
//! `scenarios/networks/simplecan.toml` (node 1 the master and producer of SC-ID 30h, node 33
//! its consumer, [`network::Protocol`]). The actions act on the same channels: `press`,
//! `release`, `stop`, `b-differs`, `cut-link`, `gfc` and `reset` as for CANopen Safety;
//! `drop` drops node 1's next packet of 30h and `corrupt` flips a bit of it (its CRC then
//! fails at node 33, and node 1's channel B finds it differs from its own: 78h). The run
//! passes when every channel ends Operational and working, node 33's channels confirmed
//! values of 30h, and node 1 was the only master the monitor saw.

use crate::network::{self, Network};
use anyhow::{Result, bail};
use emulation_wire::Status;
use safety_config::Transport;
use safety_config::monitor::model::{Monitor, PairVerdict};
use safety_config::monitor::view::{self, Screen};
use safety_config::monitor::{self, Pressed};
use safety_config::socketcand::SocketcandClient;
use shared::CanFrame;
use shared::canopen::nmt::{NmtCommand, NmtState};
use shared::safety::cause::Cause;
use std::collections::HashMap;
use std::io::{BufRead, IsTerminal, Write};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// Something a person (or a flag) does to the network.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Action {
    /// Toggle the emergency stop.
    Toggle,
    /// Press it.
    Press,
    /// Release it.
    Release,
    /// Drop node 1's next inverted frame.
    Drop,
    /// Corrupt node 1's next plain frame.
    Corrupt,
    /// Stop node 1 (mute both channels).
    Stop,
    /// Channel B of node 1 reads its input as 0 while A reads 1.
    BDiffers,
    /// Cut node 33's link, or restore it when it is cut (key `l`).
    ToggleLink,
    /// Cut node 33's link.
    CutLink,
    /// Restore node 33's link.
    RestoreLink,
    /// Send a GFC (EN 50325-5 7.2.1): every node in Operational goes to its safe state.
    Gfc,
    /// Reset both nodes and start them.
    Reset,
    /// Pause or resume the drawing (key `p`).
    Pause,
    /// End the run.
    Quit,
}

impl Action {
    /// A scheduled action's name (`--at 5s:press`), or a key of the live view (`--at 5s:l`,
    /// [`Action::key`]).
    pub fn named(name: &str) -> Result<Action, String> {
        let mut letters = name.chars();
        if let (Some(key), None) = (letters.next(), letters.next()) {
            return Action::key(key)
                .ok_or_else(|| format!("`{name}` is not a key of the run (e d c s b l g r p q)"));
        }
        Ok(match name {
            "press" => Action::Press,
            "release" => Action::Release,
            "drop" => Action::Drop,
            "corrupt" => Action::Corrupt,
            "stop" => Action::Stop,
            "b-differs" => Action::BDiffers,
            "cut-link" => Action::CutLink,
            "restore-link" => Action::RestoreLink,
            "gfc" => Action::Gfc,
            "reset" => Action::Reset,
            _ => {
                return Err(format!(
                    "`{name}` is not an action (press, release, drop, corrupt, stop, b-differs, \
                     cut-link, restore-link, gfc, reset) nor a key (e d c s b l g r p q)"
                ));
            }
        })
    }

    /// The action of a key (a single key on the live view, a line of one letter otherwise,
    /// `--at 5s:l`).
    fn key(key: char) -> Option<Action> {
        Some(match key {
            'e' => Action::Toggle,
            'd' => Action::Drop,
            'c' => Action::Corrupt,
            's' => Action::Stop,
            'b' => Action::BDiffers,
            'l' => Action::ToggleLink,
            'g' => Action::Gfc,
            'r' => Action::Reset,
            'p' => Action::Pause,
            'q' => Action::Quit,
            _ => return None,
        })
    }

    /// The action's name, as `--at` takes it.
    fn name(self) -> &'static str {
        match self {
            Action::Toggle => "e",
            Action::Press => "press",
            Action::Release => "release",
            Action::Drop => "drop",
            Action::Corrupt => "corrupt",
            Action::Stop => "stop",
            Action::BDiffers => "b-differs",
            Action::ToggleLink => "l",
            Action::CutLink => "cut-link",
            Action::RestoreLink => "restore-link",
            Action::Gfc => "gfc",
            Action::Reset => "reset",
            Action::Pause => "p",
            Action::Quit => "q",
        }
    }

    /// Whether the action is a fault that should put a node in its safe state.
    fn is_fault(self) -> bool {
        matches!(
            self,
            Action::Drop
                | Action::Corrupt
                | Action::Stop
                | Action::BDiffers
                | Action::CutLink
                | Action::Gfc
        )
    }
}

/// The keys of the live view, for its bottom line.
const KEYS: &str = "e e-stop  d drop  c corrupt  s stop node 1  b B differs  l cut/restore link  g GFC  r reset  p pause  ? help  q quit";

fn help() -> Vec<String> {
    [
        "e   press or release the emergency stop (both contacts of node 1)",
        "d   node 1's next inverted frame is dropped on the bus (node 33: SRVT elapsed)",
        "c   byte 0 of node 1's next plain frame is corrupted on the bus",
        "s   stop node 1 (both channels muted; node 33: SCT elapsed)",
        "b   channel B of node 1 reads its input as 0, channel A as 1",
        "l   cut the link between node 33's channels, or restore it",
        "g   send a GFC: every node in Operational goes to its safe state",
        "r   reset both nodes (NMT reset node), then start them; a node that does not",
        "    come back says why (a cut link stays cut: l restores it, then r)",
        "p   pause or resume the drawing",
        "q   quit (also Esc, Ctrl-C) and print the summary",
        "",
        "Channels: each MCU's status as the emulator observes it.",
        "Nodes, SRDOs, Events: the bus as the monitor decodes it.",
    ]
    .map(str::to_owned)
    .to_vec()
}

/// The longest unattended run, and the latest time an action can be scheduled at: one day.
/// Longer is a soak test, which wants its own task (the traces and status log grow with the
/// run); the bound also keeps every value far inside what `Duration` can hold.
pub const LONGEST_RUN: Duration = Duration::from_secs(24 * 60 * 60);

/// A duration such as `30s`, `500ms`, `2m` or `45` (seconds), at most [`LONGEST_RUN`].
pub fn parse_duration(text: &str) -> Result<Duration, String> {
    let (number, unit) = match text.find(|c: char| !c.is_ascii_digit() && c != '.') {
        Some(at) => text.split_at(at),
        None => (text, "s"),
    };
    let value: f64 = number
        .parse()
        .ok()
        .filter(|v: &f64| v.is_finite() && *v >= 0.0)
        .ok_or_else(|| format!("`{text}` is not a duration (e.g. 30s, 500ms, 2m)"))?;
    let seconds = match unit {
        "ms" => value / 1000.0,
        "s" => value,
        "m" | "min" => value * 60.0,
        _ => return Err(format!("`{text}`: unit `{unit}` is not ms, s or m")),
    };
    Duration::try_from_secs_f64(seconds)
        .ok()
        .filter(|duration| *duration <= LONGEST_RUN)
        .ok_or_else(|| format!("`{text}` is longer than the longest run, 24 h (86400s)"))
}

/// Every scheduled action happens before an unattended run of `duration` ends.
pub fn check_schedule(
    duration: Option<Duration>,
    schedule: &[(Duration, Action)],
) -> Result<(), String> {
    let Some(duration) = duration else {
        return Ok(());
    };
    match schedule.iter().find(|(at, _)| *at >= duration) {
        Some((at, action)) => Err(format!(
            "--at {:.3}s:{} is at or after the run ends (--for {:.3}s): it would never happen",
            at.as_secs_f64(),
            action.name(),
            duration.as_secs_f64()
        )),
        None => Ok(()),
    }
}

/// `5s:press` → when and what.
pub fn parse_at(text: &str) -> Result<(Duration, Action), String> {
    let (at, name) = text
        .split_once(':')
        .ok_or_else(|| format!("--at {text}: expected TIME:ACTION, e.g. 5s:press"))?;
    Ok((parse_duration(at)?, Action::named(name)?))
}

/// What the run did and observed, for the summary and the screen.
#[derive(Default)]
struct Observed {
    latencies_ms: Vec<f64>,
    pressed: bool,
    /// The emergency stop was pressed at this hub time and the channels' reports from this
    /// entry of the history on are searched for node 33's output 0 (the latency).
    press_pending: Option<(f64, usize)>,
    /// Faults injected since the start or the latest reset: when (run time) and what.
    faults: Vec<(Duration, Action)>,
    /// Resets done.
    resets: usize,
    /// The link between node 33's channels is cut (a reset does not mend it).
    link_cut: bool,
    /// A reset in progress.
    restart: Option<Restart>,
    /// After a reset, until the first SRDO verdict after it: how many verdicts the monitor
    /// had reached on node 1's SRDO before it (see [`sct_after_reset`]).
    verdicts_at_reset: Option<u64>,
    /// A standing line under the channel table: what a reset in progress waits for, or why a
    /// node did not come back after the last one (until the next reset).
    notice: Option<String>,
}

/// Does `action` (at run time `at`); returns what was done, in words. An action the network
/// refuses is an error, said on the screen by the caller; the run goes on.
fn apply(
    network: &mut Network,
    bus: &mut SocketcandClient,
    model: &mut Monitor,
    action: Action,
    at: Duration,
    seen: &mut Observed,
) -> Result<String> {
    let action = match action {
        Action::Toggle if seen.pressed => Action::Release,
        Action::Toggle => Action::Press,
        Action::ToggleLink if seen.link_cut => Action::RestoreLink,
        Action::ToggleLink => Action::CutLink,
        other => other,
    };
    if action.is_fault() {
        seen.faults.push((at, action));
    }
    Ok(match action {
        Action::Press => {
            let on = network::output_33(&network.control.latest) == Some(1);
            let pressed = network.command("input node1a 0")?;
            network.command("input node1b 0")?;
            seen.pressed = true;
            if on {
                seen.press_pending = Some((pressed, network.control.history.len()));
                "emergency stop pressed (node 1's input 0)".to_owned()
            } else {
                seen.press_pending = None;
                "emergency stop pressed (node 1's input 0); node 33's output was not on, so \
                 there is no latency to measure"
                    .to_owned()
            }
        }
        Action::Release => {
            network.command("input node1a 1")?;
            network.command("input node1b 1")?;
            seen.pressed = false;
            seen.press_pending = None;
            "emergency stop released".to_owned()
        }
        Action::Drop if network.protocol == network::Protocol::Simplecan => {
            network.command(&format!("drop 0x{:03X}", network::ESTOP_SC_ID))?;
            "the emulated network drops node 1's next packet of 30h".to_owned()
        }
        Action::Corrupt if network.protocol == network::Protocol::Simplecan => {
            network.command(&format!("corrupt 0x{:03X} 0 0x01", network::ESTOP_SC_ID))?;
            "the emulated network corrupts byte 0 of node 1's next packet of 30h (its CRC fails \
             at node 33; node 1's channel B finds it differs from its own)"
                .to_owned()
        }
        Action::Drop => {
            network.command(&format!("drop 0x{:03X}", network::INVERTED))?;
            "the emulated network drops node 1's next inverted frame".to_owned()
        }
        Action::Corrupt => {
            network.command(&format!("corrupt 0x{:03X} 0 0x01", network::PLAIN))?;
            "the emulated network corrupts byte 0 of node 1's next plain frame (node 1's \
             channel B sees it too and withholds the inverted frame)"
                .to_owned()
        }
        Action::Stop => {
            network.command("mute node1a")?;
            network.command("mute node1b")?;
            "node 1 stopped (both channels muted)".to_owned()
        }
        Action::BDiffers => {
            network.command("input node1b 0")?;
            "channel B of node 1 now reads its input as 0, channel A as 1".to_owned()
        }
        Action::CutLink => {
            network.command("cut node33-link")?;
            seen.link_cut = true;
            "the link between node 33's channels is cut (l restores it)".to_owned()
        }
        Action::RestoreLink => {
            network.command("restore node33-link")?;
            seen.link_cut = false;
            "the link between node 33's channels is restored (node 33 stays in its safe state \
             until a reset: r)"
                .to_owned()
        }
        Action::Gfc => {
            let gfc = shared::safety::gfc::frame();
            bus.send(&gfc)?;
            // The hub does not hand a client's own frame back to it.
            model.feed(model.now, &gfc);
            "GFC sent (CAN-ID 001h)".to_owned()
        }
        Action::Reset => {
            // Every bus fault off (node 1 unmuted) and every input released, then NMT reset
            // node: on each channel's line the hub's order holds, so every channel has its
            // input back before it handles the reset. A cut link stays cut.
            network.command("clear")?;
            for (name, _, _) in network::CHANNELS {
                network.command(&format!("input {name} 1"))?;
            }
            let reset = shared::canopen::nmt::command_frame(NmtCommand::ResetNode, 0);
            bus.send(&reset)?;
            model.feed(model.now, &reset);
            seen.pressed = false;
            seen.press_pending = None;
            seen.faults.clear();
            if seen.link_cut {
                // Still cut: it explains a node 33 that stays in its safe state.
                seen.faults.push((at, Action::CutLink));
            }
            seen.resets += 1;
            seen.verdicts_at_reset = Some(
                model
                    .srdos
                    .get(&network::PLAIN)
                    .map_or(0, |srdo| srdo.verdicts.values().sum()),
            );
            seen.restart = Some(Restart::new(network.hub_time()));
            "NMT reset node for both nodes; NMT start once both have booted".to_owned()
        }
        Action::Toggle | Action::ToggleLink | Action::Pause | Action::Quit => String::new(),
    })
}

/// The emergency stop's latency, once node 33's two channels both reported output 0 after
/// the press: the later of their first such reports, less the hub time of the press (as
/// `e2e::press` measures it).
fn press_latency(history: &[(String, f64, Status)], pressed: f64, from: usize) -> Option<f64> {
    let first_off = |channel: &str| {
        history
            .get(from..)?
            .iter()
            .find(|(name, t, status)| name == channel && *t >= pressed && status.output == 0)
            .map(|(_, t, _)| *t)
    };
    let off = first_off("node33a")?.max(first_off("node33b")?);
    Some((off - pressed) * 1000.0)
}

/// How long a reset waits, on the network's time, for the nodes' boot-up messages after NMT
/// reset node, and then for every channel Operational and working after NMT start (a node
/// boots once both its channels run).
const RESTART_PATIENCE: f64 = 10.0;

/// What a reset in progress has the run do next.
#[derive(Debug, PartialEq)]
enum Step {
    /// Nothing yet: what it waits for, in words.
    Wait(String),
    /// Send NMT start to every node; a sentence for the screen when a node did not boot.
    Start(Option<String>),
    /// The reset is over: a sentence for the screen, and whether every node came back.
    Done(String, bool),
}

/// A reset in progress (key `r`): NMT reset node was sent at `since` (hub time); then the
/// nodes' boot-up messages, NMT start, and every channel Operational and working. Each step
/// waits at most [`RESTART_PATIENCE`]; a node that does not come is named with why (its
/// channels' own reports in words, and a cut link) and the run goes on.
#[derive(Debug)]
struct Restart {
    since: f64,
    /// NMT start has been sent (at `since`).
    started: bool,
    /// Boot-up messages seen: node 1, node 33.
    booted: [bool; 2],
}

impl Restart {
    fn new(since: f64) -> Restart {
        Restart {
            since,
            started: false,
            booted: [false; 2],
        }
    }

    /// A frame from the bus: the boot-up messages (700h + node-ID, state 0).
    fn frame(&mut self, frame: &CanFrame) {
        match (frame.id().raw(), frame.data()) {
            (0x701, [0]) => self.booted[0] = true,
            (0x721, [0]) => self.booted[1] = true,
            _ => {}
        }
    }

    /// The next step at hub time `now`, with the channels' latest reports.
    fn step(&mut self, now: f64, latest: &HashMap<String, (f64, Status)>, link_cut: bool) -> Step {
        let waited = now - self.since;
        if !self.started {
            let silent: Vec<u8> = [1, 33]
                .into_iter()
                .zip(self.booted)
                .filter(|(_, booted)| !booted)
                .map(|(node, _)| node)
                .collect();
            if silent.is_empty() {
                self.started = true;
                self.since = now;
                return Step::Start(None);
            }
            if waited < RESTART_PATIENCE {
                return Step::Wait(format!(
                    "reset: waiting for the boot-up of {} ({waited:.1} s)",
                    nodes_words(&silent)
                ));
            }
            self.started = true;
            self.since = now;
            let why: Vec<String> = silent
                .iter()
                .map(|node| why_not_working(*node, latest, link_cut))
                .collect();
            return Step::Start(Some(format!(
                "no boot-up from {} within {RESTART_PATIENCE:.0} s of NMT reset node ({}); NMT \
                 start sent all the same",
                nodes_words(&silent),
                why.join("; ")
            )));
        }
        let down: Vec<u8> = [1, 33]
            .into_iter()
            .filter(|node| !network::working(latest, *node))
            .collect();
        if down.is_empty() {
            return Step::Done(
                "both nodes Operational and working again after the reset".to_owned(),
                true,
            );
        }
        if waited < RESTART_PATIENCE {
            return Step::Wait(format!(
                "reset: NMT start sent; waiting for {} to be Operational and working ({waited:.1} s)",
                nodes_words(&down)
            ));
        }
        let why: Vec<String> = down
            .iter()
            .map(|node| why_not_working(*node, latest, link_cut))
            .collect();
        Step::Done(
            format!(
                "{} did not come back within {RESTART_PATIENCE:.0} s of NMT start: {}",
                nodes_words(&down),
                why.join("; ")
            ),
            false,
        )
    }
}

/// `node 1`, `node 33`, `nodes 1 and 33`.
fn nodes_words(nodes: &[u8]) -> String {
    match nodes {
        [node] => format!("node {node}"),
        _ => format!(
            "nodes {}",
            nodes
                .iter()
                .map(u8::to_string)
                .collect::<Vec<_>>()
                .join(" and ")
        ),
    }
}

/// Why `node` is not Operational and working, in words: each channel's NMT state, safe state
/// and its cause from the channel's own report, and what the run knows that explains it.
fn why_not_working(node: u8, latest: &HashMap<String, (f64, Status)>, link_cut: bool) -> String {
    let channels: Vec<String> = network::CHANNELS
        .iter()
        .filter(|(_, id, _)| *id == node)
        .map(|(name, _, _)| match latest.get(*name) {
            None => format!("{name} never reported"),
            Some((_, s)) => format!(
                "{name} {}{}",
                s.nmt_state()
                    .map_or("in an unknown NMT state", NmtState::describe),
                match (s.working, s.link_up) {
                    (true, true) => String::new(),
                    (true, false) => ", its link down".to_owned(),
                    (false, _) => format!(", in the safe state ({})", cause_words(s.cause)),
                }
            ),
        })
        .collect();
    let mut words = format!("node {node}: {}", channels.join(", "));
    if node == 33 && link_cut {
        words.push_str(
            "; the link between its channels is cut, and a node boots and works only with both \
             channels talking (l restores the link, then r)",
        );
    }
    words
}

/// The words for the first SRDO verdict after a reset when it is "SCT exceeded": the pair's
/// period runs from the last pair before the reset, across the reset of both nodes. Node 33,
/// the consumer, was reset as well and supervises the SCT again only from its entry into
/// Operational (EN 50325-5 7.1.2: the SCT of a consumer in Operational), so the long period
/// is the reset's effect and no fault: node 33 keeps working.
fn sct_after_reset(srdo: u16, inverted: u16) -> String {
    format!(
        "SRDO {srdo:03X}h/{inverted:03X}h: SCT exceeded across the reset, no fault (node 33 \
         was reset too: its SCT runs from its start)"
    )
}

/// The cause of a channel's last safe state in words (`shared::safety::cause::Cause`, the
/// one table), or what the number is when it is no cause of this device.
fn cause_words(code: u8) -> String {
    match Cause::from_code(code) {
        Some(Cause::None) => "none".to_owned(),
        Some(cause) => cause.describe().to_owned(),
        None => format!("code {code:02X}h, no cause this device knows"),
    }
}

/// The lines of a channel's log that report one safe state each: a fault the channel found
/// logs its `Fault(..)` and then the core's `SafeState(..)` it caused, one event in two lines,
/// so the `SafeState` lines count the events; a log with only `Fault` lines keeps those.
fn safe_state_reports(lines: &[String]) -> Vec<&str> {
    let latched: Vec<&str> = lines
        .iter()
        .map(String::as_str)
        .filter(|line| line.contains("SafeState("))
        .collect();
    if latched.is_empty() {
        lines.iter().map(String::as_str).collect()
    } else {
        latched
    }
}

/// A safe-state line of a channel's decoded log in words: defmt renders
/// `shared::node::SafeStateCause` with the variants' names (`Srdo(SrdoFault { srdo:
/// SrdoNumber(1), cause: SrvtElapsed })`, `Application { detail: 48 }`, `Gfc`,
/// `Integrity(Runtime(..))`), which are [`Cause`]'s own names; the words are `Cause`'s.
/// `None` for a line that names none of them.
fn logged_cause_words(line: &str) -> Option<String> {
    let number_after = |marker: &str| -> Option<u8> {
        let rest = line.split(marker).nth(1)?;
        rest.split(|c: char| !c.is_ascii_digit())
            .next()?
            .parse()
            .ok()
    };
    if let Some(code) = number_after("Application { detail: ") {
        return Some(cause_words(code));
    }
    let named = |name: &str| {
        Cause::ALL
            .into_iter()
            .find(|cause| format!("{cause:?}") == name)
    };
    let word_after = |marker: &str| -> Option<&str> {
        let rest = line.split(marker).nth(1)?;
        rest.split(|c: char| !c.is_ascii_alphanumeric()).next()
    };
    if let Some(cause) = word_after("cause: ").and_then(named) {
        return Some(match number_after("SrdoNumber(") {
            Some(srdo) => format!("SRDO {srdo}: {}", cause.describe()),
            None => cause.describe().to_owned(),
        });
    }
    if let Some(cause) =
        word_after("Integrity(").and_then(|name| named(&format!("Integrity{name}")))
    {
        return Some(cause.describe().to_owned());
    }
    line.contains("SafeState(Gfc)")
        .then(|| Cause::Gfc.describe().to_owned())
}

/// The channels' latest status reports as lines (the live view's panel, the plain lines and
/// the summary): NMT state, working or safe, link, pins, SRDO counts, the cause in words.
fn channel_lines(latest: &HashMap<String, (f64, Status)>) -> Vec<String> {
    let mut lines = vec![format!(
        "{:<8} {:<15} {:<8} {:<5} {:>5} {:>6} {:>10} {:>10}  last safe-state cause",
        "channel", "NMT", "state", "link", "input", "output", "SRDOs sent", "validated"
    )];
    for (name, _, _) in network::CHANNELS {
        let Some((_, s)) = latest.get(name) else {
            lines.push(format!("{name:<8} (no report yet)"));
            continue;
        };
        lines.push(format!(
            "{name:<8} {:<15} {:<8} {:<5} {:>5} {:>6} {:>10} {:>10}  {}",
            s.nmt_state().map_or("unknown", NmtState::describe),
            if s.working { "working" } else { "SAFE" },
            match (s.cause, s.link_up) {
                (0x10..=0x14, _) => "FAULT",
                (_, true) => "up",
                (_, false) => "-",
            },
            s.input,
            s.output,
            s.sent,
            s.validated,
            cause_words(s.cause),
        ));
    }
    lines
}

/// How a run ended, from what was observed: whether every channel ended Operational and
/// working, which did not and why, and whether a fault injected since the last reset
/// explains it.
#[derive(Debug, PartialEq, Eq)]
pub struct Ending {
    /// The sentence for the summary.
    pub sentence: String,
    /// Whether the run counts as passed.
    pub passed: bool,
}

/// The ending of a run whose channels last reported `latest`, with the monitor's count of
/// valid pairs on the bus and the faults injected since the last reset.
fn ending(
    latest: &HashMap<String, (f64, Status)>,
    valid_pairs: u64,
    faults: &[(Duration, Action)],
) -> Ending {
    ending_for(
        network::Protocol::CanopenSafety,
        latest,
        valid_pairs,
        faults,
        None,
    )
}

/// [`ending`] for a network speaking `protocol`: with SimpleCAN, `valid_pairs` counts the
/// monitor's packets of 30h and `masters` names the SC-IDs the monitor saw sync (the run
/// passes only with node 1's alone).
fn ending_for(
    protocol: network::Protocol,
    latest: &HashMap<String, (f64, Status)>,
    valid_pairs: u64,
    faults: &[(Duration, Action)],
    masters: Option<&[u8]>,
) -> Ending {
    let (received, on_bus) = match protocol {
        network::Protocol::CanopenSafety => ("SRDO pairs", "valid pairs"),
        network::Protocol::Simplecan => ("SimpleCAN values of 30h", "packets of 30h"),
    };
    let mut unwell = Vec::new();
    for (name, _, _) in network::CHANNELS {
        match latest.get(name) {
            None => unwell.push(format!("{name} never reported")),
            Some((_, s)) if s.nmt_state() != Some(NmtState::Operational) => unwell.push(format!(
                "{name} ended {}",
                s.nmt_state()
                    .map_or("in an unknown NMT state", NmtState::describe)
            )),
            Some((_, s)) if !s.working => unwell.push(format!(
                "{name} ended in the safe state ({})",
                cause_words(s.cause)
            )),
            Some(_) => {}
        }
    }
    let validated = ["node33a", "node33b"]
        .iter()
        .map(|name| latest.get(*name).map_or(0, |(_, s)| s.validated))
        .min()
        .unwrap_or(0);
    let injected: Vec<String> = faults
        .iter()
        .map(|(at, action)| format!("{} at {:.1} s", action.name(), at.as_secs_f64()))
        .collect();
    if let Some(masters) = masters {
        if masters != [network::ESTOP_SC_ID] {
            unwell.push(format!(
                "the monitor saw syncs of {masters:02X?}, not of node 1's {:02X}h alone",
                network::ESTOP_SC_ID
            ));
        }
    }
    if unwell.is_empty() && validated > 0 {
        return Ending {
            sentence: format!(
                "every channel ended Operational and working; node 33's channels validated {validated} \
                 {received} or more each, and the monitor saw {valid_pairs} {on_bus} on the bus"
            ),
            passed: true,
        };
    }
    if unwell.is_empty() {
        return Ending {
            sentence: format!(
                "every channel ended Operational and working, but node 33 validated no {received}"
            ),
            passed: false,
        };
    }
    let what = unwell.join("; ");
    if injected.is_empty() {
        Ending {
            sentence: format!(
                "FAILED: {what}, with no fault injected since the start or the last reset"
            ),
            passed: false,
        }
    } else {
        Ending {
            sentence: format!(
                "{what}: the safe state after the injected fault(s) ({}), as it should; the \
                 monitor saw {valid_pairs} {on_bus} on the bus",
                injected.join(", ")
            ),
            passed: valid_pairs > 0,
        }
    }
}

/// The heartbeat consumer time the run's monitor judges both nodes' heartbeats by: twice
/// the emulated devices' producer heartbeat time (`safety_device::config`), one
/// heartbeat missed, as a consumer would be set up (CiA 301 7.2.8.3.2.2).
fn heartbeat_consumer_time() -> Duration {
    let producer = shared::canopen::node_id::NodeId::new(1)
        .map_or(100, |id| safety_device::config(id, "").heartbeat_ms);
    Duration::from_millis(2 * u64::from(producer))
}

/// Whether the live view is drawn now: at once when pausing, resuming or the help changed
/// (`drawn` is what the screen last showed, `showing` what it is to show: paused, help), at
/// the start, and every 200 ms while not paused. Paused, the screen keeps its last picture,
/// drawn with the word PAUSED in its title.
fn due_to_draw(drawn: (bool, bool), showing: (bool, bool), since_last: Option<Duration>) -> bool {
    let (paused, _) = showing;
    drawn != showing
        || since_last.is_none_or(|since| !paused && since >= Duration::from_millis(200))
}

/// `cargo xtask run`.
pub fn task(
    root: &std::path::Path,
    duration: Option<Duration>,
    mut schedule: Vec<(Duration, Action)>,
    protocol: network::Protocol,
) -> Result<()> {
    check_schedule(duration, &schedule).map_err(anyhow::Error::msg)?;
    let interrupted = Arc::new(AtomicBool::new(false));
    {
        let interrupted = interrupted.clone();
        // Ctrl-C or SIGTERM: end the run; the network's drop kills every child process. (On
        // the live view Ctrl-C is a key, the terminal being in raw mode.)
        crate::child::on_interrupt(move || interrupted.store(true, Ordering::SeqCst));
    }
    let live = std::io::stdout().is_terminal() && std::io::stdin().is_terminal();
    let typed = !live && duration.is_none() && std::io::stdin().is_terminal();
    if !live && !typed && duration.is_none() {
        bail!("not on a terminal: give `--for <duration>` to run unattended");
    }
    let mut network = Network::start_for(root, protocol)?;
    // The monitor's own socketcand connection, beside the configuration tool's.
    let mut bus = SocketcandClient::connect(&network::hub_tcp(), "can0")?;
    let origin = "target/emulate/network.toml";
    let file = safety_config::network_file::parse(&protocol.network_file(), origin)?;
    let mut model = Monitor::for_network(&file);
    // Wireshark's dissector of this network's safety frames, beside bus.pcap.
    std::fs::write(
        network.dir().join("safety.lua"),
        safety_config::dissector::lua(&file, origin),
    )?;
    let consumer_time = heartbeat_consumer_time();
    for (_, node, _) in network::CHANNELS {
        model.nodes.entry(node).or_default().consumer_time = Some(consumer_time);
    }
    let started = Instant::now();
    schedule.sort_by_key(|(at, _)| *at);
    let mut schedule = schedule.into_iter().peekable();
    let keys = mpsc::channel::<char>();
    if typed {
        let tx = keys.0.clone();
        std::thread::spawn(move || {
            for line in std::io::stdin().lock().lines() {
                let Ok(line) = line else { return };
                let key = line.trim().chars().next().unwrap_or(' ');
                if tx.send(key).is_err() {
                    return;
                }
            }
        });
        println!(
            "Keys (then Enter): e emergency stop, d drop, c corrupt, s stop node 1, \
             b channel B differs, l cut or restore node 33's link, g GFC, r reset, q quit"
        );
    }
    let mut terminal = if live {
        Some(monitor::Terminal::open()?)
    } else {
        None
    };
    let mut screen = Screen {
        title: "cargo xtask run: the emulated safety network (nodes 1 and 33, the shipped \
                images on four emulated STM32F405s)"
            .to_owned(),
        keys: KEYS.to_owned(),
        ..Screen::default()
    };
    let mut seen = Observed::default();
    let mut printed = 0;
    let mut last_print = Instant::now() - Duration::from_secs(1);
    let mut last_table = Vec::new();
    let mut last_draw: Option<Instant> = None;
    let mut drawn = (false, false);
    let outcome: Result<()> = 'run: loop {
        if interrupted.load(Ordering::SeqCst) {
            model.note(model.now, "interrupted".to_owned());
            break Ok(());
        }
        if duration.is_some_and(|d| started.elapsed() >= d) {
            break Ok(());
        }
        if let Err(error) = network.control.watch(Duration::from_millis(50)) {
            break Err(error.into());
        }
        if let Err(error) = network.check_alive() {
            break Err(error);
        }
        // What the bus holds now, without waiting (a deadline passed reads what has come).
        loop {
            match bus.receive_stamped(Duration::ZERO) {
                Ok(Some((at, frame))) => {
                    if let Some(restart) = seen.restart.as_mut() {
                        restart.frame(&frame);
                    }
                    model.feed(at, &frame);
                }
                Ok(None) => break,
                Err(error) => break 'run Err(error.into()),
            }
        }
        let mut actions = Vec::new();
        while let Some((_, action)) = schedule.next_if(|(at, _)| started.elapsed() >= *at) {
            actions.push(action);
        }
        let mut pressed = Vec::new();
        if let Some(terminal) = &mut terminal {
            match terminal.keys() {
                Ok(keys) => pressed = keys,
                Err(error) => break Err(error.into()),
            }
        }
        pressed.extend(keys.1.try_iter().map(Pressed::Char));
        for key in pressed {
            if screen.help.take().is_some() {
                continue;
            }
            match key {
                Pressed::Interrupt | Pressed::Escape => actions.push(Action::Quit),
                Pressed::Char('?') => screen.help = Some(help()),
                Pressed::Char(c) => match Action::key(c) {
                    Some(action) => actions.push(action),
                    None => model.note(
                        model.now,
                        format!("`{c}` is not a key (e d c s b l g r p ? q)"),
                    ),
                },
            }
        }
        if actions.contains(&Action::Quit) {
            break Ok(());
        }
        for action in actions {
            if action == Action::Pause {
                screen.paused = !screen.paused;
                continue;
            }
            match apply(
                &mut network,
                &mut bus,
                &mut model,
                action,
                started.elapsed(),
                &mut seen,
            ) {
                Ok(words) => model.note(model.now, format!("** {words}")),
                // Said on the screen; the run goes on.
                Err(error) => model.note(
                    model.now,
                    format!("** {} did not work: {error:#}", action.name()),
                ),
            }
            if action == Action::Reset {
                seen.notice = None;
            }
        }
        if let Some((at, from)) = seen.press_pending
            && let Some(ms) = press_latency(&network.control.history, at, from)
        {
            seen.press_pending = None;
            seen.latencies_ms.push(ms);
            model.note(
                model.now,
                format!("** emergency stop: node 33's output 0 after {ms:.1} ms"),
            );
        }
        if let Some(restart) = seen.restart.as_mut() {
            match restart.step(network.hub_time(), &network.control.latest, seen.link_cut) {
                Step::Wait(words) => seen.notice = Some(words),
                Step::Start(why) => {
                    if let Some(why) = why {
                        model.note(model.now, format!("** {why}"));
                    }
                    let start = shared::canopen::nmt::command_frame(NmtCommand::Start, 0);
                    match bus.send(&start) {
                        Ok(()) => model.feed(model.now, &start),
                        Err(error) => break Err(error.into()),
                    }
                    seen.notice = Some("reset: NMT start sent".to_owned());
                }
                Step::Done(words, back) => {
                    model.note(model.now, format!("** {words}"));
                    seen.notice = (!back).then_some(words);
                    seen.restart = None;
                }
            }
        }
        if let Some(before) = seen.verdicts_at_reset
            && let Some(srdo) = model.srdos.get(&network::PLAIN)
            && srdo.verdicts.values().sum::<u64>() > before
        {
            seen.verdicts_at_reset = None;
            if let Some((_, PairVerdict::SctExceeded)) = srdo.last_verdict {
                let words = sct_after_reset(srdo.watch.plain, srdo.watch.inverted);
                model.note(model.now, words);
            }
        }
        let mut channels = channel_lines(&network.control.latest);
        if let Some(notice) = &seen.notice {
            channels.push(String::new());
            channels.push(notice.clone());
        }
        match &mut terminal {
            Some(terminal) => {
                if due_to_draw(
                    drawn,
                    (screen.paused, screen.help.is_some()),
                    last_draw.map(|at| at.elapsed()),
                ) {
                    screen.panels = vec![(
                        format!(
                            "Channels (the emulator's status reports; run time {:.1} s)",
                            started.elapsed().as_secs_f64()
                        ),
                        channels,
                    )];
                    if let Err(error) = terminal.draw(&model, &screen) {
                        break Err(error.into());
                    }
                    last_draw = Some(Instant::now());
                    drawn = (screen.paused, screen.help.is_some());
                }
            }
            None => {
                for (at, line) in model.happenings_since(printed) {
                    println!("bus {:>9.3} s  {line}", at.as_secs_f64());
                }
                printed = model.happened;
                if last_print.elapsed() >= Duration::from_millis(500) && channels != last_table {
                    println!(
                        "t = {:.1} s\n{}",
                        started.elapsed().as_secs_f64(),
                        channels.join("\n")
                    );
                    let _ = std::io::stdout().flush();
                    last_print = Instant::now();
                    last_table = channels;
                }
            }
        }
    };
    drop(terminal);
    summary(network, &model, &seen, outcome)
}

fn summary(network: Network, model: &Monitor, seen: &Observed, outcome: Result<()>) -> Result<()> {
    let protocol = network.protocol;
    let [a, b] = network.crcs;
    let latest = network.control.latest.clone();
    let measured = network.measured_summary();
    let pace = network.pace_summary();
    let dir = network.dir().to_path_buf();
    let faults = network.stop()?;
    println!("\n## Summary\n{}", channel_lines(&latest).join("\n"));
    println!("\nOn the bus (the monitor):");
    for line in view::summary(model) {
        println!("  {line}");
    }
    println!();
    for ms in &seen.latencies_ms {
        println!("emergency stop → node 33's output 0: {ms:.1} ms");
    }
    if seen.resets > 0 {
        println!("resets: {}", seen.resets);
    }
    println!(
        "the shipped images, unchanged: channel A image CRC {a:08X}h, channel B {b:08X}h (as \
         `cargo xtask build` sealed them and the emulator read them)"
    );
    println!("{measured}");
    println!("{pace}");
    for (name, lines) in &faults {
        let reports = safe_state_reports(lines);
        if let Some(last) = reports.last() {
            let words = logged_cause_words(last).unwrap_or_else(|| format!("as logged: {last}"));
            println!(
                "{name}: {} safe-state report(s) in its log, the last: {words}",
                reports.len()
            );
        }
    }
    println!(
        "traces: {}/bus.log (candump), bus.pcap; decoded logs: {}/node*.log",
        dir.display(),
        dir.display()
    );
    println!(
        "safety frames in Wireshark: wireshark -X lua_script:{0}/safety.lua {0}/bus.pcap (SRDO pairs, GFC, SimpleCAN CRCs; tshark: -X lua_script:{0}/safety.lua -r {0}/bus.pcap -Y cansafety)",
        dir.display()
    );
    outcome?;
    let ending = match protocol {
        network::Protocol::CanopenSafety => {
            let valid = model.srdos.get(&network::PLAIN).map_or(0, |srdo| {
                srdo.count(safety_config::monitor::model::PairVerdict::Valid)
            });
            ending(&latest, valid, &seen.faults)
        }
        network::Protocol::Simplecan => {
            let packets = model
                .simplecan
                .sc_ids
                .get(&network::ESTOP_SC_ID)
                .map_or(0, |view| view.packets);
            let masters: Vec<u8> = model
                .simplecan
                .masters
                .iter()
                .filter(|(_, master)| master.syncs > 0)
                .map(|(sc_id, _)| *sc_id)
                .collect();
            ending_for(protocol, &latest, packets, &seen.faults, Some(&masters))
        }
    };
    println!("\nHow the run ended: {}", ending.sentence);
    if ending.passed {
        Ok(())
    } else {
        bail!("the run did not end as it should: {}", ending.sentence)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_and_schedules_parse() {
        assert_eq!(parse_duration("30s"), Ok(Duration::from_secs(30)));
        assert_eq!(parse_duration("500ms"), Ok(Duration::from_millis(500)));
        assert_eq!(parse_duration("2m"), Ok(Duration::from_secs(120)));
        assert_eq!(parse_duration("45"), Ok(Duration::from_secs(45)));
        assert!(parse_duration("soon").is_err());
        assert!(parse_duration("5h").unwrap_err().contains("unit"));
        assert_eq!(
            parse_at("5s:press"),
            Ok((Duration::from_secs(5), Action::Press))
        );
        assert!(
            parse_at("5s:explode")
                .unwrap_err()
                .contains("not an action")
        );
        assert!(parse_at("press").unwrap_err().contains("TIME:ACTION"));
    }

    /// A duration too long for `Duration` (or for a run) is a clear error, not a panic, for
    /// `--for` and `--at` alike; the longest accepted is `LONGEST_RUN` itself.
    #[test]
    fn durations_past_the_longest_run_are_refused_with_a_sentence() {
        for text in [
            "100000000000000000000000s",
            "86401s",
            "1441m",
            "999999999999ms",
        ] {
            let error = parse_duration(text).unwrap_err();
            assert!(error.contains("longest run"), "{text}: {error}");
        }
        let error = parse_at("100000000000000000000000s:press").unwrap_err();
        assert!(error.contains("longest run"), "{error}");
        assert_eq!(parse_duration("86400s"), Ok(LONGEST_RUN));
        assert_eq!(parse_duration("1440m"), Ok(LONGEST_RUN));
        for text in ["", "s", ".", "-5s", "NaNs", "infs", "1.2.3s", "1e400"] {
            assert!(parse_duration(text).is_err(), "{text:?}");
        }
    }

    fn statuses(safe: &[(&str, Cause)]) -> HashMap<String, (f64, Status)> {
        network::CHANNELS
            .iter()
            .map(|(name, _, _)| {
                let cause = safe.iter().find(|(n, _)| n == name).map(|(_, c)| *c);
                let status = Status {
                    nmt: NmtState::Operational.heartbeat_code(),
                    working: cause.is_none(),
                    link_up: true,
                    cause: cause.map_or(0, Cause::code),
                    sent: 40,
                    validated: 20,
                    ..Status::default()
                };
                ((*name).to_owned(), (10.0, status))
            })
            .collect()
    }

    /// SC_REQ_26: a SimpleCAN run passes only when node 1 (30h) was the only master the
    /// monitor saw sync; another master's syncs fail it with a sentence naming them, and a
    /// run whose node 33 confirmed no value fails in SimpleCAN's words.
    #[test]
    fn sc_req_26_a_simplecan_run_passes_only_with_node_1_the_only_master() {
        let simplecan = network::Protocol::Simplecan;
        let alone = ending_for(simplecan, &statuses(&[]), 90, &[], Some(&[0x30]));
        assert!(alone.passed, "{alone:?}");
        assert!(
            alone.sentence.contains("SimpleCAN values of 30h"),
            "{alone:?}"
        );
        let two = ending_for(simplecan, &statuses(&[]), 90, &[], Some(&[0x30, 0x38]));
        assert!(!two.passed, "{two:?}");
        assert!(two.sentence.contains("[30, 38]"), "{two:?}");
        let none = ending_for(simplecan, &statuses(&[]), 90, &[], Some(&[]));
        assert!(!none.passed, "{none:?}");
        let mut silent = statuses(&[]);
        for (_, status) in silent.values_mut() {
            status.validated = 0;
        }
        let unconfirmed = ending_for(simplecan, &silent, 0, &[], Some(&[0x30]));
        assert!(!unconfirmed.passed);
        assert!(
            unconfirmed
                .sentence
                .ends_with("node 33 validated no SimpleCAN values of 30h"),
            "{unconfirmed:?}"
        );
    }

    /// The summary says how the run ended from what was observed: all working passes; a
    /// safe state with no fault injected fails and names the channel and the cause in words;
    /// after an injected fault it is the expected reaction.
    #[test]
    fn the_run_ends_with_what_was_observed_not_with_what_was_hoped() {
        let all_well = ending(&statuses(&[]), 90, &[]);
        assert!(all_well.passed, "{all_well:?}");
        assert!(
            all_well
                .sentence
                .starts_with("every channel ended Operational and working")
        );

        let safe = statuses(&[
            ("node1a", Cause::TransmitMismatch),
            ("node33b", Cause::SrvtElapsed),
        ]);
        let unexplained = ending(&safe, 90, &[]);
        assert!(!unexplained.passed);
        assert_eq!(
            unexplained.sentence,
            "FAILED: node1a ended in the safe state (transmit mismatch A/B); node33b ended in \
             the safe state (SRVT elapsed), with no fault injected since the start or the last \
             reset"
        );
        let explained = ending(&safe, 90, &[(Duration::from_secs(5), Action::Drop)]);
        assert!(explained.passed, "{explained:?}");
        assert!(
            explained
                .sentence
                .contains("the safe state after the injected fault(s) (drop at 5.0 s)"),
            "{explained:?}"
        );

        let mut silent = statuses(&[]);
        silent.remove("node33a");
        let never = ending(&silent, 0, &[]);
        assert!(!never.passed);
        assert!(
            never.sentence.contains("node33a never reported"),
            "{never:?}"
        );
    }

    /// Every cause on the channel table is in words (Cause::describe), never a bare code.
    #[test]
    fn the_channel_table_names_every_cause_in_words() {
        for cause in Cause::ALL.into_iter().skip(1) {
            let lines = channel_lines(&statuses(&[("node1b", cause)]));
            let row = lines.iter().find(|l| l.starts_with("node1b")).unwrap();
            assert!(row.ends_with(cause.describe()), "{row}");
            assert!(!row.contains(&format!("{:02X}h", cause.code())), "{row}");
            assert!(row.contains("SAFE"), "{row}");
        }
        let lines = channel_lines(&statuses(&[]));
        assert!(lines[1].ends_with("none"), "{}", lines[1]);
        assert_eq!(cause_words(0xE7), "code E7h, no cause this device knows");
    }

    /// A terminal a person looks at: `tmux` at 120 × 40, the screen read with `capture-pane`.
    struct Tmux {
        session: String,
    }

    impl Tmux {
        fn start(command: &str) -> Tmux {
            let session = format!("xtask-run-view-{}", std::process::id());
            let status = std::process::Command::new("tmux")
                .args([
                    "new-session",
                    "-d",
                    "-s",
                    &session,
                    "-x",
                    "120",
                    "-y",
                    "40",
                    command,
                ])
                .status()
                .expect("tmux is installed");
            assert!(status.success(), "tmux new-session failed");
            Tmux { session }
        }

        fn screen(&self) -> String {
            let output = std::process::Command::new("tmux")
                .args(["capture-pane", "-p", "-t", &self.session])
                .output()
                .expect("tmux capture-pane");
            String::from_utf8_lossy(&output.stdout).into_owned()
        }

        /// The screen once `seen` holds for it, or the last screen after `patience`.
        fn wait_for(&self, patience: Duration, seen: impl Fn(&str) -> bool) -> String {
            let until = Instant::now() + patience;
            loop {
                let screen = self.screen();
                if seen(&screen) || Instant::now() >= until {
                    return screen;
                }
                std::thread::sleep(Duration::from_millis(500));
            }
        }

        fn key(&self, key: &str) {
            let status = std::process::Command::new("tmux")
                .args(["send-keys", "-t", &self.session, key])
                .status()
                .expect("tmux send-keys");
            assert!(status.success());
        }
    }

    impl Drop for Tmux {
        fn drop(&mut self) {
            let _ = std::process::Command::new("tmux")
                .args(["kill-session", "-t", &self.session])
                .status();
        }
    }

    /// The live view as a person sees it (`cargo test -p xtask -- --ignored`): the
    /// channels and nodes Operational, the SRDO pair 101h/102h with its numbers; a dropped
    /// inverted frame (key `d`) puts node 33 in its safe state, named in words; `q` ends the
    /// run, whose summary says the safe state followed the injected fault, and exits 0.
    #[test]
    #[ignore = "starts the emulated network; run with --ignored"]
    fn the_run_view_shows_channels_srdo_pairs_and_a_cause_in_words_and_quits_on_q() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let exit = std::env::temp_dir().join(format!("xtask-run-view-{}.exit", std::process::id()));
        let _ = std::fs::remove_file(&exit);
        let tmux = Tmux::start(&format!(
            "cd {} && cargo xtask run; echo EXIT=$? > {}; sleep 600",
            root.display(),
            exit.display()
        ));
        let up = |screen: &str| {
            screen.contains("Channels (the emulator's status reports")
                && screen.matches("Operational     working").count() == 4
                && screen.contains("101h/102h 1 → 33")
        };
        let screen = tmux.wait_for(Duration::from_secs(900), up);
        assert!(
            up(&screen),
            "the network did not come up on the screen:\n{screen}"
        );
        for channel in ["node1a", "node1b", "node33a", "node33b"] {
            assert!(
                screen
                    .lines()
                    .any(|line| line.starts_with(channel) && line.contains("working")),
                "{channel}:\n{screen}"
            );
        }
        for name in ["emergency stop", "safe output"] {
            assert!(
                screen
                    .lines()
                    .any(|line| line.contains(name) && line.contains("Operational")),
                "node {name:?} Operational:\n{screen}"
            );
        }
        tmux.key("d");
        let tripped =
            |screen: &str| screen.matches("SAFE").count() >= 2 && screen.contains("SRVT elapsed");
        let screen = tmux.wait_for(Duration::from_secs(60), tripped);
        assert!(
            tripped(&screen),
            "no safe state in words after the drop:\n{screen}"
        );
        assert!(
            screen.contains("** the emulated network drops node 1's next inverted frame"),
            "{screen}"
        );
        assert!(
            !screen.contains("02h SRVT"),
            "a bare cause code on the screen:\n{screen}"
        );
        tmux.key("q");
        let ended = tmux.wait_for(Duration::from_secs(120), |_| exit.exists());
        let code = std::fs::read_to_string(&exit).unwrap_or_default();
        assert_eq!(code.trim(), "EXIT=0", "{ended}");
        assert!(
            ended.contains("How the run ended:") && ended.contains("injected fault(s) (drop at"),
            "{ended}"
        );
        let _ = std::fs::remove_file(&exit);
    }

    /// The run survives every key (`cargo test -p xtask -- --ignored`): the link of
    /// node 33 cut (`l`), then a reset (`r`): node 33 does not come back, the run says why in
    /// words and goes on; the link restored (`l` again) and another reset, and both nodes are
    /// Operational and working again; the run ends by `--for` and passes.
    #[test]
    #[ignore = "starts the emulated network; run with --ignored"]
    fn the_run_survives_a_reset_with_the_link_cut_and_comes_back_once_it_is_restored() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let output = std::process::Command::new(env!("CARGO"))
            .current_dir(&root)
            .args(["xtask", "run", "--for", "40s"])
            .args([
                "--at", "5s:l", "--at", "8s:r", "--at", "24s:l", "--at", "27s:r",
            ])
            .stdin(std::process::Stdio::null())
            .output()
            .expect("cargo xtask run");
        let stdout = String::from_utf8_lossy(&output.stdout);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(output.status.success(), "{stdout}\n{stderr}");
        let position = |text: &str| {
            stdout
                .find(text)
                .unwrap_or_else(|| panic!("{text:?} not in\n{stdout}"))
        };
        let cut = position("** the link between node 33's channels is cut");
        let not_back = position("** node 33 did not come back within 10 s of NMT start");
        let why = position("the link between its channels is cut, and a node boots");
        let restored = position("** the link between node 33's channels is restored");
        let back = position("** both nodes Operational and working again after the reset");
        assert!(cut < not_back && not_back < why && why < restored && restored < back);
        assert!(
            stdout.contains("How the run ended: every channel ended Operational and working"),
            "{stdout}"
        );
    }

    /// One safe state logged as the channel's fault and the core's latch counts once.
    #[test]
    fn a_fault_and_the_safe_state_it_caused_are_one_report() {
        let lines: Vec<String> = [
            "INFO  Fault(ChannelFault { cause: LinkLost })",
            "INFO  Node(SafeState(Application { detail: 48 }))",
        ]
        .map(str::to_owned)
        .into();
        assert_eq!(
            safe_state_reports(&lines),
            ["INFO  Node(SafeState(Application { detail: 48 }))"]
        );
        let only_fault = vec!["INFO  Fault(ChannelFault { cause: LinkLost })".to_owned()];
        assert_eq!(safe_state_reports(&only_fault).len(), 1);
    }

    /// The safe-state lines of the channels' logs read in words, from Cause's one table.
    #[test]
    fn a_logged_safe_state_reads_in_words() {
        use shared::safety::srdo::SrdoFaultCause;
        let cases = [
            (
                "INFO  Node(SafeState(Application { detail: 48 }))",
                "transmit mismatch A/B",
            ),
            (
                "INFO  Node(SafeState(Srdo(SrdoFault { srdo: SrdoNumber(1), cause: SrvtElapsed })))",
                "SRDO 1: SRVT elapsed",
            ),
            ("INFO  Node(SafeState(Gfc))", "GFC"),
            (
                "INFO  Node(SafeState(Integrity(Runtime(SrdoNumber(2)))))",
                "configuration in use damaged (SRDO runtime)",
            ),
        ];
        for (line, words) in cases {
            assert_eq!(logged_cause_words(line).as_deref(), Some(words), "{line}");
        }
        assert_eq!(logged_cause_words("INFO  something else"), None);
        // Every SRDO fault's name is its Cause's name, so the log reads in Cause's words.
        for fault in [
            SrdoFaultCause::SctElapsed,
            SrdoFaultCause::SrvtElapsed,
            SrdoFaultCause::PlainRepeated,
            SrdoFaultCause::NotInverted,
            SrdoFaultCause::TooShort,
            SrdoFaultCause::TransmitHalvesNotInverted,
        ] {
            let line =
                format!("SafeState(Srdo(SrdoFault {{ srdo: SrdoNumber(3), cause: {fault:?} }}))");
            assert_eq!(
                logged_cause_words(&line),
                Some(format!("SRDO 3: {}", fault.cause().describe())),
                "{fault:?}"
            );
        }
    }

    /// Every key of the live view can be scheduled (`--at 5s:l`), as the same action the key
    /// does; a letter that is no key, or a name that is no action, is refused with a sentence.
    #[test]
    fn every_key_of_the_run_can_be_scheduled_with_at() {
        for (text, action) in [
            ("5s:l", Action::ToggleLink),
            ("5s:r", Action::Reset),
            ("5s:e", Action::Toggle),
            ("5s:p", Action::Pause),
            ("5s:q", Action::Quit),
            ("5s:restore-link", Action::RestoreLink),
            ("5s:cut-link", Action::CutLink),
        ] {
            assert_eq!(
                parse_at(text),
                Ok((Duration::from_secs(5), action)),
                "{text}"
            );
        }
        assert!(parse_at("5s:x").unwrap_err().contains("not a key"));
        // Each key's action names itself back in the form `--at` takes.
        for key in "edcsblgrpq".chars() {
            let action = Action::key(key).unwrap();
            assert_eq!(Action::named(action.name()), Ok(action), "{key}");
        }
    }

    fn restart_statuses(node33: (NmtState, bool, bool, Cause)) -> HashMap<String, (f64, Status)> {
        let mut latest = statuses(&[]);
        let (nmt, working, link_up, cause) = node33;
        for name in ["node33a", "node33b"] {
            let status = &mut latest.get_mut(name).unwrap().1;
            status.nmt = nmt.heartbeat_code();
            status.working = working;
            status.link_up = link_up;
            status.cause = cause.code();
        }
        latest
    }

    fn boot_up(node: u16) -> CanFrame {
        CanFrame::new(shared::CanId::new(0x700 + node).unwrap(), &[0]).unwrap()
    }

    /// CiA 301 7.3.2.2.1 (NMT reset node: boot-up, then Pre-operational until NMT start): a
    /// reset waits for both nodes' boot-up messages, then has NMT start sent, then waits for
    /// every channel Operational and working, and is over; what it waits for is said in words
    /// meanwhile.
    #[test]
    fn cia301_7_3_2_a_reset_starts_the_nodes_once_both_booted_and_ends_when_they_work() {
        let mut restart = Restart::new(20.0);
        let down = restart_statuses((NmtState::PreOperational, true, true, Cause::None));
        let Step::Wait(words) = restart.step(20.5, &down, false) else {
            panic!("waits for the boot-ups");
        };
        assert_eq!(
            words,
            "reset: waiting for the boot-up of nodes 1 and 33 (0.5 s)"
        );
        restart.frame(&boot_up(0x21));
        restart.frame(&boot_up(0x01));
        assert_eq!(restart.step(20.6, &down, false), Step::Start(None));
        assert!(matches!(restart.step(21.0, &down, false), Step::Wait(words)
            if words.contains("waiting for node 33 to be Operational and working")));
        let up = statuses(&[]);
        assert_eq!(
            restart.step(21.2, &up, false),
            Step::Done(
                "both nodes Operational and working again after the reset".to_owned(),
                true
            )
        );
    }

    /// A node whose link is cut does not work after a reset (its channels go to the safe
    /// state with "link silent"): the reset ends after its patience on the network's time
    /// with a sentence naming the node, each channel's state and cause in words, and the cut
    /// link with what to do; the run goes on (no error). A node that sends no boot-up is
    /// started all the same, and said so.
    #[test]
    fn cia301_7_3_2_a_node_that_does_not_come_back_after_a_reset_says_why_in_words() {
        let mut restart = Restart::new(0.0);
        restart.frame(&boot_up(0x01));
        let cut = restart_statuses((NmtState::Operational, false, false, Cause::LinkTimeout));
        let Step::Start(Some(words)) = restart.step(RESTART_PATIENCE, &cut, true) else {
            panic!("started all the same");
        };
        assert!(
            words.starts_with("no boot-up from node 33 within 10 s"),
            "{words}"
        );
        assert!(words.contains("NMT start sent all the same"), "{words}");
        assert!(matches!(restart.step(15.0, &cut, true), Step::Wait(_)));
        let Step::Done(words, false) = restart.step(20.0, &cut, true) else {
            panic!("over, not back");
        };
        assert_eq!(
            words,
            format!(
                "node 33 did not come back within 10 s of NMT start: node 33: node33a \
                 Operational, in the safe state ({cause}), node33b Operational, in the safe \
                 state ({cause}); the link between its channels is cut, and a node boots and \
                 works only with both channels talking (l restores the link, then r)",
                cause = Cause::LinkTimeout.describe()
            )
        );
    }

    /// The emergency stop's latency is read from the channels' reports after the press: the
    /// later of node 33's two channels' first report of output 0, less the press's hub time;
    /// none until both reported it.
    #[test]
    fn the_emergency_stops_latency_is_the_later_channel_of_node_33_reporting_output_0() {
        let report = |name: &str, t: f64, output: u8| {
            (
                name.to_owned(),
                t,
                Status {
                    output,
                    ..Status::default()
                },
            )
        };
        let mut history = vec![report("node33a", 9.0, 0), report("node33b", 10.01, 1)];
        assert_eq!(press_latency(&history, 10.0, 0), None, "before the press");
        history.push(report("node33a", 10.02, 0));
        assert_eq!(press_latency(&history, 10.0, 0), None, "only channel A");
        history.push(report("node33b", 10.025, 0));
        history.push(report("node33a", 10.03, 0));
        let ms = press_latency(&history, 10.0, 0).unwrap();
        assert!((ms - 25.0).abs() < 1e-6, "{ms}");
    }

    /// `p` shows that the drawing is paused: pausing draws the screen once more (its title
    /// then says PAUSED), and nothing more is drawn until it resumes, which draws at once;
    /// help appearing or going is drawn at once too.
    #[test]
    fn pausing_draws_once_to_say_so_then_keeps_the_picture() {
        let soon = Some(Duration::from_millis(10));
        let later = Some(Duration::from_secs(5));
        assert!(
            due_to_draw((false, false), (false, false), None),
            "the first picture"
        );
        assert!(!due_to_draw((false, false), (false, false), soon));
        assert!(due_to_draw((false, false), (false, false), later));
        assert!(
            due_to_draw((false, false), (true, false), soon),
            "pausing is drawn"
        );
        assert!(
            !due_to_draw((true, false), (true, false), later),
            "then kept"
        );
        assert!(
            due_to_draw((true, false), (false, false), soon),
            "resuming is drawn"
        );
        assert!(
            due_to_draw((true, false), (true, true), soon),
            "help while paused"
        );
    }

    /// The live run's monitor judges heartbeats as a consumer with twice the devices'
    /// producer time would (CiA 301 7.2.8.3.2.2).
    #[test]
    fn cia301_7_2_8_3_2_2_the_runs_heartbeat_consumer_time_is_twice_the_producer_time() {
        let id = shared::canopen::node_id::NodeId::new(33).unwrap();
        let producer = safety_device::config(id, "").heartbeat_ms;
        assert_eq!(
            heartbeat_consumer_time(),
            Duration::from_millis(2 * u64::from(producer))
        );
    }

    /// An action scheduled at or after the end of an unattended run would never happen: refused.
    #[test]
    fn a_scheduled_action_after_the_end_of_the_run_is_refused() {
        let press = (Duration::from_secs(8), Action::Press);
        assert_eq!(
            check_schedule(Some(Duration::from_secs(20)), &[press]),
            Ok(())
        );
        assert_eq!(check_schedule(None, &[press]), Ok(()));
        let error = check_schedule(Some(Duration::from_secs(5)), &[press]).unwrap_err();
        assert!(error.contains("after the run ends"), "{error}");
    }
}
