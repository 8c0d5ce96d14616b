//! Tests of channel B's LSS mirror: channel A is the node's LSS slave itself, fed the same
//! requests; each test names the CiA 305 figure or the fault it is about.

use super::*;
use shared::canopen::lss::{FASTSCAN_CONFIRM, specifier};

const IDENTITY: [u32; 4] = [0x0ABC, 0x0304, 1, 0x8000_0042];
const RATES: BitRates = BitRates::of(&[BitRate::Kbit500, BitRate::Kbit250]);
const WINDOW: Duration = Duration::from_millis(5);

fn ms(value: u64) -> Instant {
    Instant::from_micros(value * 1000)
}

fn request(data: [u8; 8]) -> CanFrame {
    CanFrame::new(MASTER_TO_SLAVE, &data).unwrap()
}

/// Channel A's slave and channel B's mirror of one unconfigured node.
struct Pair {
    a: Lss,
    b: LssMirror,
}

impl Pair {
    fn unconfigured() -> Self {
        Pair {
            a: Lss::new(IDENTITY, None, None, RATES),
            b: LssMirror::new(IDENTITY, None, None, RATES, WINDOW),
        }
    }

    /// Both channels take `data` at `at`; A announces its answer 1 ms later. A's answer.
    fn both(&mut self, at: u64, data: [u8; 8]) -> Result<Option<[u8; 8]>, LssMismatch> {
        let frame = request(data);
        let outcome = self.a.on_frame(ms(at), &frame, false, |_| Ok(()));
        let reset_b = self.b.on_request(ms(at), &frame, false, |_| Ok(()))?;
        assert_eq!(reset_b, outcome.reset_communication, "{data:02X?}");
        if outcome.reset_communication {
            self.a.reset_communication();
            self.b.reset_communication();
        }
        if let Some(answer) = outcome.response {
            self.b.on_announced(ms(at + 1), &answer)?;
        }
        self.b.poll(ms(at + 1))?;
        Ok(outcome
            .response
            .map(|answer| <[u8; 8]>::try_from(answer.data()).unwrap()))
    }

    fn settings_agree(&self) -> Result<(), LssMismatch> {
        self.b
            .check_settings(self.a.active(), self.a.pending(), self.a.bit_rate())
    }
}

fn scan(value: u32, bit_check: u8, sub: u8, next: u8) -> [u8; 8] {
    let [a, b, c, d] = value.to_le_bytes();
    [specifier::FASTSCAN, a, b, c, d, bit_check, sub, next]
}

