"""Peer filters (other people's AHRS code) run on a SensorLog, mapped to the product's conventions.

Every peer returns (N, 4) quaternions body FRD -> NED (scalar first), row k being the estimate
after step k, so they are scored exactly like the generated filters. The convention traps
(shared/PEERS.md) and how each is handled here:

- imufusion (x-io Fusion) 1.3.x: the convention is set as an *attribute* of AhrsSettings
  (`settings.convention = CONVENTION_NED`) and read back (the constructor argument is not
  stored); fed FRD gyro in °/s, accelerometer in g (specific force), magnetometer as is, dt
  per step through `set_sample_period`; returns body->NED directly. Library defaults (gain
  0.5, no rejection, no gyro-bias estimation) unless options say otherwise.
- vqf: earth frame ENU (9D: x east, y north, z up), any right-handed body; fed FRD, the
  output is rotated ENU -> NED. The sample time is fixed at construction (the median dt).
- ahrs Madgwick (earth NWU) and Mahony (earth ENU): fed in the sensor frame FLU (x forward,
  y left, z up = BROAD's own sensor axes, (x, -y, -z) of FRD), outputs rotated back to FRD ->
  NED. Both skip the whole update when the gyro sample is exactly zero; such samples (BROAD
  has them at rest) are replaced by a 1e-12 rad/s vector so the correction still runs, as in
  Madgwick's and Mahony's original C. Initial attitude from the first accelerometer and
  magnetometer samples, as BROAD's example code does.

A peer with `uses_mag = False` (vqf6d) has an arbitrary heading: scoring removes one constant
heading offset (see `broad_score`).
"""
from __future__ import annotations

import numpy as np

from ahrsgen.sim.log import G0, VALID_ACCEL, VALID_MAG, SensorLog
from ahrsgen.sim.metrics import broad_errors_deg
from ahrsgen.npquat import from_accel_mag as quat_from_accel_mag
from ahrsgen.npquat import qconj, qmul

S2 = np.sqrt(0.5)
# quaternion of the fixed rotation library-earth -> NED
Q_NWU_TO_NED = np.array([0.0, 1.0, 0.0, 0.0])      # 180° about x
Q_ENU_TO_NED = np.array([0.0, S2, S2, 0.0])        # 180° about (x+y)/√2: swaps x,y, negates z
Q_NED_TO_NED = np.array([1.0, 0.0, 0.0, 0.0])
# quaternion of the fixed rotation sensor axes -> FRD body
Q_FLU_TO_FRD = np.array([0.0, 1.0, 0.0, 0.0])
Q_FRD_TO_FRD = np.array([1.0, 0.0, 0.0, 0.0])
R_FLU_FROM_FRD = np.diag([1.0, -1.0, -1.0])         # v_flu = R v_frd


def to_ned(q_lib, q_earth_to_ned, q_sensor_to_frd):
    """Library quaternion (sensor -> library earth) -> product quaternion (FRD -> NED)."""
    return qmul(qmul(q_earth_to_ned, q_lib), qconj(q_sensor_to_frd))


def from_ned(q_ned, q_earth_to_ned, q_sensor_to_frd):
    """Inverse of to_ned: product quaternion -> the library's own frames."""
    return qmul(qmul(qconj(q_earth_to_ned), q_ned), q_sensor_to_frd)


def _first_valid(log: SensorLog, bit):
    idx = np.flatnonzero((log.valid & bit) != 0)
    return int(idx[0]) if len(idx) else None


def _initial_q(log: SensorLog):
    ka = _first_valid(log, VALID_ACCEL)
    km = _first_valid(log, VALID_MAG)
    if ka is None:
        return np.array([1.0, 0, 0, 0])
    if km is None:
        f = log.accel[ka]
        roll = np.arctan2(-f[1], -f[2])
        pitch = np.arctan2(f[0], np.hypot(f[1], f[2]))
        cr, sr, cp, sp = np.cos(roll / 2), np.sin(roll / 2), np.cos(pitch / 2), np.sin(pitch / 2)
        return np.array([cr * cp, sr * cp, cr * sp, -sr * sp])
    return quat_from_accel_mag(log.accel[ka], log.mag[km])


class Peer:
    name = "peer"
    uses_mag = True
    title = ""
    package = ""          # the PyPI package it runs (installed by the `dev` extra)

    @classmethod
    def available(cls) -> bool:
        import importlib.util
        return importlib.util.find_spec(cls.package) is not None

    def __init__(self, **options):
        self.options = options

    def run(self, log: SensorLog) -> np.ndarray:
        raise NotImplementedError


