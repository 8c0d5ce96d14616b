//! The link's latency supervision: a probe out, its echo back, the round trip against a bound.
//!
//! # Why a round trip
//!
//! The receiver's time-out ([`super::Receiver`]) finds a link that falls silent, not one that
//! keeps delivering late: every message may come a constant time after it was sent and the
//! time-out never runs out. Channel B's co-signing cannot bear that. Channel A announces each
//! plain frame over the link ([`Message::PlainFrame`]) before it hands the frame to its CAN
//! controller; channel B co-signs a plain frame only when the announcement has come, and
//! waits for it at most its window counted from the frame's arrival on the bus
//! (`channel_b::role`, "The window bounds the age of what B co-signs": that bound stays). A
//! link slower than the window makes channel A's own frame look foreign to channel B.
//!
//! Neither channel can measure a one-way latency: their clocks are not one clock. A round
//! trip is measured on one clock: the prober sends [`Message::Probe`] with a stamp of its
//! clock, the other channel sends the stamp back in [`Message::Echo`] as soon as the probe
//! arrives, and the prober compares the time since the stamp with the bound. A round trip is
//! one way there and one way back, each at least zero, so the one-way latency of either
//! direction is at most the round trip.
//!
//! # The bound
//!
//! Let channel A hand an announcement to its link queue at `t0`, and the plain frame (handed
//! to the CAN controller after it) arrive at channel B at `t1`, not before `t0`. Channel B
//! waits until `t1 + W`, `W` its window. The announcement reaches channel B at `t0 + q + l`,
//! where `q` is its time in channel A's queue and on the line (the messages ahead of it and
//! its own bytes: at most [`QUEUE_TIME`]) and `l` the rest of the way (the line's own
//! latency, the receiving loop's). A probe crosses the same way, so a round trip `r`
//! contains `l` and something more than zero on the way back: `r > l`. Hence
//!
//! ```text
//! r < W - QUEUE_TIME   =>   t0 + q + l < t0 + QUEUE_TIME + W - QUEUE_TIME <= t1 + W
//! ```
//!
//! and the announcement is in time ([`round_trip_bound`]). `round trip < W` alone is not
//! enough: a probe that found channel A's queue empty says nothing of an announcement behind
//! a full one, and the frame may reach the bus at once. The argument takes `l` as the same
//! for the probe and the announcement: a constant latency, the fault this supervision is for.
//! A link that turns slow between a probe and an announcement is caught by the probe channel
//! B sends when the frame arrives (`crate::runtime`): channel A echoes it only after it
//! received it, so after every announcement it made before the frame reached the bus, and the
//! link keeps the order; by `t1 + bound` either the echo is back, and with it every
//! announcement there was, or the round trip is over the bound, before channel B's wait ends.
//!
//! # Stamps
//!
//! The stamp is the low 32 bits of the prober's clock in microseconds ([`stamp`]): it names
//! the probe, and wraps about every 71 minutes, far beyond any bound. Echoes come back in the
//! order of their probes (the link keeps the order, and each is sent at once), so an echo
//! answers the oldest probe outstanding; the round trip is measured on the prober's own
//! [`Instant`] of that probe, not on the stamp, so the wrap never enters the arithmetic.

use super::{LinkFault, Message, QUEUE_TIME};
use shared::{Duration, Instant};

/// Probes a channel keeps outstanding at once; with that many unanswered, it sends no more
/// until the oldest is answered or falls due (which it does before any later one would).
const OUTSTANDING: usize = 4;

/// The bound on the round trip for a co-signing window `window` (channel B's wait for an
/// announcement): the window less [`QUEUE_TIME`], the longest an announcement can take
/// through channel A's link queue (see the module documentation); zero for a window no longer
/// than that, which no link meets.
pub const fn round_trip_bound(window: Duration) -> Duration {
    Duration::from_micros(window.as_micros().saturating_sub(QUEUE_TIME.as_micros()))
}

