/*
 * ahrs_invariants.h - physical invariants of a generated filter's state, checked in double.
 *
 * Shared by the libFuzzer harness (fuzz_step.c) and the soak test (../c/soak.c). Compiled
 * together with one generated filter and a layout header written from its manifest.json by
 * src/ahrsgen/check/harden.py (ahrs_layout.h), which defines:
 *   AHRS_PREFIX, AHRS_HEADER, AHRS_REAL            as for src/ahrsgen/sim/c/batch.c
 *   AHRS_REFUSED_MASK, AHRS_STATUS_ALL             refusal bits, every documented status bit
 *   AHRS_FOR_EACH_REAL(X, s)   X("name", pointer to first real, count) for every real field
 *   AHRS_FOR_EACH_QUAT(X, s)   X("name", pointer, number of quaternions, only_when_initialised)
 *   AHRS_FOR_EACH_COV(X, s)    (optional) X("name", pointer, n) for each n x n covariance,
 *                              row-major
 *   AHRS_WEIGHTS_FIELD, AHRS_WEIGHTS_COUNT (optional) particle weights
 *   AHRS_WEIGHT_SUM_FIELD      (optional, with the weights) their stored sum, for weights kept
 *                              unnormalised; without it the weights are normalised
 *   AHRS_INIT_FIELD                     (optional) the uint32 'initialised' flag
 *
 * Invariants (a violation is reported with the field and the numbers):
 *   - every real field is finite;
 *   - every quaternion has | |q| - 1 | <= AHRS_QNORM_TOL;
 *   - the covariance is symmetric, |P_ij - P_ji| <= AHRS_SYM_TOL * max_k P_kk (relative), and
 *     positive definite: every pivot of its LDL^T (Cholesky without square roots) in double
 *     is > 0;
 *   - particle weights are >= 0 and sum to 1 within AHRS_WSUM_TOL (relative to the stored sum,
 *     which is then > 0, if the filter keeps one);
 *   - the Euler angles are finite and in range (roll, yaw in [-pi, pi], pitch in [-pi/2, pi/2]).
 */
#ifndef AHRS_INVARIANTS_H
#define AHRS_INVARIANTS_H

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "ahrs_layout.h"
#include AHRS_HEADER

#define AHRS_CAT_(a, b) a##_##b
#define AHRS_CAT(a, b) AHRS_CAT_(a, b)
#define PFX(name) AHRS_CAT(AHRS_PREFIX, name)
#define AHRS_STR_(x) #x
#define AHRS_STR(x) AHRS_STR_(x)

typedef PFX(state) ahrs_state;
typedef PFX(input) ahrs_input;
typedef AHRS_REAL ahrs_real;

/* Tolerances: float keeps |q| within ~100 ulp of 1 after its per-step normalisation. */
#ifndef AHRS_QNORM_TOL
#define AHRS_QNORM_TOL (sizeof(ahrs_real) == 4u ? 1e-5 : 1e-12)
#endif
#ifndef AHRS_SYM_TOL
#define AHRS_SYM_TOL (sizeof(ahrs_real) == 4u ? 1e-5 : 1e-12)
#endif
#ifndef AHRS_WSUM_TOL
#define AHRS_WSUM_TOL (sizeof(ahrs_real) == 4u ? 1e-4 : 1e-10)
#endif

typedef struct {
    double max_qnorm_err;   /* max over quaternions of | |q| - 1 | */
    double max_asym;        /* max |P_ij - P_ji| */
    double max_asym_rel;    /* max |P_ij - P_ji| / max_k P_kk */
    double min_pivot;       /* smallest LDL^T pivot of P (absolute) */
    double min_pivot_rel;   /* smallest pivot_k / P_kk (1 = diagonal, -> 0 near singular) */
    double max_diag;        /* largest P_kk seen */
    double max_wsum_err;    /* | sum(w) - 1 | */
    char msg[256];          /* first violation of the last check, "" if none */
} ahrs_inv;

static void ahrs_inv_reset(ahrs_inv *v)
{
    memset(v, 0, sizeof *v);
    v->min_pivot = INFINITY;
    v->min_pivot_rel = INFINITY;
}

static double ahrs_max_(double a, double b) { return a > b ? a : b; }

