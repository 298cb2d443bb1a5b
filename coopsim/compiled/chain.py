"""Compiled stages 1–4: kinematics → Gibbs–Appell arm terms → object/grasp terms → closed-chain solve.

The equations are those of the reference modules (`coopsim.kinematics`, `gibbs_appell`, `grasp`,
`closed_chain`; paper eqs. 9–10, 11–13, 17–27), evaluated over the flat arrays of a `PackedModel`
into the buffers of a `Workspace` (world axes, SI). Two algorithmic differences, both exact:
  * the arm mass matrix I_m is formed by the composite-rigid-body recursion (O(n²)) instead of the
    Gram matrix of the partial accelerations (O(n³)): with the composite C_l = links l…n−1 (mass m_C,
    first moment h_C = Σ m_i c_i, inertia about the arm's base point I_C), a unit θ̈_l needs the force
    f = z_l × (h_C − m_C p_l) and the moment (base point) n = I_C z_l − h_C × (z_l × p_l), so
    I_m[j, l] = z_j · (n − p_j × f) for j ≤ l — the same entries ∂²S/∂θ̈_j∂θ̈_l;
  * 𝐈 is block diagonal (one block per arm, the object in the carrier's), factored block by block.
Return codes of `chain_forward`: OK, NOT_PD (a mass-matrix block is not positive definite),
RANK_DEFICIENT (Λ𝐈⁻¹Λᵀ lost rank: minimum-norm grasp wrenches were used), NON_FINITE.
"""

from __future__ import annotations

import numpy as np
from .jit import kernel

from .linalg import (block_cholesky, block_solve, block_solve_col, eig_solve, pivoted_cholesky,
                     pivoted_solve, safe_pivot_ratio)
from .packing import STAB_BAUMGARTE
from .spatial import axis_rotation, matmul3, matmul3_T, rot_log, rotate_inertia

OK, NOT_PD, RANK_DEFICIENT, NON_FINITE = 0, 1, 2, 3


# ------------------------------------------------------------------------------------------------
# Stage 1: kinematics
# ------------------------------------------------------------------------------------------------

@kernel
def arm_kinematics(P, W, m, q):
    """Frame poses of arm m at the stacked joint angles q (rad): R_i = R_{i−1} R0_i Rot(axis_i, θ_i),
    p_i = p_{i−1} + R_{i−1} d_i; z_i, c_i, I_i (world) and the end-effector frame."""
    o, e = P.dof[m], P.dof[m + 1]
    T, Rz = W.m3[0], W.m3[1]
    for j in range(o, e):
        Rp = P.base_rot[m] if j == o else W.R[j - 1]
        for a in range(3):
            base = P.base_pos[m, a] if j == o else W.p[j - 1, a]
            W.p[j, a] = base + Rp[a, 0] * P.joint_pos[j, 0] + Rp[a, 1] * P.joint_pos[j, 1] + Rp[a, 2] * P.joint_pos[j, 2]
        axis_rotation(P.joint_axis[j], q[j], Rz)
        matmul3(P.joint_rot[j], Rz, T)
        matmul3(Rp, T, W.R[j])
        R = W.R[j]
        for a in range(3):
            W.z[j, a] = R[a, 0] * P.joint_axis[j, 0] + R[a, 1] * P.joint_axis[j, 1] + R[a, 2] * P.joint_axis[j, 2]
            W.c[j, a] = W.p[j, a] + R[a, 0] * P.link_com[j, 0] + R[a, 1] * P.link_com[j, 1] + R[a, 2] * P.link_com[j, 2]
        rotate_inertia(R, P.link_inertia[j], T, W.I[j])
    last = e - 1
    R = W.R[last]
    for a in range(3):
        W.p_ee[m, a] = W.p[last, a] + R[a, 0] * P.ee_pos[m, 0] + R[a, 1] * P.ee_pos[m, 1] + R[a, 2] * P.ee_pos[m, 2]
    matmul3(R, P.ee_rot[m], W.R_ee[m])


