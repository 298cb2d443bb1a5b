"""The QP solver (HiGHS, polished to the exact minimiser): KKT conditions and agreement with an
independent solver on random convex problems (semidefinite Hessians too), degenerate and
cycling-prone problems, failures reported per problem — up to `coopsim inverse`, which writes its
outputs and names the samples that have no solution."""

import json
import warnings
from dataclasses import replace

import numpy as np
import pytest
import yaml
from scipy.optimize import linprog, minimize, nnls

from coopsim.inverse.distributions import grasp_line_frames
from coopsim.inverse.problem import SampleFailureWarning, inverse_problem
from coopsim.inverse.solve import default_bounds, resolution_for, resolve
from coopsim.report.inverse_report import format_inverse_summary, inverse_study, inverse_summary
from coopsim.inverse import capacity as cap
from coopsim.inverse import qp
from coopsim.inverse.qp import QPError, solve_lps, solve_qp, solve_qps
from helpers import SCENARIOS, run_cli
from inverse_cases import BUNDLED, capacity_lps, problem, run


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


def _slsqp(R, d, E, e, C, lo, hi, x0):
    fin_lo, fin_hi = np.isfinite(lo), np.isfinite(hi)
    cons = [{"type": "ineq", "fun": lambda z: (C @ z - lo)[fin_lo]},
            {"type": "ineq", "fun": lambda z: (hi - C @ z)[fin_hi]}]
    if len(E):
        cons.append({"type": "eq", "fun": lambda z: E @ z - e})
    return minimize(lambda z: 0.5 * np.sum((R @ z - d) ** 2), x0, jac=lambda z: R.T @ (R @ z - d),
                    constraints=cons, method="SLSQP", options={"ftol": 1e-15, "maxiter": 1000})


def _check_kkt(res, R, d, E, e, C, lo, hi, tol=1e-10):
    """The returned point and multipliers certify optimality: feasible (tol, relative), equality rows
    to rounding (1e-14), stationarity Hx + g = Eᵀν + Cᵀλ (1e-9), λ >= 0 at lo, <= 0 at hi, 0 off the
    working set, every held row at its bound — and, independently of the returned multipliers, NNLS
    finds non-negative ones on the rows active at x."""
    x = res.x
    scale = max(1.0, np.max(np.abs(x)))
    assert np.max(np.abs(E @ x - e), initial=0.0) <= 1e-14 * scale * max(1.0, np.max(np.abs(E), initial=0.0))
    Cx = C @ x
    assert np.all(Cx >= lo - tol * scale) and np.all(Cx <= hi + tol * scale)
    grad = R.T @ (R @ x - d)
    gscale = max(1.0, np.max(np.abs(grad)))
    assert np.max(np.abs(grad - E.T @ res.eq_mult - C.T @ res.mult)) <= 1e-9 * gscale
    assert np.all(res.mult[res.active == -1] >= -1e-10 * gscale)
    assert np.all(res.mult[(res.active == 1) & (lo < hi)] <= 1e-10 * gscale)
    assert np.all(res.mult[res.active == 0] == 0.0)
    assert np.all(np.abs(Cx - hi)[res.active == 1] <= 1e-14 * scale * max(1.0, np.max(np.abs(C))))
    assert np.all(np.abs(Cx - lo)[res.active == -1] <= 1e-14 * scale * max(1.0, np.max(np.abs(C))))
    act_hi = np.flatnonzero(np.abs(Cx - hi) <= 1e-9 * scale)
    act_lo = np.flatnonzero(np.abs(Cx - lo) <= 1e-9 * scale)
    G = np.vstack([-C[act_hi], C[act_lo], E, -E]).T
    _, resid = nnls(G, grad)
    assert resid <= 1e-8 * gscale


@pytest.mark.parametrize("seed", range(8))
def test_solution_satisfies_kkt_and_matches_slsqp(seed):
    """Feasible, a KKT certificate, and no point of SLSQP's (from a feasible start) cheaper by 1e-9."""
    rng = np.random.default_rng(seed)
    R, d, E, e, C, lo, hi, x0 = _random_qp(rng)
    res = solve_qp(R, d, E, e, C, lo, hi)
    _check_kkt(res, R, d, E, e, C, lo, hi)
    ref = _slsqp(R, d, E, e, C, lo, hi, x0)
    assert 0.5 * np.sum((R @ res.x - d) ** 2) <= ref.fun + 1e-9


