//! The control port's line protocol, on TCP, for people (`nc 127.0.0.1 29537`), scripts and
//! tests: the parser of its commands and the lines it writes. Two programs serve it:
//! `can-hub --control` (bus faults, `insert`, `mute` of a tool, `load`; it has no emulated
//! channel and refuses the commands for them in a sentence) and the emulated network of the
//! shipped images, `emulate-network --control` (`emulator::control`: everything but `load`,
//! with the channels' input pins, links, power and status reports).
//!
//! ```text
//! → input node1a 0            the input pin of channel node1a reads 0
//! → drop 0x102                the next frame with identifier 102h is lost
//! → corrupt 0x101 0 0x01      data byte 0 of the next 101h frame is XOR-ed with 01h
//! → delay 0x101 30            the next 101h frame arrives 30 ms late
//! → repeat 0x101              the next 101h frame arrives twice
//! → reorder 0x101             the next 101h frame arrives after the frame that follows it
//! → insert 0x101 00 ff        a frame 101h#00FF goes on the bus from the port itself (a rogue
//!                             sender; arbitration and bit time as for everyone)
//! → mute node1a / unmute node1a
//!                             the participant's frames stop (start again) reaching the bus
//! → cut node33-link           the link between a node's two channels passes no byte, both ways
//! → restore node33-link       it passes them again
//! → power-cycle node33a node33b
//!                             these channels are switched off and on again
//! → clear                     every injected bus fault is removed
//! → load 30 621#4018100100000000 281#5555555555555555
//!                             the hub sends these frames in turn, on its clock, so
//!                             that the traffic other than SRDOs fills 30 % of the bus
//!                             (`can_hub::load`); `load off` stops it
//! ← ok <command> t=<seconds on the server's clock>   or   error <why>
//!   (a line longer than MAX_LINE bytes, or not UTF-8, is refused with `error <why>`)
//! ← status node1a t=1.234567 nmt=5 working=1 link=1 output=1 input=1 cause=0x00 sent=12
//!          validated=0 stall_ms=3 link_gap_ms=52 busy_ms=1
//!          stack=5400 discarded=0
//!   (a channel's status, `emulation_wire::Status`, as the emulated network reports it)
//! ← pace t=12.345678 behind_ms=420.0 hold_ms=61.2 round_trips=20112 rtt_median_ms=0.41
//!          rtt_p99_ms=6.20 rtt_max_ms=48.90
//!   (every second while the emulated network is paced to the host clock, `can_hub::pace`:
//!   how far the virtual time is behind the host clock, its longest hold, the grants' round
//!   trips in host time)
//! ```

use emulation_wire::Status;
use std::fmt;
use std::io::BufRead;

/// The longest control line accepted, in bytes without its line end: ample for any command
/// (the longest, `insert` with eight data bytes, is under 40), and it keeps a client that
/// never sends a line end from making the hub hold an ever longer line.
pub const MAX_LINE: usize = 256;

/// The longest delay `delay` accepts, in milliseconds: far longer than any SCT, short enough
/// that the frame arrives within the run.
pub const MAX_DELAY_MS: u64 = 60_000;

/// Reads one line from a control client: `Ok(None)` at the end of the stream, `Ok(Some(Ok))`
/// for a line (line end and a trailing carriage return removed), `Ok(Some(Err(why)))` for a
/// line refused because it is longer than [`MAX_LINE`] or not UTF-8. Holds at most
/// [`MAX_LINE`] bytes: the rest of a long line is read and discarded up to its line end.
pub fn read_line(reader: &mut impl BufRead) -> std::io::Result<Option<Result<String, String>>> {
    let mut line = Vec::new();
    let mut too_long = false;
    let mut any = false;
    loop {
        let available = reader.fill_buf()?;
        if available.is_empty() {
            if !any {
                return Ok(None);
            }
            break;
        }
        any = true;
        let (chunk, end) = match available.iter().position(|&b| b == b'\n') {
            Some(at) => (&available[..at], Some(at + 1)),
            None => (available, None),
        };
        if line.len() + chunk.len() > MAX_LINE + 1 {
            too_long = true;
        } else {
            line.extend_from_slice(chunk);
        }
        let consumed = end.unwrap_or(available.len());
        reader.consume(consumed);
        if end.is_some() {
            break;
        }
    }
    if line.last() == Some(&b'\r') {
        line.pop();
    }
    if too_long || line.len() > MAX_LINE {
        return Ok(Some(Err(format!(
            "line longer than {MAX_LINE} bytes: refused"
        ))));
    }
    Ok(Some(String::from_utf8(line).map_err(|_| {
        "line is not UTF-8 text: refused".to_string()
    })))
}

