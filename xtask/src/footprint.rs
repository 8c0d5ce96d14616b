//! Where the bytes of a firmware image go: flash per crate, from the image's own line tables,
//! and the largest functions, from its symbol table (`cargo xtask footprint`).
//!
//! Per crate: every byte of `.text` is given to the crate whose source the line table names for
//! it. That is the innermost source location, so code inlined from `shared` into a board loop
//! counts for `shared`, not for the loop that holds it. Bytes the line table covers twice (it
//! should not) count once, for the first; bytes it does not cover (padding, veneers, a few
//! compiler-generated stubs) are listed as such. `.rodata` has no line table: it is given by
//! symbol where a symbol covers it, and the rest is listed as constants without a symbol
//! (string literals, panic locations, lookup tables).

use crate::images::{self, Layer, Sizes};
use crate::toolchain::Cross;
use anyhow::{Context, Result, bail};
use object::{Object, ObjectSection, ObjectSymbol, SymbolKind};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

/// Bytes of one image, by where they come from.
pub struct Footprint {
    /// The image's sizes (flash, RAM), as `cargo xtask build` checks them.
    pub sizes: Sizes,
    /// `.text` bytes per crate.
    pub crates: BTreeMap<String, u64>,
    /// `.text` bytes no line table row covers.
    pub uncovered: u64,
    /// The largest functions: size and demangled name without its hash.
    pub functions: Vec<(u64, String)>,
    /// `.text` bytes in `core::fmt` functions and `Debug`/`Display` implementations.
    pub formatting: u64,
    /// `.rodata` bytes.
    pub rodata: u64,
    /// `.rodata` bytes in string-like runs (16 printable bytes or more): file paths of panic
    /// locations, panic messages, names of `Debug` implementations.
    pub rodata_strings: u64,
    /// Vector table bytes.
    pub vectors: u64,
}

/// The crate a source file belongs to, from its path as the line table has it: the images'
/// paths are cut (`images::cargo` remaps them), so a crates.io source reads
/// `<name>-<version>/src/…`, the standard library `library/<crate>/…` and a workspace crate
/// `<directory>/src/…`, each behind the compilation directory; uncut paths are read too.
fn crate_of(path: &str) -> String {
    let path = path.replace('\\', "/");
    for marker in ["/registry/src/", "/git/checkouts/"] {
        if let Some((_, rest)) = path.split_once(marker) {
            // `<index>/<name>-<version>/...`
            let name = rest.split('/').nth(1).unwrap_or(rest);
            return strip_version(name).to_string();
        }
    }
    let root = crate::workspace_root();
    let relative = Path::new(&path).strip_prefix(&root).map_or_else(
        |_| path.trim_start_matches('/').to_string(),
        |relative| relative.to_string_lossy().into_owned(),
    );
    // Code a build script generated: `target/…/build/<name>-<hash>/out/…`.
    if let Some((_, rest)) = relative.split_once("/build/") {
        let directory = rest.split('/').next().unwrap_or(rest);
        return directory
            .rsplit_once('-')
            .map_or(directory, |(name, _)| name)
            .to_string();
    }
    // The standard library: `library/<crate>/…` cut, `/rustc/<hash>/library/…` uncut, and
    // `…/lib/rustlib/src/rust/library/…` where the toolchain has its `rust-src` component
    // (rustc then names the sources it has instead of the remapped ones).
    let relative = match relative.split_once("library/") {
        Some((before, rest))
            if before.is_empty()
                || before.starts_with("rustc/")
                || before.ends_with("lib/rustlib/src/rust/") =>
        {
            rest
        }
        _ => &relative,
    };
    match relative.split('/').next() {
        Some(first) if !first.is_empty() => strip_version(first).to_string(),
        _ => format!("other ({path})"),
    }
}

/// `embassy-stm32-0.6.0` → `embassy-stm32`.
fn strip_version(name: &str) -> &str {
    match name.rsplit_once('-') {
        Some((stem, version)) if version.starts_with(|c: char| c.is_ascii_digit()) => stem,
        _ => name,
    }
}

/// The debug information of an image, its sections borrowed from `file` (a section the image
/// lacks reads as empty).
pub fn dwarf_of<'a>(
    file: &object::File<'a>,
) -> Result<gimli::Dwarf<gimli::EndianSlice<'a, gimli::LittleEndian>>> {
    let load = |id: gimli::SectionId| -> Result<gimli::EndianSlice<'a, gimli::LittleEndian>> {
        let data = match file.section_by_name(id.name()) {
            Some(section) => section.data()?,
            None => &[],
        };
        Ok(gimli::EndianSlice::new(data, gimli::LittleEndian))
    };
    gimli::Dwarf::load(load)
}

