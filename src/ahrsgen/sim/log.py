"""The one sensor-log format every scenario, log reader, harness and reference shares.

Conventions (SPEC.md): NED navigation frame, FRD body frame, Hamilton scalar-first
quaternions rotating body to NED, gyro in rad/s, accelerometer as specific force in
m/s^2 (level at rest reads [0, 0, -9.81]), magnetometer in any unit, GPS velocity in
NED m/s.

Timing: sample k is what the firmware has at time t[k]. gyro[k] is the rate over the
interval (t[k-1], t[k]] (the constant rate that carries the attitude from t[k-1] to
t[k]); accel[k], mag[k], gps_vel[k] and q_true[k] are at t[k]. dt[k] = t[k] - t[k-1]
is the dt of step k; dt[0] is the nominal period. A sensor that delivered nothing at
step k has its bit cleared in valid[k] (its row then holds the last value or NaN; a
filter must not read it).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Validity bits of the input struct, shared by every generated filter.
VALID_GYRO = 1 << 0
VALID_ACCEL = 1 << 1
VALID_MAG = 1 << 2
VALID_GPS = 1 << 3
VALID_ALL = VALID_GYRO | VALID_ACCEL | VALID_MAG | VALID_GPS

G0 = 9.80665  # standard gravity, m/s^2


@dataclass
class SensorLog:
    name: str
    t: np.ndarray          # (N,) s
    dt: np.ndarray         # (N,) s
    gyro: np.ndarray       # (N,3) rad/s, FRD
    accel: np.ndarray      # (N,3) m/s^2 specific force, FRD
    mag: np.ndarray        # (N,3) any unit, FRD
    gps_vel: np.ndarray    # (N,3) m/s, NED
    valid: np.ndarray      # (N,) uint32 bit mask (VALID_*)
    q_true: np.ndarray | None = None   # (N,4) body->NED truth (or reference), NaN where unknown
    meta: dict = field(default_factory=dict)  # description, rates, noise, seed, settle_time, mag_ref_ned, ...

    def __post_init__(self):
        n = len(self.t)
        for name in ("dt", "gyro", "accel", "mag", "gps_vel", "valid"):
            a = getattr(self, name)
            if len(a) != n:
                raise ValueError(f"SensorLog {self.name!r}: {name} has {len(a)} rows, t has {n}")
        for name, cols in (("gyro", 3), ("accel", 3), ("mag", 3), ("gps_vel", 3)):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.ndim != 2 or a.shape[1] != cols:
                raise ValueError(f"SensorLog {self.name!r}: {name} must be (N, {cols}), got {a.shape}")
            setattr(self, name, a)
        self.t = np.asarray(self.t, dtype=float)
        self.dt = np.asarray(self.dt, dtype=float)
        self.valid = np.asarray(self.valid, dtype=np.uint32)
        if self.q_true is not None:
            self.q_true = np.asarray(self.q_true, dtype=float)
            if self.q_true.shape != (n, 4):
                raise ValueError(f"SensorLog {self.name!r}: q_true must be (N, 4), got {self.q_true.shape}")

    def __len__(self) -> int:
        return len(self.t)

    @property
    def settle_time(self) -> float:
        """Seconds from the start that error statistics skip (meta['settle_time'], default 0)."""
        return float(self.meta.get("settle_time", 0.0))

    def slice(self, start: int, stop: int) -> "SensorLog":
        """Rows [start, stop) as a new log (dt[0] of the slice is kept as it was)."""
        sl = slice(start, stop)
        return SensorLog(self.name, self.t[sl], self.dt[sl], self.gyro[sl], self.accel[sl],
                         self.mag[sl], self.gps_vel[sl], self.valid[sl],
                         None if self.q_true is None else self.q_true[sl], dict(self.meta))

    def averaged(self, k: int) -> "SensorLog":
        """The log an IMU running k times slower records, as an integrating IMU reports it: every
        k rows become one at the time of the last, carrying the mean gyro and accelerometer of
        the k rows (the rate over its own interval); the magnetometer, GPS and truth are that
        row's, the gyro and accelerometer valid only if they were on all k rows. Rows after the
        last whole group are dropped; meta arrays of one entry per row are thinned alike."""
        k = int(k)
        if k < 1:
            raise ValueError(f"averaged: k must be a positive integer, got {k}")
        n = len(self) // k * k
        idx = np.arange(k - 1, n, k)
        t = self.t[idx]
        dt = np.empty(len(idx))
        dt[1:] = np.diff(t)
        dt[:1] = self.dt[0] * k
        valid = self.valid[idx].copy()
        for bit in (VALID_GYRO, VALID_ACCEL):
            every = np.all((self.valid[:n].reshape(-1, k) & np.uint32(bit)) != 0, axis=1)
            valid[~every] &= ~np.uint32(bit)
        meta = {key: (np.asarray(v)[idx] if isinstance(v, np.ndarray) and v.shape[:1] == (len(self),) else v)
                for key, v in self.meta.items()}
        return SensorLog(self.name, t, dt, self.gyro[:n].reshape(-1, k, 3).mean(axis=1),
                         self.accel[:n].reshape(-1, k, 3).mean(axis=1), self.mag[idx], self.gps_vel[idx], valid,
                         None if self.q_true is None else self.q_true[idx], meta)

