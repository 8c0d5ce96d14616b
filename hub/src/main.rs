//! `can-hub`: the emulated CAN bus between QEMU instances (each one's USART2 on a Unix socket)
//! and tools (TCP on loopback), in real time, with candump and pcap traces, the links between
//! the channels of a node, and a control port for input pins and faults.
//!
//! ```text
//! can-hub --socket node1a=/tmp/bus/node1a.sock --socket node1b=/tmp/bus/node1b.sock \
//!         --link node1-link=node1a,node1b --paced \
//!         --tcp 127.0.0.1:29536 --control 127.0.0.1:29537 \
//!         --candump bus.log --pcap bus.pcap --events events.log --bit-rate 500000
//! ```
//!
//! The hub listens on each `--socket` path for one QEMU instance, which speaks CAN-over-serial
//! (`emulation_wire`; start QEMU with `-chardev socket,id=can,path=PATH` and
//! `-serial null -serial chardev:can`), and accepts any number of tool connections on `--tcp`,
//! which speak socketcand (linux-can/socketcand `doc/protocol.md`, raw mode; the bus is named
//! `can0`): the configuration tool (`--bus socketcand:127.0.0.1:29536/can0`), python-can
//! (`interface="socketcand", host=..., port=..., channel="can0"`) and python-canopen through
//! it. A `--link` relays the link messages (`Wire::Link`) between two of the `--socket`
//! participants (the two channels of a node) until the control port cuts it: on the same
//! serial line as their frames, so that each channel receives everything in the order the hub
//! sent it. With `--paced` the `--socket` participants share the hub's virtual time
//! (`can_hub::pace`): the hub grants it to them and waits for the slowest. The control port's
//! line protocol is in `can_hub::control`. The hub runs until killed.
//!
//! Nothing a participant sends makes the hub hold more and more (`can_hub::port`). A tool
//! whose transmit FIFO is full (`can_hub::bus::TRANSMIT_QUEUE`) waits, as on a real bus: its
//! bytes stay with the hub only up to `can_hub::port::BACKLOG` bytes; past that the hub stops
//! reading its socket, so the sender's writes block. An emulated MCU's bytes are always taken
//! (its acknowledgements of the virtual time travel behind its frames;
//! `can_hub::hub::Hub::receive` says why): a frame that finds its FIFO full is dropped and
//! reported here, as `board::hw` drops it. A control line is at most
//! `can_hub::control::MAX_LINE` bytes, and a tool or control client that does not read what
//! the hub writes for `can_hub::port::WRITE_TIMEOUT` is disconnected instead of stalling the
//! bus. At most `can_hub::port::MAX_CLIENTS` tools and as many control clients are connected
//! at once; one more is told so in a sentence and closed, so no number of connections makes
//! the hub hold more and more threads either.

use can_hub::bus::{BIT_RATES, Fault, Injection, Match};
use can_hub::control::{self, Command, status_line};
use can_hub::events;
use can_hub::hub::Hub;
use can_hub::load::Load;
use can_hub::pace::{self, Pacer};
use can_hub::port::{Arrival, ControlEvent, ToolEvent, accept_control, accept_socketcand, reader};
use can_hub::trace::{PcapWriter, candump_line};
use clap::Parser;
use shared::Instant;
use std::collections::HashMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::os::unix::net::UnixListener;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

