"""Small dense LPs, compiled, and the LP bound's reachability pass built on them (the step of
`coopsim.inverse.retime.lp_reachability` after its rows are built).

`dual_simplex`: max cᵀx subject to M x ≤ h (m rows, n free columns, M of full column rank), by the dual
simplex method in its active-set form: a basis is n rows B with M_B nonsingular and y = M_B⁻ᵀ c ≥ 0 (dual
feasible); its vertex x = M_B⁻¹ h_B. Each step enters the most violated row r (relative to its norm), the
multipliers move along w = M_B⁻ᵀ M_rᵀ, and the row of B whose multiplier reaches 0 first leaves (the ratio
test; ties: the smallest row index); no w_a > 0 and Σ w_a h_B,a > h_r: the LP is infeasible (a
nonnegative combination of the rows B and r is a contradiction). M_B is factorised again at each step (LU with partial pivoting,
`coopsim.compiled.lp._lu`), so no error accumulates over the steps. `dense_lp` starts from the rows of a
box around the variables (one of ±x_j ≤ cap_j per column, on the side of c_j's sign), which is dual
feasible; the stage LPs from the previous stage's basis (`_stage_lp`).

`lp_reachability_pass`: TOPP-RA's passes where each stage k is the polyhedron
{g a + h b + W z ≤ e} in (a, b, z): (a, b) = (s̈ on the interval, ṡ² at its start) and z the null-space
coordinates of the grasp wrenches of its points (slot 0 the start point, 1 the end point, 2 … the check
points). Backward from K_M = {0} at the end of each piece: K_i = [min b, max b] over the polyhedron cut by
lo_{i+1} ≤ b + 2Δa ≤ hi_{i+1} (two LPs; where that has no solution, the strip widened by tol_k, then 10 tol_k,
for the rounding of the stages before; then no controllable state), K_i = {0} at the
start of a piece (infeasible if min b > tol_k there). Forward from b = 0: the largest a at b = b_i with
b_i + 2Δa ≤ hi_{i+1} (one LP; where b_i lies off K_i by rounding and that has no solution, with the strip's
side moved out by tol_k, 10 tol_k, then without it), clipped to hi_{i+1} and raised to reach lo_{i+1}, as
`coopsim.compiled.reachability.reachability_pass` does; its z is the vertex's (off by tol_k/(2Δ) in a at
most where clipped). Cost per stage: a few simplex steps of O(n³ + m n) each, so linear in the stages.
"""

import numpy as np

from coopsim.compiled.lp import _lu, _lu_solve, _lu_solve_transposed
from coopsim.compiled.toolchain.jit import entry, kernel

OPTIMAL = 0
INFEASIBLE = 1       # no x meets the rows (dual_simplex); a stage without a controllable state (the pass)
NOT_SOLVED = 2       # the step limit, or a singular basis: the LP was not solved
PIVOT_TOL = 1e-9     # |w_a| relative to max |w| below which a row of the basis cannot leave
FEAS_TOL = 1e-12     # a row's violation relative to its norm, its bound's size and |M_r||x|
GROW = 1e3           # the factor a stage LP's box grows by while it binds
BOX_MARGIN = 1e-9    # a solution within this (relative) of the box's side is on it


@kernel
def _factor(M, h, n, B, x, LU, piv):
    """LU of M_B and the vertex x = M_B⁻¹ h_B; False at a singular basis."""
    for q in range(n):
        for j in range(n):
            LU[q, j] = M[B[q], j]
    if not _lu(LU, n, piv):
        return False
    for q in range(n):
        x[q] = h[B[q]]
    _lu_solve(LU, n, piv, x)
    return True


@kernel
def dual_feasible(M, h, n, c, B, x, LU, piv, w):
    """Whether the basis B is nonsingular with multipliers M_B⁻ᵀ c ≥ −PIVOT_TOL·max|·| (a warm start for
    `dual_simplex`).

    Args:
        M: (≥ m, ≥ n) the rows.
        h: (≥ m,) their bounds.
        n: the columns.
        c: (≥ n,) the objective.
        B: (≥ n,) int64 the basis (row indices).
        x: (≥ n,) written: the basis' vertex M_B⁻¹ h_B.
        LU, piv: (≥ n, ≥ n), (≥ n,) int64, written: M_B's factors.
        w: (≥ n,) written: the multipliers M_B⁻ᵀ c.

    Returns:
        bool: True where B is nonsingular and its multipliers are nonnegative (to the tolerance).
    """
    if not _factor(M, h, n, B, x, LU, piv):
        return False
    big = _multipliers(LU, n, piv, c, w)
    for q in range(n):
        if w[q] < -PIVOT_TOL * big:
            return False
    return True


