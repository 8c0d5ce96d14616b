//! The full-network and reaction-time results as Markdown, for docs/network-performance.md.

use super::network::{Report, SrdoStats, Traffic};
use super::plan::{self, BIT_RATE, worst_case_bits, worst_case_micros};
use super::reaction::{self, Case};
use std::fmt::Write as _;

fn ms(micros: u64) -> String {
    format!("{:.3}", micros as f64 / 1000.0)
}

fn percent(share: f64) -> String {
    format!("{:.1} %", share * 100.0)
}

/// The margins of one SRDO (µs, may be negative): SRVT, SCT after the first pair, first pair.
fn margins(report: &Report, srdo: &SrdoStats) -> (i64, i64, i64) {
    let srvt = i64::from(report.timing.srvt_ms) * 1000;
    let sct = i64::from(report.timing.sct_ms) * 1000;
    (
        srvt - srdo.max_gap_us as i64,
        sct - srdo.max_interval_us as i64,
        sct - srdo.first_us as i64,
    )
}

fn signed_ms(micros: i64) -> String {
    format!("{:.3}", micros as f64 / 1000.0)
}

/// The full network section.
pub fn full_network(report: &Report) -> String {
    let timing = &report.timing;
    let monitor = &report.monitor;
    let mut text = String::new();
    let _ = writeln!(
        text,
        "Command: `cargo xtask fullnet --minutes {}` (seed 1). 127 dual-channel nodes (254 channel \
         runtimes, each with its own protocol core, and their links) at {} kbit/s: nodes 1..64 \
         produce SRDO pairs 1..64 (CiA 304 identifiers 0xFF + 2n / 0x100 + 2n), nodes 65..127 \
         consume pairs 1..63, node 1 also consumes pair 64 (127 node-IDs for 128 roles; \
         `tests/src/fullnet/plan.rs`). Each producer's input changes at intervals drawn from \
         {}..{} ms (event-driven pairs).",
        report.bus_time.as_micros() as f64 / 60e6,
        BIT_RATE / 1000,
        plan::INPUT_CHANGE_MS.0,
        plan::INPUT_CHANGE_MS.1,
    );
    let _ = writeln!(text);
    let _ = writeln!(
        text,
        "**Timing, derived** (`Timing::derive`): a 1-byte frame takes at most {} bits ({} µs), an \
         8-byte frame {} bits ({} µs), stuff bits included (worst case (34 + 8·len − 1) / 4). \
         Refresh time {} ms: the shortest whole millisecond with the worst-case utilisation of all \
         periodic traffic at or below {}; one ms less exceeds it. SCT {} ms (the larger of 2 × \
         refresh and the last producer's CiA 304 start-up stagger, 0.5 ms × 64, plus one \
         refresh). SRVT {} ms (bound {} µs: four link messages ahead of the announcement, one \
         8-byte frame of blocking, every SRDO frame once). Link heartbeat {} ms.",
        worst_case_bits(1),
        worst_case_micros(1, BIT_RATE),
        worst_case_bits(8),
        worst_case_micros(8, BIT_RATE),
        timing.refresh_ms,
        percent(plan::UTILISATION_LIMIT),
        timing.sct_ms,
        timing.srvt_ms,
        timing.srvt_bound_us,
        timing.link_period.as_micros() / 1000,
    );
    let _ = writeln!(text);
    let _ = writeln!(text, "| traffic | worst-case share | measured share |");
    let _ = writeln!(text, "|---|---:|---:|");
    let _ = writeln!(
        text,
        "| {} ({} frames every {} ms) | {} | {} |",
        timing.srdo.what,
        timing.srdo.count,
        timing.srdo.period_us / 1000,
        percent(timing.srdo.utilisation(BIT_RATE)),
        percent(report.share(Traffic::Srdo)),
    );
    for stream in &timing.background {
        let measured = match stream.what {
            "heartbeats" => percent(report.share(Traffic::Heartbeat)),
            "PDO-like" => percent(report.share(Traffic::Pdo)),
            _ => "(in SRDO)".into(),
        };
        let _ = writeln!(
            text,
            "| {} ({} × {} bytes every {} ms) | {} | {} |",
            stream.what,
            stream.count,
            stream.len,
            stream.period_us / 1000,
            percent(stream.utilisation(BIT_RATE)),
            measured,
        );
    }
    let _ = writeln!(
        text,
        "| other (NMT, SDO, EMCY, GFC) | – | {} |",
        percent(report.share(Traffic::Other))
    );
    let _ = writeln!(
        text,
        "| **total** | {} | **{}** |",
        percent(timing.utilisation(BIT_RATE)),
        percent(report.load())
    );
    let _ = writeln!(text);
    let frames: u64 = monitor.frames.iter().sum();
    let _ = writeln!(
        text,
        "**Run**: {:.1} s of bus time after the NMT start ({:.1} s simulated in all), {} frames, \
         {} SRDO pairs. Faults or safe states reported by any channel: **{}**.",
        report.bus_time.as_micros() as f64 / 1e6,
        report.simulated.as_micros() as f64 / 1e6,
        frames,
        monitor.srdos.iter().map(|s| s.pairs).sum::<u64>(),
        monitor.faults,
    );
    for line in &monitor.fault_lines {
        let _ = writeln!(text, "- {line}");
    }
    let _ = writeln!(text);
    let all: Vec<(i64, i64, i64)> = monitor
        .srdos
        .iter()
        .map(|srdo| margins(report, srdo))
        .collect();
    let summary = |pick: fn(&(i64, i64, i64)) -> i64| {
        let values: Vec<i64> = all.iter().map(pick).collect();
        let min = values.iter().copied().min().unwrap_or(0);
        let max = values.iter().copied().max().unwrap_or(0);
        let mean = values.iter().sum::<i64>() as f64 / values.len().max(1) as f64;
        format!(
            "{} | {:.3} | {}",
            signed_ms(min),
            mean / 1000.0,
            signed_ms(max)
        )
    };
    let _ = writeln!(
        text,
        "Margins over the 64 SRDOs (ms; bound minus the worst the monitor saw on the bus):"
    );
    let _ = writeln!(text);
    let _ = writeln!(text, "| margin | min | mean | max |");
    let _ = writeln!(text, "|---|---:|---:|---:|");
    let _ = writeln!(
        text,
        "| SRVT − longest plain-to-inverted gap | {} |",
        summary(|m| m.0)
    );
    let _ = writeln!(
        text,
        "| SCT − longest interval between pairs | {} |",
        summary(|m| m.1)
    );
    let _ = writeln!(
        text,
        "| SCT − NMT start to first pair | {} |",
        summary(|m| m.2)
    );
    let _ = writeln!(text);
    let mut by_sct: Vec<&SrdoStats> = monitor.srdos.iter().collect();
    by_sct.sort_by_key(|srdo| {
        let (srvt, sct, first) = margins(report, srdo);
        srvt.min(sct).min(first)
    });
    let _ = writeln!(text, "The five SRDOs with the smallest margin:");
    let _ = writeln!(text);
    let _ = writeln!(
        text,
        "| pair (producer) | consumer | pairs | longest gap | SRVT margin | longest interval | SCT margin | first pair | its margin |"
    );
    let _ = writeln!(text, "|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for srdo in by_sct.iter().take(5) {
        let (srvt, sct, first) = margins(report, srdo);
        let _ = writeln!(
            text,
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            srdo.pair,
            srdo.consumer,
            srdo.pairs,
            ms(srdo.max_gap_us),
            signed_ms(srvt),
            ms(srdo.max_interval_us),
            signed_ms(sct),
            ms(srdo.first_us),
            signed_ms(first),
        );
    }
    let _ = writeln!(text);
    let _ = writeln!(
        text,
        "**Reaction** (producer's input change → the consumer's output, both channels in series, \
         measured on every change): to the safe value (1 → 0) {} changes, min {} / mean {:.3} / \
         **max {}** ms; back (0 → 1, both channels confirm) {} changes, min {} / mean {:.3} / max \
         {} ms.",
        monitor.to_safe.count,
        ms(monitor.to_safe.min_us),
        monitor.to_safe.mean_us() / 1000.0,
        ms(monitor.to_safe.max_us),
        monitor.to_run.count,
        ms(monitor.to_run.min_us),
        monitor.to_run.mean_us() / 1000.0,
        ms(monitor.to_run.max_us),
    );
    let _ = writeln!(text);
    let simulated_s = report.simulated.as_micros() as f64 / 1e6;
    let cpu = report.simulation_cpu.map_or_else(
        || "CPU time not available".to_string(),
        |cpu| {
            let per_minute = cpu.as_secs_f64() * 60.0 / simulated_s.max(1e-9);
            if report.threads > 1 {
                format!(
                    "{:.1} s of CPU time in all threads ({per_minute:.1} s per simulated \
                     minute), user and system, a thread's waits for the other included",
                    cpu.as_secs_f64(),
                )
            } else {
                format!(
                    "{:.1} s of CPU time in all ({per_minute:.1} s per simulated minute), user \
                     and system, the rest of the wall time waiting for a core",
                    cpu.as_secs_f64(),
                )
            }
        },
    );
    let _ = writeln!(
        text,
        "**Wall time** (release build, this 2-core machine, shared with other work; {}): \
         configuring the 127 nodes {:.3} s ({} SDO requests, the tool's procedure against each \
         core alone); simulation {:.1} s for {:.1} s simulated ({cpu}).",
        if report.threads > 1 {
            format!(
                "{} threads, channel A of each node on one and channel B on the other",
                report.threads
            )
        } else {
            "one thread".to_string()
        },
        report.configuration_wall.as_secs_f64(),
        report.sdo_requests,
        report.simulation_wall.as_secs_f64(),
        simulated_s,
    );
    text
}

