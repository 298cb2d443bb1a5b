"""Compiled stages 1–4: kinematics → Gibbs–Appell arm terms → object/grasp terms → closed-chain solve.

The equations are those of the reference modules (`coopsim.dynamics.kinematics`, `gibbs_appell`, `grasp`,
`closed_chain`; paper eqs. 9–10, 11–13, 17–27), evaluated over the flat arrays of a `PackedModel`
into the buffers of a `Workspace` (world axes, SI). Two algorithmic differences, both exact:
  * the arm mass matrix I_m is formed by the composite-rigid-body recursion (O(n²)) instead of the
    Gram matrix of the partial accelerations (O(n³)): with the composite C_l = links l…n−1 (mass m_C,
    first moment h_C = Σ m_i c_i, inertia about the arm's base point I_C), a unit θ̈_l needs the force
    f = z_l × (h_C − m_C p_l) and the moment (base point) n = I_C z_l − h_C × (z_l × p_l), so
    I_m[j, l] = z_j · (n − p_j × f) for j ≤ l — the same entries ∂²S/∂θ̈_j∂θ̈_l;
  * 𝐈 is block diagonal (one block per arm, the object in the carrier's), factored block by block,
    and Λ𝐈⁻¹Λᵀ is formed as YᵀY with Y = L⁻¹Λᵀ (`chain_solve`).
Joints are revolute or prismatic (P.joint_type, the joint model of `coopsim.core.joints`): each kernel
below branches on the type where a prismatic joint differs — its frame slides θ z along its axis
instead of turning, its Jacobian column is [z; 0], its link motion gains z θ̈ + 2ω × z θ̇ in place of
an angular term, its bias and mass-matrix rows are z · (force) instead of z · (moment).
As in the reference, every lever arm is formed from positions relative to the arm's base point
(W.p_rel, W.c_rel, W.p_ee_rel), never from world positions (W.p, W.c, W.p_ee, W.p_C are outputs).
Return codes of `chain_forward`: OK, NOT_PD (a mass-matrix block is not positive definite),
RANK_DEFICIENT (Λ𝐈⁻¹Λᵀ lost rank: minimum-norm grasp wrenches were used), NON_FINITE.
"""

from __future__ import annotations

import numpy as np
from coopsim.compiled.toolchain.jit import kernel

from coopsim.compiled.linalg import eig_solve, pivoted_cholesky, pivoted_solve, safe_pivot_ratio
from coopsim.core.model import PRISMATIC
from coopsim.compiled.packing import STAB_BAUMGARTE
from coopsim.compiled.schur import constraint_trace, group_arm, schur_factor, schur_solve
from coopsim.compiled.spatial import rot_log
from coopsim.compiled.structs import borrow

OK, NOT_PD, RANK_DEFICIENT, NON_FINITE = 0, 1, 2, 3
EIGEN, DENSE, SCHUR = 0, 1, 2   # the constraint solve's paths (`chain_solve`)


# ------------------------------------------------------------------------------------------------
# Stage 1: kinematics
# ------------------------------------------------------------------------------------------------

@kernel
def place_point(R, x, l, o, rel, world):
    """A point l fixed in a frame, relative to the arm's base point and in the world: rel ← x + R l, world ← o + rel.

    Args:
        R: (3, 3) world ← the frame.
        x: (3,) m, the frame's origin relative to the arm's base point o, world axes.
        l: (3,) m, the point in the frame.
        o: (3,) m, the arm's base point, world.
        rel: (3,) written: the point relative to o, m, world axes.
        world: (3,) written: the point, m, world.
    """
    for a in range(3):
        v = x[a] + R[a, 0] * l[0] + R[a, 1] * l[1] + R[a, 2] * l[2]
        rel[a] = v
        world[a] = o[a] + v


