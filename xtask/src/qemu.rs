//! `cargo xtask qemu a|b`: one firmware image alone under QEMU's `netduinoplus2`, its defmt
//! log decoded. With `--selftest` the image stops after its start-up self-tests and the run
//! passes only when QEMU exits with 0 and the log shows the verdict.

use crate::images::{self, Layer};
use crate::toolchain::{self, Cross};
use anyhow::{Context, Result, bail};
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

/// Builds both images for QEMU and seals them.
pub fn build(root: &Path, cross: &Cross) -> Result<()> {
    images::build_layer(root, cross, Layer::Qemu)
}

/// The QEMU image of `channel` (`a` or `b`).
pub fn image(cross: &Cross, root: &Path, channel: &str) -> PathBuf {
    images::image(cross, root, Layer::Qemu, channel)
}

/// Runs one image alone with semihosting arguments `arguments` (e.g. `selftest`); returns
/// QEMU's exit code (124: the time limit ended it) and the decoded log.
pub fn run_alone(image: &Path, arguments: &[&str], limit: Duration) -> Result<(i32, String)> {
    toolchain::require("qemu-system-arm", "run `cargo xtask setup`")?;
    toolchain::require("defmt-print", "run `cargo xtask setup`")?;
    let mut semihosting = String::from("enable=on,target=native");
    for argument in arguments {
        semihosting.push_str(",arg=");
        semihosting.push_str(argument);
    }
    let mut qemu = Command::new("timeout")
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
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .context("starting qemu-system-arm")?;
    let mut raw = Vec::new();
    if let Some(mut stdout) = qemu.stdout.take() {
        std::io::Read::read_to_end(&mut stdout, &mut raw)?;
    }
    let status = qemu.wait()?;
    let mut decoder = Command::new("defmt-print")
        .arg("-e")
        .arg(image)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .context("starting defmt-print")?;
    if let Some(mut stdin) = decoder.stdin.take() {
        stdin.write_all(&raw)?;
    }
    let decoded = decoder.wait_with_output()?;
    let log = String::from_utf8_lossy(&decoded.stdout).into_owned();
    // `timeout` exits with 124 when the limit ended the run.
    Ok((status.code().unwrap_or(-1), log))
}

/// `cargo xtask qemu`.
pub fn task(root: &Path, channel: &str, selftest: bool, seconds: u64) -> Result<()> {
    let cross = toolchain::ensure()?;
    toolchain::ensure_qemu()?;
    toolchain::ensure_defmt_print()?;
    build(root, &cross)?;
    let image = image(&cross, root, channel);
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
