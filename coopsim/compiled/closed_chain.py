"""Compiled stage 4 — the closed chain: the constraint Jacobian and bias, and the solve that eliminates
the grasp wrenches (paper eqs. 14–27; the reference is `coopsim.dynamics.closed_chain`).

𝐈 is block diagonal (one block per arm, the object in the carrier's), factored block by block, and
Λ𝐈⁻¹Λᵀ is formed as YᵀY with Y = L⁻¹Λᵀ (`chain_solve`); for three arms or more the constraint solve
runs in O(r) (`coopsim.compiled.schur`).
Return codes of `chain_forward`: OK, NOT_PD (a mass-matrix block is not positive definite),
RANK_DEFICIENT (Λ𝐈⁻¹Λᵀ lost rank: minimum-norm grasp wrenches were used), NON_FINITE.
"""

from __future__ import annotations

import numpy as np

from coopsim.compiled.gibbs_appell import arm_bias, arm_mass_matrix
from coopsim.compiled.grasp import object_dynamics, object_pose
from coopsim.compiled.kinematics import arm_jacobian, arm_kinematics
from coopsim.compiled.linalg import (column_singular_ratio, eig_solve, pivoted_cholesky, pivoted_solve,
                                     safe_pivot_ratio)
from coopsim.compiled.packing import STAB_BAUMGARTE
from coopsim.compiled.schur import arm_rows, constraint_trace, group_arm, schur_factor, schur_solve
from coopsim.compiled.spatial import rot_log
from coopsim.compiled.structs import borrow
from coopsim.compiled.toolchain.jit import kernel

OK, NOT_PD, RANK_DEFICIENT, NON_FINITE = 0, 1, 2, 3
EIGEN, DENSE, SCHUR = 0, 1, 2   # the constraint solve's paths (`chain_solve`)


@kernel
def constraint_jacobian(P, W):
    """Λ (K, N) (eq. 23): for each arm m ≠ c the rows S (J_m θ̇_m − W_mᵀ J_o θ̇_c).

    With W_mᵀ [v; ω] = [v + s_m × ω; ω]. Columns of arms other than m and c stay zero.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): W.J, W.s and W.J_o (`arm_jacobian`, `object_pose`) read;
            W.Lam written (row group g = g-th arm other than c, rows g·k … g·k + k − 1).
    """
    S, dof, c = P.rows, P.dof, P.carrier
    s, J, J_o, Lam = W.s, W.J, W.J_o, W.Lam
    k = S.shape[0]
    oc, nc = dof[c], dof[c + 1] - dof[c]
    g = 0
    for m in range(len(dof) - 1):
        if m == c:
            continue
        om, nm = dof[m], dof[m + 1] - dof[m]
        s0, s1, s2 = s[m, 0], s[m, 1], s[m, 2]
        for i in range(k):
            row = g * k + i
            S0, S1, S2, S3, S4, S5 = S[i, 0], S[i, 1], S[i, 2], S[i, 3], S[i, 4], S[i, 5]
            for j in range(nm):
                Lam[row, om + j] = (S0 * J[m, 0, j] + S1 * J[m, 1, j] + S2 * J[m, 2, j] + S3 * J[m, 3, j]
                                    + S4 * J[m, 4, j] + S5 * J[m, 5, j])
            for j in range(nc):
                jw0, jw1, jw2 = J_o[3, j], J_o[4, j], J_o[5, j]
                v = (S0 * (J_o[0, j] + s1 * jw2 - s2 * jw1) + S1 * (J_o[1, j] + s2 * jw0 - s0 * jw2)
                     + S2 * (J_o[2, j] + s0 * jw1 - s1 * jw0) + S3 * jw0 + S4 * jw1 + S5 * jw2)
                Lam[row, oc + j] = -v
        g += 1


