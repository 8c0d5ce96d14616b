//! `safety-config`: configure, verify and inspect CANopen Safety nodes (EN 50325-5) from a
//! network file, over socketcand, an SLCAN adapter or SocketCAN.

mod subcommand;

use clap::{Parser, Subcommand, ValueEnum};
use safety_config::access::{SECRET_VARIABLE, Secret, SecretSource};
use safety_config::calc::bus::Stream;
use safety_config::calc::sfrt::DeviceTiming;
use safety_config::client::Client;
use safety_config::network_file::{self, NodeSpec};
use safety_config::procedure::{self, Operator};
use safety_config::{ToolError, Transport};
use shared::canopen::od::Address;
use std::io::{IsTerminal, Write};
use std::process::ExitCode;
use std::time::Duration;
use subcommand::configuration;
use subcommand::monitor::MonitorArgs;
use subcommand::node::WriteArgs;
use subcommand::offline::{self, TimingArgs};

/// Configure, verify and inspect CANopen Safety nodes (EN 50325-5 / CiA 304).
///
/// The bus is named with --bus:
///   socketcand:HOST:PORT[/BUS]   a socketcand server (e.g. socketcand:127.0.0.1:29536/can0)
///   slcan:DEVICE[@BITRATE]       an SLCAN serial adapter (e.g. slcan:/dev/ttyACM0@500000)
///   socketcan:INTERFACE          Linux SocketCAN (built with the `socketcan` feature)
/// Without --bus: the emulated bus of `cargo xtask run`, socketcand:127.0.0.1:PORT/can0,
/// where PORT is the environment variable CAN_HUB_PORT as `cargo xtask run` reads it
/// (default 29536).
#[derive(Parser)]
#[command(version, verbatim_doc_comment)]
struct Cli {
    /// The CAN interface (see above); without it socketcand:127.0.0.1:PORT/can0 with PORT
    /// from CAN_HUB_PORT (default 29536), the bus `cargo xtask run` started.
    #[arg(long, global = true)]
    bus: Option<String>,
    /// How long one SDO request waits for its answer, in milliseconds (the network file's
    /// `sdo_timeout_ms` wins for configure and verify).
    #[arg(long, global = true, default_value_t = 500)]
    sdo_timeout_ms: u64,
    /// Print the result as JSON (for scripts) instead of sentences.
    #[arg(long, global = true)]
    json: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Listen for boot-up and heartbeat messages, then read each node's identity (0x1018).
    Scan {
        /// How long to listen, in milliseconds.
        #[arg(long, default_value_t = 1000)]
        listen_ms: u64,
    },
    /// Send an NMT command to one node or to all.
    Nmt {
        /// The command.
        command: Nmt,
        /// A node-ID (1..=127), or `all`.
        target: String,
    },
    /// Read an object (SDO upload, expedited or segmented) and print its value as the
    /// device's EDS types it (e.g. `UNSIGNED32 0x00000ABC (2748)`, a VISIBLE_STRING as text).
    ///
    /// The object is INDEX:SUB or INDEX SUB, both hexadecimal, each bare, with 0x or with h:
    /// `read 1 1018:1`, `read 1 1018 1`, `read 1 0x1018:0x01`, `read 1 1018h:01h`.
    #[command(verbatim_doc_comment)]
    Read {
        /// The node-ID (1..=127).
        #[arg(value_parser = node_id)]
        node: u8,
        /// The object's index, with its sub-index after a colon (1018:4) or as the next
        /// argument.
        object: String,
        /// The sub-index (hexadecimal), when OBJECT has none.
        sub: Option<String>,
    },
    /// Write an object (SDO download, expedited or segmented).
    ///
    /// The object is INDEX:SUB or INDEX SUB, both hexadecimal, as for `read`:
    /// `write 1 1017:0 500`, `write 1 1017 0 500`, `write 1 0x1017:0x00 0x1F4`.
    #[command(verbatim_doc_comment)]
    Write {
        /// The node-ID (1..=127).
        #[arg(value_parser = node_id)]
        node: u8,
        /// The object's index, with its sub-index after a colon (1017:0) or as the next
        /// argument.
        object: String,
        /// The sub-index (hexadecimal) when OBJECT has none, then the value: a number
        /// (decimal or 0x-hexadecimal) written in --len bytes, or with --bytes hexadecimal
        /// octets (e.g. "73 61 76 65").
        #[arg(value_name = "[SUB] VALUE", num_args = 1..=2, required = true)]
        rest: Vec<String>,
        /// Bytes of a numeric value (1, 2 or 4).
        #[arg(long, default_value_t = 4)]
        len: usize,
        /// Take the value as hexadecimal octets.
        #[arg(long)]
        bytes: bool,
        #[command(flatten)]
        unlock: Unlock,
    },
    /// Compute every SRDO signature of a network file offline (EN 50325-5 6.4.1.5, Table 9),
    /// and each node's SimpleCAN configuration signature (CRC-32/MPEG-2, 0x5EFF) with the
    /// node hash of each of its SDD entries.
    ///
    /// A node hash (SC_REQ_15) is the first non-zero 32-bit word (big-endian) of SHA-256 over
    /// "safety-config/simplecan/node-hash/v1", the network name (length-prefixed), the
    /// SC-ID, its producer's node-ID and the producer's vendor-ID, product code and serial
    /// number from the file; a network whose hashes collide is refused.
    #[command(verbatim_doc_comment)]
    Sign {
        /// The network file (TOML), or a node's DCF (`.dcf`).
        file: String,
    },
    /// Configure, read back, sign, validate and store every node of a network file
    /// (EN 50325-5 8.3.1); with a [simplecan] section also each node's SimpleCAN objects
    /// (0x5E00..0x5EFF: written, read back and compared, signed with the tool's CRC-32,
    /// 0x5EFE = A5h, stored).
    Configure {
        /// The network file (TOML), or a node's DCF (`.dcf`, as `dcf` writes it).
        file: String,
        /// Start the nodes (NMT start) when every node was configured.
        #[arg(long)]
        start: bool,
        /// Configure a node although its identity (0x1018) differs from the file.
        #[arg(long)]
        accept_identity: bool,
        #[command(flatten)]
        unlock: Unlock,
    },
    /// Set the node's secret against unauthorised configuration (SC_REQ_43, object 5C10h)
    /// and store it (0x1010). A new device takes it without --unlock; a node with a secret
    /// needs --unlock with the current one. The new secret (8 to 32 bytes) comes from
    /// --new-secret-file, SAFETY_CONFIG_NEW_SECRET or a prompt asked twice, never from the
    /// command line. Only erasing the parameter flash with the flashing tool removes it.
    SetSecret {
        /// The node-ID.
        node: u8,
        #[command(flatten)]
        unlock: Unlock,
        /// Take the new secret from the first line of this file.
        #[arg(long)]
        new_secret_file: Option<std::path::PathBuf>,
    },
    /// Read the node's access state and audit record (SC_REQ_43): validated changes, and the
    /// signatures of every SRDO before and after the last one.
    Audit {
        /// The node-ID.
        node: u8,
    },
    /// Read every node's safety configuration and compare it with a network file.
    Verify {
        /// The network file (TOML), or a node's DCF (`.dcf`).
        file: String,
    },
    /// Watch the bus live: every node's NMT state and heartbeat, every SRDO as pairs (the
    /// inversion, the plain → inverted gap against SRVT, the period against SCT), GFC, EMCY
    /// in words and SDO traffic; SimpleCAN packets decoded with the file's node hashes (each
    /// SC-ID's value and age against its timeout, its arrival against its configured slot
    /// and the jitter, syncs per master, bad CRCs; without a file they cannot be decoded, the
    /// hashes are never sent). Keys: q quit, g send GFC, p pause, ? help. Not on a
    /// terminal (or with --plain) it prints a line per happening and a summary at the end.
    Monitor {
        /// A network file (TOML) or DCF: the SRDOs to judge against their SCT and SRVT and
        /// the nodes' names. Without one, SRDOs are learned from the bus (no limits known).
        file: Option<String>,
        /// Record every frame into this candump log (`candump -l` format), or into a pcap
        /// (SocketCAN link type, for Wireshark and tshark: see `dissector`) when its name
        /// ends in `.pcap`.
        #[arg(long, value_name = "LOG")]
        record: Option<String>,
        /// Replay a candump log instead of listening to the bus, at the recorded pace.
        #[arg(long, value_name = "LOG")]
        replay: Option<String>,
        /// With --replay: as fast as the log can be read.
        #[arg(long, requires = "replay")]
        fast: bool,
        /// End after this many seconds.
        #[arg(long, value_name = "SECONDS")]
        stop_after: Option<f64>,
        /// Print a line per happening instead of the live view.
        #[arg(long)]
        plain: bool,
    },
    /// Print a Wireshark Lua dissector for the network file's safety frames: each SRDO's
    /// pairs (plain on COB-ID 1, inverted on COB-ID 2) with the bit-by-bit inversion check,
    /// the gap against SRVT and the period against SCT; the GFC (001h); SimpleCAN packets
    /// with their CRC checked against the file's node hashes. Offline.
    ///
    ///   safety-config dissector network.toml > safety.lua
    ///   wireshark -X lua_script:safety.lua bus.pcap
    ///   tshark -X lua_script:safety.lua -r bus.pcap -Y cansafety
    ///
    /// A trace: `bus.pcap` of `cargo xtask run`, or `monitor --record trace.pcap`.
    #[command(verbatim_doc_comment)]
    Dissector {
        /// The network file (TOML), or a node's DCF (`.dcf`).
        file: String,
    },
    /// Send the global fail-safe command (GFC, CAN-ID 001h): every safety node in
    /// Operational goes to its safe state.
    Gfc,
    /// Print the node's EDS (CiA 306, with the CANopen Safety keys of its Annex A), generated
    /// from the device description the firmware is built from.
    Eds {
        /// The EDS of a node that speaks SimpleCAN, with this many safety data dictionary
        /// entries (5E10h.., 1 to 80). The firmware images with SimpleCAN: `--simplecan 2
        /// --srdos 0` (eds/safety-node-simplecan.eds).
        #[arg(long, value_parser = clap::value_parser!(u8).range(1..=80))]
        simplecan: Option<u8>,
        /// With `--simplecan`: the SRDOs beside SimpleCAN, 0 (SimpleCAN instead of SRDOs, as
        /// the firmware images with SimpleCAN) or 2 to 4 (the host simulations' nodes have 4).
        #[arg(long, requires = "simplecan", value_parser = clap::value_parser!(u8).range(0..=4))]
        srdos: Option<u8>,
    },
    /// Read a node's whole object dictionary and print its DCF (CiA 306): the values it holds,
    /// signatures and 0x13FE included. `configure` and `verify` take a DCF as the file.
    Dcf {
        /// The node-ID.
        node: u8,
        /// A name for the node in the DCF.
        #[arg(long)]
        name: Option<String>,
    },
    /// The worst-case reaction time of each safety function of a network file, from the
    /// producer's input to the consumer's output, part by part (EN 50325-5 9.3.1). Offline.
    Sfrt {
        /// The network file (TOML).
        file: String,
        #[command(flatten)]
        plan: PlanArgs,
        /// Each channel's input sample period (µs).
        #[arg(long, default_value_t = DeviceTiming::HARDWARE.input_sample_us)]
        input_sample_us: u64,
        /// The largest skew between the two contacts of one input (µs), at most the sample
        /// window (5000).
        #[arg(long, default_value_t = DeviceTiming::HARDWARE.contact_skew_us)]
        contact_skew_us: u64,
        /// One step of a channel (µs), for every safety function of the file; the default is
        /// the step counted in the shipped images on the emulated STM32F405 at a bounded cycles
        /// per instruction (`safety_config::calc::target`): the CANopen Safety images' for
        /// SRDOs, the SimpleCAN images' for SimpleCAN's.
        #[arg(long)]
        processing_us: Option<u64>,
        /// The output stage after the pin (µs).
        #[arg(long, default_value_t = DeviceTiming::HARDWARE.output_us)]
        output_us: u64,
    },
    /// Layer Setting Services (CiA 305): node-IDs and bit rates over the bus, by identity
    /// (object 1018h); fastscan gives unconfigured nodes the network file's node-IDs. A node
    /// in NMT Operational answers no configuring service.
    Lss {
        #[command(subcommand)]
        action: safety_config::lss::LssCommand,
        /// How long each LSS request waits for its answers, in milliseconds (fastscan waits
        /// it on every one of its requests: several nodes may answer).
        #[arg(long, default_value_t = 100)]
        lss_timeout_ms: u64,
    },
    /// Bus load per bit rate and the residual error rate against a SIL for a network file
    /// (EN 50325-5 9.4); exits with failure when a limit is exceeded. Offline.
    Budget {
        /// The network file (TOML).
        file: String,
        #[command(flatten)]
        plan: PlanArgs,
        /// The SIL the safety functions must meet (1, 2 or 3).
        #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u8).range(1..=3))]
        sil: u8,
        /// Safety devices on the network, when there are more than the file lists.
        #[arg(long)]
        devices: Option<u32>,
    },
}

