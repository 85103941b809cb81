"""Hand-held rotation with a magnet attached to the sensor mid-run (issue 25's heading scenario).

What it reproduces: BROAD's held-back trials where a magnet is fixed to the IMU at a distance
where its field is of the order of the Earth's. The magnet turns with the sensor, so in body
axes it is a constant offset (a hard iron) that appears mid-run: a field check against a
reference learned at the start can neither accept nor reject it cleanly.

Truth: 10 s at rest (level, heading from the seed), then the amplitudes ramp in over 5 s to
hand-held rotation, each Euler angle a sum of three sinusoids with phases from the seed:
roll and pitch within about ±40°, heading sweeping ±120° around a slowly turning centre
(peak rates about 60-100 °/s). No translation. From `attach_time` (uniform in [40, 60] s by
the seed) a body-frame offset of `strength` times the Earth's field (uniform in [0.3, 1.0],
random direction, by the seed) ramps in over 0.5 s and stays.

Rates and noise: IMU and magnetometer at 285.714 Hz (BROAD's rate); gyro 0.01 °/s/√Hz and a
constant bias of 0.1-0.3 °/s per axis, accelerometer 300 µg/√Hz, magnetometer 0.3 µT per
sample on a 50 µT field (inclination 67°, declination 0: Berlin, magnetic north), in µT as in
BROAD. No GPS.

Scored from `attach_time + 30 s` (`settle_time`): the heading after the first 30 s of rotation
following the magnet's arrival. meta['magnet'] gives the time, strength and body offset.
"""
from __future__ import annotations

import numpy as np

from ahrsgen.sim.log import G0, SensorLog
from ahrsgen.sim.scenarios import _sim, handheld
from ahrsgen.sim.scenarios._sim import DEG

DESCRIPTION = ("hand-held rotation at 286 Hz, 150 s, no GPS; a magnet attached to the sensor at 40-60 s: "
               "a body-frame offset of 0.3-1x the Earth's field (50 uT, inclination 67 deg) that stays; "
               "scored from 30 s after its arrival")

FIELD_UT = handheld.FIELD_UT
SCORE_AFTER = 30.0


def make(seed: int = 0, *, rate_hz: float = 285.714, duration: float = 150.0, noise: bool = True,
         attach_time: float = -1.0, strength: float = -1.0, jitter: float = 0.0,
         dropout: dict | None = None) -> SensorLog:
    """attach_time, strength: < 0 = drawn from the seed ([40, 60] s, [0.3, 1.0] x the field)."""
    r = _sim.rng(seed, _sim._S_SCENARIO)
    ta = r.uniform(40.0, 60.0)
    k = r.uniform(0.3, 1.0)
    d = r.normal(size=3)
    d /= np.linalg.norm(d)
    if attach_time >= 0.0:
        ta = float(attach_time)
    if strength >= 0.0:
        k = float(strength)
    offset = k * FIELD_UT * d
    period = 1.0 / rate_hz
    tr = handheld.truth(duration, period, _sim.rng(seed, _sim._S_SCENARIO + 5))
    rb = _sim.rng(seed, _sim._S_GYRO_BIAS)
    bias = rb.uniform(0.1, 0.3, 3) * rb.choice([-1.0, 1.0], 3) * DEG
    sensors = _sim.SensorModel(gyro_nd=0.01 * DEG, gyro_bias=bias, accel_nd=300e-6 * G0,
                               mag_nd=0.3 / np.sqrt(rate_hz))

    def magnet(t, _r):
        return _sim.smoothstep((np.asarray(t) - ta) / 0.5)[:, None] * offset[None, :]

    return _sim.simulate(
        "attached_magnet", tr, rate_hz=rate_hz, duration=duration, seed=seed, sensors=sensors,
        noise=noise, gps_rate=None, mag_field=FIELD_UT, inclination_deg=67.0, declination_deg=0.0,
        jitter=jitter, dropout=dropout, mag_disturbance=_sim.Deterministic(magnet),
        description=DESCRIPTION, settle_time=min(ta + SCORE_AFTER, duration),
        meta={"sensor_class": "hand-held IMU at BROAD's rate (myon aktos-t class figures, ours)",
              "magnet": {"attach_time_s": float(ta), "strength_of_field": float(k),
                         "offset_body": offset.tolist()},
              "motion": "roll/pitch within about +-40 deg, heading +-120 deg around a slowly turning "
                        "centre, each a sum of three sinusoids (0.05-0.41 Hz), after 10 s at rest"})
