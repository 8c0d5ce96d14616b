//! What the monitor knows about the bus, built from frames alone (sans-I/O): fed
//! `(now, frame)` and polled with `now`, it keeps per node the NMT state and heartbeat age,
//! every SRDO as pairs with their verdicts (EN 50325-5 7.1), GFCs, EMCYs in words and SDO
//! traffic, and SimpleCAN's packets, syncs and slot timing ([`simplecan`]). The terminal view ([`super::view`]) only draws this model; the model never reads
//! a clock and does no I/O, so a replayed log gives the same model as the live bus did.
//!
//! The model's time is the bus's: each frame's timestamp (the interface's own where it
//! gives one, [`crate::Transport::receive_stamped`]). A bystander learns that time has passed
//! from the frames that come by; on a bus without any frame the model stays at the last one.
//!
//! The monitor is a bystander: its verdicts are what a consumer with the configured SCT and
//! SRVT would conclude from the frames on the bus, not the consumer's own state (which the
//! node reports in its EMCY). A gap or period *at* its limit counts as exceeded, as the
//! node's timers do.

use crate::error::abort_meaning;
use crate::network_file::Network;
use shared::CanFrame;
use shared::canopen::emcy::{Emergency, code, register};
use shared::canopen::nmt::NmtState;
use shared::safety::cause::Cause;
use shared::safety::config::ConfigError;
use std::collections::{BTreeMap, VecDeque};
use std::time::Duration;

/// How many gaps and periods each SRDO keeps for its timeline.
pub const HISTORY: usize = 60;
/// How many EMCYs and SDO aborts the model keeps (the newest).
pub const RECENT: usize = 8;
/// How many happenings the model keeps (the newest).
pub const HAPPENINGS: usize = 64;

/// The lowest and highest COB-ID of an SRDO's plain frame (EN 50325-5 7.2.1): odd,
/// 101h..=17Fh; its inverted frame is the next identifier.
const SRDO_PLAIN_IDS: std::ops::RangeInclusive<u16> = 0x101..=0x17F;

/// What the monitor expects of one SRDO: its identifiers and, when known, its timing.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SrdoWatch {
    /// COB-ID of the plain frame.
    pub plain: u16,
    /// COB-ID of the inverted frame.
    pub inverted: u16,
    /// Producer (node-ID, SRDO number), when the network file names it.
    pub producer: Option<(u8, u8)>,
    /// Consumers (node-ID, SRDO number) the network file names.
    pub consumers: Vec<(u8, u8)>,
    /// The producer's refresh time.
    pub refresh: Option<Duration>,
    /// The consumers' SCT (the shortest, when several consume it).
    pub sct: Option<Duration>,
    /// The consumers' SRVT (the shortest).
    pub srvt: Option<Duration>,
}

impl SrdoWatch {
    /// An SRDO seen on the bus but in no network file: identifiers only.
    pub fn learned(plain: u16) -> SrdoWatch {
        SrdoWatch {
            plain,
            inverted: plain + 1,
            producer: None,
            consumers: Vec::new(),
            refresh: None,
            sct: None,
            srvt: None,
        }
    }

    /// Every SRDO of a network file, one watch per pair of COB-IDs, with the producer's
    /// refresh time and the consumers' shortest SCT and SRVT.
    pub fn from_network(network: &Network) -> Vec<SrdoWatch> {
        let mut watches: Vec<SrdoWatch> = Vec::new();
        for node in &network.nodes {
            for srdo in &node.srdos {
                let settings = &srdo.settings;
                let (Ok(plain), Ok(inverted)) = (
                    u16::try_from(settings.cob_id_1),
                    u16::try_from(settings.cob_id_2),
                ) else {
                    continue;
                };
                let index = match watches.iter().position(|w| w.plain == plain) {
                    Some(index) => index,
                    None => {
                        watches.push(SrdoWatch {
                            inverted,
                            ..SrdoWatch::learned(plain)
                        });
                        watches.len() - 1
                    }
                };
                let watch = &mut watches[index];
                let cycle = Duration::from_millis(u64::from(settings.cycle_time));
                let srvt = Duration::from_millis(u64::from(settings.srvt));
                match settings.direction {
                    1 => {
                        watch.producer = Some((node.id, srdo.number));
                        watch.refresh = Some(cycle);
                    }
                    2 => {
                        watch.consumers.push((node.id, srdo.number));
                        watch.sct = Some(watch.sct.map_or(cycle, |sct| sct.min(cycle)));
                        watch.srvt = Some(watch.srvt.map_or(srvt, |old| old.min(srvt)));
                    }
                    _ => {}
                }
            }
        }
        watches.sort_by_key(|watch| watch.plain);
        watches
    }
}

