//! Tests of LSS (CiA 305) in a whole device, each naming the figure or the safety rule of
//! `canopen::lss` it verifies.

use super::tests::{Recorder, config};
use super::*;
use crate::canopen::lss::{BitRate, LssState, NodeIdSource};
use crate::canopen::storage::{RamFlash, Slot};
use crate::safety::signature;
use std::vec::Vec;

type Medium = RamFlash<8192>;
type TestNode<F = Medium> = Node<F, 4>;

const RATES: BitRates = BitRates::of(&[BitRate::Kbit500, BitRate::Kbit250]);
/// The identity of [`config`].
const IDENTITY: [u32; 4] = [0x1234, 0x5678, 1, 42];

fn id(raw: u8) -> NodeId {
    NodeId::new(raw).unwrap()
}

fn ms(value: u64) -> Instant {
    Instant::from_millis(value)
}

fn lss_request(data: [u8; 8]) -> CanFrame {
    CanFrame::new(lss::MASTER_TO_SLAVE, &data).unwrap()
}

/// A device on `flash` with LSS enabled and `switches`, polled once at 0.
fn started<F: Flash>(
    flash: F,
    switches: Option<NodeId>,
    configure: impl FnOnce(&mut NodeConfig),
) -> (TestNode<F>, Recorder) {
    let mut config = config(1);
    configure(&mut config);
    let mut node = TestNode::new(config, flash).unwrap();
    assert!(node.enable_lss(switches, RATES));
    let mut sink = Recorder::default();
    let _ = node.poll(Instant::ZERO, &mut sink);
    (node, sink)
}

/// The LSS answers in `sink`'s frames, then cleared.
fn answers(sink: &mut Recorder) -> Vec<[u8; 8]> {
    let found = sink
        .frames
        .iter()
        .filter(|frame| frame.id() == lss::SLAVE_TO_MASTER)
        .map(|frame| <[u8; 8]>::try_from(frame.data()).unwrap())
        .collect();
    sink.frames.clear();
    found
}

fn lss_events(sink: &Recorder) -> Vec<LssEvent> {
    sink.events
        .iter()
        .filter_map(|event| match event {
            Event::Lss(event) => Some(*event),
            _ => None,
        })
        .collect()
}

fn send<F: Flash>(node: &mut TestNode<F>, sink: &mut Recorder, now: Instant, data: [u8; 8]) {
    node.handle_frame(now, &lss_request(data), sink);
}

/// The one unconfigured node on the bus selected by fastscan, as CANopenNode's master does.
fn select_by_fastscan<F: Flash>(node: &mut TestNode<F>, sink: &mut Recorder) {
    let scan = |node: &mut TestNode<F>, sink: &mut Recorder, value: u32, bit, sub, next| {
        let [a, b, c, d] = value.to_le_bytes();
        send(
            node,
            sink,
            Instant::ZERO,
            [0x51, a, b, c, d, bit, sub, next],
        );
        !answers(sink).is_empty()
    };
    assert!(
        scan(node, sink, 0, 0x80, 0, 0),
        "an unconfigured node answers"
    );
    for sub in 0..4u8 {
        let mut value = 0u32;
        for bit in (0..32u8).rev() {
            if !scan(node, sink, value, bit, sub, sub) {
                value |= 1 << bit;
            }
        }
        assert_eq!(value, IDENTITY[usize::from(sub)]);
        assert!(scan(node, sink, value, 0, sub, (sub + 1) % 4));
    }
    assert_eq!(node.lss().map(Lss::state), Some(LssState::Configuration));
}

fn boot_ups(sink: &Recorder) -> Vec<u16> {
    sink.frames
        .iter()
        .filter(|frame| (0x701..=0x77F).contains(&frame.id().raw()) && frame.data() == [0])
        .map(|frame| frame.id().raw() - 0x700)
        .collect()
}

