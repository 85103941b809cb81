"""Fixed-size linear algebra as fully unrolled CasADi expressions (no loops, no inverse).

Every function takes small dense matrices (casadi SX, or DM/NumPy for evaluation) whose
sizes are known when the model is built, and returns expressions made only of +, -, *, /,
sqrt, fmax/fmin and if_else, so the emitter turns them into straight-line C.

Safety (the generated C must never produce NaN from a bad covariance):

- `cholesky` never takes the square root of a non-positive number. A pivot at or below
  `tol` is replaced by 1 (the factor is then garbage, but finite), and the smallest pivot
  is returned so the caller can test `min_pivot > tol` and skip or repair the update.
- The triangular solves divide only by the diagonal of such a factor, which is either
  sqrt(pivot > tol) or 1, so they stay finite for finite input.

Cost for n x n (m right-hand sides), counted in the unrolled expression:
  cholesky:      n sqrt, n(n-1)/2 div, ~n^3/6 mul
  solve_lower:   n*m div, ~n^2 m / 2 mul  (same for solve_upper)
  spd_solve:     cholesky + two triangular solves.
With reciprocals (`cholesky_with_inverse`, `spd_solve(..., reciprocal=True)`) every division
by a diagonal element becomes a multiplication by 1/L_jj = sqrt(1/d_j): n div + n sqrt in
all, the rest multiplications (a division costs ~14 cycles on a Cortex-M4F, a multiply 1).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from ahrsgen.constants import use


def _as_casadi(A):
    """Return (matrix, constructor) keeping SX/MX/DM as they are, NumPy/lists -> DM."""
    if isinstance(A, (ca.SX, ca.MX, ca.DM)):
        return A, type(A)
    return ca.DM(np.asarray(A, dtype=float)), ca.DM


def _zeros(kind, n, m):
    return kind.zeros(n, m)


def cholesky(A, tol: float = 0.0):
    """Lower Cholesky factor L (A = L Lᵀ) of a symmetric n x n matrix, and the smallest pivot.

    Only the lower triangle of A is read. Returns (L, min_pivot): min_pivot is the
    smallest value d_j = A_jj - sum_k L_jk² met during the factorisation; A is
    numerically positive definite (to `tol`) iff min_pivot > tol. Where a pivot is
    <= tol, L_jj = 1 is used instead of sqrt(d_j) so that the result stays finite.
    """
    tol = use(tol)      # a named constant (ahrsgen.constants) or a number
    A, kind = _as_casadi(A)
    n = A.shape[0]
    if A.shape[1] != n:
        raise ValueError(f"cholesky needs a square matrix, got {A.shape}")
    L = [[None] * n for _ in range(n)]
    min_pivot = None
    for j in range(n):
        d = A[j, j]
        for k in range(j):
            d = d - L[j][k] * L[j][k]
        ok = d > tol
        ljj = ca.sqrt(ca.if_else(ok, d, 1.0))   # sqrt argument always positive
        L[j][j] = ljj
        min_pivot = d if min_pivot is None else ca.fmin(min_pivot, d)
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s = s - L[i][k] * L[j][k]
            L[i][j] = s / ljj
    out = _zeros(kind, n, n)
    for i in range(n):
        for j in range(i + 1):
            out[i, j] = L[i][j]
    return out, min_pivot


def cholesky_with_inverse(A, tol: float = 0.0):
    """As `cholesky`, also returning the reciprocals of the diagonal: (L, inv_diag, min_pivot).

    inv_diag[j] = 1/L_jj = sqrt(1/d_j) (1 where the pivot is refused), computed once so that
    L's off-diagonal entries and later triangular solves multiply instead of divide.
    """
    tol = use(tol)      # a named constant (ahrsgen.constants) or a number
    A, kind = _as_casadi(A)
    n = A.shape[0]
    if A.shape[1] != n:
        raise ValueError(f"cholesky needs a square matrix, got {A.shape}")
    L = [[None] * n for _ in range(n)]
    inv = [None] * n
    min_pivot = None
    for j in range(n):
        d = A[j, j]
        for k in range(j):
            d = d - L[j][k] * L[j][k]
        d_safe = ca.if_else(d > tol, d, 1.0)
        inv[j] = ca.sqrt(1.0 / d_safe)
        L[j][j] = d_safe * inv[j]
        min_pivot = d if min_pivot is None else ca.fmin(min_pivot, d)
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s = s - L[i][k] * L[j][k]
            L[i][j] = s * inv[j]
    out = _zeros(kind, n, n)
    inv_out = _zeros(kind, n, 1)
    for i in range(n):
        inv_out[i] = inv[i]
        for j in range(i + 1):
            out[i, j] = L[i][j]
    return out, inv_out, min_pivot


def solve_lower(L, B, inv_diag=None):
    """X with L X = B by forward substitution (L lower triangular n x n, B n x m).

    With inv_diag (the reciprocals of L's diagonal) it multiplies instead of dividing."""
    L, kind = _as_casadi(L)
    B, _ = _as_casadi(B)
    n = L.shape[0]
    if B.shape[0] != n:
        raise ValueError(f"solve_lower: L is {L.shape}, B is {B.shape}")
    m = B.shape[1]
    X = [[None] * m for _ in range(n)]
    for c in range(m):
        for i in range(n):
            s = B[i, c]
            for k in range(i):
                s = s - L[i, k] * X[k][c]
            X[i][c] = s / L[i, i] if inv_diag is None else s * inv_diag[i]
    out = _zeros(kind, n, m)
    for i in range(n):
        for c in range(m):
            out[i, c] = X[i][c]
    return out


def solve_upper(U, B, inv_diag=None):
    """X with U X = B by back substitution (U upper triangular n x n, B n x m).

    With inv_diag (the reciprocals of U's diagonal) it multiplies instead of dividing."""
    U, kind = _as_casadi(U)
    B, _ = _as_casadi(B)
    n = U.shape[0]
    if B.shape[0] != n:
        raise ValueError(f"solve_upper: U is {U.shape}, B is {B.shape}")
    m = B.shape[1]
    X = [[None] * m for _ in range(n)]
    for c in range(m):
        for i in reversed(range(n)):
            s = B[i, c]
            for k in range(i + 1, n):
                s = s - U[i, k] * X[k][c]
            X[i][c] = s / U[i, i] if inv_diag is None else s * inv_diag[i]
    out = _zeros(kind, n, m)
    for i in range(n):
        for c in range(m):
            out[i, c] = X[i][c]
    return out


def spd_solve(A, B, tol: float = 0.0, reciprocal: bool = False):
    """X = A⁻¹ B for symmetric positive definite A, through its Cholesky factor.

    Returns (X, min_pivot); X is meaningful only when min_pivot > tol (it is finite
    either way for finite input). reciprocal=True: n divisions in all (see module doc).
    """
    if reciprocal:
        L, inv, min_pivot = cholesky_with_inverse(A, tol)
        return solve_upper(L.T, solve_lower(L, B, inv), inv), min_pivot
    L, min_pivot = cholesky(A, tol)
    Y = solve_lower(L, B)
    X = solve_upper(L.T, Y)
    return X, min_pivot


def lower_symmetric(P):
    """The symmetric matrix whose lower triangle is P's (the upper triangle is not read)."""
    P, kind = _as_casadi(P)
    n = P.shape[0]
    out = _zeros(kind, n, n)
    for i in range(n):
        for j in range(i + 1):
            out[i, j] = P[i, j]
            out[j, i] = P[i, j]
    return out


def packed_lower_pairs(n: int) -> list[tuple[int, int]]:
    """(row, column) of the lower triangle of an n x n matrix in packed order: column by
    column, each from the diagonal down (LAPACK's 'L' packed storage), n(n+1)/2 entries."""
    return [(r, c) for c in range(n) for r in range(c, n)]


def pack_lower(P):
    """The lower triangle of P as a packed column vector (packed_lower_pairs order)."""
    P, kind = _as_casadi(P)
    pairs = packed_lower_pairs(P.shape[0])
    out = _zeros(kind, len(pairs), 1)
    for k, (r, c) in enumerate(pairs):
        out[k] = P[r, c]
    return out


def unpack_symmetric(v, n: int):
    """The symmetric n x n matrix whose lower triangle is the packed vector v."""
    v, kind = _as_casadi(v)
    out = _zeros(kind, n, n)
    for k, (r, c) in enumerate(packed_lower_pairs(n)):
        out[r, c] = v[k]
        out[c, r] = v[k]
    return out


def symmetrize(P):
    """(P + Pᵀ) / 2."""
    P, _ = _as_casadi(P)
    return 0.5 * (P + P.T)


def joseph_update(P, K, H, R, HP=None, S=None, symmetric: bool = True):
    """Joseph-form covariance update (I − K H) P (I − K H)ᵀ + K R Kᵀ, evaluated expanded as

        P − K (H P) − (H P)ᵀ Kᵀ + K S Kᵀ,   S = H P Hᵀ + R

    (the same matrix for any K, so it keeps the Joseph form's robustness to a gain that is
    not exactly optimal), symmetrised unless symmetric=False. HP and S may be passed when the
    gain computation already has them.

    Why expanded: the textbook order forms I − K H, whose entries are |K||H| in size. When a
    precise measurement has a large H (an Euler angle near pitch ±90°: H ∝ 1/cos θ) along
    a direction P already knows well, |K H| reaches hundreds while P⁺ has eigenvalues
    ~1e-8 of |P|: the products of (I − K H) P (I − K H)ᵀ are then |K H|² |P| large and
    cancel to the small result, and in float their rounding (|K H|² |P| ε ~ 1e-5) makes P⁺
    indefinite. In the expanded order every term is of the size of P, K H P or K S Kᵀ,
    which for the optimal gain are all bounded by |P|.
    """
    P, kind = _as_casadi(P)
    if HP is None:
        HP = ca.mtimes(H, P)
    if S is None:
        S = ca.mtimes(HP, H.T) + R
    KHP = ca.mtimes(K, HP)
    Pn = P - KHP - KHP.T + ca.mtimes([K, S, K.T])
    return symmetrize(Pn) if symmetric else Pn
