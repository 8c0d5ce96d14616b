//! The firmware images: build, measure, and hold to the budgets (flash and RAM per image,
//! stacks included).

use crate::toolchain::{Cross, TARGET};
use anyhow::{Context, Result, bail};
use object::{Object, ObjectSection, SectionFlags, SectionKind};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Flash budget of the CANopen Safety hardware images ([`Layer::Hw`]), bytes.
///
/// 60 KiB: lowered from 62 KiB when the images lost embassy's executor and time driver (the
/// loop sleeps with `wfi` on the board's own time base); 62 KiB had been raised from 58 KiB
/// when both channels took on LSS (CiA 305), by less than LSS costs, since the board's own
/// drivers of the same day gave bytes back. The images' sizes
/// against it and the margin left are in the generated part of `docs/footprint.md` (`cargo
/// xtask footprint`); when and why the budget moved, each step measured, in its "History"
/// section. A budget is lowered as the images shrink and raised only for a safety
/// requirement or a function the product must have (LSS), never for a size step. The target is 48 KiB; what stands
/// between is in `docs/footprint.md`. The device has 768 KiB for code (`memory.x`).
pub const FLASH_BUDGET: u64 = 60 * 1024;
/// Flash budget of the hardware images with SimpleCAN (`Layer::HwSimpleCan`), bytes.
///
/// 66 KiB, lowered from 68 KiB with [`FLASH_BUDGET`] when the images lost embassy's executor;
/// 68 KiB had been raised from 64 KiB when both channels took on LSS (CiA 305), as
/// [`FLASH_BUDGET`] was. 64 KiB was the budget the images were held to when the second
/// protocol was planned (the architecture step's 48 KiB target was to leave it room under
/// 64 KiB). These images speak SimpleCAN
/// instead of SRDOs (`board::SRDOS` = 0). Channel B's is the larger: it alone pairs what it
/// hears with what A forwards (SC_REQ_24), checks the node's packets on the bus against its
/// own (Model A, SC_REQ_10) and decodes with its own diverse code, requirements that stay
/// whatever they cost. Sizes and margins: the generated part of `docs/footprint.md`; what was
/// measured on the way: its "History". [`RAM_BUDGET`] holds for both.
pub const SIMPLECAN_FLASH_BUDGET: u64 = 66 * 1024;

/// RAM budget per image, bytes, including the stack reserve below.
///
/// 20 KiB, lowered from 21 KiB when the images lost embassy's executor (its task, which held
/// the runtime, is now the runtime's own static slot). Static data does not vary at run time, so the margin the generated part of
/// `docs/footprint.md` gives is what a change may add before it is looked at; the budget's
/// earlier values and why they moved are in its "History".
pub const RAM_BUDGET: u64 = 20 * 1024;
/// RAM set aside for the stack in the budget. The linker places the stack at the top of RAM.
/// The figure is checked against the measured high-water mark: the stack is painted at
/// start-up (`board::stack`), the emulator measures each emulated channel's deepest use,
/// which `cargo xtask e2e` fails on when it is above this, and the board layer logs it.
///
/// 12 KiB. Every path of the channel runs on top of the frames of `main` and `board::hw::run`;
/// the runtime itself is a static of the image (`board::hw::RuntimeSlot`), built once at
/// start-up through a copy on the stack (`board::hw`'s `start`, whose frame is given back
/// before the loop runs), its parameters restored in the slot afterwards
/// (`Runtime::restore_parameters`). The shipped SimpleCAN images are held to the same reserve
/// by `cargo xtask e2e --protocol simplecan`. The deepest stack each emulated run measured is
/// in `docs/emulated-figures.md`; the steps that moved it are in `docs/footprint.md`
/// ("History").
pub const STACK_RESERVE: u64 = 12 * 1024;

/// The chip, as probe-rs names it.
pub const CHIP: &str = "STM32F405RGTx";

/// The images built by `cargo xtask build`.
pub const IMAGES: [&str; 2] = ["channel-a", "channel-b"];

/// Sizes of one image, as `size -A` would sum them.
#[derive(Debug, Clone, Copy)]
pub struct Sizes {
    /// Code and read-only data (flash).
    pub text: u64,
    /// Initialised data (flash and RAM).
    pub data: u64,
    /// Zero-initialised and uninitialised data (RAM).
    pub bss: u64,
}

