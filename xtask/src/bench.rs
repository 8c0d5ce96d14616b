//! `cargo xtask bench`: instruction counts of the hot paths (callgrind), the same paths on
//! nodes of 1, 4, 16 and 64 SRDOs, RAM per SRDO on the target, and the configuration tool's
//! speed on the host simulation (`tests/src/bin/tool_bench.rs`), written to
//! `docs/performance.md`; the counts also to `docs/performance.json` for machines.
//!
//! Instruction counts, unlike times, repeat exactly for the same binary and input whatever
//! else the machine does, so they can be compared with the reference figures and across
//! commits. Wall time is in `cargo bench -p shared --bench wall_time` (criterion).

use crate::images::{self, Layer};
use crate::toolchain;
use anyhow::{Context, Result, bail};
use object::{Object, ObjectSection, ObjectSymbol};
use std::fmt::Write as _;
use std::path::Path;
use std::process::Command;

/// Iterations per measured path.
const ITERATIONS: u64 = 10_000;

/// Pairs per run of a path at scale (a multiple of every SRDO count).
const SCALE_PAIRS: u64 = 6_400;

/// The SRDO counts the paths are measured at.
const SCALE_SRDOS: [u64; 4] = [1, 4, 16, 64];

/// How far the per-pair figures of a path may grow with the SRDO count (the largest at most
/// this much above the one at 1 SRDO), and how far what one more pair adds may spread over
/// the counts (the largest at most this much above the smallest). A scan over the SRDOs per
/// frame or per pair would break either; a producer's poll, whose own work is shared by its
/// pairs, makes the per-pair figure fall, which is no growth.
const SCALE_SPREAD: f64 = 0.10;

/// One measured path: the example's mode, the functions callgrind counts inside (a pattern:
/// the linker may fold a measured function with an identical one of the scaled paths and
/// keep either name), the target and the reference C stack's figure (x86-64).
struct HotPath {
    mode: &'static str,
    function: &'static str,
    what: &'static str,
    /// `None`: reported, no target.
    target: Option<u64>,
    /// `None`: the reference stack has no such path.
    reference: Option<u64>,
}

const PATHS: [HotPath; 4] = [
    HotPath {
        mode: "validated-pair",
        function: "receive_pair*",
        what: "validated 8-byte SRDO pair received",
        target: Some(250),
        reference: Some(689),
    },
    HotPath {
        mode: "produced-pair",
        function: "produce*",
        what: "8-byte SRDO pair produced",
        target: Some(250),
        reference: Some(622),
    },
    HotPath {
        mode: "idle-poll",
        function: "idle",
        what: "idle poll, nothing due",
        target: Some(4),
        reference: Some(85),
    },
    HotPath {
        mode: "integrity-check",
        function: "check*",
        what: "periodic integrity check in Operational (its own poll)",
        target: None,
        reference: None,
    },
];

/// A path measured at scale: the example's mode, the functions counted, and what it is.
struct ScaledPath {
    mode: &'static str,
    function: &'static str,
    what: &'static str,
}

const SCALED: [ScaledPath; 2] = [
    ScaledPath {
        mode: "validated-pair-at",
        function: "receive_pair*",
        what: "validated pair",
    },
    ScaledPath {
        mode: "produced-pair-at",
        function: "produce*",
        what: "produced pair",
    },
];

/// One path at the SRDO counts: instructions per pair at each.
struct Scaled {
    path: &'static ScaledPath,
    per_pair: Vec<f64>,
}

impl Scaled {
    /// How far the largest per-pair figure is above the smallest, as a fraction of it.
    fn spread(&self) -> f64 {
        spread(&self.per_pair)
    }

    /// How far the largest per-pair figure is above the one at 1 SRDO, as a fraction of it
    /// (0 when none is above it).
    fn growth(&self) -> f64 {
        let first = self.per_pair.first().copied().unwrap_or(0.0);
        let high = self.per_pair.iter().copied().fold(first, f64::max);
        high / first - 1.0
    }

