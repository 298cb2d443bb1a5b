"""Arms from robot files (`coopsim/io/robots.py`).

Independent checks: each arm read from a URDF is compared with the same chain built by Pinocchio's own
URDF parser (`independent.pinocchio_urdf`: buildModelFromUrdf, every joint off the chain locked by
buildReducedModel): link and end-effector poses ≤ 1e-10, each arm's mass matrix and bias forces ≤ 1e-10
relative (max |Δ| / max(1, max |reference|)), and for the bundled robot scenarios and a pair of arms
with a URDF prismatic joint (tests/data/robots/slide.urdf) the closed-chain accelerations and grasp
wrenches at 10 random consistent states (closed by Pinocchio-side Newton steps) ≤ 1e-9 relative
(test_independent's checks). An MJCF file whose joints sit off their bodies'
origins reads the same as the URDF written with each link frame at its joint (≤ 1e-15). The inertials,
read from the parsed file, are MuJoCo's own compile of them where MuJoCo compiles the file (≤ 1e-14
relative); links off the chain whose inertials MuJoCo refuses (tests/data/robots/bad_inertia.urdf, TIAGo
dual's and PR2's URDFs) do not stop it, and the chain reads as Pinocchio reads it. The bundled robot
scenarios pass `coopsim validate`'s checks (their own thresholds) over their first 0.1 s. Every refused
robot file or chain gets one line naming the scenario field and the element: among them a used link
whose inertial no rigid body has, and a chain joint coupled by a mimic joint (tests/data/robots/mimic.urdf).
A continuous joint may be given past a turn in rad.

The bundled robots come from the optional example-robot-data package: their tests skip without it.
The small robots under tests/data/robots/ need nothing beyond the test extra.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml

from coopsim.io import robots
from coopsim.dynamics.closed_chain import arm_poses
from coopsim.twin.harness import cross_validate
from coopsim.io.foxglove import link_frame_names, native_link_poses, scene_update
from coopsim.twin.mjcf import build_spec, qpos_address, static_settings
from coopsim.core.model import PRISMATIC, REVOLUTE
from coopsim.io.robots import ROBOTS, read_chain, robot_file, robots_folder
from coopsim.io.scenario import load_scenario, model_from_dict
from coopsim.core.errors import ScenarioError
from coopsim.core.spatial import quat_to_rot
from helpers import ROOT, SCENARIOS, mutated
from independent.pinocchio_urdf import RobotScene
from independent.checks import Report, check_arm_dynamics, check_chain, check_poses, consistent_states, random_states

DATA = ROOT / "tests" / "data" / "robots"
ROBOT_SCENARIOS = sorted((SCENARIOS / "robots").glob("*.yaml"))
needs_robots = pytest.mark.skipif(robots_folder() is None,
                                  reason="example-robot-data is not installed: pip install 'coopsim[robots]'")


def bundled(name: str):
    """A bundled robot's (file, base, tip, lock), for the Pinocchio builder."""
    r = ROBOTS[name]
    return robot_file(name), r.base, r.tip, r.lock


# ------------------------------------------------------------------------------ bundled robots
@pytest.fixture(scope="module", params=ROBOT_SCENARIOS, ids=lambda p: p.stem)
def robot_scenario(request) -> Path:
    if robots_folder() is None:
        pytest.skip("example-robot-data is not installed: pip install 'coopsim[robots]'")
    return request.param


def test_bundled_robot_scenarios_exist():
    assert {p.stem for p in ROBOT_SCENARIOS} >= {"ur5_pair_box", "panda_pair_tray", "baxter_box"}


def test_bundled_scenario_against_pinocchio_urdf(robot_scenario):
    """Poses, arm dynamics and closed-chain accelerations and wrenches against Pinocchio's URDF parser."""
    model, S = load_scenario(robot_scenario), RobotScene(robot_scenario, bundled)
    assert S.n == model.n_total and S.normal is None and model.plane is None
    assert_agrees_with_pinocchio(model, S, seed=11)


def assert_agrees_with_pinocchio(model, S: RobotScene, seed: int):
    """Poses and arm dynamics at the initial and 10 random states, closed-chain accelerations and
    wrenches at 10 consistent states (seeds `seed`, `seed` + 1), within test_independent's tolerances."""
    report = _open_arms_report(model, S, seed)
    check_chain(model, S, consistent_states(S, 10, seed=seed + 1), report)
    report.check()
    assert report.max("closed-chain accelerations (compiled)") <= 1e-9


def _open_arms_report(model, S: RobotScene, seed: int) -> Report:
    """Poses and arm dynamics at the initial and 10 random states (seed `seed`) against Pinocchio's read of
    the same robot file (`independent.checks`), collected, not yet checked."""
    report = Report(model.name)
    open_states = [("initial", model.q0, model.qd0)] + random_states(S.n, 10, seed=seed)
    check_poses(model, S, open_states, report)
    check_arm_dynamics(model, S, open_states, report)
    return report


