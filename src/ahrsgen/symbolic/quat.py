"""Quaternion algebra, rotations, Euler angles and angle wrapping as CasADi SX expressions.

Conventions (SPEC.md): Hamilton product, scalar first q = [w, x, y, z], q rotates body to
NED (v_n = q ⊗ v_b ⊗ q*), Z-Y-X Euler angles [roll, pitch, yaw], yaw in (-pi, pi].
All functions take and return casadi.SX column vectors.
"""
from __future__ import annotations

import contextlib
import contextvars
import math
from fractions import Fraction

import casadi as ca

from ahrsgen.constants import Const, use


def vec(*items) -> ca.SX:
    return ca.vertcat(*items)


def qmul(p, q) -> ca.SX:
    """Hamilton product p ⊗ q."""
    pw, px, py, pz = p[0], p[1], p[2], p[3]
    qw, qx, qy, qz = q[0], q[1], q[2], q[3]
    return vec(
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    )


def qconj(q) -> ca.SX:
    return vec(q[0], -q[1], -q[2], -q[3])


def qnormalize(q) -> ca.SX:
    return q / ca.sqrt(ca.sumsqr(q))


def pure(v) -> ca.SX:
    return vec(0, v[0], v[1], v[2])


def rotmat(q) -> ca.SX:
    """R(q) with v_n = R v_b (q assumed unit)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return ca.vertcat(
        ca.horzcat(1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        ca.horzcat(2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        ca.horzcat(2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )


def rotate(q, v) -> ca.SX:
    """Body -> NED: R(q) v."""
    return ca.mtimes(rotmat(q), v)


def rotate_inv(q, v) -> ca.SX:
    """NED -> body: R(q)^T v."""
    return ca.mtimes(rotmat(q).T, v)


# Below this rotation-vector half-angle |v| the exponential is the truncated series
#   cos|v| = sum_{k<K} (-1)^k |v|^2k / (2k)!,  sin|v|/|v| = sum_{k<K} (-1)^k |v|^2k / (2k+1)!
# (K = SERIES_TERMS, Horner in |v|^2: no sin, cos, sqrt or division). The first neglected
# terms bound the truncation error: |v|^10/10! <= 2.8e-17 and |v|^10/11! <= 2.6e-18 at
# |v| = 0.1, below double round-off (1.1e-16). 0.1 rad per half step covers rates up to
# 20 rad/s at 100 Hz; beyond it the exact sin/cos form runs (an if/else in the C: only
# the taken side is computed).
SERIES_MAX = Const("SERIES_MAX", 0.1)
SERIES_TERMS = 5
# The same for an exponential whose argument is nearly always small (a filter's correction, a
# fraction of its error per sample): 4 terms below |v| = 0.03, the first neglected
# |v|^8/8! <= 1.7e-17 and |v|^8/9! <= 1.9e-18, below double round-off too.
SMALL_SERIES_MAX = Const("SMALL_SERIES_MAX", 0.03)
SMALL_SERIES_TERMS = 4


# The series above are written for double arithmetic. A float build has no use for their tail:
# while series_precision("float") is in force, qexp and qexp_factors keep only the terms of at
# least 1/8 of float's unit roundoff 2^-24 (relative to the series' leading term) at the top of
# their range, so what they drop (alternating series with decreasing terms: at most the first
# term dropped) stays below 1/16 of an ulp of the result: below SERIES_MAX cos and sin/x keep 3
# terms of 5 (qexp_factors' k 3 of 5), below SMALL_SERIES_MAX cos 3 and sin/x 2 of 4. Double keeps
# every term.
_ROUNDOFF: contextvars.ContextVar[float | None] = contextvars.ContextVar("series_roundoff", default=None)
FLOAT_ROUNDOFF = 2.0 ** -24


@contextlib.contextmanager
def series_precision(precision: str):
    """While the block runs, the series are cut for `precision`'s arithmetic ("float" or
    "double"; see _ROUNDOFF above). The generator builds a float build's kernels in it."""
    token = _ROUNDOFF.set(FLOAT_ROUNDOFF if precision == "float" else None)
    try:
        yield
    finally:
        _ROUNDOFF.reset(token)


