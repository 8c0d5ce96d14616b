//! A sealed firmware image of this project, read from its ELF file: what goes into flash, the
//! function symbols (to name the code at a PC in sentences), and where the defmt RTT control
//! block is.
//!
//! Only the images `cargo xtask build` sealed are accepted: the seal (`IMAGE_SEAL`) must hold
//! [`dual_channel::selftest::SEALED`] and the CRC of the flash contents, checked with the same
//! function the image runs at start-up ([`dual_channel::selftest::check_image`]).

use object::read::elf::{ElfFile32, FileHeader as _, ProgramHeader as _};
use object::{Endianness, Object as _, ObjectSymbol as _, SymbolKind};
use std::path::{Path, PathBuf};

/// The first byte of flash (`memory.x`; RM0090 2.3.1), where every image begins.
pub const FLASH_ORIGIN: u32 = 0x0800_0000;
/// The F405RG's flash (RM0090 3.3: 1 Mbyte, sectors 0 to 11).
pub const FLASH_SIZE: u32 = 0x10_0000;

/// Why an ELF file is not run.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// The file could not be read.
    #[error("{path}: cannot be read: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// The file is not a 32-bit little-endian ARM ELF file.
    #[error("{path}: not a 32-bit ARM ELF file ({reason})")]
    NotElf {
        /// The file.
        path: PathBuf,
        /// What the parser said.
        reason: String,
    },
    /// A loadable segment lies outside the F405's flash.
    #[error(
        "{path}: a loadable segment at {address:#010x} ({size} bytes) lies outside the flash \
         (0x08000000 to 0x080FFFFF): not an STM32F405 image"
    )]
    OutsideFlash {
        /// The file.
        path: PathBuf,
        /// The segment's load address.
        address: u32,
        /// Its size in the file.
        size: u32,
    },
    /// No vector table at the start of flash.
    #[error(
        "{path}: no vector table at 0x08000000 (the first loadable segment starts at \
         {first:#010x}): the MCU would not know where to start"
    )]
    NoVectorTable {
        /// The file.
        path: PathBuf,
        /// Where the first loadable segment starts (0 when there is none).
        first: u32,
    },
    /// The vector table's initial stack pointer or reset vector is not usable.
    #[error(
        "{path}: the vector table's initial stack pointer {sp:#010x} or reset vector \
         {reset:#010x} is not usable (the stack must be in RAM, the reset vector a Thumb \
         address in flash)"
    )]
    BadVectorTable {
        /// The file.
        path: PathBuf,
        /// Word 0.
        sp: u32,
        /// Word 1.
        reset: u32,
    },
    /// The ELF has no `IMAGE_SEAL` symbol: not one of this project's firmware images.
    #[error("{path}: has no IMAGE_SEAL symbol: not a firmware image of this project")]
    NoSeal {
        /// The file.
        path: PathBuf,
    },
    /// The flash segments are not laid out as the seal's CRC covers them.
    #[error(
        "{path}: the flash segments are not the code from 0x08000000 and the data right after \
         it, which the image CRC covers (see `--no-rosegment` in .cargo/config.toml)"
    )]
    Layout {
        /// The file.
        path: PathBuf,
    },
    /// The seal is missing or does not match the flash contents.
    #[error(
        "{path}: not a sealed image ({fault:?}): `cargo xtask build` builds and seals the \
         images; an image whose seal does not match its flash fails its own start-up check"
    )]
    NotSealed {
        /// The file.
        path: PathBuf,
        /// What the check found.
        fault: dual_channel::selftest::ImageFault,
    },
}

/// A block of bytes to write into flash.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Segment {
    /// Load address.
    pub address: u32,
    /// Contents.
    pub bytes: Vec<u8>,
}

/// A function of the image.
#[derive(Clone, Debug)]
struct Function {
    start: u32,
    size: u32,
    name: String,
}

/// The image's function symbols, to name the code at an address.
#[derive(Clone, Debug, Default)]
pub struct Symbols {
    /// Sorted by start address.
    functions: Vec<Function>,
}

impl Symbols {
    /// Reads the function symbols of an ELF file (demangled, without their hash).
    pub fn from_elf(elf: &[u8]) -> Symbols {
        let Ok(file) = object::File::parse(elf) else {
            return Symbols::default();
        };
        let mut functions: Vec<Function> = file
            .symbols()
            .filter(|symbol| symbol.kind() == SymbolKind::Text && symbol.size() > 0)
            .filter_map(|symbol| {
                let name = symbol.name().ok()?;
                Some(Function {
                    // The Thumb bit is not part of the address.
                    start: (symbol.address() as u32) & !1,
                    size: symbol.size() as u32,
                    name: format!("{:#}", rustc_demangle::demangle(name)),
                })
            })
            .collect();
        functions.sort_by_key(|function| function.start);
        Symbols { functions }
    }

