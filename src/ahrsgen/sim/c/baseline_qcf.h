/*
 * baseline_qcf.h - the QCF of SPEC.md written by hand, as an engineer would for an MCU.
 *
 * Same algorithm, gains and input checks as the generated qcf (defaults.toml defaults),
 * plain float C, no code generator involved. It is the yardstick for the generated code's
 * speed in `ahrsgen bench` (ratio generated / hand-written ns per step).
 */
#ifndef BASELINE_QCF_H
#define BASELINE_QCF_H

#include <stdint.h>

typedef struct {
    float q[4];              /* body -> NED, [w x y z] */
    float gyro_bias[3];      /* rad/s */
    float gps_vel_hist[21];  /* last 7 GPS velocities (NED), oldest first */
    float motion_accel[3];   /* GPS-derived NED acceleration, m/s^2 */
    float gps_age;           /* s since the last GPS sample */
    uint32_t gps_count;      /* samples in the history, saturates at 7 */
    uint32_t initialised;    /* 1 once q was set from the first FQA attitude */
} baseline_qcf_state;

typedef struct {
    float gyro[3];
    float accel[3];
    float mag[3];
    float gps_vel_ned[3];
    uint32_t valid;          /* bit 0 gyro, 1 accel, 2 mag, 3 GPS */
} baseline_qcf_input;

typedef uint32_t baseline_qcf_status;

void baseline_qcf_init(baseline_qcf_state *s);
baseline_qcf_status baseline_qcf_step(baseline_qcf_state *s, const baseline_qcf_input *in, float dt);
void baseline_qcf_euler(const baseline_qcf_state *s, float rpy[3]);

#endif
