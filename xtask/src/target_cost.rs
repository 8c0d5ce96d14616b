//! `cargo xtask bench --target-cost`: Thumb instructions the real QEMU images execute, counted
//! under QEMU (netduinoplus2) one instruction per translation block on the emulated network,
//! the CPU load they imply at 168 MHz, and the processing step of the safety manual; written
//! into its own block of `docs/performance.md` and into `tool/src/calc/target_measured.rs`.
//!
//! How it counts: the emulated network of `cargo xtask run` (hub and four images) comes up,
//! configured and Operational, with QEMU's monitor of every image on a Unix socket and QEMU's
//! clock counting instructions (`-icount`, see `network::qemu_instance`). Then, one image at
//! a time, its monitor switches on `one-insn-per-tb` and `-d exec,nochain`, so that the trace
//! has one line per executed instruction with its address; the hub paces the network's
//! virtual time, so the traced (slow) image only slows the bus down. For [`TRACE_FOR`] of
//! the network's time node 1 sends its SRDO every 100 ms, the emergency stop is pressed and
//! released once (pairs with changed data, outputs driven), and the link heartbeats run; the
//! trace is counted and removed before the next image's. A call of a
//! tracked function starts at a line at the function's symbol address reached from a `bl`
//! and ends at the first line at the address after that `bl` ([`count`]); its instructions
//! are counted in thread mode only (an interrupt handler running meanwhile, which QEMU flags
//! as handler mode and which a traced QEMU takes far more often than the MCU would, is not
//! the call's cost). The unit is one iteration of the channel loop, `ChannelLoop::service`
//! (`#[inline(never)]`): what it handled is told by the markers of the QEMU board layer
//! (`board::qemu::marker`: a plain or inverted SRDO frame received or sent, link bytes),
//! whose own instructions are subtracted, and by the tracked functions it
//! called (`hand`, one received frame; `Device::poll`, the core polled; `VerdictCheck::arrive`,
//! a verdict of the cross-check). For each channel's longest iteration the log also gives its
//! instructions by the function QEMU names for each (the image's function holding the
//! address, code inlined into it included): that is how the QEMU layer's clock, a 128-bit
//! software division on every `now()`, was found to be most of the longest iterations.

pub(crate) mod count;
mod simplecan;

use crate::images::{self, Layer};
use crate::network::{CHANNELS, Network, Protocol};
use crate::toolchain;
use anyhow::{Context, Result, bail};
use count::{Call, Counted};
use object::{Object, ObjectSymbol};
use safety_config::calc::target::{self as cost, TargetCost};
use std::fmt::Write as _;
use std::io::{Read as _, Write as _};
use std::path::Path;
use std::time::Duration;

/// The document the block goes to ([`crate::fullnet::replace_block`]'s markers `target-cost`).
const DOCUMENT: &str = "docs/performance.md";
/// The block's marker name.
pub(crate) const MARKER: &str = "target-cost";
/// The SimpleCAN images' block's marker name.
pub(crate) use simplecan::MARKER as SIMPLECAN_MARKER;
/// The generated constants the tool's processing step comes from.
const MEASURED_RS: &str = "tool/src/calc/target_measured.rs";
/// How long each image's trace runs, in the network's virtual time: 15 of node 1's pairs.
const TRACE_FOR: Duration = Duration::from_millis(1500);
/// Attempts to bring the network up.
const STARTS: u32 = 3;
/// How long the traced network may take for it in host time.
const TRACE_HOST_LIMIT: Duration = Duration::from_secs(1200);
/// The hardware layer's link heartbeat period (`board::hw`): each channel computes its digest
/// once per period, for its heartbeat, and compares the other channel's with it.
const LINK_PERIOD_MS: u64 = 10;
/// The loop runs at least every input sample period (`dual_channel::channel_loop`).
const SAMPLE_PERIOD_MS: u64 = 1;
/// SRDOs of the images ([`safety_device::SRDO_COUNT`]) and of the node the load is
/// estimated for, at its refresh time.
const IMAGE_SRDOS: u64 = safety_device::SRDO_COUNT as u64;
const LOAD_SRDOS: u64 = 64;
const LOAD_REFRESH_MS: u64 = 10;

/// The tracked functions, by the end of their demangled names (each must name one symbol).
const TRACKED: [&str; 14] = [
    "dual_channel::channel_loop::ChannelLoop::service",
    "dual_channel::channel_loop::hand",
    "shared::node::Device<F,P>::poll",
    "dual_channel::crosscheck::VerdictCheck<_,S>::arrive",
    "board::qemu::marker::received",
    "board::qemu::marker::transmitted",
    "board::qemu::marker::link_received",
    "board::qemu::marker::received_plain",
    "board::qemu::marker::received_inverted",
    "board::qemu::marker::transmitted_plain",
    "board::qemu::marker::transmitted_inverted",
    "as dual_channel::runtime::Role<_>>::signature_digest",
    "dual_channel::runtime::Runtime<F,R,_,P>::heartbeat",
    "dual_channel::runtime::Runtime<F,R,_,P>::confirmed",
];
/// How many functions the log names for the longest iteration.
const SYMBOLS_SHOWN: usize = 8;

