//! `cargo xtask qemu a|b`: one firmware image alone under QEMU's `netduinoplus2`, its defmt
//! log decoded. With `--selftest` the image stops after its start-up self-tests and the run
//! passes only when QEMU exits with 0 and the log shows the verdict.

use crate::child::Guarded;
use crate::images::{self, Layer};
use crate::toolchain::{self, Cross};
use anyhow::{Context, Result, bail};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

/// Builds both images for QEMU and seals them.
pub fn build(root: &Path, cross: &Cross) -> Result<()> {
    images::build_layer(root, cross, Layer::Qemu).map(drop)
}

/// The QEMU image of `channel` (`a` or `b`).
pub fn image(cross: &Cross, root: &Path, channel: &str) -> PathBuf {
    images::image(cross, root, Layer::Qemu, channel)
}

/// Runs one image alone with semihosting arguments `arguments` (e.g. `selftest`); returns
/// QEMU's exit code (124: the time limit ended it) and the decoded log.
pub fn run_alone(image: &Path, arguments: &[&str], limit: Duration) -> Result<(i32, String)> {
    run_alone_with(image, arguments, limit, &[])
}

/// [`run_alone`] with more of QEMU's options (`extra`, e.g. an instruction trace).
fn run_alone_with(
    image: &Path,
    arguments: &[&str],
    limit: Duration,
    extra: &[&str],
) -> Result<(i32, String)> {
    toolchain::require("qemu-system-arm", "run `cargo xtask setup`")?;
    let mut semihosting = String::from("enable=on,target=native");
    for argument in arguments {
        semihosting.push_str(",arg=");
        semihosting.push_str(argument);
    }
    let mut qemu = Guarded::spawn(
        Command::new("timeout")
            .arg(format!("{}", limit.as_secs()))
            .args([
                "qemu-system-arm",
                "-M",
                "netduinoplus2",
                "-nographic",
                "-monitor",
                "none",
            ])
            .args(["-semihosting-config", &semihosting])
            // USART1 and USART3 unused, USART2 the CAN bridge (and, on a network, the link through
            // the hub): nothing attached when alone.
            .args([
                "-serial", "null", "-serial", "null", "-serial", "null", "-kernel",
            ])
            .arg(image)
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::null()),
    )
    .context("starting qemu-system-arm")?;
    let mut raw = Vec::new();
    if let Some(mut stdout) = qemu.take_stdout() {
        std::io::Read::read_to_end(&mut stdout, &mut raw)?;
    }
    let status = qemu.wait()?;
    let log = crate::defmt_log::decode(image, &raw)?;
    // `timeout` exits with 124 when the limit ended the run.
    Ok((status.code().unwrap_or(-1), log))
}

/// The start-up self-tests' cost, counted in one image's run to its self-test verdict: one
/// line per executed instruction (`one-insn-per-tb`, `-d exec,nochain`), thread mode only,
/// from the entry of each function to the return to the instruction after its `bl`.
/// `__pre_init` is the RAM test (`board::ram`, from the reset handler, on the 16 MHz HSI
/// oscillator); `board::self_test`, one call per test of
/// `dual_channel::selftest::SELF_TESTS`, runs after the clocks are raised to 168 MHz.
fn count_self_tests(image: &Path, seconds: u64) -> Result<()> {
    use std::io::BufRead as _;
    let names = ["__pre_init", "board::self_test"];
    let bytes = std::fs::read(image).with_context(|| format!("reading {}", image.display()))?;
    let file = object::File::parse(&*bytes)?;
    let entries = names.map(|name| {
        use object::{Object as _, ObjectSymbol as _};
        file.symbols()
            .filter(|symbol| symbol.kind() == object::SymbolKind::Text)
            .find(|symbol| {
                symbol
                    .name()
                    .is_ok_and(|raw| format!("{:#}", rustc_demangle::demangle(raw)) == name)
            })
            .map(|symbol| (symbol.address() & !1) as u32)
    });
    let Some(entries) = entries.into_iter().collect::<Option<Vec<u32>>>() else {
        bail!(
            "{} has no function `__pre_init` or `board::self_test`",
            image.display()
        );
    };
    let trace = image.with_extension("selftest.trace");
    let log = trace.display().to_string();
    let (code, _) = run_alone_with(
        image,
        &["selftest"],
        Duration::from_secs(seconds),
        &[
            "-accel",
            "tcg,one-insn-per-tb=on",
            "-d",
            "exec,nochain",
            "-D",
            &log,
        ],
    )?;
    if code != 0 {
        bail!("the traced self-test run ended with {code}, not 0 (raise --seconds?)");
    }
    // (function, the address it returns to, its instructions so far); calls do not nest.
    let mut open: Option<(usize, u32, u64)> = None;
    let mut calls: Vec<(usize, u64)> = Vec::new();
    let mut previous = None;
    let reader = std::io::BufReader::with_capacity(1 << 20, std::fs::File::open(&trace)?);
    for line in reader.split(b'\n') {
        let Some((pc, false)) = crate::target_cost::count::exec_pc(&line?) else {
            continue;
        };
        if let Some((function, back, count)) = open {
            if pc == back {
                calls.push((function, count));
                open = None;
            } else {
                open = Some((function, back, count + 1));
            }
        }
        if let (None, Some(function), Some(from)) =
            (open, entries.iter().position(|&at| at == pc), previous)
        {
            open = Some((function, from + 4, 1));
        }
        previous = Some(pc);
    }
    // Hundreds of megabytes; the counts are what was wanted.
    let _ = std::fs::remove_file(&trace);
    let ram: Vec<u64> = calls.iter().filter(|c| c.0 == 0).map(|c| c.1).collect();
    let tests: Vec<u64> = calls.iter().filter(|c| c.0 == 1).map(|c| c.1).collect();
    let ([ram], [ram_verdict, image_crc, known_answer]) = (ram.as_slice(), tests.as_slice()) else {
        bail!(
            "the trace holds {} RAM tests and {} self-test calls, not 1 and 3",
            ram.len(),
            tests.len()
        );
    };
    let ms = |instructions: u64, mhz: u64| instructions as f64 / (mhz as f64 * 1000.0);
    println!(
        "xtask: RAM test (March C-, before start-up): {ram} instructions, {:.1} ms at one a \
         cycle on the 16 MHz HSI",
        ms(*ram, 16)
    );
    let after = ram_verdict + image_crc + known_answer;
    println!(
        "xtask: self_test: RAM verdict {ram_verdict}, image CRC {image_crc}, CRC known answer \
         {known_answer} instructions; {after} in all, {:.2} ms at one a cycle at 168 MHz",
        ms(after, 168)
    );
    Ok(())
}

/// `cargo xtask qemu`; with `count`, the self-tests' instructions ([`count_self_tests`]).
pub fn task(root: &Path, channel: &str, selftest: bool, count: bool, seconds: u64) -> Result<()> {
    let cross = toolchain::ensure()?;
    toolchain::ensure_qemu()?;
    build(root, &cross)?;
    let image = image(&cross, root, channel);
    if count {
        return count_self_tests(&image, seconds);
    }
    let arguments: &[&str] = if selftest { &["selftest"] } else { &[] };
    let (code, log) = run_alone(&image, arguments, Duration::from_secs(seconds))?;
    print!("{log}");
    if selftest {
        if code != 0 || !log.contains("self-test verdict: true") {
            bail!("channel {channel}: self-test under QEMU failed");
        }
        println!("xtask: channel {channel}: self-test passed under QEMU");
    }
    Ok(())
}
