"""The B-spline object path: its ends, its straight special case, and its exact s- and t-derivatives
against central finite differences (a reference that cannot share the left-Jacobian algebra)."""

import numpy as np
import pytest

from coopsim.core.model import ObjectMotion, PathSpline
from coopsim.core.spatial import rot_log, rpy_to_rot
from coopsim.inverse.spline_path import (BSplinePath, greville, knots, nested, refinement, spline_arrays,
                                        straight_control_points)
from coopsim.inverse.trajectory import object_motion_at

H = 1e-5     # central differences: truncation O(h²) ~ 1e-10 × the third derivative, rounding ~ 1e-16/h


def _motion(K: int, seed: int = 3, big: bool = True) -> ObjectMotion:
    """A spatial two-waypoint motion with K random interior control points; `big`: rotation vectors up
    to about 1.5 rad (the exact left Jacobian), else below 0.05 rad (its Taylor series)."""
    rng = np.random.default_rng(seed)
    amp = 0.5 if big else 0.015
    R0, R1 = rpy_to_rot(rng.uniform(-amp, amp, 3)), rpy_to_rot(rng.uniform(-amp, amp, 3))
    path = PathSpline("bspline", rng.uniform(-0.3, 0.3, (K, 3)), rng.uniform(-2 * amp, 2 * amp, (K, 3)))
    return ObjectMotion(np.array([1.0, 4.0]), np.array([[0.1, 0.2, 0.3], [0.5, -0.1, 0.2]]), np.stack([R0, R1]),
                        "quintic", 0.1, path=path)


def test_knots_and_greville_abscissae():
    """Clamped uniform knots of degree min(3, K + 1); Greville abscissae from 0 to 1, increasing."""
    assert knots(1).tolist() == [0, 0, 0, 1, 1, 1]
    assert knots(3).tolist() == [0, 0, 0, 0, 0.5, 1, 1, 1, 1]
    xi = greville(4)
    assert xi[0] == 0 and xi[-1] == 1 and np.all(np.diff(xi) > 0)


@pytest.mark.parametrize("K", [1, 2, 5])
def test_ends_are_the_waypoint_poses(K):
    m = _motion(K)
    pts = BSplinePath(m).at(np.array([0.0, 1.0]))
    assert pts.p == pytest.approx(m.positions, abs=1e-15)
    assert pts.R[0] == pytest.approx(m.rotations[0], abs=1e-15)
    assert pts.R[1] == pytest.approx(m.rotations[1], abs=1e-13)


def test_straight_control_points_give_the_straight_path():
    """At the Greville abscissae the B-spline reproduces the segment: p = p₀ + s (p₁ − p₀), constant p′, p″ = 0."""
    m = _motion(4)
    m = ObjectMotion(m.times, m.positions, m.rotations, path=straight_control_points(m, 4))
    s = np.linspace(0, 1, 9)
    pts = BSplinePath(m).at(s)
    d = m.positions[1] - m.positions[0]
    assert pts.p == pytest.approx(m.positions[0] + s[:, None] * d, abs=1e-15)
    assert pts.dp == pytest.approx(np.tile(d, (9, 1)), abs=1e-14)
    assert np.max(np.abs(pts.ddp)) < 1e-13
    phi1 = rot_log(m.rotations[1] @ m.rotations[0].T)
    assert pts.dw == pytest.approx(np.tile(phi1, (9, 1)), abs=1e-14)     # a fixed axis: ω′ = φ₁


@pytest.mark.parametrize("big", [True, False])
@pytest.mark.parametrize("K", [1, 4])
def test_s_derivatives_match_finite_differences(K, big):
    """p′, p″ and ω′ (from log(R(s+h)R(s−h)ᵀ)/2h), ω″ (from ω′) to 1e-8 of their scale."""
    path = BSplinePath(_motion(K, big=big))
    s = np.array([0.05, 0.3, 0.5, 0.77, 0.95])
    pt, up, dn = path.at(s), path.at(s + H), path.at(s - H)
    scale = max(1.0, np.max(np.abs(pt.ddw)))
    assert pt.dp == pytest.approx((up.p - dn.p) / (2 * H), abs=1e-8)
    assert pt.ddp == pytest.approx((up.dp - dn.dp) / (2 * H), abs=1e-8)
    w = np.array([rot_log(a @ b.T) for a, b in zip(up.R, dn.R)]) / (2 * H)
    assert pt.dw == pytest.approx(w, abs=1e-8 * scale)
    assert pt.ddw == pytest.approx((up.dw - dn.dw) / (2 * H), abs=1e-8 * scale)