    /// What each pair adds between one SRDO count and the next: the difference of the
    /// instructions per transmitting poll (or per pair received, times the pairs) divided by
    /// the difference of the counts. Without a scan over the SRDOs it is the same at every
    /// count.
    fn marginal(&self) -> Vec<f64> {
        SCALE_SRDOS
            .windows(2)
            .zip(self.per_pair.windows(2))
            .map(|(counts, per_pair)| {
                let (low, high) = (counts[0] as f64, counts[1] as f64);
                (per_pair[1] * high - per_pair[0] * low) / (high - low)
            })
            .collect()
    }
}

/// The largest of `values` above the smallest, as a fraction of the smallest.
fn spread(values: &[f64]) -> f64 {
    let low = values.iter().copied().fold(f64::INFINITY, f64::min);
    let high = values.iter().copied().fold(0.0, f64::max);
    if low > 0.0 { high / low - 1.0 } else { 0.0 }
}

/// Instructions callgrind counted inside `function` (a pattern) in one run of the example.
fn count(binary: &Path, name: &str, function: &str, args: &[String]) -> Result<u64> {
    let out = std::env::temp_dir().join(format!("callgrind.{name}.out"));
    let status = Command::new("valgrind")
        .arg("--tool=callgrind")
        .arg(format!("--toggle-collect=hot_paths::{function}"))
        .arg(format!("--callgrind-out-file={}", out.display()))
        .arg(binary)
        .args(args)
        .stderr(std::process::Stdio::null())
        .status()?;
    if !status.success() {
        bail!("{name} under callgrind failed ({status})");
    }
    let total = totals(&std::fs::read_to_string(&out)?)
        .with_context(|| format!("no totals in {}", out.display()))?;
    if total == 0 {
        bail!("callgrind counted nothing inside hot_paths::{function} in {name}");
    }
    Ok(total)
}

/// RAM per SRDO target and the reference C stack's figure (Cortex-M4).
const RAM_TARGET: u64 = 160;
const RAM_REFERENCE: u64 = 676;

