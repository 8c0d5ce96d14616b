//! The firmware images: build, measure, and hold to the budgets (flash and RAM per image,
//! stacks included).

use crate::toolchain::{Cross, TARGET};
use anyhow::{Context, Result, bail};
use object::{Object, ObjectSection, SectionFlags, SectionKind};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Flash budget per image, bytes.
///
/// 58 KiB: channel A's hardware image measures 55,148 bytes and channel B's 54,892, a margin of
/// 4,244 bytes (7.1 %) for the larger (2026-12-05, `cargo xtask footprint`; 55,356 and 55,168
/// the day before, when the budget was set; on 2026-12-05 SimpleCAN's CRCs without their tables
/// moved the inlining of the CRC code these images share, +152 / +156, and the channel's
/// collector of the core's output and the hardware layer's clock reading went out of line,
/// −176 / −220 and −184 / −212, docs/footprint.md), since the panic
/// handler reads nothing of the panic (no location, no message: every panic site's location
/// record and `core::fmt` left the images, −5,796 bytes on channel B; +148 for the trail of
/// return addresses it logs instead), embassy's crates are built without their `defmt`
/// feature (−788; +128 to name the CAN bus error ourselves) and the link's messages go
/// straight into the USART's ring (−1,560). It was 64 KiB before these steps (channel B
/// 63,036 bytes): 64,376 and 64,140 before the link's messages took a fixed layout of their own
/// instead of postcard; 64,612 and 64,536 before the runtime was built where it is kept, the
/// transmit path shared by both CAN drivers and the full network's second speed round; 64,744
/// and 64,476 before the channel loop became generic over the protocol, with other changes
/// between the measurements. The SimpleCAN images (`Layer::HwSimpleCan`) have a budget of
/// their own, [`SIMPLECAN_FLASH_BUDGET`]. It was 67 KiB
/// (channel B 68,016 bytes) until the second footprint steps of `docs/footprint.md`: LLVM's
/// inlining threshold raised from opt-level `z`'s 5 to 45 (−2,492 bytes on channel B), three
/// functions inlined several times kept out of line, EXTI left out of embassy-stm32. The
/// threshold's effect is not smooth (neighbouring thresholds differ by up to 700 bytes), so a
/// change may move the image by more than its own code: re-scan before raising this. 68 KiB
/// (channel B 68,444 bytes) until the first footprint steps: identical code folded at link
/// time, the runtime built out of line and kept where it is built. Before that: 64 KiB until
/// the protection against unauthorised configuration (SC_REQ_43, `shared::node::access`,
/// +3,604 bytes on channel B) landed, since a safety requirement is not left open for a size
/// target; 72 KiB before the first footprint step (`opt-level = "z"`, no `core::fmt`
/// rendering in the panic handler, checked calls for the `unwrap`s that linked `Debug`
/// formatting, panic locations' source paths cut). The target is 48 KiB; what stands between
/// is in `docs/footprint.md`. The device has 768 KiB for code (`memory.x`).
pub const FLASH_BUDGET: u64 = 58 * 1024;
/// Flash budget of the hardware images with SimpleCAN (`Layer::HwSimpleCan`), bytes.
///
/// 64 KiB: channel A's image measures 59,172 bytes and channel B's 62,528, a margin of 3,008
/// bytes (4.6 %) for the larger (2026-12-05, `cargo xtask footprint`). These images speak
/// SimpleCAN instead of SRDOs (`board::SRDOS` = 0); with the SRDO table's code beside
/// SimpleCAN's they measured 70,768 / 74,736. 64 KiB is the budget the images were held to
/// when the second protocol was planned (the architecture step's 48 KiB target was to leave
/// it room under 64 KiB); the CANopen Safety images' [`FLASH_BUDGET`] went down to 58 KiB
/// since, as they shrank. Channel A fits that one too; channel B does not: it alone pairs
/// what it hears with what A forwards (SC_REQ_24), checks the node's packets on the bus
/// against its own (Model A, SC_REQ_10) and decodes with its own diverse code: SimpleCAN
/// costs its image 3,612 bytes more than channel A's (docs/footprint.md, where what was
/// measured on the way is). [`RAM_BUDGET`] holds for both.
pub const SIMPLECAN_FLASH_BUDGET: u64 = 64 * 1024;

