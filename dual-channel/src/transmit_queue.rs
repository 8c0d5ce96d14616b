//! The order in which a channel's frames go to its CAN controller: by identifier (a data frame
//! before a remote frame of the same identifier), frames of one identifier in the order they
//! were handed out. That is CAN arbitration's own order, applied inside the node as well, so
//! that a heartbeat or EMCY this node queued first never holds back its SRDO or its GFC
//! behind it: a software FIFO in front of the controller would (seen in the host simulation:
//! a GFC queued behind the node's heartbeat and EMCY left a replayed pair on a consumer's
//! output while the GFC waited behind them). The host bus model (`can_hub::bus`) orders each
//! participant's queue the same way.
//!
//! [`Transmitter`] is the whole transmit path of a channel's
//! [`Driver`](crate::channel_loop::Driver) on the bxCAN, whatever driver moves the frames into
//! the mailboxes (behind [`Controller`]: the board layer's own, on CAN1's registers): the
//! queue, the record of which frame each of the bxCAN's three mailboxes holds, and from it
//! which frames went out on the bus (SimpleCAN's producers and master must know: SC_REQ_18,
//! SC_REQ_23) and the withdrawal of the frames of one identifier not yet sent. All of it is
//! host-tested here against a model of the mailboxes; the board layer only implements
//! [`Controller`] on the registers.

use crate::channel_loop::QueueFull;
use core::cmp::Ordering;
use heapless::Deque;
use heapless::binary_heap::{BinaryHeap, Min};
use shared::{CanFrame, CanId};

/// A frame waiting to be sent, ordered for a min-priority queue.
#[derive(Clone, Copy, Debug)]
pub struct Queued {
    /// The frame.
    pub frame: CanFrame,
    /// When it was handed out, counting frames: the order among frames of one identifier.
    sequence: u64,
}

impl Queued {
    /// Arbitration order, then the order of handing out.
    fn key(&self) -> (u16, bool, u64) {
        (self.frame.id().raw(), self.frame.is_remote(), self.sequence)
    }
}

impl PartialEq for Queued {
    fn eq(&self, other: &Self) -> bool {
        self.key() == other.key()
    }
}

impl Eq for Queued {}

impl PartialOrd for Queued {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Queued {
    fn cmp(&self, other: &Self) -> Ordering {
        self.key().cmp(&other.key())
    }
}

/// Numbers the frames one channel hands out (a 64-bit count: it does not wrap in the life of
/// a device, at 10,000 frames a second for 58 million years).
#[derive(Debug, Default)]
pub struct Sequencer {
    next: u64,
}

impl Sequencer {
    /// A sequencer starting at 0.
    pub const fn new() -> Self {
        Sequencer { next: 0 }
    }

    /// `frame`, numbered after every frame before it.
    pub fn queue(&mut self, frame: CanFrame) -> Queued {
        let sequence = self.next;
        self.next = self.next.wrapping_add(1);
        Queued { frame, sequence }
    }
}

/// One of the bxCAN's three transmit mailboxes (RM0090 32.7.1), by number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Mailbox(u8);

impl Mailbox {
    /// The three, in the controller's numbering.
    pub const ALL: [Mailbox; 3] = [Mailbox(0), Mailbox(1), Mailbox(2)];

    /// Mailbox `index` (0..=2), `None` beyond.
    pub const fn new(index: u8) -> Option<Mailbox> {
        if index < 3 {
            Some(Mailbox(index))
        } else {
            None
        }
    }

    /// Its number, 0..=2.
    pub const fn index(self) -> usize {
        self.0 as usize
    }
}

/// Where the controller put a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Placement {
    /// The mailbox that now holds it.
    pub mailbox: Mailbox,
    /// The controller took a lower-priority pending frame back out of that mailbox for it
    /// (all three were pending): the abort of that mailbox's frame completed before the new
    /// frame went in (RM0090 32.7.1).
    pub displaced: bool,
}

