"""Scenario checks against physics and independent arithmetic (not against the simulator itself).

- determinism per seed; another seed changes the noise;
- noise off: the gyro, integrated by the exact exponential (src/ahrsgen/npquat.py, not the
  simulator's own helpers), reproduces q_true; the accelerometer is R^T(a_n - g_n) with R from
  npquat, a_n consistent with the finite-difference derivative of the true velocity; the
  magnetometer is R^T m_n with m_n from the stated inclination/declination;
- sample-rate / valid-bit bookkeeping, jitter and dropouts;
- noise: the per-sample std matches density * sqrt(rate);
- fixed-wing: initial Euler angles, airspeed floor, coordinated-turn roll = atan(V chi_dot / g);
- static scenarios: offsets exactly in the stated intervals and nowhere else.
"""
from __future__ import annotations

import numpy as np
import pytest

from ahrsgen.sim import scenarios
from ahrsgen.sim.log import G0, VALID_ACCEL, VALID_GPS, VALID_GYRO, VALID_MAG
from ahrsgen.npquat import euler_from_q, qconj, qexp, qmul, rotmat, to_rotvec

DEG = np.pi / 180

# short versions of every scenario (the tests must stay fast)
SHORT = {
    "fixedwing_gps": dict(duration=60.0),
    "static_accel_disturbance": dict(duration=30.0),
    "static_mag_disturbance": dict(duration=30.0),
    "turntable": dict(duration=30.0),
    "multirotor": dict(duration=34.0),      # through the yaw spins and the flips
}
ARRAYS = ("t", "dt", "gyro", "accel", "mag", "gps_vel", "valid", "q_true")


def test_all_scenarios_registered():
    assert set(SHORT) <= set(scenarios.names())
    for name in SHORT:
        mod = scenarios.module(name)
        assert isinstance(mod.DESCRIPTION, str) and len(mod.DESCRIPTION) > 40
        assert mod.__doc__ and len(mod.__doc__) > 200


@pytest.mark.parametrize("name", sorted(SHORT))
def test_deterministic_per_seed(name):
    a = scenarios.make(name, seed=3, **SHORT[name])
    b = scenarios.make(name, seed=3, **SHORT[name])
    c = scenarios.make(name, seed=4, **SHORT[name])
    for k in ARRAYS:
        assert np.array_equal(getattr(a, k), getattr(b, k), equal_nan=True), k
    assert not np.array_equal(a.gyro, c.gyro)
    assert not np.array_equal(a.accel, c.accel)
    # truth does not depend on the seed
    assert np.array_equal(a.q_true, c.q_true)


@pytest.mark.parametrize("name", sorted(SHORT))
def test_meta(name):
    log = scenarios.make(name, seed=0, **SHORT[name])
    m = log.meta
    for key in ("description", "rate_hz", "seed", "settle_time", "mag_ref_ned", "gps_period",
                "gyro_bias_true", "sensors", "n_samples", "duration"):
        assert key in m, key
    assert abs(np.linalg.norm(m["mag_ref_ned"]) - 1) < 1e-12
    assert m["n_samples"] == len(log)
    assert abs(len(log) - SHORT[name]["duration"] * m["rate_hz"]) <= 1
    assert np.allclose(np.diff(log.t), 1 / m["rate_hz"], rtol=0, atol=1e-12)
    assert log.dt[0] == pytest.approx(1 / m["rate_hz"])
    assert np.all((log.valid & VALID_GYRO) > 0)


def integrate_exact(log):
    """Max rotation angle between q_true and the gyro integrated by q ⊗ exp(½ ω dt)."""
    q = log.q_true[0].copy()
    worst = 0.0
    for k in range(1, len(log)):
        if not log.valid[k] & VALID_GYRO:
            q = log.q_true[k].copy()     # a lost gyro sample: the interval is gone
            continue
        q = qmul(q, qexp(0.5 * log.gyro[k] * log.dt[k]))
        q /= np.linalg.norm(q)
        worst = max(worst, np.linalg.norm(to_rotvec(qmul(qconj(q), log.q_true[k]))))
    return worst


@pytest.mark.parametrize("name,opts", [
    ("fixedwing_gps", dict(duration=60.0)),
    ("fixedwing_gps", dict(duration=30.0, rate_hz=100.0)),
    ("turntable", dict(duration=60.0)),
    ("multirotor", dict(duration=34.0)),
    ("static_accel_disturbance", dict(duration=10.0)),
])
def test_noise_free_gyro_reproduces_truth(name, opts):
    log = scenarios.make(name, seed=1, noise=False, **opts)
    # the run actually rotates (except the static one)
    total = np.sum(np.linalg.norm(log.gyro[1:], axis=1) * log.dt[1:])
    if not name.startswith("static"):
        assert total > 3.0
    assert integrate_exact(log) <= 1e-9


