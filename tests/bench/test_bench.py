"""Harness, scoring and benchmark plumbing.

- The standalone firmware-like executable (main_log.c: dt from timestamps, valid bits from
  which sensors delivered a sample) reproduces the ctypes batch run bit for bit, on real logs
  with jitter, gaps and slower mag/GPS.
- The hand-written baseline QCF implements the same algorithm as the independent NumPy
  reference (eq. 29 differentiator), statuses included.
- Scoring: declination and 6D heading handling against constructed errors.
"""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from ahrsgen import bench
from ahrsgen.sim import host, metrics, readers, scenarios
from ahrsgen.sim.log import VALID_ACCEL, VALID_ALL, VALID_GPS, VALID_GYRO, VALID_MAG, SensorLog
from ahrsgen import cli, status
from ahrsgen.generate import config
from ahrsgen.npquat import qmul
from ahrsgen.sim.readers import EXCERPTS

DATA = EXCERPTS
BROAD_X = DATA / "broad_01_excerpt.csv.gz"
ULOG_X = DATA / "px4_small_excerpt.ulg"
ULOG_MOVING = DATA / "px4_handheld_excerpt.ulg"


@pytest.fixture(scope="module")
def qcf_float():
    return host.build(config.resolve("qcf", None, [], "float", None))


@pytest.mark.parametrize("path", [ULOG_X, ULOG_MOVING, BROAD_X], ids=lambda p: p.name)
def test_standalone_executable_matches_batch(qcf_float, path):
    log = readers.read_log(path)
    if path == BROAD_X:
        log = log.slice(0, 3000)
    exe = bench.build_log_runner(qcf_float.dir)
    res_exe, summary = bench.run_log_exe(exe, log)
    res_lib = qcf_float.run(log)
    assert f"{len(log)} steps" in summary
    assert np.array_equal(res_exe.status, res_lib.status)
    # %.9g round-trips a float exactly: the two harnesses compute the same bits
    assert np.array_equal(res_exe.q.astype(np.float32), res_lib.q.astype(np.float32))
    assert np.array_equal(res_exe.rpy.astype(np.float32), res_lib.rpy.astype(np.float32))


def test_harness_log_encodes_arrivals_and_dt(tmp_path):
    """Only delivered samples are written; the executable derives valid bits and dt from the file."""
    log = readers.read_log(ULOG_X)
    p = bench.write_harness_log(log, tmp_path / "h.csv")
    lines = p.read_text().splitlines()
    assert lines[0].startswith("# ahrsgen harness log v1") and lines[1].startswith("# dt0 ")
    rows = [ln.split(",") for ln in lines[3:]]
    assert len(rows) == len(log)
    has_mag = np.array([r[7] != "" for r in rows])
    has_gps = np.array([r[10] != "" for r in rows])
    assert np.array_equal(has_mag, (log.valid & VALID_MAG) != 0)
    assert np.array_equal(has_gps, (log.valid & VALID_GPS) != 0)
    t = np.array([float(r[0]) for r in rows])
    assert np.array_equal(np.diff(t), log.dt[1:])      # dt from timestamps is the log's dt


def test_executable_sees_dropouts_as_missing(qcf_float, tmp_path):
    """A gyro sample that did not arrive is refused (GYRO_MISSING), a missing mag only skips its correction."""
    log = readers.read_log(ULOG_X).slice(0, 400)
    log.valid = log.valid.copy()
    log.valid[100] &= ~np.uint32(VALID_GYRO)
    log.valid[200] &= ~np.uint32(VALID_ACCEL)
    res, _ = bench.run_log_exe(bench.build_log_runner(qcf_float.dir), log)
    assert res.status[100] == status.GYRO_MISSING
    assert np.array_equal(res.q[100], res.q[99])            # refused: state unchanged
    assert res.status[200] == 0
    assert not np.array_equal(res.q[200], res.q[199])


@pytest.mark.parametrize("scen,opts", [("multirotor", {"duration": 20.0}),
                                       ("fixedwing_gps", {"duration": 120.0})])
def test_hand_written_qcf_is_the_specified_algorithm(scen, opts):
    log = scenarios.make(scen, seed=3, **opts)
    cfg = config.resolve("qcf", None, bench.HAND_QCF_SETS, "double", None)
    ref = host.run_reference(cfg.spec.reference(cfg.params), log)
    hand = bench.baseline_filter().run(log)
    assert np.array_equal(hand.status, ref.status)
    # float hand code vs the double NumPy reference: float rounding only
    assert np.degrees(metrics.max_angle_diff_rad(hand.q, ref.q)) < 0.01
    # the product default (centripetal model) is a different algorithm on this flight, which is
    # why the cost ratio is taken against the generated QCF built with eq. 29
    default = config.resolve("qcf", None, [], "double", None)
    if default.params.get("motion_accel_model") != "differentiator":
        gen_default = host.build(default).run(log)
        assert np.degrees(metrics.max_angle_diff_rad(gen_default.q, ref.q)) > 0.05