@kernel
def arm_kinematics(P, W, m, q):
    """Frame poses of arm m at the stacked joint angles q: R_i, p_i, z_i, c_i, I_i and the end-effector frame.

    R_i = R_{i−1} R0_i Rot(axis_i, θ_i), p_i = p_{i−1} + R_{i−1} d_i; z_i, c_i, I_i (world) and the
    end-effector frame. With Rodrigues' Rot(a, θ) = 1 + sinθ [a×] + (1 − cosθ)[a×]²,
    R0_i Rot(a_i, θ_i) = R0_i + sinθ K1_i + (1 − cosθ) K2_i (K1 = R0[a×], K2 = R0[a×]² packed),
    z_i = R_i a_i = R_{i−1} (R0_i a_i) (Rot(a, θ) a = a), and I_i = R_i I_link R_iᵀ formed as a symmetric
    matrix. The parent frame is carried in scalars. Positions are accumulated from the base point
    (W.p_rel, c_rel, p_ee_rel); the world ones add base_pos. A prismatic joint keeps R_i = R_{i−1} R0_i
    and moves p_i by θ_i z_i (θ_i in m).

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef). Written in arm m's rows, world axes: W.R (world ← link
            frame), W.z (unit joint axes), W.I (kg·m², about the centres of mass), W.p_rel, W.c_rel (m,
            joint origins and centres of mass relative to the arm's base point), W.p, W.c (the same, world
            positions), and W.R_ee[m], W.p_ee_rel[m], W.p_ee[m] (the end-effector frame).
        m: the arm index, 0-based.
        q: (N,) rad or m, the stacked joint coordinates (arm m's rows read).
    """
    dof, jt = P.dof, P.joint_type
    bp, br, jp, jr, k1, k2, jz = P.base_pos, P.base_rot, P.joint_pos, P.joint_rot, P.joint_k1, P.joint_k2, P.joint_z
    lc, li, eep, eer = P.link_com, P.link_inertia, P.ee_pos, P.ee_rot
    p, R, z, cw, Iw, p_ee, R_ee = W.p, W.R, W.z, W.c, W.I, W.p_ee, W.R_ee
    pr, cr, per = W.p_rel, W.c_rel, W.p_ee_rel
    o, e = dof[m], dof[m + 1]
    o0, o1, o2 = bp[m, 0], bp[m, 1], bp[m, 2]
    x0 = x1 = x2 = 0.0
    a00, a01, a02 = br[m, 0, 0], br[m, 0, 1], br[m, 0, 2]
    a10, a11, a12 = br[m, 1, 0], br[m, 1, 1], br[m, 1, 2]
    a20, a21, a22 = br[m, 2, 0], br[m, 2, 1], br[m, 2, 2]
    for j in range(o, e):
        d0, d1, d2 = jp[j, 0], jp[j, 1], jp[j, 2]
        x0, x1, x2 = (x0 + a00 * d0 + a01 * d1 + a02 * d2, x1 + a10 * d0 + a11 * d1 + a12 * d2,
                      x2 + a20 * d0 + a21 * d1 + a22 * d2)
        u0, u1, u2 = jz[j, 0], jz[j, 1], jz[j, 2]
        zz0 = a00 * u0 + a01 * u1 + a02 * u2
        zz1 = a10 * u0 + a11 * u1 + a12 * u2
        zz2 = a20 * u0 + a21 * u1 + a22 * u2
        z[j, 0], z[j, 1], z[j, 2] = zz0, zz1, zz2
        th = q[j]
        if jt[j] == PRISMATIC:
            sn = cs = 0.0
            x0, x1, x2 = x0 + th * zz0, x1 + th * zz1, x2 + th * zz2
        else:
            sn, cs = np.sin(th), 1.0 - np.cos(th)
        t00 = jr[j, 0, 0] + sn * k1[j, 0, 0] + cs * k2[j, 0, 0]
        t01 = jr[j, 0, 1] + sn * k1[j, 0, 1] + cs * k2[j, 0, 1]
        t02 = jr[j, 0, 2] + sn * k1[j, 0, 2] + cs * k2[j, 0, 2]
        t10 = jr[j, 1, 0] + sn * k1[j, 1, 0] + cs * k2[j, 1, 0]
        t11 = jr[j, 1, 1] + sn * k1[j, 1, 1] + cs * k2[j, 1, 1]
        t12 = jr[j, 1, 2] + sn * k1[j, 1, 2] + cs * k2[j, 1, 2]
        t20 = jr[j, 2, 0] + sn * k1[j, 2, 0] + cs * k2[j, 2, 0]
        t21 = jr[j, 2, 1] + sn * k1[j, 2, 1] + cs * k2[j, 2, 1]
        t22 = jr[j, 2, 2] + sn * k1[j, 2, 2] + cs * k2[j, 2, 2]
        b00 = a00 * t00 + a01 * t10 + a02 * t20
        b01 = a00 * t01 + a01 * t11 + a02 * t21
        b02 = a00 * t02 + a01 * t12 + a02 * t22
        b10 = a10 * t00 + a11 * t10 + a12 * t20
        b11 = a10 * t01 + a11 * t11 + a12 * t21
        b12 = a10 * t02 + a11 * t12 + a12 * t22
        b20 = a20 * t00 + a21 * t10 + a22 * t20
        b21 = a20 * t01 + a21 * t11 + a22 * t21
        b22 = a20 * t02 + a21 * t12 + a22 * t22
        R[j, 0, 0], R[j, 0, 1], R[j, 0, 2] = b00, b01, b02
        R[j, 1, 0], R[j, 1, 1], R[j, 1, 2] = b10, b11, b12
        R[j, 2, 0], R[j, 2, 1], R[j, 2, 2] = b20, b21, b22
        pr[j, 0], pr[j, 1], pr[j, 2] = x0, x1, x2
        p[j, 0], p[j, 1], p[j, 2] = o0 + x0, o1 + x1, o2 + x2
        place_point(R[j], pr[j], lc[j], bp[m], cr[j], cw[j])
        i00, i01, i02 = li[j, 0, 0], li[j, 0, 1], li[j, 0, 2]
        i10, i11, i12 = li[j, 1, 0], li[j, 1, 1], li[j, 1, 2]
        i20, i21, i22 = li[j, 2, 0], li[j, 2, 1], li[j, 2, 2]
        m00 = b00 * i00 + b01 * i10 + b02 * i20
        m01 = b00 * i01 + b01 * i11 + b02 * i21
        m02 = b00 * i02 + b01 * i12 + b02 * i22
        m10 = b10 * i00 + b11 * i10 + b12 * i20
        m11 = b10 * i01 + b11 * i11 + b12 * i21
        m12 = b10 * i02 + b11 * i12 + b12 * i22
        m20 = b20 * i00 + b21 * i10 + b22 * i20
        m21 = b20 * i01 + b21 * i11 + b22 * i21
        m22 = b20 * i02 + b21 * i12 + b22 * i22
        v01 = m00 * b10 + m01 * b11 + m02 * b12
        v02 = m00 * b20 + m01 * b21 + m02 * b22
        v12 = m10 * b20 + m11 * b21 + m12 * b22
        Iw[j, 0, 0] = m00 * b00 + m01 * b01 + m02 * b02
        Iw[j, 1, 1] = m10 * b10 + m11 * b11 + m12 * b12
        Iw[j, 2, 2] = m20 * b20 + m21 * b21 + m22 * b22
        Iw[j, 0, 1], Iw[j, 1, 0] = v01, v01
        Iw[j, 0, 2], Iw[j, 2, 0] = v02, v02
        Iw[j, 1, 2], Iw[j, 2, 1] = v12, v12
        a00, a01, a02, a10, a11, a12, a20, a21, a22 = b00, b01, b02, b10, b11, b12, b20, b21, b22
    place_point(R[e - 1], pr[e - 1], eep[m], bp[m], per[m], p_ee[m])
    for b in range(3):
        f0, f1, f2 = eer[m, 0, b], eer[m, 1, b], eer[m, 2, b]
        R_ee[m, 0, b] = a00 * f0 + a01 * f1 + a02 * f2
        R_ee[m, 1, b] = a10 * f0 + a11 * f1 + a12 * f2
        R_ee[m, 2, b] = a20 * f0 + a21 * f1 + a22 * f2


