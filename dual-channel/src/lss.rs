//! LSS (CiA 305) on the two channels of one node: channel A answers for the node, channel B
//! checks every answer against its own, and the two channels' node-ID and bit rate are
//! compared over the link before Operational.
//!
//! Both channels' cores run their own LSS slave (`shared::canopen::lss::Lss`, enabled by
//! `Runtime::enable_lss` from the same switches and each channel's own stored settings) and
//! take every request their controller receives on 7E5h. Channel A's answers go on the bus;
//! channel B sends nothing on 7E4h (one transceiver, one voice). B cannot tell A's answers on
//! the bus from other nodes' (unconfigured nodes answer fastscan with the same frame), so A
//! announces each answer over the link before it sends it ([`crate::link::Message::LssAnswer`]),
//! as it announces its plain SRDO frames, and B pairs the announcements with its own answers
//! ([`AnswerPairing`]). Both slaves are the same code (CiA 304 9.5 asks for two ways of
//! building a transmit SRDO, not an LSS answer): the pairing finds what one MCU got wrong
//! alone (a corrupted state, a request lost on one channel, a store that failed on one), not
//! a fault of the code both run.
//!
//! What an answer cannot show, the heartbeat does: each channel's link heartbeat carries its
//! node-ID in force and its LSS bit rate ([`Settings`]). The node-ID in force changes only at
//! an NMT reset, which starts a new epoch on both channels, so two heartbeats of the same
//! epoch must name the same node-ID; the bit rate cannot change in Operational (no LSS
//! configuration there, CiA 305 rule 1 of `shared::canopen::lss`), so it is compared there.
//! Either difference is the safe state with its cause in words ([`LssMismatch::describe`]).
//! The node-ID check runs in every NMT state, so a difference is found before Operational.

use heapless::Deque;
use shared::canopen::NodeId;
use shared::canopen::lss::{BitRate, SLAVE_TO_MASTER, UNCONFIGURED};
use shared::safety::cause::Cause;
use shared::{CanFrame, Duration, Instant};

/// How many answers may wait for their pair at a time (a master waits for each answer; more
/// outstanding means something is wrong already).
const PENDING: usize = 4;

/// How long an answer waits for the other channel's: longer than a link message takes
/// through its queue plus a channel's longest store of its parameters (store configuration
/// answers after the flash is programmed, on each channel in its own time). LSS configures a
/// node outside Operational only (CiA 305 rule 1 of `shared::canopen::lss`), where no output
/// is on, so the window bounds only how soon a difference is reported, never a safety output.
pub const ANSWER_WINDOW: Duration = Duration::from_millis(250);

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
    /// More answers wait for their pair than channel B holds.
    Overrun,
    /// The node-ID in force differs between the channels in the same NMT epoch.
    NodeIdDiffers {
        /// The other channel's node-ID in force (`None`: unconfigured).
        other: Option<NodeId>,
        /// This channel's.
        own: Option<NodeId>,
    },
    /// The LSS bit rate differs between the channels in Operational.
    BitRateDiffers {
        /// The other channel's (`None`: the board's own).
        other: Option<BitRate>,
        /// This channel's.
        own: Option<BitRate>,
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
            LssMismatch::Overrun => "more LSS answers wait for their pair than channel B holds",
            LssMismatch::NodeIdDiffers { .. } => {
                "the node-ID in force differs between the channels"
            }
            LssMismatch::BitRateDiffers { .. } => "the LSS bit rate differs between the channels",
        }
    }

    /// The cause code of the safe state this mismatch leads to.
    pub const fn cause(&self) -> Cause {
        match self {
            LssMismatch::NodeIdDiffers { .. } => Cause::NodeIdMismatch,
            LssMismatch::BitRateDiffers { .. } => Cause::BitRateMismatch,
            _ => Cause::LssAnswerMismatch,
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
            LssMismatch::NodeIdDiffers { other, own } => {
                write!(f, " (other {other:?}, own {own:?})")
            }
            LssMismatch::BitRateDiffers { other, own } => {
                write!(f, " (other {other:?}, own {own:?})")
            }
            LssMismatch::Overrun => Ok(()),
        }
    }
}