def _cut(fractions, top: float) -> list:
    """The terms of sum_k fractions[k] x^k (x in [0, top^2]) the arithmetic in force can see:
    every term in double; in float the trailing terms below FLOAT_ROUNDOFF / 8 of the leading
    one at x = top^2 dropped. Decided on the plain numbers (a traced build cuts alike)."""
    fr = list(fractions)
    u = _ROUNDOFF.get()
    if u is None:
        return fr
    x = float(top) ** 2
    n = len(fr)
    while n > 1 and abs(float(fr[n - 1])) * x ** (n - 1) < u / 8 * abs(float(fr[0])):
        n -= 1
    return fr[:n]


def _coefficients(fractions) -> list:
    """Series coefficients as the model's arithmetic reads them (ahrsgen.constants.use): each a
    constant named by its fraction (1/45; a negative one is the negation of its magnitude's,
    the same number), 1 as itself."""
    out = []
    for f in fractions:
        c = use(Const(str(abs(f)), float(abs(f)))) if abs(f) != 1 else 1.0
        out.append(-c if f < 0 else c)
    return out


def _cos_sinc_coefficients(terms: int = SERIES_TERMS, top: float | None = None):
    """cos x and sin x / x in x^2: (-1)^k / (2k)! and (-1)^k / (2k + 1)!, k < terms; with `top`
    (the largest x), cut for the arithmetic in force (_cut)."""
    cos_f = [Fraction((-1) ** k, math.factorial(2 * k)) for k in range(terms)]
    sinc_f = [Fraction((-1) ** k, math.factorial(2 * k + 1)) for k in range(terms)]
    if top is not None:
        cos_f, sinc_f = _cut(cos_f, top), _cut(sinc_f, top)
    return _coefficients(cos_f), _coefficients(sinc_f)


def _series(x2, coeffs):
    """Horner evaluation of sum_k coeffs[k] x2^k."""
    acc = coeffs[-1]
    for c in reversed(coeffs[:-1]):
        acc = c + x2 * acc
    return acc


def qexp(v, n2=None, small_arg: bool = False) -> ca.SX:
    """exp([0, v]) = [cos|v|, sin|v| v/|v|]: the series above below SERIES_MAX (exact at 0);
    small_arg: the shorter series below SMALL_SERIES_MAX.

    n2 stands for |v|² (default: computed from v); qexp_jacobian passes a symbol."""
    n2 = ca.sumsqr(v) if n2 is None else n2
    top = use(SMALL_SERIES_MAX) if small_arg else use(SERIES_MAX)
    small = n2 < top * top
    n = ca.sqrt(ca.fmax(n2, top * top))
    cos_c, sinc_c = _cos_sinc_coefficients(SMALL_SERIES_TERMS if small_arg else SERIES_TERMS,
                                           float(SMALL_SERIES_MAX if small_arg else SERIES_MAX))
    sinc = ca.if_else(small, _series(n2, sinc_c), ca.sin(n) / n)
    cos_n = ca.if_else(small, _series(n2, cos_c), ca.cos(n))
    return vec(cos_n, sinc * v[0], sinc * v[1], sinc * v[2])


def qexp_jacobian(v) -> ca.SX:
    """∂ qexp(v) / ∂v (4 x 3) through m = |v|²: qexp(v) = [C(m), S(m) v], so
    J = [2 C'(m) vᵀ; S(m) I + 2 S'(m) v vᵀ], with C' and S' the derivatives of the series
    below SERIES_MAX (their own Horner sums) and of cos √m and sin √m / √m above it:
    C' = −sin n / (2n), S' = (cos n − sin n / n) / (2n²), n = √m, built on the same n, sin n
    and cos n as qexp, so the emitted step computes them once."""
    m = ca.sumsqr(v)
    small = m < use(SERIES_MAX) * use(SERIES_MAX)
    n2 = ca.fmax(m, use(SERIES_MAX) * use(SERIES_MAX))
    n = ca.sqrt(n2)
    sin_n, cos_n = ca.sin(n), ca.cos(n)
    cos_c, sinc_c = _cos_sinc_coefficients()

    def d(coeffs):            # the series' derivative in m: sum_k k c_k m^(k-1)
        return [k * c for k, c in enumerate(coeffs)][1:]
    S = ca.if_else(small, _series(m, sinc_c), sin_n / n)
    dC = ca.if_else(small, _series(m, d(cos_c)), -sin_n / (2 * n))
    dS = ca.if_else(small, _series(m, d(sinc_c)), (cos_n - sin_n / n) / (2 * n2))
    return ca.vertcat(2 * dC * v.T, S * ca.SX.eye(3) + 2 * dS * ca.mtimes(v, v.T))


