//! `can-hub`: the emulated CAN bus between tools (TCP on loopback), in real time, with
//! candump and pcap traces, an event log, and a control port for bus faults and load.
//!
//! ```text
//! can-hub --tcp 127.0.0.1:29536 --control 127.0.0.1:29537 \
//!         --candump bus.log --pcap bus.pcap --events events.log --bit-rate 500000
//! ```
//!
//! The hub accepts any number of tool connections on `--tcp`, which speak socketcand
//! (linux-can/socketcand `doc/protocol.md`, raw mode; the bus is named `can0`): the
//! configuration tool (`--bus socketcand:127.0.0.1:29536/can0`), python-can
//! (`interface="socketcand", host=..., port=..., channel="can0"`) and python-canopen through
//! it, all on one bus model (`can_hub::bus`: arbitration, bit time, faults). The control
//! port's line protocol is in `can_hub::control`; the hub serves its bus commands (faults,
//! `insert`, `mute`, `clear`, `load`) and refuses, in a sentence, those for emulated channels
//! (input pins, links, power), which the emulated network of the shipped images serves
//! (`emulate-network --control`). Its clock is the host's, from its start. The hub runs until
//! killed.
//!
//! Nothing a participant sends makes the hub hold more and more (`can_hub::port`). A tool
//! whose transmit FIFO is full (`can_hub::bus::TRANSMIT_QUEUE`) waits, as on a real bus: its
//! bytes stay with the hub only up to `can_hub::port::BACKLOG` bytes; past that the hub stops
//! reading its socket, so the sender's writes block. A control line is at most
//! `can_hub::control::MAX_LINE` bytes, and a tool or control client that does not read what
//! the hub writes for `can_hub::port::WRITE_TIMEOUT` is disconnected instead of stalling the
//! bus. At most `can_hub::port::MAX_CLIENTS` tools and as many control clients are connected
//! at once; one more is told so in a sentence and closed, so no number of connections makes
//! the hub hold more and more threads either.

use can_hub::bus::{BIT_RATES, Fault, Injection, Match};
use can_hub::control::Command;
use can_hub::events;
use can_hub::hub::Hub;
use can_hub::load::Load;
use can_hub::port::{Arrival, ControlEvent, ToolEvent, accept_control, accept_socketcand};
use can_hub::trace::{PcapWriter, candump_line};
use clap::Parser;
use shared::Instant;
use std::collections::HashMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
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
    /// Write the event log here: every frame with its sender, on the hub's clock
    /// (`can_hub::events`, which gives the line format).
    #[arg(long)]
    events: Option<PathBuf>,
    /// Drop the next frame with this identifier after this many seconds: `0x102@2.5`
    /// (repeatable).
    #[arg(long)]
    drop: Vec<String>,
}

/// The name of the bus a socketcand client opens (`< open can0 >`).
const TOOL_BUS: &str = "can0";

/// The participant the hub's own frames (`insert` on the control port) are sent as.
const OWN_SENDER: usize = 0;

/// The participant the generated load (`load` on the control port) is sent as: its own
/// transmit queue, so that an `insert` never waits behind the load.
const LOAD_SENDER: usize = 1;

/// The first participant number of the tools on the TCP port (the event log's `toolN`).
const FIRST_TOOL: usize = 2;

/// The longest the main loop waits for a connection's news when nothing is due on the bus.
const IDLE: Duration = Duration::from_millis(100);

