//! Model-based property test of the SRDO consumer (EN 50325-5 7.1.2, 7.1.3; CiA 304 9.5).
//!
//! Random frames, time steps and faults go into a real node (node-ID 33, receive SRDO 1 on
//! 0x141/0x142, SCT 50 ms, SRVT 20 ms, one mapped byte and its inverted copy) and into a small
//! reference model written here from the standard's rules, independent of the crate's code.
//! After every step the two must agree on whether the node is still working and on how many
//! frames were discarded as CAN double receptions (ISO 11898-1), and the node must never
//! deliver data the model did not see arrive as a valid pair within SCT and SRVT.

use proptest::prelude::*;
use shared::canopen::NodeId;
use shared::canopen::nmt::{self, NmtCommand};
use shared::canopen::od::Address;
use shared::canopen::sdo_client;
use shared::canopen::storage::RamFlash;
use shared::node::{Event, Node, NodeConfig, Sink};
use shared::process_image::{Access, AppObject, Mappable};
use shared::{CanFrame, CanId, Duration, Instant};

const SCT: u64 = 50_000;
const SRVT: u64 = 20_000;

const fn object(index: u16, mappable: Mappable) -> AppObject {
    AppObject {
        address: Address::new(index, 1),
        len: 1,
        access: Access::ReadOnly,
        mappable,
    }
}

static OBJECTS: [AppObject; 2] = [
    object(0x6200, Mappable::Receive),
    object(0x6201, Mappable::Receive),
];

#[derive(Default)]
struct Recorder {
    delivered: u32,
    frames: Vec<CanFrame>,
}

impl Sink for Recorder {
    fn transmit(&mut self, frame: CanFrame) {
        self.frames.push(frame);
    }
    fn event(&mut self, event: Event) {
        if matches!(event, Event::SrdoReceived { .. }) {
            self.delivered += 1;
        }
    }
}

type ModelNode = Node<RamFlash<4096>, 1>;

/// Node 33 with its pre-defined receive SRDO, validated over SDO and started at t = 0.
fn started() -> ModelNode {
    let config = NodeConfig {
        node_id: NodeId::new(33).unwrap(),
        device_type: 0,
        device_name: "model",
        identity: [0; 4],
        app_objects: &OBJECTS,
        default_transmit_mapping: &[],
        default_receive_mapping: &[0x6200_0108, 0x6201_0108],
        heartbeat_ms: 0,
        sdo_timeout: Duration::from_millis(100),
        event_driven: false,
        gfc_on_fault: false,
    };
    let mut node = ModelNode::new(config, RamFlash::new()).unwrap();
    let mut sink = Recorder::default();
    node.poll(Instant::ZERO, &mut sink);
    let signature = shared::safety::signature::compute(&node.safety_config().srdos[0]);
    let sdo = CanId::new(0x621).unwrap();
    let mut exchange = |request: [u8; 8]| {
        let mut sink = Recorder::default();
        node.handle_frame(
            Instant::ZERO,
            &CanFrame::new(sdo, &request).unwrap(),
            &mut sink,
        );
        sink.frames.last().map(|f| f.data().try_into().unwrap())
    };
    sdo_client::download(
        &mut exchange,
        Address::new(0x13FF, 1),
        &signature.to_le_bytes(),
    )
    .unwrap();
    sdo_client::download(&mut exchange, Address::new(0x13FE, 0), &[0xA5]).unwrap();
    node.handle_frame(
        Instant::ZERO,
        &nmt::command_frame(NmtCommand::Start, 0),
        &mut sink,
    );
    assert!(node.is_working());
    node
}

/// A frame's data field as it is on the bus: `dlc` bytes, the rest of the buffer 0.
fn on_the_bus(dlc: u8, data: [u8; 8]) -> (u8, [u8; 8]) {
    let mut field = data;
    for (position, byte) in field.iter_mut().enumerate() {
        if position >= usize::from(dlc) {
            *byte = 0;
        }
    }
    (dlc, field)
}

/// The reference model: the consumer rules, straight from the standard.
#[derive(Debug, Default)]
struct Model {
    failed: bool,
    /// The plain frame waiting for its inverted frame (length and data field as on the bus),
    /// and when it arrived.
    pending: Option<((u8, [u8; 8]), u64)>,
    /// When the last valid pair completed (entering Operational counts, at t = 0).
    last_pair: u64,
    /// Data of the last valid pair (0 before any: the safe state).
    output: u8,
    pairs: u32,
    /// Exact repeats of the pending plain frame, discarded (ISO 11898-1 double reception).
    plain_repeated: u32,
    /// Inverted frames with no plain frame pending, discarded.
    inverted_without_plain: u32,
    /// A valid pair completed since the entry into Operational: before it, a half that does
    /// not pair (of a pair the producer's NMT reset cut) is discarded, and SRVT and SCT
    /// decide (EN 50325-5 7.1.2, 8.2.2; CiA 304 9.5 marks the old frame invalid).
    paired: bool,
}