/// Why a controller did not take a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// Not now: a pending frame blocks it (the board layer's driver refuses a frame beside a
    /// pending one of the same identifier, the `bxcan` crate 0.8 beside one of the same or a
    /// higher priority; so in both, frames of one identifier leave in order), or all three
    /// mailboxes hold frames of the same or a higher priority.
    Busy,
    /// Never: not a frame the driver can carry (a [`CanFrame`] always is one; kept so that
    /// such a frame is dropped, not left to block the queue).
    Unsendable,
}

/// A bxCAN's transmit mailboxes as a driver gives them: the three calls the transmit path
/// needs, nothing more.
pub trait Controller {
    /// Puts `frame` into a mailbox, or says why not.
    fn place(&mut self, frame: &CanFrame) -> Result<Placement, Refusal>;
    /// Takes `mailbox`'s frame back before it goes out: `true` when it did (the abort request
    /// completed with TXOK clear), `false` when the mailbox was empty or its frame went out
    /// first.
    fn abort(&mut self, mailbox: Mailbox) -> bool;
    /// Which mailboxes are empty now (CAN_TSR.TME0..2).
    fn empty(&self) -> [bool; 3];
}

/// Sent frames kept for [`Transmitter::transmitted`] because their mailbox was refilled
/// before it was asked (the other confirmations are read from the mailboxes when asked): one
/// per mailbox. More pile up only when the loop does not ask (images without SimpleCAN), and
/// then the oldest gives way; a SimpleCAN core whose confirmation was lost so treats its
/// packet as not sent and withdraws it, which finds the mailbox empty and takes nothing back.
const STASHED: usize = 3;

/// The transmit path of one channel: up to `Q` frames waiting in arbitration order, the frame
/// in each mailbox, and the frames confirmed as sent.
///
/// A mailbox's frame left it in exactly one of three ways, and the record tells which: the
/// controller took it back out for a higher-priority frame (the placement says so; the frame
/// goes back into the queue with its own number, so still ahead of later frames of its
/// identifier), [`Transmitter::withdraw`] took it back (the abort said so; the record is
/// dropped), or it went out on the bus (every other way a mailbox empties: with automatic
/// retransmission, the reset value kept, a frame that loses arbitration or meets an error is
/// sent again, RM0090 32.7.1). So a record whose mailbox is empty, or that a placement without
/// displacement overwrites, is a frame that was sent.
#[derive(Debug)]
pub struct Transmitter<const Q: usize> {
    queue: BinaryHeap<Queued, Min, Q>,
    sequencer: Sequencer,
    held: [Option<Queued>; 3],
    /// Sent frames whose mailbox was refilled before they were asked for. Images without
    /// SimpleCAN never ask: the oldest gives way.
    stashed: Deque<CanFrame, STASHED>,
}

impl<const Q: usize> Default for Transmitter<Q> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const Q: usize> Transmitter<Q> {
    /// Nothing queued, every mailbox empty.
    pub const fn new() -> Self {
        Transmitter {
            queue: BinaryHeap::new(),
            sequencer: Sequencer::new(),
            held: [None, None, None],
            stashed: Deque::new(),
        }
    }

    /// Queues `frame` and fills the mailboxes; refused when `Q` frames already wait.
    pub fn transmit(
        &mut self,
        frame: &CanFrame,
        controller: &mut impl Controller,
    ) -> Result<(), QueueFull> {
        self.queue
            .push(self.sequencer.queue(*frame))
            .map_err(|_| QueueFull)?;
        self.fill(controller);
        Ok(())
    }

    /// Moves frames, lowest identifier first, into the mailboxes while the controller takes
    /// them. A frame the controller took back out for a higher-priority one goes back into
    /// the queue (there is room: its place was just freed).
    pub fn fill(&mut self, controller: &mut impl Controller) {
        while let Some(next) = self.queue.peek() {
            let placement = match controller.place(&next.frame) {
                Ok(placement) => placement,
                Err(Refusal::Busy) => return,
                Err(Refusal::Unsendable) => {
                    let _ = self.queue.pop();
                    continue;
                }
            };
            let Some(placed) = self.queue.pop() else {
                return;
            };
            let slot = &mut self.held[placement.mailbox.index()];
            match (slot.replace(placed), placement.displaced) {
                (Some(displaced), true) => {
                    // Its place in the queue was freed by the pop above.
                    let _ = self.queue.push(displaced);
                }
                (Some(sent), false) => self.stash(sent.frame),
                (None, _) => {}
            }
        }
    }

