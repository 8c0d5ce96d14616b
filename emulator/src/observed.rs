//! What the emulator measures of an MCU from outside, as a test rig around a real board would
//! (a logic analyser on its sleep signal and on its link's receive line, a debugger watching
//! its stack pointer), for images that do not measure themselves (the shipped images have no
//! emulation wire to report on): sans-I/O trackers fed with virtual times.
//!
//! - [`Activations`]: the longest time from a wake-up of the core (from WFI or WFE) to its
//!   next sleep, interrupts included.
//! - [`LinkGaps`]: the longest time between the ends of two complete link messages reaching a
//!   channel's receive line from the other channel.
//! - [`stack_depth`]: the deepest stack, from the initial stack pointer and the lowest one seen.
//!
//! Each figure is "so far": the one in progress (an activation not yet ended, the time since
//! the last link message) counts, so that a hung core or a silent link shows at once.

use crate::time::Nanos;

/// The byte that ends every link message on the wire (COBS, `cobs_frames`): the encoding
/// leaves it out of every message's bytes.
const DELIMITER: u16 = 0;

/// The longest activation of a core: from a wake-up to the next sleep.
///
/// An activation starts when the core wakes from WFI or WFE and ends when it sleeps again
/// (WFI, WFE, or sleep-on-exit) or is reset. The run from a reset to the first sleep (the
/// boot) is no activation: nothing woke the core for it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Activations {
    /// When the core woke for the activation in progress (`None`: asleep, or booting).
    awake_since: Option<Nanos>,
    /// The longest activation that ended.
    longest: Nanos,
}

impl Activations {
    /// The core woke at `at`.
    pub fn woke(&mut self, at: Nanos) {
        self.awake_since = Some(at);
    }

    /// The core went to sleep at `at`: the activation in progress, if any, ends.
    pub fn slept(&mut self, at: Nanos) {
        if let Some(since) = self.awake_since.take() {
            self.longest = self.longest.max(at.saturating_sub(since));
        }
    }

    /// The core was reset at `at`: the activation in progress ends there (a loop that never
    /// slept again until the watchdog reset it was busy all that time), and the boot that
    /// follows is not one.
    pub fn reset(&mut self, at: Nanos) {
        self.slept(at);
    }

    /// The longest activation at virtual time `now`, the one in progress included.
    pub fn longest(&self, now: Nanos) -> Nanos {
        let current = self
            .awake_since
            .map_or(0, |since| now.saturating_sub(since));
        self.longest.max(current)
    }
}

/// The longest gap between two link messages received, from the end of one (its delimiter's
/// stop bit on the receive line) to the end of the next, once the first has come.
///
/// A message is complete at a delimiter that follows at least one other byte: two delimiters
/// in a row are an idle line, not a message (as `cobs_frames::Reassembler` reads them).
/// Whether a message decodes is the receiver's business; a broken one still shows the link
/// carrying something.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkGaps {
    /// Bytes other than the delimiter came since the last delimiter.
    in_message: bool,
    /// The end of the last complete message.
    last: Option<Nanos>,
    /// The longest gap between two complete messages.
    longest: Nanos,
}

impl LinkGaps {
    /// A word whose stop bit ended on the receive line at `at`.
    pub fn word(&mut self, word: u16, at: Nanos) {
        if word != DELIMITER {
            self.in_message = true;
            return;
        }
        if !std::mem::take(&mut self.in_message) {
            return;
        }
        if let Some(last) = self.last {
            self.longest = self.longest.max(at.saturating_sub(last));
        }
        self.last = Some(at);
    }

    /// The longest gap at virtual time `now`, the time since the last message included
    /// (0 until a first message came).
    pub fn longest(&self, now: Nanos) -> Nanos {
        let current = self.last.map_or(0, |last| now.saturating_sub(last));
        self.longest.max(current)
    }
}