    /// A table of functions given as (start, size, name), for tests.
    pub fn from_functions(functions: &[(u32, u32, &str)]) -> Symbols {
        let mut functions: Vec<Function> = functions
            .iter()
            .map(|&(start, size, name)| Function {
                start,
                size,
                name: name.to_owned(),
            })
            .collect();
        functions.sort_by_key(|function| function.start);
        Symbols { functions }
    }

    /// The start addresses of the functions named `name` (`whole`), or whose names contain
    /// it.
    pub fn starts_of(&self, name: &str, whole: bool) -> Vec<u32> {
        self.functions
            .iter()
            .filter(|function| {
                if whole {
                    function.name == name
                } else {
                    function.name.contains(name)
                }
            })
            .map(|function| function.start)
            .collect()
    }

    /// The function that holds `address`, if the symbol table knows one.
    pub fn function(&self, address: u32) -> Option<&str> {
        let index = self
            .functions
            .partition_point(|function| function.start <= address);
        let function = self.functions.get(index.checked_sub(1)?)?;
        (address < function.start.saturating_add(function.size)).then_some(function.name.as_str())
    }

    /// As [`Symbols::describe`], for a PC known only to the start of its translated block
    /// (Unicorn does not bring the PC up to date for an access to a peripheral).
    pub fn describe_block(&self, address: u32) -> String {
        match self.function(address) {
            Some(name) => format!("`{name}` (in the block from PC {address:#010x})"),
            None => format!("the block from {address:#010x} (no function symbol holds it)"),
        }
    }

    /// `function (PC 0x...)`, or the address alone when no symbol holds it.
    pub fn describe(&self, address: u32) -> String {
        match self.function(address) {
            Some(name) => format!("`{name}` (PC {address:#010x})"),
            None => format!("code at {address:#010x} (no function symbol holds it)"),
        }
    }
}

/// Whether loading an image checks its seal.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Seal {
    /// Only a sealed image is loaded (every run of the product's images).
    Required,
    /// The image is loaded whatever its seal holds, still only with an `IMAGE_SEAL` symbol: a
    /// copy damaged on purpose, to see the image's own start-up check refuse it.
    NotChecked,
}

/// A sealed image, ready to load.
#[derive(Clone, Debug)]
pub struct Image {
    /// Where it was read from.
    pub path: PathBuf,
    /// The ELF file's bytes (the defmt decoder reads its tables from them).
    pub elf: Vec<u8>,
    /// What goes into flash.
    pub segments: Vec<Segment>,
    /// The function symbols.
    pub symbols: Symbols,
    /// The address of `_SEGGER_RTT`, the defmt RTT control block, if the image has one.
    pub rtt: Option<u32>,
    /// The image CRC the seal holds.
    pub crc: u32,
}

impl Image {
    /// Reads and checks the image at `path`.
    pub fn load(path: &Path) -> Result<Image, ImageError> {
        Image::load_as(path, Seal::Required)
    }

    /// Reads the image at `path`, its seal checked as `seal` says.
    pub fn load_as(path: &Path, seal: Seal) -> Result<Image, ImageError> {
        let elf = std::fs::read(path).map_err(|source| ImageError::Read {
            path: path.to_owned(),
            source,
        })?;
        Image::parse_as(path, elf, seal)
    }

    /// Checks the image in `elf` (read from `path`).
    pub fn parse(path: &Path, elf: Vec<u8>) -> Result<Image, ImageError> {
        Image::parse_as(path, elf, Seal::Required)
    }

