"""The LP bound's free path (grasp wrenches free at every path point, `LPFreePathProblem`) on the paper carry
with one via point: its capacity against the paper W⁺ free path's, the straight path's and the best of a
brute-force grid over the via point, each grid path's capacity one LP of scipy's linprog on the grasp wrenches
(not the NLP's null-space rows); the NLP's rows against `lp_capacity`; its Jacobian against central
differences."""

from dataclasses import replace
from itertools import product

import numpy as np
import pytest
from scipy.optimize import linprog

from coopsim.core.model import torque_limits
from coopsim.inverse.capacity import mass_line
from coopsim.inverse.free_path import LPFreePathProblem, lp_resolution, optimize_path
from inverse_cases import model

CARRY = "paper_planar_2x3_carry"


def _one_via_point():
    """The paper carry with one interior control point (one via point), a 0.5 s grid, one start."""
    m = model(CARRY)
    opt = replace(m.inverse.optimize, control_points=1, sample_dt=0.5, starts=1)
    return replace(m, inverse=replace(m.inverse, optimize=opt))


@pytest.fixture(scope="module")
def carry():
    m = _one_via_point()
    return m, LPFreePathProblem(m, lp_resolution(m), "payload"), optimize_path(m, "lp", retime=False)


def _linprog_capacity(m, prob) -> float:
    """kg, the LP bound of one trajectory as one linprog: max μ with the grasp wrenches f_i of every sample free,
    A f_i − μ y₁ = y₀ and τ_min <= τ_arms + Jᵀ f_i <= τ_max (every joint is active on the paper carry)."""
    y0, y1 = mass_line(prob, "payload")
    lo, hi = torque_limits(m.motors, prob.qd)
    N, n, rk = prob.JT.shape
    k = prob.A.shape[1]
    v = N * rk + 1
    A_ub, b_ub = np.zeros((2 * N * n, v)), np.zeros(2 * N * n)
    A_eq, b_eq = np.zeros((N * k, v)), np.zeros(N * k)
    for i in range(N):
        cols = slice(i * rk, (i + 1) * rk)
        A_ub[i * n:(i + 1) * n, cols] = prob.JT[i]
        b_ub[i * n:(i + 1) * n] = hi[i] - prob.tau_arms[i]
        A_ub[(N + i) * n:(N + i + 1) * n, cols] = -prob.JT[i]
        b_ub[(N + i) * n:(N + i + 1) * n] = prob.tau_arms[i] - lo[i]
        A_eq[i * k:(i + 1) * k, cols] = prob.A[i]
        A_eq[i * k:(i + 1) * k, -1] = -y1[i]
        b_eq[i * k:(i + 1) * k] = y0[i]
    c = np.zeros(v)
    c[-1] = -1.0
    r = linprog(c, A_ub, b_ub, A_eq, b_eq, bounds=[(None, None)] * (v - 1) + [(0, None)], method="highs")
    assert r.status == 0, r.message
    return float(r.x[-1])


def test_the_lp_free_path_carries_more_than_the_paper_and_the_straight_path(carry):
    """The LP free path (the best distribution) carries more than the paper W⁺ free path (a distribution among
    the LP's) and than the straight path, whose capacity is the one-linprog bound to 1e-7 relative (HiGHS'
    tolerances); the optimiser converged (its stall criterion)."""
    m, problem, opt = carry
    paper = optimize_path(m, "paper", retime=False)
    assert opt.best.success and opt.best.status == 0
    assert opt.capacity.mass > paper.capacity.mass
    assert opt.capacity.mass > opt.straight.mass
    assert opt.straight.mass == pytest.approx(_linprog_capacity(m, problem.evaluate(np.zeros(3)).prob), rel=1e-7)


