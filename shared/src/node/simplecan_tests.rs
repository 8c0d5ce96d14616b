//! SimpleCAN in the protocol slot ([`SimpleCan`]): its objects by SDO, their storage, the
//! check at the Operational entry, and the blocks driven on frames and time, each test named
//! after the SC_REQ it verifies. A node of the test objects (node-ID 33) with a producer, a
//! consumer and the SC-ID of the network's master; the other SCLs are frames made here with
//! the packet encoder (`crate::simplecan::frame`, tested against our specification's vectors).

use super::simplecan::{
    COUNT_INDEX, CYCLE_INDEX, FIRST_ENTRY_INDEX, ROLE_CONSUME, ROLE_MASTER, ROLE_PRODUCE,
    SIGNATURE_INDEX, SimpleCanObjects, VALID_INDEX,
};
use super::srdo_table::SrdoTable;
use super::tests::config;
use super::*;
use crate::canopen::emcy::code;
use crate::canopen::sdo_client::{self, ClientError};
use crate::canopen::storage::RamFlash;
use crate::node::access::sub as access_sub;
use crate::safety::cause::Cause;
use crate::safety::config::CONFIGURATION_VALID;
use crate::simplecan::frame::{DataPacket, SYNC_IDENTIFIER, SyncPacket};
use crate::simplecan::{NodeHash, ScId};
use std::vec::Vec as StdVec;

/// The device: 4 SDD entries.
type ScNode = Device<RamFlash<8192>, SimpleCan<4>>;

const NODE: u8 = 33;
/// The SC-ID this node produces (slot 2, from 6000h:01).
const OWN: u8 = 0x40;
/// The SC-ID it consumes (the producer's slot 4, into 6200h:01, timeout 50 ms).
const CONSUMED: u8 = 0x50;
/// The network's master.
const MASTER: u8 = 0x30;
const OWN_SLOT: u16 = 2;
const CONSUMED_SLOT: u16 = 4;
const TIMEOUT_MS: u16 = 50;
/// N = 10 slots, a sync every 10 cycles: 100 ms.
const N: u64 = 10;

fn hash(sc_id: u8) -> NodeHash {
    NodeHash(0x5EED_0000 | u32::from(sc_id))
}

fn sc(raw: u8) -> ScId {
    ScId::new(raw).unwrap()
}

/// A sink that records frames, events and aborts.
#[derive(Default)]
struct Wire {
    frames: StdVec<CanFrame>,
    events: StdVec<Event>,
    aborts: StdVec<u16>,
}

impl Sink for Wire {
    fn transmit(&mut self, frame: CanFrame) {
        self.frames.push(frame);
    }
    fn event(&mut self, event: Event) {
        self.events.push(event);
    }
    fn abort(&mut self, id: CanId) {
        self.aborts.push(id.raw());
    }
}

impl Wire {
    fn simplecan(&self) -> StdVec<CanFrame> {
        self.frames
            .iter()
            .filter(|f| (0x02F..=0x07F).contains(&f.id().raw()))
            .copied()
            .collect()
    }
    fn emergencies(&self) -> StdVec<Emergency> {
        self.frames
            .iter()
            .filter(|f| f.id().raw() == 0x080 + u16::from(NODE))
            .filter_map(|f| Emergency::parse(f.data()))
            .collect()
    }
}

/// A node driven by SDO, NMT and frames as a network would: by default the device above,
/// SimpleCAN alone in its slot.
struct Bench<P: SafetyProtocol = SimpleCan<4>> {
    node: Device<RamFlash<8192>, P>,
    wire: Wire,
    now: Instant,
    /// The frames `run_until` saw handed out, with the instant.
    sent: StdVec<(Instant, CanFrame)>,
}

impl Bench {
    fn new() -> Self {
        Self::with_flash(RamFlash::new())
    }

    fn with_flash(flash: RamFlash<8192>) -> Self {
        Bench::around(ScNode::with_protocol(config(NODE), flash, SimpleCan::new()).unwrap())
    }

    fn protocol(&self) -> &SimpleCan<4> {
        self.node.protocol()
    }
}

impl<P: SafetyProtocol> Bench<P> {
    /// The bench around `node`, polled once (boot-up, Pre-operational).
    fn around(node: Device<RamFlash<8192>, P>) -> Self {
        let mut bench = Bench {
            node,
            wire: Wire::default(),
            now: Instant::ZERO,
            sent: StdVec::new(),
        };
        bench.poll();
        bench
    }