impl Sizes {
    /// Flash used.
    pub fn flash(self) -> u64 {
        self.text + self.data
    }
    /// RAM used, stack reserve included.
    pub fn ram(self) -> u64 {
        self.data + self.bss + STACK_RESERVE
    }
}

/// Reads text/data/bss from an ELF file's allocated sections.
pub fn measure(elf: &Path) -> Result<Sizes> {
    let bytes = std::fs::read(elf).with_context(|| format!("reading {}", elf.display()))?;
    let file = object::File::parse(&*bytes).context("parsing the ELF image")?;
    let mut sizes = Sizes {
        text: 0,
        data: 0,
        bss: 0,
    };
    for section in file.sections() {
        let SectionFlags::Elf { sh_flags } = section.flags() else {
            continue;
        };
        const SHF_WRITE: u64 = 0x1;
        const SHF_ALLOC: u64 = 0x2;
        if sh_flags & SHF_ALLOC == 0 || section.size() == 0 {
            continue;
        }
        let writable = sh_flags & SHF_WRITE != 0;
        match section.kind() {
            SectionKind::UninitializedData | SectionKind::UninitializedTls => {
                sizes.bss += section.size();
            }
            _ if writable => sizes.data += section.size(),
            _ => sizes.text += section.size(),
        }
    }
    Ok(sizes)
}

/// The board layer an image is built for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layer {
    /// embassy-stm32 on the STM32F405RG.
    Hw,
    /// The hardware images with SimpleCAN instead of SRDOs: built and held to their budgets
    /// ([`SIMPLECAN_FLASH_BUDGET`], [`RAM_BUDGET`]) by `cargo xtask build`, flashed by
    /// `cargo xtask flash --protocol simplecan`.
    HwSimpleCan,
}

impl Layer {
    /// Where this layer's images are built (apart, so neither overwrites the other).
    fn target_dir(self, cross: &Cross, root: &Path) -> PathBuf {
        match self {
            Layer::Hw => cross.target_dir(root),
            Layer::HwSimpleCan => cross.target_dir(root).join("hw-simplecan"),
        }
    }
}

/// `cargo <verb>` over the board crate and both images of `layer`, for thumbv7em with the
/// `firmware` profile (release, optimised for size). The one place that knows how.
pub fn cargo(cross: &Cross, root: &Path, verb: &str, layer: Layer) -> Command {
    let features = match layer {
        Layer::Hw => "channel-a/defmt,channel-b/defmt",
        Layer::HwSimpleCan => {
            "channel-a/defmt,channel-a/simplecan,channel-b/defmt,channel-b/simplecan"
        }
    };
    let mut command = cross.cargo(root).args([
        verb,
        "--profile",
        "firmware",
        "--features",
        features,
        "-p",
        "board",
    ]);
    for image in IMAGES {
        command = command.args(["-p", image]);
    }
    let remap = remapped_prefixes(cross)
        .iter()
        .map(|prefix| format!("\"--remap-path-prefix={prefix}/=\""))
        .collect::<Vec<_>>()
        .join(", ");
    // Arrays given with `--config` are joined to `.cargo/config.toml`'s, not put in its place.
    let flags = format!("target.{TARGET}.rustflags=[{remap}]");
    command = command.args(["--config", &flags]);
    command.target_dir(layer.target_dir(cross, root)).finish()
}

