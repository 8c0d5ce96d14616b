@ RM0090 10.3.11: the AHB/APB bridges turn a byte write into a word write with the byte
@ repeated in every lane. A byte written to PWR_CR's second byte (0x01: DBP) also lands in
@ the first (LPDS), the third and the fourth.
.include "common.inc"
.set systick_handler, fault
.set irq0_handler, fault
.set irq1_handler, fault

.thumb_func
.type reset, %function
reset:
  constant r0, 0x40007000   @ PWR_CR
  movs r1, #1
  strb r1, [r0, #1]
  ldr r2, [r0]              @ the whole register
  ldrb r3, [r0, #1]         @ its second byte
  b .
.size reset, . - reset
