//! The monitor's terminal view (ratatui): a thin drawing of the [`Monitor`] model, and the
//! same figures as plain lines for a summary. Nothing here decides a verdict; it only shows
//! the model's, with the numbers it rests on.

use super::model::simplecan::{ScIdView, SimpleCanView};
use super::model::{Monitor, NodeView, PairVerdict, SrdoView, describe_emergency};
use ratatui::Frame;
use ratatui::layout::{Constraint, Layout, Rect};
use ratatui::style::{Color, Modifier, Style};
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Borders, Cell, Clear, Paragraph, Row, Table};
use std::time::Duration;

/// What the caller adds around the model: a title, panels of its own (the emulated
/// network's channel table, say), the keys it takes, and whether help is shown.
#[derive(Clone, Debug, Default)]
pub struct Screen {
    /// The first line: what is monitored.
    pub title: String,
    /// Panels drawn above the model's: a title and its lines each.
    pub panels: Vec<(String, Vec<String>)>,
    /// The keys line at the bottom.
    pub keys: String,
    /// The help text, shown over everything while `Some`.
    pub help: Option<Vec<String>>,
    /// Shown in the title while set.
    pub paused: bool,
}

/// Milliseconds with one decimal.
fn ms(duration: Duration) -> String {
    format!("{:.1}", duration.as_secs_f64() * 1000.0)
}

/// A limit in whole milliseconds, or `?` when the monitor does not know it.
fn limit(duration: Option<Duration>) -> String {
    duration.map_or_else(|| "?".to_owned(), |d| d.as_millis().to_string())
}

/// A small timeline: one bar a value, its height the value's share of `scale`; a value at
/// or beyond `limit` (the verdict's bound) is `!`.
pub fn timeline(values: impl Iterator<Item = Duration>, scale: Duration, width: usize) -> String {
    const BARS: [char; 8] = ['▁', '▂', '▃', '▄', '▅', '▆', '▇', '█'];
    let values: Vec<Duration> = values.collect();
    let skip = values.len().saturating_sub(width);
    values[skip..]
        .iter()
        .map(|value| {
            if scale.is_zero() || *value >= scale {
                '!'
            } else {
                let share = value.as_secs_f64() / scale.as_secs_f64();
                BARS[((share * BARS.len() as f64) as usize).min(BARS.len() - 1)]
            }
        })
        .collect()
}

/// A timeline's scale: the verdict's limit when known, else the largest value seen (so
/// the bars still show the shape, and no `!` claims a limit nobody configured).
fn scale(limit: Option<Duration>, values: &std::collections::VecDeque<Duration>) -> Duration {
    limit.unwrap_or_else(|| {
        values
            .iter()
            .max()
            .map_or(Duration::ZERO, |max| *max + Duration::from_micros(1))
    })
}

fn node_cells(id: u8, node: &NodeView, now: Duration) -> [String; 7] {
    [
        id.to_string(),
        node.name.clone().unwrap_or_default(),
        if node.heartbeat_lost {
            "heartbeat lost".to_owned()
        } else {
            node.state
                .map_or_else(|| "not heard".to_owned(), |s| s.describe().to_owned())
        },
        node.heartbeat_age(now)
            .map_or_else(|| "-".to_owned(), |age| format!("{} ms", ms(age))),
        node.heartbeat_period
            .map_or_else(|| "-".to_owned(), |p| format!("{} ms", ms(p))),
        format!("{}/{}", node.sdo_requests, node.sdo_responses),
        node.last_emergency.map_or_else(String::new, |(at, e)| {
            format!(
                "{:04X}h {} ({:.1} s ago)",
                e.code,
                describe_emergency(&e),
                now.saturating_sub(at).as_secs_f64()
            )
        }),
    ]
}

