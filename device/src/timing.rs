//! The device's own timing: how often a channel samples its input, how long the two channels'
//! samples may differ before a frame goes anyway, and the link between the channels. The
//! channels run with these values and the tool's response-time calculation adds them up, so
//! both read them here.

use shared::Duration;

/// How often each channel samples its input pins: the channel loop reads them at least this
/// often.
pub const INPUT_SAMPLE_PERIOD: Duration = Duration::from_millis(1);

/// How long a transmit SRDO frame with changed data waits for the other channel's sample to
/// agree, and how long channel B accepts its previous sample or waits for its next one and
/// for channel A's announcement of a plain frame. It must stay well below the consumers'
/// smallest SRVT (the inverted frame can follow the plain frame up to one window late) and
/// above the link latency between the channels ([`LINK_BAUD`]).
pub const SAMPLE_WINDOW: Duration = Duration::from_millis(5);

/// The baud rate of the link USART between the two channels (bit/s).
pub const LINK_BAUD: u32 = 1_000_000;

/// Bits one byte takes on the link: a start bit, eight data bits and a stop bit.
const LINK_BITS_PER_BYTE: u64 = 10;

/// One byte on the link at [`LINK_BAUD`].
pub const LINK_BYTE_TIME: Duration =
    Duration::from_micros(LINK_BITS_PER_BYTE * 1_000_000 / LINK_BAUD as u64);

/// Link messages that may be ahead of one message in a channel's link transmit queue, and
/// the message itself: a heartbeat and the probe sent with it, the echo of the other
/// channel's probe, an input digest sent at an input change, a verdict on a received pair.
pub const LINK_MESSAGES_AHEAD: u64 = 6;

/// The longest frame on the link, bytes, its delimiter included: the link's framing of its
/// longest message (`dual_channel::link::MAX_WIRE`, which checks at compile time that it
/// is this figure).
pub const LINK_LONGEST_FRAME: usize = 23;

#[cfg(test)]
mod tests {
    use super::*;

    /// The sample window must stay above the link latency between the channels: channel B's
    /// input digest reaches channel A behind every message that may be ahead of it, each of
    /// the longest frame's length, and must still arrive within the window.
    #[test]
    fn the_sample_window_holds_the_link_queue_and_a_sample_period() {
        let queue = LINK_MESSAGES_AHEAD * LINK_LONGEST_FRAME as u64 * LINK_BYTE_TIME.as_micros();
        assert!(queue + INPUT_SAMPLE_PERIOD.as_micros() < SAMPLE_WINDOW.as_micros());
    }

    /// One byte takes ten bit times at the link's baud rate, to the microsecond.
    #[test]
    fn a_link_byte_is_ten_bit_times() {
        assert_eq!(
            u128::from(LINK_BYTE_TIME.as_micros()) * u128::from(LINK_BAUD),
            10 * 1_000_000
        );
    }
}
