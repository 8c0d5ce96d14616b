//! Tests of a whole node through its frame interface, each naming the clause it verifies.

use super::*;
use crate::canopen::emcy::code;
use crate::canopen::od::ObjectDictionary;
use crate::canopen::storage::RamFlash;
use crate::node::srdo_table::SrdoRuntime;
use crate::process_image::{Access, Mappable};
use crate::safety::config::{ConfigError, SrdoRecord};
use crate::safety::signature;
use crate::safety::srdo::{self, SrdoFaultCause};
use std::vec::Vec as StdVec;

/// A sink that records everything.
#[derive(Default)]
pub(crate) struct Recorder {
    pub frames: StdVec<CanFrame>,
    pub events: StdVec<Event>,
}

impl Sink for Recorder {
    fn transmit(&mut self, frame: CanFrame) {
        self.frames.push(frame);
    }
    fn event(&mut self, event: Event) {
        self.events.push(event);
    }
}

impl Recorder {
    fn take(&mut self) -> (StdVec<CanFrame>, StdVec<Event>) {
        (
            core::mem::take(&mut self.frames),
            core::mem::take(&mut self.events),
        )
    }
    pub(crate) fn emergencies(&self) -> StdVec<Emergency> {
        self.frames
            .iter()
            .filter(|f| (0x081..=0x0FF).contains(&f.id().raw()))
            .filter_map(|f| Emergency::parse(f.data()))
            .collect()
    }
}

const fn object(index: u16, sub: u8, len: u8, access: Access, mappable: Mappable) -> AppObject {
    AppObject {
        address: Address::new(index, sub),
        len,
        access,
        mappable,
    }
}

/// Two safety inputs with inverted copies, two safety outputs with inverted copies, and a
/// 16-bit value, plus a read-write parameter that cannot be mapped.
static OBJECTS: [AppObject; 10] = [
    object(0x6000, 1, 1, Access::ReadOnly, Mappable::Transmit),
    object(0x6000, 2, 1, Access::ReadOnly, Mappable::Transmit),
    object(0x6001, 1, 1, Access::ReadOnly, Mappable::Transmit),
    object(0x6001, 2, 1, Access::ReadOnly, Mappable::Transmit),
    object(0x6200, 1, 1, Access::ReadOnly, Mappable::Receive),
    object(0x6200, 2, 1, Access::ReadOnly, Mappable::Receive),
    object(0x6201, 1, 1, Access::ReadOnly, Mappable::Receive),
    object(0x6201, 2, 1, Access::ReadOnly, Mappable::Receive),
    object(0x6100, 1, 2, Access::ReadOnly, Mappable::Transmit),
    object(0x2000, 1, 2, Access::ReadWrite, Mappable::No),
];
static TX_MAPPING: [u32; 2] = [0x6000_0108, 0x6001_0108];
static RX_MAPPING: [u32; 2] = [0x6200_0108, 0x6201_0108];

pub(crate) fn config(node_id: u8) -> NodeConfig {
    NodeConfig {
        node_id: NodeId::new(node_id).unwrap(),
        device_type: 0x0001_0191,
        device_name: "dual-channel safety node (test)",
        identity: [0x1234, 0x5678, 1, 42],
        app_objects: &OBJECTS,
        default_transmit_mapping: &TX_MAPPING,
        default_receive_mapping: &RX_MAPPING,
        heartbeat_ms: 0,
        sdo_timeout: Duration::from_millis(500),
        event_driven: false,
        gfc_on_fault: false,
    }
}

type TestNode = Node<RamFlash<8192>, 4>;

const fn ms(value: u64) -> Instant {
    Instant::from_millis(value)
}
const fn us(value: u64) -> Instant {
    Instant::from_micros(value)
}

/// A booted node (Pre-operational), with whatever the caller did to its configuration.
fn booted(node_id: u8, configure: impl FnOnce(&mut NodeConfig)) -> (TestNode, Recorder) {
    let mut config = config(node_id);
    configure(&mut config);
    let mut node = TestNode::new(config, RamFlash::new()).unwrap();
    let mut sink = Recorder::default();
    node.poll(Instant::ZERO, &mut sink);
    sink.take();
    (node, sink)
}

/// Declares the current configuration valid the way a tool does: signatures, then A5h.
fn validate(node: &mut TestNode) {
    for record in node.core.protocol.safety.srdos.iter_mut() {
        record.signature = signature::compute(record);
    }
    node.core.protocol.safety.configuration_valid = 0xA5;
}

fn start(node: &mut TestNode, now: Instant, sink: &mut Recorder) {
    node.handle_frame(now, &nmt::command_frame(NmtCommand::Start, 0), sink);
}

/// A booted, validated node with the pre-defined configuration, started at t = 0.
fn operational(node_id: u8) -> (TestNode, Recorder) {
    let (mut node, mut sink) = booted(node_id, |_| {});
    validate(&mut node);
    start(&mut node, Instant::ZERO, &mut sink);
    assert_eq!(node.nmt_state(), NmtState::Operational);
    sink.take();
    (node, sink)
}

fn frame(id: u16, data: &[u8]) -> CanFrame {
    CanFrame::new(CanId::new(id).unwrap(), data).unwrap()
}

fn output(node: &TestNode, index: u16, sub: u8) -> u8 {
    let mut buf = [0u8; 8];
    node.read_object(Address::new(index, sub), &mut buf)
        .unwrap();
    buf[0]
}

/// Sends a valid SRDO pair for node 33's SRDO 1 (COB-IDs 0x141/0x142).
fn pair(node: &mut TestNode, at: Instant, value: u8, sink: &mut Recorder) {
    node.handle_frame(at, &frame(0x141, &[value]), sink);
    node.handle_frame(
        at + Duration::from_micros(200),
        &frame(0x142, &[!value]),
        sink,
    );
}

// ---- NMT, boot-up, heartbeat --------------------------------------------------------------

#[test]
fn cia301_7_3_2_boot_up_then_pre_operational() {
    let mut node = TestNode::new(config(5), RamFlash::new()).unwrap();
    assert_eq!(node.nmt_state(), NmtState::Initialising);
    let mut sink = Recorder::default();
    node.poll(Instant::ZERO, &mut sink);
    assert_eq!(sink.frames, [frame(0x705, &[0])]);
    assert_eq!(sink.events, [Event::NmtState(NmtState::PreOperational)]);
}

#[test]
fn cia301_7_2_8_3_2_heartbeat_reports_the_nmt_state() {
    let (mut node, mut sink) = booted(5, |config| config.heartbeat_ms = 100);
    assert_eq!(node.poll(ms(50), &mut sink), ms(100));
    assert!(sink.frames.is_empty());
    node.poll(ms(100), &mut sink);
    assert_eq!(sink.frames, [frame(0x705, &[0x7F])]);
}

