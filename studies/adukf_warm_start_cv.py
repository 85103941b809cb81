"""Issue 26: adukf's NED accelerometer low-pass with a warm start (accel_lp_warm, VQF's, as
mekf's accel_lpf_warm): until it has averaged accel_tau of samples it is their running mean,
instead of starting from its first sample and forgetting it as e^(-t/accel_tau). Chosen by
leave-one-BROAD-group-out (studies/logo_cv.py) at 286/143/95/48 Hz with the scenarios of
studies/adukf_gps_cv.py in the training set; the cross-validated figure beside the in-sample one.

    PYTHONPATH=src .venv/bin/python studies/adukf_warm_start_cv.py [DATA_DIR] [--json out.json] [--filter qcf]

--filter qcf (default adukf): the same study for qcf's NED low-pass (its accel_lp_warm, issue 26,
aiding.warm_lowpass_gain shared with adukf), the same BROAD rates and scenarios; issue 10's
ratio (adukf's motion claim) is adukf's only.

Why: the multirotor at 1 kHz (magnetometer 100 Hz) missed issue 26's rate acceptance (defaults
1.217 deg, its per-rate tune 0.533). studies/adukf_multirotor_windows.py: the gap is the start
(cold low-pass: 5-15 s 2.12 deg, 15-120 s 1.09, the second 120 s period 0.10). The filter
starts from one accelerometer sample that the motor vibration tilts by up to 15 deg; a low-pass
started from it keeps e^(-t/tau) of it while P is wide, and the gyro bias and the heading take
it. The warm start gives the first sample the weight 1/n. The GPS velocity's low-pass keeps
dt/(tau + dt) (as mekf; a running mean there lost on mekf). Not begun again after a gyro clip.

Candidates: the warm start off (the defaults before, the baseline) and on; kept only where
issue 10's acceptance holds (studies/adukf_motion_cv.py's claim, at least 10x) and admissible
only if every scenario entry stays within 10 % of the baseline's. Needs the full BROAD files.

Result (2026-12-04, float C): every fold chose the warm start, as in-sample does; BROAD 286 / 143
/ 95 / 48 Hz 2.769 / 2.899 / 3.017 / 3.707 deg out of sample (before 2.767 / 2.898 / 3.015 /
3.710; the groups move by at most 0.02); multirotor 250 Hz / 400 Hz / 1 kHz 0.427 / 0.359 / 1.217
-> 0.313 / 0.250 / 0.226 (the 1 kHz per-rate tune: 0.533; 400 Hz: 0.264), fixedwing_gps 1.774 ->
1.755, static_accel 0.492 -> 0.491, static_mag 0.313 -> 0.314, turntable 0.199 -> 0.197,
gyro_clip 0.072 -> 0.071, attached_magnet 0.084 -> 0.084; issue 10's ratio 11.3x both.

qcf (2026-12-04, float C, DATA_DIR holding broad/ of the 286 Hz trials): every fold chose the
warm start; BROAD 286 / 143 / 95 / 48 Hz 2.557 / 2.595 / 2.605 / 2.832 out of sample, as before
(every trial within 0.0002 deg); multirotor 250 Hz / 400 Hz / 1 kHz 0.586 / 0.591 / 0.560 ->
0.576 / 0.580 / 0.548, fixedwing_gps 0.888 -> 0.889, static_accel 5.567 both, static_mag 4.940
both, turntable 1.183 -> 1.182, gyro_clip 0.932 both, attached_magnet 0.517 both.
"""
from __future__ import annotations

import argparse
import sys

import adukf_gps_cv as gps
import adukf_motion_cv as motion
import adukf_rate_cv as rate
import logo_cv

BEFORE = {"accel_lp_warm": "false"}


def candidates():
    yield BEFORE
    yield {"accel_lp_warm": "true"}


def main(argv=None):
    ap = argparse.ArgumentParser(add_help=False)
    ap.add_argument("--filter", default="adukf", choices=("adukf", "qcf"))
    a, rest = ap.parse_known_args(argv)
    if a.filter == "qcf":
        return logo_cv.study(__doc__, rest, gps.SCENARIOS, motion.SEEDS, candidates(), BEFORE,
                             "qcf accelerometer low-pass warm start, leave one BROAD group out",
                             "before", "qcf", rates=rate.RATES,
                             admissible=lambda e, b: all(e[k] <= gps.WORSE_MAX * b[k] for k in gps.SCENARIOS))
    return logo_cv.study(__doc__, rest, gps.SCENARIOS, motion.SEEDS, candidates(), BEFORE,
                         "adukf accelerometer low-pass warm start, leave one BROAD group out",
                         "before", "adukf", rates=rate.RATES,
                         keep=lambda c: motion._claim(tuple(sorted(c.items()))) >= motion.CLAIM_MIN,
                         admissible=lambda e, b: all(e[k] <= gps.WORSE_MAX * b[k] for k in gps.SCENARIOS))


if __name__ == "__main__":
    sys.exit(main())