@kernel
def _multipliers(LU, n, piv, c, w):
    """The basis' multipliers w = M_B⁻ᵀ c (LU: M_B's factors) written into w; returns max |w|."""
    for q in range(n):
        w[q] = c[q]
    _lu_solve_transposed(LU, n, piv, w)
    big = 0.0
    for q in range(n):
        big = max(big, abs(w[q]))
    return big


@kernel
def dual_simplex(M, h, m, n, c, B, in_basis, x, LU, piv, w, y, max_steps, count):
    """max cᵀx subject to M[:m, :n] x ≤ h[:m] from the dual-feasible basis B (n,) (module docstring).

    The entering row is the most violated one until two steps in a row leave the multipliers where they
    were (a degenerate step, common here: the objective weighs one column), then the violated row of
    least index, and ties of the ratio test go to the row of least index (Bland's rule, which cannot cycle).
    A violated row that no row of B can leave for is infeasible only if the combination w also contradicts
    the bounds (Σ w_q h_B,q > h_r, a Farkas certificate); otherwise its violation is the vertex's rounding
    (row r is then implied by B: the strip's two sides, say) and it is passed over until B changes. On
    OPTIMAL, LU holds the final basis' factors.

    Args:
        M: (≥ m, ≥ n) the rows (each of max-norm 1 for the tolerances to mean what they say).
        h: (≥ m,) their bounds.
        m, n: the rows and the columns.
        c: (≥ n,) the objective.
        B: (≥ n,) int64 the starting basis (row indices), overwritten with the final one.
        in_basis: (≥ m,) int8 scratch, written (1: in B, 2: a row found violated by rounding only).
        x: (≥ n,) written: the final basis' vertex.
        LU, piv, w, y: (≥ n, ≥ n), (≥ n,) int64, (≥ n,), (≥ n,) scratch.
        max_steps: the most simplex steps.
        count: (≥ 1,) int64, the steps taken added to count[0].

    Returns:
        int: OPTIMAL, INFEASIBLE or NOT_SOLVED.
    """
    for i in range(m):
        in_basis[i] = 0
    for q in range(n):
        in_basis[B[q]] = 1
    degenerate = 0
    for step in range(max_steps + 1):
        if step > 0:
            count[0] += 1
        if not _factor(M, h, n, B, x, LU, piv):
            return NOT_SOLVED
        r, worst = -1, 0.0
        for i in range(m):
            if in_basis[i] != 0:
                continue
            acc, mag = 0.0, 0.0
            for j in range(n):
                acc += M[i, j] * x[j]
                mag += abs(M[i, j] * x[j])
            v = acc - h[i]
            if v > FEAS_TOL * (1.0 + abs(h[i]) + mag) and v > worst:
                r, worst = i, v
                if degenerate >= 2:
                    break
        if r < 0:
            return OPTIMAL
        if step == max_steps:
            return NOT_SOLVED
        for q in range(n):
            y[q] = c[q]
            w[q] = M[r, q]
        _lu_solve_transposed(LU, n, piv, y)
        _lu_solve_transposed(LU, n, piv, w)
        wmax, ymax = 0.0, 0.0
        for q in range(n):
            wmax = max(wmax, abs(w[q]))
            ymax = max(ymax, abs(y[q]))
        out, best = -1, np.inf
        for q in range(n):
            if w[q] > PIVOT_TOL * wmax:
                ratio = (y[q] if y[q] > PIVOT_TOL * ymax else 0.0) / w[q]
                if out < 0 or ratio < best or (ratio == best and B[q] < B[out]):
                    out, best = q, ratio
        if out < 0:
            comb, mag = 0.0, 0.0
            for q in range(n):
                comb += w[q] * h[B[q]]
                mag += abs(w[q] * h[B[q]])
            if comb - h[r] > FEAS_TOL * (1.0 + abs(h[r]) + mag):
                return INFEASIBLE
            in_basis[r] = 2
            continue
        degenerate = degenerate + 1 if best == 0.0 else (degenerate if degenerate >= 2 else 0)
        for i in range(m):
            if in_basis[i] == 2:
                in_basis[i] = 0
        in_basis[B[out]] = 0
        B[out] = r
        in_basis[r] = 1
    return NOT_SOLVED