@kernel
def constraint_bias(P, W):
    """Λ̇θ̇ (K,) (eq. 24): S (J̇_mθ̇_m − W_mᵀ J̇_oθ̇_c − [ω × (ω × (−s_m)); 0]) for each arm m ≠ c.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): W.Jd_qd, W.s, W.v_o and W.Jd_o_qd (`arm_bias`,
            `object_pose`, `object_dynamics`) read; W.Lam_dot_qd (K,) written (m/s², rad/s² in the rows S).
    """
    S, dof, c = P.rows, P.dof, P.carrier
    s, v_o, ad, Jd_qd, Ldq = W.s, W.v_o, W.Jd_o_qd, W.Jd_qd, W.Lam_dot_qd
    k = S.shape[0]
    w0, w1, w2 = v_o[3], v_o[4], v_o[5]
    ad0, ad1, ad2, ad3, ad4, ad5 = ad[0], ad[1], ad[2], ad[3], ad[4], ad[5]
    g = 0
    for m in range(len(dof) - 1):
        if m == c:
            continue
        s0, s1, s2 = s[m, 0], s[m, 1], s[m, 2]
        x0, x1, x2 = -(w1 * s2 - w2 * s1), -(w2 * s0 - w0 * s2), -(w0 * s1 - w1 * s0)   # ω × (−s_m)
        u0 = Jd_qd[m, 0] - (ad0 + s1 * ad5 - s2 * ad4) - (w1 * x2 - w2 * x1)
        u1 = Jd_qd[m, 1] - (ad1 + s2 * ad3 - s0 * ad5) - (w2 * x0 - w0 * x2)
        u2 = Jd_qd[m, 2] - (ad2 + s0 * ad4 - s1 * ad3) - (w0 * x1 - w1 * x0)
        u3 = Jd_qd[m, 3] - ad3
        u4 = Jd_qd[m, 4] - ad4
        u5 = Jd_qd[m, 5] - ad5
        for i in range(k):
            Ldq[g * k + i] = (S[i, 0] * u0 + S[i, 1] * u1 + S[i, 2] * u2 + S[i, 3] * u3 + S[i, 4] * u4
                              + S[i, 5] * u5)
        g += 1


@kernel
def arm_terms(P, W, q, qd):
    """Stages 1–2 for every open arm at (q, qd): kinematics, J_m, J̇_mθ̇_m, h_m and I_m (eq. 10).

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): written by `arm_kinematics`, `arm_jacobian`, `arm_bias` and
            `arm_mass_matrix` for every arm (no object terms yet).
        q: (N,) rad or m, the stacked joint coordinates.
        qd: (N,) rad/s or m/s, the stacked joint rates.
    """
    for m in range(len(P.dof) - 1):
        arm_kinematics(P, W, m, q)
        arm_jacobian(P, W, m)
        arm_bias(P, W, m, qd)
        arm_mass_matrix(P, W, m)


@kernel
def chain_terms(P, W, q, qd):
    """Stages 1–3 and the assembly of eqs. 17–24 at state (q, qd) into W.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): the arm terms, the object's (`object_pose`,
            `object_dynamics`), Λ (W.Lam) and Λ̇θ̇ (W.Lam_dot_qd) written.
        q: (N,) rad or m, the stacked joint coordinates.
        qd: (N,) rad/s or m/s, the stacked joint rates.
    """
    arm_terms(P, W, q, qd)
    object_pose(P, W)
    object_dynamics(P, W, qd)
    constraint_jacobian(P, W)
    constraint_bias(P, W)


@kernel
def loop_residual(P, W):
    """Φ (K,) into W.phi from the current kinematics: the loop-closure error of each arm m ≠ c.

    For each arm m ≠ c, S [p_EE,m − p_grasp,m; log(R_EE,m R_grasp,mᵀ)] (m, rad), the grasp frame
    carried by the object. No world position enters: p_EE,m − p_grasp,m = (o_m − o_c) +
    (p_EE,m − p_EE,c − s_c + s_m), the end-effectors relative to their bases o (p_grasp,m = p_C − s_m,
    p_C = p_EE,c + s_c).

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): every arm's kinematics and `object_pose`'s W.R_o and W.s
            read; W.phi (K,) written (m, rad); W.v3 and W.m3 scratch.
    """
    S, dof, c, gr, bp = P.rows, P.dof, P.carrier, P.grasp_rot, P.base_pos
    R_o, R_ee, p_ee, s, phi, lg, m3 = W.R_o, W.R_ee, W.p_ee_rel, W.s, W.phi, W.v3, W.m3
    Rd, E = m3[0], m3[1]
    k = S.shape[0]
    g = 0
    for m in range(len(dof) - 1):
        if m == c:
            continue
        for a in range(3):
            for b in range(3):
                Rd[a, b] = R_o[a, 0] * gr[m, 0, b] + R_o[a, 1] * gr[m, 1, b] + R_o[a, 2] * gr[m, 2, b]
        for a in range(3):
            for b in range(3):
                E[a, b] = R_ee[m, a, 0] * Rd[b, 0] + R_ee[m, a, 1] * Rd[b, 1] + R_ee[m, a, 2] * Rd[b, 2]
        rot_log(E, lg)
        e0 = (bp[m, 0] - bp[c, 0]) + (p_ee[m, 0] - (p_ee[c, 0] + s[c, 0] - s[m, 0]))
        e1 = (bp[m, 1] - bp[c, 1]) + (p_ee[m, 1] - (p_ee[c, 1] + s[c, 1] - s[m, 1]))
        e2 = (bp[m, 2] - bp[c, 2]) + (p_ee[m, 2] - (p_ee[c, 2] + s[c, 2] - s[m, 2]))
        for i in range(k):
            phi[g * k + i] = (S[i, 0] * e0 + S[i, 1] * e1 + S[i, 2] * e2 + S[i, 3] * lg[0] + S[i, 4] * lg[1]
                              + S[i, 5] * lg[2])
        g += 1


