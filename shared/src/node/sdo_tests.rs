//! The node seen through its SDO server on the bus, as a configuration tool sees it: every
//! abort code the device sends, and store/restore with power cuts (CiA 301 7.5.2.13/14).

use super::tests::{Recorder, config};
use super::*;
use crate::canopen::sdo_client::{self, ClientError};
use crate::canopen::storage::{PowerCutFlash, RamFlash, Slot};
use crate::safety::config::{ConfigError, SrdoRecord};
use crate::safety::signature;
use std::collections::BTreeSet;

type Medium = PowerCutFlash<RamFlash<8192>>;
type BusNode = Node<Medium, 4>;

const T0: Instant = Instant::ZERO;

fn node_on(id: u8, flash: Medium) -> (BusNode, Recorder) {
    let mut node = BusNode::new(config(id), flash).unwrap();
    let mut sink = Recorder::default();
    node.poll(T0, &mut sink);
    (node, sink)
}

fn fresh(id: u8) -> (BusNode, Recorder) {
    node_on(id, PowerCutFlash::new(RamFlash::new(), None))
}

/// One SDO request on the bus, answered (or not) on 0x580 + node-ID.
fn exchange(
    node: &mut BusNode,
    sink: &mut Recorder,
    now: Instant,
    request: [u8; 8],
) -> Option<[u8; 8]> {
    let id = u16::from(node.core.shell.config.node_id.raw());
    let frame = CanFrame::new(CanId::new(0x600 + id).unwrap(), &request).unwrap();
    sink.frames.clear();
    node.handle_frame(now, &frame, sink);
    let responses: std::vec::Vec<_> = sink
        .frames
        .iter()
        .filter(|f| f.id().raw() == 0x580 + id)
        .collect();
    assert!(responses.len() <= 1, "one answer per request");
    responses.first().map(|f| f.data().try_into().unwrap())
}

fn write(
    node: &mut BusNode,
    sink: &mut Recorder,
    index: u16,
    sub: u8,
    data: &[u8],
) -> Result<(), ClientError> {
    sdo_client::download(
        |r| exchange(node, sink, T0, r),
        Address::new(index, sub),
        data,
    )
}

fn read(
    node: &mut BusNode,
    sink: &mut Recorder,
    index: u16,
    sub: u8,
) -> Result<std::vec::Vec<u8>, ClientError> {
    sdo_client::upload(|r| exchange(node, sink, T0, r), Address::new(index, sub))
        .map(|v| v.to_vec())
}

fn abort_of(result: Result<impl core::fmt::Debug, ClientError>) -> AbortCode {
    match result {
        Err(ClientError::Aborted(code)) => code,
        other => panic!("expected an abort, got {other:?}"),
    }
}

fn nmt(node: &mut BusNode, sink: &mut Recorder, command: NmtCommand) {
    node.handle_frame(T0, &nmt::command_frame(command, 0), sink);
}

/// Configures SRDO 1 of a receive node to consume 0x101/0x102 and validates it, entirely
/// over SDO, the way the configuration tool does (EN 50325-5 8.3).
fn configure_consumer(node: &mut BusNode, sink: &mut Recorder, sct_ms: u16) {
    write(node, sink, 0x1301, 1, &[0]).unwrap();
    write(node, sink, 0x1301, 5, &0x101u32.to_le_bytes()).unwrap();
    write(node, sink, 0x1301, 6, &0x102u32.to_le_bytes()).unwrap();
    write(node, sink, 0x1301, 2, &sct_ms.to_le_bytes()).unwrap();
    write(node, sink, 0x1301, 1, &[2]).unwrap();
    let crc = signature::compute(&node.safety_config().srdos[0]);
    write(node, sink, 0x13FF, 1, &crc.to_le_bytes()).unwrap();
    write(node, sink, 0x13FE, 0, &[0xA5]).unwrap();
}

