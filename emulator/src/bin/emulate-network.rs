//! `emulate-network`: the shipped images of two safety nodes (channels A and B of each) on
//! one emulated CAN bus in one process, each node's two channels linked by their USART3s,
//! for a span of virtual time; prints every MCU's decoded log, the frames on the bus and how
//! each MCU's run ended. `cargo xtask emulate --network` builds the images and calls it.
//! With `--socketcand ADDRESS:PORT`, separate programs join the bus over TCP
//! (`emulator::socketcand`), and the virtual time follows the host clock; with `--control
//! ADDRESS:PORT` as well, a program drives the network through the line protocol of
//! `can-hub`'s control port (`emulator::control`).

use std::io::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use emulator::image::Image;
use emulator::log::LogTable;
use emulator::network::{Event, Member, Network};
use emulator::peripherals::rcc;
use emulator::time::Nanos;

/// The command line.
#[derive(Parser)]
#[command(
    name = "emulate-network",
    about = "Run the sealed images of two nodes (channels A and B each) on one emulated CAN bus"
)]
struct Cli {
    /// Channel A's sealed image.
    image_a: PathBuf,
    /// Channel B's sealed image.
    image_b: PathBuf,
    /// Virtual time to run for: `500ms`, `2s`, `1500us` (default: 2 s; with `--socketcand`,
    /// until killed).
    #[arg(long = "for", value_parser = emulator::time::parse_duration)]
    duration: Option<Nanos>,
    /// The node-IDs of the nodes (their switches), comma-separated; 0 leaves a node's
    /// switches all open, so that LSS sets its node-ID (CiA 305; its MCUs are then named
    /// `lss1a`, `lss1b`, numbered in the order given).
    #[arg(long, value_delimiter = ',', default_values_t = [1u8, 33u8])]
    nodes: Vec<u8>,
    /// The bus's bit rate.
    #[arg(long, default_value_t = 500_000)]
    bit_rate: u32,
    /// Close every channel's safety input contact at power-on.
    #[arg(long)]
    inputs_closed: bool,
    /// Write the frames on the bus as a candump log here.
    #[arg(long)]
    candump: Option<PathBuf>,
    /// Write the frames on the bus as a pcap file here (LINKTYPE_CAN_SOCKETCAN, for
    /// Wireshark), stamped with the virtual time.
    #[arg(long)]
    pcap: Option<PathBuf>,
    /// Print no MCU log lines, only the summary.
    #[arg(long)]
    quiet: bool,
    /// Run the nominal end-to-end case instead of a fixed time: configure both nodes from
    /// this network file with the configuration tool's library, start them, check that they
    /// work, open node 1's contacts and time node 33's outputs going off
    /// (`emulator::cases::nominal`). Needs `--nodes 1,33` (the default) and closed contacts.
    #[arg(long, value_name = "NETWORK_FILE")]
    nominal: Option<PathBuf>,
    /// With `--nominal`: before the emergency stop, SDO requests to node 33 and a babbling
    /// higher-priority identifier on this share of the bus (percent) beside the SRDOs.
    #[arg(long, requires = "nominal", value_parser = clap::value_parser!(u32).range(1..=90))]
    load: Option<u32>,
    /// With `--nominal`: then the end-to-end fault cases (`emulator::e2e::faults`): the
    /// inverted frame dropped and corrupted, node 1 silent, node 1's channel B reading
    /// otherwise and node 33's link cut, each timed against its bound and followed by an NMT
    /// reset of both nodes.
    #[arg(long, requires = "nominal")]
    e2e: bool,
    /// With `--nominal`: then play these scenario files (`scenarios/emulated/*.toml`) one
    /// after the other, each after an NMT reset and start of both nodes, judged by the
    /// scenario runner's judge and the campaigns' oracle (`emulator::scenario`). Repeatable.
    #[arg(long, requires = "nominal", value_name = "SCENARIO_FILE")]
    scenario: Vec<PathBuf>,
    /// SimpleCAN's measuring run instead of a fixed time, on the SimpleCAN images: configure
    /// both nodes from this SimpleCAN network file with the configuration tool's library,
    /// start them, then profile one second of Operational on every MCU with node 1's
    /// contacts opened and closed once in it (`emulator::cases::simplecan`). Needs `--nodes
    /// 1,33` (the default) and closed contacts.
    #[arg(long, value_name = "NETWORK_FILE", conflicts_with_all = ["nominal", "power_cut_sweep"])]
    simplecan: Option<PathBuf>,
    /// With `--load`: for this long (virtual time).
    #[arg(long, default_value = "10s", value_parser = emulator::time::parse_duration)]
    load_for: Nanos,
    /// With `--nominal`: write each MCU's instructions per translated block in the
    /// Operational window into this directory (`NAME.blocks`: address and instructions per
    /// line, most first; `llvm-addr2line -f -i -e IMAGE` names their source lines), the same
    /// of the activations with a pair's work alone (`NAME.work-blocks`), and its activations
    /// (`NAME.activations`: when, instructions, loop iterations, markers).
    #[arg(long, requires = "nominal", value_name = "DIR")]
    profile_blocks: Option<PathBuf>,
    /// Hang an MCU's core (no instruction, no interrupt; its watchdog runs on), as
    /// `NAME@AT/FOR`: `node33a@1200ms/300ms`. Repeatable.
    #[arg(long, value_parser = parse_hang)]
    hang: Vec<(String, Nanos, Nanos)>,
    /// Destroy an MCU's next transmissions with bit errors from a time on, as
    /// `NAME@AT/COUNT`: `node1a@1s/40` (32 make it bus-off). Repeatable.
    #[arg(long, value_parser = parse_bit_errors)]
    bit_errors: Vec<(String, Nanos, u32)>,
    /// Sweep power cuts over node 1's store instead of a fixed time: configure node 1 from
    /// this network file once without a cut, then again with its power cut at each flash
    /// program or erase step of channel A's store and then channel B's, and check that each
    /// channel keeps the old or the new parameters and that the node starts again
    /// (`emulator::cases::power_cut`).
    #[arg(long, value_name = "NETWORK_FILE")]
    power_cut_sweep: Option<PathBuf>,
    /// Serve the socketcand protocol on this TCP address (`127.0.0.1:29536`), bus `can0`, so
    /// that separate programs join the network: python-can (`interface="socketcand"`),
    /// python-canopen through it, the configuration tool (`--bus
    /// socketcand:127.0.0.1:29536/can0`). The virtual time then follows the host clock (never
    /// ahead of it), since such programs time out on the wall clock
    /// (`emulator::socketcand`).
    #[arg(long, value_name = "ADDRESS:PORT", conflicts_with_all = ["nominal", "power_cut_sweep", "simplecan"])]
    socketcand: Option<String>,
    /// With `--socketcand`: serve the control port on this TCP address (`127.0.0.1:29537`),
    /// the line protocol of `can-hub`'s (`emulator::control`): a channel's contact, the bus
    /// faults, a node's link cut and restored; every channel's status as the network shows
    /// it, and how the pacing goes, written to every client. The program then ends when an
    /// MCU stops (a fault, a lockup), so that the program driving it learns it.
    #[arg(long, value_name = "ADDRESS:PORT", requires = "socketcand")]
    control: Option<String>,
    /// With `--power-cut-sweep`: cut at every Nth step only (the first and the last steps
    /// always).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    every: u64,
}

