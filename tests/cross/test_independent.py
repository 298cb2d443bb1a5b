"""Independent scenario check: every bundled scenario read by coopsim and, separately, by
`independent.pinocchio_scene` (PyYAML and the README's conventions only, built in Pinocchio, never
importing coopsim), compared quantity by quantity.

Tolerances: link and end-effector poses ≤ 1e-10 (m, and rotation-matrix entries); each arm's mass
matrix and bias forces (arms alone, and the carrier with the object) ≤ 1e-10 relative
(max |Δ| / max(1, max |reference|)); closed-chain accelerations and grasp wrenches at 10 random
consistent states (closed by Pinocchio-side Newton steps) ≤ 1e-9 relative (max |Δ| / max |reference|
over the state); 1 s of joint angles against scipy's DOP853 (rtol = atol = 1e-12) on
pinocchio.constraintDynamics ≤ 1e-9 rad. Both coopsim engines are compared where they expose the
quantity (reference stage modules; compiled workspace and samples).

Each check collects every violation with the quantity, scenario, arm and state it concerns; the
wrong-convention tests run the same checks against a builder switched to a wrong reading (rpy
composed Rx·Ry·Rz, quaternion read [x, y, z, w], box cross-section axes swapped, joint position
default at the frame origin) and require them to fail by a wide margin.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers import SCENARIOS
from independent.checks import (
    FILES,
    TOL_CHAIN,
    TOL_DYN,
    TOL_POSE,
    TOL_TRAJ,
    WIDE,
    Report,
    check_arm_dynamics,
    check_as_read,
    check_chain,
    check_poses,
    check_trajectory,
    consistent_states,
    coopsim_model,
    full_report,
    random_states,
    scene,
)
from independent.pinocchio_scene import Conventions


@pytest.fixture(scope="module", params=FILES, ids=lambda p: p.stem)
def scenario(request) -> Path:
    return request.param


def test_builder_reads_the_scene(scenario):
    """The builder's own sanity: joint order, the carrier the README names, the scene's plane."""
    model, S = coopsim_model(scenario), scene(scenario)
    assert S.n == model.n_total and S.r == model.r
    assert [a.name for a in S.arms] == [a.name for a in model.arms]
    data = yaml.safe_load(scenario.read_text())
    grasps = data["object"]["grasps"]
    first = 0 if grasps == "derive" else [a["name"] for a in data["arms"]].index(grasps[0]["arm"])
    assert S.carrier == first == model.object.carrier, f"carrier, scenario {model.name}"
    assert (S.normal is None) == (model.plane is None), f"planar or not, scenario {model.name}"
    if S.normal is not None:
        assert np.allclose(np.abs(S.normal @ model.plane[2]), 1.0, rtol=0, atol=1e-14)


def test_scenario_as_read(scenario):
    model, S = coopsim_model(scenario), scene(scenario)
    report = Report(model.name)
    check_as_read(model, S, report)
    report.check()


def test_link_and_end_effector_poses(scenario):
    model, S = coopsim_model(scenario), scene(scenario)
    report = Report(model.name)
    check_poses(model, S, [("initial", model.q0, model.qd0)] + random_states(S.n, 10, seed=8), report)
    report.check()


def test_arm_mass_matrices_and_bias_forces(scenario):
    model, S = coopsim_model(scenario), scene(scenario)
    report = Report(model.name)
    check_arm_dynamics(model, S, [("initial", model.q0, model.qd0)] + random_states(S.n, 10, seed=8), report)
    report.check()


def test_closed_chain_accelerations_and_grasp_wrenches(scenario):
    model, S = coopsim_model(scenario), scene(scenario)
    report = Report(model.name)
    check_chain(model, S, consistent_states(S, 10, seed=9), report)
    report.check()


def test_one_second_trajectory(scenario):
    model, S = coopsim_model(scenario), scene(scenario)
    report = Report(model.name)
    check_trajectory(scenario, S, report)
    report.check()


# ------------------------------------------------------------------------- wrong conventions
SPATIAL = SCENARIOS / "spatial_6r_pair.yaml"
PAPER = SCENARIOS / "paper_planar_2x3.yaml"


def _fails_widely(report: Report, quantity: str, tol: float):
    assert report.failures, f"a wrong convention went unnoticed in {report.scenario}"
    assert report.max(quantity) > WIDE * tol, (
        f"{quantity}: a wrong convention misses by only {report.max(quantity):.3g} (tolerance {tol:g})")


def test_rpy_read_as_rx_ry_rz_is_caught():
    """spatial_6r_pair's object pose rpy [0.5708, 0, 0.0997] (grasps derived from it): composed as
    Rx·Ry·Rz it turns the bar's inertia, which the accelerations, wrenches and trajectory notice."""
    report = full_report(SPATIAL, Conventions(rpy_order="xyz"), states_from=scene(SPATIAL))
    _fails_widely(report, "closed-chain accelerations (compiled)", TOL_CHAIN)
    _fails_widely(report, "grasp wrench (compiled)", TOL_CHAIN)
    _fails_widely(report, "joint angles over 1 s", TOL_TRAJ)