def test_hand_written_qcf_bad_inputs_like_reference():
    cfg = config.resolve("qcf", None, bench.HAND_QCF_SETS, "double", None)
    ref = cfg.spec.reference(cfg.params)
    hf = bench.baseline_filter()
    s = hf.new_state()
    good = dict(gyro=(0.01, -0.02, 0.03), accel=(0.1, 0.2, -9.8), mag=(0.2, 0.0, 0.4), gps_vel=(0, 0, 0))
    cases = [
        (dict(good), VALID_GYRO | VALID_ACCEL | VALID_MAG, 0.01),
        (dict(good), VALID_GYRO | VALID_ACCEL | VALID_MAG, float("nan")),
        (dict(good), VALID_GYRO | VALID_ACCEL | VALID_MAG, -0.01),
        (dict(good), VALID_GYRO | VALID_ACCEL | VALID_MAG, 5.0),
        (dict(good), VALID_ACCEL | VALID_MAG, 0.01),
        (dict(good, gyro=(float("nan"), 0, 0)), VALID_GYRO | VALID_ACCEL, 0.01),
        (dict(good, gyro=(100.0, 0, 0)), VALID_GYRO, 0.01),
        (dict(good, accel=(0, 0, 0)), VALID_GYRO | VALID_ACCEL | VALID_MAG, 0.01),
        (dict(good, accel=(0, float("inf"), 0)), VALID_GYRO | VALID_ACCEL | VALID_MAG, 0.01),
        (dict(good, mag=(0, 0, 0)), VALID_GYRO | VALID_ACCEL | VALID_MAG, 0.01),
        (dict(good, mag=(float("nan"), 0, 0)), VALID_GYRO | VALID_ACCEL | VALID_MAG, 0.01),
        (dict(good, gps_vel=(float("nan"), 0, 0)), VALID_ALL, 0.01),
        (dict(good), VALID_GYRO | VALID_ACCEL | VALID_MAG, 0.01),
    ]
    for inp, valid, dt in cases:
        st_ref = ref.step(np.array(inp["gyro"]), np.array(inp["accel"]), np.array(inp["mag"]),
                          np.array(inp["gps_vel"]), valid, dt)
        st_c = hf.step(s, inp["gyro"], inp["accel"], inp["mag"], inp["gps_vel"], valid, dt)
        assert st_c == st_ref, (inp, valid, dt)
        q_c = np.array(s.q[:])
        assert np.all(np.isfinite(q_c))
        assert np.degrees(metrics.max_angle_diff_rad(q_c[None], ref.q[None])) < 1e-3


# ------------------------------------------------------------------------------ scoring

def _rotz(deg):
    a = np.radians(deg) / 2
    return np.array([np.cos(a), 0.0, 0.0, np.sin(a)])


def _log_with_truth(n=500, decl=None):
    rng = np.random.default_rng(0)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    meta = {"settle_time": 1.0}
    if decl is not None:
        meta["declination_deg"] = decl
    z = np.zeros((n, 3))
    return SensorLog("x", np.arange(n) * 0.01, np.full(n, 0.01), z, z, z, z,
                     np.full(n, 7, np.uint32), q, meta)


def test_score_declination_and_heading_sources():
    log = _log_with_truth(decl=8.0)
    mag_est = qmul(_rotz(-8.0), log.q_true)        # a perfect estimate in magnetic north
    s = bench.score(mag_est, log, "mag")
    assert s["total_rms"] < 1e-3 and s["yaw_rms"] < 1e-3
    s = bench.score(mag_est, log, "true")          # read as true north it is 8° off in heading
    assert s["heading_rms"] == pytest.approx(8.0, abs=1e-6)
    assert s["inclination_rms"] < 1e-3
    s = bench.score(qmul(_rotz(123.0), log.q_true), log, "none")   # 6D: constant offset removed
    assert s["total_rms"] < 1e-3
    assert s["n"] == int((log.t >= 1.0).sum())


