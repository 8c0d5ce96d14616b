//! `cargo xtask spin`: the SPIN model of the two channels' protocol
//! (`dual-channel/model/dual_channel.pml`) checked exhaustively within its bounds, and each
//! past race re-introduced by its mutation switch shown to be found where the unmodified
//! model is not at fault.
//!
//! Every run copies the model to `target/spin/<run>/`, generates the verifier (`spin -a`),
//! compiles it with gcc and runs it; the state count, depth, memory and time it reports are
//! printed, and written into the generated sections of `docs/model-checking.md` by the
//! command that measured them (`--report` for the CI size, always for `--full` and
//! `--liveness`). A check fails on any error, and on a search that was not complete (memory
//! bound, depth bound, time limit). A mutation is checked at bounds where the unmodified model
//! passes (that control run comes first and must pass); it fails when the verifier finds
//! nothing, or when what it found (replayed with `spin -t` and printed as the model's
//! sequence of events) does not show the race.

use anyhow::{Context, Result, bail};
use std::collections::BTreeSet;
use std::path::Path;
use std::process::Command;

/// The model, relative to the repository's root.
const MODEL: &str = "dual-channel/model/dual_channel.pml";

/// The document whose generated sections record the runs' figures.
const REPORT: &str = "docs/model-checking.md";

/// What `cargo xtask spin` checks.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Mode {
    /// The CI size: the fault-free model, and every mutation with its control.
    Ci,
    /// Bigger bounds, every fault class, a late channel loop (safety).
    Full,
    /// Recovery after the faults under weak fairness (LTL).
    Liveness,
}

impl Mode {
    /// The option that selects the mode, as the generated section names it.
    fn command(self) -> &'static str {
        match self {
            Mode::Ci => "cargo xtask spin",
            Mode::Full => "cargo xtask spin --full",
            Mode::Liveness => "cargo xtask spin --liveness",
        }
    }
}

/// An environment the model is checked in: its bounds as `-D` flags for spin.
struct Bounds {
    /// Its name (and the control run's directory under target/spin).
    name: &'static str,
    /// What the environment may do, in words.
    what: &'static str,
    /// `-D` flags for spin.
    defines: &'static [&'static str],
    /// The memory its verifier may use, in MB (pan's `-DMEMLIM`).
    memory: u32,
}

/// The CI bounds: after the power-on start one NMT reset and one start (the master waits a
/// tick after the reset), one input change, no fault.
const FAULT_FREE: Bounds = Bounds {
    name: "fault-free",
    what: "one NMT reset and start a tick apart, one input change, no fault",
    defines: &[
        "-DNMT_BUDGET=2",
        "-DINPUT_BUDGET=1",
        "-DSTART_AFTER_RESET_T=1",
        "-DFAULT_BUDGET=0",
    ],
    memory: MEMORY_MB,
};

/// Channel B of the producer handles its bus frames up to a tick late (a slow loop), around
/// one NMT reset and start at once; the master's NMT frames may overtake channel A's plain
/// frame (the reset trails of docs/model-checking.md); no input change (the slow-loop
/// artefact under Limits).
const LATE_B: Bounds = Bounds {
    name: "late-b",
    what: "channel B's bus frames up to a tick late; one NMT reset and start at once, the NMT \
           frames overtaking A's plain frame or not; no input change, no fault",
    defines: &[
        "-DNMT_BUDGET=2",
        "-DINPUT_BUDGET=0",
        "-DSTART_AFTER_RESET_T=0",
        "-DFAULT_BUDGET=0",
        "-DLATE_LOOPS=2",
    ],
    memory: MEMORY_MB,
};

