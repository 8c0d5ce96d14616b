//! The protocol slot proven by a second implementer: a minimal, test-only safety protocol
//! ([`Beacon`]) driven through [`Device`] exactly as the SRDO table is, through every part
//! of [`SafetyProtocol`]: start and stop with NMT, its own frames, its deadline, its objects
//! by SDO, what it persists, its refusal and its faults latching the device's safe state.

use super::tests::{Recorder, config};
use super::*;
use crate::canopen::emcy::code;
use crate::canopen::sdo_client::{self, ClientError};
use crate::canopen::storage::RamFlash;
use crate::frame::CanId;
use crate::safety::config::{CONFIGURATION_VALID, ConfigError};

/// The beacon's object: sub-index 1 its period in ms (UNSIGNED16), sub-index 2 its
/// "configuration valid" (A5h to run; any accepted write to sub-index 1 resets it).
const BEACON_INDEX: u16 = 0x5D00;
/// The identifier it receives on.
const RECEIVE_ID: u16 = 0x0F0;
/// The identifier it transmits on.
const TRANSMIT_ID: u16 = 0x0F1;
/// The cause code of a "stop" frame (data byte 0 = FFh) in its EMCY byte 1.
const STOP_CAUSE: u8 = 0x77;
/// Its EMCY 6300h byte 1 when it refuses to start.
const NOT_VALID_CAUSE: u8 = 0x66;

/// A protocol that, in Operational, sends a frame with a counter every period, delivers byte
/// 0 of each frame it receives on [`RECEIVE_ID`] into the process image (0x6200 sub 1), and
/// latches the safe state on a frame whose byte 0 is FFh.
#[derive(Debug, Default)]
struct Beacon {
    period_ms: u16,
    valid: u8,
    /// When the next beacon is due, in Operational.
    next: Option<Instant>,
    sent: u8,
    /// Frames of its own seen outside Operational (ignored).
    ignored: u32,
    /// Calls the shell made: start, stop, reset.
    starts: u32,
    stops: u32,
    resets: u32,
}

/// The process image byte the beacon delivers into (0x6200 sub 1 of the test objects).
fn delivered(node: &BeaconNode) -> u8 {
    let mut byte = [0u8; 1];
    node.read_object(Address::new(0x6200, 1), &mut byte)
        .unwrap();
    byte[0]
}

fn delivery_span(image: &ProcessImage) -> crate::process_image::Span {
    image.find(Address::new(0x6200, 1)).unwrap().1
}

impl SafetyProtocol for Beacon {
    const MAX_PERSISTED: usize = 3;

    type Image = [u8; 128];

    fn image() -> [u8; 128] {
        [0; 128]
    }

    fn load_defaults(&mut self, _config: &NodeConfig) {
        self.period_ms = 10;
        self.valid = 0;
    }

    fn persist(&self, out: &mut [u8]) -> usize {
        let [low, high] = self.period_ms.to_le_bytes();
        out[..3].copy_from_slice(&[low, high, self.valid]);
        3
    }

    fn restore(&mut self, bytes: &[u8]) -> Result<(), PersistError> {
        let [low, high, valid] = <[u8; 3]>::try_from(bytes).map_err(|_| PersistError::Malformed)?;
        self.period_ms = u16::from_le_bytes([low, high]);
        self.valid = valid;
        Ok(())
    }

    fn withdraw_validation(&mut self) {
        self.valid = 0;
    }

    fn owns(&self, index: u16) -> bool {
        index == BEACON_INDEX
    }

    fn needs_unlock(index: u16) -> bool {
        index == BEACON_INDEX
    }

    /// Its period stands for a signature.
    type Signatures = [u16; 1];

    const NO_SIGNATURES: [u16; 1] = [0];

    fn validated_signatures(&self) -> Option<[u16; 1]> {
        (self.valid == CONFIGURATION_VALID).then_some([self.period_ms])
    }

    fn read(&mut self, address: Address, buf: &mut [u8]) -> Result<usize, AbortCode> {
        let bytes: &[u8] = match address.sub {
            0 => &[2],
            1 => &self.period_ms.to_le_bytes(),
            2 => &[self.valid],
            _ => return Err(AbortCode::NoSubIndex),
        };
        buf[..bytes.len()].copy_from_slice(bytes);
        Ok(bytes.len())
    }

