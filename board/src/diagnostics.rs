//! What a channel reports about itself to whoever watches the board (the emulated network's
//! hub and its display): NMT state, safe or working, output, counters, the cause of the last
//! safe state. Sans-I/O: the board layer hands it what the runtime did and asks when a report
//! is due.
//!
//! A report goes out at once when anything a watcher acts on changes (state, output, input,
//! cause), and otherwise every [`PERIOD`], so counters stay fresh and a silent channel is
//! noticed.

use dual_channel::runtime::{
    ChannelEvent, ChannelProtocol, Role, Runtime, is_srdo, safe_state_code,
};
use emulation_wire::Status;
use shared::canopen::nmt::NmtState;
use shared::canopen::storage::Flash;
use shared::node::Event;
use shared::safety::types::SrdoNumber;
use shared::{CanFrame, Duration, Instant};

/// The longest time between two reports.
pub const PERIOD: Duration = Duration::from_millis(250);

/// The cause code reported for a received GFC (EN 50325-5 7.2.1).
pub use dual_channel::runtime::GFC_CAUSE;

/// A channel's diagnostics.
#[derive(Clone, Debug)]
pub struct Diagnostics {
    status: Status,
    last_reported: Option<Status>,
    next_report: Instant,
    last_link: Option<Instant>,
}

impl Default for Diagnostics {
    fn default() -> Self {
        Self::new()
    }
}

impl Diagnostics {
    /// Nothing counted yet; the first report is due at once.
    pub const fn new() -> Self {
        Diagnostics {
            status: Status {
                nmt: 0,
                working: false,
                link_up: false,
                output: 0,
                input: 0,
                cause: 0,
                sent: 0,
                validated: 0,
                longest_stall_ms: 0,
                longest_link_gap_ms: 0,
                longest_busy_ms: 0,
                stack_used: 0,
                discarded: 0,
            },
            last_link: None,
            last_reported: None,
            next_report: Instant::ZERO,
        }
    }

    /// The channel sent `frame`.
    pub fn transmitted(&mut self, frame: &CanFrame) {
        if is_srdo(frame) {
            self.status.sent = self.status.sent.wrapping_add(1);
        }
    }

    /// The channel reported `event`.
    pub fn event(&mut self, event: &ChannelEvent) {
        match event {
            ChannelEvent::Node(Event::SrdoReceived { .. }) => {
                self.status.validated = self.status.validated.wrapping_add(1);
            }
            // A consumed SimpleCAN value both channels confirmed counts as a valid reception
            // as an SRDO pair does (`Status::validated`).
            #[cfg(feature = "simplecan")]
            ChannelEvent::SimpleCanConfirmed { .. } => {
                self.status.validated = self.status.validated.wrapping_add(1);
            }
            ChannelEvent::Node(Event::SafeState(cause)) => {
                self.status.cause = safe_state_code(cause);
            }
            // An NMT reset (node or communication) clears the latched safe state and its
            // cause (`shared::node`): the report says "none since power-on or reset", as
            // `Status::cause` promises, not the cause of a safe state the reset ended.
            ChannelEvent::Node(Event::NmtState(NmtState::Initialising)) => self.status.cause = 0,
            ChannelEvent::Fault(fault) => self.status.cause = fault.cause_code(),
            _ => {}
        }
    }

    /// Bytes arrived from the link at `now`.
    pub fn link_received(&mut self, now: Instant) {
        if let Some(last) = self.last_link {
            let gap_ms = now.as_micros().saturating_sub(last.as_micros()) / 1000;
            let gap_ms = u16::try_from(gap_ms).unwrap_or(u16::MAX);
            self.status.longest_link_gap_ms = self.status.longest_link_gap_ms.max(gap_ms);
        }
        self.last_link = Some(now);
    }

    /// One wake-up of the channel's loop ran from `start` to `end`.
    pub fn busy(&mut self, start: Instant, end: Instant) {
        let ms = end.as_micros().saturating_sub(start.as_micros()) / 1000;
        let ms = u16::try_from(ms).unwrap_or(u16::MAX);
        self.status.longest_busy_ms = self.status.longest_busy_ms.max(ms);
    }

