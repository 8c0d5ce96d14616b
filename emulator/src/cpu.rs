//! The emulated MCU: Unicorn executes the Cortex-M4's instructions, this module does what
//! Unicorn leaves out of an M-profile core, from the ARMv7-M Architecture Reference Manual:
//! exception entry (B1.5.6) and return (B1.5.8) with tail-chaining, the NVIC's choice of the
//! exception to take (B1.5.4, B3.4), SysTick (B3.3), WFI and WFE (B1.5.18, B1.5.19), and the
//! memory map (RM0090 2.3) that routes every access to the model that claims it.
//!
//! # Virtual time
//!
//! Time is counted in core clock cycles, and one instruction is one cycle: every translated
//! block adds the number of its instructions when it starts. The Cortex-M4 executes most
//! instructions in one cycle, but loads, stores, branches, divisions and flash wait states
//! take more, so emulated code runs faster than the MCU would at the same clock; the
//! figure per run is in the `emulate` report, never here. Asleep (WFI, WFE), time jumps to the
//! next event: a peripheral model's, SysTick's, or the end of the run. The DWT's CYCCNT
//! counts the instructions executed (the core's cycles while it runs, at this rate).
//!
//! # What Unicorn does, and what is done around it
//!
//! - Unicorn (QEMU) runs the Cortex-M4 model (`ArmCpuModel::CORTEX_M4`, Thumb mode). With
//!   `Mode::MCLASS` Unicorn 2.1 replaces any model by the Cortex-M33 (ARMv8-M), so the mode is
//!   left out and the model chosen.
//! - Exception return: in Handler mode a branch to an EXC_RETURN value raises QEMU's exception
//!   8 (`EXCP_EXCEPTION_EXIT`); the interrupt hook unstacks the frame. Writing IPSR does not
//!   rebuild QEMU's cached CPU state flags, so the emulator writes APSR's flags back after
//!   it, which does.
//! - Exception entry happens at the start of a translated block: the block hook runs before
//!   the block and can redirect the PC, so an interrupt is taken between blocks (at most one
//!   block late, in virtual time: none).
//! - `wfi` returns from `emu_start` with the PC after it; `wfe` and `yield` reach the
//!   invalid-instruction hook with the PC after them. `sev` is a no-op in QEMU: the emulator
//!   places a code hook on each `sev` of the image to set the event register.
//! - Floating point: Unicorn executes VFP instructions whatever CPACR says (its M-profile FP
//!   access check is compiled out). CPACR is modelled; an FP instruction run while CPACR
//!   denies it is noticed from CONTROL.FPCA at the next exception entry or return.
//! - The stacked xPSR carries APSR, IPSR and EPSR.T; its IT bits are zero: QEMU ends a
//!   translated block at a 1 KiB boundary even inside an IT block, and its IT state lives in
//!   the translated code, which a register write in a hook does not reach, so an exception
//!   pending inside an IT block waits for the block's end (at most four instructions).

use std::cell::RefCell;
use std::collections::HashMap;
use std::rc::Rc;

use unicorn_engine::unicorn_const::{Arch, HookType, MemType, Mode, Prot};
use unicorn_engine::{ArmCpuModel, RegisterARM, Unicorn};

use crate::image::{Image, Symbols};
use crate::memory;
use crate::observed::{Activations, stack_depth};
use crate::peripherals::bxcan::{self, Can};
use crate::peripherals::dbgmcu::{self, Dbgmcu};
use crate::peripherals::flash::{self, Flash};
use crate::peripherals::gpio::{self, Gpio, Port};
use crate::peripherals::iwdg::{self, Iwdg};
use crate::peripherals::pwr::{self, Pwr};
use crate::peripherals::rcc::{self, Hse, Rcc, ResetCause};
use crate::peripherals::tim2::{self, Tim2};
use crate::peripherals::usart::{self, Transmitted, Usart};
use crate::peripherals::{AccessError, Context, Peripheral};
use crate::profile::Profile;
use crate::stop::{Access, Fault, Outcome, Stop};
use crate::system::exceptions::{FIRST_IRQ, Masks, number};
use crate::system::{self, CoreState, SystemControl};
use crate::time::{Clocks, CycleClock, Nanos};

/// Unicorn's register names, for reading the core's state.
pub use unicorn_engine::RegisterARM as Register;

type Uc<'a> = Unicorn<'a, State>;

/// How often the RTT up-buffer is drained, in instructions: often enough that `defmt-rtt`'s
/// buffer never fills between two drains.
const DRAIN_EVERY: u64 = 10_000;
/// FLASH_CR's offset (RM0090 3.9.5): an access to it stalls while the flash is busy.
const FLASH_CR: u32 = 0x10;
/// An address the core never executes (odd): `emu_start` runs until it is stopped.
const NEVER: u64 = 0xFFFF_FFFF;
/// CONTROL bits (B1.4.4).
const CONTROL_SPSEL: u64 = 1 << 1;
const CONTROL_FPCA: u64 = 1 << 2;
/// The floating-point registers of the extended frame (B1.5.6).
const FP_REGISTERS: [RegisterARM; 16] = [
    RegisterARM::S0,
    RegisterARM::S1,
    RegisterARM::S2,
    RegisterARM::S3,
    RegisterARM::S4,
    RegisterARM::S5,
    RegisterARM::S6,
    RegisterARM::S7,
    RegisterARM::S8,
    RegisterARM::S9,
    RegisterARM::S10,
    RegisterARM::S11,
    RegisterARM::S12,
    RegisterARM::S13,
    RegisterARM::S14,
    RegisterARM::S15,
];

/// Why Unicorn could not be set up.
#[derive(Debug, thiserror::Error)]
#[error("Unicorn could not {what}: {error:?}")]
pub struct EngineError {
    what: &'static str,
    error: unicorn_engine::unicorn_const::uc_error,
}

fn engine(
    what: &'static str,
) -> impl FnOnce(unicorn_engine::unicorn_const::uc_error) -> EngineError {
    move |error| EngineError { what, error }
}

/// The board around the MCU.
#[derive(Clone, Copy, Debug)]
pub struct Config {
    /// The external oscillator (the board's 8 MHz crystal, or one that fails to start).
    pub hse: Hse,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            hse: rcc::BOARD_HSE,
        }
    }
}

/// Asleep, and what wakes the core (B1.5.18, B1.5.19).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Sleep {
    /// WFI: an exception that would preempt if PRIMASK were clear.
    Interrupt,
    /// WFE: the event register, or an exception that would preempt.
    Event,
}

/// A peripheral block on the bus.
struct Block {
    base: u32,
    size: u32,
    model: Rc<RefCell<dyn Peripheral>>,
}

/// The typed models the machine itself needs to talk to.
struct Models {
    rcc: Rc<RefCell<Rcc>>,
    pwr: Rc<RefCell<Pwr>>,
    gpio: [Rc<RefCell<Gpio>>; 3],
    iwdg: Rc<RefCell<Iwdg>>,
    usart: Rc<RefCell<Usart>>,
    can: Rc<RefCell<Can>>,
    flash: Rc<RefCell<Flash>>,
    tim2: Rc<RefCell<Tim2>>,
}

/// Everything the hooks share: Unicorn's user data.
pub struct State {
    clock: CycleClock,
    instructions: u64,
    clocks: Clocks,
    system: SystemControl,
    blocks: Vec<Block>,
    models: Models,
    stop: Option<(Stop, Nanos)>,
    /// The cycle count at which the current run ends.
    end: u64,
    /// The cycle count of the next event (a model's, SysTick's, or the end).
    deadline: u64,
    /// Whether the models' state may have changed since the deadline was computed.
    recompute: bool,
    /// Whether a pending exception may have become takeable.
    attention: bool,
    /// Whether the emulator asked Unicorn to stop (as opposed to a `wfi`).
    stopping: bool,
    sleep: Option<Sleep>,
    event_register: bool,
    /// Instructions per translated block, by start address and size in bytes.
    lengths: HashMap<(u32, u32), u32>,
    symbols: Symbols,
    rtt: Option<u32>,
    log: Vec<(Nanos, Vec<u8>)>,
    next_drain: u64,
    mapped_pages: Vec<u32>,
    /// The PC and instruction count at the last invalid-instruction hook (an instruction
    /// refused twice in a row without progress is undefined, not a `wfe`).
    last_invalid: Option<(u32, u64)>,
    /// Words the USART sent that no peer took.
    usart_words: u64,
    /// Whether a peer takes the USART's words ([`Machine::wire_usart`]).
    usart_wired: bool,
    /// Words the USART started, for the peer, in the order they started.
    usart_out: Vec<Transmitted>,
    /// Whether a transmit request to the CAN controller ends the run early
    /// ([`Machine::yield_on_transmit_request`]).
    yield_on_transmit: bool,
    /// A transmit request ended the run early; [`Machine::run_until`] returns
    /// [`Outcome::Yielded`].
    yielded: bool,
    /// Until then the core executes nothing and takes no exception ([`Machine::hang`]).
    hung_until: Nanos,
    /// Times the core woke from WFI or WFE ([`Machine::wake_ups`]).
    wake_ups: u64,
    /// The flash array as Unicorn holds it (the flash model's array is the reference).
    flash_shadow: Vec<u8>,
    /// Whether the flash model's array may differ from Unicorn's.
    flash_dirty: bool,
    /// When the flash operation in progress ends: fetches from flash stall until then.
    flash_busy_until: Option<Nanos>,
    /// Where the instructions go, when asked for ([`Machine::start_profile`]).
    profile: Option<Box<Profile>>,
    /// The core's wake-ups and sleeps ([`Machine::longest_activation`]).
    activations: Activations,
    /// The main stack pointer the last reset loaded from the vector table.
    initial_sp: u32,
}

