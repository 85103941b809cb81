"""`ahrsgen tune`: choose a filter's parameters from logs with a reference attitude.

The objective is what `ahrsgen run` and `bench` score: the float C through the firmware
harness (bench.Estimator: the log's site parameters set as the bench sets them, bench.score:
the scored rows, the heading frame, BROAD's decomposition), one RMS figure in degrees per log
(--metric total | inclination | heading), averaged over the logs. Logs are evaluated in
parallel on a Fleet (local processes, or Dask with --scheduler).

Search: Optuna's TPE sampler (chosen by measurement, README "Tuning"), each parameter inside
its declared range: log-uniform where the range spans two decades or more (a range starting at 0
starts 4 decades below its top, or a decade below the default if that is lower; one without a
top ends two decades above the default), uniform
otherwise; integers likewise; booleans and choices as categories. Every study starts with the
current values (defaults, or the --config/--set ones) as its first trial, so the tuned values
are never worse than them on the training logs.

Generalisation: with K folds the logs are split round-robin into K groups (sorted order); for
each group a study of the same budget is run on the other logs and its best values are scored
on the held-out group. The cross-validated error is the mean over every log of its held-out
score, printed beside the current values' error on the same logs.

Resume: every trial is written to a journal next to the output (<output>.journal, Optuna's
JournalFileStorage); re-running the same command skips the trials already done, so an
interrupted run continues where it stopped and a larger --budget extends a finished one.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from ahrsgen.errors import ConfigError

METRICS = {"total": "total_rms", "inclination": "inclination_rms", "heading": "heading_rms"}
PENALTY_DEG = 180.0          # a log whose run failed scores as a diverged estimate


# =========================================================================================
# Logs

@dataclass(frozen=True)
class Case:
    """One log: a file, or a simulated scenario seed."""
    kind: str                  # "file" | "scenario"
    arg: str                   # path, or scenario name
    seed: int = 0
    opts: tuple = ()           # scenario options, sorted (name, value) pairs

    @property
    def label(self) -> str:
        return Path(self.arg).name if self.kind == "file" else f"{self.arg}#{self.seed}"


@lru_cache(maxsize=64)
def load_case(case: Case):
    from ahrsgen.sim import readers, scenarios
    if case.kind == "file":
        return readers.read_log(case.arg)
    return scenarios.make(case.arg, seed=case.seed, **dict(case.opts))


LOG_SUFFIXES = (".csv", ".csv.gz", ".ulg")


def _check_log(path: str) -> None:
    """A log tuning can score: readable, with a reference attitude somewhere (else every trial
    would score the failure penalty and the 'best' values would be noise). One line if not."""
    from ahrsgen.sim import readers
    try:
        log = readers.read_log(path)
    except readers.LogError as e:
        raise ConfigError(str(e)) from None
    if log.q_true is None or not np.isfinite(log.q_true).all(axis=1).any():
        raise ConfigError(f"{path}: no reference attitude to tune against (CSV columns qw,qx,qy,qz; "
                          f"ULog topic vehicle_attitude)")
    for w in log.meta.get("warnings", []) + [f"{Path(path).name}: {u}" for u in readers.unit_warnings(log)]:
        print(f"ahrsgen: warning: {w}", file=sys.stderr)      # gains tuned to a log in wrong units are wrong


def collect_cases(logs=(), logs_dir=None, scenario=None, seeds=1, scenario_opts=()) -> list[Case]:
    cases = []
    for p in logs or []:
        if not Path(p).is_file():
            raise ConfigError(f"log file {p} does not exist")
        cases.append(Case("file", str(Path(p))))
    if logs_dir:
        d = Path(logs_dir)
        if not d.is_dir():
            raise ConfigError(f"--logs {d}: not a directory")
        found = sorted(p for p in d.iterdir() if p.is_file() and p.name.endswith(LOG_SUFFIXES))
        if not found:
            raise ConfigError(f"--logs {d}: no {', '.join(LOG_SUFFIXES)} files in it")
        cases += [Case("file", str(p)) for p in found]
    for c in cases:
        if c.kind == "file":
            _check_log(c.arg)
    if scenario:
        from ahrsgen.sim import scenarios
        if scenario not in scenarios.names():
            raise ConfigError(f"unknown scenario '{scenario}' (known: {', '.join(scenarios.names())})")
        if seeds < 1:
            raise ConfigError(f"--seeds {seeds}: need at least 1")
        opts = []
        for item in scenario_opts or []:
            k, eq, v = item.partition("=")
            if not eq:
                raise ConfigError(f"--scenario-opt {item!r}: expected NAME=VALUE")
            try:
                opts.append((k, float(v)))
            except ValueError:
                opts.append((k, v))
        cases += [Case("scenario", scenario, s, tuple(sorted(opts))) for s in range(seeds)]
    if not cases:
        raise ConfigError("no logs to tune on: give --log FILE, --logs DIR or --scenario NAME")
    if len(set(cases)) != len(cases):
        raise ConfigError("the same log is given twice")
    return cases


# =========================================================================================
# Search space from the parameter declarations

@dataclass
class Dim:
    name: str
    kind: str                   # "float" | "int" | "cat"
    low: float = 0.0
    high: float = 0.0
    log: bool = False
    choices: list = field(default_factory=list)

    def distribution(self):
        import optuna.distributions as d
        if self.kind == "float":
            return d.FloatDistribution(self.low, self.high, log=self.log)
        if self.kind == "int":
            return d.IntDistribution(int(self.low), int(self.high), log=self.log)
        return d.CategoricalDistribution(self.choices)

    def contains(self, v) -> bool:
        return v in self.choices if self.kind == "cat" else self.low <= v <= self.high

    def text(self) -> str:
        if self.kind == "cat":
            return "{" + ", ".join(map(str, self.choices)) + "}"
        return f"[{self.low:g}, {self.high:g}]{' log' if self.log else ''}"


def _open_low(p, hi):
    """Lower search bound of a positive range that is open at or below 0."""
    lo = hi * 1e-4
    if isinstance(p.default, (int, float)) and not isinstance(p.default, bool) and p.default > 0:
        lo = min(lo, p.default / 10)
    return lo


def search_space(spec, items: list[str]) -> list[Dim]:
    """--params entries 'name' or 'name=lo:hi' -> dimensions inside the declared ranges."""
    dims = []
    for item in items:
        name, eq, rng = item.partition("=")
        name = name.strip()
        if name not in spec.params:
            raise ConfigError(f"--params: unknown parameter '{name}' for filter {spec.name}; "
                              f"known: {', '.join(sorted(spec.params))}")
        if any(d.name == name for d in dims):
            raise ConfigError(f"--params: '{name}' given twice")
        p = spec.params[name]
        if p.type == "bool":
            dims.append(Dim(name, "cat", choices=[False, True]))
            continue
        if p.type == "str":
            if not p.choices:
                raise ConfigError(f"--params: '{name}' is free text, nothing to search")
            dims.append(Dim(name, "cat", choices=list(p.choices)))
            continue
        if eq:
            lo_t, colon, hi_t = rng.partition(":")
            if not colon:
                raise ConfigError(f"--params {item!r}: expected {name}=LOW:HIGH")
            lo = p.coerce(lo_t, f"--params {name} lower bound")
            hi = p.coerce(hi_t, f"--params {name} upper bound")
            if not lo < hi:
                raise ConfigError(f"--params {item!r}: LOW must be below HIGH")
        else:
            lo, hi = p.min, p.max
            positive = not isinstance(p.default, bool) and p.default > 0
            if hi is None and positive and (lo is None or lo >= 0):
                hi = p.default * 100           # no upper bound: two decades above the default
                lo = p.default / 100 if lo is None else lo
            if lo is None or hi is None:
                raise ConfigError(f"--params: '{name}' has an unbounded range {p.range_text()}; "
                                  f"give one as {name}=LOW:HIGH")
            if p.max_exclusive and hi == p.max:
                hi = hi - abs(hi) * 1e-9 if p.type == "float" else hi - 1
            if lo == 0 < hi and p.type == "float":
                lo = _open_low(p, hi)
            elif p.min_exclusive:
                lo = lo + abs(lo) * 1e-9 + (1e-12 if lo == 0 else 0.0) if p.type == "float" else lo + 1
        log = lo > 0 and hi / lo >= 100
        dims.append(Dim(name, "int" if p.type == "int" else "float", float(lo), float(hi), log))
    if not dims:
        raise ConfigError("--params: name at least one parameter to tune")
    return dims


def set_text(name, value) -> str:
    """name=value as --set takes it."""
    if isinstance(value, bool):
        return f"{name}={'true' if value else 'false'}"
    if isinstance(value, float):
        return f"{name}={value!r}"
    return f"{name}={value}"


# =========================================================================================
# Evaluation (runs in the workers)

def evaluate(task: dict) -> dict:
    """One log scored with one set of values: {'label', 'score'} or {'label', 'error'}."""
    from ahrsgen.bench import Estimator, score
    case = task["case"]
    try:
        log = load_case(case)
        # runtime engine: the real-valued parameters are set in C per run on one build
        # (built once per worker and structural combination); baked: one build per trial
        rt = {k: v for k, v in task["values"].items() if k in task["runtime"]}
        folded = {k: v for k, v in task["values"].items() if k not in rt}
        est = Estimator(task["filter"], "filter", task["heading"], filter=task["filter"],
                        sets=list(task["sets"]) + [set_text(k, v) for k, v in folded.items()],
                        config=task["config"], runtime=rt)
        q, heading, _ = est.run(log)
        return {"label": case.label, "score": score(q, log, heading)}
    except Exception as e:         # a value that breaks a run scores as divergence, and says why
        return {"label": case.label, "error": f"{type(e).__name__}: {e}"}


def case_error(result: dict, metric: str) -> float:
    if "error" in result:
        return PENALTY_DEG
    v = result["score"][METRICS[metric]]
    return float(v) if math.isfinite(v) else PENALTY_DEG


# =========================================================================================
# The tuner

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
    _print_report(rep, out)
    if not rep["recommended"]:
        rep["overrides"] = dict(base.overrides)
    if output:
        if rep["recommended"]:
            write_toml(output, rep, base)
        report = Path(str(output) + ".json")
        tmp = report.with_name(report.name + ".tmp")
        tmp.write_text(json.dumps({"written_by": "ahrsgen tune", **rep, "logs": [str(c.arg) if c.kind == "file" else c.label for c in cases]},
                                  indent=1, default=str) + "\n")
        os.replace(tmp, report)
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


def _print_report(rep, out):
    unit = f"{rep['metric']} (deg, mean over logs)"
    print(f"  current  {_fmt(rep['current'])}", file=out)
    print(f"  tuned    {_fmt(rep['tuned'])}", file=out)
    print(f"  {unit}:        current   tuned", file=out)
    print(f"    training ({len(rep['logs'])} logs)   {rep['train']['current']:9.3f} {rep['train']['tuned']:7.3f}",
          file=out)
    if rep["cv"]:
        cv = rep["cv"]
        print(f"    {cv['folds']}-fold cross-validated {cv['current']:9.3f} {cv['tuned']:7.3f}"
              "   (each log scored with values tuned without it)", file=out)
    w = max(len(x) for x in rep["logs"])
    for lbl in rep["logs"]:
        line = f"    {lbl:<{w}} current {rep['train']['per_log_current'][lbl]:7.3f}  tuned {rep['train']['per_log_tuned'][lbl]:7.3f}"
        if rep["cv"]:
            line += f"  held out {rep['cv']['per_log_held_out'][lbl]:7.3f}"
        print(line, file=out)
    print(f"  {rep['trials_run']} trial(s) run in {rep['seconds']:.1f} s", file=out)
    for e in rep["errors"][:5]:
        print(f"  run error (scored {PENALTY_DEG:g} deg): {e}", file=out)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    return json.dumps(str(v))


def filter_ref_for(spec, config_path) -> str:
    """How a config at config_path names the filter so that it resolves again: a built-in by its
    name, a folder by its path relative to the config's own folder (config.config_filter_ref)."""
    if spec.origin == "built-in":
        return spec.name
    return Path(os.path.relpath(spec.folder.resolve(), Path(config_path).resolve().parent)).as_posix()


