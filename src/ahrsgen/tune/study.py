"""The Tuner: one Optuna study per set of training logs, resumable from its journal."""
from __future__ import annotations

import hashlib
import json
import sys

import numpy as np

from ahrsgen.errors import ConfigError
from ahrsgen.tune.score import case_error, evaluate

class Tuner:
    def __init__(self, filter_name, dims, cases, fleet, metric="total", config_file=None, sets=(),
                 seed=0, journal=None, progress=None, engine="runtime"):
        from ahrsgen.bench import filter_heading
        from ahrsgen.generate import config
        self.filter = filter_name
        self.dims = dims
        self.cases = cases
        self.fleet = fleet
        self.metric = metric
        self.config_file = config_file
        self.sets = list(sets)
        self.seed = seed
        self.base = config.resolve(filter_name, config_file, self.sets, "float", None)
        self.heading = filter_heading(filter_name, self.sets, config_file)
        self.journal = journal
        self.progress = progress
        self.errors: list[str] = []
        self._storage = None
        self.runtime = self._runtime_names() if engine == "runtime" else ()

    def _runtime_names(self) -> tuple:
        """Tuned real parameters the model takes at run time (the others are rebuilt per trial)."""
        from ahrsgen.generate import config, render
        names = tuple(d.name for d in self.dims if self.base.spec.params[d.name].type == "float")
        if not names:
            return ()
        try:
            cfg = config.resolve(self.filter, self.config_file, self.sets, "float", None, runtime=list(names))
            render.render(cfg)
            return names
        except ConfigError as e:
            print(f"  (runtime engine not possible: {e}; rebuilding per trial)", file=sys.stderr)
            return ()

    # ---- evaluation ---------------------------------------------------------------------
    def current(self) -> dict:
        """The values the search starts from (defaults, or --config/--set)."""
        return {d.name: self.base.params[d.name] for d in self.dims}

    def scores(self, values: dict, cases) -> list[float]:
        tasks = [{"case": c, "filter": self.filter, "config": self.config_file, "sets": self.sets,
                  "heading": self.heading, "values": values, "runtime": self.runtime} for c in cases]
        res = self.fleet.map(evaluate, tasks)
        self.last_errors = [r.get("error") for r in res]
        for r in res:
            if "error" in r and r["error"] not in self.errors:
                self.errors.append(f"{r['label']} with {values}: {r['error']}")
        return [case_error(r, self.metric) for r in res]

    # ---- one study -----------------------------------------------------------------------
    def storage(self):
        if self._storage is None:
            import optuna
            from optuna.storages.journal import JournalFileBackend
            if self.journal is None:
                self._storage = optuna.storages.InMemoryStorage()
            else:
                self._storage = optuna.storages.JournalStorage(JournalFileBackend(str(self.journal)))
        return self._storage

    def study_key(self, cases) -> str:
        h = hashlib.sha256(json.dumps({
            "filter": self.filter, "overrides": self.base.overrides, "metric": self.metric,
            "dims": [vars(d) for d in self.dims], "cases": [vars(c) for c in cases], "seed": self.seed,
        }, sort_keys=True, default=str).encode()).hexdigest()[:16]
        return f"{self.filter}-{h}"

    def optimise(self, cases, budget: int, what: str) -> tuple[dict, float, int]:
        """Best values, their mean error on `cases`, trials run now (the rest came from the journal)."""
        import optuna
        from optuna.trial import TrialState
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        study = optuna.create_study(study_name=self.study_key(cases), storage=self.storage(),
                                    direction="minimize", load_if_exists=True,
                                    sampler=sampler(self.seed, budget))
        for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
            study.tell(t.number, state=TrialState.FAIL)     # left running by an interrupted run
        dists = {d.name: d.distribution() for d in self.dims}
        done = len(study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)))
        if done == 0 and not study.get_trials(deepcopy=False, states=(TrialState.WAITING,)):
            start = self.current()
            if all(d.contains(start[d.name]) for d in self.dims):
                study.enqueue_trial(start)
        ran = 0
        for _ in range(done, budget):
            trial = study.ask(dists)
            values = {d.name: _typed(self.base.spec.params[d.name], trial.params[d.name]) for d in self.dims}
            errs = self.scores(values, cases)
            trial.set_user_attr("per_log", errs)
            study.tell(trial, float(np.mean(errs)))
            ran += 1
            if self.progress:
                self.progress.update(f"{what}: trial {trial.number} {_fmt(values)} -> {np.mean(errs):.3f}")
        if self.progress:
            for _ in range(budget - done - ran):
                self.progress.update(f"{what}: from the journal")
        best = study.best_trial
        values = {d.name: _typed(self.base.spec.params[d.name], best.params[d.name]) for d in self.dims}
        return values, float(best.value), ran


def sampler(seed: int, budget: int):
    """TPE; its random start-up phase scaled to the budget (Optuna's 10 would leave a budget
    of 8 a pure random search)."""
    import optuna
    return optuna.samplers.TPESampler(seed=seed, n_startup_trials=max(3, min(10, budget // 3)))


def _typed(p, v):
    if p.type == "float":
        return float(v)
    if p.type == "int":
        return int(v)
    return v


def _fmt(values: dict) -> str:
    return ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in values.items())
