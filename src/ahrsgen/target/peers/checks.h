/* The product's input checks written by hand, for the like-for-like peers madgwick_checked.c
 * and mahony_checked.c (the contract of src/ahrsgen/status.py and docs/DESIGN, with the
 * product's default limits): a step with a bad dt or gyro sample is refused with the state
 * untouched; a missing, non-finite, out-of-range or near-zero accelerometer or magnetometer
 * sample skips only its own correction. The same status bits as every generated step. Written
 * as a careful hand would: one norm test per sensor on the common path (|v|^2 < MAX^2 implies
 * every |v_i| < MAX), the per-component tests only when it fails. */
#ifndef AHRSGEN_PEER_CHECKS_H
#define AHRSGEN_PEER_CHECKS_H

#include <math.h>
#include <stdbool.h>
#include <stdint.h>

#include "peers.h"

#define PEER_DT_MAX 0.5f
#define PEER_GYRO_MAX 70.0f
#define PEER_ACCEL_MIN_NORM 0.5f
#define PEER_ACCEL_MAX 2000.0f
#define PEER_MAG_MIN_NORM 1e-06f
#define PEER_MAG_MAX 1e+06f

#define PEER_VALID_GYRO (1u << 0)
#define PEER_VALID_ACCEL (1u << 1)
#define PEER_VALID_MAG (1u << 2)

#define PEER_DT_INVALID (1u << 0)
#define PEER_DT_TOO_LARGE (1u << 1)
#define PEER_GYRO_MISSING (1u << 2)
#define PEER_GYRO_NONFINITE (1u << 3)
#define PEER_ACCEL_NONFINITE (1u << 4)
#define PEER_ACCEL_ZERO (1u << 5)
#define PEER_MAG_NONFINITE (1u << 6)
#define PEER_MAG_ZERO (1u << 7)
#define PEER_GYRO_RANGE (1u << 9)
#define PEER_ACCEL_RANGE (1u << 10)
#define PEER_MAG_RANGE (1u << 11)
#define PEER_REFUSED (PEER_DT_INVALID | PEER_DT_TOO_LARGE | PEER_GYRO_MISSING | PEER_GYRO_NONFINITE | PEER_GYRO_RANGE)

static inline bool peer_finite3(const float v[3])
{
    return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]);
}

static inline bool peer_within3(const float v[3], float vmax)
{
    return fabsf(v[0]) <= vmax && fabsf(v[1]) <= vmax && fabsf(v[2]) <= vmax;
}

/* 0 if an aiding sample with |v|^2 = n2 is usable, else its skip bit */
static inline uint32_t peer_aiding(const float v[3], float n2, float vmax, float min_norm,
                                   uint32_t nonfinite, uint32_t range, uint32_t zero)
{
    if (n2 < vmax * vmax && n2 >= min_norm * min_norm) {
        return 0u;
    }
    if (!peer_finite3(v)) {
        return nonfinite;
    }
    if (!peer_within3(v, vmax)) {
        return range;
    }
    return n2 >= min_norm * min_norm ? 0u : zero;
}

/* A refusal (status & PEER_REFUSED), or the skip bits of the aiding samples and which are
 * usable; an and mn are |accel|^2 and |mag|^2. */
static inline uint32_t peer_check_inputs(const peer_input *in, float dt, float an, float mn,
                                         bool *use_accel, bool *use_mag)
{
    if (!(dt > 0.0f && dt <= PEER_DT_MAX)) {
        return (isfinite(dt) && dt > 0.0f) ? PEER_DT_TOO_LARGE : PEER_DT_INVALID;
    }
    if ((in->valid & PEER_VALID_GYRO) == 0u) {
        return PEER_GYRO_MISSING;
    }
    const float *g = in->gyro;
    if (!(g[0] * g[0] + g[1] * g[1] + g[2] * g[2] < PEER_GYRO_MAX * PEER_GYRO_MAX)) {
        if (!peer_finite3(g)) {
            return PEER_GYRO_NONFINITE;
        }
        if (!peer_within3(g, PEER_GYRO_MAX)) {
            return PEER_GYRO_RANGE;
        }
    }
    uint32_t status = 0u;
    *use_accel = false;
    if ((in->valid & PEER_VALID_ACCEL) != 0u) {
        const uint32_t skip = peer_aiding(in->accel, an, PEER_ACCEL_MAX, PEER_ACCEL_MIN_NORM,
                                          PEER_ACCEL_NONFINITE, PEER_ACCEL_RANGE, PEER_ACCEL_ZERO);
        *use_accel = skip == 0u;
        status |= skip;
    }
    *use_mag = false;
    if ((in->valid & PEER_VALID_MAG) != 0u) {
        const uint32_t skip = peer_aiding(in->mag, mn, PEER_MAG_MAX, PEER_MAG_MIN_NORM,
                                          PEER_MAG_NONFINITE, PEER_MAG_RANGE, PEER_MAG_ZERO);
        *use_mag = skip == 0u;
        status |= skip;
    }
    return status;
}

#endif