    /// `true` while frames wait for a mailbox: the driver wakes when one frees.
    pub fn is_waiting(&self) -> bool {
        !self.queue.is_empty()
    }

    /// `true` while a mailbox holds a frame whose going out is still to be confirmed.
    pub fn is_pending(&self) -> bool {
        self.held.iter().any(Option::is_some)
    }

    /// `true` when [`Transmitter::transmitted`] has a frame to give.
    pub fn has_sent(&self, controller: &impl Controller) -> bool {
        !self.stashed.is_empty()
            || self
                .held
                .iter()
                .zip(controller.empty())
                .any(|(held, empty)| held.is_some() && empty)
    }

    /// The oldest frame confirmed as sent since the last call (SC_REQ_18, SC_REQ_23), `None`
    /// when there is none: first those whose mailbox was refilled, then the records of the
    /// mailboxes that are empty now, in mailbox order (two frames that left between two
    /// calls are not told apart in time; the loop asks after every service and on every
    /// completion it waits for).
    pub fn transmitted(&mut self, controller: &impl Controller) -> Option<CanFrame> {
        if let Some(frame) = self.stashed.pop_front() {
            return Some(frame);
        }
        let empty = controller.empty();
        self.held
            .iter_mut()
            .zip(empty)
            .filter(|(_, empty)| *empty)
            .find_map(|(slot, _)| slot.take())
            .map(|sent| sent.frame)
    }

    /// Withdraws every frame on `id` not yet sent (a SimpleCAN packet at the end of its slot,
    /// a sync not confirmed within 2 ms: SC_REQ_18, SC_REQ_23): out of the queue, and out of
    /// the mailboxes the controller can still take them back from. A frame already going out
    /// stays recorded, and is confirmed as sent.
    pub fn withdraw(&mut self, id: CanId, controller: &mut impl Controller) {
        let mut kept: BinaryHeap<Queued, Min, Q> = BinaryHeap::new();
        while let Some(queued) = self.queue.pop() {
            if queued.frame.id() != id {
                // As many as were taken out: there is room.
                let _ = kept.push(queued);
            }
        }
        self.queue = kept;
        for mailbox in Mailbox::ALL {
            let slot = &mut self.held[mailbox.index()];
            if slot.is_some_and(|held| held.frame.id() == id) && controller.abort(mailbox) {
                *slot = None;
            }
        }
        self.fill(controller);
    }

    fn stash(&mut self, frame: CanFrame) {
        if self.stashed.is_full() {
            let _ = self.stashed.pop_front();
        }
        let _ = self.stashed.push_back(frame);
    }
}

#[cfg(test)]
mod tests {
    extern crate std;

    use super::*;
    use std::vec::Vec;

    fn frame(id: u16, data: &[u8]) -> CanFrame {
        CanFrame::new(CanId::new(id).unwrap(), data).unwrap()
    }

    #[test]
    fn frames_leave_by_identifier_and_in_order_within_one_identifier() {
        let mut sequencer = Sequencer::new();
        let mut queue: BinaryHeap<Queued, Min, 16> = BinaryHeap::new();
        // Heartbeat and EMCY first, then the GFC, then two SDO responses of one identifier.
        for frame in [
            frame(0x701, &[5]),
            frame(0x081, &[0, 0xFF, 0x11]),
            frame(0x001, &[]),
            frame(0x581, &[1]),
            frame(0x581, &[2]),
            frame(0x101, &[1]),
        ] {
            queue.push(sequencer.queue(frame)).unwrap();
        }
        let order: heapless::Vec<(u16, u8), 8> = core::iter::from_fn(|| queue.pop())
            .map(|queued| {
                let frame = queued.frame;
                (frame.id().raw(), frame.data().first().copied().unwrap_or(0))
            })
            .collect();
        assert_eq!(
            order.as_slice(),
            &[
                (0x001, 0),
                (0x081, 0),
                (0x101, 1),
                (0x581, 1),
                (0x581, 2),
                (0x701, 5)
            ]
        );
    }

