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
with the closed-chain inverse kinematics of the path (`object_motion_trajectory`): a path it refuses is
an infeasible point (every constraint −1). SciPy's SLSQP (sequential quadratic programming on dense
Jacobians: the problem has tens of unknowns and thousands of rows) solves it from the straight path and
from random starts (fixed seed); the constraint Jacobian in δ is by forward differences of the whole
chain (IK, compiled inverse dynamics, distribution), in μ exact. The best start is the one whose
capacity, recomputed in closed form at its end point (`method_capacity`), is largest.

With `weights`, the minimum-energy resolution's energy weights Q are optimised with the path (the
paper's closing suggestion): path and weights in turn (`coopsim.inverse.capacity.optimise_weights` on
the optimum's trajectory), each round started from the last, so the capacity never drops.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from coopsim.core.errors import CoopsimError
from coopsim.core.model import Model, ObjectMotion, PathSpline, torque_limits
from coopsim.forward.diagnostics import manipulability
from coopsim.inverse.capacity import Capacity, affine_capacity, affine_torques, optimise_weights
from coopsim.inverse.problem import InverseProblem, Resolution, inverse_problem
from coopsim.inverse.solve import resolution_for
from coopsim.inverse.spline_path import KIND, straight_control_points
from coopsim.inverse.trajectory import JointTrajectory, object_motion_trajectory

FD_STEP = 1e-7            # forward-difference step in the scaled unknowns (× reach m, × 1 rad)
START_SPREAD = 0.01       # random starts: standard deviation of the scaled offsets
OFFSET_BOUND = 0.5        # |offset| <= this × the arms' mean reach (m) or this × π/2 rad
WEIGHT_ROUNDS = 2         # path / weights rounds with `weights`
INFEASIBLE = -1.0         # every constraint's value where the inverse kinematics refuses the path


class PathOptimizationError(CoopsimError):
    """The free path cannot be optimised as asked (no feasible start, or the ends out of reach)."""


@dataclass(frozen=True, eq=False)
class PathEvaluation:
    """One free path on the optimiser's grid (N samples, n joints, r arms).

    Attributes:
        traj: the JointTrajectory of the path's closed-chain inverse kinematics.
        prob: the InverseProblem along it.
        a: (N, n) N·m (N on a prismatic joint), the torques at μ = 0.
        b: (N, n) N·m per kg, their rate with the carried mass.
        lo: (N, n) N·m, τ_min of eq. 36 along the path.
        hi: (N, n) N·m, τ_max.
        manip: (N, r) each arm's manipulability (`coopsim.forward.diagnostics.manipulability`).
    """

    traj: JointTrajectory
    prob: InverseProblem
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
        capacity_kg: kg, the closed-form capacity at its end point on the optimiser's grid (nan: IK refused).
        start_capacity_kg: kg, the capacity at its start point.
        success: SLSQP reports convergence.
        status: SLSQP's exit status (0: converged).
        message: SLSQP's message.
        iterations: its iterations.
        evaluations: path evaluations (IK + inverse dynamics), finite differences included.
        wall_s: s, its wall time.
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


@dataclass(frozen=True, eq=False)
class PathOptimum:
    """The optimised free path and how it was found.

    Attributes:
        motion: the ObjectMotion of the optimum (two waypoints and its B-spline path, the scenario's time
            law and output_dt).
        capacity: the Capacity at the optimum on the optimiser's grid.
        straight: the Capacity of the straight path on that grid (the first start).
        resolution: the Resolution optimised for (its weights optimised with `weights`).
        mode: 'scaled' or 'payload'.
        success: the best start converged.
        starts: one StartResult per run (with `weights`, one per round and start).
        eval_s: s, the wall time of one path evaluation (IK, inverse dynamics, distribution).
        jacobian_s: s, the wall time of one constraint Jacobian (forward differences).
        unknowns: the number of path unknowns (K × k).
        wall_s: s, the whole optimisation's wall time.
    """

    motion: ObjectMotion
    capacity: Capacity
    straight: Capacity
    resolution: Resolution
    mode: str
    success: bool
    starts: tuple
    eval_s: float
    jacobian_s: float
    unknowns: int
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
    from coopsim.compiled import api

    traj = object_motion_trajectory(model, motion)
    terms = api.inverse_terms(model, traj.q, traj.qd, traj.qdd)
    prob = inverse_problem(model, traj, model.inverse.payload_position, terms=terms)
    a, b = affine_torques(prob, res, mode)
    lo, hi = torque_limits(model.motors, traj.qd)
    return PathEvaluation(traj, prob, a, b, lo, hi, manipulability(model, terms.J))