def write_toml(path, rep, base) -> None:
    """A config `ahrsgen generate --config` takes: the tuned values and the --config/--set ones."""
    lines = ["# written by ahrsgen tune (a later tune may replace this file)",
             f"# ahrsgen tune {rep['filter']}: {', '.join(rep['search'])} on {len(rep['logs'])} log(s), "
             f"{rep['budget']} trials, {rep['metric']}",
             f"# training error: current {rep['train']['current']:.3f} deg, tuned {rep['train']['tuned']:.3f} deg"]
    if rep["cv"]:
        lines.append(f"# {rep['cv']['folds']}-fold cross-validated error: current {rep['cv']['current']:.3f} deg, "
                     f"tuned {rep['cv']['tuned']:.3f} deg")
    lines.append("# site parameters (declination, ...) were set per log and are not written here: set yours.")
    lines.append(f'filter = "{filter_ref_for(base.spec, path)}"')
    lines.append("")
    lines.append("[params]")
    for k, v in rep["overrides"].items():
        lines.append(f"{k} = {_toml_value(v)}")
    path = Path(path)
    if path.parent and not path.parent.is_dir():
        raise ConfigError(f"-o {path}: folder {path.parent} does not exist")
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("\n".join(lines) + "\n")
    os.replace(tmp, path)