/// A symbol as QEMU names it (mangled), demangled without its hash.
fn demangled(name: &str) -> String {
    format!("{:#}", rustc_demangle::demangle(name))
}

const SERVICE: usize = 0;
const HAND: usize = 1;
const CORE_POLL: usize = 2;
const ARRIVE: usize = 3;
const RECEIVED: usize = 4;
const TRANSMITTED: usize = 5;
const LINK: usize = 6;
const RX_PLAIN: usize = 7;
const RX_INVERTED: usize = 8;
const TX_PLAIN: usize = 9;
const TX_INVERTED: usize = 10;
const DIGEST: usize = 11;
const HEARTBEAT: usize = 12;
/// Both channels' verdicts agreed on a pair (CiA 304 9.5, EN 50325-5 7.1.2): called on the
/// side whose verdict came second, the local one or the other channel's over the link.
const CONFIRMED: usize = 13;
/// The markers called by the loop: their instructions are not the loop's (the leaf markers
/// are inside them).
const MARKERS: [usize; 3] = [RECEIVED, TRANSMITTED, LINK];

/// Fewest, median and most of a set of counts, and how many.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Spread {
    fewest: u64,
    median: u64,
    most: u64,
    seen: usize,
}

impl Spread {
    fn of(mut values: Vec<u64>) -> Option<Spread> {
        values.sort_unstable();
        Some(Spread {
            fewest: *values.first()?,
            median: values[values.len() / 2],
            most: *values.last()?,
            seen: values.len(),
        })
    }

    /// Two parts that happen once each (a bound for the pair: the parts' fewest, medians
    /// and most added).
    fn plus(self, other: Spread) -> Spread {
        Spread {
            fewest: self.fewest + other.fewest,
            median: self.median + other.median,
            most: self.most + other.most,
            seen: self.seen.min(other.seen),
        }
    }
}

/// What one channel's trace showed.
#[derive(Debug, Default)]
struct Channel {
    /// Loop iterations (markers subtracted) by what they handled.
    plain_received: Vec<u64>,
    inverted_received: Vec<u64>,
    verdict: Vec<u64>,
    plain_sent: Vec<u64>,
    inverted_sent: Vec<u64>,
    idle: Vec<u64>,
    /// Every iteration.
    all: Vec<u64>,
    /// Consumer: the cost of one validated pair ([`Pair`]).
    pairs: Vec<u64>,
    /// `hand` of a plain and of an inverted frame (the runtime's `on_frame`), markers
    /// subtracted.
    hand_plain: Vec<u64>,
    hand_inverted: Vec<u64>,
    digest: Vec<u64>,
    heartbeat: Vec<u64>,
    /// The longest iteration (markers subtracted) and the tracked calls made inside it, for
    /// the log: what the iteration that sets the processing step spent its instructions on.
    longest: Option<(u64, Call)>,
    /// Lines of the trace.
    lines: u64,
}

impl Channel {
    fn of(counted: Counted) -> Channel {
        let mut channel = Channel {
            lines: counted.lines,
            ..Channel::default()
        };
        let mut pair: Option<Pair> = None;
        for call in &counted.calls {
            match call.function {
                SERVICE => channel.iteration(call, &mut pair),
                DIGEST => channel.digest.push(call.instructions),
                HEARTBEAT => channel.heartbeat.push(call.instructions),
                _ => {}
            }
        }
        channel
    }

    /// The longest iteration and the tracked calls inside it, by function (count and
    /// instructions; calls nested in one another are each counted whole).
    fn longest(&self) -> String {
        let Some((most, call)) = &self.longest else {
            return "no loop iteration".to_owned();
        };
        let (nested, symbols) = (&call.nested, &call.symbols);
        let mut parts = Vec::new();
        for (index, name) in TRACKED.iter().enumerate() {
            let calls: Vec<u64> = nested
                .iter()
                .filter(|(function, _)| *function == index)
                .map(|(_, count)| *count)
                .collect();
            if !calls.is_empty() {
                let short = name.rsplit("::").next().unwrap_or(name);
                parts.push(format!(
                    "{short} {}× {}",
                    calls.len(),
                    calls.iter().sum::<u64>()
                ));
            }
        }
        // Where its instructions are, by the image's function that holds each (inlined code
        // counts as the function it was inlined into); the markers included.
        let by_symbol: Vec<String> = symbols
            .iter()
            .take(SYMBOLS_SHOWN)
            .map(|(name, count)| {
                let name = name
                    .split(count::CALLED_FROM)
                    .map(demangled)
                    .collect::<Vec<_>>()
                    .join(count::CALLED_FROM);
                format!("{name} {count}")
            })
            .collect();
        format!(
            "longest loop iteration {most} instructions (markers subtracted); tracked calls \
             inside it: {}; by function, the {SYMBOLS_SHOWN} largest: {}",
            if parts.is_empty() {
                "none".to_owned()
            } else {
                parts.join(", ")
            },
            by_symbol.join(", ")
        )
    }

