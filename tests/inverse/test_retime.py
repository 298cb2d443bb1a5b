"""Fixed path, free timing (`coopsim.inverse.path`, `coopsim.inverse.retime`) on the paper carry, against
references that cannot share the retiming's mistakes: finite differences of the joint path, the inverse
dynamics rerun from scratch on a model carrying the mass, the forward dynamics replaying the torques, a
brute-force sweep of the scenario's own time law over its duration, and two solvers of the discrete
problem written independently (vertex enumeration against HiGHS)."""

from dataclasses import replace

import numpy as np
import pytest

from coopsim.core.model import torque_limits
from coopsim.inverse import capacity as cap
from coopsim.inverse import retime as rt
from coopsim.inverse.path import WaypointPath, joint_path, path_grid
from coopsim.inverse.problem import inverse_problem
from coopsim.inverse.replay import replay
from coopsim.inverse.solve import resolution_for, resolve
from coopsim.inverse.trajectory import object_motion_samples, object_motion_trajectory
from coopsim.io.scenario import load_scenario
from coopsim.report.inverse_report import capacity_study
from coopsim.report.optimize_report import fine_check
from helpers import SCENARIOS

INTERVALS = 20


@pytest.fixture(scope="module")
def carry():
    model = load_scenario(SCENARIOS / "paper_planar_2x3_carry.yaml")
    path = WaypointPath.of(model.inverse.object_motion)
    s, piece = path_grid(path.knots, INTERVALS)
    return model, path, joint_path(model, path, s, piece, model.inverse.object_motion.initial_guess)


def test_the_joint_path_derivatives_are_those_of_finite_differences(carry):
    """θ′ and θ″ at interior points against central differences of θ and θ′ (h = 1e-6: truncation ~1e-12,
    rounding ~1e-10 relative to θ ~ 1 rad), within 1e-8."""
    model, path, jp = carry
    h = 1e-6
    for i in (5, 30, 50):
        s, k = jp.s[i:i + 1], jp.points.piece[i:i + 1]
        plus, minus = (joint_path(model, path, s + d, k, jp.q[i]) for d in (h, -h))
        assert np.max(np.abs((plus.q - minus.q)[0] / (2 * h) - jp.d1[i])) < 1e-8
        assert np.max(np.abs((plus.d1 - minus.d1)[0] / (2 * h) - jp.d2[i])) < 1e-8


@pytest.mark.parametrize("method", ["paper", "nonsqueezing", "min_energy"])
def test_torques_are_affine_in_a_b_and_mass_as_the_inverse_dynamics_rerun(carry, method):
    """τ(a, b, μ) of path_dynamics equals the inverse dynamics rerun from scratch on a model carrying the
    payload μ at the joint motion θ̇ = θ′√b, θ̈ = θ′a + θ″b (random a, b, μ), to 1e-10 relative."""
    model, _, jp = carry
    dyn = rt.path_dynamics(model, jp, method, "payload")
    rng = np.random.default_rng(4)
    for _ in range(2):
        a, b, mu = rng.normal(0, 0.05, len(jp.s)), rng.uniform(0, 0.04, len(jp.s)), rng.uniform(1, 50)
        heavy = cap.payload_model(model, model.inverse.payload_position, mu)
        ref = resolve(inverse_problem(heavy, jp.states(a, b)), resolution_for(model, method)).tau
        assert np.max(np.abs(dyn.torques(mu, a, b) - ref)) <= 1e-10 * np.max(np.abs(ref))


def test_reachability_and_the_grid_lp_find_the_same_law(carry):
    """The two solvers of the discrete problem (TOPP-RA by vertex enumeration, or for the LP bound by small
    LPs over each stage's (a, b, grasp wrenches) with the compiled dual simplex; one HiGHS LP over the grid)
    agree on the minimum time to 1e-9 and on ṡ² to 1e-7 of its peak, for each linear resolution and the LP
    bound."""
    model, _, jp = carry
    for method in ("paper", "min_energy", "lp"):
        dyn = rt.path_dynamics(model, jp, method, "payload")
        r1, r2 = rt.retime(dyn, 20.0, "reachability"), rt.retime(dyn, 20.0, "grid_lp")
        assert r1.converged and r2.converged
        assert r1.duration == pytest.approx(r2.duration, rel=1e-9)
        assert np.max(np.abs(r1.law.b - r2.law.b)) <= 1e-7 * np.max(r1.law.b)