def test_cross_section_axes_swapped_is_caught():
    report = Report("spatial_6r_pair")
    check_arm_dynamics(coopsim_model(SPATIAL), scene(SPATIAL, Conventions(cross_section="zy")),
                       random_states(12, 10, seed=8), report)
    _fails_widely(report, "mass matrix, arm alone (reference)", TOL_DYN)


def test_joint_position_default_at_the_origin_is_caught():
    report = Report("paper_planar_2x3")
    check_poses(coopsim_model(PAPER), scene(PAPER, Conventions(joint_default="origin")),
                random_states(6, 10, seed=8), report)
    _fails_widely(report, "link position (reference)", TOL_POSE)
    _fails_widely(report, "end-effector position (compiled)", TOL_POSE)


def _variant(tmp_path: Path, base: Path, edit) -> Path:
    data = yaml.safe_load(base.read_text())
    edit(data)
    out = tmp_path / f"{base.stem}_variant.yaml"
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return out


def _with_quaternions(data):
    """spatial_6r_pair with its bases and one joint frame given as quaternions [w, x, y, z]."""
    left, right = data["arms"]
    left["base"] = {"position": left["base"]["position"], "quat": [0.0, 1.0, 0.0, 0.0]}     # π about x
    right["base"] = {"position": right["base"]["position"], "quat": [0.0, 0.0, 1.0, 0.0]}   # π about y
    c, s = np.cos(0.2), np.sin(0.2)
    left["links"][3]["joint"]["quat"] = [float(c), 0.0, float(0.6 * s), float(0.8 * s)]


def test_quaternions_are_read_wxyz(tmp_path):
    """A variant of spatial_6r_pair using `quat`: every check passes read as [w, x, y, z] and the
    poses fail read as [x, y, z, w]."""
    path = _variant(tmp_path, SPATIAL, _with_quaternions)
    full_report(path, trajectory=False).check()
    wrong = Report("spatial_6r_pair with quaternions")
    check_poses(coopsim_model(path), scene(path, Conventions(quat_order="xyzw")),
                random_states(12, 10, seed=8), wrong)
    _fails_widely(wrong, "link rotation (reference)", TOL_POSE)


def _other_keys(tmp_path: Path):
    """The paper scene rewritten with keys no bundled scenario uses: an `inertial` link (inertia as
    [Ixx, Iyy, Izz, Ixy, Ixz, Iyz], com off the axis), a box `size`, explicit `end_effector` frames
    (one turned), an explicit joint `position`, rates in deg/s, a csv torque, grasps listed
    carrier-last (so arm2 carries the object)."""
    def edit(data):
        a1, a2 = data["arms"]
        a1["links"][2] = {"joint": {"axis": [0, 0, 1], "position": [0.6, 0.0, 0.0]},
                          "inertial": {"mass": 0.7, "com": [0.03, 0.004, 0.0],
                                       "inertia": [2.0e-4, 6.0e-4, 7.0e-4, 1.0e-5, 0.0, 0.0]}}
        a1["end_effector"] = {"position": [0.05, 0.0, 0.0]}
        a1["initial"] = {"angles_deg": a1["initial"]["angles_deg"], "rates_deg": [6.0, -3.0, 2.0]}
        a1["torque"] = {"csv": "torque_arm1.csv"}
        a2["links"][1]["box"] = {"size": [0.6, 0.04, 0.05], "density": 7850}
        a2["end_effector"] = {"position": [0.05, 0.0, 0.0], "rpy_deg": [0, 0, 10]}
        data["object"]["grasps"] = [{"arm": "arm2", "position": [0.2, 0.0, 0.0], "rpy_deg": [0, 0, 190]},
                                    {"arm": "arm1", "position": [-0.2, 0.0, 0.0], "rpy_deg": [0, 0, 0]}]
    (tmp_path / "torque_arm1.csv").write_text("time,tau1,tau2,tau3\n0.0,0.5,-0.02,0.0\n0.4,0.3,0.05,-0.01\n"
                                              "1.0,0.6,0.0,0.01\n")
    return _variant(tmp_path, PAPER, edit)


def test_keys_the_bundled_scenarios_do_not_use(tmp_path):
    path = _other_keys(tmp_path)
    S = scene(path)
    assert S.carrier == 1 == coopsim_model(path).object.carrier
    full_report(path).check()
