"""Cross-validation harness: the native model and the MuJoCo twin, same scenario, same torques,
same consistent initial state, same time grid; then the agreement metrics. With a controller in the
loop (scenario `control:`) each model runs its own closed loop (the controller fed its own state) and
the controller's references, errors and torques are recorded along both runs."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Callable

import numpy as np

from coopsim.control.controller import closed_loop, record
from coopsim.core.model import Model, MujocoSettings, TorqueTable, ValidationThresholds, loop_controller
from coopsim.forward.simulate import SimResult, simulate
from coopsim.io.log import control_series as series
from coopsim.twin.compare import Comparison, compare
from coopsim.twin.mujoco_run import TwinResult, run_twin
from coopsim.twin.weld import TwinStep, explain, twin_step


@dataclass(frozen=True, eq=False)
class CrossValidation:
    """Both runs and their comparison, and with a controller its records and an open-loop replay.

    Attributes:
        native: the native run (`coopsim.forward.simulate.SimResult`, closed loop with a controller).
        twin: the MuJoCo twin's run (TwinResult) on the native output grid.
        comparison: the agreement metrics of the two runs against the scenario's thresholds.
        control: the controller along the native and the twin run (`coopsim.control.controller.Command`
            of (N, …) arrays each, native first); None without a controller.
        replay: with a controller, the twin driven open-loop by the native closed loop's torques
            (piecewise linear between the native samples) compared with the native run — information, no
            thresholds (its error is the tabulation's, and an unstable open loop, such as a pose held
            against gravity, drifts); None without a controller.
        mujoco: the twin's settings as it ran (its timestep set); None: the native model's.
        step: the twin's step and the weld yield predicted there (`coopsim.twin.weld.TwinStep`), when the
            step was automatic or the comparison failed; None otherwise.
    """

    native: SimResult
    twin: TwinResult
    comparison: Comparison
    control: tuple | None = None
    replay: Comparison | None = None
    mujoco: MujocoSettings | None = None
    step: TwinStep | None = None


def cross_validate(model: Model, duration: float | None = None, twin_model: Model | None = None,
                   progress: Callable[[str, float], None] | None = None,
                   native: SimResult | None = None) -> CrossValidation:
    """Run the native model and its MuJoCo twin on the same torques and compare them.

    A `control:` section runs in the loop of each; the comparison is against the scenario's thresholds.
    Where the twin's `mujoco.timestep` is left out, it is chosen from the weld yield predicted along the
    native run (`coopsim.twin.weld.twin_step`); a failed quantity says whether it is that yield
    (`coopsim.twin.weld.explain`).

    Args:
        model: the scenario's Model.
        duration: s, in place of the model's.
        twin_model: the model the twin is built from in place of `model` (same joints), e.g. to prove
            the harness can fail.
        progress: called with (stage, fraction done), stage "native" or "mujoco".
        native: the native run of `model` already made (e.g. a replay at fixed steps,
            `coopsim.inverse.replay.replay`), which the twin then follows from its initial state on its
            sample times; None: simulated here.

    Returns:
        CrossValidation: both runs on the native output grid, their Comparison (failures explained), the
        twin's settings and step, and with a controller its records on both sides and the twin's open-loop
        replay of the native torques.
    """
    if duration is not None:
        model = replace(model, duration=duration)

    if native is None:
        native = simulate(closed_loop(model), progress=None if progress is None else lambda f: progress("native", f))
    twin_model, step = twin_model or model, None
    if twin_model.mujoco.timestep is None:
        twin_model, step = twin_step(twin_model, native)
    twin = run_twin(twin_model, native.initial.q, native.initial.qd, native.t,
                    progress=None if progress is None else lambda f: progress("mujoco", f))
    comparison = compare(native, twin)
    if not comparison.passed:
        step = step or twin_step(twin_model, native)[1]
        comparison = explain(comparison, step, twin_model.mujoco.weld_solref is not None)
    records = _control_records(native, twin, twin_model)
    replay = None if records is None else _open_loop_replay(native, twin_model)
    return CrossValidation(native, twin, comparison, records, replay, twin_model.mujoco, step)


def _open_loop_replay(native: SimResult, twin_model: Model) -> Comparison:
    """The twin without its controller, fed the native closed loop's sampled torques, against the native
    run (every threshold infinite: reported, never judged)."""
    tables = tuple(TorqueTable(native.t, native.tau[:, sl]) for sl in twin_model.dof_slices)
    open_loop = replace(twin_model, control=None, torques=tables)
    twin = run_twin(open_loop, native.initial.q, native.initial.qd, native.t)
    return compare(native, twin, ValidationThresholds(*(np.inf,) * len(fields(ValidationThresholds))))


def _control_records(native: SimResult, twin: TwinResult, twin_model: Model) -> tuple | None:
    """The controllers of both runs evaluated at their samples (None without a controller)."""
    ctrl = loop_controller(native.model)
    if ctrl is None:
        return None
    twin_ctrl = loop_controller(closed_loop(twin_model))
    return record(ctrl, native.t, native.q, native.qd), record(twin_ctrl, twin.t, twin.q, twin.qd)


def control_series(cv: CrossValidation) -> list:
    """The log channels of the controllers (`coopsim.io.log.control_series`).

    Args:
        cv: the CrossValidation.

    Returns:
        list: the Series /native/control and /mujoco/control (`coopsim.io.log.Series`, at each run's
        sample times); empty without a controller.
    """
    if cv.control is None:
        return []
    law = cv.native.model.control.law
    return [series(rec, res.t, prefix, law) for rec, res, prefix in
            zip(cv.control, (cv.native, cv.twin), ("/native", "/mujoco"))]
