//! The hub's core: participants joined to one [`Bus`] in real time. Every connected
//! participant is a socketcand client (a tool on the TCP port: the configuration tool,
//! python-can, anything that speaks the linux-can/socketcand text protocol), served by the
//! tool crate's sans-I/O session ([`safety_config::socketcand::server`]), the same module the
//! tool's own tests run in-process; the hub's own senders (the control port's `insert`, its
//! generated load) put frames on the bus without a connection ([`Hub::send`]). A client
//! receives every frame but its own, as a socketcand daemon's raw socket does.
//!
//! Sans-I/O like the rest: the program feeds it the bytes each participant sent and the time,
//! and asks it what to write to whom and when to wake next.

use crate::bus::{Bus, Delivery, Injection, QueueFull};
use safety_config::socketcand::server::{self, Output, Session};
use shared::{CanFrame, Instant};

/// Bytes for one participant, to be written in one write of their own: one socketcand
/// message (python-can compares each handshake reply it receives by one `recv` with exact
/// equality, so replies are never joined).
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

/// The hub: each connected participant's session, the bus, frames in flight.
pub struct Hub {
    bus: Bus,
    /// Per participant, its socketcand session while it is connected.
    sessions: Vec<Option<Box<Session>>>,
    in_flight: Vec<Delivery>,
    /// Replies to socketcand clients not yet handed out by [`Hub::poll`].
    replies: Vec<Outgoing>,
    /// socketcand clients the hub is done with (an `open` of an unknown bus): the caller
    /// closes their connections, after writing what [`Hub::poll`] handed out for them.
    pub closing: Vec<usize>,
    /// Frames that completed on the bus: (end time, frame, sender), for traces.
    pub completed: Vec<(Instant, CanFrame, usize)>,
    /// The latest time a frame was queued for the bus: no frame waiting now was queued after
    /// it, so an arbitration at or after it is one every waiting frame can take part in
    /// ([`Hub::next_arbitration`]).
    last_queued: Instant,
}

impl Hub {
    /// A hub for a bus at `bit_rate`.
    pub fn new(bit_rate: u32) -> Self {
        // Each participant's frames leave by identifier: a tool's requests go one at a time,
        // and the hub's own senders queue one frame at a time.
        let mut bus = Bus::new(bit_rate, 0);
        bus.set_transmit_mailboxes(crate::bus::ORDERED_BY_IDENTIFIER);
        Hub {
            bus,
            sessions: Vec::new(),
            in_flight: Vec::new(),
            replies: Vec::new(),
            closing: Vec::new(),
            completed: Vec::new(),
            last_queued: Instant::ZERO,
        }
    }

    /// The bus (statistics, bit rate).
    pub fn bus(&self) -> &Bus {
        &self.bus
    }

    /// Participant `id` joined as a socketcand client of the bus named `bus` (e.g. `can0`):
    /// its greeting is handed out by the next [`Hub::poll`], and bus frames reach it only
    /// once it has switched to raw mode.
    pub fn join_socketcand(&mut self, id: usize, bus: &str) {
        if id >= self.sessions.len() {
            self.sessions.resize_with(id + 1, || None);
        }
        self.sessions[id] = Some(Box::new(Session::new(bus)));
        self.replies.retain(|reply| reply.to != id);
        self.replies.push(Outgoing {
            to: id,
            bytes: server::GREETING.as_bytes().to_vec(),
        });
    }

