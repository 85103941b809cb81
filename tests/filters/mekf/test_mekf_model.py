"""MEKF: symbolic Jacobians vs finite differences, CasADi kernels vs the NumPy reference.

The finite differences are taken of propagation / measurement functions written here in
plain NumPy (npquat), not of the CasADi expressions, so the check is independent.
"""
import casadi as ca
import numpy as np
import pytest

from ahrsgen.sim.log import VALID_GPS
from ahrsgen.sim.metrics import max_angle_diff_rad
from ahrsgen.sim.scenarios import make
from ahrsgen import filters
from ahrsgen.filters.mekf import model as M
from ahrsgen.filters.mekf import reference as R
from ahrsgen.npquat import euler_from_q, q_from_euler, qconj, qexp, qmul, wrap



def defaults():
    return filters.load("mekf").defaults()


def euler_params():
    """The patent's Euler-angle measurement (the kernels _kernel_run drives)."""
    return {**defaults(), "measurement": "euler_angles", "heading_source": "gps_course",
            "motion_comp": "centripetal"}


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


@pytest.mark.parametrize("omega_hat,dt", CASES + [(np.array([20.0, -15.0, 8.0]), 0.01),   # |v| > SERIES_MAX
                                               (np.array([1.0, 2.0, 2.0]), 0.0666)])      # |v| at it
def test_closed_form_attitude_rows_match_finite_differences(omega_hat, dt):
    """attitude_rows' closed form (F_q = R(a)ᵀ, F_b = −½ dt J_r; the predict_attitude kernel's)
    against finite differences of the NumPy propagation, on both sides of SERIES_MAX, and q'
    against q ⊗ exp(½ ω̂ dt) normalised."""
    from ahrsgen.npquat import qexp
    qs, w, h = ca.SX.sym("q", 4), ca.SX.sym("w", 3), ca.SX.sym("h")
    f = ca.Function("rows", [qs, w, h], list(M.attitude_rows(qs, w, h)))
    q = q_from_euler(0.3, -0.4, 2.0)
    q_new, Fq, Fb = (np.array(m) for m in f(q, omega_hat, dt))
    F_fd = central_diff(lambda d: np_propagate(d, np.zeros(6), omega_hat, dt), 6)
    assert np.max(np.abs(Fq - F_fd[:3, :3])) < 1e-8
    assert np.max(np.abs(Fb - F_fd[:3, 3:])) < 1e-8
    q_ref = qmul(q, qexp(0.5 * dt * omega_hat))
    assert np.max(np.abs(q_new.ravel() - q_ref / np.linalg.norm(q_ref))) < 1e-14


@pytest.mark.parametrize("b,gyro,dt", [([0.01, -0.02, 0.03], [0.5, -1.0, 2.0], 0.01),
                                       ([0.0] * 3, [3.0, 0.1, -0.2], 0.004),
                                       ([0.1, 0.0, -0.1], [20.0, -15.0, 8.0], 0.01)])   # |v| = 0.13 > SERIES_MAX
def test_closed_form_attitude_rows_are_casadis_jacobians(b, gyro, dt):
    """attitude_rows in the error-state blocks F = [[F_q, F_b], [0, I]], G = [[F_b, 0], [0, I]]
    (model._blocks) and its q' equal CasADi's jacobians of the propagation (jacobians_FG, the
    patent design's) and quat.integrate."""
    q, bs, g, h = ca.SX.sym("q", 4), ca.SX.sym("b", 3), ca.SX.sym("gyro", 3), ca.SX.sym("dt")
    q_new, Fq, Fb = M.attitude_rows(q, g - bs, h)
    q_ref, F, G, _ = M._time_update(filters.load("mekf").defaults(), q, bs, g, h)
    F2, G2 = M._blocks(Fq, Fb)
    check = ca.Function("check", [q, bs, g, h], [F - F2, G - G2, q_new - q_ref])
    for m in check([0.9, 0.1, -0.3, 0.2], b, gyro, dt):
        assert float(ca.mmax(ca.fabs(m))) <= 1e-12


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
    p = euler_params()
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
    p = euler_params()
    fu = M.update_function(p)
    P = np.array(M.initial_P(p))
    for q, usable in (([np.sqrt(0.5), 0, np.sqrt(0.5), 0], False), (list(q_from_euler(0.1, 1.5, 0.3)), True)):
        r = fu(q, np.zeros(3), P, np.zeros(3), [-9.8, 0, 0], np.zeros(3), [20.0, 0, 0], np.zeros(3), [1.0, 1.0, 0.0])
        assert (float(r[3]) > M.S_PIVOT_MIN) == usable


