//! Tests of the SRDO configuration rules: every abort code of a single write, and the property
//! that single writes and the Operational-entry check never disagree.

use super::*;
use crate::process_image::{Access, AppObject};
use proptest::prelude::*;

const fn object(index: u16, sub: u8, len: u8, mappable: Mappable) -> AppObject {
    AppObject {
        address: Address::new(index, sub),
        len,
        access: Access::ReadOnly,
        mappable,
    }
}

static OBJECTS: [AppObject; 12] = [
    object(0x6000, 1, 1, Mappable::Transmit),
    object(0x6000, 2, 1, Mappable::Transmit),
    object(0x6001, 1, 1, Mappable::Transmit),
    object(0x6001, 2, 1, Mappable::Transmit),
    object(0x6100, 1, 4, Mappable::Transmit),
    object(0x6101, 1, 4, Mappable::Transmit),
    object(0x6100, 2, 2, Mappable::Transmit),
    object(0x6200, 1, 1, Mappable::Receive),
    object(0x6201, 1, 1, Mappable::Receive),
    object(0x6300, 1, 8, Mappable::Transmit),
    object(0x6301, 1, 8, Mappable::Transmit),
    object(0x2000, 1, 1, Mappable::No),
];

fn image() -> ProcessImage {
    ProcessImage::new(&OBJECTS).unwrap()
}

const TX: [u32; 2] = [0x6000_0108, 0x6001_0108];
const RX: [u32; 2] = [0x6200_0108, 0x6201_0108];

/// Node 1's pre-defined configuration: SRDO 1 transmits on 0x101/0x102; SRDO 2..4 deleted.
fn config() -> SafetyConfig<4> {
    SafetyConfig::predefined(1, &TX, &RX)
}

fn write(config: &mut SafetyConfig<4>, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
    config.write(Address::new(index, sub), data, &image(), false)
}

/// Writes and asserts the specific abort code, and that the refused write changed nothing.
fn refused(config: &mut SafetyConfig<4>, index: u16, sub: u8, data: &[u8], abort: AbortCode) {
    let before = config.clone();
    assert_eq!(
        write(config, index, sub, data),
        Err(abort),
        "{index:#06x}:{sub} <- {data:02x?}"
    );
    assert_eq!(*config, before, "a refused write changes nothing");
}

/// SRDO 2 made to exist as a consumer on 0x111/0x112 through single writes.
fn with_consumer_srdo_2(config: &mut SafetyConfig<4>) {
    write(config, 0x1302, 5, &0x111u32.to_le_bytes()).unwrap();
    write(config, 0x1302, 6, &0x112u32.to_le_bytes()).unwrap();
    write(config, 0x1302, 2, &50u16.to_le_bytes()).unwrap();
    write(config, 0x1382, 1, &RX[0].to_le_bytes()).unwrap();
    write(config, 0x1382, 2, &RX[1].to_le_bytes()).unwrap();
    write(config, 0x1382, 0, &[2]).unwrap();
    write(config, 0x1302, 1, &[2]).unwrap();
}

#[test]
fn en50325_5_8_2_2_every_safety_object_is_read_only_in_operational_with_0800_0022() {
    let mut config = config();
    config.configuration_valid = CONFIGURATION_VALID;
    let image = image();
    for (index, sub, data) in [
        (0x1301, 1, &[1u8][..]),
        (0x1301, 2, &[25, 0][..]),
        (0x1301, 5, &[1, 1, 0, 0][..]),
        (0x1381, 0, &[0][..]),
        (0x1381, 1, &[0, 0, 0, 0][..]),
        (0x13FE, 0, &[0][..]),
        (0x13FF, 1, &[0, 0][..]),
    ] {
        let before = config.clone();
        assert_eq!(
            config.write(Address::new(index, sub), data, &image, true),
            Err(AbortCode::DeviceState)
        );
        assert_eq!(config, before);
    }
    // Reading stays allowed (CiA 304 Table 2, note 1); a missing entry is still named as such.
    let mut buf = [0u8; 4];
    assert_eq!(config.read(Address::new(0x1301, 1), &mut buf), Ok(1));
    assert_eq!(
        config.write(Address::new(0x1301, 9), &[0], &image, true),
        Err(AbortCode::NoSubIndex)
    );
}