/// A fault scheduled from the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Fault {
    /// `--hang`: for this long.
    Hang(Nanos),
    /// `--bit-errors`: this many transmissions.
    BitErrors(u32),
}

/// `NAME@AT/COUNT` of `--bit-errors`.
fn parse_bit_errors(text: &str) -> Result<(String, Nanos, u32), String> {
    let usage = || format!("`{text}`: give NAME@AT/COUNT, e.g. node1a@1s/40");
    let (name, rest) = text.split_once('@').ok_or_else(usage)?;
    let (at, count) = rest.split_once('/').ok_or_else(usage)?;
    Ok((
        name.to_owned(),
        emulator::time::parse_duration(at)?,
        count.parse().map_err(|_| usage())?,
    ))
}

/// `NAME@AT/FOR` of `--hang`.
fn parse_hang(text: &str) -> Result<(String, Nanos, Nanos), String> {
    let (name, times) = text
        .split_once('@')
        .ok_or_else(|| format!("`{text}`: give NAME@AT/FOR, e.g. node33a@1200ms/300ms"))?;
    let (at, duration) = times
        .split_once('/')
        .ok_or_else(|| format!("`{text}`: give NAME@AT/FOR, e.g. node33a@1200ms/300ms"))?;
    Ok((
        name.to_owned(),
        emulator::time::parse_duration(at)?,
        emulator::time::parse_duration(duration)?,
    ))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(&cli) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::FAILURE,
        Err(error) => {
            eprintln!("emulate-network: {error}");
            ExitCode::from(2)
        }
    }
}

