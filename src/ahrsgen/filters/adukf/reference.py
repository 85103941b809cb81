"""NumPy reference of the adaptive derivative UKF (A-DUKF), written from the equations.

Source: seeds/003_876a2b6ece1f51db.txt (the paper's formulas were lost; SPEC.md fixes the
reading below). Independent of the CasADi model: plain loops and numpy.linalg.

State q (4, body->NED, unit), P (4x4). One step, after the common input checks:

1. Time update (linear): A = I4 + dt/2 Ω(ω), q⁻ = A q, P⁻ = A P Aᵀ + Q.
   Product choice (documented): A is divided by |A q| = sqrt(1 + |ω|² dt²/4), which makes it
   orthogonal (AᵀA = (1 + |ω|² dt²/4) I for the first-order A), so q⁻ stays unit and the
   covariance of the unobservable norm direction does not grow without bound. faithful
   mode keeps the paper's A. Q = gyro_noise² dt/4 (I4 - q qᵀ) + q_floor dt I4 (the
   quaternion-rate noise of white gyro noise, plus a small isotropic floor).
2. Unscented measurement update (n = 4, 9 sigma points): L = chol(P⁻),
   χ0 = q⁻, χi = q⁻ + a L[:, i], χ(i+4) = q⁻ - a L[:, i], a = sqrt(n + λ),
   λ = α²(n + κ) - n; weights Wm0 = λ/(n+λ), Wc0 = Wm0 + 1 - α² + β, Wi = 1/(2(n+λ)).
   Option sigma_set = "simplex": the 2·4 points along the attitude columns of L are replaced
   by the 5 points of a spherical simplex (Julier 2003) at the same radius a, each weighing
   8 Wi / 5 (sigma_set() below).
   Each sigma point is normalised before h(q) = [R(q)ᵀ(-ĝ), R(q)ᵀ m̂], ĝ = [0,0,1].
   z = [f/|f|; m/|m|], ẑ = Σ Wm z_i, ε = z - ẑ,
   R = diag(σa² + k_a ε1..3², σm² + k_m ε4..6²),
   P_zz = Σ Wc (z_i - ẑ)(z_i - ẑ)ᵀ + R, P_xz = Σ Wc (χ_i - q⁻)(z_i - ẑ)ᵀ,
   K = P_xz P_zz⁻¹ (Cholesky solve), q⁺ = normalise(q⁻ + K ε), P⁺ = sym(P⁻ - K P_zz Kᵀ).
   A sensor that is not usable this step is masked out exactly: its rows/columns of P_zz
   become those of the identity, its columns of P_xz and its residual become 0, so K has
   zero columns for it.
3. Numerical safety: P⁻ not positive definite (smallest Cholesky pivot <= pivot_min):
   P reset to P0 = p0 I4, q = q⁻ normalised, update skipped (COV_RESET). P_zz not positive
   definite: update skipped, P = P⁻ (UPDATE_SKIPPED). A non-finite result: the state is
   left as it was before the step (NUMERIC_FAULT).

Reference field m̂ (NED unit): [cos I cos D, cos I sin D, sin I] from the configured
inclination I and declination D, or (mag_ref = "learn") I learned from the mean of
sin I = (-f̂)·m̂_b over the first `learn_samples` samples at rest; the magnetometer
correction waits until then (MAG_LEARNING).

Product defaults (issue 10; faithful ignores them):
- gyro_bias_state: x = [q; b] (n = 7, 15 sigma points). Time update with w = ω - b:
  q⁻ = A(w) q, b⁻ = b; P⁻ = F P Fᵀ + blockdiag(Q, (bias_rw² + q_floor) dt I3) with
  F = [[A, -∂(A q)/∂w], [0, I3]], ∂(A q)/∂w = c dt/2 Ξ(q) - c³ dt²/4 (q + dt/2 Ξ(q) w) wᵀ,
  c = 1/sqrt(1 + |w|² dt²/4), Ω(w) q = Ξ(q) w. The update corrects the whole x; q is normalised.
- attitude_state = "error" (with the bias state; the product default since issue 14): the
  covariance is that of the error state [d; δb] (n = 6, 13 sigma points), d a rotation in body
  axes with q_true = q̂ ⊗ δq(d), δq(d) = [1, d/2] / |[1, d/2]| (d is twice the Gibbs vector
  of the error rotation), b_true = b̂ + δb. Time update: r = δq(v), v = (ω - b̂) dt (the same
  rotation as the normalised A: A q = q ⊗ r), q⁻ = q ⊗ r, and
    d⁻ = R(r)ᵀ d - dt J δb,   J = ∂ε/∂Δv at Δv = 0 with r(v + Δv) = r(v) ⊗ δq(ε):
  r(v)* ⊗ r(v + Δv) ∝ [1 + v·(v + Δv)/4, Δv/2 - v × Δv/4], so ε = 2 vec / scal and
  J = (I3 - [v]x/2) / (1 + |v|²/4). So F = [[R(r)ᵀ, -dt J], [0, I3]] and
  Q = diag((gyro_noise² + (gyro_rate_noise w_i)² + 4 q_floor) dt (i = 1..3), (bias_rw² +
  q_floor) dt I3), w = ω - b̂ (the gyro's density grows with the rate: issue 26). P0 = diag(4 p0 I3,
  p0_bias I3) (the spread of p0 I4 on q: dq = Ξ(q) d / 2). Update: sigma points
  χ_i = L S[:, i] in the error state, attitude q⁻ ⊗ δq(χ_i[0:3]) through h; P_xz from χ_i;
  [d; δb] = K ε, q⁺ = normalise(q⁻ ⊗ [1, d/2]), b⁺ = b⁻ + δb, P⁺ = P⁻ - K P_zz Kᵀ.
  sigma_set is ignored (symmetric).
- accel_tau > 0: a ← a + dt/(τ + dt) (R(q⁻/|q⁻|) f - a) (started at R f), and the update
  measures R(q⁻/|q⁻|)ᵀ a instead of f. accel_lp_warm (issue 26, VQF's warm start): the gain is
  dt/(min(t, τ) + dt), t the time a has averaged (dt after the sample it starts at, + dt per
  sample, at most τ): the running mean of its samples until it has seen τ of them. Recovering
  from a clipped gyro sample (a = that sample) holds t.
- motion_accel_model = "gps_lowpass" (with accel_tau > 0, issue 26): the GPS velocity v (the
  sample of this step, else carried from the last one by v ← v + (R(q⁻/|q⁻|) f + g) dt) goes
  through the same low-pass, v_lp ← v_lp + k (v - v_lp) with the gain k = dt/(τ + dt) of a (1
  when a restarts at R f), and the update measures R(q⁻/|q⁻|)ᵀ (a - (v - v_lp)/τ): (v - v_lp)/τ
  is the same low-pass applied to the velocity's differences (v_k - v_{k-1})/dt, the vehicle's
  low-passed acceleration. Only while the last GPS sample is at most gps_timeout old (the age
  counted every step from the step's start); v_lp and v start at that sample after a gap.
- accel_lp_follow (with accel_tau > 0, issue 26): after an applied update that used the
  accelerometer, a ← R(q⁺) R(q⁻/|q⁻|)ᵀ a: the low-passed vector turns with the correction, so
  what it holds from before does not pull the attitude back to its old error.
- span_max > 0: each sensor's R is multiplied by max(dt / s, 1 / span_steps_max), s = the
  time since its previous sample (at least dt, at most span_max); with r_time > 0 (issue 26)
  also by r_time / dt: sigma², k eps² and adapt_max are per r_time seconds, not per IMU sample.

Initialisation: faithful: q = [1,0,0,0] (the paper). Otherwise the first step with usable
accelerometer and magnetometer sets q from tilt and tilt-compensated heading (SPEC.md
formulas) and does nothing else.
"""
from __future__ import annotations

