//! NMT slave (EN 50325-4, CiA 301 7.3.2): the device's communication state and the commands
//! that change it.

use super::node_id::NodeId;
use crate::frame::{CanFrame, CanId};

/// The NMT command identifier.
pub const NMT_ID: CanId = CanId::from_masked(0x000);

/// The NMT state of a device (CiA 301 7.3.2.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NmtState {
    /// Initialising: after power-on or a reset, until the boot-up message is sent.
    Initialising,
    /// Pre-operational: SDO, EMCY and NMT work; SRDOs do not (EN 50325-5 8.2.2).
    PreOperational,
    /// Operational: everything works, SRDOs included; safety objects are read-only.
    Operational,
    /// Stopped: only NMT (and heartbeat) work.
    Stopped,
}

impl NmtState {
    /// The state byte sent in heartbeat messages (CiA 301 7.2.8.3.2.2).
    pub const fn heartbeat_code(self) -> u8 {
        match self {
            NmtState::Initialising => 0x00,
            NmtState::Stopped => 0x04,
            NmtState::Operational => 0x05,
            NmtState::PreOperational => 0x7F,
        }
    }

    /// The state a heartbeat state byte names (CiA 301 7.2.8.3.2.2), `None` for any other
    /// byte. The toggle bit (bit 7) is not part of the state: a caller masks it.
    pub const fn from_heartbeat_code(code: u8) -> Option<NmtState> {
        match code {
            0x00 => Some(NmtState::Initialising),
            0x04 => Some(NmtState::Stopped),
            0x05 => Some(NmtState::Operational),
            0x7F => Some(NmtState::PreOperational),
            _ => None,
        }
    }

    /// The state in words, as CiA 301 names it.
    pub const fn describe(self) -> &'static str {
        match self {
            NmtState::Initialising => "Initialising",
            NmtState::PreOperational => "Pre-operational",
            NmtState::Operational => "Operational",
            NmtState::Stopped => "Stopped",
        }
    }
}

impl core::fmt::Display for NmtState {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.describe())
    }
}

/// An NMT command (CiA 301 7.2.8.3.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NmtCommand {
    /// 01h: start remote node (to Operational).
    Start,
    /// 02h: stop remote node (to Stopped).
    Stop,
    /// 80h: enter pre-operational.
    EnterPreOperational,
    /// 81h: reset node (application and communication parameters to their power-on values).
    ResetNode,
    /// 82h: reset communication (communication parameters to their power-on values).
    ResetCommunication,
}

/// Why an NMT frame was not obeyed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NmtError {
    /// An NMT frame must carry exactly two data bytes (or was a remote frame).
    Malformed,
    /// The command specifier is not one CiA 301 defines.
    UnknownCommand(u8),
}

/// Parses an NMT frame (CAN-ID 000h) for the device `node_id`. `Ok(None)` when the command is
/// addressed to another node; node-ID 0 addresses all nodes.
pub fn parse(frame: &CanFrame, node_id: NodeId) -> Result<Option<NmtCommand>, NmtError> {
    let [specifier, target] = frame.data() else {
        return Err(NmtError::Malformed);
    };
    if frame.is_remote() {
        return Err(NmtError::Malformed);
    }
    let command = match specifier {
        0x01 => NmtCommand::Start,
        0x02 => NmtCommand::Stop,
        0x80 => NmtCommand::EnterPreOperational,
        0x81 => NmtCommand::ResetNode,
        0x82 => NmtCommand::ResetCommunication,
        other => return Err(NmtError::UnknownCommand(*other)),
    };
    if *target == 0 || *target == node_id.raw() {
        Ok(Some(command))
    } else {
        Ok(None)
    }
}

/// The frame an NMT master sends to give `command` to `target` (0 for all nodes); for tools
/// and tests.
pub fn command_frame(command: NmtCommand, target: u8) -> CanFrame {
    let specifier = match command {
        NmtCommand::Start => 0x01,
        NmtCommand::Stop => 0x02,
        NmtCommand::EnterPreOperational => 0x80,
        NmtCommand::ResetNode => 0x81,
        NmtCommand::ResetCommunication => 0x82,
    };
    CanFrame::with_len(NMT_ID, [specifier, target, 0, 0, 0, 0, 0, 0], 2)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(raw: u8) -> NodeId {
        NodeId::new(raw).unwrap()
    }

    #[test]
    fn cia301_7_2_8_3_1_addressed_and_broadcast_commands() {
        for command in [
            NmtCommand::Start,
            NmtCommand::Stop,
            NmtCommand::EnterPreOperational,
            NmtCommand::ResetNode,
            NmtCommand::ResetCommunication,
        ] {
            assert_eq!(
                parse(&command_frame(command, 5), node(5)),
                Ok(Some(command))
            );
            assert_eq!(
                parse(&command_frame(command, 0), node(5)),
                Ok(Some(command))
            );
            assert_eq!(parse(&command_frame(command, 6), node(5)), Ok(None));
        }
    }

    #[test]
    fn cia301_7_2_8_3_1_malformed_and_unknown_commands_are_refused() {
        let short = CanFrame::new(NMT_ID, &[0x01]).unwrap();
        let long = CanFrame::new(NMT_ID, &[0x01, 0, 0]).unwrap();
        let remote = CanFrame::remote(NMT_ID, 2).unwrap();
        assert_eq!(parse(&short, node(1)), Err(NmtError::Malformed));
        assert_eq!(parse(&long, node(1)), Err(NmtError::Malformed));
        assert_eq!(parse(&remote, node(1)), Err(NmtError::Malformed));
        let unknown = CanFrame::new(NMT_ID, &[0x03, 1]).unwrap();
        assert_eq!(parse(&unknown, node(1)), Err(NmtError::UnknownCommand(3)));
    }

    #[test]
    fn cia301_7_2_8_3_2_2_heartbeat_state_codes() {
        assert_eq!(NmtState::Initialising.heartbeat_code(), 0x00);
        assert_eq!(NmtState::Stopped.heartbeat_code(), 0x04);
        assert_eq!(NmtState::Operational.heartbeat_code(), 0x05);
        assert_eq!(NmtState::PreOperational.heartbeat_code(), 0x7F);
    }

    #[test]
    fn cia301_7_2_8_3_2_2_a_heartbeat_state_byte_decodes_to_its_state_and_no_other_does() {
        let states = [
            NmtState::Initialising,
            NmtState::PreOperational,
            NmtState::Operational,
            NmtState::Stopped,
        ];
        for state in states {
            assert_eq!(
                NmtState::from_heartbeat_code(state.heartbeat_code()),
                Some(state)
            );
        }
        let codes = states.map(NmtState::heartbeat_code);
        for byte in (0..=u8::MAX).filter(|byte| !codes.contains(byte)) {
            assert_eq!(NmtState::from_heartbeat_code(byte), None, "{byte:#04x}");
        }
        assert_eq!(NmtState::PreOperational.describe(), "Pre-operational");
    }
}
