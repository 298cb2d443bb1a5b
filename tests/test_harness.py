"""Cross-validation: native model against the MuJoCo twin, by number, on every bundled scenario;
and the harness can fail."""

from dataclasses import replace

import pytest

from coopsim.harness import cross_validate
from coopsim.scenario import load_scenario
from conftest import SCENARIOS

SCENARIO_FILES = sorted(SCENARIOS.glob("*.yaml"))

# The acceptance bounds (rad, m) where they are stricter than a scenario's own thresholds.
ACCEPTANCE = {"paper_planar_2x3": (5.0, 1e-7, 1e-7), "spatial_6r_pair": (3.0, 1e-6, 1e-6)}


def _metric(cv, name):
    return next(m for m in cv.comparison.metrics if m.name == name)


@pytest.mark.parametrize("path", SCENARIO_FILES, ids=[p.stem for p in SCENARIO_FILES])
def test_bundled_scenario_agrees_with_its_mujoco_twin(path):
    model = load_scenario(path)
    cv = cross_validate(model)
    assert cv.comparison.passed, cv.comparison.failures()
    if model.name in ACCEPTANCE:
        duration, angle, position = ACCEPTANCE[model.name]
        assert cv.native.t[-1] == pytest.approx(duration)
        assert _metric(cv, "joint angle error").max <= angle
        assert _metric(cv, "object position error").max <= position


def test_spatial_scenario_is_a_hard_3d_case(spatial):
    """At least 6 revolute joints per arm, non-parallel axes, gravity on, object turning in 3D."""
    import numpy as np

    from coopsim.compare import orientation_error
    from coopsim.simulate import simulate

    assert spatial.plane is None and min(a.n for a in spatial.arms) >= 6
    assert np.linalg.norm(spatial.gravity) > 9
    res = simulate(replace(spatial, duration=1.5))
    turned = orientation_error(res.object_quat, np.repeat(res.object_quat[:1], len(res.t), axis=0))
    assert turned.max() > 0.1  # rad


def test_a_wrong_twin_fails_and_names_the_quantity(paper):
    """Object mass (and inertia) +1 % in the twin only."""
    wrong = replace(paper, mujoco=replace(paper.mujoco, object_mass_scale=1.01))
    cv = cross_validate(paper, duration=1.0, twin_model=wrong)
    assert not cv.comparison.passed
    failures = cv.comparison.failures()
    assert any(f.startswith("joint angle error") and "rad exceeds 1e-07 rad at arm" in f for f in failures), failures