/// Who sends and who receives an SRDO: `1 → 33`, `? → ?` when learned from the bus.
fn route(srdo: &SrdoView) -> String {
    let producer = srdo
        .watch
        .producer
        .map_or_else(|| "?".to_owned(), |(node, _)| node.to_string());
    let consumers = if srdo.watch.consumers.is_empty() {
        "?".to_owned()
    } else {
        srdo.watch
            .consumers
            .iter()
            .map(|(node, _)| node.to_string())
            .collect::<Vec<_>>()
            .join(",")
    };
    format!("{producer} → {consumers}")
}

fn verdict_words(srdo: &SrdoView, now: Duration) -> String {
    let mut words = match srdo.last_verdict {
        None => "no pair yet".to_owned(),
        Some((_, verdict)) => verdict.describe().to_owned(),
    };
    if let (Some(silent), Some(sct)) = (srdo.silent_for(now), srdo.watch.sct) {
        if silent >= sct {
            words = format!(
                "silent {:.1} s (SCT {} ms)",
                silent.as_secs_f64(),
                sct.as_millis()
            );
        }
    }
    words
}

const TIMELINE: usize = 12;

fn srdo_cells(srdo: &SrdoView, now: Duration) -> [String; 9] {
    let watch = &srdo.watch;
    [
        format!("{:03X}h/{:03X}h", watch.plain, watch.inverted),
        route(srdo),
        srdo.count(PairVerdict::Valid).to_string(),
        srdo.faults().to_string(),
        format!(
            "{} / {}",
            srdo.gaps.back().map_or_else(|| "-".to_owned(), |g| ms(*g)),
            limit(watch.srvt)
        ),
        timeline(
            srdo.gaps.iter().copied(),
            scale(watch.srvt, &srdo.gaps),
            TIMELINE,
        ),
        format!(
            "{} / {}",
            srdo.periods
                .back()
                .map_or_else(|| "-".to_owned(), |p| ms(*p)),
            limit(watch.sct)
        ),
        timeline(
            srdo.periods.iter().copied(),
            scale(watch.sct, &srdo.periods),
            TIMELINE,
        ),
        verdict_words(srdo, now),
    ]
}

/// Whether there is anything of SimpleCAN to show.
fn shows_simplecan(view: &SimpleCanView) -> bool {
    !view.sc_ids.is_empty() || !view.masters.is_empty() || view.undecodable_syncs > 0
}

fn sc_id_cells(sc_id: u8, view: &ScIdView, now: Duration) -> [String; 9] {
    let watch = &view.watch;
    let consumers = if watch.consumers.is_empty() {
        "?".to_owned()
    } else {
        watch
            .consumers
            .iter()
            .map(u8::to_string)
            .collect::<Vec<_>>()
            .join(",")
    };
    let producer = watch
        .producer
        .map_or_else(|| "?".to_owned(), |node| node.to_string());
    let (offsets, jitter) = match view.jitter() {
        Some((min, max, spread)) => (format!("{min}..{max}"), spread.to_string()),
        None => ("-".to_owned(), "-".to_owned()),
    };
    let value = if view.undecodable > 0 && view.packets == 0 {
        format!("{} without hash", view.undecodable)
    } else {
        view.value
            .map_or_else(|| "-".to_owned(), |(value, _)| format!("{value:08X}h"))
    };
    [
        format!("{sc_id:02X}h"),
        format!("{producer} → {consumers}"),
        watch
            .slot
            .map_or_else(|| "?".to_owned(), |slot| slot.to_string()),
        view.packets.to_string(),
        value,
        format!(
            "{} / {}",
            view.age(now).map_or_else(|| "-".to_owned(), ms),
            limit(watch.timeout)
        ),
        offsets,
        jitter,
        format!("{} / {}", view.outside_slot, view.bad_crc),
    ]
}

