"""Aiding-sensor conditioning shared by the filters: low-pass, rest detection, field check,
and well-conditioned tilt / heading corrections (CasADi SX, no filter imports here).

All thresholds are plain Python numbers baked in by the caller; flags are returned as 0/1
SX expressions so that a kernel can output them and the step partial can branch on them.

- `lowpass(x_lp, x, dt, tau)`: first-order low-pass x_lp + dt/(tau + dt) (x - x_lp)
  (the backward-Euler discretisation of tau x_lp' = x - x_lp; tau = 0 passes x through).
- `rest_detector(...)`: gyro steady (within a tolerance of its low-passed value), the
  low-passed rate small and |f| near gravity, for at least `min_time` s (after VQF);
  `rest_timer(...)` its timer alone (mekf tests steadiness its own way).
- `field_check(...)`: magnetometer norm and dip (sin of the angle below the horizontal)
  against a reference learned at the first sample and tracked slowly while accepted; a field
  that stays different for `new_time` s becomes the new reference (a permanent change, e.g.
  a new mounting or a new site), so a rejection cannot hold forever.
- `tilt_correction(d_n)`: the shortest rotation of the NED frame taking a measured
  down-vector d_n (any length) to [0, 0, 1]; it has no z component (never changes heading) and is well
  conditioned at every attitude except d_n = -[0, 0, 1] (upside-down measurement, where the
  x-axis half-turn is taken).
- `heading_correction(q, m, declination)`: the rotation about NED z that brings the horizontal
  part of R(q) m to magnetic north + declination; it only changes heading (never tilts).
  `heading_correction_ned(m_n, declination)` the same from the NED vector m_n.
- `gps_lowpass(...)`: the GPS velocity through the same earth-frame low-pass as the specific
  force, and the low-passed kinematic acceleration (v - v_lp)/tau removed from it (mekf's
  motion_comp = 'gps_lowpass', qcf's motion_accel_model = 'gps_lowpass').
- `norm_within(n2, center, tol)`: ||v| - center| < tol from |v|², without a square root.
- `gyro_recovery(...)`: a gyro component at the sensor's full scale (a clipped sample) and the
  recovery window that follows it (the filters decide what recovering means for them).
- `gyro_plateau(...)`: a clipped sample recognised without the range: a fast component that
  holds exactly the same value for PLATEAU_SAMPLES samples while the others change.
- `hard_iron_step(...)`: the magnetometer's hard iron learned while the sensor turns (issue 25,
  docs/mekf.md "Hard iron"; mekf, qcf and adukf): a candidate field model fitted beside the
  filter that replaces the hard iron and the field reference when it explains the field much
  better.
"""
from __future__ import annotations

import math

import casadi as ca

from ahrsgen.constants import Const, use

from . import kalman, linalg, quat

# tilt_correction: (|d| + d_z)/|d| below this (d_n within ~0.1 deg of straight up) takes the half-turn
TILT_FLIP_EPS = Const("TILT_FLIP_EPS", 1e-6)


def gps_lowpass(a_new, f_n, vel, v_lp, v_ins, alpha, dt, tau, new_gps, m_comp, gravity):
    """Returns (v_ins', v_lp', up): the low-passed specific force a_new (NED, already updated
    with the gain alpha) with the low-passed kinematic acceleration removed.

    The velocity is the GPS sample when one arrived (new_gps), else carried from the last one by
    a = R f + g (f_n = R f, no GPS-rate staircase in the derivative): v_ins'. It goes through the
    same low-pass, v_lp' = v_lp + alpha (v_ins' - v_lp), and (v_ins' - v_lp')/tau, with v_lp'
    already updated, is exactly the same discrete low-pass applied to the velocity's
    differences (v_k - v_{k-1})/dt (the low-pass of a derivative is the derivative of the
    low-pass; no differencing noise): up = a_new - (v_ins' - v_lp')/tau. Without compensation
    (m_comp = 0) the velocity low-pass holds and up = a_new."""
    vi_new = ca.if_else(new_gps, vel, v_ins + (f_n + ca.DM([0.0, 0.0, use(gravity)])) * dt)
    v_new = ca.if_else(m_comp, v_lp + alpha * (vi_new - v_lp), v_lp)
    up = ca.if_else(m_comp, a_new - (vi_new - v_new) / tau, a_new)
    return vi_new, v_new, up


