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
    """The joint transform X_J: frame i at coordinate q relative to frame i at q = 0, in frame i's axes.

    Revolute: (Rot(axis, q), 0); prismatic: (1, q axis).

    Args:
        joint_type: the joint's type code (REVOLUTE or PRISMATIC).
        axis: (3,) the unit joint axis a_i, frame i.
        q: rad or m, the joint coordinate θ_i.

    Returns:
        tuple[np.ndarray, np.ndarray]: (R_J (3, 3), d_J (3,) m), rotation and displacement, frame i's
            axes.
    """
    if joint_type == PRISMATIC:
        return np.eye(3), q * np.asarray(axis, dtype=float)
    return axis_angle_to_rot(axis, q), np.zeros(3)


def joint_transforms(joint_type: int, axis: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`joint_transform` of one joint over a series of coordinate samples.

    A revolute joint's rotation is Rodrigues' formula 1 + sin q [a×] + (1 − cos q)[a×]², as
    `spatial.axis_angle_to_rot`.

    Args:
        joint_type: the joint's type code (REVOLUTE or PRISMATIC).
        axis: (3,) the unit joint axis a_i, frame i.
        q: (S,) rad or m, the joint coordinate at each sample.

    Returns:
        tuple[np.ndarray, np.ndarray]: (R_J (S, 3, 3), d_J (S, 3) m), frame i's axes (R_J a read-only
            broadcast view for a prismatic joint).
    """
    q = np.asarray(q, dtype=float)
    a = np.asarray(axis, dtype=float)
    if joint_type == PRISMATIC:
        return np.broadcast_to(np.eye(3), q.shape + (3, 3)), q[:, None] * a
    K = skew(a)
    R = np.eye(3) + np.sin(q)[:, None, None] * K + (1.0 - np.cos(q))[:, None, None] * (K @ K)
    return R, np.zeros(q.shape + (3,))


def revolute_mask(joint_type: np.ndarray) -> np.ndarray:
    """1 for a revolute joint, 0 for a prismatic one, shaped to scale per-joint 3-vectors.

    Args:
        joint_type: (n,) joint type codes (REVOLUTE, PRISMATIC).

    Returns:
        np.ndarray: (n, 1) float, 1.0 where revolute, 0.0 where prismatic.
    """
    return (np.asarray(joint_type) == REVOLUTE).astype(float)[:, None]


def motion_subspace(joint_type: np.ndarray, z: np.ndarray, p: np.ndarray,
                    point: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The joints' motion subspaces at a point: its velocity and the angular velocity per unit joint rate.

    Revolute: z × (point − p), z; prismatic: z, 0 (module docstring). Broadcasts over the leading axes
    of point, given as (…, 1, 3).

    Args:
        joint_type: (n,) joint type codes (REVOLUTE, PRISMATIC).
        z: (n, 3) unit joint axes, world axes.
        p: (n, 3) m, the joints' frame origins, world axes, relative to the same origin as `point`.
        point: (…, 3) m, the point P, world axes ((…, 1, 3) to broadcast over several points).

    Returns:
        tuple[np.ndarray, np.ndarray]: (linear (…, n, 3), angular (…, n, 3)), world axes: the velocity
            of P (m/s per rad/s, or m/s per m/s) and the angular velocity (rad/s per rad/s, or 0) per
            unit rate of each joint.
    """
    rev = revolute_mask(joint_type)
    linear = np.where(rev > 0, cross(z, point - p), z)
    return linear, np.broadcast_to(z * rev, linear.shape)


def type_names(joint_type: Sequence[int]) -> list[str]:
    """'revolute' or 'prismatic' per joint, from type codes.

    Args:
        joint_type: (n,) joint type codes (REVOLUTE, PRISMATIC).

    Returns:
        list[str]: (n,) the type names.
    """
    return [TYPE_NAMES[int(t)] for t in joint_type]


def joint_units(joint_type: int | str) -> tuple[str, str, str]:
    """The (coordinate, rate, effort) units of a joint type.

    Args:
        joint_type: a type code (REVOLUTE, PRISMATIC) or name ('revolute', 'prismatic').

    Returns:
        tuple[str, str, str]: ('rad', 'rad/s', 'N·m') or ('m', 'm/s', 'N').
    """
    return UNITS[joint_type if isinstance(joint_type, str) else TYPE_NAMES[int(joint_type)]]


def units_of(joint_type: Sequence, kind: int, sep: str = " or ") -> str:
    """The unit of one quantity of several joints, for one axis label.

    Args:
        joint_type: (n,) the joints' type codes or names.
        kind: the quantity: COORDINATE, RATE or EFFORT.
        sep: the separator between the units when the joints mix types.

    Returns:
        str: e.g. 'rad', 'm', or both joined by `sep` ('rad or m'), in the order the types first occur.
    """
    units = list(dict.fromkeys(joint_units(t)[kind] for t in joint_type))
    return sep.join(units)
