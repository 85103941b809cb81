"""Issue 26: the ADUKF on BROAD's translation trials and at 95 Hz. With the NED low-pass turned
with each correction (accel_lp_follow) and a smaller constant gyro density (gyro_noise 0.003),
the density that grows with each axis's rate (gyro_rate_noise: a MEMS gyro's scale-factor and
cross-axis errors), the low-pass's time constant (accel_tau) and the accelerometer's noise
density (sigma_acc_density), all per second, not per sample, chosen by leave-one-group-out over
BROAD with the simulated scenarios; the cross-validated figure beside the in-sample one
(studies/logo_cv.py, as the other defaults studies).

    .venv/bin/python studies/adukf_motion_cv.py [DATA_DIR] [--json out.json]

Why (docs/adukf.md, "Translation and sample rate"): with the low-pass at 1 s, BROAD's slow
hand translations leave 3.1 deg (trial 10) and 8.5 deg (trial 15) of motion on the measured
gravity direction (computed with the reference attitude). With a gyro density of 0.01
rad/s/sqrt(Hz) the ADUKF fuses the accelerometer with a time constant near 1 s, so that motion
reaches the estimate (3 deg of tilt in motion on trial 10, mekf 0.3), and its adaptive R counts
the estimate's own error as a disturbance and keeps the accelerometer out while it lasts (R_acc
10-25 times its quiet value; trial 08 at 95 Hz: 140 times, 6 deg of tilt). A longer low-pass or
a smaller gyro density could not be had before: the low-pass, held in NED of q-, keeps the old
attitude's error after each correction and pulls it back (the multirotor at accel_tau 2 s: 10
deg), which accel_lp_follow removes. A first run of this study over gyro_noise (0.003, 0.005,
0.01) x gyro_rate_noise (0.005, 0.01, 0.015) x accel_tau (1, 1.5) at sigma_acc_density 0.008,
without the 400 Hz and 1 kHz bounds, chose 0.003, 0.015 and 1.5 s (BROAD 2.544 / 2.837 in-sample,
2.657 / 3.151 left out, at 286 / 95 Hz) but lost the multirotor at 1 kHz (1.32 -> 2.41 deg); the
accelerometer's density is in the grid for that (0.024: 1.44 deg).

Scenarios, each one entry (mean total RMS over 3 seeds): the multirotor at 250, 400 and 1 000
Hz, both static disturbances, the turntable, the gyro over-range and the magnet attached to the
sensor. Candidates are kept only where issue 10's acceptance holds (the adaptive filter at least
10 times better than the plain DUKF, k_a = k_m = 0, on every angle of both static scenarios,
seed 0, as tests/filters/adukf/test_adukf.py::test_adaptive_beats_plain_on_every_angle), and are admissible
only if the multirotor at 250 Hz is no worse than before and at 400 Hz and 1 kHz, the static
disturbances, gyro_clip and attached_magnet within 10 % of before. Needs the full BROAD files;
says so and stops when they are absent.
"""
from __future__ import annotations

import functools
import itertools
import sys

import logo_cv
from ahrsgen.generate import config
from ahrsgen.sim import host, metrics
from ahrsgen.sim.scenarios import make

SEEDS = range(3)
WORSE_MAX = 1.10
CLAIM_MIN = 10.0
KEPT = ("multirotor_400hz", "multirotor_1khz", "static_accel_disturbance", "static_mag_disturbance", "gyro_clip",
        "attached_magnet")
SCENARIOS = {"multirotor": ("multirotor", {}),
             "multirotor_400hz": ("multirotor", {"rate_hz": 400.0, "mag_rate": 100.0}),
             "multirotor_1khz": ("multirotor", {"rate_hz": 1000.0, "mag_rate": 100.0}),
             "static_accel_disturbance": ("static_accel_disturbance", {}),
             "static_mag_disturbance": ("static_mag_disturbance", {}),
             "turntable": ("turntable", {}),
             "gyro_clip": ("gyro_clip", {}),
             "attached_magnet": ("attached_magnet", {})}
BEFORE = {"accel_lp_follow": False, "gyro_noise": 0.01, "gyro_rate_noise": 0.0, "accel_tau": 1.0,
          "sigma_acc_density": 0.008}
# the paper's site, which tests/filters/adukf/test_adukf.py flies the static scenarios with
PAPER_SITE = ["mag_ref=inclination", "inclination_deg=53.0", "declination=-0.061086523819801536"]


def candidates():
    yield BEFORE
    for r, tau, d in itertools.product((0.01, 0.015), (1.0, 1.5), (0.008, 0.016, 0.024, 0.032)):
        yield {"accel_lp_follow": True, "gyro_noise": 0.003, "gyro_rate_noise": r, "accel_tau": tau,
               "sigma_acc_density": d}


def claim_ratio(sets: dict) -> float:
    """The smallest over both static scenarios (seed 0) and the three angles of plain RMS over
    adaptive RMS, float C (issue 10's acceptance: at least 10); plain: R fixed (k_a = k_m = 0,
    accel_gate = 0)."""
    kv = PAPER_SITE + [f"{k}={v}" for k, v in sets.items()]
    worst = float("inf")
    for name in ("static_accel_disturbance", "static_mag_disturbance"):
        log = make(name, 0)
        a, p = (metrics.euler_stats(host.build(config.resolve("adukf", sets=s)).run(log).q, log.q_true, log.t, 0.0)
                for s in (kv, kv + ["k_a=0", "k_m=0", "accel_gate=0"]))
        worst = min(worst, *(p[ang]["rms"] / a[ang]["rms"] for ang in ("roll", "pitch", "yaw")))
    return worst


@functools.cache
def _claim(items: tuple) -> float:
    r = claim_ratio(dict(items))
    print(f"claim {dict(items)}: {r:.1f}x", file=sys.stderr, flush=True)
    return r


def main(argv=None):
    return logo_cv.study(__doc__, argv, SCENARIOS, SEEDS, candidates(), BEFORE,
                         "adukf gyro_rate_noise x accel_tau x sigma_acc_density (low-pass turned), leave one BROAD group out",
                         "before", "adukf", keep=lambda c: _claim(tuple(sorted(c.items()))) >= CLAIM_MIN,
                         admissible=lambda e, b: e["multirotor"] <= b["multirotor"]
                         and all(e[k] <= WORSE_MAX * b[k] for k in KEPT))


if __name__ == "__main__":
    sys.exit(main())