/// Channel B late as in [`LATE_B`], the nodes left Pre-operational at power-on and the master
/// sending reset and start at once: channel A's first announcement of the new epoch reaches
/// channel B before B's own NMT frames. Channel A sends no plain frame before the reset, so
/// no frame of an ended epoch is late at B (the late-loop finding of docs/model-checking.md).
const LATE_B_FIRST_START: Bounds = Bounds {
    name: "late-b-first-start",
    what: "channel B's bus frames up to a tick late; from Pre-operational, NMT reset and start \
           at once; no input change, no fault",
    defines: &[
        "-DSTARTED=0",
        "-DNMT_BUDGET=2",
        "-DINPUT_BUDGET=0",
        "-DSTART_AFTER_RESET_T=0",
        "-DFAULT_BUDGET=0",
        "-DLATE_LOOPS=2",
    ],
    memory: MEMORY_MB,
};

/// The master starts right after its reset (the cut pair's inverted frame reaches channel A
/// in Operational only then); its NMT frames may overtake channel A's plain frame (the reset
/// trails of docs/model-checking.md); no input change ([`START_AT_ONCE_INPUT_CHANGE`] has
/// one).
const START_AT_ONCE: Bounds = Bounds {
    name: "start-at-once",
    what: "one NMT reset and start at once, the NMT frames overtaking A's plain frame or not; \
           no input change, no fault",
    defines: &[
        "-DNMT_BUDGET=2",
        "-DINPUT_BUDGET=0",
        "-DSTART_AFTER_RESET_T=0",
        "-DFAULT_BUDGET=0",
    ],
    memory: MEMORY_MB,
};

/// The master starts right after its reset, with an input change, its NMT frames
/// overtaking channel A's plain frame or not: a half of the pair the reset cut meets the
/// consumer's first pair after the start, and channel B may take A's frame of the ended epoch
/// and A's first of the new one before their announcements (the two findings after the reset
/// trails in docs/model-checking.md). The consumer's link delivers within the tick, and the
/// search needs more memory than the other CI runs ([`MEMORY_WIDE_MB`]).
const START_AT_ONCE_INPUT_CHANGE: Bounds = Bounds {
    name: "start-at-once-input-change",
    what: "one NMT reset and start at once, the NMT frames overtaking A's plain frame or not, \
           one input change, the consumer's link within the tick, no fault (`-DMEMLIM=4000`, \
           `-w26`)",
    defines: &[
        "-DNMT_BUDGET=2",
        "-DINPUT_BUDGET=1",
        "-DSTART_AFTER_RESET_T=0",
        "-DFAULT_BUDGET=0",
        "-DC_LATENCY_T=0",
    ],
    memory: MEMORY_WIDE_MB,
};

/// A past race, re-introduced by a switch of the model.
struct Mutation {
    /// Its name (and directory under target/spin).
    name: &'static str,
    /// The model's switch.
    switch: &'static str,
    /// The race, in words.
    race: &'static str,
    /// Where the unmodified model passes and the mutation is found.
    bounds: &'static Bounds,
    /// A line of the replayed counterexample that shows the race (the property it breaks,
    /// or the channel that reports it), so that another error is not taken for it.
    expect: &'static str,
}