def test_object_motion_at_follows_the_spline_with_its_time_law():
    """The twist and acceleration of `object_motion_at` on a B-spline motion are the time derivatives
    of its pose and twist (central differences in t), and the ends rest."""
    m = _motion(3)
    for t in (1.4, 2.6, 3.7):          # off the interior knot at t = 2.5 (p‴ jumps there)
        p, R, tw, ac = object_motion_at(m, t)
        pu, Ru, twu, _ = object_motion_at(m, t + H)
        pd, Rd, twd, _ = object_motion_at(m, t - H)
        assert tw[:3] == pytest.approx((pu - pd) / (2 * H), abs=1e-8)
        assert tw[3:] == pytest.approx(rot_log(Ru @ Rd.T) / (2 * H), abs=1e-8)
        assert ac == pytest.approx((twu - twd) / (2 * H), abs=1e-7)
    for t in m.times:
        assert np.max(np.abs(object_motion_at(m, t)[2])) < 1e-15


def _refined_motion(m: ObjectMotion, fine: int) -> ObjectMotion:
    """The motion whose path has `fine` interior control points: `refinement` applied to the coefficients
    [p − p₀, φ] of m's path (its end rows must come back as the ends)."""
    _, C, _ = spline_arrays(m)
    F = refinement(len(m.path.positions), fine) @ C
    assert F[0] == pytest.approx(C[0], abs=1e-15) and F[-1] == pytest.approx(C[-1], abs=1e-14)
    return ObjectMotion(m.times, m.positions, m.rotations, m.time_law, m.output_dt,
                        path=PathSpline("bspline", m.positions[0] + F[1:-1, :3], F[1:-1, 3:]))


@pytest.mark.parametrize("coarse,fine", [(1, 2), (1, 4), (2, 4), (3, 5), (4, 7), (4, 4)])
def test_refinement_of_nested_splines_is_the_same_path(coarse, fine):
    """Degree elevation (K = 1, 2: one polynomial piece) and knot insertion (K = 3 → 5, 4 → 7: the coarse
    knots among the fine ones): the refined path, evaluated by scipy's BSpline on its own knots, is the
    coarse one at 1001 points, with its s-derivatives and orientation, to 1e-12 (a 9 × 9 collocation solve
    on the Greville abscissae, values and derivatives of order 1–10: rounding ~1e-14)."""
    m = _motion(coarse)
    assert nested(coarse, fine)
    s = np.linspace(0.0, 1.0, 1001)
    a, b = BSplinePath(m).at(s), BSplinePath(_refined_motion(m, fine)).at(s)
    for x, y in zip(a, b):
        assert np.max(np.abs(x - y)) <= 1e-12


def test_refinement_of_a_spline_not_in_the_finer_space_interpolates_it():
    """K = 3 (knot 1/2) is no spline on the knots 1/3, 2/3 of K = 4: the refinement meets the coarse path at
    the fine Greville abscissae (to 1e-13) and differs from it between them (by more than 1 mm here)."""
    m = _motion(3)
    assert not nested(3, 4) and not nested(4, 3) and nested(1, 6) and not nested(2, 1)
    f = _refined_motion(m, 4)
    xi = greville(4)
    assert np.max(np.abs(BSplinePath(m).at(xi).p - BSplinePath(f).at(xi).p)) <= 1e-13
    s = np.linspace(0.0, 1.0, 201)
    assert np.max(np.abs(BSplinePath(m).at(s).p - BSplinePath(f).at(s).p)) > 1e-3
