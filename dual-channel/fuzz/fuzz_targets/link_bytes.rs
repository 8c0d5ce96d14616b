//! Any bytes on the link line into the link receiver, with time passing: no panic, a result
//! only at a delimiter, no fault reported before the first valid message (the line may carry
//! the tail of a frame sent before this channel listened), the deadline never moves back and
//! is always later than the last valid message, and a frame that yields a message re-encodes
//! (reference encoder, same sequence number) to exactly the bytes received.
#![no_main]

#[path = "reference.rs"]
#[allow(
    dead_code,
    reason = "each target uses the reference encoders of its own line only"
)]
mod reference;

use dual_channel::link::{LinkFault, Message, Receiver};
use libfuzzer_sys::fuzz_target;
use shared::{Duration, Instant};

fuzz_target!(|data: &[u8]| {
    let Some((&timing, bytes)) = data.split_first() else {
        return;
    };
    // Low nibble: the timeout in ms (1..=16); high nibble: microseconds per byte (times 16).
    let timeout = Duration::from_millis(1 + u64::from(timing & 0x0F));
    let per_byte = Duration::from_micros(u64::from(timing >> 4) * 16);
    let mut now = Instant::ZERO;
    let mut receiver = Receiver::new(now, timeout, Duration::from_millis(5));
    let mut deadline = receiver.deadline();
    let mut up = false;
    let mut frame: Vec<u8> = Vec::new();
    for &byte in bytes {
        now = now + per_byte;
        let result = receiver.receive(now, byte);
        if byte != 0 {
            frame.push(byte);
        }
        match result {
            None => {}
            Some(_) if byte != 0 => panic!("a result before the frame's delimiter"),
            Some(Ok(message)) => {
                up = true;
                check_reencodes(&frame, &message);
                assert_eq!(receiver.deadline(), now + timeout);
                assert_eq!(receiver.poll(now), Ok(()));
            }
            Some(Err(LinkFault::Timeout)) => panic!("a timeout is reported by poll, not receive"),
            Some(Err(_)) => assert!(up, "no fault before the first valid message"),
        }
        assert!(
            receiver.deadline() >= deadline,
            "the deadline never moves back"
        );
        deadline = receiver.deadline();
        assert_eq!(receiver.poll(now).is_err(), now >= deadline);
        if byte == 0 {
            frame.clear();
        }
    }
});

/// The frame that gave `message` is the reference encoding of it at the frame's own number.
fn check_reencodes(frame: &[u8], message: &Message) {
    // The sequence number is the first two bytes after COBS decoding; a frame that decoded has
    // at least seven bytes, so its first code byte covers them unless one is 0.
    let mut raw = Vec::new();
    let mut at = 0;
    while at < frame.len() {
        let code = usize::from(frame[at]);
        raw.extend_from_slice(&frame[at + 1..(at + code).min(frame.len())]);
        at += code;
        if code < 0xFF && at < frame.len() {
            raw.push(0);
        }
    }
    let sequence = u16::from_le_bytes([raw[0], raw[1]]);
    let body = reference::link_body(message);
    let mut expected = reference::cobs(&reference::link_raw(sequence, &body));
    expected.pop();
    assert_eq!(
        frame,
        &expected[..],
        "a received message re-encodes to the bytes received"
    );
}
