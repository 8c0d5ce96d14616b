@ ARMv7-M B1.5.6 / B1.5.8 with the FP extension: once CPACR grants CP10/CP11 the VFP
@ instructions run; CONTROL.FPCA is then set, entry stacks the extended frame (S0-S15,
@ FPSCR) with EXC_RETURN bit 4 clear, and return restores the FP registers.
.include "common.inc"
.set systick_handler, fault
.set irq1_handler, fault

.thumb_func
.type reset, %function
reset:
  constant r5, 0xE000ED88   @ CPACR
  constant r6, 0x00F00000   @ CP10, CP11: full access
  str r6, [r5]
  dsb
  isb
  vmov.f32 s1, #1.5
  vmov.f32 s2, #2.25
  vadd.f32 s0, s1, s2       @ 3.75
  constant r5, 0xE000E100   @ NVIC_ISER0
  movs r6, #1
  str r6, [r5]
  constant r5, 0xE000E200   @ NVIC_ISPR0
  str r6, [r5]
  b resumed
resumed:
  vmov r7, s0               @ 3.75 again after the return
  b .
.size reset, . - reset

.thumb_func
.type irq0_handler, %function
irq0_handler:
  mov r8, sp
  mov r9, lr
  vmov.f32 s0, #-1.0        @ clobbered here, restored by the return
  bx lr
.size irq0_handler, . - irq0_handler
