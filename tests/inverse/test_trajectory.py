"""Stage 6 — trajectories: the forward run's samples, the Hermite interpolant between them, the quintic
time law, closed-chain inverse kinematics of a prescribed object motion, and its error reports."""

from dataclasses import replace

import numpy as np
import pytest
import yaml

from coopsim.dynamics.closed_chain import position_residual
from coopsim.core.model import ObjectMotion
from coopsim.io.scenario import model_from_dict
from coopsim.core.errors import ScenarioError
from coopsim.forward.simulate import simulate
from coopsim.core.spatial import rot_log, rpy_to_rot
from coopsim.inverse import problem as problem_module
from coopsim.inverse import trajectory as trajectory_module
from coopsim.inverse.trajectory import (TrajectoryError, from_simulation, object_motion_at, object_motion_trajectory,
                                object_pose_of, shared_object_motion_trajectory, time_law, trajectory_at)
from coopsim.report import inverse_report
from coopsim.report.inverse_report import capacity_study, capacity_summary
from helpers import SCENARIOS, mutated
from inverse_cases import model, run

CARRY = "paper_planar_2x3_carry"


def test_hermite_interpolant_of_a_forward_run():
    """Exact at the samples (to rounding); at the midpoints of a 10 ms grid it matches a run sampled
    every 5 ms to 1e-11 rad, 1e-10 rad/s and 1e-8 rad/s² (the forward run's θ̈ is exact at its samples)."""
    m = model("paper_planar_2x3")
    coarse = from_simulation(simulate(replace(m, duration=0.5)))
    fine = simulate(replace(m, duration=0.5, integrator=replace(m.integrator, output_dt=0.005)))
    for i in (0, 7, 50):
        q, qd, qdd = trajectory_at(coarse, coarse.t[i])
        assert q == pytest.approx(coarse.q[i], rel=1e-14, abs=0)
        assert qd == pytest.approx(coarse.qd[i], rel=1e-13, abs=1e-15)
        assert qdd == pytest.approx(coarse.qdd[i], rel=1e-13, abs=1e-15)
    errs = np.zeros(3)
    for j in range(1, len(fine.t), 2):
        got = trajectory_at(coarse, fine.t[j])
        errs = np.maximum(errs, [np.max(np.abs(g - r)) for g, r in zip(got, (fine.q[j], fine.qd[j], fine.qdd[j]))])
    assert errs[0] <= 1e-11 and errs[1] <= 1e-10 and errs[2] <= 1e-8, errs


@pytest.mark.parametrize("kind", ["quintic", "cubic"])
def test_time_law_ends_and_derivatives(kind):
    """s(0) = 0, s(1) = 1, ṡ = 0 at both ends (and s̈ = 0 for the quintic); derivatives agree with
    central differences to 1e-7."""
    s0, ds0, dds0 = time_law(kind, 0.0)
    s1, ds1, dds1 = time_law(kind, 1.0)
    assert (s0, s1, ds0, ds1) == pytest.approx((0, 1, 0, 0), abs=1e-15)
    if kind == "quintic":
        assert (dds0, dds1) == pytest.approx((0, 0), abs=1e-15)
    h = 1e-5
    for u in (0.2, 0.5, 0.9):
        sp, sm = time_law(kind, u + h), time_law(kind, u - h)
        assert time_law(kind, u)[1] == pytest.approx((sp[0] - sm[0]) / (2 * h), abs=1e-7)
        assert time_law(kind, u)[2] == pytest.approx((sp[1] - sm[1]) / (2 * h), abs=1e-7)


def test_object_motion_passes_the_waypoints():
    m = model(CARRY)
    mo = m.inverse.object_motion
    for k, t in enumerate(mo.times):
        p, R, tw, ac = object_motion_at(mo, t)
        assert p == pytest.approx(mo.positions[k], abs=1e-15)
        assert np.max(np.abs(rot_log(R @ mo.rotations[k].T))) <= 1e-15
        assert np.max(np.abs(tw)) <= 1e-15 and np.max(np.abs(ac)) <= 1e-12


