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
    """One compared quantity: its max and RMS over the run, where and when the max occurs, unit, threshold.

    Where: the joint or component; when: s; threshold None: reported, not asserted.

    Attributes:
        name: the quantity, e.g. "joint angle error".
        unit: its unit ("rad", "m", "m/s", "m|rad", ...; joint metrics: the unit of the worst joint).
        max: the largest absolute error over samples and columns, in `unit`.
        rms: the root mean square of the absolute errors over samples and columns, in `unit`.
        where: the column (a joint label such as "arm 1 joint 2", or a component) of the max.
        time: s, the sample time of the max.
        threshold: the largest max that passes, in `unit`; None: reported, not asserted.
        cause: why a failed quantity differs (`coopsim.twin.weld.explain`: the twin's weld yield, or a
            disagreement of the models); None: not explained.
    """

    name: str
    unit: str
    max: float
    rms: float
    where: str
    time: float
    threshold: float | None
    cause: str | None = None

    @property
    def passed(self) -> bool:
        """Whether the max is within the threshold (always, without one)."""
        return self.threshold is None or self.max <= self.threshold

    def failure(self) -> str:
        """The one-line failure message: the max, the threshold, where and when.

        Returns:
            str: e.g. "joint angle error 2.3e-06 rad exceeds 1e-06 rad at arm 1 joint 2, t=0.35 s", and with a
            cause ": " and the cause.
        """
        return (f"{self.name} {self.max:.3g} {self.unit} exceeds {self.threshold:.3g} {self.unit} "
                f"at {self.where}, t={self.time:.6g} s" + (f": {self.cause}" if self.cause else ""))


@dataclass(frozen=True)
class Comparison:
    """All metrics of one scenario; `passed` only if every thresholded metric is within bounds.

    Attributes:
        scenario: the scenario's name.
        metrics: the Metrics, in the order `compare` forms them.
    """

    scenario: str
    metrics: tuple[Metric, ...]

    @property
    def passed(self) -> bool:
        """Whether every metric passed."""
        return all(m.passed for m in self.metrics)

    def failures(self) -> list[str]:
        """The failure messages of the metrics that did not pass.

        Returns:
            list[str]: one `Metric.failure` line each, in the metrics' order; empty when all passed.
        """
        return [m.failure() for m in self.metrics if not m.passed]

    def as_dict(self) -> dict:
        """The comparison as JSON-ready data (summary.json's "agreement").

        Returns:
            dict: scenario, passed, and metrics: name → the Metric's fields and its `passed`.
        """
        return {"scenario": self.scenario, "passed": self.passed,
                "metrics": {m.name: asdict(m) | {"passed": m.passed} for m in self.metrics}}


def _metric(name, unit, err, t, labels, threshold) -> Metric:
    """err (N, k) absolute errors; labels (k,) names of the columns; unit: one for every column, or (k,)
    one per column (joint coordinates: rad or m by joint type; the metric takes its worst column's)."""
    err = np.abs(np.asarray(err, dtype=float).reshape(len(t), -1))
    i, j = np.unravel_index(int(np.argmax(err)), err.shape)
    return Metric(name, unit if isinstance(unit, str) else unit[j], float(err[i, j]),
                  float(np.sqrt(np.mean(err ** 2))), labels[j], float(t[i]), threshold)


def compare(native: SimResult, twin: TwinResult, thresholds: ValidationThresholds | None = None) -> Comparison:
    """Max/RMS errors of the twin against the native model, checked against the thresholds.

    The errors of joint angles and rates, object position and orientation, plus MuJoCo's weld violation
    and the native loop-closure residual; the object velocity error (m/s) is reported without a
    threshold.

    Args:
        native: the native SimResult.
        twin: the MuJoCo TwinResult, on the same time grid.
        thresholds: the ValidationThresholds; None: the native model's (scenario `validation:`).

    Returns:
        Comparison: the seven Metrics: joint angle (rad or m) and rate (rad/s or m/s) errors, object
        position (m, centre of mass) and orientation (rad) errors, object velocity error (m/s), weld
        violation and native loop-closure residual (m or rad).

    Raises:
        ValueError: the two results' sample times differ.
    """
    model = native.model
    th = thresholds or model.validation
    if not np.array_equal(native.t, twin.t):
        raise ValueError("native and twin results are not on the same time grid")
    t, joints = native.t, joint_labels(model)
    units = [joint_units(jt) for jt in model.joint_type]
    metrics = (
        _metric("joint angle error", [u[COORDINATE] for u in units], twin.q - native.q, t, joints,
                th.max_angle_error),
        _metric("joint rate error", [u[RATE] for u in units], twin.qd - native.qd, t, joints, th.max_rate_error),
        _metric("object position error", "m", np.linalg.norm(twin.object_pos - native.object_pos, axis=1), t,
                ["object centre of mass"], th.max_object_position_error),
        _metric("object orientation error", "rad", orientation_error(twin.object_quat, native.object_quat), t,
                ["object frame"], th.max_object_orientation_error),
        _metric("object velocity error", "m/s",
                np.linalg.norm(twin.object_twist[:, :3] - native.object_twist[:, :3], axis=1),
                t, ["object centre of mass"], None),
        _metric("MuJoCo weld violation", "m|rad", twin.weld_violation, t, ["welds"], th.max_weld_violation),
        _metric("native loop-closure residual", "m|rad", native.residual_pos, t, ["grasps"], th.max_native_residual),
    )
    return Comparison(model.name, metrics)


def format_comparison(cmp: Comparison) -> str:
    """A fixed-width table of the metrics with PASS/FAIL marks.

    Args:
        cmp: the Comparison.

    Returns:
        str: a PASS/FAIL heading, a column header and one line per metric, without a trailing newline.
    """
    lines = [f"{cmp.scenario}: {'PASS' if cmp.passed else 'FAIL'}",
             f"  {'quantity':<30} {'max':>10} {'rms':>10} {'threshold':>10}  unit    where / when"]
    for m in cmp.metrics:
        th = f"{m.threshold:.1e}" if m.threshold is not None else "-"
        mark = "" if m.passed else "  <-- FAIL"
        lines.append(f"  {m.name:<30} {m.max:>10.3e} {m.rms:>10.3e} {th:>10}  {m.unit:<6}  "
                     f"{m.where}, t={m.time:.4g} s{mark}")
    return "\n".join(lines)
