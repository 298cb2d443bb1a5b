"""Solving the inverse-dynamics problem: a resolution chosen by name (`resolution_for`), the grasp
wrenches it distributes at every sample (`distribute`), the resolved torques, their energy (eq. 33)
and the default internal-wrench bounds of the 'bounded' resolution.

Two engines give the same numbers to rounding (`coopsim.inverse.problem.ENGINES`): 'compiled', the
default, runs the linear resolutions in one compiled pass over the samples
(`coopsim.inverse.distributions.linear_pass`); 'reference' runs every resolution's registered NumPy
function (`coopsim.inverse.resolutions.RESOLUTIONS`), the readable reference. 'bounded' is a QP in both.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np

from coopsim.core.model import Model
from coopsim.inverse.resolutions import resolution_method
from coopsim.inverse.distributions import (LINEAR_ROWS, RowKind, grasp_line_frames, internal_bound_components,
                                           internal_operator, internal_wrench, linear_pass, nonsqueezing_metric,
                                           virtual_inertias, virtual_masses)
from coopsim.inverse.problem import (InverseProblem, InverseResult, Resolution, SampleFailure, check_engine,
                                     grasp_wrenches, torques_of)


def resolution_for(model: Model, method: str, weights: np.ndarray | None = None,
                   force_bound: float = np.inf, moment_bound: float = np.inf,
                   bound_definition: str = "nonsqueezing") -> Resolution:
    """A redundancy resolution ready to run, with the scenario's data.

    Args:
        model: the Model (its energy weights, passive joints and non-squeezing virtual masses).
        method: a name in `coopsim.inverse.resolutions.RESOLUTIONS`.
        weights: (n,) energy weights Q in place of the scenario's (minimum energy, eq. 33).
        force_bound, moment_bound: N and N·m, the 'bounded' resolution's internal-wrench bounds.
        bound_definition: the internal wrench the bounds apply to, 'nonsqueezing' or 'paper'.

    Returns:
        Resolution.
    """
    resolution_method(method)
    obj = model.object
    masses, _ = virtual_masses(obj.grasp_pos, obj.mass, model.inverse.nonsqueezing_masses)
    w = model.motors.energy_weight if weights is None else np.asarray(weights, dtype=float)
    return Resolution(method, w, model.motors.passive.astype(bool), masses,
                      virtual_inertias(masses, obj.mass, obj.inertia), force_bound, moment_bound, bound_definition)


def compiled_engine(engine: str, method: str) -> bool:
    """Whether `engine` runs resolution `method` in the compiled pass (a linear resolution, engine 'compiled').

    Args:
        engine: 'compiled' or 'reference' (`coopsim.inverse.problem.ENGINES`).
        method: the resolution's name.

    Returns:
        bool: True for a linear resolution with engine 'compiled'.

    Raises:
        ValueError: an unknown engine.
    """
    return check_engine(engine) == "compiled" and method in LINEAR_ROWS


def distribute(prob: InverseProblem, y: np.ndarray, res: Resolution, failures: list | None = None,
               engine: str = "compiled") -> np.ndarray:
    """Grasp wrenches f (N, rk) of resolution `res` for the net object wrenches y (N, k).

    The compiled pass distributes them for a linear resolution (engine 'compiled'), else the
    resolution's registered function; f is nan at the samples it cannot solve ('bounded' only), which are
    appended to `failures`.

    Args:
        prob: the InverseProblem (N samples, k rows, r arms).
        y: (N, k) [N; N·m], the net object wrenches S Y to distribute (e.g. prob.y), world axes.
        res: the Resolution.
        failures: a list the SampleFailures of the unsolved samples are appended to (written); None:
            not reported.
        engine: 'compiled' or 'reference' (`coopsim.inverse.problem.ENGINES`).

    Returns:
        np.ndarray: (N, rk) [N; N·m] grasp wrenches in the rows S, arm after arm, world axes.
    """
    if compiled_engine(engine, res.method):
        return linear_pass(prob, res, np.asarray(y)[None], (res.method,)).f[LINEAR_ROWS[res.method], 0]
    f, bad = resolution_method(res.method).distribute(prob, y, res)
    if failures is not None:
        failures.extend(bad)
    return f


def cost_of(tau: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """½ τᵀQτ (N,) with Q = diag(weights) (the paper's L, eq. 33).

    Args:
        tau: (N, n) N·m (N on a prismatic joint), the joint torques of N samples.
        weights: (n,) the diagonal of Q.

    Returns:
        np.ndarray: (N,) the cost per sample (N²·m² for unit weights).
    """
    return 0.5 * np.einsum("ni,i,ni->n", tau, weights, tau)


def result_of(prob: InverseProblem, method: str, f: np.ndarray, res: Resolution, failures=()) -> InverseResult:
    """Torques, grasp wrenches, both internal wrenches and cost of the distribution f.

    Args:
        prob: the InverseProblem (N samples).
        method: the resolution's name, stored in the result.
        f: (N, rk) [N; N·m] grasp wrenches in the rows S (nan at unsolved samples).
        res: the Resolution (its weights for the cost, its virtual bodies for the non-squeezing internal
            wrench).
        failures: the SampleFailures of the unsolved samples.

    Returns:
        InverseResult: τ (N, n) N·m, grasp wrenches F_e (N, r, 6), the internal wrench (N, r, 6) at C by
        both definitions, the cost ½ τᵀQτ (N,), f and the failures.
    """
    Mstar = nonsqueezing_metric(prob, res.masses, res.inertias)
    tau = torques_of(prob, f)
    return InverseResult(method, prob.t, tau, grasp_wrenches(prob, f), internal_wrench(prob, f, "paper"),
                         internal_wrench(prob, f, "nonsqueezing", Mstar), cost_of(tau, res.weights), f,
                         tuple(failures))


def pass_result(prob: InverseProblem, res: Resolution, out, q: int = 0) -> InverseResult:
    """The InverseResult of resolution `res` in a compiled pass (`coopsim.inverse.distributions.linear_pass`).

    Args:
        prob: the InverseProblem (N samples).
        res: the Resolution (a linear one, computed in the pass; its weights for the cost).
        out: the pass (`coopsim.compiled.api.LinearPass`), with the internal wrenches of net wrench q.
        q: the index of the net wrench (prob.y) in the pass's ys.

    Returns:
        InverseResult: as `result_of` gives it.
    """
    row = LINEAR_ROWS[res.method]
    f, tau = out.f[row, q], out.tau[row, q]
    return InverseResult(res.method, prob.t, tau, grasp_wrenches(prob, f), out.internal_paper[row],
                         out.internal_nonsqueezing[row], cost_of(tau, res.weights), f, ())


def resolve(prob: InverseProblem, res: Resolution, engine: str = "compiled") -> InverseResult:
    """The inverse dynamics of a problem resolved by one resolution.

    Args:
        prob: the InverseProblem (N samples).
        res: the Resolution.
        engine: 'compiled' or 'reference' (`coopsim.inverse.problem.ENGINES`).

    Returns:
        InverseResult: per sample τ (N, n) N·m, grasp wrenches F_e (N, r, 6), the internal wrench
        (N, r, 6) by both definitions, the cost ½ τᵀQτ; nan at the samples listed in its `failures`.
    """
    if compiled_engine(engine, res.method):
        return pass_result(prob, res, linear_pass(prob, res, prob.y[None], (res.method,), wrench_of=0))
    failures: list[SampleFailure] = []
    f = distribute(prob, prob.y, res, failures, engine)
    return result_of(prob, res.method, f, res, failures)


def default_bounds(prob: InverseProblem, res: Resolution, fraction: float = 0.5,
                   engine: str = "compiled") -> tuple[float, float]:
    """The default internal-wrench bounds of the 'bounded' resolution, (force N, moment N·m).

    They are `fraction` of the peak internal-wrench components (grasp-line frames, res.bound_definition)
    of the minimum-energy distribution — at the default 0.5, a bound that halves its peak stress.

    Args:
        prob: the InverseProblem (N samples).
        res: the Resolution (its weights, passive joints, virtual bodies and bound_definition).
        fraction: the share of the peaks taken (0.5: half).
        engine: 'compiled' or 'reference' (`coopsim.inverse.problem.ENGINES`), for the minimum-energy
            distribution.

    Returns:
        tuple[float, float]: the force bound N and the moment bound N·m of the 'bounded' resolution (0
        where the internal wrench has no component of that kind).
    """
    f = distribute(prob, prob.y, replace(res, method="min_energy"), engine=engine)
    Mstar = nonsqueezing_metric(prob, res.masses, res.inertias)
    rows = internal_bound_components(grasp_line_frames(prob), internal_operator(prob, res.bound_definition, Mstar))
    v = np.abs(np.einsum("nij,nj->ni", rows.C, f))
    peak_f = float(np.max(v[rows.keep & (rows.kind == RowKind.FORCE)], initial=0.0))
    peak_m = float(np.max(v[rows.keep & (rows.kind == RowKind.MOMENT)], initial=0.0))
    return fraction * peak_f, fraction * peak_m


def nan_peak(a: np.ndarray, axis=None):
    """np.max leaving out nan (the samples a resolution could not solve); nan where nothing is left.

    Args:
        a: the array, any shape and units.
        axis: the axis (or axes) reduced, as for np.nanmax; None: all.

    Returns:
        np.ndarray | float: the peaks, in a's units, without a warning for all-nan slices.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmax(a, axis=axis)


def energy(result: InverseResult) -> float:
    """∫ ½τᵀQτ dt over the trajectory (trapezoidal rule), N²·m²·s.

    Args:
        result: the InverseResult (its cost (N,) and times t (N,) s).

    Returns:
        float: the energy, N²·m²·s for unit weights (nan if any sample's cost is nan).
    """
    return float(np.trapezoid(result.cost, result.t))
