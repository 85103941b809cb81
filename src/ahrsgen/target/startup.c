/* Startup code for the ahrsgen Cortex-M4F test image (QEMU mps2-an386, or any
 * Cortex-M4F with the memory map of mps2_an386.ld).
 *
 * Reset_Handler: enable the FPU (CPACR CP10/CP11 full access) BEFORE any floating-point
 * instruction can run, copy .data from its load image, zero .bss, call main(), and report
 * main's return value to the host through semihosting (QEMU exits with it).
 * Faults print their name and exit with a non-zero status, so a crash never hangs a test.
 *
 * Nothing here uses floating point, so the compiler cannot place an FP instruction
 * before the CPACR write; Reset_Handler is kept out of line and free of calls until the
 * FPU is on.
 */
#include <stdint.h>

#include "semihost.h"

extern uint32_t _sidata[], _sdata[], _edata[], _sbss[], _ebss[], _estack[];

int main(void);

void Reset_Handler(void);
void NMI_Handler(void);
void HardFault_Handler(void);
void MemManage_Handler(void);
void BusFault_Handler(void);
void UsageFault_Handler(void);
void Default_Handler(void);

#define SCB_CPACR (*(volatile uint32_t *)0xE000ED88u)
#define SCB_CFSR (*(volatile uint32_t *)0xE000ED28u)

__attribute__((section(".isr_vector"), used)) const uintptr_t g_vector_table[16] = {
    (uintptr_t)_estack,            /* initial main stack pointer */
    (uintptr_t)Reset_Handler,      /* reset */
    (uintptr_t)NMI_Handler,        /* NMI */
    (uintptr_t)HardFault_Handler,  /* hard fault */
    (uintptr_t)MemManage_Handler,  /* MPU fault */
    (uintptr_t)BusFault_Handler,   /* bus fault */
    (uintptr_t)UsageFault_Handler, /* usage fault */
    0u, 0u, 0u, 0u,                /* reserved */
    (uintptr_t)Default_Handler,    /* SVCall */
    (uintptr_t)Default_Handler,    /* debug monitor */
    0u,                            /* reserved */
    (uintptr_t)Default_Handler,    /* PendSV */
    (uintptr_t)Default_Handler,    /* SysTick (the harness polls it, no interrupt) */
};

/* no-tree-loop-distribute-patterns: keep the copy/zero loops as loops (GCC would call
 * newlib's memcpy/memset), so that the baseline image of the footprint holds no libc. */
__attribute__((noreturn, noinline, optimize("no-tree-loop-distribute-patterns"))) void Reset_Handler(void)
{
    /* 1. FPU on: CP10 and CP11 full access, then barriers so the next instruction sees it. */
    SCB_CPACR |= (0xFu << 20);
    __asm__ volatile("dsb\n\tisb" ::: "memory");

    /* 2. .data from flash to RAM, 3. .bss to zero (word loops; no libc calls). */
    const uint32_t *src = _sidata;
    for (uint32_t *dst = _sdata; dst < _edata;) {
        *dst++ = *src++;
    }
    for (uint32_t *dst = _sbss; dst < _ebss;) {
        *dst++ = 0u;
    }

    /* 4. run, 5. exit through semihosting with main's status. */
    int rc = main();
    sh_exit(rc);
}

static __attribute__((noreturn)) void fault(const char *name)
{
    sh_puts(name);
    sh_puts(" CFSR=");
    sh_put_hex(SCB_CFSR);
    sh_puts("\n");
    sh_exit(70);
}

void NMI_Handler(void) { fault("NMI"); }
void HardFault_Handler(void) { fault("HardFault"); }
void MemManage_Handler(void) { fault("MemManage"); }
void BusFault_Handler(void) { fault("BusFault"); }
void UsageFault_Handler(void) { fault("UsageFault"); }
void Default_Handler(void) { fault("UnexpectedInterrupt"); }
