"""Compiled stage 5: the loop-closure manifold (as `coopsim.dynamics.manifold`).

Positions are projected by Gauss–Newton steps of minimum norm, Δθ = −Λ⁺Φ(θ) with
Λ⁺ = Λᵀ(ΛΛᵀ)⁺ (ΛΛᵀ solved by its block structure in O(r) (`schur`), or by a pivoted Cholesky, or
by its eigen-decomposition when rank is lost), until
max |Φ| ≤ tol; rates by θ̇ ← θ̇ − Λ⁺Λθ̇, applied twice on one factor of ΛΛᵀ (the second pass removes
what rounding in the normal equations left).
"""

from __future__ import annotations

import numpy as np

from coopsim.compiled.closed_chain import DENSE, EIGEN, SCHUR, constraint_jacobian, loop_residual
from coopsim.compiled.grasp import object_pose
from coopsim.compiled.kinematics import arm_jacobian, arm_kinematics
from coopsim.compiled.linalg import eig_solve, finite, pivoted_cholesky, pivoted_solve, safe_pivot_ratio
from coopsim.compiled.schur import constraint_trace, schur_factor, schur_solve
from coopsim.compiled.structs import borrow
from coopsim.compiled.toolchain.jit import entry, kernel

NON_FINITE_STATE, PROJECTION_FAILED = 4, 7   # failure codes (`closed_chain`'s are 0–3, the time loop's 5–6)


@kernel
def closure_kinematics(P, W, q):
    """Kinematics, EE Jacobians, object pose, Λ and Φ at q (no dynamics).

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): every arm's kinematics and Jacobian, the object pose,
            W.Lam (K, N) and W.phi (K,) (m, rad) written.
        q: (N,) rad or m, the stacked joint coordinates.
    """
    for m in range(len(P.dof) - 1):
        arm_kinematics(P, W, m, q)
        arm_jacobian(P, W, m)
    object_pose(P, W)
    constraint_jacobian(P, W)
    loop_residual(P, W)


@kernel
def normal_factor(P, W):
    """Factor ΛΛᵀ (K × K, Λ in W.Lam) for `normal_solve`; returns the path taken.

    In O(r) by its block structure (`schur`) for three arms or more where that is certified, else formed
    and factored densely (pivoted Cholesky, or — when the pivots do not prove full rank — left formed for
    the minimum-norm eigen solution).

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): W.Lam read; the factor written into the buffers of the
            `schur` solve (W.A_f, W.d_inv, W.V, W.S, W.S_inv) or of the dense one (W.A, W.A_f, W.perm).

    Returns:
        int: `closed_chain`'s SCHUR, DENSE or EIGEN.
    """
    Lam, A, rank_tol = W.Lam, W.A, P.rank_tol
    K, N = Lam.shape
    if len(P.dof) > 3 and schur_factor(P, W, Lam, constraint_trace(P, Lam)):
        return SCHUR
    for i in range(K):
        for l in range(i, K):
            v = 0.0
            for j in range(N):
                v += Lam[i, j] * Lam[l, j]
            A[i, l] = v
            A[l, i] = v
    return DENSE if pivoted_cholesky(A, W.A_f, W.perm, K) > safe_pivot_ratio(K, rank_tol) else EIGEN


@kernel
def normal_solve(P, W, path, rhs, out):
    """out (N,) ← Λ⁺ rhs = Λᵀ (ΛΛᵀ)⁺ rhs for rhs (K,), with the factor of `normal_factor` (its path).

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): W.Lam and the factor read; W.b, W.dF overwritten, with W.yN
            (`schur` path) or W.yK (dense).
        path: the path `normal_factor` returned.
        rhs: (K,) the right-hand side (m or rad for a position step, m/s or rad/s for a rate step), read
            before W.b is written.
        out: (N,) written: Λ⁺ rhs, rad or m (rad/s or m/s for a rate step) per joint.
    """
    Lam, b, dF = W.Lam, W.b, W.dF
    K, N = Lam.shape
    for i in range(K):
        b[i] = rhs[i]
    if path == SCHUR:
        schur_solve(P, W, b, dF)
    elif path == DENSE:
        pivoted_solve(W.A_f, W.perm, K, b, W.yK, dF)
    else:
        eig_solve(W.A, b, dF, K, P.rank_tol)
    for j in range(N):
        v = 0.0
        for i in range(K):
            v += Lam[i, j] * dF[i]
        out[j] = v


@kernel
def min_norm_step(P, W, rhs, out):
    """out (N,) ← Λ⁺ rhs = Λᵀ (ΛΛᵀ)⁺ rhs for rhs (K,), with Λ in W.Lam: `normal_factor`, `normal_solve`.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): W.Lam read; the buffers of `normal_factor` and
            `normal_solve` overwritten.
        rhs: (K,) the right-hand side (m or rad for a position step, m/s or rad/s for a rate step), read
            before W.b is written.
        out: (N,) written: Λ⁺ rhs, rad or m (rad/s or m/s for a rate step) per joint.
    """
    normal_solve(P, W, normal_factor(P, W), rhs, out)


