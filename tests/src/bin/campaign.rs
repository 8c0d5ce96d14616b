//! The fault campaigns (`cargo xtask campaign`): seeded scenarios per fault class on the host
//! simulation, judged by the independent oracle; prints the table, writes the report and
//! one plot per class, and exits with failure when any scenario was unsafe, late, or could
//! not be run.

use clap::Parser;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant as WallClock;
use system_tests::campaign::{self, Class, report};

use report::Row;

#[derive(Parser)]
#[command(about = "Seeded fault campaigns with an independent oracle")]
struct Args {
    /// Scenarios per class.
    #[arg(long, default_value_t = 10_000)]
    scenarios: u64,
    /// Only this class (`corruption`, `repetition`, `sequence`, `loss`, `delay`,
    /// `insertion`, `masquerade`, `addressing`, `node-id`, `stuck-input`, `bit-flip`, `link`,
    /// `controller-silent`, `babbling`, `bus-off`, `no-inverted`, `clock-drift`); repeatable.
    #[arg(long = "class")]
    classes: Vec<String>,
    /// The bus's bit rate in kbit/s (125, 250, 500, 1000); repeatable, every one of them
    /// when not given. Each class runs its scenarios at each rate.
    #[arg(long = "bit-rate")]
    bit_rates: Vec<u32>,
    /// The first seed; scenario n of a class has seed S + n.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Worker threads (default: every core).
    #[arg(long)]
    threads: Option<usize>,
    /// Run only the scenario with this seed (with `--class`) and print its timeline.
    #[arg(long)]
    replay: Option<u64>,
    /// Write the report (`campaigns.md`) here.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Write the plots (`<class>.svg`) here: generated artefacts, not committed (with
    /// `--report` and without this, `campaigns/` beside the report).
    #[arg(long)]
    plots: Option<PathBuf>,
    /// The command line to name in the report.
    #[arg(long, default_value = "cargo xtask campaign")]
    command: String,
    /// `canopen-safety` (the SRDO classes), `simplecan` (the SimpleCAN classes, names
    /// `simplecan-…`), or both when not given.
    #[arg(long)]
    protocol: Option<String>,
}

/// The SimpleCAN campaign: the classes named (by prefix) or all, their lines, the report's
/// SimpleCAN section. `Err` when a scenario was unsafe or the report could not be written.
fn simplecan_run(args: &Args, names: &[&String]) -> Result<(), String> {
    use system_tests::campaign::simplecan::{self, ScClass};
    let mut classes: Vec<ScClass> = Vec::new();
    for name in names {
        let matching = ScClass::matching(name);
        if matching.is_empty() {
            return Err(format!(
                "no SimpleCAN class `{name}`; the classes are: {}",
                ScClass::ALL.map(ScClass::name).join(", ")
            ));
        }
        for class in matching {
            if !classes.contains(&class) {
                classes.push(class);
            }
        }
    }
    if classes.is_empty() {
        classes = ScClass::ALL.to_vec();
    }
    // The classes on every core, one class at a time per thread, in the order given.
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()))
        .clamp(1, classes.len());
    let started = WallClock::now();
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut rows: Vec<(usize, ScClass, simplecan::ScSummary)> = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..threads)
            .map(|_| {
                scope.spawn(|| {
                    let mut done = Vec::new();
                    loop {
                        let n = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some(&class) = classes.get(n) else {
                            return done;
                        };
                        let summary = simplecan::campaign(class, args.seed, args.scenarios);
                        println!("{}", simplecan::line(class, &summary));
                        done.push((n, class, summary));
                    }
                })
            })
            .collect();
        workers
            .into_iter()
            .flat_map(|worker| worker.join().expect("a campaign thread"))
            .collect()
    });
    let seconds = started.elapsed().as_secs_f64();
    rows.sort_by_key(|&(n, _, _)| n);
    let rows: Vec<(ScClass, simplecan::ScSummary)> = rows
        .into_iter()
        .map(|(_, class, summary)| (class, summary))
        .collect();
    println!(
        "campaign: {} SimpleCAN scenarios in {seconds:.1} s on {threads} thread(s)",
        rows.iter()
            .map(|(_, summary)| summary.scenarios)
            .sum::<u64>()
    );
    if let Some(dir) = &args.report {
        let path = dir.join("campaigns.md");
        let report = std::fs::read_to_string(&path).unwrap_or_default();
        let section = simplecan::section(
            &args.command,
            args.seed,
            args.scenarios,
            &rows,
            seconds,
            threads,
        );
        std::fs::create_dir_all(dir).map_err(|error| format!("{}: {error}", dir.display()))?;
        std::fs::write(&path, simplecan::with_section(&report, &section))
            .map_err(|error| format!("{}: {error}", path.display()))?;
        let plots = plots_dir(args, dir);
        std::fs::create_dir_all(&plots).map_err(|error| format!("{}: {error}", plots.display()))?;
        for (class, summary) in &rows {
            simplecan::plot(&plots, *class, summary)?;
        }
        println!("campaign: SimpleCAN section in {}", path.display());
    }
    let failed: u64 = rows
        .iter()
        .map(|(_, summary)| summary.unsafe_ + summary.spurious + summary.late)
        .sum();
    if failed == 0 {
        Ok(())
    } else {
        Err(format!(
            "{failed} SimpleCAN scenario(s) unsafe, spurious or late"
        ))
    }
}

