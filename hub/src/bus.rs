//! A simulated CAN bus: arbitration by identifier, each frame on the bus for its real bit
//! time (stuff bits included), delivered to every participant except its sender, and a fault
//! vocabulary for injecting what real buses do.
//!
//! The host simulation (`tests/`) and the emulated network's hub (`can-hub`) share this model
//! and its fault vocabulary ([`Fault`]), so a scenario means the same on both.

use shared::{CanFrame, Duration, Instant};

/// Bit rates CANopen devices commonly run at (CiA 301 Table 1 subset).
pub const BIT_RATES: [u32; 4] = [125_000, 250_000, 500_000, 1_000_000];

/// Frames one participant may have waiting for the bus in the hub ([`Bus::try_send`]): its
/// transmit FIFO. More than a node ever has pending (heartbeat, EMCY, an SRDO pair, an SDO
/// response), so only a sender that floods the bus reaches it; at 500 kbit/s the bus drains
/// it in about 7 ms. A participant whose FIFO is full waits, as a real CAN controller with
/// every transmit mailbox busy does: the hub stops taking its bytes until there is room.
pub const TRANSMIT_QUEUE: usize = 32;

/// [`Bus::try_send`] refused a frame: the participant's transmit FIFO is full.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct QueueFull {
    /// The participant.
    pub from: usize,
}

impl std::fmt::Display for QueueFull {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "participant {}'s transmit queue is full ({TRANSMIT_QUEUE} frames waiting for the bus)",
            self.from
        )
    }
}

/// The fewest bits a frame occupies ([`frame_bits`]): a frame without data whose header and
/// CRC need no stuff bit, 34 bits from start of frame to the CRC, 13 of delimiters,
/// acknowledgement, end of frame and intermission.
pub const SHORTEST_FRAME_BITS: u32 = 47;

/// Bits one standard (11-bit) frame occupies on the bus: SOF to the end of the CRC with its
/// stuff bits, then CRC delimiter, ACK slot and delimiter, end of frame and the 3-bit
/// intermission (ISO 11898-1 10.4, 10.5).
pub fn frame_bits(frame: &CanFrame) -> u32 {
    // SOF to the end of the CRC: at most 19 + 64 + 15 = 98 bits, kept on the stack (this runs
    // once per frame in the simulations: no allocation).
    let mut bits = [false; 98];
    let mut len = 0usize;
    let mut push = |bits: &mut [bool; 98], value: u32, width: u32| {
        for bit in (0..width).rev() {
            bits[len] = value >> bit & 1 == 1;
            len += 1;
        }
        len
    };
    push(&mut bits, 0, 1); // SOF
    push(&mut bits, u32::from(frame.id().raw()), 11);
    push(&mut bits, u32::from(frame.is_remote()), 1); // RTR
    push(&mut bits, 0, 1); // IDE
    push(&mut bits, 0, 1); // r0
    let mut end = push(&mut bits, u32::from(frame.dlc()), 4);
    if !frame.is_remote() {
        for &byte in frame.data() {
            end = push(&mut bits, u32::from(byte), 8);
        }
    }
    let crc = crc15(&bits[..end]);
    let end = push(&mut bits, u32::from(crc), 15);
    let stuffed = stuff_bits(&bits[..end]);
    end as u32 + stuffed + 3 + 7 + 3
}

/// Entries of a [`FrameBitsMemo`] (a power of two).
const MEMO_ENTRIES: usize = 4096;

/// [`frame_bits`] remembered per frame: the simulations put the same frames on the bus again
/// and again (heartbeats, SRDO pairs whose data changes only with the inputs), and a frame's
/// bit count (its CRC and stuff bits) costs a walk over up to 98 bits. Direct-mapped: a
/// frame's entry is chosen by a hash of its identifier, data length code, RTR bit and data
/// bytes, and holds the last frame that fell on it with its count, so a hit is a comparison
/// and a miss one [`frame_bits`]. The key is the whole frame, so the count returned is
/// always [`frame_bits`] of the frame asked about (a test compares them over many frames).
#[derive(Clone)]
pub struct FrameBitsMemo {
    /// Per entry: the frame's [`header`](FrameBitsMemo::header) (0: empty; a header is never
    /// 0), its eight data bytes (little-endian) and its bit count.
    entries: Box<[(u32, u64, u32)]>,
}

