//! The age of a received value and its safety timeout (SC_REQ_20, SC_REQ_05).
//!
//! A consumer keeps, per SC-ID it listens to, the last value that passed every check and the
//! instant it was produced: the start of the producer's slot (`docs/simplecan.md` section 5),
//! mapped to the consumer's own clock. The value's age runs from that instant, so the time a
//! packet spent in transit and in buffers is part of it. When the age reaches the configured
//! safety timeout the value is 0 from then on (SC_REQ_20), and the timeout is reported once so
//! the SCL can signal the safe state (SC_REQ_14). Before the first valid packet the value is 0
//! too (SC_REQ_29, SC_REQ_05). A timeout is latched: a later packet does not bring the value
//! back; only a new `ConsumedValue` (a reset of the SCL, SC_REQ_41) does.

use crate::time::{Duration, Instant, expired};

/// One consumed value and its age.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ConsumedValue {
    timeout: Duration,
    state: State,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
enum State {
    /// Nothing valid received yet.
    Waiting,
    /// The last valid value and when it was produced.
    Fresh { value: u32, produced: Instant },
    /// The timeout passed: 0 until reset.
    TimedOut,
}

/// What [`ConsumedValue::poll`] found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[must_use = "a timeout means the safe state for this value (SC_REQ_20)"]
pub enum Age {
    /// Within its timeout, or nothing received yet.
    Valid,
    /// The value's age reached its timeout just now: it is 0 from now on. Reported once.
    TimedOut,
}

impl ConsumedValue {
    /// A value with safety timeout `timeout`, 0 until its first valid packet.
    pub const fn new(timeout: Duration) -> Self {
        ConsumedValue {
            timeout,
            state: State::Waiting,
        }
    }

    /// A packet carrying `value`, produced at `produced` (the start of its slot, on this
    /// SCL's clock), passed every check. A packet already as old as its timeout (or older
    /// than the value held) changes nothing.
    pub fn accept(&mut self, value: u32, produced: Instant) {
        match self.state {
            State::TimedOut => {}
            State::Fresh { produced: held, .. } if produced <= held => {}
            _ => {
                self.state = State::Fresh { value, produced };
            }
        }
    }

    /// The value the application uses at `now`: the last valid one while its age is below the
    /// timeout, 0 otherwise (SC_REQ_05).
    pub fn value(&self, now: Instant) -> u32 {
        match self.state {
            State::Fresh { value, produced } if !expired(produced + self.timeout, now) => value,
            _ => 0,
        }
    }

    /// The age of the value at `now`, if one was received and has not timed out.
    pub fn age(&self, now: Instant) -> Option<Duration> {
        match self.state {
            State::Fresh { produced, .. } => Some(now.saturating_since(produced)),
            _ => None,
        }
    }

    /// Checks the age at `now`; at or past the timeout the value becomes 0 for good.
    pub fn poll(&mut self, now: Instant) -> Age {
        match self.state {
            State::Fresh { produced, .. } if expired(produced + self.timeout, now) => {
                self.state = State::TimedOut;
                Age::TimedOut
            }
            _ => Age::Valid,
        }
    }

    /// When the held value times out, or never.
    #[must_use]
    pub fn deadline(&self) -> Instant {
        match self.state {
            State::Fresh { produced, .. } => produced + self.timeout,
            _ => Instant::NEVER,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    #[test]
    fn sc_req_05_a_value_is_0_before_its_first_packet() {
        let value = ConsumedValue::new(Duration::from_millis(50));
        assert_eq!(value.value(at(0)), 0);
        assert_eq!(value.deadline(), Instant::NEVER);
    }

    /// The age counts from production: a packet produced at 10 ms and accepted at 13 ms with
    /// a 50 ms timeout is valid until 59.999 ms and 0 at 60 ms.
    #[test]
    fn sc_req_20_the_value_is_0_once_its_age_reaches_the_timeout() {
        let mut value = ConsumedValue::new(Duration::from_millis(50));
        value.accept(0xABCD, at(10));
        assert_eq!(value.age(at(13)), Some(Duration::from_millis(3)));
        assert_eq!(value.deadline(), at(60));
        assert_eq!(value.poll(Instant::from_micros(59_999)), Age::Valid);
        assert_eq!(value.value(Instant::from_micros(59_999)), 0xABCD);
        // At the deadline itself the value is already 0, even before the poll.
        assert_eq!(value.value(at(60)), 0);
        assert_eq!(value.poll(at(60)), Age::TimedOut);
        assert_eq!(value.poll(at(61)), Age::Valid, "reported once");
        assert_eq!(value.value(at(61)), 0);
    }

    #[test]
    fn sc_req_20_each_fresh_packet_restarts_the_age() {
        let mut value = ConsumedValue::new(Duration::from_millis(50));
        value.accept(1, at(0));
        value.accept(2, at(40));
        assert_eq!(value.poll(at(60)), Age::Valid);
        assert_eq!(value.value(at(60)), 2);
        assert_eq!(value.deadline(), at(90));
        // An older packet (resequenced) does not replace a newer one.
        value.accept(3, at(20));
        assert_eq!(value.value(at(60)), 2);
    }

    /// SC_REQ_41: after a timeout only a reset (a new value) brings data back.
    #[test]
    fn sc_req_20_a_timed_out_value_stays_0_until_reset() {
        let mut value = ConsumedValue::new(Duration::from_millis(50));
        value.accept(7, at(0));
        assert_eq!(value.poll(at(50)), Age::TimedOut);
        value.accept(8, at(51));
        assert_eq!(value.value(at(52)), 0);
        assert_eq!(value.deadline(), Instant::NEVER);
    }
}
