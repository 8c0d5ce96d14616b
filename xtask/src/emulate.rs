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
            // A crystal that never starts (RCC_CR.HSERDY never set, RM0090 6.2.1): the
            // channel halts in the safe state and says why, instead of waiting forever.
            let output = std::process::Command::new(&emulate)
                .arg(&image)
                .args(["--for", "1s", "--node-id", "1", "--hse-fails"])
                .output()?;
            let log = String::from_utf8_lossy(&output.stdout);
            if !log.contains("halting in the safe state: the crystal (HSE) did not start") {
                anyhow::bail!(
                    "{}: with a crystal that does not start, the shipped image does not halt \
                     safe with the reason:\n{log}",
                    image.display()
                );
            }
            println!("xtask: {protocol:?} channel {channel}: a dead crystal halts it safe, said");
            tampered_checks(root, &emulate, &image, protocol, channel)?;
            panic_check(&emulate, &image, protocol, channel)?;
        }
    }
    Ok(())
}

/// When the shipped image panics, the run ends promptly in HardFault (on a board the default
/// HardFault handler then spins unfed and the independent watchdog resets the MCU into its
/// safe state), and the image's own panic handler has logged the return addresses that lead
/// back to where the panic came from. The panic is a call of `core::panicking::panic`
/// injected by the emulator (`emulate --panic-at`) in place of whatever instruction the core
/// runs then: the shipped images have no way in for a panic on purpose, and a test entry in
/// them would be code that ships.
fn panic_check(emulate: &Path, image: &Path, protocol: Protocol, channel: &str) -> Result<()> {
    /// When the panic is injected: after the start-up, in the loop.
    const AT_MS: f64 = 700.0;
    /// How soon after it the run must have ended.
    const PROMPTLY_MS: f64 = 5.0;
    let output = std::process::Command::new(emulate)
        .arg(image)
        .args(["--for", "2s", "--node-id", "1", "--input-closed"])
        .args(["--panic-at", &format!("{AT_MS}ms")])
        .output()?;
    let log = String::from_utf8_lossy(&output.stdout);
    let failed = |why: &str| {
        anyhow::anyhow!(
            "{}: a panic on the shipped image: {why}:\n{log}{}",
            image.display(),
            String::from_utf8_lossy(&output.stderr)
        )
    };
    let injected = log
        .lines()
        .find(|line| line.contains("core::panicking::panic` injected in place of"))
        .and_then(|line| line.rsplit_once("PC 0x"))
        .and_then(|(_, rest)| u32::from_str_radix(rest.trim_end_matches(')'), 16).ok())
        .ok_or_else(|| failed("the emulator injected no call"))?;
    let stopped = log
        .lines()
        .find_map(|line| {
            let rest = line.strip_prefix("emulate: stopped at ")?;
            let (ms, why) = rest.split_once(" ms of virtual time: ")?;
            Some((ms.parse::<f64>().ok()?, why))
        })
        .ok_or_else(|| failed("the run did not end"))?;
    if output.status.success()
        || !stopped.1.starts_with("HardFault: an undefined instruction")
        || stopped.0 > AT_MS + PROMPTLY_MS
    {
        return Err(failed(&format!(
            "not ended in HardFault by the handler's `udf` within {PROMPTLY_MS} ms"
        )));
    }
    let addresses = crate::locate::panic_addresses(&log)
        .ok_or_else(|| failed("no log line with the panic's return addresses"))?;
    if !addresses
        .iter()
        .any(|&address| address & !1 == u64::from(injected))
    {
        return Err(failed(&format!(
            "the return addresses {addresses:#010x?} do not lead back to {injected:#010x}, \
             where the panic was called"
        )));
    }
    // The frames at the place, the innermost (inlined) first: named with the function it
    // was inlined into, the one the symbol table holds.
    let frames: Vec<_> = crate::locate::return_addresses(image, &[u64::from(injected) | 1])?
        .into_iter()
        .flatten()
        .collect();
    let site = match (frames.first(), frames.last()) {
        (Some(inner), Some(outer)) if frames.len() > 1 => format!("{inner}, inlined into {outer}"),
        (Some(only), _) => only.to_string(),
        _ => format!("{injected:#010x}"),
    };
    println!(
        "xtask: {protocol:?} channel {channel}: a panic ends the run in HardFault within \
         {PROMPTLY_MS} ms, its log line leading back to {site}"
    );
    Ok(())
}

