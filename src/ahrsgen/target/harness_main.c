/* ahrsgen target test image: runs a sensor log through one generated filter on the
 * Cortex-M4F and writes what the filter produced, exactly, for comparison with the host
 * float build.
 *
 * Input (host file "ahrs_in.bin", read through semihosting): records of
 *   float gyro[3], accel[3], mag[3], gps_vel[3]; uint32_t valid; float dt   (56 bytes, LE)
 * Output (host file "ahrs_out.bin"): per record, uint32_t status, uint32_t SysTick ticks
 * spent in the step call, then the raw bytes of the filter's state struct after the step
 * (padded to 4 bytes).
 * Console (semihosting): one line "AHRS_DONE n=<records> ticks=<SysTick ticks in step>
 * state_bytes=<sizeof state> stack=<deepest stack use below main's frame, bytes>".
 *
 * The filter is bound through "filter_glue.h", written by firmware_sim/target.py from the
 * generated filter's manifest: it defines glue_state, glue_init() and glue_step().
 */
#include <stdint.h>
#include <string.h>

#include "ahrs_record.h"
#include "filter_glue.h"
#include "semihost.h"

#define CHUNK 64u
#define STATE_WORDS ((sizeof(glue_state) + 3u) / 4u)

/* SysTick, free-running from the core clock; read around each step.  Under QEMU with
 * -icount the tick count is a (coarse) instruction counter; QEMU 7.2 has no DWT CYCCNT. */
#define SYST_CSR (*(volatile uint32_t *)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t *)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t *)0xE000E018u)

#define STACK_PAINT 0xA5A5A5A5u
extern uint32_t _sstack[]; /* lowest address of the stack (mps2_an386.ld) */

static ahrs_record g_in[CHUNK];
static uint32_t g_out[CHUNK * (2u + STATE_WORDS)];
static glue_state g_state;

int main(void)
{
    int32_t fin = sh_open("ahrs_in.bin", SH_MODE_RB);
    int32_t fout = sh_open("ahrs_out.bin", SH_MODE_WB);
    if (fin < 0 || fout < 0) {
        sh_puts("AHRS_ERROR cannot open ahrs_in.bin / ahrs_out.bin\n");
        return 2;
    }
    SYST_RVR = 0x00FFFFFFu;
    SYST_CVR = 0u;
    SYST_CSR = 0x5u; /* enable, core clock, no interrupt */

    /* Paint the free stack below main's frame; after the run, the lowest overwritten word
     * gives the deepest stack use of anything main called (glue_step and the filter, and
     * the much shallower semihosting calls). */
    uintptr_t sp;
    __asm__ volatile("mov %0, sp" : "=r"(sp));
    for (uint32_t *p = _sstack; (uintptr_t)p < sp - 64u; p++) {
        *p = STACK_PAINT;
    }

    glue_init(&g_state);
    uint32_t n_total = 0u;
    uint64_t ticks = 0u;
    for (;;) {
        int32_t missing = sh_read(fin, g_in, sizeof g_in);
        if (missing < 0 || (uint32_t)missing > sizeof g_in) {
            sh_puts("AHRS_ERROR read\n");
            return 3;
        }
        uint32_t got = (uint32_t)(sizeof g_in) - (uint32_t)missing;
        if (got % sizeof(ahrs_record) != 0u) {
            sh_puts("AHRS_ERROR truncated record\n");
            return 4;
        }
        uint32_t n = got / (uint32_t)sizeof(ahrs_record);
        if (n == 0u) {
            break;
        }
        uint32_t *o = g_out;
        for (uint32_t i = 0u; i < n; i++) {
            uint32_t t0 = SYST_CVR;
            uint32_t status = glue_step(&g_state, &g_in[i]);
            uint32_t t1 = SYST_CVR;
            uint32_t dt_ticks = (t0 - t1) & 0x00FFFFFFu; /* counts down */
            ticks += (uint64_t)dt_ticks;
            *o++ = status;
            *o++ = dt_ticks;
            memcpy(o, &g_state, sizeof g_state);
            o += STATE_WORDS;
        }
        size_t bytes = (size_t)((uintptr_t)o - (uintptr_t)g_out);
        if (sh_write(fout, g_out, bytes) != 0) {
            sh_puts("AHRS_ERROR write\n");
            return 5;
        }
        n_total += n;
    }
    const uint32_t *low = _sstack;
    while ((uintptr_t)low < sp && *low == STACK_PAINT) {
        low++;
    }
    uint32_t stack_depth = (uint32_t)(sp - (uintptr_t)low);

    sh_close(fin);
    sh_close(fout);
    sh_puts("AHRS_DONE n=");
    sh_put_hex(n_total);
    sh_puts(" ticks=");
    sh_put_hex((uint32_t)(ticks >> 32));
    sh_put_hex((uint32_t)ticks);
    sh_puts(" state_bytes=");
    sh_put_hex((uint32_t)sizeof g_state);
    sh_puts(" stack=");
    sh_put_hex(stack_depth);
    sh_puts("\n");
    return 0;
}
