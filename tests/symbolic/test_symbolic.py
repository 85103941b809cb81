"""The CasADi building blocks against independent NumPy code and ahrs' FQA."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from ahrsgen import npquat as nq
from ahrsgen.filters.qcf import reference as qref
from ahrsgen.symbolic import attitude, quat

rng = np.random.default_rng(7)
q4 = ca.SX.sym("q", 4)
p4 = ca.SX.sym("p", 4)
v3 = ca.SX.sym("v", 3)
f3 = ca.SX.sym("f", 3)
m3 = ca.SX.sym("m", 3)


def random_q():
    return nq.qnormalize(rng.normal(size=4))


def test_qmul_rotate_euler_match_numpy():
    mul = ca.Function("mul", [p4, q4], [quat.qmul(p4, q4)])
    rot = ca.Function("rot", [q4, v3], [quat.rotate(q4, v3), quat.rotate_inv(q4, v3)])
    eul = ca.Function("eul", [q4], [quat.euler(q4)])
    for _ in range(20):
        p, q, v = random_q(), random_q(), rng.normal(size=3)
        np.testing.assert_allclose(np.array(mul(p, q)).ravel(), nq.qmul(p, q), atol=1e-15)
        # rotation as the sandwich product q ⊗ [0 v] ⊗ q*
        sandwich = nq.qmul(nq.qmul(q, np.r_[0, v]), nq.qconj(q))[1:]
        a, b = rot(q, v)
        np.testing.assert_allclose(np.array(a).ravel(), sandwich, atol=1e-14)
        np.testing.assert_allclose(np.array(b).ravel(), nq.rotmat(q).T @ v, atol=1e-14)
        np.testing.assert_allclose(np.array(eul(q)).ravel(), nq.euler_from_q(q), atol=1e-12)


def test_euler_round_trip_and_wrap():
    fe = ca.Function("fe", [v3], [quat.from_euler(v3[0], v3[1], v3[2])])
    eul = ca.Function("eul", [q4], [quat.euler(q4)])
    for _ in range(50):
        rpy = np.array([rng.uniform(-3.1, 3.1), rng.uniform(-1.5, 1.5), rng.uniform(-3.1, 3.1)])
        np.testing.assert_allclose(np.array(eul(fe(rpy))).ravel(), rpy, atol=1e-12)
    a = ca.SX.sym("a")
    w = ca.Function("w", [a], [quat.wrap(a)])
    for val, exp in [(np.pi, np.pi), (-np.pi, np.pi), (3 * np.pi, np.pi), (2 * np.pi - 0.1, -0.1), (0.3, 0.3)]:
        assert float(w(val)) == pytest.approx(exp, abs=1e-12)
    # 359 deg - 1 deg wraps to -2 deg, never 358
    assert float(w(np.radians(359) - np.radians(1))) == pytest.approx(np.radians(-2), abs=1e-12)


def test_exponential_is_exact_rotation_and_smooth_at_zero():
    ex = ca.Function("ex", [v3], [quat.qexp(v3)])
    for scale in [0.0, 1e-9, 1e-5, 9e-5, 1.1e-4, 1e-2, 0.0999, 0.1001, 1.0, 3.0]:
        r = rng.normal(size=3)
        r = r / np.linalg.norm(r) * scale
        got = np.array(ex(r)).ravel()
        n = np.linalg.norm(r)
        exact = np.r_[np.cos(n), np.sin(n) / n * r] if n > 0 else np.r_[1.0, r]
        np.testing.assert_allclose(got, exact, atol=1e-15, rtol=1e-14)


@pytest.mark.parametrize("small_arg", [False, True])
def test_exponential_series_truncation_is_below_its_stated_bound(small_arg):
    """At the series' edge the truncated sum differs from the exact cos and sinc by no more
    than the first neglected term (|v|^2K/(2K)!, |v|^2K/(2K+1)!) plus double round-off, and that
    term is below double round-off; just beyond the edge the exact form (small_arg: the shorter
    series below SMALL_SERIES_MAX)."""
    import math
    ex = ca.Function("ex", [v3], [quat.qexp(v3, small_arg=small_arg)])
    top, K = ((quat.SMALL_SERIES_MAX, quat.SMALL_SERIES_TERMS) if small_arg
              else (quat.SERIES_MAX, quat.SERIES_TERMS))
    n = float(top) * (1 - 1e-12)
    got = np.array(ex(np.r_[n, 0.0, 0.0])).ravel()
    assert n ** (2 * K) / math.factorial(2 * K) < 1.1e-16
    assert abs(got[0] - math.cos(n)) <= n ** (2 * K) / math.factorial(2 * K) + 2e-16
    assert abs(got[1] / n - math.sin(n) / n) <= n ** (2 * K) / math.factorial(2 * K + 1) + 2e-16
    for m in (float(top) * (1 + 1e-9), 0.3 * float(top)):
        got = np.array(ex(np.r_[0.0, m, 0.0])).ravel()
        np.testing.assert_allclose(got, [math.cos(m), 0.0, math.sin(m), 0.0], atol=2e-16)


@pytest.mark.parametrize("small_arg", [False, True])
def test_float_cut_of_the_exponential_series_stays_below_a_sixteenth_ulp(small_arg):
    """Under series_precision("float") qexp and qexp_factors drop the series' tail: evaluated in
    double over the series' range, cos, sin/x and k = (x - sin x cos x)/x^3 (qexp_factors) stay
    within 2^-27 (1/16 of float's ulp at 1) of the exact values, and the cut really shortens the
    series (fewer terms than double's, whose expressions are unchanged by the block)."""
    import math
    top = float(quat.SMALL_SERIES_MAX if small_arg else quat.SERIES_MAX)
    with quat.series_precision("float"):
        ex = ca.Function("ex", [v3], [quat.qexp(v3, small_arg=small_arg)])
        cf, sf, kf = quat.qexp_factors(v3)
        fa = ca.Function("fa", [v3], [cf, sf, kf])
    full = ca.Function("full", [v3], [quat.qexp(v3, small_arg=small_arg)])
    assert ex.n_instructions() < full.n_instructions()
    for n in np.linspace(0.0, top * (1 - 1e-12), 41):
        got = np.array(ex(np.r_[n, 0.0, 0.0])).ravel()
        sinc = math.sin(n) / n if n > 0 else 1.0
        assert abs(got[0] - math.cos(n)) <= 2.0 ** -27
        assert abs((got[1] / n if n > 0 else 1.0) - sinc) <= 2.0 ** -27 or n == 0.0
        if not small_arg:
            c, s_, k = (float(x) for x in fa(np.r_[n, 0.0, 0.0]))
            k_exact = (n - math.sin(n) * math.cos(n)) / n ** 3 if n > 1e-3 else 2 / 3 - 2 * n * n / 15
            assert abs(c - math.cos(n)) <= 2.0 ** -27 and abs(s_ - sinc) <= 2.0 ** -27
            assert abs(k - k_exact) <= 2.0 ** -27 * 2 / 3 + 1e-12


def test_scaled_exponential_is_a_positive_multiple_of_the_exact_one():
    """qexp_scaled normalised equals exp([0, v]) on both sides of SERIES_MAX (the cot series
    and the exact form), and at the edge its series is within the stated neglected term."""
    ex = ca.Function("ex", [v3], [quat.qexp_scaled(v3)])
    for scale in [0.0, 1e-9, 1e-5, 1e-2, 0.0999, 0.1001, 1.0, 3.0]:
        r = rng.normal(size=3)
        r = r / np.linalg.norm(r) * scale
        got = np.array(ex(r)).ravel()
        n = np.linalg.norm(r)
        exact = np.r_[np.cos(n), np.sin(n) / n * r] if n > 0 else np.r_[1.0, r]
        assert got @ exact > 0                                  # a positive multiple: the same rotation sign
        np.testing.assert_allclose(got / np.linalg.norm(got), exact, atol=1e-15, rtol=1e-14)
    n = quat.SERIES_MAX * (1 - 1e-12)
    got = np.array(ex(np.r_[n, 0.0, 0.0])).ravel()
    assert abs(got[0] - n / np.tan(n)) <= 1382 * n ** 12 / 638512875 + 2e-16


def test_near_unit_normalisation_is_within_its_stated_error():
    """qnormalize_near_unit against q/|q| (NumPy): within NEAR_UNIT_MAX of |q|^2 = 1 the Newton
    step's relative error is 3/8 eps^2 (+ O(eps^3)), below half a float ulp (2^-25) at the
    threshold; beyond it the exact quotient."""
    f = ca.Function("nu", [q4], [quat.qnormalize_near_unit(q4)])
    bound = float(quat.NEAR_UNIT_MAX)
    assert 3 / 8 * bound ** 2 < 2.0 ** -25
    for eps in (1e-7, -3e-6, 1e-4, -0.9 * bound, 0.99 * bound, 2 * bound, -0.3, 5.0):
        u = random_q()
        q = u * np.sqrt(1 + eps)
        got = np.array(f(q)).ravel()
        err = np.linalg.norm(got - u)
        if abs(eps) < bound:
            assert err <= 3 / 8 * eps ** 2 * (1 + 2 * abs(eps)) + 1e-15, eps
        else:
            assert err < 1e-15, eps


def test_wrap_by_comparison_equals_floor_wrap_on_its_domain():
    a = ca.SX.sym("a")
    w = ca.Function("w", [a], [quat.wrap(a)])
    x = np.random.default_rng(3).uniform(-3 * np.pi + 1e-9, 3 * np.pi, 2000)
    got = np.array(w(x.reshape(1, -1))).ravel()
    np.testing.assert_allclose(got, x + 2 * np.pi * np.floor((np.pi - x) / (2 * np.pi)), atol=1e-15)


def _fqa_cases():
    mn = np.array([np.cos(1.1), 0.0, np.sin(1.1)])
    for _ in range(40):
        rpy = (rng.uniform(-3.1, 3.1), rng.uniform(-1.4, 1.4), rng.uniform(-3.1, 3.1))
        q = nq.q_from_euler(*rpy)
        R = nq.rotmat(q)
        yield q, R.T @ np.array([0, 0, -9.81]), R.T @ (48.0 * mn), mn


def test_fqa_symbolic_equals_numpy_reference_and_truth():
    F = ca.Function("F", [f3, m3], [attitude.fqa(f3, m3)])
    for q, f, m, _ in _fqa_cases():
        got = np.array(F(f, m)).ravel()
        np.testing.assert_allclose(got, qref.fqa(f, m), atol=1e-12)
        assert abs(abs(got @ q) - 1) < 1e-12     # same attitude as the truth (q or -q)


def test_fqa_reference_matches_ahrs_fqa():
    ahrs = pytest.importorskip("ahrs")
    for q, f, m, mn in _fqa_cases():
        # ahrs' FQA takes the same specific-force vector and a NED reference field, and
        # returns the body->NED quaternion (mapping verified on these random attitudes).
        theirs = ahrs.filters.FQA(mag_ref=mn.copy()).estimate(f.copy(), m.copy())
        ours = qref.fqa(f, m)
        if theirs @ ours < 0:
            theirs = -theirs
        np.testing.assert_allclose(ours, theirs, atol=1e-9)


def test_tilt_and_heading_formulas():
    roll_pitch = ca.Function("rp", [f3], list(attitude.tilt_angles(f3)))
    for q, f, m, _ in _fqa_cases():
        r, p, y = nq.euler_from_q(q)
        rr, pp = (float(v) for v in roll_pitch(f))
        assert rr == pytest.approx(r, abs=1e-9) and pp == pytest.approx(p, abs=1e-9)
        h = ca.Function("h", [m3], [attitude.tilt_compensated_heading(m3, r, p)])
        assert float(nq.wrap(float(h(m)) - y)) == pytest.approx(0, abs=1e-9)


def test_exponential_jacobian_through_the_squared_norm():
    """quat.qexp_jacobian (CasADi's derivative taken through m = |v|^2) equals CasADi's direct
    jacobian of qexp and central differences of the exact exponential, on both sides of the
    series switch and at 0."""
    J = ca.Function("J", [v3], [quat.qexp_jacobian(v3)])
    Jd = ca.Function("Jd", [v3], [ca.jacobian(quat.qexp(v3), v3)])

    def exact(r):
        n = np.linalg.norm(r)
        return np.r_[np.cos(n), np.sin(n) / n * r] if n > 0 else np.r_[1.0, r]

    h = 1e-6
    for scale in [0.0, 1e-5, 0.05, 0.0999, 0.1001, 1.0, 3.0]:
        r = rng.normal(size=3)
        r = r / np.linalg.norm(r) * scale
        got = np.array(J(r))
        np.testing.assert_allclose(got, np.array(Jd(r)), atol=1e-15, rtol=1e-13)
        fd = np.column_stack([(exact(r + h * e) - exact(r - h * e)) / (2 * h) for e in np.eye(3)])
        np.testing.assert_allclose(got, fd, atol=1e-8)
