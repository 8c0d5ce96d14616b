//! SDO client transfers (CiA 301 7.2.4), for tools, tests and the demo.
//!
//! The client is written against one function, `exchange`, that sends a request and returns
//! the server's answer (or `None` when none came in time). That keeps it free of I/O: the
//! configuration tool passes a function that talks to the bus, tests pass one that calls a
//! [`crate::node::Node`] directly. Values of up to four bytes go expedited, longer ones
//! segmented.

use super::od::{AbortCode, Address};
use super::sdo::MAX_OBJECT_LEN;
use heapless::Vec;

/// Why a client transfer failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ClientError {
    /// The server aborted the transfer with this abort code.
    Aborted(AbortCode),
    /// The server aborted the transfer with an abort code this crate does not know.
    UnknownAbort(u32),
    /// No answer came.
    NoResponse,
    /// The answer does not fit the request (wrong specifier, object or toggle).
    Protocol,
    /// The value is longer than [`MAX_OBJECT_LEN`].
    TooLong,
}

/// The variant's doc comment, with the abort code (and its meaning, CiA 301 7.2.4.3.17) or
/// the length where it names one.
impl core::fmt::Display for ClientError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let abort = |f: &mut core::fmt::Formatter<'_>, code: u32| {
            write!(f, "{:04X} {:04X}h", code >> 16, code & 0xFFFF)
        };
        match self {
            ClientError::Aborted(code) => {
                f.write_str("the server aborted the transfer with abort code ")?;
                abort(f, code.code())?;
                write!(f, " ({})", code.meaning().trim_end_matches('.'))
            }
            ClientError::UnknownAbort(code) => {
                f.write_str(
                    "the server aborted the transfer with an abort code this crate does not know, ",
                )?;
                abort(f, *code)
            }
            ClientError::NoResponse => f.write_str("no answer came"),
            ClientError::Protocol => f.write_str(
                "the answer does not fit the request (wrong specifier, object or toggle)",
            ),
            ClientError::TooLong => {
                write!(f, "the value is longer than {MAX_OBJECT_LEN} bytes")
            }
        }
    }
}

/// The abort code carried by `response`, if it is an abort frame.
fn aborted(response: &[u8; 8]) -> Option<ClientError> {
    (response[0] == 0x80).then(|| {
        let code = u32::from_le_bytes([response[4], response[5], response[6], response[7]]);
        AbortCode::from_code(code).map_or(ClientError::UnknownAbort(code), ClientError::Aborted)
    })
}

/// Sends `request`, returns the answer unless it is missing or an abort.
fn ask(
    exchange: &mut impl FnMut([u8; 8]) -> Option<[u8; 8]>,
    request: [u8; 8],
) -> Result<[u8; 8], ClientError> {
    let response = exchange(request).ok_or(ClientError::NoResponse)?;
    match aborted(&response) {
        Some(error) => Err(error),
        None => Ok(response),
    }
}

fn multiplexer(address: Address) -> [u8; 3] {
    let [lo, hi] = address.index.to_le_bytes();
    [lo, hi, address.sub]
}

/// Writes `data` to `address` (SDO download).
pub fn download(
    mut exchange: impl FnMut([u8; 8]) -> Option<[u8; 8]>,
    address: Address,
    data: &[u8],
) -> Result<(), ClientError> {
    if data.len() > MAX_OBJECT_LEN {
        return Err(ClientError::TooLong);
    }
    let [lo, hi, sub] = multiplexer(address);
    let expect_initiate = |response: [u8; 8]| {
        if response[0] == 0x60 && response[1..4] == [lo, hi, sub] {
            Ok(())
        } else {
            Err(ClientError::Protocol)
        }
    };
    if (1..=4).contains(&data.len()) {
        let mut request = [0u8; 8];
        // e = 1, s = 1, n = 4 - len; len is 1..=4.
        request[0] = 0x23 | ((4 - data.len()) as u8) << 2;
        request[1..4].copy_from_slice(&[lo, hi, sub]);
        request[4..4 + data.len()].copy_from_slice(data);
        return expect_initiate(ask(&mut exchange, request)?);
    }
    // len <= MAX_OBJECT_LEN.
    let size = (data.len() as u32).to_le_bytes();
    let initiate = [0x21, lo, hi, sub, size[0], size[1], size[2], size[3]];
    expect_initiate(ask(&mut exchange, initiate)?)?;
    let mut toggle = 0u8;
    let mut chunks = data.chunks(7).peekable();
    // A zero-length value still needs one (empty, last) segment.
    let empty: &[u8] = &[];
    let mut single = core::iter::once(empty);
    loop {
        let (chunk, last) = if data.is_empty() {
            match single.next() {
                Some(chunk) => (chunk, true),
                None => return Ok(()),
            }
        } else {
            match chunks.next() {
                Some(chunk) => (chunk, chunks.peek().is_none()),
                None => return Ok(()),
            }
        };
        let mut request = [0u8; 8];
        request[0] = toggle | ((7 - chunk.len()) as u8) << 1 | u8::from(last);
        request[1..1 + chunk.len()].copy_from_slice(chunk);
        let response = ask(&mut exchange, request)?;
        if response[0] != 0x20 | toggle {
            return Err(ClientError::Protocol);
        }
        toggle ^= 0x10;
    }
}

