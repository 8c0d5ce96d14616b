//! The full network's plan: which node produces and consumes which SRDO, the background
//! traffic, and the timing derived from worst-case frame times (ISO 11898-1 stuff bits).
//!
//! **Node-IDs and SRDOs.** CiA 304 gives 64 SRDO identifier pairs, 0xFF + 2n / 0x100 + 2n
//! for n = 1..64 (0x101..0x180), the pre-defined connection set of node-IDs 1..64. So there
//! are at most 64 SRDOs, one per producer, and a consumer takes one producer's SRDO. Node-IDs
//! go to 127, one short of 128 single-role nodes, so one node has two roles:
//!
//! - node n (1..=64) produces SRDO n on its own pair (its SRDO 1, transmit);
//! - node 64 + n (65..=127) consumes producer n's pair, n = 1..=63 (its SRDO 1, receive);
//! - node 1 also consumes producer 64's pair (its SRDO 2, receive): the 64th consumer.
//!
//! 127 dual-channel nodes, 254 channel runtimes, 64 producers, 64 consumers. Two node types,
//! each one configuration reused (the COB-IDs follow the producer), plus node 1 with both.
//!
//! **Timing.** A frame's worst-case length is its unstuffed bits plus one stuff bit per four
//! stuffable bits after the first ([`worst_case_bits`]; the bus model counts the real stuff
//! bits of every frame, never more). The refresh time is the shortest whole millisecond for
//! which the worst-case utilisation of every periodic stream, SRDO pairs, heartbeats,
//! PDO-like load and the event-driven pairs of input changes, stays at or below
//! [`UTILISATION_LIMIT`] ([`Timing::derive`]).

use shared::Duration;

/// Worst-case utilisation the periodic traffic may reach: the whole bus. Fixed-priority
/// non-preemptive CAN serves every periodic stream with a bounded response time as long as
/// the worst-case utilisation does not exceed 1; the SRDOs, above every background
/// identifier, see the background only as one frame of blocking.
pub const UTILISATION_LIMIT: f64 = 1.0;

/// The heartbeat period of every node (`safety_device::config`).
pub const HEARTBEAT: Duration = Duration::from_millis(100);

/// The PDO-like background load: this many streams of 8-byte frames, each every
/// [`PDO_PERIOD`], on identifiers 0x1C1.. (the TPDO1 identifiers of nodes 65..; the safety
/// nodes send no PDOs, so other participants stand in for them).
pub const PDO_STREAMS: u16 = 16;
/// The period of each PDO-like stream.
pub const PDO_PERIOD: Duration = Duration::from_millis(10);
/// The first PDO-like identifier.
pub const PDO_FIRST_ID: u16 = 0x1C1;

/// Each producer's input changes at intervals drawn uniformly from this range (ms), every
/// change an event-driven pair.
pub const INPUT_CHANGE_MS: (u64, u64) = (1000, 3000);

/// Producers, one per CiA 304 SRDO identifier pair.
pub const PRODUCERS: u8 = 64;

/// The bit rate of the full network.
pub const BIT_RATE: u32 = 1_000_000;

/// Bits a standard frame with `len` data bytes occupies at most (ISO 11898-1 10.5): SOF to the
/// end of the CRC is 34 + 8·len bits, all subject to stuffing, at worst one stuff bit after
/// the first five equal bits and one after every four after that, (34 + 8·len − 1) / 4; then
/// the 13 fixed-form bits (CRC delimiter, ACK slot and delimiter, EOF, intermission).
pub fn worst_case_bits(len: u8) -> u32 {
    // One formula for the plan, the tool's calculators and the safety manual.
    safety_config::calc::bus::worst_case_bits(len)
}

/// [`worst_case_bits`] in microseconds at `bit_rate`, rounded up.
pub fn worst_case_micros(len: u8, bit_rate: u32) -> u64 {
    safety_config::calc::bus::frame_micros(len, bit_rate)
}