def test_semidefinite_hessians_in_a_batch_match_slsqp():
    """40 problems at once whose Hessians RᵀR are singular (R: 3 rows, 6 columns; some R with a zero
    column, a variable the objective does not see): every one verified by its KKT certificate and
    no cheaper than SLSQP's minimiser by more than 1e-9."""
    rng = np.random.default_rng(21)
    probs = []
    for i in range(40):
        R, d, E, e, C, lo, hi, x0 = _random_qp(rng, p=3)
        if i % 4 == 0:
            R[:, 2] = 0.0
        probs.append((R, d, E, e, C, lo, hi, x0))
    batch = solve_qps(*(np.array([p[k] for p in probs]) for k in range(7)))
    assert batch.ok.all() and batch.messages == ["optimal"] * 40
    for i, (R, d, E, e, C, lo, hi, x0) in enumerate(probs):
        _check_kkt(batch.result(i), R, d, E, e, C, lo, hi)
        assert 0.5 * np.sum((R @ batch.x[i] - d) ** 2) <= _slsqp(R, d, E, e, C, lo, hi, x0).fun + 1e-9


def test_singular_hessian_gives_a_minimiser():
    """R with a null space and loose bounds: the cost reaches the unconstrained least-squares optimum."""
    rng = np.random.default_rng(5)
    R = rng.normal(size=(3, 6))
    d = rng.normal(size=3)
    res = solve_qp(R, d, np.zeros((0, 6)), np.zeros(0), np.eye(6), -100 * np.ones(6), 100 * np.ones(6))
    assert 0.5 * np.sum((R @ res.x - d) ** 2) <= 1e-20


def test_degenerate_problems_duplicated_and_dependent_rows():
    """Degenerate vertices: every inequality row duplicated, a row that is the sum of two others (all
    three active), redundant equality rows, a row with lo = hi, and the same rows with their bounds
    swapped into a second one-sided copy: each solved, certified by KKT, equal to the plain problem's
    minimiser (1e-12)."""
    rng = np.random.default_rng(8)
    R, d, E, e, C, lo, hi, _ = _random_qp(rng)
    plain = solve_qp(R, d, E, e, C, lo, hi)
    Cx = C @ plain.x
    # tighten so that rows 0 and 1 are active at the plain minimiser, then add their sum, active too
    hi2, lo2 = hi.copy(), lo.copy()
    hi2[:2] = Cx[:2]
    base = solve_qp(R, d, E, e, C, lo2, hi2)
    Csum = np.vstack([C, C[0] + C[1]])
    lo_s, hi_s = np.append(lo2, -np.inf), np.append(hi2, hi2[0] + hi2[1])
    variants = {
        "duplicated rows": (E, e, np.vstack([C, C]), np.concatenate([lo2, lo2]), np.concatenate([hi2, hi2])),
        "dependent active row": (E, e, Csum, lo_s, hi_s),
        "redundant equalities": (np.vstack([E, E, E[0] + 2 * E[1]]), np.concatenate([e, e, [e[0] + 2 * e[1]]]),
                                 C, lo2, hi2),
        "lo = hi row": (E[:1], e[:1], np.vstack([C, E[1:]]), np.append(lo2, e[1]), np.append(hi2, e[1])),
        "one-sided copies": (E, e, np.vstack([C, -C]), np.concatenate([lo2, -hi2]), np.concatenate([hi2, -lo2])),
    }
    for name, (E_, e_, C_, lo_, hi_) in variants.items():
        res = solve_qp(R, d, E_, e_, C_, lo_, hi_)
        _check_kkt(res, R, d, E_, e_, C_, lo_, hi_)
        assert np.max(np.abs(res.x - base.x)) <= 1e-12 * max(1.0, np.max(np.abs(base.x))), name


