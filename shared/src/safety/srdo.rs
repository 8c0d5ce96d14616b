//! The SRDO producer and consumer (EN 50325-5 7.1, CiA 304 8.1 and 9.5).
//!
//! Both work on [`ResolvedMapping`]s, so at run time they only copy bytes between a frame and
//! spans of the process image. Payloads are handled as little-endian `u64`s: checking that the
//! inverted frame is the bitwise inverse of the plain one is one XOR and one mask, whatever the
//! mapping.
//!
//! Timers are absolute [`Instant`]s in microseconds and expire *at* their deadline
//! ([`time::expired`]). A consumer checks its timers on every frame as well as when polled, so
//! a frame that arrives after a deadline the caller has not yet polled for is still judged
//! late.
//!
//! A consumer discards, without a fault, the two frames CAN produces on a healthy bus (see
//! [`Discarded`]): an exact repeat of the pending plain frame and an inverted frame with no
//! plain frame pending. Until its first pair since it entered Operational it also discards the
//! half of a pair that a producer's NMT reset cut and that reached the bus after the start:
//! frames that do not pair are not delivered, and SRVT and SCT decide (see
//! [`Consumer::on_plain`]). Any other deviation from "plain, then its inverse within SRVT" is
//! a fault.

use super::config::{ResolvedMapping, ValidSrdo};
use super::types::{CobIdPair, SrdoNumber};
use crate::frame::{CanFrame, CanId};
use crate::process_image::{ProcessImage, Span};
use crate::time::{self, Duration, Instant};

/// Why a consumer (or producer) gave up on an SRDO.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SrdoFaultCause {
    /// No complete pair arrived within SCT of the previous one, or of entering Operational
    /// (EN 50325-5 7.1.2, SCT event).
    SctElapsed,
    /// The inverted frame did not arrive within SRVT of its plain frame (EN 50325-5 7.1.2,
    /// SRVT event).
    SrvtElapsed,
    /// A second plain frame with other data (or another length) arrived before the inverted
    /// frame of the first (CiA 304 9.5: chronological order). An exact repeat is not a
    /// fault: see [`Discarded::PlainRepeated`].
    PlainRepeated,
    /// The inverted frame's data is not the bitwise inverse of the plain frame's
    /// (EN 50325-5 7.1.1; CiA 304 9.5: compared bit by bit).
    NotInverted,
    /// A frame carried fewer data bytes than the mapping needs; the data was not processed
    /// (EN 50325-5 7.1.3, EMCY 8210h).
    TooShort,
    /// The plain and inverted data handed in for transmission are not exact inverses, so
    /// nothing was sent.
    TransmitHalvesNotInverted,
}

impl SrdoFaultCause {
    /// This fault's cause code and name ([`Cause`](crate::safety::cause::Cause)).
    pub const fn cause(self) -> crate::safety::cause::Cause {
        use crate::safety::cause::Cause;
        match self {
            SrdoFaultCause::SctElapsed => Cause::SctElapsed,
            SrdoFaultCause::SrvtElapsed => Cause::SrvtElapsed,
            SrdoFaultCause::PlainRepeated => Cause::PlainRepeated,
            SrdoFaultCause::NotInverted => Cause::NotInverted,
            SrdoFaultCause::TooShort => Cause::TooShort,
            SrdoFaultCause::TransmitHalvesNotInverted => Cause::TransmitHalvesNotInverted,
        }
    }

    /// A stable number for this cause, sent in the manufacturer-specific bytes of EMCY: the
    /// code of [`SrdoFaultCause::cause`].
    pub const fn cause_code(self) -> u8 {
        self.cause().code()
    }

    /// The EMCY error code for this cause (EN 50325-5 7.1.3 mandates 8210h for a short frame).
    pub const fn emergency_code(self) -> u16 {
        use crate::canopen::emcy::code;
        match self {
            SrdoFaultCause::SctElapsed | SrdoFaultCause::SrvtElapsed => code::RPDO_TIMEOUT,
            SrdoFaultCause::TooShort => code::PDO_LENGTH,
            SrdoFaultCause::PlainRepeated | SrdoFaultCause::NotInverted => code::PROTOCOL_ERROR,
            SrdoFaultCause::TransmitHalvesNotInverted => code::INTERNAL_SOFTWARE,
        }
    }
}

/// A fault of one SRDO: which, and why.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SrdoFault {
    /// The SRDO.
    pub srdo: SrdoNumber,
    /// The cause.
    pub cause: SrdoFaultCause,
}

/// The payload bits that `len` bytes occupy in a little-endian `u64`.
pub use crate::process_image::byte_mask as payload_mask;

/// `true` when the first `len` bytes of `inverted` are the bitwise inverse of `plain`'s.
#[inline]
pub const fn is_inverse(plain: u64, inverted: u64, len: u8) -> bool {
    let mask = payload_mask(len);
    (plain ^ inverted) & mask == mask
}