@kernel
def arm_jacobian(P, W, m):
    """End-effector Jacobian J_m (6, n_m) of arm m, world axes, positions relative to the base point.

    Columns [z_j × (p_EE − p_j); z_j] (revolute) or [z_j; 0] (prismatic): the twist [v; ω] of the
    end-effector frame's origin per unit joint rate.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): W.z, W.p_rel and W.p_ee_rel of `arm_kinematics` read;
            W.J[m, :, :n_m] written.
        m: the arm index, 0-based.
    """
    dof, jt = P.dof, P.joint_type
    p, z, p_ee, J = W.p_rel, W.z, W.p_ee_rel, W.J
    o, e = dof[m], dof[m + 1]
    e0, e1, e2 = p_ee[m, 0], p_ee[m, 1], p_ee[m, 2]
    for j in range(o, e):
        z0, z1, z2 = z[j, 0], z[j, 1], z[j, 2]
        col = j - o
        if jt[j] == PRISMATIC:
            J[m, 0, col], J[m, 1, col], J[m, 2, col] = z0, z1, z2
            J[m, 3, col], J[m, 4, col], J[m, 5, col] = 0.0, 0.0, 0.0
            continue
        d0, d1, d2 = e0 - p[j, 0], e1 - p[j, 1], e2 - p[j, 2]
        J[m, 0, col] = z1 * d2 - z2 * d1
        J[m, 1, col] = z2 * d0 - z0 * d2
        J[m, 2, col] = z0 * d1 - z1 * d0
        J[m, 3, col] = z0
        J[m, 4, col] = z1
        J[m, 5, col] = z2


