"""mekf's heading gate (mag_head_sigmas, mag_head_tau): the magnetometer rejected while its
heading innovation, low-passed over mag_head_tau, exceeds mag_head_sigmas standard deviations of
the filter's own heading uncertainty (model.heading_check_function), chosen by
leave-one-BROAD-group-out at 286/143/95/48 Hz with the scenarios of studies/mekf_nogps_cv.py
(static magnetic disturbance, attached magnet, gyro clip, fixed-wing with and without GPS,
multirotor with and without GPS); the cross-validated figure beside the in-sample one.

    .venv/bin/python studies/mekf_heading_gate_cv.py [DATA_DIR] [--json out.json]

Why: a field turned by nearby steel with its norm and dip barely changed passes the field check
(static_mag_disturbance's y offset: the field's direction turns ~37 deg, its norm 4 % off):
mekf followed it to 10.8 deg heading error and its heading RMS over the scenario was 4.19 deg
(adukf, whose R grows with the residual, 0.30). Admissible: BROAD's mean at each rate at most 2 %
above the gate off, the multirotor at 1.0 deg or less, the fixed-wing at 0.5 deg or less, the
attached magnet, hand-held, gyro clip and the fixed-wing's GPS outage within 10 % (or 0.05 deg)
of the gate off.

Result (2026-12-05, float C): in sample and in three folds mag_head_sigmas 5, mag_head_tau 0.5
s (the new defaults; the magnet group held out chooses tau 1). Mean total RMS, degrees,
286 / 143 / 95 / 48 Hz:

    group held out      held out                     gate off
    rotation            2.47/2.62/2.73/3.02          2.46/2.62/2.74/3.02
    translation         2.34/2.32/2.27/2.25          2.34/2.32/2.27/2.25
    tapping, vibration  1.58/1.60/1.65/1.81          1.57/1.59/1.63/1.82
    magnet              1.68/1.75/1.92/2.67          1.66/1.74/1.91/2.66
    mean of 10          2.109/2.182/2.261/2.553      2.097/2.178/2.255/2.557
    in sample           2.109/2.172/2.249/2.554

Scenarios (3 seeds), gate off -> on: static_mag_disturbance 4.186 -> 0.103, attached_magnet
0.269 -> 0.248, multirotor without GPS 250 Hz 2.649 -> 2.552, 1 kHz 3.222 -> 3.131; the
multirotor with GPS (0.379 / 0.329 / 0.258), turntable 0.533, hand-held 0.252, gyro clip 0.274,
fixed-wing 0.359 and its GPS outage 0.480 unchanged. Smaller gates lose the rotation trials
(k 2: BROAD at 286 Hz 2.68-3.15, k 3: 2.36-2.70, k 4: 2.15-2.42; trial 08 up to 7.2 deg): their
P is too confident for their field's real errors: the choice is one step above that edge
(k 4, tau 1: 2.325 at 286 Hz). k 6-10 are within 0.01 deg of the gate off on BROAD at every
rate and hold the static disturbance less (k 6, tau 1: 0.17; k 10, tau 0.5: 0.25 with BROAD
2.095/2.176/2.254/2.557, no rate worse than the gate off).
"""
from __future__ import annotations

import itertools
import sys

import logo_cv
from mekf_accel_density_cv import outage_logs
from mekf_gyro_step_noise_cv import KEEP, SEEDS
from mekf_mag_dev_cv import FIXEDWING_MAX, MULTIROTOR_MAX, RATES
from mekf_nogps_cv import SCENARIOS, broad_mean

BROAD_SLACK = 1.02
OFF = {"mag_head_sigmas": 0.0, "mag_head_tau": 1.0}


def candidates():
    yield OFF
    for k, tau in itertools.product((2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0), (0.5, 1.0, 2.0)):
        yield {"mag_head_sigmas": k, "mag_head_tau": tau}


def admissible(e, base):
    return (all(broad_mean(e, s) <= BROAD_SLACK * broad_mean(base, s) for s in RATES)
            and e["multirotor"] <= MULTIROTOR_MAX and e["fixedwing_gps"] <= FIXEDWING_MAX
            and all(e[k] <= max(1.1 * base[k], base[k] + 0.05) for k in KEEP))


def main(argv=None):
    return logo_cv.study(__doc__, argv, SCENARIOS, SEEDS, candidates(), OFF,
                         "mekf heading gate, leave one BROAD group out", "gate off", "mekf", rates=RATES,
                         extra_logs=outage_logs,
                         admissible=admissible)


if __name__ == "__main__":
    sys.exit(main())
