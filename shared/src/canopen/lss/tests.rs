//! Tests of the LSS slave (CiA 305), each naming the figure or the safety rule it verifies.

use super::*;
use crate::canopen::storage::StorageError;
use std::vec::Vec;

const IDENTITY: [u32; 4] = [0x0000_0ABC, 0x0000_0304, 0x0001_0002, 0x8000_0042];
const RATES: BitRates = BitRates::of(&[BitRate::Kbit500, BitRate::Kbit250, BitRate::Kbit125]);

fn id(raw: u8) -> NodeId {
    NodeId::new(raw).unwrap()
}

fn unconfigured() -> Lss {
    Lss::new(IDENTITY, None, None, RATES)
}

fn configured(raw: u8) -> Lss {
    let stored = LssSettings {
        node_id: Some(id(raw)),
        bit_rate: None,
    };
    Lss::new(IDENTITY, None, Some(stored), RATES)
}

fn request(data: [u8; 8]) -> CanFrame {
    CanFrame::new(MASTER_TO_SLAVE, &data).unwrap()
}

/// A request carrying a 32-bit value in bytes 1..=4.
fn with_value(command: u8, value: u32) -> CanFrame {
    let [a, b, c, d] = value.to_le_bytes();
    request([command, a, b, c, d, 0, 0, 0])
}

fn fastscan(value: u32, bit_check: u8, sub: u8, next: u8) -> CanFrame {
    let [a, b, c, d] = value.to_le_bytes();
    request([specifier::FASTSCAN, a, b, c, d, bit_check, sub, next])
}

/// Handles `frame` outside Operational with a store that succeeds.
fn send(lss: &mut Lss, frame: CanFrame) -> LssOutcome {
    lss.on_frame(Instant::ZERO, &frame, false, |_| Ok(()))
}

fn answer(outcome: LssOutcome) -> Option<[u8; 8]> {
    outcome.response.map(|frame| {
        assert_eq!(frame.id(), SLAVE_TO_MASTER);
        <[u8; 8]>::try_from(frame.data()).unwrap()
    })
}

fn to_configuration(lss: &mut Lss) {
    send(
        lss,
        request([specifier::SWITCH_GLOBAL, 1, 0, 0, 0, 0, 0, 0]),
    );
    assert_eq!(lss.state(), LssState::Configuration);
}

fn selective(lss: &mut Lss, identity: [u32; 4], operational: bool) -> Vec<LssOutcome> {
    (0..4u8)
        .map(|part| {
            let frame = with_value(
                specifier::SWITCH_SELECTIVE_VENDOR + part,
                identity[usize::from(part)],
            );
            lss.on_frame(Instant::ZERO, &frame, operational, |_| Ok(()))
        })
        .collect()
}

#[test]
fn cia305_a_frame_not_8_bytes_long_or_remote_is_ignored() {
    for len in 0..8 {
        let mut lss = unconfigured();
        let data = [specifier::SWITCH_GLOBAL, 1, 0, 0, 0, 0, 0, 0];
        let frame = CanFrame::new(MASTER_TO_SLAVE, &data[..len]).unwrap();
        assert_eq!(send(&mut lss, frame), LssOutcome::default(), "{len} bytes");
        assert_eq!(lss.state(), LssState::Waiting);
        // Nor does a short fastscan or inquiry get an answer.
        let scan = fastscan(0, FASTSCAN_CONFIRM, 0, 0);
        let short = CanFrame::new(MASTER_TO_SLAVE, &scan.data()[..len]).unwrap();
        assert_eq!(send(&mut lss, short), LssOutcome::default(), "{len} bytes");
    }
    let mut lss = unconfigured();
    let remote = CanFrame::remote(MASTER_TO_SLAVE, 8).unwrap();
    assert_eq!(send(&mut lss, remote), LssOutcome::default());
    // A frame on another identifier is not the slave's.
    let other = CanFrame::new(
        SLAVE_TO_MASTER,
        &[specifier::FASTSCAN, 0, 0, 0, 0, 0x80, 0, 0],
    );
    assert_eq!(send(&mut lss, other.unwrap()), LssOutcome::default());
}

