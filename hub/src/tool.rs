//! A configuration tool's connection to the hub over TCP: send and receive CAN frames, SDO
//! transfers (through [`shared::canopen::sdo_client`]), NMT, and the EN 50325-5 signing
//! sequence (read back, sign, declare valid, store).

use crate::control::parse_status;
use emulation_wire::Status;
use emulation_wire::{Decoder, Wire, encode};
use shared::canopen::nmt::{self, NmtCommand};
use shared::canopen::od::Address;
use shared::canopen::sdo_client::{self, ClientError};
use shared::safety::config::SrdoRecord;
use shared::{CanFrame, CanId};
use std::collections::HashMap;
use std::io::{self, BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

/// A tool on the bus.
pub struct Tool {
    stream: TcpStream,
    decoder: Decoder,
    /// Every frame received, with the time it arrived.
    pub seen: Vec<(Instant, CanFrame)>,
}

impl Tool {
    /// Connects to the hub at `address`, retrying for up to `patience`.
    pub fn connect(address: &str, patience: Duration) -> io::Result<Self> {
        let give_up = Instant::now() + patience;
        loop {
            match TcpStream::connect(address) {
                Ok(stream) => {
                    stream.set_nodelay(true)?;
                    return Ok(Tool {
                        stream,
                        decoder: Decoder::new(),
                        seen: Vec::new(),
                    });
                }
                Err(error) if Instant::now() >= give_up => return Err(error),
                Err(_) => std::thread::sleep(Duration::from_millis(50)),
            }
        }
    }

    /// Sends a frame.
    pub fn send(&mut self, frame: &CanFrame) -> io::Result<()> {
        self.stream.write_all(&encode(frame))
    }

    /// Receives until `until` returns true for a frame (returned) or `patience` runs out.
    pub fn receive_until(
        &mut self,
        patience: Duration,
        mut until: impl FnMut(&CanFrame) -> bool,
    ) -> io::Result<Option<CanFrame>> {
        let give_up = Instant::now() + patience;
        let mut buf = [0u8; 256];
        loop {
            let left = give_up.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            self.stream.set_read_timeout(Some(left))?;
            let n = match self.stream.read(&mut buf) {
                Ok(0) => return Err(io::Error::new(io::ErrorKind::UnexpectedEof, "hub closed")),
                Ok(n) => n,
                Err(error)
                    if matches!(
                        error.kind(),
                        io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                    ) =>
                {
                    return Ok(None);
                }
                Err(error) => return Err(error),
            };
            let mut found = None;
            for &byte in &buf[..n] {
                if let Some(Ok(Wire::Can(frame))) = self.decoder.push(byte) {
                    self.seen.push((Instant::now(), frame));
                    if found.is_none() && until(&frame) {
                        found = Some(frame);
                    }
                }
            }
            if found.is_some() {
                return Ok(found);
            }
        }
    }

    /// Receives for `duration`, keeping everything in [`Tool::seen`].
    pub fn listen(&mut self, duration: Duration) -> io::Result<()> {
        self.receive_until(duration, |_| false).map(|_| ())
    }

    /// Sends an NMT command to `target` (0: all).
    pub fn nmt(&mut self, command: NmtCommand, target: u8) -> io::Result<()> {
        self.send(&nmt::command_frame(command, target))
    }

    fn exchange(&mut self, id: u8, request: [u8; 8]) -> Option<[u8; 8]> {
        let to = CanId::new(0x600 + u16::from(id)).ok()?;
        let from = 0x580 + u16::from(id);
        self.send(&CanFrame::new(to, &request).ok()?).ok()?;
        let reply = self
            .receive_until(Duration::from_millis(1000), |frame| {
                frame.id().raw() == from
            })
            .ok()??;
        reply.data().try_into().ok()
    }

    /// SDO download.
    pub fn write(&mut self, id: u8, address: Address, data: &[u8]) -> Result<(), ClientError> {
        sdo_client::download(|request| self.exchange(id, request), address, data)
    }

    /// SDO upload.
    pub fn read(&mut self, id: u8, address: Address) -> Result<Vec<u8>, ClientError> {
        sdo_client::upload(|request| self.exchange(id, request), address).map(|v| v.to_vec())
    }

    /// Reads SRDO `n`'s parameters back as the tool will sign them.
    pub fn read_srdo(&mut self, id: u8, n: u8) -> Result<SrdoRecord, ClientError> {
        let comm = 0x1300 + u16::from(n);
        let map = 0x1380 + u16::from(n);
        let value = |tool: &mut Self, address| -> Result<u32, ClientError> {
            let bytes = tool.read(id, address)?;
            let mut raw = [0u8; 4];
            let len = bytes.len().min(4);
            raw[..len].copy_from_slice(&bytes[..len]);
            Ok(u32::from_le_bytes(raw))
        };
        let mut record = SrdoRecord::DELETED;
        record.direction = value(self, Address::new(comm, 1))? as u8;
        record.cycle_time = value(self, Address::new(comm, 2))? as u16;
        record.srvt = value(self, Address::new(comm, 3))? as u8;
        record.cob_id_1 = value(self, Address::new(comm, 5))?;
        record.cob_id_2 = value(self, Address::new(comm, 6))?;
        record.mapping_count = value(self, Address::new(map, 0))? as u8;
        for sub in 1..=record.mapping_count.min(16) {
            record.mapping[usize::from(sub) - 1] = value(self, Address::new(map, sub))?;
        }
        Ok(record)
    }

    /// Signs SRDO 1 of node `id` from its read-back parameters, declares the configuration
    /// valid and stores it (EN 50325-5 6.4.1.5, 6.4.1.6; CiA 301 0x1010).
    pub fn sign_validate_store(&mut self, id: u8) -> Result<u16, ClientError> {
        let record = self.read_srdo(id, 1)?;
        let signature = shared::safety::signature::compute(&record);
        self.write(id, Address::new(0x13FF, 1), &signature.to_le_bytes())?;
        self.write(id, Address::new(0x13FE, 0), &[0xA5])?;
        self.write(id, Address::new(0x1010, 1), b"save")?;
        Ok(signature)
    }
}

/// A connection to the hub's control port ([`crate::control`]): commands, and the latest
/// status of every participant.
pub struct Control {
    writer: TcpStream,
    reader: BufReader<TcpStream>,
    /// The latest status of each participant, with the hub's time of arrival (seconds).
    pub latest: HashMap<String, (f64, Status)>,
    /// Every status line received, in order: (participant, hub time, status).
    pub history: Vec<(String, f64, Status)>,
    /// The latest pace line (`crate::pace`), when the hub paces its participants.
    pub pace: Option<crate::pace::PaceReport>,
}

impl Control {
    /// Connects to the control port at `address`, retrying for up to `patience`.
    pub fn connect(address: &str, patience: Duration) -> io::Result<Self> {
        let give_up = Instant::now() + patience;
        let stream = loop {
            match TcpStream::connect(address) {
                Ok(stream) => break stream,
                Err(error) if Instant::now() >= give_up => return Err(error),
                Err(_) => std::thread::sleep(Duration::from_millis(50)),
            }
        };
        stream.set_nodelay(true)?;
        Ok(Control {
            reader: BufReader::new(stream.try_clone()?),
            writer: stream,
            latest: HashMap::new(),
            history: Vec::new(),
            pace: None,
        })
    }

    /// Reads one line within `patience`; status lines are recorded. `None` when none came.
    fn line(&mut self, patience: Duration) -> io::Result<Option<String>> {
        self.reader
            .get_ref()
            .set_read_timeout(Some(patience.max(Duration::from_millis(1))))?;
        let mut line = String::new();
        match self.reader.read_line(&mut line) {
            Ok(0) => Err(io::Error::new(io::ErrorKind::UnexpectedEof, "hub closed")),
            Ok(_) => {
                let line = line.trim_end().to_string();
                if let Some((name, t, status)) = parse_status(&line) {
                    self.latest.insert(name.clone(), (t, status));
                    self.history.push((name, t, status));
                } else if let Some(pace) = crate::control::parse_pace(&line) {
                    self.pace = Some(pace);
                }
                Ok(Some(line))
            }
            Err(error)
                if matches!(
                    error.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) =>
            {
                Ok(None)
            }
            Err(error) => Err(error),
        }
    }

    /// Sends `command` and waits for its answer: `Ok(hub time in seconds)` or the hub's
    /// error.
    pub fn command(&mut self, command: &str) -> io::Result<Result<f64, String>> {
        writeln!(self.writer, "{command}")?;
        let give_up = Instant::now() + Duration::from_secs(5);
        loop {
            let left = give_up.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    "no answer from the hub",
                ));
            }
            let Some(line) = self.line(left)? else {
                continue;
            };
            if let Some(error) = line.strip_prefix("error ") {
                return Ok(Err(error.to_string()));
            }
            if let Some(rest) = line.strip_prefix("ok ") {
                let t = rest
                    .rsplit_once(" t=")
                    .and_then(|(_, t)| t.parse().ok())
                    .unwrap_or(f64::NAN);
                return Ok(Ok(t));
            }
        }
    }

    /// Reads status lines until one arrives after which `until` holds for the latest statuses
    /// (returns that line's hub time) or `patience` runs out (`None`). A condition that held
    /// already before the call is not enough: the time returned is always that of a report
    /// received during the wait, so a latency measured with it is never of an older report.
    pub fn wait_for(
        &mut self,
        patience: Duration,
        mut until: impl FnMut(&HashMap<String, (f64, Status)>) -> bool,
    ) -> io::Result<Option<f64>> {
        let give_up = Instant::now() + patience;
        loop {
            let left = give_up.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            let Some(line) = self.line(left)? else {
                continue;
            };
            if parse_status(&line).is_some() && until(&self.latest) {
                return Ok(self.history.last().map(|(_, t, _)| *t));
            }
        }
    }

    /// Reads status lines for `duration`.
    pub fn watch(&mut self, duration: Duration) -> io::Result<()> {
        self.wait_for(duration, |_| false).map(|_| ())
    }
}
