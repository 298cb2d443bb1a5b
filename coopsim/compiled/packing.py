"""Model → PackedModel: every array the compiled kernels read, built once from a frozen `Model`.

A `PackedModel` is a NamedTuple of NumPy arrays and scalars (numba passes it to compiled code as one
typed tuple). Joints of all arms are stacked arm after arm: arm m owns rows dof[m]:dof[m+1] of every
per-joint array. Units SI, frames as in `coopsim.core.model`. A `Workspace` holds the buffers the kernels
write into, so that no evaluation allocates.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from coopsim.core.model import Model, TorqueFunction, TorqueTable

STAB_NONE, STAB_PROJECTION, STAB_BAUMGARTE = 0, 1, 2
_STAB = {"none": STAB_NONE, "projection": STAB_PROJECTION, "baumgarte": STAB_BAUMGARTE}
PROJECTION_MAX_ITER = 50      # Gauss–Newton steps of a projection before it fails


class PackedModel(NamedTuple):
    """Frozen model arrays for the compiled kernels (N joints in all, r arms, k constraint rows per grasp).

    Joints of all arms are stacked arm after arm: arm m owns rows dof[m]:dof[m+1] of every per-joint
    array. Units SI, frames as in `coopsim.core.model`. A prismatic joint slides its frame θ m along its
    axis a, and its rows of the kernels are a force (N) instead of a moment. Compiled code reads these
    arrays through the StructRef `structs.to_struct` makes of the record (the kernels' argument P).

    Attributes:
        dof: (r+1,) int: arm m's joints are dof[m]:dof[m+1] (dof[r] = N).
        base_pos: (r, 3) m, the arms' base points, world.
        base_rot: (r, 3, 3) world ← base frame.
        joint_pos: (N, 3) m, origin of each joint's frame in the parent frame (the base frame for an arm's
            first joint).
        joint_rot: (N, 3, 3) R0, parent frame ← joint frame at θ = 0.
        joint_axis: (N, 3) the unit joint axis a, joint frame.
        joint_k1, joint_k2: (N, 3, 3) K1 = R0[a×] and K2 = R0[a×]², so that
            R0 Rot(a, θ) = R0 + sinθ K1 + (1 − cosθ) K2.
        joint_z: (N, 3) R0 a, the joint axis in the parent frame.
        joint_type: (N,) int: REVOLUTE or PRISMATIC (`coopsim.core.model`).
        link_mass: (N,) kg.
        link_com: (N, 3) m, centres of mass, link frame.
        link_inertia: (N, 3, 3) kg·m², about the centre of mass, link axes.
        ee_pos, ee_rot: (r, 3) m and (r, 3, 3): the end-effector frame in the last link frame (its origin,
            and last link frame ← end-effector frame).
        obj_mass: kg, the object's mass m_o.
        obj_inertia: (3, 3) kg·m², the object's inertia K about C, object axes.
        grasp_pos, grasp_rot: (r, 3) m and (r, 3, 3): EE frame m in the object frame (its origin relative to
            C, and object frame ← EE frame m).
        carrier: index c of the arm that carries the object in the reduced model (eqs. 17–19).
        gravity: (3,) m/s², world.
        rows: (k, 6) the constraint rows S kept per grasp, applied to twists [v; ω] and wrenches [f; n] in
            world axes.
        rank_tol: relative eigenvalue (of λ_max) below which Λ𝐈⁻¹Λᵀ counts as rank-deficient.
        rank_error: 1 to stop when Λ𝐈⁻¹Λᵀ loses rank, 0 to warn (minimum-norm grasp wrenches).
        stabilization: stabilization code: STAB_NONE, STAB_PROJECTION or STAB_BAUMGARTE.
        alpha, beta: 1/s, Baumgarte's gains in Λθ̈ = −Λ̇θ̇ − 2αΛθ̇ − β²Φ.
        projection_tol: m and rad, the loop-closure tolerance on max |Φ| of a projection.
        projection_max_iter: Gauss–Newton steps of a projection before it fails (PROJECTION_MAX_ITER).
        tq_off: (N+1,) int: joint j's torque table is (tq_t, tq_v)[tq_off[j]:tq_off[j+1]].
        tq_t, tq_v: the knots of the torque tables, s, and their values, N·m (N for a prismatic joint),
            joint after joint; linear between knots, held outside.
    """

    dof: np.ndarray
    base_pos: np.ndarray
    base_rot: np.ndarray
    joint_pos: np.ndarray
    joint_rot: np.ndarray
    joint_axis: np.ndarray
    joint_k1: np.ndarray
    joint_k2: np.ndarray
    joint_z: np.ndarray
    joint_type: np.ndarray
    link_mass: np.ndarray
    link_com: np.ndarray
    link_inertia: np.ndarray
    ee_pos: np.ndarray
    ee_rot: np.ndarray
    obj_mass: float
    obj_inertia: np.ndarray
    grasp_pos: np.ndarray
    grasp_rot: np.ndarray
    carrier: int
    gravity: np.ndarray
    rows: np.ndarray
    rank_tol: float
    rank_error: int
    stabilization: int
    alpha: float
    beta: float
    projection_tol: float
    projection_max_iter: int
    tq_off: np.ndarray
    tq_t: np.ndarray
    tq_v: np.ndarray


class Workspace(NamedTuple):
    """Buffers of one evaluation: N joints, r arms, nmax joints in the longest arm, K = k(r−1) rows.

    The kernels write into these (no evaluation allocates); compiled code reaches them through the
    StructRef of `structs.to_struct` (the kernels' argument W). World axes, SI.

    Attributes:
        p, R, z, c, I: (N, …) link geometry, world axes: joint origins, frames, axes, centres of mass,
            inertias.
        p_ee, R_ee: (r, 3), (r, 3, 3) the end-effector frames.
        p_rel, c_rel, p_ee_rel: (N, 3), (N, 3), (r, 3): p, c, p_ee relative to their arm's base point,
            accumulated from the base without its world position (every lever arm of the kernels is
            formed from these, so that a scene far from the world origin loses nothing to rounding;
            p, c, p_ee are those plus base_pos, for output).
        w, dw, a: (N, 3) link motion at θ̈ = 0 with base acceleration −g.
        Mb: (N, nmax) mass-matrix blocks (arm m's block in rows dof[m]:dof[m+1], columns 0:n_m).
        Lb: (N, nmax) their Cholesky factors L (lower triangle, and Lᵀ in the strict upper one).
        Lb_inv: (N,) the reciprocals of the factors' diagonals.
        h, h_arm: (N,) bias forces h = −Re, with the object in the carrier's rows and without it.
        J, Jd_qd: (r, 6, nmax), (r, 6) end-effector Jacobians and J̇θ̇.
        p_C, R_o, K_o, s: the object's centre of mass (3,), frame (3, 3), inertia (3, 3), grasp
            offsets (r, 3).
        J_o, Jd_o_qd, v_o, Y_bias: (6, nmax), (6,), (6,), (6,) the object's Jacobian, J̇_oθ̇, twist,
            and M_o J̇_oθ̇ + b_o.
        Lam, Lam_dot_qd: (K, N), (K,) Λ and Λ̇θ̇.
        X, x0: (K, N) Λ L⁻ᵀ and (N,) L⁻¹(τ − h) (𝐈 = L Lᵀ).
        A, A_f: (K, K) Λ𝐈⁻¹Λᵀ and its factor.
        b, F, res, dF: (K,) right-hand side, grasp wrenches, residual, refinement step.
        perm: (K,) int pivots.
        yK: (K,) scratch.
        phi: (K,) the loop residual Φ (m, rad).
        qdd, tau: (N,) outputs: θ̈ (rad/s² or m/s²) and the joint torques τ applied (N·m or N).
        cond: (1,) condition number λ_max/λ_min of Λ𝐈⁻¹Λᵀ (−1: not computed on the fast path).
        rank: (1,) int, the numerical rank of Λ𝐈⁻¹Λᵀ.
        path: (1,) int, the path of the last constraint solve (`closed_chain.chain_solve`: EIGEN, DENSE or
            SCHUR).
        vec6, v3, m3: (6,), (3,), (4, 3, 3) scratch.
        d_inv, V, S, S_inv, yN: the O(r) constraint solve (`schur`; n_c ≤ nmax the carrier's joints):
            (K,) reciprocals of the diagonals of the k × k factors L_g (kept in A_f's diagonal
            blocks), (K, nmax) L_D⁻¹U, (nmax, nmax) and (nmax,) the factor of I + VᵀV and its
            diagonal's reciprocals, (nmax,) scratch.
    """

    p: np.ndarray
    R: np.ndarray
    z: np.ndarray
    c: np.ndarray
    I: np.ndarray
    p_ee: np.ndarray
    R_ee: np.ndarray
    p_rel: np.ndarray
    c_rel: np.ndarray
    p_ee_rel: np.ndarray
    w: np.ndarray
    dw: np.ndarray
    a: np.ndarray
    Mb: np.ndarray
    Lb: np.ndarray
    Lb_inv: np.ndarray
    h: np.ndarray
    h_arm: np.ndarray
    J: np.ndarray
    Jd_qd: np.ndarray
    p_C: np.ndarray
    R_o: np.ndarray
    K_o: np.ndarray
    s: np.ndarray
    J_o: np.ndarray
    Jd_o_qd: np.ndarray
    v_o: np.ndarray
    Y_bias: np.ndarray
    Lam: np.ndarray
    Lam_dot_qd: np.ndarray
    X: np.ndarray
    x0: np.ndarray
    A: np.ndarray
    A_f: np.ndarray
    b: np.ndarray
    F: np.ndarray
    res: np.ndarray
    perm: np.ndarray
    yK: np.ndarray
    phi: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    cond: np.ndarray
    rank: np.ndarray
    path: np.ndarray
    dF: np.ndarray
    vec6: np.ndarray
    v3: np.ndarray
    m3: np.ndarray
    d_inv: np.ndarray
    V: np.ndarray
    S: np.ndarray
    S_inv: np.ndarray
    yN: np.ndarray


def _f(x) -> np.ndarray:
    return np.ascontiguousarray(x, dtype=np.float64)


def torque_arrays(torques, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-joint torque tables (tq_off, tq_t, tq_v) of the model's per-arm tables.

    A TorqueFunction packs as zero torque: its values are supplied per stage by the caller.

    Args:
        torques: the model's torques: the per-arm TorqueTables (times (k,) s, values (k, n_m) N·m, N for a
            prismatic joint), arm after arm, or a TorqueFunction.
        n: N, the number of joints of all arms (the width of the zero table a TorqueFunction packs as).

    Returns:
        tuple[np.ndarray, np.ndarray, np.ndarray]: tq_off (N+1,) int, tq_t and tq_v (the knots of all
            tables, joint after joint) s and N·m, as the PackedModel fields of those names.
    """
    if isinstance(torques, TorqueFunction):
        tables = [TorqueTable(np.zeros(1), np.zeros((1, n)))]
    else:
        tables = list(torques)
    off, ts, vs = [0], [], []
    for tab in tables:
        for col in np.asarray(tab.values, dtype=float).T:
            ts.append(np.asarray(tab.times, dtype=float))
            vs.append(col)
            off.append(off[-1] + len(col))
    return np.array(off, dtype=np.int64), _f(np.concatenate(ts)), _f(np.concatenate(vs))


def tabulated_torques(P: PackedModel, t: np.ndarray) -> np.ndarray:
    """τ at times t from P's per-joint tables (as `integrate.torque_at`).

    Args:
        P: the packed model (PackedModel; its tables tq_off, tq_t, tq_v are read).
        t: (S,) s, the sample times.

    Returns:
        np.ndarray: (S, N) N·m (N for a prismatic joint), linear between knots, held outside.
    """
    t = np.asarray(t, dtype=float)
    out = np.empty((len(t), int(P.dof[-1])))
    for j in range(out.shape[1]):
        sl = slice(P.tq_off[j], P.tq_off[j + 1])
        out[:, j] = np.interp(t, P.tq_t[sl], P.tq_v[sl])
    return out


def pack(model: Model) -> PackedModel:
    """The frozen arrays of `model` for the compiled kernels.

    Args:
        model: the frozen Model (its arms, object, torques, gravity, constraint rows and integrator
            settings are read).

    Returns:
        PackedModel: joints stacked arm after arm, SI, frames as in `coopsim.core.model`.
    """
    arms, obj, s = model.arms, model.object, model.integrator
    dof = np.cumsum([0] + [a.n for a in arms]).astype(np.int64)
    cat = lambda name: _f(np.concatenate([getattr(a, name) for a in arms]))  # noqa: E731
    stack = lambda name: _f(np.array([getattr(a, name) for a in arms]))      # noqa: E731
    tq_off, tq_t, tq_v = torque_arrays(model.torques, model.n_total)
    R0, a = cat("joint_rot"), cat("joint_axis")
    ax = np.zeros((len(a), 3, 3))              # [a×]
    ax[:, 0, 1], ax[:, 0, 2], ax[:, 1, 2] = -a[:, 2], a[:, 1], -a[:, 0]
    ax[:, 1, 0], ax[:, 2, 0], ax[:, 2, 1] = a[:, 2], -a[:, 1], a[:, 0]
    K1 = R0 @ ax
    return PackedModel(
        dof, stack("base_pos"), stack("base_rot"), cat("joint_pos"), R0, a,
        _f(K1), _f(K1 @ ax), _f(np.einsum("nij,nj->ni", R0, a)),
        np.ascontiguousarray(model.joint_type, dtype=np.int64),
        cat("link_mass"), cat("link_com"), cat("link_inertia"), stack("ee_pos"), stack("ee_rot"),
        float(obj.mass), _f(obj.inertia), _f(obj.grasp_pos), _f(obj.grasp_rot), int(obj.carrier),
        _f(model.gravity), _f(model.rows), float(s.rank_tol), int(s.on_rank_deficiency == "error"),
        _STAB[s.stabilization], float(s.baumgarte_alpha), float(s.baumgarte_beta), float(s.projection_tol),
        PROJECTION_MAX_ITER, tq_off, tq_t, tq_v)


def workspace(P: PackedModel) -> Workspace:
    """Fresh buffers for the kernels of model P.

    Args:
        P: the packed model (PackedModel); its sizes N, r, nmax and K = k(r−1) set the buffers' shapes.

    Returns:
        Workspace: zero-filled buffers (float64; perm, rank and path int64).
    """
    r, N = len(P.dof) - 1, int(P.dof[-1])
    nmax = int(np.max(np.diff(P.dof)))
    K = P.rows.shape[0] * (r - 1)
    z = np.zeros
    return Workspace(
        z((N, 3)), z((N, 3, 3)), z((N, 3)), z((N, 3)), z((N, 3, 3)), z((r, 3)), z((r, 3, 3)),
        z((N, 3)), z((N, 3)), z((r, 3)),
        z((N, 3)), z((N, 3)), z((N, 3)),
        z((N, nmax)), z((N, nmax)), z(N), z(N), z(N), z((r, 6, nmax)), z((r, 6)),
        z(3), z((3, 3)), z((3, 3)), z((r, 3)), z((6, nmax)), z(6), z(6), z(6),
        z((K, N)), z(K), z((K, N)), z(N), z((K, K)), z((K, K)), z(K), z(K), z(K),
        np.zeros(K, dtype=np.int64), z(K), z(K), z(N), z(N), z(1), np.zeros(1, dtype=np.int64),
        np.zeros(1, dtype=np.int64), z(K), z(6), z(3),
        z((4, 3, 3)),
        z(K), z((K, nmax)), z((nmax, nmax)), z(nmax), z(nmax))
