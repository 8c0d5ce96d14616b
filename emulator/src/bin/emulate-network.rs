//! `emulate-network`: the shipped images of two safety nodes (channels A and B of each) on
//! one emulated CAN bus in one process, each node's two channels linked by their USART3s,
//! for a span of virtual time; prints every MCU's decoded log, the frames on the bus and how
//! each MCU's run ended. `cargo xtask emulate --network` builds the images and calls it.

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
    /// Virtual time to run for: `500ms`, `2s`, `1500us`.
    #[arg(long = "for", default_value = "2s", value_parser = emulator::time::parse_duration)]
    duration: Nanos,
    /// The node-IDs of the nodes (their switches), comma-separated.
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
    /// Print no MCU log lines, only the summary.
    #[arg(long)]
    quiet: bool,
    /// Run the nominal end-to-end case instead of a fixed time: configure both nodes from
    /// this network file with the configuration tool's library, start them, check that they
    /// work, open node 1's contacts and time node 33's outputs going off
    /// (`emulator::cases::nominal`). Needs `--nodes 1,33` (the default) and closed contacts.
    #[arg(long, value_name = "NETWORK_FILE")]
    nominal: Option<PathBuf>,
    /// Keep each MCU's parameter flash (sectors 10 and 11) across runs, as a power cycle
    /// keeps it: at power-on from `DIR/<MCU>.parameters` when that file exists (else erased),
    /// at the end written back there.
    #[arg(long, value_name = "DIR")]
    parameters: Option<PathBuf>,
}

/// The parameter sectors (10 and 11, `memory.x` region PARAMETERS): address and length.
const PARAMETERS: (u32, usize) = (0x080C_0000, 2 * 128 * 1024);

/// Where `mcu`'s parameter flash is kept between runs.
fn parameters_file(dir: &std::path::Path, mcu: &str) -> PathBuf {
    dir.join(format!("{mcu}.parameters"))
}

/// `image` with `mcu`'s kept parameter flash added as a segment, when there is one.
fn with_parameters(
    image: &Image,
    dir: Option<&std::path::Path>,
    mcu: &str,
) -> Result<Image, Box<dyn std::error::Error>> {
    let mut image = image.clone();
    let Some(dir) = dir else {
        return Ok(image);
    };
    let path = parameters_file(dir, mcu);
    if path.exists() {
        let bytes = std::fs::read(&path).map_err(|error| format!("{}: {error}", path.display()))?;
        if bytes.len() != PARAMETERS.1 {
            return Err(format!(
                "{}: {} bytes, not the {} of the parameter sectors",
                path.display(),
                bytes.len(),
                PARAMETERS.1
            )
            .into());
        }
        println!(
            "emulate-network: {mcu}: parameter flash from {}",
            path.display()
        );
        image.segments.push(emulator::image::Segment {
            address: PARAMETERS.0,
            bytes,
        });
    }
    Ok(image)
}