def lowpass(x_lp, x, dt, tau: float):
    """One step of the first-order low-pass of time constant tau (s): x_lp + k (x - x_lp)."""
    if tau <= 0:
        return x
    k = dt / (use(tau) + dt)
    return x_lp + k * (x - x_lp)


def warm_lowpass_gain(lp_time, tau: float, dt):
    """The gain of a first-order low-pass of time constant tau (s) with a warm start (VQF's; issue
    26): alpha = dt / (min(t, tau) + dt), t the time it has averaged (0 at its first sample), so it
    is the running mean of its samples until it has seen tau of them and then the low-pass
    x_lp + dt/(tau + dt) (x - x_lp); its first sample weighs 1/n instead of lingering as
    e^(-t/tau). Returns (alpha, t'), t' = min(t + dt, tau). tau > 0."""
    alpha = dt / (ca.fmin(lp_time, use(tau)) + dt)
    return alpha, ca.fmin(lp_time + dt, use(tau))


def lowpass_of_rate(x_lp, delta, dt, tau: float):
    """lowpass(x_lp, delta / dt, dt, tau), the low-pass of a rate measured as a change `delta`
    over dt, written without the quotient: x_lp + (delta - dt x_lp) / (tau + dt), finite for any
    dt > 0 (a denormal dt makes delta / dt infinite). tau > 0."""
    return x_lp + (delta - dt * x_lp) / (use(tau) + dt)


# rest_detector: the steady time stops counting here, s (a whole number: exact in float)
REST_TIME_CAP = Const("REST_TIME_CAP", 1e3)


def rest_detector(gyro, accel_norm2, gyro_lp, rest_time, dt, *, tau: float, gyro_tol: float,
                  accel_tol: float, gravity: float, gyro_max: float, min_time: float, time_cap: float = REST_TIME_CAP,
                  turn_rate=None):
    """Returns (gyro_lp', rest_time', at_rest 0/1).

    Steady: |gyro - gyro_lp'| < gyro_tol and |gyro_lp'| < gyro_max (a steady turn is not
    rest; `turn_rate`, when given, is a second chance: a rotation rate the caller knows better,
    e.g. its estimate's, below gyro_max is no turn either), and the accelerometer's magnitude
    within accel_tol of gravity (from |f|^2, no root).
    rest_time counts the steady time (capped at time_cap so it stays exact in float) and is
    reset to 0 otherwise. What rest is for here is the gyro bias (the low-passed gyro while
    nothing rotates), so the rotation tests are the ones that matter: VQF's test of the
    accelerometer against its own low-pass changed no measured figure of the QCF (BROAD and
    every simulated scenario within 0.02 deg, docs/qcf.md), and the magnitude test keeps
    "at rest" from being declared under a strong acceleration at a constant attitude.
    """
    g_lp = lowpass(gyro_lp, gyro, dt, tau)
    no_turn = ca.sumsqr(g_lp) < gyro_max ** 2
    if turn_rate is not None:
        no_turn = ca.logic_or(no_turn, ca.sumsqr(turn_rate) < gyro_max ** 2)
    steady = ca.logic_and(ca.logic_and(ca.sumsqr(gyro - g_lp) < gyro_tol ** 2,
                                       norm_within(accel_norm2, gravity, accel_tol)), no_turn)
    return (g_lp, *rest_timer(steady, rest_time, dt, min_time=min_time, time_cap=time_cap))


def rest_timer(steady, rest_time, dt, *, min_time, time_cap: float = 1e3):
    """Returns (rest_time', at_rest 0/1): the steady time, counted while `steady` (0/1) up to
    time_cap (so it stays exact in float) and reset to 0 otherwise; at rest once it reaches
    min_time (rest_detector's timer, and mekf's, whose steadiness test is its own)."""
    t_new = ca.if_else(steady, ca.fmin(rest_time + dt, use(time_cap)), 0.0)
    # half a step of margin: a sum of steps landing on min_time decides alike in float and double
    return t_new, t_new + 0.5 * dt >= min_time


