//! `cargo xtask bench --target-cost`: Thumb instructions the real QEMU images execute in
//! named functions, counted under QEMU (netduinoplus2) one instruction per translation block,
//! and the CPU load they imply at 168 MHz; written into its own block of
//! `docs/performance.md`.
//!
//! How it counts: one image runs alone (no hub: its link times out and it stays in the safe
//! state, but its runtime keeps sending link heartbeats, each with its configuration digest).
//! After the start-up self-tests (the RAM test alone would take minutes traced), QEMU's
//! monitor switches on `one-insn-per-tb` and `-d exec,nochain`, so that the trace has one line
//! per executed instruction with its address. A call of a measured function starts at a line
//! at the function's symbol address reached from a `bl` (4 bytes) and ends at the first line
//! at the address after that `bl`; the lines in between are the instructions executed in the
//! function and everything it called, counted in thread mode only: an interrupt handler that
//! runs during the call (QEMU flags its blocks as handler mode) is not the function's cost.
//! The measured functions compute the same thing at every heartbeat, yet calls differ by a
//! few instructions (an instruction around an interrupt's entry and return traced twice, and
//! in a heartbeat the link messages' varying encodings); the table gives the fewest and the
//! most.

use crate::images::{self, Layer};
use crate::toolchain;
use anyhow::{Context, Result, bail};
use object::{Object, ObjectSymbol};
use std::fmt::Write as _;
use std::io::{BufRead as _, Read as _, Write as _};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The document the block goes to ([`crate::fullnet::replace_block`]'s markers `target-cost`).
const DOCUMENT: &str = "docs/performance.md";
/// The block's marker name.
pub(crate) const MARKER: &str = "target-cost";
/// How long the trace runs. Traced, the image alone spends nearly all its instructions in
/// its SysTick handler reading the host clock by semihosting, and a link heartbeat of the
/// QEMU layer (every 100 ms of host time) comes about every 20 s on a loaded machine.
const TRACE_FOR: Duration = Duration::from_secs(45);
/// A call longer than this is taken for one whose return was not recognised, and dropped.
const ABANDON_AFTER: u64 = 1_000_000;
/// The clock of the STM32F405 in the product.
const CLOCK_HZ: u64 = 168_000_000;
/// The hardware layer's link heartbeat period (`board::hw`): each channel sends its digest
/// once per period and computes it again for the other channel's digest it receives.
const LINK_PERIOD_MS: u64 = 10;
/// SRDOs of the images ([`dual_channel::device::SRDO_COUNT`]) and of the node the load is
/// estimated for.
const IMAGE_SRDOS: u64 = dual_channel::device::SRDO_COUNT as u64;
const LOAD_SRDOS: u64 = 64;

/// One measured function: which image, a piece of its demangled name that names it alone,
/// and what it is.
struct Measured {
    channel: &'static str,
    name: &'static str,
    what: &'static str,
}

const MEASURED: [Measured; 4] = [
    Measured {
        channel: "a",
        name: "as dual_channel::runtime::Role<_>>::signature_digest",
        what: "channel A's configuration digest (`Role::signature_digest`: every SRDO's \
               signature by the `crc` crate's table, folded by CRC-32)",
    },
    Measured {
        channel: "b",
        name: "as dual_channel::runtime::Role<_>>::signature_digest",
        what: "channel B's configuration digest (its own CRC, 4 bits a step, folded by CRC-32)",
    },
    Measured {
        channel: "a",
        name: "dual_channel::runtime::Runtime<F,R,_>::heartbeat",
        what: "channel A's link heartbeat (`Runtime::heartbeat`: the digest, three link \
               messages encoded and queued)",
    },
    Measured {
        channel: "b",
        name: "dual_channel::runtime::Runtime<F,R,_>::heartbeat",
        what: "channel B's link heartbeat",
    },
];

/// `cargo xtask bench --target-cost`.
pub fn run(root: &Path) -> Result<()> {
    let cross = toolchain::ensure()?;
    toolchain::ensure_qemu()?;
    toolchain::ensure_defmt_print()?;
    crate::step("QEMU images (firmware profile)");
    images::build_layer(root, &cross, Layer::Qemu)?;
    let dir = root.join("target/target-cost");
    std::fs::create_dir_all(&dir)?;
    let mut rows = Vec::new();
    for channel in ["a", "b"] {
        let image = images::image(&cross, root, Layer::Qemu, channel);
        let functions: Vec<(&Measured, u32)> = MEASURED
            .iter()
            .filter(|measured| measured.channel == channel)
            .map(|measured| Ok((measured, address(&image, measured.name)?)))
            .collect::<Result<_>>()?;
        crate::step(&format!("channel {channel}: traced under QEMU"));
        let trace = trace(&image, &dir.join(channel))?;
        let entries: Vec<u32> = functions.iter().map(|(_, at)| *at).collect();
        let counts = count_calls(&trace, &entries)?;
        // Hundreds of megabytes; the counts are what was wanted.
        let _ = std::fs::remove_file(&trace);
        for ((measured, _), calls) in functions.into_iter().zip(counts) {
            let (Some(&fewest), Some(&most)) = (calls.iter().min(), calls.iter().max()) else {
                bail!(
                    "channel {channel}: the trace holds no call of {} (the image ran too slowly, \
                     or the function is no longer called by `bl`)",
                    measured.name
                );
            };
            rows.push((measured, fewest, most, calls.len()));
        }
    }
    let block = render(&rows);
    println!("{block}");
    let path = root.join(DOCUMENT);
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("reading {DOCUMENT} (run `cargo xtask bench` first)"))?;
    let updated = match crate::fullnet::replace_block(&text, MARKER, &block) {
        Ok(updated) => updated,
        // No block yet: it goes at the end, with its markers.
        Err(_) => format!(
            "{}\n\n<!-- {MARKER}:begin (generated, do not edit) -->\n{}\n<!-- {MARKER}:end -->\n",
            text.trim_end(),
            block.trim_end()
        ),
    };
    std::fs::write(&path, updated).with_context(|| format!("writing {DOCUMENT}"))?;
    eprintln!("xtask: wrote the {MARKER} block of {DOCUMENT}");
    Ok(())
}