/// What a plan states beside the network file.
#[derive(clap::Args)]
struct PlanArgs {
    /// The bit rate the network runs at (bit/s).
    #[arg(long, default_value_t = safety_device::BIT_RATE)]
    bit_rate: u32,
    /// Other traffic on the bus, as ID:LEN:PERIOD_MS (e.g. 0x181:8:10; repeat for more).
    #[arg(long = "traffic")]
    traffic: Vec<Stream>,
    /// The shortest interval between two input changes of one producer (ms); without it one
    /// event-driven pair per refresh time is counted besides the cyclic one.
    #[arg(long)]
    event_interval_ms: Option<u64>,
}

/// Unlocking a node against unauthorised configuration (SC_REQ_43). The secret is never a
/// command-line argument (`ps` would show it): it comes from --secret-file, the environment
/// variable SAFETY_CONFIG_SECRET, or a prompt without echo.
#[derive(clap::Args)]
struct Unlock {
    /// Unlock the node with its secret before writing (SC_REQ_43). The secret comes from
    /// --secret-file, else the environment variable SAFETY_CONFIG_SECRET, else a prompt
    /// without echo; never from the command line, where `ps` would show it.
    #[arg(long)]
    unlock: bool,
    /// Take the secret from the first line of this file (implies --unlock).
    #[arg(long)]
    secret_file: Option<std::path::PathBuf>,
}

