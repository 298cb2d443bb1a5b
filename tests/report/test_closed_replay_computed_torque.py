"""The optimum replayed in closed loop under the scenario's computed-torque law (`coopsim.report.closed_replay`):
the computed-torque carry (`control_paper_carry`, minimum energy) on its first segment shortened to 2 s,
its heaviest point payload (18.08 kg at 0.2 m along the bar) retimed on 4 intervals. The loaded model's
frame sits at the composite centre of mass, 0.2·m/(m_o + m) along the bar from the nominal C (a closed form
here). Independent references: the optimum's torques from the Python closed-chain inverse dynamics
(`coopsim.inverse.replay.stage_torques`), the optimised joint path (the closed-chain IK of the optimum) and
its forward kinematics on the loaded model, the scenario's validation thresholds for the twin."""

from dataclasses import replace

import numpy as np
import pytest

from coopsim.control.controller import Controller, record
from coopsim.io.log import CLOSED_LOOP
from coopsim.io.scenario import load_scenario
from coopsim.inverse.replay import stage_torques
from coopsim.report.closed_replay import (closed_loop_replay, closed_metadata, closed_series, closed_summary,
                                          format_replay_entry, replay_entry)
from coopsim.report.optimize_report import retime_study
from coopsim.report.optimum_replay import optimum_replay
from helpers import SCENARIOS

CARRY = SCENARIOS / "control" / "control_paper_carry.yaml"


@pytest.fixture(scope="module")
def carry():
    """(model, its optimum's open-loop replay, the closed loop) of the shortened carry."""
    model = load_scenario(CARRY)
    om = model.inverse.object_motion
    model = replace(model, inverse=replace(model.inverse, object_motion=replace(
        om, times=np.array([0.0, 2.0]), positions=om.positions[:2], rotations=om.rotations[:2])))
    rep = optimum_replay(retime_study(model, intervals=4, methods=("min_energy",), method="min_energy"))
    return model, rep, closed_loop_replay(model, rep, "asked")


def test_the_law_at_the_optimised_states_is_the_optimum(carry):
    """The closed loop's controller evaluated at the optimised joint path's own samples (zero error but for the
    IK's) against τ_opt there, the resolution's torques of the loaded inverse dynamics (Python, independent of
    the compiled law): with the object gains zeroed (the law is then its feedforward alone) equal to 1e-13 of
    τ_s (machine precision: measured 1.9e-15); with the scenario's gains 100/s², 20/s to 1e-9 τ_s, the gains
    times the IK's own pose residual (≤ 1e-12 m, measured 7e-14 m: 1.4e-10 τ_s). Without the reference moved to
    the loaded frame's point the law would pull the frame 0.19 m towards the nominal C: ≥ 10 τ_s off."""
    model, rep, cr = carry
    ctrl = cr.native.model.torques.fn
    t, q, qd = rep.traj.t - rep.traj.t[0], rep.traj.q, rep.traj.qd
    stall = model.motors.stall_torque
    tau_opt = stage_torques(rep.native.sim.model, rep.traj, rep.resolution, t)
    assert cr.law == "computed_torque" and rep.resolution.method == ctrl.settings.distribution == "min_energy"
    gains = dict(object_kp=np.zeros(2), object_kd=np.zeros(2))
    bare = Controller(replace(ctrl.model, control=replace(ctrl.settings, **gains)), resolution=rep.resolution,
                      point=ctrl.point)
    assert np.max(np.abs(record(bare, t, q, qd).tau - tau_opt) / stall) <= 1e-13
    rec = record(ctrl, t, q, qd)
    assert np.max(np.abs(rec.object_error)) <= 1e-12
    assert np.max(np.abs(rec.tau - tau_opt) / stall) <= 1e-9
    unmoved = Controller(ctrl.model, resolution=rep.resolution)
    assert np.max(np.abs(record(unmoved, t, q, qd).tau - tau_opt) / stall) >= 10


