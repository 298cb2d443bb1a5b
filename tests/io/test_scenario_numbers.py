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
    assert _error(angles) == ("<scenario>: arms[0].initial.angles: joint 1 at 7 rad is more than a turn, a whole "
                              "number of radians: degrees? use angles_deg")


GANTRY = yaml.safe_load((SCENARIOS / "gantry_prismatic.yaml").read_text())


def _with_setpoint(data: dict, **setpoint) -> dict:
    """`data` with a joint PD controller holding the given `setpoint` or `setpoint_deg` (one per joint)."""
    return mutated(data, ["control"], {"law": "joint_pd", "kp": 10.0, "kd": 1.0, **setpoint})


def test_a_setpoint_is_read_per_joint_type():
    """control.setpoint is a joint coordinate: rad on a revolute joint, m on a prismatic one. Its degree
    form was converted by π/180 on every joint, a prismatic one's metres too, and 7 m on a prismatic joint
    was refused as 'degrees?'."""
    far = [7.0, 1.784505, -1.633337, 0.3, -1.387819, 2.039118]
    assert model_from_dict(_with_setpoint(GANTRY, setpoint=far)).control.setpoint.tolist() == far
    assert _error(_with_setpoint(GANTRY, setpoint_deg=[5.7, 102.2, -93.6, 17.2, -79.5, 116.8])) == (
        "<scenario>: control.setpoint_deg: arm 'gantry' joint 1 is prismatic (m): give setpoint in rad and m, not "
        "setpoint_deg")
    wrong = mutated(far, [1], 102.0)
    assert _error(_with_setpoint(GANTRY, setpoint=wrong)) == (
        "<scenario>: control.setpoint: arm 'gantry' joint 2 at 102 rad is more than a turn, a whole number of "
        "radians: degrees? use setpoint_deg")
    deg = [10.0, -20.0, 30.0, 5.0, 15.0, -25.0]
    m = model_from_dict(_with_setpoint(PAPER, setpoint_deg=deg))
    assert m.control.setpoint == pytest.approx(np.deg2rad(deg), rel=1e-15)


def test_an_angle_past_a_turn_within_a_joints_range():
    """A hand-written revolute joint whose range passes a turn takes angles up to its range in rad (the
    paper's 90° as π/2 + 2π within [−10°, 450°]: the same posture); past a turn and outside it, the
    degrees hint."""
    data = mutated(PAPER, ["arms", 0, "links", 0, "joint", "range_deg"], [-10, 450])
    angles = np.deg2rad([90.0, 303.56, 326.44])
    turned = model_from_dict(mutated(data, ["arms", 0, "initial"], {"angles": (angles + [2 * np.pi, 0, 0]).tolist()}))
    plain = model_from_dict(mutated(data, ["arms", 0, "initial"], {"angles": angles.tolist()}))
    assert turned.q0[0] == angles[0] + 2 * np.pi and np.array_equal(turned.q0[1:], plain.q0[1:])
    assert _error(mutated(data, ["arms", 0, "initial"], {"angles": [8.0, 5.3, 5.7]})) == (
        "<scenario>: arms[0].initial.angles: joint 1 at 8 rad is more than a turn, outside its range [-0.174533, "
        "7.85398] rad: degrees? use angles_deg")
