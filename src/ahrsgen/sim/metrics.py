"""Attitude error statistics: per-angle Euler errors (SPEC.md) and BROAD's method."""
from __future__ import annotations

import numpy as np

from ahrsgen.errors import ConfigError
from ahrsgen.npquat import euler_from_q, qconj, qmul, wrap


def euler_errors_deg(q_est, q_ref):
    """(N,3) roll/pitch/yaw errors in degrees, each wrapped to (-180, 180]."""
    return np.degrees(wrap(euler_from_q(q_est) - euler_from_q(q_ref)))


def euler_stats(q_est, q_ref, t=None, settle_time=0.0):
    """RMS, mean absolute and max absolute error per angle (degrees), after settle_time.

    Rows where the reference is not finite are left out.
    """
    err = euler_errors_deg(q_est, q_ref)
    keep = np.all(np.isfinite(err), axis=1)
    if t is not None:
        keep &= np.asarray(t) >= np.asarray(t)[0] + settle_time
    e = err[keep]
    if len(e) == 0:
        # a ConfigError (a ValueError too): the run asked for is too short to score, one line
        if t is not None and len(t) and np.asarray(t)[-1] - np.asarray(t)[0] < settle_time:
            raise ConfigError(f"the run lasts {np.asarray(t)[-1] - np.asarray(t)[0]:.4g} s, shorter than its settle "
                              f"time of {settle_time:g} s: nothing to score (give a longer duration)")
        raise ConfigError("no samples left to score (all before the settle time, or no reference)")
    out = {}
    for i, name in enumerate(("roll", "pitch", "yaw")):
        out[name] = {
            "rms": float(np.sqrt(np.mean(e[:, i] ** 2))),
            "mean_abs": float(np.mean(np.abs(e[:, i]))),
            "max_abs": float(np.max(np.abs(e[:, i]))),
        }
    out["n"] = int(len(e))
    return out


def broad_errors_deg(q_est, q_ref):
    """BROAD's error decomposition (earth frame): total, heading, inclination, degrees (N,)."""
    qe = qmul(q_est, qconj(q_ref))
    w = np.abs(qe[..., 0])
    z = qe[..., 3]
    total = 2 * np.arccos(np.clip(w, -1, 1))
    heading = 2 * np.arctan(np.abs(z / qe[..., 0]))
    incl = 2 * np.arccos(np.clip(np.sqrt(qe[..., 0] ** 2 + z ** 2), -1, 1))
    return np.degrees(total), np.degrees(heading), np.degrees(incl)


def max_angle_diff_rad(q_a, q_b):
    """Largest rotation angle between two quaternion sequences (q and -q equal), radians."""
    d = np.abs(np.sum(np.asarray(q_a) * np.asarray(q_b), axis=-1))
    # 2*acos(|<a,b>|) loses precision near 1; use the vector part of the error quaternion.
    qe = qmul(qconj(q_a), q_b)
    ang = 2 * np.arctan2(np.linalg.norm(qe[..., 1:], axis=-1), np.abs(qe[..., 0]))
    del d
    return float(np.max(ang)) if len(ang) else 0.0


def wrap_deg_diff(a_rad, b_rad):
    """Element-wise a - b wrapped to (-pi, pi], radians."""
    return wrap(np.asarray(a_rad) - np.asarray(b_rad))