def test_bundled_scenario_twin_agrees(robot_scenario):
    """`coopsim validate` on the first 0.1 s: the MuJoCo twin (built from the same model) within the
    scenario's own thresholds."""
    cv = cross_validate(load_scenario(robot_scenario), duration=0.1)
    assert cv.comparison.passed, cv.comparison.failures()


@needs_robots
@pytest.mark.parametrize("name", sorted(ROBOTS))
def test_every_listed_robot_reads(name):
    chain = read_chain(*bundled(name))
    assert chain.n == {"panda": 7, "xarm7": 7, "baxter_left": 7, "baxter_right": 7, "tiago_dual_left": 7,
                       "tiago_dual_right": 7, "pr2_left": 7, "pr2_right": 7, "so100": 5,
                       "so101": 5}.get(name, 6)
    assert np.all(chain.links.link_mass > 0) and np.all(np.isfinite(chain.effort)) and np.all(np.isfinite(chain.velocity))


@needs_robots
def test_urdf_limits_become_the_motor_lines():
    """ur5_robot.urdf: <limit effort> 150 N·m (shoulder, elbow) and 28 (wrist), velocity 3.15 and 3.2 rad/s."""
    model = load_scenario(SCENARIOS / "robots" / "ur5_pair_box.yaml")
    assert model.motors.stall_torque.tolist() == [150.0] * 3 + [28.0] * 3 + [150.0] * 3 + [28.0] * 3
    assert model.motors.no_load_speed.tolist() == [3.15] * 3 + [3.2] * 3 + [3.15] * 3 + [3.2] * 3
    assert model.joint_range[2].tolist() == [-3.14159265359, 3.14159265359]


def test_missing_extra_names_the_robot_and_the_extra(monkeypatch):
    monkeypatch.setattr(robots, "robots_folder", lambda: None)
    with pytest.raises(ScenarioError) as err:
        load_scenario(SCENARIOS / "robots" / "ur5_pair_box.yaml")
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.endswith("arms[0].robot: robot 'ur5' comes from the example-robot-data package, which is not "
                        "installed: pip install 'coopsim[robots]'")


# ------------------------------------------------------------------------------ small robots
TINY = {
    "name": "tiny_pair", "duration": 0.1,
    "arms": [
        {"name": "left", "file": "tiny.urdf", "chain": {"base": "world", "tip": "tool", "lock": ["finger_joint"]},
         "base": {"position": [0.0, 0.0, 0.0]}, "initial": {"angles": [0.3, 0.9, 0.4]}},
        {"name": "right", "file": "tiny.urdf", "chain": {"base": "world", "tip": "tool", "lock": ["finger_joint"]},
         "base": {"position": [0.8, 0.1, 0.0], "rpy_deg": [0, 0, 180]},
         "end_effector": {"position": [0.0, 0.01, 0.02], "rpy": [0.1, 0.0, 0.2]},
         "initial": {"angles": [-0.2, 1.1, -0.5]}},
    ],
    "object": {"box": {"size": [0.2, 0.05, 0.05], "density": 500}, "grasps": "derive"},
}


@pytest.fixture
def tiny_dir(tmp_path) -> Path:
    for name in ("tiny.urdf", "anchor.urdf", "anchor.xml", "bad_inertia.urdf", "mimic.urdf"):
        shutil.copy(DATA / name, tmp_path / name)
    return tmp_path


def _write(folder: Path, data: dict) -> Path:
    path = folder / "scenario.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_meshes_are_not_needed():
    """The test robots name mesh files that do not exist: they are read all the same."""
    assert not (DATA / "meshes").exists() and not (DATA / "no_such_mesh.stl").exists()
    assert "meshes/link1.dae" in (DATA / "tiny.urdf").read_text()
    assert read_chain(DATA / "tiny.urdf", "base_link", "tool", ["finger_joint"]).n == 3
    assert read_chain(DATA / "anchor.xml", "base", "tip").n == 2

def _open_arms_agree_with_pinocchio(path, seed: int):
    """The scenario at `path`, its open arms checked against Pinocchio (`_open_arms_report`); the model."""
    model = load_scenario(path)
    _open_arms_report(model, RobotScene(path), seed).check()
    return model



def test_small_robot_against_pinocchio_urdf(tiny_dir):
    """tiny.urdf: a fixed mount, rpy origins, an inertial turned off its link axes, a continuous joint, an
    axis (0.6, 0, 0.8), fixed links on the chain (flange) and off it (cover), a locked finger, a tool
    frame past the flange, an end-effector offset: poses and arm dynamics as Pinocchio reads the URDF."""
    path = _write(tiny_dir, TINY)
    model = _open_arms_agree_with_pinocchio(path, seed=13)
    # what the file says comes along: joint ranges (continuous: none), effort and velocity limits
    assert model.joint_range[:3].tolist() == [[-2.0, 2.5], [-np.inf, np.inf], [-3.0, 3.0]]
    assert model.motors.stall_torque[:3].tolist() == [40.0, 25.0, 12.0]
    assert model.motors.no_load_speed[:3].tolist() == [2.5, 3.0, 4.0]
    # the merged masses: link2 + cover, link3 + flange + finger (locked)
    assert model.arms[0].link_mass.tolist() == pytest.approx([1.7, 1.4, 0.9], rel=0, abs=1e-15)


