//! `cargo xtask interop`: third-party CANopen software on the emulated bus, through the hub's
//! socketcand port, in a virtual environment under `target/interop/venv` (python-can and
//! python-canopen from PyPI, pinned).
//!
//! 1. python-can's own `socketcand` bus against `can-hub` (no QEMU): frames sent by the tool
//!    library's socketcand client reach python-can, and python-can's answers reach the tool,
//!    identifier and data exact, a frame without data included.
//! 2. python-canopen against the host simulation's nodes 1 and 33 (the protocol core,
//!    configured by the tool library, in real time behind a socketcand server built from the
//!    tool's server session: `tests/src/bin/socketcand_sim.rs`), then
//! 3. python-canopen on the emulated network (four QEMU instances, as `cargo xtask run`
//!    starts and configures them); both times it loads the node's EDS (`eds/safety-node.eds`) with
//!    `canopen.import_od`, reads node 33's identity and whole SRDO configuration and agrees
//!    with the tool's reading; its write to a safety object in Operational is aborted with
//!    0800 0022h (EN 50325-5 8.2.2); in Pre-operational an SCT of 0 is aborted with
//!    0609 0032h and a valid write is accepted and resets 0x13FE (EN 50325-5 6.4.1.6).

use crate::network::{self, Network};
use anyhow::{Context, Result, bail};
use safety_config::Transport;
use safety_config::client::Client;
use safety_config::procedure;
use safety_config::socketcand::SocketcandClient;
use shared::canopen::nmt::NmtCommand;
use shared::canopen::od::Address;
use shared::{CanFrame, CanId};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

/// The PyPI packages, pinned: what CI installs is what was tested.
const PACKAGES: [&str; 2] = ["python-can==4.6.1", "canopen==2.4.1"];

/// Which part to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Part {
    /// python-can's socketcand bus against the hub alone.
    Socketcand,
    /// python-canopen on the host simulation's nodes behind a socketcand server (no QEMU).
    Simulated,
    /// python-canopen on the emulated network (QEMU).
    Canopen,
}

/// The virtual environment's Python, created and provisioned when needed.
fn python(root: &Path) -> Result<PathBuf> {
    let venv = root.join("target/interop/venv");
    let python = venv.join("bin/python");
    let wanted = PACKAGES.join(" ");
    let stamp = venv.join("xtask-packages");
    if python.exists() && std::fs::read_to_string(&stamp).is_ok_and(|held| held == wanted) {
        return Ok(python);
    }
    crate::step(&format!(
        "interop: virtual environment {} with {wanted}",
        venv.display()
    ));
    if !python.exists() {
        crate::run(Command::new("python3").args(["-m", "venv"]).arg(&venv))
            .context("creating the virtual environment (Debian: `apt-get install python3-venv`)")?;
    }
    crate::run(
        Command::new(&python)
            .args([
                "-m",
                "pip",
                "install",
                "--quiet",
                "--disable-pip-version-check",
            ])
            .args(PACKAGES),
    )?;
    std::fs::write(&stamp, wanted)?;
    Ok(python)
}

/// A child process killed when dropped.
struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// A free TCP port on the loopback address (the hub of part 1 listens there, so that it
/// never meets a network another task runs on the fixed ports).
fn free_port() -> Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port())
}

/// Runs a Python script, returns its stdout's last line as JSON.
fn script_json(command: &mut Command) -> Result<serde_json::Value> {
    let output = command.stderr(Stdio::inherit()).output()?;
    let stdout = String::from_utf8_lossy(&output.stdout);
    if !output.status.success() {
        bail!("`{command:?}` failed ({}):\n{stdout}", output.status);
    }
    let last = stdout.lines().last().unwrap_or_default();
    serde_json::from_str(last).with_context(|| format!("the script's result {last:?}"))
}

