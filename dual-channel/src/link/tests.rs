//! Link framing and receiver checks: round trips, and every fault the link must detect (missing,
//! late, repeated, corrupt), plus no panic on any byte stream.

use super::*;
use proptest::prelude::*;

const TIMEOUT: Duration = Duration::from_millis(10);

fn messages() -> Vec<Message> {
    vec![
        Message::Heartbeat {
            nmt: 0x05,
            working: true,
            epoch: 3,
            valid: 0xA5,
            signatures: 0x1234_5678,
            inputs: u32::MAX,
            node: 0xFF,
            bit_rate: 0xFF,
        },
        Message::Inputs {
            sample: 0xDEAD_BEEF,
        },
        Message::Verdict {
            srdo: 64,
            pair: u32::MAX,
            data: u64::MAX,
            valid: true,
        },
        Message::TransmitMismatch { srdo: 1 },
        Message::SafeState { cause: 0xFF },
        Message::PlainFrame {
            id: 0x7FF,
            len: 8,
            data: u64::MAX,
        },
        Message::ForeignFrame { id: 0x7FF },
        Message::Probe { stamp: u32::MAX },
        Message::Echo { stamp: 0 },
        Message::LssAnswer { data: [0xFF; 8] },
        #[cfg(feature = "simplecan")]
        Message::SimpleCanPacket {
            id: u16::MAX,
            len: 8,
            data: [0xFF; 8],
        },
    ]
}

fn feed(receiver: &mut Receiver, now: Instant, bytes: &[u8]) -> Vec<Result<Message, LinkFault>> {
    bytes
        .iter()
        .filter_map(|&byte| receiver.receive(now, byte))
        .collect()
}

#[test]
fn every_message_round_trips_and_fits_the_wire_budget() {
    let mut sender = Sender::new();
    let mut receiver = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
    for message in messages() {
        let wire = sender.encode(&message).unwrap();
        assert_eq!(wire.last(), Some(&0), "delimited");
        assert_eq!(wire.iter().filter(|&&b| b == 0).count(), 1, "one zero only");
        assert_eq!(feed(&mut receiver, Instant::ZERO, &wire), [Ok(message)]);
    }
}

#[test]
fn a_lost_message_is_reported_once_then_the_link_resynchronises() {
    let mut sender = Sender::new();
    let mut receiver = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
    let heartbeat = Message::Heartbeat {
        nmt: 5,
        working: true,
        epoch: 0,
        valid: 0xA5,
        signatures: 0,
        inputs: 0,
        node: 33,
        bit_rate: 0xFF,
    };
    feed(
        &mut receiver,
        Instant::ZERO,
        &sender.encode(&heartbeat).unwrap(),
    );
    let _lost = sender.encode(&heartbeat).unwrap();
    let third = sender.encode(&heartbeat).unwrap();
    assert_eq!(
        feed(&mut receiver, Instant::ZERO, &third),
        [Err(LinkFault::Missing {
            expected: 1,
            received: 2
        })]
    );
    let fourth = sender.encode(&heartbeat).unwrap();
    assert_eq!(feed(&mut receiver, Instant::ZERO, &fourth), [Ok(heartbeat)]);
}

#[test]
fn the_first_message_starts_the_count_within_the_startup_time() {
    let mut sender = Sender::new();
    for _ in 0..40 {
        let _ = sender.encode(&Message::Inputs { sample: 0 }).unwrap();
    }
    let startup = Duration::from_millis(500);
    let mut receiver = Receiver::new(Instant::ZERO, TIMEOUT, startup);
    assert_eq!(receiver.poll(Instant::from_millis(499)), Ok(()));
    let at = Instant::from_millis(300);
    let message = Message::Inputs { sample: 40 };
    assert_eq!(
        feed(&mut receiver, at, &sender.encode(&message).unwrap()),
        [Ok(message)]
    );
    assert_eq!(receiver.deadline(), at + TIMEOUT);
    let silent = Receiver::new(Instant::ZERO, TIMEOUT, startup);
    assert_eq!(
        silent.poll(Instant::from_millis(500)),
        Err(LinkFault::Timeout)
    );
}

