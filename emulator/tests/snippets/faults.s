@ What ends a run with a sentence: accesses no model claims (I2C1 and USART2 are not
@ modelled), an undefined instruction (HardFault), a system reset request; each reached from
@ its own entry point.
.include "common.inc"
.set systick_handler, fault
.set irq0_handler, fault
.set irq1_handler, fault

.thumb_func
.type reset, %function
reset:
  constant r0, 0x40005400   @ I2C1_CR1
  ldr r1, [r0]
  b .
.size reset, . - reset

.thumb_func
.type undefined_instruction, %function
undefined_instruction:
  movs r0, #1
  udf #7
.size undefined_instruction, . - undefined_instruction

.thumb_func
.type unclaimed_in_a_mapped_page, %function
unclaimed_in_a_mapped_page:
  constant r0, 0x40004400   @ USART2_SR: in USART3's page, not modelled
  movs r1, #0x5A
  strb r1, [r0]
  b .
.size unclaimed_in_a_mapped_page, . - unclaimed_in_a_mapped_page

.thumb_func
.type system_reset_request, %function
system_reset_request:
  constant r0, 0xE000ED0C   @ AIRCR
  constant r1, 0x05FA0004   @ VECTKEY, SYSRESETREQ
  str r1, [r0]
  b .
.size system_reset_request, . - system_reset_request
