/* Madgwick's update behind the product's input checks: the like-for-like peer of the generated
 * Madgwick (examples/madgwick built with initialise = false), doing what that step does:
 * checks.h's refusals and skips with the same status bits; an exactly zero gyro sample skips
 * the whole update (as ahrs does); accelerometer and magnetometer: the MARG gradient step,
 * accelerometer only: the gravity-only step (eq. 25-26), neither: the gyro rate alone. Starts
 * at the identity like madgwick.c. The equations are madgwick.c's, written out again with the
 * gradient's accelerometer terms shared by both corrections: madgwick.c stays exactly as it
 * is, its instruction count being the counter's calibration. */
#include <math.h>

#include "checks.h"
#include "peers.h"

#define MADGWICK_BETA 0.1f

void madgwick_checked_init(madgwick_state *s)
{
    s->q[0] = 1.0f;
    s->q[1] = 0.0f;
    s->q[2] = 0.0f;
    s->q[3] = 0.0f;
}

uint32_t madgwick_checked_step(madgwick_state *s, const madgwick_input *in, float dt)
{
    float ax = -in->accel[0], ay = -in->accel[1], az = -in->accel[2]; /* measured down */
    float mx = in->mag[0], my = in->mag[1], mz = in->mag[2];
    const float an = ax * ax + ay * ay + az * az;
    const float mn = mx * mx + my * my + mz * mz;
    bool use_accel, use_mag;
    const uint32_t status = peer_check_inputs(in, dt, an, mn, &use_accel, &use_mag);
    if ((status & PEER_REFUSED) != 0u) {
        return status;
    }
    const float gx = in->gyro[0], gy = in->gyro[1], gz = in->gyro[2];
    if (gx == 0.0f && gy == 0.0f && gz == 0.0f) {
        return status;
    }
    float q0 = s->q[0], q1 = s->q[1], q2 = s->q[2], q3 = s->q[3];
    /* rate of change from the gyroscope: 0.5 q (x) [0, w] */
    float qd0 = 0.5f * (-q1 * gx - q2 * gy - q3 * gz);
    float qd1 = 0.5f * (q0 * gx + q2 * gz - q3 * gy);
    float qd2 = 0.5f * (q0 * gy - q1 * gz + q3 * gx);
    float qd3 = 0.5f * (q0 * gz + q1 * gy - q2 * gx);
    if (use_accel) {
        float r = 1.0f / sqrtf(an);
        ax *= r;
        ay *= r;
        az *= r;
        /* objective f = [R^T d - a; R^T b - m], d = [0, 0, 1] (eq. 25, 29) and its gradient J^T f */
        const float f0 = 2.0f * (q1 * q3 - q0 * q2) - ax;
        const float f1 = 2.0f * (q0 * q1 + q2 * q3) - ay;
        const float f2 = 2.0f * (0.5f - q1 * q1 - q2 * q2) - az;
        float s0 = -2.0f * q2 * f0 + 2.0f * q1 * f1;
        float s1 = 2.0f * q3 * f0 + 2.0f * q0 * f1 - 4.0f * q1 * f2;
        float s2 = -2.0f * q0 * f0 + 2.0f * q3 * f1 - 4.0f * q2 * f2;
        float s3 = 2.0f * q1 * f0 + 2.0f * q2 * f1;
        if (use_mag) {
            r = 1.0f / sqrtf(mn);
            mx *= r;
            my *= r;
            mz *= r;
            /* earth-frame field h = R m; reference b = [sqrt(hx^2 + hy^2), 0, hz] (eq. 45-46) */
            const float hx = mx * (q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3) + 2.0f * my * (q1 * q2 - q0 * q3)
                             + 2.0f * mz * (q1 * q3 + q0 * q2);
            const float hy = 2.0f * mx * (q1 * q2 + q0 * q3) + my * (q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3)
                             + 2.0f * mz * (q2 * q3 - q0 * q1);
            const float hz = 2.0f * mx * (q1 * q3 - q0 * q2) + 2.0f * my * (q2 * q3 + q0 * q1)
                             + mz * (q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3);
            const float bx = sqrtf(hx * hx + hy * hy), bz = hz;
            const float f3 = 2.0f * bx * (0.5f - q2 * q2 - q3 * q3) + 2.0f * bz * (q1 * q3 - q0 * q2) - mx;
            const float f4 = 2.0f * bx * (q1 * q2 - q0 * q3) + 2.0f * bz * (q0 * q1 + q2 * q3) - my;
            const float f5 = 2.0f * bx * (q0 * q2 + q1 * q3) + 2.0f * bz * (0.5f - q1 * q1 - q2 * q2) - mz;
            s0 += -2.0f * bz * q2 * f3 + (-2.0f * bx * q3 + 2.0f * bz * q1) * f4 + 2.0f * bx * q2 * f5;
            s1 += 2.0f * bz * q3 * f3 + (2.0f * bx * q2 + 2.0f * bz * q0) * f4 + (2.0f * bx * q3 - 4.0f * bz * q1) * f5;
            s2 += (-4.0f * bx * q2 - 2.0f * bz * q0) * f3 + (2.0f * bx * q1 + 2.0f * bz * q3) * f4
                  + (2.0f * bx * q0 - 4.0f * bz * q2) * f5;
            s3 += (-4.0f * bx * q3 + 2.0f * bz * q1) * f3 + (-2.0f * bx * q0 + 2.0f * bz * q2) * f4 + 2.0f * bx * q1 * f5;
        }
        const float sn = s0 * s0 + s1 * s1 + s2 * s2 + s3 * s3;
        if (sn > 0.0f) {
            r = 1.0f / sqrtf(sn);
            qd0 -= MADGWICK_BETA * s0 * r;
            qd1 -= MADGWICK_BETA * s1 * r;
            qd2 -= MADGWICK_BETA * s2 * r;
            qd3 -= MADGWICK_BETA * s3 * r;
        }
    }
    q0 += qd0 * dt;
    q1 += qd1 * dt;
    q2 += qd2 * dt;
    q3 += qd3 * dt;
    const float r = 1.0f / sqrtf(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3);
    s->q[0] = q0 * r;
    s->q[1] = q1 * r;
    s->q[2] = q2 * r;
    s->q[3] = q3 * r;
    return status;
}