    /// The stack's high-water mark is `bytes`.
    pub fn stack(&mut self, bytes: usize) {
        self.status.stack_used = u16::try_from(bytes).unwrap_or(u16::MAX);
    }

    /// The channel's input pin was sampled as `value`.
    pub fn input(&mut self, value: u8) {
        self.status.input = value;
    }

    /// The emulated MCU did not run for `stall_ms` real milliseconds (kept: the longest).
    pub fn stalled(&mut self, stall_ms: u16) {
        self.status.longest_stall_ms = self.status.longest_stall_ms.max(stall_ms);
    }

    /// The report to send at `now`, if one is due: when something a watcher acts on changed
    /// since the last one, or [`PERIOD`] after it.
    pub fn report<F: Flash, R: Role<N>, const N: usize, P: ChannelProtocol<N>>(
        &mut self,
        now: Instant,
        runtime: &Runtime<F, R, N, P>,
    ) -> Option<Status> {
        self.status.nmt = runtime.node().nmt_state().heartbeat_code();
        self.status.working = runtime.is_working();
        self.status.link_up = runtime.link_up();
        // The output pin is the lowest byte of receive SRDO 1 (the demo device's relay).
        self.status.output = runtime.output(SrdoNumber::FIRST) as u8;
        // With SimpleCAN enabled: the value of the first consumed SC-ID (the demo device's
        // relay follows it), as the channel drives it.
        #[cfg(feature = "simplecan")]
        if let Some(layer) = runtime.node().protocol().simplecan() {
            let entries = layer.entries.get(..layer.count).unwrap_or(&layer.entries);
            let consumed = entries
                .iter()
                .find(|entry| entry.role == shared::node::simplecan::ROLE_CONSUME);
            if let Some(entry) = consumed {
                self.status.output = runtime.simplecan_output(entry.sc_id) as u8;
            }
        }
        let discarded = runtime.node().double_reception();
        self.status.discarded = u16::try_from(
            discarded
                .plain_repeated
                .saturating_add(discarded.inverted_without_plain),
        )
        .unwrap_or(u16::MAX);
        let changed = self.last_reported.is_none_or(|last| {
            (
                last.nmt,
                last.working,
                last.link_up,
                last.output,
                last.input,
                last.cause,
            ) != (
                self.status.nmt,
                self.status.working,
                self.status.link_up,
                self.status.output,
                self.status.input,
                self.status.cause,
            )
        });
        if !changed && !shared::time::expired(self.next_report, now) {
            return None;
        }
        self.last_reported = Some(self.status);
        self.next_report = now + PERIOD;
        Some(self.status)
    }

    /// When the next periodic report is due.
    pub fn deadline(&self) -> Instant {
        self.next_report
    }

    /// The cause code the next report carries (`Status::cause`).
    pub fn cause(&self) -> u8 {
        self.status.cause
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::node::SafeStateCause;

    /// EN 50325-5 7.2.1, CiA 301 7.3.2.2.1: a GFC latches the safe state, and NMT reset node
    /// (or communication) ends it; the report's cause follows: the GFC's code while latched,
    /// none after the reset (a safe state entered after the reset is reported again).
    #[test]
    fn en50325_5_7_2_1_a_reset_clears_the_reported_cause_of_the_safe_state_it_ended() {
        let mut diagnostics = Diagnostics::new();
        assert_eq!(diagnostics.cause(), 0);
        let gfc = ChannelEvent::Node(Event::SafeState(SafeStateCause::Gfc));
        diagnostics.event(&gfc);
        let latched = diagnostics.cause();
        assert_ne!(latched, 0);
        diagnostics.event(&ChannelEvent::Node(Event::NmtState(
            NmtState::PreOperational,
        )));
        assert_eq!(
            diagnostics.cause(),
            latched,
            "only a reset ends the safe state"
        );
        diagnostics.event(&ChannelEvent::Node(Event::NmtState(NmtState::Initialising)));
        assert_eq!(diagnostics.cause(), 0);
        diagnostics.event(&gfc);
        assert_eq!(diagnostics.cause(), latched);
    }
}
