"""The MuJoCo twin: only what the scene needs, the same parameters as the native model, files up to date."""

from pathlib import Path

import mujoco
import numpy as np
import pytest

from coopsim.mjcf import build_spec, mjcf_text, qpos_address
from coopsim.scenario import load_scenario
from coopsim.simulate import initial_state
from conftest import ROOT, SCENARIOS

SCENARIO_FILES = sorted(SCENARIOS.glob("*.yaml"))


@pytest.mark.parametrize("path", SCENARIO_FILES, ids=[p.stem for p in SCENARIO_FILES])
def test_model_file_is_up_to_date(path):
    model_file = ROOT / "models" / f"{path.stem}.xml"
    expected = mjcf_text(load_scenario(path), f"scenarios/{path.name}")
    assert model_file.is_file(), f"{model_file} missing: run `coopsim mjcf`"
    assert model_file.read_text() == expected, f"{model_file} is out of date with {path}: run `coopsim mjcf`"


@pytest.mark.parametrize("scenario", ["paper", "spatial"])
def test_twin_holds_only_what_the_scene_needs(scenario, request):
    model = request.getfixturevalue(scenario)
    m = build_spec(model).compile()
    n = model.n_total
    assert m.nbody == 1 + n + 1, "world + one body per link + the object"
    assert m.njnt == n and np.all(m.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)
    assert m.neq == model.r - 1 and np.all(m.eq_type == mujoco.mjtEq.mjEQ_WELD)
    assert m.nu == n and np.all(m.actuator_gear[:, 0] == 1.0)
    assert m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT
    assert m.ngeom == n + 1 and np.all(m.geom_contype == 0) and np.all(m.geom_conaffinity == 0)


@pytest.mark.parametrize("scenario", ["paper", "spatial"])
def test_twin_parameters_equal_the_native_model(scenario, request):
    model = request.getfixturevalue(scenario)
    m = build_spec(model).compile()
    bodies = [m.body(f"a{a}_l{i}").id for a, arm in enumerate(model.arms) for i in range(arm.n)]
    bodies.append(m.body("object").id)
    masses = np.concatenate([a.link_mass for a in model.arms] + [[model.object.mass]])
    assert np.array_equal(m.body_mass[bodies], masses)
    inertias = [I for a in model.arms for I in a.link_inertia] + [model.object.inertia]
    for b, I in zip(bodies, inertias):
        assert np.allclose(np.sort(m.body_inertia[b]), np.linalg.eigvalsh(I), rtol=1e-13, atol=0)
    assert np.allclose(m.opt.gravity, model.gravity, rtol=0, atol=0)


@pytest.mark.parametrize("scenario", ["paper", "spatial"])
def test_welds_hold_at_the_consistent_initial_state(scenario, request):
    """The weld anchor and relative pose are set explicitly: zero violation where the loop closes."""
    model = request.getfixturevalue(scenario)
    m = build_spec(model).compile()
    d = mujoco.MjData(m)
    d.qpos[qpos_address(m, model)] = initial_state(model).q
    mujoco.mj_forward(m, d)
    assert d.nefc == 6 * (model.r - 1)
    assert np.max(np.abs(d.efc_pos[: d.nefc])) <= 1e-12


def test_model_file_loads_and_matches_the_spec_to_its_printed_precision(paper):
    exact = build_spec(paper).compile()
    loaded = mujoco.MjModel.from_xml_path(str(ROOT / "models" / "paper_planar_2x3.xml"))
    assert (loaded.nbody, loaded.njnt, loaded.neq, loaded.nu) == (exact.nbody, exact.njnt, exact.neq, exact.nu)
    assert np.allclose(loaded.body_inertia, exact.body_inertia, rtol=5e-6, atol=0)  # 6 digits
    assert np.allclose(loaded.body_pos, exact.body_pos, rtol=0, atol=1e-6)
