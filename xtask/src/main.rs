//! `cargo xtask`: the project's one entry point for building, testing, running and measuring.
//!
//! Every command sets up what it needs first (the cross target, say) and says what it did, so
//! a fresh clone needs nothing but a Rust toolchain.

mod bench;
mod campaign;
mod child;
mod e2e;
mod emulate;
mod footprint;
mod fullnet;
mod generated;
mod images;
mod interop;
mod licences;
mod locate;
mod manual;
mod network;
mod run;
mod scenario;
mod spin;
mod target_cost;
mod toolchain;
mod trace;

use anyhow::{Result, bail};
use clap::{Parser, Subcommand};
use std::path::{Path, PathBuf};
use std::process::Command;

#[derive(Parser)]
#[command(
    name = "cargo xtask",
    about = "Build, test, run and measure the CANopen Safety node"
)]
struct Cli {
    #[command(subcommand)]
    command: Task,
}

#[derive(Subcommand)]
enum Task {
    /// Install what the other tasks need: the thumbv7em-none-eabihf target (rustup, or
    /// Debian's rust-web packages as a fallback), clippy and rustfmt. Idempotent.
    Setup {
        /// Also install probe-rs-tools and defmt-print (several minutes of compiling).
        #[arg(long)]
        probe_rs: bool,
        /// Also install what `cargo xtask fuzz` needs: the nightly toolchain (rustup) and
        /// cargo-fuzz (a few minutes of compiling).
        #[arg(long)]
        fuzz: bool,
    },
    /// Build the firmware images of both protocols (release: CANopen Safety, and SimpleCAN
    /// instead of SRDOs) and check their size against their budgets.
    Build,
    /// Where the bytes of the firmware images go: builds both layers' images and writes flash
    /// per crate (from the line tables) and the largest functions into docs/footprint.md.
    Footprint,
    /// Build both images and flash one to a connected STM32F405RG with probe-rs, then show its
    /// defmt log (`probe-rs run`). Needs a probe; `cargo xtask setup --probe-rs` installs
    /// probe-rs.
    Flash {
        /// Which channel's image: `a` or `b`.
        #[arg(value_parser = ["a", "b"])]
        channel: String,
        /// The image's safety protocol: `canopen-safety` (the default) or `simplecan`
        /// (SimpleCAN instead of SRDOs).
        #[arg(long, value_enum, default_value_t)]
        protocol: network::Protocol,
    },
    /// The end-to-end tests on the shipped hardware images on the emulated STM32F405
    /// network (`emulator::cases`, `emulator::e2e`): configured by the tool's library,
    /// nominal, emergency stop, dropped and corrupted frames, a silent node, a channel that
    /// reads otherwise, a cut link.
    E2e {
        /// Also 60 s of SDO and non-safety traffic on 30 % of the bus beside the SRDOs
        /// (opt-in, docs/can-receive.md).
        #[arg(long)]
        bus_load: bool,
        /// The case under bus load for this many seconds of the network's time instead
        /// (CI runs it at `e2e::CI_LOAD_SECONDS`).
        #[arg(long, value_name = "SECONDS", conflicts_with = "bus_load", value_parser = load_seconds)]
        bus_load_seconds: Option<f64>,
        /// The cases of this protocol: `canopen-safety` (the default, the cases above) or
        /// `simplecan` (the SimpleCAN images: emergency stop, node 1 the master stopped).
        #[arg(long, value_enum, default_value_t)]
        protocol: network::Protocol,
    },
    /// Where addresses of a firmware image are in the source: the functions (with what was
    /// inlined there), files and lines. For the return addresses a panic logs (`panicked;
    /// return addresses [...]`), looked up in the image that logged them.
    Where {
        /// Which channel's image: `a` or `b`.
        #[arg(value_parser = ["a", "b"])]
        channel: String,
        /// The addresses, hexadecimal (`0x08001234` or `08001234`).
        #[arg(required = true)]
        addresses: Vec<String>,
    },
    /// One shipped hardware image alone on the emulated STM32F405 (the `emulator` crate:
    /// Unicorn with the F405's peripherals modelled from RM0090), its defmt log decoded; ends
    /// with how the run ended and the emulation speed. Fails when the run stops early (an
    /// access no model claims, a HardFault, a reset). With `--network`, both nodes' four
    /// shipped images on one emulated CAN bus, each node's channels linked by USART3.
    Emulate {
        /// The four shipped images (nodes 1 and 33, channels A and B) on one emulated bus
        /// instead of one image alone.
        #[arg(long)]
        network: bool,
        /// With `--network`: the nominal end-to-end case instead of a fixed time (configure
        /// both nodes with the tool's library from `cargo xtask run`'s network file, start
        /// them, load the bus, open node 1's contacts and time node 33's outputs going off),
        /// then the end-to-end fault cases and the emulated scenarios on the shipped images
        /// (`emulator::e2e`, `emulator::scenario`); writes docs/emulated-figures.md.
        #[arg(long, requires = "network")]
        nominal: bool,
        /// With `--network`: cut node 1's power at every flash program and erase step of its
        /// store (or every `--every`th), and check each channel keeps the old or the new
        /// parameters and the node starts again.
        #[arg(long, requires = "network", conflicts_with = "nominal")]
        power_cut_sweep: bool,
        /// With `--network`: serve the socketcand protocol on this address (bus `can0`) so
        /// that python-can, python-canopen and `safety-config` join the shipped images' bus
        /// as separate programs; the virtual time follows the host clock, until Ctrl-C.
        #[arg(
            long,
            value_name = "ADDRESS:PORT",
            requires = "network",
            conflicts_with_all = ["nominal", "power_cut_sweep"]
        )]
        socketcand: Option<String>,
        /// With `--power-cut-sweep`: every Nth step only.
        #[arg(long, default_value_t = 1)]
        every: u64,
        /// Only the emulator's checks of `cargo xtask test` (the shipped images alone, then on
        /// one bus: start-up, faults, power cuts, the nominal case), on the images as built.
        #[arg(long)]
        checks: bool,
        /// Which channel's image: `a` or `b`.
        #[arg(long, value_parser = ["a", "b"], default_value = "a")]
        channel: String,
        /// Virtual time to run for: `500ms`, `2s`, `1500us`.
        #[arg(long = "for", default_value = "1s")]
        duration: String,
        /// The node-ID the node-ID switches are set to (1 to 127).
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=127))]
        node_id: u8,
        /// The image's safety protocol: `canopen-safety` (the default) or `simplecan`.
        #[arg(long, value_enum, default_value_t)]
        protocol: network::Protocol,
    },
    /// Everything CI checks: tests, clippy, rustfmt, the cross build of `shared`, the images,
    /// the shipped images on the emulated STM32F405 (start-up, faults, power cuts, the
    /// end-to-end cases and scenarios, CANopen Safety's and SimpleCAN's, a panic on purpose),
    /// the model check; last, that the committed traceability matrix
    /// (docs/traceability.md) is the one this run writes.
    Test,
    /// The main job: the emulated safety network (two nodes, the four sealed hardware images
    /// on emulated STM32F405s), configured and started, shown live through the tool's monitor; single keys
    /// press the emergency stop and inject faults. Ends with a summary that says how the run
    /// ended; fails when a channel ended in the safe state with no fault injected since the
    /// last reset, or no valid SRDO pair was exchanged.
    Run {
        /// Run unattended for this long (e.g. `30s`, at most 24 h), then print the summary.
        #[arg(long = "for", value_parser = run::parse_duration)]
        duration: Option<std::time::Duration>,
        /// Schedule an action: `5s:press` (press, release, drop, corrupt, stop, b-differs,
        /// cut-link, restore-link, gfc, reset) or a key of the live view (`5s:l`: e d c s b l
        /// g r p q); repeatable; before the end of a `--for` run.
        #[arg(long, value_parser = run::parse_at)]
        at: Vec<(std::time::Duration, run::Action)>,
        /// The safety protocol between node 1 and node 33: `canopen-safety` (SRDO 1, the
        /// default) or `simplecan` (the SimpleCAN images, SC-ID 30h, node 1 the master).
        #[arg(long, value_enum, default_value_t)]
        protocol: network::Protocol,
    },
    /// The host demo: two nodes on a simulated bus under simulated time, with an
    /// emergency stop and injected faults, every step checked.
    Demo {
        /// Arguments for the demo (`cargo xtask demo -- --help`).
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<String>,
    },
    /// Third-party CANopen software on the emulated bus through a socketcand port, in a
    /// virtual environment under target/interop (python-can, python-canopen): python-can's
    /// socketcand bus against the hub and the tool; python-canopen on the shipped images'
    /// emulated network with the node's EDS, agreeing with the tool and getting the specific
    /// aborts, sweeping the SimpleCAN images' EDS on the emulated SimpleCAN network; python-can,
    /// python-canopen and `safety-config` on the shipped images' emulated network
    /// (`emulate-network --socketcand`).
    Interop {
        /// Run one part only.
        #[arg(long, value_enum)]
        only: Option<interop::Part>,
        /// Instead of the parts: the tool and python-canopen configure and verify the same
        /// node (host simulation, then the emulated network), wall times side by side in
        /// docs/performance.md.
        #[arg(long, conflicts_with = "only")]
        bench: bool,
    },
    /// Instruction counts (callgrind) for the hot paths, and the RAM per SRDO; writes
    /// docs/performance.md.
    Bench {
        /// Check the counts against the targets and fail when one is exceeded.
        #[arg(long)]
        check: bool,
        /// Instead: the processing step of the safety manual, from the Thumb instructions the
        /// shipped images execute on the emulated STM32F405 (the nominal case); writes its
        /// block of docs/performance.md and tool/src/calc/target_measured.rs.
        #[arg(long)]
        target_cost: bool,
        /// With `--target-cost`: the images and network of this protocol, `canopen-safety`
        /// (the default) or `simplecan` (SimpleCAN's processing step, its own block and
        /// tool/src/calc/target_measured_simplecan.rs, counted in the shipped SimpleCAN images
        /// on the emulated STM32F405; their figures in docs/emulated-figures-simplecan.md).
        #[arg(long, value_enum, default_value_t, requires = "target_cost")]
        protocol: network::Protocol,
        /// With `--target-cost`: instead, the shipped CANopen Safety images on the emulated
        /// STM32F405 (per idle iteration, per pair, per MCU, the deepest stack), printed as
        /// JSON and written to docs/emulated-figures.json (with docs/emulated-figures.md).
        #[arg(long, requires = "target_cost")]
        json: bool,
    },
    /// The full network by simulation: 64 producers and 64 consumers (127 dual-channel nodes)
    /// at 1 Mbit/s with background traffic; bus load, SCT and SRVT margins per SRDO, reaction
    /// times, wall time. Writes its block of docs/network-performance.md; fails when a channel
    /// reported a fault or a margin was not positive.
    Fullnet {
        /// Bus time after the NMT start, in minutes (fractions allowed).
        #[arg(long, default_value_t = 60.0)]
        minutes: f64,
        /// Seed of the input changes and the background phases.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Print the results only; leave docs/network-performance.md as it is (CI).
        #[arg(long)]
        print_only: bool,
    },
    /// Reaction times of node 1 → node 33 by event-driven SRDO, GFC and SCT expiry at 125,
    /// 250, 500 and 1000 kbit/s, with and without higher-priority traffic (min / mean / max
    /// over seeded random phases). Writes its block of docs/network-performance.md.
    Reaction {
        /// Changes per case.
        #[arg(long, default_value_t = 200)]
        repetitions: u32,
        /// Seed of the phases.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Print the results only; leave docs/network-performance.md as it is (CI).
        #[arg(long)]
        print_only: bool,
    },
    /// The safety manual (manual/, an mdBook): writes its generated parts (safety objects,
    /// causes, reaction times, residual error rate, campaign results) from the repository's
    /// sources and committed measurements, builds it with the hardware images' CRCs to
    /// target/manual/html and checks every link and anchor. Needs mdbook.
    Manual {
        /// Fail when a committed generated part differs from a fresh one instead of writing it.
        #[arg(long)]
        check: bool,
    },
    /// Model-check the two channels' protocol with SPIN (dual-channel/model): the model
    /// exhaustively within its bounds, and each past race re-introduced by its mutation switch
    /// found, its counterexample printed. Fails on any error. Needs spin and gcc.
    Spin {
        /// Bigger bounds, every fault class, a late loop; writes the runs' figures into
        /// docs/model-checking.md.
        #[arg(long, conflicts_with = "liveness")]
        full: bool,
        /// The recovery property under weak fairness (LTL); writes its figures into
        /// docs/model-checking.md.
        #[arg(long)]
        liveness: bool,
        /// At the CI size: also write the runs' figures into docs/model-checking.md.
        #[arg(long)]
        report: bool,
        /// The minutes each verifier run may take (by default none at the CI size, 15 per run
        /// with --full, 20 with --liveness); a run stopped by it fails and is reported so.
        #[arg(long)]
        minutes: Option<u32>,
        /// With --full or --liveness: the memory each verifier run may use, in MB (pan's
        /// MEMLIM; by default 14000, a 16 GB workstation's).
        #[arg(long, value_parser = clap::value_parser!(u32).range(500..=1_000_000))]
        memory: Option<u32>,
    },
    /// Run the tests (nextest, JUnit report) and write the traceability matrix, requirement
    /// (requirements/*.toml) → tests → PASS/FAIL/not run: docs/traceability.md and
    /// target/traceability/traceability.html. Fails on a failed test, a test that names an
    /// unknown requirement, and a requirement to be verified by test that has none.
    Trace {
        /// Build the matrix from the JUnit report of the last test run instead of running
        /// the tests.
        #[arg(long)]
        report_only: bool,
        /// Also fail when the committed docs/traceability.md is not the matrix written now,
        /// naming the lines that differ (as `cargo xtask test` does).
        #[arg(long)]
        check: bool,
    },
    /// Scenario files (scenarios/*.toml unless FILES are given: a network, a timeline of
    /// stimuli and faults, expected outcomes with bounds) on the dual-channel host
    /// simulation; PASS/FAIL per expectation with the value measured and its bound.
    Scenario {
        /// Scenario files.
        files: Vec<std::path::PathBuf>,
        /// Play them on the shipped images on the emulated STM32F405s instead, after the
        /// nominal case: scenarios/emulated/*.toml unless FILES are given.
        #[arg(long)]
        emulated: bool,
    },
    /// The seeded fault campaigns on the host simulation (every IEC 61784-3 error class and
    /// every single-channel fault), judged by an oracle that does not reuse the
    /// implementation, at 125, 250, 500 and 1000 kbit/s; 10,000 scenarios per class and
    /// rate write docs/campaigns.md, a smaller run target/campaign/; every run writes its plots
    /// to target/campaign/plots/ (not committed). Fails on any unsafe or late scenario.
    Campaign {
        /// Scenarios per class.
        #[arg(long, default_value_t = campaign::FULL)]
        scenarios: u64,
        /// Only this class (repeatable): corruption, repetition, sequence, loss, delay,
        /// insertion, masquerade, addressing, node-id, stuck-input, bit-flip, link,
        /// controller-silent, babbling, bus-off, no-inverted, clock-drift.
        #[arg(long = "class")]
        classes: Vec<String>,
        /// Only this bit rate in kbit/s (repeatable): 125, 250, 500, 1000 (all when not
        /// given).
        #[arg(long = "bit-rate")]
        bit_rates: Vec<u32>,
        /// The first seed (scenario n has seed S + n).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Run only the scenario with this seed (with `--class`) and print its timeline.
        #[arg(long)]
        replay: Option<u64>,
        /// Only this protocol's classes: `canopen-safety` (SRDOs) or `simplecan`
        /// (simplecan-bad-crc, -replay, -masquerade, -lost, -delay, -babbling, -sync-loss,
        /// -two-masters, -master-gone, -leaky-counter; a `--class` prefix picks several).
        /// Both when not given.
        #[arg(long)]
        protocol: Option<String>,
    },
    /// Run every fuzz target of every fuzz crate (shared/fuzz, dual-channel/fuzz) for a while,
    /// optimised, then each again with debug assertions and overflow checks. Installs the
    /// nightly toolchain and cargo-fuzz when they are missing.
    Fuzz {
        /// Seconds per target, optimised (`cargo fuzz run -O`); 0 skips that pass.
        #[arg(long, default_value_t = 60)]
        seconds: u32,
        /// Seconds per target with debug assertions and overflow checks (`cargo fuzz run -a`);
        /// 0 skips that pass.
        #[arg(long, default_value_t = 10)]
        checked_seconds: u32,
    },
}