# gyro_plateau: this many equal samples in a row (3 repeats) of one fast component is a clip. On
# the 10 BROAD trials (286 Hz, a gyro that never clips) no component above 200 deg/s repeats
# 3 times outside whole-sample duplicates; 2 repeats happen (up to 2 per trial at 200 deg/s)
PLATEAU_SAMPLES = 4
# ... "equal" meaning within this (rad/s): far below any gyro's resolution (a 16-bit +-2000 deg/s
# gyro's step is 1e-3 rad/s), so a clipped sensor's repeated value passes and a moving one's fails
PLATEAU_TOL = Const("PLATEAU_TOL", 1e-6)


def gyro_plateau(gyro, gyro_prev, runs, *, min_rate):
    """Returns (plateau 0/1, runs'): a clipped sample recognised from the data when the user
    left the range at its default (a +-600 deg/s gyro under a 2000 deg/s setting).

    A saturated gyro reports the end of its range, exactly the same number sample after
    sample, while a moving one never does for long. runs[i] counts the repeats of component i
    (|gyro[i]| >= min_rate and |gyro[i] - gyro_prev[i]| < PLATEAU_TOL); a sample equal to the previous one in
    all three components is a duplicate (a logger repeating a sample), which neither counts
    nor resets. plateau: a count reached PLATEAU_SAMPLES - 1. min_rate <= 0: never (a number:
    no expression; a runtime parameter's symbol: its 0 counts no run, as gyro_recovery's
    full_scale)."""
    if isinstance(min_rate, (int, float)) and min_rate <= 0:
        return ca.SX(0), ca.SX.zeros(3)
    same = [ca.fabs(gyro[i] - gyro_prev[i]) < use(PLATEAU_TOL) for i in range(3)]
    dup = ca.logic_and(ca.logic_and(same[0], same[1]), same[2])
    need = PLATEAU_SAMPLES - 1
    fast = [ca.fabs(gyro[i]) >= min_rate for i in range(3)]
    if not isinstance(min_rate, (int, float)):      # a runtime parameter: 0 turns it off there too
        fast = [ca.logic_and(min_rate > 0, f) for f in fast]
    new = [ca.if_else(dup, runs[i], ca.if_else(ca.logic_and(same[i], fast[i]),
                                                   ca.fmin(runs[i] + 1.0, need), 0.0)) for i in range(3)]
    plateau = ca.logic_or(ca.logic_or(new[0] >= need, new[1] >= need), new[2] >= need)
    return plateau, ca.vertcat(*new)


def gyro_recovery(gyro, recover_time, dt, *, full_scale, recovery_time, plateau=None):
    """Returns (clipped 0/1, recover_time', recovering 0/1).

    clipped: a gyro component at or beyond full_scale, or `plateau` (gyro_plateau's flag);
    full_scale = 0 (a number): never. recover_time counts down from recovery_time, set by
    every clipped sample, to 0. recovering: more than half a step of it is left, a margin so
    that a count landing on 0 decides the same in float and double. full_scale may be a
    runtime parameter's symbol."""
    if isinstance(full_scale, (int, float)) and full_scale <= 0:
        clipped = ca.SX(0)
    else:
        clipped = ca.logic_or(ca.logic_or(ca.fabs(gyro[0]) >= full_scale, ca.fabs(gyro[1]) >= full_scale),
                              ca.fabs(gyro[2]) >= full_scale)
        if plateau is not None:
            clipped = ca.logic_or(clipped, plateau)
        if not isinstance(full_scale, (int, float)):     # a runtime parameter: 0 turns it off there too
            clipped = ca.logic_and(full_scale > 0, clipped)
    t_new = ca.if_else(clipped, recovery_time, ca.fmax(recover_time - dt, 0.0))
    return clipped, t_new, t_new > 0.5 * dt


