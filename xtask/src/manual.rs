//! `cargo xtask manual`: the safety manual (`manual/`, an mdBook) with the product's own
//! numbers, built to HTML, its links checked.
//!
//! Two kinds of generated parts:
//!
//! - **Committed** (`manual/src/generated/*.md`): made from what the repository holds, so
//!   they change only when a source changes, and CI checks (`--check`) that the committed
//!   files equal freshly generated ones: the safety objects and their ranges (the EDS the tool
//!   generates from the device description, and the configuration rules' own constants), the
//!   safe-state causes (the cause table `shared::safety::cause`, its doc comments read from
//!   its source), the reaction times (the tool's calculator, `safety_config::calc`, beside the
//!   simulated times of `docs/network-performance.md`), the residual error rate per SIL (the
//!   same function `safety-config budget` calls), the fault campaigns' results
//!   (`docs/campaigns.md`), and the SimpleCAN worked example (the calculator on
//!   `manual/src/examples/simplecan-network.toml` beside the reactions measured on two
//!   dual-channel nodes of the host simulation). The measurements are read from the
//!   committed reports, not run again: `cargo xtask reaction` and `cargo xtask campaign`
//!   write those reports and take minutes; reading them keeps this task within seconds and
//!   the manual equal to them. The SimpleCAN example is the exception: its 21 short
//!   simulated runs are deterministic and quick, so it is measured here.
//! - **Written at build time** into the staged copy of the book only
//!   (`manual/src/generated/build-time/`, committed as placeholders): the toolchain and the
//!   hardware images' CRCs (built and sealed by `images::build_layer`, which is incremental),
//!   and `docs/access-protection.md` when it exists. They depend on the machine and on
//!   every line of firmware, so committing them would make every change a manual change.
//!
//! Then `mdbook build` into `target/manual/html`, and a check of every relative link and
//! anchor in the HTML (our own: mdbook-linkcheck is not installed, and the check is short).

use crate::images::{self, Layer};
use crate::toolchain::{self, Cross};
use anyhow::{Context, Result, bail};
use safety_config::calc::budget::{self, Plan};
use safety_config::calc::bus::{Stream, frame_micros};
use safety_config::calc::report;
use safety_config::calc::residual::{self, Sil};
use safety_config::calc::sfrt::{self, DeviceTiming};
use safety_config::calc::target;
use safety_config::network_file;
use shared::safety::cause::Cause;
use shared::safety::config::ConfigError;
use shared::safety::types::{FIRST_COB_ID_MAX, FIRST_COB_ID_MIN};
use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// The committed generated parts, relative to `manual/src/generated/`.
const COMMITTED: [&str; 7] = [
    "safety-objects.md",
    "causes.md",
    "sfrt.md",
    "residual.md",
    "evidence.md",
    "processing.md",
    "simplecan.md",
];

/// The SimpleCAN network of the chapter's worked example, relative to the repository.
const SIMPLECAN_EXAMPLE: &str = "manual/src/examples/simplecan-network.toml";

/// The demo's timing, which the reaction-time measurement and the campaigns use: node 1
/// refreshes every 25 ms, node 33 allows SCT 50 ms and SRVT 20 ms.
const DEMO: (u16, u16, u8) = (25, 50, 20);

/// `cargo xtask manual [--check]`.
pub fn run(root: &Path, check: bool) -> Result<()> {
    let started = Instant::now();
    let generated = root.join("manual/src/generated");
    let parts = committed_parts(root)?;
    if check {
        let stale: Vec<&str> = parts
            .iter()
            .filter(|(name, text)| {
                std::fs::read_to_string(generated.join(name))
                    .ok()
                    .as_deref()
                    != Some(text)
            })
            .map(|(name, _)| *name)
            .collect();
        if !stale.is_empty() {
            bail!(
                "the committed generated parts of the manual differ from what `cargo xtask manual` generates now (manual/src/generated/{}): run it and commit the result",
                stale.join(", manual/src/generated/")
            );
        }
        println!(
            "xtask manual: the {} committed generated parts are up to date",
            parts.len()
        );
    } else {
        for (name, text) in &parts {
            std::fs::write(generated.join(name), text)
                .with_context(|| format!("writing manual/src/generated/{name}"))?;
        }
        println!("xtask manual: wrote {} generated parts", parts.len());
    }

    let staging = root.join("target/manual/src");
    let html = root.join("target/manual/html");
    let _ = std::fs::remove_dir_all(&staging);
    copy_tree(&root.join("manual"), &staging)?;
    let build_time = staging.join("src/generated/build-time");
    std::fs::write(build_time.join("build.md"), build_part(root)?)?;
    std::fs::write(
        build_time.join("access-protection.md"),
        access_protection(root)?,
    )?;

    toolchain::require(
        "mdbook",
        "install it with `cargo install mdbook --locked --no-default-features` (it took 13 min 50 s on this shared 2-core machine)",
    )?;
    let _ = std::fs::remove_dir_all(&html);
    crate::run(
        Command::new("mdbook")
            .arg("build")
            .arg(&staging)
            .arg("--dest-dir")
            .arg(&html),
    )?;
    let checked = check_links(&html)?;
    println!(
        "xtask manual: {} built, {} links and anchors resolve ({:.1} s)",
        html.join("index.html").display(),
        checked,
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Every committed generated part, by file name.
fn committed_parts(root: &Path) -> Result<Vec<(&'static str, String)>> {
    let performance = std::fs::read_to_string(root.join("docs/network-performance.md"))
        .context("reading docs/network-performance.md")?;
    let campaigns = std::fs::read_to_string(root.join("docs/campaigns.md"))
        .context("reading docs/campaigns.md")?;
    let causes = std::fs::read_to_string(root.join("shared/src/safety/cause.rs"))
        .context("reading shared/src/safety/cause.rs")?;
    let bench = std::fs::read_to_string(root.join("docs/performance.md"))
        .context("reading docs/performance.md")?;
    let parts = vec![
        (COMMITTED[0], safety_objects(&safety_config::eds::eds())?),
        (COMMITTED[1], cause_table(&causes)?),
        (COMMITTED[2], sfrt_part(&performance)?),
        (COMMITTED[3], residual_part()?),
        (COMMITTED[4], evidence_part(&campaigns, &performance)?),
        (COMMITTED[5], processing_part(&bench)?),
        (COMMITTED[6], simplecan_part(root)?),
    ];
    Ok(parts)
}

fn header(source: &str) -> String {
    format!("<!-- Generated by `cargo xtask manual` from {source}; do not edit. -->\n\n")
}

/// One EDS section: its keys and values.
type Section = BTreeMap<String, String>;

/// An EDS as its sections, each a map of keys to values.
fn eds_sections(text: &str) -> BTreeMap<String, Section> {
    let mut sections = BTreeMap::new();
    let mut current: Option<String> = None;
    for line in text.lines().map(str::trim) {
        if line.starts_with(';') || line.is_empty() {
            continue;
        }
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            current = Some(name.to_owned());
            sections
                .entry(name.to_owned())
                .or_insert_with(BTreeMap::new);
        } else if let (Some(section), Some((key, value))) = (&current, line.split_once('=')) {
            if let Some(keys) = sections.get_mut(section) {
                keys.insert(key.to_owned(), value.to_owned());
            }
        }
    }
    sections
}

fn data_type(code: &str) -> &'static str {
    match code {
        "0x0001" => "BOOLEAN",
        "0x0005" => "UNSIGNED8",
        "0x0006" => "UNSIGNED16",
        "0x0007" => "UNSIGNED32",
        "0x0009" => "VISIBLE_STRING",
        _ => "(other)",
    }
}

