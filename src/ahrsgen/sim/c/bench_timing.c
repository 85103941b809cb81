/*
 * bench_timing.c - CPU-time cost of a generated filter's step, for `ahrsgen bench`.
 *
 * Compiled next to batch.c into the same shared library (host.compile_shared's
 * extra_sources). Unlike the wall-clock helper in batch.c it reads this thread's CPU clock,
 * so time the thread spends descheduled on a busy machine does not count.
 */
#define _POSIX_C_SOURCE 199309L
#include <stdint.h>
#include <time.h>

#include AHRS_HEADER

#define AHRS_CAT_(a, b) a##_##b
#define AHRS_CAT(a, b) AHRS_CAT_(a, b)
#define PFX(name) AHRS_CAT(AHRS_PREFIX, name)

double ahrs_bench_cpu_ns_per_step(const PFX(state) *initial, const PFX(input) *in, const AHRS_REAL *dt,
                                  uint32_t n, uint32_t repeats);

/* CPU nanoseconds per step for `repeats` passes over n samples from a copy of the initial state. */
double ahrs_bench_cpu_ns_per_step(const PFX(state) *initial, const PFX(input) *in, const AHRS_REAL *dt,
                                  uint32_t n, uint32_t repeats)
{
    struct timespec t0, t1;
    volatile uint32_t sink = 0u;
    PFX(state) s;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t0);
    for (uint32_t r = 0u; r < repeats; r++) {
        s = *initial;
        for (uint32_t k = 0u; k < n; k++) {
            sink += (uint32_t)PFX(step)(&s, &in[k], dt[k]);
        }
    }
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t1);
    (void)sink;
    double ns = (double)(t1.tv_sec - t0.tv_sec) * 1e9 + (double)(t1.tv_nsec - t0.tv_nsec);
    return ns / ((double)n * (double)repeats);
}
