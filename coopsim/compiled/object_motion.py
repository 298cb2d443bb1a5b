"""Compiled object-motion trajectories: closed-chain inverse kinematics of a prescribed object motion in
one pass over the samples (the reference is `coopsim.inverse.trajectory.object_motion_trajectory`).

Per sample t: the object's pose, twist and acceleration along the time law (a straight line and one
fixed-axis rotation per segment between waypoints at rest, or the B-spline path of
`coopsim.inverse.spline_path` with the time law once over the whole span, `object_state`), every arm's grasp target
(`grasp_target`), the reach check, then the arm's joint motion:
  * square arms (n_m joints for n_m rows): Newton from the previous sample advanced by θ̇h + θ̈h²/2, then
    the differential kinematics (`coopsim.compiled.ik.solve`); det S J must keep its sign between samples;
  * redundant arms (more joints than rows): the ODE θ̇ = z + Aᵀ(AAᵀ)⁻¹(S v_EE − Az), z = gain (θ_rest − θ),
    A = S J (least |θ̇ − z|), integrated over each segment between waypoints by DOP853 with the step
    control, starting step and dense output of scipy's `solve_ivp` (rtol = atol = 1e-12 in the reference;
    the tableau's kernels are `coopsim.compiled.integrate`'s); at every sample and segment end the
    interpolated θ is put on the grasp by least-norm Newton (`min_norm_solve`), and θ̇, θ̈ (its exact
    derivative) are evaluated there (`redundant_rates`).
A failure stops the pass with a code, the arm, the sample and the numbers its message quotes
(`coopsim.inverse.trajectory` words it as the reference does). Failures are found in the reference's
order: the redundant arms over all samples first, then the square arms sample by sample.
"""

from __future__ import annotations

import numpy as np

from coopsim.compiled.ik import NOT_CONVERGED as IK_NOT_CONVERGED
from coopsim.compiled.ik import SINGULAR as IK_SINGULAR
from coopsim.compiled.ik import pose_error, rows_jacobian, rows_of, solve
from coopsim.compiled.integrate import (MAX_FACTOR, MIN_FACTOR, SAFETY, dense_coefficients, dense_eval, error_norm,
                                        first_step, probe_step, rk_combine, stage_input)
from coopsim.compiled.kinematics import arm_jacobian, arm_kinematics
from coopsim.compiled.linalg import copy1, lu_solve, singular_ratio
from coopsim.compiled.manifold import max_abs
# the object's state along the motion (re-exported: `object_motion.Motion`, `buffers`, the law codes)
from coopsim.compiled.object_state import (CUBIC, LAWS, LINEAR, QUINTIC, SAMPLED, SMALL_ANGLE, Buffers,  # noqa: F401
                                           Motion, basis_derivatives, buffers, left_jacobian_coefficients,
                                           object_state, segment_law, spline_state, time_law)
from coopsim.compiled.spatial import matmul3
from coopsim.compiled.toolchain.jit import entry, kernel
from coopsim.core.model import PRISMATIC

OK, OUT_OF_REACH, SINGULAR, NOT_CONVERGED, OFF_PLANE, CROSSES, STEP_COLLAPSED = range(7)
ODE_STEPS = 2_000             # the redundancy ODE's step attempts in one pass, at least (then STEP_COLLAPSED;
                              # a path the optimiser meets takes 20-40)
ODE_STEPS_PER_SAMPLE = 50     # and at least this many per sample


@entry
def object_states(mo, t_out, B, pc, R, tw, ac):
    """The object's state at every time of t_out (`object_state`).

    Args:
        mo: the Motion.
        t_out: (n_s,) s, the times.
        B: the Buffers (`buffers`; scratch).
        pc: (n_s, 3) written: m, the centre of mass C relative to mo.origin, world axes.
        R: (n_s, 3, 3) written: world ← object.
        tw: (n_s, 6) written: [v_C; ω] m/s, rad/s, world axes.
        ac: (n_s, 6) written: [a_C; ω̇] m/s², rad/s², world axes.
    """
    for i in range(len(t_out)):
        object_state(mo, t_out[i], B)
        pc[i, :] = B.pc
        R[i, :, :] = B.Ro
        tw[i, :] = B.tw
        ac[i, :] = B.ac