#[test]
fn cia301_7_2_8_3_1_nmt_commands_for_other_nodes_are_ignored_and_malformed_ones_reported() {
    let (mut node, mut sink) = booted(5, |_| {});
    node.handle_frame(ms(1), &nmt::command_frame(NmtCommand::Stop, 6), &mut sink);
    assert_eq!(node.nmt_state(), NmtState::PreOperational);
    node.handle_frame(ms(1), &frame(0x000, &[0x02]), &mut sink);
    assert_eq!(sink.events, [Event::NmtRefused(NmtError::Malformed)]);
    node.handle_frame(ms(1), &nmt::command_frame(NmtCommand::Stop, 5), &mut sink);
    assert_eq!(node.nmt_state(), NmtState::Stopped);
}

// ---- Entering Operational ----------------------------------------------------------------

#[test]
fn en50325_5_6_4_1_6_not_validated_configuration_keeps_the_node_out_of_operational() {
    let (mut node, mut sink) = booted(1, |_| {});
    start(&mut node, ms(1), &mut sink);
    assert_eq!(node.nmt_state(), NmtState::PreOperational);
    assert!(!node.is_working());
    let fault = ConfigFault {
        srdo: None,
        error: ConfigError::NotDeclaredValid,
    };
    assert_eq!(sink.events, [Event::ConfigurationRefused(fault)]);
    let emcy = sink.emergencies();
    assert_eq!(emcy.len(), 1);
    assert_eq!(emcy[0].code, code::DATA_SET);
    assert_eq!(
        emcy[0].detail[..2],
        [0, ConfigError::NotDeclaredValid.cause_code()]
    );
    // No SRDO runs: nothing is sent, however long we wait.
    sink.take();
    node.poll(ms(1_000), &mut sink);
    assert!(sink.frames.is_empty());
}

#[test]
fn en50325_5_8_3_1_signature_mismatch_names_the_srdo_and_the_cause() {
    let (mut node, mut sink) = booted(1, |_| {});
    validate(&mut node);
    node.core.protocol.safety.srdos[0].signature ^= 1;
    start(&mut node, ms(1), &mut sink);
    assert_eq!(node.nmt_state(), NmtState::PreOperational);
    let srdo_1 = SrdoNumber::new(1).unwrap();
    let fault = ConfigFault {
        srdo: Some(srdo_1),
        error: ConfigError::SignatureMismatch,
    };
    assert_eq!(sink.events, [Event::ConfigurationRefused(fault)]);
    assert_eq!(
        sink.emergencies()[0].detail[..2],
        [1, ConfigError::SignatureMismatch.cause_code()]
    );
}

#[test]
fn cia304_9_5_configuration_damaged_after_validation_is_caught_on_the_way_into_operational() {
    let (mut node, mut sink) = booted(1, |_| {});
    validate(&mut node);
    // A bit flip in RAM that keeps the signature consistent but breaks a rule (refresh 0).
    node.core.protocol.safety.srdos[0].cycle_time = 0;
    node.core.protocol.safety.srdos[0].signature =
        signature::compute(&node.core.protocol.safety.srdos[0]);
    start(&mut node, ms(1), &mut sink);
    assert_eq!(node.nmt_state(), NmtState::PreOperational);
    let fault = ConfigFault {
        srdo: SrdoNumber::new(1),
        error: ConfigError::CycleTimeZero,
    };
    assert_eq!(sink.events, [Event::ConfigurationRefused(fault)]);
}

// ---- Producer -----------------------------------------------------------------------------

#[test]
fn cia304_9_5_and_en50325_5_7_1_1_producer_sends_plain_then_inverted_after_node_id_delay() {
    let (mut node, mut sink) = operational(3);
    node.set_transmit_payloads(SrdoNumber::new(1).unwrap(), &[0x5A], &[0xA5])
        .unwrap();
    // First cyclic transmission 0.5 ms × 3 after start.
    assert_eq!(node.poll(us(1_000), &mut sink), us(1_500));
    assert!(sink.frames.is_empty());
    // The next poll may come earlier (the integrity check's period), never later.
    assert!(node.poll(us(1_500), &mut sink) <= us(26_500));
    assert_eq!(sink.frames, [frame(0x105, &[0x5A]), frame(0x106, &[0xA5])]);
    // The next pair a refresh time later, not before.
    sink.frames.clear();
    let _ = node.poll(us(26_499), &mut sink);
    assert!(sink.frames.is_empty());
    let _ = node.poll(us(26_500), &mut sink);
    assert_eq!(sink.frames, [frame(0x105, &[0x5A]), frame(0x106, &[0xA5])]);
}

#[test]
fn en50325_5_8_2_2_no_srdo_is_sent_outside_operational() {
    let (mut node, mut sink) = operational(3);
    node.set_transmit_payloads(SrdoNumber::new(1).unwrap(), &[1], &[0xFE])
        .unwrap();
    node.handle_frame(
        ms(1),
        &nmt::command_frame(NmtCommand::EnterPreOperational, 3),
        &mut sink,
    );
    sink.take();
    node.poll(ms(500), &mut sink);
    assert!(sink.frames.is_empty());
}

#[test]
fn en50325_5_7_1_1_halves_that_are_not_inverses_are_never_sent() {
    let (mut node, mut sink) = operational(3);
    let srdo = SrdoNumber::new(1).unwrap();
    node.set_transmit_half(srdo, &[0x5A], false).unwrap();
    node.set_transmit_half(srdo, &[0x5B], true).unwrap();
    node.poll(ms(2), &mut sink);
    assert!(
        sink.frames
            .iter()
            .all(|f| f.id().raw() != 0x105 && f.id().raw() != 0x106)
    );
    let fault = SrdoFault {
        srdo,
        cause: SrdoFaultCause::TransmitHalvesNotInverted,
    };
    assert!(sink.events.contains(&Event::SrdoFault(fault)));
    assert_eq!(node.fault(), Some(SafeStateCause::Srdo(fault)));
    assert_eq!(sink.emergencies()[0].code, code::INTERNAL_SOFTWARE);
    // Even after the halves are mended, the producer stays silent until reset.
    node.set_transmit_half(srdo, &[0xA5], true).unwrap();
    sink.take();
    node.poll(ms(100), &mut sink);
    assert!(sink.frames.is_empty());
}

#[test]
fn en50325_5_6_2_1_event_driven_transmission_on_a_change_of_mapped_data() {
    let (mut node, mut sink) = booted(3, |config| config.event_driven = true);
    validate(&mut node);
    start(&mut node, Instant::ZERO, &mut sink);
    let srdo = SrdoNumber::new(1).unwrap();
    node.set_transmit_payloads(srdo, &[0], &[0xFF]).unwrap();
    node.poll(ms(2), &mut sink);
    sink.take();
    node.set_transmit_payloads(srdo, &[1], &[0xFE]).unwrap();
    node.poll(ms(10), &mut sink);
    assert_eq!(sink.frames, [frame(0x105, &[1]), frame(0x106, &[0xFE])]);
}

