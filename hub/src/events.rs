//! The event log of a run on the emulated bus: every frame with the virtual time it ended and
//! the participant that sent it, and every change of an emulated channel's output, on the same
//! clock. It is what an independent bus monitor with a tap on each node's cable and a probe on
//! each output would record; the scenario runner hands it to the campaigns' oracle
//! (`system_tests::campaign::recorded`). `can-hub --events PATH` writes the frames of its bus
//! in this format (it has no emulated channel, so no output); the emulated network of the
//! shipped images records both kinds as [`Event`]s (`emulator::scenario`).
//!
//! One event a line, in time order (times never decrease):
//!
//! ```text
//! frame t=12.345678 from=node1a 101#01
//! frame t=12.345950 from=node1b 102#FE
//! frame t=12.400120 from=hub 101#01
//! frame t=12.400500 from=tool6 701#R
//! output t=12.346211 node33a 1
//! ```
//!
//! - `t=`: the virtual time in seconds (six decimals, microseconds), the clock of the bus
//!   model, the traces and the control port. For a frame: when its last bit left the bus, as
//!   every receiver gets it. For an output: when the channel's output pin took the value.
//! - `from=`: who put the frame on the bus: an emulated channel by its name (`node1a`),
//!   `hub` for a frame the control port's `insert` sent, `load` for the generated load
//!   (`load` on the control port), `toolN` for socketcand client N. A frame the control
//!   port's `corrupt`, `delay`, `repeat` or `reorder` altered keeps its sender: the fault is
//!   on the wire, the sender sent it.
//! - The frame in candump's notation: identifier in hexadecimal, `#`, the data bytes in
//!   hexadecimal (`#R` and a length digit for a remote frame: `701#R0`).
//! - `output`: the channel and its output pin's value (decimal), for its first value and for
//!   every change.

use shared::{CanFrame, CanId, Instant};
use std::fmt::Write as _;

/// One line of the event log, read back.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Event {
    /// A frame that ended on the bus.
    Frame {
        /// When its last bit left the bus, on the hub's virtual clock.
        at: Instant,
        /// The participant that sent it (see the module documentation).
        from: String,
        /// The frame as every receiver got it.
        frame: CanFrame,
    },
    /// An emulated channel's output pin took a new value.
    Output {
        /// When the pin took the value, on the virtual clock.
        at: Instant,
        /// The channel (its name).
        channel: String,
        /// The output pin's value.
        value: u8,
    },
}

impl Event {
    /// The event's time on the hub's virtual clock.
    pub fn at(&self) -> Instant {
        match self {
            Event::Frame { at, .. } | Event::Output { at, .. } => *at,
        }
    }
}

/// Seconds with six decimals: the control port's notation of the hub's time.
fn seconds(at: Instant) -> String {
    let micros = at.as_micros();
    format!("{}.{:06}", micros / 1_000_000, micros % 1_000_000)
}

/// The line of a frame that ended at `at`, sent by `from`.
pub fn frame_line(at: Instant, from: &str, frame: &CanFrame) -> String {
    let mut line = format!(
        "frame t={} from={from} {:03X}#",
        seconds(at),
        frame.id().raw()
    );
    if frame.is_remote() {
        let _ = write!(line, "R{}", frame.dlc());
    } else {
        for byte in frame.data() {
            let _ = write!(line, "{byte:02X}");
        }
    }
    line
}

/// The line of channel `channel`'s output taking `value`, reported at `at`.
pub fn output_line(at: Instant, channel: &str, value: u8) -> String {
    format!("output t={} {channel} {value}", seconds(at))
}

/// Why a line of the event log was not read, as a sentence naming the line.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ParseError {
    /// The line's number, from 1.
    pub line: usize,
    /// What is wrong with it.
    pub why: String,
}

impl std::fmt::Display for ParseError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "line {} of the hub's event log: {}", self.line, self.why)
    }
}

impl std::error::Error for ParseError {}

/// `t=SECONDS.MICROS` → the instant (exactly, without going through floating point).
fn time(word: &str) -> Result<Instant, String> {
    let value = word
        .strip_prefix("t=")
        .ok_or_else(|| format!("`{word}` is not a time (t=SECONDS.MICROSECONDS)"))?;
    let (whole, fraction) = value.split_once('.').unwrap_or((value, "0"));
    let digits = |text: &str| !text.is_empty() && text.bytes().all(|b| b.is_ascii_digit());
    if !digits(whole) || !digits(fraction) || fraction.len() > 6 {
        return Err(format!(
            "`{word}` is not a time in seconds with up to six decimals"
        ));
    }
    let whole: u64 = whole
        .parse()
        .map_err(|_| format!("`{word}` is out of range"))?;
    let fraction: u64 = format!("{fraction:0<6}")
        .parse()
        .map_err(|_| format!("`{word}` is out of range"))?;
    whole
        .checked_mul(1_000_000)
        .and_then(|micros| micros.checked_add(fraction))
        .map(Instant::from_micros)
        .ok_or_else(|| format!("`{word}` is out of range"))
}