/// The verdict on one SRDO pair, or on the lack of one (EN 50325-5 7.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum PairVerdict {
    /// Plain and inverted frame, inverse of each other, in time.
    Valid,
    /// The inverted frame is not the bitwise inverse of the plain one (EN 50325-5 7.1.1).
    NotInverted,
    /// The two frames have different lengths (EN 50325-5 7.1.3).
    LengthsDiffer,
    /// The inverted frame came at or after SRVT from the plain one (EN 50325-5 7.1.2).
    SrvtExceeded,
    /// The pair came at or after SCT from the previous one (EN 50325-5 7.1.2).
    SctExceeded,
    /// A plain frame with other data came before the inverted frame (CiA 304 9.5).
    PlainRepeated,
    /// No inverted frame followed a plain frame within SRVT (EN 50325-5 7.1.2).
    InvertedMissing,
}

impl PairVerdict {
    /// The verdict in words.
    pub const fn describe(self) -> &'static str {
        match self {
            PairVerdict::Valid => "valid",
            PairVerdict::NotInverted => "not inverted",
            PairVerdict::LengthsDiffer => "lengths differ",
            PairVerdict::SrvtExceeded => "SRVT exceeded",
            PairVerdict::SctExceeded => "SCT exceeded",
            PairVerdict::PlainRepeated => "plain frame repeated with other data",
            PairVerdict::InvertedMissing => "inverted frame missing",
        }
    }
}

/// One SRDO as the monitor saw it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SrdoView {
    /// What is expected of it.
    pub watch: SrdoWatch,
    /// The plain frame waiting for its inverted frame: when and what.
    pending: Option<(Duration, CanFrame)>,
    /// When the last complete pair's plain frame came.
    last_pair: Option<Duration>,
    /// The data of the last complete pair's plain frame.
    pub last_data: Option<CanFrame>,
    /// Plain → inverted gaps of the latest pairs, oldest first.
    pub gaps: VecDeque<Duration>,
    /// Periods between the latest pairs' plain frames, oldest first.
    pub periods: VecDeque<Duration>,
    /// How often each verdict was reached.
    pub verdicts: BTreeMap<PairVerdict, u64>,
    /// The latest verdict and when.
    pub last_verdict: Option<(Duration, PairVerdict)>,
    /// Exact repeats of the pending plain frame (CAN double reception), discarded.
    pub repeated_plain: u64,
    /// Inverted frames with no plain frame pending, discarded.
    pub orphan_inverted: u64,
}

impl SrdoView {
    fn new(watch: SrdoWatch) -> SrdoView {
        SrdoView {
            watch,
            pending: None,
            last_pair: None,
            last_data: None,
            gaps: VecDeque::new(),
            periods: VecDeque::new(),
            verdicts: BTreeMap::new(),
            last_verdict: None,
            repeated_plain: 0,
            orphan_inverted: 0,
        }
    }

    /// How often `verdict` was reached.
    pub fn count(&self, verdict: PairVerdict) -> u64 {
        self.verdicts.get(&verdict).copied().unwrap_or(0)
    }

