@ ARMv7-M B1.5.6: an interrupt pended inside an IT block. The IT block straddles a 1 KiB
@ boundary, where Unicorn (QEMU) ends a translated block, so a block starts between `it ne`
@ and its conditional instruction while the interrupt pended by the store before it waits.
@ The emulator takes it after the IT block (its IT state lives in QEMU's translated code):
@ the conditional instruction stays conditional (Z = 1 makes `ne` false, so it is skipped)
@ and the handler runs with no IT state.
.include "common.inc"
.set systick_handler, fault
.set irq1_handler, fault

.thumb_func
.type reset, %function
reset:
  constant r5, 0xE000E100   @ NVIC_ISER0
  movs r6, #1
  str r6, [r5]              @ enable line 0
  movs r2, #0
  mov.w r9, #0
  movs r4, #0
  constant r5, 0xE000E200   @ NVIC_ISPR0
  movs r0, #1
  cmp r0, #1                @ Z = 1
  b straddle
.size reset, . - reset

.balign 1024
  .space 1020
.thumb_func
.type straddle, %function
straddle:
  str r6, [r5]              @ pend line 0: taken at the next translated block
  it ne
  movne.w r2, #1            @ at the 1 KiB boundary: a block of its own, skipped (Z = 1)
  movs r4, #0x55            @ reached after the return
  b .
.size straddle, . - straddle

.thumb_func
.type irq0_handler, %function
irq0_handler:
  mrs r7, xpsr              @ first in the handler: must run (no IT state), IPSR 16
  mov.w r9, #7              @ unconditional in the handler
  ldr r8, [sp, #28]         @ the stacked xPSR, with the IT state
  bx lr
.size irq0_handler, . - irq0_handler
