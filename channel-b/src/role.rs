//! Channel B's part in the pair (CiA 304 9.5, EN 50325-5 Annex A.4): silent on the bus except
//! for the inverted frame of each transmit SRDO, which it builds by its own path
//! ([`crate::diverse`]) and sends only after channel A's plain frame matched its own result bit
//! by bit. It follows SDO requests into its own copy of the object dictionary (the core does
//! that), and signs the configuration with its own CRC ([`crate::signature`]).
//!
//! # Discrepancy window
//!
//! The two channels sample their inputs independently, so around an input change channel A's
//! frame may carry a sample channel B has just replaced, or one B has not taken yet. Channel
//! B therefore accepts A's plain frame when it matches B's current inputs, or B's previous
//! inputs if they changed less than [`ChannelB::window`] ago; otherwise it holds the frame for
//! up to the window, waiting for its own next sample. Only a frame that matches none of these
//! is a discrepancy. The window must stay well below the smallest SRVT of the consumers (the
//! inverted frame may leave up to one window late); the default is 5 ms.

use crate::diverse::{DiverseError, InputTable, compare_and_invert};
use crate::signature::{Parameters, signature};
use dual_channel::runtime::{Role, fold_signatures};
use shared::canopen::od::Address;
use shared::safety::config::{SafetyConfig, SrdoRecord};
use shared::{CanFrame, CanId, Duration, Instant};

/// The default discrepancy window.
pub const DEFAULT_WINDOW: Duration = Duration::from_millis(5);

/// A plain frame channel B could not confirm yet.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Held {
    frame: CanFrame,
    srdo: u8,
    since: Instant,
}

/// Channel B's role: its own inputs, in its own layout, and the discrepancy window.
#[derive(Clone, Debug)]
pub struct ChannelB {
    inputs: InputTable,
    /// The inputs before the latest change, and when they were replaced.
    previous: Option<(InputTable, Instant)>,
    held: Option<Held>,
    window: Duration,
}

impl ChannelB {
    /// Channel B with the inputs it samples (index, sub-index, length in bytes).
    pub fn new(inputs: &[(u16, u8, u8)]) -> Result<Self, DiverseError> {
        let mut table = InputTable::new();
        for &(index, sub, len) in inputs {
            table.declare(index, sub, len)?;
        }
        Ok(ChannelB {
            inputs: table,
            previous: None,
            held: None,
            window: DEFAULT_WINDOW,
        })
    }

    /// The discrepancy window.
    pub fn window(&self) -> Duration {
        self.window
    }

    /// Sets the discrepancy window (keep it well below the smallest SRVT).
    pub fn set_window(&mut self, window: Duration) {
        self.window = window;
    }

    /// The inverted frame for `frame` if it matches `inputs`.
    fn confirm(frame: &CanFrame, record: &SrdoRecord, inputs: &InputTable) -> Option<CanFrame> {
        let mapping = &record.mapping[..usize::from(record.mapping_count).min(16)];
        let inverted = compare_and_invert(frame.data(), mapping, inputs).ok()?;
        let id = CanId::new((record.cob_id_2 & 0x7FF) as u16).ok()?;
        CanFrame::new(id, &inverted[..frame.data().len()]).ok()
    }
}

/// The transmit SRDO whose plain COB-ID is `id`, read by channel B itself from the raw
/// records (direction 1).
fn transmit_srdo<const N: usize>(config: &SafetyConfig<N>, id: u16) -> Option<(u8, &SrdoRecord)> {
    config
        .srdos
        .iter()
        .enumerate()
        .find(|(_, record)| record.direction == 1 && record.cob_id_1 & 0x7FF == u32::from(id))
        .map(|(position, record)| ((position + 1) as u8, record))
}

impl<const N: usize> Role<N> for ChannelB {
    fn outgoing(&mut self, _frame: CanFrame, _config: &SafetyConfig<N>) -> Option<CanFrame> {
        None
    }

    fn observe(
        &mut self,
        now: Instant,
        frame: &CanFrame,
        config: &SafetyConfig<N>,
    ) -> Result<Option<CanFrame>, u8> {
        if frame.is_remote() {
            return Ok(None);
        }
        let Some((srdo, record)) = transmit_srdo(config, frame.id().raw()) else {
            return Ok(None);
        };
        if let Some(held) = self.held.take() {
            // A new plain frame while the last one is unconfirmed: the last one stays
            // unconfirmed for good.
            return Err(held.srdo);
        }
        if let Some(inverted) = Self::confirm(frame, record, &self.inputs) {
            return Ok(Some(inverted));
        }
        let recent = self
            .previous
            .as_ref()
            .filter(|(_, replaced)| now.saturating_since(*replaced) < self.window);
        if let Some((previous, _)) = recent {
            if let Some(inverted) = Self::confirm(frame, record, previous) {
                return Ok(Some(inverted));
            }
        }
        self.held = Some(Held {
            frame: *frame,
            srdo,
            since: now,
        });
        Ok(None)
    }

    fn input(
        &mut self,
        now: Instant,
        address: Address,
        value: &[u8],
        config: &SafetyConfig<N>,
    ) -> Result<Option<CanFrame>, u8> {
        let mut bytes = [0u8; 8];
        let len = value.len().min(8);
        bytes[..len].copy_from_slice(&value[..len]);
        let before = self.inputs.clone();
        // An input B does not sample is not B's: its transmit check then fails, as it must.
        let _ = self
            .inputs
            .set(address.index, address.sub, u64::from_le_bytes(bytes));
        if self.inputs != before {
            self.previous = Some((before, now));
        }
        let Some(held) = self.held else {
            return Ok(None);
        };
        let Some((_, record)) = transmit_srdo(config, held.frame.id().raw()) else {
            self.held = None;
            return Err(held.srdo);
        };
        match Self::confirm(&held.frame, record, &self.inputs) {
            Some(inverted) => {
                self.held = None;
                Ok(Some(inverted))
            }
            None => Ok(None),
        }
    }

