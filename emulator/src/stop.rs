//! Why an emulated run stopped before its time was up: each reason is a sentence that names
//! what the image did, where (the function at the PC), and what the manual says follows.

use crate::peripherals::AccessError;
use crate::peripherals::rcc::ResetCause;
use crate::time::Nanos;

/// A data access, as the sentences name it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Access {
    /// The address.
    pub address: u32,
    /// Bytes: 1, 2 or 4.
    pub size: u32,
    /// `None` for a read, the value for a write.
    pub written: Option<u32>,
}

impl core::fmt::Display for Access {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let Access {
            address,
            size,
            written,
        } = *self;
        match written {
            None => write!(f, "a {size}-byte read at {address:#010x}")?,
            Some(value) => write!(f, "a {size}-byte write of {value:#x} at {address:#010x}")?,
        }
        if let Some(block) = crate::memory::describe(address) {
            write!(f, " ({block})")?;
        }
        Ok(())
    }
}

/// What made the core take HardFault (ARMv7-M B1.5.14 fault behaviour), or lock up.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Fault {
    /// An undefined instruction: UsageFault UNDEFINSTR.
    UndefinedInstruction,
    /// An instruction in an invalid state (EPSR.T clear, a bad IT state): UsageFault INVSTATE.
    InvalidState,
    /// An exception return with an invalid EXC_RETURN or a failed integrity check (B1.5.8):
    /// UsageFault INVPC.
    InvalidReturn {
        /// The EXC_RETURN value.
        exc_return: u32,
        /// What was wrong with it.
        why: &'static str,
    },
    /// A breakpoint instruction with no debugger attached: HardFault DEBUGEVT (C1.4).
    Breakpoint,
    /// An unaligned access the core does not support: UsageFault UNALIGNED.
    Unaligned,
    /// An instruction fetch the bus refused (CCM RAM, a peripheral): BusFault IBUSERR.
    InstructionBus {
        /// The address fetched.
        address: u32,
    },
    /// The vector of an exception is not a Thumb address, or cannot be read (B1.5.6,
    /// HardFault VECTTBL or INVSTATE on the handler's first instruction).
    BadVector {
        /// The exception number.
        exception: u32,
        /// Where the vector is.
        address: u32,
        /// The vector read (`None`: not readable).
        value: Option<u32>,
    },
    /// A synchronous exception (SVCall) raised where it cannot be taken: escalated (B1.5.4).
    Escalated {
        /// The exception number.
        exception: u32,
    },
    /// A floating-point instruction ran while CPACR denies CP10/CP11 (B3.2 CPACR): the
    /// hardware takes UsageFault NOCP there. Unicorn executes it regardless, so the emulator
    /// notices at the next exception entry or return, from CONTROL.FPCA.
    FloatingPointDisabled,
    /// A bus error on a data access: a wrong flash key sequence (RM0090 3.6.1), precise
    /// BusFault.
    BusError,
    /// A QEMU exception the emulator does not map (its number).
    Other(u32),
}

impl core::fmt::Display for Fault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Fault::UndefinedInstruction => write!(
                f,
                "an undefined instruction (UsageFault UNDEFINSTR; escalated to HardFault \
                 unless SHCSR.USGFAULTENA is set)"
            ),
            Fault::InvalidState => write!(
                f,
                "an instruction executed in an invalid state, e.g. a branch to an even \
                 address (UsageFault INVSTATE)"
            ),
            Fault::InvalidReturn { exc_return, why } => write!(
                f,
                "an exception return with EXC_RETURN {exc_return:#010x}: {why} (UsageFault \
                 INVPC, ARMv7-M B1.5.8)"
            ),
            Fault::Breakpoint => write!(
                f,
                "a breakpoint instruction with no debugger attached (HardFault DEBUGEVT)"
            ),
            Fault::Unaligned => write!(f, "an unaligned access (UsageFault UNALIGNED)"),
            Fault::InstructionBus { address } => write!(
                f,
                "an instruction fetch at {address:#010x} the bus refuses{} (BusFault IBUSERR)",
                crate::memory::describe(*address)
                    .map(|block| format!(", in {block}"))
                    .unwrap_or_default()
            ),
            Fault::BadVector {
                exception,
                address,
                value: Some(value),
            } => write!(
                f,
                "exception {exception}'s vector at {address:#010x} is {value:#010x}, not a \
                 Thumb address (UsageFault INVSTATE on the handler's first instruction)"
            ),
            Fault::BadVector {
                exception,
                address,
                value: None,
            } => write!(
                f,
                "exception {exception}'s vector at {address:#010x} cannot be read (HardFault \
                 VECTTBL)"
            ),
            Fault::Escalated { exception } => write!(
                f,
                "exception {exception} raised where its priority does not let it be taken \
                 (escalated to HardFault, ARMv7-M B1.5.4)"
            ),
            Fault::FloatingPointDisabled => write!(
                f,
                "a floating-point instruction ran while CPACR denies CP10/CP11 (UsageFault \
                 NOCP on the hardware; noticed here at the next exception entry or return)"
            ),
            Fault::BusError => write!(
                f,
                "a bus error on a data access, from a wrong flash key sequence (RM0090 3.6.1; \
                 BusFault PRECISERR)"
            ),
            Fault::Other(number) => write!(f, "QEMU exception {number}, which is not mapped"),
        }
    }
}