def test_cycling_prone_problems():
    """Beale's LP (the classic cycling example of the simplex method: a degenerate vertex at the origin,
    where every constraint is active) and a 6-D Klee–Minty cube (the path through all 2⁶ vertices,
    bounds up to 5⁶), each with a small quadratic term ε|x|²/2 (ε = 1e-6) so that it is a QP: solved,
    KKT-certified, and at the LP's optimal vertex to O(ε)."""
    eps = 1e-6
    # Beale: min −3/4 x1 + 20 x2 − 1/2 x3 + 6 x4 s.t. the two degenerate rows, x3 <= 1, x >= 0
    c = np.array([-0.75, 20.0, -0.5, 6.0])
    C = np.vstack([[0.25, -8.0, -1.0, 9.0], [0.5, -12.0, -0.5, 3.0], [0.0, 0.0, 1.0, 0.0], np.eye(4)])
    lo = np.concatenate([[-np.inf, -np.inf, -np.inf], np.zeros(4)])
    hi = np.concatenate([[0.0, 0.0, 1.0], np.full(4, np.inf)])
    R, d = np.sqrt(eps) * np.eye(4), -c / np.sqrt(eps)
    res = solve_qp(R, d, np.zeros((0, 4)), np.zeros(0), C, lo, hi)
    _check_kkt(res, R, d, np.zeros((0, 4)), np.zeros(0), C, lo, hi)
    assert np.max(np.abs(res.x - [1.0, 0.0, 1.0, 0.0])) <= 1e-3
    # Klee–Minty: max Σ 2^{n−j} x_j s.t. 2 Σ_{j<i} 2^{i−j} x_j + x_i <= 5^i, x >= 0 → x = (0, …, 0, 5^n)
    n = 6
    C = np.array([[2.0 ** (i - j + 1) if j < i else (1.0 if j == i else 0.0) for j in range(n)] for i in range(n)])
    C = np.vstack([C, np.eye(n)])
    lo = np.concatenate([np.full(n, -np.inf), np.zeros(n)])
    hi = np.concatenate([5.0 ** np.arange(1, n + 1), np.full(n, np.inf)])
    c = -(2.0 ** np.arange(n - 1, -1, -1))
    R, d = np.sqrt(eps) * np.eye(n), -c / np.sqrt(eps)
    res = solve_qp(R, d, np.zeros((0, n)), np.zeros(0), C, lo, hi)
    _check_kkt(res, R, d, np.zeros((0, n)), np.zeros(0), C, lo, hi)
    assert np.max(np.abs(res.x - np.append(np.zeros(n - 1), 5.0 ** n))) <= 1e-6 * 5.0 ** n


def test_infeasible_problem_is_reported_not_raised_in_a_batch():
    """One infeasible problem (two rows demanding C₀x >= 1 and C₀x <= 0) among feasible ones: the batch
    marks it (ok False, x nan, 'infeasible'), solves the others exactly as alone; solve_qp raises
    QPError naming it; inconsistent equality rows are named as such."""
    rng = np.random.default_rng(11)
    probs = [_random_qp(rng)[:7] for _ in range(5)]
    R, d, E, e, C, lo, hi = probs[2]
    probs[2] = (R, d, E, e, np.vstack([C[0], C[0]]), np.array([1.0, -np.inf]), np.array([np.inf, 0.0]))
    m = max(len(p[4]) for p in probs)
    pad = lambda p: (*p[:4], np.vstack([p[4], np.zeros((m - len(p[4]), 6))]),               # noqa: E731
                     np.append(p[5], np.full(m - len(p[5]), -np.inf)), np.append(p[6], np.full(m - len(p[6]), np.inf)))
    padded = [pad(p) for p in probs]
    batch = solve_qps(*(np.array([p[k] for p in padded]) for k in range(7)))
    assert batch.ok.tolist() == [True, True, False, True, True]
    assert batch.messages[2] == "infeasible" and np.all(np.isnan(batch.x[2]))
    for i in (0, 1, 3, 4):
        assert np.max(np.abs(batch.x[i] - solve_qp(*probs[i]).x)) <= 1e-13
    with pytest.raises(QPError, match="infeasible"):
        solve_qp(*probs[2])
    with pytest.raises(QPError, match="equality rows are inconsistent"):
        solve_qp(R, d, np.vstack([E[0], E[0]]), np.array([0.0, 1.0]), C, lo, hi)


