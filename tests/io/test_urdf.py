"""The scene as a URDF (`coopsim/io/urdf.py`, `coopsim urdf`).

Independent checks: the URDF text is loaded by Pinocchio's URDF parser (urdfdom) and by MuJoCo's URDF
compiler, sharing nothing with coopsim but the file, and compared at random joint coordinates and rates
with coopsim's reference engine: the whole tree's mass matrix (block diagonal by arm, the object's
inertia in the carrier's block: 𝐈 of eq. 22, `chain_terms().M`) and bias forces with gravity
(`chain_terms().h`) to 1e-12 relative (max |Δ| / max(1, max |reference|)), and every link, end-effector
and object frame to 1e-12 m and 1e-12 in the rotation's entries. Scenes: planar and spatial revolute
arms, prismatic axes without a range, UR5s from a URDF (rotated joint frames; skipped without
example-robot-data).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from coopsim.core.labels import joint_labels
from coopsim.dynamics.closed_chain import arm_poses, carrier_object, chain_terms
from coopsim.io.robots import robots_folder
from coopsim.io.scenario import load_scenario
from coopsim.io.urdf import OBJECT_LINK, arm_links, urdf_text
from helpers import ROOT, SCENARIOS, run_cli

TOL = 1e-12
SCENES = ["paper_planar_2x3", "spatial_6r_pair", "gantry_prismatic", "robots/ur5_pair_box"]


@pytest.fixture(scope="module", params=SCENES)
def scene(request):
    if request.param.startswith("robots/") and robots_folder() is None:
        pytest.skip("example-robot-data is not installed: pip install 'coopsim[robots]'")
    model = load_scenario(SCENARIOS / f"{request.param}.yaml")
    return model, urdf_text(model)


def _states(model, count=4, seed=7):
    rng = np.random.default_rng(seed)
    return [(rng.uniform(-np.pi, np.pi, model.n_total), rng.uniform(-2, 2, model.n_total)) for _ in range(count)]


def _rel(a, b) -> float:
    return float(np.max(np.abs(a - b)) / max(1.0, np.max(np.abs(b))))


def _frames(model, q):
    """coopsim's frames: link name → (position, rotation), world."""
    poses = arm_poses(model, q)
    out = {}
    for links, pose in zip(arm_links(model), poses):
        out |= {name: (pose.p[i], pose.R[i]) for i, name in enumerate(links.links)}
        out[links.ee] = (pose.p_ee, pose.R_ee)
    obj = carrier_object(model, poses)
    out[OBJECT_LINK] = (obj.p_C, obj.R_o)
    return out


def _check_frames(model, q, frame_of, where: str):
    for name, (p, R) in _frames(model, q).items():
        p_ref, R_ref = frame_of(name)
        assert np.max(np.abs(p_ref - p)) <= TOL, f"{where}: frame {name} position off by {np.max(np.abs(p_ref - p)):.2g} m"
        assert np.max(np.abs(R_ref - R)) <= TOL, f"{where}: frame {name} rotation off by {np.max(np.abs(R_ref - R)):.2g}"


def test_urdf_loads_into_pinocchio_with_coopsims_mass_matrix_bias_and_frames(scene):
    model, text = scene
    pm = pin.buildModelFromXML(text)
    pm.gravity.linear = np.asarray(model.gravity, dtype=float)
    data = pm.createData()
    joints = [pm.joints[pm.getJointId(name)] for name in joint_labels(model)]
    assert pm.nv == model.n_total and all(j.nv == 1 for j in joints)
    iv = np.array([j.idx_v for j in joints])
    for q, qd in _states(model):
        qp = np.zeros(pm.nq)
        for j, x in zip(joints, q):          # a continuous joint is (cos, sin) in Pinocchio
            qp[j.idx_q:j.idx_q + j.nq] = [np.cos(x), np.sin(x)] if j.nq == 2 else [x]
        v = np.zeros(pm.nv)
        v[iv] = qd
        terms = chain_terms(model, q, qd)
        M = pin.crba(pm, data, qp)
        M = np.triu(M) + np.triu(M, 1).T
        assert _rel(M[np.ix_(iv, iv)], terms.M) <= TOL, f"{model.name}: Pinocchio's mass matrix differs"
        h = pin.rnea(pm, data, qp, v, np.zeros(pm.nv))
        assert _rel(h[iv], terms.h) <= TOL, f"{model.name}: Pinocchio's bias forces differ"
        pin.framesForwardKinematics(pm, data, qp)
        _check_frames(model, q, lambda n: (data.oMf[pm.getFrameId(n)].translation,
                                           data.oMf[pm.getFrameId(n)].rotation), f"{model.name} Pinocchio")


def test_urdf_loads_into_mujoco_with_coopsims_mass_matrix_bias_and_frames(scene):
    model, text = scene
    spec = mujoco.MjSpec.from_string(text)
    spec.compiler.fusestatic = False          # MuJoCo's URDF default merges the fixed links away
    m = spec.compile()
    m.opt.gravity[:] = model.gravity
    d = mujoco.MjData(m)
    joints = [m.joint(name) for name in joint_labels(model)]
    assert m.nv == model.n_total
    qa, va = np.array([j.qposadr[0] for j in joints]), np.array([j.dofadr[0] for j in joints])
    M = np.zeros((m.nv, m.nv))
    for q, qd in _states(model, seed=8):
        d.qpos[qa], d.qvel[va] = q, qd
        mujoco.mj_forward(m, d)
        mujoco.mj_fullM(m, d, M)
        terms = chain_terms(model, q, qd)
        assert _rel(M[np.ix_(va, va)], terms.M) <= TOL, f"{model.name}: MuJoCo's mass matrix differs"
        assert _rel(d.qfrc_bias[va], terms.h) <= TOL, f"{model.name}: MuJoCo's bias forces differ"
        _check_frames(model, q, lambda n: (d.body(n).xpos, d.body(n).xmat.reshape(3, 3)), f"{model.name} MuJoCo")


def test_urdf_names_limits_and_determinism(paper):
    """The moving joints carry the scene's joint labels, the links the ROS arm tokens; a joint without a
    range is continuous, its effort and velocity the motor's lines; the text is the same every time."""
    text = urdf_text(paper)
    assert text == urdf_text(load_scenario(SCENARIOS / "paper_planar_2x3.yaml"))
    assert '<joint name="arm 1 joint 1" type="continuous">' in text and '<link name="arm2/link3">' in text
    assert '<limit effort="0.55" velocity="5.85"/>' in text and "-0.0" not in text


def test_urdf_command_writes_the_file_and_refuses_bad_input(workdir):
    res = run_cli("urdf", "scenarios/paper_planar_2x3.yaml", "--out", "paper.urdf", cwd=workdir)
    assert res.returncode == 0, res.stderr
    assert (workdir / "paper.urdf").read_text(encoding="utf-8") == urdf_text(
        load_scenario(ROOT / "scenarios" / "paper_planar_2x3.yaml"))
    res = run_cli("urdf", "scenarios/paper_planar_2x3.yaml", "--set", "object.box.densty=1", cwd=workdir)
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "object.box.densty" in res.stderr, res.stderr
    assert not (workdir / "out").exists()