/// A command on the control port.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Command {
    /// Set emulated channel `name`'s input pin.
    Input {
        /// The participant.
        name: String,
        /// The pin's value.
        value: u8,
    },
    /// Drop the next frame with this identifier.
    Drop(u16),
    /// XOR data byte `byte` of the next frame with identifier `id` with `mask`.
    Corrupt {
        /// The identifier.
        id: u16,
        /// The data byte.
        byte: usize,
        /// The bits flipped.
        mask: u8,
    },
    /// Deliver the next frame with identifier `id` `ms` milliseconds late.
    Delay {
        /// The identifier.
        id: u16,
        /// The delay.
        ms: u64,
    },
    /// Deliver the next frame with this identifier twice.
    Repeat(u16),
    /// Deliver the next frame with this identifier after the frame that follows it.
    Reorder(u16),
    /// Put this frame on the bus, from the control port itself.
    Insert {
        /// The identifier.
        id: u16,
        /// The data bytes (at most 8).
        data: Vec<u8>,
    },
    /// Participant `name`'s frames stop (`true`) or start again (`false`) reaching the bus.
    Mute(String, bool),
    /// The link `name` between a node's two emulated channels stops passing bytes.
    Cut(String),
    /// The link `name` passes bytes again.
    Restore(String),
    /// Switch these participants off and on again (a node's supply failing and coming back):
    /// each starts from its image, its parameter flash as it stands. Only the emulated
    /// STM32F405s can (`emulate-network`); `can-hub` refuses it.
    PowerCycle(Vec<String>),
    /// Remove every injected bus fault.
    Clear,
    /// Generate load ([`crate::load`]): `percent` of the bus, these frames in turn
    /// (identifier, data).
    Load {
        /// The share of the bus, in percent.
        percent: u32,
        /// The frames, sent in turn.
        frames: Vec<(u16, Vec<u8>)>,
    },
    /// Stop the generated load.
    LoadOff,
}

/// `ID#HEXDATA` (candump's notation, e.g. `281#5555`) → identifier and data bytes.
fn candump_frame(word: &str) -> Result<(u16, Vec<u8>), String> {
    let (id, data) = word
        .split_once('#')
        .ok_or_else(|| format!("{word} is not a frame (ID#DATA in hexadecimal, e.g. 281#5555)"))?;
    let id = identifier(id)?;
    if data.len() % 2 != 0 || data.len() > 16 {
        return Err(format!(
            "{word}: the data is not 0 to 8 bytes of two hexadecimal digits each"
        ));
    }
    let data = (0..data.len() / 2)
        .map(|i| {
            data.get(2 * i..2 * i + 2)
                .and_then(|byte| u8::from_str_radix(byte, 16).ok())
                .ok_or_else(|| format!("{word}: the data is not hexadecimal"))
        })
        .collect::<Result<Vec<u8>, String>>()?;
    Ok((id, data))
}

fn identifier(word: &str) -> Result<u16, String> {
    let digits = word
        .strip_prefix("0x")
        .or_else(|| word.strip_prefix("0X"))
        .unwrap_or(word);
    u16::from_str_radix(digits, 16)
        .ok()
        .filter(|id| *id <= 0x7FF)
        .ok_or_else(|| format!("{word} is not an 11-bit identifier (hexadecimal, e.g. 0x102)"))
}

fn number<T: std::str::FromStr>(word: &str, what: &str) -> Result<T, String> {
    let parsed = match word.strip_prefix("0x") {
        Some(hex) => u64::from_str_radix(hex, 16)
            .ok()
            .and_then(|v| v.to_string().parse().ok()),
        None => word.parse().ok(),
    };
    parsed.ok_or_else(|| format!("{word} is not {what}"))
}

