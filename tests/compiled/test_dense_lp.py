"""The compiled small-LP solver and the LP bound's reachability pass (`coopsim.compiled.dense_lp`,
`coopsim.inverse.retime.lp_reachability`) against independent solvers: scipy's linprog (HiGHS) on random
LPs, and the grid LP (`coopsim.inverse.retime.grid_lp`, one HiGHS LP over the whole grid with the grasp
wrenches as explicit unknowns and the equalities as rows) on the paper carry.

Tolerances: the dual simplex ends at a vertex, its x solved by LU at the final basis, so its objective is
that of HiGHS's vertex to rounding: 1e-9 relative to max(1, |optimum|) (measured ≤ 1e-13; the random data
are O(1)). The reachability pass and the grid LP solve the same discrete problem; where the feasible
profiles have a pointwise largest one (the paper carry) both give it, up to the feasibility tolerances of
the two (the pass: 1e-12 of the stage's row scale; HiGHS: 1e-7 absolute on rows of O(10) N·m): ṡ² to
1e-9 of its peak (measured ≤ 2e-15)."""

import numpy as np
import pytest
from scipy.optimize import linprog

from coopsim.compiled import api
from coopsim.inverse import retime as rt
from coopsim.inverse.path import WaypointPath, joint_path, path_grid
from coopsim.io.scenario import load_scenario
from helpers import SCENARIOS

REL = 1e-9


def _random_lp(rng, kind):
    """(M, h, c, cap) of one random LP: 'bounded' (a point strictly inside), 'infeasible' (a row and its
    opposite apart), 'degenerate' (every row through one point, some twice), 'integer' (small integers,
    ties and repeated rows)."""
    n, m = int(rng.integers(2, 12)), int(rng.integers(1, 40))
    M, x0 = rng.normal(size=(m, n)), rng.normal(size=n)
    h = M @ x0 + rng.uniform(0.0, 1.0, m)
    c = rng.normal(size=n)
    if kind == "infeasible":
        M = np.vstack([M, M[:1], -M[:1]])
        h = np.concatenate([h, [h[0] - 5.0], [5.0 - h[0] - 1.0]])
    elif kind == "degenerate":
        M = np.vstack([M, 2.0 * M[:3]])
        h = M @ x0
        c[: n // 2] = 0.0
    elif kind == "integer":
        M, c = np.round(M), np.round(c)
        h = np.round(M @ np.round(x0)) + rng.integers(0, 2, m)
    return M, h, c, np.full(n, 10.0)


@pytest.mark.parametrize("kind", ["bounded", "infeasible", "degenerate", "integer"])
def test_the_dual_simplex_is_linprog_on_random_lps(kind):
    """60 random LPs of each kind (240 in all), max cᵀx subject to M x ≤ h and |x| ≤ 10: the same status
    as linprog; where optimal the same objective to 1e-9 and x within every row and the box to 1e-9."""
    rng = np.random.default_rng(["bounded", "infeasible", "degenerate", "integer"].index(kind))
    for _ in range(60):
        M, h, c, cap = _random_lp(rng, kind)
        status, x = api.dense_lp_solve(M, h, c, cap)
        ref = linprog(-c, A_ub=M, b_ub=h, bounds=[(-b, b) for b in cap], method="highs")
        assert ref.status in (0, 2)
        assert status == (0 if ref.status == 0 else 1)
        if kind == "infeasible":
            assert status == 1
        if status == 0:
            assert abs(c @ x + ref.fun) <= REL * max(1.0, abs(ref.fun))
            assert np.all(M @ x <= h + REL * (1.0 + np.abs(h))) and np.all(np.abs(x) <= cap * (1 + REL))


@pytest.fixture(scope="module")
def carry():
    model = load_scenario(SCENARIOS / "paper_planar_2x3_carry.yaml")
    path = WaypointPath.of(model.inverse.object_motion)
    s, piece = path_grid(path.knots, 8)
    jp = joint_path(model, path, s, piece, model.inverse.object_motion.initial_guess)
    return model, rt.path_dynamics(model, jp, rt.LP_BOUND, "payload")


@pytest.mark.parametrize("mass", [0.0, 150.0, 300.0])
def test_the_lp_bound_pass_is_the_grid_lp_with_and_without_check_points(carry, mass):
    """The rows linearised at the grid LP's minimum-time law, without and with the rows of every other
    check point (ragged stages): ṡ² equal to 1e-9 of its peak; the pass's grasp wrenches meet the object
    wrench equalities A f = y(a, b, μ) to 1e-9 of |y| and keep the law within its lines (`check_time_law`,
    eq. 36 exactly) to 1e-9 τ_s."""
    _, dyn = carry
    r = rt.retime(dyn, mass, "grid_lp", refine=False)
    b = r.law.b
    lam = rt._tangent(b, b.max())
    fp = dyn.fine_points()
    sub = fp.subset(np.arange(0, len(fp.sigma), 2))
    k = rt._stages(dyn.path.s, dyn.path.points.piece)[sub.stage]
    extra = (sub, rt._tangent((1 - sub.sigma) * b[k] + sub.sigma * b[k + 1], b.max()))
    for more in (None, extra):
        got, stats = rt.lp_reachability(dyn, mass, lam, more)
        ref, _ = rt.grid_lp(dyn, mass, lam, more)
        assert got is not None and ref is not None and "fallback" not in stats
        assert np.max(np.abs(got - ref)) <= REL * np.max(ref)
    law = rt.time_of(dyn.path.s, dyn.path.points.piece, got)
    st = rt._stages(law.s, law.piece)
    Y = dyn.y[0] + mass * dyn.y[1]
    for side, pt in ((0, st), (1, st + 1)):
        y = Y[0, pt] + law.a[st, None] * Y[1, pt] + law.b[pt, None] * Y[2, pt]
        assert np.max(np.abs(np.einsum("nkr,nr->nk", dyn.A[pt], stats["f"][:, side]) - y)) <= REL * np.max(np.abs(y))
    law_r = rt.Retiming(mass, law, True, True, 1, "reachability", stats["f"])
    assert rt.check_time_law(dyn, law_r)["max_excess"] <= 1e-9


def test_a_load_the_motors_cannot_carry_is_infeasible_in_both(carry):
    """A constant load of twice the stall torques on every motor that no grasp wrench can take: both None."""
    _, dyn = carry
    from dataclasses import replace

    weak = replace(dyn, tau=dyn.tau.copy(), fine_maker=None)
    weak.tau[0, 0] += 2.0 * dyn.stall * (1 + np.abs(dyn.JT).sum(axis=2)) * 1e3
    lam = (np.zeros(len(dyn.path.s)), np.zeros(len(dyn.path.s)))
    got, _ = rt.lp_reachability(weak, 0.0, lam)
    ref, _ = rt.grid_lp(weak, 0.0, lam)
    assert got is None and ref is None


def test_a_stage_lp_not_solved_leaves_the_solve_to_the_grid_lp(carry, monkeypatch):
    """The pass reporting a stage LP not solved (its step limit): the law is the grid LP's, and stats say why."""
    _, dyn = carry
    lam = (np.zeros(len(dyn.path.s)), np.zeros(len(dyn.path.s)))
    real = api.lp_reachability_pass
    monkeypatch.setattr(api, "lp_reachability_pass", lambda *a: (2,) + tuple(real(*a)[1:]))
    got, stats = rt.lp_reachability(dyn, 100.0, lam)
    ref, _ = rt.grid_lp(dyn, 100.0, lam)
    assert np.array_equal(got, ref) and "not solved" in stats["fallback"] and stats["status"] == 0
