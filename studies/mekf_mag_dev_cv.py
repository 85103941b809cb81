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
attached mid-run, the hand-held sensor and the gyro clip. A candidate is admissible only if it
keeps what the product wins: the multirotor at 1.0 degree or less, and the attached magnet,
hand-held and gyro-clip entries no more than 10 % (or 0.05 degree) worse than the present
defaults'. Needs the full BROAD files.

Result (2026-12-04): in-sample choice mag_heading_density 0.012, mag_dev_gain 3000 (BROAD
2.015/2.092/2.241/2.825 deg at 286/143/95/48 Hz, cross-validated 2.113/2.203/2.363/2.935); not
made the default, because the fixed-wing's yaw in a GPS outage suffers (docs/mekf.md).
"""
from __future__ import annotations

import itertools
import sys

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


def candidates():
    yield DEFAULTS
    for d, k in itertools.product((0.008, 0.012, 0.016, 0.024), (0.0, 300.0, 1000.0, 3000.0, 10000.0)):
        if (d, k) != (0.024, 0.0):
            yield {"mag_heading_density": d, "mag_dev_gain": k}


def main(argv=None):
    return logo_cv.study(__doc__, argv, SCENARIOS, SEEDS, candidates(), DEFAULTS,
                         "mekf mag_heading_density x mag_dev_gain (graded magnetometer trust), leave one BROAD group out",
                         "defaults", "mekf", rates=RATES,
                         admissible=lambda e, base: e["multirotor"] <= MULTIROTOR_MAX and all(
                             e[k] <= max(1.1 * base[k], base[k] + 0.05) for k in KEEP))


if __name__ == "__main__":
    sys.exit(main())
