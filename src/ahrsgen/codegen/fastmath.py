"""Float math without libm: the `math = "fast"` build option.

The emitter writes a call to one of these static helpers instead of sinf/cosf/atan2f/asinf/
acosf/atanf/expf/logf when a float build asks for `math = "fast"`; the template puts the C of
the helpers used into the generated file (a filter's own template code asks for more through
its model's `template_helpers`). They use only + - * /, sqrtf (one vsqrt.f32 on the
Cortex-M4F with -fno-math-errno), comparisons, float<->int conversions and integer operations
on a float's bit pattern, all exact or correctly rounded IEEE-754, so a fast build gives
bit-identical results on the host and the target (the real-libm builds differ by newlib's and
glibc's last bits).

The methods are the classical ones (Cody and Waite's range reduction, the minimax
polynomials of Cephes' single-precision sinf/cosf/atanf). The maximum errors below are
MEASURED against the host's double libm over the whole domain by tests/codegen/test_fastmath.py
(which fails if a helper exceeds its stated bound): every float of the small-argument
ranges, a dense sweep of the rest, and the special values.

Double builds always use libm: these helpers are single-precision approximations.
"""
from __future__ import annotations


from dataclasses import dataclass

import casadi as ca

MATH_MODES = ("libm", "fast")
DEFAULT_MATH = "fast"

# Arguments of fast_sinf/fast_cosf beyond this (and NaN, +-inf) give NaN: the three-part
# pi/2 of the reduction is exact for |k| < 2^13 quadrants (the filters' angles are wrapped
# or bounded by gyro_max * dt_max, far inside).
TRIG_MAX = 8192.0


@dataclass(frozen=True)
class Helper:
    name: str
    doc: str
    code: str
    needs: tuple[str, ...] = ()
    max_abs_error: float = 0.0   # stated bound vs the exact value, over the whole domain
    max_rel_error: float = 0.0   # for exp and log: bound on |got - exact| / |exact| instead
    also: tuple[str, ...] = ()   # file-scope names the code defines besides `name`


_SINCOS_BODY = """
    const float t = x * 0.636619772f;                       /* x * 2/pi */
    const int32_t k = (int32_t)((t >= 0.0f) ? t + 0.5f : t - 0.5f);
    const float kf = (float)k;
    /* Cody-Waite: pi/2 in three parts, the first two with trailing zero bits */
    const float r = ((x - kf * 1.5703125f) - kf * 4.837512969970703125e-4f)
                    - kf * 7.54978995489188216e-8f;
    const float r2 = r * r;
"""

_SIN_POLY = ("r + r * r2 * ((-1.6666654611e-1f)\n"
             "        + r2 * (8.3321608736e-3f + r2 * (-1.9515295891e-4f)))")
_COS_POLY = ("1.0f - 0.5f * r2 + r2 * r2 * (4.166664568298827e-2f\n"
             "        + r2 * ((-1.388731625493765e-3f) "
             "+ r2 * 2.443315711809948e-5f))")


def _sincos() -> str:
    """sin and cos share one function (one copy of the reduction and polynomials in flash).
    The cosine is the sine one quadrant on: with k quadrants taken off, sin(x) is +-sin(r)
    for even k and +-cos(r) for odd k, and cos(x) the other one. The emitter calls it once
    for a sin and a cos of the same argument (emit/kernel.py), fast_sinf and fast_cosf for
    one of them; either way a value is the same float. The pair comes back in registers (a
    struct of two floats is returned in s0 and s1 on the Cortex-M4F's hard-float ABI); the
    inline fast_sincosf stores it where the caller wants it, which at -O2 is its registers."""
    return ("typedef struct {\n    float s;\n    float c;\n} fast_sin_cos;\n\n"
            "static fast_sin_cos fast_sin_cos_of(float x)\n{\n"
            "    fast_sin_cos v;\n"
            f"    if (!(fabsf(x) <= {TRIG_MAX:.1f}f)) {{\n        v.s = NAN;\n        v.c = NAN;\n        return v;\n    }}"
            + _SINCOS_BODY +
            f"    const float sin_r = {_SIN_POLY};\n"
            f"    const float cos_r = {_COS_POLY};\n"
            "    const uint32_t quadrant = (uint32_t)k & 3u;\n"
            "    const float vs = ((quadrant & 1u) != 0u) ? cos_r : sin_r;\n"
            "    const float vc = ((quadrant & 1u) != 0u) ? sin_r : cos_r;\n"
            "    v.s = (quadrant >= 2u) ? -vs : vs;\n"
            "    v.c = (quadrant == 1u || quadrant == 2u) ? -vc : vc;   /* quadrant + 1 >= 2 (mod 4) */\n"
            "    return v;\n}\n\n"
            "static inline void fast_sincosf(float x, float *s, float *c)\n{\n"
            "    const fast_sin_cos v = fast_sin_cos_of(x);\n    *s = v.s;\n    *c = v.c;\n}\n")


