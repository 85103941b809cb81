"""Leave one BROAD group out: the cross-validation the defaults studies choose their defaults by
(mekf by default; `filter_name` for another filter).

A candidate is one parameter set for all data (as BROAD scores every peer). Its entries are the
10 BROAD trials, each scored as recorded (286 Hz) and averaged to 95 Hz (every three rows one,
as an integrating IMU reports them: one default for any rate), and any simulated scenarios the
study adds, each one more entry (its mean over seeds). The score of a candidate on a set of
trials is the mean of its entries: per trial the mean of its 286 Hz and 95 Hz totals, plus the
scenario entries, which are always in the training set. For each BROAD group held out, the
candidate best on the other groups (and the scenarios) is chosen and scored on the held-out
group; the mean over the 10 trials of those held-out scores is the cross-validated figure, shown
beside the in-sample choice's. Float C through the host build, as `ahrsgen run`.
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from ahrsgen.bench.scoring import filter_estimator, score
from ahrsgen.generate import config
from ahrsgen.sim import host
from ahrsgen.sim.peers import broad_score
from ahrsgen.sim.readers import broad_trials, read_log, shared_data_dir

GROUPS = {"rotation": ("01", "04", "06", "08"), "translation": ("10", "15"),
          "tapping, vibration": ("24", "26"), "magnet": ("28", "32")}
TRIALS = [t for g in GROUPS.values() for t in g]
RATES = ("", "@95")          # entry suffixes: as recorded, averaged to 95 Hz (a study may set more)
AVERAGING = {"@143": 2, "@95": 3, "@48": 6}   # suffix: rows averaged into one from 286 Hz


def setup(doc: str, argv=None):
    """A study's command line ([DATA_DIR] [--json FILE]) and its BROAD logs: (args, (logs,
    logs at 95 Hz)), the logs None (said on stdout) when the 10 trials are not there."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("data", nargs="?", default=None)
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    broad = load_broad(a.data)
    if broad is None:
        print("the 10 BROAD trials are not here (shared data folder); nothing measured")
    return a, broad


def write_json(path, results, cv) -> None:
    if path:
        with open(path, "w") as fh:
            json.dump({"candidates": [{"sets": s, "entries": e} for s, e in results], **cv}, fh, indent=1)


def scenarios(spec: dict, seeds=range(3)) -> dict:
    """{label: [log per seed]} of a study's scenario entries, spec {label: (scenario, options)}."""
    from ahrsgen.sim.scenarios import make
    return {label: [make(name, s, **opts) for s in seeds] for label, (name, opts) in spec.items()}


def load_broad(data_dir=None):
    """{trial: log} and {trial: log averaged to 95 Hz}, or None when the 10 trials are absent."""
    data = shared_data_dir(data_dir)
    paths = broad_trials(data) if data else []
    if len(paths) < len(TRIALS):
        return None
    logs = {p.name[:2]: read_log(p) for p in paths}
    return logs, {n: log.averaged(3) for n, log in logs.items()}


def at_rates(logs, rates) -> dict:
    """{suffix: {trial: log averaged}} for the rates besides 286 and 95 Hz (`slow`) in `rates`."""
    return {sfx: {n: log.averaged(AVERAGING[sfx]) for n, log in logs.items()}
            for sfx in rates if sfx not in ("", "@95")}


def evaluate(sets: dict, logs, slow, scenarios: dict, measure: str = "total", filter_name: str = "mekf",
             more=None) -> dict:
    """{entry: figure}: BROAD totals per trial and rate (`more`: at_rates' further rates), and per
    scenario the mean of `measure` ('total' or 'heading' RMS) over its logs, run and scored as
    `ahrsgen bench` does (the log's site parameters set, magnetic heading turned by the
    scenario's declination)."""
    sets_kv = [f"{k}={v}" for k, v in sets.items()]
    f = host.build(config.resolve(filter_name, sets=sets_kv))
    out = {n: broad_score(f.run(log).q, log)["total"] for n, log in logs.items()}
    for sfx, lg in {"@95": slow, **(more or {})}.items():
        out |= {n + sfx: broad_score(f.run(log).q, log)["total"] for n, log in lg.items()}
    est = filter_estimator(filter_name, sets_kv)
    for name, scen_logs in scenarios.items():
        runs = [(est.run(log), log) for log in scen_logs]        # (q, heading frame, extra)
        out[name] = float(np.mean([score(r[0], log, r[1])[measure + "_rms"] for r, log in runs]))
    return out


def objective(res: dict, trials, extra) -> float:
    """Per trial the mean over RATES (a study may set more), plus the scenario entries."""
    return (sum(sum(res[t + s] for s in RATES) / len(RATES) for t in trials) + sum(res[e] for e in extra)) / (len(trials) + len(extra))


def run(candidates, logs, slow, scenarios: dict, measure="total", progress=sys.stderr, filter_name="mekf",
        more=None) -> list:
    """[(sets, entries)] of every candidate, a line of progress each."""
    results = []
    rates = ("", "@95", *(more or {}))
    for i, sets in enumerate(candidates):
        res = evaluate(sets, logs, slow, scenarios, measure, filter_name, more)
        results.append((sets, res))
        extra = ", ".join(f"{k} {res[k]:.2f}" for k in scenarios)
        print(f"[{i + 1}] {json.dumps(sets)}: BROAD " + " / ".join(
              f"{sfx or '286'} {np.mean([res[t + sfx] for t in logs]):.3f}" for sfx in rates)
              + (f"; {extra}" if extra else ""), file=progress, flush=True)
    return results


