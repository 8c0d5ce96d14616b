//! A socketcand server in front of the host simulation (`cargo xtask interop`): nodes 1 and 33
//! of `system_tests::network`, configured by the tool library (node 33 consumes node 1's
//! SRDO 1) and started, then run in real time while socketcand clients (python-canopen, the
//! tool) join the simulated bus, served by the tool crate's own server session. No emulated
//! MCU: the same protocol core as the firmware, without the emulation's timing.
//!
//! Usage: `socketcand_sim PORT` (listens on 127.0.0.1:PORT, bus `can0`; runs until killed).
//! `socketcand_sim PORT --lss N`: instead, N devices with the LSS slave enabled and no
//! node-ID (`Network::unconfigured_lss`, serial numbers 1 to N), left to an LSS master (the
//! interop case of python-canopen's `LssMaster`; the firmware images carry no LSS).

use safety_config::network_file;
use safety_config::procedure::{self, Quiet};
use safety_config::socketcand::server::{GREETING, Output, Session};
use shared::canopen::nmt::NmtCommand;
use shared::{CanFrame, Duration};
use std::io::{ErrorKind, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::process::ExitCode;
use system_tests::network::Network;
use system_tests::tool_bus::client;

/// The simulated network's file: node 1's SRDO 1 transmits on 101h/102h every 100 ms, node
/// 33's SRDO 1 consumes it (SCT 500 ms, SRVT 100 ms), as on the emulated network.
const FILE: &str = r#"
[[node]]
id = 1
identity = { vendor = 0xABC, product = 0x304, revision = 1, serial = 1 }

[[node.srdo]]
number = 1
direction = "transmit"
refresh_time_ms = 100
srvt_ms = 20
cob_ids = [0x101, 0x102]
mapping = ["input", "input_inverted"]

[[node]]
id = 33
identity = { vendor = 0xABC, product = 0x304, revision = 1, serial = 33 }

[[node.srdo]]
number = 1
direction = "receive"
sct_ms = 500
srvt_ms = 100
cob_ids = [0x101, 0x102]
mapping = ["output", "output_inverted"]
"#;

/// One connected client.
struct Client {
    stream: TcpStream,
    session: Session,
    /// Frames it sent that have not yet come by in the trace (not echoed back to it).
    echoes: Vec<CanFrame>,
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("socketcand_sim: {error}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> Result<(), String> {
    const USAGE: &str = "usage: socketcand_sim PORT [--lss NODES]";
    let args: Vec<String> = std::env::args().skip(1).collect();
    let port: u16 = args
        .first()
        .and_then(|port| port.parse().ok())
        .ok_or(USAGE)?;
    let net = match args.get(1..).unwrap_or_default() {
        [] => configured()?,
        [flag, count] if flag == "--lss" => {
            let count: u8 = count
                .parse()
                .ok()
                .filter(|count| (1..=127).contains(count))
                .ok_or("--lss takes a number of nodes, 1 to 127")?;
            let mut net = Network::unconfigured_lss(safety_device::BIT_RATE, count);
            net.run_for(Duration::from_millis(50));
            eprintln!("socketcand_sim: {count} unconfigured LSS nodes");
            net
        }
        _ => return Err(USAGE.into()),
    };
    serve_network(net, port)
}

/// Nodes 1 and 33 configured by the tool library from [`FILE`], Operational.
fn configured() -> Result<Network, String> {
    let name = safety_device::CHANNEL_A_NAME;
    let mut net = Network::new(safety_device::BIT_RATE, &[(1, name), (33, name)]);
    net.run_for(Duration::from_millis(50));
    let file = network_file::parse(FILE, "socketcand_sim").map_err(|e| e.to_string())?;
    let mut quiet = Quiet {
        accept_identity: false,
    };
    let producer = net.index_of(1);
    net.set_input(producer, 1);
    for spec in &file.nodes {
        procedure::configure_node(&mut client(&mut net), spec, &mut quiet)
            .map_err(|e| e.to_string())?;
    }
    net.nmt(NmtCommand::Start, 0);
    net.run_for(Duration::from_millis(300));
    eprintln!("socketcand_sim: nodes 1 and 33 Operational");
    Ok(net)
}

/// Runs `net` in real time behind a socketcand server on 127.0.0.1:`port` until killed.
fn serve_network(mut net: Network, port: u16) -> Result<(), String> {
    let listener = TcpListener::bind(("127.0.0.1", port)).map_err(|e| e.to_string())?;
    listener.set_nonblocking(true).map_err(|e| e.to_string())?;
    eprintln!("socketcand_sim: socketcand on 127.0.0.1:{port}");
    let origin = net.now;
    let wall = std::time::Instant::now();
    let mut clients: Vec<Client> = Vec::new();
    let mut cursor = net.trace.len();
    loop {
        match listener.accept() {
            Ok((mut stream, _)) => {
                let _ = stream.set_nodelay(true);
                let _ = stream.set_nonblocking(true);
                if stream.write_all(GREETING.as_bytes()).is_ok() {
                    clients.push(Client {
                        stream,
                        session: Session::new("can0"),
                        echoes: Vec::new(),
                    });
                }
            }
            Err(error) if error.kind() == ErrorKind::WouldBlock => {}
            Err(error) => return Err(error.to_string()),
        }
        let clock = wall.elapsed();
        clients.retain_mut(|client| serve(client, &mut net, clock));
        let now = origin + Duration::from_micros(clock.as_micros() as u64);
        net.run_until(now);
        clients.retain_mut(|client| {
            client
                .session
                .release(clock)
                .iter()
                .all(|message| client.stream.write_all(message.as_bytes()).is_ok())
        });
        while let Some(&(at, frame)) = net.trace.get(cursor) {
            cursor += 1;
            let stamp = std::time::Duration::from_micros(at.as_micros());
            clients.retain_mut(|client| {
                if let Some(position) = client.echoes.iter().position(|echo| *echo == frame) {
                    client.echoes.remove(position);
                    return true;
                }
                match client.session.frame(&frame, stamp, clock) {
                    Some(message) => client.stream.write_all(message.as_bytes()).is_ok(),
                    None => true,
                }
            });
        }
        std::thread::sleep(std::time::Duration::from_micros(500));
    }
}

/// Reads what `client` sent and serves it (`clock`: the server's time); `false` when the
/// connection ended.
fn serve(client: &mut Client, net: &mut Network, clock: std::time::Duration) -> bool {
    let mut buffer = [0u8; 1024];
    loop {
        match client.stream.read(&mut buffer) {
            Ok(0) => return false,
            Ok(count) => {
                for output in client.session.feed(&buffer[..count], clock) {
                    match output {
                        Output::Reply(text) => {
                            if client.stream.write_all(text.as_bytes()).is_err() {
                                return false;
                            }
                        }
                        Output::Send(frame) => {
                            net.bus.send(0, frame);
                            client.echoes.push(frame);
                        }
                        Output::Close => return false,
                    }
                }
            }
            Err(error) if error.kind() == ErrorKind::WouldBlock => return true,
            Err(error) if error.kind() == ErrorKind::Interrupted => {}
            Err(_) => return false,
        }
    }
}
