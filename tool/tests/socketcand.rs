//! The socketcand client against an in-process server built from the tool's own server
//! session (`socketcand::server`), over real TCP on the loopback address: handshake, frames
//! both ways, receive deadlines, extended frames ignored.

use safety_config::Transport;
use safety_config::socketcand::SocketcandClient;
use safety_config::socketcand::server::{GREETING, Output, Session};
use shared::{CanFrame, CanId};
use std::io::{Read, Write};
use std::net::TcpListener;
use std::time::Duration;

/// Serves one client: every frame it sends is answered by the same data on the identifier
/// 80h lower (as an SDO server answers 600h + n on 580h + n), preceded by an extended frame
/// the client must ignore.
fn serve_one() -> (String, std::thread::JoinHandle<Vec<String>>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let address = listener.local_addr().unwrap().to_string();
    let handle = std::thread::spawn(move || {
        let (mut stream, _) = listener.accept().unwrap();
        stream
            .set_read_timeout(Some(Duration::from_secs(5)))
            .unwrap();
        stream.write_all(GREETING.as_bytes()).unwrap();
        let mut session = Session::new("can0");
        let mut seen = Vec::new();
        let mut buffer = [0u8; 1024];
        loop {
            let count = match stream.read(&mut buffer) {
                Ok(0) | Err(_) => return seen,
                Ok(count) => count,
            };
            seen.push(String::from_utf8_lossy(&buffer[..count]).into_owned());
            for output in session.feed(&buffer[..count], Duration::ZERO) {
                match output {
                    Output::Reply(text) => stream.write_all(text.as_bytes()).unwrap(),
                    Output::Send(frame) => {
                        assert!(session.is_raw());
                        stream.write_all(b"< frame 1AAAAAAA 1.000000 01 >").unwrap();
                        let id = CanId::new(frame.id().raw() - 0x80).unwrap();
                        let answer = CanFrame::new(id, frame.data()).unwrap();
                        let message =
                            Session::frame_message(&answer, Duration::from_micros(1_500_042));
                        stream.write_all(message.as_bytes()).unwrap();
                    }
                    Output::Close => return seen,
                }
            }
        }
    });
    (address, handle)
}

#[test]
fn socketcand_raw_mode_round_trip() {
    let (address, server) = serve_one();
    let mut client = SocketcandClient::connect(&address, "can0").unwrap();
    let request = CanFrame::new(
        CanId::new(0x621).unwrap(),
        &[0x40, 0x18, 0x10, 1, 0, 0, 0, 0],
    )
    .unwrap();
    client.send(&request).unwrap();
    let deadline = client.now() + Duration::from_secs(5);
    let answer = client.receive(deadline).unwrap().expect("an answer");
    assert_eq!(answer.id().raw(), 0x5A1);
    assert_eq!(answer.data(), request.data());
    // Nothing more: the deadline passes and the client says so.
    let soon = client.now() + Duration::from_millis(50);
    assert_eq!(client.receive(soon).unwrap(), None);
    drop(client);
    let seen = server.join().unwrap().concat();
    assert!(seen.starts_with("< open can0 >< rawmode >"), "{seen}");
    assert!(
        seen.contains("< send 621 8 40 18 10 01 00 00 00 00 >"),
        "{seen}"
    );
}

#[test]
fn socketcand_session_refuses_frames_before_raw_mode_and_unknown_buses() {
    let mut session = Session::new("can0");
    assert_eq!(
        session.feed(b"< send 123 1 01 >", Duration::ZERO),
        vec![Output::Reply("< error unknown command >".into())]
    );
    assert_eq!(
        session.feed(b"< open can1 >", Duration::ZERO),
        vec![
            Output::Reply("< error could not open bus >".into()),
            Output::Close
        ]
    );
    let mut session = Session::new("can0");
    // Split across reads, two messages in one.
    assert_eq!(session.feed(b"< open ca", Duration::ZERO), vec![]);
    assert_eq!(
        session.feed(b"n0 >< rawmode >", Duration::ZERO),
        vec![
            Output::Reply("< ok >".into()),
            Output::Reply("< ok >".into())
        ]
    );
    assert!(session.is_raw());
    let frame = CanFrame::new(CanId::new(0x1AA).unwrap(), &[0x01, 0xF1]).unwrap();
    assert_eq!(
        session.feed(b"< send 1AA 2 1 F1 >", Duration::ZERO),
        vec![Output::Send(frame)]
    );
    assert_eq!(
        session.feed(b"< send 1AA 2 01F1 >", Duration::ZERO),
        vec![Output::Send(frame)]
    );
    assert_eq!(
        Session::frame_message(&frame, Duration::from_micros(23_424_242)),
        "< frame 1AA 23.424242 01F1 >"
    );
}

