"""Issue 26's rate line for adukf: an accelerometer gate judged on a short-window mean of the
specific force (motor vibration is zero-mean at high frequency, a motion acceleration is not),
and the low-pass's own time constant while no GPS measures the motion (accel_tau_unaided),
chosen by leave-one-BROAD-group-out at 286 / 143 / 95 / 48 Hz with the scenarios, the
multirotor WITHOUT GPS (250 Hz and 1 kHz) among them.

    PYTHONPATH=src:studies .venv/bin/python studies/adukf_gate_cv.py [DATA_DIR] [--json out.json]

The gate (model.gate_weight_expr): s, a NED low-pass of R(q-) f over accel_gate_tau (0.03 s),
e² = (s_x² + s_y²)/|s|² (the sine² of its tilt from the estimate's down), and while the gyro is
slow (|ω - b| < accel_gate_rate) and no GPS compensation runs a weight
w = max(1/(1 + accel_gate e²), accel_gate_floor) (floor 0.1). accel_gate_apply says what w
acts on: "r" divides the accelerometer rows of R by it (the rejection acts on the correction, as
VQF's; the low-pass stays linear), "gain" multiplies the low-pass's gain by it (the sample
weighed before it enters the low-pass, the brief's design with the short-window judgement).

Kept only where issue 10's ratio holds (at least 10x on every angle of both static scenarios,
seed 0) against the plain DUKF, k_a = k_m = 0 AND accel_gate = 0: the gate is an adaptive R (a
weight from the measurement), so the plain DUKF has none; the ratio with the gate left in the
plain filter is printed too. Admissible only if every scenario entry stays within 10 % (or
0.05 deg) of the defaults' (mekf_nogps_cv.py's rule), the multirotor without GPS included.
Issue 26's rate line (the defaults within 10 % or 0.15 deg of the best per-rate tune: 2.321 /
2.427 / 2.565 / 3.443 at 286 / 143 / 95 / 48 Hz, studies/adukf_gps_cv.py) is printed per
candidate (LINE_OK), not used to choose. Needs the full BROAD files.
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
BEFORE = {"accel_tau_unaided": 0.0, "accel_gate": 0.0}
TUNES = {"": 2.321, "@143": 2.427, "@95": 2.565, "@48": 3.443}
GATES = ({"accel_gate": 0.0},
         {"accel_gate": 100.0, "accel_gate_rate": 1.0},
         {"accel_gate": 1000.0, "accel_gate_rate": 1.0},
         {"accel_gate": 1000.0, "accel_gate_rate": 0.3})


def candidates():
    yield BEFORE
    for tau in (0.0, 1.5, 2.0, 2.5):
        for g in GATES:
            c = {"accel_tau_unaided": tau, **g}
            if c != BEFORE:
                yield c
    # without GPS the accelerometer's density term on its own (the GPS regime keeps 0.016)
    for tau in (2.0, 2.5):
        for d in (0.004, 0.008, 0.012):
            for g in (GATES[0], GATES[2], GATES[3]):
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


def admissible(e, b):
    return all(e[k] <= max(1.1 * b[k], b[k] + 0.05) for k in SCENARIOS)


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
              f"{'adm' if admissible(e, base[1]) else 'NOT adm'}; "
              + " ".join(f"{k} {e[k]:.3f}" for k in SCENARIOS))
    kept = [r for r in results if _claim(tuple(sorted(r[0].items()))) >= motion.CLAIM_MIN]
    cv = logo_cv.cross_validate(kept, list(scen), admissible=lambda e: admissible(e, base[1]))
    logo_cv.report("adukf accelerometer gate x accel_tau_unaided, leave one BROAD group out", cv,
                   ("defaults", base[1]), scen, results, a.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
