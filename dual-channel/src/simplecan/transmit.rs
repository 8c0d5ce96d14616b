//! Model A for SimpleCAN transmission (SC_REQ_10): channel A puts the node's packets on the
//! bus; channel B computes each of them itself, with its own core, and checks the one on the
//! bus against its own.
//!
//! Why channel A transmits: it is the channel that speaks for the node on the bus (its
//! boot-up, SDO answers, EMCY, the plain SRDO frames), and channel B's controller receives
//! what A's sends (one transceiver, Model III), so B can see every packet of the node and A
//! cannot see its own. B's core runs the same SimpleCAN layer on the same configuration and
//! the same received frames, so it hands out the same packets at the same slots; the
//! runtime keeps them here instead of sending them.
//!
//! - A data packet must come back from the bus **bit for bit** as B computed it (value,
//!   cycle stamp, CRC), within its slot (1 ms, docs/simplecan.md section 5): otherwise
//!   [`TransmitFault::Mismatch`] or, at the end of the slot, [`TransmitFault::Missing`].
//! - A sync carries the time its master read when it sent it, so the two channels' syncs
//!   agree in the master's SC-ID and the cycle number and differ in the offset by as much as
//!   their clocks do: B requires the same master and cycle, an offset within
//!   [`SYNC_OFFSET_TOLERANCE`] of its own and a CRC its own decoder accepts, within 2 ms
//!   (SC_REQ_23).
//! - A packet of the node (an SC-ID it produces, a sync naming its master SC-ID) that B did
//!   not compute is a mismatch too: A's core is not doing what B's does.
//!
//! Sans-I/O: fed frames and `now`, it returns faults and its next deadline.

use super::{Decoded, RawFrame};
use shared::time::expired;
use shared::{Duration, Instant};

/// How far apart the offsets of the two channels' syncs may be: the channels' loops handle
/// NMT start (which starts both masters' clocks) within the link latency of each other
/// (about 0.2 ms at most), far less than the 2 ms a receiver tolerates (SC_REQ_30).
pub const SYNC_OFFSET_TOLERANCE: Duration = Duration::from_micros(200);

/// How long a data packet of the node may take to appear on the bus: its slot.
pub const DATA_WITHIN: Duration = Duration::from_millis(1);

/// How long a sync of the node may take to appear on the bus (SC_REQ_23).
pub const SYNC_WITHIN: Duration = Duration::from_millis(2);

/// How many of the node's packets may wait for channel A's: a data packet per produced
/// SC-ID and a sync (each waits at most 2 ms, and no two data packets share a slot).
const WAITING: usize = super::ENTRIES + 1;

/// Why the node's packet on the bus is not the one channel B computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TransmitFault {
    /// The packet on the bus differs from B's, or B computed none.
    Mismatch {
        /// The identifier.
        id: u16,
    },
    /// B computed a packet that did not appear on the bus in time.
    Missing {
        /// The identifier.
        id: u16,
    },
}

/// Channel B's packets of the node that wait for channel A's on the bus.
#[derive(Clone, Debug, Default)]
pub struct TransmitCheck {
    waiting: heapless::Vec<(RawFrame, Instant), WAITING>,
}

impl TransmitCheck {
    /// Nothing waiting.
    pub fn new() -> Self {
        TransmitCheck::default()
    }

    /// B's core handed out `own` at `now`: channel A's must appear by its deadline. A packet
    /// still waiting on the same identifier is replaced (its deadline has passed, or the
    /// poll reports it first).
    pub fn computed(&mut self, now: Instant, own: RawFrame) -> Result<(), TransmitFault> {
        let sync = own.id == shared::simplecan::frame::SYNC_IDENTIFIER.raw();
        let deadline = now + if sync { SYNC_WITHIN } else { DATA_WITHIN };
        if let Some(slot) = self.waiting.iter_mut().find(|(kept, _)| kept.id == own.id) {
            *slot = (own, deadline);
            return Ok(());
        }
        self.waiting
            .push((own, deadline))
            .map_err(|_| TransmitFault::Mismatch { id: own.id })
    }

    /// A packet of the node was heard on the bus (`decoded` by B's own decoder): B's own
    /// packet it stands for, to confirm to B's core as sent.
    pub fn heard(&mut self, heard: RawFrame, decoded: Decoded) -> Result<RawFrame, TransmitFault> {
        let mismatch = TransmitFault::Mismatch { id: heard.id };
        let index = self
            .waiting
            .iter()
            .position(|(own, _)| own.id == heard.id)
            .ok_or(mismatch)?;
        let (own, _) = self.waiting.swap_remove(index);
        if agrees(&own, &heard, decoded) {
            Ok(own)
        } else {
            Err(mismatch)
        }
    }

    /// The fault of a packet of B's whose deadline has passed at `now`, if any.
    pub fn poll(&self, now: Instant) -> Result<(), TransmitFault> {
        match self.waiting.iter().find(|(_, at)| expired(*at, now)) {
            Some((own, _)) => Err(TransmitFault::Missing { id: own.id }),
            None => Ok(()),
        }
    }

    /// When [`poll`](Self::poll) must run next ([`Instant::NEVER`]: nothing waits).
    pub fn deadline(&self) -> Instant {
        self.waiting
            .iter()
            .map(|(_, at)| *at)
            .min()
            .unwrap_or(Instant::NEVER)
    }

