"""The compiled pass of the linear resolutions (`coopsim.compiled.distributions`, through
`coopsim.inverse.distributions.linear_pass`) against the NumPy reference (engine 'reference': the registry's
functions, `torques_of`, `internal_wrench`, `affine_torques`, `mass_limits`), at every bundled scenario's
trajectory, the robot carry with its object motion, the passive-joint scene and a spatial three-arm scene.

Tolerance 1e-12 relative, to the largest magnitude of the quantity compared (for the internal wrenches, of
the grasp wrenches: they vanish for the resolution that zeroes them): both engines evaluate the same
formulas in the same floating-point arithmetic, differing in summation order, fused multiply-adds and the
factorisation of the small systems (Cholesky and Householder QR against LU and the SVD); the rounding that
leaves is a few eps times the condition numbers of those systems, measured on these scenes as ≤ 5e-14
for the torques. A capacity μ = (τ_lim − a)/b inherits the torques' error divided by the rate b at the
binding motor line: ≤ 1e-13 relative for the capacities here but one, 5e-13 for an
infeasible one (μ = −2561 kg, a motor beyond its line at zero mass whose rate b is 3000 times smaller
than its torque); the test allows REL times the larger of |μ| and max |τ_j| / |b|."""

import warnings
from dataclasses import replace

import numpy as np
import pytest

from coopsim.core.model import torque_limits
from coopsim.inverse import capacity as cap
from coopsim.inverse.distributions import LINEAR_ROWS, linear_pass
from coopsim.inverse.problem import InverseRankWarning
from coopsim.inverse.resolutions import LINEAR_METHODS
from coopsim.inverse.solve import distribute, resolution_for, resolve
from coopsim.report.inverse_report import capacity_study, solve_study
from inverse_cases import BUNDLED, model, problem, run, with_motors

CASES = BUNDLED + ["robots/panda_ceiling_carry", "hard/passive_joints", "hard/spatial_3arm_mixed"]
REL = 1e-12


def _close(got, ref, scale=None):
    """got within REL·scale of ref (default scale: max |ref|), nan exactly where ref is (unsolved samples)."""
    assert np.array_equal(np.isnan(got), np.isnan(ref))
    scale = np.nanmax(np.abs(ref), initial=0.0) if scale is None else scale
    assert np.nanmax(np.abs(got - ref), initial=0.0) <= REL * max(scale, 1e-300)


def _capacity_close(got: cap.Capacity, ref: cap.Capacity, a, b, lo, hi, act):
    """The same capacity within REL of the larger of |μ| and the torques' error over the binding line's
    rate, max |a_j| / |b_ij|: an infeasible scene's μ < 0 set by a line with a small rate b inherits more."""
    if ref.joint is None:
        assert (got.mass, got.lower, got.joint) == (ref.mass, ref.lower, None)
        return
    i, j = ref.sample, ref.joint
    spread = max(abs(ref.mass), np.max(np.abs(a[:, j])) / abs(b[i, j]))
    assert abs(got.mass - ref.mass) <= REL * spread
    assert got.lower == ref.lower or got.lower == pytest.approx(ref.lower, rel=REL)
    assert got.feasible == ref.feasible and got.note == ref.note and got.side == ref.side
    if (got.joint, got.sample) != (i, j):      # a tie (mirror-image arms): the same mass there
        up = cap.mass_limits(a[:, act], b[:, act], lo[:, act], hi[:, act])[0]
        assert up[got.sample, int(np.sum(act[:got.joint]))] == pytest.approx(ref.mass, rel=REL)


def _motorised(name):
    m, res, traj = run(name)
    return with_motors(m, res, traj)


@pytest.mark.parametrize("name", CASES)
def test_resolutions_equal_the_reference(name):
    """Torques, grasp wrenches, both internal wrenches and cost of every linear resolution."""
    m, P = model(name), problem(name)
    for method in LINEAR_METHODS:
        res = resolution_for(m, method)
        got, ref = resolve(P, res), resolve(P, res, engine="reference")
        _close(got.tau, ref.tau)
        _close(got.f, ref.f)
        _close(got.grasp_wrench, ref.grasp_wrench)
        scale = np.max(np.abs(ref.grasp_wrench))
        _close(got.internal_paper, ref.internal_paper, scale)
        _close(got.internal_nonsqueezing, ref.internal_nonsqueezing, scale)
        _close(got.cost, ref.cost)
        _close(distribute(P, P.y_unit, res), distribute(P, P.y_unit, res, engine="reference"))


@pytest.mark.parametrize("name", CASES)
def test_capacities_equal_the_reference(name):
    """(a, b) of τ(μ) = a + μ b and the closed-form capacity of every linear resolution, both modes (a
    motor-less scene gets test motors, `with_motors`)."""
    m, P = _motorised(name), problem(name)
    lo, hi = torque_limits(m.motors, P.qd)
    act = ~m.motors.passive
    for method in LINEAR_METHODS:
        res = resolution_for(m, method)
        for mode in cap.MODES:
            a, b = cap.affine_torques(P, res, mode)
            ra, rb = cap.affine_torques(P, res, mode, engine="reference")
            _close(a, ra)
            _close(b, rb, max(np.max(np.abs(rb)), np.max(np.abs(ra + rb))))
            _capacity_close(cap.method_capacity(P, res, m.motors, mode),
                            cap.method_capacity(P, res, m.motors, mode, engine="reference"), ra, rb, lo, hi, act)