impl FrameBitsMemo {
    /// An empty memo.
    pub fn new() -> Self {
        FrameBitsMemo {
            entries: vec![(0, 0, 0); MEMO_ENTRIES].into_boxed_slice(),
        }
    }

    /// Identifier, RTR bit and data length code in one number, with a bit set so that no
    /// frame's header is 0, an empty entry's.
    fn header(frame: &CanFrame) -> u32 {
        u32::from(frame.id().raw())
            | u32::from(frame.is_remote()) << 11
            | u32::from(frame.dlc()) << 12
            | 1 << 16
    }

    /// [`frame_bits`] of `frame`.
    pub fn bits(&mut self, frame: &CanFrame) -> u32 {
        let header = Self::header(frame);
        let data = u64::from_le_bytes(*frame.raw_data());
        // Fibonacci hashing: the top bits of the product pick the entry.
        let hash = (data ^ u64::from(header).rotate_left(40)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let index = (hash >> (64 - MEMO_ENTRIES.trailing_zeros())) as usize;
        let Some(entry) = self.entries.get_mut(index) else {
            return frame_bits(frame);
        };
        if entry.0 == header && entry.1 == data {
            return entry.2;
        }
        let bits = frame_bits(frame);
        *entry = (header, data, bits);
        bits
    }
}

impl Default for FrameBitsMemo {
    fn default() -> Self {
        Self::new()
    }
}

impl std::fmt::Debug for FrameBitsMemo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let used = self.entries.iter().filter(|entry| entry.0 != 0).count();
        f.debug_struct("FrameBitsMemo")
            .field("used", &used)
            .finish()
    }
}

/// The CAN CRC-15 (polynomial 0x4599) over a bit stream (ISO 11898-1 10.4.2.6).
fn crc15(bits: &[bool]) -> u16 {
    let mut crc: u16 = 0;
    for &bit in bits {
        let next = bit ^ (crc >> 14 & 1 == 1);
        crc = (crc << 1) & 0x7FFF;
        if next {
            crc ^= 0x4599;
        }
    }
    crc
}

/// Stuff bits the transmitter inserts: after five equal bits, one of the opposite value, which
/// counts towards the next run (ISO 11898-1 10.5).
fn stuff_bits(bits: &[bool]) -> u32 {
    let mut stuffed = 0;
    let mut run = 0;
    let mut last = None;
    for &bit in bits {
        if last == Some(bit) {
            run += 1;
        } else {
            last = Some(bit);
            run = 1;
        }
        if run == 5 {
            stuffed += 1;
            last = Some(!bit);
            run = 1;
        }
    }
    stuffed
}

/// Where a frame stands in arbitration: lower wins (identifier, then a data frame before a
/// remote frame).
fn priority(frame: &CanFrame) -> (u16, bool) {
    (frame.id().raw(), frame.is_remote())
}

/// How long `frame` occupies the bus at `bit_rate`.
pub fn frame_time(frame: &CanFrame, bit_rate: u32) -> Duration {
    bits_time(frame_bits(frame), bit_rate)
}

/// How long `bits` bits take at `bit_rate`, rounded up to the microsecond.
fn bits_time(bits: u32, bit_rate: u32) -> Duration {
    Duration::from_micros((u64::from(bits) * 1_000_000).div_ceil(u64::from(bit_rate)))
}

/// Which frames a fault applies to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Match {
    /// Only frames with this identifier (any when `None`).
    pub id: Option<u16>,
    /// Only frames sent by this participant (any when `None`).
    pub from: Option<usize>,
    /// Only from this instant on.
    pub after: Instant,
    /// How many matching frames the fault applies to (`None`: all).
    pub count: Option<u32>,
}

impl Match {
    /// The next frame with identifier `id` from `after` on.
    pub fn next_with_id(id: u16, after: Instant) -> Self {
        Match {
            id: Some(id),
            from: None,
            after,
            count: Some(1),
        }
    }

    /// Every frame of participant `from`, from `after` on.
    pub fn all_from(from: usize, after: Instant) -> Self {
        Match {
            id: None,
            from: Some(from),
            after,
            count: None,
        }
    }
}