    /// How many of each were seen.
    fn summary(&self) -> String {
        format!(
            "{} loop iterations: {} idle, {} plain and {} inverted frames received, {} verdicts, \
             {} pairs validated, {} plain and {} inverted frames sent; {} digests, {} heartbeats \
             ({} trace lines)",
            self.all.len(),
            self.idle.len(),
            self.plain_received.len(),
            self.inverted_received.len(),
            self.verdict.len(),
            self.pairs.len(),
            self.plain_sent.len(),
            self.inverted_sent.len(),
            self.digest.len(),
            self.heartbeat.len(),
            self.lines
        )
    }

    fn iteration(&mut self, call: &Call, pair: &mut Option<Pair>) {
        let own = call.without(&MARKERS);
        self.all.push(own);
        if self.longest.as_ref().is_none_or(|(most, _)| own > *most) {
            self.longest = Some((own, call.clone()));
        }
        let plain = call.made(RX_PLAIN);
        let inverted = call.made(RX_INVERTED);
        if plain {
            self.plain_received.push(own);
        }
        if inverted {
            self.inverted_received.push(own);
        }
        if call.made(TX_PLAIN) {
            self.plain_sent.push(own);
        }
        if call.made(TX_INVERTED) {
            self.inverted_sent.push(own);
        }
        let verdict = !plain && !inverted && call.made(LINK) && call.made(ARRIVE);
        if verdict {
            self.verdict.push(own);
        }
        if ![HAND, CORE_POLL, LINK, RECEIVED, TRANSMITTED]
            .iter()
            .any(|&f| call.made(f))
        {
            self.idle.push(own);
        }
        // The frames one by one: a `hand` after the marker of the frame it was given.
        let mut half = None;
        let mut marker_inside = 0;
        for &(function, count) in &call.nested {
            match function {
                RX_PLAIN => half = Some(true),
                RX_INVERTED => half = Some(false),
                TRANSMITTED => marker_inside += count,
                HAND => {
                    let own_hand = count - std::mem::take(&mut marker_inside);
                    match half.take() {
                        Some(true) => self.hand_plain.push(own_hand),
                        Some(false) => self.hand_inverted.push(own_hand),
                        None => {}
                    }
                }
                RECEIVED => marker_inside = 0,
                _ => {}
            }
        }
        // A plain frame opens a pair (a pair still open is dropped: its confirmation was
        // not seen); its inverted frame and the other channel's verdict add their
        // iterations, whichever comes first; the iteration that confirms closes it.
        if plain {
            *pair = Some(Pair {
                sum: 0,
                inverted: false,
            });
        }
        if let Some(open) = pair.as_mut()
            && (plain || inverted || verdict)
        {
            open.sum += own;
            open.inverted |= inverted;
        }
        if call.made(CONFIRMED) {
            if let Some(Pair {
                sum,
                inverted: true,
            }) = pair.take()
            {
                self.pairs.push(sum);
            }
        }
    }
}

/// A validated pair on a consumer, as it is counted: the loop iterations that received its
/// plain frame, its inverted frame and the other channel's verdict over the link (the
/// iteration that took in link bytes and passed a verdict to the cross-check), added, from the
/// plain frame's iteration up to the one in which `Runtime::confirmed` is called (both
/// channels' verdicts agree, CiA 304 9.5). The other channel's verdict may come before this
/// channel's inverted frame (its trace is not slowed down) or after it; then the pair is
/// confirmed in the inverted frame's iteration or in the verdict's. Iterations in between that
/// did nothing for the pair (idle polls, heartbeats) are not the pair's: they are counted
/// as what they are.
#[derive(Clone, Copy, Debug)]
struct Pair {
    /// Instructions of the pair's iterations so far, markers subtracted.
    sum: u64,
    /// Whether its inverted frame was received.
    inverted: bool,
}

/// The x86 figure of a row of the host bench's table (`docs/performance.md`, `cargo xtask
/// bench`).
fn host_figure(document: &str, row: &str) -> Option<u64> {
    document
        .lines()
        .find(|line| line.starts_with(&format!("| {row} |")))?
        .split('|')
        .nth(2)?
        .trim()
        .parse()
        .ok()
}

/// `cargo xtask bench --target-cost [--protocol simplecan]`.
pub fn run(root: &Path, protocol: Protocol) -> Result<()> {
    let cross = toolchain::ensure()?;
    let (traces, traced) = trace(root, protocol)?;
    match protocol {
        Protocol::CanopenSafety => canopen_safety(root, &cross, &traces, traced),
        Protocol::Simplecan => simplecan::run(root, &cross, &traces, traced),
    }
}

