"""MEKF product design (measurement = "vectors", the defaults): behaviour of its pieces.

Each test builds the generated C and checks one behaviour against the truth of a simulated
log (or against the NumPy reference, step by step, on a multi-rate log): rest detection
learns the gyro bias, a turntable is not rest, magnetic disturbances are rejected and a
lasting change is re-acquired, the automatic heading source, the HEADING_UNAIDED bit.
"""
import copy

import numpy as np
import pytest

from ahrsgen.sim import host
from ahrsgen.sim.log import VALID_ACCEL, VALID_GYRO, VALID_MAG, SensorLog
from ahrsgen.sim.metrics import broad_errors_deg, max_angle_diff_rad
from ahrsgen.sim.scenarios import make
from ahrsgen.sim.scenarios._static import make_static
from ahrsgen.generate import config
from ahrsgen.filters.mekf import reference as R
from ahrsgen.npquat import qexp, qmul, rotmat

DEG = np.pi / 180


def build(precision="float", sets=()):
    return host.build(config.resolve("mekf", sets=list(sets), precision=precision))


def reference(sets=()):
    cfg = config.resolve("mekf", sets=list(sets))
    return cfg.spec.reference(cfg.params)


def heading_err_deg(q, log):
    return broad_errors_deg(q, log.q_true)[1]


@pytest.mark.slow
def test_double_c_matches_reference_multirate_with_dropouts():
    """Magnetometer at 50 Hz, GPS at 5 Hz, IMU at 250 Hz with jitter and dropouts: same status
    every step, same attitude (<= 1e-9 rad) as the independent reference."""
    log = make("multirotor", 1, duration=40.0, jitter=0.0004,
               dropout={"gyro": 0.005, "accel": 0.01, "mag": 0.05, "gps": 0.1})
    assert np.any((log.valid & VALID_MAG) == 0) and np.any(log.valid == VALID_GYRO | VALID_ACCEL)
    sets = [f"declination={float(np.radians(log.meta['declination_deg']))!r}"]
    r = build("double", sets).run(log)
    rr = host.run_reference(reference(sets), log)
    assert np.array_equal(r.status, rr.status)
    assert max_angle_diff_rad(r.q, rr.q) <= 1e-9


def _static_with_bias(bias_deg_s, seconds=40.0, **kw):
    log = make_static("rest", "static, biased gyro", 0, duration=seconds, attitude_deg=(10.0, -5.0, 30.0), **kw)
    log.gyro = log.gyro + np.asarray(bias_deg_s) * DEG
    return log


def test_rest_detection_learns_the_bias_quickly():
    """A motionless IMU with a 0.5 deg/s bias: AT_REST after rest_min_time (1.5 s) and the bias
    known to 0.02 deg/s per axis 5 s later, with or without the magnetometer; without rest
    detection and without the magnetometer the vertical axis (which gravity cannot observe)
    is still off by more than 0.1 deg/s then. (With the magnetometer, the heading teaches it
    at a pace that depends on the heading noise; not asserted.)"""
    bias = np.array([0.5, -0.4, 0.5])
    log = _static_with_bias(bias, seconds=8.0)
    hf = build()
    r = hf.run(log)
    rest = (r.status & R.AT_REST) != 0
    t_rest = log.t[np.argmax(rest)] - log.t[0]
    assert rest.any() and 1.4 <= t_rest <= 2.5, t_rest
    b = np.degrees(np.array(hf.state_dict(hf.last_state)["gyro_bias"], float))
    truth = bias + np.degrees(np.asarray(log.meta["gyro_bias_true"], float))
    assert np.all(np.abs(b - truth) < 0.02), (b, truth)
    no_mag = copy.deepcopy(log)
    no_mag.valid &= ~np.uint32(VALID_MAG)
    hf.run(no_mag)
    b = np.degrees(np.array(hf.state_dict(hf.last_state)["gyro_bias"], float))
    assert np.all(np.abs(b - truth) < 0.02), (b, truth)
    hf0 = build(sets=["rest_gyro_th=0"])
    hf0.run(no_mag)
    b0 = np.degrees(np.array(hf0.state_dict(hf0.last_state)["gyro_bias"], float))
    assert abs(b0[2] - truth[2]) > 0.1, (b0, truth)


