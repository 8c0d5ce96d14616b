//! Bus traces other tools read: the candump log format (`can-utils`' `candump -l`, replayable
//! with `canplayer`) and pcap with the SocketCAN link type (Wireshark and tshark decode CANopen
//! from it).

use shared::{CanFrame, Instant};
use std::io::{self, Write};

/// The pcap link type for SocketCAN frames (LINKTYPE_CAN_SOCKETCAN).
pub const LINKTYPE_CAN_SOCKETCAN: u32 = 227;
/// SocketCAN's flag for a remote frame in the identifier word.
const CAN_RTR_FLAG: u32 = 0x4000_0000;

/// One line of a candump log: `(seconds.micros) interface ID#DATA` (`ID#R` for a remote frame),
/// as the tool's monitor writes and replays it (one format, one writer).
pub fn candump_line(at_unix_micros: u64, interface: &str, frame: &CanFrame) -> String {
    safety_config::monitor::candump::line(
        std::time::Duration::from_micros(at_unix_micros),
        interface,
        frame,
    )
}

/// Writes a pcap file of SocketCAN frames.
pub struct PcapWriter<W: Write> {
    out: W,
}

impl<W: Write> PcapWriter<W> {
    /// Writes the pcap global header (version 2.4, microsecond timestamps).
    pub fn new(mut out: W) -> io::Result<Self> {
        out.write_all(&0xA1B2_C3D4u32.to_le_bytes())?;
        out.write_all(&2u16.to_le_bytes())?;
        out.write_all(&4u16.to_le_bytes())?;
        out.write_all(&0i32.to_le_bytes())?; // timezone
        out.write_all(&0u32.to_le_bytes())?; // accuracy
        out.write_all(&65_535u32.to_le_bytes())?; // snapshot length
        out.write_all(&LINKTYPE_CAN_SOCKETCAN.to_le_bytes())?;
        Ok(PcapWriter { out })
    }

    /// Writes one frame: the pcap record header, then `struct can_frame` with the identifier
    /// word in network byte order, as LINKTYPE_CAN_SOCKETCAN specifies.
    pub fn write(&mut self, at_unix_micros: u64, frame: &CanFrame) -> io::Result<()> {
        let seconds = u32::try_from(at_unix_micros / 1_000_000).unwrap_or(u32::MAX);
        let micros = (at_unix_micros % 1_000_000) as u32;
        self.out.write_all(&seconds.to_le_bytes())?;
        self.out.write_all(&micros.to_le_bytes())?;
        self.out.write_all(&16u32.to_le_bytes())?;
        self.out.write_all(&16u32.to_le_bytes())?;
        let mut id = u32::from(frame.id().raw());
        if frame.is_remote() {
            id |= CAN_RTR_FLAG;
        }
        self.out.write_all(&id.to_be_bytes())?;
        self.out.write_all(&[frame.dlc(), 0, 0, 0])?;
        let mut data = [0u8; 8];
        if !frame.is_remote() {
            data[..frame.data().len()].copy_from_slice(frame.data());
        }
        self.out.write_all(&data)
    }

    /// Flushes the output.
    pub fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }
}

/// Microseconds since the Unix epoch of simulated instant `at`, for a run that started at
/// `start_unix_micros`.
pub fn unix_micros(start_unix_micros: u64, at: Instant) -> u64 {
    start_unix_micros + at.as_micros()
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::CanId;

    fn frame(id: u16, data: &[u8]) -> CanFrame {
        CanFrame::new(CanId::new(id).unwrap(), data).unwrap()
    }

    #[test]
    fn candump_lines_are_in_can_utils_format() {
        assert_eq!(
            candump_line(1_700_000_000_123_456, "can0", &frame(0x101, &[0x01, 0xAB])),
            "(1700000000.123456) can0 101#01AB"
        );
        let remote = CanFrame::remote(CanId::new(0x701).unwrap(), 1).unwrap();
        assert_eq!(candump_line(5, "vcan0", &remote), "(0.000005) vcan0 701#R");
    }

    #[test]
    fn pcap_records_follow_the_socketcan_link_type() {
        let mut pcap = PcapWriter::new(Vec::new()).unwrap();
        pcap.write(1_000_002, &frame(0x142, &[0xFE])).unwrap();
        let bytes = pcap.out;
        assert_eq!(bytes.len(), 24 + 16 + 16);
        assert_eq!(&bytes[20..24], &227u32.to_le_bytes());
        let record = &bytes[24..];
        assert_eq!(&record[0..4], &1u32.to_le_bytes());
        assert_eq!(&record[4..8], &2u32.to_le_bytes());
        assert_eq!(
            &record[16..20],
            &[0x00, 0x00, 0x01, 0x42],
            "identifier, big-endian"
        );
        assert_eq!(record[20], 1, "length");
        assert_eq!(record[24], 0xFE);
    }
}
