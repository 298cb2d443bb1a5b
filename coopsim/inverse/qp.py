"""Small dense convex QPs and LPs for the per-sample load-distribution problems, one at a time or a
batch at once (one per sample of a trajectory).

    minimise ½ |R x − d|²   subject to   E x = e,   lo <= C x <= hi

QPs are solved by HiGHS's QP solver (`highspy`; a maintained primal active-set method that takes a
positive *semi*definite Hessian, here H = RᵀR), then polished to the exact minimiser:

1. The equality rows (E, and rows of C with lo = hi) are eliminated, x = xp + Z z (HiGHS's QP solver
   reports solve errors on these problems when it is given them, and none without). Rows are scaled
   to a largest entry of 1, the objective to a largest Hessian entry of 1.
2. Polish (`_polish`): the equality-constrained QP on a working set of inequality rows, each held at
   one bound, is solved exactly (its KKT system in z, LU with iterative refinement; minimum-norm
   least squares when singular: redundant rows, semidefinite Hessians) and verified in the original
   rows — every row feasible (PRIMAL_TOL), stationarity (STATIONARITY_TOL) and every held row's
   multiplier of the right sign (DUAL_TOL): a KKT point of a convex QP, so the minimiser. A row the
   polished point violates joins the set, else a multiplier of the wrong sign leaves it, at most
   POLISH_STEPS times.
3. Order: the empty working set (the minimiser on the equality rows alone); for the problems it does
   not verify, every SEED_STRIDE-th goes to HiGHS (block-diagonal, about CHUNK_COLUMNS variables to a
   HiGHS QP: its fixed cost per call dominates problems this small, while its dense null-space factor
   makes one QP of a whole batch slower again), polished from the rows its duals name; the others
   start from the nearest verified problem's working set (a batch along a trajectory rarely changes
   its active set between samples); what is left goes to HiGHS in chunks, then alone, each polished,
   and last to the polish from an empty set with POLISH_STEPS changes. HiGHS's answer is only the
   guess of the active set: its tolerances (about 1e-7) never reach the result.
4. What is not verified then is reported in the result (ok False, x = nan, message: 'infeasible', or
   HiGHS's status and what the polish found) — `solve_qps` never raises for one problem; `solve_qp`
   (one problem) raises QPError.

`solve_lps` solves a batch of small LPs with HiGHS's simplex method (`highspy`): every
`lp_seed_stride`-th problem first (LP_SEED_STRIDE, fewer in a batch too short for LP_MIN_SEEDS seeds), as one block-diagonal LP; every other problem then at the optimal
basis of a seed beside it (along a trajectory the basis rarely changes between samples), its vertex
computed and certified in one compiled pass (`_vertices`, `coopsim.compiled.lp`; the NumPy reference
`_vertices_reference`: feasible, its duals of the right sign — optimal; at an
artificial cap with a feasible descent ray — unbounded); what is not certified goes to HiGHS, as one
block-diagonal LP started from those bases.
"""

from __future__ import annotations

import ctypes
import os
import sys
import threading
from typing import NamedTuple

import highspy
import numpy as np

from coopsim.core.errors import CoopsimError

CHUNK_COLUMNS = 96         # variables per HiGHS QP (whole problems, at least one)
SEED_STRIDE = 8            # every 8th problem to HiGHS first; the others start from a neighbour's working set
POLISH_STEPS = 20          # working-set changes of the polish
PRIMAL_TOL = 1e-12         # row violation, relative to the problem's largest |bound| or Σ|C_ij x_j|
DUAL_TOL = 1e-10           # wrong-sign multiplier, relative to the largest |H x|, |g| (scaled problem)
STATIONARITY_TOL = 1e-9    # |H x + g − Bᵀλ|, same scale
LP_SEED_STRIDE = 64        # a batch of LPs is first solved at every 64th problem; their bases serve the others
LP_MIN_SEEDS = 6           # a shorter batch: at least 6 seeds (stride N // 6; below a stride of 2, no seeds)


class QPError(CoopsimError):
    """The QP is infeasible, or no verified minimiser was found."""


class QPResult(NamedTuple):
    """One solved QP: the minimiser, its working set and multipliers.

    The multipliers satisfy Hx + g = Eᵀ eq_mult + Cᵀ mult (H = RᵀR, g = −Rᵀd), with mult >= 0 at lo,
    <= 0 at hi and 0 off the working set.

    Attributes:
        x: (n,) the minimiser.
        active: (m,) int8 per row of C: +1 held at hi (also rows with lo = hi), −1 held at lo, 0 not in
            the working set.
        eq_mult: (q,) the multipliers of the rows E x = e.
        mult: (m,) the multipliers of the rows of C.
    """

    x: np.ndarray
    active: np.ndarray
    eq_mult: np.ndarray
    mult: np.ndarray


class QPBatch(NamedTuple):
    """Solutions of a batch of N QPs, as QPResult's fields stacked over the problems.

    Attributes:
        ok: (N,) bool, a verified minimiser was found.
        x: (N, n) the minimisers (nan where not ok).
        active: (N, m) int8 the working sets as in QPResult (0 where not ok).
        eq_mult: (N, q) the equality rows' multipliers as in QPResult (0 where not ok).
        mult: (N, m) the multipliers of the rows of C as in QPResult (0 where not ok).
        messages: N strings: 'optimal', or why not: 'infeasible', or HiGHS's status and what the polish
            found.
    """

    ok: np.ndarray
    x: np.ndarray
    active: np.ndarray
    eq_mult: np.ndarray
    mult: np.ndarray
    messages: list

    def result(self, i: int) -> QPResult:
        """Problem i as a QPResult.

        Args:
            i: the problem's index in the batch.

        Returns:
            QPResult: its minimiser, working set and multipliers.

        Raises:
            QPError: with its message, when it was not solved.
        """
        if not self.ok[i]:
            raise QPError(f"QP not solved: {self.messages[i]}")
        return QPResult(self.x[i], self.active[i], self.eq_mult[i], self.mult[i])