def _tumble_log(gyro_matrix, seconds=60.0, dt=1 / 285.714, amp=8.0):
    """Hand-held tumbling as in BROAD's fast rotation with breaks: 5 s bursts of rotation about
    all three axes (up to ~8 rad/s), 5 s still, exact accelerometer and magnetometer; the gyro
    reads gyro_matrix @ omega (scale-factor and cross-axis errors)."""
    from ahrsgen.npquat import q_from_euler
    n = int(seconds / dt)
    t = np.arange(n) * dt
    phase = t % 10.0
    env = np.where(phase < 5.0, np.sin(np.pi * phase / 5.0) ** 2, 0.0)
    w = amp * env[:, None] * np.stack([np.sin(2 * np.pi * 0.7 * t), np.sin(2 * np.pi * 1.1 * t + 1),
                                       np.sin(2 * np.pi * 0.9 * t + 2)], axis=1)
    q = np.zeros((n, 4))
    q[0] = q_from_euler(0.1, -0.2, 0.3)
    for k in range(1, n):
        q[k] = qmul(q[k - 1], qexp(0.25 * (w[k - 1] + w[k]) * dt))
        q[k] /= np.linalg.norm(q[k])
    acc = np.array([rotmat(qq).T @ np.array([0.0, 0.0, -9.80665]) for qq in q])
    mag = np.array([rotmat(qq).T @ np.array([0.2, 0.0, 0.4]) for qq in q])
    valid = np.full(n, VALID_GYRO | VALID_ACCEL | VALID_MAG, dtype=np.uint32)
    return SensorLog("tumble", t, np.full(n, dt), w @ np.asarray(gyro_matrix).T, acc, mag, np.zeros((n, 3)),
                     valid, q)


def test_rate_noise_limits_the_heading_error_of_an_imperfect_gyro():
    """gyro_rate_noise (the gyro noise density growing with the rate) on a gyro with 2 %
    scale-factor and 1 % cross-axis errors, tumbled in bursts: the heading error these leave
    after each burst is corrected sooner, heading RMS at least 15 % lower than with the term
    off (measured 1.16 against 1.55 deg). The error is physical, not fitted: a MEMS gyro's
    datasheet gives scale-factor and cross-axis errors of this size."""
    S = np.array([[1.02, 0.01, -0.01], [0.005, 0.98, 0.01], [-0.01, 0.005, 1.015]])
    log = _tumble_log(S)
    m = log.t > 5.0

    def heading_rms(sets):
        q = build(sets=sets).run(log).q
        return float(np.sqrt(np.mean(broad_errors_deg(q[m], log.q_true[m])[1] ** 2)))
    with_term, without = heading_rms([]), heading_rms(["gyro_rate_noise=0"])
    assert with_term < 0.85 * without, (with_term, without)


def _constant_rate_log(rate_deg_s=10.0, seconds=10.0, dt=0.01):
    """Level, yawing at a constant rate: gyro and accelerometer perfectly steady."""
    n = int(seconds / dt)
    t = np.arange(n) * dt
    w = np.array([0.0, 0.0, rate_deg_s * DEG])
    q = np.zeros((n, 4))
    q[0] = [1.0, 0.0, 0.0, 0.0]
    for k in range(1, n):
        q[k] = qmul(q[k - 1], qexp(0.5 * w * dt))
    acc = np.array([rotmat(qq).T @ np.array([0.0, 0.0, -9.80665]) for qq in q])
    mag = np.array([rotmat(qq).T @ np.array([0.2, 0.0, 0.4]) for qq in q])
    valid = np.full(n, VALID_GYRO | VALID_ACCEL | VALID_MAG, dtype=np.uint32)
    return SensorLog("turn", t, np.full(n, dt), np.tile(w, (n, 1)), acc, mag, np.zeros((n, 3)), valid, q)


def test_constant_rotation_is_not_rest():
    """A turntable at 10 deg/s: gyro steady, but its low-pass is above rest_gyro_th: never AT_REST,
    and the bias is not taught the rotation rate."""
    hf = build()
    r = hf.run(_constant_rate_log())
    assert not np.any(r.status & R.AT_REST)
    assert np.abs(np.array(hf.state_dict(hf.last_state)["gyro_bias"], float)).max() < 0.2 * DEG


def _mag_offset_log(intervals, seconds):
    return make_static("magdist", "static, magnetic offsets", 0, duration=seconds,
                       attitude_deg=(5.0, -8.0, 40.0), mag_intervals=intervals)


