//! SDO server: expedited and segmented download and upload (CiA 301 7.2.4).
//!
//! The server is a small state machine between 8-byte request frames and an
//! [`ObjectDictionary`]. It owns no objects and knows no access rules; those are the
//! dictionary's. What it guarantees:
//!
//! - A download reaches the dictionary only when it is complete: segmented data is collected
//!   in the server's buffer and written in one call after the last segment. An aborted, timed
//!   out or malformed transfer writes nothing.
//! - An upload reads the object once, at the initiate request, so the client receives one
//!   consistent value even when the object changes during the transfer.
//! - Every request gets exactly one answer: the response, or an abort frame with the specific
//!   abort code (CiA 301 7.2.4.3.17). The only exception is the client's own abort request,
//!   which is not answered (CiA 301 7.2.4.3.16).
//! - A segmented transfer that stalls for longer than the timeout is aborted with
//!   0x0504_0000 at [`SdoServer::poll`]; [`SdoServer::deadline`] says when that falls due.
//!
//! Block transfer is not supported and aborts with 0x0504_0001. Objects are at most
//! [`MAX_OBJECT_LEN`] bytes.

use super::od::{AbortCode, Address, ObjectDictionary};
use crate::time::{Duration, Instant};

/// The largest object value the server transfers, in bytes (the device name is the longest).
pub const MAX_OBJECT_LEN: usize = 64;

/// Client command specifiers (bits 7..5 of byte 0), CiA 301 7.2.4.3.
mod ccs {
    pub const DOWNLOAD_SEGMENT: u8 = 0;
    pub const INITIATE_DOWNLOAD: u8 = 1;
    pub const INITIATE_UPLOAD: u8 = 2;
    pub const UPLOAD_SEGMENT: u8 = 3;
    pub const ABORT: u8 = 4;
}

/// Server command specifiers, already shifted into bits 7..5.
mod scs {
    pub const UPLOAD_SEGMENT: u8 = 0 << 5;
    pub const DOWNLOAD_SEGMENT: u8 = 1 << 5;
    pub const INITIATE_UPLOAD: u8 = 2 << 5;
    pub const INITIATE_DOWNLOAD: u8 = 3 << 5;
    pub const ABORT: u8 = 4 << 5;
}

/// The toggle bit of segment requests and responses.
const TOGGLE: u8 = 0x10;
/// Data bytes per segment.
const SEGMENT_DATA: usize = 7;

/// A segmented transfer in progress.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Transfer {
    /// No transfer; segment requests are out of place.
    Idle,
    /// Collecting segments for `address`; `len` bytes so far.
    Download {
        address: Address,
        toggle: u8,
        /// The size the client indicated, if it did.
        indicated: Option<usize>,
        len: usize,
    },
    /// Sending the `len` bytes read at the initiate request; `sent` so far.
    Upload {
        address: Address,
        toggle: u8,
        len: usize,
        sent: usize,
    },
}

/// The SDO server of one node (CiA 301 7.2.4).
#[derive(Clone, Debug)]
pub struct SdoServer {
    timeout: Duration,
    transfer: Transfer,
    /// When the transfer in progress times out.
    deadline: Instant,
    buffer: [u8; MAX_OBJECT_LEN],
}

/// An abort frame for `address` with `code` (CiA 301 7.2.4.3.17).
pub fn abort_frame(address: Address, code: AbortCode) -> [u8; 8] {
    frame(scs::ABORT, address, code.code().to_le_bytes())
}

/// A frame with command byte `command`, multiplexer `address` and four data bytes.
fn frame(command: u8, address: Address, data: [u8; 4]) -> [u8; 8] {
    let [index_lo, index_hi] = address.index.to_le_bytes();
    let [d0, d1, d2, d3] = data;
    [command, index_lo, index_hi, address.sub, d0, d1, d2, d3]
}

impl SdoServer {
    /// A server that aborts segmented transfers stalled for longer than `timeout`.
    pub const fn new(timeout: Duration) -> Self {
        SdoServer {
            timeout,
            transfer: Transfer::Idle,
            deadline: Instant::ZERO,
            buffer: [0; MAX_OBJECT_LEN],
        }
    }