impl Unlock {
    /// Where the secret comes from, when unlocking was asked for.
    fn source(&self) -> Option<SecretSource> {
        (self.unlock || self.secret_file.is_some())
            .then(|| SecretSource::choose(self.secret_file.as_deref(), SECRET_VARIABLE))
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum Nmt {
    Start,
    Stop,
    PreOperational,
    ResetNode,
    ResetCommunication,
}

/// Prints progress on stderr; asks on a terminal when an identity differs.
struct Person {
    accept_identity: bool,
    quiet: bool,
    /// Where the secret to unlock with comes from (`--unlock`).
    secret: Option<SecretSource>,
}

impl Operator for Person {
    fn note(&mut self, line: &str) {
        if !self.quiet {
            eprintln!("{line}");
        }
    }

    fn confirm_identity(&mut self, node: &NodeSpec, differences: &str) -> bool {
        if self.accept_identity {
            eprintln!(
                "node {}: identity differs ({differences}); accepted by --accept-identity",
                node.id
            );
            return true;
        }
        if !std::io::stdin().is_terminal() {
            return false;
        }
        eprint!(
            "node {} is not the device the file expects ({differences}).\nConfigure this physical node anyway? Type yes: ",
            node.id
        );
        let _ = std::io::stderr().flush();
        let mut answer = String::new();
        std::io::stdin().read_line(&mut answer).is_ok() && answer.trim() == "yes"
    }

    fn secret(&mut self, node: u8) -> Result<Option<Secret>, ToolError> {
        self.secret
            .as_ref()
            .map(|source| source.read(&format!("secret of node {node}")))
            .transpose()
    }
}

/// The interface to use: `--bus`, else the emulated bus at the port of CAN_HUB_PORT.
fn bus(given: Option<&str>) -> Result<String, ToolError> {
    use safety_config::socketcand::{HUB_PORT_VARIABLE, hub_bus};
    match given {
        Some(spec) => Ok(spec.to_owned()),
        None => {
            let port = std::env::var_os(HUB_PORT_VARIABLE);
            hub_bus(port.as_ref().map(|port| port.to_string_lossy()).as_deref())
                .map_err(ToolError::Usage)
        }
    }
}

fn open_bus(spec: &str) -> Result<Box<dyn Transport>, ToolError> {
    let usage = || {
        ToolError::Usage(format!(
            "--bus {spec:?} is not socketcand:HOST:PORT[/BUS], slcan:DEVICE[@BITRATE] or socketcan:INTERFACE"
        ))
    };
    let (kind, rest) = spec.split_once(':').ok_or_else(usage)?;
    match kind {
        "socketcand" => {
            let (address, bus) = rest.split_once('/').unwrap_or((rest, "can0"));
            Ok(Box::new(
                safety_config::socketcand::SocketcandClient::connect(address, bus)?,
            ))
        }
        "slcan" => {
            let (device, rate) = match rest.split_once('@') {
                Some((device, rate)) => (device, rate.parse().map_err(|_| usage())?),
                None => (rest, 500_000),
            };
            Ok(Box::new(safety_config::slcan::Slcan::open_path(
                device, rate,
            )?))
        }
        #[cfg(feature = "socketcan")]
        "socketcan" => Ok(Box::new(safety_config::socketcan::SocketCan::open(rest)?)),
        #[cfg(not(feature = "socketcan"))]
        "socketcan" => Err(ToolError::Usage(
            "this build has no SocketCAN: build with `--features socketcan`".into(),
        )),
        _ => Err(usage()),
    }
}

/// A node-ID argument: 1..=127 (CiA 301 7.2.8.1), or a sentence naming what it is not.
fn node_id(text: &str) -> Result<u8, String> {
    text.trim()
        .parse::<u8>()
        .ok()
        .filter(|id| (1..=127).contains(id))
        .ok_or_else(|| format!("{text:?} is not a node-ID from 1 to 127"))
}

/// A hexadecimal number of an object argument: bare (`1018`), with `0x` (`0x1018`) or with
/// `h` (`1018h`); `what` names the part ("index", "sub-index") in the error.
fn hexadecimal(text: &str, what: &str, largest: u32) -> Result<u32, ToolError> {
    let digits = text
        .strip_prefix("0x")
        .or_else(|| text.strip_prefix("0X"))
        .or_else(|| text.strip_suffix('h'))
        .or_else(|| text.strip_suffix('H'))
        .unwrap_or(text);
    if digits.is_empty() || !digits.chars().all(|c| c.is_ascii_hexdigit()) {
        return Err(ToolError::Usage(format!(
            "the {what} {text:?} is not hexadecimal (e.g. {})",
            if what == "index" {
                "1018, 0x1018 or 1018h"
            } else {
                "1, 0x01 or 01h"
            }
        )));
    }
    // Leading zeros are allowed (`0001`); a number of more than 32 bits is too large anyway.
    let significant = digits.trim_start_matches('0');
    let value = match significant.len() {
        0 => Some(0),
        1..=8 => u32::from_str_radix(significant, 16).ok(),
        _ => None,
    };
    value.filter(|value| *value <= largest).ok_or_else(|| {
        ToolError::Usage(format!(
            "the {what} {text:?} is larger than {largest:X}h, the largest {what}"
        ))
    })
}

/// The object of a `read` or `write`: `INDEX:SUB` in one argument, or `INDEX` and `SUB` in
/// two, each hexadecimal (bare, `0x` or `h`).
fn parse_object(object: &str, sub: Option<&str>) -> Result<Address, ToolError> {
    let (index, sub) = match (object.split_once(':'), sub) {
        (Some((index, sub)), None) => (index, sub),
        (None, Some(sub)) => (object, sub),
        (Some(_), Some(extra)) => {
            return Err(ToolError::Usage(format!(
                "the object {object:?} already has its sub-index; {extra:?} after it is one \
                 argument too many"
            )));
        }
        (None, None) => {
            return Err(ToolError::Usage(format!(
                "the object {object:?} needs a sub-index: {object}:0 or {object} 0 (hexadecimal)"
            )));
        }
    };
    let index = hexadecimal(index.trim(), "index", u32::from(u16::MAX))?;
    let sub = hexadecimal(sub.trim(), "sub-index", u32::from(u8::MAX))?;
    // Both were checked against their type's largest value just above.
    Ok(Address::new(index as u16, sub as u8))
}

/// The object and value of a `write`: `OBJECT VALUE` with OBJECT `INDEX:SUB`, or
/// `INDEX SUB VALUE`.
fn parse_write(object: &str, rest: &[String]) -> Result<(Address, String), ToolError> {
    match rest {
        [value] if object.contains(':') => Ok((parse_object(object, None)?, value.clone())),
        [value] => Err(ToolError::Usage(format!(
            "the object {object:?} needs a sub-index before the value {value:?}: \
             write NODE {object}:SUB {value} or write NODE {object} SUB {value}"
        ))),
        [sub, value] => Ok((parse_object(object, Some(sub))?, value.clone())),
        _ => Err(ToolError::Usage(format!(
            "write takes the object {object:?}, then the sub-index (unless after a colon) and \
             the value; {} argument(s) followed it",
            rest.len()
        ))),
    }
}

/// The value of a `write` as octets: a number (decimal or `0x`-hexadecimal) in `len` bytes,
/// or with `bytes` hexadecimal octets.
fn parse_value(value: &str, len: usize, bytes: bool) -> Result<Vec<u8>, ToolError> {
    if bytes {
        let words: Vec<String> = value.split_whitespace().map(str::to_owned).collect();
        return Ok(safety_config::socketcand::parse_hex_data(&words)?);
    }
    let number = match value
        .strip_prefix("0x")
        .or_else(|| value.strip_prefix("0X"))
    {
        Some(hex) => u64::from_str_radix(hex, 16),
        None => value.parse(),
    }
    .map_err(|_| {
        ToolError::Usage(format!(
            "the value {value:?} is not a number (decimal or 0x-hexadecimal; octets with --bytes)"
        ))
    })?;
    if !matches!(len, 1 | 2 | 4) {
        return Err(ToolError::Usage(format!(
            "--len {len} is not 1, 2 or 4 bytes"
        )));
    }
    if number >> (8 * len) != 0 {
        return Err(ToolError::Usage(format!(
            "the value {value} does not fit --len {len} byte(s)"
        )));
    }
    Ok(number.to_le_bytes()[..len].to_vec())
}

/// The line `read` prints: the object, then its value as the EDS types it, or its octets
/// when no device of this project has the object.
fn read_line(address: Address, value: &[u8]) -> String {
    let described = match safety_config::eds::entry_at(address) {
        Some(entry) => safety_config::eds::describe_value(&entry, value),
        None => {
            let hex: Vec<String> = value.iter().map(|b| format!("{b:02X}")).collect();
            format!(
                "{} byte(s) {} (not in the device's EDS: type unknown)",
                value.len(),
                hex.join(" ")
            )
        }
    };
    format!("{}: {described}", procedure::describe(address))
}

fn load(file: &str) -> Result<network_file::Network, ToolError> {
    let text = std::fs::read_to_string(file).map_err(|source| ToolError::ReadFile {
        path: file.to_owned(),
        source,
    })?;
    let is_dcf = std::path::Path::new(file)
        .extension()
        .is_some_and(|extension| extension.eq_ignore_ascii_case("dcf"));
    if is_dcf {
        Ok(network_file::parse_dcf(&text, file)?)
    } else {
        Ok(network_file::parse(&text, file)?)
    }
}

/// `value` as the JSON a command prints with `--json`. A value that does not serialise is an
/// error, so that the program prints no partial report and exits non-zero; the values are
/// serialised as they are: `serde_json::json!` panics on a value that does not serialise,
/// so it only wraps numbers, strings and bytes here, which always do.
fn json(value: &impl serde::Serialize) -> Result<String, ToolError> {
    serde_json::to_string_pretty(value).map_err(ToolError::Json)
}

/// Runs the subcommand: `Ok(false)` when it ran but found something wrong (a node not
/// configured or not matching, a limit exceeded). The commands that need no bus run first;
/// for the others the arguments are checked before the bus is opened, so that a mistyped
/// object is named as such, not hidden behind a bus that is not there.
fn run(cli: Cli) -> Result<bool, ToolError> {
    let Cli {
        bus,
        sdo_timeout_ms,
        json: as_json,
        command,
    } = cli;
    match &command {
        Command::Sign { file } => return offline::sign(file, as_json),
        Command::Dissector { file } => return offline::dissector(file),
        Command::Eds { simplecan, srdos } => return offline::eds(*simplecan, *srdos),
        Command::Monitor {
            file,
            record,
            replay,
            fast,
            stop_after,
            plain,
        } => {
            let given = MonitorArgs {
                bus: bus.as_deref(),
                file: file.as_deref(),
                record: record.as_deref(),
                replay: replay.as_deref(),
                fast: *fast,
                stop_after: *stop_after,
                plain: *plain,
            };
            return subcommand::monitor::monitor(&given, as_json);
        }
        Command::Sfrt {
            file,
            plan,
            input_sample_us,
            contact_skew_us,
            processing_us,
            output_us,
        } => {
            let given = TimingArgs {
                input_sample_us: *input_sample_us,
                contact_skew_us: *contact_skew_us,
                processing_us: *processing_us,
                output_us: *output_us,
            };
            return offline::sfrt(file, plan, &given, as_json);
        }
        Command::Budget {
            file,
            plan,
            sil,
            devices,
        } => return offline::budget(file, plan, *sil, *devices, as_json),
        Command::Read { object, sub, .. } => {
            parse_object(object, sub.as_deref())?;
        }
        Command::Write {
            object,
            rest,
            len,
            bytes,
            ..
        } => {
            let (_, value) = parse_write(object, rest)?;
            parse_value(&value, *len, *bytes)?;
        }
        _ => {}
    }
    let timeout = Duration::from_millis(sdo_timeout_ms);
    let mut client = Client::new(open_bus(&self::bus(bus.as_deref())?)?, timeout);
    match command {
        Command::Sign { .. }
        | Command::Dissector { .. }
        | Command::Eds { .. }
        | Command::Monitor { .. }
        | Command::Sfrt { .. }
        | Command::Budget { .. } => Ok(true),
        Command::Lss {
            action,
            lss_timeout_ms,
        } => subcommand::node::lss(client, &action, lss_timeout_ms, as_json),
        Command::Dcf { node, name } => subcommand::node::dcf(&mut client, node, name.as_deref()),
        Command::Scan { listen_ms } => subcommand::node::scan(&mut client, listen_ms, as_json),
        Command::Nmt { command, target } => {
            subcommand::node::nmt(&mut client, command, &target, as_json)
        }
        Command::Read { node, object, sub } => {
            subcommand::node::read(&mut client, node, &object, sub.as_deref(), as_json)
        }
        Command::Write {
            node,
            object,
            rest,
            len,
            bytes,
            unlock,
        } => {
            let given = WriteArgs {
                node,
                object: &object,
                rest: &rest,
                len,
                bytes,
                unlock: &unlock,
            };
            subcommand::node::write(&mut client, &given, as_json)
        }
        Command::Configure {
            file,
            start,
            accept_identity,
            unlock,
        } => configuration::configure(&mut client, &file, start, accept_identity, &unlock, as_json),
        Command::Verify { file } => configuration::verify(&mut client, &file, as_json),
        Command::SetSecret {
            node,
            unlock,
            new_secret_file,
        } => configuration::set_secret(
            &mut client,
            node,
            &unlock,
            new_secret_file.as_deref(),
            as_json,
        ),
        Command::Audit { node } => configuration::audit(&mut client, node, as_json),
        Command::Gfc => subcommand::node::gfc(&mut client, as_json),
    }
}

fn main() -> ExitCode {
    // Output piped into a program that stops reading (`safety-config eds | head`) ends this
    // one quietly, as it ends any Unix tool, instead of panicking in `println!`.
    sigpipe::reset();
    let cli = Cli::parse();
    let as_json = cli.json;
    match run(cli) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::FAILURE,
        Err(error) => {
            #[derive(serde::Serialize)]
            struct Failed {
                error: String,
            }
            let failed = Failed {
                error: error.to_string(),
            };
            match json(&failed) {
                Ok(text) if as_json => println!("{text}"),
                _ => eprintln!("error: {error}"),
            }
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;
    use subcommand::offline::BudgetReport;

    fn usage(result: Result<impl std::fmt::Debug, ToolError>) -> String {
        match result {
            Err(ToolError::Usage(sentence)) => sentence,
            other => panic!("expected a usage error, got {other:?}"),
        }
    }

    /// `read` and `write` take the object as one argument `INDEX:SUB` or as two, each
    /// hexadecimal bare, with `0x` or with `h`; every form names the same object.
    #[test]
    fn an_object_is_index_and_sub_index_in_every_written_form() {
        let vendor = Address::new(0x1018, 1);
        for (object, sub) in [
            ("1018:1", None),
            ("1018", Some("1")),
            ("0x1018:0x01", None),
            ("0X1018", Some("0x1")),
            ("1018h:01h", None),
            ("1018H", Some("01H")),
            ("01018:001", None),
        ] {
            assert_eq!(
                parse_object(object, sub).unwrap(),
                vendor,
                "{object} {sub:?}"
            );
        }
        // Hexadecimal throughout: sub-index 10 is 10h.
        assert_eq!(
            parse_object("1301", Some("10")).unwrap(),
            Address::new(0x1301, 0x10)
        );
        assert_eq!(
            parse_object("FFFF:FF", None).unwrap(),
            Address::new(0xFFFF, 0xFF)
        );
    }

    /// A bad object is a sentence naming the part that is wrong, never a guess.
    #[test]
    fn a_bad_object_is_refused_with_a_sentence_naming_the_argument() {
        assert_eq!(
            usage(parse_object("10G8:1", None)),
            "the index \"10G8\" is not hexadecimal (e.g. 1018, 0x1018 or 1018h)"
        );
        assert_eq!(
            usage(parse_object("1018", Some("x"))),
            "the sub-index \"x\" is not hexadecimal (e.g. 1, 0x01 or 01h)"
        );
        assert_eq!(
            usage(parse_object("12345:0", None)),
            "the index \"12345\" is larger than FFFFh, the largest index"
        );
        assert_eq!(
            usage(parse_object("1018", Some("100"))),
            "the sub-index \"100\" is larger than FFh, the largest sub-index"
        );
        assert_eq!(
            usage(parse_object("1018", None)),
            "the object \"1018\" needs a sub-index: 1018:0 or 1018 0 (hexadecimal)"
        );
        assert_eq!(
            usage(parse_object("1018:1", Some("2"))),
            "the object \"1018:1\" already has its sub-index; \"2\" after it is one argument too many"
        );
        for empty in [":1", "1018:", "0x:1", "h:1"] {
            assert!(
                usage(parse_object(empty, None)).contains("is not hexadecimal"),
                "{empty}"
            );
        }
    }

    /// `write NODE OBJECT VALUE` with OBJECT `INDEX:SUB`, or `write NODE INDEX SUB VALUE`;
    /// a value without a sub-index is refused rather than written to sub-index 0.
    #[test]
    fn write_takes_the_sub_index_after_a_colon_or_as_its_own_argument() {
        let words = |list: &[&str]| list.iter().map(|w| w.to_string()).collect::<Vec<_>>();
        let heartbeat = Address::new(0x1017, 0);
        assert_eq!(
            parse_write("1017:0", &words(&["500"])).unwrap(),
            (heartbeat, "500".to_owned())
        );
        assert_eq!(
            parse_write("1017h", &words(&["00h", "0x1F4"])).unwrap(),
            (heartbeat, "0x1F4".to_owned())
        );
        assert!(
            usage(parse_write("1017", &words(&["500"])))
                .starts_with("the object \"1017\" needs a sub-index before the value \"500\"")
        );
        assert!(usage(parse_write("1017:0", &words(&["0", "500"]))).contains("already has"));
        assert_eq!(parse_value("0x1F4", 2, false).unwrap(), vec![0xF4, 0x01]);
        assert_eq!(
            parse_value("500", 4, false).unwrap(),
            vec![0xF4, 0x01, 0, 0]
        );
        assert_eq!(
            parse_value("73 61 76 65", 4, true).unwrap(),
            b"save".to_vec()
        );
        assert_eq!(
            usage(parse_value("70000", 2, false)),
            "the value 70000 does not fit --len 2 byte(s)"
        );
        assert_eq!(
            usage(parse_value("5", 3, false)),
            "--len 3 is not 1, 2 or 4 bytes"
        );
        assert!(
            usage(parse_value("five", 1, false)).starts_with("the value \"five\" is not a number")
        );
    }

    /// The command line as a user types it: both forms of `read` parse to the same
    /// arguments; a node-ID outside 1..=127 is refused by clap with its name.
    #[test]
    fn the_command_line_takes_read_in_both_forms_and_names_a_bad_node_id() {
        for line in [
            &["safety-config", "read", "5", "1018", "1"][..],
            &["safety-config", "read", "5", "1018:1"][..],
            &["safety-config", "read", "5", "1018h:01h"][..],
        ] {
            let Command::Read { node, object, sub } = Cli::try_parse_from(line).unwrap().command
            else {
                panic!("{line:?} is not read");
            };
            assert_eq!(node, 5);
            assert_eq!(
                parse_object(&object, sub.as_deref()).unwrap(),
                Address::new(0x1018, 1)
            );
        }
        let Command::Write { object, rest, .. } =
            Cli::try_parse_from(["safety-config", "write", "5", "1017", "0", "500"])
                .unwrap()
                .command
        else {
            panic!("not write");
        };
        assert_eq!(
            parse_write(&object, &rest).unwrap(),
            (Address::new(0x1017, 0), "500".to_owned())
        );
        for bad in ["0", "128", "x"] {
            let error = Cli::try_parse_from(["safety-config", "read", bad, "1018:1"])
                .err()
                .unwrap()
                .to_string();
            assert!(
                error.contains("'<NODE>'") && error.contains("is not a node-ID from 1 to 127"),
                "{error}"
            );
        }
        assert!(
            Cli::try_parse_from(["safety-config", "write", "5", "1017", "0", "500", "1"]).is_err(),
            "a fourth word after write's node-ID"
        );
    }

    /// The default bus is the emulated bus at CAN_HUB_PORT, as `cargo xtask run` starts it;
    /// --bus wins; a variable that is not a port is refused, naming it.
    #[test]
    fn the_default_bus_follows_can_hub_port_and_a_given_bus_wins() {
        use safety_config::socketcand::hub_bus;
        assert_eq!(hub_bus(None).unwrap(), "socketcand:127.0.0.1:29536/can0");
        assert_eq!(
            hub_bus(Some("30400")).unwrap(),
            "socketcand:127.0.0.1:30400/can0"
        );
        for bad in ["", "abc", "0", "65535", "70000", "-1", " 30400"] {
            let sentence = hub_bus(Some(bad)).unwrap_err();
            assert!(
                sentence.starts_with(&format!(
                    "CAN_HUB_PORT={bad:?} is not a port from 1 to 65534"
                )),
                "{sentence}"
            );
        }
        assert_eq!(
            bus(Some("slcan:/dev/ttyACM0")).unwrap(),
            "slcan:/dev/ttyACM0"
        );
        let cli = Cli::try_parse_from(["safety-config", "scan"]).unwrap();
        assert_eq!(
            cli.bus, None,
            "no default on the command line: the variable decides"
        );
    }

    /// `read` prints the value as the EDS types the object (CiA 306 DataType): unsigned
    /// numbers in hexadecimal with every digit of the type and in decimal, a VISIBLE_STRING
    /// as text; a length other than the type's, or an object of no EDS, as octets.
    #[test]
    fn cia306_read_prints_the_value_by_its_eds_data_type() {
        assert_eq!(
            read_line(Address::new(0x1018, 1), &[0x23, 0x01, 0, 0]),
            "object 1018h:01h (identity: vendor-ID): UNSIGNED32 0x00000123 (291)"
        );
        assert_eq!(
            read_line(Address::new(0x1017, 0), &[0xF4, 0x01]),
            "object 1017h:00h: UNSIGNED16 0x01F4 (500)"
        );
        assert_eq!(
            read_line(Address::new(0x13FE, 0), &[0xA5]),
            "object 13FEh:00h (configuration valid): UNSIGNED8 0xA5 (165)"
        );
        assert_eq!(
            read_line(Address::new(0x1008, 0), b"Safety node"),
            "object 1008h:00h: VISIBLE_STRING \"Safety node\""
        );
        assert_eq!(
            read_line(Address::new(0x1018, 1), &[0x23, 0x01]),
            "object 1018h:01h (identity: vendor-ID): 2 byte(s) where UNSIGNED32 has 4: 23 01"
        );
        assert_eq!(
            read_line(Address::new(0x2FFF, 7), &[1, 2, 3]),
            "object 2FFFh:07h: 3 byte(s) 01 02 03 (not in the device's EDS: type unknown)"
        );
        // An object only a device with SimpleCAN has: typed from that device's EDS.
        let line = read_line(Address::new(0x5EFF, 0), &[0xDA, 0x9D, 0x36, 0x59]);
        assert!(
            line.ends_with(": UNSIGNED32 0x59369DDA (1496751578)"),
            "{line}"
        );
    }

    /// A value JSON cannot carry (a map keyed by pairs: JSON keys are strings) is an error
    /// that says so in a sentence, not an empty or partial report.
    #[test]
    fn a_result_that_does_not_serialise_is_an_error_not_a_partial_report() {
        let pairs: BTreeMap<(u8, u8), u16> = [((1, 2), 0x1234)].into();
        let error = json(&pairs).expect_err("JSON keys must be strings");
        assert!(matches!(error, ToolError::Json(_)));
        let sentence = error.to_string();
        assert!(
            sentence.starts_with("the result could not be written as JSON (")
                && sentence.ends_with("run the command without --json to read it"),
            "{sentence}"
        );
        // Inside a report, too: the whole report fails, no field is left out.
        let report = BudgetReport {
            budget: &serde_json::json!({"producers": 1}),
            simplecan: Some(&pairs),
        };
        assert!(matches!(json(&report), Err(ToolError::Json(_))));
    }

    /// The budget report keeps the budget's own fields at the top level, SimpleCAN's beside
    /// them only when the network file has SimpleCAN.
    #[test]
    fn the_budget_report_holds_every_field_of_the_budget_and_simplecan_when_present() {
        let budget = serde_json::json!({"producers": 2, "warnings": ["w"]});
        let without: serde_json::Value = serde_json::from_str(
            &json(&BudgetReport::<_, u8> {
                budget: &budget,
                simplecan: None,
            })
            .unwrap(),
        )
        .unwrap();
        assert_eq!(without, budget);
        let with: serde_json::Value = serde_json::from_str(
            &json(&BudgetReport {
                budget: &budget,
                simplecan: Some(&serde_json::json!({"within": true})),
            })
            .unwrap(),
        )
        .unwrap();
        assert_eq!(
            with,
            serde_json::json!({"producers": 2, "warnings": ["w"], "simplecan": {"within": true}})
        );
    }
}
