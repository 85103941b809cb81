"""Symbolic model of the MEKF (patent CN102692225B): CasADi kernels for the generated C.

Error state X = [δq (3), δb (3)], nominal q̂ (body->NED) and b̂; true attitude
normalise(q̂ ⊗ [1, δq]), true bias b̂ + δb. The Jacobians F, G (discrete error-state
propagation) and H (Euler angles of q̂ ⊗ [1, δq] at δq = 0) are taken by CasADi's
`jacobian` of the functions written out below - nothing is typed by hand here (the NumPy
reference derives them by hand, independently).

measurement = "vectors" (the product design) keeps the attitude error in the earth frame,
true attitude normalise([1, δ] ⊗ q̂), δ = R(q̂) δq: F = [[I, B], [0, I]] and constant gravity
and heading rows (predict_attitude_function). Its F's body rows F_q, F_b are written in a
closed form (attitude_rows), checked equal to CasADi's jacobians when the model is built.

Kernels:
  <p>_predict  patent steps 1-2: q̂ ← normalise(q̂ ⊗ exp(½ (ω − b̂) dt)), P ← F P Fᵀ + G Q Gᵀ
  <p>_update   steps 3-8 with a row mask: measured angles (accelerometer tilt after the
               optional motion compensation, GPS course or magnetic heading), wrapped
               innovations, Cholesky gain, Joseph update, error injection and reset
  <p>_init     first attitude from the accelerometer tilt and the heading (if any)

P is stored full (36 values, column-major = row-major since symmetric) but each kernel
reads only its lower triangle and writes the lower triangle mirrored, so the stored P is
exactly symmetric; the Joseph form keeps it positive semi-definite.
"""
from __future__ import annotations

import math

import casadi as ca

from ahrsgen.codegen import emit
from ahrsgen.constants import G0, Const, computed, use
from ahrsgen.codegen.model import FilterModel, KernelSpec, StateField
from ahrsgen.symbolic import aiding, attitude, kalman, quat

N = 6           # error-state size
S_PIVOT_MIN = Const("S_PIVOT_MIN", 1e-12)   # innovation covariance must have Cholesky pivots above this
COS2_PITCH_MIN = Const("COS2_PITCH_MIN", 1e-4)  # no correction while cos²(pitch) <= this (pitch within 0.57° of ±90°)
AGE_MAX = Const("AGE_MAX", 1e3)         # the GPS-velocity age stops counting here (s)
GPS_DT_MIN = Const("GPS_DT_MIN", 1e-3)     # two GPS samples closer than this (s) give no new acceleration
DT_Q_MIN = Const("DT_Q_MIN", 1e-9)       # s: floor of dt in the gyro-noise variance σ_g²/dt

HEAD_AGE_MAX = Const("HEAD_AGE_MAX", 1.0)    # s without a heading correction before HEADING_UNAIDED
MAG_INTERVAL_MAX = Const("MAG_INTERVAL_MAX", 0.1)  # s: a magnetometer sample stands for at most this long (mag_heading_density)

EXTRA_STATUS = [
    ("COURSE_SLOW", "GPS sample present but ground speed below gps_min_speed: yaw row dropped", "info"),
    ("ACCEL_GATED", "| |accel| - g | above accel_gate: roll/pitch rows dropped", "info"),
    ("UPDATE_SKIPPED", "correction skipped: innovation covariance not positive definite, or pitch within 0.57 deg of +-90 deg (Euler angles singular)"),
]
VECTOR_STATUS = [
    ("HEADING_UNAIDED", "no heading correction (GPS course or magnetometer) for more than 1 s", "info"),
    ("MAG_DISTURBED", "magnetometer rejected: field norm or dip angle off the learned reference, or the heading gate", "info"),
    ("AT_REST", "rest detected: the gyro reading measures the gyro bias directly", "info"),
    ("HARD_IRON_SWITCHED", "the magnetometer hard iron and reference field were replaced by the candidate fitted while turning", "info"),
    ("GYRO_RECOVERY", "a gyro component at gyro_full_scale (clipped), or within clip_recovery_time after one: the attitude covariance widened, the sensors taken as they come", "info"),
]
UP_NED = (0.0, 0.0, -1.0)   # direction of the specific force at rest, NED


# ------------------------------------------------------------------------------------
# helpers
def sym_lower(v, n=N):
    """n x n symmetric SX matrix from a flat (n*n) vector, reading only its lower triangle."""
    M = ca.SX.zeros(n, n)
    for j in range(n):
        for i in range(j, n):
            M[i, j] = v[i + n * j]
            M[j, i] = v[i + n * j]
    return M


def flat_mirrored(M, n=N):
    """Flat column-major (n*n) vector of the lower triangle of M mirrored (exactly symmetric)."""
    out = []
    for j in range(n):
        for i in range(n):
            out.append(M[max(i, j), min(i, j)])
    return ca.vertcat(*out)


def error_propagation(dq, db, ng, nb, omega_hat, dt, c=None):
    """One-step error propagation (what F and G linearise).

    Nominal: q̂' = q̂ ⊗ a, a = exp(½ ω̂ dt). Truth: q' = q ⊗ exp(½ (ω̂ − δb − n_g) dt) with
    q = q̂ ⊗ [1, δq] (unnormalised; the Jacobian at 0 does not depend on the norm), so
    [1, δq'] ∝ a* ⊗ [1, δq] ⊗ exp(½ (ω̂ − δb − n_g) dt); δb' = δb + n_b. n_g is the gyro
    rate noise averaged over the step (variance σ_g²/dt), n_b the bias random-walk
    increment (σ_bw² dt). Written this way ∂/∂δb and ∂/∂n_g are the same expression, which
    the emitter computes once.

    δq' = e_vec / e_w; at the linearisation point e = a* ⊗ a = [1, 0, 0, 0] (a is a unit
    quaternion), where the derivative of e_vec / e_w is that of e_vec: e_vec is returned and
    the Jacobian taken without the quotient rule's divisions. c: a variable standing for
    exp(½ (ω̂ − δb − n_g) dt) (jacobians_FG differentiates through it).
    """
    a = quat.qexp(0.5 * dt * omega_hat)
    if c is None:
        c = quat.qexp(0.5 * dt * (omega_hat - db - ng))
    e = quat.qmul(quat.qmul(quat.qconj(a), quat.vec(1, dq[0], dq[1], dq[2])), c)
    return ca.vertcat(e[1], e[2], e[3], db + nb)


def measurement(q, dq):
    """Euler angles of normalise(q̂ ⊗ [1, δq]) (what H linearises)."""
    return quat.euler(quat.qnormalize(quat.qmul(q, quat.vec(1, dq[0], dq[1], dq[2]))))


def jacobians_FG(omega_hat, dt):
    """(F, G) by CasADi jacobians of error_propagation at X = 0, noise = 0, taken through the
    exponential c = exp(v), v = ½ (ω̂ − δb − n_g) dt, which is all that δb and n_g enter:
    ∂f/∂x = ∂f/∂x|_c + ∂f/∂c · ∂c/∂v · ∂v/∂x (each factor a CasADi jacobian, ∂c/∂v by
    quat.qexp_jacobian), evaluated at c = exp(½ ω̂ dt)."""
    dq, db, ng, nb = (ca.SX.sym(n, 3) for n in ("dq", "db", "ng", "nb"))
    c = ca.SX.sym("c", 4)
    f = error_propagation(dq, db, ng, nb, omega_hat, dt, c=c)
    v = 0.5 * dt * (omega_hat - db - ng)
    zeros = [dq, db, ng, nb]
    chain = ca.mtimes(kalman.jacobian_at(f, c, zeros), quat.qexp_jacobian(0.5 * dt * omega_hat))
    x, w = ca.vertcat(dq, db), ca.vertcat(ng, nb)
    F = kalman.jacobian_at(f, x, zeros) + ca.mtimes(chain, ca.jacobian(v, x))
    G = kalman.jacobian_at(f, w, zeros) + ca.mtimes(chain, ca.jacobian(v, w))
    c0 = quat.qexp(0.5 * dt * omega_hat)
    return ca.substitute(F, c, c0), ca.substitute(G, c, c0)


def jacobian_H(q):
    """H (3 x 6) by CasADi jacobian of measurement at δq = 0 (zero columns for δb)."""
    dq = ca.SX.sym("dq", 3)
    Hq = kalman.jacobian_at(measurement(q, dq), dq, [dq])
    return ca.horzcat(Hq, ca.SX.zeros(3, 3))


# ------------------------------------------------------------------------------------
# kernels
def _time_update(p: dict, q, b, gyro, dt):
    """q̂' = normalise(q̂ ⊗ exp(½ ω̂ dt)), the error-state F, G (CasADi jacobians) and Q."""
    omega_hat = gyro - b
    F, G = jacobians_FG(omega_hat, dt)
    return quat.integrate(q, omega_hat, dt), F, G, _process_noise(p, dt)


