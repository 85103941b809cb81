/*
 * fuzz_step.c - libFuzzer harness for a generated filter's step function.
 *
 * One source for every filter: compiled per filter with its layout header (written by
 * src/ahrsgen/check/harden.py from manifest.json) and the generated source, under
 *   clang -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=all
 *
 * Input bytes (everything is taken bit for bit, so NaN, +-Inf, -0, denormals and 1e38 all occur):
 *   byte 0            flags: bit 0 = first run AHRS_FUZZ_WARMUP nominal steps (level, at rest,
 *                     every sensor valid), so glitches also hit an initialised, converged filter
 *   then records of   AHRS_FUZZ_RECORD bytes, at most AHRS_FUZZ_MAX_RECORDS of them:
 *     byte 0          ctrl: bit i set = field i is "plausible" (a bounded value around a nominal
 *                     one, made from the field's raw bits) instead of raw bits;
 *                     fields: 0 gyro, 1 accel, 2 mag, 3 gps_vel_ned, 4 dt
 *     byte 1          valid bits (all 8 bits taken: unknown bits must be ignored by the step)
 *     13 reals        gyro[3] accel[3] mag[3] gps_vel_ned[3] dt, raw bytes of AHRS_REAL
 * The records are stepped in a cycle for AHRS_FUZZ_STEPS steps from a fresh state.
 *
 * Known-issue exclusion (only when harden.py lists one for a filter, with its reason):
 *   -DAHRS_FUZZ_GPS_MAX=X  finite raw GPS components beyond +-X are clamped to +-X, so the
 *                          fuzzer can explore past a known overflow of huge GPS velocities.
 *   -DAHRS_FUZZ_DT_MIN=X   a positive dt below X is raised to X (known failure at the smallest
 *                          denormal dt).
 *
 * After every step (abort() on violation, after printing what broke):
 *   - the status has no bit outside the documented ones;
 *   - a refused step (status & REFUSED_MASK) left the state byte for byte unchanged;
 *   - every invariant of ahrs_invariants.h holds (finite, unit quaternions, P SPD, ...).
 */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ahrs_invariants.h"

#ifndef AHRS_FUZZ_STEPS
#define AHRS_FUZZ_STEPS 256u
#endif
#ifndef AHRS_FUZZ_WARMUP
#define AHRS_FUZZ_WARMUP 200u
#endif
#define AHRS_FUZZ_MAX_RECORDS 64u
#define AHRS_FUZZ_RECORD (2u + 13u * sizeof(ahrs_real))

static ahrs_real raw_real(const uint8_t *p)
{
    ahrs_real v;
    memcpy(&v, p, sizeof v);
    return v;
}

/* A value in [lo, hi] made from the first 4 bytes of a field's raw bits. */
static ahrs_real bounded(const uint8_t *p, double lo, double hi)
{
    uint32_t u;
    memcpy(&u, p, sizeof u);
    return (ahrs_real)(lo + (hi - lo) * ((double)u / 4294967295.0));
}

static void decode(const uint8_t *r, ahrs_input *in, ahrs_real *dt)
{
    static const double nominal[4][3] = {
        { 0.0, 0.0, 0.0 },            /* gyro, rad/s */
        { 0.0, 0.0, -9.80665 },       /* accel, level at rest */
        { 0.21, 0.0, 0.43 },          /* mag, field units */
        { 0.0, 0.0, 0.0 },            /* GPS velocity NED */
    };
    static const double spread[4] = { 3.0, 4.0, 0.2, 30.0 };
    const uint8_t ctrl = r[0];
    const uint8_t *f = r + 2;
    memset(in, 0, sizeof *in);
    in->valid = r[1];
    ahrs_real *dst[4] = { in->gyro, in->accel, in->mag, in->gps_vel_ned };
    for (int k = 0; k < 4; k++) {
        for (int i = 0; i < 3; i++) {
            const uint8_t *p = f + (size_t)(3 * k + i) * sizeof(ahrs_real);
            dst[k][i] = (ctrl & (1u << k)) ? bounded(p, nominal[k][i] - spread[k], nominal[k][i] + spread[k])
                                           : raw_real(p);
        }
    }
#ifdef AHRS_FUZZ_GPS_MAX
    for (int i = 0; i < 3; i++) {
        const double g = (double)in->gps_vel_ned[i];
        if (isfinite(g) && fabs(g) > AHRS_FUZZ_GPS_MAX) {
            in->gps_vel_ned[i] = (ahrs_real)copysign(AHRS_FUZZ_GPS_MAX, g);
        }
    }
#endif
    const uint8_t *p = f + 12u * sizeof(ahrs_real);
    *dt = (ctrl & (1u << 4)) ? bounded(p, 1e-4, 0.05) : raw_real(p);
#ifdef AHRS_FUZZ_DT_MIN
    if (*dt > (ahrs_real)0 && (double)*dt < AHRS_FUZZ_DT_MIN) {
        *dt = (ahrs_real)AHRS_FUZZ_DT_MIN;
    }
#endif
}

