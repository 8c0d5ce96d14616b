//! The scenario file (TOML): which network, what happens when, and what must follow, with
//! bounds. Every mistake comes back as a [`FileError`] naming the file, the line and the
//! column in a sentence (the `toml` crate's spans), as the tool's network file does.
//!
//! ```toml
//! name = "an inverted frame lost"
//! covers = "IEC 61784-3 loss"        # the requirement or fault class it shows
//! network = "networks/estop-output.toml"   # a network file (tool/src/network_file.rs),
//!                                          # relative to this file
//! bit_rate_kbit = 500                # optional: 125, 250, 500 (default), 1000
//! run_ms = 400                       # how long to run after the start
//!
//! [[step]]                           # times from the start (NMT start of all nodes)
//! at_ms = 100
//! fault = { kind = "drop", id = 0x102 }
//!
//! [[expect]]
//! safe = 33                          # node 33's outputs (both channels in series) at 0
//! after_ms = 100
//! within_us = 46540                  # refresh time + frame allowance + SRVT + reaction
//! cause = "SRVT elapsed"             # a name of shared::safety::cause::Cause
//! ```

use crate::campaign::BIT_RATES;
use safety_config::network_file::{self, FileError, Network};
use serde::Deserialize;
use shared::canopen::nmt::NmtCommand;
use shared::safety::cause::Cause;
use std::path::{Path, PathBuf};
use toml::Spanned;

/// One channel of a node.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
pub enum Channel {
    /// Channel A.
    A,
    /// Channel B.
    B,
}

/// A fault, in the hub's vocabulary (`hub/src/control.rs`: drop, corrupt, delay, repeat,
/// reorder, insert, mute, cut, clear) or one the host simulation alone can inject.
#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum FaultSpec {
    /// The next `count` frames (default 1) with identifier `id` are lost.
    Drop {
        /// Identifier.
        id: u16,
        /// How many (every one from now on when `all`).
        #[serde(default)]
        count: Option<u32>,
        /// Every frame with this identifier from now on.
        #[serde(default)]
        all: bool,
    },
    /// Data byte `byte` of the next frame with identifier `id` XOR `mask`, past the CRC.
    Corrupt {
        /// Identifier.
        id: u16,
        /// Data byte index.
        byte: usize,
        /// Bits flipped.
        mask: u8,
    },
    /// The next frame with identifier `id` is delivered `by_us` later.
    Delay {
        /// Identifier.
        id: u16,
        /// Extra latency in µs.
        by_us: u64,
    },
    /// The next frame with identifier `id` occupies the bus twice (CAN double reception).
    Repeat {
        /// Identifier.
        id: u16,
    },
    /// The next frame with identifier `id` is delivered after the frame that follows it.
    Reorder {
        /// Identifier.
        id: u16,
    },
    /// A frame from a foreign device (the tool's bus participant).
    Insert {
        /// Identifier.
        id: u16,
        /// Data, 0 to 8 bytes.
        data: Vec<u8>,
    },
    /// One channel's CAN controller silent: its frames never reach the bus.
    Mute {
        /// Node-ID.
        node: u8,
        /// Channel.
        channel: Channel,
    },
    /// The link between a node's channels cut.
    Cut {
        /// Node-ID.
        node: u8,
    },
    /// Every bus fault removed (what the hub's `clear` does).
    Clear,
    /// Host only: the next link byte from A to B XOR `mask`.
    LinkCorrupt {
        /// Node-ID.
        node: u8,
        /// Bits flipped.
        mask: u8,
    },
    /// Host only: every link byte of the node `us` later, both ways.
    LinkLatency {
        /// Node-ID.
        node: u8,
        /// Extra latency in µs.
        us: u64,
    },
    /// Host only: one channel's clock runs `percent` fast (negative: slow).
    Clock {
        /// Node-ID.
        node: u8,
        /// Channel.
        channel: Channel,
        /// Percent fast (negative: slow).
        percent: i64,
    },
    /// Host only: bit `bit` (0..=15) of the refresh time / SCT in the record of the
    /// `srdo`-th SRDO (from 1) the node runs, in one channel's core (the `fault-injection`
    /// hooks).
    RecordFlip {
        /// Node-ID.
        node: u8,
        /// Channel.
        channel: Channel,
        /// SRDO number, from 1.
        srdo: u8,
        /// Bit.
        bit: u8,
    },
    /// Host only: bit `bit` of byte `byte` of one channel's identifier table flipped.
    IdentifierTableFlip {
        /// Node-ID.
        node: u8,
        /// Channel.
        channel: Channel,
        /// Byte.
        byte: usize,
        /// Bit, 0..=7.
        bit: u8,
    },
    /// Host only: one channel's input keeps its present sample; later `input` steps do not
    /// reach it.
    StuckInput {
        /// Node-ID.
        node: u8,
        /// Channel.
        channel: Channel,
    },
    /// Host only: one channel's controller sends `frames` frames with identifier `id` back
    /// to back.
    Babbling {
        /// Node-ID.
        node: u8,
        /// Channel.
        channel: Channel,
        /// Identifier.
        id: u16,
        /// How many frames.
        frames: u32,
    },
    /// Host only: one channel's controller bus-off: it neither sends nor receives.
    BusOff {
        /// Node-ID.
        node: u8,
        /// Channel.
        channel: Channel,
    },
    /// Host only: channel B of the node never sends the inverted frame of any of its
    /// transmit SRDOs.
    NoInverted {
        /// Node-ID.
        node: u8,
    },
}

