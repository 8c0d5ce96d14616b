//! Heartbeat producer and boot-up message (EN 50325-4, CiA 301 7.2.8.3.2).

use super::nmt::NmtState;
use super::node_id::NodeId;
use crate::frame::{CanFrame, CanId};
use crate::time::{self, Duration, Instant};

/// The heartbeat (and boot-up) frame of `node_id` in `state`: CAN-ID 700h + node-ID, one byte.
pub const fn frame(node_id: NodeId, state: NmtState) -> CanFrame {
    CanFrame::with_len(
        CanId::from_masked(0x700 + node_id.raw() as u16),
        [state.heartbeat_code(), 0, 0, 0, 0, 0, 0, 0],
        1,
    )
}

/// The heartbeat producer, driven by object 0x1017 (producer heartbeat time in ms, 0 = off).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Heartbeat {
    period_ms: u16,
    next: Instant,
}

impl Heartbeat {
    /// A producer with period `period_ms` (0: disabled), first beat one period after `now`.
    pub fn new(period_ms: u16, now: Instant) -> Self {
        let mut heartbeat = Heartbeat {
            period_ms,
            next: Instant::NEVER,
        };
        heartbeat.restart(now);
        heartbeat
    }

    /// The configured period in ms (object 0x1017).
    pub fn period_ms(&self) -> u16 {
        self.period_ms
    }

    /// Changes the period (a write to 0x1017) and restarts the timer from `now`.
    pub fn set_period(&mut self, period_ms: u16, now: Instant) {
        self.period_ms = period_ms;
        self.restart(now);
    }

    fn restart(&mut self, now: Instant) {
        self.next = match self.period_ms {
            0 => Instant::NEVER,
            ms => now + Duration::from_millis(u64::from(ms)),
        };
    }

    /// The next beat, `Instant::NEVER` when disabled.
    pub fn deadline(&self) -> Instant {
        self.next
    }

    /// `true` (and the next beat scheduled) when a beat is due at `now`.
    pub fn poll(&mut self, now: Instant) -> bool {
        if self.period_ms == 0 || !time::expired(self.next, now) {
            return false;
        }
        let period = Duration::from_millis(u64::from(self.period_ms));
        let on_cycle = self.next + period;
        self.next = if time::expired(on_cycle, now) {
            now + period
        } else {
            on_cycle
        };
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cia301_7_2_8_3_2_heartbeat_frame() {
        let frame = frame(NodeId::new(5).unwrap(), NmtState::Operational);
        assert_eq!(frame.id().raw(), 0x705);
        assert_eq!(frame.data(), &[0x05]);
        assert_eq!(
            super::frame(NodeId::new(5).unwrap(), NmtState::Initialising).data(),
            &[0],
            "boot-up"
        );
    }

    #[test]
    fn cia301_7_2_8_3_2_producer_period_and_disable() {
        let mut heartbeat = Heartbeat::new(100, Instant::ZERO);
        assert!(!heartbeat.poll(Instant::from_millis(99)));
        assert!(heartbeat.poll(Instant::from_millis(100)));
        assert_eq!(heartbeat.deadline(), Instant::from_millis(200));
        heartbeat.set_period(0, Instant::from_millis(150));
        assert_eq!(heartbeat.deadline(), Instant::NEVER);
        assert!(!heartbeat.poll(Instant::from_millis(1_000)));
    }
}