def _process_noise(p: dict, dt, gyro=None):
    # σ_g²/dt with dt floored at DT_Q_MIN: a vanishing (even denormal) dt gives a vanishing
    # G Q Gᵀ = ¼ σ_g² dt² / max(dt, DT_Q_MIN) J Jᵀ instead of inf * 0 = NaN.
    # gyro given (the product design): each axis's density grows by gyro_rate_noise |ω_i|
    # (scale-factor and cross-axis errors grow with the rate), added in quadrature; the raw
    # rate, the bias being small beside the rates where this term matters.
    inv = 1 / ca.fmax(dt, use(DT_Q_MIN))
    if gyro is None:
        q_g = [p["gyro_noise"] ** 2 * inv] * 3
    else:
        q_g = [(p["gyro_noise"] ** 2 + (p["gyro_rate_noise"] * gyro[i]) ** 2) * inv for i in range(3)]
        if not (isinstance(p["gyro_step_noise"], (int, float)) and p["gyro_step_noise"] == 0):
            # a rate sampled at dt integrated as a constant-axis rotation: the rotation within
            # the step leaves an error of gyro_step_noise (|ω| dt)² rad per step (second order:
            # coning, an averaging IMU's mean rate); as a density over the step, (c |ω|² dt)²
            e = p["gyro_step_noise"] * ca.sumsqr(gyro) * dt
            q_g = [v + e * e for v in q_g]
    return ca.diag(ca.vertcat(*(q_g + [p["gyro_bias_rw"] ** 2 * dt] * 3)))


def predict_function(p: dict, name="predict") -> ca.Function:
    q, b, Pv, gyro, dt = (ca.SX.sym(n, k) for n, k in (("q", 4), ("b", 3), ("P", N * N), ("gyro", 3), ("dt", 1)))
    q_new, F, G, Q = _time_update(p, q, b, gyro, dt)
    P_new = kalman.predict_covariance(sym_lower(Pv), F, G, Q, symmetrize=False)   # mirrored below
    return emit.function(name, {"q": q, "b": b, "P": Pv, "gyro": gyro, "dt": dt},
                         {"q_out": q_new, "P_out": flat_mirrored(P_new)})


def _blocks(Fq, Fb):
    """F = [[F_q, F_b], [0, I]] and G = [[F_b, 0], [0, I]] of the error-state propagation."""
    Z, I = ca.SX.zeros(3, 3), ca.SX.eye(3)
    return ca.blockcat([[Fq, Fb], [Z, I]]), ca.blockcat([[Fb, Z], [Z, I]])


def attitude_rows(q, omega_hat, dt):
    """q̂' = normalise(q̂ ⊗ a), a = exp(v), v = ½ ω̂ dt, and F's attitude rows in closed form
    from a's factors (quat.qexp_factors: C = cos|v|, S = sin|v|/|v|, k), sharing v vᵀ:

      F_q = R(a)ᵀ = (C² − S² |v|²) I + 2 S² v vᵀ − 2 C S [v×]
      F_b = −½ dt J_r(2v) = −½ dt ((1 − k |v|²) I − S² [v×] + k v vᵀ)

    (J_r by [v×]² = v vᵀ − |v|² I). The same matrices as CasADi's jacobians of
    error_propagation (jacobians_FG), checked when the model is built, in about a third of the
    operations."""
    v = 0.5 * dt * omega_hat
    vv = [[v[i] * v[j] for j in range(3)] for i in range(3)]
    for i in range(3):
        for j in range(i):
            vv[i][j] = vv[j][i]
    m = vv[0][0] + vv[1][1] + vv[2][2]
    C, S, k = quat.qexp_factors(v, m)
    q_new = quat.qnormalize(quat.qmul(q, quat.vec(C, S * v[0], S * v[1], S * v[2])))
    S2 = S * S
    cq, sq2, cs2 = C * C - S2 * m, S2 + S2, 2 * (C * S)       # F_q = cq I + sq2 v vᵀ − cs2 [v×]
    h = 0.5 * dt
    cb, sb, kb = h * (k * m - 1), h * S2, -(h * k)            # F_b = cb I + sb [v×] + kb v vᵀ
    cross = [[None, -v[2], v[1]], [v[2], None, -v[0]], [-v[1], v[0], None]]      # [v×] off the diagonal
    Fq, Fb = ca.SX.zeros(3, 3), ca.SX.zeros(3, 3)
    for i in range(3):
        for j in range(3):
            if i == j:
                Fq[i, i] = cq + sq2 * vv[i][i]
                Fb[i, i] = cb + kb * vv[i][i]
            else:
                Fq[i, j] = sq2 * vv[i][j] - cs2 * cross[i][j]
                Fb[i, j] = kb * vv[i][j] + sb * cross[i][j]
    return q_new, Fq, Fb


def predict_attitude_function(p: dict, name="predict_attitude") -> ca.Function:
    """The time update in two kernels (smaller frames): the attitude and F's attitude rows by
    the bias error here; `predict_covariance` takes them.

    measurement = "vectors" keeps the attitude error in the earth frame: q = [1, δ] ⊗ q̂,
    δ = R(q̂) δq (the body-frame error δq of the patent's design, rotated). Its propagation is
    the body-frame one rotated: δ' = R(q̂') δq' = R(q̂') (F_q δq + F_b δb) = δ + R(q̂') F_b δb,
    as R(q̂') F_q = R(q̂) R(a) R(a)ᵀ = R(q̂): F = [[I, B], [0, I]], G = [[B, 0], [0, I]] with
    B = R(q̂') F_b, the body rows F_q, F_b in attitude_rows' closed form. The measurement
    rows become constants (gravity_rows, update_heading). F_q, F_b and q' equal CasADi's
    jacobians (jacobians_FG) and integrate on both sides of SERIES_MAX, F's other rows are
    [0, I] and G = [[F_b, 0], [0, I]] (∂/∂n_g is ∂/∂δb): tests/filters/mekf/test_mekf_model.py."""
    q, b, gyro, dt = (ca.SX.sym(n, k) for n, k in (("q", 4), ("b", 3), ("gyro", 3), ("dt", 1)))
    q_new, Fq, Fb = attitude_rows(q, gyro - b, dt)
    B = ca.mtimes(quat.rotmat(q_new), Fb)
    return emit.function(name, {"q": q, "b": b, "gyro": gyro, "dt": dt},
                         {"q_out": q_new, "B": ca.reshape(B, 9, 1)})


def predict_covariance_function(p: dict, name="predict_covariance") -> ca.Function:
    """P⁻ = F P Fᵀ + G Q Gᵀ, F = [[I, B], [0, I]], G = [[B, 0], [0, I]] (the earth-frame
    attitude error: see predict_attitude), B by the kernel before.

    clip = 1 (a gyro component at gyro_full_scale): the rotation the sample missed is unknown, up
    to one range's worth over the step, so the attitude block gains (gyro_full_scale dt / 2)² per
    axis (the error state is the half angle; isotropic, the same in any frame)."""
    Bv, Pv, gyro, dt, clip = (ca.SX.sym(n, k) for n, k in (("B", 9), ("P", N * N), ("gyro", 3), ("dt", 1),
                                                           ("clip", 1)))
    F, G = _blocks(ca.SX.eye(3), ca.reshape(Bv, 3, 3))
    P_new = kalman.predict_covariance(sym_lower(Pv), F, G, _process_noise(p, dt, gyro), symmetrize=False)
    w = 0.5 * p["gyro_full_scale"] * dt
    P_new = P_new + ca.if_else(clip, w * w, 0) * ca.diag(ca.DM([1, 1, 1, 0, 0, 0]))
    return emit.function(name, {"B": Bv, "P": Pv, "gyro": gyro, "dt": dt, "clip": clip},
                         {"P_out": flat_mirrored(P_new)})


def measured_angles(p: dict, q, b, gyro, accel, mag, vel, acc_n, m_comp):
    """Step 3: [φ₂, θ₂, ψ₂] from the (compensated) accelerometer and the heading source.

    f_b = dv_b/dt + ω × v_b − R(q)ᵀ g_n = R(q)ᵀ (a_n − g_n). 'centripetal' removes ω × v_b
    (v_b = R(q)ᵀ v_gps), 'gps_accel' removes R(q)ᵀ a_n with a_n from GPS differences.
    """
    f = accel
    if p["motion_comp"] == "centripetal":
        w = gyro - b
        vb = quat.rotate_inv(q, vel)
        f = accel - ca.if_else(m_comp, ca.cross(w, vb), ca.DM.zeros(3))
    elif p["motion_comp"] == "gps_accel":
        f = accel - ca.if_else(m_comp, quat.rotate_inv(q, acc_n), ca.DM.zeros(3))
    roll_a, pitch_a = attitude.tilt_angles(f)
    if p["heading_source"] == "mag":
        est = quat.euler(q)
        yaw_m = attitude.tilt_compensated_heading(mag, est[0], est[1], p["declination"])
    else:
        yaw_m = ca.atan2(vel[1], vel[0])
    return roll_a, pitch_a, yaw_m


