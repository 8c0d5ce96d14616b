@ ARMv7-M B1.5.6 / B1.5.7 / B1.5.8: entry stacks the basic frame 8-byte aligned (the SP is
@ off by 4 here, so xPSR bit 9 records the adjustment), return restores it.
.include "common.inc"
.set systick_handler, fault
.set irq1_handler, fault

.thumb_func
.type reset, %function
reset:
  sub sp, sp, #4            @ SP = 0x2001FFFC: not 8-byte aligned
  movs r0, #1
  movs r1, #2
  movs r2, #3
  movs r3, #4
  movs r4, #5
  mov r12, r4
  constant lr, 0x00004321
  constant r5, 0xE000E100   @ NVIC_ISER0
  movs r6, #1
  str r6, [r5]              @ enable interrupt line 0
  constant r5, 0xE000E200   @ NVIC_ISPR0
  str r6, [r5]              @ pend it
  adr r11, resumed
  b resumed
.align 2
resumed:
  movs r7, #0x77
  b .
.size reset, . - reset

.thumb_func
.type irq0_handler, %function
irq0_handler:
  mov r8, sp                @ the frame
  mov r9, lr                @ EXC_RETURN
  mrs r10, ipsr
  movs r0, #0x55            @ clobbered here, restored by the return
  movs r1, #0x55
  bx lr
.size irq0_handler, . - irq0_handler
