"""Real sensor logs -> SensorLog: BROAD CSV (converted layout) and PX4 ULog.

BROAD (Laidig, Caruso, Cereatti, Seel, *Data* 2021, 6(7), 72; CC BY 4.0), in the layout of
`shared/data/README.md`: gzip CSV `t,gx,gy,gz,ax,ay,az,mx,my,mz,qw,qx,qy,qz,movement`, already
in the product's conventions (FRD body, NED earth with magnetic north, specific force, rad/s,
µT). Every row is one IMU sample with gyro, accelerometer and magnetometer (all three valid
bits set); no GPS. The optical reference is `q_true` (NaN where the markers were lost); the
`movement` column goes to `meta['movement']` (bool array) for BROAD's scoring method, and
`meta['settle_time']` is the time of the first moving sample (the rest phase is for the
filter to settle).

PX4 ULog (pyulog): one step per `sensor_combined` message (gyro_rad is the mean rate over the
interval ending at `timestamp`, matching the SensorLog timing), accelerometer from the same
message. Magnetometer from `vehicle_magnetometer` (or `sensor_mag` instance 0, or the
`magnetometer_ga` fields of old `sensor_combined`); GPS velocity from `vehicle_gps_position`
(or `sensor_gps`) where `vel_ned_valid`. A mag/GPS sample is attached to the first IMU step
at or after its timestamp; its valid bit is set only on that step, other rows hold the last
value (NaN before the first). `vehicle_attitude.q` (body FRD -> NED, like ours) is
interpolated (normalised linear, sign-aligned) at the step times as `q_true`; it is PX4's own
EKF estimate, a reference rather than ground truth. PX4's heading is referenced to true
north; the declination the log used, where a parameter gives it, is `meta['declination_deg']`.
Logs start with PX4's estimator already running, so `meta['settle_time']` is short:
min(2 s, 20 % of the log).

`read_log(path)` picks the reader from the file name. `shared_data_dir()` finds the full
data sets (`$AHRSGEN_DATA`, else `<repo>/../shared/data`).
"""
from __future__ import annotations

import gzip
import os
from pathlib import Path

import numpy as np

from firmware_sim.log import VALID_ACCEL, VALID_GPS, VALID_GYRO, VALID_MAG, SensorLog

BROAD_COLUMNS = ["t", "gx", "gy", "gz", "ax", "ay", "az", "mx", "my", "mz",
                 "qw", "qx", "qy", "qz", "movement"]
BROAD_CITATION = ("D. Laidig, M. Caruso, A. Cereatti, T. Seel: BROAD - A Benchmark for Robust "
                  "Inertial Orientation Estimation. Data 2021, 6(7), 72 (CC BY 4.0)")

REPO_ROOT = Path(__file__).resolve().parent.parent
DATA_ENV = "AHRSGEN_DATA"


def shared_data_dir(option: str | os.PathLike | None = None) -> Path | None:
    """Directory holding broad/ and px4/: the option, else $AHRSGEN_DATA, else <repo>/../shared/data.

    Returns None when none of them exists (callers say so and skip real-data parts).
    """
    for cand in (option, os.environ.get(DATA_ENV), REPO_ROOT.parent / "shared" / "data"):
        if cand and Path(cand).is_dir():
            return Path(cand)
    return None


def broad_trials(data_dir: str | os.PathLike | None = None) -> list[Path]:
    """Sorted BROAD trial files (*.csv.gz / *.csv) under <data_dir>/broad (empty if absent)."""
    d = shared_data_dir(data_dir)
    if d is None or not (d / "broad").is_dir():
        return []
    return sorted(p for p in (d / "broad").iterdir() if p.name.endswith((".csv.gz", ".csv")))


def _open_text(path: Path):
    return gzip.open(path, "rt") if str(path).endswith(".gz") else open(path)


