"""Small dense linear algebra, in place, for the compiled kernels (no allocation on the hot path).

The constraint system (Λ𝐈⁻¹Λᵀ) F = b is solved by a Cholesky factorization with diagonal pivoting
when the matrix is provably of full rank, else by the reference's eigen-decomposition (minimum-norm
solution, numerical rank from eigenvalues above rank_tol·λ_max). The proof is a certified lower bound
of λ_min/λ_max from the factor: A⁻¹ = Pᵀ L⁻ᵀ L⁻¹ P, so λ_min = 1/‖A⁻¹‖₂ ≥ 1/‖L⁻¹‖_F², and
λ_max ≤ trace A; the bound 1/(‖L⁻¹‖_F² trace A) is at most K² times below the true ratio, so the
eigen-decomposition runs only for matrices within K² of the rank threshold (cost: K³/6 flops).
(The block-diagonal mass matrix is factored inside `chain.chain_solve`.) The factorization and the
solve borrow their array arguments on entry (`structs.borrow`): no reference counting on them.
"""

from __future__ import annotations

import numpy as np
from .jit import kernel
from .structs import borrow


@kernel
def pivoted_cholesky(A, Lf, perm, K):
    """Cholesky factorization with diagonal pivoting P A Pᵀ = L Lᵀ of the symmetric PSD A (K, K) into
    Lf (lower), perm[i] the row of A in position i. Returns the certified lower bound
    1/(‖L⁻¹‖_F² trace A) of λ_min/λ_max (module docstring; 0 if a pivot is not positive). Works on the
    lower triangle (A's is read; Lf's strict upper triangle is scratch for the columns of L⁻¹): a pivot swaps rows and columns j, p of the symmetric trailing matrix as
    LAPACK's dsyswapr does, and rows j, p of the columns already factored."""
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
    return 1.0 / (inverse_factor_norm2(Lf, K) * trace(A, K))


@kernel
def trace(A, K):
    v = 0.0
    for i in range(K):
        v += A[i, i]
    return v


@kernel
def inverse_factor_norm2(Lf, K):
    """‖L⁻¹‖_F² of the lower factor in Lf: column j of L⁻¹ by forward substitution (L x = e_j, x_i = 0
    for i < j), its entries below the diagonal kept in row j of Lf's strict upper triangle."""
    total = 0.0
    for j in range(K):
        xj = 1.0 / Lf[j, j]
        total += xj * xj
        for i in range(j + 1, K):
            v = -Lf[i, j] * xj
            for t in range(j + 1, i):
                v -= Lf[i, t] * Lf[j, t]
            v /= Lf[i, i]
            Lf[j, i] = v
            total += v * v
    return total


@kernel
def pivoted_solve(Lf, perm, K, b, y, x):
    """x ← A⁻¹ b with the factors of `pivoted_cholesky` (P A Pᵀ = L Lᵀ: L Lᵀ (P x) = P b); y (K,) is
    scratch; b is left unchanged and may alias neither y nor x. x holds the reciprocals 1/L_ii until
    the end (the substitutions multiply: no division on their dependency chain)."""
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
    """The value of `pivoted_cholesky`'s certified ratio above which λ_min/λ_max > rank_tol is proven:
    rank_tol itself (the bound is rigorous; K is kept for the callers' signature)."""
    return rank_tol


@kernel
def eig_solve(A, b, x, K, rank_tol):
    """Minimum-norm solution x of A x = b (A symmetric PSD) from its eigen-decomposition, keeping
    eigenvalues above rank_tol·λ_max; returns (condition number λ_max/λ_min, rank). Allocates:
    used only off the hot path (near-singular systems, and condition numbers of output samples)."""
    ev, V = np.linalg.eigh(A[:K, :K].copy())
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


@kernel
def copy1(src, dst):
    """dst[:] ← src (1-D; explicit loop: slice assignment drags numba's shape-error formatting into
    every caller's compile)."""
    for i in range(len(src)):
        dst[i] = src[i]


@kernel
def copy2(src, dst):
    """dst[:, :] ← src (2-D)."""
    for i in range(src.shape[0]):
        copy1(src[i], dst[i])


@kernel
def copy3(src, dst):
    """dst[:, :, :] ← src (3-D)."""
    for i in range(src.shape[0]):
        copy2(src[i], dst[i])
