"""The retimed optimum replayed open loop through the forward dynamics (`coopsim.report.optimum_replay`) on the
paper carry: the native model against the optimised joint path (the closed-chain IK of the retimed motion,
independent of the forward dynamics), the MuJoCo twin against the native model (MuJoCo's own integrator
and weld constraints), and the replay's run log read back as `coopsim animate` reads it."""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from coopsim.apps.animate.motion import log_payload
from coopsim.inverse import retime as rt
from coopsim.inverse.retime_weights import with_weights
from coopsim.io.log import read_run_log
from coopsim.io.mcap_codec import write_mcap
from coopsim.io.scenario import load_scenario
from coopsim.report import optimum_replay as optimum_replay_module
from coopsim.report.optimize_report import retime_study
from coopsim.report.optimum_replay import optimum_replay, replay_run_log, replay_summary
from helpers import SCENARIOS


@pytest.fixture(scope="module")
def replayed():
    """The bare object's minimum-time law (min energy, --payload 0: 4.9 s, the motors on their lines at the
    critical points), replayed."""
    model = load_scenario(SCENARIOS / "paper_planar_2x3_carry.yaml")
    study = retime_study(model, payload=0.0, intervals=6, methods=("min_energy",))
    return study, optimum_replay(study)


def test_the_native_replay_follows_the_optimised_path_and_the_twin_the_native_run(replayed):
    """Native against the optimised joint path within 1e-8 rad (the bound of the native replay test of the
    retiming) over the whole law, open loop; the torques within their lines up to the law's excess between
    grid points (≤ 1e-2 τ_s on this coarse grid); the twin within every threshold of the scenario."""
    study, rep = replayed
    s = replay_summary(rep)
    assert s["mass_kg"] == 0.0 and s["duration_s"] == pytest.approx(study.methods["min_energy"].bare.duration, rel=1e-9)
    assert s["duration_s"] == pytest.approx(s["output_dt_s"] * (s["samples"] - 1), rel=1e-12)
    assert s["native"]["max_angle_error_rad"] <= 1e-8
    assert s["native"]["max_line_excess"] <= 1e-2
    assert s["twin"]["passed"], rep.cross.comparison.failures()
    assert s["twin"]["max_angle_error_rad"] <= rep.cross.native.model.validation.max_angle_error


def test_the_replay_run_log_reads_back_as_a_run_log(replayed, tmp_path):
    """Native and twin series, the scenario named for `coopsim animate`, the native angles as replayed, the
    payload's mass and position (object frame) for the animation to draw."""
    _, rep = replayed
    streams, meta = replay_run_log(rep, {"scenario": {"file": "scenarios/paper_planar_2x3_carry.yaml"}})
    path = write_mcap(tmp_path / "optimum_run.mcap", streams, meta)
    log = read_run_log(path)
    assert {"/native/joint_state", "/mujoco/joint_state"} <= set(log.topics)
    assert np.array_equal(log.topics["/native/joint_state"]["angle"], rep.cross.native.q)
    assert log.metadata["scenario"]["file"] == "scenarios/paper_planar_2x3_carry.yaml"
    payload = log_payload(log)               # what `coopsim animate` draws on the object
    assert (payload.mass, payload.mode) == (rep.mass, "payload")
    assert np.array_equal(payload.position, rep.cross.native.model.inverse.payload_position)


@pytest.fixture(scope="module")
def lp_replayed():
    """The LP bound's bare-object minimum-time law (--payload 0, 6 intervals a segment: 4.01 s), replayed with
    its wrenches between the grid points (`coopsim.inverse.lp_replay`)."""
    model = load_scenario(SCENARIOS / "paper_planar_2x3_carry.yaml")
    study = retime_study(model, payload=0.0, intervals=6, methods=(rt.LP_BOUND,), method=rt.LP_BOUND)
    return study, optimum_replay(study)


def test_the_lp_bound_is_replayed_within_its_lines(lp_replayed):
    """The LP bound's optimum: native within 1e-8 rad of the optimised path (its wrenches meet the object wrench
    equation exactly, so they move nothing but the internal wrench), the twin within every threshold of the
    scenario. The interpolant of the LP's wrenches alone leaves the lines by more than the linear resolutions'
    replays allow on this grid (1e-2 τ_s); the wrenches replayed keep them widened by REFINE_TOL at every sample
    (1e-13 for the QP's rounding), the object wrench equation to 1e-12 there, and the excess the native run
    reports from its own torques is the distribution's (1e-12)."""
    study, rep = lp_replayed
    s = replay_summary(rep)
    d = s["lp_distribution"]
    assert s["method"] == rt.LP_BOUND and s["mass_kg"] == 0.0
    assert s["duration_s"] == pytest.approx(study.methods[rt.LP_BOUND].bare.duration, rel=1e-9)
    assert s["native"]["max_angle_error_rad"] <= 1e-8
    assert s["twin"]["passed"], rep.cross.comparison.failures()
    assert d["interpolated"] and d["interpolant_max_line_excess"] > 1e-2 and d["corrected_samples"] >= 1
    assert d["without_distribution_samples"] == 0
    assert s["native"]["max_line_excess"] <= rt.REFINE_TOL + 1e-13
    assert s["native"]["max_line_excess"] == pytest.approx(d["max_line_excess"], abs=1e-12)
    assert d["max_wrench_residual"] <= 1e-12


def test_the_twin_reads_the_native_torques_at_the_native_knots(lp_replayed):
    """Native and twin are driven by the same torques: the twin's tables hold the native tables' values at
    every native knot (copied, not recomputed), and more knots at its own RK4 stage times."""
    _, rep = lp_replayed
    for nat, tw in zip(rep.native.sim.model.torques, rep.twin_model.torques):
        at = np.isin(tw.times, nat.times)
        assert at.sum() == len(nat.times) and len(tw.times) > len(nat.times)
        assert np.array_equal(tw.values[at], nat.values)


def test_a_law_retimed_with_its_weights_is_replayed_with_them(replayed, monkeypatch):
    """With --weights the minimum energy's torques are those of the weights optimised with the law (the
    scenario's would carry a lighter load and leave the lines); the replay itself is not rerun here."""
    study, _ = replayed
    w = np.linspace(0.5, 2.0, study.model.n_total)
    weighted = replace(study, weights=SimpleNamespace(model=with_weights(study.model, w), weights=w))
    seen = {}
    monkeypatch.setattr(optimum_replay_module, "motion_replay",
                        lambda model, motion, res, *rest: seen.setdefault("res", res))
    optimum_replay(weighted)
    assert np.array_equal(seen["res"].weights, w)
