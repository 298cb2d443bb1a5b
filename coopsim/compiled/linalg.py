"""Small dense linear algebra, in place, for the compiled kernels (no allocation on the hot path).

The constraint system (Λ𝐈⁻¹Λᵀ) F = b is solved by a Cholesky factorization with diagonal pivoting
when the matrix is provably of full rank, else by the reference's eigen-decomposition (minimum-norm
solution, numerical rank from eigenvalues above rank_tol·λ_max). The proof is a certified lower bound
of λ_min/λ_max from the factor: A⁻¹ = Pᵀ L⁻ᵀ L⁻¹ P, so λ_min = 1/‖A⁻¹‖₂ ≥ 1/‖L⁻¹‖_F², and
λ_max ≤ trace A; the bound 1/(‖L⁻¹‖_F² trace A) is at most K² times below the true ratio, so the
eigen-decomposition runs only for matrices within K² of the rank threshold (cost: K³/6 flops).
(The block-diagonal mass matrix is factored inside `closed_chain.chain_solve`.) The factorization and the
solve borrow their array arguments on entry (`structs.borrow`): no reference counting on them.
"""

from __future__ import annotations

import numpy as np

from coopsim.compiled.structs import borrow
from coopsim.compiled.toolchain.jit import kernel


@kernel
def pivoted_cholesky(A, Lf, perm, K):
    """Cholesky factorization with diagonal pivoting P A Pᵀ = L Lᵀ of the symmetric PSD A (K, K).

    L goes into Lf (lower), perm[i] the row of A in position i. Works on the lower triangle (A's is read;
    Lf's strict upper triangle is scratch for the columns of L⁻¹): a pivot swaps rows and columns j, p of
    the symmetric trailing matrix as LAPACK's dsyswapr does, and rows j, p of the columns already factored.

    Args:
        A: (K, K) the symmetric PSD matrix (its lower triangle read), unchanged.
        Lf: (K, K) written: L in the lower triangle, scratch in the strict upper one.
        perm: (K,) int, written: the pivots, perm[i] the row of A in position i.
        K: the order of A.

    Returns:
        float: the certified lower bound 1/(‖L⁻¹‖_F² trace A) of λ_min/λ_max (module docstring); 0 if a
            pivot is not positive (and then Lf is incomplete).
    """
    A, Lf, perm = borrow(A), borrow(Lf), borrow(perm)
    for i in range(K):
        perm[i] = i
        for j in range(i + 1):
            Lf[i, j] = A[i, j]
    for j in range(K):
        best, p = -1.0, j
        for i in range(j, K):
            if Lf[i, i] > best:
                best, p = Lf[i, i], i
        if p != j:
            for t in range(j):
                Lf[j, t], Lf[p, t] = Lf[p, t], Lf[j, t]
            Lf[j, j], Lf[p, p] = Lf[p, p], Lf[j, j]
            for i in range(j + 1, p):
                Lf[i, j], Lf[p, i] = Lf[p, i], Lf[i, j]
            for i in range(p + 1, K):
                Lf[i, j], Lf[i, p] = Lf[i, p], Lf[i, j]
            perm[j], perm[p] = perm[p], perm[j]
        d = Lf[j, j]
        if not d > 0.0:
            return 0.0
        dj = np.sqrt(d)
        inv = 1.0 / dj
        Lf[j, j] = dj
        for i in range(j + 1, K):
            Lf[i, j] *= inv
        for c in range(j + 1, K):
            lc = Lf[c, j]
            for i in range(c, K):
                Lf[i, c] -= Lf[i, j] * lc
    return 1.0 / (inverse_factor_norm2(Lf, 0, K) * trace(A, K))


@kernel
def trace(A, K):
    """The trace of A[:K, :K].

    Args:
        A: (K, K) or larger, a square matrix.
        K: the order of the leading block summed.

    Returns:
        float: Σ_{i<K} A[i, i].
    """
    v = 0.0
    for i in range(K):
        v += A[i, i]
    return v


