//! The hub's core: participants that speak CAN-over-serial joined to one [`Bus`] in real time.
//!
//! Sans-I/O like the rest: the program feeds it the bytes each participant sent and the time,
//! and asks it what to write to whom and when to wake next.

use crate::bus::{Bus, Delivery, Injection, QueueFull};
use emulation_wire::{Decoder, LinkBytes, SerialError, Status, Wire, encode, encode_wire};
use shared::{CanFrame, Instant};

/// Bytes for one participant.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Outgoing {
    /// The participant.
    pub to: usize,
    /// CAN-over-serial bytes of one frame.
    pub bytes: Vec<u8>,
}

/// The hub: decoders per participant, the bus, frames in flight.
pub struct Hub {
    bus: Bus,
    decoders: Vec<Decoder>,
    present: Vec<bool>,
    in_flight: Vec<Delivery>,
    /// Frames that completed on the bus: (end time, frame, sender), for traces.
    pub completed: Vec<(Instant, CanFrame, usize)>,
    /// Byte streams that did not decode, per participant (a participant's framing is broken).
    pub malformed: Vec<(usize, SerialError)>,
    /// Status reports of the participants' boards: (arrival, participant, status).
    pub statuses: Vec<(Instant, usize, Status)>,
    /// Link bytes the participants sent, for the channel at the other end of their link, in
    /// the order they came: (participant, bytes).
    pub links: Vec<(usize, LinkBytes)>,
    /// Grants the participants acknowledged (`crate::pace`): (participant, virtual time).
    pub acknowledgements: Vec<(usize, Instant)>,
}

impl Hub {
    /// A hub for a bus at `bit_rate`.
    pub fn new(bit_rate: u32) -> Self {
        // Each participant's frames leave by identifier: an emulated channel's as `board::hw`
        // queues them (`board::transmit_queue`); a tool's requests go one at a time.
        let mut bus = Bus::new(bit_rate, 0);
        bus.set_transmit_mailboxes(crate::bus::ORDERED_BY_IDENTIFIER);
        Hub {
            bus,
            decoders: Vec::new(),
            present: Vec::new(),
            in_flight: Vec::new(),
            completed: Vec::new(),
            malformed: Vec::new(),
            statuses: Vec::new(),
            links: Vec::new(),
            acknowledgements: Vec::new(),
        }
    }

    /// The bus (statistics, bit rate).
    pub fn bus(&self) -> &Bus {
        &self.bus
    }

    /// Participant `id` joined.
    pub fn join(&mut self, id: usize) {
        if id >= self.present.len() {
            self.present.resize(id + 1, false);
            self.decoders.resize_with(id + 1, Decoder::new);
        }
        self.present[id] = true;
    }

    /// Participant `id` left; what it still had queued is dropped.
    pub fn leave(&mut self, id: usize) {
        if let Some(present) = self.present.get_mut(id) {
            *present = false;
        }
        self.bus.leave(id);
    }

    /// Adds a fault on the bus.
    pub fn inject(&mut self, injection: Injection) {
        self.bus.inject(injection);
    }

    /// Removes the faults for which `keep` is false (e.g. unmutes a participant).
    pub fn retain_faults(&mut self, keep: impl FnMut(&Injection) -> bool) {
        self.bus.retain_faults(keep);
    }

    /// Bytes participant `id` sent at `now`: CAN frames go on the bus, status reports to
    /// [`Hub::statuses`], link bytes to [`Hub::links`], acknowledgements of grants to
    /// [`Hub::acknowledgements`]. An input message is for boards, not from them: malformed.
    ///
    /// Returns how many bytes were taken: all of them unless the participant's transmit FIFO
    /// filled ([`crate::bus::TRANSMIT_QUEUE`]); then the sender waits, and the caller hands the
    /// rest again after [`Hub::poll`] has put frames on the bus.
    pub fn receive(&mut self, now: Instant, id: usize, bytes: &[u8]) -> usize {
        self.join(id);
        for (taken, &byte) in bytes.iter().enumerate() {
            if !self.bus.has_room(id) {
                return taken;
            }
            match self.decoders[id].push(byte) {
                // `has_room` was checked before this byte, so the frame is queued.
                Some(Ok(Wire::Can(frame))) => {
                    let _ = self.bus.try_send(id, frame);
                }
                Some(Ok(Wire::Status(status))) => self.statuses.push((now, id, status)),
                Some(Ok(Wire::Link(bytes))) => self.links.push((id, bytes)),
                Some(Ok(Wire::Time(micros))) => self
                    .acknowledgements
                    .push((id, Instant::from_micros(micros))),
                Some(Ok(Wire::Input(_))) => self.malformed.push((id, SerialError::Malformed)),
                Some(Err(error)) => self.malformed.push((id, error)),
                None => {}
            }
        }
        bytes.len()
    }