/// EN 50325-5 Annex A.4 (Model III link supervision): a board whose other channel may take
/// longer to start (the hardware's erase ahead of a parameter slot) extends the wait for the
/// first message, and only that: once a message came, the timeout alone counts.
#[test]
fn cia304_9_5_a_longer_start_up_extends_only_the_wait_for_the_first_message() {
    let startup = Duration::from_millis(500);
    let longer = Duration::from_millis(4000);
    let mut waiting = Receiver::new(Instant::ZERO, TIMEOUT, startup);
    waiting.extend_startup(longer);
    assert_eq!(waiting.poll(Instant::from_millis(4499)), Ok(()));
    assert_eq!(
        waiting.poll(Instant::from_millis(4500)),
        Err(LinkFault::Timeout)
    );

    let mut sender = Sender::new();
    let mut receiver = Receiver::new(Instant::ZERO, TIMEOUT, startup);
    let at = Instant::from_millis(100);
    let message = Message::Inputs { sample: 1 };
    assert_eq!(
        feed(&mut receiver, at, &sender.encode(&message).unwrap()),
        [Ok(message)]
    );
    receiver.extend_startup(longer);
    assert_eq!(receiver.deadline(), at + TIMEOUT);
}

#[test]
fn garbage_before_the_first_message_is_ignored_but_not_after() {
    let mut sender = Sender::new();
    let mut receiver = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
    let wire = sender.encode(&Message::Inputs { sample: 1 }).unwrap();
    // The tail of a frame sent before this channel listened.
    assert_eq!(feed(&mut receiver, Instant::ZERO, &wire[3..]), []);
    let next = sender.encode(&Message::Inputs { sample: 2 }).unwrap();
    assert_eq!(
        feed(&mut receiver, Instant::ZERO, &next),
        [Ok(Message::Inputs { sample: 2 })]
    );
    // The tail decodes to a frame long enough for a message, whose CRC fails.
    assert_eq!(
        feed(&mut receiver, Instant::ZERO, &wire[3..]),
        [Err(LinkFault::Corrupt)]
    );
}

#[test]
fn a_repeated_message_is_a_fault() {
    let mut sender = Sender::new();
    let mut receiver = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
    let wire = sender.encode(&Message::SafeState { cause: 1 }).unwrap();
    feed(&mut receiver, Instant::ZERO, &wire);
    assert_eq!(
        feed(&mut receiver, Instant::ZERO, &wire),
        [Err(LinkFault::Repeated {
            expected: 1,
            received: 0
        })]
    );
}

#[test]
fn a_flipped_bit_anywhere_is_never_accepted() {
    let mut sender = Sender::new();
    let wire = sender
        .encode(&Message::Verdict {
            srdo: 3,
            pair: 77,
            data: 0x0102_0304,
            valid: true,
        })
        .unwrap();
    for at in 0..wire.len() - 1 {
        for bit in 0..8 {
            let mut damaged = wire.clone();
            damaged[at] ^= 1 << bit;
            let mut receiver = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
            let results = feed(&mut receiver, Instant::ZERO, &damaged);
            assert!(
                results
                    .iter()
                    .all(|r| matches!(r, Err(LinkFault::Corrupt | LinkFault::Malformed))),
                "byte {at} bit {bit}: {results:?}"
            );
        }
    }
}

#[test]
fn the_link_times_out_at_the_deadline_itself_and_each_message_extends_it() {
    let mut sender = Sender::new();
    let mut receiver = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
    assert_eq!(receiver.poll(Instant::from_micros(9_999)), Ok(()));
    assert_eq!(
        receiver.poll(Instant::from_millis(10)),
        Err(LinkFault::Timeout)
    );
    let at = Instant::from_millis(8);
    feed(
        &mut receiver,
        at,
        &sender.encode(&Message::Inputs { sample: 1 }).unwrap(),
    );
    assert_eq!(receiver.deadline(), at + TIMEOUT);
    assert_eq!(receiver.poll(Instant::from_millis(17)), Ok(()));
    assert_eq!(
        receiver.poll(Instant::from_millis(18)),
        Err(LinkFault::Timeout)
    );
}

#[test]
fn an_overlong_frame_is_malformed_and_the_next_one_is_read() {
    let mut sender = Sender::new();
    let mut receiver = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
    let first = sender.encode(&Message::Inputs { sample: 6 }).unwrap();
    assert_eq!(feed(&mut receiver, Instant::ZERO, &first).len(), 1);
    let noise = [0x55u8; 3 * MAX_WIRE];
    assert_eq!(feed(&mut receiver, Instant::ZERO, &noise), []);
    assert_eq!(
        receiver.receive(Instant::ZERO, 0),
        Some(Err(LinkFault::Malformed))
    );
    let wire = sender.encode(&Message::Inputs { sample: 7 }).unwrap();
    assert_eq!(
        feed(&mut receiver, Instant::ZERO, &wire),
        [Ok(Message::Inputs { sample: 7 })]
    );
    // Idle delimiters are not messages.
    assert_eq!(feed(&mut receiver, Instant::ZERO, &[0, 0, 0]), []);
}

