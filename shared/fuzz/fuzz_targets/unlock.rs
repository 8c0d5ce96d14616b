//! Any sequence of unlock attempts, new secrets, stores, restores, guarded writes, NMT
//! commands and time steps against a node's access control (SC_REQ_43), through its SDO
//! server: no panic, and the node agrees at every step with a reference model written from
//! the rules (not from the implementation): a guarded write is accepted only on an open or
//! unlocked device, the right secret outside a lockout always unlocks, a wrong one always
//! locks out for the doubling time, the unlock ends after its period and at NMT start, stop
//! and resets, and what survives a reset is what was stored.
#![no_main]

#[path = "common.rs"]
mod common;

use arbitrary::Arbitrary;
use libfuzzer_sys::fuzz_target;
use shared::canopen::nmt::{self, NmtCommand};
use shared::canopen::od::{AbortCode, Address};
use shared::canopen::sdo_client::{self, ClientError};
use shared::canopen::storage::RamFlash;
use shared::node::access::{ACCESS_INDEX, AccessState, sub};
use shared::node::{Event, Node, Sink};
use shared::{CanFrame, CanId, Duration, Instant};

#[derive(Arbitrary, Debug)]
enum Step {
    /// An unlock attempt: the model's secret when `right`, else these bytes.
    Unlock { right: bool, other: Vec<u8> },
    /// A new secret with this salt.
    SetSecret { salt: [u8; 16], secret: Vec<u8> },
    /// 0x1010 "save".
    Store,
    /// 0x1011 "load".
    Restore,
    /// A write to a guarded object (0x1301:02, an SCT the check accepts).
    Guarded,
    /// 5C10h:03h = 1.
    Lock,
    /// An NMT command (0..=4: start, stop, pre-operational, reset node, reset communication).
    Nmt(u8),
    /// Time passes, in seconds.
    Wait(u16),
}

/// The rules of `shared::node::access`, as its documentation states them.
#[derive(Default)]
struct Model {
    secret: Option<Vec<u8>>,
    stored_secret: Option<Vec<u8>>,
    unlocked_until: Option<u64>,
    failures: u32,
    locked_out_until: u64,
}

impl Model {
    fn state(&self, now: u64) -> AccessState {
        if self.secret.is_none() {
            AccessState::Open
        } else if self.unlocked_until.is_some_and(|end| now < end) {
            AccessState::Unlocked
        } else if now < self.locked_out_until {
            AccessState::LockedOut
        } else {
            AccessState::Locked
        }
    }
    fn may_change(&self, now: u64) -> bool {
        matches!(self.state(now), AccessState::Open | AccessState::Unlocked)
    }
}

const UNLOCK_MS: u64 = 10 * 60 * 1000;

fn lockout_ms(failures: u32) -> u64 {
    (1000u64 << failures.saturating_sub(1).min(12)).min(3_600_000)
}

/// [`common::Checker`], keeping the SDO answers (0x585) too.
#[derive(Default)]
struct Recorder {
    checker: common::Checker,
    sdo: Vec<[u8; 8]>,
}

impl Sink for Recorder {
    fn transmit(&mut self, frame: CanFrame) {
        if frame.id().raw() == 0x585 {
            if let Ok(data) = <[u8; 8]>::try_from(frame.data()) {
                self.sdo.push(data);
            }
        }
        self.checker.transmit(frame);
    }
    fn event(&mut self, event: Event) {
        self.checker.event(event);
    }
}

struct Bench {
    node: Node<RamFlash<8192>, 2>,
    sink: Recorder,
    now: Instant,
}

impl Bench {
    fn exchange(&mut self, request: [u8; 8]) -> Option<[u8; 8]> {
        let frame = CanFrame::new(
            CanId::new(0x605).unwrap_or_else(|_| unreachable!()),
            &request,
        )
        .unwrap_or_else(|_| unreachable!());
        let before = self.sink.sdo.len();
        self.node.handle_frame(self.now, &frame, &mut self.sink);
        self.sink.sdo.get(before).copied()
    }
    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
        match sdo_client::download(|r| self.exchange(r), Address::new(index, sub), data) {
            Ok(()) => Ok(()),
            Err(ClientError::Aborted(code)) => Err(code),
            Err(other) => panic!("the node did not answer properly: {other:?}"),
        }
    }
}