impl State {
    fn context(&self) -> Context {
        Context {
            now: self.clock.now(),
            clocks: self.clocks,
        }
    }

    fn describe(&self, pc: u32) -> String {
        self.symbols.describe(pc)
    }

    fn find(&self, address: u32) -> Option<&Block> {
        self.blocks
            .iter()
            .find(|block| address >= block.base && address - block.base < block.size)
    }

    /// Pends the interrupt lines `model` holds up (level-sensitive: a line pends its
    /// interrupt while asserted, unless the interrupt is already pending or active, B3.4.1).
    fn sample(&mut self, model: &dyn Peripheral) {
        for &irq in model.interrupt_lines() {
            if !model.interrupt(irq) {
                continue;
            }
            let n = FIRST_IRQ + irq;
            let exceptions = &mut self.system.exceptions;
            if !exceptions.is_pending(n) && !exceptions.is_active(n) {
                exceptions.set_pending(n, true);
                self.attention = true;
                if self.system.scr() & system::SCR_SEVONPEND != 0 {
                    self.event_register = true;
                }
            }
        }
    }

    fn sample_all(&mut self) {
        let models: Vec<_> = self.blocks.iter().map(|b| b.model.clone()).collect();
        for model in models {
            self.sample(&*model.borrow());
        }
    }

    /// Follows the RCC's clocks and the PWR's backup domain protection.
    fn follow_clock_tree(&mut self) {
        let clocks = self.models.rcc.borrow().clocks();
        if clocks != self.clocks {
            self.clocks = clocks;
            self.clock.set_hz(clocks.hclk);
        }
        let writable = self.models.pwr.borrow().backup_writable();
        self.models.rcc.borrow_mut().set_backup_writable(writable);
    }

    fn set_stop(&mut self, stop: Stop) {
        if self.stop.is_none() {
            self.stop = Some((stop, self.clock.now()));
        }
    }

    /// The core goes to sleep (`sleep`) now: the activation since its wake-up ends.
    fn fall_asleep(&mut self, sleep: Sleep) {
        self.sleep = Some(sleep);
        self.activations.slept(self.clock.now());
    }

    fn core(&self, ipsr: u32) -> CoreState {
        CoreState {
            cycles: self.clock.cycles(),
            instructions: self.instructions,
            ipsr,
        }
    }
}

/// The emulated STM32F405.
pub struct Machine {
    uc: Uc<'static>,
}

fn reg(uc: &Uc<'_>, register: RegisterARM) -> u32 {
    uc.reg_read(register).unwrap_or(0) as u32
}

fn set_reg(uc: &mut Uc<'_>, register: RegisterARM, value: u32) {
    // Writing a register Unicorn knows cannot fail.
    let _ = uc.reg_write(register, u64::from(value));
}

/// Rebuilds QEMU's cached CPU state after an IPSR or CONTROL write (see the module's notes).
/// EPSR's IT bits: IT[1:0] in bits 26:25, IT[7:2] in bits 15:10 (B1.4.2).
const EPSR_IT: u32 = (3 << 25) | (0x3F << 10);

fn refresh_state_flags(uc: &mut Uc<'_>) {
    let flags = reg(uc, RegisterARM::APSR_NZCV);
    set_reg(uc, RegisterARM::APSR_NZCV, flags);
}

fn masks(uc: &Uc<'_>) -> Masks {
    Masks {
        primask: reg(uc, RegisterARM::PRIMASK) & 1 != 0,
        faultmask: reg(uc, RegisterARM::FAULTMASK) & 1 != 0,
        basepri: reg(uc, RegisterARM::BASEPRI) as u8,
    }
}

/// Thumb instructions in `bytes` (a 32-bit instruction starts with 0b11101, 0b11110 or
/// 0b11111 in its first half-word's top bits, ARMv7-M A5.1).
fn count_instructions(bytes: &[u8]) -> u32 {
    let mut count = 0;
    let mut at = 0;
    while at + 1 < bytes.len() {
        let half = u16::from_le_bytes([bytes[at], bytes[at + 1]]);
        at += if half >> 11 >= 0b11101 { 4 } else { 2 };
        count += 1;
    }
    count
}

fn read_word(uc: &Uc<'_>, address: u32) -> Option<u32> {
    let mut bytes = [0u8; 4];
    uc.mem_read(u64::from(address), &mut bytes).ok()?;
    Some(u32::from_le_bytes(bytes))
}

fn read_half(uc: &Uc<'_>, address: u32) -> Option<u16> {
    let mut bytes = [0u8; 2];
    uc.mem_read(u64::from(address), &mut bytes).ok()?;
    Some(u16::from_le_bytes(bytes))
}

/// Stops the run with `fault` at `pc`: HardFault, or lockup when the execution priority is
/// already negative (in HardFault or NMI, or FAULTMASK set).
fn fault(uc: &mut Uc<'_>, fault: Fault, pc: u32) {
    let masks = masks(uc);
    let st = uc.get_data_mut();
    let at = st.describe(pc);
    let locked = st.system.exceptions.execution_priority(masks) < 0;
    st.set_stop(if locked {
        Stop::Lockup { fault, at }
    } else {
        Stop::HardFault { fault, at }
    });
    st.stopping = true;
    let _ = uc.emu_stop();
}

/// ExceptionTaken (B1.5.6): the handler's vector from VTOR, CONTROL.SPSEL and FPCA cleared,
/// IPSR, LR = EXC_RETURN, the exception active. The frame is already on the stack.
fn take(uc: &mut Uc<'_>, n: u32, exc_return: u32) {
    let vtor = uc.get_data().system.vtor();
    let address = vtor.wrapping_add(4 * n);
    let vector = read_word(uc, address);
    let pc = reg(uc, RegisterARM::PC);
    let Some(vector) = vector.filter(|v| v & 1 == 1) else {
        fault(
            uc,
            Fault::BadVector {
                exception: n,
                address,
                value: vector,
            },
            pc,
        );
        return;
    };
    let control = uc.reg_read(RegisterARM::CONTROL).unwrap_or(0);
    let _ = uc.reg_write(
        RegisterARM::CONTROL,
        control & !(CONTROL_SPSEL | CONTROL_FPCA),
    );
    set_reg(uc, RegisterARM::IPSR, n);
    refresh_state_flags(uc);
    set_reg(uc, RegisterARM::LR, exc_return);
    set_reg(uc, RegisterARM::PC, vector);
    let st = uc.get_data_mut();
    st.system.exceptions.activate(n);
    st.event_register = true;
    st.attention = true;
}

/// Exception entry (B1.5.6 PushStack, then ExceptionTaken): the basic frame, or the
/// extended one with S0-S15 and FPSCR when CONTROL.FPCA is set, on the stack in use, 8-byte
/// aligned with the adjustment recorded in the stacked xPSR's bit 9 (B1.5.7).
fn enter(uc: &mut Uc<'_>, n: u32, return_address: u32) {
    let control = uc.reg_read(RegisterARM::CONTROL).unwrap_or(0);
    let ipsr = reg(uc, RegisterARM::IPSR) & 0x1FF;
    let (ccr, fpu) = {
        let system = &uc.get_data().system;
        (system.ccr(), system.fpu_enabled())
    };
    let fpca = control & CONTROL_FPCA != 0;
    if fpca && !fpu {
        fault(uc, Fault::FloatingPointDisabled, return_address);
        return;
    }
    let handler = ipsr != 0;
    let process_stack = !handler && control & CONTROL_SPSEL != 0;
    let sp = reg(uc, RegisterARM::SP);
    let frame_size: u32 = if fpca { 0x68 } else { 0x20 };
    let force_align = ccr & system::CCR_STKALIGN != 0;
    let realigned = force_align && sp & 4 != 0;
    let align_mask = if force_align { !7 } else { !3 };
    let frame_pointer = sp.wrapping_sub(frame_size) & align_mask;
    let xpsr =
        (reg(uc, RegisterARM::XPSR) & !(1 << 9)) | (1 << 24) | if realigned { 1 << 9 } else { 0 };
    let mut words = vec![
        reg(uc, RegisterARM::R0),
        reg(uc, RegisterARM::R1),
        reg(uc, RegisterARM::R2),
        reg(uc, RegisterARM::R3),
        reg(uc, RegisterARM::R12),
        reg(uc, RegisterARM::LR),
        return_address & !1,
        xpsr,
    ];
    if fpca {
        for register in FP_REGISTERS {
            words.push(reg(uc, register));
        }
        words.push(reg(uc, RegisterARM::FPSCR));
        words.push(0);
    }
    let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
    if uc.mem_write(u64::from(frame_pointer), &bytes).is_err() {
        // A stacking error (MSTKERR/STKERR) escalates to HardFault.
        fault(
            uc,
            Fault::InstructionBus {
                address: frame_pointer,
            },
            return_address,
        );
        return;
    }
    set_reg(uc, RegisterARM::SP, frame_pointer);
    let mut exc_return = if handler {
        0xFFFF_FFF1
    } else if process_stack {
        0xFFFF_FFFD
    } else {
        0xFFFF_FFF9
    };
    if fpca {
        exc_return &= !0x10;
    }
    take(uc, n, exc_return);
}