pub fn run(root: &Path, check: bool) -> Result<()> {
    toolchain::require("valgrind", "install Debian's valgrind package")?;
    crate::step("hot paths (release build of shared/examples/hot_paths.rs)");
    crate::run(crate::cargo().args([
        "build",
        "--release",
        "-p",
        "shared",
        "--example",
        "hot_paths",
    ]))?;
    let binary = root.join("target/release/examples/hot_paths");
    let mut rows = Vec::new();
    for path in &PATHS {
        let args = [path.mode.to_owned(), ITERATIONS.to_string()];
        let total = count(&binary, path.mode, path.function, &args)?;
        rows.push((path, total as f64 / ITERATIONS as f64));
    }
    crate::step("the hot paths on nodes of 1, 4, 16 and 64 SRDOs");
    let mut scaled = Vec::new();
    for path in &SCALED {
        let mut per_pair = Vec::new();
        for srdos in SCALE_SRDOS {
            let args = [
                path.mode.to_owned(),
                srdos.to_string(),
                SCALE_PAIRS.to_string(),
            ];
            let name = format!("{}.{srdos}", path.mode);
            let total = count(&binary, &name, path.function, &args)?;
            per_pair.push(total as f64 / SCALE_PAIRS as f64);
        }
        scaled.push(Scaled { path, per_pair });
    }

    crate::step("RAM per SRDO in the thumbv7em image");
    let cross = toolchain::ensure()?;
    crate::run(&mut images::cargo(&cross, root, "build", Layer::Hw))?;
    let image = images::image(&cross, root, Layer::Hw, "a");
    let ram = symbol_u32(&image, "SHARED_RAM_PER_SRDO")?;

    let rustc = rustc_version();
    let mut report = render(&rows, &scaled, ram, &rustc);
    let json = serde_json::to_string_pretty(&machine_readable(&rows, &scaled, ram, &rustc))?;
    std::fs::write(root.join("docs/performance.json"), format!("{json}\n"))?;
    crate::step("configuration tool: one node with 16 SRDOs on the host simulation");
    let tool = crate::cargo()
        .args([
            "run",
            "--quiet",
            "--release",
            "-p",
            "system-tests",
            "--bin",
            "tool_bench",
        ])
        .output()?;
    if !tool.status.success() {
        bail!(
            "the configuration tool's benchmark failed: {}",
            String::from_utf8_lossy(&tool.stderr)
        );
    }
    report.push_str(&String::from_utf8_lossy(&tool.stdout));
    let docs = root.join("docs");
    std::fs::create_dir_all(&docs)?;
    let path = docs.join("performance.md");
    // What other commands write here is kept as they wrote it: python-canopen beside the tool
    // (`cargo xtask interop --bench`, which needs the emulated network), the full network's
    // speed (`cargo xtask fullnet`) and the target's figures (`cargo xtask bench --target-cost`).
    let previous = std::fs::read_to_string(&path).unwrap_or_default();
    if let Some(section) = crate::interop::kept_section(&previous) {
        report = crate::interop::with_section(&report, section);
    }
    keep_blocks(&mut report, &previous);
    std::fs::write(&path, &report)?;
    println!("{report}");

    let mut over = Vec::new();
    for (path, per_op) in &rows {
        if let Some(target) = path.target.filter(|&target| *per_op > target as f64) {
            over.push(format!("{}: {per_op:.0} > {target}", path.what));
        }
    }
    if u64::from(ram) > RAM_TARGET {
        over.push(format!("RAM per SRDO: {ram} > {RAM_TARGET}"));
    }
    for path in &scaled {
        if path.growth() > SCALE_SPREAD {
            over.push(format!(
                "{} per pair at 4 to 64 SRDOs is up to {:.1} % above the one at 1 > {:.0} %",
                path.path.what,
                100.0 * path.growth(),
                100.0 * SCALE_SPREAD
            ));
        }
        let marginal = spread(&path.marginal());
        if marginal > SCALE_SPREAD {
            over.push(format!(
                "what one more {} adds spreads {:.1} % over 4 to 64 SRDOs > {:.0} %",
                path.path.what,
                100.0 * marginal,
                100.0 * SCALE_SPREAD
            ));
        }
    }
    if !over.is_empty() {
        let message = format!("over target: {}", over.join("; "));
        if check {
            bail!(message);
        }
        eprintln!("xtask: {message}");
    }
    Ok(())
}

/// The generated block `name` of `text`, its markers included.
fn generated_block(text: &str, name: &str) -> Option<String> {
    let start = text.find(&format!("<!-- {name}:begin"))?;
    let end_marker = format!("<!-- {name}:end -->");
    let end = start + text[start..].find(&end_marker)? + end_marker.len();
    Some(format!("{}\n", &text[start..end]))
}

/// Appends to `report` the blocks other commands wrote into `previous`, each after one blank
/// line (the kept section before them may end in any number of them), so that rewriting the
/// page again gives the same page.
fn keep_blocks(report: &mut String, previous: &str) {
    for name in [
        crate::fullnet::TIMING_MARKER,
        crate::target_cost::MARKER,
        crate::target_cost::SIMPLECAN_MARKER,
        crate::emulate::SPEED_MARKER,
    ] {
        if let Some(kept) = generated_block(previous, name) {
            report.truncate(report.trim_end().len());
            report.push_str("\n\n");
            report.push_str(&kept);
        }
    }
}

/// The `totals:` (or `summary:`) line of a callgrind output file.
fn totals(callgrind: &str) -> Option<u64> {
    callgrind
        .lines()
        .find_map(|line| {
            line.strip_prefix("totals:")
                .or(line.strip_prefix("summary:"))
        })
        .and_then(|value| value.split_whitespace().next())
        .and_then(|value| value.parse().ok())
}