def field_check(norm, sin_dip, ref_norm, ref_dip, dist_time, dt, *, norm_tol: float, dip_tol: float,
                ref_tau: float, new_time: float, learn_time=None, warmup: float = 0.0, hold=None):
    """Magnetic disturbance check. Returns (accept 0/1, ref_norm', ref_dip', dist_time'), and
    learn_time' last when learn_time is given.

    With learn_time (time since the first sample, a state) and warmup > 0, every sample of the
    first `warmup` seconds is accepted and the reference is their running mean (the attitude,
    hence the dip, may still be settling at the first sample).

    ref_norm <= 0 means "not learned yet": the sample is accepted and becomes the reference.
    Accepted when |norm/ref_norm - 1| < norm_tol and |sin_dip - ref_dip| < dip_tol; the
    reference then follows the field with time constant ref_tau. Rejected samples add dt to
    dist_time; once it exceeds new_time the current field becomes the reference, unless `hold`
    (a 0/1 expression: the hard-iron candidate explains the field better, hard_iron_step's suspect).
    """
    if learn_time is not None and warmup <= 0:
        return (*field_check(norm, sin_dip, ref_norm, ref_dip, dist_time, dt, norm_tol=norm_tol,
                             dip_tol=dip_tol, ref_tau=ref_tau, new_time=new_time, hold=hold), learn_time)
    if learn_time is not None:
        first = ref_norm <= 0
        t_l = ca.if_else(first, 0.0, learn_time)
        warming = t_l < warmup
        k = dt / (t_l + dt)                                    # running mean (k = 1 at the first)
        acc, n1, d1, t1 = field_check(norm, sin_dip, ref_norm, ref_dip, dist_time, dt, norm_tol=norm_tol,
                                      dip_tol=dip_tol, ref_tau=ref_tau, new_time=new_time, hold=hold)
        return (ca.if_else(warming, 1.0, acc),
                ca.if_else(warming, ref_norm + k * (norm - ref_norm), n1),
                ca.if_else(warming, ref_dip + k * (sin_dip - ref_dip), d1),
                ca.if_else(warming, 0.0, t1),
                ca.fmin(t_l + dt, warmup))
    learned = ref_norm > 0
    ok_norm = ca.fabs(norm - ref_norm) < norm_tol * ref_norm
    ok_dip = ca.fabs(sin_dip - ref_dip) < dip_tol
    ok = ca.logic_and(ok_norm, ok_dip)
    t_dist = ca.if_else(ok, 0.0, dist_time + dt)
    lasting = t_dist > new_time if hold is None else ca.logic_and(t_dist > new_time, ca.logic_not(hold))
    renew = ca.logic_or(ca.logic_not(learned), lasting)
    accept = ca.logic_or(ok, ca.logic_not(learned))
    n_new = ca.if_else(renew, norm, ca.if_else(ok, lowpass(ref_norm, norm, dt, ref_tau), ref_norm))
    d_new = ca.if_else(renew, sin_dip, ca.if_else(ok, lowpass(ref_dip, sin_dip, dt, ref_tau), ref_dip))
    return accept, n_new, d_new, ca.if_else(renew, 0.0, t_dist)


def tilt_correction(d_n):
    """Shortest NED-frame rotation taking the direction of d_n to [0, 0, 1] (no z component).

    d_n is any vector along the measured down direction (its length, n > 0, does not matter).
    The half-way quaternion [n + d_z, d_y, -d_x, 0] normalised; its squared norm
    (n + d_z)² + d_x² + d_y² is 2 n (n + d_z), so one square root and one division normalise
    it (no unit vector first). For n + d_z < TILT_FLIP_EPS n (within ~0.1 deg of straight up)
    the half-turn about x.
    """
    n = ca.sqrt(ca.sumsqr(d_n))
    w = n + d_n[2]
    flip = w < use(TILT_FLIP_EPS) * n
    inv = 1 / ca.sqrt(2 * n * w)
    return quat.vec(ca.if_else(flip, 0.0, w * inv), ca.if_else(flip, 1.0, d_n[1] * inv),
                    ca.if_else(flip, 0.0, -d_n[0] * inv), 0.0)


