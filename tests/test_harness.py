"""Cross-validation: native model against the MuJoCo twin, by number; and the harness can fail."""

from dataclasses import replace

import pytest

from coopsim.harness import cross_validate


def _metric(cv, name):
    return next(m for m in cv.comparison.metrics if m.name == name)


def test_paper_scenario_agrees_with_mujoco_over_5s(paper):
    cv = cross_validate(paper)
    assert cv.native.t[-1] == pytest.approx(5.0)
    assert _metric(cv, "joint angle error").max <= 1e-7
    assert _metric(cv, "object position error").max <= 1e-7
    assert cv.comparison.passed, cv.comparison.failures()


def test_spatial_scenario_agrees_with_mujoco_over_3s(spatial):
    cv = cross_validate(spatial)
    assert cv.native.t[-1] == pytest.approx(3.0)
    assert spatial.plane is None and spatial.arms[0].n >= 6
    assert _metric(cv, "joint angle error").max <= 1e-6
    assert _metric(cv, "object orientation error").max <= 1e-6
    assert cv.comparison.passed, cv.comparison.failures()


def test_a_wrong_twin_fails_and_names_the_quantity(paper):
    """Object mass (and inertia) +1 % in the twin only."""
    wrong = replace(paper, mujoco=replace(paper.mujoco, object_mass_scale=1.01))
    cv = cross_validate(paper, duration=1.0, twin_model=wrong)
    assert not cv.comparison.passed
    failures = cv.comparison.failures()
    assert any(f.startswith("joint angle error") and "rad exceeds 1e-07 rad at arm" in f for f in failures), failures
