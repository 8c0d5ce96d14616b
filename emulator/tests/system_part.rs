//! The Cortex-M4 system part the emulator adds to Unicorn, checked with small Thumb programs
//! (`tests/snippets/*.s`, assembled into the committed ELF files by `build.sh`): exception
//! entry and return, tail-chaining, priority masking, SysTick, WFI and WFE, the FP extension,
//! and the sentences that end a run. Test names cite the ARMv7-M Architecture Reference
//! Manual's sections.

use std::path::PathBuf;

use emulator::cpu::{Config, Machine, Register};
use emulator::image::{Image, Symbols};
use emulator::stop::{Fault, Outcome, Stop};
use object::{Object, ObjectSegment, ObjectSymbol};

const MICROSECOND: u64 = 1_000;
const MILLISECOND: u64 = 1_000_000;
/// Where the snippets record the order things ran in (see `common.inc`).
const ORDER: u32 = 0x2000_0000;

fn snippet_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/snippets")
        .join(format!("{name}.elf"))
}

/// The machine with snippet `name` in flash, after reset.
fn machine(name: &str) -> (Machine, Vec<u8>) {
    let elf = std::fs::read(snippet_path(name)).expect("the snippet's ELF file");
    let file = object::File::parse(&*elf).expect("an ELF file");
    let mut machine = Machine::new(Config::default()).expect("Unicorn starts");
    for segment in file.segments() {
        let data = segment.data().expect("segment data");
        if !data.is_empty() {
            machine
                .write_flash(segment.address() as u32, data)
                .expect("flash written");
        }
    }
    machine.set_symbols(Symbols::from_elf(&elf));
    machine.reset().expect("a vector table");
    (machine, elf)
}

fn symbol(elf: &[u8], name: &str) -> u32 {
    let file = object::File::parse(elf).expect("an ELF file");
    file.symbols()
        .find(|symbol| symbol.name() == Ok(name))
        .map(|symbol| symbol.address() as u32)
        .expect("the symbol")
}

fn word(machine: &Machine, address: u32) -> u32 {
    let bytes = machine.read_memory(address, 4).expect("memory");
    u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]])
}

fn run(machine: &mut Machine, duration: u64) {
    assert_eq!(machine.run_for(duration), Outcome::Elapsed);
}

#[test]
fn armv7m_b1_5_6_entry_stacks_the_basic_frame_8_byte_aligned_and_b1_5_8_return_restores_it() {
    let (mut machine, _) = machine("exception_frame");
    run(&mut machine, 100 * MICROSECOND);
    // In the handler: EXC_RETURN for Thread mode on the main stack, IPSR = 16 (line 0).
    assert_eq!(machine.register(Register::R9), 0xFFFF_FFF9);
    assert_eq!(machine.register(Register::R10), 16);
    // SP was 0x2001FFFC: the frame is 8-byte aligned below it (B1.5.7).
    let frame = machine.register(Register::R8);
    assert_eq!(frame, 0x2001_FFD8);
    let stacked: Vec<u32> = (0..8).map(|i| word(&machine, frame + 4 * i)).collect();
    assert_eq!(&stacked[..6], &[1, 2, 3, 4, 5, 0x4321]);
    assert_eq!(
        stacked[6],
        machine.register(Register::R11),
        "return address"
    );
    let xpsr = stacked[7];
    assert_ne!(xpsr & (1 << 9), 0, "the realignment is recorded in bit 9");
    assert_ne!(xpsr & (1 << 24), 0, "EPSR.T");
    assert_eq!(xpsr & 0x1FF, 0, "stacked from Thread mode");
    // After the return: the clobbered registers restored, the SP as it was, Thread mode.
    for (register, value) in [
        (Register::R0, 1),
        (Register::R1, 2),
        (Register::R2, 3),
        (Register::R3, 4),
        (Register::R12, 5),
        (Register::R7, 0x77),
    ] {
        assert_eq!(machine.register(register), value, "{register:?}");
    }
    assert_eq!(machine.register(Register::SP), 0x2001_FFFC);
    assert_eq!(machine.register(Register::IPSR), 0);
    assert!(!machine.system().exceptions.is_active(16));
}

