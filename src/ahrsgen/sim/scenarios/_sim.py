"""Shared truth -> sensor machinery for every simulated scenario.

A scenario describes its motion as a `Truth`: attitude (body->NED quaternions), NED velocity
and NED acceleration sampled on a fine uniform internal grid (a few ms or finer, starting a
little before t = 0 so that the first gyro sample has a predecessor). `simulate()` samples
that truth at the IMU step times and turns it into a `SensorLog` (src/ahrsgen/sim/log.py):

- gyro[k]: the constant body rate that carries q_true[k-1] to q_true[k] over dt[k], i.e. the
  rotation vector of q_true[k-1]^-1 ⊗ q_true[k] divided by dt[k]. Integrating the noise-free
  gyro with the exact exponential q[k] = q[k-1] ⊗ exp(½ gyro[k] dt[k]) reproduces q_true to
  rounding (~1e-15 rad per step). gyro[0] uses the truth at t[0] - dt[0].
  Plus: white noise, constant bias, optional bias random walk, optional extra disturbance.
- accel = R(q)^T (a_n - g_n) + noise + bias (+ disturbance), g_n = [0, 0, G0].
- mag = R(q)^T m_n + noise (+ disturbance); m_n = B [cos I cos D, cos I sin D, sin I] from
  the inclination I and declination D; the unit vector is meta['mag_ref_ned'].
- gps_vel = v_n + noise, NED.

Noise figures are given as white-noise densities ND (unit/√Hz). The discrete standard
deviation of a sample taken at rate r is sigma = ND * sqrt(r) (r = the sensor's own rate;
equivalently ND / sqrt(dt)). GPS velocity noise is given directly as a per-sample standard
deviation (m/s). The gyro bias random walk is given in rad/s/√s: b[k] = b[k-1] + BRW *
sqrt(dt[k]) * n[k].

Sensors slower than the IMU step (accel, mag, GPS) sample at their own times t_j = j / rate;
each sample is delivered at the first step k with t[k] >= t_j, is the truth *at t_j* (so a
slow sensor carries up to one IMU period of latency, as on a real flight controller), and
sets its valid bit on that step only. Rows without a sample hold the last delivered value
(NaN before the first one). A sensor at the IMU rate or faster samples at t[k] every step.

Options: timestamp jitter (std, s, clipped to ±0.4 period so time stays monotonic), random
dropouts per sensor (the sample is lost: valid bit cleared, row held). All randomness comes
from `numpy.random.default_rng([seed, stream])` with one fixed stream per purpose, so a given
seed and option set always gives the same arrays. `noise=False` makes every sensor value
exact: no white noise, bias, bias walk or random/vibration disturbance (jitter and dropouts
are separate options, off by default, that change only when and whether exact samples
arrive); disturbances that are the point of a scenario (static offsets) have their own switch
in the scenario module.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ahrsgen.sim.log import (G0, VALID_ACCEL, VALID_GPS, VALID_GYRO, VALID_MAG,
                              SensorLog)
from ahrsgen.npquat import qconj, qmul

DEG = np.pi / 180.0
G_NED = np.array([0.0, 0.0, G0])

# fixed RNG stream ids (never renumber: determinism across versions of this file)
_S_GYRO_BIAS, _S_GYRO, _S_GYRO_RW, _S_ACCEL, _S_MAG, _S_GPS, _S_JITTER, _S_DROP = range(8)
_S_SCENARIO = 100   # scenarios draw their own numbers from streams >= 100


def rng(seed: int, stream: int) -> np.random.Generator:
    """The deterministic generator of one purpose (stream) for a seed."""
    return np.random.default_rng([int(seed), int(stream)])


# ---------------------------------------------------------------- vectorised quaternion helpers

def rotvec_of(q):
    """Rotation vectors (...,3) of quaternions (...,4); q and -q give the same (shortest)."""
    q = np.asarray(q, dtype=float)
    q = np.where(q[..., :1] < 0, -q, q)
    v = q[..., 1:]
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    ang = 2.0 * np.arctan2(n, q[..., :1])
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(n > 1e-300, ang / np.where(n > 1e-300, n, 1.0), 2.0)
    return v * scale


def quat_of(r):
    """Quaternions (...,4) of rotation vectors r (...,3) (exact exponential exp(½ r))."""
    r = np.asarray(r, dtype=float)
    a = np.linalg.norm(r, axis=-1, keepdims=True)
    half = 0.5 * a
    # sin(a/2)/a, with its series near 0
    s = np.where(a > 1e-8, np.sin(half) / np.where(a > 1e-8, a, 1.0), 0.5 - a * a / 48.0)
    return np.concatenate([np.cos(half), s * r], axis=-1)


def rotmats(q):
    """(N,3,3) rotation matrices R(q), v_n = R v_b."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def to_body(q, v_n):
    """R(q)^T v_n row by row: (N,4), (N,3) or (3,) -> (N,3)."""
    R = rotmats(q)
    v_n = np.broadcast_to(np.asarray(v_n, dtype=float), (len(R), 3))
    return np.einsum("nji,nj->ni", R, v_n)