def norm_within(n2, center: float, tol: float):
    """||v| - center| < tol from n2 = |v|², without a square root: (center - tol)² < n2 <
    (center + tol)², the lower bound only when center > tol."""
    center = use(center)
    inside = n2 < (center + tol) ** 2
    return ca.logic_and(n2 > (center - tol) ** 2, inside) if center > tol else inside


# heading_correction_ned: a horizontal field part below this (any unit) has no heading: identity
HEADING_H_MIN = Const("HEADING_H_MIN", 1e-15)


def heading_correction(q, m, declination: float = 0.0):
    """Rotation about NED z taking the horizontal part of R(q) m to heading `declination`."""
    return heading_correction_ned(quat.rotate(q, m), declination)


def heading_correction_ned(m_n, declination: float = 0.0):
    """Rotation about NED z taking the horizontal part (x, y) of the NED vector m_n to heading
    `declination`: [cos(e/2), 0, 0, -sin(e/2)], e = atan2(y, x) - declination in (-pi, pi].

    Half-way forms, no trigonometry and no cancellation: with h = |(x, y)| (after turning
    (x, y) by -declination), cos(e/2) = sqrt((h + x)/2h) and |sin(e/2)| = sqrt((h - x)/2h),
    their product y/2h; so for x >= 0 the quaternion is [h + x, 0, 0, -y] / sqrt(2h(h + x)),
    for x < 0 [|y|, 0, 0, -sgn(y)(h - x)] / sqrt(2h(h - x)) (sgn(0) = +1: e = pi turns by +pi).
    A field with no horizontal part (h² < 1e-30) gives the identity.
    """
    x, y = m_n[0], m_n[1]
    if declination != 0.0:
        cd, sd = math.cos(declination), math.sin(declination)
        x, y = x * cd + y * sd, y * cd - x * sd
    h = ca.sqrt(x * x + y * y)
    degenerate = h < use(HEADING_H_MIN)
    front = x >= 0
    inv = 1 / ca.sqrt((h + h) * (h + ca.fabs(x)))
    c_h = ca.if_else(front, (h + x) * inv, ca.fabs(y) * inv)
    s_h = ca.if_else(front, -y * inv, ca.if_else(y > 0, x - h, h - x) * inv)
    return quat.vec(ca.if_else(degenerate, 1.0, c_h), 0.0, 0.0, ca.if_else(degenerate, 0.0, s_h))


def tilt_heading_vec(d_n, n, m_n, declination: float = 0.0):
    """(T_x, T_y, H_z): the vector parts tilt_correction(d_n)[1:3] and
    heading_correction_ned(rotate_xy_tilt(T, m_n), declination)[3], with n = |d_n| given (a
    caller that needs it elsewhere computes it once).

    The tilt's half-way quaternion T' = [w, d_y, -d_x, 0], w = n + d_z (the half-turn
    [0, 1, 0, 0] when flipped, as tilt_correction), is normalised only for the tilt's own
    components: R(T) m_n's horizontal part times X = |T'|² (2 n w; 1 flipped) is X v minus terms
    homogeneous in T', and the heading depends only on the direction of (x, y), so it reads
    that (x, y) X as it is (a horizontal part below HEADING_H_MIN is h X < HEADING_H_MIN X)."""
    w = n + d_n[2]
    flip = w < use(TILT_FLIP_EPS) * n
    tw = ca.if_else(flip, 0.0, w)
    tx = ca.if_else(flip, 1.0, d_n[1])
    ty = ca.if_else(flip, 0.0, -d_n[0])
    big_x = ca.if_else(flip, 1.0, 2 * n * w)
    c = ty * m_n[0] - tx * m_n[1] - tw * m_n[2]
    u = c + c
    x, y = big_x * m_n[0] - ty * u, big_x * m_n[1] + tx * u
    if declination != 0.0:
        cd, sd = math.cos(declination), math.sin(declination)
        x, y = x * cd + y * sd, y * cd - x * sd
    h = ca.sqrt(x * x + y * y)
    inv_x = 1 / ca.sqrt(big_x)
    inv_y = 1 / ca.sqrt((h + h) * (h + ca.fabs(x)))
    s_h = ca.if_else(x >= 0, -y * inv_y, ca.if_else(y > 0, x - h, h - x) * inv_y)
    return tx * inv_x, ty * inv_x, ca.if_else(h < use(HEADING_H_MIN) * big_x, 0.0, s_h)


