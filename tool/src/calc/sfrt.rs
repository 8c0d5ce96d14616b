//! The worst-case reaction time of each safety function of a planned network, from a
//! producer's input to a consumer's output, broken down (EN 50325-5 9.3.1; SC_REQ_45).
//!
//! A safety function here is one receive SRDO of a consumer and the transmit SRDO of the
//! node that produces it (the same COB-IDs). The calculation follows the path a change takes
//! through this device (`dual_channel::runtime`):
//!
//! 1. **Input sampling**: each channel samples its contact every [`DeviceTiming::input_sample_us`].
//! 2. **Sample window**: channel A holds a frame with changed data until channel B's input
//!    digest says B sampled the same (the symmetric sample window,
//!    [`SAMPLE_WINDOW`]): the skew between the two contacts, then B's
//!    digest over the link behind the link messages that may be ahead of it.
//! 3. **Producer**: this device sends a changed SRDO at once (event-driven); one step of
//!    processing.
//! 4. **Plain frame**: the longest wait for the bus (one frame of blocking, every
//!    higher-priority frame of the busy window, [`super::bus::queuing_delay`]) and its
//!    worst-case frame time with stuff bits.
//! 5. **Channel B co-signs**: B sends the inverted frame once it has both the plain frame from
//!    the bus and channel A's announcement of it from the link, then one step of processing.
//! 6. **Inverted frame**: its wait for the bus and its frame time.
//! 7. **Consumer validation**: the first of the consumer's channels that validates the pair
//!    drops its output: one step of processing.
//! 8. **Cross-check**: none towards the safe state; an output moves towards 0 at once, only
//!    raising it waits for the other channel's verdict.
//! 9. **Output**: the output stage after the channel wrote it ([`DeviceTiming::output_us`]).
//!
//! With one fault in the communication when the demand comes (the pair carrying the change is
//! lost or corrupted), the consumer drops its output when its SCT runs out after the last
//! valid pair, whose inverted frame may still have been on the bus at the demand: SCT, one
//! frame time, one step, the output. EN 50325-5 formula (3) adds the difference as the
//! "delta time of a subsystem that fails when the safety function trips"; the bound here is
//! the larger of the two paths. A GFC's path (one frame, priority 001h) is given beside them.
//!
//! Pure arithmetic on the network file and the stated timing: no bus, no clock.

use super::bus::{Stream, frame_micros, queuing_delay};
use crate::network_file::Network;
use safety_device::timing::{
    INPUT_SAMPLE_PERIOD, LINK_BYTE_TIME, LINK_LONGEST_FRAME, SAMPLE_WINDOW,
};
use shared::canopen::NodeId;
use shared::node::NodeConfig;
use shared::safety::gfc::GFC_ID;

/// The device description's timing does not depend on the node-ID; node 1's is read.
const DESCRIBED: NodeId = match NodeId::new(1) {
    Ok(id) => id,
    Err(_) => panic!("node-ID 1 is valid"),
};

/// The device description the firmware images are built from.
fn description() -> NodeConfig {
    safety_device::config(DESCRIBED, safety_device::CHANNEL_A_NAME)
}

/// Link messages that may be ahead of one message in a channel's link transmit queue, and
/// the message itself: a heartbeat (which carries the configuration and input digests) and
/// the probe of the link's round trip sent with it, the echo of the other channel's probe, an
/// input digest sent at an input change, a verdict on a received pair
/// ([`safety_device::timing::LINK_MESSAGES_AHEAD`]). The latency supervision's probe and
/// echo made it two more than before (2026-12-07); the same count bounds the round trip
/// (`dual_channel::link::round_trip_bound`).
pub const LINK_MESSAGES_AHEAD: u64 = safety_device::timing::LINK_MESSAGES_AHEAD;

/// The device's own timing, which the network file does not give.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct DeviceTiming {
    /// The period at which each channel samples its input (µs).
    pub input_sample_us: u64,
    /// The largest skew between the two contacts of one input that the function must
    /// tolerate (µs), at most [`SAMPLE_WINDOW`]: a longer one is a transmit mismatch (the
    /// producer's safe state), not a reaction.
    pub contact_skew_us: u64,
    /// One byte on the link between the channels (µs).
    pub link_byte_us: u64,
    /// One step of a channel: from a frame or a sample to its answer (µs).
    pub processing_us: u64,
    /// The output stage, after the channel wrote the output (µs).
    pub output_us: u64,
}