    /// Participant `id` left; what it still had queued is dropped.
    pub fn leave(&mut self, id: usize) {
        if let Some(session) = self.sessions.get_mut(id) {
            *session = None;
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

    /// Bytes socketcand client `id` sent at `now`, one message (up to and including its `>`)
    /// at a time: its commands are served (replies by the next [`Hub::poll`]) and the frames
    /// it sends go on the bus. Returns how many bytes were taken: the intake stops before the
    /// message that would overflow the client's transmit FIFO
    /// ([`crate::bus::TRANSMIT_QUEUE`]), so that it waits, as on a real bus, and the caller
    /// hands the rest again after [`Hub::poll`] has put frames on the bus; it stops too once
    /// the session is closing. Bytes of a participant that has not joined (or has left) are
    /// all taken and dropped: nobody reads them.
    pub fn receive(&mut self, now: Instant, id: usize, bytes: &[u8]) -> usize {
        let mut taken = 0;
        while taken < bytes.len() {
            if !self.bus.has_room(id) || self.closing.contains(&id) {
                return taken;
            }
            let rest = &bytes[taken..];
            let end = server::first_message(rest);
            let Some(Some(session)) = self.sessions.get_mut(id) else {
                return bytes.len();
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

    /// Everything due at `now`: frames that ended go to every connected participant but
    /// their sender; the next arbitration starts when the bus is free. Returns what to
    /// write, and when to call again (`None`: when bytes arrive).
    ///
    /// Replies come first; a client receives bus frames as raw-mode `frame` messages stamped
    /// with the hub's time (the end of the frame on the bus), and none before it has
    /// switched to raw mode.
    pub fn poll(&mut self, now: Instant) -> (Vec<Outgoing>, Option<Instant>) {
        let mut out = std::mem::take(&mut self.replies);
        for (to, session) in self.sessions.iter_mut().enumerate() {
            if let Some(session) = session {
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
                let stamp = clock(delivery.at);
                for (to, session) in self.sessions.iter_mut().enumerate() {
                    let Some(session) = session.as_mut().filter(|_| to != delivery.from) else {
                        continue;
                    };
                    if let Some(message) = session.frame(&delivery.frame, stamp, clock(now)) {
                        out.push(Outgoing {
                            to,
                            bytes: message.into_bytes(),
                        });
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
        let grace_ends = self.sessions.iter().flatten().filter_map(|session| {
            session
                .release_at()
                .map(|at| Instant::from_micros(at.as_micros() as u64))
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
    use safety_config::socketcand::{parse_frame_message, send_message, take_messages};
    use shared::{CanId, Duration};

    fn frame(id: u16, data: &[u8]) -> CanFrame {
        CanFrame::new(CanId::new(id).unwrap(), data).unwrap()
    }

    /// When the clients of [`clients`] are past their raw-mode grace: the tests start here.
    const START: Instant = Instant::ZERO.saturating_add(RAW_MODE_GRACE);

    /// A hub at `bit_rate` with socketcand clients `0..count`, each in raw mode since time
    /// zero, their handshake replies handed out already.
    fn clients(bit_rate: u32, count: usize) -> Hub {
        let mut hub = Hub::new(bit_rate);
        for id in 0..count {
            hub.join_socketcand(id, "can0");
            let handshake = b"< open can0 >< rawmode >";
            assert_eq!(hub.receive(Instant::ZERO, id, handshake), handshake.len());
        }
        let _ = hub.poll(Instant::ZERO);
        hub
    }

    /// Client `id` sends `frame` at `at` (its `send` message taken whole).
    fn send(hub: &mut Hub, at: Instant, id: usize, frame: &CanFrame) {
        let message = send_message(frame);
        assert_eq!(hub.receive(at, id, message.as_bytes()), message.len());
    }

    fn text(outgoing: &Outgoing) -> &str {
        std::str::from_utf8(&outgoing.bytes).expect("socketcand speaks text")
    }

    /// The frame a raw-mode `frame` message carries.
    fn decode(outgoing: &Outgoing) -> CanFrame {
        let mut buffer = text(outgoing).to_string();
        let messages = take_messages(&mut buffer);
        match messages.as_slice() {
            [words] => parse_frame_message(words)
                .expect("a well-formed message")
                .expect("a frame message"),
            other => panic!("not one message: {other:?}"),
        }
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

    #[test]
    fn frames_reach_everyone_but_the_sender_after_their_bit_time() {
        let mut hub = clients(500_000, 3);
        send(&mut hub, START, 1, &frame(0x101, &[1]));
        let (out, next) = hub.poll(START);
        assert!(out.is_empty(), "still on the bus");
        let end = next.unwrap();
        assert_eq!(
            end,
            START + crate::bus::frame_time(&frame(0x101, &[1]), 500_000)
        );
        let (out, next) = hub.poll(end);
        let receivers: Vec<usize> = out.iter().map(|o| o.to).collect();
        assert_eq!(receivers, [0, 2]);
        assert_eq!(decode(&out[0]), frame(0x101, &[1]));
        assert_eq!(next, None);
        assert_eq!(hub.completed.len(), 1);
    }

    #[test]
    fn competing_frames_go_in_identifier_order() {
        let mut hub = clients(1_000_000, 4);
        send(&mut hub, START, 0, &frame(0x701, &[5]));
        send(&mut hub, START, 1, &frame(0x102, &[0xFE]));
        send(&mut hub, START, 2, &frame(0x101, &[0x01]));
        let (out, _) = run_idle(&mut hub, START);
        let order: Vec<u16> = out
            .iter()
            .filter(|o| o.to == 3)
            .map(|o| decode(o).id().raw())
            .collect();
        assert_eq!(order, [0x101, 0x102, 0x701]);
    }

    #[test]
    fn injected_faults_apply() {
        let mut hub = clients(250_000, 2);
        hub.inject(Injection::new(
            Match::next_with_id(0x102, START),
            Fault::Drop,
        ));
        send(&mut hub, START, 0, &frame(0x102, &[0xFE]));
        let (out, _) = run_idle(&mut hub, START);
        assert!(out.is_empty(), "dropped: {out:?}");
        send(
            &mut hub,
            START + Duration::from_millis(1),
            0,
            &frame(0x102, &[0xFE]),
        );
        let (out, _) = run_idle(&mut hub, START + Duration::from_millis(1));
        assert_eq!(out.len(), 1, "only the next one is dropped");
        assert_eq!(hub.completed.len(), 1);
    }

    /// A socketcand client that sends faster than the bus takes frames waits: the hub takes
    /// its bytes up to a full transmit FIFO, the rest once the bus has room, and every frame
    /// reaches the others, in order.
    #[test]
    fn a_flooding_tool_waits_for_the_bus_and_loses_nothing() {
        let mut hub = clients(1_000_000, 2);
        let frames = 3 * crate::bus::TRANSMIT_QUEUE;
        let mut pending: Vec<u8> = (0..frames)
            .flat_map(|n| format!("< send 300 2 {:02X} {:02X} >", n % 256, n / 256).into_bytes())
            .collect();
        let first = hub.receive(START, 1, &pending);
        assert!(first < pending.len(), "a full FIFO makes the sender wait");
        assert!(!hub.has_room(1));
        pending.drain(..first);
        let mut now = START;
        let mut received = Vec::new();
        loop {
            let (out, next) = hub.poll(now);
            received.extend(out.iter().filter(|o| o.to == 0).map(decode));
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
    }

    /// A socketcand client on the hub: the greeting, one reply per command each in its own
    /// write, no bus frame before it switched to raw mode nor within [`RAW_MODE_GRACE`] of
    /// the reply, then every frame as a raw-mode message; the frames it sends reach the
    /// other clients, not itself.
    #[test]
    fn a_socketcand_client_joins_the_bus_in_raw_mode_only() {
        let mut hub = clients(500_000, 1);
        hub.join_socketcand(1, "can0");
        let (out, _) = hub.poll(Instant::ZERO);
        assert_eq!(out.len(), 1);
        assert_eq!((out[0].to, text(&out[0])), (1, "< hi >"));

        // A frame that completes before the client is in raw mode does not reach it.
        send(&mut hub, Instant::ZERO, 0, &frame(0x701, &[0x7F]));
        let (_, next) = hub.poll(Instant::ZERO);
        let (out, _) = hub.poll(next.unwrap());
        assert!(out.is_empty(), "{out:?}");

        let at = next.unwrap();
        assert_eq!(hub.receive(at, 1, b"< open can0 >< rawmode >"), 24);
        let (out, _) = hub.poll(at);
        let replies: Vec<&str> = out.iter().map(text).collect();
        assert_eq!(replies, ["< ok >", "< ok >"], "each reply on its own");

        // A frame that ends within the grace after the reply is held until the grace is over.
        send(&mut hub, at, 0, &frame(0x181, &[1, 0xAB]));
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

        // After the grace, frames go out as they end; the new client's own reach the other.
        let later = at + RAW_MODE_GRACE;
        send(&mut hub, later, 0, &frame(0x001, &[]));
        let (out, later) = run_idle(&mut hub, later);
        assert!(text(&out[0]).starts_with("< frame 001 "), "{out:?}");
        hub.receive(later, 1, b"< send 601 8 40 18 10 01 00 00 00 00 >");
        let (out, _) = run_idle(&mut hub, later);
        let to_other: Vec<CanFrame> = out.iter().filter(|o| o.to == 0).map(decode).collect();
        assert_eq!(to_other, [frame(0x601, &[0x40, 0x18, 0x10, 1, 0, 0, 0, 0])]);
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

    /// The end on the bus of each frame that completed, after [`START`], with its
    /// identifier, in order.
    fn ends(hub: &Hub) -> Vec<(u16, u64)> {
        hub.completed
            .iter()
            .map(|(at, frame, _)| (frame.id().raw(), at.as_micros() - START.as_micros()))
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
        let mut hub = clients(500_000, 3);
        let load: Vec<CanFrame> = (0..10).map(|n| frame(0x281 + n, &[0x55; 8])).collect();
        for frame in &load {
            send(&mut hub, START, 1, frame);
        }
        send(&mut hub, START, 0, &frame(0x721, &[5]));
        let _ = hub.poll(START);
        // The hub's loop comes back only 20 ms later (a busy host).
        let (out, _) = hub.poll(START + Duration::from_millis(20));
        let mut expected = Vec::new();
        let mut end = 0;
        for frame in load.iter().chain([&frame(0x721, &[5])]) {
            end += crate::bus::frame_time(frame, 500_000).as_micros();
            expected.push((frame.id().raw(), end));
        }
        assert_eq!(
            ends(&hub),
            expected,
            "back to back from the start, in identifier order"
        );
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
        let mut hub = clients(500_000, 4);
        send(&mut hub, START, 1, &frame(0x281, &[0x55; 8]));
        let _ = hub.poll(START);
        send(
            &mut hub,
            START + Duration::from_micros(10),
            0,
            &frame(0x721, &[5]),
        );
        // 10 ms later, a frame of higher priority: the bus was free long before.
        let later = START + Duration::from_millis(10);
        send(&mut hub, later, 2, &frame(0x050, &[1]));
        let _ = hub.poll(later);
        let _ = hub.poll(later + Duration::from_millis(1));
        let first = crate::bus::frame_time(&frame(0x281, &[0x55; 8]), 500_000).as_micros();
        let heartbeat = crate::bus::frame_time(&frame(0x721, &[5]), 500_000).as_micros();
        let late = crate::bus::frame_time(&frame(0x050, &[1]), 500_000).as_micros();
        assert_eq!(
            ends(&hub),
            [
                (0x281, first),
                (0x721, first + heartbeat),
                (0x050, 10_000 + late)
            ]
        );
    }

    /// A frame sent while the bus was idle starts when it was sent, not earlier (the bus
    /// cannot carry a frame before its sender had it) and not at the hub's next round; the
    /// hub's own sender, with no connection, competes as any other.
    #[test]
    fn a_frame_sent_to_an_idle_bus_starts_when_it_was_sent() {
        let mut hub = clients(500_000, 2);
        send(&mut hub, START, 1, &frame(0x281, &[1]));
        let _ = hub.poll(START);
        let sent = START + Duration::from_millis(5);
        hub.send(sent, 7, frame(0x721, &[5])).unwrap();
        let _ = hub.poll(START + Duration::from_millis(8));
        let heartbeat = crate::bus::frame_time(&frame(0x721, &[5]), 500_000).as_micros();
        assert_eq!(ends(&hub)[1], (0x721, 5_000 + heartbeat));
        assert_eq!(hub.completed[1].2, 7, "sent as participant 7");
    }
}