impl Command {
    /// Parses one line.
    pub fn parse(line: &str) -> Result<Command, String> {
        let words: Vec<&str> = line.split_whitespace().collect();
        let command = match words.as_slice() {
            ["input", name, value] => Command::Input {
                name: (*name).to_string(),
                value: number(value, "a pin value (0..255)")?,
            },
            ["drop", id] => Command::Drop(identifier(id)?),
            ["corrupt", id, byte, mask] => {
                let byte: usize = number(byte, "a data byte index (0..7)")?;
                if byte > 7 {
                    return Err(format!("data byte {byte} does not exist (0..7)"));
                }
                let mask: u8 = number(mask, "a bit mask (1..255)")?;
                if mask == 0 {
                    return Err("a mask of 0 flips no bit".into());
                }
                Command::Corrupt {
                    id: identifier(id)?,
                    byte,
                    mask,
                }
            }
            ["delay", id, ms] => {
                let ms: u64 = number(ms, "a delay in milliseconds")?;
                if ms > MAX_DELAY_MS {
                    return Err(format!(
                        "a delay of {ms} ms is longer than {MAX_DELAY_MS} ms"
                    ));
                }
                Command::Delay {
                    id: identifier(id)?,
                    ms,
                }
            }
            ["repeat", id] => Command::Repeat(identifier(id)?),
            ["reorder", id] => Command::Reorder(identifier(id)?),
            ["insert", id, bytes @ ..] => {
                if bytes.len() > 8 {
                    return Err(format!(
                        "{} data bytes: a CAN frame has at most 8",
                        bytes.len()
                    ));
                }
                let data = bytes
                    .iter()
                    .map(|byte| {
                        u8::from_str_radix(byte, 16)
                            .map_err(|_| format!("{byte} is not a data byte (hexadecimal, 00..ff)"))
                    })
                    .collect::<Result<Vec<u8>, String>>()?;
                Command::Insert {
                    id: identifier(id)?,
                    data,
                }
            }
            ["mute", name] => Command::Mute((*name).to_string(), true),
            ["unmute", name] => Command::Mute((*name).to_string(), false),
            ["cut", name] => Command::Cut((*name).to_string()),
            ["restore", name] => Command::Restore((*name).to_string()),
            ["clear"] => Command::Clear,
            ["power-cycle", names @ ..] if !names.is_empty() => {
                Command::PowerCycle(names.iter().map(|name| (*name).to_string()).collect())
            }
            ["load", "off"] => Command::LoadOff,
            ["load", percent, frames @ ..] => Command::Load {
                percent: number(percent, "a share of the bus in percent")?,
                frames: frames
                    .iter()
                    .map(|word| candump_frame(word))
                    .collect::<Result<_, _>>()?,
            },
            [] => return Err("empty command".into()),
            [verb, ..] => {
                return Err(format!(
                    "`{verb}` with {} argument(s) is not a command (input, drop, corrupt, delay, \
                     repeat, reorder, insert, mute, unmute, cut, restore, power-cycle, clear, \
                     load)",
                    words.len() - 1
                ));
            }
        };
        Ok(command)
    }
}

impl fmt::Display for Command {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Command::Input { name, value } => write!(f, "input {name} {value}"),
            Command::Drop(id) => write!(f, "drop 0x{id:03X}"),
            Command::Corrupt { id, byte, mask } => {
                write!(f, "corrupt 0x{id:03X} {byte} 0x{mask:02X}")
            }
            Command::Delay { id, ms } => write!(f, "delay 0x{id:03X} {ms}"),
            Command::Repeat(id) => write!(f, "repeat 0x{id:03X}"),
            Command::Reorder(id) => write!(f, "reorder 0x{id:03X}"),
            Command::Insert { id, data } => {
                write!(f, "insert 0x{id:03X}")?;
                data.iter().try_for_each(|byte| write!(f, " {byte:02x}"))
            }
            Command::Mute(name, true) => write!(f, "mute {name}"),
            Command::Mute(name, false) => write!(f, "unmute {name}"),
            Command::Cut(name) => write!(f, "cut {name}"),
            Command::Restore(name) => write!(f, "restore {name}"),
            Command::Clear => write!(f, "clear"),
            Command::PowerCycle(names) => write!(f, "power-cycle {}", names.join(" ")),
            Command::Load { percent, frames } => {
                write!(f, "load {percent}")?;
                frames.iter().try_for_each(|(id, data)| {
                    write!(f, " {id:03X}#")?;
                    data.iter().try_for_each(|byte| write!(f, "{byte:02X}"))
                })
            }
            Command::LoadOff => write!(f, "load off"),
        }
    }
}

