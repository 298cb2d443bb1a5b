"""Stage 5 — the loop-closure manifold: consistent initial conditions and constraint stabilization.

Positions are projected by Gauss–Newton steps of minimum norm, Δθ = −Λ⁺ Φ(θ) (Λ⁺ the
Moore–Penrose inverse, so redundant or rank-deficient rows are harmless), velocities by
θ̇ ← θ̇ − Λ⁺ Λ θ̇. Baumgarte stabilization instead adds 2αΛθ̇ + β²Φ to the acceleration constraint.
"""

from __future__ import annotations

import numpy as np

from coopsim.dynamics.closed_chain import _constraints, arm_poses, carrier_object, grasp_offsets, position_residual
from coopsim.core.errors import ConstraintError
from coopsim.dynamics.grasp import grasp_matrix_inv_T
from coopsim.dynamics.kinematics import ee_jacobian
from coopsim.core.model import Model
from coopsim.core.results import Projection


def constraint_jacobian(model: Model, q: np.ndarray) -> np.ndarray:
    """The velocity-level loop-closure Jacobian Λ at q (eq. 23: Λ θ̇ = 0 on the closed chain).

    Args:
        model: the Model.
        q: (n,) rad (m on a prismatic joint), stacked joint coordinates.

    Returns:
        np.ndarray: (k(r−1), n) Λ, k constraint rows (model.rows) for each arm but the carrier, world
            axes (rows of m/s and rad/s per unit joint rate).
    """
    poses = arm_poses(model, q)
    c = model.object.carrier
    s = grasp_offsets(model, carrier_object(model, poses))
    J = [ee_jacobian(p) for p in poses]
    J_o = grasp_matrix_inv_T(s[c]) @ J[c]
    zeros = np.zeros((model.r, 6))
    return _constraints(model, J, zeros, J_o, np.zeros(6), np.zeros(3), s)[0]


def project_positions(model: Model, q: np.ndarray, tol: float, max_iter: int = 50) -> tuple[np.ndarray, int]:
    """Gauss–Newton projection of q onto Φ(q) = 0 to max |Φ| <= tol.

    Minimum-norm steps Δθ = −Λ⁺ Φ(θ) (module docstring).

    Args:
        model: the Model.
        q: (n,) rad (m on a prismatic joint), stacked joint coordinates (not modified).
        tol: m and rad, the tolerance on max |Φ|.
        max_iter: the most Gauss–Newton steps taken.

    Returns:
        tuple[np.ndarray, int]: (the projected q (n,), the number of Gauss–Newton steps taken).

    Raises:
        ConstraintError: the projection does not converge (an unreachable grasp or a singular loop).
    """
    q = q.copy()
    for it in range(max_iter + 1):
        phi = position_residual(model, q)
        if np.max(np.abs(phi)) <= tol:
            return q, it
        if it == max_iter:
            break
        dq = np.linalg.lstsq(constraint_jacobian(model, q), phi, rcond=None)[0]
        q -= dq
    raise ConstraintError(f"loop closure did not converge: max |Φ| = {np.max(np.abs(phi)):.3g} after "
                          f"{max_iter} Gauss–Newton steps at q = {np.array2string(q, precision=6)}")


def project_velocities(model: Model, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
    """Minimum-norm correction of qd onto Λ(q) θ̇ = 0: θ̇ ← θ̇ − Λ⁺ Λ θ̇.

    Args:
        model: the Model.
        q: (n,) rad (m on a prismatic joint), stacked joint coordinates.
        qd: (n,) rad/s (m/s), stacked joint rates (not modified).

    Returns:
        np.ndarray: (n,) rad/s (m/s), the corrected joint rates.
    """
    Lam = constraint_jacobian(model, q)
    return qd - np.linalg.lstsq(Lam, Lam @ qd, rcond=None)[0]


def consistent_state(model: Model, q: np.ndarray, qd: np.ndarray) -> Projection:
    """Project (q, qd) onto the manifold (positions, then velocities) and report the correction.

    Positions to model.integrator.projection_tol (`project_positions`), then velocities
    (`project_velocities`).

    Args:
        model: the Model.
        q: (n,) rad (m on a prismatic joint), stacked joint coordinates (not modified).
        qd: (n,) rad/s (m/s), stacked joint rates (not modified).

    Returns:
        Projection: the consistent state, the corrections, max |Φ| before and after, the Gauss–Newton
            steps.

    Raises:
        ConstraintError: the position projection does not converge.
    """
    before = float(np.max(np.abs(position_residual(model, q))))
    q_new, it = project_positions(model, q, model.integrator.projection_tol)
    qd_new = project_velocities(model, q_new, qd)
    after = float(np.max(np.abs(position_residual(model, q_new))))
    return Projection(q_new, qd_new, q_new - q, qd_new - qd, before, after, it)


def baumgarte_term(model: Model, q: np.ndarray, Lam_qd: np.ndarray) -> np.ndarray:
    """2α Λθ̇ + β² Φ: the stabilising right-hand side of Baumgarte's method.

    Λθ̈ = −Λ̇θ̇ − (2α Λθ̇ + β² Φ), with α, β model.integrator.baumgarte_alpha, baumgarte_beta.

    Args:
        model: the Model.
        q: (n,) rad (m on a prismatic joint), stacked joint coordinates.
        Lam_qd: (k(r−1),) Λθ̇ at the state (m/s and rad/s rows).

    Returns:
        np.ndarray: (k(r−1),) m/s² and rad/s² rows, the term added to the acceleration constraint.
    """
    s = model.integrator
    return 2.0 * s.baumgarte_alpha * Lam_qd + s.baumgarte_beta ** 2 * position_residual(model, q)

