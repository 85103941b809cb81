"""Independent reference: `ahrs.filters.Madgwick` itself, mapped to the product's frames.

ahrs works with sensor axes FLU and an NWU earth frame; the product with FRD -> NED. Both
changes are a 180 degree turn about x: samples go in as (x, -y, -z), and the attitude comes
back as Qx (x) q_ahrs (x) Qx*, Qx = [0, 1, 0, 0]. Until it has one, the first usable accelerometer+magnetometer sample sets
the attitude (ahrsgen.npquat.from_accel_mag: TRIAD with the accelerometer primary). The
input checks are the product's shared contract (ahrsgen.codegen.input_checks); what they let through is handed to ahrs unchanged.
"""
from __future__ import annotations

import numpy as np
from ahrs.filters import Madgwick

from ahrsgen.codegen import input_checks
from ahrsgen.npquat import from_accel_mag, qconj, qmul

QX = np.array([0.0, 1.0, 0.0, 0.0])     # NWU -> NED and FLU -> FRD alike
FLU = np.array([1.0, -1.0, -1.0])        # FRD vector -> FLU vector


class Reference:
    def __init__(self, params: dict):
        self.p = dict(params)
        self.filter = Madgwick(gain=self.p["beta"])
        self.filter.gain = self.p["beta"]
        self.q = np.array([1.0, 0.0, 0.0, 0.0])
        self.initialised = not self.p["initialise"]          # body FRD -> NED

    def step(self, gyro, accel, mag, gps_vel, valid, dt):
        c = input_checks.check(self.p, ("accel", "mag"), gyro, accel, mag, gps_vel, valid, dt)
        if c.refused:
            return c.refused
        if not self.initialised and c.use_accel and c.use_mag:     # TRIAD (NumPy), not the model's FQA
            self.q = from_accel_mag(accel, mag)
            self.initialised = True
            return c.status                                        # that step does nothing else
        q_ahrs = qmul(qmul(qconj(QX), self.q), QX)
        g = FLU * c.gyro
        a = FLU * np.asarray(accel, float) if c.use_accel else np.zeros(3)
        if c.use_mag:
            q_ahrs = self.filter.updateMARG(q_ahrs, g, a, FLU * np.asarray(mag, float), dt=dt)
        else:
            q_ahrs = self.filter.updateIMU(q_ahrs, g, a, dt=dt)
        self.q = qmul(qmul(QX, np.asarray(q_ahrs, float)), qconj(QX))
        return c.status