fn abort(error: ConfigError) -> String {
    let code = error.abort_code().code();
    format!("{:04X} {:04X}h", code >> 16, code & 0xFFFF)
}

/// What the node accepts beyond the EDS's limits, from the configuration rules' own
/// constants (`shared::safety::types`, `shared::safety::config`), for SRDO 1's objects.
fn rule(index: u16, sub: u8) -> Option<String> {
    match (index, sub) {
        (0x1300, _) => Some("0 clears the indication; 1 is accepted and sends nothing".into()),
        (0x1301, 1) => Some("0 deleted, 1 transmit, 2 receive".into()),
        (0x1301, 2) => Some(format!(
            "1..65535 ms (0: {}); a receive SRDO's SCT above its SRVT",
            abort(ConfigError::CycleTimeZero)
        )),
        (0x1301, 3) => Some(format!(
            "1..255 ms (0: {}); below the SCT of a receive SRDO ({})",
            abort(ConfigError::SrvtZero),
            abort(ConfigError::SrvtNotBelowSct)
        )),
        (0x1301, 4) => Some("fixed at 254 (FEh)".into()),
        (0x1301, 5) => Some(format!(
            "{FIRST_COB_ID_MIN:03X}h..{FIRST_COB_ID_MAX:03X}h, odd; not used by another SRDO of the node"
        )),
        (0x1301, 6) => Some(format!(
            "COB-ID 1 + 1 ({:03X}h..{:03X}h, even)",
            FIRST_COB_ID_MIN + 1,
            FIRST_COB_ID_MAX + 1
        )),
        (0x1381, 0) => Some("even (plain and inverted entries in pairs); written last".into()),
        (0x1381, _) => Some(
            "index:sub:bits of a mappable object below (odd: a plain object; even: its inverted copy, same length); only while sub-index 00h is 0".into(),
        ),
        (0x13FE, _) => Some("A5h declares the configuration valid; any accepted change of a safety object sets 0".into()),
        (0x13FF, 0) => None,
        (0x13FF, _) => Some("CRC-16 of the SRDO's parameters (EN 50325-5 Table 9), computed by the tool".into()),
        _ => None,
    }
}

/// The safety objects' table (SRDO 1 standing for 2..N, which the EDS must describe alike).
fn safety_objects(eds: &str) -> Result<String> {
    let sections = eds_sections(eds);
    let srdos = safety_device::SRDO_COUNT;
    let variable = |name: &str| {
        sections
            .get(name)
            .filter(|keys| keys.contains_key("AccessType"))
    };
    let compared = ["DataType", "AccessType", "LowLimit", "HighLimit"];
    // SRDO n's objects must be SRDO 1's: then one row stands for all. Only the defaults
    // differ: SRDO 1 follows the pre-defined connection set, SRDO 2..N start deleted, and
    // those must agree among themselves.
    for n in 2..=srdos {
        for (first, other) in [(0x1301u16, 0x1300 + n as u16), (0x1381, 0x1380 + n as u16)] {
            for sub in 0..=16u8 {
                let a = variable(&format!("{first:04X}sub{sub:X}"));
                let b = variable(&format!("{other:04X}sub{sub:X}"));
                let second = variable(&format!("{:04X}sub{sub:X}", first + 1));
                let same = match (a, b, second) {
                    (Some(a), Some(b), Some(second)) => {
                        compared.iter().all(|key| a.get(*key) == b.get(*key))
                            && b.get("DefaultValue") == second.get("DefaultValue")
                    }
                    (None, None, _) => true,
                    _ => false,
                };
                if !same {
                    bail!(
                        "the EDS describes {other:04X}h sub-index {sub:02X}h otherwise than {first:04X}h: the manual's table gives SRDO 1's objects for all {srdos} SRDOs"
                    );
                }
            }
        }
    }
    let mut out =
        header("the EDS (`safety-config eds`, the device description) and the configuration rules");
    let _ = writeln!(
        out,
        "The node has {srdos} SRDOs. 1301h and 1381h stand for 1301h..{:04X}h and 1381h..{:04X}h (SRDO 1..{srdos}), which have the same sub-indices, types, access and limits.\n",
        0x1300 + srdos,
        0x1380 + srdos
    );
    out.push_str("| object | name | type | access | default | what the node accepts |\n|---|---|---|---|---|---|\n");
    let mut rows = 0;
    let mut by_address: Vec<((u16, u8), &Section)> = sections
        .iter()
        .filter_map(|(name, keys)| Some((parse_section(name)?, keys)))
        .collect();
    by_address.sort_by_key(|(address, _)| *address);
    for ((index, sub), keys) in by_address {
        let listed = index == 0x1300
            || index == 0x1301
            || index == 0x1381
            || index == 0x13FE
            || index == 0x13FF;
        if !listed || !keys.contains_key("AccessType") {
            continue;
        }
        let limits = match (keys.get("LowLimit"), keys.get("HighLimit")) {
            (Some(low), Some(high)) => format!("{low}..{high}"),
            _ => String::new(),
        };
        let accepts = match (rule(index, sub), limits.is_empty()) {
            (Some(rule), true) => rule,
            (Some(rule), false) => format!("{limits}: {rule}"),
            (None, false) => limits,
            (None, true) => "read-only".into(),
        };
        let _ = writeln!(
            out,
            "| {index:04X}h:{sub:02X}h | {} | {} | {} | {} | {accepts} |",
            keys.get("ParameterName").map_or("", String::as_str),
            data_type(keys.get("DataType").map_or("", String::as_str)),
            keys.get("AccessType").map_or("", String::as_str),
            default(
                keys,
                variable(&format!("{:04X}sub{sub:X}", index + 1)),
                index
            ),
        );
        rows += 1;
    }
    if rows == 0 {
        bail!("the EDS lists no safety object (1300h..13FFh)");
    }
    out.push_str("\nObjects an SRDO may map (the device description, `safety_device`):\n\n| object | name | SRDO direction | its copy |\n|---|---|---|---|\n");
    for object in &safety_device::OBJECTS {
        let name = safety_device::OBJECT_NAMES
            .iter()
            .find(|(_, address)| *address == object.address)
            .map_or("", |(name, _)| name);
        let copy = safety_device::INVERTED_PAIRS
            .iter()
            .find_map(|(plain, inverted)| {
                if *plain == object.address {
                    Some(format!(
                        "inverted copy in {:04X}h:{:02X}h",
                        inverted.index, inverted.sub
                    ))
                } else if *inverted == object.address {
                    Some(format!(
                        "inverted copy of {:04X}h:{:02X}h",
                        plain.index, plain.sub
                    ))
                } else {
                    None
                }
            })
            .unwrap_or_default();
        let _ = writeln!(
            out,
            "| {:04X}h:{:02X}h | {name} | {:?} | {copy} |",
            object.address.index, object.address.sub, object.mappable
        );
    }
    Ok(out)
}

