"""The optimum replayed in closed loop (`coopsim.report.closed_replay`) where open loop it leaves the
thresholds: the Panda ceiling carry (two 7R arms holding a tray against gravity, open-loop unstable),
its paper W⁺ heaviest load within 1.5 s on a coarse grid (10 intervals a segment). The tracking is
measured against the optimised joint path (the closed-chain IK, independent of both forward models), the
feedback torque against the PD law evaluated here from the run's own states, the twin against the native
closed loop on the scenario's thresholds."""

import json
from dataclasses import replace

import numpy as np
import pytest

from coopsim.apps.animate import RenderUnavailable, motion_from_log, probe_renderer
from coopsim.io.log import CLOSED_LOOP, file_sha256, read_run_log
from coopsim.io.mcap_codec import UnreadableLogError, write_mcap
from coopsim.io.robots import robots_folder
from coopsim.io.scenario import load_scenario
from coopsim.report import closed_replay
from coopsim.report.closed_replay import (
    closed_loop_reason,
    closed_loop_replay,
    closed_metadata,
    closed_replay_of,
    closed_series,
    closed_summary,
    feedback_gains,
    format_replay_entry,
    replay_entry,
)
from coopsim.report.optimize_report import retime_study
from coopsim.report.optimum_replay import optimum_replay, replay_run_log, replay_summary
from helpers import SCENARIOS, run_cli

PANDA = SCENARIOS / "robots" / "panda_ceiling_carry.yaml"

pytestmark = pytest.mark.skipif(robots_folder() is None,
                                reason="example-robot-data is not installed: pip install 'coopsim[robots]'")


@pytest.fixture(scope="module")
def panda_study():
    model = load_scenario(PANDA)
    return model, retime_study(model, duration=1.5, intervals=10, methods=("paper",), method="paper")


@pytest.fixture(scope="module")
def panda(panda_study):
    model, study = panda_study
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
    e = replay_entry(rep, closed_replay_of(model, rep))
    assert e["open_loop"] and e["closed_loop"]["why"] == "open loop outside the thresholds"
    assert e["closed_loop"]["topics"] == {"native": "/closed_loop/native", "twin": "/closed_loop/mujoco"}
    assert "closed loop (open loop outside the thresholds)" in format_replay_entry(e)
    assert "closed_loop" not in replay_entry(rep)


def test_the_default_law_stiffens_while_the_native_loop_leaves_the_threshold(panda):
    """Without a control: section ω = 10 rad/s is tried first (the fixture holds the scenario's 1e-6 rad with
    it: one try); with the threshold set below its error the replay tries ω = 30 rad/s next, with 9× the
    gains (Kp ∝ ω², Kd ∝ ω), and keeps it (the last of OMEGAS) though on this stable loop it holds no
    closer (the error is the feedforward's between grid points, not a growth), each try's largest native
    joint error reported as measured here from the kept run."""
    model, rep, cr = panda
    assert [w for w, _ in cr.tries] == [10.0] and cr.tries[0][1] <= model.validation.max_angle_error
    tight = replace(model, validation=replace(model.validation, max_angle_error=cr.tries[0][1] / 2))
    cr2 = closed_loop_replay(tight, rep, "asked")
    assert [w for w, _ in cr2.tries] == list(closed_replay.OMEGAS) == [10.0, 30.0]
    assert cr2.tries[0][1] == pytest.approx(cr.tries[0][1], rel=1e-9)
    err = float(np.max(np.abs(cr2.native.q - rep.traj.q)))
    assert err == cr2.tries[-1][1] > tight.validation.max_angle_error
    assert np.allclose(cr2.kp, 9 * cr.kp, rtol=1e-12) and np.allclose(cr2.kd, 3 * cr.kd, rtol=1e-12)
    assert closed_summary(cr2, rep.traj)["omega_tries"][-1] == {"omega_rad_s": 30.0, "native_max_angle_error_rad": err}


@pytest.fixture(scope="module")
def closed_log(panda, tmp_path_factory):
    """The optimum's run log as `coopsim optimize --replay` writes it with its closed loop (open loop, the
    closed-loop series and record), naming the scenario file by its absolute path and sha256."""
    model, rep, cr = panda
    meta = {"scenario": {"file": str(PANDA), "sha256": file_sha256(PANDA)}} | closed_metadata(cr)
    streams, records = replay_run_log(rep, meta, closed_series(cr))
    return write_mcap(tmp_path_factory.mktemp("closed_log") / "optimum_run.mcap", streams, records), streams, records