# ------------------------------------------------------------------------------------------------
# Stage 2: Gibbs–Appell arm terms
# ------------------------------------------------------------------------------------------------

@kernel
def arm_bias(P, W, m, qd):
    """h_m = −Re_m (bias forces, eq. 10) and J̇_mθ̇_m of arm m, from one forward and one backward recursion.

    The forward recursion at θ̈ = 0 with base acceleration −g (eq. 9), the backward one of ∂S/∂θ̈
    (`gibbs_gradient_of_motion`): ω_i = ω_{i−1} + z_i θ̇_i, ω̇_i = ω̇_{i−1} + ω_{i−1} × z_i θ̇_i,
    a_{i+1} = a_i + ω̇_i × d + ω_i × (ω_i × d); F_j = m_j a_cj + F_{j+1},
    N_j = (c_j − p_j) × m_j a_cj + I_j ω̇_j + ω_j × I_j ω_j + N_{j+1} + (p_{j+1} − p_j) × F_{j+1},
    h_j = z_j · N_j. A prismatic joint j leaves ω, ω̇ and adds 2 ω_{j−1} × z_j θ̇_j to a_j
    (`coopsim.dynamics.kinematics.link_motion`); its h_j = z_j · F_j.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): arm m's kinematics (`arm_kinematics`) read. Written, world
            axes: W.w, W.dw, W.a in arm m's rows (rad/s, rad/s², m/s²: link motion at θ̈ = 0 with base
            acceleration −g), W.h and W.h_arm in arm m's rows (N·m, or N for a prismatic joint), and
            W.Jd_qd[m] ([m/s²; rad/s²], the end-effector's bias acceleration without −g).
        m: the arm index, 0-based.
        qd: (N,) rad/s or m/s, the stacked joint rates (arm m's rows read).
    """
    dof, g, lm, jt = P.dof, P.gravity, P.link_mass, P.joint_type
    p, z, cw, Iw, Ww, DW, Aw = W.p_rel, W.z, W.c_rel, W.I, W.w, W.dw, W.a
    h, h_arm, Jd_qd, p_ee = W.h, W.h_arm, W.Jd_qd, W.p_ee_rel
    o, e = dof[m], dof[m + 1]
    g0, g1, g2 = g[0], g[1], g[2]
    w0 = w1 = w2 = 0.0
    dw0 = dw1 = dw2 = 0.0
    a0, a1, a2 = -g0, -g1, -g2
    q0, q1, q2 = p[o, 0], p[o, 1], p[o, 2]
    for j in range(o, e):
        if j > o:
            n0, n1, n2 = p[j, 0], p[j, 1], p[j, 2]
            d0, d1, d2 = n0 - q0, n1 - q1, n2 - q2
            q0, q1, q2 = n0, n1, n2
            x0, x1, x2 = w1 * d2 - w2 * d1, w2 * d0 - w0 * d2, w0 * d1 - w1 * d0
            a0 += dw1 * d2 - dw2 * d1 + w1 * x2 - w2 * x1
            a1 += dw2 * d0 - dw0 * d2 + w2 * x0 - w0 * x2
            a2 += dw0 * d1 - dw1 * d0 + w0 * x1 - w1 * x0
        t = qd[j]
        zq0, zq1, zq2 = z[j, 0] * t, z[j, 1] * t, z[j, 2] * t
        if jt[j] == PRISMATIC:
            a0 += 2.0 * (w1 * zq2 - w2 * zq1)
            a1 += 2.0 * (w2 * zq0 - w0 * zq2)
            a2 += 2.0 * (w0 * zq1 - w1 * zq0)
        else:
            dw0 += w1 * zq2 - w2 * zq1
            dw1 += w2 * zq0 - w0 * zq2
            dw2 += w0 * zq1 - w1 * zq0
            w0 += zq0
            w1 += zq1
            w2 += zq2
        Ww[j, 0], Ww[j, 1], Ww[j, 2] = w0, w1, w2
        DW[j, 0], DW[j, 1], DW[j, 2] = dw0, dw1, dw2
        Aw[j, 0], Aw[j, 1], Aw[j, 2] = a0, a1, a2
    # end-effector bias acceleration J̇θ̇ (the base's −g removed)
    r0, r1, r2 = p_ee[m, 0] - q0, p_ee[m, 1] - q1, p_ee[m, 2] - q2
    x0, x1, x2 = w1 * r2 - w2 * r1, w2 * r0 - w0 * r2, w0 * r1 - w1 * r0
    Jd_qd[m, 0] = a0 + dw1 * r2 - dw2 * r1 + w1 * x2 - w2 * x1 + g0
    Jd_qd[m, 1] = a1 + dw2 * r0 - dw0 * r2 + w2 * x0 - w0 * x2 + g1
    Jd_qd[m, 2] = a2 + dw0 * r1 - dw1 * r0 + w0 * x1 - w1 * x0 + g2
    Jd_qd[m, 3], Jd_qd[m, 4], Jd_qd[m, 5] = dw0, dw1, dw2
    # backward recursion (p_{j+1} carried in q0..q2)
    F0 = F1 = F2 = 0.0
    N0 = N1 = N2 = 0.0
    for j in range(e - 1, o - 1, -1):
        pj0, pj1, pj2 = p[j, 0], p[j, 1], p[j, 2]
        if j < e - 1:  # move N_{j+1} from p_{j+1} to p_j
            d0, d1, d2 = q0 - pj0, q1 - pj1, q2 - pj2
            N0 += d1 * F2 - d2 * F1
            N1 += d2 * F0 - d0 * F2
            N2 += d0 * F1 - d1 * F0
        q0, q1, q2 = pj0, pj1, pj2
        w0, w1, w2 = Ww[j, 0], Ww[j, 1], Ww[j, 2]
        dw0, dw1, dw2 = DW[j, 0], DW[j, 1], DW[j, 2]
        r0, r1, r2 = cw[j, 0] - pj0, cw[j, 1] - pj1, cw[j, 2] - pj2
        x0, x1, x2 = w1 * r2 - w2 * r1, w2 * r0 - w0 * r2, w0 * r1 - w1 * r0
        mj = lm[j]
        ma0 = mj * (Aw[j, 0] + dw1 * r2 - dw2 * r1 + w1 * x2 - w2 * x1)
        ma1 = mj * (Aw[j, 1] + dw2 * r0 - dw0 * r2 + w2 * x0 - w0 * x2)
        ma2 = mj * (Aw[j, 2] + dw0 * r1 - dw1 * r0 + w0 * x1 - w1 * x0)
        i00, i01, i02 = Iw[j, 0, 0], Iw[j, 0, 1], Iw[j, 0, 2]
        i10, i11, i12 = Iw[j, 1, 0], Iw[j, 1, 1], Iw[j, 1, 2]
        i20, i21, i22 = Iw[j, 2, 0], Iw[j, 2, 1], Iw[j, 2, 2]
        Iw0 = i00 * w0 + i01 * w1 + i02 * w2
        Iw1 = i10 * w0 + i11 * w1 + i12 * w2
        Iw2 = i20 * w0 + i21 * w1 + i22 * w2
        N0 += r1 * ma2 - r2 * ma1 + i00 * dw0 + i01 * dw1 + i02 * dw2 + w1 * Iw2 - w2 * Iw1
        N1 += r2 * ma0 - r0 * ma2 + i10 * dw0 + i11 * dw1 + i12 * dw2 + w2 * Iw0 - w0 * Iw2
        N2 += r0 * ma1 - r1 * ma0 + i20 * dw0 + i21 * dw1 + i22 * dw2 + w0 * Iw1 - w1 * Iw0
        F0 += ma0
        F1 += ma1
        F2 += ma2
        if jt[j] == PRISMATIC:
            hj = z[j, 0] * F0 + z[j, 1] * F1 + z[j, 2] * F2
        else:
            hj = z[j, 0] * N0 + z[j, 1] * N1 + z[j, 2] * N2
        h_arm[j] = hj
        h[j] = hj


