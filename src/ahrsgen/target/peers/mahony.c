/* Mahony explicit complementary filter with integral feedback (Mahony et al. 2008); see
 * peers.h. */
#include <math.h>

#include "peers.h"

#define MAHONY_KP 1.0f
#define MAHONY_KI 0.05f

void mahony_init(mahony_state *s)
{
    s->q[0] = 1.0f;
    s->q[1] = 0.0f;
    s->q[2] = 0.0f;
    s->q[3] = 0.0f;
    s->integral[0] = 0.0f;
    s->integral[1] = 0.0f;
    s->integral[2] = 0.0f;
}

uint32_t mahony_step(mahony_state *s, const mahony_input *in, float dt)
{
    float q0 = s->q[0], q1 = s->q[1], q2 = s->q[2], q3 = s->q[3];
    float gx = in->gyro[0], gy = in->gyro[1], gz = in->gyro[2];
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
        const float q00 = q0 * q0, q01 = q0 * q1, q02 = q0 * q2, q03 = q0 * q3;
        const float q11 = q1 * q1, q12 = q1 * q2, q13 = q1 * q3;
        const float q22 = q2 * q2, q23 = q2 * q3, q33 = q3 * q3;
        /* earth-frame field h = R m and reference b = [|h_xy|, 0, h_z] */
        const float hx = 2.0f * (mx * (0.5f - q22 - q33) + my * (q12 - q03) + mz * (q13 + q02));
        const float hy = 2.0f * (mx * (q12 + q03) + my * (0.5f - q11 - q33) + mz * (q23 - q01));
        const float hz = 2.0f * (mx * (q13 - q02) + my * (q23 + q01) + mz * (0.5f - q11 - q22));
        const float bx = sqrtf(hx * hx + hy * hy), bz = hz;
        /* predicted directions in body: v = R^T d, w = R^T b */
        const float vx = 2.0f * (q13 - q02), vy = 2.0f * (q01 + q23), vz = q00 - q11 - q22 + q33;
        const float wx = 2.0f * (bx * (0.5f - q22 - q33) + bz * (q13 - q02));
        const float wy = 2.0f * (bx * (q12 - q03) + bz * (q01 + q23));
        const float wz = 2.0f * (bx * (q02 + q13) + bz * (0.5f - q11 - q22));
        /* error = measured x predicted, integral and proportional feedback */
        const float ex = (ay * vz - az * vy) + (my * wz - mz * wy);
        const float ey = (az * vx - ax * vz) + (mz * wx - mx * wz);
        const float ez = (ax * vy - ay * vx) + (mx * wy - my * wx);
        s->integral[0] += MAHONY_KI * ex * dt;
        s->integral[1] += MAHONY_KI * ey * dt;
        s->integral[2] += MAHONY_KI * ez * dt;
        gx += MAHONY_KP * ex + s->integral[0];
        gy += MAHONY_KP * ey + s->integral[1];
        gz += MAHONY_KP * ez + s->integral[2];
    }
    const float h = 0.5f * dt;
    const float n0 = q0 + h * (-q1 * gx - q2 * gy - q3 * gz);
    const float n1 = q1 + h * (q0 * gx + q2 * gz - q3 * gy);
    const float n2 = q2 + h * (q0 * gy - q1 * gz + q3 * gx);
    const float n3 = q3 + h * (q0 * gz + q1 * gy - q2 * gx);
    const float r = 1.0f / sqrtf(n0 * n0 + n1 * n1 + n2 * n2 + n3 * n3);
    s->q[0] = n0 * r;
    s->q[1] = n1 * r;
    s->q[2] = n2 * r;
    s->q[3] = n3 * r;
    return 0u;
}