def test_the_run_log_holds_both_closed_loops_as_they_ran(panda, closed_log):
    """The run log read back (`read_run_log`, which checks the closed-loop pair like the open loop's) holds the
    open loop under /native and /mujoco as before and the closed loop under /closed_loop/native and
    /closed_loop/mujoco: sample times, joint angles, rates, applied torques (the ClosedReplay's, i.e. the
    feedforward plus the PD law), object pose, the controller's reference (the optimised joint path) and
    angle error, exactly (the codec stores float64 as its repr); its record names the gains."""
    model, rep, cr = panda
    log = read_run_log(closed_log[0])
    js = log.topics["/native/joint_state"]
    assert np.array_equal(js["angle"], rep.native.sim.q)
    for side, res, tau, rec in (("native", cr.native, cr.tau, cr.control[0]), ("mujoco", cr.twin, cr.twin_tau,
                                                                               cr.control[1])):
        js, ob, ctl = (log.topics[f"{CLOSED_LOOP}/{side}/{k}"] for k in ("joint_state", "object", "control"))
        assert np.array_equal(js["t"], res.t) and np.array_equal(js["angle"], res.q), side
        assert np.array_equal(js["rate"], res.qd) and np.array_equal(js["torque"], tau), side
        assert np.array_equal(ob["position"], res.object_pos), side
        assert np.array_equal(ctl["reference_angle"], rec.q_ref) and np.array_equal(ctl["torque"], rec.tau), side
    assert np.array_equal(cr.control[0].tau, cr.tau)
    # the logged reference is the optimised joint path (independent of the runs) and the error is q_r - q
    ctl = log.topics[f"{CLOSED_LOOP}/native/control"]
    assert np.max(np.abs(ctl["reference_angle"] - rep.traj.q)) <= 1e-12
    assert np.max(np.abs(ctl["angle_error"] - (rep.traj.q - cr.native.q))) <= 1e-12
    rec = log.metadata["closed_loop"]
    assert rec["why"] == cr.why and np.array_equal(json.loads(rec["kp"]), cr.kp)


def test_a_closed_loop_pair_missing_a_series_is_not_a_run_log(closed_log, tmp_path):
    """The reader checks the closed-loop pair as it checks the open loop's: without
    /closed_loop/mujoco/constraint the log is refused, naming that topic."""
    _, streams, records = closed_log
    path = write_mcap(tmp_path / "cut.mcap", [s for s in streams if s.topic != f"{CLOSED_LOOP}/mujoco/constraint"],
                      records)
    with pytest.raises(UnreadableLogError, match="no /closed_loop/mujoco/constraint series"):
        read_run_log(path)