/// Why a run stopped.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Stop {
    /// An access no model claims.
    Unclaimed {
        /// The access.
        access: Access,
        /// The code that made it.
        at: String,
    },
    /// A model refused the access (a register it does not model, a width it does not
    /// allow).
    Refused {
        /// The access.
        access: Access,
        /// The model's sentence.
        error: AccessError,
        /// The code that made it.
        at: String,
    },
    /// The core took HardFault.
    HardFault {
        /// The cause.
        fault: Fault,
        /// The code that faulted.
        at: String,
    },
    /// A fault while HardFault or NMI was active, or with FAULTMASK set: the core locks up
    /// (ARMv7-M B1.5, "Unrecoverable exception cases").
    Lockup {
        /// The fault.
        fault: Fault,
        /// The code that faulted.
        at: String,
    },
    /// A system reset: the watchdog's, or AIRCR.SYSRESETREQ.
    Reset {
        /// Which.
        cause: ResetCause,
        /// The code running when it happened.
        at: String,
    },
    /// The power cut armed in the flash model happened during a program or erase.
    PowerLost {
        /// The code running when it happened.
        at: String,
    },
    /// Unicorn reported an error the emulator did not expect.
    Engine {
        /// Unicorn's error.
        error: String,
        /// Where the core was.
        at: String,
    },
}

impl core::fmt::Display for Stop {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Stop::Unclaimed { access, at } => write!(
                f,
                "{access}, which no model claims (nothing reads as 0 here), by {at}"
            ),
            Stop::Refused { access, error, at } => write!(f, "{access} refused: {error}; by {at}"),
            Stop::HardFault { fault, at } => write!(f, "HardFault: {fault}, in {at}"),
            Stop::Lockup { fault, at } => write!(
                f,
                "lockup: {fault} while HardFault or NMI was active (ARMv7-M B1.5, \
                 unrecoverable exception cases), in {at}"
            ),
            Stop::Reset {
                cause: ResetCause::IndependentWatchdog,
                at,
            } => write!(
                f,
                "the independent watchdog ran out and reset the MCU (RM0090 21.3.1) while {at} \
                 ran"
            ),
            Stop::Reset {
                cause: ResetCause::Software,
                at,
            } => write!(
                f,
                "a system reset requested by AIRCR.SYSRESETREQ (ARMv7-M B3.2) from {at}"
            ),
            Stop::Reset {
                cause: ResetCause::PowerOn,
                at,
            } => write!(f, "a power-on reset while {at} ran"),
            Stop::PowerLost { at } => write!(
                f,
                "the power was cut during a flash program or erase operation, as armed, while \
                 {at} ran"
            ),
            Stop::Engine { error, at } => {
                write!(
                    f,
                    "Unicorn stopped with {error} at {at}, which the emulator did not expect"
                )
            }
        }
    }
}

/// How a run ended.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// The time asked for has passed.
    Elapsed,
    /// It returned early, at [`crate::cpu::Machine::now`], because the image asked the CAN
    /// controller to transmit (only when asked for:
    /// [`crate::cpu::Machine::yield_on_transmit_request`]).
    Yielded,
    /// It stopped before: the reason and the virtual time.
    Stopped {
        /// Why.
        stop: Stop,
        /// When.
        at: Nanos,
    },
}

impl std::error::Error for Stop {}
