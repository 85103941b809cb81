"""Fixed-size Cholesky, triangular solves and SPD solve (src/ahrsgen/symbolic/linalg.py)
checked against numpy.linalg on random SPD matrices, well- and ill-conditioned.

The symbolic expressions are built once per size as SX functions and evaluated by CasADi
(double). Error bounds are the textbook ones for a backward-stable method: the relative
forward error of a solve is at most ~ c * n * cond(A) * eps.
"""
from __future__ import annotations

import functools

import casadi as ca
import numpy as np
import pytest

from ahrsgen.symbolic import linalg

EPS = np.finfo(float).eps


def random_spd(rng, n, cond):
    """SPD matrix with the given 2-norm condition number (random orthogonal eigenbasis)."""
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    eig = np.logspace(0, -np.log10(cond), n) * rng.uniform(0.1, 10.0)
    A = (Q * eig) @ Q.T
    return 0.5 * (A + A.T)


@functools.lru_cache(maxsize=None)
def chol_fun(n, tol=0.0):
    A = ca.SX.sym("A", n, n)
    L, mp = linalg.cholesky(A, tol)
    return ca.Function("chol", [A], [L, mp])


@functools.lru_cache(maxsize=None)
def chol_inv_fun(n, tol=0.0):
    A = ca.SX.sym("A", n, n)
    L, inv, mp = linalg.cholesky_with_inverse(A, tol)
    return ca.Function("chol_inv", [A], [L, inv, mp])


@functools.lru_cache(maxsize=None)
def solve_fun(n, m, reciprocal=False):
    A = ca.SX.sym("A", n, n)
    B = ca.SX.sym("B", n, m)
    X, mp = linalg.spd_solve(A, B, 0.0, reciprocal)
    return ca.Function("spd_solve", [A, B], [X, mp])


@functools.lru_cache(maxsize=None)
def tri_funs(n, m):
    L = ca.SX.sym("L", n, n)
    B = ca.SX.sym("B", n, m)
    return (ca.Function("lo", [L, B], [linalg.solve_lower(L, B)]),
            ca.Function("up", [L, B], [linalg.solve_upper(L, B)]))


SIZES = [1, 2, 3, 4, 6]
CONDS = [1.0, 1e2, 1e6, 1e10]


@pytest.mark.parametrize("n", SIZES)
@pytest.mark.parametrize("cond", CONDS)
def test_cholesky_matches_numpy(n, cond):
    rng = np.random.default_rng(1000 * n + int(np.log10(cond)))
    f = chol_fun(n)
    for _ in range(20):
        A = random_spd(rng, n, cond)
        L, mp = (np.array(x) for x in f(A))
        L_np = np.linalg.cholesky(A)
        assert np.all(np.triu(L, 1) == 0.0)
        # backward error: A - L Lᵀ tiny relative to |A|
        assert np.linalg.norm(A - L @ L.T) <= 10 * n * EPS * np.linalg.norm(A)
        # forward error of the factor, bounded through the condition number
        rel = np.linalg.norm(L - L_np) / np.linalg.norm(L_np)
        assert rel <= 10 * n * cond * EPS, rel
        assert mp.item() > 0.0
        # the smallest pivot is the smallest squared diagonal of the factor
        assert mp.item() == pytest.approx(np.min(np.diag(L_np) ** 2), rel=10 * n * cond * EPS + 1e-13)
        Lr, inv, mpr = (np.array(x) for x in chol_inv_fun(n)(A))
        assert np.linalg.norm(A - Lr @ Lr.T) <= 10 * n * EPS * np.linalg.norm(A)
        assert np.linalg.norm(Lr - L_np) / np.linalg.norm(L_np) <= 10 * n * cond * EPS
        np.testing.assert_allclose(inv.ravel(), 1.0 / np.diag(L_np), rtol=10 * n * cond * EPS)
        assert mpr.item() == pytest.approx(mp.item(), rel=10 * n * cond * EPS, abs=1e-300)


