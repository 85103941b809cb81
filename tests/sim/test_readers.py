"""Log readers: BROAD CSV and PX4 ULog excerpts (src/ahrsgen/sim/data/) mapped into SensorLog.

The checks are physical, not copies of the reader's output: at rest the reference attitude
must rotate the specific force onto [0, 0, -g] and (BROAD: magnetic north) the field into the
north-down plane; integrating the gyro from the reference must land on the later reference
(gyro frame, sign and timing); mag/GPS valid bits must match the topic message counts.
"""
from __future__ import annotations

import gzip

import numpy as np
import pytest

from ahrsgen.sim import readers
from ahrsgen.sim.log import G0, VALID_ACCEL, VALID_GPS, VALID_GYRO, VALID_MAG
from ahrsgen.npquat import qconj, qexp, qmul, rotmat
from ahrsgen.sim.readers import EXCERPTS

DATA = EXCERPTS
BROAD_X = DATA / "broad_01_excerpt.csv.gz"
ULOG_X = DATA / "px4_small_excerpt.ulg"          # CubeOrange on the bench: mag, GPS, attitude
ULOG_MOVING = DATA / "px4_handheld_excerpt.ulg"  # AUAV-X21 hand-held: first 12 s, old mag layout


def _angle_deg(qa, qb):
    qe = qmul(qconj(qa), qb)
    return np.degrees(2 * np.arctan2(np.linalg.norm(qe[1:]), abs(qe[0])))


def _integrate(log, k0, k1):
    """Propagate q_true[k0] with the gyro of steps k0+1..k1 (rate over (t[k-1], t[k]])."""
    q = log.q_true[k0].copy()
    for k in range(k0 + 1, k1 + 1):
        q = qmul(q, qexp(0.5 * log.gyro[k] * log.dt[k]))
    return q


# --------------------------------------------------------------------------- BROAD

@pytest.fixture(scope="module")
def broad():
    return readers.read_log(BROAD_X)


def test_broad_shape_timing_and_bits(broad):
    with gzip.open(BROAD_X, "rt") as f:
        n_rows = sum(1 for _ in f) - 1
    assert len(broad) == n_rows
    assert np.allclose(broad.dt[1:], 0.0035, atol=2e-6)        # 285.714 Hz
    assert broad.dt[0] == pytest.approx(0.0035, abs=2e-6)
    assert np.all(broad.valid == (VALID_GYRO | VALID_ACCEL | VALID_MAG))
    assert np.all(np.isnan(broad.gps_vel))
    mv = broad.meta["movement"]
    assert mv.dtype == bool and len(mv) == len(broad) and 0 < mv.sum() < len(broad)
    first = np.flatnonzero(mv)[0]
    assert broad.settle_time == pytest.approx(broad.t[first] - broad.t[0])
    assert "Laidig" in broad.meta["citation"]


def test_broad_rest_reference_matches_gravity_and_magnetic_north(broad):
    rest = np.flatnonzero(~broad.meta["movement"] & np.all(np.isfinite(broad.q_true), axis=1))
    rest = rest[rest < np.flatnonzero(broad.meta["movement"])[0]][::50]
    f_n = np.array([rotmat(broad.q_true[k]) @ broad.accel[k] for k in rest])
    m_n = np.array([rotmat(broad.q_true[k]) @ broad.mag[k] for k in rest])
    # specific force at rest, rotated to NED, points up: [0, 0, -g]
    tilt = np.degrees(np.arccos(-f_n[:, 2] / np.linalg.norm(f_n, axis=1)))
    assert np.median(tilt) < 2.0
    assert np.median(np.linalg.norm(f_n, axis=1)) == pytest.approx(G0, rel=0.03)
    # heading reference is magnetic north: horizontal field has no east component
    decl = np.degrees(np.arctan2(m_n[:, 1], m_n[:, 0]))
    assert abs(np.median(decl)) < 3.0
    assert np.median(m_n[:, 2]) > 0          # northern hemisphere (Berlin): field points down