@kernel
def arm_jacobian(P, W, m):
    """End-effector Jacobian J_m (6, n_m): columns [z_j × (p_EE − p_j); z_j] (world axes)."""
    o, e = P.dof[m], P.dof[m + 1]
    for j in range(o, e):
        z = W.z[j]
        d0 = W.p_ee[m, 0] - W.p[j, 0]
        d1 = W.p_ee[m, 1] - W.p[j, 1]
        d2 = W.p_ee[m, 2] - W.p[j, 2]
        col = j - o
        W.J[m, 0, col] = z[1] * d2 - z[2] * d1
        W.J[m, 1, col] = z[2] * d0 - z[0] * d2
        W.J[m, 2, col] = z[0] * d1 - z[1] * d0
        W.J[m, 3, col] = z[0]
        W.J[m, 4, col] = z[1]
        W.J[m, 5, col] = z[2]


# ------------------------------------------------------------------------------------------------
# Stage 2: Gibbs–Appell arm terms
# ------------------------------------------------------------------------------------------------

@kernel
def arm_bias(P, W, m, qd):
    """h_m = −Re_m (bias forces, eq. 10) and J̇_mθ̇_m of arm m from one forward recursion at θ̈ = 0
    with base acceleration −g (eq. 9) and the backward recursion of ∂S/∂θ̈ (`gibbs_gradient_of_motion`):
    ω_i = ω_{i−1} + z_i θ̇_i, ω̇_i = ω̇_{i−1} + ω_{i−1} × z_i θ̇_i, a_{i+1} = a_i + ω̇_i × d + ω_i × (ω_i × d);
    F_j = m_j a_cj + F_{j+1}, N_j = (c_j − p_j) × m_j a_cj + I_j ω̇_j + ω_j × I_j ω_j + N_{j+1}
    + (p_{j+1} − p_j) × F_{j+1}, h_j = z_j · N_j."""
    o, e = P.dof[m], P.dof[m + 1]
    g = P.gravity
    w0 = w1 = w2 = 0.0
    dw0 = dw1 = dw2 = 0.0
    a0, a1, a2 = -g[0], -g[1], -g[2]
    for j in range(o, e):
        if j > o:
            d0 = W.p[j, 0] - W.p[j - 1, 0]
            d1 = W.p[j, 1] - W.p[j - 1, 1]
            d2 = W.p[j, 2] - W.p[j - 1, 2]
            x0, x1, x2 = w1 * d2 - w2 * d1, w2 * d0 - w0 * d2, w0 * d1 - w1 * d0
            a0 += dw1 * d2 - dw2 * d1 + w1 * x2 - w2 * x1
            a1 += dw2 * d0 - dw0 * d2 + w2 * x0 - w0 * x2
            a2 += dw0 * d1 - dw1 * d0 + w0 * x1 - w1 * x0
        zq0, zq1, zq2 = W.z[j, 0] * qd[j], W.z[j, 1] * qd[j], W.z[j, 2] * qd[j]
        dw0 += w1 * zq2 - w2 * zq1
        dw1 += w2 * zq0 - w0 * zq2
        dw2 += w0 * zq1 - w1 * zq0
        w0 += zq0
        w1 += zq1
        w2 += zq2
        W.w[j, 0], W.w[j, 1], W.w[j, 2] = w0, w1, w2
        W.dw[j, 0], W.dw[j, 1], W.dw[j, 2] = dw0, dw1, dw2
        W.a[j, 0], W.a[j, 1], W.a[j, 2] = a0, a1, a2
    # end-effector bias acceleration J̇θ̇ (the base's −g removed)
    last = e - 1
    r0, r1, r2 = W.p_ee[m, 0] - W.p[last, 0], W.p_ee[m, 1] - W.p[last, 1], W.p_ee[m, 2] - W.p[last, 2]
    x0, x1, x2 = w1 * r2 - w2 * r1, w2 * r0 - w0 * r2, w0 * r1 - w1 * r0
    W.Jd_qd[m, 0] = a0 + dw1 * r2 - dw2 * r1 + w1 * x2 - w2 * x1 + g[0]
    W.Jd_qd[m, 1] = a1 + dw2 * r0 - dw0 * r2 + w2 * x0 - w0 * x2 + g[1]
    W.Jd_qd[m, 2] = a2 + dw0 * r1 - dw1 * r0 + w0 * x1 - w1 * x0 + g[2]
    W.Jd_qd[m, 3], W.Jd_qd[m, 4], W.Jd_qd[m, 5] = dw0, dw1, dw2
    # backward recursion
    F0 = F1 = F2 = 0.0
    N0 = N1 = N2 = 0.0
    for j in range(e - 1, o - 1, -1):
        if j < e - 1:  # move N_{j+1} from p_{j+1} to p_j
            d0 = W.p[j + 1, 0] - W.p[j, 0]
            d1 = W.p[j + 1, 1] - W.p[j, 1]
            d2 = W.p[j + 1, 2] - W.p[j, 2]
            N0 += d1 * F2 - d2 * F1
            N1 += d2 * F0 - d0 * F2
            N2 += d0 * F1 - d1 * F0
        w, dw, I = W.w[j], W.dw[j], W.I[j]
        r0, r1, r2 = W.c[j, 0] - W.p[j, 0], W.c[j, 1] - W.p[j, 1], W.c[j, 2] - W.p[j, 2]
        x0, x1, x2 = w[1] * r2 - w[2] * r1, w[2] * r0 - w[0] * r2, w[0] * r1 - w[1] * r0
        mj = P.link_mass[j]
        ma0 = mj * (W.a[j, 0] + dw[1] * r2 - dw[2] * r1 + w[1] * x2 - w[2] * x1)
        ma1 = mj * (W.a[j, 1] + dw[2] * r0 - dw[0] * r2 + w[2] * x0 - w[0] * x2)
        ma2 = mj * (W.a[j, 2] + dw[0] * r1 - dw[1] * r0 + w[0] * x1 - w[1] * x0)
        Iw0 = I[0, 0] * w[0] + I[0, 1] * w[1] + I[0, 2] * w[2]
        Iw1 = I[1, 0] * w[0] + I[1, 1] * w[1] + I[1, 2] * w[2]
        Iw2 = I[2, 0] * w[0] + I[2, 1] * w[1] + I[2, 2] * w[2]
        N0 += r1 * ma2 - r2 * ma1 + I[0, 0] * dw[0] + I[0, 1] * dw[1] + I[0, 2] * dw[2] + w[1] * Iw2 - w[2] * Iw1
        N1 += r2 * ma0 - r0 * ma2 + I[1, 0] * dw[0] + I[1, 1] * dw[1] + I[1, 2] * dw[2] + w[2] * Iw0 - w[0] * Iw2
        N2 += r0 * ma1 - r1 * ma0 + I[2, 0] * dw[0] + I[2, 1] * dw[1] + I[2, 2] * dw[2] + w[0] * Iw1 - w[1] * Iw0
        F0 += ma0
        F1 += ma1
        F2 += ma2
        hj = W.z[j, 0] * N0 + W.z[j, 1] * N1 + W.z[j, 2] * N2
        W.h_arm[j] = hj
        W.h[j] = hj


