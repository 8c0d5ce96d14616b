//! `cargo xtask run`: the main job. The emulated safety network ([`Network`]) with a live
//! view of every channel, an emergency stop and faults at the keyboard, and a summary.
//!
//! Keys (type the letter and press Enter): `e` press or release the emergency stop on node
//! 1, `d` drop node 1's next inverted frame, `c` corrupt its next plain frame, `s` stop node
//! 1 (both channels muted), `b` channel B of node 1 reads the input otherwise, `l` cut the
//! link between node 33's channels, `r` reset both nodes (NMT reset node, then start), `q`
//! quit. Unattended: `--for 30s` ends the run and `--at 5s:press` (and `release`, `drop`,
//! `corrupt`, `stop`, `b-differs`, `cut-link`, `reset`) schedules the same actions.

use crate::e2e;
use crate::network::{self, Network};
use anyhow::{Result, bail};
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
    /// Cut node 33's link.
    CutLink,
    /// Reset both nodes and start them.
    Reset,
    /// End the run.
    Quit,
}

impl Action {
    /// A scheduled action's name (`--at 5s:press`).
    pub fn named(name: &str) -> Result<Action, String> {
        Ok(match name {
            "press" => Action::Press,
            "release" => Action::Release,
            "drop" => Action::Drop,
            "corrupt" => Action::Corrupt,
            "stop" => Action::Stop,
            "b-differs" => Action::BDiffers,
            "cut-link" => Action::CutLink,
            "reset" => Action::Reset,
            _ => {
                return Err(format!(
                    "`{name}` is not an action (press, release, drop, corrupt, stop, b-differs, \
                     cut-link, reset)"
                ));
            }
        })
    }

