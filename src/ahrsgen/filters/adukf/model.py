"""A-DUKF: adaptive derivative unscented Kalman filter (seeds/003, SPEC.md), symbolic model.

State q (4, body->NED), P (4x4). The equations are those of reference.py's docstring:

  predict   A = (I4 + dt/2 Ω(ω)) [/ sqrt(1 + |ω|² dt²/4) unless faithful], q⁻ = A q,
            P⁻ = A P Aᵀ + gyro_noise² dt/4 (I4 - q qᵀ) + q_floor dt I4, symmetrised
  update    L = chol(P⁻) (fixed-size, guarded), 9 sigma points q⁻, q⁻ ± a L[:, i],
            each normalised before h(q) = [R(q)ᵀ(-ĝ); R(q)ᵀ m̂]; ẑ, ε = z - ẑ,
            R = diag(σa² + k_a ε², σm² + k_m ε²) per axis, P_zz, P_xz,
            K = P_xz P_zz⁻¹ by a Cholesky solve, q⁺ = normalise(q⁻ + K ε),
            P⁺ = sym(P⁻ - K P_zz Kᵀ). Unusable sensors are masked out exactly.

Product default (issue 14, attitude_state = "error", with the gyro-bias state): P is the
covariance of the error state [d; δb], q = q̂ ⊗ [1, d/2]/|.|, b = b̂ + δb (6 states, 13 sigma
points; predict_expr, sigma_pair_error_expr, correct_expr).

GPS motion (issue 26, motion_accel_model = "gps_lowpass", with the low-pass): the GPS velocity,
carried between samples by R f + g, goes through the accelerometer's NED low-pass with the same
gain, and the update measures R(q⁻)ᵀ (a - (v - v_lp)/accel_tau): the low-passed kinematic
acceleration removed (aiding.gps_lowpass, mekf's and qcf's construction), while the last GPS
velocity is at most gps_timeout old.

The two smallest Cholesky pivots (of P⁻ and of P_zz) are outputs; the step partial uses
them to reset P or skip the update with a status bit, so the state never becomes NaN.
"""
from __future__ import annotations

import math

import casadi as ca

from ahrsgen.constants import G0, Const, named, use
from ahrsgen.codegen.emit import function
from ahrsgen.codegen.model import FilterModel, KernelSpec, StateField
from ahrsgen.symbolic import aiding, attitude, linalg, quat

N = 4
EXTRA_STATUS = [
    ("COV_RESET", "P- was not positive definite: P reset to P0, measurement update skipped"),
    ("UPDATE_SKIPPED", "P_zz was not positive definite: measurement update skipped"),
    ("NUMERIC_FAULT", "non-finite result: state left as it was before the step"),
    ("MAG_LEARNING", "reference field still being learned: magnetometer correction not applied", "info"),
    ("GYRO_RECOVERY", "a gyro component at gyro_full_scale (clipped), or within clip_recovery_time after one: the attitude covariance widened, R not adapted, the accelerometer not low-passed (error state only)", "info"),
    ("MAG_DISTURBED", "magnetometer not used: the hard-iron candidate explains the field much better than the present hard iron (mag_bias)", "info"),
    ("HARD_IRON_SWITCHED", "the hard iron and the learned field (norm, dip) were replaced by the candidate field model (mag_bias)", "info"),
]


# (row, column) of the lower triangle of a 6x6 matrix, row by row
_LOWER6 = [(r, c) for r in range(6) for c in range(r + 1)]


# s: floor of the sample interval in the density term (a denormal dt must not overflow R to inf)
SPAN_MIN = Const("SPAN_MIN", 1e-9)
# the time since the last GPS sample stops counting here, s (a whole number: exact in float)
GPS_AGE_MAX = Const("GPS_AGE_MAX", 1e3)
# (m/s²)²: the accelerometer gate's short mean counts as level below this squared norm (a zero
# sample must not divide by 0)
GATE_NORM2_MIN = Const("GATE_NORM2_MIN", 1e-6)


def _on(v) -> bool:
    """A parameter's term is written unless it is the number 0 (a runtime value is always written)."""
    return not (isinstance(v, (int, float)) and v == 0)


def omega_matrix(w):
    wx, wy, wz = w[0], w[1], w[2]
    return ca.vertcat(
        ca.horzcat(0, -wx, -wy, -wz),
        ca.horzcat(wx, 0, wz, -wy),
        ca.horzcat(wy, -wz, 0, wx),
        ca.horzcat(wz, wy, -wx, 0),
    )


def xi_matrix(q):
    """Ξ(q) with Ω(w) q = Ξ(q) w."""
    return ca.vertcat(
        ca.horzcat(-q[1], -q[2], -q[3]),
        ca.horzcat(q[0], -q[3], q[2]),
        ca.horzcat(q[3], q[0], -q[1]),
        ca.horzcat(-q[2], q[1], q[0]),
    )


def ut_parameters(alpha, beta, kappa, n=N):
    """Spread a and weights (Wm0, Wc0, Wi) of the scaled unscented transform."""
    lam = alpha * alpha * (n + kappa) - n
    return math.sqrt(n + lam), lam / (n + lam), lam / (n + lam) + 1 - alpha * alpha + beta, 1 / (2 * (n + lam))


def simplex_scales(w):
    """c_k = 1 / sqrt(j (j + 1) w), j = k + 1, of the spherical simplex of N dimensions with
    weight w per point (reference.spherical_simplex): point i (1..N+1) is Σ_k c_k t_i[k] e_k
    with the integers t_i[k] = -1 for i <= k + 1, k + 1 for i = k + 2, 0 beyond."""
    return [1.0 / math.sqrt((k + 1) * (k + 2) * w) for k in range(N)]


def normalize(v):
    """v/|v| with one division: v * sqrt(1/|v|²) (CasADi keeps this a multiplication)."""
    return v * ca.sqrt(1 / ca.sumsqr(v))


def measurement(q, m_ref):
    """h(q) = [R(q)ᵀ(-ĝ); R(q)ᵀ m̂] with ĝ = [0, 0, 1] (NED down)."""
    return ca.vertcat(quat.rotate_inv(q, ca.DM([0.0, 0.0, -1.0])), quat.rotate_inv(q, m_ref))


def has_bias_state(p) -> bool:
    """Product default: a gyro-bias state (7-state filter); faithful: the paper's 4-state filter."""
    return bool(p["gyro_bias_state"]) and not p["faithful"]


def has_error_state(p) -> bool:
    """Product default: with the bias state, the covariance is that of the 3-parameter attitude
    error and the bias (6 states; attitude_state = "error")."""
    return has_bias_state(p) and p["attitude_state"] == "error"


def gps_lowpass(p) -> bool:
    """The GPS velocity's low-passed derivative is removed in the NED low-pass (product with
    accel_tau > 0 only: without the low-pass there is nothing to share)."""
    return p["motion_accel_model"] == "gps_lowpass" and p["accel_tau"] > 0 and not p["faithful"]


def skew(v):
    """[v]x with [v]x u = v x u."""
    return ca.vertcat(ca.horzcat(0, -v[2], v[1]), ca.horzcat(v[2], 0, -v[0]), ca.horzcat(-v[1], v[0], 0))


