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