@kernel
def grasp_target(P, mo, m, B):
    """Arm m's end-effector target for the object state in B: B.p, B.R, B.tw_m, B.ac_m.

    ρ = R_o ρ_m: p_EE relative to the arm's base point is ((origin − o_m) + p_C) + ρ, R_EE = R_o R_grasp,
    v_EE = v_C + ω × ρ, a_EE = a_C + ω̇ × ρ + ω × (ω × ρ) (`coopsim.inverse.trajectory.grasp_targets`).

    Args:
        P: the compiled model (PackedModel StructRef, read only): base points and grasps.
        mo: the Motion (its origin).
        m: arm index, 0-based.
        B: the Buffers: pc, Ro, tw, ac read (`object_state`); p (m), R, tw_m, ac_m written, world axes.
    """
    g, Ro, tw, ac = P.grasp_pos[m], B.Ro, B.tw, B.ac
    r0 = Ro[0, 0] * g[0] + Ro[0, 1] * g[1] + Ro[0, 2] * g[2]
    r1 = Ro[1, 0] * g[0] + Ro[1, 1] * g[1] + Ro[1, 2] * g[2]
    r2 = Ro[2, 0] * g[0] + Ro[2, 1] * g[1] + Ro[2, 2] * g[2]
    w0, w1, w2 = tw[3], tw[4], tw[5]
    d0, d1, d2 = ac[3], ac[4], ac[5]
    x0, x1, x2 = w1 * r2 - w2 * r1, w2 * r0 - w0 * r2, w0 * r1 - w1 * r0
    B.tw_m[0], B.tw_m[1], B.tw_m[2] = tw[0] + x0, tw[1] + x1, tw[2] + x2
    B.ac_m[0] = ac[0] + (d1 * r2 - d2 * r1) + (w1 * x2 - w2 * x1)
    B.ac_m[1] = ac[1] + (d2 * r0 - d0 * r2) + (w2 * x0 - w0 * x2)
    B.ac_m[2] = ac[2] + (d0 * r1 - d1 * r0) + (w0 * x1 - w1 * x0)
    for a in range(3):
        B.tw_m[3 + a], B.ac_m[3 + a] = tw[3 + a], ac[3 + a]
    rho = (r0, r1, r2)
    for a in range(3):
        B.p[a] = ((mo.origin[a] - P.base_pos[m, a]) + B.pc[a]) + rho[a]
    matmul3(Ro, P.grasp_rot[m], B.R)


@kernel
def distance(a, b):
    """|a − b| of two 3-vectors.

    Args:
        a, b: (3,) the points, in common axes.

    Returns:
        float: the distance, in their units.
    """
    d0, d1, d2 = a[0] - b[0], a[1] - b[1], a[2] - b[2]
    return np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


@kernel
def gram(A, k, n):
    """A Aᵀ (k × k, a new array) of A[:k, :n].

    Args:
        A: (k, n) the matrix.
        k, n: its rows and columns.

    Returns:
        np.ndarray: (k, k) A Aᵀ.
    """
    G = np.empty((k, k))
    for i in range(k):
        for j in range(k):
            v = 0.0
            for c in range(n):
                v += A[i, c] * A[j, c]
            G[i, j] = v
    return G