class FusionPeer(Peer):
    """x-io Fusion (imufusion), NED convention, library defaults unless options say otherwise."""
    name = "fusion"
    package = "imufusion"
    title = "x-io Fusion (imufusion, defaults)"

    def run(self, log):
        import imufusion

        s = imufusion.AhrsSettings()
        s.convention = imufusion.CONVENTION_NED
        if s.convention != imufusion.CONVENTION_NED:
            raise RuntimeError("imufusion did not take the NED convention")
        s.sample_rate = float(round(1.0 / np.median(log.dt)))
        for k in ("gain", "acceleration_rejection", "magnetic_rejection", "rejection_timeout",
                  "gyroscope_range"):
            if k in self.options:
                setattr(s, k, self.options[k])
        a = imufusion.Ahrs()
        a.set_settings(s)
        bias = None
        if self.options.get("bias", False):
            bias = imufusion.Bias()
            bs = imufusion.BiasSettings()
            bs.sample_rate = s.sample_rate
            bias.set_settings(bs)
        gyro_dps = np.degrees(log.gyro)
        accel_g = log.accel / G0
        out = np.empty((len(log), 4))
        for k in range(len(log)):
            g = gyro_dps[k]
            if bias is not None:
                g = bias.update(g)
            a.set_sample_period(float(log.dt[k]))
            v = int(log.valid[k])
            if (v & VALID_MAG) and np.all(np.isfinite(log.mag[k])):
                a.update(g, accel_g[k], log.mag[k])
            else:
                a.update_no_magnetometer(g, accel_g[k])
            out[k] = a.get_quaternion()
        return out


class VqfPeer(Peer):
    """VQF (Laidig & Seel 2023), 9D by default; `vqf6d` ignores the magnetometer."""
    name = "vqf"
    package = "vqf"
    title = "VQF 9D (vqf)"

    def run(self, log):
        from vqf import VQF

        ts = float(np.median(log.dt))
        f = VQF(ts, **{k: v for k, v in self.options.items()})
        out = np.empty((len(log), 4))
        for k in range(len(log)):
            v = int(log.valid[k])
            gyr = np.ascontiguousarray(log.gyro[k])
            acc = np.ascontiguousarray(log.accel[k]) if v & VALID_ACCEL else None
            if self.uses_mag and (v & VALID_MAG) and np.all(np.isfinite(log.mag[k])):
                f.update(gyr, acc if acc is not None else np.zeros(3),
                         np.ascontiguousarray(log.mag[k]))
            else:
                f.update(gyr, acc if acc is not None else np.zeros(3))
            out[k] = f.getQuat9D() if self.uses_mag else f.getQuat6D()
        return to_ned(out, Q_ENU_TO_NED, Q_FRD_TO_FRD)


class Vqf6dPeer(VqfPeer):
    name = "vqf6d"
    uses_mag = False
    title = "VQF 6D (vqf, no magnetometer)"


def _nonzero_gyro(g):
    if not np.any(g):
        return np.full(3, 1e-12)
    return g


def _run_ahrs_filter(m, log, q_earth_to_ned):
    """Step an `ahrs` Madgwick/Mahony object over a log in FLU sensor axes, with its own
    earth frame (NWU or ENU, given as the rotation to NED); returns body->NED quaternions."""
    q = from_ned(_initial_q(log), q_earth_to_ned, Q_FLU_TO_FRD)
    gyr = log.gyro @ R_FLU_FROM_FRD.T
    acc = log.accel @ R_FLU_FROM_FRD.T
    mag = log.mag @ R_FLU_FROM_FRD.T
    out = np.empty((len(log), 4))
    for k in range(len(log)):
        v = int(log.valid[k])
        g = _nonzero_gyro(gyr[k])
        a = acc[k] if v & VALID_ACCEL else np.zeros(3)
        if (v & VALID_MAG) and np.all(np.isfinite(mag[k])):
            q = m.updateMARG(q, g, a, mag[k], dt=float(log.dt[k]))
        else:
            q = m.updateIMU(q, g, a, dt=float(log.dt[k]))
        out[k] = q
    return to_ned(out, q_earth_to_ned, Q_FLU_TO_FRD)


