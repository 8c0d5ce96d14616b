//! The processing step of a channel on the target: the device's part of the safety function
//! response time per step (EN 50325-5 9.3.1), from the instructions `cargo xtask bench
//! --target-cost` counted in the real QEMU images ([`MEASURED`], which that command writes
//! into `target_measured.rs`, so the figure cannot drift from the measurement), and for
//! SimpleCAN `cargo xtask bench --target-cost --protocol simplecan` in the QEMU images with
//! SimpleCAN ([`MEASURED_SIMPLECAN`], `target_measured_simplecan.rs`).
//!
//! **Measured** (QEMU's instruction trace of the emulated network, one instruction per
//! translation block, both nodes Operational, the emergency stop pressed and released):
//! the thread-mode instructions of the longest iteration of the channel loop
//! (`ChannelLoop::service`) of any kind, which a frame may have to wait behind (the loop does
//! not preempt itself); and of the longest iteration that handled the protocol's traffic (for
//! CANopen Safety a received plain or inverted SRDO frame, the other channel's verdict, a
//! frame sent; for SimpleCAN a frame received or sent).
//!
//! **Bounded by argument** (QEMU counts instructions, not cycles, and runs the QEMU board
//! layer, not the hardware one):
//! - the wake-up ([`WAKE_INSTRUCTIONS`]) and the board's work between two iterations
//!   ([`BETWEEN_ITERATIONS`]), neither of which the measurement counts;
//! - [`CPI_BOUND`] cycles per instruction;
//! - interrupt handling during a step: [`INTERRUPT_ALLOWANCE_FACTOR`];
//! - the hardware layer's driver in place of the QEMU layer's (bxCAN mailbox registers
//!   instead of decoding the emulated serial line, COBS and CRC-16 per frame, and reading
//!   the clock by semihosting): taken to cost no more than the QEMU layer's, which is not
//!   measured.

/// Instructions counted on the target (thread mode, the QEMU images).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TargetCost {
    /// The longest loop iteration of any kind seen (a frame arriving during it waits).
    pub longest_iteration: u64,
    /// The longest loop iteration that handled the safety protocol's traffic: an SRDO frame
    /// or a verdict (CANopen Safety, [`MEASURED`]); a frame received or sent (SimpleCAN,
    /// [`MEASURED_SIMPLECAN`]).
    pub longest_protocol_iteration: u64,
}

/// The wake-up, an allowance by argument (instructions): on the hardware, the interrupt's
/// handler wakes the task and embassy's executor polls it (its run queue, the task's poll,
/// the select over the CAN, link and timer futures), a few hundred instructions; 2,000 are
/// allowed. Not measured: the emulated loop did not halt while traced.
pub const WAKE_INSTRUCTIONS: u64 = 2000;

/// The board layer's work after each loop iteration, before it waits again, an allowance by
/// analysis of the images' code (instructions): `board::hw::run` feeds the watchdog and
/// searches `board::stack::WORDS_PER_STEP` words of the stack for its high-water mark, at
/// 7 Thumb instructions a word in both hardware images (address, load, compare with the
/// paint, branch, index: the loop as compiled) and a few around them, and logs a new mark
/// when it finds one (one defmt line, a few hundred); 2,500 are allowed (the test
/// `en50325_5_9_3_1_the_allowance_between_iterations_covers_the_stack_search` checks it). A frame that arrives during it waits for it, and the measurement does not count
/// it: it counts the iteration (`ChannelLoop::service`).
pub const BETWEEN_ITERATIONS: u64 = 2500;

/// The core clock of the product's STM32F405 (`board::hw`).
pub const CLOCK_HZ: u64 = 168_000_000;

/// Cycles per instruction, an assumption: 1 cycle and the flash's 5 wait states for every
/// instruction, as if the ART accelerator (RM0090 3.5.2) never hit and nothing were
/// prefetched: RM0090 Table 10 gives 5 wait states at 150–168 MHz for 2.7–3.6 V. A 128-bit
/// flash line holds 4 to 8 Thumb instructions, so charging a whole line fetch to every
/// instruction covers, on average, the Cortex-M4's multi-cycle instructions (loads 2 cycles,
/// taken branches up to 4, LDM/STM/PUSH/POP 1 + N, divisions up to 12: Cortex-M4 TRM 3.3.1).
/// It is not a proof: a cycle count on the board (DWT CYCCNT) is to confirm it.
pub const CPI_BOUND: u64 = 6;

/// Interrupt handling during one step, an allowance by argument: the step's time is
/// multiplied by this. At 1 Mbit/s a CAN frame arrives at most every 47 µs and a link byte
/// (USART at 1 Mbit/s) every 10 µs; a handler run of up to 60 instructions at [`CPI_BOUND`]
/// with 60 cycles of exception entry and exit (Cortex-M4 TRM 3.3: 12 cycles entry, up to 29
/// with the FPU's context stacked) is 420 cycles, 2.5 µs, so interrupts take at most about
/// 30 % of the core and stretch a step by at most 1 / (1 − 0.3) ≈ 1.43; the allowance
/// doubles it. The handlers' length on the hardware is not measured.
pub const INTERRUPT_ALLOWANCE_FACTOR: u64 = 2;

pub use super::target_measured::MEASURED;
pub use super::target_measured_simplecan::MEASURED_SIMPLECAN;

impl TargetCost {
    /// Instructions of the longest processing path: a wake-up, the iteration the loop was in
    /// when the frame came and the board's work after it, the iteration that handles it.
    pub const fn path_instructions(&self) -> u64 {
        WAKE_INSTRUCTIONS
            + self.longest_iteration
            + BETWEEN_ITERATIONS
            + self.longest_protocol_iteration
    }

    /// The processing step (µs): the path's instructions at [`CPI_BOUND`] on [`CLOCK_HZ`],
    /// doubled for interrupts ([`INTERRUPT_ALLOWANCE_FACTOR`]), rounded up to 10 µs.
    pub const fn processing_us(&self) -> u64 {
        let cycles = self.path_instructions() * CPI_BOUND * INTERRUPT_ALLOWANCE_FACTOR;
        let micros = (cycles * 1_000_000).div_ceil(CLOCK_HZ);
        micros.div_ceil(10) * 10
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The step is the whole path at the bounded cycles per instruction, doubled, rounded up
    /// to 10 µs: the wake-up and the board's work between iterations (2,000 and 2,500), 2,000
    /// and 1,060 instructions of iterations, 7,560 in all, are 90,720 cycles, 540.0 µs
    /// exactly; one instruction more rounds up to 550 µs.
    #[test]
    fn en50325_5_9_3_1_the_processing_step_is_the_path_at_the_bounded_cycles() {
        assert_eq!((WAKE_INSTRUCTIONS, BETWEEN_ITERATIONS), (2000, 2500));
        let cost = TargetCost {
            longest_iteration: 2000,
            longest_protocol_iteration: 1060,
        };
        assert_eq!(cost.path_instructions(), 7560);
        assert_eq!(cost.processing_us(), 540);
        let one_more = TargetCost {
            longest_protocol_iteration: 1061,
            ..cost
        };
        assert_eq!(one_more.processing_us(), 550);
    }
}
