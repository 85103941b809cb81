"""Symbolic model of the MEKF (patent CN102692225B): CasADi kernels for the generated C.

Error state X = [δq (3), δb (3)], nominal q̂ (body->NED) and b̂; true attitude
normalise(q̂ ⊗ [1, δq]), true bias b̂ + δb. The Jacobians F, G (discrete error-state
propagation) and H (Euler angles of q̂ ⊗ [1, δq] at δq = 0) are taken by CasADi's
`jacobian` of the functions written out below - nothing is typed by hand here (the NumPy
reference derives them by hand, independently).

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

import casadi as ca

from generator import emit
from generator.constants import G0
from generator.model import FilterModel, KernelSpec, StateField
from generator.symbolic import attitude, kalman, quat

N = 6           # error-state size
S_PIVOT_MIN = 1e-12   # innovation covariance must have Cholesky pivots above this
COS2_PITCH_MIN = 1e-4  # no correction while cos²(pitch) <= this (pitch within 0.57° of ±90°)
AGE_MAX = 1e3         # the GPS-velocity age stops counting here (s)
GPS_DT_MIN = 1e-3     # two GPS samples closer than this (s) give no new acceleration
DT_Q_MIN = 1e-9       # s: floor of dt in the gyro-noise variance σ_g²/dt

EXTRA_STATUS = [
    ("COURSE_SLOW", "GPS sample present but ground speed below gps_min_speed: yaw row dropped"),
    ("ACCEL_GATED", "| |accel| - g | above accel_gate: roll/pitch rows dropped"),
    ("UPDATE_SKIPPED", "correction skipped: innovation covariance not positive definite, or pitch within 0.57 deg of +-90 deg (Euler angles singular)"),
]


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


def error_propagation(dq, db, ng, nb, omega_hat, dt):
    """One-step error propagation (what F and G linearise).

    Nominal: q̂' = q̂ ⊗ a, a = exp(½ ω̂ dt). Truth: q' = q ⊗ exp(½ (ω̂ − δb − n_g) dt) with
    q = q̂ ⊗ [1, δq] (unnormalised; the Jacobian at 0 does not depend on the norm), so
    [1, δq'] ∝ a* ⊗ [1, δq] ⊗ exp(½ (ω̂ − δb − n_g) dt); δb' = δb + n_b. n_g is the gyro
    rate noise averaged over the step (variance σ_g²/dt), n_b the bias random-walk
    increment (σ_bw² dt). Written this way ∂/∂δb and ∂/∂n_g are the same expression, which
    the emitter computes once.
    """
    a = quat.qexp(0.5 * dt * omega_hat)
    e = quat.qmul(quat.qmul(quat.qconj(a), quat.vec(1, dq[0], dq[1], dq[2])),
                  quat.qexp(0.5 * dt * (omega_hat - db - ng)))
    return ca.vertcat(e[1] / e[0], e[2] / e[0], e[3] / e[0], db + nb)


def measurement(q, dq):
    """Euler angles of normalise(q̂ ⊗ [1, δq]) (what H linearises)."""
    return quat.euler(quat.qnormalize(quat.qmul(q, quat.vec(1, dq[0], dq[1], dq[2]))))


def jacobians_FG(omega_hat, dt):
    """(F, G) by CasADi jacobian of error_propagation at X = 0, noise = 0."""
    dq, db, ng, nb = (ca.SX.sym(n, 3) for n in ("dq", "db", "ng", "nb"))
    f = error_propagation(dq, db, ng, nb, omega_hat, dt)
    zeros = [dq, db, ng, nb]
    F = kalman.jacobian_at(f, ca.vertcat(dq, db), zeros)
    G = kalman.jacobian_at(f, ca.vertcat(ng, nb), zeros)
    return F, G


def jacobian_H(q):
    """H (3 x 6) by CasADi jacobian of measurement at δq = 0 (zero columns for δb)."""
    dq = ca.SX.sym("dq", 3)
    Hq = kalman.jacobian_at(measurement(q, dq), dq, [dq])
    return ca.horzcat(Hq, ca.SX.zeros(3, 3))


# ------------------------------------------------------------------------------------
# kernels
def predict_function(p: dict, name="predict") -> ca.Function:
    q = ca.SX.sym("q", 4)
    b = ca.SX.sym("b", 3)
    Pv = ca.SX.sym("P", N * N)
    gyro = ca.SX.sym("gyro", 3)
    dt = ca.SX.sym("dt")
    omega_hat = gyro - b
    q_new = quat.integrate(q, omega_hat, dt)
    F, G = jacobians_FG(omega_hat, dt)
    # σ_g²/dt with dt floored at DT_Q_MIN: a vanishing (even denormal) dt gives a vanishing
    # G Q Gᵀ = ¼ σ_g² dt² / max(dt, DT_Q_MIN) J Jᵀ instead of inf * 0 = NaN.
    q_g = p["gyro_noise"] ** 2 / ca.fmax(dt, DT_Q_MIN)
    Q = ca.diag(ca.vertcat(*([q_g] * 3 + [p["gyro_bias_rw"] ** 2 * dt] * 3)))
    P_new = kalman.predict_covariance(sym_lower(Pv), F, G, Q, symmetrize=False)   # mirrored below
    return emit.function(name, {"q": q, "b": b, "P": Pv, "gyro": gyro, "dt": dt},
                         {"q_out": q_new, "P_out": flat_mirrored(P_new)})


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
    r = [p["accel_angle_noise"] ** 2] * 2 + [r_head ** 2]
    Hm, zm, R = kalman.mask_rows(H, z, r, [mask[0], mask[0], mask[1]])
    # steps 5-7: Cholesky gain, Joseph form (mirrored below), X = K Z
    X, P_new, min_pivot = kalman.update(sym_lower(Pv), Hm, zm, R, S_PIVOT_MIN, symmetrize=False)
    q_new = quat.qnormalize(quat.qmul(q, quat.vec(1, X[0], X[1], X[2])))         # step 8
    b_new = b + X[3:6]
    # Euler angles are singular at pitch ±90°: there H has 1/cos(pitch) and the asin's
    # derivative is infinite. Report a negative pivot so the step skips the correction.
    sin_pitch = 2 * (q[0] * q[2] - q[1] * q[3])
    usable = ca.if_else(1 - sin_pitch * sin_pitch > COS2_PITCH_MIN, min_pivot, -1.0)
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


def initial_P(p: dict) -> list:
    d = [(0.5 * p["p0_att"]) ** 2] * 3 + [p["p0_bias"] ** 2] * 3
    return [d[i] if i == j else 0.0 for j in range(N) for i in range(N)]


class Model(FilterModel):
    def __init__(self, params: dict):
        p = params
        uses = ["accel"]
        if p["heading_source"] == "mag":
            uses.append("mag")
        if p["heading_source"] == "gps_course" or p["motion_comp"] != "none":
            uses.append("gps")
        super().__init__(params, sensors=tuple(uses), extra_status=list(EXTRA_STATUS))

    def state_fields(self) -> list[StateField]:
        return [
            StateField("q", 4, "attitude quaternion body->NED [w x y z]", [1.0, 0.0, 0.0, 0.0]),
            StateField("gyro_bias", 3, "gyro bias estimate, rad/s", 0.0),
            StateField("P", N * N, "error-state covariance [dq, db] (6x6, symmetric)", initial_P(self.params)),
            StateField("v_gps", 3, "last valid GPS velocity NED, m/s", 0.0),
            StateField("v_age", 1, "age of v_gps, s (stops counting at 1e3)", AGE_MAX),
            StateField("a_gps", 3, "NED acceleration from the last two GPS velocities, m/s^2 (motion_comp = gps_accel)", 0.0),
            StateField("a_ok", 1, "1 when a_gps comes from two samples at most gps_vel_timeout apart", 0, "uint32"),
            StateField("initialised", 1, "1 once the attitude has been initialised", 0 if self.params["init_from_sensors"] else 1, "uint32"),
        ]

    def kernels(self) -> list[KernelSpec]:
        p = self.params
        return [
            KernelSpec("predict", predict_function(p), "time update (patent steps 1-2)"),
            KernelSpec("update", update_function(p), "measurement update with row mask (steps 3-8)"),
            KernelSpec("init_attitude", init_function(p), "first attitude from tilt and heading"),
        ]

    def step_paths(self) -> dict[str, list[str]]:
        return {"gyro only": ["predict"], "with corrections": ["predict", "update"]}

    def template_context(self) -> dict:
        p = self.params
        return {"n": N, "heading_source": p["heading_source"], "motion_comp": p["motion_comp"],
                "s_pivot_min": S_PIVOT_MIN, "age_max": AGE_MAX, "g0": G0, "gps_dt_min": GPS_DT_MIN}
