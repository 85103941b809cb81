/*
 * soak.c - long float soak of a generated filter over synthesised varied motion.
 *
 * Compiled per filter with the layout header written by src/ahrsgen/check/harden.py (see
 * src/ahrsgen/sim/fuzz/ahrs_invariants.h) and the generated source; run as
 *     soak STEPS SEED GLITCH_RATE [MOTION [DECLINATION INCLINATION [GYRO_BIAS_SCALE]]]
 * and prints one JSON object on stdout (exit 1 if any invariant was violated).
 *
 * Motion (truth in double): roll and pitch are damped random oscillations (std ~25 deg and
 * ~15 deg), yaw follows a random turn rate (std 0.3 rad/s); every 120 s a 1 s barrel roll
 * (roll + 360 deg) and every 300 s a 3 s loop (pitch + 360 deg, through +-90 deg pitch).
 * Flight at 15 m/s along the heading, so the specific force holds the turn's centripetal
 * acceleration. IMU at 100 Hz with +-10 % dt jitter, magnetometer every 2nd step, GPS velocity
 * every 20th step (5 Hz). Unit magnetic field with the declination and inclination given on the
 * command line (harden.py passes the filter's own, so heading errors are not site mismatch).
 * Sensor errors: gyro bias [0.01 -0.015 0.008] rad/s + 0.002 rad/s white noise, accel
 * 0.05 m/s^2, mag 0.006 (field units), GPS 0.1 m/s.
 *
 * Glitches: with probability GLITCH_RATE per step one of 13 faults is injected (NaN or Inf
 * samples, zero vectors, dt 0 / negative / 10 s, gyro bit dropped, a 60 rad/s gyro spike, a
 * 1000 m/s^2 accelerometer spike, a denormal magnetometer).
 *
 * After every step: the invariants of ahrs_invariants.h (finite state, unit quaternions,
 * covariance symmetric positive definite, normalised weights, Euler angles in range).
 */
#define _POSIX_C_SOURCE 199309L
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "ahrs_invariants.h"

/* ---- random numbers: xoshiro256** seeded by SplitMix64 ---- */
static uint64_t rs[4];

static uint64_t rotl64(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }

static uint64_t rnext(void)
{
    const uint64_t r = rotl64(rs[1] * 5u, 7) * 9u;
    const uint64_t t = rs[1] << 17;
    rs[2] ^= rs[0];
    rs[3] ^= rs[1];
    rs[1] ^= rs[2];
    rs[0] ^= rs[3];
    rs[2] ^= t;
    rs[3] = rotl64(rs[3], 45);
    return r;
}

static void rseed(uint64_t seed)
{
    for (int i = 0; i < 4; i++) {
        uint64_t z = (seed += 0x9e3779b97f4a7c15ull);
        z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
        z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
        rs[i] = z ^ (z >> 31);
    }
}

static double urand(void) { return ((double)(rnext() >> 11) + 0.5) * (1.0 / 9007199254740992.0); }

static double nrand(void)
{
    const double u1 = urand(), u2 = urand();
    return sqrt(-2.0 * log(u1)) * cos(6.283185307179586 * u2);
}

/* ---- quaternion helpers (double, Hamilton, [w x y z]) ---- */
static void qmul(const double a[4], const double b[4], double o[4])
{
    const double w = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3];
    const double x = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2];
    const double y = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1];
    const double z = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0];
    o[0] = w; o[1] = x; o[2] = y; o[3] = z;
}

/* q = qz(yaw) (x) qy(pitch) (x) qx(roll), body -> NED */
static void q_from_euler(double roll, double pitch, double yaw, double q[4])
{
    const double qx[4] = { cos(0.5 * roll), sin(0.5 * roll), 0.0, 0.0 };
    const double qy[4] = { cos(0.5 * pitch), 0.0, sin(0.5 * pitch), 0.0 };
    const double qz[4] = { cos(0.5 * yaw), 0.0, 0.0, sin(0.5 * yaw) };
    double t[4];
    qmul(qz, qy, t);
    qmul(t, qx, q);
}

