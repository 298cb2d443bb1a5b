"""Small dense convex QPs and LPs for the per-sample load-distribution problems (pure NumPy/SciPy),
one at a time or a batch at once (one per sample of a trajectory).

    minimise ½ |R x − d|²   subject to   E x = e,   lo <= C x <= hi

Primal active-set method (Nocedal & Wright, *Numerical Optimization*, 2nd ed., Algorithm 16.3):
from a feasible point, solve the equality-constrained QP on the working set, step until a constraint
blocks, add it; when the step is zero, drop the constraint with the most negative multiplier, or stop
when all multipliers are non-negative (the KKT conditions hold). The least-squares form keeps every
sub-problem bounded below even when RᵀR is singular (the gradient Rᵀ(Rx − d) lies in range(RᵀR)); the
KKT systems are solved in the least-squares sense, so redundant constraints and singular Hessians give
a minimiser of minimum norm. A feasible start is taken from `x0` or from a HiGHS feasibility LP.

A row with lo = hi is an equality: it stays in every working set (a degenerate vertex where both of
its sides are active would otherwise let the iteration cycle).

A batch (`solve_qps`, one problem per sample of a trajectory) runs the same iteration on every
problem at once, vectorized over the problems not yet finished. The KKT systems of *regular*
problems (E of full row rank, RᵀR positive definite on {E x = 0}, both with condition number below
REGULAR_COND: then every working set's KKT matrix is non-singular) are solved together by LU; the
others one by one in the least-squares sense, as above.

`solve_lps` solves a batch of small LPs as one block-diagonal HiGHS LP.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .model import CoopsimError

REGULAR_COND = 1e8


class QPError(CoopsimError):
    """The QP is infeasible or the active-set iteration did not finish."""


class QPResult(NamedTuple):
    """x (n,) the minimiser; active: the working set at x, indices into the one-sided rows (the
    finite upper bounds of C in row order, then the finite lower bounds); iterations: active-set
    steps."""

    x: np.ndarray
    active: list
    iterations: int


class LPBatch(NamedTuple):
    """Solutions of a batch of N LPs: status (N,) int (linprog's: 0 optimal, 2 infeasible, 3 unbounded,
    other: failed); x (N, v) (nan where not optimal); marginals (N, mu): duals of the inequality rows
    (0 for rows left out, and where not optimal); messages: N strings."""

    status: np.ndarray
    x: np.ndarray
    marginals: np.ndarray
    messages: list


# ------------------------------------------------------------------------------------------------
# LPs
# ------------------------------------------------------------------------------------------------

def _block_diag(A: np.ndarray, keep: np.ndarray):
    """Sparse block-diagonal matrix (keep.sum(), N v) of the blocks A (N, rows, v), rows where keep
    (N, rows); zero entries left out (as linprog stores a dense matrix)."""
    from scipy.sparse import csc_array

    N, rows, v = A.shape
    row_of = (np.cumsum(keep.ravel()) - 1).reshape(N, rows)
    i, r, j = np.nonzero(keep[..., None] & (A != 0))
    return csc_array((A[i, r, j], (row_of[i, r], i * v + j)), shape=(int(keep.sum()), N * v))


def _linprog_blocks(c, A_ub, b_ub, keep, A_eq, b_eq, bounds):
    """One HiGHS LP of the problems stacked block-diagonally (min Σ cᵀx_i); the scipy result."""
    from scipy.optimize import linprog

    N, me = A_eq.shape[:2]
    has_ub = bool(keep.any())
    return linprog(np.tile(c, N), A_ub=_block_diag(A_ub, keep) if has_ub else None,
                   b_ub=b_ub[keep] if has_ub else None, A_eq=_block_diag(A_eq, np.ones((N, me), bool)) if me else None,
                   b_eq=b_eq.ravel() if me else None, bounds=list(bounds) * N, method="highs")


def solve_lps(c: np.ndarray, A_ub: np.ndarray, b_ub: np.ndarray, A_eq: np.ndarray, b_eq: np.ndarray,
              bounds, cap: float = 1e9) -> LPBatch:
    """N independent LPs  min cᵀx  s.t.  A_ub[i] x <= b_ub[i] (rows with non-finite b_ub left out),
    A_eq[i] x = b_eq[i], bounds: c (v,), A_ub (N, mu, v), b_ub (N, mu), A_eq (N, me, v), b_eq (N, me),
    bounds: v pairs (lo, hi), None for none (shared). Solved as one block-diagonal HiGHS LP (each block
    is then optimal on its own: the objective is separable) in which the variables the objective
    drives towards an infinite bound stop at ±cap; the problems that reach it are solved alone, which
    gives their own status (unbounded; cap = inf: no cap); when the combined LP has no optimum, its
    halves are solved in turn down to single problems."""
    N, v = A_eq.shape[0], A_eq.shape[2]
    keep = np.isfinite(b_ub)
    out = LPBatch(np.full(N, -1), np.full((N, v), np.nan), np.zeros(b_ub.shape), [""] * N)
    lo = np.array([-np.inf if b[0] is None else b[0] for b in bounds], float)
    hi = np.array([np.inf if b[1] is None else b[1] for b in bounds], float)
    capped_hi, capped_lo = (c < 0) & (hi > cap), (c > 0) & (lo < -cap)
    capped = [(None if np.isinf(l) else l, None if np.isinf(h) else h)
              for l, h in zip(np.where(capped_lo, -cap, lo), np.where(capped_hi, cap, hi))]

    def solve(idx, with_bounds):
        sol = _linprog_blocks(c, A_ub[idx], b_ub[idx], keep[idx], A_eq[idx], b_eq[idx], with_bounds)
        if sol.status != 0 and len(idx) > 1:
            for half in (idx[:len(idx) // 2], idx[len(idx) // 2:]):
                solve(half, with_bounds)
        elif sol.status != 0 and with_bounds is capped:
            solve(idx, bounds)
        else:
            _store(out, idx, sol, keep[idx])
            if sol.status == 0 and with_bounds is capped:
                x = out.x[idx]
                for i in idx[np.any((capped_hi & (x >= cap / 2)) | (capped_lo & (x <= -cap / 2)), axis=1)]:
                    solve(np.array([i]), bounds)

    solve(np.arange(N), capped)
    return out


def _store(out: LPBatch, idx: np.ndarray, sol, keep: np.ndarray) -> None:
    """Write the combined solution `sol` of the problems idx (rows kept: keep (len(idx), mu)) into out."""
    out.status[idx], out.x[idx], out.marginals[idx] = sol.status, np.nan, 0.0
    for i in idx:
        out.messages[i] = sol.message
    if sol.status == 0:
        out.x[idx] = sol.x.reshape(len(idx), -1)
        marg = np.zeros(keep.shape)
        marg[keep] = sol.ineqlin.marginals
        out.marginals[idx] = marg


def feasible_points(E: np.ndarray, e: np.ndarray, C: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Points (N, n) with E x = e and lo <= C x <= hi for a batch (E (N, q, n), e (N, q), C (N, m, n),
    lo/hi (N, m)): HiGHS LPs with a zero objective; raises QPError naming the first infeasible one."""
    N, n = C.shape[0], C.shape[2]
    G, h, _ = _one_sided(C, lo, hi)
    res = solve_lps(np.zeros(n), G, h, E, e, [(None, None)] * n)
    bad = np.flatnonzero(res.status != 0)
    if len(bad):
        raise QPError(f"no point satisfies the constraints ({res.messages[bad[0]]})")
    return res.x