    /// Complete pairs (valid or not) and the faults among them.
    pub fn faults(&self) -> u64 {
        self.verdicts
            .iter()
            .filter(|(verdict, _)| **verdict != PairVerdict::Valid)
            .map(|(_, count)| count)
            .sum()
    }

    /// Time since the last complete pair's plain frame, when there was one.
    pub fn silent_for(&self, now: Duration) -> Option<Duration> {
        self.last_pair.map(|at| now.saturating_sub(at))
    }

    fn judge(&mut self, now: Duration, verdict: PairVerdict) {
        *self.verdicts.entry(verdict).or_default() += 1;
        self.last_verdict = Some((now, verdict));
    }

    fn plain(&mut self, now: Duration, frame: &CanFrame) {
        if let Some((_, pending)) = &self.pending {
            if pending == frame {
                // CAN double reception (ISO 11898-1): discarded, SRVT runs from the first copy.
                self.repeated_plain += 1;
                return;
            }
            self.judge(now, PairVerdict::PlainRepeated);
        }
        self.pending = Some((now, *frame));
    }

    fn inverted(&mut self, now: Duration, frame: &CanFrame) {
        let Some((plain_at, plain)) = self.pending.take() else {
            self.orphan_inverted += 1;
            return;
        };
        let gap = now.saturating_sub(plain_at);
        push(&mut self.gaps, gap);
        let period = self.last_pair.map(|last| plain_at.saturating_sub(last));
        if let Some(period) = period {
            push(&mut self.periods, period);
        }
        self.last_pair = Some(plain_at);
        self.last_data = Some(plain);
        let verdict = if plain.data().len() != frame.data().len() {
            PairVerdict::LengthsDiffer
        } else if !plain
            .data()
            .iter()
            .zip(frame.data())
            .all(|(p, i)| *p == !*i)
        {
            PairVerdict::NotInverted
        } else if self.watch.srvt.is_some_and(|srvt| gap >= srvt) {
            PairVerdict::SrvtExceeded
        } else if self
            .watch
            .sct
            .zip(period)
            .is_some_and(|(sct, period)| period >= sct)
        {
            PairVerdict::SctExceeded
        } else {
            PairVerdict::Valid
        };
        self.judge(now, verdict);
    }

    fn poll(&mut self, now: Duration) {
        if let (Some((at, _)), Some(srvt)) = (self.pending, self.watch.srvt) {
            if now >= at + srvt {
                self.pending = None;
                self.judge(at + srvt, PairVerdict::InvertedMissing);
            }
        }
    }

    /// When [`SrdoView::poll`] next has something to do.
    fn deadline(&self) -> Option<Duration> {
        self.pending
            .zip(self.watch.srvt)
            .map(|((at, _), srvt)| at + srvt)
    }
}

fn push(history: &mut VecDeque<Duration>, value: Duration) {
    if history.len() == HISTORY {
        history.pop_front();
    }
    history.push_back(value);
}

/// One node as the monitor saw it.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct NodeView {
    /// A name from the network file.
    pub name: Option<String>,
    /// The state of its latest heartbeat or boot-up message.
    pub state: Option<NmtState>,
    /// When its latest heartbeat came.
    pub last_heartbeat: Option<Duration>,
    /// The time between its latest two heartbeats.
    pub heartbeat_period: Option<Duration>,
    /// Heartbeats and boot-up messages seen.
    pub heartbeats: u64,
    /// Its latest EMCY, decoded, and when.
    pub last_emergency: Option<(Duration, Emergency)>,
    /// SDO requests to it and responses from it (aborts included).
    pub sdo_requests: u64,
    /// SDO responses from it.
    pub sdo_responses: u64,
    /// The heartbeat consumer time its heartbeat is judged by (CiA 301 7.2.8.3.2.2, object
    /// 1016h of a consumer), when the caller knows it (a bystander cannot tell it from the
    /// bus); `None`: its heartbeat is never judged.
    pub consumer_time: Option<Duration>,
    /// Its latest heartbeat is older than its consumer time (the node went silent); cleared
    /// by its next heartbeat or boot-up message.
    pub heartbeat_lost: bool,
}

