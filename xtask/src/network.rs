//! The emulated safety network: the four sealed hardware images on the emulated STM32F405s of
//! one `emulate-network` (node 1, the emergency-stop input device and SRDO producer; node 33,
//! the safe output device and SRDO consumer; each as channel A and channel B, linked by their
//! USART3s), configured, read back, signed, validated, stored and started by the configuration
//! tool's library (`safety_config`, EN 50325-5 8.3.1) over the emulator's socketcand port, from
//! the network file [`network_file`] (written to `target/emulate/network.toml`, so that
//! `safety-config verify target/emulate/network.toml` can check a running network). The
//! emulator's control port speaks the hub's protocol (`can_hub::control`, `emulator::control`).
//!
//! With [`Protocol::Simplecan`] (`cargo xtask run --protocol simplecan`) the same four MCUs run
//! the SimpleCAN images (`images::Layer::HwSimpleCan`) and are configured from
//! `scenarios/networks/simplecan.toml`: node 1 the master and producer of SC-ID 30h, node 33
//! its consumer.
//!
//! Every child process is killed when the [`Network`] is dropped, whichever way the task
//! ends (error, panic, Ctrl-C: see [`crate::child`]).

use crate::child::Guarded;
use crate::images::{self, Layer};
use crate::toolchain;
use anyhow::{Context, Result, anyhow, bail};
use can_hub::tool::Control;
use emulation_wire::Status;
use safety_config::Transport;
use safety_config::client::Client;
use safety_config::network_file::NodeSpec;
use safety_config::procedure::{self, NodeResult, Operator};
use safety_config::socketcand::SocketcandClient;
use shared::canopen::nmt::{NmtCommand, NmtState};
use shared::safety::cause::Cause;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

/// The four emulated MCUs: (participant name, node-ID, channel).
pub const CHANNELS: [(&str, u8, &str); 4] = [
    ("node1a", 1, "a"),
    ("node1b", 1, "b"),
    ("node33a", 33, "a"),
    ("node33b", 33, "b"),
];

/// The transmit SRDO of node 1 that node 33 consumes: its two identifiers.
pub const PLAIN: u16 = 0x101;
/// The inverted half.
pub const INVERTED: u16 = 0x102;

/// The emulated network's timing: node 1 refreshes SRDO 1 every 100 ms; node 33 allows
/// 500 ms between pairs (SCT) and 100 ms between the halves of a pair (SRVT).
pub const REFRESH_MS: u64 = 100;
/// Node 33's safeguard cycle time for SRDO 1.
pub const SCT_MS: u64 = 500;
/// Node 33's SRVT for SRDO 1.
pub const SRVT_MS: u64 = 100;
/// The safety protocol the emulated network speaks between node 1 and node 33.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum Protocol {
    /// CANopen Safety: node 1's SRDO 1 on 101h/102h ([`network_file`]).
    #[default]
    CanopenSafety,
    /// SimpleCAN: node 1 the master and producer of SC-ID 30h, node 33 its consumer
    /// ([`SIMPLECAN_NETWORK_FILE`]), on the SimpleCAN images.
    Simplecan,
}

impl Protocol {
    /// The hardware images of this protocol (`cargo xtask flash`, the emulated network).
    pub fn hardware_layer(self) -> Layer {
        match self {
            Protocol::CanopenSafety => Layer::Hw,
            Protocol::Simplecan => Layer::HwSimpleCan,
        }
    }

    /// The network file the tool configures the nodes from.
    pub fn network_file(self) -> String {
        match self {
            Protocol::CanopenSafety => network_file(),
            Protocol::Simplecan => SIMPLECAN_NETWORK_FILE.to_owned(),
        }
    }

    /// What node 33 receives from node 1, in words.
    pub fn stream(self) -> &'static str {
        match self {
            Protocol::CanopenSafety => "node 1's SRDO 1 (101h/102h)",
            Protocol::Simplecan => "node 1's SimpleCAN SC-ID 30h (slot 0, master node 1)",
        }
    }
}