/// Each past race re-introduced, with the bounds it is found at and what shows it.
const MUTATIONS: [Mutation; 8] = [
    Mutation {
        name: "mutation-cosign-before-reset",
        switch: "-DMUTATION_COSIGN_BEFORE_RESET",
        race: "channel B keeps, across its NMT reset, a plain frame it saw before, and acts \
               on it after",
        bounds: &LATE_B,
        expect: "PROPERTY reset",
    },
    Mutation {
        name: "mutation-forget-ended-epoch",
        switch: "-DMUTATION_FORGET_ENDED_EPOCH",
        race: "channel A's announcements of its ended epoch forgotten at its reset, and a frame \
               channel B saw before its own reset forgotten there: a plain frame queued at the \
               reset and reaching the bus after it is foreign to channel B",
        bounds: &START_AT_ONCE,
        expect: "PROPERTY availability: ch1 safe, cause 5",
    },
    Mutation {
        name: "mutation-drop-announcements",
        switch: "-DMUTATION_DROP_ANNOUNCEMENTS",
        race: "announcements dropped across NMT epochs: channel A's first announcement after \
               the reset and start, reaching channel B before B's own NMT frames",
        bounds: &LATE_B_FIRST_START,
        expect: "PROPERTY availability: ch1 safe, cause 5",
    },
    Mutation {
        name: "mutation-cut-pair-foreign",
        switch: "-DMUTATION_CUT_PAIR_FOREIGN",
        race: "the inverted frame of a pair cut by a reset taken as foreign",
        bounds: &START_AT_ONCE,
        expect: "ch0: foreign frame on our identifiers",
    },
    Mutation {
        name: "mutation-stale-confirmation",
        switch: "-DMUTATION_STALE_CONFIRMATION",
        race: "a stale confirmation switching an output back on",
        bounds: &FAULT_FREE,
        expect: "PROPERTY output",
    },
    Mutation {
        name: "mutation-keep-announcements",
        switch: "-DMUTATION_KEEP_ANNOUNCEMENTS",
        race: "announcements of an ended epoch kept: channel B co-signs A's frame against the \
               announcement of another (and flags A's own frame as foreign when the data \
               differ)",
        bounds: &LATE_B,
        expect: "PROPERTY co-sign",
    },
    Mutation {
        name: "mutation-first-pair-strict",
        switch: "-DMUTATION_FIRST_PAIR_STRICT",
        race: "the consumer's first pair after its start judged as strictly as later ones: the \
               inverted frame of the pair the producer's reset cut, behind A's first plain \
               frame of the new epoch, is not its inverse",
        bounds: &START_AT_ONCE_INPUT_CHANGE,
        expect: "safe, cause 9, no fault",
    },
    Mutation {
        name: "mutation-second-unannounced-foreign",
        switch: "-DMUTATION_SECOND_UNANNOUNCED_FOREIGN",
        race: "channel B, between its reset and A's heartbeat of the new epoch, takes a second \
               plain frame with other data before the first one's announcement for foreign \
               (A's frame of the ended epoch, then A's first of the new one)",
        bounds: &START_AT_ONCE_INPUT_CHANGE,
        expect: "PROPERTY availability: ch1 safe, cause 5",
    },
];

/// The bounds of `--full`: from Pre-operational with the contacts open, three NMT commands,
/// two input changes; each fault class once in its own run.
const FULL: &[&str] = &[
    "-DNMT_BUDGET=3",
    "-DINPUT_BUDGET=2",
    "-DSTARTED=0",
    "-DINITIAL_INPUT=0",
    "-DSTART_AFTER_RESET_T=1",
];

/// The minutes each `--full` run may take by default (six runs; the two largest searches
/// take minutes, the others seconds).
pub const FULL_MINUTES: u32 = 15;

/// The minutes each liveness run may take by default (two runs, the first short).
pub const LIVENESS_MINUTES: u32 = 20;

/// The memory the verifier may use, in MB (pan's `-DMEMLIM`): within a CI runner's.
const MEMORY_MB: u32 = 3000;

/// The memory of the CI run whose search is larger than the others', in MB: the CI machine's
/// has room for it.
const MEMORY_WIDE_MB: u32 = 4000;

/// The memory a `--full` or `--liveness` run may use, in MB, unless `--memory` gives another:
/// these are documented commands for a workstation (16 GB), not CI runs; the searches of
/// `full-fault-free` and `recovery-input-change` need more than 6000 MB to complete.
const MEMORY_FULL_MB: u32 = 14000;

/// pan's hash table for a search given `memory` MB: 2^24 slots hold the CI size's states (its
/// memory counts), 2^26 up to 8000 MB, 2^27 beyond (a fuller table costs collisions, not
/// correctness: the search is exhaustive either way).
fn hash_slots(memory: u32) -> u32 {
    if memory <= MEMORY_MB {
        24
    } else if memory <= 8000 {
        26
    } else {
        27
    }
}

