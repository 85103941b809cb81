"""src/ahrsgen/symbolic/aiding.py against plain NumPy formulas and physical invariants."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from ahrsgen import npquat as nq
from ahrsgen.symbolic import aiding, quat


def _fn(inputs, outputs):
    f = ca.Function("f", inputs, outputs)
    return lambda *a: [np.array(o, dtype=float).ravel() for o in f.call([ca.DM(np.asarray(x, dtype=float)) for x in a])]


def test_lowpass_is_backward_euler_step():
    x_lp, x, dt = ca.SX.sym("x_lp", 3), ca.SX.sym("x", 3), ca.SX.sym("dt")
    f = _fn([x_lp, x, dt], [aiding.lowpass(x_lp, x, dt, 0.5)])
    y = np.zeros(3)
    for _ in range(1000):                     # 1 s of a unit step at 1 kHz
        y = f(y, np.ones(3), 1e-3)[0]
    # (1 + dt/tau)^-n -> exp(-t/tau) = exp(-2)
    assert y == pytest.approx(1 - (1 / (1 + 1e-3 / 0.5)) ** 1000, rel=1e-12)
    assert y[0] == pytest.approx(1 - np.exp(-2), abs=2e-3)
    assert aiding.lowpass(x_lp, x, dt, 0.0) is x


@pytest.mark.parametrize("mirror", [False, True])
def test_warm_lowpass_gain_is_the_running_mean_then_the_lowpass(mirror):
    """From t = 0 the warm gain averages: after n samples (n dt <= tau) the low-pass is their
    mean (np.mean); once t reaches tau it is the low-pass of gain dt/(tau + dt), the same as
    lowpass(). Both the CasADi function and reference_aiding's NumPy twin (mirror)."""
    from ahrsgen import reference_aiding
    tau, dt = 0.05, 1e-3
    if mirror:
        gain = lambda t: reference_aiding.warm_lowpass_gain(t, tau, dt)
    else:
        t_s = ca.SX.sym("t")
        g = _fn([t_s], list(aiding.warm_lowpass_gain(t_s, tau, dt)))
        gain = lambda t: tuple(float(v[0]) for v in g(t))
    xs = np.random.default_rng(0).normal(size=(120, 3))
    y, t = np.zeros(3), 0.0
    for n, x in enumerate(xs, 1):
        alpha, t = gain(t)
        y = y + alpha * (x - y)
        if n <= 50:
            assert y == pytest.approx(np.mean(xs[:n], axis=0), abs=1e-12)
        else:
            assert alpha == pytest.approx(dt / (tau + dt), rel=1e-12)
    assert t == pytest.approx(tau, rel=1e-12)


def test_rest_detector_counts_steady_time_and_resets():
    g, glp = (ca.SX.sym(n, 3) for n in ("g", "glp"))
    a2, t, dt = ca.SX.sym("a2"), ca.SX.sym("t"), ca.SX.sym("dt")
    f = _fn([g, a2, glp, t, dt], list(aiding.rest_detector(
        g, a2, glp, t, dt, tau=0.5, gyro_tol=0.03, accel_tol=0.5, gravity=9.81, gyro_max=0.03, min_time=1.0)))
    acc = np.array([0.0, 0.0, -9.81])
    state = [np.zeros(3), np.zeros(1)]
    rng = np.random.default_rng(0)
    for k in range(1500):                     # 1.5 s at rest (small noise, bias 0.01 rad/s)
        a = acc + 0.05 * rng.normal(size=3)
        gl, tr, rest = f(0.01 + 0.002 * rng.normal(size=3), a @ a, state[0], state[1], 1e-3)
        state = [gl, tr]
        assert bool(rest[0]) == (tr[0] >= 1.0)
    assert tr[0] == pytest.approx(1.5, abs=2e-3) and rest[0] == 1
    # a steady 0.2 rad/s turn is not rest (|gyro_lp| too large), nor is an accelerometer
    # magnitude 0.6 m/s^2 off gravity (either way), nor a gyro jolt away from its low-pass
    assert f(np.full(3, 0.2), 9.81 ** 2, np.full(3, 0.2), 5.0, 1e-3)[1][0] == 0
    assert f(np.full(3, 0.01), 10.41 ** 2, np.full(3, 0.01), 5.0, 1e-3)[1][0] == 0
    assert f(np.full(3, 0.01), 9.21 ** 2, np.full(3, 0.01), 5.0, 1e-3)[1][0] == 0
    assert f(np.full(3, 0.01), 10.21 ** 2, np.full(3, 0.01), 5.0, 1e-3)[1][0] > 0   # 0.4 off: steady
    assert f(np.array([0.1, 0.01, 0.01]), 9.81 ** 2, np.full(3, 0.01), 5.0, 1e-3)[1][0] == 0


