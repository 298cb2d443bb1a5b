"""The free path that carries the most: B-spline object paths optimised for the dynamic load carrying capacity.

Between the first and last waypoint poses of `inverse.object_motion` the object follows a B-spline path
(`coopsim.inverse.spline_path`, K interior control points) with the scenario's time law over its span.
The unknowns are the control points' offsets from the straight path in the scene's free directions
(x = Sᵀδ per control point: in-plane position and the rotation about the plane normal on a planar
scene, all six on a spatial one), scaled by the arms' mean reach (m) and 1 rad.

The capacity is a minimum over samples and motors, so the problem is written in epigraph form (smooth):

    maximise μ  over (δ, μ)  subject to, at every sample of the grid and every active motor,
        τ_min(θ̇) <= a(δ) + μ b(δ) <= τ_max(θ̇)   and   τ_min(θ̇) <= a(δ) <= τ_max(θ̇)   (eq. 36 at μ and 0),
        w_m(δ) >= margin · w_m(start pose)        (each arm's manipulability, `diagnostics.manipulability`),

with τ(μ) = a + μ b the resolution's torques (`coopsim.inverse.capacity.affine_torques`), every row
divided by the motor's stall torque. Loop closure, reach, joint ranges and singularity crossings come
with the closed-chain inverse kinematics of the path (`object_motion_trajectory`), the joint ranges also
between its samples (`check_ranges_between`): a path it refuses is an infeasible point (every constraint
−1). SciPy's SLSQP (sequential quadratic programming on dense Jacobians: the problem has tens of unknowns
and thousands of rows) solves it; the constraint Jacobian in δ is by forward differences of the whole
chain (IK, compiled inverse dynamics, distribution), in μ exact. A run ends at its heaviest accepted point
(`accepted_mass`: IK accepted, manipulability above its margin), its start included, so it never ends
below its start; it also stops when that payload gained less than STALL_GAIN
over STALL_ITERATIONS iterations (where the capacity is nearly flat in the path SLSQP's slightly
infeasible iterates otherwise walk on to its iteration limit).

Continuation in K (`_law_stage`): the straight path and the random starts (fixed seed) run on one interior
control point (a quadratic B-spline, k unknowns), the best of them is refined to 2 and then to K points
(`FreePathProblem.refined`, the same curve: a cubic B-spline space holds every quadratic and cubic) and
each refinement starts one run there; the straight path also runs on K points. The best is the converged point whose capacity, recomputed in closed
form on the object motion's output_dt grid, is largest (a refined start competes with its run's end point).

For the LP bound (method 'lp', the best distribution: `LPFreePathProblem`) the grasp wrenches are free at every
row-time: f = A⁺ȳ + N z (`coopsim.inverse.retime.grasp_null_space`) meets the object wrench and the passive
joints' zero torque exactly, and each row reads τ_min <= a(δ) + μ b(δ) + C(δ) z <= τ_max with C = Jᵀ_active N.
A row-time's rows share no unknown with another's but δ and μ, so z is maximised out of each row-time in closed
form, its LP capacity c_i(δ) (the rows' own small LP): the NLP carries z (nz unknowns per row-time, the Jacobian
exact in z and μ) only on the row-times whose c_i at the run's start is within Z_BAND of the least, and of
their motor rows those within ROW_BAND τ_s of their line there; every other row-time is one row c_i(δ) − μ >= 0,
its derivative in δ that of the LP's Lagrangian at its optimum and multipliers (the envelope theorem: the
multipliers times the forward differences of its rows, no LP at the difference points). A run's cost goes
with the square of its unknowns (SLSQP's dense subproblem); the rows left out are far from binding, and every
point a run accepts is checked on all rows (`accepted_mass`). A path's capacity is the LP over the same rows
(`coopsim.inverse.capacity.lp_capacity` under the scenario's law).

With `weights`, the minimum-energy resolution's energy weights Q are optimised with the path (the
paper's closing suggestion): path and weights in turn (`coopsim.inverse.capacity.optimise_weights` on
the optimum's trajectory), each round started from the last, so the capacity never drops.
"""

from __future__ import annotations

import time
from functools import partial
from types import SimpleNamespace
from dataclasses import dataclass, replace

import numpy as np

from coopsim.core.errors import CoopsimError
from coopsim.core.model import Model, ObjectMotion, PathSpline, torque_limits
from coopsim.core.labels import joint_labels
from coopsim.forward.diagnostics import manipulability
from coopsim.inverse.capacity import (Capacity, affine_capacity, affine_torques, lp_capacity, mass_line,
                                      nominal_mass, optimise_weights)
from coopsim.inverse.problem import InverseProblem, Resolution, inverse_problem
from coopsim.inverse.solve import resolution_for
from coopsim.inverse.path import JointPath, PathPoints, joint_path, path_grid
from coopsim.inverse.qp import solve_lps
from coopsim.inverse.retime import LP_BOUND, Retiming, TimeLaw, grasp_null_space, max_payload, path_dynamics
from coopsim.inverse.retime_weights import with_weights
from coopsim.inverse.spline_path import KIND, BSplinePath, refinement, straight_control_points
from coopsim.inverse.trajectory import TrajectoryError, object_motion_samples, object_motion_trajectory

FD_STEP = 1e-7            # forward-difference step in the scaled unknowns (× reach m, × 1 rad)
START_SPREAD = 0.01       # random starts: standard deviation of the scaled offsets
OFFSET_BOUND = 0.5        # |offset| <= this × the arms' mean reach (m) or this × π/2 rad
WEIGHT_ROUNDS = 2         # path / weights rounds with `weights`
RETIME_ROUNDS = 2         # retimed payloads (path / time law in turn): retime, optimise the path, retime
INFEASIBLE = -1.0         # every constraint's value where the inverse kinematics refuses the path
JOINT_MARGIN = 1e-6       # rad (m): how far inside its range a joint's path must stay between samples
COARSE = (1, 2)           # the starts run with these many control points first, in turn (continuation in K, `_law_stage`)
Z_BAND = 0.5              # an LP run's internal-wrench unknowns: row-times within this of the least capacity
ROW_BAND = 1.0            # ... and of those the motor rows whose slack at its start is at most this (× τ_s)
LP_ROW_CLIP = 1e3         # the other row-times' rows (c_i − μ)/kg where c_i = ±inf (unbounded, no optimum)


class PathOptimizationError(CoopsimError):
    """The free path cannot be optimised as asked (no feasible start, or the ends out of reach)."""


@dataclass(frozen=True, eq=False)
class PathEvaluation:
    """One free path on the optimiser's grid (N samples, n joints, r arms).

    Attributes:
        t: (M,) s, the time of each row (a grid point of a retimed law appears twice: with the interval
            before it and the one after it).
        prob: the InverseProblem along the path's trajectory (the scenario's time law only; else None).
        a: (M, n) N·m (N on a prismatic joint), the torques at μ = 0.
        b: (M, n) N·m per kg, their rate with the carried mass.
        lo: (M, n) N·m, τ_min of eq. 36 along the path.
        hi: (M, n) N·m, τ_max.
        manip: (N, r) each arm's manipulability at the N path points (`coopsim.forward.diagnostics.manipulability`).
    """

    t: np.ndarray
    prob: InverseProblem | None
    a: np.ndarray
    b: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    manip: np.ndarray


@dataclass(frozen=True)
class StartResult:
    """One run of the optimiser.

    Attributes:
        start: the start's index (0: the straight path).
        capacity_kg: kg, the closed-form capacity at its end point on the optimiser's grid (nan: IK refused);
            its end point is its heaviest accepted one (`accepted_mass`), start and iterates included.
        start_capacity_kg: kg, the capacity at its start point.
        success: SLSQP reports convergence, or the run stopped on the payload-gain criterion (STALL_GAIN).
        status: SLSQP's exit status (0: converged, or stopped on that criterion; `SLSQP_STATUS`).
        message: what ended the run, in words.
        iterations: its iterations.
        evaluations: path evaluations (IK + inverse dynamics), finite differences included.
        wall_s: s, its wall time.
        scenario_grid_kg: kg, the capacity at its end point on the object motion's output_dt grid (the
            scenario's time law; nan: not evaluated, or refused by the IK).
        control_points: K of its path.
    """

    start: int
    capacity_kg: float
    start_capacity_kg: float
    success: bool
    status: int
    message: str
    iterations: int
    evaluations: int
    wall_s: float
    scenario_grid_kg: float = float("nan")
    control_points: int = 0