/// A copy of the shipped `image` with its seal zeroed, and one with a bit of its CRC flipped:
/// the emulator refuses to run either as a shipped image, and given it anyway (`--unsealed`)
/// the image's own start-up check (the image CRC, CiA 304 9.5's self-test) refuses it, names
/// the fault and halts in the safe state.
fn tampered_checks(
    root: &Path,
    emulate: &Path,
    image: &Path,
    protocol: Protocol,
    channel: &str,
) -> Result<()> {
    let dir = root.join("target/emulate-tampered");
    std::fs::create_dir_all(&dir)?;
    /// How a case changes the seal's bytes.
    type Change = fn(&mut [u8]);
    let cases: [(&str, Change, &str); 2] = [
        ("unsealed", |seal| seal.fill(0), "NotSealed"),
        ("damaged", |seal| seal[4] ^= 0x01, "Mismatch"),
    ];
    for (name, change, expected) in cases {
        let copy = dir.join(format!("{protocol:?}-channel-{channel}-{name}"));
        images::tampered_copy(image, &copy, change)?;
        let output = std::process::Command::new(emulate)
            .arg(&copy)
            .args(["--for", "1s", "--node-id", "1", "--input-closed"])
            .output()?;
        let refused = String::from_utf8_lossy(&output.stderr);
        if output.status.success() || !refused.contains("not a sealed image") {
            anyhow::bail!(
                "{}: the emulator ran the {name} copy as a shipped image:\n{refused}",
                copy.display()
            );
        }
        let output = std::process::Command::new(emulate)
            .arg(&copy)
            .args([
                "--for",
                "1s",
                "--node-id",
                "1",
                "--input-closed",
                "--unsealed",
            ])
            .output()?;
        let log = String::from_utf8_lossy(&output.stdout);
        let failed = log
            .lines()
            .find(|line| line.contains("self-test: image CRC failed"));
        if !failed.is_some_and(|line| line.contains(expected))
            || log.contains("self-test: image CRC passed")
        {
            anyhow::bail!(
                "{}: the {name} copy is not refused by its own image CRC check ({expected}):\n{log}",
                copy.display()
            );
        }
        println!(
            "xtask: {protocol:?} channel {channel}: its {name} copy is refused by the emulator, \
             and by its own image CRC self-test ({expected})"
        );
    }
    Ok(())
}

/// What `cargo xtask emulate --network` runs.
#[derive(Clone, Debug, PartialEq)]
pub enum Case {
    /// The network for the duration asked for.
    Run,
    /// The nominal end-to-end case, then the fault cases; with the bus under load for this
    /// long (seconds of virtual time) before the emergency stop, if given.
    Nominal {
        /// Seconds of bus load.
        load_seconds: Option<f64>,
    },
    /// The power-cut sweep of node 1's store, at every `every`th step.
    PowerCutSweep {
        /// Every how many steps a cut is made.
        every: u64,
    },
    /// The network served over socketcand on this address, on a virtual time that follows
    /// the host clock, until interrupted (`emulate-network --socketcand`).
    Serve {
        /// `127.0.0.1:29536`.
        address: String,
    },
}

/// Builds and seals the shipped images of `protocol`, then runs both nodes (1 and 33, channels
/// A and B each) on one emulated bus for `duration` of virtual time with every contact
/// closed, or runs `case` on them (or serves them over socketcand until interrupted), and
/// prints every MCU's decoded log and the summary.
pub fn network_task(root: &Path, duration: &str, protocol: Protocol, case: Case) -> Result<()> {
    let cross = toolchain::ensure()?;
    toolchain::ensure_emulator_build_deps()?;
    let layer = protocol.hardware_layer();
    images::build_layer(root, &cross, layer)?;
    let mut arguments: Vec<std::ffi::OsString> = Vec::new();
    if let Case::Serve { address } = &case {
        let file = write_network_file(root, Protocol::CanopenSafety)?;
        println!(
            "xtask: join with python-can or python-canopen (interface socketcand, {address}, \
             channel can0), or configure the nodes with `safety-config --bus \
             socketcand:{address}/can0 configure {} --start`",
            file.display()
        );
        arguments.extend(["--socketcand".into(), address.into()]);
    } else {
        arguments.extend(["--for".into(), duration.into()]);
    }
    if !matches!(case, Case::Run | Case::Serve { .. }) {
        if protocol != Protocol::CanopenSafety {
            anyhow::bail!("the emulated network's cases are CANopen Safety's only");
        }
        let file = write_network_file(root, Protocol::CanopenSafety)?.into_os_string();
        match case {
            Case::PowerCutSweep { every } => arguments.extend([
                "--power-cut-sweep".into(),
                file,
                "--every".into(),
                every.to_string().into(),
            ]),
            Case::Run | Case::Serve { .. } | Case::Nominal { .. } => {}
        }
    }
    if let Case::Nominal { load_seconds } = case {
        // The measuring run: the same as `cargo xtask test`'s, which writes the figures.
        let emulate = build_emulate_network(root)?;
        let file = write_network_file(root, Protocol::CanopenSafety)?;
        let seconds = load_seconds.unwrap_or(NOMINAL_LOAD_SECONDS);
        return nominal_check(root, &cross, &emulate, &file, seconds, Speed::Written);
    }
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
                "emulate-network",
                "--",
            ])
            .arg(images::image(&cross, root, layer, "a"))
            .arg(images::image(&cross, root, layer, "b"))
            .arg("--inputs-closed")
            .args(arguments),
    )
}