def test_animate_draws_the_closed_loop(panda, closed_log, tmp_path):
    """`motion_from_log(closed_loop=True)` takes the closed loop's angles (not the open loop's, which differ
    by the open loop's drift), and `coopsim animate LOG --closed-loop` renders it (where OpenGL starts);
    on a log without a closed loop --closed-loop is one line and exit 2."""
    model, rep, cr = panda
    m = motion_from_log(closed_log[0], closed_loop=True)
    assert np.array_equal(m.q_native, cr.native.q) and np.array_equal(m.q_twin, cr.twin.q)
    assert m.source.startswith("closed loop of log") and m.payload.mass == rep.mass
    assert np.max(np.abs(motion_from_log(closed_log[0]).q_native - cr.native.q)) > 0
    bare = write_mcap(tmp_path / "open.mcap", *replay_run_log(rep, {"scenario": {"file": str(PANDA),
                                                                                 "sha256": file_sha256(PANDA)}}))
    try:
        probe_renderer()
    except RenderUnavailable as exc:
        pytest.skip(f"no offscreen OpenGL: {exc}")
    out = run_cli("animate", closed_log[0], "--closed-loop", "--duration", "0.2", "--fps", "10", "--width", "96",
                  "--height", "72", "--out", "a.gif", "--json", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    report = json.loads(out.stdout)
    assert report["frames"] == 3 and report["source"].startswith("closed loop of log"), report
    qn, qt = m.at(np.array([0.0, 0.1, 0.2]))
    assert report["max_angle_difference_rad"] == pytest.approx(float(np.max(np.abs(qn - qt))), rel=1e-9), report
    bad = run_cli("animate", bare, "--closed-loop", "--out", "b.gif", cwd=tmp_path)
    assert bad.returncode == 2 and "no /closed_loop/native/joint_state" in bad.stderr, bad.stderr


def test_optimize_writes_the_closed_loop_into_the_optimum_run_log(panda_study, panda, workdir, monkeypatch):
    """`coopsim optimize --retime --replay --closed-loop` (the fixtures' study and replays standing in for the
    runs, which are the fixtures' own tests above): the set as without the closed loop, optimize.json's
    closed_loop naming its topics, and optimum_run.mcap holding the open loop and the closed loop that entry
    reports, its largest joint error against the optimised path the entry's."""
    from coopsim.report import optimize_report, optimum_replay as optimum

    model, rep, cr = panda
    monkeypatch.setattr(optimize_report, "retime_study", lambda *a, **k: panda_study[1])
    monkeypatch.setattr(optimum, "optimum_replay", lambda study, progress=None: rep)
    monkeypatch.setattr(closed_replay, "closed_loop_replay", lambda m, r, why: replace(cr, why=why))
    out = run_cli("optimize", "scenarios/robots/panda_ceiling_carry.yaml", "--retime", "--duration", "1.5",
                  "--intervals", "10", "--method", "paper", "--replay", "--closed-loop", "--json", "--out", "res",
                  cwd=workdir)
    assert out.returncode == 0, out.stderr
    entry = json.loads(out.stdout)["replay"]["closed_loop"]
    assert entry["why"] == "asked" and entry["topics"]["native"] == "/closed_loop/native"
    assert sorted(p.name for p in (workdir / "res").iterdir()) == sorted(
        ["optimize.json", "optimize.mcap", "optimize_motors.png", "optimize_payload_time.png",
         "optimize_phase_plane.png", "panda_ceiling_carry_retimed.yaml", "optimum_run.mcap"])
    log = read_run_log(workdir / "res" / "optimum_run.mcap")
    assert np.array_equal(log.topics["/native/joint_state"]["angle"], rep.native.sim.q)
    for side, res in (("native", cr.native), ("mujoco", cr.twin)):
        q = log.topics[f"{CLOSED_LOOP}/{side}/joint_state"]["angle"]
        assert np.array_equal(q, res.q), side
    err = np.max(np.abs(log.topics[f"{CLOSED_LOOP}/mujoco/joint_state"]["angle"] - rep.traj.q))
    assert err == entry["twin"]["max_angle_error_rad"]
    assert log.metadata["closed_loop"]["why"] == "asked"


def test_a_computed_torque_section_on_redundant_arms_falls_back_to_joint_pd(panda):
    """The scenario's computed_torque law needs square arms (`Controller` refuses the Panda's 7R for 6 rows):
    with such a section the replay runs joint PD about the optimised joint path, its gains the law's object
    gains per unit joint inertia (Kp = 100 I_jj, Kd = 20 I_jj), and still tracks within the scenario's
    1e-6 rad."""
    from coopsim.core.model import ControlSettings

    model, rep, cr = panda
    n = model.n_total
    ct = replace(model, control=ControlSettings("computed_torque", np.zeros(n), np.zeros(n), distribution="paper",
                                                object_kp=np.array([100.0, 100.0]), object_kd=np.array([20.0, 20.0])))
    assert closed_replay.computed_torque_loop(ct, rep) is None
    cr2 = closed_loop_replay(ct, rep, "asked")
    kp, kd, _ = feedback_gains(ct, rep.traj.q[0])
    assert cr2.law == "joint_pd" and np.array_equal(cr2.kp, kp) and np.allclose(kd, 0.2 * kp, rtol=1e-12)
    assert closed_summary(cr2, rep.traj)["control_law"] == "joint_pd"
    assert float(np.max(np.abs(cr2.native.q - rep.traj.q))) <= model.validation.max_angle_error