@kernel
def max_abs(x):
    """max |x_i| (NaN if any x_i is NaN).

    Args:
        x: (n,) the array.

    Returns:
        float: max |x_i|; 0 for an empty x; NaN if any x_i is NaN.
    """
    v = 0.0
    for i in range(len(x)):
        a = abs(x[i])
        if a != a:
            return a
        if a > v:
            v = a
    return v


@kernel
def project_positions(P, W, q, tol, max_iter, step):
    """Gauss–Newton steps q ← q − Λ⁺Φ(q) in place until max |Φ| ≤ tol.

    Leaves the kinematics, Λ and Φ of the final q in W.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): the kinematics, W.Lam and W.phi of the final q written,
            with the buffers of `min_norm_step`.
        q: (N,) rad or m, the stacked joint coordinates, overwritten with the projected ones.
        tol: m and rad, the tolerance on max |Φ|.
        max_iter: the most Gauss–Newton steps.
        step: (N,) scratch (the last step).

    Returns:
        int: the number of steps taken, or −1 after max_iter steps without convergence.
    """
    for it in range(max_iter + 1):
        closure_kinematics(P, W, q)
        if max_abs(W.phi) <= tol:
            return it
        if it == max_iter:
            return -1
        min_norm_step(P, W, W.phi, step)
        for j in range(len(q)):
            q[j] -= step[j]
    return -1


@kernel
def project_rates(P, W, qd, step):
    """qd ← qd − Λ⁺Λ qd in place (twice: the second pass removes what rounding left), Λ from W.

    ΛΛᵀ is factored once for both passes (`normal_factor`).

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): W.Lam (of the projected positions) read; W.res and the
            buffers of `normal_factor` and `normal_solve` overwritten.
        qd: (N,) rad/s or m/s, the stacked joint rates, overwritten with Λ qd = 0 satisfied.
        step: (N,) scratch.
    """
    Lam, res = W.Lam, W.res
    K, N = Lam.shape
    path = normal_factor(P, W)
    for _ in range(2):
        for i in range(K):
            v = 0.0
            for j in range(N):
                v += Lam[i, j] * qd[j]
            res[i] = v
        normal_solve(P, W, path, res, step)
        for j in range(N):
            qd[j] -= step[j]


@kernel
def project_state(P, W, y, tol, max_iter, step):
    """Project y = [θ; θ̇] (2N,) onto Φ(θ) = 0 and Λ(θ)θ̇ = 0, in place.

    To max |Φ| ≤ tol, at most max_iter Gauss–Newton steps; W.phi holds the last residual. On success W
    holds `closure_kinematics` at the projected positions (what `closed_chain.chain_dynamics` starts
    from).

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): the kinematics, W.Lam and W.phi of the last iterate
            written, with the buffers of `normal_factor` and `normal_solve`.
        y: (2N,) the state [θ; θ̇] (rad or m, rad/s or m/s), overwritten with its projection (the rates
            untouched when the positions fail).
        tol: m and rad, the tolerance on max |Φ|.
        max_iter: the most Gauss–Newton steps.
        step: (N,) scratch.

    Returns:
        int: 0, PROJECTION_FAILED, or NON_FINITE_STATE (the projected y is not finite).
    """
    y, step = borrow(y), borrow(step)
    N = P.dof[-1]
    if project_positions(P, W, y[:N], tol, max_iter, step) < 0:
        return PROJECTION_FAILED
    project_rates(P, W, y[N:], step)
    return 0 if finite(y) else NON_FINITE_STATE


@entry
def consistent(P, W, y, tol, max_iter, info):
    """A consistent initial state: y = [θ; θ̇] (2N,) projected in place as `project_state` does.

    Also reports the residuals and the steps taken in info.

    Args:
        P: the compiled model (the PackedModel StructRef of `structs.to_struct`; read only).
        W: the workspace (Workspace StructRef): as `project_state` writes it.
        y: (2N,) the state [θ; θ̇] (rad or m, rad/s or m/s), overwritten with the consistent state (with
            the last iterate of the positions, rates untouched, on failure).
        tol: m and rad, the tolerance on max |Φ|.
        max_iter: the most Gauss–Newton steps.
        info: (3,) written: [max |Φ| before (m or rad), max |Φ| after, Gauss–Newton steps (max_iter on
            failure)].

    Returns:
        int: 0 or PROJECTION_FAILED (then y holds the last iterate and info[1] its residual).
    """
    N = P.dof[-1]
    step = np.empty(N)
    closure_kinematics(P, W, y[:N])
    info[0] = max_abs(W.phi)
    it = project_positions(P, W, y[:N], tol, max_iter, step)
    info[1], info[2] = max_abs(W.phi), it if it >= 0 else max_iter
    if it < 0:
        return PROJECTION_FAILED
    project_rates(P, W, y[N:], step)
    return 0