/// A channel's node-ID in force and LSS bit rate, as its link heartbeat carries them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Settings {
    /// The node-ID in force; `None`: unconfigured (FFh on the link).
    pub node_id: Option<NodeId>,
    /// The bit rate LSS stored or configured; `None`: the board's own (FFh on the link).
    pub bit_rate: Option<BitRate>,
}

impl Settings {
    /// The node-ID byte on the link: the node-ID, or FFh when unconfigured.
    pub fn node_byte(&self) -> u8 {
        self.node_id.map_or(UNCONFIGURED, NodeId::raw)
    }

    /// The bit-rate byte on the link: the CiA 305 table index, or FFh for the board's own.
    pub fn bit_rate_byte(&self) -> u8 {
        self.bit_rate.map_or(0xFF, BitRate::index)
    }

    /// The settings the bytes of a heartbeat name (an FFh or a byte that is no node-ID or
    /// table index reads as none: it then differs from any channel's that has one).
    pub fn from_bytes(node: u8, bit_rate: u8) -> Settings {
        Settings {
            node_id: NodeId::new(node).ok(),
            bit_rate: BitRate::from_index(bit_rate),
        }
    }

    /// Compares the other channel's settings of the same NMT epoch with this channel's own:
    /// the node-ID always, the bit rate when `operational` (both channels in Operational).
    pub fn compare(&self, own: &Settings, operational: bool) -> Result<(), LssMismatch> {
        if self.node_byte() != own.node_byte() {
            return Err(LssMismatch::NodeIdDiffers {
                other: self.node_id,
                own: own.node_id,
            });
        }
        if operational && self.bit_rate_byte() != own.bit_rate_byte() {
            return Err(LssMismatch::BitRateDiffers {
                other: self.bit_rate,
                own: own.bit_rate,
            });
        }
        Ok(())
    }
}

/// Channel B's pairing of its own LSS answers with channel A's announcements.
///
/// Answers pair in order, request by request. Whichever of A's announcement and B's own
/// answer comes first waits for the other up to the window; a request B answers and A does
/// not announce within the window, or an announcement B has no answer for within it, is a
/// mismatch, as is a pair that differs in any byte. A mismatch is reported once: the answers
/// waiting are dropped with it.
///
/// A channel that programs its parameter flash (store configuration, on both channels at
/// once) cannot receive link bytes meanwhile, so an announcement A made then may be lost
/// without a fault of either slave ([`AnswerPairing::link_was_deaf`]). B's answers waiting at
/// such a time are *uncertain*: one that A's next announcement does not equal, or whose window
/// ends, is dropped rather than a mismatch. An announcement that does come still pairs with
/// it, and one that differs from every uncertain answer still meets B's next answer.
#[derive(Clone, Debug)]
pub struct AnswerPairing {
    window: Duration,
    /// B's answers A has not announced yet, with when B made them.
    ours: Deque<Waiting, PENDING>,
    /// How many of [`AnswerPairing::ours`], from the front, are uncertain (their pair may
    /// have been lost on the link, [`AnswerPairing::link_was_deaf`]): the ones waiting when
    /// the link was deaf, which are ahead of every answer made since.
    uncertain: usize,
    /// A's announcements B has no answer for yet, with when they came.
    theirs: Deque<Waiting, PENDING>,
}

/// An answer waiting for its pair, and since when.
type Waiting = ([u8; 8], Instant);

impl Default for AnswerPairing {
    fn default() -> Self {
        AnswerPairing::new(ANSWER_WINDOW)
    }
}

impl AnswerPairing {
    /// Pairing answers within `window`.
    pub fn new(window: Duration) -> Self {
        AnswerPairing {
            window,
            ours: Deque::new(),
            uncertain: 0,
            theirs: Deque::new(),
        }
    }

