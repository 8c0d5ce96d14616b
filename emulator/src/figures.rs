//! The measuring runs' profiles as Markdown and JSON ([`crate::cases::Nominal`] for CANopen
//! Safety, [`crate::cases::SimpleCanRun`] for SimpleCAN; [`crate::profile`]): per MCU, the
//! cost of an idle loop iteration, of the protocol's work, of what else woke the core, the
//! functions the instructions went to, and the deepest stack. `emulate-network --nominal` and
//! `--simplecan` print these lines and `cargo xtask` writes them into
//! `docs/emulated-figures.md` and `docs/emulated-figures-simplecan.md`; no figure is written
//! anywhere else.

use crate::cases::Window;
use crate::profile::{Activation, Protocol, bit};

/// How many functions each MCU's table lists.
const TOP_FUNCTIONS: usize = 12;

/// A test on an activation's markers, for the images of a protocol.
type Test = fn(&Activation, Protocol) -> bool;

/// What a measuring run profiled: each MCU's windows (in the network's order) and deepest
/// stack, on the images of `protocol`.
#[derive(Clone, Copy, Debug)]
pub struct Profiled<'a> {
    /// The images' protocol: what an activation's protocol work is.
    pub protocol: Protocol,
    /// Each MCU's profile of the pre-operational window.
    pub pre_operational: &'a [Window],
    /// Each MCU's profile of the Operational window.
    pub operational: &'a [Window],
    /// Each MCU's deepest stack over the whole run, in bytes.
    pub deepest_stack: &'a [u32],
}

/// The protocol's words in the tables: its work, the unit the window counts
/// ([`Window::pairs`]), and the key of the JSON's longest activation with its work.
struct Words {
    work: &'static str,
    work_detail: &'static str,
    unit: &'static str,
    key: &'static str,
}

/// [`Words`] of `protocol`.
fn words(protocol: Protocol) -> Words {
    match protocol {
        Protocol::CanopenSafety => Words {
            work: "a pair's work",
            work_detail: "an SRDO frame handled or produced, a verdict",
            unit: "pair",
            key: "pair",
        },
        Protocol::Simplecan => Words {
            work: "SimpleCAN's work",
            work_detail: "a packet or sync decoded or produced, a forwarded packet paired, \
                          channel A's packet judged, a verdict",
            unit: "packet",
            key: "simplecan",
        },
    }
}

/// The key of the JSON's longest activation with the protocol's work (`longest_activation`):
/// `pair` for CANopen Safety, `simplecan` for SimpleCAN.
pub fn work_key(protocol: Protocol) -> &'static str {
    words(protocol).key
}

/// The kinds of activation, in the order the tables list them: a label and a test on the
/// markers entered.
fn kinds(protocol: Protocol) -> [(String, Test); 7] {
    let Words {
        work, work_detail, ..
    } = words(protocol);
    [
        (
            "idle loop iteration (nothing received, nothing sent)".to_owned(),
            |a, _| is_idle(a),
        ),
        (
            format!("loop iteration with {work} ({work_detail})"),
            |a, protocol| protocol.is_work(a),
        ),
        (
            format!("loop iteration with a link message received, no {work}"),
            |a, protocol| a.has("loop") && !protocol.is_work(a) && a.has("link message"),
        ),
        (
            format!("loop iteration sending the link heartbeat, no {work}"),
            |a, protocol| {
                a.has("loop")
                    && !protocol.is_work(a)
                    && !a.has("link message")
                    && a.has("heartbeat")
            },
        ),
        (
            "other loop iteration (other frames or link messages sent)".to_owned(),
            |a, protocol| {
                a.has("loop")
                    && !protocol.is_work(a)
                    && !is_idle(a)
                    && !a.has("link message")
                    && !a.has("heartbeat")
            },
        ),
        (
            "interrupts only: the link USART (a byte in or out)".to_owned(),
            |a, _| !a.has("loop") && a.has("USART3"),
        ),
        ("interrupts only: other (CAN, timer)".to_owned(), |a, _| {
            !a.has("loop") && !a.has("USART3")
        }),
    ]
}

/// A loop iteration that received nothing and sent nothing.
fn is_idle(activation: &Activation) -> bool {
    let busy = bit("frame")
        | bit("link message")
        | bit("link sent")
        | bit("heartbeat")
        | bit("CAN sent")
        | Protocol::CanopenSafety.work_marks()
        | Protocol::Simplecan.work_marks();
    activation.has("loop") && activation.marks & busy == 0
}