#[test]
fn sequence_numbers_compare_across_the_wrap() {
    assert_eq!(sequence_order(0, 0xFFFF), Order::Ahead);
    assert_eq!(sequence_order(0xFFFF, 0), Order::Behind);
    assert_eq!(sequence_order(7, 7), Order::Expected);
}

proptest! {
    /// Any body the layout reads is the one encoding of the message it reads as: written
    /// again, it gives the same octets (so no two bodies carry one message), and no body
    /// panics the reader. Tags drawn from 00h..0Eh, so that every known one and a few
    /// unknown ones come up.
    #[test]
    fn a_body_the_layout_reads_is_the_one_encoding_of_its_message(
        tag in 0u8..=0x0E,
        fields in proptest::collection::vec(prop_oneof![Just(0u8), Just(1u8), any::<u8>()], 0..=16),
    ) {
        let body = [&[tag][..], &fields].concat();
        if let Some(message) = Message::read(&body) {
            let mut out = [0u8; layout::MAX_BODY];
            let len = message.write(&mut out);
            prop_assert_eq!(len, Some(body.len()));
            prop_assert_eq!(&out[..body.len()], &body[..]);
        }
    }

    /// Any byte stream: no panic, and noise is never accepted as a message (it would need a
    /// valid COBS frame, a matching CRC-32 and a known message at once).
    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let mut receiver = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
        for result in feed(&mut receiver, Instant::ZERO, &bytes) {
            prop_assert!(result.is_err(), "{result:?}");
        }
    }

    /// EN 50325-5 Annex A.4: a stream of messages, noise, corrupted, dropped and repeated
    /// frames, handed over in slices of any sizes, gives the messages and faults it gives
    /// byte by byte, in order (and with them the same deadline).
    #[test]
    fn annex_a4_slices_of_any_size_complete_what_single_bytes_complete(
        parts in proptest::collection::vec((0u8..5, any::<u8>()), 0..40),
        cuts in proptest::collection::vec(1usize..70, 1..20),
    ) {
        let mut sender = Sender::new();
        let mut stream = Vec::new();
        let mut last = Vec::new();
        for (i, &(kind, value)) in parts.iter().enumerate() {
            let message = messages()[i % messages().len()];
            match kind {
                0 | 1 => {
                    last = sender.encode(&message).unwrap().to_vec();
                    stream.extend_from_slice(&last);
                }
                2 => {
                    let mut wire = sender.encode(&message).unwrap().to_vec();
                    let at = usize::from(value) % wire.len();
                    wire[at] ^= 1 << (value % 8);
                    stream.extend_from_slice(&wire);
                }
                3 => stream.extend_from_slice(&last),
                _ => stream.extend_from_slice(&[value, value.wrapping_mul(7), 0]),
            }
        }
        let now = Instant::from_millis(1);
        let mut one = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
        let expected = feed(&mut one, now, &stream);
        let mut sliced = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
        let mut got = Vec::new();
        let mut rest = &stream[..];
        for &cut in cuts.iter().cycle() {
            if rest.is_empty() {
                break;
            }
            let (mut chunk, after) = rest.split_at(cut.min(rest.len()));
            rest = after;
            while !chunk.is_empty() {
                let (taken, completed) = sliced.receive_bytes(now, chunk);
                prop_assert!(taken > 0 && taken <= chunk.len());
                chunk = &chunk[taken..];
                got.extend(completed);
            }
        }
        prop_assert_eq!(got, expected);
        prop_assert_eq!(sliced.deadline(), one.deadline());
    }

    /// Any message sequence with random losses: every delivered message is the one sent with
    /// that sequence number, and each loss is reported.
    #[test]
    fn losses_are_always_reported(lost in proptest::collection::vec(any::<bool>(), 1..60)) {
        let mut sender = Sender::new();
        let mut receiver = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
        // Losses before the first message received are not gaps: it starts the count.
        let mut gap = false;
        let mut started = false;
        for (i, &drop) in lost.iter().enumerate() {
            let message = Message::Inputs { sample: i as u32 };
            let wire = sender.encode(&message).unwrap();
            if drop {
                gap = started;
                continue;
            }
            started = true;
            let results = feed(&mut receiver, Instant::ZERO, &wire);
            prop_assert_eq!(results.len(), 1);
            if gap {
                let missing = matches!(results[0], Err(LinkFault::Missing { .. }));
                prop_assert!(missing);
            } else {
                prop_assert_eq!(results[0], Ok(message));
            }
            gap = false;
        }
    }
}