/// Runs the network; `Ok(false)` when an MCU stopped before the end.
fn run(cli: &Cli) -> Result<bool, Box<dyn std::error::Error>> {
    let image_a = Image::load(&cli.image_a)?;
    let image_b = Image::load(&cli.image_b)?;
    for image in [&image_a, &image_b] {
        println!(
            "emulate-network: {}: sealed image, CRC {:08X}h",
            image.path.display(),
            image.crc
        );
    }
    let tables = [
        LogTable::from_elf(&image_a.elf)?,
        LogTable::from_elf(&image_b.elf)?,
    ];
    let mut members = Vec::new();
    let mut unconfigured = 0;
    for &node in &cli.nodes {
        if node > 127 {
            return Err(format!(
                "node-ID {node} is not one of 1 to 127 (or 0: switches open, LSS)"
            )
            .into());
        }
        let (name, switches) = if node == 0 {
            unconfigured += 1;
            (format!("lss{unconfigured}"), None)
        } else {
            (format!("node{node}"), Some(node))
        };
        for (channel, image) in [("a", &image_a), ("b", &image_b)] {
            members.push(Member {
                name: format!("{name}{channel}"),
                image: image.clone(),
                node_id: switches,
                input_closed: cli.inputs_closed,
                hse: rcc::BOARD_HSE,
            });
        }
    }
    let build = || -> Result<Network, String> {
        let members = members
            .iter()
            .map(|member| Member {
                name: member.name.clone(),
                image: member.image.clone(),
                node_id: member.node_id,
                input_closed: member.input_closed,
                hse: member.hse,
            })
            .collect();
        let mut network = Network::new(members, cli.bit_rate).map_err(|e| e.to_string())?;
        for pair in 0..cli.nodes.len() {
            network.link(2 * pair, 2 * pair + 1);
        }
        Ok(network)
    };
    if let Some(path) = &cli.power_cut_sweep {
        return sweep(&build, path, cli.every);
    }
    let mut network = build()?;
    let names: Vec<String> = network.names().map(str::to_owned).collect();
    let mut decoders: Vec<_> = (0..names.len())
        .map(|mcu| tables[mcu % 2].decoder())
        .collect();
    let create = |path: &PathBuf| {
        std::fs::File::create(path)
            .map(std::io::BufWriter::new)
            .map_err(|error| format!("cannot create {}: {error}", path.display()))
    };
    let mut traces = Traces {
        candump: cli.candump.as_ref().map(create).transpose()?,
        pcap: match &cli.pcap {
            Some(path) => Some(can_hub::trace::PcapWriter::new(create(path)?)?),
            None => None,
        },
    };
    let candump = &mut traces;
    let started = std::time::Instant::now();
    let mut frames = vec![0u64; names.len() + 1];
    if let Some(path) = &cli.simplecan {
        let text = std::fs::read_to_string(path)
            .map_err(|error| format!("{}: {error}", path.display()))?;
        let file = safety_config::network_file::parse(&text, &path.display().to_string())?;
        let mut trace = Vec::new();
        let result =
            emulator::cases::simplecan(&mut network, &file, &mut |event| trace.push(event.clone()));
        trace.extend(network.take_events());
        let stopped = print_run(
            &mut network,
            &trace,
            &names,
            &mut frames,
            candump,
            (!cli.quiet).then_some(&mut decoders),
        )?;
        summary(&network, &names, &frames, started);
        return match result {
            Ok(run) => {
                println!(
                    "emulate-network: SimpleCAN's measuring run passed: configured in {:.3} s \
                     of virtual time ({} SDO requests); node 33's outputs off {:.3} ms after \
                     node 1's contacts opened, on again {:.3} ms after they closed ({} data \
                     packets of SC-ID {:02X}h in the Operational window)",
                    run.configured_in as f64 / 1e9,
                    run.sdo_requests,
                    run.reaction as f64 / 1e6,
                    run.restored as f64 / 1e6,
                    run.operational.first().map_or(0, |window| window.pairs),
                    run.sc_id
                );
                print_figures(&run.profiled(), &names);
                Ok(!stopped)
            }
            Err(why) => {
                println!("emulate-network: SimpleCAN's measuring run failed: {why}");
                Ok(false)
            }
        };
    }
    if let Some(path) = &cli.nominal {
        let text = std::fs::read_to_string(path)
            .map_err(|error| format!("{}: {error}", path.display()))?;
        let file = safety_config::network_file::parse(&text, &path.display().to_string())?;
        let mut trace = Vec::new();
        let load = cli.load.map(|percent| emulator::cases::LoadSpec {
            percent,
            duration: cli.load_for,
        });
        let mut scenarios = Vec::new();
        for path in &cli.scenario {
            scenarios.push(
                system_tests::scenario_runner::file::load(path)
                    .map_err(|error| format!("{}: {error}", path.display()))?,
            );
        }
        let mut keep = |event: &emulator::network::Event| trace.push(event.clone());
        let result =
            emulator::cases::nominal(&mut network, &file, load, &mut keep).and_then(|nominal| {
                match cli.e2e {
                    true => emulator::e2e::faults(&mut network, &file, &mut keep)
                        .map(|faults| (nominal, faults)),
                    false => Ok((nominal, Vec::new())),
                }
            });
        let result = result.and_then(|outcome| {
            if scenarios.is_empty() {
                return Ok(outcome);
            }
            match emulator::scenario::play_all(&mut network, &scenarios, &mut keep)? {
                true => Ok(outcome),
                false => Err("a scenario failed (its report above)".to_string()),
            }
        });
        network.run_until(network.now() + 100_000_000);
        trace.extend(network.take_events());
        let stopped = print_run(
            &mut network,
            &trace,
            &names,
            &mut frames,
            candump,
            (!cli.quiet).then_some(&mut decoders),
        )?;
        summary(&network, &names, &frames, started);
        return match result {
            Ok((nominal, faults)) => {
                for case in &faults {
                    let causes: Vec<String> = case
                        .causes
                        .iter()
                        .map(|(node, cause)| format!("node {node}: {cause}"))
                        .collect();
                    println!(
                        "emulate-network: fault case: {}: {:.3} ms (bound {:.3} ms); EMCY: {}",
                        case.case,
                        case.reaction as f64 / 1e6,
                        case.bound as f64 / 1e6,
                        causes.join("; ")
                    );
                }
                if cli.e2e {
                    println!(
                        "emulate-network: {} fault cases passed, each within its bound",
                        faults.len()
                    );
                }
                println!(
                    "emulate-network: nominal case passed: configured in {:.3} s of virtual \
                     time ({} SDO requests); node 33's outputs off {:.3} ms after node 1's \
                     contacts opened (bound: the refresh time, {:.0} ms)",
                    nominal.configured_in as f64 / 1e9,
                    nominal.sdo_requests,
                    nominal.reaction as f64 / 1e6,
                    nominal.bound as f64 / 1e6
                );
                if let Some(load) = &nominal.load {
                    let percentile = |p: f64| {
                        load.gaps
                            .get(((load.gaps.len() as f64 - 1.0) * p).round() as usize)
                            .map_or(0.0, |&gap| gap as f64 / 1e6)
                    };
                    println!(
                        "emulate-network: under load: {:.1} % of the bus beside the SRDOs, {} \
                         of {} SDO requests answered, no fault; {} pairs, plain-to-inverted \
                         gap median {:.3} ms, 99 % within {:.3} ms, longest {:.3} ms",
                        load.share * 100.0,
                        load.sdo_answers,
                        load.sdo_requests,
                        load.gaps.len(),
                        percentile(0.5),
                        percentile(0.99),
                        percentile(1.0)
                    );
                }
                for cost in &nominal.costs {
                    println!(
                        "emulate-network: cost {{\"mcu\": \"{}\", \
                         \"pre_operational\": {{\"instructions\": {}, \"iterations\": {}, \
                         \"per_iteration\": {:.0}}}, \
                         \"operational\": {{\"instructions\": {}, \"iterations\": {}, \
                         \"per_iteration\": {:.0}, \"pairs\": {}}}, \
                         \"per_pair_above_pre_operational\": {:.0}, \"window_s\": 1.0}}",
                        cost.name,
                        cost.idle_instructions,
                        cost.idle_wake_ups,
                        cost.per_idle_iteration(),
                        cost.operational_instructions,
                        cost.operational_wake_ups,
                        cost.operational_instructions as f64
                            / cost.operational_wake_ups.max(1) as f64,
                        cost.pairs,
                        cost.per_pair()
                    );
                }
                if let Some(dir) = &cli.profile_blocks {
                    std::fs::create_dir_all(dir)?;
                    for (name, window) in names.iter().zip(&nominal.operational) {
                        let mut text = String::new();
                        for (address, instructions) in &window.blocks {
                            text.push_str(&format!("{address:#010x} {instructions}\n"));
                        }
                        std::fs::write(dir.join(format!("{name}.blocks")), text)?;
                        let mut text = String::new();
                        for (address, instructions) in &window.work_blocks {
                            text.push_str(&format!("{address:#010x} {instructions}\n"));
                        }
                        std::fs::write(dir.join(format!("{name}.work-blocks")), text)?;
                        let mut text = String::new();
                        for activation in &window.activations {
                            text.push_str(&format!(
                                "{:.6} ms {} instructions {} iterations {}\n",
                                activation.at as f64 / 1e6,
                                activation.instructions,
                                activation.iterations,
                                activation.describe()
                            ));
                        }
                        std::fs::write(dir.join(format!("{name}.activations")), text)?;
                    }
                }
                print_figures(&nominal.profiled(), &names);
                Ok(!stopped && nominal.reaction <= nominal.bound)
            }
            Err(why) => {
                println!("emulate-network: nominal case failed: {why}");
                Ok(false)
            }
        };
    }
    let slice: Nanos = 10_000_000;
    let mut stopped = false;
    let mut hangs = Vec::new();
    let find = |option: &str, name: &str| {
        names
            .iter()
            .position(|n| n == name)
            .ok_or_else(|| format!("--{option} {name}: no MCU of that name (one of {names:?})"))
    };
    for (name, at, duration) in &cli.hang {
        hangs.push((*at, find("hang", name)?, Fault::Hang(*duration)));
    }
    for (name, at, count) in &cli.bit_errors {
        hangs.push((*at, find("bit-errors", name)?, Fault::BitErrors(*count)));
    }
    hangs.sort();
    let mut hangs = hangs.into_iter().peekable();
    let mut server = match &cli.socketcand {
        Some(address) => {
            let server = emulator::socketcand::Server::listen(address, &network)?;
            println!(
                "emulate-network: socketcand clients join on {address}, bus {}; the virtual time \
                 follows the host clock",
                emulator::socketcand::BUS
            );
            Some(server)
        }
        None => None,
    };
    let mut control = match &cli.control {
        Some(address) => {
            let port = emulator::control::Server::listen(address)?;
            let panel = emulator::control::Panel::new(&mut network, cli.inputs_closed);
            println!("emulate-network: control clients join on {address}");
            Some((port, panel))
        }
        None => None,
    };
    // With a control port, the network runs in short slices so that its commands take effect
    // and its status lines go out promptly.
    let slice = if control.is_some() { 1_000_000 } else { slice };
    let mut next_pace_line: Nanos = 0;
    let duration = match (cli.duration, &server) {
        (Some(duration), _) => duration,
        (None, Some(_)) => Nanos::MAX,
        (None, None) => 2_000_000_000,
    };
    // With a socket, how the pacing went, every so often and when clients come and go.
    let report_every: Nanos = 5_000_000_000;
    let mut next_report = report_every;
    while network.now() < duration {
        let mut until = (network.now() + slice).min(duration);
        if let Some(&(at, _, _)) = hangs.peek() {
            until = until.min(at.max(network.now() + 1));
        }
        match server.as_mut() {
            Some(server) => {
                server.run_until(&mut network, until);
                let notes = server.take_notes();
                for note in &notes {
                    println!("emulate-network: socketcand: {note}");
                }
                if network.now() >= next_report || !notes.is_empty() {
                    next_report = network.now() + report_every;
                    pace(server);
                }
            }
            None => network.run_until(until),
        }
        while let Some(&(at, mcu, fault)) = hangs.peek() {
            if at > network.now() {
                break;
            }
            let now = network.now() as f64 / 1e6;
            match fault {
                Fault::Hang(duration) => {
                    println!(
                        "{:<8} {now:>12.6} ms hung for {:.3} ms",
                        names[mcu],
                        duration as f64 / 1e6
                    );
                    network.hang(mcu, duration);
                }
                Fault::BitErrors(count) => {
                    println!(
                        "{:<8} {now:>12.6} ms its next {count} transmissions destroyed by bit \
                         errors",
                        names[mcu]
                    );
                    network.inject_bit_errors(mcu, count);
                }
            }
            hangs.next();
        }
        for mcu in 0..names.len() {
            for (at, bytes) in network.take_log(mcu) {
                for line in decoders[mcu].feed(at, &bytes) {
                    if let Some((_, panel)) = control.as_mut() {
                        panel.log(mcu, &line.message);
                    }
                    if !cli.quiet {
                        println!("{:<8} {line}", names[mcu]);
                    }
                }
            }
        }
        for event in network.take_events() {
            if let Some((_, panel)) = control.as_mut() {
                panel.event(&event);
            }
            stopped |= print_event(&event, &names, &mut frames, candump)?;
        }
        if control.is_some() {
            // Killed at the end of a run driven over the control port: the traces so far are
            // on disk.
            candump.flush()?;
            if stopped {
                // A program driving the network learns it from the end of this process; why
                // is printed above.
                summary(&network, &names, &frames, started);
                return Ok(false);
            }
        }
        if let Some((port, panel)) = control.as_mut() {
            port.serve(panel, &mut network);
            panel.measure(&network);
            for line in panel.reports(network.now()) {
                port.write(None, &line);
            }
            if let Some(server) = &server
                && network.now() >= next_pace_line
            {
                next_pace_line = network.now() + 1_000_000_000;
                port.write(None, &can_hub::control::pace_line(&server.pace_report()));
            }
        }
    }
    summary(&network, &names, &frames, started);
    if let Some(server) = &server {
        pace(server);
    }
    Ok(!stopped)
}

