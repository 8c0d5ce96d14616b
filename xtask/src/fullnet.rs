//! `cargo xtask fullnet` and `cargo xtask reaction`: the full network at scale and the
//! reaction times, by simulation (`system-tests`' `fullnet` program, release build), written
//! into their own generated blocks of `docs/network-performance.md`.
//!
//! `docs/performance.md` is regenerated whole by `cargo xtask bench` and links to that file;
//! the blocks here are replaced only between their markers, so either command leaves the
//! other's results and the hand-written text alone.

use anyhow::{Context, Result, bail};
use std::path::Path;

/// The document the results go to.
pub const DOCUMENT: &str = "docs/network-performance.md";

/// Which part.
#[derive(Clone, Copy)]
pub enum Part {
    /// The full network.
    Network,
    /// The reaction times.
    Reaction,
}

impl Part {
    fn marker(self) -> &'static str {
        match self {
            Part::Network => "fullnet",
            Part::Reaction => "reaction",
        }
    }
}

/// Runs one part with `args` for the program; prints its section and, unless `print_only`,
/// writes it into [`DOCUMENT`].
pub fn task(root: &Path, part: Part, args: &[String], print_only: bool) -> Result<()> {
    let mut command = crate::cargo();
    command.args([
        "run",
        "--quiet",
        "--release",
        "-p",
        "system-tests",
        "--bin",
        "fullnet",
        "--",
    ]);
    command.arg(match part {
        Part::Network => "network",
        Part::Reaction => "reaction",
    });
    command.args(args);
    let output = command
        .stderr(std::process::Stdio::inherit())
        .output()
        .context("running the full-network simulation")?;
    let section = String::from_utf8(output.stdout).context("the simulation's report")?;
    println!("{section}");
    if !output.status.success() {
        bail!(
            "the simulation failed ({}): a channel reported a fault or a margin was not \
             positive; its report is above",
            output.status
        );
    }
    if print_only {
        return Ok(());
    }
    let path = root.join(DOCUMENT);
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("reading {DOCUMENT} (it holds the generated blocks)"))?;
    let updated = replace_block(&text, part.marker(), &section)
        .with_context(|| format!("updating {DOCUMENT}"))?;
    std::fs::write(&path, updated).with_context(|| format!("writing {DOCUMENT}"))?;
    eprintln!("xtask: wrote the {} block of {DOCUMENT}", part.marker());
    if let Part::Network = part {
        write_timing(root, &section)?;
    }
    Ok(())
}

/// The page of benchmarks, where the full network's simulation speed is quoted too.
const PERFORMANCE: &str = "docs/performance.md";
/// Its block for the full network's speed (`cargo xtask bench` keeps it).
pub(crate) const TIMING_MARKER: &str = "fullnet-timing";

/// Quotes the run's command and wall-time lines from `section` in [`PERFORMANCE`]'s
/// [`TIMING_MARKER`] block (added at the end of the page when it has none).
fn write_timing(root: &Path, section: &str) -> Result<()> {
    let quoted: Vec<&str> = section
        .lines()
        .filter(|line| line.starts_with("Command:") || line.starts_with("**Wall time**"))
        .collect();
    if quoted.len() != 2 {
        bail!("the simulation's report has no command or no wall-time line to quote");
    }
    let block = format!(
        "## The full network: simulation speed\n\nFrom [network-performance.md]\
         (network-performance.md), written by `cargo xtask fullnet`.\n\n{}\n\n{}\n",
        quoted[0], quoted[1]
    );
    write_performance_block(root, TIMING_MARKER, &block)
}

/// Writes `block` into [`PERFORMANCE`]'s generated block `marker` (added at the end of the
/// page when it has none); `cargo xtask bench`, which writes the rest of the page, keeps it.
pub(crate) fn write_performance_block(root: &Path, marker: &str, block: &str) -> Result<()> {
    let path = root.join(PERFORMANCE);
    let text = std::fs::read_to_string(&path).unwrap_or_default();
    let updated = replace_block(&text, marker, block).unwrap_or_else(|_| {
        format!(
            "{}\n\n<!-- {marker}:begin (generated, do not edit) -->\n{}\n<!-- {marker}:end -->\n",
            text.trim_end(),
            block.trim_end()
        )
    });
    std::fs::write(&path, updated).with_context(|| format!("writing {PERFORMANCE}"))?;
    eprintln!("xtask: wrote the {marker} block of {PERFORMANCE}");
    Ok(())
}

/// `text` with the lines between `<!-- NAME:begin -->` and `<!-- NAME:end -->` replaced by
/// `section`.
pub(crate) fn replace_block(text: &str, name: &str, section: &str) -> Result<String> {
    let begin = format!("<!-- {name}:begin (generated, do not edit) -->");
    let end = format!("<!-- {name}:end -->");
    let Some(start) = text.find(&begin) else {
        bail!("no `{begin}` marker");
    };
    let Some(stop) = text[start..].find(&end).map(|at| start + at) else {
        bail!("no `{end}` marker after `{begin}`");
    };
    Ok(format!(
        "{}{begin}\n{}\n{}",
        &text[..start],
        section.trim_end(),
        &text[stop..]
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Only the named block changes; the rest of the document and the other block stay.
    #[test]
    fn a_block_is_replaced_between_its_markers_only() {
        let text = "# Title\n\nhand-written\n\n\
                    <!-- fullnet:begin (generated, do not edit) -->\nold\n<!-- fullnet:end -->\n\n\
                    <!-- reaction:begin (generated, do not edit) -->\nkept\n<!-- reaction:end -->\n";
        let updated = replace_block(text, "fullnet", "new\nlines\n").unwrap();
        assert_eq!(
            updated,
            "# Title\n\nhand-written\n\n\
             <!-- fullnet:begin (generated, do not edit) -->\nnew\nlines\n<!-- fullnet:end -->\n\n\
             <!-- reaction:begin (generated, do not edit) -->\nkept\n<!-- reaction:end -->\n"
        );
        assert!(replace_block(text, "missing", "x").is_err());
    }
}