/// The path prefixes cut from the source file names compiled into the images: each crates.io
/// index's source directory and the standard library's `/rustc/<commit>`. A panic location's
/// file name is a string in flash; cut, `embassy-stm32-0.6.0/src/can/util.rs` instead of the
/// same behind `/root/.cargo/registry/src/index.crates.io-1949cf8c6b5b557f/` (what it saved
/// of `.rodata`: `docs/footprint.md`). The names stay unambiguous: crate and version,
/// then the file. Quoted for TOML; a prefix that does not exist cuts nothing.
fn remapped_prefixes(cross: &Cross) -> Vec<String> {
    let mut prefixes = Vec::new();
    let cargo_home = std::env::var_os("CARGO_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|home| PathBuf::from(home).join(".cargo")));
    if let Some(home) = cargo_home {
        if let Ok(indexes) = std::fs::read_dir(home.join("registry/src")) {
            for index in indexes.flatten() {
                prefixes.push(index.path().display().to_string());
            }
        }
    }
    let rustc = match cross {
        Cross::Rustup => "rustc",
        Cross::Debian { .. } => "/usr/bin/rustc",
    };
    let version = Command::new(rustc).arg("-vV").output();
    let version = version.map(|output| String::from_utf8_lossy(&output.stdout).into_owned());
    if let Some(commit) = version
        .unwrap_or_default()
        .lines()
        .find_map(|line| line.strip_prefix("commit-hash: "))
    {
        prefixes.push(format!("/rustc/{}", commit.trim()));
    }
    prefixes.sort();
    prefixes
}

/// The image of `channel` (`a` or `b`) for `layer`.
pub fn image(cross: &Cross, root: &Path, layer: Layer, channel: &str) -> PathBuf {
    layer
        .target_dir(cross, root)
        .join(TARGET)
        .join("firmware")
        .join(format!("channel-{channel}"))
}

/// The first byte of flash (`memory.x`), where every image begins.
const FLASH_ORIGIN: u64 = 0x0800_0000;

/// Where an image's seal is, and what the image CRC covers: the code segment (vector table,
/// code and read-only data in one segment from the start of flash, `--no-rosegment`) and the
/// load image of `.data` (the firmware's `__erodata` and `__sidata` ranges); the seal's offset
/// in the code and in the ELF file. The few alignment bytes between the two are not written
/// by anyone (the MCU reads them as erased) and not covered.
struct Located {
    code: Vec<u8>,
    data: Vec<u8>,
    seal: usize,
    file_offset: usize,
}

fn locate(elf: &Path, bytes: &[u8]) -> Result<Located> {
    use object::read::elf::{ElfFile32, ProgramHeader as _};
    use object::{Endianness, ObjectSymbol as _};
    let file = ElfFile32::<Endianness>::parse(bytes).context("parsing the ELF image")?;
    let endian = file.endian();
    let mut segments: Vec<(u64, u64, u64)> = file
        .elf_program_headers()
        .iter()
        .filter(|header| header.p_type(endian) == object::elf::PT_LOAD)
        .filter(|header| header.p_filesz(endian) > 0)
        .map(|header| {
            (
                u64::from(header.p_paddr(endian)),
                u64::from(header.p_offset(endian)),
                u64::from(header.p_filesz(endian)),
            )
        })
        .filter(|(address, ..)| *address >= FLASH_ORIGIN)
        .collect();
    segments.sort();
    let contents = |&(_, offset, size): &(u64, u64, u64)| {
        bytes[offset as usize..(offset + size) as usize].to_vec()
    };
    let (code, data) = match segments.as_slice() {
        [code] if code.0 == FLASH_ORIGIN => (contents(code), Vec::new()),
        [code, data] if code.0 == FLASH_ORIGIN && data.0 - (code.0 + code.2) < 8 => {
            (contents(code), contents(data))
        }
        _ => bail!(
            "{}: flash segments {segments:x?} are not the code from {FLASH_ORIGIN:#x} and the \
             data right after it, which the image CRC covers (see `--no-rosegment` in \
             .cargo/config.toml)",
            elf.display()
        ),
    };
    let at = file
        .symbols()
        .find(|symbol| symbol.name() == Ok("IMAGE_SEAL"))
        .with_context(|| format!("{}: no IMAGE_SEAL symbol", elf.display()))?
        .address();
    let (address, offset, _) = segments
        .iter()
        .copied()
        .find(|(address, _, size)| (*address..address + size).contains(&at))
        .with_context(|| format!("{}: IMAGE_SEAL at {at:#x} is not in flash", elf.display()))?;
    Ok(Located {
        code,
        data,
        seal: usize::try_from(at - FLASH_ORIGIN)?,
        file_offset: usize::try_from(offset + (at - address))?,
    })
}

/// Writes the seal into a linked image: [`dual_channel::selftest::SEALED`] and the CRC-32 of
/// its flash contents, at the `IMAGE_SEAL` symbol. The image checks it at every start
/// (`board::self_test`). Returns the CRC. Idempotent: the seal's bytes are not part of it.
pub fn seal(elf: &Path) -> Result<u32> {
    use dual_channel::selftest::{SEAL_LEN, SEALED, image_crc};
    let mut bytes = std::fs::read(elf).with_context(|| format!("reading {}", elf.display()))?;
    let located = locate(elf, &bytes)?;
    let crc = image_crc(&located.code, &located.data, located.seal)
        .with_context(|| format!("{}: the seal is not inside the image", elf.display()))?;
    let mut value = [0u8; SEAL_LEN];
    value[..4].copy_from_slice(&SEALED.to_le_bytes());
    value[4..].copy_from_slice(&crc.to_le_bytes());
    bytes[located.file_offset..located.file_offset + SEAL_LEN].copy_from_slice(&value);
    std::fs::write(elf, &bytes).with_context(|| format!("writing {}", elf.display()))?;
    Ok(crc)
}

/// A copy of `elf` at `copy` with its seal's bytes changed by `change` (for the tests that an
/// unsealed or damaged image refuses to start).
pub fn tampered_copy(elf: &Path, copy: &Path, change: impl FnOnce(&mut [u8])) -> Result<()> {
    use dual_channel::selftest::SEAL_LEN;
    let mut bytes = std::fs::read(elf).with_context(|| format!("reading {}", elf.display()))?;
    let at = locate(elf, &bytes)?.file_offset;
    change(&mut bytes[at..at + SEAL_LEN]);
    std::fs::write(copy, &bytes).with_context(|| format!("writing {}", copy.display()))?;
    Ok(())
}

/// Builds both images of `layer` and seals them; their image CRCs (channels A and B).
pub fn build_layer(root: &Path, cross: &Cross, layer: Layer) -> Result<[u32; 2]> {
    crate::run(&mut cargo(cross, root, "build", layer))?;
    let mut crcs = [0; 2];
    for (crc, channel) in crcs.iter_mut().zip(["a", "b"]) {
        let elf = image(cross, root, layer, channel);
        *crc = seal(&elf)?;
        println!("xtask: channel-{channel} ({layer:?}): sealed, image CRC {crc:08X}h");
    }
    Ok(crcs)
}

/// The hardware images a user flashes (CANopen Safety, [`Layer::Hw`]; SimpleCAN,
/// [`Layer::HwSimpleCan`]) with their flash budgets.
pub const SHIPPED: [(Layer, u64); 2] = [
    (Layer::Hw, FLASH_BUDGET),
    (Layer::HwSimpleCan, SIMPLECAN_FLASH_BUDGET),
];

/// Builds the hardware images of both protocols ([`SHIPPED`]), prints their sizes and fails
/// when one exceeds its budget or links `core::fmt`.
pub fn build(root: &Path, cross: &Cross) -> Result<()> {
    for (layer, _) in SHIPPED {
        build_layer(root, cross, layer)?;
    }
    println!(
        "{:<24} {:>8} {:>8} {:>8} {:>16} {:>16}",
        "image", "text", "data", "bss", "flash/budget", "ram+stack/budget"
    );
    let mut refused = Vec::new();
    for ((layer, flash_budget), channel) in SHIPPED
        .into_iter()
        .flat_map(|shipped| [(shipped, "a"), (shipped, "b")])
    {
        let elf = image(cross, root, layer, channel);
        let sizes = measure(&elf)?;
        let image = format!("channel-{channel} ({layer:?})");
        println!(
            "{image:<24} {:>8} {:>8} {:>8} {:>7}/{:<8} {:>7}/{:<8}",
            sizes.text,
            sizes.data,
            sizes.bss,
            sizes.flash(),
            flash_budget,
            sizes.ram(),
            RAM_BUDGET
        );
        if sizes.flash() > flash_budget {
            refused.push(format!(
                "{image}: flash {} > budget {flash_budget}",
                sizes.flash()
            ));
        }
        if sizes.ram() > RAM_BUDGET {
            refused.push(format!(
                "{image}: RAM {} > budget {RAM_BUDGET}",
                sizes.ram()
            ));
        }
        let formatting = crate::footprint::formatting_functions(&elf)?;
        if !formatting.is_empty() {
            refused.push(format!(
                "{image}: links `core::fmt` ({}): the images log with defmt, and the panic \
                 handler reads nothing of the panic (docs/footprint.md); a `Debug` or \
                 `Display` in a log site or panic, or a read of the panic's message or \
                 location, brings it back",
                formatting.join(", ")
            ));
        }
    }
    if !refused.is_empty() {
        bail!("the firmware images are refused: {}", refused.join("; "));
    }
    Ok(())
}