    /// Handles one request (the data field of a frame to the server's COB-ID) and returns the
    /// response to send, if any.
    pub fn handle(
        &mut self,
        now: Instant,
        request: &[u8],
        dictionary: &mut impl ObjectDictionary,
    ) -> Option<[u8; 8]> {
        // CiA 301 7.2.4.3: SDO frames always carry 8 bytes.
        let Ok(request) = <&[u8; 8]>::try_from(request) else {
            let address = self.address();
            self.transfer = Transfer::Idle;
            return Some(abort_frame(address, AbortCode::InvalidCommand));
        };
        let address = Address::new(u16::from_le_bytes([request[1], request[2]]), request[3]);
        let result = match request[0] >> 5 {
            ccs::INITIATE_DOWNLOAD => self.initiate_download(now, address, request, dictionary),
            ccs::DOWNLOAD_SEGMENT => self.download_segment(now, request, dictionary),
            ccs::INITIATE_UPLOAD => self.initiate_upload(now, address, dictionary),
            ccs::UPLOAD_SEGMENT => self.upload_segment(now, request),
            ccs::ABORT => {
                self.transfer = Transfer::Idle;
                return None;
            }
            // Block upload (5) and block download (6) are not supported; 7 is undefined.
            _ => Err((address, AbortCode::InvalidCommand)),
        };
        Some(result.unwrap_or_else(|(address, code)| {
            self.transfer = Transfer::Idle;
            abort_frame(address, code)
        }))
    }

    /// Aborts a segmented transfer that has timed out (CiA 301 0504 0000h).
    pub fn poll(&mut self, now: Instant) -> Option<[u8; 8]> {
        if self.transfer == Transfer::Idle || now < self.deadline {
            return None;
        }
        let address = self.address();
        self.transfer = Transfer::Idle;
        Some(abort_frame(address, AbortCode::Timeout))
    }

    /// When [`SdoServer::poll`] next has something to do.
    pub fn deadline(&self) -> Option<Instant> {
        (self.transfer != Transfer::Idle).then_some(self.deadline)
    }

    /// Forgets any transfer in progress, silently (NMT reset communication).
    pub fn reset(&mut self) {
        self.transfer = Transfer::Idle;
    }

    /// `true` while a segmented transfer is in progress.
    pub fn busy(&self) -> bool {
        self.transfer != Transfer::Idle
    }

    /// The object of the transfer in progress (zero when none).
    fn address(&self) -> Address {
        match self.transfer {
            Transfer::Download { address, .. } | Transfer::Upload { address, .. } => address,
            Transfer::Idle => Address::new(0, 0),
        }
    }

    fn initiate_download(
        &mut self,
        now: Instant,
        address: Address,
        request: &[u8; 8],
        dictionary: &mut impl ObjectDictionary,
    ) -> Result<[u8; 8], (Address, AbortCode)> {
        // An initiate request always starts afresh; a transfer in progress is dropped
        // (nothing of it was written).
        self.transfer = Transfer::Idle;
        let command = request[0];
        let expedited = command & 0x02 != 0;
        let size_indicated = command & 0x01 != 0;
        let fail = |code| (address, code);
        if expedited {
            let len = if size_indicated {
                4 - usize::from((command >> 2) & 0x03)
            } else {
                // CiA 301: size not indicated, the object's own length applies.
                let mut current = [0u8; MAX_OBJECT_LEN];
                dictionary.read(address, &mut current).map_err(fail)?.min(4)
            };
            dictionary
                .write(address, &request[4..4 + len])
                .map_err(fail)?;
            return Ok(frame(scs::INITIATE_DOWNLOAD, address, [0; 4]));
        }
        if command & 0x0C != 0 {
            // n is only meaningful in expedited transfers.
            return Err(fail(AbortCode::InvalidCommand));
        }
        let indicated = if size_indicated {
            let size = u32::from_le_bytes([request[4], request[5], request[6], request[7]]);
            let size = usize::try_from(size).unwrap_or(usize::MAX);
            if size > MAX_OBJECT_LEN {
                return Err(fail(AbortCode::OutOfMemory));
            }
            Some(size)
        } else {
            None
        };
        // Refuse at once what cannot exist, before the client sends every segment.
        let mut current = [0u8; MAX_OBJECT_LEN];
        if let Err(code @ (AbortCode::NoObject | AbortCode::NoSubIndex)) =
            dictionary.read(address, &mut current)
        {
            return Err(fail(code));
        }
        self.transfer = Transfer::Download {
            address,
            toggle: 0,
            indicated,
            len: 0,
        };
        self.deadline = now + self.timeout;
        Ok(frame(scs::INITIATE_DOWNLOAD, address, [0; 4]))
    }