@pytest.mark.parametrize("method", ["paper", "min_energy", "lp"])
def test_the_heaviest_load_meets_eq_36_exactly_and_a_motor_sits_on_its_line(carry, method):
    """At the heaviest payload within the scenario's 13 s: within 1e-9 of T_max; every torque within its
    line (θ̇ = θ′√b exactly, both sides of every grid point) to 1e-9 of τ_s; the critical point has a
    motor on its line (optimality evidence; it is named) and the grid LP's dual certificate closes (its
    duals of the right sign, dual objective = primal; at the law the default solver found, the grid LP's
    optimum is that law); heavier than the scenario's own quintic law."""
    model, _, jp = carry
    dyn = rt.path_dynamics(model, jp, method, "payload")
    mass, r, _ = rt.max_payload(dyn, 13.0)
    assert r.duration <= 13.0 and r.duration == pytest.approx(13.0, rel=1e-8)
    assert rt.check_time_law(dyn, r)["max_excess"] <= 1e-9
    assert r.refine["within"]                 # and at the 10× finer grid's points (`JointPath.refined`)
    sat = rt.saturating(dyn, r)
    assert sat["excess"][sat["critical"]["index"]] >= -1e-7
    cert = rt.certificate(dyn, r)           # the grid LP's duals: of the right sign, the dual objective = the primal
    assert cert["sign_ok"] and cert["gap"] <= 1e-9 * abs(cert["primal"]) and cert["binding_rows"] > 0
    assert cert["law_gap"] <= 1e-7          # the law (reachability for the resolutions) is the grid LP's optimum
    quintic = capacity_study(model, optimise=False)
    before = quintic.lp["payload"] if method == "lp" else quintic.caps[method, "payload"]
    assert mass > before.mass
    # a little heavier is slower than T_max (the bound is tight)
    assert rt.retime(dyn, mass * (1 + 1e-6)).duration > 13.0


def test_the_optimum_beats_every_duration_of_the_scenario_law(carry):
    """Brute force: the scenario's quintic law with every waypoint time scaled to total durations of 6 to
    13 s (capacity_study at each, the model's own trajectory code); none carries more within 13 s than
    the retimed path (min energy, payload)."""
    model, _, jp = carry
    dyn = rt.path_dynamics(model, jp, "min_energy", "payload")
    best, _, _ = rt.max_payload(dyn, 13.0)
    om = model.inverse.object_motion
    sweep = []
    for T in np.linspace(6.0, 13.0, 8):
        m2 = replace(model, inverse=replace(model.inverse, object_motion=replace(om, times=om.times * T / 13.0)))
        sweep.append(capacity_study(m2, optimise=False, with_lp=False).caps["min_energy", "payload"].mass)
    assert max(sweep) <= best
    assert sweep[-1] == max(sweep)           # the family's best is its longest duration


def test_the_retimed_scenario_replays_and_follows_the_joint_path(carry):
    """The optimum as a sampled time law: the trajectory code's joint motion at the law's grid times is the
    joint path's (θ to 1e-10 rad, θ̇ = θ′√b to 1e-9); the minimum-energy torques replayed open loop through
    the forward dynamics follow it within 1e-8 rad; the replayed torques stay within their lines up to the
    law's excess between grid points (reported by the study, here ≤ 1e-3 τ_s)."""
    model, _, jp = carry
    dyn = rt.path_dynamics(model, jp, "min_energy", "payload")
    mass, r, _ = rt.max_payload(dyn, 13.0)
    motion = rt.retimed_motion(model.inverse.object_motion, r.law, output_dt=0.02)
    m2 = replace(model, inverse=replace(model.inverse, object_motion=motion))
    on = np.flatnonzero(np.concatenate([[True], np.diff(r.law.t) > 0]))
    traj = object_motion_trajectory(m2, motion)
    t_grid = r.law.t[on]
    idx = np.flatnonzero(np.isin(np.round(traj.t, 9), np.round(t_grid, 9)))
    assert len(idx) >= 2
    for i in idx:
        g = on[int(np.argmin(np.abs(t_grid - traj.t[i])))]
        assert np.max(np.abs(traj.q[i] - jp.q[g])) < 1e-10
        assert np.max(np.abs(traj.qd[i] - jp.d1[g] * np.sqrt(r.law.b[g]))) < 1e-9
    heavy = cap.payload_model(m2, model.inverse.payload_position, mass)
    rep = replay(heavy, traj, resolution_for(heavy, "min_energy"))
    assert rep.max_angle_error <= 1e-8
    res = resolution_for(m2, "min_energy")
    prob = inverse_problem(m2, traj, model.inverse.payload_position)
    a, b = cap.affine_torques(prob, res, "payload")
    lo, hi = torque_limits(m2.motors, traj.qd)
    excess = np.max(np.maximum(a + mass * b - hi, lo - a - mass * b) / m2.motors.stall_torque)
    assert excess <= 1e-3


