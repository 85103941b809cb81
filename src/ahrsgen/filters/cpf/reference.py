"""NumPy reference of the complementary + particle filter (CPF).

Source: seeds/004_5402b586fce53e2b.txt (Xu, Zhao, Luo 2021, "attitude data fusion for MEMS
sensor components based on a complementary-particle filter") and SPEC.md, section CPF.
Written from the equations, independently of the CasADi model (it never evaluates it); it
shares with the generated C only the PRNG's definition (prng.py, the same integer stream) and
the order in which random numbers are drawn, so that both runs can be compared sample by
sample.

One step (dt > 0, gyro rate ω over the last interval):

1. Accelerometer/magnetometer angles (section 1.1, SPEC conventions):
   φ_a = atan2(−f_y, −f_z), θ_a = atan2(f_x, √(f_y² + f_z²)),
   ψ_m = wrap(atan2(−Y_h, X_h) + declination), X_h = m_x cθ + m_y sθ sφ + m_z sθ cφ,
   Y_h = m_y cφ − m_z sφ, tilt-compensated with (φ_a, θ_a) (with the gyro-predicted roll and
   pitch when the accelerometer is not usable this step).
2. Gyro prediction, eq. 11: q_g = normalise((I + dt/2 Ω(ω)) q_cf) of the complementary
   filter's own previous output q_cf (the paper's cascade: complementary filter first, then
   the particle filter on its output); (φ_g, θ_g, ψ_g) = euler(q_g).
3. Complementary mix, eqs. 7-8, through wrapped differences:
   a = wrap(a_g + (1 − k)·wrap(a_am − a_g)), k = τ/(τ + dt); roll and pitch only when the
   accelerometer is usable, yaw only when the magnetometer is; q_cf = from_euler(φ, θ, ψ)
   (q_cf = q_g when neither sensor is usable).
4. Particle filter, section 2.2, on the quaternion (N particles):
   - prediction, eq. 11 with process noise, each rotation axis random-walking by
     σ_p √dt per step:
     default: x_i ← normalise((I + ½ Ω(ω dt + σ_p √dt · n_i)) x_i), n_i three standard normals
     (ziggurat, prng.py): the noise is a rotation vector added to the gyro increment, i.e. a
     perturbation in the tangent space of the unit quaternion;
     faithful: x_i ← normalise((I + dt/2 Ω(ω)) x_i + σ_p √dt / 2 · n_i), n_i four standard
     normals - the paper's additive quaternion noise W_k of eq. 9;
   - observation Y = q_cf (eq. 12, H = I); in mode "particle" Y = from_euler(φ_a, θ_a, ψ_m)
     (needs both sensors);
   - q ≡ −q: each particle is replaced by −x_i where ⟨x_i, Y⟩ < 0 (⟨x_i, q_prev⟩ < 0 in a
     step without an observation), so every particle lies in the reference's hemisphere;
   - likelihood with V ~ N(0, (σ_o/2)² I₄) and q ≡ −q: |Y − x|² taken with the nearer sign
     is 2(1 − |⟨Y, x⟩|), so p(Y|x) ∝ exp(−4(1 − |⟨Y, x⟩|)/σ_o²);
     w_i ← w_i · exp(4(|⟨Y, x_i⟩| − c_max)/σ_o²), c_max = max_i |⟨Y, x_i⟩| (eq. 13; the
     constant factor exp(4(c_max − 1)/σ_o²) cancels in the normalisation and keeps the best
     particle's factor at 1, so the exponential alone cannot underflow every weight);
   - normalisation, eq. 14, deferred: the weights are kept unnormalised with their sum S
     (weight_sum), which the update only decreases; if the new sum is not >= 2⁻²⁰ the weights
     are normalised in place (so S stays in [2⁻²⁰, 1]), and if it is not > 0 (all weights
     underflowed, or a corrupted state) they are reset to 1/N and status bit WEIGHTS_RESET is
     set;
   - estimate, eq. 15: q = normalise(Σ w_i x_i) of the aligned particles; kept if
     |Σ w_i x_i|² ≤ 1e-30 S²;
   - systematic resampling: every step in faithful mode, else when ESS = S²/Σw_i² < ess_threshold·N;
     only on steps that had an observation; positions (j + u)·S/N against the cumulative
     weights, i.e. (j + u)/N of the normalised ones; then w_i = 1/N, S = 1.
   Mode "complementary" stops after step 3 (q = q_cf, no particles, no random numbers).

Initialisation (section 1.2: the initial quaternion from the accelerometer and magnetometer
angles): the first step with a usable accelerometer sets q = q_cf = from_euler(φ_a, θ_a, ψ_m)
(ψ = 0 if the magnetometer is not usable) and draws the particles
x_i = normalise(q0 + init_spread/2 · n_i), w_i = 1/N; that step's gyro sample is not used. Until
then a step returns NOT_INITIALISED and changes nothing but the status.

Random numbers are drawn in this order, always: at initialisation, particle by particle, 4
normals each; each prediction, particle by particle, 3 normals each (4 in faithful mode); each
resampling, one uniform (u in (0, 1], positions (j + u)/N).
"""
from __future__ import annotations

