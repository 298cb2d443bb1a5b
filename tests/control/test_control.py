"""Controllers in the loop (`coopsim.control.controller`, scenario `control:`).

Independent references: the set-point itself (an input), the eq. 36 motor lines written out here, the
plain-NumPy reference engine (for the 'stages' engine), MuJoCo's own integration of the same controller
from the twin's state (harness), and a hand-written PD law passed as a notebook callable."""

from dataclasses import replace

import numpy as np
import pytest
import yaml

from coopsim.control.controller import Controller, record
from coopsim.twin.compare import compare
from coopsim.twin.harness import control_series, cross_validate
from coopsim.io.mcap_codec import log_data
from coopsim.report.summary import control_summary
from coopsim.twin.mujoco_run import run_twin
from coopsim.core.model import TorqueFeedback
from coopsim.core.errors import CoopsimError, ScenarioError
from coopsim.io.scenario import load_scenario, model_from_dict
from coopsim.control.controller import closed_loop
from coopsim.forward.simulate import simulate
from helpers import SCENARIOS

HOLD = SCENARIOS / "control" / "control_spatial_hold.yaml"


@pytest.fixture(scope="module")
def hold():
    return load_scenario(HOLD)


def _at_setpoint(model, duration, **control):
    """The scene started at rest at its controller's (projected) set-point, control fields replaced."""
    model = replace(model, control=replace(model.control, **control), duration=duration,
                    integrator=replace(model.integrator, output_dt=duration / 2))
    sp = Controller(model).setpoint
    return replace(model, q0=sp, qd0=np.zeros_like(sp)), sp


def test_pd_with_gravity_compensation_holds_the_spatial_pair(hold):
    """Started at rest at a set-point 0.18 rad from the hanging equilibrium, the spatial pair stays there
    within 1e-6 rad under PD + gravity compensation (measured 1.2e-14 rad over 0.05 s); without the
    compensation the same PD sags by more than 1e-3 rad (measured 1.6e-3 rad), so the bound can fail.
    (Convergence to the set-point from the hanging equilibrium 0.18 rad away: the bundled scenario,
    README.)"""
    model, sp = _at_setpoint(hold, 0.05)
    res = simulate(closed_loop(model))
    held = float(np.max(np.abs(res.q - sp)))
    assert held <= 1e-6, f"PD + gravity compensation drifted {held:.3g} rad from the set-point"
    assert float(np.max(np.abs(hold.q0 - sp))) > 0.1, "the set-point is the hanging equilibrium: nothing to hold"

    sag_model, _ = _at_setpoint(hold, 0.05, compensation="none")
    sag = float(np.max(np.abs(simulate(closed_loop(sag_model)).q[-1] - sp)))
    assert sag > 1e-3, f"PD without compensation stayed within {sag:.3g} rad: the hold test proves nothing"


def test_saturation_clips_at_the_motor_lines_and_counts_events(hold):
    """With `saturate`, every applied torque lies on or inside τ_min(θ̇) = −τ_s − (τ_s/ω_s)θ̇ ≤ τ ≤
    τ_s − (τ_s/ω_s)θ̇ (eq. 36, written out here), the clipped joints are the ones whose raw command
    left the band, and they are counted."""
    stall, speed = np.full(12, 5.0), np.full(12, 4.0)
    model = replace(hold, motors=replace(hold.motors, stall_torque=stall, no_load_speed=speed),
                    control=replace(hold.control, saturate=True))
    ctrl = Controller(model)
    rng = np.random.default_rng(12)
    q = ctrl.setpoint + rng.normal(0, 0.05, (6, 12))
    qd = rng.normal(0, 1.0, (6, 12))
    rec = record(ctrl, np.zeros(6), q, qd)
    lo, hi = -stall - stall / speed * qd, stall - stall / speed * qd
    assert np.all(rec.tau >= lo - 1e-12) and np.all(rec.tau <= hi + 1e-12)
    outside = (rec.raw < lo) | (rec.raw > hi)
    assert np.array_equal(rec.saturated, outside)
    assert rec.saturation_events == int(outside.sum()) > 0
    np.testing.assert_array_equal(rec.tau[~outside], rec.raw[~outside])