/// Part 1: python-can's socketcand bus and the tool's client on one hub.
fn socketcand(root: &Path, python: &Path) -> Result<()> {
    crate::step("interop 1: python-can's socketcand bus against can-hub (no QEMU)");
    crate::run(crate::cargo().args(["build", "--quiet", "-p", "can-hub"]))?;
    let port = free_port()?;
    let address = format!("127.0.0.1:{port}");
    let _hub = Killed(
        Command::new(root.join("target/debug/can-hub"))
            .args(["--tcp", &address])
            .spawn()
            .context("starting can-hub")?,
    );
    let give_up = std::time::Instant::now() + Duration::from_secs(10);
    let mut tool = loop {
        match SocketcandClient::connect(&address, "can0") {
            Ok(client) => break client,
            Err(_) if std::time::Instant::now() < give_up => {
                std::thread::sleep(Duration::from_millis(50))
            }
            Err(error) => return Err(error).context("the hub's socketcand port"),
        }
    };
    let frame = |id: u16, data: &[u8]| -> Result<CanFrame> {
        CanId::new(id)
            .and_then(|id| CanFrame::new(id, data))
            .map_err(|error| anyhow::anyhow!("frame {id:03X}h: {error:?}"))
    };
    let sent = [
        frame(0x000, &[0x01, 0x21])?,
        frame(0x001, &[])?,
        frame(0x123, &[0xA5, 0x5A, 0x00])?,
        frame(0x7FE, &[1, 2, 3, 4, 5, 6, 7, 8])?,
    ];
    let mut child = Killed(
        Command::new(python)
            .arg(root.join("xtask/interop/python_can_bus.py"))
            .args(["127.0.0.1", &port.to_string(), &sent.len().to_string()])
            .stdout(Stdio::piped())
            .spawn()?,
    );
    let stdout = child.0.stdout.take().context("the script's output")?;
    let mut lines = BufReader::new(stdout).lines();
    match lines.next() {
        Some(Ok(line)) if line == "ready" => {}
        other => bail!("python-can did not connect to the hub's socketcand port: {other:?}"),
    }
    for frame in &sent {
        tool.send(frame)?;
    }
    let deadline = tool.now() + Duration::from_secs(15);
    let mut answers = Vec::new();
    while answers.len() < sent.len() {
        match tool.receive(deadline)? {
            Some(frame) => answers.push(frame),
            None => bail!(
                "python-can answered {} of {} frames: {answers:?}",
                answers.len(),
                sent.len()
            ),
        }
    }
    for (frame, answer) in sent.iter().zip(&answers) {
        let mut reversed = frame.data().to_vec();
        reversed.reverse();
        if answer.id().raw() != frame.id().raw() + 1 || answer.data() != reversed {
            bail!("python-can answered {answer:?} to {frame:?}");
        }
    }
    let line = lines
        .next()
        .context("python-can's report")?
        .context("python-can's report")?;
    let report: serde_json::Value = serde_json::from_str(&line)?;
    let received = report["received"].as_array().context("received frames")?;
    if received.len() != sent.len() {
        bail!(
            "python-can received {} of {} frames: {line}",
            received.len(),
            sent.len()
        );
    }
    for (frame, seen) in sent.iter().zip(received) {
        let data: Vec<u8> = seen["data"]
            .as_array()
            .context("data")?
            .iter()
            .filter_map(|byte| byte.as_u64().and_then(|b| u8::try_from(b).ok()))
            .collect();
        if seen["id"].as_u64() != Some(u64::from(frame.id().raw()))
            || seen["extended"].as_bool() != Some(false)
            || data != frame.data()
        {
            bail!("python-can received {seen} for {frame:?}");
        }
    }
    println!(
        "xtask: interop 1: python-can received the tool's {} frames exactly (one without data) and the tool python-can's {} answers",
        sent.len(),
        answers.len()
    );
    Ok(())
}

/// The tool's reading of node 33's identity and SRDO configuration, as the script writes it.
fn tool_reading<T: Transport>(tool: &mut Client<T>, node: u8) -> Result<serde_json::Value> {
    let identity = procedure::read_identity(tool, node)?;
    let count = tool.read_unsigned(node, Address::new(0x13FF, 0), 1)? as u8;
    let mut srdos = Vec::new();
    for n in 1..=count {
        let record = procedure::read_record(tool, node, n)?;
        let signature = tool.read_unsigned(node, Address::new(0x13FF, n), 2)?;
        let settings = &record.settings;
        srdos.push(serde_json::json!({
            "direction": settings.direction,
            "cycle_time": settings.cycle_time,
            "srvt": settings.srvt,
            "transmission_type": record.transmission_type,
            "cob_id_1": settings.cob_id_1,
            "cob_id_2": settings.cob_id_2,
            "mapping": settings.mapping,
            "signature": signature,
        }));
    }
    let valid = tool.read_unsigned(node, Address::new(0x13FE, 0), 1)?;
    Ok(serde_json::json!({
        "identity": [identity.vendor, identity.product, identity.revision, identity.serial],
        "srdos": srdos,
        "configuration_valid": valid,
    }))
}

