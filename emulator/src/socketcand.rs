//! The emulated network's socketcand port: separate programs (python-can's `socketcand`
//! interface, python-canopen through it, the configuration tool's `--bus socketcand:...`)
//! join the bus of the shipped images as they join `can-hub`'s.
//!
//! - [`Port`], sans-I/O: each client is a session of the tool crate's socketcand server
//!   ([`safety_config::socketcand::server`], the one `can-hub` serves) and an external
//!   participant of the [`Network`]; fed a client's bytes, it puts its frames on the bus and
//!   hands back the replies, and hands out the frames the bus delivered to each client.
//! - [`Server`]: the port on TCP ([`can_hub::port`]: the accepting thread, a reader thread per
//!   client, the bounds on clients, backlog and blocked writes, as `can-hub` has them), and
//!   the network run at the pace of the host clock: third-party tools time out on the wall
//!   clock, so the virtual time never runs ahead of it ([`can_hub::pace::Pacer`], with the
//!   network as its one paced participant, granted time and acknowledging it, with
//!   [`can_hub::pace::LOOKAHEAD`] and [`can_hub::pace::GRANT_PERIOD`]). When the host cannot
//!   keep up, the virtual time falls behind and does not race to catch up: the pacer counts
//!   the time it was held.

use std::collections::BTreeMap;
use std::io::Write as _;
use std::net::{Shutdown, TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError};

use can_hub::hub::Outgoing;
use can_hub::pace::{PaceReport, Pacer};
use can_hub::port::{Arrival, ToolEvent};
use safety_config::socketcand::server::{self, Output, Session};

use crate::network::Network;
use crate::time::Nanos;

/// The name of the bus a client opens (`< open can0 >`), as on `can-hub`.
pub const BUS: &str = "can0";

/// The network's virtual time as a session's clock.
fn clock(at: Nanos) -> std::time::Duration {
    std::time::Duration::from_nanos(at)
}

/// One client: its session and its participant on the network.
struct Client {
    session: Session,
    participant: usize,
}

/// The socketcand clients of one network, by the program's number for each connection.
#[derive(Default)]
pub struct Port {
    clients: BTreeMap<usize, Client>,
    /// Replies not yet handed out by [`Port::poll`].
    replies: Vec<Outgoing>,
    /// Clients whose session ended (an `open` of another bus, a message that never ends):
    /// the program closes their connections after writing what [`Port::poll`] handed out.
    pub closing: Vec<usize>,
}

impl Port {
    /// A port with no client.
    pub fn new() -> Port {
        Port::default()
    }

    /// Client `client` connected: it joins the bus as an external participant named
    /// `socketcand<client>`; its greeting is handed out by the next [`Port::poll`], bus
    /// frames only once it has switched to raw mode.
    pub fn join(&mut self, network: &mut Network, client: usize) {
        let participant = network.join_external(&format!("socketcand{client}"));
        self.clients.insert(
            client,
            Client {
                session: Session::new(BUS),
                participant,
            },
        );
        self.replies.push(Outgoing {
            to: client,
            bytes: server::GREETING.as_bytes().to_vec(),
        });
    }

    /// Client `client`'s bytes, one message at a time, at the network's present time: its
    /// commands are served (replies by the next [`Port::poll`]) and its frames queued on the
    /// bus. Returns how many bytes were taken: the intake stops before a message once the
    /// client's transmit queue is full ([`Network::has_room`]), and the caller hands the rest
    /// again after the bus has taken frames. Nothing for a client that is not connected.
    pub fn receive(&mut self, network: &mut Network, client: usize, bytes: &[u8]) -> usize {
        let Some(joined) = self.clients.get_mut(&client) else {
            return 0;
        };
        let now = clock(network.now());
        let mut taken = 0;
        while taken < bytes.len() {
            if !network.has_room(joined.participant) || self.closing.contains(&client) {
                break;
            }
            let end = taken + server::first_message(&bytes[taken..]);
            for output in joined.session.feed(&bytes[taken..end], now) {
                match output {
                    Output::Reply(text) => self.replies.push(Outgoing {
                        to: client,
                        bytes: text.into_bytes(),
                    }),
                    Output::Send(frame) => network.send(joined.participant, frame),
                    Output::Close => self.closing.push(client),
                }
            }
            taken = end;
        }
        taken
    }

