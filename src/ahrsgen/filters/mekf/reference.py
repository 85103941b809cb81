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

from ahrsgen.constants import G0
from ahrsgen.codegen import input_checks
from ahrsgen import status as st
from ahrsgen.reference_aiding import GyroClip, HardIron, warm_lowpass_gain
from ahrsgen.npquat import euler_from_q, q_from_euler, qexp, qmul, rotmat, skew, wrap

# Filter-specific status bits (informational; the step ran).
COURSE_SLOW = st.FILTER_BASE          # GPS sample present but ground speed < gps_min_speed: yaw row dropped
ACCEL_GATED = st.FILTER_BASE << 1     # | |f| - g | > accel_gate: roll/pitch rows dropped
UPDATE_SKIPPED = st.FILTER_BASE << 2  # S not positive definite, or pitch at ±90°: no correction
# measurement = "vectors" only:
HEADING_UNAIDED = st.FILTER_BASE << 3  # no heading correction for more than HEAD_AGE_MAX s
MAG_DISTURBED = st.FILTER_BASE << 4    # magnetometer rejected: field norm or dip off its reference, or heading gate
AT_REST = st.FILTER_BASE << 5          # rest detected: the gyro bias is measured directly
HARD_IRON_SWITCHED = st.FILTER_BASE << 6  # the hard iron and reference were replaced by the candidate
GYRO_RECOVERY = st.FILTER_BASE << 7    # a gyro sample at its range, or clip_recovery_time after one
HEAD_AGE_MAX = 1.0      # s without a heading correction before HEADING_UNAIDED

COS2_PITCH_MIN = 1e-4   # no correction while cos²(pitch) <= this (pitch within 0.57° of ±90°)
AGE_MAX = 1e3   # the GPS-velocity age stops counting here (s)
MAG_INTERVAL_MAX = 0.1  # s: a magnetometer sample stands for at most this long
GPS_DT_MIN = 1e-3   # two GPS samples closer than this (s) give no new acceleration
DT_Q_MIN = 1e-9     # s: floor of dt in the gyro-noise variance σ_g²/dt

