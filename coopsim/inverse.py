"""Stage 7 — inverse dynamics of the closed chain with redundancy resolution (paper eqs. 28–35).

Along a trajectory (θ, θ̇, θ̈) every arm obeys eq. 10/28, and the object Newton–Euler equations eqs. 4–6,
11 — in the rows S the scene models (k = 3 planar, 6 spatial), with f_m ∈ Rᵏ the grasp wrench of arm m
(F_e^m = Sᵀ f_m, applied by EE m to the object at the EE point, world axes) and f = [f_1; …; f_r]:

    τ = τ_arms + Jᵀ f,     τ_arms = [I_m θ̈_m + h_m]_m  (𝐈θ̈ − Re, eq. 29),  Jᵀ = blockdiag((S J_m)ᵀ),
    A f = y,               A = [S W_1 Sᵀ … S W_r Sᵀ],  y = S Y,  Y = M_o v̇_o + b_o  (eqs. 4–6, 11).

There are k(r − 1) more unknowns than equations: each choice of f is a redundancy resolution.
  * 'paper' — zero internal force with the paper's generalized inverse (eqs. 8, 30):
    F_e^m = W_m⁻¹ Y / r (every arm carries 1/r of the net wrench, moved to its own EE).
  * 'nonsqueezing' — Erhart & Hirche (IEEE T-RO 31(5), 2015): the grasps are given virtual bodies
    (mass m_i*, inertia J_i*) whose centroid is the centre of mass C; the load distribution is the
    metric-weighted generalized inverse F_e = M* Wᵀ (W M* Wᵀ)⁻¹ Y, M* = blockdiag(m_i* I₃, J_i*), which
    at C reads f_i = (m_i*/m*) f_o + m_i* [r_i×]ᵀ J*⁻¹ n_o, n_i = J_i* J*⁻¹ n_o (r_i = grasp − C,
    J* = Σ J_i* + m_i* [r_i×][r_i×]ᵀ): every virtual body gets exactly its own rigid-body load, so no
    wrench is passed between them — non-squeezing. The Moore–Penrose inverse is the special case
    M* = I, non-squeezing only when the grasp centroid is C and with unit-dependent "inertias".
    Here m_i* come from the grasp geometry (as equal as possible with centroid C, or the scenario's
    `inverse.nonsqueezing_masses`) and J_i* = (m_i*/m_o) K_o.
  * 'min_energy' — weighted minimum energy (eqs. 33–35) written in the grasp wrenches:
    min ½ τᵀQτ s.t. A f = y (and τ_j = 0 for passive joints): the KKT system
    [JQJᵀ Cᵀ; C 0][f; λ] = [−JQτ_arms; b], C = [A; P Jᵀ], b = [y; −P τ_arms] — valid for arms whose
    Jacobian is not square or singular (solved in the least-squares sense then).
  * 'bounded' — minimum energy with every component of the internal wrench (grasp-line frame,
    non-squeezing definition by default) within ± a bound: a QP (`coopsim.qp`).

Two internal-wrench definitions are reported for every resolution, both at C, per arm (rows sum to 0):
  * paper (eq. 7 with W⁺ = (1/r)[W_m⁻¹]):   F_I^m = W_m F_e^m − F_o / r;
  * non-squeezing (Erhart & Hirche):         F_I^m = W_m [(I − G⁺ᴹ W) F_e]_m, G⁺ᴹ = M* Wᵀ(W M* Wᵀ)⁻¹.
'paper' leaves zero paper-internal wrench, 'nonsqueezing' zero non-squeezing internal wrench; they
differ (the paper's shares a net force as equal forces plus opposite moments at the grasps: a bending
pair). Planar scenes report out-of-plane components as zero (carried by the bearings).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .closed_chain import chain_terms
from .grasp import grasp_matrix
from .model import CoopsimError, Model, TorqueFunction
from .qp import solve_qp
from .spatial import cross
from .stress import grasp_line_axes, line_frame
from .trajectory import JointTrajectory, trajectory_at

METHODS = ("paper", "nonsqueezing", "min_energy", "bounded")


class InverseError(CoopsimError):
    """The inverse dynamics cannot be resolved as asked (e.g. an infeasible bound with passive joints)."""


@dataclass(frozen=True, eq=False)
class InverseProblem:
    """Per-sample terms of the inverse dynamics along a trajectory (N samples, n joints, r arms, k rows).
    t (N,) s; q, qd, qdd (N, n); tau_arms (N, n) N·m = I_m θ̈_m + h_m stacked; JT (N, n, rk) =
    blockdiag((S J_m)ᵀ); A (N, k, rk) = [S W_m Sᵀ]; y (N, k) = S Y (N, N·m) for the model's object;
    y_unit (N, k) = y per kg of object mass (object scaled at constant geometry: Y ∝ m_o);
    y_payload (N, k) per kg of point payload at `payload_position` (object frame), or None;
    W (N, r, 6, 6) grasp matrices; p_C (N, 3); R_o (N, 3, 3); twist, acc (N, 6) object [v_C; ω],
    [v̇_C; ω̇]; p_grasp (N, r, 3) grasp points; rows S (k, 6); normal (3,) plane normal or None;
    gravity (3,); mass kg; inertia (3, 3) object frame; box (3,); grasp_pos (r, 3) object frame."""

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
    p_grasp: np.ndarray
    rows: np.ndarray
    normal: np.ndarray | None
    gravity: np.ndarray
    mass: float
    inertia: np.ndarray
    box: np.ndarray
    grasp_pos: np.ndarray

    @property
    def r(self) -> int:
        return self.W.shape[1]

    @property
    def k(self) -> int:
        return self.rows.shape[0]


@dataclass(frozen=True, eq=False)
class Resolution:
    """A redundancy resolution, all but the net object wrench: method (one of METHODS); weights (n,)
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
    cost (N,) ½ τᵀQτ (N²·m²); f (N, rk) grasp wrenches in the rows S."""

    method: str
    t: np.ndarray
    tau: np.ndarray
    grasp_wrench: np.ndarray
    internal_paper: np.ndarray
    internal_nonsqueezing: np.ndarray
    cost: np.ndarray
    f: np.ndarray


def inverse_problem(model: Model, traj: JointTrajectory, payload_position: np.ndarray | None = None) -> InverseProblem:
    """Evaluate the terms of eqs. 28–32 at every sample of `traj` (chain_terms per sample)."""
    S, c, g = model.rows, model.object.carrier, model.gravity
    N, n, r, k = len(traj.t), model.n_total, model.r, model.rows.shape[0]
    out = {name: np.zeros(shape) for name, shape in [
        ("tau_arms", (N, n)), ("JT", (N, n, r * k)), ("A", (N, k, r * k)), ("y", (N, k)),
        ("y_payload", (N, k)), ("W", (N, r, 6, 6)), ("p_C", (N, 3)), ("R_o", (N, 3, 3)),
        ("twist", (N, 6)), ("acc", (N, 6)), ("p_grasp", (N, r, 3))]}
    for i, (q, qd, qdd) in enumerate(zip(traj.q, traj.qd, traj.qdd)):
        T = chain_terms(model, q, qd)
        vd_o = T.J_o @ qdd[model.dof_slices[c]] + T.Jd_o_qd
        for m, sl in enumerate(model.dof_slices):
            out["tau_arms"][i, sl] = T.M_arms[m] @ qdd[sl] + T.h_arms[m]
            out["JT"][i, sl, m * k:(m + 1) * k] = (S @ T.J[m]).T
            out["W"][i, m] = grasp_matrix(T.s[m])
            out["A"][i, :, m * k:(m + 1) * k] = S @ out["W"][i, m] @ S.T
            out["p_grasp"][i, m] = T.obj.p_C - T.s[m]
        out["y"][i] = S @ (T.M_o @ vd_o + T.b_o)
        out["p_C"][i], out["R_o"][i], out["twist"][i], out["acc"][i] = T.obj.p_C, T.obj.R_o, T.v_o, vd_o
        if payload_position is not None:
            out["y_payload"][i] = S @ payload_wrench(T.obj.R_o @ payload_position, T.v_o, vd_o, g)
    obj = model.object
    return InverseProblem(traj.t, traj.q, traj.qd, traj.qdd, out["tau_arms"], out["JT"], out["A"], out["y"],
                          out["y"] / obj.mass, None if payload_position is None else out["y_payload"],
                          out["W"], out["p_C"], out["R_o"], out["twist"], out["acc"], out["p_grasp"], S,
                          None if model.plane is None else model.plane[2], g, obj.mass, obj.inertia, obj.box,
                          obj.grasp_pos)


def payload_wrench(rho: np.ndarray, twist: np.ndarray, acc: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Net wrench at C (6,) needed per kg of a point mass at ρ = p_P − p_C (world axes):
    a_P = a_C + ω̇ × ρ + ω × (ω × ρ), Y_P = [a_P − g; ρ × (a_P − g)]."""
    w, dw = twist[3:], acc[3:]
    a = acc[:3] + cross(dw, rho) + cross(w, cross(w, rho)) - g
    return np.concatenate([a, cross(rho, a)])