@entry
def dense_lp(M, h, c, cap, x):
    """max cᵀx subject to M x ≤ h and the box |x_j| ≤ cap_j, by `dual_simplex` (rows scaled to max-norm 1).

    Args:
        M: (m, n) the rows.
        h: (m,) their bounds (+inf: no row).
        c: (n,) the objective.
        cap: (n,) the box (finite, > 0).
        x: (n,) written: the solution.

    Returns:
        int: OPTIMAL, INFEASIBLE or NOT_SOLVED.
    """
    m, n = M.shape
    R = m + 2 * n
    A, b = np.zeros((R, n)), np.zeros(R)
    k = 0
    for i in range(m):
        if not np.isfinite(h[i]):
            continue
        s = 0.0
        for j in range(n):
            s = max(s, abs(M[i, j]))
        if s == 0.0:
            if h[i] < 0.0:
                return INFEASIBLE
            continue
        for j in range(n):
            A[k, j] = M[i, j] / s
        b[k] = h[i] / s
        k += 1
    B = np.empty(n, np.int64)
    for j in range(n):
        A[k, j], b[k] = 1.0, cap[j]
        A[k + 1, j], b[k + 1] = -1.0, cap[j]
        B[j] = k if c[j] >= 0.0 else k + 1
        k += 2
    LU, piv, w, y = np.empty((n, n)), np.empty(n, np.int64), np.empty(n), np.empty(n)
    return dual_simplex(A, b, k, n, c, B, np.zeros(k, np.int8), x, LU, piv, w, y, 50 + 10 * (k + n),
                        np.zeros(1, np.int64))


@kernel
def _stage_rows(g, h, e, slot, W, r0, r1, nz, ns, d, fix_b, b_fix, strip_lo, strip_hi, cap_a, cap_b, cap_z, M, rhs):
    """The rows of one stage LP into M, rhs (max-norm 1), in a fixed order so that a neighbouring stage's
    basis means the same rows: ±a ≤ cap_a, b ≤ cap_b and −b ≤ 0 (b = b_fix: b ≤ b_fix, −b ≤ −b_fix), the strip
    lo ≤ b + 2Δa ≤ hi, ±z_j ≤ cap_z, then the stage's rows r0 … r1 − 1 (an infinite bound, or a strip side
    that is infinite: 0 ≤ 1). Returns (m, n)."""
    n = 2 + nz * ns
    m = 6 + 2 * (n - 2) + (r1 - r0)
    for i in range(m):
        for j in range(n):
            M[i, j] = 0.0
    M[0, 0], rhs[0] = 1.0, cap_a
    M[1, 0], rhs[1] = -1.0, cap_a
    M[2, 1], rhs[2] = 1.0, (b_fix if fix_b else cap_b)
    M[3, 1], rhs[3] = -1.0, (-b_fix if fix_b else 0.0)
    rhs[4], rhs[5] = 1.0, 1.0
    if np.isfinite(strip_hi):
        M[4, 0], M[4, 1], rhs[4] = 2.0 * d, 1.0, strip_hi
    if np.isfinite(strip_lo):
        M[5, 0], M[5, 1], rhs[5] = -2.0 * d, -1.0, -strip_lo
    for j in range(2, n):
        M[6 + 2 * (j - 2), j], rhs[6 + 2 * (j - 2)] = 1.0, cap_z
        M[7 + 2 * (j - 2), j], rhs[7 + 2 * (j - 2)] = -1.0, cap_z
    k = 6 + 2 * (n - 2)
    for r in range(r0, r1):
        if not np.isfinite(e[r]):
            rhs[k] = 1.0
            k += 1
            continue
        M[k, 0], M[k, 1], rhs[k] = g[r], h[r], e[r]
        if slot[r] >= 0:
            base = 2 + nz * slot[r]
            for j in range(nz):
                M[k, base + j] = W[r, j]
        k += 1
    for i in range(4, m):
        s = 0.0
        for j in range(n):
            s = max(s, abs(M[i, j]))
        if s > 0.0:
            for j in range(n):
                M[i, j] /= s
            rhs[i] /= s
    return m, n


