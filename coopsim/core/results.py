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