/// The default column: SRDO 1's (none given: it follows the node-ID), and SRDO 2..N's when
/// it differs.
fn default(keys: &Section, second: Option<&Section>, index: u16) -> String {
    let first = keys.get("DefaultValue");
    let srdo = index == 0x1301 || index == 0x1381;
    match (first, second.and_then(|s| s.get("DefaultValue"))) {
        (first, Some(other)) if srdo && first != Some(other) => format!(
            "SRDO 1: {}; SRDO 2..{}: {other}",
            first.map_or("by node-ID", String::as_str),
            safety_device::SRDO_COUNT
        ),
        (Some(first), _) => first.clone(),
        (None, _) => "by node-ID".into(),
    }
}

/// `1301sub2` → (0x1301, 2); `13FE` → (0x13FE, 0).
fn parse_section(name: &str) -> Option<(u16, u8)> {
    let (index, sub) = match name.split_once("sub") {
        Some((index, sub)) => (index, u8::from_str_radix(sub, 16).ok()?),
        None => (name, 0),
    };
    if index.len() != 4 {
        return None;
    }
    Some((u16::from_str_radix(index, 16).ok()?, sub))
}

/// The doc comment of every variant of `Cause` in `shared/src/safety/cause.rs`, by code.
fn cause_docs(source: &str) -> Result<BTreeMap<u8, String>> {
    let mut docs = BTreeMap::new();
    let mut pending = Vec::new();
    let body = source
        .split_once("pub enum Cause {")
        .map(|(_, rest)| rest)
        .and_then(|rest| rest.split_once("\n}").map(|(body, _)| body))
        .context("shared/src/safety/cause.rs has no `pub enum Cause { … }`")?;
    for line in body.lines().map(str::trim) {
        if let Some(doc) = line.strip_prefix("///") {
            pending.push(doc.trim().to_owned());
        } else if let Some((_, code)) = line.split_once(" = 0x") {
            let code = u8::from_str_radix(code.trim_end_matches(','), 16)
                .with_context(|| format!("cause.rs: {line:?} has no hexadecimal code"))?;
            docs.insert(code, pending.join(" "));
            pending.clear();
        }
    }
    Ok(docs)
}

/// What the machine builder does about a cause, by group of codes (the groups of the cause
/// table: SRDO communication 0xh, the link 1xh, the receive cross-check 2xh, the channels'
/// agreement 3xh, the other channel 40h, GFC 50h, SimpleCAN 6xh, SimpleCAN on the two
/// channels 7xh, the configuration in use Fxh).
fn advice(code: u8) -> Option<&'static str> {
    match code {
        0x00 => Some("Nothing: no safe state since power-on or the last NMT reset."),
        0x07 => Some(
            "The node's own plain and inverted halves of a transmit SRDO were not exact inverses, and nothing was sent: a fault inside the device. If it recurs after a reset, replace the device.",
        ),
        0x01..=0x0F => Some(
            "The SRDO did not arrive valid and in time. Check the producer (NMT state, its own cause), the bus (wiring, termination, error counters), the bus load against the refresh time, SCT and SRVT (`safety-config budget`, `safety-config sfrt`); a frame shortened or not inverted is a foreign or faulty sender.",
        ),
        0x10..=0x1F => Some(
            "The link between the node's two channels failed. It is inside the device: if it recurs after a power cycle, replace the device.",
        ),
        0x20..=0x2F => Some(
            "The two channels judged a received SRDO differently or not in time. Recurring: a fault inside the device (replace it) or a bus so loaded that the channels receive frames far apart (check the load).",
        ),
        0x30 | 0x31 | 0x32 | 0x35 | 0x39 => Some(
            "The two channels disagree about what the node sends, holds or does. After a reconfiguration: configure and store again with the tool (both channels must hold the same). Otherwise a fault inside the device: replace it.",
        ),
        0x33 => Some(
            "The two contacts of an input differed for longer than the discrepancy time (200 ms): a contact stuck, welded or broken, or wiring. Check the sensor and its wiring before resetting.",
        ),
        0x34 => Some(
            "Another device sent on this node's SRDO identifiers: two nodes configured with the same COB-IDs, or a non-safety device on the safety identifiers (DSP 304 9.4 forbids it). Find it before resetting: this node sends a GFC every time.",
        ),
        0x36..=0x38 => Some(
            "A limit of the channel's own design was reached (frames or events in one step, safety inputs, restoring an input after a reset), not a fault of the other channel. Keep the EMCY and the channels' logs for the manufacturer; if it recurs, the device is not fit for this configuration.",
        ),
        0x3A => Some(
            "A frame the node follows (its SRDOs, NMT, GFC or its own SDO request) found the channel's CAN receive queue full, so the channel cannot know that it saw every safety frame. Something sends on those identifiers faster than the node takes them: look for a babbling device or a tool flooding the node's SDO identifier, and check the bus load. If it recurs at normal load, replace the device.",
        ),
        0x3B => Some(
            "The channel's CAN controller went bus-off: its own frames met so many errors that it left the bus, and frames the node follows may have gone unseen. Check the wiring, the termination and the bit rate of every device (a device at another bit rate destroys frames), and the transceiver's supply; if it recurs on a sound bus, replace the device.",
        ),
        0x3C => Some(
            "The node's two channels answered an LSS request differently (CiA 305), or one answered a request the other did not: one channel's LSS state or its stored settings differ from the other's, or one CAN controller missed the request. Reset the node (NMT reset node or a power cycle) and configure it by LSS again, with the device outside Operational; if it recurs, replace the device.",
        ),
        0x3D => Some(
            "The node's two channels run on different node-IDs: their node-ID switches read differently (a switch between positions, a broken contact), or LSS gave one channel a node-ID the other does not have. Check the seven switches (all open means the node-ID is set by LSS), power the node off and on; if it recurs with the switches set firmly, replace the device.",
        ),
        0x3E => Some(
            "The node's two channels hold different LSS bit rates: a configure bit timing or store reached one channel only. Configure the bit rate by LSS again, store it, and power the node off and on; if it recurs, replace the device.",
        ),
        0x40 => Some(
            "The other channel entered its safe state first: read its own cause (the channel's status or log).",
        ),
        0x50 => Some(
            "A GFC was received: another node detected a fault and stopped the safety network. Find the node that sent it (its EMCY).",
        ),
        0x60..=0x62 => Some(
            "The node refused its SimpleCAN configuration at start (not declared valid, signature differs, or inconsistent: the EMCY's byte 2 names the SDD entry). Configure it again with the tool, which reads back and signs before declaring it valid (SC_REQ_35, SC_REQ_36).",
        ),
        0x68 => Some(
            "Two SimpleCAN masters sent syncs at once: two devices configured as potential masters with the same lowest SC-ID, or a master that did not stop when a lower one took over. Check which devices are potential masters (5E00h:05) before resetting.",
        ),
        0x69 => Some(
            "SimpleCAN packets with a bad CRC came faster than one per 3.6 s until 1000 had accumulated: a disturbed bus (wiring, termination, EMC) or devices configured with other node hashes on the same SC-IDs. Check the bus and the configuration of every device before resetting.",
        ),
        0x6A => Some(
            "A consumed SimpleCAN value was not refreshed within its safety timeout: check the producer (its NMT state, its own cause), the master (no sync for 2000 ms unsynchronises every node) and the bus.",
        ),
        0x70..=0x73 => Some(
            "The node's two channels did not see the same SimpleCAN frames: channel A's copy over the link differed from, came later than, or was never heard beside what channel B received on the bus. It is inside the device (the link or one CAN controller): if it recurs after a power cycle, replace the device.",
        ),
        0x74..=0x77 => Some(
            "The two channels judged a consumed SimpleCAN packet differently or not in time. Recurring: a fault inside the device (replace it), or a bus so loaded that the channels receive packets far apart (check the load and the cycle).",
        ),
        0x78 => Some(
            "The SimpleCAN packet channel A sent differed from the one channel B computed for the same slot: the channels disagree about what the node sends (a value outside B's samples of the last 5 ms, the cycle, or the time: channel A's clock running fast). Check the input wiring (the two contacts of an input must move within 5 ms of each other); otherwise a fault inside the device: replace it.",
        ),
        0x79 => Some(
            "A SimpleCAN packet channel B computed did not go out within its slot (a sync within 2 ms): the bus was too busy for the slot, or channel A's clock runs slow. Check the bus load against the cycle; otherwise a fault inside the device: replace it.",
        ),
        0xF0..=0xFF => Some(
            "The configuration in use no longer matches what was validated (a memory fault). Reset the node; if it recurs, replace the device.",
        ),
        _ => None,
    }
}

