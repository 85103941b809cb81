"""Kalman-filter building blocks as unrolled CasADi SX expressions (no filter imports here).

Error-state Jacobians are taken with CasADi's `jacobian` of the caller's propagation or
measurement function and evaluated at the linearisation point (error state and noise = 0),
so no Jacobian is typed by hand. The gain uses the fixed-size Cholesky solve of
`linalg.py` (no general inverse); the covariance update is the Joseph form (evaluated expanded, see
linalg.joseph_update), symmetrised.

Rows that are not measured this step are handled by a *mask* instead of separate kernels:
a masked row has H row = 0, innovation = 0 and R = 1, which makes its gain column exactly
zero and leaves P, the state and the other rows untouched (S is block-diagonal in that row,
so the Cholesky solve decouples it). One kernel then serves every subset of rows.

`scalar_updates` is the other way to take rows with a diagonal R: one at a time (one
division per row, no Cholesky), each group of rows in its own kernel that the caller runs
only when that group is measured; `joseph_row` is the Joseph form of one row for any gain.
"""
from __future__ import annotations

import casadi as ca

from ahrsgen.constants import use

from . import linalg


def jacobian_at(expr, wrt, zero_vars):
    """d expr / d wrt evaluated with every symbol in `zero_vars` set to 0.

    `wrt` and the members of `zero_vars` are SX symbol vectors (the linearisation point of an
    error-state filter: error state and noise = 0).

    Forward mode (one directional derivative per column of `wrt`), always: reverse mode
    accumulates adjoints through shared nodes without the branch masks, so a branch that is
    not taken (the sqrt of a squared norm at 0 inside a small-angle switch, for instance)
    gives 0 * inf = NaN; forward mode keeps every such term behind its if_else.
    """
    n = wrt.shape[0]
    J = ca.jtimes(expr, wrt, ca.SX.eye(n))
    syms = ca.vertcat(*zero_vars)
    return ca.substitute(J, syms, ca.SX.zeros(syms.shape[0], 1))


def predict_covariance(P, F, G, Q, symmetrize: bool = True):
    """P⁻ = F P Fᵀ + G Q Gᵀ (patent step 2), as an exactly symmetric matrix.

    Only the lower triangle is computed, and each entry from whichever side of the symmetry
    is cheaper: (F P Fᵀ)_ij = Σ_k (F P)_ik F_jk = Σ_k (F P)_jk F_ik, so where row j (or i) of F
    is a unit row the entry is an element of F P, free (an error-state F = [[A, B], [0, I]]
    gives its bias block and cross block that way, computed once). `symmetrize` is kept for
    callers: the result is exactly symmetric either way.
    """
    n = P.shape[0]
    FP = ca.mtimes(F, P)
    GQGt = ca.mtimes([G, Q, G.T])
    out = ca.SX.zeros(n, n)

    def row_cost(j):
        return 0 if _unit_row(F, j) is not None else sum(not F[j, k].is_zero() for k in range(n))

    def entry(a, j):                       # Σ_k (F P)_ak F_jk, skipping F's structural zeros
        unit = _unit_row(F, j)
        if unit is not None:
            return FP[a, unit]
        terms = [FP[a, k] * F[j, k] for k in range(n) if not F[j, k].is_zero()]
        return ca.sum1(ca.vertcat(*terms)) if terms else ca.SX(0)

    for j in range(n):
        for i in range(j, n):
            e = entry(i, j) if row_cost(j) <= row_cost(i) else entry(j, i)
            out[i, j] = e + GQGt[i, j]
            out[j, i] = out[i, j]
    return out


def _unit_row(F, j):
    """k if row j of F is the unit row e_k (structurally), else None."""
    nz = [k for k in range(F.shape[1]) if not F[j, k].is_zero()]
    return nz[0] if len(nz) == 1 and F[j, nz[0]].is_one() else None


def mask_rows(H, z, r, mask):
    """Masked measurement: rows with mask 0 get H row 0, z 0, R 1 (mask entries are 0/1 symbols).

    H (m x n), z (m), r (m, variances), mask (m). Returns (H_m, z_m, R_m). The innovation
    is masked by a select, not a product, so a masked row's z may be inf/NaN without effect;
    H is masked by a product (cheaper) and must be finite.
    """
    m = H.shape[0]
    Hm = ca.SX(H)
    zm = ca.SX.zeros(m, 1)
    R = ca.SX.zeros(m, m)
    for i in range(m):
        Hm[i, :] = mask[i] * H[i, :]
        zm[i] = ca.if_else(mask[i], z[i], 0.0)
        R[i, i] = ca.if_else(mask[i], r[i], 1.0)
    return Hm, zm, R


def gain(P, H, R, tol: float = 0.0):
    """K = P Hᵀ (H P Hᵀ + R)⁻¹ through a Cholesky solve; returns (K, S, min_pivot).

    K is meaningful only where min_pivot > tol (it is finite either way for finite input).
    """
    K, _, S, min_pivot = _gain(P, H, R, tol)
    return K, S, min_pivot


