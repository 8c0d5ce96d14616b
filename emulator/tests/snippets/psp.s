@ ARMv7-M B1.5.6 / B1.5.8: Thread mode on the process stack: the frame goes on the PSP,
@ EXC_RETURN is 0xFFFFFFFD, the handler runs on the MSP, and the return goes back to the PSP.
.include "common.inc"
.set systick_handler, fault
.set irq1_handler, fault

.thumb_func
.type reset, %function
reset:
  constant r0, 0x20010000
  msr psp, r0
  movs r0, #2
  msr control, r0           @ SPSEL: Thread mode uses the PSP
  isb
  constant r5, 0xE000E100
  movs r6, #1
  str r6, [r5]
  constant r5, 0xE000E200
  str r6, [r5]
  b resumed
resumed:
  mov r7, sp                @ the PSP again
  mrs r12, control
  b .
.size reset, . - reset

.thumb_func
.type irq0_handler, %function
irq0_handler:
  mrs r8, psp               @ the frame
  mov r9, lr
  mov r10, sp               @ the MSP
  bx lr
.size irq0_handler, . - irq0_handler
