//! The TCP side of a port that serves clients: `can-hub`'s tool and control ports, and the
//! socketcand port of the emulator's network (`emulate-network --socketcand`). The protocol
//! itself is elsewhere (socketcand: the tool crate's sans-I/O session,
//! `safety_config::socketcand::server`; the control lines: [`crate::control`]); here is what
//! keeps a port from holding more and more whatever its clients do:
//!
//! - at most [`MAX_CLIENTS`] connections of a kind at once; one more is told why in a
//!   sentence, in the protocol it speaks, and closed ([`Connections`], [`refuse`]);
//! - a client's bytes are read only while fewer than [`BACKLOG`] wait for the program
//!   ([`reader`]): a sender whose frames wait for the bus waits too, as on a real bus;
//! - a write that blocks for [`WRITE_TIMEOUT`] fails, and the program disconnects the client
//!   instead of stalling the bus.

use std::io::{Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

/// Bytes a client may have sent that the program has not yet taken (its transmit FIFO was
/// full); past this its socket is not read until the bus has taken frames.
pub const BACKLOG: usize = 4096;

/// How long a write to a client may block before the client is disconnected.
pub const WRITE_TIMEOUT: Duration = Duration::from_secs(1);

/// `true` when a write to a client failed because the client's end of the connection is
/// closed (it sent what it had and left), not because the client does not read (a write
/// blocked for [`WRITE_TIMEOUT`]): the program then writes to it no more but still takes the
/// bytes it sent before closing, up to the end of its stream.
pub fn peer_closed(error: &std::io::Error) -> bool {
    use std::io::ErrorKind;
    matches!(
        error.kind(),
        ErrorKind::BrokenPipe | ErrorKind::ConnectionReset | ErrorKind::ConnectionAborted
    )
}

/// Connections of one kind a port serves at once.
pub const MAX_CLIENTS: usize = 16;

/// Connections of one kind in use, counted up to [`MAX_CLIENTS`].
#[derive(Clone, Default)]
pub struct Connections(Arc<AtomicUsize>);

/// One connection counted in [`Connections`] until dropped (when its reader thread ends).
pub struct Counted(Arc<AtomicUsize>);

impl Connections {
    /// A place for one more connection, or `None` when all [`MAX_CLIENTS`] are in use.
    pub fn take(&self) -> Option<Counted> {
        self.0
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
                (n < MAX_CLIENTS).then_some(n + 1)
            })
            .ok()
            .map(|_| Counted(self.0.clone()))
    }
}