@pytest.mark.parametrize("n", SIZES)
@pytest.mark.parametrize("cond", CONDS)
@pytest.mark.parametrize("m", [1, 4])
@pytest.mark.parametrize("reciprocal", [False, True])
def test_spd_solve_matches_numpy(n, cond, m, reciprocal):
    rng = np.random.default_rng(7 + 100 * n + m + int(np.log10(cond)))
    f = solve_fun(n, m, reciprocal)
    for _ in range(20):
        A = random_spd(rng, n, cond)
        B = rng.standard_normal((n, m))
        X, mp = (np.array(x) for x in f(A, B))
        X_np = np.linalg.solve(A, B)
        rel = np.linalg.norm(X - X_np) / np.linalg.norm(X_np)
        assert rel <= 10 * n * cond * EPS, rel
        # residual is small whatever the conditioning
        assert np.linalg.norm(A @ X - B) <= 100 * n * EPS * np.linalg.norm(A) * np.linalg.norm(X)


@pytest.mark.parametrize("n", [1, 3, 6])
def test_triangular_solves(n):
    rng = np.random.default_rng(n)
    lo, up = tri_funs(n, 2)
    for _ in range(20):
        L = np.tril(rng.standard_normal((n, n))) + np.diag(rng.uniform(1, 3, n))
        B = rng.standard_normal((n, 2))
        X = np.array(lo(L, B))
        np.testing.assert_allclose(L @ X, B, atol=1e-12 * np.abs(B).max() * np.linalg.cond(L))
        U = L.T
        # solve_upper must read only the upper triangle: garbage below must not matter
        U_dirty = U + np.tril(rng.standard_normal((n, n)), -1)
        Y = np.array(up(U_dirty, B))
        np.testing.assert_allclose(U @ Y, B, atol=1e-12 * np.abs(B).max() * np.linalg.cond(U))


@pytest.mark.parametrize("n", [2, 4, 6])
def test_not_positive_definite_is_flagged_and_finite(n):
    rng = np.random.default_rng(42 + n)
    f = chol_fun(n)
    g = solve_fun(n, 1)
    gr = solve_fun(n, 1, True)
    cases = []
    A = random_spd(rng, n, 10.0)
    w, V = np.linalg.eigh(A)
    w[0] = -abs(w[0])                      # one negative eigenvalue: indefinite
    cases.append((V * w) @ V.T)
    w[0] = 0.0                             # singular positive semidefinite
    cases.append((V * w) @ V.T)
    cases.append(-np.eye(n))               # negative definite
    cases.append(np.zeros((n, n)))         # all zero
    C = random_spd(rng, n, 1.0)
    C[n - 1, n - 1] = -1.0                 # last pivot negative
    cases.append(C)
    for A in cases:
        L, mp = (np.array(x) for x in f(A))
        X, mp2 = (np.array(x) for x in g(A, np.ones((n, 1))))
        Xr, mp3 = (np.array(x) for x in gr(A, np.ones((n, 1))))
        assert np.all(np.isfinite(L)) and np.all(np.isfinite(X)) and np.all(np.isfinite(Xr))
        assert mp.item() == mp2.item()
        assert mp3.item() <= 1e-12 * max(1.0, np.abs(A).max())
        # flagged: the smallest pivot is not safely positive (a PSD singular matrix may
        # leave a round-off sized pivot of either sign)
        assert mp.item() <= 1e-12 * max(1.0, np.abs(A).max()), (A, mp.item())


def test_tolerance_flags_nearly_singular():
    """With tol > 0 a pivot below tol is refused (factor stays finite)."""
    A = np.diag([1.0, 1e-14, 2.0])
    L, mp = (np.array(x) for x in chol_fun(3, 1e-12)(A))
    assert mp.item() == pytest.approx(1e-14)
    assert np.all(np.isfinite(L)) and L[1, 1] == 1.0
    L0, mp0 = (np.array(x) for x in chol_fun(3, 0.0)(A))
    assert L0[1, 1] == pytest.approx(1e-7)