@kernel
def arm_mass_matrix(P, W, m):
    """I_m (n_m, n_m) of arm m by the composite-rigid-body recursion (module docstring), positions
    taken relative to the arm's base point, into W.Mb rows dof[m]:dof[m+1]."""
    o, e = P.dof[m], P.dof[m + 1]
    b0, b1, b2 = P.base_pos[m, 0], P.base_pos[m, 1], P.base_pos[m, 2]
    mc = 0.0
    hc0 = hc1 = hc2 = 0.0
    Ic = W.m3[2]
    for a in range(3):
        for b in range(3):
            Ic[a, b] = 0.0
    for l in range(e - 1, o - 1, -1):
        mi = P.link_mass[l]
        c0, c1, c2 = W.c[l, 0] - b0, W.c[l, 1] - b1, W.c[l, 2] - b2
        cc = c0 * c0 + c1 * c1 + c2 * c2
        for a in range(3):
            for b in range(3):
                Ic[a, b] += W.I[l, a, b]
        Ic[0, 0] += mi * (cc - c0 * c0)
        Ic[1, 1] += mi * (cc - c1 * c1)
        Ic[2, 2] += mi * (cc - c2 * c2)
        Ic[0, 1] -= mi * c0 * c1
        Ic[1, 0] -= mi * c0 * c1
        Ic[0, 2] -= mi * c0 * c2
        Ic[2, 0] -= mi * c0 * c2
        Ic[1, 2] -= mi * c1 * c2
        Ic[2, 1] -= mi * c1 * c2
        mc += mi
        hc0 += mi * c0
        hc1 += mi * c1
        hc2 += mi * c2
        z = W.z[l]
        p0, p1, p2 = W.p[l, 0] - b0, W.p[l, 1] - b1, W.p[l, 2] - b2
        u0, u1, u2 = hc0 - mc * p0, hc1 - mc * p1, hc2 - mc * p2
        f0, f1, f2 = z[1] * u2 - z[2] * u1, z[2] * u0 - z[0] * u2, z[0] * u1 - z[1] * u0
        v0, v1, v2 = z[1] * p2 - z[2] * p1, z[2] * p0 - z[0] * p2, z[0] * p1 - z[1] * p0
        n0 = Ic[0, 0] * z[0] + Ic[0, 1] * z[1] + Ic[0, 2] * z[2] - (hc1 * v2 - hc2 * v1)
        n1 = Ic[1, 0] * z[0] + Ic[1, 1] * z[1] + Ic[1, 2] * z[2] - (hc2 * v0 - hc0 * v2)
        n2 = Ic[2, 0] * z[0] + Ic[2, 1] * z[1] + Ic[2, 2] * z[2] - (hc0 * v1 - hc1 * v0)
        for j in range(o, l + 1):
            q0, q1, q2 = W.p[j, 0] - b0, W.p[j, 1] - b1, W.p[j, 2] - b2
            m0 = n0 - (q1 * f2 - q2 * f1)
            m1 = n1 - (q2 * f0 - q0 * f2)
            m2 = n2 - (q0 * f1 - q1 * f0)
            v = W.z[j, 0] * m0 + W.z[j, 1] * m1 + W.z[j, 2] * m2
            W.Mb[j, l - o] = v
            W.Mb[l, j - o] = v


