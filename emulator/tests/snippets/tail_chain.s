@ ARMv7-M B1.5.4 and B1.5.8: line 1 (priority 0x20), pended by line 0's handler (priority
@ 0x10), cannot preempt it; it is taken when line 0's handler returns, through the same frame.
.include "common.inc"
.set systick_handler, fault

.thumb_func
.type reset, %function
reset:
  constant r5, 0xE000E100   @ NVIC_ISER0
  movs r6, #3
  str r6, [r5]              @ enable lines 0 and 1
  constant r5, 0xE000E400   @ NVIC_IPR0
  constant r6, 0x2010
  str r6, [r5]              @ line 0: 0x10, line 1: 0x20
  movs r0, #0x42
  constant r5, 0xE000E200   @ NVIC_ISPR0
  movs r6, #1
  str r6, [r5]              @ pend line 0
  b thread
thread:
  record 9
  b .
.size reset, . - reset

.thumb_func
.type irq0_handler, %function
irq0_handler:
  mov r8, sp
  mov r9, lr
  constant r5, 0xE000E200   @ NVIC_ISPR0
  movs r6, #2
  str r6, [r5]              @ pend line 1: lower priority, it waits
  record 1
  bx lr
.size irq0_handler, . - irq0_handler

.thumb_func
.type irq1_handler, %function
irq1_handler:
  mov r10, sp
  mov r11, lr
  record 2
  bx lr
.size irq1_handler, . - irq1_handler
