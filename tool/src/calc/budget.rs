//! The budget of a planned network: its bus load at each bit rate and its residual error rate
//! against the chosen SIL (EN 50325-5 9.4), with a warning for every limit it exceeds.

use super::bus::{Stream, utilisation};
use super::residual::{self, MAX_PRODUCERS, Sil};
use super::sfrt::planned_streams;
use crate::network_file::Network;

/// The bit rates of CiA 301 Table 1 that the budget reports (kbit/s 125 to 1000).
pub const BIT_RATES: [u32; 4] = [125_000, 250_000, 500_000, 1_000_000];

/// The worst-case bus load above which the budget warns: fixed-priority CAN still bounds
/// every frame's wait up to 100 %, but above this the lowest-priority traffic (heartbeats,
/// SDO) waits long and a single fault's retransmissions have no room.
pub const LOAD_WARNING: f64 = 0.8;

/// The plan, as the caller states it beside the network file.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Plan {
    /// The SIL the safety functions must meet.
    pub sil: Sil,
    /// Safety devices on the network, when more than the file lists (other safety nodes).
    pub devices: Option<u32>,
    /// The shortest interval between two input changes of one producer (µs); none: one
    /// event-driven pair per refresh time besides the cyclic one.
    pub event_interval_us: Option<u64>,
    /// Other traffic on the bus (PDOs, SYNC, other nodes' frames).
    pub traffic: Vec<Stream>,
}

/// A limit the plan exceeds.
#[derive(Clone, Debug, PartialEq, thiserror::Error, serde::Serialize)]
pub enum Warning {
    /// Residual error rate at or above the SIL's limit.
    #[error(
        "the residual error rate {rate:.2e}/h is not below the SIL {sil} limit of {limit:.0e}/h: at most {most:.1} SRDOs per second with {devices} safety devices (now {srdos:.1}); lengthen refresh times or split the network"
    )]
    ResidualErrorRate {
        /// The rate (per hour).
        rate: f64,
        /// The SIL (number).
        sil: u8,
        /// Its limit (per hour).
        limit: f64,
        /// SRDOs per second allowed.
        most: f64,
        /// SRDOs per second planned.
        srdos: f64,
        /// Safety devices.
        devices: u32,
    },
    /// More SRDO producers than EN 50325-5 9.4.1 allows.
    #[error("the network has {producers} SRDO producers, more than the 64 EN 50325-5 9.4.1 allows")]
    TooManyProducers {
        /// Producers counted.
        producers: u32,
    },
    /// Worst-case bus load above [`LOAD_WARNING`].
    #[error(
        "at {kbit} kbit/s the worst-case bus load is {percent:.1} %, above {limit:.0} %: frames at low priority wait long and errors have no room; use a higher bit rate or less traffic"
    )]
    BusLoad {
        /// Bit rate (kbit/s).
        kbit: u32,
        /// Load (%).
        percent: f64,
        /// The warning threshold (%).
        limit: f64,
    },
}

/// The budget of one plan.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Budget {
    /// SRDO producers (nodes with a transmit SRDO).
    pub producers: u32,
    /// Safety devices counted for the residual error rate.
    pub devices: u32,
    /// SRDOs per second on the network (cyclic and event-driven).
    pub srdos_per_second: f64,
    /// Worst-case bus load (0..) at each of [`BIT_RATES`].
    pub loads: Vec<(u32, f64)>,
    /// Residual error rate per hour (EN 50325-5 9.4.2, DSP 304 9.3).
    pub rate_per_hour: f64,
    /// The highest SIL whose limit the rate stays below.
    pub highest_sil: Option<Sil>,
    /// The most SRDOs per second the chosen SIL allows with this many devices.
    pub max_srdos_per_second: f64,
    /// Every limit exceeded; the bus load only at `bit_rate`, the one the network runs at.
    pub warnings: Vec<Warning>,
}