/// Fewest, median and most of `values` (zeros when empty).
fn spread(values: &mut [u64]) -> (u64, u64, u64) {
    values.sort_unstable();
    match values {
        [] => (0, 0, 0),
        _ => (
            values[0],
            values[values.len() / 2],
            values[values.len() - 1],
        ),
    }
}

/// One MCU's totals in a window.
struct Totals {
    instructions: u64,
    iterations: usize,
    idle: (u64, u64, u64),
    pair_instructions: u64,
    link_interrupts: usize,
    link_interrupt_median: u64,
}

fn totals(window: &Window, protocol: Protocol) -> Totals {
    let activations = &window.activations;
    let mut idle: Vec<u64> = activations
        .iter()
        .filter(|a| is_idle(a))
        .map(|a| a.instructions)
        .collect();
    let mut link: Vec<u64> = activations
        .iter()
        .filter(|a| !a.has("loop") && a.has("USART3"))
        .map(|a| a.instructions)
        .collect();
    Totals {
        instructions: activations.iter().map(|a| a.instructions).sum(),
        iterations: activations.iter().map(|a| a.iterations as usize).sum(),
        idle: spread(&mut idle),
        pair_instructions: activations
            .iter()
            .filter(|a| protocol.is_work(a))
            .map(|a| a.instructions)
            .sum(),
        link_interrupts: link.len(),
        link_interrupt_median: spread(&mut link).1,
    }
}

/// The same figures machine-readable, one JSON object: per MCU and window, the longest
/// activation that ran the loop and the longest with the protocol's work (key [`work_key`]:
/// the processing step's path, `cargo xtask bench --target-cost`), the instructions, the loop
/// iterations, the idle iteration (fewest, median, most), the instructions per pair or
/// packet (the lower bound of [`markdown`]'s *per pair* or *per packet*) and the pairs or
/// packets; per MCU, the deepest stack; for CANopen Safety, the goals per channel.
pub fn json(profiled: &Profiled<'_>, names: &[String]) -> serde_json::Value {
    let protocol = profiled.protocol;
    let Words { unit, key, .. } = words(protocol);
    let window = |window: &Window| {
        let t = totals(window, protocol);
        let longest = |test: &dyn Fn(&Activation) -> bool| {
            window
                .activations
                .iter()
                .filter(|a| test(a))
                .map(|a| a.instructions)
                .max()
        };
        let mut longest_activation = serde_json::Map::new();
        longest_activation.insert("loop".into(), longest(&|a| a.has("loop")).into());
        longest_activation.insert(key.into(), longest(&|a| protocol.is_work(a)).into());
        let mut figures = serde_json::Map::new();
        figures.insert("longest_activation".into(), longest_activation.into());
        figures.insert("instructions".into(), t.instructions.into());
        figures.insert("loop_iterations".into(), t.iterations.into());
        figures.insert(
            "idle_iteration".into(),
            serde_json::json!({"fewest": t.idle.0, "median": t.idle.1, "most": t.idle.2}),
        );
        figures.insert(
            format!("per_{unit}"),
            t.pair_instructions.checked_div(window.pairs).into(),
        );
        figures.insert(format!("{unit}s"), window.pairs.into());
        figures.insert("link_usart_interrupts".into(), t.link_interrupts.into());
        serde_json::Value::Object(figures)
    };
    let mcus: Vec<serde_json::Value> = names
        .iter()
        .enumerate()
        .map(|(mcu, name)| {
            serde_json::json!({
                "mcu": name,
                "pre_operational": profiled.pre_operational.get(mcu).map(window),
                "operational": profiled.operational.get(mcu).map(window),
                "deepest_stack_bytes": profiled.deepest_stack.get(mcu),
            })
        })
        .collect();
    let goals = match protocol {
        Protocol::CanopenSafety => serde_json::json!({"per_pair": 2000, "idle_iteration": 200}),
        Protocol::Simplecan => serde_json::Value::Null,
    };
    serde_json::json!({
        "unit": "Thumb instructions executed, counted by the emulator; windows of one second",
        "goals_per_channel": goals,
        "mcus": mcus,
    })
}