    /// Forgets every waiting packet (leaving Operational, NMT reset).
    pub fn reset(&mut self) {
        self.waiting.clear();
    }
}

/// `heard` on the bus stands for B's `own` packet: a data packet bit for bit; a sync by
/// master, cycle and an offset within [`SYNC_OFFSET_TOLERANCE`], with a CRC B's decoder
/// accepted (`decoded`).
fn agrees(own: &RawFrame, heard: &RawFrame, decoded: Decoded) -> bool {
    match (Decoded::fields(own), decoded) {
        (
            Decoded::Sync {
                master,
                cycle,
                offset_micros,
            },
            Decoded::Sync {
                master: heard_master,
                cycle: heard_cycle,
                offset_micros: heard_offset,
            },
        ) => {
            master == heard_master
                && cycle == heard_cycle
                && u64::from(offset_micros.abs_diff(heard_offset))
                    <= SYNC_OFFSET_TOLERANCE.as_micros()
        }
        (Decoded::Data { .. }, _) => own == heard,
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Worked vector 1 of docs/simplecan.md section 9 (SC-ID 30h, value 1, stamp 5).
    const DATA: RawFrame = RawFrame {
        id: 0x030,
        len: 8,
        data: [0x01, 0x00, 0x00, 0x00, 0x05, 0xA4, 0x18, 0x27],
    };

    /// Worked vector 3 (master 30h, cycle 0102h, offset 250 µs).
    const SYNC: RawFrame = RawFrame {
        id: 0x02F,
        len: 8,
        data: [0x30, 0x01, 0x02, 0x00, 0xFA, 0xFD, 0x34, 0x07],
    };

    fn at(micros: u64) -> Instant {
        Instant::from_micros(micros)
    }

    #[test]
    fn sc_req_10_a_data_packet_equal_to_channel_b_s_within_its_slot_is_confirmed() {
        let mut check = TransmitCheck::new();
        check.computed(at(1_000), DATA).unwrap();
        assert_eq!(check.deadline(), at(2_000));
        assert_eq!(check.heard(DATA, Decoded::fields(&DATA)), Ok(DATA));
        assert_eq!(check.deadline(), Instant::NEVER);
        assert_eq!(check.poll(at(10_000)), Ok(()));
    }

    #[test]
    fn sc_req_10_a_data_packet_that_differs_in_any_bit_is_a_mismatch() {
        for bit in 0..64 {
            let mut heard = DATA;
            heard.data[bit / 8] ^= 1 << (bit % 8);
            let mut check = TransmitCheck::new();
            check.computed(at(0), DATA).unwrap();
            assert_eq!(
                check.heard(heard, Decoded::fields(&heard)),
                Err(TransmitFault::Mismatch { id: 0x030 }),
                "bit {bit}"
            );
        }
    }

    #[test]
    fn sc_req_10_a_packet_of_the_node_channel_b_did_not_compute_is_a_mismatch() {
        let mut check = TransmitCheck::new();
        assert_eq!(
            check.heard(DATA, Decoded::fields(&DATA)),
            Err(TransmitFault::Mismatch { id: 0x030 })
        );
    }

    /// At the end of the slot itself, as every deadline of the node.
    #[test]
    fn sc_req_10_a_data_packet_not_on_the_bus_by_the_end_of_its_slot_is_missing() {
        let mut check = TransmitCheck::new();
        check.computed(at(5_000), DATA).unwrap();
        assert_eq!(check.poll(at(5_999)), Ok(()));
        assert_eq!(
            check.poll(at(6_000)),
            Err(TransmitFault::Missing { id: 0x030 })
        );
    }

    #[test]
    fn sc_req_10_a_sync_agrees_by_master_cycle_and_an_offset_within_the_tolerance() {
        let with_offset = |offset: u16| {
            let mut sync = SYNC;
            sync.data[3..5].copy_from_slice(&offset.to_be_bytes());
            sync
        };
        let decoded = |frame: &RawFrame| Decoded::fields(frame);
        let tolerance = SYNC_OFFSET_TOLERANCE.as_micros() as u16;
        for (heard, agrees) in [
            (with_offset(250), true),
            (with_offset(250 + tolerance), true),
            (with_offset(250 - tolerance), true),
            (with_offset(250 + tolerance + 1), false),
        ] {
            let mut check = TransmitCheck::new();
            check.computed(at(0), SYNC).unwrap();
            assert_eq!(check.deadline(), at(2_000), "SC_REQ_23: 2 ms");
            let result = check.heard(heard, decoded(&heard));
            assert_eq!(result.is_ok(), agrees, "{heard:?}");
        }
        // Another cycle, or a sync B's decoder rejected, is a mismatch.
        let mut other_cycle = SYNC;
        other_cycle.data[2] = 0x03;
        let mut check = TransmitCheck::new();
        check.computed(at(0), SYNC).unwrap();
        assert!(check.heard(other_cycle, decoded(&other_cycle)).is_err());
        let mut check = TransmitCheck::new();
        check.computed(at(0), SYNC).unwrap();
        assert!(check.heard(SYNC, Decoded::Invalid).is_err());
    }
}
