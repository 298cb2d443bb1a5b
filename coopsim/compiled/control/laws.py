"""The compiled control laws and their entries (the laws of `coopsim.control.laws`, as
`coopsim.control.controller.Controller.command` evaluates them in Python): joint PD with its
compensation, computed torque on the object with per-arm grasp feedback, the command clipped to the
motor lines of eq. 36, and `feedback`, which the time loop calls at every stage.
"""

from __future__ import annotations

import numpy as np

from coopsim.compiled.closed_chain import OK
from coopsim.compiled.control.distributions import inverse_torques, state_terms
from coopsim.compiled.control.record import COMP_BIAS, COMP_NONE, CONTROL_SINGULAR, JOINT_PD
from coopsim.compiled.control.references import joint_reference, object_reference
from coopsim.compiled.linalg import copy1, gauss_solve
from coopsim.compiled.spatial import matmul3, matmul3_T, rigid_point_acceleration, rot_log
from coopsim.compiled.toolchain.jit import entry, kernel


@kernel
def joint_pd(P, W, C, t, q, qd, u):
    """u ← Kp (θ_r − θ) + Kd (θ̇_r − θ̇) + τ_comp (module docstring).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef), overwritten when there is a compensation.
        C: the controller (PackedControl StructRef): C.q_ref, C.qd_ref written, and with a compensation
            C.tau_c and the inverse dynamics' scratch.
        t: s, the time since the start of the run.
        q: (N,) rad or m, θ.
        qd: (N,) rad/s or m/s, θ̇.
        u: (N,) written: the command, N·m (N on a prismatic joint); not meaningful on CONTROL_SINGULAR.

    Returns:
        int: OK or CONTROL_SINGULAR.
    """
    joint_reference(C, t)
    for j in range(len(u)):
        u[j] = C.kp[j] * (C.q_ref[j] - q[j]) + C.kd[j] * (C.qd_ref[j] - qd[j])
    if C.compensation == COMP_NONE:
        return OK
    state_terms(P, W, C, q, qd if C.compensation == COMP_BIAS else C.zero)
    st = inverse_torques(P, W, C, C.zero, 0.0, C.tau_c)
    for j in range(len(u)):
        u[j] = u[j] + C.tau_c[j]
    return st


@kernel
def object_errors(P, W, C, t):
    """The object's pose and twist errors against the prescribed motion at t, and the commanded acceleration.

    C.err = [p_r − p; log(R_r Rᵀ)], C.rate_err = v_r − v and C.a = a_r + Kd ė + Kp e; W holds the object
    terms of (θ, θ̇).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef): reads W.p_C, W.R_o and W.v_o.
        C: the controller (PackedControl StructRef): C.err [m; rad], C.rate_err [m/s; rad/s] and C.a
            [m/s²; rad/s²] (6,) written, world axes; C.p_r, C.v_r, C.a_r, C.R3, C.R3b, C.v3 scratch.
        t: s, the time since the start of the run.
    """
    object_reference(C, t, C.R3)
    for a in range(3):
        C.err[a] = C.p_r[a] - W.p_C[a]
    matmul3_T(C.R3, W.R_o, C.R3b)
    rot_log(C.R3b, C.v3)
    for a in range(3):
        C.err[3 + a] = C.v3[a]
    for a in range(6):
        C.rate_err[a] = C.v_r[a] - W.v_o[a]
        g = 0 if a < 3 else 1
        C.a[a] = C.a_r[a] + C.okd[g] * C.rate_err[a] + C.okp[g] * C.err[a]


@kernel
def arm_accelerations(P, W, C):
    """C.qdd ← each arm's θ̈_m from S J_m θ̈_m = S (a_EE,m − J̇_mθ̇_m) for the object acceleration C.a.

    a_EE,m = [a_C + ω̇ × ρ_m + ω × (ω × ρ_m); ω̇] at the object twist W.v_o (ρ_m = −s_m). S J_m must be
    square (k = n_m).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef): reads W.v_o, W.s, W.J and W.Jd_qd.
        C: the controller (PackedControl StructRef): reads C.a; C.qdd (N,) rad/s² written; C.v3, C.v6,
            C.xk and C.G scratch.

    Returns:
        bool: False when an arm's S J_m is singular (a zero pivot), else True.
    """
    S = P.rows
    k = S.shape[0]
    w, dw = W.v_o[3:], C.a[3:]
    for m in range(len(P.dof) - 1):
        o = P.dof[m]
        for a in range(3):
            C.v3[a] = -W.s[m, a]
        rigid_point_acceleration(C.a[:3], w, dw, C.v3, C.v6[:3])
        for a in range(3):
            C.v6[3 + a] = dw[a]
        for i in range(k):
            v = 0.0
            for a in range(6):
                v += S[i, a] * (C.v6[a] - W.Jd_qd[m, a])
            C.xk[i] = v
            for j in range(k):
                v = 0.0
                for a in range(6):
                    v += S[i, a] * W.J[m, a, j]
                C.G[i, j] = v
        if gauss_solve(C.G, k, C.xk) == 0.0:
            return False
        for j in range(k):
            C.qdd[o + j] = C.xk[j]
    return True


