"""Compiled stage 3 — the object and its grasps: the object pose from the carrier arm's end effector,
and the object's inertia and bias joined to the carrier's terms (paper eqs. 17–19; the reference is
`coopsim.dynamics.grasp`).

As in the reference, every lever arm is formed from positions relative to the arm's base point
(W.p_rel, W.c_rel, W.p_ee_rel), never from world positions (W.p, W.c, W.p_ee, W.p_C are outputs).
"""

from __future__ import annotations

from coopsim.compiled.toolchain.jit import kernel


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