SLIDE = {
    "name": "slide_pair", "duration": 0.1,
    "arms": [
        {"name": "left", "file": "slide.urdf", "chain": {"base": "world", "tip": "tool"},
         "initial": {"angles": [0.2, 0.1, 0.5, 0.1, 0.6, 0.0]}},
        {"name": "right", "file": "slide.urdf", "chain": {"base": "world", "tip": "tool"},
         "base": {"position": [0.9, 0.1, 0.0], "rpy_deg": [0, 0, 180]},
         "end_effector": {"position": [0.0, 0.01, 0.02]}, "initial": {"angles": [-0.3, 0.05, 0.7, -0.2, 0.4, 0.1]}},
    ],
    "object": {"box": {"size": [0.2, 0.05, 0.05], "density": 500}, "grasps": "derive"},
}


def test_prismatic_joint_of_a_urdf_against_pinocchio(tmp_path):
    """slide.urdf: a URDF prismatic joint on the chain (axis (0.6, 0, 0.8) behind an rpy origin, a turning
    column before it, a fixed plate merged into its carriage) becomes a prismatic joint: poses, each
    arm's mass matrix and bias forces (≤ 1e-10) and closed-chain accelerations at 10 consistent states
    (≤ 1e-9 relative) as Pinocchio's buildModelFromUrdf reads the file (PrismaticUnaligned); its limits
    come along in m, N and m/s; degrees and a position outside the range are refused naming it."""
    shutil.copy(DATA / "slide.urdf", tmp_path / "slide.urdf")
    path = _write(tmp_path, SLIDE)
    model, S = load_scenario(path), RobotScene(path)
    assert model.joint_type.tolist() == [REVOLUTE, PRISMATIC, REVOLUTE, REVOLUTE, REVOLUTE, REVOLUTE] * 2
    assert [link.prismatic for arm in S.arms for link in arm.links] == [False, True, False, False, False, False] * 2
    assert_agrees_with_pinocchio(model, S, seed=17)
    assert model.joint_range[1].tolist() == [-0.1, 0.3]                        # m
    assert model.motors.stall_torque[:6].tolist() == [80.0, 400.0, 40.0, 20.0, 12.0, 8.0]   # the lift's a force, N
    assert model.motors.no_load_speed[:6].tolist() == [2.0, 0.6, 3.0, 4.0, 5.0, 6.0]        # the lift's m/s
    for init, expected in (
            ({"angles": [0.2, 0.4, 0.5, 0.1, 0.6, 0.0]},
             "arms[0].initial.angles: joint 2 (lift) at 0.4 m is outside its range [-0.1, 0.3] m"),
            ({"angles_deg": [10, 5, 30, 5, 30, 0]},
             "arms[0].initial.angles_deg: joint 2 (lift) is prismatic (m): give angles in rad and m, not angles_deg")):
        with pytest.raises(ScenarioError) as err:
            model_from_dict(mutated(SLIDE, ["arms", 0, "initial"], init), where="s.yaml", base_dir=tmp_path)
        assert str(err.value) == "s.yaml: " + expected


def test_mjcf_slide_joint_is_prismatic(tmp_path):
    """An MJCF `slide` joint on the chain is a prismatic joint too, its range (m) and actuatorfrcrange
    (N) coming along."""
    (tmp_path / "rail.xml").write_text(
        '<mujoco><worldbody><body name="cart" pos="0 0 0.1"><joint name="rail" type="slide" axis="0 1 0" '
        'range="-0.2 0.5" actuatorfrcrange="-300 250"/><inertial pos="0 0 0" mass="2" diaginertia="1 1 1"/>'
        '<body name="arm"><joint name="hinge" axis="0 0 1"/><inertial pos="0.1 0 0" mass="1" diaginertia="1 1 1"/>'
        '</body></body></worldbody></mujoco>')
    chain = read_chain(tmp_path / "rail.xml", "world", "arm")
    assert chain.links.joint_type.tolist() == [PRISMATIC, REVOLUTE] and chain.joint_names == ("rail", "hinge")
    assert chain.joint_range.tolist() == [[-0.2, 0.5], [-np.inf, np.inf]] and chain.effort.tolist() == [250.0, np.inf]
    assert chain.links.joint_axis[0].tolist() == [0.0, 1.0, 0.0]


def test_motor_overrides(tiny_dir):
    data = mutated(TINY, ["arms", 0, "motors"], {"stall_torque": [5, 6, 7], "no_load_speed": [1, float("inf"), 2]})
    model = load_scenario(_write(tiny_dir, data))
    assert model.motors.stall_torque.tolist() == [5, 6, 7, 40, 25, 12]
    assert model.motors.no_load_speed.tolist() == [1, np.inf, 2, 2.5, 3.0, 4.0]


