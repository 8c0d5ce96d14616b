//! The calculators for a SimpleCAN network (the network file's `[simplecan]` section):
//! the worst-case reaction of each consumed SC-ID (input to output, part by part) and the
//! network's residual error rate against a SIL (`docs/simplecan.md` section 8, SC_REQ_04).
//! Kept beside, not inside, [`super::sfrt`] and [`super::budget`]: it reuses their device
//! timing ([`DeviceTiming`], [`Part`]), the link latency's terms and the frame times.

use super::bus::frame_micros;
use super::residual::Sil;
use super::sfrt::{DeviceTiming, LINK_MESSAGES_AHEAD, Part};
use crate::simplecan::SimpleCanNetwork;
use safety_device::timing::LINK_LONGEST_FRAME;
use shared::simplecan::SLOT;
use shared::simplecan::residual::rate_per_hour;

/// Every SimpleCAN packet is a data frame with 8 bytes (`docs/simplecan.md` section 1).
const PACKET_LEN: u8 = 8;

/// The worst-case reaction of one consumed SC-ID at one consumer.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct ScReaction {
    /// The SC-ID.
    pub sc_id: u8,
    /// Its producer's node-ID.
    pub producer: u8,
    /// The consumer's node-ID.
    pub consumer: u8,
    /// The fault-free path, part by part.
    pub parts: Vec<Part>,
    /// Their sum (µs).
    pub fault_free_us: u64,
    /// With the packet after the demand lost: the consumer's safety timeout, counted from
    /// the start of the last valid packet's slot (SC_REQ_20), after the input sample and the
    /// producer's step that built that packet, then the cross-check and the output (µs).
    pub one_fault_us: u64,
    /// The larger of the two (µs).
    pub worst_us: u64,
}

/// Why a SimpleCAN reaction has no bound.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error, serde::Serialize)]
pub enum ScCalcError {
    /// A consumed SC-ID that no node of the file produces.
    #[error("node {node} consumes SC-ID {sc_id:02X}h, but no node in the file produces it")]
    NoProducer {
        /// The consumer.
        node: u8,
        /// The SC-ID.
        sc_id: u8,
    },
    /// An 8-byte frame that does not fit in a 1 ms slot at this bit rate (SC_REQ_18).
    #[error(
        "an 8-byte SimpleCAN packet takes {frame_us} µs at {bit_rate} bit/s, longer than its 1 ms slot"
    )]
    FrameLongerThanSlot {
        /// The frame's worst-case time.
        frame_us: u64,
        /// The bit rate.
        bit_rate: u32,
    },
}

/// The worst-case reaction of every consumed SC-ID of `network` at `bit_rate`, with the
/// device's `timing`, in consumer then SC-ID order.
///
/// The fault-free path: the input sample; the producer's step that builds the packet at its
/// slot's start; the wait for that slot, up to one cycle (N ms) when the input changed just
/// after the last one; the packet on the bus, queued at its slot's start and over before the
/// slot ends (SC_REQ_18: the slot bounds arbitration and frame time together); the
/// receiver's buffering as stated (SC_REQ_33); the consumer's validation (one step); the
/// channels' cross-check (the other channel's digest over the link behind the link
/// messages ahead of it, one step); the output stage.
pub fn reactions(
    network: &SimpleCanNetwork,
    bit_rate: u32,
    timing: &DeviceTiming,
) -> Result<Vec<ScReaction>, ScCalcError> {
    let slot_us = SLOT.as_micros();
    let frame_us = frame_micros(PACKET_LEN, bit_rate);
    if frame_us > slot_us {
        return Err(ScCalcError::FrameLongerThanSlot { frame_us, bit_rate });
    }
    let cycle_us = u64::from(network.slots_per_cycle) * slot_us;
    let cross_check_us = LINK_MESSAGES_AHEAD * LINK_LONGEST_FRAME as u64 * timing.link_byte_us
        + timing.processing_us;
    let mut reactions = Vec::new();
    for (&consumer, node) in &network.nodes {
        for consumed in &node.consumed {
            let producer = network
                .nodes
                .iter()
                .find(|(_, other)| other.produced.iter().any(|p| p.sc_id == consumed.sc_id))
                .map(|(&id, _)| id)
                .ok_or(ScCalcError::NoProducer {
                    node: consumer,
                    sc_id: consumed.sc_id,
                })?;
            let parts = vec![
                Part {
                    what: "input sample",
                    micros: timing.input_sample_us,
                },
                Part {
                    what: "producer's step (builds the packet at its slot's start)",
                    micros: timing.processing_us,
                },
                Part {
                    what: "producer's slot wait (up to one cycle)",
                    micros: cycle_us,
                },
                Part {
                    what: "packet on the bus (arbitration and frame, within its 1 ms slot)",
                    micros: slot_us,
                },
                Part {
                    what: "receive buffering (stated, SC_REQ_33)",
                    micros: u64::from(network.buffering_us),
                },
                Part {
                    what: "consumer's validation (one step)",
                    micros: timing.processing_us,
                },
                Part {
                    what: "channels' cross-check (digest over the link, one step)",
                    micros: cross_check_us,
                },
                Part {
                    what: "output stage",
                    micros: timing.output_us,
                },
            ];
            let fault_free_us = parts.iter().map(|part| part.micros).sum();
            let one_fault_us = timing.input_sample_us
                + timing.processing_us
                + u64::from(consumed.timeout_ms) * 1000
                + timing.processing_us
                + cross_check_us
                + timing.output_us;
            reactions.push(ScReaction {
                sc_id: consumed.sc_id,
                producer,
                consumer,
                parts,
                fault_free_us,
                one_fault_us,
                worst_us: fault_free_us.max(one_fault_us),
            });
        }
    }
    Ok(reactions)
}

/// The residual error rate of a SimpleCAN network (`docs/simplecan.md` section 8).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct ScResidual {
    /// SimpleCAN packets per second: one per producer slot per cycle, and the syncs.
    pub packets_per_second: f64,
    /// Λ_SL (/h), `shared::simplecan::residual::rate_per_hour`.
    pub rate_per_hour: f64,
    /// SimpleCAN's share of the SIL's limit: 1 % of it (SC_REQ_04; SIL 3: 10⁻⁹ /h).
    pub limit_per_hour: f64,
}

impl ScResidual {
    /// Whether the rate is within the limit.
    pub fn within(&self) -> bool {
        self.rate_per_hour <= self.limit_per_hour
    }
}

/// SimpleCAN's share of a SIL's residual error rate limit (SC_REQ_04: 1 %).
pub const SHARE_OF_SIL_LIMIT: f64 = 0.01;

/// The residual error rate of `network` against `sil`: ν = 1000 × (producer slots) / N +
/// 1000 / (k × N) packets per second (section 8 step 5), Λ_SL = 3600 × R_SL × ν.
pub fn residual(network: &SimpleCanNetwork, sil: Sil) -> ScResidual {
    let producers = network
        .nodes
        .values()
        .map(|node| node.produced.len())
        .sum::<usize>() as f64;
    let n = f64::from(network.slots_per_cycle);
    let k = f64::from(network.cycles_between_syncs);
    let packets_per_second = 1000.0 * producers / n + 1000.0 / (k * n);
    ScResidual {
        packets_per_second,
        rate_per_hour: rate_per_hour(packets_per_second),
        limit_per_hour: sil.limit_per_hour() * SHARE_OF_SIL_LIMIT,
    }
}
