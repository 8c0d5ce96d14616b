//! Stored parameters at power-on, through the store's own save path: a node configured over
//! SDO (values from the input) saves with 0x1010, the committed payload is read back with
//! `storage::load`, changed as the input says and committed again with `storage::store`; then
//! the medium may be damaged byte by byte, and a fresh node powers on from it.
//!
//! The records are built by the storage code itself, so the CRC matches and the parameter
//! image parser (`persist::decode`) runs for nearly every input, whatever the record header
//! looks like. Checked:
//!
//! - no panic; the node boots to Pre-operational and is not in its working state;
//! - an unchanged, undamaged payload is restored (`ParametersRestored`) to the saved
//!   configuration (mapping entries past the mapping count are not stored and read 0);
//! - a payload that is rejected sends EMCY 6300h with the detail `STORED_PARAMETERS_REJECTED`;
//! - whatever is restored, saved again with 0x1010, gives the same payload byte for byte
//!   (decode then encode is the identity on every accepted image).
//!
//! Every 2^k-th input (from 1024 on) prints how many inputs reached `persist::decode` as a
//! committed record, and how many it accepted: the share the documentation reports.
#![no_main]

#[path = "common.rs"]
#[allow(
    dead_code,
    reason = "this target records what the node reports itself; it uses the device description only"
)]
mod common;

use arbitrary::Arbitrary;
use libfuzzer_sys::fuzz_target;
use shared::canopen::nmt::NmtState;
use shared::canopen::storage::{self, RamFlash, Slot};
use shared::node::{Event, Node, STORED_PARAMETERS_REJECTED, Sink};
use shared::safety::config::SafetyConfig;
use shared::{CanFrame, CanId, Instant};
use std::sync::atomic::{AtomicU64, Ordering};

/// Bytes per slot: the largest image of a two-SRDO device and then some.
const SLOT: usize = 1024;
/// The node-ID of the device under test.
const NODE_ID: u8 = 33;

/// One expedited SDO write to the saving node, to vary the saved configuration.
#[derive(Arbitrary, Debug)]
struct Write {
    /// Which object: 0x1017, the SRDO communication and mapping objects, 0x13FE, 0x13FF.
    object: u8,
    sub: u8,
    /// 1, 2 or 4 bytes (low two bits).
    size: u8,
    value: u32,
}

/// One change to the committed payload before it is committed again.
#[derive(Arbitrary, Debug)]
enum Edit {
    /// XOR one byte (offset modulo the length).
    Flip { at: u16, mask: u8 },
    /// Set one byte.
    Set { at: u16, value: u8 },
    /// Cut the payload to this length (modulo its length + 1).
    Truncate { len: u16 },
    /// Append bytes.
    Extend { bytes: Vec<u8> },
}

/// Damage on the medium after the commit (raw slot access, as a failing flash would).
#[derive(Arbitrary, Debug)]
struct Damage {
    second_slot: bool,
    at: u16,
    mask: u8,
}

#[derive(Arbitrary, Debug)]
struct Input {
    writes: Vec<Write>,
    /// Validate the configuration (signature and 0x13FE) before saving.
    validate: bool,
    edits: Vec<Edit>,
    damage: Vec<Damage>,
}

/// Inputs seen, inputs whose record was committed when the node powered on, images accepted.
static INPUTS: AtomicU64 = AtomicU64::new(0);
static COMMITTED: AtomicU64 = AtomicU64::new(0);
static ACCEPTED: AtomicU64 = AtomicU64::new(0);

/// Records what the node reports.
#[derive(Default)]
struct Recorder {
    restored: bool,
    rejected: bool,
    rejected_emcy: bool,
    sdo_responses: Vec<[u8; 8]>,
}

impl Sink for Recorder {
    fn transmit(&mut self, frame: CanFrame) {
        assert!(frame.dlc() <= 8 && frame.id().raw() <= 0x7FF);
        let id = frame.id().raw();
        let data = frame.data();
        if id == 0x80 + u16::from(NODE_ID) && data.len() == 8 {
            let code = u16::from_le_bytes([data[0], data[1]]);
            if code == 0x6300 && data[4] == STORED_PARAMETERS_REJECTED {
                self.rejected_emcy = true;
            }
        }
        if id == 0x580 + u16::from(NODE_ID) && data.len() == 8 {
            let mut response = [0u8; 8];
            response.copy_from_slice(data);
            self.sdo_responses.push(response);
        }
    }
    fn event(&mut self, event: Event) {
        match event {
            Event::ParametersRestored => self.restored = true,
            Event::StoredParametersRejected(_) => self.rejected = true,
            _ => {}
        }
    }
}

type Device = Node<RamFlash<SLOT>, 2>;

/// An expedited SDO download to the device; `true` when it was accepted.
fn download(node: &mut Device, sink: &mut Recorder, index: u16, sub: u8, data: &[u8]) -> bool {
    let n = 4 - data.len().min(4);
    // Expedited, size indicated: command 0x23 | n << 2.
    let command = 0x23 | ((n as u8) << 2);
    let [low, high] = index.to_le_bytes();
    let mut request = [command, low, high, sub, 0, 0, 0, 0];
    request[4..4 + data.len().min(4)].copy_from_slice(&data[..data.len().min(4)]);
    let id = CanId::new(0x600 + u16::from(NODE_ID)).unwrap_or_else(|_| unreachable!());
    let frame = CanFrame::new(id, &request).unwrap_or_else(|_| unreachable!());
    sink.sdo_responses.clear();
    node.handle_frame(Instant::ZERO, &frame, sink);
    sink.sdo_responses
        .first()
        .is_some_and(|response| response[0] == 0x60)
}

