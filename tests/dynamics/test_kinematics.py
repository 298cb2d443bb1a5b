"""Stage 1 — kinematics against MuJoCo's forward kinematics and Jacobians (mj_jac, mj_jacDot)."""

import numpy as np
import pytest

from coopsim.dynamics.kinematics import arm_frames, arm_pose, ee_bias_acceleration, ee_jacobian
from coopsim.io.scenario import load_scenario
from helpers import SCENARIOS, MujocoReference, random_states, rel_err

TOL_POSE = 1e-12  # m, dimensionless rotation entries
TOL_JAC = 1e-9    # relative


@pytest.mark.parametrize("scenario", ["paper", "spatial"])
def test_ee_pose_jacobian_and_bias_match_mujoco(scenario, request):
    model = request.getfixturevalue(scenario)
    ref = MujocoReference(model, with_object=False)
    worst = {"pose": 0.0, "J": 0.0, "Jdqd": 0.0, "com": 0.0}
    for q, qd in random_states(model, 20, seed=1):
        ref.set_state(q, qd)
        for m, (arm, sl) in enumerate(zip(model.arms, model.dof_slices)):
            pose = arm_pose(arm, q[sl])
            sid = ref.m.site(f"a{m}_ee").id
            worst["pose"] = max(worst["pose"], rel_err(pose.p_ee, ref.d.site_xpos[sid]),
                                rel_err(pose.R_ee, ref.d.site_xmat[sid].reshape(3, 3)))
            bodies = [ref.m.body(f"a{m}_l{i}").id for i in range(arm.n)]
            worst["com"] = max(worst["com"], rel_err(pose.c, ref.d.xipos[bodies]))
            J_ref, Jd_ref = ref.site_jacobian(f"a{m}_ee")
            worst["J"] = max(worst["J"], rel_err(ee_jacobian(pose), J_ref[:, sl]))
            worst["Jdqd"] = max(worst["Jdqd"], rel_err(ee_bias_acceleration(pose, qd[sl]), Jd_ref))
    assert worst["pose"] <= TOL_POSE, f"end-effector pose differs from MuJoCo's site by {worst['pose']:.3g}"
    assert worst["com"] <= TOL_POSE, f"link centres of mass differ from MuJoCo's xipos by {worst['com']:.3g}"
    assert worst["J"] <= TOL_JAC, f"EE Jacobian differs from mj_jac by {worst['J']:.3g}"
    assert worst["Jdqd"] <= TOL_JAC, f"J̇θ̇ differs from mj_jacDot by {worst['Jdqd']:.3g}"


def test_bias_acceleration_matches_finite_difference_of_jacobian(spatial):
    """J̇θ̇ = d/dt (J(θ(t))) θ̇ by central differences along θ(t) = θ + t θ̇ (step 1e-6 s)."""
    arm, sl = spatial.arms[0], spatial.dof_slices[0]
    worst = 0.0
    for q, qd in random_states(spatial, 20, seed=2):
        q, qd = q[sl], qd[sl]
        h = 1e-6
        dJ = (ee_jacobian(arm_pose(arm, q + h * qd)) - ee_jacobian(arm_pose(arm, q - h * qd))) / (2 * h)
        worst = max(worst, rel_err(ee_bias_acceleration(arm_pose(arm, q), qd), dJ @ qd))
    assert worst <= 1e-8, f"J̇θ̇ differs from the finite difference by {worst:.3g}"


@pytest.mark.parametrize("scenario", ["paper", "spatial", "gantry"])
def test_link_frames_over_samples_match_mujoco(scenario, request):
    """`arm_frames` (every sample at once, for the Foxglove /tf topic) against MuJoCo's body frames
    (xpos, xmat of the twin's link bodies), at 20 random configurations; revolute and prismatic."""
    model = (load_scenario(SCENARIOS / "gantry_prismatic.yaml") if scenario == "gantry"
             else request.getfixturevalue(scenario))
    ref = MujocoReference(model, with_object=False)
    Q = np.array([q for q, _ in random_states(model, 20, seed=3)])
    worst = 0.0
    for m, (arm, sl) in enumerate(zip(model.arms, model.dof_slices)):
        p, R = arm_frames(arm, Q[:, sl])
        bodies = [ref.m.body(f"a{m}_l{i}").id for i in range(arm.n)]
        for k, q in enumerate(Q):
            ref.set_state(q, np.zeros(model.n_total))
            worst = max(worst, rel_err(p[k], ref.d.xpos[bodies]), rel_err(R[k], ref.d.xmat[bodies].reshape(-1, 3, 3)))
    assert worst <= TOL_POSE, f"link frames differ from MuJoCo's body frames by {worst:.3g}"