def test_broad_gyro_integrates_onto_reference(broad):
    mv = np.flatnonzero(broad.meta["movement"] & np.all(np.isfinite(broad.q_true), axis=1))
    k0 = mv[len(mv) // 3]
    k1 = k0 + 143                       # 0.5 s of hand-held rotation
    assert np.all(np.isfinite(broad.q_true[k0:k1 + 1]))
    travelled = _angle_deg(broad.q_true[k0], broad.q_true[k1])
    err = _angle_deg(_integrate(broad, k0, k1), broad.q_true[k1])
    assert travelled > 5.0              # the window really moves
    assert err < 0.1 * travelled        # gyro frame/sign/timing agree with the reference
    # a wrong body frame (sensor axes instead of FRD) would not integrate onto it
    wrong = broad.gyro.copy()
    broad.gyro[:] = wrong * np.array([1.0, -1.0, -1.0])
    try:
        err_wrong = _angle_deg(_integrate(broad, k0, k1), broad.q_true[k1])
    finally:
        broad.gyro[:] = wrong
    assert err_wrong > 3 * err


def test_csv_rejects_missing_columns(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text("t,gx,gy\n0,0,0\n")
    with pytest.raises(readers.LogError, match="missing column.*gz, ax, ay, az"):
        readers.read_log(p)
    with pytest.raises(ValueError, match="unknown log format"):
        (tmp_path / "a.bin").write_bytes(b"x")
        readers.read_log(tmp_path / "a.bin")
    with pytest.raises(FileNotFoundError):
        readers.read_log(tmp_path / "missing.ulg")


# --------------------------------------------------------------------------- ULog

@pytest.fixture(scope="module")
def ulog():
    return readers.read_log(ULOG_X)


@pytest.fixture(scope="module")
def raw_ulog():
    from pyulog import ULog
    return ULog(str(ULOG_X))


def test_ulog_steps_and_timing(ulog, raw_ulog):
    sc = raw_ulog.get_dataset("sensor_combined").data
    ts = np.unique(sc["timestamp"])
    assert len(ulog) == len(ts)
    assert np.allclose(ulog.t, (ts - ts[0]) * 1e-6)
    assert np.allclose(ulog.dt[1:], np.diff(ts) * 1e-6)
    assert np.all(ulog.valid & VALID_GYRO) and np.all(ulog.valid & VALID_ACCEL)
    assert np.allclose(ulog.gyro[:, 0], sc["gyro_rad[0]"][np.searchsorted(sc["timestamp"], ts)])


def test_ulog_mag_and_gps_bits_once_per_sample(ulog, raw_ulog):
    ts = np.unique(raw_ulog.get_dataset("sensor_combined").data["timestamp"])
    m = raw_ulog.get_dataset("vehicle_magnetometer").data
    in_range = (m["timestamp"] <= ts[-1])
    # one valid step per magnetometer message in the IMU time span (none shares a step here)
    assert ((ulog.valid & VALID_MAG) != 0).sum() == in_range.sum()
    g = raw_ulog.get_dataset("vehicle_gps_position").data
    ok = (g["timestamp"] <= ts[-1]) & g["vel_ned_valid"].astype(bool)
    assert ((ulog.valid & VALID_GPS) != 0).sum() == ok.sum()
    # valid rows carry the message value, the rows after hold it until the next sample
    kg = np.flatnonzero(ulog.valid & VALID_GPS)
    assert np.allclose(ulog.gps_vel[kg, 0], g["vel_n_m_s"][ok])
    assert np.allclose(ulog.gps_vel[kg[0]:kg[1], 2], g["vel_d_m_s"][ok][0])
    # each sample lands on the first IMU step at or after its timestamp
    km = np.flatnonzero(ulog.valid & VALID_MAG)
    t_us = ts
    assert np.all(t_us[km] >= m["timestamp"][in_range])
    assert np.all(t_us[km - 1] < m["timestamp"][in_range]) if km[0] > 0 else True
    assert ulog.meta["gps_rate_hz"] == pytest.approx(5.0, rel=0.1)
    assert ulog.meta["declination_deg"] == pytest.approx(3.99, abs=0.01)


def test_ulog_reference_matches_gravity(ulog):
    ok = np.flatnonzero(np.all(np.isfinite(ulog.q_true), axis=1))
    assert len(ok) > 0.95 * len(ulog)
    f_n = np.array([rotmat(ulog.q_true[k]) @ ulog.accel[k] for k in ok[::20]])
    tilt = np.degrees(np.arccos(-f_n[:, 2] / np.linalg.norm(f_n, axis=1)))
    assert np.median(tilt) < 3.0        # PX4's q is body FRD -> NED, accel is specific force


def test_ulog_handheld_gyro_integrates_onto_px4_attitude():
    log = readers.read_log(ULOG_MOVING)
    assert log.meta["mag_source"] == "sensor_combined.magnetometer_ga"
    assert log.meta["rate_hz"] == pytest.approx(250, rel=0.02)
    worst, moved = 0.0, 0.0
    for k0 in range(0, 1875, 125):       # 0.5 s windows over the hand-held part
        k1 = k0 + 125
        if not np.all(np.isfinite(log.q_true[[k0, k1]])):
            continue
        moved = max(moved, _angle_deg(log.q_true[k0], log.q_true[k1]))
        worst = max(worst, _angle_deg(_integrate(log, k0, k1), log.q_true[k1]))
    assert moved > 20.0                  # it really rotates
    assert worst < 2.0                   # gyro frame, sign and step timing agree with PX4


def test_ulog_old_sensor_combined_mag(tmp_path):
    """Old logs carry the magnetometer inside sensor_combined with a relative timestamp."""
    from pyulog import ULog
    d = readers.shared_data_dir()
    if d is None or not (d / "px4" / "sample.ulg").exists():
        pytest.skip("full PX4 sample.ulg not found (../shared/data or $AHRSGEN_DATA)")
    log = readers.read_ulog(d / "px4" / "sample.ulg")
    raw = ULog(str(d / "px4" / "sample.ulg"), message_name_filter_list=["sensor_combined"])
    sc = raw.get_dataset("sensor_combined").data
    abs_t = sc["timestamp"].astype(np.int64) + sc["magnetometer_timestamp_relative"]
    n_samples = len(np.unique(abs_t))
    assert log.meta["mag_source"] == "sensor_combined.magnetometer_ga"
    n_valid = ((log.valid & VALID_MAG) != 0).sum()
    # two samples only share a step across the log's few IMU dropouts
    assert 0.99 * n_samples <= n_valid <= n_samples
    # a valid row holds a sample taken in (t[k-1], t[k]]
    t_us = np.unique(sc["timestamp"]).astype(np.int64)
    km = np.flatnonzero(log.valid & VALID_MAG)[1:]
    lo, hi = t_us[km - 1], t_us[km]
    for k, a, b in zip(km[::97], lo[::97], hi[::97]):
        cand = (abs_t > a) & (abs_t <= b)
        assert cand.any()
        assert np.any(np.all(np.isclose(np.column_stack(
            [sc[f"magnetometer_ga[{i}]"][cand] for i in range(3)]), log.mag[k]), axis=1))
    assert log.meta["mag_rate_hz"] == pytest.approx(100, rel=0.05)


def test_shared_data_dir_env(tmp_path, monkeypatch):
    (tmp_path / "broad").mkdir()
    (tmp_path / "broad" / "99_x.csv.gz").write_bytes(b"")
    (tmp_path / "broad" / "notes.txt").write_text("not a trial")
    monkeypatch.setenv(readers.DATA_ENV, str(tmp_path))
    assert readers.shared_data_dir() == tmp_path
    assert [p.name for p in readers.broad_trials()] == ["99_x.csv.gz"]
    assert readers.shared_data_dir(tmp_path / "nope") == tmp_path


def test_full_broad_subset_reads():
    trials = readers.broad_trials()
    if not trials:
        pytest.skip("BROAD subset not found (../shared/data/broad or $AHRSGEN_DATA)")
    log = readers.read_broad(trials[0])
    assert len(log) > 40000 and log.meta["movement"].any()


def test_csv_with_a_byte_order_mark(tmp_path):
    """Excel's "CSV UTF-8" starts the file with a byte-order mark: the first column is still t.
    The file is written here byte by byte, not by the writer under test."""
    f = tmp_path / "bom.csv"
    rows = ["t,gx,gy,gz,ax,ay,az", "0.00,0.1,0.2,0.3,0,0,-9.81", "0.01,0.1,0.2,0.3,0,0,-9.81",
            "0.02,0.1,0.2,0.3,0,0,-9.81"]
    f.write_bytes(b"\xef\xbb\xbf" + "\n".join(rows).encode() + b"\n")
    log = readers.read_log(f)
    assert log.meta["columns"][0] == "t"
    assert np.allclose(log.gyro[0], [0.1, 0.2, 0.3])


def test_csv_fixture_written_by_hand_from_the_format(tmp_path):
    """A CSV written here from docs/log-format.md, not by write_csv: columns in a shuffled
    order, a vehicle flying north-east (GPS 3 m/s north, 4 m/s east, 1 m/s up = -1 down) at 5 Hz
    in a 10 Hz log, the magnetometer every other row, distinct values in every column so that
    any two swapped columns show. The reader must put each number where the format says."""
    f = tmp_path / "ne.csv"
    lines = ["gps_ve,mz,t,ax,gx,my,gps_vd,az,gz,mx,ay,gy,gps_vn,qx,qw,qz,qy"]
    for k in range(4):
        t = 0.1 * k
        gps = ("4.0", "-1.0", "3.0") if k % 2 == 0 else ("", "", "")
        mag = ("0.43", "0.01", "0.21") if k % 2 == 0 else ("", "", "")
        lines.append(f"{gps[0]},{mag[0]},{t:.1f},0.11,0.001,{mag[1]},{gps[1]},-9.79,0.003,{mag[2]},-0.07,-0.002,"
                     f"{gps[2]},0.0,1.0,0.0,0.0")
    f.write_text("\n".join(lines) + "\n")
    log = readers.read_log(f)
    assert np.allclose(log.t, [0.0, 0.1, 0.2, 0.3])
    assert np.allclose(log.gyro, [[0.001, -0.002, 0.003]] * 4)
    assert np.allclose(log.accel, [[0.11, -0.07, -9.79]] * 4)
    assert np.allclose(log.mag[0], [0.21, 0.01, 0.43]) and np.allclose(log.mag[2], [0.21, 0.01, 0.43])
    assert np.allclose(log.gps_vel[0], [3.0, 4.0, -1.0])           # north, east, down
    assert list(log.valid) == [VALID_GYRO | VALID_ACCEL | VALID_MAG | VALID_GPS, VALID_GYRO | VALID_ACCEL] * 2
    assert np.allclose(log.q_true, [[1.0, 0.0, 0.0, 0.0]] * 4)
    assert np.allclose(log.dt[1:], 0.1)


def test_csv_writer_output_read_by_the_documented_format(tmp_path):
    """write_csv's file read back with the csv module and the column names of
    docs/log-format.md (not with read_csv): each column holds the value it names."""
    import csv
    from ahrsgen.sim.log import SensorLog
    n = 3
    log = SensorLog("w", np.array([0.0, 0.01, 0.02]), np.full(n, 0.01), np.tile([0.1, 0.2, 0.3], (n, 1)),
                    np.tile([1.0, 2.0, -9.0], (n, 1)), np.tile([0.4, 0.5, 0.6], (n, 1)),
                    np.tile([7.0, 8.0, 9.0], (n, 1)), np.full(n, VALID_GYRO | VALID_ACCEL | VALID_MAG | VALID_GPS),
                    np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)))
    out = tmp_path / "w.csv"
    readers.write_csv(log, out)
    rows = list(csv.DictReader(line for line in out.read_text().splitlines() if not line.startswith("#")))
    r = rows[1]
    want = {"t": 0.01, "gx": 0.1, "gy": 0.2, "gz": 0.3, "ax": 1.0, "ay": 2.0, "az": -9.0, "mx": 0.4, "my": 0.5,
            "mz": 0.6, "gps_vn": 7.0, "gps_ve": 8.0, "gps_vd": 9.0, "qw": 1.0, "qx": 0.0}
    for col, v in want.items():
        assert float(r[col]) == pytest.approx(v), col


