//! The firmware images: build, measure, and hold to the budgets (issue 4: 64 KiB flash and
//! 32 KiB RAM per image, stacks included).

use crate::toolchain::{Cross, TARGET};
use anyhow::{Context, Result, bail};
use object::{Object, ObjectSection, SectionFlags, SectionKind};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Flash budget per image, bytes.
pub const FLASH_BUDGET: u64 = 64 * 1024;
/// RAM budget per image, bytes, including the stack reserve below.
pub const RAM_BUDGET: u64 = 32 * 1024;
/// RAM set aside for the stack in the budget. The linker places the stack at the top of RAM;
/// this figure is what the images are designed to need and is checked against the measured
/// high-water mark on target (stack painting) as the firmware grows.
pub const STACK_RESERVE: u64 = 8 * 1024;

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
}

impl Layer {
    /// Where this layer's images are built (apart, so neither overwrites the other).
    fn target_dir(self, cross: &Cross, root: &Path) -> PathBuf {
        match self {
            Layer::Hw => cross.target_dir(root),
            Layer::Qemu => cross.target_dir(root).join("qemu"),
        }
    }
}

/// `cargo <verb>` over the board crate and both images of `layer`, for thumbv7em with the
/// `firmware` profile (release, optimised for size). The one place that knows how.
pub fn cargo(cross: &Cross, root: &Path, verb: &str, layer: Layer) -> Command {
    let features = match layer {
        Layer::Hw => "channel-a/defmt,channel-b/defmt",
        Layer::Qemu => "channel-a/qemu,channel-a/defmt,channel-b/qemu,channel-b/defmt",
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
    if layer == Layer::Qemu {
        command = command.args(["--no-default-features"]);
    }
    for image in IMAGES {
        command = command.args(["-p", image]);
    }
    command.target_dir(layer.target_dir(cross, root)).finish()
}

/// The image of `channel` (`a` or `b`) for `layer`.
pub fn image(cross: &Cross, root: &Path, layer: Layer, channel: &str) -> PathBuf {
    layer
        .target_dir(cross, root)
        .join(TARGET)
        .join("firmware")
        .join(format!("channel-{channel}"))
}

/// Builds both hardware images, prints their sizes and fails when one exceeds a budget.
pub fn build(root: &Path, cross: &Cross) -> Result<()> {
    crate::run(&mut cargo(cross, root, "build", Layer::Hw))?;
    println!(
        "{:<10} {:>8} {:>8} {:>8} {:>16} {:>16}",
        "image", "text", "data", "bss", "flash/budget", "ram+stack/budget"
    );
    let mut over = Vec::new();
    for channel in ["a", "b"] {
        let sizes = measure(&image(cross, root, Layer::Hw, channel))?;
        let image = format!("channel-{channel}");
        println!(
            "{image:<10} {:>8} {:>8} {:>8} {:>7}/{:<8} {:>7}/{:<8}",
            sizes.text,
            sizes.data,
            sizes.bss,
            sizes.flash(),
            FLASH_BUDGET,
            sizes.ram(),
            RAM_BUDGET
        );
        if sizes.flash() > FLASH_BUDGET {
            over.push(format!("{image}: flash {} > {FLASH_BUDGET}", sizes.flash()));
        }
        if sizes.ram() > RAM_BUDGET {
            over.push(format!("{image}: RAM {} > {RAM_BUDGET}", sizes.ram()));
        }
    }
    if !over.is_empty() {
        bail!("over budget: {}", over.join("; "));
    }
    Ok(())
}