#[test]
fn cia301_7_2_4_identity_and_device_name_over_the_bus() {
    let (mut node, mut sink) = fresh(33);
    assert_eq!(read(&mut node, &mut sink, 0x1018, 0), Ok(vec![4]));
    assert_eq!(
        read(&mut node, &mut sink, 0x1018, 4),
        Ok(42u32.to_le_bytes().to_vec())
    );
    assert_eq!(
        read(&mut node, &mut sink, 0x1008, 0),
        Ok(b"dual-channel safety node (test)".to_vec())
    );
    // The pre-defined SRDO 1 of node 33 (EN 50325-5 Table 5, CiA 304 Table 3).
    assert_eq!(
        read(&mut node, &mut sink, 0x1301, 5),
        Ok(0x141u32.to_le_bytes().to_vec())
    );
}

/// Every abort code this device sends is reached over the bus, through the real server and
/// dictionary; the codes it never sends are listed and argued.
#[test]
fn cia301_7_2_4_3_17_every_abort_code_the_device_sends() {
    let (mut node, mut sink) = fresh(33);
    let n = &mut node;
    let s = &mut sink;
    let mut seen = BTreeSet::new();
    let mut expect = |code: AbortCode, result: Result<(), ClientError>| {
        assert_eq!(result, Err(ClientError::Aborted(code)), "{code:?}");
        seen.insert(code.code());
    };
    let raw = |n: &mut BusNode, s: &mut Recorder, now, request| {
        let reply: [u8; 8] = exchange(n, s, now, request).unwrap();
        assert_eq!(reply[0], 0x80);
        AbortCode::from_code(u32::from_le_bytes(reply[4..8].try_into().unwrap())).unwrap()
    };
    let direct = |code: AbortCode| Err(ClientError::Aborted(code));

    // Protocol level.
    expect(
        AbortCode::InvalidCommand,
        direct(raw(n, s, T0, [0xC0, 0, 0x10, 0, 0, 0, 0, 0])),
    );
    exchange(n, s, T0, [0x21, 0x08, 0x10, 0, 3, 0, 0, 0]);
    exchange(n, s, T0, [0x40, 0x08, 0x10, 0, 0, 0, 0, 0]);
    expect(
        AbortCode::ToggleBit,
        direct(raw(n, s, T0, [0x70, 0, 0, 0, 0, 0, 0, 0])),
    );
    expect(
        AbortCode::OutOfMemory,
        direct(raw(n, s, T0, [0x21, 0x00, 0x20, 1, 200, 0, 0, 0])),
    );
    exchange(n, s, T0, [0x40, 0x08, 0x10, 0, 0, 0, 0, 0]);
    sink_clear(s);
    n.poll(Instant::from_millis(499), s);
    assert!(s.frames.is_empty(), "no timeout before the deadline");
    n.poll(Instant::from_millis(500), s);
    let timeout: [u8; 8] = s.frames[0].data().try_into().unwrap();
    expect(
        AbortCode::Timeout,
        direct(
            AbortCode::from_code(u32::from_le_bytes(timeout[4..8].try_into().unwrap())).unwrap(),
        ),
    );

    // Object dictionary.
    expect(AbortCode::NoObject, write(n, s, 0x5000, 0, &[1]));
    expect(AbortCode::NoSubIndex, write(n, s, 0x1018, 9, &[1]));
    expect(AbortCode::ReadOnly, write(n, s, 0x1000, 0, &[1, 2, 3, 4]));
    expect(AbortCode::LengthTooHigh, write(n, s, 0x1017, 0, &[1, 2, 3]));
    expect(AbortCode::LengthTooLow, write(n, s, 0x1017, 0, &[1]));
    expect(AbortCode::CannotStore, write(n, s, 0x1010, 1, b"nope"));

    // Safety objects (EN 50325-5 8.2, CiA 304 Table 2).
    expect(AbortCode::ValueTooHigh, write(n, s, 0x1301, 1, &[3]));
    expect(AbortCode::ValueTooLow, write(n, s, 0x1301, 2, &[0, 0]));
    expect(AbortCode::ReadOnly, write(n, s, 0x1301, 4, &[254]));
    expect(
        AbortCode::InvalidValue,
        write(n, s, 0x1301, 5, &0x143u32.to_le_bytes()),
    );
    expect(AbortCode::DeviceState, write(n, s, 0x1381, 0, &[0]));
    write(n, s, 0x1301, 1, &[0]).unwrap();
    expect(
        AbortCode::UnsupportedAccess,
        write(n, s, 0x1381, 1, &0x6200_0108u32.to_le_bytes()),
    );
    write(n, s, 0x1381, 0, &[0]).unwrap();
    write(n, s, 0x1381, 1, &0x2000_0110u32.to_le_bytes()).unwrap();
    write(n, s, 0x1381, 2, &0x2000_0110u32.to_le_bytes()).unwrap();
    expect(AbortCode::NotMappable, write(n, s, 0x1381, 0, &[2]));
    expect(AbortCode::MappingTooLong, write(n, s, 0x1381, 0, &[18]));
    write(n, s, 0x1381, 1, &0x6200_0108u32.to_le_bytes()).unwrap();
    write(n, s, 0x1381, 2, &0x6200_0108u32.to_le_bytes()).unwrap();
    expect(
        AbortCode::ParameterIncompatible,
        write(n, s, 0x1381, 0, &[2]),
    );

    // The medium fails during a store: 0606 0000h, and the device reports why.
    n.flash_mut().cut_after(0);
    expect(AbortCode::HardwareError, write(n, s, 0x1010, 1, b"save"));
    assert!(s.events.contains(&Event::StorageFailed(
        crate::canopen::storage::StorageError::PowerLost
    )));

    let sent: BTreeSet<u32> = AbortCode::ALL.iter().map(|c| c.code()).collect();
    let never: BTreeSet<u32> = [
        // No write-only objects exist.
        AbortCode::WriteOnly,
        // Internal inconsistencies are refused as ParameterIncompatible, naming the SRDO.
        AbortCode::InternalIncompatible,
        // Lengths are always answered as too high or too low, which is more specific.
        AbortCode::LengthMismatch,
        // No access is refused for a reason the specific codes do not cover.
        AbortCode::General,
        AbortCode::LocalControl,
    ]
    .iter()
    .map(|c| c.code())
    .collect();
    let expected: BTreeSet<u32> = sent.difference(&never).copied().collect();
    assert_eq!(seen, expected);
}