/// Every cause, its code, its name, its meaning and what to do.
fn cause_table(source: &str) -> Result<String> {
    let docs = cause_docs(source)?;
    let mut out = header("the cause table `shared::safety::cause::Cause`");
    out.push_str("| code | name | what it means | what to do |\n|---|---|---|---|\n");
    for cause in Cause::ALL {
        let code = cause.code();
        let meaning = docs.get(&code).with_context(|| {
            format!("cause {code:02X}h has no doc comment in shared/src/safety/cause.rs")
        })?;
        let what = advice(code).with_context(|| {
            format!("cause {code:02X}h ({cause}) has no advice in xtask/src/manual.rs")
        })?;
        let _ = writeln!(
            out,
            "| {code:02X}h | {} | {meaning} | {what} |",
            cause.describe()
        );
    }
    let listed: BTreeSet<u8> = Cause::ALL.iter().map(|c| c.code()).collect();
    if let Some(code) = docs.keys().find(|code| !listed.contains(code)) {
        bail!("cause {code:02X}h is in cause.rs but not in Cause::ALL");
    }
    Ok(out)
}

/// The rows of the reaction block of `docs/network-performance.md`: (path, kbit/s, loaded,
/// max µs).
fn simulated_reactions(performance: &str) -> Result<Vec<(String, u32, bool, u64)>> {
    let block = block(performance, "reaction")?;
    let mut rows = Vec::new();
    for line in block
        .lines()
        .filter(|l| l.starts_with("| ") && !l.starts_with("| path"))
    {
        let cells: Vec<&str> = line.trim_matches('|').split('|').map(str::trim).collect();
        let [path, kbit, loaded, _, _, _, _, max] = cells[..] else {
            bail!("docs/network-performance.md: reaction row {line:?} has not 8 cells");
        };
        let max_us = (max
            .parse::<f64>()
            .with_context(|| format!("reaction row {line:?}"))?
            * 1000.0)
            .round() as u64;
        rows.push((path.to_owned(), kbit.parse()?, loaded == "yes", max_us));
    }
    if rows.is_empty() {
        bail!("docs/network-performance.md: the reaction block has no rows");
    }
    Ok(rows)
}

/// The lines between `<!-- NAME:begin … -->` and `<!-- NAME:end -->`.
fn block<'a>(text: &'a str, name: &str) -> Result<&'a str> {
    let begin = format!("<!-- {name}:begin");
    let end = format!("<!-- {name}:end -->");
    let start = text
        .find(&begin)
        .with_context(|| format!("no `{begin}` marker"))?;
    let body = &text[start..];
    let body = &body[body.find('\n').unwrap_or(0)..];
    let stop = body
        .find(&end)
        .with_context(|| format!("no `{end}` marker"))?;
    Ok(&body[..stop])
}