    /// Channel B's own core answered an LSS request with `answer` at `now`.
    pub fn own(&mut self, now: Instant, answer: &CanFrame) -> Result<(), LssMismatch> {
        let data = answer_bytes(answer);
        let paired = self.poll(now).and_then(|()| match self.theirs.pop_front() {
            Some((waiting, _)) if waiting == data => Ok(()),
            Some((waiting, _)) => Err(LssMismatch::AnswerDiffers {
                channel_a: waiting,
                channel_b: data,
            }),
            None => self
                .ours
                .push_back((data, now))
                .map_err(|_| LssMismatch::Overrun),
        });
        self.reported(paired)
    }

    /// Channel A announced over the link at `now` that it sends `answer` (its data).
    pub fn announced(&mut self, now: Instant, answer: [u8; 8]) -> Result<(), LssMismatch> {
        let paired = self.poll(now).and_then(|()| {
            // B's uncertain answers this announcement does not equal had theirs lost.
            while self.uncertain > 0 && self.ours.front().is_some_and(|(data, _)| *data != answer) {
                self.drop_own();
            }
            match self.ours.front().copied() {
                Some((waiting, _)) => {
                    self.drop_own();
                    if waiting == answer {
                        Ok(())
                    } else {
                        Err(LssMismatch::AnswerDiffers {
                            channel_a: answer,
                            channel_b: waiting,
                        })
                    }
                }
                None => self
                    .theirs
                    .push_back((answer, now))
                    .map_err(|_| LssMismatch::Overrun),
            }
        });
        self.reported(paired)
    }

    /// Drops B's oldest waiting answer.
    fn drop_own(&mut self) {
        self.ours.pop_front();
        self.uncertain = self.uncertain.saturating_sub(1);
    }

    /// An answer that waited longer than the window for its pair is a mismatch (an uncertain
    /// one of B's is dropped). Call at [`AnswerPairing::deadline`].
    pub fn poll(&mut self, now: Instant) -> Result<(), LssMismatch> {
        let window = self.window;
        let late = |since: Instant| shared::time::expired(since + window, now);
        while self.uncertain > 0 && self.ours.front().is_some_and(|&(_, since)| late(since)) {
            self.drop_own();
        }
        let expired = if let Some(&(data, _)) = self.ours.front().filter(|(_, since)| late(*since))
        {
            Err(LssMismatch::Unanswered { channel_b: data })
        } else if let Some(&(data, _)) = self.theirs.front().filter(|(_, since)| late(*since)) {
            Err(LssMismatch::Unexpected { channel_a: data })
        } else {
            Ok(())
        };
        self.reported(expired)
    }

    /// A mismatch drops every answer waiting, so that it is reported once.
    fn reported(&mut self, result: Result<(), LssMismatch>) -> Result<(), LssMismatch> {
        if result.is_err() {
            self.ours.clear();
            self.uncertain = 0;
            self.theirs.clear();
        }
        result
    }

    /// When [`AnswerPairing::poll`] must run next ([`Instant::NEVER`]: nothing waits).
    #[must_use]
    pub fn deadline(&self) -> Instant {
        let oldest = [self.ours.front(), self.theirs.front()]
            .into_iter()
            .flatten()
            .map(|&(_, since)| since + self.window)
            .min();
        oldest.unwrap_or(Instant::NEVER)
    }

    /// The link receiver started over: this channel could not receive for a while
    /// (`Runtime::link_was_deaf`), so announcements of that time may be lost without a fault
    /// of either slave. B's answers waiting now become uncertain. A difference they would
    /// have shown in the node-ID or bit rate is still found by the heartbeat's [`Settings`].
    pub fn link_was_deaf(&mut self) {
        self.uncertain = self.ours.len();
    }
}

/// An LSS answer's 8 data bytes (every LSS frame is 8 bytes long, CiA 305; a shorter one
/// reads with zeros and then differs from any real answer).
pub fn answer_bytes(answer: &CanFrame) -> [u8; 8] {
    let mut data = [0u8; 8];
    let bytes = answer.data();
    if let Some(head) = data.get_mut(..bytes.len()) {
        head.copy_from_slice(bytes);
    }
    data
}

/// `true` for a frame the node's LSS slave sends (7E4h).
pub fn is_answer(frame: &CanFrame) -> bool {
    frame.id() == SLAVE_TO_MASTER
}

#[cfg(test)]
mod tests;
