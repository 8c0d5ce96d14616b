//! socketcand: CAN over TCP in the ASCII protocol of linux-can/socketcand (`doc/protocol.md`),
//! raw mode. The client here is a [`Transport`]; [`server`] is the other side as a sans-I/O
//! session, so the emulated bus (or a test) can serve socketcand clients such as python-can's
//! `socketcand` interface.
//!
//! Every message is `< word arguments... >`. After connecting the server greets with `< hi >`;
//! the client opens a bus (`< open can0 >`, answered `< ok >`) and switches to raw mode
//! (`< rawmode >`, answered `< ok >`). Then the client sends `< send ID LEN B0 B1 ... >` and
//! the server pushes every bus frame as `< frame ID SECONDS.MICROSECONDS DATA >`, the data as
//! hexadecimal octets (the daemon writes them without spaces; both forms are accepted).

pub mod server;

use crate::transport::{Transport, TransportError, WallClock, frame_from_parts};
use shared::CanFrame;
use std::io::{ErrorKind, Read, Write};
use std::net::TcpStream;
use std::time::Duration;

/// How long the handshake may take before the server counts as not answering.
const HANDSHAKE_PATIENCE: Duration = Duration::from_secs(5);

/// The environment variable that moves the emulated bus's socketcand port (`cargo xtask run`
/// starts its hub there, bus `can0`), which the tool's default `--bus` follows.
pub const HUB_PORT_VARIABLE: &str = "CAN_HUB_PORT";

/// The emulated bus's socketcand port when [`HUB_PORT_VARIABLE`] is not set.
pub const DEFAULT_HUB_PORT: u16 = 29536;

/// The interface of the emulated bus, as `--bus` names it, for the value of
/// [`HUB_PORT_VARIABLE`] (`None`: not set): `socketcand:127.0.0.1:PORT/can0`. A value that
/// is not a port from 1 to 65534 (the hub's control port is the next one) is refused with a
/// sentence naming the variable, never replaced by the default in silence.
pub fn hub_bus(hub_port: Option<&str>) -> Result<String, String> {
    let port = match hub_port {
        None => DEFAULT_HUB_PORT,
        // Read exactly as `cargo xtask run` reads it (`xtask/src/network.rs`), no trimming.
        Some(text) => text
            .parse::<u16>()
            .ok()
            .filter(|port| (1..u16::MAX).contains(port))
            .ok_or_else(|| {
                format!(
                    "{HUB_PORT_VARIABLE}={text:?} is not a port from 1 to 65534: set it to the \
                     port of `cargo xtask run`'s hub, unset it for {DEFAULT_HUB_PORT}, or name \
                     the interface with --bus"
                )
            })?,
    };
    Ok(format!("socketcand:127.0.0.1:{port}/can0"))
}

/// Splits every complete `< ... >` message off the front of `buffer` and returns their words.
/// Text outside a message (whitespace between messages) is skipped; an unfinished message
/// stays in the buffer.
pub fn take_messages(buffer: &mut String) -> Vec<Vec<String>> {
    let mut messages = Vec::new();
    loop {
        let Some(start) = buffer.find('<') else {
            buffer.clear();
            return messages;
        };
        let Some(length) = buffer[start..].find('>') else {
            buffer.drain(..start);
            return messages;
        };
        let end = start + length;
        let words = buffer[start + 1..end]
            .split_whitespace()
            .map(str::to_owned)
            .collect();
        messages.push(words);
        buffer.drain(..=end);
    }
}

/// The octets of hexadecimal data words, spaced (`11 22`) or not (`1122`).
pub fn parse_hex_data(words: &[String]) -> Result<Vec<u8>, TransportError> {
    let joined: String = words.concat();
    if joined.len() % 2 != 0 {
        return Err(TransportError::Protocol(format!(
            "the data {joined:?} has an odd number of hexadecimal digits"
        )));
    }
    (0..joined.len())
        .step_by(2)
        .map(|at| {
            u8::from_str_radix(&joined[at..at + 2], 16).map_err(|_| {
                TransportError::Protocol(format!("the data {joined:?} is not hexadecimal"))
            })
        })
        .collect()
}

/// A socketcand client in raw mode.
pub struct SocketcandClient {
    stream: TcpStream,
    buffer: String,
    pending: std::collections::VecDeque<Vec<String>>,
    clock: WallClock,
}

impl SocketcandClient {
    /// Connects to the socketcand server at `address` (`host:port`) and opens `bus` in raw mode.
    pub fn connect(address: &str, bus: &str) -> Result<Self, TransportError> {
        let stream = TcpStream::connect(address).map_err(|source| TransportError::Connect {
            address: address.to_owned(),
            source,
        })?;
        stream.set_nodelay(true)?;
        let mut client = SocketcandClient {
            stream,
            buffer: String::new(),
            pending: Default::default(),
            clock: WallClock::start(),
        };
        client.expect(&["hi"])?;
        client.write_message(&format!("< open {bus} >"))?;
        client.expect(&["ok"])?;
        client.write_message("< rawmode >")?;
        client.expect(&["ok"])?;
        Ok(client)
    }

    fn write_message(&mut self, message: &str) -> Result<(), TransportError> {
        self.stream.write_all(message.as_bytes())?;
        Ok(())
    }