impl NodeView {
    /// Time since its latest heartbeat.
    pub fn heartbeat_age(&self, now: Duration) -> Option<Duration> {
        self.last_heartbeat.map(|at| now.saturating_sub(at))
    }

    /// When its heartbeat counts as lost if none comes before: its latest heartbeat plus its
    /// consumer time (a heartbeat *at* the limit is late, as a consumer's timer judges it).
    /// `None` when it is lost already, or has no consumer time (0 disables a consumer too).
    pub fn heartbeat_deadline(&self) -> Option<Duration> {
        if self.heartbeat_lost {
            return None;
        }
        let consumer_time = self.consumer_time.filter(|time| !time.is_zero())?;
        Some(self.last_heartbeat? + consumer_time)
    }
}

/// An SDO abort seen on the bus (CiA 301 7.2.4.3.17).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SdoAbort {
    /// When.
    pub at: Duration,
    /// The server's node-ID.
    pub node: u8,
    /// `true` when the server aborted (a response), `false` when the client did.
    pub by_server: bool,
    /// The object.
    pub index: u16,
    /// Its sub-index.
    pub sub: u8,
    /// The abort code.
    pub code: u32,
}

impl std::fmt::Display for SdoAbort {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "node {}: SDO {:04X}h:{:02X}h aborted by the {} with {:08X}h: {}",
            self.node,
            self.index,
            self.sub,
            if self.by_server { "node" } else { "client" },
            self.code,
            self.meaning()
        )
    }
}

impl SdoAbort {
    /// The code's CiA 301 meaning (the tool's one table of them).
    pub fn meaning(&self) -> &'static str {
        abort_meaning(self.code)
    }
}

/// The whole bus as the monitor saw it.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Monitor {
    /// Every node heard from or named in the network file, by node-ID.
    pub nodes: BTreeMap<u8, NodeView>,
    /// Every SRDO configured or seen, by plain COB-ID.
    pub srdos: BTreeMap<u16, SrdoView>,
    /// GFCs seen (CAN-ID 001h).
    pub gfcs: u64,
    /// When the latest GFC came.
    pub last_gfc: Option<Duration>,
    /// The latest EMCYs (node-ID, when, message), oldest first.
    pub emergencies: VecDeque<(u8, Duration, Emergency)>,
    /// The latest SDO aborts, oldest first.
    pub aborts: VecDeque<SdoAbort>,
    /// The latest happenings worth a line (state changes, EMCYs, GFCs, SRDO faults, SDO
    /// aborts), oldest first, at most [`HAPPENINGS`].
    pub happenings: VecDeque<(Duration, String)>,
    /// Happenings in all since the start (so a printer knows which lines are new).
    pub happened: u64,
    /// NMT commands seen.
    pub nmt_commands: u64,
    /// SimpleCAN packets (02Fh..07Fh), decoded with the network file's node hashes.
    pub simplecan: simplecan::SimpleCanView,
    /// Frames seen in all.
    pub frames: u64,
    /// The time of the latest frame or poll.
    pub now: Duration,
}

impl Monitor {
    /// A monitor that expects the SRDOs in `watches` (and learns others from the bus).
    pub fn new(watches: Vec<SrdoWatch>) -> Monitor {
        Monitor {
            srdos: watches
                .into_iter()
                .map(|watch| (watch.plain, SrdoView::new(watch)))
                .collect(),
            ..Monitor::default()
        }
    }

    /// A monitor for the network file's nodes and SRDOs.
    pub fn for_network(network: &Network) -> Monitor {
        let mut monitor = Monitor::new(SrdoWatch::from_network(network));
        for node in &network.nodes {
            monitor.nodes.entry(node.id).or_default().name = node.name.clone();
        }
        if let Some(simplecan) = &network.simplecan {
            monitor.simplecan = simplecan::SimpleCanView::for_network(simplecan);
        }
        monitor
    }