@kernel
def arm_mass_matrix(P, W, m):
    """I_m (n_m, n_m) of arm m by the composite-rigid-body recursion (module docstring) into W.Mb.

    Positions are taken relative to the arm's base point; the block goes into W.Mb rows dof[m]:dof[m+1].
    A unit θ̈_l of a prismatic joint l moves the composite C_l by z_l: force f = m_C z_l, moment (base
    point) n = h_C × z_l; a prismatic row j takes I_m[j, l] = z_j · f.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): arm m's kinematics (`arm_kinematics`) read; W.Mb rows
            dof[m]:dof[m+1], columns 0:n_m written (kg·m², kg·m or kg by the joints' types).
        m: the arm index, 0-based.
    """
    dof, lm, jt = P.dof, P.link_mass, P.joint_type
    cw, Iw, z, p, Mb = W.c_rel, W.I, W.z, W.p_rel, W.Mb
    o, e = dof[m], dof[m + 1]
    mc = 0.0
    hc0 = hc1 = hc2 = 0.0
    c00 = c01 = c02 = c11 = c12 = c22 = 0.0     # I_C (symmetric)
    for l in range(e - 1, o - 1, -1):
        mi = lm[l]
        c0, c1, c2 = cw[l, 0], cw[l, 1], cw[l, 2]
        cc = c0 * c0 + c1 * c1 + c2 * c2
        c00 += Iw[l, 0, 0] + mi * (cc - c0 * c0)
        c11 += Iw[l, 1, 1] + mi * (cc - c1 * c1)
        c22 += Iw[l, 2, 2] + mi * (cc - c2 * c2)
        c01 += Iw[l, 0, 1] - mi * c0 * c1
        c02 += Iw[l, 0, 2] - mi * c0 * c2
        c12 += Iw[l, 1, 2] - mi * c1 * c2
        mc += mi
        hc0 += mi * c0
        hc1 += mi * c1
        hc2 += mi * c2
        z0, z1, z2 = z[l, 0], z[l, 1], z[l, 2]
        p0, p1, p2 = p[l, 0], p[l, 1], p[l, 2]
        if jt[l] == PRISMATIC:
            f0, f1, f2 = mc * z0, mc * z1, mc * z2
            n0, n1, n2 = hc1 * z2 - hc2 * z1, hc2 * z0 - hc0 * z2, hc0 * z1 - hc1 * z0
        else:
            u0, u1, u2 = hc0 - mc * p0, hc1 - mc * p1, hc2 - mc * p2
            f0, f1, f2 = z1 * u2 - z2 * u1, z2 * u0 - z0 * u2, z0 * u1 - z1 * u0
            v0, v1, v2 = z1 * p2 - z2 * p1, z2 * p0 - z0 * p2, z0 * p1 - z1 * p0
            n0 = c00 * z0 + c01 * z1 + c02 * z2 - (hc1 * v2 - hc2 * v1)
            n1 = c01 * z0 + c11 * z1 + c12 * z2 - (hc2 * v0 - hc0 * v2)
            n2 = c02 * z0 + c12 * z1 + c22 * z2 - (hc0 * v1 - hc1 * v0)
        for j in range(o, l + 1):
            if jt[j] == PRISMATIC:
                v = z[j, 0] * f0 + z[j, 1] * f1 + z[j, 2] * f2
            else:
                q0, q1, q2 = p[j, 0], p[j, 1], p[j, 2]
                m0 = n0 - (q1 * f2 - q2 * f1)
                m1 = n1 - (q2 * f0 - q0 * f2)
                m2 = n2 - (q0 * f1 - q1 * f0)
                v = z[j, 0] * m0 + z[j, 1] * m1 + z[j, 2] * m2
            Mb[j, l - o] = v
            Mb[l, j - o] = v


