"""The redundancy resolutions of the inverse dynamics (paper eqs. 28–35): the grasp wrenches f that
solve A f = y (`coopsim.inverse.problem`), one function each.

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
    Jacobian is not square or singular (the minimum-norm solution where the equations lose rank by the
    forward model's rule, the scenario's rank_tol; an InverseRankWarning says where).
  * 'bounded' — minimum energy with every component of the internal wrench (grasp-line frame,
    non-squeezing definition by default) within ± a bound: a QP (`coopsim.inverse.qp`).

The resolutions are registered in `coopsim.inverse.resolutions.RESOLUTIONS` (the kernels are here);
every reader (studies, capacity, plots, CLI) takes them from there.

Two internal-wrench definitions are reported for every resolution, both at C, per arm (rows sum to 0):
  * paper (eq. 7 with W⁺ = (1/r)[W_m⁻¹]):   F_I^m = W_m F_e^m − F_o / r;
  * non-squeezing (Erhart & Hirche):         F_I^m = W_m [(I − G⁺ᴹ W) F_e]_m, G⁺ᴹ = M* Wᵀ(W M* Wᵀ)⁻¹.
'paper' leaves zero paper-internal wrench, 'nonsqueezing' zero non-squeezing internal wrench; they
differ (the paper's shares a net force as equal forces plus opposite moments at the grasps: a bending
pair). Planar scenes report out-of-plane components as zero (carried by the bearings).
"""

from __future__ import annotations

import warnings
from enum import IntEnum
from typing import NamedTuple

import numpy as np

from coopsim.inverse.qp import solve_qps
from coopsim.forward.diagnostics import describe_state
from coopsim.inverse.stress import grasp_line_axes, line_frame
from coopsim.inverse.problem import (InverseProblem, InverseRankWarning, Resolution, SampleFailure,
                                     SampleFailureWarning, failure_text, sample_problem, torques_of)


def paper_distribution(prob: InverseProblem, y: np.ndarray) -> np.ndarray:
    """Zero internal force with the paper's W⁺ (eqs. 8, 30): f_m = S W_m⁻¹ Sᵀ y / r, W_m⁻¹ = W(−s_m).

    Args:
        prob: the InverseProblem along the trajectory (N samples, n joints, r arms, k rows S).
        y: (N, k) [N; N·m], the net object wrench S Y at C in the rows S, world axes.

    Returns:
        np.ndarray: (N, rk) the grasp wrenches f = [f_1; …; f_r] in the rows S (N, N·m), world axes.
    """
    S, r = prob.rows, prob.r
    Winv = 2 * np.eye(6) - prob.W                                  # W(−s) (N, r, 6, 6), exactly
    f = (S @ Winv @ (y @ S)[:, None, :, None])[..., 0] / r
    return f.reshape(len(y), -1)


def virtual_masses(grasp_pos: np.ndarray, mass: float, ratios: np.ndarray | None = None):
    """Virtual masses m_i* of the non-squeezing distribution and the offset of their centroid from C.

    Given `ratios`, m_i* = m_o ratios_i / Σ ratios. Otherwise the masses closest to equal shares m_o/r
    with Σ m_i* = m_o and Σ m_i* g_i = 0 (g_i the grasp positions, so the centroid is C; least squares
    when C is off the grasps' affine hull); when that needs a mass below 1 % of an equal share (C on,
    near or outside the border of the grasps' hull: an arm would be left idle) equal shares are used.
    A non-zero offset means the distribution is non-squeezing for a virtual body whose centre is not
    the object's.

    Args:
        grasp_pos: (r, 3) m, the grasp positions g_i relative to C, object frame.
        mass: kg, the object's mass m_o.
        ratios: (r,) the shares of the mass (any positive scale); None: from the grasp geometry.

    Returns:
        tuple[np.ndarray, np.ndarray]: the virtual masses m_i* (r,) kg and the offset (3,) m of their
        centroid from C, object frame.
    """
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
    """Virtual inertias J_i* = (m_i*/m_o) K_o: the object's own inertia shared like the mass.

    Args:
        masses: (r,) kg, the virtual masses m_i* (`virtual_masses`).
        mass: kg, the object's mass m_o.
        inertia: (3, 3) kg·m², the object's inertia K_o about C, object frame.

    Returns:
        np.ndarray: (r, 3, 3) kg·m², J_i*, object frame.
    """
    return masses[:, None, None] / mass * inertia[None]


