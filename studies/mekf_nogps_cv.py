"""Issue 26 (defaults for any motion): mekf's residual-adaptive gravity noise (accel_adapt_cap,
and accel_adapt_sigmas, the residual in gravity-direction sigmas at which R doubles: R = sigma^2
min(1 + |z|^2 / (accel_adapt_sigmas sigma)^2, accel_adapt_cap)) chosen by
leave-one-BROAD-group-out at 286/143/95/48 Hz with the scenarios of
studies/mekf_gyro_step_noise_cv.py and the multirotor without GPS (gps_rate=0, as indoors) at
250 Hz and 1 kHz added; the cross-validated figure beside the in-sample one.

    .venv/bin/python studies/mekf_nogps_cv.py [DATA_DIR] [--json out.json]

Why: none of the earlier studies' scenario sets has a vehicle without GPS, and without it mekf's
tilt on the multirotor was as bad as VQF's (total / inclination 4.61 / 4.26 deg against adukf's
0.84 / 0.40, whose R is residual-adaptive): the gravity rows trust the low-passed specific force
through the flips and the dash (20-44 s: 9.6 and 8.0 deg inclination RMS), where a tilted thrust
accelerates the vehicle for seconds and the 1 s low-pass keeps it. Admissible: BROAD's mean at
each of the four rates at most 2 % above the defaults before (over all 10 trials: the bound the
issue states, so the choice among admissible candidates is the only part cross-validated), the
with-GPS multirotor (250 Hz, 400 Hz, 1 kHz), fixed-wing and its GPS outage within 10 % of before
and the fixed-wing at 0.5 deg or less, the attached magnet, hand-held and gyro-clip entries within
10 % (or 0.05 deg), and BROAD's mean at each rate within issue 26's bound of the best per-rate
tune of today's mekf (TUNES: 10 % or 0.15 deg). Needs the full BROAD files.

Result (2026-12-04): every fold, and in-sample, chooses accel_adapt_cap 3, accel_adapt_sigmas 1.5
(now the defaults). Mean total RMS, degrees, float C, 286 / 143 / 95 / 48 Hz:

    group held out      held out (= in-sample)       before
    rotation            2.46/2.62/2.74/3.02          2.44/2.60/2.72/3.01
    translation         2.34/2.32/2.27/2.25          2.22/2.22/2.17/2.17
    tapping, vibration  1.57/1.59/1.63/1.82          1.57/1.59/1.62/1.82
    magnet              1.66/1.74/1.91/2.66          1.74/1.77/1.89/2.73
    mean of 10          2.097/2.178/2.255/2.557      2.084/2.155/2.225/2.550

Scenarios (3 seeds), before -> chosen: multirotor without GPS 250 Hz 4.614 -> 2.649, 1 kHz
5.397 -> 3.222; with GPS multirotor 250 Hz / 400 Hz / 1 kHz 0.379 / 0.329 / 0.258 unchanged,
fixed-wing 0.347 -> 0.359, its GPS outage 0.596 -> 0.480, turntable 0.532 -> 0.533, attached
magnet, hand-held, gyro clip unchanged. Without the tune bound every fold chooses
accel_adapt_sigmas 1.2 (BROAD 2.093/2.182/2.260/2.556: 143 Hz is then 10.1 % above its tune;
without GPS 2.665 / 3.099). Outside the study, for 1.2 (seeds 3-5, total / inclination):
without GPS 250 Hz 4.66/4.26 -> 2.71/2.47, 400 Hz (no rate of the study) 4.99/4.54 -> 2.88/2.61,
1 kHz 5.42/4.91 -> 3.12/2.86. The cap alone at the old threshold (cap 3, sigmas 3) gives 3.02 /
3.89 without GPS and BROAD 2.093/2.170/2.244/2.561. More aggressive candidates (cap 5-10,
sigmas <= 1.2) gain more without GPS (down to 1.74 / 2.35) but cost BROAD more than 2 %.
adukf without GPS: 0.84 total; mekf's remaining gap is not closed by this.
"""
from __future__ import annotations

import sys

import logo_cv
from mekf_accel_density_cv import outage_logs
from mekf_gyro_step_noise_cv import KEEP, SCENARIOS as GPS_SCENARIOS, SEEDS
from mekf_mag_dev_cv import RATES

SCENARIOS = {**GPS_SCENARIOS,
             "multirotor_nogps": ("multirotor", {"gps_rate": 0}),
             "multirotor_1khz_nogps": ("multirotor", {"rate_hz": 1000.0, "mag_rate": 100.0, "gps_rate": 0})}
WITH_GPS = ("multirotor", "multirotor_400hz", "multirotor_1khz", "fixedwing_gps", "fixedwing_gps_outage")
FIXEDWING_MAX = 0.5
BROAD_SLACK = 1.02
BEFORE = {"accel_adapt_cap": 1.0, "accel_adapt_sigmas": 3.0}      # the defaults before this study
# Issue 26's rate bound: the best per-rate tune of today's mekf (ahrsgen tune mekf --logs BROAD
# averaged to the rate --params accel_angle_noise,accel_noise_density,mag_heading_density,
# gyro_rate_noise,mag_dev_gain --budget 150 --folds 0, 2026-12-04, after the earth-frame error);
# the defaults must stay within 10 % (or 0.15 deg) of it at every rate.
TUNES = {"": 1.9378, "@143": 1.9821, "@95": 2.0626, "@48": 2.3868}


def candidates():
    yield BEFORE
    for cap in (2.0, 3.0, 5.0, 10.0):
        for n in (3.0, 2.0, 1.5, 1.2, 1.0, 0.7):
            yield {"accel_adapt_cap": cap, "accel_adapt_sigmas": n}


def broad_mean(e, sfx):
    return sum(e[t + sfx] for t in logo_cv.TRIALS) / len(logo_cv.TRIALS)


def admissible(e, base):
    return (all(broad_mean(e, s) <= BROAD_SLACK * broad_mean(base, s) for s in RATES)
            and all(broad_mean(e, s) <= max(1.1 * t, t + 0.15) for s, t in TUNES.items())
            and all(e[k] <= 1.1 * base[k] for k in WITH_GPS) and e["fixedwing_gps"] <= FIXEDWING_MAX
            and all(e[k] <= max(1.1 * base[k], base[k] + 0.05) for k in KEEP))


def main(argv=None):
    return logo_cv.study(__doc__, argv, SCENARIOS, SEEDS, candidates(), BEFORE,
                         "mekf residual-adaptive gravity noise with the multirotor without GPS, "
                         "leave one BROAD group out",
                         "before", "mekf", rates=RATES,
                         extra_logs=outage_logs,
                         admissible=admissible)


if __name__ == "__main__":
    sys.exit(main())