    /// Waits for the handshake reply `words`; anything else ends the connection attempt.
    fn expect(&mut self, words: &[&str]) -> Result<(), TransportError> {
        let deadline = self.clock.now() + HANDSHAKE_PATIENCE;
        let message = self.next_message(deadline)?.ok_or_else(|| {
            TransportError::Protocol(format!("no < {} > from the server", words.join(" ")))
        })?;
        if message == words {
            Ok(())
        } else {
            Err(TransportError::Protocol(format!(
                "the server answered < {} > instead of < {} >",
                message.join(" "),
                words.join(" ")
            )))
        }
    }

    /// The next message, or `None` at `deadline`. With a deadline that has passed, what the
    /// connection already holds is still read (without waiting).
    fn next_message(&mut self, deadline: Duration) -> Result<Option<Vec<String>>, TransportError> {
        let mut waited = false;
        loop {
            if let Some(message) = self.pending.pop_front() {
                return Ok(Some(message));
            }
            let left = self.clock.until(deadline);
            if left.is_none() && waited {
                return Ok(None);
            }
            waited = true;
            let mut chunk = [0u8; 4096];
            let read = match left {
                Some(left) => {
                    self.stream.set_read_timeout(Some(left))?;
                    self.stream.read(&mut chunk)
                }
                None => self.read_without_waiting(&mut chunk),
            };
            match read {
                Ok(0) => return Err(TransportError::Closed),
                Ok(count) => {
                    let text = std::str::from_utf8(&chunk[..count]).map_err(|_| {
                        TransportError::Protocol("the server sent bytes that are not text".into())
                    })?;
                    self.buffer.push_str(text);
                    self.pending.extend(take_messages(&mut self.buffer));
                }
                Err(error)
                    if matches!(error.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
                Err(error) if error.kind() == ErrorKind::Interrupted => {}
                Err(error) => return Err(error.into()),
            }
        }
    }

    /// One read of what the connection already holds, without waiting. The socket is
    /// non-blocking only for this read: it is blocking again before the result is looked at,
    /// so a later [`Transport::send`] waits for room in the send buffer instead of failing
    /// with `WouldBlock`.
    fn read_without_waiting(&mut self, chunk: &mut [u8]) -> std::io::Result<usize> {
        self.stream.set_nonblocking(true)?;
        let read = self.stream.read(chunk);
        self.stream.set_nonblocking(false)?;
        read
    }
}

/// The frame carried by a raw-mode `frame` or `rtr` message, `None` for other messages and
/// for extended (29-bit) frames.
pub fn parse_frame_message(words: &[String]) -> Result<Option<CanFrame>, TransportError> {
    let number = |word: &String| {
        u32::from_str_radix(word, 16)
            .map_err(|_| TransportError::Protocol(format!("{word:?} is not a CAN identifier")))
    };
    match words.first().map(String::as_str) {
        Some("frame") if words.len() >= 3 => {
            // An identifier of more than three digits is an extended frame (the daemon
            // writes those with eight).
            if words[1].len() > 3 {
                return Ok(None);
            }
            let data = parse_hex_data(&words[3..])?;
            frame_from_parts(number(&words[1])?, &data).map(Some)
        }
        Some("rtr") if words.len() >= 4 => {
            if words[1].len() > 3 {
                return Ok(None);
            }
            let id = frame_from_parts(number(&words[1])?, &[])?.id();
            let dlc: u8 = words[3]
                .parse()
                .map_err(|_| TransportError::Protocol(format!("{:?} is not a DLC", words[3])))?;
            CanFrame::remote(id, dlc)
                .map(Some)
                .map_err(|_| TransportError::Protocol(format!("DLC {dlc} is more than 8")))
        }
        _ => Ok(None),
    }
}

/// The `send` (or `sendrtr`) message for `frame`, as a client writes it.
pub fn send_message(frame: &CanFrame) -> String {
    let id = frame.id().raw();
    if frame.is_remote() {
        return format!("< sendrtr {id:03X} {} >", frame.dlc());
    }
    let mut message = format!("< send {id:03X} {}", frame.data().len());
    for byte in frame.data() {
        message.push_str(&format!(" {byte:02X}"));
    }
    message.push_str(" >");
    message
}

impl Transport for SocketcandClient {
    fn now(&mut self) -> Duration {
        self.clock.now()
    }

    fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        let message = send_message(frame);
        self.write_message(&message)
    }

    fn receive(&mut self, deadline: Duration) -> Result<Option<CanFrame>, TransportError> {
        Ok(self.receive_stamped(deadline)?.map(|(_, frame)| frame))
    }

    /// The frame with the server's timestamp (`< frame ID SECONDS.MICROSECONDS DATA >`); a
    /// timestamp that is not one reads as the time of reception.
    fn receive_stamped(
        &mut self,
        deadline: Duration,
    ) -> Result<Option<(Duration, CanFrame)>, TransportError> {
        while let Some(message) = self.next_message(deadline)? {
            if message.first().map(String::as_str) == Some("error") {
                // A bus error report (`< error data >`): not a frame; SDO timeouts say the rest.
                continue;
            }
            if let Some(frame) = parse_frame_message(&message)? {
                let stamp = message.get(2).and_then(|word| parse_stamp(word));
                return Ok(Some((stamp.unwrap_or_else(|| self.clock.now()), frame)));
            }
        }
        Ok(None)
    }
}

/// A socketcand timestamp, `SECONDS.MICROSECONDS`.
fn parse_stamp(word: &str) -> Option<Duration> {
    let (seconds, micros) = word.split_once('.')?;
    if micros.len() != 6 {
        return None;
    }
    Some(Duration::from_secs(seconds.parse().ok()?) + Duration::from_micros(micros.parse().ok()?))
}
