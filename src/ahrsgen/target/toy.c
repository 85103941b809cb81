/* See toy.h. */
#include "toy.h"

#include <math.h>

void toy_init(toy_state *s)
{
    s->q[0] = 1.0f;
    s->q[1] = 0.0f;
    s->q[2] = 0.0f;
    s->q[3] = 0.0f;
    s->tilt[0] = 0.0f;
    s->tilt[1] = 0.0f;
}

uint32_t toy_step(toy_state *s, const toy_input *in, float dt)
{
    if (!(dt > 0.0f) || !(dt < 1.0f)) {
        return 1u;
    }
    if ((in->valid & 1u) == 0u) {
        return 4u;
    }
    const float wx = in->gyro[0], wy = in->gyro[1], wz = in->gyro[2];
    const float n = sqrtf(wx * wx + wy * wy + wz * wz);
    const float half = 0.5f * n * dt;
    const float c = cosf(half);
    const float k = (n > 1e-9f) ? sinf(half) / n : 0.5f * dt;
    const float dq[4] = {c, k * wx, k * wy, k * wz};
    const float *q = s->q;
    float r[4];
    r[0] = q[0] * dq[0] - q[1] * dq[1] - q[2] * dq[2] - q[3] * dq[3];
    r[1] = q[0] * dq[1] + q[1] * dq[0] + q[2] * dq[3] - q[3] * dq[2];
    r[2] = q[0] * dq[2] - q[1] * dq[3] + q[2] * dq[0] + q[3] * dq[1];
    r[3] = q[0] * dq[3] + q[1] * dq[2] - q[2] * dq[1] + q[3] * dq[0];
    const float inv = 1.0f / sqrtf(r[0] * r[0] + r[1] * r[1] + r[2] * r[2] + r[3] * r[3]);
    for (int i = 0; i < 4; i++) {
        s->q[i] = r[i] * inv;
    }
    if ((in->valid & 2u) != 0u) {
        const float fx = in->accel[0], fy = in->accel[1], fz = in->accel[2];
        s->tilt[0] += 0.02f * (atan2f(-fy, -fz) - s->tilt[0]);
        s->tilt[1] += 0.02f * (atan2f(fx, sqrtf(fy * fy + fz * fz)) - s->tilt[1]);
    }
    return 0u;
}