/// The reaction-time section.
pub fn reactions(cases: &[Case], repetitions: u32) -> String {
    let mut text = String::new();
    let _ = writeln!(
        text,
        "Command: `cargo xtask reaction --repetitions {repetitions}` (seed 1). Node 1 → node 33 \
         (dual-channel, as in the demo): refresh {} ms, SCT {} ms, SRVT {} ms, link heartbeat {} \
         ms. Each case {repetitions} times, the change at a random phase (uniform over one \
         refresh time) after 50 ms of settling; time from the change to node 33's output at 0 \
         (its two channels in series: the first channel that drops). Higher-priority traffic: \
         8-byte frames on 0x{:03X} taking {} of the bus in worst-case bits; the load column is \
         what the bus carried over the case.",
        reaction::REFRESH_MS,
        reaction::SCT_MS,
        reaction::SRVT_MS,
        crate::dual::LINK_PERIOD.as_micros() / 1000,
        reaction::HIGHER_PRIORITY_ID,
        percent(reaction::HIGHER_PRIORITY_SHARE),
    );
    let _ = writeln!(text);
    let _ = writeln!(
        text,
        "| path | kbit/s | higher-priority traffic | bus load | n | min (ms) | mean (ms) | max (ms) |"
    );
    let _ = writeln!(text, "|---|---:|---|---:|---:|---:|---:|---:|");
    for case in cases {
        let _ = writeln!(
            text,
            "| {} | {} | {} | {} | {} | {} | {:.3} | {} |",
            case.path.name(),
            case.bit_rate / 1000,
            if case.loaded { "yes" } else { "no" },
            percent(case.load),
            case.times.count,
            ms(case.times.min_us),
            case.times.mean_us() / 1000.0,
            ms(case.times.max_us),
        );
    }
    text
}
