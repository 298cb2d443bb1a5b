"""Run the MuJoCo twin: replay the scenario's torques (or its controller) through MuJoCo from a given state.

MuJoCo's RK4 evaluates the control callback at every stage with the stage's time, so the twin sees
the same continuous torque τ(t) as the native model (no zero-order hold). Where a controller's reference
jumps in acceleration (a sampled time law: s̈ constant between its samples), the steps are cut around
the jump (`reference_kinks`, `advance`), so that no RK4 step but a short one (2·10⁻⁹ of a step) straddles it.
"""

from __future__ import annotations

import bisect
import contextlib
import time
from dataclasses import dataclass
from typing import Callable

import mujoco
import numpy as np

from coopsim.control.controller import Controller, closed_loop
from coopsim.core.errors import CoopsimError
from coopsim.core.model import Model, TorqueFunction, applied_torque, torque_at
from coopsim.core.results import SampledMotion
from coopsim.twin.mjcf import build_spec, dof_address, qpos_address


@dataclass(frozen=True, eq=False)
class TwinResult(SampledMotion):
    """MuJoCo twin trajectory sampled at N times, in coopsim's joint order (n joints stacked arm by arm).

    Attributes:
        t: (N,) s, the sample times.
        q: (N, n) rad (m on a prismatic joint), the joint coordinates.
        qd: (N, n) rad/s (m/s), the joint rates.
        qdd: (N, n) rad/s² (m/s²), the joint accelerations (MuJoCo's qacc).
        tau: (N, n) N·m (N on a prismatic joint), the motor torques applied (MuJoCo's ctrl).
        object_pos: (N, 3) m, the object's centre of mass C, world.
        object_quat: (N, 4) [w, x, y, z], the object's orientation (object frame to world).
        object_twist: (N, 6) [v_C (m/s); ω (rad/s)], the object's twist at C, world axes.
        weld_violation: (N,) m or rad, max |efc_pos| over the weld rows.
        link_pos: (N, n, 3) m, MuJoCo's link frame positions (xpos), world, joints stacked as q.
        link_quat: (N, n, 4) [w, x, y, z], MuJoCo's link frame orientations (xquat), joints stacked as q.
        wall_time: s, the time the run took (not logged).
    """

    weld_violation: np.ndarray
    link_pos: np.ndarray
    link_quat: np.ndarray
    wall_time: float


@contextlib.contextmanager
def _control(model: Model, d: mujoco.MjData, ctrl_index: np.ndarray, qadr: np.ndarray, dadr: np.ndarray):
    """Drive the twin's motors with τ(d.time) (a controller in the loop: τ(d.time, q, q̇) from the twin's
    own state at qpos/dof addresses qadr, dadr): constant torques (every table a single row) are written
    into d.ctrl once; otherwise a MuJoCo control callback writes them at every stage (restored on exit)."""
    if not isinstance(model.torques, TorqueFunction) and all(len(tab.times) == 1 for tab in model.torques):
        d.ctrl[ctrl_index] = torque_at(model.torques, 0.0)
        yield
        return


    ctrl = getattr(model.torques, "fn", None)
    shared = None if isinstance(model.torques, TorqueFunction) else shared_table(model.torques)
    if isinstance(ctrl, Controller):             # compiled where it can be (`Controller.fastest`)
        fn = ctrl.fastest

        def callback(m, d):
            d.ctrl[ctrl_index] = fn(d.time, d.qpos[qadr], d.qvel[dadr])
    elif shared is not None:
        at = shared

        def callback(m, d):
            d.ctrl[ctrl_index] = at(d.time)
    else:
        def callback(m, d):
            d.ctrl[ctrl_index] = applied_torque(model.torques, d.time, d.qpos[qadr], d.qvel[dadr])

    mujoco.set_mjcb_control(callback)
    try:
        yield
    finally:
        mujoco.set_mjcb_control(None)


