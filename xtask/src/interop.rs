//! `cargo xtask interop`: third-party CANopen software on the emulated bus, through a
//! socketcand port (the hub's or `emulate-network`'s), in a virtual environment under `target/interop/venv` (python-can and
//! python-canopen from PyPI, pinned).
//!
//! 1. python-can's own `socketcand` bus against `can-hub`: frames sent by the tool
//!    library's socketcand client reach python-can, and python-can's answers reach the tool,
//!    identifier and data exact, a frame without data included.
//! 2. python-canopen against the host simulation's nodes 1 and 33 (the protocol core,
//!    configured by the tool library, in real time behind a socketcand server built from the
//!    tool's server session: `tests/src/bin/socketcand_sim.rs`), then
//! 3. python-canopen on the emulated network (the shipped images on four emulated
//!    STM32F405s, as `cargo xtask run` starts and configures them); both times it loads the node's EDS (`eds/safety-node.eds`) with
//!    `canopen.import_od`, first sweeps every entry of it on node 33 in Pre-operational (and
//!    at the end on node 1, the producer)
//!    (`xtask/interop/python_canopen_sweep.py`: each readable entry uploads as many bytes as
//!    its type has, read-only entries refuse a download with 0601 0002h and write-only ones an
//!    upload with 0601 0001h, writable 2- and 4-byte entries refuse a wrong length with a
//!    length abort, the sub-index past each record's last with 0609 0011h, an object the EDS
//!    does not list with 0602 0000h, and 13FEh reads A5h before and after), starts it again,
//!    then reads node 33's identity and whole SRDO configuration and agrees
//!    with the tool's reading; its write to a safety object in Operational is aborted with
//!    0800 0022h (EN 50325-5 8.2.2); in Pre-operational an SCT of 0 is aborted with
//!    0609 0032h and a valid write is accepted and resets 0x13FE (EN 50325-5 6.4.1.6).
//! 4. python-canopen on the emulated SimpleCAN network (the shipped SimpleCAN images, configured from
//!    `scenarios/networks/simplecan.toml`): the same sweep of every entry, with the SimpleCAN
//!    images' EDS (`eds/safety-node-simplecan.eds`), on node 33.
//! 5. (`--only mixed-load`) python-canopen beside python-can's bus load, below.
//! 6. python-canopen's LSS master (CiA 305: fast scan, configure node-ID, store) on the
//!    shipped images of an unconfigured node, switches open, on the emulator's network
//!    (`emulate-network --nodes 0 --socketcand`, [`lss`]); `--only lss-bench` times the tool's fastscan and python-canopen's against the bus
//!    time of their frames, into docs/tool.md.
//! 7. The shipped hardware images on the emulator's network (`emulate-network --socketcand`:
//!    nodes 1 and 33, channels A and B), joined by separate programs
//!    ([`emulated_network`]): python-can sees both nodes' heartbeats, python-canopen reads node
//!    1's identity and producer heartbeat time by SDO, and the `safety-config` program
//!    configures and starts both nodes from the network file.

mod lss;

use crate::child::Guarded;
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
use std::process::{Command, Stdio};
use std::time::Duration;

/// The PyPI packages, pinned: what CI installs is what was tested.
const PACKAGES: [&str; 2] = ["python-can==4.6.1", "canopen==2.4.1"];

/// Which part to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Part {
    /// python-can's socketcand bus against the hub alone.
    Socketcand,
    /// python-canopen on the host simulation's nodes behind a socketcand server.
    Simulated,
    /// python-canopen on the shipped images on the emulated network.
    Canopen,
    /// python-canopen's sweep of the SimpleCAN images' EDS on the shipped SimpleCAN images on
    /// the emulated network.
    Simplecan,
    /// python-canopen reading node 33's objects back to back on the shipped images' emulated network while
    /// python-can fills 30 % of the bus, for 60 s of the bus's time: the largest SDO response
    /// time and heartbeat gap. Only when asked for (`--only mixed-load`): it takes minutes.
    MixedLoad,
    /// python-canopen's LSS master configures an unconfigured node of the shipped images on
    /// the emulated network (fast scan, configure node-ID, store), the tool inquires it.
    Lss,
    /// python-can, python-canopen and the configuration tool as separate programs on the
    /// shipped images' emulated network (`emulate-network --socketcand`).
    EmulatedNetwork,
    /// The tool's and python-canopen's fastscan of 1 and 8 unconfigured nodes in bus time,
    /// against the bus time of their frames, into docs/tool.md. Only when asked for
    /// (`--only lss-bench`): python-canopen's scans take minutes.
    LssBench,
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