# The innovation covariance must have Cholesky pivots above this to be used.
S_PIVOT_MIN = 1e-12


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
        if str(p["measurement"]) != "vectors":
            # the Euler-angle design has one heading source and no low-pass: 'auto' means the
            # GPS course there (the patent), 'gps_lowpass' means 'gps_accel'
            if p["heading_source"] == "auto":
                p["heading_source"] = "gps_course"
            if p["motion_comp"] == "gps_lowpass":
                p["motion_comp"] = "gps_accel"
        self.p = p
        self.dt_max = float(p["dt_max"])
        self.accel_min_norm = float(p["accel_min_norm"])
        self.mag_min_norm = float(p["mag_min_norm"])
        self.heading_source = str(p["heading_source"])
        if self.heading_source not in ("auto", "gps_course", "mag"):
            raise ValueError(f"heading_source must be 'auto', 'gps_course' or 'mag', got {self.heading_source!r}")
        self.gps_min_speed = float(p["gps_min_speed"])
        self.declination = float(p["declination"])
        self.gyro_noise = float(p["gyro_noise"])
        self.gyro_bias_rw = float(p["gyro_bias_rw"])
        self.accel_angle_noise = float(p["accel_angle_noise"])
        self.accel_tilt_noise = float(p["accel_tilt_noise"])
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
        self.uses_gps = self.heading_source != "mag" or self.motion_comp != "none"
        self.uses_mag = self.heading_source != "gps_course"
        self.uses_course = self.heading_source != "mag"

        self.q = np.array([1.0, 0.0, 0.0, 0.0])
        self.gyro_bias = np.zeros(3)
        self.P = np.diag([(0.5 * self.p0_att) ** 2] * 3 + [self.p0_bias ** 2] * 3)
        self.initialised = not self.init_from_sensors
        self.v_gps = np.zeros(3)          # last valid GPS velocity (NED) for the motion compensation
        self.v_age = AGE_MAX              # its age, s (AGE_MAX: none yet)
        self.a_gps = np.zeros(3)          # NED acceleration from the last two GPS velocities
        self.a_ok = False                 # ... when they were at most gps_vel_timeout apart

        self.vectors = str(p["measurement"]) == "vectors"
        if self.vectors:
            for k in ("accel_lpf_tau", "accel_adapt_cap", "rest_gyro_th", "rest_accel_th", "rest_min_time",
                      "rest_tau", "mag_norm_th", "mag_dip_th", "mag_learn_time", "mag_reject_max",
                      "mag_ref_tau", "mag_new_time", "course_max_sideslip", "gyro_full_scale",
                      "clip_recovery_time", "gyro_rate_noise", "mag_heading_density", "accel_noise_density",
                      "mag_dev_gain", "gyro_step_noise", "accel_bias_gain", "accel_adapt_sigmas",
                      "mag_head_sigmas", "mag_head_tau"):
                setattr(self, k, float(p[k]))
            self.accel_lpf_warm = bool(p["accel_lpf_warm"])
            self.clip = GyroClip(self.gyro_full_scale, float(p["gyro_plateau_rate"]), self.clip_recovery_time)
            self.a_lp = np.zeros(3)       # earth-frame (NED) low-passed specific force
            self.lp_time = 0.0            # time a_lp has averaged, s (its warm start; at most accel_lpf_tau)
            self.v_lp = np.zeros(3)       # the GPS velocity through the same low-pass (gps_lowpass)
            self.vlp_ok = False           # v_lp follows a fresh GPS velocity
            self.v_ins = np.zeros(3)      # GPS velocity carried between samples by the accelerometer
            self.gyro_lp = np.zeros(3)    # rest detection: low-passed gyro and accelerometer (body)
            self.acc_lp = np.zeros(3)
            self.rest_time = 0.0          # time the sensors have been steady, s
            self.mag_ref = np.zeros(2)    # reference field [norm, dip (rad)]
            self.mag_ref_time = 0.0       # time spent learning the reference, s
            self.mag_rej_time = 0.0       # time the magnetometer has been rejected in a row, s
            self.mag_cand = np.zeros(2)   # candidate new reference [norm, dip] while rejected
            self.mag_cand_time = 0.0      # time the candidate has been steady, s
            self.head_age = AGE_MAX       # time since the last heading correction, s
            self.mag_age = 0.0            # time since the last usable magnetometer sample, s
            self.head_lp = 0.0            # heading gate: the magnetic heading innovation low-passed, rad
            self.head_free = False        # ... given up: a lasting inconsistent heading is accepted
            # hard iron (body axes, the field's units) and the candidate field model fitted
            # while the sensor turns, in units of the reference norm: [β (3), n, v]
            self.mag_bias_on = bool(p["mag_bias"])
            for k in ("mag_bias_rw", "mag_bias_noise", "mag_bias_min_rate", "mag_bias_settle", "mag_bias_th",
                      "mag_bias_max", "mag_bias_jump"):
                setattr(self, k, float(p[k]))
            self.mag_bias = np.zeros(3)
            self.hard_iron = HardIron(rw=self.mag_bias_rw, noise=self.mag_bias_noise, bias_max=self.mag_bias_max,
                                      settle=self.mag_bias_settle, th=self.mag_bias_th, jump=self.mag_bias_jump,
                                      refine=self.mag_norm_th)

    @property
    def mag_suspect(self) -> bool:
        return self.mag_bias_on and self.hard_iron.suspect

    # ------------------------------------------------------------------------------
    def step(self, gyro, accel, mag, gps_vel, valid: int, dt: float) -> int:
        if self.vectors:
            return self.step_vectors(gyro, accel, mag, gps_vel, valid, dt)
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
        q, P = self._time_update(gyro, dt)

        # --- steps 3-4: measurements and innovations -----------------------------------
        est = euler_from_q(q)
        rows, z, r = [], [], []
        if use_tilt:
            if self.motion_comp == "centripetal" and v_age <= self.gps_vel_timeout:
                # f = dv_b/dt + ω × v_b − R(q)ᵀ g_n: remove the turn term ω × v_b (v_b from the
                # GPS velocity and the predicted attitude); dv_b/dt is left in (not observable
                # from the rate gyro) and covered by accel_tilt_noise.
                f = f - np.cross(gyro - self.gyro_bias, rotmat(q).T @ v_gps)
            elif self.motion_comp == "gps_accel" and a_ok and v_age <= self.gps_vel_timeout:
                # f = R(q)ᵀ (a_n − g_n): remove the GPS-differenced NED acceleration
                f = f - rotmat(q).T @ a_gps
            roll_a, pitch_a = tilt(f)
            rows += [0, 1]
            z += [wrap(roll_a - est[0]), wrap(pitch_a - est[1])]
            r += [self.accel_tilt_noise ** 2] * 2
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

    # ------------------------------------------------------------------------------
    # measurement = "vectors": the product design (see the module docstring's second part)
    def _time_update(self, gyro, dt):
        """Steps 1-2: the propagated attitude and covariance (state not yet written)."""
        u = (gyro - self.gyro_bias) * dt
        q = qmul(self.q, qexp(0.5 * u))
        q = q / np.linalg.norm(q)
        F, G = propagation_jacobians(u, dt)
        if self.vectors:
            # the product design's attitude error is in the earth frame, δ = R(q̂) δq (q = [1, δ] ⊗ q̂):
            # δ' = R(q̂') δq' = R(q̂') (R(a)ᵀ δq + F_b δb) = δ + R(q̂') F_b δb
            B = rotmat(q) @ F[:3, 3:]
            F[:3, :3], F[:3, 3:], G[:3, :3] = np.eye(3), B, B
        # the product design: each axis's density grows with its (raw) rate, gyro_rate_noise
        k = self.gyro_rate_noise if self.vectors else 0.0
        q_g = (self.gyro_noise ** 2 + (k * np.asarray(gyro, dtype=float)) ** 2) / max(dt, DT_Q_MIN)
        if self.vectors:
            # a step's full-angle error c (|ω| dt)², half-angle state: ¼ dt² q = ¼ c² |ω|⁴ dt⁴
            w = np.asarray(gyro, dtype=float)
            q_g = q_g + (self.gyro_step_noise * (w @ w) * dt) ** 2
        Q = np.diag(list(q_g) + [self.gyro_bias_rw ** 2 * dt] * 3)
        P = F @ self.P @ F.T + G @ Q @ G.T
        P = 0.5 * (P + P.T)
        return q, P

    def _gps_bookkeeping(self, c, gps_vel, dt):
        """Last GPS velocity, its age and the GPS-differenced acceleration (as step())."""
        v_gps, v_age, a_gps, a_ok = self.v_gps, self.v_age, self.a_gps, self.a_ok
        if c.use_gps:
            v = np.asarray(gps_vel, dtype=float)
            if self.motion_comp == "gps_accel":
                tau = v_age + dt
                if tau > self.gps_vel_timeout:
                    a_ok = False
                elif tau >= GPS_DT_MIN:
                    a_gps, a_ok = (v - v_gps) / tau, True
            v_gps = v.copy()
            v_age = 0.0
        elif v_age < AGE_MAX:
            v_age = v_age + dt
        self.v_gps, self.v_age, self.a_gps, self.a_ok = v_gps, v_age, a_gps, a_ok

    def step_vectors(self, gyro, accel, mag, gps_vel, valid: int, dt: float) -> int:
        valid = int(valid)
        dt = float(dt)
        sensors = ("accel",) + (("mag",) if self.uses_mag else ()) + (("gps",) if self.uses_gps else ())
        c = input_checks.check(self.p, sensors, gyro, accel, mag, gps_vel, valid, dt)
        if c.refused:
            return c.refused
        status, gyro = c.status, c.gyro
        f = np.asarray(accel, dtype=float)
        use_tilt = False
        if c.use_accel:
            if self.accel_gate > 0.0 and abs(np.sqrt(f @ f) - G0) > self.accel_gate:
                status |= ACCEL_GATED
            else:
                use_tilt = True
        # heading sources: a GPS course sample this step; GPS course mode (auto) while the
        # last GPS velocity is fresh and fast enough; the magnetometer otherwise
        course_sample = False
        if c.use_gps and self.uses_course:
            v = np.asarray(gps_vel, dtype=float)
            speed2 = v[0] * v[0] + v[1] * v[1]
            if speed2 >= self.gps_min_speed ** 2 and speed2 > 0.0:
                course_sample = True
            else:
                status |= COURSE_SLOW
        self._gps_bookkeeping(c, gps_vel, dt)
        vh2 = self.v_gps[0] ** 2 + self.v_gps[1] ** 2
        # moving over ground by GPS: no rest, and the course may be the heading
        moving = (self.uses_gps and self.v_age <= self.gps_vel_timeout
                  and vh2 >= self.gps_min_speed ** 2 and vh2 > 0.0)
        m = np.asarray(mag, dtype=float) - self.mag_bias    # the hard iron removed
        # the magnetometer's own sample interval: its heading variance is a density over it
        mag_dt = dt
        if self.uses_mag:
            mag_dt = min(self.mag_age + dt, MAG_INTERVAL_MAX)
            self.mag_age = 0.0 if c.use_mag else mag_dt

        if not self.initialised:
            if not use_tilt:
                return status
            roll, pitch = tilt(f)
            yaw = 0.0
            if course_sample:
                yaw = np.arctan2(gps_vel[1], gps_vel[0])
                self.head_age = 0.0
            elif c.use_mag:
                yaw = mag_heading(m, roll, pitch, self.declination)
                self.head_age = 0.0
            self.q = q_from_euler(roll, pitch, yaw)
            self.a_lp = rotmat(self.q) @ f
            self.lp_time = dt             # a_lp is this sample: the warm start averages on from it
            self.gyro_lp = gyro.copy()
            self.acc_lp = f.copy()
            self.initialised = True
            return status

        # --- time update (as step()) ----------------------------------------------------
        q, P = self._time_update(gyro, dt)
        Rq = rotmat(q)
        # --- gyro over-range: a sample at the range is integrated as it is, and the rotation
        # it missed (unknown, up to one range's worth per step: half-angle (range dt / 2)^2 in
        # the error state) widens the attitude covariance; for clip_recovery_time after the
        # last clipped sample the corrections take the sensors as they come (no low-pass, no
        # motion weighting, no field check) so that the covariance, not the low-pass, sets
        # how fast the attitude comes back
        clipped, recovering = self.clip.step(gyro, dt)
        if clipped:
            P = P + np.diag([(0.5 * self.gyro_full_scale * dt) ** 2] * 3 + [0.0] * 3)
        if recovering:
            status |= GYRO_RECOVERY

        # --- heading source: the GPS course while moving nose first (the velocity within
        # course_max_sideslip of the body x axis: a fixed-wing, not a multirotor drifting
        # sideways) or while nothing else corrects the heading; the magnetometer otherwise
        if self.heading_source == "gps_course":
            course_mode = True
        elif self.heading_source == "mag":
            course_mode = False
        else:
            vb = Rq.T @ self.v_gps
            nose_first = vb[0] > 0.0 and vb[1] * vb[1] <= np.tan(self.course_max_sideslip) ** 2 * vb[0] * vb[0]
            course_mode = moving and (nose_first or self.head_age > HEAD_AGE_MAX)
        mag_ok = c.use_mag and not course_mode

        # --- rest detection: gyro (and accelerometer) steady near their low-pass -------
        ar = dt / (self.rest_tau + dt)
        self.gyro_lp = self.gyro_lp + ar * (gyro - self.gyro_lp)
        dg = gyro - self.gyro_lp
        th_g2 = self.rest_gyro_th ** 2
        still = dg @ dg < th_g2 and self.gyro_lp @ self.gyro_lp < th_g2
        if c.use_accel:
            self.acc_lp = self.acc_lp + ar * (f - self.acc_lp)
            da = f - self.acc_lp
            still = still and da @ da < self.rest_accel_th ** 2
        still = still and not moving
        self.rest_time = min(self.rest_time + dt, AGE_MAX) if still else 0.0
        # timers against a threshold: half a step of margin, so that a sum of steps landing on
        # the threshold decides the same in float and double (rounding moves it by ~1e-7 s)
        at_rest = self.rest_time + 0.5 * dt >= self.rest_min_time
        if at_rest:
            status |= AT_REST

        # --- earth-frame low-pass of the (motion-compensated) specific force -----------
        # gps_lowpass: the GPS velocity goes through the same low-pass; (v − v_lp)/τ (v_lp
        # updated) is then exactly that low-pass of the velocity's differences, the low-passed
        # kinematic acceleration (the low-pass of a derivative is the derivative of the low-pass), removed from the low-passed specific force.
        fresh = self.v_age <= self.gps_vel_timeout
        if self.motion_comp == "gps_lowpass" and not fresh:
            self.vlp_ok = False
        up = self.a_lp
        if use_tilt:
            fc = f
            if self.motion_comp == "centripetal" and fresh:
                fc = f - np.cross(gyro - self.gyro_bias, Rq.T @ self.v_gps)
            elif self.motion_comp == "gps_accel" and self.a_ok and fresh:
                fc = f - Rq.T @ self.a_gps
            # warm start (VQF's): until it has averaged accel_lpf_tau of samples the low-pass is
            # their running mean, so the first sample (vibration, motion) weighs 1/n, not
            # e^(-t/tau); recovering: the sample itself (the warm start is not begun again: measured
            # worse on gyro_clip, 0.31 against 0.26 deg). The velocity's low-pass keeps its gain
            # from the start
            aa = 1.0 if recovering else dt / (self.accel_lpf_tau + dt)
            warm, lp_next = warm_lowpass_gain(self.lp_time, self.accel_lpf_tau, dt)
            a_gain = 1.0 if recovering else (warm if self.accel_lpf_warm else aa)
            self.lp_time = self.lp_time if recovering else lp_next
            self.a_lp = self.a_lp + a_gain * (Rq @ fc - self.a_lp)
            up = self.a_lp
            if self.motion_comp == "gps_lowpass":
                if fresh and not self.vlp_ok:          # (re)start on the present velocity
                    self.v_lp, self.v_ins, self.vlp_ok = self.v_gps.copy(), self.v_gps.copy(), True
                # velocity: the GPS sample when one arrived, else carried by the accelerometer
                # (a = R f + g) from the last one, so that it has no GPS-rate staircase
                if c.use_gps:
                    self.v_ins = self.v_gps.copy()
                else:
                    self.v_ins = self.v_ins + (Rq @ f + np.array([0.0, 0.0, G0])) * dt
                if fresh:
                    self.v_lp = self.v_lp + aa * (self.v_ins - self.v_lp)
                    up = self.a_lp - (self.v_ins - self.v_lp) / self.accel_lpf_tau
            if up @ up <= self.accel_min_norm ** 2:
                use_tilt = False

        # --- magnetometer: disturbance detection against a learned norm and dip --------
        mag_use = False
        onset = False                    # the field is rejected this step, accepted the step before
        if mag_ok:
            mn = Rq @ m
            cur = np.array([np.sqrt(m @ m), np.arctan2(mn[2], np.hypot(mn[0], mn[1]))])
            head_off = False
            if self.mag_head_sigmas > 0.0:
                # heading gate: the low-passed heading innovation against the heading's own
                # standard deviation (H P Hᵀ = 4 P_zz, θ = 2 δ) and what the low-pass leaves of the
                # white heading noise (density² / (2 τ)); gives up after min(mag_new_time,
                # mag_reject_max) rejected, until the innovation is consistent again
                z_m = wrap(self.declination - np.arctan2(mn[1], mn[0]))
                self.head_lp = wrap(self.head_lp + mag_dt / (self.mag_head_tau + mag_dt) * wrap(z_m - self.head_lp))
                var = 4.0 * P[2, 2] + self.mag_heading_density ** 2 / (2.0 * self.mag_head_tau)
                inconsistent = self.head_lp ** 2 > self.mag_head_sigmas ** 2 * var
                self.head_free = inconsistent and (
                    self.head_free or self.mag_rej_time + dt >= min(self.mag_new_time, self.mag_reject_max))
                head_off = (inconsistent and not self.head_free and self.mag_ref_time >= self.mag_learn_time
                            and not recovering)
            if self.mag_norm_th <= 0.0 or (recovering and self.mag_ref_time >= self.mag_learn_time):
                mag_use = True
            elif self.mag_ref_time < self.mag_learn_time:
                self.mag_ref = self.mag_ref + dt / (self.mag_ref_time + dt) * (cur - self.mag_ref)
                self.mag_ref_time += dt
                mag_use = True
            else:
                if not (self._off(cur, self.mag_ref) or head_off):
                    self.mag_rej_time = 0.0
                    self.mag_ref = self.mag_ref + dt / (self.mag_ref_tau + dt) * (cur - self.mag_ref)
                    mag_use = True
                else:
                    # a new field that stays steady for mag_new_time (a lasting change) becomes
                    # the reference; after mag_reject_max rejected in a row, the present one does
                    if self._off(cur, self.mag_cand):
                        self.mag_cand = cur
                        self.mag_cand_time = 0.0
                    else:
                        self.mag_cand_time += dt
                        self.mag_cand = self.mag_cand + dt / self.mag_cand_time * (cur - self.mag_cand)
                    onset = not self.mag_rej_time > 0.0
                    self.mag_rej_time += dt
                    # (not while the hard-iron candidate explains the field: it is the better model)
                    if ((self.mag_cand_time >= self.mag_new_time or self.mag_rej_time > self.mag_reject_max)
                            and not self.mag_suspect):
                        self.mag_ref = self.mag_cand
                        self.mag_rej_time = 0.0
                        self.mag_cand_time = 0.0
                        mag_use = True
                    else:
                        status |= MAG_DISTURBED
            if (self.mag_bias_on and self.mag_ref[0] > 0.0 and self.mag_ref_time >= self.mag_learn_time
                    and not recovering):
                w = gyro - self.gyro_bias
                if onset and not self.mag_suspect:
                    self.hard_iron.reopen()      # a new disturbance: the candidate starts afresh
                if w @ w >= self.mag_bias_min_rate ** 2:
                    new = self.hard_iron.step(Rq, np.asarray(mag, dtype=float), self.mag_bias, self.mag_ref[0],
                                              np.sin(self.mag_ref[1]), dt)
                    if new is not None:          # the candidate becomes the hard iron and the reference
                        self.mag_bias = new[0]
                        self.mag_ref = np.array([new[1], np.arcsin(new[2])])
                        self.mag_rej_time = 0.0
                        self.mag_cand_time = 0.0
                        status |= HARD_IRON_SWITCHED
                        mag_use = False          # the field check was made with the old hard iron
                if mag_use and self.mag_suspect:
                    mag_use = False
                    status |= MAG_DISTURBED

        # --- gravity direction (2 rows, earth frame) and, at rest, the gyro bias (3 rows) ---
        # The measured direction up/|up| against the estimate's u = [0, 0, -1], both in the earth
        # frame: the truth's R(Exp θ q)ᵀ u rotated by R(q) is Exp(θ)ᵀ u ≈ u + skew(u) θ (θ = 2 δ,
        # the earth-frame error), whose third row is 0 (u does not move when turned about
        # itself): rows 0 and 1 only. With r_g isotropic, the body-axis rows rotated by R(q)
        # (the same update).
        rows = ([0, 1] if use_tilt else []) + ([3, 4, 5] if at_rest else [])
        if rows:
            u_n = np.array([0.0, 0.0, -1.0])
            z_g = up / np.sqrt(up @ up) - u_n      # earth frame
            # the white-noise term grows while the gyro bias is uncertain: its mean variance
            # against p0_bias²
            bias_var = (P[3, 3] + P[4, 4] + P[5, 5]) / 3.0
            sig2 = self.accel_angle_noise ** 2 + self.accel_noise_density ** 2 / max(dt, DT_Q_MIN) * (
                1.0 + self.accel_bias_gain * bias_var / self.p0_bias ** 2)
            if self.uses_gps and not fresh:
                # no motion compensation: a turn at the last GPS ground speed bends the specific
                # force by ω_v |v_h| / g (ω_v the turn rate about the vertical)
                a_turn = (Rq[2, :] @ (gyro - self.gyro_bias)) * np.hypot(self.v_gps[0], self.v_gps[1]) / G0
                sig2 += a_turn ** 2
            r_g = sig2 if recovering else sig2 * min(1.0 + (z_g @ z_g) / (self.accel_adapt_sigmas ** 2 * sig2),
                                                     self.accel_adapt_cap)
            z = np.concatenate([z_g, gyro - self.gyro_bias])
            H = np.zeros((6, 6))
            H[:3, :3] = 2.0 * skew(u_n)            # d/dθ of Rᵀ(Exp θ) u = skew(u) θ, θ = 2 δ (earth frame)
            H[3:, 3:] = np.eye(3)
            r = np.array([r_g] * 3 + [self.gyro_noise ** 2 / max(dt, DT_Q_MIN)] * 3)
            q, P, ok = self._correct(q, P, H[rows], z[rows], r[rows], None)
            if not ok:
                status |= UPDATE_SKIPPED
            Rq = rotmat(q)

        # --- heading (1 row, vertical only, gain projected so it never tilts) ------------
        head = False
        if course_sample and course_mode:
            v = np.asarray(gps_vel, dtype=float)
            z_h = wrap(np.arctan2(v[1], v[0]) - np.arctan2(Rq[1, 0], Rq[0, 0]))
            r_h = self.course_noise ** 2
            head = True
        elif mag_use:
            mn = Rq @ m
            z_h = wrap(self.declination - np.arctan2(mn[1], mn[0]))
            r_h = self.mag_heading_density ** 2 / max(mag_dt, DT_Q_MIN)
            if not recovering:
                # graded trust: the sample's field (norm, dip seen from the predicted attitude)
                # against the reference at this point
                e_n = (cur[0] - self.mag_ref[0]) / self.mag_ref[0] if self.mag_ref[0] > 0.0 else 0.0
                r_h *= 1.0 + self.mag_dev_gain * (e_n ** 2 + (cur[1] - self.mag_ref[1]) ** 2)
            head = True
        if head:
            e3 = np.array([0.0, 0.0, 1.0])         # the vertical, earth frame
            H = np.zeros((1, 6))
            H[0, :3] = 2.0 * e3                    # heading of Exp θ q: e3ᵀ θ, θ = 2 δ (earth frame)
            q, P, ok = self._correct(q, P, H, np.array([float(z_h)]), np.array([r_h]), e3)
            if ok:
                self.head_age = 0.0
            else:
                status |= UPDATE_SKIPPED
                head = False
        if not head:
            self.head_age = min(self.head_age + dt, AGE_MAX)
        if self.head_age > HEAD_AGE_MAX:
            status |= HEADING_UNAIDED
        self.q, self.P = q, P
        return status

    def _off(self, cur, ref):
        """Field [norm, dip] off a reference by more than the thresholds."""
        return abs(cur[0] - ref[0]) > self.mag_norm_th * ref[0] or abs(cur[1] - ref[1]) > self.mag_dip_th

    def _correct(self, q, P, H, z, r, project_on):
        """Kalman correction with Joseph form on the earth-frame attitude error; `project_on`
        (an earth-frame unit vector) keeps only the attitude correction about that axis (the
        gain is projected; Joseph's form holds for any gain). Returns (q, P, ok)."""
        R = np.diag(r)
        S = H @ P @ H.T + R
        S = 0.5 * (S + S.T)
        try:
            ok = np.min(np.diag(np.linalg.cholesky(S)) ** 2) > S_PIVOT_MIN
        except np.linalg.LinAlgError:
            ok = False
        if not ok:
            return q, P, False
        HP = H @ P
        K = np.linalg.solve(S, HP).T
        if project_on is not None:
            K[:3] = np.outer(project_on, project_on) @ K[:3]
        # Joseph form (I − KH) P (I − KH)ᵀ + K R Kᵀ, expanded as in step(): exact for any K,
        # the projected heading gain included
        KHP = K @ HP
        P = P - KHP - KHP.T + K @ S @ K.T
        P = 0.5 * (P + P.T)
        X = K @ z
        q = qmul(np.concatenate([[1.0], X[:3]]), q)     # q = [1, δ] ⊗ q̂
        q = q / np.linalg.norm(q)
        self.gyro_bias = self.gyro_bias + X[3:]
        return q, P, True

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
