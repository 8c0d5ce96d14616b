//! `cargo xtask bench --target-cost --protocol simplecan`: the same trace as the CANopen
//! Safety images' ([`super::trace`]), on the emulated network speaking SimpleCAN (the QEMU
//! images with SimpleCAN beside the SRDO table, node 1 producing SC-ID 30h and sending the
//! syncs, node 33 consuming it), counted by loop iteration: SimpleCAN's processing step,
//! written into its own block of `docs/performance.md` and into
//! `tool/src/calc/target_measured_simplecan.rs`.
//!
//! The SimpleCAN images inline much of what the CANopen Safety count tracks (the core's poll,
//! the verdict check, the heartbeat), so this count tracks only the loop iteration, `hand`
//! and the QEMU layer's frame and link markers: an iteration that received or sent a frame
//! handled SimpleCAN's traffic (on this network the packets of 30h, the syncs, the
//! heartbeats), the markers' own instructions subtracted as for CANopen Safety.

use super::count::{self, Counted};
use super::{Spread, TargetCost, address, cost};
use crate::images::{self, Layer};
use crate::network::CHANNELS;
use crate::toolchain::Cross;
use anyhow::{Context, Result};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The block's marker name in `docs/performance.md`.
pub(crate) const MARKER: &str = "target-cost-simplecan";
/// The generated constants of SimpleCAN's processing step.
const MEASURED_RS: &str = "tool/src/calc/target_measured_simplecan.rs";

/// The tracked functions, by the end of their demangled names (each must name one symbol).
const TRACKED: [&str; 5] = [
    "dual_channel::channel_loop::ChannelLoop::service",
    "dual_channel::channel_loop::hand",
    "board::qemu::marker::received",
    "board::qemu::marker::transmitted",
    "board::qemu::marker::link_received",
];
const SERVICE: usize = 0;
const HAND: usize = 1;
const RECEIVED: usize = 2;
const TRANSMITTED: usize = 3;
const LINK: usize = 4;
/// The markers called by the loop: their instructions are not the loop's.
const MARKERS: [usize; 3] = [RECEIVED, TRANSMITTED, LINK];

/// One channel's loop iterations, markers subtracted.
#[derive(Debug, Default)]
struct Channel {
    /// Every iteration.
    all: Vec<u64>,
    /// The iterations that received or sent a frame.
    frames: Vec<u64>,
    /// The iterations that handled nothing: no frame, no link bytes.
    idle: Vec<u64>,
}

impl Channel {
    fn of(counted: &Counted) -> Channel {
        let mut channel = Channel::default();
        for call in counted.calls.iter().filter(|call| call.function == SERVICE) {
            let own = call.without(&MARKERS);
            channel.all.push(own);
            if call.made(RECEIVED) || call.made(TRANSMITTED) {
                channel.frames.push(own);
            } else if !call.made(LINK) && !call.made(HAND) {
                channel.idle.push(own);
            }
        }
        channel
    }
}

/// The SimpleCAN images' counts: the block, the constants, SimpleCAN's processing step.
pub(super) fn run(root: &Path, cross: &Cross, traces: &[PathBuf; 4], traced: f64) -> Result<()> {
    let mut channels = Vec::new();
    for ((name, _, side), trace) in CHANNELS.into_iter().zip(traces) {
        let image = images::image(cross, root, Layer::QemuSimpleCan, side);
        let entries = TRACKED
            .iter()
            .map(|name| address(&image, name))
            .collect::<Result<Vec<u32>>>()?;
        let counted = count::count_calls(trace, &entries, &[SERVICE])?;
        // Gigabytes; the counts are what was wanted.
        let _ = std::fs::remove_file(trace);
        let channel = Channel::of(&counted);
        eprintln!(
            "xtask: {name}: {} loop iterations, {} with a frame received or sent, {} idle ({} \
             trace lines)",
            channel.all.len(),
            channel.frames.len(),
            channel.idle.len(),
            counted.lines
        );
        channels.push((name, channel));
    }
    let (block, measured) = render(&channels, traced)?;
    println!("{block}");
    let path = root.join(super::DOCUMENT);
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", super::DOCUMENT))?;
    let updated = crate::fullnet::replace_block(&text, MARKER, &block)
        .with_context(|| format!("{} has no {MARKER} block", super::DOCUMENT))?;
    std::fs::write(&path, updated).with_context(|| format!("writing {}", super::DOCUMENT))?;
    std::fs::write(root.join(MEASURED_RS), measured_rs(&measured))
        .with_context(|| format!("writing {MEASURED_RS}"))?;
    eprintln!(
        "xtask: wrote the {MARKER} block of {} and {MEASURED_RS} (SimpleCAN's processing step \
         {} µs): run `cargo xtask manual` for the manual",
        super::DOCUMENT,
        measured.processing_us()
    );
    Ok(())
}

