//! The protection of the safety configuration (SC_REQ_43) seen through the SDO server, as a
//! configuration tool sees it: refusals with their abort codes, the unlock on simulated time,
//! and what survives NMT resets.

use super::access::{
    ACCESS_INDEX, AccessState, CHANGE_COUNTER_INDEX, SALT_LEN, SIGNATURES_AFTER_INDEX,
    SIGNATURES_BEFORE_INDEX, UNLOCK_PERIOD, lockout, sub,
};
use super::tests::{Recorder, config};
use super::*;
use crate::canopen::sdo_client::{self, ClientError};
use crate::canopen::storage::RamFlash;
use crate::safety::signature;

type BusNode = Node<RamFlash<8192>, 4>;

const SECRET: &[u8] = b"maintenance 2026";
const SALT: [u8; SALT_LEN] = [0x42; SALT_LEN];

/// A node and the simulated time of the next request.
struct Bench {
    node: BusNode,
    sink: Recorder,
    now: Instant,
}

impl Bench {
    fn new() -> Self {
        let mut node = BusNode::new(config(33), RamFlash::new()).unwrap();
        let mut sink = Recorder::default();
        node.poll(Instant::ZERO, &mut sink);
        Bench {
            node,
            sink,
            now: Instant::ZERO,
        }
    }

    fn exchange(&mut self, request: [u8; 8]) -> Option<[u8; 8]> {
        let frame = CanFrame::new(CanId::new(0x600 + 33).unwrap(), &request).unwrap();
        self.sink.frames.clear();
        self.node.handle_frame(self.now, &frame, &mut self.sink);
        self.sink
            .frames
            .iter()
            .find(|f| f.id().raw() == 0x580 + 33)
            .map(|f| f.data().try_into().unwrap())
    }

    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
        sdo_client::download(|r| self.exchange(r), Address::new(index, sub), data).map_err(
            |error| match error {
                ClientError::Aborted(code) => code,
                other => panic!("expected an answer, got {other:?}"),
            },
        )
    }

    fn read(&mut self, index: u16, sub: u8) -> Result<std::vec::Vec<u8>, AbortCode> {
        sdo_client::upload(|r| self.exchange(r), Address::new(index, sub))
            .map(|v| v.to_vec())
            .map_err(|error| match error {
                ClientError::Aborted(code) => code,
                other => panic!("expected an answer, got {other:?}"),
            })
    }

    fn read_u32(&mut self, index: u16, sub: u8) -> u32 {
        let bytes = self.read(index, sub).unwrap();
        let mut word = [0u8; 4];
        word[..bytes.len()].copy_from_slice(&bytes);
        u32::from_le_bytes(word)
    }

    fn nmt(&mut self, command: NmtCommand) {
        let frame = nmt::command_frame(command, 0);
        self.node.handle_frame(self.now, &frame, &mut self.sink);
    }

    fn state(&mut self) -> u32 {
        self.read_u32(ACCESS_INDEX, sub::STATE)
    }

    fn set_secret(&mut self) -> Result<(), AbortCode> {
        let mut data = std::vec::Vec::from(SALT);
        data.extend_from_slice(SECRET);
        self.write(ACCESS_INDEX, sub::SET_SECRET, &data)
    }

    fn unlock(&mut self, secret: &[u8]) -> Result<(), AbortCode> {
        self.write(ACCESS_INDEX, sub::UNLOCK, secret)
    }

    /// Receive SRDO 1 consuming 0x101/0x102 with this SCT, signed and validated.
    fn configure(&mut self, sct_ms: u16) -> Result<(), AbortCode> {
        self.write(0x1301, 1, &[0])?;
        self.write(0x1301, 5, &0x101u32.to_le_bytes())?;
        self.write(0x1301, 6, &0x102u32.to_le_bytes())?;
        self.write(0x1301, 2, &sct_ms.to_le_bytes())?;
        self.write(0x1301, 1, &[2])?;
        let crc = signature::compute(&self.node.safety_config().srdos[0]);
        self.write(0x13FF, 1, &crc.to_le_bytes())?;
        self.write(0x13FE, 0, &[0xA5])
    }

    /// A commissioned device: configured, secret set, stored, reset (so locked).
    fn commissioned() -> Self {
        let mut bench = Bench::new();
        bench.configure(60).unwrap();
        bench.set_secret().unwrap();
        bench.write(0x1010, 1, b"save").unwrap();
        bench.nmt(NmtCommand::ResetNode);
        bench
    }

    fn advance(&mut self, duration: Duration) {
        self.now = self.now + duration;
    }
}

