"""The benchmark's timed runs on one scene: the tight native reference, the native ladders, MuJoCo's
twin through `mujoco.rollout` (the weld time constant chosen per step) and Pinocchio's
`constraintDynamics` under SciPy's DOP853."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable

import mujoco
import numpy as np

from coopsim.apps.bench.measure import (ATOL_RATIO, CHECK_FACTOR, MJ_STAGES, OUTPUT_DT, REFERENCE_ATOL,
                                        REFERENCE_RTOL, WELD_FACTORS, Ladders, RunRow, adaptive_settings, best_time,
                                        have_pinocchio, max_joint_error, rk4_settings)
from coopsim.compiled import api
from coopsim.core.errors import CoopsimError
from coopsim.core.model import IntegratorSettings, Model
from coopsim.forward.simulate import simulate


@dataclass(frozen=True, eq=False)
class Reference:
    """The tight native run on the output grid, the 10x looser check run, and their max joint difference.

    The difference is an estimate of the check run's error and an upper bound on the reference's.

    Attributes:
        result: the tight run (`SimResult`, DOP853 at REFERENCE_RTOL / REFERENCE_ATOL).
        check: the check run (`SimResult`, CHECK_FACTOR looser).
        self_convergence: rad, max |q_check − q_result| over samples and joints.
    """

    result: object
    check: object
    self_convergence: float


def reference(model: Model, output_dt: float = OUTPUT_DT) -> Reference:
    """Native DOP853 at REFERENCE_RTOL / REFERENCE_ATOL, and again CHECK_FACTOR looser.

    Both over model.duration on the output_dt grid.

    Args:
        model: the Model, its duration already the benchmark's (`bench_duration`).
        output_dt: s, the output grid's interval (default OUTPUT_DT).

    Returns:
        Reference: the two runs and their self-convergence difference rad.
    """
    tight = simulate(model, settings=adaptive_settings(model, "dop853", REFERENCE_RTOL, REFERENCE_ATOL, output_dt))
    check = simulate(model, settings=adaptive_settings(model, "dop853", REFERENCE_RTOL * CHECK_FACTOR,
                                                       REFERENCE_ATOL * CHECK_FACTOR, output_dt))
    return Reference(tight, check, max_joint_error(check.q, tight.q))


def _native_loop(model: Model, s: IntegratorSettings, ref) -> Callable[[], object]:
    """The compiled time loop alone (as `simulate` runs it: the outputs reached by dense output left to the
    sampler to project) from the reference's consistent state."""
    m = replace(model, integrator=s)
    y0 = np.concatenate([ref.initial.q, ref.initial.qd])
    fixed = s.step if s.method == "rk4" else None
    return lambda: api.integrate_chain(m, y0, ref.t, s.method, rtol=s.rtol, atol=s.atol, h_max=math.inf,
                                       fixed_step=fixed, defer=True)


def native_run(model: Model, s: IntegratorSettings, ref, ladders: Ladders) -> RunRow:
    """Time `simulate(model, settings=s)` and its time loop alone; error against the reference.

    Args:
        model: the Model.
        s: the run's IntegratorSettings (`adaptive_settings` or `rk4_settings`).
        ref: the reference run (`SimResult`): its output times, joint coordinates and consistent initial
            state (the time loop starts from it).
        ladders: the Ladders (repeats, repeat_budget_s, max_repeats).

    Returns:
        RunRow: family 'native', param rtol or step s; when the run raises CoopsimError: wall_s, max_error
        and final_violation NaN, evals 0 and note 'failed: ...'.
    """
    adaptive = s.method != "rk4"
    setting = f"rtol {s.rtol:.0e}, atol {s.atol:.0e}" if adaptive else f"step {s.step:g} s"
    label = f"{s.rtol:.0e}" if adaptive else f"{1e3 * s.step:g}ms"
    kw = dict(repeats=ladders.repeats, budget_s=ladders.repeat_budget_s, max_repeats=ladders.max_repeats)
    try:
        res, wall = best_time(lambda: simulate(model, settings=s), **kw)
        _, loop = best_time(_native_loop(model, s, ref), **kw)
    except CoopsimError as exc:
        return RunRow("native", s.method, setting, s.rtol if adaptive else s.step, label, math.nan, math.nan,
                      math.nan, 0, note=f"failed: {exc}")
    return RunRow("native", s.method, setting, s.rtol if adaptive else s.step, label, wall,
                  max_joint_error(res.q, ref.q), float(res.residual_pos[-1]), int(res.stats.n_rhs), loop_s=loop,
                  extra={"accepted": int(res.stats.n_accepted), "rejected": int(res.stats.n_rejected)})


