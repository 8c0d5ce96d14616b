@ RM0090 3.6: a store to flash reaches the flash interface, which programs it only once
@ unlocked with PG set (else PGSERR, the array untouched); the word is there when BSY clears.
.include "common.inc"
.set systick_handler, fault
.set irq0_handler, fault
.set irq1_handler, fault

.thumb_func
.type reset, %function
reset:
  constant r0, 0x40023C00   @ FLASH interface registers
  constant r1, 0x080E0000   @ sector 11
  constant r2, 0x12345678
  str r2, [r1]              @ PG not set: refused
  ldr r3, [r1]
  ldr r4, [r0, #0x0C]       @ FLASH_SR
  movs r5, #0xF0
  str r5, [r0, #0x0C]       @ clear the error flags (write one to clear)
  constant r5, 0x45670123   @ KEY1
  str r5, [r0, #0x04]
  constant r5, 0xCDEF89AB   @ KEY2
  str r5, [r0, #0x04]
  movw r5, #0x0201          @ PSIZE x32, PG
  str r5, [r0, #0x10]
  str r2, [r1]              @ programmed
wait:
  ldr r5, [r0, #0x0C]
  lsls r5, r5, #15          @ BSY (bit 16) into the sign bit
  bmi wait
  ldr r6, [r1]
  b .
.size reset, . - reset