#[test]
fn cia305_an_unknown_specifier_gets_no_answer_in_either_state() {
    let known = [
        0x04, 0x11, 0x13, 0x15, 0x17, 0x40, 0x41, 0x42, 0x43, 0x46, 0x47, 0x48, 0x49, 0x4A, 0x4B,
        0x4C, 0x51, 0x5A, 0x5B, 0x5C, 0x5D, 0x5E,
    ];
    for configuration in [false, true] {
        for command in (0..=255u8).filter(|command| !known.contains(command)) {
            let mut lss = unconfigured();
            if configuration {
                to_configuration(&mut lss);
            }
            let before = lss.clone();
            let outcome = send(&mut lss, request([command, 1, 2, 3, 4, 5, 6, 7]));
            assert_eq!(outcome, LssOutcome::default(), "{command:02X}h");
            assert_eq!(lss.state(), before.state());
            assert_eq!(lss.pending(), before.pending());
        }
    }
}

#[test]
fn cia305_fig31_switch_state_global_enters_and_leaves_the_configuration_state() {
    let mut lss = configured(5);
    let outcome = send(
        &mut lss,
        request([specifier::SWITCH_GLOBAL, 1, 0, 0, 0, 0, 0, 0]),
    );
    assert_eq!(
        outcome.response, None,
        "switch state global is not answered"
    );
    assert_eq!(outcome.event, Some(LssEvent::ConfigurationEntered));
    assert_eq!(lss.state(), LssState::Configuration);
    // A mode other than 0 and 1 changes nothing.
    send(
        &mut lss,
        request([specifier::SWITCH_GLOBAL, 2, 0, 0, 0, 0, 0, 0]),
    );
    assert_eq!(lss.state(), LssState::Configuration);
    let outcome = send(
        &mut lss,
        request([specifier::SWITCH_GLOBAL, 0, 0, 0, 0, 0, 0, 0]),
    );
    assert_eq!(outcome.event, Some(LssEvent::WaitingEntered));
    assert!(
        !outcome.reset_communication,
        "a configured node waits for NMT"
    );
    assert_eq!(lss.state(), LssState::Waiting);
}

#[test]
fn cia305_fig32_selective_switch_answers_44h_after_the_whole_identity() {
    let mut lss = configured(5);
    let outcomes = selective(&mut lss, IDENTITY, false);
    assert!(outcomes[..3].iter().all(|o| *o == LssOutcome::default()));
    assert_eq!(answer(outcomes[3]), Some([0x44, 0, 0, 0, 0, 0, 0, 0]));
    assert_eq!(outcomes[3].event, Some(LssEvent::ConfigurationEntered));
    assert_eq!(lss.state(), LssState::Configuration);
}

#[test]
fn cia305_fig32_selective_switch_with_a_partial_match_answers_nothing() {
    for wrong in 0..4 {
        let mut other = IDENTITY;
        other[wrong] ^= 1;
        let mut lss = configured(5);
        let outcomes = selective(&mut lss, other, false);
        assert!(
            outcomes.iter().all(|o| *o == LssOutcome::default()),
            "part {wrong} differs"
        );
        assert_eq!(lss.state(), LssState::Waiting);
        // The sequence starts over: the serial number alone does not complete it.
        let outcome = send(&mut lss, with_value(0x43, IDENTITY[3]));
        assert_eq!(outcome, LssOutcome::default());
    }
    // Out of order: product before vendor.
    let mut lss = configured(5);
    for (command, value) in [
        (0x41, IDENTITY[1]),
        (0x40, IDENTITY[0]),
        (0x42, IDENTITY[2]),
    ] {
        send(&mut lss, with_value(command, value));
    }
    assert_eq!(
        send(&mut lss, with_value(0x43, IDENTITY[3])),
        LssOutcome::default()
    );
    assert_eq!(lss.state(), LssState::Waiting);
}

#[test]
fn cia305_configuration_services_are_ignored_in_the_waiting_state() {
    let mut lss = configured(5);
    for command in [0x11, 0x13, 0x15, 0x17, 0x5A, 0x5B, 0x5C, 0x5D, 0x5E] {
        let outcome = send(&mut lss, request([command, 9, 0, 0, 0, 0, 0, 0]));
        assert_eq!(outcome, LssOutcome::default(), "{command:02X}h");
    }
    assert_eq!(lss.pending(), Some(id(5)));
    assert_eq!(lss.bit_rate(), None);
}

