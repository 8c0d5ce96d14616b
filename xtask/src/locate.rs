//! Where an address of a firmware image is in the source: `cargo xtask where`, and the check
//! that a panic on the emulated STM32F405 logs return addresses that lead back to the panic.
//!
//! The panic handler (`board::panic`) logs the return addresses of the calls that led to it
//! instead of the panic's location (which would keep every panic site's location and
//! `core::fmt` in flash). A return address is the instruction after a call, so each is looked
//! up one byte earlier, inside the call; the image's debug information then names the
//! function, and every function inlined at that point, with file and line.

use anyhow::{Context, Result, bail};
use std::fmt;
use std::path::Path;

/// One function at an address: the innermost inlined call first, then the functions it was
/// inlined into.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    /// The function's name, demangled, without its hash.
    pub function: String,
    /// The source file, as the debug information has it.
    pub file: String,
    /// The line, 0 when unknown.
    pub line: u32,
}

impl fmt::Display for Frame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} at {}:{}", self.function, self.file, self.line)
    }
}

/// The frames at each of `return_addresses` in the image `elf`, in the same order; an address
/// the image has no code for gets none.
pub fn return_addresses(elf: &Path, return_addresses: &[u64]) -> Result<Vec<Vec<Frame>>> {
    let bytes = std::fs::read(elf).with_context(|| format!("reading {}", elf.display()))?;
    let file = object::File::parse(&*bytes)
        .with_context(|| format!("{}: not an ELF image", elf.display()))?;
    let dwarf = crate::footprint::dwarf_of(&file)?;
    let context = addr2line::Context::from_dwarf(dwarf)
        .with_context(|| format!("{}: reading its debug information", elf.display()))?;
    return_addresses
        .iter()
        .map(|&address| {
            let mut frames = Vec::new();
            // Inside the call: a return address is the instruction after it.
            let mut found = context
                .find_frames(address.saturating_sub(1))
                .skip_all_loads()
                .with_context(|| format!("{address:#010x}: reading its frames"))?;
            while let Some(frame) = found.next()? {
                let function = match &frame.function {
                    Some(name) => {
                        let raw = name.raw_name()?;
                        format!("{:#}", rustc_demangle::demangle(&raw))
                    }
                    None => "?".to_owned(),
                };
                let (file, line) = frame.location.as_ref().map_or(("?", 0), |location| {
                    (location.file.unwrap_or("?"), location.line.unwrap_or(0))
                });
                frames.push(Frame {
                    function,
                    file: file.to_owned(),
                    line,
                });
            }
            Ok(frames)
        })
        .collect()
}

/// The addresses of a panic's log line (`panicked; return addresses [0x08001234, …]`), `None`
/// when `log` has no such line.
pub fn panic_addresses(log: &str) -> Option<Vec<u64>> {
    let line = log.lines().find(|line| line.contains("return addresses"))?;
    let (_, list) = line.split_once("return addresses")?;
    let list = list.split_once('[')?.1.split_once(']')?.0;
    list.split(',')
        .map(|item| parse_address(item.trim()).ok())
        .collect()
}

/// An address as the user writes it: hexadecimal with or without `0x`.
pub fn parse_address(text: &str) -> Result<u64> {
    let digits = text
        .strip_prefix("0x")
        .or_else(|| text.strip_prefix("0X"))
        .unwrap_or(text);
    if digits.is_empty() || digits.len() > 8 {
        bail!("`{text}` is not an address of the image: expected up to 8 hexadecimal digits");
    }
    u64::from_str_radix(digits, 16)
        .with_context(|| format!("`{text}` is not an address of the image: not hexadecimal"))
}

/// `cargo xtask where`: prints each address and the frames the image has at it, source files
/// relative to the workspace `root` (the images' own and, with the registry's prefix cut by
/// `cargo xtask build`, the crates': `embassy-stm32-0.6.0/src/…`).
pub fn task(root: &Path, elf: &Path, addresses: &[String]) -> Result<()> {
    let parsed = addresses
        .iter()
        .map(|text| parse_address(text))
        .collect::<Result<Vec<_>>>()?;
    if !elf.exists() {
        bail!(
            "{}: no such image; build it first (`cargo xtask build`): the addresses mean something only in the image that logged them",
            elf.display()
        );
    }
    for (address, frames) in parsed.iter().zip(return_addresses(elf, &parsed)?) {
        println!("{address:#010x}");
        if frames.is_empty() {
            println!("    (no code of {} there)", elf.display());
        }
        for mut frame in frames {
            if let Ok(relative) = Path::new(&frame.file).strip_prefix(root) {
                frame.file = relative.display().to_string();
            }
            println!("    {frame}");
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_addresses_of_a_panic_line_are_read_in_their_order() {
        let log = "INFO  node-ID 1\n\
                   ERROR panicked; return addresses [0x080095c2, 0x0800a83e, 0x08001001] \
                   (`cargo xtask where` names them)\n";
        assert_eq!(
            panic_addresses(log),
            Some(vec![0x0800_95c2, 0x0800_a83e, 0x0800_1001])
        );
        assert_eq!(panic_addresses("INFO  nothing happened"), None);
        assert_eq!(panic_addresses("return addresses [0x0800zz00]"), None);
    }

    #[test]
    fn an_address_is_hexadecimal_of_at_most_eight_digits() {
        assert_eq!(parse_address("0x08001234").unwrap(), 0x0800_1234);
        assert_eq!(parse_address("8001234").unwrap(), 0x0800_1234);
        for bad in ["", "0x", "0x080012345", "main", "0x0800_1234"] {
            let error = parse_address(bad).unwrap_err().to_string();
            assert!(error.contains("is not an address"), "{bad}: {error}");
        }
    }
}
