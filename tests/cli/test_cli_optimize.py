"""End-to-end: `coopsim optimize --retime` in a temporary folder — the output set, the optimised scenario
accepted as it is by `coopsim capacity`, and bad input as one line naming the field with exit 2 and
nothing written."""

import json
from pathlib import Path

import pytest
import yaml

from coopsim.inverse import retime as rt
from coopsim.io.log import read_run_log
from coopsim.io.mcap_codec import read_mcap
from coopsim.io.scenario import load_scenario
from helpers import run_cli

CARRY = "scenarios/paper_planar_2x3_carry.yaml"


def test_retime_the_paper_carry_and_run_capacity_on_the_result(workdir):
    """A coarse grid (8 intervals a segment): every method heavier after than before, the exact check at the
    grid within 1e-9 of τ_s, the set (scenario, optimize.json, optimize.mcap, 3 figures, with --replay the
    optimum's run log) complete; the optimised scenario loads in `coopsim capacity`, whose min-energy
    payload capacity along the sampled law is the optimum up to the law's excess between grid points
    (within 2 %). The replay of the heaviest load's law (13 s open loop): native within 1e-8 rad of the
    optimised path, the twin within the scenario's thresholds, and its log a run log as `coopsim animate`
    reads it, naming the scenario it draws. With --weights: the minimum energy's weights optimised with its
    law carry more than equal weights, the written scenario carries them arm by arm (so its capacity above is
    with them), and the replay's resolution is the one with them."""
    out = run_cli("optimize", CARRY, "--retime", "--replay", "--weights", "--intervals", "8", "--json", "--out",
                  "res", cwd=workdir)
    assert out.returncode == 0, out.stderr
    s = json.loads(out.stdout)
    for k, e in s["methods"].items():
        assert e["after"]["mass_kg"] > e["before"]["mass_kg"], k
        assert e["after"]["duration_s"] <= 13.0
        assert e["check_grid"]["max_excess"] <= 1e-9
        assert len(e["saturating_motor_per_point"]) == s["grid"]["points"]
    names = sorted(p.name for p in (workdir / "res").iterdir())
    assert names == sorted(["optimize.json", "optimize.mcap", "optimize_motors.png", "optimize_payload_time.png",
                            "optimize_phase_plane.png", "paper_planar_2x3_carry_retimed.yaml", "optimum_run.mcap"])
    rep = s["replay"]
    assert rep["mass_kg"] == s["methods"]["min_energy"]["after"]["mass_kg"] and rep["duration_s"] <= 13.0
    assert rep["native"]["max_angle_error_rad"] <= 1e-8 and rep["twin"]["passed"]
    assert rep["log"] == str(Path("res") / "optimum_run.mcap")
    run = read_run_log(workdir / rep["log"])
    assert {"/native/joint_state", "/mujoco/joint_state"} <= set(run.topics)
    assert run.metadata["scenario"]["file"] == CARRY
    log = read_mcap(workdir / "res" / "optimize.mcap")
    assert {"/optimize/min_energy/law", "/optimize/min_energy/torque", "/optimize/lp/law"} <= set(log.topics)
    data = yaml.safe_load((workdir / "res" / "paper_planar_2x3_carry_retimed.yaml").read_text())
    assert data["inverse"]["object_motion"]["time_law"] == "sampled"
    assert data["inverse"]["object_motion"]["rest_pull"] == "path"            # the joint path retimed
    e = s["methods"]["min_energy"]
    ew = e["energy_weights"]
    assert ew["rounds"][0]["mass_kg"] < e["after"]["mass_kg"]
    # the study's own search with those weights, on path dynamics of its own (their check points' rows found
    # afresh): the last round's payload within the search's tolerance (Brent, rtol 1e-10)
    assert e["after"]["mass_kg"] == pytest.approx(ew["rounds"][-1]["mass_kg"], rel=1e-9)
    assert [w for arm in data["arms"] for w in arm["energy_weights"]] == list(ew["weights"].values())
    cap = run_cli("capacity", "res/paper_planar_2x3_carry_retimed.yaml", "--no-optimise", "--json", "--out", "cap",
                  cwd=workdir)
    assert cap.returncode == 0, cap.stderr
    c = json.loads(cap.stdout)["capacity"]["payload"]["min_energy"]["mass_kg"]
    assert c == pytest.approx(s["methods"]["min_energy"]["after"]["mass_kg"], rel=0.02)


@pytest.mark.parametrize("args, edit, line", [
    (["--duration", "0.5"], None, "coopsim: error: --duration: no motion carries the bare object along the path "
                                  "within 0.5 s"),
    ([], ("waypoints", [1.4, 1.0, 0.0]), "coopsim: error: inverse.object_motion: the path leaves the workspace of "
                                         "arm 'arm1' at s="),
    ([], ("gravity", [0.0, -9.81, 0.0]), "coopsim: error: motors.stall_torque: arm "),
])
def test_bad_input_is_one_line_naming_the_field_and_writes_nothing(workdir, args, edit, line):
    """A duration bound below the bare object's minimum time, a waypoint out of reach, motors too weak to
    hold the bar against gravity in the plane (stall torques 0.55–0.96 N·m, the bar ~ 9.4 kg): exit 2, one
    line, no output folder."""
    path = workdir / CARRY
    if edit is not None:
        data = yaml.safe_load(path.read_text())
        if edit[0] == "waypoints":
            data["inverse"]["object_motion"]["waypoints"][1]["position"] = edit[1]
        else:
            data["gravity"] = edit[1]
        path.write_text(yaml.safe_dump(data))
    out = run_cli("optimize", CARRY, "--retime", "--intervals", "4", "--out", "res", *args, cwd=workdir)
    assert out.returncode == 2
    assert out.stderr.count("\n") == 1 and out.stderr.startswith(line), out.stderr
    assert not (workdir / "res").exists()