/// Prints the profiles' Markdown (`figures` lines) and JSON (the `figures-json` line), which
/// `cargo xtask` writes into the figures' pages.
fn print_figures(profiled: &emulator::figures::Profiled<'_>, names: &[String]) {
    for line in emulator::figures::markdown(profiled, names) {
        println!("emulate-network: figures {line}");
    }
    println!(
        "emulate-network: figures-json {}",
        emulator::figures::json(profiled, names)
    );
}

/// How the pacing to the host clock went, with the clients served so far.
fn pace(server: &emulator::socketcand::Server) {
    let report = server.pace_report();
    let ms = |d: shared::Duration| d.as_micros() as f64 / 1000.0;
    println!(
        "emulate-network: socketcand: {} clients so far; paced for {:.3} s of virtual time, {:.1} ms behind \
         the host clock, held at most {:.1} ms at a time because the emulation fell behind",
        server.clients_joined(),
        report.virtual_time.as_micros() as f64 / 1e6,
        ms(report.behind),
        ms(report.longest_hold)
    );
}

/// The traces of the frames on the bus.
struct Traces {
    candump: Option<std::io::BufWriter<std::fs::File>>,
    pcap: Option<can_hub::trace::PcapWriter<std::io::BufWriter<std::fs::File>>>,
}