# --- measurement = "vectors": gravity direction and vertical-only heading ------------------
def np_gravity_direction_earth(q, dq):
    """The direction of the specific force at rest seen from the truth [1, δ] ⊗ q (earth-frame
    error δ), rotated to the earth frame by the estimate q: R(q) R([1, δ] ⊗ q)ᵀ [0, 0, -1]."""
    from ahrsgen.npquat import rotmat
    e = qmul(np.concatenate([[1.0], dq]), q)
    return rotmat(q) @ rotmat(e / np.linalg.norm(e)).T @ np.array([0.0, 0.0, -1.0])


ATTITUDES = [(0.1, -0.05, 0.8), (2.5, 1.2, -3.0), (0.3, np.pi / 2, 1.0), (-0.2, -np.pi / 2, 0.0),
             (np.pi, 0.0, 0.4)]


@pytest.mark.parametrize("euler", ATTITUDES)
def test_gravity_H_matches_finite_differences_at_any_attitude(euler):
    """The gravity rows (earth frame x and y) on the earth-frame attitude error stay well
    conditioned at pitch ±90 deg and upside down: the Jacobian (numbers: it does not depend on
    the attitude) matches finite differences of R(q) R([1, δ] ⊗ q)ᵀ u at each attitude, has
    rank 2 (the two tilt directions), and the third (vertical) row it leaves out is 0."""
    q = q_from_euler(*euler)
    H = np.array(M.jacobian_gravity())
    H_fd = central_diff(lambda d: np_gravity_direction_earth(q, d[:3]), 6)
    assert H.shape == (2, 6)
    assert np.max(np.abs(H - H_fd[:2])) < 1e-8
    assert np.max(np.abs(H_fd[2])) < 1e-8
    assert np.linalg.matrix_rank(H[:, :3], tol=1e-6) == 2


def _body_to_earth(q):
    """T = blkdiag(R(q), I): the earth-frame error state [δ, δb] = T [δq, δb]."""
    from ahrsgen.npquat import rotmat
    T = np.eye(6)
    T[:3, :3] = rotmat(q)
    return T


@pytest.mark.parametrize("euler", ATTITUDES[:3])
def test_gravity_update_equals_the_body_axis_batch_update(euler):
    """The two earth-frame rows on the earth-frame error are the body-axis measurement
    (up/|up| in body axes against R(q)ᵀ u, three rows, H = 2 [g_b×] on the body-frame error
    δq, R_g isotropic) in other coordinates: the batch update of the three body rows, in NumPy,
    on P_b = Tᵀ P T, mapped back by T, gives the kernel's correction and P."""
    from ahrsgen.npquat import rotmat
    p = _vec_params(accel_adapt_cap=1.0)
    fu = M.update_gravity_function(p)
    q = q_from_euler(*euler)
    rng = np.random.default_rng(3)
    A = rng.normal(size=(6, 6)) * 0.1
    P = A @ A.T + 1e-3 * np.eye(6)
    up = rotmat(q) @ (rotmat(q_from_euler(euler[0] + 0.05, euler[1] - 0.03, euler[2])).T @ np.array([0.0, 0.0, -9.0]))
    dt = 0.01
    x, P_new, piv = fu(q, up, 0, dt, P.ravel(order="F"))
    Rq, T = rotmat(q), _body_to_earth(q)
    P_b = T.T @ P @ T
    g_b = Rq.T @ np.array([0.0, 0.0, -1.0])
    z = Rq.T @ up / np.linalg.norm(up) - g_b
    H = np.zeros((3, 6))
    H[:, :3] = 2.0 * R.skew(g_b)
    sig2 = p["accel_angle_noise"] ** 2 + p["accel_noise_density"] ** 2 / dt * (
        1 + p["accel_bias_gain"] * (P[3, 3] + P[4, 4] + P[5, 5]) / (3 * p["p0_bias"] ** 2))
    S = H @ P_b @ H.T + sig2 * np.eye(3)
    K = P_b @ H.T @ np.linalg.inv(S)
    assert np.max(np.abs(np.array(x).ravel() - T @ K @ z)) < 1e-12
    assert np.max(np.abs(np.array(P_new).reshape(6, 6) - T @ (P_b - K @ H @ P_b) @ T.T)) < 1e-12
    assert float(piv) > sig2


