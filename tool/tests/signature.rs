//! The tool's own Table 9 signature (EN 50325-5 6.4.1.5) against the node's
//! (`shared::safety::signature`, a different CRC implementation over a different type), on
//! random configurations and on the golden vectors of shared's tests.

use proptest::prelude::*;
use safety_config::signature::{SrdoSettings, signature};
use shared::safety::config::{SafetyConfig, SrdoRecord};

fn record(settings: &SrdoSettings) -> SrdoRecord {
    let mut record = SrdoRecord::DELETED;
    record.direction = settings.direction;
    record.cycle_time = settings.cycle_time;
    record.srvt = settings.srvt;
    record.cob_id_1 = settings.cob_id_1;
    record.cob_id_2 = settings.cob_id_2;
    record.mapping_count = settings.mapping.len() as u8;
    record.mapping[..settings.mapping.len()].copy_from_slice(&settings.mapping);
    record
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]
    #[test]
    fn en50325_5_6_4_1_5_tool_signature_equals_the_nodes(
        direction in any::<u8>(),
        cycle_time in any::<u16>(),
        srvt in any::<u8>(),
        cob_id_1 in any::<u32>(),
        cob_id_2 in any::<u32>(),
        mapping in proptest::collection::vec(any::<u32>(), 0..=16),
    ) {
        let settings = SrdoSettings { direction, cycle_time, srvt, cob_id_1, cob_id_2, mapping };
        prop_assert_eq!(signature(&settings), shared::safety::signature::compute(&record(&settings)));
    }
}

/// The golden values of shared's `en50325_5_table9_golden_values` (computed there by a third
/// implementation): pre-defined SRDO 1 of node 1 and node 33.
#[test]
fn en50325_5_table9_golden_values() {
    let tx = [0x6000_0108, 0x6001_0108];
    let rx = [0x6200_0108, 0x6201_0108];
    for (node, golden) in [(1u8, 0x191A), (33, 0x741E)] {
        let predefined = SafetyConfig::<1>::predefined(node, &tx, &rx).srdos[0];
        let settings = SrdoSettings {
            direction: predefined.direction,
            cycle_time: predefined.cycle_time,
            srvt: predefined.srvt,
            cob_id_1: predefined.cob_id_1,
            cob_id_2: predefined.cob_id_2,
            mapping: predefined.entries().to_vec(),
        };
        assert_eq!(signature(&settings), golden, "node {node}");
    }
}