/// EN 50325-5 Table 5: sub-index 04h is a read-only entry (fixed at 254), answered 0601 0002h
/// like every other read-only entry, whatever the value and its length.
#[test]
fn en50325_5_table5_transmission_type_write_aborts_0601_0002() {
    let mut config = config();
    refused(&mut config, 0x1301, 4, &[254], AbortCode::ReadOnly);
    refused(&mut config, 0x1301, 4, &[1], AbortCode::ReadOnly);
    refused(&mut config, 0x1301, 4, &[254, 0], AbortCode::ReadOnly);
    let mut buf = [0u8; 1];
    assert_eq!(config.read(Address::new(0x1301, 4), &mut buf), Ok(1));
    assert_eq!(buf[0], 254);
}

#[test]
fn en50325_5_table5_highest_sub_indices_are_read_only() {
    let mut config = config();
    refused(&mut config, 0x1301, 0, &[6], AbortCode::ReadOnly);
    refused(&mut config, 0x13FF, 0, &[4], AbortCode::ReadOnly);
}

#[test]
fn en50325_5_table5_direction_above_2_aborts_value_too_high() {
    let mut config = config();
    refused(&mut config, 0x1302, 1, &[3], AbortCode::ValueTooHigh);
}

#[test]
fn en50325_5_6_2_1_zero_times_abort_value_too_low() {
    let mut config = config();
    refused(&mut config, 0x1301, 2, &[0, 0], AbortCode::ValueTooLow);
    refused(&mut config, 0x1302, 2, &[0, 0], AbortCode::ValueTooLow);
    refused(&mut config, 0x1301, 3, &[0], AbortCode::ValueTooLow);
}

#[test]
fn srvt_must_stay_below_sct_of_an_existing_consumer() {
    let mut config = config();
    with_consumer_srdo_2(&mut config);
    refused(
        &mut config,
        0x1302,
        3,
        &[50],
        AbortCode::ParameterIncompatible,
    );
    refused(
        &mut config,
        0x1302,
        2,
        &20u16.to_le_bytes(),
        AbortCode::ParameterIncompatible,
    );
    write(&mut config, 0x1302, 3, &[49]).unwrap();
    // While deleted, fields can be set in any order; the check runs when it comes to exist.
    write(&mut config, 0x1303, 3, &[60]).unwrap();
}

#[test]
fn en50325_5_table5_cob_id_range_and_parity_aborts() {
    let mut config = config();
    refused(
        &mut config,
        0x1302,
        5,
        &0x0FFu32.to_le_bytes(),
        AbortCode::ValueTooLow,
    );
    refused(
        &mut config,
        0x1302,
        5,
        &0x181u32.to_le_bytes(),
        AbortCode::ValueTooHigh,
    );
    refused(
        &mut config,
        0x1302,
        5,
        &0x8000_0111u32.to_le_bytes(),
        AbortCode::ValueTooHigh,
    );
    refused(
        &mut config,
        0x1302,
        5,
        &0x110u32.to_le_bytes(),
        AbortCode::InvalidValue,
    );
    refused(
        &mut config,
        0x1302,
        6,
        &0x101u32.to_le_bytes(),
        AbortCode::ValueTooLow,
    );
    refused(
        &mut config,
        0x1302,
        6,
        &0x182u32.to_le_bytes(),
        AbortCode::ValueTooHigh,
    );
    refused(
        &mut config,
        0x1302,
        6,
        &0x111u32.to_le_bytes(),
        AbortCode::InvalidValue,
    );
}

#[test]
fn cia304_8_4_2_2_cob_ids_cannot_change_while_the_srdo_exists() {
    let mut config = config();
    refused(
        &mut config,
        0x1301,
        5,
        &0x103u32.to_le_bytes(),
        AbortCode::InvalidValue,
    );
    // Rewriting the same value is no change and is accepted (it still withdraws 0x13FE).
    config.configuration_valid = CONFIGURATION_VALID;
    write(&mut config, 0x1301, 5, &0x101u32.to_le_bytes()).unwrap();
    assert_eq!(config.configuration_valid, 0);
}