@kernel
def _is_box(row, n, fix_b):
    """Whether a stage LP's row (`_stage_rows`) is a side of the box (±a, b's upper side unless b is fixed, ±z)."""
    return row <= 1 or (row == 2 and not fix_b) or (6 <= row < 6 + 2 * (n - 2))


@kernel
def _off_the_box(M, rhs, m, n, c, B, in_basis, x, LU, piv, d, t, fix_b, ymax):
    """At an optimal vertex, replace each side of the box in the basis B whose multiplier is 0 (in t, from
    `_stage_lp`; again after each change) by the first row met moving off that side with the other rows of B
    kept (M_B d = −e_q): the objective does not change (cᵀd = −y_q = 0), so the new vertex is optimal. A side
    left for another side of the box stays (the problem is unbounded that way). x is the final vertex."""
    for q in range(n):
        if not (_is_box(B[q], n, fix_b) and not t[q] > PIVOT_TOL * ymax):
            continue
        for j in range(n):
            d[j] = 0.0
        d[q] = -1.0
        _lu_solve(LU, n, piv, d)
        best, enter = np.inf, -1
        for i in range(m):
            if in_basis[i] == 1:
                continue
            md, mx, mag = 0.0, 0.0, 0.0
            for j in range(n):
                md += M[i, j] * d[j]
                mx += M[i, j] * x[j]
                mag += abs(M[i, j] * d[j])
            if md > PIVOT_TOL * mag and md > 0.0:
                step = max(rhs[i] - mx, 0.0) / md
                if step < best:
                    best, enter = step, i
        if enter < 0 or _is_box(enter, n, fix_b):
            continue
        in_basis[B[q]] = 0
        B[q] = enter
        in_basis[enter] = 1
        if not _factor(M, rhs, n, B, x, LU, piv):
            return
        for j in range(n):
            t[j] = c[j]
        _lu_solve_transposed(LU, n, piv, t)


@kernel
def _slot_rows(M, slot, r0, r1, base, nz, p, B, at, Q, v):
    """Into B[at:at + nz], nz rows of point p among the stage rows r0 … r1 − 1 (M's rows base + r − r0) whose
    z_p coefficients are independent (greedy Gram–Schmidt; Q (≥ nz, ≥ nz) and v (≥ nz,) scratch). With z_p's
    columns square and nonsingular there, any multipliers of those rows are 0 in a basis where the other
    rows carry no z_p. Returns False when fewer than nz are found."""
    got = 0
    col = 2 + nz * p
    for r in range(r0, r1):
        if got == nz:
            break
        if slot[r] != p:
            continue
        k = base + r - r0
        norm = 0.0
        for j in range(nz):
            v[j] = M[k, col + j]
            norm += v[j] * v[j]
        if not norm > 0.0:
            continue
        for q in range(got):
            dot = 0.0
            for j in range(nz):
                dot += Q[q, j] * v[j]
            for j in range(nz):
                v[j] -= dot * Q[q, j]
        res = 0.0
        for j in range(nz):
            res += v[j] * v[j]
        if res > 1e-12 * norm:
            res = np.sqrt(res)
            for j in range(nz):
                Q[got, j] = v[j] / res
            B[at + got] = k
            got += 1
    return got == nz