# ------------------------------------------------------------------------------------------------
# Stage 3: object and grasps
# ------------------------------------------------------------------------------------------------

@kernel
def object_pose(P, W):
    """The object carried by arm c (eqs. 11–13): pose (p_C, R_o, K_o), offsets s_m = p_C − grasp point m
    (r, 3) and the object Jacobian J_o = W_c⁻ᵀ J_c (6, n_c), from the current kinematics."""
    c = P.carrier
    n = P.dof[c + 1] - P.dof[c]
    matmul3_T(W.R_ee[c], P.grasp_rot[c], W.R_o)
    Ro = W.R_o
    for a in range(3):
        W.p_C[a] = W.p_ee[c, a] - (Ro[a, 0] * P.grasp_pos[c, 0] + Ro[a, 1] * P.grasp_pos[c, 1] + Ro[a, 2] * P.grasp_pos[c, 2])
    rotate_inertia(Ro, P.obj_inertia, W.m3[0], W.K_o)
    for m in range(len(P.dof) - 1):
        for a in range(3):
            W.s[m, a] = -(Ro[a, 0] * P.grasp_pos[m, 0] + Ro[a, 1] * P.grasp_pos[m, 1] + Ro[a, 2] * P.grasp_pos[m, 2])
    s0, s1, s2 = W.s[c, 0], W.s[c, 1], W.s[c, 2]
    for j in range(n):
        jw0, jw1, jw2 = W.J[c, 3, j], W.J[c, 4, j], W.J[c, 5, j]
        W.J_o[0, j] = W.J[c, 0, j] - (s1 * jw2 - s2 * jw1)
        W.J_o[1, j] = W.J[c, 1, j] - (s2 * jw0 - s0 * jw2)
        W.J_o[2, j] = W.J[c, 2, j] - (s0 * jw1 - s1 * jw0)
        W.J_o[3, j], W.J_o[4, j], W.J_o[5, j] = jw0, jw1, jw2