/// Runs the task; a failure is printed as its sentences (the error and its causes), without a
/// backtrace whatever `RUST_BACKTRACE` says: these are the failures a user meets (a node that
/// did not come up, a missing tool, a check that failed), each saying where its logs are. A bug
/// in xtask itself panics, and a panic keeps its backtrace.
fn main() -> std::process::ExitCode {
    match task() {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("Error: {error}");
            for cause in error.chain().skip(1) {
                eprintln!("\nCaused by:\n{cause}");
            }
            std::process::ExitCode::FAILURE
        }
    }
}

fn task() -> Result<()> {
    let cli = Cli::parse();
    let root = workspace_root();
    // Before any child starts: a signal ends every child with xtask (`child`).
    child::end_with_xtask()?;
    match cli.command {
        Task::Setup { probe_rs, fuzz } => toolchain::setup(probe_rs, fuzz),
        Task::Build => {
            let cross = toolchain::ensure()?;
            images::build(&root, &cross)
        }
        Task::Footprint => {
            let cross = toolchain::ensure()?;
            footprint::run(&root, &cross)
        }
        Task::Test => test(&root),
        Task::E2e {
            bus_load,
            bus_load_seconds,
            protocol,
        } => {
            let load_seconds = bus_load_seconds.or(bus_load.then_some(e2e::LOAD_SECONDS));
            if protocol == network::Protocol::Simplecan {
                if load_seconds.is_some() {
                    anyhow::bail!(
                        "the case under bus load is CANopen Safety's: `cargo xtask e2e --bus-load`"
                    );
                }
                // The SimpleCAN cases over the shipped images' control port.
                e2e::simplecan(&root)
            } else {
                emulate::network_task(
                    &root,
                    "1s",
                    protocol,
                    emulate::Case::Nominal { load_seconds },
                )
            }
        }
        Task::Emulate { checks: true, .. } => {
            let cross = toolchain::ensure()?;
            images::build(&root, &cross)?;
            emulate::startup_checks(&root, &cross)?;
            emulate::network_checks(&root, &cross)
        }
        Task::Emulate {
            network: true,
            duration,
            protocol,
            nominal,
            power_cut_sweep,
            every,
            socketcand,
            ..
        } => emulate::network_task(
            &root,
            &duration,
            protocol,
            if let Some(address) = socketcand {
                emulate::Case::Serve { address }
            } else if power_cut_sweep {
                emulate::Case::PowerCutSweep { every }
            } else if nominal {
                emulate::Case::Nominal { load_seconds: None }
            } else {
                emulate::Case::Run
            },
        ),
        Task::Emulate {
            channel,
            duration,
            node_id,
            protocol,
            network: false,
            ..
        } => emulate::task(&root, &channel, &duration, node_id, protocol),
        Task::Where { channel, addresses } => {
            let cross = toolchain::ensure()?;
            locate::task(
                &root,
                &images::image(&cross, &root, images::Layer::Hw, &channel),
                &addresses,
            )
        }
        Task::Flash { channel, protocol } => {
            let cross = toolchain::ensure()?;
            images::build(&root, &cross)?;
            toolchain::require("probe-rs", "run `cargo xtask setup --probe-rs`")?;
            let image = images::image(&cross, &root, protocol.hardware_layer(), &channel);
            run(Command::new("probe-rs")
                .args(["run", "--chip", images::CHIP])
                .arg(image))
        }
        Task::Run {
            duration,
            at,
            protocol,
        } => run::task(&root, duration, at, protocol),
        Task::Demo { args } => {
            let mut command = cargo();
            command.args([
                "run",
                "--quiet",
                "--release",
                "-p",
                "system-tests",
                "--bin",
                "demo",
                "--",
            ]);
            command.args(args);
            run(&mut command)
        }
        Task::Bench {
            check,
            target_cost,
            protocol,
            json,
        } => {
            if json {
                emulate::target_cost_json(&root)
            } else if target_cost {
                target_cost::run(&root, protocol)
            } else {
                bench::run(&root, check)
            }
        }
        Task::Fullnet {
            minutes,
            seed,
            print_only,
        } => fullnet::task(
            &root,
            fullnet::Part::Network,
            &[
                "--minutes".into(),
                minutes.to_string(),
                "--seed".into(),
                seed.to_string(),
            ],
            print_only,
        ),
        Task::Reaction {
            repetitions,
            seed,
            print_only,
        } => fullnet::task(
            &root,
            fullnet::Part::Reaction,
            &[
                "--repetitions".into(),
                repetitions.to_string(),
                "--seed".into(),
                seed.to_string(),
            ],
            print_only,
        ),
        Task::Interop { bench: true, .. } => interop::bench(&root),
        Task::Interop { only, .. } => interop::task(&root, only),
        Task::Fuzz {
            seconds,
            checked_seconds,
        } => fuzz(&root, seconds, checked_seconds),
        Task::Trace { report_only, check } => trace::task(&root, report_only, check),
        Task::Spin {
            full,
            liveness,
            report,
            minutes,
            memory,
        } => {
            let mode = if full {
                spin::Mode::Full
            } else if liveness {
                spin::Mode::Liveness
            } else {
                spin::Mode::Ci
            };
            spin::task(&root, mode, report, minutes, memory)
        }
        Task::Scenario {
            files,
            emulated: false,
        } => scenario::task(&root, &files),
        Task::Scenario {
            files,
            emulated: true,
        } => scenario::emulated(&root, &files),
        Task::Manual { check } => manual::run(&root, check),
        Task::Campaign {
            scenarios,
            classes,
            bit_rates,
            seed,
            replay,
            protocol,
        } => campaign::task(
            &root,
            &campaign::Options {
                scenarios,
                classes,
                bit_rates,
                seed,
                replay,
                protocol,
            },
        ),
    }
}