class LPBatch(NamedTuple):
    """Solutions of a batch of N LPs.

    Attributes:
        status: (N,) int, linprog's status: 0 optimal, 2 infeasible, 3 unbounded, other: failed (−1: not
            solved).
        x: (N, v) the solutions (nan where not optimal).
        marginals: (N, mu) the duals of the inequality rows, as linprog's `ineqlin.marginals`: the
            objective's derivative with respect to b_ub (<= 0; 0 for rows left out, and where not optimal).
        messages: N strings, HiGHS's model status for each problem.
    """

    status: np.ndarray
    x: np.ndarray
    marginals: np.ndarray
    messages: list


# ------------------------------------------------------------------------------------------------
# LPs
# ------------------------------------------------------------------------------------------------

_LP_STATUS = {highspy.HighsModelStatus.kOptimal: 0, highspy.HighsModelStatus.kTimeLimit: 1,
              highspy.HighsModelStatus.kIterationLimit: 1, highspy.HighsModelStatus.kInfeasible: 2,
              highspy.HighsModelStatus.kModelError: 2, highspy.HighsModelStatus.kUnbounded: 3}
_BASIS_STATUS = list(highspy.HighsBasisStatus.__members__.values())      # by code: kLower, kBasic, kUpper, ...
_UNBOUNDED = "Unbounded"                                                  # HiGHS's model status string


class _LPs(NamedTuple):
    """A batch of LPs with every constraint as a row: G (N, r + v, v) the rows [A_ub; A_eq] (r of them,
    the first mu the inequality rows; keep (N, mu) those kept), then the identity (the columns' bounds);
    g_lo <= G x <= g_hi (N, r + v) (rows left out free: ±inf; A_eq rows lo = hi; the columns' bounds
    capped at ±cap for the variables the objective drives towards an infinite bound: cap_lo, cap_hi
    (v,), uncapped lo, hi (v,)); norm (N, r + v) max|G_ij| per row, bound (N,) the largest finite row
    bound; c (v,) the cost."""

    G: np.ndarray
    g_lo: np.ndarray
    g_hi: np.ndarray
    norm: np.ndarray
    bound: np.ndarray
    c: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    cap_lo: np.ndarray
    cap_hi: np.ndarray
    r: int
    mu: int
    keep: np.ndarray

    @classmethod
    def of(cls, c, A_ub, b_ub, A_eq, b_eq, bounds, cap):
        N, me, v = np.shape(A_eq)
        A_ub, b_ub = np.reshape(A_ub, (N, -1, v)), np.reshape(b_ub, (N, -1))
        c = np.asarray(c, dtype=float)
        keep = np.isfinite(b_ub)
        lo = np.array([-np.inf if b[0] is None else b[0] for b in bounds], float)
        hi = np.array([np.inf if b[1] is None else b[1] for b in bounds], float)
        cap_lo, cap_hi = np.where((c > 0) & (lo < -cap), -cap, lo), np.where((c < 0) & (hi > cap), cap, hi)
        G = np.concatenate([A_ub, A_eq, np.broadcast_to(np.eye(v), (N, v, v))], axis=1, dtype=float)
        row_lo = np.concatenate([np.full(b_ub.shape, -np.inf), b_eq], axis=1)
        row_hi = np.concatenate([np.where(keep, b_ub, np.inf), b_eq], axis=1)
        finite = np.where(np.isfinite(row_lo), np.abs(row_lo), 0.0), np.where(np.isfinite(row_hi), np.abs(row_hi), 0.0)
        return cls(G, np.concatenate([row_lo, np.broadcast_to(cap_lo, (N, v))], axis=1),
                   np.concatenate([row_hi, np.broadcast_to(cap_hi, (N, v))], axis=1), np.max(np.abs(G), axis=2),
                   np.max(np.maximum(*finite), axis=1, initial=0.0), c, lo, hi, cap_lo, cap_hi, row_lo.shape[1],
                   A_ub.shape[1], keep)


class _LPRun(NamedTuple):
    """One HiGHS run of a block of problems: linprog's status code, HiGHS's model status, x (k, v) and the
    row duals (k, r) (None unless optimal), the basis codes of the columns (k, v) and rows (k, r) (None
    unless optimal and asked for)."""

    status: int
    message: str
    x: np.ndarray | None
    duals: np.ndarray | None
    col_basis: np.ndarray | None
    row_basis: np.ndarray | None


def solve_lps(c: np.ndarray, A_ub: np.ndarray, b_ub: np.ndarray, A_eq: np.ndarray, b_eq: np.ndarray,
              bounds, cap: float = 1e9) -> LPBatch:
    """N independent LPs  min cᵀx  s.t.  A_ub[i] x <= b_ub[i],  A_eq[i] x = b_eq[i],  bounds on x.

    The variables the objective drives towards an infinite bound stop at ±cap; a problem that reaches
    it is unbounded where a ray certifies it (`_rays`), else solved alone without the cap, which gives
    its own status (cap = inf: no cap). A batch is first solved at every `lp_seed_stride`-th problem
    (the seeds, one HiGHS LP; none in a batch too short for a stride of 2); every problem's vertex is then computed
    at the optimal basis of its nearest seed, else of the other seed beside it, and kept where it is
    certified (`_vertices`). The others are solved as one block-diagonal HiGHS LP (each block is then
    optimal on its own: the objective is separable), its simplex method started from their nearest
    seeds' bases; when that LP has no optimum, its halves are solved in turn down to single problems.

    Args:
        c: (v,) the objective, shared.
        A_ub: (N, mu, v) the inequality rows.
        b_ub: (N, mu) their bounds; rows with a non-finite b_ub are left out.
        A_eq: (N, me, v) the equality rows (me may be 0).
        b_eq: (N, me) their right-hand sides.
        bounds: v pairs (lo, hi), None for none, shared by the problems.
        cap: the artificial bound of the variables driven towards an infinite bound (inf: none).

    Returns:
        LPBatch: status, x (N, v), inequality duals (N, mu) and messages of each problem.
    """
    P = _LPs.of(c, A_ub, b_ub, A_eq, b_eq, bounds, cap)
    N, v = len(P.G), len(P.c)
    out = LPBatch(np.full(N, -1), np.full((N, v), np.nan), np.zeros((N, P.mu)), [""] * N)
    capped = np.zeros(N, bool)                                      # optimal with the capped bounds
    with _HIGHS_LOCK:
        h = _highs_lp()
        todo, basis = _from_seeds(h, P, out, capped) if lp_seed_stride(N) >= 2 else (np.arange(N), None)
        _solve_blocks(h, P, todo, True, basis, out, capped)
        for i in np.flatnonzero(capped & _at_cap(P, out.x)):
            _solve_blocks(h, P, np.array([i]), False, None, out, capped)
    return out