impl DeviceTiming {
    /// The hardware: the device description's input sample period and link byte time
    /// ([`INPUT_SAMPLE_PERIOD`], [`LINK_BYTE_TIME`], which the channel loop and `board::hw`
    /// run with); the contacts' skew up to the whole sample window. Processing: the step measured on the target ([`super::target::MEASURED`],
    /// instructions counted by `cargo xtask bench --target-cost` in the shipped images on the
    /// emulated STM32F405, at the bounded cycles per instruction of
    /// [`super::target::CPI_BOUND`] on 168 MHz, doubled for interrupts). The output pin is written in the channel's step; the
    /// output stage beyond the pin (relay, contactor) is the machine builder's and not
    /// included.
    pub const HARDWARE: DeviceTiming = DeviceTiming {
        input_sample_us: INPUT_SAMPLE_PERIOD.as_micros(),
        contact_skew_us: SAMPLE_WINDOW.as_micros(),
        link_byte_us: LINK_BYTE_TIME.as_micros(),
        processing_us: super::target::MEASURED.processing_us(),
        output_us: 0,
    };

    /// The hardware with SimpleCAN: [`DeviceTiming::HARDWARE`] but for the processing step,
    /// counted in the shipped SimpleCAN images on the emulated STM32F405
    /// ([`super::target::MEASURED_SIMPLECAN`], `cargo xtask bench --target-cost --protocol
    /// simplecan`), whose activations carry SimpleCAN's work beside the SRDO table's.
    pub const HARDWARE_SIMPLECAN: DeviceTiming = DeviceTiming {
        processing_us: super::target::MEASURED_SIMPLECAN.processing_us(),
        ..DeviceTiming::HARDWARE
    };
}

/// One part of a reaction time.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Part {
    /// What it is.
    pub what: &'static str,
    /// Its worst case (µs).
    pub micros: u64,
}

/// The worst-case reaction of one safety function.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Reaction {
    /// The producer's node-ID and its transmit SRDO number.
    pub producer: (u8, u8),
    /// The consumer's node-ID and its receive SRDO number.
    pub consumer: (u8, u8),
    /// The fault-free path, part by part.
    pub parts: Vec<Part>,
    /// Their sum (µs).
    pub fault_free_us: u64,
    /// With one communication fault at the demand: the consumer's SCT watchdog (µs).
    pub one_fault_us: u64,
    /// The larger of the two: the network's part of the safety function response time (µs).
    pub worst_us: u64,
    /// The GFC's path to this consumer (µs): queuing behind NMT only, one empty frame, one step.
    pub gfc_us: u64,
}

/// Why a safety function has no bound.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error, serde::Serialize)]
pub enum SfrtError {
    /// A consumer's receive SRDO whose COB-IDs no transmit SRDO in the file uses.
    #[error(
        "node {node} SRDO {srdo} receives COB-IDs {plain:03X}h/{inverted:03X}h, but no node in the file transmits them"
    )]
    NoProducer {
        /// Consumer node-ID.
        node: u8,
        /// Its SRDO number.
        srdo: u8,
        /// COB-ID of the plain frame.
        plain: u32,
        /// COB-ID of the inverted frame.
        inverted: u32,
    },
    /// A frame of a safety function may wait for the bus as long as the consumer's SCT, or
    /// without bound.
    #[error(
        "the frame on {id:03X}h (node {node} SRDO {srdo}) may wait for the bus longer than the consumer's SCT of {sct_ms} ms at {bit_rate} bit/s: the higher-priority traffic takes too much of it (reduce the load or raise the bit rate)"
    )]
    Unbounded {
        /// The identifier.
        id: u16,
        /// The producer's node-ID.
        node: u8,
        /// Its SRDO number.
        srdo: u8,
        /// The bit rate.
        bit_rate: u32,
        /// The consumer's SCT (ms), the longest wait that still has a meaning.
        sct_ms: u16,
    },
    /// A contact skew longer than the sample window is a fault, not a reaction.
    #[error(
        "a contact skew of {skew_us} µs is longer than the sample window of {window_us} µs: the producer would report a transmit mismatch"
    )]
    SkewBeyondWindow {
        /// The skew asked for.
        skew_us: u64,
        /// The window.
        window_us: u64,
    },
}

