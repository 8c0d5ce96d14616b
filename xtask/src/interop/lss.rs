//! LSS (CiA 305) in `cargo xtask interop`: python-canopen's `LssMaster` configures an
//! unconfigured node of the shipped images on the emulated network (`--only lss`), and the
//! tool's and python-canopen's fastscan are timed against the bus time of the frames they
//! need (`--only lss-bench`).
//!
//! The benchmark's nodes are host-simulated, so that 8 of them run in simulated time for the
//! tool: whole devices of the protocol core with the LSS slave enabled (`shared::canopen::lss`,
//! the code the images carry), unconfigured, on the host simulation's bus model
//! (`system_tests::network::Network::unconfigured_lss`): behind `socketcand_sim --lss N` in
//! real time for python-canopen, and in simulated time for the tool.

use super::{free_port, load_average, script_json};
use crate::child::Guarded;
use anyhow::{Context, Result, bail};
use safety_config::lss::{LssMaster, parts};
use safety_config::socketcand::SocketcandClient;
use shared::canopen::NodeId;
use shared::canopen::lss::BitRate;
use shared::{CanFrame, CanId};
use std::path::Path;
use std::process::Command;
use std::time::Duration;
use system_tests::network::Network;
use system_tests::tool_bus::SimulatedBus;

/// The bus's bit rate, the host simulation's (`socketcand_sim`): the device's.
const BIT_RATE: u32 = safety_device::BIT_RATE;

/// The bit rate python-canopen switches the shipped images' node to (CiA 305 configure and
/// activate bit timing), per protocol: not the device's start-up rate, so that a node that
/// did not switch its controller hears nothing on the emulated bus afterwards; for SimpleCAN
/// one of its two rates (`safety_device::SIMPLECAN_LSS_BIT_RATES`).
fn switched_to(protocol: crate::network::Protocol) -> BitRate {
    match protocol {
        crate::network::Protocol::CanopenSafety => BitRate::Kbit250,
        crate::network::Protocol::Simplecan => BitRate::Kbit1000,
    }
}

/// Each node is given its serial number plus this as its node-ID.
const OFFSET: u8 = 10;

/// How long both masters wait for an LSS answer: the tool's default (`--lss-timeout-ms`).
/// python-canopen's own default (`LssMaster.RESPONSE_TIMEOUT`) is five times as long; with it
/// the same scan takes five times as long, and nothing else changes.
const TIMEOUT: Duration = Duration::from_millis(100);

/// A shorter answer window the tool is timed with as well (`--lss-timeout-ms 10`): the
/// simulated nodes answer within a frame's time; a real node may need milliseconds.
const SHORT_TIMEOUT: Duration = Duration::from_millis(10);

/// The heading of the generated block in docs/tool.md.
const BLOCK: &str = "lss-bench";

/// The identity of simulated node `serial`: the device description's (`safety_device::config`)
/// with `serial` as its serial number.
fn identity(serial: u8) -> [u32; 4] {
    // Checked when compiled: node-ID 1 is valid; the identity but for its serial number does
    // not depend on the node-ID.
    const DESCRIBED: NodeId = match NodeId::new(1) {
        Ok(id) => id,
        Err(_) => panic!("node-ID 1 is valid"),
    };
    let [vendor, product, revision, _] = safety_device::config(DESCRIBED, "").identity;
    [vendor, product, revision, u32::from(serial)]
}

/// A network file that gives nodes 1 to `count` (by serial number) the node-ID serial +
/// [`OFFSET`], each by its whole identity.
fn network_file(count: u8) -> Result<safety_config::network_file::Network> {
    let mut text = String::new();
    for serial in 1..=count {
        let [vendor, product, revision, serial_number] = identity(serial);
        text.push_str(&format!(
            "[[node]]\nid = {}\nidentity = {{ vendor = {vendor}, product = {product}, revision = {revision}, serial = {serial_number} }}\n",
            serial + OFFSET
        ));
    }
    Ok(safety_config::network_file::parse(
        &text,
        "the LSS case's network file",
    )?)
}