#[test]
fn cia305_fig33_configure_node_id_accepts_1_to_127_and_ffh() {
    let mut lss = configured(5);
    to_configuration(&mut lss);
    for raw in [1u8, 64, 127] {
        let outcome = send(&mut lss, request([0x11, raw, 0, 0, 0, 0, 0, 0]));
        assert_eq!(answer(outcome), Some([0x11, OK, 0, 0, 0, 0, 0, 0]));
        assert_eq!(outcome.event, Some(LssEvent::NodeIdPending(Some(id(raw)))));
        assert_eq!(lss.pending(), Some(id(raw)));
    }
    let outcome = send(&mut lss, request([0x11, 0xFF, 0, 0, 0, 0, 0, 0]));
    assert_eq!(answer(outcome), Some([0x11, OK, 0, 0, 0, 0, 0, 0]));
    assert_eq!(lss.pending(), None);
}

#[test]
fn cia305_fig33_configure_node_id_0_and_80h_to_feh_get_error_1_and_change_nothing() {
    let mut lss = configured(5);
    to_configuration(&mut lss);
    for raw in core::iter::once(0u8).chain(0x80..=0xFE) {
        let outcome = send(&mut lss, request([0x11, raw, 0, 0, 0, 0, 0, 0]));
        assert_eq!(
            answer(outcome),
            Some([0x11, REFUSED, 0, 0, 0, 0, 0, 0]),
            "{raw}"
        );
        assert_eq!(
            outcome.event,
            Some(LssEvent::NodeIdRefused {
                requested: raw,
                switches: false
            })
        );
        assert_eq!(lss.pending(), Some(id(5)), "{raw}");
        assert_eq!(lss.active(), Some(id(5)));
    }
}

#[test]
fn cia305_fig34_configure_bit_timing_takes_a_supported_rate_of_the_cia301_table() {
    let mut lss = configured(5);
    to_configuration(&mut lss);
    let outcome = send(&mut lss, request([0x13, 0, 3, 0, 0, 0, 0, 0]));
    assert_eq!(answer(outcome), Some([0x13, OK, 0, 0, 0, 0, 0, 0]));
    assert_eq!(lss.bit_rate(), Some(BitRate::Kbit250));
    assert_eq!(
        outcome.event,
        Some(LssEvent::BitRatePending(BitRate::Kbit250))
    );
}

#[test]
fn cia305_fig34_bit_timing_outside_the_table_or_not_supported_gets_error_1() {
    let mut lss = configured(5);
    to_configuration(&mut lss);
    send(&mut lss, request([0x13, 0, 2, 0, 0, 0, 0, 0]));
    // Another table, the reserved index 5, indices past the table, rates this board cannot.
    let refused = [
        (1u8, 2u8),
        (0xFF, 2),
        (0, 5),
        (0, 10),
        (0, 0xFF),
        (0, 0),
        (0, 9),
    ];
    for (selector, index) in refused {
        let outcome = send(&mut lss, request([0x13, selector, index, 0, 0, 0, 0, 0]));
        assert_eq!(answer(outcome), Some([0x13, REFUSED, 0, 0, 0, 0, 0, 0]));
        assert_eq!(
            outcome.event,
            Some(LssEvent::BitRateRefused { selector, index })
        );
        assert_eq!(lss.bit_rate(), Some(BitRate::Kbit500), "unchanged");
    }
}