# ------------------------------------------------------------------------------------------------
# QPs
# ------------------------------------------------------------------------------------------------

def _one_sided(C, lo, hi):
    """Rows G x <= h of a batch: G (N, 2m, n) = [C; −C], h (N, 2m) = [hi; −lo] (the C x <= hi rows
    first, then −C x <= −lo, each in row order), and finite (N, 2m): the rows with a finite bound."""
    h = np.concatenate([hi, -lo], axis=1)
    return np.concatenate([C, -C], axis=1), h, np.isfinite(h)


def solve_qp(R: np.ndarray, d: np.ndarray, E: np.ndarray, e: np.ndarray, C: np.ndarray, lo: np.ndarray,
             hi: np.ndarray, x0: np.ndarray | None = None, tol: float = 1e-12, max_iter: int = 200) -> QPResult:
    """Minimise ½|R x − d|² subject to E x = e and lo <= C x <= hi (shapes: R (p, n), d (p,), E (q, n),
    e (q,), C (m, n), lo/hi (m,), ±inf allowed). x0: a feasible start (else found by an LP).
    tol: relative tolerance of the stationarity and feasibility tests."""
    n = R.shape[1]
    return solve_qps(R[None], np.asarray(d)[None], np.reshape(E, (1, -1, n)), np.asarray(e, float)[None],
                     np.reshape(C, (1, -1, n)), np.asarray(lo, float)[None], np.asarray(hi, float)[None],
                     None if x0 is None else np.asarray(x0)[None], tol, max_iter)[0]