def _one_of_sincos(name: str, which: str) -> str:
    return f"static inline float {name}(float x)\n{{\n    return fast_sin_cos_of(x).{which};\n}}\n"


HELPERS = {
    "sincos": Helper("fast_sincosf", f"sin(x) and cos(x) with one reduction, |x| <= {TRIG_MAX:g} (NaN beyond): "
                     "fast_sin_cos_of returns both, fast_sincosf stores them through pointers, fast_sinf and "
                     "fast_cosf below return one", _sincos(), max_abs_error=1.5e-7,
                     also=("fast_sin_cos", "fast_sin_cos_of")),
    "sin": Helper("fast_sinf", f"sin(x), |x| <= {TRIG_MAX:g} (NaN beyond; sin(-0) = +0)",
                  _one_of_sincos("fast_sinf", "s"), needs=("sincos",), max_abs_error=1.5e-7),
    "cos": Helper("fast_cosf", f"cos(x), |x| <= {TRIG_MAX:g} (NaN beyond)",
                  _one_of_sincos("fast_cosf", "c"), needs=("sincos",), max_abs_error=1.5e-7),
    "atan2": Helper("fast_atan2f", "atan2(y, x), every float pair; quadrants, signed zeros and infinities as C99",
                    """static float fast_atan2f(float y, float x)
{
    if (isnan(x) || isnan(y)) {
        return x + y;
    }
    const float ax = fabsf(x);
    const float ay = fabsf(y);
    const bool steep = ay > ax;
    const float num = steep ? ax : ay;
    const float den = steep ? ay : ax;
    /* t = num / den in [0, 1]; num == den (inf/inf too) -> 1 and 0/0 -> 0 as atan2 wants */
    float t = (num < den) ? num / den : ((den > 0.0f) ? 1.0f : 0.0f);
    float a = 0.0f;
    if (t > 0.414213562f) {                                   /* tan(pi/8) */
        a = 0.785398163f;
        t = (t - 1.0f) / (t + 1.0f);
    }
    const float z = t * t;
    a += (((8.05374449538e-2f * z - 1.38776856032e-1f) * z + 1.99777106478e-1f) * z
          - 3.33329491539e-1f) * z * t + t;
    if (steep) {
        a = 1.57079633f - a;
    }
    if (signbit(x)) {
        a = 3.14159265f - a;
    }
    return signbit(y) ? -a : a;
}
""", max_abs_error=3.5e-7),
    "asin": Helper("fast_asinf", "asin(x), |x| <= 1 (NaN beyond), as atan2(x, sqrt((1 - x)(1 + x)))",
                   """static float fast_asinf(float x)
{
    return fast_atan2f(x, sqrtf((1.0f - x) * (1.0f + x)));
}
""", needs=("atan2",), max_abs_error=5e-7),
    "acos": Helper("fast_acosf", "acos(x), |x| <= 1 (NaN beyond), as atan2(sqrt((1 - x)(1 + x)), x)",
                   """static float fast_acosf(float x)
{
    return fast_atan2f(sqrtf((1.0f - x) * (1.0f + x)), x);
}
""", needs=("atan2",), max_abs_error=5e-7),
    "atan": Helper("fast_atanf", "atan(x), every float", """static float fast_atanf(float x)
{
    return fast_atan2f(x, 1.0f);
}
""", needs=("atan2",), max_abs_error=3.5e-7),
}

# exp: below -87.3 the result is flushed to 0 (NaN kept); x = k ln2 + r, |r| <= ln2 / 2 (ln2 in
# two parts), e^r by Cephes' minimax polynomial.
_EXP_FLUSH = """    if (!(x > -87.3f)) {
        return isnan(x) ? x : 0.0f;   /* below FLT_MIN: flushed to zero */
    }
"""
_EXP_POLY = """    const float kf = (float)k;
    const float r = (x - kf * 0.693359375f) - kf * (-2.12194440e-4f);
    const float p = ((((1.9875691500e-4f * r + 1.3981999507e-3f) * r + 8.3334519073e-3f) * r
                      + 4.1665795894e-2f) * r + 1.6666665459e-1f) * r + 5.0000001201e-1f;
    const float e = p * (r * r) + r + 1.0f;
"""