/// The Markdown of the profiles (no trailing blank line).
pub fn markdown(profiled: &Profiled<'_>, names: &[String]) -> Vec<String> {
    let mut out = Vec::new();
    let protocol = profiled.protocol;
    let Words { unit, .. } = words(protocol);
    let pairs = profiled.operational.first().map_or(0, |w| w.pairs);
    out.push("## Where the instructions go (profiled by the emulator)".to_owned());
    out.push(String::new());
    match protocol {
        Protocol::CanopenSafety => out.extend(canopen_introduction(pairs)),
        Protocol::Simplecan => out.extend(simplecan_introduction(pairs)),
    }
    out.push(format!(
        "| MCU | window | instructions | loop iterations | idle iteration (fewest / median / \
         most) | per {unit} | per {unit}, all but idle | link USART interrupts (median each) | \
         deepest stack |"
    ));
    out.push("|---|---|---:|---:|---:|---:|---:|---:|---:|".to_owned());
    for (mcu, name) in names.iter().enumerate() {
        for (label, windows) in [
            ("pre-operational", &profiled.pre_operational),
            ("Operational", &profiled.operational),
        ] {
            let Some(window) = windows.get(mcu) else {
                continue;
            };
            let t = totals(window, protocol);
            let idle_total: u64 = window
                .activations
                .iter()
                .filter(|a| is_idle(a))
                .map(|a| a.instructions)
                .sum();
            let per = |instructions: u64| {
                instructions
                    .checked_div(window.pairs)
                    .map_or_else(|| "–".to_owned(), |each| each.to_string())
            };
            let (per_pair, all_but_idle) =
                (per(t.pair_instructions), per(t.instructions - idle_total));
            let stack = if label == "Operational" {
                profiled
                    .deepest_stack
                    .get(mcu)
                    .map_or("–".to_owned(), |bytes| format!("{bytes} bytes"))
            } else {
                String::new()
            };
            out.push(format!(
                "| {name} | {label} | {} | {} | {} / {} / {} | {per_pair} | {all_but_idle} | \
                 {} ({}) | {stack} |",
                t.instructions,
                t.iterations,
                t.idle.0,
                t.idle.1,
                t.idle.2,
                t.link_interrupts,
                t.link_interrupt_median
            ));
        }
    }
    out.push(String::new());
    out.push(
        "*Deepest stack*: the lowest stack pointer seen at the start of a translated block from \
         power-on to the end of the case (configuration, store, load, emergency stop \
         included), below the initial stack pointer; a leaf function's own frame below it is \
         not seen."
            .to_owned(),
    );
    out.push(String::new());
    out.push("### The activations of the Operational window, by kind".to_owned());
    out.push(String::new());
    out.push(
        "| MCU | kind | activations | loop iterations in them | fewest | median | most | \
         instructions | share |"
            .to_owned(),
    );
    out.push("|---|---|---:|---:|---:|---:|---:|---:|---:|".to_owned());
    for (mcu, name) in names.iter().enumerate() {
        let Some(window) = profiled.operational.get(mcu) else {
            continue;
        };
        let total: u64 = window.activations.iter().map(|a| a.instructions).sum();
        for (kind, test) in kinds(protocol) {
            let mut counts: Vec<u64> = window
                .activations
                .iter()
                .filter(|a| test(a, protocol))
                .map(|a| a.instructions)
                .collect();
            let iterations: u32 = window
                .activations
                .iter()
                .filter(|a| test(a, protocol))
                .map(|a| a.iterations)
                .sum();
            if counts.is_empty() {
                continue;
            }
            let sum: u64 = counts.iter().sum();
            let (fewest, median, most) = spread(&mut counts);
            out.push(format!(
                "| {name} | {kind} | {} | {iterations} | {fewest} | {median} | {most} | {sum} | \
                 {:.1} % |",
                counts.len(),
                100.0 * sum as f64 / total.max(1) as f64
            ));
        }
    }
    out.push(String::new());
    out.push(format!(
        "### The functions of the Operational window, top {TOP_FUNCTIONS} per MCU"
    ));
    out.push(String::new());
    out.push(
        "A function's own instructions (callees not included, inlined code counted where it \
         was inlined), all activations together."
            .to_owned(),
    );
    out.push(String::new());
    out.push("| MCU | function | instructions | share |".to_owned());
    out.push("|---|---|---:|---:|".to_owned());
    for (mcu, name) in names.iter().enumerate() {
        let Some(window) = profiled.operational.get(mcu) else {
            continue;
        };
        let total: u64 = window.functions.iter().map(|(_, n)| n).sum();
        for (function, instructions) in window.functions.iter().take(TOP_FUNCTIONS) {
            out.push(format!(
                "| {name} | `{function}` | {instructions} | {:.1} % |",
                100.0 * *instructions as f64 / total.max(1) as f64
            ));
        }
    }
    let Words { work, unit, .. } = words(protocol);
    out.push(String::new());
    out.push(format!(
        "### Where {work} goes, top {TOP_FUNCTIONS} functions per MCU"
    ));
    out.push(String::new());
    out.push(format!(
        "The activations with {work} (the *per {unit}* column above) in the Operational window, \
         each function's own instructions in them summed and divided by the {unit}s: the \
         wake-up's and the loop's own share of those activations included."
    ));
    out.push(String::new());
    out.push(format!("| MCU | function | per {unit} | share |"));
    out.push("|---|---|---:|---:|".to_owned());
    for (mcu, name) in names.iter().enumerate() {
        let Some(window) = profiled.operational.get(mcu) else {
            continue;
        };
        let total: u64 = window.work_functions.iter().map(|(_, n)| n).sum();
        for (function, instructions) in window.work_functions.iter().take(TOP_FUNCTIONS) {
            out.push(format!(
                "| {name} | `{function}` | {:.0} | {:.1} % |",
                *instructions as f64 / window.pairs.max(1) as f64,
                100.0 * *instructions as f64 / total.max(1) as f64
            ));
        }
    }
    out.push(String::new());
    out.push(
        "### One idle loop iteration of the Operational window, function by function".to_owned(),
    );
    out.push(String::new());
    out.push(
        "The last activation of the window that was one loop iteration woken by the timer \
         alone (the input sample's), its functions in the order they were first entered, \
         each with its own instructions."
            .to_owned(),
    );
    out.push(String::new());
    out.push("| MCU | function | instructions |".to_owned());
    out.push("|---|---|---:|".to_owned());
    for (mcu, name) in names.iter().enumerate() {
        let Some(window) = profiled.operational.get(mcu) else {
            continue;
        };
        for (function, instructions) in &window.idle_iteration {
            out.push(format!("| {name} | `{function}` | {instructions} |"));
        }
    }
    if let Some(window) = profiled.operational.first() {
        out.push(String::new());
        let frames: Vec<String> = window
            .frames
            .iter()
            .map(|(id, count)| format!("{id:03X}h × {count}"))
            .collect();
        out.push(format!(
            "Frames on the bus in the Operational window: {}.",
            frames.join(", ")
        ));
    }
    out
}

