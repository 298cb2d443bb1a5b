"""The geometric object path p(s), R(s), s ∈ [0, 1], and the closed-chain joint path θ(s) along it.

A time law s(t) turns a path into a motion: with ṡ = ds/dt, s̈ = d²s/dt² the object's twist is
ṡ [p′; ω′] and its acceleration s̈ [p′; ω′] + ṡ² [p″; ω″] (′ = d/ds; ω′ is the angular velocity per
unit ṡ, world axes, ω″ its s-derivative), and every arm's joints move with

    θ̇ = θ′ ṡ,   θ̈ = θ′ s̈ + θ″ ṡ²,

θ′, θ″ the joint path's s-derivatives: the joint "velocity" and "acceleration" of the closed-chain
inverse kinematics at ṡ = 1, s̈ = 0 (`joint_path`).

A path is made of smooth pieces [s_k, s_{k+1}] (`ObjectPath.knots`); its tangent may jump at a knot,
so a time law rests there (ṡ = 0). Any object with `knots` and `at` is a path (`ObjectPath`, e.g. a
B-spline in position and orientation); `WaypointPath` is the one of a scenario's `inverse.object_motion`:
waypoint k at s = k/(w − 1), a straight line and a single-axis rotation uniform in s between them
(the geometry of `coopsim.inverse.trajectory.object_motion_at`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial
from typing import Callable, Protocol

import numpy as np

from coopsim.core.errors import ConstraintError
from coopsim.core.model import Model, ObjectMotion
from coopsim.core.spatial import axis_angle_to_rot, rot_log
from coopsim.dynamics.kinematics import reach_check
from coopsim.forward.diagnostics import joint_limit_reason, joint_limit_violation
from coopsim.inverse.trajectory import (JointTrajectory, TrajectoryError, arm_ik, arm_rates, grasp_targets,
                                        min_norm_ik, pose_error, redundant_rates)


@dataclass(frozen=True, eq=False)
class PathPoints:
    """The object path at M points (world axes, SI units).

    Attributes:
        s: (M,) the path parameter.
        piece: (M,) int, the smooth piece each point is evaluated on (a knot belongs to both pieces
            around it; the piece says which one's derivatives are meant).
        p: (M, 3) m, the object's centre of mass C relative to `origin`.
        R: (M, 3, 3) the object's orientation, world ← object.
        d1: (M, 6) [p′ (m); ω′ (rad)], the twist per unit ṡ.
        d2: (M, 6) [p″ (m); ω″ (rad)], its s-derivative.
        origin: (3,) m, world: the point p is relative to.
    """

    s: np.ndarray
    piece: np.ndarray
    p: np.ndarray
    R: np.ndarray
    d1: np.ndarray
    d2: np.ndarray
    origin: np.ndarray


class ObjectPath(Protocol):
    """A geometric object path s ∈ [0, 1] ↦ (p(s), R(s)), twice differentiable on each piece.

    What an implementation provides (e.g. a B-spline in position and a rotation-vector spline in
    orientation): the knots between its smooth pieces and its points and s-derivatives there. The
    time law rests at every knot, so pieces may meet at a corner.

    Attributes:
        knots: (P + 1,) the s values bounding the P smooth pieces, increasing from 0 to 1.
    """

    knots: np.ndarray

    def at(self, s: np.ndarray, piece: np.ndarray) -> PathPoints:
        """The path at points s (M,) on the pieces `piece` (M,) int (a knot belongs to both pieces).

        Args:
            s: (M,) the path parameter, within each point's piece.
            piece: (M,) int, the piece of each point (0 .. P − 1).

        Returns:
            PathPoints: positions, orientations and the first two s-derivatives (world axes).
        """
        ...


@dataclass(frozen=True, eq=False)
class WaypointPath:
    """The path of an ObjectMotion's waypoints: waypoint k at s_k = k/(w − 1), uniform in s between.

    On piece k with σ = (s − s_k)/Δ, Δ = 1/(w − 1): p = p_k + σ (p_{k+1} − p_k), R = R_k Exp(σφ),
    φ = log(R_kᵀ R_{k+1}); p′ = (p_{k+1} − p_k)/Δ, ω′ = R_k φ/Δ, p″ = ω″ = 0.

    Attributes:
        motion: the ObjectMotion whose waypoints (positions, rotations) make the path.
        knots: (w,) the waypoints' path parameters s_k.
    """

    motion: ObjectMotion
    knots: np.ndarray

    @classmethod
    def of(cls, motion: ObjectMotion) -> "WaypointPath":
        """The path through a motion's waypoints.

        Args:
            motion: the ObjectMotion (w ≥ 2 waypoints).

        Returns:
            WaypointPath: knots at k/(w − 1).
        """
        return cls(motion, np.linspace(0.0, 1.0, len(motion.times)))

    def at(self, s: np.ndarray, piece: np.ndarray) -> PathPoints:
        """The path at points s on pieces `piece` (see `ObjectPath.at`).

        Args:
            s: (M,) the path parameter.
            piece: (M,) int, the waypoint segment of each point.

        Returns:
            PathPoints: relative to the first waypoint's position.
        """
        m = self.motion
        s, piece = np.asarray(s, dtype=float), np.asarray(piece, dtype=int)
        origin = m.positions[0]
        delta = np.diff(self.knots)[piece]
        sigma = (s - self.knots[piece]) / delta
        dp = m.positions[piece + 1] - m.positions[piece]
        phi = np.array([rot_log(m.rotations[k].T @ m.rotations[k + 1]) for k in range(len(self.knots) - 1)])[piece]
        R = np.empty((len(s), 3, 3))
        for i, (k, f, x) in enumerate(zip(piece, phi, sigma)):
            angle = float(np.linalg.norm(f))
            R[i] = m.rotations[k] @ axis_angle_to_rot(f / angle, x * angle) if angle > 0 else m.rotations[k]
        w = np.einsum("mij,mj->mi", m.rotations[piece], phi)
        d1 = np.concatenate([dp, w], axis=1) / delta[:, None]
        p = (m.positions[piece] - origin) + sigma[:, None] * dp
        return PathPoints(s, piece, p, R, d1, np.zeros_like(d1), origin)


def path_grid(knots: np.ndarray, intervals: int) -> tuple[np.ndarray, np.ndarray]:
    """A grid of `intervals` equal intervals on each piece, knots repeated (the end of one piece, the
    start of the next).

    Args:
        knots: (P + 1,) the pieces' ends.
        intervals: the intervals per piece (≥ 1).

    Returns:
        tuple[np.ndarray, np.ndarray]: s (P (intervals + 1),) and piece (P (intervals + 1),) int.
    """
    u = np.linspace(0.0, 1.0, intervals + 1)
    s = np.concatenate([a + u * (b - a) for a, b in zip(knots[:-1], knots[1:])])
    return s, np.repeat(np.arange(len(knots) - 1), intervals + 1)


@dataclass(frozen=True, eq=False)
class JointPath:
    """The closed chain's joint path along an object path at N points (stacked arm after arm).

    Attributes:
        points: the PathPoints (N).
        q: (N, n) rad (m on a prismatic joint), θ(s).
        d1: (N, n) rad (m), θ′(s) = dθ/ds.
        d2: (N, n) rad (m), θ″(s).
        recipe: (s, piece) ↦ the JointPath of the same path, branch and redundancy resolution at other
            points (`joint_path` with this path's arguments), or None (`refined` then has none).
    """

    points: PathPoints
    q: np.ndarray
    d1: np.ndarray
    d2: np.ndarray
    recipe: Callable | None = None
    _refined: dict = field(default_factory=dict, init=False, repr=False)

    @property
    def s(self) -> np.ndarray:
        """(N,) the path parameter of the points."""
        return self.points.s

    def states(self, a, b) -> JointTrajectory:
        """The joint motion at the points for s̈ = a and ṡ² = b: θ̇ = θ′√b, θ̈ = θ′a + θ″b.

        Args:
            a: (N,) or a float, 1/s², s̈.
            b: (N,) or a float, 1/s², ṡ² (≥ 0).

        Returns:
            JointTrajectory: t = s (a label only), source 'object_motion'.
        """
        a, b = np.broadcast_to(a, self.s.shape)[:, None], np.broadcast_to(b, self.s.shape)[:, None]
        return JointTrajectory(self.s.copy(), self.q.copy(), self.d1 * np.sqrt(b), self.d1 * a + self.d2 * b,
                               "object_motion")

    def refined(self, factor: int) -> "JointPath | None":
        """The joint path at the interior points of a `factor`× finer grid: s_i + (k/factor)(s_{i+1} − s_i),
        k = 1 … factor − 1, on every interval of a piece (computed once per factor, by `recipe`).

        Args:
            factor: the finer grid's intervals per interval (≥ 2).

        Returns:
            JointPath | None: (N_intervals (factor − 1) points, interval after interval), or None
            without a recipe.

        Raises:
            TrajectoryError: as `joint_path`.
        """
        if self.recipe is None:
            return None
        if factor not in self._refined:
            s, piece = self.s, self.points.piece
            i = np.flatnonzero(piece[1:] == piece[:-1])
            u = np.arange(1, factor) / factor
            fs = (s[i, None] + u[None, :] * (s[i + 1] - s[i])[:, None]).ravel()
            # from this path's first point, as it started (a redundant arm's self-motion starts there)
            fine = self.recipe(np.append(s[0], fs), np.append(piece[0], np.repeat(piece[i], factor - 1)))
            self._refined[factor] = fine.subset(np.arange(1, len(fs) + 1))
        return self._refined[factor]

    def subset(self, idx: np.ndarray) -> "JointPath":
        """The points idx only (without a recipe).

        Args:
            idx: (M,) int, indices of the points.

        Returns:
            JointPath: M points.
        """
        p = self.points
        pts = PathPoints(p.s[idx], p.piece[idx], p.p[idx], p.R[idx], p.d1[idx], p.d2[idx], p.origin)
        return JointPath(pts, self.q[idx], self.d1[idx], self.d2[idx])


def joint_path(model: Model, path: ObjectPath, s: np.ndarray, piece: np.ndarray,
               guess: np.ndarray | None = None, rest: np.ndarray | None = None, rest_gain: float = 1.0,
               plane_tol: float = 1e-9) -> JointPath:
    """Closed-chain inverse kinematics along an object path: θ(s), θ′(s), θ″(s) of every arm.

    Square arms (as many joints as rows S): Newton from the previous point's angles advanced by
    θ′Δs + θ″Δs²/2 (`arm_ik`, from `guess` at the first point), then the differential kinematics with
    the twist [p′; ω′] and acceleration [p″; ω″] of the grasp (`arm_rates`): θ′, θ″ exactly. Redundant
    arms: θ′ = `redundant_rates` with s as the time (least |θ′ − z|, z = rest_gain (θ_rest − θ), the
    null-space pull per unit s), integrated by DOP853 piece by piece, each point put on the grasp by
    least-norm Newton. Joint ranges are checked.

    Args:
        model: the Model.
        path: the ObjectPath.
        s: (N,) the points, increasing within each piece (`path_grid`).
        piece: (N,) int, each point's piece.
        guess: (n,) rad (m), the angles picking the branch at the first point; None: model.q0.
        rest: (n,) rad (m), the redundant arms' rest posture; None: model.q0.
        rest_gain: the null-space pull per unit s of the redundant arms.
        plane_tol: m or rad, how far a grasp may leave the plane of motion of a planar scene.

    Returns:
        JointPath: θ, θ′, θ″ (N, n).

    Raises:
        TrajectoryError: a point out of reach, at a singularity, off the plane or out of a joint's range
            (one line naming the arm and s).
    """
    pts = path.at(s, piece)
    S, n = model.rows, model.n_total
    q, d1, d2 = (np.zeros((len(s), n)) for _ in range(3))
    prev = (model.q0 if guess is None else guess).astype(float).copy()
    redundant = [m for m, arm in enumerate(model.arms) if arm.n > S.shape[0]]
    for m, arm in enumerate(model.arms):
        if arm.n < S.shape[0]:
            raise TrajectoryError(f"inverse.object_motion: arm {arm.name!r} has {arm.n} joints for {S.shape[0]} "
                                  f"constrained rows")
    targets = [grasp_targets(model, pts.p[i], pts.R[i], pts.d1[i], pts.d2[i], pts.origin) for i in range(len(s))]
    for m, sl in enumerate(model.dof_slices):
        if m in redundant:
            continue
        g = prev[sl]
        for i in range(len(s)):
            p, R, tw, ac = targets[i][m]
            if i:
                h = s[i] - s[i - 1]
                g = q[i - 1, sl] + d1[i - 1, sl] * h + 0.5 * d2[i - 1, sl] * h * h
            q[i, sl] = _arm_point(model, m, p, R, g, s[i], plane_tol)
            d1[i, sl], d2[i, sl], _ = arm_rates(model.arms[m], S, q[i, sl], tw, ac)
    if redundant:
        rest_q = model.q0 if rest is None else rest
        for m in redundant:
            sl = model.dof_slices[m]
            q[:, sl], d1[:, sl], d2[:, sl] = _redundant_path(model, m, path, s, piece, targets, prev[sl],
                                                             rest_q[sl], rest_gain, plane_tol)
    hit = joint_limit_violation(model, q)
    if hit is not None:
        raise TrajectoryError(f"inverse.object_motion: at s={s[hit[0]]:.6g} "
                              f"{joint_limit_reason(model, hit[1], q[hit[0], hit[1]])}")
    return JointPath(pts, q, d1, d2, partial(joint_path, model, path, guess=guess, rest=rest, rest_gain=rest_gain,
                                             plane_tol=plane_tol))


def _where(model: Model, m: int, s: float) -> str:
    return f"arm {model.arms[m].name!r} at s={s:.6g}"


def _arm_point(model: Model, m: int, p, R, guess, s: float, plane_tol: float) -> np.ndarray:
    """Square arm m at the grasp target (p relative to its base point), one-line errors naming it and s."""
    arm = model.arms[m]
    dist, reach, ok = reach_check(arm, p)
    if not ok:
        raise TrajectoryError(f"inverse.object_motion: the path leaves the workspace of {_where(model, m, s)}: "
                              f"its grasp is {dist:.4g} m from the first joint, reach {reach:.4g} m")
    try:
        q = arm_ik(arm, model.rows, p, R, guess)
    except ConstraintError as e:
        raise TrajectoryError(f"inverse.object_motion: the path leaves the workspace of {_where(model, m, s)}: "
                              f"no joint angles reach its grasp ({e})") from None
    full = float(np.max(np.abs(pose_error(arm, q, p, R))))
    if full > plane_tol:
        raise TrajectoryError(f"inverse.object_motion: the grasp of {_where(model, m, s)} leaves the plane of "
                              f"motion by {full:.3g} (m or rad)")
    return q


def _redundant_path(model: Model, m: int, path: ObjectPath, s, piece, targets, guess, rest, gain, plane_tol,
                    sing_tol: float = 1e-7):
    """θ, θ′, θ″ (N, n_m) of redundant arm m: the redundancy ODE in s, piece by piece (`joint_path`)."""
    from scipy.integrate import solve_ivp

    arm, S = model.arms[m], model.rows
    q, d1, d2 = (np.zeros((len(s), arm.n)) for _ in range(3))

    def target(x, k):
        pts = path.at(np.array([x]), np.array([k]))
        return grasp_targets(model, pts.p[0], pts.R[0], pts.d1[0], pts.d2[0], pts.origin)[m]

    def on_grasp(x, k, y, tg=None):
        p, R = (tg or target(x, k))[:2]
        try:
            y = min_norm_ik(arm, S, p, R, y)
        except ConstraintError as e:
            raise TrajectoryError(f"inverse.object_motion: the path leaves the workspace of "
                                  f"{_where(model, m, x)}: no joint angles reach its grasp ({e})") from None
        if float(np.max(np.abs(pose_error(arm, y, p, R)))) > plane_tol:
            raise TrajectoryError(f"inverse.object_motion: the grasp of {_where(model, m, x)} leaves the plane "
                                  f"of motion")
        return y

    def rhs(x, y, k):
        return redundant_rates(arm, S, y, target(x, k)[2], None, rest, gain)[0]

    y = on_grasp(s[0], piece[0], guess)
    for k in np.unique(piece):
        idx = np.flatnonzero(piece == k)
        a, b = path.knots[k], path.knots[k + 1]
        y = on_grasp(a, k, y)
        sol = solve_ivp(rhs, (a, b), y, method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True, args=(k,))
        for i in idx:
            q[i] = on_grasp(s[i], k, sol.sol(s[i]), targets[i][m])
            r1, r2, A = redundant_rates(arm, S, q[i], targets[i][m][2], targets[i][m][3], rest, gain)
            sv = np.linalg.svd(A, compute_uv=False)
            if not sv[-1] >= sing_tol * sv[0]:
                raise TrajectoryError(f"inverse.object_motion: {_where(model, m, s[i])} meets a singularity "
                                      f"(σ_min/σ_max = {sv[-1] / sv[0]:.2g})")
            d1[i], d2[i] = r1, r2
        y = sol.sol(b)
    return q, d1, d2