def _passive_paper(duration):
    """The paper run with arm 1's wrist joint passive (its torque is 0 in the forward run)."""
    m, _, traj = run("paper_planar_2x3", duration)
    passive = np.array([False, False, True, False, False, False])
    return replace(m, motors=replace(m.motors, passive=passive)), traj


def test_infeasible_samples_are_reported_by_the_bounded_resolution():
    """A passive wrist needs an internal wrench of at least about 0.0091 N, N·m (grasp-line components)
    during the first second of the paper run and less later: with a bound of 0.0088 the bounded
    resolution has no solution at the early samples — a SampleFailureWarning names them, they are nan
    and listed in the result's failures, and every other sample is verified (passive torque 0, bound
    held, object balance) — nothing is raised; the study's text summary names them."""
    m, traj = _passive_paper(1.5)
    P = inverse_problem(m, traj)
    R = replace(resolution_for(m, "min_energy"), method="bounded", force_bound=0.0088, moment_bound=0.0088)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = resolve(P, R)
    failed = np.array([f.index for f in out.failures])
    assert 50 <= len(failed) < len(P.t) and {f.reason for f in out.failures} == {"infeasible"}
    assert [f.time for f in out.failures] == P.t[failed].tolist()
    msgs = [str(w.message) for w in caught if issubclass(w.category, SampleFailureWarning)]
    assert len(msgs) == 1 and f"no solution at {len(failed)} of {len(P.t)} samples: t=0 s (infeasible)" in msgs[0]
    bad = np.zeros(len(P.t), bool)
    bad[failed] = True
    assert np.all(np.isnan(out.tau[bad])) and np.all(np.isfinite(out.tau[~bad]))
    assert np.max(np.abs(out.tau[~bad][:, 2])) <= 1e-12
    assert np.max(np.abs(np.einsum("nij,nj->ni", P.A[~bad], out.f[~bad]) - P.y[~bad])) <= 1e-14
    assert np.max(np.abs(grasp_line_frames(P)[~bad] @ out.internal_nonsqueezing[~bad][..., :3, None])) <= 0.0088 + 1e-12
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SampleFailureWarning)
        study = inverse_study(m, ("bounded",), duration=1.5, bounds=(0.0088, 0.0088), curve=False)
    text = format_inverse_summary(inverse_summary(study))
    assert f"bounded: NO SOLUTION at {len(failed)} of {len(P.t)} samples, left out (nan): t=0 s (infeasible)" in text


def test_cli_inverse_reports_infeasible_samples_and_writes_outputs(workdir):
    """`coopsim inverse` on that case (a scenario file with the passive wrist and the bound): exit 1,
    inverse.json, inverse.mcap and the plots written; the summary marks the run incomplete and lists
    the failed samples, the text names them, stderr carries the warning; the solved samples' peaks are
    finite, the failed ones are NaN in the log; the replay is not run and says why."""
    data = yaml.safe_load((SCENARIOS / "paper_planar_2x3.yaml").read_text())
    data["arms"][0]["passive"] = [False, False, True]
    data["inverse"] = {"internal_bound": {"force": 0.0088, "moment": 0.0088}}
    path = workdir / "scenarios" / "passive.yaml"
    path.write_text(yaml.safe_dump(data))
    out = run_cli("inverse", path, "--method", "bounded", "--duration", "1.5", "--no-curve", "--replay",
                  "--json", "--out", "res", cwd=workdir)
    assert out.returncode == 1, out.stderr
    s = json.loads(out.stdout)
    b = s["methods"]["bounded"]
    assert s["complete"] is False and 50 <= len(b["failed_samples"]) < 151
    assert b["failed_samples"][0] == {"time_s": 0.0, "reason": "infeasible"}
    assert b["energy"] == "NaN" and np.isfinite(b["max_torque_norm_Nm"])
    assert b["replay"]["max_angle_error_rad"] == "NaN" and b["replay"]["failed_stage_times"]
    assert "SampleFailureWarning" in out.stderr and "no solution at" in out.stderr
    from coopsim.io.mcap_codec import read_mcap

    tau = read_mcap(workdir / "res" / "inverse.mcap").topics["/inverse/bounded/torque"]["tau"]
    assert np.sum(np.all(np.isnan(tau), axis=1)) == len(b["failed_samples"])
    for name in ("inverse_torques.png", "inverse_norms.png", "inverse_internal.png", "inverse.json"):
        assert (workdir / "res" / name).stat().st_size > 1000, name