/// The demo network's breakdown on the hardware's timing, and the calculator against every
/// simulated reaction.
fn sfrt_part(performance: &str) -> Result<String> {
    let (refresh, sct, srvt) = DEMO;
    let network = network_file::parse(&sfrt::example_network(refresh, sct, srvt), "example")?;
    let bit_rate = safety_device::BIT_RATE;
    let streams = sfrt::planned_streams(&network, None, &[]);
    let hardware = sfrt::reactions(&network, &streams, bit_rate, &DeviceTiming::HARDWARE)?;
    let mut out = header("`safety_config::calc::sfrt` and `docs/network-performance.md`");
    let _ = writeln!(
        out,
        "The example network (node 1's emergency stop, refresh {refresh} ms, to node 33's output, SCT {sct} ms, SRVT {srvt} ms) at {} kbit/s, no other traffic, with the hardware's timing (`DeviceTiming::HARDWARE`):\n",
        bit_rate / 1000
    );
    out.push_str(&report::reaction_table(&hardware[0]));
    let _ = writeln!(
        out,
        "\nThe example network file (`safety-config sfrt example.toml`, `safety-config budget example.toml`):\n\n```toml\n{}```",
        sfrt::example_network(refresh, sct, srvt)
    );
    let simulated_timing = DeviceTiming {
        input_sample_us: 0,
        contact_skew_us: 0,
        processing_us: 0,
        output_us: 0,
        ..DeviceTiming::HARDWARE
    };
    out.push_str(
        "\nThe same calculation with the simulation's timing (no sampling or processing time, both contacts together) beside the longest reaction the simulation measured (`cargo xtask reaction`, `docs/network-performance.md`); higher-priority traffic is 8-byte frames on 090h taking half the bus:\n\n| path | kbit/s | higher-priority traffic | simulated max (ms) | calculated bound (ms) | bound / simulated |\n|---|---:|---|---:|---:|---:|\n",
    );
    for (path, kbit, loaded, max_us) in simulated_reactions(performance)? {
        let rate = kbit * 1000;
        let extra: Vec<Stream> = if loaded {
            let frame = frame_micros(8, rate);
            vec![Stream {
                id: 0x090,
                len: 8,
                period_us: frame * 2,
            }]
        } else {
            Vec::new()
        };
        let streams = sfrt::planned_streams(&network, None, &extra);
        let bound = &sfrt::reactions(&network, &streams, rate, &simulated_timing)?[0];
        let calculated = match path.as_str() {
            "event-driven SRDO" => bound.fault_free_us,
            "GFC" => bound.gfc_us,
            "SCT expiry (producer stops)" => bound.one_fault_us,
            other => bail!(
                "docs/network-performance.md: reaction path {other:?} is not one the calculator knows"
            ),
        };
        if calculated < max_us {
            bail!(
                "the calculated bound {} ms for {path} at {kbit} kbit/s is below the simulated {} ms",
                report::ms(calculated),
                report::ms(max_us)
            );
        }
        let _ = writeln!(
            out,
            "| {path} | {kbit} | {} | {} | {} | {:.2} |",
            if loaded { "yes" } else { "no" },
            report::ms(max_us),
            report::ms(calculated),
            calculated as f64 / max_us.max(1) as f64
        );
    }
    Ok(out)
}

/// The SimpleCAN worked example: `safety-config sfrt` on the example file with the
/// hardware's timing, its residual error rate against SIL 3, and the same calculation on the
/// host network's timing beside the emergency-stop reactions measured on two dual-channel
/// nodes configured by the tool from that file (`system_tests::simplecan_dual`, 20 presses
/// spread over the cycle; the test `sc_req_45_…` checks the same). A measured reaction above
/// its bound fails here.
fn simplecan_part(root: &Path) -> Result<String> {
    use safety_config::calc::simplecan as calc;
    use system_tests::simplecan_dual::{
        calculator_timing, emergency_stop_reactions, reaction_with_every_packet_lost,
    };
    const PHASES: u64 = 20;
    let text = std::fs::read_to_string(root.join(SIMPLECAN_EXAMPLE))
        .with_context(|| format!("reading {SIMPLECAN_EXAMPLE}"))?;
    let file = network_file::parse(&text, SIMPLECAN_EXAMPLE)?;
    let Some(simplecan) = file.simplecan.as_ref() else {
        bail!("{SIMPLECAN_EXAMPLE} has no [simplecan] section");
    };
    let bit_rate = safety_device::BIT_RATE;
    // SimpleCAN's processing step, counted in the shipped SimpleCAN images, as
    // `docs/performance.md`'s block of the same run states it.
    let step = target::MEASURED_SIMPLECAN.processing_us();
    let bench = std::fs::read_to_string(root.join("docs/performance.md"))
        .context("reading docs/performance.md")?;
    if !block(&bench, crate::target_cost::SIMPLECAN_MARKER)?.contains(&format!("**{step} µs**"))
        || DeviceTiming::HARDWARE_SIMPLECAN.processing_us != step
    {
        bail!(
            "docs/performance.md's {} block does not give SimpleCAN's processing step of \
             safety_config::calc::target::MEASURED_SIMPLECAN ({step} µs): run `cargo xtask \
             bench --target-cost --protocol simplecan`, which writes both",
            crate::target_cost::SIMPLECAN_MARKER
        );
    }
    let hardware = calc::reactions(simplecan, bit_rate, &DeviceTiming::HARDWARE_SIMPLECAN)?;
    let host = calc::reactions(simplecan, bit_rate, &calculator_timing())?;
    let (Some(hw), Some(sim)) = (hardware.first(), host.first()) else {
        bail!("{SIMPLECAN_EXAMPLE} has no consumed SC-ID");
    };
    let Some(timeout_ms) = simplecan
        .nodes
        .get(&sim.consumer)
        .and_then(|node| node.consumed.iter().find(|c| c.sc_id == sim.sc_id))
        .map(|consumed| consumed.timeout_ms)
    else {
        bail!(
            "{SIMPLECAN_EXAMPLE}: node {} does not consume SC-ID {:02X}h",
            sim.consumer,
            sim.sc_id
        );
    };
    let measured = emergency_stop_reactions(
        &file,
        bit_rate,
        (sim.producer, sim.consumer, sim.sc_id),
        PHASES,
    )
    .map_err(|error| anyhow::anyhow!("{SIMPLECAN_EXAMPLE}: {error}"))?;
    let lost =
        reaction_with_every_packet_lost(&file, bit_rate, (sim.producer, sim.consumer, sim.sc_id))
            .map_err(|error| anyhow::anyhow!("{SIMPLECAN_EXAMPLE}: {error}"))?;
    let worst = measured.iter().copied().max().unwrap_or_default();
    let best = measured.iter().copied().min().unwrap_or_default();
    if lost > sim.one_fault_us {
        bail!(
            "the SimpleCAN reaction with every packet lost, measured {} ms on the host network, is above its calculated bound {} ms",
            report::ms(lost),
            report::ms(sim.one_fault_us)
        );
    }
    if worst > sim.fault_free_us {
        bail!(
            "the SimpleCAN reaction measured on the host network, {} ms, is above its calculated bound {} ms",
            report::ms(worst),
            report::ms(sim.fault_free_us)
        );
    }
    let mut out = header(&format!(
        "`{SIMPLECAN_EXAMPLE}` by `safety_config::calc::simplecan` and `system_tests::simplecan_dual`"
    ));
    let _ = writeln!(
        out,
        "The example network file (`safety-config sfrt simplecan-network.toml --bit-rate {bit_rate}`):\n\n```toml\n{text}```\n\nIts output, with the hardware's timing and SimpleCAN's processing step counted in the shipped SimpleCAN images on the emulated STM32F405 (`DeviceTiming::HARDWARE_SIMPLECAN`, {step} µs):\n"
    );
    out.push_str(&report::simplecan_reactions(
        &hardware,
        bit_rate,
        &DeviceTiming::HARDWARE_SIMPLECAN,
    ));
    if hw.fault_free_us <= u64::from(timeout_ms) * 1000 {
        let _ = writeln!(
            out,
            "The fault-free chain, {} ms, is within the configured safety timeout of {timeout_ms} ms: the reaction time is the timeout's path, {} ms, the safety timeout and the steps around it (SC_REQ_45).",
            report::ms(hw.fault_free_us),
            report::ms(hw.worst_us)
        );
    } else {
        let _ = writeln!(
            out,
            "The fault-free chain, {} ms, is longer than the configured safety timeout of {timeout_ms} ms: the reaction time is that chain, {} ms, not the timeout; a longer timeout makes it the timeout's path (SC_REQ_45).",
            report::ms(hw.fault_free_us),
            report::ms(hw.worst_us)
        );
    }
    out.push_str(&report::simplecan_residual(
        &calc::residual(simplecan, Sil::Sil3),
        Sil::Sil3,
    ));
    let _ = writeln!(
        out,
        "\nThe same calculation with the host network's timing (no sampling or processing time, the simulation's link) beside the emergency stop measured on two dual-channel nodes configured by the tool from this file, pressed at {PHASES} instants spread over the cycle:\n\n| path | measured (ms) | calculated bound (ms) |\n|---|---:|---:|\n| fault-free | {} .. {} | {} |\n| every packet after the demand lost (safety timeout) | {} | {} |",
        report::ms(best),
        report::ms(worst),
        report::ms(sim.fault_free_us),
        report::ms(lost),
        report::ms(sim.one_fault_us)
    );
    Ok(out)
}