    /// Takes in one frame received at `now`.
    pub fn feed(&mut self, now: Duration, frame: &CanFrame) {
        // Every deadline up to `now` first, except the SRDO whose inverted frame this is:
        // that frame is judged on arrival, with its gap, also when it is late.
        let id = frame.id().raw();
        let inverted_of =
            (SRDO_PLAIN_IDS.contains(&id.wrapping_sub(1)) && id % 2 == 0).then(|| id - 1);
        self.advance(now, inverted_of);
        self.frames += 1;
        let data = frame.data();
        match id {
            0x000 => self.nmt_commands += 1,
            0x02F..=0x07F => {
                if let Some(line) = self.simplecan.feed(now, frame) {
                    self.note(now, line);
                }
            }
            0x001 => {
                self.gfcs += 1;
                self.last_gfc = Some(now);
                self.note(now, "GFC (global fail-safe command) on the bus".to_owned());
            }
            0x081..=0x0FF => {
                if let Some(emergency) = Emergency::parse(data) {
                    let node = (id - 0x080) as u8;
                    self.nodes.entry(node).or_default().last_emergency = Some((now, emergency));
                    if self.emergencies.len() == RECENT {
                        self.emergencies.pop_front();
                    }
                    self.emergencies.push_back((node, now, emergency));
                    let words = describe_emergency(&emergency);
                    self.note(
                        now,
                        format!("node {node}: EMCY {:04X}h: {words}", emergency.code),
                    );
                }
            }
            0x101..=0x180 => self.srdo_frame(now, frame),
            0x581..=0x5FF => {
                let node = (id - 0x580) as u8;
                self.nodes.entry(node).or_default().sdo_responses += 1;
                self.sdo_abort(now, node, true, data);
            }
            0x601..=0x67F => {
                let node = (id - 0x600) as u8;
                self.nodes.entry(node).or_default().sdo_requests += 1;
                self.sdo_abort(now, node, false, data);
            }
            0x701..=0x77F => {
                if let [state] = *data {
                    let node = (id - 0x700) as u8;
                    let view = self.nodes.entry(node).or_default();
                    let before = view.state;
                    // The boot-up message (state byte 0) is sent on the way from
                    // Initialising to Pre-operational (CiA 301 7.2.8.3.2.1).
                    let boot_up = state == 0;
                    let state = if boot_up {
                        Some(NmtState::PreOperational)
                    } else {
                        NmtState::from_heartbeat_code(state & 0x7F)
                    };
                    view.state = state;
                    let silence = view.last_heartbeat.map(|at| now.saturating_sub(at));
                    let was_lost = std::mem::take(&mut view.heartbeat_lost);
                    view.heartbeat_period = silence.filter(|_| !boot_up);
                    view.last_heartbeat = Some(now);
                    view.heartbeats += 1;
                    if let (true, Some(silence)) = (was_lost, silence) {
                        self.note(
                            now,
                            format!(
                                "node {node}: heartbeat back after {:.1} ms of silence",
                                silence.as_secs_f64() * 1000.0
                            ),
                        );
                    }
                    if boot_up {
                        self.note(now, format!("node {node}: boot-up, Pre-operational"));
                    } else if before != state {
                        let words = state.map_or("an unknown NMT state", NmtState::describe);
                        self.note(now, format!("node {node}: {words}"));
                    }
                }
            }
            _ => {}
        }
    }

    /// Advances the model's time to `now`: an inverted frame not seen within SRVT is judged
    /// missing, and a heartbeat older than its node's consumer time lost
    /// ([`NodeView::consumer_time`]).
    pub fn poll(&mut self, now: Duration) {
        self.advance(now, None);
    }

