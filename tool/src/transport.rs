//! The one CAN transport trait every adapter implements: send a frame; receive the next frame
//! before a deadline. Time is the transport's own: wall-clock time for real interfaces,
//! simulated time for the host simulation, so the procedures above never read a clock and run
//! deterministically in simulation.
//!
//! Frames are CAN 2.0A (11-bit identifiers), as CANopen uses them; adapters drop extended
//! frames they receive (they cannot belong to a CANopen Safety exchange) and never send one.

use shared::CanFrame;
use std::time::Duration;

/// Why a transport could not send or receive.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// The interface failed.
    #[error("the CAN interface failed: {0}")]
    Io(#[from] std::io::Error),
    /// The other end said something this adapter does not understand.
    #[error("the CAN interface sent something this tool does not understand: {0}")]
    Protocol(String),
    /// The other end closed the connection.
    #[error("the CAN interface closed the connection")]
    Closed,
    /// No socketcand server answered at the address.
    #[error(
        "no socketcand server at {address}: {source} (start one there, or name another \
         interface with --bus)"
    )]
    Connect {
        /// The address tried (`host:port`).
        address: String,
        /// What the operating system said.
        source: std::io::Error,
    },
}

/// A CAN interface the tool talks through.
pub trait Transport {
    /// The transport's time: how long it has been open (simulated time in a simulation).
    fn now(&mut self) -> Duration;

    /// Puts `frame` on the bus.
    fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError>;

    /// The next frame received from the bus, or `None` when none came before `deadline`
    /// (a time on [`Transport::now`]'s clock). Frames this tool sent itself are not
    /// received back.
    fn receive(&mut self, deadline: Duration) -> Result<Option<CanFrame>, TransportError>;

    /// [`Transport::receive`] with the time the frame was on the bus: the interface's own
    /// timestamp where it gives one (socketcand's `frame` message carries it; on the
    /// emulated bus it is the hub's virtual time), else the time it was received on
    /// [`Transport::now`]'s clock. Timestamps of one transport are on one clock, which need
    /// not be `now`'s.
    fn receive_stamped(
        &mut self,
        deadline: Duration,
    ) -> Result<Option<(Duration, CanFrame)>, TransportError> {
        Ok(self.receive(deadline)?.map(|frame| (self.now(), frame)))
    }
}

impl<T: Transport + ?Sized> Transport for Box<T> {
    fn now(&mut self) -> Duration {
        (**self).now()
    }
    fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        (**self).send(frame)
    }
    fn receive(&mut self, deadline: Duration) -> Result<Option<CanFrame>, TransportError> {
        (**self).receive(deadline)
    }
    fn receive_stamped(
        &mut self,
        deadline: Duration,
    ) -> Result<Option<(Duration, CanFrame)>, TransportError> {
        (**self).receive_stamped(deadline)
    }
}

/// A transport borrowed: a step that takes a transport (an LSS master, say) uses the
/// client's and leaves it to the next.
impl<T: Transport + ?Sized> Transport for &mut T {
    fn now(&mut self) -> Duration {
        (**self).now()
    }
    fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        (**self).send(frame)
    }
    fn receive(&mut self, deadline: Duration) -> Result<Option<CanFrame>, TransportError> {
        (**self).receive(deadline)
    }
    fn receive_stamped(
        &mut self,
        deadline: Duration,
    ) -> Result<Option<(Duration, CanFrame)>, TransportError> {
        (**self).receive_stamped(deadline)
    }
}

/// A wall clock for real interfaces: the time since the adapter was opened.
#[derive(Clone, Copy, Debug)]
pub struct WallClock(std::time::Instant);

impl WallClock {
    /// A clock starting now.
    pub fn start() -> Self {
        WallClock(std::time::Instant::now())
    }

    /// Time since the start.
    pub fn now(&self) -> Duration {
        self.0.elapsed()
    }

    /// How long until `deadline`, or `None` when it has passed.
    pub fn until(&self, deadline: Duration) -> Option<Duration> {
        deadline
            .checked_sub(self.now())
            .filter(|left| !left.is_zero())
    }
}

/// Parses the hexadecimal data bytes of a text protocol frame (`"1122"` or `["11", "22"]`
/// joined), as SLCAN and socketcand carry them.
pub(crate) fn frame_from_parts(id: u32, data: &[u8]) -> Result<CanFrame, TransportError> {
    let id = u16::try_from(id)
        .ok()
        .and_then(|raw| shared::CanId::new(raw).ok())
        .ok_or_else(|| TransportError::Protocol(format!("CAN identifier {id:X}h is not 11-bit")))?;
    CanFrame::new(id, data)
        .map_err(|_| TransportError::Protocol(format!("{} data bytes are more than 8", data.len())))
}