def read_broad(path: str | os.PathLike, name: str | None = None) -> SensorLog:
    """One BROAD trial in the converted CSV layout (see module docstring)."""
    path = Path(path)
    with _open_text(path) as f:
        header = f.readline().strip().split(",")
        if header != BROAD_COLUMNS:
            raise ValueError(f"{path}: not the BROAD CSV layout (header {header}, expected {BROAD_COLUMNS})")
        data = np.loadtxt(f, delimiter=",", dtype=float, ndmin=2)
    if data.shape[0] < 2:
        raise ValueError(f"{path}: fewer than two samples")
    col = {c: i for i, c in enumerate(BROAD_COLUMNS)}
    t = data[:, col["t"]]
    dt = np.empty_like(t)
    dt[1:] = np.diff(t)
    dt[0] = float(np.median(dt[1:]))
    gyro = data[:, col["gx"]:col["gz"] + 1]
    accel = data[:, col["ax"]:col["az"] + 1]
    mag = data[:, col["mx"]:col["mz"] + 1]
    q = data[:, col["qw"]:col["qz"] + 1]
    movement = data[:, col["movement"]] > 0.5
    n = len(t)
    valid = np.full(n, VALID_GYRO | VALID_ACCEL | VALID_MAG, dtype=np.uint32)
    moving = np.flatnonzero(movement)
    settle = float(t[moving[0]] - t[0]) if len(moving) else 0.0
    stem = path.name.split(".")[0]
    meta = {
        "source": "BROAD",
        "description": f"BROAD trial {stem} (optical motion capture reference)",
        "citation": BROAD_CITATION,
        "file": str(path),
        "rate_hz": 1.0 / dt[0],
        "mag_unit": "uT",
        "heading_reference": "magnetic north",
        "reference": "optical motion capture (NaN where markers were lost)",
        "movement": movement,
        "settle_time": settle,
        "scoring": "broad",
    }
    return SensorLog(name or stem, t, dt, gyro, accel, mag, np.full((n, 3), np.nan), valid, q, meta)


# ---------------------------------------------------------------------------------------
# PX4 ULog

_REL_INVALID = 0x7FFFFFFF  # PX4's RELATIVE_TIMESTAMP_INVALID


def _field(d, name):
    return np.asarray(d.data[name], dtype=float)


def _vec(d, base):
    return np.column_stack([_field(d, f"{base}[{i}]") for i in range(3)])


def _time_us(d):
    """Sample time of a topic: timestamp_sample where present (when the sensor sampled)."""
    key = "timestamp_sample" if "timestamp_sample" in d.data else "timestamp"
    return np.asarray(d.data[key], dtype=np.int64)


def _dataset(ulog, names, multi_id=0):
    for nm in names:
        for d in ulog.data_list:
            if d.name == nm and d.multi_id == multi_id:
                return d
    return None


def _attach(t_steps_us, t_ev_us, values, n_cols):
    """Attach events to the first step at or after their time; (held values, arrived mask)."""
    n = len(t_steps_us)
    out = np.full((n, n_cols), np.nan)
    arrived = np.zeros(n, dtype=bool)
    if len(t_ev_us) == 0:
        return out, arrived
    k = np.searchsorted(t_steps_us, t_ev_us, side="left")
    keep = k < n
    k, vals = k[keep], values[keep]
    # several events in one step: the last one wins (firmware reads the newest sample)
    last = np.ones(len(k), dtype=bool)
    last[:-1] = k[1:] != k[:-1]
    k, vals = k[last], vals[last]
    arrived[k] = True
    # hold the last value on rows without a new sample
    idx = np.full(n, -1)
    idx[k] = np.arange(len(k))
    idx = np.maximum.accumulate(idx)
    have = idx >= 0
    out[have] = vals[idx[have]]
    return out, arrived


def _interp_quat(t_ref, q_ref, t, max_gap):
    """Normalised linear interpolation of a quaternion sequence (sign-aligned); NaN outside."""
    q_ref = np.array(q_ref, dtype=float)
    for i in range(1, len(q_ref)):   # make the sequence sign-continuous
        if np.dot(q_ref[i], q_ref[i - 1]) < 0:
            q_ref[i] = -q_ref[i]
    out = np.full((len(t), 4), np.nan)
    j = np.searchsorted(t_ref, t, side="right") - 1
    ok = (j >= 0) & (j < len(t_ref) - 1)
    j0 = j[ok]
    t0, t1 = t_ref[j0], t_ref[j0 + 1]
    gap_ok = (t1 - t0) <= max_gap
    a = ((t[ok] - t0) / (t1 - t0))[:, None]
    q = (1 - a) * q_ref[j0] + a * q_ref[j0 + 1]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[~gap_ok] = np.nan
    out[np.flatnonzero(ok)] = q
    exact = (j == len(t_ref) - 1) & (t == t_ref[-1])
    out[exact] = q_ref[-1]
    return out


