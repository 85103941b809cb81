"""Issue 26: one ADUKF default set for any sample rate. The per-sample terms of R (sigma², the
adaptation k eps² and its bound adapt_max) made the accelerometer's information per second, and
the length of an adaptive lock-out in seconds, depend on the rate: at 48 Hz a tilt error after
fast rotation raises R as much per sample as at 286 Hz, but the filter sees 6 times fewer samples
a second, so it stays locked out 6 times longer (trial 08: 10.3 deg at 48 Hz, 2.5 at 286 Hz;
trial 28: 14.1 against 3.2). `r_time` makes them the terms of a sample standing for r_time
seconds (times r_time / dt): R = (sigma² + min(k eps², adapt_max)) r_time / s + density² / s.
Chosen here by leave-one-BROAD-group-out (studies/logo_cv.py) with every trial as recorded (286
Hz) and averaged to 143, 95 and 48 Hz (each trial's objective the mean over the four rates), with
the simulated scenarios in the training set.

    .venv/bin/python studies/adukf_rate_cv.py [DATA_DIR] [--json out.json] [--second-round]

Scenarios, each one entry (mean total RMS over 3 seeds): the multirotor at 250, 400 and 1 000
Hz, both static disturbances (100 Hz), the turntable, the gyro over-range and the magnet attached
to the sensor. Candidates are kept only where issue 10's acceptance holds (the adaptive filter at
least 10 times better than the plain DUKF on every angle of both static scenarios, seed 0) and
are admissible only if the entries issue 26 names ("nothing lost": the multirotor at 250, 400
and 1 000 Hz, the turntable, gyro_clip, attached_magnet) stay within 10 % of before. The static
disturbances' own RMS is not bounded (issue 10's ratio is): every r_time > 0 here at least
doubles static_accel_disturbance's at 100 Hz (0.27 -> 0.54 deg at 0.0035) unless k_a grows,
which loses BROAD at 286 Hz; with that entry bounded at 10 % as well every fold keeps r_time = 0.
Needs the full BROAD files; says so and stops when they are absent.

Result (2026-12-04, float C; 286 / 143 / 95 / 48 Hz, mean of 10): before 2.773 / 2.932 / 3.220 /
4.513; chosen in-sample r_time = 0.0035 (k_a 300, adapt_max 10, sigma_mag_density 0.012) 2.773 /
2.905 / 3.025 / 3.727; left out 2.791 / 2.938 / 3.078 / 3.806 (the rotation and magnet folds
choose r_time 0.005, translation and tapping 0.0035). Scenarios at 0.0035: multirotor 0.68,
400 Hz 0.74, 1 kHz 1.46 (before 1.40), turntable 0.19 (0.49), static_accel 0.54 (0.27),
static_mag 0.33 (0.27), issue 10's ratio 10.6x (20.6x).

--second-round adds 9 candidates at r_time 0.0035 that move gyro_noise (0.002, 0.001), sigma_acc
(0.05, 0.09) and gyro_rate_noise (0.01, 0.015) toward a joint tune over the four rates. It wins
in-sample (gyro_noise 0.002: 2.758 / 2.892 / 3.013 / 3.716) but loses left out (2.822 / 2.967 /
3.104 / 3.822: the tapping fold picks gyro_rate_noise 0.015), so the defaults keep the first
round's choice. The joint tune itself (ahrsgen tune over the 40 logs: 2.37 / 2.44 / 2.57 / 3.35
with r_time 0.0035) breaks the scenarios (multirotor 8.2 deg, issue 10's ratio 1.9x).
"""
from __future__ import annotations

import itertools
import sys

import adukf_motion_cv as motion
import logo_cv

RATES = ("", "@143", "@95", "@48")
WORSE_MAX = 1.10
NOTHING_LOST = ("multirotor", "multirotor_400hz", "multirotor_1khz", "turntable", "gyro_clip", "attached_magnet")
BEFORE = {"r_time": 0.0, "k_a": 300.0, "adapt_max": 10.0, "sigma_mag_density": 0.012}


def candidates(second_round=False):
    yield BEFORE
    for t, (k, cap), dm in itertools.product((0.0, 0.0035, 0.005), ((300.0, 10.0), (600.0, 20.0)), (0.012, 0.024)):
        c = {"r_time": t, "k_a": k, "adapt_max": cap, "sigma_mag_density": dm}
        if c != BEFORE:
            yield c
    if not second_round:
        return
    # second round, at r_time 0.0035: a gyro density and sigma_acc toward the joint tune over the
    # four rates (gyro_noise 0.0003, sigma_acc 0.09), the moves that keep the scenarios (a larger
    # sigma_mag_density or accel_tau costs issue 10's ratio: 6.4x and 7.0x)
    for g, sa, r in itertools.product((0.002, 0.001), (0.05, 0.09), (0.01, 0.015)):
        yield {**BEFORE, "r_time": 0.0035, "gyro_noise": g, "sigma_acc": sa, "gyro_rate_noise": r}
    yield {**BEFORE, "r_time": 0.0035, "sigma_acc": 0.09}


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    second = "--second-round" in argv
    argv = [a for a in argv if a != "--second-round"]
    return logo_cv.study(__doc__, argv, motion.SCENARIOS, motion.SEEDS, candidates(second), BEFORE,
                         "adukf r_time x k_a, adapt_max x sigma_mag_density, leave one BROAD group out",
                         "before", "adukf", rates=RATES,
                         keep=lambda c: motion._claim(tuple(sorted(c.items()))) >= motion.CLAIM_MIN,
                         admissible=lambda e, b: all(e[k] <= WORSE_MAX * b[k] for k in NOTHING_LOST))


if __name__ == "__main__":
    sys.exit(main())
