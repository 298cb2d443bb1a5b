"""Work-precision benchmark (`coopsim bench`): the native model against its peers, each run timed and
measured against one tight native reference on the same output grid, in the same process.

    reference   native DOP853 at rtol 1e-13 (atol 1e-14), checked against a 10x looser run
    native      DOP853 and DOPRI5 over an rtol ladder (atol = rtol / 10), RK4 over a step ladder
    MuJoCo      the twin (`validation/peers.py`) through `mujoco.rollout`, RK4 / Euler / implicitfast
                over a timestep ladder; per (integrator, step) the weld time constant k·step with the
                lowest error over k in WELD_FACTORS
    Pinocchio   `constraintDynamics` + scipy DOP853 over an rtol ladder (only with `pin` installed)

Per run: wall time s (minimum over repeats; native: `simulate()` end to end, and `loop_s` the compiled
time loop alone from the same consistent state, which is what MuJoCo's timed `Rollout.rollout` call
does; Pinocchio: `solve_ivp`), max joint error rad over the output grid, final constraint violation
(native loop-closure residual, MuJoCo weld efc_pos, Pinocchio closure log6; m or rad). Per model: µs
per dynamics evaluation, from Python and amortised in a compiled loop. Scaling: µs per evaluation of
synthetic scenes, r arms × n joints, with power-law fits. Start-up: first-run compile time and cached
start-up, each a fresh Python process.

Everything here returns plain data (dicts, lists of `RunRow`); `coopsim.apps.bench_report` turns a report
into tables and files, `coopsim.plots.bench` draws the figures. Wall times depend on the machine and
its load: compare within one report only.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field, replace
from importlib import metadata
from pathlib import Path
from typing import Callable

import mujoco
import numpy as np

from coopsim.compiled import api
from coopsim.core.errors import CoopsimError
from coopsim.core.model import IntegratorSettings, Model
from coopsim.forward.simulate import simulate
from coopsim.io.scenario import load_scenario, model_from_dict

OUTPUT_DT = 0.05                     # s: coarse output grid; dense output means it does not limit steps
REFERENCE_RTOL, REFERENCE_ATOL = 1e-13, 1e-14
CHECK_FACTOR = 10.0                  # the self-convergence run is this much looser
ATOL_RATIO = 0.1                     # atol = rtol · ATOL_RATIO on every adaptive ladder
WELD_FACTORS = (1, 2, 4)             # MuJoCo weld time constant = k · timestep
TARGETS = (1e-3, 1e-6, 1e-8)         # rad: headline error targets
MJ_STAGES = {"RK4": 4, "Euler": 1, "implicit": 1, "implicitfast": 1}  # mj_forward-like stages per step

# The issue's targets (reported, never asserted): scenario -> {error target rad: MuJoCo ÷ native at least}
ISSUE_TARGETS = {"paper_planar_2x3": {1e-8: 50.0, 1e-6: 10.0, 1e-3: 1.0}, "spatial_6r_pair": {1e-6: 10.0}}
EVAL_RATIO_TARGET = 0.5              # native amortised µs ÷ one constraintDynamics call, at most ...
EVAL_RATIO_SCENES = ("paper_planar_2x3",)   # ... on the paper system (the issue's target)
CHOLESKY_RANK_TOL = 1e-300          # scaling diagnostic: rank_tol that keeps the Cholesky fast path
EVAL_BUDGET_S = 0.5                  # s: keep repeating a cheap µs/eval timing until this much is spent


@dataclass(frozen=True)
class Ladders:
    """What to run: the ladders of the work-precision benchmark, the repeat rules and the optional parts.

    The first-order MuJoCo integrators stop at 0.25 ms: below it they only add points far from every
    target, at the cost of the slowest rollouts. `FULL` is the default, `QUICK` a short smoke run.

    Attributes:
        rtols: native DOP853 / DOPRI5 rtol ladder (atol = rtol · ATOL_RATIO, no step bound).
        rk4_steps: s, the native RK4 step ladder.
        mujoco: (integrator, steps s) pairs of the MuJoCo twin ('RK4', 'Euler', 'implicitfast', ...), each
            step a whole fraction of OUTPUT_DT.
        pin_rtols: Pinocchio + scipy DOP853 rtol ladder (atol = rtol · ATOL_RATIO).
        max_duration: s, cap on the run length (None: the scenario's duration).
        repeats: timing repeats at least (the minimum of them is reported).
        repeat_budget_s: s, keep repeating a cheap run until this much time is spent (at most max_repeats).
        max_repeats: cap on the repeats made for repeat_budget_s.
        eval_states: states of the amortised evaluation (µs per evaluation), per scenario and per scaling
            point.
        scaling_r, scaling_n: the scaling grid: arm counts r and joints per arm n of the synthetic scenes.
        startup: measure the compile and cached start-up times (`startup_times`, fresh processes) and the
            CLI commands' wall times (`command_times`) on the first scenario.
    """

    rtols: tuple[float, ...] = tuple(10.0 ** -k for k in range(3, 13))
    rk4_steps: tuple[float, ...] = (0.05, 0.025, 0.01, 0.005, 0.0025, 0.001)
    mujoco: tuple[tuple[str, tuple[float, ...]], ...] = (("RK4", (5e-3, 2.5e-3, 1e-3, 5e-4, 2.5e-4, 1e-4)),
                                                         ("Euler", (5e-3, 2.5e-3, 1e-3, 5e-4, 2.5e-4)),
                                                         ("implicitfast", (5e-3, 2.5e-3, 1e-3, 5e-4, 2.5e-4)))
    pin_rtols: tuple[float, ...] = (1e-3, 1e-6, 1e-9, 1e-12)
    max_duration: float | None = None
    repeats: int = 3
    repeat_budget_s: float = 0.3
    max_repeats: int = 15
    eval_states: int = 20000
    scaling_r: tuple[int, ...] = (2, 3, 4, 6, 8)
    scaling_n: tuple[int, ...] = (3, 6, 7)
    startup: bool = True


FULL = Ladders()
QUICK = Ladders(rtols=(1e-3, 1e-6, 1e-9), rk4_steps=(0.05, 0.01),
                mujoco=(("RK4", (5e-3, 1e-3)), ("Euler", (5e-3, 1e-3))), pin_rtols=(1e-4, 1e-8),
                max_duration=0.5, repeats=1, repeat_budget_s=0.0, max_repeats=1, eval_states=2000,
                scaling_r=(2, 3), scaling_n=(3, 6), startup=False)


@dataclass
class RunRow:
    """One timed run of the work-precision benchmark, measured against the scenario's reference.

    Attributes:
        family: 'native' | 'mujoco' | 'pinocchio'.
        method: the integrator (dop853, dopri5, rk4; RK4, Euler, implicitfast; constraintDynamics+DOP853).
        setting: text of its tolerance or step.
        param: rtol, or step s.
        label: short plot label.
        wall_s: s, the minimum wall time over repeats (NaN: the run failed).
        max_error: rad, max joint error against the reference over the output grid (NaN: failed or
            diverged).
        final_violation: m or rad, the constraint violation at the last sample (native loop-closure
            residual, MuJoCo weld efc_pos, Pinocchio closure log6).
        evals: dynamics evaluations (native rhs, MuJoCo steps × stages, scipy nfev).
        loop_s: s, the native time loop alone (None otherwise).
        extra: per-family details (native: accepted and rejected steps; MuJoCo: weld factor, weld time
            constant s, steps and the errors of every factor).
        note: a remark ('failed: ...' for a native run that raised, the divergence of a MuJoCo run; '' otherwise).
        pareto: on the scenario's Pareto front of (max_error, wall_s).
    """

    family: str
    method: str
    setting: str
    param: float
    label: str
    wall_s: float
    max_error: float
    final_violation: float
    evals: int
    loop_s: float | None = None
    extra: dict = field(default_factory=dict)
    note: str = ""
    pareto: bool = False


# ------------------------------------------------------------------------------------------------
# pieces


def load_peers():
    """`validation/peers.py` of the source checkout as a module (loaded once, kept in sys.modules).

    The peers are validation material, not installed with the package.

    Returns:
        module: the peers module (mujoco_twin, twin_rollout, pinocchio_system, ...).

    Raises:
        CoopsimError: when validation/peers.py is not there.
    """
    name = "coopsim_validation_peers"
    if name in sys.modules:
        return sys.modules[name]
    path = Path(__file__).resolve().parents[2] / "validation" / "peers.py"
    if not path.is_file():
        raise CoopsimError(f"coopsim bench needs {path} (validation/peers.py of the source checkout)")
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def have_pinocchio() -> bool:
    """Whether the optional `pin` package (module pinocchio) can be imported.

    Returns:
        bool: True when `import pinocchio` succeeds.
    """
    try:
        import pinocchio  # noqa: F401
    except ImportError:
        return False
    return True


def best_time(fn: Callable[[], object], repeats: int = 3, budget_s: float = 0.0,
              max_repeats: int = 15) -> tuple[object, float]:
    """Time fn over at least `repeats` calls, more while the total is under budget_s (at most max_repeats).

    Args:
        fn: the callable timed, no arguments.
        repeats: calls at least (one at least).
        budget_s: s, keep calling while the calls' total wall time is under it.
        max_repeats: cap on the calls made for budget_s (`repeats` calls are made whatever it is).

    Returns:
        tuple[object, float]: (the last call's result, minimum wall time of one call s).
    """
    best, spent, k, out = math.inf, 0.0, 0, None
    while k < max(1, repeats) or (spent < budget_s and k < max_repeats):
        start = time.perf_counter()
        out = fn()
        wall = time.perf_counter() - start
        best, spent, k = min(best, wall), spent + wall, k + 1
    return out, best


def max_joint_error(q: np.ndarray, q_ref: np.ndarray) -> float:
    """max |q − q_ref| over samples and joints; NaN if q (or q_ref) has any non-finite value.

    Args:
        q: (N, n) rad (m on a prismatic joint), a run's joint coordinates on the output grid.
        q_ref: (N, n) the reference's, on the same grid.

    Returns:
        float: rad (m on a prismatic joint), or NaN.
    """
    d = np.abs(np.asarray(q, float) - np.asarray(q_ref, float))
    return float(np.max(d)) if np.all(np.isfinite(d)) else math.nan


def pareto_front(errors, times) -> np.ndarray:
    """Boolean mask of the points not dominated in (error, time), both minimised.

    A point is dominated when another is at most as large in both and smaller in one. Non-finite points
    are never on the front.

    Args:
        errors: (M,) the points' errors (rad for the benchmark's runs).
        times: (M,) their times (s).

    Returns:
        np.ndarray: (M,) bool, True on the Pareto front.
    """
    e, t = np.asarray(errors, float), np.asarray(times, float)
    ok = np.isfinite(e) & np.isfinite(t)
    mask = np.zeros(len(e), bool)
    for i in np.nonzero(ok)[0]:
        dom = ok & (e <= e[i]) & (t <= t[i]) & ((e < e[i]) | (t < t[i]))
        mask[i] = not np.any(dom)
    return mask


def power_fit(x, y) -> dict:
    """Least-squares fit of log y = log c + p log x; needs two distinct x.

    Args:
        x: (K,) positive abscissae.
        y: (K,) positive values.

    Returns:
        dict: {'exponent': p, 'coefficient': c (in y's units), 'rms_log10': rms residual in decades}.
    """
    lx, ly = np.log(np.asarray(x, float)), np.log(np.asarray(y, float))
    A = np.column_stack([np.ones_like(lx), lx])
    (a, p), *_ = np.linalg.lstsq(A, ly, rcond=None)
    res = ly - A @ np.array([a, p])
    rms = float(np.sqrt(np.mean(res ** 2)) / np.log(10))
    return {"exponent": float(p), "coefficient": float(np.exp(a)), "rms_log10": rms}


def fastest_reaching(rows: list[RunRow], family: str, target: float, key: str = "wall_s") -> RunRow | None:
    """The row of `family` with the smallest `key` time among those with max_error ≤ target.

    Only rows whose time is finite (and not None) count.

    Args:
        rows: the runs.
        family: 'native' | 'mujoco' | 'pinocchio'.
        target: rad, the error target.
        key: the time compared: 'wall_s' or 'loop_s' (s).

    Returns:
        RunRow | None: the fastest such row (None: no such row).
    """
    ok = [r for r in rows if r.family == family and np.isfinite(r.max_error) and r.max_error <= target
          and getattr(r, key) is not None and np.isfinite(getattr(r, key))]
    return min(ok, key=lambda r: getattr(r, key)) if ok else None


def bench_duration(model: Model, ladders: Ladders) -> float:
    """Run length: the scenario's, capped by ladders.max_duration, down to a whole number of OUTPUT_DT intervals.

    Whole intervals because MuJoCo samples on whole steps.

    Args:
        model: the scenario's Model (its duration s).
        ladders: the Ladders (max_duration s, None: no cap).

    Returns:
        float: s, a positive whole multiple of OUTPUT_DT (one interval at least).
    """
    d = model.duration if ladders.max_duration is None else min(model.duration, ladders.max_duration)
    return OUTPUT_DT * max(1, math.floor(d / OUTPUT_DT + 1e-9))


def adaptive_settings(model: Model, method: str, rtol: float, atol: float | None = None) -> IntegratorSettings:
    """The model's integrator settings with an adaptive method, its tolerances, unbounded step, output every OUTPUT_DT.

    Args:
        model: the Model whose integrator settings are the base.
        method: 'dop853' | 'dopri5'.
        rtol: relative tolerance.
        atol: absolute tolerance, rad or m and rad/s or m/s (default rtol · ATOL_RATIO).

    Returns:
        IntegratorSettings: the modified copy (max_step None, output_dt OUTPUT_DT s).
    """
    return replace(model.integrator, method=method, rtol=rtol, atol=rtol * ATOL_RATIO if atol is None else atol,
                   max_step=None, output_dt=OUTPUT_DT)


def rk4_settings(model: Model, step: float) -> IntegratorSettings:
    """The model's integrator settings with RK4 at `step` s, output every OUTPUT_DT.

    Args:
        model: the Model whose integrator settings are the base.
        step: s, the fixed step.

    Returns:
        IntegratorSettings: the modified copy (method 'rk4', output_dt OUTPUT_DT s).
    """
    return replace(model.integrator, method="rk4", step=step, output_dt=OUTPUT_DT)


# ------------------------------------------------------------------------------------------------
# reference and native runs


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


def reference(model: Model) -> Reference:
    """Native DOP853 at REFERENCE_RTOL / REFERENCE_ATOL, and again CHECK_FACTOR looser.

    Both over model.duration on the OUTPUT_DT grid.

    Args:
        model: the Model, its duration already the benchmark's (`bench_duration`).

    Returns:
        Reference: the two runs and their self-convergence difference rad.
    """
    tight = simulate(model, settings=adaptive_settings(model, "dop853", REFERENCE_RTOL, REFERENCE_ATOL))
    check = simulate(model, settings=adaptive_settings(model, "dop853", REFERENCE_RTOL * CHECK_FACTOR,
                                                       REFERENCE_ATOL * CHECK_FACTOR))
    return Reference(tight, check, max_joint_error(check.q, tight.q))


def _native_loop(model: Model, s: IntegratorSettings, ref) -> Callable[[], object]:
    """The compiled time loop alone (as `simulate` runs it) from the reference's consistent state."""
    m = replace(model, integrator=s)
    y0 = np.concatenate([ref.initial.q, ref.initial.qd])
    fixed = s.step if s.method == "rk4" else None
    return lambda: api.integrate_chain(m, y0, ref.t, s.method, rtol=s.rtol, atol=s.atol, h_max=math.inf,
                                       fixed_step=fixed)


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
    """DOP853 and DOPRI5 over ladders.rtols, RK4 over ladders.rk4_steps.

    Args:
        model: the Model.
        ref: the reference run (`SimResult`).
        ladders: the Ladders.

    Returns:
        list[RunRow]: the DOP853, then DOPRI5, then RK4 rows, each in ladder order (`native_run`).
    """
    cases = [adaptive_settings(model, m, r) for m in ("dop853", "dopri5") for r in ladders.rtols]
    cases += [rk4_settings(model, h) for h in ladders.rk4_steps]
    return [native_run(model, s, ref, ladders) for s in cases]


# ------------------------------------------------------------------------------------------------
# MuJoCo


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
        dt: s, the twin's timestep, a whole fraction of OUTPUT_DT.
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
    note = "" if finite else f"diverged at t = {roll.diverged_at:g} s for every weld time constant"
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


# ------------------------------------------------------------------------------------------------
# Pinocchio


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


# ------------------------------------------------------------------------------------------------
# cost per evaluation


def trajectory_states(ref, count: int) -> tuple[np.ndarray, np.ndarray]:
    """The reference's samples repeated cyclically as `count` states and torques.

    Args:
        ref: the reference run (`SimResult`): q, qd, tau on its output grid.
        count: the number of states S.

    Returns:
        tuple[np.ndarray, np.ndarray]: Y (S, 2n) = [θ; θ̇] rad, rad/s (m, m/s on a prismatic joint) and TAU
        (S, n) N·m (N).
    """
    idx = np.arange(count) % len(ref.t)
    return np.hstack([ref.q, ref.qd])[idx], ref.tau[idx]


def native_eval_us(model: Model, Y: np.ndarray, TAU: np.ndarray, repeats: int = 3, calls: int = 2000) -> dict:
    """µs per native closed-chain evaluation, amortised over the states and from Python.

    'native_amortised_us': api.evaluate_states over the S states, one thread; 'native_python_us':
    api.forward, one call from Python at Y[0], timed in loops of `calls`. Each is the minimum over at least
    `repeats` timings, more (up to 10) while under EVAL_BUDGET_S.

    Args:
        model: the Model.
        Y: (S, 2n) the states [θ; θ̇], rad, rad/s (m, m/s on a prismatic joint).
        TAU: (S, n) N·m (N), the joint torques.
        repeats: timings at least.
        calls: api.forward calls per timing.

    Returns:
        dict: 'native_amortised_us' µs, 'native_python_us' µs, 'bad_states': evaluations with a non-zero
        status.
    """
    n = model.n_total
    kw = dict(repeats=repeats, budget_s=EVAL_BUDGET_S, max_repeats=10)
    out, wall = best_time(lambda: api.evaluate_states(model, Y, TAU, n_threads=1), **kw)
    q, qd, tau = Y[0, :n].copy(), Y[0, n:].copy(), TAU[0].copy()
    api.forward(model, q, qd, tau)
    _, loop = best_time(lambda: [api.forward(model, q, qd, tau) for _ in range(calls)], **kw)
    return {"native_amortised_us": 1e6 * wall / len(Y), "native_python_us": 1e6 * loop / calls,
            "bad_states": int(np.count_nonzero(out.status))}


def peer_eval_us(model: Model, q: np.ndarray, qd: np.ndarray, tau: np.ndarray, peers, calls: int = 2000,
                 repeats: int = 3) -> dict:
    """µs per call from Python of MuJoCo's mj_forward and, with pin, of pinocchio.constraintDynamics.

    The MuJoCo twin is built at the scenario's step, RK4.

    Args:
        model: the Model.
        q: (n,) rad (m on a prismatic joint), the joint coordinates.
        qd: (n,) rad/s (m/s), the joint rates.
        tau: (n,) N·m (N), the joint torques.
        peers: the peers module (`load_peers`).
        calls: calls per timing loop.
        repeats: timing loops (the minimum is kept).

    Returns:
        dict: 'mujoco_forward_us' µs and 'pinocchio_us' µs (None without pin).
    """
    twin = peers.mujoco_twin(model, "RK4")
    out = {"mujoco_forward_us": peers.mujoco_forward_us(twin, q, qd, tau, calls, repeats), "pinocchio_us": None}
    if have_pinocchio():
        system = peers.pinocchio_system(model)
        out["pinocchio_us"] = peers.pinocchio_eval_us(system, q, qd, tau, calls, repeats)
    return out


def eval_costs(model: Model, ref, rows: list[RunRow], peers, ladders: Ladders) -> dict:
    """Per-model µs per evaluation: native, MuJoCo and Pinocchio, from Python and in their integrators.

    Native: amortised and from Python (`native_eval_us` at ladders.eval_states states of the reference),
    and in the time loop of the tightest DOP853 run (loop_s / rhs evaluations). MuJoCo: mj_forward from
    Python; amortised: rollout wall / (steps · 4) of the RK4 run with the most steps. Pinocchio: from
    Python; in its scipy integrator: wall / nfev of its tightest run. The from-Python peers are timed at
    the reference's middle sample.

    Args:
        model: the Model.
        ref: the reference run (`SimResult`).
        rows: the scenario's runs (native, MuJoCo, Pinocchio).
        peers: the peers module (`load_peers`).
        ladders: the Ladders (eval_states, repeats).

    Returns:
        dict: µs: 'native_amortised_us', 'native_python_us', 'mujoco_forward_us', 'pinocchio_us' (None
        without pin), and where such runs exist 'native_loop_us_per_rhs', 'mujoco_amortised_us',
        'pinocchio_in_integrator_us'; 'native_amortised_over_pinocchio' (with pin); 'bad_states',
        'n_joints', 'eval_states'.
    """
    Y, TAU = trajectory_states(ref, ladders.eval_states)
    n = model.n_total
    k = len(ref.t) // 2
    out = native_eval_us(model, Y, TAU, repeats=max(ladders.repeats, 2))
    out |= peer_eval_us(model, ref.q[k], ref.qd[k], ref.tau[k], peers, repeats=max(ladders.repeats, 2))
    dop = [r for r in rows if r.family == "native" and r.method == "dop853" and r.loop_s]
    if dop:
        tight = min(dop, key=lambda r: r.param)
        out["native_loop_us_per_rhs"] = 1e6 * tight.loop_s / tight.evals
    rk4 = [r for r in rows if r.family == "mujoco" and r.method == "RK4" and np.isfinite(r.wall_s)]
    if rk4:
        longest = max(rk4, key=lambda r: r.evals)
        out["mujoco_amortised_us"] = 1e6 * longest.wall_s / longest.evals
    pin = [r for r in rows if r.family == "pinocchio"]
    if pin:
        tight = min(pin, key=lambda r: r.param)
        out["pinocchio_in_integrator_us"] = 1e6 * tight.wall_s / tight.evals
    if out["pinocchio_us"]:
        out["native_amortised_over_pinocchio"] = out["native_amortised_us"] / out["pinocchio_us"]
    out["n_joints"], out["eval_states"] = n, len(Y)
    return out


# ------------------------------------------------------------------------------------------------
# headline


def headline(name: str, rows: list[RunRow], targets=TARGETS) -> list[dict]:
    """Per error target: the fastest native and MuJoCo runs reaching it and MuJoCo's wall time ÷ native's.

    The native run is picked by simulate() wall time and by time-loop time. 'ratio_wall': native simulate()
    end to end; 'ratio_loop': native time loop alone, the like-for-like of the timed rollout call. The
    issue's required ratio for this scenario is given where it sets one (None otherwise), with whether each
    ratio meets it ('met_wall', 'met_loop'; None: no requirement, or no ratio). A ratio is None when either
    side has no run within the target ('note' says which).

    Args:
        name: the scenario's name (looked up in ISSUE_TARGETS).
        rows: the scenario's runs.
        targets: rad, the error targets.

    Returns:
        list[dict]: one per target: 'target_rad' rad; 'native', 'native_by_loop', 'mujoco' (method,
        setting, wall_s s, loop_s s, max_error rad of the run, or None); 'ratio_wall', 'ratio_loop',
        'required_ratio', 'met_wall', 'met_loop', 'note'.
    """
    out = []
    for target in targets:
        nat, mj = fastest_reaching(rows, "native", target), fastest_reaching(rows, "mujoco", target)
        nat_loop = fastest_reaching(rows, "native", target, key="loop_s")
        req = ISSUE_TARGETS.get(name, {}).get(target)
        entry = {"target_rad": target, "native": _brief(nat), "native_by_loop": _brief(nat_loop), "mujoco": _brief(mj),
                 "ratio_wall": mj.wall_s / nat.wall_s if nat and mj else None,
                 "ratio_loop": mj.wall_s / nat_loop.loop_s if nat_loop and mj else None, "required_ratio": req}
        entry["note"] = "no MuJoCo run reaches this error" if mj is None else (
            "no native run reaches this error" if nat is None else "")
        for k in ("wall", "loop"):
            ratio = entry[f"ratio_{k}"]
            entry[f"met_{k}"] = None if req is None or ratio is None else bool(ratio >= req)
        out.append(entry)
    return out


def _brief(row: RunRow | None) -> dict | None:
    """method, setting, wall_s, loop_s, max_error of a row (None: none)."""
    if row is None:
        return None
    return {"method": row.method, "setting": row.setting, "wall_s": row.wall_s, "loop_s": row.loop_s,
            "max_error": row.max_error}


# ------------------------------------------------------------------------------------------------
# one scenario


def bench_scenario(model: Model, ladders: Ladders, peers, log: Callable[[str], None] = lambda s: None) -> dict:
    """The whole benchmark of one scenario: reference, every run, µs per evaluation, headline.

    The reference comes with its self-convergence, the runs with their Pareto flags.

    Args:
        model: the scenario's Model (its duration is cut to `bench_duration`).
        ladders: the Ladders.
        peers: the peers module (`load_peers`).
        log: progress callback, one line of text per stage.

    Returns:
        dict: 'name'; 'duration_s' s; 'output_dt_s' s; 'n_joints'; 'arms'; 'reference' (method, rtol,
        atol, check_rtol, check_atol, self_convergence_rad rad, far_below_targets,
        smallest_measured_error_rad rad or None, rhs_evaluations); 'runs' (`RunRow`s as dicts); 'eval_us'
        (`eval_costs`); 'headline' (`headline`); 'notes' (list of str).
    """
    model = replace(model, duration=bench_duration(model, ladders))
    log(f"{model.name}: reference ({model.duration:g} s)")
    ref = reference(model)
    log(f"{model.name}: native ladders")
    rows = native_runs(model, ref.result, ladders)
    log(f"{model.name}: MuJoCo ladders")
    rows += mujoco_runs(model, ref.result, peers, ladders)
    notes = []
    if have_pinocchio():
        log(f"{model.name}: Pinocchio ladder")
        rows += pinocchio_runs(model, ref.result, peers, ladders)
    else:
        notes.append("Pinocchio rows skipped: the optional 'pin' package is not installed (pip install -e '.[bench]')")
    for row, on in zip(rows, pareto_front([r.max_error for r in rows], [r.wall_s for r in rows])):
        row.pareto = bool(on)
    log(f"{model.name}: cost per evaluation")
    costs = eval_costs(model, ref.result, rows, peers, ladders)
    return {"name": model.name, "duration_s": model.duration, "output_dt_s": OUTPUT_DT,
            "n_joints": model.n_total, "arms": model.r, "reference": _reference_summary(ref, rows),
            "runs": [asdict(r) for r in rows], "eval_us": costs, "headline": headline(model.name, rows),
            "notes": notes}


def _reference_summary(ref: Reference, rows: list[RunRow]) -> dict:
    """Reference settings, its self-convergence difference rad, and whether it is far below every
    error target (≤ 1 % of the smallest) and below the smallest measured error."""
    errs = [r.max_error for r in rows if np.isfinite(r.max_error) and r.max_error > 0]
    sc = ref.self_convergence
    return {"method": "dop853", "rtol": REFERENCE_RTOL, "atol": REFERENCE_ATOL,
            "check_rtol": REFERENCE_RTOL * CHECK_FACTOR, "check_atol": REFERENCE_ATOL * CHECK_FACTOR,
            "self_convergence_rad": sc, "far_below_targets": bool(sc <= 0.01 * min(TARGETS)),
            "smallest_measured_error_rad": min(errs) if errs else None,
            "rhs_evaluations": int(ref.result.stats.n_rhs)}


# ------------------------------------------------------------------------------------------------
# scaling: synthetic scenes


_SPATIAL_AXES = ([0, 0, 1], [0, 1, 0], [0, 1, 0], [1, 0, 0], [0, 1, 0], [1, 0, 0], [0, 0, 1])
_SPATIAL_LENGTHS = (0.12, 0.45, 0.40, 0.10, 0.08, 0.06, 0.05)
_SPATIAL_ANGLES = (0.3, -0.9, 1.2, 0.4, -0.7, 0.5, 0.2)
_PLANAR_LENGTHS = (0.5, 0.4, 0.1)
_PLANAR_ANGLES = (1.0, -1.1, -0.7)


def synthetic_scene(r: int, n: int) -> dict:
    """Scenario data (the YAML dict) of r arms of n revolute joints around a box held in a closed chain.

    Bases on a 0.8 m circle facing the centre, holding a 0.3 × 0.3 × 0.08 m box whose grasps are derived
    from the initial configuration; zero torques, 1 s. n = 3: planar arms (parallel vertical axes, planar
    constraint rows: a 3-joint arm cannot hold a 6-D grasp, Λ𝐈⁻¹Λᵀ would be singular for r ≥ 3); n ≥ 4:
    spatial arms with non-parallel axes (yaw, pitch, pitch, roll, pitch, roll, yaw), spatial rows; n ≤ 7.

    Args:
        r: the number of arms.
        n: joints per arm: 3 (planar) or 4 to 7 (spatial).

    Returns:
        dict: the scenario (name 'synthetic_RxN', gravity, duration, arms, object).

    Raises:
        ValueError: n is neither 3 nor in 4..7.
    """
    if not (n == 3 or 4 <= n <= len(_SPATIAL_AXES)):
        raise ValueError(f"n must be 3 (planar) or 4..{len(_SPATIAL_AXES)} (spatial), got {n}")
    arms = [_synthetic_arm(m, r, n) for m in range(r)]
    return {"name": f"synthetic_{r}x{n}", "gravity": [0.0, 0.0, -9.81], "duration": 1.0, "arms": arms,
            "object": {"box": {"size": [0.3, 0.3, 0.08], "density": 1000}, "grasps": "derive"}}


def _synthetic_arm(m: int, r: int, n: int) -> dict:
    """Arm m of `synthetic_scene`: base at angle 2πm/r on the circle, yawed to face the centre."""
    phi = 2.0 * math.pi * m / r
    yaw = math.remainder(phi + math.pi, 2.0 * math.pi)
    base = {"position": [0.8 * math.cos(phi), 0.8 * math.sin(phi), 0.0], "rpy": [0.0, 0.0, yaw]}
    box = lambda L, w: {"length": L, "cross_section": [w, w], "density": 2700}
    if n == 3:
        links = [{"joint": {"axis": [0, 0, 1]}, "box": box(L, 0.04)} for L in _PLANAR_LENGTHS]
        angles = list(_PLANAR_ANGLES)
    else:
        links = [{"joint": {"axis": _SPATIAL_AXES[i]}, "box": box(_SPATIAL_LENGTHS[i], 0.05)} for i in range(n)]
        links[0]["joint"]["position"] = [0.0, 0.0, 0.3]
        angles = list(_SPATIAL_ANGLES[:n])
    angles = [a + 0.05 * m for a in angles]
    return {"name": f"arm{m}", "base": base, "links": links, "initial": {"angles": angles},
            "torque": {"constant": [0.0] * n}}


def synthetic_model(r: int, n: int) -> Model:
    """The frozen Model of `synthetic_scene(r, n)`.

    Args:
        r: the number of arms.
        n: joints per arm: 3 (planar) or 4 to 7 (spatial).

    Returns:
        Model: the frozen scenario model.
    """
    return model_from_dict(synthetic_scene(r, n), where=f"synthetic_{r}x{n}")


def scaling_point(r: int, n: int, count: int, peers=None, repeats: int = 3, seed: int = 0) -> dict:
    """µs per evaluation of synthetic_model(r, n) at `count` random states.

    The states are q0 + N(0, 0.1²) rad, rates N(0, 1) rad/s, torques N(0, 1) N·m (not on the manifold: the
    cost does not depend on it): native amortised and from Python (`native_eval_us`), and
    'native_cholesky_us', amortised with rank_tol CHOLESKY_RANK_TOL (a diagnostic: the dense path's pivoted
    Cholesky taken whenever its pivots are positive, where the default rank_tol's guaranteed-bound test may
    send it to the eigen-decomposition; for three arms or more the O(r) Schur path (`compiled.schur`) is
    taken either way where its own certificate holds); with peers also mj_forward and constraintDynamics
    from Python (at the first state).

    Args:
        r: the number of arms.
        n: joints per arm (`synthetic_scene`).
        count: the number of states S.
        peers: the peers module (`load_peers`); None: native only.
        repeats: timings at least.
        seed: seed of the random states.

    Returns:
        dict: 'r', 'n', 'n_total' (stacked joints), 'rows' (constraint rows K = rows per grasp × (r − 1)),
        'planar'; µs: 'native_amortised_us', 'native_python_us', 'native_cholesky_us', with peers
        'mujoco_forward_us' and 'pinocchio_us' (None without pin); 'bad_states'.
    """
    model = synthetic_model(r, n)
    rng = np.random.default_rng(seed)
    N = model.n_total
    Y = np.hstack([model.q0 + rng.normal(scale=0.1, size=(count, N)), rng.normal(size=(count, N))])
    TAU = rng.normal(size=(count, N))
    out = {"r": r, "n": n, "n_total": N, "rows": int(model.rows.shape[0] * (r - 1)),
           "planar": model.plane is not None} | native_eval_us(model, Y, TAU, repeats, calls=1000)
    forced = replace(model, integrator=replace(model.integrator, rank_tol=CHOLESKY_RANK_TOL))
    out["native_cholesky_us"] = native_eval_us(forced, Y, TAU, repeats, calls=1)["native_amortised_us"]
    if peers is not None:
        out |= peer_eval_us(model, Y[0, :N], Y[0, N:], TAU[0], peers, calls=1000, repeats=repeats)
    return out


def scaling_study(ladders: Ladders, peers=None, log: Callable[[str], None] = lambda s: None) -> dict:
    """Every (r, n) of the ladders' grid (`scaling_point`) and power-law fits (`scaling_fits`).

    The fits are of the amortised µs ('fits') and of the forced-Cholesky diagnostic ('fits_cholesky').

    Args:
        ladders: the Ladders (scaling_r, scaling_n, eval_states, repeats).
        peers: the peers module (`load_peers`); None: native only.
        log: progress callback, one line of text per point.

    Returns:
        dict: 'points' (`scaling_point` dicts, r outer, n inner), 'fits', 'fits_cholesky'.
    """
    points = []
    for r in ladders.scaling_r:
        for n in ladders.scaling_n:
            log(f"scaling: {r} arms x {n} joints")
            points.append(scaling_point(r, n, ladders.eval_states, peers, max(ladders.repeats, 2)))
    return {"points": points, "fits": scaling_fits(points),
            "fits_cholesky": scaling_fits(points, "native_cholesky_us")}


def scaling_fits(points: list[dict], key: str = "native_amortised_us") -> dict:
    """Power-law fits (`power_fit`) of points[key] per fixed r, per fixed n, and over every point.

    'in_total_joints' per fixed r (over n), 'in_arms' per fixed n (over r), and 'all' of every point in
    total joints; only groups of two or more distinct abscissae.

    Args:
        points: `scaling_point` dicts.
        key: the µs field fitted.

    Returns:
        dict: 'in_total_joints' {str(r): fit}, 'in_arms' {str(n): fit}, and 'all' (a fit; only with two
        distinct total joint counts).
    """
    def group(by: str, x: str) -> dict:
        out = {}
        for v in sorted({p[by] for p in points}):
            sel = [p for p in points if p[by] == v]
            if len({p[x] for p in sel}) >= 2:
                out[str(v)] = power_fit([p[x] for p in sel], [p[key] for p in sel])
        return out

    fits = {"in_total_joints": group("r", "n_total"), "in_arms": group("n", "r")}
    if len({p["n_total"] for p in points}) >= 2:
        fits["all"] = power_fit([p["n_total"] for p in points], [p[key] for p in points])
    return fits


# ------------------------------------------------------------------------------------------------
# start-up


_STARTUP_SCRIPT = ("import json, time; t0 = time.perf_counter(); from coopsim.io.scenario import load_scenario; "
                   "from coopsim.forward.simulate import simulate; m = load_scenario({path!r}); "
                   "t1 = time.perf_counter(); "
                   "{warm}simulate(m, duration=0.05); t2 = time.perf_counter(); simulate(m, duration=0.05); "
                   "t3 = time.perf_counter(); "
                   "print(json.dumps({{'imports': t1 - t0, 'first': t2 - t1, 'again': t3 - t2}}))")
_WARM_UP = "from coopsim.apps.warmup import warm_up; warm_up(); "   # what the CLI does on a first run


def _source_stamps() -> dict[str, int]:
    """Modification times (ns) of the compiled kernels' sources (coopsim/compiled/**/*.py): numba's
    cache is keyed on them."""
    root = Path(__file__).resolve().parents[1] / "compiled"
    return {str(p): p.stat().st_mtime_ns for p in sorted(root.rglob("*.py"))}


def startup_process(path: str, warm: bool, env: dict | None = None) -> tuple[float, dict]:
    """Wall time and phases of one fresh process running the start-up script on a scenario file.

    The process loads the scenario and simulates 0.05 s twice, with the CLI's warm-up first if `warm`.

    Args:
        path: the scenario file (absolute path).
        warm: run the CLI's warm-up (`coopsim.apps.warmup`) before the first simulation.
        env: the process's environment (None: this process's).

    Returns:
        tuple[float, dict]: (wall time s, phases): 'imports', 'first' and 'again' (the two 0.05 s
        simulations), in s, as the process measures them.

    Raises:
        CoopsimError: the process fails.
    """
    code = _STARTUP_SCRIPT.format(path=path, warm=_WARM_UP if warm else "")
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=900)
    wall = time.perf_counter() - start
    if done.returncode:
        raise CoopsimError(f"start-up measurement failed: {done.stderr.strip().splitlines()[-1:]}")
    return wall, json.loads(done.stdout.splitlines()[-1])


def _startup_once(path: str) -> dict:
    """One compile / cached pair of fresh processes (see `startup_times`)."""
    out = {}
    with tempfile.TemporaryDirectory(prefix="coopsim-numba-") as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        for key, warm in (("compile", True), ("cached", False)):
            out[f"{key}_s"], phases = startup_process(path, warm, env)
            out[f"{key}_inside_s"] = phases["imports"] + phases["first"]
        out["jit_load_s"] = phases["first"] - phases["again"]
        out["interpreter_s"] = out["cached_s"] - out["cached_inside_s"] - phases["again"]
    return out


def startup_times(scenario: str | Path, attempts: int = 2) -> dict:
    """Wall times of fresh `python -c` processes that import coopsim and simulate 0.05 s of `scenario` twice.

    'compile_s' with NUMBA_CACHE_DIR an empty temporary folder, compiling every kernel first as the CLI's
    first run does (`coopsim.apps.warmup`, two processes), 'cached_s' the same again with that cache filled
    and no warm-up; '..._inside_s': imports and the first run, as the process measures them; 'jit_load_s':
    the first run less the second (numba's import and loading the compiled kernels from the cache);
    'interpreter_s': the cached process's time before its first line. A source file changed between the
    two processes invalidates the cache: the pair is then run again (up to `attempts` times) and
    'sources_changed' says whether the last pair still saw a change.

    Args:
        scenario: the scenario file.
        attempts: compile / cached pairs at most (one at least).

    Returns:
        dict: s: 'compile_s', 'compile_inside_s', 'cached_s', 'cached_inside_s', 'jit_load_s',
        'interpreter_s'; 'sources_changed' (bool).
    """
    path = str(Path(scenario).resolve())
    for _ in range(max(1, attempts)):
        before = _source_stamps()
        out = _startup_once(path)
        out["sources_changed"] = _source_stamps() != before
        if not out["sources_changed"]:
            break
    return out


COMMANDS = {"run": (["run"], 5.0), "inverse --replay": (["inverse", "--replay"], 3.0),
            "capacity": (["capacity"], 3.0)}   # wall-time targets (s), paper scene, warm cache


def command_times(scenario: str | Path, repeats: int = 2, commands=COMMANDS) -> dict:
    """Wall time of each CLI command on `scenario` as a user runs it.

    Each a fresh `python -m coopsim.cli` process writing into a temporary folder, the compiled kernels
    already cached.

    Args:
        scenario: the scenario file.
        repeats: runs of each command (one at least).
        commands: {name: (CLI words, wall-time target s)} (default COMMANDS).

    Returns:
        dict: {name: {"wall_s": the minimum over `repeats` s, "target_s": s, "met": bool}}.

    Raises:
        CoopsimError: a command exits with a status other than 0 or 1 (1: it ran, but a check failed).
    """
    out = {}
    with tempfile.TemporaryDirectory(prefix="coopsim-bench-") as folder:
        for name, (words, target) in commands.items():
            walls = []
            for _ in range(max(1, repeats)):
                cmd = [sys.executable, "-m", "coopsim.cli", words[0], str(scenario), *words[1:], "--json",
                       "--out", folder]
                start = time.perf_counter()
                done = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
                walls.append(time.perf_counter() - start)
                if done.returncode not in (0, 1):      # 1: ran, but a check failed (reported by the command)
                    raise CoopsimError(f"coopsim {name} failed: {done.stderr.strip().splitlines()[-1:]}")
            out[name] = {"wall_s": min(walls), "target_s": target, "met": min(walls) <= target}
    return out


# ------------------------------------------------------------------------------------------------
# the whole benchmark


def run_bench(scenarios: list[str | Path], ladders: Ladders = FULL, peers=None,
              log: Callable[[str], None] = lambda s: None) -> dict:
    """Benchmark each scenario file, the scaling grid and (ladders.startup) the start-up and command times.

    The start-up times and the commands' wall times are measured on the first scenario.

    Args:
        scenarios: the scenario files.
        ladders: the Ladders (default FULL).
        peers: the peers module (None: `load_peers`).
        log: progress callback, one line of text per stage.

    Returns:
        dict: 'settings' (what was run: the Ladders as a dict, output_dt_s, reference tolerances,
        atol_over_rtol, weld_factors, targets_rad), 'environment' (`environment`, plus 'load_average_end'),
        'scenarios' (`bench_scenario` dicts), 'scaling' (`scaling_study`), 'startup' (`startup_times`, or
        None) and 'commands' (`command_times`, or None).
    """
    peers = peers or load_peers()
    models = [load_scenario(p) for p in scenarios]
    simulate(models[0], duration=OUTPUT_DT)  # warm-up: load (or compile) the kernels before timing
    report = {"settings": _settings(ladders), "environment": environment(), "scenarios": []}
    for model in models:
        report["scenarios"].append(bench_scenario(model, ladders, peers, log))
    report["scaling"] = scaling_study(ladders, peers, log)
    report["startup"] = report["commands"] = None
    if ladders.startup:
        log("start-up: fresh processes (compile, then cached)")
        report["startup"] = startup_times(scenarios[0])
        log("commands: run, inverse --replay, capacity as a user runs them")
        report["commands"] = command_times(scenarios[0])
    report["environment"]["load_average_end"] = environment()["load_average"]
    return report


def _settings(ladders: Ladders) -> dict:
    """The ladders and fixed choices, for the report."""
    return asdict(ladders) | {"output_dt_s": OUTPUT_DT, "reference": [REFERENCE_RTOL, REFERENCE_ATOL],
                              "atol_over_rtol": ATOL_RATIO, "weld_factors": list(WELD_FACTORS),
                              "targets_rad": list(TARGETS)}


def environment() -> dict:
    """Versions, machine and load, and the code's `source_state`, for the report.

    The 1/5/15-minute load averages now are included: other work on the machine inflates wall times.

    Returns:
        dict: 'python', 'platform', 'cpus', 'load_average' (list of three, or None), the 'numpy', 'scipy',
        'numba', 'mujoco' and 'pin' versions (None: absent), 'git_head', 'sources_sha256'.
    """
    def version(dist: str):
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            return None

    return {"python": platform.python_version(), "platform": platform.platform(), "cpus": os.cpu_count(),
            "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
            **{d: version(d) for d in ("numpy", "scipy", "numba", "mujoco", "pin")}, **source_state()}


def source_state() -> dict:
    """The code a report timed: git HEAD and a digest of the package's Python sources.

    The digest covers coopsim/**/*.py, so uncommitted edits are included.

    Returns:
        dict: 'git_head' (None outside a git checkout) and 'sources_sha256': the first 12 hex digits of the
        SHA-256 of the sources.
    """
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for p in sorted(root.rglob("*.py")):
        digest.update(p.relative_to(root).as_posix().encode() + b"\0" + p.read_bytes())
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=10)
        git = head.stdout.strip() if head.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        git = None
    return {"git_head": git, "sources_sha256": digest.hexdigest()[:12]}
