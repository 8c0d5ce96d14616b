//! The SLCAN adapter against a pseudo-terminal pair: the test plays the adapter on one end
//! (answers the setup commands, acknowledges a transmitted frame, sends frames), the tool's
//! [`Slcan`] runs on the other.

use safety_config::Transport;
use safety_config::slcan::{Slcan, decode, encode};
use serialport::{SerialPort, TTYPort};
use shared::{CanFrame, CanId};
use std::io::{Read, Write};
use std::time::Duration;

/// Reads one carriage-return-terminated command from the adapter's side.
fn command(port: &mut TTYPort) -> String {
    let mut line = Vec::new();
    let mut byte = [0u8; 1];
    while port.read_exact(&mut byte).is_ok() {
        if byte[0] == b'\r' {
            break;
        }
        line.push(byte[0]);
    }
    String::from_utf8(line).unwrap()
}

#[test]
fn slcan_setup_send_and_receive_over_a_pty() {
    let (mut adapter, tool_end) = TTYPort::pair().expect("a pseudo-terminal pair");
    adapter.set_timeout(Duration::from_secs(5)).unwrap();
    let fake = std::thread::spawn(move || {
        let mut commands = Vec::new();
        // C (BEL: already closed), S6, O.
        for answer in [&b"\x07"[..], b"\r", b"\r"] {
            commands.push(command(&mut adapter));
            adapter.write_all(answer).unwrap();
        }
        commands.push(command(&mut adapter));
        // Transmit acknowledged, an extended frame, then the answer.
        adapter
            .write_all(b"z\rT1AAAAAAA101\rt5A184318100100000000\r")
            .unwrap();
        commands.push(command(&mut adapter));
        commands
    });
    let mut slcan = Slcan::open(Box::new(tool_end), 500_000).unwrap();
    let request = CanFrame::new(
        CanId::new(0x621).unwrap(),
        &[0x40, 0x18, 0x10, 1, 0, 0, 0, 0],
    )
    .unwrap();
    slcan.send(&request).unwrap();
    let deadline = slcan.now() + Duration::from_secs(5);
    let answer = slcan.receive(deadline).unwrap().expect("a frame");
    assert_eq!(answer.id().raw(), 0x5A1);
    assert_eq!(
        answer.data(),
        &[0x43, 0x18, 0x10, 0x01, 0x00, 0x00, 0x00, 0x00]
    );
    let soon = slcan.now() + Duration::from_millis(50);
    assert_eq!(slcan.receive(soon).unwrap(), None);
    drop(slcan);
    let commands = fake.join().unwrap();
    // The closing `C` written on drop races with the pseudo-terminal closing; not checked.
    assert_eq!(commands[..4], ["C", "S6", "O", "t62184018100100000000"]);
}

#[test]
fn slcan_frames_encode_and_decode() {
    let frame = CanFrame::new(CanId::new(0x7FF).unwrap(), &[]).unwrap();
    assert_eq!(encode(&frame), "t7FF0\r");
    assert_eq!(decode("t7FF0").unwrap(), Some(frame));
    let remote = CanFrame::remote(CanId::new(0x701).unwrap(), 1).unwrap();
    assert_eq!(encode(&remote), "r7011\r");
    assert_eq!(decode("r7011").unwrap(), Some(remote));
    // A trailing timestamp is ignored; garbage is an error, not a panic.
    assert_eq!(decode("t12310112AB").unwrap().unwrap().data(), &[0x01]);
    assert!(decode("t12").is_err());
    assert!(decode("t1239").is_err());
    assert!(decode("x").is_err());
    assert_eq!(decode("T1AAAAAAA0").unwrap(), None);
}