/// Writes `cargo xtask run`'s network file of `protocol` for the emulated network's cases;
/// returns its path.
pub(crate) fn write_network_file(root: &Path, protocol: Protocol) -> Result<std::path::PathBuf> {
    let dir = root.join("target/emulate-network");
    std::fs::create_dir_all(&dir)?;
    let path = dir.join(match protocol {
        Protocol::CanopenSafety => "network.toml",
        Protocol::Simplecan => "simplecan.toml",
    });
    std::fs::write(&path, protocol.network_file())?;
    Ok(path)
}

/// How long the network check runs, in virtual time: past the first link periods, the
/// link's time-out and twenty heartbeats.
const NETWORK_CHECK: &str = "2500ms";

/// The producer heartbeat time the shipped images start with: object 1017h's default in the
/// device description the tool generates (the EDS).
pub(crate) fn default_heartbeat_ms() -> Result<u64> {
    let eds = safety_config::eds::eds();
    let section = eds
        .split("\n[")
        .find(|section| section.starts_with("1017]"))
        .ok_or_else(|| anyhow::anyhow!("the EDS has no object 1017h"))?;
    section
        .lines()
        .find_map(|line| line.strip_prefix("DefaultValue="))
        .and_then(|value| value.trim().parse().ok())
        .ok_or_else(|| anyhow::anyhow!("the EDS's object 1017h has no numeric default"))
}

/// One frame of a candump log: (seconds, identifier, data as hexadecimal).
fn candump_frames(log: &str) -> Vec<(f64, u16, String)> {
    log.lines()
        .filter_map(|line| {
            let (stamp, rest) = line.strip_prefix('(')?.split_once(')')?;
            let frame = rest.split_whitespace().nth(1)?;
            let (id, data) = frame.split_once('#')?;
            Some((
                stamp.parse().ok()?,
                u16::from_str_radix(id, 16).ok()?,
                data.to_owned(),
            ))
        })
        .collect()
}

/// What the bus trace of the fault-free start-up must show (CiA 301 7.2.8.3.2, 7.2.8.3.2.2):
/// each node's boot-up message (700h + node-ID, data 00h) once, before anything else of the
/// node's on 700h + node-ID, then heartbeats in pre-operational (7Fh) every `period_ms`
/// (within a millisecond), and nothing on the bus from any other identifier.
fn check_start_up_trace(trace: &str, nodes: &[u16], period_ms: u64) -> Result<(), String> {
    let frames = candump_frames(trace);
    if frames.is_empty() {
        return Err("no frame on the bus".into());
    }
    for &node in nodes {
        let id = 0x700 + node;
        let own: Vec<_> = frames.iter().filter(|(_, i, _)| *i == id).collect();
        let Some(((_, _, first), rest)) = own.split_first() else {
            return Err(format!("node {node} sent no boot-up message on {id:03X}h"));
        };
        if first != "00" {
            return Err(format!(
                "node {node}'s first message on {id:03X}h carries {first}, not the boot-up 00"
            ));
        }
        if rest.len() < 2 || rest.iter().any(|(_, _, data)| data != "7F") {
            return Err(format!(
                "node {node} did not follow its boot-up with heartbeats in pre-operational \
                 (7F): {rest:?}"
            ));
        }
        for pair in rest.windows(2) {
            let gap_ms = (pair[1].0 - pair[0].0) * 1e3;
            if (gap_ms - period_ms as f64).abs() > 1.0 {
                return Err(format!(
                    "node {node}'s heartbeats came {gap_ms:.3} ms apart, not every {period_ms} ms"
                ));
            }
        }
    }
    if let Some((at, id, data)) = frames
        .iter()
        .find(|(_, id, _)| !nodes.iter().any(|node| *id == 0x700 + node))
    {
        return Err(format!(
            "an unexpected frame {id:03X}#{data} at {at:.6} s: an unconfigured node sends only \
             its boot-up and heartbeats"
        ));
    }
    Ok(())
}

/// Builds the `emulate-network` program (release: the emulation's speed); returns its path.
pub(crate) fn build_emulate_network(root: &Path) -> Result<std::path::PathBuf> {
    crate::run(cargo().current_dir(root).args([
        "build",
        "--quiet",
        "--release",
        "-p",
        "emulator",
        "--bin",
        "emulate-network",
    ]))?;
    Ok(root.join("target/release/emulate-network"))
}