/// One run of the verifier.
struct Run {
    /// Its name (and directory under target/spin).
    name: String,
    /// What it checks, in words.
    what: String,
    /// `-D` flags for spin (the model's bounds and switches).
    defines: Vec<&'static str>,
    /// The LTL property to check under weak fairness, if any (otherwise assertions only).
    ltl: Option<&'static str>,
    /// For a mutation: a line of the replayed counterexample that shows the race; `None`:
    /// the unmodified model, which must pass.
    expect: Option<&'static str>,
    /// The memory its verifier may use, in MB, where it is not the mode's.
    memory: Option<u32>,
}

/// What the verifier reported.
#[derive(Debug)]
struct Outcome {
    errors: u64,
    states: u64,
    depth: u64,
    memory_mb: f64,
    seconds: f64,
    /// Why the search stopped before it was complete, if it did.
    stopped: Option<&'static str>,
}

/// The runs of `mode`.
fn runs(mode: Mode) -> Vec<Run> {
    let check = |name: &str, what: &str, defines: Vec<&'static str>| Run {
        name: name.to_string(),
        what: what.to_string(),
        defines,
        ltl: None,
        expect: None,
        memory: None,
    };
    // The full bounds with `extra`, each of which replaces the flag of its name.
    let full = |extra: &[&'static str]| {
        let name = |define: &str| define.split('=').next().unwrap_or_default().to_string();
        let mut defines: Vec<&'static str> = FULL
            .iter()
            .copied()
            .filter(|define| !extra.iter().any(|other| name(other) == name(define)))
            .collect();
        defines.extend_from_slice(extra);
        defines
    };
    // A fault class once: the nodes started at power-on with the contacts closed (the
    // outputs run, so that the fault has something to stop), no NMT command.
    let fault = |class: &'static str| {
        full(&[
            "-DSTARTED=1",
            "-DINITIAL_INPUT=1",
            "-DNMT_BUDGET=0",
            "-DFAULT_BUDGET=1",
            class,
        ])
    };
    match mode {
        Mode::Ci => {
            let mut runs = Vec::new();
            let mut checked = BTreeSet::new();
            for bounds in std::iter::once(&FAULT_FREE).chain(MUTATIONS.iter().map(|m| m.bounds)) {
                if checked.insert(bounds.name) {
                    runs.push(Run {
                        memory: Some(bounds.memory),
                        ..check(
                            bounds.name,
                            &format!("no error, no safe state: {}", bounds.what),
                            bounds.defines.to_vec(),
                        )
                    });
                }
            }
            for mutation in &MUTATIONS {
                let mut defines = mutation.bounds.defines.to_vec();
                defines.push(mutation.switch);
                runs.push(Run {
                    name: mutation.name.to_string(),
                    what: format!(
                        "{} (found at the bounds of `{}`)",
                        mutation.race, mutation.bounds.name
                    ),
                    defines,
                    ltl: None,
                    expect: Some(mutation.expect),
                    memory: Some(mutation.bounds.memory),
                });
            }
            runs
        }
        Mode::Full => vec![
            check(
                "full-fault-free",
                "safety and availability without faults",
                full(&["-DFAULT_BUDGET=0"]),
            ),
            check(
                "full-start-at-once-input-change",
                "safety and availability without faults: one NMT reset and start at once, the \
                 NMT frames overtaking A's plain frame or not, one input change, the consumer's \
                 link a tick late (the CI run `start-at-once-input-change` has it within the \
                 tick)",
                vec![
                    "-DNMT_BUDGET=2",
                    "-DINPUT_BUDGET=1",
                    "-DSTART_AFTER_RESET_T=0",
                    "-DFAULT_BUDGET=0",
                ],
            ),
            check(
                "full-foreign-frame",
                "safety with a foreign frame on the producer's identifiers (started at \
                 power-on, contacts closed, no NMT command)",
                fault("-DFAULTS=1"),
            ),
            check(
                "full-loss",
                "safety with a lost bus frame or link message (started at power-on, contacts \
                 closed, no NMT command)",
                fault("-DFAULTS=2"),
            ),
            check(
                "full-stuck-contact",
                "safety with a contact stuck (started at power-on, contacts closed, no NMT \
                 command)",
                fault("-DFAULTS=4"),
            ),
            check(
                "full-late-b",
                "safety and availability with channel B's bus frames up to a tick late, \
                 no input change (the slow-loop artefact), the NMT frames not overtaking A's \
                 plain frame",
                full(&[
                    "-DINPUT_BUDGET=0",
                    "-DFAULT_BUDGET=0",
                    "-DLATE_LOOPS=2",
                    "-DRESET_NOT_OVERTAKING",
                ]),
            ),
        ],
        Mode::Liveness => {
            let recovery = |name: &str, what: &str, inputs: &'static str| Run {
                name: name.to_string(),
                what: format!(
                    "liveness (weak fairness): after one fault of any class{what}, the contacts \
                     repaired, NMT reset and start, both nodes Operational with a confirmed pair"
                ),
                defines: vec![
                    "-DLIVENESS",
                    "-DNMT_BUDGET=0",
                    inputs,
                    "-DFAULT_BUDGET=1",
                    "-DSTART_AFTER_RESET_T=1",
                ],
                ltl: Some("recovers"),
                expect: None,
                memory: None,
            };
            vec![
                recovery("recovery", "", "-DINPUT_BUDGET=0"),
                recovery(
                    "recovery-input-change",
                    " and one input change",
                    "-DINPUT_BUDGET=1",
                ),
            ]
        }
    }
}

