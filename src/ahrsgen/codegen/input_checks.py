"""The shared input checks of every generated step (src/ahrsgen/codegen/templates/filter.c.j2), in NumPy, for
the references: same order, same thresholds, same status bits.

The references share this plumbing with each other, not with the C: it is written from the
contract in src/ahrsgen/status.py, and tests/filters/test_input_contract.py drives both sides.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ahrsgen import status as st

VALID_GYRO, VALID_ACCEL, VALID_MAG, VALID_GPS = 1, 2, 4, 8


@dataclass
class Checked:
    refused: int           # non-zero: the step is refused with this status, state untouched
    status: int            # skip bits of the aiding sensors
    use_accel: bool
    use_mag: bool
    use_gps: bool
    gyro: np.ndarray


def _aiding(v, valid, bit, vmax, vmin, b_nonfinite, b_range, b_zero):
    if not valid & bit:
        return False, 0
    v = np.asarray(v, dtype=float)
    if not np.all(np.isfinite(v)):
        return False, b_nonfinite
    if np.any(np.abs(v) > vmax):
        return False, b_range
    if vmin is not None and float(v @ v) < vmin * vmin:
        return False, b_zero
    return True, 0


def check(p: dict, sensors, gyro, accel, mag, gps_vel, valid: int, dt: float) -> Checked:
    """Classify one step's inputs for a filter reading `sensors` (of 'accel', 'mag', 'gps')."""
    valid = int(valid)
    no = Checked(0, 0, False, False, False, np.zeros(3))
    if not np.isfinite(dt) or not dt > 0:
        no.refused = st.DT_INVALID
    elif dt > p["dt_max"]:
        no.refused = st.DT_TOO_LARGE
    elif not valid & VALID_GYRO:
        no.refused = st.GYRO_MISSING
    if no.refused:
        return no
    g = np.asarray(gyro, dtype=float)
    if not np.all(np.isfinite(g)):
        no.refused = st.GYRO_NONFINITE
    elif np.any(np.abs(g) > p["gyro_max"]):
        no.refused = st.GYRO_RANGE
    if no.refused:
        return no
    status = 0
    use_accel = use_mag = use_gps = False
    if "accel" in sensors:
        use_accel, b = _aiding(accel, valid, VALID_ACCEL, p["accel_max"], p["accel_min_norm"],
                               st.ACCEL_NONFINITE, st.ACCEL_RANGE, st.ACCEL_ZERO)
        status |= b
    if "mag" in sensors:
        use_mag, b = _aiding(mag, valid, VALID_MAG, p["mag_max"], p["mag_min_norm"],
                             st.MAG_NONFINITE, st.MAG_RANGE, st.MAG_ZERO)
        status |= b
    if "gps" in sensors:
        use_gps, b = _aiding(gps_vel, valid, VALID_GPS, p["gps_vel_max"], None,
                             st.GPS_NONFINITE, st.GPS_RANGE, 0)
        status |= b
    return Checked(0, status, use_accel, use_mag, use_gps, g)
