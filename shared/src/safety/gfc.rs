//! The global fail-safe command (EN 50325-5 6.3, 7.2): one high-priority frame on CAN-ID 001h
//! that switches every safety device into its safe state at once.
//!
//! The GFC is not safety-related itself: it only shortens the reaction time, and the producer
//! must still make its SRDOs say what happened (EN 50325-5 6.3.1).

use crate::frame::{CanFrame, CanId};

/// The GFC identifier (EN 50325-5 7.2.1; CiA 304 8.3.3 Table 3).
pub const GFC_ID: CanId = CanId::from_masked(0x001);

/// Object 0x1300, the GFC parameter (EN 50325-5 6.4.2.1, Tables 14 and 15): UNSIGNED8,
/// read-write, also in Operational (8.2.2).
///
/// It *indicates*, as EN 50325-5 6.4.2.1 is written: the device sets it to 1 when it
/// requested a GFC (sent one, in Operational) or a GFC was indicated to it (received one, in
/// Operational); otherwise it is 0. An SDO write of 0 clears the indication; a write of 1 is
/// accepted and has no effect at all (nothing is sent, the indication is not set); a value
/// above 1 is refused with 0609 0031h.
///
/// How this differs from other stacks: some CANopen Safety stacks and their EDS files read
/// 0x1300 as "GFC enabled" (1 = the device may send or obey a GFC) and send a GFC when it is
/// written. A configuration tool that follows that reading and writes 1 to "enable" GFC gets
/// no GFC and no change from this device; it never trips the safety nodes on the bus. This
/// device always obeys a received GFC in Operational, and sends one only on
/// `Node::request_gfc` or, when configured, on a fault it detects (both in Operational
/// only). A generated EDS should carry this paragraph in the entry's comment.
pub const GFC_PARAMETER: u16 = 0x1300;

/// 0x1300 value: no GFC requested or indicated (EN 50325-5 6.4.2.1).
pub const GFC_NOT_VALID: u8 = 0;
/// 0x1300 value: a GFC was requested by this device or indicated to it.
pub const GFC_VALID: u8 = 1;

/// The GFC frame: CAN-ID 001h, no data.
pub const fn frame() -> CanFrame {
    CanFrame::with_len(GFC_ID, [0; 8], 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn en50325_5_7_2_1_gfc_is_one_empty_frame_on_id_1() {
        let gfc = frame();
        assert_eq!(gfc.id().raw(), 0x001);
        assert_eq!(gfc.dlc(), 0);
        assert!(!gfc.is_remote());
    }
}