def test_inverse_kinematics_follows_the_prescribed_object():
    """Carry scenario (13 s, 20 ms samples): the loop is closed to 1e-12, the carried object is at the
    prescribed pose (1e-12 m, rad), and θ, θ̇, θ̈ are consistent: the Hermite interpolant of the 20 ms
    samples matches an inverse-kinematics solve at the midpoints to 1e-10 rad (1e-8 rad/s, 1e-6 rad/s²)."""
    m, _, traj = run(CARRY)
    mo = m.inverse.object_motion
    assert traj.t[-1] == pytest.approx(13.0) and len(traj.t) == 651
    worst_loop, worst_pose = 0.0, 0.0
    for t, q in zip(traj.t[::10], traj.q[::10]):
        worst_loop = max(worst_loop, float(np.max(np.abs(position_residual(m, q)))))
        p, R = object_pose_of(m, q)
        p_ref, R_ref, _, _ = object_motion_at(mo, t)
        worst_pose = max(worst_pose, float(np.max(np.abs(p - p_ref))), float(np.max(np.abs(rot_log(R @ R_ref.T)))))
    assert worst_loop <= 1e-12 and worst_pose <= 1e-12
    mid = object_motion_trajectory(m, ObjectMotion(mo.times[:2] * 1, mo.positions[:2], mo.rotations[:2],
                                                   mo.time_law, 0.01, None))
    errs = np.zeros(3)
    for j in range(1, len(mid.t), 2):
        got = trajectory_at(traj, mid.t[j])
        errs = np.maximum(errs, [np.max(np.abs(g - r)) for g, r in zip(got, (mid.q[j], mid.qd[j], mid.qdd[j]))])
    assert errs[0] <= 1e-10 and errs[1] <= 1e-8 and errs[2] <= 1e-6, errs


def _motion(positions, yaws_deg, times=None):
    times = np.arange(len(positions), dtype=float) if times is None else np.asarray(times, float)
    return ObjectMotion(times, np.array(positions, float), np.array([rpy_to_rot([0, 0, np.deg2rad(y)]) for y in yaws_deg]),
                        "quintic", 0.05, None)


def test_out_of_reach_singular_and_off_plane_paths_are_reported():
    m = model(CARRY)
    start = [0.75, 0.9316786, 0.0]
    with pytest.raises(TrajectoryError, match=r"leaves the workspace of arm 'arm1' at t=.* s .*reach 1\.25 m"):
        object_motion_trajectory(m, _motion([start, [1.4, 1.0, 0.0]], [0, 0]))
    # ends with arm 1 fully stretched (θ₂ = 0: wrist 1.2 m from its base at 60°, link 3 along +x);
    # the last Newton solve lands on the other elbow branch, which the sign of det S J reveals
    wrist = 1.2 * np.array([np.cos(np.pi / 3), np.sin(np.pi / 3), 0.0])
    singular = wrist + [0.05 + 0.2, 0, 0]
    with pytest.raises(TrajectoryError, match=r"arm 'arm1' crosses a singularity between t=0\.95 s and t=1 s"):
        object_motion_trajectory(m, _motion([start, singular], [0, 0]))
    with pytest.raises(TrajectoryError, match=r"arm1' leaves the plane of motion"):
        object_motion_trajectory(m, _motion([start, [0.75, 0.9, 0.05]], [0, 0]))


def test_arms_with_fewer_joints_than_rows_are_refused():
    """Three joints for six rows (the planar arms forced onto spatial rows): the grasp cannot be held.
    (Arms with more joints than rows are resolved: tests/inverse/test_redundant.py.)"""
    paper = model(CARRY)
    forced = replace(paper, rows=np.eye(6))
    with pytest.raises(TrajectoryError, match=r"arm 'arm1' has 3 joints for 6 constrained rows; .*at least as many"):
        object_motion_trajectory(forced, paper.inverse.object_motion)


CARRY_YAML = yaml.safe_load((SCENARIOS / f"{CARRY}.yaml").read_text())


@pytest.mark.parametrize("path,value,message", [
    (["inverse", "colour"], "red", r"inverse\.colour: unknown field"),
    (["inverse", "trajectory"], "spline", r"inverse\.trajectory: must be one of forward, object_motion"),
    (["inverse", "object_motion", "waypoints", 1, "time"], 0.0, r"inverse\.object_motion\.waypoints: times must be strictly increasing"),
    (["inverse", "object_motion", "time_law"], "septic", r"inverse\.object_motion\.time_law: must be one of"),
    (["inverse", "object_motion"], None, r"inverse\.object_motion: trajectory: object_motion needs"),
    (["inverse", "nonsqueezing_masses"], [1.0, -1.0], r"inverse\.nonsqueezing_masses: must be positive"),
    (["inverse", "payload"], {"position": [0, 0]}, r"inverse\.payload\.position: expected shape 3"),
    (["inverse", "internal_bound"], {"force": -1.0}, r"inverse\.internal_bound\.force: must be non-negative"),
    (["inverse", "object_motion", "rest_gain"], -1.0, r"inverse\.object_motion\.rest_gain: must be non-negative"),
    (["inverse", "object_motion", "rest_posture"], [0.0] * 5, r"inverse\.object_motion\.rest_posture: expected shape 6"),
])
def test_inverse_section_errors_name_the_field(path, value, message):
    data = mutated(CARRY_YAML, path, value)
    with pytest.raises(ScenarioError, match=message):
        model_from_dict(data, where="carry.yaml")