def update_function(p: dict, name="update") -> ca.Function:
    q = ca.SX.sym("q", 4)
    b = ca.SX.sym("b", 3)
    Pv = ca.SX.sym("P", N * N)
    gyro = ca.SX.sym("gyro", 3)
    accel = ca.SX.sym("accel", 3)
    mag = ca.SX.sym("mag", 3)
    vel = ca.SX.sym("vel", 3)
    acc_n = ca.SX.sym("acc_n", 3)
    mask = ca.SX.sym("mask", 3)     # [tilt rows, heading row, motion compensation] as 0/1
    roll_a, pitch_a, yaw_m = measured_angles(p, q, b, gyro, accel, mag, vel, acc_n, mask[2])
    est = quat.euler(q)
    z = quat.wrap(ca.vertcat(roll_a, pitch_a, yaw_m) - est)                       # step 4
    H = jacobian_H(q)
    r_head = p["mag_heading_noise"] if p["heading_source"] == "mag" else p["course_noise"]
    r = [p["accel_tilt_noise"] ** 2] * 2 + [r_head ** 2]
    Hm, zm, R = kalman.mask_rows(H, z, r, [mask[0], mask[0], mask[1]])
    # steps 5-7: Cholesky gain, Joseph form (mirrored below), X = K Z
    X, P_new, min_pivot = kalman.update(sym_lower(Pv), Hm, zm, R, S_PIVOT_MIN, symmetrize=False)
    q_new = quat.qnormalize(quat.qmul(q, quat.vec(1, X[0], X[1], X[2])))         # step 8
    b_new = b + X[3:6]
    # Euler angles are singular at pitch ±90°: there H has 1/cos(pitch) and the asin's
    # derivative is infinite. Report a negative pivot so the step skips the correction.
    sin_pitch = 2 * (q[0] * q[2] - q[1] * q[3])
    usable = ca.if_else(1 - sin_pitch * sin_pitch > use(COS2_PITCH_MIN), min_pivot, -1.0)
    return emit.function(name, {"q": q, "b": b, "P": Pv, "gyro": gyro, "accel": accel, "mag": mag,
                                "vel": vel, "acc_n": acc_n, "mask": mask},
                         {"q_out": q_new, "b_out": b_new, "P_out": flat_mirrored(P_new),
                          "min_pivot": usable})


def init_function(p: dict, name="init_attitude") -> ca.Function:
    accel = ca.SX.sym("accel", 3)
    mag = ca.SX.sym("mag", 3)
    vel = ca.SX.sym("vel", 3)
    use_head = ca.SX.sym("use_head")
    roll, pitch = attitude.tilt_angles(accel)
    if p["heading_source"] == "mag":
        yaw = attitude.tilt_compensated_heading(mag, roll, pitch, p["declination"])
    else:
        yaw = ca.atan2(vel[1], vel[0])
    yaw = use_head * yaw
    return emit.function(name, {"accel": accel, "mag": mag, "vel": vel, "use_head": use_head},
                         {"q_out": quat.from_euler(roll, pitch, yaw)})


# ------------------------------------------------------------------------------------
# measurement = "vectors" (the product design)
def motion_compensated(p, q, b, gyro, accel, vel, acc_n, m_comp):
    """Specific force with the GPS-known motion acceleration removed (see measured_angles)."""
    if p["motion_comp"] == "centripetal":
        return accel - ca.if_else(m_comp, ca.cross(gyro - b, quat.rotate_inv(q, vel)), ca.DM.zeros(3))
    if p["motion_comp"] == "gps_accel":
        return accel - ca.if_else(m_comp, quat.rotate_inv(q, acc_n), ca.DM.zeros(3))
    return accel


def accel_lowpass_function(p: dict, name="accel_lowpass") -> ca.Function:
    """a_lp ← a_lp + α (R(q) f_c − a_lp), α = dt / (min(lp_time, accel_lpf_tau) + dt): the
    specific force low-passed in the earth frame (motion acceleration averages out, gravity does
    not), with VQF's warm start: lp_time, the time the low-pass has averaged (dt at the first
    sample, capped at accel_lpf_tau; lp_time_out), makes it the running mean of its samples
    until it has seen accel_lpf_tau of them, so the first sample (a multirotor's 1-3 m/s² of
    motor vibration tilts one sample by up to 15°) weighs 1/n instead of lingering as
    e^(-t/τ). The velocity's low-pass below keeps α_v = dt / (τ + dt) from its start (the
    low-passed acceleration ramps in from zero, as before: a running mean of the velocity's
    differences too was measured worse, studies/mekf_warm_start_cv.py). accel_lpf_warm = false:
    α = dt / (τ + dt) from the start (before issue 26).

    Returns the new a_lp, the new v_lp and `up`, the low-passed specific force with the
    low-passed kinematic acceleration removed: for motion_comp = 'gps_lowpass' (m_comp = 1)
    the GPS velocity goes through a low-pass of the same τ without the warm start,
    v_lp ← v_lp + α_v (v − v_lp), and
    (v − v_lp)/τ, with v_lp already updated, is exactly the same discrete low-pass applied to
    the velocity's differences (v_k − v_{k−1})/dt (the low-pass of a derivative is the derivative
    of the low-pass); up = a_lp − (v − v_lp)/τ. Otherwise up = a_lp. up_ok: |up| above
    accel_min_norm (a direction to correct the tilt with).
    """
    q, b, gyro, accel, vel, acc_n, a_lp, v_lp, v_ins = (ca.SX.sym(n, k) for n, k in (
        ("q", 4), ("b", 3), ("gyro", 3), ("accel", 3), ("vel", 3), ("acc_n", 3), ("a_lp", 3), ("v_lp", 3),
        ("v_ins", 3)))
    dt, lp_time = ca.SX.sym("dt"), ca.SX.sym("lp_time")
    mask = ca.SX.sym("mask", 3)        # [motion compensation, GPS sample this step, gyro recovery]
    m_comp = mask[0]
    f = motion_compensated(p, q, b, gyro, accel, vel, acc_n, m_comp)
    tau = p["accel_lpf_tau"]
    # recovering: the sample itself (lp_time held: a warm start begun again after a gyro clip
    # was measured worse on gyro_clip, 0.31 against 0.26 deg)
    alpha_v = ca.if_else(mask[2], 1, dt / (tau + dt))
    warm, lp_next = aiding.warm_lowpass_gain(lp_time, tau, dt)
    alpha = ca.if_else(mask[2], 1, warm if p["accel_lpf_warm"] else dt / (tau + dt))
    lp_new = ca.if_else(mask[2], lp_time, lp_next)
    f_n = quat.rotate(q, f)
    a_new = a_lp + alpha * (f_n - a_lp)
    if p["motion_comp"] == "gps_lowpass":
        # velocity: the GPS sample when one arrived, else carried by a = R f + g from the last
        # one (no GPS-rate staircase in the low-passed derivative)
        # (aiding.gps_lowpass; without compensation, m_comp = 0, the velocity low-pass holds)
        vi_new, v_new, up = aiding.gps_lowpass(a_new, f_n, vel, v_lp, v_ins, alpha_v, dt, tau,
                                               mask[1], m_comp, G0)
    else:
        vi_new, v_new, up = v_ins, v_lp, a_new
    return emit.function(name, {"q": q, "b": b, "gyro": gyro, "accel": accel, "vel": vel, "acc_n": acc_n,
                                "mask": mask, "a_lp": a_lp, "v_lp": v_lp, "v_ins": v_ins, "lp_time": lp_time,
                                "dt": dt},
                         {"a_lp_out": a_new, "v_lp_out": v_new, "v_ins_out": vi_new, "lp_time_out": lp_new,
                          "up_out": up,
                          "up_ok": ca.sumsqr(up) > _square(p["accel_min_norm"])})


def heading_features_function(name="heading_features") -> ca.Function:
    """[|m|, dip, v_bx, v_by]: the field's norm and dip (positive down) seen from the
    attitude q, and the GPS velocity in body axes (is the vehicle moving nose first?)."""
    q, m, vel = ca.SX.sym("q", 4), ca.SX.sym("mag", 3), ca.SX.sym("vel", 3)
    mn = quat.rotate(q, m)
    dip = ca.atan2(mn[2], ca.sqrt(mn[0] * mn[0] + mn[1] * mn[1]))
    vb = quat.rotate_inv(q, vel)
    return emit.function(name, {"q": q, "mag": m, "vel": vel},
                         {"feat": ca.vertcat(ca.sqrt(ca.sumsqr(m)), dip, vb[0], vb[1])})