#[test]
fn en50325_5_6_2_1_srdo_is_never_answered_on_rtr() {
    let (mut node, mut sink) = operational(3);
    node.set_transmit_payloads(SrdoNumber::new(1).unwrap(), &[1], &[0xFE])
        .unwrap();
    node.poll(ms(2), &mut sink);
    sink.take();
    node.handle_frame(
        ms(3),
        &CanFrame::remote(CanId::new(0x105).unwrap(), 1).unwrap(),
        &mut sink,
    );
    assert!(sink.frames.is_empty());
    assert_eq!(node.remote_frames_ignored(), 1);
}

// ---- Consumer -----------------------------------------------------------------------------

#[test]
fn en50325_5_6_2_2_a_valid_pair_is_delivered_and_signalled() {
    let (mut node, mut sink) = operational(33);
    pair(&mut node, ms(10), 0x3C, &mut sink);
    assert_eq!(
        sink.events,
        [Event::SrdoReceived {
            srdo: SrdoNumber::new(1).unwrap(),
            data: 0x3C
        }]
    );
    assert_eq!(
        (output(&node, 0x6200, 1), output(&node, 0x6201, 1)),
        (0x3C, 0xC3)
    );
    assert!(node.is_working());
}

fn assert_safe(node: &TestNode, sink: &Recorder, cause: SrdoFaultCause, emcy_code: u16) {
    let fault = SrdoFault {
        srdo: SrdoNumber::new(1).unwrap(),
        cause,
    };
    assert_eq!(node.fault(), Some(SafeStateCause::Srdo(fault)));
    assert!(sink.events.contains(&Event::SrdoFault(fault)));
    assert!(
        sink.events
            .contains(&Event::SafeState(SafeStateCause::Srdo(fault)))
    );
    assert_eq!(
        (output(node, 0x6200, 1), output(node, 0x6201, 1)),
        (0, 0),
        "SC_REQ_05: outputs 0"
    );
    let emcy = sink.emergencies();
    assert_eq!(emcy.len(), 1, "one EMCY");
    assert_eq!(emcy[0].code, emcy_code);
    assert_eq!(emcy[0].detail[..2], [1, cause.cause_code()]);
    assert!(!node.is_working());
}

#[test]
fn en50325_5_7_1_2_sct_event_fires_at_the_deadline_itself() {
    let (mut node, mut sink) = operational(33);
    pair(&mut node, ms(10), 0x3C, &mut sink);
    sink.take();
    // SCT 50 ms from the completed pair at 10.2 ms: due at 60.2 ms exactly.
    let deadline = node.poll(ms(20), &mut sink);
    assert!(deadline <= us(60_200));
    let mut now = deadline;
    while now < us(60_200) {
        now = node.poll(now, &mut sink);
    }
    assert_eq!(
        now,
        us(60_200),
        "the node asks to be polled at the SCT deadline itself"
    );
    assert!(node.is_working(), "not yet failed before the deadline");
    node.poll(now, &mut sink);
    assert_safe(&node, &sink, SrdoFaultCause::SctElapsed, code::RPDO_TIMEOUT);
}

#[test]
fn en50325_5_7_1_2_first_pair_is_due_within_sct_of_entering_operational() {
    let (mut node, mut sink) = operational(33);
    node.poll(ms(50), &mut sink);
    assert_safe(&node, &sink, SrdoFaultCause::SctElapsed, code::RPDO_TIMEOUT);
}

#[test]
fn en50325_5_7_1_2_srvt_event() {
    let (mut node, mut sink) = operational(33);
    node.handle_frame(ms(10), &frame(0x141, &[1]), &mut sink);
    assert_eq!(
        node.poll(ms(11), &mut sink),
        ms(30),
        "SRVT deadline 20 ms after the plain frame"
    );
    node.poll(ms(30), &mut sink);
    assert_safe(
        &node,
        &sink,
        SrdoFaultCause::SrvtElapsed,
        code::RPDO_TIMEOUT,
    );
}

#[test]
fn en50325_5_7_1_2_a_late_inverted_frame_is_refused_even_before_the_timer_is_polled() {
    let (mut node, mut sink) = operational(33);
    node.handle_frame(ms(10), &frame(0x141, &[1]), &mut sink);
    node.handle_frame(ms(31), &frame(0x142, &[0xFE]), &mut sink);
    assert_safe(
        &node,
        &sink,
        SrdoFaultCause::SrvtElapsed,
        code::RPDO_TIMEOUT,
    );
}

/// ISO 11898-1 double reception, or a consumer that started monitoring between a producer's
/// plain and inverted frames: an inverted frame with no plain frame pending is discarded and
/// counted, and the valid pair that follows is delivered.
#[test]
fn iso11898_1_double_reception_an_inverted_frame_without_plain_is_discarded_and_counted() {
    let (mut node, mut sink) = operational(33);
    node.handle_frame(ms(10), &frame(0x142, &[0xFE]), &mut sink);
    assert!(node.is_working(), "no fault for a lone inverted frame");
    assert!(sink.emergencies().is_empty());
    assert_eq!(output(&node, 0x6200, 1), 0, "nothing delivered");
    assert_eq!(node.srdo_pairs(SrdoNumber::new(1).unwrap()), 0);
    pair(&mut node, ms(20), 0x5A, &mut sink);
    assert!(node.is_working());
    assert_eq!(
        output(&node, 0x6200, 1),
        0x5A,
        "the following valid pair is delivered"
    );
    assert_eq!(node.srdo_pairs(SrdoNumber::new(1).unwrap()), 1);
    // The inverted frame of a completed pair received twice: the copy is discarded too.
    node.handle_frame(ms(21), &frame(0x142, &[!0x5A]), &mut sink);
    assert!(node.is_working());
    assert_eq!(
        node.srdo_pairs(SrdoNumber::new(1).unwrap()),
        1,
        "delivered once"
    );
    assert_eq!(
        node.double_reception(),
        DoubleReception {
            plain_repeated: 0,
            inverted_without_plain: 2,
        }
    );
}

