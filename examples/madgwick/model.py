"""Madgwick's AHRS (2010 report, eqs. 12-13, 25-34, 45-46) as a CasADi model.

Written in the product's frames (body FRD -> NED, scalar first). `ahrs.filters.Madgwick`
works in an NWU earth frame with sensor axes FLU; both frame changes are the same 180 degree
turn about x, under which the update is equivariant, so the same equations hold here with
gravity's "up" direction u = [0, 0, -1] (NED) instead of [0, 0, 1] (NWU).

One step:  qdot = 1/2 q (x) [0, w]  -  beta * grad / |grad|,   q <- normalise(q + qdot dt)
with grad = J^T f, f = [R^T u - a; R^T b - m] (a, m normalised), b = [|h_xy|, 0, h_z],
h = R m, and J = df/dq with b held fixed (CasADi differentiates f: no hand-written Jacobian).
"""
from __future__ import annotations

import casadi as ca

from ahrsgen.codegen.emit import function
from ahrsgen.codegen.model import FilterModel, KernelSpec, StateField
from ahrsgen.symbolic import attitude, quat

UP = ca.DM([0.0, 0.0, -1.0])          # "up" in NED: what a resting accelerometer measures, normalised


def _rate(q, gyro):
    return 0.5 * quat.qmul(q, quat.pure(gyro))


def _corrected(q, gyro, f, beta):
    """qdot of eq. 33: gyro rate minus beta times the normalised gradient of |f|^2 / 2."""
    grad = ca.mtimes(ca.jacobian(f, q).T, f)
    n2 = ca.sumsqr(grad)
    step = ca.if_else(n2 > 0, beta * grad / ca.sqrt(n2), ca.DM.zeros(4))      # |grad_i| <= sqrt(n2)
    return _rate(q, gyro) - step


def _advance(q, qdot, dt):
    return quat.qnormalize(q + qdot * dt)


class Model(FilterModel):
    def __init__(self, params: dict):
        super().__init__(params, sensors=("accel", "mag"))

    def state_fields(self):
        fields = [StateField("q", 4, "attitude estimate, body FRD -> NED, [w x y z]", [1.0, 0.0, 0.0, 0.0])]
        if self.params["initialise"]:        # else the step has no initialisation to wait for
            fields.append(StateField("initialised", 1, "1 once the attitude has been set from the sensors", 0, "uint32"))
        return fields

    def kernels(self):
        beta = self.params["beta"]
        q = ca.SX.sym("q", 4)
        gyro = ca.SX.sym("gyro", 3)
        accel = ca.SX.sym("accel", 3)
        mag = ca.SX.sym("mag", 3)
        dt = ca.SX.sym("dt")
        a = accel / ca.sqrt(ca.sumsqr(accel))
        m = mag / ca.sqrt(ca.sumsqr(mag))
        Rt = quat.rotmat(q).T
        # magnetic reference in the earth frame (eqs. 45-46), a constant of the descent
        h = quat.rotate(q, m)
        b = ca.SX.sym("b", 2)
        f_acc = ca.mtimes(Rt, UP) - a
        f_mag = ca.mtimes(Rt, ca.vertcat(b[0], 0, b[1])) - m
        qdot_marg = _corrected(q, gyro, ca.vertcat(f_acc, f_mag), beta)
        qdot_marg = ca.substitute(qdot_marg, b, ca.vertcat(ca.sqrt(h[0] ** 2 + h[1] ** 2), h[2]))
        qdot_imu = _corrected(q, gyro, f_acc, beta)
        ins = {"q": q, "gyro": gyro, "accel": accel, "mag": mag, "dt": dt}
        init = KernelSpec("initial_attitude", function("initial_attitude", {"accel": accel, "mag": mag},
                                                      {"q_init": attitude.fqa(accel, mag)}),
                          "attitude of one accelerometer+magnetometer sample (FQA: accelerometer-primary)")
        # initialise = false starts at the identity, as the classic C code does: no kernel, no test
        return ([init] if self.params["initialise"] else []) + [
            KernelSpec("update_marg", function("update_marg", ins, {"q_new": _advance(q, qdot_marg, dt)}),
                       "gyro rate plus gradient step towards gravity and the magnetic reference (eqs. 33, 34, 45, 46)"),
            KernelSpec("update_imu", function("update_imu", {k: ins[k] for k in ("q", "gyro", "accel", "dt")},
                                              {"q_new": _advance(q, qdot_imu, dt)}),
                       "gyro rate plus gradient step towards gravity only (eqs. 25-26, 33)"),
            KernelSpec("propagate", function("propagate", {"q": q, "gyro": gyro, "dt": dt},
                                             {"q_new": _advance(q, _rate(q, gyro), dt)}),
                       "gyro rate only (eqs. 12-13)"),
        ]

    def step_paths(self):
        return {"accel+mag": ["update_marg"], "accel only": ["update_imu"], "gyro only": ["propagate"]}