def test_noise_free_gyro_with_jitter_and_dropouts():
    log = scenarios.make("multirotor", seed=2, noise=False, duration=25.0, jitter=0.4e-3,
                         dropout={"gyro": 0.02, "gps": 0.2, "mag": 0.1, "accel": 0.05})
    dt = np.diff(log.t)
    assert dt.min() > 0 and dt.std() > 1e-4           # jitter present, time monotonic
    assert np.allclose(log.dt[1:], dt)
    assert 0.005 < np.mean((log.valid & VALID_GYRO) == 0) < 0.04
    assert integrate_exact(log) <= 1e-9
    # accel still exact at its (jittered) sample time where delivered
    ok = (log.valid & VALID_ACCEL) > 0
    a_n = log.meta["truth"]["acc_ned"]
    f = np.array([rotmat(q).T @ (a - [0, 0, G0]) for q, a in zip(log.q_true[ok], a_n[ok])])
    assert np.max(np.abs(f - log.accel[ok])) < 1e-12
    # a missing sample holds the last delivered value
    miss = np.where((log.valid & VALID_ACCEL) == 0)[0]
    miss = miss[miss > 0]
    assert np.array_equal(log.accel[miss], log.accel[miss - 1])


@pytest.mark.parametrize("name", sorted(SHORT))
def test_noise_free_accel_and_mag(name):
    log = scenarios.make(name, seed=0, noise=False, **({"disturbances": False} if name.startswith("static") else {}),
                         **SHORT[name])
    m = log.meta
    a_n = m["truth"]["acc_ned"]
    g = np.array([0.0, 0.0, G0])
    inc, dec = m["inclination_deg"] * DEG, m["declination_deg"] * DEG
    m_ref = np.array([np.cos(inc) * np.cos(dec), np.cos(inc) * np.sin(dec), np.sin(inc)])
    assert np.allclose(m_ref, m["mag_ref_ned"], atol=1e-15)
    acc_ok = (log.valid & VALID_ACCEL) > 0
    mag_ok = (log.valid & VALID_MAG) > 0
    same_rate_mag = m["mag_rate_hz"] == m["rate_hz"]
    for k in range(0, len(log), 7):
        Rt = rotmat(log.q_true[k]).T
        if acc_ok[k]:
            assert np.allclose(log.accel[k], Rt @ (a_n[k] - g), atol=1e-12, rtol=0)
        if mag_ok[k] and same_rate_mag:
            u = log.mag[k] / np.linalg.norm(log.mag[k])
            assert np.allclose(u, Rt @ m_ref, atol=1e-12)
            assert np.linalg.norm(log.mag[k]) == pytest.approx(m["mag_field"], rel=1e-12)
    if not same_rate_mag:   # slower magnetometer: sample taken at its fix time, within one IMU step
        k = np.where(mag_ok)[0]
        ang = np.arccos(np.clip([np.dot(log.mag[i] / np.linalg.norm(log.mag[i]), rotmat(log.q_true[i]).T @ m_ref)
                                 for i in k], -1, 1))
        step_rot = np.linalg.norm(m["truth"]["gyro"][k], axis=1) / m["rate_hz"]
        assert np.all(ang <= step_rot + 1e-9)
    # a_n is the derivative of the true velocity (central differences)
    v = m["truth"]["vel_ned"]
    dvdt = (v[2:] - v[:-2]) / (log.t[2:] - log.t[:-2])[:, None]
    scale = max(1.0, float(np.abs(a_n).max()))
    tol = 0.02 * scale if m["rate_hz"] < 50 else 0.005 * scale
    assert np.max(np.abs(dvdt - a_n[1:-1])) < tol


def test_level_at_rest_reads_minus_g():
    log = scenarios.make("static_accel_disturbance", seed=0, noise=False, disturbances=False, duration=5.0)
    assert np.allclose(log.accel, [0.0, 0.0, -G0], atol=1e-15, rtol=0)
    assert np.allclose(euler_from_q(log.q_true), 0.0, atol=1e-15)
    assert np.allclose(log.gyro, 0.0, atol=1e-15)


