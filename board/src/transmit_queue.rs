//! The order in which a channel's frames go to its CAN controller: by identifier (a data frame
//! before a remote frame of the same identifier), frames of one identifier in the order they
//! were handed out. That is CAN arbitration's own order, applied inside the node as well, so
//! that a heartbeat or EMCY this node queued first never holds back its SRDO or its GFC
//! behind it: a software FIFO in front of the controller would (measured in the host
//! simulation: a GFC behind the node's heartbeat and EMCY left a replayed pair on a
//! consumer's output for up to 0.46 ms). The host bus model (`can_hub::bus`) orders each
//! participant's queue the same way.
//!
//! `board::hw` keeps its frames to send in an embassy-sync `PriorityChannel` of [`Queued`]; the
//! order itself is here, host-tested.

use core::cmp::Ordering;
use shared::CanFrame;

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

#[cfg(test)]
mod tests {
    use super::*;
    use heapless::binary_heap::{BinaryHeap, Min};
    use shared::CanId;

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
}