/// The SimpleCAN network file of the emulated network, as the repository holds it.
pub const SIMPLECAN_NETWORK_FILE: &str = include_str!("../../scenarios/networks/simplecan.toml");

/// The SC-ID node 1 produces (and, as the potential master, names in its syncs) and node 33
/// consumes in [`SIMPLECAN_NETWORK_FILE`].
pub const ESTOP_SC_ID: u8 = 0x30;

/// The emulated network's socketcand port (bus `can0`) when `CAN_HUB_PORT` does not name
/// another.
const DEFAULT_HUB_PORT: u16 = 29536;

/// The emulated network's socketcand port (bus `can0`): 127.0.0.1, port `CAN_HUB_PORT`
/// (default 29536, the hub's too), so that two emulated networks can run on one machine side
/// by side.
pub fn hub_tcp() -> String {
    format!("127.0.0.1:{}", hub_port())
}

/// The emulated network's control port: the port after [`hub_tcp`]'s.
fn hub_control() -> String {
    format!("127.0.0.1:{}", hub_port() + 1)
}

/// `CAN_HUB_PORT`, or the default; a value that is not a port below 65535 is not taken
/// silently for the default.
fn hub_port() -> u16 {
    match std::env::var("CAN_HUB_PORT") {
        Ok(value) => match value.parse::<u16>() {
            Ok(port) if port > 0 && port < u16::MAX => port,
            _ => {
                eprintln!(
                    "CAN_HUB_PORT={value:?} is not a port from 1 to 65534; using {DEFAULT_HUB_PORT}"
                );
                DEFAULT_HUB_PORT
            }
        },
        Err(_) => DEFAULT_HUB_PORT,
    }
}

/// How long one SDO request of the tool waits over the emulated bus, in host time. Four
/// emulated MCUs on two shared cores answer within milliseconds of virtual time, but a
/// heavily loaded host can hold virtual time back for longer than a timeout of one second
/// (`docs/emulation.md`). A timeout only decides how long a node that really does not answer
/// takes to be reported, so it is generous.
const SDO_TIMEOUT: Duration = Duration::from_millis(5000);

/// The network file of the emulated network: node 1's SRDO 1 transmits on 101h/102h every
/// [`REFRESH_MS`]; node 33's SRDO 1 consumes it with [`SCT_MS`] and [`SRVT_MS`]. The
/// identities are the device description's (`safety_device::config`: vendor ABCh,
/// product 304h, revision 1, serial number = node-ID).
pub fn network_file() -> String {
    format!(
        r#"# The emulated network of `cargo xtask run` (written by xtask from its constants).
[bus]
sdo_timeout_ms = {sdo}

[[node]]
id = 1
name = "emergency stop"
identity = {{ vendor = 0xABC, product = 0x304, revision = 1, serial = 1 }}

[[node.srdo]]
number = 1
direction = "transmit"
refresh_time_ms = {REFRESH_MS}
srvt_ms = 20
cob_ids = [0x{PLAIN:X}, 0x{INVERTED:X}]
mapping = ["input", "input_inverted"]

[[node]]
id = 33
name = "safe output"
identity = {{ vendor = 0xABC, product = 0x304, revision = 1, serial = 33 }}

[[node.srdo]]
number = 1
direction = "receive"
sct_ms = {SCT_MS}
srvt_ms = {SRVT_MS}
cob_ids = [0x{PLAIN:X}, 0x{INVERTED:X}]
mapping = ["output", "output_inverted"]
"#,
        sdo = SDO_TIMEOUT.as_millis()
    )
}

/// Connects the tool library's socketcand client to the emulated network, retrying for up to
/// `patience`.
pub fn connect_tool(patience: Duration) -> Result<Client<SocketcandClient>> {
    connect_tool_at(&hub_tcp(), patience)
}