/// The address (Thumb bit cleared) of the one function whose demangled name contains `name`.
fn address(elf: &Path, name: &str) -> Result<u32> {
    let bytes = std::fs::read(elf).with_context(|| format!("reading {}", elf.display()))?;
    let file = object::File::parse(&*bytes)?;
    let found: Vec<u32> = file
        .symbols()
        .filter(|symbol| symbol.kind() == object::SymbolKind::Text)
        .filter(|symbol| {
            symbol
                .name()
                .is_ok_and(|raw| format!("{:#}", rustc_demangle::demangle(raw)).contains(name))
        })
        .map(|symbol| (symbol.address() & !1) as u32)
        .collect();
    match found.as_slice() {
        [address] => Ok(*address),
        [] => bail!(
            "no function named like `{name}` in {} (inlined by the compiler?)",
            elf.display()
        ),
        _ => bail!(
            "{} functions named like `{name}` in {}: the name must pick one",
            found.len(),
            elf.display()
        ),
    }
}

/// Runs `image` alone and returns the path of its instruction trace, taken after the
/// start-up self-tests for [`TRACE_FOR`].
fn trace(image: &Path, dir: &Path) -> Result<PathBuf> {
    std::fs::create_dir_all(dir)?;
    let monitor = dir.join("monitor.sock");
    let log = dir.join("defmt.raw");
    let trace = dir.join("trace.log");
    for stale in [&monitor, &trace] {
        let _ = std::fs::remove_file(stale);
    }
    let mut qemu = Qemu(
        Command::new("qemu-system-arm")
            .args(["-M", "netduinoplus2", "-nographic"])
            .arg("-monitor")
            .arg(format!("unix:{},server,nowait", monitor.display()))
            .args(["-semihosting-config", "enable=on,target=native,arg=node=1"])
            .args(["-serial", "null", "-serial", "null", "-serial", "null"])
            .arg("-kernel")
            .arg(image)
            .stdin(Stdio::null())
            .stdout(std::fs::File::create(&log)?)
            .stderr(Stdio::null())
            .spawn()
            .context("starting qemu-system-arm")?,
    );
    wait_for_log(image, &log, "node-ID", Duration::from_secs(300))?;
    let mut control = Monitor::connect(&monitor)?;
    control.command(&format!("logfile {}", trace.display()))?;
    control.command("one-insn-per-tb on")?;
    control.command("log exec,nochain")?;
    std::thread::sleep(TRACE_FOR);
    control.command("log none")?;
    control.command("quit")?;
    let _ = qemu.0.wait();
    Ok(trace)
}