    fn download_segment(
        &mut self,
        now: Instant,
        request: &[u8; 8],
        dictionary: &mut impl ObjectDictionary,
    ) -> Result<[u8; 8], (Address, AbortCode)> {
        let Transfer::Download {
            address,
            toggle,
            indicated,
            len,
        } = self.transfer
        else {
            return Err((self.address(), AbortCode::InvalidCommand));
        };
        let fail = |code| (address, code);
        let command = request[0];
        if command & TOGGLE != toggle {
            return Err(fail(AbortCode::ToggleBit));
        }
        let unused = usize::from((command >> 1) & 0x07);
        let last = command & 0x01 != 0;
        let data = &request[1..1 + SEGMENT_DATA - unused];
        let total = len + data.len();
        if indicated.is_some_and(|size| total > size) {
            return Err(fail(AbortCode::LengthTooHigh));
        }
        let target = self
            .buffer
            .get_mut(len..total)
            .ok_or(fail(AbortCode::OutOfMemory))?;
        target.copy_from_slice(data);
        let response = frame(scs::DOWNLOAD_SEGMENT | toggle, Address::new(0, 0), [0; 4]);
        if !last {
            self.transfer = Transfer::Download {
                address,
                toggle: toggle ^ TOGGLE,
                indicated,
                len: total,
            };
            self.deadline = now + self.timeout;
            return Ok(response);
        }
        if indicated.is_some_and(|size| total < size) {
            return Err(fail(AbortCode::LengthTooLow));
        }
        self.transfer = Transfer::Idle;
        dictionary
            .write(address, &self.buffer[..total])
            .map_err(fail)?;
        Ok(response)
    }

    fn initiate_upload(
        &mut self,
        now: Instant,
        address: Address,
        dictionary: &mut impl ObjectDictionary,
    ) -> Result<[u8; 8], (Address, AbortCode)> {
        self.transfer = Transfer::Idle;
        let len = dictionary
            .read(address, &mut self.buffer)
            .map_err(|code| (address, code))?;
        if (1..=4).contains(&len) {
            let mut data = [0u8; 4];
            data[..len].copy_from_slice(&self.buffer[..len]);
            // e = 1, s = 1, n = 4 - len (CiA 301 7.2.4.3.6). `len` is 1..=4.
            let unused = (4 - len) as u8;
            return Ok(frame(
                scs::INITIATE_UPLOAD | unused << 2 | 0x03,
                address,
                data,
            ));
        }
        self.transfer = Transfer::Upload {
            address,
            toggle: 0,
            len,
            sent: 0,
        };
        self.deadline = now + self.timeout;
        // `len` <= MAX_OBJECT_LEN, so it fits.
        let size = len as u32;
        Ok(frame(
            scs::INITIATE_UPLOAD | 0x01,
            address,
            size.to_le_bytes(),
        ))
    }

