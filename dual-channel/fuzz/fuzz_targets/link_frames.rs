//! Well-framed link traffic into the link receiver, checked against a reference model of its
//! sequence and timeout rules (EN 50325-5 Annex A.4: a missing, repeated, corrupt or late
//! message is a fault).
//!
//! Messages come from the input through the reference decoder of the messages' layout
//! (`reference::link_message`, written from the layout's table), so every variant of the
//! table is reached. Frames are built by the
//! reference encoder at sequence numbers the input chooses (starting anywhere, so the count
//! wraps), with valid CRCs, and then lost, replayed, corrupted (one byte, before COBS: a
//! CRC-32 detects every such error) or mixed with over-long noise and idle delimiters.
//!
//! Checked, for every frame: the receiver's result equals the model's (message, `Missing`,
//! `Repeated`, `Corrupt`, `Malformed`, or nothing before the first valid message), it reports
//! only at a delimiter, its deadline equals the model's and `poll` reports the timeout exactly
//! when the model says. The product's `Sender` encodes every message exactly as the reference
//! encoder does, and a body is accepted only when it is the one encoding of its message.
#![no_main]

#[path = "reference.rs"]
#[allow(
    dead_code,
    reason = "each target uses the reference encoders of its own line only"
)]
mod reference;

use arbitrary::Arbitrary;
use dual_channel::link::{LinkFault, Message, Receiver, Sender};
use libfuzzer_sys::fuzz_target;
use shared::{Duration, Instant};

#[derive(Arbitrary, Debug)]
enum Step {
    /// The next message (a tag and field bytes, `reference::link_body_from`; skipped when a
    /// flag is neither 0 nor 1).
    Send { message: Vec<u8> },
    /// This many messages (1..=256) lost on the line.
    Lose { count: u8 },
    /// A frame sent earlier, again (`back` frames ago).
    Replay { back: u8 },
    /// The next message with one byte of its raw frame changed.
    Corrupt { message: Vec<u8>, at: u8, mask: u8 },
    /// A frame with any body and a valid CRC at the next sequence number.
    Body { body: Vec<u8> },
    /// More non-zero bytes than a frame can hold, then a delimiter.
    Noise { extra: u8, fill: u8 },
    /// Idle delimiters.
    Idle { count: u8 },
    /// Time passes.
    Wait { ms: u16 },
}

#[derive(Arbitrary, Debug)]
struct Input {
    first_sequence: u16,
    timeout_ms: u8,
    startup_ms: u16,
    steps: Vec<Step>,
}

/// The receiver's rules, written from its documentation.
struct Model {
    expected: Option<u16>,
    deadline: Instant,
    timeout: Duration,
}

type Outcome = Option<Result<Message, LinkFault>>;

impl Model {
    /// A frame with a valid CRC and a message at `sequence`.
    fn valid(&mut self, now: Instant, sequence: u16, message: Message) -> Outcome {
        let expected = self.expected.unwrap_or(sequence);
        self.expected = Some(sequence.wrapping_add(1));
        let ahead = sequence.wrapping_sub(expected);
        Some(if ahead == 0 {
            self.deadline = now + self.timeout;
            Ok(message)
        } else if ahead < 0x8000 {
            Err(LinkFault::Missing {
                expected,
                received: sequence,
            })
        } else {
            Err(LinkFault::Repeated {
                expected,
                received: sequence,
            })
        })
    }

    /// A frame that fails before its sequence number counts: reported once the link is up.
    fn broken(&self, fault: LinkFault) -> Outcome {
        self.expected.map(|_| Err(fault))
    }
}

fn message_from(bytes: &[u8]) -> Option<(Message, Vec<u8>)> {
    let body = reference::link_body_from(bytes);
    Some((reference::link_message(&body)?, body))
}