def test_short_magnetic_disturbance_is_rejected_and_heading_held():
    """A 0.3 gauss offset for 10 s (field norm and dip far off): MAG_DISTURBED through it,
    heading held within 0.5 deg; with rejection off the heading is dragged away, more than
    ten times as far as with it (measured 2.4 deg against 0.03: how far in 10 s depends on
    the heading noise, mag_heading_density)."""
    log = _mag_offset_log([(20.0, 30.0, [0.3, -0.2, 0.0])], 40.0)
    sets = [f"declination={float(np.radians(log.meta['declination_deg']))!r}"]
    r = build(sets=sets).run(log)
    during = (log.t >= 20.05) & (log.t < 29.95)
    assert np.all(r.status[during] & R.MAG_DISTURBED)
    assert not np.any(r.status[log.t < 19.95] & R.MAG_DISTURBED)
    assert not np.any(r.status[log.t > 30.05] & R.MAG_DISTURBED)
    assert heading_err_deg(r.q, log)[log.t > 5].max() < 0.5
    r0 = build(sets=sets + ["mag_norm_th=0"]).run(log)
    assert heading_err_deg(r0.q, log)[during].max() > max(1.0, 10 * heading_err_deg(r.q, log)[during].max())


def test_lasting_magnetic_change_is_reacquired():
    """A field change that stays (steady, e.g. a magnet now fixed nearby): rejected first, then
    accepted as the new reference after mag_new_time (20 s), so the heading is not held
    unaided for ever."""
    log = _mag_offset_log([(10.0, 60.0, [0.3, -0.2, 0.0])], 45.0)
    sets = [f"declination={float(np.radians(log.meta['declination_deg']))!r}"]
    r = build(sets=sets).run(log)
    dist = (r.status & R.MAG_DISTURBED) != 0
    t_dist = log.t[dist]
    assert t_dist.min() < 10.2 and 29.5 < t_dist.max() < 30.5, (t_dist.min(), t_dist.max())
    assert not np.any(dist[log.t > 31.0])


def test_auto_heading_course_for_fixedwing_mag_when_drifting_sideways():
    """heading_source = auto: on the fixed-wing flight the GPS course is the heading (it flies
    nose first); give it a magnetometer that is 30 deg off and the estimate must not follow
    it. A multirotor flying sideways uses the magnetometer: its course is no heading."""
    fw = make("fixedwing_gps", 0, duration=120.0)
    bad = copy.deepcopy(fw)
    bad.mag = np.array([rotmat(np.array([np.cos(15 * DEG), 0, 0, np.sin(15 * DEG)])).T @ m for m in fw.mag])
    sets = [f"declination={float(np.radians(fw.meta['declination_deg']))!r}"]
    r = build(sets=sets).run(bad)
    late = fw.t > 30
    assert np.sqrt(np.mean(heading_err_deg(r.q, fw)[late] ** 2)) < 2.0
    rm = build(sets=sets + ["heading_source=mag"]).run(bad)
    assert np.sqrt(np.mean(heading_err_deg(rm.q, fw)[late] ** 2)) > 10.0


def test_heading_unaided_bit():
    """No magnetometer, no GPS: HEADING_UNAIDED on every step after the first (the first only
    initialises; the heading was never aided). A magnetometer
    sample every 0.5 s (its own rate) keeps it off; when the samples stop, it shows once the
    heading has gone 1 s uncorrected."""
    log = _constant_rate_log(0.0, seconds=3.0)
    none = copy.deepcopy(log)
    none.valid = np.full(len(log), VALID_GYRO | VALID_ACCEL, dtype=np.uint32)
    r = build().run(none)
    t = log.t - log.t[0]
    assert np.all(r.status[1:] & R.HEADING_UNAIDED)
    slow = copy.deepcopy(log)
    slow.valid = np.full(len(log), VALID_GYRO | VALID_ACCEL, dtype=np.uint32)
    slow.valid[:101:50] |= VALID_MAG                     # samples at 0, 0.5, 1.0 s, then none
    rs = build().run(slow)
    assert not np.any(rs.status[t < 1.99] & R.HEADING_UNAIDED)
    assert np.all(rs.status[t > 2.02] & R.HEADING_UNAIDED)


