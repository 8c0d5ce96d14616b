//! The server side of socketcand (linux-can/socketcand `doc/protocol.md`), as a sans-I/O
//! session per connection: fed the client's bytes, it hands back replies to write and frames
//! to put on the bus; the caller pushes bus frames with [`Session::frame_message`] once the
//! client is in raw mode ([`Session::is_raw`]).
//!
//! What clients rely on (python-can's `socketcand` interface compares each handshake reply
//! from one `recv` by exact equality): each [`Output::Reply`] is to be written on its own, and
//! no frame is pushed before the client has switched to raw mode, nor within
//! [`RAW_MODE_GRACE`] of the reply: [`Session::frame`] holds such frames and
//! [`Session::release`] hands them out when the grace is over.

use super::parse_hex_data;
use crate::transport::frame_from_parts;
use shared::CanFrame;
use std::time::Duration;

/// The greeting a server sends when a client connects.
pub const GREETING: &str = "< hi >";

/// How long after its `rawmode` reply a client receives no bus frame; frames that come
/// meanwhile are held and handed out, in order, when it is over.
///
/// Why: python-can reads the `< ok >` of `rawmode` with one `recv` and compares it with
/// exact equality, so a frame written right after the reply that reaches the client before
/// that `recv` has run (a loaded machine) fails its connection. The server cannot see when
/// the client has read the reply; 20 ms covers a client scheduled late, and is short beside
/// any SDO timeout.
pub const RAW_MODE_GRACE: Duration = Duration::from_millis(20);

/// The longest message a client may send, `<` to `>` included: a `send` of eight octets
/// written one word each fits several times over. A client that sends more without its `>`
/// is told so and closed, so that no client makes the server hold more and more.
pub const MAX_MESSAGE: usize = 256;

/// Where a session is in the protocol.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Connected, no bus opened.
    NoBus,
    /// A bus is open, broadcast-manager mode (only `rawmode` and `echo` are served here).
    Bcm,
    /// Raw mode: frames flow both ways.
    Raw,
}

/// What the caller does for the session.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Output {
    /// Write this message to the client, in a write of its own.
    Reply(String),
    /// Put this frame on the bus.
    Send(CanFrame),
    /// Close the connection (after the replies before it).
    Close,
}

/// One client connection.
#[derive(Debug)]
pub struct Session {
    bus: String,
    mode: Mode,
    buffer: String,
    /// No frame before this time (the server's clock; see [`RAW_MODE_GRACE`]).
    quiet_until: Duration,
    /// Frame messages held until `quiet_until`.
    held: Vec<String>,
}

impl Session {
    /// A session serving the bus named `bus` (e.g. `can0`); write [`GREETING`] first.
    pub fn new(bus: &str) -> Self {
        Session {
            bus: bus.to_owned(),
            mode: Mode::NoBus,
            buffer: String::new(),
            quiet_until: Duration::ZERO,
            held: Vec::new(),
        }
    }

    /// The session's mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Whether bus frames may be pushed to this client.
    pub fn is_raw(&self) -> bool {
        self.mode == Mode::Raw
    }

    /// Handles bytes from the client, received at `now` on the server's clock. Bytes that
    /// are not a message (text outside `<` and `>` other than whitespace, bytes that are not
    /// UTF-8) are answered with an error naming them, in their place among the replies; a
    /// message longer than [`MAX_MESSAGE`] with an error, and the connection is closed.
    pub fn feed(&mut self, bytes: &[u8], now: Duration) -> Vec<Output> {
        self.buffer.push_str(&String::from_utf8_lossy(bytes));
        let mut outputs = Vec::new();
        loop {
            let rest = self.buffer.trim_start();
            let skipped = self.buffer.len() - rest.len();
            self.buffer.drain(..skipped);
            if self.buffer.is_empty() {
                break;
            }
            if !self.buffer.starts_with('<') {
                let end = self.buffer.find('<').unwrap_or(self.buffer.len());
                let stray: String = self.buffer.drain(..end).collect();
                outputs.push(Output::Reply(format!(
                    "< error {} is not a socketcand message >",
                    quoted(stray.trim_end())
                )));
                continue;
            }
            let Some(end) = self.buffer.find('>') else {
                if self.buffer.len() > MAX_MESSAGE {
                    outputs.push(Output::Reply(format!(
                        "< error a message of more than {MAX_MESSAGE} bytes without its closing bracket >"
                    )));
                    outputs.push(Output::Close);
                    self.buffer.clear();
                }
                break;
            };
            let message: String = self.buffer.drain(..=end).collect();
            let words: Vec<String> = message[1..message.len() - 1]
                .split_whitespace()
                .map(str::to_owned)
                .collect();
            let was_raw = self.is_raw();
            self.handle(&words, &mut outputs);
            if !was_raw && self.is_raw() {
                self.quiet_until = now + RAW_MODE_GRACE;
            }
            if outputs.last() == Some(&Output::Close) {
                break;
            }
        }
        outputs
    }