HELPERS["exp"] = Helper(
    "fast_expf", "exp(x), every float: +inf above 88.72, 0 at and below -87.3 (where libm's results are "
    "subnormal, < 1.2e-38); the relative error is stated above -87.3", "static float fast_expf(float x)\n{\n"
    + _EXP_FLUSH + """    if (x > 88.7228391f) {
        return INFINITY;
    }
    /* x = k ln2 + r, |r| <= ln2 / 2 (ln2 in two parts); e^r by Cephes' minimax polynomial */
    const float t = x * 1.44269504f;
    const int32_t k = (int32_t)((t >= 0.0f) ? t + 0.5f : t - 0.5f);
""" + _EXP_POLY + """    /* times 2^k as two exact powers of two (k in [-126, 128]) */
    union { uint32_t u; float f; } s1, s2;
    const int32_t k1 = k / 2;
    s1.u = (uint32_t)(k1 + 127) << 23;
    s2.u = (uint32_t)(k - k1 + 127) << 23;
    return e * s1.f * s2.f;
}
""", max_rel_error=1.5e-7)


# log: x = m 2^e with m in [sqrt(1/2), sqrt(2)) from the bit pattern (subnormals scaled up by
# 2^25 first), log(m) = z - z^2/2 + z^3 P(z), z = m - 1, by Cephes' logf minimax polynomial;
# e ln2 added in two parts (0.693359375 has trailing zero bits, so e times it is exact).
HELPERS["log"] = Helper(
    "fast_logf", "log(x), every float: -inf at +-0, NaN below 0 and for NaN, +inf at +inf, "
    "subnormals included",
    """static float fast_logf(float x)
{
    if (!(x > 0.0f)) {
        return (x < 0.0f || isnan(x)) ? NAN : -INFINITY;
    }
    if (x > FLT_MAX) {
        return x;
    }
    int32_t e = 0;
    union { float f; uint32_t u; } v;
    v.f = x;
    if (x < FLT_MIN) {                                       /* subnormal: times 2^25 */
        v.f = x * 33554432.0f;
        e = -25;
    }
    e += (int32_t)(v.u >> 23) - 127;
    v.u = (v.u & 0x007FFFFFu) | 0x3F800000u;                  /* m in [1, 2) */
    if (v.f >= 1.41421356f) {                                 /* m in [sqrt(1/2), sqrt(2)) */
        v.f *= 0.5f;
        e += 1;
    }
    const float z = v.f - 1.0f;
    const float z2 = z * z;
    const float p = ((((((((7.0376836292e-2f * z - 1.1514610310e-1f) * z + 1.1676998740e-1f) * z
                         - 1.2420140846e-1f) * z + 1.4249322787e-1f) * z - 1.6668057665e-1f) * z
                      + 2.0000714765e-1f) * z - 2.4999993993e-1f) * z + 3.3333331174e-1f) * z * z2;
    const float ef = (float)e;
    return ((p - 2.12194440e-4f * ef) - 0.5f * z2 + z) + 0.693359375f * ef;
}
""", max_rel_error=1.0e-7)


# exp for x <= 0 by a table of 64 powers of two (exp_nonpos_source): relative error at most
# EXP_NONPOS_REL_ERROR + EXP_NONPOS_REL_ERROR_PER_UNIT * |x| above -87.3. The second term is
# t = x * 64/ln2 in one float product (not split as in fast_expf): its rounding, 2^-24 |t|, and
# the float constant's 1.3e-8 relative error give 7.3e-8 |x| in the result; the first is the
# truncation of e^r (2.6e-8) and four roundings. Measured by tests/filters/cpf/test_cpf.py (max 1.97e-7
# near 0, 7.0e-8 |x| beyond).
EXP_NONPOS_TABLE = 64
EXP_NONPOS_REL_ERROR = 2.5e-7
EXP_NONPOS_REL_ERROR_PER_UNIT = 8.0e-8


def _exp_nonpos_table() -> list[int]:
    """Bits of 2^(i/64), i = 0..63, as float32, less 126 in the exponent field (so that adding
    (n + 8064) / 64 to the field scales by 2^(n div 64) with no further bias)."""
    import struct
    out = []
    for i in range(EXP_NONPOS_TABLE):
        bits = struct.unpack("<I", struct.pack("<f", 2.0 ** (i / EXP_NONPOS_TABLE)))[0]
        out.append(bits - (126 << 23))
    return out