impl Traces {
    /// Writes what is buffered.
    fn flush(&mut self) -> std::io::Result<()> {
        if let Some(out) = &mut self.candump {
            out.flush()?;
        }
        if let Some(pcap) = &mut self.pcap {
            pcap.flush()?;
        }
        Ok(())
    }
}

/// Prints a case's events (`trace`, frames to the traces only) and, with `decoders`, every
/// MCU's decoded log so far; whether an MCU stopped.
fn print_run(
    network: &mut Network,
    trace: &[Event],
    names: &[String],
    frames: &mut [u64],
    traces: &mut Traces,
    decoders: Option<&mut Vec<emulator::log::LogDecoder<'_>>>,
) -> std::io::Result<bool> {
    let mut stopped = false;
    for event in trace {
        stopped |= print_event(event, names, frames, traces)?;
    }
    if let Some(decoders) = decoders {
        for (mcu, decoder) in decoders.iter_mut().enumerate() {
            for (at, bytes) in network.take_log(mcu) {
                for line in decoder.feed(at, &bytes) {
                    println!("{:<8} {line}", names[mcu]);
                }
            }
        }
    }
    Ok(stopped)
}

/// Prints one event (frames go to the traces only); whether it is an MCU's stop.
fn print_event(
    event: &Event,
    names: &[String],
    frames: &mut [u64],
    traces: &mut Traces,
) -> std::io::Result<bool> {
    match event {
        Event::Frame { at, from, frame } => {
            let index = names.iter().position(|n| n == from).unwrap_or(names.len());
            frames[index] += 1;
            if let Some(out) = &mut traces.candump {
                writeln!(
                    out,
                    "{}",
                    can_hub::trace::candump_line(at / 1_000, "vcan0", frame)
                )?;
            }
            if let Some(pcap) = &mut traces.pcap {
                pcap.write(at / 1_000, frame)?;
            }
        }
        Event::Output { at, mcu, on } => println!(
            "{:<8} {:>12.6} ms output {}",
            names[*mcu],
            *at as f64 / 1e6,
            if *on { "on" } else { "off" }
        ),
        Event::Stopped { mcu, stop, at } => {
            println!(
                "{:<8} stopped at {:.6} ms of virtual time: {stop}",
                names[*mcu],
                *at as f64 / 1e6
            );
            return Ok(true);
        }
        Event::Reset { mcu, stop, at } => println!(
            "{:<8} {:>12.6} ms reset, starting again: {stop}",
            names[*mcu],
            *at as f64 / 1e6
        ),
        Event::BitRate { at, bit_rate } => println!(
            "{:<8} {:>12.6} ms the bus runs at {bit_rate} bit/s: the LSS master activated it \
             (CiA 305)",
            "bus",
            *at as f64 / 1e6
        ),
        Event::Refused { mcu, at, frame } => println!(
            "{:<8} {:>12.6} ms sent {frame:?}, which the bus model cannot carry (an extended \
             identifier): ended with a form error",
            names[*mcu],
            *at as f64 / 1e6
        ),
    }
    Ok(false)
}