/// CiA 305 makes only a supported bit rate pending; a stored one this board does not
/// support (stored by an image with other rates) is not taken either: the board starts at
/// its own rate, the node says why at start and at every reset, activate bit timing has
/// nothing to switch to, and the next store configuration replaces the stored rate.
#[test]
fn cia305_fig34_a_stored_bit_rate_the_board_does_not_support_is_not_taken() {
    let stored = LssSettings {
        node_id: Some(id(5)),
        bit_rate: Some(BitRate::Kbit50),
    };
    let mut lss = Lss::new(IDENTITY, None, Some(stored), RATES);
    assert_eq!(lss.bit_rate(), None, "the board's own rate");
    assert_eq!(lss.active(), Some(id(5)), "the node-ID is still taken");
    assert_eq!(
        lss.start_events(),
        [
            None,
            Some(LssEvent::StoredBitRateUnsupported(BitRate::Kbit50))
        ]
    );
    to_configuration(&mut lss);
    let outcome = send(&mut lss, request([0x15, 100, 0, 0, 0, 0, 0, 0]));
    assert_eq!(outcome, LssOutcome::default());
    assert_eq!(lss.deadline(), Instant::NEVER, "no switch started");
    assert_eq!(lss.reset_communication(), Some(id(5)));
    assert_eq!(
        lss.start_events()[1],
        Some(LssEvent::StoredBitRateUnsupported(BitRate::Kbit50)),
        "still stored, still reported"
    );
    to_configuration(&mut lss);
    let outcome = lss.on_frame(
        Instant::ZERO,
        &request([0x17, 0, 0, 0, 0, 0, 0, 0]),
        false,
        |settings| {
            assert_eq!(
                settings.bit_rate, None,
                "the unsupported rate is not stored again"
            );
            Ok(())
        },
    );
    assert_eq!(answer(outcome), Some([0x17, OK, 0, 0, 0, 0, 0, 0]));
    assert_eq!(lss.start_events(), [None, None]);
    // A supported stored rate is taken as before.
    let stored = LssSettings {
        node_id: Some(id(5)),
        bit_rate: Some(BitRate::Kbit125),
    };
    let lss = Lss::new(IDENTITY, None, Some(stored), RATES);
    assert_eq!(lss.bit_rate(), Some(BitRate::Kbit125));
    assert_eq!(lss.start_events(), [None, None]);
}

#[test]
fn cia305_bit_timing_table_indices_round_trip() {
    for rate in BitRate::ALL {
        assert_eq!(BitRate::from_index(rate.index()), Some(rate));
        if let Some(bits) = rate.bits_per_second() {
            assert_eq!(BitRate::from_bits_per_second(bits), Some(rate));
        }
    }
    assert_eq!(BitRate::from_index(5), None);
    assert_eq!(BitRate::from_bits_per_second(100_000), None);
    assert_eq!(BitRate::Kbit10.index(), 8);
}

#[test]
fn cia305_fig36_store_configuration_answers_0_1_or_2() {
    let mut lss = configured(5);
    to_configuration(&mut lss);
    send(&mut lss, request([0x11, 9, 0, 0, 0, 0, 0, 0]));
    send(&mut lss, request([0x13, 0, 4, 0, 0, 0, 0, 0]));
    let mut stored = None;
    let outcome = lss.on_frame(
        Instant::ZERO,
        &request([0x17, 0, 0, 0, 0, 0, 0, 0]),
        false,
        |s| {
            stored = Some(s);
            Ok(())
        },
    );
    let expected = LssSettings {
        node_id: Some(id(9)),
        bit_rate: Some(BitRate::Kbit125),
    };
    assert_eq!(stored, Some(expected), "the pending values are stored");
    assert_eq!(answer(outcome), Some([0x17, OK, 0, 0, 0, 0, 0, 0]));
    assert_eq!(outcome.event, Some(LssEvent::Stored(expected)));
    let store = request([0x17, 0, 0, 0, 0, 0, 0, 0]);
    let outcome = lss.on_frame(Instant::ZERO, &store, false, |_| {
        Err(StoreFailure::NotSupported)
    });
    assert_eq!(answer(outcome), Some([0x17, REFUSED, 0, 0, 0, 0, 0, 0]));
    let failed = StoreFailure::Failed(StorageError::VerifyFailed);
    let outcome = lss.on_frame(Instant::ZERO, &store, false, |_| Err(failed));
    assert_eq!(
        answer(outcome),
        Some([0x17, STORE_FAILED, 0, 0, 0, 0, 0, 0])
    );
    assert_eq!(outcome.event, Some(LssEvent::StoreFailed(failed)));
}