def test_between_grid_points_only_the_rest_intervals_exceed_their_lines(carry):
    """Without the check points' rows (refine=False), on a 10x finer grid between the grid points (10 and 20
    intervals a segment): the paper W⁺ law stays within its lines (1e-9 of τ_s); the minimum-energy law
    exceeds them by at most 1e-3 τ_s, and only in an interval touching a waypoint, where ṡ = √b rises from 0
    faster than linearly (√b is concave in s; the grid bounds the velocity term at the interval's ends only)."""
    model, path, _ = carry
    for n in (10, 20):
        s, piece = path_grid(path.knots, n)
        g = joint_path(model, path, s, piece, model.inverse.object_motion.initial_guess)
        fs, fp = path_grid(path.knots, 10 * n)
        fg = joint_path(model, path, fs, fp, model.inverse.object_motion.initial_guess)
        for method, bound in (("paper", 1e-9), ("min_energy", 1e-3)):
            _, r, _ = rt.max_payload(rt.path_dynamics(model, g, method, "payload"), 13.0, refine=False)
            assert r.refine is None
            fc = fine_check(rt.path_dynamics(model, fg, method, "payload"), r)
            assert fc["max_excess"] <= bound
            if fc["max_excess"] > 1e-9:
                assert np.min(np.abs(fc["s"] - path.knots)) <= 1.0 / (len(path.knots) - 1) / n


def test_a_search_started_from_a_carried_mass_finds_the_same_heaviest_load(carry):
    """The grid rows' heaviest load (refine=False) searched from the refined law's heaviest (at_least, a mass
    those rows carry too: they are a subset): the same mass as the search from the nominal load within the
    searches' tolerance (1e-10 relative each, so 3e-10 allowed), in fewer solves; a mass not carried within
    the duration as at_least is ignored (the search from the nominal load)."""
    model, path, jp = carry
    fine = joint_path(model, path, *path_grid(path.knots, 10 * INTERVALS), model.inverse.object_motion.initial_guess)
    dyn = rt.path_dynamics(model, jp, "min_energy", "payload", fine=rt.path_dynamics(model, fine, "min_energy",
                                                                                      "payload"))
    refined = rt.max_payload(dyn, 13.0)[0]
    plain, _, n_plain = rt.max_payload(dyn, 13.0, refine=False)
    near, r, n_near = rt.max_payload(dyn, 13.0, refine=False, at_least=refined)
    assert refined < plain and r.duration <= 13.0
    assert near == pytest.approx(plain, rel=3e-10) and n_near < n_plain
    assert rt.max_payload(dyn, 13.0, refine=False, at_least=2 * plain)[0] == pytest.approx(plain, rel=3e-10)


REFINED = {"paper": 38.0, "nonsqueezing": 38.0, "min_energy": 190.0, "lp": 300.0}   # kg, near each heaviest load


@pytest.fixture(scope="module")
def short(carry):
    """The paper carry on 8 intervals a segment and on the 10× finer grid (its joint paths)."""
    model, path, _ = carry
    guess = model.inverse.object_motion.initial_guess
    grids = [path_grid(path.knots, n) for n in (8, 80)]
    return [(s, piece, joint_path(model, path, s, piece, guess)) for s, piece in grids]