@kernel
def constraint_rhs(P, W, stab):
    """b = Λ̇θ̇ + stab + Yᵀz (K,) into W.b (W.X = Yᵀ, W.x0 = z of `chain_solve`).

    Row group g runs over the columns of its arm and the carrier's only.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): W.X, W.x0 and W.Lam_dot_qd read; W.b (K,) written.
        stab: (K,) the stabilising term added to the right-hand side (zeros: none).
    """
    dof, c, k = P.dof, P.carrier, P.rows.shape[0]
    Yt, z, b, Ldq = W.X, W.x0, W.b, W.Lam_dot_qd
    oc, ec = dof[c], dof[c + 1]
    for g in range(len(dof) - 2):
        m = group_arm(g, c)
        om, em = dof[m], dof[m + 1]
        for i in range(g * k, g * k + k):
            v = Ldq[i] + stab[i]
            for j in range(oc, ec):
                v += Yt[i, j] * z[j]
            for j in range(om, em):
                v += Yt[i, j] * z[j]
            b[i] = v


@kernel
def constraint_matrix(P, W):
    """A = Λ𝐈⁻¹Λᵀ = YᵀY (K, K) into W.A, from W.X = Yᵀ.

    The dense path of `chain_solve` (when the `schur` path is not certified) and the reported condition
    number. Rows g·k + i and l share the carrier's columns, and the arm's when l is in the same group.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): W.X (`chain_solve`) read; W.A (K, K) written (both
            triangles).
    """
    dof, c, k = P.dof, P.carrier, P.rows.shape[0]
    Yt, A = W.X, W.A
    K = A.shape[0]
    oc, ec = dof[c], dof[c + 1]
    for g in range(len(dof) - 2):
        m = group_arm(g, c)
        om, em, i0 = dof[m], dof[m + 1], g * k
        for i in range(i0, i0 + k):
            for l in range(i, K):
                a = 0.0
                for j in range(oc, ec):
                    a += Yt[i, j] * Yt[l, j]
                if l < i0 + k:
                    for j in range(om, em):
                        a += Yt[i, j] * Yt[l, j]
                A[i, l] = a
                A[l, i] = a


@kernel
def solve_constraints(P, W, K):
    """F ← (Λ𝐈⁻¹Λᵀ)⁻¹ b (W.A, W.b): pivoted Cholesky when the pivots prove full rank, else eigen.

    The eigen path gives the minimum-norm solution. Sets W.rank, W.cond (−1: not computed on the fast
    path).

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): W.A and W.b read; W.F (K,) written (the loop-closure
            wrenches, N and N·m in the rows S), W.rank, W.cond; W.A_f, W.perm, W.yK overwritten.
        K: the number of constraint rows, k(r−1).

    Returns:
        bool: whether the Cholesky path was taken.
    """
    rank_tol = P.rank_tol
    A, A_f, perm, b, yK, F, rank_, cond_ = W.A, W.A_f, W.perm, W.b, W.yK, W.F, W.rank, W.cond
    ratio = pivoted_cholesky(A, A_f, perm, K)
    fast = ratio > safe_pivot_ratio(K, rank_tol)
    if fast:
        pivoted_solve(A_f, perm, K, b, yK, F)
        rank_[0] = K
        cond_[0] = -1.0
    else:
        cond, rank = eig_solve(A, b, F, K, rank_tol)
        rank_[0] = rank
        cond_[0] = cond
    return fast