    /// Client `client` left: nothing more is kept for it (the frames it queued still go on
    /// the bus, as a socketcand daemon writes what it was sent to its CAN socket).
    pub fn leave(&mut self, network: &mut Network, client: usize) {
        if let Some(joined) = self.clients.remove(&client) {
            network.leave_external(joined.participant);
        }
        self.replies.retain(|reply| reply.to != client);
        self.closing.retain(|closing| *closing != client);
    }

    /// What to write now, each in a write of its own: replies first, then the frames the bus
    /// delivered to each client in raw mode as `frame` messages stamped with their end on
    /// the bus (held within the raw-mode grace after the `rawmode` reply, and released
    /// when it is over; dropped before raw mode).
    pub fn poll(&mut self, network: &mut Network) -> Vec<Outgoing> {
        let now = clock(network.now());
        let mut out = std::mem::take(&mut self.replies);
        for (&to, joined) in &mut self.clients {
            let message = |text: String| Outgoing {
                to,
                bytes: text.into_bytes(),
            };
            out.extend(joined.session.release(now).into_iter().map(message));
            while let Some(delivery) = network.receive(joined.participant) {
                let at = std::time::Duration::from_micros(delivery.at.as_micros());
                if let Some(text) = joined.session.frame(&delivery.frame, at, now) {
                    out.push(message(text));
                }
            }
        }
        out
    }
}

/// The longest stretch of virtual time the network runs between two looks at the sockets: a
/// request waits at most this long before it is on the bus.
const STEP: Nanos = 1_000_000;

/// A connected client's connection and the bytes it sent that the port has not taken.
struct Connection {
    stream: TcpStream,
    backlog: Vec<u8>,
    pending: Arc<AtomicUsize>,
    /// The client closed its connection; it is forgotten once its bytes are taken.
    departed: bool,
    /// A write found the client's end closed: nothing more is written to it, and the bytes
    /// it sent before it closed still go on the bus, up to the end of its stream
    /// ([`Connection::departed`], which the reader thread reports after them).
    closed: bool,
}

/// The socketcand port on TCP, with the network paced to the host clock.
pub struct Server {
    port: Port,
    events: Receiver<ToolEvent>,
    connections: BTreeMap<usize, Connection>,
    pacer: Pacer,
    started: std::time::Instant,
    /// The network's time when the pacer's was zero.
    origin: Nanos,
    /// The grant of virtual time the network is running to, until it reaches it.
    granted: Option<shared::Instant>,
    /// How many clients connected.
    joined: usize,
    /// Clients that came and went, in sentences, until [`Server::take_notes`].
    notes: Vec<String>,
    /// The address it listens on.
    local: std::net::SocketAddr,
}

/// The participant number of the network in the pacer.
const NETWORK: usize = 0;

impl Server {
    /// Listens on `address` (`127.0.0.1:29536`); the network's time from now on follows the
    /// host clock, starting from `network`'s present time.
    pub fn listen(address: &str, network: &Network) -> Result<Server, String> {
        let cannot = |error: std::io::Error| {
            format!("cannot listen for socketcand clients on {address}: {error}")
        };
        let listener = TcpListener::bind(address).map_err(cannot)?;
        let local = listener.local_addr().map_err(cannot)?;
        let (tx, events) = mpsc::channel();
        can_hub::port::accept_socketcand(listener, 0, "the emulated network", move |event| {
            tx.send(event).is_ok()
        });
        let mut pacer = Pacer::new(can_hub::pace::LOOKAHEAD, can_hub::pace::GRANT_PERIOD);
        pacer.join(NETWORK);
        Ok(Server {
            port: Port::new(),
            events,
            connections: BTreeMap::new(),
            pacer,
            started: std::time::Instant::now(),
            origin: network.now(),
            granted: None,
            joined: 0,
            notes: Vec::new(),
            local,
        })
    }

    /// The address it listens on (the port chosen, when asked for port 0).
    pub fn local_addr(&self) -> std::net::SocketAddr {
        self.local
    }

    /// The host clock, on the pacer's scale.
    fn host(&self) -> shared::Instant {
        shared::Instant::from_micros(self.started.elapsed().as_micros() as u64)
    }