/// `cargo xtask test`'s check of both nodes' shipped images on one emulated bus (both
/// protocols): the four MCUs start, each node's channels link up over their USART3s and stay
/// linked, each node announces itself and keeps its heartbeat, no channel logs a fault or a
/// safe state, none stops; and the same images give the same trace and the same logs twice.
pub fn network_checks(root: &Path, cross: &toolchain::Cross) -> Result<()> {
    let emulate = build_emulate_network(root)?;
    let period_ms = default_heartbeat_ms()?;
    let scratch = root.join("target/emulate-network");
    std::fs::create_dir_all(&scratch)?;
    for protocol in [Protocol::CanopenSafety, Protocol::Simplecan] {
        let layer = protocol.hardware_layer();
        let mut runs = Vec::new();
        for run in 0..2 {
            let candump = scratch.join(format!("{protocol:?}-{run}.log"));
            let output = std::process::Command::new(&emulate)
                .arg(images::image(cross, root, layer, "a"))
                .arg(images::image(cross, root, layer, "b"))
                .args(["--for", NETWORK_CHECK, "--inputs-closed", "--candump"])
                .arg(&candump)
                .output()?;
            let log = String::from_utf8_lossy(&output.stdout).into_owned();
            let trace = std::fs::read_to_string(&candump)?;
            let troubled = log
                .lines()
                .filter(|line| line.contains("Fault") || line.contains("SafeState"))
                .collect::<Vec<_>>();
            let verdict = if !output.status.success() {
                Err("an MCU stopped, or the network could not start".to_owned())
            } else if !troubled.is_empty() {
                Err(format!("channels logged faults: {troubled:?}"))
            } else {
                check_start_up_trace(&trace, &[1, 33], period_ms)
            };
            if let Err(why) = verdict {
                anyhow::bail!(
                    "{protocol:?}: both nodes' shipped images on one emulated bus: {why}\n{log}{}",
                    String::from_utf8_lossy(&output.stderr)
                );
            }
            // The speed line is the host's; everything else is the emulation's.
            let emulated: Vec<String> = log
                .lines()
                .filter(|line| !line.contains("host time"))
                .map(str::to_owned)
                .collect();
            if let Some(speed) = log.lines().find(|line| line.contains("host time")) {
                println!("xtask: {protocol:?}: {speed}");
            }
            runs.push((emulated, trace));
        }
        if runs[0] != runs[1] {
            anyhow::bail!(
                "{protocol:?}: two runs of the same images on the emulated network differ \
                 (logs or bus trace): the emulation is not deterministic"
            );
        }
        println!(
            "xtask: {protocol:?}: both nodes started on one emulated bus, links up, heartbeats \
             every {period_ms} ms, no fault; two runs identical"
        );
        let output = std::process::Command::new(&emulate)
            .arg(images::image(cross, root, layer, "a"))
            .arg(images::image(cross, root, layer, "b"))
            .args(["--for", NETWORK_CHECK, "--inputs-closed"])
            .args([
                "--hang",
                "node33a@1200ms/500ms",
                "--bit-errors",
                "node1a@1500ms/40",
            ])
            .output()?;
        let log = String::from_utf8_lossy(&output.stdout);
        if let Err(why) = check_faults(&log) {
            anyhow::bail!(
                "{protocol:?}: a stalled loop and bus-off on the shipped images: {why}\n{log}{}",
                String::from_utf8_lossy(&output.stderr)
            );
        }
        println!(
            "xtask: {protocol:?}: a stalled loop is reset by the watchdog and says so; the other \
             channel goes safe; bus-off latches the safe state"
        );
    }
    // Power cuts while node 1 stores its configuration (CANopen Safety's file), at every
    // SWEEP_EVERY-th flash step of each channel's store (all of them:
    // `cargo xtask emulate --network --power-cut-sweep`).
    let layer = Protocol::CanopenSafety.hardware_layer();
    let file = write_network_file(root, Protocol::CanopenSafety)?;
    let output = std::process::Command::new(&emulate)
        .arg(images::image(cross, root, layer, "a"))
        .arg(images::image(cross, root, layer, "b"))
        .args(["--inputs-closed", "--power-cut-sweep"])
        .arg(&file)
        .args(["--every", &SWEEP_EVERY.to_string()])
        .output()?;
    let log = String::from_utf8_lossy(&output.stdout);
    let summary: Vec<&str> = log
        .lines()
        .filter(|line| line.starts_with("emulate-network:") && !line.contains("sealed image"))
        .collect();
    if !output.status.success() {
        anyhow::bail!(
            "power cuts during a store on the shipped images: a channel kept neither the old nor \
             the new parameters, or the node did not start again:\n{log}{}",
            String::from_utf8_lossy(&output.stderr)
        );
    }
    for line in summary {
        println!("xtask: {line}");
    }
    socketcand_check(root, cross, &emulate)?;
    nominal_check(
        root,
        cross,
        &emulate,
        &file,
        NOMINAL_LOAD_SECONDS,
        Speed::Printed,
    )
}

