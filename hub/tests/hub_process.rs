//! The `can-hub` program end to end: tools join over TCP speaking socketcand (the tool
//! library's client), a frame one sends reaches the others (not itself), and the traces it
//! writes are read by other tools: the candump log, the pcap as tshark decodes it (CANopen over
//! SocketCAN), and the event log.

use safety_config::Transport;
use safety_config::socketcand::SocketcandClient;
use shared::{CanFrame, CanId};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::process::{Child, Command};
use std::time::{Duration, Instant};

struct Hub {
    child: Child,
    dir: std::path::PathBuf,
}

impl Drop for Hub {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn start(port: u16) -> Hub {
    let dir = std::env::temp_dir().join(format!("can-hub-test-{}-{port}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let child = Command::new(env!("CARGO_BIN_EXE_can-hub"))
        .args(["--tcp", &format!("127.0.0.1:{port}")])
        .arg("--candump")
        .arg(dir.join("bus.log"))
        .arg("--pcap")
        .arg(dir.join("bus.pcap"))
        .arg("--events")
        .arg(dir.join("events.log"))
        .spawn()
        .unwrap();
    Hub { child, dir }
}

fn connect(port: u16) -> TcpStream {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        match TcpStream::connect(("127.0.0.1", port)) {
            Ok(stream) => {
                stream
                    .set_read_timeout(Some(Duration::from_secs(5)))
                    .unwrap();
                return stream;
            }
            Err(_) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(20)),
            Err(error) => panic!("hub not reachable: {error}"),
        }
    }
}

/// A socketcand client of the hub on `port` (waiting for the hub to listen).
fn tool(port: u16) -> SocketcandClient {
    let address = format!("127.0.0.1:{port}");
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        match SocketcandClient::connect(&address, "can0") {
            Ok(client) => return client,
            Err(_) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(20)),
            Err(error) => panic!("hub not reachable: {error}"),
        }
    }
}

/// The next frame a socketcand client receives, within 5 s.
fn next_frame(tool: &mut SocketcandClient) -> CanFrame {
    let deadline = tool.now() + Duration::from_secs(5);
    tool.receive(deadline)
        .expect("the connection holds")
        .expect("a frame within 5 s")
}