#[test]
fn cia305_fig37_to_41_inquire_identity_and_the_active_node_id() {
    let mut lss = configured(5);
    to_configuration(&mut lss);
    for (part, command) in (0x5A..=0x5D).enumerate() {
        let outcome = send(&mut lss, request([command, 0, 0, 0, 0, 0, 0, 0]));
        let [a, b, c, d] = IDENTITY[part].to_le_bytes();
        assert_eq!(answer(outcome), Some([command, a, b, c, d, 0, 0, 0]));
    }
    send(&mut lss, request([0x11, 9, 0, 0, 0, 0, 0, 0]));
    let outcome = send(&mut lss, request([0x5E, 0, 0, 0, 0, 0, 0, 0]));
    assert_eq!(answer(outcome), Some([0x5E, 5, 0, 0, 0, 0, 0, 0]), "active");
    let mut lss = unconfigured();
    to_configuration(&mut lss);
    let outcome = send(&mut lss, request([0x5E, 0, 0, 0, 0, 0, 0, 0]));
    assert_eq!(answer(outcome), Some([0x5E, 0xFF, 0, 0, 0, 0, 0, 0]));
}

/// The six requests of identify remote slave for the ranges given.
fn identify(lss: &mut Lss, revision: (u32, u32), serial: (u32, u32)) -> Option<[u8; 8]> {
    let parts = [
        (0x46, IDENTITY[0]),
        (0x47, IDENTITY[1]),
        (0x48, revision.0),
        (0x49, revision.1),
        (0x4A, serial.0),
        (0x4B, serial.1),
    ];
    let mut last = None;
    for (command, value) in parts {
        last = answer(send(lss, with_value(command, value)));
    }
    last
}

#[test]
fn cia305_fig42_identify_remote_slave_answers_4fh_inside_the_ranges() {
    let [_, _, revision, serial] = IDENTITY;
    let found = Some([0x4F, 0, 0, 0, 0, 0, 0, 0]);
    let mut lss = configured(5);
    assert_eq!(
        identify(&mut lss, (revision, revision), (serial, serial)),
        found
    );
    assert_eq!(identify(&mut lss, (0, u32::MAX), (serial, u32::MAX)), found);
    to_configuration(&mut lss);
    assert_eq!(
        identify(&mut lss, (0, revision), (0, serial)),
        found,
        "both states"
    );
    assert_eq!(
        identify(&mut lss, (revision + 1, u32::MAX), (0, u32::MAX)),
        None
    );
    assert_eq!(identify(&mut lss, (0, revision - 1), (0, u32::MAX)), None);
    assert_eq!(
        identify(&mut lss, (0, u32::MAX), (serial + 1, u32::MAX)),
        None
    );
    assert_eq!(identify(&mut lss, (0, u32::MAX), (0, serial - 1)), None);
    // Another vendor.
    send(&mut lss, with_value(0x46, IDENTITY[0] + 1));
    for (command, value) in [(0x47, IDENTITY[1]), (0x48, 0), (0x49, u32::MAX), (0x4A, 0)] {
        send(&mut lss, with_value(command, value));
    }
    assert_eq!(answer(send(&mut lss, with_value(0x4B, u32::MAX))), None);
}

#[test]
fn cia305_fig44_only_an_unconfigured_node_answers_identify_non_configured() {
    let ask = request([0x4C, 0, 0, 0, 0, 0, 0, 0]);
    let mut lss = unconfigured();
    assert_eq!(
        answer(send(&mut lss, ask)),
        Some([0x50, 0, 0, 0, 0, 0, 0, 0])
    );
    assert_eq!(answer(send(&mut configured(5), ask)), None);
    // A node-ID pending is enough to count as configured (CANopenNode, lely-core).
    to_configuration(&mut lss);
    send(&mut lss, request([0x11, 7, 0, 0, 0, 0, 0, 0]));
    assert_eq!(answer(send(&mut lss, ask)), None);
}

/// The fastscan master of CANopenNode (`CO_LSSmaster_IdentifyFastscan`) over one slave:
/// the identity it finds, and the number of requests.
fn scan(lss: &mut Lss) -> Option<([u32; 4], usize)> {
    let mut requests = 1;
    answer(send(lss, fastscan(0, FASTSCAN_CONFIRM, 0, 0)))?;
    let mut found = [0u32; 4];
    for sub in 0..4u8 {
        for bit in (0..32u8).rev() {
            requests += 1;
            if answer(send(lss, fastscan(found[usize::from(sub)], bit, sub, sub))).is_none() {
                found[usize::from(sub)] |= 1 << bit;
            }
        }
        requests += 1;
        let next = (sub + 1) % 4;
        answer(send(lss, fastscan(found[usize::from(sub)], 0, sub, next)))?;
    }
    Some((found, requests))
}

