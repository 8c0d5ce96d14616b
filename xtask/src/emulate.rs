//! `cargo xtask emulate`: one shipped hardware image alone on the emulated STM32F405.
//!
//! The emulator links `unicorn-engine` (GPL-2.0), so it is a program of its own (the
//! `emulator` crate's `emulate` binary) that this task builds and runs; xtask never links it.

use std::path::Path;

use anyhow::Result;

use crate::network::Protocol;
use crate::{cargo, images, toolchain};

/// Builds and seals the shipped images of `protocol`, then runs channel `channel`'s alone
/// for `duration` of virtual time (the emulator's syntax: `500ms`, `2s`), with the node-ID
/// switches set to `node_id`, and prints its decoded log and how the run ended.
pub fn task(
    root: &Path,
    channel: &str,
    duration: &str,
    node_id: u8,
    protocol: Protocol,
) -> Result<()> {
    let cross = toolchain::ensure()?;
    toolchain::ensure_emulator_build_deps()?;
    let layer = protocol.hardware_layer();
    images::build_layer(root, &cross, layer)?;
    let image = images::image(&cross, root, layer, channel);
    let node_id = node_id.to_string();
    crate::run(
        cargo()
            .current_dir(root)
            .args([
                "run",
                "--quiet",
                "--release",
                "-p",
                "emulator",
                "--bin",
                "emulate",
                "--",
            ])
            .arg(image)
            .args(["--for", duration, "--node-id", &node_id]),
    )
}

/// What every shipped image must log, and the line the emulator prints of FLASH_ACR, on its
/// start-up alone on the emulated STM32F405 (switches at node-ID 1, contact closed).
const STARTUP_LINES: [&str; 4] = [
    "self-test: RAM",
    "self-test: image CRC passed",
    "self-test: CAN loop-back",
    "FLASH_ACR at the end: 5 wait states, prefetch on, instruction cache on, data cache on",
];

/// `cargo xtask test`'s check of the shipped images on the emulator: each of the four
/// (both protocols, both channels), already built and sealed, runs alone for a second of
/// virtual time and must pass its start-up self-tests (the RAM test, the image CRC, the CAN
/// controller's message buffers in loop-back: CiA 304 9.5) on the emulated bxCAN, leave the
/// flash accelerator on at 168 MHz's five wait states (RM0090 3.5.1, Table 10), and run the
/// whole second without an unclaimed access, a fault or a reset.
pub fn startup_checks(root: &Path, cross: &toolchain::Cross) -> Result<()> {
    toolchain::ensure_emulator_build_deps()?;
    crate::run(cargo().current_dir(root).args([
        "build",
        "--quiet",
        "--release",
        "-p",
        "emulator",
        "--bin",
        "emulate",
    ]))?;
    let emulate = root.join("target/release/emulate");
    for protocol in [Protocol::CanopenSafety, Protocol::Simplecan] {
        let layer = protocol.hardware_layer();
        for channel in ["a", "b"] {
            let image = images::image(cross, root, layer, channel);
            let output = std::process::Command::new(&emulate)
                .arg(&image)
                .args(["--for", "1s", "--node-id", "1", "--input-closed"])
                .output()?;
            let log = String::from_utf8_lossy(&output.stdout);
            let line = |needle: &str| log.lines().find(|line| line.contains(needle));
            // A self-test line names its test first and says "passed" at the end of its words.
            let passed = STARTUP_LINES.iter().all(|needle| {
                line(needle)
                    .is_some_and(|line| !needle.starts_with("self-test") || line.contains("passed"))
            });
            if !output.status.success() || !passed {
                anyhow::bail!(
                    "{}: the shipped image's start-up on the emulator is not as it must be \
                     (each of {STARTUP_LINES:?} logged, passed, and the whole second run):\n{log}{}",
                    image.display(),
                    String::from_utf8_lossy(&output.stderr)
                );
            }
            println!(
                "xtask: {protocol:?} channel {channel}: start-up self-tests passed on the \
                 emulator, flash accelerator on"
            );
        }
    }
    Ok(())
}
