//! The cause codes of a safe state, each with its name: the one byte that says why a node or
//! one of its channels went to the safe state, in EMCY (the SRDO faults' manufacturer-specific
//! byte 1, 6300h byte 1 for the integrity check, FF02h byte 1 for a channel's own faults),
//! in the inter-channel link's safe-state message and in the emulated board's status report.
//!
//! Every code and its name are here and nowhere else: the protocol core and the channel
//! runtime produce a [`Cause`], and whoever shows one (the e2e summary, the run's table, a log)
//! asks it for [`Cause::describe`] (also its `Display`). A number that is no code here (an
//! application's own detail byte) decodes to `None` by [`Cause::from_code`].

/// Why a safe state was entered, as one stable byte ([`Cause::code`]).
///
/// The numbers are fixed: a tool or a log from an older image reads them the same. 3 was
/// "inverted frame without plain frame", no longer a fault (CAN double reception); it is not
/// reused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Cause {
    /// No safe state since power-on or the last NMT reset.
    None = 0x00,
    /// SCT elapsed without a complete pair (EN 50325-5 7.1.2).
    SctElapsed = 0x01,
    /// SRVT elapsed between a plain frame and its inverted frame (EN 50325-5 7.1.2).
    SrvtElapsed = 0x02,
    /// A second plain frame with other data before the inverted frame (CiA 304 9.5).
    PlainRepeated = 0x04,
    /// The inverted frame is not the bitwise inverse of the plain frame (EN 50325-5 7.1.1).
    NotInverted = 0x05,
    /// A frame shorter than the mapping needs (EN 50325-5 7.1.3).
    TooShort = 0x06,
    /// The halves handed in for transmission are not exact inverses; nothing was sent.
    TransmitHalvesNotInverted = 0x07,
    /// A link message failed its CRC.
    LinkCorrupt = 0x10,
    /// A link message passed its CRC but is not a message of the set.
    LinkMalformed = 0x11,
    /// Link messages were missing (a gap in the sequence numbers).
    LinkMissing = 0x12,
    /// A link message was repeated (a sequence number seen again).
    LinkRepeated = 0x13,
    /// The other channel has not been heard on the link in time.
    LinkTimeout = 0x14,
    /// The link's round trip reached its bound: channel A's announcement of a plain frame
    /// could come after channel B stops waiting for it.
    LinkLatency = 0x15,
    /// The channels' verdicts on a received SRDO differ.
    VerdictsDisagree = 0x20,
    /// A verdict on a received SRDO was not matched by the other channel in time.
    VerdictUnconfirmed = 0x21,
    /// The other channel sent a verdict for an SRDO this node does not have.
    VerdictForUnknownSrdo = 0x22,
    /// More verdicts waited for the other channel's than it can be behind by.
    VerdictQueueFull = 0x23,
    /// A transmit SRDO's plain half differs between the channels (CiA 304 9.5).
    TransmitMismatch = 0x30,
    /// The channels hold different configurations in Operational.
    ConfigurationMismatch = 0x31,
    /// The channels' NMT states differed for longer than two link periods.
    NmtMismatch = 0x32,
    /// The channels' input samples differed for longer than the discrepancy time.
    InputDiscrepancy = 0x33,
    /// A frame on one of the node's transmit identifiers that the node did not send.
    ForeignFrame = 0x34,
    /// The inverted frame on the bus is not the inverse of the channel's plain frame.
    InvertedMismatch = 0x35,
    /// The core handed the channel more frames or events in one call than it holds.
    CoreOutputFull = 0x36,
    /// More safety inputs were sampled than the channel's input table holds.
    InputTableFull = 0x37,
    /// An input sample written before could not be written back after an NMT reset.
    InputRestoreFailed = 0x38,
    /// The other channel's heartbeats came faster than its period allows: one of the two
    /// clocks runs too fast or too slow.
    ClockDrift = 0x39,
    /// A received frame the channel follows found its receive queue full: the channel cannot
    /// know that it saw every safety frame.
    ReceiveOverrun = 0x3A,
    /// The channel's CAN controller went bus-off (its transmit error counter passed 255):
    /// until its automatic recovery it neither sends nor receives, so the channel cannot know
    /// that it saw every safety frame.
    BusOff = 0x3B,
    /// The channels' LSS slaves answered a request differently, or one answered a request
    /// the other did not answer within the window (CiA 305, both channels of the node).
    LssAnswerMismatch = 0x3C,
    /// The channels' node-IDs in force differ in the same NMT epoch (the switches read
    /// differently, or LSS configured one channel only).
    NodeIdMismatch = 0x3D,
    /// The channels' LSS bit rates differ in Operational (CiA 305 configure bit timing
    /// reached one channel only).
    BitRateMismatch = 0x3E,
    /// The other channel went to its safe state.
    PeerSafeState = 0x40,
    /// A GFC was received (EN 50325-5 7.2.1).
    Gfc = 0x50,
    /// SimpleCAN: at start, 5EFEh did not read A5h; the configuration was never declared
    /// valid, or changed since (SC_REQ_16, SC_REQ_34).
    SimpleCanNotValidated = 0x60,
    /// SimpleCAN: at start, the CRC-32 of the configuration differed from 5EFFh
    /// (SC_REQ_17, SC_REQ_34).
    SimpleCanSignature = 0x61,
    /// SimpleCAN: at start, the configuration broke a rule of the safety data dictionary,
    /// the cycle or a mapped object (SC_REQ_12, SC_REQ_16, SC_REQ_18, SC_REQ_21, SC_REQ_22,
    /// SC_REQ_04).
    SimpleCanConfiguration = 0x62,
    /// SimpleCAN: two masters sent syncs at once (SC_REQ_26).
    SimpleCanSeveralMasters = 0x68,
    /// SimpleCAN: packets with a bad CRC reached 1000 on the leaky counter (SC_REQ_42).
    SimpleCanBadCrc = 0x69,
    /// SimpleCAN: a consumed value grew older than its safety timeout (SC_REQ_20).
    SimpleCanTimeout = 0x6A,
    /// SimpleCAN, two channels: channel A's forwarded copy of a SimpleCAN frame differs from
    /// the frame channel B heard on the bus (SC_REQ_24).
    SimpleCanForwardDiffers = 0x70,
    /// SimpleCAN, two channels: channel B heard a SimpleCAN frame and channel A's copy did
    /// not come over the link in time (SC_REQ_24).
    SimpleCanForwardLost = 0x71,
    /// SimpleCAN, two channels: channel A forwarded a SimpleCAN frame channel B did not hear
    /// (SC_REQ_24).
    SimpleCanForwardUnheard = 0x72,
    /// SimpleCAN, two channels: more SimpleCAN frames waited for their other copy than
    /// channel B holds (SC_REQ_24).
    SimpleCanForwardOverrun = 0x73,
    /// SimpleCAN, two channels: the channels' verdicts on a consumed packet differ (SC-ID,
    /// cycle stamp, value or validity; SC_REQ_10).
    SimpleCanVerdictsDisagree = 0x74,
    /// SimpleCAN, two channels: a verdict on a consumed packet was not matched by the other
    /// channel in time (SC_REQ_10).
    SimpleCanVerdictUnconfirmed = 0x75,
    /// SimpleCAN, two channels: a verdict named an SDD entry the channel does not consume.
    SimpleCanVerdictForUnknownEntry = 0x76,
    /// SimpleCAN, two channels: more verdicts on one SDD entry waited for the other channel's
    /// than it can be behind by (SC_REQ_10).
    SimpleCanVerdictQueueFull = 0x77,
    /// SimpleCAN, two channels: the packet channel A put on the bus differs from the one
    /// channel B computed for the same slot (SC_REQ_10, Model A).
    SimpleCanTransmitMismatch = 0x78,
    /// SimpleCAN, two channels: channel B computed a packet of the node's and channel A's
    /// did not appear on the bus within its slot (a sync: within 2 ms; SC_REQ_10, Model A).
    SimpleCanTransmitMissing = 0x79,
    /// In Operational the records no longer pass the Operational-entry check.
    IntegrityRecords = 0xF2,
    /// In Operational the identifier table differs from the records.
    IntegrityIdentifierTable = 0xF3,
    /// In Operational an SRDO's resolved mapping or role, or the times or identifiers its
    /// producer or consumer runs with, differ from its record.
    IntegrityRuntime = 0xF4,
    /// In Operational the list of running SRDOs differs from the records.
    IntegrityActiveList = 0xF5,
}