    /// The bxCAN's mailboxes under two drivers' rules, written from RM0090 32.7.1 and the
    /// drivers' sources, not from [`Transmitter`]: bxcan 0.8 refuses a frame while a pending
    /// one has the same or a higher priority, embassy-stm32 0.6 only while one has the same
    /// identifier (the board layer's own driver, the one shipped, refuses as embassy-stm32's
    /// does; bxcan's stricter rule stays as a second controller the queue must work with);
    /// with all three pending, a higher-priority frame displaces the
    /// lowest-priority one; the bus takes the highest-priority pending frame; a frame in
    /// flight cannot be aborted and completes, and a displacement aimed at it waits for it to
    /// complete (embassy-stm32's `read_pending_mailbox`, bxcan's alike).
    #[derive(Default)]
    struct Model {
        /// embassy-stm32's rule (the board layer's driver's) instead of bxcan's.
        embassy: bool,
        boxes: [Option<CanFrame>; 3],
        in_flight: Option<usize>,
        bus: Vec<CanFrame>,
        /// An identifier the driver cannot carry.
        unsendable: Option<u16>,
    }

    impl Model {
        fn highest_pending(&self) -> Option<usize> {
            (0..3)
                .filter(|&b| self.boxes[b].is_some())
                .min_by_key(|&b| self.boxes[b].map(|f| f.id().raw()))
        }

        /// The bus starts sending the highest-priority pending frame.
        fn start(&mut self) {
            if self.in_flight.is_none() {
                self.in_flight = self.highest_pending();
            }
        }

        /// The frame in flight completes.
        fn finish(&mut self) {
            if let Some(b) = self.in_flight.take() {
                self.bus.extend(self.boxes[b].take());
            }
        }
    }

    impl Controller for Model {
        fn place(&mut self, frame: &CanFrame) -> Result<Placement, Refusal> {
            let id = frame.id().raw();
            if Some(id) == self.unsendable {
                return Err(Refusal::Unsendable);
            }
            let pending: Vec<usize> = (0..3).filter(|&b| self.boxes[b].is_some()).collect();
            let blocks = |pending_id: u16| {
                if self.embassy {
                    pending_id == id
                } else {
                    pending_id <= id
                }
            };
            if pending
                .iter()
                .any(|&b| blocks(self.boxes[b].unwrap().id().raw()))
            {
                return Err(Refusal::Busy);
            }
            let mailbox = |b: usize| Mailbox::new(b as u8).ok_or(Refusal::Busy);
            if let Some(free) = (0..3).find(|&b| self.boxes[b].is_none()) {
                self.boxes[free] = Some(*frame);
                return Ok(Placement {
                    mailbox: mailbox(free)?,
                    displaced: false,
                });
            }
            // All three pending: the lowest goes when the frame has a higher priority.
            let lowest = (0..3)
                .max_by_key(|&b| self.boxes[b].unwrap().id().raw())
                .ok_or(Refusal::Busy)?;
            if self.boxes[lowest].is_some_and(|held| held.id().raw() <= id) {
                return Err(Refusal::Busy);
            }
            let displaced = if self.in_flight == Some(lowest) {
                self.finish();
                false
            } else {
                true
            };
            self.boxes[lowest] = Some(*frame);
            Ok(Placement {
                mailbox: mailbox(lowest)?,
                displaced,
            })
        }

        fn abort(&mut self, mailbox: Mailbox) -> bool {
            let b = mailbox.index();
            if self.in_flight == Some(b) || self.boxes[b].is_none() {
                return false;
            }
            self.boxes[b] = None;
            true
        }

        fn empty(&self) -> [bool; 3] {
            self.boxes.map(|held| held.is_none())
        }
    }

