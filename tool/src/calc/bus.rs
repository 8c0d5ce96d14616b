//! Frame times and bus arbitration on CAN: worst-case frame lengths with stuff bits
//! (ISO 11898-1 10.5), the share of the bus a set of periodic streams takes, and the longest
//! a frame can wait for the bus behind higher-priority traffic (fixed-priority,
//! non-preemptive response-time analysis of CAN, as in Davis, Burns, Bril and Lukkien,
//! "Controller Area Network schedulability analysis: refuted, revisited and revised", 2007).
//!
//! Pure functions of their arguments; nothing here reads a clock or a bus.

/// Bits a standard frame with `len` data bytes occupies at most (ISO 11898-1 10.5): start of
/// frame to the end of the CRC is 34 + 8·len bits, all subject to stuffing, at worst one
/// stuff bit after the first five equal bits and one after every four after that,
/// (34 + 8·len − 1) / 4; then the 13 fixed-form bits (CRC delimiter, ACK slot and delimiter,
/// end of frame, intermission). `len` above 8 counts as 8 (CANopen never sends more).
#[must_use]
pub fn worst_case_bits(len: u8) -> u32 {
    let len = u32::from(len.min(8));
    let stuffable = 34 + 8 * len;
    47 + 8 * len + (stuffable - 1) / 4
}

/// [`worst_case_bits`] in microseconds at `bit_rate` (bit/s), rounded up.
#[must_use]
pub fn frame_micros(len: u8, bit_rate: u32) -> u64 {
    (u64::from(worst_case_bits(len)) * 1_000_000).div_ceil(u64::from(bit_rate.max(1)))
}

/// One bit time in microseconds at `bit_rate`, rounded up (the release jitter of the
/// response-time analysis: a frame queued one bit after arbitration started waits for the
/// next).
#[must_use]
pub fn bit_micros(bit_rate: u32) -> u64 {
    1_000_000u64.div_ceil(u64::from(bit_rate.max(1)))
}

/// A periodic (or sporadic, with a shortest interval) stream of frames on one identifier.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Stream {
    /// The 11-bit identifier: lower wins arbitration.
    pub id: u16,
    /// Data bytes.
    pub len: u8,
    /// Period, or the shortest interval between two frames (µs), at least 1.
    pub period_us: u64,
}

impl Stream {
    /// Its worst-case share of the bus at `bit_rate` (0.25 = 25 %).
    #[must_use]
    pub fn utilisation(&self, bit_rate: u32) -> f64 {
        frame_micros(self.len, bit_rate) as f64 / self.period_us.max(1) as f64
    }
}

/// A traffic stream as a person writes it, `ID:LEN:PERIOD_MS` (e.g. `0x181:8:10`), that
/// does not read as one.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error(
    "{text:?} is not a stream ID:LEN:PERIOD_MS (identifier 0..=7FFh, 0 to 8 data bytes, a period above 0 ms, e.g. 0x181:8:10): {why}"
)]
pub struct StreamError {
    /// What was given.
    pub text: String,
    /// Which part is wrong.
    pub why: &'static str,
}

impl core::str::FromStr for Stream {
    type Err = StreamError;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let error = |why| StreamError {
            text: text.to_owned(),
            why,
        };
        let mut parts = text.split(':');
        let (Some(id), Some(len), Some(period), None) =
            (parts.next(), parts.next(), parts.next(), parts.next())
        else {
            return Err(error("it needs three parts"));
        };
        let id = match id.strip_prefix("0x").or_else(|| id.strip_prefix("0X")) {
            Some(hex) => u16::from_str_radix(hex, 16),
            None => id.parse(),
        }
        .ok()
        .filter(|id| *id <= 0x7FF)
        .ok_or_else(|| error("the identifier"))?;
        let len = len
            .parse()
            .ok()
            .filter(|len| *len <= 8)
            .ok_or_else(|| error("the length"))?;
        let period_ms: f64 = period
            .parse()
            .ok()
            .filter(|ms: &f64| ms.is_finite() && *ms > 0.0 && *ms <= 3.6e6)
            .ok_or_else(|| error("the period"))?;
        // Rounded down: a shorter period is the conservative reading.
        let period_us = ((period_ms * 1000.0) as u64).max(1);
        Ok(Stream { id, len, period_us })
    }
}

/// The worst-case share of the bus all `streams` take together at `bit_rate`.
#[must_use]
pub fn utilisation(streams: &[Stream], bit_rate: u32) -> f64 {
    streams.iter().map(|s| s.utilisation(bit_rate)).sum()
}

