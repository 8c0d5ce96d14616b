@ ARMv7-M B1.5.18: SEV sets the event register, the first WFE consumes it and goes on, the
@ second sleeps until an event: here SysTick's exception entry.
.include "common.inc"
.set irq0_handler, fault
.set irq1_handler, fault

.thumb_func
.type reset, %function
reset:
  constant r5, 0xE000E014   @ SYST_RVR
  movw r6, #9999
  str r6, [r5]
  constant r5, 0xE000E010   @ SYST_CSR
  movs r6, #7
  str r6, [r5]
  sev
  wfe
  movs r7, #1               @ after the first WFE
  wfe
  movs r8, #1               @ after the second
  b .
.size reset, . - reset

.thumb_func
.type systick_handler, %function
systick_handler:
  constant r5, 0xE000E010
  movs r6, #0
  str r6, [r5]              @ one interrupt is enough
  bx lr
.size systick_handler, . - systick_handler