/// Each MCU's instructions, frames and output, and the emulation's speed.
fn summary(network: &Network, names: &[String], frames: &[u64], started: std::time::Instant) {
    let host = started.elapsed().as_secs_f64();
    let virtual_seconds = network.now() as f64 / 1e9;
    for (mcu, name) in names.iter().enumerate() {
        let machine = network.machine(mcu);
        let stack = machine.deepest_stack().map_or(String::new(), |bytes| {
            format!(", deepest stack {bytes} bytes")
        });
        println!(
            "emulate-network: {name}: {} instructions, {} frames sent, output {}{}; seen from \
             outside (virtual time): longest wake-up {:.3} ms, longest link gap {:.3} ms{stack}",
            machine.instructions(),
            frames[mcu],
            if network.output(mcu) { "on" } else { "off" },
            if network.stopped(mcu) {
                ", stopped"
            } else {
                ""
            },
            machine.longest_activation() as f64 / 1e6,
            network.longest_link_gap(mcu) as f64 / 1e6,
        );
    }
    println!(
        "emulate-network: {:.3} s of virtual time in {:.3} s of host time: {:.3} s of virtual \
         time per host second for {} MCUs",
        virtual_seconds,
        host,
        virtual_seconds / host.max(1e-9),
        names.len()
    );
}

