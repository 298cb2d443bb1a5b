"""The joint model: what a joint of each type does to its link (as Featherstone's `jcalc`, or
Pinocchio's JointModel), for the reference stages; the compiled kernels branch on the same type codes
(`coopsim.core.model.REVOLUTE`, `PRISMATIC`, packed per joint).

A joint i of arm m has a unit axis a_i in its own frame i (placed by `joint_pos`, `joint_rot` at θ = 0)
and one coordinate θ_i:
  * revolute: frame i turned by θ_i rad about a_i, X_J = (Rot(a_i, θ_i), 0); effort a torque (N·m);
  * prismatic: frame i slid θ_i m along a_i, X_J = (1, θ_i a_i); effort a force (N).
Its motion subspace in world axes, written at a point P as [v_P; ω] per unit θ̇_i, with z_i = R_i a_i
and p_i the origin of frame i:
  * revolute: [z_i × (P − p_i); z_i];   * prismatic: [z_i; 0].
The Jacobian columns, the partial accelerations of the Gibbs–Appell terms and the mass matrix are
built from these; the velocity-product terms of the link motion follow from differentiating them
(`coopsim.dynamics.kinematics.link_motion`).
"""

from __future__ import annotations

import numpy as np

from collections.abc import Sequence

from coopsim.core.model import JOINT_TYPES, PRISMATIC, REVOLUTE
from coopsim.core.spatial import axis_angle_to_rot, cross, skew

TYPE_NAMES = {code: name for name, code in JOINT_TYPES.items()}          # 0 → "revolute", 1 → "prismatic"
UNITS = {"revolute": ("rad", "rad/s", "N·m"), "prismatic": ("m", "m/s", "N")}
COORDINATE, RATE, EFFORT = 0, 1, 2                                       # index into a joint's units


def joint_transform(joint_type: int, axis: np.ndarray, q: float) -> tuple[np.ndarray, np.ndarray]:
    """(R_J (3, 3), d_J (3,)): frame i at coordinate q relative to frame i at q = 0, in frame i's axes
    (revolute: Rot(axis, q), 0; prismatic: 1, q axis)."""
    if joint_type == PRISMATIC:
        return np.eye(3), q * np.asarray(axis, dtype=float)
    return axis_angle_to_rot(axis, q), np.zeros(3)


def joint_transforms(joint_type: int, axis: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`joint_transform` over samples q (S,): (R_J (S, 3, 3), d_J (S, 3)), Rodrigues' formula
    1 + sin q [a×] + (1 − cos q)[a×]² for a revolute joint, as `spatial.axis_angle_to_rot`."""
    q = np.asarray(q, dtype=float)
    a = np.asarray(axis, dtype=float)
    if joint_type == PRISMATIC:
        return np.broadcast_to(np.eye(3), q.shape + (3, 3)), q[:, None] * a
    K = skew(a)
    R = np.eye(3) + np.sin(q)[:, None, None] * K + (1.0 - np.cos(q))[:, None, None] * (K @ K)
    return R, np.zeros(q.shape + (3,))


def revolute_mask(joint_type: np.ndarray) -> np.ndarray:
    """(n, 1) float: 1 for a revolute joint, 0 for a prismatic one (to scale per-joint 3-vectors)."""
    return (np.asarray(joint_type) == REVOLUTE).astype(float)[:, None]


def motion_subspace(joint_type: np.ndarray, z: np.ndarray, p: np.ndarray, point: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(linear (…, n, 3), angular (…, n, 3)): the velocity of `point` (…, 3) and the angular velocity
    per unit rate of each joint, z (n, 3) world axes, p (n, 3) frame origins (same origin as point):
    revolute z × (point − p), z; prismatic z, 0 (module docstring). Broadcasts over leading axes of
    point (…, 1, 3)."""
    rev = revolute_mask(joint_type)
    linear = np.where(rev > 0, cross(z, point - p), z)
    return linear, np.broadcast_to(z * rev, linear.shape)


def type_names(joint_type: Sequence[int]) -> list[str]:
    """'revolute' or 'prismatic' per joint of the type codes joint_type (n,)."""
    return [TYPE_NAMES[int(t)] for t in joint_type]


def joint_units(joint_type: int | str) -> tuple[str, str, str]:
    """(coordinate, rate, effort) units of a joint type (code or name): ('rad', 'rad/s', 'N·m') or
    ('m', 'm/s', 'N')."""
    return UNITS[joint_type if isinstance(joint_type, str) else TYPE_NAMES[int(joint_type)]]


def units_of(joint_type: Sequence, kind: int, sep: str = " or ") -> str:
    """The unit of quantity `kind` (COORDINATE, RATE, EFFORT) of several joints (codes or names), for one
    axis label: 'rad', 'm', or both joined by `sep` ('rad or m') when the joints mix types."""
    units = list(dict.fromkeys(joint_units(t)[kind] for t in joint_type))
    return sep.join(units)