static void nominal_input(uint32_t k, ahrs_input *in, ahrs_real *dt)
{
    memset(in, 0, sizeof *in);
    in->gyro[2] = (ahrs_real)0.01;
    in->accel[2] = (ahrs_real)-9.80665;
    in->mag[0] = (ahrs_real)0.21;
    in->mag[2] = (ahrs_real)0.43;
    in->gps_vel_ned[0] = (ahrs_real)5.0;
    in->valid = 0x7u | ((k % 20u) == 0u ? 0x8u : 0u);
    *dt = (ahrs_real)0.01;
}

static void report(const char *what, uint32_t step, int rec, const ahrs_input *in, ahrs_real dt,
                   uint32_t status, const char *msg)
{
    fprintf(stderr, "\n*** ahrs invariant violated: %s\n", what);
    fprintf(stderr, "    step %u (record %d), status 0x%x: %s\n", step, rec, status, msg);
    fprintf(stderr, "    gyro  %a %a %a\n", (double)in->gyro[0], (double)in->gyro[1], (double)in->gyro[2]);
    fprintf(stderr, "    accel %a %a %a\n", (double)in->accel[0], (double)in->accel[1], (double)in->accel[2]);
    fprintf(stderr, "    mag   %a %a %a\n", (double)in->mag[0], (double)in->mag[1], (double)in->mag[2]);
    fprintf(stderr, "    gps   %a %a %a\n", (double)in->gps_vel_ned[0], (double)in->gps_vel_ned[1],
            (double)in->gps_vel_ned[2]);
    fprintf(stderr, "    valid 0x%x dt %a (%.9g)\n", in->valid, (double)dt, (double)dt);
    abort();
}

static void checked_step(ahrs_state *s, const ahrs_input *in, ahrs_real dt, uint32_t step, int rec, ahrs_inv *inv)
{
    ahrs_state before;
    memcpy(&before, s, sizeof before);
    const uint32_t st = PFX(step)(s, in, dt);
    if ((st & ~(uint32_t)AHRS_STATUS_ALL) != 0u) {
        report("undocumented status bit", step, rec, in, dt, st, "");
    }
    if ((st & (uint32_t)AHRS_REFUSED_MASK) != 0u && memcmp(&before, s, sizeof before) != 0) {
        report("refused step changed the state", step, rec, in, dt, st, "");
    }
    if (!ahrs_check_state(s, inv)) {
        report("state invariant", step, rec, in, dt, st, inv->msg);
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1u + AHRS_FUZZ_RECORD) {
        return 0;
    }
    const uint8_t flags = data[0];
    size_t nrec = (size - 1u) / AHRS_FUZZ_RECORD;
    if (nrec > AHRS_FUZZ_MAX_RECORDS) {
        nrec = AHRS_FUZZ_MAX_RECORDS;
    }
    ahrs_state s;
    ahrs_inv inv;
    ahrs_inv_reset(&inv);
    PFX(init)(&s);
    if (!ahrs_check_state(&s, &inv)) {
        ahrs_input none;
        memset(&none, 0, sizeof none);
        report("state after init", 0u, -1, &none, 0, 0u, inv.msg);
    }
    ahrs_input in;
    ahrs_real dt;
    if (flags & 1u) {
        for (uint32_t k = 0u; k < AHRS_FUZZ_WARMUP; k++) {
            nominal_input(k, &in, &dt);
            checked_step(&s, &in, dt, k, -1, &inv);
        }
    }
    for (uint32_t k = 0u; k < AHRS_FUZZ_STEPS; k++) {
        const size_t r = k % nrec;
        decode(data + 1u + r * AHRS_FUZZ_RECORD, &in, &dt);
        checked_step(&s, &in, dt, k, (int)r, &inv);
    }
    return 0;
}