/// A frame a consumer discarded without a fault, because CAN itself produces it on a healthy
/// bus, or an NMT reset and start do before the consumer's first pair.
///
/// ISO 11898-1 lets a receiver accept a frame twice: it takes a frame as valid at the
/// last-but-one bit of the end-of-frame field, and a transmitter that sees an error in the
/// last bit repeats the frame. And a consumer that starts monitoring (enters Operational)
/// between a producer's plain and inverted frames sees an inverted frame first. Likewise, a
/// frame a producer queued before its NMT reset (a CAN controller sends what it was handed)
/// can reach the bus after the master's start, in the consumer's new epoch, where nothing
/// completes its pair (the last two variants). None of them delivers anything: only a plain
/// frame and the inverted frame that follows it within SRVT make a pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Discarded {
    /// An exact repeat of the pending plain frame (same identifier, length and data). The
    /// pending frame's SRVT keeps running from the first copy.
    PlainRepeated,
    /// An inverted frame with no plain frame pending. SCT keeps running.
    InvertedWithoutPlain,
    /// Before the consumer's first pair since it entered Operational: the pending plain frame,
    /// replaced by a later plain frame with other data or another length (the producer's
    /// frame of its ended epoch, whose inverse nobody sends, then its first of the new one).
    /// SRVT keeps running from the first.
    PlainReplacedBeforeFirstPair,
    /// Before the consumer's first pair since it entered Operational: an inverted frame that
    /// is not the inverse of the pending plain frame (the inverted frame of a pair the
    /// producer's reset cut, still in its transmit queue when the producer's first plain frame
    /// of the new epoch went ahead of it). The plain frame stays pending; its SRVT keeps
    /// running.
    InvertedNotPairedBeforeFirstPair,
}

/// What a consumer made of a plain frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlainOutcome {
    /// The plain frame is pending; its inverted frame is due within SRVT.
    Pending,
    /// The frame was discarded: an exact repeat of the pending one.
    Discarded(Discarded),
}

/// What a consumer made of an inverted frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InvertedOutcome {
    /// A valid pair: the plain and the inverted payload, both to be delivered.
    Pair {
        /// The plain payload, little-endian.
        plain: u64,
        /// The inverted payload as received, little-endian.
        inverted: u64,
    },
    /// The frame was discarded: no plain frame was pending.
    Discarded(Discarded),
}

/// Receive side of one SRDO (EN 50325-5 7.1.2, 7.1.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Consumer {
    /// A complete pair must finish before this instant.
    sct_deadline: Instant,
    /// The pending plain frame's inverted partner must arrive before this; `NEVER` when no
    /// plain frame is pending.
    srvt_deadline: Instant,
    /// The pending plain frame's data bytes (those beyond its length are 0).
    pending: u64,
    /// SCT in ms, from the SRDO's record at the Operational entry (the integrity check
    /// compares it with the record, [`Consumer::runs_with`]).
    sct_ms: u16,
    /// SRVT in ms, from the record as SCT.
    srvt_ms: u8,
    /// The pending plain frame's data length code, to tell an exact repeat.
    pending_dlc: DataLength,
    /// A pair completed since the consumer entered Operational ([`Consumer::start`]).
    paired: bool,
}

/// A classic CAN data length code, 0..=8 (ISO 11898-1).
///
/// An enum rather than a `u8` so that its unused values leave a niche: the compiler keeps the
/// node's per-SRDO role tag in it, and the pending length costs no RAM per SRDO (checked at
/// compile time against the 160-byte budget in `node`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
enum DataLength {
    L0,
    L1,
    L2,
    L3,
    L4,
    L5,
    L6,
    L7,
    L8,
}

impl DataLength {
    /// The length of a [`CanFrame`](crate::CanFrame), whose data length code is at most 8
    /// by construction; a larger value (impossible there) reads as 8.
    const fn new(dlc: u8) -> Self {
        match dlc {
            0 => DataLength::L0,
            1 => DataLength::L1,
            2 => DataLength::L2,
            3 => DataLength::L3,
            4 => DataLength::L4,
            5 => DataLength::L5,
            6 => DataLength::L6,
            7 => DataLength::L7,
            _ => DataLength::L8,
        }
    }
}

impl Consumer {
    /// A consumer that starts monitoring at `now` with the SCT and SRVT of its record (in ms,
    /// as the record holds them): the first pair is due within SCT. Taken once, at the
    /// Operational entry, so that a frame does not look its record up.
    pub fn start(now: Instant, sct_ms: u16, srvt_ms: u8) -> Self {
        Consumer {
            sct_deadline: now + Duration::from_millis(u64::from(sct_ms)),
            srvt_deadline: Instant::NEVER,
            pending: 0,
            sct_ms,
            srvt_ms,
            pending_dlc: DataLength::L0,
            paired: false,
        }
    }

    /// The SCT it runs with.
    #[inline]
    pub fn sct(&self) -> Duration {
        Duration::from_millis(u64::from(self.sct_ms))
    }

    /// The SRVT it runs with.
    #[inline]
    pub fn srvt(&self) -> Duration {
        Duration::from_millis(u64::from(self.srvt_ms))
    }

    /// `true` when it runs with the SCT and SRVT of `valid` (the integrity check's question).
    pub fn runs_with(&self, valid: &ValidSrdo) -> bool {
        self.sct() == valid.cycle_time && self.srvt() == valid.srvt
    }

    /// The earliest instant at which [`Consumer::check_timers`] can fail.
    #[inline]
    pub fn deadline(&self) -> Instant {
        if self.srvt_deadline < self.sct_deadline {
            self.srvt_deadline
        } else {
            self.sct_deadline
        }
    }

    /// Fails when SRVT or SCT has elapsed at `now`. SRVT is reported first: when a plain frame
    /// is pending, its missing partner is the more specific cause.
    ///
    /// Out of line in the firmware images, where it was inlined three times
    /// (`docs/footprint.md`); the host builds inline it.
    #[cfg_attr(target_os = "none", inline(never))]
    #[cfg_attr(not(target_os = "none"), inline)]
    pub fn check_timers(&self, now: Instant) -> Result<(), SrdoFaultCause> {
        if time::expired(self.srvt_deadline, now) {
            Err(SrdoFaultCause::SrvtElapsed)
        } else if time::expired(self.sct_deadline, now) {
            Err(SrdoFaultCause::SctElapsed)
        } else {
            Ok(())
        }
    }