/// The configuration as stored: mapping entries past the mapping count are not part of it
/// (the image holds the entries in use only), so they read 0 after a restore.
fn in_effect(config: &SafetyConfig<2>) -> SafetyConfig<2> {
    let mut config = config.clone();
    for record in &mut config.srdos {
        let count = usize::from(record.mapping_count).min(record.mapping.len());
        record.mapping[count..].fill(0);
    }
    config
}

/// The committed payload, read back through the store's public API.
fn committed(flash: &mut RamFlash<SLOT>) -> Option<Vec<u8>> {
    let mut buf = [0u8; SLOT];
    match storage::load(flash, &mut buf) {
        Ok(Some(len)) => Some(buf[..len].to_vec()),
        _ => None,
    }
}

fn report(inputs: u64) {
    if inputs >= 1024 && inputs.is_power_of_two() {
        let committed = COMMITTED.load(Ordering::Relaxed);
        let accepted = ACCEPTED.load(Ordering::Relaxed);
        eprintln!(
            "stored_parameters: {inputs} inputs, {committed} committed records decoded ({:.1} %), \
             {accepted} accepted ({:.1} %)",
            100.0 * committed as f64 / inputs as f64,
            100.0 * accepted as f64 / inputs as f64,
        );
    }
}

fuzz_target!(|input: Input| {
    let inputs = INPUTS.fetch_add(1, Ordering::Relaxed) + 1;
    // The saving node: configured over SDO, then 0x1010 "save".
    let Ok(mut saver) = Device::new(common::config(NODE_ID, false), RamFlash::new()) else {
        return;
    };
    let mut sink = Recorder::default();
    saver.poll(Instant::ZERO, &mut sink);
    for write in input.writes.iter().take(16) {
        let index = match write.object % 6 {
            0 => 0x1017,
            1 => 0x1301,
            2 => 0x1302,
            3 => 0x1381,
            4 => 0x1382,
            _ => 0x13FF,
        };
        let bytes = write.value.to_le_bytes();
        let len = [1, 2, 4, 4][usize::from(write.size & 3)];
        let _ = download(&mut saver, &mut sink, index, write.sub % 18, &bytes[..len]);
    }
    if input.validate {
        let signature = shared::safety::signature::compute(&saver.safety_config().srdos[0]);
        let _ = download(&mut saver, &mut sink, 0x13FF, 1, &signature.to_le_bytes());
        let _ = download(&mut saver, &mut sink, 0x13FE, 0, &[0xA5]);
    }
    let saved_config = saver.safety_config().clone();
    assert!(
        download(&mut saver, &mut sink, 0x1010, 1, b"save"),
        "0x1010 save on an empty medium must succeed"
    );
    let mut flash = saver.flash().clone();
    let original = committed(&mut flash).unwrap_or_else(|| unreachable!("a save commits a record"));

    // The input's changes, committed again by the store itself.
    let mut payload = original.clone();
    for edit in input.edits.iter().take(32) {
        match edit {
            Edit::Flip { at, mask } if !payload.is_empty() => {
                let at = usize::from(*at) % payload.len();
                payload[at] ^= mask;
            }
            Edit::Set { at, value } if !payload.is_empty() => {
                let at = usize::from(*at) % payload.len();
                payload[at] = *value;
            }
            Edit::Truncate { len } => payload.truncate(usize::from(*len) % (payload.len() + 1)),
            Edit::Extend { bytes } => payload.extend_from_slice(&bytes[..bytes.len().min(SLOT)]),
            _ => {}
        }
    }
    let recommitted = storage::store(&mut flash, &payload).is_ok();
    for damage in input.damage.iter().take(4) {
        let slot = if damage.second_slot { Slot::B } else { Slot::A };
        let bytes = flash.slot_mut(slot);
        bytes[usize::from(damage.at) % SLOT] ^= damage.mask;
    }
    let stored_payload = committed(&mut flash.clone());
    if recommitted && stored_payload.as_deref() == Some(&payload[..]) {
        COMMITTED.fetch_add(1, Ordering::Relaxed);
    }

    // Power-on from the medium.
    let Ok(mut node) = Device::new(common::config(NODE_ID, false), flash) else {
        report(inputs);
        return;
    };
    let mut sink = Recorder::default();
    node.poll(Instant::ZERO, &mut sink);
    assert_eq!(node.nmt_state(), NmtState::PreOperational);
    assert!(!node.is_working(), "a node powers on in the safe state");
    assert!(!(sink.restored && sink.rejected));
    if sink.rejected {
        assert!(
            sink.rejected_emcy,
            "a rejected stored configuration is reported by EMCY 6300h"
        );
    }
    if payload == original && stored_payload.as_deref() == Some(&original[..]) {
        assert!(sink.restored, "the saved configuration is restored");
        assert_eq!(in_effect(node.safety_config()), in_effect(&saved_config));
    }
    if sink.restored {
        ACCEPTED.fetch_add(1, Ordering::Relaxed);
        let restored = stored_payload.unwrap_or_else(|| unreachable!("restored from a record"));
        // Decode then encode is the identity: saving what was restored gives the same bytes.
        assert!(download(&mut node, &mut sink, 0x1010, 1, b"save"));
        let mut flash = node.flash().clone();
        assert_eq!(committed(&mut flash).as_deref(), Some(&restored[..]));
    }
    report(inputs);
});