    fn exchange(&mut self, request: [u8; 8]) -> Option<[u8; 8]> {
        let frame = CanFrame::new(CanId::new(0x600 + u16::from(NODE)).unwrap(), &request).unwrap();
        let before = self.wire.frames.len();
        self.node.handle_frame(self.now, &frame, &mut self.wire);
        self.wire.frames[before..]
            .iter()
            .find(|f| f.id().raw() == 0x580 + u16::from(NODE))
            .map(|f| f.data().try_into().unwrap())
    }

    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
        sdo_client::download(
            |request| self.exchange(request),
            Address::new(index, sub),
            data,
        )
        .map_err(|error| match error {
            ClientError::Aborted(code) => code,
            other => panic!("{other:?}"),
        })
    }

    fn read(&mut self, index: u16, sub: u8) -> Result<StdVec<u8>, AbortCode> {
        sdo_client::upload(|request| self.exchange(request), Address::new(index, sub))
            .map(|bytes| bytes.to_vec())
            .map_err(|error| match error {
                ClientError::Aborted(code) => code,
                other => panic!("{other:?}"),
            })
    }

    fn entry(&mut self, n: u16, sc_id: u8, role: u8, slot: u16, timeout: u16, mapped: u32) {
        let index = FIRST_ENTRY_INDEX + n - 1;
        self.write(index, 1, &[sc_id]).unwrap();
        self.write(index, 2, &[role]).unwrap();
        self.write(index, 3, &slot.to_le_bytes()).unwrap();
        self.write(index, 4, &timeout.to_le_bytes()).unwrap();
        self.write(index, 5, &hash(sc_id).0.to_le_bytes()).unwrap();
        self.write(index, 6, &mapped.to_le_bytes()).unwrap();
    }

    /// The configuration of this file, written as a tool would, without the signature.
    fn configure(&mut self, potential_master: bool) {
        self.write(CYCLE_INDEX, 1, &10u16.to_le_bytes()).unwrap();
        self.write(CYCLE_INDEX, 2, &10u16.to_le_bytes()).unwrap();
        self.write(CYCLE_INDEX, 3, &0u16.to_le_bytes()).unwrap();
        self.write(CYCLE_INDEX, 4, &[1]).unwrap();
        self.write(CYCLE_INDEX, 5, &[u8::from(potential_master)])
            .unwrap();
        self.write(COUNT_INDEX, 0, &[0]).unwrap();
        self.entry(1, OWN, ROLE_PRODUCE, OWN_SLOT, 0, 0x6000_0108);
        self.entry(
            2,
            CONSUMED,
            ROLE_CONSUME,
            CONSUMED_SLOT,
            TIMEOUT_MS,
            0x6200_0108,
        );
        self.entry(3, MASTER, ROLE_MASTER, 0, 0, 0);
        self.write(COUNT_INDEX, 0, &[3]).unwrap();
    }

    /// Signs with the independent CRC below and declares the configuration valid.
    fn sign(&mut self) {
        let signature = reference_signature(&mut *self);
        self.write(SIGNATURE_INDEX, 0, &signature.to_le_bytes())
            .unwrap();
        self.write(VALID_INDEX, 0, &[CONFIGURATION_VALID]).unwrap();
    }

    fn nmt(&mut self, command: NmtCommand) {
        self.node
            .handle_frame(self.now, &nmt::command_frame(command, 0), &mut self.wire);
        self.poll();
    }

    fn poll(&mut self) -> Instant {
        self.node.poll(self.now, &mut self.wire)
    }

    /// Polls at every deadline up to `end`, confirming every frame the node hands out at
    /// once (an idle bus), except those `confirm` refuses.
    fn run_until(&mut self, end: Instant, confirm: impl Fn(&CanFrame) -> bool) {
        loop {
            let before = self.wire.frames.len();
            let next = self.poll();
            let sent: StdVec<CanFrame> = self.wire.frames[before..].to_vec();
            self.sent
                .extend(sent.iter().map(|frame| (self.now, *frame)));
            for frame in sent.iter().filter(|frame| confirm(frame)) {
                self.node.on_transmitted(self.now, frame, &mut self.wire);
            }
            if !sent.is_empty() {
                continue;
            }
            let next = next.min(self.node.poll(self.now, &mut self.wire));
            if next > end {
                self.now = end;
                return;
            }
            self.now = next.max(self.now);
        }
    }

    fn receive(&mut self, frame: CanFrame) {
        self.node.handle_frame(self.now, &frame, &mut self.wire);
        self.poll();
    }

    fn consumed_object(&self) -> u8 {
        let mut byte = [0u8];
        self.node
            .read_object(Address::new(0x6200, 1), &mut byte)
            .unwrap();
        byte[0]
    }

    fn cause(&self) -> Option<u8> {
        match self.node.fault() {
            Some(SafeStateCause::Protocol { cause, .. }) => Some(cause),
            _ => None,
        }
    }
}