/// The image's functions, size and demangled name without its hash, the largest first.
fn functions(file: &object::File<'_>) -> Vec<(u64, String)> {
    let mut functions: Vec<(u64, String)> = file
        .symbols()
        .filter(|symbol| symbol.kind() == SymbolKind::Text && symbol.size() > 0)
        .filter_map(|symbol| {
            let name = symbol.name().ok()?;
            Some((
                symbol.size(),
                format!("{:#}", rustc_demangle::demangle(name)),
            ))
        })
        .collect();
    functions.sort_by(|a, b| b.cmp(a));
    functions.dedup();
    functions
}

/// The formatting machinery (`core::fmt`, `Debug` and `Display` implementations) linked into
/// the image `elf`, by name, the largest first: none in an image that logs with defmt and
/// whose panic handler reads nothing of the panic (`board::panic`).
pub fn formatting_functions(elf: &Path) -> Result<Vec<String>> {
    let bytes = std::fs::read(elf).with_context(|| format!("reading {}", elf.display()))?;
    let file = object::File::parse(&*bytes).context("parsing the ELF image")?;
    Ok(functions(&file)
        .into_iter()
        .filter(|(_, name)| is_formatting(name))
        .map(|(_, name)| name)
        .collect())
}

/// Whether a demangled function name is formatting machinery.
fn is_formatting(name: &str) -> bool {
    name.contains("core::fmt")
        || name.contains("as core::fmt::")
        || name.contains("Debug>::fmt")
        || name.contains("Display>::fmt")
}

/// Measures one linked image (it must carry debug information: the `firmware` profile does).
pub fn measure(elf: &Path) -> Result<Footprint> {
    let bytes = std::fs::read(elf).with_context(|| format!("reading {}", elf.display()))?;
    let file = object::File::parse(&*bytes).context("parsing the ELF image")?;
    let section = |name: &str| {
        file.section_by_name(name)
            .with_context(|| format!("{}: no {name} section", elf.display()))
    };
    let text = section(".text")?;
    let rodata = section(".rodata")?;
    let vectors = section(".vector_table")?.size();
    let (start, size) = (text.address(), text.size());
    let mut owner: Vec<Option<usize>> = vec![None; usize::try_from(size)?];
    let mut names: Vec<String> = Vec::new();
    let mut index_of = |name: String| -> usize {
        match names.iter().position(|known| *known == name) {
            Some(index) => index,
            None => {
                names.push(name);
                names.len() - 1
            }
        }
    };

    let dwarf = dwarf_of(&file)?;
    let mut headers = dwarf.units();
    while let Some(header) = headers.next()? {
        let unit = dwarf.unit(header)?;
        let Some(program) = unit.line_program.clone() else {
            continue;
        };
        let comp_dir = unit
            .comp_dir
            .map(|dir| dir.to_string_lossy().into_owned())
            .unwrap_or_default();
        let mut rows = program.rows();
        let mut open: Option<(u64, usize)> = None;
        while let Some((header, row)) = rows.next_row()? {
            let address = row.address();
            if let Some((from, crate_index)) = open.take() {
                let low = from.max(start);
                let high = address.min(start + size);
                for offset in low..high.max(low) {
                    let slot = &mut owner[usize::try_from(offset - start)?];
                    slot.get_or_insert(crate_index);
                }
            }
            if row.end_sequence() {
                continue;
            }
            let Some(entry) = row.file(header) else {
                continue;
            };
            let name = dwarf.attr_string(&unit, entry.path_name())?;
            let name = name.to_string_lossy().into_owned();
            let directory = match entry.directory(header) {
                Some(directory) => dwarf
                    .attr_string(&unit, directory)?
                    .to_string_lossy()
                    .into_owned(),
                None => String::new(),
            };
            let full = if name.starts_with('/') {
                name
            } else if directory.starts_with('/') {
                format!("{directory}/{name}")
            } else {
                format!("{comp_dir}/{directory}/{name}")
            };
            open = Some((address, index_of(crate_of(&full))));
        }
    }
    let mut crates = BTreeMap::new();
    let mut uncovered = 0;
    for slot in &owner {
        match slot {
            Some(index) => *crates.entry(names[*index].clone()).or_insert(0) += 1,
            None => uncovered += 1,
        }
    }

    let functions = functions(&file);
    let formatting = functions
        .iter()
        .filter(|(_, name)| is_formatting(name))
        .map(|(size, _)| size)
        .sum();

    let data = rodata.data()?;
    let mut rodata_strings = 0;
    let mut run = 0u64;
    for &byte in data.iter().chain(std::iter::once(&0)) {
        if (0x20..0x7F).contains(&byte) {
            run += 1;
        } else {
            if run >= 16 {
                rodata_strings += run;
            }
            run = 0;
        }
    }
    Ok(Footprint {
        sizes: images::measure(elf)?,
        crates,
        uncovered,
        functions,
        formatting,
        rodata: rodata.size(),
        rodata_strings,
        vectors,
    })
}

