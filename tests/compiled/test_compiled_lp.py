"""The compiled LP vertices (`coopsim.compiled.lp`, `coopsim.inverse.qp._vertices`) against their NumPy
reference (`coopsim.inverse.qp._vertices_reference`) on the capacity LPs of every bundled scene, both
modes, maximising and minimising μ: every problem at its nearest seed's optimal basis (as `solve_lps`
uses them), and at those bases with rows shuffled in and out (bases that are invalid, singular or not
optimal). The certificates (optimal, unbounded) are the same; where certified, x and the duals agree to
1e-12 of their scale: both solve the same v × v systems (v = rk + 1 ≤ 19) at the same basis, by LU with
partial pivoting (LAPACK's and the kernel's, summing in other orders), measured ≤ 3e-15. The tests
against scipy's linprog (tests/inverse/test_qp.py) run through the compiled vertices."""

import numpy as np
import pytest

from coopsim.inverse import capacity as cap
from coopsim.inverse import qp
from inverse_cases import BUNDLED, capacity_lps

REL = 1e-12


def _seed_bases(lp):
    """(the batch `_LPs`, col (N, v), row (N, r) codes): every problem with its nearest seed's basis."""
    P = qp._LPs.of(*lp, 1e9)
    N = len(P.G)
    stride = qp.lp_seed_stride(N)
    seeds = np.arange(0, N, stride)
    with qp._HIGHS_LOCK:
        run = qp._run_lp(qp._highs_lp(), P, seeds, True, None, want_basis=True)
    assert run.status == 0
    near = np.minimum(np.rint(np.arange(N) / stride), len(seeds) - 1).astype(int)
    return P, run.col_basis[near], run.row_basis[near]


def _agree(P, col, row):
    idx = np.arange(len(col))
    x, y, ok, unbounded = qp._vertices(P, idx, col, row)
    rx, ry, rok, runbounded = qp._vertices_reference(P, idx, col, row)
    assert np.array_equal(ok, rok) and np.array_equal(unbounded, runbounded)
    for got, ref in ((x[ok], rx[ok]), (y[ok], ry[ok])):
        scale = np.max(np.abs(ref), axis=1, initial=1.0)[:, None]
        assert np.all(np.abs(got - ref) <= REL * scale)
    return int(ok.sum()), int(unbounded.sum())


@pytest.mark.parametrize("name", BUNDLED)
def test_vertices_equal_the_reference(name):
    rng = np.random.default_rng(3)
    certified = 0
    for mode in cap.MODES:
        for sense in (1.0, -1.0):
            lp = capacity_lps(name, mode)
            P, col, row = _seed_bases((sense * lp[0],) + lp[1:])
            certified += _agree(P, col, row)[0]
            swap = rng.random(row.shape) < 0.1                     # some rows in or out of the basis
            mixed = np.where(swap, np.where(row == 1, 0, 1), row).astype(np.int8)
            _agree(P, col, mixed)
            _agree(P, col, rng.integers(0, 5, row.shape).astype(np.int8))
    assert certified > 0


def test_unbounded_vertices_equal_the_reference():
    """A scene without motor limits: every problem is unbounded, certified by a ray at the cap."""
    P, col, row = _seed_bases(capacity_lps("spatial_6r_pair", "scaled", motors=False))
    ok, unbounded = _agree(P, col, row)
    assert unbounded == ok == len(col)