    /// The plain frame (COB-ID 1) arrived at `now` with `dlc` bytes of `data` (bytes beyond
    /// `dlc` are 0, as in every [`CanFrame`]).
    ///
    /// With a plain frame pending, an exact repeat of it is discarded (CAN double reception)
    /// and any other plain frame is a sequence error (CiA 304 9.5), once a pair has completed
    /// since the consumer entered Operational.
    ///
    /// Before that first pair, a plain frame with other data replaces the pending one
    /// ([`Discarded::PlainReplacedBeforeFirstPair`]), and [`Consumer::on_inverted`] discards
    /// an inverted frame that is not its inverse: the producer's NMT reset may have cut a
    /// pair whose frames were still in its CAN controllers' transmit queues, and a queued half
    /// reaches the bus after the master's start, which overtook it (EN 50325-5 8.2.2: the
    /// producer stops transmitting SRDOs at the reset, but cannot take back a frame already
    /// going out). The consumer cannot tell that half from its producer's new frames, except
    /// that it does not pair. Nothing but an exact pair is delivered, and the outputs are in
    /// the safe state until the first pair, so discarding costs only time, which stays
    /// bounded as the standard bounds it: SRVT keeps running from the first plain frame
    /// pending (EN 50325-5 7.1.2: the inverted frame that completes the first pair must still
    /// come within SRVT of it), and SCT from the entry into Operational. The old frame is
    /// marked invalid, as CiA 304 9.5 asks of an old received SRDO. From the first pair on,
    /// every deviation is a fault again at once.
    ///
    /// Inlined always: its one caller is the receive hot path, whose result it would
    /// otherwise return through memory.
    #[inline(always)]
    pub fn on_plain(
        &mut self,
        now: Instant,
        data: &[u8; 8],
        dlc: u8,
        len: u8,
    ) -> Result<PlainOutcome, SrdoFaultCause> {
        self.check_timers(now)?;
        let data = u64::from_le_bytes(*data);
        let length = DataLength::new(dlc);
        if self.srvt_deadline != Instant::NEVER {
            return if data == self.pending && length == self.pending_dlc {
                Ok(PlainOutcome::Discarded(Discarded::PlainRepeated))
            } else if self.paired {
                Err(SrdoFaultCause::PlainRepeated)
            } else {
                self.replace_before_first_pair(data, length, dlc, len)
            };
        }
        if dlc < len {
            return Err(SrdoFaultCause::TooShort);
        }
        self.pending = data;
        self.pending_dlc = length;
        self.srvt_deadline = now + self.srvt();
        Ok(PlainOutcome::Pending)
    }

    /// [`Consumer::on_plain`] before the first pair: `data` replaces the pending plain frame,
    /// whose SRVT keeps running. A frame too short is refused as ever. Cold: a reset and start
    /// that overtake a queued frame.
    #[cold]
    #[inline(never)]
    fn replace_before_first_pair(
        &mut self,
        data: u64,
        length: DataLength,
        dlc: u8,
        len: u8,
    ) -> Result<PlainOutcome, SrdoFaultCause> {
        if dlc < len {
            return Err(SrdoFaultCause::TooShort);
        }
        self.pending = data;
        self.pending_dlc = length;
        Ok(PlainOutcome::Discarded(
            Discarded::PlainReplacedBeforeFirstPair,
        ))
    }

    /// The inverted frame (COB-ID 2) arrived at `now`. A valid pair restarts SCT; with no
    /// plain frame pending the frame is discarded (CAN double reception, or monitoring that
    /// started between the two frames) and SCT keeps running. One that is not the inverse of
    /// the pending plain frame is a fault, or, before the first pair since the consumer
    /// entered Operational, discarded with the plain frame still pending and its SRVT running
    /// (see [`Consumer::on_plain`]).
    ///
    /// Inlined always: its one caller is the receive hot path, whose result it would
    /// otherwise return through memory.
    #[inline(always)]
    pub fn on_inverted(
        &mut self,
        now: Instant,
        data: &[u8; 8],
        dlc: u8,
        len: u8,
    ) -> Result<InvertedOutcome, SrdoFaultCause> {
        self.check_timers(now)?;
        if self.srvt_deadline == Instant::NEVER {
            return Ok(InvertedOutcome::Discarded(Discarded::InvertedWithoutPlain));
        }
        if dlc < len {
            return Err(SrdoFaultCause::TooShort);
        }
        let inverted = u64::from_le_bytes(*data);
        if !is_inverse(self.pending, inverted, len) {
            return if self.paired {
                Err(SrdoFaultCause::NotInverted)
            } else {
                Ok(InvertedOutcome::Discarded(
                    Discarded::InvertedNotPairedBeforeFirstPair,
                ))
            };
        }
        let plain = self.pending;
        self.pending = 0;
        self.pending_dlc = DataLength::L0;
        self.srvt_deadline = Instant::NEVER;
        self.sct_deadline = now + self.sct();
        self.paired = true;
        Ok(InvertedOutcome::Pair { plain, inverted })
    }
}

/// Transmit side of one SRDO (EN 50325-5 6.2.1, 7.1.1; CiA 304 9.5).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Producer {
    /// The next cyclic transmission.
    next: Instant,
    /// The refresh time in ms, from the SRDO's record at the Operational entry (the integrity
    /// check compares it with the record, [`Producer::runs_with`]).
    refresh_ms: u16,
    /// The identifiers it sends on, from the record as the refresh time.
    identifiers: CobIdPair,
    /// The mapped data changed since the last transmission (event-driven transmission).
    changed: bool,
}

