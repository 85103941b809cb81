"""Which optimizer `ahrsgen tune` uses: Optuna TPE vs CMA-ES (`cma`) vs SciPy (Powell), same budget.

    python docs/tune_optimizer_choice.py FILTER PARAMS BUDGET SEEDS [--set k=v ...] LOG [LOG ...]

(needs `pip install cma scipy` besides the dev extras). Optuna and CMA-ES are run with SEEDS
sampler seeds each (Powell is deterministic).
Each optimizer minimises the same objective as `ahrsgen tune` (ahrsgen.tune.Tuner.scores:
the float C through the harness, mean total RMS over the logs) over the same search space,
starting from the current values, with the same number of objective evaluations. Prints the
best error after each quarter of the budget and writes the table as JSON on stdout's last line.
"""
from __future__ import annotations

import json
import math
import sys
import time

import numpy as np


def main(filter_name, params, budget, logs, seed=0, sets=()):
    from ahrsgen import tune
    from ahrsgen.sim.fleet import Fleet
    cases = tune.collect_cases(logs)
    with Fleet(2) as fleet:
        from ahrsgen.generate import config
        base = config.resolve(filter_name, sets=list(sets))
        dims = tune.search_space(base.spec, params.split(","))
        assert all(d.kind == "float" for d in dims), "this comparison handles float parameters"
        tuner = tune.Tuner(filter_name, dims, cases, fleet, sets=sets)

        def to_values(u):           # [0,1]^n -> parameter values (log where the space is)
            out = {}
            for d, x in zip(dims, np.clip(u, 0, 1)):
                out[d.name] = float(math.exp(math.log(d.low) + x * (math.log(d.high) - math.log(d.low))) if d.log
                               else d.low + x * (d.high - d.low))
            return out

        def to_unit(values):
            return np.array([(math.log(values[d.name]) - math.log(d.low)) / (math.log(d.high) - math.log(d.low))
                             if d.log else (values[d.name] - d.low) / (d.high - d.low) for d in dims])

        x0 = to_unit(tuner.current())
        results = {}

        class Done(Exception):
            pass

        def counted(trace):
            def f(u):
                if len(trace) >= budget:
                    raise Done
                e = float(np.mean(tuner.scores(to_values(u), cases)))
                trace.append(e)
                return e
            return f

        # Optuna TPE: what tune runs
        t0 = time.time()
        tuner.journal = None
        import optuna
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        study = optuna.create_study(sampler=tune.sampler(seed, budget))
        study.enqueue_trial(tuner.current())
        trace = []
        dists = {d.name: d.distribution() for d in dims}
        for _ in range(budget):
            tr = study.ask(dists)
            e = float(np.mean(tuner.scores(dict(tr.params), cases)))
            study.tell(tr, e)
            trace.append(e)
        results["optuna_tpe"] = (trace, time.time() - t0)

        # CMA-ES in the unit cube, from the current values
        import cma
        t0 = time.time()
        trace = []
        f = counted(trace)
        es = cma.CMAEvolutionStrategy(x0, 0.3, {"bounds": [0, 1], "seed": seed + 1, "verbose": -9, "maxfevals": budget})
        try:
            while not es.stop():
                xs = es.ask()
                es.tell(xs, [f(x) for x in xs])
        except Done:
            pass
        results["cma_es"] = (trace, time.time() - t0)

        # SciPy Powell (bounded, derivative-free), from the current values: deterministic
        from scipy.optimize import minimize
        if seed:
            return _table(filter_name, params, budget, cases, results, seed)
        t0 = time.time()
        trace = []
        f = counted(trace)
        try:
            minimize(f, x0, method="Powell", bounds=[(0, 1)] * len(dims), options={"maxfev": budget})
        except Done:
            pass
        results["scipy_powell"] = (trace, time.time() - t0)

    return _table(filter_name, params, budget, cases, results, seed)


def _table(filter_name, params, budget, cases, results, seed):
    table = {}
    for name, (trace, sec) in results.items():
        best = np.minimum.accumulate(trace)
        marks = {f"best_after_{q}": float(best[min(len(best), max(1, budget * q // 4)) - 1]) for q in (1, 2, 3, 4)}
        table[name] = {**marks, "evaluations": len(trace), "seconds": round(sec, 1)}
        print(f"seed {seed} {name:<14} " + "  ".join(f"{k[-1]}/4: {v:7.3f}" for k, v in marks.items() if k.startswith("best"))
              + f"   ({len(trace)} evaluations, {sec:.0f} s)")
    print(json.dumps({"filter": filter_name, "params": params, "budget": budget, "seed": seed,
                      "logs": [c.label for c in cases], "results": table}), flush=True)


if __name__ == "__main__":
    args = sys.argv[5:]
    sets = [a.split("=", 1)[1] if a.startswith("--set=") else a for a in args if a.startswith("--set=")]
    logs = [a for a in args if not a.startswith("--set=")]
    for s in range(int(sys.argv[4])):
        main(sys.argv[1], sys.argv[2], int(sys.argv[3]), logs, seed=s, sets=sets)
