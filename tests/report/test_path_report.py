"""The free-path study on the paper carry (one via point, a 0.5 s grid): its checks, the optimised scenario
written back and read as any scenario, the path figure, the optimum replayed native and in the twin."""

from dataclasses import replace

import numpy as np
import pytest
import yaml

from coopsim.inverse.capacity import method_capacity
from coopsim.inverse.problem import inverse_problem
from coopsim.inverse.trajectory import object_motion_trajectory
from coopsim.io.log import read_run_log
from coopsim.io.mcap_codec import log_data, write_mcap
from coopsim.io.scenario import model_from_dict
from coopsim.plots.free_path import path_jobs
from coopsim.report.optimum_replay import path_replay, replay_run_log, replay_summary
from coopsim.report.path_report import format_path_summary, path_scenario, path_series, path_study, path_summary
from helpers import SCENARIOS
from inverse_cases import model

CARRY = "paper_planar_2x3_carry"


@pytest.fixture(scope="module")
def study():
    m = model(CARRY)
    opt = replace(m.inverse.optimize, control_points=1, sample_dt=0.5, starts=1)
    return path_study(replace(m, inverse=replace(m.inverse, optimize=opt)), "paper")


def test_checks_and_gains(study):
    """Gains are measured against the scenario's own path; the independent checks hold: the inverse dynamics
    rerun just below and above the capacity, the retimed law within eq. 36 at its grid and on the 10× finer
    grid between its points (1e-9 of τ_s: the check points' rows, which the B-spline joint path's recipe
    computes), the open
    loop replay of the optimum to 1e-8 rad with every torque within its line (1e-9 of τ_s)."""
    s = path_summary(study)
    p, c = s["payload_kg"], s["checks"]
    assert s["success"]
    assert p["free_path_retimed"] >= p["free_path_scenario_law"] * (1 - 1e-6) > p["own_path"]
    assert p["free_path_retimed"] > p["own_path_retimed"]
    assert s["gain"]["over_own_path"] == pytest.approx(p["free_path_retimed"] / p["own_path"])
    assert c["brute_force"]["ok"]
    assert c["finer_grid_kg"] <= c["scenario_grid_kg"] * (1 + 1e-12)
    assert c["retimed_grid_excess"] <= 1e-9 and c["retimed_fine_excess"] <= 1e-9
    assert c["replay_max_angle_error_rad"] <= 1e-8
    assert c["replay_max_line_excess"] <= 1e-9
    assert "free path" in format_path_summary(s)


def test_optimised_scenario_reads_back(study):
    """The written scenario (two waypoints, the B-spline, the sampled retimed law) loads as it is, holds the
    optimum's path bit for bit, and its own capacity (its 0.02 s samples) is the retimed payload to 2 %
    (the retimed law meets the lines at its grid points; between them it may exceed them slightly)."""
    data = yaml.safe_load((SCENARIOS / f"{CARRY}.yaml").read_text())
    m = model_from_dict(yaml.safe_load(yaml.safe_dump(path_scenario(data, study.motion))), where="opt.yaml")
    om = m.inverse.object_motion
    assert om.path.positions.tobytes() == study.motion.path.positions.tobytes()
    assert om.time_law == "sampled" and len(om.times) == 2
    c = method_capacity(inverse_problem(m, object_motion_trajectory(m, om), m.inverse.payload_position),
                        study.optimum.resolution, m.motors, study.optimum.mode)
    assert c.mass == pytest.approx(study.optimum.retimed.mass, rel=2e-2)


def test_path_figure(study):
    log = log_data(path_series(study), {"scenario": {"name": CARRY}})
    [(builder, args, path)] = path_jobs(log, "out")
    assert path.name == "optimize_path.png"
    fig = builder(*args)
    assert len(fig.axes) >= 2 and all(np.isfinite(log.topics["/optimize/path/free"]["p_C"]).ravel())


def test_the_free_path_optimum_replays_native_and_twin(study, tmp_path):
    """The written scenario's motion (the B-spline path under the sampled retimed law) at the retimed payload,
    replayed open loop (`coopsim.report.optimum_replay.path_replay`): native within 1e-8 rad of the optimised
    joint path (the closed-chain IK, independent of the forward dynamics), every torque within its line up to
    the retimed law's excess between its grid points (≤ 1e-2 τ_s on this 0.5 s grid), the twin within every
    threshold of the scenario; the log reads back as a run log of the loaded model."""
    rep = path_replay(study)
    s = replay_summary(rep)
    assert s["source"] == "free_path" and s["log"] == "optimum_path_run.mcap"
    assert s["mass_kg"] == study.optimum.retimed.mass
    assert s["duration_s"] == pytest.approx(float(study.motion.times[-1] - study.motion.times[0]), rel=1e-9)
    assert s["native"]["max_angle_error_rad"] <= 1e-8
    assert s["native"]["max_line_excess"] <= 1e-2
    assert s["twin"]["passed"], rep.cross.comparison.failures()
    streams, meta = replay_run_log(rep, {"scenario": {"file": f"scenarios/{CARRY}.yaml"}})
    log = read_run_log(write_mcap(tmp_path / s["log"], streams, meta))
    assert np.array_equal(log.topics["/native/joint_state"]["angle"], rep.cross.native.q)
    assert log.metadata["scenario"]["file"] == f"scenarios/{CARRY}.yaml"
