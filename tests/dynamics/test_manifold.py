"""Stage 5 — projection onto the loop-closure manifold and Baumgarte terms."""

import numpy as np
import pytest

from coopsim.dynamics.closed_chain import position_residual
from coopsim.core.errors import ConstraintError
from coopsim.dynamics.manifold import (baumgarte_term, constraint_jacobian, consistent_state, project_positions,
                              project_velocities)
from helpers import paper_residual_by_hand


def test_constraint_jacobian_is_the_derivative_of_the_residual(spatial):
    """Λ δq = Φ(q + δq) − Φ(q) to first order at a consistent state (central differences, 1e-6)."""
    q = consistent_state(spatial, spatial.q0, spatial.qd0).q
    Lam = constraint_jacobian(spatial, q)
    h = 1e-6
    fd = np.column_stack([(position_residual(spatial, q + h * e) - position_residual(spatial, q - h * e)) / (2 * h)
                          for e in np.eye(spatial.n_total)])
    assert np.max(np.abs(Lam - fd)) <= 1e-8


def test_projection_closes_the_paper_loop_with_a_minimum_norm_correction(paper):
    proj = consistent_state(paper, paper.q0, paper.qd0 + 0.1)
    # 3.1147e-5 m: regression pin (number produced by coopsim itself); independent check next to it:
    # planar trigonometry on the YAML's numbers (conftest.paper_residual_by_hand) gives 3.114654e-5 m.
    assert proj.residual_before == pytest.approx(3.1147e-5, rel=1e-3), f"residual before projection {proj.residual_before}"
    by_hand = float(np.max(np.abs(paper_residual_by_hand())))
    assert proj.residual_before == pytest.approx(by_hand, rel=1e-9, abs=0), \
        f"residual before projection {proj.residual_before!r} m vs {by_hand!r} m by hand"
    assert proj.residual_after <= 1e-14
    Lam = constraint_jacobian(paper, proj.q)
    assert np.max(np.abs(Lam @ proj.qd)) <= 1e-14
    # minimum norm: the correction lies in the row space of Λ at the starting point (no component
    # along the closed chain's own motion), up to the second-order Gauss–Newton update
    Lam0 = constraint_jacobian(paper, paper.q0)
    null = np.linalg.svd(Lam0)[2][Lam0.shape[0]:]
    assert np.max(np.abs(null @ proj.dq)) <= 1e-9 * np.max(np.abs(proj.dq))


def test_projection_fails_clearly_when_the_loop_cannot_close(paper):
    far = paper.q0.copy()
    far[3] += 2.5  # swing arm 2 away from its grasp
    with pytest.raises(ConstraintError, match="loop closure did not converge"):
        project_positions(paper, far, 1e-12, max_iter=5)


def test_baumgarte_term_combines_velocity_and_position_errors(paper):
    q = paper.q0
    lam_qd = np.array([1.0, 2.0, 3.0])
    expected = 2 * paper.integrator.baumgarte_alpha * lam_qd + paper.integrator.baumgarte_beta ** 2 * position_residual(paper, q)
    assert np.max(np.abs(baumgarte_term(paper, q, lam_qd) - expected)) <= 1e-15
    qd = project_velocities(paper, q, np.ones(paper.n_total))
    assert np.max(np.abs(constraint_jacobian(paper, q) @ qd)) <= 1e-14
