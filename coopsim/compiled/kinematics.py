"""Compiled stage 1 — kinematics of each arm: joint frames, link and end-effector poses, the
end-effector Jacobian (paper eqs. 9–10; the reference is `coopsim.dynamics.kinematics`).

Evaluated over the flat arrays of a `PackedModel` into the buffers of a `Workspace` (world axes, SI).
Joints are revolute or prismatic (P.joint_type, the joint model of `coopsim.core.joints`): each kernel
branches on the type where a prismatic joint differs: its frame slides θ z along its axis instead of
turning, and its Jacobian column is [z; 0].
As in the reference, every lever arm is formed from positions relative to the arm's base point
(W.p_rel, W.c_rel, W.p_ee_rel), never from world positions (W.p, W.c, W.p_ee, W.p_C are outputs).
"""

from __future__ import annotations

import numpy as np

from coopsim.compiled.toolchain.jit import kernel
from coopsim.core.model import PRISMATIC


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