@pytest.mark.parametrize("n,cap", [(1.2, 3.0), (3.0, 10.0), (0.5, 2.0)])
def test_gravity_variance_doubles_at_accel_adapt_sigmas(n, cap):
    """R_g = σ² min(1 + |z|²/(nσ)², cap), σ² = accel_angle_noise² + accel_noise_density²/dt
    (n = accel_adapt_sigmas), from the equations: a low-passed specific force leaning so that
    the residual |z| = |u - [0, 0, -1]| = 2 sin(θ/2) is n σ doubles σ²; one leaning far more
    gets cap σ²; while recovering from a gyro clip R is σ²."""
    p = _vec_params(accel_adapt_cap=cap, accel_adapt_sigmas=n)
    dt = 0.004
    sig2 = p["accel_angle_noise"] ** 2 + p["accel_noise_density"] ** 2 / dt
    q = [1.0, 0.0, 0.0, 0.0]

    def r_g(theta, recover=0):
        up = 9.8 * np.array([np.sin(theta), 0.0, -np.cos(theta)])
        return float(M.gravity_rows(p, ca.DM(q), ca.DM(up), recover, dt)[2])
    theta = 2 * np.arcsin(n * np.sqrt(sig2) / 2)
    assert abs(r_g(theta) / sig2 - 2.0) < 1e-9
    assert abs(r_g(0.0) / sig2 - 1.0) < 1e-12
    assert abs(r_g(1.5) / sig2 - cap) < 1e-12
    assert abs(r_g(1.5, recover=1) / sig2 - 1.0) < 1e-12


@pytest.mark.parametrize("omega_hat,dt", CASES + [(np.array([20.0, -15.0, 8.0]), 0.01)])
def test_earth_frame_bias_rows_match_finite_differences(omega_hat, dt):
    """predict_attitude's B (F's attitude rows by the bias error, earth-frame attitude error)
    against finite differences of the NumPy propagation of the truth [1, δ] ⊗ q with the rate
    less δb: δ' = vec([1, δ'] ∝ q_t' ⊗ q̂'*), the attitude rows by δ the identity."""
    from ahrsgen.npquat import rotmat
    q = q_from_euler(0.3, -0.4, 2.0)
    b = np.array([0.01, -0.02, 0.005])
    gyro = omega_hat + b
    a = qexp(0.5 * dt * omega_hat)
    q_hat = qmul(q, a)
    q_hat = q_hat / np.linalg.norm(q_hat)

    def propagate(x):
        qt = qmul(qmul(np.concatenate([[1.0], x[:3]]), q), qexp(0.5 * dt * (omega_hat - x[3:])))
        e = qmul(qt, qconj(q_hat))
        return e[1:] / e[0]
    J = central_diff(propagate, 6)
    fp = M.predict_attitude_function(_vec_params())
    q_out, B = (np.array(m).ravel() for m in fp(q, b, gyro, dt))
    assert np.max(np.abs(J[:, :3] - np.eye(3))) < 1e-8
    assert np.max(np.abs(B.reshape(3, 3, order="F") - J[:, 3:])) < 1e-8
    assert np.max(np.abs(q_out - q_hat)) < 1e-14
    assert np.max(np.abs(B.reshape(3, 3, order="F") - rotmat(q_hat) @ R.propagation_jacobians(omega_hat * dt, dt)[0][:3, 3:])) < 1e-12


@pytest.mark.parametrize("euler", ATTITUDES)
def test_heading_H_is_vertical_and_matches_finite_differences(euler):
    """The heading row's Jacobian: finite differences of the twist about the NED vertical of
    the earth-frame error rotation [1, δ] ⊗ q ⊗ q* (at each attitude), [0, 0, 2]: only the
    vertical component."""

    def twist(d):
        e = qmul(qmul(np.concatenate([[1.0], d[:3]]), q), qconj(q))
        return np.array([2 * np.arctan2(e[3], e[0])])
    q = q_from_euler(*euler)
    H = np.array(M.jacobian_heading())
    assert np.max(np.abs(H - central_diff(twist, 6))) < 1e-8
    assert np.max(np.abs(H[0] - [0, 0, 2, 0, 0, 0])) < 1e-12


def _vec_params(**kw):
    return {**defaults(), "declination": 0.1, **kw}


