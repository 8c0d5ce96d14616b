//! The QEMU images' defmt logs in words, decoded in xtask itself with the `defmt-decoder`
//! crate (the library `defmt-print` is built on): no tool to install before the first run.
//!
//! Each frame becomes one line as `defmt-print` prints it by default: the level in capitals,
//! padded to five characters, a space, the message (`INFO  channel A`); a frame without a
//! level is its message alone. The channels' logs are read by these lines
//! (`network::Network::stop`, `run`'s summary, `qemu`'s self-test verdict).

use anyhow::{Context, Result, anyhow};
use defmt_decoder::{DecodeError, Table};
use std::path::Path;

/// The defmt log `raw` (the bytes an image wrote through semihosting) in lines, with the
/// string table of `image`. A malformed frame is skipped with a line saying so where the
/// encoding can recover (rzCOBS can: the next frame starts after the next zero byte), and
/// ends the log with such a line where it cannot; an unfinished last frame (the run was cut
/// short) ends it with a line saying so.
pub fn decode(image: &Path, raw: &[u8]) -> Result<String> {
    let elf = std::fs::read(image).with_context(|| format!("reading {}", image.display()))?;
    let table = Table::parse(&elf)
        .map_err(|error| anyhow!("{}: its defmt data: {error}", image.display()))?
        .ok_or_else(|| anyhow!("{} holds no defmt data", image.display()))?;
    let mut decoder = table.new_stream_decoder();
    decoder.received(raw);
    let mut lines = String::new();
    loop {
        match decoder.decode() {
            Ok(frame) => {
                if let Some(level) = frame.level() {
                    lines.push_str(&format!("{:<5} ", level.as_str().to_uppercase()));
                }
                lines.push_str(&frame.display_message().to_string());
                lines.push('\n');
            }
            Err(DecodeError::UnexpectedEof) => {
                break;
            }
            Err(DecodeError::Malformed) if table.encoding().can_recover() => {
                lines.push_str("(xtask) a malformed defmt frame skipped\n");
            }
            Err(DecodeError::Malformed) => {
                lines.push_str("(xtask) a malformed defmt frame: the rest of the log is lost\n");
                break;
            }
        }
    }
    Ok(lines)
}
