"""The retiming against an independent implementation, toppra (TOPP-RA, Pham & Pham 2018; optional test
dependency): on the paper carry fed coopsim's closed-chain inverse dynamics as a black box through its
SecondOrderConstraint, and on open chains with toppra's own JointTorqueConstraint built from Pinocchio's
RNEA. The motor lines are replaced by constant torque bounds ±τ_s (what toppra handles natively).

toppra's first-order interpolation scheme is the discretisation coopsim's `retime` solves, so on one grid
the minimum times agree to toppra's solver tolerance; its collocation scheme (constraints at the grid
points only) differs by the two discretisations' difference, which shrinks as the grid is refined."""

from dataclasses import replace

import numpy as np
import pytest

from coopsim.dynamics.gibbs_appell import arm_dynamics
from coopsim.dynamics.kinematics import arm_pose
from coopsim.inverse import capacity as cap
from coopsim.inverse import retime as rt
from coopsim.inverse.path import JointPath, PathPoints, WaypointPath, joint_path, path_grid
from coopsim.inverse.problem import inverse_problem
from coopsim.inverse.solve import resolution_for, resolve
from coopsim.inverse.trajectory import JointTrajectory
from coopsim.io.scenario import load_scenario
from helpers import SCENARIOS
from independent.checks import scene

toppra = pytest.importorskip("toppra")
pin = pytest.importorskip("pinocchio")
INTERPOLATION, COLLOCATION = toppra.constraint.DiscretizationType.Interpolation, \
    toppra.constraint.DiscretizationType.Collocation


class _Path(toppra.interpolator.AbstractGeometricPath):
    """One piece of a coopsim joint path as a toppra path: θ, θ′, θ″ by coopsim's closed-chain IK at
    the asked s (computed on demand and kept)."""

    def __init__(self, model, path, piece, guess):
        self.model, self.path, self.piece, self.guess = model, path, piece, guess
        self._seen = {}

    def __call__(self, ss, order=0):
        ss = np.atleast_1d(np.asarray(ss, dtype=float))
        key = ss.tobytes()
        if key not in self._seen:
            self._seen[key] = joint_path(self.model, self.path, ss, np.full(len(ss), self.piece), self.guess)
        jp = self._seen[key]
        return (jp.q, jp.d1, jp.d2)[order]

    @property
    def dof(self):
        return self.model.n_total

    @property
    def path_interval(self):
        return np.array([self.path.knots[self.piece], self.path.knots[self.piece + 1]])


def _toppra_time(constraint, path, grid) -> float:
    algo = toppra.algorithm.TOPPRA([constraint], path, gridpoints=grid, solver_wrapper="seidel")
    _, sd, _, _ = algo.compute_parameterization(0.0, 0.0, return_data=True)
    assert np.all(np.isfinite(sd))
    return float(np.sum(2 * np.diff(grid) / (sd[1:] + sd[:-1])))


def _closed_chain_times(model, method, mass, n, scheme):
    """toppra's minimum time over the paper carry's three segments, coopsim's inverse dynamics a black box."""
    heavy = cap.payload_model(model, model.inverse.payload_position, mass)
    res = resolution_for(model, method)

    def inv_dyn(q, v, a):
        traj = JointTrajectory(np.zeros(1), q[None, :], v[None, :], a[None, :], "object_motion")
        return resolve(inverse_problem(heavy, traj), res).tau[0]

    ts = model.motors.stall_torque
    F, g = np.vstack([np.eye(len(ts)), -np.eye(len(ts))]), np.concatenate([ts, ts])
    constraint = toppra.constraint.SecondOrderConstraint(inv_dyn, lambda q: F, lambda q: g, len(ts),
                                                         discretization_scheme=scheme)
    path = WaypointPath.of(model.inverse.object_motion)
    total, guess = 0.0, model.inverse.object_motion.initial_guess
    for k in range(len(path.knots) - 1):
        p = _Path(model, path, k, guess)
        grid = np.linspace(path.knots[k], path.knots[k + 1], n + 1)
        total += _toppra_time(constraint, p, grid)
        guess = p(grid[-1:])[0]
    return total


@pytest.fixture(scope="module")
def carry():
    return load_scenario(SCENARIOS / "paper_planar_2x3_carry.yaml")


def _coopsim_time(model, method, mass, n):
    path = WaypointPath.of(model.inverse.object_motion)
    s, piece = path_grid(path.knots, n)
    jp = joint_path(model, path, s, piece, model.inverse.object_motion.initial_guess)
    dyn = rt.path_dynamics(model, jp, method, "payload")
    r = rt.retime(replace(dyn, slope=np.zeros_like(dyn.slope)), mass, "reachability", refine=False)  # toppra's grid
    assert r.feasible and r.converged
    return r.duration


