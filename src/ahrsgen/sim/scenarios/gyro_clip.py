"""A fast flip that drives the gyro past its range for 0.3 s (issue 26's over-range scenario).

What it reproduces: the pendulum recordings (another sensor, ~90 Hz) where a swing clips the gyro
at about 600 deg/s, and a multirotor's flip. A saturated gyro reports its range, not the rate, so
every estimator integrates less rotation than happened and leaves the clip with an attitude
error of tens of degrees; what matters is how fast it comes back.

Truth: 5 s at rest (level, heading from the seed), then gentle hand-held motion (roll and pitch
within about +-10 deg, heading +-20 deg, below 30 deg/s). At `flip_time` (uniform in [15, 20] s
by the seed) one full turn (360 deg) about a horizontal body axis within 30 deg of the x axis
(a roll flip), with a raised-cosine rate profile whose length is chosen so that the x gyro
stays beyond `gyro_range_deg_s` for `clip_s` seconds (the slower such flip: x rate peaking at
about 580-600 deg/s for the defaults, 14-19 deg of rotation lost for seeds 0-4).
The gentle motion goes on; the log ends 12 s after the flip.

Sensors: IMU and magnetometer at `rate_hz` (200 Hz), gyro 0.01 deg/s/sqrt(Hz) and a constant
bias of 0.1-0.3 deg/s per axis, each axis clipped at +-`gyro_range_deg_s` (500); accelerometer
300 ug/sqrt(Hz); magnetometer 0.3 uT per sample on a 50 uT field (inclination 67 deg, magnetic
north). No GPS.

meta['gyro_full_scale_rad_s'] states the gyro's range: `ahrsgen run`, `validate` and `bench` set
the filters' gyro_full_scale from it, as a user configures the sensor. Scored from 3 s after the
clip ends (`settle_time`): the acceptance is the largest attitude error
from there on (meta['clip'] gives the clip's start and end, the range and the rotation it lost).
"""
from __future__ import annotations

import numpy as np

from ahrsgen.npquat import q_from_euler, qmul
from ahrsgen.sim.log import G0, SensorLog
from ahrsgen.sim.scenarios import _sim
from ahrsgen.sim.scenarios._sim import DEG

DESCRIPTION = ("a roll flip (360 deg, peak ~600 deg/s) that clips the gyro at 500 deg/s for 0.3 s, amid "
               "gentle hand-held motion; 200 Hz IMU and magnetometer, no GPS; scored from 3 s after the clip")

FIELD_UT = 50.0
REST = 5.0
AFTER = 12.0
RECOVER = 3.0
MAX_DURATION_S = 600.0   # the longest log make() writes (a later flip_time, a slower flip: refused)


def flip_length(range_rad_s: float, clip_s: float, axis_x: float) -> float:
    """Length T of a raised-cosine turn of 2 pi whose x rate, 2 pi axis_x (1 - cos 2 pi s) / T,
    stays beyond range_rad_s for clip_s: the slower of the two flips that do (the time beyond the
    range first grows with T, then falls to 0 where the peak rate falls to the range), by
    bisection on that side. A ValueError when no one-turn flip holds the range that long (its
    time beyond the range is at most about half of 2 pi / range)."""
    k = range_rad_s / (2 * np.pi * axis_x)

    def above(T):
        c = k * T                                      # (1 - cos) > c, c in (0, 2)
        if c >= 2.0:
            return 0.0
        return T * (1.0 - np.arccos(1.0 - c) / np.pi)
    grid = np.linspace(1e-4, 2.0 / k, 4001)
    t_peak = float(grid[int(np.argmax([above(T) for T in grid]))])
    if above(t_peak) < clip_s:
        raise ValueError(f"no 360 deg flip keeps this gyro beyond {np.degrees(range_rad_s):.4g} deg/s for "
                         f"clip_s = {clip_s:g} s (at most {above(t_peak):.3g} s here): give a shorter clip_s")
    lo, hi = t_peak, 2.0 / k
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if above(mid) > clip_s else (lo, mid)
    return 0.5 * (lo + hi)


def _flip_angle(t, t0, T):
    s = np.clip((t - t0) / T, 0.0, 1.0)
    return 2 * np.pi * (s - np.sin(2 * np.pi * s) / (2 * np.pi))


