//! The independent SimpleCAN oracle: a bus monitor that knows the configured SDD (the SC-ID,
//! its producer's slot, the slots per cycle, the safety timeout, the node hash) and judges,
//! from the frames the consumer received and its mapped output alone, whether the output
//! ever held a value that no valid packet backed within its safety timeout (SC_REQ_20), and
//! when the rules require the safe state at a frame: a second active master (SC_REQ_26), the
//! bad-CRC leaky counter at 1000 (SC_REQ_42). A packet is valid only while the consumer must
//! be synced: from the second sync of one master on, until 2000 ms after the last sync
//! (SC_REQ_29, SC_REQ_30, SC_REQ_32).
//!
//! Diversity is required here, so this module does NOT call `shared::simplecan`: the CRC-24
//! (`docs/simplecan.md` section 4) is computed bit by bit below instead of with the `crc`
//! crate the node uses, the frames are decoded from their bytes as section 2 and 3 draw
//! them, the cycle a packet belongs to is taken from the master's sync packets and the bus
//! time, not from the consumer's own time base, and the synchronisation, the several-masters
//! rule and the leaky counter are written from the requirement texts, not from
//! `shared::simplecan::{sync, master, crc_monitor}`.

use shared::{CanFrame, Duration, Instant};

/// The CAN identifier of every time sync packet (`docs/simplecan.md` section 1).
pub const SYNC_ID: u16 = 0x02F;
/// The slot length: 1 ms (`docs/simplecan.md` section 5).
pub const SLOT_US: u64 = 1_000;

/// CRC-24 of `docs/simplecan.md` section 4, bit by bit: polynomial 7B01BDh, initial value
/// FFFFFFh, MSB first, not reflected, no final XOR.
pub fn crc24(bytes: &[u8]) -> u32 {
    let mut crc = 0x00FF_FFFFu32;
    for &byte in bytes {
        crc ^= u32::from(byte) << 16;
        for _ in 0..8 {
            crc = if crc & 0x0080_0000 != 0 {
                (crc << 1) ^ 0x007B_01BD
            } else {
                crc << 1
            };
            crc &= 0x00FF_FFFF;
        }
    }
    crc
}

/// The CRC a packet of `identifier` carries in bytes 5..7: over the node hash (big-endian,
/// never sent), `(identifier << 4) | 8` as two octets, and bytes 0..4.
pub fn packet_crc(hash: u32, identifier: u16, payload: &[u8; 5]) -> u32 {
    let mut fed = [0u8; 11];
    fed[..4].copy_from_slice(&hash.to_be_bytes());
    fed[4..6].copy_from_slice(&((identifier << 4) | 8).to_be_bytes());
    fed[6..].copy_from_slice(payload);
    crc24(&fed)
}

/// Whether `frame` is a well-formed SimpleCAN packet of `identifier` signed with `hash`:
/// a data frame, DLC 8, and the CRC in bytes 5..7 (MSB first) right.
pub fn signed_by(frame: &CanFrame, identifier: u16, hash: u32) -> bool {
    if frame.id().raw() != identifier || frame.is_remote() || frame.dlc() != 8 {
        return false;
    }
    let data = frame.raw_data();
    let payload = [data[0], data[1], data[2], data[3], data[4]];
    let sent = u32::from_be_bytes([0, data[5], data[6], data[7]]);
    packet_crc(hash, identifier, &payload) == sent
}

/// What the oracle knows of the monitored SDD entry and of the network's cycle.
#[derive(Clone, Copy, Debug)]
pub struct MonitoredEntry {
    /// The SC-ID (its CAN identifier).
    pub sc_id: u8,
    /// Its node hash.
    pub hash: u32,
    /// Its producer's slot.
    pub slot: u16,
    /// Slots per cycle.
    pub slots: u16,
    /// The consumer's safety timeout.
    pub timeout: Duration,
    /// The potential masters' SC-IDs and node hashes (a sync is signed with its master's).
    pub masters: [(u8, u32); 2],
    /// The stated buffering time (SC_REQ_33): how late a sync's time may be handed in.
    pub buffering: Duration,
}