def test_a_notebook_callable_runs_in_the_loop_like_the_scenario_controller(hold):
    """τ = u(t, q, q̇) written by hand (PD, no compensation) gives the trajectory of the scenario's
    `joint_pd` with compensation: none, to round-off; and the 'stages' engine (compiled evaluations in
    the Python time loop) matches the plain-NumPy reference engine on it (≤ 1e-9 rad; measured 8.9e-16
    rad, the chain moving 6.6e-4 rad in 0.02 s)."""
    model, sp = _at_setpoint(hold, 0.02, compensation="none")
    kp, kd = model.control.kp, model.control.kd
    notebook = replace(model, control=None, torques=TorqueFeedback(lambda t, q, qd: kp * (sp - q) - kd * qd))
    a, b = simulate(closed_loop(model)), simulate(closed_loop(notebook))
    assert float(np.max(np.abs(a.q - b.q))) <= 1e-12
    assert float(np.max(np.abs(a.q - a.q[0]))) > 1e-4, "the chain did not move"
    ref = simulate(closed_loop(notebook), engine="reference")
    assert float(np.max(np.abs(ref.q - b.q))) <= 1e-9


@pytest.mark.parametrize("field, value, message", [
    ("law", "pid", "control.law: must be one of joint_pd, computed_torque"),
    ("kp", [1.0, 2.0], "control.kp: expected shape 12, got [2]"),
    ("kd", -1.0, "control.kd: must be non-negative"),
    ("compensation", "full", "control.compensation: must be one of none, gravity, bias"),
    ("distribution", "magic", "control.distribution: must be one of"),
    ("reference", "object_motion", "control.setpoint: only with reference: setpoint"),
    ("saturate", "yes", "control.saturate: expected true or false"),
    ("squeeze", 1.0, "control.squeeze: unknown field"),
    ("passive", [True] + [False] * 5, "control.law: a controller needs every joint actuated"),
])
def test_control_fields_are_validated_with_one_line_errors(field, value, message):
    data = yaml.safe_load(HOLD.read_text())
    (data["arms"][0] if field == "passive" else data["control"])[field] = value
    with pytest.raises(ScenarioError) as err:
        model_from_dict(data, where="s.yaml")
    assert message in str(err.value) and "\n" not in str(err.value)


def test_a_set_point_off_the_loop_closure_is_refused_by_name(hold):
    model = replace(hold, control=replace(hold.control, setpoint=hold.control.setpoint + 0.1))
    with pytest.raises(CoopsimError, match=r"^control\.setpoint: closing the loop at the set-point needs a joint "
                                           r"correction of [0-9.]+ rad \(> integrator\.max_initial_correction"):
        simulate(closed_loop(model))


def test_computed_torque_on_redundant_arms_is_refused_by_name():
    """Differential kinematics per arm needs square arms: a 4-joint arm in a 3-row planar scene is named."""
    from coopsim.control.controller import ControlError
    from coopsim.core.model import ControlSettings

    m = load_scenario(SCENARIOS / "hard" / "planar_4arm_mixed.yaml")
    with pytest.raises(ControlError, match=r"^control\.law: computed_torque needs as many joints per arm as "
                                           r"constrained rows \(arm 'south' has 4 joints for 3 rows\)$"):
        simulate(closed_loop(replace(m, control=ControlSettings("computed_torque", np.zeros(m.n_total), np.zeros(m.n_total)))))


