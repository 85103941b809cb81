"""The example user filters (examples/madgwick, examples/mahony): CasADi models outside the
package, checked against an independent implementation, `ahrs.filters.Madgwick` / `Mahony`,
on the committed BROAD excerpt (a real handheld IMU trial, 6286 steps at 286 Hz).

Double C agrees with ahrs to 1e-9 rad (measured: 5.3e-15 and 1.1e-14 rad); float C stays
within FLOAT_BOUND_RAD of ahrs (measured: 2.4e-6 rad for both). The classic's corner cases as ahrs
runs them (an exactly zero gyro sample skips the update, no accelerometer: gyro only, no
magnetometer: the IMU update) are driven on a doctored copy of the excerpt.
"""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pytest

from conftest import needs
from firmware_sim import host, metrics, readers
from firmware_sim.log import VALID_ACCEL, VALID_MAG
from generator import config

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = [str(REPO / "examples" / n) for n in ("madgwick", "mahony")]
BROAD = REPO / "tests" / "data" / "broad_01_excerpt.csv.gz"
FLOAT_BOUND_RAD = 5e-5
pytest.importorskip("ahrs")


@functools.cache
def _broad():
    return readers.read_log(BROAD)


@functools.cache
def _reference(folder):
    cfg = config.resolve(folder)
    return host.run_reference(cfg.spec.reference(cfg.params), _broad())


@pytest.mark.parametrize("precision,bound", [("double", 1e-9), ("float", FLOAT_BOUND_RAD)])
@pytest.mark.parametrize("folder", EXAMPLES, ids=lambda p: Path(p).name)
def test_example_matches_ahrs_on_broad(folder, precision, bound):
    cfg = config.resolve(folder, precision=precision)
    c = host.build(cfg).run(_broad())
    r = _reference(folder)
    assert np.array_equal(c.status, r.status)
    diff = metrics.max_angle_diff_rad(c.q, r.q)
    assert diff <= bound, f"{cfg.filter} {precision}: {diff:.3g} rad"


@pytest.mark.parametrize("initialise", [True, False])
@pytest.mark.parametrize("folder", EXAMPLES, ids=lambda p: Path(p).name)
def test_example_corner_cases_as_ahrs(folder, initialise):
    import dataclasses
    log = _broad()
    n = 1500
    fields = {f.name: getattr(log, f.name) for f in dataclasses.fields(log)}
    cut = {k: (v[:n].copy() if isinstance(v, np.ndarray) and len(v) == len(log) else v)
           for k, v in fields.items() if k != "meta"}
    cut["gyro"][200:260] = 0.0
    cut["valid"][400:480] &= ~np.uint32(VALID_ACCEL)
    cut["valid"][600:700] &= ~np.uint32(VALID_MAG)
    cut["valid"][800:820] &= ~np.uint32(VALID_ACCEL | VALID_MAG)
    short = dataclasses.replace(log, **cut)
    cfg = config.resolve(folder, precision="double", sets=[f"initialise={str(initialise).lower()}"])
    c = host.build(cfg).run(short)
    r = host.run_reference(cfg.spec.reference(cfg.params), short)
    assert metrics.max_angle_diff_rad(c.q, r.q) <= 1e-9
    # a zero gyro sample leaves the attitude as it was: exactly in C; ahrs up to the rounding of
    # its own normalisation and of the frame changes
    assert np.array_equal(c.q[200:260], np.repeat(c.q[199:200], 60, axis=0))
    assert metrics.max_angle_diff_rad(r.q[200:260], np.repeat(r.q[199:200], 60, axis=0)) < 1e-12
    # the first step sets the attitude from the sensors (and does nothing else), or starts at identity
    # (BROAD's trial starts 90 degrees from the identity)
    to_truth = metrics.max_angle_diff_rad(c.q[:1], short.q_true[:1])
    to_identity = metrics.max_angle_diff_rad(c.q[:1], np.array([[1.0, 0.0, 0.0, 0.0]]))
    assert (to_truth < np.radians(5)) if initialise else (to_identity < 0.01 and to_truth > np.radians(45))


@needs("target")
def test_target_sets_the_example_beside_the_hand_written_peer(tmp_path, capsys):
    """`ahrsgen target ./examples/madgwick --peers`: the generated Madgwick on the emulated M4F
    agrees with its host build and is reported beside the hand-written Madgwick of the
    calibration peers, with the ratio of their instruction counts."""
    import json

    from generator import cli
    out = tmp_path / "t.json"
    rc = cli.main(["target", EXAMPLES[0], "--opt=-O2", "--peers", "--scenario-opt", "duration=16",
                   "--count-steps", "10", "--no-pinned", "--json", str(out)])
    text = capsys.readouterr().out
    assert rc == 0, text
    doc = json.loads(out.read_text())
    (r,) = doc["results"]
    assert r["filter"] == "madgwick" and r["pass"] is True
    hand = {p["filter"]: p for p in doc["peers"]}["peer:madgwick"]
    (b,) = doc["beside_peers"]
    assert b["generated"] == r["footprint"]["instructions_mean"] and b["hand_written"] == hand["instructions_mean"]
    assert f"madgwick -O2: generated {b['generated']:.0f} / hand-written {b['hand_written']:.0f}" in text


def test_every_command_takes_the_example_folder(tmp_path, capsys):
    """list, generate, validate, run, bench and harden on examples/mahony, exactly as on a
    built-in (target: the test above; tune: tests/test_tune.py)."""
    from generator import cli
    folder = EXAMPLES[1]
    runs = [
        ["list", folder],
        ["generate", folder, "--set", "kp=0.5", "-o", str(tmp_path / "gen")],
        ["validate", folder, "--scenario", "turntable", "--scenario-opt", "duration=20", "--precision", "double"],
        ["run", folder, "--log", str(BROAD)],
        ["bench", "--quick", "--filters", folder, "--peers", "mahony", "--scenarios", "turntable",
         "--scenarios-only", "-o", str(tmp_path / "bench")],
        ["harden", folder, "--fuzz-seconds", "0", "--soak-steps", "20000", "--no-cppcheck",
         "--json", str(tmp_path / "h.json")],
    ]
    for argv in runs:
        assert cli.main(argv) == 0, argv
    out = capsys.readouterr().out
    assert "mahony: Mahony" in out and "PASS" in out and "BROAD decomposition RMS" in out
    assert "| mahony_gen |" in (tmp_path / "bench" / "bench.md").read_text()      # beside ahrs' Mahony
    assert "#define MAHONY_KP 0.5f" in (tmp_path / "gen" / "mahony.h").read_text()
