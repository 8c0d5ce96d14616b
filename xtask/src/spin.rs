//! `cargo xtask spin`: the SPIN model of the two channels' protocol
//! (`dual-channel/model/dual_channel.pml`) checked exhaustively within its bounds, and each
//! past race re-introduced by its mutation switch shown to be found.
//!
//! Every run copies the model to `target/spin/<run>/`, generates the verifier (`spin -a`),
//! compiles it with gcc and runs it; the state count, depth, memory and time it reports are
//! printed. A check fails on any error, and on a search that was not complete (memory bound,
//! depth bound). A mutation fails when the verifier finds nothing; what it found is replayed
//! (`spin -t`) and printed as the model's sequence of events.

use anyhow::{Context, Result, bail};
use std::path::{Path, PathBuf};
use std::process::Command;

/// The model, relative to the repository's root.
const MODEL: &str = "dual-channel/model/dual_channel.pml";

/// The document whose generated section records the last `--full` run.
const REPORT: &str = "docs/model-checking.md";

/// The bounds of the CI-sized checks: one NMT reset and start after the power-on start, one
/// input change, and the master waits a tick after a reset before it starts.
const CI_BOUNDS: &[&str] = &[
    "-DNMT_BUDGET=2",
    "-DINPUT_BUDGET=1",
    "-DSTART_AFTER_RESET_T=1",
];

/// One run of the verifier.
struct Run {
    /// Its name (and directory under target/spin).
    name: &'static str,
    /// What it checks, in words.
    what: &'static str,
    /// `-D` flags for spin (the model's bounds and switches).
    defines: Vec<&'static str>,
    /// The LTL property to check under weak fairness, if any (otherwise assertions only).
    ltl: Option<&'static str>,
    /// `true` for a mutation: the verifier must find an error.
    mutation: bool,
    /// For a mutation: a line of the replayed counterexample that shows the race (the
    /// property it breaks, or the channel that latches), so that another error at the same
    /// bounds is not taken for it.
    expect: &'static str,
}

/// What the verifier reported.
struct Outcome {
    errors: u64,
    states: u64,
    depth: u64,
    memory_mb: f64,
    seconds: f64,
    complete: bool,
}

