"""The CSV log format (docs/log-format.md) and `ahrsgen run` on it: header-driven columns, each
sensor at its own rate, GPS velocity reaching the filter (MEKF's course heading), the reference
and movement columns, and the plot's error panel and continuous yaw."""
from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import host_build, scenario
from ahrsgen import bench
from ahrsgen.sim import readers
from ahrsgen.sim.log import VALID_ACCEL, VALID_GPS, VALID_GYRO, VALID_MAG
from ahrsgen.sim.metrics import euler_stats, max_angle_diff_rad


@pytest.fixture(scope="module")
def flight():
    return scenario("fixedwing_gps", 0, duration=120.0)


@pytest.fixture(scope="module")
def flight_csv(flight, tmp_path_factory):
    return readers.write_csv(flight, tmp_path_factory.mktemp("csv") / "flight.csv.gz")


def test_csv_round_trip_keeps_every_sample_and_rate(flight, flight_csv):
    log = readers.read_log(flight_csv)
    assert len(log) == len(flight)
    np.testing.assert_array_equal(log.valid, flight.valid)          # GPS at 5 Hz, IMU at 12.5 Hz
    for name in ("t", "gyro", "accel"):
        np.testing.assert_array_equal(getattr(log, name), getattr(flight, name))
    has = (flight.valid & VALID_GPS) != 0
    np.testing.assert_array_equal(log.gps_vel[has], flight.gps_vel[has])
    assert 4.5 < log.meta["gps_rate_hz"] < 5.5
    np.testing.assert_allclose(log.q_true, flight.q_true, rtol=0, atol=0)


def test_mekf_from_csv_uses_gps_course_heading(flight, flight_csv, capsys):
    """`ahrsgen run mekf --log FILE.csv` with GPS columns: the same attitude as running the scenario
    directly, with a heading only the GPS course can give (the default mekf has no mag heading)."""
    sets = [f"declination={math.radians(flight.meta['declination_deg'])!r}"]
    res = bench.run_on_log("mekf", str(flight_csv), sets=sets)
    q_csv = res["res"].q
    direct = host_build("mekf", "float", tuple(sets)).run(flight).q
    # identical input except dt[0] (the CSV has no nominal period: median of the steps)
    assert max_angle_diff_rad(q_csv, direct) < 1e-4
    yaw_rms = euler_stats(q_csv, flight.q_true, flight.t, 10.0)["yaw"]["rms"]
    assert yaw_rms < 2.0, yaw_rms
    # without the GPS columns the course is unknown: yaw is then far off (the heading needs GPS)
    no_gps = readers.read_log(flight_csv)
    no_gps.valid &= np.uint32(~VALID_GPS & 0xFFFFFFFF)
    blind = host_build("mekf", "float", tuple(sets)).run(no_gps).q
    assert euler_stats(blind, flight.q_true, flight.t, 10.0)["yaw"]["rms"] > 5 * yaw_rms


def test_sensors_at_their_own_rates_and_extra_columns(tmp_path):
    lines = ["t,gx,gy,gz,ax,ay,az,mx,my,mz,temperature"]
    for k in range(10):
        acc = "0,0,-9.81" if k % 2 == 0 else ",,"
        mag = "0.2,0,0.4" if k % 5 == 0 else "nan,nan,nan"
        lines.append(f"{0.01 * k},0.1,0,0,{acc},{mag},25.0")
    p = tmp_path / "rates.csv"
    p.write_text("\n".join(lines) + "\n")
    log = readers.read_log(p)
    assert np.all(log.valid & VALID_GYRO)
    assert [bool(v & VALID_ACCEL) for v in log.valid] == [k % 2 == 0 for k in range(10)]
    assert [bool(v & VALID_MAG) for v in log.valid] == [k % 5 == 0 for k in range(10)]
    assert not np.any(log.valid & VALID_GPS) and log.q_true is None
    assert log.meta["ignored_columns"] == ["temperature"]
    np.testing.assert_array_equal(log.mag[6], [0.2, 0, 0.4])          # held, bit clear


def test_partial_column_group_is_refused(tmp_path):
    p = tmp_path / "g.csv"
    p.write_text("t,gx,gy,gz,ax,ay,az,gps_vn,gps_ve\n0,0,0,0,0,0,-9.8,1,2\n0.1,0,0,0,0,0,-9.8,1,2\n")
    with pytest.raises(readers.LogError, match="gps_vd missing"):
        readers.read_log(p)


def test_reference_without_movement_rows_says_so(flight, tmp_path, capsys):
    short = flight.slice(0, 300)
    short.meta["movement"] = np.zeros(len(short), dtype=bool)
    p = readers.write_csv(short, tmp_path / "still.csv")
    bench.run_on_log("qcf", str(p))
    out = capsys.readouterr().out
    assert "no row with movement = 1" in out and "no reference attitude" not in out


def test_run_preset_reaches_the_filter(flight_csv, capsys):
    r = bench.run_on_log("mekf", str(flight_csv), preset="faithful")
    assert r["overrides"] and "motion_comp" in r["overrides"]


def test_continuous_yaw_shows_a_small_error_across_the_wrap():
    ref = np.array([178.0, 179.0, 179.9, -179.9, -179.0])
    est = ref + 2.0
    est = (est + 180.0) % 360.0 - 180.0              # 181.0 -> -179.0 etc.: wrapped like atan2
    e, r = bench.continuous_yaw_deg(est, ref)
    np.testing.assert_allclose(e - r, 2.0, atol=1e-9)
    assert np.all(np.abs(np.diff(r)) < 2.0)           # no 360 deg jump in the drawn reference


def test_continuous_yaw_continues_where_the_reference_stops():
    """BROAD's reference has gaps (occlusions) and ends (NaN) before the log. Across a gap in which
    the yaw turns 300 deg the reference's unwrapping takes the short way (-60 deg), the estimate's
    own does not; the rows without a reference go on from the row drawn before them, so the line
    does not jump by a turn where the reference stops."""
    t = np.arange(400)
    ref_u = 3.0 * t - 100.0                              # 1 100 deg of yaw: several turns
    wrap = lambda a: (a + 180.0) % 360.0 - 180.0         # noqa: E731
    est = wrap(ref_u + 2.0)
    ref = wrap(ref_u)
    ref[:20] = np.nan                                    # no reference at the start,
    ref[100:200] = np.nan                                # for 300 deg of yaw in the middle,
    ref[300:] = np.nan                                   # nor at the end
    e, r = bench.continuous_yaw_deg(est, ref)
    assert np.all(np.abs(np.diff(e[:100])) < 10.0) and np.all(np.abs(np.diff(e[200:])) < 10.0)
    has_ref = np.isfinite(ref)
    np.testing.assert_allclose(e[has_ref] - r[has_ref], 2.0, atol=1e-9)


def test_run_plot_and_csv_are_written(flight_csv, tmp_path):
    from ahrsgen import cli
    png, csv = tmp_path / "p.png", tmp_path / "r.csv"
    assert cli.main(["run", "qcf", "--log", str(flight_csv), "--plot", str(png), "--csv", str(csv)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    first, header = csv.read_text().splitlines()[:2]
    assert first == "# written by ahrsgen run" and header.startswith("t,qw,qx,qy,qz")   # docs/output-files.md
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.png", "r.csv"]     # no temporary left