/// Reads the value of `address` (SDO upload).
pub fn upload(
    mut exchange: impl FnMut([u8; 8]) -> Option<[u8; 8]>,
    address: Address,
) -> Result<Vec<u8, MAX_OBJECT_LEN>, ClientError> {
    let [lo, hi, sub] = multiplexer(address);
    let response = ask(&mut exchange, [0x40, lo, hi, sub, 0, 0, 0, 0])?;
    if response[0] & 0xE0 != 0x40 || response[1..4] != [lo, hi, sub] {
        return Err(ClientError::Protocol);
    }
    let mut value = Vec::new();
    if response[0] & 0x02 != 0 {
        let len = if response[0] & 0x01 != 0 {
            4 - usize::from((response[0] >> 2) & 0x03)
        } else {
            4
        };
        value
            .extend_from_slice(&response[4..4 + len])
            .map_err(|_| ClientError::TooLong)?;
        return Ok(value);
    }
    let mut toggle = 0u8;
    loop {
        let segment = ask(&mut exchange, [0x60 | toggle, 0, 0, 0, 0, 0, 0, 0])?;
        if segment[0] & 0xF0 != toggle {
            return Err(ClientError::Protocol);
        }
        let len = 7 - usize::from((segment[0] >> 1) & 0x07);
        value
            .extend_from_slice(&segment[1..1 + len])
            .map_err(|_| ClientError::TooLong)?;
        if segment[0] & 0x01 != 0 {
            return Ok(value);
        }
        toggle ^= 0x10;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::canopen::od::ObjectDictionary;

    #[test]
    fn a_client_error_reads_as_a_sentence_with_the_abort_code_and_its_meaning() {
        use std::string::ToString;
        assert_eq!(
            ClientError::Aborted(AbortCode::ToggleBit).to_string(),
            "the server aborted the transfer with abort code 0503 0000h (Toggle bit not alternated)"
        );
        assert_eq!(
            ClientError::UnknownAbort(0x1234_5678).to_string(),
            "the server aborted the transfer with an abort code this crate does not know, 1234 5678h"
        );
        assert_eq!(ClientError::NoResponse.to_string(), "no answer came");
        assert_eq!(
            ClientError::TooLong.to_string(),
            std::format!("the value is longer than {MAX_OBJECT_LEN} bytes")
        );
    }
    use crate::canopen::sdo::SdoServer;
    use crate::time::{Duration, Instant};
    use proptest::prelude::*;

    /// One object of any length up to 64 bytes at 0x2000:0.
    struct Store(std::vec::Vec<u8>);

    impl ObjectDictionary for Store {
        fn read(&mut self, address: Address, buf: &mut [u8]) -> Result<usize, AbortCode> {
            if address != Address::new(0x2000, 0) {
                return Err(AbortCode::NoObject);
            }
            buf[..self.0.len()].copy_from_slice(&self.0);
            Ok(self.0.len())
        }
        fn write(&mut self, address: Address, data: &[u8]) -> Result<(), AbortCode> {
            self.read(address, &mut [0; 64])?;
            self.0 = data.to_vec();
            Ok(())
        }
    }

    proptest! {
        /// Client and server agree on every length, expedited and segmented.
        #[test]
        fn client_and_server_round_trip(value in proptest::collection::vec(any::<u8>(), 0..=64)) {
            let mut server = SdoServer::new(Duration::from_millis(100));
            let mut od = Store(std::vec::Vec::new());
            let address = Address::new(0x2000, 0);
            download(|r| server.handle(Instant::ZERO, &r, &mut od), address, &value).unwrap();
            prop_assert_eq!(&od.0, &value);
            let back = upload(|r| server.handle(Instant::ZERO, &r, &mut od), address).unwrap();
            prop_assert_eq!(back.as_slice(), value.as_slice());
        }
    }

    #[test]
    fn aborts_and_silence_are_reported() {
        let mut server = SdoServer::new(Duration::from_millis(100));
        let mut od = Store(std::vec::Vec::new());
        assert_eq!(
            upload(
                |r| server.handle(Instant::ZERO, &r, &mut od),
                Address::new(0x3000, 0)
            ),
            Err(ClientError::Aborted(AbortCode::NoObject))
        );
        assert_eq!(
            download(|_| None, Address::new(0x2000, 0), &[1]),
            Err(ClientError::NoResponse)
        );
        assert_eq!(
            download(|_| None, Address::new(0x2000, 0), &[0; 65]),
            Err(ClientError::TooLong)
        );
    }
}