def shared_table(tables) -> "Callable[[float], np.ndarray] | None":
    """τ(t) of torque tables that share their times, as one stacked table: `coopsim.core.model.torque_at`'s
    values to the bit (the same row on a knot, slope·(t − t_j) + τ_j between knots with the same slope, held
    outside, nan at a nan time), one binary search for all arms instead of one per arm.

    Args:
        tables: one TorqueTable per arm.

    Returns:
        Callable[[float], np.ndarray] | None: t (s) ↦ (n_total,) N·m; None when the tables' times differ.
    """
    times = tables[0].times
    if len(times) < 2 or any(not np.array_equal(tab.times, times) for tab in tables[1:]):
        return None
    values = np.hstack([tab.values for tab in tables])
    slopes = (values[1:] - values[:-1]) / (times[1:] - times[:-1])[:, None]
    knots, first, last = times.tolist(), values[0].copy(), values[-1].copy()

    def at(t: float) -> np.ndarray:
        if t <= knots[0]:
            return first.copy()
        if t >= knots[-1]:
            return last.copy()
        if t != t:
            return np.full(values.shape[1], np.nan)
        j = bisect.bisect_right(knots, t) - 1
        if t == knots[j]:
            return values[j].copy()
        return slopes[j] * (t - knots[j]) + values[j]

    return at


def divides(t_out: np.ndarray, dt: float) -> bool:
    """Whether a step divides every interval of an output grid into whole steps.

    Args:
        t_out: (N,) s, the output times.
        dt: s, the step.

    Returns:
        bool: every interval is a whole number (at least one) of steps, to 1e-6 of a step.
    """
    k = np.diff(t_out) / dt
    return bool(np.all(np.abs(k - np.round(k)) <= 1e-6) and np.all(np.round(k) >= 1))


def _steps_per_sample(t_out: np.ndarray, dt: float) -> np.ndarray:
    if not divides(t_out, dt):
        raise CoopsimError(f"mujoco.timestep: {dt:g} s does not divide the output interval "
                           f"(integrator.output_dt) into whole steps")
    return np.round(np.diff(t_out) / dt).astype(int)


KINK_GAP = 1e-9            # the step over a kink spans ±this share of the step around it (its stages read both sides)


def reference_kinks(model: Model) -> np.ndarray:
    """The run times (s, from the run's start) where the reference of a `control:` section jumps in
    acceleration: the sample times of a sampled time law of inverse.object_motion (s̈ constant between
    samples, `coopsim.core.model.SampledTimeLaw`; the run's t = 0 is the motion's first time).

    Args:
        model: the Model.

    Returns:
        np.ndarray: (K,) s, increasing; empty without a control section or a sampled law.
    """
    motion = None if model.control is None or model.inverse is None else model.inverse.object_motion
    if motion is None or motion.time_law != "sampled" or motion.samples is None:
        return np.zeros(0)
    return np.asarray(motion.samples.t, dtype=float) - float(motion.times[0])


def advance(m: mujoco.MjModel, d: mujoco.MjData, t0: float, steps: int, kinks: np.ndarray) -> None:
    """`steps` MuJoCo steps of m.opt.timestep h from time t0, cut around every kink c within them: the steps
    end at c − ε and the next starts at c + ε (ε = KINK_GAP·h, at least 1000 ulps of the time), one step of
    2ε between, so that every RK4 stage but that short step's reads one side of the jump (a stage at c itself
    could read either). m.opt.timestep is restored.

    Args:
        m: the MjModel (its opt.timestep h).
        d: the MjData at time t0, stepped in place.
        t0: s, the time of the first step's start (the step ends counted in whole steps from here).
        steps: the number of steps of h.
        kinks: (K,) s, increasing, the times to cut at (`reference_kinks`).
    """
    h = float(m.opt.timestep)
    end = t0 + steps * h
    eps = max(KINK_GAP * h, 1e3 * float(np.spacing(abs(end))))
    lo, hi = np.searchsorted(kinks, [t0 - eps, end + eps])
    if lo >= hi:
        mujoco.mj_step(m, d, steps)
        return
    c = kinks[lo:hi]
    cuts = np.clip(np.concatenate([c - eps, c + eps]), t0, end)
    ends = t0 + h * np.arange(1, steps + 1)
    near = np.min(np.abs(ends[:, None] - c[None, :]), axis=1) <= eps     # a step end inside a cut: dropped
    points = np.unique(np.concatenate([[t0], ends[~near], cuts, [end]]))
    points = points[np.concatenate([[True], np.diff(points) > 0.5 * eps])]
    points[-1] = end
    try:
        for x, y in zip(points[:-1], points[1:]):
            m.opt.timestep = y - x
            mujoco.mj_step(m, d)
    finally:
        m.opt.timestep = h