/// Takes the pending exception of highest priority if it may preempt now, with
/// `return_address` stacked. Returns whether one was taken.
fn take_pending(uc: &mut Uc<'_>, return_address: u32) -> bool {
    if uc.get_data().system.exceptions.highest_pending().is_none() {
        uc.get_data_mut().attention = false;
        return false;
    }
    if reg(uc, RegisterARM::XPSR) & EPSR_IT != 0 {
        // Inside an IT block (a translated block can start there: QEMU ends one at a 1 KiB
        // boundary). QEMU keeps the IT state in the translated code and does not take it
        // back from a register write in a hook, so the exception waits for the block's end,
        // at most four instructions; `attention` stays set.
        return false;
    }
    let masks = masks(uc);
    let st = uc.get_data_mut();
    match st.system.exceptions.to_take(masks) {
        Some(n) => {
            enter(uc, n, return_address);
            true
        }
        None => {
            st.attention = st.system.exceptions.held_by_masks(masks);
            false
        }
    }
}

/// Exception return (B1.5.8): checks EXC_RETURN, deactivates the exception, tail-chains a
/// pending one that may preempt the code returned to, or unstacks the frame and restores
/// the mode, the stack pointer and the registers.
fn exception_return(uc: &mut Uc<'_>) {
    let exc_return = reg(uc, RegisterARM::PC) | 1;
    let returning = reg(uc, RegisterARM::IPSR) & 0x1FF;
    let invalid = |uc: &mut Uc<'_>, why: &'static str| {
        // The return address is unknown: name the handler that returned.
        let lr_site = reg(uc, RegisterARM::LR);
        fault(uc, Fault::InvalidReturn { exc_return, why }, lr_site);
    };
    let kind = exc_return & 0xF;
    if exc_return | 0x1F != 0xFFFF_FFFF || !matches!(kind, 0x1 | 0x9 | 0xD) {
        invalid(uc, "not an EXC_RETURN value");
        return;
    }
    if !uc.get_data().system.exceptions.is_active(returning) {
        invalid(uc, "the exception in IPSR is not active");
        return;
    }
    let control = uc.reg_read(RegisterARM::CONTROL).unwrap_or(0);
    if control & CONTROL_FPCA != 0 && !uc.get_data().system.fpu_enabled() {
        let pc = reg(uc, RegisterARM::LR);
        fault(uc, Fault::FloatingPointDisabled, pc);
        return;
    }
    {
        let st = uc.get_data_mut();
        st.system.exceptions.deactivate(returning);
    }
    // DeActivate: FAULTMASK is cleared on return from any exception but NMI.
    if returning != number::NMI {
        set_reg(uc, RegisterARM::FAULTMASK, 0);
    }
    let to_thread = kind != 0x1;
    let (active, nonbase) = {
        let system = &uc.get_data().system;
        (
            system.exceptions.active_count(),
            system.ccr() & system::CCR_NONBASETHRDENA != 0,
        )
    };
    if to_thread && active > 0 && !nonbase {
        invalid(uc, "it returns to Thread mode with other exceptions active");
        return;
    }
    if !to_thread && active == 0 {
        invalid(uc, "it returns to Handler mode with no exception active");
        return;
    }
    // Level-sensitive lines still asserted pend again.
    uc.get_data_mut().sample_all();
    // Tail-chaining: the frame stays, the next handler returns through it.
    let exec_masks = masks(uc);
    let chained = {
        let exceptions = &uc.get_data().system.exceptions;
        // The execution priority the code returned to would have.
        exceptions.to_take(exec_masks)
    };
    if let Some(n) = chained {
        take(uc, n, exc_return);
        return;
    }
    let process_stack = kind == 0xD;
    let extended = exc_return & 0x10 == 0;
    let frame_pointer = reg(
        uc,
        if process_stack {
            RegisterARM::PSP
        } else {
            RegisterARM::MSP
        },
    );
    let frame_size: u32 = if extended { 0x68 } else { 0x20 };
    let mut bytes = vec![0u8; frame_size as usize];
    if uc.mem_read(u64::from(frame_pointer), &mut bytes).is_err() {
        invalid(uc, "its frame cannot be read (BusFault UNSTKERR)");
        return;
    }
    let word = |i: usize| {
        u32::from_le_bytes([
            bytes[4 * i],
            bytes[4 * i + 1],
            bytes[4 * i + 2],
            bytes[4 * i + 3],
        ])
    };
    let (pc, xpsr) = (word(6), word(7));
    let stacked_ipsr = xpsr & 0x1FF;
    if to_thread != (stacked_ipsr == 0) {
        invalid(
            uc,
            "the stacked IPSR does not match the mode returned to (integrity check)",
        );
        return;
    }
    set_reg(uc, RegisterARM::XPSR_NZCVQG, xpsr);
    refresh_state_flags(uc);
    let control = uc.reg_read(RegisterARM::CONTROL).unwrap_or(0);
    let mut new_control = control & !(CONTROL_SPSEL | CONTROL_FPCA);
    if process_stack {
        new_control |= CONTROL_SPSEL;
    }
    if extended {
        new_control |= CONTROL_FPCA;
    }
    let _ = uc.reg_write(RegisterARM::CONTROL, new_control);
    let realigned = if xpsr & (1 << 9) != 0 { 4 } else { 0 };
    let new_sp = frame_pointer.wrapping_add(frame_size) | realigned;
    set_reg(
        uc,
        if process_stack {
            RegisterARM::PSP
        } else {
            RegisterARM::MSP
        },
        new_sp,
    );
    for (i, register) in [
        RegisterARM::R0,
        RegisterARM::R1,
        RegisterARM::R2,
        RegisterARM::R3,
        RegisterARM::R12,
        RegisterARM::LR,
    ]
    .into_iter()
    .enumerate()
    {
        set_reg(uc, register, word(i));
    }
    if extended {
        for (i, register) in FP_REGISTERS.into_iter().enumerate() {
            set_reg(uc, register, word(8 + i));
        }
        set_reg(uc, RegisterARM::FPSCR, word(24));
    }
    if xpsr & (1 << 24) == 0 {
        fault(uc, Fault::InvalidState, pc);
        return;
    }
    set_reg(uc, RegisterARM::PC, pc | 1);
    let st = uc.get_data_mut();
    st.event_register = true;
    st.attention = true;
    if to_thread && st.system.scr() & system::SCR_SLEEPONEXIT != 0 {
        // Sleep-on-exit (B1.5.19): back to sleep instead of Thread mode's code.
        st.fall_asleep(Sleep::Interrupt);
        st.stopping = true;
        let _ = uc.emu_stop();
    }
}

/// Brings everything due to the present: SysTick, the models whose event has come, the
/// clock tree; pends what they raise; computes the next deadline.
fn service(uc: &mut Uc<'_>) {
    let st = uc.get_data_mut();
    st.recompute = false;
    let cycles = st.clock.cycles();
    st.system.catch_up(cycles);
    if st.system.exceptions.is_pending(number::SYSTICK) {
        st.attention = true;
    }
    let ctx = st.context();
    let models: Vec<_> = st.blocks.iter().map(|b| b.model.clone()).collect();
    for model in &models {
        let due = model
            .borrow()
            .next_event(&ctx)
            .is_some_and(|at| at <= ctx.now);
        if due {
            model.borrow_mut().advance(&ctx);
        }
        st.sample(&*model.borrow());
    }
    st.follow_clock_tree();
    while let Some(word) = st.models.usart.borrow_mut().take_transmitted() {
        if st.usart_wired {
            st.usart_out.push(word);
        } else {
            st.usart_words += 1;
        }
    }
    let ctx = st.context();
    let mut deadline = st.end;
    if let Some(at) = st.system.next_event() {
        deadline = deadline.min(at);
    }
    for model in &models {
        if let Some(at) = model.borrow().next_event(&ctx) {
            deadline = deadline.min(st.clock.cycles_at(at));
        }
    }
    // An event due now that a model did not consume must not stall time.
    st.deadline = deadline.max(cycles + 1).min(st.end.max(cycles + 1));
    after_flash_access(uc);
    let st = uc.get_data_mut();
    if st.models.iwdg.borrow().reset_requested() {
        let pc = reg(uc, RegisterARM::PC);
        let st = uc.get_data_mut();
        let at = st.describe(pc);
        st.set_stop(Stop::Reset {
            cause: ResetCause::IndependentWatchdog,
            at,
        });
    }
}

