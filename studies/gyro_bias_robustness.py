"""How each filter's defaults take a gyro bias larger than the data they were chosen on.

BROAD's sensor and the simulated scenarios have gyro biases of 0.1-0.5 deg/s; an uncalibrated
MEMS gyro, or one whose offset drifted with temperature since the boot calibration, has 1 deg/s
and more. This adds a constant bias of B deg/s (along one fixed direction with all three axes:
(0.6, -0.8, 0.5) normalised) to the gyro of the 10 BROAD trials and scores the float defaults of
mekf, qcf and adukf, and VQF with its defaults, by BROAD's total RMS (mean over the trials).
Float C through the host build, as `ahrsgen run`; nothing is tuned.

    PYTHONPATH=src .venv/bin/python studies/gyro_bias_robustness.py [DATA_DIR] [--rate 95|286]
        [--bias 0,1,3] [--filters mekf,qcf,adukf,peer:vqf] [--json out.json]
        [--scenarios handheld,turntable,static_mag_disturbance]

Needs the full BROAD files (exit 2 with one line without them). With --scenarios, the product
filters are scored instead on those bench rows (simulated, seeds 0-2, as docs/<filter>.md's
scenarios block: `ahrsgen bench` scoring, the site parameters set from the log, so mag_ref is
the log's field, not learned) with the same bias added; no BROAD needed. A study, not a test:
nothing here asserts.

Result (2026-12-04, main at 7e206f7, --rate 95 --bias 0,1,2,3), mean total RMS in degrees:
mekf 2.23 / 2.23 / 2.24 / 2.36; qcf 2.61 / 2.60 / 5.40 / 12.07 (its rest detector takes a
low-passed rate above rest_gyro_tol, 2 deg/s, for a turn, so it never learns such a bias at
rest); adukf 3.22 / 3.49 / 3.86 / 39.08 (its bias state starts at p0_bias = 1e-4 (rad/s)^2, a
0.6 deg/s standard deviation); VQF 3.07 / 3.08 / 3.08 / 12.06 (its bias estimate is clipped at
biasClip = 2 deg/s).

adukf after issue 26's rest_gyro_max = 0.1 rad/s (was 0.05: a 3 deg/s offset kept its rest test,
on the raw gyro, from ever passing, so the dip was never learned and the magnetometer never
used; trials 24/26/28/32 never left MAG_LEARNING), bias 0/1/2/3/4/5 deg/s:
95 Hz 3.03 / 3.01 / 3.07 / 3.12 / 3.14 / 4.73 (before: 3.03 / 3.01 / 3.07 / 28.49 / 84.42 / 99.18);
286 Hz 2.77 / 2.77 / 2.84 / 2.88 / 2.96 / 5.04 (before: 2.77 / 2.77 / 2.84 / 27.34 / 84.36 / -).
The simulated scenarios (--scenarios) still degrade with the offset, because the bias state
learns it slowly (p0_bias 1e-4 (rad/s)^2, and the adaptive R takes the attitude error it causes
for a disturbance): see docs/adukf.md, "Gyro offset". `--scenarios handheld,turntable,
static_mag_disturbance,multirotor --filters mekf,qcf,adukf --bias 0,1,2,3` (same day, after it):
adukf handheld 0.06 / 0.13 / 0.20 / 0.39, turntable 0.19 / 0.47 / 1.27 / 2.54,
static_mag_disturbance 0.33 / 0.51 / 1.06 / 2.48, multirotor 0.68 / 0.76 / 1.03 / 1.81;
mekf 0.25 / 0.25 / 0.10 / 0.12, 0.52 / 0.54 / 0.53 / 2.04, 4.19 / 4.19 / 5.50 / 6.41,
0.93 / 0.94 / 0.95 / 0.96; qcf 0.33 / 0.33 / 0.34 / 0.67, 1.18 / 2.01 / 3.99 / 13.96,
4.94 / 4.96 / 5.07 / 6.18, 0.59 / 1.41 / 2.77 / 4.17.
"""
from __future__ import annotations

import argparse
import copy
import json
import sys
import time

