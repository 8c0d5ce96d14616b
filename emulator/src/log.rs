//! The images' defmt log, decoded in-process with `defmt-decoder` against the image's ELF.

use crate::time::Nanos;
use defmt_decoder::{DecodeError, StreamDecoder, Table};

/// Why the log cannot be decoded.
#[derive(Debug, thiserror::Error)]
pub enum LogError {
    /// The ELF has no defmt table (the image does not log with defmt).
    #[error("the image has no defmt table: it does not log with defmt")]
    NoTable,
    /// The defmt table cannot be read.
    #[error("the image's defmt table cannot be read: {0}")]
    Table(String),
}

/// The image's defmt table.
pub struct LogTable {
    table: Table,
}

impl LogTable {
    /// Reads the defmt table of an ELF file.
    pub fn from_elf(elf: &[u8]) -> Result<LogTable, LogError> {
        match Table::parse(elf) {
            Ok(Some(table)) => Ok(LogTable { table }),
            Ok(None) => Err(LogError::NoTable),
            Err(error) => Err(LogError::Table(error.to_string())),
        }
    }

    /// A decoder of the image's RTT byte stream.
    pub fn decoder(&self) -> LogDecoder<'_> {
        LogDecoder {
            stream: self.table.new_stream_decoder(),
            malformed: 0,
        }
    }
}

/// One decoded log line.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Line {
    /// When the bytes that completed it were drained.
    pub at: Nanos,
    /// The level (`INFO`, `WARN`, ...), if the frame has one.
    pub level: Option<String>,
    /// The formatted message.
    pub message: String,
}

impl core::fmt::Display for Line {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let millis = self.at as f64 / 1e6;
        let level = self.level.as_deref().unwrap_or("");
        write!(f, "{millis:>12.6} ms {level:<5} {}", self.message)
    }
}

/// Decodes the RTT stream as it arrives.
pub struct LogDecoder<'t> {
    stream: Box<dyn StreamDecoder + Send + Sync + 't>,
    malformed: u64,
}

impl LogDecoder<'_> {
    /// Feeds the bytes drained at `at` and returns the lines they complete.
    pub fn feed(&mut self, at: Nanos, bytes: &[u8]) -> Vec<Line> {
        self.stream.received(bytes);
        let mut lines = Vec::new();
        loop {
            match self.stream.decode() {
                Ok(frame) => lines.push(Line {
                    at,
                    level: frame.level().map(|level| level.as_str().to_uppercase()),
                    message: frame.display_message().to_string(),
                }),
                Err(DecodeError::UnexpectedEof) => break,
                Err(DecodeError::Malformed) => {
                    self.malformed += 1;
                    // The rzCOBS stream resynchronises at the next frame.
                    if self.malformed > 1_000_000 {
                        break;
                    }
                }
            }
        }
        lines
    }

    /// Frames that could not be decoded.
    pub fn malformed(&self) -> u64 {
        self.malformed
    }
}