def native_runs(model: Model, ref, ladders: Ladders) -> list[RunRow]:
    """DOP853 and DOPRI5 over ladders.rtols, RK4 over ladders.rk4_steps, on the reference's output grid.

    Args:
        model: the Model.
        ref: the reference run (`SimResult`; its integrator.output_dt is the grid's interval).
        ladders: the Ladders.

    Returns:
        list[RunRow]: the DOP853, then DOPRI5, then RK4 rows, each in ladder order (`native_run`).
    """
    dt = ref.model.integrator.output_dt
    cases = [adaptive_settings(model, m, r, output_dt=dt) for m in ("dop853", "dopri5") for r in ladders.rtols]
    cases += [rk4_settings(model, h, dt) for h in ladders.rk4_steps]
    return [native_run(model, s, ref, ladders) for s in cases]


class _MujocoWarnings:
    """Collect MuJoCo's warnings (instability resets) instead of letting it write MUJOCO_LOG.TXT."""

    def __enter__(self):
        self.messages: list[str] = []
        self._prev = mujoco.get_mju_user_warning()
        mujoco.set_mju_user_warning(self.messages.append)
        return self

    def __exit__(self, *exc):
        mujoco.set_mju_user_warning(self._prev)
        return False


def mujoco_run(model: Model, ref, integrator: str, dt: float, peers, ladders: Ladders) -> RunRow:
    """The twin with `integrator` at step dt: one rollout per weld time constant k·dt, the best kept and timed.

    One rollout per k in WELD_FACTORS; the lowest-error one is kept and its rollout repeated for the time.

    Args:
        model: the Model.
        ref: the reference run (`SimResult`): consistent initial state, output times, joint coordinates.
        integrator: 'RK4' | 'Euler' | 'implicit' | 'implicitfast'.
        dt: s, the twin's timestep, a whole fraction of the output grid's interval.
        peers: the peers module (`load_peers`).
        ladders: the Ladders (repeats, repeat_budget_s, max_repeats).

    Returns:
        RunRow: family 'mujoco', param dt s, evals steps × MJ_STAGES[integrator], extra weld_factor,
        weld_timeconst_s, nstep and errors_by_weld_factor; when every weld time constant diverged, the
        first factor's row (max_error NaN) with a note.
    """
    q0, qd0, t = ref.initial.q, ref.initial.qd, ref.t
    tried = {}
    with _MujocoWarnings():
        for k in WELD_FACTORS:
            twin = peers.mujoco_twin(model, integrator, dt, k * dt)
            roll = peers.twin_rollout(twin, q0, qd0, t)
            tried[k] = (max_joint_error(roll.q, ref.q), twin, roll)
        finite = [k for k in WELD_FACTORS if np.isfinite(tried[k][0])]
        k = min(finite, key=lambda j: tried[j][0]) if finite else WELD_FACTORS[0]
        err, twin, roll = tried[k]
        wall = repeat_walls(lambda: peers.twin_rollout(twin, q0, qd0, t), roll.wall_time, ladders)
    when = "" if roll.diverged_at is None else f" (at t = {roll.diverged_at:g} s)"
    note = "" if finite else f"no finite error for any weld time constant{when}"
    extra = {"weld_factor": k, "weld_timeconst_s": k * dt, "nstep": roll.nstep,
             "errors_by_weld_factor": {str(j): tried[j][0] for j in WELD_FACTORS}}
    return RunRow("mujoco", integrator, f"step {dt:g} s, weld timeconst {k}·step", dt, f"{1e3 * dt:g}ms",
                  wall, err, float(roll.weld_violation[-1]), roll.nstep * MJ_STAGES[integrator],
                  extra=extra, note=note)


