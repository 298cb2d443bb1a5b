"""The compiled controllers' closed-chain inverse dynamics: τ = τ_arms + Jᵀ f with A f = y, the net
object wrench distributed by the paper's W⁺ (f_m = S W(−s_m) Sᵀ y / r), the non-squeezing inverse
(f = M*Aᵀ(A M*Aᵀ)⁻¹ y) or weighted minimum energy (the KKT system [JᵀQJ Aᵀ; A 0][f; λ] = [−JᵀQτ_arms; y]
by Gaussian elimination with partial pivoting: the same unique minimiser as the null-space form of
`coopsim.inverse.distributions.min_energy_solve`, for actuated arms whose equations keep their rank), and
a squeeze in the null space of the grasp matrix (paper eqs. 28–35; the Python side is
`coopsim.inverse.solve`). The QP of 'bounded' is not compiled.
"""

from __future__ import annotations

import numpy as np

from coopsim.compiled.closed_chain import OK, arm_terms
from coopsim.compiled.control.record import CONTROL_SINGULAR, DIST_NONSQUEEZING, DIST_PAPER
from coopsim.compiled.grasp import object_dynamics, object_pose
from coopsim.compiled.linalg import copy2, gauss_solve
from coopsim.compiled.sample import object_acceleration, object_wrench
from coopsim.compiled.spatial import matmul3, matmul3_T
from coopsim.compiled.toolchain.jit import kernel


@kernel
def gram_solve(C, k):
    """C.x[:rk] ← MA (A MA)⁻¹ C.xk.

    Args:
        C: the controller (PackedControl StructRef): reads C.A (k, rk), C.MA (rk, k) and C.xk (k,);
            C.G and C.xk are overwritten, C.x[:rk] written.
        k: rows per grasp.

    Returns:
        bool: False when A MA is singular (a zero pivot; C.x not written), else True.
    """
    mk = C.A.shape[1]
    for i in range(k):
        for b in range(k):
            v = 0.0
            for c in range(mk):
                v += C.A[i, c] * C.MA[c, b]
            C.G[i, b] = v
    if gauss_solve(C.G, k, C.xk) == 0.0:
        return False
    for c in range(mk):
        v = 0.0
        for b in range(k):
            v += C.MA[c, b] * C.xk[b]
        C.x[c] = v
    return True


@kernel
def grasp_rows(P, W, C):
    """C.A ← [S W_m Sᵀ]_m (k, rk) and C.JT ← blockdiag((S J_m)ᵀ) (N, rk), with W_m = [[I, 0], [−[s_m×], I]].

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef): reads the grasp offsets W.s and the
            Jacobians W.J of the current state.
        C: the controller (PackedControl StructRef): C.A and C.JT written, C.v6 scratch.
    """
    S = P.rows
    k = S.shape[0]
    r = len(P.dof) - 1
    for m in range(r):
        s = W.s[m]
        for b in range(k):
            # W_m Sᵀ e_b: the row b of S as a wrench [f; n], moved: n − s × f
            f0, f1, f2 = S[b, 0], S[b, 1], S[b, 2]
            C.v6[0], C.v6[1], C.v6[2] = f0, f1, f2
            C.v6[3] = S[b, 3] - (s[1] * f2 - s[2] * f1)
            C.v6[4] = S[b, 4] - (s[2] * f0 - s[0] * f2)
            C.v6[5] = S[b, 5] - (s[0] * f1 - s[1] * f0)
            for i in range(k):
                v = 0.0
                for a in range(6):
                    v += S[i, a] * C.v6[a]
                C.A[i, m * k + b] = v
    for j in range(C.JT.shape[0]):
        for c in range(C.JT.shape[1]):
            C.JT[j, c] = 0.0
    for m in range(r):
        o, e = P.dof[m], P.dof[m + 1]
        for j in range(o, e):
            for i in range(k):
                v = 0.0
                for a in range(6):
                    v += S[i, a] * W.J[m, a, j - o]
                C.JT[j, m * k + i] = v