fn sink_clear(sink: &mut Recorder) {
    sink.frames.clear();
    sink.events.clear();
}

/// EN 50325-5 8.2.2: in Operational, every write to a safety object is refused with
/// 0800 0022h, over the bus, and changes nothing; so are store (0x1010) and restore (0x1011),
/// whose erase would stall the channel's loop.
#[test]
fn en50325_5_8_2_2_safety_objects_are_read_only_in_operational_over_the_bus() {
    let (mut node, mut sink) = fresh(33);
    configure_consumer(&mut node, &mut sink, 50);
    nmt(&mut node, &mut sink, NmtCommand::Start);
    assert_eq!(node.nmt_state(), NmtState::Operational);
    let before = node.safety_config().clone();
    let untouched = node.flash().clone().into_inner();
    for (index, sub, data) in [
        (0x1301u16, 2u8, &[100u8, 0][..]),
        (0x1381, 0, &[0]),
        (0x13FE, 0, &[0]),
        (0x13FF, 1, &[0, 0]),
        (0x1010, 1, b"save"),
        (0x1011, 1, b"load"),
    ] {
        assert_eq!(
            abort_of(write(&mut node, &mut sink, index, sub, data)),
            AbortCode::DeviceState,
            "{index:04X}:{sub}"
        );
    }
    assert_eq!(node.safety_config(), &before);
    assert_eq!(
        node.flash().clone().into_inner(),
        untouched,
        "nothing was written"
    );
}

/// CiA 301 7.5.2.13: a device built in two steps ([`Device::prepare`], then
/// [`Device::restore_parameters`] where it is kept) restores the stored configuration as
/// [`Device::with_protocol`] does; prepared, it holds the defaults, and once it has booted
/// the second step changes nothing.
#[test]
fn cia301_7_5_2_13_a_prepared_device_restores_the_stored_configuration_in_place() {
    let (mut node, mut sink) = fresh(33);
    configure_consumer(&mut node, &mut sink, 60);
    write(&mut node, &mut sink, 0x1010, 1, b"save").unwrap();
    let configured = node.safety_config().clone();
    let flash = node.core.flash.clone();
    let prepare = || {
        let table = SrdoTable::new(&config(33)).unwrap();
        BusNode::prepare(config(33), flash.clone(), table).unwrap()
    };
    let mut prepared = prepare();
    assert_ne!(prepared.safety_config(), &configured, "nothing read yet");
    prepared.restore_parameters();
    assert_eq!(prepared.safety_config(), &configured);
    let restored = BusNode::with_protocol(
        config(33),
        flash.clone(),
        SrdoTable::new(&config(33)).unwrap(),
    )
    .unwrap();
    assert_eq!(restored.safety_config(), prepared.safety_config());
    let mut booted = prepare();
    booted.poll(T0, &mut sink);
    booted.restore_parameters();
    assert_ne!(booted.safety_config(), &configured, "restored after boot");
}