/// `cargo test`, clippy, rustfmt, and the cross builds, in the order a failure is cheapest.
fn test(root: &Path) -> Result<()> {
    let cross = toolchain::ensure()?;
    // The emulator crate (clippy and its tests below) builds unicorn-engine's C code.
    toolchain::ensure_emulator_build_deps()?;
    step("rustfmt");
    run(cargo().args(["fmt", "--all", "--check"]))?;
    step("clippy (host, every crate and target)");
    run(cargo().args([
        "clippy",
        "--workspace",
        "--all-targets",
        "--",
        "-D",
        "warnings",
    ]))?;
    step("licences: no GPL crate (the emulator, unicorn-engine) in what ships");
    licences::check()?;
    step("tests (nextest, whose JUnit report the traceability matrix is built from)");
    toolchain::ensure_tshark()?;
    if !trace::run_tests(root)? {
        step("traceability matrix");
        if let Err(error) = trace::report(root, false) {
            eprintln!("xtask: {error:#}");
        }
        bail!("tests failed");
    }
    step("doc tests (nextest does not run them)");
    run(cargo().args(["test", "--workspace", "--doc"]))?;
    step("API documentation (every crate; a broken link or other rustdoc warning fails)");
    run(cargo()
        .args(["doc", "--workspace", "--no-deps"])
        .env("RUSTDOCFLAGS", "-D warnings"))?;
    step("shared for thumbv7em-none-eabihf (no_std, no heap)");
    run(&mut cross
        .cargo(root)
        .args(["build", "--release", "-p", "shared", "--features", "defmt"])
        .finish())?;
    step("clippy (firmware crates for thumbv7em-none-eabihf, with and without SimpleCAN)");
    for layer in [images::Layer::Hw, images::Layer::HwSimpleCan] {
        run(images::cargo(&cross, root, "clippy", layer).args(["--", "-D", "warnings"]))?;
    }
    step("firmware images");
    images::build(root, &cross)?;
    step("each shipped image alone on the emulated STM32F405, to its start-up self-tests");
    emulate::startup_checks(root, &cross)?;
    step("both nodes' shipped images on one emulated bus, their links on USART3");
    emulate::network_checks(root, &cross)?;
    step("end-to-end tests of the shipped SimpleCAN images on the emulated network");
    e2e::simplecan(root)?;
    step("model check of the two channels' protocol (SPIN, CI bounds)");
    spin::check(root)?;
    step("traceability matrix, and the committed one is this run's");
    trace::report(root, true)?;
    step("all checks passed");
    Ok(())
}