#[test]
fn armv7m_b1_5_8_a_lower_priority_interrupt_pended_in_a_handler_is_tail_chained_at_its_return() {
    let (mut machine, _) = machine("tail_chain");
    run(&mut machine, 100 * MICROSECOND);
    // Line 0, then line 1, then Thread mode: line 1 did not preempt line 0.
    assert_eq!(word(&machine, ORDER), 0x129);
    // Line 1's handler ran on line 0's frame, with the same EXC_RETURN.
    assert_eq!(
        machine.register(Register::R8),
        machine.register(Register::R10)
    );
    assert_eq!(machine.register(Register::R9), 0xFFFF_FFF9);
    assert_eq!(machine.register(Register::R11), 0xFFFF_FFF9);
    assert_eq!(machine.register(Register::R0), 0x42);
    assert_eq!(machine.register(Register::SP), 0x2002_0000);
}

#[test]
fn armv7m_b1_5_4_basepri_and_primask_hold_back_interrupts_until_cleared() {
    let (mut machine, _) = machine("masking");
    run(&mut machine, 100 * MICROSECOND);
    // Line 1 (above BASEPRI) at once, Thread, line 0 once BASEPRI is cleared, Thread,
    // line 0 again once PRIMASK is cleared, Thread.
    assert_eq!(word(&machine, ORDER), 0x29_1817);
}

#[test]
fn armv7m_b3_3_systick_interrupts_every_reload_plus_one_cycles_and_b1_5_19_wfi_sleeps_between() {
    let (mut machine, _) = machine("systick");
    run(&mut machine, MILLISECOND);
    let before = word(&machine, ORDER);
    let instructions = machine.instructions();
    run(&mut machine, MILLISECOND);
    // 1 ms at the reset clock (HSI, 16 MHz) is 16 000 cycles: 16 periods of 1000.
    assert_eq!(word(&machine, ORDER) - before, 16);
    // Asleep between interrupts: a few instructions per interrupt, not 16 000 cycles' worth.
    let executed = machine.instructions() - instructions;
    assert!(executed < 16 * 20, "{executed} instructions in 1 ms");
    assert!(machine.asleep());
}

/// Seen from outside (`emulator::observed`): each SysTick interrupt wakes the core for its
/// handler and the return to WFI, far shorter than the period it then sleeps; a stack
/// followed from the start goes as deep as the exception frame the interrupt stacked on the
/// initial main stack (eight words, B1.5.6), and one not followed is not reported.
#[test]
fn armv7m_b1_5_19_a_wake_up_lasts_until_wfi_and_b1_5_6_the_deepest_stack_holds_the_frame() {
    let (mut machine, elf) = machine("systick");
    assert_eq!(machine.deepest_stack(), None, "not followed");
    machine.follow_stack();
    run(&mut machine, MILLISECOND);
    let initial = word(&machine, symbol(&elf, "vectors"));
    assert_eq!(machine.deepest_stack(), Some(8 * 4), "below {initial:#x}");
    // One cycle per instruction at the reset clock (HSI, 16 MHz): the handler and the way
    // back to WFI are a few instructions, the period 1000 cycles.
    let cycle = MILLISECOND / 16_000;
    let longest = machine.longest_activation();
    assert!(
        (cycle..20 * cycle).contains(&longest),
        "longest wake-up {longest} ns"
    );
    assert!(machine.asleep());
}

/// The deepest stack is measured from the main stack pointer the reset loaded: here the
/// program's own word below it and the frame the interrupt stacked under that, realigned to
/// eight bytes (B1.5.7), as the handler saw its SP.
#[test]
fn armv7m_b1_5_7_the_deepest_stack_reaches_the_realigned_exception_frame() {
    let (mut machine, elf) = machine("exception_frame");
    machine.follow_stack();
    run(&mut machine, 100 * MICROSECOND);
    let initial = word(&machine, symbol(&elf, "vectors"));
    let frame = machine.register(Register::R8);
    assert_eq!(machine.deepest_stack(), Some(initial - frame));
    assert_eq!(
        machine.longest_activation(),
        0,
        "the core never slept: no wake-up"
    );
}