/// A status line as the emulated network sends it: participant `name`'s `status`, received at `t` seconds.
pub fn status_line(name: &str, t: f64, status: &Status) -> String {
    format!(
        "status {name} t={t:.6} nmt={} working={} link={} output={} input={} cause=0x{:02X} \
         sent={} validated={} stall_ms={} link_gap_ms={} busy_ms={} stack={} discarded={}",
        status.nmt,
        u8::from(status.working),
        u8::from(status.link_up),
        status.output,
        status.input,
        status.cause,
        status.sent,
        status.validated,
        status.longest_stall_ms,
        status.longest_link_gap_ms,
        status.longest_busy_ms,
        status.stack_used,
        status.discarded
    )
}

/// A pace line as the emulated network sends it (see the module documentation).
pub fn pace_line(report: &crate::pace::PaceReport) -> String {
    let ms = |d: shared::Duration| d.as_micros() as f64 / 1000.0;
    format!(
        "pace t={:.6} behind_ms={:.1} hold_ms={:.1} round_trips={} rtt_median_ms={:.2} \
         rtt_p99_ms={:.2} rtt_max_ms={:.2}",
        report.virtual_time.as_micros() as f64 / 1e6,
        ms(report.behind),
        ms(report.longest_hold),
        report.round_trips,
        ms(report.round_trip_median),
        ms(report.round_trip_p99),
        ms(report.round_trip_max),
    )
}

/// Reads a pace line back (durations rounded as written).
pub fn parse_pace(line: &str) -> Option<crate::pace::PaceReport> {
    let mut words = line.split_whitespace();
    if words.next()? != "pace" {
        return None;
    }
    let mut report = crate::pace::PaceReport::default();
    for word in words {
        let (key, value) = word.split_once('=')?;
        let number: f64 = value
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite() && *v >= 0.0)?;
        let ms = shared::Duration::from_micros((number * 1000.0).round() as u64);
        match key {
            "t" => report.virtual_time = shared::Instant::from_micros((number * 1e6) as u64),
            "behind_ms" => report.behind = ms,
            "hold_ms" => report.longest_hold = ms,
            "round_trips" => report.round_trips = number as usize,
            "rtt_median_ms" => report.round_trip_median = ms,
            "rtt_p99_ms" => report.round_trip_p99 = ms,
            "rtt_max_ms" => report.round_trip_max = ms,
            _ => return None,
        }
    }
    Some(report)
}