def exp_nonpos_source(name: str, name2: str) -> str:
    """C of `static inline float name2(float t)`, 2^(t/64) for t <= 0, and of
    `static inline float name(float x)`, exp(x) = name2(64 x / ln2) for x <= 0: 2^(t/64) =
    2^(n/64) e^r with n = round(t), r = (t - n) ln2/64, |r| <= ln2/128 (n by adding 1.5 2^23, which
    leaves round(t) in the low bits of the float, with no conversion); 2^(n/64) from a table of
    64 powers of two with the exponent added in the integers, e^r = 1 + r + r^2/2 (truncation
    <= 2.6e-8) evaluated in fr = t - n as (C2 fr + C1) fr + 1, C1 = ln2/64, C2 = C1^2/2. Relative
    error of exp <= EXP_NONPOS_REL_ERROR + EXP_NONPOS_REL_ERROR_PER_UNIT |x| above -87.3 (0 at
    and below, NaN kept): 2 ulp near 0, 7.2e-6 at -87.3 (the second term is the rounding of
    t = 64 x / ln2; name2 is within EXP_NONPOS_REL_ERROR of 2^(t/64) for t > -8060.626, 0 below). About 20
    instructions on the Cortex-M4F, fast_expf's reduction and polynomial about 30; a caller
    that can fold the factor 64/ln2 into its own constant calls name2 and saves one more."""
    rows = []
    tab = _exp_nonpos_table()
    for k in range(0, len(tab), 4):
        rows.append("    " + ", ".join(f"0x{b:08X}u" for b in tab[k:k + 4]))
    return (f"/* 2^(i/64) as float bits, less 126 in the exponent field */\n"
            f"static const uint32_t {name}_table[64] = {{\n" + ",\n".join(rows) + "\n};\n\n"
            f"/* 2^(t/64) for t <= 0 */\nstatic inline float {name2}(float t)\n{{\n"
            + """    if (!(t > -8060.626f)) {         /* -87.3 * 64/ln2 */
        return isnan(t) ? t : 0.0f;   /* below FLT_MIN: flushed to zero */
    }
"""
            + f"""    union {{ float f; uint32_t u; }} rn;
    rn.f = t + 12582912.0f;              /* 1.5 2^23 + round(t): round(t) in the low bits */
    const float fr = t - (rn.f - 12582912.0f);   /* t - round(t), |fr| <= 1/2: r = fr ln2/64 */
    const float e = (5.864905e-05f * fr + 0.010830425f) * fr + 1.0f;   /* e^r = 1 + r + r^2/2 */
    const uint32_t m = rn.u - 0x4B3FE080u;                 /* round(t) + 126 * 64 >= 3 */
    union {{ uint32_t u; float f; }} scale;
    scale.u = {name}_table[m & 63u] + ((m >> 6) << 23);    /* 2^(n/64) */
    return e * scale.f;
}}

/* exp(x) for x <= 0 */
static inline float {name}(float x)
{{
    return {name2}(x * 92.33248f);                         /* 64 x / ln2 */
}}
""")


# CasADi operation -> helper (unary ops take {a}, atan2 takes {a}, {b}).
OPS = {ca.OP_SIN: "sin", ca.OP_COS: "cos", ca.OP_ATAN2: "atan2", ca.OP_ASIN: "asin",
       ca.OP_ACOS: "acos", ca.OP_ATAN: "atan", ca.OP_EXP: "exp", ca.OP_LOG: "log"}


def closure(names) -> list[str]:
    """The helpers needed for `names`, dependencies first, in a fixed order."""
    need: set[str] = set()

    def add(n):
        if n not in need:
            need.add(n)
            for d in HELPERS[n].needs:
                add(d)
    for n in names:
        add(n)
    return [n for n in HELPERS if n in need and not HELPERS[n].needs] + \
           [n for n in HELPERS if n in need and HELPERS[n].needs]


def file_scope_names(names) -> list[str]:
    """Every file-scope identifier the helpers `names` need define (functions, the sin/cos pair's type)."""
    out = []
    for n in closure(names):
        out += [HELPERS[n].name, *HELPERS[n].also]
    return out


def comment(text: str, width: int = 100) -> str:
    """A C block comment of `text`, wrapped to `width` columns (` * ` continuation lines)."""
    import textwrap
    lines = textwrap.wrap(text, width - 3, initial_indent="/* ", subsequent_indent=" * ")
    if len(lines[-1]) + 3 <= width:
        return "\n".join(lines[:-1] + [lines[-1] + " */"])
    return "\n".join(lines + [" */"])


def c_source(names, prefix: str | None = None) -> str:
    """C of the helpers `names` need (static functions; <math.h>, <float.h>, <stdbool.h>,
    <stdint.h> included by the caller). With a prefix, each file-scope name is first defined as
    a macro for <prefix>_<name>, so the compiled names carry the filter's prefix and several
    generated filters build in one translation unit; c_source_end undefines the macros at the
    end of the file."""
    out = []
    if prefix:
        out.append("/* The helpers' names carry this filter's prefix (a unity build may include several\n"
                   " * generated filters); the code below writes them short. */\n"
                   + "".join(f"#define {n} {prefix}_{n}\n" for n in file_scope_names(names)))
    for n in closure(names):
        h = HELPERS[n]
        err = (f"max relative error {h.max_rel_error:.1e}" if h.max_rel_error else
               f"max abs error {h.max_abs_error:.1e}")
        out.append(comment(f"{h.doc}; {err} (tests/codegen/test_fastmath.py)") + "\n" + h.code)
    return "\n".join(out)


def c_source_end(names) -> str:
    """The #undef lines that close c_source(names, prefix)."""
    return "".join(f"#undef {n}\n" for n in file_scope_names(names))
