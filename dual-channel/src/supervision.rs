//! The channel runtime's supervision checks, each a small value fed what the channel learns
//! and polled with `now`, reporting the fault it finds and its next deadline, as
//! [`VerdictCheck`](crate::crosscheck::VerdictCheck) does for the verdicts (EN 50325-5
//! Annex A.4, Model III: each channel checks the other).
//!
//! - [`InputCheck`]: the two channels' input samples agree, or differ for less than
//!   [`INPUT_DISCREPANCY`];
//! - [`NmtCheck`]: the two channels are in the same NMT state and the same epoch (NMT resets
//!   since power-on), or differ for less than their grace time;
//! - [`ConfigurationCheck`]: in Operational both channels hold the same configuration
//!   (0x13FE and the signatures); only once it has been confirmed may an output leave the safe
//!   state.
//!
//! Each check's deadline is at the instant its fault is due; a poll at the deadline itself
//! reports it, as every timer of the core does.

use crate::runtime::{ChannelFault, INPUT_DISCREPANCY};
use shared::canopen::nmt::NmtState;
use shared::time::expired;
use shared::{Duration, Instant};

/// The input cross-check: this channel's input digest against the other's, a fault when they
/// differ for [`INPUT_DISCREPANCY`].
#[derive(Clone, Copy, Debug, Default)]
pub struct InputCheck {
    /// The other channel's last input digest.
    peer: Option<u32>,
    /// Since when the two digests differ.
    differ_since: Option<Instant>,
}

impl InputCheck {
    /// Nothing compared yet.
    pub const fn new() -> Self {
        InputCheck {
            peer: None,
            differ_since: None,
        }
    }

    /// The other channel's input digest `peer` arrived at `now`; `own` is this channel's.
    pub fn peer(&mut self, now: Instant, peer: u32, own: u32) {
        self.peer = Some(peer);
        self.compare(now, own);
    }

    /// This channel's digest is `own` at `now`: starts or stops the discrepancy timer. Before
    /// the other channel's first digest there is nothing to compare.
    pub fn compare(&mut self, now: Instant, own: u32) {
        let differ = self.peer.is_some_and(|peer| peer != own);
        match (differ, self.differ_since) {
            (true, None) => self.differ_since = Some(now),
            (false, _) => self.differ_since = None,
            (true, Some(_)) => {}
        }
    }

    /// NMT reset at `now`: a difference seen before it must last its full time after it to
    /// count again (the reset clears the latch, and the other channel's news may be on the
    /// link behind the reset).
    pub fn restart(&mut self, now: Instant) {
        if self.differ_since.is_some() {
            self.differ_since = Some(now);
        }
    }

    /// Since when the samples differ, if they do.
    pub fn differ_since(&self) -> Option<Instant> {
        self.differ_since
    }

    /// [`ChannelFault::InputDiscrepancy`] once the samples have differed for
    /// [`INPUT_DISCREPANCY`].
    pub fn poll(&self, now: Instant) -> Result<(), ChannelFault> {
        match self.differ_since {
            Some(since) if expired(since + INPUT_DISCREPANCY, now) => {
                Err(ChannelFault::InputDiscrepancy)
            }
            _ => Ok(()),
        }
    }

    /// When [`InputCheck::poll`] next has something to report ([`Instant::NEVER`]: nothing).
    #[must_use]
    pub fn deadline(&self) -> Instant {
        self.differ_since
            .map_or(Instant::NEVER, |since| since + INPUT_DISCREPANCY)
    }
}

/// The NMT cross-check: both channels in the same state and epoch.
#[derive(Clone, Copy, Debug)]
pub struct NmtCheck {
    grace: Duration,
    /// NMT resets since power-on (modulo 256).
    epoch: u8,
    /// The other channel's NMT state byte and epoch from its last heartbeat (none yet:
    /// nothing to compare).
    peer: Option<(u8, u8)>,
    /// Since when the states or epochs differ.
    differs_since: Option<Instant>,
}