/// Writes every MCU's parameter flash to `dir` (see `--parameters`).
fn keep_parameters(
    network: &Network,
    names: &[String],
    dir: &std::path::Path,
) -> Result<(), Box<dyn std::error::Error>> {
    std::fs::create_dir_all(dir)?;
    for (mcu, name) in names.iter().enumerate() {
        let bytes = network
            .machine(mcu)
            .read_memory(PARAMETERS.0, PARAMETERS.1)
            .ok_or("the parameter sectors cannot be read")?;
        std::fs::write(parameters_file(dir, name), bytes)?;
    }
    Ok(())
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
    for &node in &cli.nodes {
        if !(1..=127).contains(&node) {
            return Err(format!("node-ID {node} is not one of 1 to 127").into());
        }
        for (channel, image) in [("a", &image_a), ("b", &image_b)] {
            let name = format!("node{node}{channel}");
            members.push(Member {
                image: with_parameters(image, cli.parameters.as_deref(), &name)?,
                name,
                node_id: Some(node),
                input_closed: cli.inputs_closed,
                hse: rcc::BOARD_HSE,
            });
        }
    }
    let mut network = Network::new(members, cli.bit_rate)?;
    for pair in 0..cli.nodes.len() {
        network.link(2 * pair, 2 * pair + 1);
    }
    let names: Vec<String> = network.names().map(str::to_owned).collect();
    let mut decoders: Vec<_> = (0..names.len())
        .map(|mcu| tables[mcu % 2].decoder())
        .collect();
    let mut candump = match &cli.candump {
        Some(path) => Some(std::io::BufWriter::new(std::fs::File::create(path)?)),
        None => None,
    };
    let started = std::time::Instant::now();
    let mut frames = vec![0u64; names.len() + 1];
    if let Some(path) = &cli.nominal {
        let text = std::fs::read_to_string(path)
            .map_err(|error| format!("{}: {error}", path.display()))?;
        let file = safety_config::network_file::parse(&text, &path.display().to_string())?;
        let mut trace = Vec::new();
        let result =
            emulator::cases::nominal(&mut network, &file, &mut |event| trace.push(event.clone()));
        network.run_until(network.now() + 100_000_000);
        trace.extend(network.take_events());
        let mut stopped = false;
        for event in &trace {
            stopped |= print_event(event, &names, &mut frames, candump.as_mut())?;
        }
        if !cli.quiet {
            for mcu in 0..names.len() {
                for (at, bytes) in network.take_log(mcu) {
                    for line in decoders[mcu].feed(at, &bytes) {
                        println!("{:<8} {line}", names[mcu]);
                    }
                }
            }
        }
        summary(&network, &names, &frames, started);
        if let Some(dir) = &cli.parameters {
            keep_parameters(&network, &names, dir)?;
        }
        return match result {
            Ok(nominal) => {
                println!(
                    "emulate-network: nominal case passed: configured in {:.3} s of virtual                      time ({} SDO requests); node 33's outputs off {:.3} ms after node 1's                      contacts opened (bound: the refresh time, {:.0} ms)",
                    nominal.configured_in as f64 / 1e9,
                    nominal.sdo_requests,
                    nominal.reaction as f64 / 1e6,
                    nominal.bound as f64 / 1e6
                );
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
    while network.now() < cli.duration {
        network.run_until((network.now() + slice).min(cli.duration));
        for mcu in 0..names.len() {
            for (at, bytes) in network.take_log(mcu) {
                for line in decoders[mcu].feed(at, &bytes) {
                    if !cli.quiet {
                        println!("{:<8} {line}", names[mcu]);
                    }
                }
            }
        }
        for event in network.take_events() {
            stopped |= print_event(&event, &names, &mut frames, candump.as_mut())?;
        }
    }
    summary(&network, &names, &frames, started);
    if let Some(dir) = &cli.parameters {
        keep_parameters(&network, &names, dir)?;
    }
    Ok(!stopped)
}

/// Prints one event (frames go to the candump log only); whether it is an MCU's stop.
fn print_event(
    event: &Event,
    names: &[String],
    frames: &mut [u64],
    candump: Option<&mut std::io::BufWriter<std::fs::File>>,
) -> std::io::Result<bool> {
    match event {
        Event::Frame { at, from, frame } => {
            let index = names.iter().position(|n| n == from).unwrap_or(names.len());
            frames[index] += 1;
            if let Some(out) = candump {
                writeln!(
                    out,
                    "{}",
                    can_hub::trace::candump_line(at / 1_000, "vcan0", frame)
                )?;
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
        println!(
            "emulate-network: {name}: {} instructions, {} frames sent, output {}{}",
            machine.instructions(),
            frames[mcu],
            if network.output(mcu) { "on" } else { "off" },
            if network.stopped(mcu) {
                ", stopped"
            } else {
                ""
            }
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