#[derive(Parser)]
#[command(about = "Emulated CAN bus: arbitration, bit time, faults, traces")]
struct Args {
    /// Bit rate in bit/s: 125000, 250000, 500000 or 1000000.
    #[arg(long, default_value_t = 500_000)]
    bit_rate: u32,
    /// `[NAME=]PATH`: a Unix socket to listen on for one QEMU instance (repeatable); the name
    /// (default: the file stem) is how the control port addresses it.
    #[arg(long)]
    socket: Vec<String>,
    /// `NAME=PARTICIPANT_A,PARTICIPANT_B`: relay the link messages between these two
    /// `--socket` participants (the two channels of a node), until the control port cuts it.
    #[arg(long)]
    link: Vec<String>,
    /// The `--socket` participants are emulated MCUs on the hub's virtual time: grant it to
    /// them and let it advance only as far as the slowest has acknowledged (`can_hub::pace`).
    #[arg(long)]
    paced: bool,
    /// With `--paced`: the lookahead in microseconds, as far as a participant's clock may run
    /// past its last grant and the hub's past the oldest acknowledgement (`can_hub::pace`).
    /// It must be the one the images were built with (`emulation_wire::LOOKAHEAD`, or
    /// `SIMPLECAN_LOOKAHEAD` for the SimpleCAN images, which xtask gives).
    #[arg(long, default_value_t = pace::LOOKAHEAD.as_micros())]
    lookahead: u64,
    /// With `--paced`: how often (virtual time, microseconds) the hub grants time to each
    /// participant; more than zero and less than `--lookahead`.
    #[arg(long, default_value_t = pace::GRANT_PERIOD.as_micros())]
    grant_period: u64,
    /// A TCP address to accept tools on (e.g. 127.0.0.1:29536).
    #[arg(long)]
    tcp: Option<String>,
    /// A TCP address for the control port (e.g. 127.0.0.1:29537).
    #[arg(long)]
    control: Option<String>,
    /// Write a candump log here.
    #[arg(long)]
    candump: Option<PathBuf>,
    /// Write a pcap (SocketCAN link type) here.
    #[arg(long)]
    pcap: Option<PathBuf>,
    /// Write the event log here: every frame with its sender and every change of an emulated
    /// channel's output, on the virtual time (`can_hub::events`, which gives the line format).
    #[arg(long)]
    events: Option<PathBuf>,
    /// Drop the next frame with this identifier after this many seconds: `0x102@2.5`
    /// (repeatable).
    #[arg(long)]
    drop: Vec<String>,
}

/// The name of the bus a socketcand client opens (`< open can0 >`).
const TOOL_BUS: &str = "can0";

/// What the connection threads tell the hub.
enum Input {
    /// A participant joined: how to write to it, and its count of bytes not yet taken.
    Joined(usize, Box<dyn Write + Send>, Arc<AtomicUsize>),
    /// A socketcand client joined on the TCP port: as [`Input::Joined`], and its connection
    /// (to close it when the session ends).
    ToolJoined(usize, TcpStream, Arc<AtomicUsize>),
    Bytes(usize, Vec<u8>),
    Left(usize),
    ControlJoined(usize, Box<dyn Write + Send>),
    /// A control line, or why it was refused.
    Control(usize, Result<String, String>),
}

impl From<Arrival> for Input {
    fn from(arrival: Arrival) -> Self {
        match arrival {
            Arrival::Bytes(id, bytes) => Input::Bytes(id, bytes),
            Arrival::Left(id) => Input::Left(id),
        }
    }
}

impl From<ToolEvent> for Input {
    fn from(event: ToolEvent) -> Self {
        match event {
            ToolEvent::Joined {
                id,
                stream,
                pending,
            } => Input::ToolJoined(id, stream, pending),
            ToolEvent::Arrival(arrival) => arrival.into(),
        }
    }
}

/// `0x102@2.5` → identifier and seconds.
fn parse_drop(spec: &str) -> Result<(u16, f64), String> {
    let (id, at) = spec
        .split_once('@')
        .ok_or_else(|| format!("--drop {spec}: expected ID@SECONDS, e.g. 0x102@2.5"))?;
    let id = u16::from_str_radix(id.trim_start_matches("0x"), 16)
        .ok()
        .filter(|id| *id <= 0x7FF)
        .ok_or_else(|| format!("--drop {spec}: {id} is not an 11-bit identifier"))?;
    let at: f64 = at
        .parse()
        .ok()
        .filter(|at: &f64| at.is_finite() && *at >= 0.0)
        .ok_or_else(|| format!("--drop {spec}: {at} is not a time in seconds"))?;
    Ok((id, at))
}