/// The processing step the reaction times use (`safety_config::calc::target`, whose
/// constants `cargo xtask bench --target-cost` writes), checked against that command's block
/// of `docs/performance.md`, which it wrote in the same run: a step that differs from the
/// measurement fails here.
fn processing_part(bench: &str) -> Result<String> {
    let measured = target::MEASURED;
    let step = measured.processing_us();
    let block = block(bench, crate::target_cost::MARKER)?;
    let stated = format!(
        "{} instructions, at {} cycles per instruction",
        measured.path_instructions(),
        target::CPI_BOUND
    );
    if !block.contains(&stated) || !block.contains(&format!("**{step} µs**")) {
        bail!(
            "docs/performance.md's target-cost block does not give the processing step of \
             safety_config::calc::target ({stated}: {step} µs): run `cargo xtask bench \
             --target-cost`, which writes both"
        );
    }
    if DeviceTiming::HARDWARE.processing_us != step {
        bail!(
            "DeviceTiming::HARDWARE uses a processing step of {} µs, not the measured {step} µs",
            DeviceTiming::HARDWARE.processing_us
        );
    }
    let mut out = header("`safety_config::calc::target` and `docs/performance.md`");
    let target::Basis::Activations = measured.basis;
    let rows = format!(
        "| the activation a frame may wait behind: the longest that ran the loop, from the \
         core's wake-up to its next sleep (interrupt handlers, the iteration, \
         the watchdog fed, the stack's search) | {} | counted in the shipped images on the \
         emulated STM32F405 (most seen) |\n\
         | the activation that handles the SRDO frame, the pair or the verdict: the longest \
         with a pair's work | {} | counted in the shipped images on the emulated STM32F405 \
         (most seen) |\n",
        measured.longest_iteration, measured.longest_protocol_iteration
    );
    let _ = writeln!(
        out,
        "| part of the longest processing path | Thumb instructions | how it is known |\n\
         |---|---:|---|\n\
         {rows}\
         | **path** | **{}** | |\n",
        measured.path_instructions()
    );
    let cycles = measured.path_instructions() * target::CPI_BOUND;
    let _ = writeln!(
        out,
        "At {} cycles per instruction (an assumption: every instruction pays a flash line \
         fetch with the 5 wait states of 168 MHz, as if the ART accelerator never hit) the path \
         is {cycles} cycles, {:.1} µs at {} MHz; doubled for interrupts (an allowance by \
         argument) and rounded up to 10 µs, the processing step is **{step} µs**.",
        target::CPI_BOUND,
        cycles as f64 * 1e6 / target::CLOCK_HZ as f64,
        target::CLOCK_HZ / 1_000_000
    );
    Ok(out)
}

/// The residual error rate's limits per SIL, and the example's budget.
fn residual_part() -> Result<String> {
    let mut out = header("`safety_config::calc::residual` and `safety_config::calc::budget`");
    out.push_str("The most SRDOs per second a network may carry and stay below each SIL's limit, by number of safety devices m (Λ ≈ 3600 · 10⁻¹⁶ · v · (m − 1) · 100 per hour):\n\n| safety devices m | SIL 1 (< 10⁻⁵/h) | SIL 2 (< 10⁻⁶/h) | SIL 3 (< 10⁻⁷/h) |\n|---:|---:|---:|---:|\n");
    for devices in [2u32, 4, 8, 16, 32, 64] {
        let most = |sil| residual::max_srdos_per_second(sil, devices);
        let _ = writeln!(
            out,
            "| {devices} | {:.0} | {:.0} | {:.1} |",
            most(Sil::Sil1),
            most(Sil::Sil2),
            most(Sil::Sil3)
        );
    }
    let (refresh, sct, srvt) = DEMO;
    let network = network_file::parse(&sfrt::example_network(refresh, sct, srvt), "example")?;
    let plan = Plan {
        sil: Sil::Sil3,
        devices: None,
        event_interval_us: None,
        traffic: Vec::new(),
    };
    let budget = budget::budget(&network, &plan, safety_device::BIT_RATE);
    out.push_str("\nThe example network (`safety-config budget example.toml --sil 3`):\n\n");
    out.push_str(&report::budget(&budget, Sil::Sil3));
    Ok(out)
}

