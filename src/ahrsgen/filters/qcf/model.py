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
'gps_lowpass' (issue 26, product conditioning only; mekf's construction, aiding.gps_lowpass):
the GPS velocity (carried between samples by R f + g) goes through the NED low-pass with the
same gain as the specific force, v_lp <- v_lp + k (v - v_lp), and the tilt reads
up = a - (v - v_lp)/accel_tau: the low-passed total kinematic acceleration removed (linear and
centripetal, no differencing noise, no |f| threshold). Without a GPS sample within gps_timeout
nothing is removed and the velocity low-pass restarts on the next sample.

Product conditioning (faithful = false; issue 10; building blocks in src/ahrsgen/symbolic/aiding.py):
  init           the first accelerometer sample sets q: the shortest rotation taking its (raw) down
                 direction to NED down (tilt), then the heading of the first magnetometer
                 sample (in that step or later) by the heading correction below; with both in
                 the first step this is FQA's attitude
  low-pass       a <- a + k (R(q̂) f_g - a), k = s_a/(accel_tau + s_a): the specific force in
                 NED, low-passed (motion acceleration averages out, gravity does not);
                 accel_lp_warm (issue 26, VQF's warm start): k = s_a/(min(t, accel_tau) + s_a),
                 t the time it has averaged (0 at the first sample, + s_a per sample, at most
                 accel_tau; held and k = 1 while recovering from a gyro clip): the running mean
                 until it has seen accel_tau, the first sample weighing 1/n
  tilt           T = shortest NED rotation taking d = -a/|a| to [0,0,1] (no z part, any attitude)
  heading        H = rotation about NED z taking the horizontal part of R(T q̂) m to north +
                 declination, only for a magnetometer sample whose norm and dip (against
                 R(T q̂)ᵀ[0,0,1]) pass the field check
  error          e dt = R(q̂)ᵀ (s_a vec(T) + s_m vec(H))  (the vector part of q̂⁻¹ T H q̂ to first
                 order, each part weighted by the time s its sensor's sample stands for)
  order          predict, then correct (issue 27): q̂⁻ = normalise(q̂ ⊗ exp(½ (ω - b̂) dt)) first, so
                 the sensors of step k are compared with the attitude of step k, not of step k-1
                 (the paper's order, kept when faithful or conditioning = false, leads the truth
                 by ω dt: 0.02 rad at 2 rad/s and 100 Hz); everything below reads q̂⁻
  PI feedback    q̂ <- normalise(q̂⁻ ⊗ exp(½ kp e dt)) ; b̂ <- b̂ - ki e dt only while ||f| - g| < bias_accel_gate;
                 at rest (aiding.rest_detector) b̂ follows the low-passed gyro instead; with
                 rest_turn = 'estimate' the estimate's low-passed rotation rate
                 2 vec(q̂⁻_prev⁻¹ q̂⁻)/s (one accelerometer step to the next, the corrections
                 between included) below rest_gyro_tol is no turn either: a gyro bias the
                 accelerometer and magnetometer hold the attitude against does not turn it
  integration    as eq. 9, the gyro part in the prediction
"""
from __future__ import annotations

import casadi as ca

from ahrsgen.codegen.emit import function
from ahrsgen.constants import G0, Const, use
from ahrsgen.codegen.model import FilterModel, KernelSpec, StateField
from ahrsgen.symbolic import aiding, attitude, quat

# Eq. 29 as printed; its gain on a velocity ramp is c1 + 2 c2 + 3 c3 = 0.9854.
PAPER_COEFFS = (Const("EQ29_C1", 0.0971), Const("EQ29_C2", 0.1662), Const("EQ29_C3", 0.1853))
# the centripetal weight's cos(angle) divides by |v|, floored by its square here, (m/s)^2
ALONG_V2_MIN = Const("ALONG_V2_MIN", 1e-6)
# the time since the last GPS sample stops counting here, s (a whole number: exact in float)
GPS_AGE_MAX = Const("GPS_AGE_MAX", 1e3)
GPS_TAPS = 7          # V_{k-6} .. V_k (the differentiator; the centripetal term reads only V_k)


def gps_taps(params) -> int:
    """GPS velocities the state keeps: eq. 29 reads 7, the centripetal term the latest only."""
    return GPS_TAPS if params["motion_accel_model"] == "differentiator" else 1


def warm(params) -> bool:
    """The NED low-pass starts warm (accel_lp_warm, issue 26): product conditioning, accel_tau > 0."""
    return (bool(params["accel_lp_warm"]) and not params["faithful"] and bool(params["conditioning"])
            and params["accel_tau"] > 0)


def gps_lowpass(params) -> bool:
    """The GPS velocity's low-passed derivative is removed in the NED low-pass (product only;
    accel_tau = 0 has no low-pass to share: nothing is removed)."""
    return (params["motion_accel_model"] == "gps_lowpass" and not params["faithful"]
            and bool(params["conditioning"]) and params["accel_tau"] > 0)


def differentiator_coeffs(faithful: bool):
    coeffs = [use(c) for c in PAPER_COEFFS]
    if faithful:
        return tuple(coeffs)
    gain = sum((i + 1) * c for i, c in enumerate(coeffs))
    return tuple(c / gain for c in coeffs)


EXTRA_STATUS = [
    ("MAG_DISTURBED", "magnetometer norm or dip off its reference: heading not corrected this step", "info"),
    ("AT_REST", "at rest: the gyro bias follows the low-passed gyro", "info"),
    ("GYRO_RECOVERY", "a gyro component at gyro_full_scale (clipped), or within clip_recovery_time after one: kp_recovery on the sensors as they come", "info"),
    ("HARD_IRON_SWITCHED", "the hard iron and the field check's reference were replaced by the candidate field model (mag_bias)", "info"),
]


class Model(FilterModel):
    def __init__(self, params: dict):
        product = not params["faithful"] and params["conditioning"]
        super().__init__(params, sensors=("accel", "mag", "gps"),
                         extra_status=list(EXTRA_STATUS) if product else [])
        self.product = product

    def state_fields(self):
        p = self.params
        return [
            StateField("q", 4, "attitude estimate, body->NED, [w x y z]", [1.0, 0.0, 0.0, 0.0]),
            StateField("gyro_bias", 3, "gyro bias estimate b, rad/s", 0.0),
            StateField("gps_vel_hist", 3 * gps_taps(p), "last 7 GPS velocities (NED, m/s), oldest first"
                       if gps_taps(p) > 1 else "latest GPS velocity (NED, m/s)", 0.0),
        ] + ([
            StateField("motion_accel", 3, "latest GPS-derived motion acceleration a_{k-3}, NED, m/s^2", 0.0),
        ] if p["motion_accel_model"] == "differentiator" else []) + [
            StateField("gps_age", 1, "time since the last GPS sample, s", GPS_AGE_MAX),
            StateField("gps_count", 1, "GPS samples since the last gap (counting stops at 7)", 0, "uint32"),
            StateField("initialised", 1, "1 once the attitude has been initialised" + (
                " (tilt only), 2 with heading" if self.product else ""), 1 if p["faithful"] else 0, "uint32"),
        ] + ([] if not self.product else [
            StateField("accel_lp", 3, "low-passed specific force in NED, m/s^2 (level at rest until the "
                       "first accelerometer sample: the correction before it has zero weights)", [0.0, 0.0, -use(G0)]),
            *([StateField("lp_time", 1, "time accel_lp has averaged, s (its warm start; 0 at the first "
                          "sample, stops at accel_tau)", 0.0)] if warm(p) else []),
            StateField("accel_age", 1, "time since the last accelerometer sample, s", 0.0),
            StateField("mag_age", 1, "time since the last magnetometer sample, s", 0.0),
            StateField("rest_gyro_lp", 3, "rest detection: low-passed gyro, rad/s", 0.0),
            StateField("rest_time", 1, "rest detection: steady time so far, s", 0.0),
            *([StateField("rest_q", 4, "rest detection: the predicted attitude at the last accelerometer step",
                          [1.0, 0.0, 0.0, 0.0]),
               StateField("rest_rate_lp", 3, "rest detection: the estimate's low-passed rotation rate, rad/s", 0.0)]
              if p["rest_turn"] == "estimate" else []),
            StateField("mag_ref", 2, "field check reference: |m| and sin(dip) (|m| = 0: not learned)", 0.0),
            StateField("mag_dist_time", 1, "field check: time the field has been rejected, s", 0.0),
            StateField("mag_learn_time", 1, "field check: time since the first magnetometer sample (capped), s", 0.0),
            *self.gyro_recovery_state(),
        ] + ([
            StateField("v_lp", 3, "GPS velocity through the accelerometer's NED low-pass (gps_lowpass), m/s", 0.0),
            StateField("v_ins", 3, "GPS velocity, carried between samples by R f + g (gps_lowpass), m/s", 0.0),
            StateField("vlp_ok", 1, "1 while v_lp follows a fresh GPS velocity (gps_lowpass)", 0, "uint32"),
        ] if gps_lowpass(p) else []) + (self.hard_iron_state() if self.hard_iron() else []))

    def hard_iron(self) -> bool:
        """The hard iron is estimated (mag_bias) in the product design with the field check."""
        return self.product and bool(self.params["mag_rejection"]) and bool(self.params["mag_bias"])

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
        hist = ca.SX.sym("gps_vel_hist", 3 * gps_taps(p))
        rot = ca.SX.sym("rot", 3, 3)      # R(q), from the rotation kernel once per step
        f2 = ca.SX.sym("accel_norm2")     # |f|², from the step's input check

        # PI feedback and integration (eqs. 13, 14, 9, 7).
        q_err = quat.qmul(quat.qconj(q), q_ref)
        q_err = ca.if_else(q_err[0] < 0, -q_err, q_err)
        beta = gyro - bias + p["kp"] * q_err[1:]
        bias_new = bias - p["ki"] * q_err[1:] * dt

        # Lagged GPS differentiator (eq. 29).
        if p["motion_accel_model"] == "differentiator":
            c = differentiator_coeffs(p["faithful"])
            V = [hist[3 * i:3 * i + 3] for i in range(GPS_TAPS)]
            acc = sum(c[i - 1] * (V[3 + i] - V[3 - i]) for i in (1, 2, 3)) / (2 * p["gps_period"])

        kernels = self.product_kernels() if self.product else []
        # Gravity part of the specific force (section 3.2): f_b = R^T (a_n - g_n).
        # ||f| - g| > threshold, compared through |f|² (aiding.norm_within: no square root)
        excess = ca.logic_not(aiding.norm_within(f2, G0, p["motion_accel_threshold"]))
        if p["motion_accel_model"] == "differentiator":
            gravity_in = {"accel": f, "accel_norm2": f2, "rot": rot, "motion_accel": a_n}
            f_g = ca.if_else(excess, f - ca.mtimes(rot.T, a_n), f)
        elif p["motion_accel_model"] == "gps_lowpass":
            gravity_in = None     # removed in the NED low-pass (product), or not at all
        else:
            # The centripetal acceleration a_c = R(q)(w - b) x v_n of the latest GPS velocity,
            # computed inside the excess branch only (skipped while |f| is close to g), in body
            # axes: R^T a_c = (w - b) x v_b with v_b = R^T v_n (a rotation keeps cross products).
            v = hist[-3:]
            v_b = ca.mtimes(rot.T, v)
            a_c = ca.cross(gyro - bias, v_b)
            if self.product and p["centripetal_align"] < 1:
                # the velocity turns with the body only if the body flies along it (fixed-wing):
                # weight 1 when v is along body x, ramping to 0 at cos(angle) = centripetal_align
                c0 = p["centripetal_align"]
                along = v_b[0] * ca.sqrt(1 / ca.fmax(ca.sumsqr(v), use(ALONG_V2_MIN)))
                a_c = ca.fmin(ca.fmax((along - c0) / (1 - c0), 0.0), 1.0) * a_c
            gravity_in = {"accel": f, "accel_norm2": f2, "rot": rot, "gyro": gyro, "gyro_bias": bias,
                          "gps_vel_hist": hist}
            f_g = ca.if_else(excess, f - a_c, f)
        paper = [] if self.product else [
            KernelSpec("reference", function("reference", {"accel": f, "mag": m},
                                             {"q_ref": attitude.fqa(f, m, p["declination"])}),
                       "factored quaternion algorithm (FQA): attitude from accelerometer and magnetometer"),
            KernelSpec("reference_tilt", function("reference_tilt", {"accel": f, "q": q},
                                                  {"q_ref": attitude.tilt_with_yaw(f, quat.euler(q)[2])}),
                       "FQA tilt with the estimate's yaw, for steps without a magnetometer sample"),
            KernelSpec("update", function("update", {"q": q, "gyro_bias": bias, "gyro": gyro, "q_ref": q_ref, "dt": dt},
                                          {"q_new": quat.integrate(q, beta, dt), "gyro_bias_new": bias_new}),
                       "PI feedback on the error quaternion q^-1 (x) q_ref and integration (eqs. 13, 14, 9)"),
        ]
        return kernels + [
            KernelSpec("rotation", function("rotation", {"q": q}, {"rot": quat.rotmat(q)}),
                       "R(q), read by the kernels of a step that rotate with the estimate (computed once)"),
        ] + ([] if gravity_in is None else [
            KernelSpec("gravity_part", function("gravity_part", gravity_in, {"accel_gravity": f_g}),
                       "accelerometer minus the GPS motion acceleration when ||f| - g| exceeds the threshold" + (
                           "" if p["motion_accel_model"] == "differentiator" else
                           " (centripetal: (w - b) x R(q)^T v_gps in body axes, computed only then)")),
        ]) + paper + ([] if self.product else [
            KernelSpec("propagate", function("propagate", {"q": q, "gyro_bias": bias, "gyro": gyro, "dt": dt},
                                             {"q_new": quat.integrate_scaled(q, gyro - bias, dt)}),
                       "gyro-only integration with the bias removed (no aiding this step)"),
        ]) + ([KernelSpec("gps_accel", function("gps_accel", {"gps_vel_hist": hist}, {"motion_accel": acc}),
                         "lagged differentiator of GPS velocity (eq. 29): NED acceleration 3 samples back")]
             if p["motion_accel_model"] == "differentiator" else [])

    def product_kernels(self):
        """Kernels of the product conditioning (faithful = false); see the module docstring."""
        p = self.params
        q = ca.SX.sym("q", 4)
        bias = ca.SX.sym("gyro_bias", 3)
        gyro = ca.SX.sym("gyro", 3)
        dt = ca.SX.sym("dt")
        f = ca.SX.sym("accel", 3)
        m = ca.SX.sym("mag", 3)
        a_lp = ca.SX.sym("accel_lp", 3)
        span = ca.SX.sym("span")
        span_a = ca.SX.sym("span_accel")
        span_m = ca.SX.sym("span_mag")
        use_m = ca.SX.sym("use_mag")
        g_lp = ca.SX.sym("rest_gyro_lp", 3)
        t_rest = ca.SX.sym("rest_time")
        at_rest = ca.SX.sym("at_rest")
        use_a = ca.SX.sym("use_accel")
        recover = ca.SX.sym("recover")    # recovering from a clipped gyro sample
        m_ref = ca.SX.sym("mag_ref", 2)
        t_dist = ca.SX.sym("mag_dist_time")
        t_learn = ca.SX.sym("mag_learn_time")
        decl = p["declination"]
        rot = ca.SX.sym("rot", 3, 3)      # R(q), from the rotation kernel once per step

        m_n = ca.SX.sym("mag_ned", 3)     # R(q) m, from the mag_ned kernel once per step
        f2 = ca.SX.sym("accel_norm2")     # |f|² and |m|², from the step's input checks
        m2 = ca.SX.sym("mag_norm2")

        # first attitude: the tilt taking the measured down (-f) to NED down from the identity
        # (then heading_init with a magnetometer sample); R(q0) f = [0, 0, -|f|]
        q0 = aiding.tilt_correction(-f)
        # the tilt correction from the NED low-pass (measured down -a, any length), then the
        # heading of the field R(T) R(q) m = R(T) m_n (only its horizontal part)
        # (their vector parts from aiding.tilt_heading_vec, |a| from the tilt_norm kernel, shared
        # with the field check; the heading from R(T') m_n with T' unnormalised)
        a_n = ca.SX.sym("accel_lp_norm")  # |a|, from the tilt_norm kernel once per step
        t_x, t_y, h_z = aiding.tilt_heading_vec(-a_lp, a_n, m_n, decl)
        # e dt, the error integrated over the step (no division by dt: a tiny dt must not blow up),
        # carried as ½ kp e dt: the gain and the exponential's ½ multiply the two weights once
        # (recovering from a clipped gyro sample the gain is kp_recovery and the bias integral holds,
        # so the bias below only ever sees the nominal gain)
        gps_on = ca.SX.sym("gps_comp") if gps_lowpass(p) else None   # the GPS linear acceleration removed
        kp_now = 0.5 * p["kp"] if gps_on is None else ca.if_else(gps_on, 0.5 * p["kp_gps"], 0.5 * p["kp"])
        kh = ca.if_else(recover, 0.5 * p["kp_recovery"], kp_now)
        e_half = ca.mtimes(rot.T, ca.vertcat((kh * span_a) * t_x, (kh * span_a) * t_y, (kh * span_m) * h_z))
        # the gyro's ½ (ω - b) dt was applied by the prediction (predict kernel), before R(q) was formed
        half_rotation = e_half                                  # ½ kp e dt
        trusted = ca.logic_and(ca.logic_and(use_a, ca.logic_not(recover)),
                               aiding.norm_within(f2, G0, p["bias_accel_gate"]))
        ki_kh = (p["ki"] / (0.5 * p["kp"]) if gps_on is None
                 else ca.if_else(gps_on, p["ki"] / (0.5 * p["kp_gps"]), p["ki"] / (0.5 * p["kp"])))
        bias_pi = ca.if_else(trusted, bias - ki_kh * e_half, bias)   # b - ki e dt
        if p["rest_time"] > 0:
            bias_new = ca.if_else(at_rest, aiding.lowpass(bias, g_lp, span_a, p["rest_bias_tau"]), bias_pi)
        else:
            bias_new = bias_pi
        ks = [
            self.gyro_recovery_kernel(),
            KernelSpec("tilt_norm", function("tilt_norm", {"accel_lp": a_lp}, {"accel_lp_norm": ca.sqrt(ca.sumsqr(a_lp))}),
                       "|a| of the tilt reference, read by the field check and the tilt correction"),
            # q (x) exp(1/2 (w - b) dt) with the exponential's own series (cos and sin/x): a unit
            # quaternion times a unit one, not normalised here (a square root and a division): the
            # correction normalises its product at the end of every step
            KernelSpec("predict", function("predict", {"q": q, "gyro_bias": bias, "gyro": gyro, "dt": dt},
                                           {"q_new": quat.qmul(q, quat.qexp(0.5 * dt * (gyro - bias)))}),
                       "prediction: the gyro integrated with the bias removed, before the step's sensors are "
                       "compared with the attitude (so they meet the attitude of their own step); unit to "
                       "rounding, normalised by the correction"),
            KernelSpec("mag_ned", function("mag_ned", {"rot": rot, "mag": m}, {"mag_ned": ca.mtimes(rot, m)}),
                       "the magnetometer sample in NED, R(q) m, read by the field check and the heading correction"),
            KernelSpec("init_attitude", function("init_attitude", {"accel": f},
                                                 {"q": q0, "accel_lp": ca.vertcat(0, 0, -ca.sqrt(ca.sumsqr(f)))}),
                       "first attitude: the shortest rotation taking the accelerometer's down to NED down "
                       "(heading_init then sets the heading); the low-pass starts at R(q) f = [0, 0, -|f|]"),
            KernelSpec("heading_init", function("heading_init", {"q": q, "mag": m},
                                                {"q_new": quat.qmul(aiding.heading_correction(q, m, decl), q)}),
                       "first magnetometer sample (with the first attitude or after it): heading set, tilt kept"),
            self.accel_lowpass_kernel(),
            KernelSpec("correct", function("correct", {"q": q, "rot": rot, "gyro_bias": bias,
                                                       "accel_lp": a_lp, "accel_lp_norm": a_n, "mag_ned": m_n,
                                                       "span_accel": span_a,
                                                       "span_mag": span_m, "use_accel": use_a, "accel_norm2": f2,
                                                       "recover": recover,
                                                       **({"gps_comp": gps_on} if gps_on is not None else {}),
                                                       **({"at_rest": at_rest, "rest_gyro_lp": g_lp}
                                                          if p["rest_time"] > 0 else {})},
                                           {"q_new": quat.qnormalize_near_unit(quat.qmul(q, quat.qexp(half_rotation, small_arg=True))),
                                            "gyro_bias_new": bias_new}),
                       "tilt (low-passed accelerometer) and heading (magnetometer) corrections as PI feedback "
                       "on the predicted attitude, bias integral gated, bias at rest from the low-passed gyro",
                       flags=("use_accel", "recover") + (("gps_comp",) if gps_on is not None else ())
                       + (("at_rest",) if p["rest_time"] > 0 else ())),
        ]
        if p["rest_time"] > 0:
            ins = {"gyro": gyro, "accel_norm2": f2, "rest_gyro_lp": g_lp, "rest_time": t_rest, "span": span}
            rate_out, w2 = {}, None
            if p["rest_turn"] == "estimate":
                # the turn test on the estimate's rotation rate since the last accelerometer step
                # (predicted to predicted: the corrections in between included), low-passed: a gyro
                # bias the aiding sensors hold the attitude against is not a turn, a steady turn is
                q_prev = ca.SX.sym("rest_q", 4)
                w_lp = ca.SX.sym("rest_rate_lp", 3)
                d = quat.qmul(quat.qconj(q_prev), q)
                d = ca.if_else(d[0] < 0, -d, d)
                w2 = aiding.lowpass_of_rate(w_lp, 2 * d[1:], span, p["rest_tau"])
                ins |= {"q": q, "rest_q": q_prev, "rest_rate_lp": w_lp}
                rate_out = {"rest_rate_lp_new": w2}
            g2, t2, r2 = aiding.rest_detector(gyro, f2, g_lp, t_rest, span, tau=p["rest_tau"],
                                              gyro_tol=p["rest_gyro_tol"], accel_tol=p["rest_accel_tol"],
                                              gravity=G0, gyro_max=p["rest_gyro_tol"], min_time=p["rest_time"],
                                              turn_rate=w2)
            ks.append(KernelSpec("rest", function("rest", ins, {"rest_gyro_lp_new": g2, **rate_out,
                                                                "rest_time_new": t2, "at_rest": r2}),
                                 "rest detection: gyro steady" + (", the low-passed gyro or the estimate not turning,"
                                                                  if w2 is not None else " and") +
                                 " |f| near g for rest_time", flags=("at_rest",)))
        if p["mag_rejection"]:
            mn = ca.sqrt(m2)
            # sin(dip) = (R^T down) . m / |m| = down . R m / |m|, down = -a/|a|
            sin_dip = -ca.dot(a_lp, m_n) / (a_n * mn)
            hold = ca.SX.sym("hold") if self.hard_iron() else None   # the hard-iron candidate is the better model
            acc, n2, d2, t2, l2 = aiding.field_check(
                mn, sin_dip, m_ref[0], m_ref[1], t_dist, span, norm_tol=p["mag_norm_tol"],
                dip_tol=p["mag_dip_tol"], ref_tau=p["mag_ref_tau"], new_time=p["mag_new_time"],
                learn_time=t_learn, warmup=p["mag_warmup"], hold=hold)
            ks.append(KernelSpec("mag_check", function("mag_check", {"accel_lp": a_lp, "accel_lp_norm": a_n, "mag_norm2": m2, "mag_ned": m_n, "mag_ref": m_ref,
                                                                     "mag_dist_time": t_dist, "mag_learn_time": t_learn,
                                                                     "span": span, **({"hold": hold} if hold is not None else {})},
                                                       {"accept": acc, "mag_ref_new": ca.vertcat(n2, d2),
                                                        "mag_dist_time_new": t2, "mag_learn_time_new": l2}),
                                 "field check: |m| and sin(dip) against the learned reference"
                                 + (" (a lasting change is not taken while the hard-iron candidate is the better model)"
                                    if hold is not None else ""), flags=("accept",) + (("hold",) if hold is not None else ())))
        if self.hard_iron():
            # a call of its own: it runs only while the sensor turns, and inlined its 459 operations
            # cost the every-step path registers (fixedwing_gps: -Os 1 688 -> 1 561 est. cycles per
            # step, -O2 1 268 -> 1 264; the worst-case stack 360 -> 480 B, frames of a call chain add)
            ks.append(self.hard_iron_kernel(refine=p["mag_norm_tol"], dip_angle=False, noinline=True))
        return ks

    def accel_lowpass_kernel(self):
        p = self.params
        rot = ca.SX.sym("rot", 3, 3)
        f = ca.SX.sym("accel", 3)
        a_lp = ca.SX.sym("accel_lp", 3)
        span = ca.SX.sym("span")
        recover = ca.SX.sym("recover")
        f_n = ca.mtimes(rot, f)
        doc = ("low-pass of the specific force in NED, R(q) f (time constant accel_tau; recovering from "
               "a clipped gyro sample: the sample itself)")
        ins = {"rot": rot, "accel": f, "accel_lp": a_lp, "span": span, "recover": recover}
        outs = {}
        if warm(p):
            # VQF's warm start: the running mean of the samples until it has averaged accel_tau
            # (lp_time 0 at the first sample), held while recovering from a gyro clip
            lp_time = ca.SX.sym("lp_time")
            k_warm, lp_next = aiding.warm_lowpass_gain(lp_time, p["accel_tau"], span)
            if gps_lowpass(p):
                # its gain and the GPS velocity's, s/(min(t, tau) + s) and s/(tau + s), from one
                # division: r = s/(d_w d_g), k = d_g r and d_w r (the same float once warm)
                d_w, d_g = ca.fmin(lp_time, use(p["accel_tau"])) + span, use(p["accel_tau"]) + span
                r = span / (d_w * d_g)
                k_warm, k_gps = d_g * r, d_w * r
            alpha_a = ca.if_else(recover, 1, k_warm)
            ins["lp_time"] = lp_time
            outs["lp_time_new"] = ca.if_else(recover, lp_time, lp_next)
            doc += "; accel_lp_warm: the running mean of its samples until it has averaged accel_tau"
        if not gps_lowpass(p):
            if warm(p):
                a_new = a_lp + alpha_a * (f_n - a_lp)
            else:
                a_new = ca.if_else(recover, f_n, aiding.lowpass(a_lp, f_n, span, p["accel_tau"]))
            return KernelSpec("accel_lowpass", function("accel_lowpass", ins, {"accel_lp_new": a_new, **outs}),
                              doc, flags=("recover",))
        vel = ca.SX.sym("gps_vel", 3)
        v_lp = ca.SX.sym("v_lp", 3)
        v_ins = ca.SX.sym("v_ins", 3)
        new_gps = ca.SX.sym("new_gps")
        m_comp = ca.SX.sym("m_comp")
        alpha = ca.if_else(recover, 1, k_gps if warm(p) else span / (use(p["accel_tau"]) + span))
        a_new = a_lp + (alpha_a if warm(p) else alpha) * (f_n - a_lp)
        vi_new, v_new, up = aiding.gps_lowpass(a_new, f_n, vel, v_lp, v_ins, alpha, span, p["accel_tau"],
                                               new_gps, m_comp, G0)
        return KernelSpec("accel_lowpass", function(
            "accel_lowpass", {**ins, "gps_vel": vel, "new_gps": new_gps, "m_comp": m_comp, "v_lp": v_lp,
                              "v_ins": v_ins},
            {"accel_lp_new": a_new, **outs, "v_lp_new": v_new, "v_ins_new": vi_new, "up": up}),
            doc + "; the GPS velocity through the same low-pass (gain span/(accel_tau + span)), its "
            "low-passed derivative removed (up)",
            flags=("recover", "new_gps", "m_comp"))

    def stability_warnings(self):
        """The product loop's two limits (docs/qcf.md, 'Stable gains'), each inside the declared
        ranges. (1) A correction turns the estimate by kp s / 2 of the error per sample (s: the
        time the sample stands for, at most span_max): beyond 2 it overshoots and grows, so
        kp span_max < 4; warned from 3. (2) With the accelerometer low-pass (time constant tau)
        in the loop, the error's characteristic polynomial is tau s^3 + s^2 + kp s + ki, stable
        (Routh-Hurwitz) only if ki < kp / tau. Measured on fixedwing_gps seed 0 (12.5 Hz):
        kp = 40 follows, ki = 0.25 follows, ki = 0.6 diverges (kp = 0.3, tau = 1)."""
        p = self.params
        if not self.product:
            return []
        out = []
        if p["kp"] * p["span_max"] >= 3.0:
            out.append(f"kp x span_max = {p['kp'] * p['span_max']:.3g} >= 3: a correction at samples span_max "
                       f"apart overshoots the error (diverges from 4); lower kp or span_max")
        if gps_lowpass(p) and p["kp_gps"] * p["span_max"] >= 3.0:
            out.append(f"kp_gps x span_max = {p['kp_gps'] * p['span_max']:.3g} >= 3: a correction at samples span_max "
                       f"apart overshoots the error (diverges from 4); lower kp_gps or span_max")
        if gps_lowpass(p) and p["ki"] >= p["kp_gps"] / p["accel_tau"]:
            out.append(f"ki = {p['ki']:g} >= kp_gps / accel_tau = {p['kp_gps'] / p['accel_tau']:.3g}: the bias loop "
                       f"through the accelerometer low-pass is unstable with the GPS gain")
        if p["accel_tau"] > 0 and p["ki"] >= p["kp"] / p["accel_tau"]:
            out.append(f"ki = {p['ki']:g} >= kp / accel_tau = {p['kp'] / p['accel_tau']:.3g}: the bias loop through "
                       f"the accelerometer low-pass is unstable (tau s^3 + s^2 + kp s + ki needs ki < kp / tau)")
        return out

    def template_context(self):
        p = self.params
        return {"motion_model": p["motion_accel_model"], "product": self.product, "gps_taps": gps_taps(p),
                "rest": self.product and p["rest_time"] > 0,
                "rest_turn_estimate": self.product and p["rest_time"] > 0 and p["rest_turn"] == "estimate",
                "mag_rejection": self.product and p["mag_rejection"],
                "hard_iron": self.hard_iron(), "gps_age_max": GPS_AGE_MAX, "gps_lowpass": gps_lowpass(p),
                "warm": self.product and warm(p),
                "gyro_quiet": self.gyro_recovery_quiet()}

    def step_paths(self):
        if self.product:
            comp = ["rotation"] + ([] if self.params["motion_accel_model"] == "gps_lowpass" else ["gravity_part"])
            extra = (["rest"] if self.params["rest_time"] > 0 else []) + (["mag_check"] if self.params["mag_rejection"] else [])
            return {
                "full (accel+mag+GPS comp.)": ["predict", "gyro_recovery"] + comp + ["accel_lowpass", "tilt_norm",
                                                                                      "mag_ned"] + extra + ["correct"],
                "accel+mag": ["predict", "gyro_recovery", "rotation", "accel_lowpass", "tilt_norm", "mag_ned"] + extra
                + ["correct"],
                "gyro only": ["predict", "gyro_recovery", "rotation", "tilt_norm", "correct"],
                **({"GPS sample (extra)": ["gps_accel"]} if self.params["motion_accel_model"] == "differentiator" else {}),
            }
        comp = [] if self.params["motion_accel_model"] == "gps_lowpass" else ["rotation", "gravity_part"]
        return {
            "full (accel+mag+GPS comp.)": comp + ["reference", "update"],
            "accel+mag": ["reference", "update"],
            "gyro only": ["propagate"],
            **({"GPS sample (extra)": ["gps_accel"]} if self.params["motion_accel_model"] == "differentiator" else {}),
        }