/// RAM budget per image, bytes, including the stack reserve below.
///
/// 21 KiB: channel A's hardware image measures 21,148 bytes (8,860 of static data, the rest
/// the stack reserve) and channel B's 20,884, a margin of 356 bytes for the larger
/// (2026-12-02); static data does not vary at run time, so the margin is what a change may
/// add before it is looked at. It was 27 KiB with an 18 KiB stack
/// reserve until the main task's stack frame shrank (below); before that 24 KiB, raised for
/// the check of the other channel's time base (128 bytes), the transmit queue ordered by
/// identifier (`board::transmit_queue`, 192 bytes), which the fault campaign's oracle showed is
/// needed, and a deeper stack. The QEMU images hold more (`docs/footprint.md`) and are not
/// held to it.
pub const RAM_BUDGET: u64 = 21 * 1024;
/// RAM set aside for the stack in the budget. The linker places the stack at the top of RAM.
/// The figure is checked against the measured high-water mark: the stack is painted at
/// start-up (`board::stack`), every emulated channel reports its deepest use, which `cargo
/// xtask e2e` fails on when it is above this, and both layers log it.
///
/// 12 KiB. Every path of the channel runs on top of the main task's stack frame, which held
/// the runtime's construction inlined with two copies of the runtime: 10,428 bytes in the
/// QEMU image of channel B, 10,644 in the hardware one, now 1,460 and 1,828 (the runtime built
/// by an out-of-line `Runtime::new` and kept in its `Result`, `docs/footprint.md`). Measured on
/// channel B's QEMU image run alone (start-up with the parameters restored, then the link
/// time-out to the safe state): 13,676 bytes deepest before, 9,092 to 9,136 after (channel
/// A 8,528), at least 3,152 bytes (26 %) below the reserve. The whole end-to-end run measured 15,436 to 15,608 bytes before, its
/// deepest path on top of the same 10 KiB frame; `cargo xtask e2e` holds it to this reserve,
/// and measured 5,476 bytes deepest (channel B, 4,828 on A) once the runtime was built where
/// it is kept (`Runtime::around`, below).
///
/// The SimpleCAN QEMU images (`Layer::QemuSimpleCan`) are held to the same reserve by `cargo
/// xtask e2e --protocol simplecan`: 8,704 to 8,848 bytes deepest in three runs (channel B;
/// channel A 7,824 to 7,968), at least 3,440 bytes (28 %) below it (2026-12-02). They used
/// 24,868 bytes until the safety data dictionary held the layer's capacity instead of 80
/// entries (15,508 after that step alone) and the runtime was built in place: `Runtime::around`
/// and `Device::prepare` build it into the board's `Result`, the parameters restored there
/// afterwards (`Runtime::restore_parameters`), instead of `Runtime::new` returning it by value
/// with the restore under its frame (`docs/footprint.md`, the SimpleCAN variants).
/// The hardware layer runs the same channel code but its own drivers; its figure comes from
/// its log once it runs on a board (a static estimate of the hardware images' deepest call
/// chain, `docs/footprint.md`: 6,588 bytes for channel B's, 9,772 with SimpleCAN).
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
    /// QEMU's netduinoplus2.
    Qemu,
    /// QEMU's netduinoplus2 with SimpleCAN instead of SRDOs (`simplecan` of both images,
    /// `board::Protocol`): the images of `cargo xtask run --protocol simplecan`, built there
    /// and by `cargo xtask footprint`.
    QemuSimpleCan,
    /// The hardware images with SimpleCAN instead of SRDOs: built and held to their budgets
    /// ([`SIMPLECAN_FLASH_BUDGET`], [`RAM_BUDGET`]) by `cargo xtask build`, flashed by
    /// `cargo xtask flash --protocol simplecan`.
    HwSimpleCan,
    /// The hardware images with the bxCAN driven by the `bxcan` crate (`board`'s feature
    /// `can-bxcan`): checked by clippy in `cargo xtask test`, so that the driver compared in
    /// docs/can-driver.md keeps building; never shipped.
    HwBxcan,
}

impl Layer {
    /// Where this layer's images are built (apart, so neither overwrites the other).
    fn target_dir(self, cross: &Cross, root: &Path) -> PathBuf {
        match self {
            Layer::Hw => cross.target_dir(root),
            Layer::Qemu => cross.target_dir(root).join("qemu"),
            Layer::QemuSimpleCan => cross.target_dir(root).join("qemu-simplecan"),
            Layer::HwSimpleCan => cross.target_dir(root).join("hw-simplecan"),
            Layer::HwBxcan => cross.target_dir(root).join("hw-bxcan"),
        }
    }

    /// `true` for the QEMU layers.
    fn is_qemu(self) -> bool {
        matches!(self, Layer::Qemu | Layer::QemuSimpleCan)
    }
}

/// `cargo <verb>` over the board crate and both images of `layer`, for thumbv7em with the
/// `firmware` profile (release, optimised for size). The one place that knows how.
pub fn cargo(cross: &Cross, root: &Path, verb: &str, layer: Layer) -> Command {
    let features = match layer {
        Layer::Hw => "channel-a/defmt,channel-b/defmt",
        Layer::Qemu => "channel-a/qemu,channel-a/defmt,channel-b/qemu,channel-b/defmt",
        Layer::QemuSimpleCan => {
            "channel-a/qemu,channel-a/defmt,channel-a/simplecan,\
             channel-b/qemu,channel-b/defmt,channel-b/simplecan"
        }
        Layer::HwSimpleCan => {
            "channel-a/defmt,channel-a/simplecan,channel-b/defmt,channel-b/simplecan"
        }
        Layer::HwBxcan => "channel-a/defmt,channel-b/defmt,board/can-bxcan",
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
    if layer.is_qemu() {
        command = command.args(["--no-default-features"]);
    }
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
/// same behind `/root/.cargo/registry/src/index.crates.io-1949cf8c6b5b557f/` (1,120 bytes of
/// channel B's `.rodata`, `docs/footprint.md`). The names stay unambiguous: crate and version,
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
/// by anyone (the MCU reads them as erased, QEMU as 0) and not covered.
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

/// Builds both images of `layer` and seals them.
pub fn build_layer(root: &Path, cross: &Cross, layer: Layer) -> Result<()> {
    crate::run(&mut cargo(cross, root, "build", layer))?;
    for channel in ["a", "b"] {
        let elf = image(cross, root, layer, channel);
        let crc = seal(&elf)?;
        println!("xtask: channel-{channel} ({layer:?}): sealed, image CRC {crc:08X}h");
    }
    Ok(())
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