/// CiA 301 7.5.2.13: a stored configuration survives a reset and brings the node back to
/// Operational with the same signatures.
#[test]
fn cia301_7_5_2_13_stored_configuration_is_restored_at_reset() {
    let (mut node, mut sink) = fresh(33);
    configure_consumer(&mut node, &mut sink, 60);
    write(&mut node, &mut sink, 0x1010, 1, b"save").unwrap();
    let configured = node.safety_config().clone();
    sink_clear(&mut sink);
    nmt(&mut node, &mut sink, NmtCommand::ResetNode);
    assert!(sink.events.contains(&Event::ParametersRestored));
    assert_eq!(node.safety_config(), &configured);
    nmt(&mut node, &mut sink, NmtCommand::Start);
    assert_eq!(node.nmt_state(), NmtState::Operational);

    // 0x1011 "load": the defaults come back at the next reset, and they are not validated.
    nmt(&mut node, &mut sink, NmtCommand::EnterPreOperational);
    write(&mut node, &mut sink, 0x1011, 1, b"load").unwrap();
    nmt(&mut node, &mut sink, NmtCommand::ResetNode);
    assert_eq!(node.safety_config().srdos[0].cob_id_1, 0x141);
    assert_eq!(node.safety_config().configuration_valid, 0);
}

/// CiA 301 7.5.2.13 on flash whose erase stalls the processor (the hardware's): a store
/// succeeds while its slot is blank (a new device has two, so two stores pass); the next
/// one, and a restore (0x1011), are refused with 0800 0022h (the free slot is erased only at
/// the next start-up), with the reason as an event, and write nothing: the last store stays
/// in force.
#[test]
fn cia301_7_5_2_13_a_store_without_a_blank_slot_is_refused_for_the_device_state() {
    let medium = PowerCutFlash::new(RamFlash::new().with_stalling_erase(), None);
    let (mut node, mut sink) = node_on(33, medium);
    configure_consumer(&mut node, &mut sink, 60);
    write(&mut node, &mut sink, 0x1010, 1, b"save").unwrap();
    write(&mut node, &mut sink, 0x1010, 1, b"save").unwrap();
    let stored = node.safety_config().clone();
    let untouched = node.flash().clone().into_inner();
    configure_consumer(&mut node, &mut sink, 90);
    sink_clear(&mut sink);
    for (index, data) in [(0x1010u16, b"save"), (0x1011, b"load")] {
        assert_eq!(
            abort_of(write(&mut node, &mut sink, index, 1, data)),
            AbortCode::DeviceState,
            "{index:04X}"
        );
        assert!(
            sink.events.contains(&Event::StorageFailed(
                crate::canopen::storage::StorageError::NotErased
            )),
            "{index:04X}: {:?}",
            sink.events
        );
    }
    assert_eq!(node.flash().clone().into_inner(), untouched);
    nmt(&mut node, &mut sink, NmtCommand::ResetNode);
    assert_eq!(node.safety_config(), &stored);
}