    fn reset(&mut self) {
        // The pair in progress is forgotten; the input samples are not (they are the pins).
        self.held = None;
    }

    fn poll(&mut self, now: Instant) -> Result<(), u8> {
        match self.held {
            Some(held) if shared::time::expired(held.since + self.window, now) => {
                self.held = None;
                Err(held.srdo)
            }
            _ => Ok(()),
        }
    }

    fn deadline(&self) -> Instant {
        self.held
            .map_or(Instant::NEVER, |held| held.since + self.window)
    }

    fn signature_digest(&self, config: &SafetyConfig<N>) -> u32 {
        fold_signatures(config.srdos.iter().map(|record| {
            signature(&Parameters {
                direction: record.direction,
                cycle_time: record.cycle_time,
                srvt: record.srvt,
                cob_id_1: record.cob_id_1,
                cob_id_2: record.cob_id_2,
                mapping: &record.mapping[..usize::from(record.mapping_count).min(16)],
            })
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> SafetyConfig<1> {
        SafetyConfig::<1>::predefined(1, &[0x6000_0108, 0x6001_0108], &[])
    }

    fn frame(id: u16, data: &[u8]) -> CanFrame {
        CanFrame::new(CanId::new(id).unwrap(), data).unwrap()
    }

    fn b_with(value: u8) -> ChannelB {
        let mut b = ChannelB::new(&[(0x6000, 1, 1)]).unwrap();
        b.input(Instant::ZERO, Address::new(0x6000, 1), &[value], &config())
            .unwrap();
        b
    }

    const T: Instant = Instant::from_millis(100);

    /// CiA 304 9.5: B answers A's plain frame with the inverted frame when its own input
    /// agrees; B never sends what its core produces.
    #[test]
    fn cia304_9_5_b_sends_the_inverted_frame_after_a_bit_exact_match() {
        let mut b = b_with(0x01);
        assert_eq!(
            b.observe(T, &frame(0x101, &[0x01]), &config()),
            Ok(Some(frame(0x102, &[0xFE])))
        );
        // Not a transmit SRDO's plain frame: nothing to do.
        assert_eq!(b.observe(T, &frame(0x102, &[0xFE]), &config()), Ok(None));
        assert_eq!(b.observe(T, &frame(0x701, &[0x05]), &config()), Ok(None));
        assert_eq!(b.outgoing(frame(0x581, &[0; 8]), &config()), None);
    }

    /// CiA 304 9.5: a frame that matches none of B's samples within the window is a
    /// discrepancy, reported with the SRDO number at the end of the window, and nothing is
    /// sent.
    #[test]
    fn cia304_9_5_a_lasting_difference_is_a_discrepancy() {
        let mut b = b_with(0x01);
        assert_eq!(b.observe(T, &frame(0x101, &[0x00]), &config()), Ok(None));
        assert_eq!(Role::<1>::deadline(&b), T + DEFAULT_WINDOW);
        assert_eq!(
            Role::<1>::poll(&mut b, T + Duration::from_micros(4_999)),
            Ok(())
        );
        assert_eq!(Role::<1>::poll(&mut b, T + DEFAULT_WINDOW), Err(1));
        assert_eq!(Role::<1>::deadline(&b), Instant::NEVER);
    }

    /// A's frame sampled just before B's input changed (B's previous sample, within the
    /// window) is confirmed; after the window it is not.
    #[test]
    fn a_frame_sampled_before_bs_change_is_confirmed_within_the_window() {
        let mut b = b_with(0x01);
        b.input(T, Address::new(0x6000, 1), &[0x00], &config())
            .unwrap();
        let soon = T + Duration::from_millis(1);
        assert_eq!(
            b.observe(soon, &frame(0x101, &[0x01]), &config()),
            Ok(Some(frame(0x102, &[0xFE])))
        );
        let late = T + DEFAULT_WINDOW;
        assert_eq!(b.observe(late, &frame(0x101, &[0x01]), &config()), Ok(None));
        assert_eq!(Role::<1>::poll(&mut b, late + DEFAULT_WINDOW), Err(1));
    }

    /// A's frame carrying a change B has not sampled yet is held, and sent as soon as B's
    /// own sample agrees.
    #[test]
    fn a_frame_ahead_of_bs_sample_is_held_until_b_agrees() {
        let mut b = b_with(0x00);
        assert_eq!(b.observe(T, &frame(0x101, &[0x01]), &config()), Ok(None));
        let sampled = T + Duration::from_millis(2);
        assert_eq!(
            b.input(sampled, Address::new(0x6000, 1), &[0x01], &config()),
            Ok(Some(frame(0x102, &[0xFE])))
        );
        assert_eq!(Role::<1>::poll(&mut b, T + DEFAULT_WINDOW), Ok(()));
    }

    /// A second plain frame while one is held: the held one is a discrepancy.
    #[test]
    fn a_second_plain_frame_while_one_is_held_is_a_discrepancy() {
        let mut b = b_with(0x00);
        b.observe(T, &frame(0x101, &[0x01]), &config()).unwrap();
        assert_eq!(b.observe(T, &frame(0x101, &[0x00]), &config()), Err(1));
    }

    /// Both channels fold the same signatures, each computed its own way.
    #[test]
    fn the_digests_of_both_channels_agree() {
        let b = b_with(0);
        let config = config();
        assert_eq!(
            Role::<1>::signature_digest(&b, &config),
            fold_signatures(config.srdos.iter().map(shared::safety::signature::compute))
        );
    }
}