#[test]
fn en50325_5_6_4_1_3_cob_id_pair_is_checked_when_the_srdo_comes_to_exist() {
    let mut config = config();
    write(&mut config, 0x1302, 5, &0x111u32.to_le_bytes()).unwrap();
    write(&mut config, 0x1302, 6, &0x114u32.to_le_bytes()).unwrap();
    write(&mut config, 0x1382, 1, &TX[0].to_le_bytes()).unwrap();
    write(&mut config, 0x1382, 2, &TX[1].to_le_bytes()).unwrap();
    write(&mut config, 0x1382, 0, &[2]).unwrap();
    refused(
        &mut config,
        0x1302,
        1,
        &[1],
        AbortCode::ParameterIncompatible,
    );
    // Identifiers of another existing SRDO are refused too.
    write(&mut config, 0x1302, 5, &0x101u32.to_le_bytes()).unwrap();
    write(&mut config, 0x1302, 6, &0x102u32.to_le_bytes()).unwrap();
    refused(
        &mut config,
        0x1302,
        1,
        &[1],
        AbortCode::ParameterIncompatible,
    );
    write(&mut config, 0x1302, 5, &0x103u32.to_le_bytes()).unwrap();
    write(&mut config, 0x1302, 6, &0x104u32.to_le_bytes()).unwrap();
    write(&mut config, 0x1302, 1, &[1]).unwrap();
}

#[test]
fn en50325_5_6_4_1_4_mapping_cannot_change_while_the_srdo_exists() {
    let mut config = config();
    refused(&mut config, 0x1381, 0, &[0], AbortCode::DeviceState);
    refused(
        &mut config,
        0x1381,
        1,
        &TX[0].to_le_bytes(),
        AbortCode::DeviceState,
    );
}

#[test]
fn en50325_5_table8_mapping_entries_need_sub_index_0_at_0() {
    let mut config = config();
    write(&mut config, 0x1301, 1, &[0]).unwrap();
    refused(
        &mut config,
        0x1381,
        1,
        &TX[0].to_le_bytes(),
        AbortCode::UnsupportedAccess,
    );
    write(&mut config, 0x1381, 0, &[0]).unwrap();
    write(&mut config, 0x1381, 1, &TX[0].to_le_bytes()).unwrap();
    refused(
        &mut config,
        0x1381,
        17,
        &TX[0].to_le_bytes(),
        AbortCode::NoSubIndex,
    );
}

/// Deletes SRDO 1, writes `entries` and then `count` into sub-index 0.
fn map(config: &mut SafetyConfig<4>, entries: &[u32], count: u8) -> Result<(), AbortCode> {
    write(config, 0x1301, 1, &[0]).unwrap();
    write(config, 0x1381, 0, &[0]).unwrap();
    for (sub, entry) in entries.iter().enumerate() {
        write(config, 0x1381, sub as u8 + 1, &entry.to_le_bytes()).unwrap();
    }
    write(config, 0x1381, 0, &[count])
}

#[test]
fn en50325_5_table6_mapping_count_rules() {
    let mut config = config();
    assert_eq!(
        map(&mut config, &TX, 1),
        Err(AbortCode::InvalidValue),
        "odd count"
    );
    assert_eq!(
        map(&mut config, &TX, 18),
        Err(AbortCode::MappingTooLong),
        "more than 16 entries"
    );
    assert_eq!(map(&mut config, &TX, 0x81), Err(AbortCode::InvalidValue));
    assert_eq!(map(&mut config, &TX, 2), Ok(()));
}

#[test]
fn en50325_5_6_2_mapped_data_must_fit_eight_bytes() {
    let mut config = config();
    let entries = [0x6300_0140, 0x6301_0140, 0x6000_0108, 0x6001_0108];
    assert_eq!(map(&mut config, &entries, 2), Ok(()), "8 bytes fit");
    assert_eq!(
        map(&mut config, &entries, 4),
        Err(AbortCode::MappingTooLong),
        "9 bytes do not"
    );
}

#[test]
fn mapped_objects_must_exist_fit_and_pair_up() {
    let mut config = config();
    assert_eq!(
        map(&mut config, &[0x6500_0108, 0x6001_0108], 2),
        Err(AbortCode::NoObject)
    );
    assert_eq!(
        map(&mut config, &[0x6000_0908, 0x6001_0108], 2),
        Err(AbortCode::NoSubIndex)
    );
    assert_eq!(
        map(&mut config, &[0x2000_0108, 0x6001_0108], 2),
        Err(AbortCode::NotMappable)
    );
    assert_eq!(
        map(&mut config, &[0x6000_0110, 0x6001_0110], 2),
        Err(AbortCode::NotMappable),
        "16 bits of an 8-bit object"
    );
    assert_eq!(
        map(&mut config, &[0x6000_0104, 0x6001_0104], 2),
        Err(AbortCode::NotMappable),
        "part of a byte"
    );
    assert_eq!(
        map(&mut config, &[0x6100_0120, 0x6100_0210], 2),
        Err(AbortCode::ParameterIncompatible),
        "pair lengths differ"
    );
    assert_eq!(
        map(&mut config, &[0x6000_0108, 0x6000_0108], 2),
        Err(AbortCode::ParameterIncompatible),
        "both halves on one object"
    );
}