impl Drop for Counted {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

/// Tells a connection past [`MAX_CLIENTS`] why it is closed (`line`, in the protocol it
/// speaks), and closes it.
pub fn refuse(mut stream: TcpStream, line: &str) {
    let _ = stream.write_all(line.as_bytes());
    let _ = stream.shutdown(Shutdown::Both);
}

/// What a client's reader thread reports.
#[derive(Debug)]
pub enum Arrival {
    /// Bytes client `id` sent (counted in its `pending` until the program takes them).
    Bytes(usize, Vec<u8>),
    /// Client `id` closed its connection (or it failed).
    Left(usize),
}

/// Reads client `id`'s bytes for the program while fewer than [`BACKLOG`] are waiting
/// (`pending`, which the program lowers as it takes them); otherwise waits, and the sender
/// with it. Ends when the stream ends or `tell` returns `false` (the program is gone).
pub fn reader(
    id: usize,
    mut stream: impl Read,
    pending: Arc<AtomicUsize>,
    mut tell: impl FnMut(Arrival) -> bool,
) {
    let mut buf = [0u8; 256];
    loop {
        while pending.load(Ordering::Acquire) >= BACKLOG {
            std::thread::sleep(Duration::from_millis(1));
        }
        match stream.read(&mut buf) {
            Ok(0) | Err(_) => {
                let _ = tell(Arrival::Left(id));
                return;
            }
            Ok(n) => {
                pending.fetch_add(n, Ordering::AcqRel);
                if !tell(Arrival::Bytes(id, buf[..n].to_vec())) {
                    return;
                }
            }
        }
    }
}

/// What the socketcand port's threads report ([`accept_socketcand`]).
#[derive(Debug)]
pub enum ToolEvent {
    /// A client connected as number `id`: its connection (write to it; shut it down to end
    /// the session) and its count of bytes not yet taken (lower it by what the program takes).
    Joined {
        /// The client's number.
        id: usize,
        /// Its connection, with [`WRITE_TIMEOUT`] set.
        stream: TcpStream,
        /// Its bytes sent and not yet taken.
        pending: Arc<AtomicUsize>,
    },
    /// Bytes or a departure, from the client's reader thread.
    Arrival(Arrival),
}

/// Accepts socketcand clients on `listener` in a thread of its own, numbered `first`,
/// `first + 1`, ..., each read by a [`reader`] thread; everything is reported to `tell`.
/// Past [`MAX_CLIENTS`] a client is told, in a socketcand error message naming `server`
/// (`the hub`), that it serves that many, and closed.
pub fn accept_socketcand(
    listener: TcpListener,
    first: usize,
    server: &str,
    tell: impl Fn(ToolEvent) -> bool + Clone + Send + 'static,
) {
    let refusal = format!(
        "< error {server} serves {MAX_CLIENTS} tools at once; close one and connect again >"
    );
    let clients = Connections::default();
    std::thread::spawn(move || {
        for (offset, stream) in listener.incoming().enumerate() {
            let Ok(stream) = stream else { continue };
            let _ = stream.set_nodelay(true);
            let _ = stream.set_write_timeout(Some(WRITE_TIMEOUT));
            let Some(counted) = clients.take() else {
                refuse(stream, &refusal);
                continue;
            };
            let id = first + offset;
            let Ok(writer) = stream.try_clone() else {
                continue;
            };
            let pending = Arc::new(AtomicUsize::new(0));
            if !tell(ToolEvent::Joined {
                id,
                stream: writer,
                pending: pending.clone(),
            }) {
                return;
            }
            let tell = tell.clone();
            std::thread::spawn(move || {
                let _counted = counted;
                reader(id, stream, pending, |arrival| {
                    tell(ToolEvent::Arrival(arrival))
                });
            });
        }
    });
}

/// What the control port's threads report ([`accept_control`]).
#[derive(Debug)]
pub enum ControlEvent {
    /// A client connected as number `client`: its connection, to write the answers and the
    /// reports to (with [`WRITE_TIMEOUT`] set).
    Joined(usize, TcpStream),
    /// A line from client `client`, or why it was refused
    /// ([`crate::control::read_line`]).
    Line(usize, Result<String, String>),
}

/// Accepts control clients (the line protocol of [`crate::control`]) on `listener` in a
/// thread of its own, numbered from 0, each read line by line in a thread of its own;
/// everything is reported to `tell`. Past [`MAX_CLIENTS`] a client is told, in an `error`
/// line naming `server` (`the hub`), that it serves that many, and closed.
pub fn accept_control(
    listener: TcpListener,
    server: &str,
    tell: impl Fn(ControlEvent) -> bool + Clone + Send + 'static,
) {
    let refusal = format!(
        "error {server} serves {MAX_CLIENTS} control clients at once; close one and connect \
         again\n"
    );
    let controls = Connections::default();
    std::thread::spawn(move || {
        for (client, stream) in listener.incoming().enumerate() {
            let Ok(stream) = stream else { continue };
            let _ = stream.set_nodelay(true);
            let _ = stream.set_write_timeout(Some(WRITE_TIMEOUT));
            let Some(counted) = controls.take() else {
                refuse(stream, &refusal);
                continue;
            };
            let Ok(writer) = stream.try_clone() else {
                continue;
            };
            if !tell(ControlEvent::Joined(client, writer)) {
                return;
            }
            let tell = tell.clone();
            std::thread::spawn(move || {
                let _counted = counted;
                let mut reader = std::io::BufReader::new(stream);
                while let Ok(Some(line)) = crate::control::read_line(&mut reader) {
                    if !tell(ControlEvent::Line(client, line)) {
                        return;
                    }
                }
            });
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Error, ErrorKind};

    /// A write to a client that closed its end is told from one that blocked: only the first
    /// keeps the client's last bytes for the bus.
    #[test]
    fn a_closed_client_is_told_from_one_that_does_not_read() {
        for kind in [
            ErrorKind::BrokenPipe,
            ErrorKind::ConnectionReset,
            ErrorKind::ConnectionAborted,
        ] {
            assert!(peer_closed(&Error::from(kind)), "{kind:?}");
        }
        for kind in [ErrorKind::WouldBlock, ErrorKind::TimedOut] {
            assert!(!peer_closed(&Error::from(kind)), "{kind:?}");
        }
    }
}
