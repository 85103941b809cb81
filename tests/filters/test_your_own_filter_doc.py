"""docs/your_own_filter.md's measured figures, re-measured through the commands the page names:
`ahrsgen validate examples/madgwick` (float and double C against the NumPy reference on the
fixed-wing flight and on `--scenario multirotor`) and `ahrsgen run examples/<name>` (`bench.run.run_on_log`) on the
committed BROAD excerpt (BROAD's total / heading / inclination RMS against its optical
reference). Host C is deterministic: a figure must equal its measurement as written."""
from __future__ import annotations

import re

import pytest

from ahrsgen import cli
from ahrsgen.bench.run import run_on_log
from conftest import REPO
from docs_tables import ROOT, outside, table
from ahrsgen.sim.readers import EXCERPTS

DOC = " ".join((ROOT / "docs" / "your_own_filter.md").read_text().split())
EXAMPLE = str(REPO / "examples" / "madgwick")


def _validate(capsys, *args) -> float:
    # --tolerance 1: the sample-by-sample comparison only (no estimator judgement)
    assert cli.main(["validate", EXAMPLE, "--tolerance", "1", *args]) == 0
    out = capsys.readouterr().out
    return float(out.split("max attitude difference ")[1].split(" rad")[0])


def test_madgwick_float_and_double_against_its_reference(capsys):
    stated = re.search(r"fixed-wing flight \(([\d.e-]+) rad\).*? The same C in double is within "
                       r"([\d.e-]+) rad of the reference .*? and ([\d.e-]+) rad on `--scenario multirotor`",
                       DOC)
    assert stated, "docs/your_own_filter.md: the float bound's figures"
    fixedwing, double, multirotor = stated.groups()
    got = (_validate(capsys), _validate(capsys, "--precision", "double"),
           _validate(capsys, "--scenario", "multirotor"))
    for figure, value in zip((fixedwing, double, multirotor), got):
        assert not outside(figure, value, 0.0), (figure, value)


@pytest.mark.parametrize("name", ["Madgwick", "Mahony"])
def test_examples_on_the_broad_excerpt(name, capsys):
    stated = re.search(name + r" ([\d.]+)° (?:total RMS )?\(heading ([\d.]+)°, inclination ([\d.]+)°\)", DOC)
    assert stated, f"docs/your_own_filter.md: {name}'s BROAD figures"
    import io
    score = run_on_log(str(REPO / "examples" / name.lower()), str(EXCERPTS / "broad_01_excerpt.csv.gz"),
                       out=io.StringIO())["score"]
    for figure, key in zip(stated.groups(), ("total", "heading", "inclination")):
        assert not outside(figure, score[f"{key}_rms"], 0.0), (name, key, figure, score[f"{key}_rms"])


@pytest.mark.parametrize("name", ["madgwick", "mahony"])
def test_examples_against_ahrs_on_the_broad_excerpt(name):
    """The table of the largest attitude difference to `ahrs` (the examples' references run it)."""
    pytest.importorskip("ahrs")
    from ahrsgen.generate import config
    from ahrsgen.sim import host, metrics, readers
    [row] = [r for r in table("docs/your_own_filter.md", "maximum attitude difference to `ahrs`")
             if r[""] == name]
    log = readers.read_log(EXCERPTS / "broad_01_excerpt.csv.gz")
    folder = str(REPO / "examples" / name)
    ref = host.run_reference(config.resolve(folder).spec.reference(config.resolve(folder).params), log)
    for column, precision in (("double C", "double"), ("float C (bound 5e-5 rad)", "float")):
        got = metrics.max_angle_diff_rad(host.build(config.resolve(folder, precision=precision)).run(log).q, ref.q)
        stated = row[column].removesuffix(" rad")
        assert not outside(stated, got, 0.0), (name, precision, stated, got)