    fn advance(&mut self, now: Duration, except: Option<u16>) {
        self.now = self.now.max(now);
        let mut changed = Vec::new();
        for (plain, srdo) in &mut self.srdos {
            if except == Some(*plain) {
                continue;
            }
            let before = srdo.last_verdict.map(|(_, verdict)| verdict);
            srdo.poll(now);
            if srdo.last_verdict.map(|(_, verdict)| verdict) != before {
                changed.push((*plain, before));
            }
        }
        for (plain, before) in changed {
            self.note_verdict(plain, before);
        }
        let mut lost = Vec::new();
        for (id, node) in &mut self.nodes {
            if let Some(due) = node.heartbeat_deadline()
                && now >= due
            {
                node.heartbeat_lost = true;
                lost.push((due, *id, node.consumer_time.unwrap_or_default()));
            }
        }
        for (due, id, consumer_time) in lost {
            self.note(
                due,
                format!(
                    "node {id}: heartbeat lost (none for its consumer time, {} ms)",
                    consumer_time.as_millis()
                ),
            );
        }
    }

    /// When [`Monitor::poll`] next has a verdict to reach (an inverted frame missing, a
    /// heartbeat lost), if ever.
    #[must_use]
    pub fn deadline(&self) -> Option<Duration> {
        self.srdos
            .values()
            .filter_map(SrdoView::deadline)
            .chain(self.nodes.values().filter_map(NodeView::heartbeat_deadline))
            .min()
    }

    fn srdo_frame(&mut self, now: Duration, frame: &CanFrame) {
        let id = frame.id().raw();
        // An even identifier is the inverted frame of the SRDO one below (EN 50325-5 7.2.1).
        let plain = if id % 2 == 1 { id } else { id - 1 };
        if !SRDO_PLAIN_IDS.contains(&plain) {
            return;
        }
        let view = self
            .srdos
            .entry(plain)
            .or_insert_with(|| SrdoView::new(SrdoWatch::learned(plain)));
        let before = view.last_verdict.map(|(_, verdict)| verdict);
        if id == view.watch.plain {
            view.plain(now, frame);
        } else if id == view.watch.inverted {
            view.inverted(now, frame);
        }
        self.note_verdict(plain, before);
    }

    /// A line when an SRDO's verdict changes: the first fault after valid pairs, and the
    /// first valid pair after a fault (one line a change, not one a pair).
    fn note_verdict(&mut self, plain: u16, before: Option<PairVerdict>) {
        let Some(view) = self.srdos.get(&plain) else {
            return;
        };
        let Some((at, verdict)) = view.last_verdict else {
            return;
        };
        if Some(verdict) == before {
            return;
        }
        let line = format!(
            "SRDO {plain:03X}h/{:03X}h: {}",
            view.watch.inverted,
            verdict.describe()
        );
        self.note(at, line);
    }

    fn sdo_abort(&mut self, now: Duration, node: u8, by_server: bool, data: &[u8]) {
        // Abort transfer: command specifier 4 (CiA 301 7.2.4.3.17), 8 bytes.
        if let [command, index_low, index_high, sub, c0, c1, c2, c3] = *data {
            if command == 0x80 {
                if self.aborts.len() == RECENT {
                    self.aborts.pop_front();
                }
                let abort = SdoAbort {
                    at: now,
                    node,
                    by_server,
                    index: u16::from_le_bytes([index_low, index_high]),
                    sub,
                    code: u32::from_le_bytes([c0, c1, c2, c3]),
                };
                self.aborts.push_back(abort);
                self.note(now, abort.to_string());
            }
        }
    }

    /// Adds a happening (the caller's own, such as the end of the bus connection).
    pub fn note(&mut self, now: Duration, line: String) {
        if self.happenings.len() == HAPPENINGS {
            self.happenings.pop_front();
        }
        self.happenings.push_back((now, line));
        self.happened += 1;
    }

    /// The happenings after the first `seen` of all since the start, for a printer that
    /// has printed `seen` already (fewer when older ones were dropped).
    pub fn happenings_since(&self, seen: u64) -> impl Iterator<Item = &(Duration, String)> {
        let new = usize::try_from(self.happened.saturating_sub(seen)).unwrap_or(usize::MAX);
        self.happenings
            .iter()
            .skip(self.happenings.len().saturating_sub(new))
    }

