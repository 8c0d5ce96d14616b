//! The oracle's input from a recorded run of the emulated network: its events in the hub's
//! vocabulary (line format in `can_hub::events`: the emulator's record of the shipped
//! images' run, or, until 2026-12-07, the hub's event log of the QEMU images', `can-hub
//! --events`) turned into the frames with their senders and the consumer's output changes
//! that [`super::oracle`] judges, as it judges the host simulation's. Nothing here decides
//! what is safe: the rules are the oracle's.
//!
//! **The clocks.** On the shipped images the emulator stamps a frame when it ends and an
//! output change when the pin changes, both in its one virtual time. On the QEMU images frames
//! were stamped by the hub's bus model when they ended, and an output change by the hub when
//! the channel's status report of it arrived, on the same virtual clock. A channel handled a
//! frame that ended at hub time T at its own clock within [T − L, T + L], and a report it sent
//! at its clock c reached the hub while the hub's clock was at most c + L
//! (L = `emulation_wire::LOOKAHEAD`, `docs/emulation.md` "Why the verdicts no longer depended
//! on the host"). So a reported change was never stamped before a frame the channel had
//! received when it made it (a raise ahead of its pair stays a violation), and a lowering the
//! rules require was stamped at most 2L after the frame or deadline that requires it:
//! [`EMULATED_ALLOWANCE`] is the oracle's [`super::oracle::REACTION`] plus 2L, the allowance
//! for every emulated run (more than the shipped images' pins need).

use super::oracle::{self, Judgement, MonitoredSrdo, Observed, REACTION};
use can_hub::events::Event;
use shared::{Duration, Instant};

/// How long after the rules require a lower output the emulated consumer's reported output
/// may still show the higher value: the oracle's allowance on the host simulation plus the
/// emulation's clock bound (see the module documentation): 41 ms.
pub const EMULATED_ALLOWANCE: Duration =
    Duration::from_micros(REACTION.as_micros() + 2 * emulation_wire::LOOKAHEAD.as_micros());

/// A recorded run as the oracle takes it: the frames, each sender as a participant number
/// (numbered in the order the names appear), and every channel's output changes.
#[derive(Clone, Debug, Default)]
pub struct Recorded {
    /// The participants' names; a participant's number is its place here.
    pub participants: Vec<String>,
    /// Every frame: (end on the bus, frame, sender's number), in time order.
    pub frames: Vec<Observed>,
    /// Every output change: (report's arrival, channel's name, value), in time order.
    pub outputs: Vec<(Instant, String, u8)>,
}

impl Recorded {
    /// The run the event log `events` describes.
    pub fn new(events: &[Event]) -> Recorded {
        let mut recorded = Recorded::default();
        for event in events {
            match event {
                Event::Frame { at, from, frame } => {
                    let from = recorded.participant(from);
                    recorded.frames.push((*at, *frame, from));
                }
                Event::Output { at, channel, value } => {
                    recorded.outputs.push((*at, channel.clone(), *value));
                }
            }
        }
        // Stable: events at one instant keep the log's order.
        recorded.frames.sort_by_key(|(at, ..)| *at);
        recorded.outputs.sort_by_key(|(at, ..)| *at);
        recorded
    }

    /// The number of participant `name` (a new one for a name not seen yet: a producer
    /// that never sent still has a number no frame carries).
    pub fn participant(&mut self, name: &str) -> usize {
        match self.participants.iter().position(|known| known == name) {
            Some(number) => number,
            None => {
                self.participants.push(name.to_string());
                self.participants.len() - 1
            }
        }
    }

    /// When the effective output of the consumer whose channels are `channels` (both in
    /// series: 0 when either is 0, and before both have reported) was first 0 at or after
    /// `from`: what the runner puts beside the moment the rules required the safe state.
    pub fn off_from(&self, channels: [&str; 2], from: Instant) -> Option<Instant> {
        let mut values = [0u8; 2];
        let mut heard = [false; 2];
        let off = |values: [u8; 2], heard: [bool; 2]| {
            !(heard[0] && heard[1]) || values[0] & values[1] == 0
        };
        for (at, name, value) in &self.outputs {
            if *at > from && off(values, heard) {
                return Some(from);
            }
            let Some(channel) = channels.iter().position(|channel| channel == name) else {
                continue;
            };
            values[channel] = *value;
            heard[channel] = true;
            if *at >= from && off(values, heard) {
                return Some(*at);
            }
        }
        off(values, heard).then_some(from)
    }