#[test]
fn cia305_fig46_fastscan_finds_the_identity_and_selects_the_node() {
    let mut lss = unconfigured();
    let (found, requests) = scan(&mut lss).unwrap();
    assert_eq!(found, IDENTITY);
    assert_eq!(requests, 1 + 4 * 33);
    assert_eq!(lss.state(), LssState::Configuration);
    // Selected, it takes a node-ID and, switched back to waiting, resets its communication
    // to take it (CiA 305: it was unconfigured).
    send(&mut lss, request([0x11, 12, 0, 0, 0, 0, 0, 0]));
    let outcome = send(&mut lss, request([0x04, 0, 0, 0, 0, 0, 0, 0]));
    assert!(outcome.reset_communication);
    assert_eq!(lss.reset_communication(), Some(id(12)));
    // Configured now: it takes no part in fastscan any more.
    assert_eq!(
        answer(send(&mut lss, fastscan(0, FASTSCAN_CONFIRM, 0, 0))),
        None
    );
}

#[test]
fn cia305_fig46_fastscan_requests_out_of_range_or_for_another_part_are_ignored() {
    let mut lss = unconfigured();
    send(&mut lss, fastscan(0, FASTSCAN_CONFIRM, 0, 0));
    for (bit_check, sub, next) in [
        (32, 0, 0),
        (0x7F, 0, 0),
        (0x81, 0, 0),
        (31, 4, 0),
        (31, 0, 4),
    ] {
        let outcome = send(&mut lss, fastscan(0, bit_check, sub, next));
        assert_eq!(outcome, LssOutcome::default(), "{bit_check} {sub} {next}");
    }
    // The scan is at the vendor-ID: a request about the product code is not answered.
    assert_eq!(answer(send(&mut lss, fastscan(IDENTITY[1], 0, 1, 2))), None);
    // A configured node ignores fastscan, bit check 80h included.
    assert_eq!(
        answer(send(&mut configured(5), fastscan(0, 0x80, 0, 0))),
        None
    );
}

/// Safety rule 1: a node in NMT Operational enters no configuration state, answers no
/// selective switch, and reports each refusal.
#[test]
fn cia305_fig31_fig32_fig46_rule_1_no_configuration_state_in_operational() {
    let mut lss = configured(5);
    let outcome = lss.on_frame(
        Instant::ZERO,
        &request([0x04, 1, 0, 0, 0, 0, 0, 0]),
        true,
        |_| Ok(()),
    );
    assert_eq!(
        outcome,
        LssOutcome::event(LssEvent::RefusedInOperational { specifier: 0x04 })
    );
    assert_eq!(lss.state(), LssState::Waiting);
    let outcomes = selective(&mut lss, IDENTITY, true);
    assert_eq!(outcomes[3].response, None);
    assert_eq!(
        outcomes[3].event,
        Some(LssEvent::RefusedInOperational { specifier: 0x43 })
    );
    assert_eq!(lss.state(), LssState::Waiting);
    // So no configuring service gets through.
    let outcome = lss.on_frame(
        Instant::ZERO,
        &request([0x11, 9, 0, 0, 0, 0, 0, 0]),
        true,
        |_| Ok(()),
    );
    assert_eq!(outcome, LssOutcome::default());
    assert_eq!(lss.pending(), Some(id(5)));
    // Entering Operational leaves the configuration state.
    to_configuration(&mut lss);
    assert_eq!(
        lss.leave_configuration(),
        Some(LssEvent::ConfigurationLeftForOperational)
    );
    assert_eq!(lss.state(), LssState::Waiting);
    assert_eq!(lss.leave_configuration(), None);
}

/// Safety rule 2: a configured node-ID is pending until NMT reset communication.
#[test]
fn cia305_fig33_rule_2_a_configured_node_id_waits_for_reset_communication() {
    let mut lss = configured(5);
    to_configuration(&mut lss);
    send(&mut lss, request([0x11, 9, 0, 0, 0, 0, 0, 0]));
    let outcome = send(&mut lss, request([0x04, 0, 0, 0, 0, 0, 0, 0]));
    assert!(
        !outcome.reset_communication,
        "a configured node is not reset by LSS"
    );
    assert_eq!(lss.active(), Some(id(5)));
    assert_eq!(lss.pending(), Some(id(9)));
    assert_eq!(lss.reset_communication(), Some(id(9)));
    assert_eq!(lss.active(), Some(id(9)));
    // FFh pending makes the node unconfigured at the reset.
    to_configuration(&mut lss);
    send(&mut lss, request([0x11, 0xFF, 0, 0, 0, 0, 0, 0]));
    assert_eq!(lss.active(), Some(id(9)));
    assert_eq!(lss.reset_communication(), None);
    assert_eq!(lss.source(), NodeIdSource::Unconfigured);
    assert_eq!(lss.start_events(), [Some(LssEvent::Unconfigured), None]);
}