def test_reads_lower_triangle_only():
    rng = np.random.default_rng(3)
    A = random_spd(rng, 4, 100.0)
    A_dirty = np.tril(A) + np.triu(rng.standard_normal((4, 4)), 1)
    L, _ = (np.array(x) for x in chol_fun(4)(A_dirty))
    np.testing.assert_allclose(L, np.linalg.cholesky(A), rtol=1e-12, atol=1e-14)



def test_lower_symmetric_mirrors_the_lower_triangle_and_ignores_the_upper():
    rng = np.random.default_rng(5)
    A = rng.standard_normal((5, 5))
    S = np.array(linalg.lower_symmetric(A))
    np.testing.assert_array_equal(S, np.tril(A) + np.tril(A, -1).T)
    P = ca.SX.sym("P", 3, 3)          # symbolic: no upper-triangle symbol is read
    deps = ca.symvar(linalg.lower_symmetric(P))
    assert {str(d) for d in deps} == {str(P[i, j]) for i in range(3) for j in range(i + 1)}

def test_joseph_update_matches_textbook_and_stays_spd():
    rng = np.random.default_rng(5)
    n, m = 6, 3
    P = random_spd(rng, n, 1e3)
    H = rng.standard_normal((m, n))
    R = random_spd(rng, m, 10.0)
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    Pj = np.array(linalg.joseph_update(ca.DM(P), ca.DM(K), ca.DM(H), ca.DM(R)))
    np.testing.assert_allclose(Pj, P - K @ S @ K.T, rtol=1e-9, atol=1e-12 * np.abs(P).max())
    assert np.array_equal(Pj, Pj.T)
    assert np.min(np.linalg.eigvalsh(Pj)) > 0


def test_works_on_dm_and_numpy():
    A = np.array([[4.0, 2.0], [2.0, 3.0]])
    L, mp = linalg.cholesky(A)
    np.testing.assert_allclose(np.array(L), np.linalg.cholesky(A))
    X, _ = linalg.spd_solve(A, np.array([[1.0], [2.0]]))
    np.testing.assert_allclose(np.array(X).ravel(), np.linalg.solve(A, [1.0, 2.0]))


# ---- the same expressions emitted as C (float and double), compiled, called through ctypes --

import ctypes  # noqa: E402
import subprocess  # noqa: E402

from ahrsgen.codegen import emit  # noqa: E402

C_SIZES = (3, 4, 6)
C_NRHS = 4


@functools.lru_cache(maxsize=None)
def c_lib(precision):
    """Shared library with chol<n> and spd_solve<n> kernels for n in C_SIZES."""
    from ahrsgen.sim.host import CACHE, STRICT, cc
    parts = ["#include <math.h>", ""]
    for n in C_SIZES:
        A = ca.SX.sym("A", n, n)
        B = ca.SX.sym("B", n, C_NRHS)
        L, mp = linalg.cholesky(A)
        X, mp2 = linalg.spd_solve(A, B)
        Xr, mp3 = linalg.spd_solve(A, B, 0.0, reciprocal=True)
        for fn in (emit.function(f"chol{n}", {"A": A}, {"L": L, "min_pivot": mp}),
                   emit.function(f"spd_solve{n}", {"A": A, "B": B}, {"X": X, "min_pivot": mp2}),
                   emit.function(f"spd_solve_r{n}", {"A": A, "B": B}, {"X": Xr, "min_pivot": mp3})):
            parts.append(emit.emit(fn, precision).source(storage=""))
            parts.append("")
    src = "\n".join(parts)
    d = CACHE / "linalg_test"
    d.mkdir(parents=True, exist_ok=True)
    import hashlib
    h = hashlib.sha256((src + precision).encode()).hexdigest()[:16]
    c_file, so = d / f"linalg_{h}.c", d / f"linalg_{h}.so"
    if not so.exists():
        c_file.write_text(src)
        r = subprocess.run([cc(), *STRICT, "-Wno-missing-prototypes", "-O2", "-fPIC", "-shared",
                            "-ffp-contract=off", str(c_file), "-o", str(so), "-lm"],
                           capture_output=True, text=True)
        assert r.returncode == 0 and r.stderr == "", r.stderr
    return ctypes.CDLL(str(so))