@kernel
def inverse_factor_norm2(Lf, o, K):
    """‖L⁻¹‖_F² of the lower factor L = Lf[o:o+K, o:o+K].

    Column j of L⁻¹ by forward substitution (L x = e_j, x_i = 0 for i < j), its entries below the
    diagonal kept in row j of the block's strict upper triangle. (The block is addressed by its offset
    o, not passed as a view, so that every caller shares one compiled specialization.)

    Args:
        Lf: (≥ o+K, ≥ o+K) holding L in the lower triangle of the block; the block's strict upper
            triangle is overwritten with the columns of L⁻¹ (transposed).
        o: the offset of the block's first row and column.
        K: the order of the block.

    Returns:
        float: ‖L⁻¹‖_F².
    """
    total = 0.0
    for j in range(o, o + K):
        xj = 1.0 / Lf[j, j]
        total += xj * xj
        for i in range(j + 1, o + K):
            v = -Lf[i, j] * xj
            for t in range(j + 1, i):
                v -= Lf[i, t] * Lf[j, t]
            v /= Lf[i, i]
            Lf[j, i] = v
            total += v * v
    return total


@kernel
def cholesky(H, d):
    """Cholesky factorisation H = L Lᵀ in place, unpivoted (the lower triangle of H becomes L).

    Args:
        H: (≥ d, ≥ d) the symmetric matrix, its lower triangle read and overwritten.
        d: the size used.

    Returns:
        bool: False when a pivot is not positive (H not positive definite; H then partly overwritten).
    """
    for c in range(d):
        for r in range(c, d):
            acc = H[r, c]
            for q in range(c):
                acc -= H[r, q] * H[c, q]
            if r == c:
                if not acc > 0.0:
                    return False
                H[c, c] = np.sqrt(acc)
            else:
                H[r, c] = acc / H[c, c]
    return True


@kernel
def cholesky_solve(L, d, x):
    """x ← (L Lᵀ)⁻¹ x in place: the forward and back substitutions of a `cholesky` factor.

    Args:
        L: (≥ d, ≥ d) the factor, its lower triangle read.
        d: the size used.
        x: (≥ d,) the right-hand side, overwritten by the solution.
    """
    for a in range(d):
        for q in range(a):
            x[a] -= L[a, q] * x[q]
        x[a] /= L[a, a]
    for a in range(d - 1, -1, -1):
        for q in range(a + 1, d):
            x[a] -= L[q, a] * x[q]
        x[a] /= L[a, a]


@kernel
def trace_of_inverse(L, d, x):
    """trace(H⁻¹) = ‖L⁻¹‖_F² for H = L Lᵀ, column by column of L⁻¹.

    Args:
        L: (≥ d, ≥ d) a `cholesky` factor, its lower triangle read.
        d: the size used.
        x: (≥ d,) scratch.

    Returns:
        float: trace(H⁻¹).
    """
    total = 0.0
    for c in range(d):                           # column c of L⁻¹: L x = e_c (x_r = 0 for r < c)
        for r in range(c, d):
            acc = 1.0 if r == c else 0.0
            for k in range(c, r):
                acc -= L[r, k] * x[k]
            x[r] = acc / L[r, r]
            total += x[r] * x[r]
    return total


@kernel
def pivoted_solve(Lf, perm, K, b, y, x):
    """x ← A⁻¹ b with the factors of `pivoted_cholesky` (P A Pᵀ = L Lᵀ: L Lᵀ (P x) = P b).

    x holds the reciprocals 1/L_ii until the end (the substitutions multiply: no division on their
    dependency chain).

    Args:
        Lf: (K, K) the factor L of `pivoted_cholesky` (lower triangle read).
        perm: (K,) int, its pivots.
        K: the order of A.
        b: (K,) the right-hand side, unchanged; it may alias neither y nor x.
        y: (K,) scratch.
        x: (K,) written: the solution.
    """
    Lf, perm, b, y, x = borrow(Lf), borrow(perm), borrow(b), borrow(y), borrow(x)
    for i in range(K):
        x[i] = 1.0 / Lf[i, i]
    for i in range(K):
        v = b[perm[i]]
        for k in range(i):
            v -= Lf[i, k] * y[k]
        y[i] = v * x[i]
    for i in range(K - 1, -1, -1):
        v = y[i]
        for k in range(i + 1, K):
            v -= Lf[k, i] * y[k]
        y[i] = v * x[i]
    for i in range(K):
        x[perm[i]] = y[i]