    fn upload_segment(
        &mut self,
        now: Instant,
        request: &[u8; 8],
    ) -> Result<[u8; 8], (Address, AbortCode)> {
        let Transfer::Upload {
            address,
            toggle,
            len,
            sent,
        } = self.transfer
        else {
            return Err((self.address(), AbortCode::InvalidCommand));
        };
        if request[0] & TOGGLE != toggle {
            return Err((address, AbortCode::ToggleBit));
        }
        let chunk = (len - sent).min(SEGMENT_DATA);
        let last = sent + chunk == len;
        let mut response = [0u8; 8];
        // n = 7 - chunk, chunk is 0..=7.
        let unused = (SEGMENT_DATA - chunk) as u8;
        response[0] = scs::UPLOAD_SEGMENT | toggle | unused << 1 | u8::from(last);
        response[1..1 + chunk].copy_from_slice(&self.buffer[sent..sent + chunk]);
        self.transfer = if last {
            Transfer::Idle
        } else {
            self.deadline = now + self.timeout;
            Transfer::Upload {
                address,
                toggle: toggle ^ TOGGLE,
                len,
                sent: sent + chunk,
            }
        };
        Ok(response)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::vec::Vec;

    /// A dictionary with a u8 at 0x2000:0, a u32 at 0x2001:0, a 20-byte string at 0x2002:0
    /// (any length up to 20 accepted), a read-only u16 at 0x2003:0; it records every write.
    #[derive(Default)]
    struct Dictionary {
        byte: u8,
        word: u32,
        text: Vec<u8>,
        writes: Vec<(Address, Vec<u8>)>,
    }

    impl ObjectDictionary for Dictionary {
        fn read(&mut self, address: Address, buf: &mut [u8]) -> Result<usize, AbortCode> {
            let value: Vec<u8> = match (address.index, address.sub) {
                (0x2000, 0) => vec![self.byte],
                (0x2001, 0) => self.word.to_le_bytes().to_vec(),
                (0x2002, 0) => self.text.clone(),
                (0x2003, 0) => vec![0x34, 0x12],
                (0x2000..=0x2003, _) => return Err(AbortCode::NoSubIndex),
                _ => return Err(AbortCode::NoObject),
            };
            let target = buf.get_mut(..value.len()).ok_or(AbortCode::OutOfMemory)?;
            target.copy_from_slice(&value);
            Ok(value.len())
        }

        fn write(&mut self, address: Address, data: &[u8]) -> Result<(), AbortCode> {
            let mut scratch = [0u8; MAX_OBJECT_LEN];
            self.read(address, &mut scratch)?;
            let length = |expected: usize| match data.len() {
                l if l > expected => Err(AbortCode::LengthTooHigh),
                l if l < expected => Err(AbortCode::LengthTooLow),
                _ => Ok(()),
            };
            match address.index {
                0x2000 => {
                    length(1)?;
                    self.byte = data[0];
                }
                0x2001 => {
                    length(4)?;
                    self.word = u32::from_le_bytes(data.try_into().unwrap());
                }
                0x2002 if data.len() > 20 => return Err(AbortCode::LengthTooHigh),
                0x2002 => self.text = data.to_vec(),
                _ => return Err(AbortCode::ReadOnly),
            }
            self.writes.push((address, data.to_vec()));
            Ok(())
        }
    }

    const T0: Instant = Instant::ZERO;
    const TIMEOUT: Duration = Duration::from_millis(100);

    fn abort(index: u16, sub: u8, code: AbortCode) -> [u8; 8] {
        abort_frame(Address::new(index, sub), code)
    }

    fn server() -> (SdoServer, Dictionary) {
        (SdoServer::new(TIMEOUT), Dictionary::default())
    }

    /// CiA 301 7.2.4.3.3: expedited download with size indicated, answered with scs = 3.
    #[test]
    fn cia301_7_2_4_3_3_expedited_download_writes_and_confirms() {
        let (mut sdo, mut od) = server();
        let reply = sdo.handle(T0, &[0x23, 0x01, 0x20, 0, 1, 2, 3, 4], &mut od);
        assert_eq!(reply, Some([0x60, 0x01, 0x20, 0, 0, 0, 0, 0]));
        assert_eq!(od.word, 0x0403_0201);
        let reply = sdo.handle(T0, &[0x2F, 0x00, 0x20, 0, 9, 0, 0, 0], &mut od);
        assert_eq!(reply, Some([0x60, 0x00, 0x20, 0, 0, 0, 0, 0]));
        assert_eq!(od.byte, 9);
    }

    /// CiA 301 7.2.4.3.3: e = 1, s = 0 (size not indicated) takes the object's own length.
    #[test]
    fn cia301_7_2_4_3_3_expedited_download_without_size_uses_the_object_length() {
        let (mut sdo, mut od) = server();
        let reply = sdo.handle(T0, &[0x22, 0x00, 0x20, 0, 7, 0xEE, 0xEE, 0xEE], &mut od);
        assert_eq!(reply, Some([0x60, 0x00, 0x20, 0, 0, 0, 0, 0]));
        assert_eq!(od.writes, vec![(Address::new(0x2000, 0), vec![7])]);
    }

    /// The dictionary's abort codes reach the client with the object's multiplexer.
    #[test]
    fn dictionary_refusals_become_abort_frames() {
        let (mut sdo, mut od) = server();
        let cases = [
            (
                [0x2F, 0x00, 0x30, 0, 1, 0, 0, 0],
                abort(0x3000, 0, AbortCode::NoObject),
            ),
            (
                [0x2F, 0x00, 0x20, 5, 1, 0, 0, 0],
                abort(0x2000, 5, AbortCode::NoSubIndex),
            ),
            (
                [0x2B, 0x00, 0x20, 0, 1, 0, 0, 0],
                abort(0x2000, 0, AbortCode::LengthTooHigh),
            ),
            (
                [0x2F, 0x01, 0x20, 0, 1, 0, 0, 0],
                abort(0x2001, 0, AbortCode::LengthTooLow),
            ),
            (
                [0x2B, 0x03, 0x20, 0, 1, 0, 0, 0],
                abort(0x2003, 0, AbortCode::ReadOnly),
            ),
            (
                [0x40, 0x00, 0x30, 0, 0, 0, 0, 0],
                abort(0x3000, 0, AbortCode::NoObject),
            ),
        ];
        for (request, expected) in cases {
            assert_eq!(
                sdo.handle(T0, &request, &mut od),
                Some(expected),
                "{request:02X?}"
            );
        }
        assert!(od.writes.is_empty());
    }

    /// CiA 301 7.2.4.3.6: values of 1..4 bytes are uploaded expedited with n = 4 - size.
    #[test]
    fn cia301_7_2_4_3_6_expedited_upload_reports_the_size() {
        let (mut sdo, mut od) = server();
        od.word = 0xAABB_CCDD;
        assert_eq!(
            sdo.handle(T0, &[0x40, 0x01, 0x20, 0, 0, 0, 0, 0], &mut od),
            Some([0x43, 0x01, 0x20, 0, 0xDD, 0xCC, 0xBB, 0xAA])
        );
        assert_eq!(
            sdo.handle(T0, &[0x40, 0x03, 0x20, 0, 0, 0, 0, 0], &mut od),
            Some([0x4B, 0x03, 0x20, 0, 0x34, 0x12, 0, 0])
        );
        assert_eq!(
            sdo.handle(T0, &[0x40, 0x00, 0x20, 0, 0, 0, 0, 0], &mut od),
            Some([0x4F, 0x00, 0x20, 0, 0, 0, 0, 0])
        );
        assert!(!sdo.busy());
    }

    /// CiA 301 7.2.4.3.4..5: segmented download, toggle alternating from 0, written once
    /// after the last segment.
    #[test]
    fn cia301_7_2_4_3_4_segmented_download_writes_once_at_the_end() {
        let (mut sdo, mut od) = server();
        let text = b"light curtain 4";
        assert_eq!(
            sdo.handle(T0, &[0x21, 0x02, 0x20, 0, 15, 0, 0, 0], &mut od),
            Some([0x60, 0x02, 0x20, 0, 0, 0, 0, 0])
        );
        let mut first = [0x00u8; 8];
        first[1..].copy_from_slice(&text[..7]);
        assert_eq!(
            sdo.handle(T0, &first, &mut od),
            Some([0x20, 0, 0, 0, 0, 0, 0, 0])
        );
        let mut second = [0x10u8; 8];
        second[1..].copy_from_slice(&text[7..14]);
        assert_eq!(
            sdo.handle(T0, &second, &mut od),
            Some([0x30, 0, 0, 0, 0, 0, 0, 0])
        );
        assert!(
            od.writes.is_empty(),
            "nothing is written before the last segment"
        );
        // Last segment: one byte, n = 6, c = 1, toggle 0.
        let last = [0x0D, text[14], 0, 0, 0, 0, 0, 0];
        assert_eq!(
            sdo.handle(T0, &last, &mut od),
            Some([0x20, 0, 0, 0, 0, 0, 0, 0])
        );
        assert_eq!(od.writes, vec![(Address::new(0x2002, 0), text.to_vec())]);
        assert!(!sdo.busy());
    }

    /// CiA 301 7.2.4.3.7..8: segmented upload of a value read once at the initiate request.
    #[test]
    fn cia301_7_2_4_3_7_segmented_upload_sends_a_snapshot() {
        let (mut sdo, mut od) = server();
        od.text = b"safety node A".to_vec();
        assert_eq!(
            sdo.handle(T0, &[0x40, 0x02, 0x20, 0, 0, 0, 0, 0], &mut od),
            Some([0x41, 0x02, 0x20, 0, 13, 0, 0, 0])
        );
        od.text = b"changed meanwhile".to_vec();
        let first = sdo
            .handle(T0, &[0x60, 0, 0, 0, 0, 0, 0, 0], &mut od)
            .unwrap();
        assert_eq!(first[0], 0x00);
        assert_eq!(&first[1..], b"safety ");
        let second = sdo
            .handle(T0, &[0x70, 0, 0, 0, 0, 0, 0, 0], &mut od)
            .unwrap();
        // toggle 1, n = 1, c = 1.
        assert_eq!(second[0], 0x10 | 1 << 1 | 1);
        assert_eq!(&second[1..7], b"node A");
        assert!(!sdo.busy());
    }

    /// A zero-length value is uploaded segmented with size 0 (expedited needs 1..4 bytes).
    #[test]
    fn an_empty_value_uploads_as_one_empty_segment() {
        let (mut sdo, mut od) = server();
        assert_eq!(
            sdo.handle(T0, &[0x40, 0x02, 0x20, 0, 0, 0, 0, 0], &mut od),
            Some([0x41, 0x02, 0x20, 0, 0, 0, 0, 0])
        );
        assert_eq!(
            sdo.handle(T0, &[0x60, 0, 0, 0, 0, 0, 0, 0], &mut od),
            Some([0x0F, 0, 0, 0, 0, 0, 0, 0])
        );
    }

    /// CiA 301 0503 0000h: a repeated toggle aborts and writes nothing.
    #[test]
    fn cia301_7_2_4_3_17_a_toggle_error_aborts_without_writing() {
        let (mut sdo, mut od) = server();
        sdo.handle(T0, &[0x21, 0x02, 0x20, 0, 14, 0, 0, 0], &mut od);
        sdo.handle(T0, &[0x00, 1, 2, 3, 4, 5, 6, 7], &mut od);
        assert_eq!(
            sdo.handle(T0, &[0x00, 1, 2, 3, 4, 5, 6, 7], &mut od),
            Some(abort(0x2002, 0, AbortCode::ToggleBit))
        );
        assert!(!sdo.busy());
        assert!(od.writes.is_empty());
        // Upload: the first segment request must carry toggle 0.
        sdo.handle(T0, &[0x40, 0x02, 0x20, 0, 0, 0, 0, 0], &mut od);
        assert_eq!(
            sdo.handle(T0, &[0x70, 0, 0, 0, 0, 0, 0, 0], &mut od),
            Some(abort(0x2002, 0, AbortCode::ToggleBit))
        );
    }

    /// CiA 301 0504 0000h: a stalled transfer is aborted at its deadline, not before, and the
    /// partial data is dropped.
    #[test]
    fn cia301_7_2_4_3_17_a_stalled_transfer_times_out_at_its_deadline() {
        let (mut sdo, mut od) = server();
        assert_eq!(sdo.deadline(), None);
        sdo.handle(T0, &[0x21, 0x02, 0x20, 0, 14, 0, 0, 0], &mut od);
        let t1 = T0 + Duration::from_millis(60);
        sdo.handle(t1, &[0x00, 1, 2, 3, 4, 5, 6, 7], &mut od);
        assert_eq!(sdo.deadline(), Some(t1 + TIMEOUT));
        assert_eq!(
            sdo.poll(t1 + Duration::from_micros(TIMEOUT.as_micros() - 1)),
            None
        );
        assert_eq!(
            sdo.poll(t1 + TIMEOUT),
            Some(abort(0x2002, 0, AbortCode::Timeout))
        );
        assert_eq!(sdo.deadline(), None);
        assert_eq!(sdo.poll(t1 + TIMEOUT + TIMEOUT), None);
        // The late segment is out of place now.
        assert_eq!(
            sdo.handle(t1 + TIMEOUT, &[0x11, 8, 9, 10, 11, 12, 13, 14], &mut od),
            Some(abort(0, 0, AbortCode::InvalidCommand))
        );
        assert!(od.writes.is_empty());
    }

    /// CiA 301 0607 0012h / 0607 0013h: more or less data than the client announced.
    #[test]
    fn cia301_7_2_4_3_17_segments_must_add_up_to_the_indicated_size() {
        let (mut sdo, mut od) = server();
        sdo.handle(T0, &[0x21, 0x02, 0x20, 0, 5, 0, 0, 0], &mut od);
        assert_eq!(
            sdo.handle(T0, &[0x01, 1, 2, 3, 4, 5, 6, 7], &mut od),
            Some(abort(0x2002, 0, AbortCode::LengthTooHigh))
        );
        sdo.handle(T0, &[0x21, 0x02, 0x20, 0, 9, 0, 0, 0], &mut od);
        assert_eq!(
            sdo.handle(T0, &[0x01, 1, 2, 3, 4, 5, 6, 7], &mut od),
            Some(abort(0x2002, 0, AbortCode::LengthTooLow))
        );
        assert!(od.writes.is_empty());
    }

    /// CiA 301 0504 0005h: more than the server can hold, announced or not.
    #[test]
    fn cia301_7_2_4_3_17_oversized_downloads_run_out_of_memory_without_writing() {
        let (mut sdo, mut od) = server();
        assert_eq!(
            sdo.handle(T0, &[0x21, 0x02, 0x20, 0, 65, 0, 0, 0], &mut od),
            Some(abort(0x2002, 0, AbortCode::OutOfMemory))
        );
        sdo.handle(T0, &[0x20, 0x02, 0x20, 0, 0, 0, 0, 0], &mut od);
        let mut toggle = 0;
        let mut last = None;
        for _ in 0..10 {
            last = sdo.handle(T0, &[toggle, 1, 2, 3, 4, 5, 6, 7], &mut od);
            toggle ^= TOGGLE;
        }
        assert_eq!(last, Some(abort(0x2002, 0, AbortCode::OutOfMemory)));
        assert!(od.writes.is_empty());
    }

    /// CiA 301 0504 0001h: unknown and unsupported command specifiers, segments out of place,
    /// short frames.
    #[test]
    fn cia301_7_2_4_3_17_invalid_commands_abort() {
        let (mut sdo, mut od) = server();
        for command in [0xA0u8, 0xC0, 0xE0] {
            assert_eq!(
                sdo.handle(T0, &[command, 0x00, 0x20, 0, 0, 0, 0, 0], &mut od),
                Some(abort(0x2000, 0, AbortCode::InvalidCommand)),
                "{command:02X}"
            );
        }
        assert_eq!(
            sdo.handle(T0, &[0x00, 1, 2, 3, 4, 5, 6, 7], &mut od),
            Some(abort(0, 0, AbortCode::InvalidCommand))
        );
        assert_eq!(
            sdo.handle(T0, &[0x60, 0, 0, 0, 0, 0, 0, 0], &mut od),
            Some(abort(0, 0, AbortCode::InvalidCommand))
        );
        assert_eq!(
            sdo.handle(T0, &[0x2F, 0x00, 0x20], &mut od),
            Some(abort(0, 0, AbortCode::InvalidCommand))
        );
        assert_eq!(
            sdo.handle(T0, &[], &mut od),
            Some(abort(0, 0, AbortCode::InvalidCommand))
        );
        // A segmented initiate with n set is malformed.
        assert_eq!(
            sdo.handle(T0, &[0x25, 0x02, 0x20, 0, 4, 0, 0, 0], &mut od),
            Some(abort(0x2002, 0, AbortCode::InvalidCommand))
        );
        // A download segment during an upload ends the upload.
        od.text = b"0123456789".to_vec();
        sdo.handle(T0, &[0x40, 0x02, 0x20, 0, 0, 0, 0, 0], &mut od);
        assert_eq!(
            sdo.handle(T0, &[0x00, 1, 2, 3, 4, 5, 6, 7], &mut od),
            Some(abort(0x2002, 0, AbortCode::InvalidCommand))
        );
        assert!(!sdo.busy());
        assert!(od.writes.is_empty());
    }

    /// CiA 301 7.2.4.3.16: the client's abort ends the transfer and is not answered.
    #[test]
    fn cia301_7_2_4_3_16_a_client_abort_ends_the_transfer_silently() {
        let (mut sdo, mut od) = server();
        sdo.handle(T0, &[0x21, 0x02, 0x20, 0, 14, 0, 0, 0], &mut od);
        sdo.handle(T0, &[0x00, 1, 2, 3, 4, 5, 6, 7], &mut od);
        let client_abort = abort(0x2002, 0, AbortCode::General);
        assert_eq!(sdo.handle(T0, &client_abort, &mut od), None);
        assert!(!sdo.busy());
        assert!(od.writes.is_empty());
    }

    /// A new initiate request replaces a transfer in progress; the old data is never written.
    #[test]
    fn a_new_initiate_restarts_cleanly() {
        let (mut sdo, mut od) = server();
        sdo.handle(T0, &[0x21, 0x02, 0x20, 0, 14, 0, 0, 0], &mut od);
        sdo.handle(T0, &[0x00, 1, 2, 3, 4, 5, 6, 7], &mut od);
        sdo.handle(T0, &[0x2F, 0x00, 0x20, 0, 5, 0, 0, 0], &mut od);
        assert!(!sdo.busy());
        assert_eq!(od.writes, vec![(Address::new(0x2000, 0), vec![5])]);
    }

    /// A segmented download to an object that does not exist is refused at the initiate.
    #[test]
    fn a_segmented_download_to_a_missing_object_is_refused_early() {
        let (mut sdo, mut od) = server();
        assert_eq!(
            sdo.handle(T0, &[0x21, 0x00, 0x30, 0, 10, 0, 0, 0], &mut od),
            Some(abort(0x3000, 0, AbortCode::NoObject))
        );
        assert!(!sdo.busy());
    }

    proptest! {
        /// Any sequence of requests of any length at any time: every request except a client
        /// abort is answered, and the dictionary only ever sees writes of data that arrived
        /// complete (the write log holds only values the client sent, whole).
        #[test]
        fn any_request_sequence_is_answered_without_panic(
            steps in proptest::collection::vec(
                (0u64..300, proptest::collection::vec(any::<u8>(), 0..10)), 0..60)
        ) {
            let (mut sdo, mut od) = server();
            let mut now = T0;
            for (step_ms, request) in steps {
                now = now + Duration::from_millis(step_ms);
                if let Some(timeout) = sdo.poll(now) {
                    prop_assert_eq!(timeout[0], 0x80);
                }
                let reply = sdo.handle(now, &request, &mut od);
                let client_abort = request.len() == 8 && request[0] >> 5 == ccs::ABORT;
                prop_assert_eq!(reply.is_none(), client_abort);
                if let Some(deadline) = sdo.deadline() {
                    prop_assert!(deadline > now);
                }
            }
            for (address, data) in &od.writes {
                prop_assert!(data.len() <= 20);
                prop_assert!((0x2000..=0x2002).contains(&address.index));
            }
        }

        /// A segmented download of any value of 0..=20 bytes arrives exactly.
        #[test]
        fn segmented_download_round_trips(value in proptest::collection::vec(any::<u8>(), 0..=20)) {
            let (mut sdo, mut od) = server();
            let size = value.len() as u8;
            prop_assert_eq!(
                sdo.handle(T0, &[0x21, 0x02, 0x20, 0, size, 0, 0, 0], &mut od),
                Some([0x60, 0x02, 0x20, 0, 0, 0, 0, 0])
            );
            let mut toggle = 0u8;
            let mut chunks: Vec<&[u8]> = value.chunks(7).collect();
            if chunks.is_empty() {
                chunks.push(&[]);
            }
            let count = chunks.len();
            for (i, chunk) in chunks.into_iter().enumerate() {
                let mut request = [0u8; 8];
                let last = u8::from(i + 1 == count);
                request[0] = toggle | ((7 - chunk.len()) as u8) << 1 | last;
                request[1..1 + chunk.len()].copy_from_slice(chunk);
                prop_assert_eq!(
                    sdo.handle(T0, &request, &mut od),
                    Some([0x20 | toggle, 0, 0, 0, 0, 0, 0, 0])
                );
                toggle ^= TOGGLE;
            }
            prop_assert_eq!(&od.text, &value);
            prop_assert_eq!(od.writes.len(), 1);
        }
    }
}
