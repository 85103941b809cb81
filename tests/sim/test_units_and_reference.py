"""Results that look fine and are not (issue 27): units recognised from the data, and
reference rows that are no attitude, through `ahrsgen run`.

- gyro in deg/s (or mdeg/s), accelerometer in g (or mg): one warning line on stderr before the
  score. The gyro's unit is told from the data alone: the directions of gravity and of the
  field, seen in body axes, turn at the rate the gyro reports (readers.gyro_scale).
- a reference quaternion of zeros, or of a norm far from 1: the row is left out of the score,
  with a warning counting the rows; no NumPy warning, no 180 degree error.
"""
from __future__ import annotations

import dataclasses
import glob
import warnings

import numpy as np
import pytest

from ahrsgen.sim import readers
from ahrsgen.sim.readers import EXCERPTS
from ahrsgen import cli

BROAD = EXCERPTS / "broad_01_excerpt.csv.gz"
ULOG = EXCERPTS / "px4_handheld_excerpt.ulg"


def _variant(tmp, name, **change):
    log = readers.read_log(BROAD)
    log = dataclasses.replace(log, **{k: f(log) for k, f in change.items()})
    p = tmp / name
    readers.write_csv(log, p)
    return p


UNITS = [
    ("gyro-deg-s", dict(gyro=lambda g: np.degrees(g.gyro)), "gyro looks like it is in deg/s"),
    ("gyro-mdeg-s", dict(gyro=lambda g: 1e3 * np.degrees(g.gyro)), "gyro looks like it is in mdeg/s"),
    ("accel-g", dict(accel=lambda g: g.accel / 9.80665), "accelerometer looks like it is in g"),
    ("accel-mg", dict(accel=lambda g: 1e3 * g.accel / 9.80665), "accelerometer looks like it is in mg"),
]


@pytest.mark.parametrize("case", UNITS, ids=[c[0] for c in UNITS])
def test_units_recognised_one_line_before_the_score(case, tmp_path, capsys):
    _, change, words = case
    rc = cli.main(["run", "qcf", "--log", str(_variant(tmp_path, "u.csv", **change))])
    out, err = capsys.readouterr()
    lines = [ln for ln in err.splitlines() if words in ln]
    assert len(lines) == 1 and lines[0].startswith("ahrsgen: warning: "), err
    assert rc in (0, 1)           # mdeg/s is refused by gyro_max (exit 1); the others run


@pytest.mark.slow
def test_right_units_give_no_line(capsys):
    """No unit line for the committed excerpts or any log of the shared data (BROAD's 10 trials,
    including fast translation and magnets, and the PX4 logs): the scale of each is 1 +- 0.2."""
    files = [BROAD, ULOG] + sorted(glob.glob(str(readers.REPO_ROOT.parent / "shared" / "data" / "*" / "*.*")))
    for f in files:
        if not str(f).endswith((".csv.gz", ".ulg")):
            continue
        log = readers.read_log(f)
        assert readers.unit_warnings(log) == [], f
        s = readers.gyro_scale(log)
        # sample_log_small.ulg rotates little: its scale is not within 0.2 of 1, yet far from deg/s
        assert s is None or abs(s - 1) < 0.2 or abs(s / (np.pi / 180) - 1) > 0.5, (f, s)


def test_gyro_scale_is_the_unit_factor():
    """The estimate is the factor itself: deg/s reads pi/180 within 10 %."""
    log = readers.read_log(ULOG)
    s_rad = readers.gyro_scale(log)
    s_deg = readers.gyro_scale(dataclasses.replace(log, gyro=np.degrees(log.gyro)))
    assert abs(s_rad - 1) < 0.1 and abs(s_deg / (np.pi / 180) - 1) < 0.1, (s_rad, s_deg)


REFS = [
    ("zeros", np.zeros(4)),
    ("half-norm", np.array([0.5, 0.0, 0.0, 0.0])),
    ("double-norm", np.array([0.0, 2.0, 0.0, 0.0])),
]


@pytest.mark.parametrize("case", REFS, ids=[c[0] for c in REFS])
def test_reference_rows_far_from_unit_are_skipped(case, tmp_path, capsys):
    _, bad = case
    clean_rc = cli.main(["run", "qcf", "--log", str(BROAD)])
    clean = capsys.readouterr().out

    def spoil(log):
        q = log.q_true.copy()
        q[::3] = bad                       # every third row
        return q
    p = _variant(tmp_path, "r.csv", q_true=spoil)
    with warnings.catch_warnings():
        warnings.simplefilter("error")     # a NumPy RuntimeWarning fails the test
        rc = cli.main(["run", "qcf", "--log", str(p)])
    out, err = capsys.readouterr()
    assert rc == clean_rc == 0, err
    assert "reference row(s) with a quaternion norm" in err and "left out of the score" in err, err
    assert "nan" not in out.lower(), out
    total = float(out.split("BROAD decomposition RMS: total ")[1].split(",")[0])
    clean_total = float(clean.split("BROAD decomposition RMS: total ")[1].split(",")[0])
    assert total < 2 * clean_total + 1, (total, clean_total)      # no 180 degree rows in it


def test_tune_says_so_too(tmp_path, capsys):
    """Gains tuned to a log in the wrong units would be wrong gains: tune warns as run does."""
    p = _variant(tmp_path, "g.csv", accel=lambda g: g.accel / 9.80665)
    cli.main(["tune", "qcf", "--log", str(p), "--params", "kp", "--budget", "2", "--folds", "0",
              "-o", str(tmp_path / "t.toml")])
    err = capsys.readouterr().err
    assert "ahrsgen: warning: g.csv: the accelerometer looks like it is in g" in err, err


def test_reference_all_zeros_scores_nothing(tmp_path, capsys):
    """Issue 27's example: a reference of zeros gave 'heading nan', 180 deg and a NumPy warning."""
    p = _variant(tmp_path, "z.csv", q_true=lambda g: np.zeros_like(g.q_true))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rc = cli.main(["run", "qcf", "--log", str(p)])
    out, err = capsys.readouterr()
    assert rc == 0 and "no reference row is left, nothing to score" in err, err
    assert "RMS" not in out and "nan" not in out.lower(), out