/// A frame with a valid CRC at the next sequence number around `body`, COBS-encoded and
/// delimited: what a sender with a different encoder would put on the line.
fn frame_around(sequence: u16, body: &[u8]) -> Vec<u8> {
    let mut raw = sequence.to_le_bytes().to_vec();
    raw.extend_from_slice(body);
    let crc = CRC.checksum(&raw);
    raw.extend_from_slice(&crc.to_le_bytes());
    let mut wire = [0u8; 2 * MAX_WIRE];
    let len = cobs::encode(&raw, &mut wire);
    let mut frame = wire[..len].to_vec();
    frame.push(0);
    frame
}

/// A frame with a valid CRC whose body is not the one encoding of a message (a `bool` of
/// 02h, a body one octet short or long, an unknown tag) is malformed: each message has exactly
/// one frame, so what the CRC protects is exactly what the sender's encoder wrote (EN 50325-5
/// Annex A.4).
#[test]
fn cia304_9_5_a_link_message_in_a_non_canonical_encoding_is_malformed() {
    let mut sender = Sender::new();
    let mut receiver = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
    let first = sender.encode(&Message::Inputs { sample: 27 }).unwrap();
    assert_eq!(
        feed(&mut receiver, Instant::ZERO, &first),
        [Ok(Message::Inputs { sample: 27 })]
    );
    let verdict = [0x03, 1, 7, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 1];
    // A malformed frame does not move the count: each of these is at sequence number 1.
    for body in [
        // `valid` 02h.
        [&verdict[..14], &[2]].concat(),
        verdict[..14].to_vec(),
        [&verdict[..], &[0]].concat(),
        vec![0x00, 27, 0, 0, 0],
        vec![0xFF, 27, 0, 0, 0],
        vec![],
    ] {
        assert_eq!(
            feed(&mut receiver, Instant::ZERO, &frame_around(1, &body)),
            [Err(LinkFault::Malformed)],
            "{body:02X?}"
        );
    }
    // The same frame as the sender writes it is a message.
    assert_eq!(
        feed(&mut receiver, Instant::ZERO, &frame_around(1, &verdict)),
        [Ok(Message::Verdict {
            srdo: 1,
            pair: 7,
            data: 0x0807_0605_0403_0201,
            valid: true
        })]
    );
}

/// The layout table of `link::layout`, octet by octet: one vector per variant, each at its
/// widest, written from the table (not from the encoder), with the length the table gives.
#[test]
fn every_variant_has_the_layout_of_the_table() {
    let cases: Vec<(Message, Vec<u8>)> = vec![
        (
            Message::Heartbeat {
                nmt: 0x05,
                working: true,
                epoch: 0x21,
                valid: 0xA5,
                signatures: 0x1234_5678,
                inputs: 0x9ABC_DEF0,
                node: 0x21,
                bit_rate: 0x02,
            },
            vec![
                0x01, 0x05, 0x01, 0x21, 0xA5, 0x78, 0x56, 0x34, 0x12, 0xF0, 0xDE, 0xBC, 0x9A, 0x21,
                0x02,
            ],
        ),
        (
            Message::Inputs {
                sample: 0x0403_0201,
            },
            vec![0x02, 1, 2, 3, 4],
        ),
        (
            Message::Verdict {
                srdo: 64,
                pair: 0x0403_0201,
                data: 0x1817_1615_1413_1211,
                valid: false,
            },
            vec![
                0x03, 64, 1, 2, 3, 4, 0x11, 0x12, 0x13, 0x14, 0x15, 0x16, 0x17, 0x18, 0,
            ],
        ),
        (Message::TransmitMismatch { srdo: 9 }, vec![0x04, 9]),
        (Message::SafeState { cause: 0x3B }, vec![0x05, 0x3B]),
        (
            Message::PlainFrame {
                id: 0x101,
                len: 2,
                data: 0xAA55,
            },
            vec![0x06, 0x01, 0x01, 2, 0x55, 0xAA, 0, 0, 0, 0, 0, 0],
        ),
        (Message::ForeignFrame { id: 0x7FF }, vec![0x07, 0xFF, 0x07]),
        (
            Message::Probe { stamp: 0x0403_0201 },
            vec![0x0B, 1, 2, 3, 4],
        ),
        (
            Message::Echo { stamp: 0xFFFF_FFFE },
            vec![0x0C, 0xFE, 0xFF, 0xFF, 0xFF],
        ),
        (
            Message::LssAnswer {
                data: [0x4F, 1, 2, 3, 4, 5, 6, 7],
            },
            vec![0x0D, 0x4F, 1, 2, 3, 4, 5, 6, 7],
        ),
        #[cfg(feature = "simplecan")]
        (
            Message::SimpleCanPacket {
                id: 0x30,
                len: 8,
                data: [1, 2, 3, 4, 5, 6, 7, 8],
            },
            vec![0x08, 0x30, 0, 8, 1, 2, 3, 4, 5, 6, 7, 8],
        ),
        #[cfg(feature = "simplecan")]
        (
            Message::SimpleCanVerdict {
                entry: 2,
                sc_id: 0x31,
                cycle_stamp: 7,
                value: 0x0403_0201,
                valid: true,
            },
            vec![0x09, 2, 0x31, 7, 1, 2, 3, 4, 1],
        ),
        #[cfg(feature = "simplecan")]
        (
            Message::SimpleCanFault {
                cause: 0x71,
                id: 0x0102,
                other: 0x0304,
            },
            vec![0x0A, 0x71, 0x02, 0x01, 0x04, 0x03],
        ),
    ];
    for (message, body) in cases {
        let mut out = [0u8; layout::MAX_BODY];
        let len = message.write(&mut out).unwrap();
        assert_eq!(out[..len], body[..], "{message:?}");
        assert_eq!(Message::read(&body), Some(message));
    }
}