    fn key(line: &str) -> Option<Action> {
        Some(match line.trim() {
            "e" => Action::Toggle,
            "d" => Action::Drop,
            "c" => Action::Corrupt,
            "s" => Action::Stop,
            "b" => Action::BDiffers,
            "l" => Action::CutLink,
            "r" => Action::Reset,
            "q" => Action::Quit,
            _ => return None,
        })
    }
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
            "--at {:.3}s ({action:?}) is at or after the run ends (--for {:.3}s): it would never happen",
            at.as_secs_f64(),
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

/// What the run observed, for the summary.
#[derive(Default)]
struct Observed {
    latencies_ms: Vec<f64>,
    pressed: bool,
}

fn apply(network: &mut Network, action: Action, seen: &mut Observed) -> Result<()> {
    let action = match action {
        Action::Toggle if seen.pressed => Action::Release,
        Action::Toggle => Action::Press,
        other => other,
    };
    match action {
        Action::Press => {
            let ms = e2e::press(network)?;
            println!("** emergency stop pressed: node 33's output 0 after {ms:.1} ms");
            seen.latencies_ms.push(ms);
            seen.pressed = true;
        }
        Action::Release => {
            network.command("input node1a 1")?;
            network.command("input node1b 1")?;
            println!("** emergency stop released");
            seen.pressed = false;
        }
        Action::Drop => {
            network.command(&format!("drop 0x{:03X}", network::INVERTED))?;
            println!("** the hub drops node 1's next inverted frame");
        }
        Action::Corrupt => {
            network.command(&format!("corrupt 0x{:03X} 0 0x01", network::PLAIN))?;
            println!(
                "** the hub corrupts byte 0 of node 1's next plain frame (node 1's channel B \
                 sees it too and withholds the inverted frame)"
            );
        }
        Action::Stop => {
            network.command("mute node1a")?;
            network.command("mute node1b")?;
            println!("** node 1 stopped (both channels muted)");
        }
        Action::BDiffers => {
            network.command("input node1b 0")?;
            println!("** channel B of node 1 now reads its input as 0, channel A as 1");
        }
        Action::CutLink => {
            network.command("cut node33-link")?;
            println!("** the link between node 33's channels is cut");
        }
        Action::Reset => {
            println!("** NMT reset node for both nodes, then start");
            network.reset()?;
            seen.pressed = false;
        }
        Action::Toggle | Action::Quit => {}
    }
    Ok(())
}

/// `cargo xtask run`.
pub fn task(
    root: &std::path::Path,
    duration: Option<Duration>,
    mut schedule: Vec<(Duration, Action)>,
) -> Result<()> {
    check_schedule(duration, &schedule).map_err(anyhow::Error::msg)?;
    let interrupted = Arc::new(AtomicBool::new(false));
    {
        let interrupted = interrupted.clone();
        // Ctrl-C or SIGTERM: end the run; the network's drop kills every child process.
        ctrlc::set_handler(move || interrupted.store(true, Ordering::SeqCst))?;
    }
    let interactive = duration.is_none() && std::io::stdin().is_terminal();
    let live = std::io::stdout().is_terminal();
    let mut network = Network::start(root)?;
    let started = Instant::now();
    schedule.sort_by_key(|(at, _)| *at);
    let mut schedule = schedule.into_iter().peekable();
    let keys = mpsc::channel();
    if interactive {
        let tx = keys.0.clone();
        std::thread::spawn(move || {
            for line in std::io::stdin().lock().lines() {
                let Ok(line) = line else { return };
                if tx.send(line).is_err() {
                    return;
                }
            }
        });
        println!(
            "Keys (then Enter): e emergency stop, d drop, c corrupt, s stop node 1, \
             b channel B differs, l cut node 33's link, r reset, q quit"
        );
    } else if duration.is_none() {
        bail!("not on a terminal: give `--for <duration>` to run unattended");
    }
    let mut seen = Observed::default();
    let mut last_print = Instant::now() - Duration::from_secs(1);
    let mut last_table = String::new();
    let outcome = loop {
        if interrupted.load(Ordering::SeqCst) {
            println!("** interrupted");
            break Ok(());
        }
        if duration.is_some_and(|d| started.elapsed() >= d) {
            break Ok(());
        }
        if let Err(error) = network.control.watch(Duration::from_millis(100)) {
            break Err(error.into());
        }
        if let Err(error) = network.check_alive() {
            break Err(error);
        }
        let mut actions = Vec::new();
        while let Some((_, action)) = schedule.next_if(|(at, _)| started.elapsed() >= *at) {
            actions.push(action);
        }
        while let Ok(line) = keys.1.try_recv() {
            match Action::key(&line) {
                Some(action) => actions.push(action),
                None => println!("?? `{}` is not a key (e d c s b l r q)", line.trim()),
            }
        }
        if actions.contains(&Action::Quit) {
            break Ok(());
        }
        if let Some(error) = actions
            .into_iter()
            .find_map(|action| apply(&mut network, action, &mut seen).err())
        {
            break Err(error);
        }
        let table = network.table();
        if last_print.elapsed() >= Duration::from_millis(500) && table != last_table {
            if live {
                print!("\x1b[2J\x1b[H");
            }
            println!("t = {:.1} s\n{table}", started.elapsed().as_secs_f64());
            let _ = std::io::stdout().flush();
            last_print = Instant::now();
            last_table = table;
        }
    };
    summary(network, &seen, outcome)
}

fn summary(network: Network, seen: &Observed, outcome: Result<()>) -> Result<()> {
    let latest = network.control.latest.clone();
    let stall = network.worst(|s| s.longest_stall_ms);
    let pace = network.pace_summary();
    let dir = network.dir().to_path_buf();
    let faults = network.stop()?;
    println!("\n## Summary\n{}", network::table(&latest));
    for ms in &seen.latencies_ms {
        println!("emergency stop → node 33's output 0: {ms:.1} ms");
    }
    println!("longest stall of an emulated MCU (host time it did not run): {stall} ms");
    println!("{pace}");
    for (name, lines) in &faults {
        if let Some(last) = lines.last() {
            println!("{name}: {} safe-state report(s), last: {last}", lines.len());
        }
    }
    println!(
        "traces: {}/bus.log (candump), bus.pcap; decoded logs: {}/node*.log",
        dir.display(),
        dir.display()
    );
    outcome?;
    let sent = |name: &str| latest.get(name).is_some_and(|(_, s)| s.sent > 0);
    let validated = |name: &str| latest.get(name).is_some_and(|(_, s)| s.validated > 0);
    if sent("node1a") && sent("node1b") && validated("node33a") && validated("node33b") {
        println!("every node reached Operational and exchanged valid SRDOs");
        Ok(())
    } else {
        bail!("the nodes did not exchange valid SRDOs")
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
