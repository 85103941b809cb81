"""Issue 26: graded magnetometer trust for mekf. The magnetic heading's variance,
mag_heading_density^2 / mag_dt, is multiplied by 1 + mag_dev_gain * (e_norm^2 + e_dip^2), e_norm
the sample's field norm off the learned reference norm (a fraction), e_dip its dip off the
reference dip (rad, seen from the predicted attitude): the field check's two quantities, graded
instead of only thresholded. A clean field (the simulated multirotor, whose per-rate tune wants
mag_heading_density 0.002) is trusted more, BROAD's disturbed laboratory field less, with one
default set. Chosen with mag_heading_density by leave-one-BROAD-group-out with the scenarios;
the cross-validated figure beside the in-sample one.

    .venv/bin/python studies/mekf_mag_dev_cv.py [DATA_DIR] [--json out.json]

BROAD is scored at four rates per trial (as recorded, 286 Hz, and averaged to 143, 95 and
48 Hz: every 2, 3, 6 rows one), the objective per trial their mean (logo_cv.RATES set here).
Scenario entries (each its mean total RMS over 3 seeds, always in the training set): the
multirotor at 250, 400 and 1 000 Hz, the turntable, the static magnetic disturbance, the magnet
attached mid-run, the hand-held sensor, the gyro clip, and the fixed-wing with GPS and the same
flights with the GPS withheld for 60 s over a 20 deg banked turn (test_mekf_c.py's outage). A
candidate is admissible only if it keeps what the product wins: the multirotor at 1.0 degree or
less, the fixed-wing at 0.5 or less, and the attached magnet, hand-held and gyro-clip entries
no more than 10 % (or 0.05 degree) worse than the present defaults'. Needs the full BROAD files.

Result (2026-12-04, after the gravity rows learned the unobserved turn of a GPS outage, 17
candidates): in-sample choice mag_heading_density 0.016, mag_dev_gain 3000 (BROAD
2.037/2.057/2.113/2.381 deg at 286/143/95/48 Hz against the defaults' 2.091/2.158/2.227/2.548;
multirotor 0.76/0.76/0.76 at 250/400/1 000 Hz against 0.93/0.91/0.96; static magnetic
disturbance 0.73 against 4.19; fixed-wing 0.36 both; its outage's largest yaw error 1.5 deg).
Cross-validated 2.241/2.217/2.243/2.457: the fold that holds out the rotation trials chooses
0.024/3000 on the rest, which scores 2.94 on them at 286 Hz (the defaults 2.44). Worse than
the present defaults' cross-validated 2.100 at 286 Hz (studies/mekf_gyro_step_noise_cv.py), so
not made the default: the rotation trials want the magnetometer trusted through their field's
deviations, the other groups and the simulated fields want it graded.
"""
from __future__ import annotations

import copy
import itertools
import sys

import numpy as np

import logo_cv

SEEDS = range(3)
RATES = ("", "@143", "@95", "@48")   # BROAD as recorded and averaged (logo_cv.AVERAGING)
MULTIROTOR_MAX = 1.0             # degrees, issue 25's 'nothing lost where the product wins'
KEEP = ("attached_magnet", "handheld", "gyro_clip")
SCENARIOS = {"multirotor": ("multirotor", {}),
             "multirotor_400hz": ("multirotor", {"rate_hz": 400.0, "mag_rate": 100.0}),
             "multirotor_1khz": ("multirotor", {"rate_hz": 1000.0, "mag_rate": 100.0}),
             "turntable": ("turntable", {}),
             "static_mag_disturbance": ("static_mag_disturbance", {}),
             "attached_magnet": ("attached_magnet", {}),
             "handheld": ("handheld", {}),
             "gyro_clip": ("gyro_clip", {})}
DEFAULTS = {"mag_heading_density": 0.024, "mag_dev_gain": 0.0}


FIXEDWING_MAX = 0.5              # degrees, the fixed-wing's total RMS (issue 26)
OUTAGE = (200.0, 260.0)          # s: the GPS outage of test_mekf_c.py's outage test


def fixedwing_logs(seeds) -> dict:
    """The fixed-wing with GPS, and the same flights with the GPS velocity withheld over OUTAGE
    (a 20 deg banked turn without motion compensation), as two more scenario entries."""
    from ahrsgen.sim.log import VALID_GPS
    from ahrsgen.sim.scenarios import make
    logs = [make("fixedwing_gps", s) for s in seeds]
    out = [copy.deepcopy(log) for log in logs]
    for log in out:
        log.valid[(log.t >= OUTAGE[0]) & (log.t < OUTAGE[1])] &= ~np.uint32(VALID_GPS)
    return {"fixedwing_gps": logs, "fixedwing_gps_outage": out}


def candidates():
    yield DEFAULTS
    for d, k in itertools.product((0.008, 0.012, 0.016, 0.024), (0.0, 1000.0, 3000.0, 10000.0)):
        if (d, k) != (0.024, 0.0):
            yield {"mag_heading_density": d, "mag_dev_gain": k}


def main(argv=None):
    return logo_cv.study(__doc__, argv, SCENARIOS, SEEDS, candidates(), DEFAULTS,
                         "mekf mag_heading_density x mag_dev_gain (graded magnetometer trust), leave one BROAD group out",
                         "defaults", "mekf", rates=RATES, extra_logs=fixedwing_logs,
                         admissible=lambda e, base: e["multirotor"] <= MULTIROTOR_MAX
                         and e["fixedwing_gps"] <= FIXEDWING_MAX and all(
                             e[k] <= max(1.1 * base[k], base[k] + 0.05) for k in KEEP))


if __name__ == "__main__":
    sys.exit(main())