# hard_iron_step's constants (reference_aiding states them too; a test checks they agree)
HARD_IRON_NC = 5          # candidate field model [β (3), n, v]
HARD_IRON_RES_TAU = Const("HARD_IRON_RES_TAU", 0.2)   # s: the residuals are low-passed over this (white noise averages out)
HARD_IRON_P0 = Const("HARD_IRON_P0", 0.3)        # initial standard deviation of the candidate, fraction of the norm
HARD_IRON_RATIO = Const("HARD_IRON_RATIO", 4.0)     # the candidate must explain the field this much better (mean squares)
HARD_IRON_NORM_MIN = Const("HARD_IRON_NORM_MIN", 1e-6)  # floor of the corrected field's norm in the rows (fraction)
HARD_IRON_N_MIN = Const("HARD_IRON_N_MIN", 0.1)     # a candidate field norm below this fraction of the reference is never taken
HARD_IRON_TIME_CAP = Const("HARD_IRON_TIME_CAP", 1e3)  # s: the turning time stops counting here (exact in float)
HARD_IRON_PIVOT_MIN = Const("HARD_IRON_PIVOT_MIN", 1e-12)  # a row whose variance is not above this is not applied


def _sym_lower(v, n):
    """n x n symmetric matrix from a flat column-major vector, reading only its lower triangle."""
    return linalg.lower_symmetric(ca.reshape(v, n, n))


def _flat_mirrored(M):
    """Flat column-major vector of M's lower triangle mirrored (exactly symmetric)."""
    return ca.vec(linalg.lower_symmetric(M))


def hard_iron_residuals(u, x, Rq):
    """The candidate field model x = [β (3), n, v] (units of the reference norm): the corrected
    field d = u − β has norm n and vertical (NED down) component v. Model minus measurement for
    the two rows; neither involves the heading."""
    d = u - x[0:3]
    return ca.vertcat(ca.fmax(ca.sqrt(ca.sumsqr(d)), use(HARD_IRON_NORM_MIN)) - x[3], ca.dot(Rq[2, :].T, d) - x[4])