/// What the plan puts on the bus besides `extra`: both frames of every transmit SRDO, as a
/// cyclic stream at its refresh time and an event-driven one at `event_interval_us` (or the
/// refresh time), and every node's heartbeat (lowest priority: it only blocks).
#[must_use]
pub fn planned_streams(
    network: &Network,
    event_interval_us: Option<u64>,
    extra: &[Stream],
) -> Vec<Stream> {
    let mut streams = extra.to_vec();
    let heartbeat_us = u64::from(description().heartbeat_ms) * 1000;
    for node in &network.nodes {
        streams.push(Stream {
            id: 0x700 + u16::from(node.id),
            len: 1,
            period_us: heartbeat_us,
        });
        for srdo in node.srdos.iter().filter(|s| s.settings.direction == 1) {
            let len = frame_len(&srdo.settings.mapping);
            let refresh = u64::from(srdo.settings.cycle_time) * 1000;
            for id in [srdo.settings.cob_id_1, srdo.settings.cob_id_2] {
                let id = (id & 0x7FF) as u16;
                streams.push(Stream {
                    id,
                    len,
                    period_us: refresh,
                });
                streams.push(Stream {
                    id,
                    len,
                    period_us: event_interval_us.unwrap_or(refresh),
                });
            }
        }
    }
    streams
}

/// The data bytes of one frame of an SRDO with `mapping` (EN 50325-5 6.4.1.3): the plain
/// frame carries the odd entries, the inverted frame the even ones, of equal length; an
/// entry's low byte is its length in bits.
#[must_use]
pub fn frame_len(mapping: &[u32]) -> u8 {
    let bits: u32 = mapping.iter().step_by(2).map(|entry| entry & 0xFF).sum();
    bits.div_ceil(8).min(8) as u8
}

/// The worst-case reaction of every safety function in `network` at `bit_rate`, with
/// `streams` the whole traffic on the bus ([`planned_streams`]).
pub fn reactions(
    network: &Network,
    streams: &[Stream],
    bit_rate: u32,
    timing: &DeviceTiming,
) -> Result<Vec<Reaction>, SfrtError> {
    let window_us = SAMPLE_WINDOW.as_micros();
    if timing.contact_skew_us > window_us {
        return Err(SfrtError::SkewBeyondWindow {
            skew_us: timing.contact_skew_us,
            window_us,
        });
    }
    let link_latency = LINK_MESSAGES_AHEAD * LINK_LONGEST_FRAME as u64 * timing.link_byte_us;
    let mut out = Vec::new();
    for consumer in &network.nodes {
        for receive in consumer.srdos.iter().filter(|s| s.settings.direction == 2) {
            let (plain_id, inverted_id) = (receive.settings.cob_id_1, receive.settings.cob_id_2);
            let producer = network.nodes.iter().find_map(|node| {
                node.srdos
                    .iter()
                    .find(|s| {
                        s.settings.direction == 1
                            && s.settings.cob_id_1 == plain_id
                            && s.settings.cob_id_2 == inverted_id
                    })
                    .map(|s| (node.id, s))
            });
            let Some((producer_id, transmit)) = producer else {
                return Err(SfrtError::NoProducer {
                    node: consumer.id,
                    srdo: receive.number,
                    plain: plain_id,
                    inverted: inverted_id,
                });
            };
            let sct_us = u64::from(receive.settings.cycle_time) * 1000;
            let len = frame_len(&transmit.settings.mapping);
            let frame = frame_micros(len, bit_rate);
            let wait = |id: u32| {
                let id = (id & 0x7FF) as u16;
                queuing_delay(id, streams, 8, bit_rate, sct_us).ok_or(SfrtError::Unbounded {
                    id,
                    node: producer_id,
                    srdo: transmit.number,
                    bit_rate,
                    sct_ms: receive.settings.cycle_time,
                })
            };
            let plain_wait = wait(plain_id)?;
            let inverted_wait = wait(inverted_id)?;
            let plain_done = plain_wait + frame;
            // This device sends a changed SRDO at once; a device that did not would wait for
            // its next refresh.
            let producer_us = if description().event_driven {
                timing.processing_us
            } else {
                u64::from(transmit.settings.cycle_time) * 1000 + timing.processing_us
            };
            let co_sign = link_latency.saturating_sub(plain_done) + timing.processing_us;
            let parts = vec![
                Part {
                    what: "input sampling",
                    micros: timing.input_sample_us,
                },
                Part {
                    what: "sample window (contact skew, channel B's input digest over the link)",
                    // The frame goes when B's digest agrees, at the latest when the
                    // window ends.
                    micros: (timing.contact_skew_us + link_latency).min(window_us),
                },
                Part {
                    what: "producer (event-driven, one step)",
                    micros: producer_us,
                },
                Part {
                    what: "plain frame: wait for the bus",
                    micros: plain_wait,
                },
                Part {
                    what: "plain frame: frame time",
                    micros: frame,
                },
                Part {
                    what: "channel B co-signs (channel A's announcement over the link, one step)",
                    micros: co_sign,
                },
                Part {
                    what: "inverted frame: wait for the bus",
                    micros: inverted_wait,
                },
                Part {
                    what: "inverted frame: frame time",
                    micros: frame,
                },
                Part {
                    what: "consumer validation (one step)",
                    micros: timing.processing_us,
                },
                Part {
                    what: "cross-check (none towards the safe state)",
                    micros: 0,
                },
                Part {
                    what: "output",
                    micros: timing.output_us,
                },
            ];
            let fault_free_us = parts.iter().map(|p| p.micros).sum();
            let one_fault_us = sct_us + frame + timing.processing_us + timing.output_us;
            let gfc_wait = wait(u32::from(GFC_ID.raw()))?;
            let gfc_us =
                gfc_wait + frame_micros(0, bit_rate) + timing.processing_us + timing.output_us;
            out.push(Reaction {
                producer: (producer_id, transmit.number),
                consumer: (consumer.id, receive.number),
                parts,
                fault_free_us,
                one_fault_us,
                worst_us: fault_free_us.max(one_fault_us),
                gfc_us,
            });
        }
    }
    Ok(out)
}

