"""Issue 26's rate line for adukf without GPS: the NED low-pass's own time constant and the
accelerometer's own density while no GPS compensation runs (accel_tau_unaided,
sigma_acc_density_unaided), and an accelerometer gate judged on a short-window mean of the
specific force (accel_gate: motor vibration is zero-mean at high frequency, a motion acceleration
is not), chosen by leave-one-BROAD-group-out at 286 / 143 / 95 / 48 Hz with the scenarios, the
multirotor WITHOUT GPS (250 Hz and 1 kHz) among them.

    PYTHONPATH=src:studies .venv/bin/python studies/adukf_gate_cv.py [DATA_DIR] [--json out.json]

The gate (model.gate_weight_expr): s, a NED low-pass of R(q-) f over accel_gate_tau (0.03 s),
e² = 1 - (s·a)²/(|s|²|a|²) with a the long low-pass (the sine² of their angle), and while the
gyro is slow (|ω - b| < accel_gate_rate) and no GPS compensation runs the accelerometer rows of
R divided by w = max(1/(1 + accel_gate e²), accel_gate_floor) (floor 0.1).

Kept only where issue 10's ratio holds (at least 10x on every angle of both static scenarios,
seed 0) against the plain DUKF, R fixed: k_a = k_m = 0 AND accel_gate = 0 (the gate adapts R to
the measurement too); the ratio with the gate left in the plain filter is printed as well.
Admissible only if every scenario entry stays within 10 % (or 0.05 deg) of the defaults before
(mekf_nogps_cv.py's rule), the multirotor without GPS included, and the gyro bias is still
learned within 2 % in 120 s (tests/filters/test_presets_physics.py's perfect-sensor spin). Issue 26's rate line (the
defaults within 10 % or 0.15 deg of the best per-rate tune known, TUNES) is printed per candidate
(LINE_OK), not used to choose. Needs the full BROAD files.

Result (2026-12-05, float C, mean total RMS, deg, BROAD 286 / 143 / 95 / 48 Hz): every fold, and
in-sample, chooses accel_tau_unaided 2.0, sigma_acc_density_unaided 0.008, accel_gate 3000 at
accel_gate_rate 0.3 (now the defaults): 2.449 / 2.574 / 2.689 / 3.429, held out the same, against
2.769 / 2.899 / 3.017 / 3.707 before and the bound 2.517 / 2.613 / 2.785 / 3.572 (TUNES + 10 %).
Per group held out: rotation 2.56/2.67/2.81/3.73 (before 2.66/2.74/2.83/3.57), translation
3.98/4.16/4.09/3.89 (4.76/4.86/4.82/4.53), tapping and vibration 1.47/1.47/1.51/1.63
(1.51/1.52/1.57/1.74), magnet 1.69/1.90/2.22/4.17 (2.25/2.63/3.03/5.12). Ratio 11.3x -> 17.0x
(the same with the gate in the plain DUKF). Scenarios (3 seeds) before -> chosen: multirotor
without GPS 0.841 -> 0.631, at 1 kHz 0.801 -> 0.556, static_accel 0.491 -> 0.342, static_mag
0.314 -> 0.294, turntable 0.197 -> 0.214, gyro_clip 0.071 -> 0.095, attached_magnet 0.084 ->
0.076; with a GPS (multirotor 250 / 400 / 1 000 Hz, fixedwing_gps) unchanged. Gyro bias after
120 s: 0.5 % -> 1.8 % off. Without the bias condition every candidate with 2.5 s or with 0.004 is
admissible and the in-sample choice is 2.5 s, 0.004, gate 1000 (2.366 / 2.493 / 2.619 / 3.445,
left out 2.418 / 2.542 / 2.670 / 3.494) with the bias 3.4 % off after 120 s (0.6 % after 240 s).
Without the gate no long low-pass keeps the ratio (2.0 s: 6.9x, with 0.008 9.0x).

Earlier rounds on the branch (the designs are gone from the code; figures as measured):
- commit 83d75cd: the gate judged on the tilt of s from the estimate's down, acting on R or on
  the long low-pass's gain (the sample weighed before it enters: the previous session's design
  with the short mean). On the gain it loses BROAD at every rate: accel_gate 10 / 100 at 1 rad/s
  3.271 / 3.406 / 3.511 / 4.213 and 3.341 / 3.479 / 3.578 / 4.276 (translation 4.76 -> 7.4: a
  back-and-forth motion averages to 0 only with every sample in), 1000 at 0.3 rad/s 2.800 /
  2.935 / 3.051 / 3.746 with the multirotor without GPS 0.84 -> 2.06. On R with
  accel_tau_unaided 2.0: 2.549 / 2.651 / 2.744 / 3.440 (every fold), short of the line once the
  tunes were re-run (TUNES below the earlier 2.321 / 2.427 / 2.565 / 3.443).
- commit 6a16660: the same with sigma_acc_density_unaided: every fold chose tau 2.0, d 0.004,
  gate 1000 at 0.3, 2.410 / 2.539 / 2.665 / 3.504, ratio 14.0x against R fixed but 4.8-5x with the
  gate left in the plain DUKF, and judged against the estimate's down the gate locks in after a
  sustained acceleration: a fixed-wing that never has a GPS 16.3 -> 44.3 deg (fixedwing_gps with
  motion_accel_model = none, 2 seeds; with this round's gate 25.8).
"""
from __future__ import annotations

import functools
import sys

import numpy as np

import adukf_gps_cv as gps
import adukf_motion_cv as motion
import adukf_rate_cv as rate
import logo_cv
from ahrsgen.generate import config
from ahrsgen.sim import host, metrics
from ahrsgen.sim.scenarios import make