/// The value of a `u32` static in an ELF image.
fn symbol_u32(elf: &Path, name: &str) -> Result<u32> {
    let bytes = std::fs::read(elf).with_context(|| format!("reading {}", elf.display()))?;
    let file = object::File::parse(&*bytes)?;
    let symbol = file
        .symbols()
        .find(|symbol| symbol.name() == Ok(name))
        .with_context(|| format!("{name} not in {}", elf.display()))?;
    let section =
        file.section_by_index(symbol.section_index().context("symbol without section")?)?;
    let offset = symbol.address() - section.address();
    let data = section.data()?;
    let start = usize::try_from(offset)?;
    let value = data
        .get(start..start + 4)
        .context("symbol outside its section")?;
    Ok(u32::from_le_bytes(value.try_into()?))
}

fn rustc_version() -> String {
    Command::new("rustc")
        .arg("--version")
        .output()
        .ok()
        .map(|out| String::from_utf8_lossy(&out.stdout).trim().to_owned())
        .unwrap_or_else(|| "rustc (unknown version)".to_owned())
}

/// The figures of the report for machines (`docs/performance.json`).
fn machine_readable(
    rows: &[(&HotPath, f64)],
    scaled: &[Scaled],
    ram: u32,
    rustc: &str,
) -> serde_json::Value {
    let paths: Vec<_> = rows
        .iter()
        .map(|(path, per_op)| {
            serde_json::json!({
                "path": path.mode,
                "what": path.what,
                "instructions": (per_op * 10.0).round() / 10.0,
                "target": path.target,
                "reference_c_stack": path.reference,
            })
        })
        .collect();
    let at_scale: Vec<_> = scaled
        .iter()
        .map(|path| {
            let round = |value: f64| (value * 10.0).round() / 10.0;
            serde_json::json!({
                "path": path.path.mode,
                "what": path.path.what,
                "srdos": SCALE_SRDOS,
                "instructions_per_pair": path.per_pair.iter().copied().map(round).collect::<Vec<_>>(),
                "spread_percent": round(100.0 * path.spread()),
                "marginal_per_pair": path.marginal().into_iter().map(round).collect::<Vec<_>>(),
                "marginal_spread_percent": round(100.0 * spread(&path.marginal())),
                "spread_target_percent": 100.0 * SCALE_SPREAD,
            })
        })
        .collect();
    serde_json::json!({
        "generated_by": "cargo xtask bench",
        "rustc": rustc,
        "host": "x86-64, release profile, callgrind instruction counts",
        "iterations": ITERATIONS,
        "hot_paths": paths,
        "ram_per_srdo": { "bytes": ram, "target": RAM_TARGET, "reference_c_stack": RAM_REFERENCE },
        "at_scale": { "pairs_per_run": SCALE_PAIRS, "paths": at_scale },
    })
}