@kernel
def object_dynamics(P, W, qd):
    """Object twist v_o = J_oθ̇_c, J̇_oθ̇_c = W_c⁻ᵀ J̇_cθ̇_c + [ω × (ω × s_c); 0], and the object's inertia
    joined to the carrier block (eqs. 17–19): 𝐈_cc += J_oᵀ M_o J_o, h_c += J_oᵀ (M_o J̇_oθ̇_c + b_o),
    b_o = [−m_o g; ω × K_o ω] (W.Y_bias holds M_o J̇_oθ̇_c + b_o). Needs `object_pose` and the arm terms."""
    c = P.carrier
    o = P.dof[c]
    n = P.dof[c + 1] - o
    s0, s1, s2 = W.s[c, 0], W.s[c, 1], W.s[c, 2]
    for a in range(6):
        v = 0.0
        for j in range(n):
            v += W.J_o[a, j] * qd[o + j]
        W.v_o[a] = v
    w0, w1, w2 = W.v_o[3], W.v_o[4], W.v_o[5]
    x0, x1, x2 = w1 * s2 - w2 * s1, w2 * s0 - w0 * s2, w0 * s1 - w1 * s0
    jd = W.Jd_qd[c]
    W.Jd_o_qd[0] = jd[0] - (s1 * jd[5] - s2 * jd[4]) + w1 * x2 - w2 * x1
    W.Jd_o_qd[1] = jd[1] - (s2 * jd[3] - s0 * jd[5]) + w2 * x0 - w0 * x2
    W.Jd_o_qd[2] = jd[2] - (s0 * jd[4] - s1 * jd[3]) + w0 * x1 - w1 * x0
    W.Jd_o_qd[3], W.Jd_o_qd[4], W.Jd_o_qd[5] = jd[3], jd[4], jd[5]
    mo, K, g = P.obj_mass, W.K_o, P.gravity
    Kw0 = K[0, 0] * w0 + K[0, 1] * w1 + K[0, 2] * w2
    Kw1 = K[1, 0] * w0 + K[1, 1] * w1 + K[1, 2] * w2
    Kw2 = K[2, 0] * w0 + K[2, 1] * w1 + K[2, 2] * w2
    ad = W.Jd_o_qd
    for a in range(3):
        W.Y_bias[a] = mo * (ad[a] - g[a])
        W.Y_bias[3 + a] = K[a, 0] * ad[3] + K[a, 1] * ad[4] + K[a, 2] * ad[5]
    W.Y_bias[3] += w1 * Kw2 - w2 * Kw1
    W.Y_bias[4] += w2 * Kw0 - w0 * Kw2
    W.Y_bias[5] += w0 * Kw1 - w1 * Kw0
    for i in range(n):
        hv = 0.0
        for a in range(6):
            hv += W.J_o[a, i] * W.Y_bias[a]
        W.h[o + i] += hv
        for l in range(i, n):
            v = mo * (W.J_o[0, i] * W.J_o[0, l] + W.J_o[1, i] * W.J_o[1, l] + W.J_o[2, i] * W.J_o[2, l])
            for a in range(3):
                v += W.J_o[3 + a, i] * (K[a, 0] * W.J_o[3, l] + K[a, 1] * W.J_o[4, l] + K[a, 2] * W.J_o[5, l])
            W.Mb[o + i, l] += v
            if l != i:
                W.Mb[o + l, i] += v


# ------------------------------------------------------------------------------------------------
# Stage 4: closed chain
# ------------------------------------------------------------------------------------------------

@kernel
def constraint_jacobian(P, W):
    """Λ (K, N) (eq. 23): for each arm m ≠ c the rows S (J_m θ̇_m − W_mᵀ J_o θ̇_c), with
    W_mᵀ [v; ω] = [v + s_m × ω; ω]. Columns of arms other than m and c stay zero."""
    S = P.rows
    k = S.shape[0]
    c = P.carrier
    oc, nc = P.dof[c], P.dof[c + 1] - P.dof[c]
    g = 0
    for m in range(len(P.dof) - 1):
        if m == c:
            continue
        om, nm = P.dof[m], P.dof[m + 1] - P.dof[m]
        s0, s1, s2 = W.s[m, 0], W.s[m, 1], W.s[m, 2]
        for i in range(k):
            row = g * k + i
            for j in range(nm):
                v = 0.0
                for a in range(6):
                    v += S[i, a] * W.J[m, a, j]
                W.Lam[row, om + j] = v
            for j in range(nc):
                jw0, jw1, jw2 = W.J_o[3, j], W.J_o[4, j], W.J_o[5, j]
                v = (S[i, 0] * (W.J_o[0, j] + s1 * jw2 - s2 * jw1) + S[i, 1] * (W.J_o[1, j] + s2 * jw0 - s0 * jw2)
                     + S[i, 2] * (W.J_o[2, j] + s0 * jw1 - s1 * jw0) + S[i, 3] * jw0 + S[i, 4] * jw1 + S[i, 5] * jw2)
                W.Lam[row, oc + j] = -v
        g += 1


