//! The full network at scale and the reaction times, by simulation (`cargo xtask fullnet`,
//! `cargo xtask reaction`): prints the section of docs/network-performance.md as Markdown.
//! Exits with 1 when a channel reported a fault or a margin was negative in the full network.

use clap::{Parser, Subcommand};
use shared::Duration;
use std::process::ExitCode;
use system_tests::fullnet::{network, reaction, report};

#[derive(Parser)]
#[command(about = "The full CANopen Safety network and reaction times, simulated")]
struct Args {
    #[command(subcommand)]
    part: Part,
}

#[derive(Subcommand)]
enum Part {
    /// 64 producers and 64 consumers (127 dual-channel nodes) at 1 Mbit/s.
    Network {
        /// Bus time after the NMT start, in minutes (fractions allowed).
        #[arg(long, default_value_t = 60.0)]
        minutes: f64,
        /// Seed of the input changes and the background phases.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Threads: 1, or 2 (channel A of each node on one, channel B on the other; the
        /// report is the same but for its times). By default 2 where the machine has two
        /// cores or more, else 1 (docs/network-performance.md).
        #[arg(long, value_parser = clap::value_parser!(u8).range(1..=2))]
        threads: Option<u8>,
    },
    /// Node 1 → node 33 by event-driven SRDO, GFC and SCT expiry at every bit rate.
    Reaction {
        /// Changes per case.
        #[arg(long, default_value_t = 200)]
        repetitions: u32,
        /// Seed of the phases.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
}

fn main() -> ExitCode {
    match Args::parse().part {
        Part::Network {
            minutes,
            seed,
            threads,
        } => {
            if !(minutes > 0.0 && minutes <= 24.0 * 60.0) {
                eprintln!("fullnet: --minutes must be above 0 and at most 1440 (24 h)");
                return ExitCode::FAILURE;
            }
            let bus_time = Duration::from_micros((minutes * 60e6) as u64);
            let cores = std::thread::available_parallelism().map_or(1, usize::from);
            let threads = threads.map_or(cores.min(2), usize::from);
            match network::run(bus_time, seed, false, threads) {
                Ok(result) => {
                    print!("{}", report::full_network(&result));
                    let srvt = u64::from(result.timing.srvt_ms) * 1000;
                    let sct = u64::from(result.timing.sct_ms) * 1000;
                    let violated = result.monitor.srdos.iter().any(|srdo| {
                        srdo.pairs == 0
                            || srdo.max_gap_us >= srvt
                            || srdo.max_interval_us >= sct
                            || srdo.first_us >= sct
                    });
                    if result.monitor.faults > 0 || violated {
                        eprintln!(
                            "fullnet: a channel reported a fault or a margin was not positive"
                        );
                        return ExitCode::FAILURE;
                    }
                    ExitCode::SUCCESS
                }
                Err(error) => {
                    eprintln!("fullnet: {error}");
                    ExitCode::FAILURE
                }
            }
        }
        Part::Reaction { repetitions, seed } => match reaction::measure_all(repetitions, seed) {
            Ok(cases) => {
                print!("{}", report::reactions(&cases, repetitions));
                ExitCode::SUCCESS
            }
            Err(error) => {
                eprintln!("fullnet: {error}");
                ExitCode::FAILURE
            }
        },
    }
}