impl FaultSpec {
    /// `true` when the hub can inject this fault too (its control port's vocabulary: `drop`
    /// loses one frame, `delay` takes whole milliseconds).
    pub fn hub_can(&self) -> bool {
        match self {
            FaultSpec::Drop { count, all, .. } => !all && count.is_none_or(|count| count == 1),
            FaultSpec::Delay { by_us, .. } => by_us % 1000 == 0,
            _ => self.in_hub_vocabulary(),
        }
    }

    fn in_hub_vocabulary(&self) -> bool {
        matches!(
            self,
            FaultSpec::Corrupt { .. }
                | FaultSpec::Repeat { .. }
                | FaultSpec::Reorder { .. }
                | FaultSpec::Insert { .. }
                | FaultSpec::Mute { .. }
                | FaultSpec::Cut { .. }
                | FaultSpec::Clear
        )
    }

    /// Its `kind` as the file writes it (`drop`, `link-corrupt`, ...).
    pub fn kind(&self) -> &'static str {
        match self {
            FaultSpec::Drop { .. } => "drop",
            FaultSpec::Corrupt { .. } => "corrupt",
            FaultSpec::Delay { .. } => "delay",
            FaultSpec::Repeat { .. } => "repeat",
            FaultSpec::Reorder { .. } => "reorder",
            FaultSpec::Insert { .. } => "insert",
            FaultSpec::Mute { .. } => "mute",
            FaultSpec::Cut { .. } => "cut",
            FaultSpec::Clear => "clear",
            FaultSpec::LinkCorrupt { .. } => "link-corrupt",
            FaultSpec::LinkLatency { .. } => "link-latency",
            FaultSpec::Clock { .. } => "clock",
            FaultSpec::RecordFlip { .. } => "record-flip",
            FaultSpec::IdentifierTableFlip { .. } => "identifier-table-flip",
            FaultSpec::StuckInput { .. } => "stuck-input",
            FaultSpec::Babbling { .. } => "babbling",
            FaultSpec::BusOff { .. } => "bus-off",
            FaultSpec::NoInverted { .. } => "no-inverted",
        }
    }

    /// The identifier it names, if any.
    fn id(&self) -> Option<u16> {
        match self {
            FaultSpec::Drop { id, .. }
            | FaultSpec::Corrupt { id, .. }
            | FaultSpec::Delay { id, .. }
            | FaultSpec::Repeat { id }
            | FaultSpec::Reorder { id }
            | FaultSpec::Insert { id, .. }
            | FaultSpec::Babbling { id, .. } => Some(*id),
            _ => None,
        }
    }

    /// The node it names, if any.
    fn node(&self) -> Option<u8> {
        match self {
            FaultSpec::Mute { node, .. }
            | FaultSpec::Cut { node }
            | FaultSpec::LinkCorrupt { node, .. }
            | FaultSpec::LinkLatency { node, .. }
            | FaultSpec::Clock { node, .. }
            | FaultSpec::RecordFlip { node, .. }
            | FaultSpec::IdentifierTableFlip { node, .. }
            | FaultSpec::StuckInput { node, .. }
            | FaultSpec::Babbling { node, .. }
            | FaultSpec::BusOff { node, .. }
            | FaultSpec::NoInverted { node } => Some(*node),
            _ => None,
        }
    }
}

