//! Tests of the two channels' LSS: two slaves of one node (channel A's and channel B's),
//! fed the same requests, and channel B's pairing of their answers; each test names the
//! CiA 305 figure or the fault it is about.

use super::*;
use shared::canopen::lss::{
    BitRates, FASTSCAN_CONFIRM, Lss, MASTER_TO_SLAVE, StoreFailure, specifier,
};

const IDENTITY: [u32; 4] = [0x0ABC, 0x0304, 1, 0x8000_0042];
const RATES: BitRates = BitRates::of(&[BitRate::Kbit500, BitRate::Kbit250]);
const WINDOW: Duration = Duration::from_millis(5);

fn ms(value: u64) -> Instant {
    Instant::from_micros(value * 1000)
}

fn request(data: [u8; 8]) -> CanFrame {
    CanFrame::new(MASTER_TO_SLAVE, &data).unwrap()
}

/// Channel A's and channel B's slaves of one unconfigured node, and B's pairing.
struct Pair {
    a: Lss,
    b: Lss,
    pairing: AnswerPairing,
}

impl Pair {
    fn unconfigured() -> Self {
        Pair {
            a: Lss::new(IDENTITY, None, None, RATES),
            b: Lss::new(IDENTITY, None, None, RATES),
            pairing: AnswerPairing::new(WINDOW),
        }
    }

    /// Both channels take `data` at `at`; A announces its answer 1 ms later. A's answer.
    fn both(&mut self, at: u64, data: [u8; 8]) -> Result<Option<[u8; 8]>, LssMismatch> {
        let frame = request(data);
        let outcome = self.a.on_frame(ms(at), &frame, false, |_| Ok(()));
        let own = self.b.on_frame(ms(at), &frame, false, |_| Ok(()));
        assert_eq!(
            own.reset_communication, outcome.reset_communication,
            "{data:02X?}"
        );
        if outcome.reset_communication {
            self.a.reset_communication();
            self.b.reset_communication();
        }
        if let Some(answer) = own.response {
            self.pairing.own(ms(at), &answer)?;
        }
        if let Some(answer) = outcome.response {
            self.pairing.announced(ms(at + 1), answer_bytes(&answer))?;
        }
        self.pairing.poll(ms(at + 1))?;
        Ok(outcome.response.map(|answer| answer_bytes(&answer)))
    }

    fn settings(lss: &Lss) -> Settings {
        Settings {
            node_id: lss.active(),
            bit_rate: lss.bit_rate(),
        }
    }

    fn settings_agree(&self) -> Result<(), LssMismatch> {
        Self::settings(&self.a).compare(&Self::settings(&self.b), true)
    }
}

fn scan(value: u32, bit_check: u8, sub: u8, next: u8) -> [u8; 8] {
    let [a, b, c, d] = value.to_le_bytes();
    [specifier::FASTSCAN, a, b, c, d, bit_check, sub, next]
}

#[test]
fn cia305_fig46_fig33_fig36_both_channels_follow_a_fastscan_and_configuration_without_a_mismatch() {
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
    assert_eq!(pair.b.active().map(NodeId::raw), Some(7));
    pair.settings_agree().unwrap();
    assert_eq!(pair.pairing.deadline(), Instant::NEVER, "nothing waits");
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
    assert_eq!(error.cause(), Cause::LssAnswerMismatch);
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
    let a = pair.a.on_frame(ms(10), &store, false, |_| Err(failed));
    let b = pair.b.on_frame(ms(10), &store, false, |_| Ok(()));
    pair.pairing.own(ms(10), &b.response.unwrap()).unwrap();
    let error = pair
        .pairing
        .announced(ms(11), answer_bytes(&a.response.unwrap()))
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
    let own = pair.b.on_frame(ms(10), &inquiry, false, |_| Ok(()));
    pair.pairing.own(ms(10), &own.response.unwrap()).unwrap();
    assert_eq!(pair.pairing.deadline(), ms(15));
    assert_eq!(pair.pairing.poll(ms(14)), Ok(()), "within the window");
    let error = pair.pairing.poll(ms(15)).unwrap_err();
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
    let answer = answer_bytes(&outcome.response.unwrap());
    pair.pairing.announced(ms(0), answer).unwrap();
    let own = pair.b.on_frame(ms(3), &reset, false, |_| Ok(()));
    pair.pairing.own(ms(3), &own.response.unwrap()).unwrap();
    assert_eq!(pair.pairing.deadline(), Instant::NEVER);
    // An announcement B never has an answer for: a mismatch once the window ends.
    pair.pairing.announced(ms(10), answer).unwrap();
    assert_eq!(
        pair.pairing.poll(ms(15)),
        Err(LssMismatch::Unexpected {
            channel_a: [0x4F, 0, 0, 0, 0, 0, 0, 0]
        })
    );
}