#[cfg(feature = "simplecan")]
#[test]
fn sc_req_24_a_forwarded_simplecan_packet_arrives_byte_exact_and_fits_the_bound() {
    let mut sender = Sender::new();
    let mut receiver = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
    // Worked vector 2 of docs/simplecan.md section 9, and the largest encoding there is.
    for message in [
        Message::SimpleCanPacket {
            id: 0x07F,
            len: 8,
            data: [0xEF, 0xBE, 0xAD, 0xDE, 0xFF, 0x8B, 0x1C, 0x68],
        },
        Message::SimpleCanPacket {
            id: u16::MAX,
            len: u8::MAX,
            data: [0xFF; 8],
        },
    ] {
        let wire = sender.encode(&message).unwrap();
        assert!(wire.len() <= MAX_WIRE);
        assert_eq!(feed(&mut receiver, Instant::ZERO, &wire), [Ok(message)]);
    }
}

/// A tag the receiver was built without (the SimpleCAN variants without the feature) is a
/// malformed message, as any unknown tag; with it, the other variants' encodings are the ones
/// the table gives either way (their vectors above are checked with and without it).
#[test]
fn sc_req_24_a_variant_behind_the_feature_changes_no_other_encoding() {
    let packet = [0x08, 0x30, 0, 8, 1, 2, 3, 4, 5, 6, 7, 8];
    assert_eq!(
        Message::read(&packet).is_some(),
        cfg!(feature = "simplecan")
    );
    assert_eq!(
        Message::read(&[0x07, 0x7F, 0]),
        Some(Message::ForeignFrame { id: 0x7F })
    );
}

#[cfg(feature = "simplecan")]
#[test]
fn sc_req_10_a_simplecan_verdict_crosses_the_link_and_fits_the_bound() {
    let mut sender = Sender::new();
    let mut receiver = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
    let largest = Message::SimpleCanVerdict {
        entry: u8::MAX,
        sc_id: u8::MAX,
        cycle_stamp: u8::MAX,
        value: u32::MAX,
        valid: true,
    };
    let mut body = [0u8; layout::MAX_BODY];
    assert_eq!(largest.write(&mut body), Some(9));
    let wire = sender.encode(&largest).unwrap();
    assert!(wire.len() <= MAX_WIRE);
    assert_eq!(feed(&mut receiver, Instant::ZERO, &wire), [Ok(largest)]);
}

#[cfg(feature = "simplecan")]
#[test]
fn sc_req_14_a_simplecan_fault_crosses_the_link_and_fits_the_bound() {
    let mut sender = Sender::new();
    let mut receiver = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
    let largest = Message::SimpleCanFault {
        cause: u8::MAX,
        id: u16::MAX,
        other: u16::MAX,
    };
    let mut body = [0u8; layout::MAX_BODY];
    assert_eq!(largest.write(&mut body), Some(6));
    let wire = sender.encode(&largest).unwrap();
    assert!(wire.len() <= MAX_WIRE);
    assert_eq!(feed(&mut receiver, Instant::ZERO, &wire), [Ok(largest)]);
}