def test_native_and_twin_closed_loops_agree_and_a_wrong_sign_fails(hold):
    """The same controller in the loop of the native model and of the MuJoCo twin (fed the twin's own
    state at every RK4 stage) agree within the scenario's thresholds while the pair is pulled towards
    its set-point 0.18 rad away (measured 1.5e-7 rad over 0.03 s, the pair moving 0.045 rad); the twin's controller
    with the position gain's sign flipped fails the comparison by name (measured 0.10 rad)."""
    model = replace(hold, duration=0.03, integrator=replace(hold.integrator, output_dt=0.015))
    cv = cross_validate(model)
    assert cv.comparison.passed, cv.comparison.failures()
    moved = float(np.max(np.abs(cv.native.q[-1] - cv.native.q[0])))
    assert moved > 0.01, f"the closed loop moved only {moved:.3g} rad"

    # The log's /native/control and /mujoco/control channels: the reference is the projected set-point,
    # the error is that minus each model's own angles, and the torque is what each model applied.
    sp = Controller(model).setpoint
    topics = log_data(control_series(cv)).topics
    for prefix, res in (("/native", cv.native), ("/mujoco", cv.twin)):
        ch = topics[f"{prefix}/control"]
        np.testing.assert_array_equal(ch["reference_angle"], np.broadcast_to(sp, res.q.shape))
        np.testing.assert_allclose(ch["angle_error"], sp - res.q, rtol=0, atol=1e-15)
        np.testing.assert_allclose(ch["torque"], res.tau, rtol=1e-12, atol=1e-12)
        assert not ch["saturated"].any()
    # The tracking-error figure's curves are exactly those errors (per arm, the largest joint's).
    from coopsim.io.log import run_metadata
    from coopsim.plots.figure import arm_groups
    from coopsim.plots.control import _errors, control_jobs

    log = log_data(control_series(cv), run_metadata(model))
    assert [name for _, _, name in control_jobs(log)] == ["tracking_error.png", "internal_force.png"]
    for prefix, res in (("/native", cv.native), ("/mujoco", cv.twin)):
        curves = _errors(log.topics[f"{prefix}/control"], arm_groups(log, model.n_total))
        assert [c[0] for c in curves] == ["arm 1 (left)", "arm 2 (right)"]
        for (_, unit, y), sl in zip(curves, model.dof_slices):
            np.testing.assert_allclose(y, np.max(np.abs(sp - res.q)[:, sl], axis=1), rtol=1e-12)
    summary = control_summary(cv)
    assert summary["native"]["final_error"]["angle_rad"] == pytest.approx(float(np.max(np.abs(sp - cv.native.q[-1]))))
    c = model.control
    wrong = replace(model, control=replace(c, kp=-c.kp))
    bad = compare(cv.native, run_twin(wrong, cv.native.initial.q, cv.native.initial.qd, cv.native.t))
    assert not bad.passed
    assert any("joint angle" in f for f in bad.failures())


# ------------------------------------------------------------------------------------------------
# Object-space computed torque on the paper's bar (scenarios/control/control_paper_carry.yaml)
# ------------------------------------------------------------------------------------------------

CARRY = SCENARIOS / "control" / "control_paper_carry.yaml"
CT_DURATION = 0.1


@pytest.fixture(scope="module")
def carry():
    """The carry scene with a perfect controller model and no disturbance, started on the prescribed
    motion (closed-chain IK of the first waypoint: zero initial error), and that IK trajectory of the
    first segment sampled every 0.05 s (the knots the run's samples fall on)."""
    from coopsim.inverse.trajectory import object_motion_trajectory

    model = load_scenario(CARRY)
    om = model.inverse.object_motion
    first = replace(om, times=np.array([0.0, 5.0]), positions=om.positions[:2], rotations=om.rotations[:2],
                    output_dt=0.05)
    traj = object_motion_trajectory(model, first)
    zero = tuple(replace(tab, times=np.zeros(1), values=np.zeros((1, tab.values.shape[1]))) for tab in model.torques)
    perfect = replace(model, torques=zero, q0=traj.q[0], qd0=traj.qd[0], duration=CT_DURATION,
                      control=replace(model.control, mass_scale=1.0, squeeze=0.0),
                      integrator=replace(model.integrator, output_dt=0.05))
    return model, perfect, traj