#ifdef AHRS_FOR_EACH_COV
#define AHRS_COV_MAXDIM 32

static double ahrs_min_(double a, double b) { return a < b ? a : b; }

/* Symmetry and positive definiteness of one n x n row-major covariance (in double); on a
 * violation, 0 and a description in msg. */
static int ahrs_check_cov_(const char *name, const ahrs_real *P, int n, ahrs_inv *v, char *msg, size_t msg_size)
{
    double dmax = 0.0;
    msg[0] = '\0';
    if (n > AHRS_COV_MAXDIM) {
        (void)snprintf(msg, msg_size, "state.%s: dimension %d > AHRS_COV_MAXDIM", name, n);
        return 0;
    }
    for (int i = 0; i < n; i++) {
        dmax = ahrs_max_(dmax, fabs((double)P[i * n + i]));
    }
    v->max_diag = ahrs_max_(v->max_diag, dmax);
    double asym = 0.0;
    for (int i = 0; i < n; i++) {
        for (int j = i + 1; j < n; j++) {
            asym = ahrs_max_(asym, fabs((double)P[i * n + j] - (double)P[j * n + i]));
        }
    }
    const double asym_rel = dmax > 0.0 ? asym / dmax : asym;
    if (isfinite(asym)) {
        v->max_asym = ahrs_max_(v->max_asym, asym);
        v->max_asym_rel = ahrs_max_(v->max_asym_rel, asym_rel);
    }
    if (!(asym_rel <= AHRS_SYM_TOL)) {
        (void)snprintf(msg, msg_size,
                       "state.%s not symmetric: max |P_ij - P_ji| = %.3g (%.3g of max diag %.3g)",
                       name, asym, asym_rel, dmax);
        return 0;
    }
    /* LDL^T (Cholesky without square roots) of the symmetric part */
    double L[AHRS_COV_MAXDIM][AHRS_COV_MAXDIM];
    double D[AHRS_COV_MAXDIM];
    for (int j = 0; j < n; j++) {
        double d = (double)P[j * n + j];
        for (int k = 0; k < j; k++) {
            d -= L[j][k] * L[j][k] * D[k];
        }
        D[j] = d;
        const double pjj = (double)P[j * n + j];
        if (isfinite(d)) {
            v->min_pivot = ahrs_min_(v->min_pivot, d);
            if (pjj > 0.0) {
                v->min_pivot_rel = ahrs_min_(v->min_pivot_rel, d / pjj);
            }
        }
        if (!(d > 0.0)) {
            (void)snprintf(msg, msg_size,
                           "state.%s not positive definite: LDL^T pivot %d = %.3g (P_%d%d = %.3g)",
                           name, j, d, j, j, pjj);
            return 0;
        }
        for (int i = j + 1; i < n; i++) {
            double a = 0.5 * ((double)P[i * n + j] + (double)P[j * n + i]);
            for (int k = 0; k < j; k++) {
                a -= L[i][k] * L[j][k] * D[k];
            }
            L[i][j] = a / d;
        }
    }
    return 1;
}
#endif

/* Check the state; accumulate the figures in *v. Returns 1 if every invariant holds, else 0
 * with a description of the first violation in v->msg. */
