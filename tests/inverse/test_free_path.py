"""The free path that carries the most: optimality against a brute-force grid over one via point, the
optimum's capacity rechecked on a finer grid and by rerunning the inverse dynamics at the capacity, the
NLP's Jacobian against central differences, determinism; the joint path in s of the compiled pass
against `coopsim.inverse.path.joint_path`."""

from dataclasses import replace
from itertools import product

import numpy as np
import pytest

from coopsim.dynamics.kinematics import arm_pose, ee_jacobian
from coopsim.io.robots import robots_folder
from coopsim.inverse.capacity import brute_force_check, method_capacity
from coopsim.inverse import free_path
from coopsim.inverse.free_path import (JOINT_MARGIN, FreePathProblem, accepted_mass, check_ranges_between, optimize_path,
                                      retimed_capacity, spline_joint_path, status_text)
from coopsim.inverse.spline_path import BSplinePath
from coopsim.inverse.trajectory import TrajectoryError, trajectory_at_times, JointTrajectory
from coopsim.inverse.path import path_grid
from coopsim.inverse.problem import inverse_problem
from coopsim.inverse.solve import resolution_for
from coopsim.inverse.trajectory import object_motion_trajectory
from inverse_cases import model

CARRY = "paper_planar_2x3_carry"


def _one_via_point(**settings):
    """The paper carry with one interior control point (a quadratic B-spline: one via point), a 0.5 s grid."""
    m = model(CARRY)
    opt = replace(m.inverse.optimize, **({"control_points": 1, "sample_dt": 0.5, "starts": 1} | settings))
    return replace(m, inverse=replace(m.inverse, optimize=opt))


@pytest.fixture(scope="module")
def via_point():
    m = _one_via_point()
    return m, optimize_path(m, "paper", retime=False)


def test_optimum_is_at_least_the_best_of_a_brute_force_grid(via_point):
    """Over the one via point's in-plane offset (±2 cm) and turn (±0.05 rad), a 5 × 5 × 3 grid of closed-form
    capacities on the same samples: the optimiser converges and carries at least the grid's best (to 1e-9
    relative), and more than the straight path."""
    m, opt = via_point
    problem = FreePathProblem(m, resolution_for(m, "paper"), opt.mode)
    grid = [np.array([x / problem.scale[0], y / problem.scale[1], w])
            for x, y, w in product(np.linspace(-0.02, 0.02, 5), np.linspace(-0.02, 0.02, 5), (-0.05, 0.0, 0.05))]
    masses = [c.mass for c in map(problem.capacity, grid) if c is not None]
    assert opt.best.success and opt.starts[0].status == 0
    assert opt.capacity.mass >= max(masses) * (1 - 1e-9)
    assert opt.capacity.mass > opt.straight.mass


def test_optimum_rechecked_on_the_scenario_grid(via_point):
    """The written motion (the scenario's 0.02 s grid, which holds the optimiser's 0.5 s samples) carries no
    more than on the optimiser's grid and within 1 % of it; rerunning the inverse dynamics with the payload at
    (1 ∓ 1e-6) × that capacity puts every torque within its line below and one beyond it above."""
    m, opt = via_point
    traj = object_motion_trajectory(m, opt.motion)
    fine = method_capacity(inverse_problem(m, traj, m.inverse.payload_position), opt.resolution, m.motors, opt.mode)
    assert fine.mass <= opt.capacity.mass * (1 + 1e-12)
    assert fine.mass == pytest.approx(opt.capacity.mass, rel=1e-2)
    assert brute_force_check(m, traj, opt.resolution, opt.mode, fine, m.inverse.payload_position)["ok"]


def test_constraint_jacobian_matches_central_differences():
    """The forward-difference Jacobian in the path unknowns against central differences (step 1e-5), and the
    exact μ column, at a point off the straight path."""
    m = _one_via_point()
    problem = FreePathProblem(m, resolution_for(m, "paper"), "payload")
    x, mu, h = np.array([0.004, -0.006, 0.03]), 500.0, 1e-5
    J = problem.jacobian(x, mu)
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        central = (problem.constraints(x + e, mu) - problem.constraints(x - e, mu)) / (2 * h)
        assert J[:, i] == pytest.approx(central, abs=1e-5 * np.max(np.abs(central)))
    dmu = (problem.constraints(x, mu + 1.0) - problem.constraints(x, mu - 1.0)) / 2.0
    assert J[:, -1] == pytest.approx(dmu, abs=1e-12)