# =========================================================================================
# CLI

def _cmd_tune(args) -> int:
    from ahrsgen import filters
    filters.load(args.filter)                       # unknown filter: one line
    out = Path(args.output)
    if not out.parent.is_dir():
        raise ConfigError(f"-o {out}: folder {out.parent} does not exist")
    cases = collect_cases(args.log, args.logs, args.scenario, args.seeds, args.scenario_opt)
    from ahrsgen.fileio import check_outputs
    from ahrsgen.filters import input_folders as filter_inputs
    logs = [c.arg for c in cases if c.kind == "file"]
    check_outputs([("-o", out), ("-o (its report)", Path(str(out) + ".json"))],
                  [*logs, args.config, *filter_inputs(args.filter)], args.force)
    check_outputs([("-o (its journal)", Path(str(out) + ".journal"))], [*logs, args.config], force=True)
    params = [p for item in args.params for p in _split_params(item)]
    try:
        tune(args.filter, params, cases, budget=args.budget, folds=args.folds, metric=args.metric,
             config_file=args.config, sets=args.set, workers=args.workers, scheduler=args.scheduler,
             output=out, seed=args.seed, progress=True, engine=args.engine)
    except TuneFailed as e:
        print(f"ahrsgen: tune failed: {e}", file=sys.stderr)
        return 1
    return 0