    fn write(
        &mut self,
        address: Address,
        data: &[u8],
        _image: &ProcessImage,
        operational: bool,
    ) -> Result<(), AbortCode> {
        if operational {
            return Err(AbortCode::DeviceState);
        }
        match (address.sub, data) {
            (1, &[low, high]) => {
                self.period_ms = u16::from_le_bytes([low, high]);
                self.valid = 0;
            }
            (2, &[valid]) => self.valid = valid,
            (0, _) => return Err(AbortCode::ReadOnly),
            (1 | 2, _) => return Err(AbortCode::LengthTooHigh),
            _ => return Err(AbortCode::NoSubIndex),
        }
        Ok(())
    }

    fn start<S: Sink>(&mut self, now: Instant, slot: &mut Slot<'_, S>) -> Result<(), Refused> {
        self.starts += 1;
        if self.valid != CONFIGURATION_VALID || self.period_ms == 0 {
            self.withdraw_validation();
            return Err(slot.refuse_configuration(
                [0, NOT_VALID_CAUSE, 0, 0, 0],
                Event::ConfigurationRefused(ConfigFault {
                    srdo: None,
                    error: ConfigError::NotDeclaredValid,
                }),
            ));
        }
        self.next = Some(now + Duration::from_millis(u64::from(self.period_ms)));
        Ok(())
    }

    fn stop(&mut self, image: &mut ProcessImage) {
        self.stops += 1;
        self.next = None;
        image.set(delivery_span(image), &[0]);
    }

    fn reset(&mut self) {
        self.resets += 1;
        self.sent = 0;
    }

    fn on_frame<S: Sink>(
        &mut self,
        _now: Instant,
        frame: &CanFrame,
        slot: &mut Slot<'_, S>,
    ) -> bool {
        if frame.id().raw() != RECEIVE_ID {
            return false;
        }
        if self.next.is_none() {
            self.ignored += 1;
            return true;
        }
        match frame.data().first() {
            Some(0xFF) => {
                let cause = SafeStateCause::Protocol {
                    code: code::APPLICATION_FAULT,
                    cause: STOP_CAUSE,
                    named: 0,
                };
                let latched = slot.latched();
                self.enter_safe_state(slot.image_mut(), cause, latched);
                slot.latch(cause);
            }
            Some(&byte) if !slot.latched() => {
                let span = delivery_span(slot.image());
                slot.image_mut().set(span, &[byte]);
            }
            _ => {}
        }
        true
    }

    fn poll<S: Sink>(&mut self, now: Instant, slot: &mut Slot<'_, S>) {
        let Some(next) = self.next else { return };
        if crate::time::expired(next, now) {
            self.sent = self.sent.wrapping_add(1);
            slot.transmit(CanFrame::new(CanId::new(TRANSMIT_ID).unwrap(), &[self.sent]).unwrap());
            self.next = Some(now + Duration::from_millis(u64::from(self.period_ms)));
        }
    }

    fn deadline(&self, _now: Instant, _latched: bool) -> Instant {
        self.next.unwrap_or(Instant::NEVER)
    }

    fn enter_safe_state(
        &mut self,
        image: &mut ProcessImage,
        _cause: SafeStateCause,
        already_latched: bool,
    ) {
        if !already_latched {
            image.set(delivery_span(image), &[0]);
        }
    }

    fn object_changed(&mut self, _offset: u8) -> bool {
        false
    }
}

type BeaconNode = Device<RamFlash<8192>, Beacon>;

fn beacon_node(flash: RamFlash<8192>) -> (BeaconNode, Recorder) {
    let mut node = BeaconNode::with_protocol(config(33), flash, Beacon::default()).unwrap();
    let mut sink = Recorder::default();
    node.poll(Instant::ZERO, &mut sink);
    (node, sink)
}

fn exchange(node: &mut BeaconNode, sink: &mut Recorder, request: [u8; 8]) -> Option<[u8; 8]> {
    let frame = CanFrame::new(CanId::new(0x600 + 33).unwrap(), &request).unwrap();
    sink.frames.clear();
    node.handle_frame(Instant::ZERO, &frame, sink);
    sink.frames
        .iter()
        .find(|f| f.id().raw() == 0x580 + 33)
        .map(|f| f.data().try_into().unwrap())
}

fn sdo_write(
    node: &mut BeaconNode,
    sink: &mut Recorder,
    sub: u8,
    data: &[u8],
) -> Result<(), ClientError> {
    sdo_client::download(
        |request| exchange(node, sink, request),
        Address::new(BEACON_INDEX, sub),
        data,
    )
}