# ------------------------------------------------------------------------------------------------
# Distributions: f (N, rk) for a net object wrench y (N, k)
# ------------------------------------------------------------------------------------------------

def torques_of(prob: InverseProblem, f: np.ndarray) -> np.ndarray:
    """τ (N, n) = τ_arms + Jᵀ f (eq. 28 solved for τ)."""
    return prob.tau_arms + np.einsum("nij,nj->ni", prob.JT, f)


def grasp_wrenches(prob: InverseProblem, f: np.ndarray) -> np.ndarray:
    """F_e (N, r, 6) = Sᵀ f_m."""
    return np.einsum("ki,nmk->nmi", prob.rows, f.reshape(len(f), prob.r, prob.k))


def paper_distribution(prob: InverseProblem, y: np.ndarray) -> np.ndarray:
    """Zero internal force with the paper's W⁺ (eqs. 8, 30): f_m = S W_m⁻¹ Sᵀ y / r, W_m⁻¹ = W(−s_m)."""
    S, r = prob.rows, prob.r
    Winv = np.linalg.inv(prob.W)                                   # (N, r, 6, 6)
    f = np.einsum("ki,nmij,lj,nl->nmk", S, Winv, S, y) / r
    return f.reshape(len(y), -1)


def virtual_masses(grasp_pos: np.ndarray, mass: float, ratios: np.ndarray | None = None):
    """Virtual masses m_i* (r,) kg of the non-squeezing distribution and the offset (3,) m of their
    centroid from C (object frame). Given `ratios`, m_i* = m_o ratios_i / Σ ratios. Otherwise the masses
    closest to equal shares m_o/r with Σ m_i* = m_o and Σ m_i* g_i = 0 (g_i the grasp positions, so the
    centroid is C; least squares when C is off the grasps' affine hull); when that needs a mass below 1 %
    of an equal share (C on, near or outside the border of the grasps' hull: an arm would be left idle)
    equal shares are used. A non-zero offset means the distribution is non-squeezing for a virtual body
    whose centre is not the object's."""
    r = len(grasp_pos)
    if ratios is not None:
        m = mass * np.asarray(ratios, dtype=float) / np.sum(ratios)
    else:
        B = np.vstack([np.ones(r), grasp_pos.T])
        rhs = np.concatenate([[mass], np.zeros(3)])
        m0 = np.full(r, mass / r)
        m = m0 + np.linalg.lstsq(B, rhs - B @ m0, rcond=None)[0]
        if np.any(m < 0.01 * mass / r):
            m = m0
    return m, grasp_pos.T @ m / np.sum(m)


