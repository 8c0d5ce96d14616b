//! The monitor records what it sees into a candump log and replays it to the same model:
//! a scripted bus (simulated time) watched with a recording, then the recording replayed by
//! the library and by the `safety-config monitor --replay --fast` program.

use safety_config::Transport;
use safety_config::monitor::model::{Monitor, PairVerdict, SrdoWatch};
use safety_config::monitor::{self, Options, Source, candump};
use safety_config::transport::TransportError;
use shared::{CanFrame, CanId};
use std::collections::VecDeque;
use std::time::Duration;

const MS: Duration = Duration::from_millis(1);

fn frame(id: u16, data: &[u8]) -> CanFrame {
    CanFrame::new(CanId::new(id).unwrap(), data).unwrap()
}

/// A bus that hands out a script of frames on simulated time, then closes.
struct Script {
    now: Duration,
    frames: VecDeque<(Duration, CanFrame)>,
    sent: Vec<CanFrame>,
}

impl Transport for Script {
    fn now(&mut self) -> Duration {
        self.now
    }
    fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        self.sent.push(*frame);
        Ok(())
    }
    fn receive(&mut self, deadline: Duration) -> Result<Option<CanFrame>, TransportError> {
        match self.frames.front() {
            None => Err(TransportError::Closed),
            Some((at, _)) if *at > deadline => {
                self.now = deadline;
                Ok(None)
            }
            Some(_) => {
                let (at, frame) = self.frames.pop_front().unwrap_or_else(|| unreachable!());
                self.now = at;
                Ok(Some(frame))
            }
        }
    }
}

/// Node 1 producing 101h/102h every 100 ms for 2 s with heartbeats; one pair late (SRVT),
/// one not inverted, one inverted frame missing; node 33's EMCY; an SDO abort.
fn script() -> VecDeque<(Duration, CanFrame)> {
    let mut frames = VecDeque::new();
    frames.push_back((Duration::ZERO, frame(0x701, &[0x00])));
    for n in 0..20u32 {
        let at = n * 100 * MS + 10 * MS;
        frames.push_back((at, frame(0x701, &[0x05])));
        frames.push_back((at + MS, frame(0x101, &[0x01, 0x00])));
        let (gap, inverted): (Duration, &[u8]) = match n {
            5 => (100 * MS, &[0xFE, 0xFF]),
            9 => (2 * MS, &[0xFE, 0x7F]),
            13 => continue,
            _ => (2 * MS, &[0xFE, 0xFF]),
        };
        frames.push_back((at + MS + gap, frame(0x102, inverted)));
    }
    frames.push_back((
        2100 * MS,
        frame(0x0A1, &[0x00, 0x82, 0x11, 1, 0x05, 0, 0, 0]),
    ));
    frames.push_back((2110 * MS, frame(0x621, &[0x2F, 0x01, 0x13, 3, 0, 0, 0, 0])));
    frames.push_back((
        2111 * MS,
        frame(0x5A1, &[0x80, 0x01, 0x13, 3, 0x22, 0, 0, 0x08]),
    ));
    frames.make_contiguous().sort_by_key(|(at, _)| *at);
    frames
}

fn watched() -> Monitor {
    Monitor::new(vec![SrdoWatch {
        producer: Some((1, 1)),
        consumers: vec![(33, 1)],
        refresh: Some(100 * MS),
        sct: Some(500 * MS),
        srvt: Some(100 * MS),
        ..SrdoWatch::learned(0x101)
    }])
}