def test_inverse_section_defaults_and_values():
    m = model(CARRY)
    assert m.inverse.trajectory == "object_motion" and m.inverse.object_motion.output_dt == 0.02
    assert m.inverse.payload_position == pytest.approx([0.2, 0, 0])
    assert m.inverse.object_motion.rest_posture is None and m.inverse.object_motion.rest_gain == 1.0
    data = mutated(mutated(CARRY_YAML, ["inverse", "object_motion", "rest_gain"], 3.0),
                   ["inverse", "object_motion", "rest_posture_deg"], [90.0] * 6)
    om = model_from_dict(data, where="carry.yaml").inverse.object_motion
    assert om.rest_gain == 3.0 and om.rest_posture == pytest.approx([np.pi / 2] * 6, rel=1e-15)
    assert model("paper_planar_2x3").inverse.trajectory == "forward"


def test_points_that_differ_only_in_the_payload_share_one_trajectory(monkeypatch):
    """Two models that differ in the payload's position and the motors get the trajectory computed once
    (each its own writable copy), equal to a recomputation bit for bit; a longer link gets its own."""
    monkeypatch.setattr(trajectory_module, "_shared", type(trajectory_module._shared)())
    m = model(CARRY)
    here = replace(m, inverse=replace(m.inverse, payload_position=np.array([0.1, 0.02, 0.0])))
    there = replace(m, inverse=replace(m.inverse, payload_position=np.array([-0.2, 0.0, 0.0])),
                    motors=replace(m.motors, stall_torque=2 * m.motors.stall_torque))
    a = shared_object_motion_trajectory(here, here.inverse.object_motion)
    b = shared_object_motion_trajectory(there, there.inverse.object_motion)
    fresh = object_motion_trajectory(m, m.inverse.object_motion)
    assert len(trajectory_module._shared) == 1 and a.q is not b.q and a.q.flags.writeable
    for name in ("t", "q", "qd", "qdd"):
        assert np.array_equal(getattr(a, name), getattr(fresh, name)), name
        assert np.array_equal(getattr(b, name), getattr(fresh, name)), name
    arm = m.arms[0]
    longer = replace(m, arms=(replace(arm, ee_pos=arm.ee_pos * 1.01),) + m.arms[1:])
    c = shared_object_motion_trajectory(longer, longer.inverse.object_motion)
    assert len(trajectory_module._shared) == 2 and not np.array_equal(c.q, a.q)


def test_a_capacity_study_on_a_shared_trajectory_equals_one_computed_afresh(monkeypatch):
    """The capacity of two payload positions, the second on the first's shared trajectory, per-sample
    terms and 'scaled' LP bound, equals the same study with nothing shared (every number of the summary,
    to the last bit); the second point computed none of the three again."""
    m = model(CARRY)
    caches = [(trajectory_module, "_shared"), (problem_module, "_shared_terms"), (inverse_report, "_shared_lps")]
    summaries = {}
    for sharing in (True, False):
        for module, name in caches:
            monkeypatch.setattr(module, name, type(getattr(module, name))())
        out = []
        for x in (0.1, -0.15):
            if not sharing:
                for module, name in caches:
                    getattr(module, name).clear()
            pm = replace(m, inverse=replace(m.inverse, payload_position=np.array([x, 0.0, 0.0])))
            out.append(capacity_summary(capacity_study(pm, payload_position=pm.inverse.payload_position,
                                                       with_lp=True, optimise=False)))
        if sharing:
            assert [len(getattr(module, name)) for module, name in caches] == [1, 1, 1]
        summaries[sharing] = out
    assert summaries[True] == summaries[False]
    assert out[0]["lp_bound"]["payload"] != out[1]["lp_bound"]["payload"]