/// The double-reception counters are readable in the manufacturer area (object 5C00h,
/// read-only), so an assessor sees how often it happened; NMT reset communication clears
/// them.
#[test]
fn iso11898_1_double_reception_counters_are_readable_in_object_5c00() {
    let (mut node, mut sink) = operational(33);
    node.handle_frame(ms(1), &frame(0x142, &[0xFE]), &mut sink);
    node.handle_frame(ms(10), &frame(0x141, &[1]), &mut sink);
    for _ in 0..3 {
        node.handle_frame(ms(10), &frame(0x141, &[1]), &mut sink);
    }
    node.handle_frame(ms(11), &frame(0x142, &[0xFE]), &mut sink);
    assert!(node.is_working());
    let discarded = |srdo, discarded| Event::FrameDiscarded {
        srdo: SrdoNumber::new(srdo).unwrap(),
        discarded,
    };
    assert_eq!(
        sink.events
            .iter()
            .filter(|e| **e == discarded(1, srdo::Discarded::PlainRepeated))
            .count(),
        3
    );
    assert!(
        sink.events
            .contains(&discarded(1, srdo::Discarded::InvertedWithoutPlain))
    );
    let mut buf = [0u8; 8];
    let index = DOUBLE_RECEPTION_INDEX;
    assert_eq!(node.core.read(Address::new(index, 0), &mut buf), Ok(1));
    assert_eq!(buf[0], 2);
    assert_eq!(node.core.read(Address::new(index, 1), &mut buf), Ok(4));
    assert_eq!(u32::from_le_bytes(buf[..4].try_into().unwrap()), 3);
    assert_eq!(node.core.read(Address::new(index, 2), &mut buf), Ok(4));
    assert_eq!(u32::from_le_bytes(buf[..4].try_into().unwrap()), 1);
    assert_eq!(
        node.core.read(Address::new(index, 3), &mut buf),
        Err(AbortCode::NoSubIndex)
    );
    assert_eq!(
        node.core.write(Address::new(index, 1), &[0, 0, 0, 0]),
        Err(AbortCode::ReadOnly)
    );
    node.handle_frame(
        ms(12),
        &nmt::command_frame(NmtCommand::ResetCommunication, 0),
        &mut sink,
    );
    assert_eq!(node.double_reception(), DoubleReception::default());
}

/// When no valid pair follows a discarded inverted frame, SCT fires as usual (EN 50325-5
/// 7.1.2): the discard does not restart SCT.
#[test]
fn en50325_5_7_1_2_a_discarded_inverted_frame_does_not_restart_sct() {
    let (mut node, mut sink) = operational(33);
    node.handle_frame(ms(40), &frame(0x142, &[0xFE]), &mut sink);
    assert!(node.is_working());
    node.poll(ms(50), &mut sink);
    assert_safe(&node, &sink, SrdoFaultCause::SctElapsed, code::RPDO_TIMEOUT);
}

/// ISO 11898-1 double reception of a plain frame: the exact repeat (same identifier, same
/// data) is discarded and counted; the pair completes with its inverted frame and is
/// delivered once.
#[test]
fn iso11898_1_double_reception_an_exact_repeat_of_the_plain_frame_is_discarded_and_counted() {
    let (mut node, mut sink) = operational(33);
    node.handle_frame(ms(10), &frame(0x141, &[1]), &mut sink);
    node.handle_frame(ms(11), &frame(0x141, &[1]), &mut sink);
    assert!(node.is_working(), "no fault for an exact repeat");
    node.handle_frame(ms(12), &frame(0x142, &[0xFE]), &mut sink);
    assert!(node.is_working());
    assert_eq!(output(&node, 0x6200, 1), 1);
    let delivered = sink
        .events
        .iter()
        .filter(|e| matches!(e, Event::SrdoReceived { .. }))
        .count();
    assert_eq!(delivered, 1, "delivered once");
    assert_eq!(
        node.double_reception(),
        DoubleReception {
            plain_repeated: 1,
            inverted_without_plain: 0,
        }
    );
}

/// A discarded repeat of the plain frame keeps the SRVT of the first copy (EN 50325-5 7.1.2):
/// when the inverted frame does not follow, SRVT fires 20 ms after the first copy.
#[test]
fn en50325_5_7_1_2_a_repeated_plain_frame_keeps_the_srvt_of_the_first() {
    let (mut node, mut sink) = operational(33);
    node.handle_frame(ms(10), &frame(0x141, &[1]), &mut sink);
    node.handle_frame(ms(25), &frame(0x141, &[1]), &mut sink);
    assert!(node.is_working());
    node.poll(ms(30), &mut sink);
    assert_safe(
        &node,
        &sink,
        SrdoFaultCause::SrvtElapsed,
        code::RPDO_TIMEOUT,
    );
}

/// CiA 304 9.5: a second plain frame with *different* data (or another length) before the
/// inverted one is a sequence error once a pair completed since the entry into Operational;
/// it is no double reception.
#[test]
fn cia304_9_5_second_plain_frame_with_other_data_before_the_inverted_one_is_an_error() {
    for second in [&[2u8][..], &[1, 0][..]] {
        let (mut node, mut sink) = operational(33);
        pair(&mut node, ms(5), 0x3C, &mut sink);
        node.handle_frame(ms(10), &frame(0x141, &[1]), &mut sink);
        node.handle_frame(ms(11), &frame(0x141, second), &mut sink);
        assert_safe(
            &node,
            &sink,
            SrdoFaultCause::PlainRepeated,
            code::PROTOCOL_ERROR,
        );
    }
}

/// CiA 304 9.5: an inverted frame that is not the inverse of the pending plain frame stays a
/// fault, also when a discarded repeat came before it.
#[test]
fn cia304_9_5_after_a_discarded_repeat_a_wrong_inverted_frame_is_still_a_fault() {
    let (mut node, mut sink) = operational(33);
    pair(&mut node, ms(5), 0x3C, &mut sink);
    node.handle_frame(ms(10), &frame(0x141, &[1]), &mut sink);
    node.handle_frame(ms(11), &frame(0x141, &[1]), &mut sink);
    node.handle_frame(ms(12), &frame(0x142, &[0xFD]), &mut sink);
    assert_safe(
        &node,
        &sink,
        SrdoFaultCause::NotInverted,
        code::PROTOCOL_ERROR,
    );
}