def virtual_inertias(masses: np.ndarray, mass: float, inertia: np.ndarray) -> np.ndarray:
    """J_i* (r, 3, 3) = (m_i*/m_o) K_o, object frame: the object's own inertia shared like the mass."""
    return masses[:, None, None] / mass * inertia[None]


def nonsqueezing_metric(prob: InverseProblem, masses: np.ndarray, inertias: np.ndarray) -> np.ndarray:
    """M* (N, rk, rk) = blockdiag(S diag(m_i* I₃, R_o J_i* R_oᵀ) Sᵀ), world axes, in the rows S."""
    N, r, k, S = len(prob.t), prob.r, prob.k, prob.rows
    M = np.zeros((N, r * k, r * k))
    for i in range(r):
        B = np.zeros((N, 6, 6))
        B[:, :3, :3] = masses[i] * np.eye(3)
        B[:, 3:, 3:] = prob.R_o @ inertias[i] @ np.swapaxes(prob.R_o, 1, 2)
        M[:, i * k:(i + 1) * k, i * k:(i + 1) * k] = S @ B @ S.T
    return M


def nonsqueezing_inverse(prob: InverseProblem, Mstar: np.ndarray) -> np.ndarray:
    """G⁺ᴹ (N, rk, k) = M* Aᵀ (A M* Aᵀ)⁻¹ (Erhart & Hirche's weighted generalized inverse)."""
    MAt = Mstar @ np.swapaxes(prob.A, 1, 2)
    return MAt @ np.linalg.inv(prob.A @ MAt)