    /// How many clients connected so far.
    pub fn clients_joined(&self) -> usize {
        self.joined
    }

    /// Clients that connected, left or were disconnected since the last call, in sentences
    /// with the virtual time.
    pub fn take_notes(&mut self) -> Vec<String> {
        std::mem::take(&mut self.notes)
    }

    /// Notes `what` happened to client `id` now.
    fn note(&mut self, network: &Network, id: usize, what: &str) {
        self.notes.push(format!(
            "client {id} {what} at {:.6} s of virtual time",
            network.now() as f64 / 1e9
        ));
    }

    /// What the pacing did so far: how far the virtual time is behind the host clock, how
    /// long it was held at most because the network could not keep up.
    pub fn pace_report(&self) -> PaceReport {
        self.pacer.report(self.host())
    }

    /// Runs `network` until virtual time `until` at the pace of the host clock (never ahead
    /// of it), serving the clients meanwhile: their bytes go on the bus as they come, the
    /// frames the bus delivers go out to them at the end of each step.
    pub fn run_until(&mut self, network: &mut Network, until: Nanos) {
        while network.now() < until {
            self.take_events(network, None);
            self.feed(network);
            let target = self.pacer.advance(self.host());
            if !self.pacer.grants_due(self.host()).is_empty() {
                self.granted = Some(self.pacer.now());
            }
            let limit = (self.origin + target.as_micros() * 1_000).min(until);
            if network.now() < limit {
                network.run_until(limit.min(network.now() + STEP));
            }
            if let Some(granted) = self.granted
                && network.now() >= self.origin + granted.as_micros() * 1_000
            {
                self.pacer.acknowledged(NETWORK, granted, self.host());
                self.granted = None;
            }
            self.exchange(network);
            if network.now() >= limit && network.now() < until {
                // Ahead of the host clock: wait for it, or for a client.
                self.take_events(network, Some(std::time::Duration::from_nanos(STEP)));
            }
        }
    }

    /// Handles what the connection threads reported; with `wait`, waits that long for the
    /// first report.
    fn take_events(&mut self, network: &mut Network, wait: Option<std::time::Duration>) {
        if let Some(wait) = wait {
            match self.events.recv_timeout(wait) {
                Ok(event) => self.handle(network, event),
                Err(RecvTimeoutError::Timeout | RecvTimeoutError::Disconnected) => return,
            }
        }
        while let Ok(event) = self.events.try_recv() {
            self.handle(network, event);
        }
    }

    fn handle(&mut self, network: &mut Network, event: ToolEvent) {
        match event {
            ToolEvent::Joined {
                id,
                stream,
                pending,
            } => {
                self.joined += 1;
                self.note(network, id, "connected");
                self.port.join(network, id);
                self.connections.insert(
                    id,
                    Connection {
                        stream,
                        backlog: Vec::new(),
                        pending,
                        departed: false,
                        closed: false,
                    },
                );
                self.exchange(network);
            }
            ToolEvent::Arrival(Arrival::Bytes(id, bytes)) => {
                if let Some(connection) = self.connections.get_mut(&id) {
                    connection.backlog.extend_from_slice(&bytes);
                }
            }
            ToolEvent::Arrival(Arrival::Left(id)) => {
                if let Some(connection) = self.connections.get_mut(&id) {
                    connection.departed = true;
                }
            }
        }
    }

    /// Hands each client's waiting bytes to the port as far as its transmit queue has room;
    /// forgets the clients that left once their bytes are taken.
    fn feed(&mut self, network: &mut Network) {
        let mut gone = Vec::new();
        for (&id, connection) in &mut self.connections {
            if !connection.backlog.is_empty() {
                let taken = self.port.receive(network, id, &connection.backlog);
                connection.backlog.drain(..taken);
                connection.pending.fetch_sub(taken, Ordering::AcqRel);
            }
            if connection.departed && connection.backlog.is_empty() {
                gone.push(id);
            }
        }
        for id in gone {
            self.connections.remove(&id);
            self.port.leave(network, id);
            self.note(network, id, "left");
        }
    }