def test_score_movement_mask_and_divergence():
    log = _log_with_truth()
    mv = np.zeros(len(log), bool)
    mv[300:] = True
    log.meta["movement"] = mv
    est = log.q_true.copy()
    est[:300] = qmul(_rotz(50.0), est[:300])       # errors outside the movement phase: not scored
    assert bench.score(est, log, "mag")["total_rms"] < 1e-3
    est[400] = np.nan                               # a diverged estimate counts as 180°
    s = bench.score(est, log, "mag")
    assert s["nonfinite"] == 1
    assert s["total_rms"] == pytest.approx(np.sqrt(180.0 ** 2 / 200), rel=1e-6)


def test_run_on_broad_excerpt_cli(tmp_path, capsys):
    out_csv = tmp_path / "o.csv"
    rc = cli.main(["run", "qcf", "--log", str(BROAD_X), "--csv", str(out_csv)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "BROAD optical reference" in text and "total" in text
    data = np.loadtxt(out_csv, delimiter=",", skiprows=2)      # the marker comment, the column names
    log = readers.read_log(BROAD_X)
    assert data.shape == (len(log), 12)
    assert cli.main(["run", "qcf", "--log", str(tmp_path / "missing.ulg")]) == 2
    # the standalone executable path prints its own summary and the same score
    assert cli.main(["run", "qcf", "--log", str(ULOG_X), "--exe", "--plot", str(tmp_path / "p.png")]) == 0
    text = capsys.readouterr().out
    assert "standalone executable" in text and "ns per step" in text and "PX4 vehicle_attitude" in text
    assert (tmp_path / "p.png").stat().st_size > 10000
    # exported harness log + the printed executable reproduce the run outside Python
    hl = tmp_path / "h.csv"
    assert cli.main(["run", "qcf", "--log", str(ULOG_X), "--export-log", str(hl)]) == 0
    line = [ln for ln in capsys.readouterr().out.splitlines() if "run it with:" in ln][0]
    exe = line.split("run it with: ")[1].split()[0]
    import subprocess
    r = subprocess.run([exe, str(hl), str(tmp_path / "o2.csv")], capture_output=True, text=True)
    assert r.returncode == 0 and "1298 steps" in r.stderr


def test_mini_bench_writes_tables(tmp_path, monkeypatch):
    monkeypatch.setenv("AHRSGEN_DATA", str(tmp_path / "no-such-folder"))     # a typo: said, not silent
    rep = bench.bench(quick=True, seeds=2, filters=["qcf"], peer_names=("vqf",), out_dir=tmp_path,
                      jobs=1, scenarios_only=True, scenario_labels=["turntable"], command="test")
    assert set(rep["scenarios"]["turntable"]) == {"qcf", "vqf"}
    m = rep["scenarios"]["turntable"]["qcf"]["total_rms"]
    assert m["n"] == 2 and m["mean"] > 0
    c = rep["cost"]
    # the hand-written QCF: 34 floats (a 7-sample GPS velocity history); the default product
    # build: 13 words of the paper's filter with only the latest GPS velocity (q 4, bias 3,
    # velocity 3, GPS age, count, initialised) and 21 floats of
    # conditioning state (NED low-pass 3 and its warm-start time 1, sample ages 2, rest detector 4: low-passed gyro and
    # steady time, field reference 2 + 2 timers, the gyro over-range recovery timer and its
    # plateau detector 6: the previous gyro sample and the repeat counts), and 45 of the hard
    # iron (issue 25: the hard iron 3, the candidate 5 and its 5x5 covariance 25, its start flag,
    # residuals 4, their mean 2, mean squares 3, turning time, suspect flag); 7 of the rest
    # detector's turn test on the estimate (rest_turn: the last predicted q 4, its low-passed rate
    # 3) and 7 of the GPS linear-acceleration model (gps_lowpass: v_lp 3, v_ins 3, its flag)
    assert c["qcf_hand"]["state_bytes"] == 136 and c["qcf"]["state_bytes"] == (13 + 21 + 45 + 7 + 7) * 4
    assert 0.2 < c["qcf_eq29"]["ratio_to_hand_qcf"] < 20
    assert c["qcf"]["ops_total"] > c["qcf"]["paths"].get("gyro only", 0) > 0
    md = (tmp_path / "bench.md").read_text()
    assert "| qcf |" in md and "turntable" in md and "qcf_hand" in md
    assert f"$AHRSGEN_DATA = {tmp_path / 'no-such-folder'} is not a folder: ignored" in md
    assert json.loads((tmp_path / "bench.json").read_text())["command"] == "test"
    assert (tmp_path / "img" / "err_turntable.png").exists()


def test_bench_without_the_optional_packages(tmp_path, monkeypatch, capsys):
    """A plain `pip install .` has no peers, pyulog or matplotlib (the `dev` extra): the bench
    still runs and says what it left out; a peer asked for by name is one line, exit 2."""
    from ahrsgen.sim import peers
    monkeypatch.setattr(peers.VqfPeer, "package", "no_such_vqf_package")
    assert cli.main(["bench", "--quick", "--filters", "qcf", "--peers", "vqf", "-o", str(tmp_path / "a")]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        "ahrsgen: error: --peers vqf: package no_such_vqf_package is not installed (pip install 'ahrsgen[dev]')"]
    assert not (tmp_path / "a" / "bench.json").exists()
    from ahrsgen.bench import grid
    real_have = grid._have
    monkeypatch.setattr(grid, "_have", lambda m: m not in ("pyulog", "matplotlib") and real_have(m))
    rep = bench.bench(quick=True, filters=["qcf"], peer_names=("vqf", "madgwick"), out_dir=tmp_path / "b",
                      jobs=1, real_only=True, command="test")
    assert rep["notes"][0] == ("peers left out, their packages are not installed: vqf (no_such_vqf_package): "
                               "pip install 'ahrsgen[dev]'.")
    assert "PX4 logs left out: reading ULog needs pyulog: pip install 'ahrsgen[dev]'." in rep["notes"]
    assert "no plots: they need matplotlib: pip install 'ahrsgen[dev]'." in rep["notes"]
    assert rep["px4"] == {} and rep["plots"] == {} and not list((tmp_path / "b" / "img").iterdir())
    assert set(rep["broad"]["trials"]["broad_01_excerpt"]) == {"qcf", "madgwick"}
    assert "no plots: they need matplotlib" in (tmp_path / "b" / "bench.md").read_text()


def test_variant_option_is_validated():
    from ahrsgen.cli.bench import parse_variants
    from ahrsgen.codegen.model import ConfigError
    assert parse_variants(["soft=qcf:kp=0.05,ki=0.001"]) == [("soft", "qcf", ["kp=0.05", "ki=0.001"])]
    for bad in ["qcf:kp=1", "soft=qcf:kq=1", "soft=nofilter:kp=1", "soft=qcf:kp=-3"]:
        with pytest.raises(ConfigError):
            parse_variants([bad])


@pytest.mark.slow
def test_quick_bench_through_the_cli_covers_everything_it_claims(tmp_path):
    """`ahrsgen bench --quick` as CI runs it: every product filter and every default peer has
    an entry for every scenario of the quick grid and for every real log it read."""
    from ahrsgen import filters
    out = tmp_path / "q"
    r = subprocess.run([sys.executable, "-m", "ahrsgen.cli", "bench", "--quick", "-o", str(out)],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-2000:]
    rep = json.loads((out / "bench.json").read_text())
    expected = set(filters.names()) | set(bench.PEER_NAMES)
    labels = [label for label, _, _ in bench.scenario_configs(quick=True)]
    assert set(rep["scenarios"]) == set(labels)
    for label in labels:
        assert expected <= set(rep["scenarios"][label]), (label, expected - set(rep["scenarios"][label]))
        for name in expected:
            assert rep["scenarios"][label][name]["total_rms"]["n"] >= 1
    for name in filters.names():
        assert rep["cost"][name]["ns_per_step"] > 0 and rep["cost"][name]["state_bytes"] > 0
    assert "qcf_hand" in rep["cost"]
    assert (out / "bench.md").exists()


# --- which north the bench scores against (issue 30, class 5) -----------------------------------

def _site_log(decl_deg: float, yaw_true_deg: float, incl_deg: float = 60.0, seconds: float = 40.0) -> SensorLog:
    """A level sensor at rest, yawed yaw_true from TRUE north, in a field whose horizontal part
    points declination degrees east of true north; the reference is in true north. Written
    from the definitions here (NED, body -> NED), not by the simulator under test."""
    from ahrsgen.npquat import q_from_euler
    n = int(seconds * 100)
    d, i, y = np.radians(decl_deg), np.radians(incl_deg), np.radians(yaw_true_deg)
    m_ned = np.array([np.cos(i) * np.cos(d), np.cos(i) * np.sin(d), np.sin(i)])
    c, s = np.cos(y), np.sin(y)
    r_body_to_ned = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])       # level, yaw y
    mag = np.tile(r_body_to_ned.T @ m_ned, (n, 1))
    accel = np.tile([0.0, 0.0, -9.80665], (n, 1))
    q = np.tile(q_from_euler(0.0, 0.0, y), (n, 1))
    t = np.arange(n) * 0.01
    return SensorLog("site", t, np.full(n, 0.01), np.zeros((n, 3)), accel, mag, np.zeros((n, 3)),
                     np.full(n, VALID_GYRO | VALID_ACCEL | VALID_MAG, np.uint32), q,
                     {"declination_deg": decl_deg, "inclination_deg": incl_deg, "settle_time": 20.0,
                      "rate_hz": 100.0})