def gravity_direction(dq):
    """Earth-frame direction of the specific force at rest seen from the truth [1, δ] ⊗ q̂
    (earth-frame error δ), rotated back to the earth frame by q̂: R(q̂) R([1, δ] ⊗ q̂)ᵀ u
    = R([1, δ])ᵀ u, whatever q̂. Its Jacobian at δ = 0 is the constant 2 [u×]: the rows
    [0, 2, 0] and [−2, 0, 0], its third row 0 (a rotation about the vertical leaves it)."""
    return quat.rotate_inv(quat.qnormalize(quat.vec(1, dq[0], dq[1], dq[2])), ca.DM(UP_NED))


def heading_of_error(dq):
    """Heading part of the error: twist angle about the vertical (NED z) of the earth-frame
    error rotation e = [1, δ], 2 atan2(e_z, e_w). Its Jacobian at δ = 0 is [0, 0, 2]: only the
    vertical component, so a heading row never asks for a tilt."""
    return 2 * ca.atan2(dq[2], 1)


def jacobian_gravity():
    """The gravity rows' H (2 x 6): the earth-frame x and y rows of gravity_direction's
    Jacobian (its z row is 0; the bias columns are 0), by CasADi's jacobian: numbers."""
    dq = ca.SX.sym("dq", 3)
    Hq = ca.evalf(kalman.jacobian_at(gravity_direction(dq)[:2], dq, [dq]))
    return ca.horzcat(Hq, ca.DM.zeros(2, 3))


def jacobian_heading():
    """The heading row's H (1 x 6), by CasADi's jacobian of heading_of_error: numbers."""
    dq = ca.SX.sym("dq", 3)
    return ca.horzcat(ca.evalf(kalman.jacobian_at(heading_of_error(dq), dq, [dq])), ca.DM.zeros(1, 3))


def unit_rows(H, z, r):
    """([(h, z, r)], c²): each row of H with one nonzero entry c divided by it, z by c and r by
    c² (the same scalar measurement): h has a structural 1, the row's u = P hᵀ a column of P;
    c² the same for every row (the row variances times it are the unscaled ones)."""
    rows, c2 = [], set()
    for i in range(H.shape[0]):
        nz = [j for j in range(H.shape[1]) if float(H[i, j]) != 0.0]
        if len(nz) != 1:
            raise AssertionError(f"mekf: H row {i} has {len(nz)} nonzero entries, not one")
        c = float(H[i, nz[0]])
        h = ca.SX.zeros(1, H.shape[1])
        h[nz[0]] = 1
        rows.append((h, z[i] * (1 / c), r * (1 / (c * c))))
        c2.add(c * c)
    if len(c2) != 1:
        raise AssertionError("mekf: the rows' entries differ in magnitude")
    return rows, c2.pop()


def _inject(q, b, X):
    """The earth-frame attitude error: q ← normalise([1, x_δ] ⊗ q)."""
    return quat.qnormalize(quat.qmul(quat.vec(1, X[0], X[1], X[2]), q)), b + X[3:6]


def gravity_rows(p: dict, q, up, recover, dt, turn=None, p_bb=None):
    """The gravity-direction measurement: H (2 x 6, numbers), innovations z (2) and their
    variance r.

    z_g = up/|up| − [0, 0, −1] in the earth frame (up: accel_lowpass's earth-frame vector), its
    x and y rows (H = jacobian_gravity, the earth-frame error's constant 2 [u×]: the z row is 0,
    its update would change nothing). With R_g isotropic this is the body-axis measurement
    up/|up| in body axes − R(q̂)ᵀ [0, 0, −1] (H = 2 [R(q̂)ᵀ u ×] on the body-frame error)
    rotated by R(q̂), the same update in exact arithmetic (q̂ unit), in two rows instead of
    three and without rotating up into the body; R_g = σ² min(1 + |z_g|²/(nσ)², cap) (n = accel_adapt_sigmas), σ² = accel_angle_noise² + accel_noise_density²/dt
    (bounded residual adaptation: the correction can be weakened, never locked out); p_bb given
    (the sum of P's gyro-bias diagonal), the density term times 1 + accel_bias_gain p_bb / (3 p0_bias²).
    With GPS (`turn` = (gyro, b̂, v, unobserved)): while the last GPS velocity is stale
    (unobserved = 1: no motion compensation) σ² gains (ω_v |v_h| / g)², the angle by which a turn
    at the last GPS ground speed |v_h| tilts the specific force (ω_v = (gyro − b̂) · R(q̂)ᵀ e₃, the
    turn rate): a coordinated turn without GPS bends the measured gravity by the bank angle, and
    the tilt, and the magnetic heading through the dip, would follow it.
    """
    z_g = up / ca.sqrt(ca.sumsqr(up)) - ca.DM(UP_NED)
    # the motion the low-pass leaves (per sample) and the sensor's white noise (a density over dt)
    sig2 = p["accel_angle_noise"] ** 2
    if not (isinstance(p["accel_noise_density"], (int, float)) and p["accel_noise_density"] == 0):
        white = p["accel_noise_density"] ** 2 / ca.fmax(dt, use(DT_Q_MIN))
        if p_bb is not None and not (isinstance(p["accel_bias_gain"], (int, float)) and p["accel_bias_gain"] == 0):
            # trusted less while the gyro bias is still uncertain (its variance, the mean of P's
            # bias diagonal, against its start p0_bias²): what the tilt then takes goes into the bias
            white = white * (1 + p_bb * (p["accel_bias_gain"] / (3 * p["p0_bias"] * p["p0_bias"])))
        sig2 = sig2 + white
    if turn is not None:
        # unobserved motion: a turn at the last GPS ground speed, as an angle (centripetal / g)
        gyro, b, vel, unobserved = turn
        a_turn = ca.dot(gyro - b, quat.rotmat(q)[2, :].T) * ca.sqrt(vel[0] * vel[0] + vel[1] * vel[1]) / use(G0)
        sig2 = sig2 + ca.if_else(unobserved, a_turn * a_turn, 0)
    # recovering after a gyro clip (recover = 1): no weakening, the covariance sets the gain.
    # accel_adapt_cap = 1 (its minimum): off, min(1 + |z|²/(n²σ²), 1) is 1 exactly
    # (1 + x >= 1 for x >= 0 in floating point too), so no division is written for it
    cap = p["accel_adapt_cap"]
    if isinstance(cap, (int, float)) and cap <= 1:
        r_g = sig2
    else:
        n = p["accel_adapt_sigmas"]
        r_g = ca.if_else(recover, sig2, sig2 * ca.fmin(1 + ca.sumsqr(z_g) / ((n * n) * sig2), cap))
    return jacobian_gravity(), z_g[:2], r_g


def update_gravity_function(p: dict, gps: bool = False, name="update_gravity") -> ca.Function:
    """The two gravity rows (gravity_rows) as scalar rows in turn (kalman.scalar_updates, the
    batch update of the rows stacked), from x = 0: the correction x, P after them and the
    smallest row variance (a pivot of the batch S). One kernel for the two rows, P in
    registers between them, each element of P_out stored as soon as it is final (in place: after
    the last read of that element of P), so the kernel does not hold all of P to its end."""
    q, up, recover, dt, Pv = (ca.SX.sym(n, k) for n, k in (("q", 4), ("up", 3), ("recover", 1), ("dt", 1),
                                                            ("P", N * N)))
    ins = {"q": q, "up": up, "recover": recover, "dt": dt}
    turn = None
    if gps:
        turn = tuple(ca.SX.sym(n, k) for n, k in (("gyro", 3), ("b", 3), ("vel", 3), ("unobserved", 1)))
        ins |= dict(zip(("gyro", "b", "vel", "unobserved"), turn))
    p_bb = Pv[3 + N * 3] + Pv[4 + N * 4] + Pv[5 + N * 5]     # the gyro bias's variances (3 times their mean)
    H, z, r = gravity_rows(p, q, up, recover, dt, turn, p_bb)
    # each row divided by its one entry ±2 (unit_rows: the same measurement, u = a column of P);
    # the row variances, the scaled batch S's pivots, times 4 are the unscaled S's
    rows, c2 = unit_rows(H, z, r)
    x_new, P_new, min_pivot = kalman.scalar_updates(sym_lower(Pv), rows, tol=use(S_PIVOT_MIN) / c2)
    return emit.function(name, ins | {"P": Pv},
                         {"x_out": x_new, "P_out": flat_mirrored(P_new), "min_pivot": c2 * min_pivot})