def test_static_offsets_exactly_in_intervals():
    for name, sensor, other in (("static_accel_disturbance", "accel", "mag"),
                                ("static_mag_disturbance", "mag", "accel")):
        clean = scenarios.make(name, seed=0, noise=False, disturbances=False)
        dist = scenarios.make(name, seed=0, noise=False)
        offsets = dist.meta[f"{sensor}_offsets"]
        assert len(offsets) >= 3
        assert dist.meta["disturbance_intervals"] == [(a, b) for a, b, _ in offsets]
        diff = getattr(dist, sensor) - getattr(clean, sensor)
        expect = np.zeros_like(diff)
        for t0, t1, off in offsets:
            k0, k1 = int(round(t0 * dist.meta["rate_hz"])), int(round(t1 * dist.meta["rate_hz"]))
            expect[k0:k1] += off
            assert np.all(np.linalg.norm(off) > 0)
        on = np.any(expect != 0, axis=1)
        assert np.all(diff[~on] == 0.0)                          # nothing outside the intervals
        assert np.allclose(diff[on], expect[on], atol=1e-13, rtol=0)   # the stated offset inside
        assert np.array_equal(getattr(dist, other), getattr(clean, other))
        # with noise on, the offsets are still there on top of the noise
        noisy = scenarios.make(name, seed=0)
        noisy_clean = scenarios.make(name, seed=0, disturbances=False)
        assert np.allclose(getattr(noisy, sensor) - getattr(noisy_clean, sensor), expect, atol=1e-12)


def test_noise_std_matches_density():
    log = scenarios.make("static_mag_disturbance", seed=5, disturbances=False)
    s = log.meta["sensors"]
    rate = log.meta["rate_hz"]
    gyro_err = log.gyro - np.asarray(log.meta["gyro_bias_true"])
    acc_err = log.accel - np.array([0.0, 0.0, -G0])
    for err, nd in ((gyro_err, s["gyro_nd_rad_s_rtHz"]), (acc_err, s["accel_nd_m_s2_rtHz"])):
        sigma = nd * np.sqrt(rate)
        assert np.allclose(err.std(axis=0), sigma, rtol=0.04)
        assert np.all(np.abs(err.mean(axis=0)) < 4 * sigma / np.sqrt(len(log)))
    # MPU-6000 0.005 deg/s/rtHz at 100 Hz -> 0.05 deg/s per sample
    assert np.degrees(gyro_err.std()) == pytest.approx(0.05, rel=0.04)


@pytest.mark.parametrize("name,opts,gps_hz,mag_hz", [
    ("fixedwing_gps", dict(duration=60.0), 5.0, 12.5),
    ("fixedwing_gps", dict(duration=20.0, rate_hz=100.0), 5.0, 100.0),
    ("multirotor", dict(duration=20.0), 5.0, 50.0),
    ("multirotor", dict(duration=20.0, gps_rate=0.0), None, 50.0),     # no receiver (indoors)
    ("turntable", dict(duration=20.0), None, 10.0),
])
def test_valid_bit_rates(name, opts, gps_hz, mag_hz):
    log = scenarios.make(name, seed=0, **opts)
    dur = opts["duration"]
    n_gps = int(np.sum((log.valid & VALID_GPS) > 0))
    n_mag = int(np.sum((log.valid & VALID_MAG) > 0))
    if gps_hz is None:
        assert n_gps == 0 and log.meta["gps_period"] is None
    else:
        assert n_gps == pytest.approx(dur * gps_hz, abs=1)
        assert log.meta["gps_period"] == pytest.approx(1 / gps_hz)
        fix_t = log.meta["truth"]["gps_fix_t"]
        assert np.allclose(np.diff(fix_t), 1 / gps_hz)
        k = np.where((log.valid & VALID_GPS) > 0)[0]
        # each fix arrives at the first step at or after its time, within one period
        lag = log.t[k] - fix_t
        assert np.all(lag > -1e-9) and np.all(lag < 1 / log.meta["rate_hz"])
    assert n_mag == pytest.approx(dur * mag_hz, abs=1)
    assert np.all((log.valid & VALID_ACCEL) > 0)


def test_gps_rate_zero_is_an_option_a_negative_one_is_not():
    """--scenario-opt gps_rate=0 is a vehicle without a GPS receiver; a negative rate is refused."""
    from ahrsgen.errors import ConfigError
    assert scenarios.parse_options("multirotor", ["gps_rate=0"]) == {"gps_rate": 0.0}
    with pytest.raises(ConfigError, match="gps_rate"):
        scenarios.parse_options("multirotor", ["gps_rate=-1"])