# (|v| − sin|v| cos|v|) / |v|³ = (2x − sin 2x) / (2x³) at x = |v|: sum_k (-1)^k 2^(2k+2) |v|^2k / (2k+3)!,
# Horner in |v|^2 (SERIES_TERMS terms; the first neglected, 2^12 |v|^10 / 13!, is 6.6e-17 at
# |v| = SERIES_MAX: below double round-off beside the leading 2/3).
RJ_SERIES = tuple(Fraction((-1) ** k * 2 ** (2 * k + 2), math.factorial(2 * k + 3)) for k in range(SERIES_TERMS))


def qexp_factors(v, n2=None):
    """(cos|v|, sin|v|/|v|, k) with k = (|v| − sin|v| cos|v|)/|v|³, on one branch: the series
    below SERIES_MAX (no sin, cos, sqrt or division), else the exact forms (as qexp).

    exp([0, v]) = [cos|v|, (sin|v|/|v|) v]; with the rotation vector φ = 2v of that
    quaternion, SO(3)'s right Jacobian is J_r(φ) = I − (sin|v|/|v|)² [v×] + k [v×]²
    ((1 − cos θ)/θ² [φ×] and (θ − sin θ)/θ³ [φ×]² at θ = 2|v|). n2 stands for |v|² (default:
    computed from v)."""
    n2 = ca.sumsqr(v) if n2 is None else n2
    small = n2 < use(SERIES_MAX) * use(SERIES_MAX)
    n = ca.sqrt(ca.fmax(n2, use(SERIES_MAX) * use(SERIES_MAX)))
    cos_c, sinc_c = _cos_sinc_coefficients(SERIES_TERMS, float(SERIES_MAX))
    sin_n, cos_n = ca.sin(n), ca.cos(n)
    return (ca.if_else(small, _series(n2, cos_c), cos_n),
            ca.if_else(small, _series(n2, sinc_c), sin_n / n),
            ca.if_else(small, _series(n2, _coefficients(_cut(RJ_SERIES, float(SERIES_MAX)))),
                       (n - sin_n * cos_n) / (n2 * n)))


def integrate(q, omega, dt) -> ca.SX:
    """q ⊗ exp(½ ω dt), normalised: exact for a constant body rate over dt."""
    return qnormalize(qmul(q, qexp(0.5 * dt * omega)))


# |v| cot|v| = sum_k (-1)^k 2^2k |B_2k| |v|^2k / (2k)! (B: Bernoulli numbers), Horner in |v|^2. The
# first neglected term, 1382 |v|^12 / 638512875, is 2.2e-18 at |v| = SERIES_MAX: below double round-off.
COT_SERIES = tuple(Fraction(n, d) for n, d in ((1, 1), (-1, 3), (-1, 45), (-2, 945), (-1, 4725), (-2, 93555)))


def qexp_scaled(v) -> ca.SX:
    """A positive multiple of exp([0, v]), for a product normalised afterwards.

    Below SERIES_MAX it is exp([0, v]) divided by sin|v|/|v| (> 0): [|v| cot|v|, v], one series
    and v itself (no sin, cos, sqrt or division); above it exp itself, as qexp."""
    n2 = ca.sumsqr(v)
    small = n2 < use(SERIES_MAX) * use(SERIES_MAX)
    n = ca.sqrt(ca.fmax(n2, use(SERIES_MAX) * use(SERIES_MAX)))
    sinc = ca.sin(n) / n
    return vec(ca.if_else(small, _series(n2, _coefficients(COT_SERIES)), ca.cos(n)),
               *(ca.if_else(small, v[i], sinc * v[i]) for i in range(3)))