def cross_validate(results, extra, admissible=None) -> dict:
    """The in-sample choice, and per held-out group the choice on the rest with its held-out
    figures; only among the candidates whose entries `admissible` accepts (a bound a study
    states, e.g. an issue's 'nothing lost' figure on a scenario), when given."""
    results = [r for r in results if admissible is None or admissible(r[1])]
    best = min(results, key=lambda r: objective(r[1], TRIALS, extra))
    folds, held = [], {}
    for g, trials in GROUPS.items():
        pick = min(results, key=lambda r: objective(r[1], [t for t in TRIALS if t not in trials], extra))
        for t in trials:
            for sfx in RATES:
                held[t + sfx] = pick[1][t + sfx]
        folds.append({"held_out": g, "chosen": pick[0],
                      **{f"held_out_mean{s}": float(np.mean([pick[1][t + s] for t in trials])) for s in RATES},
                      **{f"in_sample_mean{s}": float(np.mean([best[1][t + s] for t in trials])) for s in RATES}})
    return {"in_sample_choice": best[0], "in_sample_entries": best[1], "folds": folds,
            "cross_validated": {s: float(np.mean([held[t + s] for t in TRIALS])) for s in RATES},
            "in_sample": {s: float(np.mean([best[1][t + s] for t in TRIALS])) for s in RATES}}


def print_table(title: str, cv: dict, baseline: tuple[str, dict]) -> None:
    """Folds, the means of 10 and the baseline (label, entries) beside them, 286 Hz / 95 Hz."""
    label, base = baseline
    w = 7 * len(RATES) - 1

    def cols(v, d=2):
        return "/".join(f"{x:.{d}f}" for x in v).rjust(w)
    print(f"\n{title} (mean total RMS, degrees; float C): " + " / ".join(s[1:] + " Hz" if s else "286 Hz" for s in RATES))
    print(f"{'group held out':22s} {'chosen on the rest':70s} {'held out':>{w}s} {'in-sample':>{w}s} {label:>{w}s}")
    for r in cv["folds"]:
        b = [np.mean([base[t + s] for t in GROUPS[r["held_out"]]]) for s in RATES]
        print(f"{r['held_out']:22s} {json.dumps(r['chosen']):70s} {cols(r['held_out_mean' + s] for s in RATES)} "
              f"{cols(r['in_sample_mean' + s] for s in RATES)} {cols(b)}")
    c, i = cv["cross_validated"], cv["in_sample"]
    b = [float(np.mean([base[t + s] for t in TRIALS])) for s in RATES]
    print(f"{'mean of 10':22s} {'':70s} {cols((c[s] for s in RATES), 3)} {cols((i[s] for s in RATES), 3)} {cols(b, 3)}")
    print(f"in-sample choice: {json.dumps(cv['in_sample_choice'])}")


def report(title: str, cv: dict, baseline: tuple[str, dict], scenarios, results, json_path) -> None:
    """A study's output: print_table, the scenario entries of the in-sample choice beside the
    baseline's, and the JSON (write_json)."""
    label, base = baseline
    print_table(title, cv, baseline)
    print("scenarios (mean total RMS over seeds, degrees): " + "; ".join(
        f"{k} {cv['in_sample_entries'][k]:.3f} ({label} {base[k]:.3f})" for k in scenarios))
    write_json(json_path, results, cv)


def defaults_entry(results) -> tuple[dict, dict]:
    """The candidate whose values are the present defaults."""
    p = config.resolve("mekf").params

    def same(a, b):
        try:
            return float(a) == float(b)
        except (TypeError, ValueError):
            return str(a).lower() == str(b).lower()
    return next(r for r in results if all(same(p[k], v) for k, v in r[0].items()))


def study(doc: str, argv, scenario_spec: dict, seeds, candidates, before: dict, title: str, label: str,
          filter_name: str, admissible=None, keep=None, rates=None, extra_logs=None) -> int:
    """A defaults study's whole run: the command line, the BROAD logs (at `rates`, default
    RATES: each trial's objective the mean over them) and the scenario entries (and
    `extra_logs(seeds)`: {label: [log per seed]} of logs the scenarios cannot name), every
    candidate, the one whose values are `before` (the baseline column), leave-one-group-out over
    the candidates `keep` accepts (all by default) that `admissible(entries, before's entries)`
    accepts, and the report. 2 when the BROAD files are absent."""
    global RATES
    a, broad = setup(doc, argv)
    if broad is None:
        return 2
    if rates is not None:
        RATES = tuple(rates)
    scen = scenarios(scenario_spec, seeds) | (extra_logs(seeds) if extra_logs else {})
    results = run(candidates, *broad, scen, filter_name=filter_name, more=at_rates(broad[0], RATES))
    base = next(r for r in results if r[0] == before)
    kept = [r for r in results if keep is None or keep(r[0])]
    cv = cross_validate(kept, list(scen), admissible=None if admissible is None else
                        (lambda e: admissible(e, base[1])))
    report(title, cv, (label, base[1]), scen, results, a.json)
    return 0