def test_the_lp_free_path_is_at_least_the_best_of_a_brute_force_grid(carry):
    """Over the via point's in-plane offset (±2 cm) and turn (±0.05 rad), a 5 × 5 × 3 grid of LP-bound capacities
    (one linprog per path): the optimum carries at least the grid's best, to 1e-7 relative (HiGHS' tolerances),
    and its own capacity is the one-linprog bound of its path."""
    m, problem, opt = carry
    grid = [np.array([x / problem.scale[0], y / problem.scale[1], w])
            for x, y, w in product(np.linspace(-0.02, 0.02, 5), np.linspace(-0.02, 0.02, 5), (-0.05, 0.0, 0.05))]
    masses = [_linprog_capacity(m, e.prob) for e in map(problem.evaluate, grid) if e is not None]
    assert len(masses) == len(grid)
    assert opt.capacity.mass >= max(masses) * (1 - 1e-7)
    x = problem.path_of(np.zeros(3))                                      # the optimum's offsets from its path
    d = (opt.motion.path.positions - x.positions)[0, :2] / problem.scale[:2]
    x_opt = np.array([d[0], d[1], (opt.motion.path.rotation_vectors - x.rotation_vectors)[0, 2]])
    assert opt.capacity.mass == pytest.approx(_linprog_capacity(m, problem.evaluate(x_opt).prob), rel=1e-7)


def test_the_rows_lp_is_the_lp_bound_at_every_sample(carry):
    """The NLP's rows (f = A⁺ȳ + N z, z free) maximised per sample give `lp_capacity`'s per-sample maxima (to
    1e-9 relative: the same LP in other unknowns), at a path off the straight one."""
    m, problem, _ = carry
    e = problem.evaluate(np.array([0.004, -0.006, 0.03]))
    lp = problem._row_lps(e, None)
    upper = np.select([lp.status == 0, lp.status == 3], [lp.x[:, -1], np.inf], -np.inf)
    ref = problem.capacity(np.array([0.004, -0.006, 0.03])).per_sample
    assert np.array_equal(np.isinf(upper), np.isinf(ref))
    fin = np.isfinite(ref)
    assert upper[fin] == pytest.approx(ref[fin], rel=1e-9)


def test_lp_constraint_jacobian_matches_central_differences(carry):
    """The Jacobian in the path unknowns (forward differences, z held) against central differences (step 1e-5),
    and the exact z and μ columns against differences of the rows (linear in z and μ: to 1e-9 of the largest)."""
    _, problem, _ = carry
    x, mu, h = np.array([0.004, -0.006, 0.03]), 500.0, 1e-5
    z = problem.extra_start(x, mu) + 0.1 * np.random.default_rng(0).normal(size=problem.extra_size)
    J = problem.jacobian(x, mu, z)
    assert J.shape == (len(problem.constraints(x, mu, z)), 3 + problem.extra_size + 1)
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        central = (problem.constraints(x + e, mu, z) - problem.constraints(x - e, mu, z)) / (2 * h)
        assert J[:, i] == pytest.approx(central, abs=1e-5 * np.max(np.abs(central)))
    for j in list(range(0, problem.extra_size, 7)) + [problem.extra_size - 1]:
        dz = np.zeros(problem.extra_size)
        dz[j] = 1.0
        diff = (problem.constraints(x, mu, z + dz) - problem.constraints(x, mu, z - dz)) / 2.0
        assert J[:, 3 + j] == pytest.approx(diff, abs=1e-9 * np.max(np.abs(diff)))
    dmu = (problem.constraints(x, mu + 1.0, z) - problem.constraints(x, mu - 1.0, z)) / 2.0
    assert J[:, -1] == pytest.approx(dmu, abs=1e-12)


def test_the_start_wrenches_carry_the_start_capacity(carry):
    """`extra_start` at the straight path and its capacity: every row holds (>= −1e-9 of τ_s), so SLSQP starts
    feasible."""
    _, problem, _ = carry
    x = np.zeros(3)
    mu = problem.capacity(x).mass
    assert np.min(problem.constraints(x, mu, problem.extra_start(x, mu))) >= -1e-9