@pytest.mark.parametrize("name", ["paper_planar_2x3_carry", "robots/panda_ceiling_carry", "hard/passive_joints"])
def test_capacity_study_equals_the_reference(name):
    """`capacity_study` (its one pass for every resolution and mode) against its reference engine: every
    capacity, the torques at it and the energies."""
    m = _motorised(name)
    got = capacity_study(m, with_lp=False, optimise=False)
    ref = capacity_study(m, with_lp=False, optimise=False, engine="reference")
    assert got.caps.keys() == ref.caps.keys()
    lo, hi = ref.limits
    for (method, mode), c in ref.caps.items():
        a, b = cap.affine_torques(ref.problem, resolution_for(m, method), mode, engine="reference")
        _capacity_close(got.caps[method, mode], c, a, b, lo, hi, ~m.motors.passive)
        _close(got.tau_at[method, mode], c.mass * b + a if np.isfinite(c.mass) else a,
               np.max(np.abs(a)) + abs(c.mass) * np.max(np.abs(b)))
    for k in ref.energies:
        assert got.energies[k] == pytest.approx(ref.energies[k], rel=REL)


def test_one_pass_equals_one_call_per_method():
    """The pass over several net wrenches and methods at once equals one method and one wrench at a time
    (each sample's arithmetic does not depend on the others: bit for bit)."""
    m, P = model("paper_planar_2x3_carry"), problem("paper_planar_2x3_carry")
    res = resolution_for(m, "min_energy")
    ys = np.stack([P.y, P.y_unit, P.y_payload])
    together = linear_pass(P, res, ys, LINEAR_METHODS, wrench_of=1)
    for method, row in LINEAR_ROWS.items():
        for q in range(len(ys)):
            alone = linear_pass(P, res, ys[q:q + 1], (method,), wrench_of=0)
            assert np.array_equal(alone.tau[row, 0], together.tau[row, q])
            if q == 1:
                assert np.array_equal(alone.internal_paper[row], together.internal_paper[row])


def test_rank_lost_samples_take_the_reference_path():
    """With rank_tol 0.5 no energy Hessian passes the pass's certificate: every sample goes to the NumPy
    path, with the reference's InverseRankWarning word for word and its numbers; at the scenario's rank_tol
    the pass certifies every sample (no warning)."""
    m, P = model("paper_planar_2x3"), problem("paper_planar_2x3", 0.2)
    res = resolution_for(m, "min_energy")
    strict = replace(P, rank_tol=0.5)
    with warnings.catch_warnings(record=True) as got_w:
        warnings.simplefilter("always")
        got = resolve(strict, res)
    with warnings.catch_warnings(record=True) as ref_w:
        warnings.simplefilter("always")
        ref = resolve(strict, res, engine="reference")
    got_text = [str(w.message) for w in got_w if issubclass(w.category, InverseRankWarning)]
    assert got_text and got_text == [str(w.message) for w in ref_w if issubclass(w.category, InverseRankWarning)]
    _close(got.tau, ref.tau)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InverseRankWarning)
        assert np.all(linear_pass(strict, res, P.y[None], ("min_energy",)).unsure[LINEAR_ROWS["min_energy"]])
    with warnings.catch_warnings():
        warnings.simplefilter("error", InverseRankWarning)
        assert not np.any(linear_pass(P, res, P.y[None], ("min_energy",)).unsure)


def test_unknown_engine_is_refused():
    m, P = model("paper_planar_2x3"), problem("paper_planar_2x3", 0.2)
    with pytest.raises(ValueError, match="engine"):
        resolve(P, resolution_for(m, "paper"), engine="fast")


@pytest.mark.filterwarnings("ignore::coopsim.inverse.problem.SampleFailureWarning")
@pytest.mark.parametrize("name", ["paper_planar_2x3_carry", "hard/passive_joints"])
def test_inverse_study_equals_the_reference(name):
    """`solve_study` (what `coopsim inverse` runs: every resolution, 'bounded' at its default bounds — which
    passive joints make infeasible at every sample of hard/passive_joints: nan in both —, the
    internal-wrench components and the section loads) against its reference engine."""
    got = solve_study(model(name), duration=0.3)
    ref = solve_study(model(name), duration=0.3, engine="reference")
    assert got.bounds == pytest.approx(ref.bounds, rel=REL)
    for k, r in ref.results.items():
        _close(got.results[k].tau, r.tau)
        _close(got.results[k].internal_nonsqueezing, r.internal_nonsqueezing, np.nanmax(np.abs(r.grasp_wrench),
                                                                                        initial=0.0))
    for k, s in ref.stress.items():
        _close(got.stress[k].peak_normal, s.peak_normal)
