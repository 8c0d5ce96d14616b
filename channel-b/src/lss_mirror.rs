//! Channel B's mirror of the LSS slave (CiA 305): B follows every LSS request on the bus into
//! its own slave state and checks each answer channel A announces against its own, and A's
//! node-ID and bit rate against its own; a difference is a [`LssMismatch`], whose text says
//! what differed, for the safe state.
//!
//! Channel A answers LSS for the node; channel B sends nothing on 7E4h. B cannot tell A's
//! answers on the bus from other nodes' (unconfigured nodes answer fastscan with the same
//! frame), so A announces each answer over the link before it sends it, as it does its plain
//! SRDO frames, and B compares the announcements. B's slave is its own instance of
//! `shared::canopen::lss::Lss`, in its own RAM, fed the requests B's controller received: the
//! same code as A's (CiA 304 9.5 asks for two ways of building a transmit SRDO, not an LSS
//! answer), so the mirror finds what one MCU got wrong alone (a corrupted state, a lost or
//! extra request, a different store result), not a fault of the code both run.
//!
//! Pairing: answers pair in order, request by request. Whichever of A's announcement and
//! B's own answer comes first waits for the other up to the window ([`LssMirror::new`]);
//! a request B answers and A does not announce within the window, or an announcement B has
//! no answer for within the window, is a mismatch, as is a pair that differs in any byte.
//!
//! Not yet wired: the firmware images carry no LSS (the `shared` feature `lss` is off in
//! them), so this is host-tested logic that the channel's role calls when they do.

use heapless::Deque;
use shared::canopen::NodeId;
use shared::canopen::lss::{
    BitRate, BitRates, Lss, LssSettings, MASTER_TO_SLAVE, SLAVE_TO_MASTER, StoreFailure,
};
use shared::{CanFrame, Duration, Instant};

/// How many answers may wait for their pair at a time (a master waits for each answer; more
/// outstanding means something is wrong already).
const PENDING: usize = 4;

/// What differed between the two channels' LSS; the doc comment of each variant is its
/// message ([`LssMismatch::describe`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LssMismatch {
    /// Channel A announced an LSS answer that differs from channel B's own.
    AnswerDiffers {
        /// A's answer.
        channel_a: [u8; 8],
        /// B's answer.
        channel_b: [u8; 8],
    },
    /// Channel B answered an LSS request and channel A announced no answer within the window.
    Unanswered {
        /// B's answer.
        channel_b: [u8; 8],
    },
    /// Channel A announced an LSS answer channel B had none for within the window.
    Unexpected {
        /// A's answer.
        channel_a: [u8; 8],
    },
    /// More answers wait for their pair than the mirror holds.
    Overrun,
    /// The node-ID in force or pending differs between the channels.
    NodeIdDiffers {
        /// A's node-ID in force, pending (`None`: unconfigured).
        channel_a: (Option<NodeId>, Option<NodeId>),
        /// B's node-ID in force, pending.
        channel_b: (Option<NodeId>, Option<NodeId>),
    },
    /// The LSS bit rate differs between the channels.
    BitRateDiffers {
        /// A's bit rate (`None`: the board's own).
        channel_a: Option<BitRate>,
        /// B's bit rate.
        channel_b: Option<BitRate>,
    },
}

impl LssMismatch {
    /// The mismatch in words, for the log and the safe state's cause.
    pub fn describe(&self) -> &'static str {
        match self {
            LssMismatch::AnswerDiffers { .. } => {
                "channel A announced an LSS answer that differs from channel B's own"
            }
            LssMismatch::Unanswered { .. } => {
                "channel B answered an LSS request and channel A announced no answer within the window"
            }
            LssMismatch::Unexpected { .. } => {
                "channel A announced an LSS answer channel B had none for within the window"
            }
            LssMismatch::Overrun => "more LSS answers wait for their pair than the mirror holds",
            LssMismatch::NodeIdDiffers { .. } => {
                "the LSS node-ID in force or pending differs between the channels"
            }
            LssMismatch::BitRateDiffers { .. } => "the LSS bit rate differs between the channels",
        }
    }
}

impl core::fmt::Display for LssMismatch {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.describe())?;
        match self {
            LssMismatch::AnswerDiffers {
                channel_a,
                channel_b,
            } => write!(f, " (A {channel_a:02X?}, B {channel_b:02X?})"),
            LssMismatch::Unanswered { channel_b } => write!(f, " (B {channel_b:02X?})"),
            LssMismatch::Unexpected { channel_a } => write!(f, " (A {channel_a:02X?})"),
            LssMismatch::NodeIdDiffers {
                channel_a,
                channel_b,
            } => write!(f, " (A {channel_a:?}, B {channel_b:?})"),
            LssMismatch::BitRateDiffers {
                channel_a,
                channel_b,
            } => write!(f, " (A {channel_a:?}, B {channel_b:?})"),
            LssMismatch::Overrun => Ok(()),
        }
    }
}

/// Channel B's LSS slave and the answers waiting for their pair.
#[derive(Clone, Debug)]
pub struct LssMirror {
    lss: Lss,
    window: Duration,
    /// B's answers A has not announced yet, with when B made them.
    ours: Deque<([u8; 8], Instant), PENDING>,
    /// A's announcements B has no answer for yet, with when they came.
    theirs: Deque<([u8; 8], Instant), PENDING>,
}

