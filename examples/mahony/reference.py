"""Independent reference: `ahrs.filters.Mahony` itself, mapped to the product's frames.

ahrs works with sensor axes FLU and an ENU earth frame; the product with FRD -> NED. Samples
go in as (x, -y, -z) (FLU = FRD turned 180 degrees about x); the attitude comes back as
Q_en (x) q_ahrs (x) Qx*, with Q_en = [0, 1/sqrt2, 1/sqrt2, 0] the turn ENU -> NED (swap x and
y, negate z) and Qx = [0, 1, 0, 0]. The gyro-bias estimate lives in ahrs (Mahony.b, FLU axes).
Until it has one, the first usable accelerometer+magnetometer sample sets the attitude
(ahrsgen.npquat.from_accel_mag: TRIAD with the accelerometer primary). The input checks are the product's shared contract (ahrsgen.codegen.input_checks).
"""
from __future__ import annotations

import numpy as np
from ahrs.filters import Mahony

from ahrsgen.codegen import input_checks
from ahrsgen.npquat import from_accel_mag, qconj, qmul

QX = np.array([0.0, 1.0, 0.0, 0.0])                          # FLU -> FRD
Q_EN = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])     # ENU -> NED
FLU = np.array([1.0, -1.0, -1.0])


class Reference:
    def __init__(self, params: dict):
        self.p = dict(params)
        self.filter = Mahony(k_P=self.p["kp"], k_I=self.p["ki"]) if self.p["ki"] > 0 and self.p["kp"] > 0 else None
        if self.filter is None:                 # ahrs refuses zero gains at construction; set them after
            self.filter = Mahony(k_P=1.0, k_I=1.0)
            self.filter.k_P, self.filter.k_I = self.p["kp"], self.p["ki"]
        self.q = np.array([1.0, 0.0, 0.0, 0.0])
        self.initialised = not self.p["initialise"]                 # body FRD -> NED

    @property
    def gyro_bias(self):
        return FLU * self.filter.b

    def step(self, gyro, accel, mag, gps_vel, valid, dt):
        c = input_checks.check(self.p, ("accel", "mag"), gyro, accel, mag, gps_vel, valid, dt)
        if c.refused:
            return c.refused
        if not self.initialised and c.use_accel and c.use_mag:     # TRIAD (NumPy), not the model's FQA
            self.q = from_accel_mag(accel, mag)
            self.initialised = True
            return c.status                                        # that step does nothing else
        q_ahrs = qmul(qmul(qconj(Q_EN), self.q), QX)
        g = FLU * c.gyro
        a = FLU * np.asarray(accel, float) if c.use_accel else np.zeros(3)
        if c.use_mag:
            q_ahrs = self.filter.updateMARG(q_ahrs, g, a, FLU * np.asarray(mag, float), dt=dt)
        else:
            q_ahrs = self.filter.updateIMU(q_ahrs, g, a, dt=dt)
        self.q = qmul(qmul(Q_EN, np.asarray(q_ahrs, float)), qconj(QX))
        return c.status