/// A consumer that starts monitoring at any instant relative to a running producer reaches its
/// working state and delivers: a grid of start offsets over one 25 ms period, every
/// microsecond between a plain frame and its inverted frame included (EN 50325-5 7.1.2,
/// CiA 304 9.5).
#[test]
fn en50325_5_7_1_2_a_consumer_started_at_any_instant_of_a_running_producer_works() {
    const PERIOD: u64 = 25_000;
    const GAP: u64 = 230; // plain to inverted, about one 8-byte frame at 500 kbit/s
    let offsets = (0..PERIOD).step_by(250).chain(0..=GAP + 1);
    for offset in offsets {
        let (mut node, mut sink) = booted(33, |_| {});
        validate(&mut node);
        let start_at = us(10 * PERIOD + offset);
        let mut started = false;
        for cycle in 0..20u64 {
            let plain_at = us(cycle * PERIOD);
            let value = cycle as u8 | 1;
            for (at, id, data) in [
                (plain_at, 0x141, value),
                (plain_at + Duration::from_micros(GAP), 0x142, !value),
            ] {
                if !started && at >= start_at {
                    start(&mut node, start_at, &mut sink);
                    started = true;
                }
                node.handle_frame(at, &frame(id, &[data]), &mut sink);
                node.poll(at, &mut sink);
            }
        }
        assert!(
            node.is_working(),
            "start offset {offset} µs: {:?}",
            node.fault()
        );
        assert!(
            node.srdo_pairs(SrdoNumber::new(1).unwrap()) >= 8,
            "start offset {offset} µs: pairs delivered"
        );
        assert_eq!(output(&node, 0x6200, 1), 19 | 1, "start offset {offset} µs");
    }
}

#[test]
fn cia304_9_5_data_compared_bit_by_bit() {
    let (mut node, mut sink) = operational(33);
    pair(&mut node, ms(5), 0x3C, &mut sink);
    node.handle_frame(ms(10), &frame(0x141, &[0x0F]), &mut sink);
    node.handle_frame(ms(10), &frame(0x142, &[0xF1]), &mut sink);
    assert_safe(
        &node,
        &sink,
        SrdoFaultCause::NotInverted,
        code::PROTOCOL_ERROR,
    );
}

/// EN 50325-5 7.1.2 and 8.2.2, CiA 304 9.5: before its first pair since entering
/// Operational, a consumer discards the half of a pair a producer's NMT reset cut (it may
/// reach the bus after the master's start): a plain frame replaced by one with other data, an
/// inverted frame that is not the pending frame's inverse. Each is reported, neither is
/// counted as a double reception (5C00h), nothing is delivered, and the SRVT event still ends
/// a plain frame whose inverse never comes, at the same instant as without those frames.
#[test]
fn en50325_5_7_1_2_before_the_first_pair_an_unpaired_half_is_discarded_and_srvt_still_ends_it() {
    let discarded = |discarded| Event::FrameDiscarded {
        srdo: SrdoNumber::new(1).unwrap(),
        discarded,
    };
    let (mut node, mut sink) = operational(33);
    node.handle_frame(ms(10), &frame(0x141, &[1]), &mut sink);
    node.handle_frame(ms(11), &frame(0x141, &[0]), &mut sink);
    node.handle_frame(ms(12), &frame(0x142, &[0xFE]), &mut sink);
    assert_eq!(
        sink.events,
        [
            discarded(srdo::Discarded::PlainReplacedBeforeFirstPair),
            discarded(srdo::Discarded::InvertedNotPairedBeforeFirstPair),
        ]
    );
    assert_eq!(node.double_reception(), DoubleReception::default());
    assert_eq!((output(&node, 0x6200, 1), output(&node, 0x6201, 1)), (0, 0));
    assert!(node.fault().is_none());
    node.poll(ms(29) + Duration::from_micros(999), &mut sink);
    assert!(
        node.fault().is_none(),
        "SRVT counts from the first plain frame"
    );
    node.poll(ms(30), &mut sink);
    assert_safe(
        &node,
        &sink,
        SrdoFaultCause::SrvtElapsed,
        code::RPDO_TIMEOUT,
    );
}

#[test]
fn en50325_5_7_1_3_frame_shorter_than_the_mapping_gives_emcy_8210_and_is_not_processed() {
    let (mut node, mut sink) = operational(33);
    node.handle_frame(ms(10), &frame(0x141, &[]), &mut sink);
    assert_safe(&node, &sink, SrdoFaultCause::TooShort, 0x8210);
}

#[test]
fn en50325_5_7_1_3_frame_longer_than_the_mapping_uses_only_the_mapped_bytes() {
    let (mut node, mut sink) = operational(33);
    node.handle_frame(ms(10), &frame(0x141, &[0x11, 0x22, 0x33]), &mut sink);
    node.handle_frame(ms(10), &frame(0x142, &[0xEE, 0x00, 0x00]), &mut sink);
    assert!(node.is_working());
    assert_eq!(
        (output(&node, 0x6200, 1), output(&node, 0x6201, 1)),
        (0x11, 0xEE)
    );
    // The event carries the mapped byte only, not the unmapped 0x22 0x33.
    assert_eq!(
        sink.events.last(),
        Some(&Event::SrdoReceived {
            srdo: SrdoNumber::new(1).unwrap(),
            data: 0x11
        })
    );
}

#[test]
fn en50325_5_6_2_1_rtr_on_a_receive_srdo_is_ignored_and_counted() {
    let (mut node, mut sink) = operational(33);
    let rtr = CanFrame::remote(CanId::new(0x141).unwrap(), 1).unwrap();
    node.handle_frame(ms(10), &rtr, &mut sink);
    assert_eq!(
        sink.events,
        [Event::RemoteFrameIgnored(SrdoNumber::new(1).unwrap())]
    );
    assert_eq!(node.remote_frames_ignored(), 1);
    assert!(node.is_working());
    pair(&mut node, ms(11), 7, &mut sink);
    assert_eq!(
        output(&node, 0x6200, 1),
        7,
        "the RTR did not disturb the pair order"
    );
}

#[test]
fn en50325_5_8_2_2_srdo_frames_outside_operational_are_not_processed() {
    let (mut node, mut sink) = booted(33, |_| {});
    validate(&mut node);
    pair(&mut node, ms(10), 0x3C, &mut sink);
    assert!(sink.events.is_empty());
    assert_eq!(output(&node, 0x6200, 1), 0);
}

#[test]
fn en50325_5_8_2_2_leaving_operational_puts_outputs_in_the_safe_state() {
    let (mut node, mut sink) = operational(33);
    pair(&mut node, ms(10), 0x3C, &mut sink);
    node.handle_frame(ms(11), &nmt::command_frame(NmtCommand::Stop, 0), &mut sink);
    assert_eq!((output(&node, 0x6200, 1), output(&node, 0x6201, 1)), (0, 0));
    assert!(!node.is_working());
}

