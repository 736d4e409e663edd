/*
 * The little the C example needs from its board, here QEMU's mps2-an386 (Cortex-M4F):
 * text output and exit through semihosting, a free-running cycle counter, and the stack's
 * high-water mark. On an ECU these are the UART driver, a hardware timer and the RTOS.
 */
#ifndef NEMM_EXAMPLE_BOARD_H
#define NEMM_EXAMPLE_BOARD_H

#include <stddef.h>
#include <stdint.h>

/* Writes `len` bytes to the host's stdout (semihosting). */
void board_write(const char *text, size_t len);

/* Ends the program; QEMU exits with `code`. */
void board_exit(int code) __attribute__((noreturn));

/* SysTick, counting down at the core clock over 24 bits: under QEMU's `-icount shift=0`
 * one tick is 40 instructions (mps2's 25 MHz clock, one instruction per nanosecond). */
uint32_t board_ticks(void);

/* Instructions per board_ticks() tick under `-icount shift=0`. */
#define BOARD_INSTRUCTIONS_PER_TICK 40u

/* Bytes of stack used so far (the stack is painted at reset). */
uint32_t board_stack_used(void);

#endif