/// Moves what the image logged into the machine's log.
fn drain_rtt(uc: &mut Uc<'_>) {
    struct UcMemory<'a, 'b>(&'a mut Uc<'b>);
    impl crate::rtt::Memory for UcMemory<'_, '_> {
        fn read(&mut self, address: u32, buf: &mut [u8]) -> bool {
            memory::is_ram(address) && self.0.mem_read(u64::from(address), buf).is_ok()
        }
        fn write(&mut self, address: u32, bytes: &[u8]) -> bool {
            memory::is_ram(address) && self.0.mem_write(u64::from(address), bytes).is_ok()
        }
    }
    let Some(control_block) = uc.get_data().rtt else {
        return;
    };
    let bytes = crate::rtt::drain(&mut UcMemory(uc), control_block);
    let st = uc.get_data_mut();
    st.next_drain = st.instructions + DRAIN_EVERY;
    if !bytes.is_empty() {
        let now = st.clock.now();
        st.log.push((now, bytes));
    }
}

fn on_block(uc: &mut Uc<'_>, address: u64, size: u32) {
    let address = address as u32;
    let key = (address, size);
    let count = match uc.get_data().lengths.get(&key) {
        Some(&count) => count,
        None => {
            let mut bytes = vec![0u8; size as usize];
            let count = if uc.mem_read(u64::from(address), &mut bytes).is_ok() {
                count_instructions(&bytes)
            } else {
                1
            };
            uc.get_data_mut().lengths.insert(key, count);
            count
        }
    };
    // Instruction fetches from flash stall while it is programmed or erased (RM0090 3.6).
    let fetch_stalls = uc
        .get_data()
        .flash_busy_until
        .is_some_and(|end| end > uc.get_data().clock.now());
    if fetch_stalls && address < memory::FLASH + memory::FLASH_SIZE {
        flash_stall(uc);
        service(uc);
    }
    let (due, attention, drain) = {
        let st = uc.get_data();
        (
            st.clock.cycles() >= st.deadline || st.recompute,
            st.attention,
            st.instructions >= st.next_drain,
        )
    };
    if drain {
        drain_rtt(uc);
    }
    if due {
        service(uc);
    }
    {
        let st = uc.get_data_mut();
        if st.stop.is_some() || st.clock.cycles() >= st.end {
            st.stopping = true;
            let _ = uc.emu_stop();
            return;
        }
    }
    if (attention || uc.get_data().attention) && take_pending(uc, address) {
        return;
    }
    if uc.get_data().profile.is_some() {
        let sp = reg(uc, RegisterARM::SP);
        if let Some(profile) = uc.get_data_mut().profile.as_mut() {
            profile.block(address, count, sp);
        }
    }
    let st = uc.get_data_mut();
    st.clock.add(u64::from(count));
    st.instructions += u64::from(count);
}

fn on_interrupt(uc: &mut Uc<'_>, number: u32) {
    let pc = reg(uc, RegisterARM::PC);
    match number {
        // EXCP_EXCEPTION_EXIT.
        8 => exception_return(uc),
        // EXCP_SWI: SVCall, synchronous, with the PC already after the `svc`.
        2 => {
            uc.get_data_mut()
                .system
                .exceptions
                .set_pending(number::SVCALL, true);
            let masks = masks(uc);
            if uc.get_data().system.exceptions.to_take(masks) == Some(number::SVCALL) {
                enter(uc, number::SVCALL, pc);
            } else {
                fault(
                    uc,
                    Fault::Escalated {
                        exception: number::SVCALL,
                    },
                    pc,
                );
            }
        }
        // EXCP_BKPT.
        7 => fault(uc, Fault::Breakpoint, pc),
        // EXCP_PREFETCH_ABORT.
        3 => fault(uc, Fault::InstructionBus { address: pc }, pc),
        // EXCP_UDEF, EXCP_NOCP.
        1 => fault(uc, Fault::UndefinedInstruction, pc),
        17 => fault(uc, Fault::FloatingPointDisabled, pc),
        // EXCP_INVSTATE.
        18 => fault(uc, Fault::InvalidState, pc),
        // EXCP_UNALIGNED.
        22 => fault(uc, Fault::Unaligned, pc),
        other => fault(uc, Fault::Other(other), pc),
    }
}

/// `wfe`, `yield`, an undefined instruction, or an invalid state: QEMU's "stop" exceptions.
fn on_invalid(uc: &mut Uc<'_>) -> bool {
    let pc = reg(uc, RegisterARM::PC);
    let instructions = uc.get_data().instructions;
    let repeated = uc.get_data().last_invalid == Some((pc, instructions));
    uc.get_data_mut().last_invalid = Some((pc, instructions));
    // EPSR.T clear (CPSR bit 5 in QEMU's view): INVSTATE.
    if reg(uc, RegisterARM::CPSR) & (1 << 5) == 0 {
        fault(uc, Fault::InvalidState, pc);
        return false;
    }
    let before = read_half(uc, pc.wrapping_sub(2));
    let wide = (
        read_half(uc, pc.wrapping_sub(4)),
        read_half(uc, pc.wrapping_sub(2)),
    );
    let is = |narrow: u16, wide_second: u16| {
        before == Some(narrow) || wide == (Some(0xF3AF), Some(wide_second))
    };
    if !repeated && is(0xBF20, 0x8002) {
        // WFE (B1.5.18): consumes the event register, or sleeps until an event.
        let st = uc.get_data_mut();
        if st.event_register {
            st.event_register = false;
        } else {
            st.fall_asleep(Sleep::Event);
            st.stopping = true;
            let _ = uc.emu_stop();
        }
        return true;
    }
    if !repeated && is(0xBF10, 0x8001) {
        // YIELD: a hint, nothing to do.
        return true;
    }
    fault(uc, Fault::UndefinedInstruction, pc);
    false
}

/// A data access no memory or model claims.
fn on_unmapped(uc: &mut Uc<'_>, kind: MemType, address: u64, size: usize, value: i64) -> bool {
    let pc = reg(uc, RegisterARM::PC);
    let address = address as u32;
    if matches!(kind, MemType::FETCH_UNMAPPED) {
        fault(uc, Fault::InstructionBus { address }, pc);
        return false;
    }
    let written = matches!(kind, MemType::WRITE_UNMAPPED).then_some(value as u32);
    let st = uc.get_data_mut();
    let at = st.describe(pc);
    st.set_stop(Stop::Unclaimed {
        access: Access {
            address,
            size: size as u32,
            written,
        },
        at,
    });
    st.stopping = true;
    false
}

/// A CPU write to flash (or its boot alias): the flash interface model programs it, or
/// refuses it with the error flag RM0090 3.6 names. The store itself never lands: the
/// array changes when the model's program operation ends ([`sync_flash`]).
fn on_flash_write(uc: &mut Uc<'_>, address: u64, size: usize, value: i64) -> bool {
    let address = address as u32;
    let address = if address < memory::FLASH {
        address + memory::FLASH
    } else {
        address
    };
    flash_stall(uc);
    let st = uc.get_data_mut();
    let ctx = st.context();
    let model = st.models.flash.clone();
    model
        .borrow_mut()
        .program(address, size as u32, value as u64, &ctx);
    st.sample(&*model.borrow());
    st.recompute = true;
    st.flash_dirty = true;
    after_flash_access(uc);
    true
}

/// An access to the flash array or to FLASH_CR while an operation is in progress stalls the
/// bus until it ends (RM0090 3.6): virtual time moves to its end.
fn flash_stall(uc: &mut Uc<'_>) {
    let st = uc.get_data_mut();
    if let Some(end) = st.flash_busy_until {
        let cycles = st.clock.cycles_at(end);
        st.clock.advance_to(cycles);
        st.recompute = true;
    }
}

/// After the flash model ran: its bus errors and the armed power cut stop the run, a finished
/// operation's array goes to Unicorn.
fn after_flash_access(uc: &mut Uc<'_>) {
    let pc = reg(uc, RegisterARM::PC);
    let st = uc.get_data_mut();
    let model = st.models.flash.clone();
    let mut flash = model.borrow_mut();
    let busy = flash.busy_until();
    if st.flash_busy_until.is_some() && busy.is_none() {
        st.flash_dirty = true;
    }
    st.flash_busy_until = busy;
    let bus_error = flash.take_bus_error();
    let power_lost = flash.power_lost();
    drop(flash);
    if power_lost {
        let at = st.describe(pc);
        st.set_stop(Stop::PowerLost { at });
        st.stopping = true;
        let _ = uc.emu_stop();
    } else if bus_error {
        fault(uc, Fault::BusError, pc);
    }
    sync_flash(uc);
}