#[test]
fn safe_state_is_latched_until_nmt_resets_communication() {
    let (mut node, mut sink) = operational(33);
    pair(&mut node, ms(5), 0x3C, &mut sink);
    node.handle_frame(ms(10), &frame(0x141, &[1]), &mut sink);
    node.handle_frame(ms(10), &frame(0x142, &[0xFF]), &mut sink);
    assert!(node.fault().is_some());
    // Valid pairs no longer deliver data.
    pair(&mut node, ms(11), 0x3C, &mut sink);
    assert_eq!(output(&node, 0x6200, 1), 0);
    // Pre-operational and back does not clear the latch.
    node.handle_frame(
        ms(12),
        &nmt::command_frame(NmtCommand::EnterPreOperational, 0),
        &mut sink,
    );
    start(&mut node, ms(13), &mut sink);
    assert!(node.fault().is_some());
    // Reset communication does; the stored (here: default) configuration is back, so it must
    // be validated again before the node may run.
    sink.take();
    node.handle_frame(
        ms(14),
        &nmt::command_frame(NmtCommand::ResetCommunication, 0),
        &mut sink,
    );
    assert_eq!(node.fault(), None);
    assert_eq!(node.error_register(), 0);
    assert!(
        sink.frames.contains(&frame(0x721, &[0])),
        "boot-up after reset"
    );
    assert_eq!(node.nmt_state(), NmtState::PreOperational);
    validate(&mut node);
    start(&mut node, ms(15), &mut sink);
    pair(&mut node, ms(16), 0x3C, &mut sink);
    assert_eq!(output(&node, 0x6200, 1), 0x3C);
}

// ---- GFC ----------------------------------------------------------------------------------

#[test]
fn en50325_5_7_2_1_gfc_in_operational_switches_to_the_safe_state_at_once() {
    let (mut node, mut sink) = operational(33);
    pair(&mut node, ms(10), 0x3C, &mut sink);
    sink.take();
    node.handle_frame(ms(11), &frame(0x001, &[]), &mut sink);
    assert_eq!(node.fault(), Some(SafeStateCause::Gfc));
    assert_eq!(output(&node, 0x6200, 1), 0);
    let mut buf = [0u8; 1];
    assert_eq!(node.core.read(Address::new(0x1300, 0), &mut buf), Ok(1));
    assert_eq!(
        buf[0], 1,
        "EN 50325-5 6.4.2.1: 0x1300 = 1 when a GFC was indicated"
    );
    assert!(sink.events.contains(&Event::GfcReceived));
    assert_eq!(
        sink.emergencies()[0].code,
        code::GLOBAL_FAIL_SAFE,
        "the node says why it is safe"
    );
}

#[test]
fn cia301_table2_no_emcy_in_stopped_but_the_refusal_is_still_reported() {
    let (mut node, mut sink) = booted(1, |_| {});
    node.handle_frame(ms(1), &nmt::command_frame(NmtCommand::Stop, 0), &mut sink);
    sink.take();
    start(&mut node, ms(2), &mut sink);
    assert_eq!(node.nmt_state(), NmtState::Stopped);
    assert!(sink.emergencies().is_empty());
    let fault = ConfigFault {
        srdo: None,
        error: ConfigError::NotDeclaredValid,
    };
    assert_eq!(sink.events, [Event::ConfigurationRefused(fault)]);
}

#[test]
fn en50325_5_8_2_2_gfc_outside_operational_is_ignored() {
    let (mut node, mut sink) = booted(33, |_| {});
    node.handle_frame(ms(11), &frame(0x001, &[]), &mut sink);
    assert_eq!(node.fault(), None);
    assert!(sink.events.is_empty());
}

#[test]
fn en50325_5_6_3_gfc_producer_on_request_and_on_a_detected_fault() {
    let (mut node, mut sink) = operational(33);
    assert_eq!(node.request_gfc(), Ok(()));
    node.poll(ms(1), &mut sink);
    assert_eq!(sink.frames, [gfc::frame()]);
    assert!(sink.events.contains(&Event::GfcSent));
    assert_eq!(gfc_parameter(&mut node), 1, "EN 50325-5 6.4.2.1: requested");

    let (mut node, mut sink) = booted(33, |config| config.gfc_on_fault = true);
    validate(&mut node);
    start(&mut node, Instant::ZERO, &mut sink);
    pair(&mut node, us(500), 0x3C, &mut sink);
    node.handle_frame(ms(1), &frame(0x141, &[1]), &mut sink);
    node.handle_frame(ms(1), &frame(0x142, &[0]), &mut sink);
    node.poll(ms(1), &mut sink);
    assert!(sink.frames.contains(&gfc::frame()));
}

/// 0x1300 as the dictionary reads it.
fn gfc_parameter(node: &mut TestNode) -> u8 {
    let mut buf = [0u8; 1];
    assert_eq!(node.core.read(Address::new(0x1300, 0), &mut buf), Ok(1));
    buf[0]
}

fn gfc_frames(sink: &Recorder) -> usize {
    sink.frames.iter().filter(|f| **f == gfc::frame()).count()
}

/// CiA 301 Table 2, EN 50325-5 8.2.2: outside Operational (in Stopped only NMT error control
/// is sent) a GFC request is refused and a fault with `gfc_on_fault` sends no GFC.
#[test]
fn cia301_table2_no_gfc_outside_operational() {
    for state in [NmtCommand::Stop, NmtCommand::EnterPreOperational] {
        let (mut node, mut sink) = booted(33, |config| config.gfc_on_fault = true);
        node.handle_frame(ms(1), &nmt::command_frame(state, 0), &mut sink);
        assert_eq!(
            node.request_gfc(),
            Err(ApiError::NotOperational),
            "{state:?}"
        );
        node.enter_safe_state(3, &mut sink);
        for step in 2..10 {
            node.poll(ms(step), &mut sink);
        }
        assert_eq!(gfc_frames(&sink), 0, "{state:?}");
        assert!(!sink.events.contains(&Event::GfcSent), "{state:?}");
        assert_eq!(gfc_parameter(&mut node), 0, "{state:?}: no GFC requested");
        // A request refused outside Operational is not sent later either.
        validate(&mut node);
        start(&mut node, ms(10), &mut sink);
        node.poll(ms(11), &mut sink);
        assert_eq!(gfc_frames(&sink), 0, "{state:?}: nothing left over");
    }
}

/// EN 50325-5 6.4.2.1: 0x1300 *indicates* a requested or received GFC. Writing 1 sends
/// nothing (in any NMT state) and leaves the indication as it is; writing 0 clears it; values
/// above 1 are refused (0609 0031h). Other stacks read 0x1300 as "GFC enabled": a tool that
/// writes 1 to enable must not trip the bus.
#[test]
fn en50325_5_6_4_2_1_writing_0x1300_never_sends_a_gfc() {
    let (mut node, mut sink) = booted(33, |_| {});
    assert_eq!(node.core.write(Address::new(0x1300, 0), &[1]), Ok(()));
    node.poll(ms(1), &mut sink);
    assert_eq!(gfc_frames(&sink), 0, "Pre-operational");
    assert_eq!(
        gfc_parameter(&mut node),
        0,
        "a write of 1 indicates nothing"
    );

    let (mut node, mut sink) = operational(33);
    assert_eq!(node.core.write(Address::new(0x1300, 0), &[1]), Ok(()));
    node.poll(ms(1), &mut sink);
    assert_eq!(gfc_frames(&sink), 0, "Operational");
    assert!(node.is_working(), "nothing happened");
    assert_eq!(gfc_parameter(&mut node), 0);
    assert_eq!(
        node.core.write(Address::new(0x1300, 0), &[2]),
        Err(AbortCode::ValueTooHigh)
    );

    node.handle_frame(ms(2), &frame(0x001, &[]), &mut sink);
    assert_eq!(gfc_parameter(&mut node), 1, "indicated");
    assert_eq!(node.core.write(Address::new(0x1300, 0), &[1]), Ok(()));
    assert_eq!(
        gfc_parameter(&mut node),
        1,
        "a write of 1 leaves the indication"
    );
    assert_eq!(node.core.write(Address::new(0x1300, 0), &[0]), Ok(()));
    assert_eq!(gfc_parameter(&mut node), 0, "a write of 0 clears it");
    assert_eq!(gfc_frames(&sink), 0, "this node never sent a GFC");
}

