"""Mahony's explicit complementary filter (Mahony, Hamel, Pflimlin 2008, eqs. 32, 45, 48) as
a CasADi model, in the product's frames (body FRD -> NED, scalar first).

`ahrs.filters.Mahony` uses sensor axes FLU and an ENU earth frame; the update is equivariant
under both rotations, so the same equations hold in FRD/NED with "up" u = [0, 0, -1] and the
magnetic reference b = [|h_xy|, 0, h_z] (north along x instead of y). One step:

  w_mes = a x R^T u  +  m x normalise(R^T b)        (a, m normalised; h = R m)
  b_g  <- b_g - ki w_mes dt                          (gyro-bias estimate, updated first)
  W     = w - b_g + kp w_mes
  q    <- normalise(q + 1/2 q (x) [0, W] dt)
"""
from __future__ import annotations

import casadi as ca

from ahrsgen.codegen.emit import function
from ahrsgen.codegen.model import FilterModel, KernelSpec, StateField
from ahrsgen.symbolic import attitude, quat

UP = ca.DM([0.0, 0.0, -1.0])


def _advance(q, omega, dt):
    return quat.qnormalize(q + 0.5 * quat.qmul(q, quat.pure(omega)) * dt)


class Model(FilterModel):
    def __init__(self, params: dict):
        super().__init__(params, sensors=("accel", "mag"))

    def state_fields(self):
        fields = [StateField("q", 4, "attitude estimate, body FRD -> NED, [w x y z]", [1.0, 0.0, 0.0, 0.0])]
        if self.params["initialise"]:        # else the step has no initialisation to wait for
            fields.append(StateField("initialised", 1, "1 once the attitude has been set from the sensors", 0, "uint32"))
        return fields + [StateField("gyro_bias", 3, "gyro-bias estimate b_g, rad/s (ahrs' Mahony.b)", 0.0)]

    def kernels(self):
        kp, ki = self.params["kp"], self.params["ki"]
        q = ca.SX.sym("q", 4)
        bias = ca.SX.sym("gyro_bias", 3)
        gyro = ca.SX.sym("gyro", 3)
        accel = ca.SX.sym("accel", 3)
        mag = ca.SX.sym("mag", 3)
        dt = ca.SX.sym("dt")
        a = accel / ca.sqrt(ca.sumsqr(accel))
        m = mag / ca.sqrt(ca.sumsqr(mag))
        Rt = quat.rotmat(q).T
        h = quat.rotate(q, m)
        v_m = ca.mtimes(Rt, ca.vertcat(ca.sqrt(h[0] ** 2 + h[1] ** 2), 0, h[2]))
        err_acc = ca.cross(a, ca.mtimes(Rt, UP))
        # |v_m| = |b| = |h| = |m| = 1 for a unit q: ahrs normalises v_m again, a human does not
        err_marg = err_acc + ca.cross(m, v_m)

        def corrected(err):
            bias_new = bias - ki * err * dt
            return {"q_new": _advance(q, gyro - bias_new + kp * err, dt), "gyro_bias_new": bias_new}

        ins = {"q": q, "gyro_bias": bias, "gyro": gyro, "accel": accel, "mag": mag, "dt": dt}
        imu = {k: ins[k] for k in ("q", "gyro_bias", "gyro", "accel", "dt")}
        init = KernelSpec("initial_attitude", function("initial_attitude", {"accel": accel, "mag": mag},
                                                      {"q_init": attitude.fqa(accel, mag)}),
                          "attitude of one accelerometer+magnetometer sample (FQA: accelerometer-primary)")
        # initialise = false starts at the identity, as the classic C code does: no kernel, no test
        return ([init] if self.params["initialise"] else []) + [
            KernelSpec("update_marg", function("update_marg", ins, corrected(err_marg)),
                       "direction errors to gravity and the magnetic reference: PI feedback (eqs. 32c, 48)"),
            KernelSpec("update_imu", function("update_imu", imu, corrected(err_acc)),
                       "direction error to gravity only: PI feedback (eqs. 32c, 48)"),
            KernelSpec("propagate", function("propagate", {"q": q, "gyro": gyro, "dt": dt},
                                             {"q_new": _advance(q, gyro, dt)}),
                       "raw gyro rate only (as ahrs does without an accelerometer sample: no bias removed)"),
        ]

    def step_paths(self):
        return {"accel+mag": ["update_marg"], "accel only": ["update_imu"], "gyro only": ["propagate"]}