def read_ulog(path: str | os.PathLike, name: str | None = None) -> SensorLog:
    """A PX4 ULog file mapped into a SensorLog (see module docstring)."""
    from pyulog import ULog

    path = Path(path)
    ulog = ULog(str(path))
    sc = _dataset(ulog, ["sensor_combined"])
    if sc is None:
        raise ValueError(f"{path}: no sensor_combined topic (needed for gyro and accelerometer)")
    t_us = np.asarray(sc.data["timestamp"], dtype=np.int64)
    order = np.argsort(t_us, kind="stable")
    keep = np.ones(len(order), dtype=bool)
    keep[1:] = np.diff(t_us[order]) > 0          # drop duplicated timestamps
    rows = order[keep]
    t_us = t_us[rows]
    n = len(t_us)
    gyro = _vec(sc, "gyro_rad")[rows]
    accel = _vec(sc, "accelerometer_m_s2")[rows]
    t0 = t_us[0]
    t = (t_us - t0) * 1e-6
    dt = np.empty(n)
    dt[1:] = np.diff(t)
    dt[0] = float(np.median(dt[1:])) if n > 1 else 0.004
    valid = np.full(n, VALID_GYRO | VALID_ACCEL, dtype=np.uint32)
    meta = {"source": "PX4 ULog", "file": str(path), "scoring": "px4"}

    # magnetometer
    mag_src = None
    vm = _dataset(ulog, ["vehicle_magnetometer"])
    sm = _dataset(ulog, ["sensor_mag"])
    if vm is not None:
        ev_t, ev_v, mag_src = _time_us(vm), _vec(vm, "magnetometer_ga"), "vehicle_magnetometer"
    elif sm is not None:
        ev_t = _time_us(sm)
        ev_v = np.column_stack([_field(sm, c) for c in ("x", "y", "z")])
        mag_src = "sensor_mag"
    elif "magnetometer_ga[0]" in sc.data:
        rel = np.asarray(sc.data["magnetometer_timestamp_relative"], dtype=np.int64)
        ts = np.asarray(sc.data["timestamp"], dtype=np.int64)
        ok = rel != _REL_INVALID
        abs_t = ts + rel
        vals = _vec(sc, "magnetometer_ga")
        new = np.ones(len(abs_t), dtype=bool)
        new[1:] = abs_t[1:] != abs_t[:-1]
        sel = ok & new
        ev_t, ev_v, mag_src = abs_t[sel], vals[sel], "sensor_combined.magnetometer_ga"
    if mag_src is not None:
        o = np.argsort(ev_t, kind="stable")
        mag, arrived = _attach(t_us, ev_t[o], ev_v[o], 3)
        valid[arrived] |= VALID_MAG
        meta["mag_source"] = mag_src
        meta["mag_unit"] = "gauss"
        meta["mag_rate_hz"] = float(arrived.sum() / max(t[-1] - t[0], 1e-9))
    else:
        mag = np.full((n, 3), np.nan)

    # GPS velocity
    gp = _dataset(ulog, ["vehicle_gps_position", "sensor_gps"])
    gps = np.full((n, 3), np.nan)
    if gp is not None:
        ev_t = _time_us(gp)
        ev_v = np.column_stack([_field(gp, f"vel_{c}_m_s") for c in "ned"])
        ok = np.ones(len(ev_t), dtype=bool)
        if "vel_ned_valid" in gp.data:
            ok &= np.asarray(gp.data["vel_ned_valid"]).astype(bool)
        o = np.argsort(ev_t[ok], kind="stable")
        gps, arrived = _attach(t_us, ev_t[ok][o], ev_v[ok][o], 3)
        valid[arrived] |= VALID_GPS
        meta["gps_source"] = gp.name
        meta["gps_rate_hz"] = float(arrived.sum() / max(t[-1] - t[0], 1e-9))

    # reference attitude (PX4's onboard estimate)
    q_true = None
    va = _dataset(ulog, ["vehicle_attitude"])
    if va is not None:
        ta = _time_us(va)
        qa = np.column_stack([_field(va, f"q[{i}]") for i in range(4)])
        o = np.argsort(ta, kind="stable")
        q_true = _interp_quat((ta[o] - t0) * 1e-6, qa[o], t, max_gap=0.1)
        meta["reference"] = "PX4 vehicle_attitude (onboard estimator, not ground truth)"
        meta["heading_reference"] = "true north (PX4)"

    params = ulog.initial_parameters
    for key in ("EKF2_MAG_DECL", "ATT_MAG_DECL"):
        if key in params:
            meta["declination_deg"] = float(params[key])
            meta["declination_param"] = key
            break
    duration = float(t[-1] - t[0])
    meta.update({
        "description": f"PX4 log {path.name} ({duration:.1f} s, sensor_combined at "
                       f"{1.0 / np.median(dt[1:]):.0f} Hz)",
        "rate_hz": float(1.0 / np.median(dt[1:])),
        "settle_time": min(2.0, 0.2 * duration),   # PX4 logs start with the EKF running
        "start_timestamp_us": int(t0),
    })
    return SensorLog(name or path.stem, t, dt, gyro, accel, mag, gps, valid, q_true, meta)


def read_log(path: str | os.PathLike, name: str | None = None) -> SensorLog:
    """Read a log by its file name: *.ulg -> PX4 ULog; *.csv / *.csv.gz with BROAD's header -> BROAD."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"log file not found: {p}")
    if p.suffix.lower() == ".ulg":
        return read_ulog(p, name)
    if p.name.lower().endswith((".csv", ".csv.gz")):
        return read_broad(p, name)
    raise ValueError(f"{p}: unknown log format (expected .ulg or BROAD .csv/.csv.gz)")
