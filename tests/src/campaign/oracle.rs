//! The campaigns' oracle: a bus monitor written from the standard's text, not from the
//! implementation, that judges from the frames on the bus and the consumer's outputs alone
//! whether an output left its safe state (or kept a non-safe value) on data that was not a
//! valid pair within SCT and SRVT.
//!
//! **Why it is independent.** It imports nothing from `shared::safety`, `shared::node` or
//! `dual_channel`: only the plain value types [`CanFrame`] and [`Instant`]/[`Duration`]
//! (identifier, length, data bytes; microseconds). It does its own decoding of SRDO frames
//! from the COB-IDs it is given ([`MonitoredSrdo`]), its own inversion check (bitwise NOT over
//! the mapped length), its own SRVT and SCT timing and its own reading of NMT and GFC frames.
//! The configuration it is given is the test's own statement of what was configured, not
//! read from the device (a test checks that the two agree: `campaign_oracle_configuration_…`).
//!
//! **Rules** (EN 50325-5 7.1.1, 7.1.2, 7.2.1; CiA 304 9.5), per receive SRDO of the consumer:
//!
//! 1. A *pair* is a plain frame on COB-ID 1 followed by a frame on COB-ID 2 whose first
//!    `len` data bytes are the bitwise NOT of the plain frame's, arriving less than SRVT
//!    after the plain frame (EN 50325-5 7.1.2: the SRVT has elapsed at the deadline itself).
//!    An exact copy of the pending plain frame is CAN double reception (ISO 11898-1) and
//!    ignored; an inverted frame with no plain frame pending is ignored (it cannot form a
//!    pair). A frame shorter than `len` bytes is an error; bytes beyond `len` are not
//!    mapped and not judged (EN 50325-5 7.1.3: a longer frame is used up to the mapped length).
//! 2. **Errors** the standard requires the safe state for: a second plain frame with other
//!    data while one is pending (sequence, CiA 304 9.5), an inverted frame that is not the
//!    inverse (EN 50325-5 7.1.1), a short frame, SRVT elapsed with a plain frame pending, SCT
//!    elapsed without a pair (from the start of Operational, then from each pair), and a GFC
//!    (EN 50325-5 7.2.1). The safe state is latched until NMT reset node or reset
//!    communication (EN 50325-5 7.1.2 leaves how to leave it to the device; ours latches,
//!    SC_REQ_05), so from an error on the output must stay 0 until such a reset.
//! 3. **Justification.** While the consumer is Operational and no error has occurred, the
//!    output may carry only bits of the data of the newest pair *sent by the producer*
//!    (the monitor sees which participant put a frame on the bus, as one tap per node's
//!    cable would), and only until SCT after it; any later pair, whoever sent it, may only
//!    lower it (an output follows data towards 0). A well-formed pair from anyone else
//!    (replayed, inserted, masquerading) justifies nothing.
//!
//! Outputs are judged with an allowance of [`REACTION`] for every lowering the rules
//! require: the device handles a frame or a deadline in the step it occurs, and the
//! allowance covers the link exchange when one channel's receive path is slower. Raising an
//! output is never allowed ahead of its pair.

use shared::{CanFrame, Duration, Instant};

/// How long after the rules require a lower output the consumer's output may still show
/// the higher value (see the module documentation).
pub const REACTION: Duration = Duration::from_millis(1);

/// NMT commands are on identifier 000h (CiA 301 7.2.8.3.1), GFC on 001h (EN 50325-5 7.2.1).
const NMT_ID: u16 = 0x000;
const GFC_ID: u16 = 0x001;

