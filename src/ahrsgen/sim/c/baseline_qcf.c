/*
 * baseline_qcf.c - hand-written QCF (Lü, Xiao, Hu 2014 as fixed by SPEC.md), float only.
 *
 * FQA reference attitude (half-angle form, FRD/NED), error q~ = q^-1 (x) Q_r with q~0 >= 0,
 * beta = w - b + kp q~, b <- b - ki q~ dt, q <- normalise(q (x) exp(beta dt / 2)); GPS motion
 * acceleration by the lagged differentiator (eq. 29, coefficients scaled to unit ramp gain)
 * removed from the specific force when ||f| - g| exceeds the threshold. Gains are the
 * defaults of src/ahrsgen/filters/qcf/defaults.toml.
 */
#include "baseline_qcf.h"

#include <math.h>

#define KP 0.3f
#define KI 0.002f
#define GPS_PERIOD 0.2f
#define GPS_TIMEOUT 1.0f
#define MOTION_THRESHOLD 0.3f
#define DT_MAX 0.5f
#define GYRO_MAX 70.0f
#define ACCEL_MIN 0.5f
#define ACCEL_MAX 2000.0f
#define MAG_MIN 1e-6f
#define MAG_MAX 1e6f
#define G0 9.80665f
/* eq. 29 coefficients divided by c1 + 2 c2 + 3 c3 = 0.9854 (unit gain on a ramp) */
#define C1 (0.0971f / 0.9854f)
#define C2 (0.1662f / 0.9854f)
#define C3 (0.1853f / 0.9854f)

enum {
    ST_DT_INVALID = 1u << 0, ST_DT_TOO_LARGE = 1u << 1, ST_GYRO_MISSING = 1u << 2,
    ST_GYRO_NONFINITE = 1u << 3, ST_ACCEL_NONFINITE = 1u << 4, ST_ACCEL_ZERO = 1u << 5,
    ST_MAG_NONFINITE = 1u << 6, ST_MAG_ZERO = 1u << 7, ST_GPS_NONFINITE = 1u << 8,
    ST_GYRO_RANGE = 1u << 9, ST_ACCEL_RANGE = 1u << 10, ST_MAG_RANGE = 1u << 11
};

static void qmul(const float a[4], const float b[4], float r[4])
{
    const float w = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3];
    const float x = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2];
    const float y = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1];
    const float z = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0];
    r[0] = w; r[1] = x; r[2] = y; r[3] = z;
}