/// What happens at one moment of the timeline.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Stimulus {
    /// Node `node`'s safety input: both channels, or one.
    Input {
        /// Node-ID.
        node: u8,
        /// Only this channel (both when `None`).
        channel: Option<Channel>,
        /// The sampled value.
        value: u8,
    },
    /// The tool sends an NMT command to `node` (0: all).
    Nmt {
        /// The command.
        command: NmtCommand,
        /// Node-ID, 0 for all.
        node: u8,
    },
    /// The tool sends a GFC (EN 50325-5 7.2.1).
    Gfc,
    /// A fault.
    Fault(FaultSpec),
}

/// One step of the timeline.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Step {
    /// From the start, in µs.
    pub at_us: u64,
    /// What happens.
    pub stimulus: Stimulus,
    /// Line of the step in the file.
    pub line: usize,
}

/// An expected outcome, with its bound.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Expectation {
    /// Node `node`'s outputs are safe within `within_us` of `after_us`, for `cause` when
    /// given (the first cause either channel reports).
    Safe {
        /// Node-ID.
        node: u8,
        /// The reference time from the start, in µs.
        after_us: u64,
        /// The bound, in µs.
        within_us: u64,
        /// The cause, when it matters.
        cause: Option<Cause>,
    },
    /// Node `node`'s outputs (both channels in series) carry `value` at `at_us`.
    Output {
        /// Node-ID.
        node: u8,
        /// When, from the start, in µs.
        at_us: u64,
        /// The value.
        value: u64,
    },
    /// Node `node` reports no safety event (fault, SRDO fault, safe state, GFC) from the
    /// start until `until_us`.
    Working {
        /// Node-ID.
        node: u8,
        /// Until, from the start, in µs.
        until_us: u64,
    },
    /// No EMCY from node `node` from `from_us` to `until_us`.
    NoEmcy {
        /// Node-ID.
        node: u8,
        /// From, in µs.
        from_us: u64,
        /// Until, in µs.
        until_us: u64,
    },
    /// An EMCY with `code` from node `node` within `within_us` of `after_us`.
    Emcy {
        /// Node-ID.
        node: u8,
        /// Error code.
        code: u16,
        /// The reference time, in µs.
        after_us: u64,
        /// The bound, in µs.
        within_us: u64,
    },
}

/// An expectation with where it is written.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Expect {
    /// What.
    pub expectation: Expectation,
    /// Line in the file.
    pub line: usize,
}

/// A scenario, checked.
#[derive(Clone, Debug)]
pub struct Scenario {
    /// Where it came from.
    pub path: PathBuf,
    /// Its name.
    pub name: String,
    /// The requirement or fault class it shows.
    pub covers: String,
    /// The network.
    pub network: Network,
    /// The network file's path.
    pub network_path: PathBuf,
    /// The bus's bit rate.
    pub bit_rate: u32,
    /// How long to run after the start, in µs.
    pub run_us: u64,
    /// The timeline, in time order (steps at the same time in file order).
    pub steps: Vec<Step>,
    /// The expected outcomes.
    pub expects: Vec<Expect>,
}