@kernel
def paper_distribution(P, W, C):
    """C.f ← the paper's distribution f_m = S W(−s_m) Sᵀ y / r (eqs. 8, 30).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef): reads the grasp offsets W.s.
        C: the controller (PackedControl StructRef): reads C.y (k,); C.f (rk,) written (N, N·m, in the
            rows S), C.v6 scratch.
    """
    S = P.rows
    k = S.shape[0]
    r = len(P.dof) - 1
    for a in range(6):
        v = 0.0
        for i in range(k):
            v += C.y[i] * S[i, a]
        C.v6[a] = v
    f0, f1, f2 = C.v6[0], C.v6[1], C.v6[2]
    for m in range(r):
        s = W.s[m]
        n0 = C.v6[3] + (s[1] * f2 - s[2] * f1)
        n1 = C.v6[4] + (s[2] * f0 - s[0] * f2)
        n2 = C.v6[5] + (s[0] * f1 - s[1] * f0)
        for i in range(k):
            v = S[i, 0] * f0 + S[i, 1] * f1 + S[i, 2] * f2 + S[i, 3] * n0 + S[i, 4] * n1 + S[i, 5] * n2
            C.f[m * k + i] = v / r


@kernel
def nonsqueezing_distribution(P, W, C):
    """C.f ← the non-squeezing distribution M*Aᵀ (A M*Aᵀ)⁻¹ y (Erhart & Hirche).

    M* = blockdiag(S diag(m_i* I₃, R_o J_i* R_oᵀ) Sᵀ) of the virtual bodies (C.vmass, C.vinertia).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef): reads W.R_o; W.m3[0] is scratch.
        C: the controller (PackedControl StructRef): reads C.A and C.y; C.f (rk,) written; C.MA, C.G,
            C.xk, C.x, C.v6, C.v3 and C.R3b scratch.

    Returns:
        bool: False when A M*Aᵀ is singular (a zero pivot; C.f not written), else True.
    """
    S = P.rows
    k = S.shape[0]
    r = len(P.dof) - 1
    B = W.m3[0]
    for m in range(r):
        matmul3(W.R_o, C.vinertia[m], C.R3b)
        matmul3_T(C.R3b, W.R_o, B)
        for b in range(k):             # column b of the block times Aᵀ: M*_m A_mᵀ (k, k)
            for a in range(6):
                v = 0.0
                for i in range(k):     # (Sᵀ A_mᵀ)[a, b] = Σ_i S[i, a] A[b, m k + i]
                    v += S[i, a] * C.A[b, m * k + i]
                C.v6[a] = v
            for a in range(3):
                C.v3[a] = B[a, 0] * C.v6[3] + B[a, 1] * C.v6[4] + B[a, 2] * C.v6[5]
            for i in range(k):
                C.MA[m * k + i, b] = (C.vmass[m] * (S[i, 0] * C.v6[0] + S[i, 1] * C.v6[1] + S[i, 2] * C.v6[2])
                                      + S[i, 3] * C.v3[0] + S[i, 4] * C.v3[1] + S[i, 5] * C.v3[2])
    for i in range(k):
        C.xk[i] = C.y[i]
    if not gram_solve(C, k):
        return False
    for c in range(r * k):
        C.f[c] = C.x[c]
    return True


@kernel
def min_energy_distribution(C, k):
    """C.f ← argmin ½ τᵀQτ, τ = τ_arms + Jᵀf, subject to A f = y (eqs. 33–35).

    By the KKT system [J Q Jᵀ, Aᵀ; A, 0][f; λ] = [−J Q τ_arms; y], Gaussian elimination with partial
    pivoting.

    Args:
        C: the controller (PackedControl StructRef): reads C.JT, C.weights (Q), C.tau_arms, C.A and C.y;
            C.f (rk,) written; C.kkt and C.x scratch.
        k: rows per grasp.

    Returns:
        bool: False when the KKT system is singular (a zero pivot; C.f not written), else True.
    """
    N, mk = C.JT.shape
    K = C.kkt
    Q = C.weights
    for p in range(mk):
        v = 0.0
        for j in range(N):
            v -= C.JT[j, p] * Q[j] * C.tau_arms[j]
        C.x[p] = v
        for c in range(p, mk):
            v = 0.0
            for j in range(N):
                v += C.JT[j, p] * Q[j] * C.JT[j, c]
            K[p, c], K[c, p] = v, v
        for i in range(k):
            K[mk + i, p], K[p, mk + i] = C.A[i, p], C.A[i, p]
    for i in range(k):
        C.x[mk + i] = C.y[i]
        for c in range(k):
            K[mk + i, mk + c] = 0.0
    if gauss_solve(K, mk + k, C.x) == 0.0:
        return False
    for p in range(mk):
        C.f[p] = C.x[p]
    return True