def update_rest_bias_function(p: dict, name="update_rest_bias") -> ca.Function:
    """At rest the gyro reads its bias: z_b = gyro − b̂, H = [0 I], R_b = σ_g²/dt (one
    sample's noise), 3 scalar rows after the gravity rows (x: their correction, 0 without)."""
    b, Pv, gyro, x = (ca.SX.sym(n, k) for n, k in (("b", 3), ("P", N * N), ("gyro", 3), ("x", N)))
    dt = ca.SX.sym("dt")
    r_b = p["gyro_noise"] ** 2 / ca.fmax(dt, use(DT_Q_MIN))
    H = ca.horzcat(ca.SX.zeros(3, 3), ca.SX.eye(3))
    z = gyro - b
    x_new, P_new, min_pivot = kalman.scalar_updates(sym_lower(Pv), [(H[i, :], z[i], r_b) for i in range(3)],
                                                    x=x, tol=S_PIVOT_MIN)
    return emit.function(name, {"b": b, "P": Pv, "gyro": gyro, "dt": dt, "x": x},
                         {"x_out": x_new, "P_out": flat_mirrored(P_new), "min_pivot": min_pivot})


def inject_function(name="inject") -> ca.Function:
    """Error injection and reset: q ← normalise(q ⊗ [1, x_δq]), b ← b + x_δb."""
    q, b, x = ca.SX.sym("q", 4), ca.SX.sym("b", 3), ca.SX.sym("x", N)
    q_new, b_new = _inject(q, b, x)
    return emit.function(name, {"q": q, "b": b, "x": x}, {"q_out": q_new, "b_out": b_new})


def update_heading_function(p: dict, name="update_heading") -> ca.Function:
    """One heading row: GPS course (use_course = 1) or magnetic heading, vertical only;
    returns the error-state correction x (for `inject`), P⁺ (P itself when s is not usable)
    and the innovation variance s.

    Variance: the course's course_noise² per sample; the magnetic heading's is a density,
    mag_heading_density² / mag_dt with mag_dt the magnetometer's own sample interval (the step
    keeps it, at most MAG_INTERVAL_MAX): the trust per second does not depend on the
    magnetometer's rate (its heading errors, calibration residuals and nearby iron, are
    correlated over far longer than a sample). Times 1 + mag_dev_gain e², e² the squared
    relative norm and dip (rad) deviations of the sample (feat) from the reference field
    (mag_ref), except while recovering from a gyro clip: a clean field is trusted more.

    course: z = wrap(atan2(v_E, v_N) − ψ̂), ψ̂ = atan2(R₁₀, R₀₀) (heading of the body x axis);
    mag:    z = wrap(declination − atan2(m_E, m_N)), m_n = R(q̂) m (the field's heading as
            the estimate sees it, from north it points at the declination).
    H = [0, 0, 2, 0, 0, 0] on the earth-frame attitude error (jacobian_heading). The attitude
    part of the gain is projected on the vertical (its x and y entries 0; on the body-frame
    error, the projection on R(q̂)ᵀ e₃), so the correction is a pure heading rotation;
    Joseph's form stays exact for this gain.
    """
    q, Pv, mag, vel = (ca.SX.sym(n, k) for n, k in (("q", 4), ("P", N * N), ("mag", 3), ("vel", 3)))
    use_course, mag_dt = ca.SX.sym("use_course"), ca.SX.sym("mag_dt")
    feat, ref, recover = ca.SX.sym("feat", 4), ca.SX.sym("mag_ref", 2), ca.SX.sym("recover")
    Rq = quat.rotmat(q)
    mn = ca.mtimes(Rq, mag)
    z_course = quat.wrap(ca.atan2(vel[1], vel[0]) - ca.atan2(Rq[1, 0], Rq[0, 0]))
    z_mag = quat.wrap(p["declination"] - ca.atan2(mn[1], mn[0]))
    z = ca.if_else(use_course, z_course, z_mag)
    r_mag = p["mag_heading_density"] ** 2 / ca.fmax(mag_dt, use(DT_Q_MIN))
    if not (isinstance(p["mag_dev_gain"], (int, float)) and p["mag_dev_gain"] == 0):
        # graded trust: the field's disagreement with the reference (norm relative, dip in rad;
        # feat = heading_features' [|m|, dip]) widens the variance; not while recovering from a
        # gyro clip (the dip is seen through the attitude, which is what is wrong then)
        e_n = ca.if_else(ref[0] > 0, (feat[0] - ref[0]) / ca.fmax(ref[0], use(DT_Q_MIN)), 0)
        e_d = feat[1] - ref[1]
        r_mag = r_mag * ca.if_else(recover, 1, 1 + p["mag_dev_gain"] * (e_n * e_n + e_d * e_d))
    r = ca.if_else(use_course, p["course_noise"] ** 2, r_mag)
    H = jacobian_heading()
    P = sym_lower(Pv)
    PHt = ca.mtimes(P, H.T)
    S = ca.mtimes(H, PHt) + r                                # 1 x 1
    K = PHt * ca.if_else(S > use(S_PIVOT_MIN), 1.0 / S, 1.0)        # one division (a select: stays a product)
    K[0], K[1] = 0, 0           # attitude gain about the (earth-frame) vertical only
    # Joseph form for this gain; P unchanged (selected, so the step may pass P as P_out) when
    # S is not usable - the step then skips the correction. The tilt block, which the gain
    # leaves (its x and y entries 0), is P itself: no select written for it.
    J, ok = kalman.joseph_row(P, K, PHt, S), S > use(S_PIVOT_MIN)
    P_new = ca.SX.zeros(N, N)
    for i in range(N):
        for j in range(N):
            P_new[i, j] = P[i, j] if ca.is_equal(J[i, j], P[i, j], 2) else ca.if_else(ok, J[i, j], P[i, j])
    return emit.function(name, {"q": q, "P": Pv, "mag": mag, "vel": vel, "use_course": use_course,
                                "mag_dt": mag_dt, "feat": feat, "mag_ref": ref, "recover": recover},
                         {"x_out": K * z, "P_out": flat_mirrored(P_new), "s": S})


def init_vectors_function(p: dict, name="init_attitude") -> ca.Function:
    """First attitude: tilt from the accelerometer, yaw from the GPS course (use[0]) or the
    magnetometer (use[1]) or 0; and the earth-frame low-pass started at R(q) f."""
    accel, mag, vel, use = (ca.SX.sym(n, k) for n, k in (("accel", 3), ("mag", 3), ("vel", 3), ("use", 2)))
    roll, pitch = attitude.tilt_angles(accel)
    yaw = ca.if_else(use[0], ca.atan2(vel[1], vel[0]),
                     ca.if_else(use[1], attitude.tilt_compensated_heading(mag, roll, pitch, p["declination"]), 0.0))
    q = quat.from_euler(roll, pitch, yaw)
    return emit.function(name, {"accel": accel, "mag": mag, "vel": vel, "use": use},
                         {"q_out": q, "a_lp_out": quat.rotate(q, accel)})


# ------------------------------------------------------------------------------------
# the step's bookkeeping: sample times, rest, heading source, field check (kernels, so that
# the step template is control flow and copies and the manifest's op counts cover the step)
def _square(x):
    """x² of a parameter (a number, or a runtime parameter's symbol)."""
    return x * x


def aiding_samples_function(p: dict, *, gps: bool, gps_accel: bool, course: bool, moving: bool, mag: bool,
                            name="aiding_samples") -> ca.Function:
    """The aiding samples' bookkeeping, run on every step (before the first attitude too).

    gps: the last valid GPS velocity v_gps and its age v_age (0 at a sample, else + dt while
    below AGE_MAX); `fresh`: v_age' <= gps_vel_timeout. gps_accel: at a sample, the NED
    acceleration a_gps = (v − v_gps)/τ, τ = v_age + dt, when GPS_DT_MIN <= τ <= gps_vel_timeout
    (a_ok = 1), a_ok = 0 when τ is longer, both kept when closer. course: the sample is a course
    sample when its ground speed² >= gps_min_speed² (and > 0), else `course_slow`. moving: fresh
    and v_gps' fast enough over ground (no rest; the course may be the heading).
    mag: the sample with the hard iron removed (mag − mag_bias; zeros without a usable sample)
    and its interval mag_dt = min(mag_age + dt, MAG_INTERVAL_MAX), the time since the last
    usable sample (the heading variance is a density over it); mag_age' = 0 at a sample.
    vel is the finite copy (zeros without a sample); mag is read only when use_mag."""
    dt = ca.SX.sym("dt")
    ins, outs = {}, {}
    min2 = _square(p["gps_min_speed"])
    if gps:
        vel, use_gps, v_gps, v_age = ca.SX.sym("vel", 3), ca.SX.sym("use_gps"), ca.SX.sym("v_gps", 3), ca.SX.sym("v_age")
        ins |= {"vel": vel, "use_gps": use_gps, "v_gps": v_gps, "v_age": v_age}
        v_new = ca.if_else(use_gps, vel, v_gps)
        age_new = ca.if_else(use_gps, 0.0, ca.if_else(v_age < use(AGE_MAX), v_age + dt, v_age))
        outs |= {"v_gps_out": v_new, "v_age_out": age_new}
        if gps_accel:
            a_gps, a_ok = ca.SX.sym("a_gps", 3), ca.SX.sym("a_ok")
            ins |= {"a_gps": a_gps, "a_ok": a_ok}
            tau = v_age + dt
            late = tau > p["gps_vel_timeout"]
            new = ca.logic_and(use_gps, ca.logic_and(ca.logic_not(late), tau >= use(GPS_DT_MIN)))
            outs |= {"a_gps_out": ca.if_else(new, (vel - v_gps) / tau, a_gps),
                     "a_ok_out": ca.logic_or(ca.logic_and(ca.logic_not(use_gps), a_ok), ca.logic_and(
                         use_gps, ca.logic_and(ca.logic_not(late), ca.logic_or(tau >= use(GPS_DT_MIN), a_ok))))}
        def fast_enough(v2):       # v2 >= gps_min_speed² and > 0 (the latter implied when min² > 0)
            return v2 >= min2 if isinstance(min2, (int, float)) and min2 > 0 else ca.logic_and(v2 >= min2, v2 > 0)

        if course:
            fast = fast_enough(vel[0] * vel[0] + vel[1] * vel[1])
            outs |= {"course_sample": ca.logic_and(use_gps, fast),
                     "course_slow": ca.logic_and(use_gps, ca.logic_not(fast))}
        fresh = age_new <= p["gps_vel_timeout"]
        outs["fresh"] = fresh
        if moving:
            vh2 = v_new[0] * v_new[0] + v_new[1] * v_new[1]
            outs["moving"] = ca.logic_and(fresh, fast_enough(vh2))
    if mag:
        m, bias, use_mag, mag_age = ca.SX.sym("mag", 3), ca.SX.sym("mag_bias", 3), ca.SX.sym("use_mag"), ca.SX.sym("mag_age")
        ins |= {"mag": m, "mag_bias": bias, "use_mag": use_mag, "mag_age": mag_age}
        mag_dt = ca.fmin(mag_age + dt, use(MAG_INTERVAL_MAX))
        outs |= {"mag_c": ca.if_else(use_mag, m - bias, ca.DM.zeros(3)), "mag_dt": mag_dt,
                 "mag_age_out": ca.if_else(use_mag, 0.0, mag_dt)}
    ins["dt"] = dt
    return emit.function(name, ins, outs)


