//! SLCAN serial adapters (the Lawicel ASCII dialect most USB-CAN dongles speak): `S0`..`S8`
//! set the bit rate, `O` opens and `C` closes the channel, `tIIILDD..` and `rIIIL` are standard
//! data and remote frames, `T`/`R` their extended forms. Every command ends with a carriage
//! return; the adapter answers a carriage return for yes and BEL (07h) for no, and `z`/`Z`
//! after a transmitted frame.

use crate::transport::{Transport, TransportError, WallClock, frame_from_parts};
use serialport::SerialPort;
use shared::CanFrame;
use std::io::{ErrorKind, Read, Write};
use std::time::Duration;

/// The bit rates of `S0`..`S8`, in bit/s.
pub const BIT_RATES: [u32; 9] = [
    10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 800_000, 1_000_000,
];

/// How long the adapter may take to answer a setup command.
const SETUP_PATIENCE: Duration = Duration::from_secs(2);

/// The `S` command for `bit_rate`, if SLCAN has one.
pub fn bit_rate_command(bit_rate: u32) -> Option<String> {
    BIT_RATES
        .iter()
        .position(|&rate| rate == bit_rate)
        .map(|code| format!("S{code}\r"))
}

/// The SLCAN line (with its carriage return) that transmits `frame`.
pub fn encode(frame: &CanFrame) -> String {
    let id = frame.id().raw();
    if frame.is_remote() {
        return format!("r{id:03X}{}\r", frame.dlc());
    }
    let mut line = format!("t{id:03X}{}", frame.data().len());
    for byte in frame.data() {
        line.push_str(&format!("{byte:02X}"));
    }
    line.push('\r');
    line
}

/// The frame of a received SLCAN line (without its carriage return): `None` for lines that are
/// not frames (`z`, `Z`, empty) and for extended frames. A trailing 16-bit timestamp (four
/// hexadecimal digits, when the adapter has them switched on) is ignored.
pub fn decode(line: &str) -> Result<Option<CanFrame>, TransportError> {
    let bad = || TransportError::Protocol(format!("the adapter sent {line:?}, not an SLCAN frame"));
    let kind = line.chars().next();
    match kind {
        Some('t' | 'r') => {
            let id = line
                .get(1..4)
                .and_then(|hex| u32::from_str_radix(hex, 16).ok())
                .ok_or_else(bad)?;
            let len = line
                .get(4..5)
                .and_then(|d| d.parse::<usize>().ok())
                .ok_or_else(bad)?;
            if kind == Some('r') {
                let id = frame_from_parts(id, &[])?.id();
                return CanFrame::remote(id, len as u8).map(Some).map_err(|_| bad());
            }
            let hex = line.get(5..5 + 2 * len).ok_or_else(bad)?;
            let rest = line.len() - 5 - 2 * len;
            if rest != 0 && rest != 4 {
                return Err(bad());
            }
            let data = (0..len)
                .map(|at| u8::from_str_radix(&hex[2 * at..2 * at + 2], 16).map_err(|_| bad()))
                .collect::<Result<Vec<u8>, _>>()?;
            frame_from_parts(id, &data).map(Some)
        }
        // Extended frames: not CANopen's.
        Some('T' | 'R') => Ok(None),
        // Transmit acknowledgements and empty answers.
        Some('z' | 'Z') | None => Ok(None),
        Some(_) => Err(bad()),
    }
}

/// An SLCAN adapter on a serial port.
pub struct Slcan {
    port: Box<dyn SerialPort>,
    buffer: Vec<u8>,
    lines: std::collections::VecDeque<Result<String, ()>>,
    clock: WallClock,
}

impl Slcan {
    /// Opens the serial device at `path` and the CAN channel at `bit_rate`.
    pub fn open_path(path: &str, bit_rate: u32) -> Result<Self, TransportError> {
        let port = serialport::new(path, 115_200)
            .timeout(Duration::from_millis(10))
            .open()
            .map_err(|error| TransportError::Io(error.into()))?;
        Self::open(port, bit_rate)
    }

