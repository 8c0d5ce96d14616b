//! The hub's core: participants joined to one [`Bus`] in real time. A participant speaks
//! one of two framings: CAN-over-serial ([`emulation_wire`], the emulated MCUs'
//! USART2) or socketcand (the tools on the TCP port: the configuration tool, python-can,
//! anything that speaks the linux-can/socketcand text protocol), served by the tool crate's
//! sans-I/O session ([`safety_config::socketcand::server`]), the same module the tool's own
//! tests run in-process.
//!
//! An emulated channel receives only the frames its CAN controller would let through: the
//! identifiers it listed last ([`Wire::Accept`], the acceptance list the hardware layer
//! writes into bxCAN's filter banks), every frame before its first list. A socketcand client
//! receives every frame, as a socketcand daemon's raw socket does.
//!
//! Sans-I/O like the rest: the program feeds it the bytes each participant sent and the time,
//! and asks it what to write to whom and when to wake next.

use crate::bus::{Bus, Delivery, Injection, QueueFull};
use emulation_wire::{
    AcceptChunk, Decoder, LinkBytes, SerialError, Status, Wire, encode, encode_wire,
};
use safety_config::socketcand::server::{self, Output, Session};
use shared::{CanFrame, Instant};
use std::collections::BTreeSet;

/// Bytes for one participant, to be written in one write of their own: one CAN-over-serial
/// frame, or one socketcand message (python-can compares each handshake reply it receives by
/// one `recv` with exact equality, so replies are never joined).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Outgoing {
    /// The participant.
    pub to: usize,
    /// The bytes.
    pub bytes: Vec<u8>,
}

/// How long after its `rawmode` reply a socketcand client receives no bus frame (the tool
/// crate's [`server::RAW_MODE_GRACE`], which says why); frames that complete meanwhile are
/// held and handed out, in order, when it is over.
pub const RAW_MODE_GRACE: shared::Duration =
    shared::Duration::from_micros(server::RAW_MODE_GRACE.as_micros() as u64);

/// The hub's time as the session's clock.
fn clock(at: Instant) -> std::time::Duration {
    std::time::Duration::from_micros(at.as_micros())
}

/// How a participant frames CAN frames on its connection.
#[derive(Debug)]
enum Framing {
    /// CAN-over-serial, as the emulated MCUs speak it.
    Serial(Decoder),
    /// socketcand (a tool on the TCP port).
    Socketcand(Box<Session>),
}

/// Which frames an emulated channel's controller lets through.
#[derive(Clone, Debug, Default)]
struct Acceptance {
    /// The identifiers of the last complete list; `None`: no list yet, every frame.
    list: Option<BTreeSet<u16>>,
    /// A list whose last chunk has not come yet.
    incoming: Option<BTreeSet<u16>>,
}

impl Acceptance {
    /// Takes one chunk of a list; the list applies once its last chunk has come. A chunk
    /// without the first one before it is dropped (the list before stays).
    fn take(&mut self, chunk: &AcceptChunk) {
        if chunk.is_first() {
            self.incoming = Some(BTreeSet::new());
        }
        if let Some(incoming) = self.incoming.as_mut() {
            incoming.extend(chunk.ids());
            if chunk.is_last() {
                self.list = self.incoming.take();
            }
        }
    }

    /// `true` when the controller lets `frame` through: a data frame on a listed identifier
    /// (the channel follows no remote frame, `dual_channel::filters`), or any frame before
    /// the first list.
    fn accepts(&self, frame: &CanFrame) -> bool {
        self.list
            .as_ref()
            .is_none_or(|ids| !frame.is_remote() && ids.contains(&frame.id().raw()))
    }
}

