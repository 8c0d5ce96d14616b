//! Bit flips in Operational, in every derived table and every record: each one puts the node
//! in its safe state within one check period, with EMCY 6300h and an event naming it. The
//! flips are made directly in the node's memory from this test module (no hook exists in a
//! production build).

use super::*;
use crate::canopen::emcy::{self, Emergency};
use crate::canopen::nmt::{self, NmtCommand, NmtState};
use crate::canopen::storage::RamFlash;
use crate::frame::{CanFrame, CanId};
use crate::node::tests::{Recorder, config};
use crate::node::{Event, Node};
use crate::safety::config::{ConfigError, SafetyConfig};
use crate::safety::{signature, srdo};

type TestNode = Node<RamFlash<8192>, 4>;

/// When the flips happen: well inside the first SCT (50 ms), off every period boundary.
const FLIP_AT: Instant = Instant::from_micros(7_300);
/// The producer's refresh time, the shortest cycle time of the two SRDOs.
const REFRESH_MS: u16 = 20;

/// Node 33 in Operational with SRDO 1 consuming (the pre-defined set: 0x141/0x142, SCT 50 ms)
/// and SRDO 2 producing (0x103/0x104, refresh time 20 ms); SRDOs 3 and 4 do not exist.
fn operational() -> (TestNode, Recorder) {
    let mut node = TestNode::new(config(33), RamFlash::new()).unwrap();
    let mut sink = Recorder::default();
    node.poll(Instant::ZERO, &mut sink);
    // The producer's halves: 0x6000.1 plain, 0x6001.1 its inverse.
    node.write_object(crate::canopen::od::Address::new(0x6001, 1), &[0xFF])
        .unwrap();
    let safety = &mut node.core.protocol.safety;
    let producer = &mut safety.srdos[1];
    producer.direction = 1;
    producer.cycle_time = REFRESH_MS;
    producer.srvt = 1;
    producer.cob_id_1 = 0x103;
    producer.cob_id_2 = 0x104;
    producer.mapping_count = 2;
    producer.mapping[..2].copy_from_slice(&[0x6000_0108, 0x6001_0108]);
    for record in safety.srdos.iter_mut() {
        record.signature = signature::compute(record);
    }
    safety.configuration_valid = 0xA5;
    node.handle_frame(
        Instant::ZERO,
        &nmt::command_frame(NmtCommand::Start, 0),
        &mut sink,
    );
    assert!(node.is_working());
    sink.frames.clear();
    sink.events.clear();
    (node, sink)
}

/// Polls `node` from [`FLIP_AT`] at the deadlines it reports until it latches; the latch must
/// come no later than one check period after the flip, and every deadline on the way must be
/// within that bound too (the executor sleeps until the reported deadline). Returns the cause:
/// the integrity check's finding, or the SRDO fault by which a producer found its own damaged
/// mapping or role first (the producer checks its halves before every transmission).
fn safe_within_one_period(node: &mut TestNode, sink: &mut Recorder, what: &str) -> IntegrityFault {
    let bound = FLIP_AT + Duration::from_millis(u64::from(REFRESH_MS));
    let mut now = FLIP_AT;
    loop {
        let next = node.poll(now, sink);
        if let Some(cause) = node.fault() {
            let (fault, code, detail) = match cause {
                SafeStateCause::Integrity(fault) => {
                    (fault, emcy::code::DATA_SET, fault.emergency_detail())
                }
                SafeStateCause::Srdo(srdo::SrdoFault {
                    srdo,
                    cause: cause @ srdo::SrdoFaultCause::TransmitHalvesNotInverted,
                }) => (
                    IntegrityFault::Runtime(srdo),
                    cause.emergency_code(),
                    [srdo.get(), cause.cause_code(), 0, 0, 0],
                ),
                other => panic!("{what}: latched for {other:?}"),
            };
            assert!(
                now <= bound,
                "{what}: latched at {now:?}, later than {bound:?}"
            );
            assert!(!node.is_working(), "{what}");
            assert!(
                sink.events.contains(&Event::SafeState(cause)),
                "{what}: no event"
            );
            let emergencies: std::vec::Vec<Emergency> = sink.emergencies();
            assert_eq!(emergencies.len(), 1, "{what}");
            assert_eq!(emergencies[0].code, code, "{what}");
            assert_eq!(emergencies[0].detail, detail, "{what}");
            // Received values are cleared and the producer stops (SC_REQ_05).
            let frames = sink.frames.len();
            node.poll(bound + Duration::from_millis(100), sink);
            let sent_after: std::vec::Vec<_> = sink.frames[frames..]
                .iter()
                .filter(|f| f.id().raw() == 0x103 || f.id().raw() == 0x104)
                .collect();
            assert!(sent_after.is_empty(), "{what}: the producer kept sending");
            return fault;
        }
        assert!(
            next <= bound,
            "{what}: next poll at {next:?}, past {bound:?}"
        );
        assert!(next > now, "{what}: no progress at {now:?}");
        now = next;
    }
}