impl Model {
    /// Timers first: a deadline reached at `now` is expired (EN 50325-5 7.1.2).
    fn timers(&mut self, now: u64) {
        if self.failed {
            return;
        }
        let srvt = self.pending.is_some_and(|(_, at)| now >= at + SRVT);
        let sct = now >= self.last_pair + SCT;
        if srvt || sct {
            self.fail();
        }
    }

    /// The earliest instant a timer rule can fire, while not failed.
    fn next_deadline(&self) -> Option<u64> {
        if self.failed {
            return None;
        }
        let sct = self.last_pair + SCT;
        Some(self.pending.map_or(sct, |(_, at)| sct.min(at + SRVT)))
    }

    fn fail(&mut self) {
        self.failed = true;
        self.output = 0;
        self.pending = None;
    }

    fn plain(&mut self, now: u64, dlc: u8, data: [u8; 8]) {
        self.timers(now);
        if self.failed {
            return;
        }
        let frame = on_the_bus(dlc, data);
        match self.pending {
            // The same frame again before its inverted frame: a double reception, discarded;
            // SRVT keeps running from the first copy.
            Some((pending, _)) if pending == frame => self.plain_repeated += 1,
            // Before the first pair, another plain frame (not too short) replaces the pending
            // one; SRVT keeps running from the first.
            Some((_, at)) if !self.paired && dlc >= 1 => self.pending = Some((frame, at)),
            // Another plain frame before the inverted one (CiA 304 9.5).
            Some(_) => self.fail(),
            // Too short (7.1.3).
            None if dlc < 1 => self.fail(),
            None => self.pending = Some((frame, now)),
        }
    }

    fn inverted(&mut self, now: u64, dlc: u8, byte: u8) {
        self.timers(now);
        if self.failed {
            return;
        }
        match self.pending.take() {
            Some(((_, plain), _)) if dlc >= 1 && byte == !plain[0] => {
                self.output = plain[0];
                self.last_pair = now;
                self.pairs += 1;
                self.paired = true;
            }
            // Before the first pair, not the inverse (and not too short): not delivered, the
            // plain frame stays pending with its SRVT.
            Some(pending) if !self.paired && dlc >= 1 => self.pending = Some(pending),
            // No plain frame pending: a double reception of the last inverted frame, or
            // monitoring started after its plain frame; discarded, SCT keeps running.
            None => self.inverted_without_plain += 1,
            // Too short, or not inverted.
            Some(_) => self.fail(),
        }
    }
}

#[derive(Clone, Debug)]
enum Step {
    Plain {
        dlc: u8,
        data: [u8; 8],
    },
    /// The exact inverse of the pending plain byte when `correct`, else the byte as given.
    Inverted {
        dlc: u8,
        data: [u8; 8],
        correct: bool,
    },
    /// The last plain (or inverted) frame sent, once more: a CAN double reception.
    Repeat {
        inverted: bool,
    },
    /// The last plain frame's data, one byte longer (a 0 appended): no repeat.
    Longer,
    Remote {
        inverted: bool,
    },
    Unrelated,
    Poll,
}

fn step() -> impl Strategy<Value = (u64, Step)> {
    let advance = prop_oneof![
        0u64..2_000,
        0u64..60_000,
        Just(SRVT),
        Just(SCT),
        (SRVT - 2..=SRVT + 2),
        (SCT - 2..=SCT + 2),
        (24_000u64..26_000),
    ];
    let frame = prop_oneof![
        4 => (0u8..=8, any::<[u8; 8]>()).prop_map(|(dlc, data)| Step::Plain { dlc, data }),
        4 => (0u8..=8, any::<[u8; 8]>(), prop::bool::weighted(0.85))
            .prop_map(|(dlc, data, correct)| Step::Inverted { dlc, data, correct }),
        2 => any::<bool>().prop_map(|inverted| Step::Repeat { inverted }),
        1 => Just(Step::Longer),
        1 => any::<bool>().prop_map(|inverted| Step::Remote { inverted }),
        1 => Just(Step::Unrelated),
        2 => Just(Step::Poll),
    ];
    (advance, frame)
}

/// Mostly well-formed traffic: valid pairs every ~25 ms with small jitter, so runs get deep
/// into the Operational state before a fault.
fn mostly_valid() -> impl Strategy<Value = Vec<(u64, Step)>> {
    proptest::collection::vec(
        prop_oneof![
            6 => (20_000u64..30_000, any::<u8>()).prop_map(|(gap, byte)| {
                let mut data = [0u8; 8];
                data[0] = byte;
                vec![(gap, Step::Plain { dlc: 1, data }), (300, Step::Inverted { dlc: 1, data: [0; 8], correct: true })]
            }),
            // A valid pair with one of its frames received twice (ISO 11898-1), or with the
            // consumer having missed the plain frame.
            2 => (20_000u64..30_000, any::<u8>(), 0u8..3).prop_map(|(gap, byte, which)| {
                let mut data = [0u8; 8];
                data[0] = byte;
                let plain = (gap, Step::Plain { dlc: 1, data });
                let inverted = (150, Step::Inverted { dlc: 1, data: [0; 8], correct: true });
                match which {
                    0 => vec![plain, (130, Step::Repeat { inverted: false }), inverted],
                    1 if byte == 0 => vec![plain, (130, Step::Longer), inverted],
                    1 => vec![plain, inverted, (130, Step::Repeat { inverted: true })],
                    _ => vec![(gap, Step::Inverted { dlc: 1, data: [!byte; 8], correct: false })],
                }
            }),
            1 => step().prop_map(|s| vec![s]),
        ],
        1..40,
    )
    .prop_map(|chunks| chunks.into_iter().flatten().collect())
}