SCENARIOS = {**gps.SCENARIOS,
             "multirotor_nogps": ("multirotor", {"gps_rate": 0}),
             "multirotor_1khz_nogps": ("multirotor", {"rate_hz": 1000.0, "mag_rate": 100.0, "gps_rate": 0})}
BEFORE = {"accel_tau_unaided": 0.0, "sigma_acc_density_unaided": 0.0, "accel_gate": 0.0}
# the best per-rate tune known of adukf without the gate (ahrsgen tune adukf --logs BROAD averaged
# to the rate --params gyro_noise=0.0002:0.005,gyro_rate_noise=0.003:0.03,sigma_acc=0.05:0.3,
# sigma_acc_density=0.002:0.03,sigma_mag_density=0.004:0.03,accel_tau_unaided=1:4 --set
# accel_gate=0 --budget 80 --folds 0, 2026-12-05; with the gate's parameters searched too, 286 Hz
# reached 2.307, not lower)
BIAS_MAX = 0.02
TUNES = {"": 2.288, "@143": 2.375, "@95": 2.532, "@48": 3.247}
GATES = ({"accel_gate": 0.0},
         {"accel_gate": 1000.0, "accel_gate_rate": 1.0},
         {"accel_gate": 1000.0, "accel_gate_rate": 0.3},
         {"accel_gate": 3000.0, "accel_gate_rate": 0.3})


def candidates():
    yield BEFORE
    for g in GATES[1:]:
        yield {"accel_tau_unaided": 0.0, "sigma_acc_density_unaided": 0.0, **g}
    for tau in (2.0, 2.5):
        for d in (0.0, 0.004, 0.008):
            for g in GATES:
                yield {"accel_tau_unaided": tau, "sigma_acc_density_unaided": d, **g}


def claim_ratio(sets: dict, plain_gate: bool) -> float:
    """motion.claim_ratio with the plain DUKF's gate off (plain_gate False) or left as in sets."""
    kv = motion.PAPER_SITE + [f"{k}={v}" for k, v in sets.items()]
    plain = kv + ["k_a=0", "k_m=0"] + ([] if plain_gate else ["accel_gate=0"])
    worst = float("inf")
    for name in ("static_accel_disturbance", "static_mag_disturbance"):
        log = make(name, 0)
        a, p = (metrics.euler_stats(host.build(config.resolve("adukf", sets=s)).run(log).q, log.q_true, log.t, 0.0)
                for s in (kv, plain))
        worst = min(worst, *(p[ang]["rms"] / a[ang]["rms"] for ang in ("roll", "pitch", "yaw")))
    return worst


@functools.cache
def _claim(items: tuple) -> float:
    r, r_in = claim_ratio(dict(items), False), claim_ratio(dict(items), True)
    print(f"claim {dict(items)}: {r:.1f}x (gate left in the plain DUKF: {r_in:.1f}x)", file=sys.stderr, flush=True)
    return r


@functools.cache
def _bias_error(items: tuple) -> float:
    """tests/filters/test_presets_physics.py's check, for a candidate: the largest error of the
    gyro bias learned in 120 s of a perfect-sensor spin with a known bias, as a fraction of it
    (the house asks at most 2 %: a longer low-pass without GPS learns the bias more slowly)."""
    import pathlib
    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests" / "filters"))
    from test_presets_physics import BIAS, _biased_spin
    b, _ = _biased_spin("adukf", None, tuple(f"{k}={v}" for k, v in items))
    err = float(np.max(np.abs(b - BIAS)) / np.max(np.abs(BIAS)))
    print(f"bias {dict(items)}: {100 * err:.2f} %", file=sys.stderr, flush=True)
    return err


def admissible(e, b, sets=None):
    return (all(e[k] <= max(1.1 * b[k], b[k] + 0.05) for k in SCENARIOS)
            and (sets is None or _bias_error(tuple(sorted(sets.items()))) < BIAS_MAX))


def line(e) -> str:
    means = {s: float(np.mean([e[t + s] for t in logo_cv.TRIALS])) for s in TUNES}
    ok = all(means[s] <= max(1.1 * t, t + 0.15) for s, t in TUNES.items())
    return " / ".join(f"{means[s]:.3f}" for s in TUNES) + (" LINE_OK" if ok else "")


def main(argv=None):
    a, broad = logo_cv.setup(__doc__, argv)
    if broad is None:
        return 2
    logo_cv.RATES = tuple(rate.RATES)
    scen = logo_cv.scenarios(SCENARIOS, motion.SEEDS)
    results = logo_cv.run(candidates(), *broad, scen, filter_name="adukf", more=logo_cv.at_rates(broad[0], rate.RATES))
    base = next(r for r in results if r[0] == BEFORE)
    print("\ncandidate: BROAD 286 / 143 / 95 / 48 Hz (rate line); ratio; admissible; scenarios")
    for sets, e in results:
        print(f"{sets}: {line(e)}; {_claim(tuple(sorted(sets.items()))):.1f}x; "
              f"{'adm' if admissible(e, base[1], sets) else 'NOT adm'}; bias {100 * _bias_error(tuple(sorted(sets.items()))):.1f} %; "
              + " ".join(f"{k} {e[k]:.3f}" for k in SCENARIOS))
    kept = [r for r in results if _claim(tuple(sorted(r[0].items()))) >= motion.CLAIM_MIN]
    kept = [r for r in kept if admissible(r[1], base[1], r[0])]
    cv = logo_cv.cross_validate(kept, list(scen))
    logo_cv.report("adukf accelerometer gate x accel_tau_unaided, leave one BROAD group out", cv,
                   ("defaults", base[1]), scen, results, a.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