@kernel
def ee_jacobian_rate(P, W, m, qd, dJ):
    """dJ ← J̇_m (6, n_m), the time derivative of arm m's end-effector Jacobian at the rates qd.

    As `coopsim.dynamics.kinematics.point_jacobian_rate` at P = p_EE: revolute columns
    [ż_j × (p_EE − p_j) + z_j × (v_EE − v_j); ż_j], prismatic ones [ż_j; 0], ż_j = ω_{j−1} × z_j,
    v_j = v_{j−1} + ω_{j−1} × (p_j − p_{j−1}) (+ z_j θ̇_j for a prismatic joint j).

    Args:
        P: the compiled model (PackedModel StructRef, read only).
        W: the workspace: arm m's kinematics and W.J[m] (`arm_jacobian`) read.
        m: arm index, 0-based.
        qd: (N,) rad/s or m/s, the stacked joint rates (arm m's rows read).
        dJ: (6, n_m) written, world axes, per unit rate and time.
    """
    o, e = P.dof[m], P.dof[m + 1]
    p, z, J, pt = W.p_rel, W.z, W.J, W.p_ee_rel[m]
    vp = np.zeros(3)
    for a in range(3):
        for j in range(e - o):
            vp[a] += J[m, a, j] * qd[o + j]
    w0 = w1 = w2 = 0.0
    v0 = v1 = v2 = 0.0
    for j in range(o, e):
        c = j - o
        z0, z1, z2 = z[j, 0], z[j, 1], z[j, 2]
        if j > o:
            d0, d1, d2 = p[j, 0] - p[j - 1, 0], p[j, 1] - p[j - 1, 1], p[j, 2] - p[j - 1, 2]
            v0 += w1 * d2 - w2 * d1
            v1 += w2 * d0 - w0 * d2
            v2 += w0 * d1 - w1 * d0
        t = qd[j]
        dz0, dz1, dz2 = w1 * z2 - w2 * z1, w2 * z0 - w0 * z2, w0 * z1 - w1 * z0
        if P.joint_type[j] == PRISMATIC:
            v0, v1, v2 = v0 + z0 * t, v1 + z1 * t, v2 + z2 * t
            dJ[0, c], dJ[1, c], dJ[2, c] = dz0, dz1, dz2
            dJ[3, c] = dJ[4, c] = dJ[5, c] = 0.0
            continue
        r0, r1, r2 = pt[0] - p[j, 0], pt[1] - p[j, 1], pt[2] - p[j, 2]
        u0, u1, u2 = vp[0] - v0, vp[1] - v1, vp[2] - v2
        dJ[0, c] = (dz1 * r2 - dz2 * r1) + (z1 * u2 - z2 * u1)
        dJ[1, c] = (dz2 * r0 - dz0 * r2) + (z2 * u0 - z0 * u2)
        dJ[2, c] = (dz0 * r1 - dz1 * r0) + (z0 * u1 - z1 * u0)
        dJ[3, c], dJ[4, c], dJ[5, c] = dz0, dz1, dz2
        w0, w1, w2 = w0 + z0 * t, w1 + z1 * t, w2 + z2 * t


@kernel
def redundant_rates(P, W, m, S, q, mo, B, with_acc, qd, qdd):
    """θ̇ (and θ̈) of redundant arm m at q for the end-effector target B.tw_m, B.ac_m (least |θ̇ − z|).

    As `coopsim.inverse.trajectory.redundant_rates`: A = S J_m, z = g (θ_rest − θ), AAᵀλ = S v_EE − Az,
    θ̇ = z + Aᵀλ; with_acc: Ȧ = S J̇_m, ż = ġ (θ_rest − θ) − g θ̇, AAᵀλ̇ = S a_EE − Ȧθ̇ − Aż − A Ȧᵀλ,
    θ̈ = ż + Ȧᵀλ + Aᵀλ̇; g = mo.gain, ġ = 0, or with a pull per unit path g = pull σ̇, ġ = pull σ̈
    (`coopsim.inverse.trajectory.pull_gain`).

    Args:
        P: the compiled model (PackedModel StructRef, read only).
        W: the workspace: arm m's kinematics and Jacobian overwritten.
        m: arm index, 0-based (n_m > k joints).
        S: (k, 6) row selector.
        q: (N,) rad or m, stacked joint coordinates (arm m's rows read).
        mo: the Motion (rest posture, gain and pull).
        B: the Buffers: tw_m and ac_m read (`grasp_target`), law (`object_state`).
        with_acc: also θ̈ and σ_min/σ_max of A.
        qd, qdd: (N,) written in arm m's rows: θ̇ (rad/s, m/s), and with with_acc θ̈ (rad/s², m/s²).

    Returns:
        float: σ_min/σ_max of A with with_acc, else 1.
    """
    o, n, k = P.dof[m], P.dof[m + 1] - P.dof[m], S.shape[0]
    arm_kinematics(P, W, m, q)
    arm_jacobian(P, W, m)
    A = rows_jacobian(P, W, m, S)
    AAt = gram(A, k, n)
    z, b, lam = np.empty(n), np.empty(k), np.empty(k)
    g, gd = (mo.gain, 0.0) if mo.pull == 0 else (mo.pull * B.law[0], mo.pull * B.law[1])
    for j in range(n):
        z[j] = g * (mo.rest[o + j] - q[o + j])
    rows_of(S, B.tw_m, b)
    for i in range(k):
        v = 0.0
        for j in range(n):
            v += A[i, j] * z[j]
        b[i] -= v
    lu_solve(AAt, k, b, lam)
    for j in range(n):
        v = 0.0
        for i in range(k):
            v += A[i, j] * lam[i]
        qd[o + j] = z[j] + v
    if not with_acc:
        return 1.0
    dJ = np.empty((6, n))
    ee_jacobian_rate(P, W, m, qd, dJ)
    dA = np.zeros((k, n))
    for i in range(k):
        for j in range(n):
            for a in range(6):
                dA[i, j] += S[i, a] * dJ[a, j]
    rows_of(S, B.ac_m, b)
    for i in range(k):
        v1 = v2 = v3 = 0.0
        for j in range(n):
            v1 += dA[i, j] * qd[o + j]
            v2 += A[i, j] * (gd * (mo.rest[o + j] - q[o + j]) - g * qd[o + j])
            s = 0.0
            for c in range(k):
                s += dA[c, j] * lam[c]
            v3 += A[i, j] * s
        b[i] = b[i] - v1 - v2 - v3
    dlam = np.empty(k)
    lu_solve(AAt, k, b, dlam)
    for j in range(n):
        v1 = v2 = 0.0
        for i in range(k):
            v1 += dA[i, j] * lam[i]
            v2 += A[i, j] * dlam[i]
        qdd[o + j] = gd * (mo.rest[o + j] - q[o + j]) - g * qd[o + j] + v1 + v2
    At = np.empty((n, k))
    for i in range(k):
        for j in range(n):
            At[j, i] = A[i, j]
    return singular_ratio(At, n, k)