@pytest.mark.parametrize("name", ["qcf", "mekf"])
def test_a_filter_is_scored_in_the_references_north(name):
    """With a 20 deg declination in the log, the bench sets the filter's declination, so its
    heading lands in the reference's (true) north: heading error ~0, not 20 deg."""
    from io import StringIO
    log = _site_log(20.0, 30.0)
    r = bench.run_on_log(name, "site.csv", log=log, out=StringIO())
    assert r["score"]["heading_rms"] < 0.5, r["score"]


def test_a_magnetic_heading_is_rotated_by_the_declination():
    """A peer reports magnetic heading (yaw_true - declination for an east declination); the
    bench's frame turns it into the reference's north before scoring: zero error, where a
    wrong sign would leave twice the declination."""
    from ahrsgen.npquat import q_from_euler
    log = _site_log(20.0, 30.0)
    q_mag = np.tile(q_from_euler(0.0, 0.0, np.radians(30.0 - 20.0)), (len(log), 1))
    s = bench.score(q_mag, log, "mag")
    assert s["heading_rms"] < 1e-6 and s["total_rms"] < 1e-6, s
    s_none = bench.score(q_mag, log, "true")            # taken as true north: 20 deg off
    assert abs(s_none["heading_rms"] - 20.0) < 1e-6


