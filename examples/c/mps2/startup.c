/*
 * Start-up and board support of the C example on QEMU's mps2-an386 (Cortex-M4 with FPU):
 * vector table, reset (FPU on, .data and .bss, stack painting), semihosting output and
 * exit, SysTick. Freestanding: no C library.
 */
#include "board.h"

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _stack_bottom, _stack_top;
int main(void);

#define SCB_CPACR (*(volatile uint32_t *)0xE000ED88u)
#define SYST_CSR (*(volatile uint32_t *)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t *)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t *)0xE000E018u)
#define STACK_PAINT 0xCCCCCCCCu

/* A semihosting call: operation `op` with its parameter block. */
static uint32_t semihost(uint32_t op, const void *block) {
    register uint32_t r0 __asm__("r0") = op;
    register const void *r1 __asm__("r1") = block;
    __asm__ volatile("bkpt 0xab" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}

static int32_t host_stdout = -1;

void board_write(const char *text, size_t len) {
    if (host_stdout < 0) {
        const uint32_t open[3] = {(uint32_t)":tt", 4 /* "w" */, 3};
        host_stdout = (int32_t)semihost(0x01 /* SYS_OPEN */, open);
    }
    const uint32_t write[3] = {(uint32_t)host_stdout, (uint32_t)text, (uint32_t)len};
    (void)semihost(0x05 /* SYS_WRITE */, write);
}

void board_exit(int code) {
    const uint32_t block[2] = {0x20026 /* ADP_Stopped_ApplicationExit */, (uint32_t)code};
    (void)semihost(0x20 /* SYS_EXIT_EXTENDED */, block);
    for (;;) {
    }
}

uint32_t board_ticks(void) { return SYST_CVR; }

uint32_t board_stack_used(void) {
    const uint32_t *p = &_stack_bottom;
    while (p < &_stack_top && *p == STACK_PAINT) {
        p++;
    }
    return (uint32_t)((uintptr_t)&_stack_top - (uintptr_t)p);
}

void reset_handler(void) {
    /* CP10 and CP11 (the FPU) full access, before any floating-point instruction. */
    SCB_CPACR |= 0xFu << 20;
    __asm__ volatile("dsb\n\tisb" ::: "memory");
    for (uint32_t *src = &_sidata, *dst = &_sdata; dst < &_edata;) {
        *dst++ = *src++;
    }
    for (uint32_t *dst = &_sbss; dst < &_ebss;) {
        *dst++ = 0;
    }
    /* Paint the stack below the current frame for board_stack_used(). */
    uint32_t sp;
    __asm__ volatile("mov %0, sp" : "=r"(sp));
    for (volatile uint32_t *p = &_stack_bottom; (uintptr_t)p < sp - 64u; p++) {
        *p = STACK_PAINT;
    }
    /* SysTick: core clock, full 24-bit range, no interrupt. */
    SYST_RVR = 0x00FFFFFFu;
    SYST_CVR = 0;
    SYST_CSR = 0x5u;
    board_exit(main());
}

static void fault_handler(void) {
    static const char msg[] = "c-example fault\n";
    board_write(msg, sizeof msg - 1);
    board_exit(3);
}

/* The vector table: the initial stack pointer, then the exception handlers. */
typedef void (*vector_t)(void);
__attribute__((section(".vectors"), used)) static const vector_t vectors[16] = {
    (vector_t)(uintptr_t)&_stack_top, /* initial stack pointer */
    reset_handler,
    fault_handler, /* NMI */
    fault_handler, /* HardFault */
    fault_handler, /* MemManage */
    fault_handler, /* BusFault */
    fault_handler, /* UsageFault */
    0, 0, 0, 0,
    fault_handler, /* SVCall */
    fault_handler, /* DebugMonitor */
    0,
    fault_handler, /* PendSV */
    fault_handler, /* SysTick */
};
