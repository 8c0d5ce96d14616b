//! `emulate`: runs one sealed firmware image alone on the emulated STM32F405 for a span of
//! virtual time and prints its decoded defmt log, then how the run ended and how fast it went.
//! `cargo xtask emulate` builds the images and calls it.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use clap::Parser;
use emulator::cpu::{Config, Machine};
use emulator::image::{Image, Seal};
use emulator::log::LogTable;
use emulator::peripherals::gpio::Port;
use emulator::peripherals::rcc::{self, Hse};
use emulator::stop::Outcome;
use emulator::time::Nanos;

/// The command line.
#[derive(Parser)]
#[command(
    name = "emulate",
    about = "Run one sealed firmware image on the emulated STM32F405 and print its log"
)]
struct Cli {
    /// The sealed ELF image (`cargo xtask build` writes them).
    image: PathBuf,
    /// Virtual time to run for: `500ms`, `2s`, `1500us`.
    #[arg(long = "for", default_value = "1s", value_parser = emulator::time::parse_duration)]
    duration: Nanos,
    /// Make the HSE crystal fail to start (RCC_CR.HSERDY never sets).
    #[arg(long)]
    hse_fails: bool,
    /// Close the node-ID switches of this node-ID (1 to 127): PC2 (bit 0) to PC8 (bit 6)
    /// driven high, as `board::hw` wires them. Open (all low) without it.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=127))]
    node_id: Option<u8>,
    /// Close the channel's safety input contact (PC0 driven high).
    #[arg(long)]
    input_closed: bool,
    /// Load the image even when its seal does not match its flash (a copy damaged on
    /// purpose), to see the image's own start-up check refuse it.
    #[arg(long)]
    unsealed: bool,
    /// At this virtual time, make the code the core runs call `core::panicking::panic` (a
    /// defect's panic, injected; the image's own panic handler runs, which reads nothing of
    /// the panic's arguments), the next time the core is awake and outside an IT block.
    #[arg(long, value_parser = emulator::time::parse_duration)]
    panic_at: Option<Nanos>,
}

/// The function a panic calls first (`panic!` with a message, a failed `unwrap`, a bounds
/// check), as the symbol table names it.
const PANIC: &str = "core::panicking::panic";

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(&cli) {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::FAILURE,
        Err(error) => {
            eprintln!("emulate: {error}");
            ExitCode::from(2)
        }
    }
}

/// Runs the image; `Ok(false)` when the run stopped before its time.
fn run(cli: &Cli) -> Result<bool, Box<dyn std::error::Error>> {
    let seal = if cli.unsealed {
        Seal::NotChecked
    } else {
        Seal::Required
    };
    let image = Image::load_as(&cli.image, seal)?;
    println!(
        "emulate: {}: {}, CRC {:08X}h, {} bytes of flash",
        image.path.display(),
        if cli.unsealed {
            "image loaded unchecked (--unsealed), its seal holds"
        } else {
            "sealed image"
        },
        image.crc,
        image.segments.iter().map(|s| s.bytes.len()).sum::<usize>()
    );
    let table = LogTable::from_elf(&image.elf)?;
    let mut decoder = table.decoder();
    let hse = if cli.hse_fails {
        Hse::FailsToStart
    } else {
        rcc::BOARD_HSE
    };
    let mut machine = Machine::new(Config { hse })?;
    machine.load(&image)?;
    {
        let mut port_c = machine.gpio(Port::C);
        if let Some(node_id) = cli.node_id {
            for bit in 0..7 {
                port_c.drive(2 + bit, Some(node_id & (1 << bit) != 0));
            }
        }
        port_c.drive(0, Some(cli.input_closed));
    }
    let panic_target = match cli.panic_at {
        Some(_) => Some(
            image
                .symbols
                .starts_of(PANIC, true)
                .first()
                .copied()
                .ok_or_else(|| {
                    format!("{}: no function `{PANIC}` to call", image.path.display())
                })?,
        ),
        None => None,
    };
    machine.reset()?;
    let started = Instant::now();
    let slice: Nanos = 10_000_000;
    // While the injection waits for the core to wake (or to leave an IT block).
    let nudge: Nanos = 1_000;
    let end = cli.duration;
    let mut panic_at = cli.panic_at;
    let outcome = loop {
        let mut until = (machine.now() + slice).min(end);
        if let (Some(at), Some(target)) = (panic_at, panic_target) {
            if machine.now() >= at {
                match machine.inject_call(target) {
                    Some(pc) => {
                        println!(
                            "emulate: at {:.6} ms of virtual time, a call of `{PANIC}` \
                             injected in place of {}",
                            machine.now() as f64 / 1e6,
                            image.symbols.describe(pc)
                        );
                        panic_at = None;
                    }
                    None => until = (machine.now() + nudge).min(end),
                }
            } else {
                until = until.min(at);
            }
        }
        let outcome = machine.run_until(until);
        for (at, bytes) in machine.take_log() {
            for line in decoder.feed(at, &bytes) {
                println!("{line}");
            }
        }
        if outcome != Outcome::Elapsed || machine.now() >= end {
            break outcome;
        }
    };
    let host = started.elapsed().as_secs_f64();
    let virtual_seconds = machine.now() as f64 / 1e9;
    let ok = match &outcome {
        Outcome::Elapsed | Outcome::Yielded => {
            let pc = machine.register(emulator::cpu::Register::PC);
            println!(
                "emulate: ran the full {:.3} s of virtual time; at the end the core {} {}",
                virtual_seconds,
                if machine.asleep() {
                    "was asleep after"
                } else {
                    "was running"
                },
                image.symbols.describe(pc)
            );
            true
        }
        Outcome::Stopped { stop, at } => {
            println!(
                "emulate: stopped at {:.6} ms of virtual time: {stop}",
                *at as f64 / 1e6
            );
            false
        }
    };
    let (latency, prefetch, icache, dcache) = machine.flash_accelerator();
    let on = |on: bool| if on { "on" } else { "off" };
    println!(
        "emulate: FLASH_ACR at the end: {latency} wait states, prefetch {}, instruction cache {}, \
         data cache {}",
        on(prefetch),
        on(icache),
        on(dcache)
    );
    let clocks = machine.clocks();
    println!(
        "emulate: {} instructions in {:.3} s of host time: {:.3} s of virtual time per host \
         second, {:.1} million instructions per host second; core clock {} MHz at the end",
        machine.instructions(),
        host,
        virtual_seconds / host.max(1e-9),
        machine.instructions() as f64 / host.max(1e-9) / 1e6,
        clocks.hclk / 1_000_000
    );
    if decoder.malformed() > 0 {
        println!(
            "emulate: {} log frames could not be decoded",
            decoder.malformed()
        );
    }
    if machine.unpaired_usart_words() > 0 {
        println!(
            "emulate: USART3 sent {} words with no peer wired",
            machine.unpaired_usart_words()
        );
    }
    Ok(ok)
}
