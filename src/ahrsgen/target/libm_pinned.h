/* Pinned libm for the target-vs-host identity check (firmware_sim/target.py).
 *
 * Force-included (-include) into the filter's translation unit on BOTH the Cortex-M4F
 * build (newlib) and the host build (glibc) when the check runs in "pinned" mode.  Each
 * float function is evaluated in double and rounded once to float.  newlib's and glibc's
 * double functions are both accurate to within an ulp of double, so after rounding to
 * float they agree except in the rare case (~1 in 2^28) where the exact value lies within
 * a few double ulps of a float rounding boundary.  The basic operations and sqrtf are
 * correctly rounded on both sides anyway.  So a pinned run that is bit-identical shows
 * that the only source of target/host difference in the real build is the float libm.
 *
 * Never used for the footprint or instruction counts (those use the real float libm).
 */
#ifndef AHRSGEN_LIBM_PINNED_H
#define AHRSGEN_LIBM_PINNED_H

#include <math.h>

static inline float ahrs_pinned_sinf(float x) { return (float)sin((double)x); }
static inline float ahrs_pinned_cosf(float x) { return (float)cos((double)x); }
static inline float ahrs_pinned_tanf(float x) { return (float)tan((double)x); }
static inline float ahrs_pinned_asinf(float x) { return (float)asin((double)x); }
static inline float ahrs_pinned_acosf(float x) { return (float)acos((double)x); }
static inline float ahrs_pinned_atanf(float x) { return (float)atan((double)x); }
static inline float ahrs_pinned_atan2f(float y, float x) { return (float)atan2((double)y, (double)x); }
static inline float ahrs_pinned_expf(float x) { return (float)exp((double)x); }
static inline float ahrs_pinned_logf(float x) { return (float)log((double)x); }
static inline float ahrs_pinned_powf(float x, float y) { return (float)pow((double)x, (double)y); }

#define sinf ahrs_pinned_sinf
#define cosf ahrs_pinned_cosf
#define tanf ahrs_pinned_tanf
#define asinf ahrs_pinned_asinf
#define acosf ahrs_pinned_acosf
#define atanf ahrs_pinned_atanf
#define atan2f ahrs_pinned_atan2f
#define expf ahrs_pinned_expf
#define logf ahrs_pinned_logf
#define powf ahrs_pinned_powf

#endif
