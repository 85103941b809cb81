"""tune(): the search on every log, K-fold cross-validation, the report and the config."""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from ahrsgen.errors import ConfigError
from ahrsgen.fileio import write_text_atomic
from ahrsgen.tune.report import print_report, write_toml
from ahrsgen.tune.score import METRICS
from ahrsgen.tune.space import search_space
from ahrsgen.tune.study import Tuner, _fmt

def folds_of(n: int, k: int) -> list[list[int]]:
    """Round-robin split of n logs into k held-out groups."""
    return [list(range(i, n, k)) for i in range(k)]


def tune(filter_name, params, cases, budget=40, folds=None, metric="total", config_file=None, sets=(),
         workers=2, scheduler=None, output=None, seed=0, out=None, progress=True,
         engine="runtime") -> dict:
    """Tune, cross-validate, write the TOML (and the report as JSON beside it); returns the report."""
    out = out or sys.stdout
    from ahrsgen.generate import config
    if metric not in METRICS:
        raise ConfigError(f"--metric {metric!r}: one of {', '.join(METRICS)}")
    if budget < 1:
        raise ConfigError(f"--budget {budget}: need at least 1 trial")
    try:
        import optuna  # noqa: F401   (the search; an optional extra)
    except ImportError:
        raise ConfigError("ahrsgen tune searches with Optuna, which is not installed: "
                          "pip install 'ahrsgen[tune]'") from None
    base = config.resolve(filter_name, config_file, list(sets), "float", None)
    dims = search_space(base.spec, params)
    n = len(cases)
    k = (min(5, n) if n >= 2 else 0) if folds is None else folds
    if k == 1 or k < 0 or k > n:
        raise ConfigError(f"--folds {k}: need 0 (none) or 2..{n} (the number of logs)")
    journal = Path(str(output) + ".journal") if output else None
    t0 = time.time()
    try:
        return _tune(filter_name, dims, cases, budget, k, metric, config_file, sets, workers, scheduler,
                     output, journal, seed, out, progress, engine, base, t0)
    except KeyboardInterrupt:
        if progress:
            sys.stderr.write("\n")       # end the progress bar's line
        raise


def _tune(filter_name, dims, cases, budget, k, metric, config_file, sets, workers, scheduler, output, journal,
          seed, out, progress, engine, base, t0):
    from ahrsgen.bench import Progress
    from ahrsgen.sim.fleet import Fleet
    n = len(cases)
    with Fleet(workers, scheduler) as fleet:
        prog = Progress(budget * (1 + k) + 1, stream=sys.stderr) if progress else None
        tuner = Tuner(filter_name, dims, cases, fleet, metric, config_file, sets, seed, journal, prog, engine)
        print(f"tune {filter_name} on {n} log(s), {METRICS[metric]} mean over logs, budget {budget} trials"
              f"{f', {k}-fold cross-validation' if k else ''}, on {fleet.where}", file=out)
        print("  search: " + "; ".join(f"{d.name} {d.text()}" for d in dims), file=out)
        print(f"  engine: {'one build, ' + ', '.join(tuner.runtime) + ' set at run time' if tuner.runtime else 'one build per trial (values folded)'}",
              file=out)
        start = tuner.current()
        start_errs = tuner.scores(start, cases)
        refused = [e for e in tuner.last_errors if e and e.startswith("MostlyRefused")]
        if refused:                  # the filter does not run on a log: nothing to tune from
            raise TuneFailed(refused[0].partition(": ")[2] + " (with the starting values)")
        if prog:
            prog.update("current values")
        best, train, ran = tuner.optimise(cases, budget, "all logs")
        best_errs = tuner.scores(best, cases)
        cv = None
        if k:
            held = [None] * n
            fold_rows = []
            for i, test in enumerate(folds_of(n, k)):
                train_cases = [c for j, c in enumerate(cases) if j not in test]
                vals, _, r = tuner.optimise(train_cases, budget, f"fold {i + 1}/{k}")
                ran += r
                errs = tuner.scores(vals, [cases[j] for j in test])
                for j, e in zip(test, errs):
                    held[j] = e
                fold_rows.append({"held_out": [cases[j].label for j in test], "values": vals,
                                  "held_out_error": float(np.mean(errs)),
                                  "current_error": float(np.mean([start_errs[j] for j in test]))})
            cv = {"folds": k, "tuned": float(np.mean(held)), "current": float(np.mean(start_errs)),
                  "per_fold": fold_rows, "per_log_held_out": dict(zip([c.label for c in cases], held))}
    seconds = time.time() - t0
    rep = {"filter": filter_name, "metric": METRICS[metric], "budget": budget, "logs": [c.label for c in cases],
           "search": {d.name: d.text() for d in dims}, "current": start, "tuned": best,
           "train": {"current": float(np.mean(start_errs)), "tuned": float(np.mean(best_errs)),
                     "per_log_current": dict(zip([c.label for c in cases], start_errs)),
                     "per_log_tuned": dict(zip([c.label for c in cases], best_errs))},
           "cv": cv, "trials_run": ran, "seconds": seconds, "errors": tuner.errors,
           "overrides": {**base.overrides, **best}}
    # Recommended only if the tuned values beat the starting ones where it counts: on held-out
    # logs (cross-validation), else (no folds) on the training logs, said to be in-sample.
    judge = cv if cv else rep["train"]
    rep["recommended"] = bool(judge["tuned"] < judge["current"])
    rep["judged_on"] = f"{cv['folds']}-fold cross-validation" if cv else "the training logs (in-sample only)"
    print_report(rep, out)
    if not rep["recommended"]:
        rep["overrides"] = dict(base.overrides)
    if output:
        if rep["recommended"]:
            write_toml(output, rep, base)
        report = Path(str(output) + ".json")
        write_text_atomic(report, json.dumps({"written_by": "ahrsgen tune", **rep, "logs": [str(c.arg) if c.kind == "file" else c.label for c in cases]},
                                     indent=1, default=str) + "\n")
        if rep["recommended"]:
            print(f"wrote {output} and {report.name} (the report; journal {journal.name}: re-running continues "
                  f"it)", file=out)
        else:
            print(f"wrote {report.name} (the report; journal {journal.name}); {output} not written", file=out)
    if not rep["recommended"]:
        raise TuneFailed(f"the tuned values ({_fmt(best)}) do not beat the starting ones ({_fmt(start)}) on "
                         f"{rep['judged_on']}: {judge['tuned']:.3f} vs {judge['current']:.3f} deg; "
                         f"not recommended, keep the starting values")
    if not cv:
        print("  note: no cross-validation (--folds 0 or one log): the improvement is on the training logs only",
              file=out)
    return rep


class TuneFailed(Exception):
    """A tune that produced nothing to recommend (one line; `ahrsgen tune` exits 1)."""
