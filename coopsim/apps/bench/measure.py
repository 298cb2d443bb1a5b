"""The benchmark's settings and measuring tools: the ladders (FULL, QUICK), one timed run's row
(RunRow), best-of-repeats timing, the joint error against the reference, Pareto fronts, power fits,
and the integrator settings of each rung."""

from __future__ import annotations

import importlib.util
import math
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

import coopsim
from coopsim.core.errors import CoopsimError
from coopsim.core.model import IntegratorSettings, Model


OUTPUT_DT = 0.05                     # s: coarse output grid; dense output means it does not limit steps
OWN_GRID = ("paper_planar_2x3",)     # scenes benchmarked on their own output grid too (the speed targets')
REFERENCE_RTOL, REFERENCE_ATOL = 1e-13, 1e-14
CHECK_FACTOR = 10.0                  # the self-convergence run is this much looser
ATOL_RATIO = 0.1                     # atol = rtol · ATOL_RATIO on every adaptive ladder
WELD_FACTORS = (1, 2, 4)             # MuJoCo weld time constant = k · timestep
TARGETS = (1e-3, 1e-6, 1e-8)         # rad: headline error targets
MJ_STAGES = {"RK4": 4, "Euler": 1, "implicit": 1, "implicitfast": 1}  # mj_forward-like stages per step

# The speed targets set for the benchmark (reported, never asserted):
# scenario -> {error target rad: MuJoCo ÷ native at least}
SPEED_TARGETS = {"paper_planar_2x3": {1e-8: 50.0, 1e-6: 10.0, 1e-3: 1.0}, "spatial_6r_pair": {1e-6: 10.0}}
EVAL_RATIO_TARGET = 0.5              # native amortised µs ÷ one constraintDynamics call, at most ...
EVAL_RATIO_SCENES = ("paper_planar_2x3",)   # ... on the paper system
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
        own_grid: names of the scenarios benchmarked a second time on their own output grid
            (integrator.output_dt), where it is not OUTPUT_DT: every sample is reported, so the sampling's
            share of the native time grows with the grid's density.
        inverse_dts: s, the paper carry's object-motion sample intervals of the inverse side's scaling in
            samples (`coopsim.apps.bench.inverse`; empty: no inverse figures).
        inverse_arms: arm counts r of the synthetic r × 6-joint carries of its scaling in arms.
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
    own_grid: tuple[str, ...] = OWN_GRID
    inverse_dts: tuple[float, ...] = (0.04, 0.02, 0.01, 0.005)
    inverse_arms: tuple[int, ...] = (2, 3, 4, 6, 8)


FULL = Ladders()
QUICK = Ladders(rtols=(1e-3, 1e-6, 1e-9), rk4_steps=(0.05, 0.01),
                mujoco=(("RK4", (5e-3, 1e-3)), ("Euler", (5e-3, 1e-3))), pin_rtols=(1e-4, 1e-8),
                max_duration=0.5, repeats=1, repeat_budget_s=0.0, max_repeats=1, eval_states=2000,
                scaling_r=(2, 3), scaling_n=(3, 6), startup=False, inverse_dts=(0.04, 0.02), inverse_arms=(2, 3))


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
    path = Path(coopsim.__file__).resolve().parents[1] / "validation" / "peers.py"
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


def bench_duration(model: Model, ladders: Ladders, output_dt: float = OUTPUT_DT) -> float:
    """Run length: the scenario's, capped by ladders.max_duration, down to a whole number of output intervals.

    Whole intervals because MuJoCo samples on whole steps.

    Args:
        model: the scenario's Model (its duration s).
        ladders: the Ladders (max_duration s, None: no cap).
        output_dt: s, the output grid's interval.

    Returns:
        float: s, a positive whole multiple of output_dt (one interval at least).
    """
    d = model.duration if ladders.max_duration is None else min(model.duration, ladders.max_duration)
    return output_dt * max(1, math.floor(d / output_dt + 1e-9))


def adaptive_settings(model: Model, method: str, rtol: float, atol: float | None = None,
                      output_dt: float = OUTPUT_DT) -> IntegratorSettings:
    """The model's integrator settings with an adaptive method, its tolerances, unbounded step, output every output_dt.

    Args:
        model: the Model whose integrator settings are the base.
        method: 'dop853' | 'dopri5'.
        rtol: relative tolerance.
        atol: absolute tolerance, rad or m and rad/s or m/s (default rtol · ATOL_RATIO).
        output_dt: s, the output grid's interval.

    Returns:
        IntegratorSettings: the modified copy (max_step None, output_dt s).
    """
    return replace(model.integrator, method=method, rtol=rtol, atol=rtol * ATOL_RATIO if atol is None else atol,
                   max_step=None, output_dt=output_dt)


def rk4_settings(model: Model, step: float, output_dt: float = OUTPUT_DT) -> IntegratorSettings:
    """The model's integrator settings with RK4 at `step` s, output every output_dt.

    Args:
        model: the Model whose integrator settings are the base.
        step: s, the fixed step.
        output_dt: s, the output grid's interval.

    Returns:
        IntegratorSettings: the modified copy (method 'rk4', output_dt s).
    """
    return replace(model.integrator, method="rk4", step=step, output_dt=output_dt)
