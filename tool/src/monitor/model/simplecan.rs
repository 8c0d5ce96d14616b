//! SimpleCAN as the monitor sees it (`docs/simplecan.md`): every packet on 02Fh..07Fh decoded
//! with `shared::simplecan::frame` and the node hashes of the network file, the value and age
//! of each SC-ID, the syncs and their master, the slot each data packet arrived in against its
//! configured slot, and the packets whose CRC failed.
//!
//! Without a network file the monitor knows no node hash (they are never sent, SC_REQ_15), so
//! it cannot check a CRC: it counts those packets per identifier as undecodable without the
//! hash, and decodes nothing.
//!
//! Slot timing: the monitor takes the network's global time from the latest sync (its cycle
//! number and offset, section 3) at the sync's timestamp, and runs it on with the bus's time.
//! A data packet's offset is its timestamp on that time minus the start of its configured slot
//! in the cycle its stamp names (`Schedule::timely`, the consumers' own rule); the spread of
//! the offsets is the slot timing jitter. The sync is stamped when its last bit is on the bus,
//! like every other frame, so the offsets carry the sync's own frame time (about 0.27 ms at
//! 500 kbit/s) as a constant; the jitter does not.

use crate::simplecan::SimpleCanNetwork;
use shared::CanFrame;
use shared::simplecan::frame::{DecodeError, Packet, decode, is_simplecan};
use shared::simplecan::schedule::{Schedule, Untimely};
use shared::simplecan::{NodeHash, ScId};
use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

/// How many slot offsets each SC-ID keeps.
pub const OFFSETS: usize = 60;

/// What the network file says about one SC-ID.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ScIdWatch {
    /// The producer's node-ID.
    pub producer: Option<u8>,
    /// Its slot.
    pub slot: Option<u16>,
    /// The consumers' node-IDs.
    pub consumers: Vec<u8>,
    /// The shortest safety timeout among its consumers (SC_REQ_20).
    pub timeout: Option<Duration>,
}

/// One SC-ID on the bus.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ScIdView {
    /// From the network file.
    pub watch: ScIdWatch,
    /// Packets whose CRC checked.
    pub packets: u64,
    /// The latest such packet's value and cycle stamp.
    pub value: Option<(u32, u8)>,
    /// When its value was produced, on the bus's time: the start of its slot when the slot
    /// is known, else the packet's arrival.
    pub produced_at: Option<Duration>,
    /// Arrivals after the start of the configured slot, µs, oldest first.
    pub offsets: VecDeque<u64>,
    /// Packets that came outside their slot (widened by the 2 ms sync tolerance).
    pub outside_slot: u64,
    /// Packets whose CRC failed against this SC-ID's hash.
    pub bad_crc: u64,
    /// Packets on this identifier that could not be checked: no hash known.
    pub undecodable: u64,
}

impl ScIdView {
    /// The age of the latest value at `now` (SC_REQ_20: from the start of its slot).
    pub fn age(&self, now: Duration) -> Option<Duration> {
        self.produced_at.map(|at| now.saturating_sub(at))
    }

    /// The earliest and latest offset into the slot, µs, and their spread (the jitter).
    pub fn jitter(&self) -> Option<(u64, u64, u64)> {
        let min = *self.offsets.iter().min()?;
        let max = *self.offsets.iter().max()?;
        Some((min, max, max - min))
    }
}

/// The syncs of one master.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct MasterView {
    /// Syncs whose CRC checked.
    pub syncs: u64,
    /// The latest one's bus time, cycle number and offset (µs).
    pub last: Option<(Duration, u16, u16)>,
    /// The time between its latest two syncs.
    pub interval: Option<Duration>,
}

/// The SimpleCAN traffic as the monitor saw it.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SimpleCanView {
    /// The node hashes of the network file, by SC-ID.
    hashes: BTreeMap<u8, u32>,
    /// The network file's cycle and slots, when it gives a valid one.
    pub schedule: Option<Schedule>,
    /// Every SC-ID of the file or seen on the bus.
    pub sc_ids: BTreeMap<u8, ScIdView>,
    /// Every master heard, by the SC-ID its syncs carry.
    pub masters: BTreeMap<u8, MasterView>,
    /// The latest sync: its bus time and the global time it gives (µs).
    anchor: Option<(Duration, u64)>,
    /// Syncs that could not be checked: no hash known for their master.
    pub undecodable_syncs: u64,
    /// Packets whose CRC failed, data and syncs (SC_REQ_42 counts these).
    pub bad_crc: u64,
    /// Packets refused before or after their CRC for another reason (length, remote frame,
    /// a sync's master byte or offset).
    pub malformed: u64,
}

