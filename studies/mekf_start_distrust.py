"""Issue 26: is the multirotor's 1 kHz gap to its tune the start? An emulation, not a design: the
NumPy reference (filters/mekf/reference.py, the C's double twin; accel_bias_gain = 0, which
the second emulation became) run with accel_noise_density =
D (the 1 kHz tune's 0.027) for the first T seconds of a log and the default 0.004 after, scored as
`ahrsgen bench` scores it (the site parameters set, seeds 0-2, total RMS from 5 s, degrees).

    PYTHONPATH=src .venv/bin/python studies/mekf_start_distrust.py [T ...] [--bias c ...]

--bias c: the second emulation, the distrust tied to the gyro bias's covariance instead of a
time: accel_noise_density^2 times 1 + c mean(diag P_bb) / p0_bias^2 (P_bb from the covariance at
the step's start), which is 1 + c at the start and falls as the bias is learned.

Rows: T = 0 (the defaults), then each T given (default 3 10) or each c, for the multirotor at 250 / 400 /
1 000 Hz (magnetometer 100 Hz) and the fixed-wing. Slow (the Python reference: about a minute a
log at 1 kHz). No BROAD files needed.

Result (2026-12-04, `... mekf_start_distrust.py 10`): T = 0 (the defaults) multirotor 250 / 400 /
1 000 Hz 0.485 / 0.408 / 0.376 (the C: 0.485 / 0.407 / 0.375), fixed-wing 0.381; T = 10 s
0.395 / 0.347 / 0.284, fixed-wing 0.357 (the 1 kHz budget is 0.331; accel_noise_density 0.027
throughout: 1 kHz 0.273, with a worse steady state). T = 3 s, 1 kHz alone: 0.388, no gain: the
accelerometer distrusted only in the first seconds does nothing; what the tune buys is the 5-15 s
window, while the gyro bias is still uncertain (p0_bias, studies/mekf_p0_bias_cv.py) and the
manoeuvres' residual tilt goes into it. BROAD not run (the Python reference is slow). A mechanism
tied to that, `--bias 100 400` (1 kHz and fixed-wing only, the same code in a scratch script):
c = 100 multirotor 1 kHz 0.259, fixed-wing 0.347; c = 400 0.315, 0.356 (seed 0 at 1 kHz, c = 100:
the bias variance at 0.48 / 0.069 / 0.014 of its start at 5 / 10 / 20 s). Built as
accel_bias_gain (studies/mekf_bias_gain_cv.py, default 100); the emulations here run with it off.
"""
from __future__ import annotations

import sys

import numpy as np

from ahrsgen.bench.scoring import score, site_sets
from ahrsgen.filters.mekf import reference
from ahrsgen.generate import config
from ahrsgen.sim.scenarios import make

D, DEFAULT = 0.027, 0.004
ENTRIES = {"multirotor 250 Hz": ("multirotor", {"rate_hz": 250.0, "mag_rate": 100.0}),
           "multirotor 400 Hz": ("multirotor", {"rate_hz": 400.0, "mag_rate": 100.0}),
           "multirotor 1 kHz": ("multirotor", {"rate_hz": 1000.0, "mag_rate": 100.0}),
           "fixedwing_gps": ("fixedwing_gps", {})}


class StartDistrust(reference.Reference):
    """The reference with accel_noise_density = D for the first `until` seconds."""
    until = 0.0

    def step(self, gyro, accel, mag, gps_vel, valid, dt):
        self.elapsed = getattr(self, "elapsed", 0.0) + dt
        self.accel_noise_density = D if self.elapsed < self.until else DEFAULT
        return super().step(gyro, accel, mag, gps_vel, valid, dt)


class BiasDistrust(reference.Reference):
    """The reference with accel_noise_density^2 times 1 + c mean(diag P_bb) / p0_bias^2."""
    c = 0.0

    def step(self, gyro, accel, mag, gps_vel, valid, dt):
        ratio = float(np.mean(np.diag(self.P)[3:])) / self.p0_bias ** 2
        self.accel_noise_density = DEFAULT * np.sqrt(1 + self.c * ratio)
        return super().step(gyro, accel, mag, gps_vel, valid, dt)


def total(log, until: float, c: float | None = None) -> float:
    extra, applied = site_sets("mekf", log.meta, set())
    sets = list(extra) + ["accel_bias_gain=0"]          # the emulations stand in for it
    f = (StartDistrust if c is None else BiasDistrust)(config.resolve("mekf", sets=sets).params)
    f.until, f.c = until, c
    q = np.empty((len(log), 4))
    for k in range(len(log)):
        f.step(log.gyro[k], log.accel[k], log.mag[k], log.gps_vel[k], int(log.valid[k]), log.dt[k])
        q[k] = f.q
    return score(q, log, "true" if applied else "mag")["total_rms"]


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    bias = "--bias" in argv
    values = [float(a) for a in argv if a != "--bias"] or ([] if bias else [3.0, 10.0])
    logs = {e: [make(n, s, **o) for s in range(3)] for e, (n, o) in ENTRIES.items()}
    if bias:
        print(f"mekf reference, accel_noise_density^2 times 1 + c P_bb / p0_bias^2; total RMS, deg")
        rows = [("defaults", 0.0, None)] + [(f"c = {c:g}", 0.0, c) for c in values]
    else:
        print(f"mekf reference, accel_noise_density {D} for the first T s, {DEFAULT} after; total RMS, deg")
        rows = [(f"T = {t:g} s", t, None) for t in [0.0] + values]
    for label, t, c in rows:
        print(f"{label}: " + ", ".join(f"{e} {np.mean([total(log, t, c) for log in lg]):.3f}"
                                       for e, lg in logs.items()), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