/// The introduction of the CANopen Safety images' tables: the windows, what the markers
/// are, the goals.
fn canopen_introduction(pairs: u64) -> Vec<String> {
    vec![
        format!(
            "Each MCU profiled over two windows of one second before the bus load: \
             pre-operational (unconfigured, before the configuration) and Operational ({pairs} \
             pairs of SRDO 1): every translated block counted with its \
             instructions, an *activation* being everything from one wake-up of the core \
             (WFI/WFE) to the next (the interrupt handlers, the channel \
             loop's iteration when the loop task ran, the wait it sets up), classed by the \
             functions it entered (`emulator/src/profile.rs`: the channel loop's `service`, \
             `hand` for a received frame, `Runtime::core_frame` for an SRDO produced, \
             `deliver_clamped` for a validated pair, `VerdictCheck::arrive` for the other \
             channel's verdict, the COBS reassembler for a link message, `Runtime::heartbeat`, \
             the interrupt handlers). All layers: nothing is subtracted."
        ),
        String::new(),
        "*Per pair*: the activations with a pair's work, summed and divided by the pairs (a \
         lower bound: the link bytes of the verdicts are in the USART interrupts' row). *Per \
         pair, all but idle*: every instruction of the window but the idle iterations', \
         divided by the pairs (an upper bound: the link heartbeats are in it). Goals per \
         channel: a pair at most 2,000 instructions, an idle iteration at most 200."
            .to_owned(),
        String::new(),
    ]
}

