"""symbolic/kalman.py: masked update = reduced update, gain vs NumPy, Joseph keeps P SPD,
jacobian_at vs finite differences."""
import casadi as ca
import numpy as np
import pytest

from ahrsgen.symbolic import kalman


def _spd(rng, n):
    A = rng.normal(size=(n, n))
    return A @ A.T + n * np.eye(n) * 0.1


def _update_fn(n, m, symmetrize=True):
    P = ca.SX.sym("P", n, n)
    H = ca.SX.sym("H", m, n)
    z = ca.SX.sym("z", m)
    r = ca.SX.sym("r", m)
    mask = ca.SX.sym("mask", m)
    Hm, zm, R = kalman.mask_rows(H, z, [r[i] for i in range(m)], [mask[i] for i in range(m)])
    dx, Pn, piv = kalman.update(P, Hm, zm, R, 1e-12, symmetrize)
    return ca.Function("u", [P, H, z, r, mask], [dx, Pn, piv])


def _numpy_update(P, H, z, R):
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    I_KH = np.eye(len(P)) - K @ H
    return K @ z, I_KH @ P @ I_KH.T + K @ R @ K.T


@pytest.mark.parametrize("mask", [(1, 1, 1), (1, 1, 0), (0, 0, 1), (1, 0, 1), (0, 1, 0)])
def test_masked_update_equals_reduced_update(mask):
    rng = np.random.default_rng(sum(mask))
    n, m = 6, 3
    P, H = _spd(rng, n), rng.normal(size=(m, n))
    z, r = rng.normal(size=m), rng.uniform(0.01, 0.5, m)
    f = _update_fn(n, m)
    dx, Pn, piv = (np.array(v) for v in f(P, H, z, r, np.array(mask, float)))
    rows = [i for i in range(m) if mask[i]]
    dx_ref, P_ref = _numpy_update(P, H[rows], z[rows], np.diag(r[rows]))
    assert np.allclose(dx.ravel(), dx_ref, rtol=1e-10, atol=1e-12)
    assert np.allclose(Pn, P_ref, rtol=1e-10, atol=1e-12)
    assert piv.item() > 0


def test_all_rows_masked_changes_nothing():
    rng = np.random.default_rng(1)
    P, H = _spd(rng, 6), rng.normal(size=(3, 6))
    dx, Pn, _ = (np.array(v) for v in _update_fn(6, 3)(P, H, rng.normal(size=3), np.ones(3), np.zeros(3)))
    assert np.all(dx == 0)
    assert np.allclose(Pn, P, rtol=0, atol=1e-15)


def test_joseph_keeps_spd_with_precise_measurements():
    """200 updates with measurements 1e-11 times less noisy than the prior: P stays
    symmetric positive definite (Joseph form, symmetrised)."""
    rng = np.random.default_rng(5)
    f = _update_fn(6, 3)
    P = _spd(rng, 6) * 1e3
    for _ in range(200):
        H = rng.normal(size=(3, 6))
        _, P, _ = (np.array(v) for v in f(P, H, rng.normal(size=3), np.full(3, 1e-8), np.ones(3)))
        P = P + np.eye(6) * 1e-9
        assert np.all(np.linalg.eigvalsh(0.5 * (P + P.T)) > 0)
        assert np.abs(P - P.T).max() == 0.0        # symmetrised


def test_jacobian_at_matches_finite_differences():
    x = ca.SX.sym("x", 3)
    w = ca.SX.sym("w", 2)
    expr = ca.vertcat(ca.sin(x[0] + w[0]) * ca.exp(x[1]), x[2] ** 3 + w[1] * x[0] + ca.cos(w[1]))
    J = kalman.jacobian_at(expr, x, [x])
    f = ca.Function("J", [w], [J])
    g = ca.Function("g", [x, w], [expr])
    wv = np.array([0.3, -0.7])
    h = 1e-6
    fd = np.stack([(np.array(g(h * e, wv)) - np.array(g(-h * e, wv))).ravel() / (2 * h) for e in np.eye(3)], 1)
    assert np.allclose(np.array(f(wv)), fd, atol=1e-8)


def test_predict_covariance():
    rng = np.random.default_rng(2)
    P, F, G, Q = _spd(rng, 6), rng.normal(size=(6, 6)), rng.normal(size=(6, 6)), np.diag(rng.uniform(0, 1, 6))
    out = np.array(ca.DM(kalman.predict_covariance(ca.DM(P), ca.DM(F), ca.DM(G), ca.DM(Q))))
    assert np.allclose(out, F @ P @ F.T + G @ Q @ G.T, rtol=1e-12)