import math
import tomllib
from pathlib import Path
import numpy as np


from ahrsgen.codegen import input_checks
from ahrsgen import status as st
from ahrsgen.constants import Const
from ahrsgen.filters.cpf.prng import Xoroshiro64ss

# Filter status bits (from FILTER_BASE upward; the C header defines the same values)
WEIGHTS_RESET = st.FILTER_BASE << 0     # weights summed to zero (underflow): reset to uniform
NOT_INITIALISED = st.FILTER_BASE << 1   # no usable accelerometer sample yet: nothing done

FILTER_STATUS = [
    ("WEIGHTS_RESET", WEIGHTS_RESET,
     "particle weights summed to zero (underflow or corrupted state): reset to 1/N"),
    ("NOT_INITIALISED", NOT_INITIALISED,
     "no usable accelerometer sample yet to initialise from; state unchanged"),
]

MODES = ("combined", "complementary", "particle")
# The weights are kept unnormalised with their sum (eq. 14 deferred to their next use); an
# update whose weights sum to less than this normalises them in place.
WEIGHT_SUM_MIN = Const("WEIGHT_SUM_MIN", 2.0 ** -20)
TWO_PI = 2.0 * math.pi


def default_params() -> dict:
    """Every parameter's default: the common input-check parameters, then defaults.toml."""
    from ahrsgen.codegen.model import COMMON_PARAMS
    with open(Path(__file__).with_name("defaults.toml"), "rb") as fh:
        data = tomllib.load(fh)
    out = {}
    for key in [None, *data["filter"].get("sensors", [])]:
        out.update({p.name: p.default for p in COMMON_PARAMS.get(key, [])})
    for name, spec in data["params"].items():
        out[name] = spec.get("default", out.get(name))
    return out


# ---- scalar helpers (the same formulas as the SPEC; plain floats, no CasADi) -----------------

def wrap(a: float) -> float:
    """Wrap to (-pi, pi]."""
    return a + TWO_PI * math.floor((math.pi - a) / TWO_PI)


def tilt(f) -> tuple[float, float]:
    fx, fy, fz = f
    return math.atan2(-fy, -fz), math.atan2(fx, math.sqrt(fy * fy + fz * fz))


def heading(m, roll: float, pitch: float, declination: float) -> float:
    mx, my, mz = m
    sr, cr = math.sin(roll), math.cos(roll)
    sp, cp = math.sin(pitch), math.cos(pitch)
    xh = mx * cp + my * sp * sr + mz * sp * cr
    yh = my * cr - mz * sr
    return wrap(math.atan2(-yh, xh) + declination)