#[test]
fn mapping_direction_is_checked_when_the_srdo_comes_to_exist() {
    let mut config = config();
    map(&mut config, &RX, 2).unwrap();
    refused(&mut config, 0x1301, 1, &[1], AbortCode::NotMappable);
    write(&mut config, 0x1381, 0, &[0]).unwrap();
    refused(
        &mut config,
        0x1301,
        1,
        &[1],
        AbortCode::ParameterIncompatible,
    );
}

#[test]
fn cia301_data_length_must_match_the_entry_type() {
    let mut config = config();
    refused(&mut config, 0x1302, 1, &[1, 0], AbortCode::LengthTooHigh);
    refused(&mut config, 0x1302, 2, &[1], AbortCode::LengthTooLow);
    refused(
        &mut config,
        0x1302,
        5,
        &[0x11, 0x01],
        AbortCode::LengthTooLow,
    );
    refused(&mut config, 0x13FF, 1, &[0, 0, 0], AbortCode::LengthTooHigh);
}

#[test]
fn objects_and_sub_indices_beyond_the_device_do_not_exist() {
    let mut config = config();
    refused(&mut config, 0x1305, 1, &[0], AbortCode::NoObject);
    refused(&mut config, 0x1385, 0, &[0], AbortCode::NoObject);
    refused(&mut config, 0x13FF, 5, &[0, 0], AbortCode::NoSubIndex);
    refused(&mut config, 0x1301, 7, &[0], AbortCode::NoSubIndex);
    refused(&mut config, 0x13FE, 1, &[0], AbortCode::NoSubIndex);
    refused(&mut config, 0x1380, 0, &[0], AbortCode::NoObject);
    let mut buf = [0u8; 4];
    assert_eq!(
        config.read(Address::new(0x1305, 1), &mut buf),
        Err(AbortCode::NoObject)
    );
    assert_eq!(config.read(Address::new(0x13FF, 0), &mut buf), Ok(1));
    assert_eq!(buf[0], 4);
}

#[test]
fn en50325_5_6_4_1_6_any_accepted_write_withdraws_validity() {
    for (index, sub, data) in [
        (0x1301u16, 2u8, &25u16.to_le_bytes()[..]),
        (0x1301, 3, &[20][..]),
        (0x1302, 1, &[0][..]),
        (0x13FF, 2, &[1, 2][..]),
    ] {
        let mut config = config();
        config.configuration_valid = CONFIGURATION_VALID;
        write(&mut config, index, sub, data).unwrap();
        assert_eq!(config.configuration_valid, 0, "{index:#06x}:{sub}");
    }
}

#[test]
fn en50325_5_8_3_1_declaring_valid_requires_matching_signatures() {
    let mut config = config();
    refused(
        &mut config,
        0x13FE,
        0,
        &[CONFIGURATION_VALID],
        AbortCode::ParameterIncompatible,
    );
    let signature = signature::compute(&config.srdos[0]);
    write(&mut config, 0x13FF, 1, &signature.to_le_bytes()).unwrap();
    write(&mut config, 0x13FE, 0, &[CONFIGURATION_VALID]).unwrap();
    assert_eq!(config.configuration_valid, CONFIGURATION_VALID);
    assert!(config.check_for_operational(&image(), |_, _| {}).is_ok());
    // Values other than A5h are accepted and mean "not valid".
    write(&mut config, 0x13FE, 0, &[0x5A]).unwrap();
    assert_eq!(
        config.check_for_operational(&image(), |_, _| {}),
        Err(ConfigFault {
            srdo: None,
            error: ConfigError::NotDeclaredValid
        })
    );
}

#[test]
fn every_config_error_has_a_distinct_cause_code() {
    let all = ConfigError::ALL;
    let mut codes: Vec<u8> = all.iter().map(|e| e.cause_code()).collect();
    codes.sort_unstable();
    codes.dedup();
    assert_eq!(codes.len(), all.len());
}

