"""TOPP-RA's reachability pass, compiled: the step of `coopsim.inverse.retime.reachability` after its rows
are built (`coopsim.inverse.retime.reachability_reference`, the NumPy reference, in the same words).

Stage k (K stages, interval i → i + 1 of length Δ_k) has the polygon {G a + H b ≤ E} in its (a, b) = (s̈ on
the interval, ṡ² at its start), its rows ragged: rows off[k] … off[k + 1] − 1 of the flat G, H, E.
Backward from K_M = {0} at the end of each piece: K_i = [lo_i, hi_i] the range of b over the polygon cut
by the strip lo_{i+1} ≤ b + 2Δa ≤ hi_{i+1}: its vertices (every pair of rows meeting at a point within
every row to tol_k) inside the strip, and the polygon's chords on the strip's two lines; K_i = {0} at the
start of a piece (infeasible if lo_i > tol_k there). Forward from b = 0: the largest a of the polygon at
b_i, clipped to reach K_{i+1}. Cost: per stage O(m³) for m rows (vertex enumeration), so linear in K.
"""

import numpy as np

from coopsim.compiled.toolchain.jit import entry, kernel

INFEASIBLE = 1      # a stage without a controllable state, or a piece start that cannot be at rest


@kernel
def _segment_b(G, H, E, lo_row, hi_row, d, h, tol, out):
    """(min, max) b of the polygon rows lo_row … hi_row − 1 on the line b + 2d a = h into out[0:2]; False:
    they do not meet."""
    a_hi, a_lo = np.inf, -np.inf
    for r in range(lo_row, hi_row):
        g = G[r] - 2.0 * d * H[r]
        res = E[r] - H[r] * h
        if g > 0.0:
            a_hi = min(a_hi, res / g)
        elif g < 0.0:
            a_lo = max(a_lo, res / g)
        elif res < -tol:
            return False
    if a_lo > a_hi + tol:
        return False
    if a_lo > a_hi:
        a_lo, a_hi = a_hi, a_lo
    out[0] = h - 2.0 * d * a_hi
    out[1] = h - 2.0 * d * a_lo
    return True


@kernel
def _stage_range(G, H, E, r0, r1, d, lo_next, hi_next, tol, seg):
    """(lo, hi) of K_i for stage rows r0 … r1 − 1 (`reachability_pass`); (nan, nan) without a candidate."""
    lo, hi = np.inf, -np.inf
    for p in range(r0, r1):
        for q in range(p + 1, r1):
            det = G[p] * H[q] - G[q] * H[p]
            if not abs(det) > 1e-300:
                continue
            a = (E[p] * H[q] - E[q] * H[p]) / det
            b = (G[p] * E[q] - G[q] * E[p]) / det
            if not (np.isfinite(a) and np.isfinite(b)):
                continue
            inside = b + 2.0 * d * a
            if not (inside >= lo_next - tol and inside <= hi_next + tol):
                continue
            ok = True
            for r in range(r0, r1):
                if not G[r] * a + H[r] * b <= E[r] + tol:
                    ok = False
                    break
            if ok:
                lo, hi = min(lo, b), max(hi, b)
    for h in (lo_next, hi_next):
        if _segment_b(G, H, E, r0, r1, d, h, tol, seg):
            for x in seg:
                if np.isfinite(x):
                    lo, hi = min(lo, x), max(hi, x)
    if lo > hi:
        return np.nan, np.nan
    return lo, hi


@entry
def reachability_pass(G, H, E, off, d, tol, start, end_at, start_at, b, lo, hi):
    """The backward and forward passes over K stages; b, lo, hi (N,) written (b = ṡ² at the points).

    Args:
        G, H, E: (R,) the stages' rows, flat (stage k: rows off[k] … off[k + 1] − 1).
        off: (K + 1,) int64 row offsets.
        d: (K,) the intervals' lengths Δ.
        tol: (K,) each stage's feasibility tolerance.
        start: (K,) int64 the grid point each stage starts at (its interval i → i + 1).
        end_at: (K,) bool, i + 1 ends a piece.
        start_at: (K,) bool, i starts a piece.
        b, lo, hi: (N,) out, ṡ² and the controllable sets' bounds.

    Returns:
        int: 0, or INFEASIBLE.
    """
    K = len(d)
    seg = np.empty(2)
    lo[:] = 0.0
    hi[:] = 0.0
    b[:] = 0.0
    for k in range(K - 1, -1, -1):
        i = start[k]
        if end_at[k]:
            lo[i + 1] = 0.0
            hi[i + 1] = 0.0
        l, h = _stage_range(G, H, E, off[k], off[k + 1], d[k], lo[i + 1], hi[i + 1], tol[k], seg)
        if not (l <= h):
            return INFEASIBLE
        lo[i], hi[i] = max(l, 0.0), h
        if start_at[k]:
            if lo[i] > tol[k]:
                return INFEASIBLE
            lo[i] = 0.0
            hi[i] = 0.0
    for k in range(K):
        i = start[k]
        a_max = np.inf
        for r in range(off[k], off[k + 1]):
            if G[r] > 0.0:
                a_max = min(a_max, (E[r] - H[r] * b[i]) / G[r])
        a = min(a_max, (hi[i + 1] - b[i]) / (2.0 * d[k]))
        a = max(a, (lo[i + 1] - b[i]) / (2.0 * d[k]))
        b[i + 1] = max(b[i] + 2.0 * d[k] * a, 0.0)
    return 0