    /// Sets up an adapter on `port`: closes the channel (in case it was open), sets
    /// `bit_rate`, opens it.
    pub fn open(port: Box<dyn SerialPort>, bit_rate: u32) -> Result<Self, TransportError> {
        let rate = bit_rate_command(bit_rate).ok_or_else(|| {
            TransportError::Protocol(format!(
                "SLCAN has no bit rate {bit_rate} bit/s (it has {BIT_RATES:?})"
            ))
        })?;
        let mut adapter = Slcan {
            port,
            buffer: Vec::new(),
            lines: Default::default(),
            clock: WallClock::start(),
        };
        // A channel that was closed already answers BEL to `C`: either answer is fine.
        let _closed_before = adapter.command("C\r")?;
        if adapter.command(&rate)?.is_err() {
            return Err(TransportError::Protocol(format!(
                "the adapter refused {}",
                rate.trim()
            )));
        }
        if adapter.command("O\r")?.is_err() {
            return Err(TransportError::Protocol(
                "the adapter refused to open the channel".into(),
            ));
        }
        Ok(adapter)
    }

    /// Sends a setup command; its answer: `Ok` for a carriage return, `Err` for BEL.
    fn command(&mut self, command: &str) -> Result<Result<(), ()>, TransportError> {
        self.port.write_all(command.as_bytes())?;
        let deadline = self.clock.now() + SETUP_PATIENCE;
        loop {
            match self.next_line(deadline)? {
                None => {
                    return Err(TransportError::Protocol(format!(
                        "the adapter did not answer {}",
                        command.trim()
                    )));
                }
                Some(Ok(line)) if line.is_empty() => return Ok(Ok(())),
                Some(Err(())) => return Ok(Err(())),
                // A frame that arrived meanwhile (a channel that was open): dropped, the
                // channel is being set up anew.
                Some(Ok(_)) => {}
            }
        }
    }

    /// The next line (without its carriage return), `Err(())` for a BEL, `None` at `deadline`.
    fn next_line(
        &mut self,
        deadline: Duration,
    ) -> Result<Option<Result<String, ()>>, TransportError> {
        loop {
            if let Some(line) = self.lines.pop_front() {
                return Ok(Some(line));
            }
            let Some(left) = self.clock.until(deadline) else {
                return Ok(None);
            };
            self.port
                .set_timeout(left.min(Duration::from_millis(100)))
                .map_err(|error| TransportError::Io(error.into()))?;
            let mut chunk = [0u8; 256];
            match self.port.read(&mut chunk) {
                Ok(0) => {}
                Ok(count) => {
                    for &byte in &chunk[..count] {
                        match byte {
                            b'\r' => {
                                let line = String::from_utf8_lossy(&self.buffer).into_owned();
                                self.buffer.clear();
                                self.lines.push_back(Ok(line));
                            }
                            0x07 => {
                                self.buffer.clear();
                                self.lines.push_back(Err(()));
                            }
                            b'\n' => {}
                            byte => self.buffer.push(byte),
                        }
                    }
                }
                Err(error)
                    if matches!(
                        error.kind(),
                        ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted
                    ) => {}
                Err(error) => return Err(error.into()),
            }
        }
    }
}

impl Drop for Slcan {
    fn drop(&mut self) {
        // Leave the adapter closed, as it was found; nothing to report if it is gone.
        let _ = self.port.write_all(b"C\r");
    }
}

impl Transport for Slcan {
    fn now(&mut self) -> Duration {
        self.clock.now()
    }

    fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        self.port.write_all(encode(frame).as_bytes())?;
        Ok(())
    }

    fn receive(&mut self, deadline: Duration) -> Result<Option<CanFrame>, TransportError> {
        while let Some(line) = self.next_line(deadline)? {
            match line {
                // A refused transmission: the SDO or NMT exchange that needed it times out
                // and says so.
                Err(()) => {}
                Ok(line) => {
                    if let Some(frame) = decode(&line)? {
                        return Ok(Some(frame));
                    }
                }
            }
        }
        Ok(None)
    }
}