@kernel
def min_norm_solve(P, W, m, S, q, B, tol, max_iter):
    """Redundant arm m's joint coordinates on the target B.p, B.R by least-norm Newton, in place in q.

    Steps Δθ = −Aᵀ(AAᵀ)⁻¹ S e, A = S J_m, until max |S e| ≤ tol (`coopsim.inverse.trajectory.min_norm_ik`).

    Args:
        P: the compiled model (PackedModel StructRef, read only).
        W: the workspace: arm m's kinematics and Jacobian overwritten.
        m: arm index, 0-based.
        S: (k, 6) row selector.
        q: (N,) rad or m, stacked: arm m's rows hold the guess and are overwritten with the iterates.
        B: the Buffers: p, R read; e scratch; info[0] written: the max |full pose error| at the solution
            (SOLVED) or the max |S e| before the last step.
        tol: m or rad, the tolerance on max |S e|.
        max_iter: the most Newton steps.

    Returns:
        int: OK or NOT_CONVERGED.
    """
    o, n, k = P.dof[m], P.dof[m + 1] - P.dof[m], S.shape[0]
    Se, y = np.empty(k), np.empty(k)
    for _ in range(max_iter):
        arm_kinematics(P, W, m, q)
        pose_error(P, W, m, B.p, B.R, B.e)
        rows_of(S, B.e, Se)
        if max_abs(Se) <= tol:
            B.info[0] = max_abs(B.e)
            return OK
        arm_jacobian(P, W, m)
        A = rows_jacobian(P, W, m, S)
        lu_solve(gram(A, k, n), k, Se, y)
        for j in range(n):
            v = 0.0
            for i in range(k):
                v += A[i, j] * y[i]
            q[o + j] -= v
    B.info[0] = max_abs(Se)
    return NOT_CONVERGED


@kernel
def fail(code, m, i, t, B, a, b, t_prev, info, where):
    """Record a failure and return its code.

    Args:
        code: the failure code.
        m: the arm, 0-based.
        i: the sample index (−1: a segment end).
        t: s, the time.
        B: the Buffers (pc: the object's C relative to the motion's origin).
        a, b: the two numbers the message quotes (distance and reach, ratio, error).
        t_prev: s, the previous sample's time (CROSSES).
        info: (7,) written: t, pc (3), a, b, t_prev.
        where: (2,) int written: arm, sample.

    Returns:
        int: code.
    """
    info[0] = t
    info[1], info[2], info[3] = B.pc[0], B.pc[1], B.pc[2]
    info[4], info[5], info[6] = a, b, t_prev
    where[0], where[1] = m, i
    return code