def test_run_names_the_status_bits_it_saw(tmp_path, capsys):
    """`run` says which bits a non-zero status was made of, by the header's names (issue 27)."""
    rc = cli.main(["run", "qcf", "--log", str(EXCERPTS / "broad_01_excerpt.csv.gz")])
    out = capsys.readouterr().out
    assert rc == 0
    line = next(l for l in out.splitlines() if "status bits (steps):" in l)
    assert "AT_REST" in line and "(fault)" not in line.split("AT_REST")[1].split(",")[0]


def test_bench_rows_of_an_uncalibrated_sensor_and_a_rolled_board(tmp_path):
    """Issue 25's bench rows. The uncalibrated sensor (hard iron 2x the field, 10 % soft iron):
    the filter told nothing is lost in heading, and built with what `ahrsgen calibrate` finds
    on the sensor's calibration log it scores within 10 % of the same flights without the iron.
    The board rolled 180°: built with that mounting, the very same attitude as the level board
    (ROLL_180 negates two axes exactly, so to the bit), and only the mounted build is run."""
    from ahrsgen.sim.scenarios import handheld
    rows = ["handheld", "handheld_uncalibrated_iron", "handheld_rolled_180"]
    rep = bench.bench(seeds=1, filters=["qcf"], peer_names=(), out_dir=tmp_path, jobs=1,
                      scenarios_only=True, scenario_labels=rows, command="test")
    sc = rep["scenarios"]
    clean = sc["handheld"]["qcf"]["total_rms"]["mean"]
    assert set(sc["handheld_uncalibrated_iron"]) == {"qcf", "qcf_calibrated"}
    assert sc["handheld_uncalibrated_iron"]["qcf_calibrated"]["total_rms"]["mean"] <= 1.1 * clean
    assert sc["handheld_uncalibrated_iron"]["qcf"]["total_rms"]["mean"] > 10 * clean
    assert set(sc["handheld_rolled_180"]) == {"qcf_mounted"}
    for k, v in sc["handheld"]["qcf"].items():
        if k != "nonfinite":
            assert sc["handheld_rolled_180"]["qcf_mounted"][k]["mean"] == v["mean"], k
    # the calibration the bench wrote recovers the sensor's iron (the module's constants)
    import tomllib
    cal = tomllib.loads((tmp_path / "configs" / "handheld_uncalibrated_iron.toml").read_text())["calibration"]
    assert np.allclose(cal["mag_hard_iron"], handheld.HARD_IRON, atol=0.01 * handheld.FIELD_UT)
    S = np.array(cal["mag_soft_iron"])
    SW = S @ handheld.SOFT_IRON             # S undoes W up to the field's scale
    assert np.allclose(SW / np.mean(np.diag(SW)), np.eye(3), atol=0.01)
