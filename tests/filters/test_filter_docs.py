"""docs/mekf.md's, docs/adukf.md's and docs/qcf.md's figures, re-measured. Every table of
figures in those docs stands in a block written by `python -m studies.filter_doc <filter>`; this file reads each
table back (tests/docs_tables.py) and measures every figure again with the same scoring: float C
host builds on the simulated scenarios (always available), BROAD's trials (skipped, saying so,
without the BROAD files), the manifest's operation counts, and the defaults from defaults.toml.
Host C is deterministic: a figure must equal its measurement to the last digit written."""
from __future__ import annotations

import sys
import tomllib

import numpy as np
import pytest

from docs_tables import ROOT, numbers, outside, table

sys.path.insert(0, str(ROOT))
from studies import filter_doc as fd       # noqa: E402

FILTERS = ("mekf", "adukf", "qcf")
EXACT = 0.0
BLOCK = "<!-- filter_doc.py: {} -->"


def _rows(name: str, block: str) -> list[dict[str, str]]:
    rows = table(f"docs/{name}.md", BLOCK.format(block))
    assert rows, (name, block)
    return rows


@pytest.mark.parametrize("name", FILTERS)
def test_parameter_defaults_are_the_filters(name):
    params = tomllib.loads((fd.FILTERS / name / "defaults.toml").read_text())["params"]
    for row in _rows(name, "params"):
        key = row["parameter"].strip("`")
        stated = tomllib.loads(f"v = {row['default']}")["v"]
        assert stated == params[key]["default"] and type(stated) is type(params[key]["default"]), (name, key, stated)
        assert row["unit"] == params[key].get("unit", ""), (name, key)


@pytest.mark.parametrize("name", FILTERS)
def test_operations_per_step_path_are_the_manifests(name):
    paths = fd.manifest(name)["step_paths"]
    rows = _rows(name, "cost")
    assert [r["step path"] for r in rows] == list(paths)
    for row in rows:
        p = paths[row["step path"]]
        assert [int(row[o]) for o in fd.OPS] == [p["ops"].get(o, 0) for o in fd.OPS], (name, row)
        assert int(row["total"]) == p["total"] == sum(int(row[o]) for o in fd.OPS), (name, row)


@pytest.mark.slow
@pytest.mark.parametrize("name", FILTERS)
def test_scenario_figures_hold(name):
    wrong = []
    for row in _rows(name, "scenarios"):
        bench_row = row["scenario (bench row)"].strip("`")
        settings = "" if row["settings"] == "defaults" else row["settings"]
        got = fd.scenario_rms(name, bench_row, settings, seeds=(0, 1, 2))
        if outside(row["total RMS, deg"], got, EXACT):
            wrong.append(f"{bench_row} {settings or 'defaults'}: measured {got:.4f}, the doc says {row['total RMS, deg']}")
    assert wrong == []


@pytest.mark.parametrize("name", FILTERS)
def test_broad_figures_hold(name):
    if not fd.broad_logs():
        pytest.skip("BROAD subset not found (../shared/data/broad or $AHRSGEN_DATA)")
    scores = fd.broad_scores(name)
    rows = _rows(name, "broad")
    assert len(rows) == len(scores) + 1 and rows[-1]["trial"] == f"mean of {len(scores)}"
    wrong = []
    for row in rows:
        trial = row["trial"].split()[0]
        for col, key in (("total", "total_rms"), ("heading", "heading_rms"), ("inclination", "inclination_rms")):
            got = np.mean([s[key] for s in scores.values()]) if trial == "mean" else scores[trial][key]
            if outside(row[col], got, EXACT):
                wrong.append(f"{row['trial']} {col}: measured {got:.4f}, the doc says {row[col]}")
    rates = table(f"docs/{name}.md", "Mean total RMSE with the IMU at a lower rate")
    assert [r["BROAD"] for r in rates] == list(fd.RATES)
    for row in rates:
        got = np.mean([s["total_rms"] for s in fd.broad_scores(name, fd.RATES[row["BROAD"]]).values()])
        if outside(row["mean total RMSE, deg"], got, EXACT):
            wrong.append(f"BROAD {row['BROAD']}: measured {got:.4f}, the doc says {row['mean total RMSE, deg']}")
    assert wrong == []


@pytest.mark.slow
def test_adukf_paper_reproduction_figures_hold():
    from studies import adukf_repro as repro
    tab = repro.rms_table(seeds=fd.PAPER_SEEDS)
    rows = _rows("adukf", "paper")
    assert {(r["scenario"].strip("`"), r["filter"]) for r in rows} == {(s, v) for s in tab for v in tab[s]}
    for row in rows:
        sc, v = row["scenario"].strip("`"), row["filter"]
        got = tab[sc][v].mean(axis=0)
        stated = numbers(row["ours: roll / pitch / yaw RMS, deg"])
        assert not any(outside(s, g, EXACT) for s, g in zip(stated, got)), (sc, v, stated, got)
        assert [float(x) for x in numbers(row["paper"])] == list(repro.PAPER[sc][v])   # the paper's Table 1 / 2
    for row in table("docs/adukf.md", "| scenario | DUKF / A-DUKF, ours"):
        sc = row["scenario"].strip("`")
        ratio = tab[sc]["DUKF"].mean(axis=0) / tab[sc]["A-DUKF"].mean(axis=0)
        stated = [float(x.rstrip("×")) for x in numbers(row["DUKF / A-DUKF, ours: roll / pitch / yaw"])]
        assert all(abs(s - r) <= 0.5 for s, r in zip(stated, ratio)), (sc, stated, ratio)
