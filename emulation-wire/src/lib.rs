//! The emulated network's vocabulary that its programs share apart from the safety runtime
//! (no_std, no heap): a channel's status ([`Status`], what the control port's status lines
//! carry, `can_hub::control`) and the lookahead and grant period of the virtual time held to
//! the host clock ([`LOOKAHEAD`], [`GRANT_PERIOD`], `can_hub::pace`). The emulated network of
//! the shipped images (`emulator`), the hub, xtask and the system tests use it.

#![no_std]
#![forbid(unsafe_code)]

/// The lookahead of the emulated network's virtual time (`can_hub::pace`): it runs at most
/// this far past the last grant the paced participant acknowledged. The emulated network's
/// socketcand port paces the network with it (`emulator::socketcand`); the campaigns' oracle
/// allows for it on an emulated run (`system_tests::campaign::recorded`).
pub const LOOKAHEAD: shared::Duration = shared::Duration::from_millis(20);

/// How often (virtual time) a paced participant is granted time; well below [`LOOKAHEAD`],
/// so that a participant that keeps up is never held.
pub const GRANT_PERIOD: shared::Duration = shared::Duration::from_millis(5);

/// What one emulated channel shows of itself: its state, its pins and its diagnostics, as the
/// control port reports it (`can_hub::control::status_line`). Counters wrap.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Status {
    /// The channel's NMT state as its heartbeat code (0: Initialising, 4: Stopped,
    /// 5: Operational, 127: Pre-operational).
    pub nmt: u8,
    /// Neither the channel nor its core is in the safe state.
    pub working: bool,
    /// The other channel has been heard on the link.
    pub link_up: bool,
    /// The value on the channel's output pin (lowest byte of receive SRDO 1's output).
    pub output: u8,
    /// The channel's safety input as it last sampled it.
    pub input: u8,
    /// The cause code of the last safe state latched (0: none since power-on or reset; every
    /// code and its name are in `shared::safety::cause::Cause`, see [`Status::latched_cause`]).
    pub cause: u8,
    /// SRDO frames this channel sent.
    pub sent: u16,
    /// Valid SRDO pairs this channel's core received.
    pub validated: u16,
    /// The longest time, in real milliseconds, the emulated MCU did not run (its tick
    /// interrupt came late): the emulator's scheduling jitter, for the report.
    pub longest_stall_ms: u16,
    /// The longest time, in milliseconds, between two receptions from the link (the other
    /// channel's heartbeat period plus the link's jitter), for the report.
    pub longest_link_gap_ms: u16,
    /// The longest time, in milliseconds, the channel's loop spent on one wake-up (handling
    /// frames, link bytes and timers before waiting again), for the report.
    pub longest_busy_ms: u16,
    /// The stack's high-water mark in bytes (saturating), for the report.
    pub stack_used: u16,
    /// SRDO frames the core discarded as CAN double reception (exact repeats of a pending
    /// plain frame, inverted frames with no plain frame pending; ISO 11898-1), since power-on
    /// or NMT reset, saturating: object 5C00h sub-indices 1 and 2 added up.
    pub discarded: u16,
}

impl Status {
    /// The NMT state [`Status::nmt`] names, `None` for a byte that is no heartbeat state code.
    pub const fn nmt_state(&self) -> Option<shared::canopen::nmt::NmtState> {
        shared::canopen::nmt::NmtState::from_heartbeat_code(self.nmt)
    }

    /// The cause [`Status::cause`] names, `None` for a byte that is no cause code (an
    /// application's own detail byte).
    pub fn latched_cause(&self) -> Option<shared::safety::cause::Cause> {
        shared::safety::cause::Cause::from_code(self.cause)
    }
}