/// A network file with one safety function: node 1's emergency stop (transmit SRDO 1, refresh
/// `refresh_ms`, COB-IDs 101h/102h) to node 33's output (receive SRDO 1, SCT `sct_ms`, SRVT
/// `srvt_ms`), as the demo and the reaction-time measurement have it. For tests and the
/// manual's example.
#[must_use]
pub fn example_network(refresh_ms: u16, sct_ms: u16, srvt_ms: u8) -> String {
    format!(
        r#"[[node]]
id = 1
name = "emergency stop"
identity = {{ vendor = 0xABC, product = 0x304, serial = 1 }}

[[node.srdo]]
number = 1
direction = "transmit"
refresh_time_ms = {refresh_ms}
srvt_ms = {srvt_ms}
cob_ids = [0x101, 0x102]
mapping = ["input", "input_inverted"]

[[node]]
id = 33
name = "safe output"
identity = {{ vendor = 0xABC, product = 0x304, serial = 33 }}

[[node.srdo]]
number = 1
direction = "receive"
sct_ms = {sct_ms}
srvt_ms = {srvt_ms}
cob_ids = [0x101, 0x102]
mapping = ["output", "output_inverted"]
"#
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::network_file::parse;

    /// The simulation's timing: instant sampling and processing, both contacts together.
    const SIMULATED: DeviceTiming = DeviceTiming {
        input_sample_us: 0,
        contact_skew_us: 0,
        link_byte_us: 10,
        processing_us: 0,
        output_us: 0,
    };

    fn network() -> Network {
        parse(&example_network(25, 50, 20), "example").unwrap()
    }

    /// The bound by hand at 1 Mbit/s on an otherwise empty bus: B's digest behind five link
    /// messages (6 × 23 bytes × 10 µs = 1380 µs), each frame blocked by one 8-byte frame
    /// (135 µs) and 65 µs long, channel B waiting for the announcement 1380 − 200 µs after
    /// the plain frame, the inverted frame also behind the plain frame's two streams (cyclic
    /// and event-driven, 2 × 65 µs: the analysis does not assume the producer waits for its
    /// own pair); with a fault SCT + one frame.
    #[test]
    fn en50325_5_9_3_1_the_breakdown_adds_up_to_the_bound_by_hand() {
        let network = network();
        let streams = planned_streams(&network, None, &[]);
        let reactions = reactions(&network, &streams, 1_000_000, &SIMULATED).unwrap();
        assert_eq!(reactions.len(), 1);
        let reaction = &reactions[0];
        assert_eq!((reaction.producer, reaction.consumer), ((1, 1), (33, 1)));
        let micros: Vec<u64> = reaction.parts.iter().map(|p| p.micros).collect();
        assert_eq!(micros, [0, 1380, 0, 135, 65, 1180, 265, 65, 0, 0, 0]);
        assert_eq!(reaction.fault_free_us, 3090);
        assert_eq!(reaction.one_fault_us, 50_065);
        assert_eq!(reaction.worst_us, 50_065);
        // GFC: blocked by one 8-byte frame, 55 bits of its own.
        assert_eq!(reaction.gfc_us, 135 + 55);
    }

    /// The hardware's assumptions add the input sample, the whole sample window (in place of
    /// B's digest over the link, which it bounds) and three steps of processing to the same
    /// path.
    #[test]
    fn en50325_5_9_3_1_hardware_timing_adds_sampling_window_and_processing() {
        let network = network();
        let streams = planned_streams(&network, None, &[]);
        let simulated = &reactions(&network, &streams, 1_000_000, &SIMULATED).unwrap()[0];
        let hardware =
            &reactions(&network, &streams, 1_000_000, &DeviceTiming::HARDWARE).unwrap()[0];
        let step = DeviceTiming::HARDWARE.processing_us;
        assert!(step > 0, "the processing step is measured, not left at 0");
        // The window replaces B's digest over the link (1380 µs): the frame waits 5 ms at most.
        assert_eq!(
            hardware.fault_free_us - simulated.fault_free_us,
            1000 + (SAMPLE_WINDOW.as_micros() - 1380) + 3 * step
        );
        assert_eq!(hardware.parts[1].micros, SAMPLE_WINDOW.as_micros());
        assert_eq!(hardware.one_fault_us - simulated.one_fault_us, step);
    }

    /// Higher-priority traffic lengthens both waits; a bus it fills gives no bound, and a
    /// skew longer than the window is refused, each with a sentence.
    #[test]
    fn en50325_5_9_3_1_higher_priority_traffic_and_its_limits() {
        let network = network();
        let half = Stream {
            id: 0x090,
            len: 8,
            period_us: 270,
        };
        let loaded = planned_streams(&network, None, &[half]);
        let reaction = &reactions(&network, &loaded, 1_000_000, &SIMULATED).unwrap()[0];
        // 135 blocking + two 135 µs frames of the 0x090 stream in the busy window; the
        // inverted frame also behind the plain frame's two streams.
        assert_eq!(reaction.parts[3].micros, 405);
        assert_eq!(reaction.parts[6].micros, 535);
        let full = planned_streams(
            &network,
            None,
            &[Stream {
                id: 0x090,
                len: 8,
                period_us: 135,
            }],
        );
        let error = reactions(&network, &full, 1_000_000, &SIMULATED).unwrap_err();
        assert!(matches!(
            error,
            SfrtError::Unbounded {
                id: 0x101,
                node: 1,
                srdo: 1,
                ..
            }
        ));
        assert!(
            error.to_string().contains("101h (node 1 SRDO 1)"),
            "{error}"
        );
        let skewed = DeviceTiming {
            contact_skew_us: SAMPLE_WINDOW.as_micros() + 1,
            ..SIMULATED
        };
        assert!(matches!(
            reactions(&network, &loaded, 1_000_000, &skewed),
            Err(SfrtError::SkewBeyondWindow { .. })
        ));
    }

    /// A consumer whose producer the file does not list has no reaction time.
    #[test]
    fn en50325_5_9_3_1_a_consumer_without_producer_is_named() {
        let text = example_network(25, 50, 20).replacen(
            "cob_ids = [0x101, 0x102]",
            "cob_ids = [0x103, 0x104]",
            1,
        );
        let network = parse(&text, "example").unwrap();
        let error = reactions(
            &network,
            &planned_streams(&network, None, &[]),
            500_000,
            &SIMULATED,
        )
        .unwrap_err();
        assert_eq!(
            error.to_string(),
            "node 33 SRDO 1 receives COB-IDs 101h/102h, but no node in the file transmits them"
        );
    }

    /// The plain frame carries the odd mapping entries: two 8-bit objects make 1-byte frames,
    /// four 16-bit ones 4-byte frames.
    #[test]
    fn frame_length_counts_the_plain_entries() {
        assert_eq!(frame_len(&[0x6000_0108, 0x6001_0108]), 1);
        assert_eq!(
            frame_len(&[0x6000_0110, 0x6001_0110, 0x6002_0110, 0x6003_0110]),
            4
        );
        assert_eq!(frame_len(&[]), 0);
    }
}