/// Connects the tool library's socketcand client to the socketcand server at `address`
/// (bus `can0`: the hub, or `emulate-network --socketcand`), retrying for up to `patience`.
pub fn connect_tool_at(address: &str, patience: Duration) -> Result<Client<SocketcandClient>> {
    let give_up = std::time::Instant::now() + patience;
    loop {
        match SocketcandClient::connect(address, "can0") {
            Ok(transport) => return Ok(Client::new(transport, SDO_TIMEOUT)),
            Err(error) if std::time::Instant::now() >= give_up => {
                return Err(error).context(format!("the socketcand port {address}"));
            }
            Err(_) => std::thread::sleep(Duration::from_millis(50)),
        }
    }
}

/// Receives frames for up to `patience` until nodes 1 and 33 have each sent a heartbeat (or
/// boot-up message, CiA 301 7.2.8.3.2: 700h + node-ID) whose data `state` accepts; which of
/// the two did.
pub fn await_heartbeats<T: Transport>(
    tool: &mut Client<T>,
    patience: Duration,
    state: impl Fn(&[u8]) -> bool,
) -> Result<[bool; 2]> {
    let mut heard = [false; 2];
    receive_until(tool, patience, |frame| {
        match frame.id().raw() {
            0x701 if state(frame.data()) => heard[0] = true,
            0x721 if state(frame.data()) => heard[1] = true,
            _ => {}
        }
        heard == [true, true]
    })?;
    Ok(heard)
}

/// Receives frames for up to `patience` until `until` holds for one; whether it did.
pub fn receive_until<T: Transport>(
    tool: &mut Client<T>,
    patience: Duration,
    mut until: impl FnMut(&shared::CanFrame) -> bool,
) -> Result<bool> {
    let deadline = tool.transport.now() + patience;
    while let Some(frame) = tool.transport.receive(deadline)? {
        if until(&frame) {
            return Ok(true);
        }
    }
    Ok(false)
}

/// Tells the configuration steps on stderr, prefixed `xtask:`; never accepts a node whose
/// identity differs from the file.
struct Narrator;

impl Operator for Narrator {
    fn note(&mut self, line: &str) {
        eprintln!("xtask: {line}");
    }
    fn confirm_identity(&mut self, _node: &NodeSpec, _differences: &str) -> bool {
        false
    }
}

/// The running network.
pub struct Network {
    children: Vec<(String, Guarded)>,
    /// The configuration tool (the tool library over the socketcand port), while it is
    /// needed: see [`Network::tool`].
    tool: Option<Client<SocketcandClient>>,
    /// The emulated network's control port.
    pub control: Control,
    dir: PathBuf,
    /// What the nodes speak.
    pub protocol: Protocol,
    /// The image CRCs of channels A and B, as the build sealed them and the emulator read
    /// them.
    pub crcs: [u32; 2],
}

impl Drop for Network {
    fn drop(&mut self) {
        for (_, child) in &mut self.children {
            child.end();
        }
    }
}

/// Fails with a sentence when one of the network's TCP addresses is taken already:
/// otherwise the emulator would exit and the tool might talk to whatever listens there
/// (another engineer's emulated network, say).
fn ports_free() -> Result<()> {
    for address in [hub_tcp(), hub_control()] {
        if let Err(error) = std::net::TcpListener::bind(&address) {
            if error.kind() == std::io::ErrorKind::AddrInUse {
                bail!(
                    "{address} is in use: another emulated network (`cargo xtask run` or \
                     `cargo xtask e2e`) is probably running on this machine; end it, or wait \
                     until it has ended"
                );
            }
            bail!("cannot listen on {address}: {error}");
        }
    }
    Ok(())
}

