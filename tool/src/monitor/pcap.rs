//! pcap files of CAN frames with the SocketCAN link type (LINKTYPE_CAN_SOCKETCAN), which
//! Wireshark and tshark read: the monitor records into one when `--record` names a `.pcap`,
//! and `safety-config dissector` decodes the safety frames in it.

use shared::CanFrame;
use std::io::{self, Write};
use std::time::Duration;

/// The pcap link type for SocketCAN frames (LINKTYPE_CAN_SOCKETCAN).
pub const LINKTYPE_CAN_SOCKETCAN: u32 = 227;
/// SocketCAN's flag for a remote frame in the identifier word.
const CAN_RTR_FLAG: u32 = 0x4000_0000;
/// The octets of one record: `struct can_frame`.
const RECORD_LENGTH: u32 = 16;

/// Writes a pcap file of SocketCAN frames (version 2.4, microsecond timestamps).
pub struct PcapWriter<W: Write> {
    out: W,
}

impl<W: Write> PcapWriter<W> {
    /// Writes the pcap global header.
    pub fn new(mut out: W) -> io::Result<Self> {
        out.write_all(&0xA1B2_C3D4u32.to_le_bytes())?;
        out.write_all(&2u16.to_le_bytes())?;
        out.write_all(&4u16.to_le_bytes())?;
        // Time zone and accuracy: none.
        out.write_all(&0i32.to_le_bytes())?;
        out.write_all(&0u32.to_le_bytes())?;
        // The snapshot length: every record is whole.
        out.write_all(&65_535u32.to_le_bytes())?;
        out.write_all(&LINKTYPE_CAN_SOCKETCAN.to_le_bytes())?;
        Ok(PcapWriter { out })
    }

    /// Writes one frame at `at` (time since the Unix epoch): the record header, then
    /// `struct can_frame` with the identifier word in network byte order, as
    /// LINKTYPE_CAN_SOCKETCAN specifies. A time past the year 2106 is written as the last
    /// second pcap can hold.
    pub fn write(&mut self, at: Duration, frame: &CanFrame) -> io::Result<()> {
        let seconds = u32::try_from(at.as_secs()).unwrap_or(u32::MAX);
        self.out.write_all(&seconds.to_le_bytes())?;
        self.out.write_all(&at.subsec_micros().to_le_bytes())?;
        self.out.write_all(&RECORD_LENGTH.to_le_bytes())?;
        self.out.write_all(&RECORD_LENGTH.to_le_bytes())?;
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

    /// The output, flushed.
    pub fn into_inner(mut self) -> io::Result<W> {
        self.out.flush()?;
        Ok(self.out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::CanId;

    #[test]
    fn pcap_records_follow_the_socketcan_link_type() {
        let mut pcap = PcapWriter::new(Vec::new()).unwrap();
        let frame = CanFrame::new(CanId::new(0x142).unwrap(), &[0xFE]).unwrap();
        pcap.write(Duration::from_micros(1_000_002), &frame)
            .unwrap();
        let remote = CanFrame::remote(CanId::new(0x701).unwrap(), 1).unwrap();
        pcap.write(Duration::from_secs(2), &remote).unwrap();
        let bytes = pcap.into_inner().unwrap();
        assert_eq!(bytes.len(), 24 + 2 * (16 + 16));
        assert_eq!(&bytes[0..4], &0xA1B2_C3D4u32.to_le_bytes());
        assert_eq!(&bytes[20..24], &227u32.to_le_bytes());
        let record = &bytes[24..56];
        assert_eq!(&record[0..4], &1u32.to_le_bytes(), "seconds");
        assert_eq!(&record[4..8], &2u32.to_le_bytes(), "microseconds");
        assert_eq!(&record[8..16], &[16, 0, 0, 0, 16, 0, 0, 0], "lengths");
        assert_eq!(&record[16..20], &[0x00, 0x00, 0x01, 0x42], "big-endian");
        assert_eq!(record[20], 1, "data length");
        assert_eq!(&record[24..32], &[0xFE, 0, 0, 0, 0, 0, 0, 0]);
        let record = &bytes[56..];
        assert_eq!(&record[16..20], &[0x40, 0x00, 0x07, 0x01], "remote flag");
        assert_eq!(record[20], 1, "requested length");
        assert_eq!(&record[24..32], &[0; 8], "a remote frame has no data");
    }
}
