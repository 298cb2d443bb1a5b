"""Result containers shared by the engines, the forward and inverse sides and the MuJoCo twin."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np


@dataclass(frozen=True, eq=False)
class SampledMotion:
    """Motion sampled at t (N,) s, joints stacked arm by arm (n), SI units, world axes:
    q, qd, qdd (N, n) rad, rad/s, rad/s²; tau (N, n) N·m; object_pos (N, 3) m (centre of mass);
    object_quat (N, 4) [w, x, y, z]; object_twist (N, 6) [v_C; ω]."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    object_pos: np.ndarray
    object_quat: np.ndarray
    object_twist: np.ndarray


class Projection(NamedTuple):
    """Result of a projection: q, qd the consistent state; dq, dqd the corrections applied;
    residual_before / residual_after: max |Φ| (m or rad); iterations: Gauss–Newton steps."""

    q: np.ndarray
    qd: np.ndarray
    dq: np.ndarray
    dqd: np.ndarray
    residual_before: float
    residual_after: float
    iterations: int


def output_times(duration: float, dt: float) -> np.ndarray:
    """The output grid of a run: 0, dt, 2dt, … up to and including `duration` (the last interval may
    be shorter).

    Args:
        duration: s.
        dt: s, the sample interval (integrator.output_dt).

    Returns:
        (N,) s, strictly increasing, from 0 to `duration`.
    """
    k = int(np.floor(duration / dt + 1e-9))
    t = dt * np.arange(k + 1)
    return t if duration - t[-1] <= 1e-9 * dt else np.append(t, duration)
