//! Getting a compiler for `thumbv7em-none-eabihf`.
//!
//! The normal path is rustup's prebuilt target. Where rustup cannot fetch it, Debian's
//! `rustc-web`/`cargo-web` with `rust-web-src` can build `core` from source
//! (`-Zbuild-std=core`); that path uses its own target directory so the two never mix.

use anyhow::{Context, Result, bail};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// The firmware target.
pub const TARGET: &str = "thumbv7em-none-eabihf";

/// How firmware is compiled on this machine.
pub enum Cross {
    /// rustup's prebuilt `core` for the target.
    Rustup,
    /// Debian's compiler building `core` from source; `linker` when rust-lld is missing.
    Debian { linker: Option<String> },
}

impl Cross {
    /// `cargo <args…>` for the target, run from the workspace root.
    pub fn cargo(&self, root: &Path) -> CrossCommand {
        let mut command = match self {
            Cross::Rustup => {
                Command::new(std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into()))
            }
            Cross::Debian { linker } => {
                let mut command = Command::new("/usr/bin/cargo");
                command
                    .env("RUSTC", "/usr/bin/rustc")
                    .env("RUSTC_BOOTSTRAP", "1");
                if let Some(linker) = linker {
                    command.env("CARGO_TARGET_THUMBV7EM_NONE_EABIHF_LINKER", linker);
                }
                command
            }
        };
        command.current_dir(root);
        CrossCommand {
            command,
            debian: matches!(self, Cross::Debian { .. }),
            target_dir: self.target_dir(root),
        }
    }

    /// Where this toolchain's artifacts go.
    pub fn target_dir(&self, root: &Path) -> PathBuf {
        match self {
            Cross::Rustup => root.join("target"),
            Cross::Debian { .. } => root.join("target/debian-build-std"),
        }
    }
}

/// A cargo command that gets the target flags appended after the caller's arguments.
pub struct CrossCommand {
    command: Command,
    debian: bool,
    target_dir: PathBuf,
}

impl CrossCommand {
    /// Adds arguments (the subcommand first).
    pub fn args<'a>(mut self, args: impl IntoIterator<Item = &'a str>) -> Self {
        self.command.args(args);
        self
    }

    /// Builds into `dir` instead (the other layers' images, so they never overwrite the
    /// shipped ones).
    pub fn target_dir(mut self, dir: PathBuf) -> Self {
        self.target_dir = dir;
        self
    }

    /// The finished command.
    pub fn finish(mut self) -> Command {
        self.command.args(["--target", TARGET]);
        self.command.arg("--target-dir").arg(&self.target_dir);
        if self.debian {
            self.command.arg("-Zbuild-std=core");
        }
        self.command
    }
}

/// `true` when `program` can be started.
fn exists(program: &str) -> bool {
    Command::new(program)
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|status| status.success())
}

fn output(program: &str, args: &[&str]) -> Option<String> {
    let out = Command::new(program).args(args).output().ok()?;
    out.status
        .success()
        .then(|| String::from_utf8_lossy(&out.stdout).into_owned())
}

fn rustup_has_target() -> bool {
    output("rustup", &["target", "list", "--installed"])
        .is_some_and(|list| list.lines().any(|line| line.trim() == TARGET))
}

/// Debian's toolchain, when its library source is installed.
fn debian() -> Option<Cross> {
    let sysroot = output("/usr/bin/rustc", &["--print", "sysroot"])?;
    let source = Path::new(sysroot.trim()).join("lib/rustlib/src/rust/library/core");
    if !source.is_dir() || !Path::new("/usr/bin/cargo").exists() {
        return None;
    }
    let rust_lld = Path::new(sysroot.trim())
        .join("lib/rustlib/x86_64-unknown-linux-gnu/bin/rust-lld")
        .exists();
    let linker = (!rust_lld).then(|| {
        ["ld.lld-22", "ld.lld"]
            .into_iter()
            .find(|lld| exists(lld))
            .unwrap_or("ld.lld-22")
            .to_owned()
    });
    Some(Cross::Debian { linker })
}

/// The cross toolchain, installing the target when it is missing.
pub fn ensure() -> Result<Cross> {
    if exists("rustup") {
        if !rustup_has_target() {
            eprintln!("xtask: installing the {TARGET} target with rustup");
            if super::run(Command::new("rustup").args(["target", "add", TARGET])).is_ok() {
                return Ok(Cross::Rustup);
            }
            eprintln!("xtask: rustup could not install {TARGET}; trying Debian's toolchain");
        } else {
            return Ok(Cross::Rustup);
        }
    }
    if let Some(cross) = debian() {
        return Ok(cross);
    }
    install_debian()?;
    debian()
        .context("Debian's rust-web packages are installed but their library source is not found")
}

/// Runs a shell `script` as root (through sudo unless already root), non-interactively: the
/// apt installs of `setup`.
fn as_root(script: &str) -> Result<()> {
    let root = output("id", &["-u"]).is_some_and(|uid| uid.trim() == "0");
    let mut command = if root {
        Command::new("sh")
    } else {
        let mut sudo = Command::new("sudo");
        sudo.arg("sh");
        sudo
    };
    super::run(
        command
            .args(["-c", script])
            .env("DEBIAN_FRONTEND", "noninteractive"),
    )
}