def test_mjcf_joint_anchors_read_as_the_urdf():
    """anchor.xml (hinges at `pos` off their bodies, a turned body, a motor with forcerange × gear) and
    anchor.urdf (the same arm, link frames at the joints) give the same chain."""
    a, b = read_chain(DATA / "anchor.xml", "base", "tip"), read_chain(DATA / "anchor.urdf", "base", "tip")
    for key in ("joint_pos", "joint_rot", "joint_axis", "link_mass", "link_com", "link_inertia", "ee_pos", "ee_rot"):
        assert np.max(np.abs(getattr(a.links, key) - getattr(b.links, key))) <= 1e-15, key
    assert a.joint_range.tolist() == b.joint_range.tolist() == [[-1.0, 1.0], [-np.inf, np.inf]]
    assert a.effort.tolist() == b.effort.tolist() == [20.0, np.inf]
    assert a.velocity.tolist() == [np.inf, np.inf] and b.velocity.tolist() == [1.0, np.inf]


FLOATING = """<robot name="floating"><link name="world"/>
<joint name="float" type="floating"><parent link="world"/><child link="body"/></joint>
<link name="body"><inertial><mass value="1"/><inertia ixx="1" iyy="1" izz="1" ixy="0" ixz="0" iyz="0"/></inertial></link>
<joint name="j" type="revolute"><parent link="body"/><child link="arm"/><axis xyz="0 0 1"/>
<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
<link name="arm"><inertial><mass value="1"/><inertia ixx="1" iyy="1" izz="1" ixy="0" ixz="0" iyz="0"/></inertial></link>
</robot>"""
TWO_JOINTS = """<mujoco><worldbody><body name="b"><joint name="h1" axis="0 0 1"/><joint name="h2" axis="0 1 0"/>
<inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/></body></worldbody></mujoco>"""
REF = """<mujoco><compiler angle="radian"/><worldbody><body name="b"><joint name="h" axis="0 0 1" ref="0.3"/>
<inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/></body></worldbody></mujoco>"""
BALL = """<mujoco><worldbody><body name="b"><joint name="knuckle" type="ball"/>
<inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/></body></worldbody></mujoco>"""
SLIDE_REF = """<mujoco><worldbody><body name="b"><joint name="s" type="slide" axis="1 0 0" ref="0.05"/>
<inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/></body></worldbody></mujoco>"""

NEGATIVE_MASS = """<mujoco><worldbody><body name="b"><joint name="h" axis="0 0 1"/>
<inertial pos="0 0 0" mass="-1" diaginertia="1 1 1"/></body></worldbody></mujoco>"""
COUPLED = """<mujoco><worldbody><body name="a"><joint name="ha" axis="0 0 1"/>
<inertial pos="0.1 0 0" mass="1" diaginertia="0.01 0.01 0.01"/>
<body name="b" pos="0.2 0 0"><joint name="hb" axis="0 1 0"/>
<inertial pos="0.1 0 0" mass="1" diaginertia="0.01 0.01 0.01"/></body></body></worldbody>
<equality><joint joint1="hb" joint2="ha" polycoef="0.1 2 0 0 0"/></equality></mujoco>"""