/// Copies what the flash model's array changed into Unicorn's flash and its boot alias.
fn sync_flash(uc: &mut Uc<'_>) {
    if !uc.get_data().flash_dirty {
        return;
    }
    const CHUNK: usize = 4096;
    let st = uc.get_data_mut();
    st.flash_dirty = false;
    let model = st.models.flash.clone();
    let flash = model.borrow();
    let mut changed = Vec::new();
    for (index, (now, was)) in flash
        .memory()
        .chunks(CHUNK)
        .zip(st.flash_shadow.chunks_mut(CHUNK))
        .enumerate()
    {
        if now != was {
            was.copy_from_slice(now);
            changed.push((index * CHUNK, now.to_vec()));
        }
    }
    drop(flash);
    if !changed.is_empty() {
        uc.get_data_mut().lengths.clear();
    }
    for (offset, bytes) in changed {
        let _ = uc.mem_write(u64::from(memory::FLASH) + offset as u64, &bytes);
        let _ = uc.mem_write(u64::from(memory::BOOT_ALIAS) + offset as u64, &bytes);
    }
}

/// APB1 and APB2 (RM0090 2.3, Table 1): behind the AHB/APB bridges.
fn on_apb(address: u32) -> bool {
    (0x4000_0000..0x4001_8000).contains(&address)
}

/// A read through the memory map: the AHB/APB bridges turn a byte or half-word access into a
/// word access of the whole register (RM0090 10.3.11, "Addressing an AHB peripheral that does
/// not support byte or halfword write operations"); the core takes its lane.
fn mmio_read(uc: &mut Uc<'_>, address: u32, size: u32) -> u64 {
    let reported = Access {
        address,
        size,
        written: None,
    };
    if on_apb(address) && size < 4 {
        let word = device_read(uc, address & !3, 4, reported);
        let lane = word >> (8 * (address & 3));
        return lane & ((1u64 << (8 * size)) - 1);
    }
    device_read(uc, address, size, reported)
}

/// A write through the memory map: on APB, a byte or half-word write reaches the register as
/// a word write with the data repeated in every lane (RM0090 10.3.11, as for reads).
fn mmio_write(uc: &mut Uc<'_>, address: u32, size: u32, value: u32) {
    let reported = Access {
        address,
        size,
        written: Some(value),
    };
    if on_apb(address) && size < 4 {
        let repeated = match size {
            1 => (value & 0xFF) * 0x0101_0101,
            _ => (value & 0xFFFF) * 0x0001_0001,
        };
        device_write(uc, address & !3, 4, repeated, reported);
        return;
    }
    device_write(uc, address, size, value, reported);
}

/// After a model's access: the lines it holds up pended, the clock tree followed (RCC, PWR),
/// its next event brought into the deadline (an access can only make it earlier or later;
/// a later one costs one early service, which recomputes).
fn after_model_access(st: &mut State, base: u32, model: &RefCell<dyn Peripheral>) {
    st.sample(&*model.borrow());
    if base == rcc::BASE || base == pwr::BASE {
        st.follow_clock_tree();
        st.recompute = true;
    }
    if let Some(at) = model.borrow().next_event(&st.context()) {
        st.deadline = st.deadline.min(st.clock.cycles_at(at));
    }
}

/// After an access to the system part: a pending change is looked at before the next block,
/// SysTick's next event brought into the deadline.
fn after_system_access(st: &mut State) {
    st.attention = true;
    if let Some(at) = st.system.next_event() {
        st.deadline = st.deadline.min(at);
    }
}

/// A read of a peripheral block or the private peripheral bus; `reported` is the core's
/// access, for sentences.
fn device_read(uc: &mut Uc<'_>, address: u32, size: u32, reported: Access) -> u64 {
    if uc.get_data().stop.is_some() {
        return 0;
    }
    let result = if is_system(address) {
        let ipsr = reg(uc, RegisterARM::IPSR) & 0x1FF;
        let st = uc.get_data_mut();
        let core = st.core(ipsr);
        let result = st.system.read(address, size, core);
        after_system_access(st);
        result
    } else {
        let st = uc.get_data_mut();
        match st.find(address).map(|b| (b.base, b.model.clone())) {
            Some((base, model)) => {
                if base == flash::BASE && address - base == FLASH_CR {
                    flash_stall(uc);
                }
                let st = uc.get_data_mut();
                let ctx = st.context();
                let result = {
                    let mut model = model.borrow_mut();
                    model.advance(&ctx);
                    model.read(&ctx, address - base, size)
                };
                after_model_access(st, base, &model);
                if base == flash::BASE {
                    after_flash_access(uc);
                }
                result
            }
            None => {
                unclaimed(uc, reported);
                return 0;
            }
        }
    };
    match result {
        Ok(value) => u64::from(value),
        Err(error) => {
            refused(uc, reported, error);
            0
        }
    }
}

/// A write to a peripheral block or the private peripheral bus; `reported` is the core's
/// access, for sentences.
fn device_write(uc: &mut Uc<'_>, address: u32, size: u32, value: u32, reported: Access) {
    if uc.get_data().stop.is_some() {
        return;
    }
    let result = if is_system(address) {
        let ipsr = reg(uc, RegisterARM::IPSR) & 0x1FF;
        let st = uc.get_data_mut();
        let core = st.core(ipsr);
        let result = st.system.write(address, size, value, core);
        after_system_access(st);
        match result {
            Ok(effects) if effects.system_reset => {
                let pc = reg(uc, RegisterARM::PC);
                let st = uc.get_data_mut();
                let at = st.symbols.describe_block(pc);
                st.set_stop(Stop::Reset {
                    cause: ResetCause::Software,
                    at,
                });
                st.stopping = true;
                let _ = uc.emu_stop();
                Ok(())
            }
            Ok(_) => Ok(()),
            Err(error) => Err(error),
        }
    } else {
        let st = uc.get_data_mut();
        match st.find(address).map(|b| (b.base, b.model.clone())) {
            Some((base, model)) => {
                if base == flash::BASE && address - base == FLASH_CR {
                    flash_stall(uc);
                }
                let st = uc.get_data_mut();
                let ctx = st.context();
                let requests = st.models.can.borrow().transmit_requests();
                let result = {
                    let mut model = model.borrow_mut();
                    model.advance(&ctx);
                    model.write(&ctx, address - base, size, value)
                };
                after_model_access(st, base, &model);
                let yield_now = st.yield_on_transmit
                    && base == bxcan::BASE
                    && st.models.can.borrow().transmit_requests() != requests;
                if yield_now {
                    // The bus model must see the request at this instant (arbitration
                    // starts when the bus is idle): end the run at the next translated
                    // block, whose hook stops it with the program counter exact. Stopped
                    // here, inside a memory-mapped access, the run ended with the program
                    // counter at the start of the block that holds the store (Unicorn does
                    // not sync it for these accesses) and resumed there, running the
                    // block's instructions before the store a second time on registers
                    // they had already changed. The block's time was counted at its start.
                    st.yielded = true;
                    st.end = st.clock.cycles();
                }
                let st = uc.get_data_mut();
                if base == flash::BASE {
                    st.flash_dirty = true;
                    after_flash_access(uc);
                }
                result
            }
            None => {
                unclaimed(uc, reported);
                return;
            }
        }
    };
    if let Err(error) = result {
        refused(uc, reported, error);
    }
}

fn is_system(address: u32) -> bool {
    (system::SCS_BASE..system::SCS_BASE + 0x1000).contains(&address)
        || (system::DWT_BASE..system::DWT_BASE + 0x1000).contains(&address)
}

fn unclaimed(uc: &mut Uc<'_>, access: Access) {
    let pc = reg(uc, RegisterARM::PC);
    let st = uc.get_data_mut();
    let at = st.symbols.describe_block(pc);
    st.set_stop(Stop::Unclaimed { access, at });
    st.stopping = true;
    let _ = uc.emu_stop();
}

fn refused(uc: &mut Uc<'_>, access: Access, error: AccessError) {
    let pc = reg(uc, RegisterARM::PC);
    let st = uc.get_data_mut();
    let at = st.symbols.describe_block(pc);
    st.set_stop(Stop::Refused { access, error, at });
    st.stopping = true;
    let _ = uc.emu_stop();
}

/// The addresses of `sev` instructions in `code` at `base` (half-word aligned: 16-bit
/// `0xBF40`, 32-bit `0xF3AF 0x8004`). A data half-word that looks like one costs a hook
/// that never fires.
fn sev_addresses(base: u32, code: &[u8]) -> Vec<u32> {
    let half = |at: usize| {
        code.get(at..at + 2)
            .map(|b| u16::from_le_bytes([b[0], b[1]]))
    };
    (0..code.len())
        .step_by(2)
        .filter(|&at| {
            half(at) == Some(0xBF40) || (half(at) == Some(0xF3AF) && half(at + 2) == Some(0x8004))
        })
        .map(|at| base + at as u32)
        .collect()
}

