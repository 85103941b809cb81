"""Issue 25: choose the mekf hard-iron design by leave-one-group-out over BROAD, with the
attached-magnet scenario, and report the cross-validated figure beside the in-sample one.

    .venv/bin/python studies/mekf_hard_iron_cv.py [DATA_DIR] [--json out.json]

Candidates: the hard iron off (the design before issue 25) and a small grid of its three
tuning values (mag_bias_th, mag_bias_rw, mag_bias_noise); one parameter set for all data.
The score of a candidate on a set of logs is the mean total RMS (BROAD's method) over the
BROAD trials of the set plus, as one more entry, the attached_magnet scenario's mean heading
RMS over 5 seeds (scored from 30 s after the magnet arrives). For each BROAD group held out,
the candidate best on the other three groups (and the scenario) is chosen and scored on the
held-out group; the mean over the 10 trials of those held-out scores is the cross-validated
figure. Float C through the host build, as `ahrsgen run`. Needs the full BROAD files (the
shared data folder); says so and stops when they are absent.
"""
from __future__ import annotations

import argparse
import itertools
import json
import sys

import numpy as np

from ahrsgen.generate import config
from ahrsgen.sim import host
from ahrsgen.sim.peers import broad_score
from ahrsgen.sim.readers import broad_trials, read_log, shared_data_dir
from ahrsgen.sim.scenarios import make

GROUPS = {"rotation": ("01", "04", "06", "08"), "translation": ("10", "15"),
          "tapping, vibration": ("24", "26"), "magnet": ("28", "32")}
SEEDS = range(5)


def candidates():
    yield {"mag_bias": "false"}
    for th, rw, noise in itertools.product((0.01, 0.015, 0.03), (0.001, 0.003), (0.02, 0.05)):
        yield {"mag_bias_th": th, "mag_bias_rw": rw, "mag_bias_noise": noise}


def evaluate(sets, logs, scen):
    f = host.build(config.resolve("mekf", sets=[f"{k}={v}" for k, v in sets.items()]))
    broad = {n: broad_score(f.run(log).q, log)["total"] for n, log in logs.items()}
    heading = [broad_score(f.run(log).q, log)["heading"] for log in scen]
    return broad, float(np.mean(heading))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default=None)
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    data = shared_data_dir(a.data)
    paths = broad_trials(data) if data else []
    if len(paths) < 10:
        print("the 10 BROAD trials are not here (shared data folder); nothing measured")
        return 2
    logs = {p.name[:2]: read_log(p) for p in paths}
    scen = [make("attached_magnet", s) for s in SEEDS]
    results = []
    for i, sets in enumerate(candidates()):
        broad, head = evaluate(sets, logs, scen)
        results.append((sets, broad, head))
        print(f"[{i + 1}] {sets}: BROAD mean {np.mean(list(broad.values())):.3f}, magnet scenario heading {head:.2f}",
              file=sys.stderr, flush=True)

    def score(broad, head, trials):
        return (sum(broad[t] for t in trials) + head) / (len(trials) + 1)

    all_trials = [t for g in GROUPS.values() for t in g]
    best = min(results, key=lambda r: score(r[1], r[2], all_trials))
    rows, held = [], {}
    for g, trials in GROUPS.items():
        train = [t for t in all_trials if t not in trials]
        pick = min(results, key=lambda r: score(r[1], r[2], train))
        for t in trials:
            held[t] = pick[1][t]
        rows.append({"held_out": g, "chosen": pick[0], "held_out_mean": float(np.mean([pick[1][t] for t in trials])),
                     "in_sample_mean": float(np.mean([best[1][t] for t in trials]))})
    off = results[0]
    print("\nmekf hard iron, leave one BROAD group out (mean total RMS, degrees; float C)")
    print(f"{'group held out':22s} {'chosen on the rest':48s} {'held out':>9s} {'in-sample':>10s} {'no hard iron':>13s}")
    for r in rows:
        off_g = np.mean([off[1][t] for t in GROUPS[r['held_out']]])
        print(f"{r['held_out']:22s} {json.dumps(r['chosen']):48s} {r['held_out_mean']:9.2f} {r['in_sample_mean']:10.2f} {off_g:13.2f}")
    cv = float(np.mean([held[t] for t in all_trials]))
    ins = float(np.mean([best[1][t] for t in all_trials]))
    print(f"{'mean of 10':22s} {'':48s} {cv:9.3f} {ins:10.3f} {np.mean(list(off[1].values())):13.3f}")
    print(f"in-sample choice: {json.dumps(best[0])}; attached_magnet heading {best[2]:.2f} deg "
          f"(no hard iron: {off[2]:.2f} deg)")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"candidates": [{"sets": s, "broad": b, "scenario_heading": h} for s, b, h in results],
                       "folds": rows, "cross_validated": cv, "in_sample": ins, "in_sample_choice": best[0]}, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
