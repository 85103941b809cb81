/* One sensor-log sample as the ahrsgen target harness reads it (56 bytes, little-endian;
 * firmware_sim/target.py writes the same layout with NumPy). */
#ifndef AHRSGEN_AHRS_RECORD_H
#define AHRSGEN_AHRS_RECORD_H

#include <stdint.h>

typedef struct {
    float gyro[3];    /* rad/s, FRD */
    float accel[3];   /* m/s^2 specific force, FRD */
    float mag[3];     /* any unit, FRD */
    float gps_vel[3]; /* m/s, NED */
    uint32_t valid;   /* VALID_* bits (src/ahrsgen/sim/log.py) */
    float dt;         /* s */
} ahrs_record;

#endif
