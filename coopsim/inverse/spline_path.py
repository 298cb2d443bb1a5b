"""A free-form object path: clamped B-splines in position and orientation between two poses.

The object's centre of mass follows p(s) = Σ Bᵢ(s) cᵢ, s ∈ [0, 1], a clamped B-spline of degree
d = min(3, K + 1) on uniform knots through the control points c = [p₀; c₁ … c_K; p₁] (it starts at p₀ and
ends at p₁). The orientation is R(s) = Exp(φ(s)) R₀ with φ(s) the B-spline of rotation vectors
[0; φ₁ … φ_K; log(R₁R₀ᵀ)] (world axes), so R(0) = R₀ and R(1) = R₁. Cubic B-splines are C²: the object's
acceleration is continuous along the path.

Derivatives with respect to s, exact (B-spline derivatives and the left Jacobian of SO(3)):

    p′ = Σ Bᵢ′ cᵢ,  p″ = Σ Bᵢ″ cᵢ,
    ω′ = J_l(φ) φ′  (the angular velocity per unit ṡ, world axes: Ṙ Rᵀ = [ω′ ṡ]×),
    ω″ = J_l(φ) φ″ + (d/ds J_l(φ)) φ′,
    J_l(φ) = I + A(θ)[φ]× + B(θ)[φ]×²,  A = (1 − cos θ)/θ²,  B = (θ − sin θ)/θ³,  θ = |φ|,

with A and B (and their derivatives over θ, divided by θ) from their Taylor series near θ = 0. With a
time law s(t): v = p′ṡ, a = p″ṡ² + p′s̈, ω = ω′ṡ, ω̇ = ω″ṡ² + ω′s̈.

The straight path (`straight_control_points`): control points at the Greville abscissae of the knots
on the segment p₀p₁ (and on the rotation vector's segment), which the B-spline reproduces exactly
(p(s) = p₀ + s(p₁ − p₀)).
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np

from coopsim.core.model import ObjectMotion, PathSpline
from coopsim.core.spatial import axis_angle_to_rot, cross, rot_log

KIND = "bspline"
SMALL_ANGLE = 0.1       # rad: below it A, B and their derivatives come from their Taylor series


class PathPoint(NamedTuple):
    """The object path and its s-derivatives at M path parameters (world axes, SI units).

    Attributes:
        p: (M, 3) m, the centre of mass C.
        R: (M, 3, 3) world ← object.
        dp: (M, 3) m, p′ = dp/ds.
        dw: (M, 3) rad, ω′: the angular velocity per unit ṡ.
        ddp: (M, 3) m, p″.
        ddw: (M, 3) rad, ω″ = dω′/ds.
    """

    p: np.ndarray
    R: np.ndarray
    dp: np.ndarray
    dw: np.ndarray
    ddp: np.ndarray
    ddw: np.ndarray


def degree(control_points: int) -> int:
    """The B-spline degree for K interior control points: min(3, K + 1).

    Args:
        control_points: K >= 1, the interior control points.

    Returns:
        int: the degree.
    """
    return min(3, control_points + 1)


def knots(control_points: int) -> np.ndarray:
    """Clamped uniform knots on [0, 1] for K interior control points (K + 2 in all).

    Args:
        control_points: K >= 1.

    Returns:
        np.ndarray: (K + 2 + d + 1,) the knot vector, d = `degree`, d + 1 zeros and ones at the ends.
    """
    d, n = degree(control_points), control_points + 2
    inner = np.linspace(0.0, 1.0, n - d + 1)[1:-1]
    return np.concatenate([np.zeros(d + 1), inner, np.ones(d + 1)])


def greville(control_points: int) -> np.ndarray:
    """The Greville abscissae ξᵢ (mean of d consecutive knots) of the K + 2 control points.

    Args:
        control_points: K >= 1.

    Returns:
        np.ndarray: (K + 2,) in [0, 1], 0 and 1 at the ends.
    """
    d, t = degree(control_points), knots(control_points)
    return np.array([t[i + 1:i + 1 + d].mean() for i in range(control_points + 2)])


def basis_matrix(control_points: int, s: np.ndarray) -> np.ndarray:
    """The values of the K + 2 B-spline basis functions (`knots`, `degree`) at the points s.

    Args:
        control_points: K >= 1.
        s: (M,) path parameters in [0, 1].

    Returns:
        np.ndarray: (M, K + 2), row m the basis at s[m] (each row sums to 1).
    """
    from scipy.interpolate import BSpline

    n = control_points + 2
    return BSpline(knots(control_points), np.eye(n), degree(control_points))(np.asarray(s, dtype=float))


def nested(coarse: int, fine: int) -> bool:
    """Whether every B-spline of K = coarse interior control points is one of K = fine (the spaces nested).

    K = 1 is a quadratic and K = 2 a cubic polynomial (no interior knot), in every space of degree 3;
    otherwise the coarse interior knots must be among the fine ones (knot insertion, Boehm).

    Args:
        coarse: K >= 1 of the given spline.
        fine: K >= 1 of the refined one.

    Returns:
        bool.
    """
    if fine < coarse or degree(fine) < degree(coarse):
        return False
    if coarse == fine or coarse <= 2:
        return True
    inner = knots(fine)[degree(fine) + 1:-degree(fine) - 1]
    return all(np.any(np.abs(inner - k) < 1e-12) for k in knots(coarse)[degree(coarse) + 1:-degree(coarse) - 1])


def refinement(coarse: int, fine: int) -> np.ndarray:
    """The linear map from a spline's K = coarse + 2 control points to those of K = fine + 2 that interpolate
    it at the fine knots' Greville abscissae (where the fine basis is unisolvent, Schoenberg–Whitney).

    Where the spaces are `nested` (degree elevation of K = 1, 2; knot insertion otherwise) the fine spline is
    the coarse one itself, to rounding; elsewhere it is the interpolant. The ends map to the ends (both
    splines are clamped) and a straight path to the straight path; every row sums to 1.

    Args:
        coarse: K >= 1 of the given spline.
        fine: K >= 1 of the refined one.

    Returns:
        np.ndarray: (fine + 2, coarse + 2): c_fine = M c_coarse, per coordinate.
    """
    xi = greville(fine)
    return np.linalg.solve(basis_matrix(fine, xi), basis_matrix(coarse, xi))


def end_rotation_vector(motion: ObjectMotion) -> np.ndarray:
    """log(R₁R₀ᵀ) (3,) rad, world axes: the rotation vector from the first waypoint's orientation to the last's.

    Args:
        motion: the ObjectMotion (its first and last waypoint).

    Returns:
        np.ndarray: (3,) rad.
    """
    return rot_log(motion.rotations[-1] @ motion.rotations[0].T)


def straight_control_points(motion: ObjectMotion, control_points: int) -> PathSpline:
    """The interior control points of the straight path between the first and last waypoint poses.

    Args:
        motion: the ObjectMotion (its first and last waypoint).
        control_points: K >= 1.

    Returns:
        PathSpline: K control points on the segments p₀p₁ and 0 → log(R₁R₀ᵀ) at the Greville abscissae.
    """
    xi = greville(control_points)[1:-1, None]
    p0, p1 = motion.positions[0], motion.positions[-1]
    return PathSpline(KIND, p0 + xi * (p1 - p0), xi * end_rotation_vector(motion))


def spline_arrays(motion: ObjectMotion) -> tuple[np.ndarray, np.ndarray, int]:
    """The B-spline of a motion's path as arrays: knots, control coefficients [p − p₀, φ] and degree.

    Args:
        motion: the ObjectMotion (two waypoints and a B-spline `path` of K interior control points).

    Returns:
        tuple: the knots (K + d + 3,) (`knots`), the coefficients (K + 2, 6) [m relative to the first
        waypoint's position; rad, φ], world axes, from the first pose to the last, and the degree d.
    """
    path = motion.path
    K, p0 = len(path.positions), motion.positions[0]
    rel = np.vstack([np.zeros(3), path.positions - p0, motion.positions[-1] - p0])
    phi = np.vstack([np.zeros(3), path.rotation_vectors, end_rotation_vector(motion)])
    return knots(K), np.hstack([rel, phi]), degree(K)


class BSplinePath:
    """The object path of an ObjectMotion with a B-spline `path`, as functions of s ∈ [0, 1].

    Args:
        motion: the ObjectMotion; its first and last waypoints are the ends, its `path` the interior
            control points.

    Attributes:
        R0: (3, 3) the first waypoint's orientation, world ← object.
        origin: (3,) m, the first waypoint's position (positions are evaluated relative to it).
    """

    def __init__(self, motion: ObjectMotion):
        from scipy.interpolate import BSpline

        self.R0, self.origin = motion.rotations[0], motion.positions[0]
        both = BSpline(*spline_arrays(motion))                      # [p − p₀, φ]: one evaluation for both
        self._splines = [both] + [both.derivative(k) for k in (1, 2)]

    def at(self, s, origin: np.ndarray | None = None) -> PathPoint:
        """The path and its s-derivatives at s.

        Args:
            s: (M,) path parameters in [0, 1] (a float gives M = 1).
            origin: (3,) m, world: the point p is given relative to; None: the world origin.

        Returns:
            PathPoint: p (M, 3) m relative to `origin`, R (M, 3, 3), p′, ω′, p″, ω″ (M, 3), world axes.
        """
        s = np.atleast_1d(np.asarray(s, dtype=float))
        (rel, phi), (dp, dphi), (ddp, ddphi) = ((v[:, :3], v[:, 3:]) for v in (f(s) for f in self._splines))
        base = self.origin if origin is None else self.origin - origin
        R = np.array([_exp(f) @ self.R0 for f in phi])
        dw, ddw = left_jacobian_rates(phi, dphi, ddphi)
        return PathPoint(base + rel, R, dp, dw, ddp, ddw)


def _exp(phi: np.ndarray) -> np.ndarray:
    """Exp(φ) (3, 3) of a rotation vector φ (3,) rad."""
    angle = float(np.linalg.norm(phi))
    return axis_angle_to_rot(phi / angle, angle) if angle > 0 else np.eye(3)


def _coefficients(theta: np.ndarray):
    """(A, B, A′/θ, B′/θ) (M,) of J_l at angles θ (M,): exact, or their Taylor series below SMALL_ANGLE."""
    small = theta < SMALL_ANGLE
    th = np.where(small, 1.0, theta)
    s, c = np.sin(th), np.cos(th)
    A, B = (1 - c) / th**2, (th - s) / th**3
    a1 = s / th**3 - 2 * (1 - c) / th**4
    b1 = (1 - c) / th**4 - 3 * (th - s) / th**5
    t2 = theta**2
    taylor = (1 / 2 - t2 / 24 + t2**2 / 720 - t2**3 / 40320, 1 / 6 - t2 / 120 + t2**2 / 5040 - t2**3 / 362880,
              -1 / 12 + t2 / 180 - t2**2 / 6720 + t2**3 / 453600, -1 / 60 + t2 / 1260 - t2**2 / 60480 + t2**3 / 4989600)
    return tuple(np.where(small, ts, ex) for ts, ex in zip(taylor, (A, B, a1, b1)))


def left_jacobian_rates(phi: np.ndarray, dphi: np.ndarray, ddphi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ω′ = J_l(φ) φ′ and ω″ = J_l(φ) φ″ + (d/ds J_l(φ)) φ′ for R = Exp(φ(s)) R₀.

    With J_l = I + A[φ]× + B[φ]×² and θ′ = φ·φ′/θ: (d/ds J_l) φ′ = A′/θ (φ·φ′) φ × φ′ +
    B′/θ (φ·φ′) φ × (φ × φ′) + B φ′ × (φ × φ′) (the terms with [φ′]× φ′ = 0 drop).

    Args:
        phi: (M, 3) rad, φ(s), world axes.
        dphi: (M, 3) rad, φ′(s).
        ddphi: (M, 3) rad, φ″(s).

    Returns:
        tuple[np.ndarray, np.ndarray]: ω′ (M, 3) and ω″ (M, 3) rad, world axes.
    """
    A, B, a1, b1 = _coefficients(np.linalg.norm(phi, axis=1))

    def jl(v):
        pv = cross(phi, v)
        return v + A[:, None] * pv + B[:, None] * cross(phi, pv)

    dot = np.einsum("mi,mi->m", phi, dphi)[:, None]
    pd = cross(phi, dphi)
    ddw = jl(ddphi) + a1[:, None] * dot * pd + b1[:, None] * dot * cross(phi, pd) + B[:, None] * cross(dphi, pd)
    return jl(dphi), ddw


@lru_cache(maxsize=8)
def spline_path(motion: ObjectMotion) -> BSplinePath:
    """The BSplinePath of an ObjectMotion with a B-spline path, built once per motion (the last 8 kept).

    Args:
        motion: the ObjectMotion (two waypoints and a B-spline `path`).

    Returns:
        BSplinePath.
    """
    return BSplinePath(motion)


def spline_state(motion: ObjectMotion, s: float, ds: float, dds: float, origin: np.ndarray | None = None):
    """Object state on a B-spline path at s with the rates ṡ = ds, s̈ = dds: v = p′ṡ, a = p″ṡ² + p′s̈,
    ω = ω′ṡ, ω̇ = ω″ṡ² + ω′s̈.

    Args:
        motion: the ObjectMotion (two waypoints and a B-spline `path`).
        s: the path parameter in [0, 1].
        ds: 1/s, ṡ.
        dds: 1/s², s̈.
        origin: (3,) m, world: the point p_C is given relative to; None: the world origin.

    Returns:
        tuple: p_C (3,) m relative to `origin`, R_o (3, 3), twist [v_C; ω] (6,) and acceleration
        [a_C; ω̇] (6,), world axes (as `coopsim.inverse.trajectory.object_motion_at`).
    """
    pt = spline_path(motion).at(s, origin)
    twist = np.concatenate([ds * pt.dp[0], ds * pt.dw[0]])
    acc = np.concatenate([ds * ds * pt.ddp[0] + dds * pt.dp[0], ds * ds * pt.ddw[0] + dds * pt.dw[0]])
    return pt.p[0], pt.R[0], twist, acc