/// The campaigns' result table and the full network's reaction line.
fn evidence_part(campaigns: &str, performance: &str) -> Result<String> {
    let mut out = header(
        "`docs/campaigns.md` (`cargo xtask campaign`) and `docs/network-performance.md` (`cargo xtask fullnet`)",
    );
    let result = campaigns
        .split_once("## Result")
        .map(|(_, rest)| rest)
        .context("docs/campaigns.md has no `## Result` section")?;
    let command = result
        .lines()
        .find(|line| line.starts_with('`'))
        .context("docs/campaigns.md: no command line under `## Result`")?;
    let _ = writeln!(out, "Fault campaigns: {command}\n");
    out.push_str("| class | kbit/s | requirement | injected | detected | harmless | unsafe | late | max latency (ms) | bound (ms) |\n|---|---:|---|---:|---:|---:|---:|---:|---:|---:|\n");
    let cells = |line: &str| -> Vec<String> {
        line.trim_matches('|')
            .split('|')
            .map(|cell| cell.trim().to_owned())
            .collect()
    };
    let mut rows = result.lines().skip_while(|l| !l.starts_with("| class"));
    let header = cells(rows.next().context("docs/campaigns.md: no result table")?);
    // The columns by their names, so that a column added to the campaign's table does not
    // shift what the manual reports.
    let column = |name: &str| -> Result<usize> {
        header
            .iter()
            .position(|cell| cell == name)
            .with_context(|| format!("docs/campaigns.md: the result table has no column {name:?}"))
    };
    let wanted = [
        "class",
        "kbit/s",
        "requirement",
        "injected",
        "detected",
        "harmless",
        "unsafe",
        "late",
        "max latency (ms)",
        "bound (ms)",
    ]
    .map(column);
    let mut columns = [0usize; 10];
    for (slot, found) in columns.iter_mut().zip(wanted) {
        *slot = found?;
    }
    let mut unsafe_or_late = 0u64;
    let mut injected = 0u64;
    for line in rows.skip(1) {
        if !line.starts_with('|') {
            break;
        }
        let row = cells(line);
        let cell = |i: usize| -> Result<&str> {
            row.get(columns[i]).map(String::as_str).with_context(|| {
                format!("docs/campaigns.md: row {line:?} is shorter than its header")
            })
        };
        injected += cell(3)?.parse::<u64>()?;
        unsafe_or_late += cell(6)?.parse::<u64>()? + cell(7)?.parse::<u64>()?;
        let shown = (0..columns.len())
            .map(cell)
            .collect::<Result<Vec<_>>>()?
            .join(" | ");
        let _ = writeln!(out, "| {shown} |");
    }
    let _ = writeln!(
        out,
        "\n{injected} scenarios, {unsafe_or_late} unsafe or late."
    );
    let fullnet = block(performance, "fullnet")?;
    let reaction = fullnet
        .lines()
        .find_map(|l| l.strip_prefix("**Reaction** ("))
        .and_then(|l| l.split_once("): "))
        .context("docs/network-performance.md: the fullnet block has no **Reaction** line")?;
    let _ = writeln!(
        out,
        "\nFull network (`cargo xtask fullnet`), reaction ({}): {}",
        reaction.0, reaction.1
    );
    Ok(out)
}

/// The toolchain and the hardware images' CRCs (both protocols', `images::SHIPPED`), built
/// now.
fn build_part(root: &Path) -> Result<String> {
    let cross = toolchain::ensure()?;
    for (layer, _) in images::SHIPPED {
        images::build_layer(root, &cross, layer)?;
    }
    let rustc = match cross {
        Cross::Rustup => "rustc".to_owned(),
        Cross::Debian { .. } => "/usr/bin/rustc".to_owned(),
    };
    let version = |program: &str, args: &[&str]| -> String {
        Command::new(program)
            .args(args)
            .output()
            .ok()
            .filter(|out| out.status.success())
            .map_or_else(
                || format!("({program} did not answer)"),
                |out| String::from_utf8_lossy(&out.stdout).trim().to_owned(),
            )
    };
    let commit = version("git", &["-C", &root.to_string_lossy(), "rev-parse", "HEAD"]);
    let dirty = !version(
        "git",
        &["-C", &root.to_string_lossy(), "status", "--porcelain"],
    )
    .is_empty();
    let mut out =
        String::from("<!-- Written by `cargo xtask manual` when it builds the book. -->\n\n");
    let _ = writeln!(
        out,
        "Built from commit `{commit}`{}.\n\n| | |\n|---|---|\n| compiler | `{}` |\n| cargo | `{}` |\n| target | `{}` (`firmware` profile: release, `opt-level = \"z\"`) |\n| mdBook | `{}` |\n",
        if dirty {
            " with uncommitted changes (not a release build)"
        } else {
            ""
        },
        version(&rustc, &["--version"]),
        version("cargo", &["--version"]),
        toolchain::TARGET,
        version("mdbook", &["--version"]),
    );
    out.push_str("| image | protocol | flash (bytes) | RAM with stack reserve (bytes) | image CRC (checked at every start) |\n|---|---|---:|---:|---:|\n");
    for (layer, _) in images::SHIPPED {
        let protocol = match layer {
            Layer::HwSimpleCan => {
                "SimpleCAN instead of SRDOs (`cargo xtask flash --protocol simplecan`)"
            }
            Layer::Hw => "CANopen Safety",
        };
        for channel in ["a", "b"] {
            let elf = images::image(&cross, root, layer, channel);
            let crc = images::seal(&elf)?;
            let sizes = images::measure(&elf)?;
            let _ = writeln!(
                out,
                "| channel-{channel} | {protocol} | {} | {} | {crc:08X}h |",
                sizes.flash(),
                sizes.ram()
            );
        }
    }
    Ok(out)
}

/// `docs/access-protection.md` for the book when it exists, else a sentence that it does not.
fn access_protection(root: &Path) -> Result<String> {
    let path = root.join("docs/access-protection.md");
    if path.exists() {
        let text = std::fs::read_to_string(&path).context("reading docs/access-protection.md")?;
        // Its headings one level down, under the chapter's own; its links into the
        // repository do not resolve inside the book and are shown as paths.
        Ok(text
            .lines()
            .map(|line| {
                let line = unlink(line);
                if line.starts_with('#') {
                    format!("#{line}")
                } else {
                    line
                }
            })
            .collect::<Vec<_>>()
            .join("\n")
            + "\n")
    } else {
        Ok("*`docs/access-protection.md` is not in this revision of the repository: the protection against unauthorised configuration is not described yet, and until it is, the measures below are all there is.*\n".into())
    }
}

/// `line` with every Markdown link to a relative target, `[text](target)`, written as
/// `text (target)`: the target is a path in the repository, not a page of the book.
/// Links to other sites and anchors stay.
fn unlink(line: &str) -> String {
    let mut out = String::new();
    let mut rest = line;
    while let Some(open) = rest.find('[') {
        let Some(close) = rest[open..].find("](").map(|at| open + at) else {
            break;
        };
        let Some(end) = rest[close..].find(')').map(|at| close + at) else {
            break;
        };
        let (text, target) = (&rest[open + 1..close], &rest[close + 2..end]);
        out.push_str(&rest[..open]);
        if target.contains("://") || target.starts_with('#') || target.starts_with("mailto:") {
            out.push_str(&rest[open..=end]);
        } else {
            let _ = write!(out, "{text} (`{target}`)");
        }
        rest = &rest[end + 1..];
    }
    out.push_str(rest);
    out
}

fn copy_tree(from: &Path, to: &Path) -> Result<()> {
    std::fs::create_dir_all(to)?;
    for entry in std::fs::read_dir(from).with_context(|| format!("reading {}", from.display()))? {
        let entry = entry?;
        let target = to.join(entry.file_name());
        if entry.file_type()?.is_dir() {
            copy_tree(&entry.path(), &target)?;
        } else {
            std::fs::copy(entry.path(), &target)?;
        }
    }
    Ok(())
}