@kernel
def squeeze_wrenches(P, W, C, force):
    """C.f += the squeeze wrenches, projected on the null space of A (internal forces only).

    Each grasp pushes `force` N towards C along its grasp line (ρ_m = −s_m), F_m = S [−force ρ_m/|ρ_m|; 0],
    projected as F − Aᵀ(AAᵀ)⁻¹A F (`coopsim.control.laws.squeeze_wrenches`).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef): reads the grasp offsets W.s.
        C: the controller (PackedControl StructRef): reads C.A; C.f (rk,) added to; C.fs, C.MA, C.xk, C.G
            and C.x scratch.
        force: N, the squeeze force per grasp.

    Returns:
        bool: False when A Aᵀ is singular (a zero pivot; C.f unchanged), else True.
    """
    S = P.rows
    k = S.shape[0]
    r = len(P.dof) - 1
    for m in range(r):
        s = W.s[m]
        nrm = np.sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2])
        d = nrm if nrm > 0 else 1.0
        for i in range(k):
            C.fs[m * k + i] = -force * (S[i, 0] * -s[0] + S[i, 1] * -s[1] + S[i, 2] * -s[2]) / d
    for i in range(k):
        v = 0.0
        for c in range(r * k):
            v += C.A[i, c] * C.fs[c]
            C.MA[c, i] = C.A[i, c]
        C.xk[i] = v
    if not gram_solve(C, k):
        return False
    for c in range(r * k):
        C.f[c] += C.fs[c] - C.x[c]
    return True


@kernel
def state_terms(P, W, C, q, qd):
    """The arm and object terms of (θ, θ̇) into W, the arms' own mass-matrix blocks kept in C.Mb.

    `arm_terms`, `object_pose` and `object_dynamics`; C.Mb is copied before object_dynamics adds the
    object's inertia to the carrier's block.

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef): the arm and object terms written.
        C: the controller (PackedControl StructRef): C.Mb (N, nmax) written.
        q: (N,) rad or m, the joint coordinates θ.
        qd: (N,) rad/s or m/s, the joint rates θ̇.
    """
    arm_terms(P, W, q, qd)
    copy2(W.Mb, C.Mb)
    object_pose(P, W)
    object_dynamics(P, W, qd)


@kernel
def inverse_torques(P, W, C, qdd, squeeze, tau):
    """τ ← the closed-chain inverse dynamics at (θ, θ̇, θ̈ = qdd), the object's wrench distributed by C.distribution.

    τ = τ_arms + Jᵀ f with A f = y (module docstring), plus a squeeze when `squeeze` ≠ 0. W and C.Mb
    hold the terms of (θ, θ̇) (`state_terms`).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef) with the terms of (θ, θ̇), read.
        C: the controller (PackedControl StructRef): C.tau_arms, C.acc, C.Y, C.y, C.A, C.JT, C.f and the
            distribution's scratch written.
        qdd: (N,) rad/s² (m/s²), the joint accelerations θ̈.
        squeeze: N, the squeeze force (0: none).
        tau: (N,) written: N·m (N on a prismatic joint); left unchanged on CONTROL_SINGULAR.

    Returns:
        int: OK or CONTROL_SINGULAR.
    """
    S = P.rows
    k = S.shape[0]
    for m in range(len(P.dof) - 1):
        o, e = P.dof[m], P.dof[m + 1]
        for j in range(o, e):
            v = W.h_arm[j]
            for l in range(o, e):
                v += C.Mb[j, l - o] * qdd[l]
            C.tau_arms[j] = v
    object_acceleration(P, W, qdd, C.acc)
    object_wrench(P, W, C.acc, C.Y)
    for i in range(k):
        v = 0.0
        for a in range(6):
            v += C.Y[a] * S[i, a]
        C.y[i] = v
    grasp_rows(P, W, C)
    if C.distribution == DIST_PAPER:
        paper_distribution(P, W, C)
        ok = True
    elif C.distribution == DIST_NONSQUEEZING:
        ok = nonsqueezing_distribution(P, W, C)
    else:
        ok = min_energy_distribution(C, k)
    if ok and squeeze != 0.0:
        ok = squeeze_wrenches(P, W, C, squeeze)
    if not ok:
        return CONTROL_SINGULAR
    for j in range(len(tau)):
        v = 0.0
        for c in range(C.JT.shape[1]):
            v += C.JT[j, c] * C.f[c]
        tau[j] = C.tau_arms[j] + v
    return OK