/// What happens to a matching frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fault {
    /// The frame is lost: no receiver sees it (a receiver-side error frame that the sender
    /// does not repeat, or a frame filtered out on its way).
    Drop,
    /// Data byte `byte` is XOR-ed with `mask` after the CRC check, as a faulty controller or
    /// gateway would pass it on.
    Corrupt {
        /// Index of the data byte.
        byte: usize,
        /// Bits flipped.
        mask: u8,
    },
    /// Delivered this much later than it ended on the bus (a store-and-forward gateway).
    Delay(Duration),
    /// Delivered twice.
    Repeat,
    /// Delivered right after the next frame that goes on the bus instead of before it (a
    /// store-and-forward gateway that reorders); held until there is one.
    Reorder,
    /// The sender's frames never reach the bus (a muted or disconnected participant).
    Mute,
}

/// A fault and the frames it applies to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Injection {
    /// Which frames.
    pub when: Match,
    /// What happens to them.
    pub fault: Fault,
    /// How many frames it has been applied to.
    pub applied: u32,
}

impl Injection {
    /// `fault` for the frames `when` selects.
    pub fn new(when: Match, fault: Fault) -> Self {
        Injection {
            when,
            fault,
            applied: 0,
        }
    }

    fn matches(&self, frame: &CanFrame, from: usize, now: Instant) -> bool {
        now >= self.when.after
            && self.when.id.is_none_or(|id| id == frame.id().raw())
            && self.when.from.is_none_or(|sender| sender == from)
            && self.when.count.is_none_or(|count| self.applied < count)
    }
}

/// A frame on its way to the receivers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Delivery {
    /// When the receivers get it.
    pub at: Instant,
    /// The frame as received.
    pub frame: CanFrame,
    /// Who sent it (it is not delivered back to the sender).
    pub from: usize,
    /// Bits the frame occupied on the bus, stuff bits included ([`frame_bits`]).
    pub bits: u32,
}

/// [`Bus::set_transmit_mailboxes`] for a participant's whole queue ordered by identifier.
pub const ORDERED_BY_IDENTIFIER: usize = usize::MAX;

/// The bus: one transmit queue per participant, arbitration, timing and faults.
#[derive(Clone, Debug)]
pub struct Bus {
    bit_rate: u32,
    queues: Vec<std::collections::VecDeque<CanFrame>>,
    /// How many frames at the front of each queue compete for the bus (transmit mailboxes):
    /// 1 (the default) is a FIFO, `usize::MAX` the whole queue by identifier; see
    /// [`Bus::set_transmit_mailboxes`].
    mailboxes: usize,
    /// Each non-empty queue's candidate (its best frame among the mailboxes) by arbitration
    /// order (identifier, then a data frame before a remote frame, then the lower
    /// participant), so that an arbitration among hundreds of participants does not look at
    /// each of them; and each participant's entry in it.
    heads: std::collections::BTreeSet<(u16, bool, usize)>,
    candidates: Vec<Option<(u16, bool, usize)>>,
    /// The bus is busy until then.
    free_at: Instant,
    injections: Vec<Injection>,
    /// A frame held by [`Fault::Reorder`] until the next one has been delivered.
    held: Option<Delivery>,
    /// Each frame's bit count, remembered.
    bits: FrameBitsMemo,
    /// Frames sent, for statistics: (sent, bits on the bus).
    pub frames_sent: u64,
    /// Bits the frames occupied.
    pub bits_sent: u64,
}

impl Bus {
    /// A bus at `bit_rate` with `participants` participants.
    pub fn new(bit_rate: u32, participants: usize) -> Self {
        Bus {
            bit_rate,
            queues: vec![Default::default(); participants],
            mailboxes: 1,
            heads: std::collections::BTreeSet::new(),
            candidates: vec![None; participants],
            free_at: Instant::ZERO,
            injections: Vec::new(),
            held: None,
            bits: FrameBitsMemo::new(),
            frames_sent: 0,
            bits_sent: 0,
        }
    }

    /// The bit rate.
    pub fn bit_rate(&self) -> u32 {
        self.bit_rate
    }

    /// Changes the bit rate for the frames that start from now on (an LSS activate bit
    /// timing, CiA 305 Fig. 35); a frame on the bus keeps the time it was given.
    pub fn set_bit_rate(&mut self, bit_rate: u32) {
        self.bit_rate = bit_rate;
    }

