//! The nominal case's profiles as Markdown ([`crate::cases::Nominal`], [`crate::profile`]):
//! per MCU, the cost of an idle loop iteration, of a pair, of what else woke the core, the
//! functions the instructions went to, and the deepest stack. `emulate-network --nominal`
//! prints these lines and `cargo xtask` writes them into `docs/emulated-figures.md`; no figure
//! is written anywhere else.

use crate::cases::{Nominal, Window};
use crate::profile::{Activation, bit};

/// How many functions each MCU's table lists.
const TOP_FUNCTIONS: usize = 12;

/// A test on an activation's markers.
type Test = fn(&Activation) -> bool;

/// The kinds of activation, in the order the tables list them: a label and a test on the
/// markers entered.
const KINDS: [(&str, Test); 7] = [
    (
        "idle loop iteration (nothing received, nothing sent)",
        is_idle,
    ),
    (
        "loop iteration with a pair's work (an SRDO frame handled or produced, a verdict)",
        is_pair,
    ),
    (
        "loop iteration with a link message received, no pair's work",
        |a| a.has("loop") && !is_pair(a) && a.has("link message"),
    ),
    (
        "loop iteration sending the link heartbeat, no pair's work",
        |a| a.has("loop") && !is_pair(a) && !a.has("link message") && a.has("heartbeat"),
    ),
    (
        "other loop iteration (other frames or link messages sent)",
        |a| {
            a.has("loop")
                && !is_pair(a)
                && !is_idle(a)
                && !a.has("link message")
                && !a.has("heartbeat")
        },
    ),
    ("interrupts only: the link USART (a byte in or out)", |a| {
        !a.has("loop") && a.has("USART3")
    }),
    ("interrupts only: other (CAN, timer, executor)", |a| {
        !a.has("loop") && !a.has("USART3")
    }),
];

/// A loop iteration that received nothing and sent nothing.
fn is_idle(activation: &Activation) -> bool {
    let busy = bit("frame")
        | bit("link message")
        | bit("link sent")
        | bit("heartbeat")
        | bit("CAN sent")
        | bit("SRDO produced")
        | bit("pair validated")
        | bit("verdict");
    activation.has("loop") && activation.marks & busy == 0
}

/// A loop iteration that did a pair's work: an SRDO frame handled (in the Operational window
/// without load, the only frames the channels' filters pass) or produced, a pair validated,
/// the other channel's verdict taken.
fn is_pair(activation: &Activation) -> bool {
    let pair = bit("frame") | bit("SRDO produced") | bit("pair validated") | bit("verdict");
    activation.has("loop") && activation.marks & pair != 0
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

fn totals(window: &Window) -> Totals {
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
            .filter(|a| is_pair(a))
            .map(|a| a.instructions)
            .sum(),
        link_interrupts: link.len(),
        link_interrupt_median: spread(&mut link).1,
    }
}

/// The same figures machine-readable, one JSON object: per MCU and window, the longest
/// activation that ran the loop and the longest with a pair's work (the processing step's
/// path, `cargo xtask bench --target-cost`), the instructions, the loop iterations, the idle
/// iteration (fewest, median, most), the instructions per pair (the lower bound of
/// [`markdown`]'s *per pair*) and the pairs; per MCU, the deepest stack; the goals per
/// channel.
pub fn json(nominal: &Nominal, names: &[String]) -> serde_json::Value {
    let window = |window: &Window| {
        let t = totals(window);
        let longest = |test: Test| {
            window
                .activations
                .iter()
                .filter(|a| test(a))
                .map(|a| a.instructions)
                .max()
        };
        serde_json::json!({
            "longest_activation": {
                "loop": longest(|a| a.has("loop")),
                "pair": longest(is_pair),
            },
            "instructions": t.instructions,
            "loop_iterations": t.iterations,
            "idle_iteration": {"fewest": t.idle.0, "median": t.idle.1, "most": t.idle.2},
            "per_pair": t.pair_instructions.checked_div(window.pairs),
            "pairs": window.pairs,
            "link_usart_interrupts": t.link_interrupts,
        })
    };
    let mcus: Vec<serde_json::Value> = names
        .iter()
        .enumerate()
        .map(|(mcu, name)| {
            serde_json::json!({
                "mcu": name,
                "pre_operational": nominal.pre_operational.get(mcu).map(window),
                "operational": nominal.operational.get(mcu).map(window),
                "deepest_stack_bytes": nominal.deepest_stack.get(mcu),
            })
        })
        .collect();
    serde_json::json!({
        "unit": "Thumb instructions executed, counted by the emulator; windows of one second",
        "goals_per_channel": {"per_pair": 2000, "idle_iteration": 200},
        "mcus": mcus,
    })
}