def accel_gate_function(p: dict, name="accel_gate") -> ca.Function:
    """`gated`: accel_gate > 0 and | |accel| − g | > accel_gate (the tilt rows dropped)."""
    accel = ca.SX.sym("accel", 3)
    gate = p["accel_gate"]
    gated = ca.fabs(ca.sqrt(ca.sumsqr(accel)) - G0) > gate
    if not isinstance(gate, (int, float)):
        gated = ca.logic_and(gate > 0, gated)
    return emit.function(name, {"accel": accel}, {"gated": gated})


def course_mode_function(p: dict, name="course_mode") -> ca.Function:
    """heading_source = 'auto': the GPS course is the heading while moving nose first (the
    velocity in body axes, feat[2:4], within course_max_sideslip of the body x axis:
    v_y² <= tan² v_x², v_x > 0) or while nothing has corrected the heading for HEAD_AGE_MAX."""
    feat, moving, head_age = ca.SX.sym("feat", 4), ca.SX.sym("moving"), ca.SX.sym("head_age")
    side = p["course_max_sideslip"]
    tan2 = computed("tan(course_max_sideslip)^2", lambda x: math.tan(x) ** 2, side) if isinstance(side, (int, float)) else ca.tan(side) ** 2
    nose_first = ca.logic_and(feat[2] > 0, feat[3] * feat[3] <= tan2 * feat[2] * feat[2])
    return emit.function(name, {"feat": feat, "moving": moving, "head_age": head_age},
                         {"course_mode": ca.logic_and(moving, ca.logic_or(nose_first, head_age > use(HEAD_AGE_MAX)))})


def rest_function(p: dict, name="rest") -> ca.Function:
    """Rest: every gyro sample near its low-pass and that low-pass small (not a turntable),
    both within rest_gyro_th; the accelerometer near its own low-pass (within rest_accel_th,
    when it has a sample); not moving by GPS; for rest_min_time (aiding.rest_timer). The
    low-passes: x_lp + dt/(rest_tau + dt) (x − x_lp), the accelerometer's only with a sample.
    (qcf's aiding.rest_detector tests |f| against gravity instead of the accelerometer's
    low-pass and has no GPS; the timer is the shared piece.)"""
    gyro, accel, use_accel, moving = ca.SX.sym("gyro", 3), ca.SX.sym("accel", 3), ca.SX.sym("use_accel"), ca.SX.sym("moving")
    g_lp, a_lp, t, dt = ca.SX.sym("gyro_lp", 3), ca.SX.sym("acc_lp", 3), ca.SX.sym("rest_time"), ca.SX.sym("dt")
    a = dt / (p["rest_tau"] + dt)
    g_new = g_lp + a * (gyro - g_lp)
    th2 = _square(p["rest_gyro_th"])
    still = ca.logic_and(ca.logic_and(ca.sumsqr(gyro - g_new) < th2, ca.sumsqr(g_new) < th2), ca.logic_not(moving))
    a_new = ca.if_else(use_accel, a_lp + a * (accel - a_lp), a_lp)
    steady_a = ca.sumsqr(accel - a_new) < _square(p["rest_accel_th"])
    still = ca.logic_and(still, ca.logic_or(ca.logic_not(use_accel), steady_a))
    t_new, at_rest = aiding.rest_timer(still, t, dt, min_time=p["rest_min_time"], time_cap=AGE_MAX)
    return emit.function(name, {"gyro": gyro, "accel": accel, "use_accel": use_accel, "moving": moving,
                                "gyro_lp": g_lp, "acc_lp": a_lp, "rest_time": t, "dt": dt},
                         {"gyro_lp_out": g_new, "acc_lp_out": a_new, "rest_time_out": t_new, "at_rest": at_rest})


def mag_check_function(p: dict, hard_iron: bool, name="mag_check") -> ca.Function:
    """The magnetometer's field check against a reference [norm, dip] (feat[0:2], from
    heading_features), on a step with a magnetometer sample not in course mode:

    - mag_norm_th <= 0, or recovering with the reference learned: accepted, nothing changes;
    - learning (mag_ref_time < mag_learn_time): the reference is the running mean of the
      samples (weight dt / (mag_ref_time + dt)), accepted;
    - within the reference (|norm − ref| <= mag_norm_th ref and |dip − ref| <= mag_dip_th):
      accepted, the reference follows with time constant mag_ref_tau, the rejected time reset;
    - else rejected: a candidate field, restarted at a sample off it, else averaged over the time
      it has been steady (weight dt / mag_cand_time); after mag_new_time steady (a lasting
      change) or mag_reject_max rejected in a row it becomes the reference and the sample is
      accepted (not while `hold`, the hard-iron candidate explaining the field), else
      `disturbed`.

    (qcf's aiding.field_check tests the norm's ratio and has no candidate field: mekf keeps its own.)
    hard_iron adds `onset` (rejected now, accepted the step before), `learned` (a reference
    learned, not recovering: the hard-iron fit may run) and `turning` (|gyro − b| >=
    mag_bias_min_rate)."""
    feat, ref, cand = ca.SX.sym("feat", 2), ca.SX.sym("mag_ref", 2), ca.SX.sym("mag_cand", 2)
    t_ref, t_rej, t_cand = ca.SX.sym("mag_ref_time"), ca.SX.sym("mag_rej_time"), ca.SX.sym("mag_cand_time")
    recovering, dt = ca.SX.sym("recovering"), ca.SX.sym("dt")
    nth, dth, learn = p["mag_norm_th"], p["mag_dip_th"], p["mag_learn_time"]
    learned_before = ca.logic_and(recovering, t_ref >= learn)
    if isinstance(nth, (int, float)):
        passing = ca.SX(1) if nth <= 0 else learned_before
    else:
        passing = ca.logic_or(nth <= 0, learned_before)

    def off(r):
        return ca.logic_or(ca.fabs(feat[0] - r[0]) > nth * r[0], ca.fabs(feat[1] - r[1]) > dth)

    learning = t_ref < learn
    ok = ca.logic_not(off(ref))
    head_off = ca.SX.sym("head_off")            # heading_check: the heading inconsistent (gate on)
    if heading_gate_on(p):
        ok = ca.logic_and(ok, ca.logic_not(head_off))
    ref_learn = ref + (dt / (t_ref + dt)) * (feat - ref)
    ref_follow = ref + (dt / (p["mag_ref_tau"] + dt)) * (feat - ref)
    # rejected: the candidate
    new_cand = off(cand)
    t_steady = t_cand + dt                      # > 0: the divisor of the candidate's mean
    t_c1 = ca.if_else(new_cand, 0.0, t_steady)
    cand1 = ca.if_else(new_cand, feat, cand + (dt / t_steady) * (feat - cand))
    t_rej1 = t_rej + dt
    lasting = ca.logic_or(t_c1 >= p["mag_new_time"], t_rej1 > p["mag_reject_max"])
    ins = {"feat": feat, "mag_ref": ref, "mag_ref_time": t_ref, "mag_rej_time": t_rej, "mag_cand": cand,
           "mag_cand_time": t_cand, "recovering": recovering}
    if heading_gate_on(p):
        ins["head_off"] = head_off
    if hard_iron:
        hold = ca.SX.sym("hold")
        ins["hold"] = hold
        lasting = ca.logic_and(lasting, ca.logic_not(hold))
    ins["dt"] = dt
    kept = ca.logic_or(passing, ca.logic_or(learning, ok))      # not rejected
    ref_new = ca.if_else(passing, ref, ca.if_else(learning, ref_learn, ca.if_else(ok, ref_follow,
                                                                                    ca.if_else(lasting, cand1, ref))))
    t_ref_new = ca.if_else(ca.logic_and(ca.logic_not(passing), learning), t_ref + dt, t_ref)
    t_rej_new = ca.if_else(ca.logic_or(passing, learning), t_rej,
                           ca.if_else(ok, 0.0, ca.if_else(lasting, 0.0, t_rej1)))
    outs = {"mag_ref_out": ref_new, "mag_ref_time_out": t_ref_new, "mag_rej_time_out": t_rej_new,
            "mag_cand_out": ca.if_else(kept, cand, cand1),
            "mag_cand_time_out": ca.if_else(kept, t_cand, ca.if_else(lasting, 0.0, t_c1)),
            "use": ca.logic_or(kept, lasting), "disturbed": ca.logic_not(ca.logic_or(kept, lasting))}
    if hard_iron:
        gyro, b = ca.SX.sym("gyro", 3), ca.SX.sym("gyro_bias", 3)
        ins |= {"gyro": gyro, "gyro_bias": b}
        outs |= {"onset": ca.logic_and(ca.logic_not(kept), ca.logic_not(t_rej > 0)),
                 "learned": ca.logic_and(ca.logic_and(ref_new[0] > 0, t_ref_new >= learn), ca.logic_not(recovering)),
                 "turning": ca.sumsqr(gyro - b) >= _square(p["mag_bias_min_rate"])}
    return emit.function(name, ins, outs)