    /// Participant `from` wants to send `frame` (queued in order, like a transmit FIFO, or by
    /// identifier: [`Bus::set_transmit_mailboxes`]). A
    /// participant not seen before joins the bus. For the host simulation, whose senders are
    /// the test's own code; input from outside goes through [`Bus::try_send`].
    pub fn send(&mut self, from: usize, frame: CanFrame) {
        if from >= self.queues.len() {
            self.queues.resize(from + 1, Default::default());
        }
        self.queues[from].push_back(frame);
        if self.queues[from].len() <= self.mailboxes {
            self.update_candidate(from);
        }
    }

    /// Lets the first `mailboxes` frames of each participant's queue compete for the bus by
    /// identifier, the rest waiting in order behind them: a bxCAN (three transmit mailboxes,
    /// TXFP = 0: the pending mailbox with the lowest identifier goes first) behind a software
    /// FIFO. The default, 1, is a plain FIFO. [`ORDERED_BY_IDENTIFIER`] is the whole queue by
    /// identifier, frames of one identifier in the order they were queued: `board::hw` keeps
    /// its frames to send in such a priority queue (`dual_channel::transmit_queue`), so that
    /// a node's own heartbeat or EMCY queued first never holds back its SRDO or its GFC; the
    /// dual-channel simulation and the hub model each channel's controller so. (Not for a
    /// single controller that sends both halves of an SRDO, as the single-channel demo nodes
    /// do: a new plain frame would overtake its own pending inverted one.) Set it before
    /// anything is queued.
    pub fn set_transmit_mailboxes(&mut self, mailboxes: usize) {
        self.mailboxes = mailboxes.max(1);
        for from in 0..self.queues.len() {
            self.update_candidate(from);
        }
    }

    /// The position in participant `from`'s queue of the frame that competes for the bus.
    fn candidate(&self, from: usize) -> Option<usize> {
        self.queues[from]
            .iter()
            .take(self.mailboxes)
            .enumerate()
            .min_by_key(|(_, frame)| priority(frame))
            .map(|(position, _)| position)
    }

    /// Keeps `heads` in step with participant `from`'s queue.
    fn update_candidate(&mut self, from: usize) {
        if from >= self.candidates.len() {
            self.candidates.resize(from + 1, None);
        }
        if let Some(old) = self.candidates[from].take() {
            self.heads.remove(&old);
        }
        if let Some(position) = self.candidate(from) {
            let (id, remote) = priority(&self.queues[from][position]);
            let key = (id, remote, from);
            self.heads.insert(key);
            self.candidates[from] = Some(key);
        }
    }

    /// [`Bus::send`] with the transmit FIFO bounded at [`TRANSMIT_QUEUE`] frames: a frame
    /// beyond it is refused, and the caller makes its sender wait ([`Bus::has_room`]).
    pub fn try_send(&mut self, from: usize, frame: CanFrame) -> Result<(), QueueFull> {
        if !self.has_room(from) {
            return Err(QueueFull { from });
        }
        self.send(from, frame);
        Ok(())
    }

    /// Frames participant `from` has waiting for the bus.
    pub fn queued(&self, from: usize) -> usize {
        self.queues
            .get(from)
            .map_or(0, std::collections::VecDeque::len)
    }

    /// `true` while participant `from` can queue another frame with [`Bus::try_send`].
    pub fn has_room(&self, from: usize) -> bool {
        self.queued(from) < TRANSMIT_QUEUE
    }

    /// Forgets what participant `from` still had queued (it left the bus).
    pub fn leave(&mut self, from: usize) {
        if let Some(queue) = self.queues.get_mut(from) {
            queue.clear();
            self.update_candidate(from);
        }
    }

    /// Adds a fault.
    pub fn inject(&mut self, injection: Injection) {
        self.injections.push(injection);
    }

    /// Removes every fault.
    pub fn clear_faults(&mut self) {
        self.injections.clear();
    }

    /// Keeps only the faults for which `keep` is true.
    pub fn retain_faults(&mut self, keep: impl FnMut(&Injection) -> bool) {
        self.injections.retain(keep);
    }

    /// When the bus is free again: the end of the frame on it (or of its repetition), or
    /// an instant already past.
    pub fn free_at(&self) -> Instant {
        self.free_at
    }

    /// The least time any frame occupies the bus at this bit rate ([`SHORTEST_FRAME_BITS`]):
    /// nothing that is arbitrated at an instant reaches the receivers sooner after it.
    pub fn shortest_frame(&self) -> Duration {
        bits_time(SHORTEST_FRAME_BITS, self.bit_rate)
    }