impl NmtCheck {
    /// A check that reports a difference lasting `grace`.
    pub const fn new(grace: Duration) -> Self {
        NmtCheck {
            grace,
            epoch: 0,
            peer: None,
            differs_since: None,
        }
    }

    /// This channel's epoch, sent in its heartbeat.
    pub fn epoch(&self) -> u8 {
        self.epoch
    }

    /// This channel's core went through an NMT reset: a new epoch.
    pub fn reset(&mut self) {
        self.epoch = self.epoch.wrapping_add(1);
    }

    /// The other channel's heartbeat said `nmt` (its heartbeat state byte) in `epoch`.
    pub fn peer(&mut self, now: Instant, nmt: u8, epoch: u8, own: NmtState) {
        self.peer = Some((nmt, epoch));
        self.compare(now, own);
    }

    /// The other channel's epoch as its last heartbeat said (none yet before the first).
    pub fn peer_epoch(&self) -> Option<u8> {
        self.peer.map(|(_, epoch)| epoch)
    }

    /// `true` unless the other channel's last heartbeat was in another epoch than ours: its
    /// messages are then not about the present and are ignored.
    pub fn same_epoch(&self) -> bool {
        self.peer.is_none_or(|(_, epoch)| epoch == self.epoch)
    }

    /// This channel is in `own` at `now`: starts or stops the mismatch timer.
    pub fn compare(&mut self, now: Instant, own: NmtState) {
        let agree = self
            .peer
            .is_none_or(|(nmt, epoch)| epoch == self.epoch && nmt == own.heartbeat_code());
        if agree {
            self.differs_since = None;
        } else if self.differs_since.is_none() {
            self.differs_since = Some(now);
        }
    }

    /// [`ChannelFault::NmtMismatch`] once the states or epochs have differed for the grace
    /// time.
    pub fn poll(&self, now: Instant) -> Result<(), ChannelFault> {
        match self.differs_since {
            Some(since) if expired(since + self.grace, now) => Err(ChannelFault::NmtMismatch),
            _ => Ok(()),
        }
    }

    /// When [`NmtCheck::poll`] next has something to report ([`Instant::NEVER`]: nothing).
    #[must_use]
    pub fn deadline(&self) -> Instant {
        self.differs_since
            .map_or(Instant::NEVER, |since| since + self.grace)
    }
}

/// The configuration cross-check: in Operational the other channel's configuration digest
/// (0x13FE and its signatures as it computes them) against this channel's.
#[derive(Clone, Copy, Debug, Default)]
pub struct ConfigurationCheck {
    /// In this Operational period the digests matched.
    confirmed: bool,
}

impl ConfigurationCheck {
    /// Nothing confirmed yet.
    pub const fn new() -> Self {
        ConfigurationCheck { confirmed: false }
    }

    /// The other channel's digest arrived: it was in Operational (`peer_operational`) with
    /// `differs` telling whether its digest differs from ours, and we are in Operational
    /// (`own_operational`). Digests are compared only when both are in Operational, where
    /// the configuration cannot change; a difference there is
    /// [`ChannelFault::ConfigurationMismatch`], agreement confirms the configuration.
    pub fn peer(
        &mut self,
        peer_operational: bool,
        own_operational: bool,
        differs: bool,
    ) -> Result<(), ChannelFault> {
        if peer_operational && own_operational {
            if differs {
                return Err(ChannelFault::ConfigurationMismatch);
            }
            self.confirmed = true;
        }
        Ok(())
    }

    /// This channel left Operational: the next Operational period confirms again.
    pub fn reset(&mut self) {
        self.confirmed = false;
    }