def sign_continuous(q):
    """Flip signs so consecutive quaternions have a positive dot product (same rotations)."""
    q = np.array(q, dtype=float)
    d = np.sum(q[1:] * q[:-1], axis=-1)
    flips = np.concatenate([[1.0], np.cumprod(np.where(d < 0, -1.0, 1.0))])
    return q * flips[:, None]


def integrate_body_rate(q0, w_b, h):
    """Attitude on a grid from body rates w_b (M,3) held constant over each step of length h:
    q[i+1] = q[i] ⊗ exp(½ w_b[i] h). Returns (M+1,4)."""
    w_b = np.asarray(w_b, dtype=float)
    q = np.empty((len(w_b) + 1, 4))
    q[0] = q0
    dq = quat_of(w_b * h)
    for i in range(len(w_b)):
        q[i + 1] = qmul(q[i], dq[i])
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def smoothstep(x):
    """C2 quintic ramp 0 -> 1 on x in [0, 1] (clipped outside)."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (10 + x * (-15 + 6 * x))


def smoothstep_d(x):
    """d smoothstep / dx (0 outside [0, 1]); peak 1.875 at x = 0.5."""
    inside = (x > 0) & (x < 1)
    x = np.clip(x, 0.0, 1.0)
    return np.where(inside, 30 * x * x * (1 - x) ** 2, 0.0)


def keyframes(t, times, values, ramp):
    """Piecewise-constant profile with smooth ramps: value[i] holds from times[i] on, reached by a
    quintic ramp of length ramp (scalar or per keyframe) that starts at times[i].
    Returns (value(t), d value/dt (t))."""
    t = np.asarray(t, dtype=float)
    values = np.asarray(values, dtype=float)
    ramps = np.broadcast_to(np.asarray(ramp, dtype=float), (len(times),))
    y = np.full_like(t, values[0])
    dy = np.zeros_like(t)
    for i in range(1, len(times)):
        x = (t - times[i]) / ramps[i]
        step = values[i] - values[i - 1]
        y = y + step * smoothstep(x)
        dy = dy + step * smoothstep_d(x) / ramps[i]
    return y, dy


def cumtrapz(y, h, y0=0.0):
    """Cumulative trapezoidal integral of y (M,...) on a uniform grid of step h, starting at y0."""
    y = np.asarray(y, dtype=float)
    out = np.empty_like(y)
    out[0] = y0
    out[1:] = y0 + np.cumsum(0.5 * h * (y[1:] + y[:-1]), axis=0)
    return out


# ---------------------------------------------------------------- truth

@dataclass
class Truth:
    """Motion on a fine uniform grid t0 + i h: attitude q (M,4) body->NED, NED velocity v_n
    (M,3) m/s and NED acceleration a_n (M,3) m/s^2 (the derivative of v_n). The grid must
    cover [-period, duration] of the log it is sampled into."""
    t0: float
    h: float
    q: np.ndarray
    v_n: np.ndarray
    a_n: np.ndarray

    def __post_init__(self):
        self.q = sign_continuous(np.asarray(self.q, dtype=float))
        self.q /= np.linalg.norm(self.q, axis=1, keepdims=True)
        self.v_n = np.asarray(self.v_n, dtype=float)
        self.a_n = np.asarray(self.a_n, dtype=float)
        m = len(self.q)
        if self.v_n.shape != (m, 3) or self.a_n.shape != (m, 3):
            raise ValueError("Truth: q, v_n, a_n must have the same number of rows")

    @property
    def t_end(self) -> float:
        return self.t0 + self.h * (len(self.q) - 1)

    def at(self, ts):
        """(q, v_n, a_n) at times ts: exact grid samples where ts falls on the grid (to 1e-9 of
        a step), slerp / linear interpolation in between."""
        ts = np.asarray(ts, dtype=float)
        if ts.size and (ts.min() < self.t0 - 1e-9 * self.h or ts.max() > self.t_end + 1e-9 * self.h):
            raise ValueError(f"Truth covers [{self.t0}, {self.t_end}] s, asked for "
                             f"[{ts.min()}, {ts.max()}] s")
        x = (ts - self.t0) / self.h
        i = np.floor(x + 1e-9).astype(int)
        i = np.clip(i, 0, len(self.q) - 2)
        f = x - i
        f = np.where(np.abs(f) < 1e-9, 0.0, f)
        f = np.where(np.abs(f - 1.0) < 1e-9, 1.0, f)
        q0, q1 = self.q[i], self.q[i + 1]
        dq = qmul(qconj(q0), q1)
        q = qmul(q0, quat_of(rotvec_of(dq) * f[:, None]))
        q = np.where((f == 0.0)[:, None], q0, q)
        q = np.where((f == 1.0)[:, None], q1, q)
        v = self.v_n[i] * (1 - f)[:, None] + self.v_n[i + 1] * f[:, None]
        a = self.a_n[i] * (1 - f)[:, None] + self.a_n[i + 1] * f[:, None]
        return q / np.linalg.norm(q, axis=1, keepdims=True), v, a


def static_truth(q, duration: float, period: float) -> Truth:
    """A vehicle at rest at attitude q, on the IMU grid itself (one period before t = 0 to
    one period after the end)."""
    k1 = int(np.ceil(duration / period)) + 2
    m = k1 + 2
    qs = np.tile(np.asarray(q, dtype=float), (m, 1))
    return Truth(-period, period, qs, np.zeros((m, 3)), np.zeros((m, 3)))


def offsets(intervals, t):
    """Sum of constant offsets: intervals = [(t0, t1, (3,)), ...], applied for t0 <= t < t1."""
    t = np.asarray(t, dtype=float)
    out = np.zeros((len(t), 3))
    for t0, t1, off in intervals:
        on = (t >= t0 - 1e-9) & (t < t1 - 1e-9)
        out[on] += np.asarray(off, dtype=float)
    return out


def mag_ref(inclination_deg: float, declination_deg: float) -> np.ndarray:
    """Unit Earth-field direction in NED (inclination positive down, declination east of north)."""
    inc, dec = inclination_deg * DEG, declination_deg * DEG
    return np.array([np.cos(inc) * np.cos(dec), np.cos(inc) * np.sin(dec), np.sin(inc)])


# ---------------------------------------------------------------- sensors

@dataclass
class SensorModel:
    """Sensor error figures. Densities in unit/√Hz (sigma = ND * sqrt(sample rate)).

    gyro_nd rad/s/√Hz; gyro_bias (3,) rad/s constant (None: none); gyro_bias_rw rad/s/√s;
    accel_nd m/s^2/√Hz; accel_bias (3,) m/s^2; mag_nd field-unit/√Hz; mag_bias (3,) field
    unit (hard iron, body frame); gps_sigma (3,) m/s per-sample std (N, E, D)."""
    gyro_nd: float = 0.0
    gyro_bias: np.ndarray | None = None
    gyro_bias_rw: float = 0.0
    accel_nd: float = 0.0
    accel_bias: np.ndarray | None = None
    mag_nd: float = 0.0
    mag_bias: np.ndarray | None = None
    gps_sigma: tuple = (0.0, 0.0, 0.0)

    def as_meta(self) -> dict:
        def lst(x):
            return None if x is None else [float(v) for v in np.ravel(x)]
        return {"gyro_nd_rad_s_rtHz": self.gyro_nd, "gyro_bias_rad_s": lst(self.gyro_bias),
                "gyro_bias_rw_rad_s_rts": self.gyro_bias_rw, "accel_nd_m_s2_rtHz": self.accel_nd,
                "accel_bias_m_s2": lst(self.accel_bias), "mag_nd_per_rtHz": self.mag_nd,
                "mag_bias": lst(self.mag_bias), "gps_sigma_m_s": lst(self.gps_sigma)}


def _schedule(t, rate, imu_rate, duration):
    """For a sensor at `rate`: (fix times (J,), step index of each fix (J,)). At or above the
    IMU rate: one fix per step at t[k]."""
    n = len(t)
    if rate is None or rate >= imu_rate * (1 - 1e-9):
        return t.copy(), np.arange(n)
    tj = np.arange(0.0, t[-1] + 1e-9, 1.0 / rate)
    k = np.searchsorted(t, tj - 1e-9 / imu_rate, side="left")
    keep = k < n
    tj, k = tj[keep], k[keep]
    # two fixes landing on one step (cannot happen below the IMU rate without jitter): keep the last
    last = np.r_[k[1:] != k[:-1], True]
    return tj[last], k[last]


def _deliver(n, steps, values):
    """(N,3) rows holding the last delivered sample (NaN before the first) and (N,) bool mask."""
    out = np.full((n, 3), np.nan)
    have = np.zeros(n, dtype=bool)
    out[steps] = values
    have[steps] = True
    # forward fill
    idx = np.where(have, np.arange(n), -1)
    idx = np.maximum.accumulate(idx)
    filled = np.where((idx >= 0)[:, None], out[np.maximum(idx, 0)], np.nan)
    return filled, have


def simulate(name: str, truth: Truth, *, rate_hz: float, duration: float, seed: int,
             sensors: SensorModel, noise: bool = True, accel_rate: float | None = None,
             mag_rate: float | None = None, gps_rate: float | None = 5.0,
             mag_field: float = 0.5, inclination_deg: float = 50.0, declination_deg: float = 0.0,
             jitter: float = 0.0, dropout: dict | None = None,
             accel_disturbance=None, mag_disturbance=None, gyro_disturbance=None,
             random_disturbances: bool = True, description: str = "",
             settle_time: float = 0.0, meta: dict | None = None, repeat_slow: bool = False) -> SensorLog:
    """Sample `truth` into a SensorLog at `rate_hz` for `duration` s (N = round(duration*rate)
    steps, t[k] = k / rate_hz plus jitter).

    accel_rate / mag_rate: None = every IMU step; gps_rate: None or 0 = no GPS (bit never set).
    dropout: {"gyro"|"accel"|"mag"|"gps": probability of losing each sample}.
    repeat_slow: the accelerometer and magnetometer valid bits are set on every step from their
    first sample on, the rows repeating the last sample (firmware that feeds the latest value
    every IMU step instead of flagging fresh samples); GPS keeps its own valid bit.
    *_disturbance: callable(t (J,), rng) -> (J,3) body-frame additive term, evaluated at that
    sensor's sample times (t[k] for the gyro), rng a scenario stream of the seed. A callable
    wrapped in `Deterministic(...)` is part of the scenario (static offsets) and is always applied;
    a plain callable is a random sensor error (vibration) and is dropped with noise=False or
    random_disturbances=False.
    """
    T = 1.0 / rate_hz
    n = int(round(duration * rate_hz))
    if n < 2:
        raise ValueError("duration too short for one step")
    dropout = dict(dropout or {})
    t = np.arange(n) * T
    if jitter > 0:
        j = rng(seed, _S_JITTER).normal(0.0, jitter, n)
        j = np.clip(j, -0.4 * T, 0.4 * T)
        j[0] = 0.0
        t = t + j
    dt = np.empty(n)
    dt[0] = T
    dt[1:] = np.diff(t)

    # truth at the steps and one nominal period before t[0]
    tt = np.concatenate([[t[0] - T], t])
    q_all, v_all, a_all = truth.at(tt)
    q_all = sign_continuous(q_all)
    q_true = q_all[1:]
    dts = np.concatenate([[T], dt[1:]])
    gyro_true = rotvec_of(qmul(qconj(q_all[:-1]), q_all[1:])) / dts[:, None]

    def keep_dist(d):
        return d is not None and (isinstance(d, Deterministic) or (noise and random_disturbances))

    # gyro
    gyro = gyro_true.copy()
    bias_true = np.zeros((n, 3))
    if noise:
        if sensors.gyro_bias is not None:
            bias_true += np.asarray(sensors.gyro_bias, dtype=float)
        if sensors.gyro_bias_rw > 0:
            steps = rng(seed, _S_GYRO_RW).normal(size=(n, 3)) * sensors.gyro_bias_rw * np.sqrt(dts)[:, None]
            steps[0] = 0.0
            bias_true += np.cumsum(steps, axis=0)
        gyro += bias_true
        gyro += rng(seed, _S_GYRO).normal(size=(n, 3)) * sensors.gyro_nd * np.sqrt(rate_hz)
    if keep_dist(gyro_disturbance):
        gyro += gyro_disturbance(t, rng(seed, _S_SCENARIO + 1))

    # accel
    tj_a, k_a = _schedule(t, accel_rate, rate_hz, duration)
    ra = rate_hz if accel_rate is None else min(accel_rate, rate_hz)
    if accel_rate is None or accel_rate >= rate_hz:
        qa, aa = q_true, a_all[1:]
    else:
        qa, _, aa = truth.at(tj_a)
    acc_v = to_body(qa, aa - G_NED)
    if noise:
        if sensors.accel_bias is not None:
            acc_v += np.asarray(sensors.accel_bias, dtype=float)
        acc_v += rng(seed, _S_ACCEL).normal(size=acc_v.shape) * sensors.accel_nd * np.sqrt(ra)
    if keep_dist(accel_disturbance):
        acc_v += accel_disturbance(tj_a, rng(seed, _S_SCENARIO + 2))

    # mag
    m_unit = mag_ref(inclination_deg, declination_deg)
    m_n = mag_field * m_unit
    tj_m, k_m = _schedule(t, mag_rate, rate_hz, duration)
    rm = rate_hz if mag_rate is None else min(mag_rate, rate_hz)
    qm = q_true if (mag_rate is None or mag_rate >= rate_hz) else truth.at(tj_m)[0]
    mag_v = to_body(qm, m_n)
    if noise:
        if sensors.mag_bias is not None:
            mag_v += np.asarray(sensors.mag_bias, dtype=float)
        mag_v += rng(seed, _S_MAG).normal(size=mag_v.shape) * sensors.mag_nd * np.sqrt(rm)
    if keep_dist(mag_disturbance):
        mag_v += mag_disturbance(tj_m, rng(seed, _S_SCENARIO + 3))

    # GPS (none: the vehicle has no receiver, or flies indoors)
    gps_rate = gps_rate or None
    if gps_rate is not None:
        tj_g, k_g = _schedule(t, gps_rate, rate_hz, duration)
        vg = truth.at(tj_g)[1]
        if noise:
            vg = vg + rng(seed, _S_GPS).normal(size=vg.shape) * np.asarray(sensors.gps_sigma, dtype=float)
    else:
        tj_g, k_g, vg = np.zeros(0), np.zeros(0, dtype=int), np.zeros((0, 3))

    # dropouts (a lost sample is simply not delivered)
    drop_rng = rng(seed, _S_DROP)
    def drop(key, k, *arrays):
        p = float(dropout.get(key, 0.0))
        u = drop_rng.random(len(k))      # always drawn: same stream layout for every option set
        keep = u >= p
        return (k[keep],) + tuple(a[keep] for a in arrays)

    k_a2, acc_d = drop("accel", k_a, acc_v)
    k_m2, mag_d = drop("mag", k_m, mag_v)
    k_g2, gps_d, tj_g2 = drop("gps", k_g, vg, tj_g)
    k_w = np.arange(n)
    k_w2, = drop("gyro", k_w)

    accel, have_a = _deliver(n, k_a2, acc_d)
    mag, have_m = _deliver(n, k_m2, mag_d)
    gps_vel, have_g = _deliver(n, k_g2, gps_d)
    have_w = np.zeros(n, dtype=bool)
    have_w[k_w2] = True

    if repeat_slow:
        have_a = np.all(np.isfinite(accel), axis=1)
        have_m = np.all(np.isfinite(mag), axis=1)
    valid = (np.where(have_w, VALID_GYRO, 0) | np.where(have_a, VALID_ACCEL, 0)
             | np.where(have_m, VALID_MAG, 0) | np.where(have_g, VALID_GPS, 0)).astype(np.uint32)

    md = {
        "description": description,
        "scenario": name,
        "seed": int(seed),
        "noise": bool(noise),
        "duration": float(n * T),
        "n_samples": int(n),
        "rate_hz": float(rate_hz),
        "accel_rate_hz": float(ra),
        "mag_rate_hz": float(rm),
        "gps_rate_hz": None if gps_rate is None else float(gps_rate),
        "gps_period": None if gps_rate is None else 1.0 / float(gps_rate),
        "jitter_s": float(jitter),
        "repeat_slow": bool(repeat_slow),
        "dropout": dropout,
        "settle_time": float(settle_time),
        "mag_ref_ned": m_unit.tolist(),
        "mag_field": float(mag_field),
        "inclination_deg": float(inclination_deg),
        "declination_deg": float(declination_deg),
        "gravity_ned": G_NED.tolist(),
        "sensors": sensors.as_meta() if noise else SensorModel().as_meta(),
        "gyro_bias_true": bias_true[0].tolist(),     # constant part at t[0], rad/s
        # truth arrays (for tests and analysis): true bias per step, NED acceleration / velocity
        # at the step times, GPS fix times of the delivered GPS samples
        "truth": {"gyro_bias": bias_true, "acc_ned": a_all[1:], "vel_ned": v_all[1:],
                  "gyro": gyro_true, "gps_fix_t": tj_g2, "gps_steps": k_g2},
    }
    if meta:
        md.update(meta)
    return SensorLog(name, t, dt, gyro, accel, mag, gps_vel, valid, q_true, md)


class Deterministic:
    """Wraps a disturbance callable(t, rng) that is part of the scenario (kept with noise=False)."""

    def __init__(self, fn):
        self.fn = fn

    def __call__(self, t, r):
        return self.fn(t, r)