# ------------------------------------------------------------------------------------------------
# Stage 3: object and grasps
# ------------------------------------------------------------------------------------------------

@kernel
def object_pose(P, W):
    """The object carried by arm c (eqs. 11–13): its pose, the grasp offsets and the object Jacobian.

    Pose (p_C, R_o = R_EE,c R_grasp,cᵀ, K_o = R_o K R_oᵀ), offsets s_m = p_C − grasp point m (r, 3) and
    the object Jacobian J_o = W_c⁻ᵀ J_c (6, n_c), from the current kinematics.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): the carrier's kinematics and Jacobian (`arm_kinematics`,
            `arm_jacobian`) read. Written: W.p_C (3,) m, world; W.R_o (3, 3) world ← object frame;
            W.K_o (3, 3) kg·m², about C, world axes; W.s (r, 3) m, world axes; W.J_o[:, :n_c] ([v_C; ω]
            per unit joint rate of the carrier).
    """
    dof, c, gp, gr, oi = P.dof, P.carrier, P.grasp_pos, P.grasp_rot, P.obj_inertia
    R_ee, p_ee, R_o, p_C, K_o, s, J, J_o = W.R_ee, W.p_ee, W.R_o, W.p_C, W.K_o, W.s, W.J, W.J_o
    n = dof[c + 1] - dof[c]
    for a in range(3):
        for b in range(3):
            R_o[a, b] = R_ee[c, a, 0] * gr[c, b, 0] + R_ee[c, a, 1] * gr[c, b, 1] + R_ee[c, a, 2] * gr[c, b, 2]
    o00, o01, o02 = R_o[0, 0], R_o[0, 1], R_o[0, 2]
    o10, o11, o12 = R_o[1, 0], R_o[1, 1], R_o[1, 2]
    o20, o21, o22 = R_o[2, 0], R_o[2, 1], R_o[2, 2]
    for m in range(len(dof) - 1):
        g0, g1, g2 = gp[m, 0], gp[m, 1], gp[m, 2]
        s[m, 0] = -(o00 * g0 + o01 * g1 + o02 * g2)
        s[m, 1] = -(o10 * g0 + o11 * g1 + o12 * g2)
        s[m, 2] = -(o20 * g0 + o21 * g1 + o22 * g2)
    s0, s1, s2 = s[c, 0], s[c, 1], s[c, 2]
    p_C[0], p_C[1], p_C[2] = p_ee[c, 0] + s0, p_ee[c, 1] + s1, p_ee[c, 2] + s2
    # K_o = R_o K R_oᵀ (symmetric)
    i00, i01, i02 = oi[0, 0], oi[0, 1], oi[0, 2]
    i10, i11, i12 = oi[1, 0], oi[1, 1], oi[1, 2]
    i20, i21, i22 = oi[2, 0], oi[2, 1], oi[2, 2]
    m00 = o00 * i00 + o01 * i10 + o02 * i20
    m01 = o00 * i01 + o01 * i11 + o02 * i21
    m02 = o00 * i02 + o01 * i12 + o02 * i22
    m10 = o10 * i00 + o11 * i10 + o12 * i20
    m11 = o10 * i01 + o11 * i11 + o12 * i21
    m12 = o10 * i02 + o11 * i12 + o12 * i22
    m20 = o20 * i00 + o21 * i10 + o22 * i20
    m21 = o20 * i01 + o21 * i11 + o22 * i21
    m22 = o20 * i02 + o21 * i12 + o22 * i22
    v01 = m00 * o10 + m01 * o11 + m02 * o12
    v02 = m00 * o20 + m01 * o21 + m02 * o22
    v12 = m10 * o20 + m11 * o21 + m12 * o22
    K_o[0, 0] = m00 * o00 + m01 * o01 + m02 * o02
    K_o[1, 1] = m10 * o10 + m11 * o11 + m12 * o12
    K_o[2, 2] = m20 * o20 + m21 * o21 + m22 * o22
    K_o[0, 1], K_o[1, 0] = v01, v01
    K_o[0, 2], K_o[2, 0] = v02, v02
    K_o[1, 2], K_o[2, 1] = v12, v12
    for j in range(n):
        jw0, jw1, jw2 = J[c, 3, j], J[c, 4, j], J[c, 5, j]
        J_o[0, j] = J[c, 0, j] - (s1 * jw2 - s2 * jw1)
        J_o[1, j] = J[c, 1, j] - (s2 * jw0 - s0 * jw2)
        J_o[2, j] = J[c, 2, j] - (s0 * jw1 - s1 * jw0)
        J_o[3, j], J_o[4, j], J_o[5, j] = jw0, jw1, jw2