def test_a_1khz_imu_is_as_accurate_as_a_250hz_one():
    """The gravity direction's variance is a density (accel_noise_density²/dt; accel_angle_noise,
    the per-sample term, at its minimum), so a 1 kHz IMU's samples each weigh less and its trust
    per second stays that of a 250 Hz one: the multirotor scenario (seeds 0-2, magnetometer
    100 Hz, float C, scored as the bench scores) at 1 kHz within 0.1 deg of 250 Hz (measured 0.262
    and 0.370 deg; with the per-sample term 0.07 of before 0.258 and 0.379), where the per-sample
    term alone (accel_angle_noise = 0.07, accel_noise_density = 0: the design before issue 26)
    gives 0.420 deg at 1 kHz: the vibration the accelerometer sees, trusted four times as much per
    second, moves the tilt. Before the low-pass's warm start (accel_lpf_warm) the start-up
    transient amplified the difference (2.29 against 0.956 deg, then asserted as 0.5 deg apart);
    with the body-frame attitude error (before issue 29) the per-sample term alone gave 0.636 deg,
    asserted as at least 1.5 times the error; with the earth-frame error 0.366 against 0.258 deg,
    asserted as at least 1.3 times, as now."""
    from ahrsgen.bench.scoring import filter_estimator, score

    def mean_total(sets, **opts):
        est = filter_estimator("mekf", sets)
        out = []
        for seed in range(3):
            log = make("multirotor", seed, **opts)
            q, frame, _ = est.run(log)
            out.append(score(q, log, frame)["total_rms"])
        return float(np.mean(out))
    at_250, at_1k = mean_total([]), mean_total([], rate_hz=1000.0, mag_rate=100.0)
    assert at_1k <= at_250 + 0.1, (at_1k, at_250)
    assert mean_total(["accel_angle_noise=0.07", "accel_noise_density=0"], rate_hz=1000.0, mag_rate=100.0) > 1.3 * at_1k


def test_broad_meets_issue_26s_rate_line_at_every_rate():
    """Issue 26's rate line on BROAD: the 10 trials at 286 Hz and with the IMU averaged to 143,
    95 and 48 Hz (every 2, 3, 6 rows one, as an integrating IMU reports them), float C, the mean
    total RMSE of the defaults within 10 % of the best per-rate `ahrsgen tune` found (BROAD
    alone, six parameters, budget 150: 1.920 / 1.943 / 2.019 / 2.329 deg; studies/
    mekf_motion_density_cv.py). Measured 2.077 / 2.132 / 2.175 / 2.485. With the gravity rows'
    motion as a per-sample term (accel_angle_noise 0.07, accel_adapt_cap 3, accel_adapt_sigmas
    1.5, the defaults before) the tilt was trusted less per second at the lower rates and 143
    and 95 Hz missed the line: 2.178 and 2.255 (+12.1 and +11.7 %)."""
    from ahrsgen.sim import readers
    from ahrsgen.sim.peers import broad_score
    trials = readers.broad_trials()
    if len(trials) < 10:
        pytest.skip("BROAD trials not found (../shared/data/broad or $AHRSGEN_DATA)")
    logs = [readers.read_log(p) for p in trials]
    tunes = {1: 1.920, 2: 1.943, 3: 2.019, 6: 2.329}

    def means(sets):
        f = build(sets=sets)
        return {k: float(np.mean([broad_score(f.run(lg).q, lg)["total"]
                                  for lg in (log.averaged(k) if k > 1 else log for log in logs)])) for k in tunes}
    now = means([])
    assert all(now[k] <= 1.1 * tunes[k] for k in tunes), now
    before = means(["accel_angle_noise=0.07", "accel_adapt_cap=3", "accel_adapt_sigmas=1.5"])
    assert before[2] > 1.1 * tunes[2] and before[3] > 1.1 * tunes[3], before


def test_the_1khz_multirotor_meets_issue_26s_rate_budget():
    """Issue 26's rate acceptance: at 1 kHz (magnetometer 100 Hz) the defaults within 0.15 deg of
    a per-rate `ahrsgen tune` (budget 120, six noise parameters: 0.181 deg), seeds 0-2, float C,
    scored as the bench scores. The gap was the start, while the gyro bias is learned: with the
    accelerometer trusted less then (accel_bias_gain, default 100) measured 0.262 deg, without it
    (accel_bias_gain = 0) 0.377 (0.257 and 0.375 with the per-sample gravity term before
    studies/mekf_motion_density_cv.py)."""
    from ahrsgen.bench.scoring import filter_estimator, score
    budget = 0.181 + 0.15

    def mean_total(sets):
        est = filter_estimator("mekf", sets)
        out = []
        for seed in range(3):
            log = make("multirotor", seed, rate_hz=1000.0, mag_rate=100.0)
            q, frame, _ = est.run(log)
            out.append(score(q, log, frame)["total_rms"])
        return float(np.mean(out))
    assert mean_total([]) <= budget
    assert mean_total(["accel_bias_gain=0"]) > budget