/// The deepest stack in bytes: how far below `initial` (the stack pointer the reset loaded
/// from the vector table, the top of a full-descending stack) the lowest stack pointer seen,
/// `lowest`, went; 0 when it never went below.
pub fn stack_depth(initial: u32, lowest: u32) -> u32 {
    initial.saturating_sub(lowest)
}

/// Nanoseconds as whole milliseconds for a status line (rounded down, as the images' own
/// figures are), [`u16::MAX`] at most.
pub fn status_ms(at: Nanos) -> u16 {
    u16::try_from(at / 1_000_000).unwrap_or(u16::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Nanos = 1_000_000;

    /// A wake-up's length runs to the next sleep; the longest is kept, the time asleep and
    /// the boot before the first sleep are no part of it.
    #[test]
    fn an_activation_runs_from_a_wake_up_to_the_next_sleep() {
        let mut activations = Activations::default();
        // Booting: no wake-up yet.
        activations.slept(50 * MS);
        assert_eq!(activations.longest(60 * MS), 0);
        activations.woke(100 * MS);
        activations.slept(103 * MS);
        activations.woke(200 * MS);
        activations.slept(201 * MS);
        assert_eq!(activations.longest(500 * MS), 3 * MS);
        // A sleep without a wake-up before it (WFE with nothing pending) ends nothing.
        activations.slept(600 * MS);
        assert_eq!(activations.longest(700 * MS), 3 * MS);
    }

    /// A core that does not sleep again shows in the figure while it is awake, and a reset
    /// ends its activation at the reset.
    #[test]
    fn an_activation_in_progress_counts_and_a_reset_ends_it() {
        let mut activations = Activations::default();
        activations.woke(10 * MS);
        activations.slept(11 * MS);
        activations.woke(20 * MS);
        assert_eq!(activations.longest(25 * MS), 5 * MS);
        activations.reset(70 * MS);
        assert_eq!(activations.longest(500 * MS), 50 * MS);
        // The boot after the reset is not an activation.
        activations.slept(600 * MS);
        assert_eq!(activations.longest(600 * MS), 50 * MS);
    }

    /// COBS frames end at a zero byte; the gap runs from one message's delimiter to the
    /// next's, idle delimiters are not messages, and nothing counts before the first message.
    #[test]
    fn a_link_gap_runs_between_the_ends_of_two_messages() {
        let mut gaps = LinkGaps::default();
        // Idle delimiters before the first message: no message, no gap.
        gaps.word(0, MS);
        gaps.word(0, 2 * MS);
        assert_eq!(gaps.longest(3 * MS), 0);
        // A first message ends at 10 ms: the gaps start there.
        for (byte, at) in [(3, 9 * MS), (1, 9 * MS + 10_000), (0, 10 * MS)] {
            gaps.word(byte, at);
        }
        assert_eq!(gaps.longest(10 * MS), 0);
        // The next starts 5 ms later and ends at 16 ms: a gap of 6 ms between their ends.
        gaps.word(2, 15 * MS);
        assert_eq!(gaps.longest(15 * MS), 5 * MS, "the silence so far counts");
        gaps.word(0, 16 * MS);
        // An idle delimiter later does not end a message.
        gaps.word(0, 18 * MS);
        gaps.word(7, 19 * MS);
        gaps.word(0, 20 * MS);
        assert_eq!(gaps.longest(20 * MS), 6 * MS);
        // A link that falls silent: the time since the last message is the gap so far.
        assert_eq!(gaps.longest(120 * MS), 100 * MS);
    }

    /// The stack grows down from the initial stack pointer.
    #[test]
    fn the_stack_depth_is_measured_down_from_the_initial_stack_pointer() {
        assert_eq!(stack_depth(0x2002_0000, 0x2001_F000), 0x1000);
        assert_eq!(stack_depth(0x2002_0000, u32::MAX), 0, "no block seen yet");
    }

    #[test]
    fn status_milliseconds_round_down_and_saturate() {
        assert_eq!(status_ms(2_999_999), 2);
        assert_eq!(status_ms(Nanos::MAX), u16::MAX);
    }
}