/// `[NAME=]PATH` → name and path.
fn parse_socket(spec: &str) -> Result<(String, PathBuf), String> {
    let (name, path) = match spec.split_once('=') {
        Some((name, path)) => (name.to_string(), PathBuf::from(path)),
        None => {
            let path = PathBuf::from(spec);
            let name = path
                .file_stem()
                .and_then(|stem| stem.to_str())
                .ok_or_else(|| format!("--socket {spec}: no name and no file name to use"))?
                .to_string();
            (name, path)
        }
    };
    if name.is_empty() || name.contains(char::is_whitespace) {
        return Err(format!("--socket {spec}: `{name}` is not a usable name"));
    }
    Ok((name, path))
}

/// `NAME=PARTICIPANT_A,PARTICIPANT_B`, with the participants' indices among `names`.
fn parse_link(spec: &str, names: &[String]) -> Result<(String, usize, usize), String> {
    let (name, ends) = spec
        .split_once('=')
        .ok_or_else(|| format!("--link {spec}: expected NAME=PARTICIPANT_A,PARTICIPANT_B"))?;
    let (a, b) = ends
        .split_once(',')
        .ok_or_else(|| format!("--link {spec}: expected two participants separated by a comma"))?;
    if name.is_empty() || name.contains(char::is_whitespace) {
        return Err(format!("--link {spec}: `{name}` is not a usable name"));
    }
    let index = |end: &str| {
        names
            .iter()
            .position(|n| n == end)
            .ok_or_else(|| format!("--link {spec}: `{end}` is not a --socket participant"))
    };
    let (a, b) = (index(a)?, index(b)?);
    if a == b {
        return Err(format!(
            "--link {spec}: a link joins two different participants"
        ));
    }
    Ok((name.to_string(), a, b))
}

/// Why the hub cannot listen on the TCP `address`, as a sentence with what to do.
fn cannot_listen(address: &str, error: &std::io::Error) -> String {
    if error.kind() == std::io::ErrorKind::AddrInUse {
        format!(
            "cannot listen on {address}: something else listens there already (another \
             can-hub, say, from a `cargo xtask run` or `e2e` still running); stop it or give \
             another address"
        )
    } else {
        format!("cannot listen on {address}: {error}")
    }
}

fn listen(path: &PathBuf) -> Result<UnixListener, String> {
    let _ = std::fs::remove_file(path);
    UnixListener::bind(path)
        .map_err(|error| format!("cannot listen on {}: {error}", path.display()))
}

fn main() -> ExitCode {
    let args = Args::parse();
    match start(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("can-hub: {message}");
            ExitCode::from(2)
        }
    }
}

