//! The campaigns' report: the table for `docs/campaigns.md` and one SVG plot per class (the
//! distribution of detection latencies against the class's bound).

use super::{Class, Summary, oracle::REACTION};
use plotters::prelude::*;
use std::fmt::Write as _;
use std::path::Path;

fn ms(micros: u64) -> String {
    format!("{:.3}", micros as f64 / 1000.0)
}

/// The Markdown table, one row per class.
pub fn table(results: &[(Class, Summary)]) -> String {
    let mut text = String::from(
        "| class | requirement | injected | detected | harmless | unsafe | late | harness | max latency (ms) | bound (ms) | max reaction after the oracle's deadline (µs) |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for (class, summary) in results {
        let (bound, _) = class.bound();
        let _ = writeln!(
            text,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            class.name(),
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

/// How each class's bound follows from the configuration.
pub fn bounds(results: &[(Class, Summary)]) -> String {
    let mut text = String::new();
    for (class, _) in results {
        let (bound, why) = class.bound();
        let _ = writeln!(
            text,
            "- **{}** ({} ms): {why}.",
            class.name(),
            ms(bound.as_micros())
        );
    }
    let _ = writeln!(
        text,
        "\nThe reaction allowance is the oracle's `REACTION` ({} ms).",
        ms(REACTION.as_micros())
    );
    text
}

/// Writes `dir/<class>.svg`: the latency histogram (1 ms bins) with the bound marked.
pub fn plot(dir: &Path, class: Class, summary: &Summary) -> Result<(), String> {
    let path = dir.join(format!("{}.svg", class.name()));
    let (bound, _) = class.bound();
    let bound_ms = bound.as_micros().div_ceil(1000) as u32;
    let top = bound_ms + 5;
    let mut bins = vec![0u32; top as usize + 1];
    for latency in &summary.latencies {
        let bin = (*latency / 1000).min(u64::from(top)) as usize;
        bins[bin] += 1;
    }
    let highest = bins.iter().copied().max().unwrap_or(0).max(1);
    let root = SVGBackend::new(&path, (720, 360)).into_drawing_area();
    let draw = |error: DrawingAreaErrorKind<_>| format!("{}: {error}", path.display());
    root.fill(&WHITE).map_err(draw)?;
    let caption = format!(
        "{}: {} detected of {} injected, latency (ms) against the bound {} ms",
        class.name(),
        summary.detected,
        summary.injected,
        ms(bound.as_micros())
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
        .x_desc("detection latency (ms, 1 ms bins)")
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
            vec![(bound_ms, 0), (bound_ms, highest + highest / 10 + 1)],
            RED.stroke_width(2),
        )))
        .map_err(draw)?
        .label("bound");
    root.present().map_err(draw)?;
    Ok(())
}