def test_graded_magnetometer_trust_pulls_the_heading_less_in_a_field_that_disagrees():
    """A field disturbed by less than the rejection thresholds (a 0.04 gauss offset on a 0.5
    gauss field for 20 s: never MAG_DISTURBED) pulls the heading; with the graded trust
    (mag_dev_gain 3000: the variance grows with the field's norm and dip disagreement) it pulls
    it less than with the same density and the trust not graded, and in the clean field before
    it the two are the same (measured 1.5 and 2.1 deg against 3.3 and 4.1 for the two offsets)."""
    for off in ([0.04, 0.0, 0.0], [0.0, 0.04, 0.0]):
        log = _mag_offset_log([(20.0, 40.0, off)], 50.0)
        sets = [f"declination={float(np.radians(log.meta['declination_deg']))!r}"]
        during, clean = (log.t >= 20.0) & (log.t < 40.0), (log.t > 5.0) & (log.t < 20.0)
        graded = build(sets=sets + ["mag_dev_gain=3000"]).run(log)
        plain = build(sets=sets + ["mag_dev_gain=0"]).run(log)
        assert not np.any(graded.status & R.MAG_DISTURBED) and not np.any(plain.status & R.MAG_DISTURBED)
        e_g, e_p = heading_err_deg(graded.q, log), heading_err_deg(plain.q, log)
        assert e_p[during].max() > 2.5                       # the disturbance does pull
        assert e_g[during].max() < 0.75 * e_p[during].max(), (e_g[during].max(), e_p[during].max())
        assert abs(e_g[clean].max() - e_p[clean].max()) < 0.05