def nonsqueezing_metric(prob: InverseProblem, masses: np.ndarray, inertias: np.ndarray) -> np.ndarray:
    """The non-squeezing metric M* = blockdiag(S diag(m_i* I₃, R_o J_i* R_oᵀ) Sᵀ), world axes, rows S.

    Args:
        prob: the InverseProblem along the trajectory (N samples, n joints, r arms, k rows S).
        masses: (r,) kg, the virtual masses m_i*.
        inertias: (r, 3, 3) kg·m², the virtual inertias J_i*, object frame.

    Returns:
        np.ndarray: (N, rk, rk) M* at every sample (kg and kg·m² blocks).
    """
    N, r, k, S = len(prob.t), prob.r, prob.k, prob.rows
    M = np.zeros((N, r * k, r * k))
    for i in range(r):
        B = np.zeros((N, 6, 6))
        B[:, :3, :3] = masses[i] * np.eye(3)
        B[:, 3:, 3:] = prob.R_o @ inertias[i] @ np.swapaxes(prob.R_o, 1, 2)
        M[:, i * k:(i + 1) * k, i * k:(i + 1) * k] = S @ B @ S.T
    return M


def nonsqueezing_inverse(prob: InverseProblem, Mstar: np.ndarray) -> np.ndarray:
    """G⁺ᴹ = M* Aᵀ (A M* Aᵀ)⁻¹ (Erhart & Hirche's weighted generalized inverse).

    Args:
        prob: the InverseProblem along the trajectory (N samples, n joints, r arms, k rows S).
        Mstar: (N, rk, rk) the non-squeezing metric M* (`nonsqueezing_metric`).

    Returns:
        np.ndarray: (N, rk, k) G⁺ᴹ at every sample.
    """
    MAt = Mstar @ np.swapaxes(prob.A, 1, 2)
    return MAt @ np.linalg.inv(prob.A @ MAt)


def nonsqueezing_distribution(prob: InverseProblem, y: np.ndarray, Mstar: np.ndarray) -> np.ndarray:
    """f = G⁺ᴹ y: every virtual body carries its own rigid-body load (zero non-squeezing internal wrench).

    Args:
        prob: the InverseProblem along the trajectory (N samples, n joints, r arms, k rows S).
        y: (N, k) [N; N·m], the net object wrench S Y at C in the rows S, world axes.
        Mstar: (N, rk, rk) the non-squeezing metric M* (`nonsqueezing_metric`).

    Returns:
        np.ndarray: (N, rk) the grasp wrenches f in the rows S (N, N·m), world axes.
    """
    return np.einsum("nij,nj->ni", nonsqueezing_inverse(prob, Mstar), y)


class MinEnergySetup(NamedTuple):
    """The weight-independent part of the minimum-energy distributions of s net wrenches along a trajectory.

    N samples, n joints, m = rk unknowns, c = k + #passive constraints C f = b with C = [A; P Jᵀ],
    b = [y; −P τ_arms], d = m − c free directions: every solution of C f = b is f = f_p + Z z. With
    D = Jᵀ Z and u = τ_arms + Jᵀf_p (the torques of f_p), d_j is row j of D. Sample axis last
    (vectorized over samples) except in ys.

    Attributes:
        ys: (s, N, k) [N; N·m] the net wrenches, rows S.
        fp: (m, s, N) f_p = C⁺b (minimum norm), N, N·m.
        Z: (m, d, N) an orthonormal basis of null(C).
        DD: (n, d, d, N) d_j d_jᵀ per joint j.
        Du: (n, d, s, N) d_j u_j per joint j.
        regular: (N,) bool: C has full row rank by the forward model's rule (`gram_rank`, the
            problem's rank_tol).
        passive: (n,) bool, the passive joints (τ_j = 0).
        D: (n, d, N) D = Jᵀ Z itself.
        u: (n, s, N) N·m (N on a prismatic joint), u = τ_arms + Jᵀf_p itself.
    """

    ys: np.ndarray
    fp: np.ndarray
    Z: np.ndarray
    DD: np.ndarray
    Du: np.ndarray
    regular: np.ndarray
    passive: np.ndarray
    D: np.ndarray
    u: np.ndarray


def gram_rank(sv: np.ndarray, rank_tol: float) -> np.ndarray:
    """Numerical rank of matrices from their singular values, by the forward model's rule.

    The rule for Λ𝐈⁻¹Λᵀ applied to the Gram matrix — eigenvalues σ² above rank_tol·σ_max² count.

    Args:
        sv: (…, p) the singular values of each matrix, descending.
        rank_tol: the relative eigenvalue threshold (the scenario's integrator.rank_tol).

    Returns:
        np.ndarray: (…,) int, the numerical ranks.
    """
    sq = np.asarray(sv, dtype=float) ** 2
    return np.sum(sq > rank_tol * sq[..., :1], axis=-1) if sq.shape[-1] else np.zeros(sq.shape[:-1], int)


