"""Compiled inverse kinematics of one arm (as `coopsim.inverse.trajectory.arm_ik` and `arm_rates`): Newton
steps Δθ = −(S J)⁻¹ S e(θ) on the end-effector pose error e = [p_EE(θ) − p; log(R_EE(θ) Rᵀ)] in the rows
S (k × 6, k = n_m), then the differential kinematics S J θ̇ = S v_EE, S J θ̈ = S (a_EE − J̇θ̇).
The target position p is given relative to the arm's base point and compared with the end-effector's
position relative to it (W.p_ee_rel), as every lever arm of the dynamics is: no world position enters
the error (a scene moved 100 km from the origin solves to the same angles, bit for bit).
"""

from __future__ import annotations

import numpy as np

from coopsim.compiled.gibbs_appell import arm_bias
from coopsim.compiled.kinematics import arm_jacobian, arm_kinematics
from coopsim.compiled.linalg import lu_solve, singular_ratio
from coopsim.compiled.manifold import max_abs
from coopsim.compiled.spatial import matmul3_T, rot_log
from coopsim.compiled.toolchain.jit import entry, kernel

SOLVED, SINGULAR, NOT_CONVERGED = 0, 1, 2


@kernel
def pose_error(P, W, m, p, R, e):
    """e ← the end-effector pose error [p_EE − p; log(R_EE Rᵀ)] of arm m from the current kinematics.

    p_EE and the target p are both relative to the arm's base point (W.p_ee_rel), so no world position
    enters the error.

    Args:
        P: the compiled model (PackedModel StructRef, read only).
        W: the workspace (Workspace StructRef): reads W.p_ee_rel[m] and W.R_ee[m] of the current
            kinematics (`arm_kinematics`); W.m3[3] and W.v3 are overwritten as scratch.
        m: arm index, 0-based.
        p: (3,) m, target position relative to the arm's base point, world axes.
        R: (3, 3) target orientation of the end-effector frame, world axes.
        e: (6,) written: [position error m; rotation vector rad], world axes.
    """
    E = W.m3[3]
    for a in range(3):
        e[a] = W.p_ee_rel[m, a] - p[a]
    matmul3_T(W.R_ee[m], R, E)
    rot_log(E, W.v3)
    e[3], e[4], e[5] = W.v3[0], W.v3[1], W.v3[2]


@kernel
def rows_jacobian(P, W, m, S):
    """S J_m of the current kinematics: the end-effector Jacobian of arm m in the rows S.

    Args:
        P: the compiled model (PackedModel StructRef, read only).
        W: the workspace (Workspace StructRef): reads W.J[m] (`arm_jacobian`).
        m: arm index, 0-based.
        S: (k, 6) row selector of the pose rows.

    Returns:
        np.ndarray: (k, n_m) S J_m (a new array): maps arm m's θ̇ (rad/s or m/s) to the rows S of its
        end-effector twist [v; ω] (m/s, rad/s), world axes.
    """
    n = P.dof[m + 1] - P.dof[m]
    SJ = np.zeros((S.shape[0], n))
    for i in range(S.shape[0]):
        for j in range(n):
            v = 0.0
            for a in range(6):
                v += S[i, a] * W.J[m, a, j]
            SJ[i, j] = v
    return SJ


@kernel
def rows_of(S, v, out):
    """out ← S v for the row selector S and a 6-vector v.

    Args:
        S: (k, 6) row selector.
        v: (6,) a twist, acceleration, pose error or wrench ([linear; angular]).
        out: (k,) written: S v, in the units of v.
    """
    for i in range(S.shape[0]):
        x = 0.0
        for a in range(6):
            x += S[i, a] * v[a]
        out[i] = x


@entry
def arm_solve(P, W, m, S, p, R, twist, acc, q, tol, max_iter, sing_tol, qd, qdd, info):
    """`solve` called from Python (arguments and result as there).

    Args:
        P: the compiled model (PackedModel StructRef, read only).
        W: the workspace (Workspace StructRef), as `solve`.
        m: arm index, 0-based.
        S: (k, 6) row selector of the pose rows solved, k = n_m.
        p: (3,) m, target position relative to the arm's base point, world axes.
        R: (3, 3) target orientation of the end-effector frame, world axes.
        twist: (6,) the end-effector twist [v; ω], m/s and rad/s, world axes.
        acc: (6,) the end-effector acceleration [a; ω̇], m/s² and rad/s², world axes.
        q: (N,) rad or m, the stacked joint coordinates, as `solve`.
        tol: Newton tolerance on max |S e| (m or rad).
        max_iter: cap on the Newton iterations.
        sing_tol: σ_min/σ_max of S J below which the solve stops as SINGULAR.
        qd, qdd: (N,) rad/s (m/s), rad/s² (m/s²), as `solve`.
        info: (3,) written, as `solve`.

    Returns:
        int: SOLVED, SINGULAR or NOT_CONVERGED.
    """
    return solve(P, W, m, S, p, R, twist, acc, q, tol, max_iter, sing_tol, qd, qdd, info)


