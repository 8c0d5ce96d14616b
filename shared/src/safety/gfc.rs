//! The global fail-safe command (EN 50325-5 6.3, 7.2): one high-priority frame on CAN-ID 001h
//! that switches every safety device into its safe state at once.
//!
//! The GFC is not safety-related itself: it only shortens the reaction time, and the producer
//! must still make its SRDOs say what happened (EN 50325-5 6.3.1).

use crate::frame::{CanFrame, CanId};

/// The GFC identifier (EN 50325-5 7.2.1; CiA 304 8.3.3 Table 3).
pub const GFC_ID: CanId = CanId::from_masked(0x001);

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