@kernel
def constraint_condition(P, W):
    """cond(Λ𝐈⁻¹Λᵀ) = λ_max/λ_min after `chain_solve`, the eigenvalues' ratio as an eigen-solve gives it.

    A = Λ𝐈⁻¹Λᵀ (K × K) is positive definite wherever `chain_solve` took a Cholesky path. There P A Pᵀ =
    L Lᵀ (the pivoted factor: the dense path's own in W.A_f, or formed here after the `schur` path),
    and the eigenvalues of A are the squared singular values of L: cond = (σ_max/σ_min)² of L by
    one-sided Jacobi (`linalg.column_singular_ratio`), which the diagonal pivoting makes converge in
    few sweeps (Demmel & Veselić 1992) — no eigen-decomposition of A. Where the eigen path ran (rank
    lost or not proven) its condition number W.cond is the one reported. (After the `schur` path, whose
    certificate bounds cond by 1e10, the factor always forms; were it not to, the eigen path's
    `linalg.eig_solve` would give the number.) Agrees with
    numpy.linalg.cond(A) to a relative 1e-13 + 8·K·eps·cond (tests/compiled/test_compiled.py).

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef) after `chain_solve`: W.path, W.cond and W.A_f read (W.X
            after the `schur` path); W.A (and W.A_f, W.perm, W.dF after the `schur` path) overwritten.

    Returns:
        float: λ_max/λ_min (inf when λ_min ≤ 0; 1 without constraint rows).
    """
    K = W.Lam.shape[0]
    if K == 0:
        return 1.0
    if W.path[0] == EIGEN:
        return W.cond[0]
    A, L = W.A, W.A_f
    if W.path[0] == SCHUR:
        constraint_matrix(P, W)
        if not pivoted_cholesky(A, L, W.perm, K) > 0.0:
            return eig_solve(A, W.b, W.dF, K, P.rank_tol)[0]
    for i in range(K):
        for j in range(K):
            A[i, j] = L[i, j] if i >= j else 0.0
    ratio = column_singular_ratio(A, K, K)
    return 1.0 / (ratio * ratio) if ratio > 0.0 else np.inf


