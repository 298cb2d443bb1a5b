"""The active-set QP: KKT conditions on random problems, agreement with an independent solver, errors."""

import numpy as np
import pytest
from scipy.optimize import minimize

from coopsim.qp import QPError, solve_qp


def _random_qp(rng, n=6, p=8, q=2, m=10):
    R = rng.normal(size=(p, n))
    d = rng.normal(size=p)
    E = rng.normal(size=(q, n))
    x_feas = rng.normal(size=n)
    e = E @ x_feas
    C = rng.normal(size=(m, n))
    c = C @ x_feas
    lo, hi = c - rng.uniform(0.0, 0.5, m), c + rng.uniform(0.0, 0.5, m)
    lo[::3] = -np.inf
    return R, d, E, e, C, lo, hi, x_feas


@pytest.mark.parametrize("seed", range(8))
def test_solution_satisfies_kkt_and_matches_slsqp(seed):
    """Feasible to 1e-10, no point of SLSQP's (from the same start) is cheaper by more than 1e-9, and
    stationarity holds with non-negative multipliers (checked by NNLS on the active gradients)."""
    from scipy.optimize import nnls

    rng = np.random.default_rng(seed)
    R, d, E, e, C, lo, hi, x0 = _random_qp(rng)
    res = solve_qp(R, d, E, e, C, lo, hi, x0=x0)
    x = res.x
    assert np.max(np.abs(E @ x - e)) <= 1e-10
    assert np.all(C @ x >= lo - 1e-10) and np.all(C @ x <= hi + 1e-10)
    cost = 0.5 * np.sum((R @ x - d) ** 2)
    fin_lo, fin_hi = np.isfinite(lo), np.isfinite(hi)
    cons = [{"type": "eq", "fun": lambda z: E @ z - e},
            {"type": "ineq", "fun": lambda z: (C @ z - lo)[fin_lo]},
            {"type": "ineq", "fun": lambda z: (hi - C @ z)[fin_hi]}]
    ref = minimize(lambda z: 0.5 * np.sum((R @ z - d) ** 2), x0, jac=lambda z: R.T @ (R @ z - d),
                   constraints=cons, method="SLSQP", options={"ftol": 1e-15, "maxiter": 1000})
    assert cost <= ref.fun + 1e-9
    # stationarity: −∇q = Eᵀν + Σ_active λ_i g_i, λ >= 0 (ν free: split into ±)
    grad = R.T @ (R @ x - d)
    act_hi = np.flatnonzero(np.abs(C @ x - hi) <= 1e-9)
    act_lo = np.flatnonzero(np.abs(C @ x - lo) <= 1e-9)
    G = np.vstack([C[act_hi], -C[act_lo], E, -E]).T
    lam, resid = nnls(G, -grad)
    assert resid <= 1e-8 * max(1.0, np.linalg.norm(grad))


def test_start_point_found_by_lp_and_infeasible_problem_reported():
    rng = np.random.default_rng(11)
    R, d, E, e, C, lo, hi, x0 = _random_qp(rng)
    a = solve_qp(R, d, E, e, C, lo, hi)
    b = solve_qp(R, d, E, e, C, lo, hi, x0=x0)
    assert np.max(np.abs(a.x - b.x)) <= 1e-9
    with pytest.raises(QPError, match="no point satisfies"):
        solve_qp(R, d, E, e, np.vstack([C[0], C[0]]), np.array([1.0, -np.inf]), np.array([np.inf, 0.0]))


def test_singular_hessian_gives_a_minimiser():
    """R with a null space: the cost is flat along it; the solver still returns a feasible minimiser
    (cost equal to the unconstrained least-squares optimum when the bounds are loose)."""
    rng = np.random.default_rng(5)
    R = rng.normal(size=(3, 6))
    d = rng.normal(size=3)
    E = np.zeros((0, 6))
    C = np.eye(6)
    res = solve_qp(R, d, E, np.zeros(0), C, -100 * np.ones(6), 100 * np.ones(6), x0=np.zeros(6))
    assert 0.5 * np.sum((R @ res.x - d) ** 2) <= 1e-20
