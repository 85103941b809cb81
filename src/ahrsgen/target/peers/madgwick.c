/* Madgwick MARG update, from the 2010 report's equations; see peers.h. */
#include <math.h>

#include "peers.h"

#define MADGWICK_BETA 0.1f

void madgwick_init(madgwick_state *s)
{
    s->q[0] = 1.0f;
    s->q[1] = 0.0f;
    s->q[2] = 0.0f;
    s->q[3] = 0.0f;
}

uint32_t madgwick_step(madgwick_state *s, const madgwick_input *in, float dt)
{
    float q0 = s->q[0], q1 = s->q[1], q2 = s->q[2], q3 = s->q[3];
    const float gx = in->gyro[0], gy = in->gyro[1], gz = in->gyro[2];
    /* rate of change from the gyroscope: 0.5 q (x) [0, w] */
    float qd0 = 0.5f * (-q1 * gx - q2 * gy - q3 * gz);
    float qd1 = 0.5f * (q0 * gx + q2 * gz - q3 * gy);
    float qd2 = 0.5f * (q0 * gy - q1 * gz + q3 * gx);
    float qd3 = 0.5f * (q0 * gz + q1 * gy - q2 * gx);

    float ax = -in->accel[0], ay = -in->accel[1], az = -in->accel[2]; /* measured down */
    float mx = in->mag[0], my = in->mag[1], mz = in->mag[2];
    const float an = ax * ax + ay * ay + az * az;
    const float mn = mx * mx + my * my + mz * mz;
    if (an > 0.0f && mn > 0.0f) {
        float r = 1.0f / sqrtf(an);
        ax *= r;
        ay *= r;
        az *= r;
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
        /* objective f = [R^T d - a; R^T b - m], d = [0, 0, 1] (eq. 25, 29) */
        const float f0 = 2.0f * (q1 * q3 - q0 * q2) - ax;
        const float f1 = 2.0f * (q0 * q1 + q2 * q3) - ay;
        const float f2 = 2.0f * (0.5f - q1 * q1 - q2 * q2) - az;
        const float f3 = 2.0f * bx * (0.5f - q2 * q2 - q3 * q3) + 2.0f * bz * (q1 * q3 - q0 * q2) - mx;
        const float f4 = 2.0f * bx * (q1 * q2 - q0 * q3) + 2.0f * bz * (q0 * q1 + q2 * q3) - my;
        const float f5 = 2.0f * bx * (q0 * q2 + q1 * q3) + 2.0f * bz * (0.5f - q1 * q1 - q2 * q2) - mz;
        /* gradient J^T f (eq. 26, 30, 34) */
        float s0 = -2.0f * q2 * f0 + 2.0f * q1 * f1 - 2.0f * bz * q2 * f3
                   + (-2.0f * bx * q3 + 2.0f * bz * q1) * f4 + 2.0f * bx * q2 * f5;
        float s1 = 2.0f * q3 * f0 + 2.0f * q0 * f1 - 4.0f * q1 * f2 + 2.0f * bz * q3 * f3
                   + (2.0f * bx * q2 + 2.0f * bz * q0) * f4 + (2.0f * bx * q3 - 4.0f * bz * q1) * f5;
        float s2 = -2.0f * q0 * f0 + 2.0f * q3 * f1 - 4.0f * q2 * f2 + (-4.0f * bx * q2 - 2.0f * bz * q0) * f3
                   + (2.0f * bx * q1 + 2.0f * bz * q3) * f4 + (2.0f * bx * q0 - 4.0f * bz * q2) * f5;
        float s3 = 2.0f * q1 * f0 + 2.0f * q2 * f1 + (-4.0f * bx * q3 + 2.0f * bz * q1) * f3
                   + (-2.0f * bx * q0 + 2.0f * bz * q2) * f4 + 2.0f * bx * q1 * f5;
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
    return 0u;
}