@kernel
def on_grasp(P, W, S, mo, red, first, reach_lim, t, i, B, tol, max_iter, plane_tol, info, where):
    """B.y's redundant arms put exactly on their grasps at time t (reach, least-norm Newton, plane checks).

    Args:
        P: the compiled model (PackedModel StructRef, read only).
        W: the workspace (scratch).
        S: (k, 6) row selector.
        mo: the Motion.
        red: (n_r,) int, the redundant arms.
        first: (r, 3) m, each arm's first joint origin relative to its base point (`reach_check`).
        reach_lim: (r,) m, each arm's reach with its slack.
        t: s, the time.
        i: the sample index (−1: a segment end), for a failure.
        B: the Buffers: y overwritten in the redundant arms' rows.
        tol, max_iter: the Newton tolerance (m or rad) and cap.
        plane_tol: m or rad, how far a grasp may leave the rows S.
        info, where: a failure's record (`fail`).

    Returns:
        int: OK, OUT_OF_REACH, NOT_CONVERGED or OFF_PLANE.
    """
    object_state(mo, t, B)
    for m in red:
        grasp_target(P, mo, m, B)
        d = distance(B.p, first[m])
        if not d <= reach_lim[m]:
            return fail(OUT_OF_REACH, m, i, t, B, d, 0.0, 0.0, info, where)
        if min_norm_solve(P, W, m, S, B.y, B, tol, max_iter) != OK:
            return fail(NOT_CONVERGED, m, i, t, B, B.info[0], 0.0, 0.0, info, where)
        if B.info[0] > plane_tol:
            return fail(OFF_PLANE, m, i, t, B, B.info[0], 0.0, 0.0, info, where)
    return OK


@kernel
def spread(x, idx, y):
    """y[idx] ← x (the redundant arms' coordinates into a stacked vector).

    Args:
        x: (n_red,) the coordinates, one arm after the other.
        idx: (n_red,) int, their stacked indices.
        y: (N,) written in those rows.
    """
    for j in range(len(idx)):
        y[idx[j]] = x[j]


@kernel
def ode_rhs(P, W, S, mo, red, idx, t, x, dx, B):
    """dx ← the redundant arms' θ̇ (`redundant_rates`, no θ̈) at time t and coordinates x.

    Args:
        P: the compiled model (PackedModel StructRef, read only).
        W: the workspace (scratch).
        S: (k, 6) row selector.
        mo: the Motion.
        red: (n_r,) int, the redundant arms.
        idx: (n_red,) int, the stacked indices of x.
        t: s, the time.
        x: (n_red,) rad or m, the redundant arms' coordinates.
        dx: (n_red,) written: their rates.
        B: the Buffers (y, qd and the object's state overwritten).
    """
    object_state(mo, t, B)
    spread(x, idx, B.y)
    for m in red:
        grasp_target(P, mo, m, B)
        redundant_rates(P, W, m, S, B.y, mo, B, False, B.qd, B.qdd)
    for j in range(len(idx)):
        dx[j] = B.qd[idx[j]]


@kernel
def redundant_sample(P, W, S, mo, red, first, reach_lim, i, t, B, tol, max_iter, sing_tol, plane_tol,
                     Q, QD, QDD, info, where):
    """Sample i at time t of the redundant arms from B.y (interpolated): on the grasps, then θ̇ and θ̈.

    Args:
        P: the compiled model (PackedModel StructRef, read only).
        W: the workspace (scratch).
        S: (k, 6) row selector.
        mo: the Motion.
        red: (n_r,) int, the redundant arms.
        first, reach_lim: the reach checks' numbers (`on_grasp`).
        i: the sample index.
        t: s, its time.
        B: the Buffers: y the interpolated stacked coordinates (redundant rows), corrected in place.
        tol, max_iter: the Newton tolerance (m or rad) and cap.
        sing_tol: σ_min/σ_max of S J below which an arm counts as singular.
        plane_tol: m or rad, how far a grasp may leave the rows S.
        Q, QD, QDD: (n_s, N) written in row i, the redundant arms' columns.
        info, where: a failure's record (`fail`).

    Returns:
        int: OK or a failure code.
    """
    st = on_grasp(P, W, S, mo, red, first, reach_lim, t, i, B, tol, max_iter, plane_tol, info, where)
    if st != OK:
        return st
    for m in red:
        grasp_target(P, mo, m, B)
        ratio = redundant_rates(P, W, m, S, B.y, mo, B, True, QD[i], QDD[i])
        if not ratio >= sing_tol:
            return fail(SINGULAR, m, i, t, B, ratio, 0.0, 0.0, info, where)
        for j in range(P.dof[m], P.dof[m + 1]):
            Q[i, j] = B.y[j]
    return OK