def test_fixedwing_initial_attitude_and_flight_envelope():
    log = scenarios.make("fixedwing_gps", seed=0, noise=False, rate_hz=100.0, duration=200.0)
    e0 = np.degrees(euler_from_q(log.q_true[0]))
    assert np.allclose(e0, [-28.2, -3.2, 44.8], atol=1e-10)
    e = np.degrees(euler_from_q(log.q_true))
    v = log.meta["truth"]["vel_ned"]
    speed = np.linalg.norm(v, axis=1)
    assert speed.min() >= 18.0 - 1e-9 and speed.max() <= 30.0 + 1e-9
    assert np.abs(e[:, 0]).max() == pytest.approx(35.0, abs=1e-6)
    assert np.abs(e[:, 0]).max() <= 35.0 + 1e-6
    # no wind: GPS course equals the yaw
    course = np.arctan2(v[:, 1], v[:, 0])
    assert np.max(np.abs(np.angle(np.exp(1j * (course - np.radians(e[:, 2])))))) < 1e-9
    # coordinated turn: roll = atan(V chi_dot / g), chi_dot from central differences of the course
    chi = np.unwrap(course)
    chidot = (chi[2:] - chi[:-2]) / (log.t[2:] - log.t[:-2])
    roll_ct = np.arctan(speed[1:-1] * chidot / G0)
    assert np.max(np.abs(roll_ct - np.radians(e[1:-1, 0]))) < 2e-4
    # sustained turns and speed changes: the motion acceleration matters
    acc = log.meta["truth"]["acc_ned"]
    assert np.abs(acc[:, :2]).max() > 5.0
    along = np.sum(acc * v, axis=1) / speed
    assert 2.0 < np.abs(along).max() <= 3.2
    f_excess = np.abs(np.linalg.norm(log.accel, axis=1) - G0)
    assert np.mean(f_excess > 0.5) > 0.3


def test_fixedwing_gyro_bias_drawn_from_seed():
    b = [np.degrees(scenarios.make("fixedwing_gps", seed=s, duration=5.0).meta["gyro_bias_true"]) for s in (0, 1)]
    for bi in b:
        assert np.all((np.abs(bi) >= 0.1) & (np.abs(bi) <= 0.5 + 1e-6))
    assert not np.allclose(b[0], b[1])
    log = scenarios.make("fixedwing_gps", seed=0, duration=200.0)
    # bias walk: the true bias moves, by about 0.007 deg/s per sqrt(300 s)
    drift = np.degrees(log.meta["truth"]["gyro_bias"][-1] - log.meta["truth"]["gyro_bias"][0])
    assert np.all(np.abs(drift) < 0.03) and np.any(np.abs(drift) > 1e-4)


def test_multirotor_vibration_and_manoeuvres():
    log = scenarios.make("multirotor", seed=0, duration=34.0)
    clean = scenarios.make("multirotor", seed=0, duration=34.0, noise=False)
    e = np.degrees(euler_from_q(clean.q_true))
    assert np.abs(e[:, 0]).max() == pytest.approx(45.0, abs=1e-6)
    assert np.abs(e[:, 1]).max() == pytest.approx(45.0, abs=1e-6)
    assert np.degrees(np.abs(clean.gyro[:, 2]).max()) == pytest.approx(240.0, rel=0.01)
    hover = (log.t > 2) & (log.t < 9)
    # vibration: amplitude A at f_m plus A/2 at 2 f_m plus 0.3 m/s² broadband -> RMS sqrt(5A²/8 + 0.09)
    amp = np.array([1.5, 1.5, 3.0])
    rms = np.sqrt(5 * amp ** 2 / 8 + 0.09)
    assert np.allclose((log.accel[hover] - clean.accel[hover]).std(axis=0), rms, rtol=0.1)
    assert np.all(np.abs(clean.accel[hover] - [0, 0, -G0]).max() < 1e-9)              # hovering, level
    novib = scenarios.make("multirotor", seed=0, duration=34.0, vibration=False)
    assert np.all((novib.accel[hover] - clean.accel[hover]).std(axis=0) < 0.1)


def test_multirotor_own_rate_and_repeated_magnetometer():
    """IMU 400 Hz, magnetometer 100 Hz: its bit on one step in four; repeat_slow sets it on
    every step from the first sample on, the rows holding the same samples."""
    import numpy as np
    from ahrsgen.sim import scenarios
    from ahrsgen.sim.log import VALID_MAG
    own = scenarios.make("multirotor", 0, duration=2.0, rate_hz=400.0, mag_rate=100.0)
    rep = scenarios.make("multirotor", 0, duration=2.0, rate_hz=400.0, mag_rate=100.0, repeat_slow=True)
    bits = (own.valid & VALID_MAG) != 0
    assert abs(bits.sum() - 200) <= 1 and not bits[1:4].any()
    first = int(np.argmax(bits))
    assert np.all((rep.valid[first:] & VALID_MAG) != 0) and not np.any(rep.valid[:first] & VALID_MAG)
    np.testing.assert_array_equal(rep.mag[first:], own.mag[first:])
    np.testing.assert_array_equal(rep.gyro, own.gyro)