/// CRC-32 with polynomial 04C11DB7h, initial value FFFFFFFFh, MSB first, no final XOR,
/// bit by bit: a second implementation, as the tool has one.
fn bitwise_crc32(bytes: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &byte in bytes {
        crc ^= u32::from(byte) << 24;
        for _ in 0..8 {
            crc = if crc & 0x8000_0000 != 0 {
                (crc << 1) ^ 0x04C1_1DB7
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// Section 11's signature from the objects read back by SDO, fed as the text says.
fn reference_signature<P: SafetyProtocol>(bench: &mut Bench<P>) -> u32 {
    let mut fed = StdVec::from([NODE]);
    for sub in 1..=5 {
        fed.extend(bench.read(CYCLE_INDEX, sub).unwrap());
    }
    let count = bench.read(COUNT_INDEX, 0).unwrap();
    fed.extend(&count);
    for n in 0..u16::from(count[0]) {
        for sub in 1..=6 {
            fed.extend(bench.read(FIRST_ENTRY_INDEX + n, sub).unwrap());
        }
    }
    bitwise_crc32(&fed)
}

/// A configured, signed node in Operational at 1 s, not yet synced.
fn operational(potential_master: bool) -> Bench {
    let mut bench = Bench::new();
    bench.configure(potential_master);
    bench.sign();
    bench.now = Instant::from_millis(1_000);
    bench.nmt(NmtCommand::Start);
    assert_eq!(bench.node.nmt_state(), NmtState::Operational);
    bench
}

/// The master's cycle 0 starts at local 1.2 s here: cycle c, slot s starts at
/// 1.2 s + (c × N + s) ms.
const EPOCH_US: u64 = 1_200_000;

fn slot_start(cycle: u64, slot: u16) -> Instant {
    Instant::from_micros(EPOCH_US + (cycle * N + u64::from(slot)) * 1000)
}

/// The microsecond before `at`.
fn just_before(at: Instant) -> Instant {
    Instant::from_micros(at.as_micros() - 1)
}

fn sync_frame(master: u8, cycle: u16) -> CanFrame {
    SyncPacket::new(sc(master), cycle, 0)
        .unwrap()
        .encode(hash(master))
}

/// Two syncs of the master (cycles 0 and 10): synced at the second (SC_REQ_30).
fn synced() -> Bench {
    let mut bench = operational(false);
    for cycle in [0, 10] {
        bench.now = slot_start(cycle, N as u16 - 1);
        bench.receive(sync_frame(MASTER, cycle as u16));
    }
    assert!(bench.protocol().has_global_time(bench.now));
    assert_eq!(bench.protocol().synced_to(), Some(sc(MASTER)));
    bench
}

fn data_frame(sc_id: u8, value: u32, cycle: u64) -> CanFrame {
    DataPacket {
        sc_id: sc(sc_id),
        value,
        cycle_stamp: cycle as u8,
    }
    .encode(hash(sc_id))
}

#[test]
fn sc_req_17_the_signature_is_crc32_mpeg2_over_the_objects_as_section_11_feeds_them() {
    assert_eq!(bitwise_crc32(b"123456789"), 0x0376_E6E7);
    let mut bench = Bench::new();
    bench.configure(true);
    let reference = reference_signature(&mut bench);
    assert_eq!(bench.protocol().objects().signature(NODE), reference);
    // The node-ID is part of it: a configuration copied to node 34 does not match.
    assert_ne!(bench.protocol().objects().signature(NODE + 1), reference);
}

#[test]
fn sc_req_39_the_configuration_is_written_only_in_pre_operational() {
    let mut bench = operational(false);
    let before = *bench.protocol().objects();
    for (index, sub, data) in [
        (CYCLE_INDEX, 1u8, &20u16.to_le_bytes()[..]),
        (COUNT_INDEX, 0, &[0][..]),
        (FIRST_ENTRY_INDEX, 1, &[0x41][..]),
        (VALID_INDEX, 0, &[0][..]),
        (SIGNATURE_INDEX, 0, &[0; 4][..]),
    ] {
        assert_eq!(
            bench.write(index, sub, data),
            Err(AbortCode::DeviceState),
            "{index:04X}:{sub}"
        );
    }
    assert_eq!(bench.protocol().objects(), &before);
    // Readable all the same.
    assert_eq!(
        bench.read(VALID_INDEX, 0),
        Ok(StdVec::from([CONFIGURATION_VALID]))
    );
}

/// Each refused write answers with the CiA 301 abort code of its reason, and changes nothing.
#[test]
fn sc_req_16_every_object_checks_its_value_with_the_right_abort_code() {
    let mut bench = Bench::new();
    let before = *bench.protocol().objects();
    let cases: [(u16, u8, &[u8], AbortCode); 14] = [
        (CYCLE_INDEX, 0, &[5], AbortCode::ReadOnly),
        (CYCLE_INDEX, 1, &[10], AbortCode::LengthTooLow),
        (CYCLE_INDEX, 1, &[10, 0, 0], AbortCode::LengthTooHigh),
        (CYCLE_INDEX, 1, &2u16.to_le_bytes(), AbortCode::ValueTooLow),
        (
            CYCLE_INDEX,
            1,
            &1001u16.to_le_bytes(),
            AbortCode::ValueTooHigh,
        ),
        // N = 10: k = 9 is 90 ms, k = 51 is 510 ms (SC_REQ_22).
        (CYCLE_INDEX, 2, &9u16.to_le_bytes(), AbortCode::ValueTooLow),
        (
            CYCLE_INDEX,
            2,
            &51u16.to_le_bytes(),
            AbortCode::ValueTooHigh,
        ),
        (CYCLE_INDEX, 4, &[2], AbortCode::ValueTooHigh),
        (CYCLE_INDEX, 6, &[0], AbortCode::NoSubIndex),
        (COUNT_INDEX, 0, &[5], AbortCode::ValueTooHigh),
        (FIRST_ENTRY_INDEX, 1, &[0x2F], AbortCode::ValueTooLow),
        (FIRST_ENTRY_INDEX, 2, &[4], AbortCode::ValueTooHigh),
        (
            FIRST_ENTRY_INDEX,
            4,
            &60_001u16.to_le_bytes(),
            AbortCode::ValueTooHigh,
        ),
        // This device holds 4 entries: the fifth does not exist.
        (FIRST_ENTRY_INDEX + 4, 1, &[0x41], AbortCode::NoObject),
    ];
    for (index, sub, data, abort) in cases {
        assert_eq!(
            bench.write(index, sub, data),
            Err(abort),
            "{index:04X}:{sub} {data:?}"
        );
    }
    assert_eq!(bench.protocol().objects(), &before, "nothing half-applied");
    assert_eq!(bench.read(0x5E02, 0), Err(AbortCode::NoObject));
}

/// The count is written last and checks every entry it takes in (section 11); while it is
/// not 0 the entries do not change.
#[test]
fn sc_req_16_the_entry_count_checks_every_entry() {
    let mut bench = Bench::new();
    bench.configure(false);
    assert_eq!(
        bench.write(FIRST_ENTRY_INDEX, 1, &[0x41]),
        Err(AbortCode::UnsupportedAccess)
    );
    // A value of the wrong length is a length abort whatever the state (CiA 301: as
    // python-canopen's sweep of the EDS expects of every writable entry).
    for (sub, length) in [(1u8, 1usize), (2, 1), (3, 2), (4, 2), (5, 4), (6, 4)] {
        for (wrong, abort) in [
            (length + 1, AbortCode::LengthTooHigh),
            (length - 1, AbortCode::LengthTooLow),
        ] {
            if wrong == 0 {
                continue; // an empty download is not an expedited SDO transfer
            }
            assert_eq!(
                bench.write(FIRST_ENTRY_INDEX, sub, &vec![0; wrong]),
                Err(abort),
                "5E10h:{sub:02X}h, {wrong} bytes"
            );
        }
    }
    bench.write(COUNT_INDEX, 0, &[0]).unwrap();
    // A consumer mapped onto an input (transmit-mappable): not mappable.
    bench
        .write(FIRST_ENTRY_INDEX + 1, 6, &0x6000_0208u32.to_le_bytes())
        .unwrap();
    assert_eq!(
        bench.write(COUNT_INDEX, 0, &[3]),
        Err(AbortCode::NotMappable)
    );
    // A mapped object that does not exist.
    bench
        .write(FIRST_ENTRY_INDEX + 1, 6, &0x6300_0108u32.to_le_bytes())
        .unwrap();
    assert_eq!(bench.write(COUNT_INDEX, 0, &[3]), Err(AbortCode::NoObject));
    // Two entries of one SC-ID.
    bench
        .write(FIRST_ENTRY_INDEX + 1, 6, &0x6200_0108u32.to_le_bytes())
        .unwrap();
    bench.write(FIRST_ENTRY_INDEX + 2, 1, &[OWN]).unwrap();
    assert_eq!(
        bench.write(COUNT_INDEX, 0, &[3]),
        Err(AbortCode::ParameterIncompatible)
    );
    // A producer in one of the last two slots (SC_REQ_21).
    bench.write(FIRST_ENTRY_INDEX + 2, 1, &[MASTER]).unwrap();
    bench
        .write(FIRST_ENTRY_INDEX, 3, &8u16.to_le_bytes())
        .unwrap();
    assert_eq!(
        bench.write(COUNT_INDEX, 0, &[3]),
        Err(AbortCode::ParameterIncompatible)
    );
    assert_eq!(bench.read(COUNT_INDEX, 0), Ok(StdVec::from([0])));
    bench
        .write(FIRST_ENTRY_INDEX, 3, &OWN_SLOT.to_le_bytes())
        .unwrap();
    assert_eq!(bench.write(COUNT_INDEX, 0, &[3]), Ok(()));
}

/// Every accepted write to the configuration withdraws the validation; the signature and
/// 5EFEh themselves do not.
#[test]
fn sc_req_34_a_change_withdraws_the_validation() {
    let mut bench = Bench::new();
    bench.configure(false);
    bench.sign();
    assert_eq!(
        bench.read(VALID_INDEX, 0),
        Ok(StdVec::from([CONFIGURATION_VALID]))
    );
    bench.write(CYCLE_INDEX, 3, &100u16.to_le_bytes()).unwrap();
    assert_eq!(bench.read(VALID_INDEX, 0), Ok(StdVec::from([0])));
}

/// SC_REQ_43: while the device is locked, no SimpleCAN object changes (the shell's access
/// control, as for 1301h..13FFh).
#[test]
fn sc_req_43_a_locked_device_refuses_every_simplecan_write() {
    let mut bench = Bench::new();
    let mut salt_and_secret = StdVec::from([7u8; crate::node::access::SALT_LEN]);
    salt_and_secret.extend_from_slice(b"a secret");
    bench
        .write(
            access::ACCESS_INDEX,
            access_sub::SET_SECRET,
            &salt_and_secret,
        )
        .unwrap();
    // Any NMT command but Enter Pre-operational ends an unlock.
    bench.nmt(NmtCommand::Stop);
    bench.nmt(NmtCommand::EnterPreOperational);
    for (index, sub, data) in [
        (CYCLE_INDEX, 4u8, &[1][..]),
        (COUNT_INDEX, 0, &[0][..]),
        (FIRST_ENTRY_INDEX, 5, &[1, 2, 3, 4][..]),
        (VALID_INDEX, 0, &[CONFIGURATION_VALID][..]),
        (SIGNATURE_INDEX, 0, &[1, 2, 3, 4][..]),
    ] {
        assert_eq!(
            bench.write(index, sub, data),
            Err(AbortCode::UnsupportedAccess),
            "{index:04X}:{sub}"
        );
    }
    assert_eq!(bench.protocol().objects(), &SimpleCanObjects::DEFAULT);
}

fn refused_with(bench: &Bench, cause: Cause, entry: u8) {
    assert_eq!(bench.node.nmt_state(), NmtState::PreOperational);
    assert!(
        bench
            .wire
            .events
            .contains(&Event::ProtocolConfigurationRefused {
                cause: cause.code(),
                detail: entry,
            })
    );
    let emcy = bench.wire.emergencies();
    let last = emcy.last().unwrap();
    assert_eq!(last.code, code::DATA_SET);
    assert_eq!(last.detail, [0, cause.code(), entry, 0, 0]);
}

#[test]
fn sc_req_34_a_configuration_not_declared_valid_is_refused() {
    let mut bench = Bench::new();
    bench.configure(false);
    bench.nmt(NmtCommand::Start);
    refused_with(&bench, Cause::SimpleCanNotValidated, 0);
    assert_eq!(
        Cause::SimpleCanNotValidated.describe(),
        "SimpleCAN configuration not declared valid"
    );
}

#[test]
fn sc_req_34_a_wrong_signature_is_refused_and_withdraws_the_validation() {
    let mut bench = Bench::new();
    bench.configure(false);
    bench.sign();
    let good = bench.protocol().objects().signature;
    bench
        .write(SIGNATURE_INDEX, 0, &(good ^ 1).to_le_bytes())
        .unwrap();
    bench.nmt(NmtCommand::Start);
    refused_with(&bench, Cause::SimpleCanSignature, 0);
    assert_eq!(bench.read(VALID_INDEX, 0), Ok(StdVec::from([0])));
}

/// A signed configuration that the cycle refuses: N changed to 4 after the count, so the
/// producer's slot 2 is one of the last two (SC_REQ_21). Refused at the start, naming entry 1.
#[test]
fn sc_req_16_a_signed_but_inconsistent_configuration_is_refused() {
    let mut bench = Bench::new();
    bench.configure(false);
    bench.write(CYCLE_INDEX, 1, &4u16.to_le_bytes()).unwrap();
    bench.write(CYCLE_INDEX, 2, &25u16.to_le_bytes()).unwrap();
    bench.sign();
    bench.nmt(NmtCommand::Start);
    refused_with(&bench, Cause::SimpleCanConfiguration, 1);
}

/// Disabled (5E00h:04 = 0), nothing is checked and nothing is sent: the node starts as a
/// CANopen device with no SimpleCAN at all.
#[test]
fn sc_req_16_disabled_simplecan_starts_without_a_configuration() {
    let mut bench = Bench::new();
    bench.nmt(NmtCommand::Start);
    assert_eq!(bench.node.nmt_state(), NmtState::Operational);
    bench.run_until(Instant::from_millis(3_000), |_| true);
    assert!(bench.wire.simplecan().is_empty());
    assert!(!bench.protocol().is_running());
}

/// Stored by 1010h and restored at power-on: the same objects, the same signature, and the
/// node starts.
#[test]
fn sc_req_16_the_configuration_is_stored_and_restored_whole() {
    let mut bench = Bench::new();
    bench.configure(true);
    bench.sign();
    bench.write(0x1010, 1, b"save").unwrap();
    let objects = *bench.protocol().objects();
    let flash = bench.node.flash().clone();
    let mut restored = Bench::with_flash(flash);
    assert_eq!(restored.protocol().objects(), &objects);
    restored.nmt(NmtCommand::Start);
    assert_eq!(restored.node.nmt_state(), NmtState::Operational);
}

/// Unsynced, a producer sends nothing and a consumer discards everything (SC_REQ_29).
#[test]
fn sc_req_29_unsynced_nothing_is_sent_and_everything_discarded() {
    let mut bench = operational(false);
    bench.run_until(Instant::from_millis(1_100), |_| true);
    bench.receive(data_frame(CONSUMED, 0x01, 0));
    bench.run_until(Instant::from_millis(1_150), |_| true);
    assert!(bench.wire.simplecan().is_empty());
    assert_eq!(bench.consumed_object(), 0);
    assert_eq!(bench.protocol().counters().discarded_unsynced, 1);
    // One sync is not enough (SC_REQ_30).
    bench.now = slot_start(0, N as u16 - 1);
    bench.receive(sync_frame(MASTER, 0));
    bench.run_until(slot_start(5, 0), |_| true);
    assert!(bench.wire.simplecan().is_empty());
}

/// Synced, the producer sends in its slot of every cycle, at the slot's start, with the
/// cycle stamp and its mapped object's value (SC_REQ_18, section 5).
#[test]
fn sc_req_18_the_producer_sends_its_value_at_the_start_of_its_slot() {
    let mut bench = synced();
    bench
        .node
        .write_object(Address::new(0x6000, 1), &[0x5A])
        .unwrap();
    let from = bench.wire.frames.len();
    let mut sent_at = StdVec::new();
    for cycle in 11..14u64 {
        bench.run_until(just_before(slot_start(cycle, OWN_SLOT)), |_| true);
        assert_eq!(bench.wire.frames.len(), from + sent_at.len(), "early");
        bench.run_until(slot_start(cycle, OWN_SLOT), |_| true);
        sent_at.push(bench.now);
        let frame = *bench.wire.frames.last().unwrap();
        assert_eq!(frame, data_frame(OWN, 0x5A, cycle));
    }
    assert_eq!(bench.protocol().counters().sent, 3);
}

/// A packet not on the bus by the end of its slot is withdrawn (section 5).
#[test]
fn sc_req_18_a_packet_not_sent_by_the_end_of_its_slot_is_aborted() {
    let mut bench = synced();
    bench.run_until(just_before(slot_start(11, OWN_SLOT + 1)), |_| false);
    assert!(bench.wire.aborts.is_empty());
    bench.run_until(slot_start(11, OWN_SLOT + 1), |_| false);
    assert_eq!(bench.wire.aborts, [u16::from(OWN)]);
    assert_eq!(bench.protocol().counters().aborted, 1);
}

/// A timely packet delivers its value; its age counts from the start of the producer's
/// slot; at the timeout the value is 0 and the device is in its safe state.
#[test]
fn sc_req_20_a_consumed_value_is_delivered_with_its_age_and_is_0_at_its_timeout() {
    let mut bench = synced();
    let produced = slot_start(11, CONSUMED_SLOT);
    bench.now = produced + Duration::from_micros(300);
    bench.receive(data_frame(CONSUMED, 0x01, 11));
    assert_eq!(bench.consumed_object(), 0x01);
    assert_eq!(
        bench.protocol().age(sc(CONSUMED), bench.now),
        Some(Duration::from_micros(300))
    );
    // A packet outside its slot (a cycle late) is not timely.
    bench.now = slot_start(12, CONSUMED_SLOT);
    bench.receive(data_frame(CONSUMED, 0x00, 11));
    assert_eq!(bench.protocol().counters().untimely, 1);
    let timeout = produced + Duration::from_millis(u64::from(TIMEOUT_MS));
    bench.run_until(just_before(timeout), |_| true);
    assert_eq!(bench.consumed_object(), 0x01);
    assert!(bench.node.is_working());
    bench.run_until(timeout, |_| true);
    assert_eq!(bench.consumed_object(), 0);
    assert_eq!(bench.cause(), Some(Cause::SimpleCanTimeout.code()));
}

/// 1000 packets with a bad CRC in a burst: the safe state (SC_REQ_42); 999 are not enough.
#[test]
fn sc_req_42_a_thousand_bad_crcs_latch_the_safe_state() {
    let mut bench = synced();
    let mut bad = data_frame(CONSUMED, 1, 11);
    let mut data = [0u8; 8];
    data.copy_from_slice(bad.data());
    data[7] ^= 1;
    bad = CanFrame::new(bad.id(), &data).unwrap();
    for _ in 0..999 {
        bench.receive(bad);
    }
    assert!(bench.node.fault().is_none());
    bench.receive(bad);
    assert_eq!(bench.cause(), Some(Cause::SimpleCanBadCrc.code()));
    assert_eq!(bench.protocol().counters().rejected, 1000);
}

/// A sync from a higher master while the lower one is active: several masters, the safe
/// state (SC_REQ_26); and from then on nothing is sent (SC_REQ_40).
#[test]
fn sc_req_26_and_sc_req_40_several_masters_latch_a_silent_safe_state() {
    let mut bench = synced();
    // 50h, an SC-ID whose hash the node knows, sends syncs 50 ms after 30h's last one.
    bench.now = slot_start(15, N as u16 - 1);
    bench.receive(
        SyncPacket::new(sc(CONSUMED), 15, 0)
            .unwrap()
            .encode(hash(CONSUMED)),
    );
    assert_eq!(bench.cause(), Some(Cause::SimpleCanSeveralMasters.code()));
    let emcy = bench.wire.emergencies();
    assert_eq!(
        emcy.last().unwrap().detail[1],
        Cause::SimpleCanSeveralMasters.code()
    );
    let before = bench.wire.simplecan().len();
    bench.run_until(slot_start(40, 0), |_| true);
    assert_eq!(bench.wire.simplecan().len(), before, "SC_REQ_40");
}

/// SC_REQ_41: the safe state outlasts Pre-operational and a new start; only NMT reset ends it.
#[test]
fn sc_req_41_only_a_reset_leaves_the_safe_state() {
    let mut bench = synced();
    bench.now = slot_start(11, CONSUMED_SLOT);
    bench.receive(data_frame(CONSUMED, 0x01, 11));
    bench.run_until(slot_start(20, 0), |_| true);
    assert_eq!(
        bench.cause(),
        Some(Cause::SimpleCanTimeout.code()),
        "no packet since"
    );
    bench.nmt(NmtCommand::EnterPreOperational);
    bench.nmt(NmtCommand::Start);
    assert!(bench.node.fault().is_some());
    let before = bench.wire.simplecan().len();
    for cycle in [30, 40] {
        bench.now = slot_start(cycle, N as u16 - 1);
        bench.receive(sync_frame(MASTER, cycle as u16));
    }
    bench.run_until(slot_start(45, 0), |_| true);
    assert_eq!(bench.wire.simplecan().len(), before);
    bench.nmt(NmtCommand::ResetNode);
    assert!(bench.node.fault().is_none());
}

/// A potential master alone: it listens 500 ms and t_wait ((40h − 30h) × 5 ms = 80 ms),
/// then sends its first sync in the last slot (SC_REQ_27, SC_REQ_21), then one every k × N =
/// 100 ms (SC_REQ_22); with its own time it produces (it is the active master).
#[test]
fn sc_req_27_a_lone_potential_master_waits_then_syncs_every_100_ms() {
    let mut bench = operational(true);
    let start = bench.now;
    bench.run_until(start + Duration::from_millis(900), |_| true);
    let syncs: StdVec<Instant> = bench
        .sent
        .iter()
        .filter(|(_, frame)| frame.id() == SYNC_IDENTIFIER)
        .map(|(at, _)| *at)
        .collect();
    let first = start + Duration::from_millis(580);
    assert_eq!(
        syncs,
        [
            first,
            first + Duration::from_millis(100),
            first + Duration::from_millis(200),
            first + Duration::from_millis(300),
        ]
    );
    assert!(bench.protocol().is_active_master());
    assert_eq!(bench.protocol().counters().syncs_sent, 4);
    // Its produced SC-ID goes out too, one per cycle of 10 ms.
    assert!(bench.protocol().counters().sent >= 20);
}

/// Its sync not confirmed within 2 ms is aborted (SC_REQ_23), and it backs off t_wait.
#[test]
fn sc_req_23_a_sync_not_confirmed_within_2_ms_is_aborted() {
    let mut bench = operational(true);
    let first = bench.now + Duration::from_millis(580);
    bench.run_until(first, |frame| frame.id() != SYNC_IDENTIFIER);
    assert_eq!(
        bench
            .wire
            .frames
            .iter()
            .filter(|f| f.id() == SYNC_IDENTIFIER)
            .count(),
        1
    );
    bench.run_until(first + Duration::from_micros(1_999), |f| {
        f.id() != SYNC_IDENTIFIER
    });
    assert!(!bench.wire.aborts.contains(&SYNC_IDENTIFIER.raw()));
    bench.run_until(first + Duration::from_millis(2), |f| {
        f.id() != SYNC_IDENTIFIER
    });
    assert!(bench.wire.aborts.contains(&SYNC_IDENTIFIER.raw()));
    assert_eq!(bench.protocol().counters().syncs_aborted, 1);
}

// ---- Beside CANopen Safety ---------------------------------------------------------------

/// One script for any device with the SRDO table in its slot: boot, validate the pre-defined
/// configuration, start, valid pairs on SRDO 1, frames on every SimpleCAN identifier, an SDO
/// read of 5E00h:04, then no pair until SCT has elapsed. Every frame and event handed out.
fn srdo_script<P>(mut node: Device<RamFlash<8192>, P>) -> (StdVec<CanFrame>, StdVec<Event>)
where
    P: SafetyProtocol + WithSrdoTable<Table = SrdoTable<4>>,
{
    use crate::safety::signature;
    let mut wire = Wire::default();
    node.poll(Instant::ZERO, &mut wire);
    let table = node.core.protocol.srdo_table_mut();
    for record in table.safety.srdos.iter_mut() {
        record.signature = signature::compute(record);
    }
    table.safety.configuration_valid = CONFIGURATION_VALID;
    node.handle_frame(
        Instant::ZERO,
        &nmt::command_frame(NmtCommand::Start, 0),
        &mut wire,
    );
    let mut now = Instant::ZERO;
    for step in 0..40u64 {
        now = Instant::from_millis(step * 5);
        let value = step as u8;
        let plain = CanFrame::new(CanId::new(0x141).unwrap(), &[value]).unwrap();
        let inverted = CanFrame::new(CanId::new(0x142).unwrap(), &[!value]).unwrap();
        node.handle_frame(now, &plain, &mut wire);
        node.handle_frame(now + Duration::from_micros(200), &inverted, &mut wire);
        let foreign = 0x02F + (step as u16 % 0x51);
        node.handle_frame(
            now + Duration::from_micros(300),
            &CanFrame::new(CanId::new(foreign).unwrap(), &[value; 8]).unwrap(),
            &mut wire,
        );
        node.poll(now + Duration::from_micros(400), &mut wire);
    }
    let read = CanFrame::new(
        CanId::new(0x600 + u16::from(NODE)).unwrap(),
        &[0x40, 0x00, 0x5E, 0x04, 0, 0, 0, 0],
    )
    .unwrap();
    node.handle_frame(now, &read, &mut wire);
    let mut at = now;
    while at < Instant::from_millis(2_000) {
        at = node.poll(at, &mut wire).max(at + Duration::from_micros(1));
    }
    assert!(node.fault().is_some(), "SCT elapsed: the safe state");
    (wire.frames, wire.events)
}

/// SimpleCAN disabled (the default), the device with both protocols hands out exactly what
/// the CANopen Safety node hands out, frame for frame and event for event, but the SDO answer
/// to 5E00h:04 (0 where the other has no such object).
#[test]
fn with_simplecan_disabled_the_node_is_the_canopen_safety_node() {
    let plain = Node::<RamFlash<8192>, 4>::new(config(NODE), RamFlash::new()).unwrap();
    let both = SimpleCanNode::<RamFlash<8192>, 4, 4>::new(config(NODE), RamFlash::new()).unwrap();
    let (frames, events) = srdo_script(plain);
    let (frames_both, events_both) = srdo_script(both);
    assert_eq!(events, events_both);
    assert_eq!(frames.len(), frames_both.len());
    let sdo = 0x580 + u16::from(NODE);
    for (one, other) in frames.iter().zip(&frames_both) {
        if one.id().raw() == sdo {
            assert_eq!(one.data()[0], 0x80, "no object in the CANopen Safety node");
            assert_eq!(other.data()[..5], [0x4F, 0x00, 0x5E, 0x04, 0]);
        } else {
            assert_eq!(one, other);
        }
    }
    assert!(
        events
            .iter()
            .any(|e| matches!(e, Event::SrdoReceived { .. }))
    );
}

/// Both sections stored by 1010h and restored at power-on: the SRDO records and SimpleCAN's
/// objects as they were (SC_REQ_16); a section cut short restores neither.
#[test]
fn sc_req_16_both_protocols_are_stored_and_restored_together() {
    type Both = SimpleCanNode<RamFlash<8192>, 4, 4>;
    let mut wire = Wire::default();
    let mut node = Both::new(config(NODE), RamFlash::new()).unwrap();
    node.poll(Instant::ZERO, &mut wire);
    node.core.protocol.simplecan.set_objects(SimpleCanObjects {
        enabled: 1,
        count: 1,
        signature: 0x1234_5678,
        ..SimpleCanObjects::DEFAULT
    });
    node.core.protocol.srdo.safety.srdos[0].cycle_time = 77;
    let mut image = SrdoAndSimpleCan::<4, 4>::image();
    let length = node.core.protocol.persist(image.as_mut());
    let mut restored = SrdoAndSimpleCan::<4, 4>::new(&config(NODE)).unwrap();
    restored.restore(&image.as_ref()[..length]).unwrap();
    assert_eq!(
        restored.simplecan.objects(),
        node.core.protocol.simplecan.objects()
    );
    assert_eq!(restored.srdo.config(), node.core.protocol.srdo.config());
    let mut untouched = SrdoAndSimpleCan::<4, 4>::new(&config(NODE)).unwrap();
    assert_eq!(
        untouched.restore(&image.as_ref()[..length - 1]),
        Err(PersistError::Malformed)
    );
    assert_eq!(untouched.simplecan.objects(), &SimpleCanObjects::DEFAULT);
    assert_ne!(untouched.srdo.config().srdos[0].cycle_time, 77);
}

/// A safe state the shell latches (a GFC) withdraws the packet still waiting for the bus at
/// the next poll, before its slot ends (SC_REQ_40).
#[test]
fn sc_req_40_a_gfc_withdraws_the_packet_waiting_for_the_bus() {
    let mut bench = synced();
    bench.run_until(slot_start(11, OWN_SLOT), |_| false);
    assert!(bench.wire.aborts.is_empty());
    bench.now = slot_start(11, OWN_SLOT) + Duration::from_micros(100);
    bench.receive(CanFrame::new(CanId::new(0x001).unwrap(), &[]).unwrap());
    assert_eq!(bench.node.fault(), Some(SafeStateCause::Gfc));
    assert_eq!(bench.wire.aborts, [u16::from(OWN)]);
    let before = bench.wire.simplecan().len();
    bench.run_until(slot_start(20, 0), |_| true);
    assert_eq!(bench.wire.simplecan().len(), before);
}

/// The firmware images' protocol: SimpleCAN instead of SRDOs (an SRDO table of none beside
/// it, one row of image and signatures). Configured as a tool does it (SimpleCAN's objects,
/// its signature and 5EFEh, then 13FEh, which still gates the Operational entry for the
/// table of no SRDOs), it starts, stores and restores both sections, and its validated
/// signatures are SimpleCAN's two halves, nothing left out (SC_REQ_16, SC_REQ_34).
#[test]
fn sc_req_16_simplecan_instead_of_srdos_is_configured_started_stored_and_restored() {
    type Images = SrdoAndSimpleCan<0, 2, 1>;
    let build = |flash| {
        let protocol = Images::new(&config(NODE)).unwrap();
        Bench::around(Device::with_protocol(config(NODE), flash, protocol).unwrap())
    };
    let mut bench = build(RamFlash::new());
    assert_eq!(bench.read(0x13FF, 0), Ok(vec![0]));
    assert_eq!(bench.read(0x1301, 1), Err(AbortCode::NoObject));
    bench.write(CYCLE_INDEX, 1, &10u16.to_le_bytes()).unwrap();
    bench.write(CYCLE_INDEX, 4, &[1]).unwrap();
    bench.write(CYCLE_INDEX, 5, &[1]).unwrap();
    bench.entry(1, OWN, ROLE_PRODUCE, OWN_SLOT, 0, 0x6000_0108);
    bench.entry(2, MASTER, ROLE_MASTER, 0, 0, 0);
    bench.write(COUNT_INDEX, 0, &[2]).unwrap();
    let signature = reference_signature(&mut bench);
    bench
        .write(SIGNATURE_INDEX, 0, &signature.to_le_bytes())
        .unwrap();
    bench.write(VALID_INDEX, 0, &[CONFIGURATION_VALID]).unwrap();
    // SimpleCAN is valid, the table of no SRDOs not yet: no Operational.
    bench.nmt(NmtCommand::Start);
    assert_ne!(bench.node.nmt_state(), NmtState::Operational);
    bench.write(0x13FE, 0, &[CONFIGURATION_VALID]).unwrap();
    let halves = [signature as u16, (signature >> 16) as u16];
    let validated = bench.node.core.protocol.validated_signatures().unwrap();
    assert_eq!(validated.as_ref(), &halves);
    bench.write(0x1010, 1, b"save").unwrap();
    bench.nmt(NmtCommand::Start);
    assert_eq!(bench.node.nmt_state(), NmtState::Operational);
    assert!(bench.node.core.protocol.simplecan.is_running());

    let mut restored = build(bench.node.flash().clone());
    assert_eq!(
        restored.node.core.protocol.simplecan.objects(),
        bench.node.core.protocol.simplecan.objects()
    );
    restored.nmt(NmtCommand::Start);
    assert_eq!(restored.node.nmt_state(), NmtState::Operational);
    assert!(restored.node.core.protocol.simplecan.is_running());
}
