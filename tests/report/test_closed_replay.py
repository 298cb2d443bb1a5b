"""The optimum replayed in closed loop (`coopsim.report.closed_replay`) where open loop it leaves the
thresholds: the Panda ceiling carry (two 7R arms holding a tray against gravity, open-loop unstable),
its paper W⁺ heaviest load within 1.5 s on a coarse grid (10 intervals a segment). The tracking is
measured against the optimised joint path (the closed-chain IK, independent of both forward models), the
feedback torque against the PD law evaluated here from the run's own states, the twin against the native
closed loop on the scenario's thresholds."""

from dataclasses import replace

import numpy as np
import pytest

from coopsim.io.robots import robots_folder
from coopsim.io.scenario import load_scenario
from coopsim.report import closed_replay
from coopsim.report.closed_replay import (
    closed_loop_reason,
    closed_loop_replay,
    closed_summary,
    feedback_gains,
    format_replay_entry,
    replay_entry,
)
from coopsim.report.optimize_report import retime_study
from coopsim.report.optimum_replay import optimum_replay, replay_summary
from helpers import SCENARIOS

pytestmark = pytest.mark.skipif(robots_folder() is None,
                                reason="example-robot-data is not installed: pip install 'coopsim[robots]'")


@pytest.fixture(scope="module")
def panda():
    model = load_scenario(SCENARIOS / "robots" / "panda_ceiling_carry.yaml")
    study = retime_study(model, duration=1.5, intervals=10, methods=("paper",), method="paper")
    rep = optimum_replay(study)
    return model, rep, closed_loop_replay(model, rep, closed_loop_reason(model, rep))


def test_open_loop_drifts_and_the_closed_loop_tracks_the_optimised_path(panda):
    """Open loop the native run leaves the optimised path by more than the scenario's 1e-6 rad (so the
    closed loop runs without being asked); in closed loop both models stay within 1e-6 rad and 1e-6 m of
    it, at least 5× closer than open loop, and the twin agrees with the native loop on every threshold."""
    model, rep, cr = panda
    thr = model.validation.max_angle_error
    assert rep.native.max_angle_error > thr
    assert closed_loop_reason(model, rep) == "open loop outside the thresholds"
    s = closed_summary(cr, rep.traj)
    for side in ("native", "twin"):
        assert s[side]["max_angle_error_rad"] <= min(thr, rep.native.max_angle_error / 5), side
        assert s[side]["max_object_position_error_m"] <= model.validation.max_object_position_error, side
        assert s[side]["max_object_orientation_error_rad"] <= model.validation.max_object_orientation_error, side
    assert s["twin_vs_native"]["passed"], cr.comparison.failures()


def test_the_feedback_is_pd_about_the_optimised_path_on_top_of_the_optimum(panda):
    """τ − τ_opt at the native samples is Kp (θ_r − θ) + Kd (θ̇_r − θ̇) with θ_r the optimised joint path (not
    the loaded plant's own IK: its frame sits at the composite centre, millimetres away) to 1e-9 of τ_s;
    the gains are ω² and 2ω times each joint's inertia (ω = 10 rad/s), the feedback a small share (≤ 1e-4
    τ_s), and the total torque over its lines by no more than the feedforward itself at the replay's samples
    (the law meets the lines at its grid and check points; the samples fall between them: its open-loop
    replay's excess, here ~8e-6 τ_s on this 10-interval grid) plus the feedback's peak, with 10 % for the
    twin's own stage times; no sample saturated."""
    model, rep, cr = panda
    kp, kd, _ = feedback_gains(model, rep.traj.q[0])
    assert np.allclose(kd, 0.2 * kp, rtol=1e-12) and np.all(kp > 0)
    pd = kp * (rep.traj.q - cr.native.q) + kd * (rep.traj.qd - cr.native.qd)
    stall = model.motors.stall_torque
    assert np.max(np.abs(cr.tau - cr.feedforward - pd) / stall) <= 1e-9
    s = closed_summary(cr, rep.traj)
    assert 0 < s["feedback"]["peak_rel_stall"] <= 1e-4
    open_excess = max(replay_summary(rep)["native"]["max_line_excess"], 0.0)
    assert max(s["line_excess"].values()) <= 1.1 * (open_excess + s["feedback"]["peak_rel_stall"])
    assert s["saturation_events"] == 0


def test_the_replay_entry_holds_the_closed_loop_where_asked_or_needed(panda, monkeypatch):
    """optimize.json's entry: the open loop always, "closed_loop" where the open loop fails (the closed loop
    itself is the fixture's, not run again)."""
    model, rep, cr = panda
    monkeypatch.setattr(closed_replay, "closed_loop_replay", lambda m, r, why: replace(cr, why=why))
    e = replay_entry(model, rep)
    assert e["open_loop"] and e["closed_loop"]["why"] == "open loop outside the thresholds"
    assert "closed loop (open loop outside the thresholds)" in format_replay_entry(e)
