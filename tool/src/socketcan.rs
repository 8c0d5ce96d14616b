//! SocketCAN (Linux), through the `socketcan` crate; behind the `socketcan` feature.
//!
//! Its runtime test needs a CAN interface; on a Linux machine with the `vcan` module:
//! `sudo modprobe vcan && sudo ip link add dev vcan0 type vcan && sudo ip link set up vcan0`,
//! then `SAFETY_CONFIG_VCAN=vcan0 cargo test -p safety-config --features socketcan`.

use crate::transport::{Transport, TransportError, WallClock, frame_from_parts};
use shared::CanFrame;
use socketcan::{EmbeddedFrame, Frame, Socket};
use std::io::ErrorKind;
use std::time::Duration;

/// A raw SocketCAN socket on one interface.
pub struct SocketCan {
    socket: socketcan::CanSocket,
    clock: WallClock,
}

impl SocketCan {
    /// Opens the interface `name` (e.g. `can0`, `vcan0`).
    pub fn open(name: &str) -> Result<Self, TransportError> {
        let socket = socketcan::CanSocket::open(name)?;
        Ok(SocketCan {
            socket,
            clock: WallClock::start(),
        })
    }
}

impl Transport for SocketCan {
    fn now(&mut self) -> Duration {
        self.clock.now()
    }

    fn send(&mut self, frame: &CanFrame) -> Result<(), TransportError> {
        let id = socketcan::StandardId::new(frame.id().raw())
            .ok_or_else(|| TransportError::Protocol("identifier is not 11-bit".into()))?;
        let out = if frame.is_remote() {
            socketcan::CanFrame::new_remote(id, usize::from(frame.dlc()))
        } else {
            socketcan::CanFrame::new(id, frame.data())
        }
        .ok_or_else(|| TransportError::Protocol("frame does not fit SocketCAN".into()))?;
        self.socket.write_frame(&out)?;
        Ok(())
    }

    fn receive(&mut self, deadline: Duration) -> Result<Option<CanFrame>, TransportError> {
        while let Some(left) = self.clock.until(deadline) {
            self.socket.set_read_timeout(left)?;
            match self.socket.read_frame() {
                Ok(frame) => {
                    let socketcan::Id::Standard(id) = frame.id() else {
                        continue;
                    };
                    if frame.is_error_frame() {
                        continue;
                    }
                    if frame.is_remote_frame() {
                        let id = frame_from_parts(u32::from(id.as_raw()), &[])?.id();
                        let dlc = frame.dlc() as u8;
                        return CanFrame::remote(id, dlc)
                            .map(Some)
                            .map_err(|_| TransportError::Protocol("DLC above 8".into()));
                    }
                    return frame_from_parts(u32::from(id.as_raw()), frame.data()).map(Some);
                }
                Err(error)
                    if matches!(error.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
                Err(error) => return Err(error.into()),
            }
        }
        Ok(None)
    }
}