/// The fuzz crates, each its own workspace (nightly and sanitizer flags stay out of the
/// product's). Their targets are read from the crates (`cargo fuzz list`), so a new target is
/// run without being named here.
const FUZZ_CRATES: [&str; 2] = ["shared/fuzz", "dual-channel/fuzz"];

/// `cargo +nightly fuzz <args…>` in `dir`.
fn cargo_fuzz(dir: &Path, args: &[&str]) -> Command {
    let mut command = Command::new("cargo");
    command
        .current_dir(dir)
        .args(["+nightly", "fuzz"])
        .args(args);
    command
}

/// [`cargo_fuzz`] for `build` and `run`, building into one target directory for both crates
/// (their common dependencies, libFuzzer among them, are built once). The option goes before
/// a `--` in `args`: what follows it is libFuzzer's, which would take the directory for a
/// corpus and leave `cargo fuzz run` to build again into the crate's own target directory.
fn cargo_fuzz_into(root: &Path, dir: &Path, args: &[&str]) -> Command {
    let split = args
        .iter()
        .position(|arg| *arg == "--")
        .unwrap_or(args.len());
    let (cargo_args, fuzzer_args) = args.split_at(split);
    let mut command = cargo_fuzz(dir, cargo_args);
    command
        .arg("--target-dir")
        .arg(root.join("target/fuzz"))
        .args(fuzzer_args);
    command
}