def _object_errors(model, res):
    """(position m, orientation rad) (N,) of a run's object against the prescribed motion."""
    from coopsim.core.spatial import quat_to_rot, rot_log
    from coopsim.inverse.trajectory import object_motion_at

    om = model.inverse.object_motion
    ref = [object_motion_at(om, t) for t in res.t]
    pos = np.array([np.linalg.norm(p - r[0]) for p, r in zip(res.object_pos, ref)])
    ang = np.array([np.linalg.norm(rot_log(r[1] @ quat_to_rot(q).T)) for q, r in zip(res.object_quat, ref)])
    return pos, ang


def test_computed_torque_with_a_perfect_model_is_the_inverse_dynamics_feedforward(carry):
    """Perfect model, zero initial error: the bar follows the prescribed motion to ≤ 1e-8 m and rad
    (measured 4.6e-16 m, 8.9e-16 rad), and the torques are the minimum-energy inverse-dynamics torques
    of the closed-chain IK trajectory (`coopsim.inverse.replay.stage_torques` at its knots) to ≤ 1e-8 N·m
    (measured 7e-13 N·m); with a squeeze of 2 N the bar moves the same to ≤ 1e-9 m (measured 4.4e-16 m)
    and the internal force changes by exactly the command along each grasp line (≤ 1e-6 N)."""
    from coopsim.inverse.replay import stage_torques
    from coopsim.inverse.solve import resolution_for
    from coopsim.core.spatial import quat_to_rot

    model, perfect, traj = carry
    res = simulate(closed_loop(perfect))
    pos, ang = _object_errors(model, res)
    assert pos.max() <= 1e-8 and ang.max() <= 1e-8, f"tracking error {pos.max():.3g} m, {ang.max():.3g} rad"
    # A controller that held the bar still would be off by its motion (measured 5.6e-6 m by 0.1 s).
    assert float(np.max(np.linalg.norm(res.object_pos - res.object_pos[0], axis=1))) > 1e-6, "the bar did not move"
    ff = stage_torques(model, traj, resolution_for(model, "min_energy"), res.t)
    assert float(np.max(np.abs(res.tau - ff))) <= 1e-8

    squeeze = 2.0
    sq = simulate(closed_loop(replace(perfect, control=replace(perfect.control, squeeze=squeeze))))
    assert float(np.max(np.abs(sq.object_pos - res.object_pos))) <= 1e-9
    dF = sq.internal_wrench[:, :, :3] - res.internal_wrench[:, :, :3]
    for i, quat in enumerate(sq.object_quat):
        for m in range(model.r):
            line = quat_to_rot(quat) @ model.object.grasp_pos[m]     # from C to grasp m
            np.testing.assert_allclose(dF[i, m], -squeeze * line / np.linalg.norm(line), rtol=0, atol=1e-6)


def test_computed_torque_with_a_mass_error_recovers_from_a_pulse(carry):
    """The controller believes the bar 10 % heavier and a 0.3 N·m, 0.1 s pulse hits arm 1's shoulder at
    t = 0.05 s: the tracking error stays below 5e-5 m (measured peak 2.5e-5 m at 0.2 s) and decays
    after the pulse, every sample, to at most half its peak by 0.4 s (measured 1.1e-5 m; 6.7e-6 m at
    0.6 s, the mass error's own share). RK4 at 25 ms steps: the errors of DOP853 at rtol 1e-10 to 5e-9 m
    (measured), a quarter of the evaluations (the pulse's kinks make DOP853 reject a third of its steps)."""
    model, perfect, _ = carry
    pulse = (replace(model.torques[0], times=np.array([0.0, 0.05, 0.1, 0.15, 0.6])),) + model.torques[1:]
    hit = replace(perfect, torques=pulse, duration=0.4, control=model.control,
                  integrator=replace(perfect.integrator, method="rk4", step=0.025, output_dt=0.1))
    pos, _ = _object_errors(model, simulate(closed_loop(hit)))
    peak = int(np.argmax(pos))
    assert pos.max() <= 5e-5, f"tracking error {pos.max():.3g} m"
    assert 0 < peak < len(pos) - 1 and np.all(np.diff(pos[peak:]) < 0) and pos[-1] <= 0.5 * pos[peak], \
        f"no decay after the pulse: {pos}"