def test_same_input_same_optimum():
    """Two runs (a random start included, fixed seed) give the same path to the last bit."""
    m = _one_via_point(starts=2, max_iterations=5)
    a, b = optimize_path(m, "paper", retime=False), optimize_path(m, "paper", retime=False)
    assert a.motion.path.positions.tobytes() == b.motion.path.positions.tobytes()
    assert a.motion.path.rotation_vectors.tobytes() == b.motion.path.rotation_vectors.tobytes()
    assert [r.status for r in a.starts] == [r.status for r in b.starts]


def _bent(name: str, offset: float):
    """A scene's free path with the seeded offsets x = offset per unit (K = 4; in-plane on the paper carry)."""
    m = model(name)
    problem = FreePathProblem(m, resolution_for(m, "paper"), "payload")
    return m, problem.motion_of(offset * np.random.default_rng(2).normal(0.0, 1.0, problem.size))


@pytest.mark.parametrize("name", [CARRY, pytest.param("robots/panda_ceiling_carry", marks=pytest.mark.skipif(
    robots_folder() is None, reason="example-robot-data is not installed"))])
def test_spline_joint_path_of_the_compiled_pass_equals_joint_path(name):
    """θ(s), θ′(s), θ″(s) of a bent free path on 41 points by the compiled pass in unit time (`spline_joint_path`)
    and by `joint_path` (the reference). Square arms: both Newton to max |S e| <= 1e-13 from the same
    continuation guesses, so within 2e-13/σ_min (θ′, θ″: times (1 + max |θ′|)/σ_min, resp. θ″). Redundant arms:
    the compiled pass integrates both arms' ODE in s as one system (one DOP853 error norm), joint_path arm by
    arm, so their steps differ and they agree to the integration's global error, allowed 1e-10 rad per rad of
    |θ| (a hundred times its rtol of 1e-12; measured 3.6e-11 rad, 2.1e-10 and 1.3e-9 in θ′, θ″ on the
    Panda carry)."""
    m, motion = _bent(name, 0.01)
    s, piece = path_grid(np.array([0.0, 1.0]), 40)
    got, ref = spline_joint_path(m, motion, s, piece), spline_joint_path(m, motion, s, piece, engine="reference")
    assert np.array_equal(got.points.p, ref.points.p) and np.array_equal(got.points.d2, ref.points.d2)
    s_min = min(float(np.linalg.svd(m.rows @ ee_jacobian(arm_pose(arm, q[sl])), compute_uv=False)[-1])
                for q in ref.q for arm, sl in zip(m.arms, m.dof_slices))
    ode = 1e-10 if any(arm.n > m.rows.shape[0] for arm in m.arms) else 0.0
    tol = 2e-13 / s_min + ode * (1 + np.max(np.abs(ref.q)))
    assert np.max(np.abs(got.q - ref.q)) <= tol
    for a, b in ((got.d1, ref.d1), (got.d2, ref.d2)):
        assert np.max(np.abs(a - b)) <= tol * (1 + np.max(np.abs(b))) / s_min


def test_a_refused_free_path_names_the_path_parameter():
    """A via point out of the arms' reach (0.5 × 1.25 m in y): the compiled pass in unit time refuses the path
    at a path parameter, and its text quotes it as s (no time: the path has no time law yet)."""
    m = _one_via_point()
    motion = FreePathProblem(m, resolution_for(m, "paper"), "payload").motion_of(np.array([0.0, 0.5, 0.0]))
    s, piece = path_grid(np.array([0.0, 1.0]), 40)
    with pytest.raises(TrajectoryError, match=r"^inverse\.object_motion: the path leaves the workspace of arm .* "
                                              r"at s=0\.\d+ \(object at \[") as e:
        spline_joint_path(m, motion, s, piece)
    assert "t=" not in str(e.value)


def test_accepted_mass_is_the_capacity_where_the_path_is_accepted():
    """Points of the one-via-point carry: the straight path, two small offsets, one whose via point leaves
    the arms' reach (0.5 × 1.25 m in y), one accepted by the inverse kinematics below the manipulability
    margin (0.4 × 1.25 m in x: the arms near stretched), one out of reach again: the accepted ones carry
    their closed-form capacity, the others nan."""
    m = _one_via_point()
    problem = FreePathProblem(m, resolution_for(m, "paper"), "payload")
    points = [np.zeros(3), np.array([0.004, -0.006, 0.03]), np.array([0.002, 0.003, -0.02]),
              np.array([0.0, 0.5, 0.0]), np.array([0.4, 0.0, 0.0]), np.array([0.5, 0.5, 0.0])]
    assert [problem.evaluate(x) is None for x in points] == [False, False, False, True, False, True]
    assert np.min(problem._rows(problem.evaluate(points[4]))[3]) < 0
    masses = [accepted_mass(problem, x) for x in points]
    assert np.isnan(masses[3:]).all()
    assert masses[:3] == [problem.capacity(x).mass for x in points[:3]]