/// A store interrupted by a power cut at every possible byte: after power comes back the node
/// holds the old configuration or the new one, whole, never a mix, and either one takes it to
/// Operational, because each is consistent with its own signatures.
#[test]
fn a_power_cut_during_store_leaves_the_old_or_the_new_configuration() {
    let (mut node, mut sink) = fresh(33);
    configure_consumer(&mut node, &mut sink, 60);
    write(&mut node, &mut sink, 0x1010, 1, b"save").unwrap();
    let old = node.safety_config().clone();
    let base = node.flash().clone();

    let mut outcomes = [0usize; 2];
    let mut new = None;
    let mut budget = 0;
    loop {
        let (mut node, mut sink) = node_on(33, base.clone());
        configure_consumer(&mut node, &mut sink, 90);
        new.get_or_insert_with(|| node.safety_config().clone());
        node.flash_mut().cut_after(budget);
        let stored = write(&mut node, &mut sink, 0x1010, 1, b"save");
        let completed = node.flash().powered();

        // Power cycle: a new node on the same medium.
        let mut medium = node.flash().clone();
        medium.power_on();
        let (mut node, mut sink) = node_on(33, medium);
        let restored = node.safety_config().clone();
        let is_new = &restored == new.as_ref().unwrap();
        assert!(
            is_new || restored == old,
            "budget {budget}: a mix was restored"
        );
        if stored.is_ok() {
            assert!(is_new, "budget {budget}: an acknowledged store was lost");
        } else {
            assert_eq!(abort_of(stored), AbortCode::HardwareError);
        }
        nmt(&mut node, &mut sink, NmtCommand::Start);
        assert_eq!(node.nmt_state(), NmtState::Operational, "budget {budget}");
        outcomes[usize::from(is_new)] += 1;
        if completed {
            break;
        }
        budget += 1;
    }
    assert!(outcomes[0] > 0 && outcomes[1] > 0, "{outcomes:?}");
}

/// EN 50325-5 8.3.1: a node whose restored configuration is not valid (0x13FE not A5h, a
/// signature that does not match, or a damaged medium) stays in the safe state and says why.
#[test]
fn en50325_5_8_3_1_a_restored_invalid_configuration_keeps_the_node_safe() {
    // Stored after a change that reset 0x13FE.
    let (mut node, mut sink) = fresh(33);
    configure_consumer(&mut node, &mut sink, 60);
    write(&mut node, &mut sink, 0x1301, 3, &[30]).unwrap();
    write(&mut node, &mut sink, 0x1010, 1, b"save").unwrap();
    let (mut node, mut sink) = node_on(33, node.flash().clone());
    assert!(sink.events.contains(&Event::ParametersRestored));
    nmt(&mut node, &mut sink, NmtCommand::Start);
    assert_eq!(node.nmt_state(), NmtState::PreOperational);
    assert!(!node.is_working());
    assert!(
        sink.events
            .contains(&Event::ConfigurationRefused(ConfigFault {
                srdo: None,
                error: ConfigError::NotDeclaredValid,
            }))
    );

    // Stored with A5h but a signature that does not match its record (written by a faulty
    // tool or damaged before the CRC was computed).
    let mut medium = PowerCutFlash::new(RamFlash::new(), None);
    let mut bad = SafetyConfig::<4>::predefined(33, &[], &[0x6200_0108, 0x6201_0108]);
    bad.srdos[0].signature = signature::compute(&bad.srdos[0]) ^ 1;
    bad.configuration_valid = 0xA5;
    persist::store(
        &mut medium,
        &table_with(bad),
        0,
        node_id(33),
        &super::access::Persisted::new([0; 4]),
        #[cfg(feature = "lss")]
        None,
    )
    .unwrap();
    let (mut node, mut sink) = node_on(33, medium);
    nmt(&mut node, &mut sink, NmtCommand::Start);
    assert_eq!(node.nmt_state(), NmtState::PreOperational);
    let refused = sink.events.iter().find_map(|e| match e {
        Event::ConfigurationRefused(fault) => Some(*fault),
        _ => None,
    });
    assert_eq!(
        refused.map(|f| f.error),
        Some(ConfigError::SignatureMismatch)
    );
    assert!(!sink.emergencies().is_empty());

    // A stored record damaged in the medium: reported, defaults in force, not Operational.
    let (mut node, mut sink) = fresh(33);
    configure_consumer(&mut node, &mut sink, 60);
    write(&mut node, &mut sink, 0x1010, 1, b"save").unwrap();
    let mut medium = node.flash().clone().into_inner();
    for slot in [Slot::A, Slot::B] {
        if medium.slot_mut(slot)[0] != 0xFF {
            medium.slot_mut(slot)[20] ^= 0x40;
        }
    }
    let (mut node, mut sink) = node_on(33, PowerCutFlash::new(medium, None));
    assert!(
        sink.events
            .contains(&Event::StoredParametersRejected(PersistError::Storage(
                crate::canopen::storage::StorageError::Corrupt
            )))
    );
    assert_eq!(node.safety_config().srdos[0], {
        let defaults = defaults_unsigned();
        defaults.srdos[0]
    });
    nmt(&mut node, &mut sink, NmtCommand::Start);
    assert!(!node.is_working());
    let _ = SrdoRecord::DELETED;
}