    /// Frame `n` of identifier `id`: the data is its number, so that every frame is told
    /// apart.
    fn numbered(id: u16, n: u16) -> CanFrame {
        CanFrame::new(CanId::new(id).unwrap(), &n.to_le_bytes()).unwrap()
    }

    fn number(frame: &CanFrame) -> u16 {
        u16::from_le_bytes([frame.data()[0], frame.data()[1]])
    }

    /// A frame the controller takes back out of a mailbox (three pending, a higher-priority
    /// one comes) goes back into the queue with its own number, so it still leaves before a
    /// frame of its identifier queued after it, and none is lost.
    #[test]
    fn a_frame_taken_out_of_a_mailbox_keeps_its_place_in_the_queue() {
        let mut model = Model::default();
        let mut path: Transmitter<8> = Transmitter::new();
        // Three pending frames, the heartbeat the lowest priority; a second heartbeat waits.
        for (id, n) in [(0x101, 1), (0x102, 2), (0x721, 5), (0x721, 6)] {
            path.transmit(&numbered(id, n), &mut model).unwrap();
        }
        // The GFC takes the heartbeat's mailbox; the heartbeat goes back into the queue.
        path.transmit(&numbered(0x001, 0), &mut model).unwrap();
        while path.is_waiting() || model.boxes.iter().any(Option::is_some) {
            model.start();
            model.finish();
            path.fill(&mut model);
        }
        let order: Vec<(u16, u16)> = model
            .bus
            .iter()
            .map(|frame| (frame.id().raw(), number(frame)))
            .collect();
        assert_eq!(
            order,
            [(0x001, 0), (0x101, 1), (0x102, 2), (0x721, 5), (0x721, 6)],
            "arbitration order, the first heartbeat still before the second"
        );
    }

    /// A frame the driver cannot carry is dropped; the frames behind it still go.
    #[test]
    fn a_frame_the_driver_cannot_carry_does_not_block_the_queue() {
        let mut model = Model {
            unsendable: Some(0x005),
            ..Model::default()
        };
        let mut path: Transmitter<8> = Transmitter::new();
        for (id, n) in [(0x005, 1), (0x101, 2)] {
            path.transmit(&numbered(id, n), &mut model).unwrap();
        }
        model.start();
        model.finish();
        assert_eq!(model.bus.iter().map(number).collect::<Vec<_>>(), [2]);
        assert!(path.has_sent(&model));
        assert_eq!(path.transmitted(&model).map(|f| number(&f)), Some(2));
        assert!(!path.has_sent(&model) && !path.is_waiting() && !path.is_pending());
    }

    /// SC_REQ_23: a sync not confirmed is withdrawn with the transmit buffers cleared; a
    /// withdrawn frame is never sent and never confirmed, one already on the bus is
    /// confirmed.
    #[test]
    fn sc_req_23_a_withdrawn_frame_is_neither_sent_nor_confirmed_unless_it_was_going_out() {
        let sync = 0x02F;
        let mut model = Model::default();
        let mut path: Transmitter<8> = Transmitter::new();
        // The sync in flight; two frames of higher priority, the second waiting for the
        // first (the controller's order); a second sync waiting behind them.
        path.transmit(&numbered(sync, 1), &mut model).unwrap();
        model.start();
        for (id, n) in [(0x01, 10), (0x02, 11), (sync, 2)] {
            path.transmit(&numbered(id, n), &mut model).unwrap();
        }
        assert!(path.is_waiting(), "the last sync waits for a mailbox");
        path.withdraw(CanId::new(sync).unwrap(), &mut model);
        assert!(
            path.queue
                .iter()
                .all(|queued| queued.frame.id().raw() != sync),
            "the queued sync is gone"
        );
        model.finish();
        let mut confirmed = Vec::new();
        while path.is_pending() || path.is_waiting() {
            model.start();
            model.finish();
            path.fill(&mut model);
            confirmed.extend(core::iter::from_fn(|| path.transmitted(&model)));
        }
        confirmed.extend(core::iter::from_fn(|| path.transmitted(&model)));
        let numbers = |frames: &[CanFrame]| frames.iter().map(number).collect::<Vec<_>>();
        assert_eq!(
            numbers(&model.bus),
            [1, 10, 11],
            "the sync in flight went out"
        );
        assert_eq!(
            numbers(&confirmed),
            numbers(&model.bus),
            "confirmed: what went out"
        );
    }