/// SimpleCAN's sync and error line: each master's syncs, then the counts.
fn simplecan_lines(view: &SimpleCanView, now: Duration) -> Vec<String> {
    let mut lines: Vec<String> = view
        .masters
        .iter()
        .map(|(master, sync)| {
            let mut line = format!("syncs from master SC-ID {master:02X}h: {}", sync.syncs);
            if let Some(interval) = sync.interval {
                line.push_str(&format!(", every {} ms", ms(interval)));
            }
            if let Some((at, cycle, offset)) = sync.last {
                line.push_str(&format!(
                    ", latest cycle {cycle} (+{offset} µs) {:.1} s ago",
                    now.saturating_sub(at).as_secs_f64()
                ));
            }
            line
        })
        .collect();
    let mut counts = format!(
        "SimpleCAN: {} bad CRCs, {} malformed",
        view.bad_crc, view.malformed
    );
    if view.undecodable_syncs > 0 {
        counts.push_str(&format!(", {} syncs", view.undecodable_syncs));
    }
    if !view.has_hashes() {
        counts.push_str(
            "; no network file: no node hash is known (they are never sent), so no packet can be checked or decoded",
        );
    }
    lines.push(counts);
    lines
}

/// The SDO, GFC and NMT lines: counts, then the latest aborts decoded.
fn traffic_lines(monitor: &Monitor) -> Vec<String> {
    let (requests, responses) = monitor.sdo_totals();
    let gfc = match monitor.last_gfc {
        Some(at) => format!(
            "{} (latest {:.1} s ago)",
            monitor.gfcs,
            monitor.now.saturating_sub(at).as_secs_f64()
        ),
        None => "none".to_owned(),
    };
    let mut lines = vec![format!(
        "GFC: {gfc}   SDO: {requests} requests, {responses} responses, {} aborts   NMT commands: {}   frames: {}",
        monitor.aborts.len(),
        monitor.nmt_commands,
        monitor.frames
    )];
    lines.extend(monitor.aborts.iter().rev().take(3).map(|a| a.to_string()));
    lines
}

fn block(title: &str) -> Block<'_> {
    Block::default().borders(Borders::TOP).title(Span::styled(
        title,
        Style::new().add_modifier(Modifier::BOLD),
    ))
}

fn table<'a, const N: usize>(
    header: [&'a str; N],
    rows: Vec<([String; N], Style)>,
    widths: [Constraint; N],
    title: &'a str,
) -> Table<'a> {
    Table::new(
        rows.into_iter()
            .map(|(cells, style)| Row::new(cells.map(Cell::from)).style(style)),
        widths,
    )
    .header(Row::new(header).style(Style::new().add_modifier(Modifier::UNDERLINED)))
    .block(block(title))
}

