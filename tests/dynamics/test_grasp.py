"""Stage 3 — grasp matrices, object Newton–Euler terms and the internal-wrench decomposition (eqs. 1–8)."""

import numpy as np

from coopsim.dynamics.grasp import grasp_matrix, grasp_matrix_inv_T, internal_wrench, net_object_wrench
from coopsim.core.spatial import skew


def test_grasp_matrix_moves_wrenches_and_twists_consistently():
    """Virtual power: v_EEᵀ F_e = v_oᵀ (W F_e) with v_EE = Wᵀ v_o (eqs. 2–3), and W⁻ᵀ inverts Wᵀ."""
    rng = np.random.default_rng(10)
    for _ in range(20):
        s, F, v = rng.normal(size=3), rng.normal(size=6), rng.normal(size=6)
        W = grasp_matrix(s)
        assert abs((W.T @ v) @ F - v @ (W @ F)) <= 1e-13
        assert np.max(np.abs(grasp_matrix_inv_T(s) @ W.T - np.eye(6))) <= 1e-15
        # a force f at the EE point gives a moment −s × f … about C: n_C = n + (p_EE − p_C) × f
        assert np.allclose((W @ F)[3:], F[3:] + np.cross(-s, F[:3]), rtol=0, atol=1e-14)


def test_paper_decomposition_for_two_arms():
    """F_e = W⁺ F_o + V F_I with the paper's W⁺ = ½[W_1⁻¹; W_2⁻¹] and V (eq. 8); W V = 0."""
    rng = np.random.default_rng(11)
    for _ in range(20):
        s1, s2 = rng.normal(size=3), rng.normal(size=3)
        W = [grasp_matrix(s1), grasp_matrix(s2)]
        I3, O3 = np.eye(3), np.zeros((3, 3))
        V = np.block([[-I3, O3], [-skew(s1), -I3], [I3, O3], [skew(s2), I3]])
        assert np.max(np.abs(np.hstack(W) @ V)) <= 1e-14
        F_e = rng.normal(size=(2, 6))
        F_o = net_object_wrench(W, F_e)
        F_I = internal_wrench(W, F_e)
        assert np.max(np.abs(F_I.sum(axis=0))) <= 1e-14
        W_plus = 0.5 * np.vstack([np.linalg.inv(W[0]), np.linalg.inv(W[1])])
        rebuilt = W_plus @ F_o + V @ F_I[1]
        assert np.max(np.abs(rebuilt - F_e.ravel())) <= 1e-13


def test_internal_wrench_vanishes_for_equal_shares():
    """Arms that each deliver 1/r of F_o (moved to their grasp points) leave no internal wrench."""
    rng = np.random.default_rng(12)
    W = [grasp_matrix(rng.normal(size=3)) for _ in range(3)]
    F_o = rng.normal(size=6)
    F_e = np.array([np.linalg.solve(Wm, F_o / 3) for Wm in W])
    assert np.max(np.abs(internal_wrench(W, F_e))) <= 1e-14
    assert np.max(np.abs(net_object_wrench(W, F_e) - F_o)) <= 1e-14
