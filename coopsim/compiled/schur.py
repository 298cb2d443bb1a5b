"""The constraint solve in O(r): (Y Yᵀ) x = b for the block structure of the closed chain.

Row group g of Λ (rows g·k … g·k + k − 1; m_g the g-th arm other than the carrier c) is zero outside
the columns of m_g and c, and so is every matrix Y = Λ B with B block diagonal per arm (Y = Λ L⁻ᵀ for
Λ𝐈⁻¹Λᵀ in `closed_chain.chain_solve`, Y = Λ for ΛΛᵀ in the manifold projection). Hence

    A = Y Yᵀ = D + U Uᵀ,   D = blockdiag_g(Y_g Y_gᵀ) (k × k blocks, Y_g = Y[g rows, m_g columns]),
                           U = Y[:, carrier columns] (K × n_c),

and with D = L_D L_Dᵀ, V = L_D⁻¹ U (K × n_c), S = I + VᵀV = L_S L_Sᵀ (n_c × n_c, eigenvalues ≥ 1):

    A⁻¹ b = L_D⁻ᵀ (β − V S⁻¹ Vᵀ β),   β = L_D⁻¹ b     (Sherman–Morrison–Woodbury; A = L_D (I + VVᵀ) L_Dᵀ).

Cost k³(r − 1)/6 + K n_c² + n_c³/3 flops, linear in r, against K³/6 for the dense factorization of A
(K = k(r − 1)). It needs every D_g non-singular (each arm other than the carrier moves its grasp in
all k directions) and is used only when that is certified well inside the rank threshold:
λ_min(A) ≥ λ_min(D) ≥ 1/max_g ‖L_g⁻¹‖_F² and λ_max(A) ≤ trace A, so A's ratio λ_min/λ_max is proven
above 1/(trace A · max_g ‖L_g⁻¹‖_F²). Below max(SCHUR_MIN_RATIO, rank_tol) (an arm at or near a
singular configuration, a lost rank) the callers fall back to the dense pivoted Cholesky / eigen path
of `linalg`, whose rank decision stays the reference's. The solve's error follows cond(D) rather than
cond(A), and D is the worse conditioned of the two (an arm alone, without the object: cond(D_g) up to
1e9 on the spatial scenes where cond(A) ≈ 3e4); the certificate bounds cond(D) by 1e10, and the
callers' refinement step takes the error of order cond(D)·ε down to (cond(D)·ε)². For two arms
(K = k) the dense system is no larger than the blocks, and the callers keep it.
"""

from __future__ import annotations

import numpy as np

from coopsim.compiled.linalg import inverse_factor_norm2
from coopsim.compiled.toolchain.jit import kernel

SCHUR_MIN_RATIO = 1e-10


@kernel
def group_arm(g, c):
    """The arm of row group g: the g-th arm other than the carrier c.

    Args:
        g: row-group index, 0-based (rows g·k … g·k + k − 1 of Λ).
        c: the carrier arm's index.

    Returns:
        int: the arm index m_g.
    """
    return g + 1 if g >= c else g


@kernel
def arm_rows(m, c, k, K):
    """The rows of Λ in which arm m's columns are not zero: its own group (the inverse of `group_arm`), or
    every row for the carrier c, whose columns every group shares.

    Args:
        m: arm index, 0-based.
        c: the carrier arm's index.
        k: constraint rows per grasp.
        K: rows of Λ, (r − 1)·k.

    Returns:
        tuple: (i0, i1), the rows i0 … i1 − 1.
    """
    if m == c:
        return 0, K
    g = m - 1 if m > c else m
    return g * k, g * k + k


@kernel
def constraint_trace(P, Y):
    """trace(Y Yᵀ) from the nonzero blocks of Y only.

    Σ over row groups g of ‖Y_g‖_F² + ‖U_g‖_F² (module docstring).

    Args:
        P: the compiled model (PackedModel StructRef, read only): dof, carrier and the rows S.
        Y: (K, N) block-structured matrix (Λ L⁻ᵀ or Λ; zero outside the columns of m_g and the
            carrier in each row group).

    Returns:
        float: trace(Y Yᵀ), in the squared units of Y.
    """
    dof, c, k = P.dof, P.carrier, P.rows.shape[0]
    oc, ec = dof[c], dof[c + 1]
    tr = 0.0
    for g in range(len(dof) - 2):
        m = group_arm(g, c)
        om, em = dof[m], dof[m + 1]
        for i in range(g * k, g * k + k):
            for j in range(oc, ec):
                tr += Y[i, j] * Y[i, j]
            for j in range(om, em):
                tr += Y[i, j] * Y[i, j]
    return tr


@kernel
def cholesky_entry(L, d_inv, o, i, l, a):
    """Entry (i, l), l ≤ i, of the lower Cholesky factor in L[o:, o:] of a symmetric matrix.

    The matrix's (i, l) entry is a; it is factored row by row (rows < i and entries < l of row i done):
    L_il = (a − Σ_t<l L_it L_lt) / L_ll, or on the diagonal its square root, with its reciprocal in
    d_inv[o + i].

    Args:
        L: (n, n) the factor's array, the block at offset o; entry (o + i, o + l) written.
        d_inv: (n,) reciprocals of the factor's diagonal; d_inv[o + i] written on the diagonal (and read
            for l < i: d_inv[o + l]).
        o: offset of the block in L and d_inv.
        i, l: row and column in the block, l ≤ i.
        a: the (i, l) entry of the matrix being factored.

    Returns:
        bool: False if a diagonal entry is not positive (nothing written then), else True.
    """
    for t in range(l):
        a -= L[o + i, o + t] * L[o + l, o + t]
    if l < i:
        L[o + i, o + l] = a * d_inv[o + l]
    elif a > 0.0:
        L[o + i, o + i] = np.sqrt(a)
        d_inv[o + i] = 1.0 / L[o + i, o + i]
    else:
        return False
    return True


