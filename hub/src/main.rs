//! `can-hub`: the emulated CAN bus between QEMU instances (each one's USART2 on a Unix socket)
//! and tools (TCP on loopback), in real time, with candump and pcap traces.
//!
//! ```text
//! can-hub --socket /tmp/bus/node1a.sock --socket /tmp/bus/node1b.sock --tcp 127.0.0.1:29536 \
//!         --candump bus.log --pcap bus.pcap --bit-rate 500000
//! ```
//!
//! Every participant speaks CAN-over-serial (`dual_channel::can_serial`). The hub listens on
//! each `--socket` path for one QEMU instance (start QEMU with `-chardev
//! socket,id=can,path=PATH` and `-serial null -serial chardev:can`), and accepts any number of
//! tool connections on `--tcp`. It runs until killed.

use can_hub::bus::{BIT_RATES, Fault, Injection, Match};
use can_hub::hub::Hub;
use can_hub::trace::{PcapWriter, candump_line};
use clap::Parser;
use shared::Instant;
use std::collections::HashMap;
use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::net::TcpListener;
use std::os::unix::net::UnixListener;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

#[derive(Parser)]
#[command(about = "Emulated CAN bus: arbitration, bit time, faults, traces")]
struct Args {
    /// Bit rate in bit/s: 125000, 250000, 500000 or 1000000.
    #[arg(long, default_value_t = 500_000)]
    bit_rate: u32,
    /// A Unix socket path to listen on for one QEMU instance (repeatable).
    #[arg(long)]
    socket: Vec<PathBuf>,
    /// A TCP address to accept tools on (e.g. 127.0.0.1:29536).
    #[arg(long)]
    tcp: Option<String>,
    /// Write a candump log here.
    #[arg(long)]
    candump: Option<PathBuf>,
    /// Write a pcap (SocketCAN link type) here.
    #[arg(long)]
    pcap: Option<PathBuf>,
    /// Drop the next frame with this identifier after this many seconds: `0x102@2.5`
    /// (repeatable).
    #[arg(long)]
    drop: Vec<String>,
}

/// What the connection threads tell the hub.
enum Input {
    Joined(usize, Box<dyn Write + Send>),
    Bytes(usize, Vec<u8>),
    Left(usize),
}

fn reader(id: usize, mut stream: impl Read, tx: Sender<Input>) {
    let mut buf = [0u8; 256];
    loop {
        match stream.read(&mut buf) {
            Ok(0) | Err(_) => {
                let _ = tx.send(Input::Left(id));
                return;
            }
            Ok(n) => {
                if tx.send(Input::Bytes(id, buf[..n].to_vec())).is_err() {
                    return;
                }
            }
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

fn main() -> ExitCode {
    let args = Args::parse();
    if !BIT_RATES.contains(&args.bit_rate) {
        eprintln!(
            "can-hub: --bit-rate {} is not one of {BIT_RATES:?}",
            args.bit_rate
        );
        return ExitCode::from(2);
    }
    let mut hub = Hub::new(args.bit_rate);
    for spec in &args.drop {
        match parse_drop(spec) {
            Ok((id, at)) => hub.inject(Injection::new(
                Match::next_with_id(id, Instant::from_micros((at * 1e6) as u64)),
                Fault::Drop,
            )),
            Err(message) => {
                eprintln!("can-hub: {message}");
                return ExitCode::from(2);
            }
        }
    }
    let (tx, rx) = mpsc::channel();
    let mut next_id = 0usize;
    for path in &args.socket {
        let _ = std::fs::remove_file(path);
        let listener = match UnixListener::bind(path) {
            Ok(listener) => listener,
            Err(error) => {
                eprintln!("can-hub: cannot listen on {}: {error}", path.display());
                return ExitCode::from(2);
            }
        };
        let id = next_id;
        next_id += 1;
        let tx = tx.clone();
        std::thread::spawn(move || {
            if let Ok((stream, _)) = listener.accept() {
                if let Ok(writer) = stream.try_clone() {
                    let _ = tx.send(Input::Joined(id, Box::new(writer)));
                    reader(id, stream, tx);
                }
            }
        });
    }
    if let Some(address) = &args.tcp {
        let listener = match TcpListener::bind(address) {
            Ok(listener) => listener,
            Err(error) => {
                eprintln!("can-hub: cannot listen on {address}: {error}");
                return ExitCode::from(2);
            }
        };
        let tx = tx.clone();
        let first = next_id;
        std::thread::spawn(move || {
            for (offset, stream) in listener.incoming().enumerate() {
                let Ok(stream) = stream else { continue };
                let _ = stream.set_nodelay(true);
                let id = first + offset;
                if let Ok(writer) = stream.try_clone() {
                    let _ = tx.send(Input::Joined(id, Box::new(writer)));
                    let tx = tx.clone();
                    std::thread::spawn(move || reader(id, stream, tx));
                }
            }
        });
    }
    drop(tx);
    match run(&mut hub, &rx, &args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("can-hub: {error}");
            ExitCode::FAILURE
        }
    }
}

fn run(hub: &mut Hub, rx: &Receiver<Input>, args: &Args) -> std::io::Result<()> {
    let mut candump = args
        .candump
        .as_ref()
        .map(|path| File::create(path).map(BufWriter::new))
        .transpose()?;
    let mut pcap = args
        .pcap
        .as_ref()
        .map(|path| {
            File::create(path)
                .map(BufWriter::new)
                .and_then(PcapWriter::new)
        })
        .transpose()?;
    let epoch = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64);
    let start = std::time::Instant::now();
    let now = || Instant::from_micros(start.elapsed().as_micros() as u64);
    let mut writers: HashMap<usize, Box<dyn Write + Send>> = HashMap::new();
    let mut wake: Option<Instant> = None;
    loop {
        let timeout = wake.map_or(Duration::from_millis(100), |at| {
            Duration::from_micros(at.as_micros().saturating_sub(now().as_micros()))
        });
        match rx.recv_timeout(timeout) {
            Ok(Input::Joined(id, writer)) => {
                hub.join(id);
                writers.insert(id, writer);
            }
            Ok(Input::Bytes(id, bytes)) => hub.receive(now(), id, &bytes),
            Ok(Input::Left(id)) => {
                hub.leave(id);
                writers.remove(&id);
            }
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => return Ok(()),
        }
        let (out, next) = hub.poll(now());
        wake = next;
        for outgoing in out {
            let failed = writers
                .get_mut(&outgoing.to)
                .is_some_and(|writer| writer.write_all(&outgoing.bytes).is_err());
            if failed {
                writers.remove(&outgoing.to);
                hub.leave(outgoing.to);
            }
        }
        for (at, frame, _) in hub.completed.drain(..) {
            let stamp = epoch + at.as_micros();
            if let Some(candump) = candump.as_mut() {
                writeln!(candump, "{}", candump_line(stamp, "can0", &frame))?;
                candump.flush()?;
            }
            if let Some(pcap) = pcap.as_mut() {
                pcap.write(stamp, &frame)?;
                pcap.flush()?;
            }
        }
        for (id, error) in hub.malformed.drain(..) {
            eprintln!("can-hub: participant {id}: {error:?}");
        }
    }
}