// ---- One validation: single writes and the Operational-entry check agree ------------------

/// Valid mapping pairs for each direction (transmit, receive).
const TX_PAIRS: [[u32; 2]; 4] = [
    [0x6000_0108, 0x6001_0108],
    [0x6000_0208, 0x6001_0208],
    [0x6100_0120, 0x6101_0120],
    [0x6300_0140, 0x6301_0140],
];
const RX_PAIRS: [[u32; 2]; 1] = [[0x6200_0108, 0x6201_0108]];

/// One field changed to a value at or beyond a rule's boundary.
#[derive(Clone, Debug)]
enum Perturbation {
    Direction(u8),
    CycleTime(u16),
    Srvt(u8),
    CobId1(u32),
    CobId2(u32),
    MappingCount(u8),
    Entry(usize, u32),
}

fn perturbation() -> impl Strategy<Value = Perturbation> {
    prop_oneof![
        prop_oneof![Just(0u8), Just(3u8), any::<u8>()].prop_map(Perturbation::Direction),
        prop_oneof![0u16..=2, 19u16..=22, any::<u16>()].prop_map(Perturbation::CycleTime),
        prop_oneof![0u8..=2, 18u8..=30, Just(255u8)].prop_map(Perturbation::Srvt),
        prop_oneof![0x0FFu32..=0x103, 0x17Du32..=0x183, any::<u32>()]
            .prop_map(Perturbation::CobId1),
        prop_oneof![0x100u32..=0x104, 0x17Eu32..=0x183, any::<u32>()]
            .prop_map(Perturbation::CobId2),
        prop_oneof![0u8..=5, 15u8..=18, Just(0x80u8)].prop_map(Perturbation::MappingCount),
        (
            0usize..4,
            prop_oneof![
                Just(0x6000_0108u32),
                Just(0x6200_0108u32),
                Just(0x6000_0110u32),
                Just(0x6000_0908u32),
                Just(0x6500_0108u32),
                Just(0x2000_0108u32),
                Just(0x6100_0210u32),
                any::<u32>(),
            ]
        )
            .prop_map(|(at, entry)| Perturbation::Entry(at, entry)),
    ]
}

/// A valid SRDO record (a random direction, identifier pair, times and mapping), then up to
/// two perturbations, so that the generated records sit on both sides of every rule.
fn record_strategy() -> impl Strategy<Value = SrdoRecord> {
    (
        any::<bool>(),
        0u32..63,
        10u16..=200,
        1u8..=9,
        proptest::collection::vec(0usize..4, 1..=2),
        proptest::collection::vec(perturbation(), 0..=2),
    )
        .prop_map(
            |(transmit, pair_number, cycle_time, srvt, pairs, perturbations)| {
                let mut record = SrdoRecord::DELETED;
                record.direction = if transmit { 1 } else { 2 };
                record.cycle_time = cycle_time;
                record.srvt = srvt;
                record.cob_id_1 = 0x101 + 2 * pair_number;
                record.cob_id_2 = record.cob_id_1 + 1;
                let choices: &[[u32; 2]] = if transmit { &TX_PAIRS } else { &RX_PAIRS };
                // Distinct pairs only, each object mapped once, at most 8 bytes in total.
                let mut used: Vec<[u32; 2]> = Vec::new();
                for pick in pairs {
                    let pair = choices[pick % choices.len()];
                    if !used.contains(&pair) {
                        used.push(pair);
                    }
                }
                if used.iter().map(|pair| pair[0] & 0xFF).sum::<u32>() > 64 {
                    used.truncate(1);
                }
                for (position, pair) in used.iter().enumerate() {
                    record.mapping[2 * position] = pair[0];
                    record.mapping[2 * position + 1] = pair[1];
                }
                record.mapping_count = (2 * used.len()) as u8;
                for perturbation in perturbations {
                    match perturbation {
                        Perturbation::Direction(value) => record.direction = value,
                        Perturbation::CycleTime(value) => record.cycle_time = value,
                        Perturbation::Srvt(value) => record.srvt = value,
                        Perturbation::CobId1(value) => record.cob_id_1 = value,
                        Perturbation::CobId2(value) => record.cob_id_2 = value,
                        Perturbation::MappingCount(value) => record.mapping_count = value,
                        Perturbation::Entry(at, value) => record.mapping[at] = value,
                    }
                }
                record
            },
        )
}