impl LssMirror {
    /// The mirror of a node with `identity`, node-ID `switches`, the LSS settings `stored`
    /// and the bit rates `supported` (what channel A's slave is built from), pairing answers
    /// within `window`.
    pub fn new(
        identity: [u32; 4],
        switches: Option<NodeId>,
        stored: Option<LssSettings>,
        supported: BitRates,
        window: Duration,
    ) -> Self {
        LssMirror {
            lss: Lss::new(identity, switches, stored, supported),
            window,
            ours: Deque::new(),
            theirs: Deque::new(),
        }
    }

    /// Channel B's slave.
    pub fn lss(&self) -> &Lss {
        &self.lss
    }

    /// A frame channel B's controller received at `now` (`operational`: the node is in NMT
    /// Operational); `store` is B's own store configuration. Requests go to B's slave; B's
    /// answer is paired with A's announcement. Channel A's own answers on 7E4h are not read
    /// here (they come as announcements). An NMT reset communication the request asks for is
    /// B's to perform too ([`LssMirror::reset_communication`]), as A does.
    pub fn on_request(
        &mut self,
        now: Instant,
        frame: &CanFrame,
        operational: bool,
        store: impl FnOnce(LssSettings) -> Result<(), StoreFailure>,
    ) -> Result<bool, LssMismatch> {
        if frame.id() != MASTER_TO_SLAVE {
            return Ok(false);
        }
        let outcome = self.lss.on_frame(now, frame, operational, store);
        if let Some(answer) = outcome.response {
            let data = <[u8; 8]>::try_from(answer.data()).unwrap_or_default();
            self.pair(now, data, Side::ChannelB)?;
        }
        Ok(outcome.reset_communication)
    }

    /// Channel A announced over the link at `now` that it sends `answer`.
    pub fn on_announced(&mut self, now: Instant, answer: &CanFrame) -> Result<(), LssMismatch> {
        let data = <[u8; 8]>::try_from(answer.data()).unwrap_or_default();
        if answer.id() != SLAVE_TO_MASTER || answer.data().len() != 8 {
            return Err(LssMismatch::Unexpected { channel_a: data });
        }
        self.pair(now, data, Side::ChannelA)
    }

    /// Pairs `data` from `side` with the other side's oldest waiting answer, or leaves it
    /// waiting.
    fn pair(&mut self, now: Instant, data: [u8; 8], side: Side) -> Result<(), LssMismatch> {
        self.poll(now)?;
        let (own, other) = match side {
            Side::ChannelA => (&mut self.theirs, &mut self.ours),
            Side::ChannelB => (&mut self.ours, &mut self.theirs),
        };
        match other.pop_front() {
            Some((waiting, _)) if waiting == data => Ok(()),
            Some((waiting, _)) => Err(match side {
                Side::ChannelA => LssMismatch::AnswerDiffers {
                    channel_a: data,
                    channel_b: waiting,
                },
                Side::ChannelB => LssMismatch::AnswerDiffers {
                    channel_a: waiting,
                    channel_b: data,
                },
            }),
            None => own.push_back((data, now)).map_err(|_| LssMismatch::Overrun),
        }
    }

    /// An answer that waited longer than the window for its pair is a mismatch. Call at
    /// [`LssMirror::deadline`].
    pub fn poll(&mut self, now: Instant) -> Result<(), LssMismatch> {
        let late = |since: Instant| shared::time::expired(since + self.window, now);
        if let Some(&(data, since)) = self.ours.front() {
            if late(since) {
                return Err(LssMismatch::Unanswered { channel_b: data });
            }
        }
        if let Some(&(data, since)) = self.theirs.front() {
            if late(since) {
                return Err(LssMismatch::Unexpected { channel_a: data });
            }
        }
        Ok(())
    }

    /// When [`LssMirror::poll`] must run next ([`Instant::NEVER`]: nothing waits).
    #[must_use]
    pub fn deadline(&self) -> Instant {
        let oldest = [self.ours.front(), self.theirs.front()]
            .into_iter()
            .flatten()
            .map(|&(_, since)| since + self.window)
            .min();
        oldest.unwrap_or(Instant::NEVER)
    }

    /// NMT reset communication or reset node on channel B: its slave's pending node-ID comes
    /// into force, as channel A's does. Returns B's node-ID in force.
    pub fn reset_communication(&mut self) -> Option<NodeId> {
        self.lss.reset_communication()
    }

    /// The node enters NMT Operational: B's slave leaves the configuration state, as A's does.
    pub fn leave_configuration(&mut self) {
        let _ = self.lss.leave_configuration();
    }

    /// Checks channel A's node-ID in force and pending, and its LSS bit rate, against B's
    /// (A reports them over the link after each LSS request and at each reset).
    pub fn check_settings(
        &self,
        active: Option<NodeId>,
        pending: Option<NodeId>,
        bit_rate: Option<BitRate>,
    ) -> Result<(), LssMismatch> {
        let ours = (self.lss.active(), self.lss.pending());
        if (active, pending) != ours {
            return Err(LssMismatch::NodeIdDiffers {
                channel_a: (active, pending),
                channel_b: ours,
            });
        }
        if bit_rate != self.lss.bit_rate() {
            return Err(LssMismatch::BitRateDiffers {
                channel_a: bit_rate,
                channel_b: self.lss.bit_rate(),
            });
        }
        Ok(())
    }
}

/// Which channel an answer came from.
#[derive(Clone, Copy)]
enum Side {
    ChannelA,
    ChannelB,
}

#[cfg(test)]
mod tests;