fn main() -> ExitCode {
    let args = Args::parse();
    let (simplecan_names, canopen_names): (Vec<&String>, Vec<&String>) = args
        .classes
        .iter()
        .partition(|name| name.starts_with("simplecan"));
    let (simplecan, canopen) = match args.protocol.as_deref() {
        None if args.classes.is_empty() => (true, true),
        None => (!simplecan_names.is_empty(), !canopen_names.is_empty()),
        Some("simplecan") if !canopen_names.is_empty() => {
            eprintln!(
                "campaign: `{}` is not a SimpleCAN class; the SimpleCAN classes start with `simplecan`",
                canopen_names[0]
            );
            return ExitCode::FAILURE;
        }
        Some("simplecan") => (true, false),
        Some("canopen-safety") => (false, true),
        Some(other) => {
            eprintln!(
                "campaign: no protocol `{other}`; the protocols are: canopen-safety, simplecan"
            );
            return ExitCode::FAILURE;
        }
    };
    if simplecan && let Some(seed) = args.replay {
        use system_tests::campaign::simplecan::{self, ScClass};
        for name in &simplecan_names {
            for class in ScClass::matching(name) {
                if class.dual_channel() {
                    print!(
                        "{}",
                        system_tests::campaign::simplecan_dual::timeline(class, seed)
                    );
                } else {
                    println!("{seed}: {:?}", simplecan::run(class, seed));
                }
            }
        }
    }
    let simplecan_failed = if simplecan && args.replay.is_none() {
        match simplecan_run(&args, &simplecan_names) {
            Ok(()) => false,
            Err(error) => {
                eprintln!("campaign: {error}");
                true
            }
        }
    } else {
        false
    };
    if !canopen {
        return if simplecan_failed {
            ExitCode::FAILURE
        } else {
            ExitCode::SUCCESS
        };
    }
    let mut classes = Vec::new();
    for name in canopen_names {
        match Class::from_name(name) {
            Some(class) => classes.push(class),
            None => {
                eprintln!(
                    "campaign: no class `{name}`; the classes are: {}",
                    Class::ALL.map(Class::name).join(", ")
                );
                return ExitCode::FAILURE;
            }
        }
    }
    if classes.is_empty() {
        classes = Class::ALL.to_vec();
    }
    let mut bit_rates = Vec::new();
    for kbit in &args.bit_rates {
        match campaign::BIT_RATES
            .into_iter()
            .find(|rate| *rate == kbit * 1000)
        {
            Some(rate) => bit_rates.push(rate),
            None => {
                eprintln!(
                    "campaign: no campaign at {kbit} kbit/s; the bit rates are: {}",
                    campaign::BIT_RATES
                        .map(|rate| (rate / 1000).to_string())
                        .join(", ")
                );
                return ExitCode::FAILURE;
            }
        }
    }
    if bit_rates.is_empty() {
        bit_rates = campaign::BIT_RATES.to_vec();
    }
    if let Some(seed) = args.replay {
        for (&class, &bit_rate) in classes
            .iter()
            .flat_map(|class| bit_rates.iter().map(move |rate| (class, rate)))
        {
            let result = campaign::run(class, seed, bit_rate);
            println!(
                "{} at {} kbit/s seed {seed}: {:?}, {}; latency {:?} µs",
                class.name(),
                bit_rate / 1000,
                result.outcome,
                result.fault,
                result.latency.map(shared::Duration::as_micros)
            );
            if let Some(report) = result.report {
                println!("{report}");
            }
        }
        return ExitCode::SUCCESS;
    }
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, std::num::NonZero::get));
    let started = WallClock::now();
    let mut results: Vec<Row> = Vec::new();
    for (&class, &bit_rate) in classes
        .iter()
        .flat_map(|class| bit_rates.iter().map(move |rate| (class, rate)))
    {
        let began = WallClock::now();
        let summary = campaign::campaign(class, args.seed, args.scenarios, bit_rate, threads);
        let (bound, _) = class.bound(bit_rate);
        println!(
            "campaign {:<18} {:>4} kbit/s  injected {:>6}  detected {:>6}  harmless {:>6}  unsafe {}  late {}  harness {}  max latency {:>8} µs (bound {} µs)  {:.1} s",
            class.name(),
            bit_rate / 1000,
            summary.injected,
            summary.detected,
            summary.harmless,
            summary.unsafe_,
            summary.late,
            summary.harness,
            summary
                .max_latency()
                .map_or("–".to_string(), |latency| latency.to_string()),
            bound.as_micros(),
            began.elapsed().as_secs_f64()
        );
        for failure in summary.failures.iter().take(3) {
            println!(
                "\nFAILED {} at {} kbit/s seed {} ({:?}): {}\nreplay: cargo xtask campaign --class {} --bit-rate {} --replay {}\n{}",
                class.name(),
                bit_rate / 1000,
                failure.seed,
                failure.outcome,
                failure.fault,
                class.name(),
                bit_rate / 1000,
                failure.seed,
                failure.report.as_deref().unwrap_or("")
            );
        }
        results.push((class, bit_rate, summary));
    }
    let elapsed = started.elapsed();
    let total: u64 = results.iter().map(|(_, _, summary)| summary.injected).sum();
    println!(
        "campaign: {total} scenarios in {:.1} s on {threads} thread(s), {:.0} µs per scenario and thread",
        elapsed.as_secs_f64(),
        elapsed.as_secs_f64() * 1e6 * threads as f64 / total.max(1) as f64
    );
    if let Some(dir) = &args.report {
        if let Err(error) = write_report(dir, &args, &results, elapsed, threads) {
            eprintln!("campaign: could not write the report: {error}");
            return ExitCode::FAILURE;
        }
        println!("campaign: report in {}", dir.join("campaigns.md").display());
    }
    if !simplecan_failed && results.iter().all(|(_, _, summary)| summary.passed()) {
        ExitCode::SUCCESS
    } else {
        eprintln!("campaign: FAILED: a scenario was unsafe, late, or could not be run (above)");
        ExitCode::FAILURE
    }
}