/// The round trip's bound in these tests (a window of 5 ms less the queue time).
fn bound() -> Duration {
    round_trip_bound(Duration::from_millis(5))
}

fn armed() -> RoundTrip {
    let mut round_trip = RoundTrip::new();
    round_trip.set_bound(Some(bound()));
    round_trip
}

fn stamp_of(message: Option<Message>) -> u32 {
    match message {
        Some(Message::Probe { stamp }) => stamp,
        other => panic!("a probe, not {other:?}"),
    }
}

/// CiA 304 9.5: the bound is the co-signing window less the longest an announcement takes
/// through channel A's link queue, so that a round trip under it puts the announcement at
/// channel B within the window (the `round_trip` module documentation); a window no
/// longer than the queue time gives a bound of zero, which every round trip reaches.
#[test]
fn cia304_9_5_the_round_trip_bound_is_the_window_less_the_queue_time() {
    let window = Duration::from_millis(5);
    assert_eq!(
        round_trip_bound(window).as_micros() + QUEUE_TIME.as_micros(),
        window.as_micros()
    );
    assert_eq!(
        QUEUE_TIME.as_micros(),
        MESSAGES_AHEAD * MAX_WIRE as u64 * BYTE_TIME.as_micros()
    );
    assert_eq!(round_trip_bound(QUEUE_TIME), Duration::ZERO);
    assert_eq!(round_trip_bound(Duration::ZERO), Duration::ZERO);
}

/// CiA 304 9.5, EN 50325-5 Annex A.4: an echo under the bound is accepted, one at the bound
/// or over it is a latency fault, the deadline is the oldest probe's send time plus the bound.
#[test]
fn cia304_9_5_an_echo_at_or_over_the_bound_is_a_latency_fault() {
    let sent = Instant::from_millis(100);
    let mut round_trip = armed();
    assert_eq!(round_trip.deadline(), Instant::NEVER, "nothing outstanding");
    let stamp = stamp_of(round_trip.probe(sent));
    assert_eq!(round_trip.deadline(), sent + bound());
    let just_in_time = Instant::from_micros(sent.as_micros() + bound().as_micros() - 1);
    assert_eq!(round_trip.echo(just_in_time, stamp), Ok(()));
    assert_eq!(round_trip.deadline(), Instant::NEVER, "answered");

    let stamp = stamp_of(round_trip.probe(sent));
    assert_eq!(
        round_trip.echo(sent + bound(), stamp),
        Err(LinkFault::Latency),
        "at the bound"
    );
    let stamp = stamp_of(round_trip.probe(sent));
    assert_eq!(
        round_trip.echo(sent + bound() + Duration::from_millis(3), stamp),
        Err(LinkFault::Latency),
        "over it"
    );
}

/// CiA 304 9.5: a probe whose echo is lost (or still on a slow link) is a latency fault at its
/// deadline itself, not a moment before; a later probe does not move the deadline of an
/// earlier one.
#[test]
fn cia304_9_5_a_lost_echo_is_a_latency_fault_at_the_deadline() {
    let mut round_trip = armed();
    let sent = Instant::from_millis(7);
    let _lost = stamp_of(round_trip.probe(sent));
    let _later = stamp_of(round_trip.probe(sent + Duration::from_millis(1)));
    let deadline = sent + bound();
    assert_eq!(round_trip.deadline(), deadline);
    let before = Instant::from_micros(deadline.as_micros() - 1);
    assert_eq!(round_trip.poll(before), Ok(()));
    assert_eq!(round_trip.poll(deadline), Err(LinkFault::Latency));
}

/// CiA 304 9.5: echoes answer probes in their order; an echo of a probe other than the
/// oldest outstanding one, or of none at all, answers nothing this channel asked and is a
/// latency fault, as is one that comes after a probe fell due.
#[test]
fn cia304_9_5_an_echo_that_answers_no_outstanding_probe_is_a_fault() {
    let mut round_trip = armed();
    let at = Instant::from_millis(1);
    assert_eq!(round_trip.echo(at, 0), Err(LinkFault::Latency), "none sent");
    let first = stamp_of(round_trip.probe(at));
    let second = stamp_of(round_trip.probe(at + Duration::from_micros(10)));
    assert_ne!(first, second);
    assert_eq!(
        round_trip.echo(at + Duration::from_micros(500), second),
        Err(LinkFault::Latency),
        "the second answered before the first"
    );
}