fn sdo_read(
    node: &mut BeaconNode,
    sink: &mut Recorder,
    sub: u8,
) -> Result<std::vec::Vec<u8>, ClientError> {
    sdo_client::upload(
        |request| exchange(node, sink, request),
        Address::new(BEACON_INDEX, sub),
    )
    .map(|bytes| bytes.to_vec())
}

fn nmt_at(node: &mut BeaconNode, sink: &mut Recorder, now: Instant, command: NmtCommand) {
    node.handle_frame(now, &nmt::command_frame(command, 0), sink);
}

fn frame(id: u16, data: &[u8]) -> CanFrame {
    CanFrame::new(CanId::new(id).unwrap(), data).unwrap()
}

/// Configured by SDO and started, the beacon runs on its own deadline in Operational, its
/// frames are its own (not NMT, GFC or SDO), and leaving Operational stops it.
#[test]
fn a_second_protocol_is_started_polled_fed_and_stopped_through_the_slot() {
    let (mut node, mut sink) = beacon_node(RamFlash::new());
    assert_eq!(node.protocol().resets, 0);
    assert_eq!(
        sdo_read(&mut node, &mut sink, 1).unwrap().as_slice(),
        &[10, 0]
    );
    sdo_write(&mut node, &mut sink, 1, &25u16.to_le_bytes()).unwrap();
    sdo_write(&mut node, &mut sink, 2, &[CONFIGURATION_VALID]).unwrap();

    // Outside Operational, its frames are its own and ignored, and it has no deadline.
    node.handle_frame(Instant::ZERO, &frame(RECEIVE_ID, &[7]), &mut sink);
    assert_eq!(node.protocol().ignored, 1);
    assert_eq!(delivered(&node), 0);
    assert_eq!(
        node.poll(Instant::from_millis(1), &mut sink),
        Instant::NEVER
    );

    let start = Instant::from_millis(100);
    nmt_at(&mut node, &mut sink, start, NmtCommand::Start);
    assert_eq!(node.nmt_state(), NmtState::Operational);
    assert!(node.is_working());
    assert_eq!((node.protocol().starts, node.protocol().stops), (1, 1));

    // Its deadline is the node's: polled at it, it sends, and reports the next one.
    sink.frames.clear();
    let first = start + Duration::from_millis(25);
    assert_eq!(node.poll(start, &mut sink), first);
    assert!(sink.frames.is_empty());
    assert_eq!(
        node.poll(first, &mut sink),
        first + Duration::from_millis(25)
    );
    assert_eq!(sink.frames.as_slice(), &[frame(TRANSMIT_ID, &[1])]);

    // Its frames deliver into the process image; the shell does not see them.
    node.handle_frame(first, &frame(RECEIVE_ID, &[0x42]), &mut sink);
    assert_eq!(delivered(&node), 0x42);
    // Its objects are read-only in Operational, by its own rule (EN 50325-5 8.2.2).
    assert_eq!(
        sdo_write(&mut node, &mut sink, 1, &[1, 0]),
        Err(ClientError::Aborted(AbortCode::DeviceState))
    );

    // Leaving Operational stops it: received values to 0, no deadline.
    nmt_at(&mut node, &mut sink, first, NmtCommand::EnterPreOperational);
    assert_eq!(node.protocol().stops, 2);
    assert_eq!(delivered(&node), 0);
    assert_eq!(node.poll(first, &mut sink), Instant::NEVER);
}

/// A configuration the protocol refuses keeps the node out of Operational with the EMCY
/// 6300h the protocol names (EN 50325-5 8.3.1), and its validation withdrawn.
#[test]
fn en50325_5_8_3_1_a_refused_configuration_of_a_second_protocol_keeps_the_node_out_of_operational()
{
    let (mut node, mut sink) = beacon_node(RamFlash::new());
    sink.frames.clear();
    nmt_at(&mut node, &mut sink, Instant::ZERO, NmtCommand::Start);
    assert_eq!(node.nmt_state(), NmtState::PreOperational);
    assert!(!node.is_working());
    let emergencies = sink.emergencies();
    assert_eq!(emergencies.len(), 1);
    assert_eq!(emergencies[0].code, code::DATA_SET);
    assert_eq!(emergencies[0].detail, [0, NOT_VALID_CAUSE, 0, 0, 0]);
    assert!(
        sink.events
            .contains(&Event::ConfigurationRefused(ConfigFault {
                srdo: None,
                error: ConfigError::NotDeclaredValid,
            }))
    );
    assert_eq!(
        node.poll(Instant::from_millis(1), &mut sink),
        Instant::NEVER
    );
}

