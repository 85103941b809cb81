"""QCF's GPS linear-acceleration compensation (motion_accel_model = 'gps_lowpass', issue 26),
checked on hand-built noise-free flights whose truth is known: a level vehicle that accelerates
along north. Without compensation the low-passed specific force leans by atan(a / g); with the
GPS velocity it must not lean, and without a fresh GPS velocity nothing may be removed."""
from __future__ import annotations

import numpy as np

from conftest import host_build
from ahrsgen.constants import G0
from ahrsgen.sim.log import VALID_ACCEL, VALID_GPS, VALID_GYRO, VALID_MAG, SensorLog

RATE = 200.0
ACCEL = 2.0                        # m/s^2 along north: atan(2 / 9.81) = 11.5 deg uncompensated
MAG = np.array([0.2, 0.0, 0.45])   # level, heading north: FRD = NED


def _level_flight(gps_until: float, start: float = 10.0, duration: float = 20.0) -> SensorLog:
    """Level, heading north, at rest until `start`, then ACCEL along north for 8 s, then
    constant speed; GPS velocity (exact) at 5 Hz until `gps_until` s."""
    n = int(duration * RATE)
    t = np.arange(n) / RATE
    dt = np.full(n, 1 / RATE)
    acc = np.where((t >= start) & (t < start + 8.0), ACCEL, 0.0)
    vel = np.cumsum(acc) / RATE                      # v_k = sum of the accelerations before
    accel = np.column_stack([acc, np.zeros(n), np.full(n, -G0)])   # f = R^T (a - g), R = I
    gps = np.column_stack([vel, np.zeros(n), np.zeros(n)])
    valid = np.full(n, VALID_GYRO | VALID_ACCEL | VALID_MAG, dtype=np.uint32)
    on_gps = (np.arange(n) % int(RATE / 5) == 0) & (t < gps_until)
    valid[on_gps] |= VALID_GPS
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    return SensorLog("level_accel", t, dt, np.zeros((n, 3)), accel, np.tile(MAG, (n, 1)), gps, valid, q, {})


def _tilt_deg(q) -> np.ndarray:
    """Angle between the estimate's down and the true (level) down, degrees."""
    w, x, y, z = q.T
    r22 = 1 - 2 * (x * x + y * y)                   # R(q)[2, 2]: cos of the tilt
    return np.degrees(np.arccos(np.clip(r22, -1.0, 1.0)))


def test_linear_acceleration_does_not_tilt_with_gps():
    log = _level_flight(gps_until=1e9)
    comp = _tilt_deg(host_build("qcf", "double").run(log).q)
    none = _tilt_deg(host_build("qcf", "double", ("gps_compensation=false",)).run(log).q)
    # uncompensated: the low-pass leans toward atan(2 / 9.81) = 11.5 deg (8 s is several tau)
    assert none.max() > 5.0, none.max()
    # compensated: the kinematic acceleration (v - v_lp)/tau is exactly what the low-pass holds
    # on this flight, apart from the 5 Hz GPS carried by R f + g in between (exact here)
    assert comp.max() < 0.05, comp.max()


def test_no_compensation_without_a_fresh_gps_velocity():
    # GPS for the first 5 s (at rest), none after: gps_timeout (1 s) later nothing is removed
    # and the flight is the one of a filter without GPS (the same steps, bit for bit)
    stale = host_build("qcf", "double").run(_level_flight(gps_until=5.0)).q
    never = host_build("qcf", "double").run(_level_flight(gps_until=-1.0)).q
    off = host_build("qcf", "double", ("gps_compensation=false",)).run(_level_flight(gps_until=-1.0)).q
    np.testing.assert_allclose(stale, off, rtol=0, atol=1e-12)
    np.testing.assert_allclose(never, off, rtol=0, atol=1e-12)
    assert _tilt_deg(stale).max() > 5.0


def test_kp_gps_only_while_the_gps_acceleration_is_removed():
    # without GPS the gain is kp: kp_gps changes nothing (BROAD, which has no GPS, is unchanged)
    log = _level_flight(gps_until=-1.0)
    a = host_build("qcf", "double", ("kp_gps=5",)).run(log).q
    b = host_build("qcf", "double", ("kp_gps=0.1",)).run(log).q
    np.testing.assert_array_equal(a, b)
    # with GPS it is the gain: an uncorrected gyro bias b (rest detection and bias integral off)
    # holds the tilt at 2 b / kp_gps once the loop has settled: the feedback is kp times the error
    # quaternion's vector part, sin(theta / 2) (eq. 14), and the low-pass adds no steady error
    b = 0.01
    log = _level_flight(gps_until=1e9)
    log = SensorLog(log.name, log.t, log.dt, np.tile([b, 0.0, 0.0], (len(log), 1)), log.accel, log.mag,
                    log.gps_vel, log.valid, log.q_true, log.meta)
    window = (log.t > 7.0) & (log.t < 9.9)           # settled (decay exp(-t / (2 accel_tau))), at rest
    for kp in (0.7, 2.8):
        q = host_build("qcf", "double", (f"kp_gps={kp}", "rest_time=0", "ki=0")).run(log).q
        expected = np.degrees(2 * b / kp)
        assert np.all(np.abs(_tilt_deg(q[window]) - expected) < 0.1 * expected), (kp, expected)