/// `cargo xtask spin [--full | --liveness] [--report] [--minutes N] [--memory MB]`:
/// `minutes` bounds each verifier run (`None`: no bound at the CI size, the defaults above
/// otherwise); `memory` (MB) replaces [`MEMORY_FULL_MB`] for `--full` and `--liveness`.
pub fn task(
    root: &Path,
    mode: Mode,
    report: bool,
    minutes: Option<u32>,
    memory: Option<u32>,
) -> Result<()> {
    crate::toolchain::ensure_spin()?;
    let minutes = minutes.or(match mode {
        Mode::Ci => None,
        Mode::Full => Some(FULL_MINUTES),
        Mode::Liveness => Some(LIVENESS_MINUTES),
    });
    let memory = if mode == Mode::Ci {
        if memory.is_some() {
            bail!("--memory is for --full and --liveness; the CI size keeps its bounds");
        }
        MEMORY_MB
    } else {
        memory.unwrap_or(MEMORY_FULL_MB)
    };
    let mut rows = Vec::new();
    let mut failures = Vec::new();
    for run in runs(mode) {
        let result = verify(root, &run, run.memory.unwrap_or(memory), minutes);
        match result {
            Ok(row) => rows.push(row),
            Err((row, error)) => {
                eprintln!("spin: {}: {error:#}", run.name);
                failures.push(run.name.clone());
                rows.extend(row);
            }
        }
    }
    if report || mode != Mode::Ci {
        write_report(root, mode, memory, minutes, &rows)?;
    }
    if !failures.is_empty() {
        bail!("the model check failed: {}", failures.join(", "));
    }
    Ok(())
}

/// The CI-sized check (`cargo xtask test`).
pub fn check(root: &Path) -> Result<()> {
    task(root, Mode::Ci, false, None, None)
}

