"""The computed-torque law's reference from any object motion a scenario holds: the sampled time law
`coopsim optimize --retime` writes (NAME_retimed.yaml) and a B-spline path (NAME_path.yaml's kind), read by
the compiled law through the object-motion IK's own kernel (`coopsim.compiled.object_state.object_state`).

Independent references: the object motion sampled by `coopsim.inverse.trajectory.object_motion_at` (NumPy)
for the tracking error, and the Python controller in the reference time loop (the 'stages' engine, which
reads its reference from `object_motion_at`) for the compiled law itself."""

from dataclasses import replace

import numpy as np
import pytest

from coopsim.control.controller import closed_loop
from coopsim.core.model import PathSpline
from coopsim.core.spatial import orientation_error, rots_to_quats
from coopsim.forward.simulate import simulate
from coopsim.inverse import spline_path
from coopsim.inverse.free_path import end_poses
from coopsim.inverse.trajectory import object_motion_at
from coopsim.io.scenario import load_scenario, scenario_text
from coopsim.io.yaml_rules import load_yaml
from coopsim.report.optimize_report import optimised_scenario, retime_study
from coopsim.report.path_report import path_scenario
from helpers import SCENARIOS

CARRY = SCENARIOS / "control" / "control_paper_carry.yaml"


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """The computed-torque carry's scenario files as `coopsim optimize` writes them: NAME_retimed.yaml (its
    minimum-energy heaviest-load law on 4 intervals a segment, a sampled law through 4 waypoints) and a
    NAME_path.yaml of its first segment (0 to 5 s) bent into a B-spline (2 interior control points moved
    2 cm in the plane, 0.05 rad about z); with them the scenario's own (quintic) model."""
    folder = tmp_path_factory.mktemp("written")
    model, data = load_scenario(CARRY), load_yaml(CARRY)
    study = retime_study(model, intervals=4, methods=("min_energy",), method="min_energy")
    (folder / "retimed.yaml").write_text(scenario_text(optimised_scenario(data, study.motion)))
    om = model.inverse.object_motion
    ends = end_poses(replace(om, times=om.times[:2], positions=om.positions[:2], rotations=om.rotations[:2]))
    line = spline_path.straight_control_points(ends, 2)
    bend = np.array([[0.02, -0.02, 0.0], [-0.02, 0.02, 0.0]])
    path = replace(ends, path=PathSpline(line.kind, line.positions + bend,
                                         line.rotation_vectors + np.array([[0, 0, 0.05], [0, 0, -0.05]])))
    (folder / "path.yaml").write_text(scenario_text(path_scenario(data, path)))
    return model, load_scenario(folder / "retimed.yaml"), load_scenario(folder / "path.yaml")


def _errors(res, motion):
    """The largest object position (m) and orientation (rad) error of a run against `motion` at its samples."""
    ref = [object_motion_at(motion, motion.times[0] + t) for t in res.t]
    p, q = np.array([r[0] for r in ref]), rots_to_quats(np.array([r[1] for r in ref]))
    return (float(np.max(np.linalg.norm(res.object_pos - p, axis=1))),
            float(np.max(orientation_error(res.object_quat, q))))


@pytest.mark.parametrize("which", ["retimed", "path"])
def test_computed_torque_tracks_the_written_motion(written, which):
    """`simulate` of the written file under its computed_torque section (1 s, compiled loop; the torque pulse
    starts at 1 s): with the controller's model exact (mass_scale 1) the object follows the file's own motion,
    sampled law or B-spline, to ≤ 1e-8 m and rad (measured 3.5e-9 m, the projected initial state's own
    offset at t = 0, and 4e-15 rad); with the bundled 10 % mass error to ≤ 5e-5 m (measured 9.9e-6 m on the
    retimed law, 1.4e-5 m on the B-spline), while the motion it replaced (the scenario's quintic law: 4.6e-3 m;
    the straight first segment: 7.1e-3 m) is farther than 100× that: the reference is the written motion, not
    the scenario's waypoints under another law (before, the compiled law had no sampled law: KeyError, and
    the loader refused a path)."""
    model, retimed, path = written
    m = retimed if which == "retimed" else path
    motion = m.inverse.object_motion
    assert (motion.time_law, motion.path is None) == (("sampled", True) if which == "retimed" else ("quintic", False))
    exact = simulate(closed_loop(replace(m, duration=1.0, control=replace(m.control, mass_scale=1.0))))
    assert exact.engine == "compiled"
    assert max(_errors(exact, motion)) <= 1e-8, _errors(exact, motion)
    res = simulate(closed_loop(replace(m, duration=1.0)))
    err = _errors(res, motion)[0]
    other = model.inverse.object_motion if which == "retimed" else end_poses(
        replace(motion, path=None))
    assert err <= 5e-5 and _errors(res, other)[0] >= 100 * err, (err, _errors(res, other))


