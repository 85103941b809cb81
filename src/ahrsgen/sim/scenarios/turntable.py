"""Three-axis turntable, after the CPF paper (seeds/004_5402b586fce53e2b.txt, section 3).

The paper fixed a MEMS board and magnetometer on a three-axis turntable (0.01° accuracy), let
the table's attitude change, sampled at 10 Hz for 60 s and compared with the table's angles.
It gives neither the motion nor the sensor figures; this scenario fixes them:

Truth: the IMU at the table centre (no linear acceleration; v_n = a_n = 0). The three gimbals
(outer yaw, middle pitch, inner roll = the Z-Y-X Euler angles) rest 2 s at roll 0, pitch 0,
yaw 40°, then their amplitudes ramp in over 3 s to
  roll  = 30° sin(2π 0.10 t),
  pitch = 20° sin(2π 0.07 t + 0.6),
  yaw   = 40° + 90° sin(2π 0.03 t)
(peak rates about 19, 9 and 17 °/s; pitch stays within ±20°, far from gimbal lock).

Rates: gyro, accelerometer and magnetometer at 10 Hz; no GPS.
Noise (consumer MEMS on a development board, our choice: MPU-6050 / HMC5883L datasheet
figures): gyro 0.005 °/s/√Hz white plus a constant bias of 0.1-0.5 °/s per axis (random sign,
from the seed: a roughly calibrated consumer gyro), accelerometer 400 µg/√Hz, magnetometer
2 mgauss 1σ on a 0.5 gauss field (inclination 53°, declination -3.5°).
"""
from __future__ import annotations

import numpy as np

from ahrsgen.sim.log import G0, SensorLog
from ahrsgen.sim.scenarios import _sim
from ahrsgen.sim.scenarios._sim import DEG
from ahrsgen.npquat import q_from_euler

DESCRIPTION = ("three-axis turntable after the CPF paper: 60 s at 10 Hz, roll ±30° (0.10 Hz), pitch "
               "±20° (0.07 Hz), yaw 40°±90° (0.03 Hz), no linear acceleration, no GPS; MPU-6050/HMC5883L "
               "noise (gyro 0.005°/s/√Hz, bias 0.1-0.5°/s, accel 400 µg/√Hz, mag 2 mG on 0.5 G)")


def truth(duration: float, period: float) -> _sim.Truth:
    m = int(np.ceil(period / 0.002 - 1e-9))
    h = period / m
    k0 = int(np.ceil(1.0 / h))
    k1 = int(np.ceil((duration + 1.0) / h))
    t = np.arange(-k0, k1 + 1) * h
    env = _sim.smoothstep((t - 2.0) / 3.0)
    roll = env * 30 * DEG * np.sin(2 * np.pi * 0.10 * t)
    pitch = env * 20 * DEG * np.sin(2 * np.pi * 0.07 * t + 0.6)
    yaw = 40 * DEG + env * 90 * DEG * np.sin(2 * np.pi * 0.03 * t)
    q = q_from_euler(roll, pitch, yaw)
    z = np.zeros((len(t), 3))
    return _sim.Truth(t[0], h, q, z, z.copy())


def make(seed: int = 0, *, rate_hz: float = 10.0, duration: float = 60.0, noise: bool = True,
         jitter: float = 0.0, dropout: dict | None = None, settle_time: float = 0.0) -> SensorLog:
    period = 1.0 / rate_hz
    r = _sim.rng(seed, _sim._S_GYRO_BIAS)
    bias = r.uniform(0.1, 0.5, 3) * r.choice([-1.0, 1.0], 3) * DEG
    sensors = _sim.SensorModel(gyro_nd=0.005 * DEG, gyro_bias=bias, accel_nd=400e-6 * G0,
                               mag_nd=2e-3 / np.sqrt(rate_hz))
    return _sim.simulate(
        "turntable", truth(duration, period), rate_hz=rate_hz, duration=duration, seed=seed,
        sensors=sensors, noise=noise, gps_rate=None, mag_field=0.5, inclination_deg=53.0,
        declination_deg=-3.5, jitter=jitter, dropout=dropout, description=DESCRIPTION,
        settle_time=settle_time,
        meta={"sensor_class": "MPU-6050 gyro/accel, HMC5883L magnetometer (consumer board)",
              "motion": "roll 30° sin(2π0.10t), pitch 20° sin(2π0.07t+0.6), yaw 40°+90° sin(2π0.03t), "
                        "amplitudes ramped in over t = 2..5 s"})
