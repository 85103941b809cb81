"""docs/cpf.md's tables, re-measured: the paper's Table 1 on `turntable` (double C, seeds 0-9),
every scenario at the defaults (double and float C, seed 0), and state bytes and kernel
operations versus N. The tables are written by `python -m studies.cpf_report --write`; this file
re-runs the same measurements and compares them with the figures as written (host C is
deterministic: equal to the last digit the doc writes)."""
from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

from docs_tables import ROOT, numbers, outside, table

sys.path.insert(0, str(ROOT))          # the measurements are the study's own: studies/cpf_report.py
from studies import cpf_report as report  # noqa: E402
from ahrsgen.sim import scenarios          # noqa: E402

DOC = "docs/cpf.md"
EXACT = 0.0          # deterministic host C on seeded scenarios: equal as written


def _check(label: str, stated: list[str], got) -> list[str]:
    assert len(stated) == len(got), (label, stated)
    return [f"{label}: measured {g:.4f}, the doc says {s}" for s, g in zip(stated, got) if outside(s, g, EXACT)]


def _params(variant: str, mode: str, cell: str) -> dict | None:
    """The parameters of one Table 1 cell: the row says defaults, faithful or the tuned values."""
    if variant.endswith(", defaults"):
        return {"mode": mode}
    if ", faithful" in variant:
        return None if cell == "–" else {"mode": mode, "faithful": True}
    tuned = re.search(r"\((.*)\)", cell).group(1)
    return {"mode": mode, **{k: float(v) for k, v in (kv.split() for kv in tuned.split(", "))}}


@pytest.mark.slow
def test_table1_reproduction_figures_hold():
    rows = table(DOC, "<!-- cpf_report.py: table1 -->")
    assert [r["variant"] for r in rows][0] == "paper, Table 1 (real turntable)"
    wrong, checked = [], 0
    for row in rows[1:]:
        variant = row["variant"]
        noisy = variant.startswith("turntable + noise")
        for mode in report.MODES:
            p = _params(variant, mode, row[mode])
            if p is None:
                continue
            stated = numbers(row[mode].split(" (")[0])
            wrong += _check(f"{variant} / {mode}", stated, report.rms_hpr(p, range(10), noisy))
            checked += 1
    assert checked == 16 and wrong == []


@pytest.mark.slow
def test_every_scenario_figures_hold():
    rows = table(DOC, "<!-- cpf_report.py: scenarios -->")
    assert [r["scenario"] for r in rows] == list(report.SCENARIOS)
    wrong = []
    for row in rows:
        log = scenarios.make(row["scenario"], seed=0)
        assert numbers(row["steps"]) == [str(len(log))]
        for precision in ("double", "float"):
            rms, status_clear = report.rms_rpy(precision, log)
            assert status_clear, (row["scenario"], precision)
            wrong += _check(f"{row['scenario']} {precision}", numbers(row[precision]), rms)
    assert wrong == []


def test_state_and_operations_versus_n():
    rows = table(DOC, "<!-- cpf_report.py: cost -->")
    assert [int(r["N"]) for r in rows] == [50, 100, 200]
    for row in rows:
        n = int(row["N"])
        f, d = report.hf("float", n_particles=n), report.hf("double", n_particles=n)
        for build, size, col in ((f, 4, "state B float"), (d, 8, "state B double")):
            got = build.manifest["structs"]["state"]["size"]
            assert numbers(row[col]) == [str(got)], (n, col)
            assert got == (4 + 4 + 6 * n + 2) * size + 4 * 4           # the formula the doc states
        path = f.manifest["step_paths"]["accel+mag (kernels)"]
        total, ops = row["kernel ops, step with accel+mag"].split(" (")
        assert numbers(total) == [str(path["total"])], n
        stated = dict(kv.split(" ", 1) for kv in ops.rstrip(")").split(", "))       # "add 2 663" -> add
        assert {k: int(v.replace(" ", "")) for k, v in stated.items()} == {k: v for k, v in path["ops"].items() if v}