def solve_qps(R: np.ndarray, d: np.ndarray, E: np.ndarray, e: np.ndarray, C: np.ndarray, lo: np.ndarray,
              hi: np.ndarray, x0: np.ndarray | None = None, tol: float = 1e-12, max_iter: int = 200) -> list[QPResult]:
    """`solve_qp` for a batch of N problems: R (N, p, n), d (N, p), E (N, q, n), e (N, q), C (N, m, n),
    lo/hi (N, m), x0 (N, n) or None. Returns one QPResult per problem. A row with lo = hi is an
    equality: its upper row is pinned (in every working set, never dropped), its lower row implied."""
    N, n = R.shape[0], R.shape[2]
    G, h, finite = _one_sided(C, lo, hi)
    eq = np.isfinite(hi) & (lo == hi)
    pinned = np.concatenate([eq, np.zeros_like(eq)], axis=1)
    valid = finite & ~np.concatenate([np.zeros_like(eq), eq], axis=1)
    used = finite.any(axis=0)
    G, h, finite, valid, pinned = (a[:, used] for a in (G, h, finite, valid, pinned))
    G, h = np.where(valid[..., None], G, 0.0), np.where(valid, h, np.inf)
    x = np.array(feasible_points(E, e, C, lo, hi) if x0 is None else x0, dtype=float)
    H, g = np.swapaxes(R, 1, 2) @ R, -np.einsum("npi,np->ni", R, d)
    scale = np.maximum(1.0, np.max(np.abs(H), axis=(1, 2), initial=0.0))
    gscale = np.maximum(1.0, np.max(np.abs(G), axis=(1, 2), initial=0.0))
    slack_tol = tol * np.maximum(1.0, np.max(np.abs(np.where(valid, h, 0.0)), axis=1, initial=0.0))
    work = pinned | (valid & (h - np.einsum("nmi,ni->nm", G, x) <= slack_tol[:, None]))
    work = _independent(E, G, work, pinned)
    order = np.where(work, np.arange(G.shape[1]), -1)             # insertion order in the working set
    regular = _regular(H, E)
    done, iters = np.zeros(N, bool), np.zeros(N, int)
    for it in range(max_iter):
        live = np.flatnonzero(~done)
        if not len(live):
            break
        sol = _eqp(H[live], np.einsum("nij,nj->ni", H[live], x[live]) + g[live], E[live], G[live], work[live],
                   order[live], regular[live])
        p, mult = sol[:, :n], sol[:, n + E.shape[1]:]
        moving = np.max(np.abs(p), axis=1) > tol * np.maximum(1.0, np.max(np.abs(x[live]), axis=1))
        _drop_or_finish(live[~moving], mult[~moving], work, pinned, order, done, iters, it, -tol * scale * gscale)
        _step(live[moving], p[moving], G, h, valid, work, order, x, tol * gscale, it + G.shape[1])
    if not done.all():
        raise QPError(f"active-set iteration did not converge in {max_iter} steps")
    return [QPResult(xi, a, it) for xi, a, it in zip(x, _active_lists(order, work, finite), iters.tolist())]