    /// Checks the image in `elf` (read from `path`), its seal as `seal` says.
    pub fn parse_as(path: &Path, elf: Vec<u8>, seal_check: Seal) -> Result<Image, ImageError> {
        let path_buf = path.to_owned();
        let file = ElfFile32::<Endianness>::parse(&*elf).map_err(|error| ImageError::NotElf {
            path: path_buf.clone(),
            reason: error.to_string(),
        })?;
        let endian = file.endian();
        if file.elf_header().e_machine(endian) != object::elf::EM_ARM {
            return Err(ImageError::NotElf {
                path: path_buf,
                reason: "not for ARM".to_owned(),
            });
        }
        let mut segments = Vec::new();
        for header in file.elf_program_headers() {
            if header.p_type(endian) != object::elf::PT_LOAD || header.p_filesz(endian) == 0 {
                continue;
            }
            let address = header.p_paddr(endian);
            let size = header.p_filesz(endian);
            let offset = header.p_offset(endian) as usize;
            let inside = address >= FLASH_ORIGIN
                && u64::from(address) + u64::from(size)
                    <= u64::from(FLASH_ORIGIN) + u64::from(FLASH_SIZE);
            let bytes = elf.get(offset..offset + size as usize);
            let (true, Some(bytes)) = (inside, bytes) else {
                return Err(ImageError::OutsideFlash {
                    path: path_buf,
                    address,
                    size,
                });
            };
            segments.push(Segment {
                address,
                bytes: bytes.to_vec(),
            });
        }
        segments.sort_by_key(|segment| segment.address);
        let first = segments.first().map_or(0, |segment| segment.address);
        if first != FLASH_ORIGIN || segments[0].bytes.len() < 8 {
            return Err(ImageError::NoVectorTable {
                path: path_buf,
                first,
            });
        }
        let word = |at: usize| {
            let bytes = &segments[0].bytes[at..at + 4];
            u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]])
        };
        let (sp, reset) = (word(0), word(4));
        let sp_in_ram = crate::memory::is_ram(sp.wrapping_sub(4)) && sp % 4 == 0;
        let reset_in_flash =
            reset & 1 == 1 && (FLASH_ORIGIN..FLASH_ORIGIN + FLASH_SIZE).contains(&(reset & !1));
        if !sp_in_ram || !reset_in_flash {
            return Err(ImageError::BadVectorTable {
                path: path_buf,
                sp,
                reset,
            });
        }
        let symbol = |name: &str| {
            file.symbols()
                .find(|symbol| symbol.name() == Ok(name))
                .map(|symbol| symbol.address() as u32)
        };
        let seal = symbol("IMAGE_SEAL").ok_or_else(|| ImageError::NoSeal {
            path: path_buf.clone(),
        })?;
        let crc = match seal_check {
            Seal::Required => check_seal(&path_buf, &segments, seal)?,
            Seal::NotChecked => sealed_crc(&path_buf, &segments, seal)?,
        };
        let rtt = symbol("_SEGGER_RTT");
        let symbols = Symbols::from_elf(&elf);
        drop(file);
        Ok(Image {
            path: path_buf,
            elf,
            segments,
            symbols,
            rtt,
            crc,
        })
    }
}

/// Checks the seal as the image does at start-up: the code segment from the start of flash
/// and the data's load image right after it (the alignment bytes between them not covered).
fn check_seal(path: &Path, segments: &[Segment], seal: u32) -> Result<u32, ImageError> {
    use dual_channel::selftest::check_image;
    let layout = || ImageError::Layout {
        path: path.to_owned(),
    };
    let (code, data): (&[u8], &[u8]) = match segments {
        [code] => (&code.bytes, &[]),
        [code, data] => {
            let end = code.address as u64 + code.bytes.len() as u64;
            if u64::from(data.address) < end || u64::from(data.address) - end >= 8 {
                return Err(layout());
            }
            (&code.bytes, &data.bytes)
        }
        _ => return Err(layout()),
    };
    let offset = seal.checked_sub(FLASH_ORIGIN).ok_or_else(layout)? as usize;
    check_image(code, data, offset).map_err(|fault| ImageError::NotSealed {
        path: path.to_owned(),
        fault,
    })?;
    sealed_crc(path, segments, seal)
}

/// The image CRC the seal at `seal` holds, unchecked.
fn sealed_crc(path: &Path, segments: &[Segment], seal: u32) -> Result<u32, ImageError> {
    let layout = || ImageError::Layout {
        path: path.to_owned(),
    };
    let offset = seal.checked_sub(FLASH_ORIGIN).ok_or_else(layout)? as usize;
    segments
        .first()
        .and_then(|code| {
            code.bytes
                .get(offset + 4..offset + dual_channel::selftest::SEAL_LEN)
        })
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .ok_or_else(layout)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_that_is_not_elf_is_refused_with_a_sentence() {
        let error = Image::parse(Path::new("x.bin"), vec![1, 2, 3]).unwrap_err();
        assert!(error.to_string().contains("not a 32-bit ARM ELF file"));
    }

    #[test]
    fn symbols_name_the_function_that_holds_an_address() {
        let symbols = Symbols {
            functions: vec![
                Function {
                    start: 0x100,
                    size: 0x10,
                    name: "first".to_owned(),
                },
                Function {
                    start: 0x200,
                    size: 0x20,
                    name: "second".to_owned(),
                },
            ],
        };
        assert_eq!(symbols.function(0x100), Some("first"));
        assert_eq!(symbols.function(0x10F), Some("first"));
        assert_eq!(symbols.function(0x110), None);
        assert_eq!(symbols.function(0x21F), Some("second"));
        assert_eq!(symbols.function(0x50), None);
        assert!(symbols.describe(0x204).starts_with("`second`"));
    }
}