@kernel
def chain_solve(P, W, tau, stab):
    """θ̈ (eqs. 25–27) into W.qdd and the loop-closure wrenches F (K,) into W.F for torques tau (N,).

    `stab` (K,) is added to the right-hand side of Λθ̈ = −Λ̇θ̇ − stab (zeros: none). Needs `chain_terms`
    first. One step of iterative refinement on the acceleration constraint.

    With 𝐈 = L Lᵀ (block by block: W.Lb, the reciprocals of its diagonal in W.Lb_inv, so that the
    substitutions multiply), Yᵀ = Λ L⁻ᵀ (W.X, K × N) and z = L⁻¹(τ − h) (W.x0):
        (Λ𝐈⁻¹Λᵀ) F = YᵀY F = Λ̇θ̇ + stab + Yᵀz,   θ̈ = 𝐈⁻¹(τ − h − ΛᵀF) = L⁻ᵀ(z − Y F);
    refinement: F += (YᵀY)⁻¹ (Λθ̈ + Λ̇θ̇ + stab), and θ̈ again from the refined F. YᵀY is solved in
    O(r) by its block structure (`schur`) for three arms or more where that is certified, else formed
    (`constraint_matrix`) and solved densely (`solve_constraints`), which also decides the rank. Row
    group g of Λ (rows g·k … g·k + k − 1, arm m_g = the g-th arm other than the carrier c) is zero
    outside the columns of m_g and c, and so is row g·k + i of Yᵀ: every product runs over those blocks
    only. The factor is formed row by row (the same entries and sums as column by column), each row
    followed by its forward substitution; its transpose is kept in the strict upper triangle of W.Lb, so
    that both substitutions read rows. The loops run over views of one block, indexed from 0 (numba then
    need not wrap negative indices).

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): `chain_terms`' terms read (W.Mb, W.h, W.Lam,
            W.Lam_dot_qd). Written: W.qdd (N,) rad/s² or m/s²; W.F (K,) N and N·m in the rows S; W.Lb,
            W.Lb_inv, W.X, W.x0, W.b, W.res, W.dF, W.rank, W.cond, W.path (the path taken: SCHUR, DENSE
            or EIGEN), and the buffers of the `schur` or dense solve.
        tau: (N,) N·m (N for a prismatic joint), the joint torques.
        stab: (K,) the stabilising term (zeros: none).

    Returns:
        int: OK, NOT_PD, RANK_DEFICIENT or NON_FINITE (module docstring).
    """
    tau, stab = borrow(tau), borrow(stab)
    dof, c, k, rank_tol = P.dof, P.carrier, P.rows.shape[0], P.rank_tol
    Lam, Yt, z, h, Mb, Lb, Li, b, A = W.Lam, W.X, W.x0, W.h, W.Mb, W.Lb, W.Lb_inv, W.b, W.A
    F, qdd, res, A_f, perm, yK, dF, Ldq, rank = W.F, W.qdd, W.res, W.A_f, W.perm, W.yK, W.dF, W.Lam_dot_qd, W.rank
    r = len(dof) - 1
    K = Lam.shape[0]
    oc, ec = dof[c], dof[c + 1]
    # 𝐈_m = L Lᵀ, z, and Yᵀ (the rows of arm m's group, or all of them in the carrier's columns)
    for m in range(r):
        o, e = dof[m], dof[m + 1]
        i0, i1 = arm_rows(m, c, k, K)
        M, L, Ym, Lamm = Mb[o:e], Lb[o:e], Yt[i0:i1, o:e], Lam[i0:i1, o:e]
        for j in range(e - o):
            for t in range(j):
                v = M[j, t]
                for s in range(t):
                    v -= L[j, s] * L[t, s]
                v *= Li[o + t]
                L[j, t] = v
                L[t, j] = v
            d = M[j, j]
            for s in range(j):
                d -= L[j, s] * L[j, s]
            if not d > 0.0:
                return NOT_PD
            d = np.sqrt(d)
            inv = 1.0 / d
            L[j, j] = d
            Li[o + j] = inv
            v = tau[o + j] - h[o + j]
            for t in range(j):
                v -= L[j, t] * z[o + t]
            z[o + j] = v * inv
            for i in range(i1 - i0):
                v = Lamm[i, j]
                for t in range(j):
                    v -= L[j, t] * Ym[i, t]
                Ym[i, j] = v * inv
    constraint_rhs(P, W, stab)
    if r > 2 and schur_factor(P, W, Yt, constraint_trace(P, Yt)):
        path = SCHUR
        schur_solve(P, W, b, F)
        rank[0], W.cond[0] = K, -1.0
    else:
        constraint_matrix(P, W)
        path = DENSE if solve_constraints(P, W, K) else EIGEN
    W.path[0] = path
    for it in range(2):
        # θ̈ = L⁻ᵀ(z − Y F), block by block
        for m in range(r):
            o, e = dof[m], dof[m + 1]
            i0, i1 = arm_rows(m, c, k, K)
            L, Ym = Lb[o:e], Yt[i0:i1, o:e]
            n = e - o
            for j in range(n - 1, -1, -1):
                v = z[o + j]
                for i in range(i1 - i0):
                    v -= Ym[i, j] * F[i0 + i]
                for t in range(j + 1, n):
                    v -= L[j, t] * qdd[o + t]
                qdd[o + j] = v * Li[o + j]
        if it == 1:
            break
        # refinement: residual of Λθ̈ + Λ̇θ̇ + stab = 0
        Lc, qc = Lam[:, oc:ec], qdd[oc:ec]
        for g in range(r - 1):
            mg = g + 1 if g >= c else g
            om, em = dof[mg], dof[mg + 1]
            Lm, qm = Lam[:, om:em], qdd[om:em]
            for i in range(g * k, g * k + k):
                v = Ldq[i] + stab[i]
                for j in range(ec - oc):
                    v += Lc[i, j] * qc[j]
                for j in range(em - om):
                    v += Lm[i, j] * qm[j]
                res[i] = v
        if path == SCHUR:
            schur_solve(P, W, res, dF)
        elif path == DENSE:
            pivoted_solve(A_f, perm, K, res, yK, dF)
        else:
            eig_solve(A, res, dF, K, rank_tol)
        for i in range(K):
            F[i] += dF[i]
    for j in range(dof[r]):
        if not np.isfinite(qdd[j]):
            return NON_FINITE
    return OK if rank[0] == K else RANK_DEFICIENT


