//! The campaigns' report: the table for `docs/campaigns.md` and one SVG plot per class (the
//! distribution of detection latencies against the class's bound).

use super::{Class, Summary, oracle::REACTION};
use plotters::prelude::*;
use std::fmt::Write as _;
use std::path::Path;

fn ms(micros: u64) -> String {
    format!("{:.3}", micros as f64 / 1000.0)
}

/// One row of the report: a class at a bit rate, and what its campaign found.
pub type Row = (Class, u32, Summary);

/// The plot's file name for `class` at `bit_rate`.
pub fn plot_name(class: Class, bit_rate: u32) -> String {
    format!("{}-{}k.svg", class.name(), bit_rate / 1000)
}

/// The Markdown table, one row per class and bit rate.
pub fn table(results: &[Row]) -> String {
    let mut text = String::from(
        "| class | kbit/s | requirement | injected | detected | harmless | unsafe | late | harness | max latency (ms) | bound (ms) | max reaction after the oracle's deadline (µs) |\n|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for (class, bit_rate, summary) in results {
        let (bound, _) = class.bound(*bit_rate);
        let _ = writeln!(
            text,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            class.name(),
            bit_rate / 1000,
            class.requirement(),
            summary.injected,
            summary.detected,
            summary.harmless,
            summary.unsafe_,
            summary.late,
            summary.harness,
            summary.max_latency().map_or("–".to_string(), ms),
            ms(bound.as_micros()),
            summary.max_reaction,
        );
    }
    text
}

/// How each class's bound follows from the configuration, with its value at each bit rate.
pub fn bounds(results: &[Row]) -> String {
    let mut text = String::new();
    let mut classes: Vec<Class> = results.iter().map(|(class, ..)| *class).collect();
    classes.dedup();
    for class in classes {
        let (_, why) = class.bound(super::BIT_RATE);
        let values: Vec<String> = results
            .iter()
            .filter(|(row, ..)| *row == class)
            .map(|(_, bit_rate, _)| {
                format!(
                    "{} ms at {} kbit/s",
                    ms(class.bound(*bit_rate).0.as_micros()),
                    bit_rate / 1000
                )
            })
            .collect();
        let _ = writeln!(
            text,
            "- **{}** ({}): {why}.",
            class.name(),
            values.join(", ")
        );
    }
    let _ = writeln!(
        text,
        "\nThe frame allowance is two frames of {} bits (`LONGEST_FRAME_BITS`): {}.",
        super::LONGEST_FRAME_BITS,
        super::BIT_RATES
            .map(|rate| format!(
                "{} µs at {} kbit/s",
                super::frame_allowance(rate).as_micros(),
                rate / 1000
            ))
            .join(", ")
    );
    let _ = writeln!(
        text,
        "\nThe reaction allowance is the oracle's `REACTION` ({} ms).",
        ms(REACTION.as_micros())
    );
    text
}

/// Writes `dir/<class>-<kbit/s>k.svg`: the latency histogram (1 ms bins) with the bound
/// marked.
pub fn plot(dir: &Path, class: Class, bit_rate: u32, summary: &Summary) -> Result<(), String> {
    let (bound, _) = class.bound(bit_rate);
    let title = format!("{} at {} kbit/s", class.name(), bit_rate / 1000);
    let counts = (summary.detected, summary.injected);
    histogram(
        &dir.join(plot_name(class, bit_rate)),
        &title,
        bound.as_micros(),
        &summary.latencies,
        counts,
    )
}

/// Writes the SVG at `path`: a histogram of `latencies` (µs) with `bound_us` marked, titled
/// `title` with `counts` (detected, injected). The bins are 1 ms wide, wider where the bound
/// is beyond 100 ms (at most about 100 bins); a latency beyond the plot's end counts in its
/// last bin.
pub fn histogram(
    path: &Path,
    title: &str,
    bound_us: u64,
    latencies: &[u64],
    (detected, injected): (u64, u64),
) -> Result<(), String> {
    let bin_ms = bound_us.div_ceil(100_000).max(1);
    let bin_us = bin_ms * 1000;
    let bound_bin = bound_us.div_ceil(bin_us) as u32;
    let top = bound_bin + 5;
    let mut bins = vec![0u32; top as usize + 1];
    for latency in latencies {
        let bin = (*latency / bin_us).min(u64::from(top)) as usize;
        bins[bin] += 1;
    }
    let highest = bins.iter().copied().max().unwrap_or(0).max(1);
    let root = SVGBackend::new(path, (720, 360)).into_drawing_area();
    let draw = |error: DrawingAreaErrorKind<_>| format!("{}: {error}", path.display());
    root.fill(&WHITE).map_err(draw)?;
    let caption = format!(
        "{title}: {detected} detected of {injected} injected, latency (ms) against the bound {} ms",
        ms(bound_us)
    );
    let mut chart = ChartBuilder::on(&root)
        .caption(caption, ("sans-serif", 16))
        .margin(10)
        .x_label_area_size(35)
        .y_label_area_size(50)
        .build_cartesian_2d(0u32..top + 1, 0u32..highest + highest / 10 + 1)
        .map_err(draw)?;
    chart
        .configure_mesh()
        .x_label_formatter(&|bin| (u64::from(*bin) * bin_ms).to_string())
        .x_desc(format!("detection latency (ms, {bin_ms} ms bins)"))
        .y_desc("scenarios")
        .draw()
        .map_err(draw)?;
    chart
        .draw_series(
            Histogram::vertical(&chart).style(BLUE.filled()).data(
                bins.iter()
                    .enumerate()
                    .map(|(bin, count)| (bin as u32, *count)),
            ),
        )
        .map_err(draw)?;
    chart
        .draw_series(std::iter::once(PathElement::new(
            vec![(bound_bin, 0), (bound_bin, highest + highest / 10 + 1)],
            RED.stroke_width(2),
        )))
        .map_err(draw)?
        .label("bound");
    root.present().map_err(draw)?;
    Ok(())
}