fn check(steps: Vec<(u64, Step)>) -> Result<(), TestCaseError> {
    let mut node = started();
    let mut model = Model::default();
    let mut sink = Recorder::default();
    let mut now = 0u64;
    let id = |raw| CanId::new(raw).unwrap();
    let mut last_plain = None;
    let mut last_inverted = None;
    for (advance, step) in steps {
        now += advance;
        let at = Instant::from_micros(now);
        let frame = match step {
            Step::Plain { dlc, data } => {
                model.plain(now, dlc, data);
                let frame = CanFrame::from_parts(id(0x141), dlc, data).unwrap();
                last_plain = Some(frame);
                Some(frame)
            }
            Step::Inverted {
                dlc,
                mut data,
                correct,
            } => {
                if let (true, Some(((_, plain), _))) = (correct, model.pending) {
                    data[0] = !plain[0];
                }
                model.inverted(now, dlc, data[0]);
                let frame = CanFrame::from_parts(id(0x142), dlc, data).unwrap();
                last_inverted = Some(frame);
                Some(frame)
            }
            Step::Repeat { inverted } => {
                let again = if inverted { last_inverted } else { last_plain };
                match again {
                    Some(frame) if inverted => {
                        model.inverted(now, frame.dlc(), frame.raw_data()[0]);
                    }
                    Some(frame) => model.plain(now, frame.dlc(), *frame.raw_data()),
                    None => model.timers(now),
                }
                again
            }
            Step::Longer => match last_plain {
                Some(frame) if frame.dlc() < 8 => {
                    let dlc = frame.dlc() + 1;
                    model.plain(now, dlc, *frame.raw_data());
                    let longer = CanFrame::from_parts(frame.id(), dlc, *frame.raw_data()).unwrap();
                    last_plain = Some(longer);
                    Some(longer)
                }
                _ => {
                    model.timers(now);
                    None
                }
            },
            Step::Remote { inverted } => {
                model.timers(now);
                Some(CanFrame::remote(id(if inverted { 0x142 } else { 0x141 }), 1).unwrap())
            }
            Step::Unrelated => {
                model.timers(now);
                Some(CanFrame::new(id(0x2A0), &[1, 2, 3]).unwrap())
            }
            Step::Poll => {
                model.timers(now);
                None
            }
        };
        if let Some(frame) = frame {
            node.handle_frame(at, &frame, &mut sink);
        }
        let deadline = node.poll(at, &mut sink);
        // Timers are never scheduled later than the rules require.
        if let Some(due) = model.next_deadline() {
            prop_assert!(
                deadline.as_micros() <= due,
                "poll at {} µs: next {:?}, model {}",
                now,
                deadline,
                due
            );
        }

        let mut output = [0u8; 1];
        node.read_object(Address::new(0x6200, 1), &mut output)
            .unwrap();
        prop_assert_eq!(
            node.is_working(),
            !model.failed,
            "at {} µs: {:?}",
            now,
            model
        );
        // Safety: nothing is delivered that the model did not see as a valid, timely pair,
        // and the delivered value is that pair's plain data; 0 in the safe state (SC_REQ_05).
        prop_assert_eq!(sink.delivered, model.pairs, "at {} µs", now);
        let discarded = node.double_reception();
        prop_assert_eq!(
            (discarded.plain_repeated, discarded.inverted_without_plain),
            (model.plain_repeated, model.inverted_without_plain),
            "at {} µs",
            now
        );
        prop_assert_eq!(output[0], model.output, "at {} µs", now);
        if model.failed {
            prop_assert_eq!(output[0], 0);
        }
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(600))]

    /// EN 50325-5 7.1.2, 7.1.3, CiA 304 9.5, ISO 11898-1 double reception: random traffic,
    /// timing and faults.
    #[test]
    fn en50325_5_7_1_2_consumer_matches_reference_model_on_random_traffic(
        steps in proptest::collection::vec(step(), 1..50)
    ) {
        check(steps)?;
    }

    /// The same, on traffic that is mostly valid pairs with faults sprinkled in.
    #[test]
    fn en50325_5_7_1_2_consumer_matches_reference_model_on_mostly_valid_traffic(
        steps in mostly_valid()
    ) {
        check(steps)?;
    }
}
