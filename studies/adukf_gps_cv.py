"""Issue 26: adukf's accelerometer model re-chosen once the GPS-measured motion is removed from
the low-passed specific force (motion_accel_model = "gps_lowpass"). Before it, the multirotor's
real acceleration had to be carried by the low-pass and the adaptive R, which held accel_tau
and sigma_acc away from what BROAD (no GPS) wants (its per-rate tunes: accel_tau ~2.7 s,
sigma_acc ~0.12, a small gyro_noise and sigma_acc_density). Candidates move those four toward
BROAD's optimum; chosen by leave-one-BROAD-group-out (studies/logo_cv.py) with every trial at
286, 143, 95 and 48 Hz and the scenarios (the multirotor at 250, 400 and 1 000 Hz, both static
disturbances, the turntable, gyro_clip, the attached magnet, fixedwing_gps) in the training set.

    PYTHONPATH=src .venv/bin/python studies/adukf_gps_cv.py [DATA_DIR] [--json out.json] [--second-round]

Candidates are kept only where issue 10's acceptance holds (the adaptive filter at least 10
times better than the plain DUKF on every angle of both static scenarios, seed 0) and are
admissible only if every scenario entry stays within 10 % of the present defaults'. Needs the
full BROAD files; says so and stops when they are absent.

Result (2026-12-04, float C; 286 / 143 / 95 / 48 Hz, mean of 10): before (accel_tau 1.0,
sigma_acc 0.05, sigma_acc_density 0.016, gyro_noise 0.003) 2.773 / 2.905 / 3.025 / 3.727; every
fold and the in-sample choice: sigma_acc 0.12, gyro_noise 0.002, 2.767 / 2.898 / 3.015 / 3.710
left out (the same in-sample). Scenarios: multirotor 0.419 -> 0.427, 400 Hz 0.367 -> 0.359, 1 kHz
1.277 -> 1.217, static_accel 0.535 -> 0.492, static_mag 0.334 -> 0.313, turntable 0.194 -> 0.199,
fixedwing_gps 1.919 -> 1.774; issue 10's ratio 10.6x -> 11.3x. accel_tau 2.7 (BROAD's tunes:
2.30 / 2.43 / 2.57 / 3.43 at its best here) keeps issue 10's ratio below 8x (4.8-7.8x) and, even
with the GPS, the multirotor at 250 Hz at 1.4-2.7 deg; sigma_acc_density 0.004 loses the
multirotor at 1 kHz (3.3-11 deg) and fixedwing_gps (10-23 deg). --second-round (a larger
density, toward the 1 kHz multirotor's tune: 0.024, 0.04; accel_tau 0.5): 1 kHz 0.46-0.87 deg,
but BROAD +2-18 % and static_accel 0.65-1.13 deg (ratio 4.5-10.9x): none admissible.

Issue 26's rate acceptance with these defaults (`ahrsgen tune adukf --params gyro_noise,
gyro_rate_noise,sigma_acc,sigma_acc_density,sigma_mag_density,accel_tau --budget 30 --folds 0`,
on /tmp/rs/b286 .. b48 or `--scenario multirotor --seeds 3 --scenario-opt rate_hz=R
--scenario-opt mag_rate=100`; the best of the tune from these defaults and the one from the
defaults before, BROAD's outputs being the same bits for the same parameters): BROAD 286 / 143
/ 95 / 48 Hz 2.767 / 2.898 / 3.015 / 3.710 against 2.321 / 2.427 / 2.565 / 3.443 (+19 / +19 /
+18 / +8 %), multirotor 400 Hz 0.359 against 0.264 (+0.095 deg), 1 kHz 1.217 against 0.533:
met at 48 Hz and 400 Hz only.
"""
from __future__ import annotations

import itertools
import sys

import adukf_motion_cv as motion
import adukf_rate_cv as rate
import logo_cv

WORSE_MAX = 1.10
SCENARIOS = {**motion.SCENARIOS, "fixedwing_gps": ("fixedwing_gps", {})}
BEFORE = {"accel_tau": 1.0, "sigma_acc": 0.05, "sigma_acc_density": 0.016, "gyro_noise": 0.003}


def candidates(second_round=False):
    yield BEFORE
    for tau, sa, sd, g in itertools.product((1.0, 2.7), (0.05, 0.12), (0.016, 0.004), (0.003, 0.002)):
        c = {"accel_tau": tau, "sigma_acc": sa, "sigma_acc_density": sd, "gyro_noise": g}
        if c != BEFORE:
            yield c
    if not second_round:
        return
    # second round: toward the multirotor's per-rate tunes with the GPS (1 kHz: a larger
    # accelerometer density, a shorter low-pass)
    for tau, sa, sd, g in itertools.product((1.0, 0.5), (0.05, 0.12), (0.024, 0.04), (0.003, 0.002)):
        yield {"accel_tau": tau, "sigma_acc": sa, "sigma_acc_density": sd, "gyro_noise": g}


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    second = "--second-round" in argv
    argv = [a for a in argv if a != "--second-round"]
    return logo_cv.study(__doc__, argv, SCENARIOS, motion.SEEDS, candidates(second), BEFORE,
                         "adukf accel_tau x sigma_acc x sigma_acc_density x gyro_noise with the GPS "
                         "compensation, leave one BROAD group out", "defaults", "adukf", rates=rate.RATES,
                         keep=lambda c: motion._claim(tuple(sorted(c.items()))) >= motion.CLAIM_MIN,
                         admissible=lambda e, b: all(e[k] <= WORSE_MAX * b[k] for k in SCENARIOS))


if __name__ == "__main__":
    sys.exit(main())
