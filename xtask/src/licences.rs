//! The licence boundary: the product is MIT OR Apache-2.0; `unicorn-engine` (and the QEMU
//! code in it) is GPL-2.0, and so the `emulator` crate that links it is GPL-2.0-or-later.
//! Nothing that ships may link either: the firmware crates, the protocol core and the
//! configuration tool with its library. `cargo xtask test` checks the dependency trees.

use anyhow::{Result, bail};

/// The crates that ship (firmware, the protocol core, the tool), with the features their
/// shipped builds use.
const SHIPPED: [(&str, &str); 6] = [
    ("shared", ""),
    ("dual-channel", ""),
    ("board", "board/hw"),
    ("channel-a", "board/hw"),
    ("channel-b", "board/hw"),
    ("safety-config", ""),
];

/// The GPL crates no shipped crate may depend on.
const GPL: [&str; 3] = ["unicorn-engine", "unicorn-engine-sys", "emulator"];

/// Fails when a shipped crate depends, on any target, on a GPL crate.
pub fn check() -> Result<()> {
    for (krate, features) in SHIPPED {
        let mut command = crate::cargo();
        command.args([
            "tree",
            "--quiet",
            "-p",
            krate,
            "-e",
            "normal,build",
            "--target",
            "all",
            "--prefix",
            "none",
            "-f",
            "{p}",
        ]);
        if !features.is_empty() {
            command.args(["--features", features]);
        }
        let output = command.output()?;
        if !output.status.success() {
            bail!(
                "cargo tree for {krate} failed: {}",
                String::from_utf8_lossy(&output.stderr)
            );
        }
        let tree = String::from_utf8_lossy(&output.stdout);
        if let Some(line) = tree.lines().find(|line| {
            GPL.iter()
                .any(|gpl| line.split_whitespace().next() == Some(*gpl))
        }) {
            bail!(
                "{krate} ships under MIT OR Apache-2.0 but depends on the GPL crate `{line}`: \
                 the emulator must stay a program of its own (docs/emulator.md)"
            );
        }
        println!("xtask: {krate}: no GPL crate in its dependency tree");
    }
    Ok(())
}