def test_bounded_resolution_is_exact_on_the_paper_run():
    """The polished QP solutions are exact: the object balance A f = y holds to 1e-15 N, N·m at every
    sample of the 5 s paper run (half-peak bound, most samples with an active bound)."""
    m, _, _ = run("paper_planar_2x3")
    P = problem("paper_planar_2x3")
    R = resolution_for(m, "min_energy")
    fb, mb = default_bounds(P, R)
    out = resolve(P, replace(R, method="bounded", force_bound=fb, moment_bound=mb))
    assert not out.failures
    assert np.max(np.abs(np.einsum("nij,nj->ni", P.A, out.f) - P.y)) <= 1e-15


# ------------------------------------------------------------------------------------------------
# LPs (solve_lps) against scipy's linprog: another HiGHS build, called one problem at a time
# ------------------------------------------------------------------------------------------------

LP_TOL = 1e-9     # objective, μ: relative to max(1, |value|)


def _linprog_one(lp, i):
    """scipy's linprog on problem i alone (rows with an infinite bound left out): the result and the
    inequality marginals over all rows (0 on those left out)."""
    c, A_ub, b_ub, A_eq, b_eq, bounds = lp
    keep = np.isfinite(b_ub[i])
    sol = linprog(c, A_ub=A_ub[i][keep] if keep.any() else None, b_ub=b_ub[i][keep] if keep.any() else None,
                  A_eq=A_eq[i], b_eq=b_eq[i], bounds=bounds, method="highs")
    marg = np.zeros(len(keep))
    if sol.status == 0:
        marg[keep] = sol.ineqlin.marginals if keep.any() else 0.0
    return sol, marg


def _nondegenerate(lp, i, x):
    """x is a vertex of problem i with exactly v active constraints (its duals are then unique)."""
    c, A_ub, b_ub, A_eq, b_eq, bounds = lp
    keep = np.isfinite(b_ub[i])
    slack = (b_ub[i] - A_ub[i] @ x)[keep]
    scale = max(1.0, np.max(np.abs(b_ub[i][keep]), initial=0.0), np.max(np.abs(x)))
    at_bound = sum(lo is not None and abs(x[j] - lo) <= 1e-9 * scale for j, (lo, _) in enumerate(bounds))
    return int(np.sum(np.abs(slack) <= 1e-9 * scale)) + len(b_eq[i]) + at_bound == len(c)


def _agree(batch, lp, idx):
    """Problems idx of an LPBatch agree with linprog: the same status; where optimal the objective and
    μ to LP_TOL, marginals <= 0 (linprog's sign), and equal to linprog's at a nondegenerate vertex
    both reach. Returns how many problems' marginals were compared."""
    compared = 0
    for i in idx:
        sol, marg = _linprog_one(lp, i)
        assert batch.status[i] == sol.status, (i, batch.status[i], sol.status, batch.messages[i], sol.message)
        if sol.status != 0:
            assert np.all(np.isnan(batch.x[i])) and np.all(batch.marginals[i] == 0.0)
            continue
        x, c = batch.x[i], lp[0]
        assert abs(c @ x - sol.fun) <= LP_TOL * max(1.0, abs(sol.fun)), (i, c @ x, sol.fun)
        assert abs(x[-1] - sol.x[-1]) <= LP_TOL * max(1.0, abs(sol.x[-1])), (i, x[-1], sol.x[-1])
        assert np.all(batch.marginals[i] <= 1e-12 * max(1.0, np.max(np.abs(marg)))), i
        if np.max(np.abs(x - sol.x)) <= 1e-9 * max(1.0, np.max(np.abs(x))) and _nondegenerate(lp, i, x):
            compared += 1
            assert np.max(np.abs(batch.marginals[i] - marg)) <= 1e-9 * max(1.0, np.max(np.abs(marg))), i
    return compared


