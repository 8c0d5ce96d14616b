//! A test's or a task's connection to a control port (`can-hub`'s, or the emulated
//! network's, `emulate-network --control`): commands, every channel's status reports and the
//! pace reports. (CAN frames, SDO, NMT and the configuration procedure are the tool
//! library's, `safety_config`, over the socketcand port.)

use crate::control::parse_status;
use emulation_wire::Status;
use std::collections::HashMap;
use std::io::{self, BufRead, BufReader, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

/// A connection to a control port ([`crate::control`]): commands, and the latest
/// status of every participant.
pub struct Control {
    writer: TcpStream,
    reader: BufReader<TcpStream>,
    /// The latest status of each participant, with the hub's time of arrival (seconds).
    pub latest: HashMap<String, (f64, Status)>,
    /// Every status line received, in order: (participant, hub time, status).
    pub history: Vec<(String, f64, Status)>,
    /// The latest pace line (`crate::pace`), when the server paces its network.
    pub pace: Option<crate::pace::PaceReport>,
    /// When (host time) the latest line of any kind arrived: a hub that has stopped writing
    /// is told from one whose time stands still.
    pub last_line: Option<Instant>,
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
            last_line: None,
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
                self.last_line = Some(Instant::now());
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
