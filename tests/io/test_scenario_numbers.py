"""Scenario numbers that must not be silently changed: whole-number fields refuse a fraction
instead of truncating it, and joint rates are not read as angles."""

import numpy as np
import pytest
import yaml

from coopsim.io.scenario import model_from_dict
from coopsim.core.errors import ScenarioError
from helpers import SCENARIOS, mutated, run_cli

PAPER = yaml.safe_load((SCENARIOS / "paper_planar_2x3.yaml").read_text())


def _error(data) -> str:
    with pytest.raises(ScenarioError) as exc:
        model_from_dict(data)
    return str(exc.value)


def test_mujoco_iterations_must_be_a_whole_number():
    """10.5 was int()-truncated to 10; now refused, naming the field. 10.0 is the whole number 10."""
    assert _error(mutated(PAPER, ["mujoco", "iterations"], 10.5)) == \
        "<scenario>: mujoco.iterations: must be a whole number, got 10.5"
    assert _error(mutated(PAPER, ["mujoco", "iterations"], 200.000001)) == \
        "<scenario>: mujoco.iterations: must be a whole number, got 200.000001"
    for value, iterations in ((10.0, 10), (10, 10), (1, 1)):
        got = model_from_dict(mutated(PAPER, ["mujoco", "iterations"], value)).mujoco.iterations
        assert got == iterations and type(got) is int
    assert _error(mutated(PAPER, ["mujoco", "iterations"], 0)) == "<scenario>: mujoco.iterations: must be positive, got 0.0"
    assert _error(mutated(PAPER, ["mujoco", "iterations"], "10")) == \
        "<scenario>: mujoco.iterations: expected a number, got '10'"


def test_fractional_iterations_exit_2_from_the_cli(workdir):
    (workdir / "frac.yaml").write_text(yaml.safe_dump(mutated(PAPER, ["mujoco", "iterations"], 10.5)))
    out = run_cli("simulate", "frac.yaml", cwd=workdir)
    assert out.returncode == 2
    assert out.stderr.strip() == "coopsim: error: frac.yaml: mujoco.iterations: must be a whole number, got 10.5", out.stderr


def test_initial_rates_above_a_turn_per_second_are_rates_not_degrees():
    """A rate of 7 rad/s failed with 'arms[0].initial.rates: 7 rad is more than a turn: degrees? use
    rates_deg' (the rates went through the angle reader). Rates take any finite value, in rad/s, or
    in deg/s under rates_deg; angles keep their check."""
    rates = [7.0, -12.5, 0.25]
    m = model_from_dict(mutated(PAPER, ["arms", 0, "initial", "rates"], rates))
    assert np.array_equal(m.qd0[:3], rates) and np.array_equal(m.qd0[3:], [0.0, 0.0, 0.0])
    deg = mutated(PAPER, ["arms", 1, "initial", "rates"], None)
    deg["arms"][1]["initial"]["rates_deg"] = [400.0, -90.0, 0.0]
    m = model_from_dict(deg)
    assert m.qd0[3:] == pytest.approx(np.deg2rad([400.0, -90.0, 0.0]), rel=1e-15)
    both = mutated(PAPER, ["arms", 0, "initial", "rates_deg"], [1.0, 0.0, 0.0])
    assert _error(both) == "<scenario>: arms[0].initial.rates: give either rates (rad) or rates_deg (deg), not both"
    assert _error(mutated(PAPER, ["arms", 0, "initial", "rates"], [7.0, float("nan"), 0.0])) == \
        "<scenario>: arms[0].initial.rates: must be finite"
    # angles still flag radians that look like degrees
    angles = mutated(PAPER, ["arms", 0, "initial"], {"angles": [7.0, 0.0, 0.0]})
    assert _error(angles) == "<scenario>: arms[0].initial.angles: 7 rad is more than a turn: degrees? use angles_deg"