#[test]
fn armv7m_b1_5_18_sev_sets_the_event_register_that_wfe_consumes_and_wfe_then_sleeps() {
    let (mut machine, _) = machine("wfe");
    run(&mut machine, 100 * MICROSECOND);
    assert_eq!(machine.register(Register::R7), 1, "the first WFE went on");
    assert_eq!(machine.register(Register::R8), 0, "the second WFE sleeps");
    assert!(machine.asleep());
    // SysTick's first interrupt (10 000 cycles at 16 MHz) wakes it.
    run(&mut machine, MILLISECOND);
    assert_eq!(machine.register(Register::R8), 1);
}

#[test]
fn armv7m_b1_5_6_with_fpca_entry_stacks_the_extended_frame_and_b1_5_8_restores_s0() {
    let (mut machine, _) = machine("fpu");
    run(&mut machine, 100 * MICROSECOND);
    // The VFP instructions ran once CPACR enabled them: 1.5 + 2.25.
    assert_eq!(machine.register(Register::R7), 3.75f32.to_bits());
    // EXC_RETURN with bit 4 clear: an extended frame of 0x68 bytes.
    assert_eq!(machine.register(Register::R9), 0xFFFF_FFE9);
    let frame = machine.register(Register::R8);
    assert_eq!(frame, 0x2002_0000 - 0x68);
    assert_eq!(
        word(&machine, frame + 0x20),
        3.75f32.to_bits(),
        "stacked S0"
    );
    assert_eq!(word(&machine, frame + 0x24), 1.5f32.to_bits(), "stacked S1");
    assert_eq!(machine.register(Register::SP), 0x2002_0000);
}

#[test]
fn armv7m_b1_5_6_thread_mode_on_the_process_stack_stacks_there_and_returns_there() {
    let (mut machine, _) = machine("psp");
    run(&mut machine, 100 * MICROSECOND);
    assert_eq!(machine.register(Register::R9), 0xFFFF_FFFD);
    assert_eq!(machine.register(Register::R8), 0x2001_0000 - 0x20);
    assert_eq!(
        machine.register(Register::R10),
        0x2002_0000,
        "the handler on the MSP"
    );
    assert_eq!(
        machine.register(Register::R7),
        0x2001_0000,
        "back on the PSP"
    );
    assert_eq!(machine.register(Register::R12) & 2, 2, "CONTROL.SPSEL");
}

#[test]
fn an_access_no_model_claims_stops_the_run_with_a_sentence_naming_address_access_and_function() {
    let (mut machine, _) = machine("faults");
    let Outcome::Stopped { stop, .. } = machine.run_for(MILLISECOND) else {
        panic!("the run went on");
    };
    assert!(matches!(stop, Stop::Unclaimed { .. }));
    let sentence = stop.to_string();
    assert!(
        sentence.contains("a 4-byte read at 0x40005400 (I2C1), which no model claims"),
        "{sentence}"
    );
    assert!(sentence.contains("`reset`"), "{sentence}");
}

#[test]
fn armv7m_b1_5_14_an_undefined_instruction_ends_the_run_as_a_hardfault_naming_the_function() {
    let (mut machine, elf) = machine("faults");
    machine.set_register(Register::PC, symbol(&elf, "undefined_instruction") | 1);
    let Outcome::Stopped { stop, .. } = machine.run_for(MILLISECOND) else {
        panic!("the run went on");
    };
    assert!(
        matches!(
            &stop,
            Stop::HardFault {
                fault: Fault::UndefinedInstruction,
                ..
            }
        ),
        "{stop}"
    );
    assert!(
        stop.to_string().contains("`undefined_instruction`"),
        "{stop}"
    );
}