/* v_body = R(q)^T v_ned */
static void rot_to_body(const double q[4], const double v[3], double o[3])
{
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    const double R[3][3] = {
        { 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y) },
        { 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x) },
        { 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y) },
    };
    for (int i = 0; i < 3; i++) {
        o[i] = R[0][i] * v[0] + R[1][i] * v[1] + R[2][i] * v[2];
    }
}

/* body rate that takes q0 to q1 in dt (constant-rate rotation) */
static void body_rate(const double q0[4], const double q1[4], double dt, double w[3])
{
    const double c[4] = { q0[0], -q0[1], -q0[2], -q0[3] };
    double d[4];
    qmul(c, q1, d);
    if (d[0] < 0.0) {
        for (int i = 0; i < 4; i++) d[i] = -d[i];
    }
    const double vn = sqrt(d[1] * d[1] + d[2] * d[2] + d[3] * d[3]);
    const double k = vn > 1e-15 ? 2.0 * atan2(vn, d[0]) / vn / dt : 2.0 / dt;
    for (int i = 0; i < 3; i++) w[i] = k * d[i + 1];
}

/* damped oscillator driven by white noise: stationary std sigma */
typedef struct { double x, v, w, zeta, q; } osc;

static void osc_init(osc *o, double w, double zeta, double sigma)
{
    o->x = 0.0; o->v = 0.0; o->w = w; o->zeta = zeta;
    o->q = sigma * sqrt(4.0 * zeta * w * w * w);
}

static void osc_step(osc *o, double dt)
{
    o->v += (-2.0 * o->zeta * o->w * o->v - o->w * o->w * o->x) * dt + o->q * sqrt(dt) * nrand();
    o->x += o->v * dt;
}

/* 0 -> 1 smoothly over [t0, t0 + T] */
static double ramp(double t, double t0, double T)
{
    if (t <= t0) return 0.0;
    if (t >= t0 + T) return 1.0;
    return 0.5 - 0.5 * cos(3.141592653589793 * (t - t0) / T);
}

#define NDEC 10