/// Runs `flip` on a fresh Operational node at [`FLIP_AT`] and returns what the check found.
fn flipped(what: &str, flip: impl FnOnce(&mut SrdoTable<4>)) -> IntegrityFault {
    let (mut node, mut sink) = operational();
    // Up to the flip, everything is in order.
    let mut now = Instant::ZERO;
    while now < FLIP_AT {
        now = node.poll(now, &mut sink).min(FLIP_AT);
    }
    assert!(node.is_working(), "{what}: not working before the flip");
    sink.frames.clear();
    sink.events.clear();
    flip(&mut node.core.protocol);
    safe_within_one_period(&mut node, &mut sink, what)
}

#[test]
fn en50325_5_7_1_2_the_check_runs_at_the_shortest_cycle_time_and_never_fires_on_a_sound_node() {
    let (mut node, mut sink) = operational();
    assert_eq!(
        node.core.protocol.integrity.period(),
        Duration::from_millis(u64::from(REFRESH_MS))
    );
    // Ten seconds of valid pairs every 10 ms: the check runs 500 times and finds nothing.
    let mut now = Instant::ZERO;
    for step in 1..=1000u64 {
        let at = Instant::from_millis(10 * step);
        while now < at {
            now = node.poll(now, &mut sink).min(at);
        }
        let value = step as u8;
        let plain = CanFrame::new(CanId::new(0x141).unwrap(), &[value]).unwrap();
        let inverted = CanFrame::new(CanId::new(0x142).unwrap(), &[!value]).unwrap();
        node.handle_frame(at, &plain, &mut sink);
        node.handle_frame(at + Duration::from_micros(200), &inverted, &mut sink);
    }
    assert!(node.is_working(), "{:?}", node.fault());
    // Outside Operational the check is not scheduled.
    node.handle_frame(
        now,
        &nmt::command_frame(NmtCommand::EnterPreOperational, 0),
        &mut sink,
    );
    assert_eq!(node.nmt_state(), NmtState::PreOperational);
    assert_eq!(node.core.protocol.integrity.deadline(), Instant::NEVER);
}

#[test]
fn en50325_5_8_3_1_every_bit_flip_of_the_identifier_table_in_operational_gives_the_safe_state() {
    for byte in 0..SRDO_IDS {
        for bit in 0..8 {
            let what = std::format!("identifier table byte {byte} bit {bit}");
            let fault = flipped(&what, |table| table.lookup[byte] ^= 1 << bit);
            assert_eq!(fault, IntegrityFault::IdentifierTable, "{what}");
        }
    }
}

/// Every bit of every byte of a resolved mapping (spans in use and unused, pair count,
/// length) of the consumer (slot 0) and the producer (slot 1).
#[test]
fn en50325_5_8_3_1_every_bit_flip_of_a_resolved_mapping_in_operational_gives_the_safe_state() {
    for slot in 0..2usize {
        for field in 0..34usize {
            for bit in 0..8 {
                let what = std::format!("mapping of slot {slot}, field {field}, bit {bit}");
                let fault = flipped(&what, |table| {
                    let mapping = &mut table.runtime[slot].mapping;
                    let mask = 1u8 << bit;
                    match field {
                        0..8 => mapping.plain[field].offset ^= mask,
                        8..16 => mapping.plain[field - 8].len ^= mask,
                        16..24 => mapping.inverted[field - 16].offset ^= mask,
                        24..32 => mapping.inverted[field - 24].len ^= mask,
                        32 => mapping.pairs ^= mask,
                        _ => mapping.len ^= mask,
                    }
                });
                assert_eq!(
                    fault,
                    IntegrityFault::Runtime(SrdoNumber::from_index(slot)),
                    "{what}"
                );
            }
        }
    }
}