// ---- Polling ------------------------------------------------------------------------------

#[test]
fn an_idle_poll_does_nothing_and_reports_the_same_deadline() {
    let (mut node, mut sink) = operational(33);
    let deadline = node.poll(ms(1), &mut sink);
    for step in 0..10 {
        assert_eq!(
            node.poll(ms(1) + Duration::from_micros(step), &mut sink),
            deadline
        );
    }
    assert!(sink.frames.is_empty() && sink.events.is_empty());
}

#[test]
fn node_rejects_a_bad_object_table_and_srdo_count() {
    static BAD: [AppObject; 1] = [object(0x6000, 1, 9, Access::ReadOnly, Mappable::Transmit)];
    let mut bad = config(1);
    bad.app_objects = &BAD;
    assert!(matches!(
        TestNode::new(bad, RamFlash::new()),
        Err(NodeError::Table(_))
    ));
    assert!(matches!(
        Node::<RamFlash<64>, 0>::new(config(1), RamFlash::new()),
        Err(NodeError::SrdoCount)
    ));
    static SHADOWED: [AppObject; 1] = [object(0x5C00, 1, 4, Access::ReadOnly, Mappable::No)];
    let mut shadowed = config(1);
    shadowed.app_objects = &SHADOWED;
    assert!(matches!(
        TestNode::new(shadowed, RamFlash::new()),
        Err(NodeError::ReservedIndex(DOUBLE_RECEPTION_INDEX))
    ));
}

#[test]
fn srdo_record_defaults_follow_en50325_5_table5() {
    assert_eq!(SrdoRecord::DELETED.cycle_time, 25);
    assert_eq!(SrdoRecord::DELETED.srvt, 20);
    let node_65 = SafetyConfig::<1>::predefined(65, &TX_MAPPING, &RX_MAPPING);
    assert!(
        !node_65.srdos[0].exists(),
        "node-IDs 65..127 have no pre-defined SRDO"
    );
}

#[test]
fn per_srdo_ram_is_within_160_bytes() {
    let per_srdo = core::mem::size_of::<SrdoRuntime>() + core::mem::size_of::<SrdoRecord>();
    assert_eq!(per_srdo, RAM_PER_SRDO);
    println!(
        "SrdoRuntime {} + SrdoRecord {} = {} bytes per SRDO",
        core::mem::size_of::<SrdoRuntime>(),
        core::mem::size_of::<SrdoRecord>(),
        per_srdo
    );
    assert!(per_srdo <= 160, "{per_srdo} bytes per SRDO");
}

/// Found by the `node_frames` fuzz target: a fault found by a poll (here the transmit halves
/// of an event-driven producer are not inverses, because the application never set its
/// inputs) sends its GFC in that same poll, and the poll leaves nothing due at `now`.
#[test]
fn en50325_5_6_3_a_fault_found_by_a_poll_sends_its_gfc_in_that_poll() {
    let (mut node, mut sink) = booted(1, |config| {
        config.event_driven = true;
        config.gfc_on_fault = true;
    });
    validate(&mut node);
    start(&mut node, Instant::ZERO, &mut sink);
    sink.take();
    let now = us(65_535);
    let deadline = node.poll(now, &mut sink);
    assert!(deadline > now, "{deadline:?} at {now:?}");
    assert!(sink.frames.contains(&gfc::frame()));
    assert!(sink.events.contains(&Event::GfcSent));
}

/// A fault the application found (a dual-channel cross-check): latched safe state, outputs 0
/// (SC_REQ_05), EMCY FF02h with the application's cause, and producers stop.
#[test]
fn sc_req_05_application_safe_state_clears_outputs_and_stops_producers() {
    let (mut consumer, mut sink) = operational(33);
    pair(&mut consumer, ms(10), 0x5A, &mut sink);
    assert_eq!(output(&consumer, 0x6200, 1), 0x5A);
    sink.take();
    consumer.enter_safe_state(7, &mut sink);
    assert!(!consumer.is_working());
    assert_eq!(output(&consumer, 0x6200, 1), 0);
    assert_eq!(
        consumer.fault(),
        Some(SafeStateCause::Application { detail: 7 })
    );
    let emcy = sink.emergencies();
    assert_eq!(emcy[0].code, code::APPLICATION_FAULT);
    assert_eq!(emcy[0].detail[1], 7);

    let (mut producer, mut sink) = operational(1);
    producer
        .write_object(Address::new(0x6001, 1), &[0xFF])
        .unwrap();
    producer.poll(ms(30), &mut sink);
    assert!(sink.frames.iter().any(|f| f.id().raw() == 0x101));
    producer.enter_safe_state(1, &mut sink);
    sink.take();
    producer.poll(ms(200), &mut sink);
    assert!(
        !sink
            .frames
            .iter()
            .any(|f| (0x101..=0x180).contains(&f.id().raw())),
        "no SRDO after an application fault"
    );
}

// ---- Deadlines ----------------------------------------------------------------------------

/// One step of the deadline model below.
#[derive(Clone, Copy, Debug)]
enum Step {
    /// Time passes by this many microseconds, then the node is polled.
    Poll(u64),
    /// A valid pair for receive SRDO 2 or 4 (`true`: 4) with this value.
    Pair(bool, u8),
    /// The plain frame of receive SRDO 2 or 4 (`true`: 4) with this value.
    Plain(bool, u8),
    /// Its inverted frame: the exact inverse of the last plain frame's value (`true`), or not.
    Inverted(bool, bool),
    /// The application hands transmit SRDO 1 or 3 (`true`: 3) new halves of this value, the
    /// inverted one its exact inverse (`true`) or not (event-driven transmission; halves that
    /// are not inverses halt the producers).
    Halves(bool, u8, bool),
    /// A GFC.
    Gfc,
    /// NMT enter Pre-operational, then start again.
    Restart,
    /// The application puts the device in its safe state.
    Application,
}