static void qnormalise(float q[4])
{
    const float inv = 1.0f / sqrtf(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    q[0] *= inv; q[1] *= inv; q[2] *= inv; q[3] *= inv;
}

/* v_body = R(q)^T v_ned */
static void rotate_to_body(const float q[4], const float v[3], float out[3])
{
    const float w = q[0], x = q[1], y = q[2], z = q[3];
    out[0] = (1.0f - 2.0f * (y * y + z * z)) * v[0] + 2.0f * (x * y + w * z) * v[1] + 2.0f * (x * z - w * y) * v[2];
    out[1] = 2.0f * (x * y - w * z) * v[0] + (1.0f - 2.0f * (x * x + z * z)) * v[1] + 2.0f * (y * z + w * x) * v[2];
    out[2] = 2.0f * (x * z + w * y) * v[0] + 2.0f * (y * z - w * x) * v[1] + (1.0f - 2.0f * (x * x + y * y)) * v[2];
}

/* cos and sin of half the angle whose cos is c and sin has the sign of s */
static void half_angle(float c, float s, float *ch, float *sh)
{
    if (c > 1.0f) c = 1.0f;
    if (c < -1.0f) c = -1.0f;
    *ch = sqrtf(0.5f * (1.0f + c));
    *sh = sqrtf(0.5f * (1.0f - c));
    if (s < 0.0f) *sh = -*sh;
}

/* FQA tilt: pitch then roll from the normalised specific force */
static void fqa_tilt(const float f[3], float q[4])
{
    const float inv = 1.0f / sqrtf(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
    const float ax = f[0] * inv, ay = f[1] * inv, az = f[2] * inv;
    float s_th = ax, c_th, s_ph, c_ph, chp, shp, chr, shr;
    if (s_th > 1.0f) s_th = 1.0f;
    if (s_th < -1.0f) s_th = -1.0f;
    c_th = sqrtf(1.0f - s_th * s_th);
    half_angle(c_th, s_th, &chp, &shp);
    if (c_th < 1e-6f) {
        s_ph = 0.0f; c_ph = 1.0f;
    } else {
        s_ph = -ay / c_th; c_ph = -az / c_th;
    }
    half_angle(c_ph, s_ph, &chr, &shr);
    /* q_pitch (x) q_roll = [chp,0,shp,0] (x) [chr,shr,0,0] */
    q[0] = chp * chr;
    q[1] = chp * shr;
    q[2] = shp * chr;
    q[3] = -shp * shr;
}

static void fqa(const float f[3], const float m[3], float q[4])
{
    float qt[4], ml[3], ch, sh, n;
    fqa_tilt(f, qt);
    /* field in the levelled frame: R(qt) m */
    {
        const float w = qt[0], x = qt[1], y = qt[2], z = qt[3];
        ml[0] = (1.0f - 2.0f * (y * y + z * z)) * m[0] + 2.0f * (x * y - w * z) * m[1] + 2.0f * (x * z + w * y) * m[2];
        ml[1] = 2.0f * (x * y + w * z) * m[0] + (1.0f - 2.0f * (x * x + z * z)) * m[1] + 2.0f * (y * z - w * x) * m[2];
    }
    n = sqrtf(ml[0] * ml[0] + ml[1] * ml[1]);
    if (n < 1e-30f) n = 1e-30f;
    half_angle(ml[0] / n, -ml[1] / n, &ch, &sh);
    {
        const float qy[4] = { ch, 0.0f, 0.0f, sh };
        qmul(qy, qt, q);
    }
}

static float yaw_of(const float q[4])
{
    return atan2f(2.0f * (q[0] * q[3] + q[1] * q[2]), 1.0f - 2.0f * (q[2] * q[2] + q[3] * q[3]));
}

/* q <- normalise(q (x) exp([0, r/2])) */
static void integrate(float q[4], const float r[3])
{
    const float vx = 0.5f * r[0], vy = 0.5f * r[1], vz = 0.5f * r[2];
    const float n2 = vx * vx + vy * vy + vz * vz;
    const float n = sqrtf(n2);
    float e[4], k;
    if (n < 1e-4f) {
        e[0] = 1.0f - 0.5f * n2;
        k = 1.0f - n2 / 6.0f;
    } else {
        e[0] = cosf(n);
        k = sinf(n) / n;
    }
    e[1] = k * vx; e[2] = k * vy; e[3] = k * vz;
    qmul(q, e, q);
    qnormalise(q);
}

static int finite3(const float v[3])
{
    return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]);
}

/* 0: usable; else the status bit that skips it */
static uint32_t check_vector(const float v[3], float vmax, float vmin, uint32_t nonfinite, uint32_t range, uint32_t zero)
{
    if (!finite3(v)) return nonfinite;
    if (fabsf(v[0]) > vmax || fabsf(v[1]) > vmax || fabsf(v[2]) > vmax) return range;
    if (v[0] * v[0] + v[1] * v[1] + v[2] * v[2] < vmin * vmin) return zero;
    return 0u;
}

void baseline_qcf_init(baseline_qcf_state *s)
{
    uint32_t i;
    s->q[0] = 1.0f; s->q[1] = 0.0f; s->q[2] = 0.0f; s->q[3] = 0.0f;
    for (i = 0u; i < 3u; i++) { s->gyro_bias[i] = 0.0f; s->motion_accel[i] = 0.0f; }
    for (i = 0u; i < 21u; i++) s->gps_vel_hist[i] = 0.0f;
    s->gps_age = 1e3f;
    s->gps_count = 0u;
    s->initialised = 0u;
}