impl Producer {
    /// A producer entering Operational at `now` with the refresh time (in ms, as its record
    /// holds it) and the identifiers of its record: its first cyclic transmission is delayed
    /// by 0.5 ms × node-ID (CiA 304 9.5), so producers started together do not collide.
    /// Taken once, at the Operational entry, so that a transmission does not look its record
    /// up.
    pub fn start(now: Instant, node_id: u8, refresh_ms: u16, identifiers: CobIdPair) -> Self {
        Producer {
            next: now + Duration::from_micros(500 * u64::from(node_id)),
            refresh_ms,
            identifiers,
            changed: false,
        }
    }

    /// The refresh time it runs with.
    #[inline]
    pub fn refresh(&self) -> Duration {
        Duration::from_millis(u64::from(self.refresh_ms))
    }

    /// `true` when it runs with the refresh time and the identifiers of `valid` (the
    /// integrity check's question).
    pub fn runs_with(&self, valid: &ValidSrdo) -> bool {
        self.refresh() == valid.cycle_time && self.identifiers == valid.cob_ids
    }

    /// The two frames of a pair: `plain` on COB-ID 1 and `inverted` on COB-ID 2, `len` bytes
    /// each (little-endian payloads; the bytes beyond `len` are sent as 0).
    #[inline]
    pub fn frames(&self, plain: u64, inverted: u64, len: u8) -> [CanFrame; 2] {
        [
            CanFrame::from_payload(CanId::from_masked(self.identifiers.first()), plain, len),
            CanFrame::from_payload(CanId::from_masked(self.identifiers.second()), inverted, len),
        ]
    }

    /// The next transmission, cyclic or event-driven.
    #[inline]
    pub fn deadline(&self, now: Instant) -> Instant {
        if self.changed { now } else { self.next }
    }

    /// `true` when a transmission is due at `now`.
    #[inline]
    pub fn due(&self, now: Instant) -> bool {
        self.changed || time::expired(self.next, now)
    }

    /// Marks the mapped data as changed, for event-driven transmission.
    pub fn mark_changed(&mut self) {
        self.changed = true;
    }

    /// Records a transmission at `now` and schedules the next cyclic one. The cycle keeps its
    /// phase when polled on time, and restarts from `now` when a transmission was late by a
    /// whole cycle or was event-driven (so a burst of events cannot shorten the refresh
    /// interval that consumers' SCT expects to see honoured).
    #[inline]
    pub fn sent(&mut self, now: Instant) {
        let refresh = self.refresh();
        let on_cycle = self.next + refresh;
        self.next = if self.changed || time::expired(on_cycle, now) {
            now + refresh
        } else {
            on_cycle
        };
        self.changed = false;
    }
}

/// The last offset at which a whole 8-byte window lies in the process image.
const WINDOW_END: u8 = (crate::process_image::PROCESS_IMAGE_LEN - 8) as u8;

/// Gathers the plain and inverted payloads of a transmit SRDO from the process image and checks
/// that they are exact inverses; `Err` means nothing may be sent.
#[inline]
pub fn gather(
    image: &ProcessImage,
    mapping: &ResolvedMapping,
) -> Result<(u64, u64), SrdoFaultCause> {
    // Each object is read as the 8-byte word that starts with it, masked to its length and
    // shifted to its place in the payload: a load, a mask and a shift, no copy of its length.
    // Every pair of a valid mapping has two objects of the same length, 1 byte at least, that
    // fit in what is left of the payload and whose whole words lie in the image; any other
    // pair (a damaged mapping) is left to the general path, which clamps.
    let mut plain = 0u64;
    let mut inverted = 0u64;
    let mut at = 0usize;
    let pairs = usize::from(mapping.pairs).min(mapping.plain.len());
    for (&plain_span, &inverted_span) in mapping.plain[..pairs].iter().zip(&mapping.inverted) {
        let len = usize::from(plain_span.len);
        if plain_span.len != inverted_span.len
            || plain_span.offset.max(inverted_span.offset) > WINDOW_END
            || len.wrapping_sub(1) >= 8 - at
        {
            return gather_clamped(image, mapping);
        }
        // `1 <= len <= 8 - at`, so `at < 8` and both shifts are below 64.
        let shift = 8 * at as u32;
        let mask = u64::MAX >> (64 - 8 * len as u32);
        plain |= (image.word(plain_span) & mask) << shift;
        inverted |= (image.word(inverted_span) & mask) << shift;
        at += len;
    }
    if is_inverse(plain, inverted, mapping.len) {
        Ok((plain, inverted))
    } else {
        Err(SrdoFaultCause::TransmitHalvesNotInverted)
    }
}

/// [`gather`] for any mapping, damaged ones included: each span clamped to the image, as
/// [`ProcessImage::get`] gives it, and the payload to 8 bytes. Cold: a valid mapping never
/// comes here.
#[cold]
#[inline(never)]
fn gather_clamped(
    image: &ProcessImage,
    mapping: &ResolvedMapping,
) -> Result<(u64, u64), SrdoFaultCause> {
    let mut plain = 0u64;
    let mut inverted = 0u64;
    let mut at = 0usize;
    for pair in 0..usize::from(mapping.pairs).min(mapping.plain.len()) {
        let (plain_span, inverted_span) = (mapping.plain[pair], mapping.inverted[pair]);
        let len = ProcessImage::span_len(plain_span);
        if ProcessImage::span_len(inverted_span) != len {
            return Err(SrdoFaultCause::TransmitHalvesNotInverted);
        }
        if at < 8 {
            // `at < 8`, so the shift is below 64; what goes past the payload is shifted out.
            let shift = 8 * at as u32;
            let mask = payload_mask(len.min(8) as u8);
            plain |= (image.word(plain_span) & mask) << shift;
            inverted |= (image.word(inverted_span) & mask) << shift;
        }
        at = (at + len).min(8);
    }
    if is_inverse(plain, inverted, mapping.len) {
        Ok((plain, inverted))
    } else {
        Err(SrdoFaultCause::TransmitHalvesNotInverted)
    }
}