/// An expedited SDO download of `data` (1 to 4 bytes) to `index`:`sub` of `node_id`.
fn sdo_write<F: Flash>(
    node: &mut TestNode<F>,
    sink: &mut Recorder,
    node_id: u8,
    index: u16,
    sub: u8,
    data: &[u8],
) -> [u8; 8] {
    let [low, high] = index.to_le_bytes();
    let mut value = [0u8; 4];
    value[..data.len()].copy_from_slice(data);
    let command = 0x23 | ((4 - data.len() as u8) << 2);
    let request = [
        command, low, high, sub, value[0], value[1], value[2], value[3],
    ];
    let frame = CanFrame::new(CanId::new(0x600 + u16::from(node_id)).unwrap(), &request);
    sink.frames.clear();
    node.handle_frame(Instant::ZERO, &frame.unwrap(), sink);
    let answer = sink
        .frames
        .iter()
        .find(|frame| frame.id().raw() == 0x580 + u16::from(node_id))
        .map(|frame| <[u8; 8]>::try_from(frame.data()).unwrap())
        .expect("an SDO answer");
    sink.frames.clear();
    answer
}

/// Safety rule 3: all switches open and nothing stored is an unconfigured node: no boot-up
/// message, no heartbeat, no NMT, no SDO; only LSS, fastscan included.
#[test]
fn cia305_fig46_rule_3_an_unconfigured_node_sends_no_boot_up_and_answers_fastscan() {
    let (mut node, mut sink) = started(Medium::new(), None, |c| c.heartbeat_ms = 10);
    assert!(sink.frames.is_empty(), "{:?}", sink.frames);
    assert_eq!(lss_events(&sink), [LssEvent::Unconfigured]);
    assert_eq!(node.nmt_state(), NmtState::Initialising);
    assert_eq!(node.configured_node_id(), None);
    assert_eq!(
        node.lss().map(Lss::source),
        Some(NodeIdSource::Unconfigured)
    );
    for command in [NmtCommand::Start, NmtCommand::ResetCommunication] {
        node.handle_frame(ms(1), &nmt::command_frame(command, 0), &mut sink);
    }
    let sdo = CanFrame::new(CanId::new(0x601).unwrap(), &[0x40, 0, 0x10, 0, 0, 0, 0, 0]);
    node.handle_frame(ms(2), &sdo.unwrap(), &mut sink);
    let deadline = node.poll(ms(100), &mut sink);
    assert_eq!(deadline, Instant::NEVER, "no timer runs");
    assert!(sink.frames.is_empty(), "{:?}", sink.frames);
    assert_eq!(node.nmt_state(), NmtState::Initialising);
    send(&mut node, &mut sink, ms(3), [0x51, 0, 0, 0, 0, 0x80, 0, 0]);
    assert_eq!(answers(&mut sink), [[0x4F, 0, 0, 0, 0, 0, 0, 0]]);
    send(&mut node, &mut sink, ms(3), [0x4C, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(answers(&mut sink), [[0x50, 0, 0, 0, 0, 0, 0, 0]]);
}

/// Safety rule 2, CiA 305's exception: the unconfigured node found by fastscan takes the
/// node-ID it was given when switched back to waiting, and boots on it.
#[test]
fn cia305_fig31_rule_2_an_unconfigured_node_takes_its_node_id_when_switched_to_waiting() {
    let (mut node, mut sink) = started(Medium::new(), None, |_| {});
    select_by_fastscan(&mut node, &mut sink);
    send(&mut node, &mut sink, ms(1), [0x11, 12, 0, 0, 0, 0, 0, 0]);
    assert_eq!(answers(&mut sink), [[0x11, 0, 0, 0, 0, 0, 0, 0]]);
    assert_eq!(node.configured_node_id(), None, "pending only");
    sink.events.clear();
    send(&mut node, &mut sink, ms(2), [0x04, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(boot_ups(&sink), [12]);
    assert_eq!(node.nmt_state(), NmtState::PreOperational);
    assert_eq!(node.node_id(), id(12));
    assert_eq!(node.configured_node_id(), Some(id(12)));
    // It now answers SDO on its new node-ID.
    let answer = sdo_write(&mut node, &mut sink, 12, 0x1017, 0, &[0x64, 0]);
    assert_eq!(answer[0], 0x60);
}

/// Safety rule 2: a node-ID configured in a configured node waits for NMT reset
/// communication; until then the node answers on its old one.
#[test]
fn cia305_fig33_rule_2_a_configured_node_id_takes_effect_at_nmt_reset_communication() {
    let (mut node, mut sink) = started(Medium::new(), None, |_| {});
    select_by_fastscan(&mut node, &mut sink);
    send(&mut node, &mut sink, ms(1), [0x11, 5, 0, 0, 0, 0, 0, 0]);
    send(&mut node, &mut sink, ms(1), [0x04, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(node.node_id(), id(5));
    sink.frames.clear();
    send(&mut node, &mut sink, ms(2), [0x04, 1, 0, 0, 0, 0, 0, 0]);
    send(&mut node, &mut sink, ms(2), [0x11, 9, 0, 0, 0, 0, 0, 0]);
    assert_eq!(answers(&mut sink), [[0x11, 0, 0, 0, 0, 0, 0, 0]]);
    send(&mut node, &mut sink, ms(2), [0x04, 0, 0, 0, 0, 0, 0, 0]);
    assert!(sink.frames.is_empty(), "no reset by LSS: {:?}", sink.frames);
    assert_eq!(node.node_id(), id(5));
    assert_eq!(
        sdo_write(&mut node, &mut sink, 5, 0x1017, 0, &[0, 0])[0],
        0x60
    );
    node.handle_frame(
        ms(3),
        &nmt::command_frame(NmtCommand::ResetCommunication, 5),
        &mut sink,
    );
    assert_eq!(boot_ups(&sink), [9]);
    assert_eq!(node.node_id(), id(9));
}

/// Declares the node's configuration valid the way a tool does, and stores it (0x1010).
fn validate_and_store<F: Flash>(node: &mut TestNode<F>, sink: &mut Recorder, node_id: u8) {
    for record in node.core.protocol.safety.srdos.iter_mut() {
        record.signature = signature::compute(record);
    }
    node.core.protocol.safety.configuration_valid = 0xA5;
    assert_eq!(sdo_write(node, sink, node_id, 0x1010, 1, b"save")[0], 0x60);
}

/// An unconfigured device given `node_id` by LSS, stored (17h), and booted on it.
fn assigned<F: Flash>(flash: F, node_id: u8) -> (TestNode<F>, Recorder) {
    let (mut node, mut sink) = started(flash, None, |_| {});
    select_by_fastscan(&mut node, &mut sink);
    send(
        &mut node,
        &mut sink,
        ms(1),
        [0x11, node_id, 0, 0, 0, 0, 0, 0],
    );
    send(&mut node, &mut sink, ms(1), [0x17, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(
        answers(&mut sink),
        [[0x11, 0, 0, 0, 0, 0, 0, 0], [0x17, 0, 0, 0, 0, 0, 0, 0]]
    );
    send(&mut node, &mut sink, ms(1), [0x04, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(boot_ups(&sink), [u16::from(node_id)]);
    sink.frames.clear();
    sink.events.clear();
    (node, sink)
}

/// Safety rule 2: a node restarted on another node-ID than the one its stored safety
/// configuration was validated for does not run that configuration (0x13FE reads 0), after
/// NMT reset communication and after a power cycle alike.
#[test]
fn cia305_fig33_rule_2_a_new_node_id_withdraws_the_validated_configuration() {
    let (mut node, mut sink) = assigned(Medium::new(), 5);
    validate_and_store(&mut node, &mut sink, 5);
    send(&mut node, &mut sink, ms(2), [0x04, 1, 0, 0, 0, 0, 0, 0]);
    send(&mut node, &mut sink, ms(2), [0x11, 9, 0, 0, 0, 0, 0, 0]);
    send(&mut node, &mut sink, ms(2), [0x17, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(
        answers(&mut sink),
        [[0x11, 0, 0, 0, 0, 0, 0, 0], [0x17, 0, 0, 0, 0, 0, 0, 0]]
    );
    send(&mut node, &mut sink, ms(2), [0x04, 0, 0, 0, 0, 0, 0, 0]);
    // Still node 5, still validated, until the reset.
    assert_eq!(node.safety_config().configuration_valid, 0xA5);
    node.handle_frame(
        ms(3),
        &nmt::command_frame(NmtCommand::ResetCommunication, 5),
        &mut sink,
    );
    assert_eq!(boot_ups(&sink), [9]);
    assert!(sink.events.contains(&Event::ValidatedForAnotherNodeId {
        validated_for: id(5)
    }));
    assert_ne!(node.safety_config().configuration_valid, 0xA5);
    // Power cycle: node 9 from the stored LSS settings, the configuration still not valid.
    let (node, sink) = started(node.flash().clone(), None, |_| {});
    assert_eq!(boot_ups(&sink), [9]);
    assert!(sink.events.contains(&Event::ValidatedForAnotherNodeId {
        validated_for: id(5)
    }));
    assert_ne!(node.safety_config().configuration_valid, 0xA5);
    // Switched back to 5, it is valid again: the stored parameters were never touched.
    let mut back = node.flash().clone();
    let (mut node, mut sink) = started(&mut back, None, |_| {});
    send(&mut node, &mut sink, ms(1), [0x04, 1, 0, 0, 0, 0, 0, 0]);
    send(&mut node, &mut sink, ms(1), [0x11, 5, 0, 0, 0, 0, 0, 0]);
    send(&mut node, &mut sink, ms(1), [0x17, 0, 0, 0, 0, 0, 0, 0]);
    drop(node);
    let (node, sink) = started(back, None, |_| {});
    assert_eq!(boot_ups(&sink), [5]);
    assert!(sink.events.contains(&Event::ParametersRestored));
    assert_eq!(node.safety_config().configuration_valid, 0xA5);
}

/// Safety rule 1: a node in Operational answers no switch into the configuration state and
/// logs every refusal; entering Operational leaves the configuration state.
#[test]
fn cia305_fig31_fig32_rule_1_a_node_in_operational_is_not_configured_and_logs_the_refusal() {
    let (mut node, mut sink) = started(Medium::new(), Some(id(7)), |_| {});
    for record in node.core.protocol.safety.srdos.iter_mut() {
        record.signature = signature::compute(record);
    }
    node.core.protocol.safety.configuration_valid = 0xA5;
    send(&mut node, &mut sink, ms(1), [0x04, 1, 0, 0, 0, 0, 0, 0]);
    assert_eq!(node.lss().map(Lss::state), Some(LssState::Configuration));
    sink.events.clear();
    node.handle_frame(ms(2), &nmt::command_frame(NmtCommand::Start, 0), &mut sink);
    assert_eq!(node.nmt_state(), NmtState::Operational);
    assert_eq!(
        lss_events(&sink),
        [LssEvent::ConfigurationLeftForOperational]
    );
    assert_eq!(node.lss().map(Lss::state), Some(LssState::Waiting));
    sink.events.clear();
    sink.frames.clear();
    send(&mut node, &mut sink, ms(3), [0x04, 1, 0, 0, 0, 0, 0, 0]);
    for (part, command) in (0x40..=0x43).enumerate() {
        let [a, b, c, d] = IDENTITY[part].to_le_bytes();
        send(&mut node, &mut sink, ms(3), [command, a, b, c, d, 0, 0, 0]);
    }
    send(&mut node, &mut sink, ms(3), [0x11, 9, 0, 0, 0, 0, 0, 0]);
    assert!(answers(&mut sink).is_empty());
    assert_eq!(
        lss_events(&sink),
        [
            LssEvent::RefusedInOperational { specifier: 0x04 },
            LssEvent::RefusedInOperational { specifier: 0x43 }
        ]
    );
    assert_eq!(node.lss().map(Lss::state), Some(LssState::Waiting));
    assert_eq!(node.lss().and_then(Lss::pending), None);
    assert_eq!(node.nmt_state(), NmtState::Operational);
}

/// Safety rule 3: with the switches set, their node-ID is the node's whatever LSS stored.
#[test]
fn cia305_fig33_rule_3_the_switches_win_over_the_stored_lss_node_id() {
    let (node, _) = assigned(Medium::new(), 40);
    let (mut node, mut sink) = started(node.flash().clone(), Some(id(3)), |_| {});
    assert_eq!(boot_ups(&sink), [3]);
    assert_eq!(
        lss_events(&sink),
        [LssEvent::SwitchesWin {
            switches: id(3),
            stored: Some(id(40))
        }]
    );
    assert_eq!(node.lss().map(Lss::source), Some(NodeIdSource::Switches));
    sink.frames.clear();
    send(&mut node, &mut sink, ms(1), [0x04, 1, 0, 0, 0, 0, 0, 0]);
    send(&mut node, &mut sink, ms(1), [0x11, 9, 0, 0, 0, 0, 0, 0]);
    assert_eq!(
        answers(&mut sink),
        [[0x11, 0xFF, lss::SWITCHES_SET, 0, 0, 0, 0, 0]]
    );
    node.handle_frame(
        ms(2),
        &nmt::command_frame(NmtCommand::ResetCommunication, 3),
        &mut sink,
    );
    assert_eq!(boot_ups(&sink), [3]);
}

/// CiA 305 Fig. 36: store configuration puts the LSS settings in the stored record beside the
/// parameters; a power cycle finds both; 0x1010 and 0x1011 keep the LSS settings.
#[test]
fn cia305_fig36_store_configuration_keeps_the_parameters_and_survives_a_power_cycle() {
    let (mut node, mut sink) = assigned(Medium::new(), 20);
    assert_eq!(
        sdo_write(&mut node, &mut sink, 20, 0x1017, 0, &[250, 0])[0],
        0x60
    );
    assert_eq!(
        sdo_write(&mut node, &mut sink, 20, 0x1010, 1, b"save")[0],
        0x60
    );
    send(&mut node, &mut sink, ms(1), [0x04, 1, 0, 0, 0, 0, 0, 0]);
    send(&mut node, &mut sink, ms(1), [0x13, 0, 3, 0, 0, 0, 0, 0]);
    send(&mut node, &mut sink, ms(1), [0x17, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(
        answers(&mut sink),
        [[0x13, 0, 0, 0, 0, 0, 0, 0], [0x17, 0, 0, 0, 0, 0, 0, 0]]
    );
    let settings = LssSettings {
        node_id: Some(id(20)),
        bit_rate: Some(BitRate::Kbit250),
    };
    assert!(lss_events(&sink).contains(&LssEvent::Stored(settings)));
    // Power cycle.
    let (mut node, mut sink) = started(node.flash().clone(), None, |_| {});
    assert_eq!(boot_ups(&sink), [20]);
    assert!(sink.events.contains(&Event::ParametersRestored));
    assert_eq!(
        node.core.heartbeat.period_ms(),
        250,
        "the parameters are intact"
    );
    assert_eq!(node.lss().and_then(Lss::bit_rate), Some(BitRate::Kbit250));
    // 0x1010 again, then 0x1011: the LSS settings stay.
    assert_eq!(
        sdo_write(&mut node, &mut sink, 20, 0x1010, 1, b"save")[0],
        0x60
    );
    let (mut node, mut sink) = started(node.flash().clone(), None, |_| {});
    assert_eq!(boot_ups(&sink), [20]);
    assert_eq!(
        sdo_write(&mut node, &mut sink, 20, 0x1011, 1, b"load")[0],
        0x60
    );
    let (node, sink) = started(node.flash().clone(), None, |_| {});
    assert_eq!(boot_ups(&sink), [20]);
    assert!(
        !sink.events.contains(&Event::ParametersRestored),
        "defaults after 0x1011"
    );
    assert_eq!(node.core.heartbeat.period_ms(), 0);
    assert_eq!(node.lss().and_then(Lss::bit_rate), Some(BitRate::Kbit250));
}

/// A medium whose erases and writes fail while `failing` is set.
#[derive(Clone, Debug)]
struct FailingFlash {
    inner: Medium,
    failing: bool,
}

impl Flash for FailingFlash {
    fn slot_len(&self) -> usize {
        self.inner.slot_len()
    }
    fn erase_stalls(&self) -> bool {
        self.inner.erase_stalls()
    }
    fn read(&mut self, slot: Slot, offset: usize, buf: &mut [u8]) -> Result<(), StorageError> {
        self.inner.read(slot, offset, buf)
    }
    fn erase(&mut self, slot: Slot) -> Result<(), StorageError> {
        if self.failing {
            return Err(StorageError::Medium);
        }
        self.inner.erase(slot)
    }
    fn write(&mut self, slot: Slot, offset: usize, data: &[u8]) -> Result<(), StorageError> {
        if self.failing {
            return Err(StorageError::Medium);
        }
        self.inner.write(slot, offset, data)
    }
}

/// CiA 305 Fig. 36: a store the medium fails is answered with error code 2 and leaves what
/// was stored in force.
#[test]
fn cia305_fig36_a_failed_store_answers_2_and_keeps_what_was_stored() {
    let flash = FailingFlash {
        inner: Medium::new(),
        failing: false,
    };
    let (mut node, mut sink) = assigned(flash, 20);
    node.flash_mut().failing = true;
    send(&mut node, &mut sink, ms(1), [0x04, 1, 0, 0, 0, 0, 0, 0]);
    send(&mut node, &mut sink, ms(1), [0x11, 30, 0, 0, 0, 0, 0, 0]);
    send(&mut node, &mut sink, ms(1), [0x17, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(
        answers(&mut sink),
        [[0x11, 0, 0, 0, 0, 0, 0, 0], [0x17, 2, 0, 0, 0, 0, 0, 0]]
    );
    assert!(
        lss_events(&sink).contains(&LssEvent::StoreFailed(StoreFailure::Failed(
            StorageError::Medium
        )))
    );
    let mut flash = node.flash().clone();
    flash.failing = false;
    let (node, sink) = started(flash, None, |_| {});
    assert_eq!(boot_ups(&sink), [20], "the node-ID stored before");
    assert_eq!(node.lss().and_then(Lss::pending), Some(id(20)));
}

/// CiA 305 Fig. 36: a stored record this firmware cannot read is not rewritten by store
/// configuration (it would hide the damage the node reported): error code 2.
#[test]
fn cia305_fig36_store_over_an_unreadable_record_answers_2() {
    let mut flash = Medium::new();
    crate::canopen::storage::store(&mut flash, &[9, 1, 0, 4]).unwrap();
    let (mut node, mut sink) = started(flash, None, |_| {});
    assert!(
        sink.events
            .iter()
            .any(|e| matches!(e, Event::StoredParametersRejected(_)))
    );
    send(&mut node, &mut sink, ms(1), [0x04, 1, 0, 0, 0, 0, 0, 0]);
    send(&mut node, &mut sink, ms(1), [0x11, 30, 0, 0, 0, 0, 0, 0]);
    send(&mut node, &mut sink, ms(1), [0x17, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(
        answers(&mut sink),
        [[0x11, 0, 0, 0, 0, 0, 0, 0], [0x17, 2, 0, 0, 0, 0, 0, 0]]
    );
}

/// Safety rule 4: from activate bit timing the node sends nothing (not even its heartbeat)
/// for the switch delay, reports the new bit rate, and sends nothing for the delay again.
#[test]
fn cia305_fig35_rule_4_the_node_sends_nothing_around_a_bit_rate_switch() {
    let (mut node, mut sink) = started(Medium::new(), Some(id(7)), |c| c.heartbeat_ms = 50);
    sink.frames.clear();
    send(&mut node, &mut sink, ms(10), [0x04, 1, 0, 0, 0, 0, 0, 0]);
    send(&mut node, &mut sink, ms(10), [0x13, 0, 3, 0, 0, 0, 0, 0]);
    assert_eq!(answers(&mut sink), [[0x13, 0, 0, 0, 0, 0, 0, 0]]);
    let [low, high] = 200u16.to_le_bytes();
    send(
        &mut node,
        &mut sink,
        ms(20),
        [0x15, low, high, 0, 0, 0, 0, 0],
    );
    sink.events.clear();
    let mut heartbeats = Vec::new();
    let mut switched_at = None;
    let mut now = ms(20);
    while now < ms(800) {
        let next = node.poll(now, &mut sink);
        for frame in sink.frames.drain(..) {
            heartbeats.push((now.as_micros() / 1000, frame.id().raw()));
        }
        if lss_events(&sink).contains(&LssEvent::SwitchBitRate(BitRate::Kbit250)) {
            switched_at.get_or_insert(now);
        }
        sink.events.clear();
        now = next
            .min(now + Duration::from_millis(5))
            .max(now + Duration::from_micros(1));
    }
    assert_eq!(switched_at, Some(ms(220)));
    assert!(
        heartbeats
            .iter()
            .all(|&(at, id)| id == 0x707 && !(20..420).contains(&at)),
        "{heartbeats:?}"
    );
    assert!(
        heartbeats.iter().any(|&(at, _)| at >= 420),
        "the heartbeat resumes"
    );
    // Requests in the silence get no answer either.
    let (mut node, mut sink) = started(Medium::new(), Some(id(7)), |_| {});
    send(&mut node, &mut sink, ms(10), [0x04, 1, 0, 0, 0, 0, 0, 0]);
    send(&mut node, &mut sink, ms(10), [0x13, 0, 3, 0, 0, 0, 0, 0]);
    send(
        &mut node,
        &mut sink,
        ms(20),
        [0x15, low, high, 0, 0, 0, 0, 0],
    );
    sink.frames.clear();
    send(&mut node, &mut sink, ms(100), [0x5E, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(sdo_silence(&mut node, &mut sink), 0);
    assert!(sink.frames.is_empty());
}

/// SDO requests during the silence: the number answered.
fn sdo_silence(node: &mut TestNode, sink: &mut Recorder) -> usize {
    let request = CanFrame::new(
        CanId::new(0x607).unwrap(),
        &[0x40, 0x17, 0x10, 0, 0, 0, 0, 0],
    );
    node.handle_frame(ms(150), &request.unwrap(), sink);
    sink.frames.len()
}

/// A frame that is not 8 bytes long, or an unknown specifier, changes nothing in a device.
#[test]
fn cia305_bad_frames_change_nothing_in_a_device() {
    let (mut node, mut sink) = started(Medium::new(), None, |_| {});
    for len in 0..8 {
        let frame = CanFrame::new(lss::MASTER_TO_SLAVE, &[0x51, 0, 0, 0, 0, 0x80, 0, 0][..len]);
        node.handle_frame(ms(1), &frame.unwrap(), &mut sink);
    }
    send(&mut node, &mut sink, ms(1), [0x99, 1, 0, 0, 0, 0, 0, 0]);
    assert!(sink.frames.is_empty());
    assert_eq!(node.configured_node_id(), None);
    assert_eq!(node.lss().map(Lss::state), Some(LssState::Waiting));
}

#[test]
fn lss_is_enabled_once_and_only_before_the_first_poll() {
    let mut node = TestNode::new(config(1), Medium::new()).unwrap();
    let mut sink = Recorder::default();
    let _ = node.poll(Instant::ZERO, &mut sink);
    assert!(!node.enable_lss(None, RATES));
    assert!(node.lss().is_none());
    assert_eq!(node.configured_node_id(), Some(id(1)));
    let mut node = TestNode::new(config(1), Medium::new()).unwrap();
    assert!(node.enable_lss(Some(id(2)), RATES));
    assert!(!node.enable_lss(Some(id(3)), RATES));
    assert_eq!(node.node_id(), id(2));
}