/// A receive SRDO as configured in the consumer: what the monitor watches.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MonitoredSrdo {
    /// The consumer's node-ID (NMT commands addressed to it or to all count).
    pub consumer: u8,
    /// COB-ID 1, the plain frame.
    pub plain_id: u16,
    /// COB-ID 2, the inverted frame.
    pub inverted_id: u16,
    /// Mapped data bytes in each frame.
    pub len: usize,
    /// Safeguard cycle time.
    pub sct: Duration,
    /// Safety related object validation time.
    pub srvt: Duration,
    /// The bus participants of the producing node (its two channels).
    pub producer: [usize; 2],
}

/// One frame as the monitor saw it: when it was complete on the bus, what, from whom.
pub type Observed = (Instant, CanFrame, usize);

/// A violation the oracle found.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Violation {
    /// When.
    pub at: Instant,
    /// The output value at that time.
    pub output: u64,
    /// What the rules allowed at that time (bits).
    pub allowed: u64,
    /// Why, in words.
    pub why: String,
}

/// What the oracle concluded.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Judgement {
    /// Outputs that were not justified (must be empty).
    pub violations: Vec<Violation>,
    /// The first bus-level error the rules require the safe state for, with its reason.
    pub first_error: Option<(Instant, &'static str)>,
}

/// What the rules allow on the output from a point in time on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Allowed {
    from: u64,
    bits: u64,
    why: &'static str,
}

/// The monitor's state while it replays the bus (times in µs).
struct Monitor {
    srdo: MonitoredSrdo,
    operational: bool,
    latched: bool,
    /// The pending plain frame.
    pending: Option<Pending>,
    /// SCT deadline (from Operational entry, then from each pair, whoever sent it: the
    /// consumer cannot tell senders apart).
    sct_deadline: u64,
    /// The newest pair sent by the producer: (arrival, data).
    genuine: Option<(u64, u64)>,
    /// Bits every pair since the genuine one left set (any sender).
    mask: u64,
    /// Change points of what is allowed.
    allowed: Vec<Allowed>,
    first_error: Option<(u64, &'static str)>,
}

/// A plain frame waiting for its inverted partner.
#[derive(Clone, Copy)]
struct Pending {
    at: u64,
    mapped: u64,
    dlc: u8,
    raw: [u8; 8],
    from: usize,
}

impl Monitor {
    fn new(srdo: MonitoredSrdo) -> Self {
        Monitor {
            srdo,
            operational: false,
            latched: false,
            pending: None,
            sct_deadline: u64::MAX,
            genuine: None,
            mask: u64::MAX,
            allowed: vec![Allowed {
                from: 0,
                bits: 0,
                why: "not Operational",
            }],
            first_error: None,
        }
    }

    fn current(&self, now: u64) -> u64 {
        if !self.operational || self.latched {
            return 0;
        }
        match self.genuine {
            Some((at, data)) if now < at + self.srdo.sct.as_micros() => data & self.mask,
            _ => 0,
        }
    }

    fn record(&mut self, now: u64, why: &'static str) {
        let bits = self.current(now);
        if self.allowed.last().is_none_or(|last| last.bits != bits) {
            self.allowed.push(Allowed {
                from: now,
                bits,
                why,
            });
        }
    }

    fn error(&mut self, at: u64, why: &'static str) {
        if !self.operational || self.latched {
            return;
        }
        if self.first_error.is_none() {
            self.first_error = Some((at, why));
        }
        self.latched = true;
        self.pending = None;
        self.record(at, why);
    }

    /// The deadlines that elapse up to and including `now` (a deadline at exactly `now` has
    /// elapsed: EN 50325-5 7.1.2 as the device reads it, docs/overview.md "timers fire at the deadline
    /// itself"), in time order.
    fn elapse(&mut self, now: u64) {
        loop {
            if !self.operational || self.latched {
                return;
            }
            let srvt = self
                .pending
                .map_or(u64::MAX, |pending| pending.at + self.srdo.srvt.as_micros());
            let justified_until = self
                .genuine
                .map_or(u64::MAX, |(at, _)| at + self.srdo.sct.as_micros());
            let next = srvt.min(self.sct_deadline).min(justified_until);
            if next > now {
                return;
            }
            if next == srvt {
                self.error(srvt, "SRVT elapsed with a plain frame pending");
            } else if next == self.sct_deadline {
                self.error(next, "SCT elapsed without a valid pair");
            } else {
                // The newest genuine pair is older than SCT (a foreign pair kept SCT
                // running): it justifies nothing any more.
                self.genuine = None;
                self.record(next, "newest pair from the producer older than SCT");
            }
        }
    }