def test_an_accepted_point_carries_the_bare_object(monkeypatch):
    """`accepted_mass` of the straight one-via-point path whose capacity interval [lower, mass] is replaced:
    starting above the bare object's μ (0 in the payload mode: the motors cannot move a lighter load), or
    infeasible, the point is not accepted (nan); from 0 it carries its mass."""
    from dataclasses import replace as swap

    m = _one_via_point()
    problem = FreePathProblem(m, resolution_for(m, "paper"), "payload")
    x, real = np.zeros(3), problem.capacity(np.zeros(3))
    assert real.lower == 0.0 and accepted_mass(problem, x) == real.mass
    for lower, feasible, expect in ((0.1 * real.mass, True, np.nan), (0.0, False, np.nan), (0.0, True, real.mass)):
        monkeypatch.setattr(problem, "capacity", lambda x, c=swap(real, lower=lower, feasible=feasible): c)
        got = accepted_mass(problem, x)
        assert (np.isnan(got) and np.isnan(expect)) or got == expect, (lower, feasible, got)


def test_a_run_ends_at_its_heaviest_accepted_point(monkeypatch):
    """From a turned via point (0.6 rad) on the one-via-point carry with 3 iterations, SLSQP's iterates go
    up and down (measured: 135, 534, 418, 462 kg): the run ends at the heaviest of its start, iterates and
    end point by `accepted_mass` recomputed here on every point the SLSQP callback and result show, so
    never below its start."""
    import scipy.optimize

    seen, minimize = [], scipy.optimize.minimize

    def recording(*args, **kwargs):
        inner = kwargs["callback"]
        kwargs["callback"] = lambda z: (seen.append(z[:-1].copy()), inner(z))
        out = minimize(*args, **kwargs)
        seen.append(out.x[:-1].copy())
        return out

    monkeypatch.setattr(scipy.optimize, "minimize", recording)
    m = _one_via_point()
    problem = FreePathProblem(m, resolution_for(m, "paper"), "payload")
    x0 = np.array([0.0, 0.0, -0.6])
    x, run = free_path._solve_start(problem, x0, 0, 3)
    masses = np.array([accepted_mass(problem, p) for p in [x0] + seen])
    assert run.capacity_kg == problem.capacity(x).mass == np.nanmax(masses)
    assert run.capacity_kg >= run.start_capacity_kg == masses[0]
    assert np.nanmin(masses[1:]) < 0.95 * run.capacity_kg                 # the case exercises the choice
    assert run.status == 9 and "iteration limit" in run.message


def test_continuation_refines_the_coarse_optimum_into_the_same_path():
    """The K = 1 optimum's offsets refined to K = 4 (`FreePathProblem.refined`): the same path at 501 s to
    1e-12 m, the same capacity to 1e-9 relative (the IK's Newton tolerance, 1e-13, on the same samples);
    and `optimize_path` with K = 4 ends no lower on the scenario's grid than any of its runs (K = 1 starts,
    the refined K = 2 and K = 4 runs, the straight path on K = 4; a refined start competes with its run's end)."""
    m1 = _one_via_point()
    m4 = _one_via_point(control_points=4)
    coarse = FreePathProblem(m1, resolution_for(m1, "paper"), "payload")
    fine = FreePathProblem(m4, resolution_for(m4, "paper"), "payload")
    x = np.array([0.004, -0.006, 0.03])
    xf = fine.refined(x, 1)
    s = np.linspace(0.0, 1.0, 501)
    a, b = BSplinePath(coarse.motion_of(x)).at(s), BSplinePath(fine.motion_of(xf)).at(s)
    assert max(np.max(np.abs(u - v)) for u, v in zip(a, b)) <= 1e-12
    assert fine.capacity(xf).mass == pytest.approx(coarse.capacity(x).mass, rel=1e-9)
    opt = optimize_path(m4, "paper", retime=False)
    assert [r.control_points for r in opt.starts] == [1, 2, 4, 4]             # the last: the straight path
    assert opt.starts[-1].start_capacity_kg == pytest.approx(opt.straight.mass, rel=1e-12)
    assert len(opt.motion.path.positions) == 4
    assert opt.best.scenario_grid_kg >= max(r.scenario_grid_kg for r in opt.starts)
    assert opt.capacity.mass >= opt.straight.mass


