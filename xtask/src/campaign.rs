//! `cargo xtask campaign`: the seeded fault campaigns of `tests/src/campaign` (host
//! simulation, judged by the independent oracle), run on every core.
//! Every class runs at 125, 250, 500 and 1000 kbit/s unless `--bit-rate` picks some; the
//! SimpleCAN classes (`--protocol simplecan`, names `simplecan-…`: bad CRC, replay,
//! masquerade, lost, delay, babbling, sync loss, two masters, master gone, leaky counter) run
//! on their own network at 500 kbit/s (`tests/src/campaign/simplecan.rs`), and the dual-channel
//! ones (`simplecan-dual-…`: the contacts apart, one channel's clock off) on two dual-channel
//! nodes at 500 or 1000 kbit/s (`tests/src/campaign/simplecan_dual.rs`), one class per
//! thread. Without `--protocol`, both run.
//! The full size (10,000 scenarios per class and rate, the default) writes `docs/campaigns.md`;
//! a smaller run writes its report to `target/campaign/`; every run writes its plots to
//! `target/campaign/plots/` (generated, not committed),
//! so that CI's short run never replaces the measured full run. Fails when any scenario
//! was unsafe, late, or could not be run.

use anyhow::Result;
use std::path::Path;

/// The size that writes `docs/`: at least this many scenarios per class.
pub const FULL: u64 = 10_000;

/// Options of `cargo xtask campaign`.
pub struct Options {
    /// Scenarios per class.
    pub scenarios: u64,
    /// Only these classes (all when empty).
    pub classes: Vec<String>,
    /// Only these bit rates in kbit/s (125, 250, 500 and 1000 when empty).
    pub bit_rates: Vec<u32>,
    /// The first seed.
    pub seed: u64,
    /// Replay one seed and print its timeline.
    pub replay: Option<u64>,
    /// `canopen-safety` or `simplecan` only (both when `None`).
    pub protocol: Option<String>,
}

/// Runs the campaign binary with `options`.
pub fn task(root: &Path, options: &Options) -> Result<()> {
    let mut command = super::cargo();
    // From the repository's root: the plots' directory is named relative to it in the report.
    command.current_dir(root).args(["run", "--quiet"]);
    // The full size optimised (its wall time is in docs/campaigns.md; unoptimised, a scenario
    // takes many times longer); a smaller run uses the unoptimised build `cargo xtask test` has just
    // made (nextest builds the package's binaries), so CI compiles nothing more for it.
    if options.scenarios >= FULL {
        command.arg("--release");
    }
    command.args(["-p", "system-tests", "--bin", "campaign", "--"]);
    command.args(["--scenarios", &options.scenarios.to_string()]);
    command.args(["--seed", &options.seed.to_string()]);
    for class in &options.classes {
        command.args(["--class", class]);
    }
    for kbit in &options.bit_rates {
        command.args(["--bit-rate", &kbit.to_string()]);
    }
    if let Some(protocol) = &options.protocol {
        command.args(["--protocol", protocol]);
    }
    if let Some(seed) = options.replay {
        command.args(["--replay", &seed.to_string()]);
        return super::run(&mut command);
    }
    // A full run writes its protocol's part of docs/campaigns.md: the CANopen Safety report
    // keeps the SimpleCAN section, the SimpleCAN run replaces only that section.
    let full = options.scenarios >= FULL
        && options.classes.is_empty()
        && options.bit_rates.is_empty()
        && options.seed == 0;
    let report = if full {
        root.join("docs")
    } else {
        root.join("target/campaign")
    };
    let mut line = format!("cargo xtask campaign --scenarios {}", options.scenarios);
    for class in &options.classes {
        line.push_str(&format!(" --class {class}"));
    }
    for kbit in &options.bit_rates {
        line.push_str(&format!(" --bit-rate {kbit}"));
    }
    if let Some(protocol) = &options.protocol {
        line.push_str(&format!(" --protocol {protocol}"));
    }
    if options.seed != 0 {
        line.push_str(&format!(" --seed {}", options.seed));
    }
    // The plots are generated artefacts: always under target/, never committed.
    command
        .arg("--report")
        .arg(&report)
        .args(["--plots", "target/campaign/plots"])
        .args(["--command", &line]);
    super::run(&mut command)
}
