"""From the raw sample to the body frame: sensor calibration and mounting (issue 25).

A config file may hold two tables the generated C applies to every raw sample before anything
else (input checks included), folded as constants:

    [calibration]                       # what `ahrsgen calibrate` writes
    mag_hard_iron = [hx, hy, hz]        # raw units
    mag_soft_iron = [[..], [..], [..]]  # S (symmetric, det 1)
    gyro_bias = [bx, by, bz]            # rad/s
    mag_field_norm = 48.2               # informational

    [mounting]                          # sensor axes -> body axes (FRD)
    sensor_rotation = "ROLL_180"        # every sensor; or per sensor:
    gyro_rotation = "ROLL_180_YAW_90"   # accel_rotation, mag_rotation
    mag_rotation = [w, x, y, z]         # a quaternion (sensor -> body) instead of a name

The model, in this order (calibration in the sensor's own axes, then the mounting):

    gyro_body  = R_gyro  (gyro  - gyro_bias)
    accel_body = R_accel accel
    mag_body   = R_mag   S (mag - h)          (MATLAB magcal's model; not Fusion's S m - h)

Rotation names follow PX4's `ROTATION_*` list: ROLL_a, PITCH_b, YAW_c in that order, any of them,
angles in degrees (PX4 uses multiples of 45), with or without the ROTATION_ prefix, NONE for
none. As in PX4, the name is the rotation R(roll, pitch, yaw) = Rz(yaw) Ry(pitch) Rx(roll) that
takes a vector in sensor axes to body axes. `SensorFrame.apply` does the same to a log in NumPy
(for the reference and the tests); the C is written by the generator from the same matrices.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from ahrsgen.errors import ConfigError

SENSORS = ("gyro", "accel", "mag")
_NAME = re.compile(r"^(?:ROTATION_)?(?:ROLL_(\d+))?_?(?:PITCH_(\d+))?_?(?:YAW_(\d+))?$")


def _clean(M: np.ndarray) -> np.ndarray:
    """Entries within 1e-12 of 0 or +-1 made exact (a rotation by multiples of 90 deg then
    folds to exact negations and swaps)."""
    M = np.array(M, dtype=float)
    for v in (0.0, 1.0, -1.0):
        M[np.abs(M - v) < 1e-12] = v
    return M


def rotation(spec, where: str) -> np.ndarray:
    """3x3 sensor -> body rotation from a PX4-style name or a quaternion [w, x, y, z]."""
    if isinstance(spec, str):
        name = spec.strip().upper()
        if name in ("NONE", "ROTATION_NONE"):
            return np.eye(3)
        m = _NAME.match(name)
        if not name or m is None or not any(m.groups()):
            raise ConfigError(f"{where}: rotation {spec!r} is not a name like ROLL_180, YAW_90 or "
                              f"ROLL_180_PITCH_90 (PX4's ROTATION_* list), nor a quaternion [w, x, y, z]")
        r, p, y = (math.radians(int(g)) if g else 0.0 for g in m.groups())
        cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
        Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
        Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
        Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
        return _clean(Rz @ Ry @ Rx)
    if isinstance(spec, list) and len(spec) == 4 and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                         for v in spec):
        q = np.array(spec, dtype=float)
        n = np.linalg.norm(q)
        if not np.isfinite(n) or abs(n - 1.0) > 1e-3:
            raise ConfigError(f"{where}: quaternion {spec} must have norm 1 (it has {n:.6g})")
        w, x, y, z = q / n
        return _clean([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                       [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                       [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    raise ConfigError(f"{where}: a rotation is a name like \"ROLL_180\" or a quaternion [w, x, y, z], got {spec!r}")


def _vector(v, where, n=3):
    if (not isinstance(v, list) or len(v) != n
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)):
        raise ConfigError(f"{where}: expected a list of {n} finite numbers, got {v!r}")
    return np.array(v, dtype=float)


@dataclass
class SensorFrame:
    rot: dict = field(default_factory=lambda: {s: np.eye(3) for s in SENSORS})
    gyro_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    hard_iron: np.ndarray = field(default_factory=lambda: np.zeros(3))
    soft_iron: np.ndarray = field(default_factory=lambda: np.eye(3))

    def affine(self, sensor: str):
        """(M, c): body = M (raw - c) for one sensor."""
        if sensor == "gyro":
            return self.rot["gyro"], self.gyro_bias
        if sensor == "accel":
            return self.rot["accel"], np.zeros(3)
        return self.rot["mag"] @ self.soft_iron, self.hard_iron

    def changes(self, sensor: str) -> bool:
        M, c = self.affine(sensor)
        return not (np.array_equal(M, np.eye(3)) and not np.any(c))

    def apply(self, log):
        """A copy of the log with the raw samples taken to the body frame (NaN rows stay NaN)."""
        import copy
        out = copy.copy(log)
        for s in SENSORS:
            M, c = self.affine(s)
            setattr(out, s, (np.asarray(getattr(log, s), dtype=float) - c) @ M.T)
        return out

    def record(self) -> dict:
        """The values as plain lists (manifest.json)."""
        return {"gyro_bias": self.gyro_bias.tolist(), "mag_hard_iron": self.hard_iron.tolist(),
                "mag_soft_iron": self.soft_iron.tolist(), **{f"{s}_rotation": self.rot[s].tolist() for s in SENSORS}}


CAL_KEYS = {"mag_hard_iron", "mag_soft_iron", "mag_field_norm", "gyro_bias"}
MOUNT_KEYS = {"sensor_rotation"} | {f"{s}_rotation" for s in SENSORS}


def from_config(data: dict, where: str) -> SensorFrame | None:
    """The [calibration] and [mounting] tables of a config (None when it has neither)."""
    cal, mount = data.get("calibration"), data.get("mounting")
    if cal is None and mount is None:
        return None
    f = SensorFrame()
    for name, table, keys in (("calibration", cal, CAL_KEYS), ("mounting", mount, MOUNT_KEYS)):
        if table is None:
            continue
        if not isinstance(table, dict):
            raise ConfigError(f"{where}: '{name}' must be a table ([{name}])")
        unknown = set(table) - keys
        if unknown:
            raise ConfigError(f"{where}: [{name}] has unknown key(s) {', '.join(sorted(unknown))}; "
                              f"allowed: {', '.join(sorted(keys))}")
    cal = cal or {}
    if "gyro_bias" in cal:
        f.gyro_bias = _vector(cal["gyro_bias"], f"{where}: [calibration] gyro_bias")
    if "mag_hard_iron" in cal:
        f.hard_iron = _vector(cal["mag_hard_iron"], f"{where}: [calibration] mag_hard_iron")
    if "mag_soft_iron" in cal:
        S = cal["mag_soft_iron"]
        if not isinstance(S, list) or len(S) != 3:
            raise ConfigError(f"{where}: [calibration] mag_soft_iron must be 3 rows of 3 numbers")
        S = np.array([_vector(r, f"{where}: [calibration] mag_soft_iron row") for r in S])
        if not np.allclose(S, S.T, rtol=0, atol=1e-6 * np.abs(S).max()) or np.min(np.linalg.eigvalsh(0.5 * (S + S.T))) <= 0:
            raise ConfigError(f"{where}: [calibration] mag_soft_iron must be symmetric positive definite "
                              f"(what `ahrsgen calibrate` writes)")
        f.soft_iron = S
    if "mag_field_norm" in cal:
        _vector([cal["mag_field_norm"]], f"{where}: [calibration] mag_field_norm", 1)
    mount = mount or {}
    if "sensor_rotation" in mount:
        if any(f"{s}_rotation" in mount for s in SENSORS):
            raise ConfigError(f"{where}: [mounting] has sensor_rotation and a per-sensor rotation; give one or the other")
        R = rotation(mount["sensor_rotation"], f"{where}: [mounting] sensor_rotation")
        f.rot = {s: R for s in SENSORS}
    for s in SENSORS:
        if f"{s}_rotation" in mount:
            f.rot[s] = rotation(mount[f"{s}_rotation"], f"{where}: [mounting] {s}_rotation")
    return f