REFUSED = [
    # (what is changed in arm 0, extra file, the error's end)
    ({"chain": {"base": "nope", "tip": "tool"}}, None,
     "arms[0].chain.base: base link 'nope' is not in tiny.urdf (links: world, base_link, link1, link2, cover, link3, "
     "flange, tool, finger, ghost)"),
    ({"chain": {"base": "world", "tip": "hand"}}, None, "arms[0].chain.tip: tip link 'hand' is not in tiny.urdf (links: world, base_link, link1, link2, cover, link3, "
     "flange, tool, finger, ghost)"),
    ({"chain": {"base": "link3", "tip": "link1"}}, None,
     "arms[0].chain.tip: tip link 'link1' is not below base link 'link3' in tiny.urdf: it is above it (swap base "
     "and tip?)"),
    ({"chain": {"base": "link1", "tip": "ghost"}}, None,
     "arms[0].chain.tip: tip link 'ghost' is not below base link 'link1' in tiny.urdf: the path between them "
     "branches at link 'base_link'"),
    ({"chain": {"base": "world", "tip": "tool"}}, None,
     "arms[0].file: the chain branches at link 'flange': joint 'finger_joint' (link 'finger') of tiny.urdf moves a "
     "branch off the chain (lock it, or choose a tip past it)"),
    ({"file": "ball.xml", "chain": {"base": "world", "tip": "b"}}, ("ball.xml", BALL),
     "arms[0].file: joint 'knuckle' (link 'b') of ball.xml is ball: an arm from a robot file takes revolute and "
     "prismatic joints only (lock it to hold it fixed)"),
    ({"chain": {"base": "world", "tip": "tool", "lock": ["finger_joint", "nojoint"]}}, None,
     "arms[0].chain.lock: locked joint 'nojoint' is not in tiny.urdf (joints: j1, j2, j3, finger_joint, ghost_joint)"),
    ({"chain": {"base": "base_link", "tip": "ghost"}, "initial": {"angles": [0.0]}}, None,
     "arms[0].file: the link moved by joint 'ghost_joint' in tiny.urdf has no mass or a singular inertia (mass 0 kg): "
     "give it an <inertial>"),
    ({"chain": {"base": "flange", "tip": "tool"}}, None,
     "arms[0].file: no moving joint between base link 'flange' and tip link 'tool' in tiny.urdf"),
    ({"file": "bad_inertia.urdf", "chain": {"base": "base_link", "tip": "camera"}, "initial": {"angles": [0.0]}}, None,
     "arms[0].file: link 'camera' of bad_inertia.urdf, part of the link moved by joint 'head_pan', has an inertia no "
     "rigid body has: its principal moments 0.001, 0.001, 0.01 kg·m² break the triangle inequality (the largest is "
     "more than the sum of the other two)"),
    ({"file": "negative.xml", "chain": {"base": "world", "tip": "b"}}, ("negative.xml", NEGATIVE_MASS),
     "arms[0].file: link 'b' of negative.xml, part of the link moved by joint 'h', has an inertia no rigid body has: "
     "its mass is negative (-1 kg)"),
    ({"file": "mimic.urdf", "chain": {"base": "world", "tip": "tool", "lock": ["finger_joint", "finger_r_joint"]}},
     None, "arms[0].file: joint 'j3' on the chain of mimic.urdf mimics joint 'j2' (j3 = -1·j2 + 0): coopsim does not "
     "model coupled joints; lock 'j3' and 'j2' (chain.lock), which holds them at 0, or end the chain before 'j3'"),
    ({"file": "mimic.urdf", "initial": {"angles": [0.1, 0.2]},
      "chain": {"base": "world", "tip": "link2", "lock": ["j3", "finger_joint", "finger_r_joint"]}}, None,
     "arms[0].file: joint 'j2' on the chain of mimic.urdf is mimicked by joint 'j3' (j3 = -1·j2 + 0): coopsim does "
     "not model coupled joints; lock 'j3' and 'j2' (chain.lock), which holds them at 0, or end the chain before 'j2'"),
    ({"file": "coupled.xml", "chain": {"base": "world", "tip": "b"}, "initial": {"angles": [0.1, 0.2]}},
     ("coupled.xml", COUPLED),
     "arms[0].file: joint 'hb' on the chain of coupled.xml mimics joint 'ha' (hb = 2·ha + 0.1): coopsim does not "
     "model coupled joints; end the chain before 'hb'"),
    ({"initial": {"angles": [2.6, 0.9, 0.4]}}, None,
     "arms[0].initial.angles: joint 1 (j1) at 2.6 rad is outside its range [-2, 2.5] rad"),
    ({"file": "floating.urdf", "chain": {"base": "world", "tip": "arm"}}, ("floating.urdf", FLOATING),
     "arms[0].file: joint 'float' (link 'body') of floating.urdf is free (floating): an arm from a robot file takes "
     "revolute and prismatic joints only (lock it to hold it fixed)"),
    ({"file": "two.xml", "chain": {"base": "world", "tip": "b"}}, ("two.xml", TWO_JOINTS),
     "arms[0].file: link 'b' of two.xml has 2 joints ('h1', 'h2'): an arm takes one joint per link"),
    ({"file": "ref.xml", "chain": {"base": "world", "tip": "b"}}, ("ref.xml", REF),
     "arms[0].file: joint 'h' of ref.xml has a reference angle (ref) of 0.3 rad: only 0 is supported"),
    ({"file": "slide_ref.xml", "chain": {"base": "world", "tip": "b"}}, ("slide_ref.xml", SLIDE_REF),
     "arms[0].file: joint 's' of slide_ref.xml has a reference position (ref) of 0.05 m: only 0 is supported"),
    ({"file": "broken.urdf"}, ("broken.urdf", "<robot name='x'><link name='a'>"), "arms[0].file: MuJoCo cannot read broken.urdf: "),
    ({"file": "missing.urdf"}, None, "arms[0].file: file not found: "),
    ({"chain": None}, None, "arms[0].chain: missing required field"),
    ({"file": None, "robot": "ur6"}, None, "arms[0].robot: no robot 'ur6' (robots: " + ", ".join(ROBOTS) + ")"),
    ({"links": [{"box": {"length": 0.3, "cross_section": [0.05, 0.05], "density": 1000}}]}, None,
     "arms[0].links: give exactly one of links, robot (a bundled robot) or file (a URDF or MJCF file)"),
]


@pytest.mark.parametrize("change, extra, expected", REFUSED, ids=[r[2].split(": ", 1)[1][:40] for r in REFUSED])
def test_refused_robot_files(tiny_dir, change, extra, expected):
    data = TINY
    for key, value in change.items():
        data = mutated(data, ["arms", 0, key], value)
    if extra is not None:
        (tiny_dir / extra[0]).write_text(extra[1])
    with pytest.raises(ScenarioError) as err:
        model_from_dict(data, where="s.yaml", base_dir=tiny_dir)
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith("s.yaml: " + expected) if expected.endswith(": ") else msg == "s.yaml: " + expected