import math

import numpy as np

from ahrsgen.constants import G0
from ahrsgen.reference_aiding import GyroClip, HardIron, warm_lowpass_gain
from ahrsgen.codegen import input_checks
from ahrsgen import status as st
from ahrsgen.npquat import q_from_euler, qmul, rotmat, skew

# filter-specific status bits (same values in the model and the generated C)
COV_RESET = st.FILTER_BASE << 0        # P⁻ not positive definite: P reset to P0, update skipped
UPDATE_SKIPPED = st.FILTER_BASE << 1   # P_zz not positive definite: update skipped
NUMERIC_FAULT = st.FILTER_BASE << 2    # non-finite result: state left as before the step
MAG_LEARNING = st.FILTER_BASE << 3     # reference field still being learned: no mag correction
GYRO_RECOVERY = st.FILTER_BASE << 4    # a clipped gyro sample, or clip_recovery_time after one
MAG_DISTURBED = st.FILTER_BASE << 5    # the hard-iron candidate is the better model: magnetometer not used
HARD_IRON_SWITCHED = st.FILTER_BASE << 6  # the hard iron and the learned field were replaced by the candidate

STATUS_BITS = [
    ("COV_RESET", COV_RESET, "P⁻ was not positive definite: P reset to P0, measurement update skipped"),
    ("UPDATE_SKIPPED", UPDATE_SKIPPED, "P_zz not positive definite: measurement update skipped"),
    ("NUMERIC_FAULT", NUMERIC_FAULT, "non-finite result: state left as it was before the step"),
    ("MAG_LEARNING", MAG_LEARNING, "reference field still being learned: magnetometer correction not applied"),
    ("MAG_DISTURBED", MAG_DISTURBED, "magnetometer not used: the hard-iron candidate explains the field much better"),
    ("HARD_IRON_SWITCHED", HARD_IRON_SWITCHED, "the hard iron and the learned field were replaced by the candidate"),
]

