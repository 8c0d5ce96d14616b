//! The host demo (`cargo xtask run`): an emergency-stop node and a safe output node exchange
//! SRDOs on a simulated CAN bus; an emergency stop and three injected faults show what the
//! safety layer does. Exits with 0 only when every expectation held.

use clap::Parser;
use std::process::ExitCode;
use system_tests::bus::BIT_RATES;
use system_tests::scenario::{self, Narrator, Outcome};

#[derive(Parser)]
#[command(about = "CANopen Safety demo: two nodes, one bus, simulated time")]
struct Args {
    /// Bus bit rate in bit/s (125000, 250000, 500000 or 1000000).
    #[arg(long, default_value_t = 500_000)]
    bit_rate: u32,
    /// Write the bus trace in candump log format to this file.
    #[arg(long)]
    candump: Option<std::path::PathBuf>,
    /// Only print the summary.
    #[arg(long)]
    quiet: bool,
}

struct Console {
    quiet: bool,
}

impl Narrator for Console {
    fn phase(&mut self, heading: &str) {
        if !self.quiet {
            println!("\n## {heading}");
        }
    }
    fn happened(&mut self, lines: &str) {
        if !self.quiet {
            print!("{lines}");
        }
    }
    fn outcome(&mut self, outcome: &Outcome) {
        if !self.quiet {
            print_outcome(outcome);
        }
    }
}

fn print_outcome(outcome: &Outcome) {
    let mark = if outcome.passed { "PASS" } else { "FAIL" };
    if outcome.measured.is_empty() {
        println!("   [{mark}] {}", outcome.what);
    } else {
        println!("   [{mark}] {} — {}", outcome.what, outcome.measured);
    }
}

fn main() -> ExitCode {
    let args = Args::parse();
    if !BIT_RATES.contains(&args.bit_rate) {
        eprintln!(
            "error: --bit-rate {} is not supported; use one of {BIT_RATES:?}",
            args.bit_rate
        );
        return ExitCode::from(2);
    }
    println!(
        "CANopen Safety demo: node 1 (emergency stop, SRDO producer) and node 33 (safe output, \
         SRDO consumer) on a simulated {} kbit/s bus; times are simulated time.",
        args.bit_rate / 1000
    );
    let mut console = Console { quiet: args.quiet };
    let run = scenario::run(args.bit_rate, &mut console);
    if let Some(path) = &args.candump {
        if let Err(error) = std::fs::write(path, run.network.candump()) {
            eprintln!(
                "error: cannot write the trace to {}: {error}",
                path.display()
            );
            return ExitCode::from(2);
        }
        println!("\nbus trace (candump format): {}", path.display());
    }
    let net = &run.network;
    let load = net.bus.bits_sent as f64
        / (f64::from(net.bus.bit_rate()) * net.now.as_micros() as f64 / 1e6);
    println!("\n## Summary");
    for outcome in &run.outcomes {
        print_outcome(outcome);
    }
    println!(
        "   {:.3} s simulated, {} frames, bus load {:.1} %, node 33 received {} valid SRDO pairs",
        net.now.as_micros() as f64 / 1e6,
        net.bus.frames_sent,
        100.0 * load,
        net.devices[scenario::OUTPUT_NODE].pairs_received
    );
    let failed = run.outcomes.iter().filter(|o| !o.passed).count();
    if failed == 0 {
        println!("   all {} expectations held", run.outcomes.len());
        ExitCode::SUCCESS
    } else {
        println!("   {failed} of {} expectations FAILED", run.outcomes.len());
        ExitCode::FAILURE
    }
}
