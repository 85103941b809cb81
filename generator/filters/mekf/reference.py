"""Independent NumPy reference of the MEKF (patent CN102692225B, its nine steps).

Written from the patent's equations and SPEC.md, not from the CasADi model: the Jacobians
here are derived by hand (below), the gain uses NumPy's general solver, and the rows that
are not measured are simply left out (the C uses one masked update kernel instead).

Error state X = [δq (3), δb (3)]:  q = normalise(q̂ ⊗ [1, δq]),  b = b̂ + δb  (body-frame,
right-multiplied error; δq ≈ half the small rotation angle).

Step 1 (time update):  ω̂ = ω − b̂,  u = ω̂ dt,  a = exp(½ u),  q̂ ← normalise(q̂ ⊗ a).
Step 2:  P⁻ = F P Fᵀ + G Q Gᵀ with the Jacobians of the discrete error propagation

    [1, δq'] ∝ a* ⊗ [1, δq] ⊗ exp(½ (u − (δb + n_g) dt)),   δb' = δb + n_b

  by hand at X = 0:  ∂δq'/∂δq = R(a)ᵀ  (a* ⊗ v ⊗ a rotates v by a⁻¹),
  ∂δq'/∂δb = ∂δq'/∂n_g = −½ dt J_r(u)  (exp(u + du) = exp(u) exp(J_r(u) du), J_r the right
  Jacobian of SO(3)),  ∂δb'/∂δb = ∂δb'/∂n_b = I.
  Q = diag(σ_g²/max(dt, 1e-9 s) · I, σ_bw² dt · I)  (rate noise over the step, bias
  random-walk increment; the floor keeps a vanishing dt from giving inf * 0).
Step 3:  φ₂ = atan2(−f_y, −f_z),  θ₂ = atan2(f_x, √(f_y² + f_z²)),  ψ₂ = atan2(v_E, v_N)
  (or the tilt-compensated magnetic heading computed with the predicted roll and pitch).
Step 4:  Z = wrap([φ₂, θ₂, ψ₂] − euler(q̂)).
Step 5:  K = P Hᵀ (H P Hᵀ + R)⁻¹,  H = ∂ euler(q̂ ⊗ [1, δq]) / ∂X at X = 0 = [2 W(φ̂, θ̂), 0]
  where W maps body rates to Euler-angle rates (right perturbation = body-frame rotation
  of angle 2 δq):  W = [[1, sφ tθ, cφ tθ], [0, cφ, −sφ], [0, sφ/cθ, cφ/cθ]].
Step 6:  P⁺ = (I − KH) P (I − KH)ᵀ + K R Kᵀ, then P ← (P + Pᵀ)/2, evaluated expanded as
  P − K(HP) − (HP)ᵀKᵀ + K S Kᵀ (the same matrix for any K). Near pitch ±90° H ∝ 1/cos θ and
  |KH| reaches hundreds: the textbook product then cancels terms |KH|²|P| large down to
  eigenvalues ~1e-8 |P|, which float cannot (the fuzzer found P indefinite that way).
Step 7:  X = K Z.
Step 8:  q̂ ← normalise(q̂ ⊗ [1, δq]),  b̂ ← b̂ + δb,  X ← 0.
Step 9:  [φ θ ψ] = euler(q̂).
"""
from __future__ import annotations

import numpy as np

from generator.constants import G0
from generator import input_checks
from generator import status as st
from generator.npquat import euler_from_q, q_from_euler, qexp, qmul, rotmat, wrap

# Filter-specific status bits (informational; the step ran).
COURSE_SLOW = st.FILTER_BASE          # GPS sample present but ground speed < gps_min_speed: yaw row dropped
ACCEL_GATED = st.FILTER_BASE << 1     # | |f| - g | > accel_gate: roll/pitch rows dropped
UPDATE_SKIPPED = st.FILTER_BASE << 2  # S not positive definite, or pitch at ±90°: no correction

