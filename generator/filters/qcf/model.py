"""QCF: quaternion complementary filter (Lü, Xiao, Hu 2014), symbolic model.

Per step (SPEC.md, QCF):
  gravity part   f_g = f - R(q̂)^T a_n when ||f| - g| > threshold and a GPS acceleration is
                 available (section 3.2), else f
  reference      Q_r = FQA(f_g, m) (eq. 13's Q), or tilt-only FQA with q̂'s yaw without a
                 magnetometer sample
  error          Q~ = q̂^-1 ⊗ Q_r with q~0 >= 0 (eq. 13); q~ its vector part
  PI feedback    β = ω - b̂ + kp q~ ;  b̂ <- b̂ - ki q~ dt (eq. 14, b̂ of the previous step in β)
  integration    q̂ <- normalise(q̂ ⊗ exp(½ β dt)) (eq. 9 with the Picard/exact step, eq. 7)
  GPS accel      a_{k-3} = (c1 d1 + c2 d2 + c3 d3) / (2 T), d_i = V_{k-3+i} - V_{k-3-i} (eq. 29)

Product option (motion_accel_model): eq. 29 estimates the acceleration 3 GPS samples
(0.6 s at 5 Hz) in the past; in a turn the centripetal part changes faster than that. The
centripetal acceleration of a velocity vector turning with the body, a_c = ω_n × v_n with
ω_n = R(q̂)(ω − b̂), is known at once from the gyro and the latest GPS velocity. (Adding
eq. 29's along-track part was tried and made things worse: the stale centripetal part of
the lagged estimate leaks into the projection while the velocity turns.)
"""
from __future__ import annotations

import casadi as ca

from generator.emit import function
from generator.constants import G0
from generator.model import FilterModel, KernelSpec, StateField
from generator.symbolic import attitude, quat

# Eq. 29 as printed; its gain on a velocity ramp is c1 + 2 c2 + 3 c3 = 0.9854.
PAPER_COEFFS = (0.0971, 0.1662, 0.1853)
GPS_TAPS = 7          # V_{k-6} .. V_k


def differentiator_coeffs(faithful: bool):
    if faithful:
        return PAPER_COEFFS
    gain = sum((i + 1) * c for i, c in enumerate(PAPER_COEFFS))
    return tuple(c / gain for c in PAPER_COEFFS)


