/* Calibration peers for the target instruction counts (not product filters).
 *
 * Madgwick's gradient-descent MARG filter (Madgwick 2010 report, eq. 25-34) and Mahony's
 * explicit complementary filter with integral feedback (Mahony, Hamel, Pflimlin 2008),
 * written here from the published equations, in this product's conventions (quaternion
 * body->NED, FRD body, accelerometer = specific force, so the measured "down" direction
 * is -accel).  They exist so that the instruction counter can be compared with figures
 * published for these well-known 9-axis updates on a Cortex-M4F (a few hundred
 * instructions each); counts only, no accuracy claims beyond a convergence sanity test.
 */
#ifndef AHRSGEN_PEERS_H
#define AHRSGEN_PEERS_H

#include <stdint.h>

typedef struct {
    float gyro[3], accel[3], mag[3], gps_vel_ned[3];
    uint32_t valid;
} peer_input;

typedef struct {
    float q[4];
} madgwick_state;

typedef struct {
    float q[4];
    float integral[3];
} mahony_state;

typedef peer_input madgwick_input;
typedef peer_input mahony_input;

/* like-for-like peers: the same updates behind the product's input checks (checks.h), with
 * the product's status bits as the return value */
typedef madgwick_state madgwick_checked_state;
typedef mahony_state mahony_checked_state;
typedef peer_input madgwick_checked_input;
typedef peer_input mahony_checked_input;

void madgwick_init(madgwick_state *s);
uint32_t madgwick_step(madgwick_state *s, const madgwick_input *in, float dt);
void mahony_init(mahony_state *s);
uint32_t mahony_step(mahony_state *s, const mahony_input *in, float dt);
void madgwick_checked_init(madgwick_state *s);
uint32_t madgwick_checked_step(madgwick_state *s, const madgwick_input *in, float dt);
void mahony_checked_init(mahony_state *s);
uint32_t mahony_checked_step(mahony_state *s, const mahony_input *in, float dt);

#endif
