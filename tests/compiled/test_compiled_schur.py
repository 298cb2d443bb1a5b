"""The O(r) constraint solve (`coopsim.compiled.schur`) against LAPACK through NumPy.

(Y Yᵀ) x = b for the two matrices the kernels solve with it, Y = Λ L⁻ᵀ (Λ𝐈⁻¹Λᵀ, the closed-chain
solve) and Y = Λ (ΛΛᵀ, the manifold projection), taken from the compiled workspace at consistent
states of scenes with 2, 3 and 4 arms, the carrier first or in the middle. The reference is
`numpy.linalg.solve` on the dense matrix. The kernels are callable from compiled code only, so a
test-side compiled wrapper calls them.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from numba import njit

from coopsim.compiled import api
from coopsim.compiled.schur import constraint_trace, schur_factor, schur_solve
from helpers import SCENARIOS, consistent_states
from helpers import assert_compiled_terms_match_the_reference
from coopsim.io.scenario import load_scenario

# normwise relative error against LAPACK after one refinement step, per unit of cond(A)
TOL = 1e-13

SCENES = ["paper_planar_2x3", "planar_3arm_vertical", "spatial_6r_pair", "gantry_prismatic",
          "hard/planar_4arm_mixed", "hard/spatial_3arm_mixed"]


@njit(cache=True)
def _schur(P, W, Y, b):
    x = np.zeros(len(b))
    ok = schur_factor(P, W, Y, constraint_trace(P, Y))
    if ok:
        schur_solve(P, W, b, x)
    return ok, x


def _solve(model, Y, b):
    c = api.compiled(model)
    return _schur(c.Ps, c.Ws, np.ascontiguousarray(Y), b)


def _block_condition(model, Y):
    """max_g cond(D_g), D_g = Y_g Y_gᵀ the k × k block of row group g in its arm's columns."""
    k, c, dof = model.rows.shape[0], model.object.carrier, np.cumsum([0] + [a.n for a in model.arms])
    arms = [g + 1 if g >= c else g for g in range(model.r - 1)]
    return max(np.linalg.cond(Y[g * k:g * k + k, dof[m]:dof[m + 1]] @ Y[g * k:g * k + k, dof[m]:dof[m + 1]].T)
               for g, m in enumerate(arms))


def _check(model, Y, b, where):
    """The solve's error follows cond(D) (≤ 1e-14·cond(D) relative); one step of refinement, as the
    callers take, brings it to LAPACK's (≤ 1e-13·cond(A))."""
    A = Y @ Y.T
    ref = np.linalg.solve(A, b)
    ok, x = _solve(model, Y, b)
    assert ok, f"{where}: the Schur path was not certified (cond {np.linalg.cond(A):.3g})"
    err = np.linalg.norm(x - ref) / np.linalg.norm(ref)
    assert err <= 1e-14 * _block_condition(model, Y), f"{where}: relative error {err:.3g}"
    x = x + _solve(model, Y, b - A @ x)[1]
    err = np.linalg.norm(x - ref) / np.linalg.norm(ref)
    assert err <= TOL * np.linalg.cond(A), f"{where}: relative error {err:.3g} after refinement"


def _models(name):
    model = load_scenario(SCENARIOS / f"{name}.yaml")
    yield model
    if model.r >= 3:   # the carrier in the middle: row groups before and after it
        yield dataclasses.replace(model, object=dataclasses.replace(model.object, carrier=1))


@pytest.mark.parametrize("name", SCENES)
def test_schur_solve_equals_the_dense_solve(name):
    rng = np.random.default_rng(5)
    for model in _models(name):
        for i, (q, qd) in enumerate(consistent_states(model, 3, seed=6)):
            W = api.chain_terms(model, q, qd)
            K = W.Lam.shape[0]
            for label, Y in (("Λ L⁻ᵀ", W.X.copy()), ("Λ", W.Lam.copy())):
                _check(model, Y, rng.standard_normal(K), f"{name}, carrier {model.object.carrier}, state {i}, Y = {label}")


def test_an_arm_at_its_singularity_is_left_to_the_dense_path():
    """With arm2 of hard/arm_singularity stretched (θ₂ = 0, det J = l₁l₂ sin θ₂ = 0), its block
    D_g = Λ_g Λ_gᵀ has rank k − 1: no certificate, so the kernels fall back to the rank-deciding dense
    solve. Just off it (θ₂ = 0.1, the scenario's start) the certificate holds."""
    model = load_scenario(SCENARIOS / "hard/arm_singularity.yaml")
    q = model.q0.copy()
    assert model.object.carrier == 0 and q[4] == 0.1
    W = api.chain_terms(model, q, np.zeros(model.n_total))
    assert _solve(model, W.Lam.copy(), np.ones(W.Lam.shape[0]))[0]
    q[4] = 0.0
    W = api.chain_terms(model, q, np.zeros(model.n_total))
    ok, _ = _solve(model, W.Lam.copy(), np.ones(W.Lam.shape[0]))
    assert not ok


@pytest.mark.parametrize("name", ["planar_3arm_vertical", "hard/planar_4arm_mixed", "hard/spatial_3arm_mixed"])
def test_accelerations_through_the_schur_path_match_the_reference(name):
    """θ̈ and every stage term of the compiled kernels (Schur path, r ≥ 3) against the plain-NumPy
    reference (dense solve) at 10 consistent states, ≤ 1e-12 relative (`test_compiled`)."""
    assert_compiled_terms_match_the_reference(load_scenario(SCENARIOS / f"{name}.yaml"), 10)
