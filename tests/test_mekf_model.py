"""MEKF: symbolic Jacobians vs finite differences, CasADi kernels vs the NumPy reference.

The finite differences are taken of propagation / measurement functions written here in
plain NumPy (npquat), not of the CasADi expressions, so the check is independent.
"""
import casadi as ca
import numpy as np
import pytest

from firmware_sim.log import VALID_GPS
from firmware_sim.metrics import max_angle_diff_rad
from firmware_sim.scenarios import make
from generator import filters
from generator.filters.mekf import model as M
from generator.filters.mekf import reference as R
from generator.npquat import euler_from_q, q_from_euler, qconj, qexp, qmul, wrap



def defaults():
    return filters.load("mekf").defaults()


# --- independent NumPy versions of the functions the Jacobians linearise ---------------
def np_propagate(x, noise, omega_hat, dt):
    """[1, δq'] ∝ a* ⊗ [1, δq] ⊗ exp(½(ω̂ − δb − n_g)dt), a = exp(½ ω̂ dt); δb' = δb + n_b."""
    a = qexp(0.5 * dt * omega_hat)
    e = qmul(qmul(qconj(a), np.concatenate([[1.0], x[:3]])),
             qexp(0.5 * dt * (omega_hat - x[3:] - noise[:3])))
    return np.concatenate([e[1:] / e[0], x[3:] + noise[3:]])


def np_measure(q, dq):
    e = qmul(q, np.concatenate([[1.0], dq]))
    return euler_from_q(e / np.linalg.norm(e))


def central_diff(fun, n, h=1e-6, angles=False):
    cols = []
    for i in range(n):
        d = np.zeros(n)
        d[i] = h
        diff = fun(d) - fun(-d)
        cols.append((wrap(diff) if angles else diff) / (2 * h))
    return np.stack(cols, axis=1)


CASES = [  # (omega_hat rad/s, dt s)
    (np.array([0.3, -0.2, 0.5]), 0.08),
    (np.array([2.0, 1.0, -3.0]), 0.01),
    (np.array([1e-7, 0.0, -2e-7]), 0.08),      # small-angle branch of the exponential
    (np.array([0.0, 0.0, 0.0]), 0.02),
]


@pytest.mark.parametrize("omega_hat,dt", CASES)
def test_F_G_match_finite_differences(omega_hat, dt):
    w = ca.SX.sym("w", 3)
    h = ca.SX.sym("h")
    F, G = M.jacobians_FG(w, h)
    fF = ca.Function("F", [w, h], [F, G])
    Fs, Gs = (np.array(m) for m in fF(omega_hat, dt))
    F_fd = central_diff(lambda d: np_propagate(d, np.zeros(6), omega_hat, dt), 6)
    G_fd = central_diff(lambda d: np_propagate(np.zeros(6), d, omega_hat, dt), 6)
    assert np.max(np.abs(Fs - F_fd)) < 1e-8
    assert np.max(np.abs(Gs - G_fd)) < 1e-8
    # and the reference's hand-derived Jacobians agree with both
    F_ref, G_ref = R.propagation_jacobians(omega_hat * dt, dt)
    assert np.max(np.abs(F_ref - Fs)) < 1e-12
    assert np.max(np.abs(G_ref - Gs)) < 1e-12


@pytest.mark.parametrize("euler", [(0.1, -0.05, 0.8), (-0.49, -0.056, 0.78), (2.5, 1.2, -3.0),
                                   (0.0, 0.0, np.pi)])
def test_H_matches_finite_differences(euler):
    q = q_from_euler(*euler)
    qs = ca.SX.sym("q", 4)
    fH = ca.Function("H", [qs], [M.jacobian_H(qs)])
    Hs = np.array(fH(q))
    H_fd = central_diff(lambda d: np_measure(q, d[:3]), 6, angles=True)
    assert Hs.shape == (3, 6)
    assert np.max(np.abs(Hs - H_fd)) < 1e-7
    assert np.max(np.abs(Hs - R.measurement_jacobian(q))) < 1e-12


def _kernel_run(p, log):
    """Drive the CasADi kernels the way the C step does (checks done in NumPy here)."""
    fp, fu, fi = M.predict_function(p), M.update_function(p), M.init_function(p)
    q = np.array([1.0, 0, 0, 0])
    b = np.zeros(3)
    P = np.array(M.initial_P(p))
    v = np.zeros(3)
    age = 1e30
    init = False
    out = np.empty((len(log), 4))
    for k in range(len(log)):
        dt, g, a, val = log.dt[k], log.gyro[k], log.accel[k], int(log.valid[k])
        gps = bool(val & VALID_GPS)
        if gps:
            v = log.gps_vel[k].copy()
            age = 0.0
        else:
            age += dt
        sp = np.hypot(v[0], v[1])
        course = gps and sp >= p["gps_min_speed"] and sp > 0
        if not init:
            q = np.array(fi(a, np.zeros(3), v, float(course))).ravel()
            init = True
        else:
            r = fp(q, b, P, g, dt)
            q, P = np.array(r[0]).ravel(), np.array(r[1]).ravel()
            mask = [1.0, float(course), float(age <= p["gps_vel_timeout"])]
            r = fu(q, b, P, g, a, np.zeros(3), v, np.zeros(3), mask)
            assert float(r[3]) > M.S_PIVOT_MIN
            q, b, P = (np.array(r[i]).ravel() for i in range(3))
        out[k] = q
    return out


def test_kernels_match_reference_on_fixedwing():
    p = defaults()
    log = make("fixedwing_gps", 0, duration=120.0)
    qs, _, _ = R.run(p, log)
    assert max_angle_diff_rad(_kernel_run(p, log), qs) < 1e-12


def test_sym_lower_mirrors_exactly():
    v = ca.SX.sym("v", 36)
    f = ca.Function("f", [v], [M.flat_mirrored(M.sym_lower(v) * 2)])
    x = np.arange(36.0)
    y = np.array(f(x)).reshape(6, 6)
    assert np.array_equal(y, y.T)
    assert np.array_equal(np.tril(y), np.tril(2 * x.reshape(6, 6).T))  # lower triangle, column-major


def test_update_refuses_at_vertical_pitch():
    """At pitch exactly 90 deg the Euler Jacobian is infinite: the kernel flags it (pivot < 0)."""
    p = defaults()
    fu = M.update_function(p)
    P = np.array(M.initial_P(p))
    for q, usable in (([np.sqrt(0.5), 0, np.sqrt(0.5), 0], False), (list(q_from_euler(0.1, 1.5, 0.3)), True)):
        r = fu(q, np.zeros(3), P, np.zeros(3), [-9.8, 0, 0], np.zeros(3), [20.0, 0, 0], np.zeros(3), [1.0, 1.0, 0.0])
        assert (float(r[3]) > M.S_PIVOT_MIN) == usable
