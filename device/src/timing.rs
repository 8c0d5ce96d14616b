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
