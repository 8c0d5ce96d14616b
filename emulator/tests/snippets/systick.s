@ ARMv7-M B3.3: SysTick on the processor clock with a reload value of 999 interrupts every
@ 1000 cycles; between interrupts the core sleeps in WFI (B1.5.19).
.include "common.inc"
.set irq0_handler, fault
.set irq1_handler, fault

.thumb_func
.type reset, %function
reset:
  constant r5, 0xE000E014   @ SYST_RVR
  movw r6, #999
  str r6, [r5]
  constant r5, 0xE000E018   @ SYST_CVR
  str r6, [r5]              @ any write clears it
  constant r5, 0xE000E010   @ SYST_CSR
  movs r6, #7               @ ENABLE, TICKINT, CLKSOURCE = processor clock
  str r6, [r5]
sleep:
  wfi
  b sleep
.size reset, . - reset

.thumb_func
.type systick_handler, %function
systick_handler:
  constant r4, 0x20000000
  ldr r5, [r4]
  adds r5, r5, #1
  str r5, [r4]
  bx lr
.size systick_handler, . - systick_handler