/// CiA 304 9.5: four probes at most are outstanding; the oldest falls due first, so the
/// supervision loses nothing by sending no more. After echoes it probes again.
#[test]
fn cia304_9_5_probes_outstanding_are_bounded_and_answered_in_order() {
    let mut round_trip = armed();
    let start = Instant::from_millis(50);
    let stamps: Vec<u32> = (0..4)
        .map(|i| stamp_of(round_trip.probe(start + Duration::from_micros(100 * i))))
        .collect();
    assert_eq!(round_trip.probe(start + Duration::from_millis(1)), None);
    for (i, stamp) in stamps.into_iter().enumerate() {
        let at = start + Duration::from_micros(1_000 + 100 * i as u64);
        assert_eq!(round_trip.echo(at, stamp), Ok(()), "echo {i}");
    }
    assert!(round_trip.probe(start + Duration::from_millis(2)).is_some());
}

/// CiA 304 9.5: the stamp is the low 32 bits of the prober's microseconds: it wraps about
/// every 71 minutes, and a probe sent just before the wrap and answered just after is matched
/// and measured as any other (the round trip is taken on the full instant).
#[test]
fn cia304_9_5_a_stamp_that_wraps_between_probe_and_echo_is_measured_right() {
    let wrap = 1u64 << 32;
    let sent = Instant::from_micros(3 * wrap - 300);
    let mut round_trip = armed();
    let stamp = stamp_of(round_trip.probe(sent));
    assert_eq!(stamp, u32::MAX - 299);
    assert_eq!(stamp, super::stamp(sent));
    let back = Instant::from_micros(3 * wrap + 700);
    assert_eq!(super::stamp(back), 700, "wrapped");
    assert_eq!(round_trip.deadline(), sent + bound());
    assert_eq!(round_trip.echo(back, stamp), Ok(()), "a round trip of 1 ms");
    // The same across the wrap, but late.
    let stamp = stamp_of(round_trip.probe(sent));
    assert_eq!(
        round_trip.echo(sent + bound(), stamp),
        Err(LinkFault::Latency)
    );
}

/// A disarmed supervision (a node that produces no SRDO) sends no probe and judges no echo,
/// but still takes the echoes of probes sent while it was armed off its list.
#[test]
fn a_disarmed_round_trip_sends_no_probe_and_judges_no_echo() {
    let mut round_trip = RoundTrip::new();
    assert_eq!(round_trip.bound(), None);
    assert_eq!(round_trip.probe(Instant::ZERO), None);
    round_trip.set_bound(Some(bound()));
    let stamp = stamp_of(round_trip.probe(Instant::ZERO));
    round_trip.set_bound(None);
    assert_eq!(round_trip.deadline(), Instant::NEVER);
    assert_eq!(round_trip.poll(Instant::from_millis(100)), Ok(()));
    assert_eq!(round_trip.echo(Instant::from_millis(100), stamp), Ok(()));
    round_trip.set_bound(Some(bound()));
    assert_eq!(
        round_trip.deadline(),
        Instant::NEVER,
        "nothing left outstanding"
    );
}

/// EN 50325-5 Annex A.4: a probe and its echo cross the link framed as every message, and an
/// echo sent back for a probe received is measured by the prober.
#[test]
fn cia304_9_5_a_probe_crosses_the_link_and_its_echo_comes_back() {
    let (mut a_out, mut b_out) = (Sender::new(), Sender::new());
    let mut a_in = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
    let mut b_in = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
    let mut round_trip = armed();
    let sent = Instant::from_millis(2);
    let probe = round_trip.probe(sent).unwrap();
    let at_b = sent + Duration::from_micros(400);
    let received = feed(&mut b_in, at_b, &a_out.encode(&probe).unwrap());
    let [Ok(Message::Probe { stamp })] = received[..] else {
        panic!("{received:?}")
    };
    let echo = Message::Echo { stamp };
    let back = at_b + Duration::from_micros(400);
    let received = feed(&mut a_in, back, &b_out.encode(&echo).unwrap());
    let [Ok(Message::Echo { stamp })] = received[..] else {
        panic!("{received:?}")
    };
    assert_eq!(round_trip.echo(back, stamp), Ok(()));
}