@kernel
def safe_pivot_ratio(K, rank_tol):
    """The value of `pivoted_cholesky`'s certified ratio above which λ_min/λ_max > rank_tol is proven.

    It is rank_tol itself: the bound is rigorous.

    Args:
        K: the order of the system (unused: kept for the callers' signature).
        rank_tol: the relative eigenvalue threshold of the rank decision.

    Returns:
        float: rank_tol.
    """
    return rank_tol


@kernel
def eig_solve(A, b, x, K, rank_tol):
    """Minimum-norm solution x of A x = b (A symmetric PSD) from its eigen-decomposition.

    Keeps the eigenvalues above rank_tol·λ_max. Allocates: used only off the hot path (near-singular
    systems).

    Args:
        A: (K, K) the symmetric PSD matrix, unchanged.
        b: (K,) the right-hand side, unchanged.
        x: (K,) written: the minimum-norm solution.
        K: the order of A.
        rank_tol: the relative eigenvalue threshold: eigenvalues λ > rank_tol·λ_max are kept.

    Returns:
        tuple[float, int]: the condition number λ_max/λ_min (inf when λ_min ≤ 0 or K = 0), and the
            numerical rank.
    """
    ev, V = np.empty(K), np.empty((K, K))
    jacobi_eigh(A, K, ev, V, True)
    top = ev[K - 1] if K > 0 else 0.0
    rank = 0
    for i in range(K):
        x[i] = 0.0
    for j in range(K):
        if ev[j] > rank_tol * top:
            rank += 1
            c = 0.0
            for i in range(K):
                c += V[i, j] * b[i]
            c /= ev[j]
            for i in range(K):
                x[i] += c * V[i, j]
    cond = top / ev[0] if K > 0 and ev[0] > 0 else np.inf
    return cond, rank


JACOBI_SWEEPS = 100


@kernel
def jacobi_eigh(A, K, ev, V, vectors):
    """Eigenvalues (ascending) and, with `vectors`, orthonormal eigenvectors of the symmetric A[:K, :K].

    By the cyclic Jacobi method (Golub & Van Loan, *Matrix Computations*, 4th ed., Alg. 8.5.3; rotations
    as Numerical Recipes' `jacobi`): sweeps of plane rotations zeroing each off-diagonal entry, until the
    off-diagonal part is below ε²·‖A‖_F² (absolute error ≈ ε‖A‖, as LAPACK's dsyev). Allocates a K × K
    copy. Replaces `np.linalg.eigh`, whose numba wrapper adds a long compile to every entry that reaches
    it.

    Args:
        A: (K, K) or larger, symmetric; A[:K, :K] read, unchanged.
        K: the order.
        ev: (K,) written: the eigenvalues, ascending.
        V: (K, K) written with `vectors`: the eigenvectors as its columns, in the order of ev (not touched
            otherwise).
        vectors: whether to compute the eigenvectors.
    """
    a = np.empty((K, K))
    total = 0.0
    for i in range(K):
        for j in range(K):
            a[i, j] = A[i, j]
            total += A[i, j] * A[i, j]
            if vectors:
                V[i, j] = 1.0 if i == j else 0.0
    for _ in range(JACOBI_SWEEPS):
        off = 0.0
        for p in range(K - 1):
            for q in range(p + 1, K):
                off += a[p, q] * a[p, q]
        if not off > 1e-32 * total:
            break
        for p in range(K - 1):
            for q in range(p + 1, K):
                if a[p, q] != 0.0:
                    _jacobi_rotate(a, V, K, p, q, vectors)
    for i in range(K):
        ev[i] = a[i, i]
    _sort_pairs(ev, V, K, vectors)