/// Kills QEMU when dropped, whichever way the measurement ends.
struct Qemu(Child);

impl Drop for Qemu {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Waits until the image's defmt log (decoded) contains `line`.
fn wait_for_log(image: &Path, log: &Path, line: &str, limit: Duration) -> Result<()> {
    let start = Instant::now();
    while start.elapsed() < limit {
        std::thread::sleep(Duration::from_millis(500));
        let raw = std::fs::read(log)?;
        let mut decoder = Command::new("defmt-print")
            .arg("-e")
            .arg(image)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .context("starting defmt-print")?;
        if let Some(mut stdin) = decoder.stdin.take() {
            stdin.write_all(&raw)?;
        }
        let decoded = decoder.wait_with_output()?;
        if String::from_utf8_lossy(&decoded.stdout).contains(line) {
            return Ok(());
        }
    }
    bail!(
        "{} did not log `{line}` within {} s under QEMU",
        image.display(),
        limit.as_secs()
    )
}

/// QEMU's human monitor on a Unix socket.
struct Monitor(std::os::unix::net::UnixStream);

impl Monitor {
    fn connect(path: &Path) -> Result<Self> {
        let stream = std::os::unix::net::UnixStream::connect(path)
            .with_context(|| format!("connecting to QEMU's monitor at {}", path.display()))?;
        stream.set_read_timeout(Some(Duration::from_secs(10)))?;
        let mut monitor = Monitor(stream);
        monitor.prompt()?;
        Ok(monitor)
    }

    /// Sends `command` and waits for the next prompt.
    fn command(&mut self, command: &str) -> Result<()> {
        writeln!(self.0, "{command}")?;
        if command == "quit" {
            return Ok(());
        }
        self.prompt()
            .with_context(|| format!("QEMU's monitor did not answer `{command}`"))
    }