impl SimpleCanView {
    /// The view of `network`'s SimpleCAN part: its hashes, slots, producers and consumers.
    pub fn for_network(network: &SimpleCanNetwork) -> SimpleCanView {
        let mut view = SimpleCanView {
            hashes: network.hashes.clone(),
            ..SimpleCanView::default()
        };
        let mut producers = Vec::new();
        for (&node, part) in &network.nodes {
            for produced in &part.produced {
                let watch = &mut view.sc_ids.entry(produced.sc_id).or_default().watch;
                watch.producer = Some(node);
                watch.slot = Some(produced.slot);
                if let Some(sc_id) = ScId::new(produced.sc_id) {
                    producers.push((sc_id, produced.slot));
                }
            }
            for consumed in &part.consumed {
                let watch = &mut view.sc_ids.entry(consumed.sc_id).or_default().watch;
                watch.consumers.push(node);
                let timeout = Duration::from_millis(u64::from(consumed.timeout_ms));
                watch.timeout = Some(watch.timeout.map_or(timeout, |t| t.min(timeout)));
            }
        }
        view.schedule = <Schedule>::new(
            network.slots_per_cycle,
            network.cycles_between_syncs,
            &producers,
        )
        .ok();
        view
    }

    /// Whether the view knows the node hashes (a network file was given).
    pub fn has_hashes(&self) -> bool {
        !self.hashes.is_empty()
    }

    /// The network's global time at bus time `now`, µs, from the latest sync.
    pub fn global_time(&self, now: Duration) -> Option<u64> {
        self.anchor
            .map(|(at, global)| global.saturating_add(now.saturating_sub(at).as_micros() as u64))
    }

    /// Takes in a frame on a SimpleCAN identifier at `now`; returns a line worth noting.
    pub fn feed(&mut self, now: Duration, frame: &CanFrame) -> Option<String> {
        if !is_simplecan(frame.id()) {
            return None;
        }
        let hashes = &self.hashes;
        let lookup = |sc_id: ScId| hashes.get(&sc_id.raw()).map(|hash| NodeHash(*hash));
        match decode(frame, &lookup) {
            Ok(Packet::Sync(sync)) => {
                let master = sync.master().raw();
                let view = self.masters.entry(master).or_default();
                view.syncs += 1;
                view.interval = view.last.map(|(at, _, _)| now.saturating_sub(at));
                view.last = Some((now, sync.cycle(), sync.offset_micros()));
                let first = view.syncs == 1;
                if let Some(schedule) = &self.schedule {
                    let cycle = schedule.cycle();
                    let global = cycle.slot_start(u64::from(sync.cycle()), cycle.sync_slot())
                        + u64::from(sync.offset_micros());
                    self.anchor = Some((now, global));
                }
                first.then(|| format!("SimpleCAN: syncs from master SC-ID {master:02X}h"))
            }
            Ok(Packet::Data(data)) => {
                let sc_id = data.sc_id.raw();
                let global = self.global_time(now);
                let view = self.sc_ids.entry(sc_id).or_default();
                view.packets += 1;
                view.value = Some((data.value, data.cycle_stamp));
                view.produced_at = Some(now);
                let (Some(schedule), Some(global)) = (&self.schedule, global) else {
                    return None;
                };
                match schedule.timely(data.sc_id, data.cycle_stamp, global) {
                    Ok(start) => {
                        let offset = global.saturating_sub(start);
                        if view.offsets.len() == OFFSETS {
                            view.offsets.pop_front();
                        }
                        view.offsets.push_back(offset);
                        view.produced_at = Some(now.saturating_sub(Duration::from_micros(offset)));
                        None
                    }
                    Err(Untimely::OutsideItsSlot { by_micros }) => {
                        view.outside_slot += 1;
                        Some(format!(
                            "SimpleCAN SC-ID {sc_id:02X}h: packet stamped {:02X}h outside its slot by {by_micros} µs",
                            data.cycle_stamp
                        ))
                    }
                    Err(Untimely::NoSlot) => None,
                }
            }
            Err(DecodeError::UnknownScId { sc_id }) => {
                if frame.id() == shared::simplecan::frame::SYNC_IDENTIFIER {
                    self.undecodable_syncs += 1;
                } else {
                    self.sc_ids.entry(sc_id.raw()).or_default().undecodable += 1;
                }
                None
            }
            Err(DecodeError::BadCrc { sc_id }) => {
                self.bad_crc += 1;
                let view = self.sc_ids.entry(sc_id.raw()).or_default();
                view.bad_crc += 1;
                let what = if frame.id() == shared::simplecan::frame::SYNC_IDENTIFIER {
                    "sync"
                } else {
                    "packet"
                };
                Some(format!(
                    "SimpleCAN SC-ID {:02X}h: {what} with a bad CRC ({} in all)",
                    sc_id.raw(),
                    self.bad_crc
                ))
            }
            Err(error) => {
                self.malformed += 1;
                Some(format!(
                    "SimpleCAN identifier {:03X}h: {}",
                    frame.id().raw(),
                    describe(error)
                ))
            }
        }
    }
}