/// The shipped images joined from outside (`emulate-network --socketcand`): the tool
/// library's socketcand client, a separate process as any third-party program would be,
/// receives both nodes' heartbeats (CiA 301 7.2.8.3.2) and reads node 1's identity (1018h)
/// and producer heartbeat time (1017h, the EDS's default) by SDO, on a virtual time that
/// follows the host clock. python-can, python-canopen and the tool's program on it:
/// `cargo xtask interop --only emulated-network`.
fn socketcand_check(root: &Path, cross: &toolchain::Cross, emulate: &Path) -> Result<()> {
    let layer = Protocol::CanopenSafety.hardware_layer();
    let address = format!("127.0.0.1:{}", crate::interop::free_port()?);
    let mut child = crate::child::Guarded::spawn(
        std::process::Command::new(emulate)
            .arg(images::image(cross, root, layer, "a"))
            .arg(images::image(cross, root, layer, "b"))
            .args(["--inputs-closed", "--quiet", "--socketcand", &address])
            .stdout(std::process::Stdio::null()),
    )?;
    let started = std::time::Instant::now();
    let mut tool = crate::network::connect_tool_at(&address, std::time::Duration::from_secs(20))?;
    let heard =
        crate::network::await_heartbeats(&mut tool, std::time::Duration::from_secs(10), |data| {
            data == [0x7F]
        })?;
    if heard != [true; 2] {
        anyhow::bail!(
            "a socketcand client of emulate-network heard no Pre-operational heartbeat of {} \
             within 10 s",
            match heard {
                [true, _] => "node 33",
                [_, true] => "node 1",
                _ => "node 1 nor node 33",
            }
        );
    }
    let identity = safety_config::procedure::read_identity(&mut tool, 1)?;
    let heartbeat = tool.read_unsigned(1, shared::canopen::od::Address::new(0x1017, 0), 2)?;
    let expected = default_heartbeat_ms()?;
    if u64::from(heartbeat) != expected {
        anyhow::bail!(
            "a socketcand client of emulate-network read node 1's 1017h as {heartbeat} ms, not \
             the EDS's default {expected} ms"
        );
    }
    child.end();
    println!(
        "xtask: a socketcand client of emulate-network heard both nodes' heartbeats and read \
         node 1's identity ({:X}h, {:X}h, {}, {}) and 1017h ({heartbeat} ms) by SDO, {:.1} s of \
         host time with the emulator's start",
        identity.vendor,
        identity.product,
        identity.revision,
        identity.serial,
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// How long the nominal case keeps the bus under load in `cargo xtask test` (seconds of
/// virtual time), at `e2e::LOAD_PERCENT` of the bus beside the SRDOs.
const NOMINAL_LOAD_SECONDS: f64 = crate::e2e::CI_LOAD_SECONDS;

/// Where the nominal case's figures are written.
const FIGURES: &str = "docs/emulated-figures.md";
/// The same figures machine-readable (`emulator::figures::json`).
pub(crate) const FIGURES_JSON: &str = "docs/emulated-figures.json";

/// Both nodes' shipped images configured by the tool's library, started, under bus load,
/// then the emergency stop (`emulator::cases::nominal`); writes what it measured to
/// [`FIGURES`]: the case's verdicts and timings, and where each MCU's instructions go
/// (`emulator::figures`: per idle loop iteration, per pair, per function, the deepest stack).
fn nominal_check(
    root: &Path,
    cross: &toolchain::Cross,
    emulate: &Path,
    file: &Path,
    load_seconds: f64,
    speed: Speed,
) -> Result<()> {
    let layer = Protocol::CanopenSafety.hardware_layer();
    let output = std::process::Command::new(emulate)
        .arg(images::image(cross, root, layer, "a"))
        .arg(images::image(cross, root, layer, "b"))
        .args(["--inputs-closed", "--quiet", "--e2e", "--nominal"])
        .arg(file)
        .args(scenario_arguments(root)?)
        .args([
            "--load",
            &crate::e2e::LOAD_PERCENT.to_string(),
            "--load-for",
        ])
        .arg(format!("{}ms", (load_seconds * 1000.0).round()))
        .output()?;
    let log = run_lines(&output, "the nominal case on the shipped images")?;
    let lines: Vec<&str> = log.iter().map(String::as_str).collect();
    for line in &lines {
        if !line.starts_with("cost ") && !line.starts_with("figures") {
            println!("xtask: {line}");
        }
    }
    let mut report = String::from(
        "# Figures of the shipped images on the emulated network\n\n\
         Written by `cargo xtask test`, `cargo xtask e2e` and `cargo xtask emulate --network \
         --nominal` (`xtask/src/emulate.rs`, `nominal_check`) from `emulate-network --nominal \
         --e2e` on the four shipped CANopen Safety images, with the bus under load, then the \
         end-to-end fault cases (`emulator::e2e`, each bound the standard's time plus the \
         devices' own allowance) and the scenarios of `scenarios/emulated/` \
         (`emulator::scenario`); do not edit by hand. Virtual time is exact; instructions are \
         counted by the emulator (one per executed Thumb instruction, not cycles; \
         docs/emulator.md). Two runs of the same images have given the same figures (the \
         host time a run takes, which varies, is printed, not written); any change to the \
         images' code moves them, so this page is a report of the images it was written \
         from, not a gate (docs/overview.md, \"Generated pages\").\n\n",
    );
    // The host time a run took varies from run to run and machine to machine: printed above,
    // not written, so that the page changes only when a figure of the images does.
    for line in lines.iter().filter(|line| {
        !line.starts_with("cost ")
            && !line.starts_with("figures")
            && !line.contains(" of host time")
    }) {
        report.push_str(&format!("- {line}\n"));
    }
    report.push('\n');
    for line in lines
        .iter()
        .filter_map(|line| line.strip_prefix("figures "))
    {
        report.push_str(line);
        report.push('\n');
    }
    if speed == Speed::Written {
        write_speed(root, &lines)?;
    }
    write_figures(root, FIGURES, FIGURES_JSON, &report, &lines)?;
    println!(
        "xtask: the nominal case passed on the shipped images; figures in {FIGURES} and \
         {FIGURES_JSON}"
    );
    Ok(())
}

/// Writes `report` to `page` and the JSON of the `figures-json` line of `lines` (what
/// `emulate-network` printed, its prefix cut) to `json_page`, and says whether the page
/// changed.
fn write_figures(
    root: &Path,
    page: &str,
    json_page: &str,
    report: &str,
    lines: &[&str],
) -> Result<()> {
    let committed = crate::generated::committed(root, page);
    std::fs::write(root.join(page), report)?;
    // A report, not a gate (docs/overview.md, "Generated pages"): said, so that it is committed.
    match committed.map(|committed| crate::generated::difference(&committed, report)) {
        Some(None) => println!("xtask: {page} is unchanged"),
        Some(Some(difference)) => println!(
            "xtask: {page} differs from the committed page (commit it with the change that \
             moved it), {difference}"
        ),
        None => println!("xtask: {page} is new: commit it"),
    }
    let json = lines
        .iter()
        .find_map(|line| line.strip_prefix("figures-json "))
        .ok_or_else(|| anyhow::anyhow!("emulate-network printed no figures-json line"))?;
    let value: serde_json::Value = serde_json::from_str(json)
        .map_err(|error| anyhow::anyhow!("emulate-network's figures-json line: {error}"))?;
    std::fs::write(
        root.join(json_page),
        serde_json::to_string_pretty(&value)? + "\n",
    )?;
    if let Some(why) = stack_over_reserve(&value, images::STACK_RESERVE) {
        anyhow::bail!("{why} ({json_page})");
    }
    Ok(())
}

/// The sentence naming every MCU of the measuring run's figures (`emulator::figures::json`)
/// whose deepest stack is above `reserve` bytes, the stack the RAM budget sets aside
/// ([`images::STACK_RESERVE`]), or `None` when none is; a run whose figures name no stack is
/// one too, so that a renamed field cannot pass unseen.
fn stack_over_reserve(figures: &serde_json::Value, reserve: u64) -> Option<String> {
    let mcus = figures["mcus"]
        .as_array()
        .map(Vec::as_slice)
        .unwrap_or_default();
    let over: Vec<String> = mcus
        .iter()
        .filter_map(|mcu| {
            let name = mcu["mcu"].as_str().unwrap_or("an MCU");
            match mcu["deepest_stack_bytes"].as_u64() {
                Some(bytes) if bytes <= reserve => None,
                Some(bytes) => Some(format!("{name} used {bytes} bytes of stack")),
                None => Some(format!("{name}'s deepest stack was not measured")),
            }
        })
        .collect();
    match (mcus.is_empty(), over.is_empty()) {
        (true, _) => Some("the figures name no MCU, so no stack was checked".to_string()),
        (false, true) => None,
        (false, false) => Some(format!(
            "{}, more than the {reserve} bytes the RAM budget reserves for the stack \
             (`STACK_RESERVE` in xtask/src/images.rs)",
            over.join(", ")
        )),
    }
}

/// Where SimpleCAN's measuring run's figures are written.
const SIMPLECAN_FIGURES: &str = "docs/emulated-figures-simplecan.md";
/// The same figures machine-readable (`emulator::figures::json`).
pub(crate) const SIMPLECAN_FIGURES_JSON: &str = "docs/emulated-figures-simplecan.json";

/// The lines `emulate-network` printed of its own (its prefix cut, the sealed-image lines
/// left out) in a measuring run's `output`; fails, naming `run` and with the whole output,
/// when the run failed.
fn run_lines(output: &std::process::Output, run: &str) -> Result<Vec<String>> {
    let log = String::from_utf8_lossy(&output.stdout);
    if !output.status.success() {
        anyhow::bail!(
            "{run} failed:\n{log}{}",
            String::from_utf8_lossy(&output.stderr)
        );
    }
    Ok(log
        .lines()
        .filter_map(|line| line.strip_prefix("emulate-network: "))
        .filter(|line| !line.contains("sealed image"))
        .map(str::to_owned)
        .collect())
}

/// SimpleCAN's measuring run on the four shipped SimpleCAN images (`emulate-network
/// --simplecan`, `emulator::cases::simplecan`): configured by the tool's library from
/// `scenarios/networks/simplecan.toml`, started, one second of Operational profiled on every
/// MCU with node 1's contacts opened and closed once; writes [`SIMPLECAN_FIGURES`] and
/// [`SIMPLECAN_FIGURES_JSON`].
pub fn simplecan_figures(root: &Path) -> Result<()> {
    let cross = toolchain::ensure()?;
    toolchain::ensure_emulator_build_deps()?;
    let layer = Protocol::Simplecan.hardware_layer();
    images::build_layer(root, &cross, layer)?;
    let emulate = build_emulate_network(root)?;
    let file = write_network_file(root, Protocol::Simplecan)?;
    let output = std::process::Command::new(emulate)
        .arg(images::image(&cross, root, layer, "a"))
        .arg(images::image(&cross, root, layer, "b"))
        .args(["--inputs-closed", "--quiet", "--simplecan"])
        .arg(file)
        .output()?;
    let log = run_lines(&output, "SimpleCAN's measuring run on the shipped images")?;
    let lines: Vec<&str> = log.iter().map(String::as_str).collect();
    let mut report = String::from(
        "# Figures of the shipped SimpleCAN images on the emulated network\n\n\
         Written by `cargo xtask bench --target-cost --protocol simplecan` \
         (`xtask/src/emulate.rs`, `simplecan_figures`) from `emulate-network --simplecan` on \
         the four shipped SimpleCAN images (`emulator::cases::simplecan`: node 1 the master \
         and producer of SC-ID 30h, node 33 its consumer, `scenarios/networks/simplecan.toml`); \
         do not edit by hand. Virtual time is exact; instructions are counted by the emulator \
         (one per executed Thumb instruction, not cycles; docs/emulator.md). A report of the \
         images it was written from, not a gate (docs/overview.md, \"Generated pages\").\n\n",
    );
    for line in &lines {
        if line.starts_with("figures") {
            continue;
        }
        println!("xtask: {line}");
        if !line.contains(" of host time") {
            report.push_str(&format!("- {line}\n"));
        }
    }
    report.push('\n');
    for line in lines
        .iter()
        .filter_map(|line| line.strip_prefix("figures "))
    {
        report.push_str(line);
        report.push('\n');
    }
    write_figures(
        root,
        SIMPLECAN_FIGURES,
        SIMPLECAN_FIGURES_JSON,
        &report,
        &lines,
    )?;
    println!(
        "xtask: SimpleCAN's measuring run passed on the shipped images; figures in \
         {SIMPLECAN_FIGURES} and {SIMPLECAN_FIGURES_JSON}"
    );
    Ok(())
}

/// `cargo xtask bench --target-cost --json`: the shipped images' figures as the nominal case
/// measures them on the emulated STM32F405 (`cargo xtask emulate --network --nominal`), the
/// JSON of [`FIGURES_JSON`] printed.
pub fn target_cost_json(root: &Path) -> Result<()> {
    network_task(
        root,
        "1s",
        Protocol::CanopenSafety,
        Case::Nominal { load_seconds: None },
    )?;
    print!("{}", std::fs::read_to_string(root.join(FIGURES_JSON))?);
    Ok(())
}

/// Whether [`nominal_check`] writes the emulation's speed into docs/performance.md.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Speed {
    /// Printed only (`cargo xtask test`: the host's load varies, and a page it rewrote at
    /// every run would change at every run).
    Printed,
    /// Written too (`cargo xtask emulate --network --nominal`, asked for).
    Written,
}

/// The block of docs/performance.md that holds the emulation's speed.
pub(crate) const SPEED_MARKER: &str = "emulation-speed";

/// Writes the speed line of the nominal run's output `lines` (the four shipped images on one
/// `emulate-network`, virtual time per host second) into docs/performance.md's
/// [`SPEED_MARKER`] block, with the host's load.
fn write_speed(root: &Path, lines: &[&str]) -> Result<()> {
    let speed = lines
        .iter()
        .find(|line| line.contains(" of host time") && line.contains("per host second"))
        .ok_or_else(|| anyhow::anyhow!("emulate-network printed no speed line"))?;
    let block = format!(
        "## The emulated STM32F405s: emulation speed\n\n\
         Written by `cargo xtask emulate --network --nominal` (`xtask/src/emulate.rs`, \
         `write_speed`) on this machine (2 cores, {}): the nominal case's run of the four \
         shipped CANopen Safety images on one `emulate-network` (the load case, the fault \
         cases and the scenarios included, docs/emulated-figures.md). Goal: at least one second \
         of virtual time per host second.\n\n{speed}.\n",
        crate::interop::load_average()
    );
    crate::fullnet::write_performance_block(root, SPEED_MARKER, &block)
}

/// `--scenario FILE` for every scenario written for the emulated network
/// (`scenarios/emulated/*.toml`), which the shipped images play after the fault cases.
fn scenario_arguments(root: &Path) -> Result<Vec<std::ffi::OsString>> {
    let files = system_tests::scenario_runner::files_in(&root.join("scenarios/emulated"))
        .map_err(|why| anyhow::anyhow!(why))?;
    Ok(files
        .into_iter()
        .flat_map(|file| ["--scenario".into(), file.into_os_string()])
        .collect())
}

/// `cargo xtask test` cuts the power at every this-many-th flash step of a store.
const SWEEP_EVERY: u64 = 6;

/// What the shipped images must do when node 33's channel A hangs with interrupts masked
/// and node 1's channel A's transmissions are destroyed by bit errors (the run of
/// [`network_checks`]): the independent watchdog resets the hung channel (RM0090 21.3.1), which
/// starts again and logs that the watchdog reset it; its peer latches the safe state (the
/// link fell silent); the channel whose transmit error counter passes 255 goes bus-off
/// (ISO 11898-1 12.1.4, RM0090 32.7.6) and latches the safe state.
fn check_faults(log: &str) -> Result<(), String> {
    let position = |mcu: &str, needle: &str| {
        log.lines()
            .position(|line| line.starts_with(mcu) && line.contains(needle))
    };
    let reset = position("node33a", "reset, starting again: the independent watchdog")
        .ok_or("the hung channel was not reset by its watchdog")?;
    position("node33a", "reset by the independent watchdog")
        .filter(|&said| said > reset)
        .ok_or("the channel reset by its watchdog did not say so when it started again")?;
    position("node33b", "SafeState").ok_or("the hung channel's peer did not go safe")?;
    let bus_off = position("node1a", "Fault(BusOff)")
        .ok_or("the channel whose frames were destroyed did not report bus-off")?;
    position("node1a", "SafeState")
        .filter(|&safe| safe > bus_off)
        .ok_or("bus-off did not latch the safe state")?;
    if log.contains(" stopped at ") {
        return Err("an MCU stopped".into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The RAM budget's stack reserve holds on the shipped images: an MCU whose deepest stack
    /// is above it, or not measured, fails the measuring run by name; at the reserve it
    /// passes.
    #[test]
    fn a_deepest_stack_above_the_reserve_fails_the_measuring_run() {
        let figures = |a: serde_json::Value, b: serde_json::Value| {
            serde_json::json!({"mcus": [
                {"mcu": "node1a", "deepest_stack_bytes": a},
                {"mcu": "node1b", "deepest_stack_bytes": b},
            ]})
        };
        let at = serde_json::json!(12_288);
        assert_eq!(
            stack_over_reserve(&figures(at.clone(), at.clone()), 12_288),
            None
        );
        let over = stack_over_reserve(&figures(at.clone(), serde_json::json!(12_289)), 12_288)
            .expect("over the reserve");
        assert!(
            over.starts_with("node1b used 12289 bytes of stack"),
            "{over}"
        );
        assert!(!over.contains("node1a"), "{over}");
        let missing = stack_over_reserve(&figures(at, serde_json::Value::Null), 12_288)
            .expect("not measured");
        assert!(
            missing.contains("node1b's deepest stack was not measured"),
            "{missing}"
        );
        assert!(stack_over_reserve(&serde_json::json!({}), 12_288).is_some());
    }

    const TRACE: &str = "(0.288713) vcan0 701#00\n(0.288827) vcan0 721#00\n\
                         (0.388715) vcan0 721#7F\n(0.388833) vcan0 701#7F\n\
                         (0.488717) vcan0 701#7F\n(0.488833) vcan0 721#7F\n\
                         (0.588725) vcan0 701#7F\n(0.588841) vcan0 721#7F\n";

    #[test]
    fn cia301_7_2_8_3_2_boot_up_then_steady_heartbeats_pass() {
        assert_eq!(check_start_up_trace(TRACE, &[1, 33], 100), Ok(()));
    }

    #[test]
    fn cia301_7_2_8_3_2_late_heartbeat_or_missing_boot_up_or_stray_frame_fails() {
        let late = TRACE.replace("(0.588725) vcan0 701#7F", "(0.590725) vcan0 701#7F");
        assert!(check_start_up_trace(&late, &[1, 33], 100).is_err());
        let no_boot = TRACE.replace("(0.288713) vcan0 701#00\n", "");
        assert!(check_start_up_trace(&no_boot, &[1, 33], 100).is_err());
        let stray = format!("{TRACE}(0.6) vcan0 181#01\n");
        assert!(check_start_up_trace(&stray, &[1, 33], 100).is_err());
        assert!(check_start_up_trace(TRACE, &[1, 33, 5], 100).is_err());
    }

    #[test]
    fn the_fault_check_needs_the_watchdog_reset_said_and_bus_off_latched() {
        let good = "node33a 1.0 ms reset, starting again: the independent watchdog ran out\n\
                    node33b 1.1 ms INFO Node(SafeState(Application { detail: 20 }))\n\
                    node33a 1.3 ms WARN reset by the independent watchdog: stalled\n\
                    node1a 1.5 ms INFO Fault(BusOff)\n\
                    node1a 1.6 ms INFO Node(SafeState(Application { detail: 59 }))\n";
        assert_eq!(check_faults(good), Ok(()));
        let silent = good.replace("WARN reset by the independent watchdog", "WARN started");
        assert!(check_faults(&silent).is_err());
        let not_latched = good.replace("node1a 1.6 ms INFO Node(SafeState", "node1a 1.6 ms x");
        assert!(check_faults(&not_latched).is_err());
    }

    #[test]
    fn the_heartbeat_time_comes_from_the_device_description() {
        assert!(default_heartbeat_ms().is_ok_and(|ms| ms > 0));
    }
}