def _constraints_of(prob: InverseProblem, ys: np.ndarray, passive: np.ndarray, idx=slice(None)):
    """C (N', c, m) = [A; P Jᵀ] and b (N', c, s) = [y; −P τ_arms] of the minimum-energy problem at the
    samples idx (N' of them), for their net wrenches ys (s, N', k)."""
    JT, ta = prob.JT[idx], prob.tau_arms[idx]
    C = np.concatenate([prob.A[idx], JT[:, passive, :]], axis=1)
    b = np.concatenate([np.moveaxis(ys, 0, 2),
                        np.broadcast_to(-ta[:, passive, None], (len(C), int(np.sum(passive)), len(ys)))], axis=1)
    return C, b


def min_energy_setup(prob: InverseProblem, ys: np.ndarray, passive: np.ndarray) -> MinEnergySetup:
    """The parts of the minimum-energy problem that do not depend on the weights.

    The particular solutions and null spaces of C f = b (an SVD of C per sample).

    Args:
        prob: the InverseProblem along the trajectory (N samples, n joints, r arms, k rows S).
        ys: (s, N, k) [N; N·m], s net object wrenches at C in the rows S, world axes.
        passive: (n,) bool, the passive joints (τ_j = 0 enforced).

    Returns:
        MinEnergySetup: f_p, Z and the per-joint products, samples on the last axis.
    """
    JT, ta = prob.JT, prob.tau_arms
    C, b = _constraints_of(prob, ys, passive)
    N, c, m = C.shape
    U, sv, Vt = np.linalg.svd(C)
    rank = min(c, m)
    regular = (c <= m) & (gram_rank(sv, prob.rank_tol) == rank)
    inv_s = np.divide(1.0, sv, out=np.zeros_like(sv), where=sv > 0)
    fp = np.swapaxes(Vt[:, :rank], 1, 2) @ (inv_s[..., None] * (np.swapaxes(U[:, :, :rank], 1, 2) @ b))
    Z = np.swapaxes(Vt[:, rank:], 1, 2)
    last = lambda x: np.ascontiguousarray(np.moveaxis(x, 0, -1))    # noqa: E731
    D = last(JT @ Z)                                                # (n, d, N)
    u = last(ta[..., None] + JT @ fp)                               # (n, s, N)
    return MinEnergySetup(ys, last(fp), last(Z), D[:, :, None] * D[:, None, :], D[:, :, None] * u[:, None, :],
                          regular, np.asarray(passive, bool), D, u)


def min_energy_solve(prob: InverseProblem, setup: MinEnergySetup, weights: np.ndarray) -> np.ndarray:
    """Minimum-energy distributions of setup.ys: f = f_p + Z z with (DᵀQD) z = −DᵀQu.

    The KKT system of eqs. 33–35 reduced to null(C), solved by Cholesky where it is certified
    well-conditioned. Where C or DᵀQD lost rank by the forward model's rule (the problem's rank_tol on
    the Gram matrices' relative eigenvalues) the minimum-norm solution is used — least squares on C's
    numerical range, then the minimum-norm minimiser of the energy (`_min_energy_min_norm`) — and an
    InverseRankWarning names the first samples' times and configurations.

    Args:
        prob: the InverseProblem along the trajectory (N samples, n joints, r arms, k rows S).
        setup: the MinEnergySetup (`min_energy_setup`).
        weights: (n,) the diagonal of Q (passive joints' entries ignored).

    Returns:
        np.ndarray: (s, N, m) the grasp wrenches f (m = rk) in the rows S (N, N·m), world axes.
    """
    Q = np.where(setup.passive, 0.0, weights)
    z, ok = _spd_solve(_weighted_sum(Q, setup.DD), -_weighted_sum(Q, setup.Du), prob.rank_tol)
    f = setup.fp + sum(setup.Z[:, a, None] * z[a] for a in range(len(z)))
    f = np.ascontiguousarray(np.moveaxis(f, 0, -1))
    _min_norm_at(prob, np.flatnonzero(~(setup.regular & ok)), setup.ys, Q, setup.passive, f)
    return f


def _min_norm_at(prob: InverseProblem, idx: np.ndarray, ys: np.ndarray, Q: np.ndarray, passive: np.ndarray,
                 f: np.ndarray) -> None:
    """f[:, i] (written) ← the minimum-norm minimum-energy distributions of ys[:, i] (s, k) at the samples
    idx (`_min_energy_min_norm`), with one InverseRankWarning naming those that lost rank."""
    lost = []
    for i in idx:
        f[:, i], ranks = _min_energy_min_norm(prob, i, ys[:, i], Q, passive)
        if ranks is not None:
            lost.append((i, "constraints rank {} of {}, energy Hessian rank {} of {}".format(*ranks)))
    _warn_rank_lost(prob, "minimum energy: the equations", lost, stacklevel=4)