def c_call(precision, name, *arrays, outs):
    """Call a kernel: matrices passed column-major; outs = list of (rows, cols)."""
    dt = np.float32 if precision == "float" else np.float64
    args = [np.ascontiguousarray(np.asarray(a, dtype=dt).ravel(order="F")) for a in arrays]
    res = [np.zeros(r * c, dtype=dt) for r, c in outs]
    fn = getattr(c_lib(precision), name)
    fn.restype = None
    fn(*[a.ctypes.data_as(ctypes.c_void_p) for a in args + res])
    return [x.reshape((c, r)).T.astype(float) for x, (r, c) in zip(res, outs)]


# float: condition numbers up to 1e5 (eps_f * 1e5 ~ 1e-2 relative); double up to 1e10
C_CASES = [("double", c) for c in (1.0, 1e3, 1e6, 1e10)] + [("float", c) for c in (1.0, 1e2, 1e4, 1e5)]


@pytest.mark.parametrize("precision, cond", C_CASES)
@pytest.mark.parametrize("n", C_SIZES)
def test_c_cholesky_and_solve_match_numpy(precision, cond, n):
    eps = float(np.finfo(np.float32 if precision == "float" else np.float64).eps)
    rng = np.random.default_rng(99 + n + int(np.log10(cond)))
    for _ in range(20):
        A = random_spd(rng, n, cond)
        B = rng.standard_normal((n, C_NRHS))
        if precision == "float":   # compare against the exact answer for the rounded input
            A = A.astype(np.float32).astype(float)
            B = B.astype(np.float32).astype(float)
        L, mp = c_call(precision, f"chol{n}", A, outs=[(n, n), (1, 1)])
        L_np = np.linalg.cholesky(A)
        assert np.all(np.isfinite(L)) and mp.item() > 0
        assert np.linalg.norm(A - L @ L.T) <= 10 * n * eps * np.linalg.norm(A)
        assert np.linalg.norm(L - L_np) / np.linalg.norm(L_np) <= 10 * n * cond * eps
        X_np = np.linalg.solve(A, B)
        for name in ("spd_solve", "spd_solve_r"):
            X, mp2 = c_call(precision, f"{name}{n}", A, B, outs=[(n, C_NRHS), (1, 1)])
            assert np.linalg.norm(X - X_np) / np.linalg.norm(X_np) <= 10 * n * cond * eps, name
            assert mp2.item() == pytest.approx(mp.item(), rel=float(10 * n * cond * eps))


@pytest.mark.parametrize("precision", ["float", "double"])
def test_c_not_positive_definite_is_flagged_and_finite(precision):
    rng = np.random.default_rng(11)
    for n in C_SIZES:
        A = random_spd(rng, n, 10.0)
        w, V = np.linalg.eigh(A)
        w[0] = -abs(w[0])
        for bad in ((V * w) @ V.T, -np.eye(n), np.zeros((n, n))):
            L, mp = c_call(precision, f"chol{n}", bad, outs=[(n, n), (1, 1)])
            X, _ = c_call(precision, f"spd_solve{n}", bad, np.ones((n, C_NRHS)), outs=[(n, C_NRHS), (1, 1)])
            Xr, _ = c_call(precision, f"spd_solve_r{n}", bad, np.ones((n, C_NRHS)), outs=[(n, C_NRHS), (1, 1)])
            assert np.all(np.isfinite(L)) and np.all(np.isfinite(X)) and np.all(np.isfinite(Xr))
            assert mp.item() <= 0.0
