//! EMCY producer (EN 50325-4, CiA 301 7.2.7): error codes, the error register (0x1001), and the
//! emergency frame.

use super::node_id::NodeId;
use crate::frame::{CanFrame, CanId};

/// Emergency error codes this device sends (CiA 301 Table 21).
pub mod code {
    /// Error reset or no error.
    pub const NO_ERROR: u16 = 0x0000;
    /// Internal software: the two halves handed in for an SRDO were not inverses.
    pub const INTERNAL_SOFTWARE: u16 = 0x6100;
    /// Data set: the safety configuration was refused (manufacturer bytes name SRDO and
    /// cause).
    pub const DATA_SET: u16 = 0x6300;
    /// Communication: protocol error (an SRDO frame out of order or not inverted).
    pub const PROTOCOL_ERROR: u16 = 0x8200;
    /// PDO (here: SRDO) not processed due to length error (EN 50325-5 7.1.3).
    pub const PDO_LENGTH: u16 = 0x8210;
    /// RPDO (here: SRDO) timeout: SCT or SRVT elapsed.
    pub const RPDO_TIMEOUT: u16 = 0x8250;
    /// Device-specific: safe state entered on a global fail-safe command.
    pub const GLOBAL_FAIL_SAFE: u16 = 0xFF01;
    /// Manufacturer-specific: the application put the device in its safe state (in a
    /// dual-channel device, a cross-check between the channels failed).
    pub const APPLICATION_FAULT: u16 = 0xFF02;
}

/// Bits of the error register, object 0x1001 (CiA 301 7.5.2.2).
pub mod register {
    /// Generic error (set whenever any other bit is).
    pub const GENERIC: u8 = 0x01;
    /// Communication error.
    pub const COMMUNICATION: u8 = 0x10;
    /// Device profile specific (here: the safety configuration).
    pub const PROFILE: u8 = 0x20;
    /// Manufacturer specific.
    pub const MANUFACTURER: u8 = 0x80;
}

/// One emergency message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Emergency {
    /// Error code (see [`code`]).
    pub code: u16,
    /// The error register at the time of the error.
    pub register: u8,
    /// Five manufacturer-specific bytes; this device puts the SRDO number (SimpleCAN: the
    /// packet's identifier) first and the cause number second.
    pub detail: [u8; 5],
}

impl Emergency {
    /// The EMCY frame of `node_id`: CAN-ID 080h + node-ID, 8 bytes.
    pub const fn frame(&self, node_id: NodeId) -> CanFrame {
        let [low, high] = self.code.to_le_bytes();
        let d = self.detail;
        CanFrame::with_len(
            CanId::from_masked(0x080 + node_id.raw() as u16),
            [low, high, self.register, d[0], d[1], d[2], d[3], d[4]],
            8,
        )
    }

    /// Parses an EMCY frame's data (for tools and tests).
    pub fn parse(data: &[u8]) -> Option<Emergency> {
        let [low, high, register, a, b, c, d, e] = *data else {
            return None;
        };
        Some(Emergency {
            code: u16::from_le_bytes([low, high]),
            register,
            detail: [a, b, c, d, e],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cia301_7_2_7_3_emcy_frame_layout_round_trips() {
        let emergency = Emergency {
            code: code::PDO_LENGTH,
            register: 0x11,
            detail: [1, 6, 0, 0, 0],
        };
        let frame = emergency.frame(NodeId::new(33).unwrap());
        assert_eq!(frame.id().raw(), 0x0A1);
        assert_eq!(frame.data(), &[0x10, 0x82, 0x11, 1, 6, 0, 0, 0]);
        assert_eq!(Emergency::parse(frame.data()), Some(emergency));
        assert_eq!(Emergency::parse(&[0; 7]), None);
    }
}
