"""Hand-held rotation of one sensor, as recorded (issue 25's calibration and mounting scenarios).

What it reproduces: a user's own IMU whose magnetometer was never calibrated (`iron=True`: a
hard iron of twice the Earth's field plus 10 % soft iron, from the start), or whose board is
mounted rolled 180° (`board_rotation="ROLL_180"`: every sensor reads in a frame turned from the
body's). `calibration=True` gives the log the user records for `ahrsgen calibrate`: the same
sensor, 5 s at rest, then turned slowly through every orientation.

Truth: the `attached_magnet` motion without a magnet: 10 s at rest (level, heading from the
seed), then the amplitudes ramp in over 5 s to hand-held rotation, each Euler angle a sum of
three sinusoids with phases from the seed (roll and pitch within about ±40°, heading ±120°
around a slowly turning centre). No translation. The calibration log tumbles instead: after
5 s at rest, roll, pitch and heading each sweep sinusoidally (±170°, ±80°, a full turn every
14 s), which covers the sphere of field directions.

One sensor flown on every seed: its gyro bias [0.2, -0.15, 0.25] °/s and its iron (raw
magnetometer = W m + h, h = 2 x 50 µT in a fixed direction, W symmetric with 10 % scale and a
few % cross-coupling) are constants of the module, so one calibration serves every seed; the
seed draws the motion's phases and the noise. Rates and noise as `attached_magnet`: IMU and
magnetometer at 285.714 Hz, gyro 0.01 °/s/√Hz, accelerometer 300 µg/√Hz, magnetometer 0.3 µT
per sample on a 50 µT field (inclination 67°, declination 0), in µT. No GPS. Scored from
`settle_time` 20 s. meta['sensor'] gives the iron and the board rotation.
"""
from __future__ import annotations

import numpy as np

from ahrsgen.npquat import q_from_euler
from ahrsgen.sensor_frame import rotation
from ahrsgen.sim.log import G0, SensorLog
from ahrsgen.sim.scenarios import _sim
from ahrsgen.sim.scenarios._sim import DEG

DESCRIPTION = ("hand-held rotation at 286 Hz, 150 s, no GPS, one sensor on every seed; iron=True: an "
               "uncalibrated magnetometer (hard iron 2x the 50 uT field, 10 % soft iron); board_rotation: "
               "the board mounted rotated (e.g. ROLL_180); calibration=True: the sensor's calibration log")

FIELD_UT = 50.0
INCLINATION_DEG = 67.0
REST = 10.0
RAMP = 5.0
SETTLE = 20.0
GYRO_BIAS = np.array([0.2, -0.15, 0.25]) * DEG
# the sensor's iron: raw = SOFT_IRON m + HARD_IRON (uT)
HARD_IRON = 2.0 * FIELD_UT * np.array([0.6, -0.64, 0.48])        # |h| = 2 x the field
SOFT_IRON = np.array([[1.10, 0.04, -0.03],
                      [0.04, 0.92, 0.05],
                      [-0.03, 0.05, 1.00]])


def _angles(t, r):
    env = _sim.smoothstep((t - REST) / RAMP)
    ph = r.uniform(0.0, 2 * np.pi, (3, 3))
    f = np.array([[0.11, 0.23, 0.41], [0.13, 0.19, 0.37], [0.05, 0.09, 0.17]])
    a = np.array([[18.0, 12.0, 6.0], [15.0, 10.0, 5.0], [70.0, 35.0, 15.0]]) * DEG
    out = []
    for i in range(3):
        out.append(env * sum(a[i, j] * np.sin(2 * np.pi * f[i, j] * t + ph[i, j]) for j in range(3)))
    yaw0 = r.uniform(-np.pi, np.pi)
    drift = env * 0.02 * (t - REST) * np.sign(r.uniform(-1, 1))   # slowly turning centre, rad
    return out[0], out[1], yaw0 + drift + out[2]


def _tumble(t, r):
    env = _sim.smoothstep((t - 5.0) / 2.0)
    ph = r.uniform(0.0, 2 * np.pi, 2)
    roll = env * 170.0 * DEG * np.sin(2 * np.pi * 0.043 * t + ph[0])
    pitch = env * 80.0 * DEG * np.sin(2 * np.pi * 0.031 * t + ph[1])
    yaw = env * 2 * np.pi * (t - 5.0) / 14.0
    return roll, pitch, yaw


def truth(duration: float, period: float, r, angles=_angles) -> _sim.Truth:
    """The motion on a grid of at most 1 ms covering [-1 s, duration + 1 s]."""
    m = int(np.ceil(period / 0.001 - 1e-9))
    h = period / m
    k0 = int(np.ceil(1.0 / h))
    k1 = int(np.ceil((duration + 1.0) / h))
    t = np.arange(-k0, k1 + 1) * h
    roll, pitch, yaw = angles(t, r)
    q = q_from_euler(roll, pitch, yaw)
    z = np.zeros((len(t), 3))
    return _sim.Truth(t[0], h, q, z, z.copy())


def make(seed: int = 0, *, rate_hz: float = 285.714, duration: float = 150.0, noise: bool = True,
         iron: bool = False, board_rotation: str = "NONE", calibration: bool = False,
         jitter: float = 0.0, dropout: dict | None = None) -> SensorLog:
    """board_rotation: a PX4-style name (ROLL_180, YAW_90, ...): the sensors read in the frame whose
    sensor -> body rotation `[mounting] sensor_rotation` names. calibration: the tumbling log of
    the same sensor (60 s unless `duration` is given smaller)."""
    M = rotation(board_rotation, "handheld: board_rotation")
    period = 1.0 / rate_hz
    if calibration:
        duration = min(duration, 60.0)
        tr = truth(duration, period, _sim.rng(seed, _sim._S_SCENARIO + 6), _tumble)
    else:
        tr = truth(duration, period, _sim.rng(seed, _sim._S_SCENARIO + 5))
    sensors = _sim.SensorModel(gyro_nd=0.01 * DEG, gyro_bias=GYRO_BIAS, accel_nd=300e-6 * G0,
                               mag_nd=0.3 / np.sqrt(rate_hz))
    log = _sim.simulate(
        "handheld_calibration" if calibration else "handheld", tr, rate_hz=rate_hz, duration=duration,
        seed=seed, sensors=sensors, noise=noise, gps_rate=None, mag_field=FIELD_UT,
        inclination_deg=INCLINATION_DEG, declination_deg=0.0, jitter=jitter, dropout=dropout,
        description=DESCRIPTION, settle_time=min(SETTLE, duration),
        meta={"sensor_class": "hand-held IMU at BROAD's rate (myon aktos-t class figures, ours)",
              "sensor": {"hard_iron_uT": HARD_IRON.tolist() if iron else [0.0] * 3,
                         "soft_iron": SOFT_IRON.tolist() if iron else np.eye(3).tolist(),
                         "board_rotation": board_rotation, "gyro_bias_rad_s": GYRO_BIAS.tolist()},
              "motion": ("tumbling through every orientation after 5 s at rest" if calibration else
                         "roll/pitch within about +-40 deg, heading +-120 deg around a slowly turning "
                         "centre, each a sum of three sinusoids (0.05-0.41 Hz), after 10 s at rest")})
    if iron:                      # raw = W m + h, the noise through the same soft iron
        log.mag = np.asarray(log.mag) @ SOFT_IRON.T + HARD_IRON
    if not np.array_equal(M, np.eye(3)):   # body = M sensor: each row v_s = v_b M (M orthonormal)
        for s in ("gyro", "accel", "mag"):
            setattr(log, s, np.asarray(getattr(log, s)) @ M)
    return log