import numpy as np

import logo_cv
from ahrsgen.generate import config
from ahrsgen.sim import host, peers
from ahrsgen.sim.peers import broad_score

DIRECTION = np.array([0.6, -0.8, 0.5]) / np.linalg.norm([0.6, -0.8, 0.5])
AVERAGE = {"286": 1, "143": 2, "95": 3, "48": 6}


def runner(name: str):
    """q over a log for a product filter's float defaults or a peer ('peer:vqf')."""
    if name.startswith("peer:"):
        return lambda log: peers.run(name.removeprefix("peer:"), log)
    built = host.build(config.resolve(name))
    return lambda log: built.run(log).q


def with_bias(log, bias_deg_s: float):
    out = copy.deepcopy(log)
    out.gyro = np.asarray(log.gyro) + np.radians(bias_deg_s) * DIRECTION
    return out


def scenarios_table(rows, names, biases) -> int:
    """Mean total RMS over seeds 0-2 on each bench row, as docs/<filter>.md's scenarios block."""
    from ahrsgen.bench.grid import scenario_configs
    from ahrsgen.bench.scoring import filter_estimator, score
    from ahrsgen.sim import scenarios
    grid = {label: (scen, opts) for label, scen, opts in scenario_configs(quick=False)}
    print("simulated scenarios, mean total RMS over seeds 0-2 (deg), constant gyro bias added:")
    print("| filter | scenario | " + " | ".join(f"{b:g} deg/s" for b in biases) + " |")
    print("|---|---|" + "---|" * len(biases))
    for name in names:
        est = filter_estimator(name)
        for row in rows:
            scen, opts = grid[row]
            logs = [scenarios.make(scen, seed=seed, **opts) for seed in (0, 1, 2)]
            cells = []
            for b in biases:
                totals = []
                for log in logs:
                    q, heading, _ = est.run(with_bias(log, b))
                    totals.append(score(q, log, heading)["total_rms"])
                cells.append(f"{np.mean(totals):.2f}")
            print(f"| {name} | {row} | " + " | ".join(cells) + " |", flush=True)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default=None)
    ap.add_argument("--rate", choices=sorted(AVERAGE), default="95")
    ap.add_argument("--bias", default="0,0.5,1,2,3", help="deg/s, comma-separated")
    ap.add_argument("--filters", default="mekf,qcf,adukf,peer:vqf")
    ap.add_argument("--json", default=None)
    ap.add_argument("--scenarios", default=None, help="bench rows, comma-separated (no BROAD)")
    a = ap.parse_args(argv)
    biases = [float(b) for b in a.bias.split(",")]
    names = a.filters.split(",")
    if a.scenarios:
        products = [n for n in names if not n.startswith("peer:")]
        return scenarios_table(a.scenarios.split(","), products, biases)
    broad = logo_cv.load_broad(a.data)
    if broad is None:
        print("the 10 BROAD trials are not here (shared data folder); nothing measured")
        return 2
    logs = {n: (log.averaged(AVERAGE[a.rate]) if AVERAGE[a.rate] > 1 else log)
            for n, log in broad[0].items()}
    table = {}
    for name in names:
        run = runner(name)
        t0 = time.perf_counter()
        table[name] = {}
        for b in biases:
            per = {n: broad_score(run(with_bias(log, b)), log)["total"] for n, log in sorted(logs.items())}
            table[name][b] = {"mean": float(np.mean(list(per.values()))), "trials": per}
        print(f"  {name}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    print(f"BROAD, 10 trials at {a.rate} Hz, mean total RMS (deg), constant gyro bias added:")
    print("| filter | " + " | ".join(f"{b:g} deg/s" for b in biases) + " |")
    print("|---|" + "---|" * len(biases))
    for name in names:
        print(f"| {name} | " + " | ".join(f"{table[name][b]['mean']:.2f}" for b in biases) + " |")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"rate_hz": a.rate, "direction": DIRECTION.tolist(),
                       "results": {n: {str(b): v for b, v in r.items()} for n, r in table.items()}}, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
