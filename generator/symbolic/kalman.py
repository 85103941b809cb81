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
"""
from __future__ import annotations

import casadi as ca

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
    """P⁻ = F P Fᵀ + G Q Gᵀ (patent step 2), symmetrised by averaging unless told not to
    (a caller that keeps only one triangle saves the averaging)."""
    Pn = ca.mtimes([F, P, F.T]) + ca.mtimes([G, Q, G.T])
    return linalg.symmetrize(Pn) if symmetrize else Pn


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
