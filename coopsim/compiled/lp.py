"""LP vertices at given bases, certified, compiled: the step of `coopsim.inverse.qp.solve_lps` that computes
every problem's vertex at a neighbouring seed's optimal basis (`coopsim.inverse.qp._vertices_reference`, the
NumPy reference, in the same words).

Per problem (rows G (R, v): its r constraint rows, then the identity of its columns' bounds; held codes per
row: 0 at lower, 1 basic, 2 at upper, 3 a free column at 0): the v non-basic rows M (in row order) held at
their bounds t give M x = t and Mᵀλ = c (one LU with partial pivoting for both; an exactly zero pivot: not
certified). Certified optimal when x meets every row and bound and the held ones to PRIMAL_TOL of the
problem's scale, every dual has its bound's sign to DUAL_TOL and Mᵀλ = c to STATIONARITY_TOL; at a capped
column's cap, unbounded when the ray off that bound (the other held rows kept) meets every row and the
uncapped bounds and lowers the cost.
"""

import numpy as np

from coopsim.compiled.toolchain.jit import entry, kernel


@kernel
def _lu(M, v, piv):
    """M = P L U in place (partial pivoting, piv (v,) the row swaps); False at an exactly zero pivot."""
    for c in range(v):
        p = c
        for i in range(c + 1, v):
            if abs(M[i, c]) > abs(M[p, c]):
                p = i
        piv[c] = p
        if M[p, c] == 0.0:
            return False
        if p != c:
            for j in range(v):
                M[c, j], M[p, j] = M[p, j], M[c, j]
        for i in range(c + 1, v):
            M[i, c] /= M[c, c]
            for j in range(c + 1, v):
                M[i, j] -= M[i, c] * M[c, j]
    return True


@kernel
def _lu_solve(LU, v, piv, b):
    """b ← M⁻¹ b for M = P L U (`_lu`)."""
    for c in range(v):
        p = piv[c]
        if p != c:
            b[c], b[p] = b[p], b[c]
    for i in range(v):
        for j in range(i):
            b[i] -= LU[i, j] * b[j]
    for i in range(v - 1, -1, -1):
        for j in range(i + 1, v):
            b[i] -= LU[i, j] * b[j]
        b[i] /= LU[i, i]


@kernel
def _lu_solve_transposed(LU, v, piv, b):
    """b ← M⁻ᵀ b for M = P L U (`_lu`): Uᵀ Lᵀ Pᵀ... solved in turn."""
    for i in range(v):
        for j in range(i):
            b[i] -= LU[j, i] * b[j]
        b[i] /= LU[i, i]
    for i in range(v - 1, -1, -1):
        for j in range(i + 1, v):
            b[i] -= LU[j, i] * b[j]
    for c in range(v - 1, -1, -1):
        p = piv[c]
        if p != c:
            b[c], b[p] = b[p], b[c]


@kernel
def _row_dot(G, i, x):
    """(Σ_j G_ij x_j, Σ_j |G_ij x_j|) of row i."""
    acc, mag = 0.0, 0.0
    for j in range(G.shape[1]):
        acc += G[i, j] * x[j]
        mag += abs(G[i, j]) * abs(x[j])
    return acc, mag