class Model(FilterModel):
    def __init__(self, params: dict):
        super().__init__(params, sensors=("accel", "mag", "gps"))

    def state_fields(self):
        p = self.params
        return [
            StateField("q", 4, "attitude estimate, body->NED, [w x y z]", [1.0, 0.0, 0.0, 0.0]),
            StateField("gyro_bias", 3, "gyro bias estimate b, rad/s", 0.0),
            StateField("gps_vel_hist", 3 * GPS_TAPS, "last 7 GPS velocities (NED, m/s), oldest first", 0.0),
            StateField("motion_accel", 3, "latest GPS-derived motion acceleration a_{k-3}, NED, m/s^2", 0.0),
            StateField("gps_age", 1, "time since the last GPS sample, s", 1e3),
            StateField("gps_count", 1, "GPS samples in the history (saturates at 7)", 0, "uint32"),
            StateField("initialised", 1, "1 once the attitude has been initialised", 1 if p["faithful"] else 0, "uint32"),
        ]

    def kernels(self):
        p = self.params
        q = ca.SX.sym("q", 4)
        bias = ca.SX.sym("gyro_bias", 3)
        gyro = ca.SX.sym("gyro", 3)
        dt = ca.SX.sym("dt")
        f = ca.SX.sym("accel", 3)
        m = ca.SX.sym("mag", 3)
        q_ref = ca.SX.sym("q_ref", 4)
        a_n = ca.SX.sym("motion_accel", 3)
        hist = ca.SX.sym("gps_vel_hist", 3 * GPS_TAPS)

        # Gravity part of the specific force (section 3.2): f_b = R^T (a_n - g_n).
        excess = ca.fabs(ca.sqrt(ca.sumsqr(f)) - G0) > p["motion_accel_threshold"]
        f_g = ca.if_else(excess, f - quat.rotate_inv(q, a_n), f)

        # PI feedback and integration (eqs. 13, 14, 9, 7).
        q_err = quat.qmul(quat.qconj(q), q_ref)
        q_err = ca.if_else(q_err[0] < 0, -q_err, q_err)
        beta = gyro - bias + p["kp"] * q_err[1:]
        bias_new = bias - p["ki"] * q_err[1:] * dt

        # Lagged GPS differentiator (eq. 29).
        c = differentiator_coeffs(p["faithful"])
        V = [hist[3 * i:3 * i + 3] for i in range(GPS_TAPS)]
        acc = sum(c[i - 1] * (V[3 + i] - V[3 - i]) for i in (1, 2, 3)) / (2 * p["gps_period"])

        kernels = []
        if p["motion_accel_model"] != "differentiator":
            v = hist[3 * (GPS_TAPS - 1):]                       # latest GPS velocity
            a_c = ca.cross(quat.rotate(q, gyro - bias), v)
            kernels.append(KernelSpec(
                "motion_accel", function("motion_accel", {"q": q, "gyro": gyro, "gyro_bias": bias,
                                                          "gps_vel_hist": hist},
                                         {"motion_accel_now": a_c}),
                "centripetal acceleration now: R(q)(w - b) x v_gps (NED, m/s^2)"))
        return kernels + [
            KernelSpec("gravity_part", function("gravity_part", {"accel": f, "q": q, "motion_accel": a_n},
                                                {"accel_gravity": f_g}),
                       "accelerometer minus the GPS motion acceleration when ||f| - g| exceeds the threshold"),
            KernelSpec("reference", function("reference", {"accel": f, "mag": m},
                                             {"q_ref": attitude.fqa(f, m, p["declination"])}),
                       "factored quaternion algorithm (FQA): attitude from accelerometer and magnetometer"),
            KernelSpec("reference_tilt", function("reference_tilt", {"accel": f, "q": q},
                                                  {"q_ref": attitude.tilt_with_yaw(f, quat.euler(q)[2])}),
                       "FQA tilt with the estimate's yaw, for steps without a magnetometer sample"),
            KernelSpec("update", function("update", {"q": q, "gyro_bias": bias, "gyro": gyro, "q_ref": q_ref, "dt": dt},
                                          {"q_new": quat.integrate(q, beta, dt), "gyro_bias_new": bias_new}),
                       "PI feedback on the error quaternion q^-1 (x) q_ref and integration (eqs. 13, 14, 9)"),
            KernelSpec("propagate", function("propagate", {"q": q, "gyro_bias": bias, "gyro": gyro, "dt": dt},
                                             {"q_new": quat.integrate(q, gyro - bias, dt)}),
                       "gyro-only integration with the bias removed (no aiding this step)"),
        ] + ([KernelSpec("gps_accel", function("gps_accel", {"gps_vel_hist": hist}, {"motion_accel": acc}),
                         "lagged differentiator of GPS velocity (eq. 29): NED acceleration 3 samples back")]
             if p["motion_accel_model"] == "differentiator" else [])

    def template_context(self):
        return {"motion_model": self.params["motion_accel_model"]}

    def step_paths(self):
        comp = ["gravity_part"] if self.params["motion_accel_model"] == "differentiator" else ["motion_accel", "gravity_part"]
        return {
            "full (accel+mag+GPS comp.)": comp + ["reference", "update"],
            "accel+mag": ["reference", "update"],
            "gyro only": ["propagate"],
            **({"GPS sample (extra)": ["gps_accel"]} if self.params["motion_accel_model"] == "differentiator" else {}),
        }