/// How far a packet may lie outside its producer's slot, and how far two syncs of one master
/// may disagree with the time between them, and still count: ±2 ms (SC_REQ_30,
/// `docs/simplecan.md` section 5).
pub const TOLERANCE: Duration = Duration::from_millis(2);

/// Without a sync for this long a consumer is unsynced and must discard every packet until
/// two syncs of one master have synchronised it again (SC_REQ_32, SC_REQ_29, SC_REQ_30).
pub const SYNC_LOSS: Duration = Duration::from_millis(2_000);

/// The leaky counter of SC_REQ_42's note: this many bad packets more than have leaked away
/// mean the safe state.
pub const BAD_CRC_LIMIT: u32 = 1_000;

/// The leaky counter loses 1 this often: 3600 s / 1000 (SC_REQ_42's note).
pub const LEAK_PERIOD: Duration = Duration::from_millis(3_600);

/// A packet of the monitored SC-ID that the oracle found valid: signed with the right hash,
/// received while the consumer is synced, within its producer's slot of the cycle its stamp
/// names (widened by [`TOLERANCE`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ValidPacket {
    /// When it started on the bus.
    pub start: Instant,
    /// When it ended (the consumer could use it from here).
    pub end: Instant,
    /// The latest bus instant at which its slot can have started, and not after `start`:
    /// its value's age counts from here (SC_REQ_20 counts a value's age from its slot, so a
    /// packet delayed within the tolerance is no younger than its slot).
    pub produced: Instant,
    /// Its value's low byte (the mapped output is 8 bits).
    pub value: u8,
}

/// A sync the oracle found valid: its master, its end on the bus, its global time.
#[derive(Clone, Copy, Debug)]
struct Sync {
    master: u8,
    end: Instant,
    global: u64,
}

/// The sync in `frame`, if it is one that `entry`'s consumer can check: a known master in
/// byte 0, signed with that master's hash, an offset below 1000 (`docs/simplecan.md`
/// section 3). Its global time is `((cycle × N) + N − 1) × 1000 + offset` µs.
fn sync_of(entry: &MonitoredEntry, frame: &CanFrame, end: Instant) -> Option<Sync> {
    if frame.id().raw() != SYNC_ID {
        return None;
    }
    let data = frame.raw_data();
    let &(master, hash) = entry.masters.iter().find(|(sc_id, _)| *sc_id == data[0])?;
    let offset = u64::from(u16::from_be_bytes([data[3], data[4]]));
    if !signed_by(frame, SYNC_ID, hash) || offset >= SLOT_US {
        return None;
    }
    let cycle = u64::from(u16::from_be_bytes([data[1], data[2]]));
    let slots = u64::from(entry.slots);
    Some(Sync {
        master,
        end,
        global: (cycle * slots + slots - 1) * SLOT_US + offset,
    })
}