impl Cause {
    /// Every cause, in the order of their codes.
    pub const ALL: [Cause; 54] = [
        Cause::None,
        Cause::SctElapsed,
        Cause::SrvtElapsed,
        Cause::PlainRepeated,
        Cause::NotInverted,
        Cause::TooShort,
        Cause::TransmitHalvesNotInverted,
        Cause::LinkCorrupt,
        Cause::LinkMalformed,
        Cause::LinkMissing,
        Cause::LinkRepeated,
        Cause::LinkTimeout,
        Cause::LinkLatency,
        Cause::VerdictsDisagree,
        Cause::VerdictUnconfirmed,
        Cause::VerdictForUnknownSrdo,
        Cause::VerdictQueueFull,
        Cause::TransmitMismatch,
        Cause::ConfigurationMismatch,
        Cause::NmtMismatch,
        Cause::InputDiscrepancy,
        Cause::ForeignFrame,
        Cause::InvertedMismatch,
        Cause::CoreOutputFull,
        Cause::InputTableFull,
        Cause::InputRestoreFailed,
        Cause::ClockDrift,
        Cause::ReceiveOverrun,
        Cause::BusOff,
        Cause::LssAnswerMismatch,
        Cause::NodeIdMismatch,
        Cause::BitRateMismatch,
        Cause::PeerSafeState,
        Cause::Gfc,
        Cause::SimpleCanNotValidated,
        Cause::SimpleCanSignature,
        Cause::SimpleCanConfiguration,
        Cause::SimpleCanSeveralMasters,
        Cause::SimpleCanBadCrc,
        Cause::SimpleCanTimeout,
        Cause::SimpleCanForwardDiffers,
        Cause::SimpleCanForwardLost,
        Cause::SimpleCanForwardUnheard,
        Cause::SimpleCanForwardOverrun,
        Cause::SimpleCanVerdictsDisagree,
        Cause::SimpleCanVerdictUnconfirmed,
        Cause::SimpleCanVerdictForUnknownEntry,
        Cause::SimpleCanVerdictQueueFull,
        Cause::SimpleCanTransmitMismatch,
        Cause::SimpleCanTransmitMissing,
        Cause::IntegrityRecords,
        Cause::IntegrityIdentifierTable,
        Cause::IntegrityRuntime,
        Cause::IntegrityActiveList,
    ];