def nonsqueezing_distribution(prob: InverseProblem, y: np.ndarray, Mstar: np.ndarray) -> np.ndarray:
    """f = G⁺ᴹ y: every virtual body carries its own rigid-body load (zero non-squeezing internal wrench)."""
    return np.einsum("nij,nj->ni", nonsqueezing_inverse(prob, Mstar), y)


def min_energy_distribution(prob: InverseProblem, y: np.ndarray, weights: np.ndarray,
                            passive: np.ndarray) -> np.ndarray:
    """argmin_f ½ τᵀQτ, τ = τ_arms + Jᵀf, s.t. A f = y and τ_j = 0 (passive j) — eqs. 33–35 in the grasp
    wrenches: [J Q Jᵀ, Cᵀ; C, 0][f; λ] = [−J Q τ_arms; b], C = [A; P Jᵀ], b = [y; −P τ_arms].
    Least squares (minimum norm) where the KKT matrix is singular."""
    JT, ta = prob.JT, prob.tau_arms
    Q = np.where(passive, 0.0, weights)
    H = np.einsum("nji,j,njk->nik", JT, Q, JT)
    g = np.einsum("nji,j,nj->ni", JT, Q, ta)
    Cp, bp = JT[:, passive, :], -ta[:, passive]
    C = np.concatenate([prob.A, Cp], axis=1)
    b = np.concatenate([y, bp], axis=1)
    N, m, c = H.shape[0], H.shape[1], C.shape[1]
    K = np.zeros((N, m + c, m + c))
    K[:, :m, :m], K[:, :m, m:], K[:, m:, :m] = H, np.swapaxes(C, 1, 2), C
    rhs = np.concatenate([-g, b], axis=1)
    return _kkt_solve(K, rhs)[:, :m]