/// The Markdown of the profiles (no trailing blank line).
pub fn markdown(nominal: &Nominal, names: &[String]) -> Vec<String> {
    let mut out = Vec::new();
    let pairs = nominal.operational.first().map_or(0, |w| w.pairs);
    out.push("## Where the instructions go (profiled by the emulator)".to_owned());
    out.push(String::new());
    out.push(format!(
        "Each MCU profiled over two windows of one second before the bus load: \
         pre-operational (unconfigured, before the configuration) and Operational ({pairs} \
         pairs of SRDO 1): every translated block counted with its \
         instructions, an *activation* being everything from one wake-up of the core (WFI/WFE) \
         to the next (the interrupt handlers, embassy's executor, the channel loop's iteration \
         when the loop task ran, the wait it sets up), classed by the functions it entered \
         (`emulator/src/profile.rs`: the channel loop's `service`, `hand` for a received \
         frame, `Runtime::core_frame` for an SRDO produced, `deliver_clamped` for a validated \
         pair, `VerdictCheck::arrive` for the other channel's verdict, the COBS reassembler \
         for a link message, `Runtime::heartbeat`, the interrupt handlers). All layers: \
         nothing is subtracted."
    ));
    out.push(String::new());
    out.push(
        "*Per pair*: the activations with a pair's work, summed and divided by the pairs (a \
         lower bound: the link bytes of the verdicts are in the USART interrupts' row). *Per \
         pair, all but idle*: every instruction of the window but the idle iterations', \
         divided by the pairs (an upper bound: the link heartbeats are in it). Goals per \
         channel: a pair at most 2,000 instructions, an idle iteration at most 200."
            .to_owned(),
    );
    out.push(String::new());
    out.push(
        "| MCU | window | instructions | loop iterations | idle iteration (fewest / median / \
         most) | per pair | per pair, all but idle | link USART interrupts (median each) | \
         deepest stack |"
            .to_owned(),
    );
    out.push("|---|---|---:|---:|---:|---:|---:|---:|---:|".to_owned());
    for (mcu, name) in names.iter().enumerate() {
        for (label, windows) in [
            ("pre-operational", &nominal.pre_operational),
            ("Operational", &nominal.operational),
        ] {
            let Some(window) = windows.get(mcu) else {
                continue;
            };
            let t = totals(window);
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
                nominal
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
        let Some(window) = nominal.operational.get(mcu) else {
            continue;
        };
        let total: u64 = window.activations.iter().map(|a| a.instructions).sum();
        for (kind, test) in KINDS {
            let mut counts: Vec<u64> = window
                .activations
                .iter()
                .filter(|a| test(a))
                .map(|a| a.instructions)
                .collect();
            let iterations: u32 = window
                .activations
                .iter()
                .filter(|a| test(a))
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
        let Some(window) = nominal.operational.get(mcu) else {
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
        let Some(window) = nominal.operational.get(mcu) else {
            continue;
        };
        for (function, instructions) in &window.idle_iteration {
            out.push(format!("| {name} | `{function}` | {instructions} |"));
        }
    }
    if let Some(window) = nominal.operational.first() {
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