#[test]
fn sc_req_43_a_new_device_is_commissioned_without_a_secret() {
    let mut bench = Bench::new();
    assert_eq!(bench.state(), AccessState::Open as u32);
    assert_eq!(bench.configure(60), Ok(()));
    assert_eq!(bench.write(0x1010, 1, b"save"), Ok(()));
    // An unlock attempt on an open device changes nothing.
    assert_eq!(bench.unlock(b"anything"), Ok(()));
    assert_eq!(bench.state(), AccessState::Open as u32);
}

#[test]
fn sc_req_43_a_locked_device_refuses_every_change_with_0601_0000() {
    let mut bench = Bench::commissioned();
    assert_eq!(bench.state(), AccessState::Locked as u32);
    let before = bench.node.safety_config().clone();
    for (index, sub, data) in [
        (0x1301u16, 2u8, &300u16.to_le_bytes()[..]),
        (0x1381, 0, &[0][..]),
        (0x13FF, 1, &[0, 0][..]),
        (0x13FE, 0, &[0][..]),
        (0x1010, 1, &b"save"[..]),
        (0x1011, 1, &b"load"[..]),
    ] {
        assert_eq!(
            bench.write(index, sub, data),
            Err(AbortCode::UnsupportedAccess),
            "{index:04X}:{sub}"
        );
    }
    let mut salt_and_secret = std::vec::Vec::from([0u8; SALT_LEN]);
    salt_and_secret.extend_from_slice(b"takeover");
    assert_eq!(
        bench.write(ACCESS_INDEX, sub::SET_SECRET, &salt_and_secret),
        Err(AbortCode::UnsupportedAccess)
    );
    assert_eq!(bench.node.safety_config(), &before, "nothing half-applied");
    // Objects outside the safety configuration stay writable.
    assert_eq!(bench.write(0x1017, 0, &100u16.to_le_bytes()), Ok(()));
    // The secret is never readable.
    assert_eq!(
        bench.read(ACCESS_INDEX, sub::UNLOCK),
        Err(AbortCode::WriteOnly)
    );
    assert_eq!(
        bench.read(ACCESS_INDEX, sub::SET_SECRET),
        Err(AbortCode::WriteOnly)
    );
}

#[test]
fn sc_req_43_in_operational_a_change_is_refused_for_the_device_state() {
    let mut bench = Bench::commissioned();
    bench.unlock(SECRET).unwrap();
    bench.nmt(NmtCommand::Start);
    assert_eq!(bench.node.nmt_state(), NmtState::Operational);
    assert_eq!(
        bench.write(0x1301, 2, &300u16.to_le_bytes()),
        Err(AbortCode::DeviceState)
    );
}

#[test]
fn sc_req_43_the_unlock_ends_at_nmt_start_and_at_reset() {
    let mut bench = Bench::commissioned();
    assert_eq!(bench.unlock(SECRET), Ok(()));
    assert_eq!(bench.state(), AccessState::Unlocked as u32);
    assert_eq!(bench.write(0x1301, 2, &80u16.to_le_bytes()), Ok(()));
    bench.nmt(NmtCommand::Start);
    bench.nmt(NmtCommand::EnterPreOperational);
    assert_eq!(bench.state(), AccessState::Locked as u32);
    assert_eq!(
        bench.write(0x1301, 2, &90u16.to_le_bytes()),
        Err(AbortCode::UnsupportedAccess)
    );
    for reset in [NmtCommand::ResetNode, NmtCommand::ResetCommunication] {
        bench.unlock(SECRET).unwrap();
        bench.nmt(reset);
        assert_eq!(bench.state(), AccessState::Locked as u32, "{reset:?}");
    }
    // "Enter pre-operational" alone keeps it.
    bench.unlock(SECRET).unwrap();
    bench.nmt(NmtCommand::EnterPreOperational);
    assert_eq!(bench.state(), AccessState::Unlocked as u32);
}

#[test]
fn sc_req_43_an_expired_unlock_refuses_the_change() {
    let mut bench = Bench::commissioned();
    bench.unlock(SECRET).unwrap();
    bench.advance(Duration::from_micros(UNLOCK_PERIOD.as_micros() - 1000));
    assert_eq!(bench.read_u32(ACCESS_INDEX, sub::REMAINING_MS), 1);
    assert_eq!(bench.write(0x1301, 2, &80u16.to_le_bytes()), Ok(()));
    bench.advance(Duration::from_millis(1));
    assert_eq!(bench.state(), AccessState::Locked as u32);
    assert_eq!(
        bench.write(0x1301, 2, &90u16.to_le_bytes()),
        Err(AbortCode::UnsupportedAccess)
    );
}