/// EN 50325-5 Annex A.4: a channel that could not receive for a while (a flash program held
/// its processor) restarts its receiver as at start-up: the remnant of a frame it lost a
/// byte of is no fault, the next valid message starts the count whatever its sequence
/// number, and then a gap is a fault again. A restart never shortens a start-up wait.
#[test]
fn cia304_9_5_a_restarted_receiver_ignores_what_it_lost_then_counts_again() {
    let mut sender = Sender::new();
    let mut receiver = Receiver::new(Instant::ZERO, TIMEOUT, TIMEOUT);
    let first = Message::Inputs { sample: 1 };
    assert_eq!(
        feed(
            &mut receiver,
            Instant::ZERO,
            &sender.encode(&first).unwrap()
        ),
        [Ok(first)]
    );
    let mut damaged = sender.encode(&Message::Inputs { sample: 2 }).unwrap();
    damaged.remove(3);
    // Without the restart, the remnant is a fault.
    let mut strict = receiver.clone();
    assert!(matches!(
        feed(&mut strict, Instant::ZERO, &damaged)[..],
        [Err(_)]
    ));
    let _never_seen = sender.encode(&Message::Inputs { sample: 3 }).unwrap();
    let at = Instant::from_millis(5);
    receiver.restart(at);
    assert_eq!(receiver.deadline(), at + TIMEOUT);
    assert_eq!(feed(&mut receiver, at, &damaged), []);
    let fourth = Message::Inputs { sample: 4 };
    assert_eq!(
        feed(&mut receiver, at, &sender.encode(&fourth).unwrap()),
        [Ok(fourth)]
    );
    let _lost = sender.encode(&Message::Inputs { sample: 5 }).unwrap();
    let sixth = sender.encode(&Message::Inputs { sample: 6 }).unwrap();
    assert!(matches!(
        feed(&mut receiver, at, &sixth)[..],
        [Err(LinkFault::Missing { .. })]
    ));

    let startup = Duration::from_millis(500);
    let mut waiting = Receiver::new(Instant::ZERO, TIMEOUT, startup);
    waiting.restart(Instant::from_millis(1));
    assert_eq!(waiting.deadline(), Instant::ZERO + startup);
}

/// CiA 304 9.5: a channel that could not receive for a while forgets its probes
/// outstanding: nothing falls due for them, and their echoes, late or not, are taken off
/// without a verdict and answer no newer probe. Once a newer probe is answered, the link's
/// order says no forgotten echo is still to come: an echo of one is a fault again.
#[test]
fn cia304_9_5_forgotten_probes_neither_fall_due_nor_answer_a_newer_probe() {
    let mut round_trip = armed();
    let old = stamp_of(round_trip.probe(Instant::from_millis(100)));
    round_trip.forget();
    assert_eq!(round_trip.deadline(), Instant::NEVER);
    assert_eq!(round_trip.poll(Instant::from_millis(200)), Ok(()));
    let sent = Instant::from_millis(201);
    let new = stamp_of(round_trip.probe(sent));
    assert_eq!(round_trip.echo(Instant::from_millis(202), old), Ok(()));
    assert_eq!(round_trip.deadline(), sent + bound(), "still outstanding");
    assert_eq!(round_trip.echo(Instant::from_millis(202), new), Ok(()));
    let _newest = round_trip.probe(Instant::from_millis(210));
    assert_eq!(
        round_trip.echo(Instant::from_millis(211), old),
        Err(LinkFault::Latency)
    );
}

/// CiA 304 9.5: at an NMT reset, a link that had timed out starts over (a whole timeout from
/// the reset, the count restarted), and one that had not is left as it was.
#[test]
fn cia304_9_5_an_nmt_reset_starts_over_only_a_link_that_had_timed_out() {
    let startup = Duration::from_millis(500);
    let mut sender = Sender::new();
    let mut dead = Receiver::new(Instant::ZERO, TIMEOUT, startup);
    let first = Message::Inputs { sample: 1 };
    let at = Instant::from_millis(100);
    assert_eq!(
        feed(&mut dead, at, &sender.encode(&first).unwrap()),
        [Ok(first)]
    );
    let reset = at + TIMEOUT + TIMEOUT;
    assert!(dead.reset_if_timed_out(reset));
    assert_eq!(dead.deadline(), reset + TIMEOUT);
    assert_eq!(dead.poll(reset + TIMEOUT), Err(LinkFault::Timeout));
    // The count starts with the next message, whatever its sequence number.
    for _ in 0..5 {
        let _ = sender.encode(&Message::Inputs { sample: 0 }).unwrap();
    }
    let message = Message::Inputs { sample: 7 };
    assert_eq!(
        feed(&mut dead, reset, &sender.encode(&message).unwrap()),
        [Ok(message)]
    );

    let mut alive = Receiver::new(Instant::ZERO, TIMEOUT, startup);
    let before = alive.deadline();
    assert!(!alive.reset_if_timed_out(Instant::from_millis(100)));
    assert_eq!(alive.deadline(), before);
}