N = 4
_I4 = np.eye(N)


def omega_matrix(w):
    wx, wy, wz = w
    return np.array([
        [0.0, -wx, -wy, -wz],
        [wx, 0.0, wz, -wy],
        [wy, -wz, 0.0, wx],
        [wz, wy, -wx, 0.0],
    ])


def ut_weights(alpha, beta, kappa, n=N):
    lam = alpha * alpha * (n + kappa) - n
    a = math.sqrt(n + lam)
    wm = np.full(2 * n + 1, 1.0 / (2.0 * (n + lam)))
    wc = wm.copy()
    wm[0] = lam / (n + lam)
    wc[0] = lam / (n + lam) + 1.0 - alpha * alpha + beta
    return a, wm, wc


def spherical_simplex(d, w):
    """The d + 1 non-centre points of Julier's spherical simplex set (Julier 2003, "The
    spherical simplex unscented transformation"), d x (d + 1), for weight w per point: built
    dimension by dimension, j = 1: [-1, 1] / sqrt(2 w); j > 1: every earlier point gets
    -1 / sqrt(j (j + 1) w) in dimension j, and a new point [0 .. 0, j / sqrt(j (j + 1) w)].
    Σ w χ = 0 and Σ w χ χᵀ = I."""
    X = np.array([[-1.0, 1.0]]) / math.sqrt(2.0 * w)
    for j in range(2, d + 1):
        c = 1.0 / math.sqrt(j * (j + 1) * w)
        X = np.vstack([np.hstack([X, np.zeros((j - 1, 1))]), np.append(np.full(j, -c), j * c)])
    return X


def sigma_set(kind, alpha, beta, kappa, n):
    """(S, Wm, Wc): sigma points χ_i = x + L S[:, i] (L = chol(P), lower) and their weights.
    symmetric: the scaled UT, 2n + 1 points, S = [0, a I, -a I].
    simplex: the attitude dimensions 0..3 by the N + 1 = 5 points of a spherical simplex at the
    same radius a and with the same total weight as the 2N symmetric attitude points
    (w = 2N Wi / (N + 1)); the centre and the bias dimensions' pairs ±a as in symmetric.
    Mean and covariance are matched exactly by both (Σ Wm S = 0, Σ Wm S Sᵀ = I)."""
    a, wm, wc = ut_weights(alpha, beta, kappa, n)
    if kind == "symmetric":
        return np.hstack([np.zeros((n, 1)), a * np.eye(n), -a * np.eye(n)]), wm, wc
    w_s = 2 * N * wm[1] / (N + 1)
    X = np.zeros((n, N + 1))
    X[:N] = spherical_simplex(N, w_s)
    B = np.zeros((n, n - N))
    B[N:] = a * np.eye(n - N)
    S = np.hstack([np.zeros((n, 1)), X, B, -B])
    w = np.concatenate([[wm[0]], np.full(N + 1, w_s), np.full(2 * (n - N), wm[1])])
    wcs = w.copy()
    wcs[0] = wc[0]
    return S, w, wcs


def mag_ref_from_angles(incl, decl):
    return np.array([math.cos(incl) * math.cos(decl), math.cos(incl) * math.sin(decl), math.sin(incl)])