/// The packets of `entry` that a correct consumer may accept, from the bus `trace`
/// (start, end, frame) as the consumer received it.
///
/// The consumer is synced once two syncs of one master, less than [`SYNC_LOSS`] apart,
/// agree with the bus time between them within [`TOLERANCE`] (and the buffering time: each
/// sync's time was taken at most that long before it ended); it is unsynced from the start,
/// [`SYNC_LOSS`] after the last sync, and at a sync of another master until a second one of
/// that master (stricter than a consumer that follows a takeover at once: the campaigns
/// judge no packet across a takeover). The cycle is taken from the last sync: at its end the
/// global time lay between its own and that plus the buffering time.
pub fn valid_packets(
    entry: &MonitoredEntry,
    trace: &[(Instant, Instant, CanFrame)],
) -> Vec<ValidPacket> {
    let cycle_us = u64::from(entry.slots) * SLOT_US;
    let tolerance = TOLERANCE.as_micros();
    let buffering = entry.buffering.as_micros();
    let mut last: Option<Sync> = None;
    let mut synced = false;
    let mut valid = Vec::new();
    for &(start, end, frame) in trace {
        if frame.id().raw() == SYNC_ID {
            if let Some(sync) = sync_of(entry, &frame, end) {
                synced = last.is_some_and(|previous| {
                    let measured = sync.end.saturating_since(previous.end);
                    let told = sync.global.abs_diff(previous.global);
                    previous.master == sync.master
                        && measured < SYNC_LOSS
                        && told.abs_diff(measured.as_micros()) <= tolerance + buffering
                });
                last = Some(sync);
            }
            continue;
        }
        if !signed_by(&frame, u16::from(entry.sc_id), entry.hash) {
            continue;
        }
        let Some(sync) = last else {
            continue;
        };
        if !synced || end.saturating_since(sync.end) >= SYNC_LOSS {
            continue;
        }
        let (Some(since_start), Some(since_end)) = (
            start.as_micros().checked_sub(sync.end.as_micros()),
            end.as_micros().checked_sub(sync.end.as_micros()),
        ) else {
            continue;
        };
        // The stamp unwrapped to the cycle nearest the packet's (earliest) global time.
        let earliest = sync.global + since_start;
        let near = earliest / cycle_us;
        let step = i64::from(frame.raw_data()[4].wrapping_sub(near as u8) as i8);
        let Some(cycle) = near.checked_add_signed(step) else {
            continue;
        };
        let slot_start = cycle * cycle_us + u64::from(entry.slot) * SLOT_US;
        // Received (at its end) within the slot widened by the tolerance, for some global
        // time within the uncertainty.
        let received_earliest = sync.global + since_end;
        let received_latest = received_earliest + buffering;
        let in_slot = received_latest + tolerance >= slot_start
            && received_earliest < slot_start + SLOT_US + tolerance;
        if !in_slot {
            continue;
        }
        // The slot's start on the bus: at the latest, the sync's end plus the global time
        // between them (the true global time at the sync's end was not below its own).
        let latest_slot_start = sync.end.as_micros() + slot_start.saturating_sub(sync.global);
        valid.push(ValidPacket {
            start,
            end,
            produced: Instant::from_micros(latest_slot_start.min(start.as_micros())),
            value: frame.raw_data()[0],
        });
    }
    valid
}

/// The end of the last sync `entry`'s consumer could check that ended at or before `at`.
pub fn last_sync_before(
    entry: &MonitoredEntry,
    trace: &[(Instant, Instant, CanFrame)],
    at: Instant,
) -> Option<Instant> {
    trace
        .iter()
        .filter(|(_, end, _)| *end <= at)
        .filter_map(|&(_, end, frame)| sync_of(entry, &frame, end))
        .map(|sync| sync.end)
        .next_back()
}

/// The first instant at which `entry`'s consumer had heard several active masters
/// (SC_REQ_26): a checked sync from a master with a higher SC-ID than one whose sync it
/// heard less than [`SYNC_LOSS`] before. A lower SC-ID after a higher one is a takeover
/// (SC_REQ_25); a master not heard for [`SYNC_LOSS`] is gone. From then on the consumer
/// must be in its safe state.
pub fn several_masters(
    entry: &MonitoredEntry,
    trace: &[(Instant, Instant, CanFrame)],
) -> Option<Instant> {
    let mut lowest: Option<(u8, Instant)> = None;
    for &(_, end, frame) in trace {
        let Some(sync) = sync_of(entry, &frame, end) else {
            continue;
        };
        match lowest {
            Some((lower, heard))
                if lower < sync.master && end.saturating_since(heard) < SYNC_LOSS =>
            {
                return Some(end);
            }
            _ => lowest = Some((sync.master, end)),
        }
    }
    None
}

/// When the consumer's SimpleCAN layer started: the end of the first NMT start command on
/// the bus (identifier 000h, command 01h), from which its bad-CRC counter leaks.
pub fn started_at(trace: &[(Instant, Instant, CanFrame)]) -> Option<Instant> {
    trace
        .iter()
        .find(|(_, _, frame)| {
            frame.id().raw() == 0 && frame.dlc() == 2 && frame.raw_data()[0] == 0x01
        })
        .map(|&(_, end, _)| end)
}

