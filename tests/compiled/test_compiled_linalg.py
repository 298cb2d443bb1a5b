"""The compiled small dense linear algebra (`coopsim.compiled.linalg`) against LAPACK through NumPy:
Jacobi eigen-decomposition, one-sided Jacobi singular-value ratio, LU solve and determinant. The
kernels are callable from compiled code only, so a test-side compiled wrapper calls each."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from coopsim.compiled.linalg import jacobi_eigh, lu_solve, singular_ratio


@njit(cache=True)
def _eigh(A, vectors):
    K = A.shape[0]
    ev, V = np.empty(K), np.empty((K, K))
    jacobi_eigh(A, K, ev, V, vectors)
    return ev, V


@njit(cache=True)
def _ratio(G):
    return singular_ratio(G, G.shape[0], G.shape[1])


@njit(cache=True)
def _solve(A, b):
    x = np.empty(len(b))
    det = lu_solve(A, len(b), b, x)
    return x, det


def _symmetric_cases():
    rng = np.random.default_rng(7)
    cases = []
    for K in (1, 2, 3, 6, 12, 18):
        B = rng.standard_normal((K, K))
        cases.append(B @ B.T)                                  # SPD
        Q = np.linalg.qr(rng.standard_normal((K, K)))[0]
        d = np.sort(rng.uniform(1, 2, K))
        d[: K // 2] = 1.5                                      # repeated eigenvalues
        cases.append(Q @ np.diag(d) @ Q.T)
        d[: K // 3] = 0.0                                      # rank-deficient PSD
        cases.append(Q @ np.diag(d) @ Q.T)
        cases.append(Q @ np.diag(np.logspace(-14, 0, K)) @ Q.T)   # graded, cond 1e14
    cases.append(np.zeros((4, 4)))
    return cases


@pytest.mark.parametrize("A", _symmetric_cases(), ids=lambda A: f"K{A.shape[0]}")
def test_jacobi_eigh_matches_lapack(A):
    ev, V = _eigh(A, True)
    ref = np.linalg.eigvalsh(A)
    scale = max(np.max(np.abs(ref)), 1e-300)
    assert np.max(np.abs(ev - ref)) <= 1e-14 * scale * A.shape[0], "eigenvalues differ from LAPACK dsyevd"
    assert np.all(np.diff(ev) >= 0), "eigenvalues not ascending"
    assert np.max(np.abs(V.T @ V - np.eye(len(A)))) <= 1e-14, "eigenvectors not orthonormal"
    assert np.max(np.abs(A @ V - V * ev)) <= 1e-14 * scale * A.shape[0], "A V != V diag(ev)"
    ev_only, _ = _eigh(A, False)
    assert np.array_equal(ev_only, ev), "eigenvalues depend on whether vectors are wanted"


@pytest.mark.parametrize("n,cond", [(1, 1.0), (3, 1e2), (6, 1e6), (7, 1e12)])
def test_singular_ratio_matches_lapack_svd(n, cond):
    rng = np.random.default_rng(n)
    U = np.linalg.qr(rng.standard_normal((n, n)))[0]
    V = np.linalg.qr(rng.standard_normal((n, n)))[0]
    G = U @ np.diag(np.logspace(0, -np.log10(cond), n)) @ V.T
    sv = np.linalg.svd(G, compute_uv=False)
    assert abs(_ratio(G) - sv[-1] / sv[0]) <= 1e-13 * sv[-1] / sv[0] + 1e-15, "σ_min/σ_max differs from LAPACK"


def test_singular_ratio_of_singular_and_non_finite_matrices():
    G = np.array([[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 1.0, 1.0]])
    assert _ratio(G) <= 1e-16, "rank-2 matrix: σ_min/σ_max should vanish"
    assert _ratio(np.zeros((3, 3))) == 0.0, "zero matrix"
    G[1, 1] = np.nan
    assert _ratio(G) == 0.0, "a NaN entry must read as singular, not loop or pass"


@pytest.mark.parametrize("n", [1, 2, 3, 6, 7])
def test_lu_solve_and_determinant_match_lapack(n):
    rng = np.random.default_rng(100 + n)
    A = rng.standard_normal((n, n))
    A[0], A[-1] = A[-1].copy(), 1e-3 * A[0]                  # a small leading pivot: pivoting needed
    b = rng.standard_normal(n)
    x, det = _solve(A, b)
    ref = np.linalg.solve(A, b)
    assert np.max(np.abs(x - ref)) <= 1e-12 * np.max(np.abs(ref)), "solution differs from LAPACK dgesv"
    assert abs(det - np.linalg.det(A)) <= 1e-12 * abs(np.linalg.det(A)), "determinant differs"
    assert np.array_equal(A, A.copy()), "A modified"


def test_lu_solve_of_a_singular_matrix_returns_zero_and_nan():
    A = np.array([[1.0, 2.0], [2.0, 4.0]])
    x, det = _solve(A, np.array([1.0, 1.0]))
    assert det == 0.0 and np.all(np.isnan(x)), f"singular matrix: det {det}, x {x}"
