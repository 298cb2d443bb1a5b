"""Compiled evaluation of many states: θ̈ (batches, run on threads from `api`, one workspace each: the
entries release the GIL), every reported quantity of a trajectory at its output samples (as the
reference `coopsim.forward.engines.ReferenceEngine.sample`), and the per-sample terms of the inverse dynamics (as
`coopsim.inverse.problem.inverse_problem`'s loop). Two entries only: each entry compiles the chain again.

Grasp wrenches (eqs. 4–6, 11): F_e^m = Sᵀ F_m for the arms m ≠ c, and the carrier's from the object's
Newton–Euler equation W_c F_e^c = M_o v̇_o + b_o − Σ_{m≠c} W_m F_e^m restricted to the rows S, with
W_m [f; n] = [f; n − s_m × f] and W_m⁻¹ = W(−s_m). Internal wrench (eq. 7, paper's W⁺): F_I^m = W_m F_e^m
− (1/r) Σ_j W_j F_e^j at C.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from coopsim.compiled.closed_chain import (OK, arm_terms, chain_dynamics, chain_forward, constraint_condition,
                                          loop_residual)
from coopsim.compiled.grasp import object_dynamics, object_pose
from coopsim.compiled.linalg import copy1, copy2, copy3
from coopsim.compiled.manifold import max_abs, project_state
from coopsim.compiled.spatial import rot_to_quat
from coopsim.compiled.structs import borrow
from coopsim.compiled.toolchain.jit import entry, kernel


class Samples(NamedTuple):
    """Output arrays for S samples (N joints, r arms), world axes, SI.

    Attributes:
        qdd: (S, N) θ̈, rad/s² or m/s².
        tau: (S, N) the joint torques τ, N·m (N for a prismatic joint): the input of `evaluate`.
        object_pos: (S, 3) m, the object's centre of mass C, world.
        object_quat: (S, 4) [w, x, y, z], the object frame's orientation (world ← object frame).
        object_twist: (S, 6) [v_C; ω], m/s and rad/s.
        object_acc: (S, 6) [v̇_C; ω̇], m/s² and rad/s².
        grasp_wrench: (S, r, 6) the grasp wrenches F_e^m [f; n], N and N·m, at the end-effectors (module
            docstring).
        internal_wrench: (S, r, 6) the internal wrenches F_I^m [f; n] at C, N and N·m (eq. 7).
        residual_pos: (S,) max |Φ|, m or rad.
        residual_vel: (S,) max |Λθ̇|, m/s or rad/s.
        cond: (S,) λ_max/λ_min of Λ𝐈⁻¹Λᵀ (inf when λ_min ≤ 0, 1 without constraint rows;
            `closed_chain.constraint_condition`).
        status: (S,) int, chain_forward's code (a projection's, `evaluate`).
    """

    qdd: np.ndarray
    tau: np.ndarray
    object_pos: np.ndarray
    object_quat: np.ndarray
    object_twist: np.ndarray
    object_acc: np.ndarray
    grasp_wrench: np.ndarray
    internal_wrench: np.ndarray
    residual_pos: np.ndarray
    residual_vel: np.ndarray
    cond: np.ndarray
    status: np.ndarray


def new_samples(S: int, N: int, r: int) -> Samples:
    """Zero-filled Samples for S samples of a model with N joints and r arms.

    Args:
        S: the number of samples.
        N: the number of joints of all arms.
        r: the number of arms.

    Returns:
        Samples: float64 arrays of the shapes its fields list (status int64).
    """
    z = np.zeros
    return Samples(z((S, N)), z((S, N)), z((S, 3)), z((S, 4)), z((S, 6)), z((S, 6)), z((S, r, 6)),
                   z((S, r, 6)), z(S), z(S), z(S), np.zeros(S, dtype=np.int64))


@kernel
def object_acceleration(P, W, qdd, out):
    """v̇_o (6,) = J_o θ̈_c + J̇_oθ̇_c.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): W.J_o and W.Jd_o_qd (`grasp.object_pose`,
            `grasp.object_dynamics`) read.
        qdd: (N,) θ̈, rad/s² or m/s² (the carrier's rows read).
        out: (6,) written: [v̇_C; ω̇], m/s² and rad/s², world axes.
    """
    dof, c, J_o, Jd_o_qd = P.dof, P.carrier, W.J_o, W.Jd_o_qd
    o, n = dof[c], dof[c + 1] - dof[c]
    for a in range(6):
        v = Jd_o_qd[a]
        for j in range(n):
            v += J_o[a, j] * qdd[o + j]
        out[a] = v


@kernel
def object_wrench(P, W, vd, out):
    """Y (6,) = M_o v̇_o + b_o = [m_o (v̇_C − g); K_o ω̇ + ω × K_o ω].

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): W.K_o and the object twist W.v_o read.
        vd: (6,) v̇_o = [v̇_C; ω̇], m/s² and rad/s², world axes.
        out: (6,) written: Y = [f; n] at C, N and N·m, world axes.
    """
    K, w, mo, g = W.K_o, W.v_o[3:], P.obj_mass, P.gravity
    for a in range(3):
        out[a] = mo * (vd[a] - g[a])
        out[3 + a] = K[a, 0] * vd[3] + K[a, 1] * vd[4] + K[a, 2] * vd[5]
    Kw0 = K[0, 0] * w[0] + K[0, 1] * w[1] + K[0, 2] * w[2]
    Kw1 = K[1, 0] * w[0] + K[1, 1] * w[1] + K[1, 2] * w[2]
    Kw2 = K[2, 0] * w[0] + K[2, 1] * w[1] + K[2, 2] * w[2]
    out[3] += w[1] * Kw2 - w[2] * Kw1
    out[4] += w[2] * Kw0 - w[0] * Kw2
    out[5] += w[0] * Kw1 - w[1] * Kw0


@kernel
def move_to_centre(s, F, out):
    """out (6,) ← W(s) F = [f; n − s × f].

    The wrench F = [f; n] at a point p moved to the point p + s (to C for s = s_m: eqs. 1–2).

    Args:
        s: (3,) m, world axes: the offset from the point of F to the new point (s_m = p_C − grasp point m).
        F: (6,) [f; n], N and N·m, world axes.
        out: (6,) written.
    """
    out[0], out[1], out[2] = F[0], F[1], F[2]
    out[3] = F[3] - (s[1] * F[2] - s[2] * F[1])
    out[4] = F[4] - (s[2] * F[0] - s[0] * F[2])
    out[5] = F[5] - (s[0] * F[1] - s[1] * F[0])


@kernel
def grasp_wrenches(P, W, Y, F_e, F_I):
    """F_e (r, 6) from the loop-closure wrenches W.F and the object wrench Y, and the internal wrenches F_I.

    See the module docstring (eqs. 4–7, 11).

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): W.F (`closed_chain.chain_solve`) and W.s read; W.vec6 scratch.
        Y: (6,) the object wrench M_o v̇_o + b_o at C (`object_wrench`), N and N·m, world axes;
            overwritten.
        F_e: (r, 6) written: the grasp wrenches [f; n] at the end-effectors, N and N·m, world axes.
        F_I: (r, 6) written: the internal wrenches [f; n] at C, N and N·m, world axes.
    """
    S = P.rows
    k = S.shape[0]
    c = P.carrier
    r = len(P.dof) - 1
    u = W.vec6
    g = 0
    for m in range(r):
        if m == c:
            continue
        for a in range(6):
            v = 0.0
            for i in range(k):
                v += S[i, a] * W.F[g * k + i]
            F_e[m, a] = v
        move_to_centre(W.s[m], F_e[m], u)
        for a in range(6):
            Y[a] -= u[a]
        g += 1
    for a in range(3):   # W(−s_c) Y
        u[a] = Y[a]
    sc = W.s[c]
    u[3] = Y[3] + (sc[1] * Y[2] - sc[2] * Y[1])
    u[4] = Y[4] + (sc[2] * Y[0] - sc[0] * Y[2])
    u[5] = Y[5] + (sc[0] * Y[1] - sc[1] * Y[0])
    for a in range(6):
        v = 0.0
        for i in range(k):
            sv = 0.0
            for b in range(6):
                sv += S[i, b] * u[b]
            v += S[i, a] * sv
        F_e[c, a] = v
    for m in range(r):
        move_to_centre(W.s[m], F_e[m], F_I[m])
    for a in range(6):
        mean = 0.0
        for m in range(r):
            mean += F_I[m, a]
        mean /= r
        for m in range(r):
            F_I[m, a] -= mean


@kernel
def reported(P, W, i, qd, out, Yw, phi_known):
    """Row i of `out` after an evaluation at rates qd: every reported quantity but θ̈, τ and the status.

    Object pose, twist and acceleration, grasp and internal wrenches, loop residuals (position,
    velocity) and cond(Λ𝐈⁻¹Λᵀ) (`closed_chain.constraint_condition`).

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef) after `closed_chain.chain_forward` at (θ, qd): read; W.phi
            (unless phi_known), W.A, W.A_f, W.perm, W.vec6, W.v3 and W.m3 overwritten.
        i: the sample's row.
        qd: (N,) rad/s or m/s, the stacked joint rates of the evaluation.
        out: the Samples: row i of object_pos, object_quat, object_twist, object_acc, grasp_wrench,
            internal_wrench, residual_pos, residual_vel and cond written.
        Yw: (6,) scratch (the object wrench).
        phi_known: whether W.phi already holds Φ(θ) (after a projection), else it is computed here.
    """
    N = P.dof[-1]
    K = W.Lam.shape[0]
    copy1(W.p_C, out.object_pos[i])
    rot_to_quat(W.R_o, out.object_quat[i])
    copy1(W.v_o, out.object_twist[i])
    object_acceleration(P, W, W.qdd, out.object_acc[i])
    object_wrench(P, W, out.object_acc[i], Yw)
    grasp_wrenches(P, W, Yw, out.grasp_wrench[i], out.internal_wrench[i])
    if not phi_known:
        loop_residual(P, W)
    out.residual_pos[i] = max_abs(W.phi)
    rv = 0.0
    for a in range(K):
        v = 0.0
        for j in range(N):
            v += W.Lam[a, j] * qd[j]
        rv = max(rv, abs(v))
    out.residual_vel[i] = rv
    out.cond[i] = constraint_condition(P, W)


@entry
def evaluate(P, W, Y, out, full, raw):
    """The closed chain at S states Y (S, 2N) = [θ; θ̇] with torques out.tau (S, N).

    θ̈ goes into out.qdd and the status codes into out.status; with `full`, every other field of `out`
    (Samples) too. A state flagged in raw is first projected onto the loop-closure manifold, in place,
    as the time loop projects an output (`manifold.project_state` to P.projection_tol: the same
    state), and evaluated on the projection's own kinematics (`closed_chain.chain_dynamics`: the
    kinematic terms are not computed twice); when its projection fails the row keeps zeros and its
    status is the projection's code.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef; scratch, overwritten).
        Y: (S, 2N) the states [θ; θ̇], rad or m and rad/s or m/s; the rows flagged in raw overwritten with
            their projections.
        out: the Samples (S rows): out.tau read (N·m, N for a prismatic joint); out.qdd and out.status
            written, and with `full` every other field.
        full: whether to fill the reported fields (`reported`).
        raw: (S,) int, 1 for a state to project first; or empty: none is.
    """
    N = P.dof[-1]
    stab = np.zeros(W.Lam.shape[0])
    Yw, step = np.empty(6), np.empty(N)
    Y, raw, o = borrow(Y), borrow(raw), borrowed_samples(out)
    for i in range(Y.shape[0]):
        projected = len(raw) > 0 and raw[i] != 0
        if projected:
            st = project_state(P, W, Y[i], P.projection_tol, P.projection_max_iter, step)
            if st != OK:
                o.status[i] = st
                continue
            st = chain_dynamics(P, W, Y[i, N:], o.tau[i], stab)
        else:
            st = chain_forward(P, W, Y[i, :N], Y[i, N:], o.tau[i], stab)
        o.status[i] = st
        copy1(W.qdd, o.qdd[i])
        if full:
            reported(P, W, i, Y[i, N:], o, Yw, projected)


@kernel
def borrowed_samples(out):
    """`out` (Samples) with every array borrowed (`structs.borrow`): rows indexed from it cost no
    reference count (the threads of a batch would otherwise contend on the shared arrays' counts).

    Args:
        out: the Samples; its arrays outlive the caller's use of the copy.

    Returns:
        Samples: the same arrays, borrowed.
    """
    return Samples(borrow(out.qdd), borrow(out.tau), borrow(out.object_pos), borrow(out.object_quat),
                   borrow(out.object_twist), borrow(out.object_acc), borrow(out.grasp_wrench),
                   borrow(out.internal_wrench), borrow(out.residual_pos), borrow(out.residual_vel),
                   borrow(out.cond), borrow(out.status))


class InverseTerms(NamedTuple):
    """Per-sample terms of the inverse dynamics (S samples, N joints, r arms, nmax joints per arm at most).

    World axes, SI.

    Attributes:
        tau_arms: (S, N) N·m (N for a prismatic joint), I_m θ̈_m + h_m per open arm (eq. 29, no object).
        J: (S, r, 6, nmax) EE Jacobians (columns 0:n_m of arm m).
        s: (S, r, 3) m, p_C − grasp points.
        p_C: (S, 3) m, the object's centre of mass, world.
        R_o: (S, 3, 3) world ← object frame.
        twist: (S, 6) [v_C; ω], m/s and rad/s.
        acc: (S, 6) [v̇_C; ω̇], m/s² and rad/s².
        Y: (S, 6) = M_o v̇_o + b_o at C, N and N·m.
    """

    tau_arms: np.ndarray
    J: np.ndarray
    s: np.ndarray
    p_C: np.ndarray
    R_o: np.ndarray
    twist: np.ndarray
    acc: np.ndarray
    Y: np.ndarray


def new_inverse_terms(S: int, N: int, r: int, nmax: int) -> InverseTerms:
    """Zero-filled InverseTerms for S samples of a model with N joints, r arms, nmax joints per arm at most.

    Args:
        S: the number of samples.
        N: the number of joints of all arms.
        r: the number of arms.
        nmax: the joints of the longest arm.

    Returns:
        InverseTerms: float64 arrays of the shapes its fields list.
    """
    z = np.zeros
    return InverseTerms(z((S, N)), z((S, r, 6, nmax)), z((S, r, 3)), z((S, 3)), z((S, 3, 3)), z((S, 6)),
                        z((S, 6)), z((S, 6)))


@entry
def inverse_terms(P, W, Q, QD, QDD, out):
    """Fill `out` (InverseTerms) at the states (Q, QD, QDD) (S, N).

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef; scratch, overwritten).
        Q: (S, N) rad or m, the stacked joint coordinates.
        QD: (S, N) rad/s or m/s, the stacked joint rates.
        QDD: (S, N) rad/s² or m/s², the stacked joint accelerations.
        out: the InverseTerms (S rows), every field written.
    """
    for i in range(Q.shape[0]):
        arm_terms(P, W, Q[i], QD[i])
        for m in range(len(P.dof) - 1):
            o, e = P.dof[m], P.dof[m + 1]
            for j in range(o, e):
                v = W.h_arm[j]
                for l in range(o, e):
                    v += W.Mb[j, l - o] * QDD[i, l]
                out.tau_arms[i, j] = v
        object_pose(P, W)
        object_dynamics(P, W, QD[i])
        copy3(W.J, out.J[i])
        copy2(W.s, out.s[i])
        copy1(W.p_C, out.p_C[i])
        copy2(W.R_o, out.R_o[i])
        copy1(W.v_o, out.twist[i])
        object_acceleration(P, W, QDD[i], out.acc[i])
        object_wrench(P, W, out.acc[i], out.Y[i])