/// The instant the consumer's leaky bad-CRC counter reaches [`BAD_CRC_LIMIT`] (SC_REQ_42),
/// counted by the requirement's note, not by the node's counter: from `started`, every
/// packet the consumer can check (a data frame of DLC 8 on its SC-ID or a master's, or a
/// sync naming a known master) whose CRC is wrong adds 1, at its end; every
/// [`LEAK_PERIOD`] after `started` the counter, if not 0, loses 1, before a packet that
/// ends at the same instant is counted. `None`: it never does.
pub fn bad_crc_trip(
    entry: &MonitoredEntry,
    trace: &[(Instant, Instant, CanFrame)],
    started: Instant,
) -> Option<Instant> {
    let leak = LEAK_PERIOD.as_micros();
    let mut count: u32 = 0;
    let mut next_leak = started.as_micros() + leak;
    let hash_of = |sc_id: u8| {
        if sc_id == entry.sc_id {
            Some(entry.hash)
        } else {
            entry
                .masters
                .iter()
                .find(|(master, _)| *master == sc_id)
                .map(|&(_, hash)| hash)
        }
    };
    for &(_, end, frame) in trace {
        if end < started || frame.is_remote() || frame.dlc() != 8 {
            continue;
        }
        let identifier = frame.id().raw();
        let signer = if identifier == SYNC_ID {
            frame.raw_data()[0]
        } else {
            match u8::try_from(identifier) {
                Ok(sc_id) => sc_id,
                Err(_) => continue,
            }
        };
        let Some(hash) = hash_of(signer) else {
            continue;
        };
        if signed_by(&frame, identifier, hash) {
            continue;
        }
        while next_leak <= end.as_micros() {
            count = count.saturating_sub(1);
            next_leak += leak;
        }
        count += 1;
        if count >= BAD_CRC_LIMIT {
            return Some(end);
        }
    }
    None
}

/// The first instant at which the consumer's output held a non-zero value that no valid
/// packet backed: a valid packet of that value must have ended at or before the instant and
/// been produced no more than the safety timeout before it. `outputs` are the output's
/// changes (instant, value), `until` the end of the observation. `None`: every value was
/// backed.
pub fn first_unbacked(
    entry: &MonitoredEntry,
    valid: &[ValidPacket],
    outputs: &[(Instant, u8)],
    until: Instant,
) -> Option<Instant> {
    for (n, &(from, value)) in outputs.iter().enumerate() {
        if value == 0 {
            continue;
        }
        let to = outputs.get(n + 1).map_or(until, |&(at, _)| at);
        let mut cursor = from;
        while cursor < to {
            let backing = valid
                .iter()
                .filter(|packet| packet.value == value && packet.end <= cursor)
                .map(|packet| packet.produced + entry.timeout)
                .max();
            match backing {
                Some(expires) if expires >= cursor => cursor = expires + Duration::from_micros(1),
                _ => return Some(cursor),
            }
        }
    }
    None
}

/// The first instant at or after `from` at which the output was not 0: the safe state the
/// oracle requires from `from` on was missing or left. `None`: 0 throughout.
pub fn first_not_safe(outputs: &[(Instant, u8)], from: Instant) -> Option<Instant> {
    let before = outputs
        .iter()
        .rev()
        .find(|(at, _)| *at <= from)
        .map_or(0, |&(_, value)| value);
    if before != 0 {
        return Some(from);
    }
    outputs
        .iter()
        .find(|&&(at, value)| at > from && value != 0)
        .map(|&(at, _)| at)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The check value `docs/simplecan.md` section 4 gives: "123456789" → 74A079h.
    #[test]
    fn sc_req_15_the_oracle_crc24_has_the_documented_check_value() {
        assert_eq!(crc24(b"123456789"), 0x74_A079);
    }
}