/// `ID#DATA` or `ID#RLEN` → the frame.
fn frame(word: &str) -> Result<CanFrame, String> {
    let (id, data) = word
        .split_once('#')
        .ok_or_else(|| format!("`{word}` is not a frame (ID#DATA in hexadecimal)"))?;
    let id = u16::from_str_radix(id, 16)
        .ok()
        .and_then(|id| CanId::new(id).ok())
        .ok_or_else(|| format!("`{id}` is not an 11-bit identifier in hexadecimal"))?;
    if let Some(length) = data.strip_prefix('R') {
        return length
            .parse::<u8>()
            .ok()
            .and_then(|length| CanFrame::remote(id, length).ok())
            .ok_or_else(|| format!("`{word}`: a remote frame's length is 0 to 8"));
    }
    if data.len() % 2 != 0 || data.len() > 16 {
        return Err(format!(
            "`{word}`: the data is not 0 to 8 bytes of two hexadecimal digits each"
        ));
    }
    let bytes = (0..data.len() / 2)
        .map(|i| u8::from_str_radix(&data[2 * i..2 * i + 2], 16))
        .collect::<Result<Vec<u8>, _>>()
        .map_err(|_| format!("`{word}`: the data is not hexadecimal"))?;
    CanFrame::new(id, &bytes).map_err(|_| format!("`{word}` is not a CAN frame"))
}

/// Reads one line (`number` from 1, for the error).
pub fn parse_line(number: usize, line: &str) -> Result<Event, ParseError> {
    let error = |why: String| ParseError { line: number, why };
    let words: Vec<&str> = line.split_whitespace().collect();
    match words.as_slice() {
        ["frame", at, from, frame_word] => {
            let from = from
                .strip_prefix("from=")
                .filter(|from| !from.is_empty())
                .ok_or_else(|| error(format!("`{from}` is not a sender (from=NAME)")))?;
            Ok(Event::Frame {
                at: time(at).map_err(error)?,
                from: from.to_string(),
                frame: frame(frame_word).map_err(error)?,
            })
        }
        ["output", at, channel, value] => Ok(Event::Output {
            at: time(at).map_err(error)?,
            channel: (*channel).to_string(),
            value: value
                .parse()
                .map_err(|_| error(format!("`{value}` is not an output value (0 to 255)")))?,
        }),
        _ => Err(error(format!(
            "`{line}` is neither `frame t=… from=… ID#DATA` nor `output t=… CHANNEL VALUE`"
        ))),
    }
}

/// Reads a whole log. A last line without its line end is one the hub is still writing and
/// is left out; every other line must be an event.
pub fn parse(text: &str) -> Result<Vec<Event>, ParseError> {
    let complete = match text.rfind('\n') {
        Some(end) => &text[..end],
        None => "",
    };
    complete
        .lines()
        .enumerate()
        .filter(|(_, line)| !line.trim().is_empty())
        .map(|(index, line)| parse_line(index + 1, line))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(id: u16, bytes: &[u8]) -> CanFrame {
        CanFrame::new(CanId::new(id).unwrap(), bytes).unwrap()
    }

    /// Every kind of line reads back as written, times exact to the microsecond.
    #[test]
    fn event_log_lines_read_back_as_written() {
        let events = [
            Event::Frame {
                at: Instant::from_micros(12_345_678),
                from: "node1a".into(),
                frame: data(0x101, &[0x01]),
            },
            Event::Frame {
                at: Instant::from_micros(12_345_950),
                from: "hub".into(),
                frame: data(0x001, &[]),
            },
            Event::Frame {
                at: Instant::from_micros(7),
                from: "tool6".into(),
                frame: CanFrame::remote(CanId::new(0x701).unwrap(), 1).unwrap(),
            },
            Event::Output {
                at: Instant::from_micros(12_346_211),
                channel: "node33a".into(),
                value: 1,
            },
        ];
        let mut text = String::new();
        for event in &events {
            let line = match event {
                Event::Frame { at, from, frame } => frame_line(*at, from, frame),
                Event::Output { at, channel, value } => output_line(*at, channel, *value),
            };
            text.push_str(&line);
            text.push('\n');
        }
        assert_eq!(
            text.lines().next(),
            Some("frame t=12.345678 from=node1a 101#01")
        );
        assert_eq!(
            text.lines().nth(2),
            Some("frame t=0.000007 from=tool6 701#R1")
        );
        assert_eq!(text.lines().nth(3), Some("output t=12.346211 node33a 1"));
        assert_eq!(parse(&text), Ok(events.to_vec()));
    }

    /// A line the hub has not finished is left out; a broken line is named with its number
    /// and what is wrong.
    #[test]
    fn a_broken_event_log_line_is_named_and_an_unfinished_one_left_out() {
        let text = "output t=1.000000 node33a 1\nframe t=1.000100 from=node1a 10";
        assert_eq!(parse(text).unwrap().len(), 1);
        let error = |text: &str| parse(text).unwrap_err().to_string();
        assert_eq!(
            error("output t=1 node33a 1\nframe t=1.5 from=node1a 800#00\n"),
            "line 2 of the hub's event log: `800` is not an 11-bit identifier in hexadecimal"
        );
        assert!(error("frame t=1.5 from= 101#00\n").contains("not a sender"));
        assert!(error("frame t=-1 from=hub 101#00\n").contains("not a time"));
        assert!(error("frame t=1.1234567 from=hub 101#00\n").contains("six decimals"));
        assert!(error("frame t=1 from=hub 101#0\n").contains("two hexadecimal digits"));
        assert!(error("output t=1 node33a 256\n").contains("not an output value"));
        assert!(error("status node33a t=1\n").contains("neither"));
    }
}
