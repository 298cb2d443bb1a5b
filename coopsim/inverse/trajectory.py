"""Stage 6 — trajectories to invert: joint motions (θ, θ̇, θ̈) of the closed chain.

Two sources (paper sec. 3.2):
  * the joint trajectory of a forward run (the paper's choice): θ, θ̇ are the integrator's values and
    θ̈ the closed-chain forward dynamics at the samples, so all three are exact at the samples;
  * a prescribed object motion: pose waypoints of the object's centre of mass C with a smooth time
    law, turned into joint motions of every arm by closed-chain inverse kinematics. θ comes from
    Newton's method on the loop-closure rows, θ̇ and θ̈ from the differential kinematics
    S J_m θ̇_m = S v_EE,m and S J_m θ̈_m = S (a_EE,m − J̇_mθ̇_m) (the same rows S as the forward model),
    so the three are consistent (no finite differences). Arms with more joints than rows (redundant) are
    resolved by least joint-velocity norm plus a null-space pull toward a rest posture, θ̈ its exact
    derivative (`redundant_rates`, `redundant_motion`); joint limits are checked on the result.

Between samples a trajectory is the quintic Hermite interpolant of (θ, θ̇, θ̈) at the two ends
(`trajectory_at`): C², exact at the samples, error O(h⁶) in between. Twists [v; ω] and accelerations
[a; ω̇] are in world axes; SI units.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, fields, replace

import numpy as np

from coopsim.core.digest import content_digest
from coopsim.core.errors import ConstraintError, CoopsimError
from coopsim.core.model import ArmModel, Model, ObjectMotion, SampledTimeLaw
from coopsim.core.results import output_times
from coopsim.core.spatial import axis_angle_to_rot, cross, rigid_acceleration, rot_log
from coopsim.dynamics.closed_chain import arm_poses, carrier_object
from coopsim.dynamics.kinematics import (REACH_SLACK, arm_pose, ee_bias_acceleration, ee_jacobian, point_jacobian_rate,
                                         reach_bound, reach_check)
from coopsim.forward.diagnostics import joint_limit_reason, joint_limit_violation
from coopsim.inverse.spline_path import spline_arrays, spline_state


class TrajectoryError(CoopsimError):
    """A prescribed motion cannot be turned into joint motions (out of reach, singular, too few joints,
    out of a joint's range)."""


class SingularJacobian(ConstraintError):
    """An arm's Jacobian in the constrained rows lost rank during inverse kinematics."""


@dataclass(frozen=True, eq=False)
class JointTrajectory:
    """Joint motion of the closed chain sampled at N times, stacked arm after arm and mutually consistent.

    Attributes:
        t: (N,) s, the sample times, increasing.
        q: (N, n) rad (m on a prismatic joint), the joint coordinates θ.
        qd: (N, n) rad/s (m/s), the joint rates θ̇.
        qdd: (N, n) rad/s² (m/s²), the joint accelerations θ̈.
        source: 'forward' (a forward run) or 'object_motion' (closed-chain inverse kinematics of a
            prescribed object motion).
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    source: str


def from_simulation(res) -> JointTrajectory:
    """The trajectory of a forward run: its samples as they are.

    Args:
        res: the forward run (`coopsim.forward.simulate.SimResult`); its t, q, qd and qdd are copied.

    Returns:
        JointTrajectory: t (N,) s and q, qd, qdd (N, n) of the run, source 'forward'.
    """
    return JointTrajectory(res.t.copy(), res.q.copy(), res.qd.copy(), res.qdd.copy(), "forward")


def trajectory_at(traj: JointTrajectory, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(θ, θ̇, θ̈) (n,) at time t (clamped to the sampled span); see `trajectory_at_times`.

    Args:
        traj: the JointTrajectory.
        t: s, the time.

    Returns:
        tuple[np.ndarray, np.ndarray, np.ndarray]: θ (n,) rad (m), θ̇ (n,) rad/s (m/s) and θ̈ (n,)
        rad/s² (m/s²), stacked arm after arm.
    """
    q, qd, qdd = trajectory_at_times(traj, np.array([float(t)]))
    return q[0], qd[0], qdd[0]


def trajectory_at_times(traj: JointTrajectory, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(θ, θ̇, θ̈) (M, n) at times t (M,), clamped to the sampled span.

    The quintic Hermite polynomial through (θ, θ̇, θ̈) at the ends of the sample interval holding each t,
    evaluated from the nearer end (so the sample values come back to rounding).

    Args:
        traj: the JointTrajectory (at least two samples).
        t: (M,) s, the times.

    Returns:
        tuple[np.ndarray, np.ndarray, np.ndarray]: θ (M, n) rad (m), θ̇ (M, n) rad/s (m/s) and θ̈ (M, n)
        rad/s² (m/s²), stacked arm after arm.
    """
    ts = traj.t
    t = np.clip(np.asarray(t, dtype=float), ts[0], ts[-1])
    i = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, len(ts) - 2)
    h = (ts[i + 1] - ts[i])[:, None]
    u = (t - ts[i])[:, None] / h
    a, b = (traj.q[i], traj.qd[i], traj.qdd[i]), (traj.q[i + 1], traj.qd[i + 1], traj.qdd[i + 1])
    fwd = hermite_quintic(a, b, u, h)
    q, qd, qdd = hermite_quintic((b[0], -b[1], b[2]), (a[0], -a[1], a[2]), 1.0 - u, h)
    near_start = u <= 0.5
    return tuple(np.where(near_start, f, g) for f, g in zip(fwd, (q, -qd, qdd)))


def hermite_quintic(start, end, u: float, h: float):
    """Quintic Hermite polynomial through start at u = 0 and end at u = 1 on an interval of h s: (θ, θ̇, θ̈) at u.

    With Δ = θ₁ − θ₀ and θ = Σ c_k uᵏ:

        c₀ = θ₀,  c₁ = hθ̇₀,  c₂ = h²θ̈₀/2,
        c₃ = 10Δ − 6hθ̇₀ − 4hθ̇₁ − 3h²θ̈₀/2 + h²θ̈₁/2,
        c₄ = −15Δ + 8hθ̇₀ + 7hθ̇₁ + 3h²θ̈₀/2 − h²θ̈₁,
        c₅ = 6Δ − 3hθ̇₀ − 3hθ̇₁ − h²θ̈₀/2 + h²θ̈₁/2.

    Args:
        start: (θ₀, θ̇₀, θ̈₀) at u = 0, arrays of one shape (e.g. (M, n)) in rad, rad/s, rad/s² (m, m/s,
            m/s² on a prismatic joint).
        end: (θ₁, θ̇₁, θ̈₁) at u = 1, likewise.
        u: the normalised time (t − t₀)/h in [0, 1], a float or an array broadcasting with start's
            (e.g. (M, 1)).
        h: s, the interval's length, a float or an array broadcasting likewise.

    Returns:
        tuple: (θ, θ̇, θ̈) at u, shaped like start's arrays broadcast with u, in their units (θ̇ and θ̈ per
        second, not per unit u).
    """
    p0, v0, a0 = start[0], h * start[1], h * h * start[2]
    p1, v1, a1 = end[0], h * end[1], h * h * end[2]
    d = p1 - p0
    c = [p0, v0, 0.5 * a0,
         10 * d - 6 * v0 - 4 * v1 - 1.5 * a0 + 0.5 * a1,
         -15 * d + 8 * v0 + 7 * v1 + 1.5 * a0 - a1,
         6 * d - 3 * v0 - 3 * v1 - 0.5 * a0 + 0.5 * a1]
    q = sum(ci * u ** k for k, ci in enumerate(c))
    qd = sum(k * ci * u ** (k - 1) for k, ci in enumerate(c) if k >= 1) / h
    qdd = sum(k * (k - 1) * ci * u ** (k - 2) for k, ci in enumerate(c) if k >= 2) / (h * h)
    return q, qd, qdd


def time_law(kind: str, u: float) -> tuple[float, float, float]:
    """(s, ds/du, d²s/du²) of the normalised time law on u ∈ [0, 1].

    'quintic': s = 10u³ − 15u⁴ + 6u⁵ (rest-to-rest with zero acceleration at the ends); 'cubic':
    s = 3u² − 2u³ (zero rate at the ends); 'linear': s = u (not at rest: a path traversed at ṡ = 1,
    s̈ = 0, `coopsim.inverse.free_path.spline_joint_path`; no scenario's law).

    Args:
        kind: 'quintic', 'cubic' or 'linear'.
        u: the normalised time in [0, 1] (dimensionless).

    Returns:
        tuple[float, float, float]: s, ds/du and d²s/du² at u (dimensionless).

    Raises:
        ValueError: an unknown time law.
    """
    if kind == "quintic":
        return (10 * u**3 - 15 * u**4 + 6 * u**5, 30 * u**2 - 60 * u**3 + 30 * u**4,
                60 * u - 180 * u**2 + 120 * u**3)
    if kind == "cubic":
        return 3 * u**2 - 2 * u**3, 6 * u - 6 * u**2, 6 - 12 * u
    if kind == "linear":
        return u, 1.0, 0.0
    raise ValueError(f"unknown time law {kind!r}")


def sampled_time_law_at(law: SampledTimeLaw, t: float) -> tuple[float, float, float]:
    """(s, ṡ, s̈) of a sampled time law at time t (clamped to its span): s̈ constant between samples.

    Args:
        law: the SampledTimeLaw.
        t: s, the time.

    Returns:
        tuple[float, float, float]: s, ṡ (1/s) and s̈ (1/s²) at t (s̈ of the interval starting at t
        at a sample).
    """
    ts = law.t
    t = min(max(float(t), ts[0]), ts[-1])
    k = int(np.clip(np.searchsorted(ts, t, side="right") - 1, 0, len(ts) - 2))
    tau = t - ts[k]
    acc = (law.rate[k + 1] - law.rate[k]) / (ts[k + 1] - ts[k])
    return law.s[k] + law.rate[k] * tau + 0.5 * acc * tau * tau, law.rate[k] + acc * tau, acc


def segment_at(motion: ObjectMotion, t: float) -> tuple[int, float, float, float, float]:
    """The waypoint segment at time t (clamped to the span) and its law: (i, T, s, ds/du, d²s/du²).

    Segment i runs from waypoint i to i + 1 over T s, u = (t − t_i)/T; s(u) is the normalised law
    (`time_law`), or of a sampled law σ(t) (`sampled_time_law_at`, waypoint i at σ = i/(w − 1)):
    s = (w − 1)σ − i, ds/du = (w − 1)σ̇T, d²s/du² = (w − 1)σ̈T².

    Args:
        motion: the ObjectMotion.
        t: s, the time.

    Returns:
        tuple: i, T (s), s, ds/du and d²s/du² (dimensionless).
    """
    ts = motion.times
    t = min(max(float(t), ts[0]), ts[-1])
    i = int(np.clip(np.searchsorted(ts, t, side="right") - 1, 0, len(ts) - 2))
    T = ts[i + 1] - ts[i]
    if motion.time_law == "sampled":
        sigma, rate, accel = sampled_time_law_at(motion.samples, t)
        w1 = len(ts) - 1
        return i, T, w1 * sigma - i, w1 * rate * T, w1 * accel * T**2
    return (i, T, *time_law(motion.time_law, (t - ts[i]) / T))


def pull_gain(motion: ObjectMotion, t: float) -> tuple[float, float]:
    """The redundant arms' null-space pull gain at time t and its rate: (g 1/s, ġ 1/s²), z = g (θ_rest − θ).

    rest_pull 'time': (rest_gain, 0). 'path': g = rest_gain · T · σ̇, ġ = rest_gain · T · σ̈, with σ the
    whole path's parameter (σ̇ = (ds/du)/((w − 1) T_i) on segment i, `segment_at`) and T the motion's
    duration: the pull per unit σ is rest_gain · T whatever the time law.

    Args:
        motion: the ObjectMotion.
        t: s, the time.

    Returns:
        tuple[float, float]: g and ġ.
    """
    if motion.rest_pull == "time":
        return motion.rest_gain, 0.0
    _, T, _, ds, dds = segment_at(motion, t)
    k = motion.path_gain / (len(motion.times) - 1)
    return k * ds / T, k * dds / T**2


def object_motion_at(motion: ObjectMotion, t: float, origin: np.ndarray | None = None):
    """Object state at time t (clamped to the waypoint span): p_C, R_o, twist [v_C; ω] and acceleration [a_C; ω̇].

    On segment [t_a, t_b], u = (t − t_a)/T, T = t_b − t_a: p = p_a + s(u)(p_b − p_a), R = R_a Exp(s(u) φ)
    with φ = log(R_aᵀ R_b) (one fixed axis), so v = (ṡ/T)(p_b − p_a), ω = (ṡ/T) R_a φ,
    a = (s̈/T²)(p_b − p_a), ω̇ = (s̈/T²) R_a φ (ṡ = ds/du, s̈ = d²s/du², `time_law`). A sampled time law
    gives the whole path's parameter σ(t) (`sampled_time_law_at`, waypoint i at σ = i/(w − 1)): then
    s = (w − 1)σ − i, ṡ/T = (w − 1)σ̇ and s̈/T² = (w − 1)σ̈. With `origin`, p_C is
    (p_a − origin) + s(u)(p_b − p_a), so no world position is rounded. A motion with a B-spline `path`
    follows it instead, the time law once over the whole span (`coopsim.inverse.spline_path.spline_state`).

    Args:
        motion: the ObjectMotion (waypoints, world axes, and time law).
        t: s, the time.
        origin: (3,) m, world: the point p_C is given relative to; None: the world origin.

    Returns:
        tuple: p_C (3,) m, relative to `origin`, world axes; R_o (3, 3) world ← object; twist [v_C; ω]
        (6,) [m/s; rad/s] and acceleration [a_C; ω̇] (6,) [m/s²; rad/s²], world axes.
    """
    i, T, s, ds, dds = segment_at(motion, t)
    if motion.path is not None:
        return spline_state(motion, s, ds / T, dds / T**2, origin)
    dp = motion.positions[i + 1] - motion.positions[i]
    Ra = motion.rotations[i]
    phi = rot_log(Ra.T @ motion.rotations[i + 1])
    angle = float(np.linalg.norm(phi))
    R = Ra @ axis_angle_to_rot(phi / angle, s * angle) if angle > 0 else Ra.copy()
    w_axis = Ra @ phi
    twist = np.concatenate([ds / T * dp, ds / T * w_axis])
    acc = np.concatenate([dds / T**2 * dp, dds / T**2 * w_axis])
    p_a = motion.positions[i] if origin is None else motion.positions[i] - origin
    return p_a + s * dp, R, twist, acc


def body_point_state(p: np.ndarray, R: np.ndarray, twist: np.ndarray, acc: np.ndarray, point: np.ndarray):
    """The state of a rigid body's point c (body frame) from its frame's: p + r, R, [v + ω × r; ω] and
    [a + ω̇ × r + ω × (ω × r); ω̇] with r = R c (`coopsim.core.spatial.rigid_acceleration`).

    Args:
        p: (3,) m, the frame's origin, world.
        R: (3, 3) world ← body.
        twist: (6,) [v; ω] [m/s; rad/s] of the origin, world axes.
        acc: (6,) [a; ω̇] [m/s²; rad/s²] of the origin, world axes.
        point: (3,) m, c, body frame.

    Returns:
        tuple: the point's position (3,) m, R (3, 3), its twist (6,) and acceleration (6,), world axes.
    """
    r = R @ np.asarray(point, dtype=float)
    w, dw = twist[3:], acc[3:]
    return (p + r, R, np.concatenate([twist[:3] + cross(w, r), w]),
            np.concatenate([rigid_acceleration(acc[:3], w, dw, r), dw]))


def grasp_targets(model: Model, p_C: np.ndarray, R_o: np.ndarray, twist: np.ndarray, acc: np.ndarray,
                  origin: np.ndarray | None = None):
    """End-effector targets of every arm for an object state: p_EE, R_EE, twist and acceleration per arm.

    With ρ = p_EE − p_C = R_o ρ_m (ρ_m the grasp position, object frame): p_EE relative to the arm's base
    point o_m is ((origin − o_m) + p_C) + ρ, R_EE = R_o R_grasp, v_EE = v_C + ω × ρ and
    a_EE = a_C + ω̇ × ρ + ω × (ω × ρ) (eq. 3 and its derivative).

    Args:
        model: the Model (its arms' base points and the object's grasps).
        p_C: (3,) m, the object's centre of mass C relative to `origin`, world axes.
        R_o: (3, 3) the object's orientation, world ← object.
        twist: (6,) [v_C; ω] m/s, rad/s, world axes.
        acc: (6,) [a_C; ω̇] m/s², rad/s², world axes.
        origin: (3,) m, world: the point p_C is relative to; None: the world origin.

    Returns:
        list[tuple]: one (p_EE, R_EE, twist, acceleration) per arm: p_EE (3,) m relative to the arm's
        base point, world axes; R_EE (3, 3) world ← end-effector; twist [v_EE; ω] (6,) and acceleration
        [a_EE; ω̇] (6,), world axes.
    """
    obj, w, dw = model.object, twist[3:], acc[3:]
    o = np.zeros(3) if origin is None else np.asarray(origin, dtype=float)
    out = []
    for m, arm in enumerate(model.arms):
        rho = R_o @ obj.grasp_pos[m]
        v = twist[:3] + cross(w, rho)
        a = rigid_acceleration(acc[:3], w, dw, rho)
        out.append((((o - arm.base_pos) + p_C) + rho, R_o @ obj.grasp_rot[m], np.concatenate([v, w]),
                    np.concatenate([a, dw])))
    return out


def pose_error(arm: ArmModel, q: np.ndarray, p: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Pose error [p_EE(θ) − p; log(R_EE(θ) Rᵀ)] of one arm's end-effector frame against a target.

    The target p and p_EE are both relative to the arm's base point (ArmPose.p_ee_rel): no world
    position enters the error.

    Args:
        arm: the ArmModel.
        q: (n,) rad (m on a prismatic joint), the arm's joint coordinates.
        p: (3,) m, the target position relative to the arm's base point, world axes.
        R: (3, 3) the target orientation, world axes.

    Returns:
        np.ndarray: (6,) [m; rad] the position error and rotation vector, world axes.
    """
    return pose_error_at(arm_pose(arm, q), p, R)


def pose_error_at(pose, p: np.ndarray, R: np.ndarray) -> np.ndarray:
    """`pose_error` of an ArmPose already computed.

    Args:
        pose: the arm's ArmPose (`coopsim.dynamics.kinematics.arm_pose`).
        p: (3,) m, the target position relative to the arm's base point, world axes.
        R: (3, 3) the target orientation, world axes.

    Returns:
        np.ndarray: (6,) [m; rad] [p_EE − p; log(R_EE Rᵀ)], world axes.
    """
    return np.concatenate([pose.p_ee_rel - p, rot_log(pose.R_ee @ R.T)])


def newton_failure(error: float, steps: int) -> str:
    """The reason of a Newton solve that did not converge: 'Newton did not converge (max |error| … after … steps)'.

    Args:
        error: m or rad, the max |error| left.
        steps: the steps taken.

    Returns:
        str: the one-line reason.
    """
    return f"Newton did not converge (max |error| {error:.3g} after {steps} steps)"


def arm_ik(arm: ArmModel, S: np.ndarray, p: np.ndarray, R: np.ndarray, guess: np.ndarray,
           tol: float = 1e-13, max_iter: int = 50, sing_tol: float = 1e-7) -> np.ndarray:
    """Joint angles (n,) putting the end-effector frame at (p, R) in the rows S, by Newton's method.

    Newton steps Δθ = −(S J)⁻¹ S e(θ) (e: `pose_error`) from `guess` (which picks the branch) until
    max |S e| <= tol.

    Args:
        arm: the ArmModel (n joints).
        S: (k, 6) row selector of the pose rows solved, k = n.
        p: (3,) m, the target position relative to the arm's base point, world axes.
        R: (3, 3) the target orientation, world axes.
        guess: (n,) rad (m on a prismatic joint), the starting joint coordinates (not changed).
        tol: m or rad, the tolerance on max |S e|.
        max_iter: the most Newton steps.
        sing_tol: S J counts as singular when σ_min/σ_max < sing_tol.

    Returns:
        np.ndarray: (n,) rad (m) the joint coordinates.

    Raises:
        SingularJacobian: S J is singular (a ConstraintError).
        ConstraintError: Newton does not converge in max_iter steps.
    """
    q = guess.astype(float).copy()
    for _ in range(max_iter):
        e = S @ pose_error(arm, q, p, R)
        if np.max(np.abs(e)) <= tol:
            return q
        SJ = S @ ee_jacobian(arm_pose(arm, q))
        sv = np.linalg.svd(SJ, compute_uv=False)
        if sv[-1] < sing_tol * sv[0]:
            raise SingularJacobian(f"singular Jacobian (σ_min/σ_max = {sv[-1] / sv[0]:.2g})")
        q -= np.linalg.solve(SJ, e)
    raise ConstraintError(newton_failure(float(np.max(np.abs(e))), max_iter))


def arm_rates(arm: ArmModel, S: np.ndarray, q: np.ndarray, twist: np.ndarray, acc: np.ndarray):
    """(θ̇, θ̈, det S J) of one arm from its end-effector twist and acceleration.

    Differential kinematics in the rows S: S J θ̇ = S v_EE, S J θ̈ = S (a_EE − J̇θ̇).

    Args:
        arm: the ArmModel (n joints).
        S: (k, 6) row selector, k = n.
        q: (n,) rad (m on a prismatic joint), the arm's joint coordinates.
        twist: (6,) [v_EE; ω] m/s, rad/s, the end-effector twist, world axes.
        acc: (6,) [a_EE; ω̇] m/s², rad/s², the end-effector acceleration, world axes.

    Returns:
        tuple[np.ndarray, np.ndarray, float]: θ̇ (n,) rad/s (m/s), θ̈ (n,) rad/s² (m/s²) and det S J.
    """
    pose = arm_pose(arm, q)
    SJ = S @ ee_jacobian(pose)
    qd = np.linalg.solve(SJ, S @ twist)
    qdd = np.linalg.solve(SJ, S @ (acc - ee_bias_acceleration(pose, qd)))
    return qd, qdd, float(np.linalg.det(SJ))


def object_motion_trajectory(model: Model, motion: ObjectMotion, plane_tol: float = 1e-9,
                             engine: str = "compiled") -> JointTrajectory:
    """Closed-chain inverse kinematics of a prescribed object motion, sampled every motion.output_dt
    from the first to the last waypoint.

    Each square arm is solved by continuation: Newton from the previous sample's angles advanced by
    θ̇h + θ̈h²/2 (from `initial_guess` at the first sample), so the branch chosen at the start is kept;
    the redundant arms as `redundant_motion`. engine 'compiled' runs every sample in one compiled pass
    (`coopsim.compiled.object_motion`, waypoint and B-spline paths), 'reference' the readable NumPy/SciPy
    path (`redundant_motion` and one compiled Newton solve per sample and arm); both give the same error
    texts.

    Args:
        model: the Model whose arms carry the object.
        motion: the object's waypoints and time law (scenario `inverse.object_motion`).
        plane_tol: m or rad, how far a target may leave the plane of motion of a planar scene.
        engine: 'compiled' or 'reference'.

    Returns:
        JointTrajectory: t (N,) s and q, qd, qdd (N, n) rad (or m), stacked arm by arm.

    Raises:
        TrajectoryError: naming the time and arm when a target is out of reach, an arm's Jacobian is
            singular, det(S J) changes sign between samples (a singularity is crossed), a target
            leaves the plane of motion, or a joint leaves its range.
        ValueError: an unknown engine.
    """
    t_out = motion.times[0] + output_times(motion.times[-1] - motion.times[0], motion.output_dt)
    return object_motion_samples(model, motion, t_out, plane_tol, engine)


def object_motion_samples(model: Model, motion: ObjectMotion, t_out: np.ndarray, plane_tol: float = 1e-9,
                          engine: str = "compiled", parameter: str = "t") -> JointTrajectory:
    """`object_motion_trajectory` at the sample times t_out.

    Args:
        model: the Model whose arms carry the object.
        motion: the object's waypoints and time law.
        t_out: (N,) s, the sample times, increasing, within the waypoints' span (the first one starts the
            inverse kinematics from the motion's initial guess).
        plane_tol: m or rad, how far a target may leave the plane of motion of a planar scene.
        engine: 'compiled' or 'reference'.
        parameter: what the failure texts call a sample's coordinate: 't' (the time, "t=0.5 s"), or 's'
            (a path parameter, "s=0.5": a path traversed in unit time, `coopsim.inverse.free_path.
            spline_joint_path`; compiled engine only, the reference one's path route being `joint_path`).

    Returns:
        JointTrajectory: t = t_out (N,) s and q, qd, qdd (N, n) rad (or m), stacked arm by arm.

    Raises:
        TrajectoryError: as `object_motion_trajectory`.
        ValueError: an unknown engine or parameter.
    """
    if engine not in ("compiled", "reference"):
        raise ValueError(f"unknown engine {engine!r}; expected compiled or reference")
    if parameter not in ("t", "s") or (parameter == "s" and engine == "reference"):
        raise ValueError(f"parameter {parameter!r} with engine {engine!r}; expected 't', or 's' with 'compiled'")
    S = model.rows
    redundant = _check_joint_counts(model, S)
    t_out = np.asarray(t_out, dtype=float)
    guess = model.q0 if motion.initial_guess is None else motion.initial_guess
    if engine == "reference":
        q, qd, qdd = _reference_motion(model, motion, t_out, guess, redundant, plane_tol)
    else:
        q, qd, qdd = _compiled_motion(model, motion, t_out, guess, redundant, plane_tol, parameter)
    _check_joint_limits(model, t_out, q, parameter)
    return JointTrajectory(t_out, q, qd, qdd, "object_motion")


def _compiled_motion(model: Model, motion: ObjectMotion, t_out, guess, redundant, plane_tol, parameter="t"):
    """(θ, θ̇, θ̈) of every arm by `coopsim.compiled.api.object_motion_ik`, a failure raised as the reference's."""
    from coopsim.compiled import api, object_motion as om

    bounds = [reach_bound(arm) for arm in model.arms]
    first = np.array([f for f, _ in bounds])
    reach = np.array([r for _, r in bounds])
    spline = None if motion.path is None else spline_arrays(motion)
    sol = api.object_motion_ik(model, motion, t_out, guess, redundant, first, reach * (1 + REACH_SLACK), plane_tol,
                               spline=spline)
    if sol.status == om.OK:
        return sol.q, sol.qd, sol.qdd
    m, (a, b) = sol.arm, sol.values
    reason = {om.OUT_OF_REACH: "reach", om.NOT_CONVERGED: "newton", om.OFF_PLANE: "plane", om.CROSSES: "crosses",
              om.SINGULAR: "singular_redundant" if m in redundant else "singular"}.get(sol.status)
    if reason is None:
        reason = "integration"
    detail = f"more than {b:.0f} steps" if reason == "integration" and b > 0 else ""
    raise _failure(model, reason, m, sol.t, sol.p_C, a, reach[m], sol.t_prev, detail, parameter=parameter)


def _at(parameter: str, t: float) -> str:
    """A sample's coordinate as the failure texts quote it: 't=0.5 s' (a time) or 's=0.5' (a path parameter)."""
    return f"t={t:.6g} s" if parameter == "t" else f"s={t:.6g}"


def _failure(model: Model, reason: str, m: int, t: float, p_C, value: float = 0.0, reach: float = 0.0,
             t_prev: float = 0.0, detail: str = "", parameter: str = "t") -> TrajectoryError:
    """The TrajectoryError of a failed sample of arm m at time t (p_C: the object's world position): the one
    wording of both engines. reason: 'reach' (value: the grasp's distance), 'newton' (value: max |S e|
    left, or detail: the solver's own words), 'singular' / 'singular_redundant' (value: σ_min/σ_max), 'plane'
    (value: the full pose error), 'crosses' (between t_prev and t), 'integration' (the redundant arms' ODE
    stopped; detail: why, else its step size collapsed). parameter: 't' (t is a time) or 's' (a path
    parameter: `object_motion_samples`)."""
    name = model.arms[m].name
    at, before = _at(parameter, t), _at(parameter, t_prev)
    where = f"at {at} (object at [{', '.join(f'{x:.4g}' for x in p_C)}] m)"
    leaves = f"inverse.object_motion: the path leaves the workspace of arm {name!r} {where}: "
    text = {"reach": lambda: leaves + f"its grasp is {value:.4g} m from the first joint, reach {reach:.4g} m",
            "newton": lambda: leaves + f"no joint angles reach its grasp ({detail or newton_failure(value, 50)})",
            "singular": lambda: f"inverse.object_motion: arm {name!r} meets a singularity {where}: singular "
                                f"Jacobian (σ_min/σ_max = {value:.2g})",
            "singular_redundant": lambda: f"inverse.object_motion: arm {name!r} meets a singularity at {at}: "
                                          f"singular Jacobian (σ_min/σ_max = {value:.2g})",
            "plane": lambda: f"inverse.object_motion: at {at} the grasp of arm {name!r} leaves the plane of "
                             f"motion by {value:.3g} (m or rad)",
            "integration": lambda: f"inverse.object_motion: the redundancy resolution's integration failed at "
                                   f"{at} ({detail or 'step size collapsed'})",
            "crosses": lambda: f"inverse.object_motion: arm {name!r} crosses a singularity between {before} "
                               f"and {at} (det S J changes sign)"}[reason]()
    return TrajectoryError(text)


def _reference_motion(model: Model, motion: ObjectMotion, t_out, guess, redundant, plane_tol):
    """(θ, θ̇, θ̈) of every arm the readable way: `redundant_motion`, then the square arms sample by sample."""
    N, n = len(t_out), model.n_total
    q, qd, qdd = np.zeros((N, n)), np.zeros((N, n)), np.zeros((N, n))
    dets = np.zeros((N, model.r))
    origin = motion.positions[0]           # targets relative to the arm bases through it: no world position rounded
    if redundant:
        q[:], qd[:], qdd[:] = redundant_motion(model, motion, t_out, guess, redundant, plane_tol)
    for i, t in enumerate(t_out):
        p_C, R_o, tw, ac = object_motion_at(motion, t, origin)
        if i:
            h = t - t_out[i - 1]
            guess = q[i - 1] + h * qd[i - 1] + 0.5 * h * h * qdd[i - 1]
        for m, (sl, (p, R, tw_m, ac_m)) in enumerate(zip(model.dof_slices,
                                                        grasp_targets(model, p_C, R_o, tw, ac, origin))):
            if m in redundant:
                continue
            sol = _solve_arm(model, m, p, R, tw_m, ac_m, guess, t, origin + p_C)
            if sol.full_error > plane_tol:
                raise _failure(model, "plane", m, t, origin + p_C, sol.full_error)
            q[i, sl], qd[i, sl], qdd[i, sl], dets[i, m] = sol.q[sl], sol.qd[sl], sol.qdd[sl], sol.det
            if i and np.sign(dets[i, m]) != np.sign(dets[i - 1, m]):
                raise _failure(model, "crosses", m, t, origin + p_C, t_prev=t_out[i - 1])
    return q, qd, qdd


# The fields of a Model that the object-motion trajectory does not depend on: what a sweep may change
# between points that share one trajectory (payload, motors, distributions' settings, the twin).
TRAJECTORY_INDEPENDENT = frozenset({"name", "torques", "motors", "mujoco", "validation", "control",
                                    "inverse.payload_position", "inverse.internal_force_bound",
                                    "inverse.internal_moment_bound", "inverse.nonsqueezing_masses"})
SHARED_TRAJECTORIES = 8           # the most trajectories a process keeps for sharing
_shared: OrderedDict[tuple[str, str], JointTrajectory] = OrderedDict()


def shared_object_motion_trajectory(model: Model, motion: ObjectMotion) -> JointTrajectory:
    """`object_motion_trajectory`, computed once per content of what determines it and shared.

    Models that differ only in TRAJECTORY_INDEPENDENT fields (a sweep over the payload's position, the
    motors, the distributions' bounds) get the trajectory computed once, each caller its own copy of the
    arrays (writable, as the compiled kernels take them); the last SHARED_TRAJECTORIES are kept. A model
    holding a Python callable where the trajectory depends on it is not shared.

    Args:
        model: the Model whose arms carry the object.
        motion: the object's waypoints and time law.

    Returns:
        JointTrajectory: as `object_motion_trajectory`.

    Raises:
        TrajectoryError: as `object_motion_trajectory`.
    """
    key = (content_digest(model, TRAJECTORY_INDEPENDENT), content_digest(motion))
    if None in key:
        return object_motion_trajectory(model, motion)
    if key in _shared:
        _shared.move_to_end(key)
    else:
        _shared[key] = object_motion_trajectory(model, motion)
        while len(_shared) > SHARED_TRAJECTORIES:
            _shared.popitem(last=False)
    kept = _shared[key]
    return replace(kept, **{f.name: getattr(kept, f.name).copy() for f in fields(kept)
                            if isinstance(getattr(kept, f.name), np.ndarray)})


def _check_joint_counts(model: Model, S: np.ndarray) -> list[int]:
    """Indices of the redundant arms (more joints than rows); TrajectoryError for an arm with fewer."""
    for arm in model.arms:
        if arm.n < S.shape[0]:
            raise TrajectoryError(
                f"inverse.object_motion: arm {arm.name!r} has {arm.n} joints for {S.shape[0]} constrained "
                f"rows; closed-chain inverse kinematics needs at least as many joints as rows")
    return [m for m, arm in enumerate(model.arms) if arm.n > S.shape[0]]


def _check_joint_limits(model: Model, t: np.ndarray, q: np.ndarray, parameter: str = "t"):
    hit = joint_limit_violation(model, q)
    if hit is not None:
        i, j = hit
        raise TrajectoryError(f"inverse.object_motion: at {_at(parameter, t[i])} {joint_limit_reason(model, j, q[i, j])}")


# ------------------------------------------------------------------------------------------------
# redundant arms
# ------------------------------------------------------------------------------------------------

def redundant_rates(arm: ArmModel, S: np.ndarray, q: np.ndarray, twist: np.ndarray, acc: np.ndarray | None,
                    rest: np.ndarray, gain: float, gain_rate: float = 0.0):
    """Redundancy resolution of one arm with n joints for k < n rows S: θ̇ (and θ̈) of least |θ̇ − z|.

    With A = S J_m (k × n) of full row rank: θ̇ = A⁺ S v_EE + (I − A⁺A) z, z = gain (θ_rest − θ),
    A⁺ = Aᵀ(AAᵀ)⁻¹ — the joint velocity nearest z (least |θ̇ − z|) among those that move the end-effector
    as prescribed, i.e. least |θ̇| plus a null-space pull toward the rest posture that does not move the
    end-effector. Written θ̇ = z + Aᵀλ, AAᵀλ = b − Az (b = S v_EE). Its exact time derivative:
    θ̈ = ż + Ȧᵀλ + Aᵀλ̇, ż = ġ (θ_rest − θ) − gain θ̇ (ġ = gain_rate), AAᵀλ̇ = ḃ − Ȧθ̇ − Aż − AȦᵀλ
    (so A θ̈ = S a_EE − Ȧθ̇, the differential kinematics of the square arms); Ȧ = S J̇
    (`point_jacobian_rate`).

    Args:
        arm: the ArmModel (n joints).
        S: (k, 6) row selector, k < n.
        q: (n,) rad (m on a prismatic joint), the arm's joint coordinates.
        twist: (6,) [v_EE; ω] m/s, rad/s, the end-effector twist, world axes.
        acc: (6,) [a_EE; ω̇] m/s², rad/s², the end-effector acceleration, world axes; None: θ̈ not
            computed.
        rest: (n,) rad (m), the rest posture θ_rest.
        gain: 1/s, the gain of the null-space pull toward the rest posture.
        gain_rate: 1/s², its time derivative (`pull_gain`; 0 for a constant gain).

    Returns:
        tuple: θ̇ (n,) rad/s (m/s); θ̈ (n,) rad/s² (m/s²), or None when acc is None; A = S J_m (k, n).
    """
    pose = arm_pose(arm, q)
    A = S @ ee_jacobian(pose)
    AAt = A @ A.T
    z = gain * (rest - q)
    lam = np.linalg.solve(AAt, S @ twist - A @ z)
    qd = z + A.T @ lam
    if acc is None:
        return qd, None, A
    dA = S @ point_jacobian_rate(pose, pose.p_ee_rel, qd)
    dz = gain_rate * (rest - q) - gain * qd
    dlam = np.linalg.solve(AAt, S @ acc - dA @ qd - A @ dz - A @ (dA.T @ lam))
    return qd, dz + dA.T @ lam + A.T @ dlam, A


def min_norm_ik(arm: ArmModel, S: np.ndarray, p: np.ndarray, R: np.ndarray, guess: np.ndarray,
                tol: float = 1e-13, max_iter: int = 50) -> np.ndarray:
    """Joint angles (n,) of a redundant arm putting its end-effector frame at (p, R) in the rows S (k < n).

    Least-norm Newton steps Δθ = −A⁺ S e(θ), A = S J, from `guess` until max |S e| <= tol (the solution
    nearest the guess to first order).

    Args:
        arm: the ArmModel (n joints).
        S: (k, 6) row selector, k < n.
        p: (3,) m, the target position relative to the arm's base point, world axes.
        R: (3, 3) the target orientation, world axes.
        guess: (n,) rad (m on a prismatic joint), the starting joint coordinates (not changed).
        tol: m or rad, the tolerance on max |S e|.
        max_iter: the most Newton steps.

    Returns:
        np.ndarray: (n,) rad (m) the joint coordinates.

    Raises:
        ConstraintError: Newton does not converge in max_iter steps.
    """
    q = guess.astype(float).copy()
    for _ in range(max_iter):
        pose = arm_pose(arm, q)
        e = S @ pose_error_at(pose, p, R)
        if np.max(np.abs(e)) <= tol:
            return q
        A = S @ ee_jacobian(pose)
        q -= A.T @ np.linalg.solve(A @ A.T, e)
    raise ConstraintError(newton_failure(float(np.max(np.abs(e))), max_iter))


REDUNDANT_RTOL = 1e-12   # DOP853 tolerances of the redundancy-resolution ODE (rad)
REDUNDANT_ATOL = 1e-12


def redundant_motion(model: Model, motion: ObjectMotion, t_out: np.ndarray, guess: np.ndarray,
                     arms: list[int], plane_tol: float, sing_tol: float = 1e-7):
    """(θ, θ̇, θ̈) (N, n_total) of the redundant arms `arms` at the times t_out (N,) (zeros elsewhere).

    θ(t) solves the ODE θ̇ = `redundant_rates` (rest posture and gain from `motion`, default the
    scenario's initial angles and 1/s) from the least-norm IK solution nearest `guess` at the first
    sample, integrated by DOP853 (rtol = atol = 1e-12) segment by segment between waypoints (the time
    law is smooth inside each). At every sample θ is then put exactly on the grasp by least-norm Newton
    (`min_norm_ik`, a correction of the integration error only) and θ̇, θ̈ are evaluated there, so the
    three are consistent as for the square arms.

    Args:
        model: the Model.
        motion: the prescribed ObjectMotion.
        t_out: (N,) s, the sample times, within the waypoint span.
        guess: (n_total,) rad (m), stacked joint coordinates; the redundant arms' rows start the
            least-norm IK at the first sample.
        arms: the indices of the redundant arms.
        plane_tol: m or rad, how far a grasp may leave the plane of motion of a planar scene.
        sing_tol: an arm counts as singular when σ_min/σ_max of S J is below it.

    Returns:
        tuple[np.ndarray, np.ndarray, np.ndarray]: θ (N, n_total) rad (m), θ̇ (N, n_total) rad/s (m/s)
        and θ̈ (N, n_total) rad/s² (m/s²), stacked arm after arm; zero in the other arms' columns.

    Raises:
        TrajectoryError: an arm nears a singularity (σ_min/σ_max of S J below sing_tol), leaves its
            reach or the plane of motion, or the integration stops (its step size collapsed).
    """
    from scipy.integrate import solve_ivp

    S, origin = model.rows, motion.positions[0]
    slices = [model.dof_slices[m] for m in arms]
    rest = model.q0 if motion.rest_posture is None else motion.rest_posture
    q, qd, qdd = (np.zeros((len(t_out), model.n_total)) for _ in range(3))

    def targets(t):
        p_C, R_o, tw, ac = object_motion_at(motion, t, origin)
        return grasp_targets(model, p_C, R_o, tw, ac, origin), origin + p_C

    def rates(t, y, tg, acc=False):
        out = []
        gain, gain_rate = pull_gain(motion, t)
        for m, sl in zip(arms, slices):
            y_m = y[sl]
            rd, rdd, A = redundant_rates(model.arms[m], S, y_m, tg[m][2], tg[m][3] if acc else None,
                                         rest[sl], gain, gain_rate)
            sv = np.linalg.svd(A, compute_uv=False) if acc else np.ones(1)
            if not sv[-1] >= sing_tol * sv[0]:
                raise _failure(model, "singular_redundant", m, t, np.zeros(3), sv[-1] / sv[0])
            out.append((rd, rdd))
        return out

    def on_grasp(t, y):
        (tg, p_C), y = targets(t), y.copy()
        for m, sl in zip(arms, slices):
            y[sl] = _redundant_ik(model, m, tg[m][0], tg[m][1], y[sl], t, p_C, plane_tol)
        return y, tg

    def rhs(t, x):
        return np.concatenate([rd for rd, _ in rates(t, _stacked(model.n_total, slices, x), targets(t)[0])])

    y = on_grasp(t_out[0], guess)[0]
    last = len(motion.times) - 2
    for k, (ta, tb) in enumerate(zip(motion.times[:-1], motion.times[1:])):
        inside = (t_out >= ta) & ((t_out < tb) | (k == last))      # a waypoint's sample: in the segment it starts
        x0 = np.concatenate([y[sl] for sl in slices])
        sol = solve_ivp(rhs, (ta, tb), x0, method="DOP853", rtol=REDUNDANT_RTOL, atol=REDUNDANT_ATOL,
                        dense_output=True)
        for i in np.flatnonzero(inside if sol.status == 0 else inside & (t_out <= sol.t[-1])):
            q[i], tg = on_grasp(t_out[i], _stacked(model.n_total, slices, sol.sol(t_out[i])))
            for sl, (rd, rdd) in zip(slices, rates(t_out[i], q[i], tg, acc=True)):
                qd[i, sl], qdd[i, sl] = rd, rdd
        if sol.status != 0:
            raise _failure(model, "integration", 0, float(sol.t[-1]), np.zeros(3))
        y = on_grasp(tb, _stacked(model.n_total, slices, sol.sol(tb)))[0]
    return q, qd, qdd


def _stacked(n: int, slices: list[slice], x: np.ndarray) -> np.ndarray:
    """x (the redundant arms' angles, one after the other) spread into a stacked (n,) vector."""
    y = np.zeros(n)
    for sl, xs in zip(slices, np.split(x, np.cumsum([s.stop - s.start for s in slices])[:-1])):
        y[sl] = xs
    return y


def _redundant_ik(model: Model, m: int, p, R, guess, t, p_C, plane_tol):
    """Least-norm IK of redundant arm m (`min_norm_ik`) with the one-line errors of `_solve_arm`."""
    arm, S = model.arms[m], model.rows
    dist, reach, ok = reach_check(arm, p)
    if not ok:
        raise _failure(model, "reach", m, t, p_C, dist, reach)
    try:
        q = min_norm_ik(arm, S, p, R, guess)
    except ConstraintError as e:
        raise _failure(model, "newton", m, t, p_C, detail=str(e)) from None
    full = float(np.max(np.abs(pose_error(arm, q, p, R))))
    if full > plane_tol:
        raise _failure(model, "plane", m, t, p_C, full)
    return q


def _solve_arm(model: Model, m: int, p, R, twist, acc, guess, t, p_C):
    """Arm m at the targets (p relative to its base point; compiled Newton and differential kinematics,
    `coopsim.compiled.api.solve_arm`, the same steps as `arm_ik` and `arm_rates`), with one-line errors
    naming the arm and the time (p_C: the object's world position, for the message)."""
    from coopsim.compiled import api, ik

    dist, reach, ok = reach_check(model.arms[m], p)
    if not ok:
        raise _failure(model, "reach", m, t, p_C, dist, reach)
    sol = api.solve_arm(model, m, p, R, twist, acc, guess)
    if sol.status == ik.SINGULAR:
        raise _failure(model, "singular", m, t, p_C, sol.ratio)
    if sol.status != ik.SOLVED:
        raise _failure(model, "newton", m, t, p_C, sol.ratio)
    return sol


def object_pose_of(model: Model, q: np.ndarray):
    """Object pose (p_C, R_o) carried by the carrier arm at stacked angles q.

    Args:
        model: the Model (its object's carrier arm and grasp).
        q: (n_total,) rad (m on a prismatic joint), the stacked joint coordinates, arm by arm.

    Returns:
        tuple[np.ndarray, np.ndarray]: p_C (3,) m, the object's centre of mass, world; R_o (3, 3),
        world ← object.
    """
    obj = carrier_object(model, arm_poses(model, q))
    return obj.p_C, obj.R_o