/// EN 50325-5 Table 5: sub-index 04h (transmission type, fixed at 254) is a read-only entry,
/// answered outside Operational with 0601 0002h like every other read-only entry, whatever
/// the value or its length; in Operational with 0800 0022h like every safety object
/// (EN 50325-5 8.2.2).
#[test]
fn en50325_5_table5_transmission_type_is_read_only() {
    let (mut node, mut sink) = fresh(33);
    for data in [&[254u8][..], &[1][..], &[254, 0][..]] {
        assert_eq!(
            abort_of(write(&mut node, &mut sink, 0x1301, 4, data)),
            AbortCode::ReadOnly,
            "{data:?}"
        );
    }
    assert_eq!(read(&mut node, &mut sink, 0x1301, 4), Ok(vec![254]));
    configure_consumer(&mut node, &mut sink, 50);
    nmt(&mut node, &mut sink, NmtCommand::Start);
    assert_eq!(node.nmt_state(), NmtState::Operational);
    assert_eq!(
        abort_of(write(&mut node, &mut sink, 0x1301, 4, &[254])),
        AbortCode::DeviceState
    );
}

/// EN 50325-5 6.4.1.6, 8.3.1: when NMT start refuses a restored configuration (a signature
/// that does not match), 0x13FE reads 0 at once, with the EMCY naming the SRDO and the reason;
/// the stored record stays as written.
#[test]
fn en50325_5_6_4_1_6_configuration_valid_reads_0_after_a_refused_start() {
    let mut medium = PowerCutFlash::new(RamFlash::new(), None);
    let mut bad = SafetyConfig::<4>::predefined(33, &[], &[0x6200_0108, 0x6201_0108]);
    bad.srdos[0].signature = signature::compute(&bad.srdos[0]) ^ 1;
    bad.configuration_valid = 0xA5;
    persist::store(
        &mut medium,
        &table_with(bad),
        0,
        node_id(33),
        &super::access::Persisted::new([0; 4]),
        #[cfg(feature = "lss")]
        None,
    )
    .unwrap();
    let (mut node, mut sink) = node_on(33, medium);
    assert_eq!(read(&mut node, &mut sink, 0x13FE, 0), Ok(vec![0xA5]));
    sink_clear(&mut sink);
    nmt(&mut node, &mut sink, NmtCommand::Start);
    assert_eq!(node.nmt_state(), NmtState::PreOperational);
    let emcy = sink.emergencies();
    assert_eq!(emcy.len(), 1);
    assert_eq!(emcy[0].code, crate::canopen::emcy::code::DATA_SET);
    assert_eq!(
        emcy[0].detail[..2],
        [1, ConfigError::SignatureMismatch.cause_code()]
    );
    assert_eq!(read(&mut node, &mut sink, 0x13FE, 0), Ok(vec![0]));
    // The stored record is untouched: a reset restores it as written.
    let (node, _) = node_on(33, node.flash().clone());
    assert_eq!(node.safety_config().configuration_valid, 0xA5);
}

fn node_id(id: u8) -> NodeId {
    NodeId::new(id).unwrap()
}

