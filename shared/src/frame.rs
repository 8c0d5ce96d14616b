//! Classic CAN 2.0A frames as the protocol core sees them: an 11-bit identifier, data or
//! remote, and up to eight data bytes.
//!
//! Every frame is built through a checked constructor, so a [`CanFrame`] value always holds a
//! valid identifier and a data length code of at most 8. Board layers convert their driver's
//! frame type into this one at the edge.

/// An 11-bit CAN identifier (ISO 11898-1 base format), `0x000..=0x7FF`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CanId(u16);

/// Why a frame could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// The identifier does not fit in 11 bits.
    IdentifierOutOfRange,
    /// More than 8 data bytes, or a data length code above 8.
    TooLong,
}

impl CanId {
    /// The identifier `raw`, if it fits in 11 bits.
    pub const fn new(raw: u16) -> Result<Self, FrameError> {
        if raw <= 0x7FF {
            Ok(CanId(raw))
        } else {
            Err(FrameError::IdentifierOutOfRange)
        }
    }

    /// The identifier `raw` masked to 11 bits, for constants and computed identifiers whose
    /// range is already proven (such as `0x580 + node-ID`).
    pub(crate) const fn from_masked(raw: u16) -> Self {
        CanId(raw & 0x7FF)
    }

    /// The raw identifier.
    #[inline]
    pub const fn raw(self) -> u16 {
        self.0
    }
}

/// A classic CAN data or remote frame with a base (11-bit) identifier.
///
/// Aligned to four bytes (its size, twelve, is the same either way): frames are copied at
/// every step between the controller and the core, and on the Cortex-M4 images a copy of a
/// two-byte-aligned value went through the byte-wise general copy routine, one word-aligned
/// goes word by word.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(align(4))]
pub struct CanFrame {
    id: CanId,
    remote: bool,
    dlc: u8,
    data: [u8; 8],
}

impl CanFrame {
    /// A data frame carrying `data` (at most 8 bytes).
    pub fn new(id: CanId, data: &[u8]) -> Result<Self, FrameError> {
        if data.len() > 8 {
            return Err(FrameError::TooLong);
        }
        let mut bytes = [0u8; 8];
        bytes[..data.len()].copy_from_slice(data);
        // `data.len() <= 8` was checked above, so the cast is exact.
        Ok(CanFrame {
            id,
            remote: false,
            dlc: data.len() as u8,
            data: bytes,
        })
    }

    /// A data frame from a full 8-byte buffer of which the first `dlc` bytes count.
    /// Bytes beyond `dlc` are cleared, so equal frames compare equal.
    pub fn from_parts(id: CanId, dlc: u8, data: [u8; 8]) -> Result<Self, FrameError> {
        if dlc > 8 {
            return Err(FrameError::TooLong);
        }
        let mut bytes = data;
        bytes[usize::from(dlc)..].fill(0);
        Ok(CanFrame {
            id,
            remote: false,
            dlc,
            data: bytes,
        })
    }

    /// A data frame of `len` bytes of `data`, `len` clamped to 8: for frames the crate builds
    /// itself, whose length is known to be valid, without a `Result` to unwrap.
    #[inline]
    pub(crate) const fn with_len(id: CanId, data: [u8; 8], len: u8) -> Self {
        let dlc = if len > 8 { 8 } else { len };
        let mut bytes = data;
        let mut i = dlc as usize;
        while i < 8 {
            bytes[i] = 0;
            i += 1;
        }
        CanFrame {
            id,
            remote: false,
            dlc,
            data: bytes,
        }
    }

    /// A data frame of `len` bytes (clamped to 8) of the little-endian `payload`, whose bytes
    /// beyond `len` are sent as 0: a payload the crate built as a word (an SRDO's), one mask
    /// instead of a loop over the bytes past `len`.
    #[inline]
    pub(crate) const fn from_payload(id: CanId, payload: u64, len: u8) -> Self {
        let dlc = if len > 8 { 8 } else { len };
        CanFrame {
            id,
            remote: false,
            dlc,
            data: (payload & crate::process_image::byte_mask(dlc)).to_le_bytes(),
        }
    }