fn start(args: &Args) -> Result<(), String> {
    if !BIT_RATES.contains(&args.bit_rate) {
        return Err(format!(
            "--bit-rate {} is not one of {BIT_RATES:?}",
            args.bit_rate
        ));
    }
    if args.grant_period == 0 || args.grant_period >= args.lookahead {
        return Err(format!(
            "--grant-period {} µs must be more than 0 and less than --lookahead {} µs",
            args.grant_period, args.lookahead
        ));
    }
    let mut hub = Hub::new(args.bit_rate);
    for spec in &args.drop {
        let (id, at) = parse_drop(spec)?;
        hub.inject(Injection::new(
            Match::next_with_id(id, Instant::from_micros((at * 1e6) as u64)),
            Fault::Drop,
        ));
    }
    let sockets = args
        .socket
        .iter()
        .map(|spec| parse_socket(spec))
        .collect::<Result<Vec<_>, _>>()?;
    let mut names: Vec<String> = sockets.iter().map(|(name, _)| name.clone()).collect();
    names.sort();
    if names.windows(2).any(|pair| pair[0] == pair[1]) {
        return Err("two --socket options have the same name".into());
    }
    let names: Vec<String> = sockets.iter().map(|(name, _)| name.clone()).collect();
    let mut links = Links::default();
    for spec in &args.link {
        let (name, a, b) = parse_link(spec, &names)?;
        if links.peer.contains_key(&a) || links.peer.contains_key(&b) {
            return Err(format!("--link {spec}: a participant has one link only"));
        }
        links.peer.insert(a, b);
        links.peer.insert(b, a);
        links.named.insert(name, (a, b));
    }
    let (tx, rx) = mpsc::channel();
    for (id, (_, path)) in sockets.iter().enumerate() {
        let listener = listen(path)?;
        let tx = tx.clone();
        std::thread::spawn(move || {
            let Ok((stream, _)) = listener.accept() else {
                return;
            };
            if let Ok(writer) = stream.try_clone() {
                let pending = Arc::new(AtomicUsize::new(0));
                let _ = tx.send(Input::Joined(id, Box::new(writer), pending.clone()));
                reader(id, stream, pending, |arrival| {
                    tx.send(arrival.into()).is_ok()
                });
            }
        });
    }
    if let Some(address) = &args.tcp {
        let listener = TcpListener::bind(address).map_err(|e| cannot_listen(address, &e))?;
        let tx = tx.clone();
        // After the sockets: the hub's own sender (`insert` on the control port), then its
        // load generator (`load`).
        let first = sockets.len() + 2;
        accept_socketcand(listener, first, "the hub", move |event| {
            tx.send(event.into()).is_ok()
        });
    }
    if let Some(address) = &args.control {
        let listener = TcpListener::bind(address).map_err(|e| cannot_listen(address, &e))?;
        let tx = tx.clone();
        accept_control(listener, "the hub", move |event| {
            tx.send(match event {
                ControlEvent::Joined(client, writer) => {
                    Input::ControlJoined(client, Box::new(writer))
                }
                ControlEvent::Line(client, line) => Input::Control(client, line),
            })
            .is_ok()
        });
    }
    drop(tx);
    run(&mut hub, &rx, args, names, links).map_err(|error| error.to_string())
}

/// A trace file that cannot be created, as a sentence naming it.
fn cannot_create(what: &str, path: &std::path::Path, error: std::io::Error) -> std::io::Error {
    std::io::Error::new(
        error.kind(),
        format!("cannot create the {what} {}: {error}", path.display()),
    )
}

/// The links between the channels of a node: each end's peer, by name, and which are cut.
#[derive(Default)]
struct Links {
    peer: HashMap<usize, usize>,
    named: HashMap<String, (usize, usize)>,
    cut: std::collections::HashSet<usize>,
}

/// The state the main loop keeps besides the hub.
struct Hosts {
    names: Vec<String>,
    writers: HashMap<usize, Box<dyn Write + Send>>,
    /// Bytes each participant sent that the hub has not taken yet, and the count its reader
    /// thread waits on.
    backlogs: HashMap<usize, (Vec<u8>, Arc<AtomicUsize>)>,
    controls: HashMap<usize, Box<dyn Write + Send>>,
    links: Links,
    /// The socketcand clients' connections, to close when their session ends.
    tools: HashMap<usize, TcpStream>,
    /// socketcand clients that closed their connection, whose frames still go on the bus.
    departing: Vec<usize>,
    /// The load the hub generates (`load` on the control port), sent as participant
    /// [`Hosts::load_sender`].
    load: Option<Load>,
}

impl Hosts {
    /// The participant the hub's own frames (`insert`) are sent as.
    fn own_sender(&self) -> usize {
        self.names.len()
    }

    /// The participant the generated load is sent as: its own transmit queue, so that an
    /// `insert` never waits behind the load.
    fn load_sender(&self) -> usize {
        self.names.len() + 1
    }

    /// Queues the generated load's next frame when it is due at `now`, one at a time: the
    /// next only once the bus has taken the one before. The hub's bus runs only when its loop
    /// does, so a loop that wakes late (a loaded host) finds several frames due at once;
    /// queued together they would leave by identifier (its 281h before its 621h), the SDO
    /// requests bunched at the end and node 33's answers behind them filling its transmit
    /// queue (seen: 25 answers dropped in one run). One at a time, the frames keep their turn
    /// while the load catches up, and each other sender's frame with a lower identifier than
    /// the load's next one wins the slot it competes for.
    fn generate(&mut self, hub: &mut Hub, now: Instant) {
        let sender = self.load_sender();
        let Some(load) = self.load.as_mut() else {
            return;
        };
        if hub.queued(sender) == 0
            && let Some(frame) = load.poll(now)
        {
            // The queue is empty: the frame is queued.
            let _ = hub.send(now, sender, frame);
        }
    }

