/* Fusion's and BasicVQF's updates behind the harness's filter shape (init/step on a state
 * struct), for studies/cycles_vs_peers.py. Their sources are not in this repository: the
 * study downloads the PyPI sdists (imufusion 1.3.3, vqf 2.1.2, both MIT) and compiles them with
 * these wrappers. This header is strict C99 (the harness glue includes it); the libraries' own
 * types stay inside fusion_peer.c and basicvqf_peer.cpp, which check the sizes and offsets
 * below against them at compile time.
 *
 * PEER_SAMPLE_RATE_HZ (a -D of the study, from the log): Fusion's sampleRate setting and
 * BasicVQF's sample time 1 / rate, fixed at init as each library wants it.
 */
#ifndef AHRSGEN_EXTERNAL_PEERS_H
#define AHRSGEN_EXTERNAL_PEERS_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct {
    float gyro[3], accel[3], mag[3], gps_vel_ned[3];
    uint32_t valid;
} external_peer_input;

/* FusionAhrs (124 bytes, float-aligned); its quaternion (w, x, y, z) at byte 36 */
#define FUSION_PEER_STATE_BYTES 124
#define FUSION_PEER_Q_OFFSET 36
typedef struct {
    float words[FUSION_PEER_STATE_BYTES / 4];
} fusion_state;
typedef external_peer_input fusion_input;

/* BasicVQF in single precision (176 bytes, 8-aligned: its filter states are double);
 * BasicVQFState at byte 8: gyrQuat, accQuat (w, x, y, z) and delta */
#define BASICVQF_PEER_STATE_BYTES 176
#define BASICVQF_PEER_GYRQUAT_OFFSET 8
#define BASICVQF_PEER_ACCQUAT_OFFSET 24
#define BASICVQF_PEER_DELTA_OFFSET 40
typedef struct {
    double words[BASICVQF_PEER_STATE_BYTES / 8];
} basicvqf_state;
typedef external_peer_input basicvqf_input;

void fusion_init(fusion_state *s);
uint32_t fusion_step(fusion_state *s, const fusion_input *in, float dt);
void basicvqf_init(basicvqf_state *s);
uint32_t basicvqf_step(basicvqf_state *s, const basicvqf_input *in, float dt);

#ifdef __cplusplus
}
#endif

#endif