/// The hub: each participant's framing, the bus, frames in flight.
pub struct Hub {
    bus: Bus,
    framings: Vec<Framing>,
    /// Per participant, the frames its controller lets through (emulated channels).
    acceptance: Vec<Acceptance>,
    present: Vec<bool>,
    in_flight: Vec<Delivery>,
    /// Replies to socketcand clients not yet handed out by [`Hub::poll`].
    replies: Vec<Outgoing>,
    /// socketcand clients the hub is done with (an `open` of an unknown bus): the caller
    /// closes their connections, after writing what [`Hub::poll`] handed out for them.
    pub closing: Vec<usize>,
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
    /// Frames of emulated MCUs refused because their transmit queue was full: (time,
    /// participant, frame). See [`Hub::receive`].
    pub overflowed: Vec<(Instant, usize, CanFrame)>,
    /// The latest time a frame was queued for the bus: no frame waiting now was queued after
    /// it, so an arbitration at or after it is one every waiting frame can take part in
    /// ([`Hub::next_arbitration`]).
    last_queued: Instant,
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
            framings: Vec::new(),
            acceptance: Vec::new(),
            present: Vec::new(),
            in_flight: Vec::new(),
            replies: Vec::new(),
            closing: Vec::new(),
            completed: Vec::new(),
            malformed: Vec::new(),
            statuses: Vec::new(),
            links: Vec::new(),
            acknowledgements: Vec::new(),
            overflowed: Vec::new(),
            last_queued: Instant::ZERO,
        }
    }

    /// The bus (statistics, bit rate).
    pub fn bus(&self) -> &Bus {
        &self.bus
    }

    /// Participant `id` joined, speaking CAN-over-serial (an emulated MCU).
    pub fn join(&mut self, id: usize) {
        if id >= self.present.len() {
            self.present.resize(id + 1, false);
            self.framings
                .resize_with(id + 1, || Framing::Serial(Decoder::new()));
            self.acceptance.resize_with(id + 1, Acceptance::default);
        }
        self.present[id] = true;
    }

    /// Participant `id` joined as a socketcand client of the bus named `bus` (e.g. `can0`):
    /// its greeting is handed out by the next [`Hub::poll`], and bus frames reach it only
    /// once it has switched to raw mode.
    pub fn join_socketcand(&mut self, id: usize, bus: &str) {
        self.join(id);
        self.framings[id] = Framing::Socketcand(Box::new(Session::new(bus)));
        self.replies.retain(|reply| reply.to != id);
        self.replies.push(Outgoing {
            to: id,
            bytes: server::GREETING.as_bytes().to_vec(),
        });
    }

    /// Participant `id` left; what it still had queued is dropped.
    pub fn leave(&mut self, id: usize) {
        if let Some(present) = self.present.get_mut(id) {
            *present = false;
        }
        if let Some(framing) = self.framings.get_mut(id) {
            *framing = Framing::Serial(Decoder::new());
        }
        if let Some(acceptance) = self.acceptance.get_mut(id) {
            *acceptance = Acceptance::default();
        }
        self.replies.retain(|reply| reply.to != id);
        self.closing.retain(|closing| *closing != id);
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

    /// Bytes participant `id` sent at `now`. From an emulated MCU: CAN frames go on the bus,
    /// status reports to [`Hub::statuses`], link bytes to [`Hub::links`], acknowledgements of
    /// grants to [`Hub::acknowledgements`]; an input message is for boards, not from them:
    /// malformed. From a socketcand client: its commands are served (replies by the next
    /// [`Hub::poll`]) and the frames it sends go on the bus.
    ///
    /// Returns how many bytes were taken. An emulated MCU's bytes are always all taken: its
    /// acknowledgements of grants share the line with its frames, and the virtual time
    /// waits for them (`crate::pace`). Were its intake stopped while its transmit queue is
    /// full, the time would stand still, and with it the bus that would empty the queue:
    /// under traffic of higher priority than the MCU's own frames, for longer than the
    /// lookahead, the whole network froze (the bus-load case, `docs/can-receive.md`). A frame
    /// that finds the queue full ([`crate::bus::TRANSMIT_QUEUE`]) is refused instead and
    /// recorded in [`Hub::overflowed`], as `board::hw`'s full transmit queue refuses one (the
    /// channel loop counts it as dropped there). A socketcand client is not paced: its intake
    /// stops before the message that would overflow its queue, it waits, and the caller
    /// hands the rest again after [`Hub::poll`] has put frames on the bus.
    pub fn receive(&mut self, now: Instant, id: usize, bytes: &[u8]) -> usize {
        self.join(id);
        if matches!(self.framings[id], Framing::Socketcand(_)) {
            return self.receive_socketcand(now, id, bytes);
        }
        for &byte in bytes {
            let Framing::Serial(decoder) = &mut self.framings[id] else {
                break;
            };
            match decoder.push(byte) {
                Some(Ok(Wire::Can(frame))) => self.queue_or_refuse(now, id, frame),
                Some(Ok(Wire::Status(status))) => self.statuses.push((now, id, status)),
                Some(Ok(Wire::Link(bytes))) => self.links.push((id, bytes)),
                Some(Ok(Wire::Time(micros))) => self
                    .acknowledgements
                    .push((id, Instant::from_micros(micros))),
                Some(Ok(Wire::Accept(chunk))) => self.acceptance[id].take(&chunk),
                Some(Ok(Wire::Input(_))) => self.malformed.push((id, SerialError::Malformed)),
                Some(Err(error)) => self.malformed.push((id, error)),
                None => {}
            }
        }
        bytes.len()
    }

    /// Queues an emulated MCU's `frame`, or records it in [`Hub::overflowed`] when its
    /// transmit queue is full.
    fn queue_or_refuse(&mut self, now: Instant, id: usize, frame: CanFrame) {
        if self.queue(now, id, frame).is_err() {
            self.overflowed.push((now, id, frame));
        }
    }

    /// Queues participant `id`'s `frame` at `now`, after the bus has carried, back to back,
    /// what was waiting before `now` ([`Hub::catch_up`]): the frame takes part in the
    /// arbitrations from `now` on, not in one that began before it was sent.
    fn queue(&mut self, now: Instant, id: usize, frame: CanFrame) -> Result<(), QueueFull> {
        self.catch_up(now);
        self.bus.try_send(id, frame)?;
        self.last_queued = self.last_queued.max(now);
        Ok(())
    }

    /// When the next arbitration begins, if a frame is waiting: when the bus is free, but
    /// not before the latest frame was queued. Every frame waiting was queued by then, and
    /// none had a chance at the bus since: the previous arbitration either took the bus
    /// until after it was queued or found it waiting with nothing to send.
    fn next_arbitration(&self) -> Option<Instant> {
        self.bus.next_start(self.last_queued)
    }

    /// Runs the arbitrations that begin before `before`, one after the other at the instants
    /// the bus becomes free, as a real bus carries frames back to back: the hub's loop runs
    /// when the host lets it, and an arbitration held until its next round would leave the
    /// bus idle meanwhile in the virtual time, and make a frame of low priority wait as long
    /// as a sender of higher priority has another frame queued at each round (seen: node 33's
    /// SDO answers and both nodes' heartbeats held about half a second behind a tool sending
    /// frames on low identifiers, the bus idle most of that time).
    fn catch_up(&mut self, before: Instant) {
        while let Some(start) = self.next_arbitration().filter(|start| *start < before) {
            let deliveries = self.bus.arbitrate(start);
            self.in_flight.extend(deliveries);
        }
    }

    /// A socketcand client's bytes, one message (up to and including its `>`) at a time, so
    /// that a full transmit FIFO stops the intake before the message that would overflow it.
    fn receive_socketcand(&mut self, now: Instant, id: usize, bytes: &[u8]) -> usize {
        let mut taken = 0;
        while taken < bytes.len() {
            if !self.bus.has_room(id) || self.closing.contains(&id) {
                return taken;
            }
            let rest = &bytes[taken..];
            let end = server::first_message(rest);
            let Framing::Socketcand(session) = &mut self.framings[id] else {
                return taken;
            };
            for output in session.feed(&rest[..end], clock(now)) {
                match output {
                    Output::Reply(text) => self.replies.push(Outgoing {
                        to: id,
                        bytes: text.into_bytes(),
                    }),
                    // One message holds at most one frame, and the FIFO had room for it.
                    Output::Send(frame) => {
                        let _ = self.queue(now, id, frame);
                    }
                    Output::Close => self.closing.push(id),
                }
            }
            taken += end;
        }
        taken
    }

    /// The identifiers emulated channel `id` listed last ([`Wire::Accept`]), in order; `None`
    /// before its first list (it receives every frame).
    pub fn accepted(&self, id: usize) -> Option<Vec<u16>> {
        let list = self.acceptance.get(id)?.list.as_ref()?;
        Some(list.iter().copied().collect())
    }

    /// How many frames participant `id` has waiting for the bus.
    pub fn queued(&self, id: usize) -> usize {
        self.bus.queued(id)
    }

    /// `true` while participant `id` can queue another frame (its bytes are taken).
    pub fn has_room(&self, id: usize) -> bool {
        self.bus.has_room(id)
    }

    /// `frame` goes on the bus from participant `id` (the hub's own sender, say) at `now`,
    /// which need not be connected; it competes in arbitration like any other. Refused when
    /// that participant's transmit FIFO is full.
    pub fn send(&mut self, now: Instant, id: usize, frame: CanFrame) -> Result<(), QueueFull> {
        self.queue(now, id, frame)
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
    /// sender whose controller lets them through; the next arbitration starts when the bus is
    /// free. Returns what to write, and
    /// when to call again (`None`: when bytes arrive).
    ///
    /// Replies to socketcand clients come first; a socketcand client receives bus frames as
    /// raw-mode `frame` messages stamped with the hub's time (the end of the frame on the
    /// bus), and none before it has switched to raw mode.
    pub fn poll(&mut self, now: Instant) -> (Vec<Outgoing>, Option<Instant>) {
        let mut out = std::mem::take(&mut self.replies);
        for (to, framing) in self.framings.iter_mut().enumerate() {
            if let Framing::Socketcand(session) = framing {
                out.extend(
                    session
                        .release(clock(now))
                        .into_iter()
                        .map(|message| Outgoing {
                            to,
                            bytes: message.into_bytes(),
                        }),
                );
            }
        }
        loop {
            let (due, later): (Vec<_>, Vec<_>) =
                self.in_flight.drain(..).partition(|d| d.at <= now);
            self.in_flight = later;
            for delivery in &due {
                self.completed
                    .push((delivery.at, delivery.frame, delivery.from));
                let serial = encode(&delivery.frame).to_vec();
                let stamp = clock(delivery.at);
                for (to, present) in self.present.iter().enumerate() {
                    if !*present || to == delivery.from {
                        continue;
                    }
                    match &mut self.framings[to] {
                        Framing::Serial(_) if self.acceptance[to].accepts(&delivery.frame) => {
                            out.push(Outgoing {
                                to,
                                bytes: serial.clone(),
                            });
                        }
                        Framing::Serial(_) => {}
                        Framing::Socketcand(session) => {
                            if let Some(message) = session.frame(&delivery.frame, stamp, clock(now))
                            {
                                out.push(Outgoing {
                                    to,
                                    bytes: message.into_bytes(),
                                });
                            }
                        }
                    }
                }
            }
            // Every arbitration due by `now`, each when the bus became free ([`Hub::catch_up`]);
            // a dropped or muted frame leaves it free. What ends by `now` is handed out above.
            match self.next_arbitration() {
                Some(start) if start <= now => {
                    let deliveries = self.bus.arbitrate(start);
                    self.in_flight.extend(deliveries);
                }
                _ => break,
            }
        }
        let grace_ends = self.framings.iter().filter_map(|framing| match framing {
            Framing::Socketcand(session) => session
                .release_at()
                .map(|at| Instant::from_micros(at.as_micros() as u64)),
            Framing::Serial(_) => None,
        });
        let next = self
            .in_flight
            .iter()
            .map(|d| d.at)
            .chain(self.next_arbitration())
            .chain(grace_ends)
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

    /// A socketcand client that sends faster than the bus takes frames waits: the hub takes
    /// its bytes up to a full transmit FIFO, the rest once the bus has room, and every frame
    /// reaches the others, in order.
    #[test]
    fn a_flooding_tool_waits_for_the_bus_and_loses_nothing() {
        let mut hub = Hub::new(1_000_000);
        hub.join(0);
        hub.join_socketcand(1, "can0");
        hub.receive(Instant::ZERO, 1, b"< open can0 >< rawmode >");
        let frames = 3 * crate::bus::TRANSMIT_QUEUE;
        let mut pending: Vec<u8> = (0..frames)
            .flat_map(|n| format!("< send 300 2 {:02X} {:02X} >", n % 256, n / 256).into_bytes())
            .collect();
        let first = hub.receive(Instant::ZERO, 1, &pending);
        assert!(first < pending.len(), "a full FIFO makes the sender wait");
        assert!(!hub.has_room(1));
        pending.drain(..first);
        let mut now = Instant::ZERO;
        let mut received = Vec::new();
        loop {
            let (out, next) = hub.poll(now);
            received.extend(out.iter().filter(|o| o.to == 0).map(|o| decode(&o.bytes)));
            let taken = hub.receive(now, 1, &pending);
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
        assert!(hub.overflowed.is_empty());
    }

    /// An emulated MCU whose transmit queue is full still has every byte taken: the frame
    /// beyond the queue is refused and recorded, and what follows it on the line (here an
    /// acknowledgement of a grant and a status report) is handled at once.
    #[test]
    fn an_emulated_mcu_with_a_full_transmit_queue_still_has_its_acknowledgements_taken() {
        let mut hub = Hub::new(500_000);
        hub.join(0);
        hub.join(1);
        let frames = crate::bus::TRANSMIT_QUEUE + 3;
        let mut bytes: Vec<u8> = (0..frames)
            .flat_map(|n| encode(&frame(0x5A1, &[n as u8])).to_vec())
            .collect();
        bytes.extend_from_slice(&encode_wire(&Wire::Time(4_000)));
        bytes.extend_from_slice(&encode_wire(&Wire::Status(Status::default())));
        let at = Instant::from_micros(5);
        assert_eq!(hub.receive(at, 0, &bytes), bytes.len(), "every byte taken");
        assert_eq!(hub.acknowledgements, [(0, Instant::from_micros(4_000))]);
        assert_eq!(hub.statuses.len(), 1);
        assert_eq!(hub.queued(0), crate::bus::TRANSMIT_QUEUE);
        let refused: Vec<(Instant, usize, CanFrame)> = (crate::bus::TRANSMIT_QUEUE..frames)
            .map(|n| (at, 0, frame(0x5A1, &[n as u8])))
            .collect();
        assert_eq!(hub.overflowed, refused);
    }

    /// The deadlock of the bus-load case, as a regression test on the hub and its pacer: a
    /// tool floods the bus with frames that win arbitration over an emulated MCU's (281h over
    /// 5A1h), the MCU's transmit queue is full, and it acknowledges every grant right after
    /// its frames. The virtual time keeps running (before, it stood still one lookahead after
    /// the start, and the whole network with it), and the bus keeps carrying the flood.
    #[test]
    fn the_virtual_time_runs_on_while_a_flood_of_higher_priority_holds_an_mcus_queue_full() {
        use crate::pace::{GRANT_PERIOD, LOOKAHEAD, Pacer};
        let mut hub = Hub::new(500_000);
        let mut pacer = Pacer::new(LOOKAHEAD, GRANT_PERIOD);
        hub.join(0);
        pacer.join(0);
        hub.join_socketcand(1, "can0");
        hub.receive(Instant::ZERO, 1, b"< open can0 >< rawmode >");
        let flood = b"< send 281 8 55 55 55 55 55 55 55 55 >".repeat(64);
        // The MCU's line: its frames first, then (each step) the acknowledgement of a grant.
        let mut line: Vec<u8> = (0..2 * crate::bus::TRANSMIT_QUEUE)
            .flat_map(|n| encode(&frame(0x5A1, &[n as u8])).to_vec())
            .collect();
        let mut tool_backlog: Vec<u8> = Vec::new();
        // Steps of 100 µs, so that the bus (a frame of 281h takes about 250 µs at 500 kbit/s)
        // is hardly ever idle between them: about 660 frames in 200 ms.
        for step in 0..=2_000u64 {
            let host = Instant::from_micros(100 * step);
            let now = pacer.advance(host);
            if tool_backlog.len() < flood.len() {
                tool_backlog.extend_from_slice(&flood);
            }
            let taken = hub.receive(now, 1, &tool_backlog);
            tool_backlog.drain(..taken);
            let taken = hub.receive(now, 0, &line);
            line.drain(..taken);
            for (id, time) in hub.acknowledgements.drain(..) {
                pacer.acknowledged(id, time, host);
            }
            let _ = hub.poll(now);
            for _ in pacer.grants_due(host) {
                line.extend_from_slice(&encode_wire(&Wire::Time(now.as_micros())));
            }
        }
        assert!(
            pacer.now() >= Instant::from_millis(190),
            "the virtual time stood still at {:?}",
            pacer.now()
        );
        let flood_frames = hub
            .completed
            .iter()
            .filter(|(_, frame, _)| frame.id().raw() == 0x281)
            .count();
        assert!(flood_frames > 600, "{flood_frames} flood frames on the bus");
        assert_eq!(hub.overflowed.len(), crate::bus::TRANSMIT_QUEUE);
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

    /// Polls from `now` until nothing is due any more: what was handed out, and the time then.
    fn run_idle(hub: &mut Hub, mut now: Instant) -> (Vec<Outgoing>, Instant) {
        let mut all = Vec::new();
        loop {
            let (out, next) = hub.poll(now);
            all.extend(out);
            match next {
                Some(next) => now = next,
                None => return (all, now),
            }
        }
    }

    fn text(outgoing: &Outgoing) -> &str {
        std::str::from_utf8(&outgoing.bytes).expect("socketcand speaks text")
    }

    /// A socketcand client on the hub: the greeting, one reply per command each in its own
    /// write, no bus frame before it switched to raw mode nor within [`RAW_MODE_GRACE`] of
    /// the reply, then every frame as a raw-mode message; the frames it sends reach the
    /// emulated MCUs in their own framing.
    #[test]
    fn a_socketcand_client_joins_the_bus_in_raw_mode_only() {
        let mut hub = Hub::new(500_000);
        hub.join(0);
        hub.join_socketcand(1, "can0");
        let (out, _) = hub.poll(Instant::ZERO);
        assert_eq!(out.len(), 1);
        assert_eq!((out[0].to, text(&out[0])), (1, "< hi >"));

        // A frame that completes before the client is in raw mode does not reach it.
        hub.receive(Instant::ZERO, 0, &encode(&frame(0x701, &[0x7F])));
        let (_, next) = hub.poll(Instant::ZERO);
        let (out, _) = hub.poll(next.unwrap());
        assert!(out.is_empty(), "{out:?}");

        let at = next.unwrap();
        assert_eq!(hub.receive(at, 1, b"< open can0 >< rawmode >"), 24);
        let (out, _) = hub.poll(at);
        let replies: Vec<&str> = out.iter().map(text).collect();
        assert_eq!(replies, ["< ok >", "< ok >"], "each reply on its own");

        // A frame that ends within the grace after the reply is held until the grace is over.
        hub.receive(at, 0, &encode(&frame(0x181, &[1, 0xAB])));
        let (_, next) = hub.poll(at);
        let end = next.unwrap();
        let (out, next) = hub.poll(end);
        assert!(out.is_empty(), "{out:?}");
        assert_eq!(next, Some(at + RAW_MODE_GRACE));
        let (out, _) = hub.poll(at + RAW_MODE_GRACE);
        assert_eq!(out.len(), 1);
        let micros = end.as_micros();
        assert_eq!(
            text(&out[0]),
            format!(
                "< frame 181 {}.{:06} 01AB >",
                micros / 1_000_000,
                micros % 1_000_000
            )
        );

        // After the grace, frames go out as they end; the client's own reach the MCU.
        let later = at + RAW_MODE_GRACE;
        hub.receive(later, 0, &encode(&frame(0x001, &[])));
        let (out, later) = run_idle(&mut hub, later);
        assert!(text(&out[0]).starts_with("< frame 001 "), "{out:?}");
        hub.receive(later, 1, b"< send 601 8 40 18 10 01 00 00 00 00 >");
        let (out, _) = run_idle(&mut hub, later);
        let to_mcu: Vec<CanFrame> = out
            .iter()
            .filter(|o| o.to == 0)
            .map(|o| decode(&o.bytes))
            .collect();
        assert_eq!(to_mcu, [frame(0x601, &[0x40, 0x18, 0x10, 1, 0, 0, 0, 0])]);
        assert!(out.iter().all(|o| o.to != 1), "no echo to the sender");
    }

    /// A client that opens a bus the hub does not have is told so and closed; a flooding
    /// socketcand sender waits for room in its transmit FIFO, one message at a time.
    #[test]
    fn a_socketcand_client_is_closed_on_an_unknown_bus_and_waits_when_flooding() {
        let mut hub = Hub::new(1_000_000);
        hub.join_socketcand(3, "can0");
        let _ = hub.poll(Instant::ZERO);
        hub.receive(Instant::ZERO, 3, b"< open vcan7 >");
        assert_eq!(hub.closing, [3]);
        let (out, _) = hub.poll(Instant::ZERO);
        assert_eq!(text(&out[0]), "< error could not open bus >");

        hub.join(0);
        hub.join_socketcand(1, "can0");
        hub.receive(Instant::ZERO, 1, b"< open can0 >< rawmode >");
        let message = b"< send 300 1 55 >";
        let flood: Vec<u8> = message
            .iter()
            .copied()
            .cycle()
            .take(message.len() * 3 * crate::bus::TRANSMIT_QUEUE)
            .collect();
        let taken = hub.receive(Instant::ZERO, 1, &flood);
        assert_eq!(taken, message.len() * crate::bus::TRANSMIT_QUEUE);
        assert!(!hub.has_room(1));
    }

    /// The identifiers of the frames in `out` for participant `to`, in order.
    fn frames_for(out: &[Outgoing], to: usize) -> Vec<u16> {
        out.iter()
            .filter(|o| o.to == to)
            .map(|o| decode(&o.bytes).id().raw())
            .collect()
    }

    /// An emulated channel receives every frame until it lists the identifiers its controller
    /// accepts, then only data frames on them (a list in several chunks once its last chunk
    /// has come); a channel without a list keeps receiving every frame; a channel that leaves
    /// and comes back receives everything again until it lists anew.
    #[test]
    fn an_emulated_channel_receives_only_what_its_controller_accepts() {
        let mut hub = Hub::new(1_000_000);
        for id in 0..3 {
            hub.join(id);
        }
        // NMT, an SDO answer, an SDO request, and a remote frame on the request's identifier.
        let send_all = |hub: &mut Hub, at: Instant| {
            for frame in [
                frame(0x000, &[1, 0]),
                frame(0x581, &[0x43, 0, 0x10, 0, 0, 0, 0, 0]),
                frame(0x601, &[0x40, 0, 0x10, 0, 0, 0, 0, 0]),
                CanFrame::remote(CanId::new(0x601).unwrap(), 0).unwrap(),
            ] {
                hub.receive(at, 0, &encode(&frame));
            }
            run_idle(hub, at).0
        };
        let everything = [0x000, 0x581, 0x601, 0x601];
        assert_eq!(hub.accepted(1), None);
        let out = send_all(&mut hub, Instant::ZERO);
        assert_eq!(frames_for(&out, 1), everything);

        // A list of more identifiers than one chunk holds: NMT, the SDO request and filler.
        let ids: Vec<u16> = [0x000, 0x601]
            .into_iter()
            .chain(0x100..0x100 + emulation_wire::ACCEPT_CHUNK as u16)
            .collect();
        let chunks: Vec<Vec<u8>> = AcceptChunk::split(&ids)
            .map(|chunk| encode_wire(&Wire::Accept(chunk)).to_vec())
            .collect();
        assert_eq!(chunks.len(), 2);
        hub.receive(Instant::ZERO, 1, &chunks[0]);
        assert_eq!(hub.accepted(1), None, "not before the last chunk");
        hub.receive(Instant::ZERO, 1, &chunks[1]);
        let mut sorted = ids.clone();
        sorted.sort_unstable();
        assert_eq!(hub.accepted(1), Some(sorted));

        let out = send_all(&mut hub, Instant::from_millis(10));
        assert_eq!(
            frames_for(&out, 1),
            [0x000, 0x601],
            "data frames on its list only"
        );
        assert_eq!(frames_for(&out, 2), everything, "no list: every frame");

        hub.leave(1);
        hub.join(1);
        assert_eq!(hub.accepted(1), None);
        let out = send_all(&mut hub, Instant::from_millis(20));
        assert_eq!(frames_for(&out, 1), everything);
    }

    /// A socketcand client receives every frame whatever the emulated channels listed.
    #[test]
    fn a_socketcand_client_receives_every_frame() {
        let mut hub = Hub::new(1_000_000);
        hub.join(0);
        hub.join_socketcand(1, "can0");
        hub.receive(Instant::ZERO, 1, b"< open can0 >< rawmode >");
        let list = AcceptChunk::split(&[0x000]).next().unwrap();
        hub.receive(Instant::ZERO, 0, &encode_wire(&Wire::Accept(list)));
        let later = Instant::ZERO + RAW_MODE_GRACE;
        hub.receive(later, 0, &encode(&frame(0x701, &[0x05])));
        let (out, _) = run_idle(&mut hub, later);
        assert!(
            out.iter()
                .any(|o| o.to == 1 && text(o).starts_with("< frame 701 ")),
            "{out:?}"
        );
    }

    /// The end on the bus of each frame that completed, with its identifier, in order.
    fn ends(hub: &Hub) -> Vec<(u16, u64)> {
        hub.completed
            .iter()
            .map(|(at, frame, _)| (frame.id().raw(), at.as_micros()))
            .collect()
    }

    /// ISO 11898-1 10.4.2.2 (bus idle: a node may start a frame once the intermission after
    /// the previous one is over): frames waiting go on the bus one right after the other in
    /// the virtual time, however late the hub's loop polls. A sender of higher priority with
    /// a queue of frames (a tool on low identifiers) takes the bus only for their bit times,
    /// and a node's heartbeat queued with them follows at once, not at the end of the hub's
    /// next rounds: one arbitration per round left the bus idle in the virtual time between
    /// rounds and held the heartbeat as long as the tool had a frame queued at each.
    #[test]
    fn iso11898_1_10_4_2_2_frames_follow_each_other_on_the_bus_however_late_the_hub_polls() {
        let mut hub = Hub::new(500_000);
        for id in 0..3 {
            hub.join(id);
        }
        let load: Vec<CanFrame> = (0..10).map(|n| frame(0x281 + n, &[0x55; 8])).collect();
        let bytes: Vec<u8> = load.iter().flat_map(|f| encode(f).to_vec()).collect();
        hub.receive(Instant::ZERO, 1, &bytes);
        hub.receive(Instant::ZERO, 0, &encode(&frame(0x721, &[5])));
        let _ = hub.poll(Instant::ZERO);
        // The hub's loop comes back only 20 ms later (a busy host).
        let (out, _) = hub.poll(Instant::from_millis(20));
        let ends = ends(&hub);
        let mut expected = Vec::new();
        let mut end = 0;
        for frame in load.iter().chain([&frame(0x721, &[5])]) {
            end += crate::bus::frame_time(frame, 500_000).as_micros();
            expected.push((frame.id().raw(), end));
        }
        assert_eq!(ends, expected, "back to back from 0, in identifier order");
        assert_eq!(
            out.iter().filter(|o| o.to == 2).count(),
            11,
            "every frame reached the receiver"
        );
    }

    /// ISO 11898-1 10.4.2.2: a frame sent while the bus was busy with another takes part in
    /// the arbitration at that frame's end, even when a frame of higher priority is sent
    /// later, before the hub's loop came round: it is on the bus first.
    #[test]
    fn iso11898_1_10_4_2_2_a_frame_is_not_overtaken_by_one_sent_after_the_bus_fell_free() {
        let mut hub = Hub::new(500_000);
        for id in 0..4 {
            hub.join(id);
        }
        hub.receive(Instant::ZERO, 1, &encode(&frame(0x281, &[0x55; 8])));
        let _ = hub.poll(Instant::ZERO);
        hub.receive(Instant::from_micros(10), 0, &encode(&frame(0x721, &[5])));
        // 10 ms later, a frame of higher priority: the bus was free long before.
        let later = Instant::from_millis(10);
        hub.receive(later, 2, &encode(&frame(0x050, &[1])));
        let _ = hub.poll(later);
        let _ = hub.poll(later + shared::Duration::from_millis(1));
        let first = crate::bus::frame_time(&frame(0x281, &[0x55; 8]), 500_000).as_micros();
        let heartbeat = crate::bus::frame_time(&frame(0x721, &[5]), 500_000).as_micros();
        let late = crate::bus::frame_time(&frame(0x050, &[1]), 500_000).as_micros();
        assert_eq!(
            ends(&hub),
            [
                (0x281, first),
                (0x721, first + heartbeat),
                (0x050, later.as_micros() + late)
            ]
        );
    }

    /// A frame sent while the bus was idle starts when it was sent, not earlier (the bus
    /// cannot carry a frame before its sender had it) and not at the hub's next round.
    #[test]
    fn a_frame_sent_to_an_idle_bus_starts_when_it_was_sent() {
        let mut hub = Hub::new(500_000);
        hub.join(0);
        hub.join(1);
        hub.receive(Instant::ZERO, 1, &encode(&frame(0x281, &[1])));
        let _ = hub.poll(Instant::ZERO);
        let sent = Instant::from_millis(5);
        hub.receive(sent, 0, &encode(&frame(0x721, &[5])));
        let _ = hub.poll(Instant::from_millis(8));
        let heartbeat = crate::bus::frame_time(&frame(0x721, &[5]), 500_000).as_micros();
        assert_eq!(ends(&hub)[1], (0x721, sent.as_micros() + heartbeat));
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
