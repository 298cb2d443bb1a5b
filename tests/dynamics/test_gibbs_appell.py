"""Stage 2 — recursive Gibbs–Appell arm dynamics against MuJoCo (mj_fullM, qfrc_bias) and itself."""

import numpy as np
import pytest

from coopsim.dynamics.gibbs_appell import bias_forces, gibbs_gradient, mass_matrix
from coopsim.dynamics.kinematics import arm_pose
from helpers import MujocoReference, random_states, rel_err

TOL = 1e-10  # relative to max(1, |reference|)


@pytest.mark.parametrize("scenario", ["paper", "spatial"])
def test_mass_matrix_and_bias_match_mujoco(scenario, request):
    model = request.getfixturevalue(scenario)
    ref = MujocoReference(model, with_object=False)
    worst_M, worst_h = 0.0, 0.0
    for q, qd in random_states(model, 20, seed=3):
        ref.set_state(q, qd)
        M_ref, h_ref = ref.mass_matrix(), ref.bias()
        for arm, sl in zip(model.arms, model.dof_slices):
            pose = arm_pose(arm, q[sl])
            worst_M = max(worst_M, rel_err(mass_matrix(arm, pose), M_ref[sl, sl]))
            worst_h = max(worst_h, rel_err(bias_forces(arm, pose, qd[sl], model.gravity), h_ref[sl]))
    assert worst_M <= TOL, f"mass matrix I_m differs from mj_fullM by {worst_M:.3g} (relative)"
    assert worst_h <= TOL, f"bias forces −Re_m differ from qfrc_bias by {worst_h:.3g} (relative)"


def test_gibbs_gradient_is_affine_in_acceleration_with_the_mass_matrix(spatial):
    """∂S/∂θ̈(θ̈) − ∂S/∂θ̈(0) = I_m θ̈: the backward recursion against the Hessian of S."""
    worst = 0.0
    rng = np.random.default_rng(4)
    for q, qd in random_states(spatial, 20, seed=4):
        for arm, sl in zip(spatial.arms, spatial.dof_slices):
            pose = arm_pose(arm, q[sl])
            qdd = rng.normal(size=arm.n)
            lhs = gibbs_gradient(arm, pose, qd[sl], qdd, spatial.gravity) - bias_forces(arm, pose, qd[sl], spatial.gravity)
            worst = max(worst, rel_err(lhs, mass_matrix(arm, pose) @ qdd))
    assert worst <= 1e-12, f"Gibbs gradient and mass matrix disagree by {worst:.3g}"


def test_mass_matrix_is_symmetric_positive_definite(paper):
    for q, _ in random_states(paper, 20, seed=5):
        for arm, sl in zip(paper.arms, paper.dof_slices):
            M = mass_matrix(arm, arm_pose(arm, q[sl]))
            assert np.max(np.abs(M - M.T)) <= 1e-15 * np.max(np.abs(M))
            assert np.linalg.eigvalsh(M)[0] > 0