/// A fault the protocol finds latches the device's safe state once, with the protocol's EMCY,
/// until NMT reset; the shell tells the protocol when it latches for its own causes (a GFC).
#[test]
fn en50325_5_8_2_2_a_second_protocol_latches_the_safe_state_through_the_slot() {
    let (mut node, mut sink) = beacon_node(RamFlash::new());
    sdo_write(&mut node, &mut sink, 2, &[CONFIGURATION_VALID]).unwrap();
    nmt_at(&mut node, &mut sink, Instant::ZERO, NmtCommand::Start);
    node.handle_frame(Instant::ZERO, &frame(RECEIVE_ID, &[5]), &mut sink);
    assert_eq!(delivered(&node), 5);
    sink.frames.clear();
    sink.events.clear();

    node.handle_frame(Instant::ZERO, &frame(RECEIVE_ID, &[0xFF]), &mut sink);
    let cause = SafeStateCause::Protocol {
        code: code::APPLICATION_FAULT,
        cause: STOP_CAUSE,
        named: 0,
    };
    assert_eq!(node.fault(), Some(cause));
    assert!(!node.is_working());
    assert_eq!(delivered(&node), 0);
    assert_eq!(sink.events.as_slice(), &[Event::SafeState(cause)]);
    let emergencies = sink.emergencies();
    assert_eq!(emergencies.len(), 1);
    assert_eq!(emergencies[0].code, code::APPLICATION_FAULT);
    assert_eq!(emergencies[0].detail, [0, STOP_CAUSE, 0, 0, 0]);

    // Latched: nothing is delivered any more, and a second fault sends no second EMCY.
    node.handle_frame(Instant::ZERO, &frame(RECEIVE_ID, &[6]), &mut sink);
    node.handle_frame(Instant::ZERO, &frame(RECEIVE_ID, &[0xFF]), &mut sink);
    assert_eq!(delivered(&node), 0);
    assert_eq!(sink.emergencies().len(), 1);

    // NMT reset clears the latch and resets the protocol.
    nmt_at(
        &mut node,
        &mut sink,
        Instant::ZERO,
        NmtCommand::ResetCommunication,
    );
    node.poll(Instant::ZERO, &mut sink);
    assert_eq!(node.fault(), None);
    assert_eq!(node.protocol().resets, 1);

    // A GFC is the shell's cause: the protocol puts its values in the safe state. (Nothing
    // was stored, so the reset brought the beacon's defaults back: validate it again.)
    sdo_write(&mut node, &mut sink, 2, &[CONFIGURATION_VALID]).unwrap();
    nmt_at(&mut node, &mut sink, Instant::ZERO, NmtCommand::Start);
    node.handle_frame(Instant::ZERO, &frame(RECEIVE_ID, &[9]), &mut sink);
    assert_eq!(delivered(&node), 9);
    node.handle_frame(Instant::ZERO, &frame(0x001, &[]), &mut sink);
    assert_eq!(node.fault(), Some(SafeStateCause::Gfc));
    assert_eq!(delivered(&node), 0);
}

/// 0x1010 stores the protocol's section after the shell's header, and a reset restores it
/// (CiA 301 7.5.2.13); stored on another node-ID, its validation is withdrawn (IEC 61784-3
/// addressing).
#[test]
fn cia301_7_5_2_13_a_second_protocol_persists_its_section_and_is_restored() {
    let (mut node, mut sink) = beacon_node(RamFlash::new());
    sdo_write(&mut node, &mut sink, 1, &40u16.to_le_bytes()).unwrap();
    sdo_write(&mut node, &mut sink, 2, &[CONFIGURATION_VALID]).unwrap();
    let save = Address::new(0x1010, 1);
    sdo_client::download(
        |request| exchange(&mut node, &mut sink, request),
        save,
        b"save",
    )
    .unwrap();

    let flash = node.flash().clone();
    let (mut restored, mut sink) = beacon_node(flash.clone());
    assert!(sink.events.contains(&Event::ParametersRestored));
    assert_eq!(
        sdo_read(&mut restored, &mut sink, 1).unwrap().as_slice(),
        &[40, 0]
    );
    assert_eq!(
        sdo_read(&mut restored, &mut sink, 2).unwrap().as_slice(),
        &[CONFIGURATION_VALID]
    );

    let mut other = BeaconNode::with_protocol(config(34), flash, Beacon::default()).unwrap();
    let mut sink = Recorder::default();
    other.poll(Instant::ZERO, &mut sink);
    assert_eq!(other.protocol().period_ms, 40);
    assert_eq!(other.protocol().valid, 0);
}