def _gain(P, H, R, tol):
    HP = ca.mtimes(H, P)                              # = (P Hᵀ)ᵀ, P symmetric
    S = linalg.symmetrize(ca.mtimes(HP, H.T) + R)
    KT, min_pivot = linalg.spd_solve(S, HP, tol)      # S Kᵀ = H P  (P, S symmetric)
    return KT.T, HP, S, min_pivot


def joseph(P, K, H, R, symmetrize: bool = True, HP=None, S=None):
    """P⁺ = (I − K H) P (I − K H)ᵀ + K R Kᵀ (patent step 6), evaluated in the expanded order
    of linalg.joseph_update (float-safe with large H), symmetrised unless told not to."""
    return linalg.joseph_update(P, K, H, R, HP=HP, S=S, symmetric=symmetrize)


def update(P, H, z, R, tol: float = 0.0, symmetrize: bool = True):
    """Full Kalman correction: returns (dx = K z, P⁺ (Joseph), min_pivot of S)."""
    K, HP, S, min_pivot = _gain(P, H, R, tol)
    return ca.mtimes(K, z), joseph(P, K, H, R, symmetrize, HP=HP, S=S), min_pivot


def scalar_updates(P, rows, x=None, tol: float = 0.0):
    """Sequential scalar corrections: the rows of a measurement with a diagonal R, one at a
    time. Returns (x, P⁺ (exactly symmetric), min_pivot).

    P (n x n, only its lower triangle is read); rows: [(h, z, r)], h a 1 x n row (its
    structural zeros cost nothing: a bias row [0 I] reads a column of P), z the innovation
    at the linearisation point, r its variance; x the correction accumulated by earlier rows
    (None: 0). For a measurement linearised once (H, z fixed) and R diagonal this is the
    batch update with the rows stacked, in exact arithmetic: row i uses the innovation
    z_i − h_i x, and its variance s_i = h_i P h_iᵀ + r_i is the i-th pivot of the batch S's
    Cholesky factorisation (squared), so min_pivot > tol exactly when the batch test passes.

    Per row, u = P hᵀ, k = u / s, x ← x + k (z − h x), P ← P − k uᵀ (lower triangle, then
    mirrored). Every term is of the size of P (u_i² ≤ P_ii s), as in the expanded Joseph
    form. One division per row; a pivot at or below tol takes 1 for 1/s (a finite result,
    to be discarded).
    """
    tol = use(tol)      # a named constant (ahrsgen.constants) or a number
    n = P.shape[0]
    Pl = [[P[max(i, j), min(i, j)] for j in range(n)] for i in range(n)]
    x = [ca.SX(0)] * n if x is None else [x[i] for i in range(n)]
    min_pivot = None
    for h, z, r in rows:
        nz = [k for k in range(n) if not h[k].is_zero()]
        u = [_dot([Pl[i][k] for k in nz], [h[k] for k in nz]) for i in range(n)]
        s = _dot([h[k] for k in nz], [u[k] for k in nz]) + r
        min_pivot = s if min_pivot is None else ca.fmin(min_pivot, s)
        inv_s = ca.if_else(s > tol, 1.0 / s, 1.0)   # a select: k = u * inv_s stays a product
        k_gain = [u[i] * inv_s for i in range(n)]
        innov = z - _dot([h[k] for k in nz], [x[k] for k in nz])
        x = [x[i] + k_gain[i] * innov for i in range(n)]
        for j in range(n):
            for i in range(j, n):
                Pl[i][j] = Pl[i][j] - k_gain[i] * u[j]
                Pl[j][i] = Pl[i][j]
    Pn = ca.SX.zeros(n, n)
    for i in range(n):
        for j in range(n):
            Pn[i, j] = Pl[max(i, j)][min(i, j)]
    return ca.vertcat(*x), Pn, min_pivot


def _dot(a, b):
    """Σ a_k b_k, with a factor that is structurally 1 not multiplied."""
    terms = [bk if ak.is_one() else (ak if bk.is_one() else ak * bk) for ak, bk in zip(a, b)]
    out = terms[0]
    for t in terms[1:]:
        out = out + t
    return out


def joseph_row(P, k, u, s):
    """Joseph form for one row h with any gain k: (I − k h) P (I − k h)ᵀ + k r kᵀ
    = P − k uᵀ − u kᵀ + s k kᵀ (u = P hᵀ, s = h u + r) = P − k wᵀ − w kᵀ, w = u − (s/2) k:
    two products per entry of the lower triangle, every term of the size of P (as
    linalg.joseph_update's expanded order). Returns an exactly symmetric n x n matrix."""
    n = P.shape[0]
    w = [u[i] - (0.5 * s) * k[i] for i in range(n)]
    out = ca.SX.zeros(n, n)
    for j in range(n):
        for i in range(j, n):
            out[i, j] = P[i, j] - k[i] * w[j] - w[i] * k[j]
            out[j, i] = out[i, j]
    return out