@dataclass(frozen=True, eq=False)
class PathOptimum:
    """The optimised free path and how it was found.

    Attributes:
        motion: the ObjectMotion of the optimum under the scenario's time law (two waypoints and its
            B-spline path, the scenario's time law and output_dt).
        capacity: the Capacity of `motion` on the optimiser's grid.
        straight: the Capacity of the straight path on that grid (the first start).
        resolution: the Resolution optimised for (its weights optimised with `weights`).
        mode: 'scaled' or 'payload'.
        best: the StartResult of the first stage's best run (its success, status and message say whether
            the optimiser converged).
        starts: one StartResult per optimiser run (first stage: each start, with `weights` each round;
            then one per retimed round).
        eval_s: s, the wall time of one path evaluation (IK, inverse dynamics, distribution).
        jacobian_s: s, the wall time of one constraint Jacobian (forward differences).
        unknowns: the number of path unknowns (K × k).
        retimed_motion: the ObjectMotion of the retimed stage's path (the scenario's time law; the law that
            carries `retimed.mass` is `retimed`), or None without that stage.
        retimed: the Retiming of the heaviest payload along retimed_motion's path within the duration, or None.
        retime_rounds: per round {mass_kg, retiming, run} (`_retime_stage`).
        wall_s: s, the whole optimisation's wall time.
    """

    motion: ObjectMotion
    capacity: Capacity
    straight: Capacity
    resolution: Resolution
    mode: str
    best: StartResult
    starts: tuple
    eval_s: float
    jacobian_s: float
    unknowns: int
    retimed_motion: ObjectMotion | None
    retimed: Retiming | None
    retime_rounds: tuple
    wall_s: float


def capacity_mode(model: Model) -> str:
    """The capacity the free path maximises: 'payload' when the scenario places a payload, else 'scaled'.

    Args:
        model: the Model (its inverse.payload_position).

    Returns:
        str: 'payload' or 'scaled'.
    """
    return "scaled" if model.inverse.payload_position is None else "payload"


def end_poses(motion: ObjectMotion, output_dt: float | None = None) -> ObjectMotion:
    """The motion reduced to its first and last waypoints (no path yet), optionally resampled.

    Args:
        motion: the ObjectMotion (w >= 2 waypoints).
        output_dt: s, the sample interval in place of the motion's; None: the motion's.

    Returns:
        ObjectMotion: two waypoints, the same time law, no path.
    """
    ends = [0, -1]
    return replace(motion, times=motion.times[ends], positions=motion.positions[ends],
                   rotations=motion.rotations[ends], path=None,
                   output_dt=motion.output_dt if output_dt is None else float(output_dt))


def motion_problem(model: Model, motion: ObjectMotion):
    """A motion's closed-chain IK (its joint ranges checked between the samples too, `check_ranges_between`),
    the compiled per-sample terms and the InverseProblem along it (the payload at inverse.payload_position).

    Args:
        model: the Model.
        motion: the ObjectMotion (sampled every output_dt).

    Returns:
        tuple: (JointTrajectory, InverseProblem, the terms of `coopsim.compiled.api.inverse_terms`).

    Raises:
        TrajectoryError: the inverse kinematics refuses the motion.
    """
    from coopsim.compiled import api

    traj = object_motion_trajectory(model, motion)
    check_ranges_between(model, traj.t, traj.q, traj.qd, traj.qdd)
    terms = api.inverse_terms(model, traj.q, traj.qd, traj.qdd)
    return traj, inverse_problem(model, traj, model.inverse.payload_position, terms=terms), terms


def evaluate_motion(model: Model, motion: ObjectMotion, res: Resolution, mode: str) -> PathEvaluation:
    """A motion's IK, inverse problem, affine torques, motor lines and manipulability.

    Args:
        model: the Model.
        motion: the ObjectMotion.
        res: the Resolution (linear in the net object wrench).
        mode: 'scaled' or 'payload'.

    Returns:
        PathEvaluation.

    Raises:
        TrajectoryError: the inverse kinematics refuses the motion.
    """
    traj, prob, terms = motion_problem(model, motion)
    a, b = affine_torques(prob, res, mode)
    lo, hi = torque_limits(model.motors, traj.qd)
    return PathEvaluation(traj.t, prob, a, b, lo, hi, manipulability(model, terms.J))


def check_ranges_between(model: Model, x: np.ndarray, q: np.ndarray, d1: np.ndarray, d2: np.ndarray) -> None:
    """Refuse a joint motion that may leave a joint's range, less JOINT_MARGIN, between its samples.

    The joint ranges are checked at the samples by the inverse kinematics; an optimum pressed against a range
    there can pass it in between. On each interval [x_i, x_i+1] (h = x_i+1 − x_i) the quintic Hermite
    interpolant of (θ, θ′, θ″) at its ends (`coopsim.inverse.trajectory.hermite_quintic`) lies within the hull
    of its Bernstein coefficients θ₀, θ₀ + hθ′₀/5, θ₀ + 2hθ′₀/5 + h²θ″₀/20, θ₁ − 2hθ′₁/5 + h²θ″₁/20,
    θ₁ − hθ′₁/5, θ₁: those must keep JOINT_MARGIN inside the range (the margin covering the interpolant's
    O(h⁶) distance from the joint path).

    Args:
        model: the Model (its joint_range (n, 2), or None: nothing checked).
        x: (N,) the samples' times (s) or path parameters, increasing.
        q: (N, n) rad (m), θ at the samples.
        d1: (N, n) θ′ (per unit of x).
        d2: (N, n) θ″.

    Raises:
        TrajectoryError: naming the joint and the interval.
    """
    if model.joint_range is None or len(x) < 2:
        return
    h = np.diff(np.asarray(x, dtype=float))[:, None]
    p0, p1, v0, v1, a0, a1 = q[:-1], q[1:], h * d1[:-1], h * d1[1:], h * h * d2[:-1], h * h * d2[1:]
    b = np.stack([p0, p0 + v0 / 5, p0 + 2 * v0 / 5 + a0 / 20, p1 - 2 * v1 / 5 + a1 / 20, p1 - v1 / 5, p1])
    lo, hi = model.joint_range.T
    low, high = b.min(axis=0), b.max(axis=0)
    bad = np.argwhere((low < lo + JOINT_MARGIN) | (high > hi - JOINT_MARGIN))
    if len(bad):
        i, j = bad[0]
        raise TrajectoryError(f"inverse.optimize: between {x[i]:.6g} and {x[i + 1]:.6g} "
                              f"{joint_labels(model)[j]} may come within {JOINT_MARGIN:g} of its range "
                              f"[{lo[j]:.6g}, {hi[j]:.6g}] (its path within [{low[i, j]:.6g}, {high[i, j]:.6g}])")


class SplineGeometry:
    """A B-spline path as a `coopsim.inverse.path.ObjectPath` (one smooth piece, knots [0, 1]).

    Args:
        motion: the ObjectMotion (two waypoints and a B-spline `path`).

    Attributes:
        knots: (2,) [0, 1].
        spline: the BSplinePath.
    """

    def __init__(self, motion: ObjectMotion):
        self.knots = np.array([0.0, 1.0])
        self.spline = BSplinePath(motion)

    def at(self, s: np.ndarray, piece: np.ndarray) -> PathPoints:
        """The path at points s (see `coopsim.inverse.path.ObjectPath.at`).

        Args:
            s: (M,) the path parameter in [0, 1].
            piece: (M,) int, all 0 (one piece).

        Returns:
            PathPoints: relative to the first waypoint's position.
        """
        pt = self.spline.at(s, self.spline.origin)
        return PathPoints(np.asarray(s, dtype=float), np.asarray(piece, dtype=int), pt.p, pt.R,
                          np.concatenate([pt.dp, pt.dw], axis=1), np.concatenate([pt.ddp, pt.ddw], axis=1),
                          self.spline.origin)


def weighted(model: Model, res: Resolution) -> Model:
    """The model whose energy weights are the resolution's (what `path_dynamics` and `max_payload` read).

    Args:
        model: the Model.
        res: the Resolution (its weights).

    Returns:
        Model: a copy with motors.energy_weight = res.weights.
    """
    return with_weights(model, res.weights)