    /// The byte sent for this cause.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// The cause a byte names, `None` for a number that is no cause code (an application's
    /// own detail byte, say).
    pub fn from_code(code: u8) -> Option<Cause> {
        Cause::ALL.into_iter().find(|cause| cause.code() == code)
    }

    /// The cause in words, for a person reading a table or a log.
    pub const fn describe(self) -> &'static str {
        match self {
            Cause::None => "-",
            Cause::SctElapsed => "SCT elapsed",
            Cause::SrvtElapsed => "SRVT elapsed",
            Cause::PlainRepeated => "plain frame repeated with other data",
            Cause::NotInverted => "not inverted",
            Cause::TooShort => "frame too short",
            Cause::TransmitHalvesNotInverted => "transmit halves not inverted",
            Cause::LinkCorrupt => "link message corrupt",
            Cause::LinkMalformed => "link message malformed",
            Cause::LinkMissing => "link messages missing",
            Cause::LinkRepeated => "link message repeated",
            Cause::LinkTimeout => "link silent",
            Cause::LinkLatency => "link too slow for co-signing",
            Cause::VerdictsDisagree => "verdicts differ",
            Cause::VerdictUnconfirmed => "verdict not confirmed in time",
            Cause::VerdictForUnknownSrdo => "verdict for an unknown SRDO",
            Cause::VerdictQueueFull => "verdict queue full",
            Cause::TransmitMismatch => "transmit mismatch A/B",
            Cause::ConfigurationMismatch => "configuration mismatch",
            Cause::NmtMismatch => "NMT mismatch",
            Cause::InputDiscrepancy => "input discrepancy",
            Cause::ForeignFrame => "frame on our identifier we did not send",
            Cause::InvertedMismatch => "inverted frame not the inverse of ours",
            Cause::CoreOutputFull => "core output beyond the channel's buffer",
            Cause::InputTableFull => "input table full",
            Cause::InputRestoreFailed => "input not restored after reset",
            Cause::ClockDrift => "clock of one channel drifts",
            Cause::ReceiveOverrun => "CAN receive queue overrun",
            Cause::BusOff => "CAN controller bus-off",
            Cause::LssAnswerMismatch => "LSS answers of the channels differ",
            Cause::NodeIdMismatch => "node-IDs of the channels differ",
            Cause::BitRateMismatch => "LSS bit rates of the channels differ",
            Cause::PeerSafeState => "other channel safe",
            Cause::Gfc => "GFC",
            Cause::SimpleCanNotValidated => "SimpleCAN configuration not declared valid",
            Cause::SimpleCanSignature => "SimpleCAN configuration signature differs",
            Cause::SimpleCanConfiguration => "SimpleCAN configuration inconsistent",
            Cause::SimpleCanSeveralMasters => "several SimpleCAN masters",
            Cause::SimpleCanBadCrc => "1000 SimpleCAN packets with a bad CRC",
            Cause::SimpleCanTimeout => "SimpleCAN value older than its safety timeout",
            Cause::SimpleCanForwardDiffers => "SimpleCAN copy from channel A differs",
            Cause::SimpleCanForwardLost => "SimpleCAN copy from channel A lost",
            Cause::SimpleCanForwardUnheard => "SimpleCAN copy from channel A not heard by B",
            Cause::SimpleCanForwardOverrun => "SimpleCAN copies waiting beyond the queue",
            Cause::SimpleCanVerdictsDisagree => "SimpleCAN verdicts differ",
            Cause::SimpleCanVerdictUnconfirmed => "SimpleCAN verdict not confirmed in time",
            Cause::SimpleCanVerdictForUnknownEntry => "SimpleCAN verdict for an unknown entry",
            Cause::SimpleCanVerdictQueueFull => "SimpleCAN verdict queue full",
            Cause::SimpleCanTransmitMismatch => "SimpleCAN packet sent differs from channel B's",
            Cause::SimpleCanTransmitMissing => "SimpleCAN packet of the node not sent",
            Cause::IntegrityRecords => "configuration in use damaged (records)",
            Cause::IntegrityIdentifierTable => "configuration in use damaged (identifier table)",
            Cause::IntegrityRuntime => "configuration in use damaged (SRDO runtime)",
            Cause::IntegrityActiveList => "configuration in use damaged (running SRDOs)",
        }
    }

    /// A code in words: its cause's [`describe`](Cause::describe), or "other" for a number
    /// that is no cause code.
    pub fn describe_code(code: u8) -> &'static str {
        Cause::from_code(code).map_or("other", Cause::describe)
    }
}