/// Runs one verification: its table row, or why it failed (with the row when the verifier
/// ran).
fn verify(
    root: &Path,
    run: &Run,
    memory: u32,
    minutes: Option<u32>,
) -> Result<String, (Option<String>, anyhow::Error)> {
    let dir = root.join("target/spin").join(&run.name);
    let outcome = search(root, &dir, run, memory, minutes).map_err(|error| (None, error))?;
    let summary = format!(
        "{} states, depth {}, {:.1} MB, {:.1} s, {} error(s){}",
        outcome.states,
        outcome.depth,
        outcome.memory_mb,
        outcome.seconds,
        outcome.errors,
        outcome
            .stopped
            .map(|why| format!(", {why}"))
            .unwrap_or_default()
    );
    eprintln!("spin: {}: {summary}", run.name);
    let result = match (run.expect, outcome.errors, outcome.stopped) {
        (Some(_), 0, _) => "**not found**",
        (Some(_), _, _) => "found",
        (None, 0, None) => "no error, complete",
        (None, 0, Some(why)) => why,
        (None, _, _) => "**error**",
    };
    let row = format!(
        "| {} | {} | `{}` | {} | {} | {:.1} | {:.1} | {} |",
        run.name,
        run.what,
        run.defines
            .iter()
            .map(|define| define.trim_start_matches("-D"))
            .collect::<Vec<_>>()
            .join(" "),
        outcome.states,
        outcome.depth,
        outcome.memory_mb,
        outcome.seconds,
        result
    );
    let fail = |error: anyhow::Error| (Some(row.clone()), error);
    if let Some(expect) = run.expect {
        if outcome.errors == 0 {
            return Err(fail(anyhow::anyhow!(
                "the mutation was not found ({summary})"
            )));
        }
        let events = replay(&dir, run).map_err(fail)?;
        eprintln!("spin: {}: found; the counterexample replayed:", run.name);
        eprint!("{events}");
        if !events.contains(expect) {
            return Err(fail(anyhow::anyhow!(
                "the counterexample does not show the race (no line with `{expect}`)"
            )));
        }
    } else {
        if outcome.errors > 0 {
            eprint!("{}", replay(&dir, run).map_err(fail)?);
            return Err(fail(anyhow::anyhow!("the model has an error ({summary})")));
        }
        if outcome.stopped.is_some() {
            return Err(fail(anyhow::anyhow!(
                "the search was not complete ({summary})"
            )));
        }
    }
    Ok(row)
}

/// Generates, compiles and runs the verifier of `run` in `dir`.
fn search(
    root: &Path,
    dir: &Path,
    run: &Run,
    memory: u32,
    minutes: Option<u32>,
) -> Result<Outcome> {
    std::fs::create_dir_all(dir)?;
    std::fs::copy(root.join(MODEL), dir.join("dual_channel.pml"))
        .with_context(|| format!("copying {MODEL}"))?;
    // A trail of an earlier run would be replayed for this one.
    let _ = std::fs::remove_file(dir.join("dual_channel.pml.trail"));
    eprintln!("\nspin: {} ({})", run.name, run.what);
    let mut generate = Command::new("spin");
    generate.current_dir(dir).arg("-a").args(&run.defines);
    generate.arg("dual_channel.pml");
    succeed(&mut generate).context("spin -a (is SPIN installed? apt-get install spin)")?;
    let mut compile = Command::new("gcc");
    compile.current_dir(dir).args(["-O2", "-w", "-DCOLLAPSE"]);
    compile.arg(format!("-DMEMLIM={memory}"));
    compile.args(["-o", "pan", "pan.c"]);
    if run.ltl.is_some() {
        compile.arg("-DNFAIR=3");
    } else {
        compile.arg("-DSAFETY");
    }
    succeed(&mut compile).context("compiling the verifier (gcc)")?;
    let mut verifier = Command::new(dir.join("pan"));
    let slots = format!("-w{}", hash_slots(memory));
    verifier.current_dir(dir).args(["-m500000", &slots]);
    if let Some(minutes) = minutes {
        verifier.arg(format!("-Q{minutes}"));
    }
    if let Some(property) = run.ltl {
        verifier.args(["-a", "-f", "-N", property]);
    }
    let output = verifier.output().context("running the verifier")?;
    let text = String::from_utf8_lossy(&output.stdout).into_owned();
    std::fs::write(dir.join("pan.out"), &text)?;
    parse(&text).with_context(|| format!("the verifier's report:\n{text}"))
}