/// A free TCP port on the loopback address (the hub of part 1 listens there, so that it
/// never meets a network another task runs on the fixed ports).
pub(crate) fn free_port() -> Result<u16> {
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
    crate::step("interop 1: python-can's socketcand bus against can-hub");
    crate::run(crate::cargo().args(["build", "--quiet", "-p", "can-hub"]))?;
    let port = free_port()?;
    let address = format!("127.0.0.1:{port}");
    let _hub =
        Guarded::spawn(Command::new(root.join("target/debug/can-hub")).args(["--tcp", &address]))
            .context("starting can-hub")?;
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
    let mut child = Guarded::spawn(
        Command::new(python)
            .arg(root.join("xtask/interop/python_can_bus.py"))
            .args(["127.0.0.1", &port.to_string(), &sent.len().to_string()])
            .stdout(Stdio::piped()),
    )?;
    let stdout = child.take_stdout().context("the script's output")?;
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
    crate::step("interop 2: python-canopen on the host simulation's nodes (socketcand)");
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
    let _server = Guarded::spawn(
        Command::new(root.join("target/debug/socketcand_sim")).arg(port.to_string()),
    )
    .context("starting socketcand_sim")?;
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

/// Part 3: python-canopen on the shipped images on the emulated network.
fn canopen(root: &Path, python: &Path) -> Result<()> {
    crate::step(
        "interop 3: python-canopen on the shipped images on the emulated network, through \
         emulate-network's socketcand port",
    );
    let mut network = Network::start_for(root, network::Protocol::CanopenSafety)?;
    let result = network
        .tool()
        .and_then(|tool| canopen_checks(root, python, &network::hub_tcp(), tool, "interop 3"));
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
    sweep(python, &eds, host, port, NODE, part)?;
    let heartbeat = 0x700 + u16::from(NODE);
    let operational = network::receive_until(tool, Duration::from_secs(5), |frame| {
        frame.id().raw() == heartbeat && frame.data() == [0x05]
    })?;
    if !operational {
        bail!("node {NODE} did not announce Operational within 5 s of the sweep's NMT start");
    }
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
    // The producer too (its SRDO 1 transmits by the pre-defined connection set): last, since
    // its Pre-operational stops the SRDO node 33 consumed, and node 33 is done.
    sweep(python, &eds, host, port, 1, part)
}

/// python-canopen's sweep of every entry of `eds` on `node` (`xtask/interop/python_canopen_sweep.py`:
/// sizes, access types and abort codes as the EDS and CiA 301 give them, 13FEh unchanged by
/// the refused writes); fails on any deviation, naming each.
fn sweep(python: &Path, eds: &Path, host: &str, port: &str, node: u8, part: &str) -> Result<()> {
    let root = eds
        .parent()
        .and_then(Path::parent)
        .context("the EDS's repository")?;
    let result = script_json(
        Command::new(python)
            .arg(root.join("xtask/interop/python_canopen_sweep.py"))
            .args([host, port])
            .arg(eds)
            .arg(node.to_string()),
    )?;
    let deviations: Vec<&str> = result["deviations"]
        .as_array()
        .context("the sweep's deviations")?
        .iter()
        .filter_map(serde_json::Value::as_str)
        .collect();
    if !deviations.is_empty() {
        bail!(
            "python-canopen's sweep of node {node} against {}: {} deviations:\n  {}",
            eds.display(),
            deviations.len(),
            deviations.join("\n  ")
        );
    }
    println!(
        "xtask: {part}: python-canopen's sweep of node {node} against {}: {} entries, each answered as the EDS and CiA 301 say (sizes, read-only and write-only refusals, length aborts, missing sub-indices and objects); 13FEh {}h before and after",
        eds.strip_prefix(root).unwrap_or(eds).display(),
        result["checked"],
        result["valid"].as_str().unwrap_or("?").to_uppercase()
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
    if runs(Part::Simplecan) {
        simplecan(root, &python)?;
    }
    if runs(Part::Lss) {
        lss::check(root, &python)?;
    }
    if runs(Part::EmulatedNetwork) {
        emulated_network(root, &python)?;
    }
    if only == Some(Part::MixedLoad) {
        mixed_load(root, &python)?;
    }
    if only == Some(Part::LssBench) {
        lss::bench(root, &python)?;
    }
    Ok(())
}

/// The bus time [`mixed_load`] runs for, in seconds.
pub const MIXED_LOAD_SECONDS: u32 = 60;

/// The share of the bus python-can fills in [`mixed_load`], in percent.
const MIXED_LOAD_PERCENT: u32 = 30;

/// Part 5: python-canopen uploads node 33's identity and SRDO configuration one after the
/// other (its own time-out, host time) while python-can sends ordinary frames, a fifth of
/// them on low identifiers (010h..02Eh, above every frame of the nodes), filling
/// [`MIXED_LOAD_PERCENT`] of the bus counted in the bus's time; a third connection records
/// every frame with the hub's time stamp (`xtask/interop/mixed_load.py`). Reports, on the
/// bus's time, the largest SDO response time (request to answer), the longest gap between two
/// heartbeats of each node and the longest stretch of frames back to back (a burst of the
/// load delays every frame of lower priority that long), beside the uploads, the client's
/// time-outs and the
/// replies it found answering another request. Fails when a request went unanswered on the
/// bus, or the load fell short of its share (the case then measured nothing).
fn mixed_load(root: &Path, python: &Path) -> Result<()> {
    crate::step(&format!(
        "interop 5: python-canopen reading node 33 back to back beside python-can's \
         {MIXED_LOAD_PERCENT} % of the bus, for {MIXED_LOAD_SECONDS} s of the bus's time (the \
         shipped images)"
    ));
    let mut network = Network::start_for(root, network::Protocol::CanopenSafety)?;
    network.release_tool();
    let address = network::hub_tcp();
    let result = address
        .split_once(':')
        .context("the hub's address")
        .and_then(|(host, port)| {
            script_json(
                Command::new(python)
                    .arg(root.join("xtask/interop/mixed_load.py"))
                    .args([host, port, "33"])
                    .arg(MIXED_LOAD_SECONDS.to_string())
                    .arg(MIXED_LOAD_PERCENT.to_string()),
            )
        });
    // The hub reports its pacing every second on the control port: the latest report.
    let _ = network
        .control
        .watch(std::time::Duration::from_millis(1500));
    let pace = network.pace_summary();
    let faults = network.stop();
    let result = result?;
    faults?;
    let number = |key: &str| result[key].as_f64().unwrap_or(f64::NAN);
    let gaps = &result["heartbeat_gap_max_ms"];
    let gap = |node: &str| gaps[node].as_f64().unwrap_or(f64::NAN);
    println!(
        "interop 5: {:.1} s of bus time, {} frames, the load {:.1} % of the bus ({:.1} % in \
         all; frames back to back for at most {:.1} ms); {} SDO requests answered, the largest \
         response time {:.2} ms (bus time); \
         longest gap between heartbeats: node 1 {:.1} ms, node 33 {:.1} ms (bus time; \
         producer time 100 ms); python-canopen: {} uploads, {} time-outs ({} s, host time), \
         {} replies to another request; longest upload {:.3} s of host time; {pace}",
        number("bus_seconds"),
        result["frames"],
        100.0 * number("load_share"),
        100.0 * number("bus_share"),
        number("longest_busy_ms"),
        result["sdo_responses"],
        number("sdo_response_max_ms"),
        gap("1"),
        gap("33"),
        result["uploads"],
        result["timeouts"],
        result["client_timeout_s"],
        result["wrong_replies"],
        number("longest_upload_host_s"),
    );
    if let Some(failures) = result["failures"].as_array().filter(|f| !f.is_empty()) {
        for failure in failures {
            println!(
                "interop 5: python-canopen: {}",
                failure.as_str().unwrap_or("?")
            );
        }
    }
    let requests = result["sdo_requests"].as_u64().unwrap_or(0);
    let answered = result["sdo_responses"].as_u64().unwrap_or(0);
    if answered < requests {
        bail!(
            "interop 5: {} of node 33's {requests} SDO requests on the bus went unanswered",
            requests - answered
        );
    }
    let share = 100.0 * number("load_share");
    if share.is_nan() || share < f64::from(MIXED_LOAD_PERCENT) * 0.8 {
        bail!(
            "interop 5: python-can's load filled {share:.1} % of the bus, not the \
             {MIXED_LOAD_PERCENT} % the case is about"
        );
    }
    Ok(())
}

/// Part 4: python-canopen sweeps every entry of the SimpleCAN images' EDS
/// (`eds/safety-node-simplecan.eds`) on node 33 of the emulated SimpleCAN network, as part 3
/// does the CANopen Safety EDS: the SimpleCAN objects 5E00h..5EFFh, the SRDO table of none
/// (13FEh, 13FFh:00) and the audit records of SimpleCAN's signature included.
fn simplecan(root: &Path, python: &Path) -> Result<()> {
    crate::step(
        "interop 4: python-canopen's sweep of the SimpleCAN images' EDS on the shipped \
         SimpleCAN images on the emulated network, through emulate-network's socketcand port",
    );
    let mut network = Network::start_for(root, network::Protocol::Simplecan)?;
    // Only python-canopen talks from here; the network's own connection would not be read.
    network.release_tool();
    let address = network::hub_tcp();
    let result = address
        .split_once(':')
        .context("the hub's address")
        .and_then(|(host, port)| {
            sweep(
                python,
                &root.join("eds/safety-node-simplecan.eds"),
                host,
                port,
                33,
                "interop 4",
            )
        });
    let faults = network.stop();
    result?;
    faults?;
    Ok(())
}

/// The heading of the section `cargo xtask interop --bench` writes into docs/performance.md.
pub const BENCH_HEADING: &str = "## Configuration tool beside python-canopen";

/// How many times each side configures and verifies the node (the table gives the median
/// and the range).
const BENCH_ROUNDS: usize = 5;

/// The bench's nodes: node 1, and in the second case node 33 beside it.
const BENCH_NODES: [u8; 2] = [1, 33];

/// The bench's network file for the first `nodes` of [`BENCH_NODES`]: each with every SRDO the
/// firmware holds (`safety_device::SRDO_COUNT`) transmitting the input and its inverted
/// copy, as `tool_bench`'s 16 do on the host simulation; node 1 on 101h..108h, node 33 on the
/// next identifiers (the bench does not start the nodes, but no two SRDOs share one).
fn bench_file(nodes: usize) -> String {
    let mut file = String::new();
    for (index, id) in BENCH_NODES.iter().take(nodes).enumerate() {
        file.push_str(&format!(
            "[[node]]\nid = {id}\nidentity = {{ vendor = 0xABC, product = 0x304, revision = 1, serial = {id} }}\n"
        ));
        for n in 1..=safety_device::SRDO_COUNT {
            let plain = 0x0FF + 2 * (index * safety_device::SRDO_COUNT + n);
            file.push_str(&format!(
                "\n[[node.srdo]]\nnumber = {n}\ndirection = \"transmit\"\nrefresh_time_ms = 100\n\
                 srvt_ms = 20\ncob_ids = [0x{plain:X}, 0x{:X}]\nmapping = [\"input\", \"input_inverted\"]\n",
                plain + 1
            ));
        }
        file.push('\n');
    }
    file
}

/// One side's round: wall time of configure and of verify, SDO transactions of each.
#[derive(Clone, Copy, Debug)]
struct Round {
    configure: Duration,
    verify: Duration,
    configure_transactions: u64,
    verify_transactions: u64,
}

/// The tool library configures and verifies the bench's nodes; fails unless every node is
/// configured, valid and matches the file. One node: `configure` and `verify` over
/// `clients[0]`, as the program runs them; several: `configure_concurrently` and
/// `verify_concurrently`, node `i` over `clients[i]`.
fn tool_round(
    clients: &mut [Client<SocketcandClient>],
    spec: &safety_config::network_file::Network,
) -> Result<Round> {
    let requests = |clients: &[Client<SocketcandClient>]| -> u64 {
        clients.iter().map(|client| client.requests).sum()
    };
    let quiet = &mut procedure::Quiet {
        accept_identity: false,
    };
    let before = requests(clients);
    let started = std::time::Instant::now();
    let report = match clients {
        [client] => procedure::configure(client, spec, false, quiet)?,
        _ => procedure::configure_concurrently(clients, spec, false, quiet)?,
    };
    let configured = std::time::Instant::now();
    let configure_transactions = requests(clients) - before;
    if !report.success() {
        bail!(
            "the tool did not configure the bench's nodes: {:?}",
            report.nodes
        );
    }
    let verdicts = match clients {
        [client] => procedure::verify(client, spec)?,
        _ => procedure::verify_concurrently(clients, spec)?,
    };
    let verified = std::time::Instant::now();
    if !verdicts
        .iter()
        .all(|verdict| matches!(verdict, procedure::Verdict::Matches { .. }))
    {
        bail!("the tool's verify after its configure: {verdicts:?}");
    }
    Ok(Round {
        configure: configured - started,
        verify: verified - configured,
        configure_transactions,
        verify_transactions: requests(clients) - before - configure_transactions,
    })
}

/// python-canopen does the same writes and read-backs; then the tool verifies what it left
/// (the same verified result: matches the file, signatures valid, 0x13FE = A5h).
fn python_round(
    root: &Path,
    python: &Path,
    address: &str,
    tool: &mut Client<SocketcandClient>,
    spec: &safety_config::network_file::Network,
) -> Result<Round> {
    let (host, port) = address.split_once(':').context("the server's address")?;
    let nodes: Vec<serde_json::Value> = spec
        .nodes
        .iter()
        .map(|node| {
            let srdos: Vec<serde_json::Value> = node
                .srdos
                .iter()
                .map(|srdo| {
                    let s = &srdo.settings;
                    serde_json::json!({
                        "number": srdo.number, "direction": s.direction,
                        "cycle_time": s.cycle_time, "srvt": s.srvt, "cob_id_1": s.cob_id_1,
                        "cob_id_2": s.cob_id_2, "mapping": s.mapping,
                    })
                })
                .collect();
            serde_json::json!({ "id": node.id, "srdos": srdos })
        })
        .collect();
    let result = script_json(
        Command::new(python)
            .arg(root.join("xtask/interop/python_canopen_configure.py"))
            .args([host, port])
            .arg(root.join("eds/safety-node.eds"))
            .arg(serde_json::json!({ "nodes": nodes }).to_string()),
    )?;
    let verdicts = procedure::verify(tool, spec)?;
    if !verdicts
        .iter()
        .all(|verdict| matches!(verdict, procedure::Verdict::Matches { .. }))
    {
        bail!("the tool's verify after python-canopen's configure: {verdicts:?}");
    }
    let seconds = |key: &str| {
        result[key]
            .as_f64()
            .and_then(|s| Duration::try_from_secs_f64(s).ok())
            .with_context(|| format!("python-canopen's {key} in {result}"))
    };
    let count = |key: &str| {
        result[key]
            .as_u64()
            .with_context(|| format!("python-canopen's {key} in {result}"))
    };
    Ok(Round {
        configure: seconds("configure_s")?,
        verify: seconds("verify_s")?,
        configure_transactions: count("configure_transactions")?,
        verify_transactions: count("verify_transactions")?,
    })
}

/// Median and range of `values` in milliseconds, `median (min–max)`.
fn spread(mut values: Vec<Duration>) -> (Duration, String) {
    values.sort();
    let ms = |d: &Duration| d.as_secs_f64() * 1000.0;
    let median = values[values.len() / 2];
    let text = format!(
        "{:.0} ms ({:.0}–{:.0})",
        ms(&median),
        ms(&values[0]),
        ms(&values[values.len() - 1])
    );
    (median, text)
}

/// Whether the target (the tool faster than python-canopen) is met on one bus, judged on
/// configure + verify of every round: met when every round of the tool was faster than every
/// round of python-canopen; a faster median alone, with the rounds overlapping, does not
/// show it.
fn verdict(tool: &[Round], python: &[Round]) -> String {
    let total = |rounds: &[Round]| -> Vec<Duration> {
        let mut totals: Vec<Duration> = rounds.iter().map(|r| r.configure + r.verify).collect();
        totals.sort();
        totals
    };
    let (ours, theirs) = (total(tool), total(python));
    let ms = |d: Duration| d.as_secs_f64() * 1000.0;
    let (our_median, their_median) = (ours[ours.len() / 2], theirs[theirs.len() / 2]);
    if ours[ours.len() - 1] < theirs[0] {
        format!(
            "met: every round of the tool was faster than every round of python-canopen \
             (median {:.2} times as fast)",
            ms(their_median) / ms(our_median)
        )
    } else if our_median < their_median {
        format!(
            "not shown: the tool's median is faster ({:.0} ms against {:.0} ms) but the rounds \
             overlap",
            ms(our_median),
            ms(their_median)
        )
    } else {
        format!(
            "NOT met: the tool's median {:.0} ms, python-canopen's {:.0} ms",
            ms(our_median),
            ms(their_median)
        )
    }
}

/// The rounds of both sides on one bus with `nodes` nodes, as table rows.
fn bench_rows(bus: &str, nodes: &str, tool: &[Round], python: &[Round]) -> String {
    let mut rows = String::new();
    for (who, rounds) in [("safety-config", tool), ("python-canopen 2.4.1", python)] {
        let (_, configure) = spread(rounds.iter().map(|r| r.configure).collect());
        let (_, verify) = spread(rounds.iter().map(|r| r.verify).collect());
        let (_, both) = spread(rounds.iter().map(|r| r.configure + r.verify).collect());
        let first = rounds[0];
        rows.push_str(&format!(
            "| {bus} | {nodes} | {who} | {} + {} | {configure} | {verify} | {both} |\n",
            first.configure_transactions, first.verify_transactions
        ));
    }
    rows
}

/// One case of the bench on one bus: the tool's rounds and python-canopen's.
struct Case {
    tool: Vec<Round>,
    python: Vec<Round>,
}

/// Both cases (node 1 alone, nodes 1 and 33) on the socketcand server at `address`: each
/// side [`BENCH_ROUNDS`] times, alternating. The tool has a connection of its own per node
/// (`procedure::configure_concurrently`), python-canopen one for all; both connect before
/// their clocks start.
fn bench_on(
    root: &Path,
    python: &Path,
    address: &str,
    mut start_up: impl FnMut() -> Result<()>,
) -> Result<[Case; 2]> {
    // Both sides wait as long for an SDO answer (the script's RESPONSE_TIMEOUT): on the
    // emulated network a loaded host holds the virtual time, and with it an answer, for
    // seconds of host time now and then (`docs/emulation.md`), which the bench should time,
    // not fail on.
    // Connected per case, so that no connection sits unread through a case it has no part
    // in (the server's frames would pile up in it, and its first request drain them).
    let mut case = |nodes: usize| -> Result<Case> {
        let mut clients = BENCH_NODES[..nodes]
            .iter()
            .map(|_| {
                SocketcandClient::connect(address, "can0")
                    .map(|transport| Client::new(transport, BENCH_SDO_TIMEOUT))
                    .context("the bench's connections to the socketcand server")
            })
            .collect::<Result<Vec<_>>>()?;
        let spec = safety_config::network_file::parse(&bench_file(nodes), "bench network file")?;
        let (tool, python) =
            bench_rounds(root, python, address, &mut clients, &spec, &mut start_up)?;
        Ok(Case { tool, python })
    };
    Ok([case(1)?, case(BENCH_NODES.len())?])
}

/// Switches every node of the shipped images' network off and on (`power-cycle` on the
/// control port) and waits until each of [`BENCH_NODES`] answers an SDO upload of its
/// identity again: a store needs a start-up since the last one (the manual,
/// "Parameterisation"), and each round of the bench stores.
fn power_cycle_nodes(network: &mut Network) -> Result<()> {
    network.command("power-cycle node1a node1b node33a node33b")?;
    let mut client = Client::new(
        SocketcandClient::connect(&network::hub_tcp(), "can0")
            .context("a connection to wait for the nodes' start-up")?,
        Duration::from_millis(500),
    );
    let give_up = std::time::Instant::now() + Duration::from_secs(60);
    for node in BENCH_NODES {
        while safety_config::procedure::read_identity(&mut client, node).is_err() {
            if std::time::Instant::now() >= give_up {
                bail!("node {node} did not answer an SDO upload within 60 s of its power cycle");
            }
        }
    }
    Ok(())
}

/// How long each side of the bench waits for one SDO answer: python-canopen's
/// `RESPONSE_TIMEOUT` in `xtask/interop/python_canopen_configure.py`.
const BENCH_SDO_TIMEOUT: Duration = Duration::from_secs(2);

/// [`bench_on`]'s rounds of one case, alternating.
fn bench_rounds(
    root: &Path,
    python: &Path,
    address: &str,
    clients: &mut [Client<SocketcandClient>],
    spec: &safety_config::network_file::Network,
    start_up: &mut impl FnMut() -> Result<()>,
) -> Result<(Vec<Round>, Vec<Round>)> {
    let (mut ours, mut theirs) = (Vec::new(), Vec::new());
    for round in 1..=BENCH_ROUNDS {
        start_up()?;
        ours.push(tool_round(clients, spec)?);
        start_up()?;
        theirs.push(python_round(root, python, address, &mut clients[0], spec)?);
        println!(
            "xtask: bench round {round} ({} node(s)): tool {:?} + {:?}, python-canopen {:?} + {:?}",
            spec.nodes.len(),
            ours[round - 1].configure,
            ours[round - 1].verify,
            theirs[round - 1].configure,
            theirs[round - 1].verify
        );
    }
    Ok((ours, theirs))
}

/// `cargo xtask interop --bench`: the tool and python-canopen configure and verify the same
/// node, then two nodes, on the emulated bus (and on the host simulation behind
/// `socketcand_sim`), wall times side by side, written into docs/performance.md.
pub fn bench(root: &Path) -> Result<()> {
    let python = python(root)?;
    let count = safety_device::SRDO_COUNT;

    crate::step("interop bench 1: the host simulation behind socketcand_sim");
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
    let simulated = {
        let _server = Guarded::spawn(
            Command::new(root.join("target/debug/socketcand_sim")).arg(port.to_string()),
        )
        .context("starting socketcand_sim")?;
        // The simulation configures its nodes before it listens.
        let give_up = std::time::Instant::now() + Duration::from_secs(20);
        while SocketcandClient::connect(&address, "can0").is_err() {
            if std::time::Instant::now() >= give_up {
                bail!("socketcand_sim did not listen on {address} within 20 s");
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        // The simulation's flash erases without stalling: a store needs no start-up.
        bench_on(root, &python, &address, || Ok(()))?
    };

    crate::step(
        "interop bench 2: the shipped images on the emulated network, through \
         emulate-network's socketcand port, every node switched off and on before each store",
    );
    let mut network = Network::start_for(root, network::Protocol::CanopenSafety)?;
    // The network's own connection would not be read during the bench.
    network.release_tool();
    let emulated = bench_on(root, &python, &network::hub_tcp(), || {
        power_cycle_nodes(&mut network)
    });
    let faults = network.stop();
    let emulated = emulated?;
    faults?;

    let buses = [
        (
            "host simulation (socketcand_sim)",
            "host simulation",
            &simulated,
        ),
        (
            "emulated network (the shipped images, emulate-network)",
            "emulated network",
            &emulated,
        ),
    ];
    let mut rows = String::new();
    let mut verdicts = String::new();
    for (index, (nodes, named)) in [("1", "Node 1"), ("1 and 33", "Nodes 1 and 33")]
        .into_iter()
        .enumerate()
    {
        for (bus, short, cases) in &buses {
            let case = &cases[index];
            rows.push_str(&bench_rows(bus, nodes, &case.tool, &case.python));
            verdicts.push_str(&format!(
                " {named}, {short}: {}.",
                verdict(&case.tool, &case.python)
            ));
        }
    }
    let section = format!(
        "{BENCH_HEADING}\n\n\
         Generated by `cargo xtask interop --bench` ({}): node 1, then nodes 1 and 33, each \
         node with its {count} SRDOs (`safety_device::SRDO_COUNT`, all the firmware \
         holds; each transmits the input and its inverted copy) configured and verified \
         {BENCH_ROUNDS} times by each side, alternating, through a socketcand server: \
         `safety-config`'s `configure` and `verify` (the library, as the program runs them; \
         with two nodes `configure_concurrently` and `verify_concurrently`, each node over a \
         connection of its own, the nodes side by side, CiA 301 7.2.4 allowing one transfer at \
         a time per SDO server), and python-canopen 2.4.1 doing the same SDO writes and \
         read-backs in the same order, node after node \
         (`xtask/interop/python_canopen_configure.py`: identity, NMT pre-operational, every \
         SRDO deleted, mappings, communication parameters, every record read back and \
         compared, signatures by `binascii.crc_hqx` written and read back, 0x13FE, store, \
         0x13FE again; then identity, 0x13FE, every record and signature; the tool's verify \
         reads 0x13FF:00h as well; python-canopen could run a thread per node too, the script \
         does not). After every python-canopen round the tool's `verify` confirms the same \
         result: every node matches the file, signed and valid. Both sides connect before \
         their clocks start. Wall time, host load included, median (min–max) of the rounds; \
         on the emulated network (the shipped images on `emulate-network`) the bus runs on \
         the network's virtual time, so host load slows both sides alike, and every node is \
         switched off and on before each side's round, outside its clock (a store needs a \
         start-up since the last one on the hardware).\n\n\
         | bus | nodes | who | SDO transactions (configure + verify) | configure | verify | both |\n\
         |-----|-------|-----|--------------------------------------:|----------:|-------:|-----:|\n\
         {rows}\n\
         Target: faster than python-canopen for the same verified result (configure + \
         verify, every round).{verdicts}\n",
        load_average(),
    );
    let docs = root.join("docs/performance.md");
    let old = std::fs::read_to_string(&docs).unwrap_or_default();
    std::fs::write(&docs, with_section(&old, &section))?;
    println!("{section}");
    Ok(())
}

/// The machine's load average as the bench saw it (`/proc/loadavg`), for the report.
pub(crate) fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|text| text.split_whitespace().next().map(str::to_owned))
        .map_or_else(
            || "load average unknown".to_owned(),
            |load| format!("load average {load} at the end"),
        )
}

/// `document` with its [`BENCH_HEADING`] section (up to the next `## ` heading) replaced by
/// `section`, or `section` appended when it has none.
pub fn with_section(document: &str, section: &str) -> String {
    let Some(start) = document.find(BENCH_HEADING) else {
        let mut out = document.trim_end().to_owned();
        out.push_str("\n\n");
        out.push_str(section);
        return out;
    };
    let end = section_end(document, start);
    format!("{}{section}{}", &document[..start], &document[end..])
}

/// Where the section that starts at `start` ends: at the next heading of its level or the
/// next generated block's marker (another writer's, `<!-- name:begin ... -->`), which belongs
/// to what follows; else at the end of `document`.
fn section_end(document: &str, start: usize) -> usize {
    let from = start + BENCH_HEADING.len();
    ["\n## ", "\n<!-- "]
        .iter()
        .filter_map(|next| document[from..].find(next))
        .min()
        .map_or(document.len(), |at| from + at + 1)
}

/// The [`BENCH_HEADING`] section of `document`, for a writer of the rest of the file to
/// keep (`cargo xtask bench`).
pub fn kept_section(document: &str) -> Option<&str> {
    let start = document.find(BENCH_HEADING)?;
    Some(&document[start..section_end(document, start)])
}

/// How long python-can listens to the shipped images' heartbeats in part 7 (host time).
const HEARTBEAT_SECONDS: &str = "2";

/// Part 7: the shipped hardware images on the emulator's network, joined from outside over
/// its socketcand port (`emulate-network --socketcand`, the virtual time following the host
/// clock): python-can receives both nodes' heartbeats (CiA 301 7.2.8.3.2: Pre-operational,
/// unconfigured); python-canopen reads node 1's identity (1018h) and producer heartbeat time
/// (1017h) by SDO, which agree with the tool library's reading and the EDS's default; then
/// the `safety-config` program configures both nodes from the network file and starts them
/// (EN 50325-5 8.3.1), and the tool library sees both heartbeats Operational and node 1's
/// SRDO 1 on the bus. Measured, not asserted: the heartbeat period python-can saw on the
/// server's time stamps and the wall time of each step.
fn emulated_network(root: &Path, python: &Path) -> Result<()> {
    crate::step(
        "interop 7: python-can, python-canopen and safety-config on the shipped images' \
         emulated network (emulate-network --socketcand)",
    );
    crate::run(
        crate::cargo()
            .current_dir(root)
            .args(["build", "--quiet", "-p", "safety-config"]),
    )?;
    let mut served = ShippedNetwork::serve(
        root,
        network::Protocol::CanopenSafety,
        "emulated-network",
        &["--inputs-closed"],
    )?;
    let file = served.dir.join("network.toml");
    std::fs::write(&file, network::Protocol::CanopenSafety.network_file())?;
    let result = emulated_network_checks(root, python, &served.address, &file);
    served.emulator.end();
    let log_path = served.log;
    let log = std::fs::read_to_string(&log_path).unwrap_or_default();
    if let Some(line) = log.lines().rev().find(|line| line.contains("socketcand:")) {
        println!("xtask: interop 7: {line}");
    }
    result.with_context(|| format!("the emulator's output is in {}", log_path.display()))
}

/// The shipped CANopen Safety images on the emulator's network, serving socketcand
/// (`emulate-network --socketcand`), as parts 6 and 7 run them.
struct ShippedNetwork {
    /// The running emulator; ended on drop.
    emulator: Guarded,
    /// Its socketcand address (`127.0.0.1:PORT`).
    address: String,
    /// The part's directory under `target/interop/`.
    dir: PathBuf,
    /// The emulator's output.
    log: PathBuf,
}

impl ShippedNetwork {
    /// Builds the shipped images of `protocol` and `emulate-network`, and starts it with
    /// `arguments` (the nodes, the contacts) on a free port, its output in `target/interop/NAME/`.
    fn serve(
        root: &Path,
        protocol: network::Protocol,
        name: &str,
        arguments: &[&str],
    ) -> Result<ShippedNetwork> {
        let cross = crate::toolchain::ensure()?;
        crate::toolchain::ensure_emulator_build_deps()?;
        let layer = protocol.hardware_layer();
        crate::images::build_layer(root, &cross, layer)?;
        let emulate = crate::emulate::build_emulate_network(root)?;
        let dir = root.join("target/interop").join(name);
        std::fs::create_dir_all(&dir)?;
        let log = dir.join("emulate-network.log");
        let output = std::fs::File::create(&log)?;
        let address = format!("127.0.0.1:{}", free_port()?);
        let emulator = Guarded::spawn(
            Command::new(emulate)
                .arg(crate::images::image(&cross, root, layer, "a"))
                .arg(crate::images::image(&cross, root, layer, "b"))
                .args(arguments)
                .args(["--quiet", "--socketcand", &address])
                .stdout(output.try_clone()?)
                .stderr(output),
        )
        .context("starting emulate-network")?;
        Ok(ShippedNetwork {
            emulator,
            address,
            dir,
            log,
        })
    }
}

/// Part 7's steps against the emulated network serving socketcand at `address`.
fn emulated_network_checks(root: &Path, python: &Path, address: &str, file: &Path) -> Result<()> {
    let mut tool = network::connect_tool_at(address, Duration::from_secs(20))?;
    let booted = network::await_heartbeats(&mut tool, Duration::from_secs(20), |_| true)?;
    if booted != [true, true] {
        bail!("no heartbeat from node 1 and node 33 within 20 s of joining: {booted:?}");
    }

    let (host, port) = address.split_once(':').context("the address")?;
    let started = std::time::Instant::now();
    let result = script_json(
        Command::new(python)
            .arg(root.join("xtask/interop/python_emulated_network.py"))
            .args([host, port])
            .arg(root.join("eds/safety-node.eds"))
            .arg(HEARTBEAT_SECONDS),
    )?;
    let python_seconds = started.elapsed().as_secs_f64();
    let mut periods = Vec::new();
    for node in ["1", "33"] {
        let beats = result["heartbeats"][node].as_array().with_context(|| {
            format!("python-can received no heartbeat of node {node}: {result}")
        })?;
        let states: Vec<u64> = beats.iter().filter_map(|beat| beat[1].as_u64()).collect();
        if states.is_empty() || states.iter().any(|state| *state != 0x7F) {
            bail!(
                "python-can received node {node}'s heartbeats with states {states:X?}, not \
                 Pre-operational (7Fh) each"
            );
        }
        let stamps: Vec<f64> = beats.iter().filter_map(|beat| beat[0].as_f64()).collect();
        let gaps: Vec<f64> = stamps.windows(2).map(|pair| pair[1] - pair[0]).collect();
        let mean = gaps.iter().sum::<f64>() / gaps.len().max(1) as f64;
        periods.push(format!(
            "node {node}: {} heartbeats, {:.1} ms apart on average",
            states.len(),
            mean * 1e3
        ));
    }
    let theirs = &result["node1"];
    let ours = procedure::read_identity(&mut tool, 1)?;
    let identity = [ours.vendor, ours.product, ours.revision, ours.serial];
    if theirs["identity"] != serde_json::json!(identity) {
        bail!(
            "python-canopen read node 1's identity {} and the tool {identity:X?}",
            theirs["identity"]
        );
    }
    let heartbeat_ms = crate::emulate::default_heartbeat_ms()?;
    if theirs["heartbeat_time_ms"].as_u64() != Some(heartbeat_ms) {
        bail!(
            "python-canopen read node 1's 1017h as {}, not the EDS's default {heartbeat_ms} ms",
            theirs["heartbeat_time_ms"]
        );
    }
    println!(
        "xtask: interop 7: python-can received {} frames in {HEARTBEAT_SECONDS} s, both nodes' \
         heartbeats Pre-operational ({}; the producer heartbeat time is {heartbeat_ms} ms); \
         python-canopen read node 1's 1018h:01h..04h {:X?} (as the tool does) and 1017h = \
         {heartbeat_ms} ms in {} s; {python_seconds:.1} s with its start",
        result["frames"],
        periods.join(", "),
        identity,
        theirs["sdo_seconds"]
    );

    // Closed while the tool runs: a socketcand client that does not read is disconnected
    // once its unread frames pass the server's write time-out (`can_hub::port`), which a
    // configuration on a loaded host outlasts. A new one watches the start.
    drop(tool);
    let started = std::time::Instant::now();
    let output = Command::new(root.join("target/debug/safety-config"))
        .args(["--bus", &format!("socketcand:{address}/can0"), "configure"])
        .arg(file)
        .arg("--start")
        .stdin(Stdio::null())
        .output()
        .context("running safety-config")?;
    let configured = started.elapsed().as_secs_f64();
    if !output.status.success() {
        bail!(
            "safety-config configure on the emulated network failed ({}):\n{}{}",
            output.status,
            String::from_utf8_lossy(&output.stdout),
            String::from_utf8_lossy(&output.stderr)
        );
    }
    let mut tool = network::connect_tool_at(address, Duration::from_secs(20))?;
    let mut seen = [false; 3];
    network::receive_until(&mut tool, Duration::from_secs(5), |frame| {
        match (frame.id().raw(), frame.data()) {
            (0x701, [0x05]) => seen[0] = true,
            (0x721, [0x05]) => seen[1] = true,
            (0x101, _) => seen[2] = true,
            _ => {}
        }
        seen == [true; 3]
    })?;
    if seen != [true; 3] {
        bail!(
            "after safety-config configure --start: node 1 Operational {}, node 33 Operational \
             {}, node 1's SRDO 1 (101h) on the bus {} (within 5 s)",
            seen[0],
            seen[1],
            seen[2]
        );
    }
    println!(
        "xtask: interop 7: safety-config configured, validated, stored and started nodes 1 and \
         33 from {} in {configured:.1} s of host time (its start included); both heartbeats \
         Operational and node 1's SRDO 1 on the bus",
        file.strip_prefix(root).unwrap_or(file).display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bench's section replaces its old self and nothing else; a writer of the rest of
    /// the file (`cargo xtask bench`) can take it over.
    #[test]
    fn the_bench_section_is_replaced_in_place_and_kept_by_other_writers() {
        let old = format!("# P\n\n## A\na\n{BENCH_HEADING}\nold\n## B\nb\n");
        let new = with_section(&old, &format!("{BENCH_HEADING}\nnew\n"));
        assert_eq!(
            new,
            format!("# P\n\n## A\na\n{BENCH_HEADING}\nnew\n## B\nb\n")
        );
        assert_eq!(
            kept_section(&new),
            Some(format!("{BENCH_HEADING}\nnew\n").as_str())
        );
        let last = with_section("# P\n", &format!("{BENCH_HEADING}\nx\n"));
        assert_eq!(last, format!("# P\n\n{BENCH_HEADING}\nx\n"));
        assert_eq!(
            with_section(&last, &format!("{BENCH_HEADING}\ny\n")),
            format!("# P\n\n{BENCH_HEADING}\ny\n")
        );
        assert_eq!(kept_section("# P\n"), None);
        // Another writer's generated block after the section is not the section's.
        let marked =
            format!("{BENCH_HEADING}\nold\n<!-- t:begin (generated) -->\n## T\n<!-- t:end -->\n");
        assert_eq!(
            with_section(&marked, &format!("{BENCH_HEADING}\nnew\n")),
            format!("{BENCH_HEADING}\nnew\n<!-- t:begin (generated) -->\n## T\n<!-- t:end -->\n")
        );
    }

    /// The target counts as met only when every round of the tool beat every round of
    /// python-canopen; a faster median over overlapping rounds is said to show nothing.
    #[test]
    fn the_speed_target_is_met_only_when_every_round_is_faster() {
        let round = |ms: u64| Round {
            configure: Duration::from_millis(ms),
            verify: Duration::ZERO,
            configure_transactions: 0,
            verify_transactions: 0,
        };
        let rounds = |list: &[u64]| list.iter().map(|ms| round(*ms)).collect::<Vec<_>>();
        let met = verdict(&rounds(&[100, 110, 120]), &rounds(&[200, 210, 230]));
        assert_eq!(
            met,
            "met: every round of the tool was faster than every round of python-canopen \
             (median 1.91 times as fast)"
        );
        let overlap = verdict(&rounds(&[100, 110, 250]), &rounds(&[200, 210, 230]));
        assert!(overlap.starts_with("not shown"), "{overlap}");
        let slower = verdict(&rounds(&[300, 310, 320]), &rounds(&[200, 210, 230]));
        assert!(slower.starts_with("NOT met"), "{slower}");
    }

    /// The bench's network files are valid and give each node every SRDO the firmware
    /// holds, no identifier used twice.
    #[test]
    fn the_bench_network_files_configure_every_srdo_of_the_device() {
        for nodes in 1..=BENCH_NODES.len() {
            let network = safety_config::network_file::parse(&bench_file(nodes), "bench").unwrap();
            let ids: Vec<u8> = network.nodes.iter().map(|node| node.id).collect();
            assert_eq!(ids, BENCH_NODES[..nodes]);
            let mut cob_ids = std::collections::BTreeSet::new();
            for node in &network.nodes {
                assert_eq!(node.srdos.len(), safety_device::SRDO_COUNT);
                for srdo in &node.srdos {
                    assert!(cob_ids.insert(srdo.settings.cob_id_1));
                    assert!(cob_ids.insert(srdo.settings.cob_id_2));
                }
            }
        }
    }
}