def test_field_check_learns_rejects_and_renews():
    s = [ca.SX.sym(n) for n in ("n", "d", "rn", "rd", "t", "dt")]
    f = _fn(s, list(aiding.field_check(*s, norm_tol=0.1, dip_tol=0.1, ref_tau=10.0, new_time=2.0)))
    acc, rn, rd, t = f(50.0, 0.8, 0.0, 0.0, 0.0, 0.01)            # first sample: learned
    assert (acc[0], rn[0], rd[0], t[0]) == (1, 50.0, 0.8, 0.0)
    acc, rn, rd, t = f(51.0, 0.81, 50.0, 0.8, 0.0, 0.01)          # close: accepted, tracked
    assert acc[0] == 1 and rn[0] == pytest.approx(50 + 0.01 / 10.01) and t[0] == 0
    assert f(60.0, 0.8, 50.0, 0.8, 0.0, 0.01)[0][0] == 0          # norm 20 % off
    assert f(50.0, 0.95, 50.0, 0.8, 0.0, 0.01)[0][0] == 0         # dip off
    acc, rn, rd, t = f(60.0, 0.8, 50.0, 0.8, 1.0, 0.01)           # rejected: reference held
    assert (acc[0], rn[0], t[0]) == (0, 50.0, pytest.approx(1.01))
    acc, rn, rd, t = f(60.0, 0.9, 50.0, 0.8, 1.995, 0.01)         # rejected for > 2 s: renewed
    assert (rn[0], rd[0], t[0]) == (60.0, 0.9, 0.0)