    /// `true` while participant `id` can queue another frame (its bytes are taken).
    pub fn has_room(&self, id: usize) -> bool {
        self.bus.has_room(id)
    }

    /// `frame` goes on the bus from participant `id` (the hub's own sender, say), which need
    /// not be connected; it competes in arbitration like any other. Refused when that
    /// participant's transmit FIFO is full.
    pub fn send(&mut self, id: usize, frame: CanFrame) -> Result<(), QueueFull> {
        self.bus.try_send(id, frame)
    }

    /// The bytes that set a board's input pin to `value`.
    pub fn input(value: u8) -> Vec<u8> {
        encode_wire(&Wire::Input(value)).to_vec()
    }

    /// The bytes that grant a board the virtual time `time` (`crate::pace`).
    pub fn grant(time: Instant) -> Vec<u8> {
        encode_wire(&Wire::Time(time.as_micros())).to_vec()
    }

    /// The bytes that hand a board link bytes from the other channel of its node.
    pub fn link(bytes: &LinkBytes) -> Vec<u8> {
        encode_wire(&Wire::Link(*bytes)).to_vec()
    }

    /// Everything due at `now`: frames that ended go to every present participant but their
    /// sender; the next arbitration starts when the bus is free. Returns what to write, and
    /// when to call again (`None`: when bytes arrive).
    pub fn poll(&mut self, now: Instant) -> (Vec<Outgoing>, Option<Instant>) {
        let mut out = Vec::new();
        loop {
            let (due, later): (Vec<_>, Vec<_>) =
                self.in_flight.drain(..).partition(|d| d.at <= now);
            self.in_flight = later;
            for delivery in &due {
                self.completed
                    .push((delivery.at, delivery.frame, delivery.from));
                let bytes = encode(&delivery.frame).to_vec();
                for (to, present) in self.present.iter().enumerate() {
                    if *present && to != delivery.from {
                        out.push(Outgoing {
                            to,
                            bytes: bytes.clone(),
                        });
                    }
                }
            }
            // Arbitrate while the bus is free at `now`; a dropped or muted frame leaves it free.
            if self.bus.next_start(now).is_some_and(|start| start <= now) {
                let deliveries = self.bus.arbitrate(now);
                if deliveries.is_empty() {
                    continue;
                }
                self.in_flight.extend(deliveries);
            }
            break;
        }
        let next = self
            .in_flight
            .iter()
            .map(|d| d.at)
            .chain(self.bus.next_start(now))
            .min();
        (out, next)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bus::{Fault, Match};
    use shared::{CanId, Duration};

    fn frame(id: u16, data: &[u8]) -> CanFrame {
        CanFrame::new(CanId::new(id).unwrap(), data).unwrap()
    }

    fn decode(bytes: &[u8]) -> CanFrame {
        let mut decoder = Decoder::new();
        match bytes.iter().find_map(|&b| decoder.push(b)) {
            Some(Ok(Wire::Can(frame))) => frame,
            other => panic!("not a frame: {other:?}"),
        }
    }

    #[test]
    fn frames_reach_everyone_but_the_sender_after_their_bit_time() {
        let mut hub = Hub::new(500_000);
        for id in 0..3 {
            hub.join(id);
        }
        hub.receive(Instant::ZERO, 1, &encode(&frame(0x101, &[1])));
        let (out, next) = hub.poll(Instant::ZERO);
        assert!(out.is_empty(), "still on the bus");
        let end = next.unwrap();
        assert_eq!(
            end.as_micros(),
            crate::bus::frame_time(&frame(0x101, &[1]), 500_000).as_micros()
        );
        let (out, next) = hub.poll(end);
        let receivers: Vec<usize> = out.iter().map(|o| o.to).collect();
        assert_eq!(receivers, [0, 2]);
        assert_eq!(decode(&out[0].bytes), frame(0x101, &[1]));
        assert_eq!(next, None);
        assert_eq!(hub.completed.len(), 1);
    }

    #[test]
    fn competing_frames_go_in_identifier_order() {
        let mut hub = Hub::new(1_000_000);
        for id in 0..3 {
            hub.join(id);
        }
        hub.receive(Instant::ZERO, 0, &encode(&frame(0x701, &[5])));
        hub.receive(Instant::ZERO, 1, &encode(&frame(0x102, &[0xFE])));
        hub.receive(Instant::ZERO, 2, &encode(&frame(0x101, &[0x01])));
        let mut now = Instant::ZERO;
        let mut order = Vec::new();
        loop {
            let (out, next) = hub.poll(now);
            order.extend(
                out.iter()
                    .filter(|o| o.to == 0 || o.to == 1)
                    .map(|o| decode(&o.bytes).id().raw()),
            );
            match next {
                Some(next) => now = next,
                None => break,
            }
        }
        order.dedup();
        assert_eq!(order, [0x101, 0x102, 0x701]);
    }

    #[test]
    fn injected_faults_apply_and_broken_framing_is_reported() {
        let mut hub = Hub::new(250_000);
        hub.join(0);
        hub.join(1);
        hub.inject(Injection::new(
            Match::next_with_id(0x102, Instant::ZERO),
            Fault::Drop,
        ));
        hub.receive(Instant::ZERO, 0, &encode(&frame(0x102, &[0xFE])));
        let (_, next) = hub.poll(Instant::ZERO);
        let (out, _) = hub.poll(next.unwrap_or(Instant::ZERO) + Duration::from_millis(1));
        assert!(out.is_empty(), "dropped");
        hub.receive(Instant::ZERO, 1, &[0x05, 0x01, 0x00]);
        assert_eq!(hub.malformed.len(), 1);
    }

    /// A participant that sends faster than the bus takes frames waits: the hub takes its
    /// bytes up to a full transmit FIFO, the rest once the bus has room, and every frame
    /// reaches the others, in order.
    #[test]
    fn a_flooding_sender_waits_for_the_bus_and_loses_nothing() {
        let mut hub = Hub::new(1_000_000);
        hub.join(0);
        hub.join(1);
        let frames = 3 * crate::bus::TRANSMIT_QUEUE;
        let mut pending: Vec<u8> = (0..frames)
            .flat_map(|n| encode(&frame(0x300, &(n as u16).to_le_bytes())).to_vec())
            .collect();
        let first = hub.receive(Instant::ZERO, 0, &pending);
        assert!(first < pending.len(), "a full FIFO makes the sender wait");
        assert!(!hub.has_room(0));
        pending.drain(..first);
        let mut now = Instant::ZERO;
        let mut received = Vec::new();
        loop {
            let (out, next) = hub.poll(now);
            received.extend(out.iter().filter(|o| o.to == 1).map(|o| decode(&o.bytes)));
            let taken = hub.receive(now, 0, &pending);
            pending.drain(..taken);
            match next {
                Some(next) => now = next,
                None if pending.is_empty() => break,
                None => {}
            }
        }
        let expected: Vec<CanFrame> = (0..frames)
            .map(|n| frame(0x300, &(n as u16).to_le_bytes()))
            .collect();
        assert_eq!(received, expected);
    }

    /// Link bytes and acknowledgements of grants are kept off the bus, in the order they came.
    #[test]
    fn link_bytes_and_acknowledgements_are_kept_off_the_bus() {
        let mut hub = Hub::new(500_000);
        hub.join(0);
        hub.join(1);
        let hello = LinkBytes::new(b"hello").unwrap();
        let mut bytes = encode_wire(&Wire::Link(hello)).to_vec();
        bytes.extend_from_slice(&encode_wire(&Wire::Time(1_234)));
        hub.receive(Instant::ZERO, 0, &bytes);
        assert_eq!(hub.links, [(0, hello)]);
        assert_eq!(hub.acknowledgements, [(0, Instant::from_micros(1_234))]);
        let (out, next) = hub.poll(Instant::ZERO);
        assert!(out.is_empty() && next.is_none(), "nothing on the bus");
        let mut decoder = Decoder::new();
        let relayed: Vec<_> = Hub::link(&hello)
            .into_iter()
            .chain(Hub::grant(Instant::from_micros(7)))
            .filter_map(|b| decoder.push(b))
            .collect();
        assert_eq!(relayed, [Ok(Wire::Link(hello)), Ok(Wire::Time(7))]);
    }

    #[test]
    fn status_reports_are_kept_off_the_bus() {
        let mut hub = Hub::new(500_000);
        hub.join(0);
        hub.join(1);
        let status = Status {
            nmt: 5,
            working: true,
            ..Status::default()
        };
        let at = Instant::from_micros(7);
        hub.receive(at, 0, &encode_wire(&Wire::Status(status)));
        assert_eq!(hub.statuses, [(at, 0, status)]);
        let (out, next) = hub.poll(at);
        assert!(out.is_empty() && next.is_none(), "nothing on the bus");
        hub.receive(at, 0, &Hub::input(0));
        assert_eq!(
            hub.malformed.len(),
            1,
            "input pins are set by the hub, not by boards"
        );
    }
}