@kernel
def object_dynamics(P, W, qd):
    """Object twist, J̇_oθ̇_c, and the object's inertia joined to the carrier block (eqs. 17–19).

    Object twist v_o = J_oθ̇_c, J̇_oθ̇_c = W_c⁻ᵀ J̇_cθ̇_c + [ω × (ω × s_c); 0], and the object's inertia
    joined to the carrier block: 𝐈_cc += J_oᵀ M_o J_o, h_c += J_oᵀ (M_o J̇_oθ̇_c + b_o),
    b_o = [−m_o g; ω × K_o ω] (W.Y_bias holds M_o J̇_oθ̇_c + b_o). Needs `object_pose` and the arm terms.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): `object_pose`'s terms and the carrier's W.Jd_qd read.
            Written, world axes: W.v_o (6,) [v_C; ω] m/s, rad/s; W.Jd_o_qd (6,) m/s², rad/s²; W.Y_bias (6,)
            N, N·m. Added to (once per evaluation, after `arm_bias` and `arm_mass_matrix`): W.h and W.Mb in
            the carrier's rows.
        qd: (N,) rad/s or m/s, the stacked joint rates (the carrier's rows read).
    """
    dof, c, mo, g = P.dof, P.carrier, P.obj_mass, P.gravity
    s, J_o, v_o, Jd_qd, Jd_o_qd, K, Y, h, Mb = W.s, W.J_o, W.v_o, W.Jd_qd, W.Jd_o_qd, W.K_o, W.Y_bias, W.h, W.Mb
    o = dof[c]
    n = dof[c + 1] - o
    s0, s1, s2 = s[c, 0], s[c, 1], s[c, 2]
    for a in range(6):
        v = 0.0
        for j in range(n):
            v += J_o[a, j] * qd[o + j]
        v_o[a] = v
    w0, w1, w2 = v_o[3], v_o[4], v_o[5]
    x0, x1, x2 = w1 * s2 - w2 * s1, w2 * s0 - w0 * s2, w0 * s1 - w1 * s0
    j0, j1, j2, j3, j4, j5 = Jd_qd[c, 0], Jd_qd[c, 1], Jd_qd[c, 2], Jd_qd[c, 3], Jd_qd[c, 4], Jd_qd[c, 5]
    ad0 = j0 - (s1 * j5 - s2 * j4) + w1 * x2 - w2 * x1
    ad1 = j1 - (s2 * j3 - s0 * j5) + w2 * x0 - w0 * x2
    ad2 = j2 - (s0 * j4 - s1 * j3) + w0 * x1 - w1 * x0
    Jd_o_qd[0], Jd_o_qd[1], Jd_o_qd[2] = ad0, ad1, ad2
    Jd_o_qd[3], Jd_o_qd[4], Jd_o_qd[5] = j3, j4, j5
    k00, k01, k02 = K[0, 0], K[0, 1], K[0, 2]
    k10, k11, k12 = K[1, 0], K[1, 1], K[1, 2]
    k20, k21, k22 = K[2, 0], K[2, 1], K[2, 2]
    Kw0 = k00 * w0 + k01 * w1 + k02 * w2
    Kw1 = k10 * w0 + k11 * w1 + k12 * w2
    Kw2 = k20 * w0 + k21 * w1 + k22 * w2
    Y[0] = mo * (ad0 - g[0])
    Y[1] = mo * (ad1 - g[1])
    Y[2] = mo * (ad2 - g[2])
    Y[3] = k00 * j3 + k01 * j4 + k02 * j5 + (w1 * Kw2 - w2 * Kw1)
    Y[4] = k10 * j3 + k11 * j4 + k12 * j5 + (w2 * Kw0 - w0 * Kw2)
    Y[5] = k20 * j3 + k21 * j4 + k22 * j5 + (w0 * Kw1 - w1 * Kw0)
    for i in range(n):
        hv = 0.0
        for a in range(6):
            hv += J_o[a, i] * Y[a]
        h[o + i] += hv
        e0, e1, e2, e3, e4, e5 = J_o[0, i], J_o[1, i], J_o[2, i], J_o[3, i], J_o[4, i], J_o[5, i]
        for l in range(i, n):
            f3, f4, f5 = J_o[3, l], J_o[4, l], J_o[5, l]
            v = (mo * (e0 * J_o[0, l] + e1 * J_o[1, l] + e2 * J_o[2, l])
                 + e3 * (k00 * f3 + k01 * f4 + k02 * f5) + e4 * (k10 * f3 + k11 * f4 + k12 * f5)
                 + e5 * (k20 * f3 + k21 * f4 + k22 * f5))
            Mb[o + i, l] += v
            if l != i:
                Mb[o + l, i] += v


