"""docs/qcf.md, "Gains chosen by cross-validation": the defaults' figures of its tables,
re-measured (float C, defaults, BROAD's scoring; the scenarios as `ahrsgen bench` scores them).
The per-rate tune column is the study's (`ahrsgen tune`, not re-run here). Needs the full BROAD
files; skips, saying so, without them."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import host_build, scenario
from docs_tables import table
from ahrsgen.bench.scoring import filter_estimator, score
from ahrsgen.sim import readers
from ahrsgen.sim.peers import broad_score

ROWS = {"BROAD 286 Hz": 1, "BROAD averaged to 143 Hz": 2, "BROAD averaged to 95 Hz": 3,
        "BROAD averaged to 48 Hz": 6}
MULTIROTOR = {"`multirotor` 250 Hz": {}, "`multirotor` 400 Hz (magnetometer 100 Hz)": {"rate_hz": 400.0, "mag_rate": 100.0},
              "`multirotor` 1 kHz (magnetometer 100 Hz)": {"rate_hz": 1000.0, "mag_rate": 100.0}}


def _defaults_column() -> dict[str, float]:
    rows = table("docs/qcf.md", "Against a per-rate tune of the same filter")
    return {r["data"]: float(r["defaults"].rstrip("°")) for r in rows}


def test_the_per_rate_table_lists_what_this_file_measures():
    assert set(_defaults_column()) == set(ROWS) | set(MULTIROTOR)


def test_defaults_on_broad_at_each_rate():
    trials = readers.broad_trials()
    if not trials:
        pytest.skip("BROAD subset not found (../shared/data/broad or $AHRSGEN_DATA)")
    doc = _defaults_column()
    f = host_build("qcf")
    logs = [readers.read_log(p) for p in trials]
    for row, k in ROWS.items():
        got = np.mean([broad_score(f.run(lg).q, lg)["total"] for lg in (x.averaged(k) if k > 1 else x for x in logs)])
        assert round(float(got), 3) == pytest.approx(doc[row], abs=0.0015), row


def test_defaults_on_the_multirotor_at_each_rate():
    doc = _defaults_column()
    est = filter_estimator("qcf")
    for row, opts in MULTIROTOR.items():
        totals = []
        for seed in range(3):
            log = scenario("multirotor", seed, **opts)
            q, heading, _ = est.run(log)
            totals.append(score(q, log, heading)["total_rms"])
        assert round(float(np.mean(totals)), 3) == pytest.approx(doc[row], abs=0.0015), row