/// Connects the configuration tool and the control port to the network's process just
/// started (`children[0]`, its errors in `dir/errors`), retrying for a few seconds; ends
/// every child and fails with a sentence naming `what` when it does not accept them or has
/// exited (another program may listen there: connected to it, the run would drive that).
fn connect(
    children: &mut [(String, Guarded)],
    dir: &Path,
    errors: &str,
    what: &str,
) -> Result<(Client<SocketcandClient>, Control)> {
    let (tool, control) = match (
        connect_tool(Duration::from_secs(5)),
        Control::connect(&hub_control(), Duration::from_secs(5)),
    ) {
        (Ok(tool), Ok(control)) => (tool, control),
        (tool, control) => {
            for (_, child) in children.iter_mut() {
                child.end();
            }
            let error = match (tool, control) {
                (Err(error), _) => format!("{error:#}"),
                (_, Err(error)) => error.to_string(),
                _ => String::new(),
            };
            bail!(
                "{what} did not accept connections on {} / {}: {error}",
                hub_tcp(),
                hub_control()
            );
        }
    };
    if let Some(status) = children[0].1.try_wait()? {
        let log = std::fs::read_to_string(dir.join(errors)).unwrap_or_default();
        let log = log.trim();
        let log = log.trim_start_matches("emulate-network: ");
        bail!("{what} exited at once ({status}): {log}");
    }
    Ok((tool, control))
}

/// The image CRC `emulate-network` reports for `image` in its output `log` (`emulate-network:
/// PATH: sealed image, CRC 1234ABCDh`), once it has written it.
fn reported_crc(log: &str, image: &Path) -> Option<u32> {
    let prefix = format!("emulate-network: {}: sealed image, CRC ", image.display());
    log.lines().find_map(|line| {
        let hex = line.strip_prefix(&prefix)?.strip_suffix('h')?;
        u32::from_str_radix(hex, 16).ok()
    })
}

/// `true` when every channel of `node` (1 or 33) is Operational and working.
pub fn working(latest: &HashMap<String, (f64, Status)>, node: u8) -> bool {
    CHANNELS
        .iter()
        .filter(|(_, id, _)| *id == node)
        .all(|(name, _, _)| {
            latest.get(*name).is_some_and(|(_, s)| {
                s.nmt_state() == Some(NmtState::Operational) && s.working && s.link_up
            })
        })
}

/// The output both channels of node 33 drive, when they agree.
pub fn output_33(latest: &HashMap<String, (f64, Status)>) -> Option<u8> {
    let a = latest.get("node33a")?.1.output;
    let b = latest.get("node33b")?.1.output;
    (a == b).then_some(a)
}