/// The checks of the unmodified model at `bounds`.
fn checks(bounds: &[&'static str], full: bool) -> Vec<Run> {
    let with = |extra: &[&'static str]| {
        let mut defines = bounds.to_vec();
        defines.extend_from_slice(extra);
        defines
    };
    let mut runs = vec![Run {
        name: "fault-free",
        what: "safety and availability without faults: outputs, co-signing, no safe state",
        defines: with(&["-DFAULT_BUDGET=0"]),
        ltl: None,
        mutation: false,
        expect: "",
    }];
    if full {
        runs.extend([
        Run {
            name: "foreign-frame",
            what: "safety with a foreign frame on the producer's identifiers",
            defines: with(&["-DFAULT_BUDGET=1", "-DFAULTS=1", "-DNMT_BUDGET=0"]),
            ltl: None,
            mutation: false,
            expect: "",
        },
        Run {
            name: "loss",
            what: "safety with a lost bus frame or link message",
            defines: with(&["-DFAULT_BUDGET=1", "-DFAULTS=2", "-DNMT_BUDGET=0"]),
            ltl: None,
            mutation: false,
            expect: "",
        },
        Run {
            name: "stuck-contact",
            what: "safety with a contact stuck",
            defines: with(&["-DFAULT_BUDGET=1", "-DFAULTS=4", "-DNMT_BUDGET=0"]),
            ltl: None,
            mutation: false,
            expect: "",
        },
        Run {
            name: "recovery",
            what: "liveness (weak fairness): after the last fault, NMT reset and start, both nodes Operational with a confirmed pair",
            defines: vec![
                "-DLIVENESS",
                "-DNMT_BUDGET=0",
                "-DINPUT_BUDGET=0",
                "-DFAULT_BUDGET=1",
                "-DSTART_AFTER_RESET_T=1",
            ],
            ltl: Some("recovers"),
            mutation: false,
            expect: "",
        },
        ]);
    }
    if full {
        runs.push(Run {
            name: "slow-loops",
            what: "safety and availability with both producer channels' loops slow",
            defines: with(&["-DFAULT_BUDGET=0", "-DSLOW_LOOPS=3"]),
            ltl: None,
            mutation: false,
            expect: "",
        });
    }
    runs
}

/// Each past race re-introduced, with the bounds it is found at and what shows it.
fn mutations() -> Vec<Run> {
    let with = |base: &[&'static str], extra: &[&'static str]| {
        let mut defines = base.to_vec();
        defines.push("-DFAULT_BUDGET=0");
        defines.extend_from_slice(extra);
        defines
    };
    // The master starts right after a reset: the cut pair's inverted frame and channel A's
    // first frames after the start race with the reset only then. At these bounds the
    // unmodified model has the finding of docs/model-checking.md (channel B reports a frame
    // of the ended epoch as foreign); the races below show in other channels or properties.
    const START_AT_ONCE: &[&str] = &["-DNMT_BUDGET=2", "-DINPUT_BUDGET=1"];
    vec![
        Run {
            name: "mutation-cosign-before-reset",
            what: "channel B co-signing a plain frame before it handled an NMT reset (it keeps the frame across its reset)",
            defines: with(
                CI_BOUNDS,
                &["-DMUTATION_COSIGN_BEFORE_RESET", "-DSLOW_LOOPS=2"],
            ),
            ltl: None,
            mutation: true,
            expect: "PROPERTY availability: ch1",
        },
        Run {
            name: "mutation-drop-announcements",
            what: "announcements dropped across epochs",
            defines: with(
                CI_BOUNDS,
                &["-DMUTATION_DROP_ANNOUNCEMENTS", "-DSLOW_LOOPS=2"],
            ),
            ltl: None,
            mutation: true,
            expect: "PROPERTY availability: ch1",
        },
        Run {
            name: "mutation-cut-pair-foreign",
            what: "the inverted frame of a pair cut by a reset taken as foreign",
            defines: with(
                START_AT_ONCE,
                &["-DMUTATION_CUT_PAIR_FOREIGN", "-DRESET_NOT_OVERTAKING"],
            ),
            ltl: None,
            mutation: true,
            expect: "ch0: foreign frame on our identifiers",
        },
        Run {
            name: "mutation-stale-confirmation",
            what: "a stale confirmation switching an output back on",
            defines: with(CI_BOUNDS, &["-DMUTATION_STALE_CONFIRMATION"]),
            ltl: None,
            mutation: true,
            expect: "PROPERTY output",
        },
        Run {
            name: "mutation-keep-announcements",
            what: "channel B flagging A's own frame as foreign when the link is slow (announcements of an ended epoch kept)",
            defines: with(
                START_AT_ONCE,
                &["-DMUTATION_KEEP_ANNOUNCEMENTS", "-DWITHDRAW_AT_RESET"],
            ),
            ltl: None,
            mutation: true,
            expect: "PROPERTY co-sign",
        },
    ]
}

/// `cargo xtask spin [--full]`.
pub fn task(root: &Path, full: bool) -> Result<()> {
    crate::toolchain::ensure_spin()?;
    let bounds: Vec<&'static str> = if full {
        vec![
            "-DNMT_BUDGET=3",
            "-DINPUT_BUDGET=2",
            "-DSTARTED=0",
            "-DINITIAL_INPUT=0",
            "-DSTART_AFTER_RESET_T=1",
        ]
    } else {
        CI_BOUNDS.to_vec()
    };
    let mut lines = Vec::new();
    let mut runs = checks(&bounds, full);
    runs.extend(mutations());
    let mut failures = Vec::new();
    for run in &runs {
        match verify(root, run) {
            Ok(line) => lines.push(line),
            Err(error) => {
                eprintln!("spin: {}: {error:#}", run.name);
                failures.push(run.name);
            }
        }
    }
    if full {
        write_report(root, &bounds, &lines)?;
    }
    if !failures.is_empty() {
        bail!("the model check failed: {}", failures.join(", "));
    }
    Ok(())
}

/// The CI-sized check (`cargo xtask test`).
pub fn check(root: &Path) -> Result<()> {
    task(root, false)
}