/// Safety rule 3: the switches win over a stored LSS node-ID, configure node-ID is refused
/// while they are set, and all switches open means the LSS node-ID (or none).
#[test]
fn cia305_fig33_rule_3_the_switches_win_over_an_lss_node_id() {
    let stored = LssSettings {
        node_id: Some(id(40)),
        bit_rate: None,
    };
    let mut lss = Lss::new(IDENTITY, Some(id(3)), Some(stored), RATES);
    assert_eq!(lss.active(), Some(id(3)));
    assert_eq!(lss.source(), NodeIdSource::Switches);
    assert_eq!(
        lss.start_events(),
        [
            Some(LssEvent::SwitchesWin {
                switches: id(3),
                stored: Some(id(40))
            }),
            None
        ]
    );
    to_configuration(&mut lss);
    let outcome = send(&mut lss, request([0x11, 9, 0, 0, 0, 0, 0, 0]));
    assert_eq!(
        answer(outcome),
        Some([0x11, MANUFACTURER_SPECIFIC, SWITCHES_SET, 0, 0, 0, 0, 0])
    );
    assert_eq!(lss.reset_communication(), Some(id(3)));
    // Open switches: the stored LSS node-ID; nothing stored: unconfigured.
    assert_eq!(
        Lss::new(IDENTITY, None, Some(stored), RATES).active(),
        Some(id(40))
    );
    assert_eq!(
        Lss::new(IDENTITY, None, Some(stored), RATES).source(),
        NodeIdSource::Lss
    );
    assert_eq!(Lss::new(IDENTITY, None, None, RATES).active(), None);
    // Switches equal to the stored node-ID: nothing to report.
    assert_eq!(
        Lss::new(IDENTITY, Some(id(40)), Some(stored), RATES).start_events(),
        [None, None]
    );
    // The unconfigured node with switches set is not unconfigured: no fastscan answer.
    let mut switched = Lss::new(IDENTITY, Some(id(3)), None, RATES);
    assert_eq!(answer(send(&mut switched, fastscan(0, 0x80, 0, 0))), None);
}

/// Safety rule 4: activate bit timing silences the node for the switch delay, reports the
/// new bit rate, then keeps it silent for the delay again.
#[test]
fn cia305_fig35_rule_4_activate_bit_timing_is_silent_around_the_switch() {
    let mut lss = configured(5);
    to_configuration(&mut lss);
    send(&mut lss, request([0x13, 0, 3, 0, 0, 0, 0, 0]));
    let start = Instant::from_millis(100);
    let delay = 250u16.to_le_bytes();
    let outcome = lss.on_frame(
        start,
        &request([0x15, delay[0], delay[1], 0, 0, 0, 0, 0]),
        false,
        |_| Ok(()),
    );
    assert_eq!(outcome, LssOutcome::default(), "activate is not answered");
    assert!(lss.muted(start));
    assert_eq!(lss.deadline(), Instant::from_millis(350));
    assert_eq!(lss.poll(Instant::from_millis(349)), None);
    // Requests during the silence get no answer.
    let inquiry = lss.on_frame(
        Instant::from_millis(200),
        &request([0x5E, 0, 0, 0, 0, 0, 0, 0]),
        false,
        |_| Ok(()),
    );
    assert_eq!(inquiry, LssOutcome::default());
    assert_eq!(
        lss.poll(Instant::from_millis(350)),
        Some(LssEvent::SwitchBitRate(BitRate::Kbit250))
    );
    assert!(lss.muted(Instant::from_millis(599)));
    assert_eq!(lss.deadline(), Instant::from_millis(600));
    assert_eq!(lss.poll(Instant::from_millis(600)), None);
    assert!(!lss.muted(Instant::from_millis(600)));
    assert_eq!(lss.deadline(), Instant::NEVER);
    let inquiry = send(&mut lss, request([0x5E, 0, 0, 0, 0, 0, 0, 0]));
    assert_eq!(answer(inquiry), Some([0x5E, 5, 0, 0, 0, 0, 0, 0]));
}