    /// When the next arbitration can start, if anything is waiting.
    pub fn next_start(&self, now: Instant) -> Option<Instant> {
        (!self.heads.is_empty()).then(|| self.free_at.max(now))
    }

    /// Runs one arbitration at `now` (the bus must be free): the lowest identifier among the
    /// queue heads (the frames in the transmit mailboxes) wins; returns the deliveries it causes (none for a dropped or muted frame,
    /// two for a repeated one).
    pub fn arbitrate(&mut self, now: Instant) -> Vec<Delivery> {
        let mut deliveries = Vec::new();
        self.arbitrate_into(now, &mut deliveries);
        deliveries
    }

    /// [`Bus::arbitrate`], appending the deliveries to `deliveries` (no allocation once
    /// `deliveries` has room: the simulations call this for every frame).
    pub fn arbitrate_into(&mut self, now: Instant, deliveries: &mut Vec<Delivery>) {
        if now < self.free_at {
            return;
        }
        // Identifier order; at equal identifiers a data frame wins over a remote frame, and
        // at equal frames the lower participant (the order `heads` keeps).
        let Some(&(_, _, from)) = self.heads.first() else {
            return;
        };
        let Some(frame) = self
            .candidate(from)
            .and_then(|position| self.queues[from].remove(position))
        else {
            return;
        };
        self.update_candidate(from);
        let mut delivered = frame;
        let mut at = now;
        let mut copies = 1;
        let mut reorder = false;
        for injection in self.injections.iter_mut() {
            if !injection.matches(&frame, from, now) {
                continue;
            }
            injection.applied += 1;
            match injection.fault {
                Fault::Mute => return,
                Fault::Drop => copies = 0,
                Fault::Corrupt { byte, mask } => {
                    let mut data = *delivered.raw_data();
                    if let Some(target) = data.get_mut(byte) {
                        *target ^= mask;
                    }
                    if let Ok(corrupted) =
                        CanFrame::from_parts(delivered.id(), delivered.dlc(), data)
                    {
                        delivered = corrupted;
                    }
                }
                Fault::Delay(delay) => at = at + delay,
                Fault::Repeat => copies = 2,
                Fault::Reorder => reorder = true,
            }
        }
        let bits = self.bits.bits(&frame);
        let duration = bits_time(bits, self.bit_rate);
        self.free_at = now + duration;
        self.frames_sent += 1;
        self.bits_sent += u64::from(bits);
        let end = at + duration;
        let first = deliveries.len();
        for copy in 0..copies {
            // A repeated frame occupies the bus again right after the first.
            let extra = Duration::from_micros(duration.as_micros() * copy);
            deliveries.push(Delivery {
                at: end + extra,
                frame: delivered,
                from,
                bits,
            });
        }
        if copies == 2 {
            self.free_at = self.free_at + duration;
        }
        if reorder && self.held.is_none() {
            // Held back: it reaches the receivers just after the next frame does.
            self.held = deliveries.pop();
            deliveries.truncate(first);
        } else if let Some(mut held) = self.held.take() {
            if let Some(last) = deliveries[first..].last() {
                held.at = last.at + Duration::from_micros(1);
                deliveries.push(held);
            } else {
                self.held = Some(held);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::CanId;

    fn frame(id: u16, data: &[u8]) -> CanFrame {
        CanFrame::new(CanId::new(id).unwrap(), data).unwrap()
    }

    /// A reordered frame reaches the receivers just after the frame that followed it on the
    /// bus (CiA 304 9.5: an inverted frame before its plain frame must be caught).
    #[test]
    fn a_reordered_frame_arrives_after_the_next_one() {
        let mut bus = Bus::new(500_000, 2);
        bus.inject(Injection::new(
            Match::next_with_id(0x101, Instant::ZERO),
            Fault::Reorder,
        ));
        bus.send(0, frame(0x101, &[1]));
        bus.send(1, frame(0x102, &[0xFE]));
        let mut now = Instant::ZERO;
        let mut delivered = Vec::new();
        while let Some(start) = bus.next_start(now) {
            now = start;
            delivered.extend(bus.arbitrate(now));
        }
        let order: Vec<(u16, u64)> = delivered
            .iter()
            .map(|d| (d.frame.id().raw(), d.at.as_micros()))
            .collect();
        assert_eq!(order.len(), 2, "{order:?}");
        assert_eq!((order[0].0, order[1].0), (0x102, 0x101), "{order:?}");
        assert!(order[1].1 > order[0].1);
    }

    /// No frame occupies the bus for fewer than [`SHORTEST_FRAME_BITS`] bits (the full
    /// network's engine takes it as the least time between an arbitration and its
    /// delivery), and some frame does occupy exactly that many: every identifier, data and
    /// remote, without data and with every length of data drawn from a fixed sequence.
    #[test]
    fn no_frame_is_shorter_than_the_shortest_frame() {
        let mut shortest = u32::MAX;
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        for id in 0..2048u16 {
            let id = CanId::new(id).unwrap();
            let mut frames = vec![CanFrame::new(id, &[]).unwrap()];
            frames.extend((0..=8).map(|dlc| CanFrame::remote(id, dlc).unwrap()));
            for len in 1..=8 {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                frames.push(CanFrame::new(id, &state.to_le_bytes()[..len]).unwrap());
            }
            for frame in &frames {
                shortest = shortest.min(frame_bits(frame));
            }
        }
        assert_eq!(shortest, SHORTEST_FRAME_BITS);
        let bus = Bus::new(1_000_000, 1);
        assert_eq!(bus.shortest_frame(), Duration::from_micros(47));
        let bus = Bus::new(125_000, 1);
        assert_eq!(bus.shortest_frame(), Duration::from_micros(376));
    }

    /// ISO 11898-1: an all-dominant header gives a stuff bit after every fifth bit.
    #[test]
    fn bit_time_counts_stuff_bits() {
        // 19 header bits and a CRC of 0, all dominant: 34 bits, 6 stuff bits, 13 trailing.
        assert_eq!(frame_bits(&frame(0x000, &[])), 34 + 6 + 13);
        // A frame never takes fewer than its unstuffed bits nor more than the worst case.
        for id in [0x000u16, 0x101, 0x555, 0x7FF] {
            for len in 0..=8usize {
                for fill in [0x00u8, 0xFF, 0xAA, 0x0F] {
                    let bits = frame_bits(&frame(id, &vec![fill; len]));
                    let unstuffed = 47 + 8 * len as u32;
                    let stuffable = 34 + 8 * len as u32;
                    assert!(bits >= unstuffed, "{id:03X} {len} {fill:02X}");
                    assert!(
                        bits <= unstuffed + (stuffable - 1) / 4,
                        "{id:03X} {len} {fill:02X}"
                    );
                }
            }
        }
        // An 8-byte SRDO frame at 500 kbit/s takes 2 µs per bit.
        let srdo = frame(0x101, &[0x55; 8]);
        assert_eq!(
            frame_time(&srdo, 500_000).as_micros(),
            u64::from(frame_bits(&srdo)) * 2
        );
    }

    /// The memo gives [`frame_bits`] of every frame asked about: over many frames (data and
    /// remote, every length, random data), far more than it has entries, each asked about
    /// several times, so that frames evict one another and come back; few identifiers, so
    /// that frames differing in their data alone meet in one entry.
    #[test]
    fn the_memo_gives_the_bit_count_of_every_frame() {
        let mut memo = FrameBitsMemo::new();
        let mut state = 0x2545_F491_4F6C_DD1Du64;
        let mut next = || {
            // xorshift64: a fixed, reproducible sequence.
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let frames: Vec<CanFrame> = (0..3 * MEMO_ENTRIES)
            .map(|_| {
                let random = next();
                let id = CanId::new([0x000, 0x101, 0x555, 0x7FF][(random & 3) as usize]).unwrap();
                let dlc = (random >> 11) as u8 % 9;
                // A few values only in the data, so that frames differ in a byte or two.
                let data = (next() & 0x0101_0101_0303_0F0F).to_le_bytes();
                if random >> 20 & 7 == 0 {
                    CanFrame::remote(id, dlc).unwrap()
                } else {
                    CanFrame::from_parts(id, dlc, data).unwrap()
                }
            })
            .collect();
        for round in 0..4 {
            for at in 0..frames.len() {
                let frame = &frames[(at * (2 * round + 1)) % frames.len()];
                assert_eq!(memo.bits(frame), frame_bits(frame), "{frame:?}");
            }
        }
    }

    #[test]
    fn lowest_identifier_wins_arbitration_and_the_sender_waits() {
        let mut bus = Bus::new(500_000, 3);
        bus.send(0, frame(0x102, &[1]));
        bus.send(1, frame(0x701, &[5]));
        bus.send(2, frame(0x081, &[0; 8]));
        let first = bus.arbitrate(Instant::ZERO);
        assert_eq!(first[0].frame.id().raw(), 0x081);
        assert_eq!(first[0].from, 2);
        // The bus is busy until the first frame has ended.
        assert_eq!(bus.next_start(Instant::ZERO), Some(first[0].at));
        assert!(bus.arbitrate(Instant::ZERO).is_empty());
        let second = bus.arbitrate(first[0].at);
        assert_eq!(second[0].frame.id().raw(), 0x102);
        let third = bus.arbitrate(second[0].at);
        assert_eq!(third[0].frame.id().raw(), 0x701);
        assert_eq!(bus.next_start(third[0].at), None);
    }

    /// With three transmit mailboxes a node's own low-priority frame queued first does not hold
    /// back its higher-priority one (bxCAN, TXFP = 0); a fourth frame waits for a mailbox, and
    /// with one mailbox the queue is a FIFO.
    #[test]
    fn transmit_mailboxes_send_by_identifier_and_the_rest_in_order() {
        let order = |mailboxes: usize| {
            let mut bus = Bus::new(500_000, 2);
            bus.set_transmit_mailboxes(mailboxes);
            for id in [0x701, 0x705, 0x703, 0x101] {
                bus.send(0, frame(id, &[0]));
            }
            bus.send(1, frame(0x200, &[0]));
            let mut now = Instant::ZERO;
            let mut ids = Vec::new();
            while let Some(start) = bus.next_start(now) {
                now = start;
                let delivered = bus.arbitrate(now);
                now = delivered[0].at;
                ids.push(delivered[0].frame.id().raw());
            }
            ids
        };
        assert_eq!(order(3), [0x200, 0x701, 0x101, 0x703, 0x705]);
        assert_eq!(order(1), [0x200, 0x701, 0x705, 0x703, 0x101]);
        assert_eq!(order(8), [0x101, 0x200, 0x701, 0x703, 0x705]);
    }

    /// A participant's transmit FIFO holds `TRANSMIT_QUEUE` frames; one more is refused (the
    /// sender has to wait) and nothing queued is lost; once the bus has taken a frame there is
    /// room again.
    #[test]
    fn a_full_transmit_queue_refuses_the_next_frame_and_loses_none() {
        let mut bus = Bus::new(500_000, 2);
        for n in 0..TRANSMIT_QUEUE {
            assert_eq!(bus.try_send(0, frame(0x200, &[n as u8])), Ok(()));
        }
        assert_eq!(
            bus.try_send(0, frame(0x200, &[0xEE])),
            Err(QueueFull { from: 0 })
        );
        assert_eq!(bus.queued(0), TRANSMIT_QUEUE);
        assert!(bus.has_room(1), "the other participant's FIFO is its own");
        let first = bus.arbitrate(Instant::ZERO);
        assert_eq!(first[0].frame.data(), &[0]);
        assert!(bus.has_room(0));
        let mut now = first[0].at;
        let mut delivered = vec![0u8];
        while let Some(start) = bus.next_start(now) {
            now = start;
            delivered.extend(bus.arbitrate(now).iter().map(|d| d.frame.data()[0]));
        }
        let expected: Vec<u8> = (0..TRANSMIT_QUEUE as u8).collect();
        assert_eq!(delivered, expected, "every queued frame, in order");
    }

    #[test]
    fn faults_apply_to_the_frames_they_match() {
        let mut bus = Bus::new(250_000, 2);
        bus.inject(Injection::new(
            Match::next_with_id(0x102, Instant::ZERO),
            Fault::Corrupt {
                byte: 0,
                mask: 0x01,
            },
        ));
        bus.inject(Injection::new(
            Match::all_from(1, Instant::ZERO),
            Fault::Mute,
        ));
        bus.send(0, frame(0x102, &[0xFE]));
        bus.send(1, frame(0x101, &[0x01]));
        assert!(bus.arbitrate(Instant::ZERO).is_empty(), "muted");
        let corrupted = bus.arbitrate(Instant::ZERO);
        assert_eq!(corrupted[0].frame.data(), &[0xFF]);
        bus.send(0, frame(0x102, &[0xFE]));
        let clean = bus.arbitrate(Instant::from_millis(1));
        assert_eq!(
            clean[0].frame.data(),
            &[0xFE],
            "the corruption applied once"
        );
    }
}
