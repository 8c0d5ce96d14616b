//! `safety-config monitor`: a live view of a CANopen Safety bus, from the bus or from a
//! candump log.
//!
//! - [`model`]: frames → what the bus shows (nodes, SRDO pairs and their verdicts, GFC,
//!   EMCY in words, SDO traffic), sans-I/O: fed `(now, frame)`, polled with `now`.
//! - [`view`]: the terminal drawing of the model (ratatui), and the same as plain lines.
//! - [`candump`]: the candump log format the monitor records and replays.
//! - [`pcap`]: pcap files (SocketCAN link type) the monitor records for Wireshark.
//!
//! This module is the I/O around them: the bus or the log, the keyboard, the terminal, the
//! recording.

pub mod candump;
pub mod model;
pub mod pcap;
pub mod view;

use crate::transport::{Transport, TransportError};
use candump::LoggedFrame;
use model::Monitor;
use ratatui::crossterm::event::{self, Event, KeyCode, KeyEventKind, KeyModifiers};
use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime};
use view::Screen;

/// Why the monitor stopped before it was asked to.
#[derive(Debug, thiserror::Error)]
pub enum MonitorError {
    /// The CAN interface failed.
    #[error(transparent)]
    Bus(#[from] TransportError),
    /// A line of the log to replay is not a candump line.
    #[error("the log to replay has a line the monitor cannot read: {0}")]
    Log(#[from] candump::LogError),
    /// The log to replay could not be read.
    #[error("cannot read the log {path}: {source}")]
    ReadLog {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// The recording could not be written.
    #[error("cannot write the recording {path}: {source}")]
    WriteLog {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// The terminal could not be drawn on or read from.
    #[error("the terminal failed: {0}")]
    Terminal(std::io::Error),
    /// Ctrl-C (SIGINT) could not be caught.
    #[error("the monitor cannot catch Ctrl-C to end with its summary: {0}")]
    Interrupt(#[from] ctrlc::Error),
}

/// Where the frames come from.
pub enum Source {
    /// A live bus.
    Bus(Box<dyn Transport>),
    /// A recorded log, at the recorded pace or as fast as it can be read.
    Replay {
        /// The log's frames.
        frames: Vec<LoggedFrame>,
        /// `true`: no waiting between frames.
        fast: bool,
    },
}

impl Source {
    /// The frames of the candump log at `path`, to replay.
    pub fn replay(path: &std::path::Path, fast: bool) -> Result<Source, MonitorError> {
        let text = std::fs::read_to_string(path).map_err(|source| MonitorError::ReadLog {
            path: path.to_owned(),
            source,
        })?;
        let frames = candump::parse(&text, &path.display().to_string())?;
        Ok(Source::Replay { frames, fast })
    }
}

/// How the monitor runs.
#[derive(Clone, Debug, Default)]
pub struct Options {
    /// The title line (what is monitored).
    pub title: String,
    /// Record every frame into this file: a pcap ([`pcap`]) when its name ends in `.pcap`,
    /// else a candump log.
    pub record: Option<PathBuf>,
    /// End after this long (wall-clock time); `None`: until `q`, or the end of a replay.
    pub stop_after: Option<Duration>,
    /// Draw the live view (a terminal); `false` prints a line per happening instead.
    pub live: bool,
    /// Ends the monitor, as `q` does, once it is `true` ([`interrupt_on_ctrl_c`]).
    pub interrupt: Option<Arc<AtomicBool>>,
}

/// A flag that Ctrl-C (SIGINT) sets, for [`Options::interrupt`]: the monitor then ends as
/// with `q`, and a plain run prints its summary. A second Ctrl-C before the monitor has ended
/// ends the process at once (exit status 130, as a shell reports SIGINT). In the live view
/// the terminal is in raw mode, where Ctrl-C is a key, not a signal; a SIGINT sent by
/// another process ends it the same way.
pub fn interrupt_on_ctrl_c() -> Result<Arc<AtomicBool>, MonitorError> {
    let flag = Arc::new(AtomicBool::new(false));
    let set = Arc::clone(&flag);
    ctrlc::set_handler(move || {
        if set.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
    })?;
    Ok(flag)
}

/// The keys the monitor takes, for the bottom line and the help.
const KEYS: &str = "q quit   g send GFC   p pause   ? help";

fn help() -> Vec<String> {
    [
        "q        quit (also Esc, Ctrl-C)",
        "g        send a GFC (global fail-safe command, CAN-ID 001h): every safety node in",
        "         Operational goes to its safe state (EN 50325-5 7.2.1); live bus only",
        "p        pause or resume the drawing (the model keeps taking frames)",
        "?        this help",
        "",
        "gap      plain → inverted frame of one pair, against SRVT",
        "period   between the plain frames of consecutive pairs, against SCT",
        "!        a gap or period at or over its limit (EN 50325-5 7.1.2)",
        "?        a limit the network file does not give (SRDO learned from the bus)",
    ]
    .map(str::to_owned)
    .to_vec()
}

/// A key the monitor acts on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Key {
    /// End.
    Quit,
    /// Send a GFC.
    Gfc,
    /// Pause or resume drawing.
    Pause,
    /// Show or hide the help.
    Help,
    /// Any other key.
    Other,
}

/// What a pressed key asks of the monitor.
pub fn key(pressed: Pressed) -> Key {
    match pressed {
        Pressed::Interrupt | Pressed::Escape | Pressed::Char('q') => Key::Quit,
        Pressed::Char('g') => Key::Gfc,
        Pressed::Char('p') => Key::Pause,
        Pressed::Char('?') => Key::Help,
        Pressed::Char(_) => Key::Other,
    }
}

/// How often the view is redrawn.
const FRAME_PERIOD: Duration = Duration::from_millis(100);

/// Runs the monitor until `q`, the end of `options.stop_after` or (not on a terminal) the
/// end of a replayed log; returns the model as it ended.
pub fn run(
    mut source: Source,
    mut monitor: Monitor,
    options: Options,
) -> Result<Monitor, MonitorError> {
    let mut recording = match &options.record {
        Some(path) => Some((
            Recording::create(path).map_err(|source| MonitorError::WriteLog {
                path: path.clone(),
                source,
            })?,
            path.clone(),
        )),
        None => None,
    };
    let mut terminal = if options.live {
        Some(Terminal::open()?)
    } else {
        None
    };
    let started = Instant::now();
    // Unix time minus the bus's timestamp of the first frame: a recording's lines carry
    // Unix time, as `candump -l` writes it, with the bus's own gaps between them.
    let mut epoch: Option<Duration> = None;
    let mut screen = Screen {
        title: options.title.clone(),
        keys: KEYS.to_owned(),
        ..Screen::default()
    };
    let mut printed = 0;
    let mut next_frame = 0;
    let mut last_draw: Option<Instant> = None;
    // The bus closed (read no more), and that was noted.
    let (mut bus_closed, mut noted_close) = (false, false);
    loop {
        // Frames: from the bus until the next drawing is due; from a log those due by now.
        let mut received = Vec::new();
        let mut origin = Duration::ZERO;
        let done = match &mut source {
            Source::Bus(_) if bus_closed => true,
            Source::Bus(bus) => {
                let until = bus.now() + FRAME_PERIOD / 2;
                let closed = loop {
                    match bus.receive_stamped(until) {
                        Ok(Some((at, frame))) => {
                            received.push((at, frame));
                            if received.len() >= 256 {
                                break false;
                            }
                        }
                        Ok(None) => break false,
                        // The server ended the session: the end of what there is to see.
                        Err(TransportError::Closed) => break true,
                        Err(error) => return Err(error.into()),
                    }
                };
                if closed {
                    bus_closed = true;
                    // Noted after this batch's frames, below.
                }
                closed
            }
            Source::Replay { frames, fast } => {
                origin = frames.first().map_or(Duration::ZERO, |f| f.at);
                let elapsed = started.elapsed();
                while let Some(logged) = frames.get(next_frame) {
                    let at = logged.at.saturating_sub(origin);
                    if !*fast && at > elapsed {
                        break;
                    }
                    received.push((at, logged.frame));
                    next_frame += 1;
                }
                if !*fast {
                    std::thread::sleep(Duration::from_millis(10));
                }
                next_frame == frames.len()
            }
        };
        for (now, frame) in &received {
            monitor.feed(*now, frame);
            if let Some((file, path)) = &mut recording {
                let at = match &source {
                    Source::Replay { .. } => origin + *now,
                    Source::Bus(_) => {
                        *epoch.get_or_insert_with(|| {
                            SystemTime::now()
                                .duration_since(SystemTime::UNIX_EPOCH)
                                .unwrap_or_default()
                                .saturating_sub(*now)
                        }) + *now
                    }
                };
                file.write(at, frame)
                    .map_err(|source| MonitorError::WriteLog {
                        path: path.clone(),
                        source,
                    })?;
            }
        }
        if bus_closed && !noted_close {
            noted_close = true;
            let line = "the CAN interface closed the connection".to_owned();
            monitor.note(monitor.now, line);
        }
        let interrupted = options
            .interrupt
            .as_ref()
            .is_some_and(|flag| flag.load(Ordering::SeqCst));
        if interrupted {
            monitor.note(monitor.now, "stopped by Ctrl-C (SIGINT)".to_owned());
        }
        if terminal.is_none() {
            for (at, line) in monitor.happenings_since(printed) {
                println!("{:>9.3} s  {line}", at.as_secs_f64());
            }
            printed = monitor.happened;
        }
        if interrupted {
            break;
        }
        if options
            .stop_after
            .is_some_and(|limit| started.elapsed() >= limit)
        {
            break;
        }
        let Some(terminal) = &mut terminal else {
            if done {
                break;
            }
            continue;
        };
        let mut quit = false;
        for pressed in terminal.keys()? {
            match key(pressed) {
                _ if screen.help.is_some() => screen.help = None,
                Key::Quit => quit = true,
                Key::Help => screen.help = Some(help()),
                Key::Pause => screen.paused = !screen.paused,
                Key::Gfc if bus_closed => {
                    monitor.note(monitor.now, "no GFC sent: the bus has closed".to_owned());
                }
                Key::Gfc => {
                    if let Source::Replay { .. } = source {
                        monitor.note(monitor.now, "no GFC sent: this is a replay".to_owned());
                    }
                    if let Source::Bus(bus) = &mut source {
                        let gfc = shared::safety::gfc::frame();
                        bus.send(&gfc)?;
                        // The transport does not hand back what this tool sent; it went on
                        // the bus after the latest frame seen.
                        let now = monitor.now;
                        monitor.feed(now, &gfc);
                        monitor.note(now, "GFC sent by this monitor (key g)".to_owned());
                    }
                }
                Key::Other => {}
            }
        }
        if quit {
            break;
        }
        let due = last_draw.is_none_or(|at| at.elapsed() >= FRAME_PERIOD);
        if due && (!screen.paused || last_draw.is_none()) {
            terminal.draw(&monitor, &screen)?;
            last_draw = Some(Instant::now());
        } else if done {
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    drop(terminal);
    if let Some((mut file, path)) = recording {
        file.flush()
            .map_err(|source| MonitorError::WriteLog { path, source })?;
    }
    Ok(monitor)
}

/// A recording of the bus: a candump log, or a pcap.
enum Recording {
    /// `candump -l` lines on the interface `can0`.
    Candump(std::io::BufWriter<std::fs::File>),
    /// pcap records with the SocketCAN link type.
    Pcap(pcap::PcapWriter<std::io::BufWriter<std::fs::File>>),
}

impl Recording {
    /// A new recording at `path`: a pcap when the name ends in `.pcap`, else a candump log.
    fn create(path: &std::path::Path) -> std::io::Result<Recording> {
        let file = std::io::BufWriter::new(std::fs::File::create(path)?);
        let is_pcap = path
            .extension()
            .is_some_and(|extension| extension.eq_ignore_ascii_case("pcap"));
        Ok(if is_pcap {
            Recording::Pcap(pcap::PcapWriter::new(file)?)
        } else {
            Recording::Candump(file)
        })
    }

    /// Records `frame` at `at` (time since the Unix epoch, or since a replayed log's zero).
    fn write(&mut self, at: Duration, frame: &shared::CanFrame) -> std::io::Result<()> {
        match self {
            Recording::Candump(file) => writeln!(file, "{}", candump::line(at, "can0", frame)),
            Recording::Pcap(pcap) => pcap.write(at, frame),
        }
    }

    /// Writes out what is buffered.
    fn flush(&mut self) -> std::io::Result<()> {
        match self {
            Recording::Candump(file) => file.flush(),
            Recording::Pcap(pcap) => pcap.flush(),
        }
    }
}

/// The terminal in raw mode on the alternate screen, given back as it was when dropped (on
/// an error or a panic too).
struct Live(ratatui::DefaultTerminal);

impl Drop for Live {
    fn drop(&mut self) {
        ratatui::restore();
    }
}

/// A key pressed on the [`Terminal`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pressed {
    /// A character key.
    Char(char),
    /// Esc.
    Escape,
    /// Ctrl-C (in raw mode it is a key, not a signal).
    Interrupt,
}

/// The live view for a caller with a loop of its own (`cargo xtask run`): the terminal in
/// raw mode on the alternate screen, drawn in place, single keys without Enter. Dropping it
/// gives the terminal back as it was.
pub struct Terminal(Live);

impl Terminal {
    /// Takes over the terminal.
    pub fn open() -> Result<Terminal, MonitorError> {
        Ok(Terminal(Live(
            ratatui::try_init().map_err(MonitorError::Terminal)?,
        )))
    }

    /// Draws `monitor` with `screen` around it.
    pub fn draw(&mut self, monitor: &Monitor, screen: &Screen) -> Result<(), MonitorError> {
        self.0
            .0
            .draw(|frame| view::draw(frame, monitor, screen))
            .map(|_| ())
            .map_err(MonitorError::Terminal)
    }

    /// The keys pressed since the last call, without waiting.
    pub fn keys(&mut self) -> Result<Vec<Pressed>, MonitorError> {
        let mut keys = Vec::new();
        while event::poll(Duration::ZERO).map_err(MonitorError::Terminal)? {
            let Event::Key(key) = event::read().map_err(MonitorError::Terminal)? else {
                continue;
            };
            if key.kind != KeyEventKind::Press {
                continue;
            }
            keys.push(match key.code {
                KeyCode::Char('c') if key.modifiers.contains(KeyModifiers::CONTROL) => {
                    Pressed::Interrupt
                }
                KeyCode::Char(c) => Pressed::Char(c),
                KeyCode::Esc => Pressed::Escape,
                _ => continue,
            });
        }
        Ok(keys)
    }
}
