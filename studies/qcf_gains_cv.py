"""Issue 26: the QCF's gains (kp, ki) and its NED low-pass (accel_tau), chosen by leave-one-group-out
over BROAD with the simulated scenarios; the cross-validated figure beside the in-sample one
(studies/logo_cv.py, as the mekf and adukf studies).

    .venv/bin/python studies/qcf_gains_cv.py [DATA_DIR] [--json out.json]

Why: a per-rate `ahrsgen tune qcf --params kp,ki,accel_tau,motion_accel_threshold --folds 0`
(60 trials, 2026-12-04) beat the defaults by 14.6 % at 286 Hz, 11.3 % at 143 Hz, 11.0 % at
95 Hz and 4.9 % at 48 Hz, every time with ki near 0.00025 (default 0.002) and accel_tau 2-3 s
(default 1 s); issue 26 asks for the defaults within 10 % of such a tune at every rate. The
scenarios keep what the QCF is for: the fixed-wing with GPS at 12.5 and 100 Hz, the multirotor
at 250 Hz and 1 kHz, the gyro over-range recovery and the turntable, each one entry (mean total
RMS over 3 seeds). A candidate is admissible only if fixedwing_gps and gyro_clip stay within
10 % of the present defaults. Needs the full BROAD files; says so and stops when they are absent.
"""
from __future__ import annotations

import itertools
import sys

import logo_cv

SEEDS = range(3)
WORSE_MAX = 1.10
KEPT = ("fixedwing_gps", "gyro_clip")
SCENARIOS = {"fixedwing_gps": ("fixedwing_gps", {}),
             "fixedwing_gps_100hz": ("fixedwing_gps", {"rate_hz": 100.0}),
             "multirotor": ("multirotor", {}),
             "multirotor_1khz": ("multirotor", {"rate_hz": 1000.0, "mag_rate": 100.0}),
             "gyro_clip": ("gyro_clip", {}),
             "turntable": ("turntable", {})}
BEFORE = {"kp": 0.3, "ki": 0.002, "accel_tau": 1.0}


def candidates():
    for kp, ki, tau in itertools.product((0.2, 0.25, 0.3), (0.00025, 0.0007, 0.002), (1.0, 2.0, 3.0)):
        yield {"kp": kp, "ki": ki, "accel_tau": tau}


def main(argv=None):
    return logo_cv.study(__doc__, argv, SCENARIOS, SEEDS, candidates(), BEFORE,
                         "qcf kp x ki x accel_tau, leave one BROAD group out", "0.3, 0.002, 1 (before)", "qcf",
                         admissible=lambda e, b: all(e[k] <= WORSE_MAX * b[k] for k in KEPT))


if __name__ == "__main__":
    sys.exit(main())