@kernel
def baumgarte_rhs(P, W, qd, out):
    """out (K,) ← 2α Λθ̇ + β² Φ (Baumgarte's stabilising right-hand side), or zeros without it.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): W.Lam and the kinematics read; W.phi written
            (`loop_residual`).
        qd: (N,) rad/s or m/s, the stacked joint rates.
        out: (K,) written (m/s², rad/s² in the rows S).
    """
    Lam, phi = W.Lam, W.phi
    K, N = Lam.shape
    if P.stabilization != STAB_BAUMGARTE:
        for i in range(K):
            out[i] = 0.0
        return
    loop_residual(P, W)
    al, be = P.alpha, P.beta
    for i in range(K):
        v = 0.0
        for j in range(N):
            v += Lam[i, j] * qd[j]
        out[i] = 2.0 * al * v + be * be * phi[i]


@kernel
def chain_forward(P, W, q, qd, tau, stab):
    """One closed-chain forward-dynamics evaluation at (q, qd) with torques tau: W.qdd, W.F and every term.

    Every intermediate term goes into W: the kinematic terms at q (each arm's kinematics and Jacobian,
    the object pose, Λ), then `chain_dynamics`, with the stages of the first called from here directly:
    every level of calls takes references to its array arguments that numba cannot prune (atomic
    updates). The array arguments are borrowed at once (`structs.borrow`): no reference to them is held
    across the calls.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): every term of the evaluation written; the results are
            W.qdd (N,) θ̈, rad/s² or m/s², and W.F (K,) the loop-closure wrenches, N and N·m in the rows S.
        q: (N,) rad or m, the stacked joint coordinates.
        qd: (N,) rad/s or m/s, the stacked joint rates.
        tau: (N,) N·m (N for a prismatic joint), the joint torques.
        stab: (K,) scratch, overwritten with the Baumgarte term (zeros without it).

    Returns:
        int: OK, NOT_PD, RANK_DEFICIENT or NON_FINITE (module docstring).
    """
    q, qd, tau, stab = borrow(q), borrow(qd), borrow(tau), borrow(stab)
    for m in range(len(P.dof) - 1):
        arm_kinematics(P, W, m, q)
        arm_jacobian(P, W, m)
    object_pose(P, W)
    constraint_jacobian(P, W)
    return chain_dynamics(P, W, qd, tau, stab)


@kernel
def chain_dynamics(P, W, qd, tau, stab):
    """The closed-chain forward dynamics at rates qd, torques tau, on the kinematic terms already in W.

    `chain_forward` after its kinematic terms at q (each arm's kinematics and Jacobian, the object
    pose, Λ: as `manifold.closure_kinematics` leaves them): the arm terms at qd, the object's, Λ̇θ̇,
    the Baumgarte term when selected (that kernel is only entered then), and `chain_solve`. Each arm's
    terms read that arm's kinematics only, so they come out as an evaluation from scratch gives them.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): the kinematic terms at q read; every other term of the
            evaluation written (W.qdd (N,) θ̈, rad/s² or m/s², W.F (K,) N and N·m in the rows S).
        qd: (N,) rad/s or m/s, the stacked joint rates.
        tau: (N,) N·m (N for a prismatic joint), the joint torques.
        stab: (K,) scratch, overwritten with the Baumgarte term (zeros without it).

    Returns:
        int: OK, NOT_PD, RANK_DEFICIENT or NON_FINITE (module docstring).
    """
    qd, tau, stab = borrow(qd), borrow(tau), borrow(stab)
    for m in range(len(P.dof) - 1):
        arm_bias(P, W, m, qd)
        arm_mass_matrix(P, W, m)
    object_dynamics(P, W, qd)
    constraint_bias(P, W)
    if P.stabilization == STAB_BAUMGARTE:
        baumgarte_rhs(P, W, qd, stab)
    else:
        for i in range(len(stab)):
            stab[i] = 0.0
    return chain_solve(P, W, tau, stab)