    /// When the generated load wants to be asked again (`None`: no load, or its frame is
    /// still queued and the bus's next arbitration wakes the loop anyway).
    fn load_deadline(&self, hub: &Hub) -> Option<Instant> {
        let load = self.load.as_ref()?;
        (hub.queued(self.load_sender()) == 0).then(|| load.deadline())
    }

    /// Participant `id` as the event log names a frame's sender (`can_hub::events`).
    fn sender_name(&self, id: usize) -> String {
        match self.names.get(id) {
            Some(name) => name.clone(),
            None if id == self.own_sender() => "hub".to_string(),
            None if id == self.load_sender() => "load".to_string(),
            None => format!("tool{id}"),
        }
    }

    fn participant(&self, name: &str) -> Result<usize, String> {
        self.names.iter().position(|n| n == name).ok_or_else(|| {
            format!(
                "no participant `{name}` (there are: {})",
                self.names.join(", ")
            )
        })
    }

    /// Carries out one control command at `now`.
    fn apply(&mut self, hub: &mut Hub, now: Instant, command: &Command) -> Result<(), String> {
        let next = |id| Match::next_with_id(id, now);
        match command {
            Command::Input { name, value } => {
                let id = self.participant(name)?;
                let writer = self
                    .writers
                    .get_mut(&id)
                    .ok_or_else(|| format!("`{name}` is not connected"))?;
                writer
                    .write_all(&Hub::input(*value))
                    .map_err(|error| format!("`{name}`: {error}"))?;
            }
            Command::Drop(id) => hub.inject(Injection::new(next(*id), Fault::Drop)),
            Command::Corrupt { id, byte, mask } => hub.inject(Injection::new(
                next(*id),
                Fault::Corrupt {
                    byte: *byte,
                    mask: *mask,
                },
            )),
            Command::Delay { id, ms } => hub.inject(Injection::new(
                next(*id),
                Fault::Delay(shared::Duration::from_millis(*ms)),
            )),
            Command::Repeat(id) => hub.inject(Injection::new(next(*id), Fault::Repeat)),
            Command::Reorder(id) => hub.inject(Injection::new(next(*id), Fault::Reorder)),
            Command::Insert { id, data } => {
                let frame = shared::CanId::new(*id)
                    .ok()
                    .and_then(|id| shared::CanFrame::new(id, data).ok())
                    .ok_or_else(|| format!("{command} is not a CAN frame"))?;
                hub.send(now, self.own_sender(), frame).map_err(|_| {
                    format!(
                        "the hub's own transmit queue is full ({} frames waiting for the \
                             bus): {command} not sent",
                        can_hub::bus::TRANSMIT_QUEUE
                    )
                })?;
            }
            Command::Mute(name, true) => {
                let id = self.participant(name)?;
                hub.inject(Injection::new(Match::all_from(id, now), Fault::Mute));
            }
            Command::Mute(name, false) => {
                let id = self.participant(name)?;
                hub.retain_faults(|injection| {
                    !(injection.fault == Fault::Mute && injection.when.from == Some(id))
                });
            }
            Command::Cut(name) => {
                let (a, b) = *self
                    .links
                    .named
                    .get(name)
                    .ok_or_else(|| format!("no link `{name}`"))?;
                self.links.cut.extend([a, b]);
            }
            Command::Restore(name) => {
                let (a, b) = *self
                    .links
                    .named
                    .get(name)
                    .ok_or_else(|| format!("no link `{name}`"))?;
                self.links.cut.retain(|end| *end != a && *end != b);
            }
            Command::Clear => hub.retain_faults(|_| false),
            Command::PowerCycle(_) => {
                return Err(
                    "the hub cannot switch a QEMU instance off and on (the emulated STM32F405s \
                     of `emulate-network` can)"
                        .to_owned(),
                );
            }
            Command::Load { percent, frames } => {
                let frames = frames
                    .iter()
                    .map(|(id, data)| {
                        shared::CanId::new(*id)
                            .ok()
                            .and_then(|id| shared::CanFrame::new(id, data).ok())
                            .ok_or_else(|| format!("{id:03X}h with {data:02X?} is not a CAN frame"))
                    })
                    .collect::<Result<Vec<_>, String>>()?;
                let load = Load::new(*percent, hub.bus().bit_rate(), frames, now)
                    .map_err(|error| error.to_string())?;
                // A new load replaces the old one, and what the old one still had queued.
                hub.leave(self.load_sender());
                self.load = Some(load);
            }
            Command::LoadOff => {
                let load = self.load.take().ok_or("no load is running")?;
                hub.leave(self.load_sender());
                eprintln!(
                    "can-hub: load of {} % stopped at t={:.6} s after {} frames",
                    load.percent(),
                    now.as_micros() as f64 / 1e6,
                    load.sent()
                );
            }
        }
        Ok(())
    }