static int ahrs_check_state(const ahrs_state *s, ahrs_inv *v)
{
    int ok = 1;
    v->msg[0] = '\0';
#define AHRS_FAIL_(...)                                              \
    do {                                                             \
        if (ok) {                                                    \
            (void)snprintf(v->msg, sizeof v->msg, __VA_ARGS__);      \
        }                                                            \
        ok = 0;                                                      \
    } while (0)

    /* 1. finiteness of every real field */
#define AHRS_X_FINITE_(name, ptr, count)                                             \
    for (uint32_t i_ = 0u; i_ < (uint32_t)(count); i_++) {                           \
        if (!isfinite((double)(ptr)[i_])) {                                          \
            AHRS_FAIL_("state.%s[%u] not finite (%g)", name, i_, (double)(ptr)[i_]); \
            break;                                                                   \
        }                                                                            \
    }
    AHRS_FOR_EACH_REAL(AHRS_X_FINITE_, s)
#undef AHRS_X_FINITE_

    /* 2. unit quaternions */
#ifdef AHRS_INIT_FIELD
    const int initialised_ = s->AHRS_INIT_FIELD != 0u;
#else
    const int initialised_ = 1;
#endif
#define AHRS_X_QUAT_(name, ptr, nq, need_init)                                              \
    if (!(need_init) || initialised_) {                                                     \
        for (uint32_t j_ = 0u; j_ < (uint32_t)(nq); j_++) {                                 \
            const ahrs_real *qq_ = &(ptr)[4u * j_];                                         \
            double n2_ = 0.0;                                                               \
            for (uint32_t i_ = 0u; i_ < 4u; i_++) {                                         \
                n2_ += (double)qq_[i_] * (double)qq_[i_];                                   \
            }                                                                               \
            const double e_ = fabs(sqrt(n2_) - 1.0);                                        \
            if (!(e_ <= AHRS_QNORM_TOL)) {                                                  \
                AHRS_FAIL_("state.%s quaternion %u: | |q| - 1 | = %.3g > %.1g "             \
                           "(q = %.9g %.9g %.9g %.9g)", name, j_, e_, (double)AHRS_QNORM_TOL, \
                           (double)qq_[0], (double)qq_[1], (double)qq_[2], (double)qq_[3]); \
            }                                                                               \
            if (isfinite(e_)) {                                                             \
                v->max_qnorm_err = ahrs_max_(v->max_qnorm_err, e_);                         \
            }                                                                               \
        }                                                                                   \
    }
    AHRS_FOR_EACH_QUAT(AHRS_X_QUAT_, s)
#undef AHRS_X_QUAT_

    /* 3. covariances symmetric positive definite */
#ifdef AHRS_FOR_EACH_COV
    char cov_msg_[200];
#define AHRS_X_COV_(name, ptr, n)                                           \
    if (!ahrs_check_cov_(name, (ptr), (n), v, cov_msg_, sizeof cov_msg_)) { \
        AHRS_FAIL_("%s", cov_msg_);                                         \
    }
    AHRS_FOR_EACH_COV(AHRS_X_COV_, s)
#undef AHRS_X_COV_
#endif

#ifdef AHRS_WEIGHTS_FIELD
    /* 4. particle weights: non-negative, normalised (by their stored sum, if kept) */
    {
        double sum = 0.0;
#ifdef AHRS_WEIGHT_SUM_FIELD
        const double norm = (double)s->AHRS_WEIGHT_SUM_FIELD;
        if (!(norm > 0.0)) {
            AHRS_FAIL_("state.%s = %.3g <= 0", AHRS_STR(AHRS_WEIGHT_SUM_FIELD), norm);
        }
#else
        const double norm = 1.0;
#endif
        for (uint32_t i = 0u; i < (uint32_t)AHRS_WEIGHTS_COUNT; i++) {
            const double w = (double)s->AHRS_WEIGHTS_FIELD[i];
            if (!(w >= 0.0)) {
                AHRS_FAIL_("state.%s[%u] = %.3g < 0", AHRS_STR(AHRS_WEIGHTS_FIELD), i, w);
            }
            sum += w;
        }
        const double e = fabs(sum / norm - 1.0);
        if (isfinite(e)) {
            v->max_wsum_err = ahrs_max_(v->max_wsum_err, e);
        }
        if (!(e <= AHRS_WSUM_TOL)) {
            AHRS_FAIL_("state.%s sum to %.9g", AHRS_STR(AHRS_WEIGHTS_FIELD), sum);
        }
    }
#endif

    /* 5. Euler angles of the estimate */
    {
        ahrs_real rpy[3];
        PFX(euler)(s, rpy);
        const double pi = 3.14159265358979323846 * (1.0 + 1e-6);
        if (!(fabs((double)rpy[0]) <= pi && fabs((double)rpy[1]) <= 0.5 * pi && fabs((double)rpy[2]) <= pi)) {
            AHRS_FAIL_("euler out of range or not finite: %g %g %g", (double)rpy[0], (double)rpy[1], (double)rpy[2]);
        }
    }
#undef AHRS_FAIL_
    return ok;
}

#endif /* AHRS_INVARIANTS_H */
