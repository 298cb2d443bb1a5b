"""Agreement metrics between the native model and the MuJoCo twin on a common time grid."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from coopsim.core.joints import COORDINATE, RATE, joint_units
from coopsim.core.labels import joint_labels
from coopsim.core.model import ValidationThresholds
from coopsim.twin.mujoco_run import TwinResult
from coopsim.forward.simulate import SimResult
from coopsim.core.spatial import orientation_error  # noqa: F401  (the metric; re-exported for the tests)


@dataclass(frozen=True)
class Metric:
    """One compared quantity: max and RMS over the run, where (joint or component) and when (s) the
    max occurs, its unit and threshold (None: reported, not asserted)."""

    name: str
    unit: str
    max: float
    rms: float
    where: str
    time: float
    threshold: float | None

    @property
    def passed(self) -> bool:
        return self.threshold is None or self.max <= self.threshold

    def failure(self) -> str:
        return (f"{self.name} {self.max:.3g} {self.unit} exceeds {self.threshold:.3g} {self.unit} "
                f"at {self.where}, t={self.time:.6g} s")


@dataclass(frozen=True)
class Comparison:
    """All metrics of one scenario; `passed` only if every thresholded metric is within bounds."""

    scenario: str
    metrics: tuple[Metric, ...]

    @property
    def passed(self) -> bool:
        return all(m.passed for m in self.metrics)

    def failures(self) -> list[str]:
        return [m.failure() for m in self.metrics if not m.passed]

    def as_dict(self) -> dict:
        return {"scenario": self.scenario, "passed": self.passed,
                "metrics": {m.name: asdict(m) | {"passed": m.passed} for m in self.metrics}}


def _metric(name, unit, err, t, labels, threshold) -> Metric:
    """err (N, k) absolute errors; labels (k,) names of the columns; unit: one for every column, or (k,)
    one per column (joint coordinates: rad or m by joint type; the metric takes its worst column's)."""
    err = np.abs(np.asarray(err, dtype=float).reshape(len(t), -1))
    i, j = np.unravel_index(int(np.argmax(err)), err.shape)
    return Metric(name, unit if isinstance(unit, str) else unit[j], float(err[i, j]), float(np.sqrt(np.mean(err ** 2))), labels[j], float(t[i]), threshold)


def compare(native: SimResult, twin: TwinResult, thresholds: ValidationThresholds | None = None) -> Comparison:
    """Max/RMS errors of joint angles and rates, object position and orientation, plus MuJoCo's weld
    violation and the native loop-closure residual, checked against the thresholds."""
    model = native.model
    th = thresholds or model.validation
    if not np.array_equal(native.t, twin.t):
        raise ValueError("native and twin results are not on the same time grid")
    t, joints = native.t, joint_labels(model)
    units = [joint_units(jt) for jt in model.joint_type]
    metrics = (
        _metric("joint angle error", [u[COORDINATE] for u in units], twin.q - native.q, t, joints, th.max_angle_error),
        _metric("joint rate error", [u[RATE] for u in units], twin.qd - native.qd, t, joints, th.max_rate_error),
        _metric("object position error", "m", np.linalg.norm(twin.object_pos - native.object_pos, axis=1), t,
                ["object centre of mass"], th.max_object_position_error),
        _metric("object orientation error", "rad", orientation_error(twin.object_quat, native.object_quat), t,
                ["object frame"], th.max_object_orientation_error),
        _metric("object velocity error", "m/s", np.linalg.norm(twin.object_twist[:, :3] - native.object_twist[:, :3], axis=1),
                t, ["object centre of mass"], None),
        _metric("MuJoCo weld violation", "m|rad", twin.weld_violation, t, ["welds"], th.max_weld_violation),
        _metric("native loop-closure residual", "m|rad", native.residual_pos, t, ["grasps"], th.max_native_residual),
    )
    return Comparison(model.name, metrics)


def format_comparison(cmp: Comparison) -> str:
    """A fixed-width table of the metrics with PASS/FAIL marks."""
    lines = [f"{cmp.scenario}: {'PASS' if cmp.passed else 'FAIL'}",
             f"  {'quantity':<30} {'max':>10} {'rms':>10} {'threshold':>10}  unit    where / when"]
    for m in cmp.metrics:
        th = f"{m.threshold:.1e}" if m.threshold is not None else "-"
        mark = "" if m.passed else "  <-- FAIL"
        lines.append(f"  {m.name:<30} {m.max:>10.3e} {m.rms:>10.3e} {th:>10}  {m.unit:<6}  {m.where}, t={m.time:.4g} s{mark}")
    return "\n".join(lines)