/// Delivers a validated pair into the process image: plain data to the plain objects, inverted
/// data (as received) to the inverted objects.
///
/// Inlined always: its one caller is the receive hot path, where a call cost the pair the
/// saving and restoring of the callee's registers.
#[inline(always)]
pub fn deliver(image: &mut ProcessImage, mapping: &ResolvedMapping, plain: u64, inverted: u64) {
    let mut at = 0u32;
    let pairs = usize::from(mapping.pairs).min(mapping.plain.len());
    for (&plain_span, &inverted_span) in mapping.plain[..pairs].iter().zip(&mapping.inverted) {
        // Validation keeps every object inside the 8 payload bytes, so an object starts at
        // byte 0..=7 and the shift is below 64; the mask keeps a damaged mapping from
        // panicking (it then delivers wrong bytes, which validation has already excluded).
        let shift = (8 * at) & 63;
        let (plain_part, inverted_part) = (plain >> shift, inverted >> shift);
        // Both branches write the same bytes: this one only lets the compiler drop the
        // bounds checks of `put_le` and share the mask.
        if plain_span.len == inverted_span.len
            && plain_span.offset.max(inverted_span.offset) <= WINDOW_END
        {
            // Every pair of a valid mapping: both words lie in the image, one mask for both.
            image.put_le(plain_span, plain_part);
            image.put_le(inverted_span, inverted_part);
        } else {
            deliver_clamped(image, plain_span, inverted_span, plain_part, inverted_part);
        }
        at += u32::from(plain_span.len);
    }
}

/// One pair of [`deliver`] whose objects differ in length or whose 8-byte windows end past the
/// image (a damaged mapping). Cold: a valid mapping never comes here.
#[cold]
#[inline(never)]
fn deliver_clamped(
    image: &mut ProcessImage,
    plain_span: Span,
    inverted_span: Span,
    plain: u64,
    inverted: u64,
) {
    image.put_le(plain_span, plain);
    image.put_le(inverted_span, inverted);
}