class MadgwickPeer(Peer):
    """ahrs.filters.Madgwick (earth NWU), fed in FLU sensor axes; beta default 0.12."""
    name = "madgwick"
    package = "ahrs"
    title = "Madgwick (ahrs, beta 0.12)"

    def run(self, log):
        from ahrs.filters import Madgwick

        beta = float(self.options.get("beta", 0.12))
        m = Madgwick(frequency=1.0 / float(np.median(log.dt)), gain=beta)
        m.gain = beta
        return _run_ahrs_filter(m, log, Q_NWU_TO_NED)


class MahonyPeer(Peer):
    """ahrs.filters.Mahony (earth ENU), fed in FLU sensor axes; Kp 0.74, Ki 0.0012 by default."""
    name = "mahony"
    package = "ahrs"
    title = "Mahony (ahrs, Kp 0.74, Ki 0.0012)"

    def run(self, log):
        from ahrs.filters import Mahony

        kp = float(self.options.get("k_P", 0.74))
        ki = float(self.options.get("k_I", 0.0012))
        m = Mahony(frequency=1.0 / float(np.median(log.dt)), k_P=kp, k_I=ki)
        return _run_ahrs_filter(m, log, Q_ENU_TO_NED)


PEERS = {p.name: p for p in (VqfPeer, Vqf6dPeer, FusionPeer, MadgwickPeer, MahonyPeer)}


def names() -> list[str]:
    return list(PEERS)


def make(name: str, **options) -> Peer:
    if name not in PEERS:
        raise KeyError(f"unknown peer {name!r} (known: {', '.join(PEERS)})")
    return PEERS[name](**options)


def run(name: str, log: SensorLog, **options) -> np.ndarray:
    return make(name, **options).run(log)


# ---------------------------------------------------------------------------------------
# BROAD's scoring method

def remove_heading_offset(q_est, q_ref, mask=None):
    """q_est with one constant rotation about the NED vertical removed (6D filters).

    The offset is the circular mean, over the rows in `mask` with a finite reference, of the
    heading part 2·atan2(z, w) of the earth-frame error q_est ⊗ q_ref⁻¹.
    """
    ss, sc, n = heading_offset_sums(q_est, q_ref, mask)
    if not n:
        return np.array(q_est, dtype=float)
    return rotate_heading(q_est, np.arctan2(ss / n, sc / n))


def heading_offset_sums(q_est, q_ref, mask=None) -> tuple[float, float, int]:
    """(sum of sin, sum of cos, count) of the heading offsets remove_heading_offset averages: sums
    of a log's chunks add up to the whole log's (the mean is sum / count)."""
    qe = qmul(q_est, qconj(q_ref))
    ok = np.all(np.isfinite(qe), axis=1)
    if mask is not None:
        ok &= np.asarray(mask, dtype=bool)
    if not ok.any():
        return 0.0, 0.0, 0
    delta = 2.0 * np.arctan2(qe[ok, 3], qe[ok, 0])
    return float(np.sum(np.sin(delta))), float(np.sum(np.cos(delta))), int(ok.sum())


def rotate_heading(q_est, d: float) -> np.ndarray:
    """q_est rotated by -d (radians) about the NED vertical: a heading offset d removed."""
    rot = np.array([np.cos(-d / 2), 0.0, 0.0, np.sin(-d / 2)])
    return qmul(rot, q_est)


def broad_score(q_est, log: SensorLog, uses_mag: bool = True, mask=None) -> dict:
    """BROAD's RMSE (degrees): total / heading / inclination over moving samples with a finite reference.

    `mask` defaults to meta['movement'] (all rows after settle time when absent). For filters
    that do not use the magnetometer one constant heading offset is removed first.
    """
    if log.q_true is None:
        raise ValueError(f"log {log.name!r} has no reference attitude")
    if mask is None:
        mask = log.meta.get("movement")
    if mask is None:
        mask = log.t >= log.t[0] + log.settle_time
    mask = np.asarray(mask, dtype=bool) & np.all(np.isfinite(log.q_true), axis=1)
    q_est = np.asarray(q_est, dtype=float)
    if not uses_mag:
        q_est = remove_heading_offset(q_est, log.q_true, mask)
    tot, head, incl = broad_errors_deg(q_est[mask], log.q_true[mask])
    rms = lambda e: float(np.sqrt(np.mean(e ** 2)))  # noqa: E731
    return {"total": rms(tot), "heading": rms(head), "inclination": rms(incl), "n": int(mask.sum())}