/// IEC 61784-3 (addressing, masquerade), EN 50325-5 6.4.1.6: a configuration validated on
/// node-ID 33 and restored on node-ID 34 is not valid there: 0x13FE reads 0, an EMCY says so
/// at boot (naming the node-ID it was validated for), and the node stays in the safe state
/// until a tool reconfigures and validates it for the new node-ID.
#[test]
fn iec61784_3_a_configuration_validated_for_another_node_id_is_not_valid() {
    let (mut node, mut sink) = fresh(33);
    configure_consumer(&mut node, &mut sink, 60);
    write(&mut node, &mut sink, 0x1010, 1, b"save").unwrap();
    let stored = node.safety_config().clone();
    let medium = node.flash().clone();

    let (mut node, mut sink) = node_on(34, medium);
    assert!(sink.events.contains(&Event::ValidatedForAnotherNodeId {
        validated_for: node_id(33)
    }));
    let emcy = sink.emergencies();
    assert_eq!(emcy.len(), 1);
    assert_eq!(emcy[0].code, crate::canopen::emcy::code::DATA_SET);
    assert_eq!(emcy[0].detail[..3], [0, VALIDATED_FOR_ANOTHER_NODE_ID, 33]);
    assert_eq!(
        node.safety_config().srdos,
        stored.srdos,
        "the configuration is kept for the tool to see and change"
    );
    assert_eq!(read(&mut node, &mut sink, 0x13FE, 0), Ok(vec![0]));
    nmt(&mut node, &mut sink, NmtCommand::Start);
    assert_eq!(node.nmt_state(), NmtState::PreOperational);
    assert!(!node.is_working());

    // Reconfigured and validated for node-ID 34, stored: it runs, also after a reset.
    write(&mut node, &mut sink, 0x1301, 2, &70u16.to_le_bytes()).unwrap();
    let crc = signature::compute(&node.safety_config().srdos[0]);
    write(&mut node, &mut sink, 0x13FF, 1, &crc.to_le_bytes()).unwrap();
    write(&mut node, &mut sink, 0x13FE, 0, &[0xA5]).unwrap();
    write(&mut node, &mut sink, 0x1010, 1, b"save").unwrap();
    let (mut node, mut sink) = node_on(34, node.flash().clone());
    assert!(sink.events.contains(&Event::ParametersRestored));
    nmt(&mut node, &mut sink, NmtCommand::Start);
    assert_eq!(node.nmt_state(), NmtState::Operational);

    // The same medium back on node-ID 33 is now the other node's configuration.
    let (mut node, mut sink) = node_on(33, node.flash().clone());
    nmt(&mut node, &mut sink, NmtCommand::Start);
    assert_eq!(node.nmt_state(), NmtState::PreOperational);
    assert_eq!(read(&mut node, &mut sink, 0x13FE, 0), Ok(vec![0]));
}

/// EN 50325-5 Table 5, CiA 304 8.3.3: with nothing stored, the pre-defined connection set
/// follows the node-ID.
#[test]
fn en50325_5_table5_defaults_follow_the_node_id() {
    for (id, first) in [(33u8, 0x141u32), (34, 0x143), (2, 0x103)] {
        let (mut node, mut sink) = fresh(id);
        assert_eq!(
            read(&mut node, &mut sink, 0x1301, 5),
            Ok(first.to_le_bytes().to_vec()),
            "node-ID {id}"
        );
        assert_eq!(
            read(&mut node, &mut sink, 0x1301, 6),
            Ok((first + 1).to_le_bytes().to_vec())
        );
    }
}

/// A record stored by the previous format (version 1, which did not say which node-ID it was
/// validated for) is not misread as a valid configuration: it is reported, and the node runs
/// on its defaults, not validated, in the safe state.
#[test]
fn en50325_5_8_3_1_a_record_of_the_previous_format_is_reported_not_used() {
    // Version 1 layout: version, heartbeat (2), 0x13FE, SRDO count, then the records.
    let defaults = defaults_unsigned();
    let mut image = std::vec![1u8, 0, 0, 0xA5, 4];
    for record in &defaults.srdos {
        image.push(record.direction);
        image.extend_from_slice(&record.cycle_time.to_le_bytes());
        image.push(record.srvt);
        image.extend_from_slice(&record.cob_id_1.to_le_bytes());
        image.extend_from_slice(&record.cob_id_2.to_le_bytes());
        image.push(record.mapping_count);
        for entry in record.entries() {
            image.extend_from_slice(&entry.to_le_bytes());
        }
        image.extend_from_slice(&signature::compute(record).to_le_bytes());
    }
    let mut medium = PowerCutFlash::new(RamFlash::new(), None);
    crate::canopen::storage::store(&mut medium, &image).unwrap();
    let (mut node, mut sink) = node_on(33, medium);
    assert!(sink.events.contains(&Event::StoredParametersRejected(
        PersistError::PreviousFormat(1)
    )));
    assert!(
        sink.emergencies()
            .iter()
            .any(|e| e.detail[..2] == [0, STORED_PARAMETERS_REJECTED])
    );
    assert_eq!(node.safety_config(), &defaults_unsigned());
    nmt(&mut node, &mut sink, NmtCommand::Start);
    assert!(!node.is_working());
}