#[test]
fn cia305_fig46_fig33_fig36_the_mirror_follows_a_fastscan_and_configuration_without_a_mismatch() {
    let mut pair = Pair::unconfigured();
    let mut at = 0;
    let mut step = |pair: &mut Pair, data| {
        at += 10;
        pair.both(at, data).unwrap()
    };
    assert!(step(&mut pair, scan(0, FASTSCAN_CONFIRM, 0, 0)).is_some());
    let mut found = [0u32; 4];
    for sub in 0..4u8 {
        for bit in (0..32u8).rev() {
            if step(&mut pair, scan(found[usize::from(sub)], bit, sub, sub)).is_none() {
                found[usize::from(sub)] |= 1 << bit;
            }
        }
        let next = (sub + 1) % 4;
        assert!(step(&mut pair, scan(found[usize::from(sub)], 0, sub, next)).is_some());
    }
    assert_eq!(found, IDENTITY);
    assert_eq!(
        step(
            &mut pair,
            [specifier::CONFIGURE_NODE_ID, 7, 0, 0, 0, 0, 0, 0]
        ),
        Some([specifier::CONFIGURE_NODE_ID, 0, 0, 0, 0, 0, 0, 0])
    );
    step(
        &mut pair,
        [specifier::CONFIGURE_BIT_TIMING, 0, 3, 0, 0, 0, 0, 0],
    );
    step(
        &mut pair,
        [specifier::STORE_CONFIGURATION, 0, 0, 0, 0, 0, 0, 0],
    );
    pair.settings_agree().unwrap();
    // Back to waiting: the unconfigured node takes node-ID 7 on both channels.
    step(&mut pair, [specifier::SWITCH_GLOBAL, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(pair.b.lss().active().map(NodeId::raw), Some(7));
    pair.settings_agree().unwrap();
    assert_eq!(pair.b.deadline(), Instant::NEVER, "nothing waits");
}

#[test]
fn cia305_fig33_an_answer_of_channel_a_that_differs_is_a_mismatch_in_words() {
    // Channel A's slave believes its switches are set (a corrupted state): it refuses the
    // node-ID with FFh, 01h where channel B's accepts it.
    let mut pair = Pair::unconfigured();
    pair.a = Lss::new(IDENTITY, NodeId::new(3).ok(), None, RATES);
    pair.both(0, [specifier::SWITCH_GLOBAL, 1, 0, 0, 0, 0, 0, 0])
        .unwrap();
    let error = pair
        .both(10, [specifier::CONFIGURE_NODE_ID, 7, 0, 0, 0, 0, 0, 0])
        .unwrap_err();
    assert_eq!(
        error,
        LssMismatch::AnswerDiffers {
            channel_a: [0x11, 0xFF, 0x01, 0, 0, 0, 0, 0],
            channel_b: [0x11, 0, 0, 0, 0, 0, 0, 0],
        }
    );
    assert_eq!(
        error.to_string(),
        "channel A announced an LSS answer that differs from channel B's own \
         (A [11, FF, 01, 00, 00, 00, 00, 00], B [11, 00, 00, 00, 00, 00, 00, 00])"
    );
}

#[test]
fn cia305_fig36_a_store_that_fails_on_one_channel_only_is_a_mismatch() {
    let mut pair = Pair::unconfigured();
    pair.both(0, [specifier::SWITCH_GLOBAL, 1, 0, 0, 0, 0, 0, 0])
        .unwrap();
    let store = request([specifier::STORE_CONFIGURATION, 0, 0, 0, 0, 0, 0, 0]);
    let failed = StoreFailure::Failed(shared::canopen::storage::StorageError::VerifyFailed);
    let outcome = pair.a.on_frame(ms(10), &store, false, |_| Err(failed));
    pair.b
        .on_request(ms(10), &store, false, |_| Ok(()))
        .unwrap();
    let error = pair
        .b
        .on_announced(ms(11), &outcome.response.unwrap())
        .unwrap_err();
    assert!(matches!(
        error,
        LssMismatch::AnswerDiffers {
            channel_a: [0x17, 2, ..],
            channel_b: [0x17, 0, ..]
        }
    ));
}

#[test]
fn cia305_a_request_channel_a_missed_is_found_when_the_window_ends() {
    let mut pair = Pair::unconfigured();
    pair.both(0, [specifier::SWITCH_GLOBAL, 1, 0, 0, 0, 0, 0, 0])
        .unwrap();
    // Only channel B received the inquiry.
    let inquiry = request([specifier::INQUIRE_NODE_ID, 0, 0, 0, 0, 0, 0, 0]);
    pair.b
        .on_request(ms(10), &inquiry, false, |_| Ok(()))
        .unwrap();
    assert_eq!(pair.b.deadline(), ms(15));
    assert_eq!(pair.b.poll(ms(14)), Ok(()), "within the window");
    let error = pair.b.poll(ms(15)).unwrap_err();
    assert_eq!(
        error,
        LssMismatch::Unanswered {
            channel_b: [0x5E, 0xFF, 0, 0, 0, 0, 0, 0]
        }
    );
    assert!(error.to_string().starts_with(
        "channel B answered an LSS request and channel A announced no answer within the window"
    ));
}

#[test]
fn cia305_an_answer_announced_first_waits_for_channel_b_within_the_window() {
    let mut pair = Pair::unconfigured();
    let reset = request(scan(0, FASTSCAN_CONFIRM, 0, 0));
    let outcome = pair.a.on_frame(ms(0), &reset, false, |_| Ok(()));
    let answer = outcome.response.unwrap();
    pair.b.on_announced(ms(0), &answer).unwrap();
    pair.b.on_request(ms(3), &reset, false, |_| Ok(())).unwrap();
    assert_eq!(pair.b.deadline(), Instant::NEVER);
    // An announcement B never has an answer for: a mismatch once the window ends.
    pair.b.on_announced(ms(10), &answer).unwrap();
    assert_eq!(
        pair.b.poll(ms(15)),
        Err(LssMismatch::Unexpected {
            channel_a: [0x4F, 0, 0, 0, 0, 0, 0, 0]
        })
    );
    // An announcement on another identifier is never A's LSS answer.
    let foreign = CanFrame::new(MASTER_TO_SLAVE, &[0x4F, 0, 0, 0, 0, 0, 0, 0]).unwrap();
    assert!(matches!(
        pair.b.on_announced(ms(20), &foreign),
        Err(LssMismatch::Unexpected { .. })
    ));
}

#[test]
fn cia305_fig33_fig34_node_id_and_bit_rate_are_compared_with_channel_a() {
    let mut pair = Pair::unconfigured();
    pair.both(0, [specifier::SWITCH_GLOBAL, 1, 0, 0, 0, 0, 0, 0])
        .unwrap();
    pair.both(10, [specifier::CONFIGURE_NODE_ID, 9, 0, 0, 0, 0, 0, 0])
        .unwrap();
    pair.settings_agree().unwrap();
    let nine = NodeId::new(9).ok();
    let error = pair
        .b
        .check_settings(None, NodeId::new(8).ok(), None)
        .unwrap_err();
    assert_eq!(
        error,
        LssMismatch::NodeIdDiffers {
            channel_a: (None, NodeId::new(8).ok()),
            channel_b: (None, nine),
        }
    );
    assert!(
        error
            .to_string()
            .starts_with("the LSS node-ID in force or pending differs between the channels")
    );
    assert_eq!(
        pair.b.check_settings(None, nine, Some(BitRate::Kbit250)),
        Err(LssMismatch::BitRateDiffers {
            channel_a: Some(BitRate::Kbit250),
            channel_b: None
        })
    );
}

#[test]
fn the_mirror_holds_a_bounded_number_of_waiting_answers() {
    let mut pair = Pair::unconfigured();
    let answer = CanFrame::new(SLAVE_TO_MASTER, &[0x4F, 0, 0, 0, 0, 0, 0, 0]).unwrap();
    for _ in 0..PENDING {
        pair.b.on_announced(ms(0), &answer).unwrap();
    }
    assert_eq!(
        pair.b.on_announced(ms(0), &answer),
        Err(LssMismatch::Overrun)
    );
}
