"""The LP bound's grasp wrenches between its grid points (`coopsim.inverse.lp_replay`) on the paper carry's bare
object minimum-time law (6 intervals a segment), against references outside the module: the LP's own wrenches
at its grid points, the inverse problem's equations rerun from scratch at states between them, and each
state's least excess over the motor lines by scipy's linprog (the LP bound's definition, written afresh)."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import linprog

from coopsim.core.model import torque_limits
from coopsim.inverse import retime as rt
from coopsim.inverse.lp_replay import lp_distribution, lp_wrenches
from coopsim.inverse.path import WaypointPath, joint_path, path_grid
from coopsim.inverse.problem import inverse_problem, sample_problem
from coopsim.io.scenario import load_scenario
from helpers import SCENARIOS


@pytest.fixture(scope="module")
def law():
    """The bare object's (payload 0 kg) minimum-time law of the LP bound, its rows at the grid points only, and
    the joint path at the grid points and at each interval's middle (in s)."""
    model = load_scenario(SCENARIOS / "paper_planar_2x3_carry.yaml")
    path = WaypointPath.of(model.inverse.object_motion)
    s, piece = path_grid(path.knots, 6)
    jp = joint_path(model, path, s, piece, model.inverse.object_motion.initial_guess)
    r = rt.retime(rt.path_dynamics(model, jp, rt.LP_BOUND, "payload", fine=None), 0.0)
    assert r.feasible and r.f is not None
    return model, jp, jp.refined(2), r


def _stages(r):
    return np.flatnonzero(r.law.piece[1:] == r.law.piece[:-1])


def _residual(prob, f, passive):
    """max |[A; Jᵀ_passive] f − [y; −τ_arms,passive]| over that right-hand side's peak."""
    A = np.concatenate([prob.A, prob.JT[:, passive, :]], 1)
    y = np.concatenate([prob.y, -prob.tau_arms[:, passive]], 1)
    return np.max(np.abs(np.einsum("nqi,ni->nq", A, f) - y)) / np.max(np.abs(y))


def _least_excess(prob, i, motors):
    """The least max relative excess over the lines of any f with A f = y at sample i (scipy linprog, HiGHS)."""
    lo, hi = torque_limits(motors, prob.qd[i])
    ts, JT, ta = motors.stall_torque, prob.JT[i], prob.tau_arms[i]
    rk = JT.shape[1]
    A_ub = np.vstack([np.hstack([JT, -ts[:, None]]), np.hstack([-JT, -ts[:, None]])])
    b_ub = np.concatenate([hi - ta, ta - lo])
    A_eq = np.hstack([prob.A[i], np.zeros((prob.A.shape[1], 1))])
    c = np.zeros(rk + 1)
    c[-1] = 1.0
    out = linprog(c, A_ub=A_ub, b_ub=b_ub, A_eq=A_eq, b_eq=prob.y[i], bounds=[(None, None)] * (rk + 1))
    assert out.status == 0
    return out.x[-1]


def test_at_the_grid_points_the_wrenches_are_the_lps(law):
    """At every interval's start (its own s̈, as the sampled law takes it) the wrenches are the LP's to 1e-12 of
    their peak, none corrected and within the lines to REFINE_TOL (the retiming's own check); the object wrench
    equation rerun from scratch holds to 1e-12 relative."""
    model, jp, _, r = law
    st = _stages(r)
    prob = sample_problem(inverse_problem(model, jp.states(r.law.a, r.law.b)), st)
    d = lp_distribution(replace(prob, t=r.law.t[st]), lp_wrenches(r), model.motors, model.motors.passive)
    assert np.max(np.abs(d.f - r.f[:, 0])) <= 1e-12 * np.max(np.abs(r.f))
    assert not d.corrected.any() and np.max(d.excess) <= rt.REFINE_TOL
    assert _residual(prob, d.f, model.motors.passive) <= 1e-12


def test_between_the_grid_points_the_wrenches_meet_the_equations_and_the_least_excess(law):
    """At each interval's middle (s, b = the mean of its ends' ṡ², its s̈, t from the law) the object wrench
    equation holds to 1e-12; the interpolant leaves the lines (by 2.0e-2 τ_s: the LP fixes no wrench there) at
    every middle, while some distribution keeps them at each (linprog's least excess, ≤ −1.1e-3 τ_s), and the
    wrenches applied keep the lines widened by REFINE_TOL (the module's bound; 1e-13 for the QP's rounding)."""
    model, _, mid, r = law
    st = _stages(r)
    b = 0.5 * (r.law.b[st] + r.law.b[st + 1])
    t = r.law.t[st] + 2 * (mid.s - r.law.s[st]) / (np.sqrt(r.law.b[st]) + np.sqrt(b))
    prob = replace(inverse_problem(model, mid.states(r.law.a[st], b)), t=t)
    d = lp_distribution(prob, lp_wrenches(r), model.motors, model.motors.passive)
    assert _residual(prob, d.f, model.motors.passive) <= 1e-12
    assert np.max(d.interpolant_excess) > 1e-3 and d.corrected.sum() >= 1
    least = np.array([_least_excess(prob, i, model.motors) for i in range(len(t))])
    assert np.max(least) < 0 and np.max(d.excess) <= rt.REFINE_TOL + 1e-13
    assert np.all(d.excess[~d.corrected] == d.interpolant_excess[~d.corrected])