#[test]
fn sc_req_43_a_wrong_secret_is_refused_and_the_lockout_survives_nmt_reset() {
    let mut bench = Bench::commissioned();
    assert_eq!(bench.unlock(b"guess 1"), Err(AbortCode::CannotStore));
    assert_eq!(bench.read_u32(ACCESS_INDEX, sub::FAILED_ATTEMPTS), 1);
    assert_eq!(bench.state(), AccessState::LockedOut as u32);
    bench.advance(lockout(1));
    assert_eq!(bench.unlock(b"guess 2"), Err(AbortCode::CannotStore));
    // Reset node and reset communication are anyone's to send: they do not clear the count.
    bench.nmt(NmtCommand::ResetNode);
    bench.nmt(NmtCommand::ResetCommunication);
    assert_eq!(bench.read_u32(ACCESS_INDEX, sub::FAILED_ATTEMPTS), 2);
    assert_eq!(
        u64::from(bench.read_u32(ACCESS_INDEX, sub::REMAINING_MS)) * 1000,
        lockout(2).as_micros()
    );
    // Too many attempts: even the right secret is refused during the lockout, uncounted.
    assert_eq!(bench.unlock(SECRET), Err(AbortCode::DeviceState));
    assert_eq!(bench.read_u32(ACCESS_INDEX, sub::FAILED_ATTEMPTS), 2);
    bench.advance(lockout(2));
    assert_eq!(bench.unlock(SECRET), Ok(()));
    assert_eq!(bench.read_u32(ACCESS_INDEX, sub::FAILED_ATTEMPTS), 0);
}

#[test]
fn sc_req_43_the_audit_record_of_a_validated_change_survives_reset() {
    let mut bench = Bench::commissioned();
    let first = bench.node.safety_config().srdos[0].signature;
    assert_eq!(bench.read_u32(CHANGE_COUNTER_INDEX, 0), 1);
    bench.unlock(SECRET).unwrap();
    bench.configure(120).unwrap();
    let second = bench.node.safety_config().srdos[0].signature;
    assert_ne!(first, second);
    bench.write(0x1010, 1, b"save").unwrap();
    bench.nmt(NmtCommand::ResetNode);
    assert_eq!(bench.read_u32(CHANGE_COUNTER_INDEX, 0), 2);
    assert_eq!(bench.read_u32(SIGNATURES_BEFORE_INDEX, 0), 4);
    assert_eq!(bench.read_u32(SIGNATURES_BEFORE_INDEX, 1), u32::from(first));
    assert_eq!(bench.read_u32(SIGNATURES_AFTER_INDEX, 1), u32::from(second));
    assert_eq!(bench.read_u32(SIGNATURES_AFTER_INDEX, 2), 0);
    assert_eq!(
        bench.write(CHANGE_COUNTER_INDEX, 0, &[0; 4]),
        Err(AbortCode::ReadOnly)
    );
}

#[test]
fn sc_req_43_restoring_the_defaults_keeps_the_secret_and_the_audit_record() {
    let mut bench = Bench::commissioned();
    bench.unlock(SECRET).unwrap();
    assert_eq!(bench.write(0x1011, 1, b"load"), Ok(()));
    bench.nmt(NmtCommand::ResetNode);
    assert_eq!(bench.node.safety_config().srdos[0].cob_id_1, 0x141);
    assert_eq!(bench.node.safety_config().configuration_valid, 0);
    assert_eq!(bench.state(), AccessState::Locked as u32);
    assert_eq!(bench.read_u32(CHANGE_COUNTER_INDEX, 0), 1);
    assert_eq!(
        bench.write(0x1301, 2, &80u16.to_le_bytes()),
        Err(AbortCode::UnsupportedAccess)
    );
}

#[test]
fn sc_req_43_a_secret_set_but_not_stored_is_forgotten_at_reset() {
    let mut bench = Bench::new();
    bench.set_secret().unwrap();
    assert_eq!(bench.state(), AccessState::Unlocked as u32);
    bench.nmt(NmtCommand::ResetNode);
    assert_eq!(bench.state(), AccessState::Open as u32);
}

#[test]
fn sc_req_43_application_objects_may_not_take_the_access_indices() {
    use crate::process_image::{Access, AppObject, Mappable};
    static TABLES: [[AppObject; 1]; 4] = {
        const fn at(index: u16) -> [AppObject; 1] {
            [AppObject {
                address: Address::new(index, 1),
                len: 1,
                access: Access::ReadWrite,
                mappable: Mappable::No,
            }]
        }
        [at(0x5C10), at(0x5C11), at(0x5C12), at(0x5C13)]
    };
    for (table, index) in TABLES.iter().zip(super::access::INDICES) {
        let mut shadowed = config(33);
        shadowed.app_objects = table;
        assert_eq!(
            BusNode::new(shadowed, RamFlash::new()).err(),
            Some(NodeError::ReservedIndex(index))
        );
    }
}
