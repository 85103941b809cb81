"""NumPy mirrors, for the filters' references, of aiding steps that every filter's reference
runs alike. Written from the equations in the docstrings of symbolic/aiding.py, not from the
CasADi code, so that validate compares two implementations."""
from __future__ import annotations

import numpy as np

# the rule's constants, as symbolic/aiding states them (this layer cannot import it; a test
# checks they agree): equal samples in a row of one fast component, "equal" within (rad/s)
PLATEAU_SAMPLES = 4
PLATEAU_TOL = 1e-6


def warm_lowpass_gain(lp_time: float, tau: float, dt: float) -> tuple[float, float]:
    """A first-order low-pass of time constant tau with a warm start: until it has averaged tau
    of samples it is their running mean. t is the time it has averaged (0 before its first
    sample); the gain is dt / (min(t, tau) + dt) and t becomes min(t + dt, tau). Returns both."""
    return dt / (min(lp_time, tau) + dt), min(lp_time + dt, tau)


class GyroClip:
    """A gyro sample is clipped when a component is at or beyond full_scale, or when one at or
    above plateau_rate has held its value (within PLATEAU_TOL) for PLATEAU_SAMPLES samples while
    the others changed (a sample equal to the previous one in every component is a duplicate: it neither
    counts nor resets). full_scale = 0 turns both off. Each clipped sample restarts
    recovery_time of recovery; a step recovers while more than half a step of it is left."""

    def __init__(self, full_scale: float, plateau_rate: float, recovery_time: float):
        self.full_scale, self.plateau_rate, self.recovery_time = full_scale, plateau_rate, recovery_time
        self.prev = np.zeros(3)
        self.repeats = np.zeros(3)
        self.recover_time = 0.0

    def step(self, gyro, dt: float) -> tuple[bool, bool]:
        """(clipped, recovering) for this sample; updates the state."""
        gyro = np.asarray(gyro, dtype=float)
        plateau = False
        if self.plateau_rate > 0:
            same = np.abs(gyro - self.prev) < PLATEAU_TOL
            if not same.all():
                self.repeats = np.where(same & (np.abs(gyro) >= self.plateau_rate),
                                        np.minimum(self.repeats + 1, PLATEAU_SAMPLES - 1), 0.0)
            plateau = bool(np.any(self.repeats >= PLATEAU_SAMPLES - 1))
        self.prev = gyro.copy()
        clipped = self.full_scale > 0 and (plateau or bool(np.max(np.abs(gyro)) >= self.full_scale))
        if clipped:
            self.recover_time = self.recovery_time
        elif self.recover_time > 0:
            self.recover_time = max(self.recover_time - dt, 0.0)
        return clipped, self.recover_time > 0.5 * dt


# the hard iron's constants, as symbolic/aiding states them (a test checks they agree)
HARD_IRON_RES_TAU = 0.2    # s: the residuals are low-passed over this
HARD_IRON_P0 = 0.3         # initial standard deviation of the candidate, fraction of the norm
HARD_IRON_RATIO = 4.0      # the candidate must explain the field this much better (mean squares)
HARD_IRON_NORM_MIN = 1e-6  # floor of the corrected field's norm in the rows (fraction)
HARD_IRON_N_MIN = 0.1      # a candidate norm below this fraction of the reference is never taken
HARD_IRON_TIME_CAP = 1e3   # s: the turning time stops counting here