#[test]
fn cia305_fig36_lss_settings_round_trip_and_refuse_other_bytes() {
    for node_id in [None, Some(id(1)), Some(id(127))] {
        for bit_rate in core::iter::once(None).chain(BitRate::ALL.map(Some)) {
            let settings = LssSettings { node_id, bit_rate };
            assert_eq!(LssSettings::decode(settings.encode()), Some(settings));
        }
    }
    for bad in [
        [0, 0xFF],
        [0x80, 0xFF],
        [0xFE, 0xFF],
        [1, 5],
        [1, 10],
        [1, 0xFE],
    ] {
        assert_eq!(LssSettings::decode(bad), None, "{bad:?}");
    }
}

/// In the configuration state too, a configuring request that is not 8 bytes long is not
/// answered and applies nothing: no node-ID, no bit rate, no store, no switch.
#[test]
fn cia305_a_configuring_request_of_the_wrong_length_applies_nothing() {
    let requests = [
        [specifier::CONFIGURE_NODE_ID, 9, 0, 0, 0, 0, 0, 0],
        [specifier::CONFIGURE_BIT_TIMING, 0, 3, 0, 0, 0, 0, 0],
        [specifier::ACTIVATE_BIT_TIMING, 10, 0, 0, 0, 0, 0, 0],
        [specifier::STORE_CONFIGURATION, 0, 0, 0, 0, 0, 0, 0],
        [specifier::INQUIRE_NODE_ID, 0, 0, 0, 0, 0, 0, 0],
        [specifier::SWITCH_GLOBAL, 0, 0, 0, 0, 0, 0, 0],
    ];
    for data in requests {
        for len in 0..8 {
            let mut lss = configured(5);
            to_configuration(&mut lss);
            let frame = CanFrame::new(MASTER_TO_SLAVE, &data[..len]).unwrap();
            let mut stored = false;
            let outcome = lss.on_frame(Instant::ZERO, &frame, false, |_| {
                stored = true;
                Ok(())
            });
            let what = format!("{:02X}h, {len} bytes", data[0]);
            assert_eq!(outcome, LssOutcome::default(), "{what}");
            assert!(!stored, "{what}");
            assert_eq!(lss.state(), LssState::Configuration, "{what}");
            assert_eq!(lss.pending(), Some(id(5)), "{what}");
            assert_eq!(lss.bit_rate(), None, "{what}");
            assert_eq!(lss.deadline(), Instant::NEVER, "{what}: no switch started");
        }
    }
}

/// Every request with a refused value (node-ID 0 or 80h..FEh, a bit timing outside the table
/// or not supported) leaves the whole slave as it was: what a refused request changes is
/// nothing but its answer.
#[test]
fn cia305_fig33_fig34_a_refused_value_leaves_the_whole_slave_unchanged() {
    let mut refused = Vec::new();
    for raw in core::iter::once(0u8).chain(0x80..=0xFE) {
        refused.push([specifier::CONFIGURE_NODE_ID, raw, 0, 0, 0, 0, 0, 0]);
    }
    for selector in 0..=255u8 {
        for index in 0..=255u8 {
            let supported = selector == 0
                && BitRate::from_index(index).is_some_and(|rate| RATES.contains(rate));
            if !supported {
                refused.push([
                    specifier::CONFIGURE_BIT_TIMING,
                    selector,
                    index,
                    0,
                    0,
                    0,
                    0,
                    0,
                ]);
            }
        }
    }
    let mut lss = configured(5);
    to_configuration(&mut lss);
    send(&mut lss, request([0x13, 0, 2, 0, 0, 0, 0, 0]));
    let before = lss.clone();
    for data in refused {
        let outcome = send(&mut lss, request(data));
        assert_eq!(answer(outcome).map(|a| a[1]), Some(REFUSED), "{data:02X?}");
        assert_eq!(lss, before, "{data:02X?}");
    }
}