def _active_lists(order: np.ndarray, work: np.ndarray, valid: np.ndarray) -> list[list]:
    """Working sets (N lists, insertion order) as indices into each problem's finite one-sided rows."""
    index = np.cumsum(valid, axis=1) - 1
    rows = np.argsort(np.where(work, order, np.iinfo(order.dtype).max), axis=1, kind="stable")
    sets = np.take_along_axis(index, rows, axis=1).tolist()
    return [s[:k] for s, k in zip(sets, work.sum(axis=1).tolist())]


def _drop_or_finish(idx, mult, work, pinned, order, done, iters, it, floor) -> None:
    """Problems idx whose step is zero: finished when no working inequality (pinned rows are
    equalities) has a multiplier below floor (N,); else the most negative one (first added on ties)
    leaves."""
    if not len(idx):
        return
    w = work[idx] & ~pinned[idx]
    m = np.where(w, mult, np.inf)
    low = np.min(m, axis=1, initial=np.inf)
    finish = ~w.any(axis=1) | (low >= floor[idx])
    done[idx[finish]], iters[idx[finish]] = True, it
    drop = ~finish
    if drop.any():
        tie = w[drop] & (m[drop] == low[drop, None])
        j = np.argmin(np.where(tie, order[idx[drop]], np.iinfo(order.dtype).max), axis=1)
        work[idx[drop], j], order[idx[drop], j] = False, -1


def _step(idx, p, G, h, valid, work, order, x, thr, stamp) -> None:
    """Problems idx move along p (n_idx, n) until the first blocking constraint (h − G x)/(G p), as the
    sequential scan does: a negative ratio (a row already slightly violated) stops at 0 on the last
    such row; otherwise the smallest ratio below 1 (first on ties); the blocking row joins the set."""
    if not len(idx) or not G.shape[1]:
        x[idx] += p
        return
    Gp = np.einsum("nmi,ni->nm", G[idx], p)
    elig = valid[idx] & ~work[idx] & (Gp > (thr[idx] * np.max(np.abs(p), axis=1))[:, None])
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(elig, (h[idx] - np.einsum("nmi,ni->nm", G[idx], x[idx])) / Gp, np.inf)
    neg = ratio < 0
    last_neg = ratio.shape[1] - 1 - np.argmax(neg[:, ::-1], axis=1)
    first_min = np.argmin(ratio, axis=1)
    has_neg, blocks = neg.any(axis=1), ratio[np.arange(len(idx)), first_min] < 1.0
    block = np.where(has_neg, last_neg, first_min)
    alpha = np.where(has_neg, 0.0, np.where(blocks, ratio[np.arange(len(idx)), first_min], 1.0))
    x[idx] += alpha[:, None] * p
    hit = has_neg | blocks
    work[idx[hit], block[hit]], order[idx[hit], block[hit]] = True, stamp


def _regular(H: np.ndarray, E: np.ndarray) -> np.ndarray:
    """(N,) bool: E (N, q, n) has full row rank and H (N, n, n) is positive definite on its null space,
    both with condition number below REGULAR_COND — then every KKT matrix of the iteration (E and
    independent working rows) is non-singular."""
    N, q, n = E.shape
    if q > n:
        return np.zeros(N, bool)
    if q:
        _, s, Vt = np.linalg.svd(E)
        ok = s[:, -1] > s[:, 0] / REGULAR_COND
        Z = np.swapaxes(Vt[:, q:], 1, 2)
    else:
        ok, Z = np.ones(N, bool), np.broadcast_to(np.eye(n), (N, n, n))
    if q == n:
        return ok
    lam = np.linalg.eigvalsh(np.swapaxes(Z, 1, 2) @ H @ Z)
    return ok & (lam[:, 0] > lam[:, -1] / REGULAR_COND)