def test_under_a_retimed_law_the_rows_lp_is_the_retimed_payload(carry):
    """A bent path retimed for the LP bound on 4 intervals (`retimed_capacity`, `max_payload` of the 'lp' path
    dynamics: its own LP formulation on f, checked also between the grid points): the law held fixed, each grid
    point on both sides with its own z (2 × 5 row-times), the rows' LP capacity is never below that payload and
    here equal to it (measured 5·10⁻¹⁶ relative; allowed 1e-7, the bisection's and HiGHS' tolerances); the
    Jacobian's z columns there are exact (rows linear in z)."""
    from coopsim.inverse.free_path import retimed_capacity

    m, problem, _ = carry
    x = np.array([0.004, -0.006, 0.03])
    mass, r = retimed_capacity(m, problem.motion_of(x), problem.res, "payload", 13.0, 4)
    held = problem.variant(law=r.law)
    assert held.extra_size == 2 * 5 * 3
    got = held.capacity(x).mass
    assert got >= mass * (1 - 1e-9)
    assert got == pytest.approx(mass, rel=1e-7)
    z = held.extra_start(x, mass)
    assert np.min(held.constraints(x, mass, z)) >= -1e-9
    J = held.jacobian(x, mass, z)
    for j in (0, held.extra_size - 1):
        dz = np.zeros(held.extra_size)
        dz[j] = 1.0
        diff = (held.constraints(x, mass, z + dz) - held.constraints(x, mass, z - dz)) / 2.0
        assert J[:, 3 + j] == pytest.approx(diff, abs=1e-9 * np.max(np.abs(diff)))


def test_the_other_row_times_rows_are_their_lp_capacities(carry):
    """After `extra_start` z is carried on the row-times near the least capacity only: each other row-time's row is
    (c_i − μ)/kg with c_i the `lp_capacity` per-sample maximum (the LP on the grasp wrenches, not the NLP's rows:
    to 1e-9 relative, HiGHS' tolerances), and its Jacobian in the path (the LP's Lagrangian, envelope theorem) is
    the central difference (step 1e-5) of those maxima to 1e-4 of the largest (the differences' O(h²) and the
    forward step's O(1e-7)); the free row-times' rows left out have slack above ROW_BAND at the start."""
    from coopsim.inverse.free_path import LP_ROW_CLIP, ROW_BAND

    _, problem, _ = carry
    x, h = np.array([0.004, -0.006, 0.03]), 1e-5
    c = problem.capacity(x).per_sample
    mu = 0.9 * float(np.min(c))
    z = problem.extra_start(x, mu)
    free, rest = problem._split(len(c))
    assert 0 < len(free) < len(c) and len(rest)
    m = problem.evaluate(x).C.shape[1]
    kept = int(np.sum(problem.kept))
    rows = problem.constraints(x, mu, z)[kept:kept + len(rest)]
    fin = np.isfinite(c[rest])                                         # unbounded (at rest): the constant LP_ROW_CLIP
    assert np.all(rows[~fin] == LP_ROW_CLIP) and np.all(c[rest][~fin] == np.inf) and np.sum(fin) > 0
    assert rows[fin] * problem.kg == pytest.approx(c[rest][fin] - mu, rel=1e-9)
    J = problem.jacobian(x, mu, z)[kept:kept + len(rest), :3]
    assert np.all(J[~fin] == 0.0)
    for i in range(3):
        e = np.zeros(3)
        e[i] = h
        central = (problem.capacity(x + e).per_sample[rest][fin] - problem.capacity(x - e).per_sample[rest][fin]) / (2 * h)
        assert J[fin, i] * problem.kg == pytest.approx(central, abs=1e-4 * np.max(np.abs(central)))
    T, U, B, _ = problem._rows(problem.evaluate(x))
    G = problem._G(problem.evaluate(x))[free]
    Gz = np.einsum("njz,nz->nj", G, z.reshape(len(free), -1))
    slack = np.concatenate([T.reshape(-1, m)[free] - mu * B.reshape(-1, m)[free] - Gz,
                            U.reshape(-1, m)[free] + mu * B.reshape(-1, m)[free] + Gz], 1)
    assert np.all(slack[~problem.kept] > ROW_BAND) and np.min(slack[problem.kept]) >= -1e-9
