"""The inverse-dynamics problem of the closed chain along a trajectory (paper eqs. 28–32), and its
result: every arm obeys eq. 10/28 and the object Newton–Euler equations eqs. 4–6, 11 in the rows S
the scene models (k = 3 planar, 6 spatial), f_m ∈ Rᵏ the grasp wrench of arm m (F_e^m = Sᵀ f_m,
applied by EE m to the object at the EE point, world axes), f = [f_1; …; f_r]:

    τ = τ_arms + Jᵀ f,     τ_arms = [I_m θ̈_m + h_m]_m  (𝐈θ̈ − Re, eq. 29),  Jᵀ = blockdiag((S J_m)ᵀ),
    A f = y,               A = [S W_1 Sᵀ … S W_r Sᵀ],  y = S Y,  Y = M_o v̇_o + b_o  (eqs. 4–6, 11).

There are k(r − 1) more unknowns than equations: each choice of f is a redundancy resolution
(`coopsim.inverse.distributions`, registered in `coopsim.inverse.resolutions`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from coopsim.dynamics.grasp import grasp_matrix
from coopsim.core.model import Model
from coopsim.core.errors import ConstraintRankWarning, CoopsimError
from coopsim.core.spatial import cross, rigid_acceleration
from coopsim.inverse.trajectory import JointTrajectory


class InverseError(CoopsimError):
    """The inverse dynamics cannot be resolved as asked (e.g. an infeasible bound with passive joints)."""


class InverseRankWarning(ConstraintRankWarning):
    """The equations of a resolution lost rank at some samples, by the forward model's rule (the
    scenario's integrator.rank_tol on the relative eigenvalues of the Gram matrix, as for Λ𝐈⁻¹Λᵀ): the
    minimum-norm solution is used there; the message names the first times and configurations."""


class SampleFailureWarning(UserWarning):
    """A resolution has no solution at some samples (e.g. 'bounded': an infeasible bound): they are
    left out (nan) and listed in InverseResult.failures; the other samples are exact."""


class SampleFailure(NamedTuple):
    """A sample a resolution could not solve: index into the trajectory, time s, reason."""

    index: int
    time: float
    reason: str


def failure_text(failures: list[tuple[float, str]], shown: int = 3) -> str:
    """'t=0.35 s (infeasible), …' for the first `shown` of (time s, reason) pairs."""
    text = ", ".join(f"t={t:.6g} s ({reason})" for t, reason in failures[:shown])
    return text + (", ..." if len(failures) > shown else "")


@dataclass(frozen=True, eq=False)
class InverseProblem:
    """Per-sample terms of the inverse dynamics along a trajectory (N samples, n joints, r arms, k rows).
    t (N,) s; q, qd, qdd (N, n); tau_arms (N, n) N·m = I_m θ̈_m + h_m stacked; JT (N, n, rk) =
    blockdiag((S J_m)ᵀ); A (N, k, rk) = [S W_m Sᵀ]; y (N, k) = S Y (N, N·m) for the model's object;
    y_unit (N, k) = y per kg of object mass (object scaled at constant geometry: Y ∝ m_o);
    y_payload (N, k) per kg of point payload at `payload_position` (object frame), or None;
    W (N, r, 6, 6) grasp matrices; p_C (N, 3) (world, for output only); R_o (N, 3, 3); twist, acc
    (N, 6) object [v_C; ω], [v̇_C; ω̇]; grasp_offset (N, r, 3) grasp points relative to C (p_grasp − p_C,
    formed without world positions); rows S (k, 6); normal (3,) plane normal or None; gravity (3,);
    mass kg; inertia (3, 3) object frame; box (3,); grasp_pos (r, 3) object frame; rank_tol: the
    scenario's integrator.rank_tol, the relative eigenvalue below which a Gram matrix of the equations
    counts as rank-deficient (as for the forward model's Λ𝐈⁻¹Λᵀ)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau_arms: np.ndarray
    JT: np.ndarray
    A: np.ndarray
    y: np.ndarray
    y_unit: np.ndarray
    y_payload: np.ndarray | None
    W: np.ndarray
    p_C: np.ndarray
    R_o: np.ndarray
    twist: np.ndarray
    acc: np.ndarray
    grasp_offset: np.ndarray
    rows: np.ndarray
    normal: np.ndarray | None
    gravity: np.ndarray
    mass: float
    inertia: np.ndarray
    box: np.ndarray
    grasp_pos: np.ndarray
    rank_tol: float = 1e-10

    @property
    def r(self) -> int:
        return self.W.shape[1]

    @property
    def k(self) -> int:
        return self.rows.shape[0]


@dataclass(frozen=True, eq=False)
class Resolution:
    """A redundancy resolution, all but the net object wrench: method (a name in RESOLUTIONS); weights (n,)
    diagonal of Q; passive (n,) bool (τ = 0 enforced by 'min_energy' and 'bounded'); masses (r,) kg and
    inertias (r, 3, 3) kg·m² (object frame) of the non-squeezing virtual bodies; force_bound N,
    moment_bound N·m and bound_definition ('nonsqueezing' | 'paper') of 'bounded'."""

    method: str
    weights: np.ndarray
    passive: np.ndarray
    masses: np.ndarray
    inertias: np.ndarray
    force_bound: float = np.inf
    moment_bound: float = np.inf
    bound_definition: str = "nonsqueezing"


@dataclass(frozen=True, eq=False)
class InverseResult:
    """One resolution along the trajectory: t (N,) s; tau (N, n) N·m; grasp_wrench (N, r, 6) F_e^m;
    internal_paper and internal_nonsqueezing (N, r, 6) internal wrench at C by each definition;
    cost (N,) ½ τᵀQτ (N²·m²); f (N, rk) grasp wrenches in the rows S; failures: the samples it could
    not solve (SampleFailure; every array is nan there)."""

    method: str
    t: np.ndarray
    tau: np.ndarray
    grasp_wrench: np.ndarray
    internal_paper: np.ndarray
    internal_nonsqueezing: np.ndarray
    cost: np.ndarray
    f: np.ndarray
    failures: tuple = ()


def inverse_problem(model: Model, traj: JointTrajectory, payload_position: np.ndarray | None = None,
                    terms=None) -> InverseProblem:
    """The terms of eqs. 28–32 at every sample of a joint trajectory.

    Args:
        model: the Model.
        traj: the JointTrajectory (N samples).
        payload_position: (3,) m, object frame: a point payload's position, for the capacity's
            payload axis; None: none.
        terms: the compiled per-sample kinematics and arm dynamics when the caller has them (else
            `coopsim.compiled.api.inverse_terms`, batched over threads).

    Returns:
        InverseProblem: per sample τ_arms, Jᵀ, A, y and what the resolutions need (world axes, SI).
    """
    from coopsim.compiled import api

    S, g = model.rows, model.gravity
    N, r, k = len(traj.t), model.r, model.rows.shape[0]
    T = api.inverse_terms(model, traj.q, traj.qd, traj.qdd) if terms is None else terms
    JT = np.zeros((N, model.n_total, r * k))
    for m, sl in enumerate(model.dof_slices):
        JT[:, sl, m * k:(m + 1) * k] = np.swapaxes(S @ T.J[:, m, :, :sl.stop - sl.start], 1, 2)
    W = grasp_matrix(T.s)
    A = np.concatenate([S @ W[:, m] @ S.T for m in range(r)], axis=2)
    y_payload = None
    if payload_position is not None:
        rho = T.R_o @ np.asarray(payload_position, dtype=float)
        y_payload = payload_wrench(rho, T.twist, T.acc, g) @ S.T
    obj = model.object
    y = T.Y @ S.T
    return InverseProblem(traj.t, traj.q, traj.qd, traj.qdd, T.tau_arms, JT, A, y, y / obj.mass, y_payload,
                          W, T.p_C, T.R_o, T.twist, T.acc, -T.s, S,
                          None if model.plane is None else model.plane[2], g, obj.mass, obj.inertia, obj.box,
                          obj.grasp_pos, model.integrator.rank_tol)


def payload_wrench(rho: np.ndarray, twist: np.ndarray, acc: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Net wrench at C (…, 6) needed per kg of a point mass at ρ = p_P − p_C (…, 3) (world axes; twist,
    acc (…, 6)): a_P = a_C + ω̇ × ρ + ω × (ω × ρ), Y_P = [a_P − g; ρ × (a_P − g)]."""
    a = rigid_acceleration(acc[..., :3], twist[..., 3:], acc[..., 3:], rho) - g
    return np.concatenate([a, cross(rho, a)], axis=-1)


def torques_of(prob: InverseProblem, f: np.ndarray) -> np.ndarray:
    """τ (N, n) = τ_arms + Jᵀ f (eq. 28 solved for τ)."""
    return prob.tau_arms + np.einsum("nij,nj->ni", prob.JT, f)


def grasp_wrenches(prob: InverseProblem, f: np.ndarray) -> np.ndarray:
    """F_e (N, r, 6) = Sᵀ f_m."""
    return np.einsum("ki,nmk->nmi", prob.rows, f.reshape(len(f), prob.r, prob.k))