    /// SDO requests and responses seen, over all nodes.
    pub fn sdo_totals(&self) -> (u64, u64) {
        self.nodes.values().fold((0, 0), |(req, res), node| {
            (req + node.sdo_requests, res + node.sdo_responses)
        })
    }
}

/// The error register's bits in words (CiA 301 7.5.2.2).
pub fn describe_register(bits: u8) -> String {
    let names = [
        (register::GENERIC, "generic"),
        (0x02, "current"),
        (0x04, "voltage"),
        (0x08, "temperature"),
        (register::COMMUNICATION, "communication"),
        (register::PROFILE, "device profile"),
        (register::MANUFACTURER, "manufacturer"),
    ];
    let set: Vec<&str> = names
        .iter()
        .filter(|(bit, _)| bits & bit != 0)
        .map(|(_, name)| *name)
        .collect();
    if set.is_empty() {
        "no error".to_owned()
    } else {
        set.join(", ")
    }
}

/// A cause byte in words: its [`Cause`] (the one table of them), or the number.
fn cause_words(byte: u8) -> String {
    Cause::from_code(byte).map_or_else(|| format!("cause {byte:02X}h"), |c| c.describe().into())
}

/// `true` for a SimpleCAN cause (60h..7Fh), whose EMCY names an SC-ID or a CAN identifier
/// rather than an SRDO.
fn is_simplecan(cause: u8) -> bool {
    (0x60..0x80).contains(&cause)
}

/// An EMCY in words: what this device means by its code and manufacturer-specific bytes
/// (byte 0 the SRDO number, or for a SimpleCAN cause the packet's identifier, its SC-ID or
/// 2Fh for a sync; byte 1 the cause; FF02h: bytes 2..=3 the identifier of the frame
/// concerned; see `shared::node` and `shared::safety::cause`).
pub fn describe_emergency(emergency: &Emergency) -> String {
    let [srdo, cause, third, fourth, _] = emergency.detail;
    let srdo_words = |text: String| {
        if srdo == 0 {
            text
        } else if is_simplecan(cause) {
            format!("SC-ID {srdo:02X}h: {text}")
        } else {
            format!("SRDO {srdo}: {text}")
        }
    };
    match emergency.code {
        code::NO_ERROR => "error reset: no error".to_owned(),
        code::RPDO_TIMEOUT | code::PROTOCOL_ERROR | code::PDO_LENGTH => {
            srdo_words(cause_words(cause))
        }
        code::INTERNAL_SOFTWARE => srdo_words(Cause::TransmitHalvesNotInverted.to_string()),
        code::GLOBAL_FAIL_SAFE => "GFC received: safe state".to_owned(),
        code::APPLICATION_FAULT => {
            let id = u16::from_le_bytes([third, fourth]);
            let named = (is_simplecan(cause) || cause == Cause::ForeignFrame.code()) && id != 0;
            if named {
                format!("channel cross-check: {} ({id:03X}h)", cause_words(cause))
            } else {
                format!("channel cross-check: {}", cause_words(cause))
            }
        }
        code::DATA_SET => match cause {
            shared::node::STORED_PARAMETERS_REJECTED => {
                "stored parameters rejected: defaults in force, not validated".to_owned()
            }
            shared::node::VALIDATED_FOR_ANOTHER_NODE_ID => {
                format!("configuration was validated for node-ID {third}, not this one")
            }
            _ => match Cause::from_code(cause) {
                Some(found) if cause >= Cause::IntegrityRecords.code() => {
                    srdo_words(found.describe().to_owned())
                }
                _ => srdo_words(match ConfigError::from_cause_code(cause) {
                    Some(reason) => format!("configuration refused at NMT start: {reason}"),
                    None => format!("configuration refused at NMT start (reason {cause})"),
                }),
            },
        },
        other => format!("error code {other:04X}h"),
    }
}

pub mod simplecan;

#[cfg(test)]
mod tests;