def h_meas(q, m_ref):
    """[R(q)ᵀ(-ĝ); R(q)ᵀ m̂] for unit q."""
    Rt = rotmat(q).T
    return np.concatenate([Rt @ np.array([0.0, 0.0, -1.0]), Rt @ m_ref])


def h_meas_batch(qs, m_ref):
    """h of each row of qs (k,4), unit quaternions: (k,6)."""
    w, x, y, z = qs.T
    R = np.empty((len(qs), 3, 3))
    R[:, 0, 0] = 1 - 2 * (y * y + z * z)
    R[:, 0, 1] = 2 * (x * y - w * z)
    R[:, 0, 2] = 2 * (x * z + w * y)
    R[:, 1, 0] = 2 * (x * y + w * z)
    R[:, 1, 1] = 1 - 2 * (x * x + z * z)
    R[:, 1, 2] = 2 * (y * z - w * x)
    R[:, 2, 0] = 2 * (x * z - w * y)
    R[:, 2, 1] = 2 * (y * z + w * x)
    R[:, 2, 2] = 1 - 2 * (x * x + y * y)
    # R^T v = rows of v^T R
    return np.concatenate([-R[:, 2, :], np.einsum("j,kji->ki", m_ref, R)], axis=1)


def q_from_accel_mag(f, m, decl):
    """Tilt (SPEC formulas) + tilt-compensated heading -> body->NED quaternion."""
    roll = math.atan2(-f[1], -f[2])
    pitch = math.atan2(f[0], math.hypot(f[1], f[2]))
    sr, cr, sp, cp = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch)
    xh = m[0] * cp + m[1] * sp * sr + m[2] * sp * cr
    yh = m[1] * cr - m[2] * sr
    yaw = math.atan2(-yh, xh) + decl
    return np.asarray(q_from_euler(roll, pitch, yaw), dtype=float)


def _chol(A):
    """(L, min pivot) with numpy; min pivot <= 0 reported as -inf when numpy refuses."""
    try:
        L = np.linalg.cholesky(A)
    except np.linalg.LinAlgError:
        return None, -np.inf
    return L, float(np.min(np.diag(L)) ** 2)


def dq_gibbs(d):
    """δq(d) = [1, d/2] / |[1, d/2]|: the rotation of the attitude error d (twice its Gibbs vector)."""
    v = np.concatenate([[1.0], 0.5 * np.asarray(d, dtype=float)])
    return v / np.linalg.norm(v)


def xi(q):
    """Ξ(q) with Ω(w) q = Ξ(q) w."""
    q0, q1, q2, q3 = q
    return np.array([[-q1, -q2, -q3], [q0, -q3, q2], [q3, q0, -q1], [-q2, q1, q0]])