#[test]
fn frames_reach_the_other_participants_and_the_traces() {
    let port = 20_000 + (std::process::id() % 20_000) as u16;
    let hub = start(port);
    let mut first = tool(port);
    let mut tool = self::tool(port);
    let mut other = self::tool(port);
    // All joined (and out of the raw-mode grace) before anything is sent.
    std::thread::sleep(Duration::from_millis(200));
    let boot_up = CanFrame::new(CanId::new(0x701).unwrap(), &[0x00]).unwrap();
    let sdo = CanFrame::new(
        CanId::new(0x601).unwrap(),
        &[0x40, 0x00, 0x10, 0, 0, 0, 0, 0],
    )
    .unwrap();
    let gfc = CanFrame::new(CanId::new(0x001).unwrap(), &[]).unwrap();
    first.send(&boot_up).unwrap();
    assert_eq!(next_frame(&mut tool), boot_up);
    assert_eq!(next_frame(&mut other), boot_up);
    tool.send(&sdo).unwrap();
    assert_eq!(next_frame(&mut first), sdo);
    assert_eq!(next_frame(&mut other), sdo);
    other.send(&gfc).unwrap();
    assert_eq!(next_frame(&mut first), gfc);
    assert_eq!(next_frame(&mut tool), gfc, "a frame without data");
    // The sender does not receive its own frame back.
    let soon = tool.now() + Duration::from_millis(200);
    assert_eq!(tool.receive(soon).unwrap(), None);

    let log = std::fs::read_to_string(hub.dir.join("bus.log")).unwrap();
    let lines: Vec<&str> = log.lines().collect();
    assert_eq!(lines.len(), 3, "{log}");
    assert!(lines[0].ends_with(" can0 701#00"), "{log}");
    assert!(lines[1].ends_with(" can0 601#4000100000000000"), "{log}");
    assert!(lines[2].ends_with(" can0 001#"), "{log}");

    // tshark (Debian's package; `cargo xtask setup` installs it) decodes CANopen from the pcap.
    let tshark = Command::new("tshark")
        .args(["-r"])
        .arg(hub.dir.join("bus.pcap"))
        .args(["-d", "can.subdissector,canopen"])
        .output();
    match tshark {
        Ok(output) if output.status.success() => {
            let text = String::from_utf8_lossy(&output.stdout);
            let lines: Vec<&str> = text.lines().collect();
            assert_eq!(lines.len(), 3, "{text}");
            assert!(
                lines[0].contains("CANopen") && lines[0].contains("Boot-up"),
                "{text}"
            );
            assert!(
                lines[1].contains("CANopen") && lines[1].contains("SDO"),
                "{text}"
            );
        }
        Ok(output) => panic!("tshark failed: {}", String::from_utf8_lossy(&output.stderr)),
        Err(_) => panic!("tshark is missing: run `cargo xtask setup`"),
    }

    // The event log: the same frames with their senders, the tools by their participant
    // numbers (after the hub's own sender and its load), in time order.
    let path = hub.dir.join("events.log");
    let deadline = Instant::now() + Duration::from_secs(5);
    let events = loop {
        let text = std::fs::read_to_string(&path).unwrap();
        let events = can_hub::events::parse(&text).unwrap();
        if events.len() >= 3 || Instant::now() > deadline {
            break events;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let described: Vec<String> = events
        .iter()
        .map(|event| match event {
            can_hub::events::Event::Frame { from, frame, .. } => {
                format!("{from} {:03X}", frame.id().raw())
            }
            can_hub::events::Event::Output { channel, value, .. } => {
                format!("{channel} output {value}")
            }
        })
        .collect();
    assert_eq!(described, ["tool2 701", "tool3 601", "tool4 001"]);
    assert!(
        events.windows(2).all(|pair| pair[0].at() <= pair[1].at()),
        "{events:?}"
    );
}

/// The control port: commands are answered, bad ones with the reason (those for emulated
/// channels, which the hub has not, among them); an inserted frame reaches the tools; an
/// injected fault applies to the next matching frame; a muted tool's frames reach nobody until
/// it is unmuted.
#[test]
fn the_control_port_inserts_injects_and_mutes() {
    use can_hub::tool::Control;
    let port = 20_000 + (std::process::id() % 20_000) as u16 + 1;
    let control_port = port + 20_000;
    let dir = std::env::temp_dir().join(format!("can-hub-control-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let child = Command::new(env!("CARGO_BIN_EXE_can-hub"))
        .args(["--tcp", &format!("127.0.0.1:{port}")])
        .args(["--control", &format!("127.0.0.1:{control_port}")])
        .spawn()
        .unwrap();
    let _hub = Hub { child, dir };
    let mut tool = tool(port);
    let mut sender = self::tool(port);
    let mut control = Control::connect(
        &format!("127.0.0.1:{control_port}"),
        Duration::from_secs(10),
    )
    .unwrap();
    std::thread::sleep(Duration::from_millis(200));

    assert!(control.command("insert 0x123 01 02").unwrap().is_ok());
    let inserted = CanFrame::new(CanId::new(0x123).unwrap(), &[1, 2]).unwrap();
    assert_eq!(next_frame(&mut tool), inserted);

    assert!(control.command("drop 0x124").unwrap().is_ok());
    assert!(control.command("insert 0x124 01").unwrap().is_ok());
    assert!(control.command("insert 0x125 02").unwrap().is_ok());
    let next = next_frame(&mut tool);
    assert_eq!(next.id().raw(), 0x125, "the 124h frame was dropped");

    let error = control.command("drop 0x800").unwrap().unwrap_err();
    assert!(error.contains("11-bit"), "{error}");
    for line in [
        "input node1a 1",
        "cut node1-link",
        "restore node1-link",
        "power-cycle node1a",
    ] {
        let error = control.command(line).unwrap().unwrap_err();
        assert!(error.contains("no emulated channel"), "{line}: {error}");
    }
    let error = control.command("mute nobody").unwrap().unwrap_err();
    assert!(error.contains("no participant `nobody`"), "{error}");
    assert!(error.contains("tool2, tool3"), "{error}");

    // The tools are participants 2 and 3, as the event log names them.
    let frame = |n: u8| CanFrame::new(CanId::new(0x301).unwrap(), &[n]).unwrap();
    assert!(control.command("mute tool3").unwrap().is_ok());
    sender.send(&frame(1)).unwrap();
    let soon = tool.now() + Duration::from_millis(300);
    assert_eq!(
        tool.receive(soon).unwrap(),
        None,
        "a muted tool reaches nobody"
    );
    assert!(control.command("unmute tool3").unwrap().is_ok());
    sender.send(&frame(2)).unwrap();
    assert_eq!(next_frame(&mut tool), frame(2));
}

/// The control port refuses a line longer than `control::MAX_LINE` bytes with a sentence (a
/// client that sends no line end does not make the hub hold an ever longer line), and answers
/// the next command as usual.
#[test]
fn an_over_long_control_line_is_refused_and_the_port_keeps_working() {
    use std::io::BufRead;
    let port = 20_000 + (std::process::id() % 20_000) as u16 + 2;
    let control_port = port + 20_000;
    let dir = std::env::temp_dir().join(format!("can-hub-long-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let child = Command::new(env!("CARGO_BIN_EXE_can-hub"))
        .args(["--control", &format!("127.0.0.1:{control_port}")])
        .spawn()
        .unwrap();
    let _hub = Hub { child, dir };
    let mut control = connect(control_port);
    let mut replies = std::io::BufReader::new(control.try_clone().unwrap());
    let long = vec![b'x'; 1 << 20];
    control.write_all(&long).unwrap();
    control.write_all(b"\nclear\n").unwrap();
    let mut reply = String::new();
    replies.read_line(&mut reply).unwrap();
    assert!(
        reply.starts_with("error line longer than 256 bytes"),
        "{reply}"
    );
    reply.clear();
    replies.read_line(&mut reply).unwrap();
    assert!(reply.starts_with("ok clear"), "{reply}");
}

/// A tool that sends far faster than the bus carries frames waits (its transmit FIFO in the
/// hub is bounded, and the hub stops reading it): every frame still reaches the other tool,
/// in order, none lost.
#[test]
fn a_flooding_tool_waits_for_the_bus_and_every_frame_arrives_in_order() {
    let port = 20_000 + (std::process::id() % 20_000) as u16 + 3;
    let hub = start(port);
    let mut sender = tool(port);
    let mut receiver = tool(port);
    std::thread::sleep(Duration::from_millis(200));
    const FRAMES: u16 = 2000;
    let frames: Vec<CanFrame> = (0..FRAMES)
        .map(|n| CanFrame::new(CanId::new(0x300).unwrap(), &n.to_le_bytes()).unwrap())
        .collect();
    let writer = std::thread::spawn(move || {
        for frame in &frames {
            sender.send(frame).unwrap();
        }
        sender
    });
    for n in 0..FRAMES {
        let frame = next_frame(&mut receiver);
        assert_eq!(frame.data(), n.to_le_bytes(), "frame {n}");
    }
    let _sender = writer.join().unwrap();
    drop(hub);
}

/// A socketcand client that sends frames and closes its connection at once (a script that
/// sends and exits) still has every frame put on the bus, in order.
#[test]
fn frames_of_a_client_that_closed_at_once_still_reach_the_bus() {
    let port = 20_000 + (std::process::id() % 20_000) as u16 + 4;
    let hub = start(port);
    let mut receiver = tool(port);
    std::thread::sleep(Duration::from_millis(100));
    {
        let mut sender = connect(port);
        let mut greeting = [0u8; 6];
        sender.read_exact(&mut greeting).unwrap();
        assert_eq!(&greeting, b"< hi >");
        sender.write_all(b"< open can0 >").unwrap();
        let mut ok = [0u8; 6];
        sender.read_exact(&mut ok).unwrap();
        sender.write_all(b"< rawmode >").unwrap();
        sender.read_exact(&mut ok).unwrap();
        let burst: String = (0..20u8).map(|n| format!("< send 300 1 {n:X} >")).collect();
        sender.write_all(burst.as_bytes()).unwrap();
    }
    for n in 0..20u8 {
        assert_eq!(next_frame(&mut receiver).data(), [n], "frame {n}");
    }
    drop(hub);
}

/// The greeting or refusal a fresh connection reads first (up to its closing `>`).
fn first_reply(stream: &mut TcpStream) -> String {
    let mut reply = Vec::new();
    let mut byte = [0u8; 1];
    while stream.read(&mut byte).unwrap_or(0) == 1 {
        reply.push(byte[0]);
        if byte[0] == b'>' {
            break;
        }
    }
    String::from_utf8_lossy(&reply).into_owned()
}

/// Connections are bounded: the seventeenth tool is told in a sentence that the hub serves 16
/// at once and is closed; when one of the 16 leaves, a new tool is greeted again.
#[test]
fn a_tool_past_the_limit_is_refused_in_words_and_a_freed_place_is_served() {
    let port = 20_000 + (std::process::id() % 20_000) as u16 + 5;
    let _hub = start(port);
    let mut held: Vec<TcpStream> = (0..16).map(|_| connect(port)).collect();
    for stream in &mut held {
        assert_eq!(first_reply(stream), "< hi >");
    }
    let mut refused = connect(port);
    let reply = first_reply(&mut refused);
    assert!(
        reply.starts_with("< error the hub serves 16 tools at once"),
        "{reply}"
    );
    assert_eq!(
        refused.read(&mut [0u8; 1]).unwrap_or(0),
        0,
        "closed after it"
    );
    drop(held.pop());
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let mut again = connect(port);
        let reply = first_reply(&mut again);
        if reply == "< hi >" {
            break;
        }
        // The hub may not have seen the freed connection end yet.
        assert!(Instant::now() < deadline, "never served again: {reply}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The control port's `load`: the hub sends the frames given in turn (one at a time, so
/// that a late wake-up does not reorder them by identifier); the traffic never
/// runs ahead of its share of the bit time since the command (each frame's timestamp, the
/// end of the frame on the bus, bounds the bits before it); `load off` stops it; a load
/// that cannot be generated is refused with a sentence.
#[test]
fn the_hub_generates_load_in_turn_within_its_share_and_stops_on_command() {
    use can_hub::tool::Control;
    let port = 20_000 + (std::process::id() % 20_000) as u16 + 6;
    let control_port = port + 20_000;
    let dir = std::env::temp_dir().join(format!("can-hub-load-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let child = Command::new(env!("CARGO_BIN_EXE_can-hub"))
        .args(["--tcp", &format!("127.0.0.1:{port}")])
        .args(["--control", &format!("127.0.0.1:{control_port}")])
        .spawn()
        .unwrap();
    let _hub = Hub { child, dir };
    let mut tool = tool(port);
    let mut control = Control::connect(
        &format!("127.0.0.1:{control_port}"),
        Duration::from_secs(10),
    )
    .unwrap();
    std::thread::sleep(Duration::from_millis(200));

    let error = control.command("load off").unwrap().unwrap_err();
    assert_eq!(error, "no load is running");
    let error = control.command("load 95 281#55").unwrap().unwrap_err();
    assert!(error.contains("not one from 1 to 90 %"), "{error}");
    let error = control.command("load 20 101#01").unwrap().unwrap_err();
    assert!(error.contains("101h is an SRDO identifier"), "{error}");

    let start = control
        .command("load 20 281#5555555555555555 282#AA")
        .unwrap()
        .unwrap();
    let frames = [
        CanFrame::new(CanId::new(0x281).unwrap(), &[0x55; 8]).unwrap(),
        CanFrame::new(CanId::new(0x282).unwrap(), &[0xAA]).unwrap(),
    ];
    let mut bits = 0u64;
    for n in 0..400 {
        let deadline = tool.now() + Duration::from_secs(5);
        let (stamp, frame) = tool
            .receive_stamped(deadline)
            .unwrap()
            .expect("a frame within 5 s");
        assert_eq!(frame, frames[n % 2], "frame {n} in turn");
        bits += u64::from(can_hub::bus::frame_bits(&frame));
        // 20 % of 500 kbit/s: 100 bits per millisecond since the command.
        let allowed = (stamp.as_secs_f64() - start) * 100_000.0;
        assert!(
            bits as f64 <= allowed + 0.5,
            "frame {n}: {bits} bits by {:.6} s, more than the share's {allowed:.0}",
            stamp.as_secs_f64()
        );
    }
    let stopped = control.command("load off").unwrap().unwrap();
    // What was queued before the stop may still end; nothing starts after it.
    let last_frame = frames
        .iter()
        .map(|frame| can_hub::bus::frame_time(frame, 500_000).as_micros())
        .max()
        .unwrap() as f64
        / 1e6;
    loop {
        let deadline = tool.now() + Duration::from_millis(300);
        match tool.receive_stamped(deadline).unwrap() {
            Some((stamp, _)) => assert!(
                stamp.as_secs_f64() <= stopped + last_frame + 1e-6,
                "a frame ended at {:.6} s, after the stop at {stopped:.6} s",
                stamp.as_secs_f64()
            ),
            None => break,
        }
    }
}