def hard_iron_step(q, mag, b, ref, cx, cP, fresh, reopen, rlp, rmean, e, turn_time, dt, *, rw, noise, bias_max,
                   settle, th, jump, refine, dip_angle: bool):
    """One step of the hard-iron estimate while the sensor turns (the caller tests the turning).
    Returns {name: SX} of the updated state and two flags:

    - the fit: a candidate x = [β (3), n, v], in units of the reference norm B = ref[0]: the
      field u − β (u = mag / B, mag raw) has norm n and NED down component v. Started
      (`fresh`, 0/1) from the present hard iron b and reference; `reopen` (0/1) sets its
      covariance back to HARD_IRON_P0² I (a new disturbance); then P += rw² dt I, the norm and
      vertical rows (H by CasADi jacobian at the prior x, variance noise²) in turn, |β| bounded
      by bias_max;
    - the bookkeeping: the residuals of the present model [|c| − 1, (R c)_D − sin dip]
      (c = (mag − b)/B) and of the candidate, low-passed over HARD_IRON_RES_TAU (rlp); the
      present ones' mean over `settle` (rmean); the mean squares over `settle` of the present,
      the candidate and the present less its mean (e); the time turning (turn_time);
    - suspect: over `settle` of turning the candidate explains the field HARD_IRON_RATIO times
      better than the present model even re-referenced (e[2] > ratio e[1]) and its hard iron
      differs from b by at least `jump` of the field (`refine` once |b| is itself that large);
    - switched: suspect, the candidate's residuals below th (RMS), its hard iron known to th
      (root of its covariance trace) and n > HARD_IRON_N_MIN: b = B β, the reference
      [n B, v/n] (dip_angle: [n B, asin(v/n)]), the candidate re-expressed in the new norm, e
      set to the candidate's, rmean and turn_time to 0, suspect to 0.

    ref is [norm, sin dip], or [norm, dip angle] with dip_angle."""
    NC = HARD_IRON_NC
    B = ref[0]
    sin_dip = ca.sin(ref[1]) if dip_angle else ref[1]
    Rq = quat.rotmat(q)
    u = mag / B
    x0 = ca.if_else(fresh, ca.vertcat(b / B, 1.0, sin_dip), cx)
    P0 = ca.if_else(ca.logic_or(fresh, reopen), ca.SX.eye(NC) * use(HARD_IRON_P0) ** 2, _sym_lower(cP, NC))
    P0 = P0 + ca.SX.eye(NC) * (rw ** 2 * dt)
    xs = ca.SX.sym("x", NC)
    res = hard_iron_residuals(u, xs, Rq)
    H = ca.substitute(ca.jacobian(res, xs), xs, x0)
    z = -ca.substitute(res, xs, x0)
    dx, P1, _ = kalman.scalar_updates(P0, [(H[i, :], z[i], noise ** 2) for i in range(2)], tol=use(HARD_IRON_PIVOT_MIN))
    x1 = x0 + dx
    nb = ca.sqrt(ca.sumsqr(x1[0:3]))
    scale = ca.if_else(nb > bias_max, bias_max / nb, 1.0)
    x1 = ca.vertcat(x1[0:3] * scale, x1[3], x1[4])
    c = u - b / B
    r = ca.vertcat(ca.sqrt(ca.sumsqr(c)) - 1.0, ca.dot(Rq[2, :].T, c) - sin_dip, hard_iron_residuals(u, x1, Rq))
    rlp1 = lowpass(rlp, r, dt, HARD_IRON_RES_TAU)
    a = dt / (settle + dt)
    rmean1 = rmean + a * (rlp1[0:2] - rmean)
    d0, d1 = rlp1[0] - rmean1[0], rlp1[1] - rmean1[1]
    e_new = ca.vertcat(rlp1[0] * rlp1[0] + rlp1[1] * rlp1[1], rlp1[2] * rlp1[2] + rlp1[3] * rlp1[3], d0 * d0 + d1 * d1)
    e1 = e + a * (e_new - e)
    turn1 = ca.fmin(turn_time + dt, use(HARD_IRON_TIME_CAP))
    better = ca.logic_and(turn1 >= settle, e1[2] > use(HARD_IRON_RATIO) * e1[1])
    db2 = ca.sumsqr(x1[0:3] * B - b)
    b2 = ca.sumsqr(b)
    jmp = ca.if_else(b2 >= jump * jump * B * B, refine, jump)
    suspect = ca.logic_and(better, db2 >= jmp * jmp * B * B)
    th2 = th * th
    p_beta = P1[0, 0] + P1[1, 1] + P1[2, 2]
    switched = ca.logic_and(ca.logic_and(suspect, e1[1] < th2), ca.logic_and(p_beta < th2, x1[3] > use(HARD_IRON_N_MIN)))
    n = x1[3]
    s_new = ca.fmin(ca.fmax(x1[4] / n, -1.0), 1.0)
    ref_sw = ca.vertcat(n * B, ca.asin(s_new) if dip_angle else s_new)
    cP1 = _flat_mirrored(P1)
    return {"b_out": ca.if_else(switched, B * x1[0:3], b),
            "ref_out": ca.if_else(switched, ref_sw, ref),
            "cx_out": ca.if_else(switched, ca.vertcat(x1[0:3] / n, 1.0, x1[4] / n), x1),
            "cP_out": ca.if_else(switched, _flat_mirrored(P1 / (n * n)), cP1),
            "rlp_out": rlp1,
            "rmean_out": ca.if_else(switched, ca.SX.zeros(2), rmean1),
            "e_out": ca.if_else(switched, ca.vertcat(e1[1], e1[1], e1[1]), e1),
            "turn_time_out": ca.if_else(switched, 0.0, turn1),
            "suspect": ca.logic_and(suspect, ca.logic_not(switched)),
            "switched": switched}
