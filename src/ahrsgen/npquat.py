"""Plain NumPy quaternion and angle helpers for the references, scenarios and metrics.

Written independently of the CasADi building blocks in src/ahrsgen/symbolic/ so that the
references do not share code with the models they check. Conventions as in SPEC.md:
Hamilton product, scalar first, q rotates body to NED, Z-Y-X Euler angles.
"""
from __future__ import annotations

import numpy as np


def qmul(p, q):
    """Hamilton product p ⊗ q (works on (...,4) arrays)."""
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack([
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    ], axis=-1)


def qconj(q):
    q = np.asarray(q, dtype=float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def qnormalize(q):
    q = np.asarray(q, dtype=float)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def qrot(q, v):
    """Rotate vector v by q: q ⊗ [0, v] ⊗ q* (body -> NED for a body->NED q)."""
    return rotmat(q) @ np.asarray(v, dtype=float)


def skew(v):
    """[v]x, with [v]x u = v x u."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rotmat(q):
    """Rotation matrix R(q) with v_n = R v_b."""
    w, x, y, z = np.asarray(q, dtype=float)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def qexp(v):
    """exp of the pure quaternion [0, v]: [cos|v|, sin|v| v/|v|]."""
    v = np.asarray(v, dtype=float)
    n = np.linalg.norm(v)
    if n < 1e-12:
        return np.array([1.0, *v])
    return np.concatenate([[np.cos(n)], np.sin(n) / n * v])


def from_rotvec(r):
    """Quaternion of the rotation vector r (angle |r| about r/|r|)."""
    return qexp(0.5 * np.asarray(r, dtype=float))


def to_rotvec(q):
    """Rotation vector of q (shortest: q and -q give the same)."""
    q = np.asarray(q, dtype=float)
    if q[0] < 0:
        q = -q
    n = np.linalg.norm(q[1:])
    if n < 1e-15:
        return 2.0 * q[1:]
    return 2.0 * np.arctan2(n, q[0]) * q[1:] / n


def wrap(a):
    """Wrap angles to (-pi, pi]."""
    a = np.asarray(a, dtype=float)
    return a + 2 * np.pi * np.floor((np.pi - a) / (2 * np.pi))


def euler_from_q(q):
    """Z-Y-X Euler angles [roll, pitch, yaw] of body->NED quaternion(s) q (...,4)."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = np.moveaxis(q, -1, 0)
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - x * z), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=-1)


def q_from_euler(roll, pitch, yaw):
    """Body->NED quaternion of Z-Y-X Euler angles: qz(yaw) ⊗ qy(pitch) ⊗ qx(roll)."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.stack([
        cy * cp * cr + sy * sp * sr,
        cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr,
        sy * cp * cr - cy * sp * sr,
    ], axis=-1)


def from_rotmat(R):
    """Quaternion (scalar first, w >= 0) of a rotation matrix (Shepperd's method)."""
    R = np.asarray(R, dtype=float)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(1.0 + tr)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def from_accel_mag(accel, mag):
    """Body FRD -> NED attitude from one specific-force and one magnetometer sample (TRIAD)."""
    down = -np.asarray(accel, dtype=float)
    down /= np.linalg.norm(down)
    east = np.cross(down, mag)
    east /= np.linalg.norm(east)
    north = np.cross(east, down)
    R_nb = np.vstack([north, east, down])   # rows: NED axes in body coordinates -> R^T
    return from_rotmat(R_nb)           # R_nb maps body -> NED coordinates
