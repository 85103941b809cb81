"""PX4 ULog (pyulog) -> SensorLog.

One step per `sensor_combined` message (gyro_rad is the mean rate over the
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
"""
from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from ahrsgen.errors import LogError
from ahrsgen.sim.log import VALID_ACCEL, VALID_GPS, VALID_GYRO, VALID_MAG, SensorLog

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


ULOG_MAGIC = b"ULog\x01\x12\x35"


def ulog_truncation(path: str | os.PathLike) -> str | None:
    """Where a ULog file ends inside a record (a log cut in half), as a sentence; None if it ends
    on a record boundary. Walks the record headers (uint16 size, uint8 type) after the 16-byte
    file header; pyulog drops such a last record silently."""
    data = Path(path).read_bytes()
    pos, n, records = 16, len(data), 0
    while pos + 3 <= n:
        size = int.from_bytes(data[pos:pos + 2], "little")
        if pos + 3 + size > n:
            return (f"the file ends in the middle of record {records + 1} (at byte {pos} of {n}, "
                    f"{pos + 3 + size - n} bytes missing): the log was cut off")
        pos += 3 + size
        records += 1
    if pos != n:
        return f"the file ends in the middle of a record header (at byte {pos} of {n}): the log was cut off"
    return None


def read_ulog(path: str | os.PathLike, name: str | None = None) -> SensorLog:
    """A PX4 ULog file mapped into a SensorLog (see module docstring)."""
    path = Path(path)
    try:
        from pyulog import ULog
    except ImportError:
        raise LogError(f"{path}: reading PX4 ULog needs the pyulog package: pip install 'ahrsgen[dev]'") from None
    with open(path, "rb") as fh:
        head = fh.read(16)
    if head and len(head) < 16 and (head.startswith(ULOG_MAGIC) or ULOG_MAGIC.startswith(head)):
        raise LogError(f"{path}: truncated PX4 ULog file ({len(head)} bytes, shorter than the 16-byte ULog header)")
    if len(head) < 16 or not head.startswith(ULOG_MAGIC):
        raise LogError(f"{path}: not a PX4 ULog file (it does not start with the ULog header)")
    try:
        import contextlib
        with contextlib.redirect_stdout(io.StringIO()):      # pyulog prints its corruption notes
            ulog = ULog(str(path))
    except Exception as e:                                    # pyulog raises bare exceptions on bad data
        raise LogError(f"{path}: unreadable ULog file ({type(e).__name__}: {str(e)[:80]})") from None
    warnings = []
    cut = ulog_truncation(path)
    if cut:
        warnings.append(f"{path.name}: {cut}")
    if ulog.file_corruption:
        warnings.append(f"{path.name}: pyulog found corrupt records and skipped them")
    sc = _dataset(ulog, ["sensor_combined"])
    if sc is None:
        raise LogError(f"{path}: no sensor_combined topic (needed for gyro and accelerometer)"
                       + (f"; {cut}" if cut else ""))
    if len(sc.data["timestamp"]) < 2:
        raise LogError(f"{path}: {len(sc.data['timestamp'])} sensor_combined sample(s); a log needs at least two")
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
    meta = {"source": "PX4 ULog", "file": str(path), "scoring": "px4", "warnings": warnings}

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
