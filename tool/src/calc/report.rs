//! The calculators' results as text, the same for `safety-config` and the safety manual.

use super::budget::Budget;
use super::residual::Sil;
use super::sfrt::{DeviceTiming, Part, Reaction};
use super::simplecan::{ScReaction, ScResidual};
use std::fmt::Write;

/// Microseconds as milliseconds with three decimals.
#[must_use]
pub fn ms(micros: u64) -> String {
    format!("{}.{:03}", micros / 1000, micros % 1000)
}

/// A reaction as a Markdown table: its parts, the fault-free sum, the path with one fault
/// (`one_fault`: what that fault is) and the larger of the two.
fn breakdown(
    parts: &[Part],
    fault_free_us: u64,
    one_fault: &str,
    one_fault_us: u64,
    worst_us: u64,
) -> String {
    let mut out = String::from("| part | worst case (ms) |\n|---|---:|\n");
    for part in parts {
        let _ = writeln!(out, "| {} | {} |", part.what, ms(part.micros));
    }
    let _ = writeln!(out, "| **fault-free** | **{}** |", ms(fault_free_us));
    let _ = writeln!(out, "| {one_fault} | {} |", ms(one_fault_us));
    let _ = writeln!(
        out,
        "| **worst case: the network's part of the SFRT** | **{}** |",
        ms(worst_us)
    );
    out
}

/// One safety function's breakdown as a Markdown table.
#[must_use]
pub fn reaction_table(reaction: &Reaction) -> String {
    let mut out = breakdown(
        &reaction.parts,
        reaction.fault_free_us,
        "with one communication fault (SCT, one frame, one step, output)",
        reaction.one_fault_us,
        reaction.worst_us,
    );
    let _ = writeln!(
        out,
        "| GFC, from its transmit queue | {} |",
        ms(reaction.gfc_us)
    );
    out
}

/// Every safety function of a network, for `safety-config sfrt`.
#[must_use]
pub fn reactions(reactions: &[Reaction], bit_rate: u32, timing: &DeviceTiming) -> String {
    let mut out = String::new();
    for reaction in reactions {
        let _ = writeln!(
            out,
            "node {} SRDO {} -> node {} SRDO {} at {} kbit/s:\n",
            reaction.producer.0,
            reaction.producer.1,
            reaction.consumer.0,
            reaction.consumer.1,
            bit_rate / 1000
        );
        out.push_str(&reaction_table(reaction));
        out.push('\n');
    }
    let _ = writeln!(
        out,
        "Assumed: input sample {} ms, contact skew up to {} ms, link {} µs per byte, {} ms per channel step{}, output stage {} ms. Not included: the sensor, the actuator, and the controller if there is one (EN 50325-5 9.3.1 formula (3) adds them).",
        ms(timing.input_sample_us),
        ms(timing.contact_skew_us),
        timing.link_byte_us,
        ms(timing.processing_us),
        if timing.processing_us == super::target::MEASURED.processing_us() {
            " (instructions counted in the shipped images on the emulated STM32F405, cycles per instruction bounded by assumption: `safety_config::calc::target`)"
        } else {
            ""
        },
        ms(timing.output_us)
    );
    out
}

/// A plan's budget, for `safety-config budget`.
#[must_use]
pub fn budget(budget: &Budget, sil: Sil) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "SRDO producers: {}; safety devices: {}; SRDOs per second: {:.1}.\n",
        budget.producers, budget.devices, budget.srdos_per_second
    );
    out.push_str("| kbit/s | worst-case bus load |\n|---:|---:|\n");
    for (rate, load) in &budget.loads {
        let _ = writeln!(out, "| {} | {:.1} % |", rate / 1000, load * 100.0);
    }
    let _ = writeln!(
        out,
        "\nResidual error rate (EN 50325-5 9.4.2, DSP 304 9.3): {:.2e} per hour; SIL {} allows below {:.0e} per hour, at most {:.1} SRDOs per second with {} devices. Highest SIL met: {}.",
        budget.rate_per_hour,
        sil.level(),
        sil.limit_per_hour(),
        budget.max_srdos_per_second,
        budget.devices,
        budget
            .highest_sil
            .map_or("none".to_owned(), |sil| format!("SIL {}", sil.level()))
    );
    for warning in &budget.warnings {
        let _ = writeln!(out, "warning: {warning}");
    }
    out
}

/// Every consumed SC-ID of a SimpleCAN network, for `safety-config sfrt` on a file with a
/// `[simplecan]` section.
#[must_use]
pub fn simplecan_reactions(
    reactions: &[ScReaction],
    bit_rate: u32,
    timing: &DeviceTiming,
) -> String {
    let mut out = String::new();
    for reaction in reactions {
        let _ = writeln!(
            out,
            "node {} SimpleCAN SC-ID {:02X}h -> node {} at {} kbit/s:\n",
            reaction.producer,
            reaction.sc_id,
            reaction.consumer,
            bit_rate / 1000
        );
        out.push_str(&breakdown(
            &reaction.parts,
            reaction.fault_free_us,
            "with the packet after the demand lost (safety timeout, SC_REQ_20)",
            reaction.one_fault_us,
            reaction.worst_us,
        ));
        out.push('\n');
    }
    if !reactions.is_empty() {
        let _ = writeln!(
            out,
            "SimpleCAN's channel step: {} ms{}.\n",
            ms(timing.processing_us),
            if timing.processing_us == super::target::MEASURED_SIMPLECAN.processing_us() {
                " (instructions counted in the shipped SimpleCAN images on the emulated STM32F405, cycles per instruction bounded by assumption: `safety_config::calc::target`)"
            } else {
                ""
            }
        );
    }
    out
}

/// A SimpleCAN network's residual error rate against its share of a SIL's limit, for
/// `safety-config budget` on a file with a `[simplecan]` section.
#[must_use]
pub fn simplecan_residual(residual: &ScResidual, sil: Sil) -> String {
    let mut out = format!(
        "\nSimpleCAN residual error rate (SC_REQ_04, docs/simplecan.md section 8): {:.2e} per hour at {:.1} packets per second; SimpleCAN's share of SIL {} is below {:.0e} per hour.\n",
        residual.rate_per_hour,
        residual.packets_per_second,
        sil.level(),
        residual.limit_per_hour
    );
    if !residual.within() {
        let _ = writeln!(
            out,
            "warning: the SimpleCAN residual error rate {:.2e} per hour exceeds SIL {}'s share {:.0e} per hour: fewer producer slots or a longer cycle",
            residual.rate_per_hour,
            sil.level(),
            residual.limit_per_hour
        );
    }
    out
}