/// A damaged copy of the record's values a running producer or consumer took at the
/// Operational entry (a producer's refresh time or identifiers, a consumer's SCT or SRVT): the
/// receive and transmit paths run on these copies, not on the records, so the check compares
/// them with the records.
#[test]
fn en50325_5_8_3_1_a_changed_time_or_identifier_of_a_running_srdo_gives_the_safe_state() {
    let other_pair = crate::safety::types::CobIdPair::new(0x105, 0x106).unwrap();
    let own_pair = crate::safety::types::CobIdPair::new(0x103, 0x104).unwrap();
    for (what, slot, role) in [
        (
            "the consumer's SCT",
            0,
            Role::Consumer(srdo::Consumer::start(Instant::ZERO, 50 ^ 4, 20)),
        ),
        (
            "the consumer's SRVT",
            0,
            Role::Consumer(srdo::Consumer::start(Instant::ZERO, 50, 20 ^ 1)),
        ),
        (
            "the producer's refresh time",
            1,
            Role::Producer(srdo::Producer::start(
                Instant::ZERO,
                33,
                REFRESH_MS ^ 8,
                own_pair,
            )),
        ),
        (
            "the producer's identifiers",
            1,
            Role::Producer(srdo::Producer::start(
                Instant::ZERO,
                33,
                REFRESH_MS,
                other_pair,
            )),
        ),
    ] {
        let fault = flipped(what, |table| table.runtime[slot].role = role);
        assert_eq!(
            fault,
            IntegrityFault::Runtime(SrdoNumber::from_index(slot)),
            "{what}"
        );
    }
}

/// A damaged role: a running SRDO that is idle or has the other role, an idle one that runs.
#[test]
fn en50325_5_8_3_1_a_changed_role_in_operational_gives_the_safe_state() {
    let consumer = Role::Consumer(srdo::Consumer::start(Instant::ZERO, 50, 20));
    let producer = Role::Producer(srdo::Producer::start(
        Instant::ZERO,
        33,
        REFRESH_MS,
        crate::safety::types::CobIdPair::new(0x103, 0x104).unwrap(),
    ));
    for (slot, role) in [
        (0, Role::Idle),
        (0, producer),
        (1, Role::Idle),
        (1, consumer),
        (2, consumer),
        (3, producer),
    ] {
        let what = std::format!("slot {slot} as {role:?}");
        let fault = flipped(&what, |table| table.runtime[slot].role = role);
        assert_eq!(
            fault,
            IntegrityFault::Runtime(SrdoNumber::from_index(slot)),
            "{what}"
        );
    }
    // An idle slot with a mapping resolved into it.
    let fault = flipped("idle slot with a mapping", |table| {
        table.runtime[3].mapping.len = 1;
    });
    assert_eq!(fault, IntegrityFault::Runtime(SrdoNumber::from_index(3)));
}

#[test]
fn en50325_5_8_3_1_every_bit_flip_of_the_active_list_in_operational_gives_the_safe_state() {
    for position in 0..2 {
        for bit in 0..8 {
            let what = std::format!("active list entry {position} bit {bit}");
            let fault = flipped(&what, |table| table.active[position] ^= 1 << bit);
            assert_eq!(fault, IntegrityFault::ActiveList, "{what}");
        }
    }
    let fault = flipped("an entry lost", |table| {
        table.active.pop();
    });
    assert_eq!(fault, IntegrityFault::ActiveList);
    let fault = flipped("an entry added", |table| {
        table.active.push(2).unwrap();
    });
    assert_eq!(fault, IntegrityFault::ActiveList);
}

/// A named change to the records.
type Flip = (
    std::string::String,
    std::boxed::Box<dyn Fn(&mut SafetyConfig<4>)>,
);

