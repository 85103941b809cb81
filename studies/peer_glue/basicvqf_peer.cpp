// BasicVQF (Laidig & Seel 2023; the basic version, without rest detection and magnetic
// disturbance rejection) behind the harness shape; see external_peers.h. Built with
// VQF_SINGLE_PRECISION, so vqf_real_t is float; BasicVQF keeps its low-pass filter states and
// coefficients in double whatever that define says, so its step runs soft-double helpers on a
// single-precision FPU: that is BasicVQF "in single precision" as its authors ship it.
//
// The library's defaults (tauAcc 3 s, tauMag 9 s), sample time 1 / PEER_SAMPLE_RATE_HZ for all
// three sensors. The step is BasicVQF::update(gyr, acc, mag) on the harness's SI samples
// (rad/s, m/s^2, any magnetometer unit: what VQF takes), in place in the caller's state.
#include <cstddef>
#include <new>

#include "basicvqf.hpp"
#include "external_peers.h"

#ifndef PEER_SAMPLE_RATE_HZ
#error "PEER_SAMPLE_RATE_HZ: the study passes the log's sample rate"
#endif

namespace {
struct Layout : BasicVQF {     // names BasicVQF's protected state for offsetof only
    static constexpr std::size_t state_at() { return offsetof(Layout, state); }
};
}  // namespace

static_assert(sizeof(vqf_real_t) == 4, "VQF_SINGLE_PRECISION");
static_assert(sizeof(BasicVQF) == BASICVQF_PEER_STATE_BYTES, "BASICVQF_PEER_STATE_BYTES");
static_assert(sizeof(basicvqf_state) == sizeof(BasicVQF) && alignof(basicvqf_state) >= alignof(BasicVQF),
              "basicvqf_state");
static_assert(Layout::state_at() + offsetof(BasicVQFState, gyrQuat) == BASICVQF_PEER_GYRQUAT_OFFSET, "gyrQuat");
static_assert(Layout::state_at() + offsetof(BasicVQFState, accQuat) == BASICVQF_PEER_ACCQUAT_OFFSET, "accQuat");
static_assert(Layout::state_at() + offsetof(BasicVQFState, delta) == BASICVQF_PEER_DELTA_OFFSET, "delta");

extern "C" void basicvqf_init(basicvqf_state *s)
{
    new (s) BasicVQF(1.0f / PEER_SAMPLE_RATE_HZ);
}

extern "C" uint32_t basicvqf_step(basicvqf_state *s, const basicvqf_input *in, float dt)
{
    (void)dt;      // BasicVQF's sample time is fixed at construction
    std::launder(reinterpret_cast<BasicVQF *>(s))->update(in->gyro, in->accel, in->mag);
    return 0;
}
