//! `cargo xtask scenario [FILES...]`: the scenario files (`scenarios/*.toml` when none is
//! given) played on the dual-channel host simulation by `system-tests`' `scenario` program
//! (`tests/src/scenario_runner`): PASS or FAIL per expected outcome with the value measured
//! and its bound, the timeline around a failure. Fails when a file does not parse or an
//! expectation fails.

use anyhow::Result;
use std::path::{Path, PathBuf};

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