def test_joint_pd_reference_follows_the_object_motion(carry):
    """reference: object_motion — the PD's joint reference at time t is the closed-chain IK of the
    prescribed motion: the object pose it carries (`object_pose_of`, forward kinematics) is the
    prescribed one to 1e-12 m, at a sample of the IK trajectory and between samples (its quintic
    Hermite interpolant; measured 3e-16 to 4e-15 m), and its rates start at zero (rest at waypoint 1)."""
    from coopsim.core.model import ControlSettings
    from coopsim.inverse.trajectory import object_motion_at, object_pose_of

    model, perfect, traj = carry
    first = replace(model.inverse.object_motion, times=traj.t[[0, -1]], output_dt=0.05)
    pd = replace(perfect, inverse=replace(model.inverse, object_motion=first),
                 control=ControlSettings("joint_pd", np.ones(6), np.ones(6), reference="object_motion"))
    ctrl = Controller(pd)
    for t in (0.25, 0.27, 2.33):
        q_ref, _ = ctrl.reference(t)
        off = np.linalg.norm(object_pose_of(pd, q_ref)[0] - object_motion_at(first, t)[0])
        assert off <= 1e-12, f"t={t} s: the reference carries the object {off:.3g} m off the prescribed motion"
    np.testing.assert_array_equal(ctrl.reference(0.0)[1], traj.qd[0])
    assert np.all(traj.qd[0] == 0)


def test_exported_torque_csv_read_back_by_a_scenario_reproduces_the_carry(carry, tmp_path):
    """The minimum-energy inverse-dynamics torques of the carry, written as one CSV per arm
    (`coopsim.io.torque_csv`, what `coopsim inverse --torques-csv` writes) every 5 ms and read back by the
    scenario's `torque: {csv: …}`, drive the forward model along the prescribed motion to ≤ 1e-6 rad over
    2 s (measured 4.3e-7 rad; 4.4e-5 rad at 50 ms: the error is the piecewise-linear table's, O(dt²))."""
    from coopsim.inverse.replay import stage_torques
    from coopsim.inverse.solve import resolution_for
    from coopsim.io.torque_csv import write_torque_csvs
    from coopsim.inverse.trajectory import trajectory_at_times

    model, _, traj = carry
    t = np.linspace(0.0, 2.0, 401)
    tau = stage_torques(model, traj, resolution_for(model, "min_energy"), t)
    paths = write_torque_csvs(tmp_path / "carry", model, t, tau)
    data = yaml.safe_load(CARRY.read_text())
    del data["control"]
    data["duration"] = 2.0
    for arm, sl, path in zip(data["arms"], model.dof_slices, paths):
        arm["torque"], arm["initial"] = {"csv": path.name}, {"angles": traj.q[0, sl].tolist()}
    read = model_from_dict(data, where="carry.yaml", base_dir=tmp_path)
    for tab, sl in zip(read.torques, model.dof_slices):
        np.testing.assert_array_equal(tab.values, tau[:, sl])   # exact round trip
    res = simulate(closed_loop(read))
    q_ref, _, _ = trajectory_at_times(traj, res.t)
    assert float(np.max(np.abs(res.q - q_ref))) <= 1e-6
    assert float(np.max(np.abs(res.q - res.q[0]))) > 0.05, "the carry did not move"