class Reference:
    def __init__(self, params: dict):
        self.p = dict(params)
        p = self.p
        self.bias_state = bool(p["gyro_bias_state"]) and not p["faithful"]
        self.err = self.bias_state and p["attitude_state"] == "error"
        self.n = 6 if self.err else (7 if self.bias_state else N)
        self.lowpass = p["accel_tau"] > 0 and not p["faithful"]
        self.rated = p["span_max"] > 0 and not p["faithful"]
        self.accel_lp = np.zeros(3)
        self.lp_time = 0.0              # time accel_lp has averaged (its warm start), s, at most accel_tau
        self.gate = self.lowpass and self.err and p["accel_gate"] > 0
        self.accel_short = np.zeros(3)  # the gate's short NED mean of the specific force
        self.gps_lp = p["motion_accel_model"] == "gps_lowpass" and self.lowpass
        self.gps_vel = np.zeros(3)      # the latest GPS velocity (NED) and its age
        self.gps_age = 1e3              # model.GPS_AGE_MAX: no sample yet
        self.v_lp = np.zeros(3)         # the velocity through the accelerometer's low-pass
        self.v_ins = np.zeros(3)        # the velocity, carried between GPS samples by R f + g
        self.vlp_ok = False
        self.sample_age = np.zeros(2)
        self.bias = np.zeros(3)
        kind = "symmetric" if p["faithful"] or self.err else p["sigma_set"]       # faithful: the paper's points
        self.S, self.wm, self.wc = sigma_set(kind, p["ut_alpha"], p["ut_beta"], p["ut_kappa"], self.n)
        self.decl = float(p["declination"])
        self.learn = p["mag_ref"] == "learn"
        self.m_ref = (np.zeros(3) if self.learn
                      else mag_ref_from_angles(math.radians(p["inclination_deg"]), self.decl))
        self.learn_count = 0
        self.learn_sum = 0.0
        self.q = np.array([1.0, 0.0, 0.0, 0.0])
        self.P = self.P0()
        self.initialized = bool(p["faithful"])
        self.r_diag = np.zeros(6)       # R used by the last step (0 = sensor not used)
        self.clip = GyroClip(float(self.p["gyro_full_scale"]), float(self.p["gyro_plateau_rate"]),
                             float(self.p["clip_recovery_time"]))   # gyro over-range (error state)
        # the hard iron (docs/adukf.md, "Hard iron"): in the error-state design
        self.hard_iron_on = self.err and bool(p["mag_bias"])
        self.mag_bias = np.zeros(3)
        self.field = np.zeros(2)        # [norm, sin(inclination)]: the hard iron's reference
        self.learn_norm = 0.0           # |m| summed over the learning's rest samples
        self.mag_off = False            # the present model's norm residual off by mag_norm_tol
        if self.hard_iron_on:
            self.hard_iron = HardIron(rw=p["mag_bias_rw"], noise=p["mag_bias_noise"], bias_max=p["mag_bias_max"],
                                      settle=p["mag_bias_settle"], th=p["mag_bias_th"], jump=p["mag_bias_jump"],
                                      refine=p["mag_norm_tol"])

    def _set_m_ref(self, sin_incl):
        s_incl = min(max(sin_incl, -1.0), 1.0)
        c_incl = math.sqrt(1.0 - s_incl * s_incl)
        self.m_ref = np.array([c_incl * math.cos(self.decl), c_incl * math.sin(self.decl), s_incl])

    def P0(self):
        if self.err:
            return np.diag([4.0 * self.p["p0"]] * 3 + [self.p["p0_bias"]] * 3)
        return np.diag([self.p["p0"]] * 4 + [self.p["p0_bias"]] * (self.n - 4))

    def step(self, gyro, accel, mag, gps_vel, valid: int, dt: float) -> int:
        p = self.p
        c = input_checks.check(p, ("accel", "mag", "gps") if self.gps_lp else ("accel", "mag"),
                               gyro, accel, mag, gps_vel, valid, dt)
        if c.refused:
            return c.refused
        status, use_a, use_m, w = c.status, c.use_accel, c.use_mag, c.gyro
        use_g = self.gps_lp and c.use_gps
        m_comp = False
        if self.gps_lp:
            # the latest GPS velocity and its age; compensate while it is at most gps_timeout old
            if use_g:
                self.gps_vel = np.asarray(gps_vel, dtype=float).copy()
                self.gps_age = 0.0
            elif self.gps_age < 1e3:
                self.gps_age += dt
            m_comp = self.gps_age <= p["gps_timeout"]
            if not m_comp:
                self.vlp_ok = False
        wl = [float(x) for x in w]
        f = np.asarray(accel, dtype=float)
        m = np.asarray(mag, dtype=float)
        mag_ok = use_m

        # learning the reference field (dip angle) from samples at rest (and, for the hard iron,
        # its norm, also when the dip is configured)
        if (self.learn or self.hard_iron_on) and self.learn_count < p["learn_samples"]:
            if use_a and use_m:
                fn = np.linalg.norm(f)
                at_rest = (np.linalg.norm(w) < p["rest_gyro_max"]
                           and abs(fn - G0) < p["rest_accel_tol"])
                if at_rest:
                    self.learn_sum += float(np.dot(-f / fn, m / np.linalg.norm(m)))
                    self.learn_norm += float(np.linalg.norm(m))
                    self.learn_count += 1
                    if self.learn_count >= p["learn_samples"]:
                        if self.learn:
                            self._set_m_ref(self.learn_sum / self.learn_count)
                        self.field = np.array([self.learn_norm / self.learn_count, self.m_ref[2]])
            if self.learn and self.learn_count < p["learn_samples"]:
                if use_m:
                    status |= MAG_LEARNING
                use_m = False

        # initialisation from the first accelerometer + magnetometer sample
        if not self.initialized:
            if use_a and mag_ok:
                self.q = q_from_accel_mag(f, m, self.decl)
                self.P = self.P0()
                self.initialized = True
                self.r_diag = np.zeros(6)
                return status & ~MAG_LEARNING

        q_old, P_old, b_old = self.q.copy(), self.P.copy(), self.bias.copy()
        n = self.n

        # gyro over-range (error state): a clipped sample is integrated as it is, the rotation it
        # missed (up to one full scale's worth over the step) widens the attitude covariance, and
        # for clip_recovery_time after the last one R is not adapted and the accelerometer is not
        # low-passed (the timer keeps half a step of margin: float and double decide alike)
        clipped = recovering = False
        if self.err:
            clipped, recovering = self.clip.step(wl, dt)
            if recovering:
                status |= GYRO_RECOVERY

        # 1. time update (with the bias state: w = ω - b, F from the derivative above)
        if self.bias_state:
            wl = [wl[i] - self.bias[i] for i in range(3)]
        w_v = np.array(wl)
        A = _I4 + 0.5 * dt * omega_matrix(wl)
        c_norm = 1.0
        if not p["faithful"]:
            c_norm = 1.0 / math.sqrt(1.0 + 0.25 * dt * dt * (wl[0] ** 2 + wl[1] ** 2 + wl[2] ** 2))
            A = A * c_norm
        q = self.q
        Q = (p["gyro_noise"] ** 2 * dt / 4.0) * (_I4 - np.outer(q, q)) + p["q_floor"] * dt * _I4
        qm = A @ q
        if self.err:
            v = w_v * dt
            r = dq_gibbs(v)
            qm = qmul(q, r)
            J = (np.eye(3) - 0.5 * skew(v)) / (1.0 + 0.25 * float(v @ v))
            F = np.eye(6)
            F[:3, :3] = rotmat(r).T
            F[:3, 3:] = -dt * J
            # the gyro's density grows with the rate on each axis: gyro_rate_noise |ω_i|, in quadrature
            Qx = np.diag([(p["gyro_noise"] ** 2 + (p["gyro_rate_noise"] * w_v[i]) ** 2 + 4.0 * p["q_floor"]) * dt
                          for i in range(3)] + [(p["bias_rw"] ** 2 + p["q_floor"]) * dt] * 3)
            xm = np.concatenate([qm, self.bias])
            Pm = F @ self.P @ F.T + Qx
            if clipped:
                Pm = Pm + np.diag([(p["gyro_full_scale"] * dt) ** 2] * 3 + [0.0] * 3)
        elif self.bias_state:
            X = xi(q)
            dqdw = (c_norm * 0.5 * dt * X
                    - c_norm ** 3 * 0.25 * dt * dt * np.outer(q + 0.5 * dt * X @ w_v, w_v))
            F = np.eye(7)
            F[:4, :4] = A
            F[:4, 4:] = -dqdw
            Qx = np.zeros((7, 7))
            Qx[:4, :4] = Q
            Qx[4:, 4:] = (p["bias_rw"] ** 2 + p["q_floor"]) * dt * np.eye(3)
            xm = np.concatenate([qm, self.bias])
            Pm = F @ self.P @ F.T + Qx
        else:
            xm = qm
            Pm = A @ self.P @ A.T + Q
        Pm = 0.5 * (Pm + Pm.T)
        r_diag = np.zeros(6)

        # sensors at their own rates: the time each sample stands for
        scale = np.ones(6)
        noise = np.zeros(6)          # sigma_acc_density² / s_a on the accelerometer rows (rated)
        if self.rated:
            self.sample_age = np.minimum(self.sample_age + dt, p["span_max"])
            span = np.maximum(self.sample_age, dt)
            scale = np.repeat(np.maximum(dt / span, 1.0 / p["span_steps_max"]), 3)
            if p["r_time"] > 0:      # per-sample terms of a sample standing for r_time seconds
                scale = scale * p["r_time"] / max(dt, 1e-9)                 # model.SPAN_MIN
            d_a = p["sigma_acc_density"]
            if (self.err and self.lowpass and p["sigma_acc_density_unaided"] > 0 and not m_comp):
                d_a = p["sigma_acc_density_unaided"]      # no GPS compensation runs
            noise[:3] = d_a ** 2 / max(span[0], 1e-9)     # model.SPAN_MIN
            noise[3:] = p["sigma_mag_density"] ** 2 / max(span[1], 1e-9)
            if use_a:
                self.sample_age[0] = 0.0
            if use_m:
                self.sample_age[1] = 0.0

        # the hard iron: fitted while turning, the field used as m - b
        if self.hard_iron_on and use_m:
            m = m - self.mag_bias
        if self.hard_iron_on and use_m and self.learn_count >= p["learn_samples"]:
            w_b = np.asarray(c.gyro, dtype=float) - self.bias
            if not recovering and w_b @ w_b >= p["mag_bias_min_rate"] ** 2:
                new = self.hard_iron.step(rotmat(q_old), np.asarray(mag, dtype=float), self.mag_bias, self.field[0],
                                          self.field[1], span[1] if self.rated else dt)
                # the present model's norm residual leaving mag_norm_tol: a new disturbance, the
                # candidate's covariance reopens (for its next fit)
                off = abs(self.hard_iron.rlp[0]) > p["mag_norm_tol"]
                reopen = off and not self.mag_off and not self.hard_iron.suspect
                self.mag_off = off
                if new is not None:          # the candidate becomes the hard iron and the learned field
                    self.mag_bias = new[0]
                    self.field = np.array([new[1], new[2]])
                    self._set_m_ref(new[2])
                    status |= HARD_IRON_SWITCHED
                    use_m = False            # the sample was judged with the old hard iron
                if reopen:
                    self.hard_iron.reopen()
            if use_m and self.hard_iron.suspect:
                use_m = False
                status |= MAG_DISTURBED

        x_new = np.concatenate([qm / math.sqrt(float(qm @ qm)), xm[4:]])
        P_new = Pm
        w_g = 1.0                       # the accelerometer gate's weight (accel_gate)
        if use_a or use_m:
            f_meas = f
            if self.lowpass and use_a:
                qn = x_new[:4]
                f_n = rotmat(qn) @ f
                restart = not np.any(self.accel_lp)
                start = restart or recovering
                if start:
                    self.accel_lp = f_n                          # start at the first sample (and recovering)
                k_lp = dt / (p["accel_tau"] + dt)
                # no motion measurement (no GPS compensation running): the low-pass's own time
                # constant accel_tau_unaided (0: accel_tau)
                tau_a = p["accel_tau_unaided"] if p["accel_tau_unaided"] > 0 and not m_comp else p["accel_tau"]
                # warm start (VQF's): the running mean of the samples until it has averaged
                # tau_a of them; recovering holds the time (not begun again after a clip)
                t_lp = 0.0 if restart else self.lp_time
                k_warm, t_next = warm_lowpass_gain(t_lp, tau_a, dt)
                k_a = k_warm if p["accel_lp_warm"] else dt / (tau_a + dt)
                if self.gate:
                    # the gate: the short NED mean s (started at the sample with the low-pass), the
                    # sine² of its angle to the low-pass as it stood, e² = 1 - (s·a)²/(|s|²|a|²), and
                    # the weight w = max(1/(1 + accel_gate e²), floor) that divides the accelerometer
                    # rows of R, while the gyro is slow (|ω - b| < accel_gate_rate) and neither a
                    # start nor the GPS compensation
                    if start:
                        self.accel_short = f_n.copy()
                    s_g = self.accel_short + dt / (p["accel_gate_tau"] + dt) * (f_n - self.accel_short)
                    self.accel_short = s_g
                    w_b = np.asarray(c.gyro, dtype=float) - self.bias
                    if not start and not m_comp and float(w_b @ w_b) < p["accel_gate_rate"] ** 2:
                        n2 = float(s_g @ s_g) * float(self.accel_lp @ self.accel_lp)
                        e2 = (n2 - float(s_g @ self.accel_lp) ** 2) / max(n2, 1e-6)    # model.GATE_NORM2_MIN
                        w_g = max(1.0 / (1.0 + p["accel_gate"] * e2), p["accel_gate_floor"])
                self.accel_lp = self.accel_lp + k_a * (f_n - self.accel_lp)
                if restart or not recovering:
                    self.lp_time = t_next
                up = self.accel_lp
                if self.gps_lp:
                    if m_comp and not self.vlp_ok:
                        self.v_lp = self.gps_vel.copy()
                        self.v_ins = self.gps_vel.copy()
                        self.vlp_ok = True
                    # the velocity: this step's GPS sample, else carried by a = R f + g
                    self.v_ins = self.gps_vel.copy() if use_g else self.v_ins + (f_n + np.array([0.0, 0.0, G0])) * dt
                    if m_comp:
                        self.v_lp = self.v_lp + (1.0 if start else k_lp) * (self.v_ins - self.v_lp)
                        up = self.accel_lp - (self.v_ins - self.v_lp) / p["accel_tau"]
                f_meas = rotmat(qn).T @ up
            L, piv = _chol(Pm)
            if not piv > p["pivot_min"]:
                status |= COV_RESET
                P_new = self.P0()
            else:
                if self.err:          # error-state points, their attitude q⁻ ⊗ δq(d_i)
                    chis = (L @ self.S).T
                    cq = np.array([qmul(xm[:4], dq_gibbs(c[:3])) for c in chis])
                    xc = np.zeros(6)
                else:
                    chis = xm + (L @ self.S).T
                    cq = chis[:, :4]
                    xc = xm
                Z = h_meas_batch(cq / np.linalg.norm(cq, axis=1, keepdims=True), self.m_ref)
                zhat = self.wm @ Z
                z = np.concatenate([f_meas / math.sqrt(float(f_meas @ f_meas)) if use_a else np.zeros(3),
                                    m / math.sqrt(float(m @ m)) if use_m else np.zeros(3)])
                eps = z - zhat
                adapt = np.concatenate([p["k_a"] * eps[:3] ** 2, p["k_m"] * eps[3:] ** 2])
                if p["adapt_max"] > 0:
                    adapt = np.minimum(adapt, p["adapt_max"])
                if recovering:
                    adapt = np.zeros(6)
                R = (np.concatenate([np.full(3, p["sigma_acc"] ** 2), np.full(3, p["sigma_mag"] ** 2)]) + adapt) * scale + noise
                R[:3] = R[:3] / w_g     # the gate: the accelerometer's rows over its weight
                dZ = Z - zhat
                dX = chis - xc
                Pzz = (self.wc[:, None] * dZ).T @ dZ + np.diag(R)
                Pxz = (self.wc[:, None] * dX).T @ dZ
                mask = np.array([use_a] * 3 + [use_m] * 3)
                eps = np.where(mask, eps, 0.0)
                Pxz[:, ~mask] = 0.0
                Pzz[~mask, :] = 0.0
                Pzz[:, ~mask] = 0.0
                Pzz[~mask, ~mask] = 1.0
                _, piv_zz = _chol(Pzz)
                if not piv_zz > p["pivot_min"]:
                    status |= UPDATE_SKIPPED
                else:
                    K = np.linalg.solve(Pzz, Pxz.T).T
                    if self.err:
                        dx = K @ eps
                        qp = qmul(xm[:4], np.concatenate([[1.0], 0.5 * dx[:3]]))
                        x_new = np.concatenate([qp / math.sqrt(float(qp @ qp)), xm[4:] + dx[3:]])
                    else:
                        xp = xm + K @ eps
                        x_new = np.concatenate([xp[:4] / math.sqrt(float(xp[:4] @ xp[:4])), xp[4:]])
                    P_new = Pm - K @ Pzz @ K.T
                    P_new = 0.5 * (P_new + P_new.T)
                    r_diag = np.where(mask, R, 0.0)
                    if self.lowpass and use_a and p["accel_lp_follow"]:
                        # the low-pass turned with the correction: R(q⁺) R(q⁻)ᵀ a
                        self.accel_lp = rotmat(x_new[:4]) @ (rotmat(qn).T @ self.accel_lp)

        if not (np.isfinite(x_new).all() and np.isfinite(P_new).all()):
            self.q, self.P, self.bias = q_old, P_old, b_old
            self.r_diag = np.zeros(6)
            return status | NUMERIC_FAULT
        self.q, self.P, self.r_diag = x_new[:4], P_new, r_diag
        if self.bias_state:
            self.bias = x_new[4:]
        return status


def run(log, params, record_r=False):
    """Run the reference over a SensorLog; returns q (N,4) (and R diagonals (N,6))."""
    ref = Reference(params)
    qs = np.empty((len(log), 4))
    rs = np.empty((len(log), 6)) if record_r else None
    for k in range(len(log)):
        ref.step(log.gyro[k], log.accel[k], log.mag[k], log.gps_vel[k], int(log.valid[k]), float(log.dt[k]))
        qs[k] = ref.q
        if record_r:
            rs[k] = ref.r_diag
    return (qs, rs) if record_r else qs


def default_params() -> dict:
    """Every parameter's default (defaults.toml plus the common input checks)."""
    from ahrsgen import filters
    return filters.load("adukf").defaults()
