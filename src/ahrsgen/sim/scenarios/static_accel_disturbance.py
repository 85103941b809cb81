"""Static Pixhawk with external-acceleration disturbances, after the ADUKF paper
(seeds/003_876a2b6ece1f51db.txt, Table 1 experiment).

Truth: level and motionless for 120 s (roll = pitch = yaw = 0 by default, so a filter that
starts from the identity quaternion as in the paper starts on the truth; `attitude_deg`
changes it). IMU and magnetometer at 100 Hz (the paper gives no rate), no GPS.
Noise: MPU-6000 / HMC5883L datasheet figures (gyro 0.005 °/s/√Hz, accel 400 µg/√Hz,
mag 2 mgauss 1σ on 0.5 gauss), residual gyro bias ≤ 0.05 °/s per axis from the seed.

Disturbance (the paper's figures are lost; sizes and intervals are ours): constant offsets
added to the accelerometer, 10 s each, on one axis, two axes, then all three, so that the
per-axis adaptive noise of the A-DUKF has something to tell apart:

| interval (s) | offset [x, y, z] (m/s²) |
|---|---|
| [15, 25) | [+2.0, 0, 0] |
| [40, 50) | [0, -2.0, 0] |
| [65, 75) | [+1.5, +1.5, 0] |
| [90, 100) | [-1.0, +1.0, -2.0] |

They are in meta['accel_offsets'] as (t0, t1, offset), applied for t0 <= t < t1; the
magnetometer is clean. `disturbances=False` gives the clean static log.
"""
from __future__ import annotations

from ahrsgen.sim.log import SensorLog
from ahrsgen.sim.scenarios._static import make_static

DESCRIPTION = ("static level Pixhawk after the ADUKF paper: 120 s, IMU+mag 100 Hz, no GPS, MPU-6000/"
               "HMC5883L noise; constant accelerometer offsets of 2-2.6 m/s² for 10 s at 15, 40, 65, 90 s "
               "on x, y, x+y, x+y+z")

ACCEL_OFFSETS = [(15.0, 25.0, (2.0, 0.0, 0.0)),
                 (40.0, 50.0, (0.0, -2.0, 0.0)),
                 (65.0, 75.0, (1.5, 1.5, 0.0)),
                 (90.0, 100.0, (-1.0, 1.0, -2.0))]


def make(seed: int = 0, *, rate_hz: float = 100.0, duration: float = 120.0,
         attitude_deg=(0.0, 0.0, 0.0), noise: bool = True, disturbances: bool = True,
         mag_rate: float | None = None, jitter: float = 0.0, dropout: dict | None = None,
         settle_time: float = 0.0) -> SensorLog:
    return make_static("static_accel_disturbance", DESCRIPTION, seed, accel_intervals=ACCEL_OFFSETS,
                       rate_hz=rate_hz, mag_rate=mag_rate, duration=duration,
                       attitude_deg=attitude_deg, noise=noise, disturbances=disturbances,
                       jitter=jitter, dropout=dropout, settle_time=settle_time)