/// Feeds `wire` at `now`; the result of its last byte (every earlier byte must give none).
fn deliver(receiver: &mut Receiver, now: Instant, wire: &[u8]) -> Outcome {
    let mut outcome = None;
    for (at, &byte) in wire.iter().enumerate() {
        let result = receiver.receive(now, byte);
        if result.is_some() {
            assert_eq!(byte, 0, "a result only at a delimiter");
            assert!(outcome.is_none(), "one result per frame");
            assert_eq!(at, wire.len() - 1);
            outcome = result;
        }
    }
    outcome
}

fuzz_target!(|input: Input| {
    reference::check_crc();
    let timeout = Duration::from_millis(1 + u64::from(input.timeout_ms));
    let mut now = Instant::ZERO;
    let startup = Duration::from_millis(u64::from(input.startup_ms));
    let mut receiver = Receiver::new(now, timeout, startup);
    let mut model = Model {
        expected: None,
        deadline: now + startup,
        timeout,
    };
    let mut sender = Sender::new();
    let mut sender_sequence = 0u16;
    let mut sequence = input.first_sequence;
    let mut sent: Vec<(Vec<u8>, u16, Message)> = Vec::new();

    for step in input.steps.iter().take(256) {
        let (wire, expected) = match step {
            Step::Send { message } => {
                let Some((message, body)) = message_from(message) else {
                    continue;
                };
                // The product's encoder against the reference, at its own sequence numbers.
                let encoded = sender
                    .encode(&message)
                    .unwrap_or_else(|_| unreachable!("every message fits"));
                assert_eq!(
                    &encoded[..],
                    &reference::cobs(&reference::link_raw(sender_sequence, &body))[..]
                );
                sender_sequence = sender_sequence.wrapping_add(1);
                let wire = reference::cobs(&reference::link_raw(sequence, &body));
                let expected = model.valid(now, sequence, message);
                sent.push((wire.clone(), sequence, message));
                sequence = sequence.wrapping_add(1);
                (wire, expected)
            }
            Step::Lose { count } => {
                sequence = sequence.wrapping_add(u16::from(*count) + 1);
                continue;
            }
            Step::Replay { back } => {
                let Some((wire, replayed, message)) = sent
                    .len()
                    .checked_sub(1 + usize::from(*back))
                    .map(|at| sent[at].clone())
                else {
                    continue;
                };
                let expected = model.valid(now, replayed, message);
                (wire, expected)
            }
            Step::Corrupt { message, at, mask } => {
                let Some((_, body)) = message_from(message) else {
                    continue;
                };
                let mut raw = reference::link_raw(sequence, &body);
                let at = usize::from(*at) % raw.len();
                raw[at] ^= if *mask == 0 { 0x01 } else { *mask };
                // The message was sent; the line changed it.
                sequence = sequence.wrapping_add(1);
                (reference::cobs(&raw), model.broken(LinkFault::Corrupt))
            }
            Step::Body { body } => {
                let body = &body[..body.len().min(40)];
                let raw = reference::link_raw(sequence, body);
                // The receiver takes a message in its one encoding only.
                let expected = match reference::link_message(body) {
                    Some(message) => {
                        let expected = model.valid(now, sequence, message);
                        sequence = sequence.wrapping_add(1);
                        expected
                    }
                    None => model.broken(LinkFault::Malformed),
                };
                (reference::cobs(&raw), expected)
            }
            Step::Noise { extra, fill } => {
                let mut wire = vec![
                    if *fill == 0 { 0x55 } else { *fill };
                    dual_channel::link::MAX_WIRE + 1 + usize::from(*extra)
                ];
                wire.push(0);
                (wire, model.broken(LinkFault::Malformed))
            }
            Step::Idle { count } => (vec![0; usize::from(*count % 8)], None),
            Step::Wait { ms } => {
                now = now + Duration::from_millis(u64::from(*ms));
                (Vec::new(), None)
            }
        };
        assert_eq!(
            deliver(&mut receiver, now, &wire),
            expected,
            "step {step:?}"
        );
        assert_eq!(receiver.deadline(), model.deadline);
        let late = now >= model.deadline;
        assert_eq!(
            receiver.poll(now),
            if late {
                Err(LinkFault::Timeout)
            } else {
                Ok(())
            }
        );
    }
});