COS2_PITCH_MIN = 1e-4   # no correction while cos²(pitch) <= this (pitch within 0.57° of ±90°)
AGE_MAX = 1e3   # the GPS-velocity age stops counting here (s)
GPS_DT_MIN = 1e-3   # two GPS samples closer than this (s) give no new acceleration
DT_Q_MIN = 1e-9     # s: floor of dt in the gyro-noise variance σ_g²/dt

# The innovation covariance must have Cholesky pivots above this to be used.
S_PIVOT_MIN = 1e-12


def skew(v):
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def right_jacobian(u):
    """J_r(u) of SO(3): Exp(u + du) ≈ Exp(u) Exp(J_r(u) du)."""
    th2 = float(u @ u)
    S = skew(u)
    if th2 < 1e-8:
        # series: I - S/2 + S²/6 (next terms O(θ³), below round-off at θ < 1e-4)
        return np.eye(3) - 0.5 * S + S @ S / 6.0
    th = np.sqrt(th2)
    return np.eye(3) - (1 - np.cos(th)) / th2 * S + (th - np.sin(th)) / (th2 * th) * (S @ S)


def euler_rate_matrix(roll, pitch):
    """W with [φ̇, θ̇, ψ̇] = W ω_body (Z-Y-X Euler angles)."""
    sr, cr = np.sin(roll), np.cos(roll)
    tp, cp = np.tan(pitch), np.cos(pitch)
    return np.array([[1.0, sr * tp, cr * tp], [0.0, cr, -sr], [0.0, sr / cp, cr / cp]])


def tilt(f):
    return np.arctan2(-f[1], -f[2]), np.arctan2(f[0], np.hypot(f[1], f[2]))


def mag_heading(m, roll, pitch, declination):
    sr, cr, sp, cp = np.sin(roll), np.cos(roll), np.sin(pitch), np.cos(pitch)
    xh = m[0] * cp + m[1] * sp * sr + m[2] * sp * cr
    yh = m[1] * cr - m[2] * sr
    return float(wrap(np.arctan2(-yh, xh) + declination))


def propagation_jacobians(u, dt):
    """(F, G) of the discrete error-state propagation over one step (hand-derived, see top)."""
    a = qexp(0.5 * np.asarray(u, dtype=float))
    Jr = right_jacobian(np.asarray(u, dtype=float))
    F = np.eye(6)
    F[:3, :3] = rotmat(a).T
    F[:3, 3:] = -0.5 * dt * Jr
    G = np.zeros((6, 6))
    G[:3, :3] = -0.5 * dt * Jr
    G[3:, 3:] = np.eye(3)
    return F, G


def measurement_jacobian(q):
    """H (3x6) of euler(q ⊗ [1, δq]) w.r.t. X at X = 0."""
    roll, pitch, _ = euler_from_q(q)
    H = np.zeros((3, 6))
    H[:, :3] = 2.0 * euler_rate_matrix(roll, pitch)
    return H


