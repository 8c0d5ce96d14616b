//! The scenario runner (`cargo xtask scenario [FILES...]`): plays each scenario file on the
//! dual-channel host simulation and prints PASS or FAIL per expected outcome with the value
//! measured and its bound, and the timeline around a failure. Exits with failure when a file
//! cannot be read or parsed (the file, line and column in a sentence) or an expectation
//! failed.

use clap::Parser;
use std::path::PathBuf;
use std::process::ExitCode;
use system_tests::scenario_runner::{self, file};

#[derive(Parser)]
#[command(about = "Scenario files played on the dual-channel host simulation")]
struct Args {
    /// Scenario files (TOML); every `*.toml` directly in `scenarios/` when none is given.
    files: Vec<PathBuf>,
    /// Where the scenarios are when no file is given.
    #[arg(long, default_value = "scenarios")]
    dir: PathBuf,
}

fn main() -> ExitCode {
    let args = Args::parse();
    let files = if args.files.is_empty() {
        match scenario_runner::files_in(&args.dir) {
            Ok(files) => files,
            Err(error) => {
                eprintln!("scenario: {error}");
                return ExitCode::FAILURE;
            }
        }
    } else {
        args.files
    };
    let (mut passed, mut failed) = (0, 0);
    for path in &files {
        let outcome = file::load(path)
            .map_err(|error| error.to_string())
            .and_then(|scenario| scenario_runner::run(&scenario).map(|report| (scenario, report)));
        match outcome {
            Ok((scenario, report)) => {
                print!("{}", report.text(&scenario));
                if report.passed() {
                    passed += 1;
                } else {
                    failed += 1;
                }
            }
            Err(error) => {
                println!("scenario: {error}");
                failed += 1;
            }
        }
    }
    println!(
        "scenario: {passed} passed, {failed} failed, of {}",
        files.len()
    );
    if failed == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}