/// The stamp of a probe sent at `now`: the low 32 bits of its microseconds.
pub const fn stamp(now: Instant) -> u32 {
    // Truncation is the point: the stamp names the probe, the prober keeps the full instant.
    now.as_micros() as u32
}

/// The prober's side of the round trip: the probes outstanding and the bound.
#[derive(Clone, Debug)]
pub struct RoundTrip {
    /// When each probe not answered yet was sent, oldest first.
    outstanding: heapless::Deque<Instant, OUTSTANDING>,
    /// The bound; `None`: the supervision is not armed (nothing the link carries needs it).
    bound: Option<Duration>,
    /// The stamps of the probes [`RoundTrip::forget`] forgot, whose echoes may still come.
    forgotten: heapless::Vec<u32, OUTSTANDING>,
}

impl Default for RoundTrip {
    fn default() -> Self {
        Self::new()
    }
}

impl RoundTrip {
    /// No probe outstanding, not armed.
    pub const fn new() -> Self {
        RoundTrip {
            outstanding: heapless::Deque::new(),
            bound: None,
            forgotten: heapless::Vec::new(),
        }
    }

    /// Arms the supervision with `bound` (`None`: disarms it). Probes outstanding are judged
    /// by the bound in force when their echo comes or their time runs out.
    pub fn set_bound(&mut self, bound: Option<Duration>) {
        self.bound = bound;
    }

    /// The bound in force.
    pub fn bound(&self) -> Option<Duration> {
        self.bound
    }

    /// A probe to send now, recorded as outstanding; `None` when the supervision is not armed,
    /// or `OUTSTANDING` probes are unanswered already.
    #[must_use]
    pub fn probe(&mut self, now: Instant) -> Option<Message> {
        self.bound?;
        self.outstanding.push_back(now).ok()?;
        Some(Message::Probe { stamp: stamp(now) })
    }

    /// The echo of the probe with `stamp` came at `now`: [`LinkFault::Latency`] when the round
    /// trip is at or over the bound, or the echo does not answer the oldest probe outstanding.
    /// A disarmed supervision only takes the probe off the list.
    pub fn echo(&mut self, now: Instant, stamp: u32) -> Result<(), LinkFault> {
        if self.forgotten.contains(&stamp) {
            // The echo of a forgotten probe: it measures nothing. (`retain`, not `remove`:
            // no index, so no panic path and its formatting in the image.)
            self.forgotten.retain(|&forgotten| forgotten != stamp);
            return Ok(());
        }
        // The link keeps the order: every forgotten echo still to come would have come first.
        self.forgotten.clear();
        let sent = self.outstanding.pop_front();
        if sent.map(self::stamp) != Some(stamp) {
            return Err(LinkFault::Latency);
        }
        match (sent, self.bound) {
            (Some(sent), Some(bound)) if now.saturating_since(sent) >= bound => {
                Err(LinkFault::Latency)
            }
            _ => Ok(()),
        }
    }

    /// Forgets the probes outstanding: a channel that could not receive for a while (its
    /// processor held by a flash program) may have lost their echoes, and those it did not
    /// lose measured its own stall. Their echoes, when they come, are taken off and judged
    /// by nothing.
    pub fn forget(&mut self) {
        self.forgotten.clear();
        while let Some(sent) = self.outstanding.pop_front() {
            // As many places as probes outstanding: never full.
            let _ = self.forgotten.push(stamp(sent));
        }
    }

    /// When the oldest probe outstanding falls due ([`Instant::NEVER`]: none, or not armed).
    pub fn deadline(&self) -> Instant {
        match (self.outstanding.front(), self.bound) {
            (Some(&sent), Some(bound)) => sent + bound,
            _ => Instant::NEVER,
        }
    }

    /// [`LinkFault::Latency`] once the oldest probe outstanding has not been answered within
    /// the bound. Fires at the deadline itself, as an echo that comes then is late.
    pub fn poll(&self, now: Instant) -> Result<(), LinkFault> {
        if shared::time::expired(self.deadline(), now) {
            Err(LinkFault::Latency)
        } else {
            Ok(())
        }
    }
}
