"""Static Pixhawk with magnetic disturbances, after the ADUKF paper
(seeds/003_876a2b6ece1f51db.txt, Table 2 experiment).

Truth, rates and noise as static_accel_disturbance (level, motionless, 120 s, IMU+mag 100 Hz,
MPU-6000 / HMC5883L figures, no GPS).

Disturbance (the paper's figures are lost; sizes and intervals are ours): constant offsets
added to the magnetometer (gauss, on a 0.5 gauss field: 20-40 % of it, a nearby motor or
steel object), 10 s each:

| interval (s) | offset [x, y, z] (gauss) |
|---|---|
| [15, 25) | [+0.15, 0, 0] |
| [40, 50) | [0, -0.15, 0] |
| [65, 75) | [0, 0, +0.20] |
| [90, 100) | [-0.10, +0.10, -0.10] |

They are in meta['mag_offsets'] as (t0, t1, offset), applied for t0 <= t < t1; the
accelerometer is clean. `disturbances=False` gives the clean static log.
"""
from __future__ import annotations

from ahrsgen.sim.log import SensorLog
from ahrsgen.sim.scenarios._static import make_static

DESCRIPTION = ("static level Pixhawk after the ADUKF paper: 120 s, IMU+mag 100 Hz, no GPS, MPU-6000/"
               "HMC5883L noise; constant magnetometer offsets of 0.15-0.2 gauss (0.5 gauss field) "
               "for 10 s at 15, 40, 65, 90 s on x, y, z, x+y+z")

MAG_OFFSETS = [(15.0, 25.0, (0.15, 0.0, 0.0)),
               (40.0, 50.0, (0.0, -0.15, 0.0)),
               (65.0, 75.0, (0.0, 0.0, 0.20)),
               (90.0, 100.0, (-0.10, 0.10, -0.10))]


def make(seed: int = 0, *, rate_hz: float = 100.0, duration: float = 120.0,
         attitude_deg=(0.0, 0.0, 0.0), noise: bool = True, disturbances: bool = True,
         mag_rate: float | None = None, jitter: float = 0.0, dropout: dict | None = None,
         settle_time: float = 0.0) -> SensorLog:
    return make_static("static_mag_disturbance", DESCRIPTION, seed, mag_intervals=MAG_OFFSETS,
                       rate_hz=rate_hz, mag_rate=mag_rate, duration=duration,
                       attitude_deg=attitude_deg, noise=noise, disturbances=disturbances,
                       jitter=jitter, dropout=dropout, settle_time=settle_time)
