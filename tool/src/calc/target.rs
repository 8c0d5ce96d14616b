//! The processing step of a channel on the target: the device's part of the safety function
//! response time per step (EN 50325-5 9.3.1), from the instructions counted on the target,
//! which the commands that count them write into generated files (so the figure cannot drift
//! from the measurement):
//!
//! - **CANopen Safety** ([`MEASURED`], `target_measured.rs`, `cargo xtask bench
//!   --target-cost`): the shipped CANopen Safety images on the emulated STM32F405
//!   (`emulator`), the nominal case.
//! - **SimpleCAN** ([`MEASURED_SIMPLECAN`], `target_measured_simplecan.rs`, `cargo xtask bench
//!   --target-cost --protocol simplecan`): the shipped SimpleCAN images on the emulated
//!   STM32F405, SimpleCAN's measuring run (node 1 producing an SC-ID and sending the syncs,
//!   node 33 consuming it, the emergency stop opened and closed).
//!
//! Both are counted by [`Basis::Activations`]: whole activations of the core, each from a
//! wake-up to the next sleep, so the wake-up, the interrupt handlers that ran meanwhile,
//! the loop iteration and the board's work after it are all counted. The
//! path a frame takes is the longest activation of any kind that had the loop run, which a
//! frame arriving during it waits behind (the loop does not preempt itself), then the longest
//! one that did the protocol's work (for CANopen Safety a received plain or inverted SRDO
//! frame, a pair produced or validated, the other channel's verdict; for SimpleCAN a packet or
//! sync decoded or produced, channel A's forwarded copy paired, channel A's packet judged by
//! channel B, the other channel's verdict).
//!
//! **Bounded by argument**: [`CPI_BOUND`] cycles per instruction (the emulator counts
//! instructions, not cycles), and [`INTERRUPT_ALLOWANCE_FACTOR`] for interrupts beyond those
//! counted (the emulated traffic raises fewer than a fully loaded bus at 1 Mbit/s would).

/// What the instructions of a [`TargetCost`] were counted over.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Basis {
    /// Whole activations of the shipped images on the emulated STM32F405 (`emulator::profile`):
    /// the wake-up and the board's work around the loop iteration are in the count.
    Activations,
}

/// Instructions counted on the target ([`Basis`] says over what).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TargetCost {
    /// What was counted.
    pub basis: Basis,
    /// The longest activation with a loop iteration, of any kind seen (a frame arriving
    /// during it waits).
    pub longest_iteration: u64,
    /// The longest one that did the safety protocol's work: an SRDO frame, a pair produced or
    /// validated, a verdict (CANopen Safety, [`MEASURED`]); a packet or sync decoded or
    /// produced, a forwarded packet paired, channel A's packet judged, a verdict (SimpleCAN,
    /// [`MEASURED_SIMPLECAN`]).
    pub longest_protocol_iteration: u64,
}

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
    /// Instructions of the longest processing path: the activation the loop was in when the
    /// frame came (its wake-up and the board's work after the iteration included), then the
    /// activation that handles it ([`Basis::Activations`]: both counted whole).
    pub const fn path_instructions(&self) -> u64 {
        match self.basis {
            Basis::Activations => self.longest_iteration + self.longest_protocol_iteration,
        }
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
    /// to 10 µs: activations of 6,500 and 1,060 instructions, 7,560 in all, are 90,720
    /// cycles, 540.0 µs exactly; one instruction more rounds up to 550 µs.
    #[test]
    fn en50325_5_9_3_1_the_processing_step_is_the_path_at_the_bounded_cycles() {
        let cost = TargetCost {
            basis: Basis::Activations,
            longest_iteration: 6500,
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