class Model(FilterModel):
    def __init__(self, params: dict):
        super().__init__(params, sensors=("accel", "mag", "gps") if gps_lowpass(params) else ("accel", "mag"),
                         extra_status=list(EXTRA_STATUS))
        self.gps = gps_lowpass(params)
        self.err = has_error_state(params)
        self.nx = 7 if has_bias_state(params) else N      # the state x: q, or [q; gyro bias]
        self.n = 6 if self.err else self.nx              # P's size: [δθ; b] (error state), or x's
        self.na = 3 if self.err else N                   # the columns of L that move the attitude

    def simplex(self) -> bool:
        return self.params["sigma_set"] == "simplex" and not self.params["faithful"] and not self.err

    def ut(self):
        """(a, Wc0, w, c_dd): spread, centre's covariance weight, weight of each attitude point
        (Wi, or the simplex's 2N Wi / (N + 1): the same total) and c_dd = Σ Wc - 2 (the same for
        both sets)."""
        p = self.params
        n = self.n
        a, _, wc0, wi = ut_parameters(p["ut_alpha"], p["ut_beta"], p["ut_kappa"], n)
        w = 2 * N * wi / (N + 1) if self.simplex() else wi
        # named in the C (ahrsgen.constants.named): the spread and the weight of a point
        return named("UT_A", a), wc0, named("UT_W", w), wc0 + 2 * n * wi - 2

    def m_ref_configured(self):
        p = self.params
        i, d = math.radians(p["inclination_deg"]), float(p["declination"])
        return [math.cos(i) * math.cos(d), math.cos(i) * math.sin(d), math.sin(i)]

    def state_fields(self):
        p = self.params
        n = self.n
        p0 = [self.p0_diag()[r] if r == c else 0.0 for c in range(n) for r in range(n)]
        learn = p["mag_ref"] == "learn"
        return [
            StateField("q", 4, "attitude estimate, body->NED, [w x y z]", [1.0, 0.0, 0.0, 0.0]),
        ] + ([StateField("gyro_bias", 3, "gyro bias estimate, rad/s", 0.0)] if self.nx == 7 else []) + [
            StateField("P", n * n, f"covariance of {self.p_meaning()}, {n}x{n} (symmetric; column-major)", p0),
            StateField("m_ref", 3, "reference field direction, NED unit vector", [0.0] * 3 if learn else self.m_ref_configured()),
            StateField("r_diag", 6, "diagonal of the adaptive R used by the last update (0: sensor not used)", 0.0),
        ] + ([StateField("sample_age", 2, "time since the last accelerometer / magnetometer sample, s", 0.0)]
             if self.own_rates() else []) + ([StateField("accel_lp", 3, "low-passed specific force in NED, m/s^2 (accel_tau > 0)", 0.0),
                  StateField("lp_time", 1, "time accel_lp has averaged, s (its warm start; stops at accel_tau)", 0.0)]
             if self.lowpass() else []) + ([StateField("accel_short", 3, "the accelerometer gate's short NED mean of the "
                                                     "specific force (accel_gate_tau), m/s^2", 0.0)]
                                          if self.gate() else []) + ([
                StateField("gps_vel", 3, "latest GPS velocity (NED, m/s; gps_lowpass)", 0.0),
                StateField("gps_age", 1, "time since the last GPS sample, s (gps_lowpass)", GPS_AGE_MAX),
                StateField("v_lp", 3, "GPS velocity through the accelerometer's NED low-pass (gps_lowpass), m/s", 0.0),
                StateField("v_ins", 3, "GPS velocity, carried between samples by R f + g (gps_lowpass), m/s", 0.0),
                StateField("vlp_ok", 1, "1 while v_lp follows a fresh GPS velocity (gps_lowpass)", 0, "uint32"),
             ] if self.gps else []) + (self.gyro_recovery_state() if self.err else []) + [
            StateField("work", self.work_layout()["size"], "scratch of the step (P-, the update's matrices and sigma-point sums"
                       + (", x- and x+) " if self.nx == 7 else ") ") +
                       "kept here instead of on the stack: no meaning between steps, zeroed when an update or its "
                       "result is refused", 0.0),
            StateField("learn_sum", 1, "mag_ref = learn: sum of sin(inclination) over rest samples", 0.0),
            StateField("learn_count", 1, "mag_ref = learn: rest samples summed so far", 0, "uint32"),
            StateField("initialised", 1, "1 once the attitude has been initialised", 1 if p["faithful"] else 0, "uint32"),
        ] + ([StateField("mag_field", 2, "the hard iron's reference field: [norm (the field's units), sin(inclination)], "
                         "learned at rest as m_ref is, with either mag_ref (the norm summed there first)", 0.0),
              StateField("mag_off", 1, "1 while the hard-iron residual of the field norm is off by more than "
                         "mag_norm_tol (its onset reopens the candidate)", 0, "uint32"),
              *self.hard_iron_state()] if self.hard_iron() else [])

    def hard_iron(self) -> bool:
        """The hard iron is estimated (mag_bias) in the error-state design (its field norm learned at
        rest as the dip is, with either mag_ref)."""
        return self.err and bool(self.params["mag_bias"])

    def p_meaning(self) -> str:
        if self.err:
            return ("[attitude error d (rad, body axes: q = q_est * [1, d/2] normalised); gyro_bias]")
        return "q" if self.n == 4 else "[q; gyro_bias]"

    def work_layout(self) -> dict:
        """Offsets (floats) of the step's scratch in the state's `work`, the one place they are
        derived (the template reads them): P_pred first (its lower triangle, packed: linalg's
        packed_lower_pairs); then the update's floats: the sigma points' aL and z0, the pairs'
        differences and sums (zdiff, zsum), P_zz (packed) and the residual (R goes to the
        state's r_diag directly). sigma_set = simplex: the points' attitude parts (4 x 5, over
        the first 20 of zdiff, which the innovation writes after they are read) and their
        deviations zdev (6 x 5) in place of zsum. The gain kernel reads all its inputs before it writes, so G
        and g go over zdiff and the residual; the innovation and correct kernels store each
        output as soon as computed (early_writes), so their outputs overlap none of their
        inputs: P_new (packed) over zsum and P_zz, both dead by then. Then x_pred and x_new (bias
        state); `update_end` ends the update's floats, `size` the whole scratch."""
        n, na = self.n, self.na
        npk = n * (n + 1) // 2
        at = {"P_pred": 0, "aL": npk}
        at["z0"] = at["aL"] + na * n
        at["zdiff"] = at["z0"] + 6
        if self.simplex():
            at["points"] = at["zdiff"]
            at["zdev"] = at["zdiff"] + 6 * N
            at["P_zz"] = at["zdev"] + 6 * (N + 1)
            at["P_new"] = at["zdev"]
        else:
            at["zsum"] = at["zdiff"] + 6 * na
            at["P_zz"] = at["zsum"] + 6 * na
            at["P_new"] = at["zsum"]
        at["residual"] = at["P_zz"] + 21
        at["update_end"] = at["residual"] + 6
        at["G"] = at["zdiff"]          # written by gain, which reads zdiff
        at["g"] = at["residual"]       # written by gain, which reads the residual
        assert at["P_new"] + npk <= at["residual"] and at["G"] + na * (na + 1) // 2 <= at["zdiff"] + 6 * na
        assert at.get("points", 0) + 4 * (N + 1) <= at["zdiff"] + 6 * na
        at["x_pred"] = at["update_end"]
        at["x_new"] = at["x_pred"] + 7
        at["size"] = at["update_end"] + (14 if self.nx == 7 else 0)
        return at

    def r_scale(self, dt, span):
        """dt / span, at least 1 / span_steps_max (a sample never counts for more steps than that:
        a tiny dt after a normal one must not make the measurement look exact). With r_time > 0
        (issue 26) also times r_time / dt: the per-sample terms of R (sigma², the adaptation k ε²
        and its bound) are those of a sample standing for r_time seconds, so what a sensor tells
        per second, and how long an adaptive lock-out lasts, do not depend on the sample rate."""
        scale = ca.fmax(dt / span, 1.0 / self.params["span_steps_max"])
        t = self.params["r_time"]
        if isinstance(t, (int, float)) and t == 0:
            return scale
        return scale * t / ca.fmax(dt, use(SPAN_MIN))

    def own_rates(self) -> bool:
        return not self.params["faithful"] and self.params["span_max"] > 0

    def lowpass(self) -> bool:
        return self.params["accel_tau"] > 0 and not self.params["faithful"]

    def unaided(self) -> bool:
        """The low-pass has its own time constant while no GPS compensation runs (accel_tau_unaided)."""
        p = self.params
        return self.lowpass() and p["accel_tau_unaided"] > 0 and p["accel_tau_unaided"] != p["accel_tau"]

    def density_split(self) -> bool:
        """The accelerometer's density term has its own value while no GPS compensation runs
        (sigma_acc_density_unaided; error state, sensors at their own rates)."""
        p = self.params
        return (self.err and self.own_rates() and self.lowpass() and p["sigma_acc_density_unaided"] > 0
                and p["sigma_acc_density_unaided"] != p["sigma_acc_density"])

    def gate(self) -> bool:
        """The accelerometer gate (accel_gate > 0, error state with the low-pass): the
        accelerometer rows of R grow as the specific force's short-window mean tilts."""
        return self.lowpass() and self.err and self.params["accel_gate"] > 0

    def gate_weight_expr(self, a_short, a_lp, f_n, dt, gyro, bias, off):
        """The accelerometer gate (issue 26). A short NED low-pass of the specific force,
        s <- s + dt/(accel_gate_tau + dt)(f_n - s) (tens of ms: motor vibration, zero-mean at
        high frequency, averages out of it; a motion acceleration or an offset does not), and the
        sine² of the angle between it and the long low-pass a_lp (as it stood before this sample),
        e² = 1 - (s·a)²/(|s|²|a|²): motion is the short mean departing from the long one. An error
        of the estimate's attitude turns both alike (both are in the estimate's NED), so it does
        not close the gate, and a sustained acceleration does not keep it closed: once the long
        low-pass has taken it in, e² is small again. While the gyro is slow (|ω - b| <
        accel_gate_rate) and `off` is false, the weight w = max(1/(1 + accel_gate e²),
        accel_gate_floor), else 1; the accelerometer rows of R are divided by it
        (residual_and_r): the rejection acts on the correction, and the long low-pass stays linear
        (weighing the samples that enter it biases a zero-mean motion's average:
        studies/adukf_gate_cv.py). Returns (w, s')."""
        p = self.params
        s_new = a_short + (dt / (use(p["accel_gate_tau"]) + dt)) * (f_n - a_short)
        sa = ca.dot(s_new, a_lp)
        n2 = ca.sumsqr(s_new) * ca.sumsqr(a_lp)
        e2 = (n2 - sa * sa) / ca.fmax(n2, use(GATE_NORM2_MIN))
        w = ca.fmax(1.0 / (1.0 + p["accel_gate"] * e2), p["accel_gate_floor"])
        wb = gyro - bias
        slow = ca.sumsqr(wb) < p["accel_gate_rate"] ** 2
        return ca.if_else(ca.logic_and(slow, ca.logic_not(off)), w, 1.0), s_new

    def accel_lowpass_expr(self, a_lp, f_n, lp_time, dt, restart, start, m_comp=None):
        """The NED low-pass of the specific force f_n = R(q-) f: a ← a + α (f_n − a), started at
        f_n (restart, or recovering from a clipped gyro sample: start). α = dt / (τ + dt), or with
        accel_lp_warm (VQF's warm start, issue 26) α = dt / (min(lp_time, τ) + dt), lp_time the
        time it has averaged (0 at a restart, then + dt per sample, capped at τ): the running mean
        of its samples until it has seen τ of them, so its first sample (a multirotor's motor
        vibration tilts one sample by up to 15°) weighs 1/n instead of lingering as e^(−t/τ).
        Recovering holds lp_time (the warm start is not begun again after a gyro clip, as mekf).
        Returns the new low-pass and lp_time."""
        tau = self.params["accel_tau"]
        tau_u = self.params["accel_tau_unaided"]
        if self.unaided():
            # no motion measurement (no GPS compensation running, or none built): the low-pass
            # must average the vehicle's motion out by itself, over accel_tau_unaided
            tau = tau_u if m_comp is None else ca.if_else(m_comp, use(tau), use(tau_u))
        base = ca.if_else(restart, 0, lp_time)
        alpha, lp_next = aiding.warm_lowpass_gain(base, tau, dt)
        if not self.params["accel_lp_warm"]:
            alpha = dt / (use(tau) + dt)
        start_lp = ca.if_else(start, f_n, a_lp)
        a_new = start_lp + alpha * (f_n - start_lp)
        lp_new = ca.if_else(ca.logic_and(start, ca.logic_not(restart)), lp_time, lp_next)
        return a_new, lp_new

    def follow(self) -> bool:
        """The NED low-pass is turned with each correction of the attitude (accel_lp_follow)."""
        return self.lowpass() and bool(self.params["accel_lp_follow"])

    def p0_diag(self):
        """P0's diagonal. Error state: 4 p0 per attitude-error axis, the same spread of attitude as
        p0 I4 on q (a small rotation d moves a unit q by dq = Ξ(q) d / 2, and Ξᵀ Ξ = I3)."""
        p = self.params
        if self.err:
            return [4.0 * p["p0"]] * 3 + [p["p0_bias"]] * 3
        return [p["p0"]] * 4 + [p["p0_bias"]] * (self.n - 4)

    # ------------------------------------------------------------------ kernels
    def predict_expr(self, q, P, w, dt):
        """q is the state x (q, or [q; b] with the bias state). Returns x⁻, q⁻/|q⁻|, P⁻.

        P is read through its lower triangle (it is exactly symmetric: every kernel writes one
        triangle and mirrors it), and P⁻ = F P Fᵀ + Q is computed on its lower triangle and
        mirrored, which is the symmetrisation (P⁻ + P⁻ᵀ)/2 of the equations without its cost."""
        p = self.params
        n = self.n
        x = q
        if self.nx == 7:
            q, b = x[:4], x[4:]
            w = w - b
        A1 = ca.SX.eye(N) + 0.5 * dt * omega_matrix(w)
        c_n = c_sq = 1.0
        if not p["faithful"]:
            # A = c A1, c = 1 / sqrt(1 + |ω|²dt²/4) written as sqrt(1/x): one division. c² = 1/x
            # is written h + h with h = 0.5/x (exactly 1/x): CasADi turns y * (1/x) into y / x,
            # and the products by c² below should stay multiplications.
            half = 0.5 / (1 + 0.25 * dt * dt * ca.sumsqr(w))
            c_sq = half + half
            c_n = ca.sqrt(c_sq)
        Q = (p["gyro_noise"] ** 2 * 0.25 * dt) * (ca.SX.eye(N) - ca.mtimes(q, q.T)) + p["q_floor"] * dt * ca.SX.eye(N)
        Ps = linalg.lower_symmetric(P)
        Pm = ca.SX.zeros(n, n)
        Qb = p["bias_rw"] ** 2 * dt + p["q_floor"] * dt
        if self.err:
            # error state [d; b]: q = q̂ ⊗ δq(d), δq(d) = [1, d/2]/|[1, d/2]|, b = b̂ + δb. The step's
            # rotation is r = δq(v), v = (ω - b̂) dt (q⁻ = q ⊗ r = A q, A as above), so
            # d⁻ = R(r)ᵀ d + J δv with δv = -dt δb to first order: F = [[Φ, B], [0, I3]],
            # Φ = R(r)ᵀ = c² ((1 - |v|²/4) I3 + v vᵀ/2 - [v]x) = (2c² - 1) I3 + c² (v vᵀ/2 - [v]x),
            # B = -dt J = -dt c² (I3 - [v]x / 2) (c² = 1/(1 + |v|²/4); the Jacobian of
            # v -> δq(v) on the right, reference.py derives it). Q: the gyro's angle random
            # walk gyro_noise² dt and 4 q_floor dt on each attitude axis (the quaternion form's Q
            # is this mapped by Ξ(q)/2), the bias random walk on the bias.
            # F P Fᵀ by blocks, F1 = [Φ, B]: M1 = F1 P (3 x 6), attitude block M1 F1ᵀ, cross
            # block M1[:, 3:6], bias block P_bb.
            qm = c_n * ca.mtimes(A1, q)
            Phi = (c_sq + c_sq - 1.0) * ca.SX.eye(3) + c_sq * ((0.5 * dt * dt) * ca.mtimes(w, w.T) - dt * skew(w))
            B = (-dt * c_sq) * ca.SX.eye(3) + (0.5 * dt * dt * c_sq) * skew(w)
            F1 = ca.horzcat(Phi, B)
            M1 = ca.mtimes(F1, Ps)
            Qa = (p["gyro_noise"] ** 2 + 4.0 * p["q_floor"]) * dt
            # a MEMS gyro's scale-factor and cross-axis errors grow with the rate: each axis's
            # density grows by gyro_rate_noise |ω_i| in quadrature (a density: rate-independent)
            g_r = p["gyro_rate_noise"]
            Qs = [Qa + (g_r * g_r * dt) * (w[i] * w[i]) for i in range(3)] if _on(g_r) else [Qa] * 3
            for r in range(n):
                for c in range(r + 1):
                    if r < 3:
                        Pm[r, c] = ca.mtimes(M1[r, :], F1[c, :].T) + (Qs[r] if r == c else 0.0)
                    elif c < 3:
                        Pm[r, c] = M1[c, r]
                    else:
                        Pm[r, c] = Ps[r, c] + (Qb if r == c else 0.0)
                    Pm[c, r] = Pm[r, c]
            return ca.vertcat(qm, b), normalize(qm), Pm
        if n == 4:
            A = A1 * c_n
            qm = ca.mtimes(A, q)
            AP = ca.mtimes(A, Ps)
            for r in range(N):
                for c in range(r + 1):
                    Pm[r, c] = ca.mtimes(AP[r, :], A[c, :].T) + Q[r, c]
                    Pm[c, r] = Pm[r, c]
            return qm, normalize(qm), Pm
        # bias state: x⁻ = [A(ω - b) q; b], F = [[A, G], [0, I3]] with
        # G = ∂q⁻/∂b = -∂q⁻/∂w = -(c dt/2 Ξ(q) - c² dt²/4 q⁻ wᵀ) (c: A's normalisation;
        # reference.py, test_bias_state_jacobian_matches_finite_differences), bias random walk in Q.
        # c is factored out: A = c A1 (A1 = I4 + dt/2 Ω(ω), ones on its diagonal), G = c G1, so
        # F[0:4, :] = c F1 with F1 = [A1, G1]. F P Fᵀ by blocks: M1 = F1 P (4 x 7) gives the q-q
        # block c² M1 F1ᵀ (lower triangle) and the q-b block c M1[:, 4:7] (P symmetric); the
        # b-b block is P_bb.
        qm = c_n * ca.mtimes(A1, q)
        G1 = -(0.5 * dt) * xi_matrix(q) + ca.mtimes((c_n * 0.25 * dt * dt) * qm, w.T)
        F1 = ca.horzcat(A1, G1)
        M1 = ca.mtimes(F1, Ps)
        for r in range(n):
            for c in range(r + 1):
                if r < N:
                    Pm[r, c] = c_sq * ca.mtimes(M1[r, :], F1[c, :].T) + Q[r, c]
                elif c < N:
                    Pm[r, c] = c_n * M1[c, r]
                else:
                    Pm[r, c] = Ps[r, c] + (Qb if r == c else 0.0)
                Pm[c, r] = Pm[r, c]
        xm = ca.vertcat(qm, b)
        return xm, normalize(qm), Pm

    def sigma_setup_expr(self, qn, Pm, m_ref, qm=None):
        """L = chol(P⁻) (its smallest pivot is an output), aL = a L[:, 0:4] and z₀ = h(q⁻), the
        centre's measurement, from qn = q⁻/|q⁻| as predict computed it (not normalised again).
        sigma_set = simplex: aL = L[:, 0:4] diag(c) instead, and a fourth output, the attitude
        parts of the 5 simplex points (qm = x⁻).

        The structure of the sigma-point set, used exactly (no approximation):
        χ = x⁻ ± a L[:, j] with L lower triangular: for a bias column (j ≥ 4) L[0:4, j] = 0, so
        the attitude part of those points is q⁻ itself and their measurement is z₀: only the
        4 columns of aL move the attitude, 9 distinct points in all."""
        p = self.params
        a, _, w, _ = self.ut()
        L, _, piv_p = linalg.cholesky_with_inverse(Pm, p["pivot_min"])
        z0 = measurement(qn, m_ref)
        if not self.simplex():
            return a * L[:, :self.na], z0, piv_p
        # simplex: V = L[:, 0:4] diag(c) and the 5 points' attitude parts q⁻ + u_i, u_i =
        # V[0:4, :] t_i (simplex_scales), by suffix sums R_k = Σ_{k' >= k} V[:, k']: u_1 = -R_0,
        # u_{k+2} = (k + 1) V[:, k] - R_{k+1}
        V = ca.horzcat(*[L[:, k] * c for k, c in enumerate(simplex_scales(w))])
        Vq = [V[:N, k] for k in range(N)]
        R = [None] * N
        R[N - 1] = Vq[N - 1]
        for k in range(N - 2, -1, -1):
            R[k] = Vq[k] + R[k + 1]
        U = [-R[0]] + [(k + 1) * Vq[k] - R[k + 1] if k < N - 1 else (k + 1) * Vq[k] for k in range(N)]
        return V, z0, piv_p, ca.vertcat(*[qm[:N] + u for u in U])

    def sigma_pair_expr(self, qm, col, m_ref, z0):
        """One pair of sigma points q⁻ ± col (col = a L[0:4, j]), each normalised and mapped
        through h, as deviations from the centre e± = h(χ±) - z₀; returned: e₊ + e₋ and e₊ - e₋
        (the innovation kernel sums over the pairs)."""
        ep = measurement(normalize(qm + col), m_ref) - z0
        en = measurement(normalize(qm - col), m_ref) - z0
        return ep + en, ep - en

    def sigma_pair_error_expr(self, col, z0):
        """Error state: the pair of sigma points ±d (d = col = a L[0:3, j]), q̂ ⊗ δq(±d), as
        deviations from the centre. With δq(±d) = [k, ±k d/2], k² = 1/(1 + |d|²/4), and u the
        centre's body-frame vectors (z₀ = [u_g; u_m]): h(q̂ ⊗ δq) = R(δq)ᵀ R(q̂)ᵀ v = R(δq)ᵀ u, and
        R([w, s])ᵀ u = u - 2w (s x u) + 2 s x (s x u), so e± = ∓k² (d x u) + k²/2 d x (d x u):
        e₊ + e₋ = k² d x (d x u), e₊ - e₋ = -2k² (d x u) (exact; no normalisation, no m_ref)."""
        half = 0.5 / (1.0 + 0.25 * ca.sumsqr(col))
        k2 = half + half            # exactly 1/x, kept a product (as in predict_expr)
        s, d = [], []
        for u in (z0[0:3], z0[3:6]):
            a = ca.cross(col, u)
            s.append(k2 * ca.cross(col, a))
            d.append((-2.0 * k2) * a)
        return ca.vertcat(*s), ca.vertcat(*d)

    def sigma_point_expr(self, point, m_ref, z0):
        """sigma_set = simplex: one point's attitude part χ (sigma_setup), normalised and mapped
        through h, as its deviation from the centre h(χ) - z₀."""
        return measurement(normalize(point), m_ref) - z0

    def residual_and_r(self, zhat, f, m, scale, recover=None, span=None, gate_w=None, aided=None):
        """ε = z - ẑ and the adaptive per-axis R (both sigma sets); recovering from a clipped gyro
        sample (recover = 1) R is not adapted: the large residual is the attitude's error. With
        span (product, sensors at their own rates) the accelerometer's rows add its white noise
        as a density, sigma_acc_density² / s_a (s_a: the time its sample stands for). gate_w (the
        accelerometer gate's weight, gate_weight_expr): the accelerometer rows over it."""
        p = self.params
        z = ca.vertcat(normalize(f), normalize(m))
        eps = z - zhat
        sa2, sm2 = p["sigma_acc"] ** 2, p["sigma_mag"] ** 2
        adapt = [p["k_a"] * eps[i] ** 2 for i in range(3)] + [p["k_m"] * eps[i] ** 2 for i in range(3, 6)]
        if p["adapt_max"] > 0:        # product option: bound the inflation (0 = as the paper, unbounded)
            adapt = [ca.fmin(x, p["adapt_max"]) for x in adapt]
        if recover is not None:
            adapt = [ca.if_else(recover, 0.0, x) for x in adapt]
        R = [sa2 + adapt[i] for i in range(3)] + [sm2 + adapt[i] for i in range(3, 6)]
        if scale is not None:
            R = [R[i] * scale[0] for i in range(3)] + [R[i] * scale[1] for i in range(3, 6)]
        d = p["sigma_acc_density"]
        if span is not None and self.density_split():
            # no GPS compensation (aided false, or no GPS input): sigma_acc_density_unaided
            du = p["sigma_acc_density_unaided"]
            d2 = du ** 2 if aided is None else ca.if_else(aided, d ** 2, du ** 2)
            R = [R[i] + d2 / ca.fmax(span[0], use(SPAN_MIN)) for i in range(3)] + R[3:]
        elif span is not None and not (isinstance(d, (int, float)) and d == 0):
            R = [R[i] + d ** 2 / ca.fmax(span[0], use(SPAN_MIN)) for i in range(3)] + R[3:]
        dm = p["sigma_mag_density"]
        if span is not None and not (isinstance(dm, (int, float)) and dm == 0):
            R = R[:3] + [R[i] + dm ** 2 / ca.fmax(span[1], use(SPAN_MIN)) for i in range(3, 6)]
        if gate_w is not None:        # the accelerometer gate: its rows of R over the gate's weight
            R = [R[i] / gate_w for i in range(3)] + R[3:]
        return eps, R

    def innovation_simplex_expr(self, z0, zdev, f, m, scale=None, span=None):
        """sigma_set = simplex: ẑ, residual, R, P_zz and D from the 5 points' deviations e_i
        (sigma_point_expr; zero for the centre and the bias columns' points). With w the
        weight of a simplex point: ẑ = z₀ + δ, δ = w Σ e_i; P_zz = w Σ e_i e_iᵀ + c_dd δδᵀ + R
        (as innovation_expr); P_xz = w Σ_i V t_i e_iᵀ = w V Dᵀ with D[:, k] = Σ_i t_i[k] e_i =
        (k + 1) e_{k+2} - Σ_{i <= k+1} e_i (prefix sums; the bias points' ±a L cancel, as do
        the Σ t_i = 0 with δ), so gain and correct are those of the symmetric set with w."""
        _, _, w, c_dd = self.ut()
        E = [zdev[6 * i:6 * i + 6] for i in range(N + 1)]
        T = [E[0]]
        for i in range(1, N + 1):
            T.append(T[-1] + E[i])
        delta = w * T[N]
        eps, R = self.residual_and_r(z0 + delta, f, m, scale, span=span)
        D = [E[1] - T[0]] + [(k + 1) * E[k + 1] - T[k] for k in range(1, N)]
        Pzz = ca.SX.zeros(6, 6)
        for r, c in _LOWER6:
            zz = sum([E[i][r] * E[i][c] for i in range(1, N + 1)], E[0][r] * E[0][c])
            Pzz[r, c] = w * zz + c_dd * delta[r] * delta[c] + (R[r] if r == c else 0.0)
            Pzz[c, r] = Pzz[r, c]
        return Pzz, eps, ca.vertcat(*R), ca.vertcat(*D)

    def innovation_expr(self, z0, zsum, zdiff, f, m, scale=None, recover=None, span=None, gate_w=None, aided=None):
        """ẑ, residual, adaptive R and P_zz from the sigma pairs' deviations (sigma_pair_expr:
        s_j = e_j+ + e_j-, d_j = e_j+ - e_j- for the 4 columns of aL; e_i = z_i - z₀, zero for
        the centre and for the 2(n-4) points of the bias columns). Exact rewrites of the sums of
        the equations:
        - Σ Wm = 1, so ẑ = z₀ + δ with δ = Wi Σ_i e_i = Wi Σ_j s_j.
        - Σ Wc_i (z_i - ẑ)(z_i - ẑ)ᵀ = Σ Wc_i (e_i - δ)(e_i - δ)ᵀ = Wi Σ e_i e_iᵀ + (ΣWc - 2) δδᵀ,
          because Σ Wc_i e_i = Wi Σ e_i = δ (Wc_i = Wm_i = Wi for i ≥ 1, e₀ = 0);
          ΣWc - 2 = β - α² (1 at the defaults), and e₊e₊ᵀ + e₋e₋ᵀ = (s sᵀ + d dᵀ)/2.
        (P_xz = Wi Σ_j aL[:, j] d_jᵀ is never formed: see gain_expr. The step masks an unusable
        sensor out exactly afterwards: identity block in P_zz, zero rows of d (so zero
        cross-covariance), residual and R, so its columns of K are exactly zero; the reference
        does the same.)
        scale (product, sensors at their own rates): [dt/s_a, dt/s_m], R of each sensor times
        the ratio of the step to the time its sample stands for (sigma is per IMU step; a
        sample standing for k steps carries k steps' information)."""
        _, _, wi, c_dd = self.ut()           # c_dd = Σ Wc - 2
        na = self.na
        S = [zsum[6 * j:6 * j + 6] for j in range(na)]
        D = [zdiff[6 * j:6 * j + 6] for j in range(na)]
        delta = wi * sum(S[1:], S[0])
        eps, R = self.residual_and_r(z0 + delta, f, m, scale, recover, span, gate_w, aided)
        Pzz = ca.SX.zeros(6, 6)
        for r, c in _LOWER6:     # symmetric: lower triangle once, mirrored
            zz = sum([S[j][r] * S[j][c] + D[j][r] * D[j][c] for j in range(1, na)], S[0][r] * S[0][c] + D[0][r] * D[0][c])
            Pzz[r, c] = (0.5 * wi) * zz + c_dd * delta[r] * delta[c] + (R[r] if r == c else 0.0)
            Pzz[c, r] = Pzz[r, c]
        return Pzz, eps, ca.vertcat(*R)

    def gain_expr(self, Pzz, zdiff, eps):
        """The update without forming K, P_xz or U, through L = chol(P_zz), and the smallest
        pivot of P_zz. With χ - x⁻ = ±a L[:, j], P_xz = Wi Σ_j aL[:, j] d_jᵀ = Wi aL Dᵀ
        (D = [d_0 .. d_3], 6 x 4; the bias columns cancel), so with W = L⁻¹ D (the forward
        substitution on D's 4 columns) and v = L⁻¹ ε:
          K ε = P_xz P_zz⁻¹ ε = Wi aL Wᵀ v = aL g,          g = Wi Wᵀ v      (4)
          K P_zz Kᵀ = Wi² aL Wᵀ W aLᵀ = aL G aLᵀ,          G = Wi² Wᵀ W     (4 x 4)
        g and G (its lower triangle, packed) are this kernel's outputs (see correct_expr)."""
        p = self.params
        wi = self.ut()[2]            # the weight of an attitude point (Wi; simplex: w)
        Lz, inv, piv_zz = linalg.cholesky_with_inverse(Pzz, p["pivot_min"])
        na = self.na
        W = linalg.solve_lower(Lz, ca.reshape(zdiff, 6, na), inv)
        v = linalg.solve_lower(Lz, eps, inv)
        g = wi * ca.mtimes(W.T, v)
        G = ca.SX.zeros(na, na)
        for r, c in linalg.packed_lower_pairs(na):
            G[r, c] = (wi * wi) * ca.dot(W[:, r], W[:, c])
            G[c, r] = G[r, c]
        return g, linalg.pack_lower(G), piv_zz

    def correct_expr(self, xm, Pm, aL, g, G):
        """x⁺ = x⁻ + K ε = x⁻ + aL g (q normalised) and P⁺ = P⁻ - K P_zz Kᵀ = P⁻ - aL G aLᵀ on
        its lower triangle (gain_expr), the top of aL lower triangular (aL[r, j] = 0 for
        j > r): H = aL G, then P⁺[r, c] = P⁻[r, c] - H[r, :] aL[c, :]ᵀ."""
        n, na = self.n, self.na
        nz = lambda r: range(min(r, na - 1) + 1)      # noqa: E731  the j with aL[r, j] != 0
        x_new = ca.vertcat(*[sum([aL[r, j] * g[j] for j in nz(r)][1:], aL[r, 0] * g[0]) for r in range(n)])
        if self.err:
            # x_new = [d; δb] = K ε: q⁺ = q⁻ ⊗ δq(d) = (q⁻ + Ξ(q⁻) d / 2) normalised, b⁺ = b⁻ + δb
            q_new = ca.vertcat(normalize(xm[:4] + ca.mtimes(xi_matrix(xm[:4]), 0.5 * x_new[:3])), xm[4:] + x_new[3:])
        else:
            x_new = xm + x_new
            q_new = normalize(x_new) if n == 4 else ca.vertcat(normalize(x_new[:4]), x_new[4:])
        H = [[sum([aL[r, j] * G[j, k] for j in nz(r)][1:], aL[r, 0] * G[0, k]) for k in range(na)] for r in range(n)]
        P_new = ca.SX.zeros(n, n)
        for r, c in linalg.packed_lower_pairs(n):
            P_new[r, c] = Pm[r, c] - sum([H[r][k] * aL[c, k] for k in nz(c)][1:], H[r][0] * aL[c, 0])
            P_new[c, r] = P_new[r, c]
        return q_new, P_new

    def kernels(self):
        p = self.params
        n, na, nx = self.n, self.na, self.nx
        xs = "q" if nx == 4 else "x"
        if nx == 7:          # the state's q and gyro_bias as they are (no copy into one x)
            q_in = {"q": ca.SX.sym("q", 4), "gyro_bias": ca.SX.sym("gyro_bias", 3)}
            q = ca.vertcat(q_in["q"], q_in["gyro_bias"])
        else:
            q = ca.SX.sym(xs, nx)
            q_in = {xs: q}
        P = ca.SX.sym("P", n, n)
        w = ca.SX.sym("gyro", 3)
        dt = ca.SX.sym("dt")
        f = ca.SX.sym("accel", 3)
        m = ca.SX.sym("mag", 3)
        m_ref = ca.SX.sym("m_ref", 3)
        qm = ca.SX.sym(xs + "_pred", nx)
        Pm_packed = ca.SX.sym("P_pred", n * (n + 1) // 2)     # lower triangle, packed (linalg)
        Pm = linalg.unpack_symmetric(Pm_packed, n)

        qm_e, qn_e, Pm_e = self.predict_expr(q, P, w, dt)
        clip = ca.SX.sym("clip")               # a gyro component at gyro_full_scale (error state)
        if self.err:
            # the rotation the clipped sample missed: up to one full scale's worth over the step,
            # on each attitude-error axis (d is the rotation angle to first order)
            wc2 = (p["gyro_full_scale"] * dt) ** 2
            for i in range(3):
                Pm_e[i, i] = Pm_e[i, i] + ca.if_else(clip, wc2, 0.0)
        qn = ca.SX.sym("q_pred_unit", 4)
        a_lp = ca.SX.sym("accel_lp", 3)
        restart = ca.SX.sym("restart")
        f_n = quat.rotate(qn, f)
        recover = ca.SX.sym("recover")        # recovering from a clipped gyro sample (error state)
        start = ca.logic_or(restart, recover) if self.err else restart     # (recovering: the sample itself)
        lp_time = ca.SX.sym("lp_time")
        m_comp = ca.SX.sym("m_comp")           # the GPS motion compensation runs (gps_lowpass)
        gate_in, gate_out, weight = {}, {}, None
        if self.gate():
            gyro_in, bias_in, a_short = ca.SX.sym("gyro", 3), ca.SX.sym("gyro_bias", 3), ca.SX.sym("accel_short", 3)
            # no gate where the low-pass starts at the sample, nor while the GPS removes the motion
            off = ca.logic_or(start, m_comp) if self.gps else start
            weight, s_new = self.gate_weight_expr(ca.if_else(start, f_n, a_short), a_lp, f_n, dt, gyro_in, bias_in, off)
            gate_in = {"gyro": gyro_in, "gyro_bias": bias_in, "accel_short": a_short}
            gate_out = {"accel_short_new": s_new, "gate_w": weight}
        a_lp_new, lp_time_new = self.accel_lowpass_expr(a_lp, f_n, lp_time, dt, restart, start,
                                                        m_comp if self.gps else None)
        lp_in = {"q_pred_unit": qn, "accel": f, "accel_lp": a_lp, "lp_time": lp_time, "restart": restart, "dt": dt,
                 **({"recover": recover} if self.err else {})}
        lp_out = {"accel_lp_new": a_lp_new, "lp_time_new": lp_time_new, "accel_body": quat.rotate_inv(qn, a_lp_new)}
        lp_doc = ("NED low-pass of the specific force R(q-) f (restart: start at R(q-) f; accel_lp_warm: the "
                  "running mean of its samples until it has averaged accel_tau"
                  + (", accel_tau_unaided while no GPS compensation runs" if self.unaided() else "")
                  + "); the update measures R(q-)^T of it (recovering from a clipped gyro sample: the sample itself)")
        if self.gps:
            vel = ca.SX.sym("gps_vel", 3)
            v_lp = ca.SX.sym("v_lp", 3)
            v_ins = ca.SX.sym("v_ins", 3)
            new_gps = ca.SX.sym("new_gps")
            # the velocity's low-pass gain: that of the specific force (1 when it restarts at R f)
            alpha = ca.if_else(start, 1, dt / (use(p["accel_tau"]) + dt))
            vi_new, v_new, up = aiding.gps_lowpass(a_lp_new, f_n, vel, v_lp, v_ins, alpha, dt, p["accel_tau"],
                                                   new_gps, m_comp, G0)
            lp_in.update({"gps_vel": vel, "new_gps": new_gps, "m_comp": m_comp, "v_lp": v_lp, "v_ins": v_ins})
            lp_out = {"accel_lp_new": a_lp_new, "lp_time_new": lp_time_new, "accel_body": quat.rotate_inv(qn, up),
                      "v_lp_new": v_new,
                      "v_ins_new": vi_new}
            lp_doc = lp_doc.replace("measures R(q-)^T of it", "measures R(q-)^T of it less the GPS velocity's "
                                    "low-passed derivative (v_ins - v_lp)/accel_tau (m_comp; v through the same "
                                    "low-pass, carried by R f + g between GPS samples)")
        if self.gate():
            lp_in.update(gate_in)
            lp_out.update(gate_out)
            lp_doc += ("; accel_gate: the short NED mean accel_short and the gate's weight gate_w from its tilt "
                       "(1 unless the gyro is slow and no GPS compensation runs; the update divides R's "
                       "accelerometer rows by it)")
        Pzz_packed = ca.SX.sym("P_zz", 21)        # lower triangle, packed (linalg)
        Pzz = linalg.unpack_symmetric(Pzz_packed, 6)
        eps = ca.SX.sym("residual", 6)
        span = ca.SX.sym("span", 2)            # time each sample stands for: accel, mag
        rated = self.own_rates()
        aL = ca.SX.sym("aL", n, na)
        z0 = ca.SX.sym("z0", 6)
        simplex = self.simplex()
        setup_out = self.sigma_setup_expr(qn, Pm, m_ref, qm)
        aL_e, z0_e, piv_p = setup_out[:3]
        q4 = ca.SX.sym("q_pred", 4)
        qf = ca.SX.sym("q_new", 4)
        col = ca.SX.sym("col", na)
        zsum = ca.SX.sym("zsum", 6 * na)
        zdiff = ca.SX.sym("zdiff", 6 * na)
        zdev = ca.SX.sym("zdev", 6 * (N + 1))
        point = ca.SX.sym("point", 4)
        scale = [self.r_scale(dt, span[0]), self.r_scale(dt, span[1])] if rated else None
        sp = span if rated else None
        if simplex:
            Pzz_e, eps_e, r_e, zd_e = self.innovation_simplex_expr(z0, zdev, f, m, scale, sp)
        elif self.err:
            zs_e, zd_e = self.sigma_pair_error_expr(col, z0)
            gate_w = ca.SX.sym("gate_w") if self.gate() else None
            aided = m_comp if self.gps and self.density_split() else None
            Pzz_e, eps_e, r_e = self.innovation_expr(z0, zsum, zdiff, f, m, scale, recover, sp, gate_w, aided)
        else:
            zs_e, zd_e = self.sigma_pair_expr(q4, col, m_ref, z0)
            Pzz_e, eps_e, r_e = self.innovation_expr(z0, zsum, zdiff, f, m, scale, span=sp)
        g = ca.SX.sym("g", na)
        G_packed = ca.SX.sym("G", na * (na + 1) // 2)
        g_e, G_e, piv_zz = self.gain_expr(Pzz, zdiff, eps)
        q_new, P_new = self.correct_expr(qm, Pm, aL, g, linalg.unpack_symmetric(G_packed, na))

        decl = float(p["declination"])
        roll, pitch = attitude.tilt_angles(f)
        yaw = attitude.tilt_compensated_heading(m, roll, pitch, decl)
        q_init = quat.from_euler(roll, pitch, yaw)

        innov_doc = ("predicted measurement, residual, adaptive per-axis R and P_zz from the sigma "
                     "pairs' sums and differences of deviations")
        innov_in = {"z0": z0, "zsum": zsum, "zdiff": zdiff}
        innov_out = {}
        if self.err:
            points = [KernelSpec("sigma_pair", function("sigma_pair", {"col": col, "z0": z0},
                                                        {"zsum": zs_e, "zdiff": zd_e}),
                                 "sigma points q- * dq(+col) and q- * dq(-col) (col = a L[0:3, j], an attitude "
                                 "error), mapped through h, as deviations e+, e- from z0: e+ + e- and e+ - e- "
                                 "(called once per attitude column of aL)")]
        elif not simplex:
            points = [KernelSpec("sigma_pair", function("sigma_pair", {"q_pred": q4, "col": col, "m_ref": m_ref,
                                                                       "z0": z0}, {"zsum": zs_e, "zdiff": zd_e}),
                                 "sigma points q- + col and q- - col, each normalised and mapped through h, as "
                                 "deviations e+, e- from z0: e+ + e- and e+ - e- (called once per column of aL)")]
        else:
            innov_doc = ("predicted measurement, residual, adaptive per-axis R, P_zz and D (zdiff: P_xz = w aL D^T) "
                         "from the simplex points' deviations")
            innov_in = {"z0": z0, "zdev": zdev}
            innov_out = {"zdiff": zd_e}
            points = [KernelSpec("sigma_point", function("sigma_point", {"point": point, "m_ref": m_ref, "z0": z0},
                                                         {"zdev": self.sigma_point_expr(point, m_ref, z0)}),
                                 "sigma point (attitude part), normalised and mapped through h, as its deviation "
                                 "from z0 (called once per simplex point)")]
        specs = [
            KernelSpec("predict", function("predict", {**q_in, "P": P, "gyro": w, "dt": dt,
                                                       **({"clip": clip} if self.err else {})},
                                           {xs + "_pred": qm_e, "q_pred_unit": qn_e,
                                            "P_pred": linalg.pack_lower(Pm_e)}),
                       ("time update of the error state [d; db]: q- = A q = q * dq((w - b) dt), "
                        "P- = F P F^T + Q with F = [[Phi, B], [0, I3]]" if self.err else
                        "linear Kalman time update: q- = A q, P- = A P A^T + Q"), noinline=True, early_writes=True,
                       flags=("clip",) if self.err else ()),
            KernelSpec("sigma_setup", function("sigma_setup", {**({xs + "_pred": qm} if simplex else {}),
                                                               "q_pred_unit": qn, "P_pred": Pm_packed, "m_ref": m_ref},
                                               {"aL": aL_e, "z0": z0_e, "pivot_P": piv_p,
                                                **({"points": setup_out[3]} if simplex else {})}),
                       ("L = chol(P-), aL = L[:, 0:4] diag(c) (the columns that move the attitude), the 5 "
                        "simplex points' attitude parts q- + aL[0:4, :] t_i, z0 = h(q-); pivot_P = smallest "
                        "pivot of P-"
                        if simplex else
                        f"L = chol(P-), aL = a L[:, 0:{na}] (the columns that move the attitude: a bias column "
                        f"moves none, so {2 * na + 1} distinct sigma points), z0 = h(q-); pivot_P = smallest pivot of P-"),
                       noinline=True, early_writes=True),
            *points,
            KernelSpec("innovation", function("innovation", {**innov_in, "accel": f, "mag": m,
                                                             **({"dt": dt, "span": span} if rated else {}),
                                                             **({"recover": recover} if self.err else {}),
                                                             **({"gate_w": gate_w} if self.gate() else {}),
                                                             **({"m_comp": m_comp} if self.gps and self.density_split()
                                                                else {})},
                                              {"P_zz": linalg.pack_lower(Pzz_e), "residual": eps_e, "r_diag": r_e,
                                               **innov_out}),
                       innov_doc, noinline=True, early_writes=True,
                       flags=(("recover",) if self.err else ()) + (("m_comp",) if self.gps and self.density_split() else ())),
            KernelSpec("gain", function("gain", {"P_zz": Pzz_packed, "zdiff": zdiff, "residual": eps},
                                        {"g": g_e, "G": G_e, "pivot_zz": piv_zz}),
                       "with L = chol(P_zz), W = L^-1 D (D the pairs' differences) and v = L^-1 eps: "
                       "g = Wi W^T v and G = Wi^2 W^T W (lower triangle, packed), so that K eps = aL g and "
                       "K P_zz K^T = aL G aL^T (K, P_xz never formed); pivot_zz = smallest pivot of P_zz",
                       noinline=True),
            KernelSpec("correct", function("correct", {xs + "_pred": qm, "P_pred": Pm_packed, "aL": aL, "g": g,
                                                       "G": G_packed},
                                           {xs + "_new": q_new, "P_new": linalg.pack_lower(P_new)}),
                       ("[d; db] = aL g = K eps, q+ = q- * [1, d/2] normalised, b+ = b- + db, "
                        if self.err else "x+ = x- + aL g = x- + K eps (q normalised), ")
                       + "P+ = P- - aL G aL^T = P- - K P_zz K^T",
                       noinline=True, early_writes=True),
            *([KernelSpec("accel_lowpass", function("accel_lowpass", lp_in, lp_out), lp_doc,
                          flags=(("restart", "recover") if self.err else ("restart",))
                          + (("new_gps", "m_comp") if self.gps else ()))]
              if self.lowpass() else []),
            *([KernelSpec("accel_lp_follow", function(
                "accel_lp_follow", {"q_pred": q4, "q_new": qf, "accel_lp": a_lp},
                {"accel_lp_new": quat.rotate(qf, quat.rotate_inv(normalize(q4), a_lp))}),
                "the NED low-pass turned with the update's correction: R(q+) R(q-)^T accel_lp (q- "
                "normalised here), so the correction is not undone by what the low-pass holds")]
              if self.follow() else []),
            *([self.gyro_recovery_kernel()] if self.err else []),
            KernelSpec("init_q", function("init_q", {"accel": f, "mag": m}, {"q": q_init}),
                       "initial attitude: accelerometer tilt and tilt-compensated heading (+ declination)"),
        ]
        if p["mag_ref"] == "learn" or self.hard_iron():
            g = ca.SX.sym("gyro", 3)
            fn = ca.sqrt(ca.sumsqr(f))
            rest = ca.logic_and(ca.sumsqr(g) < p["rest_gyro_max"] ** 2, ca.fabs(fn - use(G0)) < p["rest_accel_tol"])
            sin_dip = -ca.dot(f, m) / (fn * ca.sqrt(ca.sumsqr(m)))
            ssum = ca.SX.sym("learn_sum")
            cnt = ca.SX.sym("count")
            s_i = ca.fmin(ca.fmax(ssum / cnt, -1.0), 1.0)
            c_i = ca.sqrt(ca.fmax(1 - s_i * s_i, 0.0))
            m_learn = ca.vertcat(c_i * math.cos(decl), c_i * math.sin(decl), s_i)
            specs += [
                KernelSpec("learn_sample", function("learn_sample", {"gyro": g, "accel": f, "mag": m},
                                                    {"rest": rest, "sin_dip": sin_dip,
                                                     **({"norm": ca.sqrt(ca.sumsqr(m))} if self.hard_iron() else {})}),
                           "rest test and sin(inclination) = -f.m/(|f||m|) of one sample"
                           + (", and |m|" if self.hard_iron() else ""), flags=("rest",)),
                KernelSpec("learn_finish", function("learn_finish", {"learn_sum": ssum, "count": cnt},
                                                    {"m_ref": m_learn}),
                           "reference field from the mean sin(inclination) and the declination"),
            ]
            if self.hard_iron():
                specs.append(self.hard_iron_kernel(refine=p["mag_norm_tol"], dip_angle=False, noinline=True))
        return specs

    def step_paths(self):
        first = ["gyro_recovery", "predict"] if self.err else ["predict"]
        return {
            "accel+mag update": first + ["sigma_setup"]
            + (["sigma_point"] * (N + 1) if self.simplex() else ["sigma_pair"] * self.na) + ["innovation", "gain", "correct"],
            "gyro only": first,
        }

    def template_context(self):
        n = self.n
        return {"recovery": self.err, "learn": self.params["mag_ref"] == "learn", "hard_iron": self.hard_iron(), "n": n, "nx": self.nx, "na": self.na, "err": self.err, "lowpass": self.lowpass(), "follow": self.follow(), "gps": self.gps, "gps_age_max": GPS_AGE_MAX, "rated": self.own_rates(), "bias": self.nx == 7, "simplex": self.simplex(), "xs": "q" if self.nx == 4 else "x", "at": self.work_layout(),
                "packed": linalg.packed_lower_pairs(n),
                "gyro_quiet": self.gyro_recovery_quiet() if self.err else [], "gate": self.gate(), "split": self.gps and self.density_split()}
