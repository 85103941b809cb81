/*
 * batch.c - run a generated filter over a whole sensor log, as firmware would step it.
 *
 * Compiled together with one generated filter: -DAHRS_PREFIX=qcf -DAHRS_HEADER='"qcf.h"'
 * -DAHRS_REAL=float. Exposes prefix-free entry points for ctypes (src/ahrsgen/sim/host.py).
 */
#define _POSIX_C_SOURCE 199309L
#include <stdint.h>
#include <time.h>

#include AHRS_HEADER

#define AHRS_CAT_(a, b) a##_##b
#define AHRS_CAT(a, b) AHRS_CAT_(a, b)
#define PFX(name) AHRS_CAT(AHRS_PREFIX, name)

typedef PFX(state) ahrs_state;
typedef PFX(input) ahrs_input;
typedef AHRS_REAL ahrs_real;

uint32_t ahrs_sizeof_state(void) { return (uint32_t)sizeof(ahrs_state); }
uint32_t ahrs_sizeof_input(void) { return (uint32_t)sizeof(ahrs_input); }
void ahrs_init(ahrs_state *s) { PFX(init)(s); }
uint32_t ahrs_step(ahrs_state *s, const ahrs_input *in, ahrs_real dt) { return PFX(step)(s, in, dt); }
void ahrs_euler(const ahrs_state *s, ahrs_real rpy[3]) { PFX(euler)(s, rpy); }

/* Step through n samples; after each, store q (4), Euler angles (3) and the status. */
void ahrs_run(ahrs_state *s, const ahrs_input *in, const ahrs_real *dt, uint32_t n,
              ahrs_real *q_out, ahrs_real *rpy_out, uint32_t *status_out)
{
    for (uint32_t k = 0u; k < n; k++) {
        status_out[k] = PFX(step)(s, &in[k], dt[k]);
        for (uint32_t i = 0u; i < 4u; i++) {
            q_out[4u * k + i] = s->q[i];
        }
        PFX(euler)(s, &rpy_out[3u * k]);
    }
}

/* Median-free timing helper: nanoseconds for `repeats` passes over n samples from a copy
 * of the initial state (the caller takes the median over several calls). */
double ahrs_time_ns_per_step(const ahrs_state *initial, const ahrs_input *in, const ahrs_real *dt,
                             uint32_t n, uint32_t repeats)
{
    struct timespec t0, t1;
    volatile uint32_t sink = 0u;
    ahrs_state s;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (uint32_t r = 0u; r < repeats; r++) {
        s = *initial;
        for (uint32_t k = 0u; k < n; k++) {
            sink += PFX(step)(&s, &in[k], dt[k]);
        }
    }
    clock_gettime(CLOCK_MONOTONIC, &t1);
    (void)sink;
    double ns = (double)(t1.tv_sec - t0.tv_sec) * 1e9 + (double)(t1.tv_nsec - t0.tv_nsec);
    return ns / ((double)n * (double)repeats);
}