def test_the_compiled_reference_is_the_python_controllers(written):
    """The compiled loop against the 'stages' engine (the Python controller reading `object_motion_at` at every
    stage) on 40 ms of each written motion, RK4 at 5 ms (no accept/reject decision for round-off to flip):
    the same trajectory and torques to ≤ 1e-10 rad and N·m, as for the waypoint laws
    (`tests/control/test_control_loop.py`; measured 0 rad, 4e-16 N·m on torques up to 1.9 N·m)."""
    for m in written[1:]:
        m = replace(m, duration=0.04, integrator=replace(m.integrator, output_dt=0.02, method="rk4", step=0.005))
        a, b = simulate(closed_loop(m)), simulate(closed_loop(m), engine="stages")
        assert (a.engine, b.engine) == ("compiled", "stages")
        assert np.max(np.abs(a.q - b.q)) <= 1e-10 and np.max(np.abs(a.tau - b.tau)) <= 1e-10
        assert np.max(np.abs(a.q[-1] - a.q[0])) > 1e-7


def test_the_twin_under_the_law_meets_the_native_loop_on_a_sampled_law(written, monkeypatch):
    """The retimed file under its computed_torque section, 3 s (three of the sampled law's samples inside),
    native against the twin at 1 ms RK4 (the automatic step's size here): with the twin's steps cut around
    the samples, where the reference's s̈ jumps (`coopsim.twin.mujoco_run.advance`), within 2e-8 rad
    (measured 7.6e-9 rad, the weld yield's own 7.6e-9 predicted); uncut (the jumps inside RK4 steps) more than
    ten times farther (measured 5.9e-7 rad)."""
    from coopsim.twin import mujoco_run

    m = written[1]
    m = replace(m, duration=3.0, mujoco=replace(m.mujoco, timestep=0.001))
    kinks = mujoco_run.reference_kinks(m)
    assert np.sum((kinks > 0.0) & (kinks < 3.0)) == 3
    native = simulate(closed_loop(m))
    cut = np.max(np.abs(mujoco_run.run_twin(m, native.q[0], native.qd[0], native.t).q - native.q))
    monkeypatch.setattr(mujoco_run, "reference_kinks", lambda model: np.zeros(0))
    uncut = np.max(np.abs(mujoco_run.run_twin(m, native.q[0], native.qd[0], native.t).q - native.q))
    assert cut <= 2e-8 and uncut >= 10 * cut, (cut, uncut)


POINT = np.array([0.19, -0.03, 0.05])    # m, object axes: a body point off every axis


def _spatial_path():
    """The carry's first segment (0 to 5 s, quintic) as a B-spline bent out of the plane: 2 interior control
    points moved 2 cm along every axis and turned 0.1–0.2 rad about x and y, so that ω and ω̇ have every
    component and ω × (ω × r) does not vanish."""
    om = load_scenario(CARRY).inverse.object_motion
    ends = end_poses(replace(om, times=om.times[:2], positions=om.positions[:2], rotations=om.rotations[:2]))
    line = spline_path.straight_control_points(ends, 2)
    bend = np.array([[0.02, -0.02, 0.02], [-0.02, 0.02, 0.01]])
    turn = np.array([[0.1, -0.2, 0.05], [-0.15, 0.1, -0.05]])
    return replace(ends, path=PathSpline(line.kind, line.positions + bend, line.rotation_vectors + turn))