/// The block of `docs/performance.md` and the measured constants.
fn render(channels: &[(&str, Channel)], traced: f64) -> Result<(String, TargetCost)> {
    let spread = |name: &str, what: &str, values: &Vec<u64>| {
        Spread::of(values.clone()).with_context(|| {
            format!(
                "the trace of {name} holds no {what} (the network ran too briefly, or a tracked \
                 function is no longer called by `bl`)"
            )
        })
    };
    let mut md = String::new();
    let _ = writeln!(
        md,
        "## On the target with SimpleCAN: Thumb instructions under QEMU\n\n\
         Generated by `cargo xtask bench --target-cost --protocol simplecan` \
         (`xtask/src/target_cost/simplecan.rs`): the emulated network of `cargo xtask run \
         --protocol simplecan` (the QEMU images with SimpleCAN beside the SRDO table; node 1 \
         produces SC-ID 30h in slot 0 and sends the syncs, node 33 consumes it), configured and \
         Operational, each of the four images traced as in the block above, for at least \
         {traced:.2} s of the network's time each, the emergency stop pressed and released once. \
         The unit is one iteration of the channel loop, the QEMU layer's markers subtracted; \
         an iteration that received or sent a frame handled the network's traffic (the \
         packets of 30h, the syncs, the heartbeats).\n"
    );
    let _ = writeln!(
        md,
        "| image | iterations | fewest | median | most | seen |\n|---|---|---:|---:|---:|---:|"
    );
    for (name, channel) in channels {
        for (what, values) in [
            ("every iteration", &channel.all),
            ("a frame received or sent", &channel.frames),
            ("idle: no frame, no link bytes", &channel.idle),
        ] {
            let s = spread(name, what, values)?;
            let _ = writeln!(
                md,
                "| {name} | {what} | {} | {} | {} | {} |",
                s.fewest, s.median, s.most, s.seen
            );
        }
    }
    let most = |pick: fn(&Channel) -> &Vec<u64>| {
        channels
            .iter()
            .flat_map(|(_, channel)| pick(channel).iter().copied())
            .max()
            .unwrap_or(0)
    };
    let measured = TargetCost {
        longest_iteration: most(|c| &c.all),
        longest_protocol_iteration: most(|c| &c.frames),
    };
    let _ = writeln!(
        md,
        "\n**SimpleCAN's processing step** (`safety_config::calc::target::MEASURED_SIMPLECAN`, \
         the safety manual's SimpleCAN reaction times): the wake-up allowed by argument ({} \
         instructions), the longest loop iteration of any kind ({}), the board's work after it \
         allowed by analysis ({}), and the longest iteration that received or sent a frame \
         ({}): {} instructions, at {} cycles per instruction on {} MHz and doubled for \
         interrupts, rounded up to 10 µs: **{} µs**. Observed in Operational with the packets \
         and syncs flowing; iterations that handle SDO requests, NMT commands or the parameter \
         store were not traced.",
        cost::WAKE_INSTRUCTIONS,
        measured.longest_iteration,
        cost::BETWEEN_ITERATIONS,
        measured.longest_protocol_iteration,
        measured.path_instructions(),
        cost::CPI_BOUND,
        cost::CLOCK_HZ / 1_000_000,
        measured.processing_us()
    );
    Ok((md, measured))
}

/// The generated constants of SimpleCAN's processing step.
fn measured_rs(measured: &TargetCost) -> String {
    format!(
        "//! Generated by `cargo xtask bench --target-cost --protocol simplecan` (do not edit): the\n\
         //! instructions it counted in the QEMU images with SimpleCAN, which [`super::target`] turns\n\
         //! into SimpleCAN's processing step.\n\n\
         use super::target::TargetCost;\n\n\
         /// Counted by `cargo xtask bench --target-cost --protocol simplecan`.\n\
         pub const MEASURED_SIMPLECAN: TargetCost = TargetCost {{\n    \
         longest_iteration: {},\n    \
         longest_protocol_iteration: {},\n\
         }};\n",
        measured.longest_iteration, measured.longest_protocol_iteration
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use count::Call;

    /// An iteration that received or sent a frame is a frame iteration, markers subtracted;
    /// one with link bytes only is neither that nor idle; one that did nothing is idle.
    #[test]
    fn iterations_are_sorted_by_what_they_handled_markers_subtracted() {
        let call = |instructions, nested: Vec<(usize, u64)>| Call {
            function: SERVICE,
            instructions,
            nested,
            symbols: Vec::new(),
        };
        let counted = Counted {
            calls: vec![
                call(1000, vec![(RECEIVED, 100), (HAND, 600)]),
                call(500, vec![(TRANSMITTED, 50)]),
                call(300, vec![(LINK, 40)]),
                call(200, vec![]),
            ],
            lines: 2000,
        };
        let channel = Channel::of(&counted);
        assert_eq!(channel.all, [900, 450, 260, 200]);
        assert_eq!(channel.frames, [900, 450]);
        assert_eq!(channel.idle, [200]);
    }

    /// The generated file is the constants it was given, as the tool reads them.
    #[test]
    fn the_generated_constants_are_the_measurement() {
        let text = measured_rs(&TargetCost {
            longest_iteration: 12345,
            longest_protocol_iteration: 678,
        });
        assert!(text.contains("pub const MEASURED_SIMPLECAN: TargetCost = TargetCost {"));
        assert!(text.contains("    longest_iteration: 12345,\n"));
        assert!(text.contains("    longest_protocol_iteration: 678,\n"));
    }
}