def _integrate(log):
    q = [log.q_true[0]]
    for k in range(1, len(log)):
        q.append(qmul(q[-1], qexp(0.5 * log.gyro[k] * log.dt[k])))
    return np.array(q)


def test_gyro_clip_truth_and_clip():
    """gyro_clip: without noise and below the range (clip_s=0) the gyro integrated by the exact
    exponential reproduces the truth through the flip; at the default the x gyro is held at
    the range for 0.3 s (to 20 ms: each sample is the step's mean rate, which crosses the range
    later than the rate itself) and the integrated gyro then misses the rotation meta
    reports (the flip's 360 deg minus what the clipped samples carry)."""
    from ahrsgen.sim.metrics import max_angle_diff_rad
    rng = np.radians(500.0)
    slow = scenarios.make("gyro_clip", seed=2, noise=False, clip_s=0.0)
    assert np.abs(slow.gyro).max() <= 0.91 * rng
    assert max_angle_diff_rad(_integrate(slow), slow.q_true) <= 1e-6
    log = scenarios.make("gyro_clip", seed=2, noise=False)
    at = np.abs(log.gyro[:, 0]) >= rng
    assert abs(np.count_nonzero(at) * log.dt[1] - 0.3) <= 0.02
    lost = np.degrees(max_angle_diff_rad(_integrate(log)[-1:], log.q_true[-1:]))
    assert 10.0 < lost and abs(lost - log.meta["clip"]["rotation_lost_deg"]) < 0.05 * lost


def test_gyro_clip_at_the_pendulums_range_or_refused():
    """At 600 deg/s (the pendulum's clip) a one-turn flip holds the x gyro at the range for 0.3 s
    where its axis allows (to 20 ms, as above); where it cannot, make() says so instead of
    writing a log without a clip (seed 1 used to); so does the CLI, in one line."""
    rng = np.radians(600.0)
    for seed in (0, 2, 3):
        log = scenarios.make("gyro_clip", seed=seed, noise=False, gyro_range_deg_s=600.0)
        at = np.abs(log.gyro[:, 0]) >= rng
        assert abs(np.count_nonzero(at) * log.dt[1] - 0.3) <= 0.02, seed
    with pytest.raises(ValueError, match="no 360 deg flip keeps this gyro beyond 600 deg/s"):
        scenarios.make("gyro_clip", seed=1, gyro_range_deg_s=600.0)
    assert scenarios.make("gyro_clip", seed=1, gyro_range_deg_s=600.0, clip_s=0.25).meta["clip"]["end_s"]


def test_averaged_log_is_the_slower_integrating_imu():
    """SensorLog.averaged(k): every k rows one at the last row's time, the mean gyro and
    accelerometer of the k rows; on a noise-free flight the averaged gyro still carries the
    attitude (integrated exactly, it follows the truth to a small second-order error), a gyro
    sample missing in a group makes the averaged row's gyro invalid, and per-row meta arrays
    are thinned alike."""
    log = scenarios.make("attached_magnet", 0, noise=False, duration=30.0)
    log.meta["movement"] = np.arange(len(log)) % 2 == 0
    slow = log.averaged(3)
    n = len(log) // 3
    assert len(slow) == n
    assert np.array_equal(slow.t, log.t[2:3 * n:3])
    assert np.allclose(slow.dt[1:], 3 * log.dt[1], rtol=1e-9)
    assert np.allclose(slow.gyro[5], log.gyro[15:18].mean(axis=0), rtol=0, atol=1e-15)
    assert np.array_equal(slow.mag, log.mag[2:3 * n:3]) and np.array_equal(slow.q_true, log.q_true[2:3 * n:3])
    assert np.array_equal(slow.meta["movement"], log.meta["movement"][2:3 * n:3])
    assert integrate_exact(slow) < np.radians(0.05)
    log.valid[16] &= ~np.uint32(VALID_GYRO)
    v = log.averaged(3).valid
    assert not v[5] & VALID_GYRO and v[4] & VALID_GYRO and v[5] & VALID_ACCEL
    with pytest.raises(ValueError):
        log.averaged(0)