/// The markdown tables for both images of a layer.
fn report(layer: Layer, measured: &[(&str, Footprint)], out: &mut String) -> Result<()> {
    writeln!(out, "### {layer:?} images\n")?;
    writeln!(
        out,
        "| | {} |",
        measured
            .iter()
            .map(|(name, _)| *name)
            .collect::<Vec<_>>()
            .join(" | ")
    )?;
    writeln!(out, "|---|{}", "---:|".repeat(measured.len()))?;
    let row = |out: &mut String, label: &str, value: &dyn Fn(&Footprint) -> u64| {
        let cells: Vec<String> = measured.iter().map(|(_, f)| value(f).to_string()).collect();
        writeln!(out, "| {label} | {} |", cells.join(" | "))
    };
    row(out, "flash (text + data)", &|f| f.sizes.flash())?;
    row(out, "RAM (data + bss + stack reserve)", &|f| f.sizes.ram())?;
    row(out, "vector table", &|f| f.vectors)?;
    row(out, "`.rodata`", &|f| f.rodata)?;
    row(out, "`.rodata` in strings of 16 bytes or more", &|f| {
        f.rodata_strings
    })?;
    row(out, "`.text` in `core::fmt`, `Debug` and `Display`", &|f| {
        f.formatting
    })?;
    writeln!(out)?;

    let mut all: Vec<String> = measured
        .iter()
        .flat_map(|(_, f)| f.crates.keys().cloned())
        .collect();
    all.sort();
    all.dedup();
    let total = |name: &str| -> u64 {
        measured
            .iter()
            .map(|(_, f)| f.crates.get(name).copied().unwrap_or(0))
            .sum()
    };
    all.sort_by_key(|name| std::cmp::Reverse(total(name)));
    writeln!(out, "`.text` per crate (bytes, by the line table):\n")?;
    writeln!(
        out,
        "| crate | {} |",
        measured
            .iter()
            .map(|(name, _)| *name)
            .collect::<Vec<_>>()
            .join(" | ")
    )?;
    writeln!(out, "|---|{}", "---:|".repeat(measured.len()))?;
    for name in &all {
        let cells: Vec<String> = measured
            .iter()
            .map(|(_, f)| f.crates.get(name).copied().unwrap_or(0).to_string())
            .collect();
        writeln!(out, "| {name} | {} |", cells.join(" | "))?;
    }
    row(out, "(no line table row)", &|f| f.uncovered)?;
    writeln!(out)?;

    for (name, footprint) in measured {
        writeln!(
            out,
            "Largest functions of {name} (bytes, inlined code included):\n"
        )?;
        writeln!(out, "| bytes | function |")?;
        writeln!(out, "|---:|---|")?;
        for (size, function) in footprint.functions.iter().take(15) {
            writeln!(out, "| {size} | `{}` |", function.replace('|', "\\|"))?;
        }
        writeln!(out)?;
    }
    Ok(())
}