    /// The oracle's judgement of receive SRDO `srdo` of the consumer whose two channels'
    /// outputs are `channels` (the names in the log, channel A first), up to `end`, with
    /// [`EMULATED_ALLOWANCE`].
    pub fn judge(&self, srdo: MonitoredSrdo, channels: [&str; 2], end: Instant) -> Judgement {
        let outputs: Vec<(Instant, usize, u64)> = self
            .outputs
            .iter()
            .filter_map(|(at, name, value)| {
                let channel = channels.iter().position(|channel| channel == name)?;
                Some((*at, channel, u64::from(*value)))
            })
            .collect();
        oracle::judge_with_allowance(srdo, &self.frames, &outputs, end, EMULATED_ALLOWANCE)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use can_hub::events;

    /// Node 33's SRDO 1 on the emulated network (`scenarios/networks/emulated.toml`: SCT
    /// 500 ms, SRVT 100 ms, one mapped byte), produced by node 1's channels.
    fn emulated(recorded: &mut Recorded) -> MonitoredSrdo {
        MonitoredSrdo {
            consumer: 33,
            plain_id: 0x101,
            inverted_id: 0x102,
            len: 1,
            sct: Duration::from_millis(500),
            srvt: Duration::from_millis(100),
            producer: [
                recorded.participant("node1a"),
                recorded.participant("node1b"),
            ],
        }
    }

    /// A hand-made event log of the emulated network: the tool starts all nodes, node 1
    /// sends released (01h/FEh) every 100 ms, node 33's channels report their output on
    /// about 10 ms after each pair (within the emulation's clock bound), then `tail`.
    fn log(tail: &str) -> String {
        let mut text = String::from("frame t=1.000000 from=tool6 000#0100\n");
        for pair in 0..3u64 {
            let plain = 1_100_000 + 100_000 * pair;
            let _ = std::fmt::Write::write_fmt(
                &mut text,
                format_args!(
                    "frame t={}.{:06} from=node1a 101#01\nframe t={}.{:06} from=node1b 102#FE\n",
                    plain / 1_000_000,
                    plain % 1_000_000,
                    (plain + 300) / 1_000_000,
                    (plain + 300) % 1_000_000,
                ),
            );
        }
        text.push_str("output t=1.110000 node33a 1\noutput t=1.112000 node33b 1\n");
        text.push_str(tail);
        text
    }

    fn judge(text: &str, end_us: u64) -> Judgement {
        let events = events::parse(text).expect("the log reads");
        let mut recorded = Recorded::new(&events);
        let srdo = emulated(&mut recorded);
        recorded.judge(srdo, ["node33a", "node33b"], Instant::from_micros(end_us))
    }

    /// CiA 304 9.5, EN 50325-5 7.1.1: a recorded run in which node 33 follows node 1's
    /// valid pairs and drops its output 20 ms after an inverted frame that is not the
    /// inverse (within the emulation's allowance) is judged safe; the same run with the
    /// output left on after the broken pair is judged unsafe, at the instant the allowance
    /// ran out, and why.
    #[test]
    fn the_oracle_judges_a_recorded_log_safe_and_the_same_log_with_the_output_left_on_unsafe() {
        let broken = "frame t=1.400000 from=node1a 101#01\nframe t=1.400300 from=node1b 102#FF\n";
        let safe = log(&format!(
            "{broken}output t=1.420000 node33a 0\noutput t=1.421000 node33b 0\n"
        ));
        let judgement = judge(&safe, 1_600_000);
        assert_eq!(judgement.violations, []);
        assert_eq!(
            judgement.first_error,
            Some((
                Instant::from_micros(1_400_300),
                "inverted frame is not the inverse of the plain frame"
            ))
        );

        let unsafe_run = log(broken);
        let judgement = judge(&unsafe_run, 1_600_000);
        let first = judgement.violations.first().expect("a violation");
        assert_eq!(
            first.at,
            Instant::from_micros(1_400_300) + EMULATED_ALLOWANCE,
            "{first:?}"
        );
        assert_eq!((first.output, first.allowed), (1, 0));
        assert!(
            first.why.contains("inverted frame is not the inverse"),
            "{}",
            first.why
        );
    }

    /// EN 50325-5 7.1.2 (SRVT), IEC 61784-3 masquerade: an output raised on a pair from
    /// another sender (the hub's `insert`) is unsafe whatever the allowance, even while
    /// node 1's own pairs are valid; and an output change reported before the valid pair
    /// that would justify it (on the hub's clock) is a raise ahead of its pair.
    #[test]
    fn the_oracle_finds_a_recorded_raise_on_a_foreign_pair_or_ahead_of_its_pair_unsafe() {
        let foreign = log("output t=1.350000 node33a 0\noutput t=1.350000 node33b 0\n\
             frame t=1.360000 from=hub 101#03\nframe t=1.360300 from=hub 102#FC\n\
             output t=1.370000 node33a 3\noutput t=1.371000 node33b 3\n");
        let judgement = judge(&foreign, 1_500_000);
        let first = judgement.violations.first().expect("a violation");
        assert_eq!(first.at, Instant::from_micros(1_371_000));
        assert_eq!(
            (first.output, first.allowed),
            (3, 1),
            "only node 1's bit: {}",
            first.why
        );

        // Both channels on 1 ms before the first pair ended on the bus.
        let early = "frame t=1.000000 from=tool6 000#0100\n\
                     output t=1.100000 node33a 1\noutput t=1.100000 node33b 1\n\
                     frame t=1.100800 from=node1a 101#01\nframe t=1.101100 from=node1b 102#FE\n";
        let judgement = judge(early, 1_200_000);
        assert_eq!(
            judgement.violations.first().map(|violation| violation.at),
            Some(Instant::from_micros(1_100_000))
        );
    }

    /// The consumer's output is off from the first report at or after the moment asked
    /// about in which either channel is 0, or at once when it already was.
    #[test]
    fn the_consumer_is_off_from_the_first_report_of_a_channel_at_0() {
        let events = events::parse(&log(
            "output t=1.420000 node33b 0\noutput t=1.500000 node33b 1\n",
        ))
        .expect("the log reads");
        let recorded = Recorded::new(&events);
        let off = |ms| recorded.off_from(["node33a", "node33b"], Instant::from_millis(ms));
        assert_eq!(
            off(1_000),
            Some(Instant::from_millis(1_000)),
            "before any report"
        );
        assert_eq!(off(1_200), Some(Instant::from_millis(1_420)));
        assert_eq!(off(1_450), Some(Instant::from_millis(1_450)), "off already");
        assert_eq!(off(1_550), None, "on again to the end");
    }

    /// The allowance is the oracle's own plus twice the emulation's lookahead.
    #[test]
    fn the_emulated_allowance_is_the_reaction_plus_twice_the_lookahead() {
        assert_eq!(EMULATED_ALLOWANCE, Duration::from_millis(41));
    }
}
