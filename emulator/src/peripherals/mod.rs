//! The F405 peripheral models: one per register block, each a small state machine written
//! from RM0090 and tested from the manual's statements (never from our drivers' behaviour).
//!
//! Every model implements [`Peripheral`]: the CPU side routes each access inside the block
//! to it with the block-relative offset, tells it the time, and asks it when it next has
//! something to do and which interrupt lines it holds up. What a model does not implement
//! is an [`AccessError`], which ends the run with a sentence: nothing reads as 0 silently.

#[cfg(test)]
mod bench;
pub mod bxcan;
pub mod dbgmcu;
pub mod flash;
pub mod gpio;
pub mod iwdg;
pub mod pwr;
pub mod rcc;
pub mod tim2;
pub mod usart;

use crate::time::{Clocks, Nanos};

/// What the CPU side lends a model on each call.
#[derive(Clone, Copy, Debug)]
pub struct Context {
    /// Virtual time now.
    pub now: Nanos,
    /// The clock frequencies now (the RCC model's).
    pub clocks: Clocks,
}

/// An access a model refuses: the run ends with this sentence, the address and the PC.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum AccessError {
    /// No register at this offset in the block (or not one the model implements).
    Unmodelled {
        /// The block's name, e.g. "CAN1 (RM0090 32)".
        block: &'static str,
        /// Offset from the block's base.
        offset: u32,
    },
    /// A register accessed with a width the manual does not allow, or the model does not
    /// implement.
    Width {
        /// The block's name.
        block: &'static str,
        /// Offset from the block's base.
        offset: u32,
        /// Access size in bytes.
        size: u32,
    },
}

impl core::fmt::Display for AccessError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            AccessError::Unmodelled { block, offset } => {
                write!(f, "{block}: no modelled register at offset {offset:#05x}")
            }
            AccessError::Width {
                block,
                offset,
                size,
            } => write!(
                f,
                "{block}: a {size}-byte access at offset {offset:#05x} is not modelled"
            ),
        }
    }
}

impl std::error::Error for AccessError {}

/// One peripheral register block.
pub trait Peripheral {
    /// The block's name and its RM0090 section, for messages: "CAN1 (RM0090 32)".
    fn name(&self) -> &'static str;

    /// Reads `size` bytes (1, 2 or 4) at `offset` from the block's base.
    fn read(&mut self, ctx: &Context, offset: u32, size: u32) -> Result<u32, AccessError>;

    /// Writes the low `size` bytes of `value` at `offset`.
    fn write(
        &mut self,
        ctx: &Context,
        offset: u32,
        size: u32,
        value: u32,
    ) -> Result<(), AccessError>;

    /// Brings the model's state up to `ctx.now` (a byte finished, a frame sent, a counter
    /// expired). Called before every access and whenever [`Peripheral::next_event`] is due.
    fn advance(&mut self, ctx: &Context) {
        let _ = ctx;
    }

    /// When the model next changes by itself (`None`: not before an access).
    fn next_event(&self, ctx: &Context) -> Option<Nanos> {
        let _ = ctx;
        None
    }

    /// The NVIC interrupt lines (IRQ numbers, RM0090 Table 61) this block drives.
    fn interrupt_lines(&self) -> &'static [u32] {
        &[]
    }

    /// Whether the block holds interrupt line `irq` asserted now (level: the NVIC pends it
    /// while it is asserted).
    fn interrupt(&self, irq: u32) -> bool {
        let _ = irq;
        false
    }
}