fn render(rows: &[(&HotPath, f64)], scaled: &[Scaled], ram: u32, rustc: &str) -> String {
    let mut md = String::new();
    let _ = writeln!(md, "# Performance of the protocol core\n");
    let _ = writeln!(
        md,
        "Generated by `cargo xtask bench` ({rustc}, x86-64, release profile). Instruction \
         counts are callgrind's, counted only inside the measured function, over {ITERATIONS} \
         iterations, divided by the iterations; they repeat exactly for the same binary. The \
         reference is the best open-source C stack on the same paths.\n"
    );
    let _ = writeln!(md, "| path | instructions | target | reference C stack |");
    let _ = writeln!(md, "|------|-------------:|-------:|------------------:|");
    for (path, per_op) in rows {
        let target = path
            .target
            .map_or("–".to_owned(), |target| format!("≤ {target}"));
        let reference = path
            .reference
            .map_or("–".to_owned(), |reference| reference.to_string());
        let _ = writeln!(
            md,
            "| {} | {per_op:.0} | {target} | {reference} |",
            path.what
        );
    }
    let _ = writeln!(
        md,
        "| RAM per SRDO (state + mapping + record), thumbv7em | {ram} bytes | ≤ {RAM_TARGET} | {RAM_REFERENCE} |\n"
    );
    let _ = writeln!(
        md,
        "What is measured (see `shared/examples/hot_paths.rs`):\n\n\
         - *validated pair*: node 33, Operational, SRDO 1 mapped to two 32-bit outputs with \
         their inverted copies (8 bytes per frame). Both frames through `Node::handle_frame`: \
         identifier lookup, order, SRVT and SCT checks, bit-by-bit inversion, delivery into the \
         object dictionary and the `SrdoReceived` event.\n\
         - *produced pair*: node 1, the poll at which the cyclic transmission is due: gather the \
         mapped inputs, check that the halves are inverses, hand both frames to the sink, \
         reschedule.\n\
         - *idle poll*: `Node::poll` before the next deadline.\n\
         - *integrity check*: node 1 as for the produced pair, the poll at which the periodic \
         check of the configuration in use is due (every refresh time): the Operational-entry \
         check again, the tables derived again and compared (`shared/src/node/srdo_table/\
         integrity.rs`).\n\
         - *RAM per SRDO*: `shared::node::RAM_PER_SRDO` as compiled into the channel-a image \
         (read from the ELF symbol `SHARED_RAM_PER_SRDO`); a compile-time assertion keeps it \
         at or below {RAM_TARGET} on every target.\n\n\
         Wall time: `cargo bench -p shared --bench wall_time` (criterion; machine-dependent).\n\n\
         The full network at scale (127 dual-channel nodes at 1 Mbit/s) and the measured \
         reaction times: [network-performance.md](network-performance.md) (`cargo xtask \
         fullnet`, `cargo xtask reaction`)."
    );
    render_scaled(&mut md, scaled);
    md
}