class HardIron:
    """The magnetometer's hard iron learned while the sensor turns (docs/mekf.md "Hard iron"),
    for the references of mekf, qcf and adukf.

    A candidate field model x = [β (3), n, v], in units of the reference norm B: the field
    u − β (u = m / B, m raw) has norm n and NED down component v. Two rows, the norm and the
    vertical component (neither involves the heading), linearised once at the prior x and
    applied as a batch; H by hand: [−dᵀ/|d|, −1, 0] and [−e_Dᵀ R, 0, −1], d = u − β. The
    candidate replaces the hard iron and the reference (b = B β, [n B, v/n]) when, over `settle`
    of turning, it explains the field (mean square of its residuals low-passed over
    HARD_IRON_RES_TAU below th²) HARD_IRON_RATIO times better than the present hard iron does even
    with its reference re-fitted (the present residuals less their mean), it differs from the
    present hard iron by `jump` of the field (`refine` once that is itself that large) and its
    hard iron is known to th (root of its covariance trace). The caller keeps the hard iron and
    the reference; `step` returns the new ones on a switch."""

    def __init__(self, *, rw, noise, bias_max, settle, th, jump, refine):
        self.rw, self.noise, self.bias_max = rw, noise, bias_max
        self.settle, self.th, self.jump, self.refine = settle, th, jump, refine
        self.x = np.zeros(5)
        self.P = np.eye(5) * HARD_IRON_P0 ** 2
        self.started = False
        self.rlp = np.zeros(4)         # residuals [present (2), candidate (2)], low-passed
        self.rmean = np.zeros(2)       # the present residuals' mean over settle
        self.e = np.zeros(3)           # mean squares: present, candidate, present less its mean
        self.turn_time = 0.0
        self.suspect = False           # the candidate explains the field, the present model not

    def reopen(self):
        """A new disturbance: the candidate's covariance back to its prior."""
        self.P = np.eye(5) * HARD_IRON_P0 ** 2

    def step(self, Rq, m_raw, b, ref_norm, sin_dip, dt):
        """One step while turning. Returns None, or on a switch (b, norm, sin dip) of the new model."""
        B = ref_norm
        u = np.asarray(m_raw, dtype=float) / B
        if not self.started:
            self.x = np.concatenate([b / B, [1.0, sin_dip]])
            self.P = np.eye(5) * HARD_IRON_P0 ** 2
            self.started = True
        x = self.x
        P = self.P + np.eye(5) * self.rw ** 2 * dt
        d = u - x[:3]
        nd = max(np.sqrt(d @ d), HARD_IRON_NORM_MIN)
        H = np.array([np.concatenate([-d / nd, [-1.0, 0.0]]), np.concatenate([-Rq[2], [0.0, -1.0]])])
        res = np.array([nd - x[3], Rq[2] @ d - x[4]])       # model minus measurement (0)
        S = H @ P @ H.T + np.eye(2) * self.noise ** 2
        K = P @ H.T @ np.linalg.inv(S)
        x = x - K @ res
        P = P - K @ H @ P
        P = 0.5 * (P + P.T)
        nb = np.sqrt(x[:3] @ x[:3])
        if nb > self.bias_max:
            x = np.concatenate([x[:3] * (self.bias_max / nb), x[3:]])
        self.x, self.P = x, P
        c = u - b / B
        d = u - x[:3]
        r = np.array([np.sqrt(c @ c) - 1.0, Rq[2] @ c - sin_dip, max(np.sqrt(d @ d), HARD_IRON_NORM_MIN) - x[3],
                      Rq[2] @ d - x[4]])
        self.rlp = self.rlp + dt / (HARD_IRON_RES_TAU + dt) * (r - self.rlp)
        a = dt / (self.settle + dt)
        self.rmean = self.rmean + a * (self.rlp[:2] - self.rmean)
        dr = self.rlp[:2] - self.rmean
        e = np.array([self.rlp[:2] @ self.rlp[:2], self.rlp[2:] @ self.rlp[2:], dr @ dr])
        self.e = self.e + a * (e - self.e)
        self.turn_time = min(self.turn_time + dt, HARD_IRON_TIME_CAP)
        better = self.turn_time >= self.settle and self.e[2] > HARD_IRON_RATIO * self.e[1]
        bb = b / B
        db = x[:3] - bb
        jump = self.refine if bb @ bb >= self.jump ** 2 else self.jump
        self.suspect = better and db @ db >= jump ** 2
        if not (self.suspect and self.e[1] < self.th ** 2 and np.trace(P[:3, :3]) < self.th ** 2
                and x[3] > HARD_IRON_N_MIN):
            return None
        n = x[3]
        self.x = np.concatenate([x[:3] / n, [1.0, x[4] / n]])
        self.P = P / (n * n)
        self.e[:] = self.e[1]
        self.rmean[:] = 0.0
        self.turn_time = 0.0
        self.suspect = False
        return B * x[:3], n * B, float(np.clip(x[4] / n, -1.0, 1.0))