/// `cargo xtask fuzz`: every target for `seconds` optimised, then for `checked_seconds` with
/// debug assertions and overflow checks. Fails at the first target that finds a crash (the
/// input is in that crate's `artifacts/`).
fn fuzz(root: &Path, seconds: u32, checked_seconds: u32) -> Result<()> {
    toolchain::ensure_fuzzing()?;
    // A pass of 0 s is skipped (libFuzzer would read 0 as "no limit").
    let passes = [("-O", seconds), ("-a", checked_seconds)];
    for (profile, seconds) in passes.into_iter().filter(|(_, seconds)| *seconds > 0) {
        for dir in FUZZ_CRATES {
            let dir = root.join(dir);
            step(&format!("fuzz: build {} ({profile})", dir.display()));
            run(&mut cargo_fuzz_into(root, &dir, &["build", profile]))?;
            let list = cargo_fuzz(&dir, &["list"]).output()?;
            if !list.status.success() {
                bail!("`cargo fuzz list` failed in {}", dir.display());
            }
            let targets = String::from_utf8_lossy(&list.stdout).into_owned();
            for target in targets.split_whitespace() {
                step(&format!("fuzz {target} ({profile}) for {seconds} s"));
                run(cargo_fuzz_into(root, &dir, &["run", target, profile, "--"])
                    .arg(format!("-max_total_time={seconds}")))?;
            }
        }
    }
    Ok(())
}

/// The workspace root (xtask lives one level below it).
fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map_or_else(|| PathBuf::from("."), Path::to_path_buf)
}

/// The cargo that runs us.
fn cargo() -> Command {
    let mut command = Command::new(std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into()));
    command.current_dir(workspace_root());
    command
}

/// Prints a step heading.
fn step(what: &str) {
    eprintln!("\n== xtask: {what}");
}

/// Runs `command`, failing with the command line when it fails.
fn run(command: &mut Command) -> Result<()> {
    let status = command.status()?;
    if !status.success() {
        bail!("`{command:?}` failed ({status})");
    }
    Ok(())
}

/// `--bus-load-seconds`: a positive, finite number of seconds.
fn load_seconds(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(seconds) if seconds.is_finite() && seconds > 0.0 => Ok(seconds),
        _ => Err(format!(
            "the bus load's duration must be a positive number of seconds, not \"{text}\""
        )),
    }
}