NONPD = """<robot name="nonpd"><link name="world"/>
<joint name="j" type="continuous"><parent link="world"/><child link="b"/><axis xyz="0 0 1"/></joint>
<link name="b"><inertial><mass value="0.000001"/><inertia ixx="0.00000002371" ixy="0.00000006119" ixz="0.00000001179"
iyy="0.00000002833" iyz="0.00000000774" izz="0.00000003849"/></inertial></link></robot>"""


def test_a_used_inertia_that_is_not_positive_semi_definite_is_refused(tmp_path):
    """TIAGo's antenna inertia (eigenvalues about −3.5e-8, 3.5e-8, 9.1e-8 kg·m²) on a moving link."""
    (tmp_path / "nonpd.urdf").write_text(NONPD)
    expected = (r"^link 'b' of nonpd\.urdf, part of the link moved by joint 'j', has an inertia no rigid body has: "
                r"its principal moments -3\.\d+e-08, .* kg·m² are not all ≥ 0 \(the matrix is not positive "
                r"semi-definite\)$")
    with pytest.raises(robots.RobotFileError, match=expected):
        read_chain(tmp_path / "nonpd.urdf", "world", "b")


BAD = {
    "name": "bad_inertia_pair", "duration": 0.1,
    "arms": [
        {"name": "left", "file": "bad_inertia.urdf", "chain": {"base": "world", "tip": "tool"},
         "initial": {"angles": [0.3, 0.9, -0.4]}},
        {"name": "right", "file": "bad_inertia.urdf", "chain": {"base": "world", "tip": "tool"},
         "base": {"position": [0.9, 0.1, 0.0], "rpy_deg": [0, 0, 180]}, "initial": {"angles": [-0.2, 1.0, -0.6]}},
    ],
    "object": {"box": {"size": [0.2, 0.05, 0.05], "density": 500}, "grasps": "derive"},
}


def test_bad_inertias_off_the_chain_do_not_stop_it(tiny_dir):
    """bad_inertia.urdf carries an antenna (inertia not positive semi-definite) and a camera on a panning
    head (moments breaking the triangle inequality) that MuJoCo refuses to compile; the arm's chain uses
    neither and reads as Pinocchio's buildModelFromUrdf does (poses and arm dynamics at the initial and
    10 random states, ≤ 1e-10)."""
    with pytest.raises(ValueError, match="inertia must have positive eigenvalues"):
        _mujoco_inertials(DATA / "bad_inertia.urdf")
    path = _write(tiny_dir, BAD)
    model = _open_arms_agree_with_pinocchio(path, seed=19)
    assert model.arms[0].link_mass.tolist() == [1.5, 1.2, 0.7]


def _mujoco_inertials(path: Path):
    """MuJoCo's own compile of the file's inertials (geoms and meshes deleted, inertia from the inertials,
    MINVAL for massless bodies where the file sets no bounds): per body the mass, centre of mass and inertia
    about it in the body frame."""
    spec = mujoco.MjSpec.from_file(str(path))
    for element in list(spec.geoms) + list(spec.meshes):
        spec.delete(element)
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    spec.compiler.fusestatic = False
    if spec.compiler.boundmass == 0 and spec.compiler.boundinertia == 0:
        spec.compiler.boundmass = spec.compiler.boundinertia = mujoco.mjMINVAL
    m = spec.compile()
    R = np.array([quat_to_rot(q) for q in m.body_iquat])
    return m.body_mass, m.body_ipos, R @ (m.body_inertia[:, :, None] * np.swapaxes(R, 1, 2))


INERTIALS = """<mujoco>
<compiler angle="radian" boundmass="0.01" boundinertia="0.001" settotalmass="7" balanceinertia="true"/>
<worldbody><body name="a"><joint name="ha" axis="0 0 1"/>
<inertial pos="0.1 0 0" euler="0.3 0.2 0.1" mass="2" diaginertia="0.01 0.02 0.025"/>
<body name="b" pos="0.3 0 0"><joint name="hb" axis="0 1 0"/>
<inertial pos="0 0.1 0" mass="1" fullinertia="0.02 0.03 0.04 0.001 -0.002 0.003"/>
<body name="c" pos="0 0.2 0">
<inertial pos="0 0 0.05" quat="0.9 0.1 0.2 0.3" mass="0.5" diaginertia="0.001 0.001 0.005"/>
</body><body name="d"/></body></body></worldbody></mujoco>"""


