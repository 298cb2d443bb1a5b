"""Stage 4 — the closed chain: eliminate the grasp wrenches (paper eqs. 14–27, r arms).

The object is rigidly attached to the carrier arm c (the paper's arm 1): its twist is
v_o = J_o θ̇_c with J_o = W_c⁻ᵀ J_c, and its inertia joins arm c (eqs. 17–19):
    𝐈_cc = I_c + J_oᵀ M_o J_o,   h_c = −Re_c + J_oᵀ (M_o J̇_o θ̇_c + b_o).
Every other arm m must give its end-effector the twist of the object's grasp point (eqs. 14–16):
    Λ_m θ̇ = S (J_m θ̇_m − W_mᵀ J_o θ̇_c) = 0,
with S (k × 6) the constraint rows the scene needs (k = 3 planar, 6 spatial). With F the stacked
grasp wrenches of the arms m ≠ c (F_e^m = Sᵀ F_m), the system is (eqs. 20–25)
    𝐈 θ̈ + h + Λᵀ F = τ,   Λ θ̈ = −Λ̇θ̇ (− 2αΛθ̇ − β²Φ with Baumgarte stabilization),
    (Λ 𝐈⁻¹ Λᵀ) F = Λ 𝐈⁻¹ (τ − h) + Λ̇θ̇ (+ 2αΛθ̇ + β²Φ),   θ̈ = 𝐈⁻¹ (τ − h − Λᵀ F)   (eqs. 26–27).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from coopsim.core.errors import ConstraintError
from coopsim.dynamics.gibbs_appell import arm_dynamics
from coopsim.dynamics.grasp import (ObjectPose, grasp_matrix, grasp_matrix_inv_T, object_bias_wrench,
                    object_mass_matrix, object_pose)
from coopsim.dynamics.kinematics import ArmPose, arm_pose, ee_jacobian
from coopsim.core.model import Model
from coopsim.core.spatial import rigid_acceleration, rot_log


class ChainTerms(NamedTuple):
    """Everything the closed-chain solve needs at one state (world axes, SI).

    n joints stacked arm by arm, r arms, k constraint rows per grasp, c the carrier arm.

    Attributes:
        poses: the ArmPose of each arm (r).
        J: the end-effector Jacobians J_m (6, n_m) of the arms (r), world axes, EE point.
        Jd_qd: (r, 6) J̇_mθ̇_m [m/s²; rad/s²] at each EE point.
        M: (n, n) 𝐈 of eq. 22 (object inertia in the carrier block), kg·m², kg·m or kg by joint types.
        h: (n,) N·m (N on a prismatic joint), the τ-side terms (−Re + C_oθ̇ + C_g).
        M_arms: the per-arm mass matrices I_m (n_m, n_m) without the object (eq. 10).
        h_arms: the per-arm bias forces −Re_m (n_m,) without the object (eq. 10).
        obj: the ObjectPose carried by arm c.
        J_o: (6, n_c) object Jacobian through the carrier, v_o = J_o θ̇_c (at C).
        Jd_o_qd: (6,) J̇_oθ̇_c [m/s²; rad/s²] at C.
        v_o: (6,) the object twist [v_C; ω] (m/s, rad/s).
        M_o: (6, 6) object mass matrix diag(m_o I₃, K_o) at C (eq. 11), kg and kg·m².
        b_o: (6,) [N; N·m] object bias wrench at C (eq. 11).
        s: (r, 3) m, p_C − grasp point of each arm.
        Lam: (k(r−1), n) the constraint Jacobian Λ.
        Lam_dot_qd: (k(r−1),) Λ̇θ̇ (m/s², rad/s² by row).
        Lam_qd: (k(r−1),) Λθ̇ (m/s, rad/s by row).
    """

    poses: list
    J: list
    Jd_qd: np.ndarray
    M: np.ndarray
    h: np.ndarray
    M_arms: list
    h_arms: list
    obj: ObjectPose
    J_o: np.ndarray
    Jd_o_qd: np.ndarray
    v_o: np.ndarray
    M_o: np.ndarray
    b_o: np.ndarray
    s: np.ndarray
    Lam: np.ndarray
    Lam_dot_qd: np.ndarray
    Lam_qd: np.ndarray


class ChainAcceleration(NamedTuple):
    """Closed-chain forward dynamics result (`forward_dynamics`), world axes.

    Attributes:
        qdd: (n,) rad/s² (m/s² on a prismatic joint), the joint accelerations θ̈.
        F_e: (r, 6) [f; n] N, N·m, the grasp wrenches (EE on object, at the EE point, world axes;
            out-of-plane components zero in a planar scene).
        vd_o: (6,) the object acceleration [v̇_C; ω̇] (m/s², rad/s²).
        cond: the condition number of Λ𝐈⁻¹Λᵀ.
        rank: its numerical rank (< rows: rank-deficient, minimum-norm grasp wrenches).
    """

    qdd: np.ndarray
    F_e: np.ndarray
    vd_o: np.ndarray
    cond: float
    rank: int


def arm_poses(model: Model, q: np.ndarray) -> list[ArmPose]:
    """Stage 1 for every arm: forward kinematics at the stacked joint angles.

    Args:
        model: the Model.
        q: (n,) rad or m, the stacked joint coordinates, arm by arm.

    Returns:
        list[ArmPose]: one per arm (r).
    """
    return [arm_pose(arm, q[sl]) for arm, sl in zip(model.arms, model.dof_slices)]


def carrier_object(model: Model, poses: list[ArmPose]) -> ObjectPose:
    """Object pose carried by arm c's end-effector (eqs. 11–13 via arm 1).

    Args:
        model: the Model (its object's carrier arm c and grasp).
        poses: the ArmPose of every arm (`arm_poses`).

    Returns:
        ObjectPose: C, R_o and the object's inertia about C, world axes.
    """
    c = model.object.carrier
    return object_pose(model.object, poses[c].p_ee, poses[c].R_ee, c)


def grasp_offsets(model: Model, obj: ObjectPose) -> np.ndarray:
    """Grasp offsets s_m = p_C − (grasp point of arm m on the object), world axes.

    Args:
        model: the Model (its object's grasp positions, object frame).
        obj: the ObjectPose (its rotation R_o).

    Returns:
        np.ndarray: (r, 3) m, s_m, world axes.
    """
    return -(obj.R_o @ model.object.grasp_pos.T).T


def position_residual(model: Model, q: np.ndarray) -> np.ndarray:
    """Loop-closure residual Φ: for each arm m ≠ c, S [p_EE,m − p_grasp,m; log(R_EE,m R_grasp,mᵀ)].

    The grasp frame is carried by the object on the carrier arm. The position error is formed without
    world positions (module `kinematics`), as the base offset o_m − o_c plus p_EE,m − p_grasp,m
    relative to the bases, p_grasp,m = p_EE,c + R_o (g_m − g_c).

    Args:
        model: the Model.
        q: (n,) rad or m, the stacked joint coordinates.

    Returns:
        np.ndarray: (k(r−1),) Φ, m (position rows) and rad (orientation rows), world axes, in the
        scene's rows S.
    """
    poses = arm_poses(model, q)
    obj = carrier_object(model, poses)
    c, gp = model.object.carrier, model.object.grasp_pos
    rows = []
    for m in _others(model):
        R_des = obj.R_o @ model.object.grasp_rot[m]
        p_grasp = poses[c].p_ee_rel + obj.R_o @ (gp[m] - gp[c])             # relative to o_c
        p_err = (poses[m].origin - poses[c].origin) + (poses[m].p_ee_rel - p_grasp)
        err = np.concatenate([p_err, rot_log(poses[m].R_ee @ R_des.T)])
        rows.append(model.rows @ err)
    return np.concatenate(rows)


def _others(model: Model) -> list[int]:
    return [m for m in range(model.r) if m != model.object.carrier]


def chain_terms(model: Model, q: np.ndarray, qd: np.ndarray) -> ChainTerms:
    """Stages 1–3 and the assembly of eqs. 17–24 at state (q, qd).

    Args:
        model: the Model.
        q: (n,) rad or m, the stacked joint coordinates.
        qd: (n,) rad/s or m/s, the stacked joint rates.

    Returns:
        ChainTerms: every term of the closed-chain solve at that state.
    """
    sl, c, g = model.dof_slices, model.object.carrier, model.gravity
    poses = arm_poses(model, q)
    dyn = [arm_dynamics(arm, pose, qd[s], g) for arm, pose, s in zip(model.arms, poses, sl)]
    J = [ee_jacobian(p) for p in poses]
    Jd_qd = np.array([d[2] for d in dyn])
    obj = carrier_object(model, poses)
    s = grasp_offsets(model, obj)
    Winv_T = grasp_matrix_inv_T(s[c])
    J_o = Winv_T @ J[c]
    v_o = J_o @ qd[sl[c]]
    w = v_o[3:]
    Jd_o_qd = np.concatenate([rigid_acceleration(Jd_qd[c][:3], w, Jd_qd[c][3:], s[c]), Jd_qd[c][3:]])   # at C
    M_o, b_o = object_mass_matrix(model.object, obj), object_bias_wrench(model.object, obj, w, g)
    n = model.n_total
    M = np.zeros((n, n))
    h = np.zeros(n)
    for (Mm, hm, _), si in zip(dyn, sl):
        M[si, si], h[si] = Mm, hm
    M[sl[c], sl[c]] += J_o.T @ M_o @ J_o
    h[sl[c]] += J_o.T @ (M_o @ Jd_o_qd + b_o)
    Lam, Lam_dot_qd = _constraints(model, J, Jd_qd, J_o, Jd_o_qd, w, s)
    return ChainTerms(poses, J, Jd_qd, M, h, [d[0] for d in dyn], [d[1] for d in dyn], obj, J_o,
                      Jd_o_qd, v_o, M_o, b_o, s, Lam, Lam_dot_qd, Lam @ qd)


def _constraints(model, J, Jd_qd, J_o, Jd_o_qd, w, s):
    """Λ (k(r−1), n) and Λ̇θ̇ (eqs. 23–24): S (J_m θ̇_m − W_mᵀ v_o) for each m ≠ c."""
    sl, c, S = model.dof_slices, model.object.carrier, model.rows
    k = S.shape[0]
    others = _others(model)
    Lam = np.zeros((k * len(others), model.n_total))
    Lam_dot_qd = np.zeros(k * len(others))
    for row, m in enumerate(others):
        WmT = grasp_matrix(s[m]).T
        rs = slice(k * row, k * (row + 1))
        Lam[rs, sl[m]] = S @ J[m]
        Lam[rs, sl[c]] = -S @ WmT @ J_o
        a_grasp = rigid_acceleration(Jd_o_qd[:3], w, Jd_o_qd[3:], -s[m])     # grasp point m = C − s_m
        Lam_dot_qd[rs] = S @ (Jd_qd[m] - np.concatenate([a_grasp, Jd_o_qd[3:]]))
    return Lam, Lam_dot_qd


def forward_dynamics(model: Model, terms: ChainTerms, tau: np.ndarray,
                     stabilization: np.ndarray | None = None) -> ChainAcceleration:
    """θ̈ (eqs. 25–27) and the grasp wrenches for joint torques tau.

    Args:
        model: the Model (its constraint rows, carrier arm and integrator.rank_tol).
        terms: the ChainTerms at the state (`chain_terms`).
        tau: (n,) N·m (N on a prismatic joint), the stacked joint torques.
        stabilization: (k(r−1),) extra right-hand side of Λθ̈ = −Λ̇θ̇ − stabilization (Baumgarte,
            2αΛθ̇ + β²Φ); None: none.

    Returns:
        ChainAcceleration: θ̈, the grasp wrenches, the object acceleration, cond and rank of Λ𝐈⁻¹Λᵀ.

    Raises:
        ConstraintError: the closed-chain mass matrix 𝐈 is not positive definite.
    """
    # 𝐈 = L Lᵀ (LAPACK potrf: fails unless 𝐈 is positive definite) and both solves on that factor
    # (potrs; scipy's solve_triangular costs far more on these tiny matrices). Imported here: the
    # commands run the compiled engine and need not load scipy.linalg to start (DEFERRED,
    # tests/cross/test_architecture.py).
    from scipy.linalg import cho_factor, cho_solve

    try:
        factor = cho_factor(terms.M, lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        raise ConstraintError("closed-chain mass matrix is not positive definite") from None
    X = cho_solve(factor, np.column_stack([tau - terms.h, terms.Lam.T]), check_finite=False)
    x0, IinvLamT = X[:, 0], X[:, 1:]
    A = terms.Lam @ IinvLamT
    b = terms.Lam @ x0 + terms.Lam_dot_qd
    if stabilization is not None:
        b = b + stabilization
    F, cond, rank = _psd_solve(A, b, model.integrator.rank_tol)
    qdd = x0 - IinvLamT @ F
    # one step of iterative refinement on the acceleration constraint Λθ̈ = −Λ̇θ̇ (− stabilization)
    dF = _psd_solve(A, terms.Lam @ qdd + b - terms.Lam @ x0, model.integrator.rank_tol)[0]
    F, qdd = F + dF, qdd - IinvLamT @ dF
    F_e, vd_o = _grasp_wrenches(model, terms, qdd, F)
    return ChainAcceleration(qdd, F_e, vd_o, cond, rank)


def _psd_solve(A: np.ndarray, b: np.ndarray, rank_tol: float) -> tuple[np.ndarray, float, int]:
    """Minimum-norm solution of A x = b for symmetric positive semi-definite A, with the condition
    number λ_max/λ_min and the numerical rank (eigenvalues above rank_tol·λ_max)."""
    ev, V = np.linalg.eigh(A)
    top = ev[-1] if ev.size else 0.0
    keep = ev > rank_tol * top
    cond = float(top / ev[0]) if ev.size and ev[0] > 0 else float("inf")
    x = V[:, keep] @ ((V[:, keep].T @ b) / ev[keep])
    return x, cond, int(keep.sum())


def _grasp_wrenches(model: Model, terms: ChainTerms, qdd: np.ndarray, F: np.ndarray):
    """F_e (r, 6): Sᵀ F for m ≠ c; the carrier's from the object's Newton–Euler equation
    W_c F_e^c = M_o v̇_o + b_o − Σ_{m≠c} W_m F_e^m (eqs. 4–6, 11), restricted to the scene's rows."""
    S, c = model.rows, model.object.carrier
    k = S.shape[0]
    vd_o = terms.J_o @ qdd[model.dof_slices[c]] + terms.Jd_o_qd
    F_e = np.zeros((model.r, 6))
    Y = terms.M_o @ vd_o + terms.b_o
    for row, m in enumerate(_others(model)):
        F_e[m] = S.T @ F[k * row:k * (row + 1)]
        Y = Y - grasp_matrix(terms.s[m]) @ F_e[m]
    F_e[c] = S.T @ (S @ (grasp_matrix(-terms.s[c]) @ Y))  # W_c⁻¹ = W(−s_c)
    return F_e, vd_o