def run_twin(model: Model, q0: np.ndarray, qd0: np.ndarray, t_out: np.ndarray, progress=None) -> TwinResult:
    """Simulate the twin from (q0, qd0) at t_out[0] = 0 and sample it at t_out.

    The sample intervals are whole multiples of model.mujoco.timestep (set: `coopsim.twin.weld.twin_step`
    chooses an automatic one from the native run). A `control:` section runs its
    controller in the loop (`coopsim.control.controller.closed_loop`), fed the twin's state at every RK4
    stage; the steps are cut around the jumps of its reference's acceleration (`advance`).

    Args:
        model: the scenario's Model (the twin is built from it, `coopsim.twin.mjcf.build_spec`).
        q0: (n,) rad (m on a prismatic joint), the initial joint coordinates (the consistent state).
        qd0: (n,) rad/s (m/s), the initial joint rates.
        t_out: (N,) s, the sample times, from 0.
        progress: called with the fraction done ((i + 1) / N) after each sample; None: no reports.

    Returns:
        TwinResult: the twin's samples at t_out, world axes, SI.

    Raises:
        CoopsimError: mujoco.timestep does not divide the output intervals into whole steps.
    """
    model = closed_loop(model)
    m = build_spec(model).compile()
    d = mujoco.MjData(m)
    qadr, dadr = qpos_address(m, model), dof_address(m, model)
    ctrl = np.array([m.actuator(f"a{a}_m{i}").id for a, arm in enumerate(model.arms) for i in range(arm.n)])
    obj = m.body("object").id
    links = np.array([m.body(f"a{a}_l{i}").id for a, arm in enumerate(model.arms) for i in range(arm.n)])
    weld_rows = lambda: d.efc_type[: d.nefc] == mujoco.mjtConstraint.mjCNSTR_EQUALITY  # noqa: E731
    steps = _steps_per_sample(t_out, m.opt.timestep)
    kinks = reference_kinks(model)
    N, n = len(t_out), model.n_total
    out = {k: np.zeros((N,) + s) for k, s in [("q", (n,)), ("qd", (n,)), ("qdd", (n,)), ("tau", (n,)),
                                            ("object_pos", (3,)), ("object_quat", (4,)),
                                            ("object_twist", (6,)), ("weld_violation", ()),
                                            ("link_pos", (n, 3)), ("link_quat", (n, 4))]}
    d.qpos[qadr], d.qvel[dadr], d.time = q0, qd0, t_out[0]
    start = time.perf_counter()
    vel = np.zeros(6)
    with _control(model, d, ctrl, qadr, dadr):
        for i in range(N):
            if i:
                advance(m, d, float(t_out[i - 1]), int(steps[i - 1]), kinks)
            mujoco.mj_forward(m, d)
            mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, obj, vel, 0)
            out["q"][i], out["qd"][i], out["qdd"][i] = d.qpos[qadr], d.qvel[dadr], d.qacc[dadr]
            out["tau"][i] = d.ctrl[ctrl]
            out["object_pos"][i], out["object_quat"][i] = d.xpos[obj], d.xquat[obj]
            out["object_twist"][i] = np.concatenate([vel[3:], vel[:3]])
            out["link_pos"][i], out["link_quat"][i] = d.xpos[links], d.xquat[links]
            efc = d.efc_pos[: d.nefc][weld_rows()]
            out["weld_violation"][i] = np.max(np.abs(efc)) if efc.size else 0.0
            if progress is not None:
                progress((i + 1) / N)
    wall = time.perf_counter() - start
    return TwinResult(t=np.asarray(t_out, dtype=float), wall_time=wall, **out)