def _eqp(H, grad, E, G, work, order, regular):
    """Steps p and multipliers of min ½pᵀHp + gradᵀp s.t. E p = 0, G_w p = 0 for a batch: (N, n + q + M)
    = [p; ν; λ] with λ_j = 0 off the working set. KKT [H Bᵀ; B 0][p; λ] = [−grad; 0], B = [E; G_w]:
    LU for regular problems (all at once, rows off the working set replaced by λ_j = 0), least squares
    (minimum norm) for the others."""
    N, n = grad.shape
    q, M = E.shape[1], G.shape[1]
    out = np.zeros((N, n + q + M))
    reg = np.flatnonzero(regular)
    if len(reg):
        try:
            out[reg] = _kkt_lu(H[reg], grad[reg], E[reg], G[reg], work[reg])
        except np.linalg.LinAlgError:                   # a singular system after all: all by least squares
            regular = np.zeros_like(regular)
    for i in np.flatnonzero(~regular):
        rows = np.flatnonzero(work[i])
        rows = rows[np.argsort(order[i, rows], kind="stable")]
        B = np.vstack([E[i], G[i, rows]])
        k = len(B)
        K = np.block([[H[i], B.T], [B, np.zeros((k, k))]])
        sol = np.linalg.lstsq(K, np.concatenate([-grad[i], np.zeros(k)]), rcond=None)[0]
        out[i, :n + q], out[i, n + q + rows] = sol[:n + q], sol[n + q:]
    return out


def _kkt_lu(H, grad, E, G, work):
    """[p; ν; λ] (N, n + q + M) of the padded KKT systems, solved together by LU: the rows in no
    problem's working set are left out, the others off a problem's set give λ_j = 0."""
    N, n = grad.shape
    q, M = E.shape[1], G.shape[1]
    cols = np.flatnonzero(work.any(axis=0))
    w = work[:, cols]
    GW = G[:, cols] * w[..., None]
    S = n + q + len(cols)
    K = np.zeros((N, S, S))
    K[:, :n, :n], K[:, :n, n:n + q], K[:, n:n + q, :n] = H, np.swapaxes(E, 1, 2), E
    K[:, :n, n + q:], K[:, n + q:, :n] = np.swapaxes(GW, 1, 2), GW
    K[:, np.arange(n + q, S), np.arange(n + q, S)] = ~w
    rhs = np.zeros((N, S, 1))
    rhs[:, :n, 0] = -grad
    sol = np.linalg.solve(K, rhs)[..., 0]
    out = np.zeros((N, n + q + M))
    out[:, :n + q], out[:, n + q + cols] = sol[:, :n + q], sol[:, n + q:]
    return out


def _independent(E: np.ndarray, G: np.ndarray, work: np.ndarray, pinned: np.ndarray) -> np.ndarray:
    """The largest greedy subset of each problem's working rows — the pinned ones first, each group in
    row order — that, with E, is linearly independent (numpy's matrix_rank tolerance on
    [E; kept; candidate])."""
    keep = np.zeros_like(work)
    q, n = E.shape[1], E.shape[2]
    for group in (work & pinned, work & ~pinned):
        for j in np.flatnonzero(group.any(axis=0)):
            idx = np.flatnonzero(group[:, j])
            trial = np.concatenate([E[idx], G[idx] * keep[idx][..., None], G[idx, j:j + 1]], axis=1)
            s = np.linalg.svd(trial, compute_uv=False)
            count = q + keep[idx].sum(axis=1) + 1
            tol = s[:, 0] * np.maximum(count, n) * np.finfo(float).eps
            keep[idx[np.sum(s > tol[:, None], axis=1) == count], j] = True
    return keep