    /// Hands each participant's waiting bytes to the hub as far as its transmit FIFO has
    /// room; `true` when any were taken.
    fn feed(&mut self, hub: &mut Hub, now: Instant) -> bool {
        let mut fed = false;
        for (id, (bytes, pending)) in &mut self.backlogs {
            if bytes.is_empty() {
                continue;
            }
            let taken = hub.receive(now, *id, bytes);
            bytes.drain(..taken);
            pending.fetch_sub(taken, Ordering::AcqRel);
            fed |= taken > 0;
        }
        fed
    }

    /// Writes `bytes` to participant `to`; one that cannot be written to has left.
    fn write(&mut self, hub: &mut Hub, pacer: &mut Pacer, to: usize, bytes: &[u8]) {
        let failed = self
            .writers
            .get_mut(&to)
            .is_some_and(|writer| writer.write_all(bytes).is_err());
        if failed {
            self.writers.remove(&to);
            hub.leave(to);
            pacer.leave(to);
        }
    }

    fn tell_controls(&mut self, line: &str) {
        self.controls
            .retain(|_, writer| writeln!(writer, "{line}").is_ok());
    }
}

fn run(
    hub: &mut Hub,
    rx: &Receiver<Input>,
    args: &Args,
    names: Vec<String>,
    links: Links,
) -> std::io::Result<()> {
    let mut candump = args
        .candump
        .as_ref()
        .map(|path| {
            File::create(path)
                .map(BufWriter::new)
                .map_err(|error| cannot_create("candump log", path, error))
        })
        .transpose()?;
    let mut pcap = args
        .pcap
        .as_ref()
        .map(|path| {
            File::create(path)
                .map(BufWriter::new)
                .and_then(PcapWriter::new)
                .map_err(|error| cannot_create("pcap trace", path, error))
        })
        .transpose()?;
    let mut event_log = args
        .events
        .as_ref()
        .map(|path| {
            File::create(path)
                .map(BufWriter::new)
                .map_err(|error| cannot_create("event log", path, error))
        })
        .transpose()?;
    let mut outputs = events::Outputs::default();
    let epoch = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64);
    let start = std::time::Instant::now();
    let host = || Instant::from_micros(start.elapsed().as_micros() as u64);
    // The bus, the traces and the control port run on the virtual time: the host's clock,
    // held back while a paced participant lags (`can_hub::pace`); unpaced, they are the same.
    let mut pacer = Pacer::new(
        shared::Duration::from_micros(args.lookahead),
        shared::Duration::from_micros(args.grant_period),
    );
    let paced = |id: usize| args.paced && id < names.len();
    let seconds = |at: Instant| at.as_micros() as f64 / 1e6;
    let mut hosts = Hosts {
        names: names.clone(),
        writers: HashMap::new(),
        backlogs: HashMap::new(),
        controls: HashMap::new(),
        links,
        tools: HashMap::new(),
        departing: Vec::new(),
        load: None,
    };
    let mut wake: Option<Instant> = None;
    let mut next_report = Instant::ZERO;
    loop {
        let now = pacer.advance(host());
        // The virtual time runs at most as fast as the host's; held, an acknowledgement
        // (input) wakes the loop; at the latest after a resend period.
        let timeout = match [wake, pacer.next_grant()].into_iter().flatten().min() {
            Some(at) => Duration::from_micros(
                at.as_micros()
                    .saturating_sub(now.as_micros())
                    .clamp(100, pace::RESEND.as_micros()),
            ),
            None => Duration::from_micros(pace::RESEND.as_micros()),
        };
        match rx.recv_timeout(timeout) {
            Ok(Input::Joined(id, writer, pending)) => {
                hub.join(id);
                if paced(id) {
                    pacer.join(id);
                }
                hosts.writers.insert(id, writer);
                hosts.backlogs.insert(id, (Vec::new(), pending));
            }
            Ok(Input::Bytes(id, bytes)) => {
                if let Some((backlog, _)) = hosts.backlogs.get_mut(&id) {
                    backlog.extend_from_slice(&bytes);
                }
            }
            Ok(Input::ToolJoined(id, stream, pending)) => {
                hub.join_socketcand(id, TOOL_BUS);
                if let Ok(closer) = stream.try_clone() {
                    hosts.tools.insert(id, closer);
                }
                hosts.writers.insert(id, Box::new(stream));
                hosts.backlogs.insert(id, (Vec::new(), pending));
            }
            // A socketcand client that closed its connection still has its frames sent: what
            // it wrote before closing was handed to the bus, as a socketcand daemon writes
            // it to its CAN socket (a script that sends and exits loses nothing). An emulated
            // MCU that ends is a controller gone, its queue with it.
            Ok(Input::Left(id)) if hosts.tools.remove(&id).is_some() => {
                hosts.writers.remove(&id);
                hosts.departing.push(id);
            }
            Ok(Input::Left(id)) => {
                hub.leave(id);
                pacer.leave(id);
                hosts.writers.remove(&id);
                hosts.backlogs.remove(&id);
            }
            Ok(Input::ControlJoined(client, writer)) => {
                hosts.controls.insert(client, writer);
            }
            Ok(Input::Control(client, line)) => {
                let at = pacer.advance(host());
                let reply = match line
                    .and_then(|line| Command::parse(&line))
                    .and_then(|command| hosts.apply(hub, at, &command).map(|()| command))
                {
                    Ok(command) => format!("ok {command} t={:.6}", seconds(at)),
                    Err(why) => format!("error {why}"),
                };
                let gone = hosts
                    .controls
                    .get_mut(&client)
                    .is_some_and(|writer| writeln!(writer, "{reply}").is_err());
                if gone {
                    hosts.controls.remove(&client);
                }
            }
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => return Ok(()),
        }
        // Bytes first (frames join their senders' FIFOs), then the bus; arbitration makes room,
        // so waiting bytes are offered again and the bus asked once more.
        let now = pacer.advance(host());
        hosts.feed(hub, now);
        for (id, time) in hub.acknowledgements.drain(..) {
            pacer.acknowledged(id, time, host());
        }
        let now = pacer.advance(host());
        hosts.generate(hub, now);
        let (mut out, mut next) = hub.poll(now);
        if hosts.feed(hub, now) {
            let (more, later) = hub.poll(now);
            out.extend(more);
            next = later;
        }
        wake = next.into_iter().chain(hosts.load_deadline(hub)).min();
        // Link messages go to the other end at once, in the order they came, on the same
        // line as the frames (so before any grant that follows them).
        let links: Vec<_> = hub.links.drain(..).collect();
        for (from, bytes) in links {
            let Some(&to) = hosts.links.peer.get(&from) else {
                let name = hosts.names.get(from).map_or("a tool", String::as_str);
                eprintln!("can-hub: {name} (participant {from}) sent link bytes but has no --link");
                continue;
            };
            if !hosts.links.cut.contains(&from) {
                out.push(can_hub::hub::Outgoing {
                    to,
                    bytes: Hub::link(&bytes),
                });
            }
        }
        for outgoing in out {
            hosts.write(hub, &mut pacer, outgoing.to, &outgoing.bytes);
        }
        // After every frame and link message up to `now`: the grant of `now`.
        for id in pacer.grants_due(host()) {
            hosts.write(hub, &mut pacer, id, &Hub::grant(now));
        }
        if args.paced && host() >= next_report {
            next_report = host() + shared::Duration::from_millis(1000);
            hosts.tell_controls(&control::pace_line(&pacer.report(host())));
            if let Some((id, acknowledged)) = pacer.slowest() {
                let name = hosts.names.get(id).map_or("?", String::as_str).to_string();
                hosts.tell_controls(&control::slowest_line(&name, seconds(acknowledged)));
            }
        }
        let gone: Vec<usize> = hosts
            .departing
            .iter()
            .copied()
            .filter(|id| {
                hosts
                    .backlogs
                    .get(id)
                    .is_none_or(|(bytes, _)| bytes.is_empty())
                    && hub.queued(*id) == 0
            })
            .collect();
        for id in gone {
            hosts.departing.retain(|departing| *departing != id);
            hosts.backlogs.remove(&id);
            hub.leave(id);
        }
        let closing: Vec<usize> = hub.closing.drain(..).collect();
        for id in closing {
            // The reader thread then sees the end of the stream and reports the departure.
            if let Some(stream) = hosts.tools.remove(&id) {
                let _ = stream.shutdown(Shutdown::Both);
            }
            hosts.writers.remove(&id);
            hosts.backlogs.remove(&id);
            hub.leave(id);
        }
        let load_sender = hosts.load_sender();
        let mut logged: Vec<(Instant, String)> = Vec::new();
        for (at, frame, from) in hub.completed.drain(..) {
            if let Some(load) = hosts.load.as_mut() {
                load.completed(&frame, from == load_sender);
            }
            let stamp = epoch + at.as_micros();
            if let Some(candump) = candump.as_mut() {
                writeln!(candump, "{}", candump_line(stamp, "can0", &frame))?;
                candump.flush()?;
            }
            if let Some(pcap) = pcap.as_mut() {
                pcap.write(stamp, &frame)?;
                pcap.flush()?;
            }
            if event_log.is_some() {
                logged.push((at, events::frame_line(at, &hosts.sender_name(from), &frame)));
            }
        }
        let statuses: Vec<_> = hub.statuses.drain(..).collect();
        for (at, id, status) in statuses {
            let name = hosts
                .names
                .get(id)
                .cloned()
                .unwrap_or_else(|| format!("tool{id}"));
            if event_log.is_some()
                && let Some(line) = outputs.report(at, &name, status.output)
            {
                logged.push((at, line));
            }
            hosts.tell_controls(&status_line(&name, seconds(at), &status));
        }
        // In time order: this round's reports were taken before its frames ended.
        if let Some(log) = event_log.as_mut() {
            logged.sort_by_key(|(at, _)| *at);
            for (_, line) in logged.drain(..) {
                writeln!(log, "{line}")?;
            }
            log.flush()?;
        }
        for (at, id, frame) in hub.overflowed.drain(..) {
            let name = hosts.names.get(id).map_or("?", String::as_str);
            eprintln!(
                "can-hub: {name}'s transmit queue is full ({} frames waiting for the bus) at \
                 t={:.6} s: its frame {:03X}h is dropped, as board::hw drops a frame its full \
                 transmit queue refuses",
                can_hub::bus::TRANSMIT_QUEUE,
                seconds(at),
                frame.id().raw()
            );
        }
        for (id, error) in hub.malformed.drain(..) {
            eprintln!("can-hub: participant {id}: a message refused: {error}");
        }
    }
}