@pytest.mark.parametrize("use_course", [0.0, 1.0])
def test_heading_update_never_tilts_and_keeps_P_spd(use_course):
    """A heading correction with a large innovation and a P with tilt-heading correlation:
    the gravity direction of the estimate is unchanged (gain projected on the vertical),
    heading moves toward the measurement, P stays symmetric positive definite."""
    from ahrsgen.npquat import rotmat
    p = _vec_params()
    fu, fi = M.update_heading_function(p), M.inject_function()
    q = q_from_euler(0.4, -0.3, 0.2)
    rng = np.random.default_rng(1)
    A = rng.normal(size=(6, 6)) * 0.2
    P = A @ A.T + 1e-4 * np.eye(6)
    mag = rotmat(q_from_euler(0.4, -0.3, 1.0)).T @ np.array([20.0, 0.0, 40.0])   # field seen 0.8 rad off
    vel = np.array([10 * np.cos(1.0), 10 * np.sin(1.0), 0.0])
    feat, ref = [np.linalg.norm(mag), 0.9, 0.0, 0.0], [np.linalg.norm(mag), 0.9]   # a clean field
    x, P_new, s = fu(q, P.ravel(order="F"), mag, vel, use_course, 0.01, feat, ref, 0)   # mag at 100 Hz
    q_new = np.array(fi(q, np.zeros(3), x)[0]).ravel()
    P_new = np.array(P_new).reshape(6, 6)
    assert float(s) > M.S_PIVOT_MIN
    assert np.max(np.abs(rotmat(q_new)[2] - rotmat(q)[2])) < 1e-12          # no tilt
    yaw_old, yaw_new = euler_from_q(q)[2], euler_from_q(q_new)[2]
    target = 1.0 + (0.0 if use_course else 0.1)
    assert abs(wrap(target - yaw_new)) < abs(wrap(target - yaw_old))
    assert np.array_equal(P_new, P_new.T)
    assert np.min(np.linalg.eigvalsh(P_new)) > 0


def test_gravity_update_keeps_P_spd_at_vertical_pitch():
    """Gravity rows at pitch 90 deg: usable pivot, P symmetric positive definite, tilt moves
    toward the measured direction (no Euler singularity in this measurement). The gyro bias
    already learned (variance 1e-6, a hundredth of p0_bias²: accel_bias_gain barely weighs)."""
    from ahrsgen.npquat import rotmat
    p = _vec_params()
    fu, fi = M.update_gravity_function(p), M.inject_function()
    q = q_from_euler(0.0, np.pi / 2, 0.3)
    P = np.diag([0.01] * 3 + [1e-6] * 3)
    q_true = q_from_euler(0.0, np.pi / 2 - 0.1, 0.3)
    a_lp = rotmat(q_true).T @ np.array([0.0, 0.0, -9.81])
    a_lp_n = rotmat(q) @ a_lp                       # the kernel takes the earth-frame low-pass
    x, P_new, piv = fu(q, a_lp_n, 0, 0.01, P.ravel())
    assert float(piv) > M.S_PIVOT_MIN
    q_new = np.array(fi(q, np.zeros(3), x)[0]).ravel()
    P_new = np.array(P_new).reshape(6, 6)
    up = lambda qq: rotmat(qq)[2]
    assert np.linalg.norm(up(q_new) - up(q_true)) < 0.5 * np.linalg.norm(up(q) - up(q_true))
    assert np.min(np.linalg.eigvalsh(P_new)) > 0


@pytest.mark.parametrize("dt", [0.08, 0.01, 1 / 400])
def test_lowpass_removes_a_steady_motion_acceleration_exactly(dt):
    """Physics: under a constant kinematic acceleration a (a coordinated turn's centripetal
    term, a linear speed-up) the specific force is f = a - g. Between GPS samples the kernel
    carries the velocity with v += (R f + g) dt, so the low-passed derivative of v is the
    low-passed a, and up = lowpass(f) - lowpass(a) must converge to -g itself at any rate.
    (The first version divided by tau + dt instead of tau and left dt/(tau + dt) of the
    acceleration in up: 7 % at 12.5 Hz, 1.7 deg of tilt in a fixed-wing turn.)"""
    p = defaults()
    fn = M.accel_lowpass_function(p)
    a = np.array([3.0, -1.5, 0.8])                   # m/s^2, NED
    g = np.array([0.0, 0.0, M.G0])
    q = np.array([1.0, 0.0, 0.0, 0.0])               # body = NED: f in body axes = f in NED
    a_lp, v_lp, v_ins, lp_time = np.zeros(3), np.zeros(3), np.zeros(3), 0.0
    for k in range(int(round(15 * p["accel_lpf_tau"] / dt))):
        mask = [1.0, 1.0 if k == 0 else 0.0, 0.0]    # one GPS sample at the start, then none
        out = fn(q=q, b=np.zeros(3), gyro=np.zeros(3), accel=a - g, vel=np.zeros(3), acc_n=np.zeros(3),
                 mask=mask, a_lp=a_lp, v_lp=v_lp, v_ins=v_ins, lp_time=lp_time, dt=dt)
        a_lp, v_lp, v_ins = (np.asarray(out[n]).ravel() for n in ("a_lp_out", "v_lp_out", "v_ins_out"))
        lp_time = float(out["lp_time_out"])
        up = np.asarray(out["up_out"]).ravel()
    assert np.linalg.norm(up - (-g)) < 1e-4 * M.G0, up