def lp_seed_stride(N: int) -> int:
    """The stride of `solve_lps`'s seeds in a batch of N problems: LP_SEED_STRIDE, or N // LP_MIN_SEEDS
    when that is smaller (a short batch still has LP_MIN_SEEDS seeds whose bases serve the others).

    Args:
        N: the number of problems.

    Returns:
        int: every how many problems one is a seed (below 2: the batch is solved without seeds).
    """
    return min(LP_SEED_STRIDE, N // LP_MIN_SEEDS)


def _at_cap(P: _LPs, x: np.ndarray) -> np.ndarray:
    """(k,) bool: a capped variable of x (k, v) is at least half-way to its cap (nan: no)."""
    with np.errstate(invalid="ignore"):
        return np.any(((P.cap_hi < P.hi) & (x >= P.cap_hi / 2)) | ((P.cap_lo > P.lo) & (x <= P.cap_lo / 2)), axis=1)


def _from_seeds(h, P: _LPs, out: LPBatch, capped: np.ndarray):
    """Solve the seeds (every `lp_seed_stride`-th problem, capped, one HiGHS LP), then every problem at
    the optimal basis of its nearest seed and, where that fails, of the other seed beside it; store the
    certified ones (capped), as unbounded those with a certified ray (`_rays`). Returns the problems
    left and the bases (col (N, v), row (N, r)) of every problem's nearest seed — all problems and None
    when the seeds' LP has no optimum."""
    N = len(P.G)
    stride = lp_seed_stride(N)
    seeds = np.arange(0, N, stride)
    run = _run_lp(h, P, seeds, True, None, want_basis=True)
    if run.status != 0:
        return np.arange(N), None
    pos = np.arange(N) / stride
    near = np.minimum(np.rint(pos), len(seeds) - 1).astype(int)
    other = np.minimum(np.where(near > pos, np.floor(pos), np.ceil(pos)), len(seeds) - 1).astype(int)
    todo = np.arange(N)
    for s, tried in ((near, np.zeros(N, bool)), (other, other == near)):
        trial = todo[~tried[todo]]
        x, y, ok, unbounded = _vertices(P, trial, run.col_basis[s[trial]], run.row_basis[s[trial]])
        fin = ok & ~unbounded
        _store(out, trial[fin], 0, run.message, x[fin], y[fin], P)
        _store(out, trial[unbounded], 3, _UNBOUNDED, None, None, P)
        capped[trial[fin]] = True
        todo = np.setdiff1d(todo, trial[ok])
    return todo, (run.col_basis[near], run.row_basis[near])


def _solve_blocks(h, P: _LPs, idx: np.ndarray, capped: bool, basis, out: LPBatch, was_capped: np.ndarray) -> None:
    """Solve the problems idx as one block-diagonal HiGHS LP (bounds capped or not), started from the
    bases (col (N, v), row (N, r) codes, None: HiGHS's own start), and store them; a run without an
    optimum is repeated without the bases, then its halves are solved in turn, a single capped
    problem without the cap."""
    if not len(idx):
        return
    run = _run_lp(h, P, idx, capped, None if basis is None else (basis[0][idx], basis[1][idx]))
    if run.status != 0 and basis is not None:
        _solve_blocks(h, P, idx, capped, None, out, was_capped)
    elif run.status != 0 and len(idx) > 1:
        for half in (idx[:len(idx) // 2], idx[len(idx) // 2:]):
            _solve_blocks(h, P, half, capped, None, out, was_capped)
    elif run.status != 0 and capped:
        _solve_blocks(h, P, idx, False, None, out, was_capped)
    else:
        _store(out, idx, run.status, run.message, run.x, run.duals, P)
        was_capped[idx] = capped and run.status == 0
        at = _at_cap(P, out.x[idx]) if capped else np.zeros(len(idx), bool)
        if np.any(at):                                          # a certified ray spares their runs alone
            col, row = _basis_codes(h, len(idx))
            unbounded = _vertices(P, idx[at], col[at], row[at])[3]
            _store(out, idx[at][unbounded], 3, _UNBOUNDED, None, None, P)
            was_capped[idx[at][unbounded]] = False


def _run_lp(h, P: _LPs, idx: np.ndarray, capped: bool, basis, want_basis: bool = False) -> _LPRun:
    """Solve the problems idx as one block-diagonal HiGHS LP (bounds capped or not), from the basis
    (col (k, v), row (k, r) codes) where one is given (else HiGHS's presolve and crash)."""
    k, r, v = len(idx), P.r, len(P.c)
    Bt = np.swapaxes(P.G[idx, :r], 1, 2)                            # (k, v, r): column-major blocks
    nz = Bt != 0
    b, j, i = np.nonzero(nz)
    start = np.concatenate([[0], np.cumsum(nz.sum(axis=2).ravel())[:-1]]).astype(np.int32)
    lo, hi = (P.cap_lo, P.cap_hi) if capped else (P.lo, P.hi)
    h.passModel(k * v, k * r, len(b), 1, 1, 0.0, np.tile(P.c, k), np.tile(lo, k), np.tile(hi, k),
                P.g_lo[idx, :r].ravel(), P.g_hi[idx, :r].ravel(), start, (b * r + i).astype(np.int32), Bt[nz],
                np.zeros(k * v, np.int32))
    if basis is not None:
        hb = highspy.HighsBasis()
        hb.col_status = [_BASIS_STATUS[s] for s in basis[0].ravel().tolist()]
        hb.row_status = [_BASIS_STATUS[s] for s in basis[1].ravel().tolist()]
        hb.valid, hb.alien = True, False                          # as many basic as rows, by construction
        h.setBasis(hb)
    h.run()
    model_status = h.getModelStatus()
    status, message = _LP_STATUS.get(model_status, 4), h.modelStatusToString(model_status)
    if status != 0:
        return _LPRun(status, message, None, None, None, None)
    sol = h.getSolution()
    x, duals = np.asarray(sol.col_value).reshape(k, v), np.asarray(sol.row_dual).reshape(k, r)
    return _LPRun(status, message, x, duals, *(_basis_codes(h, k) if want_basis else (None, None)))


def _basis_codes(h, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The basis of the k problems HiGHS has just solved together: codes col (k, v), row (k, r)."""
    hb = h.getBasis()
    return tuple(np.array(s, dtype=np.int8).reshape(k, -1) for s in (hb.col_status, hb.row_status))


def _vertices(P: _LPs, idx: np.ndarray, col_basis: np.ndarray, row_basis: np.ndarray):
    """`_vertices_reference`, compiled (`coopsim.compiled.lp`): the same certificates, the same vertices
    to rounding (one LU with partial pivoting per problem for both solves).

    Args:
        P: the batch (`_LPs`).
        idx: (k,) int, the problems.
        col_basis: (k, v) int8 HiGHS's basis codes of their columns.
        row_basis: (k, r) int8 those of their rows.

    Returns:
        tuple: x (k, v), row duals (k, r), ok (k,) bool and unbounded (k,) bool.
    """
    from coopsim.compiled import api

    held = np.concatenate([row_basis, col_basis], axis=1)
    x, dual, ok, unbounded = api.lp_vertices(P.G, P.g_lo, P.g_hi, P.norm, P.bound, P.c, P.lo, P.hi, P.cap_lo, P.cap_hi,
                                             P.r, idx, held, (PRIMAL_TOL, DUAL_TOL, STATIONARITY_TOL))
    return x, dual[:, :P.r], ok, unbounded


def _vertices_reference(P: _LPs, idx: np.ndarray, col_basis: np.ndarray, row_basis: np.ndarray):
    """(x (k, v), row duals (k, r), ok (k,)) of the problems idx (capped bounds) at the bases (HiGHS's
    codes, col (k, v), row (k, r)): the v constraints a basis holds (its nonbasic rows and columns, at
    their lower or upper bound, a free column at 0) solved for x, and Mᵀλ = c (M their rows) for the
    duals. ok: a certified optimum — x meets every row and bound and the held ones (to PRIMAL_TOL, of
    the problem's largest row bound or Σ|B_ij x_j|), each dual has its bound's sign (>= 0 at a lower,
    <= 0 at an upper bound, 0 at a free column, either on a fixed one; to DUAL_TOL of the largest
    |c_j|, |λ_i|·max|M_i|) and Mᵀλ = c to STATIONARITY_TOL of the same."""
    k, r, v = len(idx), P.r, len(P.c)
    held = np.concatenate([row_basis, col_basis], axis=1)           # (k, r + v): 0 lower, 1 basic, 2 upper, 3 zero
    G, g_lo, g_hi, norm = P.G[idx], P.g_lo[idx], P.g_hi[idx], P.norm[idx]
    order = np.argsort(held == 1, axis=1, kind="stable")[:, :v]     # the held constraints first
    M = np.take_along_axis(G, order[..., None], axis=1)
    code = np.take_along_axis(held, order, axis=1)
    t = np.where(code == 2, np.take_along_axis(g_hi, order, axis=1),
                 np.where(code == 3, 0.0, np.take_along_axis(g_lo, order, axis=1)))
    valid = ((held != 1).sum(axis=1) == v) & np.all(held <= 3, axis=1) & np.all(np.isfinite(t), axis=1)
    M[~valid], t[~valid] = np.eye(v), 0.0
    with np.errstate(all="ignore"):
        try:
            x, lam = _solve_both(M, t, P.c)
        except np.linalg.LinAlgError:                               # a singular M: those are not certified
            valid &= (np.linalg.det(M) != 0) & (np.linalg.det(np.swapaxes(M, 1, 2)) != 0)
            M[~valid], t[~valid] = np.eye(v), 0.0
            x, lam = _solve_both(M, t, P.c)
        dual = np.zeros((k, r + v))
        np.put_along_axis(dual, order, lam, axis=1)
        Gx = (G @ x[..., None])[..., 0]
        pscale = np.maximum(P.bound[idx], np.max(np.abs(G) @ np.abs(x)[..., None], axis=(1, 2)))
        viol = np.max(np.maximum(g_lo - Gx, Gx - g_hi), axis=1)
        res = np.max(np.abs((M @ x[..., None])[..., 0] - t), axis=1)
        weight = np.abs(dual) * norm
        wrong = np.where(held == 0, -dual, np.where(held == 2, dual, 0.0)) * norm    # > 0: the wrong sign
        wrong = np.where(g_lo == g_hi, 0.0, np.where(held == 3, weight, wrong))
        dscale = np.maximum(np.max(np.abs(P.c), initial=0.0), np.max(weight, axis=1))
        stat = np.max(np.abs((lam[:, None, :] @ M)[:, 0] - P.c), axis=1)
        ok = (valid & (viol <= PRIMAL_TOL * pscale) & (res <= PRIMAL_TOL * pscale)
              & (np.max(wrong, axis=1) <= DUAL_TOL * dscale) & (stat <= STATIONARITY_TOL * dscale))
        at_cap = ((P.cap_hi < P.hi) & (held[:, r:] == 2)) | ((P.cap_lo > P.lo) & (held[:, r:] == 0))
        sub = np.flatnonzero(ok & np.any(at_cap, axis=1))
        unbounded = np.zeros(k, bool)
        unbounded[sub] = _rays(P, idx[sub], M[sub], order[sub], at_cap[sub])
    return x, dual[:, :r], ok, unbounded


def _solve_both(M: np.ndarray, t: np.ndarray, c: np.ndarray):
    """x (k, v) and λ (k, v) of M x = t and Mᵀλ = c (M (k, v, v)); LinAlgError where an M is singular."""
    k, v = t.shape
    return (np.linalg.solve(M, t[..., None])[..., 0],
            np.linalg.solve(np.swapaxes(M, 1, 2), np.broadcast_to(c, (k, v))[..., None])[..., 0])


def _rays(P: _LPs, idx: np.ndarray, M: np.ndarray, order: np.ndarray, at_cap: np.ndarray) -> np.ndarray:
    """(k,) bool: certified vertices of the problems idx (M (k, v, v) the rows of their held constraints
    in `order` (k, v)) at which a capped column sits at its cap (at_cap (k, v), the first of them taken)
    has a ray — off that bound, the other held constraints kept — that meets every row and bound
    without the cap (to PRIMAL_TOL of Σ|G_ij d_j|) and lowers the cost (by more than DUAL_TOL of
    Σ|c_j d_j|): without the cap the problem is unbounded."""
    k, r, v = len(idx), P.r, len(P.c)
    rows = np.arange(k)
    j = np.argmax(at_cap, axis=1)
    e = np.zeros((k, v))
    e[rows, np.argmax(order == (r + j)[:, None], axis=1)] = np.where(P.cap_hi[j] < P.hi[j], 1.0, -1.0)
    d = np.linalg.solve(M, e[..., None])[..., 0]
    G = P.G[idx]
    Gd = (G @ d[..., None])[..., 0]
    tol = PRIMAL_TOL * np.max(np.abs(G) @ np.abs(d)[..., None], axis=(1, 2))[:, None]
    lo = np.concatenate([P.g_lo[idx, :r], np.broadcast_to(P.lo, (k, v))], axis=1)
    hi = np.concatenate([P.g_hi[idx, :r], np.broadcast_to(P.hi, (k, v))], axis=1)
    meets = np.all(((Gd <= tol) | ~np.isfinite(hi)) & ((Gd >= -tol) | ~np.isfinite(lo)), axis=1)
    return meets & (d @ P.c < -DUAL_TOL * (np.abs(d) @ np.abs(P.c)))


def _store(out: LPBatch, idx: np.ndarray, status: int, message: str, x, duals, P: _LPs) -> None:
    """Write the status, message, x (len(idx), v) and row duals (len(idx), r) of the problems idx into out
    (x nan and duals 0 unless optimal; the duals of the inequality rows left out 0)."""
    out.status[idx], out.x[idx], out.marginals[idx] = status, np.nan, 0.0
    messages = out.messages
    for i in idx.tolist():
        messages[i] = message
    if status == 0:
        out.x[idx] = x
        out.marginals[idx] = np.where(P.keep[idx], duals[:, :P.mu], 0.0)


# ------------------------------------------------------------------------------------------------
# QPs
# ------------------------------------------------------------------------------------------------

def solve_qp(R: np.ndarray, d: np.ndarray, E: np.ndarray, e: np.ndarray, C: np.ndarray, lo: np.ndarray,
             hi: np.ndarray) -> QPResult:
    """Minimise ½|R x − d|² subject to E x = e and lo <= C x <= hi (one problem; `solve_qps`).

    Args:
        R: (p, n) the objective's matrix.
        d: (p,) the objective's target.
        E: (q, n) the equality rows (q may be 0).
        e: (q,) their right-hand sides.
        C: (m, n) the inequality rows.
        lo, hi: (m,) their bounds, ±inf allowed (lo = hi: an equality).

    Returns:
        QPResult: the verified minimiser, its working set and multipliers.

    Raises:
        QPError: the problem is infeasible or no verified minimiser is found.
    """
    n = np.shape(R)[1]
    one = lambda a: np.asarray(a, dtype=float).reshape(1, -1)          # noqa: E731
    batch = solve_qps(np.asarray(R, dtype=float)[None], one(d), np.reshape(E, (1, -1, n)), one(e),
                      np.reshape(C, (1, -1, n)), one(lo), one(hi))
    return batch.result(0)


def solve_qps(R: np.ndarray, d: np.ndarray, E: np.ndarray, e: np.ndarray, C: np.ndarray, lo: np.ndarray,
              hi: np.ndarray) -> QPBatch:
    """`solve_qp` for a batch of N problems; one that fails is reported in the QPBatch, never raised.

    A failed problem has ok False, x nan and a message. The steps are in the module docstring.

    Args:
        R: (N, p, n) the objectives' matrices.
        d: (N, p) the objectives' targets.
        E: (N, q, n) the equality rows (q may be 0).
        e: (N, q) their right-hand sides.
        C: (N, m, n) the inequality rows.
        lo, hi: (N, m) their bounds, ±inf allowed (lo = hi: an equality).

    Returns:
        QPBatch: per problem ok, the minimiser, working set, multipliers and message.
    """
    P = _Scaled.of(*(np.asarray(a, dtype=float) for a in (R, d, E, e, C, lo, hi)))
    N, n = P.g.shape
    q, r = np.shape(E)[1], P.B.shape[1]
    red = _Reduced.of(P)
    out = _Outcome.empty(N, n, r)
    status = np.where(red.consistent, "", "Infeasible").astype(object)
    cand = np.flatnonzero(red.consistent)
    _polish(P, red, cand, np.zeros((len(cand), r), np.int8), 0, out)
    rest = cand[~out.ok[cand]]
    if len(rest):
        guess_y = np.full(P.lo.shape, np.nan)
        with _HIGHS_LOCK:
            h = _highs()
            seeds = rest[::SEED_STRIDE]
            for chunk in _chunks(seeds, red.free[seeds].sum(axis=1)):
                _run_highs(h, red, chunk, guess_y, status)
            _polish_guesses(P, red, seeds, guess_y, out)
            _polish_from_neighbours(P, red, rest, out)
            todo = rest[~out.ok[rest]]
            for chunk in _chunks(todo, red.free[todo].sum(axis=1)):
                _run_highs(h, red, chunk, guess_y, status)
            _polish_guesses(P, red, todo, guess_y, out)
            again = rest[~out.ok[rest]] if len(rest) > 1 else rest[:0]
            guess_y[again] = np.nan
            for i in again:                                   # alone: its own status, a fresh guess
                _run_highs(h, red, np.array([i]), guess_y, status)
            _polish_guesses(P, red, again, guess_y, out)
        last = rest[~out.ok[rest]]                            # a working-set search of the polish's own
        _polish(P, red, last, np.zeros((len(last), r), np.int8), POLISH_STEPS, out)
    messages = []
    for i in range(N):
        if out.ok[i]:
            messages.append("optimal")
        elif not red.consistent[i]:
            messages.append("infeasible (the equality rows are inconsistent)")
        elif status[i] == "Infeasible":
            messages.append("infeasible")
        else:
            messages.append(f"HiGHS: {status[i].lower()}; polish: {out.why[i]}")
    x, lam, held = out.x, out.lam * P.D / P.sigma[:, None], out.held
    x[~out.ok], lam[~out.ok], held[~out.ok] = np.nan, 0.0, 0
    return QPBatch(out.ok, x, held[:, q:].copy(), lam[:, :q], lam[:, q:], messages)


def _chunks(idx: np.ndarray, width: np.ndarray) -> list[np.ndarray]:
    """idx cut into consecutive runs of about CHUNK_COLUMNS variables (width (len(idx),) each)."""
    ends = np.cumsum(width)
    cut = np.flatnonzero(np.diff(ends // CHUNK_COLUMNS)) + 1
    return np.split(idx, cut)


def _polish_from_neighbours(P: _Scaled, red: "_Reduced", idx: np.ndarray, out: "_Outcome") -> None:
    """Polish the problems idx not yet verified from the working set of the nearest verified one in
    idx (batch order: along a trajectory the active set rarely changes from one sample to the next)."""
    done, todo = idx[out.ok[idx]], idx[~out.ok[idx]]
    if not len(done) or not len(todo):
        return
    pos = np.clip(np.searchsorted(done, todo), 1, len(done)) - 1
    right = np.minimum(pos + 1, len(done) - 1)
    near = np.where(np.abs(done[right] - todo) < np.abs(todo - done[pos]), done[right], done[pos])
    _polish(P, red, todo, np.where(P.ineq[todo], out.held[near], 0).astype(np.int8), POLISH_STEPS, out)


def _polish_guesses(P: _Scaled, red: "_Reduced", idx: np.ndarray, guess_y: np.ndarray, out: "_Outcome") -> None:
    """Polish the problems idx that HiGHS gave a guess, from the working sets its duals name."""
    idx = idx[np.all(np.isfinite(guess_y[idx]), axis=1)]
    y, lo, hi = guess_y[idx], red.lo[idx], red.hi[idx]
    W = np.zeros(y.shape, np.int8)
    W[(y < 0) & np.isfinite(hi)] = 1                           # y < 0: held at hi, y > 0: at lo
    W[(y > 0) & np.isfinite(lo)] = -1
    _polish(P, red, idx, W, POLISH_STEPS, out)


class _Scaled(NamedTuple):
    """A batch with every row B = [E; C] scaled to a largest |entry| of 1 (D (N, r) = 1/that, 1 for a
    zero row) and the objective ½xᵀHx + gᵀx (H = RᵀR, g = −Rᵀd) by sigma (N,) = 1/max|H| (1/max|g|
    for H = 0): B (N, r, n), lo/hi (N, r) scaled bounds (E rows: lo = hi = e), eq (N, r) lo = hi,
    ineq (N, r): the other rows with a finite bound (the rest are no constraint)."""

    H: np.ndarray
    g: np.ndarray
    B: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    eq: np.ndarray
    ineq: np.ndarray
    D: np.ndarray
    sigma: np.ndarray

    @classmethod
    def of(cls, R, d, E, e, C, lo, hi):
        H, g = np.swapaxes(R, 1, 2) @ R, -np.einsum("npi,np->ni", R, d)
        B = np.concatenate([E, C], axis=1)
        lo, hi = np.concatenate([e, lo], axis=1), np.concatenate([e, hi], axis=1)
        big = np.max(np.abs(B), axis=2, initial=0.0)
        D = 1.0 / np.where(big > 0, big, 1.0)
        hmax = np.max(np.abs(H), axis=(1, 2), initial=0.0)
        gmax = np.max(np.abs(g), axis=1, initial=0.0)
        sigma = 1.0 / np.where(hmax > 0, hmax, np.where(gmax > 0, gmax, 1.0))
        eq = (lo == hi) & np.isfinite(lo)
        return cls(H * sigma[:, None, None], g * sigma[:, None], B * D[..., None], lo * D, hi * D, eq,
                   (np.isfinite(lo) | np.isfinite(hi)) & ~eq, D, sigma)


class _Reduced(NamedTuple):
    """The problems with their equality rows (E, and rows of C with lo = hi) eliminated: x = xp + Z z.
    Z (N, n, n): an orthonormal basis of the equality rows' null space in the columns `free` (N, n)
    (the last n − rank), zero elsewhere; xp (N, n) their minimum-norm solution; consistent (N,): xp
    satisfies them; Einv (N, r, n): (B_eqᵀ)⁺ (zero rows off the equality rows), for their multipliers;
    in z: H (N, n, n) = ZᵀHZ + 1 on the diagonal off `free` (those z are 0), g (N, n) = Zᵀ(H xp + g),
    C (N, r, n) = B Z, lo/hi (N, r) = bounds − B xp (the inequality rows' part)."""

    Z: np.ndarray
    xp: np.ndarray
    free: np.ndarray
    consistent: np.ndarray
    Einv: np.ndarray
    H: np.ndarray
    g: np.ndarray
    C: np.ndarray
    lo: np.ndarray
    hi: np.ndarray

    @classmethod
    def of(cls, P: _Scaled):
        N, r, n = P.B.shape
        rows = np.flatnonzero(P.eq.any(axis=0))
        Eq = P.B[:, rows] * P.eq[:, rows, None]
        e = np.where(P.eq[:, rows], P.lo[:, rows], 0.0)
        Einv = np.zeros((N, r, n))
        if len(rows):
            U, s, Vt = np.linalg.svd(Eq)
            k = s.shape[1]
            big = s > s[:, :1] * max(len(rows), n) * np.finfo(float).eps
            inv = np.divide(1.0, s, out=np.zeros_like(s), where=big)
            xp = np.einsum("nji,nj->ni", Vt[:, :k], inv * np.einsum("nkj,nk->nj", U[:, :, :k], e))
            Einv[:, rows] = U[:, :, :k] @ (inv[..., None] * Vt[:, :k])
            free = np.arange(n)[None, :] >= big.sum(axis=1)[:, None]
            Z = np.swapaxes(Vt, 1, 2) * free[:, None, :]
        else:
            xp, free, Z = np.zeros((N, n)), np.ones((N, n), bool), np.broadcast_to(np.eye(n), (N, n, n)).copy()
        res = np.max(np.abs(np.einsum("nij,nj->ni", Eq, xp) - e), axis=1, initial=0.0)
        scale = np.maximum(np.max(np.abs(e), axis=1, initial=0.0),
                           np.max(np.abs(Eq) @ np.abs(xp)[..., None], axis=(1, 2), initial=0.0))
        consistent = res <= PRIMAL_TOL * scale
        Zt = np.swapaxes(Z, 1, 2)
        H = Zt @ P.H @ Z
        H[:, np.arange(n), np.arange(n)] += ~free
        Bxp = np.einsum("nij,nj->ni", P.B, xp)
        g = np.einsum("nij,nj->ni", Zt, np.einsum("nij,nj->ni", P.H, xp) + P.g)
        return cls(Z, xp, free, consistent, Einv, H, g, P.B @ Z,
                   np.where(P.ineq, P.lo - Bxp, -np.inf), np.where(P.ineq, P.hi - Bxp, np.inf))

    def refine(self, P: _Scaled, idx: np.ndarray, x: np.ndarray) -> np.ndarray:
        """The least correction (len(idx), n) of x to the equality rows, B_eq⁺ (e − B_eq x): xp + Z z
        meets them only to eps·|x|·(number of columns), as Z's null space is exact only to rounding."""
        res = np.where(P.eq[idx], P.lo[idx] - np.einsum("pij,pj->pi", P.B[idx], x), 0.0)
        return np.einsum("prj,pr->pj", self.Einv[idx], res)


class _Outcome(NamedTuple):
    """What the polish verified so far, per problem of the batch: ok (N,), x (N, n), lam (N, r) scaled
    multipliers (Hx + g = Bᵀλ in the scaled problem), held (N, r) int8 (+1 at hi or an equality row,
    −1 at lo, 0 free), why (N,) the last polish's reason for not ok."""

    ok: np.ndarray
    x: np.ndarray
    lam: np.ndarray
    held: np.ndarray
    why: list

    @classmethod
    def empty(cls, N: int, n: int, r: int):
        return cls(np.zeros(N, bool), np.full((N, n), np.nan), np.zeros((N, r)), np.zeros((N, r), np.int8), [""] * N)


_HIGHS_LOCK = threading.RLock()
_HIGHS = {}


def _highs():
    """The process's HiGHS instance for the QPs, silent, entries below 1e-12 dropped."""
    if "qp" not in _HIGHS:
        h = _silent_highs()
        h.setOptionValue("small_matrix_value", 1e-12)
        _HIGHS["qp"] = h
    return _HIGHS["qp"]


def _highs_lp():
    """The process's HiGHS instance for the LPs, silent, with linprog's options (dual simplex)."""
    if "lp" not in _HIGHS:
        h = _silent_highs()
        h.setOptionValue("simplex_strategy", 1)
        _HIGHS["lp"] = h
    return _HIGHS["lp"]


def _silent_highs():
    """A new HiGHS instance with its output off. The first one HiGHS makes prints its banner on the
    C-level standard output (it would corrupt `--json` output): that is sent to the null device."""
    try:
        sys.stdout.flush()
        saved = os.dup(1)
    except (OSError, ValueError, AttributeError):
        saved = None
    try:
        if saved is not None:
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, 1)
            os.close(null)
        h = highspy.Highs()
        h.setOptionValue("output_flag", False)
    finally:
        if saved is not None:
            _flush_c_stdout()
            os.dup2(saved, 1)
            os.close(saved)
    return h


def _flush_c_stdout() -> None:
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError, TypeError):
        pass


def _run_highs(h, red: _Reduced, idx: np.ndarray, guess_y: np.ndarray, status: np.ndarray) -> None:
    """Solve the reduced problems idx (z in their `free` columns, inequality rows only: HiGHS's QP
    solver reports solve errors on these problems with their equality rows, and none without) as one
    block-diagonal HiGHS QP; store its row duals (gradient = Cᵀy, scaled problem; 0 off the
    inequality rows) as their guesses (they stay nan when HiGHS has none) and HiGHS's model status as
    theirs."""
    k, n = len(idx), red.g.shape[1]
    fr = red.free[idx]
    keep = np.isfinite(red.lo[idx]) | np.isfinite(red.hi[idx])
    A = red.C[idx][keep]
    col = np.cumsum(fr.ravel()).reshape(k, n) - 1                # global column of each free (problem, j)
    blk = np.nonzero(keep)[0]
    nz = (np.abs(A) > 1e-12) & fr[blk]                          # HiGHS drops them anyway (small_matrix_value)
    a_start = np.concatenate([[0], np.cumsum(nz.sum(axis=1))[:-1]]).astype(np.int32)
    b_col = np.nonzero(fr)[0]
    Hc = np.swapaxes(np.tril(red.H[idx]), 1, 2)[fr]             # column (b, c): H[b, r >= c, c]
    qnz = (np.abs(Hc) > 1e-12) & fr[b_col]
    q_start = np.concatenate([[0], np.cumsum(qnz.sum(axis=1))[:-1]]).astype(np.int32)
    ncol = len(b_col)
    inf = np.full(ncol, np.inf)
    h.passModel(ncol, len(A), int(nz.sum()), int(qnz.sum()), 2, 1, 1, 0.0, red.g[idx][fr], -inf, inf,
                red.lo[idx][keep], red.hi[idx][keep], a_start, col[blk][nz].astype(np.int32), A[nz],
                q_start, col[b_col][qnz].astype(np.int32), Hc[qnz], np.zeros(ncol, np.int32))
    h.run()
    status[idx] = h.modelStatusToString(h.getModelStatus())
    duals = np.asarray(h.getSolution().row_dual, dtype=float)
    if len(duals) == len(A):                  # also after a solve error: a guess, which the polish verifies
        y = np.zeros(keep.shape)
        y[keep] = duals
        guess_y[idx] = y


def _polish(P: _Scaled, red: _Reduced, idx: np.ndarray, W: np.ndarray, steps: int, out: _Outcome) -> None:
    """Polish the problems idx from the inequality working sets W (len(idx), r) (module docstring, step
    2), at most `steps` working-set changes: the KKT system of the reduced problem on W (`_kkt`), x =
    xp + Z z, verified in the scaled problem. Records every verified problem in `out`, and the reason
    of every other (an earlier verified entry is kept)."""
    W = W.copy()
    live = np.arange(len(idx))
    finite = lambda b: np.where(np.isfinite(b), np.abs(b), 0.0)  # noqa: E731
    for step in range(steps + 1):
        if not len(live):
            break
        i_ = idx[live]
        Wl, Hz, gz, Cz = W[live], red.H[i_], red.g[i_], red.C[i_]
        target = np.where(Wl > 0, red.hi[i_], np.where(Wl < 0, red.lo[i_], 0.0))
        z, lz = _kkt(Hz, gz, Cz, Wl != 0, target)
        x = red.xp[i_] + np.einsum("pij,pj->pi", red.Z[i_], z)
        x += red.refine(P, i_, x)
        B, lo, hi = P.B[i_], P.lo[i_], P.hi[i_]
        Bx = np.einsum("pij,pj->pi", B, x)
        v_lo, v_hi = lo - Bx, Bx - hi                           # −inf where that side is unbounded
        viol = np.maximum(np.maximum(v_lo, v_hi), 0.0)
        pscale = np.maximum(np.max(np.maximum(finite(lo), finite(hi)), axis=1, initial=0.0),
                            np.max(np.abs(B) @ np.abs(x)[..., None], axis=(1, 2), initial=0.0))
        sscale = np.maximum(np.max(np.abs(Hz) @ np.abs(z)[..., None], axis=(1, 2), initial=0.0),
                            np.max(np.abs(gz), axis=1, initial=0.0))
        stat = np.max(np.abs(np.einsum("pij,pj->pi", Hz, z) + gz - np.einsum("pji,pj->pi", Cz, lz)),
                      axis=1, initial=0.0)
        wrong = np.where(Wl != 0, Wl * lz, -np.inf)             # > 0: a wrong sign (λ <= 0 at hi, >= 0 at lo)
        worst_v, worst_w = np.max(viol, axis=1, initial=0.0), np.max(wrong, axis=1, initial=-np.inf)
        feasible = worst_v <= PRIMAL_TOL * pscale
        stationary = stat <= STATIONARITY_TOL * np.maximum(sscale, 1e-300)
        done = feasible & stationary & (worst_w <= DUAL_TOL * sscale)
        j_v, j_w = np.argmax(viol, axis=1), np.argmax(wrong, axis=1)
        stuck = ~done & (~stationary | (~feasible & ((Wl[np.arange(len(live)), j_v] != 0) | P.eq[i_, j_v])))
        last = step == steps
        p = np.flatnonzero(done)
        i = i_[p]
        grad = np.einsum("pij,pj->pi", P.H[i], x[p]) + P.g[i] - np.einsum("pji,pj->pi", B[p], lz[p])
        out.ok[i], out.x[i], out.held[i] = True, x[p], np.where(P.eq[i], 1, Wl[p])
        out.lam[i] = lz[p] + np.einsum("prn,pn->pr", red.Einv[i], grad)   # + the equality rows' multipliers
        for p in np.flatnonzero(stuck | (last & ~done)):
            out.why[i_[p]] = (f"the KKT system of the working set has no stationary solution (residual {stat[p]:.2g})"
                              if not stationary[p] else
                              f"no verified minimiser in {steps} working-set changes (violation {worst_v[p]:.2g}, "
                              f"wrong-sign multiplier {max(worst_w[p], 0.0):.2g}, scaled)")
        move = np.flatnonzero(~(done | stuck))
        if last:
            break
        add = move[~feasible[move]]
        W[live[add], j_v[add]] = np.where(v_hi[add, j_v[add]] > v_lo[add, j_v[add]], 1, -1)
        drop = move[feasible[move]]
        W[live[drop], j_w[drop]] = 0
        live = live[move]


def _kkt(H: np.ndarray, g: np.ndarray, C: np.ndarray, W: np.ndarray, target: np.ndarray):
    """z (P, n) and λ (P, r) of min ½zᵀHz + gᵀz s.t. C_j z = target_j for the rows W (P, r) bool: the
    KKT systems [H C_Wᵀ; C_W 0][z; −λ] = [−g; target_W], padded with λ_j = 0 off W (rows in no
    problem's W left out), solved together by LU with two steps of iterative refinement (multipliers
    far larger than z would otherwise leave the held rows off by eps·|λ|); a singular one, or one whose
    solution is 1e12 times its right-hand side, alone in the minimum-norm least-squares sense
    (redundant rows, flat directions). Hz + g = Cᵀλ."""
    P, n = g.shape
    cols = np.flatnonzero(W.any(axis=0))
    w = W[:, cols]
    CW = C[:, cols] * w[..., None]
    S = n + len(cols)
    K = np.zeros((P, S, S))
    K[:, :n, :n], K[:, :n, n:], K[:, n:, :n] = H, np.swapaxes(CW, 1, 2), CW
    K[:, np.arange(n, S), np.arange(n, S)] = ~w
    rhs = np.concatenate([-g, np.where(w, target[:, cols], 0.0)], axis=1)
    try:
        sol = np.linalg.solve(K, rhs[..., None])[..., 0]
        for _ in range(2):
            sol += np.linalg.solve(K, (rhs - np.einsum("pij,pj->pi", K, sol))[..., None])[..., 0]
        bad = ~np.all(np.isfinite(sol), axis=1)
    except np.linalg.LinAlgError:
        sol, bad = np.zeros((P, S)), np.ones(P, bool)
    size = np.max(np.abs(rhs), axis=1, initial=0.0)
    bad |= np.max(np.abs(sol), axis=1, initial=0.0) > 1e12 * np.maximum(size, 1e-300)
    for p in np.flatnonzero(bad):
        sol[p] = np.linalg.lstsq(K[p], rhs[p], rcond=None)[0]
    lam = np.zeros(W.shape)
    lam[:, cols] = -sol[:, n:]
    return sol[:, :n], lam
