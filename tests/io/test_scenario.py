"""Scenario loading: the bundled files load; every malformed input fails with one line naming the field."""


import numpy as np
import pytest
import yaml

from coopsim.core.model import torque_at
from coopsim.io.scenario import load_scenario, model_from_dict
from coopsim.core.errors import ConstraintError, ScenarioError
from coopsim.forward.simulate import initial_state
from helpers import SCENARIOS, mutated, paper_residual_by_hand

PAPER = yaml.safe_load((SCENARIOS / "paper_planar_2x3.yaml").read_text())


def test_paper_scenario_reproduces_table_1(paper):
    """Link masses 7850·0.6·0.04² = 7.536 kg, object 7850·0.4·0.06·0.1 = 18.84 kg, planar rows,
    end-effector gap 0.4 m + 3.1e-5 m before projection (the rounding of the paper's angles)."""
    assert paper.arms[0].link_mass == pytest.approx([7.536, 7.536, 0.628], rel=1e-14)
    assert paper.object.mass == pytest.approx(18.84, rel=1e-14)
    assert paper.plane is not None and paper.rows.shape == (3, 6)
    assert np.rad2deg(paper.q0[:3]) == pytest.approx([90.0, 303.56, 326.44], rel=1e-14)
    init = initial_state(paper)
    # 3.1147e-5 m: regression pin (number produced by coopsim itself); independently, planar
    # trigonometry on the YAML's numbers gives the same gap, all of it along x.
    assert init.residual_before == pytest.approx(3.1147e-5, rel=1e-3), f"residual before projection {init.residual_before}"
    gap = paper_residual_by_hand()
    assert init.residual_before == pytest.approx(abs(gap[0]), rel=1e-9, abs=0) and np.max(np.abs(gap[1:])) <= 1e-15, \
        f"residual before projection {init.residual_before!r} m vs [Δx, Δy, Δψ] = {gap} by hand"
    assert init.residual_after <= 1e-12




CASES = [
    (["arms", 0, "links", 1, "box", "density"], -7850, r"arms\[0\]\.links\[1\]\.box\.density: must be positive"),
    (["arms", 0, "links", 0, "joint", "axis"], [0, 0, 0], r"arms\[0\]\.links\[0\]\.joint\.axis: zero-length axis"),
    (["arms", 1, "initial", "angles_deg"], [90, 56.44], r"arms\[1\]\.initial\.angles_deg: expected shape 3"),
    (["arms", 0, "initial"], {"angles": [90.0, 303.56, 326.44]}, r"arms\[0\]\.initial\.angles: .*degrees\? use angles_deg"),
    (["arms", 0, "torque"], {"constant": [0.5, "x", 0]}, r"arms\[0\]\.torque\.constant: expected numbers"),
    (["arms", 0, "colour"], "red", r"arms\[0\]\.colour: unknown field"),
    (["duration"], -1.0, r"duration: must be positive"),
    (["duration"], "five", r"duration: expected a number"),
    (["duration"], None, r"duration: missing required field"),
    (["object", "box", "size"], [0.4, 0.06], r"object\.box\.size: expected shape 3"),
    (["object", "grasps", 1, "arm"], "arm7", r"object\.grasps\[1\]\.arm: no arm 'arm7'"),
    (["object", "grasps", 1, "position"], [2.5, 0.0, 0.0], r"object\.grasps\[1\]: arm 'arm2' cannot reach its grasp"),
    (["integrator", "method"], "euler", r"integrator\.method: must be one of dop853, dopri5, rk4"),
    (["arms", 0, "motors", "stall_torque"], [0.55, -0.96, 0.96], r"arms\[0\]\.motors\.stall_torque: must be positive"),
    (["arms", 0, "torque"], {"csv": "missing.csv"}, r"arms\[0\]\.torque\.csv: file not found"),
    (["arms", 0, "torque"], {"table": {"time": [0, 1, 1], "values": [[0, 0, 0]] * 3}},
     r"arms\[0\]\.torque\.table: times must be strictly increasing"),
    (["arms", 0, "links", 0, "inertial"], {"mass": 1.0, "inertia": [1, 1, 1, 0, 0, 0]},
     r"arms\[0\]\.links\[0\]\.box: give exactly one of box or inertial"),
    (["arms"], [PAPER["arms"][0]], r"arms: expected a list of at least 2 entries"),
    (["object"], {"inertial": {"mass": -18.84, "inertia": [0.27, 0.26, 0.02, 0, 0, 0]}, "grasps": "derive"},
     r"object\.inertial\.mass: must be positive"),
]


