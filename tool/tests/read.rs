//! `safety-config read` as a user types it, against an in-process socketcand server that
//! answers SDO uploads (CiA 301 expedited transfer) for a few objects: the default bus
//! follows CAN_HUB_PORT, the object is taken in every written form, and the value is printed
//! as the EDS types it.

use safety_config::socketcand::server::{GREETING, Output, Session};
use shared::{CanFrame, CanId};
use std::io::{Read, Write};
use std::net::TcpListener;
use std::process::Command;
use std::time::Duration;

/// The node the server answers for.
const NODE: u8 = 5;

/// The value of each object the server holds: `(index, sub-index, octets)`.
const OBJECTS: [(u16, u8, &[u8]); 3] = [
    (0x1018, 1, &[0x23, 0x01, 0x00, 0x00]),
    (0x1017, 0, &[0xF4, 0x01]),
    (0x1008, 0, b"Node"),
];

/// The expedited upload response to an upload request, or an abort "object does not exist"
/// (0602 0000h) for any other object.
fn answer(request: &CanFrame) -> Option<CanFrame> {
    let data = request.data();
    if request.id().raw() != 0x600 + u16::from(NODE) || data.first() != Some(&0x40) {
        return None;
    }
    let (index, sub) = (u16::from_le_bytes([data[1], data[2]]), data[3]);
    let mut response = [0u8; 8];
    response[1..4].copy_from_slice(&data[1..4]);
    match OBJECTS.iter().find(|(i, s, _)| *i == index && *s == sub) {
        Some((_, _, value)) => {
            // Expedited, size indicated, 4 − n unused octets.
            response[0] = 0x43 | ((4 - value.len() as u8) << 2);
            response[4..4 + value.len()].copy_from_slice(value);
        }
        None => {
            response[0] = 0x80;
            response[4..8].copy_from_slice(&0x0602_0000u32.to_le_bytes());
        }
    }
    let id = CanId::new(0x580 + u16::from(NODE)).unwrap();
    Some(CanFrame::new(id, &response).unwrap())
}

/// Serves `clients` connections one after the other; returns the port.
fn serve(clients: usize) -> (u16, std::thread::JoinHandle<()>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let handle = std::thread::spawn(move || {
        for _ in 0..clients {
            let (mut stream, _) = listener.accept().unwrap();
            stream
                .set_read_timeout(Some(Duration::from_secs(10)))
                .unwrap();
            stream.write_all(GREETING.as_bytes()).unwrap();
            let mut session = Session::new("can0");
            let mut buffer = [0u8; 1024];
            'client: loop {
                let count = match stream.read(&mut buffer) {
                    Ok(0) | Err(_) => break,
                    Ok(count) => count,
                };
                for output in session.feed(&buffer[..count], Duration::ZERO) {
                    match output {
                        Output::Reply(text) => stream.write_all(text.as_bytes()).unwrap(),
                        Output::Send(frame) => {
                            if let Some(response) = answer(&frame) {
                                let message =
                                    Session::frame_message(&response, Duration::from_secs(1));
                                stream.write_all(message.as_bytes()).unwrap();
                            }
                        }
                        Output::Close => break 'client,
                    }
                }
            }
        }
    });
    (port, handle)
}

/// Runs `safety-config read ARGUMENTS` with CAN_HUB_PORT = `port` and no --bus.
fn read(port: u16, arguments: &[&str]) -> (bool, String, String) {
    let output = Command::new(env!("CARGO_BIN_EXE_safety-config"))
        .env("CAN_HUB_PORT", port.to_string())
        .arg("read")
        .args(arguments)
        .output()
        .unwrap();
    (
        output.status.success(),
        String::from_utf8_lossy(&output.stdout).into_owned(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
}

#[test]
fn cia306_read_as_typed_follows_can_hub_port_and_prints_values_by_their_eds_type() {
    let forms: [&[&str]; 4] = [
        &["5", "1018", "1"],
        &["5", "1018:1"],
        &["5", "0x1018:0x01"],
        &["5", "1018h:01h"],
    ];
    let (port, server) = serve(forms.len() + 3);
    for form in forms {
        let (success, stdout, stderr) = read(port, form);
        assert!(success, "{form:?}: {stderr}");
        assert_eq!(
            stdout, "object 1018h:01h (identity: vendor-ID): UNSIGNED32 0x00000123 (291)\n",
            "{form:?}"
        );
    }
    let (success, stdout, stderr) = read(port, &["5", "1017", "0"]);
    assert!(success, "{stderr}");
    assert_eq!(stdout, "object 1017h:00h: UNSIGNED16 0x01F4 (500)\n");
    let (success, stdout, stderr) = read(port, &["5", "1008:0"]);
    assert!(success, "{stderr}");
    assert_eq!(stdout, "object 1008h:00h: VISIBLE_STRING \"Node\"\n");
    // JSON carries the type and the decoded value beside the octets.
    let output = Command::new(env!("CARGO_BIN_EXE_safety-config"))
        .env("CAN_HUB_PORT", port.to_string())
        .args(["--json", "read", "5", "1017", "0"])
        .output()
        .unwrap();
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(
        report,
        serde_json::json!({"node": 5, "index": 0x1017, "sub": 0, "bytes": [0xF4, 0x01],
            "type": "UNSIGNED16", "value": 500})
    );
    server.join().unwrap();

    // A bad argument is named before any bus is opened (no server listens now).
    let (success, _, stderr) = read(port, &["5", "1018"]);
    assert!(!success);
    assert_eq!(
        stderr,
        "error: the object \"1018\" needs a sub-index: 1018:0 or 1018 0 (hexadecimal)\n"
    );
    // A CAN_HUB_PORT that is not a port is named, not replaced by the default.
    let output = Command::new(env!("CARGO_BIN_EXE_safety-config"))
        .env("CAN_HUB_PORT", "hub")
        .args(["read", "5", "1018:1"])
        .output()
        .unwrap();
    assert!(!output.status.success());
    assert!(
        String::from_utf8_lossy(&output.stderr)
            .starts_with("error: CAN_HUB_PORT=\"hub\" is not a port from 1 to 65534"),
        "{output:?}"
    );
}
