"""Issue 26: choose mekf's gravity-direction noise as two terms, the motion the accelerometer
low-pass leaves (accel_angle_noise, per sample: the same at any rate) and the sensor's white
noise (accel_noise_density, a density: its per-sample variance is density^2 / dt), by
leave-one-group-out over BROAD with the simulated scenarios; the cross-validated figure beside
the in-sample one.

    .venv/bin/python studies/mekf_accel_density_cv.py [DATA_DIR] [--json out.json]

Why: with a per-sample noise alone a 1 kHz IMU trusts gravity four times as much per second as
a 250 Hz one; the multirotor scenario at 1 kHz was 2.3 degrees against 0.6 for a per-rate tune
(issue 26's rate acceptance). Candidates: a grid of the two values, one parameter set for all
data. Cross-validation as studies/logo_cv.py says (BROAD at 286 and 95 Hz), with one entry more
per scenario (each its mean total RMS over 3 seeds): the multirotor at 250, 400 and 1 000 Hz,
the fixed-wing at 12.5 Hz (where the per-sample term must stay), the turntable (10 Hz) and the
static accelerometer disturbance, and the fixed-wing with its GPS lost for 60 s (200-260 s,
banked turns included: the specific force then carries the turns' acceleration uncompensated,
which only the per-sample term covers at 12.5 Hz). A candidate is admissible only if it keeps
what the product wins: the multirotor at 250 Hz at 1.0 degree or less, the fixed-wing at 0.40 or
less (0.36 before) and the GPS outage no more than 10 % worse than before. Needs the full BROAD files (the shared data folder); says so and stops when absent.
"""
from __future__ import annotations

import itertools
import sys

import numpy as np

import logo_cv
from ahrsgen.sim.log import VALID_GPS
from ahrsgen.sim.scenarios import make

SEEDS = range(3)
MULTIROTOR_MAX = 1.0        # degrees, issue 25's 'nothing lost where the product wins'
FIXEDWING_MAX = 0.40
SCENARIOS = {"multirotor": ("multirotor", {}),
             "multirotor_400hz": ("multirotor", {"rate_hz": 400.0, "mag_rate": 100.0}),
             "multirotor_1khz": ("multirotor", {"rate_hz": 1000.0, "mag_rate": 100.0}),
             "fixedwing_gps": ("fixedwing_gps", {}),
             "turntable": ("turntable", {}),
             "static_accel_disturbance": ("static_accel_disturbance", {})}


OUTAGE_WORSE_MAX = 1.10     # the GPS-outage entry at most this times the before candidate's


def gps_outage(log):
    """The log with its GPS velocity invalid from 200 to 260 s."""
    out = (log.t >= 200.0) & (log.t < 260.0)
    log.valid = np.where(out, log.valid & ~np.uint32(VALID_GPS), log.valid).astype(log.valid.dtype)
    return log


def outage_logs(seeds) -> dict:
    """The fixed-wing with its 60 s GPS outage, one log per seed (a study's extra_logs)."""
    return {"fixedwing_gps_outage": [gps_outage(make("fixedwing_gps", s)) for s in seeds]}


def candidates():
    # density 0.004 rad sqrt(s): 0.068 rad per sample at 286 Hz, 0.126 at 1 kHz, 0.014 at 12.5 Hz
    for a, d in itertools.product((0.02, 0.03, 0.04, 0.05, 0.06, 0.07, 0.09), (0.0, 0.002, 0.003, 0.004, 0.005, 0.006, 0.008)):
        yield {"accel_angle_noise": a, "accel_noise_density": d}


def main(argv=None):
    a, broad = logo_cv.setup(__doc__, argv)
    if broad is None:
        return 2
    scen = logo_cv.scenarios(SCENARIOS, SEEDS)
    scen.update(outage_logs(SEEDS))
    results = logo_cv.run(candidates(), *broad, scen)
    before = next(r for r in results if r[0] == {"accel_angle_noise": 0.07, "accel_noise_density": 0.0})
    cv = logo_cv.cross_validate(results, list(scen), admissible=lambda e: e["multirotor"] <= MULTIROTOR_MAX
                                and e["fixedwing_gps"] <= FIXEDWING_MAX
                                and e["fixedwing_gps_outage"] <= OUTAGE_WORSE_MAX * before[1]["fixedwing_gps_outage"])
    logo_cv.report("mekf accel_angle_noise x accel_noise_density, leave one BROAD group out", cv,
                   ("0.07, 0 (before)", before[1]), scen, results, a.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