@kernel
def _extend(saved, m_prev, n_prev, m, n, nz, ns, slot, r0, r1, M, B, Q, v):
    """B from the basis `saved` of an LP of the same kind with n_prev ≤ n columns (`_stage_rows`' layout: its
    box rows kept, its stage rows moved to this stage's, a row past this stage's: False), and for each point
    it did not have, nz of that point's rows (`_slot_rows`)."""
    base_prev, base = 6 + 2 * (n_prev - 2), 6 + 2 * (n - 2)
    for q in range(n_prev):
        row = saved[q]
        if row >= base_prev:
            row += base - base_prev
        if row >= m:
            return False
        B[q] = row
    for p in range((n_prev - 2) // nz if nz > 0 else 0, ns):
        if not _slot_rows(M, slot, r0, r1, base, nz, p, B, 2 + nz * p, Q, v):
            return False
    return True


@kernel
def _stage_lp(g, h, e, slot, W, r0, r1, nz, ns, d, fix_b, b_fix, strip_lo, strip_hi, caps, cap_max, clean,
              c, M, rhs, B, saved, shape, in_basis, x, LU, piv, w, y, count):
    """One stage LP (`_stage_rows`), max cᵀx by `dual_simplex`, in a box grown GROW× from caps (a, b, z) up
    to cap_max until no side of the box in the final basis has a positive multiplier (then its optimum is
    the LP's without the box: its multipliers are dual feasible there; b's lower side b ≥ 0 is a row of the
    problem) or, infeasible, the box is the largest. With `clean`, the vertex is then moved off the box's
    sides in the basis (`_off_the_box`), so that the wrenches' coordinates are those of a vertex of the
    problem's own rows. Each solve starts from the basis `saved` of the last LP of the same kind (`_extend`:
    its rows, and for points it did not have nz of their own rows) where it is dual feasible here, else from
    the box's sides for a and b (the side of c_j's sign) and nz rows of each point (`_slot_rows`; the
    multipliers of those are 0, so dual feasible); `saved` and `shape` (m, n) updated on success; count (4,) adds
    [LPs solved, simplex steps, cold starts, box growths]. Returns the status."""
    ca, cb, cz = caps[0], caps[1], caps[2]
    while True:
        m, n = _stage_rows(g, h, e, slot, W, r0, r1, nz, ns, d, fix_b, b_fix, strip_lo, strip_hi, ca, cb, cz, M,
                           rhs)
        warm = False
        if 2 <= shape[1] <= n:
            warm = _extend(saved, shape[0], shape[1], m, n, nz, ns, slot, r0, r1, M, B, LU, w)
            if warm:
                warm = dual_feasible(M, rhs, n, c, B, x, LU, piv, w)
        count[0] += 1
        if not warm:
            count[2] += 1
            B[0] = 0 if c[0] >= 0.0 else 1
            B[1] = 2 if c[1] >= 0.0 else 3
            for p in range(ns):
                if not _slot_rows(M, slot, r0, r1, 6 + 2 * (n - 2), nz, p, B, 2 + nz * p, LU, w):
                    for j in range(2 + nz * p, 2 + nz * (p + 1)):
                        B[j] = 6 + 2 * (j - 2) + (0 if c[j] >= 0.0 else 1)
        status = dual_simplex(M, rhs, m, n, c, B, in_basis, x, LU, piv, w, y, 50 + 10 * (m + n), count[1:])
        last = ca >= cap_max[0] and cb >= cap_max[1] and cz >= cap_max[2]
        if status == OPTIMAL:
            for q in range(n):
                saved[q] = B[q]
            shape[0], shape[1] = m, n
            ymax = _multipliers(LU, n, piv, c, y)
            binding = False
            for q in range(n):
                if _is_box(B[q], n, fix_b) and y[q] > PIVOT_TOL * ymax:
                    binding = True
            if not binding or last:
                if clean:
                    _off_the_box(M, rhs, m, n, c, B, in_basis, x, LU, piv, w, y, fix_b, ymax)
                return status
        elif status == NOT_SOLVED or last:
            return status
        count[3] += 1
        ca, cb, cz = min(ca * GROW, cap_max[0]), min(cb * GROW, cap_max[1]), min(cz * GROW, cap_max[2])


@entry
def lp_reachability_pass(g, h, e, slot, W, off, nslot, d, tol, caps, cap_max, start, end_at, start_at,
                         b, lo, hi, a, z, count):
    """The backward and forward passes over K stages (module docstring); b, lo, hi (N,), a (K,), z (K, 2, nz)
    written.

    Args:
        g, h, e: (R,) the stages' rows g a + h b + W z ≤ e, flat (stage k: rows off[k] … off[k + 1] − 1;
            e = +inf: no row).
        slot: (R,) int64 the point of its stage whose z the row's W multiplies (−1: none).
        W: (R, nz) those coefficients.
        off: (K + 1,) int64 row offsets.
        nslot: (K,) int64 the points carrying z per stage (≥ 2: its two grid points first).
        d: (K,) the intervals' lengths Δ.
        tol: (K,) each stage's feasibility tolerance (the strip's slack and a piece start's rest).
        caps: (K, 3) the first box around a, b and each z per stage (grown where it binds, `_stage_lp`).
        cap_max: (3,) the largest box.
        start: (K,) int64 the grid point each stage starts at (its interval i → i + 1).
        end_at: (K,) bool, i + 1 ends a piece.
        start_at: (K,) bool, i starts a piece.
        b, lo, hi: (N,) out, ṡ² and the controllable sets' bounds.
        a: (K,) out, s̈ per stage.
        z: (K, 2, nz) out, the null-space coordinates at the stage's two grid points in its forward LP.
        count: (4,) int64 out, [stage LPs solved, simplex steps, cold starts, box growths].

    Returns:
        int: 0, INFEASIBLE, or NOT_SOLVED (a stage LP not solved).
    """
    K, nz = len(d), W.shape[1]
    ns_max, m_max = 2, 1
    for k in range(K):
        ns_max = max(ns_max, nslot[k])
        m_max = max(m_max, off[k + 1] - off[k])
    n_max = 2 + nz * ns_max
    R = m_max + 6 + 2 * n_max
    M, rhs = np.empty((R, n_max)), np.empty(R)
    B, in_basis = np.empty(n_max, np.int64), np.zeros(R, np.int8)
    saved, shape = np.zeros((3, n_max), np.int64), np.full((3, 2), -1, np.int64)
    x, LU, piv = np.empty(n_max), np.empty((n_max, n_max)), np.empty(n_max, np.int64)
    w, y = np.empty(n_max), np.empty(n_max)
    c = np.zeros(n_max)
    bounds = np.empty(2)
    count[:] = 0
    lo[:] = 0.0
    hi[:] = 0.0
    b[:] = 0.0
    for k in range(K - 1, -1, -1):
        i = start[k]
        if end_at[k]:
            lo[i + 1] = 0.0
            hi[i + 1] = 0.0
        for side in range(2):
            for j in range(n_max):
                c[j] = 0.0
            c[1] = 1.0 if side == 0 else -1.0
            for attempt in range(3):                              # the strip, then with slack (rounding)
                slack = (0.0, tol[k], 10.0 * tol[k])[attempt]
                status = _stage_lp(g, h, e, slot, W, off[k], off[k + 1], nz, nslot[k], d[k], False, 0.0,
                                   lo[i + 1] - slack, hi[i + 1] + slack, caps[k], cap_max, False, c, M, rhs,
                                   B, saved[side], shape[side], in_basis, x, LU, piv, w, y, count)
                if status != INFEASIBLE:
                    break
            if status != OPTIMAL:
                return status
            bounds[side] = x[1]
        lo[i], hi[i] = max(bounds[1], 0.0), bounds[0]
        if start_at[k]:
            if lo[i] > tol[k]:
                return INFEASIBLE
            lo[i] = 0.0
            hi[i] = 0.0
    for j in range(n_max):
        c[j] = 0.0
    c[0] = 1.0
    for k in range(K):
        i = start[k]
        top = (hi[i + 1] - b[i]) / (2.0 * d[k])
        for attempt in range(4):                                  # the strip's side: hi, then with slack, then none
            slack = (0.0, tol[k], 10.0 * tol[k], np.inf)[attempt]
            status = _stage_lp(g, h, e, slot, W, off[k], off[k + 1], nz, nslot[k], d[k], True, b[i], -np.inf,
                               hi[i + 1] + slack, caps[k], cap_max, True, c, M, rhs, B, saved[2], shape[2],
                               in_basis, x, LU, piv, w, y, count)
            if status != INFEASIBLE:
                break
        if status != OPTIMAL:
            return status
        step = min(x[0], top)
        step = max(step, (lo[i + 1] - b[i]) / (2.0 * d[k]))
        a[k] = step
        for p in range(2):
            for j in range(nz):
                z[k, p, j] = x[2 + nz * p + j]
        b[i + 1] = max(b[i] + 2.0 * d[k] * step, 0.0)
    return 0