def test_predict_covariance_with_unit_rows():
    """An error-state F = [[A, B], [0, I]]: the entries read from F P instead of multiplied."""
    rng = np.random.default_rng(3)
    F = np.block([[rng.normal(size=(3, 6))], [np.zeros((3, 3)), np.eye(3)]])
    P, G, Q = _spd(rng, 6), rng.normal(size=(6, 6)), np.diag(rng.uniform(0, 1, 6))
    Ps, Fs = ca.SX.sym("P", 6, 6), ca.SX(F)
    for i in range(3):
        for j in range(6):
            Fs[i, j] = ca.SX.sym(f"f{i}{j}")
    syms = ca.vertcat(*[Fs[i, j] for i in range(3) for j in range(6)])
    f = ca.Function("p", [Ps, syms], [kalman.predict_covariance(Ps, Fs, ca.DM(G), ca.DM(Q))])
    out = np.array(f(P, F[:3].ravel()))
    assert np.array_equal(out, out.T)
    assert np.allclose(out, F @ P @ F.T + G @ Q @ G.T, rtol=1e-12, atol=1e-14)
    assert f.n_instructions() < ca.Function("q", [Ps, syms], [ca.mtimes([Fs, Ps, Fs.T])]).n_instructions()


def _scalar_fn(n, rows_h, x_in):
    """kalman.scalar_updates over rows with the given H (0 entries structural) as a Function."""
    P, z, r, x = ca.SX.sym("P", n, n), ca.SX.sym("z", len(rows_h)), ca.SX.sym("r", len(rows_h)), ca.SX.sym("x", n)
    hs = [ca.SX(ca.DM(h).T) for h in rows_h]
    dx, Pn, piv = kalman.scalar_updates(P, [(hs[i], z[i], r[i]) for i in range(len(hs))], x if x_in else None, 1e-12)
    return ca.Function("s", [P, z, r, x], [dx, Pn, piv])


def test_scalar_updates_equal_the_batch_update():
    """Rows in turn, in two groups chained through x (as the MEKF step calls them: three
    general rows, then three [0 I] rows), equal the batch update of all six rows stacked; the
    smallest row variance is the smallest squared Cholesky pivot of the batch S."""
    rng = np.random.default_rng(4)
    n = 6
    for trial in range(5):
        P = _spd(rng, n) * 10.0 ** rng.uniform(-4, 0)
        H1 = np.hstack([rng.normal(size=(3, 3)), np.zeros((3, 3))])
        H2 = np.hstack([np.zeros((3, 3)), np.eye(3)])
        z = rng.normal(size=6) * 0.1
        r = np.concatenate([rng.uniform(0.01, 1, 3), rng.uniform(1e-6, 1e-3, 3)])
        x1, P1, piv1 = _scalar_fn(n, H1, False)(P, z[:3], r[:3], np.zeros(n))
        x2, P2, piv2 = _scalar_fn(n, H2, True)(P1, z[3:], r[3:], x1)
        H = np.vstack([H1, H2])
        dx, P_ref = _numpy_update(P, H, z, np.diag(r))
        assert np.allclose(np.array(x2).ravel(), dx, rtol=1e-9, atol=1e-14)
        assert np.allclose(np.array(P2), P_ref, rtol=1e-9, atol=1e-14 * np.max(np.abs(P)))
        assert np.array_equal(np.array(P2), np.array(P2).T)
        S = H @ P @ H.T + np.diag(r)
        pivots = np.diag(np.linalg.cholesky(S)) ** 2
        assert np.isclose(min(float(piv1), float(piv2)), np.min(pivots), rtol=1e-9)


def test_scalar_updates_bias_rows_read_columns():
    """A row [0 .. 1 .. 0] multiplies nothing for P hᵀ: three such rows cost no more than the
    P - k uᵀ products (21 per row), the gain and x (6 + 6 per row) and a few scalars."""
    f = _scalar_fn(6, np.hstack([np.zeros((3, 3)), np.eye(3)]), True)
    muls = sum(f.instruction_id(k) == ca.OP_MUL for k in range(f.n_instructions()))
    assert muls <= 3 * (21 + 6 + 6)


def test_joseph_row_equals_textbook_joseph_for_any_gain():
    """One row, a gain that is not the optimal one (projected, as the MEKF heading row's):
    P - k w^T - w k^T, w = u - s k / 2, equals (I - k h) P (I - k h)^T + k r k^T."""
    rng = np.random.default_rng(5)
    n = 6
    P, h = _spd(rng, n), rng.normal(size=n)
    r = 0.3
    u = P @ h
    s = h @ u + r
    k = (u / s) * rng.uniform(0.2, 1.5, n)              # any gain
    Ps, ks, us, ss = ca.SX.sym("P", n, n), ca.SX.sym("k", n), ca.SX.sym("u", n), ca.SX.sym("s")
    f = ca.Function("j", [Ps, ks, us, ss], [kalman.joseph_row(Ps, ks, us, ss)])
    out = np.array(f(P, k, u, s))
    I_kh = np.eye(n) - np.outer(k, h)
    assert np.array_equal(out, out.T)
    assert np.allclose(out, I_kh @ P @ I_kh.T + r * np.outer(k, k), rtol=1e-12, atol=1e-12)