@pytest.mark.parametrize("path,value,message", CASES, ids=[".".join(map(str, c[0])) for c in CASES])
def test_bad_input_names_the_field(path, value, message):
    with pytest.raises(ScenarioError, match=message) as info:
        model_from_dict(mutated(PAPER, path, value), where="s.yaml")
    assert "\n" not in str(info.value)
    assert str(info.value).startswith("s.yaml: ")


def test_explicit_inertia_must_be_physical():
    link = {"joint": {"axis": [0, 0, 1]}, "inertial": {"mass": 1.0, "com": [0.3, 0, 0], "inertia": [1.0, 1.0, 5.0, 0, 0, 0]}}
    data = mutated(PAPER, ["arms", 0, "links", 0], link)
    with pytest.raises(ScenarioError, match=r"arms\[0\]\.links\[0\]\.inertial\.inertia: principal moments .* triangle"):
        model_from_dict(data, where="s.yaml")


def test_grasp_needing_a_large_correction_is_rejected(paper):
    """A reachable but wrong grasp (0.1 m off) needs more than max_initial_correction."""
    model = model_from_dict(mutated(PAPER, ["object", "grasps", 1, "position"], [0.3, 0.0, 0.0]), where="s.yaml")
    with pytest.raises(ConstraintError, match=r"object\.grasps: closing the loop .* needs a joint correction of"):
        initial_state(model)


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ScenarioError, match="scenario file not found"):
        load_scenario(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("arms: [1, 2\nduration: 3\n")
    with pytest.raises(ScenarioError, match=r"bad\.yaml: malformed YAML at line"):
        load_scenario(bad)


def test_torque_table_and_csv_inputs(tmp_path):
    csv = tmp_path / "tau.csv"
    csv.write_text("time,t1,t2,t3\n0,0,0,0\n1,1,2,3\n")
    data = mutated(PAPER, ["arms", 0, "torque"], {"csv": "tau.csv"})
    data = mutated(data, ["arms", 1, "torque"], {"table": {"time": [0, 2], "values": [[0, 0, 0], [2, 4, 6]]}})
    scen = tmp_path / "s.yaml"
    scen.write_text(yaml.safe_dump(data))
    model = load_scenario(scen)
    assert torque_at(model.torques, 0.5) == pytest.approx([0.5, 1.0, 1.5, 0.5, 1.0, 1.5], rel=1e-15)
    assert torque_at(model.torques, 5.0) == pytest.approx([1, 2, 3, 2, 4, 6], rel=1e-15)


def test_derived_grasps_close_the_loop_exactly(spatial):
    assert initial_state(spatial).residual_before <= 1e-14


CARRY = yaml.safe_load((SCENARIOS / "paper_planar_2x3_carry.yaml").read_text())
ENDS = [CARRY["inverse"]["object_motion"]["waypoints"][i] for i in (0, -1)]
PATH = {"kind": "bspline", "control_points": [{"position": [0.76, 0.92, 0.0], "rotation_vector": [0, 0, 0.05]},
                                              {"position": [0.74, 0.91, 0.0]}]}
SPLINE = mutated(mutated(CARRY, ["inverse", "object_motion", "waypoints"], ENDS), ["inverse", "object_motion", "path"],
                 PATH)


def test_object_path_and_optimize_settings():
    """A B-spline path between two waypoints (rotation vectors default to zero) and inverse.optimize."""
    data = mutated(SPLINE, ["inverse", "optimize"], {"control_points": 6, "starts": 2, "seed": 7,
                                                      "manipulability_margin": 0.25, "sample_dt": 0.2})
    inv = model_from_dict(data, where="s.yaml").inverse
    path = inv.object_motion.path
    assert path.kind == "bspline"
    assert path.positions.tolist() == [[0.76, 0.92, 0.0], [0.74, 0.91, 0.0]]
    assert path.rotation_vectors.tolist() == [[0, 0, 0.05], [0, 0, 0]]
    opt = inv.optimize
    assert (opt.control_points, opt.starts, opt.seed, opt.manipulability_margin, opt.sample_dt) == (6, 2, 7, 0.25, 0.2)
    assert model_from_dict(CARRY, where="s.yaml").inverse.object_motion.path is None


OM = ["inverse", "object_motion"]
PATH_CASES = [
    (mutated(SPLINE, OM + ["waypoints"], CARRY["inverse"]["object_motion"]["waypoints"]),
     r"inverse\.object_motion\.waypoints: a path runs between two waypoints \(its ends\), got 4"),
    (mutated(SPLINE, OM + ["path", "kind"], "bezier"), r"inverse\.object_motion\.path\.kind: must be one of bspline"),
    (mutated(SPLINE, OM + ["path", "control_points"], []),
     r"inverse\.object_motion\.path\.control_points: expected a list of at least 1"),
    (mutated(SPLINE, OM + ["path", "control_points", 1, "rotation_vector"], [0, 0, 3.2]),
     r"inverse\.object_motion\.path\.control_points\[1\]\.rotation_vector: must be shorter than pi rad"),
    (mutated(SPLINE, OM + ["path", "control_points", 0, "rpy"], [0, 0, 1]),
     r"inverse\.object_motion\.path\.control_points\[0\]\.rpy: unknown field"),
    (mutated(CARRY, ["inverse", "optimize"], {"control_points": 0}),
     r"inverse\.optimize\.control_points: must be positive"),
    (mutated(CARRY, ["inverse", "optimize"], {"control_points": 2.5}),
     r"inverse\.optimize\.control_points: must be a whole number"),
    (mutated(CARRY, ["inverse", "optimize"], {"manipulability_margin": 1.0}),
     r"inverse\.optimize\.manipulability_margin: must be below 1"),
    (mutated(CARRY, ["inverse", "optimize"], {"grid": 3}), r"inverse\.optimize\.grid: unknown field"),
    (mutated(CARRY, OM + ["rest_pull"], "speed"), r"inverse\.object_motion\.rest_pull: must be one of time, path"),
]


@pytest.mark.parametrize("data,message", PATH_CASES, ids=[m.split(":")[0].replace("\\", "") for _, m in PATH_CASES])
def test_bad_path_or_optimize_names_the_field(data, message):
    with pytest.raises(ScenarioError, match=message) as info:
        model_from_dict(data, where="s.yaml")
    assert "\n" not in str(info.value)


def test_a_sampled_time_law_is_read_and_checked():
    """time_law: sampled reads its samples (t, s, rate); samples that do not meet a constant s̈ between them,
    or miss a waypoint, are one line naming time_law_samples' field."""
    data = yaml.safe_load((SCENARIOS / "paper_planar_2x3_carry.yaml").read_text())
    om = data["inverse"]["object_motion"]
    om["waypoints"] = om["waypoints"][:2]
    om["time_law"] = "sampled"
    # rest to rest in 5 s over s ∈ [0, 1]: ṡ = 0, 0.4, 0 at t = 0, 2.5, 5 (s = 0, 0.5, 1)
    om["time_law_samples"] = {"t": [0.0, 2.5, 5.0], "s": [0.0, 0.5, 1.0], "rate": [0.0, 0.4, 0.0]}
    law = model_from_dict(data, where="s.yaml").inverse.object_motion.samples
    assert law.t.tolist() == [0.0, 2.5, 5.0] and law.rate.tolist() == [0.0, 0.4, 0.0]
    bad = mutated(data, ["inverse", "object_motion", "time_law_samples", "rate"], [0.0, 0.3, 0.0])
    with pytest.raises(ScenarioError, match=r"^s\.yaml: inverse\.object_motion\.time_law_samples\.rate: samples 0 "
                                            r"and 1 do not meet a constant acceleration"):
        model_from_dict(bad, where="s.yaml")
    bad = mutated(data, ["inverse", "object_motion", "time_law_samples", "t"], [0.0, 2.5, 4.0])
    with pytest.raises(ScenarioError, match=r"time_law_samples\.t: must increase strictly from the first "
                                            r"waypoint's time 0 s to the last's 5 s"):
        model_from_dict(bad, where="s.yaml")


def test_the_rest_pull_is_read():
    assert model_from_dict(CARRY, where="s.yaml").inverse.object_motion.rest_pull == "time"
    data = mutated(CARRY, OM + ["rest_pull"], "path")
    assert model_from_dict(data, where="s.yaml").inverse.object_motion.rest_pull == "path"