fn temporary(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("safety-config-monitor-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

#[test]
fn the_monitor_records_a_candump_log_that_replays_to_the_same_model() {
    let log = temporary("recorded.log");
    let bus = Script {
        now: Duration::ZERO,
        frames: script(),
        sent: Vec::new(),
    };
    let frames = bus.frames.len();
    let live = monitor::run(
        Source::Bus(Box::new(bus)),
        watched(),
        Options {
            record: Some(log.clone()),
            ..Options::default()
        },
    )
    .unwrap();
    let view = &live.srdos[&0x101];
    assert_eq!(view.count(PairVerdict::Valid), 17);
    assert_eq!(view.count(PairVerdict::SrvtExceeded), 1);
    assert_eq!(view.count(PairVerdict::NotInverted), 1);
    assert_eq!(view.count(PairVerdict::InvertedMissing), 1);
    assert_eq!(
        live.happenings.back().unwrap().1,
        "the CAN interface closed the connection"
    );

    let text = std::fs::read_to_string(&log).unwrap();
    let logged = candump::parse(&text, "recorded.log").unwrap();
    assert_eq!(logged.len(), frames);
    assert!(text.lines().all(|line| line.contains(" can0 ")), "{text}");

    let replayed = monitor::run(
        Source::replay(&log, true).unwrap(),
        watched(),
        Options::default(),
    )
    .unwrap();
    assert_eq!(replayed.srdos, live.srdos);
    assert_eq!(replayed.nodes, live.nodes);
    assert_eq!(replayed.aborts, live.aborts);
    let without_close = live.happenings.len() - 1;
    assert_eq!(
        Vec::from(replayed.happenings.clone()),
        Vec::from(live.happenings.clone())[..without_close]
    );
}

/// The program replays a log (not on a terminal: a line per happening, then the summary)
/// and judges it against the network file's SCT and SRVT; a log with a bad line is refused
/// with the line.
#[test]
fn the_monitor_program_replays_a_log_in_plain_lines_with_a_summary() {
    let log = temporary("program.log");
    let lines: Vec<String> = script()
        .iter()
        .map(|(at, frame)| candump::line(*at + Duration::from_secs(1_700_000_000), "can0", frame))
        .collect();
    std::fs::write(&log, lines.join("\n")).unwrap();
    let network = temporary("network.toml");
    std::fs::write(
        &network,
        r#"
[[node]]
id = 1
name = "emergency stop"
identity = { vendor = 0xABC, product = 0x304, serial = 1 }
[[node.srdo]]
number = 1
direction = "transmit"
refresh_time_ms = 100
srvt_ms = 20
cob_ids = [0x101, 0x102]
mapping = ["input", "input_inverted"]

[[node]]
id = 33
identity = { vendor = 0xABC, product = 0x304, serial = 33 }
[[node.srdo]]
number = 1
direction = "receive"
sct_ms = 500
srvt_ms = 100
cob_ids = [0x101, 0x102]
mapping = ["output", "output_inverted"]
"#,
    )
    .unwrap();
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_safety-config"))
        .args(["monitor", "--fast", "--replay"])
        .arg(&log)
        .arg(&network)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    for expected in [
        "    0.000 s  node 1: boot-up, Pre-operational",
        "    0.611 s  SRDO 101h/102h: SRVT exceeded",
        "    0.913 s  SRDO 101h/102h: not inverted",
        "    1.411 s  SRDO 101h/102h: inverted frame missing",
        "    2.100 s  node 33: EMCY 8200h: SRDO 1: not inverted",
        "## Summary",
        "node 1 (emergency stop): Operational",
        "SRDO 101h/102h (1 → 33): 17 valid, 1 not inverted, 1 SRVT exceeded, 1 inverted frame missing; largest gap 100.0 ms (SRVT 100 ms), largest period 200.0 ms (SCT 500 ms)",
    ] {
        assert!(stdout.contains(expected), "{expected:?} in\n{stdout}");
    }

    std::fs::write(&log, format!("{}\n(1.0) can0 101#00\n", lines[0])).unwrap();
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_safety-config"))
        .args(["monitor", "--fast", "--replay"])
        .arg(&log)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(
        stderr.contains("program.log:2: the timestamp `1.0` is not seconds.microseconds"),
        "{stderr}"
    );
}

/// The socketcand client hands the monitor the server's timestamp of each frame (on the
/// emulated bus, the hub's virtual time), not the time it read the frame from TCP; a
/// timestamp that is not `SECONDS.MICROSECONDS` reads as the time of reception.
#[test]
fn socketcand_frames_carry_the_servers_timestamp() {
    use std::io::{Read, Write};
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let address = listener.local_addr().unwrap().to_string();
    let server = std::thread::spawn(move || {
        let (mut stream, _) = listener.accept().unwrap();
        let mut buffer = [0u8; 256];
        stream.write_all(b"< hi >").unwrap();
        let _ = stream.read(&mut buffer).unwrap();
        stream.write_all(b"< ok >").unwrap();
        let _ = stream.read(&mut buffer).unwrap();
        stream.write_all(b"< ok >").unwrap();
        stream
            .write_all(b"< frame 101 12.345678 01A5 >< frame 102 soon FE5A >")
            .unwrap();
    });
    let mut client =
        safety_config::socketcand::SocketcandClient::connect(&address, "can0").unwrap();
    let deadline = client.now() + Duration::from_secs(5);
    let (at, first) = client.receive_stamped(deadline).unwrap().unwrap();
    assert_eq!(at, Duration::from_micros(12_345_678));
    assert_eq!(first, frame(0x101, &[0x01, 0xA5]));
    let before = client.now();
    let (at, second) = client.receive_stamped(deadline).unwrap().unwrap();
    assert_eq!(second, frame(0x102, &[0xFE, 0x5A]));
    assert!(at >= before && at <= client.now(), "{at:?}");
    server.join().unwrap();
}

/// Ctrl-C (SIGINT) ends a plain run as the end of the log would: the line saying so, then the
/// summary of what was seen up to then, and success. The log lasts ten minutes at the
/// recorded pace, so only the signal can end the run before the watchdog does.
#[test]
fn the_monitor_program_prints_its_summary_on_ctrl_c_in_plain_mode() {
    use std::io::BufRead;
    let log = temporary("interrupted.log");
    let start = Duration::from_secs(1_700_000_000);
    let mut lines = vec![candump::line(start, "can0", &frame(0x701, &[0x00]))];
    for n in 0..6000u64 {
        let at = start + Duration::from_millis(100 * n + 10);
        lines.push(candump::line(at, "can0", &frame(0x701, &[0x05])));
        lines.push(candump::line(at + MS, "can0", &frame(0x101, &[0x01, 0x00])));
        lines.push(candump::line(
            at + 2 * MS,
            "can0",
            &frame(0x102, &[0xFE, 0xFF]),
        ));
    }
    std::fs::write(&log, lines.join("\n")).unwrap();
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_safety-config"))
        .args(["monitor", "--plain", "--replay"])
        .arg(&log)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id().to_string();
    // The watchdog: a run that ignores the signal is killed, and the test fails below.
    let watchdog_pid = pid.clone();
    let (done, finished) = std::sync::mpsc::channel::<()>();
    let watchdog = std::thread::spawn(move || {
        if finished.recv_timeout(Duration::from_secs(120)).is_err() {
            let _ = std::process::Command::new("kill")
                .args(["-s", "KILL", &watchdog_pid])
                .status();
        }
    });
    let mut stdout = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut first = String::new();
    stdout.read_line(&mut first).unwrap();
    assert!(
        first.contains("node 1: boot-up, Pre-operational"),
        "{first}"
    );
    let sent = std::process::Command::new("kill")
        .args(["-s", "INT", &pid])
        .status()
        .unwrap();
    assert!(sent.success());
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut stdout, &mut rest).unwrap();
    let status = child.wait().unwrap();
    let _ = done.send(());
    watchdog.join().unwrap();
    let mut stderr = String::new();
    std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
    assert!(status.success(), "{status}: {first}{rest}\n{stderr}");
    let interrupted = rest
        .find("stopped by Ctrl-C (SIGINT)")
        .unwrap_or_else(|| panic!("no Ctrl-C line in\n{first}{rest}"));
    let summary = rest
        .find("## Summary")
        .unwrap_or_else(|| panic!("no summary in\n{first}{rest}"));
    assert!(interrupted < summary, "{rest}");
    assert!(
        rest[summary..].contains("node 1: "),
        "the summary names what was seen: {rest}"
    );
    assert!(
        !rest.contains("6000 valid"),
        "the whole log was replayed: {rest}"
    );
}