    /// Writes what the port hands out; closes the sessions that ended and the connections
    /// that cannot be written to (a client that does not read for
    /// [`can_hub::port::WRITE_TIMEOUT`]).
    fn exchange(&mut self, network: &mut Network) {
        let mut failed = Vec::new();
        for outgoing in self.port.poll(network) {
            let Some(connection) = self.connections.get_mut(&outgoing.to) else {
                continue;
            };
            if connection.departed || connection.closed {
                continue;
            }
            match connection.stream.write_all(&outgoing.bytes) {
                Ok(()) => {}
                // A client that sent its last frame and closed (the configuration tool after
                // its NMT start, say) is not cut off: the frame may still be on its way from
                // the reader thread, and dropping the connection here lost it.
                Err(error) if can_hub::port::peer_closed(&error) => connection.closed = true,
                Err(_) => failed.push(outgoing.to),
            }
        }
        let closing: Vec<usize> = self.port.closing.drain(..).collect();
        let ended = closing
            .into_iter()
            .map(|id| {
                (
                    id,
                    "was disconnected: its session ended (an error was sent to it)",
                )
            })
            .chain(failed.into_iter().map(|id| {
                (
                    id,
                    "was disconnected: it did not read what was written to it",
                )
            }));
        for (id, why) in ended.collect::<Vec<_>>() {
            if let Some(connection) = self.connections.remove(&id) {
                // The reader thread then sees the end of the stream and reports it.
                let _ = connection.stream.shutdown(Shutdown::Both);
            }
            self.port.leave(network, id);
            self.note(network, id, why);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A network of no MCU: the bus alone, with its external participants.
    fn bus_only() -> Network {
        Network::new(Vec::new(), 500_000).expect("a network of no MCU")
    }

    fn text(outgoing: &Outgoing) -> &str {
        std::str::from_utf8(&outgoing.bytes).expect("socketcand is text")
    }

    /// Two clients in raw mode: what one sends reaches the other as a raw-mode `frame`
    /// message stamped with the frame's end on the bus (after the raw-mode grace), and not
    /// the sender; each reply is a write of its own.
    #[test]
    fn a_clients_frame_reaches_the_other_client_in_raw_mode() {
        let mut network = bus_only();
        let mut port = Port::new();
        port.join(&mut network, 0);
        port.join(&mut network, 1);
        let greetings = port.poll(&mut network);
        assert_eq!(
            greetings.iter().map(text).collect::<Vec<_>>(),
            ["< hi >"; 2]
        );
        for client in [0, 1] {
            let hello = b"< open can0 >< rawmode >";
            assert_eq!(port.receive(&mut network, client, hello), hello.len());
        }
        let replies = port.poll(&mut network);
        assert_eq!(replies.iter().map(text).collect::<Vec<_>>(), ["< ok >"; 4]);
        // After the raw-mode grace, client 0 sends a frame.
        network.run_until(50_000_000);
        port.receive(&mut network, 0, b"< send 123 2 AB CD >");
        network.run_until(60_000_000);
        let out = port.poll(&mut network);
        assert_eq!(out.len(), 1, "{out:?}");
        assert_eq!(out[0].to, 1);
        assert!(
            text(&out[0]).starts_with("< frame 123 0.050") && text(&out[0]).ends_with(" ABCD >"),
            "{}",
            text(&out[0])
        );
    }

    /// A client that floods the bus waits: its intake stops before the message that would
    /// overflow its transmit queue, and goes on once the bus has taken frames.
    #[test]
    fn a_flooding_client_waits_for_room_on_the_bus() {
        let mut network = bus_only();
        let mut port = Port::new();
        port.join(&mut network, 0);
        port.receive(&mut network, 0, b"< open can0 >< rawmode >");
        let message = b"< send 300 8 00 11 22 33 44 55 66 77 >";
        let flood = message.repeat(3 * can_hub::bus::TRANSMIT_QUEUE);
        let taken = port.receive(&mut network, 0, &flood);
        assert_eq!(taken, message.len() * can_hub::bus::TRANSMIT_QUEUE);
        network.run_until(10_000_000);
        let more = port.receive(&mut network, 0, &flood[taken..]);
        assert!(more > 0, "room again once the bus has carried frames");
    }

    /// Bytes that are not socketcand are answered with an error naming them and the session
    /// goes on; a client that opens another bus is told so and closed; a client that left
    /// gets nothing more.
    #[test]
    fn bad_bytes_get_an_error_and_a_wrong_bus_closes_the_session() {
        let mut network = bus_only();
        let mut port = Port::new();
        port.join(&mut network, 0);
        port.join(&mut network, 1);
        let _ = port.poll(&mut network);
        port.receive(&mut network, 0, b"\xFF\xFEjunk< echo >");
        let out = port.poll(&mut network);
        assert_eq!(
            out.iter().map(text).collect::<Vec<_>>(),
            [
                "< error \"??junk\" is not a socketcand message >",
                "< echo >"
            ]
        );
        port.receive(&mut network, 1, b"< open vcan7 >< rawmode >");
        assert_eq!(port.closing, [1]);
        let out = port.poll(&mut network);
        assert_eq!(
            out.iter().map(text).collect::<Vec<_>>(),
            ["< error could not open bus >"]
        );
        port.leave(&mut network, 1);
        assert!(port.closing.is_empty());
        assert_eq!(port.receive(&mut network, 1, b"< echo >"), 0);
    }

    /// Reads what `stream` has, as text, until it ends with `until` or nothing comes for
    /// `patience`.
    fn read_for(stream: &mut TcpStream, until: &str, patience: std::time::Duration) -> String {
        use std::io::Read as _;
        stream.set_read_timeout(Some(patience)).expect("a time-out");
        let mut text = String::new();
        let mut buffer = [0u8; 1024];
        while let Ok(count) = stream.read(&mut buffer) {
            if count == 0 {
                break;
            }
            text.push_str(&String::from_utf8_lossy(&buffer[..count]));
            if text.ends_with(until) {
                break;
            }
        }
        text
    }

    /// Over TCP: two programs join; one's frame reaches the other stamped in the virtual
    /// time; bytes that are not socketcand get an error and the network runs on; the
    /// virtual time did not run ahead of the host clock; comings and goings are noted.
    #[test]
    fn programs_join_over_tcp_on_a_virtual_time_behind_the_host_clock() {
        let mut network = bus_only();
        let started = std::time::Instant::now();
        let mut server = Server::listen("127.0.0.1:0", &network).expect("a port");
        let address = server.local_addr();
        let sender = std::thread::spawn(move || {
            let mut stream = TcpStream::connect(address).expect("connected");
            stream.write_all(b"< open can0 >").unwrap();
            stream.write_all(b"\x00\x01 not socketcand").unwrap();
            stream.write_all(b"< rawmode >").unwrap();
            std::thread::sleep(std::time::Duration::from_millis(100));
            stream.write_all(b"< send 7E5 1 2A >").unwrap();
            read_for(&mut stream, "no end", std::time::Duration::from_millis(200))
        });
        let receiver = std::thread::spawn(move || {
            let mut stream = TcpStream::connect(address).expect("connected");
            stream.write_all(b"< open can0 >< rawmode >").unwrap();
            read_for(&mut stream, " 2A >", std::time::Duration::from_secs(2))
        });
        server.run_until(&mut network, 1_000_000_000);
        assert!(
            started.elapsed() >= std::time::Duration::from_secs(1),
            "the virtual time ran ahead of the host clock"
        );
        let sent = sender.join().unwrap();
        assert!(
            sent.starts_with(
                "< hi >< ok >< error \"?? not socketcand\" is not a socketcand message >< ok >"
            ),
            "{sent}"
        );
        assert!(!sent.contains("< frame"), "no echo to the sender: {sent}");
        let received = receiver.join().unwrap();
        assert!(received.starts_with("< hi >< ok >< ok >"), "{received}");
        assert!(received.contains("< frame 7E5 0."), "{received}");
        assert!(received.contains(" 2A >"), "{received}");
        server.run_until(&mut network, 1_100_000_000);
        let notes = server.take_notes();
        assert_eq!(
            notes.iter().filter(|n| n.contains("connected")).count(),
            2,
            "{notes:?}"
        );
        assert_eq!(
            notes.iter().filter(|n| n.contains("left")).count(),
            2,
            "{notes:?}"
        );
        assert_eq!(server.clients_joined(), 2);
    }
}