    fn prompt(&mut self) -> Result<()> {
        let mut seen = Vec::new();
        let mut byte = [0u8; 1];
        while !seen.ends_with(b"(qemu) ") {
            if self.0.read(&mut byte)? == 0 {
                bail!("QEMU's monitor closed");
            }
            seen.push(byte[0]);
        }
        Ok(())
    }
}

/// The program counter of one `-d exec` line with one instruction per translation block,
/// `Trace 0: 0x… [flags/pc/…] symbol`, when the instruction ran in thread mode (bit 0 of the
/// block's flags is QEMU's handler-mode flag for M-profile cores).
fn thread_pc(line: &str) -> Option<u32> {
    let fields = line.strip_prefix("Trace ")?.split_once('[')?.1;
    let mut fields = fields.split('/');
    let flags = u32::from_str_radix(fields.next()?, 16).ok()?;
    let pc = u64::from_str_radix(fields.next()?, 16).ok()?;
    (flags & 1 == 0).then_some(pc as u32)
}

/// For each entry address, the thread-mode instructions of every complete call in the trace
/// (an interrupt handler's instructions are not the call's).
fn count_calls(trace: &Path, entries: &[u32]) -> Result<Vec<Vec<u64>>> {
    let file = std::fs::File::open(trace)
        .with_context(|| format!("reading the trace {}", trace.display()))?;
    let mut calls = vec![Vec::new(); entries.len()];
    // Calls in progress: (which function, the address it returns to, instructions so far).
    let mut open: Vec<(usize, u32, u64)> = Vec::new();
    let mut previous: Option<u32> = None;
    for line in std::io::BufReader::new(file).lines() {
        let Some(pc) = thread_pc(&line?) else {
            continue;
        };
        // A return first: the instruction after the call is not part of it.
        open.retain(|&(function, back, count)| {
            if pc == back {
                calls[function].push(count);
                false
            } else {
                true
            }
        });
        for entry in open.iter_mut() {
            entry.2 += 1;
        }
        // One entered otherwise than by `bl` (a tail call) never sees its return address.
        open.retain(|&(_, _, count)| count < ABANDON_AFTER);
        if let (Some(function), Some(from)) = (entries.iter().position(|&at| at == pc), previous) {
            open.push((function, from + 4, 1));
        }
        previous = Some(pc);
    }
    Ok(calls)
}

fn render(rows: &[(&Measured, u64, u64, usize)]) -> String {
    let mut md = String::new();
    let _ = writeln!(
        md,
        "## On the target: Thumb instructions under QEMU\n\n\
         Generated by `cargo xtask bench --target-cost`: the QEMU images (`firmware` profile, as \
         the hardware images are compiled) run alone on QEMU's netduinoplus2, traced one \
         instruction per translation block after their start-up self-tests; a call counts every \
         instruction from the function's entry to the return to its caller, callees included, \
         in thread mode (an interrupt handler running meanwhile is not counted); calls differ by \
         a few instructions, and the table gives the fewest and the most. The images hold {IMAGE_SRDOS} SRDOs; the load column scales the digest to \
         {LOAD_SRDOS} SRDOs ({}×, the digest is one signature per record) and counts it twice per \
         {LINK_PERIOD_MS} ms link period (each channel computes it for its own heartbeat and \
         again for the other channel's digest it receives), at one instruction per cycle of \
         {} MHz: a lower bound, as loads, taken branches and flash wait states take more.\n",
        LOAD_SRDOS / IMAGE_SRDOS,
        CLOCK_HZ / 1_000_000
    );
    let _ = writeln!(
        md,
        "| function | instructions ({IMAGE_SRDOS} SRDOs), fewest | most | calls seen | load at {LOAD_SRDOS} SRDOs, every {LINK_PERIOD_MS} ms, twice |"
    );
    let _ = writeln!(md, "|---|---:|---:|---:|---:|");
    for (measured, instructions, most, calls) in rows {
        let load = if measured.name.ends_with("signature_digest") {
            let per_second = instructions * (LOAD_SRDOS / IMAGE_SRDOS) * 2 * 1000 / LINK_PERIOD_MS;
            format!("{:.1} %", per_second as f64 * 100.0 / CLOCK_HZ as f64)
        } else {
            "–".to_owned()
        };
        let _ = writeln!(
            md,
            "| {} | {instructions} | {most} | {calls} | {load} |",
            measured.what
        );
    }
    let _ = writeln!(
        md,
        "\nNot counted on the target yet: the validated pair, the produced pair and the idle \
         poll beside the x86 figures above. An image alone never hears the other channel, so \
         its core never boots, let alone reaches Operational; and `Runtime::on_frame`, \
         `Node::handle_frame` and `Runtime::poll` are inlined into the main task under fat \
         LTO, so they have no symbol of their own to count between. Counting them needs \
         the emulated network (hub and four images) with one image traced, or markers in the \
         board layer."
    );
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A call is counted from its entry to the return to the instruction after its `bl`,
    /// nested calls included, interrupt handlers not; a call still open at the end of the
    /// trace is not counted.
    #[test]
    fn calls_are_counted_from_entry_to_return() {
        let line = |pc: u32| format!("Trace 0: 0x7f00 [00800408/{pc:016x}/00000110/ff020201] f\n");
        let handler =
            |pc: u32| format!("Trace 0: 0x7f00 [00800409/{pc:016x}/00000110/ff020201] h\n");
        let mut text = String::from("IN: noise\n");
        // bl at 0x100 → 0x200 (3 instructions, one of them a nested call, and an interrupt
        // handler of two that is not counted) → back at 0x104.
        for pc in [0x100, 0x200, 0x202] {
            text.push_str(&line(pc));
        }
        text.push_str(&handler(0x500));
        text.push_str(&handler(0x502));
        for pc in [0x300, 0x104, 0x106] {
            text.push_str(&line(pc));
        }
        // A second call, cut off by the end of the trace.
        text.push_str(&line(0x110));
        text.push_str(&line(0x200));
        let dir = std::env::temp_dir().join(format!("target-cost-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("trace.log");
        std::fs::write(&path, text).unwrap();
        assert_eq!(count_calls(&path, &[0x200]).unwrap(), vec![vec![3]]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