@kernel
def redundant_pass(P, W, L, tab, S, mo, red, idx, first, reach_lim, t_out, guess, tol, max_iter, sing_tol,
                   plane_tol, rtol, atol, Q, QD, QDD, info, where, B):
    """Every sample of the redundant arms: the ODE of `redundant_rates` by DOP853 segment by segment.

    Each segment [t_a, t_b] between waypoints is one `solve_ivp` call of the reference: Hairer's starting
    step, h_abs·min(10, 0.9 err^(−1/8)) after an accepted step (at most 1 right after a rejection),
    h_abs·max(0.2, 0.9 err^(−1/8)) after a rejected one, the step cut to end on t_b; each sample in
    [t_a, t_b) (the last segment: to its end) taken from the dense output of the first step ending at or
    after it, then put on the grasps (`redundant_sample`); the segment's end state put on the grasps
    starts the next one. The pass stops with STEP_COLLAPSED when a step falls below 10 ulp of t (info's
    second number 0) or after max(ODE_STEPS, ODE_STEPS_PER_SAMPLE × samples) step attempts (that budget
    there): near a singularity the ODE turns stiff and can take 10⁵ steps before its step collapses
    (the reference, without a budget, reaches the collapse).

    Args:
        P: the compiled model (PackedModel StructRef, read only).
        W: the workspace (scratch).
        L: a Loop StructRef (`integrate.new_loop`) of the redundant arms' n_red coordinates: its y, fy,
            K, y_new, ytmp and Fd used as the integration's state and scratch.
        tab: DOP853's Tableau StructRef.
        S: (k, 6) row selector.
        mo: the Motion.
        red: (n_r,) int, the redundant arms.
        idx: (n_red,) int, the stacked indices of their joints.
        first, reach_lim: the reach checks' numbers (`on_grasp`).
        t_out: (n_s,) s, the sample times.
        guess: (N,) rad or m, stacked: the start of the least-norm IK at the first sample.
        tol, max_iter: the Newton tolerance (m or rad) and cap.
        sing_tol: σ_min/σ_max of S J below which an arm counts as singular.
        plane_tol: m or rad, how far a grasp may leave the rows S.
        rtol, atol: DOP853's tolerances.
        Q, QD, QDD: (n_s, N) written in the redundant arms' columns.
        info, where: a failure's record (`fail`).
        B: the Buffers.

    Returns:
        int: OK or a failure code.
    """
    n_s, ts, s = len(t_out), mo.times, tab.stages
    expo = -1.0 / (tab.err_order + 1)
    budget, attempts = max(ODE_STEPS, ODE_STEPS_PER_SAMPLE * n_s), 0
    copy1(guess, B.y)
    st = on_grasp(P, W, S, mo, red, first, reach_lim, t_out[0], 0, B, tol, max_iter, plane_tol, info, where)
    if st != OK:
        return st
    for j in range(len(idx)):
        L.y[j] = B.y[idx[j]]
    i = 0
    n_seg = len(ts) - 1
    for k in range(n_seg):
        ta, tb, last = ts[k], ts[k + 1], k == n_seg - 1
        ode_rhs(P, W, S, mo, red, idx, ta, L.y, L.fy, B)
        span = tb - ta
        h0 = probe_step(L, span, rtol, atol)
        ode_rhs(P, W, S, mo, red, idx, ta + h0, L.ytmp, L.K[1], B)
        h_abs = first_step(tab, L, h0, span, np.inf, rtol, atol)
        t = ta
        while t < tb:
            min_step = 10.0 * (np.nextafter(t, np.inf) - t)
            h_abs = max(h_abs, min_step)
            rejected = False
            while True:
                if h_abs < min_step:
                    return fail(STEP_COLLAPSED, 0, i, t, B, h_abs, 0.0, 0.0, info, where)
                attempts += 1
                if attempts > budget:
                    return fail(STEP_COLLAPSED, 0, i, t, B, h_abs, float(budget), 0.0, info, where)
                t_new = min(t + h_abs, tb)
                h = t_new - t
                h_abs = abs(h)
                copy1(L.fy, L.K[0])
                for c in range(1, s):
                    stage_input(tab, L, L.y, h, c)
                    ode_rhs(P, W, S, mo, red, idx, t + tab.C[c] * h, L.ytmp, L.K[c], B)
                rk_combine(tab, L, L.y, h, L.y_new)
                ode_rhs(P, W, S, mo, red, idx, t + h, L.y_new, L.K[s], B)
                err = error_norm(tab, L, L.y, L.y_new, h, rtol, atol)
                if err < 1.0:
                    factor = MAX_FACTOR if err == 0.0 else min(MAX_FACTOR, SAFETY * err ** expo)
                    if rejected:
                        factor = min(1.0, factor)
                    h_abs *= factor
                    break
                h_abs *= max(MIN_FACTOR, SAFETY * err ** expo)
                rejected = True
            ends = t_new == tb
            here = i < n_s and ((last and ends) or (t_out[i] <= t_new and (last or t_out[i] < tb)))
            if here or ends:
                for c in range(13, 16):
                    stage_input(tab, L, L.y, h, c)
                    ode_rhs(P, W, S, mo, red, idx, t + tab.C[c] * h, L.ytmp, L.K[c], B)
                dense_coefficients(tab, L, L.y, L.y_new, h)
            while i < n_s and ((last and ends) or (t_out[i] <= t_new and (last or t_out[i] < tb))):
                dense_eval(tab, L, L.y, h, (t_out[i] - t) / h, B.x)
                spread(B.x, idx, B.y)
                st = redundant_sample(P, W, S, mo, red, first, reach_lim, i, t_out[i], B, tol, max_iter, sing_tol,
                                      plane_tol, Q, QD, QDD, info, where)
                if st != OK:
                    return st
                i += 1
            if ends:
                dense_eval(tab, L, L.y, h, 1.0, B.x)
            copy1(L.y_new, L.y)
            copy1(L.K[s], L.fy)
            t = t_new
        spread(B.x, idx, B.y)
        st = on_grasp(P, W, S, mo, red, first, reach_lim, tb, -1, B, tol, max_iter, plane_tol, info, where)
        if st != OK:
            return st
        for j in range(len(idx)):
            L.y[j] = B.y[idx[j]]
    return OK