def spline_joint_path(model: Model, motion: ObjectMotion, s: np.ndarray, piece: np.ndarray,
                      engine: str = "compiled") -> JointPath:
    """`coopsim.inverse.path.joint_path` of a B-spline motion at the points s: θ(s), θ′(s), θ″(s).

    engine 'compiled': the compiled object-motion pass (`object_motion_samples`) of the path traversed in
    unit time at ṡ = 1, s̈ = 0 (times [0, 1], the 'linear' law s = u, sampled at t = s), whose θ̇, θ̈ are
    then θ′, θ″; its failures quote the path parameter s. 'reference': `joint_path` (NumPy per point; SciPy's DOP853 in
    s for the redundant arms). Both take the square arms by Newton continuation and the redundant ones
    by the least-|θ′ − z| ODE in s, so they agree to the solvers' tolerances; the compiled pass also
    refuses a path on which an arm's det S J changes sign between points.

    Args:
        model: the Model.
        motion: the ObjectMotion (two waypoints and a B-spline path; its initial guess, rest posture and
            gain, the gain per unit s being rest_gain × the span, as the time law's s runs over it).
        s: (N,) the path points, increasing, from 0 (the first point starts the IK from the guess).
        piece: (N,) int, zeros.
        engine: 'compiled' or 'reference'.

    Returns:
        JointPath: with its recipe (this function on the same motion), so that the retiming's check points
        between the grid points (`JointPath.refined`) are computed as the grid was.

    Raises:
        TrajectoryError: the inverse kinematics refuses the path.
        ValueError: an unknown engine.
    """
    guess = model.q0 if motion.initial_guess is None else motion.initial_guess
    gain = motion.path_gain
    geometry = SplineGeometry(motion)
    if engine == "reference":
        return joint_path(model, geometry, s, piece, guess, motion.rest_posture, gain)
    unit = replace(motion, times=np.array([0.0, 1.0]), time_law="linear", samples=None, rest_gain=gain,
                   initial_guess=guess)
    traj = object_motion_samples(model, unit, s, engine=engine, parameter="s")
    return JointPath(geometry.at(s, piece), traj.q, traj.qd, traj.qdd,
                     partial(spline_joint_path, model, motion, engine=engine))     # its check points' recipe


def evaluate_law(model: Model, motion: ObjectMotion, law: TimeLaw, res: Resolution, mode: str) -> PathEvaluation:
    """A B-spline motion under a retimed law (held fixed as s(t)): rows at both sides of every grid point.

    With the law's b = ṡ² at the points and a = s̈ constant on each interval, each point is checked with
    the interval before it and the one after it (as `coopsim.inverse.retime.check_time_law`); the torques
    are those of `coopsim.inverse.retime.path_dynamics`, the lines eq. 36 at θ̇ = θ′√b.

    Args:
        model: the Model.
        motion: the ObjectMotion (two waypoints and a B-spline path).
        law: the TimeLaw (one piece, its grid s).
        res: the Resolution (its method and weights).
        mode: 'scaled' or 'payload'.

    Returns:
        PathEvaluation: 2N rows (before, then after), prob None.

    Raises:
        TrajectoryError: the inverse kinematics refuses the path.
    """
    dyn, sides, b, lo, hi, manip = law_dynamics(weighted(model, res), motion, law, res.method, mode)
    a0, b0 = ([dyn.tau[k, 0] + a * dyn.tau[k, 1] + b * dyn.tau[k, 2] for a in sides] for k in (0, 1))
    return PathEvaluation(np.tile(law.t, 2), None, np.vstack(a0), np.vstack(b0), np.vstack([lo, lo]),
                          np.vstack([hi, hi]), manip)


def law_dynamics(model: Model, motion: ObjectMotion, law: TimeLaw, method: str, mode: str):
    """The parts of a B-spline motion under a retimed law that `evaluate_law` and `LPFreePathProblem` share.

    Args:
        model: the Model (its energy weights those of the resolution).
        motion: the ObjectMotion (two waypoints and a B-spline path).
        law: the TimeLaw (one piece, its grid s, N points).
        method: a linear resolution's name or 'lp' (`path_dynamics`).
        mode: 'scaled' or 'payload'.

    Returns:
        tuple: (dyn, sides, b, lo, hi, manip): the PathDynamics, s̈ (N, 1) of the interval before each point
        and of the one after it, ṡ² b (N, 1), τ_min and τ_max (N, n) of eq. 36 at θ̇ = θ′√b, each arm's
        manipulability (N, r).

    Raises:
        TrajectoryError: the inverse kinematics refuses the path.
    """
    from coopsim.compiled import api

    jp = spline_joint_path(model, motion, law.s, law.piece)
    check_ranges_between(model, law.s, jp.q, jp.d1, jp.d2)
    dyn = path_dynamics(model, jp, method, mode)
    b = law.b[:, None]
    qd = jp.d1 * np.sqrt(np.maximum(b, 0.0))
    lo, hi = torque_limits(model.motors, qd)
    sides = [np.append(0.0, law.a[:-1])[:, None], law.a[:, None]]
    zero = np.zeros_like(jp.q)
    J = api.inverse_terms(model, jp.q, zero, zero).J
    return dyn, sides, b, lo, hi, manipulability(model, J)


def retimed_capacity(model: Model, motion: ObjectMotion, res: Resolution, mode: str, duration: float,
                     intervals: int, above: float | None = None) -> tuple[float, Retiming] | None:
    """The heaviest payload the B-spline motion's path carries within `duration`, the time law free
    (`coopsim.inverse.retime.max_payload` on `intervals` equal intervals of s).

    With `above` (another path's payload) the path is first asked whether it carries that mass within the
    duration at all (one minimum-time solve: the minimum time grows with the mass); where it does not, None,
    and where it does, the search starts from it (`max_payload(at_least=above, only_above=True)`).

    Args:
        model: the Model.
        motion: the ObjectMotion (two waypoints and a B-spline path).
        res: the Resolution (its method and weights).
        mode: 'scaled' or 'payload'.
        duration: s, T_max.
        intervals: the grid's intervals.
        above: kg, a payload to beat, or None.

    Returns:
        tuple[float, Retiming] | None: the mass kg and its Retiming; None where `above` is given and the path
        does not carry it within the duration.

    Raises:
        TrajectoryError: the inverse kinematics refuses the path.
        RetimeError: as `max_payload`.
    """
    m = weighted(model, res)
    s, piece = path_grid(np.array([0.0, 1.0]), intervals)
    dyn = path_dynamics(m, spline_joint_path(m, motion, s, piece), res.method, mode)
    found = max_payload(dyn, duration, at_least=above, only_above=above is not None)
    return None if found is None else found[:2]