    /// A remote frame (RTR) requesting `dlc` bytes.
    pub fn remote(id: CanId, dlc: u8) -> Result<Self, FrameError> {
        if dlc > 8 {
            return Err(FrameError::TooLong);
        }
        Ok(CanFrame {
            id,
            remote: true,
            dlc,
            data: [0; 8],
        })
    }

    /// The identifier.
    #[inline]
    pub const fn id(&self) -> CanId {
        self.id
    }

    /// `true` for a remote frame (RTR set).
    #[inline]
    pub const fn is_remote(&self) -> bool {
        self.remote
    }

    /// The data length code, `0..=8`.
    #[inline]
    pub const fn dlc(&self) -> u8 {
        self.dlc
    }

    /// The data bytes (empty for a remote frame).
    #[inline]
    pub fn data(&self) -> &[u8] {
        if self.remote {
            &[]
        } else {
            &self.data[..usize::from(self.dlc)]
        }
    }

    /// All eight data bytes; bytes beyond the data length code are zero.
    #[inline]
    pub const fn raw_data(&self) -> &[u8; 8] {
        &self.data
    }

    /// A received standard frame as a CAN controller reports it (identifier, remote flag,
    /// length code, the eight data registers), or `None` when it is not CANopen's: a length code
    /// over 8 (ISO 11898-1 allows 9 to 15 for 8 bytes; CANopen frames never carry them) is
    /// dropped like an extended frame, and the consumers' timers catch a frame lost so.
    pub fn received(id: u16, remote: bool, dlc: u8, data: &[u8; 8]) -> Option<CanFrame> {
        let id = CanId::new(id).ok()?;
        if remote {
            CanFrame::remote(id, dlc).ok()
        } else {
            CanFrame::new(id, data.get(..usize::from(dlc))?).ok()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identifiers_above_eleven_bits_are_rejected() {
        assert!(CanId::new(0x7FF).is_ok());
        assert_eq!(CanId::new(0x800), Err(FrameError::IdentifierOutOfRange));
    }

    #[test]
    fn frames_longer_than_eight_bytes_are_rejected() {
        let id = CanId::new(0x101).unwrap();
        assert_eq!(CanFrame::new(id, &[0; 9]), Err(FrameError::TooLong));
        assert_eq!(CanFrame::remote(id, 9), Err(FrameError::TooLong));
        assert_eq!(
            CanFrame::from_parts(id, 9, [0; 8]),
            Err(FrameError::TooLong)
        );
    }

    #[test]
    fn bytes_beyond_the_length_are_cleared() {
        let id = CanId::new(0x101).unwrap();
        let frame = CanFrame::from_parts(id, 2, [1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
        assert_eq!(frame.data(), &[1, 2]);
        assert_eq!(frame, CanFrame::new(id, &[1, 2]).unwrap());
    }

    /// CiA 301 7.2.2 / ISO 11898-1: every length code a controller can report, for data and
    /// remote frames; none panics, and only 0 to 8 make a frame.
    #[test]
    fn every_received_length_code_is_handled() {
        let data = [1, 2, 3, 4, 5, 6, 7, 8];
        for dlc in 0..=15u8 {
            let frame = CanFrame::received(0x181, false, dlc, &data);
            let remote = CanFrame::received(0x181, true, dlc, &data);
            if dlc <= 8 {
                assert_eq!(frame.unwrap().data(), &data[..usize::from(dlc)]);
                assert!(remote.is_some_and(|r| r.is_remote() && r.dlc() == dlc));
            } else {
                assert!(frame.is_none() && remote.is_none(), "length {dlc}");
            }
        }
        assert!(CanFrame::received(0x800, false, 1, &data).is_none());
    }

    #[test]
    fn a_remote_frame_has_no_data() {
        let frame = CanFrame::remote(CanId::new(0x101).unwrap(), 8).unwrap();
        assert!(frame.is_remote());
        assert_eq!(frame.dlc(), 8);
        assert!(frame.data().is_empty());
    }
}