/// What the images of layer `with` hold beyond those of layer `base` (SimpleCAN beside the
/// SRDO table): flash, RAM and the crates whose `.text` grew the most, per channel.
fn added(
    base: Layer,
    base_measured: &[(&str, Footprint)],
    with: Layer,
    with_measured: &[(&str, Footprint)],
    out: &mut String,
) -> Result<()> {
    let pairs: Vec<(&str, &Footprint, &Footprint)> = base_measured
        .iter()
        .zip(with_measured)
        .map(|((name, base), (_, with))| (*name, base, with))
        .collect();
    writeln!(
        out,
        "### What the {with:?} images add to the {base:?} images\n"
    )?;
    writeln!(
        out,
        "| | {} |\n|---|{}",
        pairs
            .iter()
            .map(|(name, _, _)| *name)
            .collect::<Vec<_>>()
            .join(" | "),
        "---:|".repeat(pairs.len())
    )?;
    let signed = |from: u64, to: u64| {
        let delta = i128::from(to) - i128::from(from);
        if delta > 0 {
            format!("+{delta}")
        } else {
            delta.to_string()
        }
    };
    let row = |out: &mut String, label: &str, value: &dyn Fn(&Footprint) -> u64| {
        let cells: Vec<String> = pairs
            .iter()
            .map(|(_, base, with)| signed(value(base), value(with)))
            .collect();
        writeln!(out, "| {label} | {} |", cells.join(" | "))
    };
    row(out, "flash (text + data)", &|f| f.sizes.flash())?;
    row(out, "RAM (data + bss + stack reserve)", &|f| f.sizes.ram())?;
    row(out, "`.rodata`", &|f| f.rodata)?;
    let mut crates: Vec<String> = pairs
        .iter()
        .flat_map(|(_, base, with)| base.crates.keys().chain(with.crates.keys()).cloned())
        .collect();
    crates.sort();
    crates.dedup();
    let grown = |name: &str| -> i128 {
        pairs
            .iter()
            .map(|(_, base, with)| {
                i128::from(with.crates.get(name).copied().unwrap_or(0))
                    - i128::from(base.crates.get(name).copied().unwrap_or(0))
            })
            .sum()
    };
    crates.sort_by_key(|name| std::cmp::Reverse(grown(name)));
    for name in crates.iter().take(8) {
        row(out, &format!("`.text` of {name}"), &|f| {
            f.crates.get(name).copied().unwrap_or(0)
        })?;
    }
    writeln!(out)?;
    Ok(())
}

