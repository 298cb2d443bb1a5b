"""Controllers in the loop (scenario `control:`, `coopsim.core.model.ControlSettings`).

Each law is a pure function of the time and the state the integrator evaluates, τ = u(t, θ, θ̇); the
scenario's torque tables are added to it (they act as a disturbance), then the motor lines of eq. 36
clip it when `saturate` is set:

  * joint_pd:  τ = τ_comp(θ, θ̇) + Kp (θ_r − θ) + Kd (θ̇_r − θ̇), with τ_comp the closed-chain inverse
    dynamics (`coopsim.inverse.solve`) at (θ, 0, 0) ('gravity') or (θ, θ̇, 0) ('bias'), the object's share
    distributed by a redundancy resolution (`coopsim.inverse.resolutions`); θ_r a set-point on the loop-closure
    manifold or the joint trajectory of a prescribed object motion.
  * computed_torque: the object acceleration a = a_r + Kd (v_r − v) + Kp e (pose error e = [p_r − p;
    log(R_r Rᵀ)], world axes; the reference inverse.object_motion's, or moved to a body point c given to the
    Controller, `coopsim.inverse.trajectory.body_point_state`, which the object frame then tracks) is turned
    into the arms' joint accelerations by differential kinematics (`coopsim.inverse.trajectory.arm_rates`),
    and the closed-chain inverse dynamics of (θ, θ̇, θ̈) distributed by the resolution gives τ; a squeeze force
    f_s along each grasp line (towards the centre of mass) is added in the null space of the grasp matrix, so it
    changes the grasp wrenches, never the motion;
    and each arm's grasp error (`grasp_errors`) is fed back in joint space, τ_m += J_mᵀSᵀS (Kp e_m +
    Kd ė_m) (zero on the native model up to its closure tolerance; the twin's welds yield).
    With a perfect model and zero initial error this is the inverse-dynamics feedforward of the
    prescribed motion.

Two implementations of the same laws: `Controller.command` here (NumPy over the compiled inverse-dynamics
terms: the 'stages' engine of `coopsim.forward.simulate` calls it at every stage of the reference time loop),
and `coopsim.compiled.control` (the whole evaluation compiled, called by the compiled time loop at
every stage: the default engine; `Controller.packed` is its data). The 'bounded' distribution (a QP)
and Python callables (`TorqueFeedback`) run on the 'stages' engine only (`Controller.compiled_reason`).
The MuJoCo twin calls the controller through its control callback at every RK4 stage
(`coopsim.twin.mujoco_run`), compiled where it can be.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, fields, replace
from functools import cached_property

import numpy as np

from coopsim.control.laws import (
    grasp_errors,
    grasp_torques,
    joint_accelerations,
    object_acceleration,
    pd_torque,
    pose_error,
    saturate,
    squeeze_wrenches,
)
from coopsim.core.errors import ConstraintError, CoopsimError
from coopsim.core.model import COMPENSATIONS, COMPILED_DISTRIBUTIONS, LAWS, REFERENCES, Model, TorqueFeedback, torque_at
from coopsim.forward.diagnostics import describe_state, run_warning
from coopsim.inverse.problem import SampleFailureWarning, inverse_problem, torques_of
from coopsim.inverse.spline_path import spline_arrays
from coopsim.inverse.trajectory import (JointTrajectory, body_point_state, object_motion_at, object_motion_trajectory,
                                       trajectory_at)

# The compiled engine's modules and the distributions are imported in the methods that use them
# (tests/cross/test_architecture.py, DEFERRED): every run imports this module for closed_loop, and most runs
# have no controller.




class ControlError(CoopsimError):
    """A controller cannot be built for this scene (one line naming the field)."""


@dataclass(frozen=True, eq=False)
class Command:
    """A controller's evaluation at one state, or along a run with a leading sample axis N (`record`).

    Joint vectors are stacked arm after arm (n = n_total); rad and N·m on revolute joints, m and N on
    prismatic ones.

    Attributes:
        q_ref, qd_ref: (n,) rad, rad/s, the joint reference (joint_pd; nan for computed_torque).
        angle_error: (n,) rad, q_ref − q (joint_pd; nan for computed_torque).
        object_error: (6,) [m; rad], the object pose error against the reference, world axes
            (computed_torque; nan for joint_pd).
        object_rate_error: (6,) [m/s; rad/s], the object twist error, world axes (computed_torque;
            nan for joint_pd).
        raw: (n,) N·m, the command before saturation (the scenario's torque tables included).
        tau: (n,) N·m, what the motors apply (raw clipped to the motor lines of eq. 36 when
            control.saturate).
    """

    q_ref: np.ndarray
    qd_ref: np.ndarray
    angle_error: np.ndarray
    object_error: np.ndarray
    object_rate_error: np.ndarray
    raw: np.ndarray
    tau: np.ndarray

    @property
    def saturated(self) -> np.ndarray:
        """bool, shaped as tau: the joints whose command the motor lines clipped."""
        return self.raw != self.tau

    @property
    def saturation_events(self) -> int:
        """How many (sample, joint) pairs the motor lines clipped."""
        return int(np.count_nonzero(self.saturated))


class Controller:
    """The controller of a scenario's `control:` section, called as u(t, q, qd) -> τ (n,) N·m.

    It acts on its own model `plant` (the scene, its object mass and inertia scaled by
    control.mass_scale), with the scene's torque tables added to its command. Built lazily: the
    set-point projection and the reference trajectory are computed on first use.

    Args:
        model: the scene, with `control` set (ControlSettings).
        trajectory: joint_pd with reference 'object_motion': the JointTrajectory it tracks in place of the
            closed-chain IK of inverse.object_motion (e.g. an optimum's, computed on another model than the
            plant's); None: that IK.
        resolution: the Resolution that distributes the object's share (e.g. an optimum's, its virtual bodies
            and weights another model's); None: control.distribution's on the plant (`resolution`).
        point: computed_torque: (3,) m, c, object axes: where the plant's object frame sits relative to the
            point inverse.object_motion prescribes; the reference is moved to that body point
            (`coopsim.inverse.trajectory.body_point_state`), so that the point −c of the plant's frame follows
            the motion (e.g. c a composite centre of mass relative to the nominal one); None: zero.

    Attributes:
        model: the scene as given.
        settings: model.control.
        plant: the model the controller believes in (`_controller_model`).

    Raises:
        ControlError: computed_torque on an arm with more or fewer joints than constrained rows.
    """

    def __init__(self, model: Model, trajectory: JointTrajectory | None = None, resolution=None,
                 point: np.ndarray | None = None):
        self.model, self.settings, self._given, self._resolution = model, model.control, trajectory, resolution
        self.point = np.zeros(3) if point is None else np.asarray(point, dtype=float)
        self.plant = _controller_model(model, model.control.mass_scale)
        k = model.rows.shape[0]
        if self.settings.law == "computed_torque" and any(arm.n != k for arm in model.arms):
            arm = next(a for a in model.arms if a.n != k)
            raise ControlError(f"control.law: computed_torque needs as many joints per arm as constrained rows "
                               f"(arm {arm.name!r} has {arm.n} joints for {k} rows)")

    @cached_property
    def resolution(self):
        """The distribution's resolution: the one given, else `coopsim.inverse.solve.resolution_for`'s; 'bounded'
        with the bounds of inverse.internal_force_bound and internal_moment_bound (none: unbounded)."""
        from coopsim.inverse.solve import resolution_for

        if self._resolution is not None:
            return self._resolution
        inv = self.plant.inverse
        bounds = [np.inf if b is None else b for b in (inv.internal_force_bound, inv.internal_moment_bound)]
        return resolution_for(self.plant, self.settings.distribution, force_bound=bounds[0], moment_bound=bounds[1])

    @cached_property
    def fallbacks(self) -> list:
        """(t s, q (n,), reason) of every evaluation whose 'bounded' QP had no solution and that took
        control.fallback instead (appended as they happen)."""
        return []

    def _distribute(self, prob, t: float):
        """Grasp wrenches f (1, rk) of the resolution at one state (`inverse_dynamics`); where 'bounded' has
        no solution, control.fallback's (recorded in `fallbacks`), or a ControlError with 'error'."""
        from coopsim.inverse.solve import distribute, resolution_for

        failures: list = []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SampleFailureWarning)     # reported as a RunWarning instead
            f = distribute(prob, prob.y, self.resolution, failures)
        if not failures:
            return f
        fallback, reason = self.settings.fallback, failures[0].reason
        if fallback == "error":
            raise ControlError(f"control.fallback: error: the 'bounded' distribution has no solution at "
                               f"{describe_state(t, prob.q[0])}: {reason}")
        self.fallbacks.append((t, prob.q[0].copy(), reason))
        return distribute(prob, prob.y, resolution_for(self.plant, fallback))

    @cached_property
    def setpoint(self) -> np.ndarray:
        """The set-point on the loop-closure manifold: control.setpoint (default the scenario's initial
        angles) projected as the initial state is; ControlError when that moves it by more than
        integrator.max_initial_correction."""
        from coopsim.compiled.api import consistent_state

        s = self.settings
        field, q = ("arms[].initial", self.model.q0) if s.setpoint is None else ("control.setpoint", s.setpoint)
        try:
            proj = consistent_state(self.model, q, np.zeros_like(q))
        except ConstraintError as exc:
            raise ControlError(f"{field}: the arms cannot close the loop at the set-point: {exc}") from None
        worst, limit = float(np.max(np.abs(proj.dq))), self.model.integrator.max_initial_correction
        if worst > limit:
            raise ControlError(f"{field}: closing the loop at the set-point needs a joint correction of {worst:.4g} "
                               f"rad (> integrator.max_initial_correction = {limit:g} rad)")
        return proj.q

    @cached_property
    def trajectory(self):
        """The joint trajectory of inverse.object_motion (`coopsim.inverse.trajectory.JointTrajectory`), or the
        one given."""
        if self._given is not None:
            return self._given
        return object_motion_trajectory(self.model, self.model.inverse.object_motion)

    def reference(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The joint reference of joint_pd at time t.

        Args:
            t: s, from the start of the run.

        Returns:
            tuple: θ_r (n,) rad and θ̇_r (n,) rad/s: the set-point and zero, or the joint trajectory of
            inverse.object_motion at t.
        """
        if self.settings.reference == "setpoint":
            return self.setpoint, np.zeros_like(self.setpoint)

        q, qd, _ = trajectory_at(self.trajectory, self.trajectory.t[0] + t)
        return q, qd

    def inverse_dynamics(self, q, qd, qdd, squeeze: float = 0.0, t: float = 0.0):
        """The closed-chain inverse dynamics at one state, on the controller's model.

        The object's net wrench is distributed by the resolution (`_distribute`, eqs. 28–35), a squeeze
        added in the null space of the grasp matrix.

        Args:
            q, qd, qdd: (n,) rad, rad/s, rad/s², the joint state and accelerations.
            squeeze: N, the squeeze force along each grasp line (`coopsim.control.laws.squeeze_wrenches`).
            t: s, the time, for the messages.

        Returns:
            tuple: τ (n,) N·m and the InverseProblem of that state (`coopsim.inverse.problem`).

        Raises:
            ControlError: 'bounded' has no solution there and control.fallback is 'error'.
        """
        traj = JointTrajectory(np.zeros(1), q[None], qd[None], qdd[None], "control")
        prob = inverse_problem(self.plant, traj, terms=self._terms(traj.q, traj.qd, traj.qdd))
        f = self._distribute(prob, t)
        if squeeze:
            f = f + squeeze_wrenches(prob.grasp_offset[0], prob.rows, prob.A[0], squeeze)[None]
        return torques_of(prob, f)[0], prob

    @cached_property
    def _kernel(self):
        from coopsim.compiled import api
        from coopsim.compiled.packing import workspace
        from coopsim.compiled.structs import to_struct

        P, _, Ps, _ = api.compiled(self.plant)
        W = workspace(P)
        return Ps, to_struct(W), W, int(P.dof[-1]), len(P.dof) - 1, int(np.max(np.diff(P.dof)))

    def _terms(self, Q, QD, QDD):
        """The compiled inverse-dynamics terms of one state (Q, QD, QDD (1, n)) on this controller's own
        workspace (as `coopsim.compiled.api.inverse_terms`, without a workspace built per call)."""
        from coopsim.compiled import sample

        Ps, ws, _, n, r, nmax = self._kernel
        out = sample.new_inverse_terms(1, n, r, nmax)
        sample.inverse_terms(Ps, ws, Q, QD, QDD, out)
        return out

    def command(self, t: float, q: np.ndarray, qd: np.ndarray) -> Command:
        """The whole evaluation of the law at one state.

        Args:
            t: s, from the start of the run.
            q, qd: (n,) rad, rad/s, the joint state.

        Returns:
            Command: the references, errors, raw command and applied torques (n,) at (t, q, qd).
        """
        s, n = self.settings, len(q)
        nan6, nan_n = np.full(6, np.nan), np.full(n, np.nan)
        if s.law == "joint_pd":
            q_ref, qd_ref = self.reference(t)
            u = pd_torque(s.kp, s.kd, q_ref, qd_ref, q, qd)
            if s.compensation != "none":
                u = u + self.inverse_dynamics(q, qd if s.compensation == "bias" else np.zeros(n), np.zeros(n), t=t)[0]
            e, ed = nan6, nan6
        else:
            q_ref, qd_ref = nan_n, nan_n
            u, e, ed = self._computed_torque(t, q, qd)
        raw = u + torque_at(self.model.torques, t)
        tau = saturate(self.model.motors, raw, qd) if s.saturate else raw
        return Command(q_ref, qd_ref, q_ref - q, e, ed, raw, tau)

    def _computed_torque(self, t, q, qd):
        s, m = self.settings, self.plant
        state = self._terms(q[None], qd[None], np.zeros((1, len(q))))
        W = self._kernel[2]                      # J, J̇θ̇ of every arm at (q, qd), from that evaluation
        p, R, v = state.p_C[0], state.R_o[0], state.twist[0]
        motion = m.inverse.object_motion
        p_r, R_r, v_r, a_r = body_point_state(*object_motion_at(motion, motion.times[0] + t), self.point)
        e, ed = pose_error(p_r, R_r, p, R), v_r - v
        a = object_acceleration(s.object_kp, s.object_kd, e, ed, a_r)
        n = [sl.stop - sl.start for sl in m.dof_slices]
        qdd = joint_accelerations(m.rows, W.J, W.Jd_qd, -state.s[0], v, a, n)
        J = W.J.copy()                                   # the next evaluation reuses W
        ge, ged = self._grasp_errors(q, qd, state)
        u = self.inverse_dynamics(q, qd, qdd, s.squeeze, t)[0]
        if np.any(s.grasp_kp) or np.any(s.grasp_kd):
            u = u + grasp_torques(m.rows, J, s.grasp_kp, s.grasp_kd, ge, ged, n)
        return u, e, ed

    def _grasp_errors(self, q, qd, state):
        """`grasp_errors` at (q, qd) from the terms `state` of `_terms` there (the workspace holds them)."""
        m, W = self.plant, self._kernel[2]
        ee_twist = np.array([W.J[i][:, :sl.stop - sl.start] @ qd[sl] for i, sl in enumerate(m.dof_slices)])
        return grasp_errors(m.object.grasp_pos, m.object.grasp_rot, state.p_C[0], state.R_o[0], state.twist[0],
                            W.p_ee, W.R_ee, ee_twist)

    def grasp_errors_at(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every arm's grasp error and its rate at one state (`coopsim.control.laws.grasp_errors`).

        The object pose and twist are those of the carrier arm's grasp, as the native model's.

        Args:
            q, qd: (n,) rad, rad/s, the joint state.

        Returns:
            tuple: e (r, 6) [m; rad] and ė (r, 6) [m/s; rad/s], world axes.
        """
        state = self._terms(q[None], qd[None], np.zeros((1, len(q))))
        return self._grasp_errors(q, qd, state)

    def __call__(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        return self.command(t, q, qd).tau

    @cached_property
    def compiled_reason(self) -> str | None:
        """Why this controller cannot run in the compiled time loop (None when it can)."""
        d = self.settings.distribution
        if d not in COMPILED_DISTRIBUTIONS:
            return f"control.distribution {d!r} (a QP per evaluation) is evaluated in Python"
        return None

    @cached_property
    def packed(self):
        """The controller's data for the compiled laws (`coopsim.compiled.control.PackedControl`)."""
        from coopsim.compiled import control as cc

        s, m = self.settings, self.model
        N, r, k = m.n_total, m.r, m.rows.shape[0]
        fields = dict(kp=s.kp, kd=s.kd, okp=s.object_kp, okd=s.object_kd, squeeze=s.squeeze, saturate=int(s.saturate),
                      gkp=s.grasp_kp, gkd=s.grasp_kd,
                      compensation=COMPENSATIONS.index(s.compensation), distribution=COMPILED_DISTRIBUTIONS.index(
                          s.distribution), reference=REFERENCES.index(s.reference))
        if s.law == "joint_pd" and s.reference == "setpoint":
            fields.update(q_set=self.setpoint)
        elif s.law == "joint_pd":
            tr = self.trajectory
            fields.update(tr_t=tr.t, tr_q=tr.q, tr_qd=tr.qd, tr_qdd=tr.qdd)
        else:
            fields.update(_packed_motion(self.plant, self.plant.inverse.object_motion), om_point=self.point)
        res = self.resolution
        return cc.new_control(N, r, k, max(a.n for a in m.arms), LAWS.index(s.law), weights=res.weights,
                              vmass=res.masses, vinertia=res.inertias, stall=m.motors.stall_torque,
                              slope=m.motors.line_slope, **fields)

    @cached_property
    def compiled_loop(self) -> tuple:
        """(Pc, Wc, C): the controller's model, a workspace of its own and `packed`, as the StructRefs the
        compiled time loop takes (`coopsim.compiled.api.integrate_chain`)."""
        from coopsim.compiled import api
        from coopsim.compiled.control import control_struct

        api.announce_compile("control")
        P = api.compiled(self.plant).P
        return api.compiled(self.plant).Ps, api.fresh_workspace(P), control_struct(self.packed)

    def loop_record(self) -> tuple:
        """`compiled_loop`, its evaluation counters reset for a new run (`coopsim.core.model.LoopController`).

        Returns:
            tuple: (Pc, Wc, C), the StructRefs the compiled time loop takes.
        """
        self.packed.count[:] = 0
        return self.compiled_loop

    def loop_counts(self) -> tuple:
        """The compiled laws' evaluation counters since `loop_record` (`coopsim.compiled.control`).

        Returns:
            tuple: one int per counter of PackedControl.count.
        """
        return tuple(int(c) for c in self.packed.count)

    def loop_torques(self, t: np.ndarray, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """The compiled controller's torques at many samples (`coopsim.core.model.LoopController`).

        Args:
            t: (N,) s, the sample times.
            q, qd: (N, n) rad, rad/s, the joint states.

        Returns:
            np.ndarray: τ (N, n) N·m.
        """
        return self.compiled_commands(t, q, qd).tau

    def run_warnings(self) -> list:
        """The warnings of the run so far: a `distribution_fallback` RunWarning when the controller fell
        back from 'bounded' (at its first evaluation that did, with their count).

        Returns:
            list: none or one RunWarning (`coopsim.forward.diagnostics.run_warning`).
        """
        if not self.fallbacks:
            return []
        t, q, reason = self.fallbacks[0]
        count, fallback = len(self.fallbacks), self.settings.fallback
        return [run_warning("distribution_fallback", t, q, f"the 'bounded' distribution has no solution ({reason}); "
                            f"the {fallback!r} distribution was used there and at {count - 1} later controller "
                            f"evaluations (control.fallback)", fallbacks=count)]

    def compiled_call(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """The compiled controller at one state (as `__call__`).

        Args:
            t: s, from the start of the run.
            q, qd: (n,) rad, rad/s, the joint state.

        Returns:
            np.ndarray: τ (n,) N·m.

        Raises:
            ControlError: the law's equations are singular at that state.
        """
        from coopsim.compiled import api
        from coopsim.compiled.control import evaluate

        Ps, Ws, C = self.compiled_loop
        tau = np.array(torque_at(self.model.torques, t), dtype=float)
        st = evaluate(Ps, Ws, C, float(t), np.concatenate([q, qd]).astype(float), tau)
        if st:
            raise ControlError(f"control: at t={t:.6g} s: {api.REASONS[st]}")
        return tau

    @property
    def fastest(self):
        """τ = u(t, q, qd): `compiled_call` where the controller is compiled, else this Controller."""
        return self.compiled_call if self.compiled_reason is None else self

    def compiled_commands(self, t: np.ndarray, q: np.ndarray, qd: np.ndarray) -> Command:
        """The compiled controller at every sample of a run, as `record` gives.

        Args:
            t: (N,) s, the sample times.
            q, qd: (N, n) rad, rad/s, the joint states.

        Returns:
            Command: (N, …) arrays.

        Raises:
            ControlError: the law's equations are singular at a sample (the first one named).
        """
        from coopsim.compiled import api
        from coopsim.compiled.control import commands
        from coopsim.compiled.packing import tabulated_torques

        N, n = q.shape
        Ps, Ws, C = self.compiled_loop
        t = np.ascontiguousarray(t, dtype=float)
        Y = np.ascontiguousarray(np.concatenate([q, qd], axis=1), dtype=float)
        tables = tabulated_torques(api.compiled(self.model).P, t)
        raw, tau, q_ref, qd_ref = (np.zeros((N, n)) for _ in range(4))
        e, ed, status = np.zeros((N, 6)), np.zeros((N, 6)), np.zeros(N, dtype=np.int64)
        commands(Ps, Ws, C, t, Y, tables, raw, tau, q_ref, qd_ref, e, ed, status)
        if np.any(status):
            i = int(np.flatnonzero(status)[0])
            raise ControlError(f"control: at t={t[i]:.6g} s: {api.REASONS[int(status[i])]}")
        return Command(q_ref, qd_ref, q_ref - q, e, ed, raw, tau)


def _packed_motion(model: Model, motion) -> dict:
    """The object motion's fields for `coopsim.compiled.control` (`coopsim.compiled.api.motion_struct`, the
    object-motion IK's own packing: waypoints under any time law, or a B-spline path)."""
    from coopsim.compiled.api import motion_struct

    mo = motion_struct(model, motion, None if motion.path is None else spline_arrays(motion))
    return dict(om_t=mo.times, om_p=mo.positions, om_R=mo.rotations, om_origin=mo.origin, time_law=mo.law,
                om_law_t=mo.law_t, om_law_s=mo.law_s, om_law_rate=mo.law_rate, om_knots=mo.knots, om_ctrl=mo.ctrl,
                om_degree=mo.degree, om_R0=mo.R0)


def _controller_model(model: Model, mass_scale: float) -> Model:
    """The model the controller believes in: the object's mass and inertia times mass_scale."""
    if mass_scale == 1.0:
        return model
    obj = model.object
    return replace(model, object=replace(obj, mass=obj.mass * mass_scale, inertia=obj.inertia * mass_scale))


def closed_loop(model: Model) -> Model:
    """The model with its `control:` section in the loop, ready for `coopsim.forward.simulate`.

    Args:
        model: a Model, with or without a `control:` section.

    Returns:
        The model with torques a TorqueFeedback of its Controller (the scenario's torque tables are
        added to the command); the model itself when it has no controller or already feeds back.
    """
    if model.control is None or isinstance(model.torques, TorqueFeedback):
        return model
    return replace(model, torques=TorqueFeedback(Controller(model)))


def record(controller: Controller, t: np.ndarray, q: np.ndarray, qd: np.ndarray) -> Command:
    """The controller evaluated at every sample of a run (compiled where it can be).

    Args:
        controller: the Controller.
        t: (N,) s, the sample times.
        q, qd: (N, n) rad, rad/s, the joint states.

    Returns:
        Command: (N, …) arrays.
    """
    if controller.compiled_reason is None:
        return controller.compiled_commands(t, q, qd)
    cmds = [controller.command(float(ti), qi, qdi) for ti, qi, qdi in zip(t, q, qd)]
    return Command(**{f.name: np.array([getattr(c, f.name) for c in cmds]) for f in fields(Command)})
