"""A small dense convex QP solver for the per-sample load-distribution problems (pure NumPy/SciPy).

    minimise ½ |R x − d|²   subject to   E x = e,   lo <= C x <= hi

Primal active-set method (Nocedal & Wright, *Numerical Optimization*, 2nd ed., Algorithm 16.3):
from a feasible point, solve the equality-constrained QP on the working set, step until a constraint
blocks, add it; when the step is zero, drop the constraint with the most negative multiplier, or stop
when all multipliers are non-negative (the KKT conditions hold). The least-squares form keeps every
sub-problem bounded below even when RᵀR is singular (the gradient Rᵀ(Rx − d) lies in range(RᵀR)); the
KKT systems are solved in the least-squares sense, so redundant constraints and singular Hessians give
a minimiser of minimum norm. A feasible start is taken from `x0` or from a HiGHS feasibility LP.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .model import CoopsimError


class QPError(CoopsimError):
    """The QP is infeasible or the active-set iteration did not finish."""


class QPResult(NamedTuple):
    """x (n,) the minimiser; active: the working set at x, indices into the one-sided rows (the
    finite upper bounds of C in row order, then the finite lower bounds); iterations: active-set
    steps."""

    x: np.ndarray
    active: list
    iterations: int


def feasible_point(E: np.ndarray, e: np.ndarray, C: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """A point with E x = e and lo <= C x <= hi (HiGHS LP with a zero objective); raises QPError."""
    from scipy.optimize import linprog

    n = C.shape[1] if C.size else E.shape[1]
    A_ub, b_ub = _one_sided(C, lo, hi)
    res = linprog(np.zeros(n), A_ub=A_ub if len(b_ub) else None, b_ub=b_ub if len(b_ub) else None,
                  A_eq=E if len(e) else None, b_eq=e if len(e) else None, bounds=[(None, None)] * n,
                  method="highs")
    if res.status != 0:
        raise QPError(f"no point satisfies the constraints ({res.message})")
    return res.x


def _one_sided(C, lo, hi):
    """Rows G x <= h: C x <= hi (finite hi), −C x <= −lo (finite lo)."""
    up, dn = np.isfinite(hi), np.isfinite(lo)
    G = np.vstack([C[up], -C[dn]]) if C.size else np.zeros((0, 0))
    h = np.concatenate([hi[up], -lo[dn]])
    return G, h


def solve_qp(R: np.ndarray, d: np.ndarray, E: np.ndarray, e: np.ndarray, C: np.ndarray, lo: np.ndarray,
             hi: np.ndarray, x0: np.ndarray | None = None, tol: float = 1e-12, max_iter: int = 200) -> QPResult:
    """Minimise ½|R x − d|² subject to E x = e and lo <= C x <= hi (shapes: R (p, n), d (p,), E (q, n),
    e (q,), C (m, n), lo/hi (m,), ±inf allowed). x0: a feasible start (else found by an LP).
    tol: relative tolerance of the stationarity and feasibility tests."""
    n = R.shape[1]
    E = E.reshape(-1, n)
    C = C.reshape(-1, n)
    G, h = _one_sided(C, lo, hi)
    if x0 is None:
        x0 = feasible_point(E, e, C, lo, hi)
    x = np.array(x0, dtype=float)
    H, g = R.T @ R, -R.T @ d
    scale = max(1.0, float(np.max(np.abs(H))) if H.size else 1.0)
    gscale = max(1.0, float(np.max(np.abs(G))) if G.size else 1.0)
    slack_tol = tol * max(1.0, float(np.max(np.abs(h))) if h.size else 1.0)
    work = [i for i in range(len(h)) if h[i] - G[i] @ x <= slack_tol]
    work = _independent(E, G, work)
    for it in range(max_iter):
        B = np.vstack([E, G[work]]) if work else E
        p, lam = _eqp(H, H @ x + g, B)
        if np.max(np.abs(p), initial=0.0) <= tol * max(1.0, float(np.max(np.abs(x)))):
            mult = lam[len(E):]
            if not work or np.min(mult) >= -tol * scale * gscale:
                return QPResult(x, work, it)
            work.pop(int(np.argmin(mult)))
            continue
        Gp = G @ p
        alpha, block = 1.0, None
        for i in range(len(h)):
            if i not in work and Gp[i] > tol * gscale * np.max(np.abs(p)):
                step = (h[i] - G[i] @ x) / Gp[i]
                if step < alpha:
                    alpha, block = max(step, 0.0), i
        x = x + alpha * p
        if block is not None:
            work.append(block)
    raise QPError(f"active-set iteration did not converge in {max_iter} steps")


def _eqp(H: np.ndarray, grad: np.ndarray, B: np.ndarray):
    """Step p and multipliers λ of min ½pᵀHp + gradᵀp s.t. B p = 0 (KKT, least squares):
    [H Bᵀ; B 0][p; λ] = [−grad; 0]."""
    n, k = H.shape[0], B.shape[0]
    K = np.block([[H, B.T], [B, np.zeros((k, k))]])
    sol = np.linalg.lstsq(K, np.concatenate([-grad, np.zeros(k)]), rcond=None)[0]
    return sol[:n], sol[n:]


def _independent(E: np.ndarray, G: np.ndarray, work: list) -> list:
    """The largest prefix-greedy subset of `work` whose rows, with E, are linearly independent."""
    keep, rows = [], [r for r in E]
    for i in work:
        trial = np.array(rows + [G[i]])
        if np.linalg.matrix_rank(trial) == len(trial):
            keep.append(i)
            rows.append(G[i])
    return keep