/// The longest a frame on identifier `id` waits from being queued until it wins arbitration,
/// at `bit_rate`, among `streams` (the frame's own stream may be among them; only streams
/// with a lower identifier delay it, and one frame of any other identifier, already on the
/// bus when it is queued, blocks it once: CAN does not preempt).
///
/// The queuing delay `w` is the least fixed point of
/// `w = B + Σ_{j: id_j < id} ⌈(w + τ) / T_j⌉ · C_j`, with `B` the longest frame of a stream
/// with a higher identifier (at least `blocking_len` bytes: a frame the plan does not list, a
/// heartbeat, an SDO, is 8 bytes at most), `τ` one bit time, `T_j` and `C_j` each
/// higher-priority stream's period and worst-case frame time. The iteration starts at `B`
/// and only grows, so it reaches the least fixed point or passes `limit_us`.
///
/// `None` when the higher-priority streams take the whole bus (no fixed point exists) or the
/// delay would exceed `limit_us`: the frame has no bounded delay the caller may rely on.
#[must_use]
pub fn queuing_delay(
    id: u16,
    streams: &[Stream],
    blocking_len: u8,
    bit_rate: u32,
    limit_us: u64,
) -> Option<u64> {
    let blocking = streams
        .iter()
        .filter(|s| s.id > id)
        .map(|s| frame_micros(s.len, bit_rate))
        .chain([frame_micros(blocking_len, bit_rate)])
        .max()
        .unwrap_or(0);
    let higher: Vec<&Stream> = streams.iter().filter(|s| s.id < id).collect();
    let tau = bit_micros(bit_rate);
    let mut delay = blocking;
    loop {
        let next = blocking
            + higher
                .iter()
                .map(|s| (delay + tau).div_ceil(s.period_us.max(1)) * frame_micros(s.len, bit_rate))
                .sum::<u64>();
        if next > limit_us {
            return None;
        }
        if next == delay {
            return Some(delay);
        }
        delay = next;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The boundaries of the stuffing formula: 0 and 8 data bytes, and 9 counts as 8.
    #[test]
    fn worst_case_frame_is_55_bits_empty_and_135_bits_with_eight_bytes() {
        assert_eq!(worst_case_bits(0), 55);
        assert_eq!(worst_case_bits(1), 65);
        assert_eq!(worst_case_bits(8), 135);
        assert_eq!(worst_case_bits(9), 135);
        assert_eq!(frame_micros(8, 1_000_000), 135);
        assert_eq!(frame_micros(1, 125_000), 520);
        // 55 bits at 500 kbit/s are 110 µs exactly; 65 bits at 250 kbit/s 260 µs.
        assert_eq!(frame_micros(0, 500_000), 110);
        assert_eq!(frame_micros(1, 250_000), 260);
    }

    /// With nothing else on the bus a frame waits only for the 8-byte frame that may
    /// already be on it.
    #[test]
    fn an_empty_bus_delays_by_one_frame_of_blocking() {
        assert_eq!(queuing_delay(0x101, &[], 8, 1_000_000, 10_000), Some(135));
        assert_eq!(queuing_delay(0x101, &[], 0, 1_000_000, 10_000), Some(55));
    }

    /// Lower-priority streams block once; higher-priority streams delay by every frame
    /// released within the busy window: the fixed point, by hand.
    #[test]
    fn higher_priority_frames_are_counted_in_the_busy_window() {
        // One 8-byte stream above, every 270 µs (50 % of the bus at 1 Mbit/s); blocking 135.
        let above = Stream {
            id: 0x090,
            len: 8,
            period_us: 270,
        };
        let below = Stream {
            id: 0x700,
            len: 1,
            period_us: 100_000,
        };
        // w0 = 135; w1 = 135 + ceil(136/270)·135 = 270; w2 = 135 + ceil(271/270)·135 = 405;
        // w3 = 135 + ceil(406/270)·135 = 405.
        assert_eq!(
            queuing_delay(0x101, &[above, below], 8, 1_000_000, 10_000),
            Some(405)
        );
        // The frame's own identifier and those below it never count as higher priority, and
        // the longest lower-priority frame blocks: the 1-byte stream's 65 µs.
        assert_eq!(
            queuing_delay(0x090, &[above, below], 0, 1_000_000, 10_000),
            Some(65)
        );
    }

    /// A bus the higher-priority traffic fills has no bound, and neither has a delay over
    /// the limit.
    #[test]
    fn a_saturated_bus_gives_no_bound() {
        let full = Stream {
            id: 0x090,
            len: 8,
            period_us: 135,
        };
        assert_eq!(queuing_delay(0x101, &[full], 8, 1_000_000, 1_000_000), None);
        let half = Stream {
            id: 0x090,
            len: 8,
            period_us: 270,
        };
        assert_eq!(queuing_delay(0x101, &[half], 8, 1_000_000, 404), None);
        assert_eq!(queuing_delay(0x101, &[half], 8, 1_000_000, 405), Some(405));
    }

    /// A stream reads from `ID:LEN:PERIOD_MS`; every wrong part is named.
    #[test]
    fn a_stream_reads_from_id_length_and_period() {
        let stream: Stream = "0x181:8:10".parse().unwrap();
        assert_eq!(
            stream,
            Stream {
                id: 0x181,
                len: 8,
                period_us: 10_000
            }
        );
        let stream: Stream = "144:0:0.27".parse().unwrap();
        assert_eq!(
            stream,
            Stream {
                id: 144,
                len: 0,
                period_us: 270
            }
        );
        for (text, why) in [
            ("0x800:8:10", "the identifier"),
            ("0x181:9:10", "the length"),
            ("0x181:8:0", "the period"),
            ("0x181:8", "it needs three parts"),
            ("0x181:8:10:1", "it needs three parts"),
        ] {
            assert_eq!(text.parse::<Stream>().unwrap_err().why, why, "{text}");
        }
        assert!(
            "1:2"
                .parse::<Stream>()
                .unwrap_err()
                .to_string()
                .starts_with("\"1:2\" is not a stream")
        );
    }

    #[test]
    fn utilisation_adds_the_streams() {
        let streams = [
            Stream {
                id: 0x090,
                len: 8,
                period_us: 270,
            },
            Stream {
                id: 0x700,
                len: 8,
                period_us: 1350,
            },
        ];
        assert!((utilisation(&streams, 1_000_000) - 0.6).abs() < 1e-12);
    }
}