@pytest.mark.parametrize("seed", range(5))
def test_tilt_correction_aligns_down_and_keeps_heading(seed):
    d = ca.SX.sym("d", 3)
    f = _fn([d], [aiding.tilt_correction(d)])
    rng = np.random.default_rng(seed)
    v = rng.normal(size=3)
    v /= np.linalg.norm(v)
    q = f(v)[0]
    assert np.linalg.norm(q) == pytest.approx(1, abs=1e-12) and q[3] == 0
    np.testing.assert_allclose(nq.rotmat(q) @ v, [0, 0, 1], atol=1e-12)
    # shortest: the angle equals the angle between v and e_z
    assert 2 * np.arccos(min(q[0], 1)) == pytest.approx(np.arccos(v[2]), abs=1e-9)
    np.testing.assert_allclose(nq.rotmat(f(np.array([0, 0, -1.0]))[0]) @ [0, 0, -1.0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(f(3.7 * v)[0], q, atol=1e-15)            # the length does not matter
    t = ca.SX.sym("t", 3)
    xy = _fn([t, d], [quat.rotate_xy_tilt(quat.vec(t[0], t[1], t[2], 0), d)])
    np.testing.assert_allclose(xy(q[:3], 2 * v)[0], (nq.rotmat(q) @ (2 * v))[:2], atol=1e-12)


@pytest.mark.parametrize("decl", [0.0, 0.3])
def test_tilt_heading_vec_is_the_tilt_then_the_heading_correction(decl):
    """The vector parts of tilt_correction(d) and heading_correction_ned(R(T) m) (each checked
    against physics above and below), from |d| given and the heading read off the unnormalised
    tilt: upright, tilted, upside down (the flip) and a field straight along the tilted down."""
    d, m, n = ca.SX.sym("d", 3), ca.SX.sym("m", 3), ca.SX.sym("n")
    ours = _fn([d, n, m], [ca.vertcat(*aiding.tilt_heading_vec(d, n, m, decl))])
    T = aiding.tilt_correction(d)
    H = aiding.heading_correction_ned(quat.rotate_xy_tilt(T, m), decl)
    theirs = _fn([d, m], [ca.vertcat(T[1], T[2], H[3])])
    rng = np.random.default_rng(4)
    cases = [(9.8 * np.array([0.1, -0.05, 1.0]), np.array([20.0, -3.0, 40.0]))]
    for _ in range(20):
        cases.append((rng.normal(size=3) * rng.uniform(0.5, 20), rng.normal(size=3) * rng.uniform(0.2, 60)))
    cases.append((np.array([1e-9, 0.0, -9.8]), np.array([20.0, 5.0, 40.0])))        # flipped
    v = rng.normal(size=3)
    cases.append((v, -3.0 * v / np.linalg.norm(v)))               # no horizontal part once tilted
    for dv, mv in cases:
        got, want = ours(dv, np.linalg.norm(dv), mv)[0], theirs(dv, mv)[0]
        np.testing.assert_allclose(got, want, atol=1e-12)
    assert ours(*cases[-2][:1], 9.8, cases[-2][1])[0][:2] == pytest.approx([1.0, 0.0])
    assert ours(cases[-1][0], np.linalg.norm(cases[-1][0]), cases[-1][1])[0][2] == 0.0


@pytest.mark.parametrize("decl", [0.0, 0.3])
def test_heading_correction_turns_field_north_without_tilting(decl):
    q, m = ca.SX.sym("q", 4), ca.SX.sym("m", 3)
    f = _fn([q, m], [aiding.heading_correction(q, m, decl)])
    rng = np.random.default_rng(1)
    m_n = np.array([0.4 * np.cos(decl), 0.4 * np.sin(decl), 0.3])      # true field, heading decl
    for _ in range(10):
        q_true = nq.qnormalize(rng.normal(size=4))
        err = nq.from_rotvec([0, 0, rng.uniform(-3, 3)])                 # heading error only
        q_est = nq.qmul(err, q_true)
        m_b = nq.rotmat(q_true).T @ m_n
        c = f(q_est, m_b)[0]
        assert c[1] == 0 and c[2] == 0
        fixed = nq.qmul(c, q_est)
        np.testing.assert_allclose(nq.rotmat(fixed) @ m_b, m_n, atol=1e-9)
        # tilt untouched: the body's down direction is the same before and after
        np.testing.assert_allclose(nq.rotmat(fixed).T @ [0, 0, 1], nq.rotmat(q_est).T @ [0, 0, 1], atol=1e-12)


def test_field_check_warmup_averages_then_checks():
    s = [ca.SX.sym(n) for n in ("n", "d", "rn", "rd", "t", "dt", "lt")]
    f = _fn(s, list(aiding.field_check(*s[:6], norm_tol=0.1, dip_tol=0.1, ref_tau=10.0, new_time=2.0,
                                       learn_time=s[6], warmup=1.0)))
    acc, rn, rd, t, lt = f(50.0, 0.8, 0.0, 0.0, 0.0, 0.5, 0.0)          # first sample
    assert (acc[0], rn[0], rd[0], lt[0]) == (1, 50.0, 0.8, 0.5)
    acc, rn, rd, t, lt = f(70.0, 0.6, 50.0, 0.8, 0.0, 0.5, 0.5)         # still warming: accepted, mean
    assert (acc[0], rn[0], lt[0]) == (1, 60.0, 1.0) and rd[0] == pytest.approx(0.7)
    assert f(90.0, 0.7, 60.0, 0.7, 0.0, 0.5, 1.0)[0][0] == 0            # after warm-up: checked
    g = _fn(s, list(aiding.field_check(*s[:6], norm_tol=0.1, dip_tol=0.1, ref_tau=10.0, new_time=2.0,
                                       learn_time=s[6], warmup=0.0)))
    out = g(90.0, 0.7, 60.0, 0.7, 0.0, 0.5, 0.25)                       # warmup 0: learn_time passes through
    assert len(out) == 5 and out[0][0] == 0 and out[4][0] == 0.25