impl Machine {
    /// An STM32F405 on `config`'s board, powered but not reset: flash erased, RAM zero, the
    /// peripherals at their reset values.
    pub fn new(config: Config) -> Result<Machine, EngineError> {
        let rcc = Rc::new(RefCell::new(Rcc::new(config.hse)));
        let pwr = Rc::new(RefCell::new(Pwr::new()));
        let gpio = [Port::A, Port::B, Port::C].map(|port| Rc::new(RefCell::new(Gpio::new(port))));
        let iwdg = Rc::new(RefCell::new(Iwdg::new()));
        let usart = Rc::new(RefCell::new(Usart::new()));
        let can = Rc::new(RefCell::new(Can::new()));
        let flash = Rc::new(RefCell::new(Flash::new()));
        let tim2 = Rc::new(RefCell::new(Tim2::new()));
        let state = State {
            clock: CycleClock::new(Clocks::RESET.hclk),
            instructions: 0,
            clocks: Clocks::RESET,
            system: SystemControl::new(),
            blocks: Vec::new(),
            models: Models {
                rcc: rcc.clone(),
                pwr: pwr.clone(),
                gpio: gpio.clone(),
                iwdg: iwdg.clone(),
                usart: usart.clone(),
                can: can.clone(),
                flash: flash.clone(),
                tim2: tim2.clone(),
            },
            stop: None,
            end: 0,
            deadline: 0,
            recompute: true,
            attention: false,
            stopping: false,
            sleep: None,
            event_register: false,
            lengths: HashMap::new(),
            symbols: Symbols::default(),
            rtt: None,
            log: Vec::new(),
            next_drain: 0,
            mapped_pages: Vec::new(),
            last_invalid: None,
            usart_words: 0,
            usart_wired: false,
            usart_out: Vec::new(),
            yield_on_transmit: false,
            yielded: false,
            hung_until: 0,
            wake_ups: 0,
            flash_shadow: vec![0xFF; memory::FLASH_SIZE as usize],
            flash_dirty: false,
            flash_busy_until: None,
            profile: None,
            activations: Activations::default(),
            initial_sp: 0,
        };
        let mut uc = Unicorn::new_with_data(Arch::ARM, Mode::THUMB | Mode::LITTLE_ENDIAN, state)
            .map_err(engine("start"))?;
        uc.ctl_set_cpu_model(ArmCpuModel::CORTEX_M4 as i32)
            .map_err(engine("select the Cortex-M4"))?;
        let read_exec = Prot::READ | Prot::EXEC;
        uc.mem_map(
            u64::from(memory::FLASH),
            u64::from(memory::FLASH_SIZE),
            read_exec,
        )
        .map_err(engine("map flash"))?;
        uc.mem_map(
            u64::from(memory::BOOT_ALIAS),
            u64::from(memory::FLASH_SIZE),
            read_exec,
        )
        .map_err(engine("map the boot alias"))?;
        uc.mem_map(
            u64::from(memory::SRAM),
            u64::from(memory::SRAM_SIZE),
            Prot::ALL,
        )
        .map_err(engine("map SRAM"))?;
        uc.mem_map(
            u64::from(memory::CCM),
            u64::from(memory::CCM_SIZE),
            Prot::READ | Prot::WRITE,
        )
        .map_err(engine("map CCM RAM"))?;
        let erased = vec![0xFFu8; memory::FLASH_SIZE as usize];
        uc.mem_write(u64::from(memory::FLASH), &erased)
            .map_err(engine("erase flash"))?;
        uc.mem_write(u64::from(memory::BOOT_ALIAS), &erased)
            .map_err(engine("erase the boot alias"))?;
        uc.add_block_hook(1, 0, on_block)
            .map_err(engine("hook blocks"))?;
        uc.add_intr_hook(on_interrupt)
            .map_err(engine("hook exceptions"))?;
        uc.add_insn_invalid_hook(on_invalid)
            .map_err(engine("hook invalid instructions"))?;
        uc.add_mem_hook(HookType::MEM_UNMAPPED, 1, 0, on_unmapped)
            .map_err(engine("hook unmapped memory"))?;
        uc.add_mem_hook(
            HookType::MEM_WRITE_PROT,
            0,
            u64::from(memory::FLASH + memory::FLASH_SIZE - 1),
            |uc, _, address, size, value| on_flash_write(uc, address, size, value),
        )
        .map_err(engine("hook flash writes"))?;
        uc.add_mem_hook(HookType::MEM_FETCH_PROT, 1, 0, |uc, _, address, _, _| {
            let pc = reg(uc, RegisterARM::PC);
            fault(
                uc,
                Fault::InstructionBus {
                    address: address as u32,
                },
                pc,
            );
            false
        })
        .map_err(engine("hook fetches"))?;
        let mut machine = Machine { uc };
        machine.attach(rcc::BASE, rcc::SIZE, rcc)?;
        machine.attach(pwr::BASE, pwr::SIZE, pwr)?;
        for model in gpio {
            let base = model.borrow().port().base();
            machine.attach(base, gpio::SIZE, model)?;
        }
        machine.attach(iwdg::BASE, iwdg::SIZE, iwdg)?;
        machine.attach(usart::BASE, usart::SIZE, usart)?;
        machine.attach(bxcan::BASE, bxcan::SIZE, can)?;
        machine.attach(flash::BASE, flash::SIZE, flash)?;
        machine.attach(tim2::BASE, tim2::SIZE, tim2)?;
        machine.attach(
            dbgmcu::BASE,
            dbgmcu::SIZE,
            Rc::new(RefCell::new(Dbgmcu::new())),
        )?;
        for page in [system::SCS_BASE, system::DWT_BASE] {
            machine.map_page(page)?;
        }
        Ok(machine)
    }

    /// Routes `size` bytes from `base` to `model`.
    pub fn attach(
        &mut self,
        base: u32,
        size: u32,
        model: Rc<RefCell<dyn Peripheral>>,
    ) -> Result<(), EngineError> {
        let first = base & !(memory::PAGE - 1);
        let last = (base + size - 1) & !(memory::PAGE - 1);
        let mut page = first;
        while page <= last {
            self.map_page(page)?;
            page += memory::PAGE;
        }
        self.uc
            .get_data_mut()
            .blocks
            .push(Block { base, size, model });
        Ok(())
    }