    fn handle(&mut self, words: &[String], outputs: &mut Vec<Output>) {
        let reply = |text: &str| Output::Reply(text.to_owned());
        let command = words.first().map(String::as_str).unwrap_or("");
        match (self.mode, command) {
            (_, "echo") => outputs.push(reply("< echo >")),
            (Mode::NoBus, "open") => {
                if words.get(1) == Some(&self.bus) && words.len() == 2 {
                    self.mode = Mode::Bcm;
                    outputs.push(reply("< ok >"));
                } else {
                    outputs.push(reply("< error could not open bus >"));
                    outputs.push(Output::Close);
                }
            }
            (Mode::Bcm | Mode::Raw, "rawmode") => {
                self.mode = Mode::Raw;
                outputs.push(reply("< ok >"));
            }
            (Mode::Raw, "bcmmode") => {
                self.mode = Mode::Bcm;
                outputs.push(reply("< ok >"));
            }
            (Mode::Bcm | Mode::Raw, "send" | "sendrtr") => match parse_send(words) {
                Ok(frame) => outputs.push(Output::Send(frame)),
                Err(reason) => outputs.push(Output::Reply(format!("< error {reason} >"))),
            },
            _ => outputs.push(reply("< error unknown command >")),
        }
    }

    /// A bus frame that ended at `at` (bus time), offered at `now` (the server's clock): its
    /// message to write now, or `None` when the client is not in raw mode (dropped) or within
    /// the grace after its `rawmode` reply (held for [`Session::release`]).
    pub fn frame(&mut self, frame: &CanFrame, at: Duration, now: Duration) -> Option<String> {
        if !self.is_raw() {
            return None;
        }
        let message = Self::frame_message(frame, at);
        if now < self.quiet_until {
            self.held.push(message);
            None
        } else {
            Some(message)
        }
    }

    /// The held frame messages, once the grace is over at `now` (in order; empty before).
    pub fn release(&mut self, now: Duration) -> Vec<String> {
        if now < self.quiet_until {
            return Vec::new();
        }
        std::mem::take(&mut self.held)
    }

    /// When held frames are due ([`Session::release`]), if any are held.
    pub fn release_at(&self) -> Option<Duration> {
        (!self.held.is_empty()).then_some(self.quiet_until)
    }

    /// The raw-mode message for a bus frame received at `at` (bus time), as the daemon writes
    /// it: identifier in three hexadecimal digits, time as seconds.microseconds, the data as
    /// hexadecimal octets without spaces. A frame without data keeps the daemon's empty data
    /// field (`< frame 001 1.000000  >`, two spaces): python-can splits the message at single
    /// spaces and takes the third part as the data.
    pub fn frame_message(frame: &CanFrame, at: Duration) -> String {
        let id = frame.id().raw();
        let seconds = at.as_secs();
        let micros = at.subsec_micros();
        if frame.is_remote() {
            return format!("< rtr {id:03X} {seconds}.{micros:06} {} >", frame.dlc());
        }
        let data: String = frame.data().iter().map(|b| format!("{b:02X}")).collect();
        format!("< frame {id:03X} {seconds}.{micros:06} {data} >")
    }
}

/// How many of `bytes` make up their first message, its `>` included (all of them when none
/// ends there): a server that stops taking a client's bytes before a message that would
/// overflow its transmit queue feeds [`Session::feed`] one such piece at a time.
pub fn first_message(bytes: &[u8]) -> usize {
    bytes
        .iter()
        .position(|&byte| byte == b'>')
        .map_or(bytes.len(), |at| at + 1)
}

/// `text` quoted for an error message: at most 32 characters, none that would end the
/// message or break the line (`<`, `>`, control characters and the replacement character of
/// bytes that are not UTF-8 are shown as `?`).
fn quoted(text: &str) -> String {
    let shown: String = text
        .chars()
        .take(32)
        .map(|c| {
            if c == '<' || c == '>' || c.is_control() || c == char::REPLACEMENT_CHARACTER {
                '?'
            } else {
                c
            }
        })
        .collect();
    let more = if text.chars().count() > 32 { "..." } else { "" };
    format!("\"{shown}{more}\"")
}

/// The frame of a `send ID LEN B...` or `sendrtr ID LEN` command.
fn parse_send(words: &[String]) -> Result<CanFrame, String> {
    let (Some(id), Some(len)) = (words.get(1), words.get(2)) else {
        return Err("send needs an identifier and a length".into());
    };
    let id = u32::from_str_radix(id, 16).map_err(|_| format!("{id} is not an identifier"))?;
    let len: usize = len.parse().map_err(|_| format!("{len} is not a length"))?;
    if words[0] == "sendrtr" {
        let id = frame_from_parts(id, &[]).map_err(|e| e.to_string())?.id();
        let dlc = u8::try_from(len).map_err(|_| format!("{len} is not a DLC"))?;
        return CanFrame::remote(id, dlc).map_err(|_| format!("DLC {dlc} is more than 8"));
    }
    // One word per octet (`1 F1`, as the protocol's example writes them) or all in one.
    let octets = &words[3..];
    let data = if octets.len() == len {
        octets
            .iter()
            .map(|word| u8::from_str_radix(word, 16).map_err(|_| format!("{word} is not an octet")))
            .collect::<Result<Vec<u8>, String>>()?
    } else {
        parse_hex_data(octets).map_err(|e| e.to_string())?
    };
    if data.len() != len {
        return Err(format!("{len} bytes announced, {} given", data.len()));
    }
    frame_from_parts(id, &data).map_err(|e| e.to_string())
}
