"""Issue 26's rate line for mekf at 143 and 95 Hz: the motion the accelerometer low-pass leaves
as a density (its per-sample variance grows with the rate) instead of a per-sample term, chosen
with the residual adaptation by leave-one-BROAD-group-out at 286/143/95/48 Hz with the scenarios
of studies/mekf_nogps_cv.py (the multirotor without GPS included) and the static accelerometer
disturbance; the cross-validated figure beside the in-sample one.

    PYTHONPATH=src:studies .venv/bin/python studies/mekf_motion_density_cv.py [DATA_DIR] [--json out.json]

Why: the gravity rows' variance is accel_angle_noise^2 (per sample, the same at any rate) +
accel_noise_density^2 / dt. The per-sample term stood for the motion the 1 s earth-frame
low-pass leaves, an error correlated over about that second: N samples of it a second carry the
information of about one per low-pass time whatever N is, so as a per-sample variance it must
grow as 1/dt, a density, like the sensor's white noise. As a constant per sample (0.07 rad) it
made the tilt's trust per second fall with the rate: at 143 / 95 / 48 Hz the defaults trusted
gravity 34 / 51 / 72 % less per second than at 286 Hz. Per trial, the defaults lost at the
slower rates in the rotation trials (01, 04, 08: inclination 0.74 -> 0.89 -> 1.00 deg in trial
01 at 286 / 143 / 95 Hz, and the heading through the field's dip, 1.44 -> 1.60 -> 1.69) and in
the stationary magnet (28), more than the per-rate tunes do: 2.097 / 2.178 / 2.255 / 2.557 at
286/143/95/48 Hz against tune B's 1.920 / 1.948 / 2.019 / 2.329 (+9.2 / +11.8 / +11.7 / +9.8 %,
the line 10 %). Admissible, as issue 26 states its bounds: BROAD's mean at each rate within 10 %
(or 0.15 deg) of the best per-rate tune found (TUNES), the with-GPS multirotor (250 Hz, 400 Hz,
1 kHz), the fixed-wing and its GPS outage within 10 % of the defaults before, the fixed-wing at
0.5 deg or less, the multirotor at 1 deg or less, the attached magnet, hand-held, gyro-clip and
static accelerometer disturbance entries within 10 % (or 0.05 deg), and the multirotor without
GPS at 250 Hz and 1 kHz no worse than before (2 % slack). Needs the full BROAD files.

Result (2026-12-05, 207 candidates): every fold, and in-sample, chooses accel_angle_noise 1e-4
(its minimum: the per-sample term out of effect), accel_noise_density 0.004 (unchanged),
accel_adapt_cap 7, accel_adapt_sigmas 1.0 (now the defaults). Mean total RMS, degrees, float C,
286 / 143 / 95 / 48 Hz:

    group held out      held out (= in-sample)       before
    rotation            2.33/2.41/2.47/2.76          2.46/2.62/2.74/3.02
    translation         2.44/2.46/2.41/2.34          2.34/2.32/2.27/2.25
    tapping, vibration  1.57/1.58/1.62/1.90          1.57/1.59/1.63/1.82
    magnet              1.71/1.79/1.89/2.66          1.66/1.74/1.91/2.66
    mean of 10          2.077/2.132/2.175/2.485      2.097/2.178/2.255/2.557

Against the tunes (+8.2 / +9.7 / +7.7 / +6.7 %): all four rates within the line, left out as in
sample. Scenarios (3 seeds), before -> chosen: multirotor without GPS 250 Hz 2.649 -> 2.182,
1 kHz 3.222 -> 2.686; with GPS 250 Hz / 400 Hz / 1 kHz 0.379 / 0.329 / 0.258 -> 0.370 / 0.332 /
0.262; fixed-wing 0.359 -> 0.346, its GPS outage 0.480 -> 0.444; turntable 0.533 -> 0.334;
static accelerometer disturbance 3.391 -> 3.413; gyro clip 0.274 -> 0.248; attached magnet 0.269
-> 0.264; hand-held 0.252 -> 0.239; static magnetic disturbance 4.186 both. Without the static
accelerometer disturbance among the entries every fold chose accel_adapt_sigmas 0.8 (BROAD
2.081/2.130/2.168/2.474, that scenario 3.82: +13 %). The candidates beyond the grid's edge lose
the fixed-wing (0.42-0.50 deg) or BROAD's line at 143 Hz. TUNES at 143 Hz is the re-run tune of
the chosen defaults (`ahrsgen tune mekf --logs BROAD averaged to 143 Hz --params
accel_angle_noise,accel_noise_density,mag_heading_density,gyro_rate_noise,mag_dev_gain,
accel_adapt_sigmas --budget 150 --folds 0`: 1.943, tune B 1.948); at 95 Hz it finds tune B's
2.019 again. accel_angle_noise 0.02 with the same cap and threshold (in-sample 2.081 / 2.141 /
2.190 / 2.484) is +10.2 % at 143 Hz against that tune.
"""
from __future__ import annotations