/// A shipped layer, its flash budget and its images as measured (channel name, footprint).
type Shipped<'a> = (Layer, u64, &'a [(&'a str, Footprint)]);

/// The shipped images against their budgets (`images::SHIPPED`, `images::RAM_BUDGET`, of
/// which `images::STACK_RESERVE` is the stack's): what `cargo xtask build` checks, with the
/// margin each image has left.
fn budgets(shipped: &[Shipped<'_>], out: &mut String) -> Result<()> {
    writeln!(out, "### The shipped images against their budgets\n")?;
    writeln!(
        out,
        "The stack reserve, part of the RAM budget, is {} bytes (`images::STACK_RESERVE`).\n",
        images::STACK_RESERVE
    )?;
    writeln!(
        out,
        "| image | flash | flash budget | flash left | RAM with the stack reserve | RAM budget | RAM left |"
    )?;
    writeln!(out, "|---|---:|---:|---:|---:|---:|---:|")?;
    for (layer, flash_budget, measured) in shipped {
        for (name, footprint) in *measured {
            let (flash, ram) = (footprint.sizes.flash(), footprint.sizes.ram());
            let left = |budget: u64, used: u64| i128::from(budget) - i128::from(used);
            writeln!(
                out,
                "| {name} ({layer:?}) | {flash} | {flash_budget} | {} | {ram} | {} | {} |",
                left(*flash_budget, flash),
                images::RAM_BUDGET,
                left(images::RAM_BUDGET, ram)
            )?;
        }
    }
    writeln!(out)?;
    Ok(())
}

/// The commit the images were built from, abbreviated, and whether files outside `docs/`
/// differed from it; "unknown" when git cannot say.
fn source_commit(root: &Path) -> String {
    let git = |args: &[&str]| {
        std::process::Command::new("git")
            .current_dir(root)
            .args(args)
            .output()
            .ok()
            .filter(|output| output.status.success())
            .map(|output| String::from_utf8_lossy(&output.stdout).trim().to_owned())
    };
    match git(&["rev-parse", "--short=10", "HEAD"]) {
        Some(commit) => match git(&["status", "--porcelain", "--", ".", ":!docs"]) {
            Some(changes) if !changes.is_empty() => {
                format!("{commit} with changes not committed")
            }
            _ => commit,
        },
        None => "unknown".to_owned(),
    }
}

const BEGIN: &str = "<!-- cargo xtask footprint: begin -->";
const END: &str = "<!-- cargo xtask footprint: end -->";

/// Builds both layers' images, measures them and writes the tables into `docs/footprint.md`
/// between its markers (the text around them is kept).
pub fn run(root: &Path, cross: &Cross) -> Result<()> {
    let mut tables = String::new();
    let rustc = std::process::Command::new("rustc")
        .arg("--version")
        .output()
        .map(|output| String::from_utf8_lossy(&output.stdout).into_owned())
        .unwrap_or_default();
    writeln!(
        tables,
        "Measured by `cargo xtask footprint` on commit {} ({}, `firmware` profile).\n",
        source_commit(root),
        rustc.trim()
    )?;
    let mut layers = Vec::new();
    for layer in [Layer::Hw, Layer::HwSimpleCan] {
        images::build_layer(root, cross, layer)?;
        let mut measured = Vec::new();
        for (name, channel) in [("channel-a", "a"), ("channel-b", "b")] {
            measured.push((name, measure(&images::image(cross, root, layer, channel))?));
        }
        report(layer, &measured, &mut tables)?;
        layers.push((layer, measured));
    }
    let of = |wanted: Layer| {
        layers
            .iter()
            .find(|(layer, _)| *layer == wanted)
            .map(|(_, measured)| measured.as_slice())
            .unwrap_or_default()
    };
    let mut shipped = String::new();
    let with_budgets: Vec<Shipped<'_>> = images::SHIPPED
        .iter()
        .map(|&(layer, budget)| (layer, budget, of(layer)))
        .collect();
    budgets(&with_budgets, &mut shipped)?;
    tables.insert_str(tables.find("### ").unwrap_or(tables.len()), &shipped);
    added(
        Layer::Hw,
        of(Layer::Hw),
        Layer::HwSimpleCan,
        of(Layer::HwSimpleCan),
        &mut tables,
    )?;
    let path = root.join("docs/footprint.md");
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let (Some(begin), Some(end)) = (text.find(BEGIN), text.find(END)) else {
        bail!(
            "{}: no `{BEGIN}` … `{END}` markers to write between",
            path.display()
        );
    };
    let updated = format!("{}{BEGIN}\n{tables}{}", &text[..begin], &text[end..]);
    std::fs::write(&path, updated).with_context(|| format!("writing {}", path.display()))?;
    print!("{tables}");
    println!("xtask: wrote {}", path.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_registry_path_names_its_crate_without_the_version() {
        assert_eq!(
            crate_of(
                "/root/.cargo/registry/src/index.crates.io-1949cf8c6b5b557f/embassy-stm32-0.6.0/src/can/util.rs"
            ),
            "embassy-stm32"
        );
        assert_eq!(
            crate_of(
                "/root/.cargo/registry/src/index.crates.io-1949cf8c6b5b557f/cortex-m-rt-0.7.5/src/lib.rs"
            ),
            "cortex-m-rt"
        );
    }

    #[test]
    fn a_cut_path_names_its_crate() {
        let root = crate::workspace_root();
        let cut = |path: &str| crate_of(&root.join(path).to_string_lossy());
        assert_eq!(cut("embassy-stm32-0.6.0/src/can/util.rs"), "embassy-stm32");
        assert_eq!(cut("library/core/src/ptr/mod.rs"), "core");
        assert_eq!(
            cut("library/compiler-builtins/compiler-builtins/src/mem/mod.rs"),
            "compiler-builtins"
        );
        assert_eq!(cut("dual-channel/src/runtime.rs"), "dual-channel");
        assert_eq!(
            cut(
                "target/thumbv7em-none-eabihf/firmware/build/embassy-stm32-0d5f1e2a3b4c5d6e/out/_generated.rs"
            ),
            "embassy-stm32"
        );
    }

    #[test]
    fn a_standard_library_path_names_its_library() {
        assert_eq!(
            crate_of("/rustc/59807616e1ee4a59b3d5e8f2d0bd0f4a3c2a4fe5/library/core/src/fmt/mod.rs"),
            "core"
        );
        assert_eq!(
            crate_of(
                "/root/.rustup/toolchains/1.95.0-x86_64-unknown-linux-gnu/lib/rustlib/src/rust/library/core/src/ptr/mod.rs"
            ),
            "core"
        );
    }

    #[test]
    fn a_workspace_path_names_its_directory() {
        let path = crate::workspace_root().join("shared/src/node/mod.rs");
        assert_eq!(crate_of(&path.to_string_lossy()), "shared");
    }

    #[test]
    fn formatting_machinery_is_recognised_and_protocol_code_is_not() {
        assert!(is_formatting("<core::fmt::Formatter>::pad"));
        assert!(is_formatting(
            "<embassy_stm32::can::enums::TimingCalcError as core::fmt::Debug>::fmt"
        ));
        assert!(!is_formatting("shared::node::Node<F,_>::poll_due"));
        assert!(!is_formatting(
            "<shared::safety::srdo::SrdoFault as defmt::traits::Format>::_format_data"
        ));
    }
}