#[test]
fn cia305_fig36_an_announcement_lost_while_both_channels_stored_is_not_a_fault() {
    // Both channels store at once; channel A's announcement of its answer is lost while
    // channel B programs its flash.
    let mut pair = AnswerPairing::new(WINDOW);
    let stored = CanFrame::new(SLAVE_TO_MASTER, &[0x17, 0, 0, 0, 0, 0, 0, 0]).unwrap();
    pair.own(ms(0), &stored).unwrap();
    pair.link_was_deaf();
    assert_eq!(pair.poll(ms(100)), Ok(()), "dropped when its window ends");
    assert_eq!(pair.deadline(), Instant::NEVER);
    // Lost, and the next request's answers come before the window ends: the uncertain
    // answer gives way to them.
    pair.own(ms(200), &stored).unwrap();
    pair.link_was_deaf();
    let inquiry = CanFrame::new(SLAVE_TO_MASTER, &[0x5E, 11, 0, 0, 0, 0, 0, 0]).unwrap();
    pair.own(ms(201), &inquiry).unwrap();
    pair.announced(ms(202), answer_bytes(&inquiry)).unwrap();
    assert_eq!(pair.deadline(), Instant::NEVER);
}

#[test]
fn cia305_fig36_an_announcement_that_came_through_the_deaf_time_still_pairs() {
    let mut pair = AnswerPairing::new(WINDOW);
    let stored = CanFrame::new(SLAVE_TO_MASTER, &[0x17, 0, 0, 0, 0, 0, 0, 0]).unwrap();
    pair.own(ms(0), &stored).unwrap();
    pair.link_was_deaf();
    pair.announced(ms(2), answer_bytes(&stored)).unwrap();
    assert_eq!(pair.deadline(), Instant::NEVER);
    // An announcement B has no answer for at all is still found.
    pair.announced(ms(10), [0x17, 2, 0, 0, 0, 0, 0, 0]).unwrap();
    assert!(matches!(
        pair.poll(ms(15)),
        Err(LssMismatch::Unexpected { .. })
    ));
    assert_eq!(
        pair.deadline(),
        Instant::NEVER,
        "reported once, then dropped"
    );
}

#[test]
fn cia305_fig33_fig34_node_id_and_bit_rate_are_compared_between_the_channels() {
    let mut pair = Pair::unconfigured();
    pair.both(0, [specifier::SWITCH_GLOBAL, 1, 0, 0, 0, 0, 0, 0])
        .unwrap();
    pair.both(10, [specifier::CONFIGURE_NODE_ID, 9, 0, 0, 0, 0, 0, 0])
        .unwrap();
    pair.settings_agree().unwrap();
    let own = Pair::settings(&pair.b);
    let eight = Settings::from_bytes(8, 0xFF);
    let error = eight.compare(&own, false).unwrap_err();
    assert_eq!(
        error,
        LssMismatch::NodeIdDiffers {
            other: NodeId::new(8).ok(),
            own: None,
        }
    );
    assert_eq!(error.cause(), Cause::NodeIdMismatch);
    assert!(
        error
            .to_string()
            .starts_with("the node-ID in force differs between the channels")
    );
    // The bit rate only in Operational, where LSS cannot change it.
    let faster = Settings {
        node_id: None,
        bit_rate: Some(BitRate::Kbit250),
    };
    assert_eq!(faster.compare(&own, false), Ok(()));
    let error = faster.compare(&own, true).unwrap_err();
    assert_eq!(
        error,
        LssMismatch::BitRateDiffers {
            other: Some(BitRate::Kbit250),
            own: None
        }
    );
    assert_eq!(error.cause(), Cause::BitRateMismatch);
    // The link bytes read back as they were written.
    let settings = Settings {
        node_id: NodeId::new(9).ok(),
        bit_rate: Some(BitRate::Kbit250),
    };
    assert_eq!(
        Settings::from_bytes(settings.node_byte(), settings.bit_rate_byte()),
        settings
    );
    assert_eq!(Settings::from_bytes(0xFF, 0xFF), own);
}

#[test]
fn channel_b_holds_a_bounded_number_of_waiting_answers() {
    let mut pair = AnswerPairing::new(WINDOW);
    let answer = [0x4F, 0, 0, 0, 0, 0, 0, 0];
    for _ in 0..PENDING {
        pair.announced(ms(0), answer).unwrap();
    }
    assert_eq!(pair.announced(ms(0), answer), Err(LssMismatch::Overrun));
}
