"""Issue 26: mekf's accelerometer trusted less while the gyro bias is still uncertain
(accel_bias_gain: accel_noise_density's term of the gravity variance times 1 + accel_bias_gain
p_bb / p0_bias², p_bb the mean of the bias variances), chosen by leave-one-BROAD-group-out at
286/143/95/48 Hz with the scenarios (logo_cv); the cross-validated figure beside the in-sample one.

    .venv/bin/python studies/mekf_bias_gain_cv.py [DATA_DIR] [--json out.json]

Why: the 1 kHz multirotor's gap to its tune is the 5-15 s window, while the bias is still learned
(studies/mekf_start_distrust.py, studies/mekf_p0_bias_cv.py). Scenario entries and admissibility
as studies/mekf_warm_start_cv.py. Needs the full BROAD files.

Result (2026-12-04): every fold, and in-sample, chooses 100 (cross-validated = in-sample =
before 2.091/2.158/2.227/2.549 deg at 286/143/95/48 Hz: BROAD starts at rest, where the bias is
read from the gyro). accel_bias_gain 0 / 30 / 100 / 300: multirotor 250 Hz 0.49 / 0.40 / 0.38 /
0.40, 400 Hz 0.41 / 0.32 / 0.33 / 0.35, 1 kHz 0.38 / 0.27 / 0.26 / 0.29, fixed-wing 0.38 / 0.35 /
0.35 / 0.35, its GPS outage 0.61 / 0.60 / 0.60 / 0.60, turntable 0.52 / 0.53 / 0.53 / 0.54,
gyro_clip 0.26 / 0.27 / 0.27 / 0.28, attached magnet 0.26 / 0.27 / 0.27 / 0.27; at 100 exactly
multirotor 0.379 / 0.328 / 0.257, fixed-wing 0.346, outage 0.597, turntable 0.532, gyro_clip
0.275, attached magnet 0.270 (before 0.491 / 0.407 / 0.375, 0.380, 0.613, 0.519, 0.264, 0.265).
"""
from __future__ import annotations

import sys

from mekf_gyro_step_noise_cv import mekf_study

BEFORE = {"accel_bias_gain": 0.0}      # the default before this study


def candidates():
    for v in (0.0, 30.0, 100.0, 300.0):
        yield {"accel_bias_gain": v}


def main(argv=None):
    return mekf_study(__doc__, argv, candidates(), BEFORE,
                      "mekf accelerometer trust while the gyro bias is learned, leave one BROAD group out",
                      "defaults")


if __name__ == "__main__":
    sys.exit(main())