@kernel
def constraint_bias(P, W):
    """Λ̇θ̇ (K,) (eq. 24): S (J̇_mθ̇_m − W_mᵀ J̇_oθ̇_c − [ω × (ω × (−s_m)); 0]) for each arm m ≠ c."""
    S = P.rows
    k = S.shape[0]
    w0, w1, w2 = W.v_o[3], W.v_o[4], W.v_o[5]
    ad = W.Jd_o_qd
    u = W.vec6
    g = 0
    for m in range(len(P.dof) - 1):
        if m == P.carrier:
            continue
        s0, s1, s2 = W.s[m, 0], W.s[m, 1], W.s[m, 2]
        x0, x1, x2 = -(w1 * s2 - w2 * s1), -(w2 * s0 - w0 * s2), -(w0 * s1 - w1 * s0)   # ω × (−s_m)
        u[0] = W.Jd_qd[m, 0] - (ad[0] + s1 * ad[5] - s2 * ad[4]) - (w1 * x2 - w2 * x1)
        u[1] = W.Jd_qd[m, 1] - (ad[1] + s2 * ad[3] - s0 * ad[5]) - (w2 * x0 - w0 * x2)
        u[2] = W.Jd_qd[m, 2] - (ad[2] + s0 * ad[4] - s1 * ad[3]) - (w0 * x1 - w1 * x0)
        u[3] = W.Jd_qd[m, 3] - ad[3]
        u[4] = W.Jd_qd[m, 4] - ad[4]
        u[5] = W.Jd_qd[m, 5] - ad[5]
        for i in range(k):
            v = 0.0
            for a in range(6):
                v += S[i, a] * u[a]
            W.Lam_dot_qd[g * k + i] = v
        g += 1


@kernel
def arm_terms(P, W, q, qd):
    """Stages 1–2 for every open arm at (q, qd) (N,): kinematics, J_m, J̇_mθ̇_m, h_m and I_m (eq. 10)."""
    for m in range(len(P.dof) - 1):
        arm_kinematics(P, W, m, q)
        arm_jacobian(P, W, m)
        arm_bias(P, W, m, qd)
        arm_mass_matrix(P, W, m)


@kernel
def chain_terms(P, W, q, qd):
    """Stages 1–3 and the assembly of eqs. 17–24 at state (q, qd) (N,) into W."""
    arm_terms(P, W, q, qd)
    object_pose(P, W)
    object_dynamics(P, W, qd)
    constraint_jacobian(P, W)
    constraint_bias(P, W)


@kernel
def loop_residual(P, W):
    """Φ (K,) into W.phi from the current kinematics: for each arm m ≠ c,
    S [p_EE,m − p_grasp,m; log(R_EE,m R_grasp,mᵀ)] (m, rad), the grasp frame carried by the object."""
    S = P.rows
    k = S.shape[0]
    Ro = W.R_o
    Rd, E = W.m3[0], W.m3[1]
    err = W.vec6
    lg = W.v3
    g = 0
    for m in range(len(P.dof) - 1):
        if m == P.carrier:
            continue
        matmul3(Ro, P.grasp_rot[m], Rd)
        for a in range(3):
            err[a] = W.p_ee[m, a] - W.p_C[a] + W.s[m, a]   # p_des = p_C + R_o g_m = p_C − s_m
        matmul3_T(W.R_ee[m], Rd, E)
        rot_log(E, lg)
        err[3], err[4], err[5] = lg[0], lg[1], lg[2]
        for i in range(k):
            v = 0.0
            for a in range(6):
                v += S[i, a] * err[a]
            W.phi[g * k + i] = v
        g += 1


@kernel
def solve_constraints(P, W, K):
    """F ← (Λ𝐈⁻¹Λᵀ)⁻¹ b (W.A, W.b): pivoted Cholesky when the pivots prove full rank, else the
    minimum-norm eigen solution. Sets W.rank, W.cond (−1: not computed on the fast path)."""
    ratio = pivoted_cholesky(W.A, W.A_f, W.perm, K)
    if ratio > safe_pivot_ratio(K, P.rank_tol):
        pivoted_solve(W.A_f, W.perm, K, W.b, W.yK, W.F)
        W.rank[0] = K
        W.cond[0] = -1.0
        return True
    cond, rank = eig_solve(W.A, W.b, W.F, K, P.rank_tol)
    W.rank[0] = rank
    W.cond[0] = cond
    return False


