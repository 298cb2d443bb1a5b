"""Compiled stage 2 — the Gibbs–Appell terms of each arm: bias forces and mass matrix (paper eqs.
11–13; the reference is `coopsim.dynamics.gibbs_appell`).

One algorithmic difference, exact: the arm mass matrix I_m is formed by the composite-rigid-body
recursion (O(n²)) instead of the Gram matrix of the partial accelerations (O(n³)): with the composite
C_l = links l…n−1 (mass m_C, first moment h_C = Σ m_i c_i, inertia about the arm's base point I_C), a unit
θ̈_l needs the force f = z_l × (h_C − m_C p_l) and the moment (base point) n = I_C z_l − h_C × (z_l × p_l),
so I_m[j, l] = z_j · (n − p_j × f) for j ≤ l — the same entries ∂²S/∂θ̈_j∂θ̈_l.
Joints are revolute or prismatic (P.joint_type, the joint model of `coopsim.core.joints`): each kernel
branches on the type where a prismatic joint differs: its link motion gains z θ̈ + 2ω × z θ̇ in place of
an angular term, and its bias and mass-matrix rows are z · (force) instead of z · (moment).
As in the reference, every lever arm is formed from positions relative to the arm's base point
(W.p_rel, W.c_rel, W.p_ee_rel), never from world positions (W.p, W.c, W.p_ee, W.p_C are outputs).
"""

from __future__ import annotations

from coopsim.compiled.toolchain.jit import kernel
from coopsim.core.model import PRISMATIC


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
