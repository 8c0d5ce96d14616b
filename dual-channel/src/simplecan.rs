//! Channel B's check of the SimpleCAN frames channel A forwards (SC_REQ_24, SC_REQ_10).
//!
//! Model III: both controllers hang on one transceiver, so channel B hears every SimpleCAN
//! frame on the bus itself, and channel A forwards the same frame over the link as it
//! received it (`Message::SimpleCanPacket`). B pairs the two copies in bus order, which both
//! controllers see alike: each frame B heard must come from A, equal byte for byte, within
//! `bound`, and each forwarded copy must be one B heard. A copy that differs, one that does
//! not come, or one B never heard is a fault of the pair of channels (the link, A's
//! controller or B's): B goes to the safe state with its own cause, rather than decoding
//! either copy.
//!
//! Sans-I/O: fed frames and `now`, it returns faults and the next deadline.

use crate::link::Message;
use shared::{Duration, Instant};

/// How many frames may wait for their other copy; more is a fault (`Overrun`). A SimpleCAN
/// frame takes at least 111 bit times on the bus (8 bytes, base identifier, no stuff bits,
/// interframe space), so 8 waiting frames span at least 888 µs at 1 Mbit/s: a bound up to
/// that never overruns, even on a bus full of SimpleCAN frames.
pub const DEPTH: usize = 8;

/// One SimpleCAN frame as a controller received it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RawFrame {
    /// CAN identifier.
    pub id: u16,
    /// Data length code.
    pub len: u8,
    /// Payload, bytes beyond `len` 0.
    pub data: [u8; 8],
}

impl RawFrame {
    /// The link message channel A sends for this frame: the frame, not unpacked.
    pub const fn forward(self) -> Message {
        Message::SimpleCanPacket {
            id: self.id,
            len: self.len,
            data: self.data,
        }
    }
}

/// Why the two copies of a SimpleCAN frame do not agree.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ForwardFault {
    /// The forwarded copy differs from the frame B heard.
    Differs {
        /// The identifier B heard.
        heard: u16,
        /// The identifier of A's copy.
        forwarded: u16,
    },
    /// B heard this frame, and A's copy did not come within the bound.
    Lost {
        /// The identifier.
        id: u16,
    },
    /// A forwarded this frame, and B did not hear it within the bound.
    Unheard {
        /// The identifier.
        id: u16,
    },
    /// More than [`DEPTH`] frames wait for their other copy.
    Overrun,
}

type Waiting = heapless::Deque<(RawFrame, Instant), DEPTH>;

/// Channel B's pairing of the frames it hears with those A forwards.
#[derive(Clone, Debug)]
pub struct ForwardCheck {
    bound: Duration,
    heard: Waiting,
    forwarded: Waiting,
}

impl ForwardCheck {
    /// A check that waits at most `bound` for the second copy of a frame.
    pub fn new(bound: Duration) -> Self {
        ForwardCheck {
            bound,
            heard: Waiting::new(),
            forwarded: Waiting::new(),
        }
    }

    /// B's controller received `frame` at `now`. `Ok(Some(frame))`: both copies agree and
    /// the frame is B's to decode.
    pub fn heard(
        &mut self,
        now: Instant,
        frame: RawFrame,
    ) -> Result<Option<RawFrame>, ForwardFault> {
        Self::pair(now, self.bound, frame, &mut self.forwarded, &mut self.heard)
            .map_err(|fault| fault.map_or(ForwardFault::Overrun, |a| Self::differs(frame, a)))
    }

    /// A's copy of a frame came over the link at `now`.
    pub fn forwarded(
        &mut self,
        now: Instant,
        frame: RawFrame,
    ) -> Result<Option<RawFrame>, ForwardFault> {
        Self::pair(now, self.bound, frame, &mut self.heard, &mut self.forwarded)
            .map_err(|fault| fault.map_or(ForwardFault::Overrun, |b| Self::differs(b, frame)))
    }

    fn differs(heard: RawFrame, forwarded: RawFrame) -> ForwardFault {
        ForwardFault::Differs {
            heard: heard.id,
            forwarded: forwarded.id,
        }
    }

    /// Pairs `frame` with the oldest waiting copy of the other side, or queues it.
    /// `Err(Some(other))`: the copies differ; `Err(None)`: the queue is full.
    fn pair(
        now: Instant,
        bound: Duration,
        frame: RawFrame,
        others: &mut Waiting,
        mine: &mut Waiting,
    ) -> Result<Option<RawFrame>, Option<RawFrame>> {
        match others.pop_front() {
            Some((other, _)) if other == frame => Ok(Some(frame)),
            Some((other, _)) => Err(Some(other)),
            None => mine
                .push_back((frame, now + bound))
                .map(|()| None)
                .map_err(|_| None),
        }
    }

    /// The fault of a copy whose other one is overdue at `now`, if any.
    pub fn poll(&self, now: Instant) -> Result<(), ForwardFault> {
        if let Some((frame, deadline)) = self.heard.front() {
            if now >= *deadline {
                return Err(ForwardFault::Lost { id: frame.id });
            }
        }
        if let Some((frame, deadline)) = self.forwarded.front() {
            if now >= *deadline {
                return Err(ForwardFault::Unheard { id: frame.id });
            }
        }
        Ok(())
    }

    /// When [`poll`](Self::poll) must run next, if a copy waits.
    pub fn deadline(&self) -> Option<Instant> {
        let heard = self.heard.front().map(|(_, at)| *at);
        let forwarded = self.forwarded.front().map(|(_, at)| *at);
        match (heard, forwarded) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }
}

#[cfg(test)]
mod tests;