/// `socketcand_sim --lss count` on a free port, listening: the guard and its address.
fn start_simulation(root: &Path, count: u8) -> Result<(Guarded, String)> {
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
    let server = Guarded::spawn(
        Command::new(root.join("target/debug/socketcand_sim"))
            .arg(port.to_string())
            .args(["--lss", &count.to_string()]),
    )
    .context("starting socketcand_sim --lss")?;
    let give_up = std::time::Instant::now() + Duration::from_secs(20);
    while SocketcandClient::connect(&address, "can0").is_err() {
        if std::time::Instant::now() >= give_up {
            bail!("socketcand_sim did not listen on {address} within 20 s");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    Ok((server, address))
}

/// `xtask/interop/python_canopen_lss.py` against the server at `address`.
fn python_canopen(
    root: &Path,
    python: &Path,
    address: &str,
    store: bool,
    check: bool,
    bit_rate: Option<BitRate>,
) -> Result<serde_json::Value> {
    let (host, port) = address.split_once(':').context("the server's address")?;
    let mut command = Command::new(python);
    command
        .arg(root.join("xtask/interop/python_canopen_lss.py"))
        .args([host, port, &OFFSET.to_string()])
        .arg(TIMEOUT.as_secs_f64().to_string())
        .arg(if store { "1" } else { "0" })
        .arg(if check { "1" } else { "0" });
    if let Some(rate) = bit_rate {
        command.arg(rate.index().to_string());
    }
    script_json(&mut command)
}

/// A frame of the script's record: (time stamp in seconds, identifier, data in hex).
fn recorded(entry: &serde_json::Value) -> Option<(f64, CanFrame)> {
    let stamp = entry[0].as_f64()?;
    let id = u16::try_from(entry[1].as_u64()?).ok()?;
    let hex = entry[2].as_str()?;
    let data: Vec<u8> = (0..hex.len() / 2)
        .map(|at| u8::from_str_radix(hex.get(2 * at..2 * at + 2)?, 16).ok())
        .collect::<Option<_>>()?;
    let frame = CanFrame::new(CanId::new(id).ok()?, &data).ok()?;
    Some((stamp, frame))
}

/// `cargo xtask interop --only lss`: python-canopen's `LssMaster` finds the one unconfigured
/// node by fast scan, gives it node-ID 11, has 800 kbit/s refused, configures
/// [`switched_to`], has it store both and activates the bit rate; the emulated bus switches
/// with the master, and the node boots on 11, answers python-canopen's SDO upload of its
/// identity there, and boots on 11 again after an NMT reset node, at the stored rate; the
/// tool's LSS master then selects it by identity and inquires node-ID 11 active.
/// The node is the shipped hardware images (channels A and B) on the emulated STM32F405s,
/// their node-ID switches all open (`emulate-network --nodes 0 --socketcand`): channel A
/// answers, channel B checks each answer against its own (`dual_channel::lss`), and a
/// difference would put the node in its safe state, which the check would see as a missing
/// answer or boot-up.
pub fn check(root: &Path, python: &Path) -> Result<()> {
    for protocol in [
        crate::network::Protocol::CanopenSafety,
        crate::network::Protocol::Simplecan,
    ] {
        check_protocol(root, python, protocol)?;
    }
    Ok(())
}

/// [`check`] on the shipped images of `protocol`.
fn check_protocol(root: &Path, python: &Path, protocol: crate::network::Protocol) -> Result<()> {
    crate::step(&format!(
        "interop 6: python-canopen's LSS master (fast scan, configure node-ID and bit timing, \
         store, activate bit timing) on the shipped {protocol:?} images of an unconfigured node \
         (switches open) on the emulated network"
    ));
    let name = format!("lss-{protocol:?}");
    let mut served = super::ShippedNetwork::serve(root, protocol, &name, &["--nodes", "0"])?;
    let give_up = std::time::Instant::now() + Duration::from_secs(60);
    while SocketcandClient::connect(&served.address, "can0").is_err() {
        if std::time::Instant::now() >= give_up {
            served.emulator.end();
            bail!(
                "emulate-network did not listen on {} within 60 s",
                served.address
            );
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let switched = switched_to(protocol);
    let result = check_at(root, python, &served.address, switched);
    served.emulator.end();
    let log = served.log;
    result
        .and_then(|()| {
            // The bus model switched with the master (emulator::network, "Bit rate"): the
            // node's answers after it prove that both channels' controllers switched too.
            let bit_rate = switched.bits_per_second().unwrap_or(0);
            let output = std::fs::read_to_string(&log)?;
            if !output.contains(&format!("the bus runs at {bit_rate} bit/s")) {
                bail!("the emulated bus never switched to {bit_rate} bit/s");
            }
            Ok(())
        })
        .with_context(|| format!("the emulator's output is in {}", log.display()))
}

/// [`check`]'s steps against the server at `address`.
fn check_at(root: &Path, python: &Path, address: &str, switched: BitRate) -> Result<()> {
    let result = python_canopen(root, python, address, true, true, Some(switched))?;
    let serial = 1u8;
    let node_id = serial + OFFSET;
    let found: Vec<(Vec<u64>, u64)> = result["found"]
        .as_array()
        .context("the script's nodes found")?
        .iter()
        .map(|entry| {
            let identity = entry["identity"]
                .as_array()
                .map(|parts| parts.iter().filter_map(serde_json::Value::as_u64).collect())
                .unwrap_or_default();
            (identity, entry["node_id"].as_u64().unwrap_or(0))
        })
        .collect();
    let wanted: Vec<u64> = identity(serial)
        .iter()
        .map(|&part| u64::from(part))
        .collect();
    if found != [(wanted.clone(), u64::from(node_id))] {
        bail!(
            "python-canopen's fast scan found {found:?}, not the one node {wanted:X?} given node-ID {node_id}"
        );
    }
    // CiA 305 Fig. 34: a rate the device cannot make is refused with error code 1.
    if result["refused_800"]
        .as_str()
        .is_none_or(|error| !error.ends_with(": 1"))
    {
        bail!(
            "python-canopen's configure bit timing to 800 kbit/s was not refused with error \
             code 1: {}",
            result["refused_800"]
        );
    }
    if let Some(failures) = result["failures"].as_array().filter(|f| !f.is_empty()) {
        bail!("python-canopen's check after the scan: {failures:?}");
    }
    let read: Vec<u64> = result["checked"][0]["identity"]
        .as_array()
        .map(|parts| parts.iter().filter_map(serde_json::Value::as_u64).collect())
        .unwrap_or_default();
    if read != wanted {
        bail!("python-canopen read 1018h of node {node_id} as {read:X?}, not {wanted:X?}");
    }
    let frames: Vec<(f64, CanFrame)> = result["frames"]
        .as_array()
        .context("the recorded frames")?
        .iter()
        .filter_map(recorded)
        .collect();
    // Channel B checks every answer of channel A's against its own: a difference would be
    // the safe state, which an EMCY says (FF02h, the cause in byte 4).
    if let Some((_, emcy)) = frames
        .iter()
        .find(|(_, frame)| (0x081..=0x0FF).contains(&frame.id().raw()))
    {
        bail!(
            "the node sent an EMCY during the LSS configuration ({:03X}h {:02X?}): {}",
            emcy.id().raw(),
            emcy.data(),
            emcy.data().get(4).map_or("no cause byte", |&code| {
                shared::safety::cause::Cause::describe_code(code)
            })
        );
    }
    let boot_ups = frames
        .iter()
        .filter(|(_, frame)| frame.id().raw() == 0x700 + u16::from(node_id) && frame.data() == [0])
        .count();
    if boot_ups != 2 {
        bail!(
            "node {node_id} booted {boot_ups} times on its new node-ID, not twice (after the switch to LSS waiting, after NMT reset node)"
        );
    }
    let stored = frames.iter().any(|(_, frame)| {
        frame.id() == shared::canopen::lss::SLAVE_TO_MASTER
            && frame.data()
                == [
                    shared::canopen::lss::specifier::STORE_CONFIGURATION,
                    0,
                    0,
                    0,
                    0,
                    0,
                    0,
                    0,
                ]
    });
    if !stored {
        bail!(
            "node {node_id} did not answer python-canopen's store configuration with error code 0"
        );
    }
    let transport = SocketcandClient::connect(address, "can0").context("the tool's connection")?;
    let mut master = LssMaster::new(transport, TIMEOUT);
    let target = safety_config::lss::identity(identity(serial));
    master.select(target)?;
    let active = master.inquire_node_id(safety_config::lss::Target::Node(target));
    master.switch_global(false)?;
    if active? != Some(node_id) {
        bail!("the tool's LSS inquiry of {target}: not node-ID {node_id} active");
    }
    let requests = frames
        .iter()
        .filter(|(_, frame)| frame.id() == shared::canopen::lss::MASTER_TO_SLAVE)
        .count();
    println!(
        "xtask: interop 6: python-canopen's LssMaster found the unconfigured node {target} by fast scan ({requests} LSS requests), gave it node-ID {node_id}, had 800 kbit/s refused (error code 1), configured {} bit/s, had it store both (17h answered with error code 0) and activated the bit rate; on the bus at the new rate it booted on {node_id}, answered python-canopen's upload of 1018h there, booted on {node_id} again after NMT reset node (at the stored rate), and the tool's LSS inquiry reads node-ID {node_id} active",
        switched.bits_per_second().unwrap_or(0)
    );
    Ok(())
}

/// One master's fastscan of `nodes` unconfigured nodes, in bus time.
#[derive(Clone, Debug)]
struct Run {
    /// Nodes given a node-ID.
    assigned: usize,
    /// LSS requests on the bus.
    requests: usize,
    /// LSS answers on the bus (each node's own counted).
    answers: usize,
    /// Boot-up messages.
    boot_ups: usize,
    /// Other frames on the bus meanwhile (the configured nodes' heartbeats).
    other: usize,
    /// The bus time of the LSS frames and boot-ups, back to back.
    floor: Duration,
    /// From the start of the first request to the end (the tool returned; python-canopen's
    /// `fast_scan` said no node is left).
    taken: Duration,
    /// How long the master waited for an answer.
    timeout: Duration,
    /// The bus time of the last request (the one nobody answers; it is on the bus while the
    /// master waits).
    last_request: Duration,
}

impl Run {
    /// [`Run::taken`] over [`Run::floor`].
    fn ratio(&self) -> f64 {
        self.taken.as_secs_f64() / self.floor.as_secs_f64()
    }

    /// The same without the final wait: the wait for an answer to the last request, less
    /// that request's own bus time.
    fn ratio_without_the_last_wait(&self) -> f64 {
        let wait = self.timeout.saturating_sub(self.last_request);
        self.taken.saturating_sub(wait).as_secs_f64() / self.floor.as_secs_f64()
    }
}

impl Run {
    /// Counts `frames` (bus time stamps at the end of each) of a run that took `taken`.
    fn of(
        frames: impl Iterator<Item = CanFrame>,
        taken: Duration,
        timeout: Duration,
        assigned: usize,
    ) -> Run {
        let mut run = Run {
            assigned,
            requests: 0,
            answers: 0,
            boot_ups: 0,
            other: 0,
            floor: Duration::ZERO,
            taken,
            timeout,
            last_request: Duration::ZERO,
        };
        for frame in frames {
            let id = frame.id();
            let needed = if id == shared::canopen::lss::MASTER_TO_SLAVE {
                run.requests += 1;
                run.last_request = frame_time(&frame);
                true
            } else if id == shared::canopen::lss::SLAVE_TO_MASTER {
                run.answers += 1;
                true
            } else if (0x701..=0x77F).contains(&id.raw()) && frame.data() == [0] {
                run.boot_ups += 1;
                true
            } else {
                run.other += 1;
                false
            };
            if needed {
                run.floor += frame_time(&frame);
            }
        }
        run
    }
}

/// How long `frame` occupies the bus at [`BIT_RATE`] (stuff bits and intermission included).
fn frame_time(frame: &CanFrame) -> Duration {
    Duration::from_micros(can_hub::bus::frame_time(frame, BIT_RATE).as_micros())
}

/// The tool's `lss fastscan FILE --store` of `count` unconfigured nodes in simulated time,
/// waiting `timeout` for an answer.
fn tool_run(count: u8, timeout: Duration) -> Result<Run> {
    let file = network_file(count)?;
    let mut net = Network::unconfigured_lss(BIT_RATE, count);
    net.run_for(shared::Duration::from_millis(50));
    let (start, from) = (net.now, net.trace.len());
    let report =
        LssMaster::new(SimulatedBus::new(&mut net), timeout).fastscan_assign(&file, true)?;
    let taken = Duration::from_micros(net.now.as_micros() - start.as_micros());
    // `Network::unconfigured_lss` gives the devices serial numbers 1 to `count`, in order.
    for (device, serial) in net.devices.iter().zip(1..=count) {
        let given = device.node.configured_node_id().map(|id| id.raw());
        if given != Some(serial + OFFSET) {
            bail!("the tool's fastscan left node {serial} with node-ID {given:?}");
        }
    }
    let frames = net.trace[from..].iter().map(|(_, frame)| *frame);
    let run = Run::of(frames, taken, timeout, report.assigned.len());
    if report
        .assigned
        .iter()
        .map(|a| parts(a.identity)[3])
        .ne(1..=u32::from(count))
    {
        bail!("the tool's fastscan assigned {:?}", report.assigned);
    }
    Ok(run)
}

/// python-canopen's fast scan of `count` unconfigured nodes behind `socketcand_sim`, on the
/// simulated bus's time (the server's time stamps; the simulation runs in real time there).
fn python_run(root: &Path, python: &Path, count: u8) -> Result<Run> {
    let (_server, address) = start_simulation(root, count)?;
    let result = python_canopen(root, python, &address, true, false, None)?;
    let frames: Vec<(f64, CanFrame)> = result["frames"]
        .as_array()
        .context("the recorded frames")?
        .iter()
        .filter_map(recorded)
        .collect();
    let (Some(first), Some(end)) = (result["first_request"].as_f64(), result["end"].as_f64())
    else {
        bail!("python-canopen's run has no first request or end mark: {result}");
    };
    // Stamps are taken at the end of each frame: both ends moved to the frames' starts.
    let start_of = |stamp: f64| {
        frames
            .iter()
            .find(|(at, frame)| *at == stamp && frame.id() == shared::canopen::lss::MASTER_TO_SLAVE)
            .map_or(stamp, |(_, frame)| stamp - frame_time(frame).as_secs_f64())
    };
    let (start, stop) = (start_of(first), start_of(end));
    let inside = frames
        .iter()
        .filter(|(at, _)| *at > start && *at < end)
        .map(|(_, frame)| *frame);
    let assigned = result["found"].as_array().map_or(0, Vec::len);
    if assigned != usize::from(count) {
        bail!(
            "python-canopen's fast scan configured {assigned} of {count} nodes: {}",
            result["found"]
        );
    }
    Ok(Run::of(
        inside,
        Duration::from_secs_f64(stop - start),
        TIMEOUT,
        assigned,
    ))
}

/// A duration in milliseconds for the table.
fn ms(duration: Duration) -> String {
    format!("{:.1}", duration.as_secs_f64() * 1000.0)
}

/// One table row.
fn row(who: &str, nodes: u8, run: &Run) -> String {
    format!(
        "| {who} | {} | {nodes} | {} | {} + {} + {} | {} | {} | {} | {:.2} | {:.2} |\n",
        run.timeout.as_millis(),
        run.assigned,
        run.requests,
        run.answers,
        run.boot_ups,
        run.other,
        ms(run.floor),
        ms(run.taken),
        run.ratio(),
        run.ratio_without_the_last_wait(),
    )
}

/// What the goal's first half says of `run`.
fn judged(run: &Run) -> String {
    let within = |ratio: f64| {
        if ratio <= 1.25 {
            "within"
        } else {
            "NOT within"
        }
    };
    format!(
        "{} 1.25 times the floor with the final wait ({:.2}), {} without it ({:.2})",
        within(run.ratio()),
        run.ratio(),
        within(run.ratio_without_the_last_wait()),
        run.ratio_without_the_last_wait()
    )
}

/// `cargo xtask interop --only lss-bench`: the tool and python-canopen each find and
/// configure 1 and 8 unconfigured nodes; bus time against the floor, written into
/// docs/tool.md.
pub fn bench(root: &Path, python: &Path) -> Result<()> {
    crate::step(
        "interop lss-bench: fastscan of 1 and 8 unconfigured nodes, the tool and python-canopen, in bus time",
    );
    let mut rows = String::new();
    let mut verdicts = String::new();
    for count in [1u8, 8] {
        let tool = tool_run(count, TIMEOUT)?;
        println!("xtask: lss-bench: the tool, {count} node(s): {tool:?}");
        let short = tool_run(count, SHORT_TIMEOUT)?;
        println!("xtask: lss-bench: the tool, {count} node(s), {SHORT_TIMEOUT:?}: {short:?}");
        let theirs = python_run(root, python, count)?;
        println!("xtask: lss-bench: python-canopen, {count} node(s): {theirs:?}");
        rows.push_str(&row("safety-config", count, &tool));
        rows.push_str(&row("safety-config", count, &short));
        rows.push_str(&row("python-canopen 2.4.1", count, &theirs));
        let faster = theirs.taken.as_secs_f64() / tool.taken.as_secs_f64();
        verdicts.push_str(&format!(
            " {count} node(s): the tool {} at {} ms, {} at {} ms; {faster:.0} times as fast as \
             python-canopen at {} ms{}.",
            judged(&tool),
            TIMEOUT.as_millis(),
            judged(&short),
            SHORT_TIMEOUT.as_millis(),
            TIMEOUT.as_millis(),
            if faster > 1.0 { "" } else { " (NOT faster)" },
        ));
    }
    let section = format!(
        "<!-- {BLOCK}:begin (generated by `cargo xtask interop --only lss-bench`; do not edit) -->\n\
         ### Fastscan timed in bus time\n\n\
         Each master finds N unconfigured nodes and gives each the node-ID of the network file \
         (serial number + {OFFSET}), stored: `safety-config`'s `lss fastscan FILE --store` \
         (`LssMaster::fastscan_assign`) on the host simulation in simulated time, and \
         python-canopen 2.4.1's `LssMaster` (`fast_scan`, `configure_node_id`, \
         `store_configuration`, `send_switch_state_global`, until `fast_scan` finds none; \
         `xtask/interop/python_canopen_lss.py`) behind `socketcand_sim --lss N`, where the \
         simulation runs in real time and the server's time stamps are the bus's. The nodes are \
         host-simulated devices with the LSS slave (the protocol core the images carry), on the \
         bus model at {} kbit/s; both masters wait {} ms for an answer (the tool's default; \
         python-canopen's own is 500 ms), the tool also {} ms (`--lss-timeout-ms`); the \
         simulated nodes answer at once, python-canopen sleeps 10 ms after each fast-scan \
         request. The tool selects the nodes the file names by their whole identity and \
         scans no bit (`tool/src/lss.rs`); python-canopen scans all 128 bits of each node. *Floor*: the bus time of the LSS requests, the \
         nodes' answers and boot-up messages of the run, back to back (stuff bits and \
         intermission included); *taken*: from the start of the first request to the end \
         (the tool returned; python-canopen's `fast_scan` found no node). A master cannot \
         know that no unconfigured node is left but by one request nobody answers: the last \
         column takes that one wait off (less the bus time of that request, which is on the bus \
         while the master waits).\n\n\
         | master | answer window (ms) | nodes | configured | frames: requests + answers + boot-ups | other frames (heartbeats) | floor (ms) | taken (ms) | taken / floor | without the final wait |\n\
         |---|---:|---:|---:|---|---:|---:|---:|---:|---:|\n\
         {rows}\n\
         Goal: at most 1.25 times the floor, and faster than python-canopen.{verdicts} \
         python-canopen's times follow the host's ({}).\n\
         <!-- {BLOCK}:end -->\n",
        BIT_RATE / 1000,
        TIMEOUT.as_millis(),
        SHORT_TIMEOUT.as_millis(),
        load_average(),
    );
    let docs = root.join("docs/tool.md");
    let old = std::fs::read_to_string(&docs)?;
    std::fs::write(&docs, with_block(&old, &section)?)?;
    println!("{section}");
    Ok(())
}

/// `document` with its generated block replaced by `block`; an error when it has no block.
fn with_block(document: &str, block: &str) -> Result<String> {
    let begin = format!("<!-- {BLOCK}:begin");
    let end = format!("<!-- {BLOCK}:end -->\n");
    let (Some(start), Some(stop)) = (document.find(&begin), document.find(&end)) else {
        bail!("docs/tool.md has no `{begin} ... {end}` block for the LSS bench");
    };
    Ok(format!(
        "{}{block}{}",
        &document[..start],
        &document[stop + end.len()..]
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bench's block replaces its old self and nothing else.
    #[test]
    fn the_lss_bench_block_is_replaced_in_place() {
        let old = "# T\n<!-- lss-bench:begin x -->\nold\n<!-- lss-bench:end -->\n## N\n";
        let new = with_block(
            old,
            "<!-- lss-bench:begin y -->\nnew\n<!-- lss-bench:end -->\n",
        );
        assert_eq!(
            new.unwrap(),
            "# T\n<!-- lss-bench:begin y -->\nnew\n<!-- lss-bench:end -->\n## N\n"
        );
        assert!(with_block("# T\n", "x").is_err());
    }

    /// Each frame is counted once, in its kind; only the LSS frames and boot-ups make the
    /// floor.
    #[test]
    fn cia305_the_floor_counts_the_lss_frames_and_boot_ups() {
        let frame = |id: u16, data: &[u8]| CanFrame::new(CanId::new(id).unwrap(), data).unwrap();
        let frames = [
            frame(0x7E5, &[0x51, 0, 0, 0, 0, 0x80, 0, 0]),
            frame(0x7E4, &[0x4F, 0, 0, 0, 0, 0, 0, 0]),
            frame(0x70B, &[0]),
            frame(0x70B, &[0x7F]),
        ];
        let run = Run::of(frames.into_iter(), Duration::from_millis(1), TIMEOUT, 1);
        assert_eq!(
            (run.requests, run.answers, run.boot_ups, run.other),
            (1, 1, 1, 1)
        );
        let floor: Duration = frames[..3].iter().map(frame_time).sum();
        assert_eq!(run.floor, floor);
    }
}
