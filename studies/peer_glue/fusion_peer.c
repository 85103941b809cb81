/* x-io Fusion's AHRS (FusionAhrsUpdate, 9-axis) behind the harness shape; see external_peers.h.
 *
 * Settings: the README's table, "appropriate for most applications" (gain 0.5, acceleration and
 * magnetic rejection 10 degrees, rejection timeout 5 s: what older Fusion called
 * recoveryTriggerPeriod = 5 * sampleRate), gyroscope range 2000 deg/s. Convention NED: the
 * harness gives FRD body axes and the product's quaternions are body -> NED, so the outputs
 * compare as they are (the convention only picks the branch of HalfGravity/HalfWest). No
 * FusionBias (the old FusionOffset): the 1.3.3 README has no example that runs it. Fusion's own
 * defaults otherwise (fast inverse square root, inline functions).
 *
 * The step converts the harness's SI units to Fusion's (deg/s, g), passes dt with
 * FusionAhrsSetSamplePeriod as the README suggests for a measured period, then updates:
 * what firmware with SI sensors writes around Fusion.
 */
#include <stddef.h>

#include "FusionAhrs.h"
#include "external_peers.h"

#ifndef PEER_SAMPLE_RATE_HZ
#error "PEER_SAMPLE_RATE_HZ: the study passes the log's sample rate"
#endif

/* compile-time checks of the layout external_peers.h states (C99: a negative array size fails) */
typedef char fusion_state_bytes_check[sizeof(FusionAhrs) == FUSION_PEER_STATE_BYTES ? 1 : -1];
typedef char fusion_q_offset_check[offsetof(FusionAhrs, quaternion) == FUSION_PEER_Q_OFFSET ? 1 : -1];
typedef char fusion_state_check[sizeof(FusionAhrs) == sizeof(fusion_state) ? 1 : -1];

#define RAD_TO_DEG 57.29577951308232f
#define INV_G0 (1.0f / 9.80665f)

void fusion_init(fusion_state *s)
{
    FusionAhrs *const ahrs = (FusionAhrs *)s;
    FusionAhrsInitialise(ahrs);
    const FusionAhrsSettings settings = {
        .sampleRate = PEER_SAMPLE_RATE_HZ,
        .convention = FusionConventionNed,
        .gain = 0.5f,
        .gyroscopeRange = 2000.0f,
        .accelerationRejection = 10.0f,
        .magneticRejection = 10.0f,
        .rejectionTimeout = 5.0f,
    };
    FusionAhrsSetSettings(ahrs, &settings);
}

uint32_t fusion_step(fusion_state *s, const fusion_input *in, float dt)
{
    FusionAhrs *const ahrs = (FusionAhrs *)s;
    const FusionVector gyroscope = {.axis = {in->gyro[0] * RAD_TO_DEG, in->gyro[1] * RAD_TO_DEG,
                                             in->gyro[2] * RAD_TO_DEG}};
    const FusionVector accelerometer = {.axis = {in->accel[0] * INV_G0, in->accel[1] * INV_G0,
                                                 in->accel[2] * INV_G0}};
    const FusionVector magnetometer = {.axis = {in->mag[0], in->mag[1], in->mag[2]}};
    FusionAhrsSetSamplePeriod(ahrs, dt);
    FusionAhrsUpdate(ahrs, gyroscope, accelerometer, magnetometer);
    return 0;
}