/// The counterexample's events (`spin -t`): the model's `@tick ...` lines and the violated
/// property.
fn replay(dir: &Path, run: &Run) -> Result<String> {
    let mut command = Command::new("spin");
    // The trail names the claim it was found with (spin's -N would name a file).
    command.current_dir(dir).arg("-t").args(&run.defines);
    command.arg("dual_channel.pml");
    let output = command.output().context("spin -t")?;
    let text = String::from_utf8_lossy(&output.stdout);
    let events: String = text
        .lines()
        .map(str::trim)
        .filter(|line| {
            line.starts_with('@')
                || line.contains("assertion violated")
                || line.contains("START OF CYCLE")
        })
        .map(|line| format!("    {line}\n"))
        .collect();
    Ok(events)
}

/// Reads pan's report.
fn parse(text: &str) -> Result<Outcome> {
    let number_before = |marker: &str| -> Option<f64> {
        let line = text.lines().find(|line| line.contains(marker))?;
        let before = line.split(marker).next()?;
        before.split_whitespace().last()?.parse().ok()
    };
    let number_after = |marker: &str| -> Option<f64> {
        let line = text.lines().find(|line| line.contains(marker))?;
        let after = line.split(marker).nth(1)?;
        after
            .split(|c: char| c == ',' || c.is_whitespace())
            .find(|word| !word.is_empty())?
            .parse()
            .ok()
    };
    let errors = number_after("errors:").context("no error count")?;
    let states = number_before("states, stored").context("no state count")?;
    let depth = number_after("depth reached").context("no depth")?;
    let memory_mb = number_before("total actual memory usage")
        .or_else(|| number_before("memory usage (Mbyte)"))
        .context("no memory")?;
    let seconds = number_after("pan: elapsed time").unwrap_or(0.0);
    let stopped = if text.contains("reached -DMEMLIM bound") {
        Some("stopped at the memory bound")
    } else if text.contains("Time limit of") {
        Some("stopped at the time limit")
    } else if text.contains("max search depth too small") {
        Some("stopped at the depth bound")
    } else if text.contains("Search not completed") && errors == 0.0 {
        Some("not completed")
    } else {
        None
    };
    // The verifier prints whole numbers; the casts only drop a ".0".
    #[expect(
        clippy::cast_possible_truncation,
        clippy::cast_sign_loss,
        reason = "pan prints counts as whole numbers"
    )]
    Ok(Outcome {
        errors: errors as u64,
        states: states as u64,
        depth: depth as u64,
        memory_mb,
        seconds,
        stopped,
    })
}

/// Runs `command`, failing with its output when it fails.
fn succeed(command: &mut Command) -> Result<()> {
    let output = command.output()?;
    if !output.status.success() {
        bail!(
            "`{command:?}` failed ({}):\n{}{}",
            output.status,
            String::from_utf8_lossy(&output.stdout),
            String::from_utf8_lossy(&output.stderr)
        );
    }
    Ok(())
}

/// The first line of a command's output (`spin -V`, `gcc --version`), for the report.
fn version(program: &str, arg: &str) -> String {
    Command::new(program)
        .arg(arg)
        .output()
        .ok()
        .and_then(|output| {
            String::from_utf8_lossy(&output.stdout)
                .lines()
                .next()
                .map(|line| line.trim().to_string())
        })
        .unwrap_or_else(|| format!("{program}: version unknown"))
}

