"""The joint model (coopsim.core.joints): prismatic joints beside revolute ones, end to end.

Against MuJoCo's own algorithms (the twin built with slide joints): link frames ≤ 1e-12 m, each open arm's
mass matrix (mj_fullM) and bias forces (qfrc_bias) ≤ 1e-10 relative, end-effector Jacobians, J̇θ̇ and the
whole J̇ of `point_jacobian_rate` (mj_jac, mj_jacDot) ≤ 1e-12, closed-chain accelerations against the KKT
solve built from MuJoCo's open chain ≤ 1e-9 relative — both engines, on the bundled `gantry_prismatic`
(prismatic first joints, planar, gravity in the plane) and on `spatial_6r_pair` with joints 3 and 5 of each
arm made prismatic (spatial: a prismatic joint behind a turning link, whose Coriolis term 2ω × zθ̇ the planar
scene never exercises). Compiled against reference ≤ 1e-12 relative (the bundled scenario is also in
tests/compiled/test_compiled.py, tests/cross/test_independent.py (Pinocchio), tests/twin/test_harness.py (twin
agreement and a wrong twin), tests/cross/test_inverse_mujoco.py and tests/inverse/test_capacity.py, which
cover every bundled scenario). Inverse dynamics replay, capacities on the force–speed lines of the prismatic
motors, and the scenario's one-line refusals.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import yaml

from coopsim.dynamics.closed_chain import chain_terms, forward_dynamics
from coopsim.compiled import api
from coopsim.dynamics.gibbs_appell import bias_forces, mass_matrix
from coopsim.report.inverse_report import capacity_study, inverse_study
from coopsim.core.joints import joint_units
from coopsim.dynamics.kinematics import arm_pose, ee_bias_acceleration, ee_jacobian, point_jacobian_rate, reach_check
from coopsim.core.model import PRISMATIC, REVOLUTE
from coopsim.io.scenario import load_scenario, model_from_dict
from coopsim.core.errors import ScenarioError
from helpers import (SCENARIOS, MujocoReference, consistent_states, mujoco_kkt_acceleration, mutated,
                      rel_err)
from helpers import assert_compiled_terms_match_the_reference

GANTRY_FILE = SCENARIOS / "gantry_prismatic.yaml"
GANTRY = yaml.safe_load(GANTRY_FILE.read_text())


def _spatial_with_prismatic() -> dict:
    """spatial_6r_pair with joints 3 and 5 of each arm prismatic (their initial values read as m)."""
    data = yaml.safe_load((SCENARIOS / "spatial_6r_pair.yaml").read_text()) | {"name": "spatial_prismatic"}
    for arm in data["arms"]:
        for i in (2, 4):
            arm["links"][i].setdefault("joint", {})["type"] = "prismatic"
    return data


@pytest.fixture(scope="module", params=["gantry", "spatial"])
def scene(request):
    if request.param == "gantry":
        return load_scenario(GANTRY_FILE)
    return model_from_dict(_spatial_with_prismatic())


def test_scenes_hold_both_joint_types(scene):
    types = scene.joint_type
    assert np.any(types == PRISMATIC) and np.any(types == REVOLUTE)
    if scene.name == "gantry_prismatic":    # revolute axes along y, the rail along x and the lift along z
        assert scene.plane is not None and abs(scene.plane[2] @ [0.0, 1.0, 0.0]) == pytest.approx(1.0, abs=1e-15)
    else:
        assert scene.name == "spatial_prismatic" and scene.plane is None


def test_open_arms_equal_mujocos_algorithms(scene):
    """Link frames, J, J̇θ̇, I_m and h of each open arm, both engines, against MuJoCo (slide joints)
    at 8 random states (coordinates q0 + N(0, 0.5²) rad or m, rates N(0, 1))."""
    ref = MujocoReference(scene, with_object=False)
    kinds = ref.m.jnt_type[[ref.m.joint(f"a{m}_j{i}").id for m, a in enumerate(scene.arms) for i in range(a.n)]]
    assert np.array_equal(kinds == mujoco.mjtJoint.mjJNT_SLIDE, scene.joint_type == PRISMATIC)
    rng = np.random.default_rng(5)
    worst = {}

    def add(name, err):
        worst[name] = max(worst.get(name, 0.0), err)

    for _ in range(8):
        q, qd = scene.q0 + rng.normal(scale=0.5, size=scene.n_total), rng.normal(size=scene.n_total)
        ref.set_state(q, qd)
        M, h = ref.mass_matrix(), ref.bias()
        W = api.chain_terms(scene, q, qd)
        for m, (arm, sl) in enumerate(zip(scene.arms, scene.dof_slices)):
            pose = arm_pose(arm, q[sl])
            bodies = [ref.m.body(f"a{m}_l{i}").id for i in range(arm.n)]
            add("link origins", float(np.max(np.abs(pose.p - ref.d.xpos[bodies]))))
            add("link frames", float(np.max(np.abs(pose.R - ref.d.xmat[bodies].reshape(-1, 3, 3)))))
            J, Jd_qd = ref.site_jacobian(f"a{m}_ee")
            add("J̇ (reference)", rel_err(point_jacobian_rate(pose, pose.p_ee_rel, qd[sl]),
                                          ref.site_jacobian_and_rate(f"a{m}_ee")[1][:, sl]))
            n = arm.n
            for engine, (Mm, hm, Jm, Jdm) in {
                    "reference": (mass_matrix(arm, pose), bias_forces(arm, pose, qd[sl], scene.gravity),
                                  ee_jacobian(pose), ee_bias_acceleration(pose, qd[sl])),
                    "compiled": (W.Mb[sl, :n], W.h_arm[sl], W.J[m, :, :n], W.Jd_qd[m])}.items():
                if not (engine == "compiled" and m == scene.object.carrier):   # W.Mb holds the object there
                    add(f"mass matrix ({engine})", rel_err(Mm, M[sl, sl]))
                add(f"bias forces ({engine})", rel_err(hm, h[sl]))
                add(f"Jacobian ({engine})", rel_err(Jm, J[:, sl]))
                add(f"J̇θ̇ ({engine})", rel_err(Jdm, Jd_qd))
    tol = {"mass matrix": 1e-10, "bias forces": 1e-10}
    bad = {k: v for k, v in worst.items() if v > tol.get(k.split(" (")[0], 1e-12)}
    assert not bad, f"{scene.name}: against MuJoCo: {bad}"


def test_closed_chain_accelerations_equal_the_mujoco_kkt_solve(scene):
    """θ̈ of both engines against [M Gᵀ; G 0] built from MuJoCo's open chain (object on its carrier),
    at 6 random consistent states with N(0, 2²) efforts: ≤ 1e-9 relative (max |Δ| / max |θ̈_ref|)."""
    ref = MujocoReference(scene, with_object=True)
    rng = np.random.default_rng(6)
    worst = {"reference": 0.0, "compiled": 0.0}
    for q, qd in consistent_states(scene, 6, seed=7):
        tau = rng.normal(scale=2.0, size=scene.n_total)
        qdd_ref = mujoco_kkt_acceleration(scene, ref, q, qd, tau)
        scale = np.max(np.abs(qdd_ref))
        for engine, qdd in (("reference", forward_dynamics(scene, chain_terms(scene, q, qd), tau).qdd),
                            ("compiled", api.forward(scene, q, qd, tau).qdd)):
            worst[engine] = max(worst[engine], float(np.max(np.abs(qdd - qdd_ref))) / scale)
    assert max(worst.values()) <= 1e-9, f"{scene.name}: θ̈ against MuJoCo's KKT solve: {worst}"


def test_compiled_terms_equal_the_reference_behind_a_turning_link():
    """The spatial scene with prismatic joints 3 and 5 (the bundled gantry: tests/compiled/test_compiled.py)."""
    assert_compiled_terms_match_the_reference(model_from_dict(_spatial_with_prismatic()), 5)


# ------------------------------------------------------------------------------ inverse, capacity
@pytest.fixture(scope="module")
def gantry():
    return load_scenario(GANTRY_FILE)


def test_inverse_dynamics_replays_the_gantry_run(gantry):
    """Each resolution's efforts (N on the axes, N·m on the revolute joints), fed back through the
    forward dynamics, reproduce the 1 s trajectory: ≤ 1e-10 (rad or m), rates ≤ 1e-9. Measured
    2.3e-13 and 2.9e-13, 2.4e-12 and 3.3e-12 (a regression pin of the accuracy)."""
    study = inverse_study(gantry, methods=("paper", "min_energy"), with_replay=True, curve=False)
    for k, r in study.replays.items():
        assert r.max_angle_error <= 1e-10 and r.max_rate_error <= 1e-9, (k, r.max_angle_error, r.max_rate_error)


def test_capacity_with_force_limits_on_the_linear_axes(gantry):
    """DLCC of the gantry's 1 s run. The lift's motor line is a force against a speed, written here from
    the scenario's numbers (150 N stall force, 1.5 m/s no-load speed), and the non-squeezing
    resolution's force at its capacity lies on it at the saturation time. Capacities are regression pins
    (numbers coopsim produced, rel 1e-6): 7.07688 (paper's W⁺, arm 1 joint 3 on τ_min at 1 s),
    10.2841 (non-squeezing, the lift on f_max at 0.54 s), 5.88011 (minimum energy, arm 1 joint 3 at
    0.5 s), LP bound 18.4418 kg (the lift at 0.5 s); the brute-force check agrees."""
    study = capacity_study(gantry, optimise=False, check=True)
    caps = {k: c for (k, _), c in study.caps.items()}
    pins = {"paper": (7.0768809, 2, 1.0, "lower"), "nonsqueezing": (10.2841253, 3, 0.54, "upper"),
            "min_energy": (5.8801060, 2, 0.5, "lower")}
    for k, (mass, joint, time, side) in pins.items():
        c = caps[k]
        assert (c.mass, c.joint, c.time, c.side) == (pytest.approx(mass, rel=1e-6), joint, pytest.approx(time), side), k
    lp = study.lp["scaled"]
    assert (lp.mass, lp.joint, lp.time) == (pytest.approx(18.4417999, rel=1e-6), 3, pytest.approx(0.5))
    assert all(v["ok"] for v in study.checks.values()), study.checks
    lift = GANTRY["arms"][1]["motors"]
    stall, speed = lift["stall_torque"][0], lift["no_load_speed"][0]
    c, j = caps["nonsqueezing"], 3
    v = study.traj.qd[c.sample, j]                                            # m/s
    assert gantry.joint_type[j] == PRISMATIC and joint_units(PRISMATIC) == ("m", "m/s", "N")
    assert study.tau_at["nonsqueezing", "scaled"][c.sample, j] == pytest.approx(stall * (1 - v / speed), rel=1e-9)


# --------------------------------------------------------------------------------- the scenario
def _error(data) -> str:
    with pytest.raises(ScenarioError) as exc:
        model_from_dict(data)
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


def test_degrees_are_refused_where_a_prismatic_joint_would_read_them():
    init = GANTRY["arms"][0]["initial"]
    deg = mutated(GANTRY, ["arms", 0, "initial"], {"angles_deg": init["angles"]})
    assert _error(deg) == ("<scenario>: arms[0].initial.angles_deg: joint 1 is prismatic (m): give angles "
                           "in rad and m, not angles_deg")
    rates = mutated(GANTRY, ["arms", 1, "initial"], {**init, "rates_deg": [1.0, 2.0, 3.0]})
    assert _error(rates) == ("<scenario>: arms[1].initial.rates_deg: joint 1 is prismatic (m/s): give rates "
                             "in rad/s and m/s, not rates_deg")
    motion = {"trajectory": "object_motion", "object_motion": {
        "initial_guess_deg": [0.0] * 6, "waypoints": [{"time": 0.0, "position": [0.0, 0.0, 0.5]},
                                                      {"time": 1.0, "position": [0.1, 0.0, 0.5]}]}}
    assert _error(mutated(GANTRY, ["inverse"], motion)) == (
        "<scenario>: inverse.object_motion.initial_guess_deg: arm 'gantry' joint 1 is prismatic (m): give "
        "initial_guess in rad and m, not initial_guess_deg")


def test_unknown_joint_type_is_refused():
    bad = mutated(GANTRY, ["arms", 0, "links", 1, "joint", "type"], "helical")
    assert _error(bad) == ("<scenario>: arms[0].links[1].joint.type: must be one of revolute, prismatic; "
                           "got 'helical'")


def test_a_long_slide_is_not_taken_for_degrees():
    """Over 2π m on a prismatic joint is a coordinate, not a misread angle; 7 rad on a revolute one is."""
    far = mutated(GANTRY, ["arms", 0, "initial", "angles"], [7.0, 1.784505, -1.633337])
    assert model_from_dict(far).q0[0] == 7.0
    wrong = mutated(GANTRY, ["arms", 0, "initial", "angles"], [0.1, 7.0, -1.633337])
    assert _error(wrong) == ("<scenario>: arms[0].initial.angles: joint 2 at 7 rad is more than a turn, a whole number "
                             "of radians: degrees? use angles_deg")


def test_a_slides_range_is_in_metres():
    """A prismatic joint's `range` is in m (no turn check, no `range_deg`): kept, and checked at the
    initial coordinate in m."""
    rail = ["arms", 0, "links", 0, "joint"]
    ranged = mutated(GANTRY, rail + ["range"], [-7.0, 8.0])
    assert model_from_dict(ranged).joint_range[0].tolist() == [-7.0, 8.0]
    assert _error(mutated(GANTRY, rail + ["range"], [0.2, 0.5])) == (
        "<scenario>: arms[0].initial.angles: joint 1 at 0.1 m is outside its range [0.2, 0.5] m")
    assert _error(mutated(GANTRY, rail + ["range_deg"], [-10, 10])) == (
        "<scenario>: arms[0].links[0].joint.range_deg: the joint is prismatic (m): give range in m, not range_deg")


def test_plane_of_motion_takes_slides_across_the_normal():
    """A slide in the plane keeps the scene planar (3 rows per grasp); one along the normal makes it
    spatial (6 rows). An arm with a slide has no fixed reach."""
    assert model_from_dict(GANTRY).rows.shape == (3, 6)
    across = mutated(GANTRY, ["arms", 0, "links", 0, "joint", "axis"], [1, 1, 0])
    assert model_from_dict(across).rows.shape == (6, 6)
    assert reach_check(model_from_dict(GANTRY).arms[0], np.full(3, 1e3)).ok


def test_the_command_line_refuses_degrees_for_a_slide(tmp_path, capfd):
    from coopsim.cli import main

    init = GANTRY["arms"][0]["initial"]
    path = tmp_path / "g.yaml"
    path.write_text(yaml.safe_dump(mutated(GANTRY, ["arms", 0, "initial"], {"angles_deg": init["angles"]})))
    capfd.readouterr()
    assert main(["simulate", str(path)]) == 2
    err = capfd.readouterr().err.strip().splitlines()
    assert err == [f"coopsim: error: {path}: arms[0].initial.angles_deg: joint 1 is prismatic (m): give "
                   "angles in rad and m, not angles_deg"]


def test_units_follow_the_joint_types(gantry):
    """What a person reads names each joint's unit: the log records the joint types (plots take their
    axis units from them; a log without them is revolute), the agreement table takes its worst joint's
    unit, the text summary both."""
    from coopsim.twin.compare import _metric
    from coopsim.core.joints import COORDINATE, EFFORT, RATE, units_of
    from coopsim.core.labels import metadata_joint_types
    from coopsim.io.log import run_metadata

    meta = run_metadata(gantry)
    types = ["prismatic", "revolute", "revolute"] * 2
    assert metadata_joint_types(meta, 6) == types
    assert metadata_joint_types({"model": {}}, 2) == ["revolute"] * 2
    assert [units_of(types[:1], k) for k in (COORDINATE, RATE, EFFORT)] == ["m", "m/s", "N"]
    assert units_of(types[:3], COORDINATE) == "m or rad" and units_of(types[1:3], EFFORT) == "N·m"
    err = np.array([[0.0, 1e-9], [2e-9, 0.0]])
    assert _metric("joint angle error", ["m", "rad"], err, np.array([0.0, 1.0]), ["j1", "j2"], None).unit == "m"


def test_object_motion_ik_moves_the_slides():
    """Closed-chain inverse kinematics of a prescribed carry (0.3 s, the bar 6 cm along and 3 cm up,
    turned 0.1 rad): every sample puts the object where the motion says (the kinematics are MuJoCo's,
    test above), and the rail and the lift both move."""
    from coopsim.inverse.trajectory import object_motion_at, object_motion_trajectory, object_pose_of

    carry = {"trajectory": "object_motion", "object_motion": {"output_dt": 0.02, "waypoints": [
        {"time": 0.0, "position": [0.0, 0.0, 0.5]}, {"time": 0.3, "position": [0.06, 0.0, 0.53], "rpy": [0, 0.1, 0]}]}}
    model = model_from_dict(mutated(GANTRY, ["inverse"], carry))
    traj = object_motion_trajectory(model, model.inverse.object_motion)
    for t, q in zip(traj.t, traj.q):
        p, R, _, _ = object_motion_at(model.inverse.object_motion, t)
        p_C, R_o = object_pose_of(model, q)
        assert np.max(np.abs(p_C - p)) <= 1e-12 and np.max(np.abs(R_o - R)) <= 1e-12, t
    moved = np.abs(traj.q[-1] - traj.q[0])
    assert np.all(moved[model.joint_type == PRISMATIC] > 1e-3), moved