fn install_debian() -> Result<()> {
    eprintln!("xtask: installing Debian's rustc-web, cargo-web, rust-web-src and lld-22");
    as_root("apt-get update -qq && apt-get install -y -qq rustc-web cargo-web rust-web-src lld-22")
}

/// `cargo xtask setup`.
pub fn setup(probe_rs: bool, fuzz: bool) -> Result<()> {
    let cross = ensure()?;
    match &cross {
        Cross::Rustup => eprintln!("xtask: {TARGET}: rustup target installed"),
        Cross::Debian { .. } => eprintln!("xtask: {TARGET}: Debian toolchain with build-std"),
    }
    if exists("rustup") {
        for component in ["clippy", "rustfmt"] {
            let installed = output("rustup", &["component", "list", "--installed"])
                .is_some_and(|list| list.lines().any(|line| line.starts_with(component)));
            if installed {
                eprintln!("xtask: {component}: installed");
            } else {
                eprintln!("xtask: installing {component}");
                super::run(Command::new("rustup").args(["component", "add", component]))?;
            }
        }
    }
    if probe_rs {
        for (tool, krate) in [
            ("probe-rs", "probe-rs-tools"),
            ("defmt-print", "defmt-print"),
        ] {
            if exists(tool) {
                eprintln!("xtask: {tool}: installed");
            } else {
                eprintln!("xtask: installing {krate} (cargo install --locked)");
                super::run(Command::new("cargo").args(["install", "--locked", krate]))?;
            }
        }
    }
    if fuzz {
        ensure_fuzzing()?;
    }
    ensure_emulator_build_deps()?;
    ensure_spin()?;
    ensure_tshark()?;
    if !exists("valgrind") {
        eprintln!("xtask: note: valgrind is missing; `cargo xtask bench` needs it");
    }
    Ok(())
}

/// The nightly toolchain (rustup, minimal profile) and cargo-fuzz (`cargo install --locked`),
/// for `cargo xtask fuzz`: libFuzzer's instrumentation needs nightly flags.
pub fn ensure_fuzzing() -> Result<()> {
    let nightly = output("rustup", &["toolchain", "list"])
        .is_some_and(|list| list.lines().any(|line| line.starts_with("nightly")));
    if nightly {
        eprintln!("xtask: nightly toolchain: installed");
    } else {
        eprintln!("xtask: installing the nightly toolchain (rustup, minimal profile)");
        super::run(Command::new("rustup").args([
            "toolchain",
            "install",
            "nightly",
            "--profile",
            "minimal",
        ]))?;
    }
    if output("cargo", &["fuzz", "--version"]).is_some() {
        eprintln!("xtask: cargo-fuzz: installed");
        return Ok(());
    }
    eprintln!("xtask: installing cargo-fuzz (cargo install --locked), for the fuzz targets");
    super::run(Command::new("cargo").args(["install", "--locked", "cargo-fuzz"]))
}

/// Whether Debian's package `package` is installed.
fn debian_package_installed(package: &str) -> bool {
    output("dpkg-query", &["-W", "-f=${Status}", package])
        .is_some_and(|status| status.contains("install ok installed"))
}

/// SPIN (Debian's package `spin`), the model checker of the channels' protocol
/// (`cargo xtask spin`, `dual-channel/model/`); it compiles its verifiers with gcc.
pub fn ensure_spin() -> Result<()> {
    // SPIN prints its version with -V (`--version` is a usage error, exit 1).
    let installed = Command::new("spin")
        .arg("-V")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|status| status.success());
    if installed {
        eprintln!("xtask: spin: installed");
        return Ok(());
    }
    eprintln!(
        "xtask: installing spin (Debian), the model checker of the channels' protocol \
         (dual-channel/model)"
    );
    as_root("apt-get update -qq && apt-get install -y -qq spin")
}

/// cmake and libclang-dev (Debian's packages), which building the emulator's
/// `unicorn-engine` needs: cmake builds Unicorn's C code, libclang lets bindgen generate its
/// Rust bindings.
pub fn ensure_emulator_build_deps() -> Result<()> {
    let missing: Vec<&str> = ["cmake", "libclang-dev"]
        .into_iter()
        .filter(|package| !debian_package_installed(package))
        .collect();
    if missing.is_empty() {
        eprintln!("xtask: cmake, libclang-dev: installed");
        return Ok(());
    }
    eprintln!(
        "xtask: installing {} (Debian), which the emulator's unicorn-engine needs to build \
         (cmake for Unicorn's C code, libclang for bindgen)",
        missing.join(", ")
    );
    as_root(&format!(
        "apt-get update -qq && apt-get install -y -qq {}",
        missing.join(" ")
    ))
}

/// tshark (Debian's package), which the hub's test uses to check that its pcap traces decode
/// as CANopen.
pub fn ensure_tshark() -> Result<()> {
    if exists("tshark") {
        eprintln!("xtask: tshark: installed");
        return Ok(());
    }
    eprintln!("xtask: installing tshark (Debian)");
    as_root("apt-get update -qq && apt-get install -y -qq tshark")
}

/// Fails with a clear message when a tool a task needs is missing.
pub fn require(program: &str, hint: &str) -> Result<()> {
    if !exists(program) {
        bail!("`{program}` is not installed: {hint}");
    }
    Ok(())
}