# --- a ULog field against the file's bytes decoded by hand (issue 30, class 1) ----------------
_ULOG_TYPES = {"int8_t": "b", "uint8_t": "B", "int16_t": "h", "uint16_t": "H", "int32_t": "i", "uint32_t": "I",
               "int64_t": "q", "uint64_t": "Q", "float": "f", "double": "d", "bool": "?", "char": "c"}


def _ulog_by_hand(path, topic: str) -> list[dict]:
    """Every `topic` message of a ULog, decoded from the format in PX4's ULog file-format
    document, independently of pyulog: 16-byte header, then records (uint16 size, uint8 type,
    payload); 'F' defines a format "name:type field;...", 'A' subscribes (uint8 multi_id, uint16
    msg_id, name), 'D' carries data (uint16 msg_id, fields in order, little-endian, packed).
    Only formats of basic types are decoded (enough for sensor_combined); trailing padding fields
    are not in the data."""
    import struct
    data = path.read_bytes()
    assert data[:7] == b"ULog\x01\x12\x35"
    pos, formats, subs, out = 16, {}, {}, []
    while pos + 3 <= len(data):
        size, kind = struct.unpack_from("<HB", data, pos)
        body = data[pos + 3:pos + 3 + size]
        pos += 3 + size
        if kind == ord("F"):
            name, _, fields = body.decode().partition(":")
            formats[name] = [f.split(" ") for f in fields.split(";") if f]
        elif kind == ord("A"):
            subs[struct.unpack_from("<H", body, 1)[0]] = body[3:].decode()
        elif kind == ord("D") and subs.get(struct.unpack_from("<H", body, 0)[0]) == topic:
            vals, off = {}, 2
            for typ, fname in formats[topic]:
                base, count = typ, 1
                if "[" in typ:
                    base, count = typ[:-1].split("[")
                    count = int(count)
                code = _ULOG_TYPES[base]
                if fname.startswith("_padding") and off + struct.calcsize(f"<{count}{code}") > len(body):
                    break                 # trailing padding is not written (the format document)
                v = struct.unpack_from(f"<{count}{code}", body, off)
                off += struct.calcsize(f"<{count}{code}")
                vals[fname] = v if count > 1 else v[0]
            out.append(vals)
    return out


def test_ulog_gyro_and_accel_match_the_bytes_decoded_by_hand():
    path = EXCERPTS / "px4_small_excerpt.ulg"
    msgs = _ulog_by_hand(path, "sensor_combined")
    assert len(msgs) > 100
    log = readers.read_log(path)
    by_t = {m["timestamp"]: m for m in msgs}
    t0 = min(by_t)
    for k in (0, 1, len(log) // 2, len(log) - 1):
        m = by_t[t0 + int(round(log.t[k] * 1e6))]
        assert np.array_equal(log.gyro[k], np.array(m["gyro_rad"], dtype=np.float32).astype(float)), k
        assert np.array_equal(log.accel[k], np.array(m["accelerometer_m_s2"], dtype=np.float32).astype(float)), k
