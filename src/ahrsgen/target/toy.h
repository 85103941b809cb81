/* Toolchain bring-up filter for the ahrsgen target checks (not a product filter).
 * Same API shape as a generated filter: gyro integration with the exact quaternion
 * exponential (sqrtf, sinf, cosf) and an accelerometer tilt pull (atan2f), so the
 * cross build exercises hard-float code AND newlib's libm. */
#ifndef TOY_H
#define TOY_H

#include <stdint.h>

typedef struct {
    float q[4];
    float tilt[2];
} toy_state;

typedef struct {
    float gyro[3], accel[3], mag[3], gps_vel_ned[3];
    uint32_t valid;
} toy_input;

void toy_init(toy_state *s);
uint32_t toy_step(toy_state *s, const toy_input *in, float dt);

#endif