/// Every HTML file under `dir`.
fn html_files(dir: &Path, out: &mut Vec<PathBuf>) -> Result<()> {
    for entry in std::fs::read_dir(dir)? {
        let path = entry?.path();
        if path.is_dir() {
            html_files(&path, out)?;
        } else if path.extension().is_some_and(|e| e == "html") {
            out.push(path);
        }
    }
    Ok(())
}

/// The values of every `attribute="…"` in `html`.
fn attributes<'a>(html: &'a str, attribute: &str) -> Vec<&'a str> {
    let needle = format!(" {attribute}=\"");
    let mut found = Vec::new();
    let mut rest = html;
    while let Some(at) = rest.find(&needle) {
        rest = &rest[at + needle.len()..];
        if let Some(end) = rest.find('"') {
            found.push(&rest[..end]);
            rest = &rest[end..];
        }
    }
    found
}

/// Checks that every relative link (`href`, `src`) in the book resolves to a file, and every
/// fragment to an `id` in it. Returns how many were checked.
fn check_links(html_dir: &Path) -> Result<usize> {
    let mut files = Vec::new();
    html_files(html_dir, &mut files)?;
    let mut ids: BTreeMap<PathBuf, BTreeSet<String>> = BTreeMap::new();
    for file in &files {
        let text = std::fs::read_to_string(file)?;
        ids.insert(
            file.clone(),
            attributes(&text, "id")
                .into_iter()
                .map(str::to_owned)
                .collect(),
        );
    }
    let mut broken = Vec::new();
    let mut checked = 0;
    for file in &files {
        // mdBook's print page repeats every chapter with rewritten links; the chapters are
        // checked themselves.
        if file
            .file_name()
            .is_some_and(|n| n == "print.html" || n == "404.html")
        {
            continue;
        }
        let text = std::fs::read_to_string(file)?;
        for link in attributes(&text, "href")
            .into_iter()
            .chain(attributes(&text, "src"))
        {
            if link.contains("://")
                || link.starts_with("mailto:")
                || link.starts_with("javascript:")
                || link.starts_with("data:")
            {
                continue;
            }
            checked += 1;
            let (path, fragment) = link.split_once('#').unwrap_or((link, ""));
            let path = path.split('?').next().unwrap_or(path);
            let target = if path.is_empty() {
                file.clone()
            } else {
                let base = file.parent().unwrap_or(html_dir);
                let joined = base.join(path);
                if joined.is_dir() {
                    joined.join("index.html")
                } else {
                    joined
                }
            };
            let Ok(target) = target.canonicalize() else {
                broken.push(format!(
                    "{}: {link} (no such file)",
                    relative(file, html_dir)
                ));
                continue;
            };
            if fragment.is_empty() {
                continue;
            }
            let found = ids
                .iter()
                .find(|(path, _)| path.canonicalize().ok().as_ref() == Some(&target))
                .is_some_and(|(_, ids)| ids.contains(fragment));
            if !found {
                broken.push(format!(
                    "{}: {link} (no anchor #{fragment})",
                    relative(file, html_dir)
                ));
            }
        }
    }
    if !broken.is_empty() {
        bail!(
            "{} links in the manual do not resolve:\n  {}",
            broken.len(),
            broken.join("\n  ")
        );
    }
    Ok(checked)
}

fn relative(path: &Path, base: &Path) -> String {
    path.strip_prefix(base)
        .unwrap_or(path)
        .display()
        .to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The block reader finds the lines between the markers, or says which marker is missing.
    #[test]
    fn a_block_is_read_between_its_markers() {
        let text = "a\n<!-- reaction:begin (generated, do not edit) -->\none\ntwo\n<!-- reaction:end -->\nb";
        assert_eq!(block(text, "reaction").unwrap(), "\none\ntwo\n");
        assert!(
            block(text, "fullnet")
                .unwrap_err()
                .to_string()
                .contains("fullnet:begin")
        );
    }

    /// Every cause has its doc comment and its advice, and the table has a row for each.
    #[test]
    fn every_cause_of_the_table_has_its_meaning_and_advice() {
        let source = include_str!("../../shared/src/safety/cause.rs");
        let table = cause_table(source).unwrap();
        assert_eq!(
            table
                .lines()
                .filter(|l| l.starts_with("| ") && !l.starts_with("| code"))
                .count(),
            Cause::ALL.len()
        );
        assert!(table.contains(
            "| 01h | SCT elapsed | SCT elapsed without a complete pair (EN 50325-5 7.1.2). |"
        ));
    }

    /// Links into the repository become paths; links to other sites and anchors stay.
    #[test]
    fn repository_links_of_an_included_document_become_paths() {
        assert_eq!(
            unlink("see [the README](../README.md) and [CiA](https://can-cia.org) or [below](#x)."),
            "see the README (`../README.md`) and [CiA](https://can-cia.org) or [below](#x)."
        );
        assert_eq!(unlink("a [bracket] alone"), "a [bracket] alone");
    }

    /// The committed generated parts are what the sources and the committed measurements
    /// give now (what `cargo xtask manual --check` checks, here without mdBook): a change of
    /// the EDS, the cause table, the calculators or a measurement report fails until
    /// `cargo xtask manual` is run and its output committed.
    #[test]
    fn en50325_5_9_6_the_committed_generated_parts_of_the_manual_are_current() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
        for (name, text) in committed_parts(root).unwrap() {
            let committed =
                std::fs::read_to_string(root.join("manual/src/generated").join(name)).unwrap();
            assert!(
                committed == text,
                "manual/src/generated/{name} is stale: run `cargo xtask manual` and commit it"
            );
        }
    }

    /// The link checker finds a missing file and a missing anchor, and passes good links.
    #[test]
    fn broken_links_and_anchors_are_named() {
        let dir = std::env::temp_dir().join(format!("xtask-manual-links-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("a.html"),
            r#"<a href="b.html#here">b</a> <a href="https://x">x</a> <h1 id="top">"#,
        )
        .unwrap();
        std::fs::write(
            dir.join("b.html"),
            r#"<p id="here"></p><a href="a.html#top">a</a>"#,
        )
        .unwrap();
        assert_eq!(check_links(&dir).unwrap(), 2);
        std::fs::write(
            dir.join("b.html"),
            r#"<a href="a.html#gone">a</a> <img src="c.png">"#,
        )
        .unwrap();
        let error = check_links(&dir).unwrap_err().to_string();
        assert!(
            error.contains("b.html: a.html#gone (no anchor #gone)"),
            "{error}"
        );
        assert!(error.contains("b.html: c.png (no such file)"), "{error}");
        assert!(
            error.contains("a.html: b.html#here (no anchor #here)"),
            "{error}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