def test_slsqp_status_in_words():
    assert status_text(9, 40) == "status 9: the iteration limit was reached (inverse.optimize.max_iterations: 40)"
    assert status_text(8).startswith("status 8: the line search found no descent")
    assert status_text(42) == "status 42: an exit mode SciPy does not document"


def test_a_joint_passing_its_range_between_samples_is_refused():
    """θ = sin(2πt) of one joint sampled every 0.2 s (peak 1 at t = 0.25 s, samples at most 0.951): with the
    range ±1.05 it is accepted (the Bernstein hull, a bound of the interpolant, reaches 1.031 there) and the
    interpolant on a fine grid stays inside it; with ±0.99, which every sample keeps but the motion passes,
    refused naming the joint and the interval of the peak."""
    m = model(CARRY)
    t = np.linspace(0.0, 1.0, 6)
    w = 2 * np.pi
    q, qd, qdd = (np.zeros((6, m.n_total)) for _ in range(3))
    q[:, 2], qd[:, 2], qdd[:, 2] = np.sin(w * t), w * np.cos(w * t), -w * w * np.sin(w * t)
    wide = np.tile([-np.inf, np.inf], (m.n_total, 1))
    wide[2] = [-1.05, 1.05]
    check_ranges_between(replace(m, joint_range=wide), t, q, qd, qdd)
    fine = trajectory_at_times(JointTrajectory(t, q, qd, qdd, "object_motion"), np.linspace(0, 1, 1001))[0][:, 2]
    assert 0.999 < np.max(np.abs(fine)) <= 1.05 - JOINT_MARGIN and np.max(np.abs(q[:, 2])) < 0.99
    narrow = wide.copy()
    narrow[2] = [-0.99, 0.99]
    with pytest.raises(TrajectoryError, match=r"^inverse\.optimize: between 0\.2 and 0\.4 arm 1 .*joint 3 may come "
                                              r"within 1e-06 of its range \[-0\.99, 0\.99\]"):
        check_ranges_between(replace(m, joint_range=narrow), t, q, qd, qdd)


@pytest.mark.skipif(robots_folder() is None, reason="example-robot-data is not installed")
def test_a_stiff_redundancy_ode_stops_at_its_step_budget():
    """A Panda carry path SLSQP reached (K = 1, paper W⁺, its offsets at their bounds): the redundancy ODE turns
    stiff near a singularity and, without a budget, ran 4.7-6.3 s to its step-size collapse; the compiled
    pass stops it after max(2000, 50 × samples) step attempts (here 2000, 31 samples; a path the optimiser
    accepts takes 20-40 steps) with that reason."""
    from coopsim.compiled.object_motion import ODE_STEPS
    from coopsim.inverse.free_path import evaluate_motion

    m = model("robots/panda_ceiling_carry")
    problem = FreePathProblem(m, resolution_for(m, "paper"), "payload", control_points=1)
    x = np.array([0.5, 0.5, -0.1708011961256875, -0.5063840506485718, 0.7853981633974483, 0.2406830246843173])
    with pytest.raises(TrajectoryError, match=f"integration failed at t=1\\.\\d+ s \\(more than {ODE_STEPS} steps\\)"):
        evaluate_motion(m, problem.motion_of(x), problem.res, problem.mode)


def test_a_retimed_path_asked_to_beat_a_payload():
    """The straight one-via-point path retimed within 13 s (26 intervals): asked to beat 1 % more than its own
    heaviest payload it says no (None: its minimum time at that mass exceeds 13 s); asked to beat 1 % less, it
    finds the same heaviest payload as the plain search, within the two searches' tolerances (1e-10 of the
    mass each, 3e-10 allowed)."""
    m = _one_via_point()
    problem = FreePathProblem(m, resolution_for(m, "paper"), "payload")
    motion = problem.motion_of(np.zeros(problem.size))
    mass, r = retimed_capacity(m, motion, problem.res, "payload", 13.0, 26)
    assert r.duration <= 13.0 and mass > 0.0
    assert retimed_capacity(m, motion, problem.res, "payload", 13.0, 26, above=1.01 * mass) is None
    near, r_near = retimed_capacity(m, motion, problem.res, "payload", 13.0, 26, above=0.99 * mass)
    assert near == pytest.approx(mass, rel=3e-10) and r_near.duration <= 13.0