/// Draws the model and the caller's screen into `frame`.
pub fn draw(frame: &mut Frame<'_>, monitor: &Monitor, screen: &Screen) {
    let now = monitor.now;
    let traffic = traffic_lines(monitor);
    let simplecan = shows_simplecan(&monitor.simplecan)
        .then(|| (&monitor.simplecan, simplecan_lines(&monitor.simplecan, now)));
    let mut constraints = vec![Constraint::Length(1)];
    for (_, lines) in &screen.panels {
        constraints.push(Constraint::Length(lines.len() as u16 + 1));
    }
    constraints.extend([
        Constraint::Length(monitor.nodes.len().max(1) as u16 + 2),
        Constraint::Length(monitor.srdos.len().max(1) as u16 + 2),
        Constraint::Length(simplecan.as_ref().map_or(0, |(view, lines)| {
            (view.sc_ids.len() + lines.len()) as u16 + 2
        })),
        Constraint::Length(traffic.len() as u16 + 1),
        Constraint::Min(2),
        Constraint::Length(1),
    ]);
    let areas = Layout::vertical(constraints).split(frame.area());
    let mut area = areas.iter().copied();
    let mut next = || area.next().unwrap_or_default();

    let mut title = format!("{}   bus time {:.1} s", screen.title, now.as_secs_f64());
    if screen.paused {
        title.push_str("   PAUSED");
    }
    frame.render_widget(
        Paragraph::new(title).style(Style::new().add_modifier(Modifier::BOLD)),
        next(),
    );
    for (title, lines) in &screen.panels {
        let text: Vec<Line<'_>> = lines.iter().map(|l| Line::raw(l.as_str())).collect();
        frame.render_widget(Paragraph::new(text).block(block(title)), next());
    }

    let nodes = monitor
        .nodes
        .iter()
        .map(|(id, node)| (node_cells(*id, node, now), Style::new()))
        .collect();
    frame.render_widget(
        table(
            [
                "node",
                "name",
                "NMT",
                "heartbeat age",
                "period",
                "SDO req/resp",
                "last EMCY",
            ],
            nodes,
            [
                Constraint::Length(4),
                Constraint::Length(16),
                Constraint::Length(15),
                Constraint::Length(13),
                Constraint::Length(10),
                Constraint::Length(12),
                Constraint::Min(20),
            ],
            "Nodes",
        ),
        next(),
    );

    let srdos = monitor
        .srdos
        .values()
        .map(|srdo| {
            let style = match srdo.last_verdict {
                Some((_, PairVerdict::Valid)) => Style::new(),
                None => Style::new().fg(Color::DarkGray),
                Some(_) => Style::new().fg(Color::Red),
            };
            (srdo_cells(srdo, now), style)
        })
        .collect();
    frame.render_widget(
        table(
            [
                "SRDO",
                "from → to",
                "valid",
                "faults",
                "gap/SRVT ms",
                "gaps",
                "period/SCT ms",
                "periods",
                "verdict",
            ],
            srdos,
            [
                Constraint::Length(9),
                Constraint::Length(9),
                Constraint::Length(7),
                Constraint::Length(6),
                Constraint::Length(11),
                Constraint::Length(TIMELINE as u16),
                Constraint::Length(13),
                Constraint::Length(TIMELINE as u16),
                Constraint::Min(12),
            ],
            "SRDOs (plain → inverted gap against SRVT, period against SCT; ! at or over the limit)",
        ),
        next(),
    );

    let simplecan_area = next();
    if let Some((view, lines)) = simplecan {
        let [table_area, lines_area] = Layout::vertical([
            Constraint::Length(view.sc_ids.len() as u16 + 2),
            Constraint::Min(1),
        ])
        .areas(simplecan_area);
        let rows = view
            .sc_ids
            .iter()
            .map(|(sc_id, sc)| {
                let style = if sc.bad_crc > 0 || sc.outside_slot > 0 {
                    Style::new().fg(Color::Red)
                } else if sc.packets == 0 {
                    Style::new().fg(Color::DarkGray)
                } else {
                    Style::new()
                };
                (sc_id_cells(*sc_id, sc, now), style)
            })
            .collect();
        frame.render_widget(
            table(
                [
                    "SC-ID",
                    "from → to",
                    "slot",
                    "packets",
                    "value",
                    "age/timeout ms",
                    "slot offset µs",
                    "jitter µs",
                    "outside/bad CRC",
                ],
                rows,
                [
                    Constraint::Length(5),
                    Constraint::Length(9),
                    Constraint::Length(4),
                    Constraint::Length(7),
                    Constraint::Length(17),
                    Constraint::Length(14),
                    Constraint::Length(14),
                    Constraint::Length(9),
                    Constraint::Min(15),
                ],
                "SimpleCAN (values, age from the slot's start against the timeout, arrival against the configured slot)",
            ),
            table_area,
        );
        let text: Vec<Line<'_>> = lines.into_iter().map(Line::raw).collect();
        frame.render_widget(Paragraph::new(text), lines_area);
    }

    let traffic: Vec<Line<'_>> = traffic.into_iter().map(Line::raw).collect();
    frame.render_widget(
        Paragraph::new(traffic).block(block("GFC, SDO, NMT")),
        next(),
    );

    let events_area = next();
    let room = usize::from(events_area.height.saturating_sub(1));
    let skip = monitor.happenings.len().saturating_sub(room);
    let events: Vec<Line<'_>> = monitor
        .happenings
        .iter()
        .skip(skip)
        .map(|(at, line)| Line::raw(format!("{:>9.3} s  {line}", at.as_secs_f64())))
        .collect();
    frame.render_widget(Paragraph::new(events).block(block("Events")), events_area);
    frame.render_widget(
        Paragraph::new(screen.keys.as_str()).style(Style::new().fg(Color::Cyan)),
        next(),
    );

    if let Some(help) = &screen.help {
        let area = centred(frame.area(), help);
        frame.render_widget(Clear, area);
        let text: Vec<Line<'_>> = help.iter().map(|l| Line::raw(l.as_str())).collect();
        frame.render_widget(
            Paragraph::new(text).block(Block::bordered().title(HELP_TITLE)),
            area,
        );
    }
}

