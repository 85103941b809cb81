"""docs/scenarios.md's figures, made again: the overview table (written by
`python -m studies.scenarios_doc`) row by row from the simulator, measured from the log itself
(steps, sample intervals, distinct sensor samples) rather than from its meta; and the rotation
the gyro_clip flip loses over seeds 0-4. (The attached_magnet and gyro_clip tables are
re-measured by tests/filters/mekf/test_mekf_hard_iron.py and tests/filters/test_gyro_clip.py.)"""
from __future__ import annotations

import ast
import re

import numpy as np

from docs_tables import DOCS, numbers, table
from ahrsgen.sim import scenarios
from ahrsgen.sim.log import VALID_GPS, VALID_MAG


def _options(cell: str) -> dict:
    if cell == "-":
        return {}
    return {k: ast.literal_eval(v) for k, v in (kv.split("=") for kv in cell.split(", "))}


def _sample_rate(log, column: np.ndarray, bit: int, duration: float) -> float | None:
    """Distinct samples per second of a sensor: steps with its bit set whose value changed (a
    sample repeated on every step counts once)."""
    valid = (log.valid & np.uint32(bit)) != 0
    if not valid.any():
        return None
    new = valid & np.r_[True, np.any(column[1:] != column[:-1], axis=1)]
    return float(new.sum()) / duration


def test_overview_table_is_what_the_simulator_makes():
    rows = table("docs/scenarios.md", "<!-- scenarios_doc.py: overview -->")
    assert {r["name"].strip("`") for r in rows} == set(scenarios.names())
    for row in rows:
        name, opts = row["name"].strip("`"), _options(row["options"])
        log = scenarios.make(name, seed=0, **opts)
        where = (name, row["options"])
        assert numbers(row["steps"]) == [str(len(log))], where
        imu = 1.0 / float(np.median(np.diff(log.t)))
        assert abs(imu / float(row["IMU Hz"]) - 1) < 1e-3, (where, imu)
        duration = len(log) / imu
        assert abs(duration - float(row["duration s"])) <= max(0.05, 1.5 / imu), (where, duration)
        for col, data, bit in (("mag Hz", log.mag, VALID_MAG), ("GPS Hz", log.gps_vel, VALID_GPS)):
            got = _sample_rate(log, data, bit, duration)
            if row[col] == "none":
                assert got is None, (where, col, got)
            else:
                assert got is not None and abs(got / float(row[col]) - 1) < 0.01, (where, col, got)


def test_gyro_clip_rotation_lost_over_seeds():
    text = (DOCS / "scenarios.md").read_text()
    lo, hi = map(int, re.search(r"lost \((\d+)–(\d+)° for seeds 0–4\)", text).groups())
    lost = []
    for seed in range(5):
        log = scenarios.make("gyro_clip", seed=seed)
        clip = log.meta["clip"]
        # the noise-free gyro less the clipped one, integrated over the clip (the noise and the
        # bias over 0.4 s are a small fraction of a degree)
        w = (log.t >= clip["start_s"] - 0.05) & (log.t <= clip["end_s"] + 0.05)
        missed = ((log.meta["truth"]["gyro"] - log.gyro)[w] * log.dt[w, None]).sum(axis=0)
        lost.append(float(np.degrees(np.linalg.norm(missed))))
    assert (round(min(lost)), round(max(lost))) == (lo, hi), lost
