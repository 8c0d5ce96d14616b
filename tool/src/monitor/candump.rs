//! candump log files (`can-utils`' `candump -l` format, replayable with `canplayer`):
//! `(seconds.microseconds) interface ID#DATA`, one frame a line, `ID#R` for a remote frame.
//! The monitor records the bus into one and replays one; parsing is strict and names the
//! line of anything it cannot read.

use shared::{CanFrame, CanId};
use std::time::Duration;

/// A line of a candump log the monitor cannot read.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{origin}:{line}: {message}")]
pub struct LogError {
    /// The file's name.
    pub origin: String,
    /// Line, from 1.
    pub line: usize,
    /// What is wrong.
    pub message: String,
}

/// One frame of a log and its timestamp.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoggedFrame {
    /// The timestamp as written (time since the Unix epoch for `candump -l`, or since the
    /// recording started for the monitor's own logs).
    pub at: Duration,
    /// The frame.
    pub frame: CanFrame,
}

/// The candump line of `frame` at `at` on `interface`.
pub fn line(at: Duration, interface: &str, frame: &CanFrame) -> String {
    let mut text = format!(
        "({}.{:06}) {interface} {:03X}#",
        at.as_secs(),
        at.subsec_micros(),
        frame.id().raw()
    );
    if frame.is_remote() {
        text.push('R');
    } else {
        for byte in frame.data() {
            text.push_str(&format!("{byte:02X}"));
        }
    }
    text
}

/// Every frame of a candump log, in file order. Empty lines are skipped; a line that is
/// not `(seconds.micros) interface ID#DATA` with an 11-bit identifier and at most 8 data
/// bytes is an error naming the line. Extended (29-bit) identifiers are an error too: the
/// monitor watches CANopen, which has none.
pub fn parse(text: &str, origin: &str) -> Result<Vec<LoggedFrame>, LogError> {
    let mut frames = Vec::new();
    for (number, raw) in (1..).zip(text.lines()) {
        let raw = raw.trim();
        if raw.is_empty() {
            continue;
        }
        let error = |message: String| LogError {
            origin: origin.to_owned(),
            line: number,
            message,
        };
        frames.push(parse_line(raw).map_err(error)?);
    }
    Ok(frames)
}

fn parse_line(raw: &str) -> Result<LoggedFrame, String> {
    let mut words = raw.split_whitespace();
    let (Some(stamp), Some(_interface), Some(frame), None) =
        (words.next(), words.next(), words.next(), words.next())
    else {
        return Err(format!(
            "`{raw}` is not `(seconds.micros) interface ID#DATA`"
        ));
    };
    let stamp = stamp
        .strip_prefix('(')
        .and_then(|s| s.strip_suffix(')'))
        .ok_or_else(|| format!("the timestamp `{stamp}` is not in parentheses"))?;
    let (seconds, micros) = stamp
        .split_once('.')
        .ok_or_else(|| format!("the timestamp `{stamp}` is not seconds.microseconds"))?;
    let bad_stamp = || format!("the timestamp `{stamp}` is not seconds.microseconds");
    if micros.len() != 6 {
        return Err(bad_stamp());
    }
    let at = Duration::from_secs(seconds.parse().map_err(|_| bad_stamp())?)
        + Duration::from_micros(micros.parse().map_err(|_| bad_stamp())?);
    let (id, data) = frame
        .split_once('#')
        .ok_or_else(|| format!("the frame `{frame}` has no `#` between identifier and data"))?;
    if id.len() != 3 {
        return Err(format!(
            "the identifier `{id}` is not three hexadecimal digits (an 11-bit CAN identifier)"
        ));
    }
    let id = u16::from_str_radix(id, 16)
        .ok()
        .and_then(|raw| CanId::new(raw).ok())
        .ok_or_else(|| format!("the identifier `{id}` is not an 11-bit CAN identifier"))?;
    let frame = if data == "R" {
        CanFrame::remote(id, 0).map_err(|_| "a remote frame of more than 8 bytes".to_owned())?
    } else {
        if data.len() % 2 != 0 || data.len() > 16 {
            return Err(format!(
                "the data `{data}` is not up to 8 bytes of two hexadecimal digits each"
            ));
        }
        let bytes = (0..data.len())
            .step_by(2)
            .map(|at| u8::from_str_radix(&data[at..at + 2], 16))
            .collect::<Result<Vec<u8>, _>>()
            .map_err(|_| format!("the data `{data}` is not hexadecimal"))?;
        CanFrame::new(id, &bytes).map_err(|_| format!("the data `{data}` is over 8 bytes"))?
    };
    Ok(LoggedFrame { at, frame })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(id: u16, data: &[u8]) -> CanFrame {
        CanFrame::new(CanId::new(id).unwrap(), data).unwrap()
    }

    #[test]
    fn a_line_is_in_candump_log_format_and_reads_back() {
        let plain = frame(0x101, &[0x01, 0xA5]);
        let text = line(Duration::from_micros(1_700_000_123_456), "can0", &plain);
        assert_eq!(text, "(1700000.123456) can0 101#01A5");
        let empty = line(Duration::from_millis(5), "can0", &frame(0x001, &[]));
        assert_eq!(empty, "(0.005000) can0 001#");
        let both = parse(&format!("{text}\n\n{empty}\n"), "t.log").unwrap();
        assert_eq!(
            both,
            [
                LoggedFrame {
                    at: Duration::from_micros(1_700_000_123_456),
                    frame: plain
                },
                LoggedFrame {
                    at: Duration::from_millis(5),
                    frame: frame(0x001, &[])
                },
            ]
        );
    }

    #[test]
    fn a_line_the_monitor_cannot_read_is_named_with_its_number() {
        let cases = [
            (
                "(1.000000) can0",
                "is not `(seconds.micros) interface ID#DATA`",
            ),
            ("1.000000 can0 101#00", "not in parentheses"),
            ("(1.0) can0 101#00", "not seconds.microseconds"),
            ("(1.000000) can0 101-00", "no `#`"),
            ("(1.000000) can0 12345678#00", "three hexadecimal digits"),
            ("(1.000000) can0 800#00", "not an 11-bit"),
            ("(1.000000) can0 101#0", "two hexadecimal digits"),
            ("(1.000000) can0 101#000102030405060708", "up to 8 bytes"),
            ("(1.000000) can0 101#ZZ", "not hexadecimal"),
        ];
        for (bad, expected) in cases {
            let error = parse(&format!("(0.000001) can0 001#\n{bad}\n"), "x.log").unwrap_err();
            assert_eq!((error.origin.as_str(), error.line), ("x.log", 2), "{bad}");
            assert!(error.message.contains(expected), "{bad}: {error}");
        }
    }
}

#[cfg(test)]
mod properties {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// Any text: a clear error or frames, never a panic.
        #[test]
        fn any_text_parses_or_is_refused_without_panic(text in "\\PC{0,200}") {
            let _ = parse(&text, "any.log");
        }

        /// Every data frame's line reads back as the same frame at the same microsecond.
        #[test]
        fn every_line_reads_back_as_its_frame(
            id in 0u16..0x800,
            data in proptest::collection::vec(any::<u8>(), 0..=8),
            micros in 0u64..4_000_000_000_000_000,
        ) {
            let frame = CanFrame::new(CanId::new(id).unwrap(), &data).unwrap();
            let at = Duration::from_micros(micros);
            let text = line(at, "can0", &frame);
            prop_assert_eq!(parse(&text, "x").unwrap(), vec![LoggedFrame { at, frame }]);
        }
    }
}