/// The section of the paths at 1 to 64 SRDOs.
fn render_scaled(md: &mut String, scaled: &[Scaled]) {
    let _ = writeln!(md, "\n## The hot paths at 1, 4, 16 and 64 SRDOs\n");
    let _ = writeln!(
        md,
        "The same two paths on a node with that many SRDOs configured and running (modes \
         `validated-pair-at` and `produced-pair-at` of `shared/examples/hot_paths.rs`), \
         {SCALE_PAIRS} pairs per run, instructions per pair. The consumer (node 33, all its \
         SRDOs receiving, on identifiers 101h.. in turn) is fed its SRDOs' pairs in turn, \
         every 500 µs; it finds each frame's SRDO in the identifier table built at the \
         Operational entry, so a frame costs the same whatever the count. The producer's \
         SRDOs (node 1, all transmitting) share the pre-defined refresh time, so each \
         transmitting poll sends one pair per SRDO: the per-pair figure carries the poll's \
         own work divided by the count, and falls with it; *per added pair* is what one more \
         SRDO adds to a run (the difference of the instructions per poll divided by the \
         difference of the counts), which a scan over the SRDOs per frame or per pair would \
         make grow. Target: no per-pair figure more than {:.0} % above the one at 1 SRDO, and \
         what one more pair adds within {:.0} % at every count. Also in \
         `docs/performance.json`.\n",
        100.0 * SCALE_SPREAD,
        100.0 * SCALE_SPREAD
    );
    let counts: Vec<String> = SCALE_SRDOS
        .iter()
        .map(|&n| format!("{n} SRDO{}", if n == 1 { "" } else { "s" }))
        .collect();
    let _ = writeln!(md, "| path | {} | spread |", counts.join(" | "));
    let _ = writeln!(
        md,
        "|------|{}-------:|",
        "------:|".repeat(SCALE_SRDOS.len())
    );
    for path in scaled {
        let cells: Vec<String> = path.per_pair.iter().map(|v| format!("{v:.1}")).collect();
        let _ = writeln!(
            md,
            "| {} | {} | {:.1} % |",
            path.path.what,
            cells.join(" | "),
            100.0 * path.spread()
        );
        let marginal = path.marginal();
        let cells: Vec<String> = std::iter::once("".to_owned())
            .chain(marginal.iter().map(|v| format!("{v:.1}")))
            .collect();
        let _ = writeln!(
            md,
            "| {}, per added pair | {} | {:.1} % |",
            path.path.what,
            cells.join(" | "),
            100.0 * spread(&marginal)
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The page is rewritten whole; another command's block is found with its markers, so
    /// that it can be kept.
    #[test]
    fn another_commands_block_is_found_with_its_markers() {
        let page = "# Performance\n\nold table\n\n\
                    <!-- target-cost:begin (generated, do not edit) -->\nfigures\n\
                    <!-- target-cost:end -->\ntrailing\n";
        assert_eq!(
            generated_block(page, "target-cost").as_deref(),
            Some(
                "<!-- target-cost:begin (generated, do not edit) -->\nfigures\n\
                 <!-- target-cost:end -->\n"
            )
        );
        assert_eq!(generated_block(page, "fullnet-timing"), None);
    }

    /// A path whose figures do not move has no spread; a doubling is a spread of 100 %; what
    /// a pair adds is the slope of the instructions per run over the counts.
    #[test]
    fn spread_and_what_a_pair_adds() {
        assert_eq!(spread(&[200.0, 200.0, 200.0]), 0.0);
        assert!((spread(&[100.0, 200.0, 150.0]) - 1.0).abs() < 1e-12);
        static PATH: ScaledPath = ScaledPath {
            mode: "produced-pair-at",
            function: "produce*",
            what: "produced pair",
        };
        // A poll costing 100 plus 200 per pair: per pair 300, 225, 206.25, 201.5625.
        let per_pair = SCALE_SRDOS
            .iter()
            .map(|&n| (100.0 + 200.0 * n as f64) / n as f64)
            .collect();
        let scaled = Scaled {
            path: &PATH,
            per_pair,
        };
        assert!(scaled.marginal().iter().all(|m| (m - 200.0).abs() < 1e-9));
        assert!((scaled.spread() - (300.0 / 201.5625 - 1.0)).abs() < 1e-12);
        assert_eq!(
            scaled.growth(),
            0.0,
            "a per-pair figure that falls does not grow"
        );
        // A scan over the SRDOs per pair (10 per SRDO configured): it grows, and what a pair
        // adds grows with the count.
        let scanning = Scaled {
            path: &PATH,
            per_pair: SCALE_SRDOS
                .iter()
                .map(|&n| 200.0 + 10.0 * n as f64)
                .collect(),
        };
        assert!(scanning.growth() > SCALE_SPREAD);
        assert!(spread(&scanning.marginal()) > SCALE_SPREAD);
    }

    /// Each kept block follows one blank line, however many the text before it ended with,
    /// so a page rewritten from itself is the same page.
    #[test]
    fn kept_blocks_are_kept_once_and_the_page_does_not_grow() {
        let page = "# Performance\n\ntable\n\n\n\n\
                    <!-- fullnet-timing:begin (generated, do not edit) -->\nspeed\n\
                    <!-- fullnet-timing:end -->\n\n\
                    <!-- target-cost:begin (generated, do not edit) -->\nfigures\n\
                    <!-- target-cost:end -->\n";
        let mut once = "# Performance\n\ntable\n\n\n".to_owned();
        keep_blocks(&mut once, page);
        assert_eq!(
            once,
            "# Performance\n\ntable\n\n\
             <!-- fullnet-timing:begin (generated, do not edit) -->\nspeed\n\
             <!-- fullnet-timing:end -->\n\n\
             <!-- target-cost:begin (generated, do not edit) -->\nfigures\n\
             <!-- target-cost:end -->\n"
        );
        let mut twice = "# Performance\n\ntable\n\n\n".to_owned();
        keep_blocks(&mut twice, &once);
        assert_eq!(twice, once);
    }
}
