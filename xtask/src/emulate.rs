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
