"""Stage 9 — dynamic load carrying capacity (DLCC, paper sec. 3.3, eq. 36) and beyond.

Along a fixed trajectory the net object wrench is affine in the carried mass μ:
  * 'scaled': the object scaled at constant geometry (density × μ/m_o): Y = μ Y/m_o (M_o, b_o ∝ m_o);
  * 'payload': a point payload of mass μ at a fixed point of the object: Y = Y_o + μ Y_P.
Every resolution whose distribution is linear in the net wrench (those the registry
`coopsim.inverse.resolutions.RESOLUTIONS` marks linear: 'paper', 'nonsqueezing', 'min_energy' — with fixed virtual
bodies and weights) therefore gives torques τ(μ) = a + μ b, and the
motor lines of eq. 36,
    τ_min(θ̇) = −τ_s − (τ_s/ω_s) θ̇  <=  τ  <=  τ_max(θ̇) = τ_s − (τ_s/ω_s) θ̇,
cut μ to an interval per joint and sample. The capacity is the upper end of their intersection, in
closed form (no bisection); the constraint that sets it names the motor that saturates first and when.

Beyond the paper:
  * `lp_capacity`: the largest μ for which *some* distribution f with A f = y(μ) keeps every torque
    within its lines — a linear program per sample (HiGHS, all samples in one block-diagonal LP); the
    capacity is the smallest over the samples. It bounds every resolution's capacity from above (each
    resolution is one such f).
  * `optimise_weights`: the energy weights Q that maximise the minimum-energy capacity (the paper's
    closing suggestion), by Nelder–Mead on log Q from equal weights and from the paper's heuristic.
  * `energy_stress_curve`: energy of the bounded-internal-wrench minimum-energy QP against its bound.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from coopsim.core.model import Model, Motors, torque_limits
from coopsim.inverse.distributions import (
    LINEAR_ROWS,
    MinEnergySetup,
    grasp_line_frames,
    internal_bound_components,
    internal_operator,
    linear_pass,
    mass_limits,
    min_energy_setup,
    min_energy_solve,
)
from coopsim.inverse.problem import InverseProblem, Resolution, inverse_problem, torques_of
from coopsim.inverse.qp import LPBatch, QPError, solve_lps
from coopsim.inverse.resolutions import LINEAR_METHODS, resolution_method
from coopsim.inverse.solve import compiled_engine, distribute, energy, nan_peak, resolve

MODES = ("scaled", "payload")


@dataclass(frozen=True)
class Capacity:
    """Dynamic load carrying capacity (DLCC) along a trajectory, and the motor that saturates first.

    Attributes:
        mass: kg, the largest carried mass (the whole object's for 'scaled', the payload's for
            'payload'; inf: unbounded).
        lower: kg, the smallest carried mass (0 unless the motors cannot move a lighter load).
        feasible: lower <= mass.
        joint: stacked index of the motor that saturates first (at `mass`); None where the mass is not
            finite (or, for the LP bound, no motor line binds).
        sample: index of the sample at which it saturates; None likewise.
        time: s, the time of that sample; None likewise.
        side: 'upper' (the τ_max line) or 'lower' (the τ_min line); None likewise.
        note: why it is infeasible, if so ("" otherwise).
        per_sample: (N,) kg, the largest mass each sample alone allows (the capacity is their minimum
            when every sample allows 0); not compared, not in the repr.
    """

    mass: float
    lower: float
    feasible: bool
    joint: int | None
    sample: int | None
    time: float | None
    side: str | None
    note: str = ""
    per_sample: np.ndarray | None = field(default=None, compare=False, repr=False)


def nominal_mass(model: Model, mode: str) -> float:
    """kg, the carried mass μ of the bare object: the object's mass in the 'scaled' mode (μ the whole
    object's), 0 in the 'payload' mode (μ the payload's).

    Args:
        model: the Model.
        mode: 'scaled' or 'payload'.

    Returns:
        float: kg.
    """
    return float(model.object.mass) if mode == "scaled" else 0.0


def mass_line(prob: InverseProblem, mode: str) -> tuple[np.ndarray, np.ndarray]:
    """(y₀, y₁) (N, k): the net object wrench is y₀ + μ y₁ for carried mass μ.

    'scaled': y₀ = 0, y₁ = y per kg of object mass (the object scaled at constant geometry);
    'payload': y₀ = the nominal object's y, y₁ = y per kg of point payload.

    Args:
        prob: the InverseProblem (N samples, k rows S); 'payload' needs it built with a payload
            position.
        mode: 'scaled' or 'payload'.

    Returns:
        tuple[np.ndarray, np.ndarray]: y₀ (N, k) [N; N·m] and y₁ (N, k) [N; N·m] per kg, net object
        wrenches at C in the rows S, world axes.

    Raises:
        ValueError: an unknown mode, or 'payload' on a problem without a payload position.
    """
    if mode == "scaled":
        return np.zeros_like(prob.y), prob.y_unit
    if mode == "payload":
        if prob.y_payload is None:
            raise ValueError("payload capacity needs the problem built with a payload position")
        return prob.y, prob.y_payload
    raise ValueError(f"unknown capacity mode {mode!r}; expected one of {', '.join(MODES)}")


def affine_torques(prob: InverseProblem, res: Resolution, mode: str,
                   engine: str = "compiled") -> tuple[np.ndarray, np.ndarray]:
    """(a, b) (N, n): τ(μ) = a + μ b for resolution `res` (two evaluations, exact for linear ones).

    Args:
        prob: the InverseProblem (N samples, n joints).
        res: the Resolution (linear in the net object wrench for the result to be exact).
        mode: 'scaled' or 'payload' (`mass_line`).
        engine: 'compiled' (one pass for both evaluations) or 'reference' (`coopsim.inverse.problem.ENGINES`).

    Returns:
        tuple[np.ndarray, np.ndarray]: a (N, n) N·m, the torques at μ = 0, and b (N, n) N·m per kg (N
        and N per kg on a prismatic joint).
    """
    y0, y1 = mass_line(prob, mode)
    if compiled_engine(engine, res.method):
        tau = linear_pass(prob, res, np.stack([y0, y0 + y1]), (res.method,)).tau[LINEAR_ROWS[res.method]]
        return tau[0], tau[1] - tau[0]
    a = torques_of(prob, distribute(prob, y0, res, engine=engine))
    return a, torques_of(prob, distribute(prob, y0 + y1, res, engine=engine)) - a


def mass_interval(up: np.ndarray, dn: np.ndarray) -> tuple[float, float, bool]:
    """(mass, lower, feasible) of the per-constraint limits (N, n).

    The largest mass is min(up), the smallest max(0, max(dn)); feasible: lower <= mass (an infinite
    mass: feasible when +inf).

    Args:
        up: (N, n) kg, the largest μ per constraint (`mass_limits`).
        dn: (N, n) kg, the smallest μ per constraint.

    Returns:
        tuple[float, float, bool]: mass kg, lower kg and feasible.
    """
    mass, lower = float(np.min(up)), max(0.0, float(np.max(dn)))
    return mass, lower, (lower <= mass) if np.isfinite(mass) else mass > 0


def affine_capacity(a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray, t: np.ndarray,
                    joints: np.ndarray | None = None) -> Capacity:
    """Closed-form capacity of τ(μ) = a + μ b within lo <= τ <= hi, μ >= 0, from `mass_limits`.

    Args:
        a: (N, n) N·m (N on a prismatic joint), the torques at μ = 0.
        b: (N, n) N·m per kg, the torques' rate with the carried mass.
        lo, hi: (N, n) N·m, the motor lines τ_min, τ_max at the samples (eq. 36).
        t: (N,) s, the sample times.
        joints: (n,) bool, the joints whose limits count; None: all.

    Returns:
        Capacity: the mass interval, the first motor to saturate (stacked index, sample, time, side)
        and the per-sample largest masses (N,) kg.
    """
    sel = np.ones(a.shape[1], bool) if joints is None else joints
    up, dn = mass_limits(a[:, sel], b[:, sel], lo[:, sel], hi[:, sel])
    return limits_capacity(up, dn, b[:, sel], t, np.flatnonzero(sel))


def limits_capacity(up: np.ndarray, dn: np.ndarray, b: np.ndarray, t: np.ndarray, joints: np.ndarray) -> Capacity:
    """The Capacity of per-constraint mass limits (`mass_limits`) over some joints.

    Args:
        up: (N, n') kg, the largest μ per sample and counted joint.
        dn: (N, n') kg, the smallest.
        b: (N, n') N·m per kg, the torques' rate with the carried mass at those joints (the side).
        t: (N,) s, the sample times.
        joints: (n',) int, the stacked indices of the counted joints.

    Returns:
        Capacity: the mass interval, the first motor to saturate (stacked index, sample, time, side)
        and the per-sample largest masses (N,) kg.
    """
    mass, lower, feasible = mass_interval(up, dn)
    i, j = np.unravel_index(int(np.argmin(up)), up.shape)
    side = "upper" if b[i, j] > 0 else "lower"
    per_sample = np.min(up, axis=1)
    if not np.isfinite(mass):
        return Capacity(mass, lower, feasible, None, None, None, None,
                        "" if mass > 0 else "a torque is outside its limits at every mass", per_sample)
    return Capacity(mass, lower, feasible, int(joints[j]), int(i), float(t[i]), side,
                    "" if feasible else "no mass keeps every torque within its limits", per_sample)


def method_capacity(prob: InverseProblem, res: Resolution, motors: Motors, mode: str = "scaled",
                    passive_tol: float = 1e-9, engine: str = "compiled") -> Capacity:
    """DLCC of resolution `res` in closed form (eq. 36), for the resolutions linear in the net object wrench.

    Those are the ones the registry marks linear (`coopsim.inverse.resolutions.LINEAR_METHODS`); any
    other ('bounded') is refused with the registry's reason: its torques are a nonlinear function of the
    carried mass, which the two-point affine fit would silently get wrong. Passive joints must carry no
    torque: 'min_energy' enforces it; for the others a passive torque above passive_tol makes it
    infeasible.

    Args:
        prob: the InverseProblem (N samples, n joints).
        res: the Resolution (its method, weights, passive joints and virtual bodies).
        motors: the Motors (stall torques τ_s and no-load speeds ω_s of eq. 36).
        mode: 'scaled' (object mass) or 'payload' (point payload mass).
        passive_tol: N·m (N on a prismatic joint), the largest passive-joint torque (or its rate per kg)
            tolerated.
        engine: 'compiled' (`linear_study`) or 'reference' (`coopsim.inverse.problem.ENGINES`).

    Returns:
        Capacity: over the active joints; infeasible (note says why) when a resolution other than
        'min_energy' puts torque on passive joints.

    Raises:
        ValueError: a resolution that is not linear in the net object wrench, or an unknown mode.
    """
    _check_linear(res.method)
    if compiled_engine(engine, res.method):
        return linear_study(prob, res, (res.method,), motors, (mode,), passive_tol).caps[res.method, mode]
    a, b = affine_torques(prob, res, mode, engine)
    lo, hi = torque_limits(motors, prob.qd)
    return _passive_checked(affine_capacity(a, b, lo, hi, prob.t, ~res.passive), res, a, b, passive_tol)


def _check_linear(name: str) -> None:
    """Raise the registry's reason when resolution `name` has no closed-form capacity."""
    method = resolution_method(name)
    if not method.linear:
        raise ValueError(f"method_capacity: resolution {name!r} has no closed-form capacity: "
                         f"{method.nonlinear_why} (closed form for {', '.join(LINEAR_METHODS)}; lp_capacity with "
                         f"internal_bound bounds every distribution within the bounds)")


def _passive_checked(cap: Capacity, res: Resolution, a: np.ndarray, b: np.ndarray, passive_tol: float) -> Capacity:
    """cap, made infeasible where a resolution other than 'min_energy' puts torque (a + μ b) on passive joints."""
    passive = res.passive
    if np.any(passive) and res.method != "min_energy":
        if np.max(np.abs(a[:, passive])) > passive_tol or np.max(np.abs(b[:, passive])) > passive_tol:
            return replace(cap, feasible=False, note=f"'{res.method}' puts torque on passive joints")
    return cap


class LinearStudy(NamedTuple):
    """The linear resolutions' torques and closed-form capacities from one compiled pass (`linear_study`).

    Attributes:
        torques: {method: τ (N, n) N·m at the nominal net wrench prob.y}.
        caps: {(method, mode): Capacity}, as `method_capacity` gives it.
        affine: {(method, mode): (a, b)}, as `affine_torques` gives them (N, n) N·m and N·m per kg.
    """

    torques: dict
    caps: dict
    affine: dict


def linear_study(prob: InverseProblem, res: Resolution, methods, motors: Motors, modes,
                 passive_tol: float = 1e-9) -> LinearStudy:
    """Torques and closed-form capacities of linear resolutions in several modes, in one compiled pass.

    The net wrenches prob.y and each mode's y₀, y₀ + y₁ (`mass_line`) distributed by every method, the
    torques and the ratio tests against the motor lines in one pass over the samples
    (`coopsim.inverse.distributions.linear_pass`); the same numbers as `resolve`, `affine_torques` and
    `method_capacity` of each (method, mode).

    Args:
        prob: the InverseProblem (N samples, n joints).
        res: the Resolution whose settings every method uses (weights, passive joints, virtual bodies).
        methods: the linear resolutions (names in `coopsim.inverse.resolutions.LINEAR_METHODS`).
        motors: the Motors (eq. 36 lines).
        modes: the capacity modes ('scaled', 'payload').
        passive_tol: N·m (N on a prismatic joint), the largest passive-joint torque tolerated
            (`method_capacity`).

    Returns:
        LinearStudy: the torques at the nominal mass, the Capacity and (a, b) of every (method, mode).

    Raises:
        ValueError: a resolution that is not linear, or an unknown mode.
    """
    for name in methods:
        _check_linear(name)
    lines = [mass_line(prob, mode) for mode in modes]
    ys = np.stack([prob.y] + [y for y0, y1 in lines for y in (y0, y0 + y1)])
    lo, hi = torque_limits(motors, prob.qd)
    pairs = [(1 + 2 * p, 2 + 2 * p) for p in range(len(modes))]
    out = linear_pass(prob, res, ys, methods, limits=(lo, hi), pairs=pairs)
    act = np.flatnonzero(~res.passive)
    torques, caps, affine = {}, {}, {}
    for name in methods:
        row, one = LINEAR_ROWS[name], replace(res, method=name)
        torques[name] = out.tau[row, 0]
        for p, mode in enumerate(modes):
            a = out.tau[row, 1 + 2 * p]
            b = out.tau[row, 2 + 2 * p] - a
            cap = limits_capacity(out.up[row, p][:, act], out.dn[row, p][:, act], b[:, act], prob.t, act)
            caps[name, mode], affine[name, mode] = _passive_checked(cap, one, a, b, passive_tol), (a, b)
    return LinearStudy(torques, caps, affine)


# ------------------------------------------------------------------------------------------------
# Beyond the paper
# ------------------------------------------------------------------------------------------------

def lp_capacity(prob: InverseProblem, motors: Motors, passive: np.ndarray, mode: str = "scaled",
                internal_bound: tuple[float, float] | None = None, Mstar: np.ndarray | None = None,
                definition: str = "nonsqueezing", zero_feasible: bool = False) -> Capacity:
    """Capacity over all distributions: per sample the largest μ for which some f keeps every torque within its lines.

    Per sample the LP max μ s.t. A f − μ y₁ = y₀, τ_min <= τ_arms + Jᵀ f <= τ_max (active joints),
    Jᵀf = −τ_arms (passive rows), μ >= 0, and with `internal_bound` every internal-wrench component
    (grasp-line frames, `definition`) within ±bound; the capacity is the smallest per-sample maximum.
    The per-sample feasible sets are intervals, so their intersection is [max lower, min upper]: the
    lower ends are 0 when `zero_feasible`, else found by a second LP. All samples' LPs are solved
    together (`coopsim.inverse.qp.solve_lps`). The motor reported is the one whose line has the largest
    dual value at the binding sample (its LP solved alone).

    Args:
        prob: the InverseProblem (N samples, n joints, r arms, k rows S).
        motors: the Motors (eq. 36 lines).
        passive: (n,) bool, the passive joints (zero torque enforced).
        mode: 'scaled' or 'payload' (`mass_line`).
        internal_bound: (force N, moment N·m) bounds of the internal-wrench components; None: no bound.
        Mstar: (N, rk, rk) the non-squeezing metric M* (`nonsqueezing_metric`), needed with
            internal_bound and definition 'nonsqueezing'.
        definition: the internal wrench the bounds apply to, 'nonsqueezing' or 'paper'.
        zero_feasible: a resolution is known to be feasible at μ = 0 (the lower ends are then 0, no
            second LP).

    Returns:
        Capacity: mass and lower kg, the binding sample and time, the motor with the largest dual value
        (None when no motor line binds) and per_sample (N,) kg the per-sample maxima (inf: unbounded,
        −inf: infeasible).

    Raises:
        QPError: HiGHS fails on a sample (neither optimal, infeasible nor unbounded).
    """
    A_ub, b_ub, A_eq, b_eq = _lp_rows(prob, motors, passive, mode, internal_bound, Mstar, definition)
    N, m = len(prob.t), prob.r * prob.k
    bounds = [(None, None)] * m + [(0, None)]
    c = np.zeros(m + 1)
    c[-1] = -1.0
    top = solve_lps(c, A_ub, b_ub, A_eq, b_eq, bounds)
    failed = np.flatnonzero(~np.isin(top.status, (0, 2, 3)))
    if len(failed):
        raise QPError(f"capacity LP bound: HiGHS failed at t={prob.t[failed[0]]:.6g} s: "
                      f"{' '.join(str(top.messages[failed[0]]).split())}")
    upper = np.select([top.status == 0, top.status == 3], [top.x[:, -1], np.inf], -np.inf)
    lower = np.zeros(N)
    solved = np.flatnonzero(top.status == 0)
    if not zero_feasible and len(solved):
        low = solve_lps(-c, A_ub[solved], b_ub[solved], A_eq[solved], b_eq[solved], bounds)
        lower[solved] = np.where(low.status == 0, low.x[:, -1], np.inf)
    i = int(np.argmin(upper))
    mass, low = float(upper[i]), float(np.max(lower))
    feasible = low <= mass
    if not np.isfinite(mass):
        return Capacity(mass, low, mass > 0, None, None, None, None, "" if mass > 0 else "infeasible LP", upper)
    alone = solve_lps(c, A_ub[i:i + 1], b_ub[i:i + 1], A_eq[i:i + 1], b_eq[i:i + 1], bounds, cap=np.inf)
    j, side = _binding_motor(alone, ~passive)
    return Capacity(mass, low, feasible, j, i, float(prob.t[i]), side,
                    "" if feasible else "no mass is feasible at every sample", upper)


def least_excess(tau_arms: np.ndarray, JT: np.ndarray, A: np.ndarray, y: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 stall: np.ndarray, passive: np.ndarray) -> LPBatch:
    """Per point the grasp wrenches f with A f = y and zero passive torques whose torques τ = τ_arms + Jᵀ f leave
    their motor lines least: min e s.t. τ_j − τ_max,j <= e τ_s,j and τ_min,j − τ_j <= e τ_s,j (active joints with
    a finite τ_s), one small LP per point (`coopsim.inverse.qp.solve_lps`).

    Args:
        tau_arms: (N, n) N·m (N), the arms' own torques (no object).
        JT: (N, n, rk) Jᵀ, the end-effector Jacobians in the rows S, transposed.
        A: (N, k, rk) the grasp-matrix rows.
        y: (N, k) [N; N·m], the net object wrench.
        lo, hi: (N, n) N·m (N), the motor lines τ_min, τ_max of eq. 36 at the points' joint rates.
        stall: (n,) N·m (N), τ_s (inf: no limit).
        passive: (n,) bool, the passive joints (zero torque).

    Returns:
        LPBatch: per point x = [f (rk) N, N·m; e] (e relative to τ_s; ≤ 0: within every line) and its status.
    """
    N, rk = JT.shape[0], JT.shape[2]
    j = np.flatnonzero(~passive & np.isfinite(stall))
    ts = np.broadcast_to(stall[j], (N, len(j)))[:, :, None]
    A_ub = np.concatenate([np.concatenate([JT[:, j], -ts], 2), np.concatenate([-JT[:, j], -ts], 2)], 1)
    b_ub = np.concatenate([hi[:, j] - tau_arms[:, j], tau_arms[:, j] - lo[:, j]], 1)
    A_eq = np.concatenate([A, JT[:, passive, :]], 1)
    A_eq = np.concatenate([A_eq, np.zeros((N, A_eq.shape[1], 1))], 2)
    b_eq = np.concatenate([y, -tau_arms[:, passive]], 1)
    c = np.zeros(rk + 1)
    c[-1] = 1.0
    return solve_lps(c, A_ub, b_ub, A_eq, b_eq, [(None, None)] * (rk + 1))


def _lp_rows(prob: InverseProblem, motors: Motors, passive: np.ndarray, mode: str,
             internal_bound: tuple[float, float] | None, Mstar: np.ndarray | None, definition: str):
    """Per-sample LP rows in the unknowns [f; μ] (m + 1): A_ub (N, rows, m + 1), b_ub (N, rows) — the
    τ_max rows of the active joints, then their τ_min rows, then with `internal_bound` the internal
    components' upper and lower rows (rows with an infinite bound, or left out by
    `internal_bound_components`, carry b_ub = inf) — and A_eq (N, k + #passive, m + 1), b_eq."""
    y0, y1 = mass_line(prob, mode)
    lo, hi = torque_limits(motors, prob.qd)
    act = ~passive
    JT, ta = prob.JT, prob.tau_arms
    rows, rhs = [JT[:, act] if not np.all(act) else JT], [hi[:, act] - ta[:, act], ta[:, act] - lo[:, act]]
    if internal_bound is not None:
        comp = internal_bound_components(grasp_line_frames(prob), internal_operator(prob, definition, Mstar),
                                         *internal_bound)
        bound = np.where(comp.keep, comp.bound, np.inf)
        rows, rhs = rows + [comp.C], rhs + [bound, bound]
    A_ub = np.zeros((len(JT), 2 * sum(block.shape[1] for block in rows), JT.shape[2] + 1))
    at = 0
    for block in rows:                            # each block's upper rows, then its lower (negated) rows
        A_ub[:, at:at + block.shape[1], :-1] = block
        np.negative(block, out=A_ub[:, at + block.shape[1]:at + 2 * block.shape[1], :-1])
        at += 2 * block.shape[1]
    zero = np.zeros((len(JT), int(passive.sum()), 1))
    A_eq = np.concatenate([np.concatenate([prob.A, -y1[:, :, None]], axis=2),
                           np.concatenate([JT[:, passive], zero], axis=2)], axis=1)
    return A_ub, np.concatenate(rhs, axis=1), A_eq, np.concatenate([y0, -ta[:, passive]], axis=1)


def _binding_motor(lp: LPBatch, act: np.ndarray) -> tuple[int | None, str | None]:
    """(stacked joint, 'upper' | 'lower') of the motor line with the largest dual value in a one-sample
    LP solution (τ_max rows of the active joints first, then τ_min rows); (None, None) if all are 0."""
    marg = np.abs(lp.marginals[0, :2 * act.sum()])
    if not np.any(marg > 0):
        return None, None
    k = int(np.argmax(marg))
    return int(np.flatnonzero(act)[k % act.sum()]), ("lower" if k >= act.sum() else "upper")


def min_energy_affine_torques(prob: InverseProblem, setup: MinEnergySetup, weights: np.ndarray):
    """(a, b) (N, n): the minimum-energy torques τ(μ) = a + μ b for the weights.

    Args:
        prob: the InverseProblem (N samples, n joints).
        setup: the MinEnergySetup of the two net wrenches y₀ and y₀ + y₁ of `mass_line`
            (`min_energy_setup`).
        weights: (n,) the diagonal of Q.

    Returns:
        tuple: a (N, n) N·m, the torques at μ = 0, and b (N, n) N·m per kg (N, N per kg on a prismatic
        joint).
    """
    f0, f1 = min_energy_solve(prob, setup, weights)
    a = torques_of(prob, f0)
    return a, torques_of(prob, f1) - a


def min_energy_interval(prob: InverseProblem, setup: MinEnergySetup, weights: np.ndarray, lo: np.ndarray,
                        hi: np.ndarray, act: np.ndarray) -> tuple[float, float, bool]:
    """`mass_interval` (mass, lower, feasible) of the minimum-energy torques for the weights.

    Compiled (`coopsim.compiled.capacity`, one pass over the samples), or through
    `min_energy_affine_torques` where that is not certified (rank lost or an ill-conditioned energy
    Hessian somewhere).

    Args:
        prob: the InverseProblem (N samples, n joints).
        setup: the MinEnergySetup of the two net wrenches y₀ and y₀ + y₁ of `mass_line`.
        weights: (n,) the diagonal of Q (passive joints' entries ignored).
        lo, hi: (N, n) N·m, the motor lines τ_min, τ_max at the samples.
        act: (n,) bool, the joints whose limits count.

    Returns:
        tuple[float, float, bool]: mass kg, lower kg and feasible.
    """
    from coopsim.compiled.api import announce_compile
    from coopsim.compiled.capacity import min_energy_mass_interval

    announce_compile("extras")
    mass, lower, certain = min_energy_mass_interval(setup.D, setup.u, np.where(setup.passive, 0.0, weights),
                                                    lo, hi, act, setup.regular, prob.rank_tol)
    if certain:
        return mass, lower, (lower <= mass) if np.isfinite(mass) else mass > 0
    a, b = min_energy_affine_torques(prob, setup, weights)
    return mass_interval(*mass_limits(a[:, act], b[:, act], lo[:, act], hi[:, act]))


def optimise_weights(prob: InverseProblem, res: Resolution, motors: Motors, mode: str = "scaled",
                     max_evals: int = 400) -> tuple[np.ndarray, Capacity]:
    """Energy weights (n,) maximising the minimum-energy capacity, with that capacity.

    Weights are scale-free: normalised to a geometric mean of 1 over the active joints. Nelder–Mead on
    log-weights (clipped to ±ln 10⁴) from equal weights, from the paper's suggestion (weight ×10 on the
    motor that saturates first) and from `res.weights` when they are not all equal (the scenario's
    `energy_weights`); the best is kept. The weight-independent part of the minimum-energy problem
    (`min_energy_setup`, both net wrenches y₀ and y₀ + y₁) is set up once; each evaluation is one
    compiled pass over the samples (`min_energy_interval`).

    Args:
        prob: the InverseProblem (N samples, n joints).
        res: the Resolution (its passive joints and its weights as a starting point).
        motors: the Motors (eq. 36 lines).
        mode: 'scaled' or 'payload' (`mass_line`).
        max_evals: the most objective evaluations of each Nelder–Mead run.

    Returns:
        tuple[np.ndarray, Capacity]: the weights (n,) (1 on passive joints) and the minimum-energy
        Capacity with them.
    """
    from scipy.optimize import minimize

    act = ~res.passive
    lo, hi = torque_limits(motors, prob.qd)
    y0, y1 = mass_line(prob, mode)
    setup = min_energy_setup(prob, np.stack([y0, y0 + y1]), res.passive)

    def weights_of(logw):
        w = np.ones(len(act))
        w[act] = np.exp(np.clip(logw, -np.log(1e4), np.log(1e4)))
        return w

    def capacity_of(logw):
        w = weights_of(logw)
        return (w, *min_energy_affine_torques(prob, setup, w))

    def objective(logw):
        mass, _, feasible = min_energy_interval(prob, setup, weights_of(logw), lo, hi, act)
        return -mass if feasible else 1e6

    base = affine_capacity(*capacity_of(np.zeros(act.sum()))[1:], lo, hi, prob.t, act)
    starts = [np.zeros(act.sum())]
    if base.joint is not None and act[base.joint]:
        s = np.zeros(act.sum())
        s[int(np.sum(act[:base.joint]))] = np.log(10.0)
        starts.append(s)
    own = np.log(res.weights[act])
    if np.ptp(own) > 0:
        starts.append(own - own.mean())
    best = None
    for x0 in starts:
        opt = minimize(objective, x0, method="Nelder-Mead",
                       options={"maxfev": max_evals, "xatol": 1e-4, "fatol": 1e-9, "adaptive": True})
        if best is None or opt.fun < best.fun:
            best = opt
    logw = np.clip(best.x, -np.log(1e4), np.log(1e4))
    logw -= logw.mean()
    w, a, b = capacity_of(logw)
    return w, affine_capacity(a, b, lo, hi, prob.t, act)


def energy_stress_curve(prob: InverseProblem, res: Resolution, peak: tuple[float, float],
                        fractions=(1.0, 0.75, 0.5, 0.25, 0.1, 0.0)) -> list[dict]:
    """Energy of the bounded minimum-energy resolution against its internal-wrench bound (fraction × peak).

    Args:
        prob: the InverseProblem (N samples).
        res: the Resolution whose weights, passive joints, virtual bodies and bound_definition are used
            (its method is replaced by 'bounded').
        peak: (force N, moment N·m), the minimum-energy distribution's peak internal-wrench components.
        fractions: the fractions of the peak taken as bounds.

    Returns:
        list[dict]: one per fraction: fraction, force_bound_N, moment_bound_Nm, energy (N²·m²·s for
        unit weights), max_internal_force_N, max_internal_moment_Nm (of res.bound_definition's internal
        wrench) and failed_samples (how many samples have no solution; then energy is nan and the maxima
        leave them out).
    """
    out = []
    for frac in fractions:
        r = replace(res, method="bounded", force_bound=frac * peak[0], moment_bound=frac * peak[1])
        result = resolve(prob, r)
        F_I = result.internal_nonsqueezing if res.bound_definition == "nonsqueezing" else result.internal_paper
        out.append({"fraction": frac, "force_bound_N": frac * peak[0], "moment_bound_Nm": frac * peak[1],
                    "energy": energy(result),
                    "max_internal_force_N": float(nan_peak(np.linalg.norm(F_I[..., :3], axis=-1))),
                    "max_internal_moment_Nm": float(nan_peak(np.linalg.norm(F_I[..., 3:], axis=-1))),
                    "failed_samples": len(result.failures)})
    return out


# ------------------------------------------------------------------------------------------------
# Models at another mass (independent brute-force checks)
# ------------------------------------------------------------------------------------------------

def scaled_model(model: Model, mass: float) -> Model:
    """The model with its object scaled to `mass` kg at constant geometry (inertia ∝ mass).

    Args:
        model: the Model.
        mass: kg, the object's new mass.

    Returns:
        Model: a copy with the object's mass and inertia scaled.
    """
    obj = model.object
    return replace(model, object=replace(obj, mass=float(mass), inertia=obj.inertia * (mass / obj.mass)))


def payload_centre(model: Model, position: np.ndarray, mass: float) -> np.ndarray:
    """The centre of mass of the object with a point payload, relative to the object's own: m p / (m_o + m).

    Args:
        model: the Model (its object's mass m_o).
        position: (3,) m, p, the payload's position, object frame (relative to the nominal C).
        mass: kg, m, the payload's mass.

    Returns:
        np.ndarray: (3,) m, object frame: where `payload_model`'s composite frame sits.
    """
    return mass * np.asarray(position, dtype=float) / (model.object.mass + mass)


def payload_model(model: Model, position: np.ndarray, mass: float) -> Model:
    """The model whose object also carries a point mass `mass` kg at `position`.

    The composite's frame sits at the new centre of mass (same axes), inertia by the parallel-axis rule;
    the grasp positions are shifted to it.

    Args:
        model: the Model.
        position: (3,) m, the payload's position, object frame (relative to the nominal C).
        mass: kg, the payload's mass.

    Returns:
        Model: a copy with the composite object's mass, inertia about the new C and grasp positions.
    """
    obj = model.object
    total = obj.mass + mass
    shift = payload_centre(model, position, mass)
    d0, d1 = -shift, position - shift

    def steiner(m, d):
        return m * (np.dot(d, d) * np.eye(3) - np.outer(d, d))

    inertia = obj.inertia + steiner(obj.mass, d0) + steiner(mass, d1)
    return replace(model, object=replace(obj, mass=total, inertia=inertia, grasp_pos=obj.grasp_pos - shift))


def brute_force_check(model: Model, traj, res: Resolution, mode: str, capacity: Capacity,
                      payload_position: np.ndarray | None = None, rel: float = 1e-6) -> dict:
    """Independent check of a closed-form capacity, by rerunning the inverse dynamics just below and above it.

    The model is rebuilt with the object scaled to (or carrying a payload of) capacity·(1 ∓ rel), the
    inverse dynamics rerun from scratch with the same resolution, and the largest excess of a torque over
    its motor line measured (< 0: within).

    Args:
        model: the Model (nominal object).
        traj: the JointTrajectory the capacity was computed on.
        res: the Resolution.
        mode: 'scaled' or 'payload'.
        capacity: the Capacity checked (finite mass).
        payload_position: (3,) m, object frame, the payload's position (needed for 'payload').
        rel: the relative step below and above the capacity.

    Returns:
        dict: below_excess and above_excess N·m (N on a prismatic joint), above_joint (stacked index)
        and above_time s of the largest excess above, and ok: below < 0 < above.
    """
    lo, hi = torque_limits(model.motors, traj.qd)
    out = {}
    for key, factor in (("below", 1 - rel), ("above", 1 + rel)):
        mass = capacity.mass * factor
        m2 = scaled_model(model, mass) if mode == "scaled" else payload_model(model, payload_position, mass)
        tau = resolve(inverse_problem(m2, traj), res).tau
        excess = np.maximum(tau - hi, lo - tau)[:, ~res.passive]
        i, j = np.unravel_index(int(np.argmax(excess)), excess.shape)
        out[f"{key}_excess"] = float(excess[i, j])
        if key == "above":
            out["above_joint"], out["above_time"] = int(np.flatnonzero(~res.passive)[j]), float(traj.t[i])
    out["ok"] = out["below_excess"] < 0 < out["above_excess"]
    return out