@pytest.mark.filterwarnings("ignore:compiler attribute 'settotalmass' is deprecated")   # MuJoCo's own compile warns
def test_inertials_read_as_mujoco_compiles_them(tmp_path):
    """The masses and inertias read from the parsed file (MuJoCo compiling stand-ins) are MuJoCo's own:
    URDF inertials turned off their link axes, MJCF diagonal inertias in an euler or quat frame, a full
    inertia, bodies without an inertial (mass 0 where MuJoCo gives them MINVAL), and the file's boundmass,
    boundinertia, settotalmass and balanceinertia: masses and inertias ≤ 1e-14 relative to the largest
    (MuJoCo's iterative eigen-decomposition rounds: 1.3e-15 measured), centres of mass ≤ 1e-15 m."""
    (tmp_path / "inertials.xml").write_text(INERTIALS)
    for path in (DATA / "tiny.urdf", DATA / "anchor.xml", DATA / "slide.urdf", tmp_path / "inertials.xml"):
        mass, com, inertia = _mujoco_inertials(path)
        dyn = robots.compile_dynamics(path)
        R = np.array([quat_to_rot(q) for q in dyn.model.body_iquat])
        mine = R @ dyn.inertia @ np.swapaxes(R, 1, 2)
        assert np.max(np.abs(dyn.mass - mass)) <= 1e-14 * mass.max(), path.name
        massive = dyn.mass > 0          # a body without an inertial has no centre of mass to compare
        assert np.max(np.abs(dyn.model.body_ipos - com)[massive]) <= 1e-15, path.name
        assert np.max(np.abs(mine - inertia)[massive]) <= 1e-14 * np.abs(inertia).max(), path.name
        assert all(p is None for p in dyn.problem), path.name


def test_mimic_joints_locked_together_read_as_fixed(tiny_dir):
    """The lock the refusal suggests: j2 and j3 (j3 = −j2) locked, the fingers too, leaves j1 alone, the
    rest merged into its link."""
    chain = read_chain(tiny_dir / "mimic.urdf", "world", "tool", ["j2", "j3", "finger_joint", "finger_r_joint"])
    assert chain.joint_names == ("j1",)
    assert chain.links.link_mass.tolist() == pytest.approx([1.5 + 1.2 + 0.7 + 0.1], rel=1e-15)


@needs_robots
def test_tiago_dual_and_pr2_read_past_links_mujoco_refuses():
    """MuJoCo refuses to compile either whole file (an antenna of TIAGo's base, a camera mount of PR2's
    head); their arms read all the same, and a chain that does use PR2's camera mount is refused, naming it."""
    for name, element in (("tiago_dual_left", "base_antenna_left_link"), ("pr2_left", "sensor_mount_link")):
        with pytest.raises(ValueError, match=element):
            _mujoco_inertials(robot_file(name))
        assert read_chain(*bundled(name)).n == 7
    expected = (r"^link 'sensor_mount_link' of pr2\.urdf, part of the link moved by joint 'head_tilt_joint', has an "
                r"inertia no rigid body has: its principal moments 0\.001, 0\.001, 0\.01 kg·m² break the triangle")
    with pytest.raises(robots.RobotFileError, match=expected):
        read_chain(robot_file("pr2_left"), "torso_lift_link", "sensor_mount_link")


@needs_robots
def test_pr2_mimic_fingers_refused_on_the_chain():
    """PR2's gripper: a chain through the finger joint, the five that mimic it locked, is refused naming
    the first coupling (the right finger mimics it)."""
    lock = [j for j in ROBOTS["pr2_left"].lock if j != "l_gripper_l_finger_joint"]
    expected = (r"^joint 'l_gripper_l_finger_joint' on the chain of pr2\.urdf is mimicked by joint 'l_gripper_r_finger_"
                r"joint' \(l_gripper_r_finger_joint = 1·l_gripper_l_finger_joint \+ 0\)")
    with pytest.raises(robots.RobotFileError, match=expected):
        read_chain(robot_file("pr2_left"), "torso_lift_link", "l_gripper_l_finger_link", lock)


def test_a_continuous_joint_may_turn_past_a_turn(tiny_dir):
    """tiny.urdf's j2 is continuous: 6.5 rad is an angle (PR2's forearm roll at 6.5 rad was refused as
    degrees); a whole number of radians past a turn still reads as degrees there, and so does a value past
    a turn outside a joint's range (j1: [-2, 2.5] rad)."""
    ok = mutated(TINY, ["arms", 0, "initial", "angles"], [0.3, 6.5, 0.4])
    assert load_scenario(_write(tiny_dir, ok)).q0[1] == 6.5
    for angles, expected in (
            ([0.3, 7, 0.4], "joint 2 (j2) at 7 rad is more than a turn, a whole number of radians: degrees? use "
                            "angles_deg"),
            ([30, 0.9, 0.4], "joint 1 (j1) at 30 rad is more than a turn, outside its range [-2, 2.5] rad: degrees? "
                             "use angles_deg"),
            ([-6.5, 0.9, 0.4], "joint 1 (j1) at -6.5 rad is more than a turn, outside its range [-2, 2.5] rad: "
                               "degrees? use angles_deg")):
        with pytest.raises(ScenarioError) as err:
            model_from_dict(mutated(TINY, ["arms", 0, "initial", "angles"], angles), where="s.yaml", base_dir=tiny_dir)
        assert str(err.value) == "s.yaml: arms[0].initial.angles: " + expected