class FreePathProblem:
    """The epigraph NLP of one scenario, resolution and mode (see the module docstring).

    Args:
        model: the Model (its inverse.object_motion's first and last waypoints, inverse.optimize).
        res: the Resolution (linear in the net object wrench).
        mode: 'scaled' or 'payload'.
        law: a retimed TimeLaw held fixed (s(t) as it is, `evaluate_law`); None: the scenario's time law
            on the grid of inverse.optimize.sample_dt (`evaluate_motion`).
        control_points: K, the interior control points; None: inverse.optimize.control_points.

    Attributes:
        model: the Model.
        res: the Resolution.
        mode: the capacity mode.
        law: the TimeLaw held fixed, or None.
        ends: the two-waypoint ObjectMotion on the optimiser's grid (inverse.optimize.sample_dt).
        straight: the PathSpline of the straight path (offsets are from it).
        scale: (K·k,) the unknowns' units: the arms' mean reach (m) on position rows, 1 rad on rotation rows.
        bounds: (K·k,) the bound on each scaled offset's magnitude.
        evaluations: path evaluations so far.
    """

    def __init__(self, model: Model, res: Resolution, mode: str, law: TimeLaw | None = None,
                 control_points: int | None = None):
        opt = model.inverse.optimize
        K = opt.control_points if control_points is None else int(control_points)
        self.model, self.res, self.mode, self.law = model, res, mode, law
        self.ends = end_poses(model.inverse.object_motion, opt.sample_dt)
        self.straight = straight_control_points(self.ends, K)
        S = model.rows
        reach = float(np.mean([np.sum(np.linalg.norm(a.joint_pos[1:], axis=1)) + np.linalg.norm(a.ee_pos)
                               for a in model.arms]))
        self._basis = S.T                                           # (6, k): offsets [dp; dφ] = Sᵀ δ
        self._row_scale = np.where(np.any(S[:, :3] != 0, axis=1), reach, 1.0)
        self.scale = np.tile(self._row_scale, K)
        position = np.tile(np.any(S[:, :3] != 0, axis=1), K)
        self.bounds = np.where(position, OFFSET_BOUND, OFFSET_BOUND * np.pi / 2)
        self._act = ~res.passive & np.isfinite(model.motors.stall_torque)
        self._ts = model.motors.stall_torque[self._act]
        self._cache: dict[bytes, PathEvaluation | None] = {}
        self.evaluations = 0
        first = self.evaluate(np.zeros(len(self.scale)))
        if first is None:
            raise PathOptimizationError("inverse.object_motion: the straight path between the first and last "
                                        "waypoints is refused by the inverse kinematics")
        self._manip0 = first.manip[0]

    @property
    def size(self) -> int:
        """The number of path unknowns K·k."""
        return len(self.scale)

    @property
    def control_points(self) -> int:
        """K, the interior control points."""
        return len(self.straight.positions)

    def refined(self, x: np.ndarray, coarse: int) -> np.ndarray:
        """This problem's scaled offsets of the path of a coarser one's offsets x (`spline_path.refinement`:
        the same curve where the B-spline spaces are nested, as from K = 1 or 2, else its interpolant at
        the Greville abscissae).

        Args:
            x: (coarse·k,) the coarse problem's scaled offsets (same scene, same scales per control point).
            coarse: its K.

        Returns:
            np.ndarray: (K·k,) the offsets here; within the bounds where x is (the map's rows are convex
            combinations where nested).
        """
        M = refinement(coarse, self.control_points)[1:-1, 1:-1]          # the ends' offsets are zero
        return np.clip((M @ np.asarray(x, dtype=float).reshape(coarse, -1)).ravel(), -self.bounds, self.bounds)

    def path_of(self, x: np.ndarray) -> PathSpline:
        """The PathSpline of scaled offsets x (K·k,).

        Args:
            x: (K·k,) the scaled offsets from the straight path, control point after control point.

        Returns:
            PathSpline: its interior control points, world axes.
        """
        d = (np.asarray(x, dtype=float) * self.scale).reshape(-1, len(self._row_scale)) @ self._basis.T
        return PathSpline(KIND, self.straight.positions + d[:, :3], self.straight.rotation_vectors + d[:, 3:])

    def motion_of(self, x: np.ndarray, output_dt: float | None = None) -> ObjectMotion:
        """The ObjectMotion of scaled offsets x.

        Args:
            x: (K·k,) the scaled offsets.
            output_dt: s, the sample interval; None: the optimiser's grid.

        Returns:
            ObjectMotion: two waypoints and the path.
        """
        m = replace(self.ends, path=self.path_of(x))
        return m if output_dt is None else replace(m, output_dt=float(output_dt))

    def evaluate(self, x: np.ndarray) -> PathEvaluation | None:
        """The path of x on the optimiser's grid, or None where the inverse kinematics refuses it (cached).

        Args:
            x: (K·k,) the scaled offsets.

        Returns:
            PathEvaluation | None.
        """
        key = np.asarray(x, dtype=float).tobytes()
        if key not in self._cache:
            if len(self._cache) > 4 * self.size + 8:
                self._cache.clear()
            self.evaluations += 1
            try:
                self._cache[key] = self._evaluation(self.motion_of(x))
            except CoopsimError:
                self._cache[key] = None
        return self._cache[key]

    def _evaluation(self, motion: ObjectMotion) -> PathEvaluation:
        """The PathEvaluation of a motion under this problem's law (`evaluate_motion` or `evaluate_law`)."""
        if self.law is None:
            return evaluate_motion(self.model, motion, self.res, self.mode)
        return evaluate_law(self.model, motion, self.law, self.res, self.mode)

    def variant(self, law: TimeLaw | None = None, control_points: int | None = None) -> "FreePathProblem":
        """The same problem (class, model, resolution, mode) with another law held fixed or another K.

        Args:
            law: the TimeLaw held fixed; None: the scenario's law.
            control_points: K; None: this one's.

        Returns:
            FreePathProblem: of this one's class.
        """
        return type(self)(self.model, self.res, self.mode, law=law,
                          control_points=self.control_points if control_points is None else control_points)

    @property
    def extra_size(self) -> int:
        """The number of unknowns besides the path's and μ (0 here; the LP bound's internal wrenches)."""
        return 0

    def extra_start(self, x: np.ndarray, mu: float) -> np.ndarray:
        """The extra unknowns' start at path x and mass μ: none for a linear resolution.

        Args:
            x: (K·k,) the scaled offsets.
            mu: kg, the carried mass.

        Returns:
            np.ndarray: (extra_size,) = (0,).
        """
        return np.zeros(0)

    def capacity(self, x: np.ndarray) -> Capacity | None:
        """The closed-form capacity of the path of x on the optimiser's grid (None: refused by the IK).

        Args:
            x: (K·k,) the scaled offsets.

        Returns:
            Capacity | None.
        """
        e = self.evaluate(x)
        return None if e is None else affine_capacity(e.a, e.b, e.lo, e.hi, e.t, ~self.res.passive)

    def scenario_grid_capacity(self, x: np.ndarray) -> float:
        """kg, the closed-form capacity of the path of x under the scenario's time law on its output_dt grid
        (nan where the IK refuses it; not cached).

        Args:
            x: (K·k,) the scaled offsets.

        Returns:
            float: kg.
        """
        try:
            e = evaluate_motion(self.model, self.motion_of(x, self.model.inverse.object_motion.output_dt), self.res,
                                self.mode)
        except CoopsimError:
            return float("nan")
        return affine_capacity(e.a, e.b, e.lo, e.hi, e.t, ~self.res.passive).mass

    def _rows(self, e: PathEvaluation) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(T, U, B, W): (τ_max − a)/τ_s, (a − τ_min)/τ_s, b/τ_s over the active motors, flattened, and
        the manipulability rows w/w₀ − margin."""
        act, ts = self._act, self._ts
        T = ((e.hi - e.a)[:, act] / ts).ravel()
        U = ((e.a - e.lo)[:, act] / ts).ravel()
        B = (e.b[:, act] / ts).ravel()
        W = (e.manip / self._manip0 - self.model.inverse.optimize.manipulability_margin).ravel()
        return T, U, B, W

    def constraints(self, x: np.ndarray, mu: float, extra: np.ndarray | None = None) -> np.ndarray:
        """The NLP's inequality rows (>= 0 feasible) at (x, μ).

        Args:
            x: (K·k,) the scaled offsets.
            mu: kg, the carried mass.
            extra: the extra unknowns (none here; ignored).

        Returns:
            np.ndarray: [T − μB; U + μB; T; U; W] (see `_rows`); INFEASIBLE everywhere where the IK refuses.
        """
        e = self.evaluate(x)
        return np.full(self._count(), INFEASIBLE) if e is None else self._nlp_rows(e, mu, extra)

    def _nlp_rows(self, e: PathEvaluation, mu: float, extra: np.ndarray | None, held=None) -> np.ndarray:
        """The NLP's rows of an accepted path's evaluation (`constraints`; `held` is the LP bound's)."""
        T, U, B, W = self._rows(e)
        return np.concatenate([T - mu * B, U + mu * B, T, U, W])

    def _held(self, e: PathEvaluation):
        """What the Jacobian's differences in x hold at the point of evaluation e besides the unknowns (none here;
        the LP bound's row-time LPs, `LPFreePathProblem._held`)."""
        return None

    def _count(self) -> int:
        T, _, _, W = self._rows(self.evaluate(np.zeros(self.size)))
        return 4 * len(T) + len(W)

    def jacobian(self, x: np.ndarray, mu: float, extra: np.ndarray | None = None) -> np.ndarray:
        """d(constraints)/d(x, extra, μ) (rows, K·k + extra_size + 1): forward differences in x (backward
        where the forward point is refused; the extra unknowns held), exact in the extra unknowns and μ.

        Args:
            x: (K·k,) the scaled offsets.
            mu: kg, the carried mass.
            extra: (extra_size,) the extra unknowns; None: zeros.

        Returns:
            np.ndarray: the Jacobian; zero rows in x where the IK refuses x itself.
        """
        x = np.asarray(x, dtype=float)
        extra = np.zeros(self.extra_size) if extra is None else np.asarray(extra, dtype=float)
        e = self.evaluate(x)
        if e is None:
            return np.zeros((self._count(), self.size + self.extra_size + 1))
        held = self._held(e)
        c0 = self._nlp_rows(e, mu, extra, held)
        J = np.zeros((len(c0), self.size + self.extra_size + 1))
        for i in range(self.size):
            for h in (FD_STEP, -FD_STEP):
                xi = x.copy()
                xi[i] += h
                ei = self.evaluate(xi)
                if ei is not None:
                    J[:, i] = (self._nlp_rows(ei, mu, extra, held) - c0) / h
                    break
        J[:, self.size:] = self._exact_columns(e, len(c0))
        return J

    def _exact_columns(self, e: PathEvaluation, rows: int) -> np.ndarray:
        """The constraints' derivatives in the extra unknowns and μ (rows, extra_size + 1): here d/dμ only."""
        B = self._rows(e)[2]
        return np.concatenate([-B, B, np.zeros(rows - 2 * len(B))])[:, None]


def lp_resolution(model: Model) -> Resolution:
    """The Resolution standing for the LP bound (method 'lp'): it carries the passive joints and the energy
    weights that `path_dynamics` and `max_payload` read; the distribution itself is free.

    Args:
        model: the Model.

    Returns:
        Resolution: method LP_BOUND.
    """
    return replace(resolution_for(model, "paper"), method=LP_BOUND)


def lp_motion_capacity(model: Model, motion: ObjectMotion, mode: str) -> Capacity:
    """The LP bound's capacity of a motion at its output_dt samples (`coopsim.inverse.capacity.lp_capacity`).

    Args:
        model: the Model.
        motion: the ObjectMotion.
        mode: 'scaled' or 'payload'.

    Returns:
        Capacity.

    Raises:
        TrajectoryError: the inverse kinematics refuses the motion.
    """
    prob = motion_problem(model, motion)[1]
    return lp_capacity(prob, model.motors, model.motors.passive.astype(bool), mode)


@dataclass(frozen=True, eq=False)
class LPEvaluation(PathEvaluation):
    """A free path's rows for the LP bound (M rows, n joints, m active motors with a finite stall torque, nz
    internal-wrench unknowns per row): a, b the torques of the grasp wrenches f = A⁺ȳ (`grasp_null_space`)
    at μ = 0 and per kg, C = Jᵀ_active N their rate with the internal wrenches z (f = A⁺ȳ + N z).

    Attributes:
        C: (M, m, nz) N·m per unit of z (N, N·m: the null space's columns are orthonormal).
    """

    C: np.ndarray = None


class LPFreePathProblem(FreePathProblem):
    """The free path of the LP bound (the best distribution): grasp wrenches free at every row-time.

    The unknowns are the path's offsets x, the internal wrenches z (nz per row-time: each grid point of a law
    held fixed has its own on each side) scaled by `z_scale`, and μ:

        maximise μ  subject to  τ_min <= a(x) + μ b(x) + C(x) z <= τ_max  (active motors, eq. 36, over τ_s)
                                and each arm's manipulability rows (as `FreePathProblem`),

    f = A⁺ȳ + N z meeting the object wrench and the passive joints' zero torque exactly at every row, the
    null space N aligned to the straight path's (orthogonal Procrustes per row) so that it is smooth in x.
    The capacity of a path is the LP over the same rows (max μ with z free per row; under the scenario's law
    `coopsim.inverse.capacity.lp_capacity` of its inverse problem). Rows at μ = 0 are not imposed. z is carried on
    the row-times `free` only, with their motor rows `kept`; each other row-time is the row (c_i − μ)/kg of its
    LP capacity c_i (module docstring; `extra_start` chooses them at a run's start).

    Args: as `FreePathProblem` (res: `lp_resolution`).

    Attributes:
        z_scale: N (N·m) per unit of a scaled z: 1 / the largest |C|/τ_s at the straight path.
        kg: kg, the unit of the other row-times' rows: the straight path's capacity (at least 1 kg).
        free: (F,) int, the row-times with z unknowns (None: all of them).
        kept: (F, 2m) bool, their motor rows carried, τ_max sides then τ_min sides (None: all).
    """

    def __init__(self, model: Model, res: Resolution, mode: str, law: TimeLaw | None = None,
                 control_points: int | None = None):
        self._null_ref, self.free, self.kept, self._lps = None, None, None, {}
        super().__init__(model, res, mode, law, control_points)
        first = self.evaluate(np.zeros(self.size))
        G = first.C / self._ts[None, :, None]
        self.z_scale = 1.0 / max(float(np.max(np.abs(G), initial=0.0)), 1e-300)
        straight = self.capacity(np.zeros(self.size)).mass
        self.kg = max(abs(straight), 1.0) if np.isfinite(straight) else 1.0

    def _evaluation(self, motion: ObjectMotion) -> LPEvaluation:
        model, mode = self.model, self.mode
        if self.law is None:
            traj, prob, terms = motion_problem(model, motion)
            y0, y1 = mass_line(prob, mode)
            lo, hi = torque_limits(model.motors, traj.qd)
            manip = manipulability(model, terms.J)
            t, ta, JT, A = traj.t, prob.tau_arms, prob.JT, prob.A
        else:
            dyn, sides, b, lo, hi, manip = law_dynamics(model, motion, self.law, LP_BOUND, mode)
            ta, y0, y1 = (np.vstack([c[0] + a * c[1] + b * c[2] for a in sides])
                          for c in (dyn.tau[0], dyn.y[0], dyn.y[1]))
            t, JT, A, lo, hi, prob = np.tile(self.law.t, 2), np.tile(dyn.JT, (2, 1, 1)), np.tile(dyn.A, (2, 1, 1)), \
                np.vstack([lo, lo]), np.vstack([hi, hi]), None
        active = ~self.res.passive
        ns = grasp_null_space(SimpleNamespace(A=A, JT=JT, active=active, stall=model.motors.stall_torque))
        if ns is None:
            raise PathOptimizationError("inverse.optimize: the grasp's null space changes rank along the path")
        plus, null = ns
        Aeq = np.concatenate([A, JT[:, ~active, :]], 1)
        rhs = np.stack([np.concatenate([y0, -ta[:, ~active]], 1), np.concatenate([y1, 0.0 * ta[:, ~active]], 1)])
        F = np.einsum("niq,xnq->xni", plus, rhs)
        miss = np.max(np.abs(np.einsum("nqi,xni->xnq", Aeq, F) - rhs), initial=0.0)
        if not miss <= 1e-9 * max(float(np.max(np.abs(rhs), initial=0.0)), 1e-300):
            raise PathOptimizationError("inverse.optimize: the object wrench and the passive joints' zero torque "
                                        "cannot be met by the grasp wrenches along the path")
        if self._null_ref is None:
            self._null_ref = null
        U, _, Vt = np.linalg.svd(np.swapaxes(null, 1, 2) @ self._null_ref)
        null = null @ (U @ Vt)                                  # the basis nearest the straight path's
        a = ta + np.einsum("nji,ni->nj", JT, F[0])
        b = np.einsum("nji,ni->nj", JT, F[1])
        return LPEvaluation(t, prob, a, b, lo, hi, manip, JT[:, self._act, :] @ null)

    @property
    def extra_size(self) -> int:
        """nz × the row-times with internal-wrench unknowns (`free`: all of them unless `extra_start` chose)."""
        e = self.evaluate(np.zeros(self.size))
        return int(e.C.shape[2] * (e.C.shape[0] if self.free is None else len(self.free)))

    def _G(self, e: LPEvaluation) -> np.ndarray:
        """(M, m, nz) C/τ_s per unit of scaled z."""
        return e.C / self._ts[None, :, None] * self.z_scale

    def _split(self, M: int) -> tuple[np.ndarray, np.ndarray]:
        """(the row-times with z unknowns, the others), indices into the M row-times."""
        free = np.arange(M) if self.free is None else self.free
        return free, np.setdiff1d(np.arange(M), free)

    def _count(self) -> int:
        e = self.evaluate(np.zeros(self.size))
        M, m, _ = e.C.shape
        free, rest = self._split(M)
        return int(np.sum(self._kept(len(free), m))) + len(rest) + len(self._rows(e)[3])

    def constraints(self, x: np.ndarray, mu: float, extra: np.ndarray | None = None) -> np.ndarray:
        """The NLP's rows (>= 0 feasible) at (x, μ, z): [T − μB − Gz; U + μB + Gz] of the row-times with z unknowns
        (`free`; `_rows`, G = C/τ_s), (c_i − μ)/`kg` of each other row-time i (c_i its LP capacity, `_row_lps`;
        ±LP_ROW_CLIP where unbounded or without an optimum), then W.

        Args:
            x: (K·k,) the scaled offsets.
            mu: kg, the carried mass.
            extra: (nz × len(free),) the scaled internal wrenches (row-time after row-time); None: zeros.

        Returns:
            np.ndarray: the rows; INFEASIBLE everywhere where the IK refuses x.
        """
        e = self.evaluate(x)
        return np.full(self._count(), INFEASIBLE) if e is None else self._nlp_rows(e, mu, extra)

    def _nlp_rows(self, e: LPEvaluation, mu: float, extra: np.ndarray | None, held=None) -> np.ndarray:
        """`constraints` of an accepted path's evaluation; with `held` (`_held` at another evaluation) the other
        row-times' rows are their LPs' Lagrangians at the held optima and multipliers (`_held_rows`)."""
        T, U, B, W = self._rows(e)
        G = self._G(e)
        M, m, nz = G.shape
        free, rest = self._split(M)
        T, U, B = (v.reshape(M, m)[free] for v in (T, U, B))
        z = np.zeros((len(free), nz)) if extra is None else np.asarray(extra, dtype=float).reshape(len(free), nz)
        Gz = np.einsum("njz,nz->nj", G[free], z)
        if held is None:
            others = self._lp_rows(self._rest_lps(e, rest), mu)
        else:
            others = self._held_rows(e, rest, mu, held)
        keep = self._kept(len(free), m)
        return np.concatenate([(T - mu * B - Gz)[keep[:, :m]], (U + mu * B + Gz)[keep[:, m:]], others, W])

    def _kept(self, F: int, m: int) -> np.ndarray:
        """(F, 2m) bool, the motor rows [τ_max side, τ_min side] of the free row-times that the NLP carries."""
        return np.ones((F, 2 * m), bool) if self.kept is None else self.kept

    def _rest_lps(self, e: LPEvaluation, rest: np.ndarray):
        """The `_row_lps` capacity batch of the row-times `rest` of evaluation e (the last few kept)."""
        hit = self._lps.get(id(e))
        if hit is None or hit[0] is not e or not np.array_equal(hit[1], rest):
            if len(self._lps) > 8:
                self._lps.clear()
            hit = self._lps[id(e)] = (e, rest, self._row_lps(e, None, rest) if len(rest) else None)
        return hit[2]

    def _lp_rows(self, lp, mu: float) -> np.ndarray:
        """(c_i − μ)/kg per LP of the batch (c_i its optimum; LP_ROW_CLIP where it is unbounded, −LP_ROW_CLIP where it
        has no optimum otherwise)."""
        if lp is None:
            return np.zeros(0)
        return np.select([lp.status == 0, lp.status == 3], [(lp.x[:, -1] - mu) / self.kg, LP_ROW_CLIP], -LP_ROW_CLIP)

    def _held(self, e: LPEvaluation):
        """The other row-times' LP optima (z, μ) and multipliers at evaluation e, for `_held_rows`; None: no others."""
        rest = self._split(e.C.shape[0])[1]
        lp = self._rest_lps(e, rest)
        return None if lp is None else (lp, rest)

    def _held_rows(self, e: LPEvaluation, rest: np.ndarray, mu: float, held) -> np.ndarray:
        """The other row-times' rows as the Lagrangian of their LPs at the held optimum v* = (z*, c*) and multipliers
        y >= 0: (c* + yᵀ s(v*) − μ)/kg, s the LP's row slacks at evaluation e (complementary slackness: c* at the
        held point itself). Its change with the path is the LP optimum's (the envelope theorem) where the basis
        is unique; held constant where the LP had no optimum."""
        lp, _ = held
        T, U, B, _ = self._rows(e)
        G = self._G(e)
        M, m, nz = G.shape
        T, U, B = (v.reshape(M, m)[rest] for v in (T, U, B))
        fixed = self._lp_rows(lp, mu)
        ok = lp.status == 0
        v = np.where(ok[:, None], np.nan_to_num(lp.x), 0.0)
        Gz = np.einsum("njz,nz->nj", G[rest], v[:, :-1])
        s = np.concatenate([T - v[:, -1:] * B - Gz, U + v[:, -1:] * B + Gz], 1)
        lagrangian = (v[:, -1] + np.sum(-lp.marginals * s, axis=1) - mu) / self.kg
        return np.where(ok, lagrangian, fixed)

    def _exact_columns(self, e: LPEvaluation, rows: int) -> np.ndarray:
        """d/dz (block-diagonal ∓G on the row-times with z) and d/dμ of the rows (rows, nz × len(free) + 1)."""
        B = self._rows(e)[2]
        G = self._G(e)
        M, m, nz = G.shape
        free, rest = self._split(M)
        F = len(free)
        block = np.zeros((F, m, F, nz))
        block[np.arange(F), :, np.arange(F), :] = G[free]
        block = block.reshape(F * m, F * nz)
        Bf = B.reshape(M, m)[free].ravel()
        keep = self._kept(F, m)
        k1, k2 = keep[:, :m].ravel(), keep[:, m:].ravel()
        n1, n2 = int(np.sum(k1)), int(np.sum(k2))
        out = np.zeros((rows, F * nz + 1))
        out[:n1, :-1], out[n1:n1 + n2, :-1] = -block[k1], block[k2]
        out[:n1, -1], out[n1:n1 + n2, -1] = -Bf[k1], Bf[k2]
        if len(rest):                                           # constant where the LP has no optimum
            out[n1 + n2:n1 + n2 + len(rest), -1] = np.where(self._rest_lps(e, rest).status == 0, -1.0 / self.kg, 0.0)
        return out

    def _row_lps(self, e: LPEvaluation, mu: float | None, rows: np.ndarray | None = None):
        """Per row-time (of `rows`; None: all) one LP on the NLP's rows: mu None: max μ >= 0 with z free (unknowns
        [z; μ]); else the largest common slack t <= 1 of the rows at that μ (unknowns [z; t]). Returns the
        `solve_lps` batch."""
        T, U, B, _ = self._rows(e)
        G = self._G(e)
        M, m, nz = G.shape
        pick = np.arange(M) if rows is None else rows
        T, U, B = (v.reshape(M, m)[pick] for v in (T, U, B))
        G = G[pick]
        k = len(pick)
        last = B if mu is None else np.ones((k, m))
        lastn = -B if mu is None else np.ones((k, m))
        A_ub = np.concatenate([np.concatenate([G, last[:, :, None]], 2), np.concatenate([-G, lastn[:, :, None]], 2)], 1)
        b_ub = np.concatenate([T, U], 1) if mu is None else np.concatenate([T - mu * B, U + mu * B], 1)
        c = np.zeros(nz + 1)
        c[-1] = -1.0
        bounds = [(None, None)] * nz + ([(0.0, None)] if mu is None else [(None, 1.0)])
        return solve_lps(c, A_ub, b_ub, np.zeros((k, 0, nz + 1)), np.zeros((k, 0)), bounds)

    def capacity(self, x: np.ndarray) -> Capacity | None:
        """The LP bound's capacity of the path of x on the optimiser's grid (None: refused by the IK): under the
        scenario's law `lp_capacity` of its inverse problem; under a law held fixed the LP of each row-time
        (`_row_lps`), its smallest optimum.

        Args:
            x: (K·k,) the scaled offsets.

        Returns:
            Capacity | None.
        """
        e = self.evaluate(x)
        if e is None:
            return None
        if e.prob is not None:
            return lp_capacity(e.prob, self.model.motors, self.res.passive, self.mode)
        lp = self._row_lps(e, None)
        upper = np.select([lp.status == 0, lp.status == 3], [lp.x[:, -1], np.inf], -np.inf)
        i = int(np.argmin(upper))
        mass = float(upper[i])
        return Capacity(mass, 0.0, mass >= 0.0, None, i, float(e.t[i]), None,
                        "" if mass >= 0.0 else "infeasible LP", upper)

    def extra_start(self, x: np.ndarray, mu: float) -> np.ndarray:
        """Choose the row-times with internal-wrench unknowns (`free`: those whose LP capacity at x is within Z_BAND
        of the least; all where that is not positive and finite) and start their scaled internal wrenches feasible
        for mass μ with the largest common slack per row-time (`_row_lps`); zeros on a row-time whose LP has no
        optimum, or where the IK refuses x.

        Args:
            x: (K·k,) the scaled offsets.
            mu: kg, the carried mass.

        Returns:
            np.ndarray: (extra_size,) the z of every free row-time, one after the other.
        """
        e = self.evaluate(x)
        self.free = self.kept = None
        if e is None:
            return np.zeros(self.extra_size)
        top = self._row_lps(e, None)
        upper = np.select([top.status == 0, top.status == 3], [top.x[:, -1], np.inf], -np.inf)
        low = float(np.min(upper))
        self.free = (np.flatnonzero(upper <= (1.0 + Z_BAND) * low) if np.isfinite(low) and low > 0.0
                     else np.arange(len(upper)))
        lp = self._row_lps(e, float(mu), self.free)
        z = np.where((lp.status == 0)[:, None], np.nan_to_num(lp.x[:, :-1]), 0.0)
        T, U, B, _ = self._rows(e)
        M, m, nz = e.C.shape
        T, U, B = (v.reshape(M, m)[self.free] for v in (T, U, B))
        Gz = np.einsum("njz,nz->nj", self._G(e)[self.free], z)
        self.kept = np.concatenate([T - mu * B - Gz, U + mu * B + Gz], 1) <= ROW_BAND
        return z.ravel()

    def scenario_grid_capacity(self, x: np.ndarray) -> float:
        """kg, the LP bound's capacity of the path of x under the scenario's law on its output_dt grid
        (`lp_motion_capacity`; nan where the IK refuses it).

        Args:
            x: (K·k,) the scaled offsets.

        Returns:
            float: kg.
        """
        try:
            return lp_motion_capacity(self.model, self.motion_of(x, self.model.inverse.object_motion.output_dt),
                                      self.mode).mass
        except CoopsimError:
            return float("nan")


STALL_GAIN = 1e-3         # a run stops when its best accepted payload gained less than this, relative,
STALL_ITERATIONS = 15     # over this many iterations
SLSQP_STATUS = {          # scipy's SLSQP exit modes, worded for a user
    0: "converged", 2: "more equality constraints than unknowns",
    3: "its least-squares subproblem took more than 3 n iterations",
    4: "the linearised constraints are incompatible (no step satisfies them)",
    5: "its least-squares subproblem is singular (matrix E)", 6: "its least-squares subproblem is singular (matrix C)",
    7: "its equality subproblem is rank-deficient", 8: "the line search found no descent (positive directional derivative)",
    9: "the iteration limit was reached",
}


def status_text(status: int, max_iterations: int | None = None) -> str:
    """What an SLSQP exit status means, in words (`SLSQP_STATUS`).

    Args:
        status: SLSQP's exit mode.
        max_iterations: the run's iteration limit, named with status 9; None: not named.

    Returns:
        str: e.g. 'status 9: the iteration limit was reached (inverse.optimize.max_iterations: 100)'.
    """
    text = f"status {status}: {SLSQP_STATUS.get(status, 'an exit mode SciPy does not document')}"
    return text + (f" (inverse.optimize.max_iterations: {max_iterations})"
                   if status == 9 and max_iterations is not None else "")


def accepted_mass(problem: FreePathProblem, x: np.ndarray) -> float:
    """kg, the closed-form capacity of the path of x where the inverse kinematics accepts it with every arm's
    manipulability above its margin and the bare object carried; else nan.

    Args:
        problem: the FreePathProblem.
        x: (K·k,) the scaled offsets.

    Returns:
        float: kg, or nan.
    """
    e = problem.evaluate(x)
    if e is None or np.min(problem._rows(e)[3], initial=np.inf) < 0.0:
        return float("nan")
    cap = problem.capacity(x)
    carried = cap.feasible and cap.lower <= nominal_mass(problem.model, problem.mode) <= cap.mass
    return float(cap.mass) if carried and np.isfinite(cap.mass) else float("nan")


def _solve_start(problem: FreePathProblem, x0: np.ndarray, index: int, max_iter: int):
    """One SLSQP run from x0: (x, StartResult), x the heaviest accepted point among its start, its iterates
    and its end point (`accepted_mass`), so a run never ends below its start. It stops early when that
    payload gained less than STALL_GAIN (relative) over the last STALL_ITERATIONS iterations: a converged
    run by that criterion (on the Panda carry the capacity is nearly flat in the path, gravity-bound, and
    SLSQP's infeasible iterates wander while the payload of its accepted ones no longer grows)."""
    from scipy.optimize import minimize

    t0, n0 = time.perf_counter(), problem.evaluations
    x0 = np.asarray(x0, dtype=float)
    start = problem.capacity(x0)
    mu0 = max(0.0, start.mass) if start is not None and np.isfinite(start.mass) else 0.0
    ref = max(mu0, 1.0)                                  # μ in units of the start's capacity
    nx = problem.size                                    # unknowns [x; extra; μ/ref] (`extra_start`)
    e0 = problem.extra_start(x0, mu0)

    def split(z):
        return z[:nx], z[-1] * ref, z[nx:-1]

    def jac(z):
        J = problem.jacobian(*split(z))
        J[:, -1] *= ref
        return J

    m0 = accepted_mass(problem, x0)
    best = {"x": x0, "mass": m0 if np.isfinite(m0) else -np.inf, "iterate": 0, "history": [m0], "stalled": False}

    def watch(z):
        x = z[:nx].copy()
        m = accepted_mass(problem, x)
        best["history"].append(m)
        if np.isfinite(m) and m > best["mass"]:
            best.update(x=x, mass=m, iterate=len(best["history"]) - 1)
        h = np.array(best["history"])
        if len(h) > STALL_ITERATIONS and np.isfinite(best["mass"]):
            before = np.nanmax(np.append(h[:-STALL_ITERATIONS], -np.inf))
            if before > -np.inf and best["mass"] <= before * (1 + STALL_GAIN):
                best["stalled"] = True
                raise StopIteration

    bound = [(-b, b) for b in problem.bounds] + [(None, None)] * len(e0) + [(0.0, None)]
    opt = minimize(lambda z: -z[-1], np.concatenate([x0, e0, [mu0 / ref]]), jac=lambda z: np.append(np.zeros(len(z) - 1), -1.0),
                   method="SLSQP", bounds=bound,
                   constraints=[{"type": "ineq", "fun": lambda z: problem.constraints(*split(z)), "jac": jac}],
                   options={"maxiter": max_iter, "ftol": 1e-9}, callback=watch)
    end = accepted_mass(problem, opt.x[:nx])
    if np.isfinite(end) and end >= best["mass"] * (1 - 1e-9):                  # its end point, unless lighter
        best.update(x=opt.x[:nx].copy(), mass=end, iterate=int(opt.nit))
    if best["stalled"]:
        success, status = True, 0
        message = (f"stopped: its payload gained less than {100 * STALL_GAIN:g} % over the last {STALL_ITERATIONS} "
                   f"iterations (best at iterate {best['iterate']} of {int(opt.nit)})")
    else:
        success, status = bool(opt.success), int(opt.status)
        message = status_text(status, max_iter) + (f"; its best accepted point is iterate {best['iterate']}"
                                          if best["iterate"] != int(opt.nit) else "")
    x = best["x"]
    cap = problem.capacity(x)
    mass = cap.mass if cap is not None else float("nan")
    return x, StartResult(index, float(mass), float(start.mass if start is not None else np.nan), success, status, message,
                          int(opt.nit), problem.evaluations - n0, time.perf_counter() - t0,
                          control_points=problem.control_points)


def _starts(problem: FreePathProblem, count: int, seed: int) -> list[np.ndarray]:
    """The straight path, then count − 1 random offsets (normal, START_SPREAD, seeded), each halved until
    the inverse kinematics accepts it (at most 8 times; then the straight path)."""
    rng = np.random.default_rng(seed)
    out = [np.zeros(problem.size)]
    for _ in range(count - 1):
        x = rng.normal(0.0, START_SPREAD, problem.size)
        for _ in range(8):
            if problem.evaluate(x) is not None:
                break
            x = 0.5 * x
        else:
            x = np.zeros(problem.size)
        out.append(x)
    return out


def _timings(problem: FreePathProblem) -> tuple[float, float]:
    """(one evaluation, one Jacobian) wall time s at the straight path, uncached."""
    problem._cache.clear()
    t0 = time.perf_counter()
    problem.evaluate(np.zeros(problem.size))
    t1 = time.perf_counter()
    problem.jacobian(np.zeros(problem.size), 0.0)
    return t1 - t0, time.perf_counter() - t1


def optimize_path(model: Model, method: str, mode: str | None = None, weights: bool = False,
                  duration: float | None = None, retime: bool = True, progress=None) -> PathOptimum:
    """The free path between the first and last waypoint poses that carries the most (module docstring).

    First the path under the scenario's time law (several starts; with `weights` the minimum-energy
    weights in turn); then, with `retime`, path and time law in turn: the heaviest payload the path
    carries within `duration` with its time law free (`retimed_capacity`), the path optimised again with
    that law held fixed as s(t) (`evaluate_law`), RETIME_ROUNDS times; each step keeps the last one's
    payload feasible, so the payload never drops.

    Args:
        model: the Model (inverse.object_motion with at least two waypoints; inverse.optimize).
        method: a linear resolution ('paper', 'nonsqueezing', 'min_energy') or 'lp' (the LP bound,
            `LPFreePathProblem`).
        mode: 'scaled' or 'payload'; None: `capacity_mode`.
        weights: with 'min_energy', optimise its energy weights with the path.
        duration: s, T_max of the retimed stage; None: the waypoints' span.
        retime: also the retimed stage.
        progress: called with the fraction done (0 to 1) after each run; None: silent.

    Returns:
        PathOptimum: the best paths and payloads, every run's statistics, the gradients' cost.

    Raises:
        PathOptimizationError: the straight path is refused by the inverse kinematics, or every start ends
            on a path it refuses.
        RetimeError: the retimed stage has no motion carrying the bare object within `duration`.
        ValueError: `weights` with another method than 'min_energy'.
    """
    if weights and method != "min_energy":
        raise ValueError("optimize_path: weights are optimised with the minimum-energy resolution only")
    t0 = time.perf_counter()
    opt, mode = model.inverse.optimize, mode or capacity_mode(model)
    om = model.inverse.object_motion
    problem = (LPFreePathProblem(model, lp_resolution(model), mode) if method == LP_BOUND
               else FreePathProblem(model, resolution_for(model, method), mode))
    straight = problem.capacity(np.zeros(problem.size))
    eval_s, jacobian_s = _timings(problem)
    total = (WEIGHT_ROUNDS if weights else 1) + (RETIME_ROUNDS if retime else 0)
    runs, (mass, x, problem, best), others = _law_stage(problem, weights, lambda f: _tell(progress, f * (total - (
        RETIME_ROUNDS if retime else 0)) / total))
    quintic = (problem.motion_of(x, om.output_dt), problem.capacity(x))
    rounds = []
    if retime:
        T = float(om.times[-1] - om.times[0]) if duration is None else float(duration)
        intervals = max(1, int(round((om.times[-1] - om.times[0]) / opt.sample_dt)))
        x, rounds, runs = _retime_stage(problem, x, T, intervals, runs, progress, total, others)
    return PathOptimum(quintic[0], quintic[1], straight, problem.res, mode, best, tuple(runs), eval_s,
                       jacobian_s, problem.size, problem.motion_of(x, om.output_dt) if retime else None,
                       rounds[-1]["retiming"] if rounds else None, tuple(rounds), time.perf_counter() - t0)


def _tell(progress, fraction: float) -> None:
    if progress is not None:
        progress(fraction)


def _law_stage(problem: FreePathProblem, weights: bool, progress):
    """The path under the scenario's time law (and the weights in turn): (runs, best, others), best = (mass kg,
    x, problem, its StartResult): the converged run heaviest on the scenario's output_dt grid (the optimiser's
    coarser grid can favour a path whose peak falls between its samples), else the heaviest; others: the
    offsets (on best's problem) of the other candidate paths for the retimed stage.

    Continuation in K: with K > COARSE[0] control points every start (the straight path and the random
    ones) runs first on COARSE[0] points (k unknowns for K·k, each Jacobian as much cheaper); the best of
    them, refined to each following level of COARSE and then to K (`FreePathProblem.refined`: the same
    curve, a cubic B-spline space holding every quadratic and cubic), starts one run there and competes with
    its end point; then the straight path runs on K points too (on the Panda carry's paper W⁺ it finds an
    optimum the refined one does not). Every level's best and the straight run's end are candidates of the
    retimed stage (a path heavier under the scenario's law need not be heavier retimed)."""
    opt, runs, best, others = problem.model.inverse.optimize, [], None, []
    rounds = WEIGHT_ROUNDS if weights else 1
    for rnd in range(rounds):
        levels = [k for k in COARSE if k < problem.control_points]
        if rnd == 0 and levels:
            stage = problem.variant(control_points=levels[0])
            lead = _best_run(stage, _starts(stage, opt.starts, opt.seed), runs, None,
                             lambda f: progress((rnd + 0.5 * f) / rounds))
            leads = [(lead[1], stage.control_points)]
            for i, k in enumerate(levels[1:] + [problem.control_points]):
                fine = problem if k == problem.control_points else problem.variant(control_points=k)
                x_lead = fine.refined(lead[1], stage.control_points)
                lead = _best_run(fine, [x_lead], runs, (lead[0], x_lead, fine, lead[3]),
                                 lambda f: progress((rnd + 0.5 + 0.3 * (i + f) / len(levels)) / rounds))
                stage = fine
                leads.append((lead[1], k))
            ends = []
            best = _best_run(problem, [np.zeros(problem.size)], runs, lead, lambda f: progress((rnd + 1) / rounds),
                             ends)                       # the straight path on K points too
            others = [problem.refined(x_k, k) for x_k, k in leads[:-1]] + [leads[-1][0], ends[0]]
            others = [x for x in others if x is not best[1]]
        else:
            starts = _starts(problem, opt.starts, opt.seed) if rnd == 0 else [best[1]]
            best = _best_run(problem, starts, runs, best, lambda f: progress((rnd + f) / rounds))
        if weights and rnd < rounds - 1:
            w, _ = optimise_weights(best[2].evaluate(best[1]).prob, best[2].res, problem.model.motors, problem.mode)
            problem = FreePathProblem(problem.model, replace(problem.res, weights=w), problem.mode)
    return runs, best, others


def _best_run(problem: FreePathProblem, starts: list, runs: list, best, progress, ends: list | None = None):
    """One run from each start (appended to runs, its end point to `ends` if given): the best of them and
    `best` (as `_law_stage` ranks them).

    Raises:
        PathOptimizationError: no run and no `best` ends on a path the inverse kinematics accepts.
    """
    for i, x0 in enumerate(starts):
        x, run = _solve_start(problem, x0, len(runs), problem.model.inverse.optimize.max_iterations)
        run = replace(run, scenario_grid_kg=problem.scenario_grid_capacity(x))
        runs.append(run)
        if ends is not None:
            ends.append(x)
        if np.isfinite(run.scenario_grid_kg) and (best is None or (run.success, run.scenario_grid_kg) > (
                best[3].success, best[0])):
            best = (run.scenario_grid_kg, x, problem, run)     # a converged run before any other
        progress((i + 1) / len(starts))
    if best is None:
        raise PathOptimizationError("inverse.optimize: no start ends on a path the inverse kinematics accepts")
    return best


def _retime_stage(problem: FreePathProblem, x: np.ndarray, duration: float, intervals: int, runs: list,
                  progress, total: int, others: tuple = ()):
    """Path and retimed law in turn from x (or the heaviest retimed of x and `others`): (x, rounds, runs); each
    round a dict of the retimed payload (mass_kg, retiming) at the round's path and the fixed-law run that
    followed (its StartResult or None). A round whose retimed payload is below the last one's is dropped and
    the last one stands (the fixed-law run checks the law at its grid points only, the retiming also between
    them, so a fixed-law gain may not survive retiming). Where the inverse kinematics (or the joint-range check
    between the law's grid points) refuses the path under the law, the round has a "note" and no run."""
    model, res, mode = problem.model, problem.res, problem.mode
    rounds, x_new = [], x
    for rnd in range(RETIME_ROUNDS):
        if rnd == 0:
            mass, r = retimed_capacity(model, problem.motion_of(x), res, mode, duration, intervals)
            for other in others:
                try:
                    found = retimed_capacity(model, problem.motion_of(other), res, mode, duration, intervals,
                                             above=mass)
                except CoopsimError:
                    continue
                if found is not None and found[0] > mass:
                    x, (mass, r) = other, found
        else:
            found = retimed_capacity(model, problem.motion_of(x_new), res, mode, duration, intervals,
                                     above=rounds[-1]["mass_kg"])
            if found is None or not found[0] > rounds[-1]["mass_kg"]:
                break                                    # the last round's path and law stand
            x, (mass, r) = x_new, found
        rounds.append({"mass_kg": mass, "retiming": r, "run": None})
        _tell(progress, (total - RETIME_ROUNDS + rnd + 0.5) / total)
        if rnd == RETIME_ROUNDS - 1:
            break
        try:
            fixed = problem.variant(law=r.law)
        except PathOptimizationError:                    # the straight path under the law: the manipulability's base
            fixed = None
        if fixed is None or fixed.evaluate(x) is None:
            rounds[-1]["note"] = ("no fixed-law pass: the path under the retimed law is refused by the inverse "
                                  "kinematics or its joint-range check between the law's grid points")
            break
        x_new, run = _solve_start(fixed, x, len(runs), problem.model.inverse.optimize.max_iterations)
        runs.append(run)
        rounds[-1]["run"] = run
        _tell(progress, (total - RETIME_ROUNDS + rnd + 1) / total)
        if not (np.isfinite(run.capacity_kg) and run.capacity_kg > mass * (1 + 1e-9)):
            break                                        # no gain with the law held: the last retiming stands
    return x, rounds, runs
