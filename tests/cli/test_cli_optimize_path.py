"""End-to-end: `coopsim optimize --path` in a temporary folder on the paper carry with one via point: the set
it writes, the optimised scenario loading as it is, bad input and a non-converging
optimiser (one line, nothing written)."""

import json

import pytest
import yaml

from coopsim.io.log import read_run_log
from coopsim.io.scenario import load_scenario
from helpers import run_cli

SMALL = {"control_points": 1, "sample_dt": 0.5, "starts": 1}


def _scenario(workdir, **optimize):
    path = workdir / "scenarios" / "paper_planar_2x3_carry.yaml"
    data = yaml.safe_load(path.read_text())
    data["inverse"]["optimize"] = SMALL | optimize
    path.write_text(yaml.safe_dump(data))
    return path


def test_optimize_path_writes_one_set(workdir):
    """With --retime and --replay beside it: optimize.json's path entry holds the payloads, the gain over the
    scenario's own path (its quintic law) and over the own path retimed, the solver's runs and the checks; the
    written scenario loads as any scenario (its capacity: tests/report/test_path_report.py); both optima are
    replayed in the one set (native within 1e-8 rad, the twin within the thresholds: the figures in
    tests/report/test_path_report.py), each with its run log."""
    out = run_cli("optimize", _scenario(workdir), "--retime", "--intervals", "6", "--path", "--method", "paper",
                  "--replay", "--json", "--out", "res", cwd=workdir)
    assert out.returncode == 0, out.stderr
    summary = json.loads(out.stdout)
    p = summary["path"]
    assert summary["methods"]["paper"]["after"]["mass_kg"] > 0           # the retiming beside it
    kg = p["payload_kg"]
    assert p["success"] and p["solver"]["runs"][0]["status"] == 0
    assert kg["free_path_retimed"] > kg["own_path_retimed"] > kg["own_path"]
    assert p["gain"]["over_own_path"] == pytest.approx(kg["free_path_retimed"] / kg["own_path"])
    assert p["checks"]["brute_force"]["ok"]
    files = {f.name for f in (workdir / "res").iterdir()}
    assert {"optimize.json", "optimize.mcap", "optimize_path.png", "optimize_payload_time.png",
            "paper_planar_2x3_carry_path.yaml", "paper_planar_2x3_carry_retimed.yaml", "optimum_run.mcap",
            "optimum_path_run.mcap"} <= files
    for rep, source in ((summary["replay"], "retimed"), (p["replay"], "free_path")):
        assert rep["source"] == source and rep["native"]["max_angle_error_rad"] <= 1e-8 and rep["twin"]["passed"]
        assert {"/native/joint_state", "/mujoco/joint_state"} <= set(read_run_log(workdir / rep["log"]).topics)
    assert p["replay"]["mass_kg"] == kg["free_path_retimed"]
    m = load_scenario(workdir / "res" / "paper_planar_2x3_carry_path.yaml")
    assert m.inverse.object_motion.path is not None and m.inverse.object_motion.time_law == "sampled"


@pytest.mark.parametrize("args,optimize,message", [
    (["--path", "--weights", "--method", "nonsqueezing"], {},
     "coopsim: error: --weights: the energy weights are the minimum energy's; give --method min_energy"),
    (["--path", "--weights", "--method", "lp"], {},
     "coopsim: error: --weights: the energy weights are the minimum energy's; give --method min_energy"),
    (["--path", "--method", "paper"], {"max_iterations": 1},
     "coopsim: error: optimize --path: the free-path optimiser did not converge: its best run (K = 1, 1 iteration) "
     "ended with SLSQP status 9: the iteration limit was reached (inverse.optimize.max_iterations: 1)"),
])
def test_bad_input_or_no_convergence_is_one_line_and_writes_nothing(workdir, args, optimize, message):
    out = run_cli("optimize", _scenario(workdir, **optimize), *args, "--out", "res", cwd=workdir)
    assert out.returncode == 2
    assert out.stderr.count("\n") == 1 and out.stderr.startswith(message)
    assert not (workdir / "res").exists()


def test_optimize_path_lp_writes_its_set(workdir):
    """--path --method lp (the best distribution; a 1 s optimiser grid, so 13 retiming intervals): optimize.json's
    path entry (method lp, the LP free path at least the straight path's capacity and its retimed payload at least
    the own path's retimed, the checks without a brute-force rerun) and the free path's scenario, which loads
    as it is."""
    out = run_cli("optimize", _scenario(workdir, sample_dt=1.0), "--path", "--method", "lp", "--json", "--out", "res",
                  cwd=workdir)
    assert out.returncode == 0, out.stderr
    p = json.loads(out.stdout)["path"]
    kg = p["payload_kg"]
    assert p["method"] == "lp" and p["success"] and p["checks"]["brute_force"] is None
    assert kg["free_path_scenario_law_optimiser_grid"] >= kg["straight_path"] * (1 - 1e-9)
    assert kg["free_path_retimed"] >= kg["own_path_retimed"] * (1 - 1e-9) > 0
    assert p["checks"]["retimed_grid_excess"] <= 1e-9
    files = {f.name for f in (workdir / "res").iterdir()}
    assert {"optimize.json", "optimize.mcap", "optimize_path.png", "paper_planar_2x3_carry_path.yaml"} <= files
    m = load_scenario(workdir / "res" / "paper_planar_2x3_carry_path.yaml")
    assert m.inverse.object_motion.path is not None and m.inverse.object_motion.time_law == "sampled"


def test_weights_with_the_free_path_are_written_into_its_scenario(workdir):
    """--path --weights (min energy): the path entry's weights are the optimised ones (not all equal) and the
    written scenario carries them arm by arm, so `coopsim inverse`/`capacity` of it use the optimum's Q."""
    out = run_cli("optimize", _scenario(workdir), "--path", "--weights", "--json", "--out", "res", cwd=workdir)
    assert out.returncode == 0, out.stderr
    w = json.loads(out.stdout)["path"]["weights"]
    assert max(w) > 1.01 * min(w)
    m = load_scenario(workdir / "res" / "paper_planar_2x3_carry_path.yaml")
    assert m.motors.energy_weight.tolist() == w