/// Sets every object of a receive mapping to 0, the safe state (SC_REQ_05).
pub fn clear(image: &mut ProcessImage, mapping: &ResolvedMapping) {
    for pair in 0..usize::from(mapping.pairs).min(mapping.plain.len()) {
        image.clear(mapping.plain[pair]);
        image.clear(mapping.inverted[pair]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::safety::types::Direction;

    /// SCT and SRVT of the consumers, in ms as their records hold them.
    const SCT_MS: u16 = 50;
    const SRVT_MS: u8 = 20;
    /// The identifiers of the producers.
    fn identifiers() -> CobIdPair {
        CobIdPair::new(0x101, 0x102).expect("valid pair")
    }
    const fn at(micros: u64) -> Instant {
        Instant::from_micros(micros)
    }
    fn bytes(value: u64) -> [u8; 8] {
        value.to_le_bytes()
    }

    /// What `gather` did before it copied whole windows: each object's bytes alone, into
    /// zeroed payloads. The reference the window copy is held to.
    fn gather_by_bytes(
        image: &ProcessImage,
        mapping: &ResolvedMapping,
    ) -> Result<(u64, u64), SrdoFaultCause> {
        let mut plain = [0u8; 8];
        let mut inverted = [0u8; 8];
        let mut at = 0usize;
        for pair in 0..usize::from(mapping.pairs).min(mapping.plain.len()) {
            let source = image.get(mapping.plain[pair]);
            let mirror = image.get(mapping.inverted[pair]);
            let end = (at + source.len()).min(8);
            if mirror.len() != source.len() {
                return Err(SrdoFaultCause::TransmitHalvesNotInverted);
            }
            plain[at..end].copy_from_slice(&source[..end - at]);
            inverted[at..end].copy_from_slice(&mirror[..end - at]);
            at = end;
        }
        let (plain, inverted) = (u64::from_le_bytes(plain), u64::from_le_bytes(inverted));
        if is_inverse(plain, inverted, mapping.len) {
            Ok((plain, inverted))
        } else {
            Err(SrdoFaultCause::TransmitHalvesNotInverted)
        }
    }

    static ONE_OBJECT: [crate::process_image::AppObject; 1] = [crate::process_image::AppObject {
        address: crate::canopen::od::Address::new(0x6000, 1),
        len: 1,
        access: crate::process_image::Access::ReadOnly,
        mappable: crate::process_image::Mappable::Transmit,
    }];

    proptest::proptest! {
        /// EN 50325-5 7.1.1: the transmit path's window copy gathers what the byte copy of
        /// each object gathers, valid pair or fault, on any mapping: valid ones (the inverted
        /// objects 32 bytes on, holding the complement), objects at the end of the image
        /// (no whole window there), past it, longer than 8 bytes or than the payload, halves
        /// of unequal length, and a pair count beyond the spans.
        #[test]
        fn en50325_5_7_1_1_gather_gives_what_the_byte_copy_of_each_object_gives(
            low in proptest::collection::vec(proptest::num::u8::ANY, 32),
            flipped in 0usize..40,
            spans in proptest::collection::vec(
                (0u8..70, 0u8..11, proptest::bool::weighted(0.8), 0u8..70, 0u8..11),
                8,
            ),
            pairs in 0u8..10,
            len in 0u8..10,
        ) {
            let mut image = ProcessImage::new(&ONE_OBJECT).unwrap();
            let mut bytes = [0u8; crate::process_image::PROCESS_IMAGE_LEN];
            for (at, &byte) in low.iter().enumerate() {
                bytes[at] = byte;
                bytes[at + 32] = !byte;
            }
            if let Some(byte) = bytes.get_mut(flipped) {
                *byte ^= 0x10;
            }
            image.set(Span { offset: 0, len: 64 }, &bytes);
            let mut mapping = ResolvedMapping::EMPTY;
            for (pair, &(offset, span_len, valid, other, other_len)) in spans.iter().enumerate() {
                mapping.plain[pair] = Span { offset, len: span_len };
                mapping.inverted[pair] = if valid {
                    Span { offset: offset.saturating_add(32), len: span_len }
                } else {
                    Span { offset: other, len: other_len }
                };
            }
            mapping.pairs = pairs;
            mapping.len = len;
            proptest::prop_assert_eq!(gather(&image, &mapping), gather_by_bytes(&image, &mapping));
        }
    }

    #[test]
    fn en50325_5_7_1_1_inverse_check_covers_exactly_the_mapped_bytes() {
        assert!(is_inverse(0x12, 0xED, 1));
        assert!(
            is_inverse(0x12, 0xFFFF_FFED, 1),
            "bytes beyond the mapping do not count"
        );
        assert!(!is_inverse(0x12, 0xEC, 1));
        assert!(is_inverse(0x0123_4567_89AB_CDEF, !0x0123_4567_89AB_CDEF, 8));
        assert!(!is_inverse(
            0x0123_4567_89AB_CDEF,
            !0x0123_4567_89AB_CDEF ^ (1 << 63),
            8
        ));
    }

    #[test]
    fn en50325_5_7_1_2_a_valid_pair_restarts_sct() {
        let mut consumer = Consumer::start(at(0), SCT_MS, SRVT_MS);
        assert_eq!(consumer.deadline(), at(50_000));
        consumer.on_plain(at(10_000), &bytes(0x5A), 1, 1).unwrap();
        assert_eq!(consumer.deadline(), at(30_000), "SRVT now the earliest");
        assert_eq!(
            consumer.on_inverted(at(10_200), &bytes(0xA5), 1, 1),
            Ok(InvertedOutcome::Pair {
                plain: 0x5A,
                inverted: 0xA5
            })
        );
        assert_eq!(consumer.deadline(), at(60_200));
    }

    #[test]
    fn en50325_5_7_1_2_sct_event_at_the_deadline_itself() {
        let consumer = Consumer::start(at(0), SCT_MS, SRVT_MS);
        assert_eq!(consumer.check_timers(at(49_999)), Ok(()));
        assert_eq!(
            consumer.check_timers(at(50_000)),
            Err(SrdoFaultCause::SctElapsed)
        );
    }

    #[test]
    fn en50325_5_7_1_2_srvt_event_and_late_frames_are_judged_on_arrival() {
        let mut consumer = Consumer::start(at(0), SCT_MS, SRVT_MS);
        consumer.on_plain(at(1_000), &bytes(1), 1, 1).unwrap();
        assert_eq!(
            consumer.check_timers(at(21_000)),
            Err(SrdoFaultCause::SrvtElapsed)
        );
        // Not polled in between: the late inverted frame itself is refused.
        assert_eq!(
            consumer.on_inverted(at(21_000), &bytes(0xFE), 1, 1),
            Err(SrdoFaultCause::SrvtElapsed)
        );
    }

    /// A consumer that took one pair (plain 1 at 1 us, its inverse at 2 us) after starting at 0:
    /// every deviation is a fault from then on.
    fn paired_once() -> Consumer {
        let mut consumer = Consumer::start(at(0), SCT_MS, SRVT_MS);
        consumer.on_plain(at(1), &bytes(1), 1, 1).unwrap();
        assert!(matches!(
            consumer.on_inverted(at(2), &bytes(0xFE), 1, 1),
            Ok(InvertedOutcome::Pair { .. })
        ));
        consumer
    }

    #[test]
    fn cia304_9_5_order_is_checked_and_double_receptions_are_discarded() {
        let mut consumer = paired_once();
        assert_eq!(
            consumer.on_inverted(at(11), &bytes(0xFE), 1, 1),
            Ok(InvertedOutcome::Discarded(Discarded::InvertedWithoutPlain))
        );
        assert_eq!(consumer.deadline(), at(50_002), "SCT keeps running");
        assert_eq!(
            consumer.on_plain(at(12), &bytes(1), 1, 1),
            Ok(PlainOutcome::Pending)
        );
        assert_eq!(
            consumer.on_plain(at(13), &bytes(1), 1, 1),
            Ok(PlainOutcome::Discarded(Discarded::PlainRepeated))
        );
        assert_eq!(consumer.deadline(), at(20_012), "SRVT of the first copy");
        for (data, dlc) in [(2, 1), (1, 2), (0x0101, 2)] {
            let mut copy = consumer;
            assert_eq!(
                copy.on_plain(at(14), &bytes(data), dlc, 1),
                Err(SrdoFaultCause::PlainRepeated),
                "{data:#x} length {dlc}"
            );
        }
        assert_eq!(
            consumer.on_inverted(at(15), &bytes(0xFE), 1, 1),
            Ok(InvertedOutcome::Pair {
                plain: 1,
                inverted: 0xFE
            })
        );
        assert_eq!(
            consumer.on_inverted(at(16), &bytes(0xFE), 1, 1),
            Ok(InvertedOutcome::Discarded(Discarded::InvertedWithoutPlain)),
            "a repeat of the inverted frame"
        );
        assert_eq!(consumer.deadline(), at(50_015));
    }

    #[test]
    fn en50325_5_7_1_3_short_frames_are_not_processed() {
        let mut consumer = Consumer::start(at(0), SCT_MS, SRVT_MS);
        assert_eq!(
            consumer.on_plain(at(1), &bytes(1), 1, 2),
            Err(SrdoFaultCause::TooShort)
        );
        consumer.on_plain(at(2), &bytes(0x0201), 2, 2).unwrap();
        assert_eq!(
            consumer.on_inverted(at(3), &bytes(0xFDFE), 1, 2),
            Err(SrdoFaultCause::TooShort)
        );
    }

    #[test]
    fn en50325_5_7_1_3_longer_frames_use_only_the_mapped_bytes() {
        let mut consumer = Consumer::start(at(0), SCT_MS, SRVT_MS);
        consumer
            .on_plain(at(1), &[0x01, 0xAA, 0xBB, 0, 0, 0, 0, 0], 3, 1)
            .unwrap();
        let Ok(InvertedOutcome::Pair { plain, inverted }) =
            consumer.on_inverted(at(2), &[0xFE, 0x00, 0x00, 0, 0, 0, 0, 0], 3, 1)
        else {
            panic!("a valid pair");
        };
        assert_eq!((plain as u8, inverted as u8), (0x01, 0xFE));
    }

    #[test]
    fn en50325_5_7_1_1_not_inverted_data_is_refused_bit_by_bit() {
        for bit in 0..64 {
            let mut consumer = Consumer::start(at(0), SCT_MS, SRVT_MS);
            consumer.on_plain(at(1), &bytes(0), 8, 8).unwrap();
            consumer.on_inverted(at(2), &bytes(!0), 8, 8).unwrap();
            let plain = 0x0123_4567_89AB_CDEFu64;
            consumer.on_plain(at(3), &bytes(plain), 8, 8).unwrap();
            let wrong = !plain ^ (1 << bit);
            assert_eq!(
                consumer.on_inverted(at(4), &bytes(wrong), 8, 8),
                Err(SrdoFaultCause::NotInverted),
                "bit {bit}"
            );
        }
    }

    /// CiA 304 9.5, EN 50325-5 7.1.2 and 8.2.2: before its first pair since entering
    /// Operational, a consumer takes a plain frame with other data (or another length) for
    /// the producer's next one: the pending frame (the ended epoch's, say, whose inverse
    /// nobody sends) is marked invalid and replaced. SRVT still counts from the first plain
    /// frame, so the first pair is due as early as ever; its inverse alone completes it; the
    /// replaced frame's inverse is discarded too. Once a pair is complete, the same order is a
    /// sequence error again.
    #[test]
    fn cia304_9_5_before_the_first_pair_a_plain_frame_with_other_data_replaces_the_pending_one() {
        let mut consumer = Consumer::start(at(0), SCT_MS, SRVT_MS);
        consumer.on_plain(at(1_000), &bytes(1), 1, 1).unwrap();
        for (data, dlc) in [(0, 1), (0x0100, 2), (0, 1)] {
            assert_eq!(
                consumer.on_plain(at(1_500), &bytes(data), dlc, 1),
                Ok(PlainOutcome::Discarded(
                    Discarded::PlainReplacedBeforeFirstPair
                )),
                "{data:#x} length {dlc}"
            );
        }
        assert_eq!(
            consumer.on_plain(at(1_600), &bytes(0), 1, 1),
            Ok(PlainOutcome::Discarded(Discarded::PlainRepeated)),
            "an exact repeat of the frame that replaced it"
        );
        assert_eq!(
            consumer.deadline(),
            at(21_000),
            "SRVT of the first plain frame"
        );
        let mut late = consumer;
        assert_eq!(
            late.on_inverted(at(21_000), &bytes(0xFF), 1, 1),
            Err(SrdoFaultCause::SrvtElapsed),
            "the first pair is due within SRVT of the first plain frame"
        );
        assert_eq!(
            consumer.on_inverted(at(1_700), &bytes(0xFE), 1, 1),
            Ok(InvertedOutcome::Discarded(
                Discarded::InvertedNotPairedBeforeFirstPair
            )),
            "the replaced frame's inverse"
        );
        assert_eq!(
            consumer.on_inverted(at(1_800), &bytes(0xFF), 1, 1),
            Ok(InvertedOutcome::Pair {
                plain: 0,
                inverted: 0xFF
            })
        );
        consumer.on_plain(at(2_000), &bytes(0), 1, 1).unwrap();
        assert_eq!(
            consumer.on_plain(at(2_100), &bytes(1), 1, 1),
            Err(SrdoFaultCause::PlainRepeated),
            "after the first pair"
        );
    }

    /// EN 50325-5 7.1.1 and 7.1.2, CiA 304 9.5 (bit by bit): before the first pair an inverted
    /// frame that is not the inverse of the pending plain frame, in any bit, is never
    /// delivered: the plain frame stays pending, and without its inverse the SRVT event
    /// follows at the same instant as it would without that frame, or its exact inverse
    /// completes the pair. A frame too short is refused before the first pair as after it.
    #[test]
    fn en50325_5_7_1_1_before_the_first_pair_a_wrong_inverse_is_never_delivered_and_srvt_ends_it() {
        let plain = 0x0123_4567_89AB_CDEFu64;
        for bit in 0..64 {
            let mut consumer = Consumer::start(at(0), SCT_MS, SRVT_MS);
            consumer.on_plain(at(1), &bytes(plain), 8, 8).unwrap();
            let wrong = !plain ^ (1 << bit);
            assert_eq!(
                consumer.on_inverted(at(2), &bytes(wrong), 8, 8),
                Ok(InvertedOutcome::Discarded(
                    Discarded::InvertedNotPairedBeforeFirstPair
                )),
                "bit {bit}"
            );
            assert_eq!(consumer.check_timers(at(20_000)), Ok(()), "bit {bit}");
            let mut late = consumer;
            assert_eq!(
                late.check_timers(at(20_001)),
                Err(SrdoFaultCause::SrvtElapsed),
                "bit {bit}"
            );
            assert_eq!(
                late.on_inverted(at(20_001), &bytes(!plain), 8, 8),
                Err(SrdoFaultCause::SrvtElapsed),
                "bit {bit}"
            );
            assert_eq!(
                consumer.on_inverted(at(3), &bytes(!plain), 8, 8),
                Ok(InvertedOutcome::Pair {
                    plain,
                    inverted: !plain
                }),
                "bit {bit}"
            );
        }
        let mut consumer = Consumer::start(at(0), SCT_MS, SRVT_MS);
        consumer.on_plain(at(1), &bytes(0x0201), 2, 2).unwrap();
        assert_eq!(
            consumer.on_plain(at(2), &bytes(0x03), 1, 2),
            Err(SrdoFaultCause::TooShort)
        );
        assert_eq!(
            consumer.on_inverted(at(3), &bytes(0xFE), 1, 2),
            Err(SrdoFaultCause::TooShort)
        );
    }

    /// A validated SRDO with these times and identifiers, its mapping empty (not looked at).
    fn valid(direction: Direction, cycle_ms: u16, srvt_ms: u8, first: u32) -> ValidSrdo {
        ValidSrdo {
            direction,
            cob_ids: CobIdPair::new(first, first + 1).expect("valid pair"),
            cycle_time: Duration::from_millis(u64::from(cycle_ms)),
            srvt: Duration::from_millis(u64::from(srvt_ms)),
            mapping: ResolvedMapping::EMPTY,
        }
    }

    /// What the integrity check asks: a consumer runs with its record's SCT and SRVT and with
    /// no others, a producer with its record's refresh time and identifiers.
    #[test]
    fn en50325_5_8_3_1_producer_and_consumer_run_with_their_records_values() {
        let consumer = Consumer::start(at(0), SCT_MS, SRVT_MS);
        assert_eq!(consumer.sct(), Duration::from_millis(50));
        assert_eq!(consumer.srvt(), Duration::from_millis(20));
        assert!(consumer.runs_with(&valid(Direction::Receive, 50, 20, 0x101)));
        assert!(!consumer.runs_with(&valid(Direction::Receive, 51, 20, 0x101)));
        assert!(!consumer.runs_with(&valid(Direction::Receive, 50, 21, 0x101)));
        let producer = Producer::start(at(0), 1, 25, identifiers());
        assert_eq!(producer.refresh(), Duration::from_millis(25));
        assert!(producer.runs_with(&valid(Direction::Transmit, 25, 1, 0x101)));
        assert!(!producer.runs_with(&valid(Direction::Transmit, 24, 1, 0x101)));
        assert!(!producer.runs_with(&valid(Direction::Transmit, 25, 1, 0x103)));
    }

    /// EN 50325-5 7.1.1: the plain payload on COB-ID 1, the inverted one on COB-ID 2, each as
    /// long as the mapping, nothing sent beyond it.
    #[test]
    fn en50325_5_7_1_1_a_pair_goes_on_the_records_identifiers_with_the_mapped_length() {
        let producer = Producer::start(at(0), 1, 25, identifiers());
        let [plain, inverted] = producer.frames(0x1122_3344_5566_7788, !0x5566_7788, 3);
        assert_eq!(plain.id().raw(), 0x101);
        assert_eq!(inverted.id().raw(), 0x102);
        assert_eq!(plain.data(), &[0x88, 0x77, 0x66]);
        assert_eq!(inverted.data(), &[0x77, 0x88, 0x99]);
        assert_eq!(plain.raw_data(), &[0x88, 0x77, 0x66, 0, 0, 0, 0, 0]);
        assert_eq!(inverted.raw_data(), &[0x77, 0x88, 0x99, 0, 0, 0, 0, 0]);
        let [whole, _] = producer.frames(u64::MAX, 0, 8);
        assert_eq!(whole.data(), &[0xFF; 8]);
    }

    #[test]
    fn cia304_9_5_first_transmission_delayed_half_a_millisecond_per_node_id() {
        assert_eq!(
            Producer::start(at(1_000), 1, 25, identifiers()).deadline(at(1_000)),
            at(1_500)
        );
        assert_eq!(
            Producer::start(at(0), 64, 25, identifiers()).deadline(at(0)),
            at(32_000)
        );
    }

    #[test]
    fn en50325_5_6_2_1_cyclic_transmission_keeps_phase_and_events_go_at_once() {
        let mut producer = Producer::start(at(0), 2, 25, identifiers());
        assert!(!producer.due(at(999)));
        assert!(producer.due(at(1_000)));
        producer.sent(at(1_100));
        assert_eq!(
            producer.deadline(at(1_100)),
            at(26_000),
            "phase kept despite 100 µs lateness"
        );
        producer.mark_changed();
        assert!(producer.due(at(5_000)));
        producer.sent(at(5_000));
        assert_eq!(
            producer.deadline(at(5_000)),
            at(30_000),
            "event restarts the cycle"
        );
        producer.sent(at(90_000));
        assert_eq!(
            producer.deadline(at(90_000)),
            at(115_000),
            "a missed cycle restarts from now"
        );
    }
}