fn step() -> impl proptest::strategy::Strategy<Value = Step> {
    use proptest::prelude::*;
    // Faults latch for good, so they are rare: most runs go on long enough to exercise the
    // timers of a working device.
    prop_oneof![
        30 => (0u64..12_000).prop_map(Step::Poll),
        30 => (any::<bool>(), any::<u8>()).prop_map(|(k, v)| Step::Pair(k, v)),
        6 => (any::<bool>(), any::<u8>()).prop_map(|(k, v)| Step::Plain(k, v)),
        6 => (any::<bool>(), proptest::bool::weighted(0.9))
            .prop_map(|(k, exact)| Step::Inverted(k, exact)),
        8 => (any::<bool>(), any::<u8>(), proptest::bool::weighted(0.9))
            .prop_map(|(k, v, exact)| Step::Halves(k, v, exact)),
        1 => Just(Step::Gfc),
        2 => Just(Step::Restart),
        1 => Just(Step::Application),
    ]
}

proptest::proptest! {
    /// CiA 304 9.5, EN 50325-5 7.1.2: the deadline the SRDO table answers (after a poll, from
    /// the poll's own pass over the SRDOs) is the one a fresh pass over them gives, through
    /// pairs, faults, late frames, event-driven transmissions, GFC and the application's safe
    /// state; so the node is polled at every SRVT, SCT and refresh deadline.
    #[test]
    fn cia304_9_5_the_deadline_after_a_poll_is_the_earliest_timer_of_the_srdos(
        steps in proptest::collection::vec(step(), 1..120),
    ) {
        let (mut node, mut sink) = booted(3, |config| config.event_driven = true);
        let srdos = &mut node.core.protocol.safety.srdos;
        // SRDO 1 transmits (pre-defined for node 3), SRDO 3 too with other inputs and another
        // refresh time; SRDOs 2 and 4 receive, with their own SCT and SRVT.
        srdos[2] = srdos[0];
        srdos[2].cycle_time = 30;
        srdos[2].cob_id_1 = 0x111;
        srdos[2].cob_id_2 = 0x112;
        srdos[2].mapping[..2].copy_from_slice(&[0x6000_0208, 0x6001_0208]);
        for (slot, first, sct, srvt) in [(1, 0x141, 50, 20), (3, 0x151, 35, 8)] {
            let record = &mut srdos[slot];
            record.direction = 2;
            record.cycle_time = sct;
            record.srvt = srvt;
            record.cob_id_1 = first;
            record.cob_id_2 = first + 1;
            record.mapping_count = 2;
            record.mapping[..2].copy_from_slice(&RX_MAPPING);
        }
        validate(&mut node);
        for srdo in [1, 3] {
            let srdo = SrdoNumber::new(srdo).unwrap();
            node.set_transmit_payloads(srdo, &[0], &[0xFF]).unwrap();
        }
        start(&mut node, Instant::ZERO, &mut sink);
        proptest::prop_assert!(node.is_working());
        let mut now = Instant::ZERO;
        let mut last_plain = [0u8; 2];
        for step in steps {
            let id = |fourth: bool| if fourth { 0x151 } else { 0x141 };
            match step {
                Step::Poll(micros) => {
                    now = now + Duration::from_micros(micros);
                    node.poll(now, &mut sink);
                }
                Step::Pair(fourth, value) => {
                    node.handle_frame(now, &frame(id(fourth), &[value]), &mut sink);
                    node.handle_frame(now, &frame(id(fourth) + 1, &[!value]), &mut sink);
                }
                Step::Plain(fourth, value) => {
                    last_plain[usize::from(fourth)] = value;
                    node.handle_frame(now, &frame(id(fourth), &[value]), &mut sink);
                }
                Step::Inverted(fourth, exact) => {
                    let plain = last_plain[usize::from(fourth)];
                    let value = if exact { !plain } else { plain };
                    node.handle_frame(now, &frame(id(fourth) + 1, &[value]), &mut sink);
                }
                Step::Halves(third, plain, exact) => {
                    let inverted = if exact { !plain } else { plain };
                    let srdo = SrdoNumber::new(if third { 3 } else { 1 }).unwrap();
                    node.set_transmit_payloads(srdo, &[plain], &[inverted]).unwrap();
                }
                Step::Gfc => node.handle_frame(now, &gfc::frame(), &mut sink),
                Step::Restart => {
                    let command = nmt::command_frame(NmtCommand::EnterPreOperational, 0);
                    node.handle_frame(now, &command, &mut sink);
                    start(&mut node, now, &mut sink);
                }
                Step::Application => node.enter_safe_state(7, &mut sink),
            }
            if node.nmt_state() == NmtState::Operational {
                let (table, latched) = (&node.core.protocol, node.fault().is_some());
                proptest::prop_assert_eq!(
                    table.deadline(now, latched),
                    table.fresh_deadline(now, latched),
                    "after {:?}",
                    step
                );
            }
            sink.take();
        }
    }
}

/// EN 50325-5 6.2.2 (object 0x1340, CiA 304 8.4.2): the last SRDO of the largest device, SRDO
/// 64, receives like the first: its identifiers lead to it, and a valid pair is delivered.
#[test]
fn en50325_5_6_2_2_srdo_64_of_a_64_srdo_device_receives_its_pairs() {
    let mut node = Node::<RamFlash<16384>, 64>::new(config(33), RamFlash::new()).unwrap();
    let mut sink = Recorder::default();
    node.poll(Instant::ZERO, &mut sink);
    let srdos = &mut node.core.protocol.safety.srdos;
    srdos[63] = srdos[0];
    srdos[0] = SrdoRecord::DELETED;
    srdos[63].cob_id_1 = 0x17F;
    srdos[63].cob_id_2 = 0x180;
    for record in srdos.iter_mut() {
        record.signature = signature::compute(record);
    }
    node.core.protocol.safety.configuration_valid = 0xA5;
    node.handle_frame(
        Instant::ZERO,
        &nmt::command_frame(NmtCommand::Start, 0),
        &mut sink,
    );
    assert!(node.is_working());
    node.handle_frame(ms(10), &frame(0x17F, &[0x5A]), &mut sink);
    node.handle_frame(ms(11), &frame(0x180, &[0xA5]), &mut sink);
    let srdo = SrdoNumber::new(64).unwrap();
    assert_eq!(node.srdo_pairs(srdo), 1);
    assert!(
        sink.events
            .contains(&Event::SrdoReceived { srdo, data: 0x5A })
    );
    let mut value = [0u8; 1];
    node.read_object(Address::new(0x6200, 1), &mut value)
        .unwrap();
    assert_eq!(value, [0x5A], "the plain value in its object");
}