@kernel
def sign(x):
    """The sign of x: −1, 0 or 1 (as numpy.sign).

    Args:
        x: the number.

    Returns:
        float: its sign.
    """
    return 1.0 if x > 0 else (-1.0 if x < 0 else 0.0)


@kernel
def square_pass(P, W, S, mo, square, first, reach_lim, t_out, guess, tol, max_iter, sing_tol, plane_tol,
                Q, QD, QDD, info, where, B):
    """Every sample of the square arms: Newton by continuation and the differential kinematics.

    At sample i > 0 the guess is θ + hθ̇ + h²θ̈/2 of sample i − 1 (h the interval); det S J must keep its
    sign from one sample to the next.

    Args:
        P: the compiled model (PackedModel StructRef, read only).
        W: the workspace (scratch).
        S: (k, 6) row selector.
        mo: the Motion.
        square: (n_q,) int, the square arms.
        first, reach_lim: the reach checks' numbers (`on_grasp`).
        t_out: (n_s,) s, the sample times.
        guess: (N,) rad or m, stacked: the start of Newton at the first sample.
        tol, max_iter: the Newton tolerance (m or rad) and cap.
        sing_tol: σ_min/σ_max of S J below which the solve stops as singular.
        plane_tol: m or rad, how far a grasp may leave the rows S.
        Q, QD, QDD: (n_s, N) written in the square arms' columns.
        info, where: a failure's record (`fail`).
        B: the Buffers.

    Returns:
        int: OK or a failure code.
    """
    N = len(guess)
    copy1(guess, B.y)
    for i in range(len(t_out)):
        t = t_out[i]
        object_state(mo, t, B)
        if i:
            h = t - t_out[i - 1]
            for j in range(N):
                B.y[j] = Q[i - 1, j] + h * QD[i - 1, j] + 0.5 * h * h * QDD[i - 1, j]
        for m in square:
            grasp_target(P, mo, m, B)
            d = distance(B.p, first[m])
            if not d <= reach_lim[m]:
                return fail(OUT_OF_REACH, m, i, t, B, d, 0.0, 0.0, info, where)
            st = solve(P, W, m, S, B.p, B.R, B.tw_m, B.ac_m, B.y, tol, max_iter, sing_tol, QD[i], QDD[i], B.info)
            if st == IK_SINGULAR:
                return fail(SINGULAR, m, i, t, B, B.info[0], 0.0, 0.0, info, where)
            if st == IK_NOT_CONVERGED:
                return fail(NOT_CONVERGED, m, i, t, B, B.info[0], 0.0, 0.0, info, where)
            if B.info[2] > plane_tol:
                return fail(OFF_PLANE, m, i, t, B, B.info[2], 0.0, 0.0, info, where)
            for j in range(P.dof[m], P.dof[m + 1]):
                Q[i, j] = B.y[j]
            det = B.info[1]
            if i and sign(det) != sign(B.det[m]):
                return fail(CROSSES, m, i, t, B, det, B.det[m], t_out[i - 1], info, where)
            B.det[m] = det
    return OK