# qnormalize_near_unit: one Newton step for 1/sqrt(|q|^2) from 1 while |q|^2 - 1 is below this
# (2^-12, exact in float): q (3 - |q|^2)/2 = q/|q| (1 - 3/8 eps^2 + O(eps^3)), eps = |q|^2 - 1,
# a relative error below 2.3e-8 there, under half a float ulp; beyond it the exact quotient
NEAR_UNIT_MAX = Const("NEAR_UNIT_MAX", 2.0 ** -12)


def qnormalize_near_unit(q) -> ca.SX:
    """qnormalize for a q whose norm is 1 to rounding (a product of unit quaternions): a square
    root and a division only when |q|^2 is off 1 by more than NEAR_UNIT_MAX."""
    n2 = ca.sumsqr(q)
    eps = n2 - 1
    near = ca.fabs(eps) < use(NEAR_UNIT_MAX)
    return ca.if_else(near, q * (1 - 0.5 * eps), q / ca.sqrt(n2))


def integrate_scaled(q, omega, dt) -> ca.SX:
    """integrate(q, omega, dt), the same rotation: the normalisation absorbs qexp_scaled's factor."""
    return qnormalize(qmul(q, qexp_scaled(0.5 * dt * omega)))


def rotate_xy_tilt(t, v) -> ca.SX:
    """The first two components of R(t) v for a unit t = [w, x, y, 0] (no z part):
    R's rows [1 - 2y², 2xy, 2wy] and [2xy, 1 - 2x², -2wx] as v_x - y u and v_y + x u,
    u = 2 (y v_x - x v_y - w v_z)."""
    w, x, y = t[0], t[1], t[2]
    c = y * v[0] - x * v[1] - w * v[2]
    u = c + c
    return vec(v[0] - y * u, v[1] + x * u)


PI = Const("pi", math.pi)


def wrap(a) -> ca.SX:
    """Wrap an angle in (-3 pi, 3 pi] to (-pi, pi] by two comparisons (no floor).

    Every angle a filter wraps is a sum or difference of two angles in (-pi, pi] (or such
    an angle plus a declination in [-pi, pi]), so one 2 pi step is enough; there it
    equals a + 2 pi floor((pi - a) / 2 pi)."""
    pi = use(PI)
    two_pi = 2 * pi
    return ca.if_else(a > pi, a - two_pi, ca.if_else(a <= -pi, a + two_pi, a))


def euler(q) -> ca.SX:
    """Z-Y-X Euler angles [roll, pitch, yaw] of a unit body->NED quaternion."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    r21 = 2 * (w * x + y * z)
    r22 = 1 - 2 * (x * x + y * y)
    roll = ca.atan2(r21, r22)
    # pitch = asin(2(wy - xz)), written as atan2 against cos(pitch) = |(R21, R22)|: well
    # conditioned up to +-90 deg, and no asinf (newlib's pulls errno state into RAM).
    pitch = ca.atan2(2 * (w * y - x * z), ca.sqrt(r21 * r21 + r22 * r22))
    yaw = ca.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return vec(roll, pitch, yaw)


def from_euler(roll, pitch, yaw) -> ca.SX:
    """qz(yaw) ⊗ qy(pitch) ⊗ qx(roll)."""
    cr, sr = ca.cos(roll / 2), ca.sin(roll / 2)
    cp, sp = ca.cos(pitch / 2), ca.sin(pitch / 2)
    cy, sy = ca.cos(yaw / 2), ca.sin(yaw / 2)
    return vec(
        cy * cp * cr + sy * sp * sr,
        cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr,
        sy * cp * cr - cy * sp * sr,
    )


def axis_quat(axis: int, c_half, s_half) -> ca.SX:
    """Quaternion of a rotation about body axis 0/1/2 from cos and sin of the half angle."""
    comps = [0, 0, 0]
    comps[axis] = s_half
    return vec(c_half, *comps)


def half_angle(c, s):
    """(cos(a/2), sin(a/2)) from cos a and sin a, with a in (-pi, pi] (FQA's eqs. 23-24)."""
    c = ca.fmin(ca.fmax(c, -1), 1)
    c_half = ca.sqrt((1 + c) / 2)
    # sign(s) with sign(0) taken as +1, so a = pi gives sin(a/2) = 1 (not 0)
    sgn = ca.if_else(s < 0, -1, 1)
    s_half = sgn * ca.sqrt((1 - c) / 2)
    return c_half, s_half