def heading_gate_on(p: dict) -> bool:
    """The heading-consistency gate is built only when it can be on (mag_head_sigmas > 0 or a
    runtime value): a build without it has no unreachable code."""
    k = p.get("mag_head_sigmas")
    return not isinstance(k, (int, float)) or k > 0


def heading_check_function(p: dict, name="heading_check") -> ca.Function:
    """The magnetometer heading against the filter's own heading uncertainty, on a step with a
    magnetometer sample not in course mode: its innovation z = wrap(declination − atan2(m_E,
    m_N)) (update_heading's, from the predicted attitude) low-passed over its sample interval
    with time constant mag_head_tau, head_lp' = wrap(head_lp + a wrap(z − head_lp)),
    a = mag_dt / (mag_head_tau + mag_dt). Consistent while head_lp'² <= mag_head_sigmas² (H P Hᵀ
    + mag_heading_density² / (2 mag_head_tau)): the heading's own variance and what the
    low-pass leaves of the white heading noise. A confident filter whose low-passed heading
    innovation exceeds that sees a field turned by a disturbance the norm and dip checks
    miss (steel nearby turns the field's direction, barely its norm): `off`, rejected as the
    field check rejects. Not while learning the reference field or recovering from a gyro clip
    (P is large then anyway), and not once the rejection has lasted min(mag_new_time,
    mag_reject_max) (`free`: kept while the innovation stays inconsistent, so a lasting change
    is accepted and followed)."""
    q, Pv, mag = ca.SX.sym("q", 4), ca.SX.sym("P", N * N), ca.SX.sym("mag", 3)
    lp, free, t_ref, t_rej = ca.SX.sym("head_lp"), ca.SX.sym("head_free"), ca.SX.sym("mag_ref_time"), ca.SX.sym("mag_rej_time")
    recovering, mag_dt, dt = ca.SX.sym("recovering"), ca.SX.sym("mag_dt"), ca.SX.sym("dt")
    tau, k = p["mag_head_tau"], p["mag_head_sigmas"]
    mn = ca.mtimes(quat.rotmat(q), mag)
    z = quat.wrap(p["declination"] - ca.atan2(mn[1], mn[0]))
    lp_new = quat.wrap(lp + (mag_dt / (tau + mag_dt)) * quat.wrap(z - lp))
    H = jacobian_heading()
    var = ca.mtimes(ca.mtimes(H, sym_lower(Pv)), H.T) + p["mag_heading_density"] ** 2 / (2 * tau)
    inconsistent = lp_new * lp_new > (k * k) * var
    active = ca.logic_and(t_ref >= p["mag_learn_time"], ca.logic_not(recovering))
    given_up = t_rej + dt >= min(p["mag_new_time"], p["mag_reject_max"]) if all(
        isinstance(p[n], (int, float)) for n in ("mag_new_time", "mag_reject_max")) else ca.logic_or(
        t_rej + dt >= p["mag_new_time"], t_rej + dt >= p["mag_reject_max"])
    free_new = ca.logic_and(inconsistent, ca.logic_or(free, given_up))
    return emit.function(name, {"q": q, "P": Pv, "mag": mag, "head_lp": lp, "head_free": free,
                                "mag_ref_time": t_ref, "mag_rej_time": t_rej, "recovering": recovering,
                                "mag_dt": mag_dt, "dt": dt},
                         {"head_lp_out": lp_new, "head_free_out": free_new,
                          "off": ca.logic_and(active, ca.logic_and(inconsistent, ca.logic_not(free_new)))})


def head_timer_function(name="head_timer") -> ca.Function:
    """head_age: 0 after a heading correction, else + dt up to AGE_MAX; `unaided` past HEAD_AGE_MAX."""
    headed, age, dt = ca.SX.sym("headed"), ca.SX.sym("head_age"), ca.SX.sym("dt")
    new = ca.if_else(headed, 0.0, ca.if_else(age < use(AGE_MAX), ca.fmin(age + dt, use(AGE_MAX)), age))
    return emit.function(name, {"headed": headed, "head_age": age, "dt": dt},
                         {"head_age_out": new, "unaided": new > use(HEAD_AGE_MAX)})


def initial_P(p: dict) -> list:
    d = [(0.5 * p["p0_att"]) ** 2] * 3 + [p["p0_bias"] ** 2] * 3
    return [d[i] if i == j else 0.0 for j in range(N) for i in range(N)]


def euler_design_params(p: dict) -> dict:
    """measurement = 'euler_angles' has one heading source and no low-pass: there 'auto' means
    the GPS course (the patent) and 'gps_lowpass' means 'gps_accel' (docs/mekf.md)."""
    p = dict(p)
    if p["heading_source"] == "auto":
        p["heading_source"] = "gps_course"
    if p["motion_comp"] == "gps_lowpass":
        p["motion_comp"] = "gps_accel"
    return p