/// The emulated network speaking `protocol`, each of its four images traced in turn for
/// [`TRACE_FOR`] of the network's time with the emergency stop pressed and released: the
/// traces' paths, in [`CHANNELS`]' order, and the shortest time an image was traced for.
fn trace(root: &Path, protocol: Protocol) -> Result<([std::path::PathBuf; 4], f64)> {
    let mut network = start(root, protocol)?;
    // One image traced at a time: the others run at full speed, so the network's time moves
    // at the traced image's pace. The traces are counted once the network has ended: while
    // counting, nothing would read the hub's control port, and the status reports piled up
    // there would move the network's time on at once when read again.
    let mut traced = Vec::new();
    let traces = CHANNELS.map(|(name, _, _)| network.dir().join(format!("{name}.trace")));
    for ((name, _, _), trace) in CHANNELS.iter().zip(&traces) {
        let _ = std::fs::remove_file(trace);
        crate::step(&format!(
            "{name}: traced for {} s of the network's time",
            TRACE_FOR.as_secs_f64()
        ));
        let mut monitor = Monitor::connect(&network.monitor(name))?;
        monitor.command(&format!("logfile {}", trace.display()))?;
        monitor.command("one-insn-per-tb on")?;
        monitor.command("log exec,nochain")?;
        let started = network.hub_time();
        let third = TRACE_FOR / 3;
        let give_up = std::time::Instant::now() + TRACE_HOST_LIMIT;
        for (part, level) in [(1, Some(0)), (2, Some(1)), (3, None)] {
            let until = started + (third * part).as_secs_f64();
            while network.hub_time() < until {
                if std::time::Instant::now() >= give_up {
                    bail!(
                        "traced, the network reached only {:.3} s of its time in {} s of host \
                         time",
                        network.hub_time() - started,
                        TRACE_HOST_LIMIT.as_secs()
                    );
                }
                network.wait_for(Duration::from_millis(100), |_| false)?;
            }
            if let Some(level) = level {
                press(&mut network, level)?;
            }
        }
        monitor.command("log none")?;
        monitor.command("one-insn-per-tb off")?;
        traced.push(network.hub_time() - started);
    }
    drop(network);
    Ok((traces, traced.into_iter().fold(f64::INFINITY, f64::min)))
}

/// The CANopen Safety images' counts: `docs/performance.md`'s block and the processing step.
fn canopen_safety(
    root: &Path,
    cross: &toolchain::Cross,
    traces: &[std::path::PathBuf; 4],
    traced: f64,
) -> Result<()> {
    let mut channels = Vec::new();
    for ((name, _, side), trace) in CHANNELS.into_iter().zip(traces) {
        let image = images::image(cross, root, Layer::Qemu, side);
        let channel = Channel::of(counted(&image, &TRACKED, trace, &[SERVICE, HAND])?);
        eprintln!("xtask: {name}: {}", channel.summary());
        eprintln!("xtask: {name}: {}", channel.longest());
        channels.push((name, channel));
    }
    let text = std::fs::read_to_string(root.join(DOCUMENT))
        .with_context(|| format!("reading {DOCUMENT} (run `cargo xtask bench` first)"))?;
    let (block, measured) = render(&channels, &text, traced)?;
    let rs = measured_rs(
        "//! Generated by `cargo xtask bench --target-cost` (do not edit): the instructions it counted\n\
         //! on the target, which [`super::target`] turns into the processing step.\n",
        "cargo xtask bench --target-cost",
        "MEASURED",
        &measured,
    );
    write_results(root, MARKER, &block, MEASURED_RS, &rs)?;
    eprintln!(
        "xtask: wrote the {MARKER} block of {DOCUMENT} and {MEASURED_RS} (processing step {} µs): \
         run `cargo xtask manual` for the manual",
        measured.processing_us()
    );
    Ok(())
}

/// The calls of the `tracked` functions (by name, each naming one function of `image`) in
/// `trace`, with the calls nested in those of `nesting`; the trace is removed after.
fn counted(image: &Path, tracked: &[&str], trace: &Path, nesting: &[usize]) -> Result<Counted> {
    let entries = tracked
        .iter()
        .map(|name| address(image, name))
        .collect::<Result<Vec<u32>>>()?;
    let counted = count::count_calls(trace, &entries, nesting)?;
    // Gigabytes; the counts are what was wanted.
    let _ = std::fs::remove_file(trace);
    Ok(counted)
}

/// Writes `block` between `marker`'s markers of [`DOCUMENT`] and `rs` to `rs_path`, the
/// generated constants the tool's processing step comes from, and prints the block.
fn write_results(root: &Path, marker: &str, block: &str, rs_path: &str, rs: &str) -> Result<()> {
    println!("{block}");
    let path = root.join(DOCUMENT);
    let text = std::fs::read_to_string(&path).with_context(|| format!("reading {DOCUMENT}"))?;
    let updated = crate::fullnet::replace_block(&text, marker, block)
        .with_context(|| format!("{DOCUMENT} has no {marker} block"))?;
    std::fs::write(&path, updated).with_context(|| format!("writing {DOCUMENT}"))?;
    std::fs::write(root.join(rs_path), rs).with_context(|| format!("writing {rs_path}"))
}

/// The processing step's figure as both blocks state it, which `cargo xtask manual` looks
/// for: the path's instructions, the cycles, the step.
fn step_sentence(measured: &TargetCost) -> String {
    format!(
        "{} instructions, at {} cycles per instruction on {} MHz and doubled for interrupts, \
         rounded up to 10 µs: **{} µs**",
        measured.path_instructions(),
        cost::CPI_BOUND,
        cost::CLOCK_HZ / 1_000_000,
        measured.processing_us()
    )
}