    fn map_page(&mut self, page: u32) -> Result<(), EngineError> {
        if self.uc.get_data().mapped_pages.contains(&page) {
            return Ok(());
        }
        self.uc
            .mmio_map(
                u64::from(page),
                u64::from(memory::PAGE),
                Some(move |uc: &mut Uc<'_>, offset: u64, size: usize| {
                    mmio_read(uc, page + offset as u32, size as u32)
                }),
                Some(
                    move |uc: &mut Uc<'_>, offset: u64, size: usize, value: u64| {
                        mmio_write(uc, page + offset as u32, size as u32, value as u32)
                    },
                ),
            )
            .map_err(engine("map a peripheral page"))?;
        self.uc.get_data_mut().mapped_pages.push(page);
        Ok(())
    }

    /// Writes `bytes` into flash at `address` (and its boot alias), as a programmer would.
    pub fn write_flash(&mut self, address: u32, bytes: &[u8]) -> Result<(), EngineError> {
        let offset = address.wrapping_sub(memory::FLASH);
        self.uc
            .mem_write(u64::from(address), bytes)
            .map_err(engine("write flash"))?;
        self.uc
            .mem_write(u64::from(memory::BOOT_ALIAS + offset), bytes)
            .map_err(engine("write the boot alias"))?;
        let st = self.uc.get_data_mut();
        st.lengths.clear();
        let range = offset as usize..offset as usize + bytes.len();
        st.models.flash.borrow_mut().memory_mut()[range.clone()].copy_from_slice(bytes);
        st.flash_shadow[range].copy_from_slice(bytes);
        for sev in sev_addresses(address, bytes) {
            self.uc
                .add_code_hook(u64::from(sev), u64::from(sev), |uc, _, _| {
                    uc.get_data_mut().event_register = true;
                })
                .map_err(engine("hook a sev"))?;
        }
        Ok(())
    }

    /// Writes `bytes` into RAM at `address`.
    pub fn write_memory(&mut self, address: u32, bytes: &[u8]) -> Result<(), EngineError> {
        self.uc
            .mem_write(u64::from(address), bytes)
            .map_err(engine("write memory"))
    }

    /// Reads `length` bytes of memory at `address` (`None`: not memory).
    pub fn read_memory(&self, address: u32, length: usize) -> Option<Vec<u8>> {
        self.uc.mem_read_as_vec(u64::from(address), length).ok()
    }

    /// Loads a sealed image: its flash contents, its symbols (for sentences), its RTT
    /// control block (for the log).
    pub fn load(&mut self, image: &Image) -> Result<(), EngineError> {
        for segment in &image.segments {
            self.write_flash(segment.address, &segment.bytes)?;
        }
        let st = self.uc.get_data_mut();
        st.symbols = image.symbols.clone();
        st.rtt = image.rtt;
        Ok(())
    }

    /// Names the code at addresses after these symbols.
    pub fn set_symbols(&mut self, symbols: Symbols) {
        self.uc.get_data_mut().symbols = symbols;
    }

    /// The power-on reset (B1.5.5): the main stack pointer and the PC from the vector table
    /// at 0 (flash, through the boot alias), Thread mode, privileged, nothing pending. For a
    /// new machine: a reset during a run (the watchdog's, SYSRESETREQ) ends the run instead
    /// ([`Stop::Reset`]).
    pub fn reset(&mut self) -> Result<(), Stop> {
        let sp = read_word(&self.uc, memory::BOOT_ALIAS);
        let pc = read_word(&self.uc, memory::BOOT_ALIAS + 4);
        let (Some(sp), Some(pc)) = (sp, pc) else {
            return Err(Stop::HardFault {
                fault: Fault::BadVector {
                    exception: number::RESET,
                    address: memory::BOOT_ALIAS,
                    value: None,
                },
                at: "reset".to_owned(),
            });
        };
        if pc & 1 == 0 {
            return Err(Stop::HardFault {
                fault: Fault::BadVector {
                    exception: number::RESET,
                    address: memory::BOOT_ALIAS + 4,
                    value: Some(pc),
                },
                at: "reset".to_owned(),
            });
        }
        let uc = &mut self.uc;
        set_reg(uc, RegisterARM::IPSR, 0);
        let _ = uc.reg_write(RegisterARM::CONTROL, 0);
        refresh_state_flags(uc);
        set_reg(uc, RegisterARM::MSP, sp & !3);
        set_reg(uc, RegisterARM::PRIMASK, 0);
        set_reg(uc, RegisterARM::FAULTMASK, 0);
        set_reg(uc, RegisterARM::BASEPRI, 0);
        set_reg(uc, RegisterARM::LR, 0xFFFF_FFFF);
        set_reg(uc, RegisterARM::PC, pc);
        let st = uc.get_data_mut();
        let now = st.clock.now();
        st.activations.reset(now);
        st.initial_sp = sp & !3;
        st.system = SystemControl::new();
        st.hung_until = 0;
        st.stop = None;
        st.sleep = None;
        st.event_register = false;
        st.recompute = true;
        Ok(())
    }

    /// Arms a power cut during flash program or erase operation `step` (counted since the
    /// last power-on), torn as `seed` chooses ([`Flash::cut_power_at`]): the run stops with
    /// [`Stop::PowerLost`] there.
    pub fn cut_power_at(&mut self, step: u64, seed: u64) {
        self.uc
            .get_data()
            .models
            .flash
            .borrow_mut()
            .cut_power_at(step, seed);
    }

    /// Flash program and erase operations started since the last power-on.
    pub fn flash_operations(&self) -> u64 {
        self.uc
            .get_data()
            .models
            .flash
            .borrow()
            .operations_started()
    }

    /// The flash array as it stands (1 MiB from 0800_0000h).
    pub fn flash_array(&self) -> Vec<u8> {
        self.uc.get_data().models.flash.borrow().memory().to_vec()
    }

    /// Power back on after a power loss: [`Machine::system_reset`] for a power-on (RCC_CSR:
    /// PORRSTF, PINRSTF, BORRSTF), SRAM and CCM cleared (their contents are not kept without
    /// power), the flash array as the loss left it.
    pub fn power_on_again(&mut self) -> Result<(), Stop> {
        for (base, size) in [
            (memory::SRAM, memory::SRAM_SIZE),
            (memory::CCM, memory::CCM_SIZE),
        ] {
            self.uc
                .mem_write(u64::from(base), &vec![0; size as usize])
                .map_err(|error| Stop::Engine {
                    error: format!("{error:?}"),
                    at: "power-on".to_owned(),
                })?;
        }
        self.uc.get_data_mut().stop = None;
        self.system_reset(ResetCause::PowerOn)
    }

    /// A system reset for `cause` (the watchdog's, or software's SYSRESETREQ), as the MCU
    /// takes it (RM0090 7.1.2): every peripheral back to its reset state except what a
    /// system reset keeps — the RCC's reset flags gain the cause's (RM0090 7.3.21, CSR), the
    /// flash array stays, SRAM keeps its contents, the DBGMCU register and the backup domain
    /// are untouched, the board keeps driving its pins — then the core starts from the
    /// vector table again on the 16 MHz HSI.
    pub fn system_reset(&mut self, cause: ResetCause) -> Result<(), Stop> {
        {
            let st = self.uc.get_data_mut();
            let now = st.clock.now();
            let models = &st.models;
            let rcc = models.rcc.borrow().after_reset(cause, now);
            *models.rcc.borrow_mut() = rcc;
            *models.pwr.borrow_mut() = Pwr::new();
            for port in &models.gpio {
                let fresh = port.borrow().after_reset();
                *port.borrow_mut() = fresh;
            }
            *models.iwdg.borrow_mut() = Iwdg::new();
            *models.usart.borrow_mut() = Usart::new();
            *models.can.borrow_mut() = Can::new();
            let flash = models.flash.borrow().after_reset();
            *models.flash.borrow_mut() = flash;
            *models.tim2.borrow_mut() = Tim2::new();
            st.flash_busy_until = None;
            st.flash_dirty = true;
            st.follow_clock_tree();
            st.usart_out.clear();
        }
        // What an operation left in the array is what the core reads from now on.
        sync_flash(&mut self.uc);
        self.reset()
    }

    /// Runs for `duration` of virtual time (or until something stops the run).
    pub fn run_for(&mut self, duration: Nanos) -> Outcome {
        let until = self.now().saturating_add(duration);
        self.run_until(until)
    }

    /// Runs until virtual time `until` (or until something stops the run).
    pub fn run_until(&mut self, until: Nanos) -> Outcome {
        loop {
            let st = self.uc.get_data_mut();
            if let Some((stop, at)) = st.stop.clone() {
                drain_rtt(&mut self.uc);
                return Outcome::Stopped { stop, at };
            }
            if std::mem::take(&mut st.yielded) {
                drain_rtt(&mut self.uc);
                return Outcome::Yielded;
            }
            st.end = st.clock.cycles_at(until);
            if st.clock.cycles() >= st.end {
                drain_rtt(&mut self.uc);
                return Outcome::Elapsed;
            }
            service(&mut self.uc);
            if self.uc.get_data().stop.is_some() {
                continue;
            }
            let st = self.uc.get_data_mut();
            if st.hung_until > st.clock.now() {
                // Hung: time and the peripherals go on (the watchdog counts down), the core
                // does nothing.
                let next = st
                    .deadline
                    .min(st.end)
                    .min(st.clock.cycles_at(st.hung_until));
                st.clock.advance_to(next.max(st.clock.cycles() + 1));
                st.recompute = true;
                continue;
            }
            if let Some(sleep) = self.uc.get_data().sleep {
                self.sleep_step(sleep);
                continue;
            }
            let pc = reg(&self.uc, RegisterARM::PC);
            if self.uc.get_data().attention {
                take_pending(&mut self.uc, pc);
                if self.uc.get_data().stop.is_some() {
                    continue;
                }
            }
            self.uc.get_data_mut().stopping = false;
            let pc = reg(&self.uc, RegisterARM::PC);
            let result = self.uc.emu_start(u64::from(pc | 1), NEVER, 0, 0);
            let after = reg(&self.uc, RegisterARM::PC);
            let st = self.uc.get_data();
            let (stopping, sleeping, stopped) =
                (st.stopping, st.sleep.is_some(), st.stop.is_some());
            match result {
                Err(error) if !stopped => {
                    let st = self.uc.get_data_mut();
                    let at = st.describe(after);
                    st.set_stop(Stop::Engine {
                        error: format!("{error:?}"),
                        at,
                    });
                }
                Ok(()) if !stopping && !sleeping && !stopped => {
                    let wfi = read_half(&self.uc, after.wrapping_sub(2)) == Some(0xBF30)
                        || (read_half(&self.uc, after.wrapping_sub(4)) == Some(0xF3AF)
                            && read_half(&self.uc, after.wrapping_sub(2)) == Some(0x8003));
                    let st = self.uc.get_data_mut();
                    if wfi {
                        st.fall_asleep(Sleep::Interrupt);
                    } else {
                        let at = st.describe(after);
                        st.set_stop(Stop::Engine {
                            error: "a return without a reason".to_owned(),
                            at,
                        });
                    }
                }
                _ => {}
            }
        }
    }

    /// One step of sleep: wakes, or moves time to the next event.
    fn sleep_step(&mut self, sleep: Sleep) {
        let masks = masks(&self.uc);
        let st = self.uc.get_data_mut();
        let exceptions = &st.system.exceptions;
        let woken = match sleep {
            Sleep::Interrupt => exceptions
                .to_take(Masks {
                    primask: false,
                    ..masks
                })
                .is_some(),
            Sleep::Event => {
                if st.event_register {
                    st.event_register = false;
                    true
                } else {
                    exceptions.to_take(masks).is_some()
                }
            }
        };
        if woken {
            st.sleep = None;
            st.attention = true;
            st.wake_ups += 1;
            let now = st.clock.now();
            st.activations.woke(now);
            if let Some(profile) = st.profile.as_mut() {
                profile.woke(now);
            }
            return;
        }
        let next = st.deadline.min(st.end);
        st.clock.advance_to(next);
        st.recompute = true;
    }

    /// Virtual time now.
    pub fn now(&self) -> Nanos {
        self.uc.get_data().clock.now()
    }

    /// Instructions executed since power-on.
    pub fn instructions(&self) -> u64 {
        self.uc.get_data().instructions
    }

    /// The clock frequencies the RCC gives now.
    pub fn clocks(&self) -> Clocks {
        self.uc.get_data().clocks
    }

    /// Times the core woke from WFI or WFE since power-on: the image's loop iterations, for
    /// an image whose loop sleeps when it has nothing to do.
    pub fn wake_ups(&self) -> u64 {
        self.uc.get_data().wake_ups
    }

    /// Starts profiling ([`crate::profile`]): the instructions per block and per activation
    /// and the deepest stack from now on; a profile already running starts a new window
    /// ([`Profile::restart`]) and keeps its deepest stack.
    pub fn start_profile(&mut self) {
        let st = self.uc.get_data_mut();
        match st.profile.as_mut() {
            Some(profile) => profile.restart(),
            None => st.profile = Some(Box::new(Profile::new(&st.symbols))),
        }
    }

    /// Stops counting blocks and activations; the deepest stack is still followed
    /// ([`Profile::pause`]). [`Machine::start_profile`] starts a new window.
    pub fn pause_profile(&mut self) {
        if let Some(profile) = self.uc.get_data_mut().profile.as_mut() {
            profile.pause();
        }
    }

    /// The profile since [`Machine::start_profile`] (`None`: not profiling).
    pub fn profile(&self) -> Option<&Profile> {
        self.uc.get_data().profile.as_deref()
    }

    /// The image's function symbols, to read a profile with.
    pub fn symbols(&self) -> &Symbols {
        &self.uc.get_data().symbols
    }

    /// Follows the deepest stack from now on ([`Machine::deepest_stack`]): a paused profile
    /// ([`Profile::pause`]) unless one runs already. It costs a register read at every
    /// translated block's start.
    pub fn follow_stack(&mut self) {
        if self.uc.get_data().profile.is_none() {
            self.start_profile();
            self.pause_profile();
        }
    }

    /// The deepest stack since the profile started ([`Machine::start_profile`],
    /// [`Machine::follow_stack`]), in bytes below the main stack pointer the last reset
    /// loaded ([`crate::observed::stack_depth`]); `None` when the stack is not followed.
    pub fn deepest_stack(&self) -> Option<u32> {
        let st = self.uc.get_data();
        let profile = st.profile.as_ref()?;
        Some(stack_depth(st.initial_sp, profile.lowest_sp()))
    }

    /// The longest activation of the core so far, the one in progress included: from a
    /// wake-up (from WFI or WFE) to the next sleep or reset, in virtual time
    /// ([`crate::observed::Activations`]).
    pub fn longest_activation(&self) -> Nanos {
        let st = self.uc.get_data();
        st.activations.longest(st.clock.now())
    }

    /// Whether the core is asleep (WFI or WFE) at the end of the last run.
    pub fn asleep(&self) -> bool {
        self.uc.get_data().sleep.is_some()
    }

    /// A core register.
    pub fn register(&self, register: Register) -> u32 {
        reg(&self.uc, register)
    }

    /// Sets a core register (the PC with its Thumb bit, as `bx` would).
    pub fn set_register(&mut self, register: Register, value: u32) {
        set_reg(&mut self.uc, register, value);
    }

    /// Makes the code the core runs call the function at `address` now, as a `bl` in place
    /// of the instruction it would execute next would (LR = that instruction's address with
    /// its Thumb bit, PC = `address`): a defect's call, injected (`emulate --panic-at`).
    /// `None`, and nothing changed, while the core sleeps or is inside an IT block (QEMU
    /// keeps the IT state in the translated code, so a call from there would run
    /// conditionally); else the address of the instruction the call replaced.
    pub fn inject_call(&mut self, address: u32) -> Option<u32> {
        if self.asleep() || reg(&self.uc, RegisterARM::XPSR) & EPSR_IT != 0 {
            return None;
        }
        let pc = reg(&self.uc, RegisterARM::PC);
        set_reg(&mut self.uc, RegisterARM::LR, pc | 1);
        set_reg(&mut self.uc, RegisterARM::PC, address | 1);
        Some(pc)
    }

    /// The system part (NVIC, SCB, SysTick), for tests and reports.
    pub fn system(&self) -> &SystemControl {
        &self.uc.get_data().system
    }

    /// The system part, to pend an interrupt from outside (tests).
    pub fn system_mut(&mut self) -> &mut SystemControl {
        let st = self.uc.get_data_mut();
        st.attention = true;
        &mut st.system
    }

    /// A GPIO port.
    pub fn gpio(&self, port: Port) -> std::cell::RefMut<'_, Gpio> {
        let index = match port {
            Port::A => 0,
            Port::B => 1,
            Port::C => 2,
        };
        self.uc.get_data().models.gpio[index].borrow_mut()
    }

    /// FLASH_ACR as the image left it (RM0090 3.9.1): wait states, prefetch, instruction
    /// cache, data cache.
    pub fn flash_accelerator(&self) -> (u32, bool, bool, bool) {
        self.uc.get_data().models.flash.borrow().accelerator()
    }

    /// The bxCAN model (for a bus to offer and deliver frames).
    pub fn can(&self) -> Rc<RefCell<Can>> {
        self.uc.get_data().models.can.clone()
    }

    /// Words the USART sent that nothing took (no peer wired).
    pub fn unpaired_usart_words(&self) -> u64 {
        self.uc.get_data().usart_words
    }

    /// Wires USART3's TX line to a peer: from now on the words it sends are kept for
    /// [`Machine::take_usart_words`] instead of counted as lost.
    pub fn wire_usart(&mut self) {
        self.uc.get_data_mut().usart_wired = true;
    }

    /// The words USART3 started since the last call (wired: [`Machine::wire_usart`]), each
    /// with its start and end on the line.
    pub fn take_usart_words(&mut self) -> Vec<Transmitted> {
        std::mem::take(&mut self.uc.get_data_mut().usart_out)
    }

    /// A word whose last stop bit reaches USART3's RX pin at `at` (a peer's word).
    pub fn usart_receive(&mut self, word: u16, at: Nanos) {
        let st = self.uc.get_data_mut();
        st.models.usart.borrow_mut().receive(word, at);
        st.deadline = st.deadline.min(st.clock.cycles_at(at));
        st.recompute = true;
    }

    /// Hangs the core until virtual time `until`: it executes no instruction and takes no
    /// exception, as a loop stuck with interrupts masked would, while time and the
    /// peripherals go on (the independent watchdog expires unless fed). A reset ends it.
    pub fn hang(&mut self, until: Nanos) {
        self.uc.get_data_mut().hung_until = until;
    }

    /// Makes a transmit request to the CAN controller (TXRQ set in a mailbox) end
    /// [`Machine::run_until`] early with [`Outcome::Yielded`], so that a bus model sees the
    /// request at the instant it was made.
    pub fn yield_on_transmit_request(&mut self, on: bool) {
        self.uc.get_data_mut().yield_on_transmit = on;
    }

    /// Tells the machine that the bus side changed the CAN controller (a frame delivered,
    /// a transmission concluded): its interrupt lines and next event are looked at before
    /// the next instruction.
    pub fn can_changed(&mut self) {
        let st = self.uc.get_data_mut();
        st.recompute = true;
        st.attention = true;
    }

    /// The RTT bytes the image wrote since the last call, with the time of each drain.
    pub fn take_log(&mut self) -> Vec<(Nanos, Vec<u8>)> {
        std::mem::take(&mut self.uc.get_data_mut().log)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn armv7m_a5_1_thumb_instruction_lengths_are_counted_from_their_first_half_word() {
        // movs r0, #1 (16-bit); movw r0, #0x1234 (32-bit); bx lr (16-bit).
        let bytes = [0x01, 0x20, 0x41, 0xF2, 0x34, 0x20, 0x70, 0x47];
        assert_eq!(count_instructions(&bytes), 3);
    }

    #[test]
    fn sev_encodings_are_found_at_half_word_boundaries() {
        let code = [0x40, 0xBF, 0x00, 0xBF, 0xAF, 0xF3, 0x04, 0x80, 0xBF, 0x40];
        assert_eq!(sev_addresses(0x100, &code), vec![0x100, 0x104]);
    }
}