def test_a_linearisation_that_does_not_converge_says_so_and_writes_nothing(workdir, monkeypatch):
    """One linearisation allowed: the command names the method, the status and the last change, exit 2."""
    monkeypatch.setattr(rt, "MAX_LINEARISATIONS", 1)
    out = run_cli("optimize", CARRY, "--retime", "--intervals", "4", "--out", "res", cwd=workdir)
    assert out.returncode == 2
    assert "the linearisation of the motor lines did not converge" in out.stderr
    assert "status: not converged after 1 linearisations" in out.stderr
    assert not (workdir / "res").exists()


def test_the_lp_bound_is_replayed_in_its_set(workdir):
    """--method lp --replay (the bare object's minimum-time law, 4 intervals a segment): the complete set with
    the optimum's run log; the replay's native run within 1e-8 rad of the optimised path, the twin within the
    scenario's thresholds, the LP's wrenches between its grid points keeping the lines widened by REFINE_TOL
    (1e-13 for the QP's rounding) and the object wrench equation to 1e-12."""
    out = run_cli("optimize", CARRY, "--retime", "--method", "lp", "--payload", "0", "--replay", "--intervals", "4",
                  "--json", "--out", "res", cwd=workdir)
    assert out.returncode == 0, out.stderr
    s = json.loads(out.stdout)
    names = sorted(p.name for p in (workdir / "res").iterdir())
    assert names == sorted(["optimize.json", "optimize.mcap", "optimize_motors.png", "optimize_payload_time.png",
                            "optimize_phase_plane.png", "paper_planar_2x3_carry_retimed.yaml", "optimum_run.mcap"])
    rep = s["replay"]
    assert rep["method"] == "lp" and rep["mass_kg"] == 0.0
    assert rep["duration_s"] == pytest.approx(s["methods"]["lp"]["payload"]["duration_s"], rel=1e-9)
    assert rep["native"]["max_angle_error_rad"] <= 1e-8 and rep["twin"]["passed"]
    assert rep["native"]["max_line_excess"] <= rt.REFINE_TOL + 1e-13
    assert rep["lp_distribution"]["max_wrench_residual"] <= 1e-12
    assert {"/native/joint_state", "/mujoco/joint_state"} <= set(read_run_log(workdir / rep["log"]).topics)


@pytest.mark.parametrize("args, line", [
    (["--replay"], "coopsim: error: optimize: give --retime (the fixed path's time law) and/or --path"),
    (["--retime", "--closed-loop"], "coopsim: error: --closed-loop: replays the optimum under feedback; give it "
                                    "with --replay"),
])
def test_replay_without_an_optimum_is_refused(workdir, args, line):
    """--replay alone (nothing to replay), --closed-loop without --replay: one line, exit 2, nothing written."""
    out = run_cli("optimize", CARRY, *args, "--out", "res", cwd=workdir)
    assert out.returncode == 2 and out.stderr.startswith(line), out.stderr
    assert not (workdir / "res").exists()


def test_weights_of_another_resolution_are_refused(workdir):
    out = run_cli("optimize", CARRY, "--retime", "--weights", "--method", "paper", "--out", "res", cwd=workdir)
    assert out.returncode == 2
    assert out.stderr.startswith("coopsim: error: --weights: the energy weights are the minimum energy's")
    assert not (workdir / "res").exists()


def test_closed_loop_replay_of_a_computed_torque_scenario_runs_its_law(workdir):
    """`coopsim optimize scenarios/control/control_paper_carry.yaml --retime --replay --closed-loop` on its first
    segment shortened to 3 s (--set), 4 intervals, T_max 3 s: the set written with the run log; the replay's
    closed loop runs the scenario's computed_torque law (named in optimize.json and the run log's record),
    its native loop within 1e-10 rad and 1e-10 m of the optimised path (measured 3.5e-14 rad, 9.0e-15 m; the
    bound the law's own test holds, `tests/report/test_closed_replay_computed_torque.py`), the twin within the
    scenario's thresholds and agreeing with it; the log's closed-loop control topics are the object-space law's."""
    scenario = "scenarios/control/control_paper_carry.yaml"
    first = ("inverse.object_motion.waypoints=[{time: 0.0, position: [0.75, 0.9316786, 0.0], rpy_deg: [0, 0, 0]}, "
             "{time: 3.0, position: [0.80, 0.88, 0.0], rpy_deg: [0, 0, 5]}]")
    out = run_cli("optimize", scenario, "--retime", "--replay", "--closed-loop", "--intervals", "4", "--duration", "3",
                  "--set", first, "--json", "--out", "res", cwd=workdir)
    assert out.returncode == 0, out.stderr
    names = {p.name for p in (workdir / "res").iterdir()}
    assert {"control_paper_carry_retimed.yaml", "optimize.json", "optimum_run.mcap"} <= names
    c = json.loads(out.stdout)["replay"]["closed_loop"]
    assert c["why"] == "asked" and c["control_law"] == "computed_torque"
    assert c["native"]["max_angle_error_rad"] <= 1e-10 and c["native"]["max_object_position_error_m"] <= 1e-10
    thr = load_scenario(workdir / scenario).validation.max_angle_error
    assert c["twin"]["max_angle_error_rad"] <= thr and c["twin_vs_native"]["passed"]
    run = read_run_log(workdir / "res" / "optimum_run.mcap")
    assert run.metadata["closed_loop"]["control_law"] == "computed_torque"
    assert "pose_error" in run.topics["/closed_loop/native/control"]