def test_the_body_point_reference_is_the_derivative_of_its_pose():
    """`body_point_state` of the object motion at a body point c (0.19, −0.03, 0.05 m) against central
    differences of its own pose (h = 1e-4 s): p_c(t) = p(t) + R(t) c differentiated gives the twist's linear
    part, log(R(t+h) R(t−h)ᵀ)/2h the angular, and the differences of that twist the acceleration, at 7 times
    of a bent 3-D B-spline path. The differences' truncation is O(h²) (measured 5.7e-9, 6.7e-9, 7.8e-9 of
    each quantity's peak, falling 4× with h halved) and their round-off ≈ 1e-16/h ≈ 1e-12: within 1e-7 of
    each peak. The point sits at R c from C itself, and its linear rates differ from C's by ≥ 1e-3 of their
    peak, its angular ones not at all (the test sees the offset)."""
    from coopsim.core.spatial import rot_log
    from coopsim.inverse.trajectory import body_point_state

    motion, h = _spatial_path(), 1e-4

    def at(t):
        return body_point_state(*object_motion_at(motion, t), POINT)

    times = np.linspace(0.3, 4.7, 7)
    states = [at(t) for t in times]
    p, R, tw, ac = (np.array([s[k] for s in states]) for k in range(4))
    fd_v = np.array([(at(t + h)[0] - at(t - h)[0]) / (2 * h) for t in times])
    fd_w = np.array([rot_log(at(t + h)[1] @ at(t - h)[1].T) / (2 * h) for t in times])
    fd_a = np.array([(at(t + h)[2] - at(t - h)[2]) / (2 * h) for t in times])
    for got, ref in ((tw[:, :3], fd_v), (tw[:, 3:], fd_w), (ac, fd_a)):
        assert np.max(np.abs(got - ref)) <= 1e-7 * np.max(np.abs(ref)), np.max(np.abs(got - ref)) / np.max(np.abs(ref))
    own = [object_motion_at(motion, t) for t in times]
    assert np.allclose(p, [o[0] + o[1] @ POINT for o in own], rtol=0, atol=1e-15)
    for k, s in ((2, tw), (3, ac)):
        base = np.array([o[k] for o in own])
        assert np.max(np.abs(s[:, :3] - base[:, :3])) >= 1e-3 * np.max(np.abs(s[:, :3]))
        assert np.array_equal(s[:, 3:], base[:, 3:])


def test_the_compiled_body_point_reference_is_the_python_controllers(written):
    """The computed-torque law with its reference moved to the body point c (`Controller(point=)`), compiled
    loop against the 'stages' engine (the Python controller, `body_point_state`), 40 ms RK4 at 5 ms on the
    written B-spline: the same trajectory and torques to ≤ 1e-10 rad and N·m (as without a point, above); the
    run starts at C on the motion, so the law's first pose error is R₀c itself (the reference is C + R c, not
    C − R c), up to the projected initial state's own 3.5e-9 m offset (above): within 1e-8 m; and the object is
    pulled towards it (its position moves ≥ 1e-4 m)."""
    from coopsim.control.controller import Controller
    from coopsim.core.model import TorqueFeedback

    m = written[2]
    m = replace(m, duration=0.04, integrator=replace(m.integrator, output_dt=0.02, method="rk4", step=0.005),
                control=replace(m.control, mass_scale=1.0, squeeze=0.0))
    loop = replace(m, torques=TorqueFeedback(Controller(m, point=POINT)))
    a, b = simulate(loop), simulate(loop, engine="stages")
    assert (a.engine, b.engine) == ("compiled", "stages")
    assert np.max(np.abs(a.q - b.q)) <= 1e-10 and np.max(np.abs(a.tau - b.tau)) <= 1e-10
    rec = loop.torques.fn.compiled_commands(a.t, a.q, a.qd)
    R0 = object_motion_at(m.inverse.object_motion, m.inverse.object_motion.times[0])[1]
    assert np.max(np.abs(rec.object_error[0, :3] - R0 @ POINT)) <= 1e-8
    assert np.linalg.norm(a.object_pos[-1] - a.object_pos[0]) >= 1e-4