def euler(q) -> tuple[float, float, float]:
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(min(max(2 * (w * y - x * z), -1.0), 1.0))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def from_euler(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return np.array([cy * cp * cr + sy * sp * sr,
                     cy * cp * sr - sy * sp * cr,
                     cy * sp * cr + sy * cp * sr,
                     sy * cp * cr - cy * sp * sr])


def transition(w, dt: float) -> np.ndarray:
    """Eq. 11: I + dt/2 Ω(ω), acting on scalar-first column quaternions (q ⊗ [0, ω] form)."""
    h = 0.5 * dt
    wx, wy, wz = (h * w[0], h * w[1], h * w[2])
    return np.array([[1.0, -wx, -wy, -wz],
                     [wx, 1.0, wz, -wy],
                     [wy, -wz, 1.0, wx],
                     [wz, wy, -wx, 1.0]])


def transitions(theta: np.ndarray) -> np.ndarray:
    """I + ½ Ω(θ) for each rotation vector θ (rows of an (n, 3) array): (n, 4, 4)."""
    n = len(theta)
    tx, ty, tz = (0.5 * theta[:, k] for k in range(3))
    one = np.ones(n)
    return np.stack([np.stack([one, -tx, -ty, -tz], axis=1),
                     np.stack([tx, one, tz, -ty], axis=1),
                     np.stack([ty, -tz, one, tx], axis=1),
                     np.stack([tz, ty, -tx, one], axis=1)], axis=1)


class Reference:
    """Independent NumPy CPF; same status logic and random-number order as the generated C."""

    def __init__(self, params: dict | None = None):
        p = default_params()
        if params:
            unknown = set(params) - set(p)
            if unknown:
                raise KeyError(f"unknown CPF parameters: {sorted(unknown)}")
            p.update(params)
        self.p = p
        self.mode = p["mode"]
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {self.mode!r}")
        self.N = int(p["n_particles"])
        self.rng = Xoroshiro64ss(int(p["seed"]))
        self.q = np.array([1.0, 0.0, 0.0, 0.0])
        self.q_cf = np.array([1.0, 0.0, 0.0, 0.0])
        self.particles = np.zeros((self.N, 4))          # drawn at initialisation
        self.weights = np.full(self.N, 1.0 / self.N)
        self.weight_sum = 1.0
        self.ess = float(self.N)
        self.initialised = False
        self.n_resample = 0

    # -- helpers ------------------------------------------------------------------------------
    def _normals(self, n: int, k: int = 4) -> np.ndarray:
        """n particles' noise, (n, k), drawn particle by particle as the C does."""
        g = self.rng.gauss
        return np.array([g() for _ in range(n * k)]).reshape(n, k)

    # -- the step -----------------------------------------------------------------------------
    def step(self, gyro, accel, mag, gps_vel, valid: int, dt: float) -> int:
        p = self.p
        dt = float(dt)
        c = input_checks.check(p, ("accel", "mag"), gyro, accel, mag, gps_vel, valid, dt)
        if c.refused:
            return c.refused
        w = [float(x) for x in c.gyro]
        f = [float(x) for x in accel]
        m = [float(x) for x in mag]
        acc_ok, mag_ok = c.use_accel, c.use_mag
        status = c.status
        decl = p["declination"]

        if not self.initialised:
            if not acc_ok:
                return status | NOT_INITIALISED
            r_a, p_a = tilt(f)
            y_m = heading(m, r_a, p_a, decl) if mag_ok else 0.0
            q0 = from_euler(r_a, p_a, y_m)
            self.q = q0.copy()
            self.q_cf = q0.copy()
            if self.mode != "complementary":
                s0 = 0.5 * p["init_spread"]
                x = q0[None, :] + s0 * self._normals(self.N)
                self.particles = x / np.linalg.norm(x, axis=1, keepdims=True)
                self.weights = np.full(self.N, 1.0 / self.N)
                self.weight_sum = 1.0
                self.ess = float(self.N)
            self.initialised = True
            return status

        A = transition(w, dt)
        r_a = p_a = y_m = 0.0
        if acc_ok:
            r_a, p_a = tilt(f)

        # ---- complementary filter (eqs. 7, 8, 11) ----
        if self.mode != "particle":
            q_g = A @ self.q_cf
            q_g = q_g / np.linalg.norm(q_g)
            if acc_ok or mag_ok:
                e_g = euler(q_g)
                if mag_ok:
                    rt, pt = (r_a, p_a) if acc_ok else (e_g[0], e_g[1])
                    y_m = heading(m, rt, pt, decl)
                g = dt / (p["tau"] + dt)                  # 1 - k, k = tau / (tau + dt)
                g_rp = g if acc_ok else 0.0
                g_y = g if mag_ok else 0.0
                am = (r_a, p_a, y_m)
                gains = (g_rp, g_rp, g_y)
                ang = [wrap(e_g[i] + gains[i] * wrap(am[i] - e_g[i])) for i in range(3)]
                self.q_cf = from_euler(*ang)
            else:
                self.q_cf = q_g
            if self.mode == "complementary":
                self.q = self.q_cf.copy()
                return status
            have_obs = acc_ok or mag_ok
            Y = self.q_cf
        else:
            have_obs = acc_ok and mag_ok
            if have_obs:
                Y = from_euler(r_a, p_a, heading(m, r_a, p_a, decl))

        # ---- particle filter (section 2.2) ----
        N = self.N
        if p["faithful"]:       # the paper's additive quaternion noise (eq. 9)
            sp = 0.5 * p["process_noise"] * math.sqrt(dt)
            x = self.particles @ A.T + sp * self._normals(N)
        else:                   # a rotation vector per particle, added to the gyro increment
            theta = dt * np.array(w)[None, :] + p["process_noise"] * math.sqrt(dt) * self._normals(N, 3)
            x = np.einsum("nij,nj->ni", transitions(theta), self.particles)
        x = x / np.linalg.norm(x, axis=1, keepdims=True)
        # q ≡ −q: each particle kept in the hemisphere of the observation (of the last estimate
        # without one), so d = ⟨x, Y⟩ >= 0 is |⟨x, Y⟩| and the particles enter the mean as they are
        d = x @ (Y if have_obs else self.q)
        flip = d < 0.0
        x[flip] = -x[flip]
        d = np.where(flip, -d, d)
        self.particles = x
        wts = self.weights
        if have_obs:
            cmax = float(np.max(d))
            gain = 4.0 / (p["obs_noise"] * p["obs_noise"])
            # the weights times the likelihood scaled by its maximum (eq. 13); eq. 14's division
            # by their sum is deferred to where they are used
            wts = self.weights * np.exp(gain * (d - cmax))
            s = float(np.sum(wts))
            if not s >= WEIGHT_SUM_MIN:
                if s > 0.0:
                    wts = wts / s
                else:
                    wts = np.full(N, 1.0 / N)
                    status |= WEIGHTS_RESET
            self.weights = wts
        s = float(np.sum(wts))
        # estimate, eq. 15
        acc = wts @ x
        n2 = float(acc @ acc)
        if n2 > 1e-30 * s * s:
            self.q = acc / math.sqrt(n2)
        self.weight_sum = s
        self.ess = s * s / float(np.sum(wts * wts))
        if have_obs and (p["faithful"] or self.ess < p["ess_threshold"] * N):
            self._resample()
        return status

    def _resample(self):
        """Systematic resampling with the C's tie rule and in-place copy order."""
        N = self.N
        u = self.rng.uniform()
        cum = np.cumsum(self.weights)                    # sequential sums, as the C walks them
        pos = (np.arange(N) + u) * (self.weight_sum / N)   # (j + u)/N of the normalised weights
        idx = np.minimum(np.searchsorted(cum, pos, side="left"), N - 1)   # first c >= u_j
        counts = np.bincount(idx, minlength=N)
        x = self.particles
        d = 0
        for i in range(N):                               # extra copies go to dead slots, in order
            while counts[i] > 1:
                while counts[d] != 0:
                    d += 1
                x[d] = x[i]
                counts[d] = 1
                counts[i] -= 1
        self.weights = np.full(N, 1.0 / N)
        self.weight_sum = 1.0
        self.ess = float(N)
        self.n_resample += 1

    # convenience for tests and reports
    def euler(self) -> np.ndarray:
        return np.array(euler(self.q))


def run(log, params: dict | None = None, return_ref: bool = False):
    """Run the reference over a SensorLog; returns q (N,4), status (N,) [, the Reference]."""
    ref = Reference(params)
    n = len(log)
    qs = np.empty((n, 4))
    sts = np.empty(n, dtype=np.uint32)
    for k in range(n):
        sts[k] = ref.step(log.gyro[k], log.accel[k], log.mag[k], log.gps_vel[k],
                          int(log.valid[k]), float(log.dt[k]))
        qs[k] = ref.q
    if return_ref:
        return qs, sts, ref
    return qs, sts