@pytest.mark.parametrize("name", BUNDLED)
def test_lps_match_linprog_on_the_bundled_scenes(name):
    """The capacity LPs of every bundled scene (both modes; max μ and min μ): solve_lps on the whole
    batch, and on single problems without the cap (the direct HiGHS path), against scipy's linprog
    alone on every 10th problem and every one whose status is not optimal: statuses equal (optimal, and
    unbounded where a sample allows any mass), objective and μ to LP_TOL (HiGHS certifies 1e-7 in its
    scaled problem; both end on the same vertex here: measured <= 3e-13), marginals <= 0 as linprog's
    and equal to them (1e-9) wherever both reach the same nondegenerate vertex."""
    for mode in cap.MODES:
        for sense in (1.0, -1.0):
            lp = capacity_lps(name, mode)
            lp = (sense * lp[0],) + lp[1:]
            N = len(lp[1])
            batch = solve_lps(*lp)
            idx = np.union1d(np.arange(0, N, 10), np.flatnonzero(batch.status != 0))
            compared = _agree(batch, lp, idx)
            assert compared > 0 or sense < 0          # min μ: μ = 0 where f is not unique (no vertex compared)
            for i in idx[::4]:
                one = (lp[0], *(a[i:i + 1] for a in lp[1:5]), lp[5])
                _agree(solve_lps(*one, cap=np.inf), one, [0])


@pytest.mark.parametrize("name", ["spatial_6r_pair", "hard/spatial_3arm_mixed"])
def test_short_lp_batches_start_from_seeds_and_match_linprog(name, monkeypatch):
    """A batch shorter than 2·LP_SEED_STRIDE (the first 101 capacity LPs of a spatial scene, as a 101-sample
    carry gives) is seeded too (`qp.lp_seed_stride`): the seeds are solved first and at least a third of
    the problems are certified at their bases (a regression pin: 66 and 38 of 101 here, where the optimal
    basis changes along the motion; the others go to HiGHS after them); every problem agrees with
    linprog alone (`_agree`)."""
    lp = capacity_lps(name, "scaled")
    short = (lp[0], *(a[:101] for a in lp[1:5]), lp[5])
    sizes, run_lp = [], qp._run_lp
    monkeypatch.setattr(qp, "_run_lp", lambda h, P, idx, *a, **k: sizes.append(len(idx)) or run_lp(h, P, idx, *a, **k))
    batch = solve_lps(*short)
    assert sizes[0] == len(range(0, 101, qp.lp_seed_stride(101))) and sum(sizes[1:]) <= 101 * 2 / 3, sizes
    assert _agree(batch, short, np.arange(101)) > 0


def test_lps_infeasible_and_unbounded_problems_match_linprog():
    """The paper carry's capacity LPs made infeasible at some samples (every torque row <= −1: τ >= 1
    and τ <= −1 at once), at a seed (problem 0: the seeds' LP has no optimum) or not (130, 131), and
    unbounded at others (no mass column in the equality rows: any μ carries), and a scene with no motor
    limits (every problem unbounded): the statuses are linprog's (2, 3) at those problems, and the
    other problems' solutions stay as without them."""
    lp = capacity_lps("paper_planar_2x3_carry", "scaled")
    base = solve_lps(*lp)
    for bad in ([0, 130, 131], [130, 131]):
        b_ub = lp[2].copy()
        b_ub[bad] = -1.0
        A_eq = lp[3].copy()
        A_eq[[64, 200], :, -1] = 0.0
        broken = (lp[0], lp[1], b_ub, A_eq) + lp[4:]
        batch = solve_lps(*broken)
        assert batch.status[bad].tolist() == [2] * len(bad) and batch.status[[64, 200]].tolist() == [3, 3]
        _agree(batch, broken, bad + [64, 200, 1, 65, 129, 132])
        rest = np.setdiff1d(np.arange(len(b_ub)), bad + [64, 200])
        assert np.array_equal(batch.status[rest], base.status[rest])
        ok = rest[base.status[rest] == 0]
        assert np.max(np.abs(batch.x[ok, -1] - base.x[ok, -1]) / np.maximum(1.0, base.x[ok, -1])) <= LP_TOL
    free = capacity_lps("spatial_6r_pair", "scaled", motors=False)
    batch = solve_lps(*free)
    assert np.all(batch.status == 3)
    _agree(batch, free, np.arange(0, 301, 10))