def test_closed_chain_minimum_time_agrees_with_toppra(carry):
    """Paper carry, minimum energy, 20 kg payload, constant bounds ±τ_s: toppra's interpolation scheme on the
    same grid (12 intervals a segment) gives coopsim's minimum time to 1e-6; its collocation scheme differs
    by less on 24 intervals than on 12."""
    method, mass = "min_energy", 20.0
    mine = {n: _coopsim_time(carry, method, mass, n) for n in (12, 24)}
    assert _closed_chain_times(carry, method, mass, 12, INTERPOLATION) == pytest.approx(mine[12], rel=1e-6)
    gap = [abs(_closed_chain_times(carry, method, mass, n, COLLOCATION) - mine[n]) for n in (12, 24)]
    assert gap[1] < gap[0]


def test_open_chain_minimum_time_agrees_with_toppra_and_pinocchio():
    """One planar 3R arm of the paper (Pinocchio built from the YAML text alone) along a joint-space spline,
    torques ±τ_s: toppra with JointTorqueConstraint from Pinocchio's RNEA against coopsim's retime fed
    coopsim's own open-chain arm dynamics (τ = I θ̈ + h): the same time of the greedy reachability law to
    1e-6 on one grid (interpolation scheme, both TOPP-RA); collocation's gap shrinks from 30 to 60
    intervals; coopsim's grid LP finds a law at least as fast, within the lines."""
    path_file = SCENARIOS / "paper_planar_2x3.yaml"
    S = scene(path_file)
    model = load_scenario(path_file)
    arm, n = model.arms[0], model.arms[0].n
    ways = np.array([[1.4, 5.0, 5.6], [1.9, 4.6, 5.2], [1.2, 5.3, 5.9]])
    spline = toppra.SplineInterpolator(np.linspace(0, 1, 3), ways, bc_type="clamped")
    full = np.zeros(S.n)
    data = S.open.createData()

    def rnea(q, v, a):
        x, y, z = full.copy(), full.copy(), full.copy()
        x[:n], y[:n], z[:n] = q, v, a
        return pin.rnea(S.open, data, x, y, z)[:n]

    stall = model.motors.stall_torque[:n]
    constraint = {s: toppra.constraint.JointTorqueConstraint(rnea, np.stack([-stall, stall], 1), np.zeros(n),
                                                             discretization_scheme=s)
                  for s in (INTERPOLATION, COLLOCATION)}

    def coopsim_time(N):
        s = np.linspace(0, 1, N + 1)
        q, d1, d2 = spline(s), spline(s, 1), spline(s, 2)
        tau = np.zeros((3, N + 1, n))
        for i in range(N + 1):
            pose = arm_pose(arm, q[i])
            I0, h0, _ = arm_dynamics(arm, pose, np.zeros(n), model.gravity)
            _, h1, _ = arm_dynamics(arm, pose, d1[i], model.gravity)
            tau[:, i] = h0, I0 @ d1[i], I0 @ d2[i] + h1 - h0
        z = np.zeros((N + 1, 3))
        points = PathPoints(s, np.zeros(N + 1, int), z, np.zeros((N + 1, 3, 3)), z, z, np.zeros(3))
        dyn = rt.PathDynamics(JointPath(points, q, d1, d2), "open", "payload", np.stack([tau, np.zeros_like(tau)]),
                              None, None, None, stall, np.zeros(n), np.ones(n, bool), 0.0)
        greedy, lp = rt.retime(dyn, 0.0, "reachability"), rt.retime(dyn, 0.0, "grid_lp")
        for r in (greedy, lp):
            assert rt.check_time_law(dyn, r)["max_excess"] <= 1e-12
        # the interpolation scheme's greedy forward pass is not always the fastest feasible law: the
        # grid LP (largest Σ ṡ²) finds a faster one here, within the same exactly checked lines
        assert lp.duration <= greedy.duration * (1 + 1e-12)
        return greedy.duration

    mine = {N: coopsim_time(N) for N in (30, 60)}
    grid = {N: np.linspace(0, 1, N + 1) for N in (30, 60)}
    assert _toppra_time(constraint[INTERPOLATION], spline, grid[30]) == pytest.approx(mine[30], rel=1e-6)
    gap = [abs(_toppra_time(constraint[COLLOCATION], spline, grid[N]) - mine[N]) for N in (30, 60)]
    assert gap[1] < gap[0]