    /// Both channels confirmed the configuration in this Operational period: an output may
    /// leave the safe state.
    pub fn confirmed(&self) -> bool {
        self.confirmed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LIMIT: Duration = INPUT_DISCREPANCY;

    /// EN 50325-5 Annex A.4: samples that differ for the limit are a fault, at the deadline
    /// itself; agreement before it stops the timer.
    #[test]
    fn differing_input_samples_are_a_fault_at_the_limit_and_agreement_stops_the_timer() {
        let mut check = InputCheck::new();
        let t = Instant::from_millis(10);
        check.compare(t, 1);
        assert_eq!(check.deadline(), Instant::NEVER, "no peer digest yet");
        check.peer(t, 2, 1);
        assert_eq!(check.deadline(), t + LIMIT);
        let just_before = Instant::from_micros((t + LIMIT).as_micros() - 1);
        assert_eq!(check.poll(just_before), Ok(()));
        assert_eq!(check.poll(t + LIMIT), Err(ChannelFault::InputDiscrepancy));
        // Still different later: the timer keeps its start.
        check.compare(Instant::from_millis(100), 3);
        assert_eq!(check.deadline(), t + LIMIT);
        check.compare(Instant::from_millis(150), 2);
        assert_eq!(
            (check.deadline(), check.differ_since()),
            (Instant::NEVER, None)
        );
        assert_eq!(check.poll(Instant::from_millis(500)), Ok(()));
    }

    /// A difference seen before an NMT reset counts from the reset on.
    #[test]
    fn an_nmt_reset_restarts_a_running_input_discrepancy_timer_only() {
        let mut check = InputCheck::new();
        check.restart(Instant::from_millis(5));
        assert_eq!(check.deadline(), Instant::NEVER);
        check.peer(Instant::from_millis(10), 2, 1);
        check.restart(Instant::from_millis(100));
        assert_eq!(check.deadline(), Instant::from_millis(100) + LIMIT);
    }

    /// EN 50325-5 Annex A.4: NMT states or epochs that differ for the grace time are a fault.
    #[test]
    fn differing_nmt_states_or_epochs_are_a_fault_after_the_grace_time() {
        let grace = Duration::from_millis(40);
        let mut check = NmtCheck::new(grace);
        let t = Instant::from_millis(10);
        check.compare(t, NmtState::Operational);
        assert_eq!(check.deadline(), Instant::NEVER, "no heartbeat yet");
        check.peer(
            t,
            NmtState::PreOperational.heartbeat_code(),
            0,
            NmtState::Operational,
        );
        let just_before = Instant::from_micros((t + grace).as_micros() - 1);
        assert_eq!(check.poll(just_before), Ok(()));
        assert_eq!(check.poll(t + grace), Err(ChannelFault::NmtMismatch));
        check.peer(
            t,
            NmtState::Operational.heartbeat_code(),
            0,
            NmtState::Operational,
        );
        assert_eq!(check.deadline(), Instant::NEVER);
        // The same state in another epoch is a difference too, and its messages are ignored.
        check.reset();
        assert_eq!(check.epoch(), 1);
        assert!(!check.same_epoch());
        check.compare(t, NmtState::Operational);
        assert_eq!(check.deadline(), t + grace);
        check.peer(
            t,
            NmtState::Operational.heartbeat_code(),
            1,
            NmtState::Operational,
        );
        assert!(check.same_epoch());
        assert_eq!(check.deadline(), Instant::NEVER);
    }

    /// The epoch wraps at 256 resets rather than overflowing.
    #[test]
    fn the_epoch_wraps() {
        let mut check = NmtCheck::new(Duration::from_millis(40));
        for _ in 0..256 {
            check.reset();
        }
        assert_eq!(check.epoch(), 0);
    }

    /// Digests are compared only when both channels are in Operational; a difference there
    /// is a fault, agreement confirms until the channel leaves Operational.
    #[test]
    fn the_configuration_is_confirmed_only_by_agreement_in_operational() {
        let mut check = ConfigurationCheck::new();
        assert_eq!(check.peer(true, false, true), Ok(()));
        assert_eq!(check.peer(false, true, true), Ok(()));
        assert!(!check.confirmed());
        assert_eq!(
            check.peer(true, true, true),
            Err(ChannelFault::ConfigurationMismatch)
        );
        assert!(!check.confirmed());
        assert_eq!(check.peer(true, true, false), Ok(()));
        assert!(check.confirmed());
        check.reset();
        assert!(!check.confirmed());
    }
}