impl Network {
    /// Builds what is missing, starts the four MCUs speaking `protocol`, configures both nodes
    /// over the bus and starts them; returns once both nodes are Operational and node 33's
    /// output follows node 1's input. The MCUs run the sealed hardware images on
    /// `emulate-network`, serving socketcand on [`hub_tcp`] and its control port on the port
    /// after it. Refuses to run images whose CRC the emulator reads differently from what the
    /// build sealed.
    pub fn start_for(root: &Path, protocol: Protocol) -> Result<Network> {
        eprintln!(
            "xtask: [1/4] the compiler's target {} for the firmware (rustup; installed once), \
             and what the emulator's build needs",
            toolchain::TARGET
        );
        let cross = toolchain::ensure()?;
        toolchain::ensure_emulator_build_deps()?;
        let layer = protocol.hardware_layer();
        eprintln!("xtask: [2/4] building and sealing the hardware images ({layer:?})");
        let sealed = images::build_layer(root, &cross, layer)?;
        eprintln!(
            "xtask: [3/4] building emulate-network, the emulated STM32F405s on one CAN bus \
             (release; minutes the first time)"
        );
        let emulate = crate::emulate::build_emulate_network(root)?;
        eprintln!(
            "xtask: [4/4] starting emulate-network (nodes 1 and 33, channels A and B, the \
             shipped images unchanged), then configuring both nodes over the bus with the tool \
             library"
        );
        let dir = root.join("target/emulate");
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir)?;
        ports_free()?;
        let paths = ["a", "b"].map(|channel| images::image(&cross, root, layer, channel));
        let output = dir.join("emulate-network.log");
        let mut command = Command::new(emulate);
        command
            .args(&paths)
            .args(["--nodes", "1,33", "--inputs-closed"])
            .args(["--socketcand", &hub_tcp(), "--control", &hub_control()])
            .arg("--candump")
            .arg(dir.join("bus.log"))
            .arg("--pcap")
            .arg(dir.join("bus.pcap"))
            .stdin(Stdio::null())
            .stdout(std::fs::File::create(&output)?)
            .stderr(std::fs::File::create(dir.join("emulate-network.err"))?);
        let emulator = Guarded::spawn(&mut command).context("starting emulate-network")?;
        let mut children = vec![("emulate-network".to_string(), emulator)];
        let (tool, control) = connect(
            &mut children,
            &dir,
            "emulate-network.err",
            "emulate-network",
        )?;
        // It reports the CRCs it read before it listens.
        let log = std::fs::read_to_string(&output)?;
        for ((channel, path), crc) in ["A", "B"].iter().zip(&paths).zip(sealed) {
            match reported_crc(&log, path) {
                Some(read) if read == crc => eprintln!(
                    "xtask: channel {channel}: image CRC {crc:08X}h, as the build sealed it and \
                     the emulator read it"
                ),
                read => {
                    for (_, child) in &mut children {
                        child.end();
                    }
                    bail!(
                        "channel {channel}'s image {} was sealed with image CRC {crc:08X}h, but \
                         the emulator read {}: refused (was the image changed after the build?)",
                        path.display(),
                        read.map_or("no CRC".to_owned(), |read| format!("{read:08X}h"))
                    );
                }
            }
        }
        let mut network = Network {
            children,
            tool: Some(tool),
            control,
            dir,
            protocol,
            crcs: sealed,
        };
        if let Err(error) = network.configure() {
            let _ = network.save_logs();
            return Err(error.context(format!(
                "the emulated network did not come up (logs and traces in {})",
                network.dir.display()
            )));
        }
        Ok(network)
    }

    /// The configuration tool, connected to the socketcand port (again) if it is not.
    ///
    /// Between uses it is disconnected ([`Network::release_tool`]): a socketcand client that
    /// does not read lets the server's writes to it pile up until they block it (for its
    /// write time-out, then it drops the client), and nothing reads the tool's frames while a
    /// run or the end-to-end cases go on.
    pub fn tool(&mut self) -> Result<&mut Client<SocketcandClient>> {
        if self.tool.is_none() {
            self.tool = Some(connect_tool(Duration::from_secs(5))?);
        }
        self.tool
            .as_mut()
            .ok_or_else(|| anyhow!("the tool is not connected"))
    }

    /// Disconnects the configuration tool until [`Network::tool`] is called again.
    pub fn release_tool(&mut self) {
        self.tool = None;
    }

    /// Fails when the emulated network has ended (an MCU's fault or lockup ends
    /// `emulate-network`).
    pub fn check_alive(&mut self) -> Result<()> {
        for (name, child) in &mut self.children {
            if let Some(status) = child.try_wait()? {
                bail!(
                    "{name} ended ({status}): an MCU's HardFault, lockup or an access no model \
                     claims; its output is {}",
                    self.dir.join("emulate-network.log").display()
                );
            }
        }
        Ok(())
    }

    /// Waits up to `patience` of the network's time (the emulator's virtual clock, which
    /// follows the host clock and host load slows down) for the statuses to satisfy `until`;
    /// returns the network's time. A network that stops reporting altogether is given up on
    /// after ten times `patience` of host time, plus ten seconds.
    pub fn wait_for(
        &mut self,
        patience: Duration,
        mut until: impl FnMut(&HashMap<String, (f64, Status)>) -> bool,
    ) -> Result<Option<f64>> {
        let start = self.hub_time();
        let give_up = std::time::Instant::now() + patience * 10 + Duration::from_secs(10);
        loop {
            let slice = Duration::from_millis(200).min(patience);
            let found = self.control.wait_for(slice, &mut until)?;
            self.check_alive()?;
            if found.is_some() {
                return Ok(found);
            }
            let waited = self.hub_time() - start;
            if waited >= patience.as_secs_f64() || std::time::Instant::now() >= give_up {
                return Ok(None);
            }
        }
    }

    /// The latest hub time known from the control port (seconds): of the newest status or
    /// pace report.
    pub fn hub_time(&self) -> f64 {
        let pace = self
            .control
            .pace
            .as_ref()
            .map_or(0.0, |pace| pace.virtual_time.as_micros() as f64 / 1e6);
        self.control
            .latest
            .values()
            .map(|(t, _)| *t)
            .fold(pace, f64::max)
    }

    /// A control command that must be accepted; returns the hub time it took effect.
    pub fn command(&mut self, command: &str) -> Result<f64> {
        self.control
            .command(command)?
            .map_err(|why| anyhow!("the emulated network refused `{command}`: {why}"))
    }

    fn configure(&mut self) -> Result<()> {
        eprintln!("xtask: waiting for the boot-up messages of nodes 1 and 33");
        let booted = await_heartbeats(self.tool()?, Duration::from_secs(20), |_| true)?;
        self.check_alive()?;
        if booted != [true, true] {
            let silent: Vec<&str> = [("node 1", booted[0]), ("node 33", booted[1])]
                .into_iter()
                .filter(|(_, up)| !up)
                .map(|(node, _)| node)
                .collect();
            bail!(
                "no boot-up message from {} within 20 s (a node boots once both its channels \
                 have heard each other over the link: the channels' logs say why not)",
                silent.join(" and ")
            );
        }
        eprintln!(
            "xtask: configuring from {}: node 33 consumes {}",
            self.dir.join("network.toml").display(),
            self.protocol.stream()
        );
        let text = self.protocol.network_file();
        std::fs::write(self.dir.join("network.toml"), &text)?;
        let file = safety_config::network_file::parse(&text, "network.toml")?;
        let report = procedure::configure(self.tool()?, &file, false, &mut Narrator)?;
        let failures: Vec<String> = report
            .nodes
            .iter()
            .filter_map(|result| match result {
                NodeResult::Done(done) => {
                    eprintln!(
                        "xtask: node {}: {} SDO transfers, signatures {}",
                        done.node,
                        done.sdo_requests,
                        done.signatures_in_words()
                    );
                    None
                }
                NodeResult::Failed { error, .. } => Some(error.clone()),
            })
            .collect();
        if !failures.is_empty() {
            bail!("configuration failed:\n{}", failures.join("\n"));
        }
        // The start waits for three status reports from every channel after the store (a
        // report comes only from a channel whose loop runs).
        let stored = self.command("clear")?;
        let mut reports: HashMap<String, usize> = HashMap::new();
        let mut seen: HashMap<String, f64> = HashMap::new();
        let free = self.wait_for(Duration::from_secs(10), |latest| {
            for (name, _, _) in CHANNELS {
                if let Some((t, _)) = latest.get(name) {
                    if *t > stored && seen.get(name) != Some(t) {
                        seen.insert(name.to_string(), *t);
                        *reports.entry(name.to_string()).or_default() += 1;
                    }
                }
            }
            CHANNELS
                .iter()
                .all(|(name, _, _)| reports.get(*name).is_some_and(|count| *count >= 3))
        })?;
        if free.is_none() {
            bail!(
                "not every channel reported three times after storing:\n{}",
                self.table()
            );
        }
        self.start_nodes()
    }

    /// NMT start for every node, then waits until both are Operational and working and node
    /// 33's output is 1 (node 1's input released).
    pub fn start_nodes(&mut self) -> Result<()> {
        self.tool()?.nmt(NmtCommand::Start, 0)?;
        self.release_tool();
        let up = self.wait_for(Duration::from_secs(10), |latest| {
            working(latest, 1) && working(latest, 33) && output_33(latest) == Some(1)
        })?;
        if up.is_none() {
            bail!(
                "the nodes did not become Operational with node 33's output on within 10 s:\n{}",
                self.table()
            );
        }
        Ok(())
    }

    /// The latest status of every channel, as a table.
    pub fn table(&self) -> String {
        table(&self.control.latest)
    }

    /// The largest value of one of the channels' measured figures (`|s| s.stack_used`, the
    /// longest stall, link gap or loop wake-up) over every channel's latest report.
    pub fn worst(&self, figure: fn(&Status) -> u16) -> u16 {
        self.control
            .latest
            .values()
            .map(|(_, status)| figure(status))
            .max()
            .unwrap_or(0)
    }

    /// The channels' measured figures (the worst over every channel's latest report), as a
    /// sentence for the summary that says who measured them and how: the emulator measures
    /// the shipped images from outside in its lockstep virtual time, where no MCU stalls
    /// (`emulator::control`, `emulator::observed`).
    pub fn measured_summary(&self) -> String {
        let link_gap = self.worst(|s| s.longest_link_gap_ms);
        let busy = self.worst(|s| s.longest_busy_ms);
        let stack = self.worst(|s| s.stack_used);
        let reserve = crate::images::STACK_RESERVE;
        format!(
            "stall: none (the emulator runs every MCU in one lockstep virtual time; none \
             stops while the others run on); measured by the emulator from outside, in \
             virtual time: longest link gap {link_gap} ms (between the ends of two link \
             messages reaching a channel), longest wake-up {} (of a core, to its next \
             sleep, interrupts included), deepest stack {stack} bytes (reserve {reserve} \
             bytes; the stack pointer at every translated block's start)",
            whole_ms(busy)
        )
    }

    /// What the hub's pacing did (`can_hub::pace`), as a sentence for the summary: how much
    /// virtual time passed in how much host time, the longest hold and the grants' round trips.
    pub fn pace_summary(&self) -> String {
        let Some(pace) = &self.control.pace else {
            return "virtual time: no report from the hub yet".to_string();
        };
        let ms = |d: shared::Duration| d.as_micros() as f64 / 1000.0;
        let virtual_s = pace.virtual_time.as_micros() as f64 / 1e6;
        let host_s = virtual_s + ms(pace.behind) / 1000.0;
        format!(
            "virtual time: {virtual_s:.1} s in {host_s:.1} s of host time ({:.0} %), held at most \
             {:.0} ms at a time; grant round trips (host time) median {:.1} ms, 99 % within \
             {:.1} ms, longest {:.0} ms ({} grants)",
            100.0 * virtual_s / host_s.max(1e-9),
            ms(pace.longest_hold),
            ms(pace.round_trip_median),
            ms(pace.round_trip_p99),
            ms(pace.round_trip_max),
            pace.round_trips,
        )
    }

    /// Stops the emulated network, writes each MCU's decoded log (the emulator decodes them,
    /// each line after its MCU's name) into `target/emulate/<name>.log`, and returns the
    /// channel faults each log shows.
    pub fn stop(mut self) -> Result<Vec<(String, Vec<String>)>> {
        self.save_logs()
    }

    fn save_logs(&mut self) -> Result<Vec<(String, Vec<String>)>> {
        let history: String = self
            .control
            .history
            .iter()
            .map(|(name, t, status)| can_hub::control::status_line(name, *t, status) + "\n")
            .collect();
        std::fs::write(self.dir.join("status.log"), history)?;
        for (_, child) in &mut self.children {
            child.end();
        }
        let output = std::fs::read_to_string(self.dir.join("emulate-network.log"))?;
        let mut faults = Vec::new();
        for (name, _, _) in CHANNELS {
            let decoded: String = output
                .lines()
                .filter_map(|line| {
                    let (mcu, rest) = line.split_once(' ')?;
                    (mcu == name).then(|| rest.trim_start().to_owned() + "\n")
                })
                .collect();
            std::fs::write(self.dir.join(format!("{name}.log")), &decoded)?;
            let lines = decoded
                .lines()
                .filter(|line| line.contains("Fault(") || line.contains("SafeState("))
                .map(|line| line.trim().to_string())
                .collect();
            faults.push((name.to_string(), lines));
        }
        Ok(faults)
    }

    /// Where the traces and logs are.
    pub fn dir(&self) -> &Path {
        &self.dir
    }
}