    fn reset(&mut self, now: u64, why: &'static str, clear_latch: bool) {
        self.operational = false;
        if clear_latch {
            self.latched = false;
        }
        self.pending = None;
        self.genuine = None;
        self.mask = u64::MAX;
        self.sct_deadline = u64::MAX;
        self.record(now, why);
    }

    fn frame(&mut self, now: u64, frame: &CanFrame, from: usize) {
        self.elapse(now);
        let id = frame.id().raw();
        let data = frame.data();
        if frame.is_remote() {
            return;
        }
        if id == NMT_ID && data.len() == 2 {
            if data[1] != 0 && data[1] != self.srdo.consumer {
                return;
            }
            match data[0] {
                0x01 if !self.operational => {
                    self.operational = true;
                    self.sct_deadline = now + self.srdo.sct.as_micros();
                    self.genuine = None;
                    self.mask = u64::MAX;
                    self.record(now, "NMT start");
                }
                0x02 | 0x80 => self.reset(now, "NMT stop or pre-operational", false),
                0x81 | 0x82 => self.reset(now, "NMT reset", true),
                _ => {}
            }
            return;
        }
        if !self.operational || self.latched {
            return;
        }
        if id == GFC_ID {
            self.error(now, "GFC on the bus");
            return;
        }
        let len = self.srdo.len;
        let mapped = |bytes: &[u8]| -> u64 {
            let mut raw = [0u8; 8];
            raw[..len].copy_from_slice(&bytes[..len]);
            u64::from_le_bytes(raw)
        };
        let all_mapped: u64 = if len >= 8 {
            u64::MAX
        } else {
            (1u64 << (8 * len)) - 1
        };
        if id == self.srdo.plain_id {
            if let Some(pending) = self.pending {
                if pending.dlc == frame.dlc() && pending.raw == *frame.raw_data() {
                    return; // CAN double reception: ignored
                }
                self.error(now, "second plain frame with other data (sequence)");
                return;
            }
            if data.len() < len {
                self.error(now, "plain frame shorter than its mapping");
                return;
            }
            self.pending = Some(Pending {
                at: now,
                mapped: mapped(data),
                dlc: frame.dlc(),
                raw: *frame.raw_data(),
                from,
            });
        } else if id == self.srdo.inverted_id {
            let Some(pending) = self.pending else {
                return; // no plain frame pending: it cannot form a pair
            };
            if data.len() < len {
                self.error(now, "inverted frame shorter than its mapping");
                return;
            }
            if mapped(data) != !pending.mapped & all_mapped {
                self.error(now, "inverted frame is not the inverse of the plain frame");
                return;
            }
            self.pending = None;
            self.sct_deadline = now + self.srdo.sct.as_micros();
            let genuine =
                self.srdo.producer.contains(&from) && self.srdo.producer.contains(&pending.from);
            if genuine {
                self.genuine = Some((now, pending.mapped));
                self.mask = u64::MAX;
                self.record(now, "valid pair from the producer");
            } else {
                self.mask &= pending.mapped;
                self.record(now, "valid pair from another sender (justifies nothing)");
            }
        }
    }

    /// What was allowed at `t` (the change point in force at `t`).
    fn allowed_at(&self, t: u64) -> Allowed {
        let index = self.allowed.partition_point(|change| change.from <= t);
        self.allowed[index.saturating_sub(1)]
    }