@kernel
def computed_torque(P, W, C, t, q, qd, u):
    """u ← the object-space computed torque (module docstring), with the grasp feedback added.

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef), overwritten with the terms of (θ, θ̇).
        C: the controller (PackedControl StructRef): C.err, C.rate_err, C.gerr written, and the
            inverse dynamics' scratch.
        t: s, the time since the start of the run.
        q: (N,) rad or m, θ.
        qd: (N,) rad/s or m/s, θ̇.
        u: (N,) written: the command, N·m (N on a prismatic joint); not meaningful on CONTROL_SINGULAR.

    Returns:
        int: OK or CONTROL_SINGULAR.
    """
    state_terms(P, W, C, q, qd)
    object_errors(P, W, C, t)
    if not arm_accelerations(P, W, C):
        return CONTROL_SINGULAR
    st = inverse_torques(P, W, C, C.qdd, C.squeeze, u)
    grasp_feedback(P, W, C, qd, u)
    return st


@kernel
def grasp_feedback(P, W, C, qd, u):
    """u += J_mᵀ Sᵀ S (Kp e_m + Kd ė_m) for every arm m (`coopsim.control.laws.grasp_errors`).

    e_m = [p_t − p_EE; log(R_t R_EEᵀ)] is the pose error of its end effector against where its grasp
    puts it on the object (p_t = p_C + R_o g_m, R_t = R_o G_m), ė_m = [v_C + ω × R_o g_m; ω] − J_m θ̇_m
    the twist error; gains gkp, gkd (2,) [linear, angular]. W holds the terms of (θ, θ̇).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef): reads W.R_o, W.p_C, W.v_o, W.p_ee, W.R_ee
            and W.J.
        C: the controller (PackedControl StructRef): C.gerr (r, 6) [m; rad] written, world axes; C.v3,
            C.v6, C.R3, C.R3b and C.xk scratch.
        qd: (N,) rad/s or m/s, θ̇.
        u: (N,) N·m (N on a prismatic joint), added to.
    """
    S = P.rows
    k = S.shape[0]
    w = W.v_o[3:]
    for m in range(len(P.dof) - 1):
        o, e = P.dof[m], P.dof[m + 1]
        for a in range(3):
            g = P.grasp_pos[m]
            C.v3[a] = W.R_o[a, 0] * g[0] + W.R_o[a, 1] * g[1] + W.R_o[a, 2] * g[2]
        matmul3(W.R_o, P.grasp_rot[m], C.R3)
        matmul3_T(C.R3, W.R_ee[m], C.R3b)
        for a in range(3):
            C.gerr[m, a] = (W.p_C[a] + C.v3[a]) - W.p_ee[m, a]
        rot_log(C.R3b, C.gerr[m, 3:])
        rho = C.v3
        C.v6[0] = W.v_o[0] + (w[1] * rho[2] - w[2] * rho[1])
        C.v6[1] = W.v_o[1] + (w[2] * rho[0] - w[0] * rho[2])
        C.v6[2] = W.v_o[2] + (w[0] * rho[1] - w[1] * rho[0])
        for a in range(3):
            C.v6[3 + a] = w[a]
        for a in range(6):
            v = C.v6[a]
            for j in range(o, e):
                v -= W.J[m, a, j - o] * qd[j]
            g = 0 if a < 3 else 1
            C.v6[a] = C.gkp[g] * C.gerr[m, a] + C.gkd[g] * v
        for i in range(k):
            v = 0.0
            for a in range(6):
                v += S[i, a] * C.v6[a]
            C.xk[i] = v
        for j in range(o, e):
            v = 0.0
            for i in range(k):
                sj = 0.0
                for a in range(6):
                    sj += S[i, a] * W.J[m, a, j - o]
                v += sj * C.xk[i]
            u[j] += v