/// The introduction of the SimpleCAN images' tables: the windows, what the markers are.
fn simplecan_introduction(packets: u64) -> Vec<String> {
    vec![
        format!(
            "Each MCU profiled over two windows of one second: pre-operational (unconfigured, \
             before the configuration) and Operational ({packets} data packets of node 1's \
             SC-ID 30h on the bus, the syncs beside them, node 1's contacts opened and closed \
             once in it): every translated block counted with its instructions, an \
             *activation* being everything from one wake-up of the core (WFI/WFE) to the next \
             (the interrupt handlers, the channel loop's iteration when \
             the loop task ran, the wait it sets up), classed by the functions it entered \
             (`emulator/src/profile.rs`: the channel loop's `service`, `hand` for a received \
             frame, `shared::simplecan::frame::crc` for a packet or sync decoded or produced, \
             `frame::seal` for one produced, `ForwardCheck::pair` for channel A's forwarded \
             copy paired on channel B, `TransmitCheck::judge` for channel A's packet judged \
             against channel B's own (Model A), `VerdictCheck::arrive` for the other channel's \
             verdict, the COBS reassembler for a link message, `Runtime::heartbeat`, the \
             interrupt handlers). All layers: nothing is subtracted."
        ),
        String::new(),
        "*Per packet*: the activations with SimpleCAN's work, summed and divided by the data \
         packets of 30h (the syncs' work is in the sum, so this is more than a packet's own \
         cost; the link bytes of the verdicts are in the USART interrupts' row). *Per packet, \
         all but idle*: every instruction of the window but the idle iterations', divided by \
         the packets (the link heartbeats are in it)."
            .to_owned(),
        String::new(),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An activation of `labels` entered, the loop once if it is among them.
    fn activation(instructions: u64, labels: &[&str]) -> Activation {
        Activation {
            at: 0,
            instructions,
            marks: labels.iter().map(|label| bit(label)).fold(0, |a, b| a | b),
            iterations: u32::from(labels.contains(&"loop")),
        }
    }

    /// The kinds `activation` falls in, by their index in [`kinds`].
    fn kinds_of(activation: &Activation, protocol: Protocol) -> Vec<usize> {
        kinds(protocol)
            .iter()
            .enumerate()
            .filter(|(_, (_, test))| test(activation, protocol))
            .map(|(index, _)| index)
            .collect()
    }

    /// Every activation falls in exactly one kind, and a SimpleCAN activation that decoded or
    /// produced a packet (its CRC), paired channel A's forwarded copy or took a verdict is
    /// SimpleCAN's work on the SimpleCAN images, never idle; a frame handed to the loop
    /// without a packet decoded (a heartbeat) is not.
    #[test]
    fn an_activation_with_a_simplecan_packet_is_simplecans_work() {
        let work = 1;
        let cases: [(&[&str], usize); 9] = [
            (&["loop", "timer"], 0),
            (&["loop", "frame", "SimpleCAN packet"], work),
            (
                &["loop", "SimpleCAN packet", "SimpleCAN sealed", "CAN sent"],
                work,
            ),
            (&["loop", "link message", "SimpleCAN forward paired"], work),
            (&["loop", "link message", "verdict"], work),
            (&["loop", "frame", "SimpleCAN judged"], work),
            (&["loop", "frame"], 4),
            (&["loop", "link message"], 2),
            (&["USART3"], 5),
        ];
        for (labels, kind) in cases {
            let a = activation(100, labels);
            assert_eq!(kinds_of(&a, Protocol::Simplecan), [kind], "{labels:?}");
        }
        // The same frame handed to the loop is a pair's work on the CANopen Safety images
        // (the only frames their filters pass in Operational are SRDOs), and a SimpleCAN
        // packet's markers are not.
        let frame = activation(100, &["loop", "frame"]);
        assert_eq!(kinds_of(&frame, Protocol::CanopenSafety), [work]);
        let packet = activation(100, &["loop", "SimpleCAN packet"]);
        assert_eq!(kinds_of(&packet, Protocol::CanopenSafety), [4]);
        assert!(!is_idle(&packet));
    }

    /// The JSON gives the longest activation with SimpleCAN's work under its own key, and
    /// the longest that ran the loop of any kind.
    #[test]
    fn the_json_gives_the_longest_activation_with_the_protocols_work() {
        let window = Window {
            activations: vec![
                activation(5000, &["loop", "timer"]),
                activation(3000, &["loop", "SimpleCAN packet"]),
                activation(2000, &["loop", "verdict"]),
                activation(9000, &["USART3"]),
            ],
            functions: Vec::new(),
            pairs: 2,
            frames: Vec::new(),
            blocks: Vec::new(),
            idle_iteration: Vec::new(),
            work_functions: Vec::new(),
            work_blocks: Vec::new(),
        };
        let windows = [window];
        let profiled = Profiled {
            protocol: Protocol::Simplecan,
            pre_operational: &windows,
            operational: &windows,
            deepest_stack: &[512],
        };
        let json = json(&profiled, &["node1a".to_owned()]);
        let operational = &json["mcus"][0]["operational"];
        assert_eq!(operational["longest_activation"]["loop"], 5000);
        assert_eq!(
            operational["longest_activation"][work_key(Protocol::Simplecan)],
            3000
        );
        assert_eq!(operational["per_packet"], 2500);
        assert_eq!(operational["packets"], 2);
    }
}
