"""Common part of the two static scenarios after the ADUKF paper (seeds/003_876a2b6ece1f51db.txt).

The paper logged a level, motionless Pixhawk for 120 s and added "constant offsets at certain
time intervals" to the accelerometer (Table 1) or to the magnetometer (Table 2) data; its
figures (and so the offset sizes, intervals and rates) did not survive, so this module fixes
them (see the two scenario modules).

Sensor figures, Pixhawk 1 class (InvenSense MPU-6000 gyro/accelerometer, Honeywell HMC5883L
magnetometer), from their datasheets: gyro rate-noise density 0.005 °/s/√Hz, accelerometer
400 µg/√Hz, magnetometer noise floor 2 mgauss (1σ per sample) on a 0.5 gauss field. The gyro
is taken as calibrated at boot (as PX4 logs it): a residual constant bias of at most 0.05 °/s
per axis, drawn from the seed; no bias walk over 120 s. Field: Xi'an (the authors' city),
inclination 53°, declination -3.5°. No GPS (indoors, static).
"""
from __future__ import annotations

import numpy as np

from ahrsgen.sim.log import G0, SensorLog
from ahrsgen.sim.scenarios import _sim
from ahrsgen.sim.scenarios._sim import DEG
from ahrsgen.npquat import q_from_euler

GYRO_ND = 0.005 * DEG          # rad/s/√Hz (MPU-6000)
ACCEL_ND = 400e-6 * G0         # m/s²/√Hz (MPU-6000)
MAG_SIGMA = 2e-3               # gauss per sample (HMC5883L noise floor)
MAG_FIELD = 0.5                # gauss


def make_static(name: str, description: str, seed: int, *, accel_intervals=(), mag_intervals=(),
                rate_hz: float = 100.0, mag_rate: float | None = None, duration: float = 120.0,
                attitude_deg=(0.0, 0.0, 0.0), noise: bool = True, disturbances: bool = True,
                jitter: float = 0.0, dropout: dict | None = None,
                settle_time: float = 0.0) -> SensorLog:
    period = 1.0 / rate_hz
    roll, pitch, yaw = (a * DEG for a in attitude_deg)
    q = q_from_euler(roll, pitch, yaw)
    tr = _sim.static_truth(q, duration, period)
    r = _sim.rng(seed, _sim._S_GYRO_BIAS)
    bias = r.uniform(-0.05, 0.05, 3) * DEG
    mr = rate_hz if mag_rate is None else min(mag_rate, rate_hz)
    sensors = _sim.SensorModel(gyro_nd=GYRO_ND, gyro_bias=bias, accel_nd=ACCEL_ND,
                               mag_nd=MAG_SIGMA / np.sqrt(mr))
    acc_iv = [(float(a), float(b), [float(x) for x in off]) for a, b, off in accel_intervals]
    mag_iv = [(float(a), float(b), [float(x) for x in off]) for a, b, off in mag_intervals]
    acc_d = _sim.Deterministic(lambda t, _r: _sim.offsets(acc_iv, t)) if (disturbances and acc_iv) else None
    mag_d = _sim.Deterministic(lambda t, _r: _sim.offsets(mag_iv, t)) if (disturbances and mag_iv) else None
    return _sim.simulate(
        name, tr, rate_hz=rate_hz, duration=duration, seed=seed, sensors=sensors, noise=noise,
        mag_rate=mag_rate, gps_rate=None, mag_field=MAG_FIELD, inclination_deg=53.0,
        declination_deg=-3.5, jitter=jitter, dropout=dropout, accel_disturbance=acc_d,
        mag_disturbance=mag_d, description=description, settle_time=settle_time,
        meta={"attitude_deg": [float(a) for a in attitude_deg],
              "disturbances": bool(disturbances),
              "accel_offsets": acc_iv if disturbances else [],
              "mag_offsets": mag_iv if disturbances else [],
              "disturbance_intervals": [(a, b) for a, b, _ in (acc_iv + mag_iv)] if disturbances else [],
              "sensor_class": "MPU-6000 gyro/accel, HMC5883L magnetometer (Pixhawk 1)"})