#[test]
fn an_elf_that_is_not_a_sealed_image_of_this_project_is_refused_with_a_sentence() {
    let error = Image::load(&snippet_path("exception_frame")).unwrap_err();
    assert!(
        error
            .to_string()
            .contains("not a firmware image of this project"),
        "{error}"
    );
}

#[test]
fn an_unmodelled_register_in_a_page_with_a_model_stops_the_run_too() {
    let (mut machine, elf) = machine("faults");
    machine.set_register(Register::PC, symbol(&elf, "unclaimed_in_a_mapped_page") | 1);
    let Outcome::Stopped { stop, .. } = machine.run_for(MILLISECOND) else {
        panic!("the run went on");
    };
    let sentence = stop.to_string();
    assert!(
        sentence.contains("a 1-byte write of 0x5a at 0x40004400 (USART2), which no model claims"),
        "{sentence}"
    );
    assert!(
        sentence.contains("`unclaimed_in_a_mapped_page`"),
        "{sentence}"
    );
}

#[test]
fn armv7m_b3_2_aircr_sysresetreq_with_its_key_ends_the_run_as_a_system_reset() {
    let (mut machine, elf) = machine("faults");
    machine.set_register(Register::PC, symbol(&elf, "system_reset_request") | 1);
    let Outcome::Stopped { stop, .. } = machine.run_for(MILLISECOND) else {
        panic!("the run went on");
    };
    assert!(
        matches!(
            stop,
            Stop::Reset {
                cause: emulator::peripherals::rcc::ResetCause::Software,
                ..
            }
        ),
        "{stop}"
    );
}

#[test]
fn rm0090_10_3_11_a_byte_write_on_apb_reaches_the_register_as_a_word_with_the_byte_repeated() {
    let (mut machine, _) = machine("apb_bridge");
    run(&mut machine, 100 * MICROSECOND);
    // 0x01010101 written: LPDS (bit 0) and DBP (bit 8) kept, VOS (bit 14) cleared; the
    // other lanes' bits are reserved or write-one-to-clear-only.
    assert_eq!(machine.register(Register::R2), 0x0101);
    assert_eq!(machine.register(Register::R3), 0x01);
}

#[test]
fn rm0090_3_6_a_store_to_flash_is_programmed_by_the_flash_interface_only_with_pg_set() {
    let (mut machine, _) = machine("flash");
    run(&mut machine, MILLISECOND);
    assert_eq!(
        machine.register(Register::R3),
        0xFFFF_FFFF,
        "refused without PG"
    );
    assert_ne!(machine.register(Register::R4) & (1 << 7), 0, "PGSERR");
    assert_eq!(machine.register(Register::R6), 0x1234_5678, "programmed");
    assert_eq!(word(&machine, 0x080E_0000), 0x1234_5678);
    // The boot alias shows the same array.
    assert_eq!(word(&machine, 0x000E_0000), 0x1234_5678);
}

#[test]
fn armv7m_b1_5_6_an_interrupt_pending_inside_an_it_block_is_taken_after_it_and_the_block_stays_conditional()
 {
    let (mut machine, _) = machine("it_block");
    run(&mut machine, 100 * MICROSECOND);
    // The handler ran with no IT state: its first instruction (under `ne` with Z = 1 it
    // would be skipped) read IPSR 16, and the next one executed too.
    assert_eq!(machine.register(Register::R7) & 0x1FF, 16);
    assert_eq!(machine.register(Register::R9), 7);
    let it_bits = |xpsr: u32| ((xpsr >> 25) & 3) | ((xpsr >> 8) & 0xFC);
    // Taken after the IT block: no IT state stacked.
    assert_eq!(it_bits(machine.register(Register::R8)), 0);
    // The conditional instruction stayed conditional: skipped (Z = 1).
    assert_eq!(machine.register(Register::R2), 0);
    assert_eq!(machine.register(Register::R4), 0x55);
}