/// What the connection threads tell the hub.
enum Input {
    /// A socketcand client joined on the TCP port: its connection (to write to it and to
    /// close it when the session ends), and its count of bytes not yet taken.
    ToolJoined(usize, TcpStream, Arc<AtomicUsize>),
    /// Bytes a tool sent.
    Bytes(usize, Vec<u8>),
    /// A tool closed its connection.
    Left(usize),
    /// A control client joined: how to write to it.
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

/// Why the hub cannot listen on the TCP `address`, as a sentence with what to do.
fn cannot_listen(address: &str, error: &std::io::Error) -> String {
    if error.kind() == std::io::ErrorKind::AddrInUse {
        format!(
            "cannot listen on {address}: something else listens there already (another \
             can-hub or an emulate-network, say, from a `cargo xtask` command still running); \
             stop it or give another address"
        )
    } else {
        format!("cannot listen on {address}: {error}")
    }
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
    let mut hub = Hub::new(args.bit_rate);
    for spec in &args.drop {
        let (id, at) = parse_drop(spec)?;
        hub.inject(Injection::new(
            Match::next_with_id(id, Instant::from_micros((at * 1e6) as u64)),
            Fault::Drop,
        ));
    }
    let (tx, rx) = mpsc::channel();
    if let Some(address) = &args.tcp {
        let listener = TcpListener::bind(address).map_err(|e| cannot_listen(address, &e))?;
        let tx = tx.clone();
        accept_socketcand(listener, FIRST_TOOL, "the hub", move |event| {
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
    run(&mut hub, &rx, args).map_err(|error| error.to_string())
}

/// A trace file that cannot be created, as a sentence naming it.
fn cannot_create(what: &str, path: &std::path::Path, error: std::io::Error) -> std::io::Error {
    std::io::Error::new(
        error.kind(),
        format!("cannot create the {what} {}: {error}", path.display()),
    )
}

/// The state the main loop keeps besides the hub.
#[derive(Default)]
struct Hosts {
    /// How to write to each connected tool.
    writers: HashMap<usize, TcpStream>,
    /// Bytes each tool sent that the hub has not taken yet, and the count its reader thread
    /// waits on.
    backlogs: HashMap<usize, (Vec<u8>, Arc<AtomicUsize>)>,
    controls: HashMap<usize, Box<dyn Write + Send>>,
    /// The tools' connections, to close when their session ends.
    tools: HashMap<usize, TcpStream>,
    /// Tools that closed their connection, whose frames still go on the bus.
    departing: Vec<usize>,
    /// The load the hub generates (`load` on the control port), sent as [`LOAD_SENDER`].
    load: Option<Load>,
}

impl Hosts {
    /// Queues the generated load's next frame when it is due at `now`, one at a time: the
    /// next only once the bus has taken the one before. The hub's bus runs only when its loop
    /// does, so a loop that wakes late (a loaded host) finds several frames due at once;
    /// queued together they would leave by identifier (its 281h before its 621h), the SDO
    /// requests bunched at the end and the answers to them behind. One at a time, the frames
    /// keep their turn while the load catches up, and each other sender's frame with a lower
    /// identifier than the load's next one wins the slot it competes for.
    fn generate(&mut self, hub: &mut Hub, now: Instant) {
        let Some(load) = self.load.as_mut() else {
            return;
        };
        if hub.queued(LOAD_SENDER) == 0
            && let Some(frame) = load.poll(now)
        {
            // The queue is empty: the frame is queued.
            let _ = hub.send(now, LOAD_SENDER, frame);
        }
    }

    /// When the generated load wants to be asked again (`None`: no load, or its frame is
    /// still queued and the bus's next arbitration wakes the loop anyway).
    fn load_deadline(&self, hub: &Hub) -> Option<Instant> {
        let load = self.load.as_ref()?;
        (hub.queued(LOAD_SENDER) == 0).then(|| load.deadline())
    }

    /// Participant `id` as the event log names a frame's sender (`can_hub::events`).
    fn sender_name(id: usize) -> String {
        match id {
            OWN_SENDER => "hub".to_string(),
            LOAD_SENDER => "load".to_string(),
            _ => format!("tool{id}"),
        }
    }

    /// The connected tool the event log names `name` (`tool2`).
    fn participant(&self, name: &str) -> Result<usize, String> {
        name.strip_prefix("tool")
            .and_then(|number| number.parse().ok())
            .filter(|id| self.writers.contains_key(id))
            .ok_or_else(|| {
                let mut tools: Vec<usize> = self.writers.keys().copied().collect();
                tools.sort_unstable();
                let tools: Vec<String> = tools.iter().map(|id| Self::sender_name(*id)).collect();
                format!(
                    "no participant `{name}`: the hub's participants are its connected tools, \
                     named as in the event log (now: {})",
                    if tools.is_empty() {
                        "none".to_string()
                    } else {
                        tools.join(", ")
                    }
                )
            })
    }

    /// Carries out one control command at `now`.
    fn apply(&mut self, hub: &mut Hub, now: Instant, command: &Command) -> Result<(), String> {
        let next = |id| Match::next_with_id(id, now);
        match command {
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
                hub.send(now, OWN_SENDER, frame).map_err(|_| {
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
            Command::Clear => hub.retain_faults(|_| false),
            Command::Input { .. }
            | Command::Cut(_)
            | Command::Restore(_)
            | Command::PowerCycle(_) => {
                return Err(format!(
                    "the hub has no emulated channel, so no input pin, link or power supply \
                     (`{command}` is for the emulated STM32F405s of `emulate-network`)"
                ));
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
                hub.leave(LOAD_SENDER);
                self.load = Some(load);
            }
            Command::LoadOff => {
                let load = self.load.take().ok_or("no load is running")?;
                hub.leave(LOAD_SENDER);
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

    /// Hands each tool's waiting bytes to the hub as far as its transmit FIFO has room;
    /// `true` when any were taken.
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

    /// Writes `bytes` to tool `to`. A tool whose end of the connection is closed is written
    /// to no more, and leaves when its reader reports the end of its stream, after the bytes
    /// it sent before closing (its last frames still go on the bus); one that does not read
    /// for `can_hub::port::WRITE_TIMEOUT` leaves at once.
    fn write(&mut self, hub: &mut Hub, to: usize, bytes: &[u8]) {
        let Some(writer) = self.writers.get_mut(&to) else {
            return;
        };
        match writer.write_all(bytes) {
            Ok(()) => {}
            Err(error) if can_hub::port::peer_closed(&error) => {
                self.writers.remove(&to);
            }
            Err(_) => {
                self.writers.remove(&to);
                hub.leave(to);
            }
        }
    }
}

fn run(hub: &mut Hub, rx: &Receiver<Input>, args: &Args) -> std::io::Result<()> {
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
    let epoch = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64);
    // The bus, the traces and the control port run on the host's clock since the start.
    let start = std::time::Instant::now();
    let host = || Instant::from_micros(start.elapsed().as_micros() as u64);
    let seconds = |at: Instant| at.as_micros() as f64 / 1e6;
    let mut hosts = Hosts::default();
    let mut wake: Option<Instant> = None;
    loop {
        let now = host();
        let timeout = wake.map_or(IDLE, |at| {
            Duration::from_micros(at.as_micros().saturating_sub(now.as_micros()))
                .clamp(Duration::from_micros(100), IDLE)
        });
        match rx.recv_timeout(timeout) {
            Ok(Input::Bytes(id, bytes)) => {
                if let Some((backlog, _)) = hosts.backlogs.get_mut(&id) {
                    backlog.extend_from_slice(&bytes);
                }
            }
            Ok(Input::ToolJoined(id, stream, pending)) => {
                hub.join_socketcand(id, TOOL_BUS);
                if let Ok(writer) = stream.try_clone() {
                    hosts.writers.insert(id, writer);
                }
                hosts.tools.insert(id, stream);
                hosts.backlogs.insert(id, (Vec::new(), pending));
            }
            // A tool that closed its connection still has its frames sent: what it wrote
            // before closing was handed to the bus, as a socketcand daemon writes it to its
            // CAN socket (a script that sends and exits loses nothing).
            Ok(Input::Left(id)) => {
                hosts.tools.remove(&id);
                hosts.writers.remove(&id);
                hosts.departing.push(id);
            }
            Ok(Input::ControlJoined(client, writer)) => {
                hosts.controls.insert(client, writer);
            }
            Ok(Input::Control(client, line)) => {
                let at = host();
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
        let now = host();
        hosts.feed(hub, now);
        hosts.generate(hub, now);
        let (mut out, mut next) = hub.poll(now);
        if hosts.feed(hub, now) {
            let (more, later) = hub.poll(now);
            out.extend(more);
            next = later;
        }
        wake = next.into_iter().chain(hosts.load_deadline(hub)).min();
        for outgoing in out {
            hosts.write(hub, outgoing.to, &outgoing.bytes);
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
        let mut logged: Vec<(Instant, String)> = Vec::new();
        for (at, frame, from) in hub.completed.drain(..) {
            if let Some(load) = hosts.load.as_mut() {
                load.completed(&frame, from == LOAD_SENDER);
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
                logged.push((
                    at,
                    events::frame_line(at, &Hosts::sender_name(from), &frame),
                ));
            }
        }
        // In time order: a round hands frames out in the order they went on the bus, and a
        // delayed one ends later than that.
        if let Some(log) = event_log.as_mut() {
            logged.sort_by_key(|(at, _)| *at);
            for (_, line) in logged {
                writeln!(log, "{line}")?;
            }
            log.flush()?;
        }
    }
}