    /// The bits allowed at some point of `[t - allowance, t]`: a lowering the rules require
    /// may take up to `allowance` ([`REACTION`] on the host simulation); a raise is allowed
    /// only from its pair on.
    fn allowed_within_reaction(&self, t: u64, allowance: Duration) -> u64 {
        let start = t.saturating_sub(allowance.as_micros());
        let mut bits = self.allowed_at(start).bits;
        for change in &self.allowed {
            if change.from > start && change.from <= t {
                bits |= change.bits;
            }
        }
        bits
    }
}

/// Judges the outputs of one receive SRDO against the bus.
///
/// `frames` are the frames as delivered on the bus, in time order; `outputs` are the changes
/// of each output channel of the consumer `(time, channel, value)` (every channel starts at
/// 0, the safe state; the effective output is their bitwise AND, relays in series);
/// everything up to `end` is judged.
pub fn judge(
    srdo: MonitoredSrdo,
    frames: &[Observed],
    outputs: &[(Instant, usize, u64)],
    end: Instant,
) -> Judgement {
    judge_with_allowance(srdo, frames, outputs, end, REACTION)
}

/// [`judge`] with another allowance than [`REACTION`] for a lowering the rules require:
/// for outputs observed on another clock than the frames', the bound of the two clocks'
/// difference added (the emulated network's, `super::recorded::EMULATED_ALLOWANCE`). The
/// rules are the same; a raise ahead of its pair on the frames' clock stays a violation.
pub fn judge_with_allowance(
    srdo: MonitoredSrdo,
    frames: &[Observed],
    outputs: &[(Instant, usize, u64)],
    end: Instant,
    allowance: Duration,
) -> Judgement {
    let mut monitor = Monitor::new(srdo);
    // In time order (stable: frames at the same instant keep the bus's order), whatever
    // order the caller recorded them in.
    let mut frames = frames.to_vec();
    frames.sort_by_key(|(at, ..)| *at);
    for (at, frame, from) in &frames {
        monitor.frame(at.as_micros(), frame, *from);
    }
    monitor.elapse(end.as_micros());
    // The effective output as change points.
    let mut channels: Vec<u64> = Vec::new();
    let mut effective: Vec<(u64, u64)> = vec![(0, 0)];
    for (at, channel, value) in outputs {
        if channels.len() <= *channel {
            channels.resize(channel + 1, 0);
        }
        channels[*channel] = *value;
        let value = if channels.len() < 2 {
            0 // one channel alone never drives the output (two relays in series)
        } else {
            channels.iter().fold(u64::MAX, |acc, v| acc & v)
        };
        let at = at.as_micros();
        match effective.last_mut() {
            Some(last) if last.0 == at => last.1 = value,
            _ => effective.push((at, value)),
        }
    }
    let output_at = |t: u64| {
        let index = effective.partition_point(|(from, _)| *from <= t);
        effective[index.saturating_sub(1)].1
    };
    // Check at every output change and wherever an allowance has just run out.
    let mut checks: Vec<u64> = effective.iter().map(|(at, _)| *at).collect();
    checks.extend(
        monitor
            .allowed
            .iter()
            .map(|change| change.from + allowance.as_micros()),
    );
    checks.retain(|t| *t <= end.as_micros());
    checks.sort_unstable();
    checks.dedup();
    let mut violations = Vec::new();
    for t in checks {
        let output = output_at(t);
        let allowed = monitor.allowed_within_reaction(t, allowance);
        if output & !allowed != 0 {
            let rule = monitor.allowed_at(t);
            violations.push(Violation {
                at: Instant::from_micros(t),
                output,
                allowed,
                why: format!(
                    "output {output:#x} at {t} µs, allowed {allowed:#x} ({} since {} µs)",
                    rule.why, rule.from
                ),
            });
        }
    }
    Judgement {
        violations,
        first_error: monitor
            .first_error
            .map(|(at, why)| (Instant::from_micros(at), why)),
    }
}