class Model(FilterModel):
    def __init__(self, params: dict):
        self.vectors = params["measurement"] == "vectors"
        if not self.vectors:
            params = euler_design_params(params)
        p = params
        uses = ["accel"]
        if p["heading_source"] != "gps_course":
            uses.append("mag")
        if p["heading_source"] != "mag" or p["motion_comp"] != "none":
            uses.append("gps")
        status = list(EXTRA_STATUS) + (list(VECTOR_STATUS) if self.vectors else [])
        super().__init__(params, sensors=tuple(uses), extra_status=status)

    def state_fields(self) -> list[StateField]:
        return [
            StateField("q", 4, "attitude quaternion body->NED [w x y z]", [1.0, 0.0, 0.0, 0.0]),
            StateField("gyro_bias", 3, "gyro bias estimate, rad/s", 0.0),
            StateField("P", N * N, "error-state covariance [d, db] (6x6, symmetric; d the attitude error, "
                       + ("earth frame)" if self.vectors else "body frame)"), initial_P(self.params)),
            StateField("v_gps", 3, "last valid GPS velocity NED, m/s", 0.0),
            StateField("v_age", 1, "age of v_gps, s (stops counting at 1e3)", AGE_MAX),
            StateField("a_gps", 3, "NED acceleration from the last two GPS velocities, m/s^2 (motion_comp = gps_accel)", 0.0),
            StateField("a_ok", 1, "1 when a_gps comes from two samples at most gps_vel_timeout apart", 0, "uint32"),
            StateField("initialised", 1, "1 once the attitude has been initialised", 0 if self.params["init_from_sensors"] else 1, "uint32"),
        ] + (self._vector_fields() if self.vectors else [])

    def _vector_fields(self) -> list[StateField]:
        return [
            StateField("a_lp", 3, "specific force low-passed in the earth frame (NED), m/s^2", 0.0),
            StateField("lp_time", 1, "time a_lp has averaged, s (its warm start; stops at accel_lpf_tau)", 0.0),
            StateField("v_lp", 3, "GPS velocity through the same low-pass (motion_comp = gps_lowpass), m/s", 0.0),
            StateField("vlp_ok", 1, "1 while v_lp follows a fresh GPS velocity", 0, "uint32"),
            StateField("v_ins", 3, "GPS velocity carried between GPS samples by the accelerometer, m/s", 0.0),
            StateField("gyro_lp", 3, "rest detection: low-passed gyro, rad/s", 0.0),
            StateField("acc_lp", 3, "rest detection: low-passed accelerometer, m/s^2", 0.0),
            StateField("rest_time", 1, "time the gyro and accelerometer have been steady, s (stops at 1e3)", 0.0),
            StateField("mag_ref", 2, "reference field [norm, dip angle rad] (learned, then followed while accepted)", 0.0),
            StateField("mag_ref_time", 1, "time spent learning the reference field, s", 0.0),
            StateField("mag_rej_time", 1, "time the magnetometer has been rejected in a row, s", 0.0),
            StateField("mag_cand", 2, "candidate new reference [norm, dip] while rejected", 0.0),
            StateField("mag_cand_time", 1, "time the candidate field has been steady, s", 0.0),
            StateField("head_age", 1, "time since the last heading correction, s (stops at 1e3)", AGE_MAX),
            StateField("mag_age", 1, f"time since the last usable magnetometer sample, s (stops at {MAG_INTERVAL_MAX:g})", 0.0),
        ] + ([
            StateField("head_lp", 1, "magnetometer heading innovation low-passed over mag_head_tau, rad", 0.0),
            StateField("head_free", 1, "1 while the heading gate has given up (a lasting inconsistent heading)", 0, "uint32"),
        ] if self._heading_gate() else []) + [
            *self.gyro_recovery_state(),
            self.hard_iron_bias_field(),
        ] + (self.hard_iron_state(bias=False) if self._hard_iron() else [])

    def _samples(self) -> dict:
        """What aiding_samples keeps in this configuration (its keyword arguments)."""
        p, gps = self.params, "gps" in self.sensors
        return {"gps": gps, "gps_accel": gps and p["motion_comp"] == "gps_accel",
                "course": gps and p["heading_source"] != "mag" and (self.vectors or p["heading_source"] == "gps_course"),
                "moving": gps and self.vectors, "mag": self.vectors and p["heading_source"] != "gps_course"}

    def _samples_kernel(self) -> list[KernelSpec]:
        k = self._samples()
        if not (k["gps"] or k["mag"]):
            return []
        flags = (("use_gps", "fresh") if k["gps"] else ()) + (("a_ok", "a_ok_out") if k["gps_accel"] else ()) + (
            ("course_sample", "course_slow") if k["course"] else ()) + (("moving",) if k["moving"] else ()) + (
            ("use_mag",) if k["mag"] else ())
        return [KernelSpec("aiding_samples", aiding_samples_function(self.params, **k),
                           "aiding samples: GPS velocity, its age and acceleration, course sample, moving; the "
                           "magnetometer's sample less the hard iron and its interval", flags=flags)]

    def _accel_gate_on(self) -> bool:
        """The norm gate's test is written only when it can be on (a runtime value, or > 0): no
        unreachable code in a default build. dict.get: not a use of a runtime value."""
        gate = self.params.get("accel_gate")
        return not isinstance(gate, (int, float)) or gate > 0

    def _gate_kernel(self) -> list[KernelSpec]:
        return [KernelSpec("accel_gate", accel_gate_function(self.params), "accelerometer norm gate",
                           flags=("gated",))] if self._accel_gate_on() else []

    def _vector_kernels(self) -> list[KernelSpec]:
        p = self.params
        auto = p["heading_source"] == "auto"
        mag = p["heading_source"] != "gps_course"
        return self._gate_kernel() + self._samples_kernel() + [
            KernelSpec("rest", rest_function(p), "rest: gyro and accelerometer near their low-passes, for rest_min_time",
                       flags=("use_accel", "moving", "at_rest")),
            KernelSpec("head_timer", head_timer_function(), "time since the last heading correction",
                       flags=("headed", "unaided")),
        ] + ([KernelSpec("course_mode", course_mode_function(p), "heading source: GPS course or magnetometer",
                         flags=("moving", "course_mode"))] if auto else []) + (
            [KernelSpec("mag_check", mag_check_function(p, self._hard_iron()),
                        "field check: norm and dip against the learned reference, candidate field",
                        flags=("recovering", "use", "disturbed") + (("head_off",) if self._heading_gate() else ()) + (
                            ("hold", "onset", "learned", "turning") if self._hard_iron() else ()))] if mag else []) + (
            [KernelSpec("heading_check", heading_check_function(p),
                        "heading gate: the low-passed magnetic heading innovation against the filter's heading variance",
                        flags=("head_free", "recovering", "head_free_out", "off"))] if self._heading_gate() else [])

    def kernels(self) -> list[KernelSpec]:
        p = self.params
        if self.vectors:
            return self._vector_kernels() + [
                self.gyro_recovery_kernel(),
                KernelSpec("predict_attitude", predict_attitude_function(p), "time update: attitude and F's attitude rows",
                           early_writes=True, in_place=(("q_out", "q"),)),
                KernelSpec("predict_covariance", predict_covariance_function(p), "time update: covariance",
                           flags=("clip",)),
                KernelSpec("accel_lowpass", accel_lowpass_function(p), "earth-frame low-pass of the compensated specific force",
                           flags=("mask", "up_ok"), early_writes=True,
                           in_place=(("a_lp_out", "a_lp"), ("v_lp_out", "v_lp"), ("v_ins_out", "v_ins"),
                                     ("lp_time_out", "lp_time"))),
                KernelSpec("heading_features", heading_features_function(), "field norm and dip; GPS velocity in body axes"),
                KernelSpec("update_gravity", update_gravity_function(p, "gps" in self.sensors),
                           "gravity direction: two scalar rows on the attitude error (earth frame)",
                           flags=("recover",) + (("unobserved",) if "gps" in self.sensors else ()),
                           early_writes=True, in_place=(("P_out", "P"),)),
                KernelSpec("update_rest_bias", update_rest_bias_function(p), "at rest, the gyro bias: three scalar rows"),
                KernelSpec("inject", inject_function(), "error injection into q and the gyro bias"),
                KernelSpec("update_heading", update_heading_function(p), "one heading row, gain projected on the vertical",
                           flags=("use_course", "recover")),
                KernelSpec("init_attitude", init_vectors_function(p), "first attitude and low-pass state",
                           flags=("use",)),
            ] + ([self.hard_iron_kernel(refine=p["mag_norm_th"], dip_angle=True)] if self._hard_iron() else [])
        return self._gate_kernel() + self._samples_kernel() + [
            KernelSpec("predict", predict_function(p), "time update (patent steps 1-2)"),
            KernelSpec("update", update_function(p), "measurement update with row mask (steps 3-8)", flags=("mask",)),
            KernelSpec("init_attitude", init_function(p), "first attitude from tilt and heading", flags=("use_head",)),
        ]

    def _heading_gate(self) -> bool:
        return self.vectors and self.params["heading_source"] != "gps_course" and heading_gate_on(self.params)

    def _hard_iron(self) -> bool:
        return self.vectors and bool(self.params["mag_bias"]) and self.params["heading_source"] != "gps_course"

    def step_paths(self) -> dict[str, list[str]]:
        """Every kernel a step of the path runs (an aiding step: accelerometer and heading)."""
        p = self.params
        gate = ["accel_gate"] if self._accel_gate_on() else []     # on a step with an accelerometer sample
        pre = ["aiding_samples"] if self._samples_kernel() else []
        if self.vectors:
            every = ["gyro_recovery", "predict_attitude", "predict_covariance", "heading_features"] + (
                ["course_mode"] if p["heading_source"] == "auto" else []) + ["rest"]
            aided = gate + pre + every + ["accel_lowpass"] + (
                ["heading_check"] if self._heading_gate() else []) + (
                ["mag_check"] if p["heading_source"] != "gps_course" else []) + ["update_gravity"]
            heading = ["inject", "update_heading", "inject", "head_timer"]
            return {"gyro only": pre + every + ["head_timer"],
                    "with corrections": aided + heading,
                    "at rest": aided + ["update_rest_bias"] + heading}
        return {"gyro only": pre + ["predict"], "with corrections": gate + pre + ["predict", "update"]}

    def template_context(self) -> dict:
        p = self.params
        return {"n": N, "heading_source": p["heading_source"], "motion_comp": p["motion_comp"],
                "s_pivot_min": S_PIVOT_MIN, "vectors": self.vectors, "hard_iron": self._hard_iron(),
                "samples_kw": self._samples(), "heading_gate": self._heading_gate(),
                "accel_gate_on": self._accel_gate_on(), "gyro_quiet": self.gyro_recovery_quiet()}