@kernel
def _jacobi_rotate(a, V, K, p, q, vectors):
    """a ← Jᵀ a J and V ← V J for the rotation J in the (p, q) plane that zeroes a[p, q]."""
    theta = (a[q, q] - a[p, p]) / (2.0 * a[p, q])
    t = 1.0 / (abs(theta) + np.sqrt(theta * theta + 1.0))
    if theta < 0.0:
        t = -t
    c = 1.0 / np.sqrt(t * t + 1.0)
    s = t * c
    for k in range(K):
        akp, akq = a[k, p], a[k, q]
        a[k, p] = c * akp - s * akq
        a[k, q] = s * akp + c * akq
    for k in range(K):
        apk, aqk = a[p, k], a[q, k]
        a[p, k] = c * apk - s * aqk
        a[q, k] = s * apk + c * aqk
    a[p, q] = 0.0
    a[q, p] = 0.0
    if vectors:
        for k in range(K):
            vkp, vkq = V[k, p], V[k, q]
            V[k, p] = c * vkp - s * vkq
            V[k, q] = s * vkp + c * vkq


@kernel
def _sort_pairs(ev, V, K, vectors):
    """Sort ev (K,) ascending, the columns of V with it (selection sort: K is small)."""
    for i in range(K - 1):
        j = i
        for k in range(i + 1, K):
            if ev[k] < ev[j]:
                j = k
        if j != i:
            ev[i], ev[j] = ev[j], ev[i]
            if vectors:
                for k in range(K):
                    V[k, i], V[k, j] = V[k, j], V[k, i]


@kernel
def singular_ratio(G, m, n):
    """σ_min/σ_max of G[:m, :n] (m ≥ n) by one-sided Jacobi (`column_singular_ratio` on a copy).

    Allocates an m × n copy.

    Args:
        G: (m, n) or larger; G[:m, :n] read, unchanged.
        m, n: the rows and columns of the block, m ≥ n.

    Returns:
        float: σ_min/σ_max in [0, 1]; 0 for a zero or non-finite G.
    """
    U = np.empty((m, n))
    for i in range(m):
        for j in range(n):
            U[i, j] = G[i, j]
            if not np.isfinite(G[i, j]):
                return 0.0
    return column_singular_ratio(U, m, n)


@kernel
def column_singular_ratio(U, m, n):
    """σ_min/σ_max of the finite U[:m, :n] (m ≥ n) by one-sided Jacobi, rotating U's columns in place.

    Hestenes' method (Demmel & Veselić 1992: high relative accuracy): plane rotations of column pairs
    until every pair is orthogonal to 1e-15 of its norms (|u_iᵀu_j| ≤ 1e-15 ‖u_i‖‖u_j‖, compared
    squared); the singular values are then the columns' norms.

    Args:
        U: (m, n) or larger, finite; U[:m, :n] overwritten (its columns rotated: the singular values
            are kept).
        m, n: the rows and columns of the block, m ≥ n.

    Returns:
        float: σ_min/σ_max in [0, 1]; 0 for a zero U.
    """
    for _ in range(JACOBI_SWEEPS):
        rotated = False
        for i in range(n - 1):
            for j in range(i + 1, n):
                al, be, ga = 0.0, 0.0, 0.0
                for k in range(m):
                    al += U[k, i] * U[k, i]
                    be += U[k, j] * U[k, j]
                    ga += U[k, i] * U[k, j]
                if ga * ga <= 1e-30 * (al * be):
                    continue
                rotated = True
                zeta = (be - al) / (2.0 * ga)
                t = 1.0 / (abs(zeta) + np.sqrt(1.0 + zeta * zeta))
                if zeta < 0.0:
                    t = -t
                c = 1.0 / np.sqrt(1.0 + t * t)
                s = c * t
                for k in range(m):
                    ui, uj = U[k, i], U[k, j]
                    U[k, i] = c * ui - s * uj
                    U[k, j] = s * ui + c * uj
        if not rotated:
            break
    lo, hi = np.inf, 0.0
    for j in range(n):
        v = 0.0
        for k in range(m):
            v += U[k, j] * U[k, j]
        v = np.sqrt(v)
        lo, hi = min(lo, v), max(hi, v)
    return lo / hi if hi > 0.0 else 0.0