def mujoco_runs(model: Model, ref, peers, ladders: Ladders) -> list[RunRow]:
    """Every (integrator, steps) ladder of ladders.mujoco.

    Args:
        model: the Model.
        ref: the reference run (`SimResult`).
        peers: the peers module (`load_peers`).
        ladders: the Ladders.

    Returns:
        list[RunRow]: one `mujoco_run` per (integrator, step), in ladder order.
    """
    return [mujoco_run(model, ref, integ, dt, peers, ladders) for integ, steps in ladders.mujoco for dt in steps]


def pinocchio_runs(model: Model, ref, peers, ladders: Ladders) -> list[RunRow]:
    """constraintDynamics + scipy DOP853 over ladders.pin_rtols (atol = rtol · ATOL_RATIO).

    Args:
        model: the Model.
        ref: the reference run (`SimResult`).
        peers: the peers module (`load_peers`).
        ladders: the Ladders.

    Returns:
        list[RunRow]: one `pinocchio_run` per rtol; [] without pinocchio.
    """
    if not have_pinocchio():
        return []
    system = peers.pinocchio_system(model)
    return [pinocchio_run(system, ref, rtol, peers, ladders) for rtol in ladders.pin_rtols]


def pinocchio_run(system, ref, rtol: float, peers, ladders: Ladders) -> RunRow:
    """One Pinocchio trajectory (scipy DOP853 at rtol, atol = rtol · ATOL_RATIO), repeated for the time.

    It starts from the reference's consistent state; the time is that of solve_ivp alone.

    Args:
        system: the model's Pinocchio system (`peers.pinocchio_system`).
        ref: the reference run (`SimResult`): consistent initial state, output times, joint coordinates.
        rtol: scipy DOP853's relative tolerance.
        peers: the peers module (`load_peers`).
        ladders: the Ladders (repeats, repeat_budget_s, max_repeats).

    Returns:
        RunRow: family 'pinocchio', param rtol, final_violation the closure residual (m or rad) at the last
        sample, evals scipy's nfev.
    """
    run = lambda: peers.pinocchio_trajectory(system, ref.initial.q, ref.initial.qd, ref.t, None, rtol,
                                             rtol * ATOL_RATIO)
    traj = run()
    wall = repeat_walls(run, traj.wall_time, ladders)
    return RunRow("pinocchio", "constraintDynamics+DOP853", f"rtol {rtol:.0e}, atol {rtol * ATOL_RATIO:.0e}", rtol,
                  f"{rtol:.0e}", wall, max_joint_error(traj.q, ref.q), float(traj.residual[-1]), traj.nfev)


def repeat_walls(run: Callable[[], object], first: float, ladders: Ladders) -> float:
    """Minimum wall time over `first` and further calls of run(), repeated as `best_time` repeats.

    Each call returns an object with .wall_time s, its own timing of the part that counts.

    Args:
        run: the callable repeated, no arguments, returning an object with .wall_time (s).
        first: s, the wall time of the call already made.
        ladders: the Ladders (repeats, repeat_budget_s s, max_repeats).

    Returns:
        float: s, the minimum.
    """
    walls = [first]
    while len(walls) < ladders.repeats or (sum(walls) < ladders.repeat_budget_s and len(walls) < ladders.max_repeats):
        walls.append(run().wall_time)
    return min(walls)