@entry
def trajectory(P, W, L, tab, S, mo, red, idx, square, first, reach_lim, t_out, guess, tol, max_iter, sing_tol,
               plane_tol, rtol, atol, Q, QD, QDD, info, where, B):
    """Closed-chain inverse kinematics of the object motion mo at every sample (module docstring).

    Args:
        P: the compiled model (PackedModel StructRef, read only).
        W: the workspace (Workspace StructRef, scratch).
        L: a Loop StructRef of the redundant arms' n_red coordinates (`redundant_pass`).
        tab: DOP853's Tableau StructRef.
        S: (k, 6) row selector of the constrained pose rows.
        mo: the Motion.
        red: (n_r,) int, the redundant arms (more joints than rows).
        idx: (n_red,) int, the stacked indices of their joints.
        square: (n_q,) int, the other arms (as many joints as rows).
        first: (r, 3) m, each arm's first joint origin relative to its base point, world axes.
        reach_lim: (r,) m, each arm's reach times (1 + slack): a target farther from the first joint is
            out of reach.
        t_out: (n_s,) s, the sample times, within the waypoints' span.
        guess: (N,) rad or m, stacked: the inverse kinematics' start at the first sample.
        tol, max_iter: the Newton tolerance on max |S e| (m or rad) and the cap on its steps.
        sing_tol: σ_min/σ_max of S J below which an arm counts as singular.
        plane_tol: m or rad, how far a grasp may leave the rows S (max |full pose error|).
        rtol, atol: DOP853's tolerances for the redundant arms' ODE.
        Q, QD, QDD: (n_s, N) written: θ (rad, m), θ̇ (rad/s, m/s) and θ̈ (rad/s², m/s²), stacked arm after
            arm (rows after a failure left as they were).
        info: (7,) float written on a failure: t s, the object's C relative to mo.origin (3) m, two numbers
            (OUT_OF_REACH: the distance m; SINGULAR: σ_min/σ_max; NOT_CONVERGED: max |S e| left;
            OFF_PLANE: max |pose error|; CROSSES: det S J here and at the previous sample), the previous
            sample's time s.
        where: (2,) int written on a failure: the arm and the sample index (−1: a segment's end).
        B: the Buffers (`buffers`).

    Returns:
        int: OK or a failure code (OUT_OF_REACH, SINGULAR, NOT_CONVERGED, OFF_PLANE, CROSSES,
        STEP_COLLAPSED).
    """
    if len(red):
        st = redundant_pass(P, W, L, tab, S, mo, red, idx, first, reach_lim, t_out, guess, tol, max_iter, sing_tol,
                            plane_tol, rtol, atol, Q, QD, QDD, info, where, B)
        if st != OK:
            return st
    return square_pass(P, W, S, mo, square, first, reach_lim, t_out, guess, tol, max_iter, sing_tol, plane_tol,
                       Q, QD, QDD, info, where, B)