@kernel
def solve(P, W, m, S, p, R, twist, acc, q, tol, max_iter, sing_tol, qd, qdd, info):
    """Joint angles of arm m putting the end-effector frame at (p, R) in the rows S, then θ̇ and θ̈.

    Newton steps Δθ = −(S J)⁻¹ S e(θ) on the pose error e (`pose_error`) until max |S e| ≤ tol, then the
    differential kinematics S J θ̇ = S v_EE and S J θ̈ = S (a_EE − J̇θ̇) for the end-effector twist and
    acceleration (module docstring). S J must be square (k = n_m).

    Args:
        P: the compiled model (PackedModel StructRef, read only).
        W: the workspace (Workspace StructRef): arm m's kinematics and W.J[m] are overwritten, and when
            SOLVED its bias terms too (W.Jd_qd[m], its rows of W.h, W.h_arm, W.w, W.dw, W.a).
        m: arm index, 0-based.
        S: (k, 6) row selector of the pose rows solved, k = n_m.
        p: (3,) m, target position relative to the arm's base point, world axes.
        R: (3, 3) target orientation of the end-effector frame, world axes.
        twist: (6,) the end-effector twist [v; ω], m/s and rad/s, world axes.
        acc: (6,) the end-effector acceleration [a; ω̇], m/s² and rad/s², world axes.
        q: (N,) rad or m, the stacked joint coordinates; arm m's rows hold the guess and are
            overwritten with the Newton iterates (the solution when SOLVED).
        tol: Newton tolerance on max |S e| (m or rad).
        max_iter: cap on the Newton iterations.
        sing_tol: σ_min/σ_max of S J below which the solve stops as SINGULAR.
        qd, qdd: (N,) rad/s (m/s), rad/s² (m/s²): arm m's rows written with θ̇ and θ̈ when SOLVED.
        info: (3,) written: info[0] σ_min/σ_max of S J at the failure (SINGULAR) or the max |S e| left
            (NOT_CONVERGED, at the iterate before the last step); info[1] det S J and info[2] max |full
            pose error| over all six rows (m or rad) at the solution (SOLVED).

    Returns:
        int: SOLVED, SINGULAR or NOT_CONVERGED.
    """
    o, n = P.dof[m], P.dof[m + 1] - P.dof[m]
    k = S.shape[0]
    e, Se, v = np.empty(6), np.empty(k), np.empty(n)
    status = NOT_CONVERGED
    for _ in range(max_iter):
        arm_kinematics(P, W, m, q)
        pose_error(P, W, m, p, R, e)
        rows_of(S, e, Se)
        if max_abs(Se) <= tol:
            status = SOLVED
            break
        arm_jacobian(P, W, m)
        SJ = rows_jacobian(P, W, m, S)
        ratio = singular_ratio(SJ, k, n)
        if ratio < sing_tol:
            info[0] = ratio
            return SINGULAR
        lu_solve(SJ, n, Se, v)
        for j in range(n):
            q[o + j] -= v[j]
    if status != SOLVED:
        info[0] = max_abs(Se)
        return status
    info[2] = max_abs(e)
    arm_jacobian(P, W, m)
    SJ = rows_jacobian(P, W, m, S)
    rows_of(S, twist, Se)
    info[1] = lu_solve(SJ, n, Se, v)
    for j in range(n):
        qd[o + j] = v[j]
    arm_bias(P, W, m, qd)
    rhs = np.empty(6)
    for a in range(6):
        rhs[a] = acc[a] - W.Jd_qd[m, a]
    rows_of(S, rhs, Se)
    lu_solve(SJ, n, Se, v)
    for j in range(n):
        qdd[o + j] = v[j]
    return SOLVED