@pytest.mark.parametrize("method", list(REFINED))
def test_with_the_check_points_rows_the_law_meets_eq_36_between_the_grid_points(carry, short, method):
    """8 intervals a segment, a payload near each one's heaviest within 13 s: without the rows of the check
    points the minimum-time law exceeds its lines between the grid points (min energy, LP bound: by more than
    1e-7 τ_s, `fine_check`); with them (`retime`'s default; both solvers for the linear resolutions) at every
    point of the 10× finer grid the torques recomputed from scratch — the inverse dynamics rerun on a model
    carrying the payload at θ̇ = θ′√b, θ̈ = θ′a + θ″b with the law's a and b there (b linear, a constant on
    the interval), the LP bound's best distribution by one linprog per point on that rerun's grasp matrix —
    are within their lines to 1e-9 τ_s, and the minimum time is no shorter (the rows only remove laws).
    Both solvers (the LP bound's reachability: the check points' wrenches free per point in its stage LPs)."""
    model, _, _ = carry
    (_, _, g), (fs, fp, fine) = short
    dyn = rt.path_dynamics(model, g, method, "payload", fine=fine)       # its check points: the finer grid's
    mass = REFINED[method]
    coarse = rt.retime(dyn, mass, refine=False)
    ex0 = fine_check(rt.path_dynamics(model, fine, method, "payload"), coarse)["max_excess"]
    assert ex0 > (1e-7 if method in ("min_energy", "lp") else -1.0)
    heavy = cap.payload_model(model, model.inverse.payload_position, mass)
    ts, active = model.motors.stall_torque, ~model.motors.passive.astype(bool)
    for solver in ("grid_lp", "reachability"):
        r = rt.retime(dyn, mass, solver)
        assert r.refine["within"] and (r.refine["rows"].size > 0) == (ex0 > rt.REFINE_TOL)
        assert r.duration >= coarse.duration * (1 - 1e-12)
        a, b = r.law.at(fs, fp)
        prob = inverse_problem(heavy, fine.states(a, b))
        lo, hi = torque_limits(model.motors, fine.d1 * np.sqrt(b)[:, None])
        if method == "lp":
            excess = max(_best_distribution_excess(prob, lo[i], hi[i], ts, active, i) for i in range(len(fs)))
        else:
            tau = resolve(prob, resolution_for(model, method)).tau
            excess = float(np.max(np.maximum(tau - hi, lo - tau) / ts))
        assert excess <= 1e-9


def _best_distribution_excess(prob, lo, hi, ts, active, i):
    """min over the grasp wrenches f (A f = y, passive torques 0) of max_j excess_j/τ_s at sample i: linprog."""
    from scipy.optimize import linprog

    JT, A, y, ta = prob.JT[i], prob.A[i], prob.y[i], prob.tau_arms[i]
    rk = JT.shape[1]
    col = -ts[active][:, None]
    A_ub = np.vstack([np.hstack([JT[active], col]), np.hstack([-JT[active], col])])
    b_ub = np.concatenate([hi[active] - ta[active], ta[active] - lo[active]])
    A_eq = np.vstack([np.hstack([A, np.zeros((A.shape[0], 1))]), np.hstack([JT[~active], np.zeros(((~active).sum(), 1))])])
    b_eq = np.concatenate([y, -ta[~active]])
    c = np.zeros(rk + 1)
    c[-1] = 1.0
    res = linprog(c, A_ub=A_ub, b_ub=b_ub, A_eq=A_eq, b_eq=b_eq, bounds=[(None, None)] * (rk + 1), method="highs")
    assert res.status == 0
    return float(res.x[-1])


def test_the_lp_bound_heaviest_payload_by_reachability_is_the_grid_lp(carry, short):
    """8 intervals a segment with the check points of the 10× finer grid: the LP bound's bare-object minimum
    time and heaviest payload within 13 s by the reachability pass (its stage LPs compiled) and by the grid
    LP (HiGHS) agree to 1e-9 relative — the same discrete problem, whose largest ṡ² profile both reach up
    to their feasibility tolerances (1e-12 of a stage's row scale; HiGHS's 1e-7 on rows of O(10) N·m, on ṡ²
    of O(0.1)) and Brent's 1e-10 on the mass; measured ≤ 1e-14 — and each law meets its lines at every check
    point (refine['within'])."""
    model, _, _ = carry
    (_, _, g), (_, _, fine) = short
    dyn = rt.path_dynamics(model, g, "lp", "payload", fine=fine)
    bare = [rt.retime(dyn, 0.0, x) for x in ("reachability", "grid_lp")]
    assert bare[0].duration == pytest.approx(bare[1].duration, rel=1e-9)
    heavy = [rt.max_payload(dyn, 13.0, x) for x in ("reachability", "grid_lp")]
    assert heavy[0][0] == pytest.approx(heavy[1][0], rel=1e-9)
    assert all(h[1].refine["within"] and h[1].solver == x for h, x in zip(heavy, ("reachability", "grid_lp")))
    assert rt.default_solver(dyn) == "reachability"      # 2 + 3·(2 + 9) = 35 unknowns a stage at most


