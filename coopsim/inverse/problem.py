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

from collections import OrderedDict
from dataclasses import dataclass, fields, replace
from typing import NamedTuple

import numpy as np

from coopsim.core.digest import content_digest
from coopsim.dynamics.grasp import grasp_matrix
from coopsim.core.model import Model
from coopsim.core.errors import ConstraintRankWarning, CoopsimError
from coopsim.core.spatial import cross, rigid_acceleration
from coopsim.inverse.trajectory import JointTrajectory


ENGINES = ("compiled", "reference")   # the inverse side's two engines: compiled passes, or the NumPy reference


def check_engine(engine: str) -> str:
    """The engine, checked.

    Args:
        engine: 'compiled' (the compiled passes over the samples) or 'reference' (the readable NumPy
            functions, which give the same numbers to rounding).

    Returns:
        str: engine.

    Raises:
        ValueError: an unknown engine.
    """
    if engine not in ENGINES:
        raise ValueError(f"unknown engine {engine!r}; expected one of {', '.join(ENGINES)}")
    return engine


class InverseError(CoopsimError):
    """The inverse dynamics cannot be resolved as asked (e.g. an infeasible bound with passive joints)."""


class InverseRankWarning(ConstraintRankWarning):
    """The equations of a resolution lost rank at some samples: the minimum-norm solution is used there.

    Rank is judged by the forward model's rule (the scenario's integrator.rank_tol on the relative
    eigenvalues of the Gram matrix, as for Λ𝐈⁻¹Λᵀ); the message names the first times and
    configurations.
    """


class SampleFailureWarning(UserWarning):
    """A resolution has no solution at some samples: they are left out (nan).

    E.g. 'bounded' with an infeasible bound. The samples are listed in InverseResult.failures; the other
    samples are exact.
    """


class SampleFailure(NamedTuple):
    """A sample a resolution could not solve.

    Attributes:
        index: the sample's index into the trajectory (0-based).
        time: s, the sample's time.
        reason: why it has no solution (e.g. 'infeasible').
    """

    index: int
    time: float
    reason: str


def failure_text(failures: list[tuple[float, str]], shown: int = 3) -> str:
    """'t=0.35 s (infeasible), …' for the first `shown` of (time, reason) pairs.

    Args:
        failures: the (time s, reason) pairs.
        shown: how many are named; ', ...' follows when there are more.

    Returns:
        str: the one-line list.
    """
    text = ", ".join(f"t={t:.6g} s ({reason})" for t, reason in failures[:shown])
    return text + (", ..." if len(failures) > shown else "")


@dataclass(frozen=True, eq=False)
class InverseProblem:
    """Per-sample terms of the inverse dynamics along a trajectory (N samples, n joints, r arms, k rows).

    World axes and SI units unless stated.

    Attributes:
        t: (N,) s, the sample times.
        q: (N, n) rad (m on a prismatic joint), the stacked joint coordinates θ.
        qd: (N, n) rad/s (m/s), θ̇.
        qdd: (N, n) rad/s² (m/s²), θ̈.
        tau_arms: (N, n) N·m (N on a prismatic joint), I_m θ̈_m + h_m stacked (eq. 29, no object).
        JT: (N, n, rk) Jᵀ = blockdiag((S J_m)ᵀ), the end-effector Jacobians in the rows S, transposed.
        A: (N, k, rk) A = [S W_1 Sᵀ … S W_r Sᵀ].
        y: (N, k) [N; N·m], y = S Y for the model's object (Y = M_o v̇_o + b_o at C).
        y_unit: (N, k) [N/kg; N·m/kg], y per kg of object mass (object scaled at constant geometry:
            Y ∝ m_o).
        y_payload: (N, k) [N/kg; N·m/kg] per kg of point payload at `payload_position` (object frame),
            or None.
        W: (N, r, 6, 6) the grasp matrices W_m (eq. 2).
        p_C: (N, 3) m, the object's centre of mass C (world, for output only).
        R_o: (N, 3, 3) the object rotation, world ← object frame.
        twist: (N, 6) [v_C (m/s); ω (rad/s)], the object's twist at C.
        acc: (N, 6) [v̇_C (m/s²); ω̇ (rad/s²)], the object's acceleration at C.
        grasp_offset: (N, r, 3) m, the grasp points relative to C (p_grasp − p_C, formed without world
            positions).
        rows: (k, 6) the constraint rows S.
        normal: (3,) the plane normal of a planar scene, or None.
        gravity: (3,) m/s².
        mass: kg, the object's mass m_o.
        inertia: (3, 3) kg·m², the object's inertia about C, object frame.
        box: (3,) m, the object's box size along the object axes (zeros: none).
        grasp_pos: (r, 3) m, the grasp points (end-effector frame origins), object frame.
        rank_tol: the scenario's integrator.rank_tol, the relative eigenvalue below which a Gram matrix of
            the equations counts as rank-deficient (as for the forward model's Λ𝐈⁻¹Λᵀ).
    """

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
        """The number of arms r."""
        return self.W.shape[1]

    @property
    def k(self) -> int:
        """The number of constraint rows k per grasp (3 planar, 6 spatial)."""
        return self.rows.shape[0]