/// A cause code as words ([`Cause::describe`], the one table of them).
pub fn cause(code: u8) -> &'static str {
    Cause::describe_code(code)
}

/// A status's NMT state as words.
fn nmt(status: &Status) -> &'static str {
    status.nmt_state().map_or("?", NmtState::describe)
}

/// The statuses as a table.
pub fn table(latest: &HashMap<String, (f64, Status)>) -> String {
    let mut out = String::from(
        "node ch  NMT              state    link  input output  SRDOs sent  validated  last cause\n",
    );
    for (name, node, channel) in CHANNELS {
        let Some((_, s)) = latest.get(name) else {
            out.push_str(&format!(
                "{node:>4} {}   (no report yet)\n",
                channel.to_uppercase()
            ));
            continue;
        };
        out.push_str(&format!(
            "{node:>4} {}   {:<16} {:<8} {:<5} {:>5} {:>6} {:>11} {:>10}  {:02X}h {}\n",
            channel.to_uppercase(),
            nmt(s),
            if s.working { "working" } else { "SAFE" },
            match (s.cause, s.link_up) {
                (0x10..=0x14, _) => "FAULT",
                (_, true) => "up",
                (_, false) => "-",
            },
            s.input,
            s.output,
            s.sent,
            s.validated,
            s.cause,
            cause(s.cause),
        ));
    }
    out
}