@kernel
def lu_solve(A, n, b, x):
    """x ← A⁻¹ b for the square A[:n, :n] by Gaussian elimination with partial pivoting.

    A and b are unchanged. Allocates a copy of A.

    Args:
        A: (n, n) or larger; A[:n, :n] read, unchanged.
        n: the order.
        b: (n,) the right-hand side, unchanged.
        x: (n,) written: the solution (NaN for an exactly singular A).

    Returns:
        float: det A (0 for an exactly singular A).
    """
    a = np.empty((n, n))
    for i in range(n):
        x[i] = b[i]
        for j in range(n):
            a[i, j] = A[i, j]
    return gauss_solve(a, n, x)


@kernel
def gauss_solve(a, n, x):
    """x ← a⁻¹ x for the square a[:n, :n] by Gaussian elimination with partial pivoting, in place.

    a is overwritten by its factors; nothing is allocated.

    Args:
        a: (n, n) or larger; a[:n, :n] overwritten by its factors.
        n: the order.
        x: (n,) the right-hand side, overwritten with the solution (NaN for an exactly singular a).

    Returns:
        float: det a (0 for an exactly singular a).
    """
    det = 1.0
    for k in range(n):
        p = k
        for i in range(k + 1, n):
            if abs(a[i, k]) > abs(a[p, k]):
                p = i
        if a[p, k] == 0.0:
            for i in range(n):
                x[i] = np.nan
            return 0.0
        if p != k:
            det = -det
            x[k], x[p] = x[p], x[k]
            for j in range(n):
                a[k, j], a[p, j] = a[p, j], a[k, j]
        det *= a[k, k]
        for i in range(k + 1, n):
            f = a[i, k] / a[k, k]
            for j in range(k + 1, n):
                a[i, j] -= f * a[k, j]
            x[i] -= f * x[k]
    for i in range(n - 1, -1, -1):
        v = x[i]
        for j in range(i + 1, n):
            v -= a[i, j] * x[j]
        x[i] = v / a[i, i]
    return det


@kernel
def bisect(ts, lo, hi, t):
    """The index i in [lo, hi) with ts[i] <= t < ts[i+1]: the interval of a table holding t.

    Args:
        ts: (T,) sorted knots.
        lo, hi: indices with ts[lo] <= t < ts[hi].
        t: the value located.

    Returns:
        int: i.
    """
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if ts[mid] <= t:
            lo = mid
        else:
            hi = mid
    return lo


@kernel
def finite(y):
    """Whether every entry of y is finite (no NaN, no ±inf).

    Args:
        y: (n,) the array tested.

    Returns:
        bool: True when all are finite.
    """
    for i in range(len(y)):
        if not np.isfinite(y[i]):
            return False
    return True


@kernel
def copy1(src, dst):
    """dst[:] ← src (1-D).

    An explicit loop: slice assignment drags numba's shape-error formatting into every caller's compile.

    Args:
        src: (n,) the source.
        dst: (n,) or longer, written.
    """
    for i in range(len(src)):
        dst[i] = src[i]


@kernel
def copy2(src, dst):
    """dst[:, :] ← src (2-D).

    Args:
        src: (a, b) the source.
        dst: (a, b) or larger, written.
    """
    for i in range(src.shape[0]):
        copy1(src[i], dst[i])


@kernel
def copy3(src, dst):
    """dst[:, :, :] ← src (3-D).

    Args:
        src: (a, b, c) the source.
        dst: (a, b, c) or larger, written.
    """
    for i in range(src.shape[0]):
        copy2(src[i], dst[i])
