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

One module per step: cases (the logs), space (the search space), score (one log, one set of
values, in the workers), study (the Tuner: one Optuna study), run (tune(): search, folds,
report), report (what is printed and the config written), cli (`ahrsgen tune`).
"""
from __future__ import annotations

from ahrsgen.tune.cases import LOG_SUFFIXES, Case, collect_cases, load_case  # noqa: F401
from ahrsgen.tune.cli import register_cli  # noqa: F401
from ahrsgen.tune.report import filter_ref_for, write_toml  # noqa: F401
from ahrsgen.tune.run import TuneFailed, folds_of, tune  # noqa: F401
from ahrsgen.tune.score import METRICS, PENALTY_DEG, case_error, evaluate  # noqa: F401
from ahrsgen.tune.space import Dim, search_space, set_text  # noqa: F401
from ahrsgen.tune.study import Tuner, sampler  # noqa: F401