def test_motors_that_cannot_hold_the_object_and_a_too_short_duration_are_named(carry):
    """A stall torque below the static torque: one line naming motors.stall_torque and the motor; a bound
    below the bare object's minimum time: one line naming the duration's field."""
    model, _, jp = carry
    dyn = rt.path_dynamics(model, jp, "min_energy", "payload")
    with pytest.raises(rt.RetimeError, match=r"^--duration: no motion carries the bare object"):
        rt.max_payload(dyn, 1.0)
    weak = replace(dyn, tau=dyn.tau.copy())
    weak.tau[0, 0] += 10.0                     # a constant 10 N·m load on every motor at rest
    with pytest.raises(rt.RetimeError, match=r"^motors.stall_torque: joint \d cannot hold the bare object"):
        rt.max_payload(weak, 13.0)


def test_the_refined_joint_path_is_the_joint_path_of_the_finer_grid():
    """`JointPath.refined` (the check points' joint path) against `joint_path` run afresh on the finer grid,
    on the Panda ceiling carry (redundant arms: the self-motion of the redundancy ODE starts at the first
    point in both): θ and θ′ at the shared points to 1e-12 (rad, rad per unit s)."""
    model = load_scenario(SCENARIOS / "robots" / "panda_ceiling_carry.yaml")
    om = model.inverse.object_motion
    path = WaypointPath.of(om)
    args = (model.q0 if om.initial_guess is None else om.initial_guess, om.rest_posture,
            om.rest_gain * float(om.times[-1] - om.times[0]))
    s, piece = path_grid(path.knots, 3)
    fine = joint_path(model, path, s, piece, *args).refined(2)
    fs, fp = path_grid(path.knots, 6)
    ref = joint_path(model, path, fs, fp, *args)
    at = [int(np.flatnonzero(np.isclose(fs, x, rtol=0, atol=1e-12) & (fp == k))[0])
          for x, k in zip(fine.s, fine.points.piece)]
    assert len(at) == len(fine.s) == 3 * (len(path.knots) - 1)
    assert np.max(np.abs(ref.q[at] - fine.q)) <= 1e-12 and np.max(np.abs(ref.d1[at] - fine.d1)) <= 1e-12


@pytest.mark.skipif(not (SCENARIOS / "robots" / "panda_ceiling_carry.yaml").exists(), reason="no Panda scene")
def test_a_faster_retimed_law_keeps_the_redundant_arms_on_the_retimed_joint_path():
    """The Panda carry's bare minimum-time law (0.78 s, the motion's 3 s): the retimed motion's pull per unit
    path (rest_pull 'path', rest_gain scaled by 3 s over the law's duration) keeps the redundant arms on the
    joint path that was retimed (gain rest_gain × 3 s per unit s) at the law's grid times, to 1e-9 rad (two
    DOP853 runs at rtol 1e-12, one in s and one in t); with the scenario's rest_gain unscaled they leave it."""
    from coopsim.io.robots import robots_folder

    if robots_folder() is None:
        pytest.skip("example-robot-data is not installed")
    model = load_scenario(SCENARIOS / "robots" / "panda_ceiling_carry.yaml")
    mo = model.inverse.object_motion
    span = float(mo.times[-1] - mo.times[0])
    path = WaypointPath.of(mo)
    s, piece = path_grid(path.knots, 4)
    jp = joint_path(model, path, s, piece, mo.initial_guess, mo.rest_posture, mo.rest_gain * span)
    r = rt.retime(rt.path_dynamics(model, jp, "paper", "payload"), 0.0)
    motion = rt.retimed_motion(mo, r.law)
    assert motion.rest_pull == "path" and r.duration < 0.5 * span
    on = np.flatnonzero(np.concatenate([[True], np.diff(r.law.t) > 0]))

    def off_path(m):
        traj = object_motion_samples(model, m, m.times[0] + r.law.t[on])
        return float(np.max(np.abs(traj.q - jp.q[on])))

    assert off_path(motion) <= 1e-9
    assert off_path(replace(motion, rest_gain=mo.rest_gain)) > 1e-6