impl Scenario {
    /// `true` when every fault is one the hub can inject too.
    pub fn hub_only(&self) -> bool {
        self.steps.iter().all(|step| match &step.stimulus {
            Stimulus::Fault(fault) => fault.hub_can(),
            _ => true,
        })
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScenario {
    name: String,
    covers: String,
    network: Spanned<String>,
    bit_rate_kbit: Option<Spanned<u32>>,
    run_ms: Spanned<u64>,
    #[serde(default)]
    step: Vec<Spanned<RawStep>>,
    #[serde(default)]
    expect: Vec<Spanned<RawExpect>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStep {
    at_ms: u64,
    #[serde(default)]
    at_us: u64,
    input: Option<Spanned<RawInput>>,
    nmt: Option<Spanned<RawNmt>>,
    #[serde(default)]
    gfc: bool,
    fault: Option<Spanned<FaultSpec>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawInput {
    node: u8,
    channel: Option<Channel>,
    value: u8,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawNmt {
    command: Spanned<String>,
    #[serde(default)]
    node: u8,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawExpect {
    safe: Option<u8>,
    output: Option<u8>,
    working: Option<u8>,
    no_emcy: Option<u8>,
    emcy: Option<u8>,
    after_ms: Option<u64>,
    within_ms: Option<u64>,
    within_us: Option<u64>,
    cause: Option<Spanned<String>>,
    at_ms: Option<u64>,
    equals: Option<u64>,
    until_ms: Option<u64>,
    from_ms: Option<u64>,
    code: Option<u16>,
}

/// Line and column (from 1, in characters) of byte `offset` in `text`.
fn position(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |at| at + 1);
    (line, before[line_start..].chars().count() + 1)
}

struct Checker<'a> {
    text: &'a str,
    origin: String,
}

impl Checker<'_> {
    fn error(&self, span: std::ops::Range<usize>, message: impl Into<String>) -> FileError {
        let (line, column) = position(self.text, span.start);
        FileError {
            origin: self.origin.clone(),
            line,
            column,
            message: message.into(),
        }
    }

    fn line(&self, span: &std::ops::Range<usize>) -> usize {
        position(self.text, span.start).0
    }
}

/// The command an NMT step names.
fn nmt_command(name: &str) -> Option<NmtCommand> {
    Some(match name {
        "start" => NmtCommand::Start,
        "stop" => NmtCommand::Stop,
        "pre-operational" => NmtCommand::EnterPreOperational,
        "reset-node" => NmtCommand::ResetNode,
        "reset-communication" => NmtCommand::ResetCommunication,
        _ => return None,
    })
}

/// Reads and checks the scenario at `path`; its network file is read relative to it.
pub fn load(path: &Path) -> Result<Scenario, FileError> {
    let origin = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|error| FileError {
        origin: origin.clone(),
        line: 0,
        column: 0,
        message: format!("the scenario cannot be read: {error}"),
    })?;
    let base = path.parent().unwrap_or(Path::new("."));
    parse(&text, &origin, base)
}

/// Parses and checks a scenario; `origin` names it in errors, `base` is the directory its
/// network file is relative to.
pub fn parse(text: &str, origin: &str, base: &Path) -> Result<Scenario, FileError> {
    let checker = Checker {
        text,
        origin: origin.to_owned(),
    };
    let raw: RawScenario = toml::from_str(text).map_err(|error| {
        let span = error.span().unwrap_or(0..0);
        checker.error(span, error.message().trim_end().to_owned())
    })?;
    let network_path = base.join(raw.network.get_ref());
    let network_text = std::fs::read_to_string(&network_path).map_err(|error| {
        checker.error(
            raw.network.span(),
            format!(
                "the network file {} cannot be read: {error}",
                network_path.display()
            ),
        )
    })?;
    let network = network_file::parse(&network_text, &network_path.display().to_string())?;
    let ids: Vec<u8> = network.nodes.iter().map(|node| node.id).collect();
    let known = |node: u8, span: std::ops::Range<usize>, what: &str| {
        if ids.contains(&node) {
            Ok(())
        } else {
            Err(checker.error(
                span,
                format!(
                    "{what} names node {node}, but the network file {} has only node(s) {}",
                    network_path.display(),
                    ids.iter().map(u8::to_string).collect::<Vec<_>>().join(", ")
                ),
            ))
        }
    };
    let bit_rate = match &raw.bit_rate_kbit {
        None => crate::campaign::BIT_RATE,
        Some(kbit) => {
            let rate = kbit.get_ref() * 1000;
            if !BIT_RATES.contains(&rate) {
                return Err(checker.error(
                    kbit.span(),
                    format!(
                        "the bit rate is {} kbit/s, but the simulation runs at {} kbit/s",
                        kbit.get_ref(),
                        BIT_RATES.map(|rate| (rate / 1000).to_string()).join(", ")
                    ),
                ));
            }
            rate
        }
    };
    let run_us = raw.run_ms.get_ref() * 1000;
    if run_us == 0 {
        return Err(checker.error(raw.run_ms.span(), "run_ms must be more than 0"));
    }
    let mut steps = Vec::new();
    for step in &raw.step {
        let span = step.span();
        let raw_step = step.get_ref();
        let at_us = raw_step.at_ms * 1000 + raw_step.at_us;
        if at_us > run_us {
            return Err(checker.error(
                span.clone(),
                format!(
                    "this step is at {} µs, after the end of the run ({} ms)",
                    at_us,
                    raw.run_ms.get_ref()
                ),
            ));
        }
        let mut stimuli = Vec::new();
        if let Some(input) = &raw_step.input {
            let RawInput {
                node,
                channel,
                value,
            } = *input.get_ref();
            known(node, input.span(), "this input")?;
            stimuli.push(Stimulus::Input {
                node,
                channel,
                value,
            });
        }
        if let Some(nmt) = &raw_step.nmt {
            let raw_nmt = nmt.get_ref();
            let command = nmt_command(raw_nmt.command.get_ref()).ok_or_else(|| {
                checker.error(
                    raw_nmt.command.span(),
                    format!(
                        "NMT command `{}` is none of start, stop, pre-operational, reset-node, reset-communication",
                        raw_nmt.command.get_ref()
                    ),
                )
            })?;
            if raw_nmt.node != 0 {
                known(raw_nmt.node, nmt.span(), "this NMT command")?;
            }
            stimuli.push(Stimulus::Nmt {
                command,
                node: raw_nmt.node,
            });
        }
        if raw_step.gfc {
            stimuli.push(Stimulus::Gfc);
        }
        if let Some(fault) = &raw_step.fault {
            if let Some(node) = fault.get_ref().node() {
                known(node, fault.span(), "this fault")?;
            }
            if let Some(id) = fault.get_ref().id().filter(|id| *id > 0x7FF) {
                return Err(checker.error(
                    fault.span(),
                    format!("identifier {id:#x} is beyond the 11-bit identifiers (at most 0x7FF)"),
                ));
            }
            if let FaultSpec::Insert { data, .. } = fault.get_ref() {
                if data.len() > 8 {
                    return Err(checker.error(
                        fault.span(),
                        format!(
                            "an inserted frame has 0 to 8 data bytes, not {}",
                            data.len()
                        ),
                    ));
                }
            }
            if let FaultSpec::RecordFlip { node, srdo, .. } = fault.get_ref() {
                let runs = network
                    .nodes
                    .iter()
                    .find(|spec| spec.id == *node)
                    .map_or(0, |spec| spec.srdos.len());
                if *srdo == 0 || usize::from(*srdo) > runs {
                    return Err(checker.error(
                        fault.span(),
                        format!(
                            "a record flip names the node's {srdo}th SRDO, but node {node} runs {runs} in the network file"
                        ),
                    ));
                }
            }
            stimuli.push(Stimulus::Fault(fault.get_ref().clone()));
        }
        let [stimulus] = <[Stimulus; 1]>::try_from(stimuli).map_err(|stimuli| {
            checker.error(
                span.clone(),
                format!(
                    "a step has exactly one of input, nmt, gfc or fault; this one has {}",
                    stimuli.len()
                ),
            )
        })?;
        steps.push(Step {
            at_us,
            stimulus,
            line: checker.line(&span),
        });
    }
    steps.sort_by_key(|step| step.at_us);
    let mut expects = Vec::new();
    for expect in &raw.expect {
        let span = expect.span();
        let e = expect.get_ref();
        let ms = |value: Option<u64>, what: &str| {
            value.map(|ms| ms * 1000).ok_or_else(|| {
                checker.error(span.clone(), format!("this expectation needs {what}"))
            })
        };
        let kinds = [e.safe, e.output, e.working, e.no_emcy, e.emcy]
            .iter()
            .filter(|kind| kind.is_some())
            .count();
        if kinds != 1 {
            return Err(checker.error(
                span.clone(),
                format!(
                    "an expectation has exactly one of safe, output, working, no_emcy or emcy; this one has {kinds}"
                ),
            ));
        }
        let expectation = if let Some(node) = e.safe {
            known(node, span.clone(), "this expectation")?;
            let cause = match &e.cause {
                None => None,
                Some(name) => Some(
                    Cause::ALL
                        .into_iter()
                        .find(|cause| cause.describe().eq_ignore_ascii_case(name.get_ref()))
                        .ok_or_else(|| {
                            checker.error(
                                name.span(),
                                format!(
                                    "cause `{}` is not a cause's name; the names are: {}",
                                    name.get_ref(),
                                    Cause::ALL.map(Cause::describe).join(", ")
                                ),
                            )
                        })?,
                ),
            };
            let within_us = match (e.within_ms, e.within_us) {
                (Some(ms), None) => ms * 1000,
                (None, Some(us)) => us,
                _ => {
                    return Err(checker.error(
                        span.clone(),
                        "a safe expectation needs its bound: within_ms or within_us",
                    ));
                }
            };
            Expectation::Safe {
                node,
                after_us: ms(e.after_ms, "after_ms")?,
                within_us,
                cause,
            }
        } else if let Some(node) = e.output {
            known(node, span.clone(), "this expectation")?;
            Expectation::Output {
                node,
                at_us: ms(e.at_ms, "at_ms")?,
                value: e.equals.ok_or_else(|| {
                    checker.error(span.clone(), "an output expectation needs equals")
                })?,
            }
        } else if let Some(node) = e.working {
            known(node, span.clone(), "this expectation")?;
            Expectation::Working {
                node,
                until_us: ms(e.until_ms.or(Some(*raw.run_ms.get_ref())), "until_ms")?,
            }
        } else if let Some(node) = e.no_emcy {
            known(node, span.clone(), "this expectation")?;
            Expectation::NoEmcy {
                node,
                from_us: e.from_ms.unwrap_or(0) * 1000,
                until_us: ms(e.until_ms.or(Some(*raw.run_ms.get_ref())), "until_ms")?,
            }
        } else if let Some(node) = e.emcy {
            known(node, span.clone(), "this expectation")?;
            let within_us = match (e.within_ms, e.within_us) {
                (Some(ms), None) => ms * 1000,
                (None, Some(us)) => us,
                _ => {
                    return Err(checker.error(
                        span.clone(),
                        "an emcy expectation needs its bound: within_ms or within_us",
                    ));
                }
            };
            Expectation::Emcy {
                node,
                code: e.code.ok_or_else(|| {
                    checker.error(span.clone(), "an emcy expectation needs its code")
                })?,
                after_us: ms(e.after_ms, "after_ms")?,
                within_us,
            }
        } else {
            return Err(checker.error(span.clone(), "this expectation names no kind"));
        };
        expects.push(Expect {
            expectation,
            line: checker.line(&span),
        });
    }
    if expects.is_empty() {
        return Err(checker.error(
            0..0,
            "a scenario needs at least one [[expect]]: without one it shows nothing",
        ));
    }
    Ok(Scenario {
        path: PathBuf::from(origin),
        name: raw.name,
        covers: raw.covers,
        network,
        network_path,
        bit_rate,
        run_us,
        steps,
        expects,
    })
}