baseline_qcf_status baseline_qcf_step(baseline_qcf_state *s, const baseline_qcf_input *in, float dt)
{
    uint32_t status = 0u, i, bad;
    int use_accel = 0, use_mag = 0, use_gps = 0;

    if (!isfinite(dt) || !(dt > 0.0f)) return ST_DT_INVALID;
    if (dt > DT_MAX) return ST_DT_TOO_LARGE;
    if ((in->valid & 1u) == 0u) return ST_GYRO_MISSING;
    if (!finite3(in->gyro)) return ST_GYRO_NONFINITE;
    if (fabsf(in->gyro[0]) > GYRO_MAX || fabsf(in->gyro[1]) > GYRO_MAX || fabsf(in->gyro[2]) > GYRO_MAX) {
        return ST_GYRO_RANGE;
    }
    if (in->valid & 2u) {
        bad = check_vector(in->accel, ACCEL_MAX, ACCEL_MIN, ST_ACCEL_NONFINITE, ST_ACCEL_RANGE, ST_ACCEL_ZERO);
        status |= bad;
        use_accel = (bad == 0u);
    }
    if (in->valid & 4u) {
        bad = check_vector(in->mag, MAG_MAX, MAG_MIN, ST_MAG_NONFINITE, ST_MAG_RANGE, ST_MAG_ZERO);
        status |= bad;
        use_mag = (bad == 0u);
    }
    if (in->valid & 8u) {
        if (finite3(in->gps_vel_ned)) use_gps = 1;
        else status |= ST_GPS_NONFINITE;
    }

    if (use_gps) {
        if (s->gps_age > GPS_TIMEOUT) s->gps_count = 0u;
        for (i = 0u; i < 18u; i++) s->gps_vel_hist[i] = s->gps_vel_hist[i + 3u];
        for (i = 0u; i < 3u; i++) s->gps_vel_hist[18u + i] = in->gps_vel_ned[i];
        if (s->gps_count < 7u) s->gps_count++;
        s->gps_age = 0.0f;
        if (s->gps_count == 7u) {
            const float *v = s->gps_vel_hist;   /* v[3*j + axis], j = 0 oldest .. 6 newest */
            for (i = 0u; i < 3u; i++) {
                const float d1 = v[12u + i] - v[6u + i];
                const float d2 = v[15u + i] - v[3u + i];
                const float d3 = v[18u + i] - v[i];
                s->motion_accel[i] = (C1 * d1 + C2 * d2 + C3 * d3) / (2.0f * GPS_PERIOD);
            }
        }
    } else if (s->gps_age < 1e3f) {
        s->gps_age += dt;
    }

    if (use_accel) {
        float f[3] = { in->accel[0], in->accel[1], in->accel[2] };
        float q_ref[4], q_inv[4], e[4], beta[3];
        if (s->gps_count == 7u && s->gps_age <= GPS_TIMEOUT) {
            const float fn = sqrtf(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
            if (fabsf(fn - G0) > MOTION_THRESHOLD) {
                float a_b[3];
                rotate_to_body(s->q, s->motion_accel, a_b);
                f[0] -= a_b[0]; f[1] -= a_b[1]; f[2] -= a_b[2];
            }
        }
        if (use_mag) {
            fqa(f, in->mag, q_ref);
            if (s->initialised == 0u) {
                s->q[0] = q_ref[0]; s->q[1] = q_ref[1]; s->q[2] = q_ref[2]; s->q[3] = q_ref[3];
                s->initialised = 1u;
            }
        } else {
            float qt[4];
            const float half = 0.5f * yaw_of(s->q);
            const float qy[4] = { cosf(half), 0.0f, 0.0f, sinf(half) };
            fqa_tilt(f, qt);
            qmul(qy, qt, q_ref);
        }
        q_inv[0] = s->q[0]; q_inv[1] = -s->q[1]; q_inv[2] = -s->q[2]; q_inv[3] = -s->q[3];
        qmul(q_inv, q_ref, e);
        if (e[0] < 0.0f) { e[1] = -e[1]; e[2] = -e[2]; e[3] = -e[3]; }
        for (i = 0u; i < 3u; i++) {
            beta[i] = in->gyro[i] - s->gyro_bias[i] + KP * e[i + 1u];
            s->gyro_bias[i] -= KI * e[i + 1u] * dt;
        }
        for (i = 0u; i < 3u; i++) beta[i] *= dt;
        integrate(s->q, beta);
    } else {
        float r[3];
        for (i = 0u; i < 3u; i++) r[i] = (in->gyro[i] - s->gyro_bias[i]) * dt;
        integrate(s->q, r);
    }
    return status;
}

void baseline_qcf_euler(const baseline_qcf_state *s, float rpy[3])
{
    const float w = s->q[0], x = s->q[1], y = s->q[2], z = s->q[3];
    float sp = 2.0f * (w * y - x * z);
    if (sp > 1.0f) sp = 1.0f;
    if (sp < -1.0f) sp = -1.0f;
    rpy[0] = atan2f(2.0f * (w * x + y * z), 1.0f - 2.0f * (x * x + y * y));
    rpy[1] = asinf(sp);
    rpy[2] = atan2f(2.0f * (w * z + x * y), 1.0f - 2.0f * (y * y + z * z));
}