# ------------------------------------------------------------------------------------------------
# Stage 4: closed chain
# ------------------------------------------------------------------------------------------------

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
            W.Lb_inv, W.X, W.x0, W.b, W.res, W.dF, W.rank, W.cond, and the buffers of the `schur` or dense
            solve.
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
        i0, i1 = 0, K
        if m != c:
            g = m - 1 if m > c else m
            i0, i1 = g * k, g * k + k
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
    for it in range(2):
        # θ̈ = L⁻ᵀ(z − Y F), block by block
        for m in range(r):
            o, e = dof[m], dof[m + 1]
            i0, i1 = 0, K
            if m != c:
                g = m - 1 if m > c else m
                i0, i1 = g * k, g * k + k
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

    Every intermediate term goes into W. `chain_terms`, `baumgarte_rhs` and `chain_solve`, with the
    stages of the first called from here directly: every level of calls takes references to its array
    arguments that numba cannot prune (atomic updates), and the Baumgarte kernel is only entered when
    selected. The array arguments are borrowed at once (`structs.borrow`): no reference to them is held
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
        arm_bias(P, W, m, qd)
        arm_mass_matrix(P, W, m)
    object_pose(P, W)
    object_dynamics(P, W, qd)
    constraint_jacobian(P, W)
    constraint_bias(P, W)
    if P.stabilization == STAB_BAUMGARTE:
        baumgarte_rhs(P, W, qd, stab)
    else:
        for i in range(len(stab)):
            stab[i] = 0.0
    return chain_solve(P, W, tau, stab)