@dataclass(frozen=True, eq=False)
class Resolution:
    """A redundancy resolution, all but the net object wrench.

    Attributes:
        method: a name in RESOLUTIONS (`coopsim.inverse.resolutions`).
        weights: (n,) the diagonal of Q (the cost ½ τᵀQτ).
        passive: (n,) bool, the passive joints (τ = 0 enforced by 'min_energy' and 'bounded').
        masses: (r,) kg, the masses of the non-squeezing virtual bodies.
        inertias: (r, 3, 3) kg·m² (object frame), the inertias of the non-squeezing virtual bodies.
        force_bound: N, the internal-force bound of 'bounded' (inf: none).
        moment_bound: N·m, the internal-moment bound of 'bounded' (inf: none).
        bound_definition: 'nonsqueezing' | 'paper', the internal wrench the bounds of 'bounded' apply to.
    """

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
    """One resolution along the trajectory (N samples, n joints, r arms, k rows), world axes.

    Attributes:
        method: the resolution's name (a key of RESOLUTIONS).
        t: (N,) s, the sample times.
        tau: (N, n) N·m (N on a prismatic joint), the joint torques.
        grasp_wrench: (N, r, 6) [N; N·m], F_e^m, applied by EE m to the object at the EE point.
        internal_paper: (N, r, 6) [N; N·m], the internal wrench at C by the paper's definition (W⁺).
        internal_nonsqueezing: (N, r, 6) [N; N·m], the internal wrench at C by the non-squeezing
            definition.
        cost: (N,) ½ τᵀQτ (N²·m²).
        f: (N, rk) [N; N·m], the grasp wrenches in the rows S, arm after arm.
        failures: the samples it could not solve (SampleFailure; every array is nan there).
    """

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


TERMS_INDEPENDENT = frozenset({"name", "duration", "torques", "motors", "mujoco", "validation", "control",
                               "inverse"})   # Model fields the per-sample terms do not read
SHARED_TERMS = 8                  # the most per-sample terms a process keeps for sharing
_shared_terms: OrderedDict[tuple[str, str], object] = OrderedDict()


def shared_inverse_problem(model: Model, traj: JointTrajectory,
                           payload_position: np.ndarray | None = None) -> InverseProblem:
    """`inverse_problem` with the compiled per-sample terms computed once per content of what determines
    them (the model less TERMS_INDEPENDENT, and the trajectory) and shared: the points of a sweep over the
    payload's position, the motors or the distributions' settings evaluate the kinematics and arm dynamics
    once. Each problem gets its own copy of the terms' arrays.

    Args:
        model: the Model.
        traj: the JointTrajectory (N samples).
        payload_position: (3,) m, object frame: a point payload's position; None: none.

    Returns:
        InverseProblem: as `inverse_problem`, equal to it bit for bit.
    """
    from coopsim.compiled import api

    key = (content_digest(model, TERMS_INDEPENDENT), content_digest(traj))
    if None in key:
        return inverse_problem(model, traj, payload_position)
    if key in _shared_terms:
        _shared_terms.move_to_end(key)
    else:
        _shared_terms[key] = api.inverse_terms(model, traj.q, traj.qd, traj.qdd)
        while len(_shared_terms) > SHARED_TERMS:
            _shared_terms.popitem(last=False)
    kept = _shared_terms[key]
    terms = kept._replace(**{k: v.copy() for k, v in kept._asdict().items() if isinstance(v, np.ndarray)})
    return inverse_problem(model, traj, payload_position, terms)


SAMPLED = ("t", "q", "qd", "qdd", "tau_arms", "JT", "A", "y", "y_unit", "y_payload", "W", "p_C", "R_o", "twist", "acc",
           "grasp_offset")   # the InverseProblem fields with one row per sample


def sample_problem(prob: InverseProblem, idx: np.ndarray) -> InverseProblem:
    """The problem at some of its samples only.

    Args:
        prob: the InverseProblem (N samples).
        idx: (N',) int, the samples kept (indices into the trajectory, in the order wanted).

    Returns:
        InverseProblem: N' samples, the same scene data (no factorisation kept).
    """
    return replace(prob, **{f.name: getattr(prob, f.name)[idx] for f in fields(prob)
                            if f.name in SAMPLED and getattr(prob, f.name) is not None})


def payload_wrench(rho: np.ndarray, twist: np.ndarray, acc: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Net wrench at C needed per kg of a point mass at ρ = p_P − p_C.

    a_P = a_C + ω̇ × ρ + ω × (ω × ρ), Y_P = [a_P − g; ρ × (a_P − g)].

    Args:
        rho: (…, 3) m, ρ = p_P − p_C, world axes.
        twist: (…, 6) [v_C (m/s); ω (rad/s)], the object's twist at C, world axes.
        acc: (…, 6) [v̇_C (m/s²); ω̇ (rad/s²)], the object's acceleration at C, world axes.
        g: (3,) m/s², gravity, world axes.

    Returns:
        np.ndarray: (…, 6) [N/kg; N·m/kg], Y_P at C, world axes.
    """
    a = rigid_acceleration(acc[..., :3], twist[..., 3:], acc[..., 3:], rho) - g
    return np.concatenate([a, cross(rho, a)], axis=-1)


def torques_of(prob: InverseProblem, f: np.ndarray) -> np.ndarray:
    """τ = τ_arms + Jᵀ f (eq. 28 solved for τ).

    Args:
        prob: the InverseProblem (N samples).
        f: (N, rk) [N; N·m], the grasp wrenches in the rows S, arm after arm, world axes.

    Returns:
        np.ndarray: (N, n) N·m (N on a prismatic joint), the joint torques.
    """
    return prob.tau_arms + np.einsum("nij,nj->ni", prob.JT, f)


def grasp_wrenches(prob: InverseProblem, f: np.ndarray) -> np.ndarray:
    """F_e^m = Sᵀ f_m for every arm.

    Args:
        prob: the InverseProblem (N samples, r arms, rows S).
        f: (N, rk) [N; N·m], the grasp wrenches in the rows S, arm after arm, world axes.

    Returns:
        np.ndarray: (N, r, 6) [N; N·m], F_e^m applied by EE m to the object at the EE point, world axes.
    """
    return np.einsum("ki,nmk->nmi", prob.rows, f.reshape(len(f), prob.r, prob.k))