/// Writes `mode`'s rows into its generated section of [`REPORT`].
fn write_report(
    root: &Path,
    mode: Mode,
    memory: u32,
    minutes: Option<u32>,
    rows: &[String],
) -> Result<()> {
    let command = mode.command();
    let begin = format!("<!-- generated by {command}: begin -->");
    let end = format!("<!-- generated by {command}: end -->");
    let path = root.join(REPORT);
    let text = std::fs::read_to_string(&path).with_context(|| format!("reading {REPORT}"))?;
    let (head, rest) = text
        .split_once(&begin)
        .with_context(|| format!("{REPORT} has no line `{begin}`"))?;
    let (_, tail) = rest
        .split_once(&end)
        .with_context(|| format!("{REPORT} has no line `{end}`"))?;
    let bounds = match mode {
        Mode::Ci => "each run's flags".to_string(),
        Mode::Full => format!(
            "each run's flags (the full bounds `{}`, some replaced)",
            FULL.join(" ")
        ),
        Mode::Liveness => "the run's flags".to_string(),
    };
    let limit = minutes.map_or("none".to_string(), |minutes| {
        format!("{minutes} min per run (`pan -Q{minutes}`)")
    });
    let mut section = format!(
        "{begin}\n\nMeasured by `{command}` with {} and {} (`-O2 -DCOLLAPSE -DMEMLIM={memory}`, \
         `pan -m500000 -w{}`); bounds: {bounds}; time limit: {limit}; {} cores.\n\n\
         | run | checks | flags | states stored | depth | memory (MB) | time (s) | result |\n\
         |---|---|---|---|---|---|---|---|\n",
        version("spin", "-V"),
        version("gcc", "--version"),
        hash_slots(memory),
        std::thread::available_parallelism().map_or(0, std::num::NonZero::get),
    );
    for row in rows {
        section.push_str(row);
        section.push('\n');
    }
    section.push('\n');
    std::fs::write(&path, format!("{head}{section}{end}{tail}"))?;
    eprintln!("spin: wrote {REPORT}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::parse;

    /// The end of a report of pan (SPIN 6.5.2) after `head`, with `errors` and `states`.
    fn report(head: &str, errors: u32, states: u64) -> String {
        format!(
            "{head}\n(Spin Version 6.5.2 -- 6 December 2019)\n\
             State-vector 404 byte, depth reached 962, errors: {errors}\n \
             {states} states, stored\n 57217313 states, matched\n\
             Stats on memory usage (in Megabytes):\n 5871.027\ttotal actual memory usage\n\n\
             pan: elapsed time 303 seconds\n"
        )
    }

    #[test]
    fn a_complete_search_reports_its_figures_and_no_stop() {
        let outcome = parse(&report("", 0, 900_558)).expect("a whole report");
        assert_eq!(outcome.errors, 0);
        assert_eq!(outcome.states, 900_558);
        assert_eq!(outcome.depth, 962);
        assert!((outcome.memory_mb - 5871.027).abs() < 1e-6);
        assert!((outcome.seconds - 303.0).abs() < 1e-6);
        assert_eq!(outcome.stopped, None);
    }

    #[test]
    fn a_search_stopped_at_the_time_limit_or_the_memory_bound_is_not_complete() {
        let timed = report(
            "Time limit of      5 minutes exceeded\n\nWarning: Search not completed",
            0,
            23_000_000,
        );
        assert_eq!(
            parse(&timed).expect("a whole report").stopped,
            Some("stopped at the time limit")
        );
        let memory = report(
            "pan: reached -DMEMLIM bound\n\nWarning: Search not completed",
            0,
            23_000_000,
        );
        assert_eq!(
            parse(&memory).expect("a whole report").stopped,
            Some("stopped at the memory bound")
        );
    }

    #[test]
    fn a_search_that_found_an_error_is_not_reported_as_stopped() {
        // pan stops at the first error and says the search was not completed.
        let found = report(
            "pan:1: assertion violated injected (at depth 115)\n",
            1,
            10_201,
        );
        let outcome = parse(&found).expect("a whole report");
        assert_eq!(outcome.errors, 1);
        assert_eq!(outcome.stopped, None);
    }

    #[test]
    fn a_report_without_figures_is_refused() {
        assert!(parse("spin: dual_channel.pml:276, Error: d_step sequence too long").is_err());
    }
}
