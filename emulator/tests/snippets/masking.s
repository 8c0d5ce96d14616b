@ ARMv7-M B1.5.4: BASEPRI holds back what is not of higher priority than it, PRIMASK holds
@ back everything configurable; clearing them lets the pending interrupt in.
.include "common.inc"
.set systick_handler, fault

.thumb_func
.type reset, %function
reset:
  constant r5, 0xE000E100   @ NVIC_ISER0
  movs r6, #3
  str r6, [r5]
  constant r5, 0xE000E400   @ NVIC_IPR0
  constant r6, 0x1020
  str r6, [r5]              @ line 0: 0x20, line 1: 0x10
  movs r0, #0x20
  msr basepri, r0           @ masks priority 0x20 and below
  constant r5, 0xE000E200   @ NVIC_ISPR0
  movs r6, #3
  str r6, [r5]              @ pend both: line 1 runs, line 0 waits
  b step1
step1:
  record 9
  movs r0, #0
  msr basepri, r0           @ line 0 runs
  b step2
step2:
  cpsid i
  constant r5, 0xE000E200
  movs r6, #1
  str r6, [r5]              @ pend line 0 under PRIMASK
  b step3
step3:
  record 8
  cpsie i                   @ line 0 runs
  b step4
step4:
  record 7
  b .
.size reset, . - reset

.thumb_func
.type irq0_handler, %function
irq0_handler:
  record 1
  bx lr
.size irq0_handler, . - irq0_handler

.thumb_func
.type irq1_handler, %function
irq1_handler:
  record 2
  bx lr
.size irq1_handler, . - irq1_handler