/// The budget of `network` at `bit_rate` (the other bit rates are reported for comparison).
#[must_use]
pub fn budget(network: &Network, plan: &Plan, bit_rate: u32) -> Budget {
    let transmits = || {
        network
            .nodes
            .iter()
            .flat_map(|node| node.srdos.iter())
            .filter(|srdo| srdo.settings.direction == 1)
    };
    let producers = network
        .nodes
        .iter()
        .filter(|node| node.srdos.iter().any(|s| s.settings.direction == 1))
        .count() as u32;
    let devices = plan.devices.unwrap_or(0).max(network.nodes.len() as u32);
    let per_second = |us: u64| 1e6 / us.max(1) as f64;
    // Without a stated interval, one event-driven pair per refresh time besides the cyclic
    // one, in the rate as on the bus (`planned_streams`): the worst the plan can assume.
    // A fold from +0.0, not `sum()`: the sum of no `f64`s is −0.0, which a network without
    // SRDOs would print as "-0.00e0 per hour".
    let srdos_per_second = transmits()
        .map(|srdo| {
            let refresh = u64::from(srdo.settings.cycle_time) * 1000;
            per_second(refresh) + per_second(plan.event_interval_us.unwrap_or(refresh))
        })
        .fold(0.0, |sum, rate| sum + rate);
    let streams = planned_streams(network, plan.event_interval_us, &plan.traffic);
    let mut bit_rates: Vec<u32> = BIT_RATES.to_vec();
    if !bit_rates.contains(&bit_rate) {
        bit_rates.push(bit_rate);
        bit_rates.sort_unstable();
    }
    let loads: Vec<(u32, f64)> = bit_rates
        .iter()
        .map(|&rate| (rate, utilisation(&streams, rate)))
        .collect();
    let rate_per_hour = residual::rate_per_hour(srdos_per_second, devices);
    let max_srdos_per_second = residual::max_srdos_per_second(plan.sil, devices);
    let mut warnings = Vec::new();
    if rate_per_hour >= plan.sil.limit_per_hour() {
        warnings.push(Warning::ResidualErrorRate {
            rate: rate_per_hour,
            sil: plan.sil.level(),
            limit: plan.sil.limit_per_hour(),
            most: max_srdos_per_second,
            srdos: srdos_per_second,
            devices,
        });
    }
    if producers > MAX_PRODUCERS {
        warnings.push(Warning::TooManyProducers { producers });
    }
    if let Some(&(_, load)) = loads.iter().find(|(rate, _)| *rate == bit_rate) {
        if load > LOAD_WARNING {
            warnings.push(Warning::BusLoad {
                kbit: bit_rate / 1000,
                percent: load * 100.0,
                limit: LOAD_WARNING * 100.0,
            });
        }
    }
    Budget {
        producers,
        devices,
        srdos_per_second,
        loads,
        rate_per_hour,
        highest_sil: residual::highest_sil(rate_per_hour),
        max_srdos_per_second,
        warnings,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calc::sfrt::example_network;
    use crate::network_file::{Identity, NodeSpec, SrdoSpec, parse};
    use crate::signature::SrdoSettings;

    fn plan(sil: Sil) -> Plan {
        Plan {
            sil,
            devices: None,
            event_interval_us: None,
            traffic: Vec::new(),
        }
    }

    /// `producers` nodes, each with one transmit SRDO at `refresh_ms`.
    fn producers(count: u8, refresh_ms: u16) -> Network {
        let nodes = (1..=count)
            .map(|id| NodeSpec {
                id,
                name: None,
                identity: Identity {
                    vendor: 0xABC,
                    product: 0x304,
                    revision: None,
                    serial: 1,
                },
                srdos: vec![SrdoSpec {
                    number: 1,
                    settings: SrdoSettings {
                        direction: 1,
                        cycle_time: refresh_ms,
                        srvt: 20,
                        cob_id_1: 0xFF + 2 * u32::from(id),
                        cob_id_2: 0x100 + 2 * u32::from(id),
                        mapping: vec![0x6000_0108, 0x6001_0108],
                    },
                }],
                clear_gfc_indication: false,
            })
            .collect();
        Network {
            sdo_timeout: std::time::Duration::from_millis(500),
            nodes,
            lss_fastscan: false,
            simplecan: None,
        }
    }

    /// The demo's network (two devices, one SRDO every 25 ms and at most one event-driven one
    /// in between: 80 per second) is far inside SIL 3, and its
    /// load at 125 kbit/s is what the frames add up to: two 520 µs frames twice per 25 ms
    /// (cyclic and at most one event each refresh) and two heartbeats every 100 ms.
    #[test]
    fn en50325_5_9_4_2_the_demo_network_meets_sil3() {
        let network = parse(&example_network(25, 50, 20), "example").unwrap();
        let budget = budget(&network, &plan(Sil::Sil3), 500_000);
        assert_eq!((budget.producers, budget.devices), (1, 2));
        assert!((budget.srdos_per_second - 80.0).abs() < 1e-9);
        assert_eq!(budget.highest_sil, Some(Sil::Sil3));
        assert!(budget.warnings.is_empty(), "{:?}", budget.warnings);
        let (_, load) = budget.loads[0];
        assert!((load - (4.0 * 520.0 / 25_000.0 + 2.0 * 520.0 / 100_000.0)).abs() < 1e-12);
    }

    /// 64 producers at 10 ms, with an event-driven pair each refresh, are 12800 SRDOs per
    /// second: SIL 3 allows 44, SIL 1 4409; the
    /// budget warns with the figures, and the bus at 125 kbit/s is overloaded.
    #[test]
    fn en50325_5_9_4_2_a_busy_network_is_warned_for_sil3() {
        let network = producers(64, 10);
        let budget = budget(&network, &plan(Sil::Sil3), 125_000);
        assert_eq!(budget.highest_sil, None);
        let warning = budget.warnings[0].to_string();
        assert!(
            warning.contains("not below the SIL 3 limit of 1e-7/h"),
            "{warning}"
        );
        assert!(
            warning.contains("at most 44.1 SRDOs per second with 64 safety devices (now 12800.0)"),
            "{warning}"
        );
        assert!(matches!(
            budget.warnings[1],
            Warning::BusLoad { kbit: 125, .. }
        ));
        assert_eq!(budget.warnings.len(), 2);
    }

    /// EN 50325-5 9.4.1: a 65th producer is warned of, 64 are not.
    #[test]
    fn en50325_5_9_4_1_more_than_64_producers_are_warned_of() {
        let sil1 = |count| budget(&producers(count, 1000), &plan(Sil::Sil1), 1_000_000);
        assert!(
            !sil1(64)
                .warnings
                .iter()
                .any(|w| matches!(w, Warning::TooManyProducers { .. }))
        );
        assert!(
            sil1(65)
                .warnings
                .contains(&Warning::TooManyProducers { producers: 65 })
        );
    }

    /// The load warning starts above 80 %, at the network's own bit rate only.
    #[test]
    fn the_load_warning_is_for_the_chosen_bit_rate_above_80_percent() {
        let network = producers(1, 1000);
        // One 8-byte stream of 135 µs at 1 Mbit/s every 168 µs: 80.4 % with the SRDO frames.
        let traffic = vec![Stream {
            id: 0x200,
            len: 8,
            period_us: 168,
        }];
        let plan = Plan {
            traffic,
            ..plan(Sil::Sil1)
        };
        let at_1m = budget(&network, &plan, 1_000_000);
        let load = at_1m
            .loads
            .iter()
            .find(|(rate, _)| *rate == 1_000_000)
            .unwrap()
            .1;
        assert!(load > LOAD_WARNING && load < 0.81, "{load}");
        assert!(matches!(
            at_1m.warnings[..],
            [Warning::BusLoad { kbit: 1000, .. }]
        ));
        let lighter = Plan {
            traffic: vec![Stream {
                id: 0x200,
                len: 8,
                period_us: 180,
            }],
            ..plan
        };
        assert!(budget(&network, &lighter, 1_000_000).warnings.is_empty());
    }
}