/// Builds `target` through single SDO-style writes the way a tool does (delete, parameters,
/// mapping, then direction); `true` when every write was accepted.
fn replay(config: &mut SafetyConfig<4>, slot: u16, target: &SrdoRecord) -> bool {
    let image = image();
    let mut w = |index: u16, sub: u8, data: &[u8]| {
        config
            .write(Address::new(index, sub), data, &image, false)
            .is_ok()
    };
    let (communication, mapping) = (0x1301 + slot, 0x1381 + slot);
    w(communication, 1, &[0])
        && w(communication, 2, &target.cycle_time.to_le_bytes())
        && w(communication, 3, &[target.srvt])
        && w(communication, 5, &target.cob_id_1.to_le_bytes())
        && w(communication, 6, &target.cob_id_2.to_le_bytes())
        && w(mapping, 0, &[0])
        && target
            .mapping
            .iter()
            .enumerate()
            .all(|(sub, entry)| w(mapping, sub as u8 + 1, &entry.to_le_bytes()))
        && w(mapping, 0, &[target.mapping_count])
        && w(communication, 1, &[target.direction])
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2048, failure_persistence: None, .. ProptestConfig::default() })]

    /// One validation (issue: "the same code judges a single SDO write and the whole
    /// configuration on the way into Operational"): a configuration of existing SRDOs can be
    /// built by accepted single writes exactly when the Operational-entry check accepts it.
    #[test]
    fn single_writes_and_operational_entry_agree(targets in proptest::collection::vec(record_strategy(), 1..=3)) {
        let mut written = SafetyConfig::<4>::predefined(65, &TX, &RX);
        let mut direct = written.clone();
        let mut all_accepted = true;
        for (slot, target) in targets.iter().enumerate() {
            if target.direction == 0 {
                // A deleted SRDO never runs: the Operational-entry check ignores its fields,
                // while single writes still judge each field. Only existing SRDOs are in scope.
                all_accepted &= written
                    .write(Address::new(0x1301 + slot as u16, 1), &[0], &image(), false)
                    .is_ok();
                direct.srdos[slot] = written.srdos[slot];
            } else {
                all_accepted &= replay(&mut written, slot as u16, target);
                direct.srdos[slot] = *target;
            }
        }
        let image = image();
        prop_assert_eq!(all_accepted, direct.check_structure(&image).is_ok());
        if all_accepted {
            prop_assert_eq!(&written, &direct);
        }
    }

    /// After any sequence of writes, accepted or not, every existing SRDO passes the
    /// Operational-entry check, and refused writes change nothing.
    #[test]
    fn accepted_writes_keep_every_existing_srdo_valid(
        writes in proptest::collection::vec(
            (0u16..=4, 0u8..=7, proptest::collection::vec(any::<u8>(), 0..=5), any::<bool>()),
            1..60,
        )
    ) {
        let image = image();
        let mut config = SafetyConfig::<4>::predefined(1, &TX, &RX);
        for (slot, sub, data, mapping) in writes {
            let index = if mapping { 0x1381 + slot } else { 0x1301 + slot };
            let before = config.clone();
            if config.write(Address::new(index, sub), &data, &image, false).is_err() {
                prop_assert_eq!(&config, &before);
            }
            prop_assert!(config.check_structure(&image).is_ok());
        }
    }
}

/// A tool names a refused configuration from the cause byte of its EMCY: every reason comes
/// back from its code, no two share a code or a sentence, and code 11 (retired) names none.
#[test]
fn every_refusal_reason_is_found_by_its_emcy_cause_code_and_has_its_own_words() {
    let mut codes = std::collections::BTreeSet::new();
    let mut words = std::collections::BTreeSet::new();
    for error in ConfigError::ALL {
        assert_eq!(
            ConfigError::from_cause_code(error.cause_code()),
            Some(error)
        );
        assert!(codes.insert(error.cause_code()), "{error:?}: code shared");
        assert!(words.insert(error.describe()), "{error:?}: words shared");
        assert_eq!(std::format!("{error}"), error.describe());
    }
    assert_eq!(ConfigError::from_cause_code(11), None);
    assert_eq!(ConfigError::from_cause_code(0), None);
    assert_eq!(ConfigError::from_cause_code(25), None);
}