/// A refusal in words (docs/simplecan.md section 10).
pub fn describe(error: DecodeError) -> String {
    match error {
        DecodeError::NotSimpleCan => "not a SimpleCAN identifier".to_owned(),
        DecodeError::RemoteFrame => "a remote frame".to_owned(),
        DecodeError::WrongLength { dlc } => format!("{dlc} data bytes, not 8"),
        DecodeError::InvalidMasterScId { raw } => {
            format!("a sync naming {raw:02X}h, which is not an SC-ID")
        }
        DecodeError::UnknownScId { sc_id } => {
            format!("SC-ID {:02X}h without a known node hash", sc_id.raw())
        }
        DecodeError::BadCrc { sc_id } => format!("bad CRC for SC-ID {:02X}h", sc_id.raw()),
        DecodeError::OffsetOutOfRange { offset_micros } => {
            format!("a sync offset of {offset_micros} µs, not below 1000")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::monitor::model::Monitor;
    use shared::simplecan::frame::{DataPacket, SyncPacket};

    const FILE: &str = r#"[simplecan]
network_name = "monitor test"
slots_per_cycle = 10
cycles_between_syncs = 10
buffering_us = 0

[[node]]
id = 1
identity = { vendor = 1, product = 2, serial = 1 }
[node.simplecan]
potential_master = true
produce = [{ sc_id = 0x30, slot = 0, object = "input" }]

[[node]]
id = 2
identity = { vendor = 1, product = 2, serial = 2 }
[node.simplecan]
produce = [{ sc_id = 0x41, slot = 3, object = "input" }]
consume = [{ sc_id = 0x30, timeout_ms = 50, object = "output" }]

[[node]]
id = 33
identity = { vendor = 1, product = 2, serial = 33 }
[node.simplecan]
consume = [{ sc_id = 0x41, timeout_ms = 20, object = "output" }]
"#;

    fn sc(raw: u8) -> ScId {
        ScId::new(raw).unwrap()
    }

    fn ms(micros: u64) -> Duration {
        Duration::from_micros(micros)
    }

    fn setup() -> (Monitor, BTreeMap<u8, u32>) {
        let network = crate::network_file::parse(FILE, "net.toml").unwrap();
        let hashes = network.simplecan.as_ref().unwrap().hashes.clone();
        (Monitor::for_network(&network), hashes)
    }

    fn data(hashes: &BTreeMap<u8, u32>, sc_id: u8, value: u32, stamp: u8) -> CanFrame {
        DataPacket {
            sc_id: sc(sc_id),
            value,
            cycle_stamp: stamp,
        }
        .encode(NodeHash(hashes[&sc_id]))
    }

    fn sync(hashes: &BTreeMap<u8, u32>, cycle: u16, offset: u16) -> CanFrame {
        SyncPacket::new(sc(0x30), cycle, offset)
            .unwrap()
            .encode(NodeHash(hashes[&0x30]))
    }

    /// A sync of cycle 0 taken 300 µs into slot 9 arrives at bus time 9.3 ms: the bus's time
    /// is then the global time. SC-ID 41h (slot 3) stamped 1 arrives 200 µs into slot 3 of
    /// cycle 1, stamped 2 500 µs into cycle 2's: offsets 200 and 500, jitter 300 µs; its age
    /// counts from the slot's start.
    #[test]
    fn sc_req_18_each_packets_offset_into_its_slot_and_the_jitter() {
        let (mut monitor, hashes) = setup();
        monitor.feed(ms(9_300), &sync(&hashes, 0, 300));
        assert_eq!(monitor.simplecan.global_time(ms(9_300)), Some(9_300));
        monitor.feed(ms(13_200), &data(&hashes, 0x41, 1, 1));
        monitor.feed(ms(23_500), &data(&hashes, 0x41, 1, 2));
        let view = &monitor.simplecan.sc_ids[&0x41];
        assert_eq!(view.packets, 2);
        assert_eq!(view.offsets, [200, 500]);
        assert_eq!(view.jitter(), Some((200, 500, 300)));
        assert_eq!(view.value, Some((1, 2)));
        assert_eq!(view.age(ms(30_000)), Some(ms(7_000)));
        assert_eq!(view.watch.producer, Some(2));
        assert_eq!(view.watch.slot, Some(3));
        assert_eq!(view.watch.timeout, Some(ms(20_000)));
        assert_eq!(view.watch.consumers, [33]);
    }

    /// Stamped for cycle 2 (slot 3 at 23 ms, accepted up to 26 ms with the 2 ms tolerance),
    /// arriving at 28 ms: outside its slot by 2000 µs, counted and noted.
    #[test]
    fn sc_req_18_a_packet_outside_its_slot_is_counted_with_the_distance() {
        let (mut monitor, hashes) = setup();
        monitor.feed(ms(9_300), &sync(&hashes, 0, 300));
        monitor.feed(ms(28_000), &data(&hashes, 0x41, 1, 2));
        let view = &monitor.simplecan.sc_ids[&0x41];
        assert_eq!((view.packets, view.outside_slot), (1, 1));
        assert!(view.offsets.is_empty());
        assert_eq!(
            monitor.happenings.back().unwrap().1,
            "SimpleCAN SC-ID 41h: packet stamped 02h outside its slot by 2000 µs"
        );
    }

    #[test]
    fn sc_req_22_syncs_are_shown_with_their_master_and_interval() {
        let (mut monitor, hashes) = setup();
        monitor.feed(ms(9_300), &sync(&hashes, 0, 300));
        monitor.feed(ms(109_300), &sync(&hashes, 10, 300));
        let master = &monitor.simplecan.masters[&0x30];
        assert_eq!(master.syncs, 2);
        assert_eq!(master.interval, Some(ms(100_000)));
        assert_eq!(master.last, Some((ms(109_300), 10, 300)));
        assert_eq!(monitor.simplecan.global_time(ms(109_300)), Some(109_300));
    }

    /// A packet of 41h signed with another hash (another network's, say) fails its CRC: not a
    /// value, counted per SC-ID and in all (SC_REQ_42 counts these), and noted.
    #[test]
    fn sc_req_42_packets_with_a_bad_crc_are_counted() {
        let (mut monitor, hashes) = setup();
        let mut foreign = hashes.clone();
        foreign.insert(0x41, hashes[&0x41] ^ 1);
        monitor.feed(ms(1_000), &data(&foreign, 0x41, 7, 0));
        monitor.feed(ms(2_000), &data(&foreign, 0x41, 7, 0));
        let view = &monitor.simplecan.sc_ids[&0x41];
        assert_eq!((view.packets, view.bad_crc, view.value), (0, 2, None));
        assert_eq!(monitor.simplecan.bad_crc, 2);
        assert_eq!(
            monitor.happenings.back().unwrap().1,
            "SimpleCAN SC-ID 41h: packet with a bad CRC (2 in all)"
        );
    }

    /// Without a network file no hash is known: packets are counted per identifier as
    /// undecodable, syncs apart, and nothing is decoded.
    #[test]
    fn sc_req_15_without_the_file_packets_cannot_be_decoded() {
        let (_, hashes) = setup();
        let mut monitor = Monitor::default();
        monitor.feed(ms(1_000), &data(&hashes, 0x41, 7, 0));
        monitor.feed(ms(2_000), &sync(&hashes, 0, 0));
        let view = &monitor.simplecan;
        assert!(!view.has_hashes());
        assert_eq!(view.sc_ids[&0x41].undecodable, 1);
        assert_eq!(view.sc_ids[&0x41].packets, 0);
        assert_eq!(view.undecodable_syncs, 1);
        assert!(view.masters.is_empty());
    }

    #[test]
    fn a_packet_of_another_length_is_refused_in_words() {
        let (mut monitor, _) = setup();
        let id = shared::CanId::new(0x41).unwrap();
        monitor.feed(ms(1_000), &CanFrame::new(id, &[0; 7]).unwrap());
        assert_eq!(monitor.simplecan.malformed, 1);
        assert_eq!(
            monitor.happenings.back().unwrap().1,
            "SimpleCAN identifier 041h: 7 data bytes, not 8"
        );
    }
}