    /// Against the model of each driver's rule over 2,000 seeded runs of random operations
    /// (frames handed out, the bus starting and finishing frames, withdrawals, confirmations
    /// asked for):
    /// every frame that went out is confirmed exactly once and nothing else is; frames of
    /// one identifier go out in the order handed out; a withdrawn frame that was not going
    /// out never goes out; every other frame handed out goes out once the bus drains.
    #[test]
    fn confirmations_are_exactly_the_frames_that_went_out() {
        let ids = [0x01F, 0x02F, 0x030, 0x031, 0x101, 0x102, 0x701];
        for seed in 0..2_000u64 {
            let embassy = seed % 2 == 1;
            let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
            let mut random = |bound: u64| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                state % bound
            };
            let mut model = Model {
                embassy,
                ..Model::default()
            };
            let mut path: Transmitter<6> = Transmitter::new();
            let mut handed: Vec<CanFrame> = Vec::new();
            let mut withdrawn: Vec<u16> = Vec::new();
            let mut confirmed: Vec<CanFrame> = Vec::new();
            for n in 0..200u16 {
                // The loop asks after every service; here at least every third operation,
                // so that no more frames complete unasked than the path keeps.
                if n % 3 == 0 {
                    confirmed.extend(core::iter::from_fn(|| path.transmitted(&model)));
                }
                match random(6) {
                    0 | 1 => {
                        let frame = numbered(ids[random(ids.len() as u64) as usize], n);
                        if path.transmit(&frame, &mut model).is_ok() {
                            handed.push(frame);
                        }
                    }
                    2 => model.start(),
                    3 => {
                        model.finish();
                        path.fill(&mut model);
                    }
                    4 => {
                        let id = ids[random(ids.len() as u64) as usize];
                        let flying = model.in_flight.and_then(|b| model.boxes[b]);
                        withdrawn.extend(
                            handed
                                .iter()
                                .filter(|f| f.id().raw() == id)
                                .filter(|f| !model.bus.contains(f) && flying != Some(**f))
                                .map(number),
                        );
                        path.withdraw(CanId::new(id).unwrap(), &mut model);
                    }
                    _ => confirmed.extend(core::iter::from_fn(|| path.transmitted(&model))),
                }
            }
            // The bus drains.
            while path.is_waiting() || model.boxes.iter().any(Option::is_some) {
                model.start();
                model.finish();
                path.fill(&mut model);
                confirmed.extend(core::iter::from_fn(|| path.transmitted(&model)));
            }
            confirmed.extend(core::iter::from_fn(|| path.transmitted(&model)));

            let mut sent: Vec<u16> = model.bus.iter().map(number).collect();
            let mut told: Vec<u16> = confirmed.iter().map(number).collect();
            sent.sort_unstable();
            told.sort_unstable();
            assert_eq!(told, sent, "seed {seed}: confirmed exactly what went out");
            for id in ids {
                let on_bus: Vec<u16> = model
                    .bus
                    .iter()
                    .filter(|f| f.id().raw() == id)
                    .map(number)
                    .collect();
                assert!(
                    on_bus.windows(2).all(|w| w[0] < w[1]),
                    "seed {seed}: {id:03X} out of order: {on_bus:?}"
                );
            }
            for frame in &handed {
                let n = number(frame);
                let went = model.bus.iter().filter(|f| number(f) == n).count();
                let expected = usize::from(!withdrawn.contains(&n));
                assert_eq!(
                    went,
                    expected,
                    "seed {seed}: frame {n} on {:03X}",
                    frame.id().raw()
                );
            }
        }
    }
}
