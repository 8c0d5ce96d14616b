//! `cargo xtask scenario [FILES...]`: the scenario files (`scenarios/*.toml` when none is
//! given) played on the dual-channel host simulation by `system-tests`' `scenario` program
//! (`tests/src/scenario_runner`): PASS or FAIL per expected outcome with the value measured
//! and its bound, the timeline around a failure. Fails when a file does not parse or an
//! expectation fails.
//!
//! `cargo xtask scenario --emulated [FILES...]` plays them (`scenarios/emulated/*.toml` when
//! none is given) on the shipped images instead ([`emulated`]): the four sealed hardware
//! images on the emulated STM32F405s (`emulate-network --nominal --scenario`, played by
//! `emulator::scenario` after the nominal case), every expectation judged from what the
//! emulated network observed (`system_tests::scenario_runner::emulated::judge`), and the
//! campaigns' oracle's verdict on each, printed as the host runs print it. `cargo xtask test`
//! plays every file of `scenarios/emulated/` the same way (`emulate::network_checks`).

use crate::network::{self, Protocol};
use crate::{images, toolchain};
use anyhow::{Context, Result, anyhow};
use std::path::{Path, PathBuf};
use system_tests::scenario_runner::emulated as player;
use system_tests::scenario_runner::{self, file};

/// Runs the scenario program on `files` (paths as given on the command line, relative to
/// the directory the command was started in).
pub fn task(root: &Path, files: &[PathBuf]) -> Result<()> {
    let here = std::env::current_dir()?;
    let mut command = super::cargo();
    command.args([
        "run",
        "--quiet",
        "-p",
        "system-tests",
        "--bin",
        "scenario",
        "--",
    ]);
    command.arg("--dir").arg(root.join("scenarios"));
    for file in files {
        command.arg(here.join(file));
    }
    super::run(&mut command)
}

/// The network the emulated scenarios must name: the one `cargo xtask run` configures.
fn emulated_network() -> Result<safety_config::network_file::Network> {
    Ok(safety_config::network_file::parse(
        &network::network_file(),
        "the emulated network",
    )?)
}

/// Plays `files` (every `*.toml` of `scenarios/emulated/` when none is given) on the shipped
/// images on the emulated STM32F405s, after the nominal case (`emulate-network --nominal
/// --scenario`). Every file is loaded and checked before the network starts. Fails when one
/// does not parse, is not playable there, or an expectation fails.
pub fn emulated(root: &Path, files: &[PathBuf]) -> Result<()> {
    let here = std::env::current_dir()?;
    let files: Vec<PathBuf> = if files.is_empty() {
        scenario_runner::files_in(&root.join("scenarios/emulated")).map_err(|why| anyhow!(why))?
    } else {
        files.iter().map(|file| here.join(file)).collect()
    };
    let expected = emulated_network()?;
    for path in &files {
        let scenario = file::load(path)?;
        player::check_playable(&scenario, &expected, safety_device::BIT_RATE)
            .map_err(|why| anyhow!(why))?;
    }
    let cross = toolchain::ensure()?;
    toolchain::ensure_emulator_build_deps()?;
    let layer = Protocol::CanopenSafety.hardware_layer();
    images::build_layer(root, &cross, layer)?;
    let emulate = crate::emulate::build_emulate_network(root)?;
    let network_file = crate::emulate::write_network_file(root, Protocol::CanopenSafety)?;
    let mut command = std::process::Command::new(emulate);
    command
        .arg(images::image(&cross, root, layer, "a"))
        .arg(images::image(&cross, root, layer, "b"))
        .args(["--inputs-closed", "--nominal"])
        .arg(network_file);
    for file in &files {
        command.arg("--scenario").arg(file);
    }
    let output = command.output().context("running emulate-network")?;
    // The reports, the events and the channels' logs; not the nominal case's profile tables,
    // which `cargo xtask emulate --network --nominal` writes into docs/emulated-figures.md.
    for line in String::from_utf8_lossy(&output.stdout).lines() {
        if !line.starts_with("emulate-network: figures")
            && !line.starts_with("emulate-network: cost ")
        {
            println!("{line}");
        }
    }
    eprint!("{}", String::from_utf8_lossy(&output.stderr));
    if !output.status.success() {
        anyhow::bail!(
            "a scenario failed on the shipped images, or the network did not come up (above)"
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The emulated scenarios' network file is the network `cargo xtask run` configures, so
    /// the host runs of those files play the emulated timing.
    #[test]
    fn the_emulated_scenarios_network_file_is_the_one_xtask_configures() {
        let path =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/networks/emulated.toml");
        let text = std::fs::read_to_string(&path).expect("scenarios/networks/emulated.toml");
        let committed = safety_config::network_file::parse(&text, "emulated.toml").expect("parses");
        assert_eq!(committed, emulated_network().expect("parses"));
    }

    /// Every file of `scenarios/emulated/` can be played there: the
    /// emulated network, its bit rate, only faults the hub can inject.
    #[test]
    fn every_emulated_scenario_is_playable_on_the_emulated_network() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let files = scenario_runner::files_in(&root.join("scenarios/emulated")).expect("listed");
        assert!(files.len() >= 9, "{} emulated scenarios", files.len());
        let expected = emulated_network().expect("parses");
        for path in &files {
            let scenario = file::load(path).unwrap_or_else(|error| panic!("{error}"));
            player::check_playable(&scenario, &expected, safety_device::BIT_RATE)
                .unwrap_or_else(|why| panic!("{why}"));
        }
    }
}