fn defaults_unsigned() -> SafetyConfig<4> {
    SafetyConfig::<4>::predefined(33, &[], &[0x6200_0108, 0x6201_0108])
}

/// EN 50325-5 8.3.1 and CiA 301 7.2.7: damage anywhere in the stored record (its header as
/// much as its payload) is reported the same way at boot: `StoredParametersRejected`, EMCY
/// 6300h naming the stored parameters, the defaults in force and the node kept out of its
/// working state. Every single bit of the record is flipped in turn, in a medium that also
/// still holds the older record (a power cut after the commit); the one exception is the
/// commit word, whose flip still restores the newest configuration, intact (see
/// `canopen::storage`): an older one never comes back.
#[test]
fn en50325_5_8_3_1_every_bit_flip_of_the_stored_record_is_reported_with_emcy_6300() {
    let (mut node, mut sink) = fresh(33);
    configure_consumer(&mut node, &mut sink, 60);
    write(&mut node, &mut sink, 0x1010, 1, b"save").unwrap();
    let old = node.safety_config().clone();
    let old_medium = node.flash().clone().into_inner();
    configure_consumer(&mut node, &mut sink, 90);
    write(&mut node, &mut sink, 0x1010, 1, b"save").unwrap();
    let new = node.safety_config().clone();
    let mut medium = node.flash().clone().into_inner();
    // Put the old record back beside the new one, not retired: the state a power cut
    // between the commit and the retirement of the superseded slot leaves. The new record
    // is the one committed (first word programmed) and not retired (second word erased).
    let live = |slot: &[u8; 8192]| slot[0] != 0xFF && slot[4..8] == [0xFF; 4];
    let new_slot = if live(medium.slot_mut(Slot::A)) {
        Slot::A
    } else {
        Slot::B
    };
    *medium.slot_mut(new_slot.other()) = *old_medium.clone().slot_mut(new_slot.other());
    let (_, sink) = node_on(33, PowerCutFlash::new(medium.clone(), None));
    assert!(sink.events.contains(&Event::ParametersRestored));

    let used = medium
        .slot_mut(new_slot)
        .iter()
        .rposition(|&b| b != 0xFF)
        .unwrap()
        + 1;
    let defaults = defaults_unsigned();
    let (mut rejected, mut restored) = (0, 0);
    for bit in 0..used * 8 {
        let mut damaged = medium.clone();
        damaged.slot_mut(new_slot)[bit / 8] ^= 1 << (bit % 8);
        let (mut node, mut sink) = node_on(33, PowerCutFlash::new(damaged, None));
        assert_ne!(
            node.safety_config(),
            &old,
            "bit {bit}: the older configuration"
        );
        if node.safety_config() == &new {
            assert!(
                sink.events.contains(&Event::ParametersRestored),
                "bit {bit}"
            );
            restored += 1;
            continue;
        }
        rejected += 1;
        assert!(
            sink.events
                .contains(&Event::StoredParametersRejected(PersistError::Storage(
                    crate::canopen::storage::StorageError::Corrupt
                ))),
            "bit {bit}: {:?}",
            sink.events
        );
        let emcy = sink.emergencies();
        assert_eq!(emcy.len(), 1, "bit {bit}");
        assert_eq!(emcy[0].code, crate::canopen::emcy::code::DATA_SET);
        assert_eq!(emcy[0].detail[..2], [0, STORED_PARAMETERS_REJECTED]);
        assert_eq!(node.safety_config(), &defaults, "bit {bit}");
        nmt(&mut node, &mut sink, NmtCommand::Start);
        assert!(!node.is_working(), "bit {bit}");
    }
    // Only the commit word's 32 bits restore; everything else is damage.
    assert_eq!(restored, 32);
    assert_eq!(rejected, used * 8 - 32);
}

/// A stopped SRDO table of node 33 holding `safety`, to store as a tool would have left it.
fn table_with(safety: SafetyConfig<4>) -> SrdoTable<4> {
    let mut table = SrdoTable::new(&super::tests::config(33)).unwrap();
    table.safety = safety;
    table
}