/// A status line's whole milliseconds in words: `0` is "under 1 ms" (the line rounds down).
fn whole_ms(ms: u16) -> String {
    if ms == 0 {
        "under 1 ms".to_owned()
    } else {
        format!("{ms} ms")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A status line's figure rounds down to whole milliseconds: 0 is a time under 1 ms, not
    /// none.
    #[test]
    fn a_figure_of_0_ms_reads_as_under_1_ms() {
        assert_eq!(whole_ms(0), "under 1 ms");
        assert_eq!(whole_ms(12), "12 ms");
    }

    /// The image CRC is read from the emulator's own line for that image and no other: a
    /// line for another path, or one that is not a CRC, gives none (and the run refuses).
    #[test]
    fn the_emulators_image_crc_is_read_from_its_line_for_that_image() {
        let log = "emulate-network: /t/channel-a: sealed image, CRC 1234ABCDh\n\
                   emulate-network: /t/channel-b: sealed image, CRC 0BADF00Dh\n\
                   emulate-network: /t/channel-c: sealed image, CRC nonsenseh\n";
        assert_eq!(
            reported_crc(log, Path::new("/t/channel-a")),
            Some(0x1234_ABCD)
        );
        assert_eq!(
            reported_crc(log, Path::new("/t/channel-b")),
            Some(0x0BAD_F00D)
        );
        assert_eq!(reported_crc(log, Path::new("/t/channel-c")), None);
        assert_eq!(reported_crc(log, Path::new("/t/channel")), None);
    }

    /// The SimpleCAN network file of `cargo xtask run --protocol simplecan` parses, takes
    /// xtask's SDO time-out, and has node 1 as the only potential master, producing 30h,
    /// and node 33 consuming it (what the run's ending checks).
    #[test]
    fn the_simplecan_network_file_is_node_1_mastering_and_producing_30h_for_node_33() {
        let file =
            safety_config::network_file::parse(SIMPLECAN_NETWORK_FILE, "simplecan.toml").unwrap();
        assert_eq!(file.sdo_timeout, SDO_TIMEOUT);
        let simplecan = file.simplecan.expect("a SimpleCAN part");
        let node_1 = &simplecan.nodes[&1];
        assert!(node_1.potential_master);
        assert_eq!(node_1.lowest_produced(), Some(ESTOP_SC_ID));
        let node_33 = &simplecan.nodes[&33];
        assert!(!node_33.potential_master);
        assert_eq!(
            node_33
                .consumed
                .iter()
                .map(|consumed| consumed.sc_id)
                .collect::<Vec<_>>(),
            [ESTOP_SC_ID]
        );
    }
}
