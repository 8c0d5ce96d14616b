//! Generated pages that are committed: the committed copy, and where a fresh one differs from it.
//!
//! `cargo xtask test` writes the traceability matrix afresh and fails when it differs from the
//! committed one (docs/overview.md, "Generated pages"), naming the first lines that differ, so
//! that a committed page never claims what no run showed.

use std::path::Path;
use std::process::Command;

/// Changed lines shown where two texts differ.
const SHOWN_LINES: usize = 12;
/// Characters of a line shown before it is cut.
const SHOWN_CHARACTERS: usize = 200;

/// The committed text of `relative` (a path from the workspace root): the `HEAD` commit's
/// (`git show HEAD:<path>`), or the file as it stands when git cannot say (not a checkout, no
/// git), or `None` when there is neither.
pub fn committed(root: &Path, relative: &str) -> Option<String> {
    let shown = Command::new("git")
        .current_dir(root)
        .args(["show", &format!("HEAD:{relative}")])
        .output();
    match shown {
        Ok(output) if output.status.success() => {
            Some(String::from_utf8_lossy(&output.stdout).into_owned())
        }
        _ => std::fs::read_to_string(root.join(relative)).ok(),
    }
}

/// Where `fresh` differs from `committed`, line by line (`similar`'s diff): a sentence and the
/// differing lines, `-` the committed page's and `+` the fresh one's, each with its line
/// number; a line changed in place is shown from a little before its first changed character.
/// `None` when they are the same text.
pub fn difference(committed: &str, fresh: &str) -> Option<String> {
    if committed == fresh {
        return None;
    }
    let old: Vec<&str> = committed.lines().collect();
    let new: Vec<&str> = fresh.lines().collect();
    let diff = similar::TextDiff::from_lines(committed, fresh);
    // (sign, line number, line, the line it replaces or is replaced by)
    let mut changes: Vec<(char, usize, &str, Option<&str>)> = Vec::new();
    for op in diff.ops() {
        let (tag, removed, added) = op.as_tag_tuple();
        if tag == similar::DiffTag::Equal {
            continue;
        }
        for (offset, index) in removed.clone().enumerate() {
            let pair = paired(offset, &added, &new);
            changes.push(('-', index + 1, old.get(index).copied().unwrap_or(""), pair));
        }
        for (offset, index) in added.clone().enumerate() {
            let pair = paired(offset, &removed, &old);
            changes.push(('+', index + 1, new.get(index).copied().unwrap_or(""), pair));
        }
    }
    let count = |wanted: char| changes.iter().filter(|change| change.0 == wanted).count();
    let mut text = format!(
        "{} line(s) of the committed page are not in the fresh one and {} of the fresh one are \
         new",
        count('-'),
        count('+')
    );
    for (sign, number, line, pair) in changes.iter().take(SHOWN_LINES) {
        text.push_str(&format!("\n  {sign} {number}: {}", shown(line, *pair)));
    }
    if changes.len() > SHOWN_LINES {
        text.push_str(&format!(
            "\n  … and {} more changed line(s)",
            changes.len() - SHOWN_LINES
        ));
    }
    Some(text)
}

/// The line of `lines` at `offset` into `range`, when the range is that long.
fn paired<'a>(offset: usize, range: &std::ops::Range<usize>, lines: &[&'a str]) -> Option<&'a str> {
    let index = range.start + offset;
    if index < range.end {
        lines.get(index).copied()
    } else {
        None
    }
}

/// `line` cut to [`SHOWN_CHARACTERS`], starting a little before where it first differs from
/// `pair` (the line it replaces, or is replaced by), so that the change is in what is shown.
fn shown(line: &str, pair: Option<&str>) -> String {
    let first_difference = pair.map_or(0, |pair| {
        line.chars()
            .zip(pair.chars())
            .take_while(|(a, b)| a == b)
            .count()
    });
    let skip = first_difference.saturating_sub(SHOWN_CHARACTERS / 4);
    let total = line.chars().count();
    let mut text: String = if skip > 0 {
        "…".into()
    } else {
        String::new()
    };
    text.extend(line.chars().skip(skip).take(SHOWN_CHARACTERS));
    if skip + SHOWN_CHARACTERS < total {
        text.push_str(" …");
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_same_text_has_no_difference() {
        assert_eq!(difference("a\nb\n", "a\nb\n"), None);
    }

    #[test]
    fn changed_lines_are_named_by_their_numbers_and_equal_ones_are_not_shown() {
        let committed = "title\n1251 tests ran\nsame\nsame\nlast: old\n";
        let fresh = "title\n1252 tests ran\nsame\nsame\nlast: new\n";
        let text = difference(committed, fresh).expect("the texts differ");
        assert!(
            text.starts_with("2 line(s) of the committed page"),
            "{text}"
        );
        assert!(text.contains("\n  - 2: 1251 tests ran"), "{text}");
        assert!(text.contains("\n  + 2: 1252 tests ran"), "{text}");
        assert!(text.contains("\n  - 5: last: old"), "{text}");
        assert!(text.contains("\n  + 5: last: new"), "{text}");
        assert!(!text.contains("title") && !text.contains("same"), "{text}");
    }

    #[test]
    fn changed_lines_are_shown_up_to_the_limit_and_counted_beyond_it() {
        let fresh: String = (0..20).map(|n| format!("new {n}\n")).collect();
        let text = difference("head\n", &format!("head\n{fresh}")).expect("the texts differ");
        assert!(text.starts_with("0 line(s)"), "{text}");
        assert!(text.contains("+ 13: new 11"), "{text}");
        assert!(!text.contains("new 12"), "{text}");
        assert!(text.ends_with("… and 8 more changed line(s)"), "{text}");
    }

    #[test]
    fn a_long_line_changed_far_in_is_shown_where_it_changed() {
        let head = "y".repeat(400);
        let text = difference(&format!("{head} old\n"), &format!("{head} new\n"))
            .expect("the texts differ");
        assert!(text.contains("- 1: …yyy"), "{text}");
        assert!(text.contains("y old") && text.contains("y new"), "{text}");
    }

    #[test]
    fn a_long_line_is_cut() {
        let long = "x".repeat(500);
        let text = difference("a\n", &format!("{long}\n")).expect("the texts differ");
        assert!(text.contains(" …"), "{text}");
        assert!(text.len() < 500, "{text}");
    }
}