fuzz_target!(|steps: Vec<Step>| {
    let Ok(node) = Node::<RamFlash<8192>, 2>::new(common::config(5, false), RamFlash::new()) else {
        return;
    };
    let mut bench = Bench {
        node,
        sink: Recorder::default(),
        now: Instant::ZERO,
    };
    bench.node.poll(bench.now, &mut bench.sink);
    let mut model = Model::default();
    for step in steps.into_iter().take(64) {
        let now = bench.now.as_micros() / 1000;
        match step {
            Step::Unlock { right, mut other } => {
                // Up to 40 bytes: past the node's 32, within what one SDO transfer of the
                // client carries (64).
                other.truncate(40);
                let candidate = match (&model.secret, right) {
                    (Some(secret), true) => secret.clone(),
                    _ => other,
                };
                let result = bench.write(ACCESS_INDEX, sub::UNLOCK, &candidate);
                if candidate.is_empty() || candidate.len() > 32 {
                    assert!(result.is_err());
                } else if model.secret.is_none() {
                    assert_eq!(result, Ok(()));
                } else if now < model.locked_out_until {
                    assert_eq!(result, Err(AbortCode::DeviceState));
                } else if model.secret.as_deref() == Some(&candidate[..]) {
                    assert_eq!(result, Ok(()));
                    model.failures = 0;
                    model.unlocked_until = Some(now + UNLOCK_MS);
                } else {
                    assert_eq!(result, Err(AbortCode::CannotStore));
                    model.failures += 1;
                    model.locked_out_until = now + lockout_ms(model.failures);
                    model.unlocked_until = None;
                }
            }
            Step::SetSecret { salt, mut secret } => {
                secret.truncate(40);
                let mut data = salt.to_vec();
                data.extend_from_slice(&secret);
                let result = bench.write(ACCESS_INDEX, sub::SET_SECRET, &data);
                let fits = (8..=32).contains(&secret.len());
                assert_eq!(result.is_ok(), model.may_change(now) && fits, "{result:?}");
                if result.is_ok() {
                    model.secret = Some(secret);
                    model.unlocked_until = Some(now + UNLOCK_MS);
                }
            }
            Step::Store | Step::Restore => {
                let (index, word) = match step {
                    Step::Store => (0x1010, b"save"),
                    _ => (0x1011, b"load"),
                };
                let result = bench.write(index, 1, word);
                assert_eq!(result.is_ok(), model.may_change(now), "{result:?}");
                if result.is_ok() {
                    model.stored_secret = model.secret.clone();
                }
            }
            Step::Guarded => {
                let result = bench.write(0x1301, 2, &200u16.to_le_bytes());
                if model.may_change(now) {
                    assert_ne!(result, Err(AbortCode::UnsupportedAccess));
                } else {
                    assert_eq!(result, Err(AbortCode::UnsupportedAccess));
                }
            }
            Step::Lock => {
                assert_eq!(bench.write(ACCESS_INDEX, sub::STATE, &[1]), Ok(()));
                model.unlocked_until = None;
            }
            Step::Nmt(raw) => {
                let command = match raw % 5 {
                    0 => NmtCommand::Start,
                    1 => NmtCommand::Stop,
                    2 => NmtCommand::EnterPreOperational,
                    3 => NmtCommand::ResetNode,
                    _ => NmtCommand::ResetCommunication,
                };
                bench.node.handle_frame(
                    bench.now,
                    &nmt::command_frame(command, 0),
                    &mut bench.sink,
                );
                if command != NmtCommand::EnterPreOperational {
                    model.unlocked_until = None;
                }
                if matches!(
                    command,
                    NmtCommand::ResetNode | NmtCommand::ResetCommunication
                ) {
                    model.secret = model.stored_secret.clone();
                }
                // SDO is answered in Pre-operational (and Operational); come back to it.
                bench.node.handle_frame(
                    bench.now,
                    &nmt::command_frame(NmtCommand::EnterPreOperational, 0),
                    &mut bench.sink,
                );
            }
            Step::Wait(seconds) => {
                bench.now = bench.now + Duration::from_millis(u64::from(seconds) * 1000);
            }
        }
        bench.node.poll(bench.now, &mut bench.sink);
        let now = bench.now.as_micros() / 1000;
        assert_eq!(bench.node.access().state(bench.now), model.state(now));
    }
});
