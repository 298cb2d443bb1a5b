"""Result containers shared by the engines, the forward and inverse sides and the MuJoCo twin."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np


@dataclass(frozen=True, eq=False)
class SampledMotion:
    """Motion sampled at N times, joints stacked arm by arm (n), SI units, world axes.

    Attributes:
        t: (N,) s, the sample times.
        q: (N, n) rad (m on a prismatic joint), joint coordinates.
        qd: (N, n) rad/s (m/s), joint rates.
        qdd: (N, n) rad/s² (m/s²), joint accelerations.
        tau: (N, n) N·m (N on a prismatic joint), joint torques.
        object_pos: (N, 3) m, the object's centre of mass C, world axes.
        object_quat: (N, 4) [w, x, y, z], the object's orientation (object frame to world).
        object_twist: (N, 6) [v_C (m/s); ω (rad/s)], the object's twist at C, world axes.
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    tau: np.ndarray
    object_pos: np.ndarray
    object_quat: np.ndarray
    object_twist: np.ndarray


class Projection(NamedTuple):
    """Result of a projection of a state onto the loop-closure manifold.

    Attributes:
        q: (n,) rad (m on a prismatic joint), the consistent joint coordinates.
        qd: (n,) rad/s (m/s), the consistent joint rates.
        dq: (n,) rad (m), the correction applied to q.
        dqd: (n,) rad/s (m/s), the correction applied to qd.
        residual_before: m or rad, max |Φ| of the loop closure before the projection.
        residual_after: m or rad, max |Φ| after it.
        iterations: the number of Gauss–Newton steps taken.
    """

    q: np.ndarray
    qd: np.ndarray
    dq: np.ndarray
    dqd: np.ndarray
    residual_before: float
    residual_after: float
    iterations: int


def output_times(duration: float, dt: float) -> np.ndarray:
    """The output grid of a run: 0, dt, 2dt, … up to and including `duration`.

    The last interval may be shorter.

    Args:
        duration: s.
        dt: s, the sample interval (integrator.output_dt).

    Returns:
        np.ndarray: (N,) s, strictly increasing, from 0 to `duration`.
    """
    k = int(np.floor(duration / dt + 1e-9))
    t = dt * np.arange(k + 1)
    return t if duration - t[-1] <= 1e-9 * dt else np.append(t, duration)