/// Part 2: python-canopen on the host simulation behind a socketcand server.
fn simulated(root: &Path, python: &Path) -> Result<()> {
    crate::step("interop 2: python-canopen on the host simulation's nodes (socketcand, no QEMU)");
    crate::run(crate::cargo().args([
        "build",
        "--quiet",
        "-p",
        "system-tests",
        "--bin",
        "socketcand_sim",
    ]))?;
    let port = free_port()?;
    let address = format!("127.0.0.1:{port}");
    let _server = Killed(
        Command::new(root.join("target/debug/socketcand_sim"))
            .arg(port.to_string())
            .spawn()
            .context("starting socketcand_sim")?,
    );
    let give_up = std::time::Instant::now() + Duration::from_secs(20);
    let transport = loop {
        match SocketcandClient::connect(&address, "can0") {
            Ok(client) => break client,
            Err(_) if std::time::Instant::now() < give_up => {
                std::thread::sleep(Duration::from_millis(50))
            }
            Err(error) => return Err(error).context("the simulation's socketcand port"),
        }
    };
    let mut tool = Client::new(transport, Duration::from_millis(1000));
    canopen_checks(root, python, &address, &mut tool, "interop 2")
}

/// Part 3: python-canopen on the emulated network.
fn canopen(root: &Path, python: &Path) -> Result<()> {
    crate::step("interop 3: python-canopen on the emulated network (QEMU) through can-hub");
    let mut network = Network::start(root)?;
    let result = network
        .tool()
        .and_then(|tool| canopen_checks(root, python, network::HUB_TCP, tool, "interop 3"));
    let faults = network.stop();
    result?;
    faults?;
    Ok(())
}

/// python-canopen against node 33 at the socketcand server `address`, with `tool` (the tool
/// library's client on the same bus) as the reference reading.
fn canopen_checks(
    root: &Path,
    python: &Path,
    address: &str,
    tool: &mut Client<SocketcandClient>,
    part: &str,
) -> Result<()> {
    const NODE: u8 = 33;
    let (host, port) = address.split_once(':').context("the server's address")?;
    let eds = root.join("eds/safety-node.eds");
    let script = |phase: &str| {
        let mut command = Command::new(python);
        command
            .arg(root.join("xtask/interop/python_canopen.py"))
            .args([host, port])
            .arg(&eds)
            .args([&NODE.to_string(), phase]);
        command
    };
    let theirs = script_json(&mut script("operational"))?;
    let ours = tool_reading(tool, NODE)?;
    for key in ["identity", "srdos", "configuration_valid"] {
        if theirs[key] != ours[key] {
            bail!(
                "python-canopen and the tool read node {NODE}'s {key} differently:\n  python-canopen: {}\n  tool: {}",
                theirs[key],
                ours[key]
            );
        }
    }
    if ours["configuration_valid"] != 0xA5 {
        bail!("node {NODE} is not validated: {ours}");
    }
    let abort = theirs["operational_write_abort"].as_u64();
    if abort != Some(0x0800_0022) {
        bail!(
            "python-canopen's write to 1301h:03h in Operational: abort {abort:X?}, not 0800 0022h"
        );
    }
    println!(
        "xtask: {part}: python-canopen (EDS from eds/safety-node.eds) reads node {NODE}'s identity and {} SRDO records as the tool does; its write in Operational: abort 0800 0022h",
        ours["srdos"].as_array().map_or(0, Vec::len)
    );

    tool.nmt(NmtCommand::EnterPreOperational, NODE)?;
    let heartbeat = 0x700 + u16::from(NODE);
    let announced = network::receive_until(tool, Duration::from_secs(5), |frame| {
        frame.id().raw() == heartbeat && frame.data() == [0x7F]
    })?;
    if !announced {
        bail!("node {NODE} did not announce Pre-operational in its heartbeat within 5 s");
    }
    let theirs = script_json(&mut script("pre-operational"))?;
    let out_of_range = theirs["out_of_range_abort"].as_u64();
    if out_of_range != Some(0x0609_0032) {
        bail!("python-canopen's SCT of 0: abort {out_of_range:X?}, not 0609 0032h (value too low)");
    }
    if !theirs["valid_write_abort"].is_null() {
        bail!(
            "python-canopen's valid write was refused: {}",
            theirs["valid_write_abort"]
        );
    }
    let valid = tool.read_unsigned(NODE, Address::new(0x13FE, 0), 1)?;
    if theirs["configuration_valid"] != 0 || valid != 0 {
        bail!(
            "after python-canopen's valid write 0x13FE reads {} (python-canopen) and {valid:02X}h (tool), not 0",
            theirs["configuration_valid"]
        );
    }
    println!(
        "xtask: {part}: in Pre-operational an SCT of 0 is aborted with 0609 0032h; a valid write is accepted and 0x13FE reads 0 (python-canopen and the tool)"
    );
    Ok(())
}

/// `cargo xtask interop`.
pub fn task(root: &Path, only: Option<Part>) -> Result<()> {
    let python = python(root)?;
    let runs = |part| only.is_none_or(|only| only == part);
    if runs(Part::Socketcand) {
        socketcand(root, &python)?;
    }
    if runs(Part::Simulated) {
        simulated(root, &python)?;
    }
    if runs(Part::Canopen) {
        canopen(root, &python)?;
    }
    Ok(())
}