def _kkt_solve(K: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve the batched systems K x = rhs; minimum-norm least squares for singular ones."""
    cond = np.linalg.cond(K)
    x = np.empty_like(rhs)
    ok = cond < 1e12
    if np.any(ok):
        x[ok] = np.linalg.solve(K[ok], rhs[ok][..., None])[..., 0]
    for i in np.flatnonzero(~ok):
        x[i] = np.linalg.lstsq(K[i], rhs[i], rcond=None)[0]
    return x


def min_energy_torques_jacobian_form(prob: InverseProblem, y: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The paper's own form of eqs. 33–35 (square, non-singular S J_m only): with 𝒜 = A J⁻ᵀ,
    τ = Q⁻¹𝒜ᵀλ, λ = (𝒜 Q⁻¹ 𝒜ᵀ)⁻¹ (𝒜 τ_arms + y) — the sign of Y that eqs. 10, 11 and 31 imply."""
    Acal = prob.A @ np.linalg.inv(prob.JT)
    Qi = 1.0 / weights
    AQ = Acal * Qi[None, None, :]
    lam = np.linalg.solve(AQ @ np.swapaxes(Acal, 1, 2),
                          (np.einsum("nij,nj->ni", Acal, prob.tau_arms) + y)[..., None])[..., 0]
    return np.einsum("nji,nj->ni", AQ, lam)


def distribution_of_torques(prob: InverseProblem, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Grasp wrenches f (N, rk) that given torques imply ([Jᵀ; A] f = [τ − τ_arms; y] in least squares)
    and the residual (N,) of that system (zero when τ moves the chain along the trajectory)."""
    M = np.concatenate([prob.JT, prob.A], axis=1)
    rhs = np.concatenate([tau - prob.tau_arms, prob.y], axis=1)
    f = np.array([np.linalg.lstsq(Mi, ri, rcond=None)[0] for Mi, ri in zip(M, rhs)])
    res = np.max(np.abs(np.einsum("nij,nj->ni", M, f) - rhs), axis=1)
    return f, res


# ------------------------------------------------------------------------------------------------
# Internal wrenches
# ------------------------------------------------------------------------------------------------

def internal_operator(prob: InverseProblem, definition: str, Mstar: np.ndarray | None = None) -> np.ndarray:
    """L (N, 6r, rk): the stacked internal wrenches at C, F_I = L f, projected on the modelled rows.
    'paper':         F_I^m = W_m Sᵀ f_m − (1/r) Σ_j W_j Sᵀ f_j;
    'nonsqueezing':  F_I^m = W_m Sᵀ [(I − G⁺ᴹ A) f]_m."""
    N, r, k, S = len(prob.t), prob.r, prob.k, prob.rows
    Wb = np.zeros((N, 6 * r, r * k))
    for m in range(r):
        Wb[:, 6 * m:6 * m + 6, m * k:(m + 1) * k] = prob.W[:, m] @ S.T
    if definition == "paper":
        L = Wb - np.tile(Wb.reshape(N, r, 6, r * k).sum(axis=1) / r, (1, r, 1))
    elif definition == "nonsqueezing":
        Gp = nonsqueezing_inverse(prob, Mstar)
        L = Wb @ (np.eye(r * k)[None] - Gp @ prob.A)
    else:
        raise ValueError(f"unknown internal-wrench definition {definition!r}")
    P = np.kron(np.eye(r), S.T @ S)
    return P[None] @ L


def internal_wrench(prob: InverseProblem, f: np.ndarray, definition: str, Mstar: np.ndarray | None = None) -> np.ndarray:
    """Internal wrench (N, r, 6) at C of the distribution f by `definition` (see internal_operator)."""
    L = internal_operator(prob, definition, Mstar)
    return np.einsum("nij,nj->ni", L, f).reshape(len(f), prob.r, 6)


def bounded_min_energy_distribution(prob: InverseProblem, y: np.ndarray, res: Resolution, Mstar: np.ndarray) -> np.ndarray:
    """Minimum energy with a bounded internal wrench (a QP per sample): min ½τᵀQτ s.t. A f = y,
    τ_j = 0 (passive), and for every arm m every component of its internal wrench at C (definition
    res.bound_definition) in its grasp-line frame (axial, 2 shear | torsion, 2 bending) within
    ± res.force_bound (N) | ± res.moment_bound (N·m). Starts from the definition's zero-internal
    distribution (feasible) unless joints are passive (then a feasibility LP)."""
    L = internal_operator(prob, res.bound_definition, Mstar)
    start = (nonsqueezing_distribution(prob, y, Mstar) if res.bound_definition == "nonsqueezing"
             else paper_distribution(prob, y))
    sq = np.sqrt(np.where(res.passive, 0.0, res.weights))
    f = np.zeros((len(y), prob.r * prob.k))
    for i in range(len(y)):
        C, bound = internal_bound_rows(prob, i, L[i], res)
        E = np.vstack([prob.A[i], prob.JT[i][res.passive]])
        e = np.concatenate([y[i], -prob.tau_arms[i][res.passive]])
        x0 = None if np.any(res.passive) else start[i]
        f[i] = solve_qp(sq[:, None] * prob.JT[i], -sq * prob.tau_arms[i], E, e, C, -bound, bound, x0=x0).x
    return f


def internal_bound_rows(prob: InverseProblem, i: int, L: np.ndarray, res: Resolution):
    """Rows C (m, rk) of the internal-wrench components in the grasp-line frames and their bounds (m,),
    without rows that vanish (out-of-plane) or repeat another (for r = 2 the two arms' are opposite)."""
    axes = grasp_line_axes(prob.p_grasp[i], prob.p_C[i])
    rows, bounds = [], []
    for m in range(prob.r):
        B = line_frame(axes[m], prob.normal)
        block = np.zeros((6, 6))
        block[:3, :3], block[3:, 3:] = B, B
        comp = block @ L[6 * m:6 * m + 6]
        for j in range(6):
            rows.append(comp[j])
            bounds.append(res.force_bound if j < 3 else res.moment_bound)
    rows, bounds = np.array(rows), np.array(bounds)
    norms = np.linalg.norm(rows, axis=1)
    keep = []
    for j in np.flatnonzero(norms > 1e-12 * max(norms.max(), 1e-300)):
        u = rows[j] / norms[j]
        if not any(abs(abs(u @ rows[i2] / norms[i2]) - 1) < 1e-12 and bounds[i2] == bounds[j] for i2 in keep):
            keep.append(j)
    return rows[keep], bounds[keep]


# ------------------------------------------------------------------------------------------------
# Resolutions along the trajectory
# ------------------------------------------------------------------------------------------------

def resolution_for(model: Model, method: str, weights: np.ndarray | None = None,
                   force_bound: float = np.inf, moment_bound: float = np.inf,
                   bound_definition: str = "nonsqueezing") -> Resolution:
    """The resolution `method` with the scenario's weights, passive flags and virtual masses."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    obj = model.object
    masses, _ = virtual_masses(obj.grasp_pos, obj.mass, model.inverse.nonsqueezing_masses)
    w = model.motors.energy_weight if weights is None else np.asarray(weights, dtype=float)
    return Resolution(method, w, model.motors.passive.astype(bool), masses,
                      virtual_inertias(masses, obj.mass, obj.inertia), force_bound, moment_bound, bound_definition)


def distribute(prob: InverseProblem, y: np.ndarray, res: Resolution) -> np.ndarray:
    """Grasp wrenches f (N, rk) of resolution `res` for the net object wrenches y (N, k)."""
    if res.method == "paper":
        return paper_distribution(prob, y)
    Mstar = nonsqueezing_metric(prob, res.masses, res.inertias)
    if res.method == "nonsqueezing":
        return nonsqueezing_distribution(prob, y, Mstar)
    if res.method == "min_energy":
        return min_energy_distribution(prob, y, res.weights, res.passive)
    if res.method == "bounded":
        return bounded_min_energy_distribution(prob, y, res, Mstar)
    raise ValueError(f"unknown method {res.method!r}")


def cost_of(tau: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """½ τᵀQτ (N,) with Q = diag(weights) (the paper's L, eq. 33)."""
    return 0.5 * np.einsum("ni,i,ni->n", tau, weights, tau)


def result_of(prob: InverseProblem, method: str, f: np.ndarray, res: Resolution) -> InverseResult:
    """Torques, grasp wrenches, both internal wrenches and cost of the distribution f."""
    Mstar = nonsqueezing_metric(prob, res.masses, res.inertias)
    tau = torques_of(prob, f)
    return InverseResult(method, prob.t, tau, grasp_wrenches(prob, f), internal_wrench(prob, f, "paper"),
                         internal_wrench(prob, f, "nonsqueezing", Mstar), cost_of(tau, res.weights), f)


def resolve(prob: InverseProblem, res: Resolution) -> InverseResult:
    """Inverse dynamics of `prob` resolved by `res` (output per sample: τ, F_e, internal wrenches, cost)."""
    return result_of(prob, res.method, distribute(prob, prob.y, res), res)


def default_bounds(prob: InverseProblem, res: Resolution, fraction: float = 0.5) -> tuple[float, float]:
    """(force N, moment N·m): `fraction` of the peak internal-wrench components (grasp-line frames,
    res.bound_definition) of the minimum-energy distribution — a bound that halves its peak stress."""
    f = min_energy_distribution(prob, prob.y, res.weights, res.passive)
    Mstar = nonsqueezing_metric(prob, res.masses, res.inertias)
    L = internal_operator(prob, res.bound_definition, Mstar)
    peak_f, peak_m = 0.0, 0.0
    for i in range(len(f)):
        C, bound = internal_bound_rows(prob, i, L[i], replace(res, force_bound=1.0, moment_bound=2.0))
        v = np.abs(C @ f[i])
        peak_f = max(peak_f, float(np.max(v[bound == 1.0], initial=0.0)))
        peak_m = max(peak_m, float(np.max(v[bound == 2.0], initial=0.0)))
    return fraction * peak_f, fraction * peak_m


def energy(result: InverseResult) -> float:
    """∫ ½τᵀQτ dt over the trajectory (trapezoidal rule), N²·m²·s."""
    return float(np.trapezoid(result.cost, result.t))


# ------------------------------------------------------------------------------------------------
# Replay: the torques of a resolution fed back through the forward dynamics
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Replay:
    """Forward simulation driven by a resolution's torques: sim (SimResult on the trajectory's sample
    times), max_angle_error rad and max_rate_error rad/s against the trajectory."""

    sim: object
    max_angle_error: float
    max_rate_error: float


def torque_function(model: Model, traj: JointTrajectory, res: Resolution) -> TorqueFunction:
    """τ(t) of resolution `res` along `traj` at any time t (relative to traj.t[0]): the trajectory's
    quintic Hermite interpolant at t, then the inverse dynamics of that single state."""
    t0 = traj.t[0]

    def fn(t: float) -> np.ndarray:
        q, qd, qdd = trajectory_at(traj, t0 + t)
        one = JointTrajectory(np.array([t0 + t]), q[None], qd[None], qdd[None], traj.source)
        prob = inverse_problem(model, one)
        return torques_of(prob, distribute(prob, prob.y, res))[0]

    return TorqueFunction(fn)


def replay(model: Model, traj: JointTrajectory, res: Resolution) -> Replay:
    """Simulate the closed chain from the trajectory's first state with the torques of `res` evaluated
    at the integrator's stage times, sampled at the trajectory's (uniform) sample times."""
    from .simulate import simulate

    dt = float(traj.t[1] - traj.t[0])
    replay_model = replace(model, torques=torque_function(model, traj, res), q0=traj.q[0], qd0=traj.qd[0],
                           duration=float(traj.t[-1] - traj.t[0]),
                           integrator=replace(model.integrator, output_dt=dt))
    sim = simulate(replay_model)
    if len(sim.t) != len(traj.t):
        raise InverseError("replay: the trajectory's samples are not evenly spaced")
    return Replay(sim, float(np.max(np.abs(sim.q - traj.q))), float(np.max(np.abs(sim.qd - traj.qd))))