class Reference:
    def __init__(self, params: dict):
        p = dict(params)
        self.p = p
        self.dt_max = float(p["dt_max"])
        self.accel_min_norm = float(p["accel_min_norm"])
        self.mag_min_norm = float(p["mag_min_norm"])
        self.heading_source = str(p["heading_source"])
        if self.heading_source not in ("gps_course", "mag"):
            raise ValueError(f"heading_source must be 'gps_course' or 'mag', got {self.heading_source!r}")
        self.gps_min_speed = float(p["gps_min_speed"])
        self.declination = float(p["declination"])
        self.gyro_noise = float(p["gyro_noise"])
        self.gyro_bias_rw = float(p["gyro_bias_rw"])
        self.accel_angle_noise = float(p["accel_angle_noise"])
        self.course_noise = float(p["course_noise"])
        self.mag_heading_noise = float(p["mag_heading_noise"])
        self.accel_gate = float(p["accel_gate"])
        self.init_from_sensors = bool(p["init_from_sensors"])
        self.motion_comp = str(p["motion_comp"])
        self.gps_vel_timeout = float(p["gps_vel_timeout"])
        self.gps_vel_max = float(p["gps_vel_max"])
        self.p0_att = float(p["p0_att"])
        self.p0_bias = float(p["p0_bias"])
        self.gyro_max = float(p["gyro_max"])
        self.accel_max = float(p["accel_max"])
        self.mag_max = float(p["mag_max"])
        # the step reads GPS only when something uses it (heading or compensation)
        self.uses_gps = self.heading_source == "gps_course" or self.motion_comp != "none"

        self.q = np.array([1.0, 0.0, 0.0, 0.0])
        self.gyro_bias = np.zeros(3)
        self.P = np.diag([(0.5 * self.p0_att) ** 2] * 3 + [self.p0_bias ** 2] * 3)
        self.initialised = not self.init_from_sensors
        self.v_gps = np.zeros(3)          # last valid GPS velocity (NED) for the motion compensation
        self.v_age = AGE_MAX              # its age, s (AGE_MAX: none yet)
        self.a_gps = np.zeros(3)          # NED acceleration from the last two GPS velocities
        self.a_ok = False                 # ... when they were at most gps_vel_timeout apart

    # ------------------------------------------------------------------------------
    def step(self, gyro, accel, mag, gps_vel, valid: int, dt: float) -> int:
        valid = int(valid)
        dt = float(dt)
        sensors = ("accel",) + (("mag",) if self.heading_source == "mag" else ()) + (("gps",) if self.uses_gps else ())
        c = input_checks.check(self.p, sensors, gyro, accel, mag, gps_vel, valid, dt)
        if c.refused:
            return c.refused
        status, gyro = c.status, c.gyro

        # --- which corrections are usable (same order of checks as the generated C) ----
        use_tilt = False
        if c.use_accel:
            f = np.asarray(accel, dtype=float)
            if self.accel_gate > 0.0 and abs(np.sqrt(f @ f) - G0) > self.accel_gate:
                status |= ACCEL_GATED
            else:
                use_tilt = True
        course_ok = False
        gps_fresh = c.use_gps
        if gps_fresh:
            v = np.asarray(gps_vel, dtype=float)
            speed2 = v[0] * v[0] + v[1] * v[1]
            if self.heading_source == "gps_course":
                if speed2 >= self.gps_min_speed ** 2 and speed2 > 0.0:
                    course_ok = True
                else:
                    status |= COURSE_SLOW
        mag_ok = c.use_mag
        if mag_ok:
            m = np.asarray(mag, dtype=float)

        # --- last GPS velocity and GPS acceleration, for the motion compensation ----------
        v_age = self.v_age                # (age saturates at AGE_MAX)
        v_gps = self.v_gps
        a_gps, a_ok = self.a_gps, self.a_ok
        if gps_fresh:
            if self.motion_comp == "gps_accel":
                tau = v_age + dt          # time since the previous GPS sample
                if tau > self.gps_vel_timeout:
                    a_ok = False
                elif tau >= GPS_DT_MIN:   # (closer samples leave the acceleration as it was)
                    a_gps, a_ok = (v - v_gps) / tau, True
            v_gps = v.copy()
            v_age = 0.0
        elif v_age < AGE_MAX:
            v_age = v_age + dt

        # --- initialisation from the first usable accelerometer sample ------------------
        self.a_gps, self.a_ok = a_gps, a_ok
        if not self.initialised:
            self.v_gps, self.v_age = v_gps, v_age
            if not use_tilt:
                return status          # nothing to start from yet: state unchanged
            roll, pitch = tilt(f)
            if course_ok:
                yaw = np.arctan2(v[1], v[0])
            elif mag_ok:
                yaw = mag_heading(m, roll, pitch, self.declination)
            else:
                yaw = 0.0
            self.q = q_from_euler(roll, pitch, yaw)
            self.initialised = True
            return status

        # --- steps 1-2: time update --------------------------------------------------
        u = (gyro - self.gyro_bias) * dt
        q = qmul(self.q, qexp(0.5 * u))
        q = q / np.linalg.norm(q)
        F, G = propagation_jacobians(u, dt)
        Q = np.diag([self.gyro_noise ** 2 / max(dt, DT_Q_MIN)] * 3 + [self.gyro_bias_rw ** 2 * dt] * 3)
        P = F @ self.P @ F.T + G @ Q @ G.T
        P = 0.5 * (P + P.T)

        # --- steps 3-4: measurements and innovations -----------------------------------
        est = euler_from_q(q)
        rows, z, r = [], [], []
        if use_tilt:
            if self.motion_comp == "centripetal" and v_age <= self.gps_vel_timeout:
                # f = dv_b/dt + ω × v_b − R(q)ᵀ g_n: remove the turn term ω × v_b (v_b from the
                # GPS velocity and the predicted attitude); dv_b/dt is left in (not observable
                # from the rate gyro) and covered by accel_angle_noise.
                f = f - np.cross(gyro - self.gyro_bias, rotmat(q).T @ v_gps)
            elif self.motion_comp == "gps_accel" and a_ok and v_age <= self.gps_vel_timeout:
                # f = R(q)ᵀ (a_n − g_n): remove the GPS-differenced NED acceleration
                f = f - rotmat(q).T @ a_gps
            roll_a, pitch_a = tilt(f)
            rows += [0, 1]
            z += [wrap(roll_a - est[0]), wrap(pitch_a - est[1])]
            r += [self.accel_angle_noise ** 2] * 2
        if course_ok:
            rows.append(2)
            z.append(wrap(np.arctan2(v[1], v[0]) - est[2]))
            r.append(self.course_noise ** 2)
        elif mag_ok:
            rows.append(2)
            z.append(wrap(mag_heading(m, est[0], est[1], self.declination) - est[2]))
            r.append(self.mag_heading_noise ** 2)

        if rows:
            # --- steps 5-8: gain, Joseph update, error state, reset ------------------------
            sin_pitch = 2 * (q[0] * q[2] - q[1] * q[3])
            if 1 - sin_pitch * sin_pitch <= COS2_PITCH_MIN:
                # Euler angles singular at pitch ±90° (H has 1/cos(pitch)): no correction
                self.q, self.P = q, P
                self.v_gps, self.v_age = v_gps, v_age
                return status | UPDATE_SKIPPED
            H = measurement_jacobian(q)[rows]
            R = np.diag(r)
            S = H @ P @ H.T + R
            S = 0.5 * (S + S.T)
            try:                                     # same test as the C: Cholesky pivots > S_PIVOT_MIN
                pivots_ok = np.min(np.diag(np.linalg.cholesky(S)) ** 2) > S_PIVOT_MIN
            except np.linalg.LinAlgError:
                pivots_ok = False
            if not pivots_ok:
                status |= UPDATE_SKIPPED
            else:
                HP = H @ P
                K = np.linalg.solve(S, HP).T         # P Hᵀ S⁻¹ (S, P symmetric)
                # Joseph form (I − KH) P (I − KH)ᵀ + K R Kᵀ, expanded (see the top)
                KHP = K @ HP
                P = P - KHP - KHP.T + K @ S @ K.T
                P = 0.5 * (P + P.T)
                X = K @ np.asarray(z, dtype=float)
                q = qmul(q, np.concatenate([[1.0], X[:3]]))
                q = q / np.linalg.norm(q)
                self.gyro_bias = self.gyro_bias + X[3:]
        self.q = q
        self.P = P
        self.v_gps, self.v_age = v_gps, v_age
        return status

    def euler(self) -> np.ndarray:
        return euler_from_q(self.q)


def run(params: dict, log):
    """Run the reference over a SensorLog; returns (q (N,4), status (N,), bias (N,3))."""
    ref = Reference(params)
    n = len(log)
    qs = np.empty((n, 4))
    bs = np.empty((n, 3))
    sts = np.empty(n, dtype=np.int64)
    for k in range(n):
        sts[k] = ref.step(log.gyro[k], log.accel[k], log.mag[k], log.gps_vel[k], int(log.valid[k]), log.dt[k])
        qs[k] = ref.q
        bs[k] = ref.gyro_bias
    return qs, sts, bs