/// `--power-cut-sweep`: the reference store, then a power cut at each step; `Ok(false)` when a
/// step broke the rule.
fn sweep(
    build: &dyn Fn() -> Result<Network, String>,
    path: &std::path::Path,
    every: u64,
) -> Result<bool, Box<dyn std::error::Error>> {
    let started = std::time::Instant::now();
    let text =
        std::fs::read_to_string(path).map_err(|error| format!("{}: {error}", path.display()))?;
    let file = safety_config::network_file::parse(&text, &path.display().to_string())?;
    let reference = emulator::cases::reference(build, &file)?;
    println!(
        "emulate-network: node 1's store without a cut: {} and {} flash operations on channels \
         A and B; {} bytes of parameters",
        reference.operations[0],
        reference.operations[1],
        reference.new[0].as_ref().map_or(0, Vec::len)
    );
    let mut failures = 0;
    for (channel, name) in ["A", "B"].iter().enumerate() {
        let last = reference.operations[channel];
        let steps: Vec<u64> = (0..=last)
            .filter(|step| step % every == 0 || *step + 1 >= last)
            .collect();
        let (mut kept_old, mut kept_new, mut mixed_channels, mut cuts) = (0, 0, 0, 0);
        for &step in &steps {
            match emulator::cases::power_cut(build, &file, &reference, channel, step, step) {
                Ok(Some(cut)) => {
                    cuts += 1;
                    if cut.new[channel] {
                        kept_new += 1;
                    } else {
                        kept_old += 1;
                    }
                    if cut.new[0] != cut.new[1] {
                        mixed_channels += 1;
                    }
                }
                Ok(None) => {}
                Err(why) => {
                    failures += 1;
                    println!("emulate-network: channel {name}, cut at step {step}: {why}");
                }
            }
        }
        println!(
            "emulate-network: channel {name}: power cut at {cuts} of its {last} store steps: \
             old parameters kept {kept_old} times, new {kept_new} times, the two channels then \
             held different records {mixed_channels} times{}",
            if failures == 0 {
                "; the node started again every time"
            } else {
                ""
            }
        );
    }
    println!(
        "emulate-network: power-cut sweep {} in {:.1} s of host time",
        if failures == 0 { "passed" } else { "FAILED" },
        started.elapsed().as_secs_f64()
    );
    Ok(failures == 0)
}