impl core::fmt::Display for Cause {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.describe())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_cause_code_decodes_to_its_cause_and_no_two_share_a_code() {
        for (index, cause) in Cause::ALL.into_iter().enumerate() {
            assert_eq!(Cause::from_code(cause.code()), Some(cause));
            for other in &Cause::ALL[index + 1..] {
                assert_ne!(cause.code(), other.code(), "{cause:?} and {other:?}");
            }
        }
        // ALL lists them in the order of their codes, so none is left out by a slip.
        assert!(
            Cause::ALL
                .windows(2)
                .all(|pair| pair[0].code() < pair[1].code())
        );
    }

    #[test]
    fn a_number_that_is_no_cause_code_is_none_and_reads_other() {
        for code in [0x03, 0x08, 0x16, 0x24, 0x3F, 0x41, 0x51, 0xF1, 0xF6, 0xFF] {
            assert_eq!(Cause::from_code(code), None, "{code:#04x}");
            assert_eq!(Cause::describe_code(code), "other");
        }
    }

    #[test]
    fn the_codes_logs_and_tools_already_read_are_unchanged() {
        let fixed = [
            (Cause::SctElapsed, 0x01),
            (Cause::SrvtElapsed, 0x02),
            (Cause::NotInverted, 0x05),
            (Cause::LinkTimeout, 0x14),
            (Cause::LinkLatency, 0x15),
            (Cause::VerdictUnconfirmed, 0x21),
            (Cause::InputDiscrepancy, 0x33),
            (Cause::ReceiveOverrun, 0x3A),
            (Cause::BusOff, 0x3B),
            (Cause::PeerSafeState, 0x40),
            (Cause::Gfc, 0x50),
            (Cause::IntegrityRecords, 0xF2),
            (Cause::IntegrityActiveList, 0xF5),
        ];
        for (cause, code) in fixed {
            assert_eq!(cause.code(), code, "{cause:?}");
        }
    }

    #[test]
    fn a_cause_displays_its_description() {
        assert_eq!(Cause::InputTableFull.to_string(), "input table full");
        assert_eq!(Cause::describe_code(0x23), "verdict queue full");
    }
}
