"""The logs a tune scores: files with a reference attitude, or simulated scenario seeds."""
from __future__ import annotations

import sys
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ahrsgen.errors import ConfigError

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
