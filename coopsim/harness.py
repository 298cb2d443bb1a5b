"""Cross-validation harness: the native model and the MuJoCo twin, same scenario, same torques,
same consistent initial state, same time grid; then the agreement metrics."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

from .compare import Comparison, compare
from .model import Model
from .mujoco_run import TwinResult, run_twin
from .simulate import SimResult, simulate


@dataclass(frozen=True, eq=False)
class CrossValidation:
    native: SimResult
    twin: TwinResult
    comparison: Comparison


def cross_validate(model: Model, duration: float | None = None, twin_model: Model | None = None,
                   progress: Callable[[str, float], None] | None = None) -> CrossValidation:
    """Run both models over `duration` (default the scenario's) and compare them. `twin_model`
    replaces the model the twin is built from (same joints), e.g. to prove the harness can fail."""
    if duration is not None:
        model = replace(model, duration=duration)
    native = simulate(model, progress=None if progress is None else lambda f: progress("native", f))
    twin = run_twin(twin_model or model, native.initial.q, native.initial.qd, native.t,
                    progress=None if progress is None else lambda f: progress("mujoco", f))
    return CrossValidation(native, twin, compare(native, twin))
