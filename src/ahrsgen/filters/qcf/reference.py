"""QCF reference in plain NumPy, written from the paper's equations (not from the model).

Same step logic and status bits as the generated C; see model.py's docstring for the
equations. FQA follows Yun, Bachmann, McGhee (2008) in the product's FRD/NED convention.
"""
from __future__ import annotations

import numpy as np

from ahrsgen import npquat as nq
from ahrsgen.codegen import input_checks
from ahrsgen.constants import G0
from ahrsgen.reference_aiding import GyroClip, HardIron, warm_lowpass_gain

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


def tilt_correction(d):
    """Shortest rotation (NED) taking the unit vector d to e_z = [0, 0, 1]: axis d x e_z,
    angle acos(d_z); upside down (d_z <= -1 + 1e-6) the half-turn about x."""
    d = np.asarray(d, float)
    if 1 + d[2] < 1e-6:
        return np.array([0.0, 1.0, 0.0, 0.0])
    axis = np.cross(d, [0.0, 0.0, 1.0])
    s = np.linalg.norm(axis)
    ang = np.arctan2(s, d[2])
    if s == 0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.concatenate([[np.cos(ang / 2)], np.sin(ang / 2) * axis / s])


def heading_correction(q, m, declination=0.0):
    """Rotation about NED z by -(heading of R(q) m's horizontal part - declination)."""
    m_n = nq.rotmat(q) @ np.asarray(m, float)
    if m_n[0] ** 2 + m_n[1] ** 2 < 1e-30:
        return np.array([1.0, 0.0, 0.0, 0.0])
    err = np.arctan2(m_n[1], m_n[0]) - declination
    err = (err + np.pi) % (2 * np.pi) - np.pi
    return np.array([np.cos(err / 2), 0.0, 0.0, -np.sin(err / 2)])


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
        self.initialised = 1 if self.p["faithful"] else 0
        self.product = not self.p["faithful"] and self.p["conditioning"]
        self.accel_lp = np.array([0.0, 0.0, -G0])   # read by nothing before the first accelerometer sample
        self.accel_age = self.mag_age = 0.0
        self.lp_time = 0.0            # time accel_lp has averaged (accel_lp_warm), s, at most accel_tau
        # gps_lowpass: the GPS velocity through the accelerometer's low-pass
        self.gps_lp = (self.product and self.p["motion_accel_model"] == "gps_lowpass" and self.p["accel_tau"] > 0)
        self.v_lp = np.zeros(3)
        self.v_ins = np.zeros(3)
        self.vlp_ok = False
        self.rest_gyro_lp = np.zeros(3)
        self.rest_time = 0.0
        self.rest_q = np.array([1.0, 0.0, 0.0, 0.0])   # rest_turn = estimate: predicted q, last accel step
        self.rest_rate_lp = np.zeros(3)
        self.mag_ref = np.zeros(2)         # |m|, sin(dip); |m| = 0: not learned
        self.mag_dist_time = 0.0
        self.mag_learn_time = 0.0          # time since the first magnetometer sample (capped at warmup)
        self.clip = GyroClip(float(self.p["gyro_full_scale"]), float(self.p["gyro_plateau_rate"]),
                             float(self.p["clip_recovery_time"]))
        # the hard iron (docs/qcf.md, "Hard iron"): with the field check, in the product design
        self.hard_iron_on = self.product and bool(self.p["mag_rejection"]) and bool(self.p["mag_bias"])
        self.mag_bias = np.zeros(3)
        if self.hard_iron_on:
            self.hard_iron = HardIron(rw=self.p["mag_bias_rw"], noise=self.p["mag_bias_noise"],
                                      bias_max=self.p["mag_bias_max"], settle=self.p["mag_bias_settle"],
                                      th=self.p["mag_bias_th"], jump=self.p["mag_bias_jump"],
                                      refine=self.p["mag_norm_tol"])

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

        f = np.asarray(accel, float)
        if self.product:
            # predict, then correct: the gyro first moves the attitude to this step, so the
            # sensors below meet the attitude of their own step (issue 27; the paper's order,
            # kept when faithful or conditioning = false, leads the truth by omega dt)
            self.q = integrate(self.q, gyro - self.bias, dt)
            self._start(f, mag, use_accel, use_mag, gyro, p)
        if use_accel:
            model = p["motion_accel_model"]
            need = 7 if model == "differentiator" else 1
            if model != "gps_lowpass" and p["gps_compensation"] and len(self.hist) >= need and self.gps_age <= p["gps_timeout"]:
                a_n = self.motion_accel
                if model != "differentiator":
                    # centripetal acceleration of the GPS velocity turning with the body
                    v = self.hist[-1]
                    a_n = np.cross(nq.rotmat(self.q) @ (gyro - self.bias), v)
                    c0 = p["centripetal_align"]
                    if self.product and c0 < 1:
                        # only a velocity along the body's x axis turns with the body
                        along = (nq.rotmat(self.q)[:, 0] @ v) / np.sqrt(max(v @ v, 1e-6))
                        a_n = np.clip((along - c0) / (1 - c0), 0.0, 1.0) * a_n
                if abs(np.linalg.norm(f) - G0) > p["motion_accel_threshold"]:
                    f = f - nq.rotmat(self.q).T @ a_n
        if self.product:
            return self._product_step(status, gyro, np.asarray(accel, float), f, mag, use_accel, use_mag, use_gps, dt)
        if use_accel:
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

    # ---------------------------------------------------------------- product conditioning
    def _start(self, f, mag, use_accel, use_mag, gyro, p):
        """Initialisation, before anything else of the step reads the attitude. The first
        accelerometer sample: the shortest rotation taking its (raw) down to NED down, then the
        field's heading if the step has a magnetometer sample; else the first magnetometer
        sample after it: the heading, tilt kept."""
        if self.initialised == 0 and use_accel:
            self.q = tilt_correction(-f / np.linalg.norm(f))
            if use_mag:
                self.q = nq.qmul(heading_correction(self.q, mag, p["declination"]), self.q)
            self.accel_lp = nq.rotmat(self.q) @ f
            self.initialised = 2 if use_mag else 1
            self.accel_age = self.mag_age = 0.0
            self.lp_time = 0.0
            self.rest_gyro_lp = gyro.copy()
            self.rest_q = self.q.copy()
        elif self.initialised == 1 and use_mag:
            self.q = nq.qmul(heading_correction(self.q, mag, p["declination"]), self.q)
            self.rest_q = self.q.copy()              # setting the heading is no turn
            self.initialised = 2
            self.mag_age = 0.0

    def _product_step(self, status, gyro, f_raw, f, mag, use_accel, use_mag, use_gps, dt):
        """See model.py's docstring: NED low-pass, tilt/heading corrections, gate, rest, field check."""
        p = self.p
        from ahrsgen.filters.qcf.model import EXTRA_STATUS
        bit = {entry[0]: 1 << (16 + i) for i, entry in enumerate(EXTRA_STATUS)}
        if self.initialised == 0:            # no accelerometer sample yet (_start sets it): predicted only
            return status
        # gyro over-range: a clipped sample was integrated as it is; for clip_recovery_time after
        # the last one the correction takes the sensors as they come with kp_recovery (half a
        # step of margin on the timer: float and double decide alike)
        _, recovering = self.clip.step(gyro, dt)
        if recovering:
            status |= bit["GYRO_RECOVERY"]
        self.accel_age = min(self.accel_age + dt, p["span_max"])
        self.mag_age = min(self.mag_age + dt, p["span_max"])
        at_rest = False
        # gps_lowpass: compensate while the last GPS velocity is at most gps_timeout old
        m_comp = self.gps_lp and p["gps_compensation"] and len(self.hist) >= 1 and self.gps_age <= p["gps_timeout"]
        if not m_comp:
            self.vlp_ok = False
        up = self.accel_lp        # the tilt reference (without an accelerometer sample: the last low-pass)
        if use_accel:
            s = self.accel_age
            f_n = nq.rotmat(self.q) @ f
            k = s / (p["accel_tau"] + s) if p["accel_tau"] > 0 and not recovering else 1.0
            k_a = k                   # the gain of accel_lp (k: the GPS velocity's)
            if p["accel_lp_warm"] and p["accel_tau"] > 0 and not recovering:
                # warm start (VQF's): the running mean until it has averaged accel_tau;
                # recovering from a gyro clip takes the sample and holds the time
                k_a, self.lp_time = warm_lowpass_gain(self.lp_time, p["accel_tau"], s)
            self.accel_lp = self.accel_lp + k_a * (f_n - self.accel_lp)
            up = self.accel_lp
            if self.gps_lp:
                # velocity: the GPS sample of this step, else carried by the kinematic acceleration
                # a = R f + g; low-passed with the same gain k; its low-passed derivative
                # (the low-pass of (v_k - v_{k-1})/s) is (v - v_lp)/tau, removed from the tilt reference
                if m_comp and not self.vlp_ok:
                    self.v_lp = self.hist[-1].copy()
                    self.v_ins = self.hist[-1].copy()
                    self.vlp_ok = True
                self.v_ins = self.hist[-1].copy() if use_gps else self.v_ins + (f_n + np.array([0.0, 0.0, G0])) * s
                if m_comp:
                    self.v_lp = self.v_lp + k * (self.v_ins - self.v_lp)
                    up = self.accel_lp - (self.v_ins - self.v_lp) / p["accel_tau"]
            if p["rest_time"] > 0:
                k = s / (p["rest_tau"] + s)
                self.rest_gyro_lp = self.rest_gyro_lp + k * (gyro - self.rest_gyro_lp)
                tol = p["rest_gyro_tol"]
                no_turn = np.linalg.norm(self.rest_gyro_lp) < tol
                if p["rest_turn"] == "estimate":
                    # the estimate's rotation since the last accelerometer step (predicted to
                    # predicted: the corrections between included) as a rate, low-passed
                    d = nq.qmul(nq.qconj(self.rest_q), self.q)
                    d = -d if d[0] < 0 else d
                    # the low-pass of the rate 2 d / s, k (2 d / s - lp), written without the
                    # quotient by s (a denormal span would make it infinite)
                    self.rest_rate_lp = self.rest_rate_lp + (2 * d[1:] - s * self.rest_rate_lp) / (p["rest_tau"] + s)
                    self.rest_q = self.q.copy()
                    # a gyro bias the sensors hold the attitude against is no turn either
                    no_turn = no_turn or np.linalg.norm(self.rest_rate_lp) < tol
                steady = (np.linalg.norm(gyro - self.rest_gyro_lp) < tol
                          and abs(np.linalg.norm(f_raw) - G0) < p["rest_accel_tol"]
                          and no_turn)
                self.rest_time = min(self.rest_time + s, 1e3) if steady else 0.0
                at_rest = self.rest_time + 0.5 * s >= p["rest_time"]    # (half a step of margin)
                if at_rest:
                    status |= bit["AT_REST"]
        down = -up / np.linalg.norm(up)
        heading_ok = use_mag
        mag_raw = mag
        if use_mag and self.hard_iron_on:
            mag = np.asarray(mag, float) - self.mag_bias       # the hard iron removed
        suspect = self.hard_iron_on and self.hard_iron.suspect
        was_accepted = self.mag_dist_time <= 0.0
        if use_mag and p["mag_rejection"]:
            m = np.asarray(mag, float)
            norm = np.linalg.norm(m)
            sin_dip = (nq.rotmat(self.q).T @ down) @ m / norm
            ref_n, ref_d = self.mag_ref
            s = self.mag_age
            accepted = True
            if ref_n <= 0 or (p["mag_warmup"] > 0 and self.mag_learn_time < p["mag_warmup"]):
                # warm-up: accept, the reference is the mean of the samples so far
                if ref_n <= 0:
                    self.mag_learn_time = 0.0
                n_seen = self.mag_learn_time / s + 1          # samples so far, weighted by their span
                self.mag_ref = self.mag_ref + (np.array([norm, sin_dip]) - self.mag_ref) / n_seen
                self.mag_dist_time = 0.0
                self.mag_learn_time = min(self.mag_learn_time + s, p["mag_warmup"])
            elif abs(norm / ref_n - 1) < p["mag_norm_tol"] and abs(sin_dip - ref_d) < p["mag_dip_tol"]:
                k = s / (p["mag_ref_tau"] + s)
                self.mag_ref = self.mag_ref + k * (np.array([norm, sin_dip]) - self.mag_ref)
                self.mag_dist_time = 0.0
            else:
                accepted = False
                if not recovering:           # the dip was judged with the attitude that is wrong
                    heading_ok = False
                    status |= bit["MAG_DISTURBED"]
                self.mag_dist_time += s
                # a lasting change: new reference (not while the hard-iron candidate is the better model)
                if self.mag_dist_time > p["mag_new_time"] and not suspect:
                    self.mag_ref = np.array([norm, sin_dip])
                    self.mag_dist_time = 0.0
            if (self.hard_iron_on and self.mag_ref[0] > 0 and self.mag_learn_time >= p["mag_warmup"]
                    and not recovering):
                if not accepted and was_accepted and not suspect:
                    self.hard_iron.reopen()          # a new disturbance: the candidate starts afresh
                w = gyro - self.bias
                if w @ w >= p["mag_bias_min_rate"] ** 2:
                    new = self.hard_iron.step(nq.rotmat(self.q), np.asarray(mag_raw, float), self.mag_bias,
                                              self.mag_ref[0], self.mag_ref[1], self.mag_age)
                    if new is not None:              # the candidate becomes the hard iron and the reference
                        self.mag_bias = new[0]
                        self.mag_ref = np.array([new[1], new[2]])
                        self.mag_dist_time = 0.0
                        status |= bit["HARD_IRON_SWITCHED"]
                        heading_ok = False           # the field check was made with the old hard iron
                if heading_ok and self.hard_iron.suspect:
                    heading_ok = False
                    status |= bit["MAG_DISTURBED"]
        if use_accel or heading_ok:
            T = tilt_correction(down)
            e_n = (self.accel_age if use_accel else 0.0) * T[1:]
            if heading_ok:
                H = heading_correction(nq.qmul(T, self.q), mag, p["declination"])
                e_n = e_n + self.mag_age * H[1:]
            e_dt = nq.rotmat(self.q).T @ e_n                 # error integrated over the step
            kp = p["kp_recovery"] if recovering else (p["kp_gps"] if m_comp else p["kp"])
            theta = kp * e_dt                                  # the correction (the gyro's part was predicted)
            if at_rest:
                s = self.accel_age
                self.bias = self.bias + s / (p["rest_bias_tau"] + s) * (self.rest_gyro_lp - self.bias)
            elif use_accel and not recovering and abs(np.linalg.norm(f_raw) - G0) < p["bias_accel_gate"]:
                self.bias = self.bias - p["ki"] * e_dt
            self.q = integrate(self.q, theta, 1.0)
        if use_accel:
            self.accel_age = 0.0
        if use_mag:
            self.mag_age = 0.0
        return status