@kernel
def chain_solve(P, W, tau, stab):
    """θ̈ (eqs. 25–27) into W.qdd and the loop-closure wrenches F (K,) into W.F for torques tau (N,),
    with `stab` (K,) added to the right-hand side of Λθ̈ = −Λ̇θ̇ − stab (zeros: none). Needs
    `chain_terms` first. One step of iterative refinement on the acceleration constraint. Returns a
    status code (module docstring)."""
    Lam_, X_, x0_, h_, Mb_, Lb_, b_, A_ = W.Lam, W.X, W.x0, W.h, W.Mb, W.Lb, W.b, W.A
    F_, qdd_, res_, A_f_, perm_, yK_, dF_, Lam_dot_qd_ = W.F, W.qdd, W.res, W.A_f, W.perm, W.yK, W.dF, W.Lam_dot_qd
    dof = P.dof
    N = dof[-1]
    K = Lam_.shape[0]
    for m in range(len(dof) - 1):
        o, n = dof[m], dof[m + 1] - dof[m]
        if not block_cholesky(Mb_, Lb_, o, n):
            return NOT_PD
    for i in range(N):
        x0_[i] = tau[i] - h_[i]
    for m in range(len(dof) - 1):
        block_solve(Lb_, dof[m], dof[m + 1] - dof[m], x0_, dof[m])
    # X = 𝐈⁻¹Λᵀ: row group g touches arm m and the carrier only
    c = P.carrier
    k = P.rows.shape[0]
    g = 0
    for m in range(len(dof) - 1):
        if m == c:
            continue
        for i in range(g * k, (g + 1) * k):
            for blk in (m, c):
                o, e = dof[blk], dof[blk + 1]
                for j in range(o, e):
                    X_[j, i] = Lam_[i, j]
                block_solve_col(Lb_, o, e - o, X_, i)
        g += 1
    for i in range(K):
        v = Lam_dot_qd_[i] + stab[i]
        for j in range(N):
            v += Lam_[i, j] * x0_[j]
        b_[i] = v
        for l in range(i, K):
            a = 0.0
            for j in range(N):
                a += Lam_[i, j] * X_[j, l]
            A_[i, l] = a
            A_[l, i] = a
    fast = solve_constraints(P, W, K)
    for j in range(N):
        v = x0_[j]
        for i in range(K):
            v -= X_[j, i] * F_[i]
        qdd_[j] = v
    # refinement: residual of Λθ̈ + Λ̇θ̇ + stab = 0
    for i in range(K):
        v = Lam_dot_qd_[i] + stab[i]
        for j in range(N):
            v += Lam_[i, j] * qdd_[j]
        res_[i] = v
    if fast:
        pivoted_solve(A_f_, perm_, K, res_, yK_, dF_)
    else:
        eig_solve(A_, res_, dF_, K, P.rank_tol)
    for i in range(K):
        F_[i] += dF_[i]
    for j in range(N):
        v = 0.0
        for i in range(K):
            v += X_[j, i] * dF_[i]
        qdd_[j] -= v
    for j in range(N):
        if not np.isfinite(qdd_[j]):
            return NON_FINITE
    return OK if W.rank[0] == K else RANK_DEFICIENT


@kernel
def baumgarte_rhs(P, W, qd, out):
    """out (K,) ← 2α Λθ̇ + β² Φ (Baumgarte's stabilising right-hand side), or zeros without it."""
    K = W.Lam.shape[0]
    if P.stabilization != STAB_BAUMGARTE:
        for i in range(K):
            out[i] = 0.0
        return
    loop_residual(P, W)
    for i in range(K):
        v = 0.0
        for j in range(P.dof[-1]):
            v += W.Lam[i, j] * qd[j]
        out[i] = 2.0 * P.alpha * v + P.beta * P.beta * W.phi[i]


@kernel
def chain_forward(P, W, q, qd, tau, stab):
    """One closed-chain forward-dynamics evaluation at (q, qd) with torques tau: W.qdd, W.F and every
    intermediate term in W; stab (K,) scratch for the Baumgarte term. Returns a status code."""
    chain_terms(P, W, q, qd)
    baumgarte_rhs(P, W, qd, stab)
    return chain_solve(P, W, tau, stab)