def test_step_noise_covers_the_integration_error_of_a_low_rate_gyro():
    """gyro_step_noise: the mean rate an integrating gyro reports over a step, integrated as a
    rotation about a constant axis, misses the rotation's change of axis within the step (second
    order in |w| dt). Tumbling as BROAD's fast rotation (truth at 960 Hz), the gyro averaged to
    48 Hz, the accelerometer and magnetometer sampled exactly at the row: total RMS with the term
    at most 0.8 times without (measured 0.31 against 0.47 deg). (With the accelerometer averaged
    too, its mean lies half a step behind the attitude, and trusting it more costs instead:
    docs/mekf.md.)"""
    fine = _tumble_log(np.eye(3), dt=1 / 960.0)
    log = fine.averaged(20)
    log.accel = fine.accel[np.arange(19, len(fine) // 20 * 20, 20)]
    m = log.t > 5.0

    def total_rms(sets):
        q = build(sets=sets).run(log).q
        return float(np.sqrt(np.mean(broad_errors_deg(q[m], log.q_true[m])[0] ** 2)))
    with_term, without = total_rms([]), total_rms(["gyro_step_noise=0"])
    assert with_term < 0.8 * without, (with_term, without)


def test_low_pass_warm_start_forgets_a_bad_first_sample():
    """A motionless IMU (100 Hz, no noise, rest detection off as on a vibrating vehicle, no
    magnetometer) whose first accelerometer sample carries 3 m/s² of vibration: the filter starts
    from that sample (17° of tilt). A low-pass started from it keeps e^(-t/tau) of the spike,
    atan(3 e^(-t) / g) of tilt (tau 1 s), 4.6° RMS over 0.1-6 s; the warm start's running mean of
    n samples keeps 3/(n g), 0.22° RMS. The estimate's tilt error over 0.1-6 s, RMS: below half
    the former (measured 1.41° with the warm start, 6.59° without: the filter followed the
    low-pass and put the spike into the gyro bias)."""
    log = make_static("rest", "spike", 0, duration=6.0, attitude_deg=(10.0, -5.0, 30.0), noise=False)
    log.accel = log.accel.copy()
    log.accel[0] += [3.0, 0.0, 0.0]
    log.valid = np.full(len(log), VALID_GYRO | VALID_ACCEL, dtype=np.uint32)
    r = build(sets=["rest_gyro_th=0"]).run(log)
    inc = broad_errors_deg(r.q, log.q_true)[2]
    m = log.t >= 0.1
    kept = np.degrees(np.arctan(3.0 * np.exp(-log.t[m] / 1.0) / 9.80665))
    assert np.sqrt(np.mean(inc[m] ** 2)) < 0.5 * np.sqrt(np.mean(kept ** 2))


def _turned_field_log(t0, t1, seconds):
    """Static and level (the static_mag_disturbance scenario's truth and noise): a 0.15 gauss
    offset across the 0.5 gauss field's horizontal part (body y) from t0 to t1: the field's
    direction turns by ~37 deg with its norm ~4 % off and its dip barely changed (the field
    check passes it)."""
    return make_static("turned", "static, turned field", 0, duration=seconds,
                       mag_intervals=[(t0, t1, (0.0, -0.15, 0.0))])


def test_heading_gate_holds_the_heading_in_a_field_turned_with_its_norm_and_dip():
    """The heading gate (defaults mag_head_sigmas 5, mag_head_tau 0.5 s): a field turned by
    nearby steel passes the norm and dip checks, and without the gate mekf follows it (measured
    10.8 deg after the 10 s); with it the low-passed heading innovation leaves the filter's own
    heading uncertainty within a fraction of a second, MAG_DISTURBED is set for nearly the whole
    interval and the heading is held (measured 0.26 deg at most, MAG_DISTURBED from 0.16 s on);
    before it nothing is rejected. The gate off: the same filter is dragged more than ten times
    as far."""
    log = _turned_field_log(40.0, 50.0, 70.0)
    sets = [f"declination={float(np.radians(log.meta['declination_deg']))!r}"]
    during = (log.t >= 40.0) & (log.t < 50.0)
    gated = build(sets=sets).run(log)
    plain = build(sets=sets + ["mag_head_sigmas=0"]).run(log)
    dist = (gated.status & R.MAG_DISTURBED) != 0
    assert not np.any(plain.status & R.MAG_DISTURBED)              # the field check passes it
    assert not np.any(dist[log.t < 40.0])
    assert np.all(dist[(log.t >= 41.0) & (log.t < 50.0)])
    e_g, e_p = heading_err_deg(gated.q, log), heading_err_deg(plain.q, log)
    assert e_p[during].max() > 8.0
    assert e_g[log.t > 5.0].max() < 1.0
    assert e_p[during].max() > 10 * e_g[during].max()


def test_heading_gate_accepts_a_lasting_turned_field_after_mag_new_time():
    """A turned field that stays (steel fixed nearby): rejected by the heading gate for
    mag_new_time (20 s), then accepted and followed (the gate gives up while the innovation
    stays inconsistent): heading is never held unaided for longer (measured: rejected from 40.16
    s, 98.5 % of the steps to 60.3 s; after it a few steps near 78 s, where the innovation
    crosses the gate while it converges, 0.2 % of 75-80 s; the heading then follows the turned
    field, 22.6 deg off the truth at 90 s, as without the gate)."""
    log = _turned_field_log(40.0, 200.0, 110.0)
    sets = [f"declination={float(np.radians(log.meta['declination_deg']))!r}"]
    r = build(sets=sets).run(log)
    dist = (r.status & R.MAG_DISTURBED) != 0
    t_dist = log.t[dist]
    assert 40.0 <= t_dist.min() < 41.0
    assert dist[(log.t >= 41.0) & (log.t < 59.9)].mean() > 0.95
    assert 59.9 < t_dist[log.t[dist] < 65.0].max() < 60.5
    assert dist[log.t >= 60.5].mean() < 0.01
    e = heading_err_deg(r.q, log)
    assert e[np.searchsorted(log.t, 90.0)] > 15.0


@pytest.mark.slow
def test_double_c_matches_reference_with_the_heading_gate():
    """The gate's rejection and its giving up: same status every step, same attitude (<= 1e-9
    rad) as the independent reference, on a held and a lasting turned field."""
    for log in (_turned_field_log(40.0, 50.0, 70.0), _turned_field_log(40.0, 200.0, 80.0)):
        sets = [f"declination={float(np.radians(log.meta['declination_deg']))!r}"]
        r = build("double", sets).run(log)
        rr = host.run_reference(reference(sets), log)
        assert np.any(r.status & R.MAG_DISTURBED)
        assert np.array_equal(r.status, rr.status)
        assert max_angle_diff_rad(r.q, rr.q) <= 1e-9