/// One periodic stream for the budget: `count` frames of `len` bytes every `period_us`.
#[derive(Clone, Copy, Debug)]
pub struct Stream {
    /// What it is.
    pub what: &'static str,
    /// Frames per period.
    pub count: u32,
    /// Data bytes.
    pub len: u8,
    /// Period (µs).
    pub period_us: u64,
}

impl Stream {
    /// Its worst-case share of the bus at `bit_rate`.
    pub fn utilisation(&self, bit_rate: u32) -> f64 {
        f64::from(self.count) * worst_case_micros(self.len, bit_rate) as f64 / self.period_us as f64
    }
}

/// The timing of the full network.
#[derive(Clone, Debug)]
pub struct Timing {
    /// Refresh time of every producer (ms).
    pub refresh_ms: u16,
    /// SCT of every consumer (ms).
    pub sct_ms: u16,
    /// SRVT of every consumer (ms).
    pub srvt_ms: u8,
    /// The link heartbeat between the channels of a node.
    pub link_period: Duration,
    /// The background streams, for the report.
    pub background: Vec<Stream>,
    /// The SRDO streams at the refresh time.
    pub srdo: Stream,
    /// Worst-case SRVT bound the SRVT covers (µs), for the report.
    pub srvt_bound_us: u64,
}

impl Timing {
    /// Derives the timing for `producers` producers and `nodes` nodes at `bit_rate`:
    ///
    /// - refresh: the shortest whole ms with worst-case utilisation ≤ [`UTILISATION_LIMIT`];
    /// - SRVT: a bound on the gap between a plain and its inverted frame: channel A's
    ///   announcement to channel B over the link (at most
    ///   [`safety_config::calc::sfrt::LINK_MESSAGES_AHEAD`] link messages with the
    ///   announcement, [`dual_channel::link::MAX_WIRE`] bytes each at 10 µs), one frame of blocking (8 bytes), and every other SRDO frame once (each
    ///   producer sends at most one pair per refresh time, and the bound stays below it);
    /// - SCT: covers both a refresh interval stretched by a whole refresh time of jitter
    ///   (2 × refresh) and the CiA 304 9.5 start-up stagger of the last producer (0.5 ms ×
    ///   node-ID) plus one refresh time, the first pair a consumer waits for;
    /// - link period: the simulation's 10 ms ([`crate::dual::LINK_PERIOD`]), at least four
    ///   per SCT as the channel runtime asks.
    pub fn derive(producers: u8, nodes: u32, bit_rate: u32) -> Self {
        let background = vec![
            Stream {
                what: "heartbeats",
                count: nodes,
                len: 1,
                period_us: HEARTBEAT.as_micros(),
            },
            Stream {
                what: "PDO-like",
                count: u32::from(PDO_STREAMS),
                len: 8,
                period_us: PDO_PERIOD.as_micros(),
            },
            Stream {
                what: "event-driven SRDO pairs (input changes)",
                count: 2 * u32::from(producers),
                len: 1,
                period_us: INPUT_CHANGE_MS.0 * 1000,
            },
        ];
        let background_share: f64 = background.iter().map(|s| s.utilisation(bit_rate)).sum();
        let pair_frames = 2 * u32::from(producers);
        let mut refresh_ms: u16 = 1;
        let srdo = loop {
            let stream = Stream {
                what: "cyclic SRDO pairs",
                count: pair_frames,
                len: 1,
                period_us: u64::from(refresh_ms) * 1000,
            };
            if stream.utilisation(bit_rate) + background_share <= UTILISATION_LIMIT {
                break stream;
            }
            refresh_ms += 1;
        };
        let link_bytes =
            safety_config::calc::sfrt::LINK_MESSAGES_AHEAD * dual_channel::link::MAX_WIRE as u64;
        let srvt_bound_us = link_bytes * crate::dual::LINK_BYTE_TIME.as_micros()
            + worst_case_micros(8, bit_rate)
            + u64::from(pair_frames) * worst_case_micros(1, bit_rate);
        let srvt_ms = srvt_bound_us.div_ceil(1000) as u8;
        let stagger_ms = u64::from(producers).div_ceil(2);
        let sct_ms = (2 * u64::from(refresh_ms)).max(stagger_ms + u64::from(refresh_ms)) as u16;
        Timing {
            refresh_ms,
            sct_ms,
            srvt_ms,
            link_period: crate::dual::LINK_PERIOD,
            background,
            srdo,
            srvt_bound_us,
        }
    }