/// Bytes that are not socketcand messages are answered with an error naming them, in their
/// place among the replies, and the session goes on; a message that never ends is refused
/// once it is longer than `MAX_MESSAGE` and the connection closed, so that no client makes
/// the server hold more and more.
#[test]
fn socketcand_session_names_bytes_that_are_not_messages_and_bounds_a_message() {
    use safety_config::socketcand::server::MAX_MESSAGE;
    let mut session = Session::new("can0");
    let outputs = session.feed(b"< open can0 > hello\xFF\x00> < rawmode >", Duration::ZERO);
    assert_eq!(
        outputs,
        vec![
            Output::Reply("< ok >".into()),
            Output::Reply("< error \"hello???\" is not a socketcand message >".into()),
            Output::Reply("< ok >".into()),
        ]
    );
    assert!(session.is_raw());
    let long = [b'x'; 64].repeat(40);
    let outputs = session.feed(
        &[b"< send 123 8 ", long.as_slice()].concat(),
        Duration::ZERO,
    );
    assert_eq!(
        outputs,
        vec![
            Output::Reply(format!(
                "< error a message of more than {MAX_MESSAGE} bytes without its closing bracket >"
            )),
            Output::Close
        ]
    );
}

/// A bus address where nothing listens is reported as a sentence naming that address.
#[test]
fn no_server_is_reported_with_its_address() {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("a free port");
    let address = listener.local_addr().expect("its address").to_string();
    drop(listener);
    let error = match safety_config::socketcand::SocketcandClient::connect(&address, "can0") {
        Ok(_) => panic!("connected to a closed port"),
        Err(error) => error.to_string(),
    };
    assert!(
        error.starts_with(&format!("no socketcand server at {address}: ")),
        "{error}"
    );
}

/// No frame reaches a client before raw mode, nor within `RAW_MODE_GRACE` of the `rawmode`
/// reply (python-can reads that reply with one `recv`): such frames are held and released
/// in order once the grace is over.
#[test]
fn socketcand_session_holds_frames_within_the_raw_mode_grace() {
    use safety_config::socketcand::server::RAW_MODE_GRACE;
    let frame = |id: u16| CanFrame::new(CanId::new(id).unwrap(), &[id as u8]).unwrap();
    let at = Duration::from_millis(3);
    let mut session = Session::new("can0");
    assert_eq!(
        session.frame(&frame(0x101), at, at),
        None,
        "no bus open yet"
    );
    session.feed(b"< open can0 >", at);
    assert_eq!(
        session.frame(&frame(0x101), at, at),
        None,
        "not in raw mode"
    );
    let raw = Duration::from_millis(10);
    session.feed(b"< rawmode >", raw);
    assert_eq!(session.frame(&frame(0x102), raw, raw), None);
    assert_eq!(
        session.frame(&frame(0x103), raw, raw + RAW_MODE_GRACE / 2),
        None
    );
    assert_eq!(session.release_at(), Some(raw + RAW_MODE_GRACE));
    assert!(session.release(raw + RAW_MODE_GRACE / 2).is_empty());
    let released = session.release(raw + RAW_MODE_GRACE);
    assert_eq!(
        released,
        [
            Session::frame_message(&frame(0x102), raw),
            Session::frame_message(&frame(0x103), raw)
        ]
    );
    assert_eq!(session.release_at(), None);
    let later = raw + RAW_MODE_GRACE;
    assert_eq!(
        session.frame(&frame(0x104), later, later),
        Some(Session::frame_message(&frame(0x104), later))
    );
}

/// A `receive` whose deadline has already passed reads without waiting; the socket must be
/// blocking again afterwards, so that sends that fill the connection's buffers wait for the
/// server instead of failing with `WouldBlock`. The server reads nothing for a while after
/// the handshake, so the client's sends (more than the loopback buffers hold) must wait.
#[test]
fn socketcand_send_after_a_passed_deadline_waits_instead_of_failing() {
    const FRAMES: usize = 200_000;
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let address = listener.local_addr().unwrap().to_string();
    let server = std::thread::spawn(move || {
        let (mut stream, _) = listener.accept().unwrap();
        stream.write_all(GREETING.as_bytes()).unwrap();
        let mut session = Session::new("can0");
        let mut buffer = [0u8; 65536];
        let mut sends = 0usize;
        let mut raw_since: Option<std::time::Instant> = None;
        loop {
            // Once in raw mode, let the client's sends pile up before draining them.
            if let Some(since) = raw_since.take() {
                std::thread::sleep(Duration::from_millis(300).saturating_sub(since.elapsed()));
            }
            let count = match stream.read(&mut buffer) {
                Ok(0) | Err(_) => return sends,
                Ok(count) => count,
            };
            let was_raw = session.is_raw();
            for output in session.feed(&buffer[..count], Duration::ZERO) {
                match output {
                    Output::Reply(text) => stream.write_all(text.as_bytes()).unwrap(),
                    Output::Send(_) => sends += 1,
                    Output::Close => return sends,
                }
            }
            if !was_raw && session.is_raw() {
                raw_since = Some(std::time::Instant::now());
            }
        }
    });
    let mut client = SocketcandClient::connect(&address, "can0").unwrap();
    let passed = client.now();
    assert_eq!(client.receive(passed).unwrap(), None);
    let frame = CanFrame::new(
        CanId::new(0x621).unwrap(),
        &[0x40, 0x18, 0x10, 1, 0, 0, 0, 0],
    )
    .unwrap();
    for sent in 0..FRAMES {
        if let Err(error) = client.send(&frame) {
            panic!("send {sent} of {FRAMES} failed: {error}");
        }
    }
    drop(client);
    assert_eq!(server.join().unwrap(), FRAMES);
}