/// The network with every image's monitor. Counting instructions, the images answer SDO
/// requests more slowly, and on a loaded machine the configuration's SDO time-out has been
/// seen to expire (2 starts of 5): up to [`STARTS`] attempts.
fn start(root: &Path, protocol: Protocol) -> Result<Network> {
    let mut attempt = 1;
    loop {
        match Network::start_with_monitors(root, &CHANNELS.map(|(name, _, _)| name), protocol) {
            Ok(network) => return Ok(network),
            Err(error) if attempt < STARTS => {
                eprintln!("xtask: the traced network did not come up ({error:#}); again");
                attempt += 1;
            }
            Err(error) => return Err(error),
        }
    }
}

/// Sets both contacts of node 1's emergency stop to `level` (0: pressed). The traced images
/// hold the hub's virtual time back, so its answer may come after the control client's
/// five seconds: the hub still applies the command when its time gets there.
fn press(network: &mut Network, level: u8) -> Result<()> {
    for channel in ["node1a", "node1b"] {
        let command = format!("input {channel} {level}");
        match network.control.command(&command) {
            Ok(Ok(_)) => {}
            Ok(Err(why)) => bail!("the hub refused `{command}`: {why}"),
            Err(error) if error.kind() == std::io::ErrorKind::TimedOut => {
                eprintln!("xtask: `{command}`: the hub has not answered yet (traced images)");
            }
            Err(error) => return Err(error).context(format!("`{command}` to the hub")),
        }
    }
    Ok(())
}

/// A generated file of the tool's processing step: its `header` (the module's `//!` lines),
/// then `constant`, the instructions `command` counted.
fn measured_rs(header: &str, command: &str, constant: &str, measured: &TargetCost) -> String {
    format!(
        "{header}\n\
         use super::target::TargetCost;\n\
         \n\
         /// Counted by `{command}`.\n\
         pub const {constant}: TargetCost = TargetCost {{\n    \
         longest_iteration: {},\n    \
         longest_protocol_iteration: {},\n\
         }};\n",
        measured.longest_iteration, measured.longest_protocol_iteration
    )
}

/// The address (Thumb bit cleared) of the one function whose demangled name ends with `name`.
fn address(elf: &Path, name: &str) -> Result<u32> {
    let bytes = std::fs::read(elf).with_context(|| format!("reading {}", elf.display()))?;
    let file = object::File::parse(&*bytes)?;
    let found: Vec<u32> = file
        .symbols()
        .filter(|symbol| symbol.kind() == object::SymbolKind::Text)
        .filter(|symbol| {
            symbol
                .name()
                .is_ok_and(|raw| format!("{:#}", rustc_demangle::demangle(raw)).ends_with(name))
        })
        .map(|symbol| (symbol.address() & !1) as u32)
        .collect();
    match found.as_slice() {
        [address] => Ok(*address),
        [] => bail!(
            "no function named like `{name}` in {} (inlined by the compiler, or renamed: a generic parameter added?)",
            elf.display()
        ),
        _ => bail!(
            "{} functions named like `{name}` in {}: the name must pick one",
            found.len(),
            elf.display()
        ),
    }
}

/// QEMU's human monitor on a Unix socket.
struct Monitor(std::os::unix::net::UnixStream);

impl Monitor {
    fn connect(path: &Path) -> Result<Self> {
        let stream = std::os::unix::net::UnixStream::connect(path)
            .with_context(|| format!("connecting to QEMU's monitor at {}", path.display()))?;
        stream.set_read_timeout(Some(Duration::from_secs(10)))?;
        let mut monitor = Monitor(stream);
        monitor.prompt()?;
        Ok(monitor)
    }

    /// Sends `command` and waits for the next prompt.
    fn command(&mut self, command: &str) -> Result<()> {
        writeln!(self.0, "{command}")?;
        if command == "quit" {
            return Ok(());
        }
        self.prompt()
            .with_context(|| format!("QEMU's monitor did not answer `{command}`"))
    }

    fn prompt(&mut self) -> Result<()> {
        let mut seen = Vec::new();
        let mut byte = [0u8; 1];
        while !seen.ends_with(b"(qemu) ") {
            if self.0.read(&mut byte)? == 0 {
                bail!("QEMU's monitor closed");
            }
            seen.push(byte[0]);
        }
        Ok(())
    }
}

/// One row of the table: the operation, the image, what the count covers, the spread, the
/// x86 figure beside it.
struct Row {
    operation: &'static str,
    image: String,
    what: &'static str,
    spread: Spread,
    host: Option<u64>,
}

/// The channels' figures of `pick` (each channel named in `names`).
fn spread<C>(
    channels: &[(&str, C)],
    name: &str,
    what: &str,
    pick: impl Fn(&C) -> &Vec<u64>,
) -> Result<Spread> {
    let (_, channel) = channels
        .iter()
        .find(|(n, _)| *n == name)
        .with_context(|| format!("no trace of {name}"))?;
    Spread::of(pick(channel).clone()).with_context(|| {
        format!(
            "the trace of {name} holds no iteration counted as {what:?} (the network ran too \
             briefly, the node left Operational, or a tracked function is no longer called by \
             `bl`)"
        )
    })
}

/// The most of `pick` over every channel.
fn most<C>(channels: &[(&str, C)], pick: impl Fn(&C) -> &Vec<u64>) -> u64 {
    channels
        .iter()
        .flat_map(|(_, channel)| pick(channel).iter().copied())
        .max()
        .unwrap_or(0)
}