def truth(duration, period, r, flip_time, T, axis) -> _sim.Truth:
    m = int(np.ceil(period / 0.001 - 1e-9))
    h = period / m
    k0, k1 = int(np.ceil(1.0 / h)), int(np.ceil((duration + 1.0) / h))
    t = np.arange(-k0, k1 + 1) * h
    env = _sim.smoothstep((t - REST) / 3.0)
    ph = r.uniform(0.0, 2 * np.pi, 3)
    roll = env * 8.0 * DEG * np.sin(2 * np.pi * 0.21 * t + ph[0])
    pitch = env * 7.0 * DEG * np.sin(2 * np.pi * 0.17 * t + ph[1])
    yaw = r.uniform(-np.pi, np.pi) + env * 20.0 * DEG * np.sin(2 * np.pi * 0.07 * t + ph[2])
    phi = _flip_angle(t, flip_time, T)
    q_flip = np.column_stack([np.cos(phi / 2), np.sin(phi / 2)[:, None] * axis[None, :]])
    q = qmul(q_from_euler(roll, pitch, yaw), q_flip)
    z = np.zeros((len(t), 3))
    return _sim.Truth(t[0], h, q, z, z.copy())


def make(seed: int = 0, *, rate_hz: float = 200.0, gyro_range_deg_s: float = 500.0, clip_s: float = 0.3,
         flip_time: float = -1.0, noise: bool = True, jitter: float = 0.0,
         dropout: dict | None = None, range_stated: bool = True) -> SensorLog:
    """flip_time < 0: drawn from the seed in [15, 20] s. clip_s = 0: the same flip slow enough
    that the gyro never clips (its peak rate is then 90 % of the range). range_stated = False:
    the log does not state the gyro's range (a user who left gyro_full_scale at its default;
    the filters must recognise the clip from the data)."""
    r = _sim.rng(seed, _sim._S_SCENARIO)
    tf = r.uniform(15.0, 20.0) if flip_time < 0.0 else float(flip_time)
    a = r.uniform(-30.0, 30.0) * DEG
    axis = np.array([np.cos(a), np.sin(a), 0.0])
    rng_rad = gyro_range_deg_s * DEG
    T = flip_length(rng_rad, clip_s, axis[0]) if clip_s > 0 else 4 * np.pi * axis[0] / (0.9 * rng_rad)
    period = 1.0 / rate_hz
    clip_end = tf + 0.5 * (T + clip_s)
    duration = tf + T + AFTER
    if duration > MAX_DURATION_S:
        raise ValueError(f"the flip ends at {tf + T:.4g} s (flip_time and a {T:.3g} s flip): the log would be "
                         f"{duration:.4g} s long, at most {MAX_DURATION_S:g}")
    tr = truth(duration, period, _sim.rng(seed, _sim._S_SCENARIO + 5), tf, T, axis)
    rb = _sim.rng(seed, _sim._S_GYRO_BIAS)
    bias = rb.uniform(0.1, 0.3, 3) * rb.choice([-1.0, 1.0], 3) * DEG
    sensors = _sim.SensorModel(gyro_nd=0.01 * DEG, gyro_bias=bias, accel_nd=300e-6 * G0,
                               mag_nd=0.3 / np.sqrt(rate_hz))
    log = _sim.simulate(
        "gyro_clip", tr, rate_hz=rate_hz, duration=duration, seed=seed, sensors=sensors, noise=noise,
        gps_rate=None, mag_field=FIELD_UT, inclination_deg=67.0, declination_deg=0.0, jitter=jitter,
        dropout=dropout, description=DESCRIPTION, settle_time=clip_end + RECOVER,
        meta={"sensor_class": "hand-held IMU with a +-500 deg/s gyro (ours)"})
    raw = log.gyro.copy()
    log.gyro = np.clip(log.gyro, -rng_rad, rng_rad)
    clipped = np.any(np.abs(raw) > rng_rad, axis=1)
    lost = float(np.sum(np.abs(raw - log.gyro).max(axis=1) * log.dt)) / DEG
    if range_stated:
        log.meta["gyro_full_scale_rad_s"] = float(rng_rad)     # the sensor's range, as a user configures it
    log.meta["clip"] = {"gyro_range_rad_s": float(rng_rad), "flip_time_s": float(tf), "flip_length_s": float(T),
                        "start_s": float(log.t[clipped][0]) if clipped.any() else None,
                        "end_s": float(log.t[clipped][-1]) if clipped.any() else None,
                        "clipped_steps": int(clipped.sum()), "rotation_lost_deg": lost,
                        "axis_body": axis.tolist()}
    return log