/// Reads a status line back: (participant, t, status).
pub fn parse_status(line: &str) -> Option<(String, f64, Status)> {
    let mut words = line.split_whitespace();
    if words.next()? != "status" {
        return None;
    }
    let name = words.next()?.to_string();
    let mut t = None;
    let mut status = Status::default();
    for word in words {
        let (key, value) = word.split_once('=')?;
        let int = || -> Option<u16> {
            match value.strip_prefix("0x") {
                Some(hex) => u16::from_str_radix(hex, 16).ok(),
                None => value.parse().ok(),
            }
        };
        match key {
            "t" => t = value.parse().ok(),
            "nmt" => status.nmt = u8::try_from(int()?).ok()?,
            "working" => status.working = int()? != 0,
            "link" => status.link_up = int()? != 0,
            "output" => status.output = u8::try_from(int()?).ok()?,
            "input" => status.input = u8::try_from(int()?).ok()?,
            "cause" => status.cause = u8::try_from(int()?).ok()?,
            "sent" => status.sent = int()?,
            "validated" => status.validated = int()?,
            "stall_ms" => status.longest_stall_ms = int()?,
            "link_gap_ms" => status.longest_link_gap_ms = int()?,
            "busy_ms" => status.longest_busy_ms = int()?,
            "stack" => status.stack_used = int()?,
            "discarded" => status.discarded = int()?,
            _ => return None,
        }
    }
    Some((name, t?, status))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pace line reads back as written (to the precision written).
    #[test]
    fn pace_lines_round_trip() {
        use shared::{Duration, Instant};
        let report = crate::pace::PaceReport {
            virtual_time: Instant::from_micros(12_345_678),
            behind: Duration::from_micros(420_000),
            longest_hold: Duration::from_micros(61_200),
            round_trips: 20_112,
            round_trip_median: Duration::from_micros(410),
            round_trip_p99: Duration::from_micros(6_200),
            round_trip_max: Duration::from_micros(48_900),
        };
        assert_eq!(parse_pace(&pace_line(&report)), Some(report));
        assert_eq!(parse_pace("pace t=1 hold_ms=-1"), None);
        assert_eq!(parse_pace("status node1a t=1"), None);
    }

    /// A line past `MAX_LINE` bytes is refused with a sentence, held no longer than the bound,
    /// and the next line is read as usual; so are lines that are not UTF-8.
    #[test]
    fn an_over_long_or_non_text_control_line_is_refused_and_the_next_one_read() {
        let mut input = Vec::new();
        input.extend(std::iter::repeat_n(b'x', 1_000_000));
        input.extend_from_slice(b"\nclear\r\n");
        input.extend_from_slice(&[0xFF, 0xFE, b'\n']);
        input.extend_from_slice(&[b'y'; MAX_LINE]);
        input.extend_from_slice(b"\nlast");
        // A small buffer, so a long line arrives in many pieces.
        let mut reader = std::io::BufReader::with_capacity(64, &input[..]);
        let error = read_line(&mut reader).unwrap().unwrap().unwrap_err();
        assert!(error.contains("longer than 256 bytes"), "{error}");
        assert_eq!(read_line(&mut reader).unwrap(), Some(Ok("clear".into())));
        let error = read_line(&mut reader).unwrap().unwrap().unwrap_err();
        assert!(error.contains("not UTF-8"), "{error}");
        let longest = read_line(&mut reader).unwrap().unwrap().unwrap();
        assert_eq!(
            longest.len(),
            MAX_LINE,
            "a line of exactly MAX_LINE bytes is taken"
        );
        assert_eq!(read_line(&mut reader).unwrap(), Some(Ok("last".into())));
        assert_eq!(read_line(&mut reader).unwrap(), None);
    }

    #[test]
    fn a_delay_longer_than_a_minute_is_refused() {
        assert!(Command::parse("delay 0x101 60000").is_ok());
        let error = Command::parse("delay 0x101 18446744073709551615").unwrap_err();
        assert!(error.contains("longer than 60000 ms"), "{error}");
    }

    #[test]
    fn commands_parse_and_print_back() {
        for line in [
            "input node1a 0",
            "drop 0x102",
            "corrupt 0x101 0 0x01",
            "delay 0x101 30",
            "repeat 0x101",
            "reorder 0x101",
            "insert 0x101 00 ff",
            "insert 0x000",
            "mute node1a",
            "unmute node1b",
            "cut node33-link",
            "restore node33-link",
            "power-cycle node1a node1b",
            "clear",
            "load 30 621#4018100100000000 281#5555555555555555 000#",
            "load off",
        ] {
            let command = Command::parse(line).unwrap();
            assert_eq!(command.to_string(), line);
        }
        assert_eq!(Command::parse("drop 102"), Ok(Command::Drop(0x102)));
    }

    #[test]
    fn bad_commands_say_what_is_wrong() {
        let error = |line| Command::parse(line).unwrap_err();
        assert!(error("drop 0x800").contains("11-bit"));
        assert!(error("corrupt 0x101 8 1").contains("byte 8"));
        assert!(error("corrupt 0x101 0 0").contains("mask of 0"));
        assert!(error("input node1a 256").contains("pin value"));
        assert!(error("explode").contains("not a command"));
        assert!(error("insert 0x101 0 1 2 3 4 5 6 7 8").contains("at most 8"));
        assert!(error("insert 0x101 xyz").contains("data byte"));
        assert!(error("").contains("empty"));
        assert!(error("load 30 281").contains("not a frame"));
        assert!(error("load 30 281#555").contains("two hexadecimal digits"));
        assert!(error("load 30 281#XY").contains("not hexadecimal"));
        assert!(error("load 30 281#000000000000000000").contains("0 to 8 bytes"));
        assert!(error("load much 281#00").contains("share of the bus"));
        assert!(error("power-cycle").contains("not a command"));
    }

    #[test]
    fn status_lines_round_trip() {
        let status = Status {
            nmt: 5,
            working: true,
            link_up: true,
            output: 1,
            input: 1,
            cause: 0x14,
            sent: 300,
            validated: 299,
            longest_stall_ms: 12,
            longest_link_gap_ms: 60,
            longest_busy_ms: 3,
            stack_used: 5400,
            discarded: 2,
        };
        let line = status_line("node33a", 12.5, &status);
        assert_eq!(
            parse_status(&line),
            Some(("node33a".to_string(), 12.5, status))
        );
    }
}
