//! The independent SimpleCAN oracle: a bus monitor that knows the configured SDD (the SC-ID,
//! its producer's slot, the slots per cycle, the safety timeout, the node hash) and judges,
//! from the frames on the bus and the consumer's mapped output alone, whether the output ever
//! held a value that no valid packet backed within its safety timeout (SC_REQ_20).
//!
//! Diversity is required here, so this module does NOT call `shared::simplecan`: the CRC-24
//! (`docs/simplecan.md` section 4) is computed bit by bit below instead of with the `crc`
//! crate the node uses, the frames are decoded from their bytes as section 2 and 3 draw
//! them, and the cycle a packet belongs to is taken from the master's sync packets and the
//! bus time, not from the consumer's own time base.

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

/// A packet of the monitored SC-ID that the oracle found valid: signed with the right hash,
/// in the producer's slot, with the cycle stamp of that slot's cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ValidPacket {
    /// When it started on the bus (the consumer counts its age from about here).
    pub start: Instant,
    /// When it ended (the consumer could use it from here).
    pub end: Instant,
    /// Its value's low byte (the mapped output is 8 bits).
    pub value: u8,
}

/// The packets of `entry` that a correct consumer may accept, from the bus `trace`
/// (start, end, frame). The cycle is taken from the last valid sync before the packet: its
/// global time `((cycle × N) + N − 1) × 1000 + offset` µs (`docs/simplecan.md` section 3)
/// was taken at most the buffering time before the sync ended.
pub fn valid_packets(
    entry: &MonitoredEntry,
    trace: &[(Instant, Instant, CanFrame)],
) -> Vec<ValidPacket> {
    let cycle_us = u64::from(entry.slots) * SLOT_US;
    let mut sync: Option<(Instant, u64)> = None;
    let mut valid = Vec::new();
    for &(start, end, frame) in trace {
        let data = frame.raw_data();
        if frame.id().raw() == SYNC_ID {
            let master = entry.masters.iter().find(|(sc_id, _)| *sc_id == data[0]);
            let offset = u64::from(u16::from_be_bytes([data[3], data[4]]));
            if let Some(&(_, hash)) = master
                && signed_by(&frame, SYNC_ID, hash)
                && offset < SLOT_US
            {
                let cycle = u64::from(u16::from_be_bytes([data[1], data[2]]));
                let global = (cycle * u64::from(entry.slots) + u64::from(entry.slots) - 1)
                    * SLOT_US
                    + offset;
                sync = Some((end, global));
            }
            continue;
        }
        if !signed_by(&frame, u16::from(entry.sc_id), entry.hash) {
            continue;
        }
        let Some((sync_end, sync_global)) = sync else {
            continue;
        };
        // The global time the packet started at, give or take the sync's buffering.
        let Some(since) = start.as_micros().checked_sub(sync_end.as_micros()) else {
            continue;
        };
        let latest = sync_global + entry.buffering.as_micros() + since;
        let earliest = sync_global + since;
        let slot_start = |global: u64| {
            let cycle = global / cycle_us;
            (cycle, cycle * cycle_us + u64::from(entry.slot) * SLOT_US)
        };
        // In the producer's slot of a cycle whose stamp the packet carries, for some time
        // within the uncertainty.
        let in_slot = [earliest, latest].into_iter().any(|global| {
            let (cycle, from) = slot_start(global);
            global >= from && global < from + SLOT_US && (cycle & 0xFF) as u8 == data[4]
        });
        if in_slot {
            valid.push(ValidPacket {
                start,
                end,
                value: data[0],
            });
        }
    }
    valid
}

/// The first instant at which the consumer's output held a non-zero value that no valid
/// packet backed: a valid packet of that value must have ended at or before the instant and
/// started no more than the safety timeout before it. `outputs` are the output's changes
/// (instant, value), `until` the end of the observation. `None`: every value was backed.
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
                .map(|packet| packet.start + entry.timeout)
                .max();
            match backing {
                Some(expires) if expires >= cursor => cursor = expires + Duration::from_micros(1),
                _ => return Some(cursor),
            }
        }
    }
    None
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