import itertools
import sys

import logo_cv
from mekf_accel_density_cv import outage_logs
from mekf_gyro_step_noise_cv import SEEDS
from mekf_mag_dev_cv import KEEP, MULTIROTOR_MAX, RATES
from mekf_nogps_cv import FIXEDWING_MAX, SCENARIOS as NOGPS_SCENARIOS, WITH_GPS, broad_mean

# the scenarios of studies/mekf_nogps_cv.py, and the static accelerometer disturbance back (as in
# studies/mekf_accel_density_cv.py): the gravity rows' weighting is what it measures
SCENARIOS = {**NOGPS_SCENARIOS, "static_accel_disturbance": ("static_accel_disturbance", {})}
BEFORE = {"accel_angle_noise": 0.07, "accel_noise_density": 0.004, "accel_adapt_cap": 3.0,
          "accel_adapt_sigmas": 1.5}
# Issue 26's rate line: the best per-rate tunes of the model found so far (BROAD alone, 6
# parameters, budget 150): tune B of studies/mekf_rate_tunes_cv.py, at 143 Hz the re-run tune of
# the defaults this study chose (1.943; tune B 1.948)
TUNES = {"": 1.920, "@143": 1.943, "@95": 2.019, "@48": 2.329}
NOGPS = ("multirotor_nogps", "multirotor_1khz_nogps")
NOGPS_SLACK = 1.02
ANGLE_MIN = 1e-4            # accel_angle_noise's minimum: 1e-8 rad^2 per sample, none in effect


def candidates():
    yield BEFORE
    for a, d, cap, n in itertools.product((ANGLE_MIN, 0.02, 0.035), (0.004, 0.0045, 0.005, 0.0055),
                                          (3.0, 4.0, 5.0, 7.0), (0.8, 1.0, 1.2, 1.5)):
        yield {"accel_angle_noise": a, "accel_noise_density": d, "accel_adapt_cap": cap, "accel_adapt_sigmas": n}
    # beyond the grid's edge (a smaller density, a larger cap, a lower threshold): none admissible
    for a, d, cap, n in itertools.product((ANGLE_MIN, 0.02), (0.0035, 0.004), (7.0, 10.0), (0.6, 0.8)):
        if (d, cap, n) != (0.004, 7.0, 0.8):
            yield {"accel_angle_noise": a, "accel_noise_density": d, "accel_adapt_cap": cap, "accel_adapt_sigmas": n}


def admissible(e, base):
    return (all(broad_mean(e, s) <= max(1.1 * t, t + 0.15) for s, t in TUNES.items())
            and all(e[k] <= 1.1 * base[k] for k in WITH_GPS) and e["fixedwing_gps"] <= FIXEDWING_MAX
            and e["multirotor"] <= MULTIROTOR_MAX
            and all(e[k] <= max(1.1 * base[k], base[k] + 0.05) for k in (*KEEP, "static_accel_disturbance"))
            and all(e[k] <= NOGPS_SLACK * base[k] for k in NOGPS))


def main(argv=None):
    return logo_cv.study(__doc__, argv, SCENARIOS, SEEDS, candidates(), BEFORE,
                         "mekf: the low-pass's motion as a density, with the residual adaptation, "
                         "leave one BROAD group out",
                         "before", "mekf", rates=RATES,
                         extra_logs=outage_logs,
                         admissible=admissible)


if __name__ == "__main__":
    sys.exit(main())