/// Runs one verification and says what it found, as one table row.
fn verify(root: &Path, run: &Run) -> Result<String> {
    let dir = root.join("target/spin").join(run.name);
    std::fs::create_dir_all(&dir)?;
    std::fs::copy(root.join(MODEL), dir.join("dual_channel.pml"))
        .with_context(|| format!("copying {MODEL}"))?;
    eprintln!("\nspin: {} ({})", run.name, run.what);
    let mut generate = Command::new("spin");
    generate.current_dir(&dir).arg("-a").args(&run.defines);
    generate.arg("dual_channel.pml");
    succeed(&mut generate).context("spin -a (is SPIN installed? apt-get install spin)")?;
    let mut compile = Command::new("gcc");
    compile.current_dir(&dir).args([
        "-O2",
        "-w",
        "-DCOLLAPSE",
        "-DMEMLIM=6000",
        "-o",
        "pan",
        "pan.c",
    ]);
    if run.ltl.is_some() {
        compile.arg("-DNFAIR=3");
    } else {
        compile.arg("-DSAFETY");
    }
    succeed(&mut compile).context("compiling the verifier (gcc)")?;
    let mut verifier = Command::new(dir.join("pan"));
    verifier.current_dir(&dir).args(["-m500000", "-w26"]);
    if let Some(property) = run.ltl {
        verifier.args(["-a", "-f", "-N", property]);
    }
    let output = verifier.output().context("running the verifier")?;
    let text = String::from_utf8_lossy(&output.stdout).into_owned();
    std::fs::write(dir.join("pan.out"), &text)?;
    let outcome = parse(&text).with_context(|| format!("the verifier's report:\n{text}"))?;
    let summary = format!(
        "{} states, depth {}, {:.1} MB, {:.1} s, {} error(s)",
        outcome.states, outcome.depth, outcome.memory_mb, outcome.seconds, outcome.errors
    );
    eprintln!("spin: {}: {summary}", run.name);
    let row = format!(
        "| {} | {} | {} | {} | {:.1} | {:.1} | {} |",
        run.name,
        run.what,
        outcome.states,
        outcome.depth,
        outcome.memory_mb,
        outcome.seconds,
        outcome.errors
    );
    if run.mutation {
        if outcome.errors == 0 {
            bail!("the mutation was not found ({summary})");
        }
        let events = replay(&dir, run)?;
        eprintln!("spin: {}: found; the counterexample replayed:", run.name);
        eprint!("{events}");
        if !events.contains(run.expect) {
            bail!(
                "the counterexample does not show the race (no line with `{}`)",
                run.expect
            );
        }
    } else {
        if outcome.errors > 0 {
            eprint!("{}", replay(&dir, run)?);
            bail!("the model has an error ({summary})");
        }
        if !outcome.complete {
            bail!("the search was not complete ({summary}): raise the bounds' memory or depth");
        }
    }
    Ok(row)
}

/// The counterexample's events (`spin -t`): the model's `@tick ...` lines and the violated
/// property.
fn replay(dir: &Path, run: &Run) -> Result<String> {
    let mut command = Command::new("spin");
    command.current_dir(dir).arg("-t").args(&run.defines);
    if let Some(property) = run.ltl {
        command.args(["-N", property]);
    }
    command.arg("dual_channel.pml");
    let output = command.output().context("spin -t")?;
    let text = String::from_utf8_lossy(&output.stdout);
    let events: String = text
        .lines()
        .map(str::trim)
        .filter(|line| {
            line.starts_with('@')
                || line.contains("assertion violated")
                || line.contains("acceptance cycle")
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
    let memory_mb = number_before("total actual memory usage").context("no memory")?;
    let seconds = number_after("pan: elapsed time").unwrap_or(0.0);
    let complete = !text.contains("Search not completed") || errors > 0.0;
    let complete = complete && !text.contains("max search depth too small");
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
        complete,
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

/// Writes the last `--full` run into the generated section of [`REPORT`].
fn write_report(root: &Path, bounds: &[&str], rows: &[String]) -> Result<()> {
    const BEGIN: &str = "<!-- generated by cargo xtask spin --full: begin -->";
    const END: &str = "<!-- generated by cargo xtask spin --full: end -->";
    let path: PathBuf = root.join(REPORT);
    let text = std::fs::read_to_string(&path).with_context(|| format!("reading {REPORT}"))?;
    let (head, rest) = text
        .split_once(BEGIN)
        .with_context(|| format!("{REPORT} has no line `{BEGIN}`"))?;
    let (_, tail) = rest
        .split_once(END)
        .with_context(|| format!("{REPORT} has no line `{END}`"))?;
    let mut section = format!(
        "{BEGIN}\n\nBounds of the checks: `{}`; mutations at the CI bounds `{}`.\n\n\
         | run | checks | states stored | depth | memory (MB) | time (s) | errors |\n\
         |---|---|---|---|---|---|---|\n",
        bounds.join(" "),
        CI_BOUNDS.join(" ")
    );
    for row in rows {
        section.push_str(row);
        section.push('\n');
    }
    section.push('\n');
    std::fs::write(&path, format!("{head}{section}{END}{tail}"))?;
    eprintln!("spin: wrote {REPORT}");
    Ok(())
}