/// No application object may use an index the protocol owns.
#[test]
fn an_application_object_on_a_protocol_index_is_refused() {
    static CLASHING: [AppObject; 1] = [AppObject {
        address: Address::new(BEACON_INDEX, 1),
        len: 1,
        access: crate::process_image::Access::ReadOnly,
        mappable: crate::process_image::Mappable::No,
    }];
    let mut clashing = config(33);
    clashing.app_objects = &CLASHING;
    assert_eq!(
        BeaconNode::with_protocol(clashing, RamFlash::new(), Beacon::default()).err(),
        Some(NodeError::ReservedIndex(BEACON_INDEX))
    );
}

/// The access control is the shell's, not the SRDO table's: on a device running another
/// protocol it guards the objects that protocol says need the unlock, besides 0x1010, and its
/// audit record holds that protocol's signatures.
#[test]
fn sc_req_43_the_shell_guards_what_the_protocol_names_and_audits_its_signatures() {
    use super::access::{
        ACCESS_INDEX, AccessState, CHANGE_COUNTER_INDEX, SALT_LEN, SIGNATURES_AFTER_INDEX,
        SIGNATURES_BEFORE_INDEX, sub,
    };
    const SECRET: &[u8] = b"beacon secret";
    let (mut node, mut sink) = beacon_node(RamFlash::new());
    let mut write = |node: &mut BeaconNode, address: Address, data: &[u8]| {
        sdo_client::download(|request| exchange(node, &mut sink, request), address, data)
    };

    // Open: configured and validated without a secret; the audit records the first change.
    write(
        &mut node,
        Address::new(BEACON_INDEX, 1),
        &25u16.to_le_bytes(),
    )
    .unwrap();
    write(
        &mut node,
        Address::new(BEACON_INDEX, 2),
        &[CONFIGURATION_VALID],
    )
    .unwrap();
    assert_eq!(node.access().audit().changes, 1);
    assert_eq!(node.access().audit().after, [25]);

    let mut salted = [0x11u8; SALT_LEN + SECRET.len()];
    salted[SALT_LEN..].copy_from_slice(SECRET);
    write(
        &mut node,
        Address::new(ACCESS_INDEX, sub::SET_SECRET),
        &salted,
    )
    .unwrap();
    write(&mut node, Address::new(ACCESS_INDEX, sub::STATE), &[1]).unwrap();
    assert_eq!(node.access().state(Instant::ZERO), AccessState::Locked);

    // Locked: the protocol's guarded object and 0x1010 are refused, and nothing changed.
    for (address, data) in [
        (Address::new(BEACON_INDEX, 1), &40u16.to_le_bytes()[..]),
        (Address::new(BEACON_INDEX, 2), &[0][..]),
        (Address::new(0x1010, 1), &b"save"[..]),
    ] {
        assert_eq!(
            write(&mut node, address, data),
            Err(ClientError::Aborted(AbortCode::UnsupportedAccess)),
            "{address:?}"
        );
    }
    assert_eq!(
        (node.protocol().period_ms, node.protocol().valid),
        (25, 0xA5)
    );
    // The shell's own objects that are not safety configuration stay writable.
    write(&mut node, Address::new(0x1017, 0), &100u16.to_le_bytes()).unwrap();

    // Unlocked: a validated change is recorded with the protocol's signatures.
    write(&mut node, Address::new(ACCESS_INDEX, sub::UNLOCK), SECRET).unwrap();
    write(
        &mut node,
        Address::new(BEACON_INDEX, 1),
        &40u16.to_le_bytes(),
    )
    .unwrap();
    assert_eq!(node.access().audit().changes, 1, "not validated yet");
    write(
        &mut node,
        Address::new(BEACON_INDEX, 2),
        &[CONFIGURATION_VALID],
    )
    .unwrap();
    let mut read = |address: Address| {
        sdo_client::upload(|request| exchange(&mut node, &mut sink, request), address)
            .map(|bytes| bytes.to_vec())
    };
    assert_eq!(
        read(Address::new(CHANGE_COUNTER_INDEX, 0)),
        Ok(vec![2, 0, 0, 0])
    );
    assert_eq!(read(Address::new(SIGNATURES_BEFORE_INDEX, 0)), Ok(vec![1]));
    assert_eq!(
        read(Address::new(SIGNATURES_BEFORE_INDEX, 1)),
        Ok(vec![25, 0])
    );
    assert_eq!(
        read(Address::new(SIGNATURES_AFTER_INDEX, 1)),
        Ok(vec![40, 0])
    );
}
