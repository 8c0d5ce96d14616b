//! `cargo xtask bench`: instruction counts of the hot paths (callgrind) and RAM per SRDO on
//! the target, and the configuration tool's speed on the host simulation
//! (`tests/src/bin/tool_bench.rs`), written to `docs/performance.md`.
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

/// One measured path: the example's mode, the function callgrind counts inside, the target
/// and the reference C stack's figure (x86-64).
struct HotPath {
    mode: &'static str,
    function: &'static str,
    what: &'static str,
    target: u64,
    reference: u64,
}

const PATHS: [HotPath; 3] = [
    HotPath {
        mode: "validated-pair",
        function: "receive_pair",
        what: "validated 8-byte SRDO pair received",
        target: 345,
        reference: 689,
    },
    HotPath {
        mode: "produced-pair",
        function: "produce",
        what: "8-byte SRDO pair produced",
        target: 345,
        reference: 622,
    },
    HotPath {
        mode: "idle-poll",
        function: "idle",
        what: "idle poll, nothing due",
        target: 40,
        reference: 85,
    },
];

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
        let out = std::env::temp_dir().join(format!("callgrind.{}.out", path.mode));
        let status = Command::new("valgrind")
            .arg("--tool=callgrind")
            .arg(format!("--toggle-collect=hot_paths::{}", path.function))
            .arg(format!("--callgrind-out-file={}", out.display()))
            .arg(&binary)
            .args([path.mode, &ITERATIONS.to_string()])
            .stderr(std::process::Stdio::null())
            .status()?;
        if !status.success() {
            bail!("{} under callgrind failed ({status})", path.mode);
        }
        let total = totals(&std::fs::read_to_string(&out)?)
            .with_context(|| format!("no totals in {}", out.display()))?;
        rows.push((path, total as f64 / ITERATIONS as f64));
    }

    crate::step("RAM per SRDO in the thumbv7em image");
    let cross = toolchain::ensure()?;
    crate::run(&mut images::cargo(&cross, root, "build", Layer::Hw))?;
    let image = images::image(&cross, root, Layer::Hw, "a");
    let ram = symbol_u32(&image, "SHARED_RAM_PER_SRDO")?;

    let mut report = render(&rows, ram, &rustc_version());
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
        if *per_op > path.target as f64 {
            over.push(format!("{}: {per_op:.0} > {}", path.what, path.target));
        }
    }
    if u64::from(ram) > RAM_TARGET {
        over.push(format!("RAM per SRDO: {ram} > {RAM_TARGET}"));
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

fn render(rows: &[(&HotPath, f64)], ram: u32, rustc: &str) -> String {
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
        let _ = writeln!(
            md,
            "| {} | {per_op:.0} | ≤ {} | {} |",
            path.what, path.target, path.reference
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
         - *RAM per SRDO*: `shared::node::RAM_PER_SRDO` as compiled into the channel-a image \
         (read from the ELF symbol `SHARED_RAM_PER_SRDO`); a compile-time assertion keeps it \
         at or below {RAM_TARGET} on every target.\n\n\
         Wall time: `cargo bench -p shared --bench wall_time` (criterion; machine-dependent).\n\n\
         The full network at scale (127 dual-channel nodes at 1 Mbit/s) and the measured \
         reaction times: [network-performance.md](network-performance.md) (`cargo xtask \
         fullnet`, `cargo xtask reaction`)."
    );
    md
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