@entry
def lp_vertices(G, g_lo, g_hi, norm, bound, c, lo, hi, cap_lo, cap_hi, r, idx, held, primal_tol, dual_tol,
                stat_tol, x, dual, ok, unbounded):
    """Vertices of k of a batch's LPs at given bases, certified optimal or unbounded (module docstring).

    Args:
        G: (N, R, v) the batch's rows: r constraint rows, then the identity (R = r + v).
        g_lo, g_hi: (N, R) their bounds, the columns' capped (±inf: none).
        norm: (N, R) max |G_ij| per row.
        bound: (N,) the largest finite row bound per problem.
        c: (v,) the cost.
        lo, hi: (v,) the columns' uncapped bounds.
        cap_lo, cap_hi: (v,) the columns' capped bounds.
        r: the number of constraint rows.
        idx: (k,) int64, the problems.
        held: (k, R) int8 the basis codes per row (0 lower, 1 basic, 2 upper, 3 zero).
        primal_tol, dual_tol, stat_tol: the certificates' relative tolerances (`coopsim.inverse.qp`).
        x: (k, v), written: the vertices.
        dual: (k, R), written: the rows' duals (0 on the basic ones).
        ok: (k,) bool, written: certified optimal.
        unbounded: (k,) bool, written: certified optimal at a cap with a descent ray (unbounded without it).
    """
    k, (R, v) = idx.shape[0], G.shape[1:]
    M, t, lam = np.empty((v, v)), np.empty(v), np.empty(v)
    order, piv = np.empty(v, np.int64), np.empty(v, np.int64)
    d = np.empty(v)
    cmax = 0.0
    for j in range(v):
        cmax = max(cmax, abs(c[j]))
    for p in range(k):
        q = idx[p]
        ok[p], unbounded[p] = False, False
        for i in range(R):
            dual[p, i] = 0.0
        for j in range(v):
            x[p, j] = 0.0
        n_held, valid = 0, True
        for i in range(R):
            h = held[p, i]
            if h > 3:
                valid = False
            if h != 1:
                if n_held < v:
                    order[n_held] = i
                n_held += 1
        if not valid or n_held != v:
            continue
        for a in range(v):
            i = order[a]
            h = held[p, i]
            t[a] = g_hi[q, i] if h == 2 else (0.0 if h == 3 else g_lo[q, i])
            if not np.isfinite(t[a]):
                valid = False
            for j in range(v):
                M[a, j] = G[q, i, j]
        if not valid or not _lu(M, v, piv):
            continue
        for a in range(v):
            x[p, a] = t[a]
            lam[a] = c[a]
        _lu_solve(M, v, piv, x[p])
        _lu_solve_transposed(M, v, piv, lam)
        finite = True
        for a in range(v):
            finite = finite and np.isfinite(x[p, a]) and np.isfinite(lam[a])
        if not finite:
            continue
        pscale, viol, res = bound[q], -np.inf, 0.0
        for i in range(R):
            gx, mag = _row_dot(G[q], i, x[p])
            pscale = max(pscale, mag)
            viol = max(viol, max(g_lo[q, i] - gx, gx - g_hi[q, i]))
        for a in range(v):
            dual[p, order[a]] = lam[a]
            gx, _ = _row_dot(G[q], order[a], x[p])
            res = max(res, abs(gx - t[a]))
        dscale, wrong = cmax, -np.inf
        for i in range(R):
            h = held[p, i]
            weight = abs(dual[p, i]) * norm[q, i]
            dscale = max(dscale, weight)
            if g_lo[q, i] == g_hi[q, i]:
                w = 0.0
            elif h == 3:
                w = weight
            elif h == 0:
                w = -dual[p, i] * norm[q, i]
            elif h == 2:
                w = dual[p, i] * norm[q, i]
            else:
                w = 0.0
            wrong = max(wrong, w)
        stat = 0.0
        for j in range(v):
            acc = 0.0
            for a in range(v):
                acc += lam[a] * G[q, order[a], j]
            stat = max(stat, abs(acc - c[j]))
        ok[p] = (viol <= primal_tol * pscale and res <= primal_tol * pscale and wrong <= dual_tol * dscale
                 and stat <= stat_tol * dscale)
        if ok[p]:
            unbounded[p] = _ray(G[q], g_lo[q], g_hi[q], c, lo, hi, cap_lo, cap_hi, r, held[p], order, M, piv, d,
                                primal_tol, dual_tol)


@kernel
def _ray(G, g_lo, g_hi, c, lo, hi, cap_lo, cap_hi, r, held, order, LU, piv, d, primal_tol, dual_tol):
    """At a certified vertex whose first capped column sits at its cap (none: False): whether the ray off
    that bound, the other held rows kept (M d = ±e), meets every row and the uncapped bounds and lowers
    the cost (`coopsim.inverse.qp._rays`)."""
    R, v = G.shape
    j = -1
    for q in range(v):
        h = held[r + q]
        if (cap_hi[q] < hi[q] and h == 2) or (cap_lo[q] > lo[q] and h == 0):
            j = q
            break
    if j < 0:
        return False
    for a in range(v):
        d[a] = 0.0
    for a in range(v):
        if order[a] == r + j:
            d[a] = 1.0 if cap_hi[j] < hi[j] else -1.0
            break
    _lu_solve(LU, v, piv, d)
    scale = 0.0
    for i in range(R):
        scale = max(scale, _row_dot(G, i, d)[1])
    tol = primal_tol * scale
    for i in range(R):
        gd = _row_dot(G, i, d)[0]
        up = g_hi[i] if i < r else hi[i - r]
        down = g_lo[i] if i < r else lo[i - r]
        if (gd > tol and np.isfinite(up)) or (gd < -tol and np.isfinite(down)):
            return False
    dc, mag = 0.0, 0.0
    for a in range(v):
        dc += d[a] * c[a]
        mag += abs(d[a]) * abs(c[a])
    return dc < -dual_tol * mag