class FreePathProblem:
    """The epigraph NLP of one scenario, resolution and mode (see the module docstring).

    Args:
        model: the Model (its inverse.object_motion's first and last waypoints, inverse.optimize).
        res: the Resolution (linear in the net object wrench).
        mode: 'scaled' or 'payload'.

    Attributes:
        model: the Model.
        res: the Resolution.
        mode: the capacity mode.
        ends: the two-waypoint ObjectMotion on the optimiser's grid (inverse.optimize.sample_dt).
        straight: the PathSpline of the straight path (offsets are from it).
        scale: (K·k,) the unknowns' units: the arms' mean reach (m) on position rows, 1 rad on rotation rows.
        bounds: (K·k,) the bound on each scaled offset's magnitude.
        evaluations: path evaluations so far.
    """

    def __init__(self, model: Model, res: Resolution, mode: str):
        opt = model.inverse.optimize
        self.model, self.res, self.mode = model, res, mode
        self.ends = end_poses(model.inverse.object_motion, opt.sample_dt)
        self.straight = straight_control_points(self.ends, opt.control_points)
        S = model.rows
        reach = float(np.mean([np.sum(np.linalg.norm(a.joint_pos[1:], axis=1)) + np.linalg.norm(a.ee_pos)
                               for a in model.arms]))
        self._basis = S.T                                           # (6, k): offsets [dp; dφ] = Sᵀ δ
        self._row_scale = np.where(np.any(S[:, :3] != 0, axis=1), reach, 1.0)
        self.scale = np.tile(self._row_scale, opt.control_points)
        position = np.tile(np.any(S[:, :3] != 0, axis=1), opt.control_points)
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
                self._cache[key] = evaluate_motion(self.model, self.motion_of(x), self.res, self.mode)
            except CoopsimError:
                self._cache[key] = None
        return self._cache[key]

    def capacity(self, x: np.ndarray) -> Capacity | None:
        """The closed-form capacity of the path of x on the optimiser's grid (None: refused by the IK).

        Args:
            x: (K·k,) the scaled offsets.

        Returns:
            Capacity | None.
        """
        e = self.evaluate(x)
        return None if e is None else affine_capacity(e.a, e.b, e.lo, e.hi, e.traj.t, ~self.res.passive)

    def _rows(self, e: PathEvaluation) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(T, U, B, W): (τ_max − a)/τ_s, (a − τ_min)/τ_s, b/τ_s over the active motors, flattened, and
        the manipulability rows w/w₀ − margin."""
        act, ts = self._act, self._ts
        T = ((e.hi - e.a)[:, act] / ts).ravel()
        U = ((e.a - e.lo)[:, act] / ts).ravel()
        B = (e.b[:, act] / ts).ravel()
        W = (e.manip / self._manip0 - self.model.inverse.optimize.manipulability_margin).ravel()
        return T, U, B, W

    def constraints(self, x: np.ndarray, mu: float) -> np.ndarray:
        """The NLP's inequality rows (>= 0 feasible) at (x, μ).

        Args:
            x: (K·k,) the scaled offsets.
            mu: kg, the carried mass.

        Returns:
            np.ndarray: [T − μB; U + μB; T; U; W] (see `_rows`); INFEASIBLE everywhere where the IK refuses.
        """
        e = self.evaluate(x)
        if e is None:
            return np.full(self._count(), INFEASIBLE)
        T, U, B, W = self._rows(e)
        return np.concatenate([T - mu * B, U + mu * B, T, U, W])

    def _count(self) -> int:
        T, _, _, W = self._rows(self.evaluate(np.zeros(self.size)))
        return 4 * len(T) + len(W)

    def jacobian(self, x: np.ndarray, mu: float) -> np.ndarray:
        """d(constraints)/d(x, μ) (rows, K·k + 1): forward differences in x (backward where the forward
        point is refused), exact in μ.

        Args:
            x: (K·k,) the scaled offsets.
            mu: kg, the carried mass.

        Returns:
            np.ndarray: the Jacobian; zero rows in x where the IK refuses x itself.
        """
        x = np.asarray(x, dtype=float)
        c0 = self.constraints(x, mu)
        J = np.zeros((len(c0), self.size + 1))
        e = self.evaluate(x)
        if e is None:
            return J
        for i in range(self.size):
            for h in (FD_STEP, -FD_STEP):
                xi = x.copy()
                xi[i] += h
                if self.evaluate(xi) is not None:
                    J[:, i] = (self.constraints(xi, mu) - c0) / h
                    break
        B = self._rows(e)[2]
        J[:, -1] = np.concatenate([-B, B, np.zeros(len(c0) - 2 * len(B))])
        return J


def _solve_start(problem: FreePathProblem, x0: np.ndarray, index: int, max_iter: int):
    """One SLSQP run from x0: (x, StartResult)."""
    from scipy.optimize import minimize

    t0, n0 = time.perf_counter(), problem.evaluations
    start = problem.capacity(x0)
    mu0 = max(0.0, start.mass) if start is not None and np.isfinite(start.mass) else 0.0
    ref = max(mu0, 1.0)                                  # μ in units of the start's capacity

    def split(z):
        return z[:-1], z[-1] * ref

    def jac(z):
        J = problem.jacobian(*split(z))
        J[:, -1] *= ref
        return J

    bound = [(-b, b) for b in problem.bounds] + [(0.0, None)]
    opt = minimize(lambda z: -z[-1], np.append(x0, mu0 / ref), jac=lambda z: np.append(np.zeros(len(z) - 1), -1.0),
                   method="SLSQP", bounds=bound,
                   constraints=[{"type": "ineq", "fun": lambda z: problem.constraints(*split(z)), "jac": jac}],
                   options={"maxiter": max_iter, "ftol": 1e-9})
    x = opt.x[:-1]
    cap = problem.capacity(x)
    mass = cap.mass if cap is not None else float("nan")
    return x, StartResult(index, float(mass), float(mu0 if start is not None else np.nan), bool(opt.success),
                          int(opt.status), str(opt.message), int(opt.nit), problem.evaluations - n0,
                          time.perf_counter() - t0)


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
                  progress=None) -> PathOptimum:
    """The free path between the first and last waypoint poses that carries the most (module docstring).

    Args:
        model: the Model (inverse.object_motion with at least two waypoints; inverse.optimize).
        method: a linear resolution ('paper', 'nonsqueezing', 'min_energy').
        mode: 'scaled' or 'payload'; None: `capacity_mode`.
        weights: with 'min_energy', optimise its energy weights with the path.
        progress: called with the fraction done (0 to 1) after each start; None: silent.

    Returns:
        PathOptimum: the best start's path and capacity, every start's statistics, the gradients' cost.

    Raises:
        PathOptimizationError: the straight path is refused by the inverse kinematics, or every start ends
            on a path it refuses.
        ValueError: `weights` with another method than 'min_energy'.
    """
    if weights and method != "min_energy":
        raise ValueError("optimize_path: weights are optimised with the minimum-energy resolution only")
    t0 = time.perf_counter()
    opt, mode = model.inverse.optimize, mode or capacity_mode(model)
    res = resolution_for(model, method)
    problem = FreePathProblem(model, res, mode)
    straight = problem.capacity(np.zeros(problem.size))
    eval_s, jacobian_s = _timings(problem)
    runs, best = [], None                              # best: (capacity kg, x, problem)
    rounds = WEIGHT_ROUNDS if weights else 1
    for rnd in range(rounds):
        starts = _starts(problem, opt.starts, opt.seed) if rnd == 0 else [best[1]]
        for i, x0 in enumerate(starts):
            x, run = _solve_start(problem, x0, len(runs), opt.max_iterations)
            runs.append(run)
            if np.isfinite(run.capacity_kg) and (best is None or run.capacity_kg > best[0]):
                best = (run.capacity_kg, x, problem, run.success)
            if progress is not None:
                progress((rnd + (i + 1) / len(starts)) / rounds)
        if best is None:
            raise PathOptimizationError("inverse.optimize: no start ends on a path the inverse kinematics accepts")
        if weights and rnd < rounds - 1:
            w, _ = optimise_weights(problem.evaluate(best[1]).prob, problem.res, model.motors, mode)
            problem = FreePathProblem(model, replace(problem.res, weights=w), mode)
    _, x, problem, success = best
    return PathOptimum(problem.motion_of(x, model.inverse.object_motion.output_dt), problem.capacity(x), straight,
                       problem.res, mode, success, tuple(runs), eval_s, jacobian_s, problem.size,
                       time.perf_counter() - t0)