@needs_robots
def test_pr2_forearm_roll_past_a_turn():
    """The issue's case: PR2's forearm roll (continuous) at 6.5 rad, the same posture as 6.5 − 2π."""
    path = SCENARIOS / "robots" / "pr2_box.yaml"
    turned = load_scenario(path, overrides=[("arms[0].initial.angles[4]", 6.5)])
    assert turned.q0[4] == 6.5
    plain = load_scenario(path, overrides=[("arms[0].initial.angles[4]", 6.5 - 2 * np.pi)])
    a, b = arm_poses(turned, turned.q0)[0], arm_poses(plain, plain.q0)[0]
    assert np.max(np.abs(a.p_ee - b.p_ee)) <= 1e-12 and np.max(np.abs(a.R_ee - b.R_ee)) <= 1e-12


def test_hand_written_joint_range():
    """A hand-written joint may give its `range` too: kept in the model, checked at the initial angles."""
    base = yaml.safe_load((SCENARIOS / "paper_planar_2x3.yaml").read_text())
    data = mutated(base, ["arms", 0, "links", 1, "joint", "range_deg"], [-10, 310])     # angle 303.56°
    assert np.allclose(model_from_dict(data).joint_range[1], np.deg2rad([-10, 310]), rtol=0, atol=1e-15)
    data = mutated(base, ["arms", 0, "links", 1, "joint", "range_deg"], [-10, 300])
    with pytest.raises(ScenarioError, match=r"arms\[0\]\.initial\.angles: joint 2 at 5\.29812 rad is outside its "
                                            r"range \[-0\.174533, 5\.23599\] rad"):
        model_from_dict(data)


# ------------------------------------------------------------------------------ drawing
def _box_ends(center, R, size):
    """The two ends of a drawing box along its x axis: center ∓ (size_x / 2) R[:, 0]."""
    half = 0.5 * size[0] * R[:, 0]
    return center - half, center + half


def _joint_points(model, q):
    """Per arm, the kinematic joint positions and end-effector point (n + 1, 3), world."""
    return [np.vstack([p.p, p.p_ee[None]]) for p in arm_poses(model, q)]


def assert_links_drawn_joint_to_joint(model, q):
    """The MuJoCo twin's link boxes (what `coopsim animate` draws) and the log's /scene cubes placed by
    its /tf link frames (Foxglove) run from each joint to the next (the last to the end-effector) at the
    angles q, ≤ 1e-12 m; a link whose next joint sits on its own is a cube centred on its joint."""
    points = _joint_points(model, q)
    mj = build_spec(model, static_settings(model)).compile()
    d = mujoco.MjData(mj)
    d.qpos[qpos_address(mj, model)] = q
    mujoco.mj_kinematics(mj, d)
    pos, quat = native_link_poses(model, q[None])
    cubes = {e["id"]: e["cubes"][0] for e in scene_update(model, True, False).messages[0]["entities"]}
    names = iter(link_frame_names(model, "native"))
    k = 0
    for m, arm in enumerate(model.arms):
        for i in range(arm.n):
            (g,) = [g for g in range(mj.ngeom) if mj.body(mj.geom_bodyid[g]).name == f"a{m}_l{i}"]
            c = cubes[next(names)]
            R_link = quat_to_rot(quat[0, k])
            R_cube = quat_to_rot([c["pose"]["orientation"][a] for a in "wxyz"])
            centre = pos[0, k] + R_link @ [c["pose"]["position"][a] for a in "xyz"]
            size = [c["size"][a] for a in "xyz"]
            drawn = (_box_ends(d.geom_xpos[g], d.geom_xmat[g].reshape(3, 3), 2 * mj.geom_size[g]),
                     _box_ends(centre, R_link @ R_cube, size))
            length = np.linalg.norm(points[m][i + 1] - points[m][i])
            expected = (points[m][i], points[m][i + 1]) if length > 1e-9 else (points[m][i], points[m][i])
            for ends in drawn:
                if length <= 1e-9:
                    ends = (0.5 * (ends[0] + ends[1]),) * 2
                assert np.max(np.abs(np.array(ends) - np.array(expected))) <= 1e-12, (model.name, m, i)
            k += 1


@needs_robots
def test_robot_links_are_drawn_from_joint_to_joint():
    """panda_ceiling_carry at its initial and two random postures."""
    model = load_scenario(SCENARIOS / "robots" / "panda_ceiling_carry.yaml")
    rng = np.random.default_rng(5)
    for q in (model.q0, *rng.uniform(-2, 2, (2, model.n_total))):
        assert_links_drawn_joint_to_joint(model, q)


def test_small_robot_links_are_drawn_from_joint_to_joint(tiny_dir):
    """tiny.urdf (an end-effector offset past the tip, rpy joint origins) needs no optional package."""
    model = load_scenario(_write(tiny_dir, TINY))
    assert_links_drawn_joint_to_joint(model, model.q0 + 0.3)