const HELP_TITLE: &str = "Help (any key closes)";

fn centred(outer: Rect, lines: &[String]) -> Rect {
    let widest = lines.iter().map(|l| l.chars().count()).max().unwrap_or(0);
    let width = widest.max(HELP_TITLE.len()) as u16 + 4;
    let height = lines.len() as u16 + 2;
    let width = width.min(outer.width);
    let height = height.min(outer.height);
    Rect::new(
        outer.x + (outer.width - width) / 2,
        outer.y + (outer.height - height) / 2,
        width,
        height,
    )
}

/// The model as plain lines, for a summary or a log: every node and every SRDO with its
/// counts and the largest gap and period against their limits.
pub fn summary(monitor: &Monitor) -> Vec<String> {
    let now = monitor.now;
    let mut lines = Vec::new();
    for (id, node) in &monitor.nodes {
        let [_, name, state, age, _, sdo, emcy] = node_cells(*id, node, now);
        let mut line = format!("node {id}");
        if !name.is_empty() {
            line.push_str(&format!(" ({name})"));
        }
        line.push_str(&format!(": {state}, heartbeat age {age}, SDO {sdo}"));
        if !emcy.is_empty() {
            line.push_str(&format!(", last EMCY {emcy}"));
        }
        lines.push(line);
    }
    for srdo in monitor.srdos.values() {
        let watch = &srdo.watch;
        let largest = |values: &std::collections::VecDeque<Duration>| {
            values
                .iter()
                .max()
                .map_or_else(|| "-".to_owned(), |v| ms(*v))
        };
        let mut counts: Vec<String> = srdo
            .verdicts
            .iter()
            .map(|(verdict, count)| format!("{count} {}", verdict.describe()))
            .collect();
        if counts.is_empty() {
            counts.push("no pair".to_owned());
        }
        lines.push(format!(
            "SRDO {:03X}h/{:03X}h ({}): {}; largest gap {} ms (SRVT {} ms), largest period {} ms (SCT {} ms); now {}",
            watch.plain,
            watch.inverted,
            route(srdo),
            counts.join(", "),
            largest(&srdo.gaps),
            limit(watch.srvt),
            largest(&srdo.periods),
            limit(watch.sct),
            verdict_words(srdo, now),
        ));
    }
    if shows_simplecan(&monitor.simplecan) {
        let view = &monitor.simplecan;
        for (sc_id, sc) in &view.sc_ids {
            let [
                name,
                route,
                slot,
                packets,
                value,
                age,
                offsets,
                jitter,
                errors,
            ] = sc_id_cells(*sc_id, sc, now);
            lines.push(format!(
                "SimpleCAN SC-ID {name} ({route}, slot {slot}): {packets} packets, value {value}, age/timeout {age} ms, slot offset {offsets} µs, jitter {jitter} µs, outside slot/bad CRC {errors}"
            ));
        }
        lines.extend(simplecan_lines(view, now));
    }
    lines.extend(traffic_lines(monitor));
    lines
}

#[cfg(test)]
mod tests;