def _split_params(text: str) -> list[str]:
    return [s.strip() for s in text.split(",") if s.strip()]


def register_cli(sub) -> None:
    from ahrsgen.argtypes import nonneg_int_arg, positive_int_arg   # loaded: it is the caller
    p = sub.add_parser("tune", help="choose parameters from logs with a reference attitude; write a TOML config",
                       description="Search the named parameters of a filter inside their declared ranges (Optuna "
                                   "TPE) to minimise the RMS attitude error of its float C over logs with a "
                                   "reference, scored as 'ahrsgen run' and 'bench' score; report the training and "
                                   "K-fold cross-validated error beside the current values; write a config that "
                                   "'ahrsgen generate --config' takes. Interrupt and re-run to resume. The "
                                   "config is written only if the tuned values beat the current ones out of "
                                   "sample (cross-validated; with --folds 0, on the training logs); else exit 1 "
                                   "with the report only. Exit 1 too if the filter refuses most steps of a log.")
    p.add_argument("filter", help="filter name (see 'ahrsgen list')")
    p.add_argument("--log", action="append", default=[], metavar="FILE", help="BROAD .csv/.csv.gz or PX4 .ulg (repeatable)")
    p.add_argument("--logs", metavar="DIR", help="every .csv, .csv.gz and .ulg file in DIR")
    p.add_argument("--scenario", help="also simulated flights of this scenario (see 'ahrsgen list')")
    p.add_argument("--seeds", type=positive_int_arg, default=1, help="scenario seeds 0..N-1 (default 1)")
    p.add_argument("--scenario-opt", action="append", default=[], metavar="NAME=VALUE", help="scenario option")
    p.add_argument("--params", action="append", required=True, metavar="NAME[=LOW:HIGH],...",
                   help="parameters to tune, comma-separated; optional search range inside the declared one")
    p.add_argument("--metric", choices=list(METRICS), default="total",
                   help="error to minimise: BROAD's total, inclination or heading RMS (default total)")
    p.add_argument("--budget", type=positive_int_arg, default=40, help="trials per study (default 40)")
    p.add_argument("--folds", type=int, help="K-fold cross-validation over logs (default min(5, logs); 0 = none)")
    p.add_argument("--config", metavar="FILE.toml", help="start from this config (its values are kept)")
    p.add_argument("--set", metavar="NAME=VALUE", action="append", default=[], help="fix a parameter")
    p.add_argument("--workers", type=positive_int_arg, default=2, help="local worker processes (default 2)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run on this Dask distributed scheduler instead")
    p.add_argument("--seed", type=nonneg_int_arg, default=0, help="sampler seed, a whole number >= 0 (default 0)")
    p.add_argument("--engine", choices=["runtime", "baked"], default="runtime",
                   help="runtime (default): build once with the tuned real parameters as runtime parameters "
                        "and set them per trial; baked: fold them in and rebuild per trial")
    p.add_argument("-o", "--output", required=True, metavar="TUNED.toml",
                   help="config file to write (with TUNED.toml.json, the report); an existing file is replaced "
                        "only if ahrsgen wrote it (docs/output-files.md)")
    from ahrsgen.fileio import add_force_option
    add_force_option(p)
    p.set_defaults(func=_cmd_tune)