/// Every bit of every field the two existing records hold (mapping entries up to their count,
/// signature included), every bit of 0x13FE, and the direction of the records that do not
/// exist (nothing else of a deleted record is read by anything).
#[test]
fn en50325_5_8_3_1_every_bit_flip_of_a_record_in_operational_gives_the_safe_state() {
    let mut flips: std::vec::Vec<Flip> = std::vec::Vec::new();
    for slot in 0..2usize {
        for bit in 0..8u32 {
            flips.push((
                std::format!("SRDO {} direction bit {bit}", slot + 1),
                std::boxed::Box::new(move |s| s.srdos[slot].direction ^= 1 << bit),
            ));
            flips.push((
                std::format!("SRDO {} SRVT bit {bit}", slot + 1),
                std::boxed::Box::new(move |s| s.srdos[slot].srvt ^= 1 << bit),
            ));
            flips.push((
                std::format!("SRDO {} mapping count bit {bit}", slot + 1),
                std::boxed::Box::new(move |s| s.srdos[slot].mapping_count ^= 1 << bit),
            ));
        }
        for bit in 0..16u32 {
            flips.push((
                std::format!("SRDO {} cycle time bit {bit}", slot + 1),
                std::boxed::Box::new(move |s| s.srdos[slot].cycle_time ^= 1 << bit),
            ));
            flips.push((
                std::format!("SRDO {} signature bit {bit}", slot + 1),
                std::boxed::Box::new(move |s| s.srdos[slot].signature ^= 1 << bit),
            ));
        }
        for bit in 0..32u32 {
            flips.push((
                std::format!("SRDO {} COB-ID 1 bit {bit}", slot + 1),
                std::boxed::Box::new(move |s| s.srdos[slot].cob_id_1 ^= 1 << bit),
            ));
            flips.push((
                std::format!("SRDO {} COB-ID 2 bit {bit}", slot + 1),
                std::boxed::Box::new(move |s| s.srdos[slot].cob_id_2 ^= 1 << bit),
            ));
            for entry in 0..2 {
                flips.push((
                    std::format!("SRDO {} mapping entry {entry} bit {bit}", slot + 1),
                    std::boxed::Box::new(move |s| s.srdos[slot].mapping[entry] ^= 1 << bit),
                ));
            }
        }
    }
    for slot in 2..4usize {
        for bit in 0..8u32 {
            flips.push((
                std::format!("deleted SRDO {} direction bit {bit}", slot + 1),
                std::boxed::Box::new(move |s| s.srdos[slot].direction ^= 1 << bit),
            ));
        }
    }
    for bit in 0..8u32 {
        flips.push((
            std::format!("0x13FE bit {bit}"),
            std::boxed::Box::new(move |s| s.configuration_valid ^= 1 << bit),
        ));
    }
    for (what, flip) in &flips {
        // Mostly the records' own check; a flip that deletes an SRDO (direction 0) leaves
        // records that pass, and is found as a running SRDO the records no longer have.
        let fault = flipped(what, |table| flip(&mut table.safety));
        match fault {
            IntegrityFault::Records(config_fault) if what.starts_with("0x13FE") => {
                assert_eq!(config_fault.error, ConfigError::NotDeclaredValid, "{what}");
            }
            IntegrityFault::Records(_) => {}
            IntegrityFault::ActiveList if what.contains("direction") => {}
            other => panic!("{what}: {other:?}"),
        }
    }
    assert_eq!(flips.len(), 2 * (3 * 8 + 2 * 16 + 4 * 32) + 2 * 8 + 8);
}

/// EMCY 6300h (EN 50325-5 6.4.1.6; CiA 301 7.2.7): every device-wide detail byte 1 names one
/// reason only, and none of them can be read as a [`ConfigError`] cause code (1..=24), so a
/// tool that decodes byte 1 never confuses "validated for another node-ID" with damage found in
/// Operational, or either with a refused configuration.
#[test]
fn en50325_5_6_4_1_6_emcy_detail_codes_are_distinct() {
    let codes = [
        crate::node::STORED_PARAMETERS_REJECTED,
        crate::node::VALIDATED_FOR_ANOTHER_NODE_ID,
        cause::RECORDS,
        cause::IDENTIFIER_TABLE,
        cause::RUNTIME,
        cause::ACTIVE_LIST,
    ];
    for (i, a) in codes.iter().enumerate() {
        assert!(
            *a > ConfigError::SignatureMismatch.cause_code(),
            "{a:#04x} overlaps a ConfigError cause code"
        );
        for b in &codes[i + 1..] {
            assert_ne!(a, b, "EMCY 6300h detail {a:#04x} has two meanings");
        }
    }
}