def _warn_rank_lost(prob: InverseProblem, what: str, lost: list[tuple[int, str]], shown: int = 3,
                    stacklevel: int = 3) -> None:
    """An InverseRankWarning that `what` lost rank at the samples of `lost` ((index, ranks text) pairs),
    naming the first `shown` times and configurations; nothing when `lost` is empty."""
    if lost:
        where = "; ".join(f"{describe_state(prob.t[i], prob.q[i])} ({ranks})" for i, ranks in lost[:shown])
        warnings.warn(f"{what} lost rank (rank_tol {prob.rank_tol:.3g}) at {len(lost)} of {len(prob.t)} samples: "
                      f"{where}{'; ...' if len(lost) > shown else ''}; using minimum-norm grasp wrenches there",
                      InverseRankWarning, stacklevel=stacklevel)


def _weighted_sum(Q: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Σ_j Q_j X_j (X[0].shape) of X (n, ...)."""
    return (Q @ X.reshape(len(Q), -1)).reshape(X.shape[1:])


def min_energy_distribution(prob: InverseProblem, y: np.ndarray, weights: np.ndarray,
                            passive: np.ndarray) -> np.ndarray:
    """argmin_f ½ τᵀQτ, τ = τ_arms + Jᵀf, s.t. A f = y and τ_j = 0 (passive j) — eqs. 33–35.

    In the grasp wrenches: [J Q Jᵀ, Cᵀ; C, 0][f; λ] = [−J Q τ_arms; b], C = [A; P Jᵀ], b = [y; −P τ_arms],
    solved in the null space of C (`min_energy_solve`). Minimum norm where the equations lost rank.

    Args:
        prob: the InverseProblem along the trajectory (N samples, n joints, r arms, k rows S).
        y: (N, k) [N; N·m], the net object wrench S Y at C in the rows S, world axes.
        weights: (n,) the diagonal of Q.
        passive: (n,) bool, the passive joints (τ_j = 0 enforced).

    Returns:
        np.ndarray: (N, rk) the grasp wrenches f in the rows S (N, N·m), world axes.
    """
    return min_energy_solve(prob, min_energy_setup(prob, y[None], passive), weights)[0]


def _min_energy_min_norm(prob: InverseProblem, i: int, ys: np.ndarray, Q: np.ndarray, passive: np.ndarray):
    """f (s, m) at sample i for the net wrenches ys (s, k) with the numerical ranks of the forward model's
    rule (`gram_rank`, the problem's rank_tol): f_p = C⁺b on C's numerical range (least squares where
    C f = b has no exact solution), Z the rest, z = −(DᵀQD)⁺ DᵀQu on the eigenvalues of DᵀQD above
    rank_tol·λ_max — the minimum-norm minimiser of the energy (f_p ⊥ Z z). Second value: (rank of C, its
    rows, rank of DᵀQD, its size) when either lost rank, else None (only ill-conditioned for Cholesky)."""
    C, b = _constraints_of(prob, ys[:, None], passive, slice(i, i + 1))
    C, b = C[0], b[0]
    JT, ta = prob.JT[i], prob.tau_arms[i]
    U, sv, Vt = np.linalg.svd(C)
    rc = int(gram_rank(sv, prob.rank_tol))
    fp = Vt[:rc].T @ ((U[:, :rc].T @ b) / sv[:rc, None])              # (m, s)
    Z = Vt[rc:].T                                                      # (m, d)
    D = JT @ Z
    H = D.T @ (Q[:, None] * D)
    g = D.T @ (Q[:, None] * (ta[:, None] + JT @ fp))
    ev, V = np.linalg.eigh(H)
    keep = ev > prob.rank_tol * ev[-1] if len(ev) and ev[-1] > 0 else np.zeros(len(ev), bool)
    z = -V[:, keep] @ ((V[:, keep].T @ g) / ev[keep, None])
    lost = rc < C.shape[0] or int(keep.sum()) < len(ev)
    return (fp + Z @ z).T, ((rc, C.shape[0], int(keep.sum()), len(ev)) if lost else None)


def _spd_solve(H: np.ndarray, r: np.ndarray, rank_tol: float) -> tuple[np.ndarray, np.ndarray]:
    """z (d, s, N) with H z = r for symmetric H (d, d, N) and right-hand sides r (d, s, N), samples on
    the last axis: Cholesky, vectorized over the samples (entry by entry: d is small). ok (N,) bool: H
    is positive definite with every eigenvalue above rank_tol·λ_max (the forward model's rank rule),
    certified by the bound λ_max/λ_min <= trace(H)ᵈ/det(H); eigenvalues decide where the bound is not
    enough."""
    d, N = H.shape[0], H.shape[-1]
    L = [[None] * d for _ in range(d)]
    pivots = []
    for j in range(d):
        for i in range(j, d):
            acc = H[i, j].copy()
            for k in range(j):
                acc -= L[i][k] * L[j][k]
            if i == j:
                pivots.append(acc)
                L[j][j] = np.sqrt(np.where(acc > 0, acc, 1.0))
            else:
                L[i][j] = acc / L[j][j]
    z = [None] * d
    for j in range(d):
        z[j] = r[j].copy()
        for k in range(j):
            z[j] -= L[j][k] * z[k]
        z[j] /= L[j][j]
    for j in reversed(range(d)):
        for k in range(j + 1, d):
            z[j] -= L[k][j] * z[k]
        z[j] /= L[j][j]
    if d == 0:
        return np.zeros(r.shape), np.ones(N, bool)
    pd = np.all(np.array(pivots) > 0, axis=0)
    ok = pd & (rank_tol * sum(H[j, j] for j in range(d)) ** d < np.prod(pivots, axis=0))
    unsure = np.flatnonzero(pd & ~ok)
    if len(unsure):
        lam = np.linalg.eigvalsh(np.moveaxis(H[..., unsure], -1, 0))
        ok[unsure] = lam[:, 0] > rank_tol * lam[:, -1]
    return np.array(z), ok


def min_energy_torques_jacobian_form(prob: InverseProblem, y: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The paper's own form of eqs. 33–35 (square, non-singular S J_m only): τ = Q⁻¹𝒜ᵀλ, 𝒜 = A J⁻ᵀ.

    λ = (𝒜 Q⁻¹ 𝒜ᵀ)⁻¹ (𝒜 τ_arms + y) — the sign of Y that eqs. 10, 11 and 31 imply.

    Args:
        prob: the InverseProblem along the trajectory (N samples, n joints, r arms, k rows S).
        y: (N, k) [N; N·m], the net object wrench S Y at C in the rows S, world axes.
        weights: (n,) the diagonal of Q (positive).

    Returns:
        np.ndarray: (N, n) N·m (N on a prismatic joint), the joint torques τ.
    """
    Acal = prob.A @ np.linalg.inv(prob.JT)
    Qi = 1.0 / weights
    AQ = Acal * Qi[None, None, :]
    lam = np.linalg.solve(AQ @ np.swapaxes(Acal, 1, 2),
                          (np.einsum("nij,nj->ni", Acal, prob.tau_arms) + y)[..., None])[..., 0]
    return np.einsum("nji,nj->ni", AQ, lam)


def distribution_of_torques(prob: InverseProblem, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Grasp wrenches that given torques imply: [Jᵀ; A] f = [τ − τ_arms; y] in least squares.

    Where [Jᵀ; A] lost column rank by the forward model's rule (`gram_rank`, the problem's rank_tol) f
    is the minimum-norm solution and an InverseRankWarning names the first samples' times and
    configurations.

    Args:
        prob: the InverseProblem along the trajectory (N samples, n joints, r arms, k rows S).
        tau: (N, n) N·m (N on a prismatic joint), the joint torques.

    Returns:
        tuple[np.ndarray, np.ndarray]: f (N, rk) in the rows S (N, N·m), world axes, and the residual
        (N,) max |[Jᵀ; A] f − [τ − τ_arms; y]| of that system (N·m or N; zero when τ moves the chain
        along the trajectory).
    """
    M = np.concatenate([prob.JT, prob.A], axis=1)
    rhs = np.concatenate([tau - prob.tau_arms, prob.y], axis=1)
    U, s, Vt = np.linalg.svd(M, full_matrices=False)
    rank = gram_rank(s, prob.rank_tol)
    inv_s = np.divide(1.0, s, out=np.zeros_like(s), where=np.arange(s.shape[1]) < rank[:, None])
    f = np.einsum("nij,ni,nki,nk->nj", Vt, inv_s, U, rhs)
    res = np.max(np.abs(np.einsum("nij,nj->ni", M, f) - rhs), axis=1)
    _warn_rank_lost(prob, "grasp wrenches of given torques: [Jᵀ; A]",
                    [(i, f"rank {rank[i]} of {M.shape[2]}") for i in np.flatnonzero(rank < M.shape[2])])
    return f, res


def internal_operator(prob: InverseProblem, definition: str, Mstar: np.ndarray | None = None) -> np.ndarray:
    """The internal-wrench operator L: the stacked internal wrenches at C, F_I = L f, on the modelled rows.

        'paper':         F_I^m = W_m Sᵀ f_m − (1/r) Σ_j W_j Sᵀ f_j;
        'nonsqueezing':  F_I^m = W_m Sᵀ [(I − G⁺ᴹ A) f]_m.

    Args:
        prob: the InverseProblem along the trajectory (N samples, n joints, r arms, k rows S).
        definition: 'paper' or 'nonsqueezing'.
        Mstar: (N, rk, rk) the non-squeezing metric M* (needed by 'nonsqueezing'; None for 'paper').

    Returns:
        np.ndarray: (N, 6r, rk) L, world axes (arm m's [f; n] at rows 6m…6m+5).

    Raises:
        ValueError: an unknown definition.
    """
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


def internal_wrench(prob: InverseProblem, f: np.ndarray, definition: str,
                    Mstar: np.ndarray | None = None) -> np.ndarray:
    """Internal wrench at C of the distribution f by `definition` (see internal_operator).

    Args:
        prob: the InverseProblem along the trajectory (N samples, n joints, r arms, k rows S).
        f: (N, rk) the grasp wrenches in the rows S (N, N·m).
        definition: 'paper' or 'nonsqueezing'.
        Mstar: (N, rk, rk) the non-squeezing metric M* (needed by 'nonsqueezing'; None for 'paper').

    Returns:
        np.ndarray: (N, r, 6) [f; n] N, N·m, the internal wrench of each arm at C, world axes.

    Raises:
        ValueError: an unknown definition.
    """
    L = internal_operator(prob, definition, Mstar)
    return np.einsum("nij,nj->ni", L, f).reshape(len(f), prob.r, 6)


def bounded_min_energy_distribution(prob: InverseProblem, y: np.ndarray, res: Resolution, Mstar: np.ndarray,
                                    failures: list | None = None) -> np.ndarray:
    """Minimum energy with a bounded internal wrench: a QP per sample, all solved together.

    Solved by `coopsim.inverse.qp.solve_qps` (HiGHS, polished to the exact minimiser): min ½τᵀQτ
    s.t. A f = y, τ_j = 0 (passive), and for every arm m every component of its internal wrench at C
    (definition res.bound_definition) in its grasp-line frame (axial, 2 shear | torsion, 2 bending)
    within ± res.force_bound (N) | ± res.moment_bound (N·m). A sample whose QP has no solution
    (infeasible: a bound that passive joints cannot meet; or not solved) is nan, named in a
    SampleFailureWarning and appended to `failures` (SampleFailure) — the other samples are unaffected.

    Args:
        prob: the InverseProblem along the trajectory (N samples, n joints, r arms, k rows S).
        y: (N, k) [N; N·m], the net object wrench S Y at C in the rows S, world axes.
        res: the Resolution (weights, passive joints, force_bound, moment_bound, bound_definition).
        Mstar: (N, rk, rk) the non-squeezing metric M* (used by the 'nonsqueezing' bound definition).
        failures: a list the failed samples (SampleFailure) are appended to (written); None: not kept.

    Returns:
        np.ndarray: (N, rk) the grasp wrenches f in the rows S (N, N·m), world axes; nan rows where
        a sample has no solution.
    """
    rows = internal_bound_components(grasp_line_frames(prob), internal_operator(prob, res.bound_definition, Mstar),
                                     res.force_bound, res.moment_bound)
    hi = np.where(rows.keep, rows.bound, np.inf)
    sq = np.sqrt(np.where(res.passive, 0.0, res.weights))
    E = np.concatenate([prob.A, prob.JT[:, res.passive]], axis=1)
    e = np.concatenate([y, -prob.tau_arms[:, res.passive]], axis=1)
    qps = solve_qps(sq[None, :, None] * prob.JT, -sq * prob.tau_arms, E, e, rows.C, -hi, hi)
    bad = [SampleFailure(int(i), float(prob.t[i]), qps.messages[i]) for i in np.flatnonzero(~qps.ok)]
    if bad:
        warnings.warn(f"'bounded' (|internal| <= {res.force_bound:.4g} N, {res.moment_bound:.4g} N·m): no solution at "
                      f"{len(bad)} of {len(y)} samples: {failure_text([(b.time, b.reason) for b in bad])}; they are "
                      f"left out (nan)", SampleFailureWarning, stacklevel=2)
        if failures is not None:
            failures.extend(bad)
    return qps.x


class RowKind(IntEnum):
    """What an internal-wrench component row bounds: a force (N) or a moment (N·m)."""

    FORCE = 0
    MOMENT = 1


# the kind of each of an arm's six grasp-line components: axial, two shear | torsion, two bending
ARM_ROW_KINDS = np.array([RowKind.FORCE] * 3 + [RowKind.MOMENT] * 3, dtype=np.int8)


class BoundRows(NamedTuple):
    """Internal-wrench component rows (`internal_bound_components`).

    Attributes:
        C: (N, 6r, rk) the components as rows of f (axial, two shear, torsion, two bending per arm).
        kind: (6r,) RowKind values.
        bound: (6r,) N or N·m by kind.
        keep: (N, 6r) bool: the rows to bound.
    """

    C: np.ndarray
    kind: np.ndarray
    bound: np.ndarray
    keep: np.ndarray


def internal_bound_components(frames: np.ndarray, L: np.ndarray, force_bound: float = np.inf,
                              moment_bound: float = np.inf) -> BoundRows:
    """Every internal-wrench component in the grasp-line frames as rows of f, with kinds, bounds and keep.

    C (N, 6r, rk) holds arm m's axial, two shear, torsion and two bending components at rows 6m…6m+5;
    the kinds (6r,) are explicit (RowKind: the kind never has to be told from a bound value); keep
    (N, 6r) marks the rows that neither vanish (out-of-plane) nor repeat an earlier kept row of the
    same kind (parallel and of the same length: for r = 2 the two arms' are opposite).

    Args:
        frames: (N, r, 3, 3) the grasp-line frames, rows the axes in world axes (`grasp_line_frames`).
        L: (N, 6r, rk) the internal-wrench operator (`internal_operator`).
        force_bound: N, the bound of the force components.
        moment_bound: N·m, the bound of the moment components.

    Returns:
        BoundRows: C, kind, bound (force_bound N, moment_bound N·m) and keep.
    """
    N, r = frames.shape[:2]
    C = (frames[:, :, None] @ L.reshape(N, r, 2, 3, -1)).reshape(N, 6 * r, -1)
    kind = np.tile(ARM_ROW_KINDS, r)
    bound = np.where(kind == RowKind.FORCE, float(force_bound), float(moment_bound))
    norms = np.linalg.norm(C, axis=2)
    scale = np.maximum(norms.max(axis=1, keepdims=True), 1e-300)
    live = norms > 1e-12 * scale
    with np.errstate(divide="ignore", invalid="ignore"):
        u = C / norms[..., None]
    parallel = np.abs(np.abs(u @ np.swapaxes(u, 1, 2)) - 1) < 1e-12
    same_length = np.abs(norms[:, :, None] - norms[:, None, :]) <= 1e-12 * scale[..., None]
    repeats = parallel & same_length & (kind[:, None] == kind[None, :])
    keep = np.zeros((N, 6 * r), bool)
    for j in range(6 * r):
        keep[:, j] = live[:, j] & ~np.any(keep[:, :j] & repeats[:, j, :j], axis=1)
    return BoundRows(C, kind, bound, keep)


def internal_bound_rows(prob: InverseProblem, i: int, L: np.ndarray, res: Resolution):
    """Rows of the internal-wrench components at sample i in the grasp-line frames, and their bounds.

    Those `internal_bound_components` keeps.

    Args:
        prob: the InverseProblem along the trajectory (N samples, n joints, r arms, k rows S).
        i: sample index, 0-based.
        L: (6r, rk) sample i's internal operator (`internal_operator`).
        res: the Resolution (its force_bound N and moment_bound N·m).

    Returns:
        tuple[np.ndarray, np.ndarray]: the rows C (m, rk) of f and their bounds (m,) N or N·m, m the
        rows kept.
    """
    frames = line_frame(grasp_line_axes(prob.grasp_offset[i:i + 1]), prob.normal)
    rows = internal_bound_components(frames, L[None], res.force_bound, res.moment_bound)
    return rows.C[0, rows.keep[0]], rows.bound[rows.keep[0]]


def grasp_line_frames(prob: InverseProblem) -> np.ndarray:
    """Every arm's grasp-line frame along the problem's trajectory.

    `coopsim.inverse.stress.line_frame` of `coopsim.inverse.stress.grasp_line_axes` of the grasp
    offsets from C.

    Args:
        prob: the InverseProblem along the trajectory (N samples, n joints, r arms, k rows S).

    Returns:
        np.ndarray: (N, r, 3, 3) the frames' rows: axial axis (towards grasp m), shear axis, third
        axis (the plane normal in a planar scene), world axes.
    """
    return line_frame(grasp_line_axes(prob.grasp_offset), prob.normal)


# ------------------------------------------------------------------------------------------------
# The compiled pass of the linear resolutions
# ------------------------------------------------------------------------------------------------

LINEAR_ROWS = {"paper": 0, "nonsqueezing": 1, "min_energy": 2}   # method → its row in a pass's method axis


def mass_limits(a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(up, dn) (N, n) kg: per constraint lo <= a + μ b <= hi the largest and smallest μ.

    b > 0 gives (lo − a)/b <= μ <= (hi − a)/b, b < 0 the same with lo, hi exchanged, b = 0 needs
    lo <= a <= hi (up = −inf where it does not hold); nan (0/0, ∞/∞) counts as no limit.

    Args:
        a: (N, n) N·m (N on a prismatic joint), the torques at μ = 0.
        b: (N, n) N·m per kg, the torques' rate with the carried mass.
        lo, hi: (N, n) N·m, the lower and upper torque limits (±inf: none).

    Returns:
        tuple[np.ndarray, np.ndarray]: up (N, n) kg, the largest μ per constraint (+inf: no upper limit,
        −inf: none feasible), and dn (N, n) kg, the smallest (−inf: no lower limit).
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        to_hi, to_lo = (hi - a) / b, (lo - a) / b
    pos, neg = b > 0, b < 0
    up = np.where(pos, to_hi, np.where(neg, to_lo, np.inf))
    dn = np.where(pos, to_lo, np.where(neg, to_hi, -np.inf))
    up = np.where((b == 0) & ((a < lo) | (a > hi)), -np.inf, up)
    return np.where(np.isnan(up), np.inf, up), dn


def linear_pass(prob: InverseProblem, res: Resolution, ys: np.ndarray, methods, wrench_of: int | None = None,
                limits: tuple[np.ndarray, np.ndarray] | None = None, pairs=()):
    """The linear resolutions of several net wrenches at every sample, compiled (`coopsim.compiled.distributions`).

    The same distributions as `paper_distribution`, `nonsqueezing_distribution` and
    `min_energy_distribution`, the torques `torques_of`, the internal wrenches `internal_wrench` by both
    definitions and the ratio tests `mass_limits`, in one pass over the samples.
    The samples the pass leaves (the minimum-energy equations not certified of full rank and
    well-conditioned) are solved by the NumPy path, with its InverseRankWarning where they lost rank.

    Args:
        prob: the InverseProblem along the trajectory (N samples, n joints, r arms, k rows S).
        res: the Resolution whose settings are used (weights, passive joints, virtual bodies; not its method).
        ys: (s, N, k) [N; N·m], the net object wrenches S Y at C in the rows S, world axes.
        methods: the names of the linear resolutions computed (keys of LINEAR_ROWS).
        wrench_of: the index into ys whose internal wrenches are computed; None: none.
        limits: (τ_min, τ_max) (N, n) N·m, the motor lines of the ratio tests; None: no test.
        pairs: (y₀, y₀ + y₁) index pairs into ys, one ratio test each (τ(μ) = a + μ b, a = τ(y₀),
            b = τ(y₀ + y₁) − a).

    Returns:
        coopsim.compiled.api.LinearPass: per method row (LINEAR_ROWS) f (3, s, N, rk), τ (3, s, N, n),
        the internal wrenches (3, N, r, 6) of ys[wrench_of] and the ratio tests' up, dn (3, P, N, n) kg;
        rows of methods not asked for are zeros.
    """
    from coopsim.compiled import api

    ys = np.asarray(ys, dtype=float)
    N, n, m = prob.JT.shape
    which = np.array([name in methods for name in LINEAR_ROWS])
    lo, hi = limits if limits is not None else (np.zeros((N, n)), np.zeros((N, n)))
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2) if limits is not None else np.zeros((0, 2), np.int64)
    out = api.linear_pass(prob.JT, prob.A, prob.tau_arms, prob.W, prob.R_o, prob.rows, res.masses, res.inertias,
                          res.passive, res.weights, ys, which, -1 if wrench_of is None else wrench_of, lo, hi, pairs,
                          prob.rank_tol)
    for name, row in LINEAR_ROWS.items():
        idx = np.flatnonzero(out.unsure[row])
        if which[row] and len(idx):
            _numpy_rows(prob, res, ys, name, idx, out, wrench_of, lo, hi, pairs)
    return out


def _numpy_rows(prob: InverseProblem, res: Resolution, ys: np.ndarray, name: str, idx: np.ndarray, out,
                wrench_of: int | None, lo: np.ndarray, hi: np.ndarray, pairs: np.ndarray) -> None:
    """The pass's outputs of method `name` at the samples idx, written by the NumPy path."""
    row = LINEAR_ROWS[name]
    f = out.f[row]
    sub = sample_problem(prob, idx)
    if name == "min_energy":
        _min_norm_at(prob, idx, ys, np.where(res.passive, 0.0, res.weights), np.asarray(res.passive, bool), f)
    elif name == "nonsqueezing":
        Mstar = nonsqueezing_metric(sub, res.masses, res.inertias)
        f[:, idx] = [nonsqueezing_distribution(sub, y[idx], Mstar) for y in ys]
    else:
        f[:, idx] = [paper_distribution(sub, y[idx]) for y in ys]
    out.tau[row][:, idx] = [torques_of(sub, fq[idx]) for fq in f]
    if wrench_of is not None:
        out.internal_paper[row][idx] = internal_wrench(sub, f[wrench_of, idx], "paper")
        out.internal_nonsqueezing[row][idx] = internal_wrench(sub, f[wrench_of, idx], "nonsqueezing",
                                                              nonsqueezing_metric(sub, res.masses, res.inertias))
    for p, (i0, i1) in enumerate(pairs):
        a = out.tau[row, i0][idx]
        out.up[row, p][idx], out.dn[row, p][idx] = mass_limits(a, out.tau[row, i1][idx] - a, lo[idx], hi[idx])