def test_the_closed_loop_tracks_the_optimum_native_and_twin(carry):
    """The tracked point is the composite centre, m/(m_o + m)·0.2 m along the bar; the native loop (adaptive
    DOP853 at rtol 1e-12) stays within 1e-10 rad of the optimised joint path and 1e-10 m, 1e-10 rad of the
    loaded frame's pose along it (measured 2.5e-13 rad, 8.5e-14 m, 4.2e-14 rad: the IK's own residual), the
    law's own error at its point the same to 1e-12 m (the reference moved to the right point); its torque
    within 1e-8 τ_s of τ_opt (the gains times that error: measured 2.8e-10 τ_s). The twin (its welds yield:
    1.4e-8 rad) within the scenario's thresholds of the optimised path and of the native loop."""
    model, rep, cr = carry
    m, mo = rep.mass, model.object.mass
    assert np.allclose(cr.point, [0.2 * m / (mo + m), 0.0, 0.0], rtol=1e-12, atol=1e-15)
    s = closed_summary(cr, rep.traj)
    n, tw, v = s["native"], s["twin"], model.validation
    assert n["max_angle_error_rad"] <= 1e-10
    assert max(n["max_object_position_error_m"], n["max_object_orientation_error_rad"]) <= 1e-10
    assert abs(n["max_tracked_position_error_m"] - n["max_object_position_error_m"]) <= 1e-12
    assert np.max(np.abs(cr.tau - cr.feedforward) / model.motors.stall_torque) <= 1e-8
    assert tw["max_angle_error_rad"] <= v.max_angle_error
    assert tw["max_object_position_error_m"] <= v.max_object_position_error
    assert tw["max_object_orientation_error_rad"] <= v.max_object_orientation_error
    assert s["twin_vs_native"]["passed"], cr.comparison.failures()


def test_the_entry_the_log_and_the_record_name_the_law(carry):
    """optimize.json's closed_loop entry names computed_torque and its tracked point, the text line too; the
    run log's control topics are the object-space law's (pose and twist errors, the command), its record names
    the law."""
    model, rep, cr = carry
    e = replay_entry(rep, cr)["closed_loop"]
    assert e["control_law"] == "computed_torque" and "computed torque" in e["law"]
    assert e["tracked_point_m"] == cr.point.tolist() and e["kp"] == [100.0, 100.0]
    assert "closed loop (asked), computed_torque:" in format_replay_entry(replay_entry(rep, cr))
    ctl = {s.topic: s for s in closed_series(cr)}[f"{CLOSED_LOOP}/native/control"]
    assert ctl.schema_name == "coopsim.ObjectControl"
    assert np.array_equal(ctl.fields["pose_error"], cr.control[0].object_error)
    assert closed_metadata(cr)["closed_loop"]["control_law"] == "computed_torque"


def test_a_bspline_optimum_with_the_object_scaled_is_tracked_at_its_own_centre():
    """A free-path optimum's kind of motion (the carry's first segment, 2 s, as a B-spline: 2 interior control
    points moved 2 cm, 0.05 rad about z) with the whole object scaled to 1.5× its mass ('scaled': the frame
    stays at C, tracked point zero), replayed with the paper resolution: the law follows the B-spline, native
    within 1e-10 rad and m of the optimised path (the same bound as the sampled law's above; measured 2.8e-13
    rad, 9.3e-14 m), and the twin within the scenario's thresholds (measured 1.2e-7 rad, its welds yielding)
    and agreeing with the native loop."""
    from coopsim.core.model import PathSpline
    from coopsim.inverse import spline_path
    from coopsim.inverse.free_path import end_poses
    from coopsim.inverse.solve import resolution_for
    from coopsim.report.optimum_replay import motion_replay

    model = load_scenario(CARRY)
    om = model.inverse.object_motion
    ends = end_poses(replace(om, times=np.array([0.0, 2.0]), positions=om.positions[:2], rotations=om.rotations[:2]))
    line = spline_path.straight_control_points(ends, 2)
    path = replace(ends, path=PathSpline(line.kind, line.positions + np.array([[0.02, -0.02, 0.0], [-0.02, 0.02, 0.0]]),
                                         line.rotation_vectors + np.array([[0, 0, 0.05], [0, 0, -0.05]])))
    rep = motion_replay(model, path, resolution_for(model, "paper"), "scaled", 1.5 * model.object.mass, "free_path")
    cr = closed_loop_replay(model, rep, "asked")
    assert cr.law == "computed_torque" and np.array_equal(cr.point, np.zeros(3))
    s = closed_summary(cr, rep.traj)
    assert max(s["native"]["max_angle_error_rad"], s["native"]["max_object_position_error_m"]) <= 1e-10
    assert s["twin"]["max_angle_error_rad"] <= model.validation.max_angle_error and s["twin_vs_native"]["passed"]
