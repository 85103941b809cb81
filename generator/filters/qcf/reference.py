"""QCF reference in plain NumPy, written from the paper's equations (not from the model).

Same step logic and status bits as the generated C; see model.py's docstring for the
equations. FQA follows Yun, Bachmann, McGhee (2008) in the product's FRD/NED convention.
"""
from __future__ import annotations

import numpy as np

from generator import npquat as nq
from generator import input_checks
from generator.constants import G0

PAPER_COEFFS = np.array([0.0971, 0.1662, 0.1853])


def _half(c, s):
    c = min(max(c, -1.0), 1.0)
    sign = -1.0 if s < 0 else 1.0
    return np.sqrt((1 + c) / 2), sign * np.sqrt((1 - c) / 2)


def fqa_tilt(f):
    a = np.asarray(f, float) / np.linalg.norm(f)
    s_th = min(max(a[0], -1.0), 1.0)
    c_th = np.sqrt(1 - s_th * s_th)
    ch, sh = _half(c_th, s_th)
    q_pitch = np.array([ch, 0.0, sh, 0.0])
    if c_th < 1e-6:
        s_ph, c_ph = 0.0, 1.0
    else:
        s_ph, c_ph = -a[1] / c_th, -a[2] / c_th
    ch, sh = _half(c_ph, s_ph)
    q_roll = np.array([ch, sh, 0.0, 0.0])
    return nq.qmul(q_pitch, q_roll)


def fqa(f, m, declination=0.0):
    """Body->NED attitude from specific force f and field m (FQA, half-angle form)."""
    q_tilt = fqa_tilt(f)
    ml = nq.rotmat(q_tilt) @ np.asarray(m, float)
    n = max(np.hypot(ml[0], ml[1]), 1e-30)
    ch, sh = _half(ml[0] / n, -ml[1] / n)
    q = nq.qmul(np.array([ch, 0.0, 0.0, sh]), q_tilt)
    if declination:
        q = nq.qmul(np.array([np.cos(declination / 2), 0, 0, np.sin(declination / 2)]), q)
    return q


def fqa_tilt_with_yaw(f, yaw):
    return nq.qmul(np.array([np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)]), fqa_tilt(f))


def integrate(q, omega, dt):
    return nq.qnormalize(nq.qmul(q, _exp_half(np.asarray(omega, float) * dt)))


def _exp_half(rotvec):
    """exp([0, r/2]) with the same small-angle series as the C (threshold 1e-4 on |r/2|)."""
    v = 0.5 * rotvec
    n2 = float(v @ v)
    n = np.sqrt(n2)
    if n < 1e-4:
        return np.array([1 - n2 / 2, *((1 - n2 / 6) * v)])
    return np.array([np.cos(n), *(np.sin(n) / n * v)])


class Reference:
    def __init__(self, params: dict):
        self.p = dict(params)
        c = PAPER_COEFFS
        if not self.p["faithful"]:
            c = c / (c[0] + 2 * c[1] + 3 * c[2])
        self.coeffs = c
        self.q = np.array([1.0, 0.0, 0.0, 0.0])
        self.bias = np.zeros(3)
        self.hist = []                    # GPS velocities, oldest first, at most 7
        self.motion_accel = np.zeros(3)
        self.gps_age = 1e3
        self.initialised = bool(self.p["faithful"])

    def step(self, gyro, accel, mag, gps_vel, valid, dt):
        p = self.p
        c = input_checks.check(p, ("accel", "mag", "gps"), gyro, accel, mag, gps_vel, valid, dt)
        if c.refused:
            return c.refused
        status, use_accel, use_mag, use_gps, gyro = c.status, c.use_accel, c.use_mag, c.use_gps, c.gyro

        if use_gps:
            if self.gps_age > p["gps_timeout"]:
                self.hist = []
            self.hist = (self.hist + [np.asarray(gps_vel, float)])[-7:]
            self.gps_age = 0.0
            if len(self.hist) == 7 and p["motion_accel_model"] == "differentiator":   # (the C keeps it only then)
                V = self.hist
                d = [V[3 + i] - V[3 - i] for i in (1, 2, 3)]
                self.motion_accel = sum(c * di for c, di in zip(self.coeffs, d)) / (2 * p["gps_period"])
        elif self.gps_age < 1e3:
            self.gps_age += dt

        if use_accel:
            f = np.asarray(accel, float)
            model = p["motion_accel_model"]
            need = 7 if model == "differentiator" else 1
            if p["gps_compensation"] and len(self.hist) >= need and self.gps_age <= p["gps_timeout"]:
                a_n = self.motion_accel
                if model != "differentiator":
                    # centripetal acceleration of the GPS velocity turning with the body
                    v = self.hist[-1]
                    a_n = np.cross(nq.rotmat(self.q) @ (gyro - self.bias), v)
                if abs(np.linalg.norm(f) - G0) > p["motion_accel_threshold"]:
                    f = f - nq.rotmat(self.q).T @ a_n
            if use_mag:
                q_ref = fqa(f, mag, p["declination"])
                if not self.initialised:
                    self.q = q_ref.copy()
                    self.initialised = True
            else:
                q_ref = fqa_tilt_with_yaw(f, nq.euler_from_q(self.q)[2])
            q_err = nq.qmul(nq.qconj(self.q), q_ref)
            if q_err[0] < 0:
                q_err = -q_err
            beta = gyro - self.bias + p["kp"] * q_err[1:]
            self.bias = self.bias - p["ki"] * q_err[1:] * dt
            self.q = integrate(self.q, beta, dt)
        else:
            self.q = integrate(self.q, gyro - self.bias, dt)
        return status
