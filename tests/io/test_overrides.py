"""`--set PATH=VALUE` (coopsim/io/overrides.py): the overridden scenario is the edited file, bad paths and
values are one-line errors naming the path (exit 2)."""

import json

import numpy as np
import pytest
import yaml

from helpers import SCENARIOS, mutated, run_cli
from coopsim.io.overrides import OverrideError, apply_overrides, format_path, parse_assignment, parse_path
from coopsim.io.scenario import load_scenario
from coopsim.io.yaml_rules import load_yaml

CARRY = SCENARIOS / "paper_planar_2x3_carry.yaml"


@pytest.mark.parametrize("path, parts", [
    ("object.box.density", ("object", "box", "density")),
    ("arms[1].motors.stall_torque[0]", ("arms", 1, "motors", "stall_torque", 0)),
    ("inverse.object_motion.waypoints[2].position", ("inverse", "object_motion", "waypoints", 2, "position")),
    ("a[0][1]", ("a", 0, 1)),
])
def test_paths_parse_and_print_back(path, parts):
    assert parse_path(path) == parts
    assert format_path(parts) == path


def test_override_equals_the_edited_file(tmp_path):
    """Every field kind the issue names: a density, a motor of arm 2, the payload, a waypoint; the model
    built with --set is the model of a file edited by hand (and the data itself is not changed)."""
    data = load_yaml(CARRY)
    sets = ["object.box.density=2700", "arms[1].motors.stall_torque[0]=0.7", "inverse.payload.position=[0.1, 0.02, 0]",
            "inverse.object_motion.waypoints[2].position=[0.73, 0.85, 0.0]"]
    pairs = [parse_assignment(s) for s in sets]
    over = apply_overrides(data, pairs)
    assert data == load_yaml(CARRY)                       # the input is left alone
    edited = mutated(mutated(mutated(mutated(data, ["object", "box", "density"], 2700),
                                     ["arms", 1, "motors", "stall_torque"], [0.7, 0.96, 0.96]),
                             ["inverse", "payload", "position"], [0.1, 0.02, 0]),
                     ["inverse", "object_motion", "waypoints", 2, "position"], [0.73, 0.85, 0.0])
    assert over == edited
    (tmp_path / "carry.yaml").write_text(yaml.safe_dump(edited))
    a, b = load_scenario(CARRY, overrides=pairs), load_scenario(tmp_path / "carry.yaml")
    assert a.object.mass == b.object.mass == pytest.approx(2700 * 0.4 * 0.06 * 0.1, rel=1e-15)   # ρ · volume
    assert np.array_equal(a.motors.stall_torque, b.motors.stall_torque) and a.motors.stall_torque[3] == 0.7
    assert np.array_equal(a.inverse.payload_position, [0.1, 0.02, 0.0])
    assert np.array_equal(a.inverse.object_motion.positions, b.inverse.object_motion.positions)


def test_cli_set_gives_the_numbers_of_the_edited_file(workdir):
    data = mutated(load_yaml(SCENARIOS / "paper_planar_2x3.yaml"), ["object", "box", "density"], 2700)
    (workdir / "light.yaml").write_text(yaml.safe_dump(data))
    a = run_cli("simulate", "scenarios/paper_planar_2x3.yaml", "--duration", "0.2", "--json",
                "--set", "object.box.density=7850", "--set", "object.box.density=2700", cwd=workdir)   # the last wins
    b = run_cli("simulate", "light.yaml", "--duration", "0.2", "--json", cwd=workdir)
    assert a.returncode == b.returncode == 0, a.stderr + b.stderr
    sa, sb = json.loads(a.stdout), json.loads(b.stdout)
    del sa["wall_time_s"], sb["wall_time_s"]
    assert sa == sb


@pytest.mark.parametrize("assignment, message", [
    ("objct.box.density=1", "--set objct.box.density: the scenario has no key 'objct' (its keys: name,"),
    ("arms[5].motors.stall_torque[0]=1", "--set arms[5].motors.stall_torque[0]: arms has 2 items, so [5] does not exist"),
    ("arms[0].motors.stall_torque[7]=1", "arms[0].motors.stall_torque has 3 items, so [7] does not exist"),
    ("object.box.density.x=1", "--set object.box.density.x: object.box.density is not a mapping (it holds 7850)"),
    ("arms.name=a", "--set arms.name: arms is not a mapping (it holds a list)"),
    ("object..box=1", "--set object..box: malformed path at character 8"),
    ("arms[x].name=a", "--set arms[x].name: malformed path at character 5"),
    ("object.box.density", "--set object.box.density: expected PATH=VALUE"),
    ("object.box.density=[1, 2", "--set object.box.density: value '[1, 2': malformed YAML"),
    # validated as the file is: the same lines as an edited file gets
    ("object.box.density=-3", "paper_planar_2x3.yaml: object.box.density: must be positive, got -3.0"),
    ("object.box.density=1e3", "paper_planar_2x3.yaml: object.box.density: expected a number, got '1e3'"),
    ("object.box.densty=3", "paper_planar_2x3.yaml: object.box.densty: unknown field (known here: density, size)"),
])
def test_bad_set_is_one_line_naming_the_path(workdir, assignment, message):
    out = run_cli("simulate", "scenarios/paper_planar_2x3.yaml", "--set", assignment, cwd=workdir)
    assert out.returncode == 2
    assert out.stderr.count("\n") == 1 and out.stderr.startswith("coopsim: error: ")
    assert message in out.stderr, out.stderr


def test_every_scenario_command_takes_set():
    from coopsim.cli import build_parser

    parser = build_parser()
    for command in ("simulate", "run", "validate", "mjcf", "inverse", "capacity", "optimize", "animate", "view",
                    "sweep"):
        args = parser.parse_args([command, "x.yaml", "--set", "a=1", "--set", "b=2"])
        assert args.set == ["a=1", "b=2"], command
    with pytest.raises(OverrideError, match="no key 'a'"):
        apply_overrides({"b": 1}, [("a.c", 1)])


def test_a_section_the_file_leaves_out_is_set_whole():
    """`inverse.optimize` is absent from the paper carry: its fields cannot be reached one by one (a typo in
    a section name must not create it), the error says how to set it, and the whole section is validated as
    the file's would be."""
    with pytest.raises(OverrideError, match=r"inverse has no key 'optimize' .*inverse\.optimize=\{\.\.\.\}"):
        apply_overrides(load_yaml(CARRY), [("inverse.optimize.control_points", 3)])
    m = load_scenario(CARRY, overrides=[parse_assignment("inverse.optimize={control_points: 3, starts: 2}")])
    assert (m.inverse.optimize.control_points, m.inverse.optimize.starts) == (3, 2)
    assert load_scenario(CARRY).inverse.optimize.control_points == 4             # the default