@kernel
def schur_factor(P, W, Y, trA):
    """Factor A = Y Yᵀ (Y block-structured) as D + U Uᵀ for `schur_solve` (module docstring).

    L_g goes into the diagonal blocks of W.A_f (lower triangle; `linalg.inverse_factor_norm2` uses their
    strict upper triangle as scratch) with the reciprocals of their diagonals in W.d_inv, V = L_D⁻¹U into
    W.V[:, :n_c], L_S into W.S[:n_c, :n_c] (lower triangle) with reciprocals in W.S_inv.

    Args:
        P: the compiled model (PackedModel StructRef, read only): dof, carrier, rows S and rank_tol.
        W: the workspace (Workspace StructRef): W.A_f, W.d_inv, W.V, W.S, W.S_inv written.
        Y: (K, N) block-structured matrix (Λ L⁻ᵀ or Λ), K = k(r − 1).
        trA: trace(Y Yᵀ) (`constraint_trace`).

    Returns:
        bool: True when A's conditioning is certified above max(SCHUR_MIN_RATIO, rank_tol) (and for
        K = 0), False (and the factors unusable) otherwise.
    """
    dof, c, k = P.dof, P.carrier, P.rows.shape[0]
    Lf, di, V, S, Si = W.A_f, W.d_inv, W.V, W.S, W.S_inv
    K = k * (len(dof) - 2)
    if K == 0:
        return True
    oc, nc = dof[c], dof[c + 1] - dof[c]
    worst = 0.0
    for g in range(len(dof) - 2):
        m = group_arm(g, c)
        om, nm, i0 = dof[m], dof[m + 1] - dof[m], g * k
        Yg, Ug, Lg, dg, Vg = (Y[i0:i0 + k, om:om + nm], Y[i0:i0 + k, oc:oc + nc], Lf[i0:i0 + k, i0:i0 + k],
                              di[i0:i0 + k], V[i0:i0 + k])
        for i in range(k):
            for l in range(i + 1):
                a = 0.0
                for j in range(nm):
                    a += Yg[i, j] * Yg[l, j]
                if not cholesky_entry(Lf, di, i0, i, l, a):
                    return False
            for j in range(nc):       # row i of V_g = L_g⁻¹ U_g
                v = Ug[i, j]
                for t in range(i):
                    v -= Lg[i, t] * Vg[t, j]
                Vg[i, j] = v * dg[i]
        worst = max(worst, inverse_factor_norm2(Lf, i0, k))
    if not 1.0 / (worst * trA) > max(SCHUR_MIN_RATIO, P.rank_tol):
        return False
    for i in range(nc):               # S = I + VᵀV = L_S L_Sᵀ, row by row
        for l in range(i + 1):
            a = 1.0 if l == i else 0.0
            for t in range(K):
                a += V[t, i] * V[t, l]
            cholesky_entry(S, Si, 0, i, l, a)     # a ≥ 1 on the diagonal
    return True


@kernel
def schur_solve(P, W, b, x):
    """x ← A⁻¹ b with the factors of `schur_factor` (Sherman–Morrison–Woodbury, module docstring).

    Args:
        P: the compiled model (PackedModel StructRef, read only): dof, carrier and the rows S.
        W: the workspace (Workspace StructRef) holding the factors (W.A_f, W.d_inv, W.V, W.S,
            W.S_inv); W.yN (n_c,) is overwritten as scratch.
        b: (K,) right-hand side, left unchanged; must not alias x.
        x: (K,) written: A⁻¹ b.
    """
    dof, c, k = P.dof, P.carrier, P.rows.shape[0]
    Lf, di, V, S, Si, y = W.A_f, W.d_inv, W.V, W.S, W.S_inv, W.yN
    K = k * (len(dof) - 2)
    nc = dof[c + 1] - dof[c]
    for i0 in range(0, K, k):         # β = L_D⁻¹ b into x
        Lg = Lf[i0:i0 + k, i0:i0 + k]
        for i in range(k):
            v = b[i0 + i]
            for t in range(i):
                v -= Lg[i, t] * x[i0 + t]
            x[i0 + i] = v * di[i0 + i]
    for i in range(nc):               # y = L_S⁻¹ Vᵀβ
        v = 0.0
        for t in range(K):
            v += V[t, i] * x[t]
        for t in range(i):
            v -= S[i, t] * y[t]
        y[i] = v * Si[i]
    for i in range(nc - 1, -1, -1):   # y = L_S⁻ᵀ y = S⁻¹ Vᵀβ
        v = y[i]
        for t in range(i + 1, nc):
            v -= S[t, i] * y[t]
        y[i] = v * Si[i]
    for t in range(K):                # x = β − V y
        v = x[t]
        for i in range(nc):
            v -= V[t, i] * y[i]
        x[t] = v
    for i0 in range(0, K, k):         # x = L_D⁻ᵀ x
        Lg = Lf[i0:i0 + k, i0:i0 + k]
        for i in range(k - 1, -1, -1):
            v = x[i0 + i]
            for t in range(i + 1, k):
                v -= Lg[t, i] * x[i0 + t]
            x[i0 + i] = v * di[i0 + i]