@kernel
def command(P, W, C, t, q, qd, u):
    """u ← the law's command at (t, θ, θ̇) on the controller's model (P, W).

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef), overwritten.
        C: the controller (PackedControl StructRef): the law's references, errors and scratch written.
        t: s, the time since the start of the run.
        q: (N,) rad or m, θ.
        qd: (N,) rad/s or m/s, θ̇.
        u: (N,) written: the command, N·m (N on a prismatic joint); not meaningful on CONTROL_SINGULAR.

    Returns:
        int: OK or CONTROL_SINGULAR.
    """
    if C.law == JOINT_PD:
        return joint_pd(P, W, C, t, q, qd, u)
    return computed_torque(P, W, C, t, q, qd, u)


@kernel
def feedback(P, W, C, t, q, qd, tau):
    """τ ← the law's command plus the torque tables, clipped to the motor lines with `saturate`.

    The sum (C.raw) is clipped to τ_min(θ̇) ≤ τ ≤ τ_max(θ̇) of eq. 36 when C.saturate is set; the
    evaluation and its clipped joints are counted in C.count.

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef), overwritten.
        C: the controller (PackedControl StructRef): C.u, C.raw and the law's outputs written, C.count
            incremented.
        t: s, the time since the start of the run.
        q: (N,) rad or m, θ.
        qd: (N,) rad/s or m/s, θ̇.
        tau: (N,) N·m (N on a prismatic joint): holds the torque tables at t on entry, overwritten
            with the controller's torque (not meaningful on CONTROL_SINGULAR).

    Returns:
        int: OK or CONTROL_SINGULAR.
    """
    st = command(P, W, C, t, q, qd, C.u)
    C.count[0] += 1
    clipped = 0
    for j in range(len(tau)):
        raw = C.u[j] + tau[j]
        C.raw[j] = raw
        if C.saturate:
            drop = C.slope[j] * qd[j]
            v = min(max(raw, -C.stall[j] - drop), C.stall[j] - drop)
            clipped += v != raw
            raw = v
        tau[j] = raw
    if clipped:
        C.count[1] += 1
        C.count[2] += clipped
    return st


@entry
def commands(P, W, C, t, Y, tables, raw, tau, q_ref, qd_ref, err, rate_err, status):
    """The controller at S samples, with what the law sets at each (`feedback`).

    q_ref, qd_ref, err and rate_err hold what the law sets and nan for the other law's.

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef), overwritten.
        C: the controller (PackedControl StructRef): scratch, C.count incremented.
        t: (S,) s, the sample times since the start of the run.
        Y: (S, 2N) the states [θ; θ̇] (rad or m, rad/s or m/s).
        tables: (S, N) N·m, the torque tables at t.
        raw: (S, N) written: N·m, command plus tables before saturation.
        tau: (S, N) written: N·m, the torques (after saturation when C.saturate is set).
        q_ref, qd_ref: (S, N) written: the joint reference θ_r, θ̇_r (rad or m, per s).
        err, rate_err: (S, 6) written: the object pose and twist error [m; rad], [m/s; rad/s], world axes.
        status: (S,) int written: OK or CONTROL_SINGULAR per sample.
    """
    N = tables.shape[1]
    for i in range(len(t)):
        for j in range(N):
            tau[i, j] = tables[i, j]
        for a in range(6):
            C.err[a], C.rate_err[a] = np.nan, np.nan
        for j in range(N):
            C.q_ref[j], C.qd_ref[j] = np.nan, np.nan
        status[i] = feedback(P, W, C, t[i], Y[i, :N], Y[i, N:], tau[i])
        copy1(C.raw, raw[i])
        copy1(C.q_ref, q_ref[i])
        copy1(C.qd_ref, qd_ref[i])
        copy1(C.err, err[i])
        copy1(C.rate_err, rate_err[i])


@entry
def evaluate(P, W, C, t, y, tau):
    """τ ← the controller's torque at (t, y = [θ; θ̇]) for one state (`feedback`).

    For the MuJoCo twin's control callback.

    Args:
        P: the controller's compiled model (PackedModel StructRef, read only: the scene with the
            controller's object mass).
        W: the controller's workspace (Workspace StructRef), overwritten.
        C: the controller (PackedControl StructRef): scratch, C.count incremented.
        t: s, the time since the start of the run.
        y: (2N,) the state [θ; θ̇] (rad or m, rad/s or m/s).
        tau: (N,) N·m (N on a prismatic joint): the torque tables at t on entry, overwritten with the
            controller's torque.

    Returns:
        int: OK or CONTROL_SINGULAR.
    """
    N = len(tau)
    return feedback(P, W, C, t, y[:N], y[N:], tau)