/// The block of `docs/performance.md` and the measured constants of the processing step.
fn render(
    channels: &[(&str, Channel)],
    document: &str,
    traced: f64,
) -> Result<(String, TargetCost)> {
    const VALIDATED: &str = "validated 8-byte SRDO pair received";
    const PRODUCED: &str = "8-byte SRDO pair produced";
    const IDLE: &str = "idle poll, nothing due";
    let host = |row| host_figure(document, row);
    let mut rows = Vec::new();
    for name in ["node33a", "node33b"] {
        rows.push(Row {
            operation: VALIDATED,
            image: name.to_owned(),
            what: "the loop iterations of the plain frame, the inverted frame and the other \
                   channel's verdict (cross-check, output)",
            spread: spread(channels, name, "pairs", |c| &c.pairs)?,
            host: host(VALIDATED),
        });
        rows.push(Row {
            operation: VALIDATED,
            image: name.to_owned(),
            what: "`hand` of both frames only (the runtime's `on_frame`: the core's \
                   `handle_frame`, the verdict queued for the link)",
            spread: spread(channels, name, "hand plain", |c| &c.hand_plain)?.plus(spread(
                channels,
                name,
                "hand inverted",
                |c| &c.hand_inverted,
            )?),
            host: host(VALIDATED),
        });
    }
    let plain_sent = spread(channels, "node1a", "plain sent", |c| &c.plain_sent)?;
    let inverted_sent = spread(channels, "node1b", "inverted sent", |c| &c.inverted_sent)?;
    let own_inverted = spread(channels, "node1a", "inverted received", |c| {
        &c.inverted_received
    })?;
    rows.push(Row {
        operation: PRODUCED,
        image: "node1a".to_owned(),
        what: "the loop iteration that built and sent the plain frame",
        spread: plain_sent,
        host: host(PRODUCED),
    });
    rows.push(Row {
        operation: PRODUCED,
        image: "node1b".to_owned(),
        what: "the loop iteration that took the plain frame from the bus and built and sent \
               the inverted one (its own mapping and inversion)",
        spread: inverted_sent,
        host: None,
    });
    rows.push(Row {
        operation: PRODUCED,
        image: "node1a + node1b".to_owned(),
        what: "both halves added (fewest, medians, most added)",
        spread: plain_sent.plus(inverted_sent),
        host: host(PRODUCED),
    });
    rows.push(Row {
        operation: PRODUCED,
        image: "node1a".to_owned(),
        what: "the loop iteration that saw its node's inverted frame (transmit check)",
        spread: own_inverted,
        host: None,
    });
    for (name, _, _) in CHANNELS {
        rows.push(Row {
            operation: IDLE,
            image: name.to_owned(),
            what: "a loop iteration with nothing received, nothing due (pins read, the \
                   deadline compared)",
            spread: spread(channels, name, "idle", |c| &c.idle)?,
            host: host(IDLE),
        });
    }
    for (name, _, _) in CHANNELS {
        rows.push(Row {
            operation: "any loop iteration",
            image: name.to_owned(),
            what: "every iteration traced",
            spread: spread(channels, name, "all", |c| &c.all)?,
            host: None,
        });
    }
    for name in ["node1a", "node1b"] {
        rows.push(Row {
            operation: "configuration digest",
            image: name.to_owned(),
            what: if name.ends_with('a') {
                "`Role::signature_digest`: every SRDO's signature by the `crc` crate's \
                 table, folded by CRC-32"
            } else {
                "`Role::signature_digest`: channel B's own CRC, 8 bits a step, folded by \
                 CRC-32"
            },
            spread: spread(channels, name, "digest", |c| &c.digest)?,
            host: None,
        });
        rows.push(Row {
            operation: "link heartbeat",
            image: name.to_owned(),
            what: "`Runtime::heartbeat`: the digest, the heartbeat message encoded and queued",
            spread: spread(channels, name, "heartbeat", |c| &c.heartbeat)?,
            host: None,
        });
    }

    let measured = TargetCost {
        longest_iteration: most(channels, |c| &c.all),
        longest_protocol_iteration: [
            most(channels, |c| &c.plain_received),
            most(channels, |c| &c.inverted_received),
            most(channels, |c| &c.verdict),
            most(channels, |c| &c.plain_sent),
            most(channels, |c| &c.inverted_sent),
        ]
        .into_iter()
        .max()
        .unwrap_or(0),
    };

    // The load of a node with 64 SRDOs at a 10 ms refresh, its busier channel.
    let per = |name: &str, pick: fn(&Channel) -> &Vec<u64>| {
        spread(channels, name, "figure for the load", pick).map(|s| s.most)
    };
    let scale = LOAD_SRDOS / IMAGE_SRDOS;
    let mut overhead = Vec::new();
    for name in ["node1a", "node1b", "node33a", "node33b"] {
        // The digest and heartbeat are counted on node 1's channels, the same code on
        // node 33's channel of the same side.
        let side = if name.ends_with('a') {
            "node1a"
        } else {
            "node1b"
        };
        let digest = per(side, |c| &c.digest)?;
        let heartbeat = per(side, |c| &c.heartbeat)?;
        let periods = LOAD_REFRESH_MS / LINK_PERIOD_MS;
        let idle_rounds = LOAD_REFRESH_MS / SAMPLE_PERIOD_MS;
        let idle = per(name, |c| &c.idle)?;
        // The board layer's work after every round (the heartbeat's and the idle ones here;
        // the pairs' below), which the iterations' counts leave out.
        overhead.push(
            periods * (scale * digest + heartbeat.saturating_sub(digest))
                + idle_rounds * idle
                + (periods + idle_rounds) * cost::BETWEEN_ITERATIONS,
        );
    }
    // Loop rounds per pair: the consumer's plain frame, inverted frame and the other
    // channel's verdict; producer channel A's plain frame sent and its node's inverted frame
    // seen; channel B's plain frame taken and its inverted frame sent.
    let rounds = |per_pair: u64| LOAD_SRDOS * per_pair * cost::BETWEEN_ITERATIONS;
    let consumer = [
        LOAD_SRDOS * per("node33a", |c| &c.pairs)? + rounds(3) + overhead[2],
        LOAD_SRDOS * per("node33b", |c| &c.pairs)? + rounds(3) + overhead[3],
    ];
    let producer = [
        LOAD_SRDOS * (plain_sent.most + own_inverted.most) + rounds(2) + overhead[0],
        LOAD_SRDOS * inverted_sent.most + rounds(1) + overhead[1],
    ];
    let budget = cost::CLOCK_HZ / 1000 * LOAD_REFRESH_MS;
    let load = |instructions: u64, cpi: u64| instructions * cpi * 100 / budget;

    let mut md = String::new();
    let _ = writeln!(
        md,
        "## On the target: Thumb instructions under QEMU\n\n\
         Generated by `cargo xtask bench --target-cost` (`xtask/src/target_cost.rs`): the \
         emulated network of `cargo xtask run` (the QEMU images, `firmware` profile as the \
         hardware images are compiled; node 1 sends SRDO 1 every 100 ms, node 33 consumes it), \
         configured and Operational, each of the four images traced by QEMU one instruction \
         per translation block, one at a time, for at least {traced:.2} s of the network's time each (QEMU's clock counting \
         instructions, `-icount shift=2`, so that SysTick keeps the core's pace), the \
         emergency stop pressed and released once. The unit is one iteration of the channel loop \
         (`ChannelLoop::service`, from its entry to its return, callees included, in thread \
         mode: interrupt handlers are not counted); what an iteration handled is told by \
         markers of the QEMU layer (`board::qemu::marker`), whose instructions are \
         subtracted. An iteration holds the QEMU layer's driver work too (the emulated serial \
         line decoded, COBS and CRC-16, the clock read by semihosting), where the hardware \
         layer reads bxCAN's mailboxes. The x86 column is the host bench's above \
         (callgrind, the protocol core's function alone: `Node::handle_frame` of both \
         frames, `Node::poll`); the target's figures are whole loop iterations. The images \
         hold {IMAGE_SRDOS} SRDOs, one configured.\n"
    );
    let _ = writeln!(
        md,
        "| operation | image | counted | fewest | median | most | seen | x86 (host bench) |\n\
         |---|---|---|---:|---:|---:|---:|---:|"
    );
    for row in &rows {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {} | {} |",
            row.operation,
            row.image,
            row.what,
            row.spread.fewest,
            row.spread.median,
            row.spread.most,
            row.spread.seen,
            row.host.map_or("–".to_owned(), |h| h.to_string())
        );
    }
    let _ = writeln!(
        md,
        "\n**CPU load at {} MHz, a node with {LOAD_SRDOS} SRDOs at a {LOAD_REFRESH_MS} ms \
         refresh**, its busier channel, per {LOAD_REFRESH_MS} ms: {LOAD_SRDOS} times the most \
         a pair took on that channel, the configuration digest scaled to {LOAD_SRDOS} SRDOs \
         ({scale}×, one signature per record) computed once per {LINK_PERIOD_MS} ms link \
         period (for its own heartbeat, which the other channel's digest is compared with) \
         with the rest of the heartbeat, an idle iteration every {SAMPLE_PERIOD_MS} ms, and \
         after every one of these rounds the board layer's work the iterations leave out \
         ({} instructions, `safety_config::calc::target::BETWEEN_ITERATIONS`: the stack's \
         search). At one instruction per cycle (a lower bound) and at the {} cycles per \
         instruction the processing step assumes \
         (`safety_config::calc::target::CPI_BOUND`):\n",
        cost::CLOCK_HZ / 1_000_000,
        cost::BETWEEN_ITERATIONS,
        cost::CPI_BOUND
    );
    let _ = writeln!(
        md,
        "| node | instructions per {LOAD_REFRESH_MS} ms | load at 1 cycle per instruction | \
         load at {} |\n|---|---:|---:|---:|",
        cost::CPI_BOUND
    );
    for (what, instructions) in [
        (
            format!("{LOAD_SRDOS} receive SRDOs (consumer)"),
            consumer[0].max(consumer[1]),
        ),
        (
            format!("{LOAD_SRDOS} transmit SRDOs (producer)"),
            producer[0].max(producer[1]),
        ),
    ] {
        let _ = writeln!(
            md,
            "| {what} | {instructions} | {} % | {} % |",
            load(instructions, 1),
            load(instructions, cost::CPI_BOUND)
        );
    }
    let _ = writeln!(
        md,
        "\nThe per-pair figures are of this image's table ({IMAGE_SRDOS} SRDOs, one \
         configured); the parts of an iteration that walk the SRDO table (the acceptance \
         list, the output pins) grow with it and are not scaled here.\n\n\
         **Processing step** (the safety manual's response time, `safety_config::calc::target`): \
         the wake-up allowed by argument ({} instructions; the emulated loop never halted while \
         traced, the hub's time grants keep its line busy), the longest loop iteration of any \
         kind, which a frame may wait behind ({}), the board's work after it, allowed by \
         analysis of the images' code ({}: the watchdog fed, the stack's search of \
         `board::stack::WORDS_PER_STEP` words and a new mark's log line, not counted here), \
         and the longest iteration that handled \
         an SRDO frame or a verdict ({}): {}. Observed in \
         Operational with the pair flowing; iterations that handle SDO requests, NMT commands \
         or the parameter store were not traced.",
        cost::WAKE_INSTRUCTIONS,
        measured.longest_iteration,
        cost::BETWEEN_ITERATIONS,
        measured.longest_protocol_iteration,
        step_sentence(&measured)
    );
    Ok((md, measured))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A consumer's pair is the iterations of its plain frame, its inverted frame and the
    /// other channel's verdict, markers subtracted, closed by the confirmation; an idle
    /// iteration is one that received, polled and sent nothing.
    #[test]
    fn a_pair_is_its_three_iterations_and_idle_is_nothing_done() {
        let call = |instructions, nested| Call::traced(SERVICE, instructions, nested);
        let counted = Counted {
            calls: vec![
                call(50, vec![]),
                call(300, vec![(RX_PLAIN, 2), (RECEIVED, 10), (HAND, 200)]),
                call(60, vec![(CORE_POLL, 20)]),
                call(400, vec![(RX_INVERTED, 2), (RECEIVED, 10), (HAND, 250)]),
                call(250, vec![(LINK, 5), (ARRIVE, 40), (CONFIRMED, 30)]),
                call(55, vec![]),
            ],
            lines: 0,
        };
        let channel = Channel::of(counted);
        assert_eq!(channel.pairs, vec![290 + 390 + 245]);
        assert_eq!(channel.idle, vec![50, 55]);
        assert_eq!(channel.hand_plain, vec![200]);
        assert_eq!(channel.hand_inverted, vec![250]);
        assert_eq!(channel.verdict, vec![245]);
        assert_eq!(channel.all.iter().max(), Some(&390));
    }

    /// The other channel's verdict may arrive before this channel's inverted frame: the pair
    /// is then confirmed in the inverted frame's iteration, and an idle poll in between is
    /// not the pair's. A pair whose confirmation is not seen is not counted.
    #[test]
    fn a_pair_confirmed_by_its_inverted_frame_counts_the_verdict_received_before() {
        let call = |instructions, nested| Call::traced(SERVICE, instructions, nested);
        let counted = Counted {
            calls: vec![
                call(300, vec![(RX_PLAIN, 2), (RECEIVED, 10), (HAND, 200)]),
                call(250, vec![(LINK, 5), (ARRIVE, 40)]),
                call(50, vec![]),
                call(
                    400,
                    vec![
                        (RX_INVERTED, 2),
                        (RECEIVED, 10),
                        (HAND, 250),
                        (CONFIRMED, 30),
                    ],
                ),
                // A plain frame whose pair is never confirmed, then the next pair.
                call(300, vec![(RX_PLAIN, 2), (RECEIVED, 10), (HAND, 200)]),
                call(310, vec![(RX_PLAIN, 2), (RECEIVED, 10), (HAND, 200)]),
                call(400, vec![(RX_INVERTED, 2), (RECEIVED, 10), (HAND, 250)]),
                call(250, vec![(LINK, 5), (ARRIVE, 40), (CONFIRMED, 30)]),
            ],
            lines: 0,
        };
        let channel = Channel::of(counted);
        assert_eq!(channel.pairs, vec![290 + 245 + 390, 300 + 390 + 245]);
        assert_eq!(channel.idle, vec![50]);
    }

    /// The file the tool compiles is what this writer makes of the constants the tool holds.
    #[test]
    fn the_generated_constants_file_is_the_writers() {
        let text = measured_rs(
            "//! Generated by `cargo xtask bench --target-cost` (do not edit): the instructions it counted\n\
             //! on the target, which [`super::target`] turns into the processing step.\n",
            "cargo xtask bench --target-cost",
            "MEASURED",
            &cost::MEASURED,
        );
        assert_eq!(text, include_str!("../../tool/src/calc/target_measured.rs"));
    }

    /// The x86 figures come from the host bench's table.
    #[test]
    fn the_host_figure_is_read_from_its_row() {
        let doc =
            "| path | instructions |\n|---|---:|\n| idle poll, nothing due | 4 | ≤ 40 | 85 |\n";
        assert_eq!(host_figure(doc, "idle poll, nothing due"), Some(4));
        assert_eq!(host_figure(doc, "nothing"), None);
    }
}
