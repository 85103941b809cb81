"""Issue 25/26: choose mekf's gyro_rate_noise (the gyro noise density growing with the rate:
scale-factor and cross-axis errors) and mag_heading_density (the magnetic heading's variance
over the magnetometer's own sample interval) together, by leave-one-group-out over
BROAD with the simulated scenarios, and report the cross-validated figure beside the in-sample
one.

    .venv/bin/python studies/mekf_gyro_rate_noise_cv.py [DATA_DIR] [--json out.json]

Candidates: a grid of the two values, one parameter set for all data. Cross-validation as
studies/logo_cv.py says (BROAD at 286 and 95 Hz), with one entry more per scenario where the
magnetometer sets the heading (multirotor at 250 and 400 Hz, turntable, static_mag_disturbance,
attached_magnet; each its mean total RMS over 3 seeds). The simulated gyros have no scale-factor
error, the BROAD sensor's has some: the scenarios keep the choice from trading their heading
for BROAD's. A candidate is admissible only if it keeps issue 25's bound where the product
wins, the multirotor scenario at 1.0 degrees or less (fixedwing_gps takes its heading from the
GPS course, which neither value touches). Needs the full BROAD files (the shared data folder); says so and stops when they
are absent.
"""
from __future__ import annotations

import itertools
import sys

import logo_cv

SEEDS = range(3)
MULTIROTOR_MAX = 1.0        # degrees, issue 25's 'nothing lost where the product wins'
SCENARIOS = {"multirotor": ("multirotor", {}),
             "multirotor_400hz": ("multirotor", {"rate_hz": 400.0, "mag_rate": 100.0}),
             "turntable": ("turntable", {}),
             "static_mag_disturbance": ("static_mag_disturbance", {}),
             "attached_magnet": ("attached_magnet", {})}


def candidates():
    # densities: 0.1 to 0.6 rad per sample at BROAD's 286 Hz
    for k, h in itertools.product((0.0, 5e-4, 1e-3, 1.5e-3, 2e-3), (0.006, 0.009, 0.012, 0.015, 0.018, 0.024, 0.03, 0.036)):
        yield {"gyro_rate_noise": k, "mag_heading_density": h}


def main(argv=None):
    a, broad = logo_cv.setup(__doc__, argv)
    if broad is None:
        return 2
    scen = logo_cv.scenarios(SCENARIOS, SEEDS)
    results = logo_cv.run(candidates(), *broad, scen)
    cv = logo_cv.cross_validate(results, list(scen), admissible=lambda e: e["multirotor"] <= MULTIROTOR_MAX)
    before = next(r for r in results if r[0] == {"gyro_rate_noise": 0.0, "mag_heading_density": 0.006})
    logo_cv.report("mekf gyro_rate_noise x mag_heading_density, leave one BROAD group out", cv,
                   ("0, 0.006 (~before)", before[1]), scen, results, a.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
