//! The node-ID on the device's seven switches: what two readings at start-up mean. The
//! board layer only reads the switches' pins; both channels read them.

use shared::canopen::NodeId;

/// Why the node-ID switches were not accepted: the node stays in the safe state, silent on
/// the bus, and says why in its log.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SwitchFault {
    /// Two readings 1 ms apart differ (a switch between positions, or a broken contact).
    Unsettled {
        /// The first reading.
        first: u8,
        /// The second reading.
        second: u8,
    },
    /// The reading is not a node-ID (CiA 301 7.5.2: 1 to 127) nor all switches open.
    Invalid(u8),
}

/// The node-ID on the board's seven switches (bit 0 first, closed = 1), from two readings
/// taken 1 ms apart at start-up; a change later takes effect at the next reset, as CiA 301
/// has it for node-IDs. Readings that differ, or 0, are refused. Both channels read the
/// switches; when they read different IDs, channel B does not follow the tool's requests for
/// channel A's node, keeps its unvalidated defaults and stays out of Operational, and the
/// link's NMT cross-check puts both channels in the safe state (host test
/// `channels_with_different_node_ids_never_leave_the_safe_state`).
pub fn node_id_from_switches(first: u8, second: u8) -> Result<NodeId, SwitchFault> {
    if first != second {
        return Err(SwitchFault::Unsettled { first, second });
    }
    NodeId::new(first).map_err(|_| SwitchFault::Invalid(first))
}

/// The node-ID switches as the boards use them with LSS (CiA 305): a node-ID where set
/// (the switches win over a node-ID LSS stored), `None` where all seven are open ("use
/// LSS": the node-ID LSS stored, or none, node-ID FFh, until a master gives it one).
/// Readings that differ are refused as by [`node_id_from_switches`].
pub fn node_id_or_lss(first: u8, second: u8) -> Result<Option<NodeId>, SwitchFault> {
    match node_id_from_switches(first, second) {
        Ok(id) => Ok(Some(id)),
        Err(SwitchFault::Invalid(0)) => Ok(None),
        Err(fault) => Err(fault),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cia305_all_switches_open_means_use_lss_and_set_switches_win() {
        assert_eq!(node_id_or_lss(0, 0), Ok(None));
        assert_eq!(
            node_id_or_lss(33, 33).map(|id| id.map(NodeId::raw)),
            Ok(Some(33))
        );
        assert_eq!(
            node_id_or_lss(0, 4),
            Err(SwitchFault::Unsettled {
                first: 0,
                second: 4
            })
        );
        assert_eq!(node_id_or_lss(200, 200), Err(SwitchFault::Invalid(200)));
    }

    #[test]
    fn cia301_7_5_2_node_id_from_switches() {
        assert_eq!(node_id_from_switches(33, 33).map(NodeId::raw), Ok(33));
        assert_eq!(node_id_from_switches(127, 127).map(NodeId::raw), Ok(127));
        assert_eq!(node_id_from_switches(1, 1).map(NodeId::raw), Ok(1));
        assert_eq!(node_id_from_switches(0, 0), Err(SwitchFault::Invalid(0)));
        assert_eq!(
            node_id_from_switches(128, 128),
            Err(SwitchFault::Invalid(128))
        );
        assert_eq!(
            node_id_from_switches(33, 32),
            Err(SwitchFault::Unsettled {
                first: 33,
                second: 32
            })
        );
    }
}