int main(int argc, char **argv)
{
    if (argc < 4) {
        fprintf(stderr, "usage: %s STEPS SEED GLITCH_RATE [MOTION: 1 varied (default), 0 gentle] [DECLINATION INCLINATION (rad)] [GYRO_BIAS_SCALE]\n", argv[0]);
        return 2;
    }
    const uint64_t steps = strtoull(argv[1], NULL, 10);
    const uint64_t seed = strtoull(argv[2], NULL, 10);
    const double glitch_rate = strtod(argv[3], NULL);
    const int varied = argc > 4 ? atoi(argv[4]) != 0 : 1;
    const double decl = argc > 6 ? strtod(argv[5], NULL) : 0.0;
    const double incl = argc > 6 ? strtod(argv[6], NULL) : 1.0;
    const double bias_scale = argc > 7 ? strtod(argv[7], NULL) : 1.0;
    rseed(seed);

    const double g = 9.80665, V = 15.0, dt0 = 0.01, settle = 30.0;
    const double bias[3] = { 0.01 * bias_scale, -0.015 * bias_scale, 0.008 * bias_scale };
    /* unit Earth field, NED (the filter's own declination/inclination, so heading is comparable) */
    const double m_ned[3] = { cos(incl) * cos(decl), cos(incl) * sin(decl), sin(incl) };
    osc roll, pitch;
    osc_init(&roll, 0.5, 0.7, varied ? 0.44 : 0.09);
    osc_init(&pitch, 0.5, 0.7, varied ? 0.26 : 0.05);
    double yaw = 0.3, yaw_rate = 0.0;
    const double yaw_tau = 5.0, yaw_sigma = varied ? 0.3 : 0.05;

    double t = 0.0;
    double q_true[4], q_prev[4];
    q_from_euler(0.0, 0.0, yaw, q_true);
    double v_prev[3] = { V * cos(yaw), V * sin(yaw), 0.0 };

    ahrs_state s;
    PFX(init)(&s);
    ahrs_inv inv, dec[NDEC];
    ahrs_inv_reset(&inv);
    for (int i = 0; i < NDEC; i++) ahrs_inv_reset(&dec[i]);

    uint64_t violations = 0, first_violation = 0, refused = 0, glitches = 0, flagged = 0;
    uint32_t status_or = 0u;
    char first_msg[256] = "";
    double err_sum2 = 0.0, err_max = 0.0, err_max_after_glitch_free = 0.0;
    uint64_t err_n = 0, since_glitch = 1000000;
    double dec_err2[NDEC] = { 0.0 };
    uint64_t dec_err_n[NDEC] = { 0 };
    double step_ns = 0.0;
    struct timespec w0, w1, a, b;
    clock_gettime(CLOCK_MONOTONIC, &w0);

    for (uint64_t k = 0; k < steps; k++) {
        /* truth */
        const double dt = dt0 * (1.0 + 0.1 * (2.0 * urand() - 1.0));
        t += dt;
        osc_step(&roll, dt);
        osc_step(&pitch, dt);
        yaw_rate += -yaw_rate / yaw_tau * dt + yaw_sigma * sqrt(2.0 / yaw_tau) * sqrt(dt) * nrand();
        yaw += yaw_rate * dt;
        if (yaw > 3.141592653589793) yaw -= 6.283185307179586;
        if (yaw < -3.141592653589793) yaw += 6.283185307179586;
        const double tf = fmod(t - 60.0 + 120.0, 120.0), tl = fmod(t - 150.0 + 300.0, 300.0);
        const double flip = varied && t > 60.0 ? 6.283185307179586 * ramp(tf, 0.0, 1.0) : 0.0;
        const double loop = varied && t > 150.0 ? 6.283185307179586 * ramp(tl, 0.0, 3.0) : 0.0;
        for (int i = 0; i < 4; i++) q_prev[i] = q_true[i];
        q_from_euler(roll.x + flip, pitch.x + loop, yaw, q_true);
        /* keep sign continuity for the rate computation only */
        const double v[3] = { V * cos(yaw), V * sin(yaw), 0.0 };
        const double acc[3] = { (v[0] - v_prev[0]) / dt, (v[1] - v_prev[1]) / dt, (v[2] - v_prev[2]) / dt };
        for (int i = 0; i < 3; i++) v_prev[i] = v[i];

        /* sensors */
        double w[3], f_ned[3], f[3], m[3];
        body_rate(q_prev, q_true, dt, w);
        f_ned[0] = acc[0]; f_ned[1] = acc[1]; f_ned[2] = acc[2] - g;
        rot_to_body(q_true, f_ned, f);
        rot_to_body(q_true, m_ned, m);
        ahrs_input in;
        memset(&in, 0, sizeof in);
        for (int i = 0; i < 3; i++) {
            in.gyro[i] = (ahrs_real)(w[i] + bias[i] + 0.002 * nrand());
            in.accel[i] = (ahrs_real)(f[i] + 0.05 * nrand());
            in.mag[i] = (ahrs_real)(m[i] + 0.006 * nrand());
            in.gps_vel_ned[i] = (ahrs_real)(v[i] + 0.1 * nrand());
        }
        in.valid = 0x3u | ((k % 2u) == 0u ? 0x4u : 0u) | ((k % 20u) == 0u ? 0x8u : 0u);
        ahrs_real dt_in = (ahrs_real)dt;
        if (glitch_rate > 0.0 && urand() < glitch_rate) {
            glitches++;
            since_glitch = 0;
            switch ((int)(urand() * 13.0)) {
            case 0: in.gyro[(int)(urand() * 3.0)] = (ahrs_real)NAN; break;
            case 1: in.accel[(int)(urand() * 3.0)] = (ahrs_real)INFINITY; break;
            case 2: in.mag[(int)(urand() * 3.0)] = (ahrs_real)NAN; in.valid |= 0x4u; break;
            case 3: in.accel[0] = (ahrs_real)1000.0; break;
            case 4: in.accel[0] = in.accel[1] = in.accel[2] = (ahrs_real)0.0; break;
            case 5: in.mag[0] = in.mag[1] = in.mag[2] = (ahrs_real)0.0; in.valid |= 0x4u; break;
            case 6: dt_in = (ahrs_real)0.0; break;
            case 7: dt_in = (ahrs_real)10.0; break;
            case 8: dt_in = (ahrs_real)-0.01; break;
            case 9: in.valid &= ~0x1u; break;
            case 10: in.gps_vel_ned[1] = (ahrs_real)NAN; in.valid |= 0x8u; break;
            case 11: in.gyro[2] = (ahrs_real)60.0; break;
            default: in.mag[0] = (ahrs_real)1e-40; in.mag[1] = in.mag[2] = (ahrs_real)0.0; in.valid |= 0x4u; break;
            }
        }

        /* filter */
        clock_gettime(CLOCK_MONOTONIC, &a);
        const uint32_t st = PFX(step)(&s, &in, dt_in);
        clock_gettime(CLOCK_MONOTONIC, &b);
        step_ns += (double)(b.tv_sec - a.tv_sec) * 1e9 + (double)(b.tv_nsec - a.tv_nsec);
        status_or |= st;
        if (st & (uint32_t)AHRS_REFUSED_MASK) refused++;
        if (st != 0u) flagged++;

        /* invariants */
        const int d = (int)((k * NDEC) / (steps ? steps : 1));
        const int ok1 = ahrs_check_state(&s, &dec[d]);
        const int ok2 = (st & ~(uint32_t)AHRS_STATUS_ALL) == 0u;
        if (!ok1 || !ok2) {
            if (violations == 0) {
                first_violation = k;
                (void)snprintf(first_msg, sizeof first_msg, "%s", ok1 ? "undocumented status bit" : dec[d].msg);
            }
            violations++;
        }

        /* attitude error vs truth (informative) */
        if (t > settle) {
            double dot = 0.0;
            for (int i = 0; i < 4; i++) dot += (double)s.q[i] * q_true[i];
            dot = fabs(dot);
            const double e = 2.0 * acos(dot > 1.0 ? 1.0 : dot) * 57.29577951308232;
            if (isfinite(e)) {
                err_sum2 += e * e;
                err_n++;
                dec_err2[d] += e * e;
                dec_err_n[d]++;
                if (e > err_max) err_max = e;
                if (since_glitch > 3000 && e > err_max_after_glitch_free) err_max_after_glitch_free = e;
            }
        }
        since_glitch++;
    }
    clock_gettime(CLOCK_MONOTONIC, &w1);
    const double wall = (double)(w1.tv_sec - w0.tv_sec) + 1e-9 * (double)(w1.tv_nsec - w0.tv_nsec);

    /* combine deciles */
    for (int i = 0; i < NDEC; i++) {
        if (dec[i].max_qnorm_err > inv.max_qnorm_err) inv.max_qnorm_err = dec[i].max_qnorm_err;
        if (dec[i].max_asym > inv.max_asym) inv.max_asym = dec[i].max_asym;
        if (dec[i].max_asym_rel > inv.max_asym_rel) inv.max_asym_rel = dec[i].max_asym_rel;
        if (dec[i].min_pivot < inv.min_pivot) inv.min_pivot = dec[i].min_pivot;
        if (dec[i].min_pivot_rel < inv.min_pivot_rel) inv.min_pivot_rel = dec[i].min_pivot_rel;
        if (dec[i].max_diag > inv.max_diag) inv.max_diag = dec[i].max_diag;
        if (dec[i].max_wsum_err > inv.max_wsum_err) inv.max_wsum_err = dec[i].max_wsum_err;
    }
#ifdef AHRS_FOR_EACH_COV
    const int has_cov = 1;
#else
    const int has_cov = 0;
#endif
#ifdef AHRS_WEIGHTS_FIELD
    const int has_w = 1;
#else
    const int has_w = 0;
#endif
    printf("{\n");
    printf("  \"filter\": \"%s\",\n  \"precision\": \"%s\",\n", AHRS_STR(AHRS_PREFIX), sizeof(ahrs_real) == 4u ? "float" : "double");
    printf("  \"steps\": %llu,\n  \"seed\": %llu,\n  \"simulated_s\": %.1f,\n", (unsigned long long)steps,
           (unsigned long long)seed, t);
    printf("  \"motion\": \"%s\",\n  \"mag_declination_rad\": %.6g,\n  \"mag_inclination_rad\": %.6g,\n"
           "  \"gyro_bias_scale\": %g,\n", varied ? "varied" : "gentle", decl, incl, bias_scale);
    printf("  \"glitch_rate\": %g,\n  \"glitches\": %llu,\n  \"refused\": %llu,\n  \"flagged\": %llu,\n  \"status_or\": %u,\n",
           glitch_rate, (unsigned long long)glitches, (unsigned long long)refused, (unsigned long long)flagged, status_or);
    printf("  \"violations\": %llu,\n  \"first_violation_step\": %lld,\n  \"first_violation\": \"%s\",\n",
           (unsigned long long)violations, violations ? (long long)first_violation : -1LL, first_msg);
    printf("  \"qnorm_tol\": %.3g,\n  \"max_qnorm_err\": %.6g,\n", (double)AHRS_QNORM_TOL, inv.max_qnorm_err);
    printf("  \"has_covariance\": %s,\n", has_cov ? "true" : "false");
    if (has_cov) {
        printf("  \"max_asym\": %.6g,\n  \"max_asym_rel\": %.6g,\n  \"min_pivot\": %.6g,\n  \"min_pivot_rel\": %.6g,\n"
               "  \"max_cov_diag\": %.6g,\n", inv.max_asym, inv.max_asym_rel, inv.min_pivot, inv.min_pivot_rel, inv.max_diag);
    }
    if (has_w) {
        printf("  \"max_weight_sum_err\": %.6g,\n", inv.max_wsum_err);
    }
    printf("  \"deciles\": {\"max_qnorm_err\": [");
    for (int i = 0; i < NDEC; i++) printf("%s%.3g", i ? ", " : "", dec[i].max_qnorm_err);
    printf("]");
    if (has_cov) {
        printf(", \"max_asym_rel\": [");
        for (int i = 0; i < NDEC; i++) printf("%s%.3g", i ? ", " : "", dec[i].max_asym_rel);
        printf("], \"min_pivot\": [");
        for (int i = 0; i < NDEC; i++) printf("%s%.3g", i ? ", " : "", dec[i].min_pivot);
        printf("], \"min_pivot_rel\": [");
        for (int i = 0; i < NDEC; i++) printf("%s%.3g", i ? ", " : "", dec[i].min_pivot_rel);
        printf("]");
    }
    printf(", \"att_err_rms_deg\": [");
    for (int i = 0; i < NDEC; i++) printf("%s%.3g", i ? ", " : "", dec_err_n[i] ? sqrt(dec_err2[i] / (double)dec_err_n[i]) : 0.0);
    printf("]},\n");
    printf("  \"att_err_rms_deg\": %.4g,\n  \"att_err_max_deg\": %.4g,\n  \"att_err_max_glitch_free_deg\": %.4g,\n",
           err_n ? sqrt(err_sum2 / (double)err_n) : 0.0, err_max, err_max_after_glitch_free);
    printf("  \"ns_per_step\": %.1f,\n  \"wall_s\": %.2f\n}\n", steps ? step_ns / (double)steps : 0.0, wall);
    return violations ? 1 : 0;
}