/// Where the plots go: `--plots`, else `campaigns/` beside the report.
fn plots_dir(args: &Args, report: &std::path::Path) -> PathBuf {
    args.plots
        .clone()
        .unwrap_or_else(|| report.join("campaigns"))
}

fn write_report(
    dir: &std::path::Path,
    args: &Args,
    results: &[Row],
    elapsed: std::time::Duration,
    threads: usize,
) -> Result<(), String> {
    let plots = plots_dir(args, dir);
    std::fs::create_dir_all(&plots).map_err(|error| format!("{}: {error}", plots.display()))?;
    for (class, bit_rate, summary) in results {
        report::plot(&plots, *class, *bit_rate, summary)?;
    }
    let total: u64 = results.iter().map(|(_, _, summary)| summary.injected).sum();
    let mut text = String::new();
    text.push_str(include_str!("../campaign/campaigns_head.md"));
    text.push_str(&format!(
        "\n## Result\n\n`{}` ({} scenarios per class and bit rate, seeds {}..{}): {total} scenarios in {:.0} s on {threads} thread(s) of the shared 2-core development machine ({:.0} µs per scenario and thread).\n\n",
        args.command,
        args.scenarios,
        args.seed,
        args.seed + args.scenarios,
        elapsed.as_secs_f64(),
        elapsed.as_secs_f64() * 1e6 * threads as f64 / total.max(1) as f64
    ));
    text.push_str(&report::table(results));
    text.push_str("\n## Bounds, and how they follow from the configuration\n\n");
    text.push_str(&report::bounds(results));
    text.push_str("\n## Plots\n\n");
    text.push_str(&format!(
        "The run writes each class's latency histogram against its bound to `{}` (generated, \
         not committed: `{}` writes them again):\n\n",
        plots.display(),
        args.command
    ));
    for (class, bit_rate, _) in results {
        let name = report::plot_name(*class, *bit_rate);
        text.push_str(&format!(
            "- {} at {} kbit/s: `{name}`\n",
            class.name(),
            bit_rate / 1000,
        ));
    }
    let failures: Vec<_> = results
        .iter()
        .flat_map(|(_, _, summary)| summary.failures.iter())
        .collect();
    if !failures.is_empty() {
        text.push_str("\n## Failed scenarios\n\n");
        for failure in failures.iter().take(20) {
            text.push_str(&format!(
                "- {} at {} kbit/s seed {} ({:?}): {}; replay with `cargo xtask campaign --class {} --bit-rate {} --replay {}`\n",
                failure.class.name(),
                failure.bit_rate / 1000,
                failure.seed,
                failure.outcome,
                failure.fault,
                failure.class.name(),
                failure.bit_rate / 1000,
                failure.seed
            ));
        }
    }
    let path = dir.join("campaigns.md");
    // The SimpleCAN run's section, kept (it is written by its own run).
    let previous = std::fs::read_to_string(&path).unwrap_or_default();
    if let Some(section) = system_tests::campaign::simplecan::section_of(&previous) {
        text.push('\n');
        text.push_str(section);
        text.push('\n');
    }
    std::fs::write(&path, text).map_err(|error| format!("{}: {error}", path.display()))
}
