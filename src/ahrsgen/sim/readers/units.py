"""Units recognised from a log's data (an accelerometer in g, a gyro in deg/s)."""
from __future__ import annotations

import numpy as np

from ahrsgen.sim.log import VALID_ACCEL, VALID_GYRO, VALID_MAG, SensorLog

def unit_warnings(log: SensorLog) -> list[str]:
    """Units recognised from the data, one line each (empty when they look right):

    - accelerometer: the median norm of its samples is g at rest and in most flight; a log in g
      reads about 1, in mg about 1000;
    - gyro: a direction fixed in NED (gravity, the field) seen in body axes turns as
      du/dt = -omega x u. The least-squares scale s in du/dt = -s (omega x u) over the log is
      1 for rad/s and pi/180 = 0.0175 for deg/s. Needs some rotation (else no line).
    """
    out = []
    acc_ok = (log.valid & VALID_ACCEL) != 0
    if acc_ok.sum() >= 10:
        med = float(np.median(np.linalg.norm(log.accel[acc_ok], axis=1)))
        if 0.5 < med < 2.0:
            out.append(f"the accelerometer looks like it is in g (median |a| = {med:.3g}), not m/s^2: "
                       f"multiply it by 9.80665")
        elif 500 < med < 2000:
            out.append(f"the accelerometer looks like it is in mg (median |a| = {med:.4g}), not m/s^2: "
                       f"multiply it by 0.00980665")
    s = gyro_scale(log)
    if s is not None and abs(s / (np.pi / 180) - 1) < 0.3:
        out.append(f"the gyro looks like it is in deg/s, not rad/s: the attitude change the accelerometer and "
                   f"magnetometer show is {s:.3g} x the gyro's (1 for rad/s, 0.0175 for deg/s)")
    elif s is not None and abs(s / (np.pi / 180e3) - 1) < 0.3:
        out.append(f"the gyro looks like it is in mdeg/s, not rad/s: the attitude change the accelerometer and "
                   f"magnetometer show is {s:.3g} x the gyro's (1 for rad/s)")
    return out


def gyro_scale(log: SensorLog, window_s: float = 0.05) -> float | None:
    """Least-squares s in du/dt = -s (omega x u) for the unit accelerometer and magnetometer
    directions u (see unit_warnings), over windows of about window_s; None when the log shows
    too little rotation to tell."""
    n = len(log)
    if n < 20:
        return None
    h = max(1, int(round(window_s / max(float(np.median(log.dt)), 1e-9))))
    num = den = seen = 0.0
    for bit, arr in ((VALID_ACCEL, log.accel), (VALID_MAG, log.mag)):
        ok = ((log.valid & bit) != 0) & ((log.valid & VALID_GYRO) != 0)
        a, b = np.arange(0, n - h), np.arange(h, n)
        pair = ok[a] & ok[b] & np.all(np.isfinite(log.gyro[a]), axis=1) & np.all(np.isfinite(log.gyro[b]), axis=1)
        a, b = a[pair], b[pair]
        if len(a) < 10:
            continue
        na, nb = np.linalg.norm(arr[a], axis=1), np.linalg.norm(arr[b], axis=1)
        # only samples of the undisturbed vector (norm within 5 % of its median): gravity without
        # motion acceleration, the field without a magnet nearby
        med = float(np.median(np.linalg.norm(arr[ok], axis=1))) if ok.any() else 0.0
        good = ((na > 0) & (nb > 0) & np.isfinite(na) & np.isfinite(nb)
                & (np.abs(na - med) < 0.05 * med) & (np.abs(nb - med) < 0.05 * med))
        a, b, na, nb = a[good], b[good], na[good], nb[good]
        ua, ub = arr[a] / na[:, None], arr[b] / nb[:, None]
        span = log.t[b] - log.t[a]
        du = (ub - ua) / span[:, None]
        w = 0.5 * (log.gyro[a] + log.gyro[b])
        pred = -np.cross(w, 0.5 * (ua + ub))
        num += float(np.sum(du * pred))
        den += float(np.sum(pred * pred))
        seen = max(seen, float(np.sqrt(np.mean(np.sum(du * du, axis=1)))))
    # the directions must show some rotation (0.05 rad/s RMS of |du/dt|): a still log says nothing
    if den <= 0 or seen < 0.05:
        return None
    return num / den