    /// The worst-case utilisation of everything periodic.
    pub fn utilisation(&self, bit_rate: u32) -> f64 {
        self.srdo.utilisation(bit_rate)
            + self
                .background
                .iter()
                .map(|s| s.utilisation(bit_rate))
                .sum::<f64>()
    }
}

/// What one node does.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Role {
    /// Node-ID.
    pub id: u8,
    /// The SRDO pair it produces (its SRDO 1), if any.
    pub produces: Option<u8>,
    /// The SRDO pair it consumes and the SRDO number it receives it with, if any.
    pub consumes: Option<(u8, u8)>,
}

/// The 127 nodes of the full network (see the module documentation).
pub fn roles() -> Vec<Role> {
    let mut roles: Vec<Role> = (1..=PRODUCERS)
        .map(|n| Role {
            id: n,
            produces: Some(n),
            consumes: None,
        })
        .collect();
    roles[0].consumes = Some((PRODUCERS, 2));
    roles.extend((1..PRODUCERS).map(|n| Role {
        id: PRODUCERS + n,
        produces: None,
        consumes: Some((n, 1)),
    }));
    roles
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 64 producers on the 64 CiA 304 pairs, 64 consumers, each pair consumed exactly once,
    /// node-IDs 1..=127 each once.
    #[test]
    fn cia304_8_3_3_every_srdo_pair_has_one_producer_and_one_consumer_in_the_full_network() {
        let roles = roles();
        assert_eq!(roles.len(), 127);
        let mut ids: Vec<u8> = roles.iter().map(|r| r.id).collect();
        ids.sort_unstable();
        assert_eq!(ids, (1..=127).collect::<Vec<u8>>());
        for pair in 1..=PRODUCERS {
            assert_eq!(roles.iter().filter(|r| r.produces == Some(pair)).count(), 1);
            assert_eq!(
                roles
                    .iter()
                    .filter(|r| r.consumes.is_some_and(|(p, _)| p == pair))
                    .count(),
                1
            );
        }
        assert!(
            roles
                .iter()
                .all(|r| r.consumes.is_none_or(|(p, _)| Some(p) != r.produces))
        );
    }

    /// The worst case of the formula is reached by a real frame and never exceeded by any.
    #[test]
    fn worst_case_frame_bits_bound_every_frame() {
        use shared::{CanFrame, CanId};
        for len in 0..=8u8 {
            let mut worst = 0;
            for id in (0..0x800u16).step_by(7) {
                for fill in [0x00u8, 0xFF, 0x0F, 0xF0, 0x55, 0x3C] {
                    let frame =
                        CanFrame::new(CanId::new(id).unwrap(), &vec![fill; usize::from(len)])
                            .unwrap();
                    let bits = crate::bus::frame_bits(&frame);
                    assert!(bits <= worst_case_bits(len), "{id:03X} {len} {fill:02X}");
                    worst = worst.max(bits);
                }
            }
            assert!(worst > 47 + 8 * u32::from(len), "stuffing happens");
        }
    }

    /// The derived timing keeps the worst-case utilisation within the limit, one ms less of
    /// refresh would not, SRVT < SCT, and four link periods fit in the SCT.
    #[test]
    fn timing_is_the_shortest_refresh_within_the_limit() {
        let timing = Timing::derive(PRODUCERS, 127, BIT_RATE);
        assert!(timing.utilisation(BIT_RATE) <= UTILISATION_LIMIT);
        let mut faster = timing.clone();
        faster.srdo.period_us -= 1000;
        assert!(faster.utilisation(BIT_RATE) > UTILISATION_LIMIT);
        assert!(u16::from(timing.srvt_ms) < timing.sct_ms);
        assert!(u64::from(timing.sct_ms) * 1000 >= 4 * timing.link_period.as_micros());
    }
}
